//! Rendered cases: measurements of the bench made by an independent
//! polarized path tracer (Mitsuba 3, `validation/mitsuba/`), held against
//! polnlos's `T` and reconstructed beside polnlos's own simulation.
//!
//! Why: every other check compares polnlos with itself. A case is a folder
//! with `scene.toml`, `truth.npy` (scene grid), `i.npy` (the render in
//! MODEL.md row order) and `sigma.npy` (its per-element Monte-Carlo
//! standard error), as `validation/mitsuba/render.py` writes it.

use std::path::{Path, PathBuf};

use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, StandardNormal};
use serde::Serialize;

use super::BenchError;
use crate::files::npy;
use crate::scene::Scene;
use crate::simulate::{unpolarized_peak, NoiseModel};
use crate::solve::lambda::NoiseLevel;
use crate::solve::metrics::{compare, Metrics};
use crate::solve::reconstruct::Context;
use crate::solve::{condition, reconstruct, SolveRequest};
use crate::transport::Transport;

/// The folder of the shipped cases, relative to the repository.
pub const DEFAULT_DIR: &str = "tests/data/rendered";

/// One rendered case.
#[derive(Debug, Clone)]
pub struct RenderedCase {
    /// Folder name (`crossed`, `nopol-kd`, ...).
    pub name: String,
    /// The scene it renders.
    pub scene: Scene,
    /// The hidden scene, row-major on the scene grid.
    pub truth: Vec<f64>,
    /// The render, one value per row of `T`.
    pub i: Vec<f64>,
    /// Its per-element standard error.
    pub sigma: Vec<f64>,
}

impl RenderedCase {
    /// Reads the case in `dir`, checking every array against the scene's `T` shape.
    pub fn load(dir: &Path) -> Result<Self, BenchError> {
        let name = dir
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_default();
        let bad = |reason: String| BenchError::Rendered {
            case: dir.display().to_string(),
            reason,
        };
        let scene = Scene::load(&dir.join("scene.toml")).map_err(|e| bad(e.to_string()))?;
        let read = |file: &str, len: usize| -> Result<Vec<f64>, BenchError> {
            let a = npy::read(&dir.join(file)).map_err(|e| bad(e.to_string()))?;
            if a.data.len() != len {
                return Err(bad(format!(
                    "{file} has {} values, the scene needs {len}",
                    a.data.len()
                )));
            }
            if a.data.iter().any(|v| !v.is_finite()) {
                return Err(bad(format!("{file} has a value that is not finite")));
            }
            Ok(a.data)
        };
        let truth = read("truth.npy", scene.cols())?;
        let i = read("i.npy", scene.rows())?;
        let sigma = read("sigma.npy", scene.rows())?;
        Ok(Self {
            name,
            scene,
            truth,
            i,
            sigma,
        })
    }

    /// Every case under `root` (one folder each), in name order.
    pub fn load_all(root: &Path) -> Result<Vec<Self>, BenchError> {
        let entries = std::fs::read_dir(root).map_err(|e| BenchError::Rendered {
            case: root.display().to_string(),
            reason: format!("cannot list the rendered cases: {e}"),
        })?;
        let mut dirs: Vec<PathBuf> = entries
            .filter_map(|e| e.ok().map(|e| e.path()))
            .filter(|p| p.join("scene.toml").is_file())
            .collect();
        dirs.sort();
        dirs.iter().map(|d| Self::load(d)).collect()
    }

    /// The render's noise floor, `sqrt(mean sigma^2)`.
    pub fn noise_rms(&self) -> f64 {
        (self.sigma.iter().map(|s| s * s).sum::<f64>() / self.sigma.len().max(1) as f64).sqrt()
    }
}

/// How polnlos's prediction `T truth` agrees with a render.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Agreement {
    /// Least-squares gain from `T truth` to the render (1 when the units agree).
    pub gain: f64,
    /// Pearson correlation of the two.
    pub correlation: f64,
    /// RMS of `render - gain T truth`, relative to the render's RMS.
    pub residual: f64,
    /// The render's noise floor relative to its RMS.
    pub noise: f64,
    /// `residual / noise`: 1 when the model explains the render to its noise.
    pub ratio: f64,
}

/// The agreement of `t` (built from the case's scene, or a variant of it) with the render.
pub fn agreement(t: &Transport, case: &RenderedCase) -> Agreement {
    let m = t.apply(&case.truth);
    let i = &case.i;
    let dot = |a: &[f64], b: &[f64]| a.iter().zip(b).map(|(x, y)| x * y).sum::<f64>();
    let gain = dot(&m, i) / dot(&m, &m).max(1e-300);
    let n = i.len().max(1) as f64;
    let rms = (dot(i, i) / n).sqrt().max(1e-300);
    let resid = (i
        .iter()
        .zip(&m)
        .map(|(a, b)| (a - gain * b).powi(2))
        .sum::<f64>()
        / n)
        .sqrt();
    let (mi, mm) = (i.iter().sum::<f64>() / n, m.iter().sum::<f64>() / n);
    let cov: f64 = i.iter().zip(&m).map(|(a, b)| (a - mi) * (b - mm)).sum();
    let vi: f64 = i.iter().map(|a| (a - mi).powi(2)).sum();
    let vm: f64 = m.iter().map(|b| (b - mm).powi(2)).sum();
    let noise = case.noise_rms() / rms;
    Agreement {
        gain,
        correlation: cov / (vi * vm).sqrt().max(1e-300),
        residual: resid / rms,
        noise,
        ratio: (resid / rms) / noise.max(1e-300),
    }
}

/// The noise both reconstructions of a [`Pair`] carry.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum PairNoise {
    /// The render's own Monte-Carlo noise; the simulation gets Gaussian noise
    /// of the render's per-element standard error (seeded).
    Render {
        /// Seed of the simulation's noise.
        seed: u64,
    },
    /// A camera at the exposure the scene's unpolarized image sets, on top
    /// of each (the render's own noise is then far below the camera's).
    Camera(NoiseModel),
}

/// A reconstruction of the render and of polnlos's own simulation, both at
/// the same noise.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Pair {
    /// From the render.
    pub rendered: Metrics,
    /// From `T truth`.
    pub simulated: Metrics,
}

/// Reconstructs the case's render and polnlos's own `T truth` with `t` (the
/// case's scene, or a variant of it) at the same `noise`, with the automatic
/// λ from that noise level (the default request).
pub fn reconstruct_pair(
    t: &Transport,
    case: &RenderedCase,
    noise: PairNoise,
) -> Result<Pair, BenchError> {
    let cond = condition(t)?;
    let grid = t.scene_grid;
    let solve = |i: &[f64], level: NoiseLevel| -> Result<Metrics, BenchError> {
        let solved = reconstruct(
            t,
            i,
            Some(level),
            &cond,
            &SolveRequest::default(),
            Context::default(),
        )?;
        Ok(compare(grid, &case.truth, &solved.image))
    };
    let clean = t.apply(&case.truth);
    match noise {
        PairNoise::Render { seed } => {
            let variance: Vec<f64> = case.sigma.iter().map(|s| s * s).collect();
            let mut rng = ChaCha8Rng::seed_from_u64(seed);
            let sim: Vec<f64> = clean
                .iter()
                .zip(&case.sigma)
                .map(|(c, s)| {
                    let z: f64 = StandardNormal.sample(&mut rng);
                    c + s * z
                })
                .collect();
            Ok(Pair {
                rendered: solve(&case.i, NoiseLevel::measured(variance.clone()))?,
                simulated: solve(&sim, NoiseLevel::measured(variance))?,
            })
        }
        PairNoise::Camera(model) => {
            let peak = unpolarized_peak(&case.scene, t, &case.truth)?;
            let camera = |signal: Vec<f64>| -> Result<Metrics, BenchError> {
                let sim = model
                    .apply(signal, peak)
                    .map_err(|source| BenchError::Simulate {
                        case: case.name.clone(),
                        source,
                    })?;
                let level = NoiseLevel::from_camera(
                    &sim.measurement,
                    sim.electrons_per_unit,
                    model.read_noise,
                    sim.units_per_dn,
                );
                solve(&sim.measurement, level)
            };
            Ok(Pair {
                rendered: camera(case.i.clone())?,
                simulated: camera(clean)?,
            })
        }
    }
}
