//! ADMM for MODEL.md Eq. 12, `min ||i - T l||^2 + lambda TV(l)` s.t. `0 <= l <= 1`.
//!
//! Splitting (Boyd et al. 2011, scaled form): `z1 = D l` carries the isotropic
//! TV (group soft-threshold), `z2 = l` the box (projection). Written as the
//! equivalent `1/2 ||i - T l||^2 + lambda/2 TV(l)`, the l-update solves
//! `(T^T T + rho (D^T D + I)) l = T^T i + rho (D^T (z1 - u1) + z2 - u2)`
//! with one Cholesky factorization for the whole solve. Stopping uses the
//! primal/dual residuals with absolute and relative tolerances (Boyd §3.3.1).

use std::time::Instant;

use faer::linalg::solvers::Llt;
use faer::linalg::triangular_solve::{
    solve_lower_triangular_in_place, solve_upper_triangular_in_place,
};
use faer::{MatMut, Par, Side};

use super::gram::Normal;
use super::lowrank::Workspace;
use super::tv::{add_divergence_adjoint, add_laplacian_lower, gradient, total_variation};
use super::{
    check_lambda, check_measurement, check_tol, Reconstruction, SolveError, SolveStats, Stop,
};
use crate::transport::Transport;

/// Parameters of an ADMM-TV solve; `None` picks a default scaled to `T`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AdmmSettings<'a> {
    /// TV weight in MODEL.md units; default `1e-2 * mean(diag(T^T T))`.
    pub lambda: Option<f64>,
    /// Penalty, fixed when given. Default: start at `max(lambda, 1e-3
    /// mean(diag(T^T T)))` (or `1e-2 mean(diag)` when `lambda = 0`; on the
    /// Brewster bench this converges in a few hundred iterations where `rho =
    /// mean(diag(T^T T))` needs thousands) and balance the primal and dual
    /// residuals (Boyd et al. 2011, §3.4.1), refactorizing when rho changes.
    pub rho: Option<f64>,
    /// Iteration cap.
    pub max_iter: usize,
    /// Upper bound of the box `0 <= l <= upper`: 1 for radiance in MODEL.md
    /// units (Eq. 12); `f64::INFINITY` when the gain is unknown and `l` is
    /// in the measurement's own units (docs/realphoto.md).
    pub upper: f64,
    /// Relative tolerance `eps_rel`; the absolute one is `tol * 1e-2`.
    pub tol: f64,
    /// Ends the solve early with [`SolveError::Stopped`] when raised.
    pub stop: Stop<'a>,
}

impl Default for AdmmSettings<'_> {
    fn default() -> Self {
        Self {
            lambda: None,
            rho: None,
            max_iter: 500,
            upper: 1.0,
            tol: 1e-4,
            stop: Stop::default(),
        }
    }
}

/// Default relative TV weight, `lambda = LAMBDA_REL * mean(diag(T^T T))`: the
/// best of 1e-3..1 on the 16x16 Brewster bench at 2e4 photons (see tests/daemon/roundtrip.rs).
pub const LAMBDA_REL: f64 = 1e-2;

/// Smallest default starting penalty, relative to `mean(diag(T^T T))`: below
/// it `T^T T + rho (D^T D + I)` inherits `kappa(T)^2` and ADMM stalls.
pub const RHO_FLOOR_REL: f64 = 1e-3;
/// Residual balancing: check every this many iterations ...
const BALANCE_EVERY: usize = 10;
/// ... change rho by this factor when one scaled residual exceeds the other
/// by `BALANCE_MU` ...
const BALANCE_TAU: f64 = 2.0;
const BALANCE_MU: f64 = 10.0;
/// ... at most this many times per solve (each costs a Cholesky).
const MAX_REFACTOR: usize = 20;

/// The factor of `T^T T + rho (D^T D + I)`: a dense Cholesky, or through
/// the Gram's low-rank form (the Cholesky of an `r x r` matrix, Woodbury).
#[derive(Clone)]
pub(crate) enum Factor {
    Dense(Llt<f64>),
    LowRank(Llt<f64>),
}

/// Factor of `T^T T + rho (D^T D + I)`.
fn factorize(normal: &Normal, grid: crate::scene::Grid, rho: f64) -> Result<Factor, SolveError> {
    if let Some(lr) = normal.low_rank() {
        return Ok(Factor::LowRank(lr.factor(rho)?));
    }
    let n = normal.lower().nrows();
    let mut a = normal.lower().clone();
    for k in 0..n {
        a[(k, k)] += rho;
    }
    add_laplacian_lower(grid, rho, |r, c, v| a[(r, c)] += v);
    a.llt(Side::Lower).map(Factor::Dense).map_err(|e| SolveError::Factorization(format!("Cholesky of T^T T + rho (D^T D + I) failed ({e:?}); rho = {rho} may be too small against the entries of T")))
}

/// Dense triangular solves go parallel from this many unknowns (below,
/// rayon's hand-off costs more than it saves).
const PAR_SOLVE_MIN: usize = 1024;

/// `x <- (T^T T + rho (D^T D + I))^-1 x` with `factor` (made for this `rho`).
fn solve_system(normal: &Normal, factor: &Factor, rho: f64, x: &mut [f64], ws: &mut Workspace) {
    match (factor, normal.low_rank()) {
        (Factor::LowRank(f), Some(lr)) => lr.solve(f, rho, x, ws),
        (Factor::Dense(f), _) => {
            let n = x.len();
            let par = if n >= PAR_SOLVE_MIN {
                super::par()
            } else {
                Par::Seq
            };
            let mut xm = MatMut::from_column_major_slice_mut(x, n, 1);
            solve_lower_triangular_in_place(f.L(), xm.as_mut(), par);
            solve_upper_triangular_in_place(f.L().transpose(), xm.as_mut(), par);
        }
        (Factor::LowRank(_), None) => {
            unreachable!("a low-rank factor comes from a low-rank Normal")
        }
    }
}

/// Whether `factor` was made from this kind of `normal`.
fn fits(normal: &Normal, factor: &Factor) -> bool {
    matches!(factor, Factor::LowRank(_)) == normal.low_rank().is_some()
}

/// Runs ADMM-TV on a measurement `i` of the scene seen through `t`.
pub fn admm_tv(
    t: &Transport,
    i: &[f64],
    settings: &AdmmSettings,
) -> Result<Reconstruction, SolveError> {
    check_measurement(t, i)?;
    let normal = Normal::of(t, i);
    admm_tv_prepared(t, i, &normal, settings)
}

/// Where an ADMM-TV solve starts and what it leaves for the next: the
/// iterate (image, splitting variables, scaled duals) and the Cholesky
/// factor with its penalty. Solving a sequence of close measurements (the
/// running mean of a capture) from the previous state needs no new
/// factorization and few iterations.
#[derive(Default, Clone)]
pub struct AdmmState {
    factor: Option<(f64, Factor)>,
    l: Vec<f64>,
    z1: Vec<f64>,
    z2: Vec<f64>,
    u1: Vec<f64>,
    u2: Vec<f64>,
}

impl AdmmState {
    /// The image of the last solve (empty before the first).
    pub fn image(&self) -> &[f64] {
        &self.z2
    }

    /// A copy of the iterate without the factor (a point of a λ path).
    pub fn iterate(&self) -> AdmmState {
        AdmmState {
            factor: None,
            l: self.l.clone(),
            z1: self.z1.clone(),
            z2: self.z2.clone(),
            u1: self.u1.clone(),
            u2: self.u2.clone(),
        }
    }

    /// Starts the next solve from `from`'s iterate, keeping this state's
    /// factor, for a TV weight `tv_ratio` times `from`'s: the scaled TV dual
    /// (bounded by `lambda / 2 rho` and at that bound on every edge where the
    /// image changes) is scaled with it.
    pub fn start_from(&mut self, from: &AdmmState, tv_ratio: f64) {
        self.l.clone_from(&from.l);
        self.z1.clone_from(&from.z1);
        self.z2.clone_from(&from.z2);
        self.u2.clone_from(&from.u2);
        self.u1.clone_from(&from.u1);
        self.u1.iter_mut().for_each(|u| *u *= tv_ratio);
    }
}

/// `v` when it has `len` values (a warm start), else zeros.
fn warm(v: &mut Vec<f64>, len: usize) -> Vec<f64> {
    let v = std::mem::take(v);
    if v.len() == len {
        v
    } else {
        vec![0.0; len]
    }
}

/// [`admm_tv`] with `T^T T` and `T^T i` already formed (`i` already checked).
pub fn admm_tv_prepared(
    t: &Transport,
    i: &[f64],
    normal: &Normal,
    settings: &AdmmSettings,
) -> Result<Reconstruction, SolveError> {
    admm_tv_warm(t, i, normal, settings, &mut AdmmState::default())
}

/// [`admm_tv_prepared`] starting from `state` (its iterate, and its factor
/// when it has one for this `T`), and leaving the result's there.
pub fn admm_tv_warm(
    t: &Transport,
    i: &[f64],
    normal: &Normal,
    settings: &AdmmSettings,
    state: &mut AdmmState,
) -> Result<Reconstruction, SolveError> {
    check_tol(settings.tol)?;
    let start = Instant::now();
    let grid = t.scene_grid();
    let n = t.cols();
    let scale = normal.scale();
    let ti = &normal.ti;
    let gram_seconds = normal.seconds;
    let mut warnings = Vec::new();
    if scale == 0.0 {
        warnings.push("T is all zero: no scene element lights the wall as the cameras see it; the result is the zero image".into());
    }
    let unit = normal.unit();
    let lambda = settings.lambda.unwrap_or(LAMBDA_REL * unit);
    let adaptive = settings.rho.is_none();
    let mut rho = settings.rho.unwrap_or(if lambda > 0.0 {
        lambda.max(RHO_FLOOR_REL * unit)
    } else {
        LAMBDA_REL * unit
    });
    check_lambda(lambda)?;
    if settings.upper.is_nan() || settings.upper <= 0.0 {
        return Err(SolveError::Parameter {
            name: "upper",
            value: settings.upper,
            reason: "must be > 0 (infinite: no upper bound)",
        });
    }
    if !(rho > 0.0 && rho.is_finite()) {
        return Err(SolveError::Parameter {
            name: "rho",
            value: rho,
            reason: "must be a finite number > 0",
        });
    }
    if lambda == 0.0 {
        warnings.push(
            "lambda = 0: no regularization, only the box constraint; expect noise amplification"
                .into(),
        );
    }

    // System matrix T^T T + rho (D^T D + I), lower triangle, factorized
    // once (again only when residual balancing changes rho); a warm start
    // keeps the previous solve's factor and penalty.
    let t0 = Instant::now();
    let same_shape = state.l.len() == n;
    let mut llt = match state.factor.take() {
        Some((r, f)) if same_shape && fits(normal, &f) && settings.rho.is_none_or(|x| x == r) => {
            rho = r;
            f
        }
        _ => factorize(normal, grid, rho)?,
    };
    let mut factor_seconds = t0.elapsed().as_secs_f64();
    let mut refactorizations = 0;

    // Iterate without allocating: every buffer is sized once here.
    let t1 = Instant::now();
    let mut kappa_tv = 0.5 * lambda / rho;
    let eps_rel = settings.tol;
    let eps_abs = settings.tol * 1e-2;
    let sqrt_p = ((3 * n) as f64).sqrt();
    let sqrt_n = (n as f64).sqrt();
    let mut l = warm(&mut state.l, n);
    let mut dl = vec![0.0; 2 * n];
    let mut z1 = warm(&mut state.z1, 2 * n);
    let mut z2 = warm(&mut state.z2, n);
    let mut u1 = warm(&mut state.u1, 2 * n);
    let mut u2 = warm(&mut state.u2, n);
    let mut w1 = vec![0.0; 2 * n];
    let mut rhs = vec![0.0; n];
    let mut dual = vec![0.0; n];
    let mut ws = Workspace::default();
    let (mut r_norm, mut s_norm) = (f64::INFINITY, f64::INFINITY);
    let mut iterations = 0;
    let mut converged = false;
    for _ in 0..settings.max_iter {
        settings.stop.check(iterations)?;
        iterations += 1;
        // l-update.
        for k in 0..2 * n {
            w1[k] = z1[k] - u1[k];
        }
        rhs.fill(0.0);
        add_divergence_adjoint(grid, &w1, &mut rhs);
        for k in 0..n {
            rhs[k] = ti[k] + rho * (rhs[k] + z2[k] - u2[k]);
        }
        solve_system(normal, &llt, rho, &mut rhs, &mut ws);
        l.copy_from_slice(&rhs);

        // z-updates, keeping the change of z for the dual residual.
        gradient(grid, &l, &mut dl);
        let mut z_norm2 = 0.0;
        let mut ax_norm2 = 0.0;
        for j in 0..n {
            let (vx, vy) = (dl[j] + u1[j], dl[n + j] + u1[n + j]);
            let mag = vx.hypot(vy);
            let shrink = if mag > kappa_tv {
                1.0 - kappa_tv / mag
            } else {
                0.0
            };
            let (nx, ny) = (vx * shrink, vy * shrink);
            w1[j] = nx - z1[j];
            w1[n + j] = ny - z1[n + j];
            z1[j] = nx;
            z1[n + j] = ny;
            z_norm2 += nx * nx + ny * ny;
            ax_norm2 += dl[j] * dl[j] + dl[n + j] * dl[n + j];
        }
        dual.iter_mut().for_each(|d| *d = 0.0);
        add_divergence_adjoint(grid, &w1, &mut dual);
        for k in 0..n {
            let nz = (l[k] + u2[k]).clamp(0.0, settings.upper);
            dual[k] += nz - z2[k];
            z2[k] = nz;
            z_norm2 += nz * nz;
            ax_norm2 += l[k] * l[k];
        }

        // Dual ascent and residuals.
        let mut r2 = 0.0;
        for k in 0..2 * n {
            let r = dl[k] - z1[k];
            u1[k] += r;
            r2 += r * r;
        }
        for k in 0..n {
            let r = l[k] - z2[k];
            u2[k] += r;
            r2 += r * r;
        }
        r_norm = r2.sqrt();
        s_norm = rho * dual.iter().map(|d| d * d).sum::<f64>().sqrt();
        // ||A^T u|| for the dual tolerance, reusing `dual` as scratch.
        dual.iter_mut().for_each(|d| *d = 0.0);
        add_divergence_adjoint(grid, &u1, &mut dual);
        let atu = dual
            .iter()
            .zip(&u2)
            .map(|(a, b)| (a + b) * (a + b))
            .sum::<f64>()
            .sqrt();
        let eps_pri = sqrt_p * eps_abs + eps_rel * ax_norm2.sqrt().max(z_norm2.sqrt());
        // Both terms in l units times rho: the dual residual scales with rho.
        let eps_dual = rho * (sqrt_n * eps_abs + eps_rel * atu);
        if r_norm <= eps_pri && s_norm <= eps_dual {
            converged = true;
            break;
        }
        // Residual balancing, on residuals relative to their tolerances.
        if adaptive && iterations % BALANCE_EVERY == 0 && refactorizations < MAX_REFACTOR {
            let (rp, rd) = (r_norm / eps_pri, s_norm / eps_dual);
            let factor = if rp > BALANCE_MU * rd {
                BALANCE_TAU
            } else if rd > BALANCE_MU * rp {
                1.0 / BALANCE_TAU
            } else {
                1.0
            };
            if factor != 1.0 {
                let t2 = Instant::now();
                if let Ok(f) = factorize(normal, grid, rho * factor) {
                    llt = f;
                    rho *= factor;
                    kappa_tv = 0.5 * lambda / rho;
                    u1.iter_mut()
                        .chain(u2.iter_mut())
                        .for_each(|u| *u /= factor);
                    refactorizations += 1;
                }
                factor_seconds += t2.elapsed().as_secs_f64();
            }
        }
    }
    let iterate_seconds = t1.elapsed().as_secs_f64();
    if !converged {
        warnings.push(format!(
            "ADMM stopped at the iteration cap ({iterations}) before meeting tol = {}: primal residual {r_norm:.3e}, dual residual {s_norm:.3e}; raise max_iter or tol (\"max_iter\" / \"tol\" in a request, --max-iter / --tol on the command line)",
            settings.tol
        ));
    }

    // The returned image is z2: feasible by construction.
    let image = z2.clone();
    *state = AdmmState {
        factor: Some((rho, llt)),
        l,
        z1,
        z2,
        u1,
        u2,
    };
    let (lo, hi) = image
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &v| {
            (a.min(v), b.max(v))
        });
    if n > 1 && hi - lo < 1e-3 {
        warnings.push(format!(
            "the recovered image is flat (values {lo:.4} to {hi:.4}): lambda = {lambda:.3e} may be far too large, or the measurement carries no signal"
        ));
    }
    let (misfit, objective) = objective_of(t, i, &image, lambda);
    Ok(Reconstruction {
        image,
        stats: SolveStats {
            solver: "admm-tv".into(),
            lambda: Some(lambda),
            rho: Some(rho),
            iterations,
            converged,
            primal_residual: Some(r_norm),
            dual_residual: Some(s_norm),
            objective,
            data_misfit: misfit,
            rank: None,
            clipped_fraction: None,
            gram_seconds,
            factor_seconds,
            iterate_seconds,
            total_seconds: gram_seconds + start.elapsed().as_secs_f64(),
            warnings,
        },
    })
}

/// `(||i - T l||^2, ||i - T l||^2 + lambda TV(l))`, MODEL.md Eq. 12's objective.
pub(crate) fn objective_of(t: &Transport, i: &[f64], l: &[f64], lambda: f64) -> (f64, f64) {
    let pred = t.apply(l);
    let misfit: f64 = pred.iter().zip(i).map(|(p, m)| (m - p) * (m - p)).sum();
    (misfit, misfit + lambda * total_variation(t.scene_grid(), l))
}
