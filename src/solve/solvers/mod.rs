//! The solvers polnlos offers, one file each, and the one door every solve
//! goes through: a [`Solver`] is a registered `Method`, asked what it
//! needs ([`Needs`]) and run on a [`Problem`] with [`Solver::run`] (or
//! `Solver::solve` from a kept `Warm` state).
//!
//! Why one door: the automatic λ, the daemon's progressive and live steps,
//! the photo fit and the bench all solve through it, so a new solver is
//! picked up by each of them, by the CLI's `--solver`, the API's `solver`
//! enum (and so the page's list and Python), and by the suite's
//! every-solver tests, with no list to update.
//!
//! A new solver: its file here (a unit struct implementing `Method`) and
//! one line in [`Solver::ALL`]. A parameter of its own: a field of
//! [`SolveRequest`], read in its `Method::solve`.

mod admm;
mod baseline;
mod fista;
mod gradient_projection;
mod request;

use std::any::Any;
use std::borrow::Cow;

use super::gram::Normal;
use super::{Reconstruction, SolveError};
use crate::stop::Stop;
use crate::transport::Transport;

pub use admm::{admm_tv, admm_tv_prepared, AdmmSettings, LAMBDA_REL};
pub use baseline::{least_squares, tikhonov};
#[cfg(feature = "report")]
pub use fista::tv_denoise;
pub use fista::FistaSettings;
pub(crate) use fista::{largest_eigenvalue, symmetric};
pub use request::SolveRequest;

/// Iteration cap of an automatic-λ solve unless the request sets one: small
/// λs (low noise) converge slowly.
pub const AUTO_MAX_ITER: usize = 5000;

/// One solver: its name, what it needs and how it solves.
///
/// Why a trait: a solver is one file implementing it plus its line in
/// [`Solver::ALL`]; everything else (names, help, schema, the λ rule, warm
/// starts) is read from here.
pub(crate) trait Method: Sync {
    /// The name in files, requests and `--solver` (`admm-tv`, ...).
    fn name(&self) -> &'static str;
    /// One line for `--help` and the API document.
    fn about(&self) -> &'static str;
    /// What the caller should form for it.
    fn needs(&self) -> Needs;
    /// Solves `p` (MODEL.md Eq. 12 for the TV solvers), starting from
    /// `warm` and leaving its state there when it keeps one
    /// ([`Needs::warm_start`]; other solvers ignore it).
    fn solve(&self, p: &Problem<'_>, warm: Option<&mut Warm>)
        -> Result<Reconstruction, SolveError>;
    /// Solves the colours of one `T` together (each `(i, normal)`, every
    /// normal on one Gram; `p` gives `T`, the request, the box and the
    /// stop flag), from `warm`; `None` when this solver solves one image at
    /// a time.
    #[cfg(feature = "daemon")]
    fn solve_colours(
        &self,
        _p: &Problem<'_>,
        _colours: &[(&[f64], &Normal)],
        _warm: Option<&mut Warm>,
    ) -> Option<Result<Vec<Reconstruction>, SolveError>> {
        None
    }
}

/// A registered solver: a small copyable handle on its `Method`.
#[derive(Clone, Copy)]
pub struct Solver(&'static dyn Method);

impl Solver {
    /// Every solver, in the order the CLI and the API list them; the first
    /// is the default. Registering a solver is adding its line here.
    pub const ALL: &'static [Solver] = &[
        Solver::ADMM_TV,
        Solver::FISTA_TV,
        Solver(&gradient_projection::GpTv),
        Solver::TIKHONOV,
        Solver::LSQ,
    ];
    /// ADMM with isotropic TV and the box (the default).
    pub const ADMM_TV: Solver = Solver(&admm::AdmmTv);
    /// FISTA with a TV proximal step and the box.
    pub const FISTA_TV: Solver = Solver(&fista::FistaTv);
    /// Tikhonov (ridge), clipped to the box.
    pub const TIKHONOV: Solver = Solver(&baseline::Tikhonov);
    /// The (truncated) pseudo-inverse, clipped to the box.
    pub const LSQ: Solver = Solver(&baseline::Lsq);

    /// The name in files and requests (`admm-tv`, ...).
    pub fn name(self) -> &'static str {
        self.0.name()
    }

    /// One line on what it is.
    pub fn about(self) -> &'static str {
        self.0.about()
    }

    /// What this solver needs from its caller.
    pub fn needs(self) -> Needs {
        self.0.needs()
    }

    /// The solver named `name`, if one is.
    pub fn named(name: &str) -> Option<Solver> {
        Solver::ALL.iter().copied().find(|s| s.name() == name)
    }

    /// Every solver's name, in [`Solver::ALL`]'s order: what the API's enum,
    /// serde's "expected one of" and messages list.
    pub fn names() -> &'static [&'static str] {
        static NAMES: std::sync::OnceLock<Vec<&'static str>> = std::sync::OnceLock::new();
        NAMES.get_or_init(|| Solver::ALL.iter().map(|s| s.name()).collect())
    }

    /// Solves `p` from a cold start.
    pub fn run(self, p: &Problem<'_>) -> Result<Reconstruction, SolveError> {
        self.0.solve(p, None)
    }

    /// Solves `p` starting from `warm` (a previous solve of this solver on
    /// the same `T`), and leaves the result's state there.
    /// Why: a λ search, a progressive step or a live window is a sequence
    /// of close problems; a solver that keeps its factor and iterate pays
    /// neither again.
    pub(crate) fn solve(
        self,
        p: &Problem<'_>,
        warm: &mut Warm,
    ) -> Result<Reconstruction, SolveError> {
        self.0.solve(p, Some(warm))
    }

    /// Solves a colour camera's colours of one `T` together (`colours`: each
    /// colour's measurement and normal equations, on one Gram; `p`: `T`,
    /// the request, the box and the stop flag), from `warm` when given;
    /// `None` when this solver solves one image at a time.
    /// Why: calibrated colours share their edges; ADMM-TV's colour TV pays
    /// for an edge once for every colour that has it.
    #[cfg(feature = "daemon")]
    pub(crate) fn solve_colours(
        self,
        p: &Problem<'_>,
        colours: &[(&[f64], &Normal)],
        warm: Option<&mut Warm>,
    ) -> Option<Result<Vec<Reconstruction>, SolveError>> {
        self.0.solve_colours(p, colours, warm)
    }

    /// The solver that searches this one's automatic λ: itself when it
    /// keeps a warm start, else ADMM-TV.
    /// Why: every solver that takes λ from the noise minimizes the same
    /// TV-and-box objective (MODEL.md Eq. 12), so ADMM's warm λ path
    /// chooses the λ for one that would cold-start each of its ~20 trials.
    pub(crate) fn lambda_searcher(self) -> Solver {
        if self.needs().warm_start {
            self
        } else {
            Solver::ADMM_TV
        }
    }
}

impl Default for Solver {
    fn default() -> Self {
        Solver::ALL[0]
    }
}

/// Two handles are equal when they name the same solver.
impl PartialEq for Solver {
    fn eq(&self, other: &Self) -> bool {
        self.name() == other.name()
    }
}

impl Eq for Solver {}

impl std::fmt::Debug for Solver {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

impl serde::Serialize for Solver {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        s.serialize_str(self.name())
    }
}

impl<'de> serde::Deserialize<'de> for Solver {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        let name = <Cow<'de, str>>::deserialize(d)?;
        Solver::named(&name)
            .ok_or_else(|| serde::de::Error::unknown_variant(&name, Solver::names()))
    }
}

impl clap::ValueEnum for Solver {
    fn value_variants<'a>() -> &'a [Self] {
        Solver::ALL
    }

    fn to_possible_value(&self) -> Option<clap::builder::PossibleValue> {
        Some(clap::builder::PossibleValue::new(self.name()).help(self.about()))
    }
}

impl utoipa::PartialSchema for Solver {
    fn schema() -> utoipa::openapi::RefOr<utoipa::openapi::schema::Schema> {
        let about: Vec<String> = Solver::ALL
            .iter()
            .map(|s| format!("`{}`: {}", s.name(), s.about()))
            .collect();
        utoipa::openapi::schema::ObjectBuilder::new()
            .schema_type(utoipa::openapi::schema::Type::String)
            .enum_values(Some(Solver::names().iter().copied()))
            .description(Some(format!(
                "The solvers polnlos offers. {}",
                about.join("; ")
            )))
            .into()
    }
}

impl utoipa::ToSchema for Solver {
    fn name() -> Cow<'static, str> {
        Cow::Borrowed("Solver")
    }
}

/// What a solver needs from its caller, so that a caller forms only that.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Needs {
    /// `T^T T` and `T^T i` ([`Normal`]): a caller that has the Gram (the
    /// daemon caches one per scene) hands it over instead of a second one.
    pub gram: bool,
    /// A TV weight, chosen from the noise when the request gives none
    /// (the resolved-discrepancy rule, searched by
    /// `Solver::lambda_searcher`); without, λ is the solver's own default
    /// or unused.
    pub lambda_from_noise: bool,
    /// Whether it continues from a previous solution kept in a `Warm`
    /// (`Solver::solve`): the λ search, the daemon's progressive steps
    /// and live view use it.
    pub warm_start: bool,
}

/// One problem for a solver: `T`, the measurement, the Gram when the solver
/// needs it, the λ chosen (given or from the noise) and the request.
#[derive(Clone, Copy)]
pub struct Problem<'a> {
    /// The transport matrix.
    pub t: &'a Transport,
    /// The measurement, one value per row of `t`.
    pub i: &'a [f64],
    /// `T^T T` and `T^T i` of `t` and `i`, when [`Needs::gram`] (else formed here).
    pub normal: Option<&'a Normal>,
    /// The request: the solver, the TV or ridge weight to use (`lambda`,
    /// None: the solver's default), iteration cap, tolerance, rcond, rho.
    pub req: SolveRequest,
    /// Whether λ was chosen automatically (a larger iteration cap).
    pub auto: bool,
    /// Upper bound of the box `0 <= l <= upper`: 1 for radiance in MODEL.md
    /// units; infinite when the gain is unknown (a photo, docs/realphoto.md).
    pub upper: f64,
    /// Raised by another thread to stop an iterative solver.
    pub stop: Stop<'a>,
}

impl<'a> Problem<'a> {
    /// `req` on `i` of `t` at its own λ, in MODEL.md units (box `[0, 1]`),
    /// from a cold start's iteration cap.
    pub fn new(t: &'a Transport, i: &'a [f64], req: SolveRequest) -> Self {
        Problem {
            t,
            i,
            normal: None,
            req,
            auto: false,
            upper: 1.0,
            stop: Stop::default(),
        }
    }

    /// The iteration cap: the request's, else `default` (or
    /// [`AUTO_MAX_ITER`] with an automatic λ).
    pub(crate) fn max_iter(&self, default: usize) -> usize {
        self.req
            .max_iter
            .unwrap_or(if self.auto { AUTO_MAX_ITER } else { default })
    }
}

/// A solver's state between solves of close problems (its iterate, and its
/// factorization while `T` and the penalty hold), opaque to the caller.
#[derive(Default)]
pub(crate) struct Warm(Option<Box<dyn WarmState>>);

/// What a solver keeps in a `Warm`.
pub(crate) trait WarmState: Any + Send + Sync {
    /// A copy of the iterate without the factorization (a point of a λ path).
    fn iterate(&self) -> Box<dyn WarmState>;
    /// A whole copy, factorization included (independent replicas of one fit).
    fn clone_box(&self) -> Box<dyn WarmState>;
    /// Starts the next solve from `from`'s iterate, keeping this state's
    /// factorization, for a TV weight `tv_ratio` times `from`'s.
    fn start_from(&mut self, from: &dyn WarmState, tv_ratio: f64);
    /// For the solver that owns it.
    fn as_any(&self) -> &dyn Any;
    /// For the solver that owns it.
    fn as_any_mut(&mut self) -> &mut dyn Any;
}

impl Clone for Warm {
    fn clone(&self) -> Self {
        Warm(self.0.as_deref().map(|s| s.clone_box()))
    }
}

impl Warm {
    /// A copy of the iterate without the factorization.
    pub(crate) fn iterate(&self) -> Warm {
        Warm(self.0.as_deref().map(|s| s.iterate()))
    }

    /// Starts the next solve from `from`'s iterate at `tv_ratio` times its
    /// TV weight (nothing when either is empty).
    pub(crate) fn start_from(&mut self, from: &Warm, tv_ratio: f64) {
        if let (Some(s), Some(f)) = (self.0.as_deref_mut(), from.0.as_deref()) {
            s.start_from(f, tv_ratio);
        }
    }

    /// The state of type `S`, a new one when this holds none or another
    /// solver's.
    pub(crate) fn state<S: WarmState + Default>(&mut self) -> &mut S {
        if !self.0.as_deref().is_some_and(|s| s.as_any().is::<S>()) {
            self.0 = Some(Box::new(S::default()));
        }
        self.0
            .as_deref_mut()
            .and_then(|s| s.as_any_mut().downcast_mut::<S>())
            .expect("the state was just made of this type")
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
        for &s in Solver::ALL {
            for gram in [false, true] {
                let p = Problem {
                    normal: (gram && s.needs().gram).then_some(&normal),
                    ..Problem::new(
                        &t,
                        &i,
                        SolveRequest {
                            solver: s,
                            lambda: Some(1e-9),
                            ..req
                        },
                    )
                };
                let r = s.run(&p).unwrap();
                assert_eq!(r.stats.solver, s.name());
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
    fn a_warm_solver_continues_where_it_stopped() {
        // Ten iterations, then ten more from the kept state, equal twenty
        // from cold for every solver that keeps one.
        let t = doubling();
        let i: Vec<f64> = (0..16).map(|k| 0.1 + 0.1 * (k % 5) as f64).collect();
        for &s in Solver::ALL.iter().filter(|s| s.needs().warm_start) {
            let at = |n| {
                Problem::new(
                    &t,
                    &i,
                    SolveRequest {
                        solver: s,
                        lambda: Some(1e-2),
                        max_iter: Some(n),
                        tol: Some(1e-15),
                        rho: Some(1.0),
                        ..Default::default()
                    },
                )
            };
            let mut warm = Warm::default();
            s.solve(&at(10), &mut warm).unwrap();
            let twice = s.solve(&at(10), &mut warm).unwrap();
            let once = s.run(&at(20)).unwrap();
            let gap = twice
                .image
                .iter()
                .zip(&once.image)
                .map(|(a, b)| (a - b).abs())
                .fold(0.0, f64::max);
            assert!(gap < 1e-12, "{}: {gap}", s.name());
        }
    }

    #[test]
    fn names_are_the_json_and_command_line_names() {
        for &s in Solver::ALL {
            assert_eq!(serde_json::to_value(s).unwrap(), s.name());
            assert_eq!(
                serde_json::from_value::<Solver>(serde_json::json!(s.name())).unwrap(),
                s
            );
            assert_eq!(
                <Solver as clap::ValueEnum>::from_str(s.name(), false).unwrap(),
                s
            );
            assert!(!s.about().is_empty());
        }
        let err = serde_json::from_value::<Solver>(serde_json::json!("cg")).unwrap_err();
        assert!(err.to_string().contains("gp-tv"), "{err}");
        assert_eq!(Solver::default(), Solver::ADMM_TV);
    }

    #[test]
    fn what_each_solver_needs() {
        // Only ADMM-TV uses T^T T and a warm start; the TV solvers take λ
        // from the noise, searched by ADMM-TV's warm path.
        let with = |f: fn(Needs) -> bool| -> Vec<&str> {
            Solver::ALL
                .iter()
                .filter(|s| f(s.needs()))
                .map(|s| s.name())
                .collect()
        };
        assert_eq!(with(|n| n.gram), ["admm-tv"]);
        assert_eq!(with(|n| n.warm_start), ["admm-tv"]);
        assert_eq!(
            with(|n| n.lambda_from_noise),
            ["admm-tv", "fista-tv", "gp-tv"]
        );
        assert!(Solver::ALL
            .iter()
            .all(|s| s.lambda_searcher() == Solver::ADMM_TV));
    }
}
