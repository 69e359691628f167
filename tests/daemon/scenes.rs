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
        .find(|l| l.starts_with("homography = [[-613.055374"))
        .unwrap();
    assert!(text.contains(line_b), "{text}");
    // Written beside the original it loads, with the fitted homography.
    let beside = scenes.join("meshy-calibrated.toml");
    std::fs::write(&beside, text).unwrap();
    let s = Scene::load(&beside).unwrap();
    let fitted: [[f64; 3]; 3] = serde_json::from_value(cal["homography"].clone()).unwrap();
    // Within the last digit: serde_json's float parsing (without its
    // float_roundtrip feature) can land one ulp from the written number.
    let read = s.pose("C").unwrap().homography.unwrap().matrix();
    for (r, f) in read.iter().flatten().zip(fitted.iter().flatten()) {
        assert!(
            (r - f).abs() <= 1e-12 * f.abs().max(1.0),
            "{read:?} vs {fitted:?}"
        );
    }
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

/// The built-in crossed bench's file with a note of the user's, its
/// hidden scene `grid` cells a side.
fn crossed(grid: usize) -> String {
    let text = polnlos::scene::builtin::text("brewster-crossed").expect("built in");
    assert!(text.contains("grid = [8, 8]"));
    format!(
        "# posted over HTTP\n{}",
        text.replacen("grid = [8, 8]", &format!("grid = [{grid}, {grid}]"), 1)
    )
}

/// The shape in a `.npy` file's header (`(8, 8)`).
fn npy_shape(bytes: &[u8]) -> String {
    let header = String::from_utf8_lossy(&bytes[..bytes.len().min(128)]).into_owned();
    let at = header.find("'shape': ").expect("a shape") + "'shape': ".len();
    let shape = header[at..].split(')').next().unwrap_or_default();
    format!("{})", shape.trim_end_matches([',', ' ']))
}

#[test]
fn scenes_are_posted_replaced_and_deleted_without_a_restart() {
    let _g = lock();
    let dir = scratch();
    let files = dir.path().join("scenes");
    std::fs::create_dir_all(&files).unwrap();
    std::fs::write(files.join("good.toml"), crossed(8)).unwrap();
    std::fs::write(files.join("broken.toml"), "[wall]\ncenter = [0.0, 0.0\n").unwrap();
    let list = |names: &[&str]| {
        names
            .iter()
            .map(|n| format!("{:?}", files.join(n).to_str().unwrap()))
            .collect::<Vec<_>>()
            .join(", ")
    };
    let cfg = config(
        dir.path(),
        &[(
            "scene_files = []",
            &format!("scene_files = [{}]", list(&["good.toml", "broken.toml"])),
        )],
    );
    let d = Daemon::start(&cfg, &dir.path().join("data"));
    // The broken file is listed with its error; the others serve.
    let listed = d.json("/scenes");
    let entry = |l: &serde_json::Value, name: &str| {
        l.as_array()
            .unwrap()
            .iter()
            .find(|s| s["name"] == name)
            .cloned()
            .unwrap_or_default()
    };
    let broken = entry(&listed, "broken");
    assert_eq!(broken["origin"], "file", "{listed}");
    assert!(
        broken["error"].as_str().unwrap().contains("line 2"),
        "{listed}"
    );
    assert!(entry(&listed, "good")["error"].is_null(), "{listed}");
    let (s, b) = d.get("/scenes/broken/wall");
    assert_eq!(s, 404, "{b}");
    let (s, b) = d.get("/scenes/good/wall");
    assert_eq!(s, 200, "{b}");
    // A capture of another scene runs while a scene is posted.
    let (s, b, loc) = d.post(
        "/captures",
        r#"{"scene": "brewster-crossed", "pose": "A", "polarizer_deg": 0, "exposure_us": 20000, "frames": 16, "dark_frames": 2}"#,
    );
    assert_eq!(s, 202, "{b}");
    let (s, b) = d.send_toml("POST", "/scenes?name=posted", &crossed(8));
    assert_eq!(s, 201, "{b}");
    let (s, b) = d.send_toml("POST", "/scenes?name=posted", &crossed(8));
    assert_eq!(s, 409, "{b}");
    let (s, b) = d.send_toml("POST", "/scenes?name=bad", "[wall]\nsize = [0.3,\n");
    assert_eq!(s, 422, "{b}");
    assert!(b.contains("line 2"), "{b}");
    let (s, b, _) = d.post("/scenes?name=json", "{}");
    assert_eq!(s, 415, "{b}");
    let running = d.wait(&loc.unwrap(), Duration::from_secs(120));
    assert_eq!(running["state"], "done", "{running}");
    assert!(dir.path().join("data/scenes/posted.toml").exists());
    // The posted scene captures and reconstructs, no restart between.
    let c = d.run_job("/captures", r#"{"scene": "posted", "pose": "A", "polarizer_deg": 0, "exposure_us": 20000, "frames": 8, "dark_frames": 2}"#, Duration::from_secs(120));
    assert_eq!(c["state"], "done", "{c}");
    let reconstruct = |body: String| {
        let (s, b, loc) = d.post("/reconstructions", &body);
        assert_eq!(s, 202, "{b}");
        loc.unwrap()
    };
    let body = format!(
        r#"{{"scene": "posted", "captures": [{}], "truth": "letter"}}"#,
        c["id"]
    );
    let first = reconstruct(body.clone());
    // Once it runs (or is done), the scene is replaced: it keeps the old one.
    let t = std::time::Instant::now();
    while d.json(&first)["state"] == "queued" {
        assert!(t.elapsed() < Duration::from_secs(120), "never started");
        std::thread::sleep(Duration::from_millis(5));
    }
    let (s, b) = d.send_toml("PUT", "/scenes/posted", &crossed(4));
    assert_eq!(s, 200, "{b}");
    let old = d.wait(&first, Duration::from_secs(240));
    assert_eq!(old["state"], "done", "{old}");
    println!(
        "posted scene: PSNR {:.2} dB",
        crate::daemon::common::psnr(&old)
    );
    assert!(crate::daemon::common::psnr(&old) > 10.0, "{old}");
    let (_, npy) = d.get_bytes(&format!("{first}/recovered.npy"));
    assert_eq!(npy_shape(&npy), "(8, 8)");
    let new = d.wait(&reconstruct(body), Duration::from_secs(240));
    assert_eq!(new["state"], "done", "{new}");
    let (_, npy) = d.get_bytes(&format!("/reconstructions/{}/recovered.npy", new["id"]));
    assert_eq!(npy_shape(&npy), "(4, 4)");
    // DELETE: gone from the list and the data directory; a file's scene stays.
    let (s, b) = d.delete("/scenes/good");
    assert_eq!(s, 409, "{b}");
    let (s, b) = d.delete("/scenes/posted");
    assert_eq!(s, 204, "{b}");
    assert!(entry(&d.json("/scenes"), "posted").is_null());
    assert!(!dir.path().join("data/scenes/posted.toml").exists());
    let (s, b) = d.delete("/scenes/posted");
    assert_eq!(s, 404, "{b}");
}

#[test]
fn sighup_reads_the_scene_files_again() {
    let _g = lock();
    let dir = scratch();
    let files = dir.path().join("scenes");
    std::fs::create_dir_all(&files).unwrap();
    let file = files.join("edited.toml");
    std::fs::write(&file, "[wall]\n").unwrap();
    let cfg = config(
        dir.path(),
        &[(
            "scene_files = []",
            &format!("scene_files = [{:?}]", file.to_str().unwrap()),
        )],
    );
    let d = Daemon::start(&cfg, &dir.path().join("data"));
    let edited = |l: serde_json::Value| {
        l.as_array()
            .unwrap()
            .iter()
            .find(|s| s["name"] == "edited" && s["origin"] == "file")
            .cloned()
            .unwrap_or_default()
    };
    assert!(edited(d.json("/scenes"))["error"].is_string());
    std::fs::write(&file, crossed(8)).unwrap();
    let hup = std::process::Command::new("kill")
        .args(["-HUP", &d.pid().to_string()])
        .status()
        .unwrap();
    assert!(hup.success());
    let t = std::time::Instant::now();
    loop {
        let listed = d.json("/scenes");
        let entry = edited(listed.clone());
        if !entry.is_null() && entry["error"].is_null() {
            break;
        }
        assert!(
            t.elapsed() < Duration::from_secs(30),
            "not reloaded: {listed}"
        );
        std::thread::sleep(Duration::from_millis(50));
    }
    let (s, b) = d.get("/scenes/edited/wall");
    assert_eq!(s, 200, "{b}");
}
