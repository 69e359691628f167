//! FISTA for MODEL.md Eq. 12 with a TV proximal step and the box constraint,
//! the solver Saunders et al. (2019) use for computational periscopy.
//!
//! Same objective as [`super::admm`], `1/2 ||i - T l||^2 + lambda/2 TV(l)` on
//! `0 <= l <= 1`. The gradient step uses `T^T T` (no factorization, so a
//! FISTA iteration is cheaper to start than ADMM's Cholesky); the proximal
//! step is Beck and Teboulle's fast gradient projection (FGP, IEEE TIP 2009)
//! on the dual of the constrained TV denoising problem, warm-started from the
//! previous outer iteration. Step `1/L` with `L = sigma_max(T)^2` by power
//! iteration.

use std::time::Instant;

use faer::Mat;

use super::admm::{objective_of, LAMBDA_REL};
use super::{Method, Needs, Problem, Warm};
use crate::scene::Grid;
use crate::solve::gram::Normal;
use crate::solve::tv::{add_divergence_adjoint, gradient};
use crate::solve::{
    check_lambda, check_measurement, check_tol, Reconstruction, SolveError, SolveStats,
};
use crate::stop::Stop;
use crate::transport::Transport;

/// Parameters of a FISTA-TV solve.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FistaSettings<'a> {
    /// TV weight in MODEL.md units; default as ADMM's, `1e-2 * mean(diag(T^T T))`.
    pub lambda: Option<f64>,
    /// Outer iteration cap.
    pub max_iter: usize,
    /// Stop when `||l_k - l_{k-1}|| <= tol * max(||l_k||, 1e-12)`.
    pub tol: f64,
    /// FGP iterations per proximal step.
    pub inner: usize,
    /// Ends the solve early with [`SolveError::Stopped`] when raised.
    pub stop: Stop<'a>,
}

impl Default for FistaSettings<'_> {
    fn default() -> Self {
        Self {
            lambda: None,
            max_iter: 500,
            tol: 1e-5,
            inner: 10,
            stop: Stop::default(),
        }
    }
}

/// Runs FISTA-TV on a measurement `i` of the scene seen through `t`.
pub(crate) fn fista_tv(
    t: &Transport,
    i: &[f64],
    settings: &FistaSettings,
) -> Result<Reconstruction, SolveError> {
    check_measurement(t, i)?;
    let normal = Normal::new(t.as_mat(), i);
    fista_tv_prepared(t, i, &normal, settings)
}

/// Largest eigenvalue of the symmetric `g` by power iteration (relative
/// change below 1e-6 or 200 steps), from a positive start vector.
pub(crate) fn largest_eigenvalue(g: &Mat<f64>) -> f64 {
    let n = g.nrows();
    let mut v = Mat::<f64>::from_fn(n, 1, |_, _| 1.0 / (n as f64).sqrt());
    let mut lambda = 0.0;
    for _ in 0..200 {
        let w = g * &v;
        let norm = w.norm_l2();
        if norm == 0.0 || !norm.is_finite() {
            return 0.0;
        }
        v = w * faer::Scale(1.0 / norm);
        let done = (norm - lambda).abs() <= 1e-6 * norm;
        lambda = norm;
        if done {
            break;
        }
    }
    lambda
}

/// `T^T T` as a full symmetric matrix from its lower triangle.
pub(crate) fn symmetric(lower: &Mat<f64>) -> Mat<f64> {
    let n = lower.nrows();
    Mat::from_fn(
        n,
        n,
        |r, c| {
            if r >= c {
                lower[(r, c)]
            } else {
                lower[(c, r)]
            }
        },
    )
}

/// Scratch buffers of the proximal step, allocated once per solve.
pub(crate) struct Prox {
    grid: Grid,
    /// Upper bound of the box `[0, upper]`.
    upper: f64,
    /// FGP's momentum on the dual (else plain gradient projection).
    accelerated: bool,
    /// Dual variable (warm start), `2n`.
    p: Vec<f64>,
    /// Extrapolated dual, `2n`.
    r: Vec<f64>,
    /// Previous dual, `2n`.
    p_old: Vec<f64>,
    /// Gradient scratch, `2n`.
    g: Vec<f64>,
    /// Primal scratch, `n`.
    x: Vec<f64>,
}

impl Prox {
    pub(crate) fn new(grid: Grid) -> Self {
        Self::with(grid, 1.0, true)
    }

    /// Plain gradient projection (no momentum) on the box `[0, upper]`.
    pub(super) fn plain(grid: Grid, upper: f64) -> Self {
        Self::with(grid, upper, false)
    }

    fn with(grid: Grid, upper: f64, accelerated: bool) -> Self {
        let n = grid.count();
        Self {
            grid,
            upper,
            accelerated,
            p: vec![0.0; 2 * n],
            r: vec![0.0; 2 * n],
            p_old: vec![0.0; 2 * n],
            g: vec![0.0; 2 * n],
            x: vec![0.0; n],
        }
    }

    /// `x = P_box(b - mu D^T q)`.
    fn primal(grid: Grid, upper: f64, b: &[f64], mu: f64, q: &[f64], x: &mut [f64]) {
        x.fill(0.0);
        add_divergence_adjoint(grid, q, x);
        for (xk, bk) in x.iter_mut().zip(b) {
            *xk = (bk - mu * *xk).clamp(0.0, upper);
        }
    }

    /// `argmin_x 1/2 ||x - b||^2 + mu TV(x)` on `[0, upper]`, into `out`.
    pub(crate) fn solve(&mut self, b: &[f64], mu: f64, iterations: usize, out: &mut [f64]) {
        if mu <= 0.0 {
            for (o, v) in out.iter_mut().zip(b) {
                *o = v.clamp(0.0, self.upper);
            }
            return;
        }
        let n = self.grid.count();
        let step = 1.0 / (8.0 * mu);
        self.r.copy_from_slice(&self.p);
        let mut tk = 1.0f64;
        for _ in 0..iterations {
            Self::primal(self.grid, self.upper, b, mu, &self.r, &mut self.x);
            gradient(self.grid, &self.x, &mut self.g);
            self.p_old.copy_from_slice(&self.p);
            for j in 0..n {
                let (px, py) = (
                    self.r[j] + step * self.g[j],
                    self.r[n + j] + step * self.g[n + j],
                );
                let m = px.hypot(py).max(1.0);
                self.p[j] = px / m;
                self.p[n + j] = py / m;
            }
            if !self.accelerated {
                self.r.copy_from_slice(&self.p);
                continue;
            }
            let t_next = 0.5 * (1.0 + (1.0 + 4.0 * tk * tk).sqrt());
            let beta = (tk - 1.0) / t_next;
            for k in 0..2 * n {
                self.r[k] = self.p[k] + beta * (self.p[k] - self.p_old[k]);
            }
            tk = t_next;
        }
        Self::primal(self.grid, self.upper, b, mu, &self.p, out);
    }
}

/// TV denoising of an image on `grid`: `argmin_x 1/2 ||x - b||^2 + weight
/// TV(x)` on `[0, 1]`, by Chambolle's dual projection in its accelerated form
/// (FGP, Beck & Teboulle 2009), `iterations` steps from a zero dual.
///
/// Why here: the paper's Fig. 9 asks whether post-processing a baseline
/// reconstruction closes the gap to the polarized one; this is the same
/// proximal step FISTA-TV takes, so the comparison uses one TV.
#[cfg(feature = "report")]
pub fn tv_denoise(grid: Grid, b: &[f64], weight: f64, iterations: usize) -> Vec<f64> {
    let mut prox = Prox::new(grid);
    let mut out = vec![0.0; grid.count()];
    prox.solve(b, weight.max(0.0), iterations, &mut out);
    out
}

/// [`fista_tv`] with `T^T T` and `T^T i` already formed (`i` already checked).
pub(crate) fn fista_tv_prepared(
    t: &Transport,
    i: &[f64],
    normal: &Normal,
    settings: &FistaSettings,
) -> Result<Reconstruction, SolveError> {
    proximal_gradient(t, i, normal, settings, &FISTA)
}

/// Which proximal gradient: FISTA (momentum on both loops, the box
/// `[0, 1]`) or the plain one GP-TV runs.
pub(super) struct Variant {
    /// The name in the solver's statistics.
    pub name: &'static str,
    /// How its iteration-cap warning names it.
    pub label: &'static str,
    /// Nesterov momentum on the outer step and FGP's on the TV dual.
    pub momentum: bool,
    /// Upper bound of the box.
    pub upper: f64,
}

/// FISTA-TV's variant.
const FISTA: Variant = Variant {
    name: "fista-tv",
    label: "FISTA",
    momentum: true,
    upper: 1.0,
};

/// Proximal gradient on `1/2 ||i - T l||^2 + lambda/2 TV(l)` on the box:
/// FISTA's loop, or with `variant.momentum` off the plain one.
pub(super) fn proximal_gradient(
    t: &Transport,
    i: &[f64],
    normal: &Normal,
    settings: &FistaSettings,
    variant: &Variant,
) -> Result<Reconstruction, SolveError> {
    check_tol(settings.tol)?;
    if settings.inner == 0 {
        return Err(SolveError::Parameter {
            name: "inner",
            value: 0.0,
            reason: "must be at least 1 proximal iteration",
        });
    }
    let start = Instant::now();
    let n = t.cols();
    let lambda = settings.lambda.unwrap_or(LAMBDA_REL * normal.unit());
    check_lambda(lambda)?;
    let mut warnings = Vec::new();
    let g = symmetric(normal.lower());
    let lip = largest_eigenvalue(&g) * 1.01;
    let factor_seconds = start.elapsed().as_secs_f64();
    if lip == 0.0 {
        warnings.push("T is all zero: no scene element lights the wall as the cameras see it; the result is the zero image".into());
    }
    if lambda == 0.0 {
        warnings.push(
            "lambda = 0: no regularization, only the box constraint; expect noise amplification"
                .into(),
        );
    }

    let t1 = Instant::now();
    let mu = if lip > 0.0 { 0.5 * lambda / lip } else { 0.0 };
    let mut prox = match variant.momentum {
        true => Prox::new(t.scene_grid()),
        false => Prox::plain(t.scene_grid(), variant.upper),
    };
    let mut x = vec![0.0; n];
    let mut x_old = vec![0.0; n];
    let mut y = vec![0.0; n];
    let mut v = vec![0.0; n];
    let mut gy = Mat::<f64>::zeros(n, 1);
    let mut ym = Mat::<f64>::zeros(n, 1);
    let mut tk = 1.0f64;
    let mut iterations = 0;
    let mut converged = lip == 0.0;
    let mut change = f64::INFINITY;
    while !converged && iterations < settings.max_iter {
        crate::solve::check_stop(settings.stop, iterations)?;
        iterations += 1;
        for k in 0..n {
            ym[(k, 0)] = y[k];
        }
        faer::linalg::matmul::matmul(
            gy.as_mut(),
            faer::Accum::Replace,
            g.as_ref(),
            ym.as_ref(),
            1.0,
            faer::Par::Seq,
        );
        for k in 0..n {
            v[k] = y[k] - (gy[(k, 0)] - normal.ti[k]) / lip;
        }
        x_old.copy_from_slice(&x);
        prox.solve(&v, mu, settings.inner, &mut x);
        let t_next = 0.5 * (1.0 + (1.0 + 4.0 * tk * tk).sqrt());
        let beta = match variant.momentum {
            true => (tk - 1.0) / t_next,
            false => 0.0,
        };
        let (mut d2, mut x2) = (0.0, 0.0);
        for k in 0..n {
            let d = x[k] - x_old[k];
            y[k] = x[k] + beta * d;
            d2 += d * d;
            x2 += x[k] * x[k];
        }
        tk = t_next;
        change = d2.sqrt() / x2.sqrt().max(1e-12);
        converged = change <= settings.tol;
    }
    let iterate_seconds = t1.elapsed().as_secs_f64();
    if !converged {
        warnings.push(format!(
            "{} stopped at the iteration cap ({iterations}) before meeting tol = {}: relative change {change:.3e}; raise max_iter or tol (\"max_iter\" / \"tol\" in a request, --max-iter / --tol on the command line)",
            variant.label,
            settings.tol
        ));
    }
    let (misfit, objective) = objective_of(t, i, &x, lambda);
    Ok(Reconstruction {
        image: x,
        stats: SolveStats {
            solver: variant.name.into(),
            lambda: Some(lambda),
            rho: None,
            iterations,
            converged,
            primal_residual: Some(change),
            dual_residual: None,
            objective,
            data_misfit: misfit,
            rank: None,
            clipped_fraction: None,
            gram_seconds: normal.seconds,
            factor_seconds,
            iterate_seconds,
            total_seconds: normal.seconds + start.elapsed().as_secs_f64(),
            warnings,
        },
    })
}

/// FISTA-TV as a registered solver.
pub(super) struct FistaTv;

impl Method for FistaTv {
    fn name(&self) -> &'static str {
        "fista-tv"
    }

    fn about(&self) -> &'static str {
        "FISTA with a TV proximal step and the box (Saunders et al. 2019); the same objective as admm-tv"
    }

    fn needs(&self) -> Needs {
        Needs {
            gram: false,
            lambda_from_noise: true,
            warm_start: false,
        }
    }

    fn solve(&self, p: &Problem<'_>, _: Option<&mut Warm>) -> Result<Reconstruction, SolveError> {
        let d = FistaSettings::default();
        let settings = FistaSettings {
            lambda: p.req.lambda,
            max_iter: p.max_iter(d.max_iter),
            tol: p.req.tol.unwrap_or(d.tol),
            stop: p.stop,
            ..d
        };
        match p.normal {
            Some(nm) => fista_tv_prepared(p.t, p.i, nm, &settings),
            None => fista_tv(p.t, p.i, &settings),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::solve::solvers::admm::{admm_tv, AdmmSettings};
    use crate::solve::tv::total_variation;

    fn identity(grid: Grid) -> Transport {
        let n = grid.count();
        let mut data = vec![0.0; n * n];
        for k in 0..n {
            data[k * n + k] = 1.0;
        }
        let block = crate::transport::Block {
            pose: "A".into(),
            channel: crate::scene::Channel::None,
        };
        Transport::from_col_major(n, n, data, vec![block], Grid { nu: n, nv: 1 }, grid)
    }

    #[test]
    #[cfg(feature = "report")]
    fn tv_denoising_restores_a_noisy_step() {
        // A step edge plus alternating noise: denoising brings it closer to
        // the step, and a zero weight only clips to the box.
        let grid = Grid { nu: 8, nv: 8 };
        let truth: Vec<f64> = (0..64).map(|k| if k % 8 < 4 { 0.2 } else { 0.8 }).collect();
        let noisy: Vec<f64> = truth
            .iter()
            .enumerate()
            .map(|(k, v)| v + if (k / 8 + k) % 2 == 0 { 0.1 } else { -0.1 })
            .collect();
        let err = |x: &[f64]| {
            x.iter()
                .zip(&truth)
                .map(|(a, b)| (a - b).powi(2))
                .sum::<f64>()
        };
        let den = tv_denoise(grid, &noisy, 0.1, 200);
        assert!(
            err(&den) < 0.2 * err(&noisy),
            "{} vs {}",
            err(&den),
            err(&noisy)
        );
        let clipped = tv_denoise(grid, &[1.5; 64], 0.0, 10);
        assert!(clipped.iter().all(|&v| v == 1.0));
    }

    #[test]
    fn prox_without_tv_is_the_box_projection() {
        let grid = Grid { nu: 3, nv: 1 };
        let mut p = Prox::new(grid);
        let mut out = vec![0.0; 3];
        p.solve(&[-0.5, 0.3, 1.7], 0.0, 5, &mut out);
        assert_eq!(out, vec![0.0, 0.3, 1.0]);
    }

    #[test]
    fn prox_of_a_step_lowers_tv_by_the_weight() {
        // 1/2 ||x - b||^2 + mu TV(x) on a 1-D step 0|1 of 8 pixels: the
        // minimizer moves each side by mu / 4 towards the other (4 pixels per side).
        let grid = Grid { nu: 8, nv: 1 };
        let b: Vec<f64> = (0..8).map(|k| if k < 4 { 0.2 } else { 0.8 }).collect();
        let mut p = Prox::new(grid);
        let mut out = vec![0.0; 8];
        p.solve(&b, 0.4, 500, &mut out);
        for k in 0..4 {
            assert!((out[k] - 0.3).abs() < 1e-6, "{out:?}");
            assert!((out[k + 4] - 0.7).abs() < 1e-6, "{out:?}");
        }
    }

    #[test]
    fn agrees_with_admm_on_the_same_objective() {
        let grid = Grid { nu: 6, nv: 6 };
        let t = identity(grid);
        let truth: Vec<f64> = (0..36)
            .map(|k| if (k % 6) > 2 && k / 6 > 1 { 0.9 } else { 0.1 })
            .collect();
        let i: Vec<f64> = truth
            .iter()
            .enumerate()
            .map(|(k, v)| v + 0.05 * ((k * 7919) % 13) as f64 / 13.0 - 0.025)
            .collect();
        let lambda = 0.05;
        let f = fista_tv(
            &t,
            &i,
            &FistaSettings {
                lambda: Some(lambda),
                max_iter: 3000,
                tol: 1e-10,
                inner: 50,
                ..Default::default()
            },
        )
        .unwrap();
        let a = admm_tv(
            &t,
            &i,
            &AdmmSettings {
                lambda: Some(lambda),
                rho: Some(0.1),
                max_iter: 20000,
                tol: 1e-9,
                ..Default::default()
            },
        )
        .unwrap();
        assert!(f.stats.converged);
        let diff = f
            .image
            .iter()
            .zip(&a.image)
            .map(|(x, y)| (x - y).abs())
            .fold(0.0, f64::max);
        assert!(diff < 1e-3, "max difference {diff}");
        assert!((f.stats.objective - a.stats.objective).abs() < 1e-5);
        assert!(total_variation(grid, &f.image) < total_variation(grid, &i));
        assert!(f.image.iter().all(|v| (0.0..=1.0).contains(v)));
    }

    #[test]
    fn bad_parameters_are_named() {
        let grid = Grid { nu: 2, nv: 2 };
        let t = identity(grid);
        let i = vec![0.5; 4];
        let e = fista_tv(
            &t,
            &i,
            &FistaSettings {
                lambda: Some(-1.0),
                ..FistaSettings::default()
            },
        )
        .unwrap_err();
        assert!(e.to_string().starts_with("lambda = -1"), "{e}");
        let e = fista_tv(
            &t,
            &i,
            &FistaSettings {
                inner: 0,
                ..FistaSettings::default()
            },
        )
        .unwrap_err();
        assert!(e.to_string().starts_with("inner = 0"), "{e}");
    }

    #[test]
    fn iteration_cap_is_reported() {
        let grid = Grid { nu: 4, nv: 4 };
        let t = identity(grid);
        let i: Vec<f64> = (0..16).map(|k| (k as f64) / 16.0).collect();
        let r = fista_tv(
            &t,
            &i,
            &FistaSettings {
                max_iter: 2,
                tol: 1e-14,
                ..FistaSettings::default()
            },
        )
        .unwrap();
        assert!(!r.stats.converged);
        assert_eq!(r.stats.iterations, 2);
        assert!(r.stats.warnings[0].contains("iteration cap (2)"));
    }

    #[test]
    fn a_raised_stop_ends_both_solvers_at_a_checkpoint() {
        use std::sync::atomic::{AtomicBool, Ordering};
        let grid = Grid { nu: 4, nv: 4 };
        let t = identity(grid);
        let i: Vec<f64> = (0..16).map(|k| (k as f64) / 16.0).collect();
        const CAP: usize = 10_000_000;
        let flag = AtomicBool::new(true);
        let stop = Stop::on(&flag);
        let admm = |stop| {
            admm_tv(
                &t,
                &i,
                &AdmmSettings {
                    max_iter: CAP,
                    tol: 1e-300,
                    stop,
                    ..Default::default()
                },
            )
        };
        let fista = |stop| {
            fista_tv(
                &t,
                &i,
                &FistaSettings {
                    max_iter: CAP,
                    tol: 1e-300,
                    stop,
                    ..Default::default()
                },
            )
        };
        for e in [admm(stop).unwrap_err(), fista(stop).unwrap_err()] {
            assert!(matches!(e, SolveError::Stopped { iterations: 0 }), "{e}");
        }
        // Raised by another thread while the solve runs: it ends at a
        // checkpoint short of its cap instead of running CAP iterations
        // (seconds). Under load the raise can come before the solve's first
        // look at the flag (a stop at iteration 0, also a checkpoint); the
        // raise then waits longer, until a stop lands mid-run.
        let mut mid_run = None;
        for delay_ms in [20, 100, 500, 2000] {
            flag.store(false, Ordering::SeqCst);
            let iterations = std::thread::scope(|s| {
                let raise = s.spawn(|| {
                    std::thread::sleep(std::time::Duration::from_millis(delay_ms));
                    flag.store(true, Ordering::SeqCst);
                });
                let got = match admm(stop) {
                    Err(SolveError::Stopped { iterations }) => iterations,
                    other => panic!(
                        "expected a stop, got {:?}",
                        other.map(|r| r.stats.iterations)
                    ),
                };
                raise.join().unwrap();
                got
            });
            assert!(
                iterations < CAP && iterations % Stop::EVERY == 0,
                "{iterations}"
            );
            if iterations > 0 {
                mid_run = Some(iterations);
                break;
            }
        }
        assert!(mid_run.is_some(), "no stop landed mid-run");
        // An unraised stop changes nothing.
        flag.store(false, Ordering::SeqCst);
        let (a, b) = (fista(stop).unwrap(), fista(Stop::default()).unwrap());
        assert_eq!(a.image, b.image);
    }
}
