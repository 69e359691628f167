//! Reproducible reports of how well-posed the bench is: the paper's Table 1
//! (condition number per polarizer configuration, with and without the
//! occluder) and Fig. 6 (condition number against wall roughness).
//!
//! Pure computations returning typed rows; `polnlos bench` writes them as
//! JSON, Markdown and charts ([`charts`]).

pub(crate) mod active;
pub mod charts;
pub(crate) mod lambda;
mod live;
pub(crate) mod mosaic;
pub(crate) mod peer;
pub(crate) mod photons;
pub(crate) mod rendered;
pub(crate) mod sampling;
pub(crate) mod scaling;
mod selection;
pub(crate) mod shape;
pub(crate) mod speed;
pub(crate) mod stability;
mod tables;

pub use live::{LiveReport, LiveRow, SoakSample};
pub use mosaic::{mosaic_report, STEPS as MOSAIC_STEPS};
pub use photons::best_lambda;
pub use rendered::{agreement, reconstruct_pair, PairNoise, RenderedCase, DEFAULT_DIR};
pub use selection::BenchSelection;
pub use shape::Report;
pub use tables::Conditioning;
pub(crate) use tables::Roughness;

use serde::Serialize;

use crate::scene::{Scene, SceneError, SceneParts};
use crate::solve::{condition, SolveError};
use crate::transport::{build, MemoryBudget, TransportError};

/// Polarizer configurations of the reference bench, in the paper's order.
pub(crate) const CONFIGS: [&str; 4] = ["nopol", "rotating", "crossed", "multi"];

/// Wall roughness values of the Fig. 6 sweep.
pub(crate) const ROUGHNESS: [f64; 7] = [0.05, 0.1, 0.2, 0.3, 0.5, 0.7, 1.0];

/// Why a report could not be computed.
#[derive(Debug, thiserror::Error)]
pub enum BenchError {
    /// A built-in scene is missing or invalid.
    #[error("scene {name}: {reason}")]
    Scene {
        /// Scene name.
        name: String,
        /// What is wrong.
        reason: String,
    },
    /// Building `T` failed.
    #[error(transparent)]
    Transport(#[from] TransportError),
    /// The SVD failed.
    #[error(transparent)]
    Solve(#[from] SolveError),
    /// A simulated measurement could not be made.
    #[error("{case}: {source}")]
    Simulate {
        /// Which case or sweep.
        case: String,
        /// Why.
        source: crate::simulate::SimulateError,
    },
    /// The NumPy peer could not be run or read back.
    #[error("NumPy peer: {0}")]
    Peer(String),
    /// A rendered case could not be read.
    #[error("rendered case {case}: {reason}")]
    Rendered {
        /// Its folder.
        case: String,
        /// What is wrong.
        reason: String,
    },
}

/// One row of the conditioning table.
#[derive(Debug, Clone, Serialize)]
pub struct CondRow {
    /// Scene file name.
    pub scene: String,
    /// `nopol`, `rotating`, `crossed` or `multi`.
    pub config: String,
    /// With the Saunders occluder.
    pub occluder: bool,
    /// Scene grid side (3 or 8).
    pub grid: usize,
    /// Rows x columns of `T`.
    pub shape: (usize, usize),
    /// Condition number (`"inf"` when rank-deficient).
    #[serde(serialize_with = "crate::solve::json::finite_or_inf")]
    pub kappa: f64,
    /// Seconds to build `T` and its SVD.
    pub seconds: f64,
}

/// The name of a built-in bench scene.
pub fn scene_name(config: &str, occluder: bool, grid: usize) -> String {
    let base = if occluder { "occluder" } else { "brewster" };
    if grid == 3 {
        format!("{base}-{config}-3x3")
    } else {
        format!("{base}-{config}")
    }
}

/// Median of `v` (mean of the middle two for an even count; NaN when empty).
pub(crate) fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    let n = v.len();
    if n == 0 {
        return f64::NAN;
    }
    if n % 2 == 1 {
        v[n / 2]
    } else {
        0.5 * (v[n / 2 - 1] + v[n / 2])
    }
}

/// A condition number as the tables print it (`inf` when rank-deficient).
pub(crate) fn fmt_kappa(k: f64) -> String {
    if k.is_finite() {
        format!("{k:.3e}")
    } else {
        "inf".into()
    }
}

/// A duration with three significant digits in a unit that fits: `1.23 s`,
/// `45.6 ms`, `789 us` (never `0.000 s`).
pub(crate) fn fmt_seconds(s: f64) -> String {
    match s {
        s if !s.is_finite() || s < 0.0 => "-".into(),
        s if s >= 1.0 => format!("{s:.2} s"),
        s if s >= 0.1 => format!("{:.0} ms", s * 1e3),
        s if s >= 0.01 => format!("{:.1} ms", s * 1e3),
        s if s >= 1e-3 => format!("{:.2} ms", s * 1e3),
        s => format!("{:.0} us", s * 1e6),
    }
}

/// Runs `f` three times; returns the last result and the median wall time.
pub(crate) fn timed3<T>(
    mut f: impl FnMut() -> Result<T, BenchError>,
) -> Result<(T, f64), BenchError> {
    let mut times = Vec::with_capacity(3);
    let mut run = || -> Result<T, BenchError> {
        let start = std::time::Instant::now();
        let out = f()?;
        times.push(start.elapsed().as_secs_f64());
        Ok(out)
    };
    run()?;
    run()?;
    let out = run()?;
    Ok((out, median(times)))
}

/// A built-in scene, or a bench error naming it.
pub(crate) fn builtin(name: &str) -> Result<Scene, BenchError> {
    match Scene::builtin(name) {
        Some(Ok(s)) => Ok(s),
        Some(Err(e)) => Err(BenchError::Scene {
            name: name.into(),
            reason: e.to_string(),
        }),
        None => Err(BenchError::Scene {
            name: name.into(),
            reason: "not a built-in scene".into(),
        }),
    }
}

/// `scene` changed by `change` and validated again, or a bench error naming it `name`.
pub(crate) fn edit(
    name: &str,
    scene: Scene,
    change: impl FnOnce(&mut SceneParts),
) -> Result<Scene, BenchError> {
    scene.edit(change).map_err(|e| BenchError::Scene {
        name: name.into(),
        reason: e.to_string(),
    })
}

fn kappa(scene: &Scene, budget: MemoryBudget) -> Result<f64, BenchError> {
    Ok(condition(&build(scene, budget)?)?.kappa)
}

/// Table 1: kappa for every configuration, with and without the occluder, on
/// the given scene grids (3 and/or 8). `step()` is called after each row.
pub(crate) fn conditioning_table(
    grids: &[usize],
    budget: MemoryBudget,
    step: &mut dyn FnMut(),
) -> Result<Vec<CondRow>, BenchError> {
    let mut rows = Vec::new();
    for &grid in grids {
        for occluder in [false, true] {
            for config in CONFIGS {
                let name = scene_name(config, occluder, grid);
                let scene = builtin(&name)?;
                let start = std::time::Instant::now();
                let t = build(&scene, budget)?;
                let c = condition(&t)?;
                rows.push(CondRow {
                    scene: name,
                    config: config.into(),
                    occluder,
                    grid,
                    shape: (t.rows(), t.cols()),
                    kappa: c.kappa,
                    seconds: start.elapsed().as_secs_f64(),
                });
                step();
            }
        }
    }
    Ok(rows)
}

/// One point of the roughness sweep.
#[derive(Debug, Clone, Serialize)]
pub(crate) struct RoughRow {
    /// `nopol`, `crossed` or `multi`.
    pub config: String,
    /// With the Saunders occluder.
    pub occluder: bool,
    /// Scene grid side.
    pub grid: usize,
    /// GGX alpha.
    pub roughness: f64,
    /// Condition number.
    #[serde(serialize_with = "crate::solve::json::finite_or_inf")]
    pub kappa: f64,
}

/// Fig. 6: kappa against roughness for nopol, crossed and multi, with and without the occluder.
pub(crate) fn roughness_sweep(
    grid: usize,
    budget: MemoryBudget,
    step: &mut dyn FnMut(),
) -> Result<Vec<RoughRow>, BenchError> {
    let mut rows = Vec::new();
    for occluder in [false, true] {
        for config in ["nopol", "crossed", "multi"] {
            let name = scene_name(config, occluder, grid);
            let base = builtin(&name)?;
            for &alpha in &ROUGHNESS {
                let s = edit(&name, base.clone(), |s| s.wall.brdf.alpha = alpha)?;
                rows.push(RoughRow {
                    config: config.into(),
                    occluder,
                    grid,
                    roughness: alpha,
                    kappa: kappa(&s, budget)?,
                });
                step();
            }
        }
    }
    Ok(rows)
}

/// Rows that [`conditioning_table`] will compute, for a progress bar.
pub(crate) fn conditioning_len(grids: &[usize]) -> usize {
    grids.len() * 2 * CONFIGS.len()
}

/// Points that [`roughness_sweep`] will compute.
pub(crate) fn roughness_len() -> usize {
    2 * 3 * ROUGHNESS.len()
}

impl From<SceneError> for BenchError {
    fn from(e: SceneError) -> Self {
        BenchError::Scene {
            name: String::new(),
            reason: e.to_string(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn durations_keep_three_digits_and_never_print_zero() {
        assert_eq!(fmt_seconds(12.345), "12.35 s");
        assert_eq!(fmt_seconds(0.1234), "123 ms");
        assert_eq!(fmt_seconds(0.04567), "45.7 ms");
        assert_eq!(fmt_seconds(0.001234), "1.23 ms");
        assert_eq!(fmt_seconds(0.000_345), "345 us");
        assert_eq!(fmt_seconds(f64::NAN), "-");
    }

    #[test]
    fn names_match_the_shipped_files() {
        assert_eq!(scene_name("crossed", false, 3), "brewster-crossed-3x3");
        assert_eq!(scene_name("multi", true, 8), "occluder-multi");
        for grid in [3, 8] {
            for occ in [false, true] {
                for c in CONFIGS {
                    assert!(Scene::builtin(&scene_name(c, occ, grid)).is_some());
                }
            }
        }
    }
}
