//! Where the methods fail (issue 2): mirror-like and fully diffuse walls, a
//! grazing camera, a rank-deficient T, bad measurements, lambda = 0.
//! Every case ends in finite numbers with a warning, an infinite kappa, or a
//! clear error; never a NaN or a panic.

use std::path::PathBuf;

use polnlos::scene::Scene;
use polnlos::simulate::patterns::Pattern;
use polnlos::solve::{admm_tv, condition, least_squares, tikhonov, AdmmSettings, SolveError};
use polnlos::transport::{build, MemoryBudget, Transport};

fn crossed3(edit: impl Fn(String) -> String) -> Scene {
    let path =
        PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("config/scenes/brewster-crossed-3x3.toml");
    Scene::from_toml_str(&edit(std::fs::read_to_string(path).unwrap())).unwrap()
}

fn all_finite(v: &[f64]) -> bool {
    v.iter().all(|x| x.is_finite())
}

/// Builds T, checks it and its kappa, and runs all three solvers on a clean measurement.
fn survives(scene: &Scene) -> (Transport, f64) {
    let t = build(scene, MemoryBudget::DEFAULT).unwrap();
    assert!(all_finite(t.col_major()), "T has a non-finite entry");
    let c = condition(&t).unwrap();
    assert!(!c.kappa.is_nan());
    let i = t.apply(&Pattern::Disk.render(t.scene_grid()));
    let r = admm_tv(&t, &i, &AdmmSettings::default()).unwrap();
    assert!(all_finite(&r.image) && r.image.iter().all(|v| (0.0..=1.0).contains(v)));
    assert!(
        r.stats.converged || !r.stats.warnings.is_empty(),
        "no convergence and no warning"
    );
    assert!(all_finite(&least_squares(&t, &i, None).unwrap().image));
    if let Ok(r) = tikhonov(&t, &i, None) {
        assert!(all_finite(&r.image));
    }
    (t, c.kappa)
}

#[test]
fn mirror_like_and_fully_diffuse_walls() {
    let mirror = crossed3(|s| s.replace("roughness = 0.3", "roughness = 0.01"));
    let (_, kappa) = survives(&mirror);
    // A near-mirror wall concentrates each scene element on a few wall elements.
    let lit = |t: &Transport| {
        let c = t.col(4);
        let max = c.iter().cloned().fold(0.0, f64::max);
        c.iter().filter(|v| **v > 1e-2 * max).count()
    };
    let open = |s: String| s.replace("polarizer_deg = [0.0]", "polarizer_deg = []");
    let (t, _) = survives(&crossed3(|s| {
        open(s).replace("roughness = 0.3", "roughness = 0.01")
    }));
    let (glossy, _) = survives(&crossed3(open));
    assert!(
        lit(&t) * 4 < lit(&glossy),
        "lit elements {} vs {}",
        lit(&t),
        lit(&glossy)
    );
    let diffuse = crossed3(|s| {
        s.replace("roughness = 0.3", "roughness = 1.0")
            .replace("kd = 0.0", "kd = 1.0")
    });
    let (_, kappa_d) = survives(&diffuse);
    assert!(
        kappa_d > kappa,
        "a diffuse wall must be worse conditioned: {kappa_d} vs {kappa}"
    );
}

#[test]
fn grazing_camera() {
    let s = crossed3(|s| s.replace("camera = [0.416, 0.0, 0.277]", "camera = [2.0, 0.0, 0.002]"));
    survives(&s);
}

#[test]
fn rank_deficient_transport() {
    // Two identical poses, and a 3x3 scene shrunk to a point: nine identical columns.
    let s = crossed3(|s| {
        let pose = "[[pose]]\nname = \"A2\"\ncamera = [0.416, 0.0, 0.277]\npolarizer_deg = [0.0]\n";
        format!(
            "{}\n{pose}",
            s.replace("size = [0.2, 0.2]", "size = [1e-20, 1e-20]")
        )
    });
    let (t, kappa) = survives(&s);
    assert!(kappa.is_infinite(), "kappa {kappa}");
    let c = condition(&t).unwrap();
    assert_eq!(c.rank, 1);
    let i = t.apply(&[0.5; 9]);
    let lsq = least_squares(&t, &i, None).unwrap();
    assert_eq!(lsq.stats.rank, Some(1));
    assert!(lsq.stats.warnings.iter().any(|w| w.contains("rank 1")));
    // Unregularized normal equations cannot be factorized: a clear error.
    match tikhonov(&t, &i, Some(0.0)) {
        Err(SolveError::Factorization(m)) => assert!(
            m.contains("raise lambda") && m.contains("\"lambda\" / \"solver\" in a request"),
            "{m}"
        ),
        Ok(r) => assert!(all_finite(&r.image)),
        Err(e) => panic!("unexpected error {e}"),
    }
}

#[test]
fn fewer_rows_than_columns_is_infinitely_ill_conditioned() {
    let s = crossed3(|s| s.replace("grid = [32, 32]", "grid = [2, 2]"));
    let t = build(&s, MemoryBudget::DEFAULT).unwrap();
    assert_eq!((t.rows(), t.cols()), (4, 9));
    assert!(condition(&t).unwrap().kappa.is_infinite());
    survives(&s);
}

#[test]
fn bad_measurements_are_clear_errors() {
    let t = build(&crossed3(|s| s), MemoryBudget::DEFAULT).unwrap();
    let mut i = t.apply(&[0.3; 9]);
    let e = admm_tv(&t, &i[..100], &AdmmSettings::default()).unwrap_err();
    assert!(
        matches!(
            e,
            SolveError::Length {
                expected: 1024,
                got: 100
            }
        ),
        "{e}"
    );
    i[17] = f64::NAN;
    for e in [
        admm_tv(&t, &i, &AdmmSettings::default()).unwrap_err(),
        least_squares(&t, &i, None).unwrap_err(),
        tikhonov(&t, &i, None).unwrap_err(),
    ] {
        assert!(matches!(e, SolveError::NonFinite { index: 17, .. }), "{e}");
    }
    i[17] = 0.0;
    let e = admm_tv(
        &t,
        &i,
        &AdmmSettings {
            rho: Some(-1.0),
            ..Default::default()
        },
    )
    .unwrap_err();
    assert_eq!(e.to_string(), "rho = -1: must be a finite number > 0");
    let e = admm_tv(
        &t,
        &i,
        &AdmmSettings {
            lambda: Some(f64::INFINITY),
            ..Default::default()
        },
    )
    .unwrap_err();
    assert!(e.to_string().starts_with("lambda = inf"));
}

#[test]
fn lambda_zero_is_box_constrained_least_squares() {
    let t = build(&crossed3(|s| s), MemoryBudget::DEFAULT).unwrap();
    let truth = Pattern::Letter.render(t.scene_grid());
    let i = t.apply(&truth);
    let r = admm_tv(
        &t,
        &i,
        &AdmmSettings {
            lambda: Some(0.0),
            max_iter: 5000,
            tol: 1e-6,
            ..Default::default()
        },
    )
    .unwrap();
    assert!(r.stats.warnings.iter().any(|w| w.contains("lambda = 0")));
    assert!(all_finite(&r.image));
    // Noiseless data, well-conditioned 3x3 T: the exact scene comes back.
    let err = truth
        .iter()
        .zip(&r.image)
        .map(|(a, b)| (a - b).abs())
        .fold(0.0, f64::max);
    assert!(err < 1e-3, "max error {err}");
}

#[test]
fn an_iteration_cap_is_reported_not_hidden() {
    let t = build(&crossed3(|s| s), MemoryBudget::DEFAULT).unwrap();
    let i = t.apply(&Pattern::Bars.render(t.scene_grid()));
    let r = admm_tv(
        &t,
        &i,
        &AdmmSettings {
            max_iter: 2,
            tol: 1e-12,
            ..Default::default()
        },
    )
    .unwrap();
    assert!(!r.stats.converged);
    assert_eq!(r.stats.iterations, 2);
    assert!(
        r.stats.warnings[0].contains("iteration cap"),
        "{:?}",
        r.stats.warnings
    );
}
