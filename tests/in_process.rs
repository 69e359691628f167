//! The daemon and its router in-process, on the synthetic camera: no socket,
//! no Aravis. What goes through real HTTP and the Aravis fake camera is in
//! `tests/daemon.rs`; this shows the library entry points are enough to run
//! the whole service with any frame source.

use std::sync::Arc;
use std::time::{Duration, Instant};

use axum::body::Body;
use axum::http::{Request, StatusCode};
use polnlos::daemon::scenes::Scenes;
use polnlos::daemon::{CameraSetup, Config, Daemon};
use polnlos::store::Store;
use tower::ServiceExt;

async fn daemon(dir: &std::path::Path) -> Arc<Daemon> {
    let mut config = Config::embedded();
    config.data_dir = dir.join("data");
    config.camera.fake = false;
    config.demo.scene = "brewster-crossed-3x3".into();
    config.demo.pattern = "disk".into();
    let store = Store::open(&config.data_dir).expect("data directory");
    let scenes = Arc::new(Scenes::load(&config.scene_files).expect("built-in scenes"));
    let camera = CameraSetup::synthetic(&config, &scenes)
        .await
        .expect("synthetic camera");
    Daemon::start_with(config, store, scenes, camera)
        .await
        .expect("daemon starts")
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
        if matches!(v["state"].as_str(), Some("done" | "failed")) || start.elapsed() > within {
            return v;
        }
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn capture_and_reconstruct_through_the_router_on_the_synthetic_camera() {
    let dir = tempfile::tempdir().expect("temp dir");
    let d = daemon(dir.path()).await;
    let start = Instant::now();
    while !d.camera_connected() && start.elapsed() < Duration::from_secs(5) {
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
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
