//! What cannot be reconstructed is refused before the bench is used, and a
//! result says what it is worth (issue 47, items 5 and 6): real HTTP on
//! 127.0.0.1, the real catalogue, Aravis's fake camera.

use std::path::{Path, PathBuf};
use std::time::Duration;

use crate::daemon::common::{config, lock, scratch, Daemon};

/// The built-in crossed bench with `edits`, written as `<name>.toml` in `dir`.
fn crossed(dir: &Path, name: &str, edits: &[(&str, &str)]) -> PathBuf {
    let mut text = polnlos::scene::builtin::text("brewster-crossed")
        .unwrap()
        .to_string();
    for (from, to) in edits {
        assert!(text.contains(from), "{from}");
        text = text.replacen(from, to, 1);
    }
    let path = dir.join(format!("{name}.toml"));
    std::fs::write(&path, text).unwrap();
    path
}

/// A daemon on Aravis's fake camera that also knows these scene files.
fn daemon_with(dir: &Path, scenes: &[PathBuf]) -> Daemon {
    let files: Vec<String> = scenes
        .iter()
        .map(|p| format!("{:?}", p.display().to_string()))
        .collect();
    let listed = format!("scene_files = [{}]", files.join(", "));
    let cfg = config(dir, &[("scene_files = []", &listed)]);
    Daemon::start(&cfg, &dir.join("data"))
}

#[test]
fn a_capture_or_plan_that_could_not_be_reconstructed_is_refused_naming_the_fix() {
    let _g = lock();
    let dir = scratch();
    let chair = Path::new(env!("CARGO_MANIFEST_DIR")).join("config/photos/saunders-chair.toml");
    // Shifted 200 px right, pose A's wall leaves the 512 px frame; "free"
    // names no frame, so only the wall's place in the region counts.
    let shifted = crossed(
        dir.path(),
        "shifted",
        &[
            ("region = [0, 0, 512, 512]", ""),
            (
                "[-425.517945, 1220.52494, 255.5]",
                "[-758.604399, 1220.52494, 455.5]",
            ),
        ],
    );
    let free = crossed(dir.path(), "free", &[("region = [0, 0, 512, 512]", "")]);
    let d = daemon_with(dir.path(), &[chair, shifted, free]);
    let refused = |path: &str, body: &str| {
        let (s, b, _) = d.post(path, body);
        assert_eq!(s, 422, "{path} {body}: {b}");
        let v: serde_json::Value = serde_json::from_str(&b).unwrap();
        v["detail"].as_str().unwrap().to_string()
    };
    // A pose with no homography: the capture and the plan, naming the route
    // that fits one (not the wall's BRDF fit).
    let photo = r#"{"scene": "saunders-chair", "pose": "photo", "exposure_us": 20000}"#;
    for m in [
        refused("/captures", photo),
        refused(
            "/plans",
            r#"{"scene": "saunders-chair", "exposure_us": 20000, "frames": 1}"#,
        ),
    ] {
        assert!(
            m.contains("pose \"photo\" of scene \"saunders-chair\" has no homography"),
            "{m}"
        );
        assert!(
            m.contains("POST /calibrations,") && !m.contains("/calibrations/wall"),
            "{m}"
        );
    }
    // The wall view says the same route.
    let wall = d.json("/scenes/saunders-chair/wall");
    let why = wall[0]["why"].as_str().unwrap();
    assert!(
        why.contains("POST /calibrations,") && !why.contains("/calibrations/wall"),
        "{wall}"
    );
    // The target capture that finds the homography stays allowed.
    let target = d.run_job(
        "/captures",
        r#"{"scene": "saunders-chair", "pose": "photo", "kind": "target", "exposure_us": 20000}"#,
        Duration::from_secs(30),
    );
    assert_eq!(target["state"], "done", "{target}");
    // A wall partly off the frame: through the pose's homography, or
    // through the capture's region on the 2048 px sensor.
    for m in [
        refused(
            "/captures",
            r#"{"scene": "shifted", "pose": "A", "polarizer_deg": 0, "exposure_us": 20000}"#,
        ),
        refused(
            "/plans",
            r#"{"scene": "shifted", "exposure_us": 20000, "frames": 1}"#,
        ),
    ] {
        assert!(m.contains("imaged partly outside the frame"), "{m}");
        assert!(m.contains("GET /scenes/shifted/wall"), "{m}");
    }
    let m = refused(
        "/captures",
        r#"{"scene": "free", "pose": "A", "polarizer_deg": 0, "exposure_us": 20000, "region": [0, 0, 256, 256]}"#,
    );
    assert!(
        m.contains("region = [0, 0, 256, 256]") && m.contains("partly outside"),
        "{m}"
    );
    // A region other than the frame the pose's homography maps into.
    let m = refused(
        "/captures",
        r#"{"scene": "brewster-crossed", "pose": "A", "polarizer_deg": 0, "exposure_us": 20000, "region": [0, 0, 256, 256]}"#,
    );
    assert!(
        m.contains("maps the wall into region [0, 0, 512, 512]"),
        "{m}"
    );
    // An unknown pose, with the scene's poses.
    let m = refused(
        "/captures",
        r#"{"scene": "brewster-crossed", "pose": "Z", "polarizer_deg": 0, "exposure_us": 20000}"#,
    );
    assert!(m.contains("has no pose \"Z\"; its poses: A"), "{m}");
    // Nothing refused reached the bench or the catalogue.
    assert_eq!(d.json("/plans").as_array().map(Vec::len), Some(0));
    let captures = d.json("/captures");
    assert_eq!(captures.as_array().map(Vec::len), Some(1), "{captures}");
    // The same wall in the frame is accepted.
    let ok = d.run_job(
        "/captures",
        r#"{"scene": "free", "pose": "A", "polarizer_deg": 0, "exposure_us": 20000}"#,
        Duration::from_secs(30),
    );
    assert_eq!(ok["state"], "done", "{ok}");
}

#[test]
fn a_reconstruction_says_what_its_captures_lost_and_fails_when_no_element_was_measured() {
    let _g = lock();
    let dir = scratch();
    let d = daemon_with(dir.path(), &[]);
    let long = Duration::from_secs(60);
    let crossed = |extra: &str| {
        let c = d.run_job(
            "/captures",
            &format!(r#"{{"scene": "brewster-crossed", "pose": "A", "polarizer_deg": 0{extra}}}"#),
            long,
        );
        assert_eq!(c["state"], "done", "{c}");
        c["id"].as_i64().unwrap()
    };
    // A capture that lost frames on the link: its record counts them (set
    // here in the catalogue, as a lossy link would have).
    let lossy = crossed(r#", "exposure_us": 20000, "frames": 5, "dark_frames": 1"#);
    let db = rusqlite::Connection::open(dir.path().join("data/catalogue.sqlite")).unwrap();
    let lose = |id: i64| {
        db.execute(
            "UPDATE captures SET frame_counts = ?2 WHERE id = ?1",
            rusqlite::params![id, r#"{"received": 5, "dropped": 0, "broken": 4}"#],
        )
        .unwrap();
    };
    lose(lossy);
    let c = d.json(&format!("/captures/{lossy}"));
    assert_eq!(c["frame_counts"]["broken"], 4, "{c}");
    assert_eq!(c["frames_taken"], 6, "{c}");
    let said = "lost 4 frames (0 dropped, 4 broken) besides the 5 received whole";
    let r = d.run_job(
        "/reconstructions",
        &format!(r#"{{"scene": "brewster-crossed", "captures": [{lossy}], "truth": "letter"}}"#),
        long,
    );
    assert_eq!(r["state"], "done", "{r}");
    let warnings = r["report"]["warnings"].to_string();
    assert!(
        warnings.contains(&format!("capture {lossy} {said}")),
        "{warnings}"
    );
    // Every pixel saturated (4 s at the demo's 20 ms reference: 200 times
    // its dark level's 1 % of full scale): no element is measured, and the
    // reconstruction fails naming the capture, its saturation and its losses,
    // instead of a "done" on an all-zero T.
    let blind = crossed(r#", "exposure_us": 4000000, "frames": 1"#);
    let c = d.json(&format!("/captures/{blind}"));
    assert_eq!(c["clipping"]["saturated"], c["clipping"]["pixels"], "{c}");
    lose(blind);
    let r = d.run_job(
        "/reconstructions",
        &format!(r#"{{"scene": "brewster-crossed", "captures": [{blind}]}}"#),
        long,
    );
    assert_eq!(r["state"], "failed", "{r}");
    let error = r["error"].as_str().unwrap();
    assert!(error.starts_with("no wall element was measured"), "{error}");
    assert!(
        error.contains(&format!(
            "capture {blind} saturated: 262144 of 262144 pixels at full scale"
        )),
        "{error}"
    );
    assert!(error.contains(&format!("; it {said}")), "{error}");
}
