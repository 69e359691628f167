//! Soak: `polnlos serve` (Aravis fake camera, 127.0.0.1 only) under a mixed
//! load from several client threads, killed with SIGKILL at random moments
//! and restarted, for a bounded time. After every kill it checks that every
//! capture and reconstruction that was done is still done with byte-identical
//! files and that SQLite's integrity check passes; it prints requests held,
//! status counts, p50/p99 latency, RSS growth within each run and the kill
//! rounds survived. Not part of `cargo test`: `cargo bench --bench soak`
//! (`SOAK_SECONDS`, default 120; `SOAK_SEED`, default 1; `SOAK_MAX_LIFE`,
//! the longest a daemon lives before its kill, default 20 s).

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use rand::{Rng, SeedableRng};
use sha2::{Digest, Sha256};

struct Run {
    child: Child,
    base: String,
}

fn free_port() -> u16 {
    std::net::TcpListener::bind("127.0.0.1:0")
        .and_then(|l| l.local_addr())
        .map(|a| a.port())
        .expect("a free loopback port")
}

fn agent() -> ureq::Agent {
    ureq::Agent::config_builder()
        .http_status_as_error(false)
        .timeout_global(Some(Duration::from_secs(10)))
        .build()
        .into()
}

fn start(data: &Path, log: &Path) -> Run {
    let port = free_port();
    let mut child = Command::new(env!("CARGO_BIN_EXE_polnlos"))
        .args([
            "serve",
            "--bind",
            &format!("127.0.0.1:{port}"),
            "--data-dir",
        ])
        .arg(data)
        .stdout(Stdio::null())
        .stderr(std::fs::File::create(log).expect("log file"))
        .spawn()
        .expect("spawn polnlos serve");
    let base = format!("http://127.0.0.1:{port}");
    let a = agent();
    let t = Instant::now();
    while t.elapsed() < Duration::from_secs(30) {
        if let Ok(mut r) = a.get(format!("{base}/health")).call() {
            if r.body_mut()
                .read_to_string()
                .unwrap_or_default()
                .contains("\"camera_connected\":true")
            {
                return Run { child, base };
            }
        }
        std::thread::sleep(Duration::from_millis(100));
    }
    let _ = child.kill();
    let _ = child.wait();
    panic!("daemon did not come up; see {}", log.display());
}

fn rss_kib(pid: u32) -> u64 {
    std::fs::read_to_string(format!("/proc/{pid}/status"))
        .unwrap_or_default()
        .lines()
        .find(|l| l.starts_with("VmRSS:"))
        .and_then(|l| l.split_whitespace().nth(1)?.parse().ok())
        .unwrap_or(0)
}

/// sha256 of every file of every done job: what a kill must not change.
fn snapshot(data: &Path) -> BTreeMap<PathBuf, String> {
    let conn = rusqlite::Connection::open(data.join("catalogue.sqlite")).expect("catalogue");
    let mut out = BTreeMap::new();
    for (table, folder) in [
        ("captures", "captures"),
        ("reconstructions", "reconstructions"),
    ] {
        let mut st = conn
            .prepare(&format!("SELECT id FROM {table} WHERE state = 'done'"))
            .expect("query");
        let ids: Vec<i64> = st
            .query_map([], |r| r.get(0))
            .expect("rows")
            .flatten()
            .collect();
        for id in ids {
            let dir = data.join(folder).join(id.to_string());
            for e in std::fs::read_dir(&dir).into_iter().flatten().flatten() {
                let bytes = std::fs::read(e.path()).unwrap_or_default();
                out.insert(e.path(), format!("{:x}", Sha256::digest(&bytes)));
            }
        }
    }
    out
}

fn integrity_ok(data: &Path) -> bool {
    rusqlite::Connection::open(data.join("catalogue.sqlite"))
        .and_then(|c| c.query_row("PRAGMA integrity_check", [], |r| r.get::<_, String>(0)))
        .map(|s| s == "ok")
        .unwrap_or(false)
}

#[derive(Default)]
struct Tally {
    latencies_us: Vec<u64>,
    statuses: BTreeMap<u16, u64>,
    refused: u64,
}

fn load(base: String, stop: Arc<AtomicBool>, tally: Arc<Mutex<Tally>>, seed: u64) {
    let a = agent();
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    while !stop.load(Ordering::Relaxed) {
        let pick = rng.random_range(0..100);
        let t = Instant::now();
        let r = match pick {
            0..=29 => a.get(format!("{base}/health")).call(),
            30..=44 => a.get(format!("{base}/captures?limit=20")).call(),
            45..=54 => a.get(format!("{base}/camera")).call(),
            55..=64 => a.get(format!("{base}/metrics")).call(),
            65..=74 => a
                .get(format!("{base}/captures/{}/mean.tiff", rng.random_range(1..40)))
                .call(),
            75..=89 => a
                .post(format!("{base}/captures"))
                .header("content-type", "application/json")
                .send(format!(
                    r#"{{"scene": "brewster-crossed-3x3", "pose": "A", "polarizer_deg": 0, "exposure_us": {}, "frames": {}}}"#,
                    rng.random_range(2000..20000),
                    rng.random_range(1..4)
                )),
            90..=94 => a
                .post(format!("{base}/reconstructions"))
                .header("content-type", "application/json")
                .send(format!(
                    r#"{{"scene": "brewster-crossed-3x3", "captures": [{}], "lambda": 0.01}}"#,
                    rng.random_range(1..40)
                )),
            _ => a
                .post(format!("{base}/captures"))
                .header("content-type", "application/json")
                .send("{\"scene\": 5}"),
        };
        let us = t.elapsed().as_micros() as u64;
        let mut tl = tally.lock().unwrap_or_else(|e| e.into_inner());
        match r {
            Ok(resp) => {
                tl.latencies_us.push(us);
                *tl.statuses.entry(resp.status().as_u16()).or_insert(0) += 1;
            }
            // The daemon is being killed or restarted.
            Err(_) => tl.refused += 1,
        }
    }
}

fn percentile(sorted: &[u64], p: f64) -> f64 {
    if sorted.is_empty() {
        return 0.0;
    }
    sorted[((sorted.len() - 1) as f64 * p).round() as usize] as f64 / 1000.0
}

fn main() {
    let seconds: u64 = std::env::var("SOAK_SECONDS")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(120);
    let seed: u64 = std::env::var("SOAK_SEED")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(1);
    let max_life: u64 = std::env::var("SOAK_MAX_LIFE")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(20)
        .max(6);
    let dir = tempfile::tempdir().expect("scratch folder");
    let data = dir.path().join("data");
    let log = dir.path().join("daemon.log");
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    let tally = Arc::new(Mutex::new(Tally::default()));
    let deadline = Instant::now() + Duration::from_secs(seconds);
    let (mut rounds, mut checked_files, mut rss_growth) = (0u32, 0usize, Vec::new());
    println!("soak: {seconds} s, seed {seed}, 4 client threads, SIGKILL every 5-{max_life} s");
    while Instant::now() < deadline {
        let mut run = start(&data, &log);
        let pid = run.child.id();
        std::thread::sleep(Duration::from_millis(500));
        let rss0 = rss_kib(pid);
        let stop = Arc::new(AtomicBool::new(false));
        let clients: Vec<_> = (0..4)
            .map(|k: u64| {
                let (b, s, t) = (run.base.clone(), stop.clone(), tally.clone());
                let seed: u64 = rng.random();
                std::thread::spawn(move || load(b, s, t, seed ^ k))
            })
            .collect();
        let life = Duration::from_millis(rng.random_range(5_000..max_life * 1000));
        let until = (Instant::now() + life).min(deadline);
        let mut rss_mid = 0;
        let half = Instant::now() + life / 2;
        while Instant::now() < until {
            std::thread::sleep(Duration::from_millis(100));
            if rss_mid == 0 && Instant::now() >= half {
                rss_mid = rss_kib(pid);
            }
        }
        let rss1 = rss_kib(pid);
        rss_growth.push(rss1 as i64 - rss0 as i64);
        let before = snapshot(&data);
        // SIGKILL, mid-whatever it was doing.
        let _ = run.child.kill();
        let _ = run.child.wait();
        stop.store(true, Ordering::Relaxed);
        for c in clients {
            let _ = c.join();
        }
        assert!(
            integrity_ok(&data),
            "PRAGMA integrity_check failed after kill {rounds}"
        );
        let after = snapshot(&data);
        for (path, hash) in &before {
            assert_eq!(
                after.get(path),
                Some(hash),
                "{} changed or vanished after a kill",
                path.display()
            );
        }
        checked_files += before.len();
        rounds += 1;
        println!(
            "  round {rounds}: killed after {:.1} s, RSS {rss0} -> {rss_mid} (half-way) -> {rss1} KiB, {} done files intact",
            life.as_secs_f64(),
            before.len()
        );
    }
    // A last start: the previous run's queued and running jobs read interrupted, nothing else moved.
    let before = snapshot(&data);
    let mut run = start(&data, &log);
    let after = snapshot(&data);
    assert_eq!(before, after, "a restart changed done files");
    let _ = run.child.kill();
    let _ = run.child.wait();
    let t = tally.lock().unwrap_or_else(|e| e.into_inner());
    let mut lat = t.latencies_us.clone();
    lat.sort_unstable();
    let answered: u64 = t.statuses.values().sum();
    let server_errors: u64 = t
        .statuses
        .iter()
        .filter(|(s, _)| **s >= 500)
        .map(|(_, n)| n)
        .sum();
    let max_growth = rss_growth.iter().copied().max().unwrap_or(0);
    println!("kill rounds survived: {rounds} (integrity_check ok, {checked_files} done-file checks, all byte-identical)");
    println!("requests answered: {answered} (5xx: {server_errors}); not answered while killed/restarting: {}", t.refused);
    println!("statuses: {:?}", t.statuses);
    println!(
        "latency p50 {:.2} ms, p99 {:.2} ms",
        percentile(&lat, 0.5),
        percentile(&lat, 0.99)
    );
    println!(
        "RSS growth within a run: max {max_growth} KiB over {} runs",
        rss_growth.len()
    );
    assert_eq!(server_errors, 0, "5xx answers under load");
}
