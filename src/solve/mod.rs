//! Recovering the hidden scene from a measurement (MODEL.md Eq. 12) and
//! judging the result: the solvers (`solvers`: ADMM-TV with a box
//! constraint, FISTA-TV, GP-TV, least-squares and Tikhonov baselines), the
//! automatic λ ([`lambda`]), conditioning of `T` and image metrics
//! (`judge/`), and the operators they share (`operators/`).
//!
//! Solvers take the transport as a dense column-major view and a measurement
//! slice; they check both before any arithmetic, so a wrong length or a NaN
//! becomes a [`SolveError`], never a panic or a NaN image.

// By kind, as the folders show: the solvers, the λ rules, the judging of
// a result, the linear operators they share; the pipelines that use them
// (reconstruct, photo, radiometry, plan, scene, json) sit here. The public
// paths stay flat (`solve::metrics`, `solve::lambda`, ...).
mod judge;
pub mod lambda;
mod operators;
pub(crate) mod solvers;

pub mod json;
pub mod photo;
pub mod radiometry;
pub mod reconstruct;
pub mod resolution;
pub mod scene;
/// The live view's tracker (only the daemon has a live view).
#[cfg(feature = "daemon")]
pub(crate) mod track;

pub(crate) use judge::{adequacy, conditioning};
pub use judge::{metrics, report};
pub use operators::gram;
pub(crate) use operators::{lowrank, triangular, tv};

#[cfg(feature = "daemon")]
pub(crate) use conditioning::condition_with;
pub use conditioning::{condition, Conditioning};
pub use reconstruct::reconstruct;
#[cfg(feature = "report")]
pub(crate) use solvers::tv_denoise;
pub(crate) use solvers::Problem;
pub use solvers::{
    admm_tv, admm_tv_prepared, least_squares, tikhonov, AdmmSettings, FistaSettings, Needs,
    SolveRequest, Solver, AUTO_MAX_ITER, LAMBDA_REL,
};

/// How far (relative) a stream's noise, or its measurement's norm, may move
/// from the one its λ was searched at before λ is searched again (the norm:
/// a scene that changed, such as a difference image while its background
/// settles, wants another λ).
/// Why: a search is about twenty solves; a live view's windows (the same
/// frames count, the same exposure) all have one noise, and a λ within a
/// few percent of the search's gives the same image. On a chair-size scene
/// (1044 unknowns, three colours) the search of every window held live
/// view to 0.16 results a second.
#[cfg(feature = "daemon")]
pub(crate) const LAMBDA_KEPT: f64 = 0.1;

use crate::transport::Transport;

/// Current parallelism for dense kernels (faer's global setting): every
/// solver's factorizations and products run at it.
pub(crate) fn par() -> faer::Par {
    faer::get_global_parallelism()
}

/// Why a reconstruction could not be computed.
#[derive(Debug, thiserror::Error)]
pub enum SolveError {
    /// The measurement does not have one value per row of `T`.
    #[error("measurement has {got} values but T has {expected} rows (wall elements x pose/angle blocks); was it simulated for another scene?")]
    Length {
        /// Rows of `T`.
        expected: usize,
        /// Values given.
        got: usize,
    },
    /// The measurement holds a NaN or an infinity.
    #[error("measurement value {index} is {value}; every value must be finite (check the capture or the dark frame)")]
    NonFinite {
        /// First bad index.
        index: usize,
        /// Its value.
        value: f64,
    },
    /// A solver parameter is out of range.
    #[error("{name} = {value}: {reason}")]
    Parameter {
        /// Parameter name, as on the command line.
        name: &'static str,
        /// Given value.
        value: f64,
        /// Acceptable range.
        reason: &'static str,
    },
    /// A dense factorization failed (not positive definite / no convergence).
    #[error("{0}")]
    Factorization(String),
    /// Colours solved together (ADMM-TV's colour TV) were not all of one
    /// `T`: their normal equations do not share its Gram.
    #[error("colour {colour}'s normal equations are not on the first colour's T^T T: colours solved together must share one T (solve them apart)")]
    OtherGram {
        /// The first colour (from 0) on another Gram.
        colour: usize,
    },
    /// The caller raised the solve's [`Stop`](crate::stop::Stop) flag (a cancelled job).
    #[error("stopped on request after {iterations} iterations")]
    Stopped {
        /// Iterations run before the flag was seen.
        iterations: usize,
    },
}

/// `Err(Stopped)` when `stop` is raised at a checkpoint iteration.
pub(crate) fn check_stop(stop: crate::stop::Stop<'_>, iterations: usize) -> Result<(), SolveError> {
    if stop.raised_at(iterations) {
        Err(SolveError::Stopped { iterations })
    } else {
        Ok(())
    }
}

/// The recovered scene and how it was obtained.
#[derive(Debug, Clone, serde::Serialize)]
pub struct Reconstruction {
    /// Scene radiance per element, row-major on the scene grid, in [0, 1].
    #[serde(skip)]
    pub image: Vec<f64>,
    /// Solver statistics.
    pub stats: SolveStats,
}

/// Statistics every solver reports (the `solver` object of `report.json`).
#[derive(Debug, Clone, Default, serde::Serialize)]
pub struct SolveStats {
    /// The solver's name (`admm-tv`, ...).
    pub solver: String,
    /// Regularization weight actually used (MODEL.md units), if any.
    pub lambda: Option<f64>,
    /// ADMM penalty actually used.
    pub rho: Option<f64>,
    /// Iterations run (0 for direct solvers).
    pub iterations: usize,
    /// Whether the stopping rule was met (direct solvers: always).
    pub converged: bool,
    /// Final primal residual `||A l - z||` (ADMM).
    pub primal_residual: Option<f64>,
    /// Final dual residual `rho ||A^T (z - z_prev)||` (ADMM).
    pub dual_residual: Option<f64>,
    /// `||i - T l||^2 + lambda TV(l)` at the returned `l`.
    pub objective: f64,
    /// `||i - T l||^2` at the returned `l`.
    pub data_misfit: f64,
    /// Rank used by the pseudo-inverse (lsq).
    pub rank: Option<usize>,
    /// Fraction of the unconstrained solution clipped into [0, 1] (baselines).
    pub clipped_fraction: Option<f64>,
    /// Seconds spent forming `T^T T` (and `T^T i`).
    pub gram_seconds: f64,
    /// Seconds spent in the factorization.
    pub factor_seconds: f64,
    /// Seconds spent iterating (ADMM) or back-substituting.
    pub iterate_seconds: f64,
    /// Total wall time of the solve.
    pub total_seconds: f64,
    /// Things the user should know before trusting the result.
    pub warnings: Vec<String>,
}

/// Checks an iterative solver's tolerance (`> 0`, finite).
pub(crate) fn check_tol(tol: f64) -> Result<(), SolveError> {
    if tol > 0.0 && tol.is_finite() {
        Ok(())
    } else {
        Err(SolveError::Parameter {
            name: "tol",
            value: tol,
            reason: "must be a positive number",
        })
    }
}

/// Checks a regularization weight (`>= 0`, finite).
pub(crate) fn check_lambda(lambda: f64) -> Result<(), SolveError> {
    if lambda >= 0.0 && lambda.is_finite() {
        Ok(())
    } else {
        Err(SolveError::Parameter {
            name: "lambda",
            value: lambda,
            reason: "must be a finite number >= 0",
        })
    }
}

/// The rows of `i` that were not measured (NaN: a wall element with a
/// pixel at full scale in some frame), set to 0 with their `variance` 0;
/// returns their indices, whose rows of `T` must be zeroed too
/// ([`Transport::with_rows_zeroed`]): no part in the fit or the noise.
pub(crate) fn zero_unmeasured(i: &mut [f64], mut variance: Option<&mut [f64]>) -> Vec<usize> {
    let missing: Vec<usize> = (0..i.len()).filter(|&j| !i[j].is_finite()).collect();
    for &j in &missing {
        i[j] = 0.0;
        if let Some(v) = variance.as_deref_mut().and_then(|v| v.get_mut(j)) {
            *v = 0.0;
        }
    }
    missing
}

/// What a report says of `missing` rows out of `rows`, if any.
pub(crate) fn unmeasured_warning(missing: &[usize], rows: usize) -> Option<String> {
    (!missing.is_empty()).then(|| {
        format!(
            "{} of {rows} wall elements were not measured (a pixel of theirs saturated) and are left out of the fit",
            missing.len()
        )
    })
}

/// Checks a measurement against `T` before a solve.
pub(crate) fn check_measurement(t: &Transport, i: &[f64]) -> Result<(), SolveError> {
    if i.len() != t.rows() {
        return Err(SolveError::Length {
            expected: t.rows(),
            got: i.len(),
        });
    }
    if let Some((index, &value)) = i.iter().enumerate().find(|(_, v)| !v.is_finite()) {
        return Err(SolveError::NonFinite { index, value });
    }
    Ok(())
}
