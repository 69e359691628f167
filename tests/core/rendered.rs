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

use polnlos::optics::{DiffuseModel, PolarizerModel};
use polnlos::report::{agreement, reconstruct_pair, PairNoise, RenderedCase};
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
    crate::priority::background();
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
    crate::priority::background();
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
    crate::priority::background();
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
    crate::priority::background();
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

/// The cases rendered as camera frames (a jittered ray per pixel sample
/// through each pose's homography), measured as polnlos measures a capture.
fn frame_cases() -> Vec<RenderedCase> {
    let root = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests/data/rendered");
    let mut out = Vec::new();
    for name in ["crossed", "rotating", "occluder-crossed", "multi"] {
        let dir = root.join(name);
        if dir.join("frames").is_dir() {
            out.push(RenderedCase::load_frames(&dir).unwrap());
        }
    }
    out
}

/// `scene` with its rows sampled `sampling` (and the wall's `m`).
fn sampled(c: &RenderedCase, sampling: &str, m: usize) -> polnlos::scene::Scene {
    let s = polnlos::scene::WallSampling::from_name(sampling).unwrap();
    c.scene
        .clone()
        .edit(|p| {
            p.wall.sampling = s;
            p.wall.plane.supersample = m;
        })
        .unwrap()
}

/// Gain, residual and noise (relative to the render's rms) of `predicted`
/// against the render on the rows `rows` of every block.
fn agreement_on(c: &RenderedCase, rows: &[usize], predicted: &[f64]) -> (f64, f64, f64) {
    let n_wall = c.scene.wall().plane.grid.count();
    let blocks = c.scene.block_count();
    let (mut i, mut s) = (Vec::new(), Vec::new());
    for b in 0..blocks {
        for &j in rows {
            i.push(c.i[b * n_wall + j]);
            s.push(c.sigma[b * n_wall + j]);
        }
    }
    let dot = |a: &[f64], b: &[f64]| a.iter().zip(b).map(|(x, y)| x * y).sum::<f64>();
    let gain = dot(predicted, &i) / dot(predicted, predicted);
    let n = i.len() as f64;
    let rms = (dot(&i, &i) / n).sqrt();
    let resid = (i
        .iter()
        .zip(predicted)
        .map(|(a, p)| (a - gain * p).powi(2))
        .sum::<f64>()
        / n)
        .sqrt();
    let noise = (dot(&s, &s) / n).sqrt();
    (gain, resid / rms, noise / rms)
}

#[test]
fn camera_frames_measure_to_the_pixel_rows_within_their_noise() {
    crate::priority::background();
    // MODEL.md revision 3: the measurement averages every pixel of an element,
    // and rows over exactly those pixels explain it to the render's noise;
    // rows over the element's uniform sub-samples leave the pixel straddling.
    // Rows of every 16th element (64 per block), so that the occluder's
    // shadow edges can have the 32x32 scene sub-samples they need.
    let all = frame_cases();
    let names: Vec<&str> = all.iter().map(|c| c.name.as_str()).collect();
    for needed in [
        "crossed-frames",
        "rotating-frames",
        "occluder-crossed-frames",
    ] {
        assert!(
            names.contains(&needed),
            "no camera-frame case {needed}: {names:?}"
        );
    }
    println!("case                     rows           gain     residual  noise    ratio");
    for c in &all {
        let rows: Vec<usize> = (3..c.scene.wall().plane.grid.count()).step_by(16).collect();
        for (sampling, m) in [("pixels", 1), ("uniform", 1), ("uniform", 4)] {
            let scene = sampled(c, sampling, m);
            let data =
                polnlos::transport::build_elements(&scene, &rows, MemoryBudget::DEFAULT).unwrap();
            let n = rows.len() * scene.block_count();
            let mut predicted = vec![0.0; n];
            for (k, col) in data.chunks(n).enumerate() {
                predicted
                    .iter_mut()
                    .zip(col)
                    .for_each(|(p, t)| *p += t * c.truth[k]);
            }
            let (gain, residual, noise) = agreement_on(c, &rows, &predicted);
            let ratio = residual / noise;
            println!(
                "{:<24} {sampling:>7} m={m}  {gain:.5}  {:.4}%   {:.4}%  {ratio:.2}",
                c.name,
                100.0 * residual,
                100.0 * noise,
            );
            if sampling == "pixels" {
                assert!((gain - 1.0).abs() <= 0.005, "{}: gain {gain}", c.name);
                assert!(ratio <= 1.5, "{}: residual {ratio} x the noise", c.name);
            }
        }
    }
}

#[test]
fn camera_frames_reconstruct_with_pixel_rows_at_least_as_well_as_with_centre_samples() {
    crate::priority::background();
    let c = frame_cases()
        .into_iter()
        .find(|c| c.name == "crossed-frames")
        .unwrap();
    let noise = PairNoise::Render { seed: 5 };
    let pixels = build(&sampled(&c, "pixels", 1), MemoryBudget::DEFAULT).unwrap();
    let centre = build(&sampled(&c, "uniform", 1), MemoryBudget::DEFAULT).unwrap();
    let p = reconstruct_pair(&pixels, &c, noise, MemoryBudget::DEFAULT).unwrap();
    let u = reconstruct_pair(&centre, &c, noise, MemoryBudget::DEFAULT).unwrap();
    println!(
        "crossed camera frames: PSNR {:.2} dB with pixel rows, {:.2} dB with centre samples",
        p.rendered.psnr_db, u.rendered.psnr_db
    );
    assert!(p.rendered.psnr_db >= u.rendered.psnr_db - 0.1);
    // And as well as polnlos's own simulation at the render's noise.
    assert!(p.rendered.psnr_db >= p.simulated.psnr_db - 1.5, "{p:?}");
}

/// Issue 27's comparison: a polarization camera against a crossed and a
/// rotating sheet at equal total exposure, on polnlos's camera-frame
/// simulation and on Mitsuba's camera frames composed into a mosaic.
#[test]
fn a_polarization_camera_is_compared_with_sheets_at_equal_exposure() {
    crate::priority::background();
    let dir = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests/data/rendered/rotating/frames");
    let mut steps = 0;
    let r =
        polnlos::report::mosaic_report(&dir, MemoryBudget::DEFAULT, &mut || steps += 1).unwrap();
    assert_eq!(steps, polnlos::report::MOSAIC_STEPS);
    assert!(r.rendered_skipped.is_none(), "{:?}", r.rendered_skipped);
    for row in &r.rows {
        println!(
            "{:32} kappa {:.3e}  PSNR simulated {:.2} dB, Mitsuba {:.2} dB",
            row.setup,
            row.kappa,
            row.simulated.psnr_db,
            row.rendered.map_or(f64::NAN, |m| m.psnr_db)
        );
    }
    let by = |s: &str| r.rows.iter().find(|row| row.setup.starts_with(s)).unwrap();
    let (rotating, ideal) = (by("rotating"), by("mosaic, ideal"));
    // An ideal mosaic at crossed is the rotating sheet's T, each block's rows
    // over a quarter of the pixels (kappa within 1 %); one exposure of all the
    // time gathers the photons four quarter exposures do.
    assert!((ideal.kappa / rotating.kappa - 1.0).abs() < 0.01);
    for (mosaic, sheet) in [
        (ideal.simulated, rotating.simulated),
        (ideal.rendered.unwrap(), rotating.rendered.unwrap()),
    ] {
        assert!(
            mosaic.psnr_db > sheet.psnr_db - 1.0,
            "mosaic {} dB, rotating sheet {} dB",
            mosaic.psnr_db,
            sheet.psnr_db
        );
    }
    let md = polnlos::report::Report::markdown(&r);
    assert!(md.contains("| mosaic, extinction 100 | 1 |"), "{md}");
}

/// Issue 26: a scene file that leaves the sampling keys out lets a
/// reconstruction choose them from the noise (`transport::choose`); on the
/// camera-frame renders that choice reconstructs within 0.5 dB of the file
/// with scene supersample 8 and pixel rows.
#[test]
fn a_file_without_sampling_keys_reconstructs_as_well_as_supersample_8() {
    crate::priority::background();
    use polnlos::solve::lambda::NoiseLevel;
    use polnlos::solve::metrics::compare;
    use polnlos::solve::reconstruct::Context;
    use polnlos::solve::{condition, reconstruct, SolveRequest};
    use rand::SeedableRng;
    use rand_distr::{Distribution, StandardNormal};
    let root = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests/data/rendered");
    let budget = MemoryBudget::DEFAULT;
    for case in frame_cases() {
        // The case's file with every sampling key removed.
        let dir = root
            .join(case.name.trim_end_matches("-frames"))
            .join("frames");
        let text: String = std::fs::read_to_string(dir.join("scene.toml"))
            .unwrap()
            .lines()
            .filter(|l| !l.starts_with("supersample") && !l.starts_with("sampling"))
            .map(|l| format!("{l}\n"))
            .collect();
        let bare = polnlos::scene::Scene::from_toml_str(&text).unwrap();
        let left = bare.left_out();
        assert!(left.wall_supersample && left.scene_supersample && left.sampling);
        let fine = bare
            .clone()
            .edit(|p| {
                p.hidden.plane.supersample = 8;
                p.wall.sampling = polnlos::scene::WallSampling::Pixels;
            })
            .unwrap();
        let t_fine = build(&fine, budget).unwrap();
        // Its conditioning serves both noise levels (an SVD of a T with
        // pixel rows: most of this test's time).
        let cond_fine = condition(&t_fine).unwrap();
        // The other samplings chosen, each built and conditioned once.
        let mut chosen_ts: Vec<(
            String,
            polnlos::transport::Transport,
            polnlos::solve::Conditioning,
        )> = Vec::new();
        // At the render's noise, and at 10x it (a shorter capture), where
        // the choice is coarser.
        for factor in [1.0, 10.0] {
            let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(5);
            let extra = (factor * factor - 1.0f64).sqrt();
            let i: Vec<f64> = case
                .i
                .iter()
                .zip(&case.sigma)
                .map(|(v, s)| {
                    let z: f64 = StandardNormal.sample(&mut rng);
                    v + extra * s * z
                })
                .collect();
            let variance: Vec<f64> = case.sigma.iter().map(|s| (factor * s).powi(2)).collect();
            let psnr =
                |t: &polnlos::transport::Transport, cond: &polnlos::solve::Conditioning| -> f64 {
                    let solved = reconstruct(
                        t,
                        &i,
                        Some(NoiseLevel::measured(variance.clone())),
                        cond,
                        &SolveRequest::default(),
                        Context::default(),
                    )
                    .unwrap();
                    compare(t.scene_grid(), &case.truth, &solved.image).psnr_db
                };
            let (chosen, choice) =
                polnlos::transport::choose::choose(&bare, &variance, budget).unwrap();
            // The same sampling is the same T: built once.
            let same = (
                choice.sampling,
                choice.wall_supersample,
                choice.scene_supersample,
            ) == (fine.wall().sampling, fine.wall().plane.supersample, 8);
            let b = psnr(&t_fine, &cond_fine);
            let a = if same {
                b
            } else {
                let key = format!(
                    "{:?} {} {}",
                    choice.sampling, choice.wall_supersample, choice.scene_supersample
                );
                if !chosen_ts.iter().any(|c| c.0 == key) {
                    let t = build(&chosen, budget).unwrap();
                    let cond = condition(&t).unwrap();
                    chosen_ts.push((key.clone(), t, cond));
                }
                let (_, t, cond) = chosen_ts.iter().find(|c| c.0 == key).unwrap();
                psnr(t, cond)
            };
            println!(
                "{} at {factor}x the render noise: chose {:?} (scene supersample {}, error {:.2} of the noise) {a:.2} dB, supersample 8 {b:.2} dB",
                case.name, choice.chosen, choice.scene_supersample, choice.error_over_noise
            );
            assert!(
                (a - b).abs() <= 0.5,
                "{} at {factor}x: {a} dB vs {b} dB",
                case.name
            );
        }
    }
}
