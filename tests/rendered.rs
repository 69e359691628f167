//! polnlos against data it did not make: cases rendered by Mitsuba 3's
//! polarized path tracer (`validation/mitsuba/`, committed in
//! `tests/data/rendered/`; no Mitsuba is needed to run this).
//!
//! For every case `T truth` must match the render with a gain within 0.5 %
//! of 1 and a residual within 1.5x the render's noise floor; the previous
//! reading of the model (transmitting axis, Lambert diffuse term) must not;
//! and reconstructing the rendered crossed case must lose at most 1.5 dB
//! against reconstructing polnlos's own simulation at the same noise.

use std::path::PathBuf;

use polnlos::bench::rendered::{agreement, reconstruct_pair, PairNoise, RenderedCase};
use polnlos::optics::{DiffuseModel, PolarizerModel};
use polnlos::transport::{build, MemoryBudget};

fn cases() -> Vec<RenderedCase> {
    let root = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests/data/rendered");
    RenderedCase::load_all(&root).unwrap()
}

fn case(name: &str) -> RenderedCase {
    cases().into_iter().find(|c| c.name == name).unwrap()
}

#[test]
fn every_rendered_case_matches_t_to_its_noise() {
    let all = cases();
    let names: Vec<&str> = all.iter().map(|c| c.name.as_str()).collect();
    for needed in [
        "crossed",
        "nopol",
        "rotating",
        "multi",
        "crossed-kd",
        "nopol-kd",
        "occluder-crossed",
    ] {
        assert!(
            names.contains(&needed),
            "no rendered case {needed}: {names:?}"
        );
    }
    println!("case               gain     corr       residual  noise    ratio");
    for c in &all {
        let a = agreement(&build(&c.scene, MemoryBudget::DEFAULT).unwrap(), c);
        println!(
            "{:<18} {:.5}  {:.7}  {:.4}%   {:.4}%  {:.2}",
            c.name,
            a.gain,
            a.correlation,
            100.0 * a.residual,
            100.0 * a.noise,
            a.ratio
        );
        assert!((a.gain - 1.0).abs() <= 0.005, "{}: gain {}", c.name, a.gain);
        assert!(
            a.ratio <= 1.5,
            "{}: residual {} x the noise",
            c.name,
            a.ratio
        );
    }
}

#[test]
fn the_revision_1_model_does_not_explain_the_renders() {
    // The transmitting axis under crossed extinction and the Lambert diffuse
    // term leave structure far above the render's noise.
    let crossed = case("crossed");
    let t = build(
        &crossed
            .scene
            .with_polarizer_model(PolarizerModel::Transmitting),
        MemoryBudget::DEFAULT,
    )
    .unwrap();
    let a = agreement(&t, &crossed);
    println!("crossed, transmitting: {a:?}");
    assert!(a.ratio > 10.0, "{a:?}");

    let kd = case("nopol-kd");
    let lambert = kd
        .scene
        .clone()
        .edit(|s| s.wall.brdf.diffuse = DiffuseModel::Lambert)
        .unwrap();
    let a = agreement(&build(&lambert, MemoryBudget::DEFAULT).unwrap(), &kd);
    println!("nopol-kd, lambert: {a:?}");
    assert!(a.ratio > 3.0, "{a:?}");
}

#[test]
fn the_rendered_crossed_case_reconstructs_as_well_as_polnlos_own_simulation() {
    // At the render's own noise (0.19 %): the simulation gets Gaussian noise
    // of the render's per-element standard error.
    let c = case("crossed");
    let noise = PairNoise::Render { seed: 5 };
    let t = build(&c.scene, MemoryBudget::DEFAULT).unwrap();
    let pair = reconstruct_pair(&t, &c, noise, MemoryBudget::DEFAULT).unwrap();
    println!("absorbing: {pair:?}");
    let loss = pair.simulated.psnr_db - pair.rendered.psnr_db;
    assert!(loss <= 1.5, "the render loses {loss:.2} dB: {pair:?}");
    // Under the previous reading the same render loses several dB: the check bites.
    let t = build(
        &c.scene.with_polarizer_model(PolarizerModel::Transmitting),
        MemoryBudget::DEFAULT,
    )
    .unwrap();
    let old = reconstruct_pair(&t, &c, noise, MemoryBudget::DEFAULT).unwrap();
    println!("transmitting: {old:?}");
    assert!(
        old.simulated.psnr_db - old.rendered.psnr_db > 3.0,
        "{old:?}"
    );
}

#[test]
fn a_reconstruction_says_when_the_model_does_not_explain_the_data() {
    use polnlos::solve::lambda::NoiseLevel;
    use polnlos::solve::reconstruct::Context;
    use polnlos::solve::{condition, reconstruct, SolveRequest};
    let c = case("crossed");
    let variance: Vec<f64> = c.sigma.iter().map(|s| s * s).collect();
    let check = |model: PolarizerModel| {
        let t = build(&c.scene.with_polarizer_model(model), MemoryBudget::DEFAULT).unwrap();
        let cond = condition(&t).unwrap();
        reconstruct(
            &t,
            &c.i,
            Some(NoiseLevel::measured(variance.clone())),
            &cond,
            &SolveRequest::default(),
            Context::default(),
        )
        .unwrap()
        .report
    };
    let good = check(PolarizerModel::Absorbing);
    let a = good.model_check.unwrap();
    println!("absorbing: {a:?}");
    assert_eq!(a.explained, Some(true), "{a:?}");
    assert!(!good.warnings.iter().any(|w| w.contains("does not explain")));
    let bad = check(PolarizerModel::Transmitting);
    let a = bad.model_check.unwrap();
    println!("transmitting: {a:?}");
    assert_eq!(a.explained, Some(false), "{a:?}");
    assert!(a.misfit_to_noise.unwrap() > 10.0, "{a:?}");
    let w = bad
        .warnings
        .iter()
        .find(|w| w.contains("does not explain this measurement"))
        .unwrap();
    assert!(
        w.contains("polarizer model") && w.contains("homographies"),
        "{w}"
    );
}
