//! Live reconstruction from the camera stream (issue 49): the daemon on
//! Aravis's fake camera repeats a capture request and reconstructs each new
//! window of frames, gives way to a queued capture and resumes, and stops on
//! `DELETE /live`. Real HTTP on 127.0.0.1, real Aravis.

use std::time::{Duration, Instant};

use serde_json::Value;

use crate::daemon::common::{config, lock, psnr, scratch, Daemon};

/// The crossed bench's capture of 8 frames of 20 ms (50 frames a second),
/// with 2 dark frames the fake bench takes with the scene switched off.
const CAPTURE: &str = r#"{"scene": "brewster-crossed", "pose": "A", "polarizer_deg": 0, "exposure_us": 20000, "frames": 8, "dark_frames": 2}"#;

/// The same request as a live view: windows of 8 frames, against the letter.
const LIVE: &str = r#"{"scene": "brewster-crossed", "pose": "A", "polarizer_deg": 0, "exposure_us": 20000, "frames": 8, "dark_frames": 2, "progressive": {"truth": "letter"}}"#;

/// A done capture's reconstruction against the letter.
fn reconstruct(d: &Daemon, capture: &Value) -> Value {
    let r = d.run_job(
        "/reconstructions",
        &format!(
            r#"{{"scene": "brewster-crossed", "captures": [{}], "truth": "letter"}}"#,
            capture["id"]
        ),
        Duration::from_secs(120),
    );
    assert_eq!(r["state"], "done", "{r}");
    r
}

/// Polls `GET /live` until `until` holds (within 30 s); the PSNR of every
/// newest result seen on the way.
fn watch(d: &Daemon, until: impl Fn(&Value) -> bool) -> (Value, Vec<f64>) {
    let t = Instant::now();
    let mut seen = Vec::new();
    loop {
        let v = d.json("/live");
        if let Some(p) = v["last"]["psnr_db"].as_f64() {
            seen.push(p);
        }
        if until(&v) {
            return (v, seen);
        }
        assert!(t.elapsed() < Duration::from_secs(30), "live view: {v}");
        std::thread::sleep(Duration::from_millis(100));
    }
}

#[test]
fn live_view_solves_each_window_as_a_capture_would_gives_way_to_a_capture_and_stops() {
    let _g = lock();
    let dir = scratch();
    let mut d = Daemon::start(&config(dir.path(), &[]), &dir.path().join("data"));
    assert_eq!(d.json("/live")["state"], "off");
    let (s, b) = d.get("/live/image.png");
    assert_eq!(s, 404, "{b}");
    // Refused, naming what is wrong: a window beyond 64 frames, a dark
    // capture, an unknown scene.
    for (body, status, says) in [
        (
            LIVE.replace(r#""frames": 8"#, r#""frames": 65"#),
            422,
            "a live window is 1 to 64",
        ),
        (
            LIVE.replace(r#""scene": "#, r#""kind": "dark", "scene": "#),
            422,
            "leave kind out",
        ),
        (
            LIVE.replace("brewster-crossed", "no-such-scene"),
            404,
            "no-such-scene",
        ),
    ] {
        let (s, b, _) = d.post("/live", &body);
        assert_eq!(s, status, "{body}: {b}");
        assert!(b.contains(says), "{b}");
    }
    assert_eq!(d.json("/live")["state"], "off");

    // A capture of the same frames without live view, as the reference.
    let before = d.run_job("/captures", CAPTURE, Duration::from_secs(60));
    assert_eq!(before["state"], "done", "{before}");
    let offline = psnr(&reconstruct(&d, &before));

    let (s, b, loc) = d.post("/live", LIVE);
    assert_eq!(s, 202, "{b}");
    assert_eq!(loc.as_deref(), Some("/live"));
    let (v, seen) = watch(&d, |v| v["results"].as_u64().unwrap_or(0) >= 40);
    println!("live view after 40 results: {v}");
    assert_eq!(v["state"], "running", "{v}");
    assert_eq!(v["window"], 8);
    // Measured, not bounded (timings are the benchmarks'; the issue note
    // records them): 44 results a second, median latency 14 ms (10.5-11.9
    // and 68-80 ms while every window searched its λ).
    let rate = v["results_per_second"].as_f64().expect("a rate");
    let latency = v["median_latency_ms"].as_f64().expect("a latency");
    assert!(rate > 0.0 && latency > 0.0, "{v}");
    assert_eq!(v["last"]["frames"], 8, "each result solves a full window");
    // Each result is as good as the reconstruction of a capture of as many
    // frames (another 8, so its own noise): the median no more than 0.5 dB
    // below it (measured 0.1-0.4 dB above).
    assert!(!seen.is_empty());
    println!("live PSNR seen {seen:.2?}, offline {offline:.2}");
    let mut sorted = seen.clone();
    sorted.sort_by(f64::total_cmp);
    let median = sorted[sorted.len() / 2];
    assert!(
        median >= offline - 0.5,
        "live median {median:.2} dB, offline {offline:.2} dB"
    );
    println!(
        "{} results a second, median latency {latency:.1} ms; PSNR live {:.2}-{:.2} dB, offline {offline:.2} dB",
        rate,
        seen.iter().copied().fold(f64::INFINITY, f64::min),
        seen.iter().copied().fold(0.0, f64::max)
    );
    let (s, png) = d.get_bytes("/live/image.png");
    assert_eq!(s, 200);
    assert_eq!(&png[1..4], b"PNG");
    let size = |at: usize| u32::from_be_bytes([png[at], png[at + 1], png[at + 2], png[at + 3]]);
    assert_eq!((size(16), size(20)), (8, 8), "the scene grid");

    // A capture queued during live view takes the camera, gets every frame
    // and the same result; live view resumes after it.
    let results = v["results"].as_u64().unwrap();
    let during = d.run_job("/captures", CAPTURE, Duration::from_secs(60));
    assert_eq!(during["state"], "done", "{during}");
    assert_eq!(during["frame_counts"]["received"], 10, "{during}");
    // Its PSNR within the spread of same-length windows (the live results
    // and the capture before; one session spanned 14.11-14.75 dB), widened
    // by 0.5 dB: two single 8-frame captures once differed by 0.95 dB.
    let online = psnr(&reconstruct(&d, &during));
    let lo = seen.iter().copied().fold(offline, f64::min) - 0.5;
    let hi = seen.iter().copied().fold(offline, f64::max) + 0.5;
    assert!(
        (lo..=hi).contains(&online),
        "capture during live view {online:.2} dB, outside {lo:.2}-{hi:.2} dB (without live view {offline:.2} dB)"
    );
    let (v, _) = watch(&d, |v| {
        v["state"] == "running" && v["results"].as_u64().unwrap_or(0) >= results + 10
    });
    assert_eq!(v["session"], 1, "{v}");

    // Stopped: off, and the camera free for a settings change at once.
    let (s, b) = d.delete("/live");
    assert_eq!(s, 200, "{b}");
    let stopped: Value = serde_json::from_str(&b).unwrap();
    assert_eq!(stopped["state"], "off");
    assert!(stopped["results"].as_u64().unwrap() >= results + 10);
    let t = Instant::now();
    loop {
        let (s, b) = d.put("/camera/settings", r#"{"exposure_us": 10000}"#);
        if s == 200 {
            break;
        }
        assert_eq!(s, 409, "{b}");
        assert!(
            t.elapsed() < Duration::from_secs(5),
            "camera still busy: {b}"
        );
        std::thread::sleep(Duration::from_millis(50));
    }
    assert_eq!(d.json("/live")["state"], "off");

    // SIGTERM while a live session streams: the daemon stops it and exits
    // cleanly and promptly (systemd's `stop`).
    let (s, b, _) = d.post("/live", LIVE);
    assert_eq!(s, 202, "{b}");
    watch(&d, |v| v["results"].as_u64().unwrap_or(0) >= 3);
    let t = Instant::now();
    let status = d.terminate();
    let took = t.elapsed();
    assert!(status.success(), "{status:?}");
    assert!(took < Duration::from_secs(10), "exit took {took:?}");
}

/// Issue 49: live view of a chair-size scene (a 126 x 126 wall, a 36 x 29
/// scene, a colour camera's three colours) on the fake Bayer bench: each
/// window solved in colour, its λ searched once and kept while the noise
/// stays the same. The rate and latency are printed, not bounded (measured
/// 2.07-2.11 results a second, median latency 445-470 ms, with the fake
/// camera's frame rendering on the same two cores; 0.16 a second while
/// every window searched its λ).
#[test]
fn live_view_of_a_chair_size_colour_scene() {
    let _g = lock();
    let dir = scratch();
    let text = std::fs::read_to_string(
        std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("config/scenes/brewster-crossed.toml"),
    )
    .unwrap()
    .replacen("grid = [32, 32]", "grid = [126, 126]", 1)
    .replacen("grid = [8, 8]", "grid = [36, 29]", 1);
    let file = dir.path().join("chair-size.toml");
    std::fs::write(&file, text).unwrap();
    let listed = format!("scene_files = [{:?}]", file.display().to_string());
    let cfg = config(
        dir.path(),
        &[
            ("scene_files = []", &listed),
            ("fake_sensor = \"mono\"", "fake_sensor = \"bayer\""),
            ("scene = \"brewster-crossed\"", "scene = \"chair-size\""),
        ],
    );
    let d = Daemon::start(&cfg, &dir.path().join("data"));
    let live = LIVE.replace("brewster-crossed", "chair-size");
    let (s, b, _) = d.post("/live", &live);
    assert_eq!(s, 202, "{b}");
    let (v, seen) = watch(&d, |v| v["results"].as_u64().unwrap_or(0) >= 12);
    assert_eq!(v["state"], "running", "{v}");
    let rate = v["results_per_second"].as_f64().expect("a rate");
    let latency = v["median_latency_ms"].as_f64().expect("a latency");
    println!(
        "chair-size live view: {rate:.2} results a second, median latency {latency:.0} ms, PSNR {:.2}-{:.2} dB",
        seen.iter().copied().fold(f64::INFINITY, f64::min),
        seen.iter().copied().fold(0.0, f64::max)
    );
    assert!(rate > 0.0 && latency > 0.0, "{v}");
    assert_eq!(v["last"]["frames"], 8, "each result solves a full window");
    // The letter, not noise: every result well above a flat image's PSNR.
    assert!(seen.iter().all(|p| *p > 9.0), "{seen:?}");
    let (s, png) = d.get_bytes("/live/image.png");
    assert_eq!(s, 200);
    let size = |at: usize| u32::from_be_bytes([png[at], png[at + 1], png[at + 2], png[at + 3]]);
    assert_eq!((size(16), size(20)), (36, 29), "the scene grid");
    assert_eq!(png[25], 2, "an RGB image");
    let (s, b) = d.delete("/live");
    assert_eq!(s, 200, "{b}");
}
