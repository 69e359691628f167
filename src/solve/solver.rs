//! The solvers polnlos offers, what each needs, the request that picks one
//! and its parameters, and running it: the one place a solver is declared. [`super::reconstruct()`] (the CLI, the daemon,
//! the bench) asks a [`Solver`] what it needs (`T^T T`, a TV weight chosen
//! from the noise, a warm start) and runs it through [`Solver::run`]; the
//! API's `solver` enum, and so the page's list, is this type's.
//!
//! A new solver: its file in `src/solve/`, and here a variant, its name,
//! its [`Needs`] and its arm of [`Solver::run`]. A parameter of its own: a
//! field of [`SolveRequest`] (the API's bodies, the stored parameters and
//! the CLI's flags embed that struct), read in its arm of [`Solver::run`].

use serde::{Deserialize, Serialize};

use super::gram::Normal;
use super::{
    admm::admm_tv_prepared, admm_tv, fista_tv, least_squares, tikhonov, AdmmSettings,
    FistaSettings, Reconstruction, SolveError, Stop,
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

/// What to solve with: the solver and its parameters, declared here once.
///
/// Every front end embeds this struct rather than restating its fields:
/// the daemon's `POST /reconstructions` body and a plan's `reconstruct`
/// (`#[serde(flatten)]`, so the keys sit in the body itself), the stored
/// parameters of a reconstruction (`ReconstructionParams`), and the CLI's
/// `reconstruct` (`#[command(flatten)]`: each field's `help` is its flag's
/// text, its doc comment the API's). A solver's new parameter is a field
/// here, read by that solver's arm of [`Solver::run`].
///
/// The one exception is the CLI's `--lambda`, which also takes `auto` and
/// goes with `--noise-from` and `--variance`: it stays in the CLI's
/// arguments (`src/cli/reconstruct.rs`) and fills `lambda`.
#[derive(
    Debug, Clone, Default, PartialEq, Serialize, Deserialize, utoipa::ToSchema, clap::Args,
)]
pub struct SolveRequest {
    /// `admm-tv` (default), `fista-tv`, `tikhonov` or `lsq`.
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

/// What a solver needs from its caller, so that a caller forms only that.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Needs {
    /// `T^T T` and `T^T i` ([`Normal`]): a caller that has the Gram (the
    /// daemon caches one per scene) hands it over instead of a second one.
    pub gram: bool,
    /// A TV weight, chosen from the noise when the request gives none
    /// (the resolved-discrepancy rule); without, λ is the solver's own
    /// default or unused.
    pub lambda_from_noise: bool,
    /// Whether it can continue from a previous solution with its
    /// factorization kept (the daemon's progressive steps use it).
    pub warm_start: bool,
}

/// One problem for [`Solver::run`]: `T`, the measurement, the Gram when the
/// solver needs it, the λ chosen (given or from the noise) and the request.
pub struct Problem<'a> {
    /// The transport matrix.
    pub t: &'a Transport,
    /// The measurement, one value per row of `t`.
    pub i: &'a [f64],
    /// `T^T T` and `T^T i` of `t` and `i`, when [`Needs::gram`] (else formed here).
    pub normal: Option<&'a Normal>,
    /// The TV or ridge weight to use (None: the solver's default).
    pub lambda: Option<f64>,
    /// The request (iteration cap, tolerance, rcond, rho).
    pub req: &'a SolveRequest,
    /// Whether λ was chosen automatically (a larger iteration cap).
    pub auto: bool,
    /// Raised by another thread to stop an iterative solver.
    pub stop: Stop<'a>,
}

impl Solver {
    /// Every solver, in the order the CLI and the API list them.
    pub const ALL: [Solver; 4] = [
        Solver::AdmmTv,
        Solver::FistaTv,
        Solver::Tikhonov,
        Solver::Lsq,
    ];

    /// What this solver needs from its caller.
    pub fn needs(self) -> Needs {
        match self {
            Solver::AdmmTv => Needs {
                gram: true,
                lambda_from_noise: true,
                warm_start: true,
            },
            Solver::FistaTv => Needs {
                gram: false,
                lambda_from_noise: true,
                warm_start: false,
            },
            Solver::Tikhonov | Solver::Lsq => Needs {
                gram: false,
                lambda_from_noise: false,
                warm_start: false,
            },
        }
    }

    /// Solves `p` with this solver (MODEL.md Eq. 12 for the TV solvers).
    pub fn run(self, p: &Problem<'_>) -> Result<Reconstruction, SolveError> {
        let (req, auto) = (p.req, p.auto);
        match self {
            Solver::AdmmTv => {
                let settings = AdmmSettings {
                    lambda: p.lambda,
                    ..req.admm(auto, p.stop)
                };
                match p.normal {
                    Some(nm) => admm_tv_prepared(p.t, p.i, nm, &settings),
                    None => admm_tv(p.t, p.i, &settings),
                }
            }
            Solver::FistaTv => {
                let d = FistaSettings::default();
                fista_tv(
                    p.t,
                    p.i,
                    &FistaSettings {
                        lambda: p.lambda,
                        max_iter: req.max_iter.unwrap_or(if auto {
                            AUTO_MAX_ITER
                        } else {
                            d.max_iter
                        }),
                        tol: req.tol.unwrap_or(d.tol),
                        stop: p.stop,
                        ..d
                    },
                )
            }
            Solver::Tikhonov => tikhonov(p.t, p.i, p.lambda),
            Solver::Lsq => least_squares(p.t, p.i, req.rcond),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scene::Grid;

    /// 2x the identity on a 4x4 grid: every solver recovers `i / 2`.
    fn doubling() -> Transport {
        let grid = Grid { nu: 4, nv: 4 };
        let n = grid.count();
        let mut data = vec![0.0; n * n];
        for k in 0..n {
            data[k * n + k] = 2.0;
        }
        let block = crate::transport::Block {
            pose: "A".into(),
            channel: crate::scene::Channel::None,
        };
        Transport::from_col_major(n, n, data, vec![block], Grid { nu: n, nv: 1 }, grid)
    }

    #[test]
    fn every_solver_runs_through_one_door_with_or_without_the_gram() {
        let t = doubling();
        let l: Vec<f64> = (0..16).map(|k| 0.2 + 0.04 * k as f64).collect();
        let i: Vec<f64> = l.iter().map(|v| 2.0 * v).collect();
        let normal = Normal::of(&t, &i);
        let req = SolveRequest {
            tol: Some(1e-8),
            max_iter: Some(5000),
            ..Default::default()
        };
        for s in Solver::ALL {
            for gram in [false, true] {
                let p = Problem {
                    t: &t,
                    i: &i,
                    normal: (gram && s.needs().gram).then_some(&normal),
                    lambda: Some(1e-9),
                    req: &SolveRequest {
                        solver: s,
                        ..req.clone()
                    },
                    auto: false,
                    stop: Stop::default(),
                };
                let r = s.run(&p).unwrap();
                let err = r
                    .image
                    .iter()
                    .zip(&l)
                    .map(|(a, b)| (a - b).abs())
                    .fold(0.0, f64::max);
                assert!(err < 1e-3, "{}: largest error {err}", s.name());
            }
        }
    }

    #[test]
    fn what_each_solver_needs() {
        // Only ADMM-TV uses T^T T and a warm start; the TV solvers take λ from the noise.
        let gram: Vec<&str> = Solver::ALL
            .iter()
            .filter(|s| s.needs().gram)
            .map(|s| s.name())
            .collect();
        assert_eq!(gram, ["admm-tv"]);
        let tv: Vec<&str> = Solver::ALL
            .iter()
            .filter(|s| s.needs().lambda_from_noise)
            .map(|s| s.name())
            .collect();
        assert_eq!(tv, ["admm-tv", "fista-tv"]);
        assert!(Solver::ALL
            .iter()
            .all(|s| s.needs().warm_start == (*s == Solver::AdmmTv)));
    }
}
