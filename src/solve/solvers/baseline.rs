//! Baselines for the reconstruction: the (truncated) pseudo-inverse and
//! Tikhonov regularization, both followed by clipping into [0, 1] so that
//! they are compared with ADMM-TV on the same domain (MODEL.md "Metrics").

use std::time::Instant;

use faer::Side;

use super::admm::objective_of;
use super::{Method, Needs, Problem, Warm};
use crate::solve::gram::{adjoint, gram_lower, mean_diag};
use crate::solve::{check_measurement, par, Reconstruction, SolveError, SolveStats};
use crate::transport::Transport;

/// Default Tikhonov weight relative to `mean(diag(T^T T))`.
pub(crate) const TIKHONOV_REL: f64 = 1e-3;

/// `l = clip(T^+ i)` with singular values below `rcond * sigma_max` dropped;
/// `rcond = None` keeps MODEL.md's numerical-rank threshold
/// `max(M, N) * 2.2e-16`, i.e. the plain pseudo-inverse.
pub fn least_squares(
    t: &Transport,
    i: &[f64],
    rcond: Option<f64>,
) -> Result<Reconstruction, SolveError> {
    check_measurement(t, i)?;
    if let Some(r) = rcond {
        if !(0.0..1.0).contains(&r) {
            return Err(SolveError::Parameter {
                name: "rcond",
                value: r,
                reason: "must be in [0, 1)",
            });
        }
    }
    let start = Instant::now();
    let m = t.as_mat();
    let svd = m
        .thin_svd()
        .map_err(|e| SolveError::Factorization(format!("SVD of T did not converge ({e:?})")))?;
    let factor_seconds = start.elapsed().as_secs_f64();
    let t1 = Instant::now();
    let s = svd.S().column_vector();
    let (u, v) = (svd.U(), svd.V());
    let smax = if s.nrows() > 0 { s[0] } else { 0.0 };
    let cut = smax
        * rcond.unwrap_or(t.rows().max(t.cols()) as f64 * crate::solve::conditioning::RANK_EPS);
    let n = t.cols();
    let mut x = vec![0.0; n];
    let mut rank = 0;
    for r in 0..s.nrows() {
        if s[r] <= cut || s[r] == 0.0 {
            break;
        }
        rank += 1;
        let c: f64 = u.col(r).iter().zip(i).map(|(a, b)| a * b).sum::<f64>() / s[r];
        for (xk, vk) in x.iter_mut().zip(v.col(r).iter()) {
            *xk += c * vk;
        }
    }
    let (image, clipped) = clip(x);
    let mut warnings = Vec::new();
    if rank < n {
        warnings.push(format!("T has numerical rank {rank} < {n} scene elements: the pseudo-inverse is blind to {} directions of the scene", n - rank));
    }
    let (misfit, objective) = objective_of(t, i, &image, 0.0);
    Ok(Reconstruction {
        image,
        stats: SolveStats {
            solver: "lsq".into(),
            rank: Some(rank),
            converged: true,
            objective,
            data_misfit: misfit,
            clipped_fraction: Some(clipped),
            factor_seconds,
            iterate_seconds: t1.elapsed().as_secs_f64(),
            total_seconds: start.elapsed().as_secs_f64(),
            warnings,
            ..SolveStats::default()
        },
    })
}

/// `l = clip((T^T T + lambda I)^{-1} T^T i)`, the minimizer of
/// `||i - T l||^2 + lambda ||l||^2`; default `lambda = 1e-3 mean(diag(T^T T))`.
pub fn tikhonov(
    t: &Transport,
    i: &[f64],
    lambda: Option<f64>,
) -> Result<Reconstruction, SolveError> {
    check_measurement(t, i)?;
    let start = Instant::now();
    let m = t.as_mat();
    let mut g = gram_lower(m, par());
    let ti = adjoint(m, i);
    let gram_seconds = start.elapsed().as_secs_f64();
    let scale = mean_diag(&g);
    let lambda = lambda.unwrap_or(TIKHONOV_REL * if scale > 0.0 { scale } else { 1.0 });
    if !(lambda >= 0.0 && lambda.is_finite()) {
        return Err(SolveError::Parameter {
            name: "lambda",
            value: lambda,
            reason: "must be a finite number >= 0",
        });
    }
    let t0 = Instant::now();
    for k in 0..t.cols() {
        g[(k, k)] += lambda;
    }
    let llt = g.llt(Side::Lower).map_err(|e| {
        SolveError::Factorization(format!(
            "Cholesky of T^T T + lambda I failed ({e:?}): T is rank-deficient and lambda = {lambda} is too small; raise lambda or use the lsq solver (\"lambda\" / \"solver\" in a request, --lambda / --solver on the command line)"
        ))
    })?;
    let factor_seconds = t0.elapsed().as_secs_f64();
    let t1 = Instant::now();
    let rhs = faer::Mat::from_fn(t.cols(), 1, |r, _| ti[r]);
    let sol = faer::linalg::solvers::Solve::solve(&llt, &rhs);
    let x: Vec<f64> = (0..t.cols()).map(|r| sol[(r, 0)]).collect();
    let (image, clipped) = clip(x);
    let (misfit, _) = objective_of(t, i, &image, 0.0);
    let l2: f64 = image.iter().map(|v| v * v).sum();
    Ok(Reconstruction {
        image,
        stats: SolveStats {
            solver: "tikhonov".into(),
            lambda: Some(lambda),
            converged: true,
            objective: misfit + lambda * l2,
            data_misfit: misfit,
            clipped_fraction: Some(clipped),
            gram_seconds,
            factor_seconds,
            iterate_seconds: t1.elapsed().as_secs_f64(),
            total_seconds: start.elapsed().as_secs_f64(),
            ..SolveStats::default()
        },
    })
}

/// Clips into [0, 1]; returns the fraction of values that moved.
fn clip(x: Vec<f64>) -> (Vec<f64>, f64) {
    let n = x.len().max(1);
    let mut moved = 0;
    let out = x
        .into_iter()
        .map(|v| {
            let c = v.clamp(0.0, 1.0);
            if c != v {
                moved += 1;
            }
            c
        })
        .collect();
    (out, moved as f64 / n as f64)
}
/// Tikhonov as a registered solver.
pub(super) struct Tikhonov;

impl Method for Tikhonov {
    fn name(&self) -> &'static str {
        "tikhonov"
    }

    fn about(&self) -> &'static str {
        "Tikhonov (ridge) regularization, clipped to [0, 1]; lambda default 1e-3 mean(diag(T^T T))"
    }

    fn needs(&self) -> Needs {
        Needs {
            gram: false,
            lambda_from_noise: false,
            warm_start: false,
        }
    }

    fn solve(&self, p: &Problem<'_>, _: Option<&mut Warm>) -> Result<Reconstruction, SolveError> {
        tikhonov(p.t, p.i, p.req.lambda)
    }
}

/// The pseudo-inverse as a registered solver.
pub(super) struct Lsq;

impl Method for Lsq {
    fn name(&self) -> &'static str {
        "lsq"
    }

    fn about(&self) -> &'static str {
        "the (truncated) pseudo-inverse, clipped to [0, 1]; rcond sets the cut-off"
    }

    fn needs(&self) -> Needs {
        Needs {
            gram: false,
            lambda_from_noise: false,
            warm_start: false,
        }
    }

    fn solve(&self, p: &Problem<'_>, _: Option<&mut Warm>) -> Result<Reconstruction, SolveError> {
        least_squares(p.t, p.i, p.req.rcond)
    }
}
