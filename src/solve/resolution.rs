//! Scene resolution from the physics: for candidate scene grids, the
//! condition number of `T` and how much the pseudo-inverse amplifies the
//! camera noise, and the finest grid whose least-squares estimate stays within
//! a tolerance of the radiance range.
//!
//! Why this rule: the least-squares error covariance is `sigma^2 (T^T T)^-1`,
//! so the expected per-element RMS error is `sigma sqrt(mean_i 1/s_i^2)` with
//! `s_i` the singular values of `T`; when it is below `tolerance` (default 0.1
//! of the [0, 1] range) the measurement alone resolves every element, and a
//! finer grid asks the regularizer to invent what the data cannot say.

use serde::Serialize;

use super::conditioning::condition;
use super::lambda::NoiseLevel;
use super::SolveError;
use crate::scene::{Grid, Scene, SceneError};
use crate::simulate::NoiseModel;
use crate::transport::{build, MemoryBudget, TransportError};

/// One candidate grid.
#[derive(Debug, Clone, Serialize)]
pub struct GridCandidate {
    /// Scene grid side.
    pub grid: usize,
    /// Rows x columns of `T`.
    pub shape: (usize, usize),
    /// Condition number.
    #[serde(serialize_with = "crate::solve::json::finite_or_inf")]
    pub kappa: f64,
    /// Numerical rank.
    pub rank: usize,
    /// Expected per-element RMS error of the pseudo-inverse, in units of the
    /// radiance range (`"inf"` when rank-deficient).
    #[serde(serialize_with = "crate::solve::json::finite_or_inf")]
    pub noise_amplification: f64,
    /// Whether the measurement supports this grid.
    pub supported: bool,
}

/// The grid advice for a scene: every candidate and the finest resolved.
#[derive(Debug, Clone, Serialize)]
pub struct GridAdvice {
    /// Candidates, coarse to fine.
    pub rows: Vec<GridCandidate>,
    /// Finest supported grid side, if any.
    pub recommended: Option<usize>,
    /// RMS noise of one measurement at mid-grey, units of `T l`.
    pub sigma: f64,
    /// Tolerance used.
    pub tolerance: f64,
}

/// Why the grids could not be judged.
#[derive(Debug, thiserror::Error)]
pub enum ResolutionError {
    /// Building `T`.
    #[error(transparent)]
    Transport(#[from] TransportError),
    /// A grid that makes the scene invalid (zero, or past the loader's limit).
    #[error(transparent)]
    Scene(#[from] SceneError),
    /// The SVD.
    #[error(transparent)]
    Solve(#[from] SolveError),
    /// The noise model.
    #[error(transparent)]
    Noise(#[from] crate::simulate::SimulateError),
    /// A pose's pixels could not be found on the wall.
    #[error(transparent)]
    Footprint(#[from] crate::scene::FootprintError),
}

/// Plans the scene grid for `scene` under the camera `noise`, each candidate `T` built within `budget`.
pub fn finest_grid(
    scene: &Scene,
    noise: &NoiseModel,
    grids: &[usize],
    tolerance: f64,
    budget: MemoryBudget,
) -> Result<GridAdvice, ResolutionError> {
    noise.validate()?;
    let mut rows = Vec::new();
    let mut sigma = 0.0;
    for &g in grids {
        let s = scene
            .clone()
            .edit(|s| s.hidden.plane.grid = Grid { nu: g, nv: g })?;
        let t = build(&s, budget)?;
        let c = condition(&t)?;
        // Exposure as in `simulate`: `photons` at the unpolarized peak of a fully lit scene.
        let ones = vec![1.0; t.cols()];
        let peak = crate::simulate::unpolarized_peak(&s, &t, &ones, budget)?;
        let epu = noise.photons / peak.max(1e-300);
        let full = f64::from((1u32 << noise.bits) - 1);
        let grey = t.apply(&vec![0.5; t.cols()]);
        let mut level =
            NoiseLevel::from_camera(&grey, epu, noise.read_noise, noise.photons / full / epu);
        // Measured from camera frames, an element averages its pixels' photons.
        if let Some(pixels) = crate::scene::effective_pixels(&s)? {
            level
                .variance
                .iter_mut()
                .zip(&pixels)
                .for_each(|(v, n)| *v /= n.max(1.0));
        }
        sigma = level.mean_variance().sqrt();
        let amp = c.noise_amplification(sigma);
        rows.push(GridCandidate {
            grid: g,
            shape: (t.rows(), t.cols()),
            kappa: c.kappa,
            rank: c.rank,
            noise_amplification: amp,
            supported: amp <= tolerance,
        });
    }
    let recommended = rows.iter().filter(|r| r.supported).map(|r| r.grid).max();
    Ok(GridAdvice {
        rows,
        recommended,
        sigma,
        tolerance,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn more_light_supports_finer_grids() {
        let s = Scene::builtin("brewster-crossed").unwrap().unwrap();
        let grids = [2, 3, 4, 6, 8];
        let shot = |photons| NoiseModel {
            photons,
            read_noise: 0.0,
            bits: 16,
            seed: 1,
        };
        let dim = finest_grid(&s, &shot(1e3), &grids, 0.1, MemoryBudget::DEFAULT).unwrap();
        let bright = finest_grid(&s, &shot(1e5), &grids, 0.1, MemoryBudget::DEFAULT).unwrap();
        // Amplification grows with the grid, and shrinks as sqrt(photons).
        for w in dim.rows.windows(2) {
            assert!(
                w[1].noise_amplification >= w[0].noise_amplification,
                "{:?}",
                dim.rows
            );
        }
        assert!(bright.recommended.unwrap_or(0) >= dim.recommended.unwrap_or(0));
        // Shot-noise limited: 100 x the photons, 1/10 of the noise.
        let r = bright.rows[1].noise_amplification / dim.rows[1].noise_amplification;
        assert!((r - 0.1).abs() < 0.01, "{r}");
    }
}
