//! GP-TV: proximal gradient (ISTA) on MODEL.md Eq. 12's objective,
//! `1/2 ||i - T l||^2 + lambda/2 TV(l)` on the box, whose TV-and-box
//! proximal step is Chambolle's dual gradient projection (Beck & Teboulle
//! 2009, "GP"): the plainest first-order TV solver, without FISTA's
//! momentum on either loop.
//!
//! Why kept: a reference that is easy to check by hand (each step lowers
//! the objective), and the solver that shows a new one is this file and its
//! line in [`super::Solver::ALL`].

use std::time::Instant;

use faer::Mat;

use super::admm::{objective_of, LAMBDA_REL};
use super::fista::{largest_eigenvalue, symmetric};
use super::{Method, Needs, Problem, Warm};
use crate::scene::Grid;
use crate::solve::gram::Normal;
use crate::solve::tv::{add_divergence_adjoint, gradient};
use crate::solve::{
    check_lambda, check_measurement, check_tol, Reconstruction, SolveError, SolveStats,
};

/// Outer iterations unless the request sets a cap.
const MAX_ITER: usize = 1000;
/// Relative change of `l` between outer iterations that ends the solve.
const TOL: f64 = 1e-5;
/// Dual projection steps per proximal step (the dual is kept between steps).
const INNER: usize = 20;

/// GP-TV as a registered solver.
pub(super) struct GpTv;

impl Method for GpTv {
    fn name(&self) -> &'static str {
        "gp-tv"
    }

    fn about(&self) -> &'static str {
        "proximal gradient with a gradient-projection TV step and the box, no momentum; the same objective as admm-tv"
    }

    fn needs(&self) -> Needs {
        Needs {
            gram: false,
            lambda_from_noise: true,
            warm_start: false,
        }
    }

    fn solve(&self, p: &Problem<'_>, _: Option<&mut Warm>) -> Result<Reconstruction, SolveError> {
        let formed;
        let normal = match p.normal {
            Some(nm) => nm,
            None => {
                check_measurement(p.t, p.i)?;
                formed = Normal::new(p.t.as_mat(), p.i);
                &formed
            }
        };
        let tol = p.req.tol.unwrap_or(TOL);
        check_tol(tol)?;
        let lambda = p.req.lambda.unwrap_or(LAMBDA_REL * normal.unit());
        check_lambda(lambda)?;
        let start = Instant::now();
        let n = p.t.cols();
        let g = symmetric(normal.lower());
        let lip = largest_eigenvalue(&g) * 1.01;
        let factor_seconds = start.elapsed().as_secs_f64();
        let mut warnings = Vec::new();
        if lip == 0.0 {
            warnings.push("T is all zero: no scene element lights the wall as the cameras see it; the result is the zero image".into());
        }
        let t1 = Instant::now();
        // The proximal step of `lambda/2 TV` at step `1/lip`.
        let mu = if lip > 0.0 { 0.5 * lambda / lip } else { 0.0 };
        let mut dual = Dual::new(p.t.scene_grid(), p.upper);
        let (mut l, mut v) = (vec![0.0; n], vec![0.0; n]);
        let (mut lm, mut gl) = (Mat::<f64>::zeros(n, 1), Mat::<f64>::zeros(n, 1));
        let max_iter = p.max_iter(MAX_ITER);
        let (mut iterations, mut converged, mut change) = (0, lip == 0.0, f64::INFINITY);
        while !converged && iterations < max_iter {
            p.stop.check(iterations)?;
            iterations += 1;
            for k in 0..n {
                lm[(k, 0)] = l[k];
            }
            faer::linalg::matmul::matmul(
                gl.as_mut(),
                faer::Accum::Replace,
                g.as_ref(),
                lm.as_ref(),
                1.0,
                faer::Par::Seq,
            );
            for k in 0..n {
                v[k] = l[k] - (gl[(k, 0)] - normal.ti[k]) / lip;
            }
            let (d2, l2) = dual.prox(&v, mu, &mut l);
            change = d2.sqrt() / l2.sqrt().max(1e-12);
            converged = change <= tol;
        }
        if !converged {
            warnings.push(format!(
                "GP-TV stopped at the iteration cap ({iterations}) before meeting tol = {tol}: relative change {change:.3e}; raise max_iter or tol (\"max_iter\" / \"tol\" in a request, --max-iter / --tol on the command line)"
            ));
        }
        let iterate_seconds = t1.elapsed().as_secs_f64();
        let (misfit, objective) = objective_of(p.t, p.i, &l, lambda);
        Ok(Reconstruction {
            image: l,
            stats: SolveStats {
                solver: self.name().into(),
                lambda: Some(lambda),
                iterations,
                converged,
                primal_residual: Some(change),
                objective,
                data_misfit: misfit,
                gram_seconds: normal.seconds,
                factor_seconds,
                iterate_seconds,
                total_seconds: normal.seconds + start.elapsed().as_secs_f64(),
                warnings,
                ..SolveStats::default()
            },
        })
    }
}

/// The TV dual of the proximal step, kept from one outer iteration to the next.
struct Dual {
    grid: Grid,
    upper: f64,
    /// `2n`: the dual field, each pair in the unit disk.
    q: Vec<f64>,
    /// `2n`: gradient scratch.
    g: Vec<f64>,
    /// `n`: primal scratch.
    x: Vec<f64>,
}

impl Dual {
    fn new(grid: Grid, upper: f64) -> Self {
        let n = grid.count();
        Self {
            grid,
            upper,
            q: vec![0.0; 2 * n],
            g: vec![0.0; 2 * n],
            x: vec![0.0; n],
        }
    }

    /// `x = P_box(b - mu D^T q)`.
    fn primal(&mut self, b: &[f64], mu: f64) {
        self.x.fill(0.0);
        add_divergence_adjoint(self.grid, &self.q, &mut self.x);
        for (x, b) in self.x.iter_mut().zip(b) {
            *x = (b - mu * *x).clamp(0.0, self.upper);
        }
    }

    /// `l = argmin_x 1/2 ||x - b||^2 + mu TV(x)` on the box by [`INNER`]
    /// projected gradient steps on the dual (step `1/8mu`, `8` bounding
    /// `||D||^2`); returns `||l - l_before||^2` and `||l||^2`.
    fn prox(&mut self, b: &[f64], mu: f64, l: &mut [f64]) -> (f64, f64) {
        let n = self.grid.count();
        if mu > 0.0 {
            let step = 1.0 / (8.0 * mu);
            for _ in 0..INNER {
                self.primal(b, mu);
                gradient(self.grid, &self.x, &mut self.g);
                for j in 0..n {
                    let (a, c) = (
                        self.q[j] + step * self.g[j],
                        self.q[n + j] + step * self.g[n + j],
                    );
                    let m = a.hypot(c).max(1.0);
                    self.q[j] = a / m;
                    self.q[n + j] = c / m;
                }
            }
        }
        self.primal(b, mu);
        let (mut d2, mut l2) = (0.0, 0.0);
        for (lk, xk) in l.iter_mut().zip(&self.x) {
            d2 += (xk - *lk).powi(2);
            l2 += xk * xk;
            *lk = *xk;
        }
        (d2, l2)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::solve::solvers::{SolveRequest, Solver};
    use crate::solve::tv::total_variation;
    use crate::transport::{Block, Transport};

    /// A blurred 8x8 scene: neighbours mix, so TV matters.
    fn blur() -> (Transport, Vec<f64>) {
        let grid = Grid { nu: 8, nv: 8 };
        let n = grid.count();
        let mut data = vec![0.0; n * n];
        for c in 0..n {
            let (u, v) = (c % 8, c / 8);
            for r in 0..n {
                let (a, b) = (r % 8, r / 8);
                let d2 = (u.abs_diff(a).pow(2) + v.abs_diff(b).pow(2)) as f64;
                data[c * n + r] = (-d2 / 2.0).exp();
            }
        }
        let block = Block {
            pose: "A".into(),
            channel: crate::scene::Channel::None,
        };
        let t = Transport::from_col_major(n, n, data, vec![block], Grid { nu: n, nv: 1 }, grid);
        let l: Vec<f64> = (0..n)
            .map(|c| {
                if (2..6).contains(&(c % 8)) && (2..6).contains(&(c / 8)) {
                    0.9
                } else {
                    0.1
                }
            })
            .collect();
        (t, l)
    }

    #[test]
    fn gp_tv_reaches_admm_tv_s_minimum() {
        // The same objective: GP-TV's value at its end is within 1e-4 of
        // ADMM-TV's converged one, and its TV is no larger than the truth's
        // blurred measurement would give without regularization.
        let (t, truth) = blur();
        let i: Vec<f64> = {
            let mut i = vec![0.0; t.rows()];
            for (c, l) in truth.iter().enumerate() {
                for (r, v) in t.col(c).iter().enumerate() {
                    i[r] += v * l;
                }
            }
            i.iter()
                .enumerate()
                .map(|(k, v)| v + 0.02 * ((k * 7 % 5) as f64 - 2.0))
                .collect()
        };
        let run = |solver: Solver, max_iter| {
            solver
                .run(&Problem::new(
                    &t,
                    &i,
                    SolveRequest {
                        solver,
                        lambda: Some(0.05),
                        max_iter: Some(max_iter),
                        tol: Some(1e-9),
                        ..Default::default()
                    },
                ))
                .unwrap()
        };
        let gp = run(Solver::named("gp-tv").unwrap(), 20000);
        let admm = run(Solver::ADMM_TV, 20000);
        assert_eq!(gp.stats.solver, "gp-tv");
        let rel = (gp.stats.objective - admm.stats.objective) / admm.stats.objective;
        assert!(
            rel.abs() < 1e-4,
            "gp {} admm {}",
            gp.stats.objective,
            admm.stats.objective
        );
        assert!(gp.image.iter().all(|v| (0.0..=1.0).contains(v)));
        let grid = t.scene_grid();
        assert!(total_variation(grid, &gp.image) < total_variation(grid, &truth) * 1.5);
        // Fewer iterations leave a larger objective: each step lowers it.
        assert!(run(Solver::named("gp-tv").unwrap(), 5).stats.objective > gp.stats.objective);
    }
}
