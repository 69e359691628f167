//! GP-TV: proximal gradient (ISTA) on MODEL.md Eq. 12's objective,
//! `1/2 ||i - T l||^2 + lambda/2 TV(l)` on the box, whose TV-and-box
//! proximal step is Chambolle's dual gradient projection (Beck & Teboulle
//! 2009, "GP"): the plainest first-order TV solver, FISTA's loop
//! ([`super::fista`]) without momentum on either level.
//!
//! Why kept: a reference that is easy to check by hand (each step lowers
//! the objective), and the solver that shows a new one is this file and its
//! line in [`super::Solver::ALL`].

use super::fista::{proximal_gradient, FistaSettings, Variant};
use super::{Method, Needs, Problem, Warm};
use crate::solve::gram::Normal;
use crate::solve::{check_measurement, Reconstruction, SolveError};

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
        let settings = FistaSettings {
            lambda: p.req.lambda,
            max_iter: p.max_iter(MAX_ITER),
            tol: p.req.tol.unwrap_or(TOL),
            inner: INNER,
            stop: p.stop,
        };
        let variant = Variant {
            name: self.name(),
            label: "GP-TV",
            momentum: false,
            upper: p.upper,
        };
        proximal_gradient(p.t, p.i, normal, &settings, &variant)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scene::Grid;
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
