//! Whether a model explains a measurement: the best fit's misfit against the
//! noise level, as chi-square per degree of freedom.
//!
//! Why: a bench is model error plus noise. A fit whose residual is several
//! times the noise is not a measurement of the scene (or the wall) but of
//! what the model leaves out, and its numbers, standard errors included,
//! must say so. MODEL.md fixes no rule; ours: `chi2/dof = sum_j r_j^2 /
//! sigma_j^2 / dof`, flagged when the residual's RMS exceeds
//! [`MISFIT_LIMIT`] times the noise's (`chi2/dof > 9`).

use serde::Serialize;

/// Largest accepted ratio of the residual's RMS to the noise's RMS,
/// `sqrt(chi2/dof)`, before a fit is flagged: about 3x the noise unexplained.
pub const MISFIT_LIMIT: f64 = 3.0;

/// The likely causes a flagged fit names, in the order a bench user checks them.
pub(crate) const LIKELY_CAUSES: &str = "the polarizer model ([polarizer] model = \"absorbing\" or \"transmitting\"), the poses' homographies, the wall parameters (roughness, ior, kd, [wall] diffuse), stray light on the wall, or captures without dark subtraction";

/// How well a fit explains its measurement.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Adequacy {
    /// `sum r^2 / sigma^2 / dof`; `None` when no independent noise level is known.
    pub chi2_per_dof: Option<f64>,
    /// `sqrt(chi2/dof)`: the residual's RMS in units of the noise's RMS.
    pub misfit_to_noise: Option<f64>,
    /// Degrees of freedom: measurements minus fitted numbers.
    pub dof: usize,
    /// RMS of the residual, in the units of the measurement.
    pub residual_rms: f64,
    /// RMS of the noise (`sqrt(mean sigma^2)`), when known.
    pub noise_rms: Option<f64>,
    /// Whether the model explains the measurement to within [`MISFIT_LIMIT`]
    /// times its noise; `None` when that cannot be told (no noise level).
    pub explained: Option<bool>,
}

impl Adequacy {
    /// The check of residual `r` of a fit with `fitted` free numbers, against
    /// per-measurement noise variances (`None`: unknown). Elements of zero
    /// variance carry no noise estimate and are left out of chi-square.
    pub fn of(residual: &[f64], variance: Option<&[f64]>, fitted: usize) -> Self {
        let n = residual.len();
        let dof = n.saturating_sub(fitted).max(1);
        let rss: f64 = residual.iter().map(|r| r * r).sum();
        let residual_rms = (rss / n.max(1) as f64).sqrt();
        let noise = variance.and_then(|v| {
            let (chi2, used, var_sum) = residual
                .iter()
                .zip(v)
                .filter(|(_, s)| **s > 0.0)
                .fold((0.0, 0usize, 0.0), |(c, k, vs), (r, s)| {
                    (c + r * r / s, k + 1, vs + s)
                });
            (used > fitted && chi2.is_finite()).then(|| {
                let dof_used = (used - fitted) as f64;
                (chi2 / dof_used, (var_sum / used as f64).sqrt())
            })
        });
        let chi2_per_dof = noise.map(|(c, _)| c);
        let misfit_to_noise = chi2_per_dof.map(f64::sqrt);
        Self {
            chi2_per_dof,
            misfit_to_noise,
            dof,
            residual_rms,
            noise_rms: noise.map(|(_, s)| s),
            explained: misfit_to_noise.map(|m| m <= MISFIT_LIMIT),
        }
    }

    /// The check from a misfit alone: `rss = ||i - T l||^2` of the best fit
    /// with `fitted` effective free numbers, against the noise's total
    /// variance `sum sigma^2` over `n` measurements (chi-square with the mean
    /// variance; used where the fit reports its misfit but not its residual).
    pub fn of_misfit(rss: f64, total_variance: f64, n: usize, fitted: usize) -> Self {
        let dof = n.saturating_sub(fitted).max(1);
        let mean_var = total_variance / n.max(1) as f64;
        let chi2_per_dof =
            (mean_var > 0.0 && rss.is_finite()).then(|| rss / (mean_var * dof as f64));
        let misfit_to_noise = chi2_per_dof.map(f64::sqrt);
        Self {
            chi2_per_dof,
            misfit_to_noise,
            dof,
            residual_rms: (rss / n.max(1) as f64).sqrt(),
            noise_rms: (mean_var > 0.0).then(|| mean_var.sqrt()),
            explained: misfit_to_noise.map(|m| m <= MISFIT_LIMIT),
        }
    }

    /// The factor that standard errors from the noise alone must be scaled
    /// by so that they cover the misfit: `max(1, sqrt(chi2/dof))`.
    pub fn error_scale(&self) -> f64 {
        self.misfit_to_noise.map_or(1.0, |m| m.max(1.0))
    }

    /// The warning a flagged fit deserves, naming what was fitted and the
    /// likely causes; `None` when the model explains the data or that is unknown.
    pub fn warning(&self, what: &str) -> Option<String> {
        self.warning_with_causes(what, LIKELY_CAUSES)
    }

    /// [`Adequacy::warning`] naming other likely `causes` (a fit that is not of `T`).
    pub fn warning_with_causes(&self, what: &str, causes: &str) -> Option<String> {
        match (self.explained, self.misfit_to_noise) {
            (Some(false), Some(m)) => Some(format!(
                "the model does not explain {what}: its best fit leaves {m:.1}x the noise unexplained (chi2/dof = {:.3}, more than {MISFIT_LIMIT}x is flagged); likely causes: {causes}",
                m * m
            )),
            _ => None,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn residual_at_the_noise_is_explained() {
        // Residual +-1 on every element, noise variance 1: chi2/dof = n/(n-2).
        let r: Vec<f64> = (0..100)
            .map(|k| if k % 2 == 0 { 1.0 } else { -1.0 })
            .collect();
        let a = Adequacy::of(&r, Some(&vec![1.0; 100]), 2);
        assert!((a.chi2_per_dof.unwrap() - 100.0 / 98.0).abs() < 1e-12);
        assert_eq!(a.explained, Some(true));
        assert_eq!(a.error_scale(), a.misfit_to_noise.unwrap());
        assert!(a.warning("the capture").is_none());
        assert_eq!(a.dof, 98);
    }

    #[test]
    fn a_misfit_of_21x_the_noise_is_flagged_and_scales_the_errors() {
        // 0.63 % residual at 0.03 % noise (the wall calibration).
        let r = vec![0.0063; 400];
        let a = Adequacy::of(&r, Some(&vec![0.0003f64.powi(2); 400]), 4);
        let m = a.misfit_to_noise.unwrap();
        assert!((m - 21.0 * (400.0f64 / 396.0).sqrt()).abs() < 1e-9, "{m}");
        assert_eq!(a.explained, Some(false));
        assert!((a.error_scale() - m).abs() < 1e-12);
        let w = a.warning("the source captures").unwrap();
        assert!(
            w.contains("21.1x the noise") && w.contains("polarizer model"),
            "{w}"
        );
    }

    #[test]
    fn a_misfit_alone_gives_the_same_verdict() {
        let a = Adequacy::of_misfit(400.0 * 0.0063f64.powi(2), 400.0 * 0.0003f64.powi(2), 400, 4);
        let b = Adequacy::of(&vec![0.0063; 400], Some(&vec![0.0003f64.powi(2); 400]), 4);
        assert!((a.chi2_per_dof.unwrap() - b.chi2_per_dof.unwrap()).abs() < 1e-9);
        assert_eq!(a.explained, Some(false));
        assert_eq!(Adequacy::of_misfit(1.0, 0.0, 10, 1).explained, None);
    }

    #[test]
    fn no_noise_level_means_no_verdict() {
        let a = Adequacy::of(&[1.0, 2.0, 3.0], None, 1);
        assert_eq!((a.chi2_per_dof, a.explained), (None, None));
        assert_eq!(a.error_scale(), 1.0);
        assert!(a.warning("x").is_none());
        // Zero variances carry no estimate: too few left is no verdict either.
        let b = Adequacy::of(&[1.0, 2.0, 3.0], Some(&[0.0, 0.0, 1.0]), 1);
        assert_eq!(b.explained, None);
    }
}
