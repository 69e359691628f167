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

use super::{Method, Needs, Problem, Warm, WarmState};
use crate::scene::Grid;
use crate::solve::gram::Normal;
use crate::solve::lowrank::Workspace;
use crate::solve::tv::{add_divergence_adjoint, add_laplacian_lower, gradient, total_variation};
use crate::solve::{
    check_lambda, check_measurement, check_tol, Reconstruction, SolveError, SolveStats,
};
use crate::stop::Stop;
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

impl<'a> AdmmSettings<'a> {
    /// The [`Problem`] of these settings on `i` of `t` for ADMM-TV, with
    /// its Gram: what [`AdmmTv`] reads back into the same settings.
    pub(crate) fn problem(self, t: &'a Transport, i: &'a [f64], normal: &'a Normal) -> Problem<'a> {
        Problem {
            t,
            i,
            normal: Some(normal),
            req: super::SolveRequest {
                solver: super::Solver::ADMM_TV,
                lambda: self.lambda,
                rho: self.rho,
                max_iter: Some(self.max_iter),
                tol: Some(self.tol),
                rcond: None,
            },
            auto: false,
            upper: self.upper,
            stop: self.stop,
        }
    }
}

/// Default relative TV weight, `lambda = LAMBDA_REL * mean(diag(T^T T))`: the
/// best of 1e-3..1 on the 16x16 Brewster bench at 2e4 photons (see tests/daemon/roundtrip.rs).
pub const LAMBDA_REL: f64 = 1e-2;

/// Smallest default starting penalty, relative to `mean(diag(T^T T))`: below
/// it `T^T T + rho (D^T D + I)` inherits `kappa(T)^2` and ADMM stalls.
pub(crate) const RHO_FLOOR_REL: f64 = 1e-3;
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
/// rayon's hand-off costs more than it saves: the two solves of one ADMM
/// step took 0.25 / 0.43 ms alone / on two threads at 1044 unknowns, 1.5 /
/// 1.8 ms at 2048, 10.3 / 8.7 ms at 4096, on the 2-core machine).
const PAR_SOLVE_MIN: usize = 4096;

/// `x <- (T^T T + rho (D^T D + I))^-1 x` with `factor` (made for this `rho`).
fn solve_system(normal: &Normal, factor: &Factor, rho: f64, x: &mut [f64], ws: &mut Workspace) {
    match (factor, normal.low_rank()) {
        (Factor::LowRank(f), Some(lr)) => lr.solve(f, rho, x, ws),
        (Factor::Dense(f), _) => {
            let n = x.len();
            if n < PAR_SOLVE_MIN && crate::solve::triangular::solve_llt_in_place(f.L(), x).is_some()
            {
                return;
            }
            let par = if n >= PAR_SOLVE_MIN {
                crate::solve::par()
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
pub(super) struct AdmmState {
    factor: Option<(f64, Factor)>,
    l: Vec<f64>,
    z1: Vec<f64>,
    z2: Vec<f64>,
    u1: Vec<f64>,
    u2: Vec<f64>,
}

impl WarmState for AdmmState {
    fn iterate(&self) -> Box<dyn WarmState> {
        Box::new(AdmmState {
            factor: None,
            l: self.l.clone(),
            z1: self.z1.clone(),
            z2: self.z2.clone(),
            u1: self.u1.clone(),
            u2: self.u2.clone(),
        })
    }

    fn clone_box(&self) -> Box<dyn WarmState> {
        Box::new(self.clone())
    }

    /// The scaled TV dual (bounded by `lambda / 2 rho` and at that bound on
    /// every edge where the image changes) is scaled with the weight.
    fn start_from(&mut self, from: &dyn WarmState, tv_ratio: f64) {
        let Some(from) = from.as_any().downcast_ref::<AdmmState>() else {
            return;
        };
        self.l.clone_from(&from.l);
        self.z1.clone_from(&from.z1);
        self.z2.clone_from(&from.z2);
        self.u2.clone_from(&from.u2);
        self.u1.clone_from(&from.u1);
        self.u1.iter_mut().for_each(|u| *u *= tv_ratio);
    }

    fn as_any(&self) -> &dyn std::any::Any {
        self
    }

    fn as_any_mut(&mut self) -> &mut dyn std::any::Any {
        self
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
fn admm_tv_warm(
    t: &Transport,
    i: &[f64],
    normal: &Normal,
    settings: &AdmmSettings,
    state: &mut AdmmState,
) -> Result<Reconstruction, SolveError> {
    let mut solved = admm_tv_joint(t, &[(i, normal)], settings, state)?;
    Ok(solved.remove(0))
}

/// ADMM-TV of a colour camera's colours of one scene solved together: each
/// colour's MODEL.md Eq. 12 data term, with the colour TV (an element's
/// gradients in every colour shrink as one group, Blomgren and Chan 1998).
/// Each colour is `(i, normal)`, its `T^T i` in `normal`, every `normal`
/// on the same Gram (`T` is the colours' one transport matrix).
///
/// Why: solved alone, a colour with few photons (a Bayer sensor's red and
/// blue) puts its noise into edges the others do not have, and a white
/// scene comes back tinted; together, an edge costs less where the colours
/// share it, so each colour's level is set by its data and its edges by all.
#[cfg(any(test, feature = "daemon"))]
fn admm_tv_colours(
    t: &Transport,
    colours: &[(&[f64], &Normal)],
    settings: &AdmmSettings,
    state: &mut AdmmState,
) -> Result<Vec<Reconstruction>, SolveError> {
    for (c, (i, normal)) in colours.iter().enumerate() {
        check_measurement(t, i)?;
        if normal.ti.len() != t.cols() {
            return Err(SolveError::OtherGram { colour: c });
        }
    }
    if let Some(colour) = crate::solve::gram::off_gram(colours.iter().map(|c| c.1)) {
        return Err(SolveError::OtherGram { colour });
    }
    admm_tv_joint(t, colours, settings, state)
}

/// The solve of [`admm_tv_colours`] (one colour: [`admm_tv_warm`]) from `state`.
fn admm_tv_joint(
    t: &Transport,
    colours: &[(&[f64], &Normal)],
    settings: &AdmmSettings,
    state: &mut AdmmState,
) -> Result<Vec<Reconstruction>, SolveError> {
    check_tol(settings.tol)?;
    let Some(&(_, normal)) = colours.first() else {
        return Ok(Vec::new());
    };
    let start = Instant::now();
    let grid = t.scene_grid();
    let n = t.cols();
    let gram_seconds = normal.seconds;
    let Setup {
        lambda,
        rho,
        adaptive,
        mut warnings,
    } = setup(normal, settings)?;

    // System matrix T^T T + rho (D^T D + I), lower triangle, factorized
    // once (again only when residual balancing changes rho); a warm start
    // keeps the previous solve's factor and penalty.
    let t0 = Instant::now();
    let m = colours.len() * n;
    let (rho, llt) = state.take_factor(normal, grid, m, settings.rho, rho)?;
    let mut penalty = Penalty {
        lambda,
        adaptive,
        rho,
        llt,
        kappa_tv: 0.5 * lambda / rho,
        refactorizations: 0,
        factor_seconds: t0.elapsed().as_secs_f64(),
    };

    // Iterate without allocating: every buffer is sized once here.
    let t1 = Instant::now();
    let mut it = Iterate::take(state, grid, n, colours.len());
    let tis: Vec<&[f64]> = colours.iter().map(|(_, nm)| nm.ti.as_slice()).collect();
    let outcome = run_iterations(normal, &tis, settings, &mut penalty, &mut it)?;
    let iterate_seconds = t1.elapsed().as_secs_f64();
    warnings.extend(outcome.cap_warning(settings.tol));

    // The returned images are z2: feasible by construction.
    let Penalty {
        rho,
        llt,
        factor_seconds,
        ..
    } = penalty;
    let images = it.store(state, rho, llt);
    let total_seconds = gram_seconds + start.elapsed().as_secs_f64();
    Ok(colours
        .iter()
        .zip((0..colours.len()).map(|c| &images[c * n..(c + 1) * n]))
        .map(|(&(i, nm), image)| {
            let mut warnings = warnings.clone();
            warnings.extend(flat_warning(image, lambda));
            let (misfit, objective) = objective_with(t, i, nm, image, lambda);
            Reconstruction {
                image: image.to_vec(),
                stats: SolveStats {
                    solver: "admm-tv".into(),
                    lambda: Some(lambda),
                    rho: Some(rho),
                    iterations: outcome.iterations,
                    converged: outcome.converged,
                    primal_residual: Some(outcome.r_norm),
                    dual_residual: Some(outcome.s_norm),
                    objective,
                    data_misfit: misfit,
                    rank: None,
                    clipped_fraction: None,
                    gram_seconds,
                    factor_seconds,
                    iterate_seconds,
                    total_seconds,
                    warnings,
                },
            }
        })
        .collect())
}

/// The checked parameters of one solve and the warnings they raise.
/// Why: defaults and validation read apart from the iterations they set up.
struct Setup {
    /// TV weight of MODEL.md Eq. 12.
    lambda: f64,
    /// Starting penalty (a warm start may keep its previous one).
    rho: f64,
    /// Whether residual balancing may change `rho` (none was given).
    adaptive: bool,
    /// Warnings so far.
    warnings: Vec<String>,
}

/// Picks `lambda` and `rho` (defaults scaled to `T`) and checks them and `upper`.
/// Why: a bad parameter is named before any factorization is paid for.
fn setup(normal: &Normal, settings: &AdmmSettings) -> Result<Setup, SolveError> {
    let scale = normal.scale();
    let mut warnings = Vec::new();
    if scale == 0.0 {
        warnings.push("T is all zero: no scene element lights the wall as the cameras see it; the result is the zero image".into());
    }
    let unit = normal.unit();
    let lambda = settings.lambda.unwrap_or(LAMBDA_REL * unit);
    let adaptive = settings.rho.is_none();
    let rho = settings.rho.unwrap_or(if lambda > 0.0 {
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
    Ok(Setup {
        lambda,
        rho,
        adaptive,
        warnings,
    })
}

impl AdmmState {
    /// Takes this state's factor and penalty when they fit `normal`, `n`
    /// unknowns and the fixed penalty if one is given, else factorizes at `rho`.
    /// Why: a warm start then pays no Cholesky; a new `T` or penalty must.
    fn take_factor(
        &mut self,
        normal: &Normal,
        grid: Grid,
        n: usize,
        fixed: Option<f64>,
        rho: f64,
    ) -> Result<(f64, Factor), SolveError> {
        let same_shape = self.l.len() == n;
        match self.factor.take() {
            Some((r, f)) if same_shape && fits(normal, &f) && fixed.is_none_or(|x| x == r) => {
                Ok((r, f))
            }
            _ => Ok((rho, factorize(normal, grid, rho)?)),
        }
    }
}

/// The penalty `rho` with its factor and the TV threshold `lambda / 2 rho`.
/// Why: residual balancing changes the three together and counts its cost.
struct Penalty {
    /// TV weight of MODEL.md Eq. 12.
    lambda: f64,
    /// Whether residual balancing may change `rho`.
    adaptive: bool,
    /// Current penalty.
    rho: f64,
    /// Factor of `T^T T + rho (D^T D + I)` for this `rho`.
    llt: Factor,
    /// Group soft-threshold of the TV splitting, `lambda / 2 rho`.
    kappa_tv: f64,
    /// Factorizations residual balancing made so far.
    refactorizations: usize,
    /// Seconds spent factorizing.
    factor_seconds: f64,
}

impl Penalty {
    /// Whether residual balancing looks at the residuals after `iterations`.
    /// Why: every `BALANCE_EVERY` iterations, `MAX_REFACTOR` times at most (each costs a Cholesky).
    fn due(&self, iterations: usize) -> bool {
        self.adaptive
            && iterations.is_multiple_of(BALANCE_EVERY)
            && self.refactorizations < MAX_REFACTOR
    }

    /// Residual balancing (Boyd et al. 2011, §3.4.1) on the primal and dual
    /// residuals `rp`, `rd` relative to their tolerances.
    /// Why: a fixed rho far from balance converges slowly; the scaled duals
    /// follow rho, and a failed factorization keeps the old one.
    fn balance(&mut self, normal: &Normal, it: &mut Iterate, rp: f64, rd: f64) {
        let factor = if rp > BALANCE_MU * rd {
            BALANCE_TAU
        } else if rd > BALANCE_MU * rp {
            1.0 / BALANCE_TAU
        } else {
            1.0
        };
        if factor != 1.0 {
            let t2 = Instant::now();
            if let Ok(f) = factorize(normal, it.grid, self.rho * factor) {
                self.llt = f;
                self.rho *= factor;
                self.kappa_tv = 0.5 * self.lambda / self.rho;
                it.u1
                    .iter_mut()
                    .chain(it.u2.iter_mut())
                    .for_each(|u| *u /= factor);
                self.refactorizations += 1;
            }
            self.factor_seconds += t2.elapsed().as_secs_f64();
        }
    }
}

/// The iterate (image `l`, splitting variables `z1 = D l` and `z2 = l`,
/// scaled duals `u1`, `u2`) and the scratch buffers of one solve, for
/// `channels` images solved together (one per colour, each `n` unknowns
/// in a block of its own; `D l`, `z1`, `u1` and `w1` are `2 n` a colour).
/// Why: sized once per solve, so that the iterations run without allocating.
struct Iterate {
    /// The scene grid `D` differentiates on.
    grid: Grid,
    /// Images solved together: 1, or a colour camera's 3 (joint TV).
    channels: usize,
    l: Vec<f64>,
    /// `D l`.
    dl: Vec<f64>,
    z1: Vec<f64>,
    z2: Vec<f64>,
    u1: Vec<f64>,
    u2: Vec<f64>,
    /// Scratch: `z1 - u1`, then the change of `z1`.
    w1: Vec<f64>,
    /// Scratch: one colour's l-update right-hand side.
    rhs: Vec<f64>,
    /// Scratch: the dual residual, then `D^T u1`.
    dual: Vec<f64>,
    ws: Workspace,
}

impl Iterate {
    /// `state`'s iterate when it has `channels` images of `n` unknowns (a
    /// warm start), else zeros.
    /// Why: a solve of a close measurement then starts near its answer.
    fn take(state: &mut AdmmState, grid: Grid, n: usize, channels: usize) -> Self {
        let m = channels * n;
        Self {
            grid,
            channels,
            l: warm(&mut state.l, m),
            dl: vec![0.0; 2 * m],
            z1: warm(&mut state.z1, 2 * m),
            z2: warm(&mut state.z2, m),
            u1: warm(&mut state.u1, 2 * m),
            u2: warm(&mut state.u2, m),
            w1: vec![0.0; 2 * m],
            rhs: vec![0.0; n],
            dual: vec![0.0; m],
            ws: Workspace::default(),
        }
    }

    /// l-update of each colour `c`: `(T^T T + rho (D^T D + I)) l_c = T^T i_c
    /// + rho (D^T (z1_c - u1_c) + z2_c - u2_c)`, `tis[c]` its `T^T i_c`.
    /// Why: MODEL.md Eq. 12's data term plus both splittings' penalties, through `llt` (for `rho`);
    /// the colours share `T`, so one factor serves them all.
    fn update_l(&mut self, tis: &[&[f64]], normal: &Normal, llt: &Factor, rho: f64) {
        let Self {
            grid,
            l,
            z1,
            z2,
            u1,
            u2,
            w1,
            rhs,
            ws,
            ..
        } = self;
        let n = rhs.len();
        for (c, ti) in tis.iter().enumerate() {
            let (g, b) = (2 * c * n..2 * (c + 1) * n, c * n..(c + 1) * n);
            for k in g.clone() {
                w1[k] = z1[k] - u1[k];
            }
            rhs.fill(0.0);
            add_divergence_adjoint(*grid, &w1[g], rhs);
            let (z2, u2) = (&z2[b.clone()], &u2[b.clone()]);
            for k in 0..n {
                rhs[k] = ti[k] + rho * (rhs[k] + z2[k] - u2[k]);
            }
            solve_system(normal, llt, rho, rhs, ws);
            l[b].copy_from_slice(rhs);
        }
    }

    /// z-updates: `z1` the group soft-threshold of `D l + u1` at `kappa_tv`
    /// (MODEL.md Eq. 12's isotropic TV; with several colours, the group is
    /// an element's gradients in every colour: the colour TV of Blomgren and
    /// Chan 1998), `z2` the projection of `l + u2` onto the box `[0, upper]`;
    /// returns `(||z||^2, ||A l||^2)`, `A l = (D l, l)`.
    /// Why: keeps the change of z in `dual` (as `D^T dz1 + dz2`) for the dual residual.
    fn update_z(&mut self, kappa_tv: f64, upper: f64) -> (f64, f64) {
        let Self {
            grid,
            channels,
            l,
            dl,
            z1,
            z2,
            u1,
            u2,
            w1,
            dual,
            ..
        } = self;
        let (m, cs) = (l.len(), *channels);
        let n = m / cs;
        for c in 0..cs {
            gradient(
                *grid,
                &l[c * n..(c + 1) * n],
                &mut dl[2 * c * n..2 * (c + 1) * n],
            );
        }
        let mut z_norm2 = 0.0;
        let mut ax_norm2 = 0.0;
        for j in 0..n {
            // Element j's gradient in colour c is at (2 c n + j, 2 c n + n + j).
            let at = |c: usize| (2 * c * n + j, 2 * c * n + n + j);
            let v = |c: usize| {
                let (x, y) = at(c);
                (dl[x] + u1[x], dl[y] + u1[y])
            };
            let mag = match cs {
                1 => {
                    let (vx, vy) = v(0);
                    vx.hypot(vy)
                }
                _ => (0..cs)
                    .map(|c| {
                        let (vx, vy) = v(c);
                        vx * vx + vy * vy
                    })
                    .sum::<f64>()
                    .sqrt(),
            };
            let shrink = if mag > kappa_tv {
                1.0 - kappa_tv / mag
            } else {
                0.0
            };
            for c in 0..cs {
                let ((x, y), (vx, vy)) = (at(c), v(c));
                let (nx, ny) = (vx * shrink, vy * shrink);
                w1[x] = nx - z1[x];
                w1[y] = ny - z1[y];
                z1[x] = nx;
                z1[y] = ny;
                z_norm2 += nx * nx + ny * ny;
                ax_norm2 += dl[x] * dl[x] + dl[y] * dl[y];
            }
        }
        dual.iter_mut().for_each(|d| *d = 0.0);
        for c in 0..cs {
            add_divergence_adjoint(
                *grid,
                &w1[2 * c * n..2 * (c + 1) * n],
                &mut dual[c * n..(c + 1) * n],
            );
        }
        for k in 0..m {
            let nz = (l[k] + u2[k]).clamp(0.0, upper);
            dual[k] += nz - z2[k];
            z2[k] = nz;
            z_norm2 += nz * nz;
            ax_norm2 += l[k] * l[k];
        }
        (z_norm2, ax_norm2)
    }

    /// Dual ascent `u += A l - z`; returns the primal residual `||A l - z||`,
    /// the dual residual `rho ||D^T dz1 + dz2||` and `||A^T u||`.
    /// Why: the three norms the stopping test (Boyd §3.3.1) compares.
    fn update_duals(&mut self, rho: f64) -> (f64, f64, f64) {
        let Self {
            grid,
            channels,
            l,
            dl,
            z1,
            z2,
            u1,
            u2,
            dual,
            ..
        } = self;
        let (m, cs) = (l.len(), *channels);
        let n = m / cs;
        let mut r2 = 0.0;
        for k in 0..2 * m {
            let r = dl[k] - z1[k];
            u1[k] += r;
            r2 += r * r;
        }
        for k in 0..m {
            let r = l[k] - z2[k];
            u2[k] += r;
            r2 += r * r;
        }
        let r_norm = r2.sqrt();
        let s_norm = rho * dual.iter().map(|d| d * d).sum::<f64>().sqrt();
        // ||A^T u|| for the dual tolerance, reusing `dual` as scratch.
        dual.iter_mut().for_each(|d| *d = 0.0);
        for c in 0..cs {
            add_divergence_adjoint(
                *grid,
                &u1[2 * c * n..2 * (c + 1) * n],
                &mut dual[c * n..(c + 1) * n],
            );
        }
        let atu = dual
            .iter()
            .zip(u2.iter())
            .map(|(a, b)| (a + b) * (a + b))
            .sum::<f64>()
            .sqrt();
        (r_norm, s_norm, atu)
    }

    /// Leaves the iterate and the factor `llt` of `rho` in `state`; returns the images `z2`.
    /// Why: z2 is feasible by construction; the next warm solve starts from the rest.
    fn store(self, state: &mut AdmmState, rho: f64, llt: Factor) -> Vec<f64> {
        let image = self.z2.clone();
        *state = AdmmState {
            factor: Some((rho, llt)),
            l: self.l,
            z1: self.z1,
            z2: self.z2,
            u1: self.u1,
            u2: self.u2,
        };
        image
    }
}

/// Absolute and relative tolerances of the stopping test (Boyd et al. 2011, §3.3.1).
/// Why: fixed per solve, they turn each iteration's norms into two bounds.
struct Tolerance {
    eps_abs: f64,
    eps_rel: f64,
    /// `sqrt` of the number of constraints, `3 n`.
    sqrt_p: f64,
    /// `sqrt` of the number of unknowns, `n`.
    sqrt_n: f64,
}

impl Tolerance {
    /// Tolerances for relative tolerance `tol` (the absolute one is `tol * 1e-2`) and `n` unknowns.
    /// Why: [`AdmmSettings::tol`] is the one number a caller gives.
    fn new(tol: f64, n: usize) -> Self {
        Self {
            eps_rel: tol,
            eps_abs: tol * 1e-2,
            sqrt_p: ((3 * n) as f64).sqrt(),
            sqrt_n: (n as f64).sqrt(),
        }
    }

    /// `(eps_pri, eps_dual)` from `||A l||^2`, `||z||^2` and `||A^T u||` at penalty `rho`.
    /// Why: the primal and dual residuals are each compared with their own bound.
    fn bounds(&self, rho: f64, ax_norm2: f64, z_norm2: f64, atu: f64) -> (f64, f64) {
        let eps_pri =
            self.sqrt_p * self.eps_abs + self.eps_rel * ax_norm2.sqrt().max(z_norm2.sqrt());
        // Both terms in l units times rho: the dual residual scales with rho.
        let eps_dual = rho * (self.sqrt_n * self.eps_abs + self.eps_rel * atu);
        (eps_pri, eps_dual)
    }
}

/// How the iterations ended.
/// Why: the result's statistics and the iteration-cap warning report it.
struct Outcome {
    iterations: usize,
    converged: bool,
    /// Last primal residual.
    r_norm: f64,
    /// Last dual residual.
    s_norm: f64,
}

impl Outcome {
    /// The warning of a solve that stopped at the iteration cap, if this one did.
    /// Why: it names the residuals and the settings that would let it converge.
    fn cap_warning(&self, tol: f64) -> Option<String> {
        let Outcome {
            iterations,
            converged,
            r_norm,
            s_norm,
        } = *self;
        if converged {
            return None;
        }
        Some(format!(
            "ADMM stopped at the iteration cap ({iterations}) before meeting tol = {}: primal residual {r_norm:.3e}, dual residual {s_norm:.3e}; raise max_iter or tol (\"max_iter\" / \"tol\" in a request, --max-iter / --tol on the command line)",
            tol
        ))
    }
}

/// Iterates from `it` until the residuals meet their tolerances or
/// `settings.max_iter` is reached, checking `settings.stop` first each time.
/// Why: one iteration is the updates, the stopping test, then residual balancing.
fn run_iterations(
    normal: &Normal,
    tis: &[&[f64]],
    settings: &AdmmSettings,
    penalty: &mut Penalty,
    it: &mut Iterate,
) -> Result<Outcome, SolveError> {
    let tolerance = Tolerance::new(settings.tol, it.l.len());
    let mut outcome = Outcome {
        iterations: 0,
        converged: false,
        r_norm: f64::INFINITY,
        s_norm: f64::INFINITY,
    };
    for _ in 0..settings.max_iter {
        crate::solve::check_stop(settings.stop, outcome.iterations)?;
        outcome.iterations += 1;
        it.update_l(tis, normal, &penalty.llt, penalty.rho);
        let (z_norm2, ax_norm2) = it.update_z(penalty.kappa_tv, settings.upper);
        let (r_norm, s_norm, atu) = it.update_duals(penalty.rho);
        outcome.r_norm = r_norm;
        outcome.s_norm = s_norm;
        let (eps_pri, eps_dual) = tolerance.bounds(penalty.rho, ax_norm2, z_norm2, atu);
        if r_norm <= eps_pri && s_norm <= eps_dual {
            outcome.converged = true;
            break;
        }
        // Residual balancing, on residuals relative to their tolerances.
        if penalty.due(outcome.iterations) {
            penalty.balance(normal, it, r_norm / eps_pri, s_norm / eps_dual);
        }
    }
    Ok(outcome)
}

/// The warning of a flat recovered image (values within 1e-3 over more than one element).
/// Why: a far too large lambda and a measurement without signal both look like this.
fn flat_warning(image: &[f64], lambda: f64) -> Option<String> {
    let (lo, hi) = image
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &v| {
            (a.min(v), b.max(v))
        });
    if image.len() > 1 && hi - lo < 1e-3 {
        return Some(format!(
            "the recovered image is flat (values {lo:.4} to {hi:.4}): lambda = {lambda:.3e} may be far too large, or the measurement carries no signal"
        ));
    }
    None
}

/// [`objective_of`] from the normal equations where that is exact enough:
/// `||i - T l||^2 = l^T G l - 2 l^T T^T i + i^T i` reads the `N x N` Gram
/// instead of the `M x N` `T` (a chair photo's differenced `T` is 265 MB,
/// its Gram 8.7 MB; each solve of a λ search ends here). Where the misfit
/// is below `1e-6` of `i^T i`, the cancellation would cost more than 1e-10
/// of it: `T l` is formed instead.
fn objective_with(t: &Transport, i: &[f64], normal: &Normal, l: &[f64], lambda: f64) -> (f64, f64) {
    let g = normal.lower();
    let n = l.len();
    if g.nrows() != n || normal.ti.len() != n {
        return objective_of(t, i, l, lambda);
    }
    // l^T G l from the lower triangle: the diagonal once, below it twice.
    let mut quad = 0.0;
    for c in 0..n {
        let col = g.col(c);
        let lc = l[c];
        let below: f64 = (c + 1..n).map(|r| col[r] * l[r]).sum();
        quad += lc * (col[c] * lc + 2.0 * below);
    }
    let cross: f64 = l.iter().zip(&normal.ti).map(|(a, b)| a * b).sum();
    let energy: f64 = i.iter().map(|v| v * v).sum();
    let misfit = quad - 2.0 * cross + energy;
    if misfit.is_nan() || misfit < 1e-6 * energy {
        return objective_of(t, i, l, lambda);
    }
    (misfit, misfit + lambda * total_variation(t.scene_grid(), l))
}

/// `(||i - T l||^2, ||i - T l||^2 + lambda TV(l))`, MODEL.md Eq. 12's objective.
pub(crate) fn objective_of(t: &Transport, i: &[f64], l: &[f64], lambda: f64) -> (f64, f64) {
    let pred = t.apply(l);
    let misfit: f64 = pred.iter().zip(i).map(|(p, m)| (m - p) * (m - p)).sum();
    (misfit, misfit + lambda * total_variation(t.scene_grid(), l))
}

/// ADMM-TV as a registered solver.
pub(super) struct AdmmTv;

impl Method for AdmmTv {
    fn name(&self) -> &'static str {
        "admm-tv"
    }

    fn about(&self) -> &'static str {
        "ADMM with isotropic TV and the box 0 <= l <= 1 (MODEL.md Eq. 12); keeps its Cholesky factor and iterate between solves"
    }

    fn needs(&self) -> Needs {
        Needs {
            gram: true,
            lambda_from_noise: true,
            warm_start: true,
        }
    }

    fn solve(
        &self,
        p: &Problem<'_>,
        warm: Option<&mut Warm>,
    ) -> Result<Reconstruction, SolveError> {
        let settings = settings_of(p);
        let formed;
        let normal = match p.normal {
            Some(nm) => nm,
            None => {
                check_measurement(p.t, p.i)?;
                formed = Normal::of(p.t, p.i);
                &formed
            }
        };
        match warm {
            Some(w) => admm_tv_warm(p.t, p.i, normal, &settings, w.state::<AdmmState>()),
            None => admm_tv_prepared(p.t, p.i, normal, &settings),
        }
    }

    #[cfg(feature = "daemon")]
    fn solve_colours(
        &self,
        p: &Problem<'_>,
        colours: &[(&[f64], &Normal)],
        warm: Option<&mut Warm>,
    ) -> Option<Result<Vec<Reconstruction>, SolveError>> {
        let mut cold = AdmmState::default();
        let state = match warm {
            Some(w) => w.state::<AdmmState>(),
            None => &mut cold,
        };
        Some(admm_tv_colours(p.t, colours, &settings_of(p), state))
    }
}

/// The settings of ADMM-TV that problem `p` asks for.
fn settings_of<'a>(p: &Problem<'a>) -> AdmmSettings<'a> {
    let d = AdmmSettings::default();
    AdmmSettings {
        lambda: p.req.lambda,
        rho: p.req.rho,
        max_iter: p.max_iter(d.max_iter),
        upper: p.upper,
        tol: p.req.tol.unwrap_or(d.tol),
        stop: p.stop,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scene::Grid;

    /// A dense `rows x 16` `T` of smooth positive entries.
    fn smooth(rows: usize) -> Transport {
        let (grid, n) = (Grid { nu: 4, nv: 4 }, 16);
        let data = (0..rows * n)
            .map(|k| 1.0 + ((k % rows) as f64 * 0.37 + (k / rows) as f64 * 1.3).sin())
            .collect();
        let block = crate::transport::Block {
            pose: "A".into(),
            channel: crate::scene::Channel::None,
        };
        Transport::from_col_major(rows, n, data, vec![block], Grid { nu: rows, nv: 1 }, grid)
    }

    #[test]
    fn three_equal_colours_together_solve_as_one_at_lambda_over_root_three() {
        // Three equal colours: sum_c ||i - T l||^2 + lambda sum_j ||(D l)_j||
        // sqrt(3) = 3 (||i - T l||^2 + lambda / sqrt(3) TV(l)).
        let t = smooth(40);
        let truth: Vec<f64> = (0..16).map(|k| if k % 4 < 2 { 0.8 } else { 0.2 }).collect();
        let i: Vec<f64> = t
            .apply(&truth)
            .iter()
            .enumerate()
            .map(|(j, v)| v + 0.05 * (j as f64 * 2.3).sin())
            .collect();
        let normal = Normal::of(&t, &i);
        let tight = |lambda: f64| AdmmSettings {
            lambda: Some(lambda),
            rho: Some(1.0),
            max_iter: 200_000,
            tol: 1e-11,
            ..AdmmSettings::default()
        };
        let lambda = 3.0;
        let together = admm_tv_colours(
            &t,
            &[(&i, &normal), (&i, &normal), (&i, &normal)],
            &tight(lambda),
            &mut AdmmState::default(),
        )
        .unwrap();
        let alone = admm_tv_prepared(&t, &i, &normal, &tight(lambda / 3f64.sqrt())).unwrap();
        let apart = admm_tv_prepared(&t, &i, &normal, &tight(lambda)).unwrap();
        let diff = |a: &[f64], b: &[f64]| {
            a.iter()
                .zip(b)
                .map(|(x, y)| (x - y).abs())
                .fold(0.0, f64::max)
        };
        for r in &together {
            assert!(r.stats.converged);
            assert!(
                diff(&r.image, &alone.image) < 1e-6,
                "{:?} vs {:?}",
                r.image,
                alone.image
            );
        }
        // Not the solve of each colour alone at lambda: the TV is shared.
        assert!(diff(&together[0].image, &apart.image) > 1e-3);
    }

    /// MODEL.md Eq. 12's objective summed over colours, with the colour TV:
    /// `sum_c ||i_c - T l_c||^2 + lambda sum_j sqrt(sum_c |(D l_c)_j|^2)`.
    fn colour_objective(t: &Transport, is: &[Vec<f64>], ls: &[Vec<f64>], lambda: f64) -> f64 {
        let grid = t.scene_grid();
        let n = grid.count();
        let mut g2 = vec![0.0; n];
        let mut misfit = 0.0;
        for (i, l) in is.iter().zip(ls) {
            misfit += objective_of(t, i, l, 0.0).0;
            let mut g = vec![0.0; 2 * n];
            gradient(grid, l, &mut g);
            for j in 0..n {
                g2[j] += g[j] * g[j] + g[n + j] * g[n + j];
            }
        }
        misfit + lambda * g2.iter().map(|v| v.sqrt()).sum::<f64>()
    }

    proptest::proptest! {
        #![proptest_config(proptest::prelude::ProptestConfig::with_cases(24))]
        /// Together, the colours reach an objective with the colour TV no
        /// higher than their solves apart at the same λ, inside the box.
        #[test]
        fn colours_together_minimize_the_colour_objective(
            seed in 0u64..1_000_000,
            lambda in 0.05f64..5.0,
        ) {
            let t = smooth(40);
            let mut state = seed.wrapping_mul(0x9E37_79B9_7F4A_7C15) | 1;
            let mut next = || {
                state ^= state << 13;
                state ^= state >> 7;
                state ^= state << 17;
                (state >> 11) as f64 / (1u64 << 53) as f64
            };
            let is: Vec<Vec<f64>> = (0..3)
                .map(|_| {
                    let x: Vec<f64> = (0..16).map(|_| next()).collect();
                    t.apply(&x).iter().map(|v| v + 0.3 * (next() - 0.5)).collect()
                })
                .collect();
            let gram = std::sync::Arc::new(crate::solve::gram::Gram::of(&t));
            let normals: Vec<Normal> = is
                .iter()
                .map(|i| Normal::with(std::sync::Arc::clone(&gram), &t, i))
                .collect();
            let tight = AdmmSettings {
                lambda: Some(lambda),
                rho: Some(1.0),
                max_iter: 100_000,
                tol: 1e-10,
                ..AdmmSettings::default()
            };
            let inputs: Vec<(&[f64], &Normal)> =
                is.iter().map(|i| &i[..]).zip(&normals).collect();
            let together =
                admm_tv_colours(&t, &inputs, &tight, &mut AdmmState::default()).unwrap();
            let joint: Vec<Vec<f64>> = together.iter().map(|r| r.image.clone()).collect();
            let apart: Vec<Vec<f64>> = is
                .iter()
                .zip(&normals)
                .map(|(i, nm)| admm_tv_prepared(&t, i, nm, &tight).unwrap().image)
                .collect();
            let j = colour_objective(&t, &is, &joint, lambda);
            let a = colour_objective(&t, &is, &apart, lambda);
            proptest::prop_assert!(j <= a * (1.0 + 1e-6) + 1e-9, "together {j}, apart {a}");
            proptest::prop_assert!(joint.iter().flatten().all(|v| (0.0..=1.0).contains(v)));
        }
    }

    #[test]
    fn colours_of_other_grams_are_not_solved_together() {
        let t = smooth(40);
        let i = vec![1.0; 40];
        let (a, b) = (Normal::of(&t, &i), Normal::of(&t, &i));
        let e = admm_tv_colours(
            &t,
            &[(&i, &a), (&i, &b)],
            &AdmmSettings::default(),
            &mut AdmmState::default(),
        )
        .unwrap_err();
        assert!(matches!(e, SolveError::OtherGram { colour: 1 }), "{e}");
        let e = admm_tv_colours(
            &t,
            &[(&i, &a), (&i[..30], &a)],
            &AdmmSettings::default(),
            &mut AdmmState::default(),
        )
        .unwrap_err();
        assert!(matches!(e, SolveError::Length { .. }), "{e}");
        assert!(
            admm_tv_colours(&t, &[], &AdmmSettings::default(), &mut AdmmState::default())
                .unwrap()
                .is_empty()
        );
    }

    #[test]
    fn the_misfit_from_the_gram_is_the_misfit_from_t() {
        let t = smooth(40);
        let l: Vec<f64> = (0..16).map(|k| 0.1 * k as f64).collect();
        // A measurement the image fits badly: the Gram's form.
        let i: Vec<f64> = (0..40).map(|j| 3.0 + (j as f64 * 0.9).cos()).collect();
        let normal = Normal::of(&t, &i);
        let (a, oa) = objective_with(&t, &i, &normal, &l, 0.3);
        let (b, ob) = objective_of(&t, &i, &l, 0.3);
        assert!(a >= 1e-6 * i.iter().map(|v| v * v).sum::<f64>());
        assert!((a - b).abs() <= 1e-12 * b, "{a} {b}");
        assert!((oa - ob).abs() <= 1e-12 * ob, "{oa} {ob}");
        // A measurement the image fits exactly: T l is formed (the Gram's
        // form would be all cancellation), so the misfit is T's own.
        let exact = t.apply(&l);
        let normal = Normal::of(&t, &exact);
        assert_eq!(
            objective_with(&t, &exact, &normal, &l, 0.3),
            objective_of(&t, &exact, &l, 0.3)
        );
    }
}
