//! Helpers for the daemon tests: run `polnlos serve` on 127.0.0.1 and talk
//! HTTP to it. Everything stays on loopback and is bounded in time.

#![allow(dead_code)]

use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::sync::Mutex;
use std::time::{Duration, Instant};

/// Aravis state is global and the fake camera owns 127.0.0.1's GVCP port:
/// one test at a time uses Aravis, in-process (`camera.rs`) or in a daemon.
pub static ARAVIS: Mutex<()> = Mutex::new(());

/// Daemon tests that run at once: eight, whatever `RUST_TEST_THREADS` is.
///
/// Why: the suite runs more test threads than that so that the core's
/// CPU-bound tests (idle class, `tests/priority.rs`) start at once beside
/// them, not after them; the daemon tests, each with its daemon, fake
/// camera or browser in the normal class, must not all run at once on two
/// cores (sixteen of them at once timed out camera, web and schemathesis
/// tests: docs/test-times.md).
const DAEMON_SLOTS: usize = 8;

static SLOTS: (Mutex<usize>, std::sync::Condvar) = (Mutex::new(0), std::sync::Condvar::new());

/// One of the [`DAEMON_SLOTS`], held by a test thread until it ends.
struct Slot;

impl Drop for Slot {
    fn drop(&mut self) {
        let (taken, freed) = &SLOTS;
        *taken.lock().unwrap_or_else(|e| e.into_inner()) -= 1;
        freed.notify_one();
    }
}

thread_local! {
    static HELD: std::cell::RefCell<Option<Slot>> = const { std::cell::RefCell::new(None) };
}

/// Waits for a daemon-test slot unless this test (thread) holds one; it
/// is given back when the test's thread ends (libtest runs each test on a
/// thread of its own). [`lock`] and [`scratch`] take it, so every test that
/// starts a daemon, a camera or a browser does.
pub fn slot() {
    if HELD.with(|h| h.borrow().is_some()) {
        return;
    }
    let (taken, freed) = &SLOTS;
    let mut n = taken.lock().unwrap_or_else(|e| e.into_inner());
    while *n >= DAEMON_SLOTS {
        n = freed.wait(n).unwrap_or_else(|e| e.into_inner());
    }
    *n += 1;
    drop(n);
    HELD.with(|h| *h.borrow_mut() = Some(Slot));
}

/// Takes the Aravis lock for the rest of the caller's scope.
pub fn lock() -> AravisHold {
    slot();
    let asked = std::time::SystemTime::now();
    let guard = ARAVIS.lock().unwrap_or_else(|e| e.into_inner());
    AravisHold {
        _guard: guard,
        asked,
        got: std::time::SystemTime::now(),
    }
}

/// The Aravis lock, held: on drop, with `POLNLOS_ARAVIS_LOG` set (as
/// scripts/test-times.sh sets it), one line per hold is appended to that
/// file (the test, and the Unix times in seconds when it asked for, got and
/// gave back the lock), so docs/test-times.md can show the tests that wait
/// on one another for the one fake camera.
pub struct AravisHold {
    _guard: std::sync::MutexGuard<'static, ()>,
    asked: std::time::SystemTime,
    got: std::time::SystemTime,
}

impl Drop for AravisHold {
    fn drop(&mut self) {
        let Some(log) = std::env::var_os("POLNLOS_ARAVIS_LOG") else {
            return;
        };
        let s = |t: std::time::SystemTime| {
            t.duration_since(std::time::UNIX_EPOCH)
                .map_or(0.0, |d| d.as_secs_f64())
        };
        let line = format!(
            "{}\t{:.2}\t{:.2}\t{:.2}\n",
            std::thread::current().name().unwrap_or("?"),
            s(self.asked),
            s(self.got),
            s(std::time::SystemTime::now())
        );
        use std::io::Write;
        if let Ok(mut f) = std::fs::OpenOptions::new()
            .create(true)
            .append(true)
            .open(log)
        {
            let _ = f.write_all(line.as_bytes());
        }
    }
}

/// A temporary folder for a test's data directory, configuration and
/// files: in `/dev/shm` when that is a tmpfs with room (4 GiB free), else
/// in the system's temporary folder.
///
/// Why: the daemon fsyncs every frame file, its catalogue and its plans, and
/// on the 2-core test machine's disk one test's writes made another's fsync
/// wait: the disk sat at 85-93 % I/O wait for 30 s, a 150-frame capture ran
/// at 5 frames a second and a cancel came too late (docs/test-times.md).
/// On tmpfs the same files are written, fsynced and renamed, without the
/// wait. Docker's default /dev/shm (64 MiB) is too small and is not used.
pub fn scratch() -> tempfile::TempDir {
    slot();
    // Looked up once per test process, not once per test.
    static ROOT: std::sync::OnceLock<Option<PathBuf>> = std::sync::OnceLock::new();
    let root = ROOT.get_or_init(|| {
        let shm = Path::new("/dev/shm");
        let tmpfs = std::fs::read_to_string("/proc/mounts").is_ok_and(|m| {
            m.lines().any(|l| {
                l.split_whitespace().nth(1) == Some("/dev/shm")
                    && l.split_whitespace().nth(2) == Some("tmpfs")
            })
        });
        let room = polnlos::files::space::free_disk_bytes(shm).is_ok_and(|b| b >= 4 << 30);
        (tmpfs && room).then(|| shm.to_path_buf())
    });
    let builder = tempfile::Builder::new().prefix("polnlos-test-").to_owned();
    if let Some(Ok(d)) = root.as_ref().map(|r| builder.tempdir_in(r)) {
        return d;
    }
    builder.tempdir().expect("a temporary folder")
}

pub fn free_port() -> u16 {
    std::net::TcpListener::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port()
}

/// A config file: the embedded default with some lines replaced.
pub fn config(dir: &Path, edits: &[(&str, &str)]) -> PathBuf {
    let mut text = polnlos::daemon::DEFAULT_TOML.to_string();
    for (from, to) in edits {
        assert!(text.contains(from), "{from}");
        text = text.replacen(from, to, 1);
    }
    let p = dir.join("polnlos.toml");
    std::fs::write(&p, text).unwrap();
    p
}

/// A reconstruction record's PSNR against its truth (NaN without one).
pub fn psnr(r: &serde_json::Value) -> f64 {
    r["report"]["metrics"]["psnr_db"]
        .as_f64()
        .unwrap_or(f64::NAN)
}

/// HTTP to a daemon on 127.0.0.1: its address, a client and the bearer
/// token it sends (if any).
pub struct Client {
    pub base: String,
    pub agent: ureq::Agent,
    pub token: Option<String>,
}

impl Client {
    fn on_port(port: u16) -> Self {
        let agent: ureq::Agent = ureq::Agent::config_builder()
            .http_status_as_error(false)
            .timeout_global(Some(Duration::from_secs(30)))
            .build()
            .into();
        Self {
            base: format!("http://127.0.0.1:{port}"),
            agent,
            token: None,
        }
    }

    pub fn get(&self, path: &str) -> (u16, String) {
        let mut req = self.agent.get(format!("{}{path}", self.base));
        if let Some(t) = &self.token {
            req = req.header("authorization", format!("Bearer {t}"));
        }
        match req.call() {
            Ok(mut r) => (
                r.status().as_u16(),
                r.body_mut().read_to_string().unwrap_or_default(),
            ),
            Err(_) => (0, String::new()),
        }
    }

    /// The value of header `name` in the answer to `GET path`.
    pub fn get_header(&self, path: &str, name: &str) -> Option<String> {
        let mut req = self.agent.get(format!("{}{path}", self.base));
        if let Some(t) = &self.token {
            req = req.header("authorization", format!("Bearer {t}"));
        }
        let r = req.call().unwrap();
        r.headers()
            .get(name)
            .and_then(|v| v.to_str().ok())
            .map(String::from)
    }

    pub fn get_bytes(&self, path: &str) -> (u16, Vec<u8>) {
        let mut req = self.agent.get(format!("{}{path}", self.base));
        if let Some(t) = &self.token {
            req = req.header("authorization", format!("Bearer {t}"));
        }
        let mut r = req.call().unwrap();
        (
            r.status().as_u16(),
            r.body_mut()
                .with_config()
                .limit(64 << 20)
                .read_to_vec()
                .unwrap(),
        )
    }

    pub fn post(&self, path: &str, body: &str) -> (u16, String, Option<String>) {
        self.post_as(path, "application/json", body.as_bytes())
    }

    /// POSTs `body` to `path` and asserts it is refused with 422 and an
    /// answer that says `says`.
    pub fn refused(&self, path: &str, body: &str, says: &str) {
        let (s, b, _) = self.post(path, body);
        assert_eq!(s, 422, "{body}: {b}");
        assert!(b.contains(says), "{says}: {b}");
    }

    /// POSTs `body` as `application/octet-stream` (a file upload).
    pub fn post_bytes(&self, path: &str, body: &[u8]) -> (u16, String, Option<String>) {
        self.post_as(path, "application/octet-stream", body)
    }

    /// POSTs `body` with `content_type`: the status, the body and the Location.
    fn post_as(
        &self,
        path: &str,
        content_type: &str,
        body: &[u8],
    ) -> (u16, String, Option<String>) {
        let mut req = self
            .agent
            .post(format!("{}{path}", self.base))
            .header("content-type", content_type);
        if let Some(t) = &self.token {
            req = req.header("authorization", format!("Bearer {t}"));
        }
        let mut r = req.send(body).unwrap();
        let loc = r
            .headers()
            .get("location")
            .and_then(|v| v.to_str().ok())
            .map(String::from);
        (
            r.status().as_u16(),
            r.body_mut().read_to_string().unwrap_or_default(),
            loc,
        )
    }

    /// Sends `body` as a scene file (`application/toml`) with `method`
    /// (`POST` or `PUT`): the status and the body.
    pub fn send_toml(&self, method: &str, path: &str, body: &str) -> (u16, String) {
        let url = format!("{}{path}", self.base);
        let mut req = match method {
            "PUT" => self.agent.put(url),
            _ => self.agent.post(url),
        }
        .header("content-type", "application/toml");
        if let Some(t) = &self.token {
            req = req.header("authorization", format!("Bearer {t}"));
        }
        let mut r = req.send(body).unwrap();
        (
            r.status().as_u16(),
            r.body_mut().read_to_string().unwrap_or_default(),
        )
    }

    pub fn put(&self, path: &str, body: &str) -> (u16, String) {
        let mut req = self
            .agent
            .put(format!("{}{path}", self.base))
            .header("content-type", "application/json");
        if let Some(t) = &self.token {
            req = req.header("authorization", format!("Bearer {t}"));
        }
        let mut r = req.send(body).unwrap();
        (
            r.status().as_u16(),
            r.body_mut().read_to_string().unwrap_or_default(),
        )
    }

    pub fn delete(&self, path: &str) -> (u16, String) {
        let mut req = self.agent.delete(format!("{}{path}", self.base));
        if let Some(t) = &self.token {
            req = req.header("authorization", format!("Bearer {t}"));
        }
        let mut r = req.call().unwrap();
        (
            r.status().as_u16(),
            r.body_mut().read_to_string().unwrap_or_default(),
        )
    }

    /// Sends raw bytes on a fresh connection; returns the status (0 when the
    /// server closed without answering) and the body.
    pub fn raw(&self, request: &[u8]) -> (u16, String) {
        use std::io::{Read, Write};
        let addr = self.base.trim_start_matches("http://");
        let mut s = std::net::TcpStream::connect(addr).unwrap();
        s.set_read_timeout(Some(Duration::from_secs(20))).unwrap();
        let _ = s.write_all(request);
        let mut out = Vec::new();
        let _ = s.read_to_end(&mut out);
        let text = String::from_utf8_lossy(&out).into_owned();
        let status = text
            .split_whitespace()
            .nth(1)
            .and_then(|c| c.parse().ok())
            .unwrap_or(0);
        let body = text
            .split_once("\r\n\r\n")
            .map(|x| x.1.to_string())
            .unwrap_or_default();
        (status, body)
    }

    pub fn json(&self, path: &str) -> serde_json::Value {
        let (s, b) = self.get(path);
        assert_eq!(s, 200, "{path}: {b}");
        serde_json::from_str(&b).unwrap()
    }

    /// Posts a job and waits until it leaves queued/running.
    pub fn run_job(&self, path: &str, body: &str, within: Duration) -> serde_json::Value {
        let (s, b, loc) = self.post(path, body);
        assert_eq!(s, 202, "{path}: {b}");
        let loc = loc.expect("Location header");
        self.wait(&loc, within)
    }

    /// Waits until plan `loc` is in one of `states`; the plan.
    pub fn wait_plan(&self, loc: &str, states: &[&str], within: Duration) -> serde_json::Value {
        let t = Instant::now();
        loop {
            let v = self.json(loc);
            if states.iter().any(|s| v["state"] == *s) {
                return v;
            }
            assert!(t.elapsed() < within, "{loc}: {v}");
            std::thread::sleep(Duration::from_millis(100));
        }
    }

    pub fn wait(&self, loc: &str, within: Duration) -> serde_json::Value {
        let t = Instant::now();
        loop {
            let v = self.json(loc);
            let st = v["state"].as_str().unwrap_or("").to_string();
            if st != "queued" && st != "running" {
                return v;
            }
            assert!(t.elapsed() < within, "{loc} still {st}");
            std::thread::sleep(Duration::from_millis(100));
        }
    }
}

/// A `polnlos serve` process; killed on drop. For tests whose point is the
/// process (signals, start-up refusals, a second daemon, its memory) or
/// Aravis's fake camera; the others use [`InProcess`].
pub struct Daemon {
    pub child: Child,
    client: Client,
    /// The daemon's stderr (its log, and Aravis's warnings and stream
    /// events): its end is printed when the test fails.
    log: PathBuf,
}

impl Daemon {
    /// Starts `polnlos serve` and waits for /health.
    pub fn start(config: &Path, data: &Path) -> Self {
        Self::start_with(Command::new(env!("CARGO_BIN_EXE_polnlos")), config, data)
    }

    pub fn start_with(cmd: Command, config: &Path, data: &Path) -> Self {
        Self::spawn(cmd, config, data, true)
    }

    /// Starts `polnlos serve` and returns as soon as /health answers,
    /// camera connected or not (what a script that starts the daemon and
    /// posts at once sees).
    pub fn start_answering(config: &Path, data: &Path) -> Self {
        Self::spawn(
            Command::new(env!("CARGO_BIN_EXE_polnlos")),
            config,
            data,
            false,
        )
    }

    fn spawn(mut cmd: Command, config: &Path, data: &Path, camera: bool) -> Self {
        let port = free_port();
        let log = std::fs::File::create(data.with_extension("log")).unwrap();
        // Aravis's warnings, and its stream's start, stop and lost frames:
        // a failed capture's log then shows what the camera and the stream
        // did (the fake camera runs in the daemon, so both sides).
        let child = cmd
            .env("ARV_DEBUG", "all:1,stream:2,stream-thread:2")
            .args(["serve", "--config"])
            .arg(config)
            .args(["--bind", &format!("127.0.0.1:{port}"), "--data-dir"])
            .arg(data)
            .stdout(Stdio::null())
            .stderr(log)
            .spawn()
            .expect("spawn polnlos serve");
        let mut d = Self {
            child,
            client: Client::on_port(port),
            log: data.with_extension("log"),
        };
        let t = Instant::now();
        loop {
            let (status, body) = d.get("/health");
            if status == 200 && (!camera || body.contains("\"camera_connected\":true")) {
                break;
            }
            if let Ok(Some(status)) = d.child.try_wait() {
                panic!(
                    "daemon exited with {status}: {}",
                    std::fs::read_to_string(data.with_extension("log")).unwrap_or_default()
                );
            }
            assert!(
                t.elapsed() < Duration::from_secs(30),
                "daemon did not come up"
            );
            std::thread::sleep(Duration::from_millis(100));
        }
        d
    }

    /// Sends SIGTERM (what systemd sends on `systemctl stop`) and waits up
    /// to 30 s for the daemon to exit; its exit status.
    pub fn terminate(&mut self) -> std::process::ExitStatus {
        let term = Command::new("kill")
            .args(["-TERM", &self.pid().to_string()])
            .status()
            .unwrap();
        assert!(term.success());
        let t = Instant::now();
        loop {
            if let Some(s) = self.child.try_wait().unwrap() {
                return s;
            }
            assert!(
                t.elapsed() < Duration::from_secs(30),
                "the daemon did not stop within 30 s of SIGTERM"
            );
            std::thread::sleep(Duration::from_millis(20));
        }
    }

    pub fn pid(&self) -> u32 {
        self.child.id()
    }

    pub fn rss_kib(&self) -> u64 {
        std::fs::read_to_string(format!("/proc/{}/status", self.pid()))
            .unwrap_or_default()
            .lines()
            .find(|l| l.starts_with("VmRSS:"))
            .and_then(|l| l.split_whitespace().nth(1)?.parse().ok())
            .unwrap_or(0)
    }
}

impl Drop for Daemon {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
        if std::thread::panicking() {
            let log = std::fs::read_to_string(&self.log).unwrap_or_default();
            let lines: Vec<&str> = log.lines().collect();
            let tail = &lines[lines.len().saturating_sub(120)..];
            println!(
                "--- the end of the daemon's log ({}):\n{}",
                self.log.display(),
                tail.join("\n")
            );
        }
    }
}

impl std::ops::Deref for Daemon {
    type Target = Client;
    fn deref(&self) -> &Client {
        &self.client
    }
}

impl std::ops::DerefMut for Daemon {
    fn deref_mut(&mut self) -> &mut Client {
        &mut self.client
    }
}

/// A daemon in this test process on the synthetic camera (no Aravis, so no
/// lock: these run side by side), serving real HTTP on 127.0.0.1 through
/// `polnlos::api::run`, as `polnlos serve` does. Stopped and drained on drop.
pub struct InProcess {
    client: Client,
    pub daemon: std::sync::Arc<polnlos::daemon::Daemon>,
    stop: Option<tokio::sync::oneshot::Sender<()>>,
    thread: Option<std::thread::JoinHandle<()>>,
}

impl InProcess {
    /// Starts the daemon `config` describes, on `data`, with the synthetic
    /// camera showing the config's demo scene; returns once the camera is
    /// connected.
    pub fn start(config: &Path, data: &Path) -> Self {
        use polnlos::daemon::{CameraSetup, Config, SceneRegistry};
        // No Aravis: the cores the camera tests leave idle are enough, for
        // this daemon and for what the test starts beside it (a browser,
        // schemathesis, Python).
        crate::priority::background();
        // The daemon's log, into the test's captured output (its threads
        // inherit the test thread's capture): shown when the test fails.
        let _ = tracing_subscriber::fmt()
            .with_test_writer()
            .with_max_level(tracing::Level::INFO)
            .try_init();
        let mut cfg = Config::load(config).expect("config");
        cfg.data_dir = data.to_path_buf();
        cfg.validate().expect("valid config");
        let (ready_tx, ready_rx) = std::sync::mpsc::channel();
        let (stop_tx, stop_rx) = tokio::sync::oneshot::channel::<()>();
        let thread = std::thread::spawn(move || {
            let rt = tokio::runtime::Builder::new_multi_thread()
                .worker_threads(2)
                .enable_all()
                .build()
                .expect("runtime");
            rt.block_on(async move {
                let listener = tokio::net::TcpListener::bind("127.0.0.1:0")
                    .await
                    .expect("bind 127.0.0.1");
                let port = listener.local_addr().expect("local address").port();
                let store = polnlos::store::Store::open(&cfg.data_dir).expect("data directory");
                let scenes = std::sync::Arc::new(
                    SceneRegistry::open(
                        &cfg.scene_files,
                        &cfg.data_dir,
                        polnlos::transport::MemoryBudget::DEFAULT,
                    )
                    .expect("scenes"),
                );
                let camera = CameraSetup::synthetic(&cfg, &scenes.now())
                    .await
                    .expect("synthetic camera");
                let d = polnlos::daemon::Daemon::start_with(cfg, store, scenes, camera)
                    .await
                    .expect("daemon starts");
                let _ = ready_tx.send((port, d.clone()));
                polnlos::api::run(listener, d, async {
                    let _ = stop_rx.await;
                })
                .await
                .expect("HTTP server");
            });
        });
        let (port, daemon) = ready_rx.recv().expect("in-process daemon did not start");
        let s = Self {
            client: Client::on_port(port),
            daemon,
            stop: Some(stop_tx),
            thread: Some(thread),
        };
        let t = Instant::now();
        while !s.daemon.camera().status().connected {
            assert!(
                t.elapsed() < Duration::from_secs(30),
                "camera did not connect"
            );
            std::thread::sleep(Duration::from_millis(20));
        }
        s
    }
}

impl std::ops::Deref for InProcess {
    type Target = Client;
    fn deref(&self) -> &Client {
        &self.client
    }
}

impl std::ops::DerefMut for InProcess {
    fn deref_mut(&mut self) -> &mut Client {
        &mut self.client
    }
}

impl InProcess {
    /// Stops the server and drains the daemon; its port then refuses
    /// connections, as a daemon that went away does.
    pub fn stop(&mut self) {
        if let Some(stop) = self.stop.take() {
            let _ = stop.send(());
        }
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

impl Drop for InProcess {
    fn drop(&mut self) {
        self.stop();
    }
}
