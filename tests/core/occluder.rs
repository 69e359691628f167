//! `calibrate occluder` (docs/realphoto.md, "Placing the occluders"): the
//! CLI's refusals of bad input, the fit on a simulated chair photo, and (a
//! study, `--ignored`) on the real one.

use std::path::PathBuf;
use std::process::Command;

use polnlos::files::npy;

fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

/// Bad input is refused before any `T` is built, naming what is wrong.
#[test]
fn calibrate_occluder_refuses_a_bad_selection_and_a_photo_of_another_scene() {
    crate::priority::background();
    let scene = root().join("config/photos/saunders-chair.toml");
    let photo = root().join("tests/data/saunders-chair/measurement.npy");
    let run = |args: &[&str]| {
        Command::new(env!("CARGO_BIN_EXE_polnlos"))
            .args(["calibrate", "occluder"])
            .args(args)
            .output()
            .unwrap()
    };
    let (s, p) = (scene.to_str().unwrap(), photo.to_str().unwrap());
    let out = run(&[s, "--measurement", p, "--occluder", "0,3-12"]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{err}");
    assert!(
        err.contains("occluder 12 is not in the scene, which has 12"),
        "{err}"
    );
    let out = run(&[s, "--measurement", p, "--range", "0"]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{err}");
    assert!(err.contains("range = 0"), "{err}");
    let out = run(&[s, "--measurement", p, "--occluder", "3-x"]);
    assert_eq!(out.status.code(), Some(2));
    let dir = tempfile::tempdir().unwrap();
    let short = dir.path().join("short.npy");
    npy::write_f64(&short, &[100], &[1.0; 100]).unwrap();
    let out = run(&[s, "--measurement", short.to_str().unwrap()]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(3), "{err}");
    assert!(err.contains("short.npy") && err.contains("15876"), "{err}");
}

/// A simulated chair photo on a coarser wall: the scene's light through the
/// chair (point shadows of 36 sources a block, the data the fit does not
/// make: it builds area shadows of one cell a block), with a gain, a
/// background and noise. Started 2 cm off, the fit comes back to the chair.
#[test]
fn calibrate_occluder_finds_the_chair_of_a_simulated_photo_from_2_cm_off() {
    crate::priority::background();
    use polnlos::calibrate::occluder::{fit_occluder, moved, OccluderOptions};
    use polnlos::scene::{Scene, ShadowModel};
    use polnlos::transport::{build, MemoryBudget};

    let text = std::fs::read_to_string(root().join("config/photos/saunders-chair.toml")).unwrap();
    let text = text.replace("grid = [126, 126]", "grid = [42, 42]");
    let scene = Scene::from_toml_str(&text).unwrap();
    let all: Vec<usize> = (0..scene.occluders().len()).collect();
    let render = build(
        &moved(&scene, &all, [0.0; 3], 6, ShadowModel::Point).unwrap(),
        MemoryBudget::DEFAULT,
    )
    .unwrap();
    let channels: Vec<Vec<f64>> = super::photo::truth()
        .iter()
        .enumerate()
        .map(|(c, l)| super::photo::photo(&render, l, 2e8, 40.0, 1e-3, 11 + c as u64))
        .collect();
    let off = [0.0141, -0.0141, 0.0];
    let start = moved(&scene, &all, off, 2, ShadowModel::Point).unwrap();
    let f = fit_occluder(&start, &channels, &OccluderOptions::default()).unwrap();
    let end: Vec<f64> = (0..3).map(|a| off[a] + f.translation[a]).collect();
    let miss = end.iter().map(|x| x * x).sum::<f64>().sqrt();
    eprintln!(
        "ends {end:?} from the chair, {:.1} mm; {} builds, {:.1} s",
        miss * 1e3,
        f.builds,
        f.seconds
    );
    assert!(miss < 0.003, "{end:?}");
}

/// The chair photo: started with the chair 2 cm off its measured position
/// (`Occ_LLcorner_true`, along x), the fit places it within 1 cm.
///
/// A study, not in the suite: 31 `T` builds of the 126 x 126 wall take 48 s
/// on the idle 2-core machine (81 s of CPU), against the suite's 5-minute
/// budget (docs/test-times.md); the simulated chair above holds the same
/// search in 5 s. Run it with
/// `cargo test --locked --test suite -- --ignored --nocapture calibrate_occluder_places`.
#[test]
#[ignore]
fn calibrate_occluder_places_the_photo_s_chair_within_1_cm_from_2_cm_off() {
    crate::priority::background();
    use polnlos::calibrate::occluder::{fit_occluder, moved, OccluderOptions};
    use polnlos::scene::Scene;
    use polnlos::solve::photo::split_channels;

    let data = root().join("tests/data/saunders-chair");
    let geometry: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(data.join("geometry.json")).unwrap())
            .unwrap();
    let corner = |key: &str| -> Vec<f64> {
        let v = &geometry["occluder"][key];
        (0..3).map(|a| v[a].as_f64().unwrap()).collect()
    };
    let (truth, quads) = (
        corner("Occ_LLcorner_true"),
        corner("Occ_LLcorner_used_for_quads"),
    );
    let scene = Scene::load(&root().join("config/photos/saunders-chair.toml")).unwrap();
    let photo = npy::read(&data.join("measurement.npy")).unwrap();
    let channels = split_channels(&photo.shape, &photo.data, scene.rows()).unwrap();
    let all: Vec<usize> = (0..scene.occluders().len()).collect();
    // The quads' translation that puts the chair at its measured position.
    let at: Vec<f64> = (0..3).map(|a| truth[a] - quads[a]).collect();
    let off = [at[0] + 0.02, at[1], at[2]];
    let start = moved(&scene, &all, off, 2, scene.hidden().shadows).unwrap();
    let f = fit_occluder(&start, &channels, &OccluderOptions::default()).unwrap();
    let miss = (0..3)
        .map(|a| (off[a] + f.translation[a] - at[a]).powi(2))
        .sum::<f64>()
        .sqrt();
    eprintln!(
        "translation {:?}, {:.1} mm from the measured corner; {} builds, {:.1} s",
        f.translation,
        miss * 1e3,
        f.builds,
        f.seconds
    );
    assert!(miss < 0.01, "{miss}");
}
