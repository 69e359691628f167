//! Reconstruction time against the scene grid, end to end: `polnlos
//! reconstruct` run as a user runs it (fixed λ and automatic λ), its peak
//! memory, and the NumPy peer's fixed-λ ADMM (500 iterations, solve only,
//! `T` given) on the same scene file and measurement, beside the arithmetic
//! floor of a dense solve.
//!
//! Each reconstruction is a child process so that its wall time includes
//! everything (T, Gram, conditioning, noise estimate, λ trials) and its peak
//! resident set is its own (`VmHWM`).

use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::Instant;

use serde::Serialize;

use super::charts::{panels, Chart, ChartError, Marker, Plot, Series};
use super::BenchError;
use crate::files::npy;
use crate::scene::{Grid, Scene};
use crate::simulate::patterns::Pattern;
use crate::simulate::{unpolarized_peak, NoiseModel};
use crate::solve::solvers::LAMBDA_REL;
use crate::transport::{build, MemoryBudget};

/// Built-in scene of the sweep: two crossed poses (B, C).
pub const SCENE: &str = "brewster-multi";
/// Photo-electrons at the brightest element of the unpolarized image.
pub const PHOTONS: f64 = 1e4;
/// Iterations of the NumPy peer's fixed-λ ADMM.
pub(crate) const PEER_ITERATIONS: usize = 500;
/// Dense GEMM rate of the two cores the floor assumes, flop/s.
pub(crate) const FLOOR_RATE: f64 = 100e9;

/// One scene grid of the sweep.
#[derive(Debug, Clone, Serialize)]
pub struct ScalingRow {
    /// Scene grid side.
    pub grid: usize,
    /// Rows and columns of `T`.
    pub shape: (usize, usize),
    /// Seconds to build `T` (as the reconstruction reports it).
    pub transport_seconds: f64,
    /// Wall time of `polnlos reconstruct --lambda 1e-2 x mean(diag(T^T T))`.
    pub fixed_seconds: f64,
    /// Wall time of `polnlos reconstruct` (automatic λ).
    pub auto_seconds: f64,
    /// PSNR of the two, dB.
    pub fixed_psnr_db: f64,
    /// PSNR with the automatic λ, dB.
    pub auto_psnr_db: f64,
    /// Peak resident set of the two, MB.
    pub fixed_rss_mb: f64,
    /// Peak resident set with the automatic λ, MB.
    pub auto_rss_mb: f64,
    /// `1.5 x (size of T + size of the Gram)`, MB: the memory goal.
    pub rss_budget_mb: f64,
    /// Rank the reconstruction reported (to the Gram's resolution on large grids).
    pub rank: usize,
    /// The NumPy peer: Gram + factor + 500 iterations, seconds (`None`: not run).
    pub peer_seconds: Option<f64>,
    /// The peer's PSNR, dB.
    pub peer_psnr_db: Option<f64>,
    /// Dense floor: `(2 M N^2 + N^3 / 3 + 500 * 2 N^2) / FLOOR_RATE`, seconds.
    pub floor_seconds: f64,
}

/// The sweep and why the peer did not run, if it did not.
#[derive(Debug, Clone, Serialize)]
pub struct Scaling {
    /// Wall grid side.
    pub wall: usize,
    /// One row per scene grid.
    pub rows: Vec<ScalingRow>,
    /// Why the NumPy peer was skipped.
    pub peer_skipped: Option<String>,
}

fn err(what: &str, e: impl std::fmt::Display) -> BenchError {
    BenchError::Peer(format!("scaling sweep, {what}: {e}"))
}

/// The high-water resident set of process `pid`, kB (`VmHWM`), if readable.
fn high_water_kb(pid: u32) -> Option<u64> {
    let status = std::fs::read_to_string(format!("/proc/{pid}/status")).ok()?;
    let line = status.lines().find(|l| l.starts_with("VmHWM:"))?;
    line.split_whitespace().nth(1)?.parse().ok()
}

/// Runs `cmd`, returns (wall seconds, peak RSS in MB). The peak is the
/// child's `VmHWM`, polled every few milliseconds while it runs: unlike
/// `ru_maxrss` it starts afresh at `exec`, so it is not the spawning bench's
/// own size (a spawn shares the parent's memory until `exec`).
fn run_measured(mut cmd: Command) -> Result<(f64, f64), BenchError> {
    let start = Instant::now();
    let mut child = cmd
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .map_err(|e| err("spawn", e))?;
    let mut peak_kb = 0;
    let status = loop {
        if let Some(kb) = high_water_kb(child.id()) {
            peak_kb = peak_kb.max(kb);
        }
        match child.try_wait().map_err(|e| err("wait", e))? {
            Some(status) => break status,
            None => std::thread::sleep(std::time::Duration::from_millis(5)),
        }
    };
    let seconds = start.elapsed().as_secs_f64();
    if !status.success() {
        let mut stderr = String::new();
        if let Some(mut e) = child.stderr.take() {
            use std::io::Read;
            let _ = e.read_to_string(&mut stderr);
        }
        return Err(err("reconstruct failed", stderr));
    }
    Ok((seconds, peak_kb as f64 / 1024.0))
}

fn report_field(dir: &Path, f: impl Fn(&serde_json::Value) -> Option<f64>) -> f64 {
    std::fs::read(dir.join("report.json"))
        .ok()
        .and_then(|b| serde_json::from_slice::<serde_json::Value>(&b).ok())
        .and_then(|v| f(&v))
        .unwrap_or(f64::NAN)
}

/// Runs the sweep over `grids` at wall `wall` in `work`, with `exe` the
/// polnlos binary, calling `step()` after each grid.
pub(crate) fn scaling_sweep(
    exe: &Path,
    wall: usize,
    grids: &[usize],
    work: &Path,
    budget: MemoryBudget,
    step: &mut dyn FnMut(),
) -> Result<Scaling, BenchError> {
    std::fs::create_dir_all(work).map_err(|e| err("work folder", e))?;
    let text = crate::scene::builtin::text(SCENE).ok_or_else(|| err("scene", SCENE))?;
    let numpy = super::peer::numpy_available();
    let peer_skipped = numpy.as_ref().err().map(ToString::to_string);
    let script = work.join("peer.py");
    std::fs::write(&script, super::peer::SCRIPT).map_err(|e| err("peer.py", e))?;
    let mut rows = Vec::new();
    for &g in grids {
        let input = write_inputs(text, wall, g, work, budget)?;
        let fixed = reconstruct(exe, &input, input.dir.join("fixed"), Some(input.lambda))?;
        let auto = reconstruct(exe, &input, input.dir.join("auto"), None)?;
        let peer = if numpy.is_ok() {
            Some(run_peer(&script, &input, wall)?)
        } else {
            None
        };
        rows.push(scaling_row(&input, &fixed, &auto, peer));
        let _ = std::fs::remove_dir_all(&input.dir);
        step();
    }
    Ok(Scaling {
        wall,
        rows,
        peer_skipped,
    })
}

/// One scene grid's inputs on disk, in their own folder, and what the row
/// needs of `T` (its shape, the fixed λ) and of the truth.
/// Both reconstructions and the peer read these same files, so they solve
/// the same problem; `T` itself is not kept.
struct GridInput {
    grid: usize,
    dir: PathBuf,
    scene_file: PathBuf,
    measurement: PathBuf,
    truth_file: PathBuf,
    truth: Vec<f64>,
    lambda: f64,
    shape: (usize, usize),
}

/// Writes grid `g`'s scene file, simulated measurement and truth into
/// `work/grid-{g}`: the built-in scene with both grids set, the letter at
/// [`PHOTONS`] photo-electrons.
/// `T` is built here and dropped on return, so the bench does not hold it
/// while the timed children run.
fn write_inputs(
    text: &str,
    wall: usize,
    g: usize,
    work: &Path,
    budget: MemoryBudget,
) -> Result<GridInput, BenchError> {
    let scene = super::edit(SCENE, Scene::from_toml_str(text)?, |s| {
        s.wall.plane.grid = Grid { nu: wall, nv: wall };
        s.hidden.plane.grid = Grid { nu: g, nv: g };
    })?;
    // The scene file the child reads: the built-in one with both grids set.
    let toml = text
        .replacen("grid = [32, 32]", &format!("grid = [{wall}, {wall}]"), 1)
        .replacen("grid = [8, 8]", &format!("grid = [{g}, {g}]"), 1);
    let dir = work.join(format!("grid-{g}"));
    std::fs::create_dir_all(&dir).map_err(|e| err("work folder", e))?;
    let scene_file = dir.join("scene.toml");
    std::fs::write(&scene_file, &toml).map_err(|e| err("scene.toml", e))?;
    let t = build(&scene, budget)?;
    if Scene::from_toml_str(&toml)?.cols() != t.cols() {
        return Err(err("scene grid", "the built-in scene's grids moved"));
    }
    let truth = Pattern::Letter.render(t.scene_grid());
    let peak = unpolarized_peak(&scene, &t, &truth, budget)?;
    let sim = NoiseModel {
        photons: PHOTONS,
        ..NoiseModel::default()
    }
    .apply(t.apply(&truth), peak)
    .map_err(|source| BenchError::Simulate {
        case: format!("scaling sweep {g}x{g}"),
        source,
    })?;
    let (measurement, truth_file) = (dir.join("measurement.npy"), dir.join("truth.npy"));
    npy::write_f64(&measurement, &[sim.measurement.len()], &sim.measurement)
        .map_err(|e| err("measurement.npy", e))?;
    npy::write_f64(&truth_file, &[g, g], &truth).map_err(|e| err("truth.npy", e))?;
    Ok(GridInput {
        grid: g,
        dir,
        scene_file,
        measurement,
        truth_file,
        truth,
        lambda: LAMBDA_REL * t.mean_column_norm2(),
        shape: (t.rows(), t.cols()),
    })
}

/// One `polnlos reconstruct` child: its wall seconds, peak RSS in MB and
/// the folder it wrote its report to.
/// The row reads the PSNR, rank and build time from that report.
struct Run {
    seconds: f64,
    rss_mb: f64,
    out: PathBuf,
}

/// Runs `polnlos reconstruct` on `input` into `out`, at `lambda` when given
/// (automatic λ otherwise), as a measured child process.
/// A child, so its time is end to end and its peak memory its own.
fn reconstruct(
    exe: &Path,
    input: &GridInput,
    out: PathBuf,
    lambda: Option<f64>,
) -> Result<Run, BenchError> {
    let mut cmd = Command::new(exe);
    cmd.arg("reconstruct")
        .arg(&input.scene_file)
        .arg("--measurement")
        .arg(&input.measurement)
        .arg("--truth")
        .arg(&input.truth_file)
        .arg("--out")
        .arg(&out);
    if let Some(l) = lambda {
        cmd.args(["--lambda", &format!("{l:e}")]);
    }
    let (seconds, rss_mb) = run_measured(cmd)?;
    Ok(Run {
        seconds,
        rss_mb,
        out,
    })
}

/// Runs the NumPy peer (`script`) on `input` for [`PEER_ITERATIONS`]
/// iterations; returns its Gram + factor + iteration seconds and its PSNR, dB.
/// Only the solve is timed, from `T` given, as the peer's build is not what
/// this sweep compares.
fn run_peer(script: &Path, input: &GridInput, wall: usize) -> Result<(f64, f64), BenchError> {
    let dir = &input.dir;
    let out = Command::new("python3")
        .arg(script)
        .arg(&input.scene_file)
        .args(["--wall", &wall.to_string()])
        .args(["--scene-grid", &input.grid.to_string()])
        .arg("--measurement")
        .arg(&input.measurement)
        .arg("--out")
        .arg(dir)
        .args(["--iterations", &PEER_ITERATIONS.to_string(), "--no-save"])
        .output()
        .map_err(|e| err("python3", e))?;
    if !out.status.success() {
        return Err(err("the NumPy peer", String::from_utf8_lossy(&out.stderr)));
    }
    let json: serde_json::Value = serde_json::from_slice(
        &std::fs::read(dir.join("peer.json")).map_err(|e| err("peer.json", e))?,
    )
    .map_err(|e| err("peer.json", e))?;
    let secs = |k: &str| json[k].as_f64().unwrap_or(f64::NAN);
    let seconds = secs("gram_seconds") + secs("factor_seconds") + secs("iterate_seconds");
    let rec = npy::read(&dir.join("recovered.npy")).map_err(|e| err("recovered", e))?;
    Ok((
        seconds,
        crate::solve::metrics::psnr(&input.truth, &rec.data),
    ))
}

/// The sweep's row for `input`: the two runs, their reports, the peer's
/// (seconds, PSNR) if it ran, the memory budget and the dense floor.
/// Read before the grid's folder is removed, since the reports are in it.
fn scaling_row(input: &GridInput, fixed: &Run, auto: &Run, peer: Option<(f64, f64)>) -> ScalingRow {
    let psnr = |v: &serde_json::Value| v["metrics"]["psnr_db"].as_f64();
    let (m, n) = input.shape;
    let (mf, nf) = (m as f64, n as f64);
    ScalingRow {
        grid: input.grid,
        shape: (m, n),
        transport_seconds: report_field(&fixed.out, |v| v["transport_seconds"].as_f64()),
        fixed_seconds: fixed.seconds,
        auto_seconds: auto.seconds,
        fixed_psnr_db: report_field(&fixed.out, psnr),
        auto_psnr_db: report_field(&auto.out, psnr),
        fixed_rss_mb: fixed.rss_mb,
        auto_rss_mb: auto.rss_mb,
        rss_budget_mb: 1.5 * 8.0 * (mf * nf + nf * nf) / (1024.0 * 1024.0),
        rank: report_field(&auto.out, |v| v["conditioning"]["rank"].as_f64()) as usize,
        peer_seconds: peer.map(|p| p.0),
        peer_psnr_db: peer.map(|p| p.1),
        floor_seconds: (2.0 * mf * nf * nf
            + nf * nf * nf / 3.0
            + PEER_ITERATIONS as f64 * 2.0 * nf * nf)
            / FLOOR_RATE,
    }
}

/// Time against the scene grid: both polnlos runs, T alone, the peer, the floor.
pub fn chart(s: &Scaling) -> Result<Chart, ChartError> {
    let pts = |f: &dyn Fn(&ScalingRow) -> Option<f64>| -> Vec<(f64, f64)> {
        s.rows
            .iter()
            .filter_map(|r| f(r).map(|y| (r.grid as f64, y)))
            .collect()
    };
    let mut series = vec![
        Series::line(
            "polnlos reconstruct, automatic λ",
            0,
            pts(&|r| Some(r.auto_seconds)),
        ),
        Series::line(
            "polnlos reconstruct, fixed λ",
            1,
            pts(&|r| Some(r.fixed_seconds)),
        ),
        Series {
            marker: Marker::Triangle,
            ..Series::line(
                format!("NumPy ADMM-TV, fixed λ ({PEER_ITERATIONS} it., solve only)"),
                2,
                pts(&|r| r.peer_seconds),
            )
        },
        Series {
            marker: Marker::Cross,
            thin: true,
            ..Series::line("build T", 3, pts(&|r| Some(r.transport_seconds)))
        },
    ];
    series.push(Series {
        marker: Marker::None,
        ..Series::line(
            format!(
                "dense floor: 2MN² + N³/3 + {PEER_ITERATIONS}·2N² flop at {:.0} GFLOP/s",
                FLOOR_RATE / 1e9
            ),
            7,
            pts(&|r| Some(r.floor_seconds)),
        )
    });
    panels(&[Plot {
        title: format!(
            "{SCENE}, wall {0}x{0}, letter, {PHOTONS:.0} e-: time against the scene grid",
            s.wall
        ),
        x_label: "scene grid side".into(),
        y_label: "wall time, s".into(),
        x_log: false,
        y_log: true,
        x_integer: true,
        series,
    }])
}

/// The sweep as a Markdown table with the ratios to the peer.
pub fn markdown(s: &Scaling) -> String {
    use super::fmt_seconds as t;
    let mut md = format!(
        "## Reconstruction against the scene grid\n\n`polnlos reconstruct` end to end (a child process: T, Gram, conditioning, noise estimate, λ trials, files), built-in {SCENE} with the wall at {0}x{0}, letter truth, {PHOTONS:.0} photo-electrons; fixed λ = 1e-2 x mean(diag(TᵀT)). The NumPy peer (`benches/peer/peer.py`) solves the same measurement with {PEER_ITERATIONS} ADMM iterations at a fixed λ and ρ, timed from T given (Gram, factor, iterations). The floor is a dense solve's arithmetic at {1:.0} GFLOP/s; polnlos goes below it on large grids by working with the Gram's low-rank form. Memory budget: 1.5 x (T + Gram).\n\n![time against the scene grid](scaling.png)\n\n",
        s.wall,
        FLOOR_RATE / 1e9
    );
    if let Some(why) = &s.peer_skipped {
        let _ = writeln!(md, "NumPy peer skipped: {why}.\n");
    }
    md.push_str("| scene grid | T | build T | fixed λ | automatic λ | NumPy fixed λ | NumPy / fixed | NumPy / automatic | PSNR fixed / auto / NumPy | peak RSS fixed / auto | budget | rank | floor |\n|---|---|---|---|---|---|---|---|---|---|---|---|---|\n");
    for r in &s.rows {
        let ratio = |x: f64| {
            r.peer_seconds
                .map(|p| format!("{:.1}x", p / x))
                .unwrap_or_else(|| "-".into())
        };
        let _ = writeln!(
            md,
            "| {0}x{0} | {1} x {2} | {3} | {4} | {5} | {6} | {7} | {8} | {9:.2} / {10:.2} / {11} dB | {12:.0} / {13:.0} MB | {14:.0} MB | {15} | {16} |",
            r.grid,
            r.shape.0,
            r.shape.1,
            t(r.transport_seconds),
            t(r.fixed_seconds),
            t(r.auto_seconds),
            r.peer_seconds.map(t).unwrap_or_else(|| "-".into()),
            ratio(r.fixed_seconds),
            ratio(r.auto_seconds),
            r.fixed_psnr_db,
            r.auto_psnr_db,
            r.peer_psnr_db
                .map(|p| format!("{p:.2}"))
                .unwrap_or_else(|| "-".into()),
            r.fixed_rss_mb,
            r.auto_rss_mb,
            r.rss_budget_mb,
            r.rank,
            t(r.floor_seconds)
        );
    }
    md.push('\n');
    md
}

impl super::Report for Scaling {
    fn json(&self) -> serde_json::Map<String, serde_json::Value> {
        super::shape::fields(vec![("scaling", serde_json::to_value(self))])
    }

    fn charts(&self) -> Result<Vec<(String, Chart)>, ChartError> {
        Ok(vec![("scaling".into(), chart(self)?)])
    }

    fn markdown(&self) -> String {
        markdown(self)
    }
}
