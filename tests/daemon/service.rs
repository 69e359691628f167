//! `polnlos serve` end to end over real HTTP on 127.0.0.1, with Aravis's
//! GigE Vision fake camera showing the demo hidden scene.

use std::time::{Duration, Instant};

use crate::daemon::common::{config, lock, psnr, scratch, Client, Daemon, InProcess};
use polnlos::scene::Scene;
use polnlos::simulate::patterns::Pattern;
use polnlos::solve::metrics;
use polnlos::transport::MemoryBudget;

fn truth(scene: &str) -> (polnlos::scene::Grid, Vec<f64>) {
    let text = std::fs::read_to_string(format!(
        "{}/config/scenes/{scene}.toml",
        env!("CARGO_MANIFEST_DIR")
    ))
    .unwrap();
    let grid = Scene::from_toml_str(&text).unwrap().hidden().plane.grid;
    (grid, Pattern::Letter.render(grid))
}

/// A reconstruction's `recovered.npy` (top row first, docs/formats.md
/// "Which way is up") in the scene grid's element order, as [`truth`].
fn recovered(d: &Client, id: i64) -> Vec<f64> {
    let (s, bytes) = d.get_bytes(&format!("/reconstructions/{id}/recovered.npy"));
    assert_eq!(s, 200);
    let dir = scratch();
    let p = dir.path().join("r.npy");
    std::fs::write(&p, bytes).unwrap();
    let a = polnlos::files::npy::read(&p).unwrap();
    let [nv, nu] = a.shape[..] else {
        panic!("shape {:?}", a.shape)
    };
    polnlos::scene::Grid { nu, nv }.from_top_first(&a.data, 1)
}

/// `polnlos measure` on a capture's downloaded raw frames and dark frames,
/// with the radiometric gain `GET /calibrations` shows (the one the
/// reconstruction's report names), gives the measurement the daemon solved
/// (the same assembly code), block by block, given in reverse order.
fn offline_measure_matches_the_daemon(
    d: &Client,
    scene: &str,
    ids: &[i64],
    daemon_i: &[f64],
    report: &serde_json::Value,
) {
    let gains = d.json("/calibrations");
    let gain = gains["radiometric"]
        .as_array()
        .unwrap()
        .iter()
        .find(|g| g["scene"] == scene)
        .unwrap_or_else(|| panic!("no gain for {scene}: {gains}"));
    assert_eq!(gain["source"], "fake camera", "{gain}");
    let g = gain["gain"].as_f64().unwrap();
    assert_eq!(report["gain"]["value"].as_f64(), Some(g), "{report}");
    assert_eq!(report["gain"]["source"], "calibration", "{report}");
    let dir = scratch();
    let mut cmd = std::process::Command::new(env!("CARGO_BIN_EXE_polnlos"));
    cmd.args([
        "measure",
        scene,
        "--exposure-us",
        "20000",
        "--gain",
        &g.to_string(),
    ]);
    for id in ids.iter().rev() {
        for file in ["frame", "dark"] {
            let (s, bytes) = d.get_bytes(&format!("/captures/{id}/{file}.tiff"));
            assert_eq!(s, 200);
            let p = dir.path().join(format!("{file}-{id}.tiff"));
            std::fs::write(&p, bytes).unwrap();
            cmd.arg(format!(
                "--{}",
                if file == "frame" { "frames" } else { "dark" }
            ))
            .arg(&p);
        }
        let c = d.json(&format!("/captures/{id}"));
        cmd.args(["--pose", c["pose"].as_str().unwrap()]);
        let angle = match c["channels"].as_array().unwrap().as_slice() {
            [one] if one["analyzer"] == "sheet" => one["deg"].to_string(),
            [one] if one["analyzer"] == "none" => "none".to_string(),
            _ => "mosaic".to_string(),
        };
        cmd.args(["--angle", &angle]);
    }
    let out = dir.path().join("i.npy");
    let o = cmd.arg("--out").arg(&out).output().unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let i = polnlos::files::npy::read(&out).unwrap().data;
    assert_eq!(i.len(), daemon_i.len());
    let top = daemon_i.iter().fold(0.0f64, |m, v| m.max(v.abs()));
    assert!(top > 0.0, "{top}");
    for (k, (a, b)) in daemon_i.iter().zip(&i).enumerate() {
        assert!(
            (a - b).abs() <= 1e-6 * top,
            "element {k}: daemon {a}, offline {b}"
        );
    }
    let var = polnlos::files::npy::read(&dir.path().join("i.variance.npy")).unwrap();
    assert_eq!(var.data.len(), i.len());
    assert!(var.data.iter().all(|v| *v > 0.0));
}

#[test]
fn capture_every_block_reconstruct_and_fetch() {
    let _g = lock();
    let dir = scratch();
    let cfg = config(dir.path(), &[]);
    let d = Daemon::start(&cfg, &dir.path().join("data"));
    let cam = d.json("/camera");
    assert_eq!(cam["connected"], true, "{cam}");
    let mut report = Vec::new();
    for (scene, blocks) in [
        ("brewster-crossed", vec![("A", 0.0)]),
        ("brewster-multi", vec![("B", 0.0), ("C", 0.0)]),
    ] {
        let mut ids = Vec::new();
        for (pose, angle) in blocks {
            let body = format!(
                r#"{{"scene": "{scene}", "pose": "{pose}", "polarizer_deg": {angle}, "exposure_us": 20000, "gain": 0, "frames": 4, "dark_frames": 2}}"#
            );
            let c = d.run_job("/captures", &body, Duration::from_secs(30));
            assert_eq!(c["state"], "done", "{c}");
            assert_eq!(c["frames_taken"], 6);
            ids.push(c["id"].as_i64().unwrap());
            let (s, tiff) = d.get_bytes(&format!("/captures/{}/frame.tiff", ids.last().unwrap()));
            assert_eq!(s, 200);
            assert_eq!(&tiff[..2], b"II");
            assert_eq!(
                d.get(&format!("/captures/{}/preview.png", ids.last().unwrap()))
                    .0,
                200
            );
            // Everything the capture has can be downloaded: its 2 dark
            // frames and the variance of its 4-frame mean too.
            let id = ids.last().unwrap();
            let (s, dark) = d.get_bytes(&format!("/captures/{id}/dark.tiff"));
            assert_eq!((s, &dark[..2]), (200, &b"II"[..]));
            let (s, var) = d.get_bytes(&format!("/captures/{id}/variance.tiff"));
            assert_eq!((s, &var[..2]), (200, &b"II"[..]));
        }
        let body =
            serde_json::json!({ "scene": scene, "captures": ids, "solver": "admm-tv", "truth": "letter" }).to_string();
        let r = d.run_job("/reconstructions", &body, Duration::from_secs(60));
        assert_eq!(r["state"], "done", "{r}");
        assert!(r["kappa"].as_f64().unwrap() > 1.0);
        // No lambda in the request and 4 frames per capture: lambda comes from
        // the frame-to-frame noise (the fake camera's shot and read noise);
        // should ADMM reach its cap, it says so.
        assert_eq!(
            r["report"]["lambda_choice"]["rule"], "resolved-discrepancy",
            "{r}"
        );
        assert!(
            r["report"]["solver"]["converged"].as_bool().unwrap()
                || r["report"]["warnings"]
                    .to_string()
                    .contains("iteration cap"),
            "{r}"
        );
        // kappa ~1e8: the frame-to-frame noise cannot support an 8x8 least-squares estimate.
        assert!(
            r["report"]["notes"]
                .to_string()
                .contains("finer than this measurement supports"),
            "{}",
            r["report"]["notes"]
        );
        let img = recovered(&d, r["id"].as_i64().unwrap());
        let (grid, t) = truth(scene);
        let m = metrics::compare(grid, &t, &img);
        assert!(
            (r["report"]["metrics"]["psnr_db"]
                .as_f64()
                .unwrap_or(f64::NAN)
                - m.psnr_db)
                .abs()
                < 1e-9,
            "report metrics = recomputed: {} {}",
            r["params"],
            r["report"]["metrics"]
        );
        report.push(format!(
            "{scene}: PSNR {:.2} dB, ZNCC {:.3}, SSIM {:.3}",
            m.psnr_db, m.zncc, m.ssim
        ));
        let (s, png) = d.get_bytes(&format!("/reconstructions/{}/image.png", r["id"]));
        assert_eq!((s, &png[1..4]), (200, &b"PNG"[..]));
        // Enlarged for a viewer: each element a 16x16 block, the same values.
        let (s, big) = d.get_bytes(&format!("/reconstructions/{}/image.png?scale=16", r["id"]));
        assert_eq!(s, 200);
        let (small, big) = (crate::png::decode(&png), crate::png::decode(&big));
        assert_eq!(
            (big.width, big.height, big.channels, big.bits),
            (small.width * 16, small.height * 16, 1, 16)
        );
        for y in 0..big.height {
            for x in 0..big.width {
                assert_eq!(big.at(x, y, 0), small.at(x / 16, y / 16, 0), "({x}, {y})");
            }
        }
        for bad in ["0", "100000", "two"] {
            let (s, b) = d.get(&format!(
                "/reconstructions/{}/image.png?scale={bad}",
                r["id"]
            ));
            assert_eq!(s, if bad == "two" { 400 } else { 422 }, "{bad}: {b}");
        }
        // The truth it was compared with, on the scene grid, at the same scale.
        let (s, png) = d.get_bytes(&format!("/reconstructions/{}/truth.png", r["id"]));
        assert_eq!((s, &png[1..4]), (200, &b"PNG"[..]));
        let shown = crate::png::decode(&png);
        let (grid, t) = truth(scene);
        assert_eq!((shown.width, shown.height), (grid.nu, grid.nv));
        // Shown top row first, as every scene image.
        let t = grid.to_top_first(&t, 1);
        let px: Vec<f64> = shown
            .grey()
            .iter()
            .map(|&p| f64::from(p) / 65535.0)
            .collect();
        assert!(px.iter().zip(&t).all(|(a, b)| (a - b).abs() < 1e-4));
        // The measurement it solved (one value per row of T) and its report.
        let (s, npy) = d.get_bytes(&format!("/reconstructions/{}/measurement.npy", r["id"]));
        assert_eq!(s, 200);
        let m_i = polnlos::files::npy::decode(&npy).unwrap();
        assert_eq!(m_i.data.len() as u64, r["report"]["rows"].as_u64().unwrap());
        let (s, rep) = d.get(&format!("/reconstructions/{}/report.json", r["id"]));
        assert_eq!(s, 200);
        let rep: serde_json::Value = serde_json::from_str(&rep).unwrap();
        assert_eq!(rep["conditioning"], r["report"]["conditioning"]);
        if scene == "brewster-multi" {
            offline_measure_matches_the_daemon(&d, scene, &ids, &m_i.data, &rep);
        }
        println!("{}", report.last().unwrap());
        // The bound: clearly better than the best featureless guess (the truth's
        // own mean everywhere), by 3 dB; what limits the result is the sensor's
        // noise through kappa(T) ~ 1e8 of the 8x8 scene.
        let mean = t.iter().sum::<f64>() / t.len() as f64;
        let grey = metrics::psnr(&t, &vec![mean; t.len()]);
        assert!(
            m.psnr_db > grey + 3.0 && m.zncc > 0.6,
            "{} (uniform guess {grey:.2} dB)",
            report.last().unwrap()
        );
    }
    // The 3x3 grid of the same bench is supported: no such warning.
    let c = d.run_job("/captures", r#"{"scene": "brewster-crossed-3x3", "pose": "A", "polarizer_deg": 0, "exposure_us": 20000, "frames": 4, "dark_frames": 1}"#, Duration::from_secs(30));
    let r = d.run_job(
        "/reconstructions",
        &format!(
            r#"{{"scene": "brewster-crossed-3x3", "captures": [{}]}}"#,
            c["id"]
        ),
        Duration::from_secs(30),
    );
    assert_eq!(r["state"], "done", "{r}");
    assert!(
        !r["report"]["notes"].to_string().contains("finer than"),
        "{}",
        r["report"]["notes"]
    );
    let jobs = d.json("/jobs/capture-1");
    assert_eq!(jobs["job"], "capture-1");
    let metrics = d.get("/metrics").1;
    assert!(
        metrics.contains("polnlos_captures_done_total 4"),
        "{metrics}"
    );
    assert!(
        metrics.contains("polnlos_camera_frames_completed_total 23"),
        "{metrics}"
    );
    let spec = d.json("/openapi.json");
    assert!(spec["paths"]["/captures"]["post"].is_object());
    for list in ["/captures", "/reconstructions"] {
        let header =
            &spec["paths"][list]["get"]["responses"]["200"]["headers"]["polnlos-unreadable"];
        assert!(
            header["description"]
                .as_str()
                .is_some_and(|d| d.contains("could not read")),
            "{list}: {header}"
        );
    }
    assert!(spec["components"]["schemas"]["CaptureBody"].is_object());
    openapi_is_complete(&spec);
}

/// Every operation the document names answers its errors as `ErrorBody`,
/// and the bearer scheme is declared. The operations are read from the
/// document, which the router generates from the routes it serves (and
/// `tests/daemon/in_process.rs` holds the two equal), so a new route is checked
/// without being listed here.
fn openapi_is_complete(spec: &serde_json::Value) {
    assert_eq!(
        spec["components"]["securitySchemes"]["bearer"]["scheme"], "bearer",
        "{}",
        spec["components"]
    );
    let paths = spec["paths"].as_object().expect("the document names paths");
    let mut operations = 0;
    for (path, item) in paths {
        for method in ["get", "put", "post", "delete", "patch"] {
            let op = &item[method];
            if !op.is_object() {
                continue;
            }
            operations += 1;
            for code in ["401", "403", "500"] {
                let schema =
                    &op["responses"][code]["content"]["application/json"]["schema"]["$ref"];
                assert_eq!(
                    schema, "#/components/schemas/ErrorBody",
                    "{method} {path} {code}"
                );
            }
        }
    }
    assert!(operations > 0, "the document names no operation");
    let accepted = &spec["paths"]["/captures"]["post"]["responses"]["202"]["content"]
        ["application/json"]["schema"]["$ref"];
    assert_eq!(accepted, "#/components/schemas/CaptureAccepted");
}

#[test]
fn bad_requests_get_a_reason_never_a_500() {
    let dir = scratch();
    let cfg = config(
        dir.path(),
        &[("max_body_bytes = 65536", "max_body_bytes = 4096")],
    );
    let d = InProcess::start(&cfg, &dir.path().join("data"));
    let cases: Vec<(&str, String, u16, &str)> = vec![
        ("/captures", "{not json".into(), 400, "malformed_json"),
        ("/captures", r#"{"scene": "brewster-crossed"}"#.into(), 422, "invalid_request"),
        ("/captures", r#"{"scene": "brewster-crossed", "pose": "A", "polarizer_deg": 0, "exposure_us": 1}"#.into(), 422, "exposure_us = 1"),
        ("/captures", r#"{"scene": "brewster-crossed", "pose": "A", "polarizer_deg": 0, "exposure_us": 1e12}"#.into(), 422, "exposure_us"),
        ("/captures", r#"{"scene": "nope", "pose": "A", "exposure_us": 1000}"#.into(), 404, "unknown scene"),
        ("/captures", r#"{"scene": "brewster-crossed", "pose": "Z", "polarizer_deg": 0, "exposure_us": 1000}"#.into(), 422, "has no pose"),
        ("/captures", r#"{"scene": "brewster-crossed", "pose": "A", "polarizer_deg": 45, "exposure_us": 1000}"#.into(), 422, "not an angle"),
        ("/captures", r#"{"scene": "brewster-crossed", "pose": "A", "exposure_us": 1000}"#.into(), 422, "give polarizer_deg"),
        ("/captures", r#"{"scene": "brewster-crossed", "pose": "A", "polarizer_deg": 0, "exposure_us": 1000, "frames": 0}"#.into(), 422, "frames = 0"),
        ("/captures", r#"{"scene": "brewster-crossed", "pose": "A", "polarizer_deg": 0, "exposure_us": 1000, "gain": 99}"#.into(), 422, "gain = 99"),
        ("/captures", r#"{"scene": "brewster-crossed", "pose": "A", "polarizer_deg": 0, "exposure_us": 1000, "colour": 1}"#.into(), 422, "unknown field"),
        ("/captures", format!(r#"{{"scene": "{}"}}"#, "x".repeat(5000)), 413, "body_too_large"),
        ("/reconstructions", r#"{"scene": "brewster-crossed", "captures": [999]}"#.into(), 404, "no capture with id 999"),
        ("/reconstructions", r#"{"scene": "brewster-crossed", "captures": []}"#.into(), 422, "give one capture for each"),
        ("/reconstructions", r#"{"scene": "brewster-crossed", "captures": [1], "solver": "magic"}"#.into(), 422, "solver"),
        ("/reconstructions", r#"{"scene": "brewster-crossed", "captures": [1], "lambda": -1}"#.into(), 422, "lambda = -1"),
        ("/reconstructions", r#"{"scene": "brewster-crossed", "captures": [1], "truth": "cat"}"#.into(), 422, "truth"),
    ];
    for (path, body, status, needle) in cases {
        let (s, b, _) = d.post(path, &body);
        assert_eq!(s, status, "{body}: {b}");
        let v: serde_json::Value =
            serde_json::from_str(&b).unwrap_or_else(|_| panic!("not JSON: {b}"));
        assert!(v["error"].is_string() && v["detail"].is_string(), "{b}");
        assert!(b.contains(needle), "{body}: {b} lacks {needle:?}");
    }
    for (path, status) in [
        ("/captures/999", 404),
        ("/captures/abc", 400),
        ("/captures/0", 400),
        ("/reconstructions/-2/image.png", 400),
        ("/reconstructions/5", 404),
        ("/jobs/capture-77", 404),
        ("/jobs/x", 404),
        ("/nowhere", 404),
        ("/captures?limit=0", 422),
    ] {
        let (s, b) = d.get(path);
        assert_eq!(s, status, "{path}: {b}");
        assert!(serde_json::from_str::<serde_json::Value>(&b).unwrap()["detail"].is_string());
    }
    // A capture of another scene cannot feed this scene's reconstruction.
    let c = d.run_job(
        "/captures",
        r#"{"scene": "brewster-nopol", "pose": "A", "exposure_us": 1000}"#,
        Duration::from_secs(20),
    );
    assert_eq!(c["state"], "done", "{c}");
    let (s, b, _) = d.post(
        "/reconstructions",
        &format!(
            r#"{{"scene": "brewster-crossed", "captures": [{}]}}"#,
            c["id"]
        ),
    );
    assert_eq!(s, 422, "{b}");
    assert!(b.contains("belongs to scene \\\"brewster-nopol\\\""), "{b}");
    assert_eq!(d.get("/health").0, 200, "still up");
}

#[test]
fn a_token_guards_every_mutating_request() {
    let dir = scratch();
    let cfg = config(dir.path(), &[("token = \"\"", "token = \"s3cret\"")]);
    let mut d = InProcess::start(&cfg, &dir.path().join("data"));
    let body =
        r#"{"scene": "brewster-crossed", "pose": "A", "polarizer_deg": 0, "exposure_us": 1000}"#;
    let (s, b, _) = d.post("/captures", body);
    assert_eq!(s, 401, "{b}");
    assert!(b.contains("Bearer"));
    d.token = Some("wrong".into());
    assert_eq!(d.post("/captures", body).0, 401);
    assert_eq!(d.get("/captures").0, 401, "reads need the token too");
    assert_eq!(d.get("/metrics").0, 401);
    assert_eq!(d.get("/health").0, 200, "liveness needs none");
    d.token = Some("s3cret".into());
    assert_eq!(d.post("/captures", body).0, 202);
    assert_eq!(d.get("/captures").0, 200);
    // The scheme is case-insensitive (RFC 7235).
    let (s, _) = d.raw(b"GET /captures HTTP/1.1\r\nHost: 127.0.0.1\r\nAuthorization: bearer s3cret\r\nConnection: close\r\n\r\n");
    assert_eq!(s, 200);
    drop(d);
    // public_reads lets GETs through without it; writes still need it.
    let cfg = config(
        dir.path(),
        &[
            ("token = \"\"", "token = \"s3cret\""),
            ("public_reads = false", "public_reads = true"),
        ],
    );
    let d = InProcess::start(&cfg, &dir.path().join("data2"));
    assert_eq!(d.get("/captures").0, 200);
    assert_eq!(d.post("/captures", body).0, 401);
}

#[test]
fn a_full_queue_answers_429_and_a_bounded_load_sees_nothing_else() {
    let _g = lock();
    let dir = scratch();
    let cfg = config(dir.path(), &[("captures = 16", "captures = 4")]);
    let d = Daemon::start(&cfg, &dir.path().join("data"));
    let rss_before = d.rss_kib();
    let body = r#"{"scene": "brewster-crossed", "pose": "A", "polarizer_deg": 0, "exposure_us": 50000, "frames": 2}"#;
    let (base, agent) = (d.base.clone(), d.agent.clone());
    let started = std::time::Instant::now();
    // 32 threads x 63 requests = 2016, every third a POST.
    let handles: Vec<_> = (0..32)
        .map(|t| {
            let (base, agent) = (base.clone(), agent.clone());
            std::thread::spawn(move || {
                let mut counts = std::collections::BTreeMap::<u16, u32>::new();
                for k in 0..63 {
                    let r = if (t + k) % 3 == 0 {
                        agent
                            .post(format!("{base}/captures"))
                            .header("content-type", "application/json")
                            .send(body)
                    } else if k % 2 == 0 {
                        agent.get(format!("{base}/captures?limit=5")).call()
                    } else {
                        agent.get(format!("{base}/health")).call()
                    };
                    let s = r.map(|mut r| {
                        let _ = r.body_mut().read_to_string();
                        r.status().as_u16()
                    });
                    *counts.entry(s.unwrap_or(0)).or_default() += 1;
                }
                counts
            })
        })
        .collect();
    let mut total = std::collections::BTreeMap::<u16, u32>::new();
    for h in handles {
        for (s, n) in h.join().unwrap() {
            *total.entry(s).or_default() += n;
        }
    }
    let elapsed = started.elapsed();
    let rss_after = d.rss_kib();
    println!("2016 requests in {elapsed:?}: {total:?}; RSS {rss_before} -> {rss_after} KiB");
    assert_eq!(total.values().sum::<u32>(), 2016);
    assert!(
        total.keys().all(|s| [200, 202, 429].contains(s)),
        "{total:?}"
    );
    assert!(
        total.get(&429).copied().unwrap_or(0) > 0,
        "the queue of 4 must overflow"
    );
    assert!(
        rss_after < rss_before + 100 * 1024,
        "RSS grew from {rss_before} to {rss_after} KiB"
    );
    let m = d.get("/metrics").1;
    assert!(
        m.contains(&format!(
            "polnlos_requests_rejected_queue_full_total {}",
            total[&429]
        )),
        "{m}"
    );
}

#[test]
fn events_report_frames_and_job_states() {
    use std::io::BufRead;
    let dir = scratch();
    let cfg = config(dir.path(), &[]);
    let d = InProcess::start(&cfg, &dir.path().join("data"));
    let agent: ureq::Agent = ureq::Agent::config_builder()
        .timeout_global(Some(Duration::from_secs(15)))
        .build()
        .into();
    let url = format!("{}/events", d.base);
    let reader = std::thread::spawn(move || {
        let mut r = agent.get(url).call().unwrap();
        assert_eq!(
            r.headers().get("content-type").unwrap(),
            "text/event-stream"
        );
        let mut lines = std::io::BufReader::new(r.body_mut().as_reader()).lines();
        let mut seen = Vec::new();
        while let Some(Ok(line)) = lines.next() {
            if let Some(data) = line.strip_prefix("data: ") {
                let v: serde_json::Value = serde_json::from_str(data).unwrap();
                let done = v["type"] == "job" && v["state"] == "done";
                seen.push(v);
                if done {
                    break;
                }
            }
        }
        seen
    });
    std::thread::sleep(Duration::from_millis(300));
    let c = d.run_job("/captures", r#"{"scene": "brewster-crossed", "pose": "A", "polarizer_deg": 0, "exposure_us": 10000, "frames": 3, "dark_frames": 1}"#, Duration::from_secs(20));
    assert_eq!(c["state"], "done");
    let seen = reader.join().unwrap();
    let frames: Vec<i64> = seen
        .iter()
        .filter(|v| v["type"] == "frame")
        .map(|v| v["taken"].as_i64().unwrap())
        .collect();
    assert_eq!(frames, vec![1, 2, 3, 4], "{seen:?}");
    assert!(seen
        .iter()
        .any(|v| v["type"] == "job" && v["state"] == "running" && v["job"] == "capture-1"));
}

#[test]
fn camera_settings_are_validated_and_applied() {
    let _g = lock();
    let dir = scratch();
    let cfg = config(dir.path(), &[]);
    let d = Daemon::start(&cfg, &dir.path().join("data"));
    let cam = d.json("/camera");
    assert_eq!(cam["info"]["exposure_feature"], "ExposureTimeAbs", "{cam}");
    assert_eq!(cam["info"]["gain_feature"], "GainRaw");
    assert_eq!(cam["info"]["sensor"], serde_json::json!([2048, 2048]));
    let put = |body: &str| {
        let mut r = d
            .agent
            .put(format!("{}/camera/settings", d.base))
            .header("content-type", "application/json")
            .send(body)
            .unwrap();
        (r.status().as_u16(), r.body_mut().read_to_string().unwrap())
    };
    let (s, b) = put(
        r#"{"exposure_us": 5000, "gain": 2, "pixel_format": "Mono8", "region": null, "binning": null, "trigger": "software"}"#,
    );
    assert_eq!(s, 200, "{b}");
    let v: serde_json::Value = serde_json::from_str(&b).unwrap();
    assert_eq!(v["settings"]["pixel_format"], "Mono8");
    let (s, b) = put(
        r#"{"exposure_us": 1, "gain": 0, "pixel_format": "Mono16", "region": null, "binning": null, "trigger": "free"}"#,
    );
    assert_eq!(s, 422, "{b}");
    assert!(b.contains("ExposureTimeAbs = 1: out of range"), "{b}");
    // A partial body changes what it names; the rest keep their defaults.
    let (s, b) = put(r#"{"exposure_us": 1000}"#);
    assert_eq!(s, 200, "{b}");
    let defaults = &d.json("/camera")["capture_defaults"];
    assert_eq!(defaults["exposure_us"], 1000.0, "{defaults}");
    assert_eq!(defaults["pixel_format"], "Mono8", "{defaults}");
    assert_eq!(defaults["trigger"], "software", "{defaults}");
    let (s, b) = put(r#"{"pixel_format": "Mono16", "trigger": "free"}"#);
    assert_eq!(s, 200, "{b}");
    let defaults = &d.json("/camera")["capture_defaults"];
    assert_eq!(defaults["pixel_format"], "Mono16", "{defaults}");
    assert_eq!(defaults["exposure_us"], 1000.0, "{defaults}");
    // An unknown key is named, not ignored.
    let (s, b) = put(r#"{"pixel_fromat": "Mono8"}"#);
    assert_eq!(s, 422, "{b}");
    assert!(b.contains("pixel_fromat"), "{b}");
}

#[test]
fn a_capture_s_settings_do_not_leak_into_the_next() {
    let dir = scratch();
    let cfg = config(dir.path(), &[]);
    let d = InProcess::start(&cfg, &dir.path().join("data"));
    let before = d.json("/camera")["capture_defaults"].clone();
    assert_eq!(before["pixel_format"], "Mono16", "{before}");
    // One capture states Mono8, 5 ms, gain 2 ...
    let c = d.run_job("/captures", r#"{"scene": "brewster-crossed", "pose": "A", "polarizer_deg": 0, "exposure_us": 5000, "gain": 2, "pixel_format": "Mono8", "frames": 2}"#, Duration::from_secs(20));
    assert_eq!(c["state"], "done", "{c}");
    assert_eq!(c["pixel_format"], "Mono8", "{c}");
    // ... the camera now reads back Mono8, but the defaults are unchanged ...
    let cam = d.json("/camera");
    assert_eq!(cam["capture_defaults"], before, "{cam}");
    // ... and a capture that states none runs with them.
    // (exposure is always the capture's own: stated, or "auto".)
    let c = d.run_job("/captures", r#"{"scene": "brewster-crossed", "pose": "A", "polarizer_deg": 0, "exposure_us": 20000, "frames": 2}"#, Duration::from_secs(20));
    assert_eq!(c["state"], "done", "{c}");
    assert_eq!(c["pixel_format"], "Mono16", "{c}");
    assert_eq!(c["gain"], before["gain"], "{c}");
    assert_eq!(c["trigger"], before["trigger"], "{c}");
    // Every setting a capture leaves out inherits the defaults the same way,
    // gain included (it used to default to 0 whatever the defaults said).
    let agent = &d.agent;
    let r = agent
        .put(format!("{}/camera/settings", d.base))
        .header("content-type", "application/json")
        .send(r#"{"gain": 3, "pixel_format": "Mono8"}"#)
        .unwrap();
    assert_eq!(r.status().as_u16(), 200);
    let c = d.run_job("/captures", r#"{"scene": "brewster-crossed", "pose": "A", "polarizer_deg": 0, "exposure_us": 20000, "frames": 2}"#, Duration::from_secs(20));
    assert_eq!(c["state"], "done", "{c}");
    assert_eq!(
        (c["gain"].as_f64(), c["pixel_format"].as_str()),
        (Some(3.0), Some("Mono8")),
        "{c}"
    );
}

#[test]
fn auto_exposure_reaches_the_planned_signal() {
    let dir = scratch();
    let cfg = config(dir.path(), &[]);
    let d = InProcess::start(&cfg, &dir.path().join("data"));

    // The plan of the rotating bench: one block per angle, the crossed one darkest.
    let plan = d.json("/scenes/brewster-rotating-3x3/exposure");
    let blocks = plan.as_array().unwrap();
    assert_eq!(blocks.len(), 4, "{plan}");
    let exposure = |b: &serde_json::Value| b["exposure_us"].as_f64().unwrap();
    let crossed = blocks
        .iter()
        .find(|b| b["channel"] == serde_json::json!({"analyzer": "sheet", "deg": 0.0}))
        .unwrap();
    assert!(
        blocks.iter().all(|b| exposure(b) <= exposure(crossed)),
        "{plan}"
    );
    for b in blocks {
        assert!(
            // 0.1 us exposure steps: 0.8 to half a step.
            (b["peak_fraction"].as_f64().unwrap() - 0.8).abs() <= 0.8 * 0.05 / exposure(b),
            "{b}"
        );
        assert!(b["snr"].as_f64().unwrap() >= 100.0, "{b}");
    }
    let (s, body) = d.get("/scenes/brewster-crossed/exposure?peak_fraction=2");
    assert_eq!(s, 422, "{body}");
    assert!(body.contains("peak_fraction = 2"), "{body}");
    assert_eq!(d.get("/scenes/nope/exposure").0, 404);

    // An automatic capture of the demo scene's crossed block.
    let plan = d.json("/scenes/brewster-crossed/exposure?peak_fraction=0.5");
    let planned = plan[0]["exposure_us"].as_f64().unwrap();
    let (s, body, loc) = d.post(
        "/captures",
        r#"{"scene": "brewster-crossed", "pose": "A", "polarizer_deg": 0, "exposure": "auto", "target": {"peak_fraction": 0.5, "snr": 50}, "frames": 2, "dark_frames": 1}"#,
    );
    assert_eq!(s, 202, "{body}");
    let accepted: serde_json::Value = serde_json::from_str(&body).unwrap();
    assert!((accepted["exposure_us"].as_f64().unwrap() - planned).abs() < 1e-6 * planned);
    assert_eq!(accepted["frames"], 2);
    let c = d.wait(&loc.unwrap(), Duration::from_secs(60));
    assert_eq!(c["state"], "done", "{c}");
    assert!((c["exposure_us"].as_f64().unwrap() - planned).abs() < 1e-6 * planned);

    // The plan is for the brightest admissible scene (l = 1); the demo shows the
    // letter, so its brightest wall element reaches 0.5 x max(T l) / max(T 1).
    let (s, tiff) = d.get_bytes(&format!("/captures/{}/mean.tiff", c["id"]));
    assert_eq!(s, 200);
    let mdir = scratch();
    std::fs::write(mdir.path().join("mean.tiff"), tiff).unwrap();
    let mean = polnlos::store::read_mean(mdir.path()).unwrap();
    let scene = Scene::builtin("brewster-crossed").unwrap().unwrap();
    let t = polnlos::transport::build(&scene, MemoryBudget::DEFAULT).unwrap();
    let (_, letter) = truth("brewster-crossed");
    let max = |v: Vec<f64>| v.into_iter().fold(0.0, f64::max);
    let expect = 0.5 * max(t.apply(&letter)) / max(t.apply(&vec![1.0; t.cols()]));
    let wall = polnlos::measure::wall_means(
        &mean,
        scene.poses()[0].homography.as_ref().unwrap(),
        &scene.wall().plane,
        "A",
    )
    .unwrap();
    let got = max(wall) / 65535.0;
    println!("auto exposure {planned:.0} us: peak {got:.4} of full scale, expected {expect:.4}");
    assert!((got / expect - 1.0).abs() < 0.03, "peak {got} vs {expect}");

    // Both or neither: a clear refusal.
    let (s, body, _) = d.post(
        "/captures",
        r#"{"scene": "brewster-crossed", "pose": "A", "polarizer_deg": 0, "exposure": "auto", "exposure_us": 1000}"#,
    );
    assert_eq!(s, 422, "{body}");
    assert!(body.contains("not both"), "{body}");
    // Neither: the exposure is inherited from the capture defaults, as
    // every camera setting is (it was a 422 before).
    let (_, camera) = d.get("/camera");
    let camera: serde_json::Value = serde_json::from_str(&camera).unwrap();
    let default = camera["capture_defaults"]["exposure_us"].as_f64().unwrap();
    let (s, body, _) = d.post(
        "/captures",
        r#"{"scene": "brewster-crossed", "pose": "A", "polarizer_deg": 0}"#,
    );
    assert_eq!(s, 202, "{body}");
    let accepted: serde_json::Value = serde_json::from_str(&body).unwrap();
    assert_eq!(accepted["exposure_us"].as_f64(), Some(default), "{body}");
}

#[test]
fn one_reconstruction_path_fista_and_lambda_from_a_single_frame() {
    let dir = scratch();
    let cfg = config(dir.path(), &[]);
    let d = InProcess::start(&cfg, &dir.path().join("data"));
    // One frame: no frame-to-frame variance, so the noise comes from the residual.
    let c = d.run_job(
        "/captures",
        r#"{"scene": "brewster-crossed", "pose": "A", "polarizer_deg": 0, "exposure_us": 20000, "frames": 1, "dark_frames": 2}"#,
        Duration::from_secs(30),
    );
    assert_eq!(c["state"], "done", "{c}");
    // Every solver the API document lists (the library's registry), so a
    // new one is run here with no edit; the TV solvers choose λ.
    let spec = d.json("/openapi.json");
    let solvers: Vec<String> = spec["components"]["schemas"]["Solver"]["enum"]
        .as_array()
        .expect("the Solver schema lists the solvers")
        .iter()
        .map(|s| s.as_str().unwrap().to_string())
        .collect();
    assert!(
        solvers.len() >= 5 && solvers.contains(&"gp-tv".to_string()),
        "{solvers:?}"
    );
    for solver in &solvers {
        let body = serde_json::json!({ "scene": "brewster-crossed", "captures": [c["id"]], "solver": solver, "truth": "letter" }).to_string();
        let r = d.run_job("/reconstructions", &body, Duration::from_secs(120));
        assert_eq!(r["state"], "done", "{r}");
        assert_eq!(r["solver"], solver.as_str());
        let choice = &r["report"]["lambda_choice"];
        if !solver.ends_with("-tv") {
            println!("{solver}: PSNR {} dB", r["report"]["metrics"]["psnr_db"]);
            assert!(choice.is_null(), "{r}");
            continue;
        }
        assert_eq!(choice["noise"], "residual", "{r}");
        assert_eq!(r["report"]["solver"]["lambda"], choice["lambda"]);
        let psnr = r["report"]["metrics"]["psnr_db"].as_f64().unwrap();
        println!("{solver}: PSNR {psnr:.2} dB, lambda {}", choice["lambda"]);
        // One 20 ms frame under the sensor's shot and read noise (ADMM 13.8 dB
        // measured): clearly better than the best featureless guess, the
        // truth's own mean everywhere.
        let (_, t) = truth("brewster-crossed");
        let mean = t.iter().sum::<f64>() / t.len() as f64;
        let grey = metrics::psnr(&t, &vec![mean; t.len()]);
        println!("uniform guess {grey:.2} dB");
        assert!(
            psnr > grey + 3.0,
            "{solver}: {psnr} dB, uniform guess {grey:.2} dB"
        );
    }
    // Without dark subtraction the camera's dark level is an offset T cannot
    // fit: the report says so.
    let raw = d.run_job(
        "/captures",
        r#"{"scene": "brewster-crossed", "pose": "A", "polarizer_deg": 0, "exposure_us": 20000}"#,
        Duration::from_secs(30),
    );
    let body =
        serde_json::json!({ "scene": "brewster-crossed", "captures": [raw["id"]] }).to_string();
    let r = d.run_job("/reconstructions", &body, Duration::from_secs(120));
    assert!(
        r["report"]["warnings"]
            .to_string()
            .contains("no dark subtraction"),
        "{r}"
    );
    let (s, b, _) = d.post(
        "/reconstructions",
        &format!(
            r#"{{"scene": "brewster-crossed", "captures": [{}], "solver": "magic"}}"#,
            c["id"]
        ),
    );
    assert_eq!(s, 422, "{b}");
    assert!(b.contains("fista-tv"), "the error lists the solvers: {b}");
}

#[test]
fn cancel_stops_a_running_capture_promptly_and_keeps_nothing_of_it() {
    let _g = lock();
    let dir = scratch();
    let cfg = config(dir.path(), &[]);
    let data = dir.path().join("data");
    let d = Daemon::start(&cfg, &data);
    // 150 frames of 20 ms through Aravis's fake camera (3 s) after 4 dark
    // frames, and one queued behind it.
    let long = r#"{"scene": "brewster-crossed", "pose": "A", "polarizer_deg": 0, "exposure_us": 20000, "frames": 150, "dark_frames": 4}"#;
    let (s, b, running) = d.post("/captures", long);
    assert_eq!(s, 202, "{b}");
    let (s, b, queued) = d.post("/captures", long);
    assert_eq!(s, 202, "{b}");
    let (running, queued) = (running.unwrap(), queued.unwrap());
    let t = Instant::now();
    while d.json(&running)["frames_taken"].as_i64().unwrap_or(0) < 5 {
        assert!(t.elapsed() < Duration::from_secs(20), "no frames");
        std::thread::sleep(Duration::from_millis(20));
    }

    // The queued one is cancelled at once and never runs.
    let (s, b) = d.delete("/jobs/capture-2");
    assert_eq!(s, 200, "{b}");
    assert_eq!(
        serde_json::from_str::<serde_json::Value>(&b).unwrap()["state"],
        "cancelled"
    );

    // The running one stops within a frame or two, not after 150.
    let t = Instant::now();
    let (s, b) = d.delete("/jobs/capture-1");
    let took = t.elapsed();
    assert_eq!(s, 200, "{b}");
    let c: serde_json::Value = serde_json::from_str(&b).unwrap();
    assert_eq!(c["state"], "cancelled", "{c}");
    let taken = c["frames_taken"].as_i64().unwrap();
    println!("cancelled after {taken} of 150 frames; DELETE answered in {took:?}");
    assert!(taken < 100, "{c}");
    assert!(took < Duration::from_millis(1500), "{took:?}");
    // Nothing half-written is kept: no frame file, no dark frames (complete
    // before the light frames began, of no use without them), no temporary.
    let files: Vec<String> = std::fs::read_dir(data.join("captures/1"))
        .map(|r| {
            r.map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
                .collect()
        })
        .unwrap_or_default();
    assert!(files.is_empty(), "{files:?}");
    assert_eq!(d.get("/captures/1/frame.tiff").0, 404);
    assert_eq!(d.json(&queued)["state"], "cancelled");
    assert_eq!(d.json(&queued)["started_at"], serde_json::Value::Null);

    // An ended job cannot be cancelled; an unknown one is not found.
    let (s, b) = d.delete("/jobs/capture-1");
    assert_eq!(s, 409, "{b}");
    assert!(b.contains("is cancelled; only queued or running"), "{b}");
    assert_eq!(d.delete("/jobs/capture-99").0, 404);
    assert_eq!(d.delete("/jobs/frame-1").0, 404);

    // The camera is free and works; the cancellations are counted.
    let c = d.run_job("/captures", r#"{"scene": "brewster-crossed", "pose": "A", "polarizer_deg": 0, "exposure_us": 20000, "frames": 2}"#, Duration::from_secs(20));
    assert_eq!(c["state"], "done", "{c}");
    // Its own frame counts, not the camera's since the start (which include
    // the cancelled capture's). Under the suite's load the stream thread can
    // be starved and a frame arrive broken: counted, and replaced.
    assert_eq!(c["frame_counts"]["received"], 2, "{c}");
    assert_eq!(c["frame_counts"]["dropped"], 0, "{c}");
    // A solver stopped at its cap says how to raise it in a request too.
    let r = d.run_job(
        "/reconstructions",
        r#"{"scene": "brewster-crossed", "captures": [3], "solver": "fista-tv", "lambda": 0.001, "max_iter": 3}"#,
        Duration::from_secs(60),
    );
    assert_eq!(r["state"], "done", "{r}");
    let warnings = r["report"]["warnings"].to_string();
    assert!(
        warnings.contains(r#"\"max_iter\" / \"tol\" in a request"#),
        "{warnings}"
    );
    let (_, metrics) = d.get("/metrics");
    // The log says what each job did, with its id and how long it took.
    let log = std::fs::read_to_string(data.with_extension("log")).unwrap();
    for line in [
        "capture-1 queued: brewster-crossed pose A at 0°, 150 frames + 4 dark of 20000 us",
        "capture-1 started",
        "capture-2 cancelled while queued",
        "capture-1: cancel asked while it runs",
        "job ended job=capture-1 outcome=\"cancelled\" seconds=",
        "capture-3 started",
        // Broken buffers are counted but not asserted here: under the
        // suite's load Aravis can hand back a burst of never-filled
        // ("Cleared") buffers right after a cancelled acquisition.
        "job{id=capture-3}: polnlos::daemon::jobs::capture: 2 frames received, 0 dropped, ",
        "job ended job=capture-3 outcome=\"done\" seconds=",
        "reconstruction-1 queued: brewster-crossed of captures [3], fista-tv",
        "reconstruction-1 started",
        "job ended job=reconstruction-1 outcome=\"done\" seconds=",
        // Each request, with its number, method, path, status and latency:
        // a refusal as a warning, an answer at info.
        " method=DELETE path=/jobs/capture-1}: polnlos::api: refused status=409 latency_ms=",
        " method=GET path=/metrics}: polnlos::api: answered status=200 latency_ms=",
    ] {
        assert!(log.contains(line), "no {line:?} in the log:\n{log}");
    }
    let refused = log
        .lines()
        .find(|l| l.contains("path=/jobs/capture-1}: polnlos::api: refused status=409"))
        .unwrap_or_default();
    assert!(refused.contains("request{id="), "{refused}");
    assert!(
        metrics.contains("polnlos_jobs_cancelled_total 2"),
        "{metrics}"
    );

    // Raw frames left in a cancelled capture's folder (a daemon stopped
    // before it could remove them) are removed at the next start; a done
    // capture's are kept.
    std::fs::create_dir_all(data.join("captures/2")).unwrap();
    std::fs::write(data.join("captures/2/dark.tiff"), b"left behind").unwrap();
    drop(d);
    let d = Daemon::start(&cfg, &data);
    assert!(!data.join("captures/2/dark.tiff").exists());
    assert!(data.join("captures/3/frames.tiff").exists());
    assert_eq!(d.json("/captures/3")["state"], "done");
}

#[test]
fn a_target_capture_through_aravis_calibrates_the_pose() {
    let _g = lock();
    let dir = scratch();
    let cfg = config(dir.path(), &[]);
    let d = Daemon::start(&cfg, &dir.path().join("data"));
    let c = d.run_job("/captures", r#"{"kind": "target", "scene": "brewster-multi", "pose": "C", "polarizer_deg": 0, "exposure_us": 20000, "frames": 4, "dark_frames": 2}"#, Duration::from_secs(30));
    assert_eq!(c["state"], "done", "{c}");
    let (s, b, _) = d.post("/calibrations", r#"{"capture": 1}"#);
    assert_eq!(s, 200, "{b}");
    // JSON Schema calls 1.0 an integer, so a generated client may send it.
    let (s, b1, _) = d.post("/calibrations", r#"{"capture": 1.0}"#);
    assert_eq!(s, 200, "{b1}");
    let (s, b2, _) = d.post("/calibrations", r#"{"capture": 1.5}"#);
    assert_eq!(s, 422, "{b2}");
    assert!(b2.contains("whole number"), "{b2}");
    let cal: serde_json::Value = serde_json::from_str(&b).unwrap();
    println!(
        "pose C: {} dots, RMS {:.3} px, largest {:.3} px",
        cal["dots"], cal["rms_px"], cal["max_px"]
    );
    let fitted: [[f64; 3]; 3] = serde_json::from_value(cal["homography"].clone()).unwrap();
    let fitted = polnlos::scene::Homography::new(fitted).unwrap();
    let shipped = Scene::builtin("brewster-multi").unwrap().unwrap();
    let h = shipped.pose("C").unwrap().homography.unwrap();
    let target = polnlos::calibrate::geometry::Target::default_target();
    let worst = polnlos::calibrate::geometry::max_distance(&fitted, &h, &target.dots);
    println!("largest distance from the shipped homography at the dots: {worst:.3} px");
    assert!(worst < 0.3, "{worst}");
    assert!(cal["rms_px"].as_f64().unwrap() < 0.2, "{cal}");
    // 4 frames: the centroid noise is known, so the fit says whether the
    // homography explains the dots to it.
    println!(
        "model check: {} warnings: {}",
        cal["model_check"], cal["warnings"]
    );
    assert!(
        cal["model_check"]["chi2_per_dof"].as_f64().is_some(),
        "{cal}"
    );
    // The fake target is noiseless (centroid noise ~4e-6 px, the digitizer's
    // rounding), so the centroids' perspective bias (~0.05 px) is far above
    // it: the answer says so, with the absolute numbers.
    assert_eq!(cal["model_check"]["explained"], false, "{cal}");
    let w = cal["warnings"][0].as_str().unwrap();
    assert!(
        w.contains("does not explain the dots") && w.contains("reprojection RMS 0.0"),
        "{w}"
    );
    // The scene file to review parses and carries the fit.
    let s = Scene::from_toml_str(cal["scene_toml"].as_str().unwrap()).unwrap();
    let written = s.pose("C").unwrap().homography.unwrap().matrix();
    for (a, b) in written
        .iter()
        .flatten()
        .zip(fitted.matrix().iter().flatten())
    {
        assert!((a - b).abs() <= 1e-9 * b.abs().max(1.0), "{a} vs {b}");
    }
    // A capture of the scene, not of the target, is refused with a reason.
    let light = d.run_job("/captures", r#"{"scene": "brewster-multi", "pose": "C", "polarizer_deg": 0, "exposure_us": 20000, "frames": 1}"#, Duration::from_secs(30));
    let (s, b, _) = d.post(
        "/calibrations",
        &format!(r#"{{"capture": {}}}"#, light["id"]),
    );
    assert_eq!(s, 422, "{b}");
    assert!(
        b.contains("needs a done \\\"kind\\\": \\\"target\\\" capture"),
        "{b}"
    );
    // A target capture cannot be reconstructed.
    let (s, b, _) = d.post(
        "/reconstructions",
        r#"{"scene": "brewster-multi", "captures": [1, 2]}"#,
    );
    assert_eq!(s, 422, "{b}");
    // A catalogue row that cannot be read (a column of the wrong type, written
    // behind the daemon's back) is a 500 naming the capture, not a 404.
    let db = rusqlite::Connection::open(dir.path().join("data/catalogue.sqlite")).unwrap();
    db.execute("UPDATE captures SET frames = 'four' WHERE id = 1", [])
        .unwrap();
    let (s, b, _) = d.post("/calibrations", r#"{"capture": 1}"#);
    println!("unreadable row: {s} {b}");
    assert_eq!(s, 500, "{b}");
    assert!(
        b.contains("capture 1: the catalogue could not be read"),
        "{b}"
    );
    assert!(b.contains("\"error\":\"internal\""), "{b}");
    let (s, b, _) = d.post(
        "/reconstructions",
        r#"{"scene": "brewster-multi", "captures": [1, 2]}"#,
    );
    assert_eq!(s, 500, "{b}");
    assert!(!b.contains("no capture"), "{b}");
    // The list shows the other captures; the damaged one is logged and named
    // in the answer's header, not listed.
    assert_eq!(
        d.get_header("/captures", "polnlos-unreadable").as_deref(),
        Some("1")
    );
    let list = d.json("/captures");
    let ids: Vec<i64> = list
        .as_array()
        .unwrap()
        .iter()
        .map(|c| c["id"].as_i64().unwrap())
        .collect();
    assert_eq!(ids, [2], "{list}");
    // Mended, the same capture calibrates again.
    db.execute("UPDATE captures SET frames = 4 WHERE id = 1", [])
        .unwrap();
    assert_eq!(d.get_header("/captures", "polnlos-unreadable"), None);
    let (s, b, _) = d.post("/calibrations", r#"{"capture": 1}"#);
    assert_eq!(s, 200, "{b}");
}

#[test]
fn source_captures_through_aravis_calibrate_the_wall_and_the_gain() {
    let _g = lock();
    let dir = scratch();
    let cfg = config(dir.path(), &[]);
    let d = Daemon::start(&cfg, &dir.path().join("data"));
    // A done source capture of pose A (crossed), 20 ms per frame. The 5 mm
    // source lights the wall faintly: under the sensor's noise 32 frames
    // cannot tell its position from another, 320 can (6.4 s of light; 200 ms
    // frames would do as well but stall under the suite's load).
    let source_capture = |frames: u32, dark_frames: u32| {
        let c = d.run_job("/captures", &format!(r#"{{"kind": "source", "scene": "brewster-crossed", "pose": "A", "polarizer_deg": 0, "exposure_us": 20000, "frames": {frames}, "dark_frames": {dark_frames}}}"#), Duration::from_secs(60));
        assert_eq!(c["state"], "done", "{c}");
    };
    // The fake bench's point source at [0.03, -0.02], seen from pose A.
    source_capture(320, 32);
    let (s, b, _) = d.post(
        "/calibrations/wall",
        r#"{"scene": "brewster-crossed", "captures": [1], "source": [0.03, -0.02]}"#,
    );
    assert_eq!(s, 200, "{b}");
    let v: serde_json::Value = serde_json::from_str(&b).unwrap();
    println!("{}", serde_json::to_string_pretty(&v["fit"]).unwrap());
    let p = |k: &str| v["fit"]["params"][k].as_f64().unwrap();
    let configured = v["configured_gain"].as_f64().unwrap();
    println!(
        "gain {} against the demo calibration {configured}",
        p("gain")
    );
    // The demo wall: alpha 0.3, ior 1.5, kd 0; the source has unit radiance,
    // so its gain is the demo's radiometric calibration.
    assert!((p("alpha") - 0.3).abs() < 0.03, "{v}");
    assert!((p("ior") - 1.5).abs() < 0.1, "{v}");
    assert!(p("kd") < 0.01, "{v}");
    // The gain within 3 of its reported standard errors (12 % measured: the
    // 32 dark frames' noise dominates), and those errors small enough to
    // calibrate with.
    let sigma_gain = v["fit"]["sigma"]["gain"].as_f64().unwrap();
    assert!((p("gain") - configured).abs() < 3.0 * sigma_gain, "{v}");
    assert!(sigma_gain < 0.15 * configured, "{v}");
    // No warning but a count of frames lost to the suite's load (broken
    // and replaced, said in the same sentence as in a capture's report).
    let warnings = v["warnings"].as_array().expect("warnings is a list");
    assert!(
        warnings.iter().all(|w| w
            .as_str()
            .is_some_and(|w| w.contains("besides the") && w.contains("received whole"))),
        "{v}"
    );
    assert!(
        v["fit"].get("warnings").is_none(),
        "said once, at the top: {v}"
    );
    // 320 frames: the model check is against the frame variance, and the
    // fake bench (rendered with the absorbing sheet) is explained by it; the
    // transmitting reading fits no better (under this noise the two differ
    // by less than chi2/dof's own spread, sqrt(2 / dof) = 0.044).
    let check = &v["fit"]["model_check"];
    assert_eq!(check["explained"], true, "{check}");
    let models = v["fit"]["polarizer_models"].as_array().unwrap();
    assert_eq!(models[0]["model"], "absorbing", "{v}");
    assert_eq!(models[0]["used"], true, "{v}");
    assert_eq!(models[1]["model"], "transmitting", "{v}");
    let chi2 = |m: &serde_json::Value| m["chi2_per_dof"].as_f64().unwrap_or(f64::NAN);
    let spread = (2.0 / check["dof"].as_f64().unwrap_or(1.0)).sqrt();
    assert!(chi2(&models[1]) > chi2(&models[0]) - 2.0 * spread, "{v}");
    // The wrong source position is refused, not fitted.
    let (s, b, _) = d.post(
        "/calibrations/wall",
        r#"{"scene": "brewster-crossed", "captures": [1], "source": [-0.06, 0.06]}"#,
    );
    assert_eq!(s, 422, "{b}");
    assert!(b.contains("do not match the capture"), "{b}");
    assert!(!b.contains("dots"), "{b}");
    // Two captures of the source, given as two positions (the fake bench has
    // one): fitted together, each position with its own residual.
    source_capture(320, 32);
    let two = r#"{"scene": "brewster-crossed", "sources": [{"source": [0.03, -0.02], "captures": [1]}, {"source": [0.03, -0.02], "captures": [2]}]}"#;
    let (s, b, _) = d.post("/calibrations/wall", two);
    assert_eq!(s, 200, "{b}");
    let v: serde_json::Value = serde_json::from_str(&b).unwrap();
    let positions = v["positions"].as_array().unwrap();
    assert_eq!(positions.len(), 2, "{v}");
    assert_eq!(positions[1]["captures"], serde_json::json!([2]), "{v}");
    // Each within the accepted 25 % beyond the noise (11 % and 16 %
    // measured; the wrong position above is refused).
    for p in positions {
        assert!(p["relative_residual"].as_f64().unwrap() < 0.25, "{v}");
    }
    assert_eq!(v["captures"], serde_json::json!([1, 2]), "{v}");
    assert!((param(&v, "alpha") - 0.3).abs() < 0.03, "{v}");
    // One misplaced position among two is named.
    let (s, b, _) = d.post(
        "/calibrations/wall",
        &two.replacen(
            "[0.03, -0.02], \"captures\": [2]",
            "[-0.06, 0.06], \"captures\": [2]",
            1,
        ),
    );
    assert_eq!(s, 422, "{b}");
    assert!(b.contains("source at (-0.06, 0.06) m"), "{b}");
    // A capture at two positions, and more captures than blocks, are refused.
    let (s, b, _) = d.post(
        "/calibrations/wall",
        r#"{"scene": "brewster-crossed", "sources": [{"source": [0.03, -0.02], "captures": [1]}, {"source": [0.03, -0.02], "captures": [1]}]}"#,
    );
    assert_eq!(s, 422, "{b}");
    assert!(b.contains("capture 1 is given twice"), "{b}");
    let (s, b, _) = d.post(
        "/calibrations/wall",
        r#"{"scene": "brewster-crossed", "captures": [1, 2], "source": [0.03, -0.02]}"#,
    );
    assert_eq!(s, 422, "{b}");
    assert!(
        b.contains("captures 1 and 2 are both for block pose A at 0°"),
        "{b}"
    );
    // A source capture without dark frames: its offset leaves the fit
    // refused, and the refusal names the missing dark subtraction.
    source_capture(8, 0);
    let (s, b, _) = d.post(
        "/calibrations/wall",
        r#"{"scene": "brewster-crossed", "captures": [3], "source": [0.03, -0.02]}"#,
    );
    assert_eq!(s, 422, "{b}");
    // After "Also:", other notes may come first (under load the fake
    // camera can hand back broken frames, which the refusal also names).
    let also = b.split_once("Also: ").map_or("", |(_, rest)| rest);
    assert!(also.contains("capture 3 has no dark subtraction"), "{b}");
}

/// A fitted wall parameter of a `POST /calibrations/wall` answer.
fn param(v: &serde_json::Value, k: &str) -> f64 {
    v["fit"]["params"][k].as_f64().unwrap()
}

#[test]
fn captures_and_reconstructions_can_be_deleted_with_their_files() {
    let dir = scratch();
    let cfg = config(dir.path(), &[]);
    let data = dir.path().join("data");
    let d = InProcess::start(&cfg, &data);
    let capture = r#"{"scene": "brewster-crossed", "pose": "A", "polarizer_deg": 0, "exposure_us": 20000, "frames": 2, "dark_frames": 1}"#;
    for _ in 0..2 {
        let c = d.run_job("/captures", capture, Duration::from_secs(20));
        assert_eq!(c["state"], "done", "{c}");
    }
    let r = d.run_job(
        "/reconstructions",
        r#"{"scene": "brewster-crossed", "captures": [1]}"#,
        Duration::from_secs(30),
    );
    assert_eq!(r["state"], "done", "{r}");
    assert!(data.join("captures/1").is_dir() && data.join("reconstructions/1").is_dir());
    // A capture a kept reconstruction uses is refused, naming it.
    let (s, b) = d.delete("/captures/1");
    assert_eq!(s, 409, "{b}");
    assert!(b.contains("reconstruction 1 uses it"), "{b}");
    assert!(data.join("captures/1/mean.tiff").is_file());
    // A capture nothing uses goes, row and files.
    let (s, b) = d.delete("/captures/2");
    assert_eq!(s, 200, "{b}");
    assert!(!data.join("captures/2").exists());
    assert_eq!(d.get("/captures/2").0, 404);
    let ids: Vec<i64> = d
        .json("/captures")
        .as_array()
        .unwrap()
        .iter()
        .map(|c| c["id"].as_i64().unwrap())
        .collect();
    assert_eq!(ids, [1]);
    // Asked for, the capture goes with the reconstructions that use it.
    let (s, b) = d.delete("/captures/1?with_reconstructions=true");
    assert_eq!(s, 200, "{b}");
    let v: serde_json::Value = serde_json::from_str(&b).unwrap();
    assert_eq!(v["reconstructions"], serde_json::json!([1]), "{v}");
    assert!(!data.join("captures/1").exists() && !data.join("reconstructions/1").exists());
    assert_eq!(d.get("/reconstructions/1").0, 404);
    assert_eq!(d.delete("/captures/1").0, 404);
    // A running capture is refused until cancelled; a reconstruction alone goes.
    let (s, b, loc) = d.post("/captures", r#"{"scene": "brewster-crossed", "pose": "A", "polarizer_deg": 0, "exposure_us": 20000, "frames": 150}"#);
    assert_eq!(s, 202, "{b}");
    let id = d.json(&loc.clone().unwrap())["id"].as_i64().unwrap();
    let (s, b) = d.delete(&format!("/captures/{id}"));
    assert_eq!(s, 409, "{b}");
    assert!(b.contains("cancel it first"), "{b}");
    assert_eq!(d.delete(&format!("/jobs/capture-{id}")).0, 200);
    let (s, b) = d.delete(&format!("/captures/{id}"));
    assert_eq!(s, 200, "{b}");
    let c = d.run_job("/captures", capture, Duration::from_secs(20));
    let r = d.run_job(
        "/reconstructions",
        &format!(
            r#"{{"scene": "brewster-crossed", "captures": [{}]}}"#,
            c["id"]
        ),
        Duration::from_secs(30),
    );
    let (s, b) = d.delete(&format!("/reconstructions/{}", r["id"]));
    assert_eq!(s, 200, "{b}");
    assert!(!data.join(format!("reconstructions/{}", r["id"])).exists());
    assert!(data
        .join(format!("captures/{}/mean.tiff", c["id"]))
        .is_file());
    // A deletion a stopped daemon left half done is finished or undone by
    // the row at the next start: a parked folder whose row exists comes
    // back, one whose row is gone is removed.
    let kept = data.join(format!("captures/{}", c["id"]));
    drop(d);
    std::fs::rename(&kept, kept.with_file_name(format!("{}.deleting", c["id"]))).unwrap();
    std::fs::create_dir_all(data.join("captures/999.deleting")).unwrap();
    let d = InProcess::start(&cfg, &data);
    assert!(
        kept.join("mean.tiff").is_file(),
        "the kept capture's files came back"
    );
    assert!(!data.join("captures/999.deleting").exists());
    assert_eq!(d.json(&format!("/captures/{}", c["id"]))["state"], "done");
    // An id is never issued twice (issue 31): the newest capture deleted, the
    // next one gets a new id, and again after a restart; likewise reconstructions.
    let newest = c["id"].as_i64().unwrap();
    assert_eq!(d.delete(&format!("/captures/{newest}")).0, 200);
    let next = d.run_job("/captures", capture, Duration::from_secs(20));
    assert_eq!(next["id"].as_i64(), Some(newest + 1), "{next}");
    assert_eq!(d.delete(&format!("/captures/{}", newest + 1)).0, 200);
    drop(d);
    let d = InProcess::start(&cfg, &data);
    let after = d.run_job("/captures", capture, Duration::from_secs(20));
    assert_eq!(after["id"].as_i64(), Some(newest + 2), "{after}");
    let again = d.run_job(
        "/reconstructions",
        &format!(
            r#"{{"scene": "brewster-crossed", "captures": [{}]}}"#,
            newest + 2
        ),
        Duration::from_secs(30),
    );
    assert_eq!(
        again["id"].as_i64(),
        r["id"].as_i64().map(|i| i + 1),
        "{again}"
    );
}

#[test]
fn retention_deletes_the_oldest_finished_captures_never_a_running_one() {
    use std::io::BufRead;
    let dir = scratch();
    // 3 MiB for all data, checked every 0.2 s; a 256x256 capture of 4 frames
    // and 2 dark frames takes about 1.3 MB.
    let cfg = config(
        dir.path(),
        &[
            ("max_total_mib = 0", "max_total_mib = 3"),
            ("check_every_s = 60", "check_every_s = 0.2"),
        ],
    );
    let data = dir.path().join("data");
    let d = InProcess::start(&cfg, &data);
    let agent: ureq::Agent = ureq::Agent::config_builder()
        .timeout_global(Some(Duration::from_secs(40)))
        .build()
        .into();
    let url = format!("{}/events", d.base);
    let events = std::thread::spawn(move || {
        let mut r = agent.get(url).call().unwrap();
        let lines = std::io::BufReader::new(r.body_mut().as_reader()).lines();
        let mut deleted = Vec::new();
        for line in lines.map_while(Result::ok) {
            if let Some(data) = line.strip_prefix("data: ") {
                let v: serde_json::Value = serde_json::from_str(data).unwrap();
                if v["type"] == "deleted" {
                    deleted.push(v.clone());
                    if v["id"] == 2 {
                        break;
                    }
                }
            }
        }
        deleted
    });
    std::thread::sleep(Duration::from_millis(300));
    // Target captures: a light one must hold the wall (the whole 512 x 512 frame).
    let small = r#"{"scene": "brewster-crossed", "pose": "A", "polarizer_deg": 0, "kind": "target", "exposure_us": 20000, "frames": 4, "dark_frames": 2, "region": [0, 0, 256, 256]}"#;
    for _ in 0..3 {
        let c = d.run_job("/captures", small, Duration::from_secs(20));
        assert_eq!(c["state"], "done", "{c}");
    }
    let ids = |d: &Client| -> Vec<i64> {
        d.json("/captures")
            .as_array()
            .unwrap()
            .iter()
            .map(|c| c["id"].as_i64().unwrap())
            .collect()
    };
    let until = |want: &[i64]| {
        let t0 = Instant::now();
        while ids(&d) != want && t0.elapsed() < Duration::from_secs(10) {
            std::thread::sleep(Duration::from_millis(100));
        }
        assert_eq!(ids(&d), want);
    };
    // 3 captures take ~3.9 MB > 3 MiB: the oldest goes, files and row.
    until(&[3, 2]);
    assert!(!data.join("captures/1").exists() && data.join("captures/2/mean.tiff").is_file());
    // A long capture grows past the limit while it runs: the oldest finished
    // capture goes, the newest finished one and the running one stay.
    let (s, b, loc) = d.post(
        "/captures",
        r#"{"scene": "brewster-crossed", "pose": "A", "polarizer_deg": 0, "kind": "target", "exposure_us": 20000, "frames": 200, "region": [0, 0, 256, 256]}"#,
    );
    assert_eq!(s, 202, "{b}");
    let loc = loc.unwrap();
    until(&[4, 3]);
    assert_eq!(d.json(&loc)["state"], "running");
    let deleted = events.join().unwrap();
    assert_eq!(
        deleted,
        vec![
            serde_json::json!({"type": "deleted", "kind": "capture", "id": 1, "reason": "retention"}),
            serde_json::json!({"type": "deleted", "kind": "capture", "id": 2, "reason": "retention"}),
        ]
    );
    let (s, _) = d.delete("/jobs/capture-4");
    assert_eq!(s, 200);
}

#[test]
fn the_live_view_shows_a_fresh_frame_before_any_capture_with_its_levels() {
    let dir = scratch();
    let cfg = config(dir.path(), &[]);
    let d = InProcess::start(&cfg, &dir.path().join("data"));
    assert_eq!(d.json("/camera")["connected"], true);
    // Without live=true there is no frame before a capture...
    assert_eq!(d.get("/camera/frame.png").0, 404);
    // ...with it, the idle camera takes one at the capture defaults.
    let (s, plain) = d.get_bytes("/camera/frame.png?live=true");
    assert_eq!((s, &plain[1..4]), (200, &b"PNG"[..]));
    let levels: serde_json::Value = serde_json::from_str(
        &d.get_header("/camera/frame.png?live=true", "polnlos-levels")
            .unwrap(),
    )
    .unwrap();
    let hist: u64 = levels["histogram"]
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v.as_u64().unwrap())
        .sum();
    assert_eq!(hist, 512 * 512, "{levels}");
    assert_eq!(levels["histogram"].as_array().unwrap().len(), 64);
    let (peak, low, high) = (
        levels["peak"].as_f64().unwrap(),
        levels["low"].as_u64().unwrap(),
        levels["high"].as_u64().unwrap(),
    );
    assert!(peak > 0.0 && peak < 1.0 && high > low, "{levels}");
    // Neither the stretch nor the histogram is narrower than 1/512 of full
    // scale: a DN of noise is not shown as black and white.
    let (h_lo, h_hi) = (
        levels["histogram_low"].as_u64().unwrap(),
        levels["histogram_high"].as_u64().unwrap(),
    );
    assert!(high - low >= 127 && h_hi - h_lo >= 127, "{levels}");
    assert!(h_lo <= low && high <= h_hi.max(high), "{levels}");
    // The idle camera sees the lit wall, as on a real bench (issue 38: it
    // showed the dark level, a flat grey, until the first capture), so the
    // view can aim: stretched, the wall's image spans most of the range.
    let (s, stretched) = d.get_bytes("/camera/frame.png?live=true&stretch=true");
    assert_eq!(s, 200);
    let range16 = |png: &[u8]| {
        let img = crate::png::decode(png);
        let v = img.grey();
        (*v.iter().min().unwrap(), *v.iter().max().unwrap())
    };
    let (lo, hi) = range16(&stretched);
    println!("idle live view, stretched: {lo}..{hi}; levels {levels}");
    assert!(hi - lo > 30_000, "{lo}..{hi}: {levels}");
    assert!(
        range16(&plain).1 < 65535,
        "the crossed frame does not reach full scale"
    );
    // An unknown query key is refused, naming it.
    let (s, b) = d.get("/camera/frame.png?zoom=4");
    assert_eq!(s, 400, "{b}");
}

#[test]
fn a_capture_records_its_saturated_pixels_and_a_sane_exposure_has_none() {
    let dir = scratch();
    let cfg = config(dir.path(), &[]);
    let d = InProcess::start(&cfg, &dir.path().join("data"));
    let capture = |deg: u32, exposure_us: u32| {
        d.run_job(
            "/captures",
            &format!(
                r#"{{"scene": "brewster-rotating", "pose": "A", "polarizer_deg": {deg}, "exposure_us": {exposure_us}, "frames": 2, "pixel_format": "Mono16"}}"#
            ),
            Duration::from_secs(60),
        )
    };
    // The glare block (polarizer parallel) at five times the planned exposure.
    let over = capture(90, 100_000);
    assert_eq!(over["state"], "done", "{over}");
    let cl = &over["clipping"];
    let saturated = cl["saturated"].as_u64().unwrap();
    println!("100 ms at 90 degrees: {cl}");
    assert!(saturated > 1000, "{over}");
    assert_eq!(cl["frames_saturated"], 2, "{over}");
    assert_eq!(cl["pixels"], 512 * 512, "{over}");
    // The same block at the exposure the daemon plans for it has none.
    let (s, plan) = d.get("/scenes/brewster-rotating/exposure");
    assert_eq!(s, 200, "{plan}");
    let sane = capture(90, 5_000);
    assert_eq!(sane["state"], "done", "{sane}");
    assert_eq!(sane["clipping"]["saturated"], 0, "{sane}; plan {plan}");
}

#[test]
fn a_reconstruction_from_saturated_captures_says_so_first() {
    let dir = scratch();
    let cfg = config(
        dir.path(),
        &[(
            "scene = \"brewster-crossed\"",
            "scene = \"brewster-rotating\"",
        )],
    );
    let d = InProcess::start(&cfg, &dir.path().join("data"));
    let long = Duration::from_secs(120);
    let mut ids = Vec::new();
    for (deg, exposure_us) in [(0, 100_000), (45, 100_000), (90, 100_000), (135, 100_000)] {
        let c = d.run_job(
            "/captures",
            &format!(r#"{{"scene": "brewster-rotating", "pose": "A", "polarizer_deg": {deg}, "exposure_us": {exposure_us}, "frames": 2, "dark_frames": 1}}"#),
            long,
        );
        assert_eq!(c["state"], "done", "{c}");
        ids.push(c["id"].as_i64().unwrap());
    }
    let r = d.run_job(
        "/reconstructions",
        &format!(r#"{{"scene": "brewster-rotating", "captures": {ids:?}, "truth": "letter"}}"#),
        long,
    );
    assert_eq!(r["state"], "done", "{r}");
    let warnings: Vec<String> = r["report"]["warnings"]
        .as_array()
        .unwrap()
        .iter()
        .map(|w| w.as_str().unwrap().to_string())
        .collect();
    // The crossed block (0 degrees) did not saturate; the other three did,
    // and their warnings lead, in capture order.
    let saturated: Vec<&String> = warnings
        .iter()
        .filter(|w| w.starts_with("capture ") && w.contains("saturated"))
        .collect();
    assert_eq!(saturated.len(), 3, "{warnings:#?}");
    for (w, id) in warnings.iter().take(3).zip(&ids[1..]) {
        assert!(
            w.starts_with(&format!("capture {id} saturated: "))
                && w.contains("lower exposure_us")
                && w.contains("left out of their elements' means"),
            "{warnings:#?}"
        );
    }
    assert!(
        warnings
            .iter()
            .any(|w| w.contains("wall elements were not measured")),
        "{warnings:#?}"
    );
    println!("{}", warnings.join("\n"));
    // The stored measurement marks those elements NaN, as many as it says,
    // so an offline re-solve leaves them out again.
    let lost: usize = warnings
        .iter()
        .find_map(|w| w.split(" of ").next()?.parse().ok())
        .expect("a count of elements not measured");
    let (s, npy) = d.get_bytes(&format!("/reconstructions/{}/measurement.npy", r["id"]));
    assert_eq!(s, 200);
    let m = polnlos::files::npy::decode(&npy).unwrap();
    assert_eq!(m.data.iter().filter(|v| v.is_nan()).count(), lost);
    // From the pixels in range the saturated captures reconstruct within
    // 1 dB of the same blocks at a sane 20 ms (issue 38).
    let mut sane = Vec::new();
    for deg in [0, 45, 90, 135] {
        let c = d.run_job(
            "/captures",
            &format!(r#"{{"scene": "brewster-rotating", "pose": "A", "polarizer_deg": {deg}, "exposure_us": 20000, "frames": 2, "dark_frames": 1}}"#),
            long,
        );
        assert_eq!(c["state"], "done", "{c}");
        sane.push(c["id"].as_i64().unwrap());
    }
    let clean = d.run_job(
        "/reconstructions",
        &format!(r#"{{"scene": "brewster-rotating", "captures": {sane:?}, "truth": "letter"}}"#),
        long,
    );
    assert_eq!(clean["state"], "done", "{clean}");
    println!(
        "saturated 100 ms captures, in-range pixels: {:.2} dB (model check {}); 20 ms: {:.2} dB",
        psnr(&r),
        r["report"]["model_check"],
        psnr(&clean)
    );
    assert!(
        psnr(&r) >= psnr(&clean) - 1.0,
        "{} vs {}",
        psnr(&r),
        psnr(&clean)
    );
}

#[test]
fn a_capture_saturated_beyond_the_configured_share_fails_when_told_to() {
    let dir = scratch();
    let cfg = config(
        dir.path(),
        &[
            ("saturated = \"warn\"", "saturated = \"fail\""),
            ("saturated_share = 0.0", "saturated_share = 0.08"),
        ],
    );
    let d = InProcess::start(&cfg, &dir.path().join("data"));
    let capture = |deg: u32| {
        d.run_job(
            "/captures",
            &format!(r#"{{"scene": "brewster-rotating", "pose": "A", "polarizer_deg": {deg}, "exposure_us": 100000, "frames": 2}}"#),
            Duration::from_secs(60),
        )
    };
    // The glare block: about 28,600 of 262,144 pixels (10.9 %) saturated,
    // over 8 % (the count moves with the sensor's noise by a few hundred).
    let over = capture(90);
    assert_eq!(over["state"], "failed", "{over}");
    let error = over["error"].as_str().unwrap();
    let count = |text: &str| -> u64 {
        let head = text
            .split(" of 262144 pixels at full scale")
            .next()
            .unwrap_or("");
        head.rsplit(' ')
            .next()
            .and_then(|n| n.parse().ok())
            .unwrap_or(0)
    };
    assert!((27_000..30_500).contains(&count(error)), "{error}");
    assert!(error.contains("saturated = \"warn\""), "{error}");
    let (s, _) = d.get(&format!("/captures/{}/frame.tiff", over["id"]));
    assert_eq!(s, 404, "a failed capture keeps no frames");
    // 45 degrees: about 13,800 pixels (5.3 %), under the share: kept, counted.
    let under = capture(45);
    assert_eq!(under["state"], "done", "{under}");
    let n = under["clipping"]["saturated"].as_u64().unwrap_or(0);
    assert!((12_500..15_000).contains(&n), "{under}");
}
