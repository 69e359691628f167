//! The request that picks a solver and its parameters: one struct every
//! front end embeds (the API's bodies, the stored parameters, the CLI's
//! flags), so a parameter is declared once.

use serde::{Deserialize, Serialize};

use super::admm::AdmmSettings;
use super::Solver;
use crate::solve::SolveError;
use crate::stop::Stop;

/// What to solve with: the solver and its parameters, declared here once.
///
/// Every front end embeds this struct rather than restating its fields:
/// the daemon's `POST /reconstructions` body and a plan's `reconstruct`
/// (`#[serde(flatten)]`, so the keys sit in the body itself), the stored
/// parameters of a reconstruction (`ReconstructionParams`), and the CLI's
/// `reconstruct` (`#[command(flatten)]`: each field's `help` is its flag's
/// text, its doc comment the API's). A solver's new parameter is a field
/// here, read by that solver's `Method::solve`.
///
/// The one exception is the CLI's `--lambda`, which also takes `auto` and
/// goes with `--noise-from` and `--variance`: it stays in the CLI's
/// arguments (`src/cli/reconstruct.rs`) and fills `lambda`.
#[derive(
    Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize, utoipa::ToSchema, clap::Args,
)]
pub struct SolveRequest {
    /// The solver (default `admm-tv`; `/openapi.json` and `--help` list them all).
    #[serde(default)]
    #[arg(long, value_enum, default_value = "admm-tv", help = "Solver")]
    pub solver: Solver,
    /// Regularization weight (MODEL.md units). Default for the TV solvers:
    /// chosen from the noise (resolved-discrepancy rule; `lambda_choice` in
    /// the report says how), the frame-to-frame noise when every capture has
    /// 2 frames or more, else the noise in the measurement's residual;
    /// Tikhonov's: `1e-3 x mean(diag(T^T T))`.
    #[arg(skip)]
    pub lambda: Option<f64>,
    /// ADMM penalty (default: balanced automatically).
    #[arg(
        long,
        value_name = "R",
        help = "ADMM penalty (default: balanced automatically)"
    )]
    pub rho: Option<f64>,
    /// Iteration cap (1-100000; default 500, 5000 with an automatic λ).
    #[serde(default, deserialize_with = "crate::integral::opt_count")]
    #[schema(minimum = 1, maximum = 100000)]
    #[arg(
        long = "max-iter",
        value_name = "N",
        help = "ADMM / FISTA iteration cap (default 500; 5000 with an automatic lambda)"
    )]
    pub max_iter: Option<usize>,
    /// Tolerance in (0, 1) (default 1e-4 for ADMM, 1e-5 for FISTA).
    #[arg(
        long,
        value_name = "T",
        default_value = cli_tol(),
        help = "ADMM relative tolerance on the primal/dual residuals (FISTA: on the relative change of l between iterations)"
    )]
    pub tol: Option<f64>,
    /// Relative singular-value cut-off of `lsq` (default: numerical rank).
    #[arg(
        long,
        value_name = "R",
        help = "Relative singular-value cut-off for --solver lsq (default: numerical rank only)"
    )]
    pub rcond: Option<f64>,
}

/// The CLI's `--tol` when not given: ADMM's default, for every solver (as
/// the CLI always had it; a request without `tol` takes each solver's own).
fn cli_tol() -> &'static str {
    static TOL: std::sync::OnceLock<String> = std::sync::OnceLock::new();
    TOL.get_or_init(|| AdmmSettings::default().tol.to_string())
}

/// Iteration cap of an automatic-λ solve unless the request sets one: small
/// λs (low noise) converge slowly.
pub const AUTO_MAX_ITER: usize = 5000;

impl SolveRequest {
    /// Checks every parameter before anything is computed (a request from a
    /// client is refused with this message before it is queued).
    pub fn check(&self) -> Result<(), SolveError> {
        let bad = |name, value: f64, reason| {
            Err(SolveError::Parameter {
                name,
                value,
                reason,
            })
        };
        if let Some(l) = self.lambda {
            if !(l >= 0.0 && l.is_finite()) {
                return bad("lambda", l, "must be a finite number >= 0");
            }
        }
        if let Some(r) = self.rho {
            if !(r > 0.0 && r.is_finite()) {
                return bad("rho", r, "must be a finite number > 0");
            }
        }
        if let Some(m) = self.max_iter {
            if !(1..=100_000).contains(&m) {
                return bad("max_iter", m as f64, "must be from 1 to 100000");
            }
        }
        if let Some(t) = self.tol {
            if !(t > 0.0 && t < 1.0) {
                return bad("tol", t, "must be in (0, 1)");
            }
        }
        if let Some(r) = self.rcond {
            if !(0.0..1.0).contains(&r) {
                return bad("rcond", r, "must be in [0, 1)");
            }
        }
        Ok(())
    }

    /// ADMM's settings for this request (`auto`: λ chosen from the noise,
    /// which wants the larger iteration cap).
    pub fn admm<'a>(&self, auto: bool, stop: Stop<'a>) -> AdmmSettings<'a> {
        let d = AdmmSettings::default();
        AdmmSettings {
            lambda: self.lambda,
            rho: self.rho,
            max_iter: self
                .max_iter
                .unwrap_or(if auto { AUTO_MAX_ITER } else { d.max_iter }),
            tol: self.tol.unwrap_or(d.tol),
            stop,
            ..d
        }
    }
}
