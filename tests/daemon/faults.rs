//! Faults the daemon must survive (issue 3): the camera vanishing mid-capture
//! and coming back, a SIGKILL during a capture, a full data disk, an unusable
//! data directory. Real Aravis, real HTTP on 127.0.0.1, the real database file.

use std::process::Command;
use std::time::{Duration, Instant};

use crate::daemon::common::{config, lock, scratch, Client, Daemon};
use polnlos::camera::fake::FakeBench;
use polnlos::scene::Frame;

fn external_fake() -> FakeBench {
    FakeBench::start(
        "127.0.0.1",
        "POLNLOS-EXT",
        polnlos::camera::BenchImages {
            scene: vec![("A".into(), Some(0.0), Frame::zeros(512, 512))],
            ..Default::default()
        },
        20_000.0,
    )
    .unwrap()
}

fn wait_camera(d: &Client, connected: bool, within: Duration) -> bool {
    let t = Instant::now();
    while t.elapsed() < within {
        if d.json("/camera")["connected"] == connected {
            return true;
        }
        std::thread::sleep(Duration::from_millis(100));
    }
    false
}

#[test]
fn the_camera_stops_mid_capture_the_job_fails_and_the_daemon_reconnects() {
    let _g = lock();
    let dir = scratch();
    // The camera is not the daemon's own fake: this test owns it and pulls
    // its plug. (The setting's line, not the comment above it that also
    // says "fake = true": the daemon's own fake would refuse the address.)
    let cfg = config(dir.path(), &[("\nfake = true", "\nfake = false")]);
    let fake = external_fake();
    let d = Daemon::start(&cfg, &dir.path().join("data"));
    assert!(wait_camera(&d, true, Duration::from_secs(10)));
    let (s, b, loc) = d.post("/captures", r#"{"scene": "brewster-crossed", "pose": "A", "polarizer_deg": 0, "exposure_us": 100000, "frames": 30}"#);
    assert_eq!(s, 202, "{b}");
    std::thread::sleep(Duration::from_millis(800));
    drop(fake);
    let c = d.wait(&loc.unwrap(), Duration::from_secs(30));
    assert_eq!(c["state"], "failed", "{c}");
    let err = c["error"].as_str().unwrap();
    assert!(
        err.contains("no frame within") || err.contains("not connected"),
        "{err}"
    );
    assert_eq!(d.get("/health").0, 200);
    assert!(wait_camera(&d, false, Duration::from_secs(5)));
    // While it is away, captures fail (after a 5 s grace) with the reason.
    let c = d.run_job(
        "/captures",
        r#"{"scene": "brewster-crossed", "pose": "A", "polarizer_deg": 0, "exposure_us": 1000}"#,
        Duration::from_secs(20),
    );
    assert_eq!(c["state"], "failed");
    assert!(
        c["error"].as_str().unwrap().contains("not connected"),
        "{c}"
    );
    // It comes back: the daemon reconnects by itself.
    let _fake = external_fake();
    assert!(
        wait_camera(&d, true, Duration::from_secs(20)),
        "{}",
        d.json("/camera")
    );
    // A 2 s exposure (frame rate matched to it) completes without a timeout.
    let c = d.run_job("/captures", r#"{"scene": "brewster-crossed", "pose": "A", "polarizer_deg": 0, "exposure_us": 2000000, "frames": 2, "pixel_format": "Mono8"}"#, Duration::from_secs(30));
    assert_eq!(c["state"], "done", "{c}");
    assert_eq!(
        c["counters"]["timeouts"], 1,
        "only the one from the pulled plug: {c}"
    );
}

/// A first short capture done (its `mean.tiff` returned), then `long`
/// posted and running with at least `frames` taken (its location returned).
fn done_then_running(d: &Client, long: &str, frames: i64) -> (Vec<u8>, String) {
    let done = d.run_job("/captures", r#"{"scene": "brewster-crossed", "pose": "A", "polarizer_deg": 0, "exposure_us": 20000, "frames": 3}"#, Duration::from_secs(20));
    assert_eq!(done["state"], "done");
    let (_, mean) = d.get_bytes("/captures/1/mean.tiff");
    let (s, _, loc) = d.post("/captures", long);
    assert_eq!(s, 202);
    let loc = loc.unwrap();
    let t = Instant::now();
    while d.json(&loc)["frames_taken"].as_i64().unwrap_or(0) < frames {
        // 30 s, not 10: with the suite's CPU-bound cases beside it a capture
        // once took longer than 10 s to take its first frames.
        assert!(
            t.elapsed() < Duration::from_secs(30),
            "capture never started"
        );
        std::thread::sleep(Duration::from_millis(50));
    }
    (mean, loc)
}

#[test]
fn sigkill_during_a_capture_loses_nothing_completed() {
    let _g = lock();
    let dir = scratch();
    let data = dir.path().join("data");
    let cfg = config(dir.path(), &[]);
    let mut d = Daemon::start(&cfg, &data);
    let (mean_before, loc) = done_then_running(
        &d,
        r#"{"scene": "brewster-crossed", "pose": "A", "polarizer_deg": 0, "exposure_us": 500000, "frames": 20}"#,
        1,
    );
    d.child.kill().unwrap(); // SIGKILL
    d.child.wait().unwrap();
    drop(d);
    let d = Daemon::start(&cfg, &data);
    let before = d.json("/captures/1");
    assert_eq!(before["state"], "done");
    assert_eq!(
        d.get_bytes("/captures/1/mean.tiff").1,
        mean_before,
        "completed files intact"
    );
    let killed = d.json(&loc);
    assert_eq!(killed["state"], "interrupted", "{killed}");
    assert!(
        killed["error"].as_str().unwrap().contains("daemon stopped"),
        "{killed}"
    );
    let again = d.run_job(
        "/captures",
        r#"{"scene": "brewster-crossed", "pose": "A", "polarizer_deg": 0, "exposure_us": 20000}"#,
        Duration::from_secs(20),
    );
    assert_eq!(again["state"], "done");
    assert_eq!(again["id"], 3);
}

#[test]
fn sigterm_during_a_capture_interrupts_it_and_drains_before_exit() {
    let _g = lock();
    let dir = scratch();
    let data = dir.path().join("data");
    let cfg = config(dir.path(), &[]);
    let mut d = Daemon::start(&cfg, &data);
    let (mean_before, loc) = done_then_running(
        &d,
        r#"{"scene": "brewster-crossed", "pose": "A", "polarizer_deg": 0, "exposure_us": 200000, "frames": 100}"#,
        2,
    );
    let (s, _, queued) = d.post(
        "/captures",
        r#"{"scene": "brewster-crossed", "pose": "A", "polarizer_deg": 0, "exposure_us": 20000}"#,
    );
    assert_eq!(s, 202);
    let queued = queued.unwrap();
    let status = d.terminate();
    assert!(status.success(), "{status}");
    // The catalogue as the stopped daemon left it, before any restart's
    // recovery: the running capture was stopped and recorded by the daemon
    // itself, the queued one never started.
    let db = rusqlite::Connection::open(data.join("catalogue.sqlite")).unwrap();
    let row = |id: i64| -> (String, Option<String>) {
        db.query_row(
            "SELECT state, error FROM captures WHERE id = ?1",
            [id],
            |r| Ok((r.get(0)?, r.get(1)?)),
        )
        .unwrap()
    };
    let (state, error) = row(2);
    assert_eq!(state, "interrupted");
    assert!(error.unwrap_or_default().contains("daemon stopped"));
    assert_eq!(row(3).0, "queued");
    assert_eq!(row(1).0, "done");
    let folder = data.join("captures/2");
    for f in ["frames.tiff", "mean.tiff", "variance.tiff"] {
        assert!(
            !folder.join(f).exists(),
            "{f} of the interrupted capture was kept"
        );
    }
    drop(db);
    drop(d);
    let d = Daemon::start(&cfg, &data);
    assert_eq!(d.json("/captures/1")["state"], "done");
    assert_eq!(d.get_bytes("/captures/1/mean.tiff").1, mean_before);
    assert_eq!(d.json(&loc)["state"], "interrupted");
    assert_eq!(d.json(&queued)["state"], "interrupted");
}

/// Whether this process may make a private mount namespace (root, as in CI).
fn can_unshare_mounts() -> bool {
    Command::new("unshare")
        .args(["-m", "true"])
        .output()
        .map(|o| o.status.success())
        .unwrap_or(false)
}

#[test]
fn a_full_disk_fails_the_job_clearly_and_keeps_earlier_data() {
    if !can_unshare_mounts() {
        println!("skipped: `unshare -m` is not permitted here (needs root, as in CI), so no private tmpfs can stand in for a full disk");
        return;
    }
    let _g = lock();
    let dir = scratch();
    let data = dir.path().join("data");
    std::fs::create_dir_all(&data).unwrap();
    let cfg = config(
        dir.path(),
        &[("reserve_free_mib = 64", "reserve_free_mib = 0")],
    );
    // A private mount namespace with a 24 MiB tmpfs as the data directory.
    let mut cmd = Command::new("unshare");
    cmd.args([
        "-m",
        "sh",
        "-c",
        "mount -t tmpfs -o size=24m tmpfs \"$POLNLOS_TMPFS\" && exec \"$0\" \"$@\"",
        env!("CARGO_BIN_EXE_polnlos"),
    ])
    .env("POLNLOS_TMPFS", &data);
    let d = Daemon::start_with(cmd, &cfg, &data);
    let small = d.run_job("/captures", r#"{"scene": "brewster-crossed", "pose": "A", "polarizer_deg": 0, "exposure_us": 20000, "pixel_format": "Mono8"}"#, Duration::from_secs(20));
    assert_eq!(small["state"], "done", "{small}");
    let (_, mean) = d.get_bytes("/captures/1/mean.tiff");
    // A capture whose files cannot fit is refused before it is queued.
    let (s, b, _) = d.post("/captures", r#"{"scene": "brewster-crossed", "pose": "A", "polarizer_deg": 0, "exposure_us": 20000, "frames": 200}"#);
    assert_eq!(s, 507, "{b}");
    assert!(
        b.contains("needs 104.3 MiB") && b.contains("MiB free"),
        "{b}"
    );
    // One that fits is admitted; then something else fills the disk while
    // it runs (written into the daemon's tmpfs through /proc/PID/root).
    let (s, b, loc) = d.post("/captures", r#"{"scene": "brewster-crossed", "pose": "A", "polarizer_deg": 0, "exposure_us": 100000, "frames": 20}"#);
    assert_eq!(s, 202, "{b}");
    let filler = format!("/proc/{}/root{}/filler", d.pid(), data.display());
    let mut f = std::fs::File::create(&filler).unwrap();
    let chunk = vec![0u8; 1 << 20];
    while std::io::Write::write_all(&mut f, &chunk).is_ok() {}
    drop(f);
    let big = d.wait(&loc.unwrap(), Duration::from_secs(30));
    assert_eq!(big["state"], "failed", "{big}");
    let error = big["error"].as_str().unwrap();
    assert!(error.contains("No space left on device"), "{big}");
    assert!(
        !error.contains(&data.display().to_string()),
        "no absolute path: {error}"
    );
    assert_eq!(d.get("/health").0, 200);
    assert_eq!(d.json("/captures/1")["state"], "done");
    assert_eq!(
        d.get_bytes("/captures/1/mean.tiff").1,
        mean,
        "earlier files intact"
    );
    assert_eq!(
        d.get("/captures/2/frame.tiff").0,
        404,
        "no half-written file is served"
    );
    let left: Vec<_> = std::fs::read_dir(format!(
        "/proc/{}/root{}/captures/2",
        d.pid(),
        data.display()
    ))
    .map(|r| r.flatten().map(|e| e.file_name()).collect())
    .unwrap_or_default();
    assert!(left.is_empty(), "nothing half-written is kept: {left:?}");
}

#[test]
fn an_unusable_data_directory_is_a_clear_startup_error() {
    let dir = scratch();
    let file = dir.path().join("not-a-dir");
    std::fs::write(&file, b"x").unwrap();
    let cfg = config(dir.path(), &[]);
    let out = Command::new(env!("CARGO_BIN_EXE_polnlos"))
        .args(["serve", "--config"])
        .arg(&cfg)
        .arg("--data-dir")
        .arg(file.join("data"))
        .output()
        .unwrap();
    // Exit status 3: a path the user named (the data directory) is unusable.
    assert_eq!(out.status.code(), Some(3));
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("data directory") && err.contains("not-a-dir"),
        "{err}"
    );
}

/// Busy loops on every core (and as many again), until dropped.
struct Load {
    stop: std::sync::Arc<std::sync::atomic::AtomicBool>,
    threads: Vec<std::thread::JoinHandle<()>>,
}

impl Load {
    fn start() -> Self {
        let stop = std::sync::Arc::new(std::sync::atomic::AtomicBool::new(false));
        let n = 2 * std::thread::available_parallelism().map_or(2, |n| n.get());
        let threads = (0..n)
            .map(|_| {
                let stop = stop.clone();
                std::thread::spawn(move || {
                    let mut x = 1.0f64;
                    while !stop.load(std::sync::atomic::Ordering::Relaxed) {
                        for _ in 0..10_000 {
                            x = (x * 1.000_001).sin() + 1.0;
                        }
                    }
                    std::hint::black_box(x);
                })
            })
            .collect();
        Self { stop, threads }
    }
}

impl Drop for Load {
    fn drop(&mut self) {
        self.stop.store(true, std::sync::atomic::Ordering::Relaxed);
        for t in self.threads.drain(..) {
            let _ = t.join();
        }
    }
}

#[test]
fn captures_posted_as_the_daemon_starts_on_a_busy_machine_finish_and_lose_no_frame() {
    let _g = lock();
    let dir = scratch();
    let cfg = config(dir.path(), &[]);
    let load = Load::start();
    let mut took = Vec::new();
    // A 2-frame 20 ms capture posted the moment /health answers (the camera
    // may not be connected yet): done well within 30 s, every time.
    for k in 0..4 {
        let data = dir.path().join(format!("data-{k}"));
        let d = Daemon::start_answering(&cfg, &data);
        let t = Instant::now();
        // Before the camera has reported its region the daemon says so
        // (503, retry); a script that retries gets its capture queued.
        let (s, b, loc) = loop {
            let (s, b, loc) = d.post(
                "/captures",
                r#"{"scene": "brewster-crossed", "pose": "A", "polarizer_deg": 0, "exposure_us": 20000, "frames": 2}"#,
            );
            if s != 503 || t.elapsed() > Duration::from_secs(10) {
                break (s, b, loc);
            }
            assert!(
                b.contains("retry when GET /camera shows it connected"),
                "{b}"
            );
            std::thread::sleep(Duration::from_millis(50));
        };
        assert_eq!(s, 202, "start {k}: {b}");
        let c = d.wait(&loc.unwrap(), Duration::from_secs(30));
        assert_eq!(c["state"], "done", "start {k}: {c}");
        took.push(t.elapsed());
        assert_eq!(c["frame_counts"]["dropped"], 0, "{c}");
    }
    println!("2-frame captures from a cold start under load: {took:?}");
    // 200 frames of 1 ms (the fake camera's fastest, 1000 frames a second)
    // on the 2 cores without the extra load: all 200 kept. A frame lost to
    // the rest of the suite's load (2 of 202 broken once in CI, when the
    // socket held one frame) is replaced by a later one and counted as the
    // camera counted it, never kept.
    drop(load);
    let d = Daemon::start(&cfg, &dir.path().join("data-200"));
    let c = d.run_job(
        "/captures",
        r#"{"scene": "brewster-crossed", "pose": "A", "polarizer_deg": 0, "exposure_us": 1000, "frames": 200}"#,
        Duration::from_secs(60),
    );
    assert_eq!(c["state"], "done", "{c}");
    let counts = &c["frame_counts"];
    let n = |v: &serde_json::Value| v.as_u64().unwrap_or(u64::MAX);
    println!("200 frames of 1 ms: {counts}");
    assert_eq!(n(&counts["received"]), 200, "{c}");
    assert_eq!(n(&c["counters"]["completed"]), 200, "{c}");
    // This daemon's camera took this capture only: its broken buffers are
    // the capture's.
    assert_eq!(counts["broken"], c["counters"]["failed"], "{c}");
    assert!(n(&counts["dropped"]) + n(&counts["broken"]) <= 10, "{c}");
}

#[test]
fn sigterm_with_an_event_stream_open_ends_the_stream_and_does_not_wait_for_it() {
    use std::io::{Read, Write};
    let _g = lock();
    let dir = scratch();
    let data = dir.path().join("data");
    let cfg = config(dir.path(), &[]);
    let mut d = Daemon::start(&cfg, &data);
    // A page or a script listening to GET /events, as the issue found it.
    let addr = d.base.trim_start_matches("http://").to_string();
    let mut sse = std::net::TcpStream::connect(&addr).unwrap();
    sse.set_read_timeout(Some(Duration::from_secs(20))).unwrap();
    sse.write_all(format!("GET /events HTTP/1.1\r\nHost: {addr}\r\n\r\n").as_bytes())
        .unwrap();
    let mut head = [0u8; 256];
    let n = sse.read(&mut head).unwrap();
    let head = String::from_utf8_lossy(&head[..n]).to_string();
    assert!(head.starts_with("HTTP/1.1 200"), "{head}");
    assert!(head.contains("text/event-stream"), "{head}");
    // The stream ends (end of file), not cut off by the drain's timeout:
    // read on a thread while the daemon stops.
    let reader = std::thread::spawn(move || {
        let mut rest = Vec::new();
        sse.read_to_end(&mut rest).map(|_| ())
    });
    let status = d.terminate();
    assert!(status.success(), "{status}");
    reader
        .join()
        .unwrap()
        .expect("the event stream ends when the daemon stops");
    let log = std::fs::read_to_string(data.with_extension("log")).unwrap_or_default();
    assert!(
        !log.contains("still busy after"),
        "the shutdown waited for the event stream:\n{log}"
    );
}

#[test]
fn sigterm_during_a_reconstruction_puts_it_back_and_the_next_start_resumes_it() {
    let _g = lock();
    let dir = scratch();
    let data = dir.path().join("data");
    let cfg = config(dir.path(), &[]);
    let mut d = Daemon::start(&cfg, &data);
    let c = d.run_job(
        "/captures",
        r#"{"scene": "brewster-crossed", "pose": "A", "polarizer_deg": 0, "exposure_us": 2000, "frames": 2, "dark_frames": 1}"#,
        Duration::from_secs(60),
    );
    assert_eq!(c["state"], "done", "{c}");
    // A long one (an automatic λ's solves, each to a 100000-iteration cap)
    // running, and a short one queued behind it.
    let (s, b, slow) = d.post(
        "/reconstructions",
        r#"{"scene": "brewster-crossed", "captures": [1], "max_iter": 100000, "tol": 1e-15}"#,
    );
    assert_eq!(s, 202, "{b}");
    let (s, b, quick) = d.post(
        "/reconstructions",
        r#"{"scene": "brewster-crossed", "captures": [1]}"#,
    );
    assert_eq!(s, 202, "{b}");
    let (slow, quick) = (slow.expect("Location"), quick.expect("Location"));
    let t = Instant::now();
    while d.json(&slow)["state"] != "running" {
        assert!(t.elapsed() < Duration::from_secs(60), "never started");
        std::thread::sleep(Duration::from_millis(20));
    }
    std::thread::sleep(Duration::from_millis(300));
    let status = d.terminate();
    assert!(status.success(), "{status}");
    // As the stopped daemon left them: both wait in the queue, neither wrote a result.
    let db = rusqlite::Connection::open(data.join("catalogue.sqlite")).unwrap();
    let states: Vec<(i64, String)> = db
        .prepare("SELECT id, state FROM reconstructions ORDER BY id")
        .unwrap()
        .query_map([], |r| Ok((r.get(0)?, r.get(1)?)))
        .unwrap()
        .map(Result::unwrap)
        .collect();
    assert_eq!(states, [(1, "queued".into()), (2, "queued".into())]);
    drop(db);
    assert!(!data.join("reconstructions/1/report.json").exists());
    drop(d);
    // The next start runs them again, in their order.
    let d = Daemon::start(&cfg, &data);
    let t = Instant::now();
    while d.json(&slow)["state"] != "running" {
        assert!(
            t.elapsed() < Duration::from_secs(60),
            "not resumed: {}",
            d.json(&slow)
        );
        std::thread::sleep(Duration::from_millis(20));
    }
    let (s, b) = d.delete("/jobs/reconstruction-1");
    assert!(s == 200 || s == 202, "{s} {b}");
    assert_eq!(
        d.wait(&slow, Duration::from_secs(120))["state"],
        "cancelled"
    );
    let done = d.wait(&quick, Duration::from_secs(120));
    assert_eq!(done["state"], "done", "{done}");
    assert!(data.join("reconstructions/2/image.png").exists());
}
