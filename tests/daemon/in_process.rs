//! The daemon and its router in-process, on the synthetic camera: no socket,
//! no Aravis. What goes through real HTTP and the Aravis fake camera is in
//! `tests/daemon/service.rs`; this shows the library entry points are enough to run
//! the whole service with any frame source.

use std::sync::Arc;
use std::time::{Duration, Instant};

use axum::body::Body;
use axum::http::{Request, StatusCode};
use polnlos::daemon::SceneRegistry;
use polnlos::daemon::{CameraSetup, Config, Daemon};
use polnlos::store::Store;
use polnlos::transport::MemoryBudget;
use tower::ServiceExt;

use crate::daemon::common::scratch;

/// A daemon on the synthetic camera showing `scene`'s `pattern`, its camera connected.
async fn daemon_showing(dir: &std::path::Path, scene: &str, pattern: &str) -> Arc<Daemon> {
    let mut config = Config::embedded();
    config.data_dir = dir.join("data");
    config.camera.fake = false;
    config.queue.reconstruction_workers = 1;
    config.demo.scene = scene.into();
    config.demo.pattern = pattern.into();
    let store = Store::open(&config.data_dir).expect("data directory");
    let registry = Arc::new(
        SceneRegistry::open(&config.scene_files, &config.data_dir, MemoryBudget::DEFAULT)
            .expect("built-in scenes"),
    );
    let scenes = registry.now();
    // The demo scene's T, Gram and conditioning, formed before any job (as
    // a daemon that has reconstructed it once has them): a progressive
    // capture's solver otherwise forms them while its frames arrive, and on
    // a loaded machine (this process's rayon pool at idle priority, beside
    // the suite's long computations) every frame had arrived by then, so
    // only the first and the last snapshot were solved.
    scenes
        .conditioning(scene)
        .expect("the demo scene's conditioning");
    scenes.gram(scene).expect("the demo scene's Gram");
    let camera = CameraSetup::synthetic(&config, &scenes)
        .await
        .expect("synthetic camera");
    connected(Daemon::start_with(config, store, registry, camera).await).await
}

/// The started daemon, once its camera is connected.
async fn connected(started: Result<Arc<Daemon>, polnlos::daemon::DaemonError>) -> Arc<Daemon> {
    let d = started.expect("daemon starts");
    let start = Instant::now();
    while !d.camera().status().connected {
        assert!(
            start.elapsed() < Duration::from_secs(10),
            "camera did not connect"
        );
        tokio::time::sleep(Duration::from_millis(10)).await;
    }
    d
}

async fn daemon(dir: &std::path::Path) -> Arc<Daemon> {
    daemon_showing(dir, "brewster-crossed-3x3", "disk").await
}

/// One request through the router, as a client on the loopback would send it.
async fn call(
    d: &Arc<Daemon>,
    method: &str,
    uri: &str,
    body: Option<serde_json::Value>,
) -> (StatusCode, serde_json::Value) {
    let mut req = Request::builder()
        .method(method)
        .uri(uri)
        .header("host", "127.0.0.1:8470");
    if body.is_some() {
        req = req.header("content-type", "application/json");
    }
    let body = body.map_or(Body::empty(), |b| Body::from(b.to_string()));
    let res = polnlos::api::router(d.clone())
        .oneshot(req.body(body).expect("request"))
        .await
        .expect("the router answers");
    let status = res.status();
    let bytes = axum::body::to_bytes(res.into_body(), 1 << 20)
        .await
        .expect("body");
    let value = serde_json::from_slice(&bytes).unwrap_or(serde_json::Value::Null);
    (status, value)
}

async fn wait_done(d: &Arc<Daemon>, job: &str, within: Duration) -> serde_json::Value {
    let start = Instant::now();
    loop {
        let (_, v) = call(d, "GET", &format!("/jobs/{job}"), None).await;
        if matches!(v["state"].as_str(), Some("done" | "failed" | "cancelled"))
            || start.elapsed() > within
        {
            return v;
        }
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn capture_and_reconstruct_through_the_router_on_the_synthetic_camera() {
    let dir = scratch();
    let d = daemon(dir.path()).await;
    let (s, cam) = call(&d, "GET", "/camera", None).await;
    assert_eq!(s, StatusCode::OK);
    assert_eq!(cam["connected"], true, "{cam}");
    assert_eq!(cam["info"]["model"], "Synthetic", "{cam}");

    let capture = serde_json::json!({ "scene": "brewster-crossed-3x3", "pose": "A",
        "polarizer_deg": 0, "exposure_us": 2000, "frames": 4, "dark_frames": 2 });
    let (s, accepted) = call(&d, "POST", "/captures", Some(capture)).await;
    assert_eq!(s, StatusCode::ACCEPTED, "{accepted}");
    assert_eq!(accepted["region"], serde_json::json!([0, 0, 512, 512]));
    let job = accepted["job"].as_str().expect("job id").to_string();
    let c = wait_done(&d, &job, Duration::from_secs(30)).await;
    assert_eq!(c["state"], "done", "{c}");
    assert_eq!(c["frames_taken"], 6, "{c}");

    let recon = serde_json::json!({ "scene": "brewster-crossed-3x3",
        "captures": [c["id"]], "truth": "disk" });
    let (s, accepted) = call(&d, "POST", "/reconstructions", Some(recon)).await;
    assert_eq!(s, StatusCode::ACCEPTED, "{accepted}");
    let job = accepted["job"].as_str().expect("job id").to_string();
    let r = wait_done(&d, &job, Duration::from_secs(60)).await;
    assert_eq!(r["state"], "done", "{r}");
    let psnr = r["report"]["metrics"]["psnr_db"]
        .as_f64()
        .unwrap_or(f64::NAN);
    println!("in-process reconstruction of the 3x3 disk: PSNR {psnr:.2} dB");
    // A 3x3 disk from 4 dark-subtracted frames: the solve recovers it well
    // (a wrong row order, scale or dark level gives under 10 dB).
    assert!(psnr > 20.0, "{r}");

    // Errors come back typed through the same router.
    let (s, e) = call(
        &d,
        "POST",
        "/captures",
        Some(serde_json::json!({
        "scene": "brewster-crossed-3x3", "pose": "A", "polarizer_deg": 0, "exposure_us": 1 })),
    )
    .await;
    assert_eq!(s, StatusCode::UNPROCESSABLE_ENTITY, "{e}");
    assert!(
        e["detail"]
            .as_str()
            .unwrap_or("")
            .contains("exposure_us = 1"),
        "{e}"
    );
    d.shutdown();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn cancel_a_queued_and_a_running_reconstruction() {
    let dir = scratch();
    let d = daemon(dir.path()).await;
    let capture = serde_json::json!({ "scene": "brewster-crossed", "pose": "A",
        "polarizer_deg": 0, "exposure_us": 2000, "frames": 2, "dark_frames": 1 });
    let (s, a) = call(&d, "POST", "/captures", Some(capture)).await;
    assert_eq!(s, StatusCode::ACCEPTED, "{a}");
    let c = wait_done(&d, "capture-1", Duration::from_secs(30)).await;
    assert_eq!(c["state"], "done", "{c}");
    // The whole work of a reconstruction once, cold (T, its Gram and
    // conditioning, an automatic λ's solves): what the cancel's bound
    // scales with, so that a loaded machine slows both alike.
    let alone = Instant::now();
    let quick = serde_json::json!({ "scene": "brewster-crossed", "captures": [1] });
    let (s, a) = call(&d, "POST", "/reconstructions", Some(quick)).await;
    assert_eq!(s, StatusCode::ACCEPTED, "{a}");
    let r = wait_done(&d, "reconstruction-1", Duration::from_secs(120)).await;
    assert_eq!(r["state"], "done", "{r}");
    let alone = alone.elapsed();
    // A long solve (automatic λ: about twenty ADMM solves, each to the
    // 100000-iteration cap of a tolerance it never reaches: many times the
    // reconstruction above) and one queued behind it.
    let slow = serde_json::json!({ "scene": "brewster-crossed", "captures": [1],
        "max_iter": 100000, "tol": 1e-15 });
    for _ in 0..2 {
        let (s, a) = call(&d, "POST", "/reconstructions", Some(slow.clone())).await;
        assert_eq!(s, StatusCode::ACCEPTED, "{a}");
    }
    let start = Instant::now();
    while call(&d, "GET", "/jobs/reconstruction-2", None).await.1["state"] != "running" {
        assert!(start.elapsed() < Duration::from_secs(60));
        tokio::time::sleep(Duration::from_millis(10)).await;
    }
    let (s, r) = call(&d, "DELETE", "/jobs/reconstruction-3", None).await;
    assert_eq!(
        (s, r["state"].as_str()),
        (StatusCode::OK, Some("cancelled")),
        "{r}"
    );
    // Let the solve get going, then cancel it: the solver sees the flag
    // within ten iterations, so the job ends long before the solve would.
    tokio::time::sleep(Duration::from_millis(300)).await;
    let cancelled_at = Instant::now();
    let (s, r) = call(&d, "DELETE", "/jobs/reconstruction-2", None).await;
    assert!(s == StatusCode::OK || s == StatusCode::ACCEPTED, "{s} {r}");
    let r = wait_done(&d, "reconstruction-2", Duration::from_secs(600)).await;
    assert_eq!(r["state"], "cancelled", "{r}");
    let took = cancelled_at.elapsed();
    println!("a running reconstruction ended {took:?} after its cancel; the whole of a quick one took {alone:?}");
    // Protects: the cancel ends the solve rather than waiting for it. The
    // quick reconstruction's whole work (cold) is the unit; the slow
    // solve alone is many of them.
    assert!(
        took < alone * 2,
        "{took:?} against {alone:?} for a whole reconstruction"
    );
    // Nothing was written for either.
    for id in [2, 3] {
        let dir = d.store().reconstruction_dir(id);
        assert!(!dir.join("report.json").exists() && !dir.join("image.png").exists());
    }
    d.shutdown();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn progressive_reconstruction_converges_while_frames_arrive() {
    let dir = scratch();
    let d = daemon_showing(dir.path(), "brewster-crossed", "disk").await;
    // Mono8 at 1/5 of the reference exposure: the peak is about 40 DN, so
    // the sensor's noise of every frame is what averaging reduces.
    let capture = serde_json::json!({ "scene": "brewster-crossed", "pose": "A",
        "polarizer_deg": 0, "exposure_us": 4000, "frames": 60, "dark_frames": 8,
        "pixel_format": "Mono8",
        "progressive": { "every": 5, "truth": "disk" } });
    let mut events = d.subscribe();
    let (s, a) = call(&d, "POST", "/captures", Some(capture)).await;
    assert_eq!(s, StatusCode::ACCEPTED, "{a}");
    let c = wait_done(&d, "capture-1", Duration::from_secs(60)).await;
    assert_eq!(c["state"], "done", "{c}");
    let dir = d.store().capture_dir(1);
    let steps: Vec<serde_json::Value> =
        serde_json::from_slice(&std::fs::read(dir.join("progressive.json")).expect("steps"))
            .expect("json");
    let last = steps.last().expect("a step");
    assert_eq!(last["frames"], 60, "the final mean always gets its step");
    let final_psnr = last["psnr_db"].as_f64().expect("psnr");
    println!("frames | iterations | change | PSNR dB");
    for s in &steps {
        println!(
            "{:>6} | {:>10} | {:>6} | {:.2}",
            s["frames"],
            s["iterations"],
            s["change"]
                .as_f64()
                .map_or("-".into(), |c| format!("{c:.3}")),
            s["psnr_db"].as_f64().unwrap_or(f64::NAN)
        );
    }
    let first_within = steps
        .iter()
        .find(|s| (s["psnr_db"].as_f64().unwrap_or(f64::NAN) - final_psnr).abs() <= 1.0)
        .map(|s| s["frames"].as_i64().unwrap_or(0))
        .unwrap_or(0);
    println!("within 1 dB of the final {final_psnr:.2} dB from {first_within} of 60 frames");
    assert!(steps.len() >= 3, "{steps:?}");
    assert!(final_psnr > 15.0, "{final_psnr}");
    // Every step took the automatic λ from the running frame variance; the
    // noise falls as frames arrive, so the λ of the last step is below the
    // first one's.
    let lambdas: Vec<f64> = steps
        .iter()
        .map(|s| s["lambda"].as_f64().expect("a λ per step"))
        .collect();
    assert!(lambdas[lambdas.len() - 1] < lambdas[0], "{lambdas:?}");
    // The last step is as good as reconstructing the same capture afterwards.
    let (s, r) = call(
        &d,
        "POST",
        "/reconstructions",
        Some(serde_json::json!({ "scene": "brewster-crossed", "captures": [1], "truth": "disk" })),
    )
    .await;
    assert_eq!(s, StatusCode::ACCEPTED, "{r}");
    let rec = wait_done(&d, "reconstruction-1", Duration::from_secs(60)).await;
    let after = rec["report"]["metrics"]["psnr_db"].as_f64().expect("psnr");
    println!("last step {final_psnr:.2} dB, reconstruction of the same capture {after:.2} dB");
    println!(
        "reconstruction: model {}, lambda {}; last step lambda {}",
        rec["report"]["model"], rec["report"]["solver"]["lambda"], last["lambda"]
    );
    assert!((final_psnr - after).abs() <= 0.5, "{final_psnr} vs {after}");
    // The image route serves the latest, and the steps were events.
    let png = std::fs::read(dir.join("progressive.png")).expect("image");
    assert_eq!(&png[1..4], b"PNG");
    let mut seen = 0;
    while let Ok(e) = events.try_recv() {
        if matches!(e, polnlos::daemon::Event::Progressive { .. }) {
            seen += 1;
        }
    }
    assert_eq!(seen, steps.len());
    d.shutdown();
}

/// Status and error detail of one bodiless request; a success's body is not
/// read (`/events` never ends).
async fn answer(d: &Arc<Daemon>, method: &str, uri: &str) -> (StatusCode, String) {
    let req = Request::builder()
        .method(method)
        .uri(uri)
        .header("host", "127.0.0.1:8470")
        .body(Body::empty())
        .expect("request");
    let res = polnlos::api::router(d.clone())
        .oneshot(req)
        .await
        .expect("the router answers");
    let status = res.status();
    if status.is_success() {
        return (status, String::new());
    }
    let bytes = axum::body::to_bytes(res.into_body(), 1 << 20)
        .await
        .expect("body");
    let v: serde_json::Value = serde_json::from_slice(&bytes).unwrap_or_default();
    (status, v["detail"].as_str().unwrap_or_default().to_string())
}

/// The router serves exactly what `/openapi.json` names: each documented
/// operation reaches its handler (neither the "no route" 404 nor a 405), and
/// every other method on a documented path is a 405. The operations are
/// read from the document, so a new route is covered by being declared.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_router_serves_exactly_the_operations_its_document_names() {
    let dir = scratch();
    let d = daemon(dir.path()).await;
    let (s, spec) = call(&d, "GET", "/openapi.json", None).await;
    assert_eq!(s, StatusCode::OK, "{spec}");
    let paths = spec["paths"].as_object().expect("the document names paths");
    let mut operations = 0;
    for (path, item) in paths {
        // Every path parameter as "1": a request that reaches the handler
        // and is refused there (no such capture, job or scene), changing nothing.
        let uri: Vec<&str> = path
            .split('/')
            .map(|seg| if seg.starts_with('{') { "1" } else { seg })
            .collect();
        let uri = uri.join("/");
        for method in ["GET", "PUT", "POST", "DELETE", "PATCH"] {
            let documented = item[method.to_lowercase()].is_object();
            let (status, detail) = answer(&d, method, &uri).await;
            if documented {
                operations += 1;
                let unrouted = status == StatusCode::METHOD_NOT_ALLOWED
                    || (status == StatusCode::NOT_FOUND && detail.starts_with("no route"));
                assert!(
                    !unrouted,
                    "{method} {path} is documented but not served: {status} {detail}"
                );
            } else {
                assert_eq!(
                    status,
                    StatusCode::METHOD_NOT_ALLOWED,
                    "{method} {path} is served but not documented: {detail}"
                );
            }
        }
    }
    assert!(operations > 0, "the document names no operation");
    // An undocumented path is not routed at all.
    let (status, detail) = answer(&d, "GET", "/nowhere").await;
    assert_eq!(status, StatusCode::NOT_FOUND);
    assert!(detail.starts_with("no route"), "{detail}");
    d.shutdown();
}

/// The property names of schema `name` in `spec`, through `$ref`s and the
/// `allOf` a body that embeds another struct (`#[serde(flatten)]`) becomes.
fn property_names(spec: &serde_json::Value, schema: &serde_json::Value) -> Vec<String> {
    if let Some(r) = schema["$ref"].as_str() {
        let name = r.trim_start_matches("#/components/schemas/");
        return property_names(spec, &spec["components"]["schemas"][name]);
    }
    let mut names: Vec<String> = schema["properties"]
        .as_object()
        .map(|p| p.keys().cloned().collect())
        .unwrap_or_default();
    for part in schema["allOf"].as_array().into_iter().flatten() {
        names.extend(property_names(spec, part));
    }
    names.sort();
    names
}

/// Issue 39: the solver's parameters are declared once (`SolveRequest`) and
/// embedded in the bodies; the document still lists each of them for the
/// reconstruction request and for a plan's reconstruction.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_document_lists_every_solver_parameter_for_reconstructions_and_plans() {
    let dir = scratch();
    let d = daemon(dir.path()).await;
    let (s, spec) = call(&d, "GET", "/openapi.json", None).await;
    assert_eq!(s, StatusCode::OK, "{spec}");
    let schemas = &spec["components"]["schemas"];
    let reconstruction = property_names(&spec, &schemas["ReconstructionBody"]);
    let plan = property_names(&spec, &schemas["PlanBody"]);
    assert!(plan.iter().any(|p| p == "reconstruct"), "{plan:?}");
    let plan_reconstruct = property_names(
        &spec,
        &schemas["PlanBody"]["allOf"]
            .as_array()
            .into_iter()
            .flatten()
            .find_map(|part| part["properties"].get("reconstruct"))
            .cloned()
            .unwrap_or_default(),
    );
    for parameter in ["solver", "lambda", "rho", "max_iter", "tol", "rcond"] {
        for (body, names) in [
            ("ReconstructionBody", &reconstruction),
            ("PlanBody.reconstruct", &plan_reconstruct),
        ] {
            assert!(
                names.iter().any(|n| n == parameter),
                "{body} lacks {parameter}: {names:?}"
            );
        }
    }
    for own in ["scene", "captures", "truth", "partial"] {
        assert!(
            reconstruction.iter().any(|n| n == own),
            "{reconstruction:?}"
        );
    }
    // max_iter keeps its range; the bodies their required fields.
    let max_iter = &schemas["SolveRequest"]["properties"]["max_iter"];
    assert_eq!(
        (max_iter["minimum"].as_f64(), max_iter["maximum"].as_f64()),
        (Some(1.0), Some(100000.0)),
        "{max_iter}"
    );
    let required: Vec<&serde_json::Value> = schemas["ReconstructionBody"]["allOf"]
        .as_array()
        .into_iter()
        .flatten()
        .flat_map(|part| part["required"].as_array().into_iter().flatten())
        .collect();
    assert_eq!(
        required,
        ["scene", "captures"],
        "{}",
        schemas["ReconstructionBody"]
    );
    d.shutdown();
}

/// A camera that stops delivering without an error while `frozen` is set
/// (what no Aravis camera does: every Aravis wait times out), and otherwise
/// delivers flat frames at once.
struct Freezing {
    frozen: Arc<std::sync::atomic::AtomicBool>,
}

impl polnlos::camera::CameraDevice for Freezing {
    fn describe(&mut self) -> Result<polnlos::camera::CameraInfo, polnlos::camera::CameraError> {
        Ok(polnlos::camera::CameraInfo {
            id: "Test-Freezing-1".into(),
            address: "in-process".into(),
            vendor: "Test".into(),
            model: "Freezing".into(),
            serial: "1".into(),
            sensor: (512, 512),
            ranges: polnlos::camera::CameraRanges {
                exposure_us: (10.0, 1e7),
                ..polnlos::camera::CameraRanges::synthetic()
            },
            frame_rate: None,
            pixel_formats: Vec::new(),
            mosaic: None,
            bayer: None,
            limits: polnlos::camera::SensorLimits {
                sensor: [512, 512],
                ..Default::default()
            },
            settings: polnlos::camera::Acquisition::defaults_at([0, 0, 512, 512], [1, 1]),
        })
    }
    fn configure(
        &mut self,
        _: &polnlos::camera::Acquisition,
    ) -> Result<(), polnlos::camera::CameraError> {
        Ok(())
    }
    fn acquire(
        &mut self,
        n: usize,
        sink: &mut polnlos::camera::FrameSink<'_>,
    ) -> Result<polnlos::camera::FrameCounts, polnlos::camera::CameraError> {
        while self.frozen.load(std::sync::atomic::Ordering::SeqCst) {
            std::thread::sleep(Duration::from_millis(10));
        }
        for k in 0..n {
            let frame = polnlos::camera::RawFrame {
                width: 512,
                height: 512,
                bits: 16,
                pixels: vec![1000; 512 * 512],
                frame_id: k as u64 + 1,
                system_timestamp_ns: 0,
            };
            sink(frame).map_err(polnlos::camera::CameraError::Stopped)?;
        }
        Ok(polnlos::camera::FrameCounts {
            received: n as u64,
            ..Default::default()
        })
    }
    fn counters(&self) -> polnlos::camera::Counters {
        polnlos::camera::Counters::default()
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_camera_that_stalls_fails_its_capture_in_bounded_time_and_the_queue_goes_on() {
    let dir = scratch();
    let mut config = Config::embedded();
    config.data_dir = dir.path().join("data");
    config.camera.fake = false;
    config.camera.stall_slack_s = 1.0;
    let store = Store::open(&config.data_dir).expect("data directory");
    let scenes = Arc::new(
        SceneRegistry::open(&config.scene_files, &config.data_dir, MemoryBudget::DEFAULT)
            .expect("built-in scenes"),
    );
    let frozen = Arc::new(std::sync::atomic::AtomicBool::new(true));
    let f = frozen.clone();
    let camera = CameraSetup {
        opener: Box::new(move || {
            Ok(Box::new(Freezing { frozen: f.clone() }) as Box<dyn polnlos::camera::CameraDevice>)
        }),
        bench: Arc::new(polnlos::rig::bench::ManualBench),
        demo_calibration: None,
        watch_usb: false,
    };
    let d = connected(Daemon::start_with(config, store, scenes, camera).await).await;
    let capture = serde_json::json!({ "scene": "brewster-crossed", "pose": "A",
        "polarizer_deg": 0, "exposure_us": 20000, "frames": 2 });
    let (s, first) = call(&d, "POST", "/captures", Some(capture.clone())).await;
    assert_eq!(s, StatusCode::ACCEPTED, "{first}");
    let (s, second) = call(&d, "POST", "/captures", Some(capture)).await;
    assert_eq!(s, StatusCode::ACCEPTED, "{second}");
    // Frozen: the first fails after twice its frames' time plus the 1 s slack.
    let t = Instant::now();
    let c = wait_done(&d, first["job"].as_str().unwrap(), Duration::from_secs(20)).await;
    let took = t.elapsed();
    assert_eq!(c["state"], "failed", "{c}");
    assert!(
        c["error"]
            .as_str()
            .unwrap()
            .contains("the camera stalled: 0 of 2 frames"),
        "{c}"
    );
    assert!(took < Duration::from_secs(5), "{took:?}");
    // The camera comes back: the queued capture runs.
    frozen.store(false, std::sync::atomic::Ordering::SeqCst);
    let c = wait_done(&d, second["job"].as_str().unwrap(), Duration::from_secs(20)).await;
    assert_eq!(c["state"], "done", "{c}");
    assert_eq!(c["frame_counts"]["received"], 2, "{c}");
}
