//! The bench's geometry fitted to its own photos: the occluders' place, the
//! hidden plane's offset in its plane, the wall-to-scene distance (and, when
//! asked, the occluders' turn and the wall's field of view), with an
//! uncertainty that includes the model's error.
//!
//! Why: a tape measure gives a bench to a centimetre, and one centimetre of
//! occluder or field of view costs a real photo 0.1-0.2 ZNCC
//! (docs/realphoto.md, "Fitting the geometry"). By variable projection the
//! hidden image (or a known image's gain) and the photo's background are
//! eliminated at each geometry (the data term of differences), and
//! Levenberg-Marquardt descends the residual on a coarse wall first, then on
//! the full one, with `T` built with area shadows (smooth in the geometry).

mod fit;
mod place;
mod search;

pub use place::{Freedom, Placement};

use crate::optics::Vec3;
use crate::scene::{Scene, SceneError, ShadowModel};
use crate::solve::photo::difference_residuals;
use crate::solve::SolveError;
use crate::stop::Stop;
use crate::transport::{build_with_progress, MemoryBudget, TransportError};

/// Why the geometry could not be fitted.
#[derive(Debug, thiserror::Error)]
pub enum SceneFitError {
    /// No photo was given.
    #[error("no photo (measurement) was given")]
    NoPhotos,
    /// A photo has no colour channel.
    #[error("photo {photo} has no channel")]
    NoChannels {
        /// Photo index, in the order given.
        photo: usize,
    },
    /// A channel does not have one value per row of the scene's `T`.
    #[error("photo {photo} channel {channel} has {got} values but the scene's T has {rows} rows (wall elements x blocks): was the photo taken of another scene?")]
    Rows {
        /// Photo index.
        photo: usize,
        /// Channel index.
        channel: usize,
        /// Values given.
        got: usize,
        /// Rows of `T`.
        rows: usize,
    },
    /// A known image does not fit its photo or the scene's grid.
    #[error("photo {photo}'s known image has {got} {what}, the photo needs {want}: give one image per colour channel on the scene's grid")]
    Known {
        /// Photo index.
        photo: usize,
        /// What was counted (channels, or cells of a channel).
        what: &'static str,
        /// Count given.
        got: usize,
        /// Count needed.
        want: usize,
    },
    /// Nothing to fit.
    #[error("no freedom to fit: name at least one (occluder-x, occluder-y, occluder-z, scene-u, scene-v, distance, occluder-yaw, wall-u, wall-v)")]
    NothingFree,
    /// A freedom of the occluders on a scene without occluders.
    #[error("{0} moves the occluders, and the scene has none selected: leave it out of --free")]
    NoOccluders(&'static str),
    /// An option is out of range.
    #[error("{name} = {value}: {reason}")]
    Parameter {
        /// Option name, as on the command line.
        name: &'static str,
        /// Given value.
        value: f64,
        /// What it must be.
        reason: &'static str,
    },
    /// The occluder selection is wrong.
    #[error(transparent)]
    Selection(#[from] crate::calibrate::occluder::OccluderError),
    /// A mesh path cannot be written for the placed file's folder.
    #[error(transparent)]
    MeshPath(#[from] crate::calibrate::scene_text::MeshPathError),
    /// The scene at a trial geometry does not validate.
    #[error("the scene with its geometry moved: {0}")]
    Scene(#[from] SceneError),
    /// `T` could not be built.
    #[error(transparent)]
    Transport(#[from] TransportError),
    /// The photo's fit failed.
    #[error(transparent)]
    Solve(#[from] SolveError),
    /// The fit was stopped before its end.
    #[error("the geometry fit was stopped")]
    Stopped,
    /// The scene file's text is not TOML.
    #[error("the scene file is not TOML: {0}")]
    Toml(#[source] toml_edit::TomlError),
    /// A table the placed geometry is written into is missing.
    #[error("the scene file has no [{0}] to write the fitted geometry into")]
    Missing(&'static str),
    /// A mesh occluder cannot be turned in its file (its entry has no rotation).
    #[error("occluder {0} is a mesh, whose file entry has no rotation: fit without occluder-yaw")]
    TurnedMesh(usize),
}

/// One photo of the bench: its channels in `T`'s row order and, for a
/// calibration shot, the image the hidden monitor showed (one per channel,
/// on the scene's grid in its element order), whose gain is fitted.
#[derive(Debug, Clone, Default)]
pub struct Shot {
    /// The photo's channels, one value per row of `T` each.
    pub channels: Vec<Vec<f64>>,
    /// The known image per channel; `None`: the scene is unknown and fitted.
    pub known: Option<Vec<Vec<f64>>>,
}

/// How the fit runs; `Default` gives the documented defaults
/// ([`SceneFitOptions::fit`] runs it).
#[derive(Debug, Clone)]
pub struct SceneFitOptions {
    /// What is fitted, in any order ([`Freedom::DEFAULT`] by default).
    pub free: Vec<Freedom>,
    /// Largest offset of a length from the file's value, metres.
    pub range: f64,
    /// Largest turn, degrees.
    pub range_deg: f64,
    /// Occluders that move together, by index; `None`: all.
    pub selected: Option<Vec<usize>>,
    /// The uncertainty: offsets whose misfit (the others refitted) stays
    /// within this fraction of the lowest.
    pub tolerance: f64,
    /// The coarse level's wall is this many times coarser per axis; `None`:
    /// about 40 elements on its shorter side; 1: no coarse level.
    pub coarse: Option<usize>,
    /// `T` builds the fit's search may spend, both levels together (and
    /// then one Jacobian at its end, for the uncertainty, when the search
    /// left none there).
    pub max_evaluations: usize,
    /// Memory budget of each `T`.
    pub budget: MemoryBudget,
}

/// Default [`SceneFitOptions::range`]: a tape measure's error, three times.
pub(super) const RANGE: f64 = 0.03;
/// Default [`SceneFitOptions::range_deg`].
pub(super) const RANGE_DEG: f64 = 5.0;
/// Default [`SceneFitOptions::tolerance`].
pub(super) const TOLERANCE: f64 = 0.01;
/// Default [`SceneFitOptions::max_evaluations`].
pub(super) const MAX_EVALUATIONS: usize = 80;
/// Correlation above which two fitted freedoms are reported as not told apart.
pub(super) const CONFOUNDED: f64 = 0.95;

impl Default for SceneFitOptions {
    fn default() -> Self {
        Self {
            free: Freedom::DEFAULT.to_vec(),
            range: RANGE,
            range_deg: RANGE_DEG,
            selected: None,
            tolerance: TOLERANCE,
            coarse: None,
            max_evaluations: MAX_EVALUATIONS,
            budget: MemoryBudget::default(),
        }
    }
}

/// How far a fit is: `T` builds done and what the search may spend (the
/// uncertainty's Jacobian at the end may add a few).
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
pub struct FitProgress {
    /// `T` builds done.
    pub builds: usize,
    /// Builds the search may spend.
    pub max_builds: usize,
}

/// One fitted freedom.
#[derive(Debug, Clone, Copy, serde::Serialize)]
pub struct Fitted {
    /// What was fitted.
    pub freedom: Freedom,
    /// Its offset from the file's value (metres or degrees).
    pub offset: f64,
    /// Half the span of offsets whose misfit, the other freedoms refitted,
    /// stays within the tolerance of the lowest (the quadratic model of the
    /// misfit at the end): the model's error included as the misfit shows it.
    pub uncertainty: f64,
    /// The standard deviation the residual's scatter alone gives (as if
    /// the residual were noise): a lower bound.
    pub sd_noise: f64,
}

/// Why a fit's result should be checked by other means.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
#[serde(tag = "kind", rename_all = "snake_case")]
pub enum SceneFitWarning {
    /// A freedom ended on its range's bound: the truth may lie beyond.
    OnBound {
        /// The freedom.
        freedom: Freedom,
    },
    /// The fit spent its evaluations before it settled.
    OutOfEvaluations {
        /// Evaluations spent.
        evaluations: usize,
    },
    /// Two freedoms move the photo alike: their sum or difference is
    /// fitted, not each.
    Confounded {
        /// One freedom.
        a: Freedom,
        /// The other.
        b: Freedom,
        /// Their correlation in the fit.
        correlation: f64,
    },
    /// The data do not pin a freedom within its range.
    Unconstrained {
        /// The freedom.
        freedom: Freedom,
    },
    /// The end has no Jacobian: no uncertainty could be given.
    NoUncertainty,
}

impl std::fmt::Display for SceneFitWarning {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            SceneFitWarning::OnBound { freedom } => write!(
                f,
                "{} ended on its range's bound: the bench may be further off (raise --range, or measure it again)",
                freedom.name()
            ),
            SceneFitWarning::OutOfEvaluations { evaluations } => write!(
                f,
                "the fit spent its {evaluations} T builds before it settled (raise --max-evaluations)"
            ),
            SceneFitWarning::Confounded { a, b, correlation } => write!(
                f,
                "{} and {} move the photo alike (correlation {correlation:+.3}): the photos cannot tell them apart; measure one and fit the other (--free)",
                a.name(),
                b.name()
            ),
            SceneFitWarning::Unconstrained { freedom } => write!(
                f,
                "the photos do not pin {} within its range: its value is a guess (measure it, and leave it out of --free)",
                freedom.name()
            ),
            SceneFitWarning::NoUncertainty => {
                write!(f, "the fit ended without a Jacobian at its end: no uncertainty")
            }
        }
    }
}

/// One level of the coarse-to-fine fit.
#[derive(Debug, Clone, Copy, serde::Serialize)]
pub struct Level {
    /// Wall elements per coarse element along each axis (1: the full wall).
    pub factor: usize,
    /// The misfit where the level started.
    pub misfit_start: f64,
    /// The misfit where it ended.
    pub misfit_end: f64,
    /// `T` builds spent.
    pub evaluations: usize,
    /// Where it ended.
    pub end: Placement,
    /// Wall-clock seconds.
    pub seconds: f64,
}

/// The fitted geometry.
#[derive(Debug, Clone, serde::Serialize)]
pub struct SceneFit {
    /// The offsets from the scene file (zero where not fitted).
    pub placement: Placement,
    /// Occluders moved, by index.
    pub selected: Vec<usize>,
    /// Each fitted freedom, in the order asked.
    pub fitted: Vec<Fitted>,
    /// The full wall's misfit at the file's geometry.
    pub misfit_as_written: f64,
    /// The full wall's misfit at the fitted one.
    pub misfit_fitted: f64,
    /// The levels, coarse first.
    pub levels: Vec<Level>,
    /// Warnings, each a reason to check the result.
    pub warnings: Vec<SceneFitWarning>,
    /// `T` builds spent in all.
    pub evaluations: usize,
    /// Wall-clock seconds.
    pub seconds: f64,
}

/// Checks the photos against the scene.
pub(super) fn check_shots(scene: &Scene, shots: &[Shot]) -> Result<(), SceneFitError> {
    if shots.is_empty() {
        return Err(SceneFitError::NoPhotos);
    }
    for (photo, s) in shots.iter().enumerate() {
        if s.channels.is_empty() {
            return Err(SceneFitError::NoChannels { photo });
        }
        for (channel, c) in s.channels.iter().enumerate() {
            if c.len() != scene.rows() {
                return Err(SceneFitError::Rows {
                    photo,
                    channel,
                    got: c.len(),
                    rows: scene.rows(),
                });
            }
        }
        if let Some(k) = &s.known {
            let bad = |what, got, want| SceneFitError::Known {
                photo,
                what,
                got,
                want,
            };
            if k.len() != s.channels.len() {
                return Err(bad("channels", k.len(), s.channels.len()));
            }
            if let Some(l) = k.iter().find(|l| l.len() != scene.cols()) {
                return Err(bad("cells", l.len(), scene.cols()));
            }
        }
    }
    Ok(())
}

/// A positive, finite option or an error naming it.
pub(super) fn positive(name: &'static str, value: f64) -> Result<f64, SceneFitError> {
    if value.is_finite() && value > 0.0 {
        Ok(value)
    } else {
        Err(SceneFitError::Parameter {
            name,
            value,
            reason: "must be a positive number",
        })
    }
}

/// The free freedoms, each once, in the order asked; an error for an empty
/// list or one that moves occluders the scene does not have.
pub(super) fn free_list(
    scene: &Scene,
    options: &SceneFitOptions,
) -> Result<Vec<Freedom>, SceneFitError> {
    let mut free: Vec<Freedom> = Vec::new();
    for f in &options.free {
        if !free.contains(f) {
            free.push(*f);
        }
    }
    if free.is_empty() {
        return Err(SceneFitError::NothingFree);
    }
    let moves_occluders = |f: &Freedom| {
        matches!(
            f,
            Freedom::OccluderX | Freedom::OccluderY | Freedom::OccluderZ | Freedom::OccluderYaw
        )
    };
    if scene.occluders().is_empty() {
        if let Some(f) = free.iter().find(|f| moves_occluders(f)) {
            return Err(SceneFitError::NoOccluders(f.name()));
        }
    }
    Ok(free)
}

impl SceneFitOptions {
    /// Fits the geometry of `scene` to `shots`; `stop` ends it early with
    /// [`SceneFitError::Stopped`].
    pub fn fit(
        &self,
        scene: &Scene,
        shots: &[Shot],
        stop: Stop<'_>,
    ) -> Result<SceneFit, SceneFitError> {
        fit::fit_scene(scene, shots, self, stop, &|_| {})
    }

    /// [`SceneFitOptions::fit`], telling `progress` after each `T` build:
    /// a fit takes minutes, and its caller shows how far it is.
    pub fn fit_telling(
        &self,
        scene: &Scene,
        shots: &[Shot],
        stop: Stop<'_>,
        progress: &dyn Fn(FitProgress),
    ) -> Result<SceneFit, SceneFitError> {
        fit::fit_scene(scene, shots, self, stop, progress)
    }
}

impl SceneFit {
    /// The scene file `text` (a file in `from_dir`) with the fitted
    /// geometry, as a file in `to_dir`: only the moved values change
    /// (comments, order and the rest as written; relative mesh paths
    /// rewritten for `to_dir`), validated there.
    pub fn placed_file(
        &self,
        text: &str,
        from_dir: &std::path::Path,
        to_dir: &std::path::Path,
    ) -> Result<String, SceneFitError> {
        place::placed_scene_file(text, from_dir, &self.selected, &self.placement, to_dir)
    }
}
