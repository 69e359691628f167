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

    // A mount sweep (`POST /mount/zero`) takes the camera at live view's
    // next frame: live view says it is paused by the sweep meanwhile (it
    // gives the camera back when its stream stops, before the window in
    // hand is solved: schemathesis once saw the sweep's 5 s wait run out
    // while live view held the camera through a solve, under a whole
    // suite's load), and runs again after it.
    let before_sweep = v["results"].as_u64().unwrap();
    let paused = std::thread::scope(|scope| {
        let sweep = scope.spawn(|| {
            d.post(
                "/mount/zero",
                r#"{"scene": "brewster-crossed", "pose": "A"}"#,
            )
        });
        let (paused, _) = watch(&d, |v| v["state"] == "paused");
        let (s, b, _) = sweep.join().unwrap();
        assert_eq!(s, 200, "{b}");
        paused
    });
    assert_eq!(paused["paused_by"], "a mount sweep", "{paused}");
    let (v, _) = watch(&d, |v| {
        v["state"] == "running" && v["results"].as_u64().unwrap_or(0) >= before_sweep + 3
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

/// The live request recording its first `n` frames.
fn recording(n: usize) -> String {
    LIVE.replace(
        r#""progressive""#,
        &format!(r#""record": {{"frames": {n}}}, "progressive""#),
    )
}

/// Polls `GET /captures/{id}` until it is no longer queued or running (within 30 s).
fn ended_capture(d: &Daemon, id: &Value) -> Value {
    let t = Instant::now();
    loop {
        let c = d.json(&format!("/captures/{id}"));
        if c["state"] != "queued" && c["state"] != "running" {
            return c;
        }
        assert!(t.elapsed() < Duration::from_secs(30), "capture: {c}");
        std::thread::sleep(Duration::from_millis(50));
    }
}

/// The frame id and arrival time (Unix ns) of every page of a capture's raw frames.
fn pages(d: &Daemon, id: &Value) -> Vec<(u64, u64)> {
    let (s, tiff) = d.get_bytes(&format!("/captures/{id}/frame.tiff"));
    assert_eq!(s, 200);
    let mut dec = tiff::decoder::Decoder::new(std::io::Cursor::new(tiff)).unwrap();
    let mut out = Vec::new();
    loop {
        let desc = dec
            .get_tag_ascii_string(tiff::tags::Tag::ImageDescription)
            .unwrap();
        let v: Value = serde_json::from_str(&desc).unwrap();
        let n = |k: &str| v[k].as_u64().unwrap_or_else(|| panic!("{k}: {v}"));
        out.push((n("frame_id"), n("system_timestamp_ns")));
        if !dec.more_images() {
            return out;
        }
        dec.next_image().unwrap();
    }
}

/// Nanoseconds since the Unix epoch, now.
fn unix_ns() -> u64 {
    let d = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .unwrap();
    u64::try_from(d.as_nanos()).unwrap()
}

/// Issue 49, item 4: `record` writes the first 16 frames of a live session
/// (after its 2 dark frames) to a new capture while live view runs on; the
/// capture holds those frames (consecutive ids, arrived within the
/// session) and reconstructs as well as the session's windows do. The
/// recording's field is checked first (422s naming it).
#[test]
fn live_view_records_its_first_frames_as_a_capture_that_reconstructs_like_its_windows() {
    let _g = lock();
    let dir = scratch();
    let d = Daemon::start(&config(dir.path(), &[]), &dir.path().join("data"));
    for (record, says) in [
        (
            r#"{"frames": 0}"#,
            "record.frames = 0: a recording is 1 to 998 frames",
        ),
        (
            r#"{"frames": 999}"#,
            "record.frames = 999: a recording is 1 to 998",
        ),
        (r#"{"frames": -1}"#, "record.frames: -1 is negative"),
        (r#"{"frames": 1.5}"#, "record.frames: invalid value"),
        (r#"{}"#, "record: missing field `frames`"),
        (r#"{"frames": 4, "n": 1}"#, "record.n: unknown field `n`"),
    ] {
        let body = LIVE.replace(
            r#""progressive""#,
            &format!(r#""record": {record}, "progressive""#),
        );
        d.refused("/live", &body, says);
    }
    d.refused(
        "/captures",
        &CAPTURE.replace('}', r#", "record": {"frames": 4}}"#),
        "record is live view's (POST /live)",
    );
    assert_eq!(d.json("/captures"), serde_json::json!([]), "nothing stored");
    assert_eq!(d.json("/live")["state"], "off");
    // Documented: the body's field, its count, and what GET /live and a capture show of it.
    let spec = d.json("/openapi.json");
    let schemas = &spec["components"]["schemas"];
    let described = |schema: &str, field: &str| {
        let text = schemas[schema].to_string();
        assert!(
            text.contains(&format!("\"{field}\"")),
            "{schema}.{field}: {text}"
        );
    };
    described("CaptureBody", "record");
    described("RecordBody", "frames");
    described("LiveView", "recording");
    described("RecordingView", "capture");
    described("CaptureRecord", "live");
    described("LiveInfo", "frames_asked");

    let posted = unix_ns();
    let t = Instant::now();
    let (s, b, _) = d.post("/live", &recording(16));
    assert_eq!(s, 202, "{b}");
    let started: Value = serde_json::from_str(&b).unwrap();
    let id = started["recording"]["capture"].clone();
    assert!(id.is_i64(), "{started}");
    assert_eq!(started["recording"]["of"], 16, "{started}");
    assert_eq!(started["recording"]["state"], "waiting", "{started}");
    let (v, seen) = watch(&d, |v| v["recording"]["state"] == "done");
    let took = t.elapsed();
    let done = unix_ns();
    assert_eq!(v["state"], "running", "{v}");
    assert_eq!(v["recording"]["frames"], 16, "{v}");
    assert!(v["frames"].as_u64().unwrap() >= 16, "{v}");
    let c = d.json(&format!("/captures/{id}"));
    println!("recording done {took:?} after POST /live: {c}");
    assert_eq!(c["state"], "done", "{c}");
    assert_eq!(
        (c["kind"].as_str(), c["frames"].as_i64()),
        (Some("light"), Some(16)),
        "{c}"
    );
    assert_eq!(c["dark_frames"], 2, "{c}");
    assert_eq!(c["frames_taken"], 18, "{c}");
    assert_eq!(c["frame_counts"]["received"], 18, "{c}");
    assert_eq!(c["frame_counts"]["dropped"], 0, "{c}");
    assert_eq!(c["exposure_us"], 20000.0, "{c}");
    assert_eq!(c["live"]["session"], started["session"], "{c}");
    assert_eq!(c["live"]["frames_asked"], 16, "{c}");
    assert!(c["live"].get("ended").is_none(), "{c}");
    // Its frames are 16 of the session's stream, in order, none missing.
    let p = pages(&d, &id);
    assert_eq!(p.len(), 16);
    let next = |w: &[(u64, u64)]| polnlos::camera::frames_between(w[0].0, w[1].0) == Some(0);
    assert!(p.windows(2).all(next), "{p:?}");
    assert!(
        p.iter().all(|&(_, ns)| (posted..=done).contains(&ns)),
        "{p:?}"
    );
    let listed = d.json("/captures");
    assert!(
        listed.as_array().unwrap().iter().any(|l| l["id"] == id),
        "{listed}"
    );

    // Live view ran on while it recorded, and after.
    let results = v["results"].as_u64().unwrap();
    let (v, more) = watch(&d, |v| v["results"].as_u64().unwrap_or(0) >= results + 20);
    assert_eq!(v["state"], "running", "{v}");
    assert_eq!(v["recording"]["state"], "done", "{v}");
    // The recording reconstructs like any capture, as well as the session's
    // 8-frame windows (from twice their frames): not more than 0.5 dB below
    // their median.
    let mut psnrs: Vec<f64> = seen.iter().chain(&more).copied().collect();
    psnrs.sort_by(f64::total_cmp);
    let median = psnrs[psnrs.len() / 2];
    let recorded = psnr(&reconstruct(&d, &c));
    println!(
        "recording of 16 frames: {recorded:.2} dB; live windows {:.2}-{:.2} dB, median {median:.2} dB ({} results)",
        psnrs[0],
        psnrs[psnrs.len() - 1],
        psnrs.len()
    );
    assert!(
        recorded >= median - 0.5,
        "{recorded:.2} dB against {median:.2} dB"
    );
    let (s, b) = d.delete("/live");
    assert_eq!(s, 200, "{b}");
}

/// Issue 49, item 4: a recording cut short keeps the frames it got and says
/// so: a capture queued during it pauses the session (the recording ends
/// there, and the resumed session does not record again); `DELETE /live`
/// ends another, and SIGTERM a third.
#[test]
fn a_live_recording_cut_short_keeps_the_frames_it_got_and_says_why() {
    let _g = lock();
    let dir = scratch();
    let mut d = Daemon::start(&config(dir.path(), &[]), &dir.path().join("data"));
    let (s, b, _) = d.post("/live", &recording(600));
    assert_eq!(s, 202, "{b}");
    let id = serde_json::from_str::<Value>(&b).unwrap()["recording"]["capture"].clone();
    watch(&d, |v| v["recording"]["frames"].as_u64().unwrap_or(0) >= 5);
    let taken = d.run_job("/captures", CAPTURE, Duration::from_secs(60));
    assert_eq!(taken["state"], "done", "{taken}");
    let c = ended_capture(&d, &id);
    println!("paused by a capture: {c}");
    let k = c["frames"].as_u64().unwrap();
    assert_eq!(c["state"], "done", "{c}");
    assert!((5..600).contains(&k), "{c}");
    assert_eq!(c["frame_counts"]["received"], k + 2, "{c}");
    assert_eq!(c["frames_taken"], k + 2, "{c}");
    assert_eq!(c["live"]["frames_asked"], 600, "{c}");
    let ended = c["live"]["ended"].as_str().unwrap();
    assert_eq!(
        ended,
        format!("a queued capture paused live view after {k} of 600 frames")
    );
    assert_eq!(pages(&d, &id).len() as u64, k);
    let (v, _) = watch(&d, |v| {
        v["state"] == "running" && v["results"].as_u64().unwrap_or(0) > 0
    });
    let r = &v["recording"];
    assert_eq!(
        (r["state"].as_str(), r["frames"].as_u64()),
        (Some("ended"), Some(k)),
        "{v}"
    );
    assert_eq!(r["reason"], ended, "{v}");
    let r = reconstruct(&d, &c);
    println!("its reconstruction from {k} frames: {:.2} dB", psnr(&r));

    // DELETE /live: the next session's recording keeps what it got.
    let (s, b, _) = d.post("/live", &recording(600));
    assert_eq!(s, 202, "{b}");
    let id = serde_json::from_str::<Value>(&b).unwrap()["recording"]["capture"].clone();
    watch(&d, |v| v["recording"]["frames"].as_u64().unwrap_or(0) >= 3);
    let (s, b) = d.delete("/live");
    assert_eq!(s, 200, "{b}");
    let c = ended_capture(&d, &id);
    println!("stopped by DELETE /live: {c}");
    let k = c["frames"].as_u64().unwrap();
    assert_eq!(c["state"], "done", "{c}");
    assert!((3..600).contains(&k), "{c}");
    assert_eq!(
        c["live"]["ended"],
        format!("live view was stopped or replaced after {k} of 600 frames")
    );
    assert_eq!(pages(&d, &id).len() as u64, k);
    assert_eq!(reconstruct(&d, &c)["state"], "done");

    // SIGTERM: the daemon finishes the recording with what it got before it exits.
    let (s, b, _) = d.post("/live", &recording(600));
    assert_eq!(s, 202, "{b}");
    let id = serde_json::from_str::<Value>(&b).unwrap()["recording"]["capture"].clone();
    watch(&d, |v| v["recording"]["frames"].as_u64().unwrap_or(0) >= 3);
    assert!(d.terminate().success());
    let store = polnlos::store::Store::open(&dir.path().join("data")).unwrap();
    let c = serde_json::to_value(store.capture(id.as_i64().unwrap()).unwrap()).unwrap();
    println!("stopped by SIGTERM: {c}");
    let k = c["frames"].as_u64().unwrap();
    assert_eq!(c["state"], "done", "{c}");
    assert_eq!(
        c["live"]["ended"],
        format!("the daemon stopped after {k} of 600 frames")
    );
}

/// Issue 49: live view of a photo scene (fitted radiometry): each window's
/// gain and background are fitted with the scene, as a reconstruction with
/// `"radiometry": "fitted"` fits them. The session records its first window
/// (`record`), and the first result is that recording's reconstruction:
/// the same PSNR, gain and background. Without dark frames the background
/// is the sensor's dark level (the fake sensor's, which grows with the
/// exposure as room light would); with them it is gone.
#[test]
fn live_view_of_a_photo_scene_fits_gain_and_background_as_its_reconstruction_does() {
    let _g = lock();
    let dir = scratch();
    let d = Daemon::start(&config(dir.path(), &[]), &dir.path().join("data"));
    let fitted =
        r#""record": {"frames": 8}, "progressive": {"truth": "letter", "radiometry": "fitted"}"#;
    let body = LIVE.replace(r#""progressive": {"truth": "letter"}"#, fitted);
    // Difference mode keeps its background in calibrated units: refused fitted.
    d.refused(
        "/live",
        &body.replace(
            r#""dark_frames": 2,"#,
            r#""dark_frames": 2, "difference": {},"#,
        ),
        "fitted radiometry would fit away",
    );
    let mut level = None;
    for darks in [0, 2] {
        let events = live_events(&d, 1, |_| true);
        let live = body.replace(r#""dark_frames": 2"#, &format!(r#""dark_frames": {darks}"#));
        let (s, b, _) = d.post("/live", &live);
        assert_eq!(s, 202, "{b}");
        let first = events.join().unwrap().remove(0);
        let (v, seen) = watch(&d, |v| v["results"].as_u64().unwrap_or(0) >= 15);
        println!("darks {darks}: first result {first}; live {v}");
        assert_eq!(v["state"], "running", "{v}");
        assert_eq!(v["radiometry"]["mode"], "fitted", "{v}");
        assert_eq!(v["radiometry"]["given"], true, "{v}");
        assert_eq!(v["last"]["fitted"]["shadows"], "point", "{v}");
        let (s, b) = d.delete("/live");
        assert_eq!(s, 200, "{b}");
        // The recording holds the first window (and the session's darks).
        let c = ended_capture(&d, &v["recording"]["capture"]);
        assert_eq!(c["state"], "done", "{c}");
        let r = d.run_job(
            "/reconstructions",
            &format!(
                r#"{{"scene": "brewster-crossed", "captures": [{}], "truth": "letter", "radiometry": "fitted"}}"#,
                c["id"]
            ),
            Duration::from_secs(120),
        );
        assert_eq!(r["state"], "done", "{r}");
        let offline = (
            psnr(&r),
            r["report"]["channels"][0]["gain"].as_f64().unwrap(),
            r["report"]["channels"][0]["background"][0]
                .as_f64()
                .unwrap(),
        );
        let step = &first;
        let live = (
            step["psnr_db"].as_f64().unwrap(),
            step["fitted"]["gain"][0].as_f64().unwrap(),
            step["fitted"]["background"][0][0].as_f64().unwrap(),
        );
        assert_eq!(step["fitted"]["lambda_searched"], true, "{first}");
        println!(
            "darks {darks}: first window live {:.3} dB, gain {:.4e}, background {:.4e}; its recording offline {:.3} dB, {:.4e}, {:.4e}; later windows {:.2}-{:.2} dB",
            live.0, live.1, live.2, offline.0, offline.1, offline.2,
            seen.iter().copied().fold(f64::INFINITY, f64::min),
            seen.iter().copied().fold(0.0, f64::max)
        );
        // The same window, the same numbers.
        assert!((live.0 - offline.0).abs() < 0.05, "{live:?} vs {offline:?}");
        assert!(
            (live.1 / offline.1 - 1.0).abs() < 0.01,
            "{live:?} vs {offline:?}"
        );
        match level {
            None => {
                // The dark level: positive, and the same as offline's.
                assert!(live.2 > 0.0, "{live:?}");
                assert!(
                    (live.2 / offline.2 - 1.0).abs() < 0.01,
                    "{live:?} vs {offline:?}"
                );
                level = Some(live.2);
            }
            Some(level) => {
                // Dark frames subtracted: no background left, live or offline.
                assert!(
                    live.2.abs() < 0.05 * level,
                    "{live:?}; {level:e} without darks"
                );
                assert!(
                    offline.2.abs() < 0.05 * level,
                    "{offline:?}; {level:e} without darks"
                );
            }
        }
        // Every later window of the same frames count is as good (within
        // 0.5 dB of the first at the median).
        let mut sorted = seen.clone();
        sorted.sort_by(f64::total_cmp);
        let median = sorted[sorted.len() / 2];
        assert!(
            (median - live.0).abs() < 0.5,
            "median {median:.2} dB, first {:.2} dB",
            live.0
        );
    }
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
    // Without a colour calibration, live view fits each colour's gain and
    // background as the reconstruction of a capture would (measured 2.9-3.1
    // results a second, PSNR 5.0-5.2 dB, the reconstruction's 5.17 dB: the
    // first differences of this wide wall hardly see a constant scene light,
    // which the calibrated gain pins down). Its radiometry is said once its
    // solver is set up, before a result.
    let live = LIVE.replace("brewster-crossed", "chair-size");
    let (s, b, _) = d.post("/live", &live);
    assert_eq!(s, 202, "{b}");
    let (v, _) = watch(&d, |v| v["radiometry"].is_object());
    assert_eq!(v["radiometry"]["mode"], "fitted", "{v}");
    let why = v["radiometry"]["reason"].as_str().unwrap_or_default();
    assert!(why.contains("no colour calibration"), "{v}");
    // With the calibrated gain asked for, each colour is divided by it.
    let live = live.replace(
        r#""truth": "letter""#,
        r#""truth": "letter", "radiometry": "calibrated""#,
    );
    let (s, b, _) = d.post("/live", &live);
    assert_eq!(s, 202, "{b}");
    let (v, seen) = watch(&d, |v| {
        v["session"] == 2 && v["results"].as_u64().unwrap_or(0) >= 12
    });
    assert_eq!(v["radiometry"]["mode"], "calibrated", "{v}");
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

/// The moving fake bench's disk: a circle of 5 cm about the hidden-scene
/// plane's centre, a turn every 3 s (10.5 cm/s), a disk of 3 cm radius.
const TURN_S: f64 = 3.0;
const CIRCLE_M: f64 = 0.05;
const DISK_M: f64 = 0.03;

/// One element of the demo scene's 8 x 8 grid over 0.2 m, metres.
const CELL_M: f64 = 0.025;

/// Where the disk is at Unix time `t`, computed here from the config (the
/// daemon's own function is not asked): anticlockwise from +u.
fn truth(t: f64) -> (f64, f64) {
    let a = std::f64::consts::TAU * (t / TURN_S).rem_euclid(1.0);
    (CIRCLE_M * a.cos(), CIRCLE_M * a.sin())
}

/// The track file's rows: time, and the centroid and its spread when there is one.
fn track_rows(d: &Daemon) -> Vec<(f64, Option<[f64; 4]>)> {
    let (s, csv) = d.get("/live/track.csv");
    assert_eq!(s, 200, "{csv}");
    let mut lines = csv.lines();
    assert_eq!(lines.next(), Some("time_s,u_m,v_m,sigma_u_m,sigma_v_m"));
    lines
        .map(|l| {
            let f: Vec<&str> = l.split(',').collect();
            assert_eq!(f.len(), 5, "{l}");
            let n = |k: usize| f[k].parse::<f64>().ok();
            let c = match (n(1), n(2), n(3), n(4)) {
                (Some(u), Some(v), Some(su), Some(sv)) => Some([u, v, su, sv]),
                _ => None,
            };
            (n(0).expect("a time"), c)
        })
        .collect()
}

/// The `live` events of the next `n` results that `keep` keeps, read from
/// `/events` (subscribed before it returns).
fn live_events(
    d: &Daemon,
    n: usize,
    keep: fn(&Value) -> bool,
) -> std::thread::JoinHandle<Vec<Value>> {
    use std::io::BufRead;
    let agent: ureq::Agent = ureq::Agent::config_builder()
        .timeout_global(Some(Duration::from_secs(60)))
        .build()
        .into();
    let url = format!("{}/events", d.base);
    // Subscribed once the daemon answered: no event after this is missed.
    let mut r = agent.get(url).call().unwrap();
    std::thread::spawn(move || {
        let mut lines = std::io::BufReader::new(r.body_mut().as_reader()).lines();
        let mut seen = Vec::new();
        while let Some(Ok(line)) = lines.next() {
            let Some(data) = line.strip_prefix("data: ") else {
                continue;
            };
            let v: Value = serde_json::from_str(data).unwrap();
            if v["type"] == "live" && keep(&v) {
                seen.push(v);
                if seen.len() == n {
                    break;
                }
            }
        }
        seen
    })
}

/// Issue 49, "motion" and "a fake bench that moves": the fake bench's
/// hidden scene carries a disk round a circle over the letter; live view in
/// difference mode, through Aravis's fake camera and real HTTP, tracks it
/// within one scene cell of where it was at every result over a full turn,
/// once the background has seen one turn of it (the settling time: until
/// then the background holds only part of the path, and the disk's recent
/// positions dim it). The rate, the latency and the error are printed.
#[test]
fn live_difference_mode_tracks_a_moving_disk_within_a_scene_cell_over_its_path() {
    let _g = lock();
    let dir = scratch();
    let motion = format!(
        "\nsensor_noise = true\nmotion = {{ radius_m = {CIRCLE_M}, period_s = {TURN_S}, disk_radius_m = {DISK_M} }}\n"
    );
    let cfg = config(dir.path(), &[("\nsensor_noise = true\n", &motion)]);
    let d = Daemon::start(&cfg, &dir.path().join("data"));
    let live = LIVE.replace(
        r#""progressive": {"truth": "letter"}"#,
        r#""difference": {}"#,
    );
    // Refused, naming the field: a background of no time, a difference
    // mode asked of a capture.
    d.refused(
        "/live",
        &live.replace(
            r#""difference": {}"#,
            r#""difference": {"background_s": 0}"#,
        ),
        "difference.background_s",
    );
    d.refused("/captures", &live, "difference is live view's");

    let events = live_events(&d, 10, |v| v["centroid"].is_object());
    let (s, b, _) = d.post("/live", &live);
    assert_eq!(s, 202, "{b}");
    // Results until one turn past the settling turn.
    let started = Instant::now();
    let rows = loop {
        let rows = track_rows(&d);
        if let (Some(first), Some(last)) = (rows.first(), rows.last()) {
            if last.0 >= first.0 + 2.0 * TURN_S + 0.2 {
                break rows;
            }
        }
        assert!(
            started.elapsed() < Duration::from_secs(60),
            "{}",
            d.json("/live")
        );
        std::thread::sleep(Duration::from_millis(100));
    };
    let v = d.json("/live");
    assert_eq!(v["state"], "running", "{v}");
    assert_eq!(v["difference_background_s"], 10.0, "{v}");
    assert!(
        v["last"]["psnr_db"].is_null(),
        "no truth for a difference: {v}"
    );
    let settled = rows[0].0 + TURN_S;
    let judged: Vec<_> = rows.iter().filter(|r| r.0 >= settled).collect();
    let span = judged.last().unwrap().0 - judged[0].0;
    assert!(span >= TURN_S, "{span} s of results judged");
    // Every judged result found the disk, within one cell of the truth.
    let mut errors = Vec::new();
    let mut within_2_sigma = 0;
    let mut table = String::new();
    for (t, c) in &judged {
        let (tu, tv) = truth(*t);
        let [u, v, su, sv] = c.unwrap_or([f64::NAN; 4]);
        let e = (u - tu).hypot(v - tv);
        table += &format!(
            "{:.3} s: ({u:.4}, {v:.4}) +- ({su:.4}, {sv:.4}) m, truth ({tu:.4}, {tv:.4}) m, {:.2} cells\n",
            t - rows[0].0,
            e / CELL_M
        );
        within_2_sigma += usize::from((u - tu).abs() <= 2.0 * su && (v - tv).abs() <= 2.0 * sv);
        errors.push(e / CELL_M);
    }
    let bad = errors.iter().filter(|e| e.is_nan() || **e > 1.0).count();
    assert_eq!(
        bad, 0,
        "{bad} results off by more than a cell (or none found):\n{table}"
    );
    assert!(
        judged.iter().all(|(_, c)| c
            .is_some_and(|[_, _, su, sv]| su > 0.0 && sv > 0.0 && su < CELL_M && sv < CELL_M)),
        "{table}"
    );
    errors.sort_by(f64::total_cmp);
    let early: Vec<f64> = rows
        .iter()
        .filter(|r| r.0 < settled)
        .map(|r| {
            r.1.map_or(f64::NAN, |[u, v, _, _]| {
                let (tu, tv) = truth(r.0);
                (u - tu).hypot(v - tv) / CELL_M
            })
        })
        .collect();
    println!(
        "difference mode over a {TURN_S} s turn: {} results judged, error median {:.3} max {:.3} cells, {within_2_sigma} within 2 sigma per axis; {:.1} results a second, median latency {:.1} ms; the settling turn's errors (cells) {early:.2?}",
        judged.len(),
        errors[errors.len() / 2],
        errors[errors.len() - 1],
        v["results_per_second"].as_f64().unwrap_or(f64::NAN),
        v["median_latency_ms"].as_f64().unwrap_or(f64::NAN),
    );
    // Each result's centroid went out on /events as the track has it.
    let seen = events.join().unwrap();
    assert_eq!(seen.len(), 10);
    for e in &seen {
        let t = e["time_s"].as_f64().unwrap();
        let row = rows
            .iter()
            .find(|r| (r.0 - t).abs() < 2e-6)
            .unwrap_or_else(|| panic!("event at {t} not in the track"));
        let c = row.1.unwrap();
        assert!(
            (e["centroid"]["u_m"].as_f64().unwrap() - c[0]).abs() < 2e-6,
            "{e}"
        );
        assert!(
            (e["centroid"]["v_m"].as_f64().unwrap() - c[1]).abs() < 2e-6,
            "{e}"
        );
    }
    let (s, b) = d.delete("/live");
    assert_eq!(s, 200, "{b}");
    assert!(
        track_rows(&d).len() >= rows.len(),
        "the track outlives the session"
    );
}

/// Issue 49, item 5: `polnlos bench --live` runs a daemon on the fake
/// camera, measures its live view and the offline reconstruction of a
/// capture of the same window, and writes the report. Its numbers are the
/// benchmark's (docs/bench/live.md), not bounded here; what is held is that
/// each was measured: results came, each with a latency and a PSNR near the
/// offline one, and the daemon's memory was read.
#[test]
fn bench_live_measures_live_view_beside_the_offline_reconstruction() {
    let _g = lock();
    let dir = scratch();
    let out = dir.path().join("bench");
    let run = std::process::Command::new(env!("CARGO_BIN_EXE_polnlos"))
        .args(["bench", "--live", "--quick", "--live-seconds", "3", "--out"])
        .arg(&out)
        .output()
        .unwrap();
    assert!(
        run.status.success(),
        "{}",
        String::from_utf8_lossy(&run.stderr)
    );
    let report: Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("live.json")).unwrap()).unwrap();
    println!("{report}");
    let rows = report["live"].as_array().unwrap();
    assert_eq!(rows.len(), 1, "{report}");
    let r = &rows[0];
    assert_eq!(
        (r["wall"][0].as_u64(), r["grid"][0].as_u64()),
        (Some(32), Some(8))
    );
    let num = |k: &str| r[k].as_f64().unwrap_or(f64::NAN);
    assert!(r["results"].as_u64().unwrap() >= 3, "{r}");
    assert!(num("results_per_second") > 0.0, "{r}");
    assert!(num("median_latency_ms") > 0.0, "{r}");
    assert!(num("offline_seconds") > 0.0, "{r}");
    assert!(num("rss_mib") > 10.0, "{r}");
    // The letter, not noise, both ways, and the two within the spread of
    // single 8-frame windows (the live test holds the 0.5 dB median).
    let (live, offline) = (num("live_psnr_db"), num("offline_psnr_db"));
    assert!(live > 11.0 && offline > 11.0, "{r}");
    assert!((live - offline).abs() < 1.5, "{r}");
    let md = std::fs::read_to_string(out.join("live.md")).unwrap();
    assert!(md.contains("| wall 32x32, scene 8x8 | 64 | 8 |"), "{md}");
    let png = std::fs::read(out.join("live.png")).unwrap();
    assert_eq!(&png[1..4], b"PNG");
    assert!(out.join("live.svg").exists());
}
