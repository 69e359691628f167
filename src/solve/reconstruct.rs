//! The reconstruction use case, once, for every front end: a typed request
//! (solver and its parameters), the noise level when one is known, and the
//! report. `polnlos reconstruct` and the daemon both call [`reconstruct`], so
//! a solver, a warning or the automatic λ exists in both or in neither.
//!
//! λ is chosen from the noise whenever the request leaves it out (the
//! resolved-discrepancy rule of [`super::lambda`]): from the caller's noise
//! level (a camera model, frame-to-frame variance) or, when there is none,
//! from the measurement itself ([`NoiseLevel::from_residual`]).

use serde::{Deserialize, Serialize};

use super::adequacy::Adequacy;
use super::admm::admm_tv_prepared;
use super::conditioning::Conditioning;
use super::gram::Normal;
use super::lambda::{
    admm_tv_resolved, admm_tv_resolved_prepared, least_squares_residual_with, LambdaChoice,
    NoiseLevel, NoiseSource, RESOLVED_TOLERANCE,
};
use super::report::{mean_snr, snr_warnings, Report};
use super::{
    admm_tv, fista_tv, least_squares, tikhonov, AdmmSettings, FistaSettings, SolveError, Stop,
};
use crate::transport::Transport;

/// The solvers polnlos offers.
#[derive(
    Debug,
    Clone,
    Copy,
    PartialEq,
    Eq,
    Default,
    Serialize,
    Deserialize,
    clap::ValueEnum,
    utoipa::ToSchema,
)]
#[serde(rename_all = "kebab-case")]
pub enum Solver {
    /// ADMM with isotropic TV and the box 0 <= l <= 1 (MODEL.md Eq. 12).
    #[default]
    AdmmTv,
    /// FISTA with a TV proximal step and the box (Saunders et al. 2019); same objective.
    FistaTv,
    /// Tikhonov (ridge) regularization, clipped to [0, 1].
    Tikhonov,
    /// (Truncated) pseudo-inverse, clipped to [0, 1].
    Lsq,
}

impl Solver {
    /// The name in files and requests (`admm-tv`, ...).
    pub fn name(self) -> &'static str {
        match self {
            Solver::AdmmTv => "admm-tv",
            Solver::FistaTv => "fista-tv",
            Solver::Tikhonov => "tikhonov",
            Solver::Lsq => "lsq",
        }
    }
}

/// What to solve with: the same fields from the command line and from JSON.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
pub struct SolveRequest {
    /// Solver (default `admm-tv`).
    #[serde(default)]
    pub solver: Solver,
    /// TV weight in MODEL.md units; absent: chosen from the noise (TV
    /// solvers), `1e-3 x mean(diag(T^T T))` (Tikhonov).
    pub lambda: Option<f64>,
    /// ADMM penalty (default: balanced automatically).
    pub rho: Option<f64>,
    /// Iteration cap (1-100000; default 500, 5000 with an automatic λ).
    pub max_iter: Option<usize>,
    /// Tolerance in (0, 1) (default 1e-4).
    pub tol: Option<f64>,
    /// Relative singular-value cut-off of `lsq` (default: numerical rank).
    pub rcond: Option<f64>,
}

/// Iteration cap of an automatic-λ solve unless the request sets one: small
/// λs (low noise) converge slowly.
pub const AUTO_MAX_ITER: usize = 5000;

/// Largest least-squares RMS error (fraction of the radiance range) before a
/// reconstruction warns that its grid is finer than the data support (as
/// `polnlos plan`).
pub const PLAN_TOLERANCE: f64 = RESOLVED_TOLERANCE;

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

    fn admm<'a>(&self, auto: bool, stop: Stop<'a>) -> AdmmSettings<'a> {
        let d = AdmmSettings::default();
        AdmmSettings {
            lambda: self.lambda,
            rho: self.rho,
            max_iter: self
                .max_iter
                .unwrap_or(if auto { AUTO_MAX_ITER } else { d.max_iter }),
            tol: self.tol.unwrap_or(d.tol),
            stop,
        }
    }
}

/// Where the result and its report name the scene, what to compare with,
/// and the flag that ends the solve early (a cancelled job).
#[derive(Default)]
pub struct Context<'a> {
    /// Scene name (file stem).
    pub scene: String,
    /// Seconds spent building `T`.
    pub transport_seconds: f64,
    /// Truth on the scene grid, for PSNR, ZNCC and SSIM.
    pub truth: Option<&'a [f64]>,
    /// Raised by another thread to stop the iterative solvers.
    pub stop: Stop<'a>,
}

/// A finished reconstruction: the image on the scene grid and its report.
pub struct Solved {
    /// Recovered radiance, row-major on the scene grid, in [0, 1].
    pub image: Vec<f64>,
    /// Everything the user should know about it.
    pub report: Report,
}

/// Solves `req` on measurement `i` of `t`, with the noise level when the
/// caller knows it (else estimated from `i` for an automatic λ), and
/// assembles the report (conditioning, solver statistics, λ choice, metrics
/// against the truth, SNR and grid warnings).
pub fn reconstruct(
    t: &Transport,
    i: &[f64],
    noise: Option<NoiseLevel>,
    cond: &Conditioning,
    req: &SolveRequest,
    ctx: Context<'_>,
) -> Result<Solved, SolveError> {
    req.check()?;
    let normal = if req.solver == Solver::AdmmTv {
        super::check_measurement(t, i)?;
        Some(Normal::of(t, i))
    } else {
        None
    };
    reconstruct_prepared(t, i, noise, cond, normal.as_ref(), req, ctx)
}

/// [`reconstruct`] with `T^T T` and `T^T i` already formed for ADMM-TV
/// (`normal`, made with [`Normal::of`] from this `t` and `i`): one Gram, and
/// its low-rank form, serve the conditioning, the noise estimate, every λ
/// trial and the solve.
pub fn reconstruct_prepared(
    t: &Transport,
    i: &[f64],
    noise: Option<NoiseLevel>,
    cond: &Conditioning,
    normal: Option<&Normal>,
    req: &SolveRequest,
    ctx: Context<'_>,
) -> Result<Solved, SolveError> {
    req.check()?;
    super::check_measurement(t, i)?;
    let tv = matches!(req.solver, Solver::AdmmTv | Solver::FistaTv);
    let auto = tv && req.lambda.is_none();
    let noise = match noise {
        Some(n) => Some(n),
        None if auto => NoiseLevel::from_residual_with(t, i, normal),
        None => None,
    };
    let mut warnings = Vec::new();
    let mut lambda_choice: Option<LambdaChoice> = None;
    // An automatic λ: the resolved-discrepancy rule on ADMM-TV (FISTA-TV
    // minimizes the same objective, so it takes the λ that rule chose).
    let mut lambda = req.lambda;
    let mut admm_result = None;
    if auto {
        match &noise {
            Some(n) => {
                let settings = req.admm(true, ctx.stop);
                let (r, choice) = match normal {
                    Some(nm) => admm_tv_resolved_prepared(t, i, nm, n, &cond.singular_values, &settings)?,
                    None => admm_tv_resolved(t, i, n, &cond.singular_values, &settings)?,
                };
                lambda = Some(choice.lambda);
                lambda_choice = Some(choice);
                admm_result = Some(r);
            }
            None => warnings.push(format!(
                "λ is the fixed default: the measurement has too few rows beyond T's columns ({} x {}) to estimate its noise, and no noise level was given",
                t.rows(),
                t.cols()
            )),
        }
    }
    let rec = match req.solver {
        Solver::AdmmTv => match admm_result {
            Some(r) => r,
            None => match normal {
                Some(nm) => admm_tv_prepared(t, i, nm, &req.admm(false, ctx.stop))?,
                None => admm_tv(t, i, &req.admm(false, ctx.stop))?,
            },
        },
        Solver::FistaTv => {
            let d = FistaSettings::default();
            fista_tv(
                t,
                i,
                &FistaSettings {
                    lambda,
                    max_iter: req
                        .max_iter
                        .unwrap_or(if auto { AUTO_MAX_ITER } else { d.max_iter }),
                    tol: req.tol.unwrap_or(d.tol),
                    stop: ctx.stop,
                    ..d
                },
            )?
        }
        Solver::Tikhonov => tikhonov(t, i, req.lambda)?,
        Solver::Lsq => least_squares(t, i, req.rcond)?,
    };
    if let Some(n) = &noise {
        warnings.extend(snr_warnings(mean_snr(i, &n.variance)));
        warnings.extend(grid_warning(t, cond, n));
    }
    let model_check = noise
        .as_ref()
        .and_then(|n| model_check(t, i, n, lambda_choice.as_ref(), normal));
    warnings.extend(model_check.and_then(|a| a.warning("this measurement")));
    let image = rec.image.clone();
    let mut report = Report::new(
        ctx.scene,
        t,
        ctx.transport_seconds,
        cond,
        rec,
        ctx.truth,
        lambda_choice,
    );
    report.warnings.splice(0..0, warnings);
    report.model_check = model_check;
    Ok(Solved { image, report })
}

/// The model check of a reconstruction (see [`super::adequacy`]): the best
/// attainable misfit against an independent noise level. With an automatic
/// λ the scan already found that misfit (its floor, box constraint
/// included, with the resolved components as the fitted numbers); otherwise
/// the unconstrained least-squares residual. `None` when the noise was
/// estimated from that same residual, or the measurement has too few rows.
fn model_check(
    t: &Transport,
    i: &[f64],
    noise: &NoiseLevel,
    choice: Option<&LambdaChoice>,
    normal: Option<&Normal>,
) -> Option<Adequacy> {
    if noise.source == NoiseSource::Residual {
        return None;
    }
    if let Some((floor, p)) = choice.and_then(|c| Some((c.floor?, c.resolved?))) {
        return Some(Adequacy::of_misfit(floor, noise.total(), t.rows(), p));
    }
    let r = least_squares_residual_with(t, i, normal)?;
    Some(Adequacy::of(&r, Some(&noise.variance), t.cols()))
}

/// The warning when the scene grid is finer than the noise supports: the
/// least-squares RMS error `sigma sqrt(mean 1/s_i^2)` over the `PLAN_TOLERANCE`
/// (the `polnlos plan` rule).
fn grid_warning(t: &Transport, cond: &Conditioning, noise: &NoiseLevel) -> Option<String> {
    let amp = cond.noise_amplification(noise.mean_variance().sqrt());
    (amp > PLAN_TOLERANCE).then(|| {
        format!(
            "the {}x{} scene grid is finer than this measurement supports: its noise alone gives a least-squares RMS error of {amp:.2e} of the radiance range (> {PLAN_TOLERANCE}); `polnlos plan` suggests a coarser grid, or take more frames",
            t.scene_grid().nu, t.scene_grid().nv
        )
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn requests_are_checked_before_solving() {
        SolveRequest::default().check().unwrap();
        for bad in [
            SolveRequest {
                lambda: Some(-1.0),
                ..Default::default()
            },
            SolveRequest {
                rho: Some(0.0),
                ..Default::default()
            },
            SolveRequest {
                max_iter: Some(0),
                ..Default::default()
            },
            SolveRequest {
                tol: Some(1.0),
                ..Default::default()
            },
            SolveRequest {
                rcond: Some(f64::NAN),
                ..Default::default()
            },
        ] {
            assert!(bad.check().is_err(), "{bad:?}");
        }
    }

    #[test]
    fn solver_names_are_the_json_names() {
        for s in [
            Solver::AdmmTv,
            Solver::FistaTv,
            Solver::Tikhonov,
            Solver::Lsq,
        ] {
            assert_eq!(serde_json::to_value(s).unwrap(), s.name());
            assert_eq!(
                serde_json::from_value::<Solver>(serde_json::json!(s.name())).unwrap(),
                s
            );
        }
    }
}
