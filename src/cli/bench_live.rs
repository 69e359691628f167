//! `polnlos bench --live`: live view's results a second and frame-to-result
//! latency against the scene grid and the wall size, beside the offline
//! reconstruction of a capture of the same window, and optionally a long
//! session's memory (issue 49).
//!
//! Each configuration runs `polnlos serve` (this binary) on Aravis's fake
//! camera in a child process on 127.0.0.1, as a lab runs it, and talks to
//! it over HTTP; the rows go to [`polnlos::report::LiveReport`].

use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use anyhow::{bail, Context};
use serde_json::{json, Value};

use polnlos::report::{LiveReport, LiveRow, SoakSample};

/// One bench configuration: the wall's and the hidden scene's grids and
/// the fake camera's sensor.
#[derive(Debug, Clone, Copy)]
struct Case {
    wall: [usize; 2],
    grid: [usize; 2],
    /// `[camera] fake_sensor`: "mono", or "bayer" (three colours).
    sensor: &'static str,
}

/// The full sweep: the demo bench, finer scene grids, larger walls, and a
/// chair-size colour scene (126 x 126 wall, 36 x 29 scene, three colours).
const FULL: [Case; 6] = [
    Case {
        wall: [32, 32],
        grid: [8, 8],
        sensor: "mono",
    },
    Case {
        wall: [32, 32],
        grid: [16, 16],
        sensor: "mono",
    },
    Case {
        wall: [64, 64],
        grid: [16, 16],
        sensor: "mono",
    },
    Case {
        wall: [64, 64],
        grid: [32, 32],
        sensor: "mono",
    },
    Case {
        wall: [126, 126],
        grid: [32, 32],
        sensor: "mono",
    },
    Case {
        wall: [126, 126],
        grid: [36, 29],
        sensor: "bayer",
    },
];

/// Frames of a live window and of the offline capture, and their exposure.
const WINDOW: usize = 8;
const EXPOSURE_US: f64 = 20_000.0;

/// The scene file every configuration edits: the demo bench's crossed pose.
const BASE_SCENE: &str = "brewster-crossed";
/// The stem of the edited scene file, so the name the daemon knows it by.
const SCENE: &str = "bench-live";

/// How long a daemon may take to come up, a job to finish, live view to
/// give its first results.
const READY: Duration = Duration::from_secs(60);
const JOB: Duration = Duration::from_secs(300);
/// How often a long session's memory is read: within the daemon's 10 s
/// idle-connection timeout (`[http] header_timeout_s`), so that the kept
/// connection is never the one the daemon is closing.
const SOAK_EVERY: Duration = Duration::from_secs(5);
/// How often a job's state is read: the offline time is read to within it.
const POLL: Duration = Duration::from_millis(20);

/// What `polnlos bench --live` measures.
#[derive(Debug, Clone, Copy)]
pub(super) struct Selection {
    /// One configuration (the demo bench) only.
    pub(super) quick: bool,
    /// Seconds each live session is measured for, after its first results.
    pub(super) seconds: f64,
    /// Minutes the first configuration's session is then held for, its
    /// memory read every five seconds (0: none).
    pub(super) soak_minutes: f64,
    /// Loopback address of the fake cameras.
    pub(super) camera_address: std::net::Ipv4Addr,
}

/// Runs the sweep (and the long session) and returns its report. Its
/// working folder (scene files, configurations, daemon logs) is removed
/// when it succeeds and kept when it fails: the error names a log in it.
pub(super) fn run(s: Selection, tick: &mut dyn FnMut()) -> anyhow::Result<LiveReport> {
    let work = std::env::temp_dir().join(format!("polnlos-bench-live-{}", std::process::id()));
    let report = sweep(s, &work, tick)?;
    let _ = std::fs::remove_dir_all(&work);
    Ok(report)
}

/// Configurations `polnlos bench --live` runs, for its progress bar.
pub(super) fn steps(quick: bool) -> usize {
    if quick {
        1
    } else {
        FULL.len()
    }
}

fn sweep(s: Selection, work: &Path, tick: &mut dyn FnMut()) -> anyhow::Result<LiveReport> {
    let cases: &[Case] = if s.quick { &FULL[..1] } else { &FULL };
    let mut report = LiveReport::default();
    for (k, case) in cases.iter().enumerate() {
        let soak = (k == 0 && s.soak_minutes > 0.0).then_some(s.soak_minutes);
        let dir = work.join(format!("case-{k}"));
        let (row, samples) = measure(case, &dir, &s, soak)
            .with_context(|| format!("live bench, wall {:?}, scene {:?}", case.wall, case.grid))?;
        report.rows.push(row);
        report.soak.extend(samples);
        tick();
    }
    Ok(report)
}

/// One configuration: a daemon showing the letter on the edited scene,
/// a live session measured for `seconds` (then held `soak` minutes), and
/// after it a capture of one window reconstructed offline, both with the
/// fake camera's calibrated gain (`"radiometry": "calibrated"`: without a
/// colour calibration both would fit a colour camera's gains and
/// backgrounds, the radiometry of a photo, not of this bench).
fn measure(
    case: &Case,
    dir: &Path,
    s: &Selection,
    soak: Option<f64>,
) -> anyhow::Result<(LiveRow, Vec<SoakSample>)> {
    std::fs::create_dir_all(dir).with_context(|| format!("cannot create {}", dir.display()))?;
    let scene = dir.join(format!("{SCENE}.toml"));
    std::fs::write(&scene, scene_text(case)?)?;
    let config = dir.join("polnlos.toml");
    std::fs::write(&config, config_text(&scene, case.sensor, s.camera_address)?)?;
    let daemon = Daemon::start(&config, &dir.join("data"), &dir.join("daemon.log"))?;

    let request = json!({
        "scene": SCENE, "pose": "A", "polarizer_deg": 0, "exposure_us": EXPOSURE_US,
        "frames": WINDOW, "dark_frames": 2,
    });
    let mut live = request.clone();
    live["progressive"] = json!({ "truth": "letter", "radiometry": "calibrated" });
    daemon.send("POST", "/live", Some(&live), 202)?;
    let first = daemon.wait_live(|v| count(v, "results") >= 3)?;
    let session = Session::watch(&daemon, first, Duration::from_secs_f64(s.seconds))?;
    let samples = match soak {
        Some(minutes) => soak_session(&daemon, minutes)?,
        None => Vec::new(),
    };
    let end = daemon.send("DELETE", "/live", None, 200)?;

    let capture = daemon.run_job("/captures", &request)?;
    let id = capture["id"].as_i64().context("a capture id")?;
    let asked = Instant::now();
    let rec = daemon.run_job(
        "/reconstructions",
        &json!({
            "scene": SCENE, "captures": [id], "truth": "letter", "radiometry": "calibrated",
        }),
    )?;
    let offline_seconds = asked.elapsed().as_secs_f64();
    let row = LiveRow {
        wall: case.wall,
        grid: case.grid,
        colours: if case.sensor == "bayer" { 3 } else { 1 },
        window: WINDOW,
        exposure_us: EXPOSURE_US,
        results: count(&end, "results"),
        frames_not_solved: count(&end, "frames_not_solved"),
        results_per_second: session.rate,
        median_latency_ms: end["median_latency_ms"].as_f64().unwrap_or(f64::NAN),
        live_psnr_db: median(session.psnr),
        offline_psnr_db: rec["report"]["metrics"]["psnr_db"]
            .as_f64()
            .unwrap_or(f64::NAN),
        offline_seconds,
        rss_mib: daemon.rss_mib(),
    };
    Ok((row, samples))
}

/// The built-in crossed scene with the case's wall and scene grids.
fn scene_text(case: &Case) -> anyhow::Result<String> {
    let text = polnlos::scene::builtin::text(BASE_SCENE).context("the built-in crossed scene")?;
    let mut t: toml::Table = toml::from_str(text)?;
    for (key, grid) in [("wall", case.wall), ("scene", case.grid)] {
        let table = t
            .get_mut(key)
            .and_then(|v| v.as_table_mut())
            .with_context(|| format!("[{key}] in the built-in crossed scene"))?;
        table.insert("grid".into(), toml::Value::try_from(grid)?);
    }
    Ok(toml::to_string(&t)?)
}

/// The embedded default configuration, the fake camera on `camera` showing
/// the letter on `scene` through `sensor`.
fn config_text(scene: &Path, sensor: &str, camera: std::net::Ipv4Addr) -> anyhow::Result<String> {
    let mut t: toml::Table = toml::from_str(polnlos::daemon::DEFAULT_TOML)?;
    t.insert(
        "scene_files".into(),
        toml::Value::Array(vec![scene.display().to_string().into()]),
    );
    let mut set = |table: &str, key: &str, value: &str| -> anyhow::Result<()> {
        t.get_mut(table)
            .and_then(|v| v.as_table_mut())
            .with_context(|| format!("[{table}] in the embedded configuration"))?
            .insert(key.into(), value.into());
        Ok(())
    };
    set("camera", "fake_sensor", sensor)?;
    set("camera", "address", &camera.to_string())?;
    set("demo", "scene", SCENE)?;
    set("demo", "pattern", "letter")?;
    Ok(toml::to_string(&t)?)
}

/// What one live session gave between two readings of `GET /live`.
struct Session {
    /// Results a second between the readings.
    rate: f64,
    /// PSNR of every result seen, dB.
    psnr: Vec<f64>,
}

impl Session {
    /// Reads `GET /live` every 100 ms for `span` after `first`.
    fn watch(d: &Daemon, first: Value, span: Duration) -> anyhow::Result<Self> {
        let (start, results0) = (Instant::now(), count(&first, "results"));
        let (mut seen, mut psnr) = (results0, Vec::new());
        let mut last = first;
        while start.elapsed() < span {
            std::thread::sleep(Duration::from_millis(100));
            last = d.send("GET", "/live", None, 200)?;
            if last["state"] != "running" {
                bail!("live view is {} during the bench: {last}", last["state"]);
            }
            let n = count(&last, "results");
            if n > seen {
                seen = n;
                psnr.extend(last["last"]["psnr_db"].as_f64());
            }
        }
        let rate = (count(&last, "results") - results0) as f64 / start.elapsed().as_secs_f64();
        Ok(Self { rate, psnr })
    }
}

/// Holds the running session `minutes`, reading the daemon's memory and
/// rate every [`SOAK_EVERY`].
fn soak_session(d: &Daemon, minutes: f64) -> anyhow::Result<Vec<SoakSample>> {
    let (start, mut out) = (Instant::now(), Vec::new());
    let span = Duration::from_secs_f64(minutes * 60.0);
    loop {
        let v = d.send("GET", "/live", None, 200)?;
        if v["state"] != "running" {
            bail!("live view is {} during the long session: {v}", v["state"]);
        }
        out.push(SoakSample {
            minutes: start.elapsed().as_secs_f64() / 60.0,
            rss_mib: d.rss_mib(),
            results: count(&v, "results"),
            results_per_second: v["results_per_second"].as_f64().unwrap_or(0.0),
        });
        if start.elapsed() >= span {
            return Ok(out);
        }
        std::thread::sleep(SOAK_EVERY.min(span.saturating_sub(start.elapsed())));
    }
}

fn count(v: &Value, key: &str) -> u64 {
    v[key].as_u64().unwrap_or(0)
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v.get(v.len() / 2).copied().unwrap_or(f64::NAN)
}

/// `polnlos serve` in a child process on a free loopback port, killed on drop.
struct Daemon {
    child: Child,
    base: String,
    agent: ureq::Agent,
    log: PathBuf,
}

impl Daemon {
    /// Starts it and waits until its camera is connected.
    fn start(config: &Path, data: &Path, log: &Path) -> anyhow::Result<Self> {
        let port = std::net::TcpListener::bind("127.0.0.1:0")
            .and_then(|l| l.local_addr())
            .context("no free loopback port")?
            .port();
        let exe = std::env::current_exe().context("cannot find this program to run its daemon")?;
        let child = Command::new(exe)
            .arg("serve")
            .arg("--config")
            .arg(config)
            .args(["--bind", &format!("127.0.0.1:{port}"), "--data-dir"])
            .arg(data)
            .stdout(Stdio::null())
            .stderr(std::fs::File::create(log)?)
            .spawn()
            .context("cannot start polnlos serve")?;
        let d = Self {
            child,
            base: format!("http://127.0.0.1:{port}"),
            agent: ureq::Agent::config_builder()
                .http_status_as_error(false)
                .timeout_global(Some(Duration::from_secs(30)))
                .build()
                .into(),
            log: log.to_path_buf(),
        };
        let t = Instant::now();
        while t.elapsed() < READY {
            if let Ok(v) = d.send("GET", "/health", None, 200) {
                if v["camera_connected"] == true {
                    return Ok(d);
                }
            }
            std::thread::sleep(Duration::from_millis(100));
        }
        bail!(
            "the daemon's camera did not connect within {} s; see {}",
            READY.as_secs(),
            d.log.display()
        )
    }

    /// One request; its JSON body, or an error unless the status is `want`.
    fn send(
        &self,
        method: &str,
        path: &str,
        body: Option<&Value>,
        want: u16,
    ) -> anyhow::Result<Value> {
        let url = format!("{}{path}", self.base);
        let sent = match (method, body) {
            ("POST", Some(b)) => self.agent.post(&url).send_json(b),
            ("DELETE", _) => self.agent.delete(&url).call(),
            _ => self.agent.get(&url).call(),
        };
        let mut r = sent.with_context(|| format!("{method} {path}"))?;
        let status = r.status().as_u16();
        let text = r.body_mut().read_to_string().unwrap_or_default();
        if status != want {
            bail!(
                "{method} {path}: {status} {text} (see {})",
                self.log.display()
            );
        }
        serde_json::from_str(&text).with_context(|| format!("{method} {path}: {text}"))
    }

    /// POSTs a job and waits until it is done; its record.
    fn run_job(&self, path: &str, body: &Value) -> anyhow::Result<Value> {
        let id = self.send("POST", path, Some(body), 202)?["id"]
            .as_i64()
            .with_context(|| format!("POST {path}: no id"))?;
        let t = Instant::now();
        while t.elapsed() < JOB {
            let v = self.send("GET", &format!("{path}/{id}"), None, 200)?;
            match v["state"].as_str() {
                Some("done") => return Ok(v),
                Some("queued" | "running") => std::thread::sleep(POLL),
                _ => bail!("{path}/{id} ended {}: {}", v["state"], v["error"]),
            }
        }
        bail!("{path}/{id} not done within {} s", JOB.as_secs())
    }

    /// Waits until `GET /live` satisfies `until`.
    fn wait_live(&self, until: impl Fn(&Value) -> bool) -> anyhow::Result<Value> {
        let t = Instant::now();
        loop {
            let v = self.send("GET", "/live", None, 200)?;
            if until(&v) {
                return Ok(v);
            }
            if v["state"] == "failed" || t.elapsed() > READY {
                bail!("live view did not start: {v}");
            }
            std::thread::sleep(Duration::from_millis(100));
        }
    }

    /// The child's resident memory, MiB (NaN when unreadable).
    fn rss_mib(&self) -> f64 {
        std::fs::read_to_string(format!("/proc/{}/status", self.child.id()))
            .ok()
            .and_then(|s| {
                s.lines()
                    .find(|l| l.starts_with("VmRSS:"))
                    .and_then(|l| l.split_whitespace().nth(1)?.parse::<f64>().ok())
            })
            .map_or(f64::NAN, |kib| kib / 1024.0)
    }
}

impl Drop for Daemon {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}
