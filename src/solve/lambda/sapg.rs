//! Empirical-Bayes TV weight: the θ of the prior `exp(-θ TV(l))` on the box
//! `[0, 1]^d` that maximizes the marginal likelihood `p(i | θ)`, by the
//! stochastic approximation proximal gradient algorithm (SAPG, Algorithm 1 of
//! Vidal, De Bortoli, Pereyra, Durmus, "Maximum likelihood estimation of
//! regularization parameters in high-dimensional inverse problems: an
//! empirical Bayesian approach", SIAM J. Imaging Sci. 13(4), 2020).
//!
//! Why this rule: it reads the whole posterior, not one residual, and needs
//! only the noise variance; TV is 1-homogeneous, so `d / θ - TV(X)` with `X`
//! drawn from the posterior is an unbiased estimate of `d/dθ log p(i | θ)`.
//!
//! Scaling: the likelihood is `exp(-1/2 ||i - T l||^2_W)`, `W = diag(1 /
//! sigma_j^2)`. ADMM here minimizes the unweighted `||i - T l||^2 + λ TV(l)`
//! (MODEL.md Eq. 12, see `crate::solve::solvers`), the MAP of that posterior when
//! `W = w I`; with `w = mean(1 / sigma_j^2)` that MAP is at `λ = 2 θ / w`.

use std::time::Instant;

use faer::Mat;
use rand::SeedableRng;
use rand_distr::Distribution;

use crate::solve::gram::Normal;
use crate::solve::lambda::{check_noise, NoiseLevel};
use crate::solve::solvers::{largest_eigenvalue, AdmmSettings, Prox, Solver, LAMBDA_REL};
use crate::solve::tv::total_variation;
use crate::solve::{check_measurement, Reconstruction, SolveError};
use crate::transport::Transport;

/// Parameters of [`sapg`]; the defaults are the paper's TV-deblurring ones
/// where they carry over (δ exponent 0.8, log step 10 = `0.1 / θ_0` at its
/// `θ_0 = 0.01`, MYULA smoothing `min(5 / L, 2)`, step `0.98 / (L + 1/λ)`,
/// 300 warm-up steps, 25 proximal iterations).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SapgSettings {
    /// MYULA steps at the initial θ before θ moves.
    pub warmup: usize,
    /// SAPG iterations (one MYULA step and one θ step each).
    pub iterations: usize,
    /// Fraction of the iterations skipped before averaging log θ.
    pub burn_in: f64,
    /// `c` of the step `δ_k = c k^-exponent / d` in log θ (times `θ_k`).
    pub log_step: f64,
    /// Exponent of the step decay.
    pub exponent: f64,
    /// Dual iterations of the TV proximal map per MYULA step.
    pub prox_iterations: usize,
    /// Seed of the Langevin noise.
    pub seed: u64,
}

impl Default for SapgSettings {
    fn default() -> Self {
        Self {
            warmup: 300,
            iterations: 3000,
            burn_in: 0.5,
            log_step: 10.0,
            exponent: 0.8,
            prox_iterations: 25,
            seed: 1,
        }
    }
}

/// What [`sapg`] found.
#[derive(Debug, Clone, serde::Serialize)]
pub struct SapgEstimate {
    /// θ of the prior `exp(-θ TV(l))`, averaged in log over the later iterations.
    pub theta: f64,
    /// The ADMM weight of that θ, `2 θ / mean(1 / sigma^2)` (MODEL.md units).
    pub lambda: f64,
    /// θ the chain started at, `d / TV(x0)`.
    pub theta_init: f64,
    /// Mean of `θ_k TV(X_k) / d` over the averaged iterations (1 at the
    /// marginal-likelihood optimum when the chain has mixed).
    pub balance: f64,
    /// Lipschitz constant of the likelihood's gradient, `||T^T W T||`.
    pub lipschitz: f64,
    /// MYULA step.
    pub gamma: f64,
    /// Wall time, seconds.
    pub seconds: f64,
}

/// Empirical-Bayes θ by SAPG with a MYULA sampler (Vidal et al. 2020,
/// Algorithm 1): `η = log θ`, `X_{k+1} = X_k - γ ∇f(X_k) - γ/λ (X_k -
/// prox_{λ θ_k g}(X_k)) + sqrt(2γ) Z`, `g = TV + box` (its proximal map by
/// `crate::solve::tv_denoise`'s dual iterations), then `η_{k+1} = Proj(η_k
/// + δ_k θ_k (d / θ_k - TV(X_{k+1})))`, `θ = exp(mean η)` over the later
/// iterations. `x0` starts the chain and sets `θ_0 = d / TV(x0)`; θ stays in
/// `θ_0 [1e-4, 1e4]`.
///
/// Why: the marginal-likelihood θ is the established empirical-Bayes
/// choice for TV (Vidal et al., SIAM J. Imaging Sci. 13, 2020).
pub fn sapg(
    t: &Transport,
    i: &[f64],
    noise: &NoiseLevel,
    x0: &[f64],
    settings: &SapgSettings,
) -> Result<SapgEstimate, SolveError> {
    check_measurement(t, i)?;
    check_noise(noise, i)?;
    let start = Instant::now();
    let (m, d) = (t.rows(), t.cols());
    if x0.len() != d || x0.iter().any(|v| !v.is_finite()) {
        return Err(SolveError::Parameter {
            name: "x0",
            value: x0.len() as f64,
            reason: "needs one finite value per scene element",
        });
    }
    if noise.variance.iter().any(|&v| v <= 0.0) {
        return Err(SolveError::Parameter {
            name: "noise",
            value: 0.0,
            reason: "SAPG needs a variance > 0 for every measurement",
        });
    }
    if settings.iterations == 0 || !(0.0..1.0).contains(&settings.burn_in) {
        return Err(SolveError::Parameter {
            name: "iterations",
            value: settings.iterations as f64,
            reason: "needs at least one iteration and a burn-in fraction in [0, 1)",
        });
    }
    let grid = t.scene_grid();
    // The weighted Gram T^T W T and T^T W i.
    let sd: Vec<f64> = noise.variance.iter().map(|v| v.sqrt()).collect();
    let tw = Mat::<f64>::from_fn(m, d, |r, c| t.get(r, c) / sd[r]);
    let g = tw.transpose() * &tw;
    let b: Vec<f64> = (0..d)
        .map(|c| (0..m).map(|r| tw[(r, c)] * i[r] / sd[r]).sum())
        .collect();
    let w_mean = noise.variance.iter().map(|v| 1.0 / v).sum::<f64>() / m as f64;
    let lip = largest_eigenvalue(&g);
    if !(lip > 0.0 && lip.is_finite()) {
        return Err(SolveError::Parameter {
            name: "T",
            value: lip,
            reason: "T^T W T has no positive eigenvalue: no scene element reaches the wall",
        });
    }
    let smoothing = (5.0 / lip).min(2.0);
    let gamma = 0.98 / (lip + 1.0 / smoothing);
    let theta_init = d as f64 / total_variation(grid, x0).max(1e-3);
    let (eta_min, eta_max) = ((theta_init * 1e-4).ln(), (theta_init * 1e4).ln());

    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(settings.seed);
    let normal = rand_distr::StandardNormal;
    let mut prox = Prox::new(grid);
    let mut x = x0.to_vec();
    let mut px = vec![0.0; d];
    let mut xm = Mat::<f64>::zeros(d, 1);
    let noise_scale = (2.0 * gamma).sqrt();
    // One MYULA step at θ, in place.
    let mut step = |x: &mut Vec<f64>, theta: f64, rng: &mut rand_chacha::ChaCha8Rng| {
        prox.solve(x, smoothing * theta, settings.prox_iterations, &mut px);
        for (k, v) in x.iter().enumerate() {
            xm[(k, 0)] = *v;
        }
        let gx = &g * &xm;
        for k in 0..d {
            let grad = gx[(k, 0)] - b[k];
            let z: f64 = normal.sample(rng);
            x[k] += -gamma * grad + gamma / smoothing * (px[k] - x[k]) + noise_scale * z;
        }
    };
    for _ in 0..settings.warmup {
        step(&mut x, theta_init, &mut rng);
    }
    let mut eta = theta_init.ln();
    let skip = (settings.burn_in * settings.iterations as f64) as usize;
    let (mut eta_sum, mut balance_sum, mut count) = (0.0, 0.0, 0usize);
    for k in 1..=settings.iterations {
        let theta = eta.exp();
        step(&mut x, theta, &mut rng);
        let ratio = theta * total_variation(grid, &x) / d as f64;
        let delta = settings.log_step * (k as f64).powf(-settings.exponent) / d as f64;
        // δ_k (d / θ - TV(X)) θ = δ_k d (1 - θ TV(X) / d).
        eta = (eta + delta * d as f64 * (1.0 - ratio)).clamp(eta_min, eta_max);
        if k > skip {
            eta_sum += eta;
            balance_sum += ratio;
            count += 1;
        }
    }
    let count = count.max(1) as f64;
    let theta = (eta_sum / count).exp();
    if !theta.is_finite() {
        return Err(SolveError::Parameter {
            name: "theta",
            value: theta,
            reason: "the SAPG iterates left the finite numbers",
        });
    }
    Ok(SapgEstimate {
        theta,
        lambda: 2.0 * theta / w_mean,
        theta_init,
        balance: balance_sum / count,
        lipschitz: lip,
        gamma,
        seconds: start.elapsed().as_secs_f64(),
    })
}

/// ADMM-TV at the SAPG λ: the chain starts from the ADMM solution at the
/// fixed default λ, then one more ADMM solve at `2 θ / mean(1 / sigma^2)`.
///
/// Why: the empirical-Bayes rule of Vidal et al. (2020) as an automatic λ.
pub fn admm_tv_sapg(
    t: &Transport,
    i: &[f64],
    normal: &Normal,
    noise: &NoiseLevel,
    sapg_settings: &SapgSettings,
    settings: &AdmmSettings,
) -> Result<(Reconstruction, SapgEstimate), SolveError> {
    let x0 = Solver::ADMM_TV.run(
        &AdmmSettings {
            lambda: Some(LAMBDA_REL * normal.unit()),
            ..*settings
        }
        .problem(t, i, normal),
    )?;
    let est = sapg(t, i, noise, &x0.image, sapg_settings)?;
    let rec = Solver::ADMM_TV.run(
        &AdmmSettings {
            lambda: Some(est.lambda),
            ..*settings
        }
        .problem(t, i, normal),
    )?;
    Ok((rec, est))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scene::{Channel, Grid};
    use crate::simulate::patterns::Pattern;
    use crate::transport::Block;

    /// Denoising on an 8x8 grid: `T` the identity (64 x 64).
    fn identity(n: usize) -> Transport {
        let grid = Grid { nu: n, nv: n };
        let d = grid.count();
        let mut data = vec![0.0; d * d];
        for k in 0..d {
            data[k * d + k] = 1.0;
        }
        let block = Block {
            pose: "A".into(),
            channel: Channel::None,
        };
        Transport::from_col_major(d, d, data, vec![block], grid, grid)
    }

    fn noisy(t: &Transport, truth: &[f64], sigma: f64, seed: u64) -> Vec<f64> {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
        t.apply(truth)
            .iter()
            .map(|c| {
                let z: f64 = rand_distr::StandardNormal.sample(&mut rng);
                c + sigma * z
            })
            .collect()
    }

    #[test]
    fn more_noise_gives_a_larger_lambda() {
        let t = identity(8);
        let truth = Pattern::Disk.render(t.scene_grid());
        let settings = SapgSettings {
            iterations: 1500,
            ..Default::default()
        };
        let lambda = |sigma: f64| {
            let i = noisy(&t, &truth, sigma, 4);
            let noise = NoiseLevel::measured(vec![sigma * sigma; i.len()]);
            let x0: Vec<f64> = i.iter().map(|v| v.clamp(0.0, 1.0)).collect();
            let est = sapg(&t, &i, &noise, &x0, &settings).unwrap();
            assert!(est.theta.is_finite() && est.theta > 0.0, "{est:?}");
            est.lambda
        };
        let (low, high) = (lambda(0.05), lambda(0.2));
        assert!(
            high > 2.0 * low,
            "λ {low:.3e} at sigma 0.05, {high:.3e} at 0.2"
        );
    }

    #[test]
    fn bad_inputs_are_errors_not_panics() {
        let t = identity(4);
        let i = vec![0.5; 16];
        let noise = NoiseLevel::measured(vec![0.01; 16]);
        let s = SapgSettings::default();
        assert!(sapg(&t, &i, &noise, &[0.0; 3], &s).is_err());
        assert!(sapg(&t, &i, &NoiseLevel::measured(vec![0.0; 16]), &[0.0; 16], &s).is_err());
        assert!(sapg(&t, &i[..8], &noise, &[0.0; 16], &s).is_err());
    }
}
