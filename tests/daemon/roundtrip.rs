//! Simulate, then reconstruct, on the 16x16-scene Brewster bench with noise
//! (issue 2): ADMM-TV against least squares, the crossed polarizer against no
//! polarizer at equal exposure, and the camera-frame path through homographies.

use std::path::PathBuf;

use polnlos::measure::wall_means;
use polnlos::scene::{FrameGeometry, Scene};
use polnlos::simulate::camera;
use polnlos::simulate::patterns::Pattern;
use polnlos::simulate::{unpolarized_peak, NoiseModel, Simulation};
use polnlos::solve::{admm_tv, least_squares, metrics, AdmmSettings};
use polnlos::transport::{build, MemoryBudget, Transport};

fn bench16(kind: &str) -> Scene {
    let path = PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join(format!("config/scenes/brewster-{kind}.toml"));
    let text = std::fs::read_to_string(path)
        .unwrap()
        .replace("grid = [8, 8]", "grid = [16, 16]");
    Scene::from_toml_str(&text).unwrap()
}

const NOISE: NoiseModel = NoiseModel {
    photons: 20_000.0,
    read_noise: 5.0,
    bits: 12,
    seed: 11,
};

fn simulate(scene: &Scene, t: &Transport, truth: &[f64]) -> Simulation {
    let peak = unpolarized_peak(scene, t, truth, MemoryBudget::DEFAULT).unwrap();
    NOISE.apply(t.apply(truth), peak).unwrap()
}

#[test]
fn admm_tv_beats_least_squares_and_the_crossed_polarizer_helps() {
    let settings = AdmmSettings {
        max_iter: 3000,
        ..Default::default()
    };
    let crossed = bench16("crossed");
    let nopol = bench16("nopol");
    let (tc, tn) = (
        build(&crossed, MemoryBudget::DEFAULT).unwrap(),
        build(&nopol, MemoryBudget::DEFAULT).unwrap(),
    );
    let mut crossed_wins = 0;
    for p in Pattern::ALL {
        let truth = p.render(tc.scene_grid());
        let sc = simulate(&crossed, &tc, &truth);
        let sn = simulate(&nopol, &tn, &truth);
        let admm_c = admm_tv(&tc, &sc.measurement, &settings).unwrap();
        let admm_n = admm_tv(&tn, &sn.measurement, &settings).unwrap();
        let lsq_c = least_squares(&tc, &sc.measurement, None).unwrap();
        let (pc, pn, pl) = (
            metrics::psnr(&truth, &admm_c.image),
            metrics::psnr(&truth, &admm_n.image),
            metrics::psnr(&truth, &lsq_c.image),
        );
        println!(
            "{:6}: ADMM-TV crossed {pc:.2} dB ({} it), ADMM-TV no polarizer {pn:.2} dB ({} it), LSQ crossed {pl:.2} dB",
            p.name(),
            admm_c.stats.iterations,
            admm_n.stats.iterations
        );
        assert!(admm_c.stats.converged && admm_n.stats.converged);
        assert!(pc > pl + 5.0, "{}: ADMM-TV {pc} vs LSQ {pl}", p.name());
        // The crossed image is darker at equal exposure: fewer electrons.
        let mean = |s: &Simulation| {
            s.clean.iter().sum::<f64>() * s.electrons_per_unit / s.clean.len() as f64
        };
        assert!(mean(&sc) < 0.5 * mean(&sn));
        crossed_wins += (pc > pn) as usize;
    }
    assert!(crossed_wins >= 1, "the crossed polarizer won on no pattern");
}

#[test]
fn frames_rendered_pixel_by_pixel_measure_back_to_the_pixel_rows() {
    // Each pixel at its own wall point; with rows over exactly those pixels
    // (MODEL.md revision 3, sampling = "pixels") T l is what the camera measures.
    let scene = Scene::from_toml_str(
        &std::fs::read_to_string(
            PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("config/scenes/brewster-multi.toml"),
        )
        .unwrap()
        .replace("ks = 1.0", "ks = 1.0\nsampling = \"pixels\""),
    )
    .unwrap();
    let t = build(&scene, MemoryBudget::DEFAULT).unwrap();
    let truth = Pattern::Letter.render(t.scene_grid());
    let want = t.apply(&truth);
    let frames = camera::render(&scene, &truth, FrameGeometry::plain(512, 512));
    for (b, (block, frame)) in frames.iter().enumerate() {
        let pose = scene.pose(&block.pose).unwrap();
        let h = pose.homography.as_ref().unwrap();
        let back = wall_means(frame.as_ref().unwrap(), h, &scene.wall().plane, &pose.name).unwrap();
        for (j, (a, w)) in back.iter().zip(&want[t.block_rows(b)]).enumerate() {
            assert!(
                (a - w).abs() <= 1e-6 * w.abs().max(1e-12),
                "block {b} element {j}: {a} vs {w}"
            );
        }
    }
}

#[test]
fn a_wall_element_outside_the_frame_is_an_error_naming_it() {
    let scene = bench16("crossed");
    let pose = &scene.poses()[0];
    let frame = polnlos::scene::Frame::zeros(300, 300);
    let e = wall_means(
        &frame,
        pose.homography.as_ref().unwrap(),
        &scene.wall().plane,
        "A",
    )
    .unwrap_err();
    assert!(
        e.to_string().starts_with("pose \"A\": wall element")
            && e.to_string().contains("partly outside the frame"),
        "{e}"
    );
}

#[test]
fn frames_with_per_pixel_noise_carry_a_variance_the_model_check_confirms() {
    // Camera frames drawn pixel by pixel with per-pixel noise, measured from all
    // of each element's pixels: with the rows that match (sampling = "pixels")
    // the best fit's misfit is the propagated noise, chi2/dof = 1 +- 0.1.
    use polnlos::measure::{assemble, CaptureFrames, FrameStack};
    use polnlos::solve::lambda::NoiseLevel;
    use polnlos::solve::reconstruct::{reconstruct, Context};
    use polnlos::solve::{condition, SolveRequest};
    use rand::SeedableRng;
    use rand_distr::{Distribution, Normal};
    let text = std::fs::read_to_string(
        PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("config/scenes/brewster-rotating.toml"),
    )
    .unwrap()
    .replace("ks = 1.0", "ks = 1.0\nsampling = \"pixels\"");
    let scene = Scene::from_toml_str(&text).unwrap();
    let t = build(&scene, MemoryBudget::DEFAULT).unwrap();
    let truth = Pattern::Disk.render(t.scene_grid());
    let rendered = camera::render(&scene, &truth, FrameGeometry::plain(512, 512));
    let peak = rendered
        .iter()
        .flat_map(|(_, f)| f.as_ref().unwrap().pixels.iter().copied())
        .fold(0.0f32, f32::max);
    let dn_per_unit = 3000.0 / f64::from(peak);
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(21);
    // Four blocks of 1024 elements, 16 frames each: chi2/dof of 4000 terms
    // scatters by about 2 %.
    let (blocks, captures): (Vec<_>, Vec<_>) = rendered
        .into_iter()
        .map(|(block, clean)| {
            let clean = clean.unwrap();
            let mut stack = FrameStack::new(512, 512);
            for _ in 0..16 {
                let frame: Vec<f64> = clean
                    .pixels
                    .iter()
                    .map(|&c| {
                        let dn = f64::from(c) * dn_per_unit;
                        // Shot noise of ~1 e-/DN and 5 DN of read noise.
                        dn + Normal::new(0.0, (dn + 25.0).sqrt())
                            .unwrap()
                            .sample(&mut rng)
                    })
                    .collect();
                stack.push(&frame);
            }
            let capture = CaptureFrames {
                name: block.label(),
                pose: block.pose.clone(),
                channels: vec![block.channel],
                mean: stack.mean_minus(None).unwrap(),
                variance: stack.variance_frame(),
                frames: 16,
                full_scale: dn_per_unit,
                exposure_us: 1.0,
                offset: [0, 0],
                binning: [1, 1],
                bayer: None,
            };
            (block, capture)
        })
        .unzip();
    let m = assemble(&scene, &blocks, &captures).unwrap();
    let cond = condition(&t).unwrap();
    let ctx = Context {
        scene: "brewster-rotating".into(),
        transport_seconds: 0.0,
        truth: Some(&truth),
        stop: Default::default(),
    };
    let noise = NoiseLevel::measured(m.variance.unwrap());
    let solved = reconstruct(&t, &m.i, Some(noise), &cond, &SolveRequest::default(), ctx).unwrap();
    let check = solved.report.model_check.unwrap();
    let chi2 = check.chi2_per_dof.unwrap();
    println!(
        "chi2/dof {chi2:.3}, PSNR {:.2} dB",
        solved.report.metrics.unwrap().psnr_db
    );
    assert!((chi2 - 1.0).abs() <= 0.1, "{check:?}");
}
