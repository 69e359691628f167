//! Choosing the TV weight from the noise (Morozov's discrepancy principle):
//! the largest smoothing whose data misfit is what the noise alone explains,
//! `||i - T l_lambda||^2 = sum_j sigma_j^2`.
//!
//! Why this rule: it needs no truth, only the noise level that a capture
//! (frame-to-frame variance) or a simulation (photons, read noise, bits)
//! provides, and the misfit grows monotonically with lambda, so a bisection in
//! log(lambda) finds it. One `T^T T` serves every trial.

use crate::solve::gram::Normal;
use crate::solve::solvers::{AdmmSettings, Problem, SolveRequest, Warm};
use crate::solve::{check_measurement, Reconstruction, SolveError};
use crate::transport::Transport;

/// Per-measurement noise variance, in the units of `T l` squared.
#[derive(Debug, Clone, PartialEq)]
pub struct NoiseLevel {
    /// `sigma_j^2` for every row of `T`.
    pub variance: Vec<f64>,
    /// Where the estimate came from.
    pub source: NoiseSource,
}

/// Where a noise estimate came from (reported in `lambda_choice.noise`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum NoiseSource {
    /// A camera model: photons, read noise and bits ([`NoiseLevel::from_camera`]).
    CameraModel,
    /// The frame-to-frame variance of the captures' mean.
    FrameVariance,
    /// The measurement alone: its least-squares residual outside range(T)
    /// ([`NoiseLevel::from_residual`]).
    Residual,
    /// The measurement alone: the misfit of its best non-negative fit
    /// ([`admm_tv_own_misfit_prepared`]).
    OwnMisfit,
}

/// Fewest residual degrees of freedom (rows minus columns) for
/// [`NoiseLevel::from_residual`]: below it the estimate is too noisy to use.
pub(crate) const MIN_RESIDUAL_DOF: usize = 16;

impl NoiseLevel {
    /// Per-row variances measured by the caller (e.g. frame-to-frame).
    pub fn measured(variance: Vec<f64>) -> Self {
        Self {
            variance,
            source: NoiseSource::FrameVariance,
        }
    }

    /// The noise of one measurement from the measurement alone: the part of
    /// `i` outside range(T) is noise only, so with `M` rows and `N` columns
    /// `sigma^2 = ||i - Q Q^T i||^2 / (M - N)`, `Q` the thin orthonormal
    /// factor of a Householder QR of `T` (its span holds range(T) and has `N`
    /// dimensions even when `T` is rank-deficient, where a least-squares
    /// solve would divide by zero). The same variance for every row. `None`
    /// when `M - N < MIN_RESIDUAL_DOF` or `i` does not fit `T`. Model error
    /// counts as noise here, so a mismatched model gets more smoothing, not less.
    pub fn from_residual(t: &Transport, i: &[f64]) -> Option<Self> {
        Self::from_residual_with(t, i, None)
    }

    /// [`NoiseLevel::from_residual`] with the Gram already formed: when it
    /// has a low-rank form, range(T) is spanned (to its tolerance) by the
    /// `r` pivot columns, so the QR is of those `M x r` columns and the
    /// residual has `M - r` degrees of freedom (instead of a QR of all of
    /// `T`, `2 M N^2` flops and an `M x N` `Q`).
    pub fn from_residual_with(t: &Transport, i: &[f64], normal: Option<&Normal>) -> Option<Self> {
        let m = t.rows();
        let (r, fitted) = residual_and_rank(t, i, normal)?;
        let var = r.iter().map(|x| x * x).sum::<f64>() / (m - fitted) as f64;
        var.is_finite().then(|| Self {
            variance: vec![var; m],
            source: NoiseSource::Residual,
        })
    }

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
            source: NoiseSource::CameraModel,
        }
    }

    /// `sum_j sigma_j^2`: the expected misfit of the true scene.
    pub fn total(&self) -> f64 {
        self.variance.iter().sum()
    }

    /// `mean_j sigma_j^2`.
    pub fn mean_variance(&self) -> f64 {
        self.total() / self.variance.len().max(1) as f64
    }
}

/// The least noisy of several colours' variances (by their mean over the
/// measured rows, variance > 0): the colour whose noise chooses the one
/// sampling colours solved together share.
/// Why: the others would choose a coarser `T` than it needs.
#[cfg(feature = "daemon")]
pub(crate) fn least_noisy<'a>(variances: impl IntoIterator<Item = &'a [f64]>) -> Option<&'a [f64]> {
    let mean = |v: &[f64]| {
        let (sum, count) = v
            .iter()
            .filter(|x| **x > 0.0)
            .fold((0.0, 0usize), |(s, c), x| (s + x, c + 1));
        match count {
            0 => f64::INFINITY,
            _ => sum / count as f64,
        }
    };
    variances
        .into_iter()
        .min_by(|a, b| mean(a).total_cmp(&mean(b)))
}

/// The residual `i - Q Q^T i` of the unconstrained least-squares fit of `i`
/// by `T` (Householder QR, thin `Q`; the Gram's factor when `normal` is
/// given; see [`NoiseLevel::from_residual_with`]): what no scene can
/// explain. `None` when `M - N < MIN_RESIDUAL_DOF` or `i` does not fit `T`.
pub(crate) fn least_squares_residual_with(
    t: &Transport,
    i: &[f64],
    normal: Option<&Normal>,
) -> Option<Vec<f64>> {
    residual_and_rank(t, i, normal).map(|(r, _)| r)
}

/// The residual outside range(T) and the dimension of the space fitted.
fn residual_and_rank(
    t: &Transport,
    i: &[f64],
    normal: Option<&Normal>,
) -> Option<(Vec<f64>, usize)> {
    let (m, n) = (t.rows(), t.cols());
    if i.len() != m || m < n + MIN_RESIDUAL_DOF || i.iter().any(|v| !v.is_finite()) {
        return None;
    }
    let (a, fitted) = match normal.and_then(|nm| nm.low_rank()) {
        Some(lr) => (
            faer::Mat::<f64>::from_fn(m, lr.pivots.len(), |r, k| t.col(lr.pivots[k])[r]),
            lr.pivots.len(),
        ),
        None => (t.as_mat().to_owned(), n),
    };
    Some((projection_residual(a, i), fitted))
}

/// `i` minus its orthogonal projection on the columns of `a` (`m x k`,
/// `k <= m`, consumed): Householder QR in place, `Q^T i`, its first `k`
/// entries zeroed, `Q` applied back. One copy of the columns and no thin `Q`
/// (half the memory of `qr().compute_thin_Q()`), which matters at the
/// 8192 x 4096 of a 64x64 scene grid.
fn projection_residual(mut a: faer::Mat<f64>, i: &[f64]) -> Vec<f64> {
    use faer::dyn_stack::{MemBuffer, MemStack};
    use faer::linalg::householder as hh;
    use faer::linalg::qr::no_pivoting::factor;
    let (m, k) = (a.nrows(), a.ncols());
    let par = crate::solve::par();
    let bs = factor::recommended_block_size::<f64>(m, k);
    let mut coeff = faer::Mat::<f64>::zeros(bs, k);
    let scratch = factor::qr_in_place_scratch::<f64>(m, k, bs, par, Default::default())
        .or(
            hh::apply_block_householder_sequence_transpose_on_the_left_in_place_scratch::<f64>(
                m, bs, 1,
            ),
        )
        .or(hh::apply_block_householder_sequence_on_the_left_in_place_scratch::<f64>(m, bs, 1));
    let mut mem = MemBuffer::new(scratch);
    let stack = MemStack::new(&mut mem);
    factor::qr_in_place(a.as_mut(), coeff.as_mut(), par, stack, Default::default());
    let mut b = faer::Mat::<f64>::from_fn(m, 1, |r, _| i[r]);
    hh::apply_block_householder_sequence_transpose_on_the_left_in_place_with_conj(
        a.as_ref(),
        coeff.as_ref(),
        faer::Conj::No,
        b.as_mut(),
        par,
        stack,
    );
    for r in 0..k.min(m) {
        b[(r, 0)] = 0.0;
    }
    hh::apply_block_householder_sequence_on_the_left_in_place_with_conj(
        a.as_ref(),
        coeff.as_ref(),
        faer::Conj::No,
        b.as_mut(),
        par,
        stack,
    );
    (0..m).map(|r| b[(r, 0)]).collect()
}

/// How the automatic lambda was found (the `lambda_choice` of a report).
#[derive(Debug, Clone, serde::Serialize)]
pub struct LambdaChoice {
    /// `resolved-discrepancy` (the default) or `discrepancy` (Morozov).
    pub rule: &'static str,
    /// Where the noise level came from.
    pub noise: NoiseSource,
    /// Mean noise variance per measurement, units of `T l` squared.
    pub noise_variance: f64,
    /// Best attainable misfit (smallest over the scan); resolved rule only.
    pub floor: Option<f64>,
    /// Components of the scene the measurement resolves; resolved rule only.
    pub resolved: Option<usize>,
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
/// Bisection steps in log10(lambda): 8 decades / 2^14 = 5e-4 decade.
const STEPS: usize = 14;

/// Per-component error, in units of the radiance range, below which a scene
/// component counts as resolved: the tolerance of [`crate::solve::resolution`].
pub(crate) const RESOLVED_TOLERANCE: f64 = 0.1;

/// ADMM-TV with lambda from the noise, the *resolved discrepancy* rule.
///
/// Morozov's rule aims the misfit at `sum sigma^2`, but with a box constraint
/// and an ill-conditioned `T` the best attainable misfit (the floor `F`) is
/// not `sum sigma^2`, and the whole range of useful lambdas sits within a few
/// `sigma^2` of `F` (on the Brewster bench Morozov's target lies at the knee,
/// 5-10x too much smoothing, or below the floor). This rule lets the
/// regularizer cost as much misfit as the noise carries in the components of
/// the scene that the measurement resolves: target `F + p mean(sigma^2)` with
/// `p` the number of singular values of `T` above `mean(sigma) / 0.1` (the
/// same 0.1-of-range criterion as `polnlos grid`), and picks the largest
/// lambda that meets it. `F` is the smallest misfit of a half-decade scan.
pub fn admm_tv_resolved(
    t: &Transport,
    i: &[f64],
    noise: &NoiseLevel,
    singular_values: &[f64],
    settings: &AdmmSettings,
) -> Result<(Reconstruction, LambdaChoice), SolveError> {
    check_measurement(t, i)?;
    check_noise(noise, i)?;
    let normal = Normal::of(t, i);
    admm_tv_resolved_prepared(t, i, &normal, noise, singular_values, settings)
}

/// [`admm_tv_resolved`] with `T^T T` and `T^T i` already formed (`i` already checked).
pub fn admm_tv_resolved_prepared(
    t: &Transport,
    i: &[f64],
    normal: &Normal,
    noise: &NoiseLevel,
    singular_values: &[f64],
    settings: &AdmmSettings,
) -> Result<(Reconstruction, LambdaChoice), SolveError> {
    resolved(settings.problem(t, i, normal), noise, singular_values, true)
}

/// How [`admm_tv_own_misfit_prepared`] aims the misfit, from its floor.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum OwnMisfitRule {
    /// Morozov's on the floor's noise, `F M / (M - N)`: a photo's rule
    /// (`solve::photo`).
    Discrepancy,
    /// The resolved discrepancy on the floor's noise, `F + p F / (M - N)`.
    Resolved,
}

/// ADMM-TV with λ from the measurement's own misfit: the floor `F` (the
/// smallest misfit of the scan, box constraint included) estimates the
/// noise as `F / (M - N)`, `M` the rows that carry data and `N` the
/// unknowns, and `rule` sets the target from it. `None` when `M - N` is
/// below `MIN_RESIDUAL_DOF`.
///
/// Why kept beside the default: docs/lambda.md ("One measurement, no noise
/// figure") measured both against the residual rule a calibrated
/// measurement gets (`offline::lambda::one_measurement...`); neither did
/// better, so the default stays and this is the study's.
pub fn admm_tv_own_misfit_prepared(
    t: &Transport,
    i: &[f64],
    normal: &Normal,
    singular_values: &[f64],
    settings: &AdmmSettings,
    rule: OwnMisfitRule,
) -> Result<Option<(Reconstruction, LambdaChoice)>, SolveError> {
    check_measurement(t, i)?;
    // Rows that carry data: a measured value or a non-zero row of `T`
    // (one pass down the columns).
    let mut carries: Vec<bool> = i.iter().map(|v| *v != 0.0).collect();
    for k in 0..t.cols() {
        for (c, v) in carries.iter_mut().zip(t.col(k)) {
            *c |= *v != 0.0;
        }
    }
    let rows = carries.iter().filter(|c| **c).count();
    let n = t.cols();
    if rows < n + MIN_RESIDUAL_DOF {
        return Ok(None);
    }
    let dof = rows - n;
    let aim = match rule {
        OwnMisfitRule::Discrepancy => Aim::OwnMisfit { rows, dof },
        OwnMisfitRule::Resolved => Aim::OwnResolved {
            dof,
            sv: singular_values,
        },
    };
    scan_and_bisect(settings.problem(t, i, normal), aim, singular_values, true).map(Some)
}

/// The components resolved to [`RESOLVED_TOLERANCE`] at noise `sigma`.
fn resolved_count(singular_values: &[f64], sigma: f64) -> usize {
    singular_values
        .iter()
        .filter(|&&s| s * RESOLVED_TOLERANCE >= sigma)
        .count()
        .max(1)
}

/// What a λ search aims the misfit at, from the floor `F` it finds.
#[derive(Debug, Clone, Copy)]
enum Aim<'a> {
    /// `F + p mean(sigma^2)` ([`admm_tv_resolved`]).
    Resolved {
        p: usize,
        mean_var: f64,
        source: NoiseSource,
    },
    /// `F rows / dof` ([`OwnMisfitRule::Discrepancy`]).
    OwnMisfit { rows: usize, dof: usize },
    /// `F + p F / dof`, `p` resolved at that noise ([`OwnMisfitRule::Resolved`]).
    OwnResolved { dof: usize, sv: &'a [f64] },
}

impl Aim<'_> {
    fn target(&self, floor: f64) -> f64 {
        match *self {
            Aim::Resolved { p, mean_var, .. } => floor + p as f64 * mean_var,
            Aim::OwnMisfit { rows, dof } => floor * rows as f64 / dof as f64,
            Aim::OwnResolved { dof, sv } => {
                let var = floor / dof as f64;
                floor + resolved_count(sv, var.sqrt()) as f64 * var
            }
        }
    }
}

/// The resolved-discrepancy rule on `p` (its solver, `T`, measurement and
/// Gram; λ left to the search), its trials solved as a warm path when the
/// solver keeps a warm start, or each from zero (`warm = false`, the cold
/// search the path is checked against).
pub(crate) fn resolved(
    p: Problem<'_>,
    noise: &NoiseLevel,
    singular_values: &[f64],
    warm: bool,
) -> Result<(Reconstruction, LambdaChoice), SolveError> {
    check_noise(noise, p.i)?;
    let mean_var = noise.mean_variance();
    let sigma = mean_var.sqrt();
    let aim = Aim::Resolved {
        p: resolved_count(singular_values, sigma),
        mean_var,
        source: noise.source,
    };
    scan_and_bisect(p, aim, singular_values, warm)
}

/// The half-decade scan for the floor and a bracket, then the bisection for
/// the largest λ whose misfit meets `aim`'s target.
fn scan_and_bisect(
    p: Problem<'_>,
    aim: Aim,
    singular_values: &[f64],
    warm: bool,
) -> Result<(Reconstruction, LambdaChoice), SolveError> {
    let unit = match p.normal {
        Some(nm) => nm.unit(),
        None => Normal::of(p.t, p.i).unit(),
    };
    let mut path = Path::new(p, warm);
    let mut solve = |lambda: f64| path.solve(lambda);
    // Half-decade scan over SCAN_REL: the floor and a bracket.
    let scan: Vec<f64> = (0..=SCAN_STEPS)
        .map(|k| SCAN_REL.0 + (SCAN_REL.1 - SCAN_REL.0) * k as f64 / SCAN_STEPS as f64)
        .map(|e| unit * 10f64.powf(e))
        .collect();
    // The misfit of an exact solve never decreases as lambda grows, so the
    // scan stops at the first trial above the target: the larger lambdas
    // could only lower the floor by the solves' inexactness.
    let mut results: Vec<Reconstruction> = Vec::with_capacity(scan.len());
    let (mut argmin, mut floor) = (0, f64::INFINITY);
    for &l in &scan {
        let r = solve(l)?;
        let misfit = r.stats.data_misfit;
        results.push(r);
        if misfit < floor {
            (argmin, floor) = (results.len() - 1, misfit);
        }
        if misfit > aim.target(floor) {
            break;
        }
    }
    let target = aim.target(floor);
    // Largest scanned lambda at or above the floor's that meets the target.
    let mut k = argmin;
    while k + 1 < results.len() && results[k + 1].stats.data_misfit <= target {
        k += 1;
    }
    let mut best = results.swap_remove(k);
    if k + 1 < scan.len() {
        best = bisect(
            (scan[k].log10(), scan[k + 1].log10()),
            BISECT_STEPS,
            target,
            best,
            &mut solve,
        )?;
    } else {
        best.stats.warnings.push("even the strongest regularization tried stays within the noise of the resolved components: the measurement carries almost no information about the scene".into());
    }
    let (rule, source, mean_var, resolved) = match aim {
        Aim::Resolved {
            p,
            mean_var,
            source,
        } => ("resolved-discrepancy", source, mean_var, Some(p)),
        Aim::OwnMisfit { dof, .. } => (
            "own-misfit-discrepancy",
            NoiseSource::OwnMisfit,
            floor / dof as f64,
            None,
        ),
        Aim::OwnResolved { dof, sv } => (
            "resolved-discrepancy",
            NoiseSource::OwnMisfit,
            floor / dof as f64,
            Some(resolved_count(sv, (floor / dof as f64).sqrt())),
        ),
    };
    let sigma = mean_var.sqrt();
    if resolved == Some(1)
        && singular_values
            .first()
            .is_none_or(|&s| s * RESOLVED_TOLERANCE < sigma)
    {
        best.stats.warnings.push(format!(
            "no scene component is resolved to {RESOLVED_TOLERANCE} of the range at this noise level (largest singular value {:.3e}, noise {sigma:.3e}): expect a nearly flat result",
            singular_values.first().copied().unwrap_or(0.0)
        ));
    }
    let choice = LambdaChoice {
        rule,
        noise: source,
        noise_variance: mean_var,
        floor: Some(floor),
        resolved,
        target,
        misfit: best.stats.data_misfit,
        lambda: best.stats.lambda.unwrap_or(0.0),
        trials: path.trials,
    };
    Ok((best, choice))
}

/// Bisection in log10(lambda) over `(lo, hi)` for the largest lambda whose
/// misfit stays at or below `target`; `keep` is the best so far (at `lo`).
fn bisect(
    (mut lo, mut hi): (f64, f64),
    steps: usize,
    target: f64,
    mut keep: Reconstruction,
    solve: &mut impl FnMut(f64) -> Result<Reconstruction, SolveError>,
) -> Result<Reconstruction, SolveError> {
    for _ in 0..steps {
        let mid = 0.5 * (lo + hi);
        let r = solve(10f64.powf(mid))?;
        if r.stats.data_misfit > target {
            hi = mid;
        } else {
            lo = mid;
            keep = r;
        }
    }
    Ok(keep)
}

/// The λ trials on one measurement, solved as a path: one Gram, one
/// factor carried from trial to trial (its penalty kept, so no new
/// factorization unless residual balancing asks for one), and each trial
/// started from the iterate of the nearest λ solved so far (its TV dual
/// scaled to the new λ) instead of from zero.
pub(super) struct Path<'a> {
    /// The problem every trial solves, at its own λ, with `p.req.solver`.
    p: Problem<'a>,
    /// Whether trials start from their neighbours (else from zero, the cold search).
    warm: bool,
    state: Warm,
    /// (log10 lambda, iterate) of every trial.
    points: Vec<(f64, Warm)>,
    /// Every (lambda, misfit) tried, in order.
    pub(super) trials: Vec<(f64, f64)>,
}

impl<'a> Path<'a> {
    /// The path of `p`'s solver; warm only when that solver keeps a warm start.
    pub(super) fn new(p: Problem<'a>, warm: bool) -> Self {
        Self {
            warm: warm && p.req.solver.needs().warm_start,
            p,
            state: Warm::default(),
            points: Vec::new(),
            trials: Vec::new(),
        }
    }

    /// One solve at `lambda`, recorded as (lambda, misfit).
    pub(super) fn solve(&mut self, lambda: f64) -> Result<Reconstruction, SolveError> {
        let p = Problem {
            req: SolveRequest {
                lambda: Some(lambda),
                ..self.p.req
            },
            ..self.p
        };
        let solver = p.req.solver;
        let x = lambda.log10();
        let r = if self.warm {
            let nearest = self
                .points
                .iter()
                .min_by(|a, b| (a.0 - x).abs().total_cmp(&(b.0 - x).abs()));
            if let Some((y, from)) = nearest {
                self.state.start_from(from, 10f64.powf(x - y));
            }
            let r = solver.solve(&p, &mut self.state)?;
            self.points.push((x, self.state.iterate()));
            r
        } else {
            solver.run(&p)?
        };
        self.trials.push((lambda, r.stats.data_misfit));
        Ok(r)
    }
}

/// Scan range of [`admm_tv_resolved`], log10 of lambda relative to `mean(diag(T^T T))`.
const SCAN_REL: (f64, f64) = (-6.0, 0.0);
/// Half-decade steps over the scan range.
const SCAN_STEPS: usize = 12;
/// Bisection steps inside the bracketing half decade (0.5 / 2^6 = 0.008 decade).
const BISECT_STEPS: usize = 6;

pub(super) fn check_noise(noise: &NoiseLevel, i: &[f64]) -> Result<(), SolveError> {
    if noise.variance.len() != i.len()
        || noise.variance.iter().any(|v| !(v.is_finite() && *v >= 0.0))
    {
        return Err(SolveError::Parameter {
            name: "noise",
            value: noise.variance.len() as f64,
            reason: "needs one finite variance >= 0 per measurement",
        });
    }
    Ok(())
}

/// ADMM-TV with lambda chosen by Morozov's discrepancy principle (kept for
/// comparison; see [`admm_tv_resolved`] for the default rule).
pub fn admm_tv_discrepancy(
    t: &Transport,
    i: &[f64],
    noise: &NoiseLevel,
    settings: &AdmmSettings,
) -> Result<(Reconstruction, LambdaChoice), SolveError> {
    check_measurement(t, i)?;
    check_noise(noise, i)?;
    let normal = Normal::of(t, i);
    let unit = normal.unit();
    let target = noise.total();
    let mut path = Path::new(settings.problem(t, i, &normal), false);
    let mut solve = |lambda: f64| path.solve(lambda);
    let (lo, hi) = ((RANGE_REL.0 * unit).log10(), (RANGE_REL.1 * unit).log10());
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
            bisect((lo, hi), STEPS, target, at_lo, &mut solve)?
        }
    };
    if let Some(w) = warning {
        best.stats.warnings.push(w);
    }
    let choice = LambdaChoice {
        rule: "discrepancy",
        noise: noise.source,
        noise_variance: noise.mean_variance(),
        floor: None,
        resolved: None,
        target,
        misfit: best.stats.data_misfit,
        lambda: best.stats.lambda.unwrap_or(0.0),
        trials: path.trials,
    };
    Ok((best, choice))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scene::{Grid, Scene};
    use crate::simulate::patterns::Pattern;
    use crate::transport::build;
    use crate::transport::MemoryBudget;

    #[test]
    fn projection_residual_is_orthogonal_to_the_columns_and_leaves_the_rest() {
        // Columns spanning a known subspace of R^7: e0 + e1, e1 - e2, e3 (and
        // a scaled copy folded in, so the QR sees 4 columns of rank 3).
        let cols = [
            [1.0, 1.0, 0.0, 0.0, 0.0, 0.0, 0.0],
            [0.0, 1.0, -1.0, 0.0, 0.0, 0.0, 0.0],
            [0.0, 0.0, 0.0, 2.0, 0.0, 0.0, 0.0],
        ];
        let a = faer::Mat::<f64>::from_fn(7, 3, |r, k| cols[k][r]);
        let inside = [3.0, 1.0, 2.0, -4.0, 0.0, 0.0, 0.0]; // (3,1,2) = 3 c0 - 2 c1
        let outside = [0.0, 0.0, 0.0, 0.0, 1.5, -2.0, 0.5];
        let i: Vec<f64> = inside.iter().zip(&outside).map(|(a, b)| a + b).collect();
        let r = projection_residual(a, &i);
        for (got, want) in r.iter().zip(&outside) {
            assert!((got - want).abs() < 1e-12, "{r:?}");
        }
    }

    /// Brewster bench, poses B and C, wall 32x32, scene `n x n`.
    pub(super) fn bench(n: usize) -> Transport {
        let s = Scene::builtin("brewster-multi")
            .unwrap()
            .unwrap()
            .edit(|s| s.hidden.plane.grid = Grid { nu: n, nv: n })
            .unwrap();
        build(&s, MemoryBudget::DEFAULT).unwrap()
    }

    /// Gaussian noise of standard deviation `sigma` (Box-Muller on an LCG).
    /// `T` times `pattern` plus white noise of 1 % of its peak (seeded
    /// ChaCha8, as the simulator draws): the measurement and that sigma.
    fn noisy(t: &Transport, pattern: Pattern, seed: u64) -> (Vec<f64>, f64) {
        use rand::SeedableRng;
        use rand_distr::Distribution;
        let clean = t.apply(&pattern.render(t.scene_grid()));
        let sigma = 0.01 * clean.iter().copied().fold(0.0, f64::max);
        let noise = rand_distr::Normal::new(0.0, sigma).expect("a finite sigma");
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
        let i = clean.iter().map(|c| c + noise.sample(&mut rng)).collect();
        (i, sigma)
    }

    #[test]
    fn noise_from_the_pivot_columns_matches_the_full_qr() {
        // 576 columns, rank far lower: the low-rank form is taken.
        let t = bench(24);
        let (i, sigma) = noisy(&t, Pattern::Letter, 7);
        let normal = Normal::of(&t, &i);
        let lr = normal.low_rank().expect("low rank");
        assert!(lr.rank() < t.cols() / 4, "rank {}", lr.rank());
        let full = NoiseLevel::from_residual(&t, &i).unwrap().mean_variance();
        let fast = NoiseLevel::from_residual_with(&t, &i, Some(&normal))
            .unwrap()
            .mean_variance();
        let s2 = sigma * sigma;
        // Both unbiased; 2048 - 576 and 2048 - r degrees of freedom.
        assert!((full / s2 - 1.0).abs() < 0.08, "full QR {}", full / s2);
        assert!(
            (fast / s2 - 1.0).abs() < 0.08,
            "pivot columns {}",
            fast / s2
        );
    }

    #[test]
    fn the_warm_path_picks_the_cold_search_lambda() {
        for n in [12, 24] {
            let t = bench(n);
            let (i, sigma) = noisy(&t, Pattern::Disk, 11);
            let normal = Normal::of(&t, &i);
            let noise = NoiseLevel::measured(vec![sigma * sigma; i.len()]);
            let sv = crate::solve::condition(&t).unwrap().singular_values;
            let settings = AdmmSettings {
                max_iter: 5000,
                ..AdmmSettings::default()
            };
            let solve =
                |warm| resolved(settings.problem(&t, &i, &normal), &noise, &sv, warm).unwrap();
            let (cold, cold_choice) = solve(false);
            let (warm, warm_choice) = solve(true);
            let decades = (warm_choice.lambda / cold_choice.lambda).log10().abs();
            let truth = Pattern::Disk.render(t.scene_grid());
            let psnr = |r: &Reconstruction| crate::solve::metrics::psnr(&truth, &r.image);
            println!(
                "{n}x{n}: lambda {:.4e} (cold) {:.4e} (warm), {decades:.4} decade apart; PSNR {:.2} / {:.2} dB",
                cold_choice.lambda,
                warm_choice.lambda,
                psnr(&cold),
                psnr(&warm)
            );
            // One bisection step: 0.5 / 2^BISECT_STEPS decade.
            assert!(
                decades <= 0.5 / (1 << BISECT_STEPS) as f64 + 1e-9,
                "{decades}"
            );
            assert!((psnr(&cold) - psnr(&warm)).abs() < 0.05);
        }
    }

    #[test]
    #[cfg(feature = "daemon")]
    fn the_least_noisy_colour_is_by_its_measured_rows() {
        let red = [4.0, 4.0, 4.0, 4.0];
        let green = [1.0, 1.0, 0.0, 0.0];
        let blue = [2.0, 2.0, 2.0, 2.0];
        let none = [0.0; 4];
        let got = least_noisy([&red[..], &green[..], &blue[..], &none[..]]);
        assert_eq!(got, Some(&green[..]));
        // Unmeasured rows (0) do not make a colour look quieter than it is:
        // 3 over its one measured row, not 0.75 over all four.
        let got = least_noisy([&red[..], &[3.0, 0.0, 0.0, 0.0][..], &blue[..]]);
        assert_eq!(got, Some(&blue[..]));
        assert_eq!(least_noisy([]), None);
    }
}
