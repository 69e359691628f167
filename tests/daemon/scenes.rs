//! Scenes through the daemon: a scene file with a relative mesh path
//! calibrated over HTTP, written back as the user wrote it. Real HTTP on
//! 127.0.0.1, the real binary, Aravis's fake camera.

use std::path::Path;
use std::time::Duration;

use polnlos::scene::Scene;

use crate::daemon::common::{config, lock, scratch, Daemon};

/// A small triangle between the hidden scene and the wall of the bench.
const MESH: &str = "v -0.2 0 0.15\nv -0.19 0 0.15\nv -0.2 0.01 0.15\nf 1 2 3\n";

/// The built-in `brewster-multi` bench as a file `meshy.toml` in `dir`
/// with a comment of the user's and an occluder whose mesh `box.obj` lies
/// beside it (a relative path, as docs/guide.md writes one).
fn meshy_scene(dir: &Path) -> std::path::PathBuf {
    let text = format!(
        "# the user's own note, kept\n{}\n[[occluder]]\nmesh = \"box.obj\"  # beside this file\n",
        polnlos::scene::builtin::text("brewster-multi").expect("built in")
    );
    std::fs::create_dir_all(dir).unwrap();
    std::fs::write(dir.join("box.obj"), MESH).unwrap();
    let path = dir.join("meshy.toml");
    std::fs::write(&path, text).unwrap();
    path
}

#[test]
fn a_scene_with_a_relative_mesh_calibrates_its_pose_and_keeps_its_text() {
    let _g = lock();
    let dir = scratch();
    let scenes = dir.path().join("scenes");
    let file = meshy_scene(&scenes);
    let cfg = config(
        dir.path(),
        &[(
            "scene_files = []",
            &format!("scene_files = [{:?}]", file.to_str().unwrap()),
        )],
    );
    let d = Daemon::start(&cfg, &dir.path().join("data"));
    let c = d.run_job("/captures", r#"{"kind": "target", "scene": "meshy", "pose": "C", "polarizer_deg": 0, "exposure_us": 20000, "frames": 4, "dark_frames": 2}"#, Duration::from_secs(60));
    assert_eq!(c["state"], "done", "{c}");
    let (s, b, _) = d.post("/calibrations", &format!(r#"{{"capture": {}}}"#, c["id"]));
    assert_eq!(s, 200, "{b}");
    let cal: serde_json::Value = serde_json::from_str(&b).unwrap();
    let text = cal["scene_toml"].as_str().unwrap();
    // The user's file as written: comments, the mesh path, the tables' order.
    assert!(text.starts_with("# the user's own note, kept\n"), "{text}");
    assert!(
        text.contains("mesh = \"box.obj\"  # beside this file"),
        "{text}"
    );
    assert!(text.contains("# wall (u,v) m -> 512x512 pixels"), "{text}");
    assert!(text.find("[wall]") < text.find("[scene]"), "{text}");
    // Only the fitted values changed: pose B's line is as it was.
    let original = std::fs::read_to_string(&file).unwrap();
    let line_b = original
        .lines()
        .find(|l| l.starts_with("homography = [[-224.312174"))
        .unwrap();
    assert!(text.contains(line_b), "{text}");
    // Written beside the original it loads, with the fitted homography.
    let beside = scenes.join("meshy-calibrated.toml");
    std::fs::write(&beside, text).unwrap();
    let s = Scene::load(&beside).unwrap();
    let fitted: [[f64; 3]; 3] = serde_json::from_value(cal["homography"].clone()).unwrap();
    assert_eq!(s.pose("C").unwrap().homography.unwrap().matrix(), fitted);
    assert_eq!(s.occluders().len(), 1);
}

#[test]
fn an_uncalibrated_colour_capture_is_not_warned_about_its_orientation() {
    let _g = lock();
    let dir = scratch();
    let cfg = config(
        dir.path(),
        &[("fake_sensor = \"mono\"", "fake_sensor = \"bayer\"")],
    );
    let d = Daemon::start(&cfg, &dir.path().join("data"));
    let c = d.run_job("/captures", r#"{"scene": "brewster-crossed", "pose": "A", "polarizer_deg": 0, "exposure_us": 20000, "frames": 4, "dark_frames": 2}"#, Duration::from_secs(240));
    assert_eq!(c["state"], "done", "{c}");
    let r = d.run_job(
        "/reconstructions",
        &format!(
            r#"{{"scene": "brewster-crossed", "captures": [{}], "truth": "letter"}}"#,
            c["id"]
        ),
        Duration::from_secs(240),
    );
    assert_eq!(r["state"], "done", "{r}");
    assert_eq!(r["report"]["radiometry"]["mode"], "fitted", "{r}");
    // Its rows are in the order the pose's homography fixed: no check, no warning.
    assert!(r["report"]["orientation"].is_null(), "{r}");
    let warnings = r["report"]["warnings"].as_array().unwrap();
    assert!(
        warnings
            .iter()
            .all(|w| !w.as_str().unwrap().contains("fits T better")),
        "{warnings:?}"
    );
}
