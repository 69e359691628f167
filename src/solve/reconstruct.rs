//! The reconstruction use case, once, for every front end: a typed request
//! (solver and its parameters), the noise level when one is known, and the
//! report. `polnlos reconstruct` and the daemon both call [`reconstruct`], so
//! a solver, a warning or the automatic λ exists in both or in neither.
//!
//! λ is chosen from the noise whenever the request leaves it out (the
//! resolved-discrepancy rule of [`super::lambda`]): from the caller's noise
//! level (a camera model, frame-to-frame variance) or, when there is none,
//! from the measurement itself ([`NoiseLevel::from_residual`]).

use super::adequacy::Adequacy;
use super::conditioning::Conditioning;
use super::gram::Normal;
use super::lambda::{
    least_squares_residual_with, resolved, LambdaChoice, NoiseLevel, NoiseSource,
    RESOLVED_TOLERANCE,
};
use super::report::{mean_snr, snr_warnings, Report};
use super::solvers::{Problem, SolveRequest};
use super::SolveError;
use crate::stop::Stop;
use crate::transport::Transport;

/// Largest least-squares RMS error (fraction of the radiance range) before a
/// reconstruction warns that its grid is finer than the data support (as
/// `polnlos grid`).
pub(crate) const RESOLUTION_TOLERANCE: f64 = RESOLVED_TOLERANCE;

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
    let normal = if req.solver.needs().gram {
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
pub(crate) fn reconstruct_prepared(
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
    let auto = req.solver.needs().lambda_from_noise && req.lambda.is_none();
    let noise = match noise {
        Some(n) => Some(n),
        None if auto => NoiseLevel::from_residual_with(t, i, normal),
        None => None,
    };
    let (warnings, mut notes) = (Vec::new(), Vec::new());
    let mut lambda_choice: Option<LambdaChoice> = None;
    let problem = Problem {
        normal,
        auto,
        stop: ctx.stop,
        ..Problem::new(t, i, *req)
    };
    // An automatic λ: the resolved-discrepancy rule, searched by the
    // solver's λ searcher (itself, or ADMM-TV for one that minimizes the
    // same objective without a warm start); its result is the solve when
    // the searcher is the solver asked for.
    let mut searched = None;
    let mut lambda = req.lambda;
    if auto {
        match &noise {
            Some(n) => {
                let searcher = req.solver.lambda_searcher();
                let formed;
                let normal = match normal {
                    Some(nm) => nm,
                    None => {
                        formed = Normal::of(t, i);
                        &formed
                    }
                };
                let p = Problem {
                    normal: Some(normal),
                    req: SolveRequest {
                        solver: searcher,
                        ..*req
                    },
                    ..problem
                };
                let (r, choice) = resolved(p, n, &cond.singular_values, true)?;
                lambda = Some(choice.lambda);
                lambda_choice = Some(choice);
                searched = (searcher == req.solver).then_some(r);
            }
            None => notes.push(format!(
                "λ is the fixed default: the measurement has too few rows beyond T's columns ({} x {}) to estimate its noise, and no noise level was given",
                t.rows(),
                t.cols()
            )),
        }
    }
    let rec = match searched {
        Some(r) => r,
        None => req.solver.run(&Problem {
            req: SolveRequest { lambda, ..*req },
            ..problem
        })?,
    };
    let solved = Solution {
        t,
        i,
        noise: noise.as_ref(),
        cond,
        normal,
    };
    Ok(solved.judge(rec, lambda_choice, (warnings, notes), &ctx))
}

/// One colour of [`reconstruct_colours`]: its measurement, its noise level
/// when known, and its normal equations (every colour's on one Gram).
#[cfg(feature = "daemon")]
pub(crate) struct ColourInput<'a> {
    pub(crate) i: &'a [f64],
    pub(crate) noise: Option<NoiseLevel>,
    pub(crate) normal: &'a Normal,
}

/// A colour camera's colours of one scene solved together at `lambda` with
/// `req`'s solver ([`super::Solver::solve_colours`]: ADMM-TV's colour TV), each with
/// its own report, as [`reconstruct_prepared`] gives one colour's; `None`
/// when the solver solves one image at a time.
///
/// Why: calibrated colours of one `T` share their edges; solved apart, the
/// colours with fewer photons put noise into edges of their own, and a
/// white scene comes back tinted (docs/guide.md, "Colours solved together").
#[cfg(feature = "daemon")]
pub(crate) fn reconstruct_colours(
    t: &Transport,
    colours: &[ColourInput<'_>],
    cond: &Conditioning,
    req: &SolveRequest,
    lambda: f64,
    ctx: Context<'_>,
) -> Result<Option<Vec<Solved>>, SolveError> {
    let req = SolveRequest {
        lambda: Some(lambda),
        ..*req
    };
    req.check()?;
    let Some(first) = colours.first() else {
        return Ok(Some(Vec::new()));
    };
    let problem = Problem {
        stop: ctx.stop,
        ..Problem::new(t, first.i, req)
    };
    let inputs: Vec<(&[f64], &Normal)> = colours.iter().map(|c| (c.i, c.normal)).collect();
    let Some(recs) = req.solver.solve_colours(&problem, &inputs, None) else {
        return Ok(None);
    };
    Ok(Some(
        colours
            .iter()
            .zip(recs?)
            .map(|(c, rec)| {
                let solved = Solution {
                    t,
                    i: c.i,
                    noise: c.noise.as_ref(),
                    cond,
                    normal: Some(c.normal),
                };
                solved.judge(rec, None, (Vec::new(), Vec::new()), &ctx)
            })
            .collect(),
    ))
}

/// What a solve was of: the judgement of its result reads these.
struct Solution<'a> {
    t: &'a Transport,
    i: &'a [f64],
    noise: Option<&'a NoiseLevel>,
    cond: &'a Conditioning,
    normal: Option<&'a Normal>,
}

impl Solution<'_> {
    /// `rec` with its report: the SNR warnings and grid note from the noise,
    /// the model check, the metrics against the truth, and the
    /// `(warnings, notes)` the solve already had.
    /// Why: one colour alone or colours together, a result is judged alike.
    fn judge(
        &self,
        rec: super::Reconstruction,
        lambda_choice: Option<LambdaChoice>,
        (mut warnings, mut notes): (Vec<String>, Vec<String>),
        ctx: &Context<'_>,
    ) -> Solved {
        let Self {
            t,
            i,
            noise,
            cond,
            normal,
        } = *self;
        if let Some(n) = noise {
            warnings.extend(snr_warnings(mean_snr(i, &n.variance)));
            notes.extend(grid_note(t, cond, n));
        }
        let model_check = noise.and_then(|n| model_check(t, i, n, lambda_choice.as_ref(), normal));
        warnings.extend(model_check.and_then(|a| a.warning("this measurement")));
        let image = rec.image.clone();
        let mut report = Report::new(
            ctx.scene.clone(),
            t,
            ctx.transport_seconds,
            cond,
            rec,
            ctx.truth,
            lambda_choice,
        );
        report.warnings.splice(0..0, warnings);
        report.notes.extend(notes);
        report.model_check = model_check;
        Solved { image, report }
    }
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
        // Rows of zero variance (not measured: zeroed with their rows of T)
        // are no measurement: neither in the mean variance nor in the dof.
        let measured = noise.variance.iter().filter(|v| **v > 0.0).count();
        return Some(Adequacy::of_misfit(floor, noise.total(), measured, p));
    }
    let r = least_squares_residual_with(t, i, normal)?;
    Some(Adequacy::of(&r, Some(&noise.variance), t.cols()))
}

/// The note when the scene grid is finer than the noise supports: the
/// least-squares RMS error `sigma sqrt(mean 1/s_i^2)` over the `RESOLUTION_TOLERANCE`
/// (the `polnlos grid` rule).
fn grid_note(t: &Transport, cond: &Conditioning, noise: &NoiseLevel) -> Option<String> {
    let amp = cond.noise_amplification(noise.mean_variance().sqrt());
    (amp > RESOLUTION_TOLERANCE).then(|| {
        format!(
            "the {}x{} scene grid is finer than this measurement supports: its noise alone gives a least-squares RMS error of {amp:.2e} of the radiance range (> {RESOLUTION_TOLERANCE}); `polnlos grid` suggests a coarser grid, or take more frames",
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
}
