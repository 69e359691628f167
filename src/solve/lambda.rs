//! Choosing the TV weight from the noise (Morozov's discrepancy principle):
//! the largest smoothing whose data misfit is what the noise alone explains,
//! `||i - T l_lambda||^2 = sum_j sigma_j^2`.
//!
//! Why this rule: it needs no truth, only the noise level that a capture
//! (frame-to-frame variance) or a simulation (photons, read noise, bits)
//! provides, and the misfit grows monotonically with lambda, so a bisection in
//! log(lambda) finds it. One `T^T T` serves every trial.

use super::admm::{admm_tv_prepared, AdmmSettings};
use super::gram::Normal;
use super::{check_measurement, Reconstruction, SolveError};
use crate::transport::Transport;

/// Per-measurement noise variance, in the units of `T l` squared.
#[derive(Debug, Clone, PartialEq)]
pub struct NoiseLevel {
    /// `sigma_j^2` for every row of `T`.
    pub variance: Vec<f64>,
}

impl NoiseLevel {
    /// The noise of a simulated camera (see [`crate::simulate::NoiseModel`]):
    /// shot noise from the measured signal, read noise and quantization,
    /// `sigma_j^2 = (max(i_j, 0) e + r^2)/e^2 + q^2/12` with `e` electrons per
    /// unit and `q` units per digital number.
    pub fn from_camera(
        i: &[f64],
        electrons_per_unit: f64,
        read_noise: f64,
        units_per_dn: f64,
    ) -> Self {
        let e = electrons_per_unit;
        Self {
            variance: i
                .iter()
                .map(|&v| {
                    (v.max(0.0) * e + read_noise * read_noise) / (e * e)
                        + units_per_dn * units_per_dn / 12.0
                })
                .collect(),
        }
    }

    /// `sum_j sigma_j^2`: the expected misfit of the true scene.
    pub fn total(&self) -> f64 {
        self.variance.iter().sum()
    }
}

/// How the automatic lambda was found (the `lambda_choice` of a report).
#[derive(Debug, Clone, serde::Serialize)]
pub struct LambdaChoice {
    /// `discrepancy`.
    pub rule: &'static str,
    /// Misfit aimed at, `sum sigma^2`.
    pub target: f64,
    /// Misfit reached.
    pub misfit: f64,
    /// Lambda chosen.
    pub lambda: f64,
    /// Every (lambda, misfit) tried, in order.
    pub trials: Vec<(f64, f64)>,
}

/// Lambda range searched, relative to `mean(diag(T^T T))`.
const RANGE_REL: (f64, f64) = (1e-7, 1e1);
/// Smallest penalty used, relative to `mean(diag(T^T T))`.
const RHO_FLOOR_REL: f64 = 1e-3;
/// Bisection steps in log10(lambda): 8 decades / 2^14 = 5e-4 decade.
const STEPS: usize = 14;

/// ADMM-TV with lambda chosen by the discrepancy principle.
pub fn admm_tv_discrepancy(
    t: &Transport,
    i: &[f64],
    noise: &NoiseLevel,
    settings: &AdmmSettings,
) -> Result<(Reconstruction, LambdaChoice), SolveError> {
    check_measurement(t, i)?;
    if noise.variance.len() != i.len()
        || noise.variance.iter().any(|v| !(v.is_finite() && *v >= 0.0))
    {
        return Err(SolveError::Parameter {
            name: "noise",
            value: noise.variance.len() as f64,
            reason: "needs one finite variance >= 0 per measurement",
        });
    }
    let normal = Normal::new(t.as_mat(), i);
    let unit = normal.unit();
    let target = noise.total();
    let mut trials = Vec::new();
    let mut solve = |lambda: f64| -> Result<Reconstruction, SolveError> {
        // rho = lambda converges fastest, but below RHO_FLOOR_REL the system
        // T^T T + rho (D^T D + I) inherits kappa(T)^2 and ADMM stalls.
        let rho = settings.rho.unwrap_or(lambda.max(RHO_FLOOR_REL * unit));
        let r = admm_tv_prepared(
            t,
            i,
            &normal,
            &AdmmSettings {
                lambda: Some(lambda),
                rho: Some(rho),
                ..*settings
            },
        )?;
        trials.push((lambda, r.stats.data_misfit));
        Ok(r)
    };
    let (mut lo, mut hi) = ((RANGE_REL.0 * unit).log10(), (RANGE_REL.1 * unit).log10());
    let at_hi = solve(10f64.powf(hi))?;
    let mut warning = None;
    let mut best = if at_hi.stats.data_misfit <= target {
        warning = Some("even the strongest regularization tried fits the data within the noise: the measurement carries almost no information about the scene".to_string());
        at_hi
    } else {
        let at_lo = solve(10f64.powf(lo))?;
        if at_lo.stats.data_misfit > target {
            warning = Some(format!(
                "the data misfit ({:.3e}) stays above the noise level ({target:.3e}) even with almost no regularization: the noise is underestimated or the model does not fit the measurement",
                at_lo.stats.data_misfit
            ));
            at_lo
        } else {
            let mut keep = at_lo;
            for _ in 0..STEPS {
                let mid = 0.5 * (lo + hi);
                let r = solve(10f64.powf(mid))?;
                if r.stats.data_misfit > target {
                    hi = mid;
                } else {
                    lo = mid;
                    keep = r;
                }
            }
            keep
        }
    };
    if let Some(w) = warning {
        best.stats.warnings.push(w);
    }
    let choice = LambdaChoice {
        rule: "discrepancy",
        target,
        misfit: best.stats.data_misfit,
        lambda: best.stats.lambda.unwrap_or(0.0),
        trials,
    };
    Ok((best, choice))
}
