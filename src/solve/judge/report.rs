//! The `report.json` of a reconstruction: solver statistics, conditioning of
//! `T` and, when the truth is known, the image metrics. Shared by the CLI and
//! the daemon so both write the same, documented format.

use crate::scene::Grid;
use crate::solve::conditioning::Conditioning;
use crate::solve::metrics::Metrics;
use crate::solve::SolveStats;
use crate::transport::Block;

/// Above this condition number a result is flagged as untrustworthy.
pub(crate) const KAPPA_WARN: f64 = 1e8;

/// Conditioning of `T` without the full spectrum.
#[derive(Debug, Clone, serde::Serialize)]
pub struct ConditioningSummary {
    /// `sigma_max / sigma_min` (`"inf"` when rank-deficient).
    #[serde(serialize_with = "crate::solve::json::finite_or_inf")]
    pub kappa: f64,
    /// Numerical rank.
    pub rank: usize,
    /// Largest singular value.
    pub sigma_max: f64,
    /// Smallest singular value.
    pub sigma_min: f64,
}

impl From<&Conditioning> for ConditioningSummary {
    fn from(c: &Conditioning) -> Self {
        Self {
            kappa: c.kappa,
            rank: c.rank,
            sigma_max: c.singular_values.first().copied().unwrap_or(0.0),
            sigma_min: c.singular_values.last().copied().unwrap_or(0.0),
        }
    }
}

/// Everything a reconstruction reports.
#[derive(Debug, Clone, serde::Serialize)]
pub struct Report {
    /// Scene name (file stem).
    pub scene: String,
    /// Scene grid (shape of the recovered image: `nv` rows, `nu` columns).
    pub scene_grid: Grid,
    /// Wall grid.
    pub wall_grid: Grid,
    /// Row blocks of `T`, in measurement order.
    pub blocks: Vec<Block>,
    /// Rows of `T`.
    pub rows: usize,
    /// Columns of `T`.
    pub cols: usize,
    /// Seconds spent building `T`.
    pub transport_seconds: f64,
    /// Conditioning of `T`.
    pub conditioning: ConditioningSummary,
    /// Solver statistics.
    pub solver: SolveStats,
    /// Metrics against the truth, when one was given.
    pub metrics: Option<Metrics>,
    /// How lambda was chosen, when it was chosen automatically.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub lambda_choice: Option<crate::solve::lambda::LambdaChoice>,
    /// Whether `T` explains the measurement: the best fit's misfit against
    /// the noise level; `null` when no independent noise level is known (a
    /// noise estimated from the same residual cannot tell model from noise).
    pub model_check: Option<crate::solve::adequacy::Adequacy>,
    /// How finely `T` was sampled when polnlos chose it from the noise
    /// (keys the scene file left out; MODEL.md "Rows that match the measurement").
    #[serde(skip_serializing_if = "Option::is_none")]
    pub model: Option<crate::transport::choose::ModelChoice>,
    /// The radiometric gain the measurement was divided by into units of
    /// `T l` (fraction of full scale per microsecond of exposure per unit of
    /// `T l`), and where it came from; `polnlos measure --gain` with this
    /// number reproduces the measurement offline. Absent when the
    /// measurement was given in units of `T l`.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub gain: Option<Gain>,
    /// Calibrated (this report) or fitted, whether the request named it,
    /// and why; absent where no choice was made (`polnlos reconstruct`
    /// reads a measurement in units of `T l`).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub radiometry: Option<crate::solve::radiometry::RadiometryChoice>,
    /// Something is wrong with this result: the model does not explain the
    /// measurement, pixels saturated, frames lost, the solver stopped short.
    pub warnings: Vec<String>,
    /// Facts about the bench that hold for any result from it: the
    /// conditioning of `T`, a grid finer than the noise supports, a default
    /// λ. Why apart: a warning must stand out, and it cannot when every
    /// result carries these.
    pub notes: Vec<String>,
    /// A colour camera's result: each colour's own fit, red, green, blue
    /// (the rest of the report is green's, its metrics all three's).
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub colours: Vec<ColourReport>,
}

/// One colour of a colour camera's reconstruction, fitted on its own.
#[derive(Debug, Clone, serde::Serialize)]
pub struct ColourReport {
    /// Which colour.
    pub colour: crate::scene::Colour,
    /// Metrics against the truth, when one was given.
    pub metrics: Option<Metrics>,
    /// How its λ was chosen.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub lambda_choice: Option<crate::solve::lambda::LambdaChoice>,
    /// Whether `T` explains this colour's measurement.
    pub model_check: Option<crate::solve::adequacy::Adequacy>,
    /// The gain its measurement was divided by.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub gain: Option<Gain>,
    /// Solver statistics.
    pub solver: SolveStats,
    /// What is wrong with this colour's result.
    pub warnings: Vec<String>,
}

impl ColourReport {
    /// The colour's part of its own full `report`.
    pub fn of(colour: crate::scene::Colour, report: &Report) -> Self {
        Self {
            colour,
            metrics: report.metrics,
            lambda_choice: report.lambda_choice.clone(),
            model_check: report.model_check,
            gain: report.gain,
            solver: report.solver.clone(),
            warnings: report.warnings.clone(),
        }
    }

    /// The metrics of all colours together: PSNR of their mean squared
    /// error (that of every value), and the mean ZNCC and SSIM; `None`
    /// without a truth. (The daemon's colour result replaces the mean ZNCC
    /// by the ZNCC of every value, which needs the images.)
    pub fn combined(colours: &[ColourReport]) -> Option<Metrics> {
        let all: Vec<&Metrics> = colours
            .iter()
            .map(|c| c.metrics.as_ref())
            .collect::<Option<_>>()?;
        let n = all.len().max(1) as f64;
        let mse = all
            .iter()
            .map(|m| 10f64.powf(-m.psnr_db / 10.0))
            .sum::<f64>()
            / n;
        Some(Metrics {
            psnr_db: -10.0 * mse.log10(),
            zncc: all.iter().map(|m| m.zncc).sum::<f64>() / n,
            ssim: all.iter().map(|m| m.ssim).sum::<f64>() / n,
        })
    }
}

impl Report {
    /// Assembles the report of a finished solve: layout from `T`, the
    /// conditioning summary, metrics against `truth` when given, the
    /// solver's warnings and the conditioning's notes.
    pub fn new(
        scene: String,
        t: &crate::transport::Transport,
        transport_seconds: f64,
        cond: &Conditioning,
        rec: crate::solve::Reconstruction,
        truth: Option<&[f64]>,
        lambda_choice: Option<crate::solve::lambda::LambdaChoice>,
    ) -> Self {
        let warnings = rec.stats.warnings.clone();
        Self {
            scene,
            scene_grid: t.scene_grid(),
            wall_grid: t.wall_grid(),
            blocks: t.blocks().to_vec(),
            rows: t.rows(),
            cols: t.cols(),
            transport_seconds,
            conditioning: cond.into(),
            metrics: truth.map(|tr| crate::solve::metrics::compare(t.scene_grid(), tr, &rec.image)),
            solver: rec.stats,
            lambda_choice,
            model_check: None,
            model: None,
            gain: None,
            radiometry: None,
            warnings,
            notes: conditioning_notes(cond),
            colours: Vec::new(),
        }
    }
}

/// Notes that the conditioning of `T` implies for any result.
pub(crate) fn conditioning_notes(c: &Conditioning) -> Vec<String> {
    if c.is_rank_deficient() {
        let resolution = if c.from_gram {
            format!(
                ", counting singular values above {:.1e} of the largest (the resolution of T^T T)",
                c.threshold
                    / c.singular_values
                        .first()
                        .copied()
                        .unwrap_or(1.0)
                        .max(f64::MIN_POSITIVE)
            )
        } else {
            String::new()
        };
        vec![format!(
            "T is rank-deficient (rank {} of {} scene elements{resolution}): some scene patterns are invisible to this setup; use a coarser scene grid, more poses or polarizer angles",
            c.rank, c.cols
        )]
    } else if c.kappa > KAPPA_WARN {
        vec![format!("kappa(T) = {:.3e} > {KAPPA_WARN:.0e}: noise is amplified that much; trust only heavily regularized results", c.kappa)]
    } else {
        Vec::new()
    }
}

/// Mean SNR below which a measurement is mostly noise.
pub(crate) const SNR_WARN: f64 = 1.0;

/// Mean per-element SNR of a measurement, `mean_j max(i_j, 0) / sigma_j`
/// (elements with zero variance are left out).
pub fn mean_snr(i: &[f64], variance: &[f64]) -> f64 {
    let (sum, n) = i
        .iter()
        .zip(variance)
        .filter(|(_, v)| **v > 0.0)
        .fold((0.0, 0usize), |(s, n), (x, v)| {
            (s + x.max(0.0) / v.sqrt(), n + 1)
        });
    if n == 0 {
        f64::INFINITY
    } else {
        sum / n as f64
    }
}

/// The warning a measurement of mean SNR `snr` deserves, if any.
pub(crate) fn snr_warnings(snr: f64) -> Vec<String> {
    if snr < SNR_WARN {
        vec![format!(
            "the mean SNR of the measurement is {snr:.2} (< {SNR_WARN}): it is mostly noise, so the result shows the regularizer more than the scene; expose longer or average more frames"
        )]
    } else {
        Vec::new()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn mean_snr_and_its_warning() {
        // 100 / 10 and 4 / 2: mean SNR 6; zero-variance elements are left out.
        assert_eq!(mean_snr(&[100.0, 4.0, 7.0], &[100.0, 4.0, 0.0]), 6.0);
        assert_eq!(mean_snr(&[-1.0, 1.0], &[1.0, 4.0]), 0.25);
        assert!(snr_warnings(6.0).is_empty());
        assert!(snr_warnings(0.25)[0].contains("mean SNR of the measurement is 0.25"));
        assert_eq!(mean_snr(&[1.0], &[0.0]), f64::INFINITY);
    }
}

/// The radiometric gain a measurement was divided by.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct Gain {
    /// Fraction of full scale per microsecond of exposure per unit of `T l`.
    pub value: f64,
    /// `calibration` (the daemon's `[calibration]`, or the fake camera's
    /// known one) or `estimated` (scaled so the brightest recovered element
    /// is about 1: relative units only).
    pub source: &'static str,
}
