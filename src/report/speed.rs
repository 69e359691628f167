//! Speed against accuracy: every solver at several budgets, on several
//! problem sizes, timed and scored (PSNR, SSIM) over several noise seeds.
//!
//! Two exposure rules, as on the bench: *equal exposure* (the crossed
//! capture gets the exposure that puts `photons` electrons on the brightest
//! element of the unpolarized image, so it is darker and noisier) and *equal
//! photon budget* (the crossed capture is exposed longer, until its own
//! brightest element collects `photons`). Times are those of a standalone
//! solve: forming `T^T T` is counted in every solver that needs it.

use std::fmt::Write as _;

use std::time::Instant;

use serde::Serialize;

use super::charts::{panel_grid, Chart, ChartError, Marker, Plot, Series};

use super::{builtin, median, BenchError};
use crate::scene::{Grid, Scene};
use crate::simulate::patterns::Pattern;
use crate::simulate::NoiseModel;
use crate::solve::gram::Normal;
use crate::solve::{metrics, SolveError, SolveRequest, Solver};
use crate::transport::{build, MemoryBudget, Transport};

/// One problem size of the sweep.
#[derive(Debug, Clone, Copy, Serialize)]
pub struct Size {
    /// Short label (`S`, `M`, `L`).
    pub label: &'static str,
    /// Scene grid side.
    pub scene: usize,
    /// Wall grid side.
    pub wall: usize,
    /// Number of crossed-polarizer poses (1: A; 2: B, C; 3: A, B, C).
    pub poses: usize,
}

/// The sizes of the full sweep: scene 8x8 to 32x32, wall 32x32 to 96x96, 1-3 poses.
pub const SIZES: [Size; 3] = [
    Size {
        label: "S",
        scene: 8,
        wall: 32,
        poses: 1,
    },
    Size {
        label: "M",
        scene: 16,
        wall: 64,
        poses: 2,
    },
    Size {
        label: "L",
        scene: 32,
        wall: 96,
        poses: 3,
    },
];

/// Exposure rules of the two panels.
pub const EXPOSURES: [&str; 2] = ["equal exposure", "equal photon budget"];

/// Iteration budgets of the iterative solvers (run to the budget, no early stop).
pub(crate) const BUDGETS: [usize; 6] = [10, 25, 50, 100, 200, 500];

/// Tolerances of the ADMM runs that stop on their own (cap 5000 iterations).
pub(crate) const TOLERANCES: [f64; 3] = [1e-2, 1e-3, 1e-4];

/// Photo-electrons at the brightest element (see [`EXPOSURES`]), read noise
/// 5 e-, 12 bits: the round-trip bench of tests/daemon/roundtrip.rs.
pub const PHOTONS: f64 = 2e4;

/// One timed solve.
#[derive(Debug, Clone, Serialize)]
pub struct SpeedRow {
    /// Size label.
    pub size: &'static str,
    /// Exposure rule.
    pub exposure: &'static str,
    /// `lsq`, `tikhonov`, `admm-tv`, `admm-tv tol`, `fista-tv`, `admm-tv nopol`.
    pub solver: &'static str,
    /// Iteration budget or tolerance, as text (`200`, `1e-3`, `-`).
    pub budget: String,
    /// Noise seed.
    pub seed: u64,
    /// Wall time of the standalone solve, seconds.
    pub seconds: f64,
    /// PSNR against the truth, dB.
    pub psnr_db: f64,
    /// SSIM against the truth.
    pub ssim: f64,
    /// Iterations run.
    pub iterations: usize,
    /// Whether the solver met its own stopping rule.
    pub converged: bool,
}

/// Median and spread over seeds of one (size, exposure, solver, budget).
#[derive(Debug, Clone, Serialize)]
pub struct SpeedSummary {
    /// Size label.
    pub size: &'static str,
    /// Exposure rule.
    pub exposure: &'static str,
    /// Solver.
    pub solver: &'static str,
    /// Budget.
    pub budget: String,
    /// Median seconds.
    pub seconds: f64,
    /// Median PSNR, dB.
    pub psnr_db: f64,
    /// Lowest and highest PSNR over seeds.
    pub psnr_range: (f64, f64),
    /// Median SSIM.
    pub ssim: f64,
    /// Lowest and highest SSIM over seeds.
    pub ssim_range: (f64, f64),
    /// On the Pareto front of (median seconds, median PSNR) for its size and
    /// exposure (the no-polarizer reference is left out of the front).
    pub pareto: bool,
}

/// The Brewster bench at `size`: crossed polarizer on poses A; B, C; or A, B, C.
pub(crate) fn scene_for(size: &Size) -> Result<Scene, BenchError> {
    let a = builtin("brewster-crossed")?;
    let bc = builtin("brewster-multi")?;
    let poses = match size.poses {
        1 => a.poses().to_vec(),
        2 => bc.poses().to_vec(),
        _ => a.poses().iter().chain(bc.poses()).cloned().collect(),
    };
    super::edit("brewster-crossed", a, |s| {
        s.poses = poses;
        s.wall.plane.grid = Grid {
            nu: size.wall,
            nv: size.wall,
        };
        s.hidden.plane.grid = Grid {
            nu: size.scene,
            nv: size.scene,
        };
    })
}

fn solve_err(e: SolveError) -> BenchError {
    BenchError::Solve(e)
}

/// Which measurement a row was solved on.
#[derive(Clone, Copy)]
struct Ctx {
    size: &'static str,
    exposure: &'static str,
    seed: u64,
}

struct Problem {
    t: Transport,
    truth: Vec<f64>,
    grid: Grid,
}

impl Problem {
    fn row(
        &self,
        ctx: Ctx,
        solver: &'static str,
        budget: String,
        seconds: f64,
        rec: &crate::solve::Reconstruction,
    ) -> SpeedRow {
        SpeedRow {
            size: ctx.size,
            exposure: ctx.exposure,
            solver,
            budget,
            seed: ctx.seed,
            seconds,
            psnr_db: metrics::psnr(&self.truth, &rec.image),
            ssim: metrics::ssim(self.grid, &self.truth, &rec.image),
            iterations: rec.stats.iterations,
            converged: rec.stats.converged,
        }
    }
}

/// Runs every solver on one noisy measurement, appending rows.
fn run_solvers(
    p: &Problem,
    ctx: Ctx,
    i: &[f64],
    budgets: &[usize],
    rows: &mut Vec<SpeedRow>,
) -> Result<(), BenchError> {
    let normal = Normal::new(p.t.as_mat(), i);
    let gram = normal.seconds;

    // Every solver through its door, on one Gram: `budget` iterations (no
    // tolerance stops them early) or, for the direct ones, once.
    let at = |solver: Solver, max_iter: Option<usize>, tol: f64| crate::solve::Problem {
        normal: Some(&normal),
        ..crate::solve::Problem::new(
            &p.t,
            i,
            SolveRequest {
                solver,
                max_iter,
                tol: Some(tol),
                ..SolveRequest::default()
            },
        )
    };
    let r = Solver::LSQ
        .run(&crate::solve::Problem::new(
            &p.t,
            i,
            SolveRequest {
                solver: Solver::LSQ,
                ..SolveRequest::default()
            },
        ))
        .map_err(solve_err)?;
    rows.push(p.row(ctx, "lsq", "-".into(), r.stats.total_seconds, &r));
    let r = Solver::TIKHONOV
        .run(&crate::solve::Problem::new(
            &p.t,
            i,
            SolveRequest {
                solver: Solver::TIKHONOV,
                ..SolveRequest::default()
            },
        ))
        .map_err(solve_err)?;
    rows.push(p.row(ctx, "tikhonov", "-".into(), r.stats.total_seconds, &r));
    for &b in budgets {
        for solver in [Solver::ADMM_TV, Solver::FISTA_TV] {
            let start = Instant::now();
            let r = solver.run(&at(solver, Some(b), 1e-12)).map_err(solve_err)?;
            let secs = gram + start.elapsed().as_secs_f64();
            rows.push(p.row(ctx, solver.name(), b.to_string(), secs, &r));
        }
    }
    for &tol in &TOLERANCES {
        let start = Instant::now();
        let r = Solver::ADMM_TV
            .run(&at(Solver::ADMM_TV, Some(5000), tol))
            .map_err(solve_err)?;
        let secs = gram + start.elapsed().as_secs_f64();
        rows.push(p.row(ctx, "admm-tv tol", format!("{tol:.0e}"), secs, &r));
    }
    Ok(())
}

/// Runs the sweep over `sizes` and `seeds` (1..=seeds), calling `step()` after
/// each (size, seed).
pub(crate) fn speed_sweep(
    sizes: &[Size],
    seeds: u64,
    budgets: &[usize],
    budget: MemoryBudget,
    step: &mut dyn FnMut(),
) -> Result<Vec<SpeedRow>, BenchError> {
    let mut rows = Vec::new();
    for size in sizes {
        let scene = scene_for(size)?;
        let t = build(&scene, budget)?;
        let t_nopol = build(&scene.without_polarizers(), budget)?;
        let grid = t.scene_grid();
        let truth = Pattern::Letter.render(grid);
        let p = Problem { t, truth, grid };
        let nopol = Problem {
            t: t_nopol,
            truth: p.truth.clone(),
            grid,
        };
        let clean = p.t.apply(&p.truth);
        let clean_nopol = nopol.t.apply(&p.truth);
        let peak_nopol = clean_nopol.iter().copied().fold(0.0, f64::max);
        let peak_crossed = clean.iter().copied().fold(0.0, f64::max);
        for seed in 1..=seeds {
            let model = NoiseModel {
                photons: PHOTONS,
                read_noise: 5.0,
                bits: 12,
                seed,
            };
            let simulate = |clean: &[f64], peak: f64| {
                model
                    .apply(clean.to_vec(), peak)
                    .map_err(|source| BenchError::Simulate {
                        case: format!("speed sweep {}", size.label),
                        source,
                    })
            };
            // The unpolarized capture is the same in both panels (its exposure
            // is the reference): solved once per seed, ADMM-TV at its defaults.
            let sim_nopol = simulate(&clean_nopol, peak_nopol)?;
            let start = Instant::now();
            let r_nopol = Solver::ADMM_TV
                .run(&crate::solve::Problem::new(
                    &nopol.t,
                    &sim_nopol.measurement,
                    SolveRequest::default(),
                ))
                .map_err(solve_err)?;
            let secs_nopol = start.elapsed().as_secs_f64();
            for (exposure, peak) in EXPOSURES.into_iter().zip([peak_nopol, peak_crossed]) {
                let ctx = Ctx {
                    size: size.label,
                    exposure,
                    seed,
                };
                let sim = simulate(&clean, peak)?;
                run_solvers(&p, ctx, &sim.measurement, budgets, &mut rows)?;
                rows.push(nopol.row(ctx, "admm-tv nopol", "500".into(), secs_nopol, &r_nopol));
            }
            step();
        }
    }
    Ok(rows)
}

fn range(v: &[f64]) -> (f64, f64) {
    v.iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &x| {
            (a.min(x), b.max(x))
        })
}

/// Medians and spreads over seeds, with the Pareto front marked.
pub(crate) fn summarize(rows: &[SpeedRow]) -> Vec<SpeedSummary> {
    let mut keys: Vec<(&'static str, &'static str, &'static str, String)> = Vec::new();
    for r in rows {
        let k = (r.size, r.exposure, r.solver, r.budget.clone());
        if !keys.contains(&k) {
            keys.push(k);
        }
    }
    let mut out: Vec<SpeedSummary> = keys
        .into_iter()
        .map(|(size, exposure, solver, budget)| {
            let g: Vec<&SpeedRow> = rows
                .iter()
                .filter(|r| {
                    r.size == size
                        && r.exposure == exposure
                        && r.solver == solver
                        && r.budget == budget
                })
                .collect();
            let psnr: Vec<f64> = g.iter().map(|r| r.psnr_db).collect();
            let ssim: Vec<f64> = g.iter().map(|r| r.ssim).collect();
            SpeedSummary {
                size,
                exposure,
                solver,
                budget,
                seconds: median(g.iter().map(|r| r.seconds).collect()),
                psnr_db: median(psnr.clone()),
                psnr_range: range(&psnr),
                ssim: median(ssim.clone()),
                ssim_range: range(&ssim),
                pareto: false,
            }
        })
        .collect();
    let mut groups: Vec<(&str, &str)> = out.iter().map(|s| (s.size, s.exposure)).collect();
    groups.dedup();
    for (size, exposure) in groups {
        let idx: Vec<usize> = (0..out.len())
            .filter(|&k| {
                out[k].size == size
                    && out[k].exposure == exposure
                    && out[k].solver != "admm-tv nopol"
            })
            .collect();
        let pts: Vec<(f64, f64)> = idx
            .iter()
            .map(|&k| (out[k].seconds, out[k].psnr_db))
            .collect();
        for f in super::charts::pareto_front(&pts) {
            out[idx[f]].pareto = true;
        }
    }
    out
}

/// Legend name, palette colour, marker and line of each solver family.
const STYLE: [(&str, &str, usize, Marker, bool); 6] = [
    (
        "admm-tv",
        "ADMM-TV, iteration budget",
        0,
        Marker::Circle,
        true,
    ),
    (
        "fista-tv",
        "FISTA-TV, iteration budget",
        1,
        Marker::Triangle,
        true,
    ),
    (
        "admm-tv tol",
        "ADMM-TV, tol 1e-2 / 1e-3 / 1e-4",
        2,
        Marker::Cross,
        true,
    ),
    (
        "lsq",
        "least squares (pseudo-inverse)",
        3,
        Marker::Circle,
        false,
    ),
    ("tikhonov", "Tikhonov", 4, Marker::Circle, false),
    (
        "admm-tv nopol",
        "ADMM-TV, no polarizer",
        5,
        Marker::Cross,
        false,
    ),
];

/// For each size, one chart: PSNR (top) and SSIM (bottom) against seconds,
/// equal exposure (left) and equal photon budget (right), medians over seeds
/// with min-max bars and the Pareto front of the PSNR panels.
pub fn charts(summary: &[SpeedSummary]) -> Result<Vec<(String, Chart)>, ChartError> {
    let mut sizes: Vec<&str> = summary.iter().map(|s| s.size).collect();
    sizes.dedup();
    let mut out = Vec::new();
    for size in sizes {
        let dims = SIZES
            .iter()
            .find(|s| s.label == size)
            .map(|s| {
                format!(
                    "scene {0}x{0}, wall {1}x{1}, {2} pose{3}",
                    s.scene,
                    s.wall,
                    s.poses,
                    if s.poses > 1 { "s" } else { "" }
                )
            })
            .unwrap_or_default();
        let mut plots = Vec::new();
        for ssim in [false, true] {
            for exposure in EXPOSURES {
                let here: Vec<&SpeedSummary> = summary
                    .iter()
                    .filter(|s| s.size == size && s.exposure == exposure)
                    .collect();
                let value = |s: &SpeedSummary| if ssim { s.ssim } else { s.psnr_db };
                let spread = |s: &SpeedSummary| {
                    if ssim {
                        s.ssim_range
                    } else {
                        s.psnr_range
                    }
                };
                let mut series: Vec<Series> = STYLE
                    .iter()
                    .filter_map(|&(solver, name, color, marker, line)| {
                        let mut pts: Vec<&&SpeedSummary> =
                            here.iter().filter(|s| s.solver == solver).collect();
                        if pts.is_empty() {
                            return None;
                        }
                        pts.sort_by(|a, b| a.seconds.total_cmp(&b.seconds));
                        Some(Series {
                            name: name.into(),
                            points: pts.iter().map(|s| (s.seconds, value(s))).collect(),
                            spread: pts.iter().map(|s| spread(s)).collect(),
                            color,
                            marker,
                            line,
                            thin: true,
                        })
                    })
                    .collect();
                if !ssim {
                    let mut front: Vec<(f64, f64)> = here
                        .iter()
                        .filter(|s| s.pareto)
                        .map(|s| (s.seconds, s.psnr_db))
                        .collect();
                    front.sort_by(|a, b| a.0.total_cmp(&b.0));
                    series.push(Series {
                        name: "Pareto front".into(),
                        points: front,
                        spread: Vec::new(),
                        color: 7,
                        marker: Marker::None,
                        line: true,
                        thin: false,
                    });
                }
                plots.push(Plot {
                    title: format!("{exposure} ({dims})"),
                    x_label: "wall time of the solve, s".into(),
                    y_label: if ssim { "SSIM" } else { "PSNR, dB" }.into(),
                    x_log: true,
                    y_log: false,
                    x_integer: false,
                    series,
                });
            }
        }
        out.push((format!("speed-accuracy-{size}"), panel_grid(&plots, 2)?));
    }
    Ok(out)
}

/// The sweep as Markdown tables, one per size.
pub fn markdown(summary: &[SpeedSummary], seeds: u64) -> String {
    let mut md = format!(
        "Letter pattern, {PHOTONS:.0} photo-electrons at the brightest element, read noise 5 e-, 12 bits; medians over {seeds} noise seed(s), PSNR range in brackets; * marks the Pareto front (fastest for its PSNR).\n\n"
    );
    let mut sizes: Vec<&str> = summary.iter().map(|s| s.size).collect();
    sizes.dedup();
    for size in sizes {
        if let Some(d) = SIZES.iter().find(|s| s.label == size) {
            let _ = writeln!(
                md,
                "### {size}: scene {0}x{0}, wall {1}x{1}, {2} crossed pose(s)\n\n![speed against accuracy](speed-accuracy-{size}.png)\n",
                d.scene, d.wall, d.poses
            );
        }
        md.push_str("| exposure | solver | budget | time | PSNR dB [min, max] | SSIM | front |\n|---|---|---|---|---|---|---|\n");
        for s in summary.iter().filter(|s| s.size == size) {
            let _ = writeln!(
                md,
                "| {} | {} | {} | {} | {:.2} [{:.2}, {:.2}] | {:.3} | {} |",
                s.exposure,
                s.solver,
                s.budget,
                super::fmt_seconds(s.seconds),
                s.psnr_db,
                s.psnr_range.0,
                s.psnr_range.1,
                s.ssim,
                if s.pareto { "*" } else { "" }
            );
        }
        md.push('\n');
    }
    md
}

/// The speed-against-accuracy sweep as a report.
pub struct Speed {
    /// Noise seeds per size.
    pub seeds: u64,
    /// Medians per (size, exposure, solver, budget).
    pub summary: Vec<SpeedSummary>,
    /// Every run.
    pub runs: Vec<SpeedRow>,
}

impl super::Report for Speed {
    fn json(&self) -> serde_json::Map<String, serde_json::Value> {
        super::shape::fields(vec![
            ("speed_seeds", serde_json::to_value(self.seeds)),
            ("speed", serde_json::to_value(&self.summary)),
            ("speed_runs", serde_json::to_value(&self.runs)),
        ])
    }

    fn charts(&self) -> Result<Vec<(String, Chart)>, ChartError> {
        charts(&self.summary)
    }

    fn markdown(&self) -> String {
        format!(
            "## Speed against accuracy\n\n{}",
            markdown(&self.summary, self.seeds)
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sizes_build_the_shapes_they_name() {
        let s = scene_for(&SIZES[2]).unwrap();
        assert_eq!(s.poses().len(), 3);
        assert_eq!(s.rows(), 3 * 96 * 96);
        assert_eq!(s.cols(), 32 * 32);
        let s = scene_for(&SIZES[1]).unwrap();
        assert_eq!(
            s.poses()
                .iter()
                .map(|p| p.name.as_str())
                .collect::<Vec<_>>(),
            ["B", "C"]
        );
    }

    #[test]
    fn summary_takes_medians_and_marks_the_front() {
        let row = |solver, budget: &str, seed, seconds, psnr_db| SpeedRow {
            size: "S",
            exposure: EXPOSURES[0],
            solver,
            budget: budget.into(),
            seed,
            seconds,
            psnr_db,
            ssim: 0.5,
            iterations: 1,
            converged: true,
        };
        let rows = vec![
            row("lsq", "-", 1, 0.1, 3.0),
            row("lsq", "-", 2, 0.3, 5.0),
            row("lsq", "-", 3, 0.2, 4.0),
            row("admm-tv", "10", 1, 0.05, 10.0),
            row("admm-tv", "500", 1, 1.0, 9.0),
            row("admm-tv nopol", "500", 1, 0.01, 30.0),
        ];
        let s = summarize(&rows);
        assert_eq!(s.len(), 4);
        assert_eq!((s[0].seconds, s[0].psnr_db), (0.2, 4.0));
        assert_eq!(s[0].psnr_range, (3.0, 5.0));
        let front: Vec<&str> = s.iter().filter(|r| r.pareto).map(|r| r.solver).collect();
        assert_eq!(front, ["admm-tv"]);
        assert!(!s[2].pareto, "a slower, worse budget is dominated");
    }
}
