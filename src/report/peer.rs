//! polnlos against a straightforward vectorized NumPy implementation of the
//! same model and ADMM (`benches/peer/peer.py`, embedded here), run on the
//! same scene and measurement when `python3` with NumPy is on the PATH.
//!
//! Reports both speeds and checks that both give the same `T` and the same
//! recovery.

use std::path::Path;
use std::process::Command;

use serde::Serialize;

use super::{median, timed3, BenchError};
use crate::files::npy;
use crate::scene::{Grid, Scene};
use crate::simulate::patterns::Pattern;
use crate::simulate::{unpolarized_peak, NoiseModel};
use crate::solve::solvers::LAMBDA_REL;
use crate::solve::{metrics, Problem, SolveRequest, Solver};
use crate::transport::{build, MemoryBudget, Transport};

pub(crate) static SCRIPT: &str = include_str!("../../benches/peer/peer.py");

/// ADMM iterations timed on both sides.
pub(crate) const ITERATIONS: usize = 200;

/// The comparison, or why it did not run.
#[derive(Debug, Clone, Serialize)]
pub struct PeerReport {
    /// Built-in scene used.
    pub scene: String,
    /// Wall grid side.
    pub wall: usize,
    /// Scene grid side.
    pub scene_grid: usize,
    /// Why the peer did not run (no python3 / NumPy), if it did not.
    pub skipped: Option<String>,
    /// NumPy version.
    pub numpy: Option<String>,
    /// polnlos: median seconds to build `T` (3 runs).
    pub polnlos_build_seconds: f64,
    /// polnlos: median seconds for `T^T T` (3 runs).
    pub polnlos_gram_seconds: f64,
    /// polnlos: median seconds for the Cholesky factor and 200 ADMM iterations (3 runs).
    pub polnlos_solve_seconds: f64,
    /// NumPy: seconds to build `T`.
    pub peer_build_seconds: f64,
    /// NumPy: seconds for `T^T T` (and `T^T i`).
    pub peer_gram_seconds: f64,
    /// NumPy: seconds for the factor (Cholesky, its inverse, `D^T D`) and 200 iterations.
    pub peer_solve_seconds: f64,
    /// `peer / polnlos` for the build.
    pub build_speedup: f64,
    /// `peer / polnlos` for `T^T T`.
    pub gram_speedup: f64,
    /// `peer / polnlos` for factor + 200 iterations.
    pub solve_speedup: f64,
    /// `max |T_peer - T| / max |T|`.
    pub t_difference: f64,
    /// `max |l_peer - l|` of the recovered images.
    pub recovery_difference: f64,
    /// PSNR of polnlos's recovery, dB.
    pub polnlos_psnr_db: f64,
    /// PSNR of the peer's recovery, dB.
    pub peer_psnr_db: f64,
}

fn io(what: &str, e: impl std::fmt::Display) -> BenchError {
    BenchError::Peer(format!("{what}: {e}"))
}

/// Why the NumPy peer cannot run here (a bench then skips it, saying so).
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub(crate) enum NoNumpy {
    /// `python3` could not be started.
    #[error("python3 not found ({0})")]
    Python(String),
    /// `python3` runs but cannot import NumPy (what it printed).
    #[error("python3 has no NumPy ({0}); pip install numpy")]
    Import(String),
}

/// Whether `python3` with NumPy runs here: its NumPy version, or why not.
pub(crate) fn numpy_available() -> Result<String, NoNumpy> {
    let out = Command::new("python3")
        .args(["-c", "import numpy; print(numpy.__version__)"])
        .output()
        .map_err(|e| NoNumpy::Python(e.to_string()))?;
    if !out.status.success() {
        return Err(NoNumpy::Import(
            String::from_utf8_lossy(&out.stderr).trim().to_string(),
        ));
    }
    Ok(String::from_utf8_lossy(&out.stdout).trim().to_string())
}

/// Runs polnlos and the peer on `name` at the given grids, in `work`.
pub fn compare(
    name: &str,
    wall: usize,
    scene_grid: usize,
    work: &Path,
    budget: MemoryBudget,
) -> Result<PeerReport, BenchError> {
    let text = crate::scene::builtin::text(name)
        .ok_or_else(|| io("scene", format!("{name} is not built in")))?;
    let scene = super::edit(name, Scene::from_toml_str(text)?, |s| {
        s.wall.plane.grid = Grid { nu: wall, nv: wall };
        s.hidden.plane.grid = Grid {
            nu: scene_grid,
            nv: scene_grid,
        };
    })?;
    let mut report = unmeasured(name, wall, scene_grid);
    let ours = run_polnlos(&scene, budget, &mut report)?;

    let version = match numpy_available() {
        Ok(v) => v,
        Err(reason) => {
            report.skipped = Some(reason.to_string());
            return Ok(report);
        }
    };
    report.numpy = Some(version);
    let json = run_peer(work, text, wall, scene_grid, &ours.measurement)?;
    let secs = |k: &str| json[k].as_f64().unwrap_or(f64::NAN);
    report.peer_build_seconds = secs("build_seconds");
    report.peer_gram_seconds = secs("gram_seconds");
    report.peer_solve_seconds = secs("factor_seconds") + secs("iterate_seconds");
    report.build_speedup = report.peer_build_seconds / report.polnlos_build_seconds;
    report.gram_speedup = report.peer_gram_seconds / report.polnlos_gram_seconds;
    report.solve_speedup = report.peer_solve_seconds / report.polnlos_solve_seconds;

    check_agreement(work, &ours, &mut report)?;
    Ok(report)
}

/// A report for `name` at the given grids with nothing measured yet (every number NaN).
/// Each stage fills its own columns; a skipped peer leaves its columns NaN.
fn unmeasured(name: &str, wall: usize, scene_grid: usize) -> PeerReport {
    PeerReport {
        scene: name.into(),
        wall,
        scene_grid,
        skipped: None,
        numpy: None,
        polnlos_build_seconds: f64::NAN,
        polnlos_gram_seconds: f64::NAN,
        polnlos_solve_seconds: f64::NAN,
        peer_build_seconds: f64::NAN,
        peer_gram_seconds: f64::NAN,
        peer_solve_seconds: f64::NAN,
        build_speedup: f64::NAN,
        gram_speedup: f64::NAN,
        solve_speedup: f64::NAN,
        t_difference: f64::NAN,
        recovery_difference: f64::NAN,
        polnlos_psnr_db: f64::NAN,
        peer_psnr_db: f64::NAN,
    }
}

/// polnlos's side of the comparison: its `T`, the letter it simulated, the
/// noisy measurement and its recovery from it.
/// Kept after the timing because the peer is given this measurement and its
/// `T` and recovery are checked against these.
struct Ours {
    t: Transport,
    truth: Vec<f64>,
    measurement: Vec<f64>,
    image: Vec<f64>,
}

/// Times polnlos (build `T`, then Gram and factor + [`ITERATIONS`] ADMM
/// iterations, medians of 3 runs) on the letter at 2e4 photo-electrons.
/// Fills the report's polnlos columns and keeps what the peer is compared with.
fn run_polnlos(
    scene: &Scene,
    budget: MemoryBudget,
    report: &mut PeerReport,
) -> Result<Ours, BenchError> {
    let (t, build_seconds) = timed3(|| Ok(build(scene, budget)?))?;
    report.polnlos_build_seconds = build_seconds;
    let truth = Pattern::Letter.render(t.scene_grid());
    let peak = unpolarized_peak(scene, &t, &truth, budget)?;
    let sim = NoiseModel {
        photons: 2e4,
        ..NoiseModel::default()
    }
    .apply(t.apply(&truth), peak)
    .map_err(|e| io("simulation", e))?;
    // The peer's algorithm: lambda = rho = 1e-2 mean(diag(T^T T)), fixed
    // (no residual balancing), 200 iterations.
    let unit = t.mean_column_norm2();
    let request = SolveRequest {
        solver: Solver::ADMM_TV,
        lambda: Some(LAMBDA_REL * unit),
        rho: Some(LAMBDA_REL * unit),
        max_iter: Some(ITERATIONS),
        tol: Some(1e-300),
        rcond: None,
    };
    let problem = Problem::new(&t, &sim.measurement, request);
    let mut runs = Vec::new();
    for _ in 0..3 {
        let s = Solver::ADMM_TV.run(&problem)?.stats;
        runs.push((s.gram_seconds, s.factor_seconds + s.iterate_seconds));
    }
    report.polnlos_gram_seconds = median(runs.iter().map(|r| r.0).collect());
    report.polnlos_solve_seconds = median(runs.iter().map(|r| r.1).collect());
    let ours = Solver::ADMM_TV.run(&problem)?;
    report.polnlos_psnr_db = metrics::psnr(&truth, &ours.image);
    Ok(Ours {
        t,
        truth,
        measurement: sim.measurement,
        image: ours.image,
    })
}

/// Writes the peer script, the scene file `text` and `measurement` into
/// `work`, runs the peer there and returns its `peer.json` (its timings).
/// The peer reads the same scene file and measurement so that any difference
/// is the implementation's, not the inputs'.
fn run_peer(
    work: &Path,
    text: &str,
    wall: usize,
    scene_grid: usize,
    measurement: &[f64],
) -> Result<serde_json::Value, BenchError> {
    std::fs::create_dir_all(work).map_err(|e| io(&work.display().to_string(), e))?;
    let (script, scene_file, meas) = (
        work.join("peer.py"),
        work.join("scene.toml"),
        work.join("measurement.npy"),
    );
    std::fs::write(&script, SCRIPT).map_err(|e| io("peer.py", e))?;
    std::fs::write(&scene_file, text).map_err(|e| io("scene.toml", e))?;
    npy::write_f64(&meas, &[measurement.len()], measurement)
        .map_err(|e| io("measurement.npy", e))?;
    let out = Command::new("python3")
        .arg(&script)
        .arg(&scene_file)
        .args(["--wall", &wall.to_string()])
        .args(["--scene-grid", &scene_grid.to_string()])
        .arg("--measurement")
        .arg(&meas)
        .arg("--out")
        .arg(work)
        .output()
        .map_err(|e| io("python3", e))?;
    if !out.status.success() {
        return Err(io(
            "the NumPy peer failed",
            String::from_utf8_lossy(&out.stderr),
        ));
    }
    serde_json::from_slice(&std::fs::read(work.join("peer.json")).map_err(|e| io("peer.json", e))?)
        .map_err(|e| io("peer.json", e))
}

/// Reads the peer's `T.npy` and `recovered.npy` from `work` and fills the
/// report's differences from `ours` and the peer's PSNR.
/// Speed alone would not say the two solve the same problem; these say they do.
fn check_agreement(work: &Path, ours: &Ours, report: &mut PeerReport) -> Result<(), BenchError> {
    let t = &ours.t;
    let pt = npy::read(&work.join("T.npy")).map_err(|e| io("T.npy", e))?;
    if pt.shape != [t.rows(), t.cols()] {
        return Err(io(
            "T.npy",
            format!("shape {:?}, expected {}x{}", pt.shape, t.rows(), t.cols()),
        ));
    }
    let ours_rm = t.to_row_major();
    let scale = ours_rm.iter().fold(0.0f64, |a, v| a.max(v.abs()));
    report.t_difference = pt
        .data
        .iter()
        .zip(&ours_rm)
        .map(|(a, b)| (a - b).abs())
        .fold(0.0, f64::max)
        / scale;
    let rec = npy::read(&work.join("recovered.npy")).map_err(|e| io("recovered.npy", e))?;
    report.recovery_difference = rec
        .data
        .iter()
        .zip(&ours.image)
        .map(|(a, b)| (a - b).abs())
        .fold(0.0, f64::max);
    report.peer_psnr_db = metrics::psnr(&ours.truth, &rec.data);
    Ok(())
}

impl super::Report for PeerReport {
    fn json(&self) -> serde_json::Map<String, serde_json::Value> {
        super::shape::fields(vec![("peer", serde_json::to_value(self))])
    }

    fn charts(&self) -> Result<Vec<(String, super::charts::Chart)>, super::charts::ChartError> {
        Ok(Vec::new())
    }

    fn markdown(&self) -> String {
        use super::fmt_seconds as t;
        use std::fmt::Write as _;
        let p = self;
        let mut md = format!(
            "## Against a NumPy peer\n\nScene {0}, wall {1}x{1}, scene {2}x{2} (T {3} x {4}); `benches/peer/peer.py`, same scene file and measurement.\n\n",
            p.scene,
            p.wall,
            p.scene_grid,
            p.wall * p.wall * 2,
            p.scene_grid * p.scene_grid
        );
        if let Some(why) = &p.skipped {
            let _ = writeln!(
                md,
                "Peer skipped: {why}. polnlos alone: build {}, T^T T {}, factorization + {ITERATIONS} ADMM iterations {}.\n",
                t(p.polnlos_build_seconds),
                t(p.polnlos_gram_seconds),
                t(p.polnlos_solve_seconds)
            );
            return md;
        }
        let _ = writeln!(
            md,
            "| step | polnlos | NumPy {} | speed-up |\n|---|---|---|---|\n| build T | {} | {} | {:.1}x |\n| T^T T (dense product; NumPy: OpenBLAS syrk) | {} | {} | {:.1}x |\n| factorization + {ITERATIONS} ADMM iterations | {} | {} | {:.1}x |\n\nSame T: max |T_numpy - T| / max |T| = {:.1e}. Same recovery: max |l_numpy - l| = {:.1e}; PSNR {:.2} dB (polnlos) and {:.2} dB (NumPy).\n",
            p.numpy.as_deref().unwrap_or("?"),
            t(p.polnlos_build_seconds),
            t(p.peer_build_seconds),
            p.build_speedup,
            t(p.polnlos_gram_seconds),
            t(p.peer_gram_seconds),
            p.gram_speedup,
            t(p.polnlos_solve_seconds),
            t(p.peer_solve_seconds),
            p.solve_speedup,
            p.t_difference,
            p.recovery_difference,
            p.polnlos_psnr_db,
            p.peer_psnr_db
        );
        md
    }
}
