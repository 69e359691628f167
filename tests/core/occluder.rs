//! `calibrate occluder` (docs/realphoto.md, "Placing the occluders"): the
//! CLI's refusals of bad input. The fit itself does not yet reach its goal
//! (1 cm on the chair photo), so no test holds it (docs/realphoto.md).

use std::path::PathBuf;
use std::process::Command;

use polnlos::files::npy;

fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

/// Bad input is refused before any `T` is built, naming what is wrong.
#[test]
fn calibrate_occluder_refuses_a_bad_selection_and_a_photo_of_another_scene() {
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
