//! Where the occluders stand, fitted to photos: the translation (common to
//! the selected occluders) that minimizes the photos' model misfit, with an
//! uncertainty that includes the model's own error.
//!
//! Why: a passive reconstruction needs the occluder's position to a few
//! millimetres, and a tape measure gives it to a centimetre at best; the
//! photo itself says where the shadows fall (docs/realphoto.md, "Placing
//! the occluders"). The misfit is the least-squares misfit of the data term
//! of differences (blind to the photo's unknown gain and ambient light)
//! summed over the colour channels of every photo, with `T` built with area
//! shadows: exact, and continuous in the translation.

use std::collections::HashMap;
use std::path::Path;

use super::scene_text::rebase;
use std::time::Instant;

use crate::optics::Vec3;
use crate::scene::{Mesh, Occluder, Scene, SceneError, SceneParts, ShadowModel};
use crate::solve::photo::{least_squares_misfits, noise_checks, DataTerm};
use crate::solve::SolveError;
use crate::transport::{build, MemoryBudget, TransportError};

/// Why the occluders could not be fitted.
#[derive(Debug, thiserror::Error)]
pub enum OccluderError {
    /// The scene has no occluder to move.
    #[error("the scene has no [[occluder]]: there is nothing to place")]
    NoOccluders,
    /// A selected occluder index is not in the scene.
    #[error("occluder {index} is not in the scene, which has {count} (0 to {})", count.saturating_sub(1))]
    Index {
        /// The index asked for.
        index: usize,
        /// Occluders in the scene.
        count: usize,
    },
    /// The selection names no occluder.
    #[error("the occluder selection is empty")]
    NoneSelected,
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
        /// Photo index, in the order given.
        photo: usize,
        /// Channel index.
        channel: usize,
        /// Values given.
        got: usize,
        /// Rows of `T`.
        rows: usize,
    },
    /// The noise variances do not match the photos: `photo` is `None` when
    /// their count differs, else the photo whose channels differ.
    #[error("{got} noise variances for {want} {}: give one variance per measurement, with the measurement's channels", match photo { None => "measurements".to_string(), Some(p) => format!("channels of measurement {p}") })]
    Variances {
        /// The photo whose channel count differs; `None`: the photo count.
        photo: Option<usize>,
        /// Variances given.
        got: usize,
        /// Photos (or channels) given.
        want: usize,
    },
    /// A search option is out of range.
    #[error("{name} = {value}: {reason}")]
    Parameter {
        /// Option name, as on the command line.
        name: &'static str,
        /// Given value.
        value: f64,
        /// What it must be.
        reason: &'static str,
    },
    /// The scene with the occluders moved does not validate.
    #[error("the scene with its occluders moved: {0}")]
    Scene(#[from] SceneError),
    /// A scene file's text could not be edited.
    #[error("scene file: {0}")]
    SceneFile(String),
    /// A mesh path cannot be written for the new scene file's folder.
    #[error(transparent)]
    MeshPath(#[from] super::scene_text::MeshPathError),
    /// `T` could not be built.
    #[error(transparent)]
    Transport(#[from] TransportError),
    /// The photo's fit failed.
    #[error(transparent)]
    Solve(#[from] SolveError),
}

/// How the search runs; `Default` gives the documented defaults.
#[derive(Debug, Clone)]
pub struct OccluderOptions {
    /// Indices of the occluders that move together; `None`: all.
    pub selected: Option<Vec<usize>>,
    /// Largest distance searched from the start along each axis, metres.
    pub range: f64,
    /// First step, metres; `None`: `STEP_SHADOW_PITCHES` shadow pitches.
    pub step: Option<f64>,
    /// Last step, metres; `None`: one shadow pitch (`shadow_pitch`).
    pub min_step: Option<f64>,
    /// Scene `supersample` of the `T` the objective builds; `None`: 1 with
    /// area shadows (a block's visibility is then exact, only its emission
    /// is taken at its centre), else the scene's own raised to `SUPERSAMPLE`.
    pub supersample: Option<usize>,
    /// Shadows of the objective's `T`; area shadows by default, whatever
    /// the scene says, for a misfit continuous in the translation.
    pub shadows: ShadowModel,
    /// The uncertainty region: translations whose misfit is within this
    /// fraction of the lowest misfit ([`TOLERANCE`]).
    pub tolerance: f64,
    /// Most objective evaluations (`T` builds) the search may spend.
    pub max_evaluations: usize,
    /// Descents on the same lattice ([`STARTS`]): from the scene's position
    /// and from two first steps out along the diagonals, so that a misfit
    /// with several lows is found out ([`FitWarning::OtherLow`]).
    pub starts: usize,
    /// Memory budget of each `T`.
    pub budget: MemoryBudget,
    /// Each photo's noise variance, channel by channel and row by row as
    /// the photos (`measure`'s `.variance.npy`): the model check's noise.
    /// `None`: each channel's noise from its residual's roughness, which a
    /// model error rough at the wall element's scale inflates.
    pub variances: Option<Vec<Vec<Vec<f64>>>>,
}

/// Default search range per axis, metres: a first guess measured by hand.
pub const RANGE: f64 = 0.05;
/// Default first step in shadow pitches (then halved down to one pitch).
pub(crate) const STEP_SHADOW_PITCHES: f64 = 4.0;
/// Default scene supersample of the objective's `T` with point shadows: at
/// the chair's 2 the objective is rough by 5 % from one millimetre to the
/// next, at 6 by 1 % (docs/realphoto.md).
pub(crate) const SUPERSAMPLE: usize = 6;
/// Default relative misfit threshold of the uncertainty region: the model's
/// own error moves the misfit's minimum by as much as the translations
/// within this fraction of it span (measured on the chair photo and on
/// simulated photos made unlike the model, docs/realphoto.md).
pub const TOLERANCE: f64 = 0.02;
/// A misfit whose ripple (its RMS about a parabola over three steps each
/// side, [`Found::ripple`]) exceeds this fraction of its value cannot be
/// trusted: on the chair photo it is 0.7-0.8 % (1.3 % at most over 2 cm),
/// on simulated photos of the voxel Π made unlike the model 2.5-11 %, and
/// there the lowest misfit lay 20-35 mm from the truth (docs/realphoto.md).
pub(crate) const ROUGH_RIPPLE: f64 = 0.02;
/// A lowest misfit more than this many times the noise's
/// ([`OccluderFit::noise_misfit`]) is the model's error's, not the noise's
/// ([`FitWarning::ModelError`]).
pub const MODEL_ERROR: f64 = 1.1;
/// Default cap on objective evaluations: about four minutes on the chair.
pub const MAX_EVALUATIONS: usize = 300;
/// Default descents: from the scene's position and from two more starts.
pub const STARTS: usize = 3;

impl Default for OccluderOptions {
    fn default() -> Self {
        Self {
            selected: None,
            range: RANGE,
            step: None,
            min_step: None,
            supersample: None,
            shadows: ShadowModel::Area,
            tolerance: TOLERANCE,
            max_evaluations: MAX_EVALUATIONS,
            starts: STARTS,
            budget: MemoryBudget::DEFAULT,
            variances: None,
        }
    }
}

/// One evaluation of the objective.
#[derive(Debug, Clone, serde::Serialize)]
pub struct Probe {
    /// Translation from the start, metres.
    pub translation: [f64; 3],
    /// Misfit summed over the photos.
    pub objective: f64,
    /// Each photo's misfit, summed over its channels.
    pub photos: Vec<f64>,
}

/// Why a fit's position cannot be trusted as its uncertainty says.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
#[serde(tag = "kind", rename_all = "snake_case")]
pub enum FitWarning {
    /// The lowest misfit is on the searched range's edge along `axis`: the
    /// minimum may lie beyond it.
    AtEdge {
        /// 0, 1, 2: x, y, z.
        axis: usize,
    },
    /// The misfit stays within the threshold up to the range's edge along
    /// `axis` on the `side` (-1 or +1): the photos do not fix that
    /// coordinate within the range.
    Flat {
        /// 0, 1, 2: x, y, z.
        axis: usize,
        /// -1: towards lower values; +1: towards higher.
        side: i8,
    },
    /// An evaluated translation outside the profile's bracket, `at` from
    /// the end (metres), has a misfit within the threshold: separated lows.
    Separated {
        /// From the end, metres.
        at: [f64; 3],
        /// Its misfit.
        objective: f64,
    },
    /// The misfit's ripple is more than `ROUGH_RIPPLE` of its value: the
    /// model's discretization, not the photo, shapes it at the
    /// few-millimetre scale.
    Rough {
        /// The ripple relative to the lowest misfit.
        ripple: f64,
    },
    /// A descent from another start ended in another low, outside the
    /// region and above its threshold: which low the fit ends in depends
    /// on where it starts, and the photos' misfit is shaped by what the
    /// model gets wrong.
    OtherLow {
        /// Where that descent started, from the scene's position (metres).
        start: [f64; 3],
        /// Where it ended, from the fit's end (metres).
        at: [f64; 3],
        /// Its misfit.
        objective: f64,
        /// That misfit over the lowest, less 1.
        above: f64,
    },
    /// The lowest misfit is more than [`MODEL_ERROR`] times what the
    /// photos' noise alone would leave ([`OccluderFit::noise_misfit`]): the
    /// model's error, not the noise, shapes the misfit, and its lowest point
    /// can lie centimetres from the occluders with nothing else showing it.
    ModelError {
        /// The lowest misfit over the noise's.
        ratio: f64,
    },
    /// The evaluation cap ended the search before the uncertainty region
    /// was bracketed.
    Budget {
        /// Evaluations spent.
        evaluations: usize,
    },
}

/// Where the model check's noise came from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum NoiseFrom {
    /// The photos' own variances ([`OccluderOptions::variances`]).
    Variance,
    /// The roughness of each channel's residual: high where the model's
    /// error is rough, so the check may read low, never high.
    Roughness,
}

/// The name of axis `a` in the scene's frame.
fn axis_name(a: usize) -> &'static str {
    ["x", "y", "z"].get(a).copied().unwrap_or("?")
}

/// Metres as a signed millimetre triple.
fn mm(v: [f64; 3]) -> String {
    format!(
        "({:+.1}, {:+.1}, {:+.1}) mm",
        v[0] * 1e3,
        v[1] * 1e3,
        v[2] * 1e3
    )
}

impl std::fmt::Display for FitWarning {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            FitWarning::AtEdge { axis } => write!(
                f,
                "the lowest misfit lies on the searched range's edge along {}: the occluders may stand beyond it (start closer or widen --range)",
                axis_name(*axis)
            ),
            FitWarning::Flat { axis, side } => write!(
                f,
                "the misfit stays within the threshold up to the range's edge towards {}{}: the photos do not fix {} within the range",
                if *side < 0 { "-" } else { "+" },
                axis_name(*axis),
                axis_name(*axis)
            ),
            FitWarning::Separated { at, objective } => write!(
                f,
                "the translation {} from the end has a misfit within the threshold too ({objective:.4e}) but is separated from it: the misfit has several lows",
                mm(*at)
            ),
            FitWarning::Rough { ripple } => write!(
                f,
                "the misfit ripples by {:.1} % of its value from one step to the next (more than {:.0} %): the model's blocks and shadows, not the photo, shape it at the few-millimetre scale, and on photos made unlike the model its lowest point lay 2-3 cm from the occluders (docs/realphoto.md)",
                100.0 * ripple,
                100.0 * ROUGH_RIPPLE
            ),
            FitWarning::OtherLow {
                start,
                at,
                objective,
                above,
            } => write!(
                f,
                "the descent started at {} ended in another low, {} from the end (misfit {objective:.4e}, {:.1} % above): where the fit ends depends on where it starts, so the model's error, not the photos, may place the occluders; check the position by other means",
                mm(*start),
                mm(*at),
                100.0 * above
            ),
            FitWarning::ModelError { ratio } => write!(
                f,
                "the lowest misfit is {ratio:.2} times what the photos' noise alone would leave (more than {MODEL_ERROR}): the model's error shapes the misfit, and on photos made unlike the model its lowest point lay 2-3 cm from the occluders with nothing else showing it (docs/realphoto.md, \"The model check\"); check the position by other means"
            ),
            FitWarning::Budget { evaluations } => write!(
                f,
                "the search spent its {evaluations} evaluations before the uncertainty was bracketed (raise --max-evaluations)"
            ),
        }
    }
}

/// The fitted translation and what it rests on.
#[derive(Debug, Clone, serde::Serialize)]
pub struct OccluderFit {
    /// Indices of the occluders moved.
    pub selected: Vec<usize>,
    /// Translation from the scene's position, metres: the evaluated
    /// translation of lowest misfit.
    pub translation: [f64; 3],
    /// Uncertainty of each component, metres, the model's error included:
    /// the larger side of [`OccluderFit::extent`].
    pub uncertainty: [f64; 3],
    /// Per axis, how far below and above the translation the misfit stays
    /// within the threshold (to the first evaluated point beyond it), metres.
    pub extent: [[f64; 2]; 3],
    /// The misfit threshold of the uncertainty region (absolute): the
    /// largest of the tolerance's share of the lowest misfit, one noise
    /// variance, and [`RIPPLE_FACTOR`] times the misfit's ripple.
    pub threshold: f64,
    /// That threshold relative to the lowest misfit.
    pub relative_threshold: f64,
    /// The tolerance asked for (a fraction of the lowest misfit).
    pub tolerance: f64,
    /// The misfit's ripple near the end (its RMS about a parabola over three steps each side).
    pub ripple: f64,
    /// The noise's share of the uncertainty alone, metres: the displacement
    /// that raises the misfit by one noise variance (from the curvature).
    pub sd_noise: [f64; 3],
    /// Curvature of the objective along each axis at the end, per m² (0
    /// when not convex there).
    pub curvature: [f64; 3],
    /// The misfit the photos' noise alone would leave at the end, summed
    /// over the channels ([`OccluderFit::noise_from`] says which noise):
    /// `None` where a channel has no more rows of differences than the
    /// scene has cells, or a photo is too small to measure its noise.
    pub noise_misfit: Option<f64>,
    /// The lowest misfit over [`OccluderFit::noise_misfit`]: near 1 when
    /// the model explains the photos to their noise.
    pub model_error: Option<f64>,
    /// Where that noise came from.
    pub noise_from: NoiseFrom,
    /// Why the fit cannot be trusted as the uncertainty says; empty when
    /// it can.
    pub warnings: Vec<FitWarning>,
    /// The selected occluders' bounding box, lowest corner, before the move.
    pub corner_start: [f64; 3],
    /// The same corner moved by the translation.
    pub corner_end: [f64; 3],
    /// Objective at the scene's own position.
    pub objective_start: f64,
    /// Objective at the translation (the lowest evaluated).
    pub objective_end: f64,
    /// Each photo's misfit at the start and at the end.
    pub objective_photos: Vec<[f64; 2]>,
    /// Rows of the data term, all channels of all photos.
    pub rows: usize,
    /// First and last step, metres.
    pub steps: [f64; 2],
    /// Scene supersample of the objective's `T`.
    pub supersample: usize,
    /// `T` builds (one per objective evaluation).
    pub builds: usize,
    /// Seconds, all builds and fits.
    pub seconds: f64,
    /// Every evaluation, in order.
    pub probes: Vec<Probe>,
}

impl OccluderFit {
    /// Whether the uncertainty can be taken as it stands (no warning).
    pub fn trusted(&self) -> bool {
        self.warnings.is_empty()
    }
}

/// The occluder indices `selected` names, checked against the scene.
pub(crate) fn selection(
    scene: &Scene,
    selected: Option<&[usize]>,
) -> Result<Vec<usize>, OccluderError> {
    let count = scene.occluders().len();
    if count == 0 {
        return Err(OccluderError::NoOccluders);
    }
    let Some(s) = selected else {
        return Ok((0..count).collect());
    };
    if s.is_empty() {
        return Err(OccluderError::NoneSelected);
    }
    if let Some(&index) = s.iter().find(|&&i| i >= count) {
        return Err(OccluderError::Index { index, count });
    }
    let mut v = s.to_vec();
    v.sort_unstable();
    v.dedup();
    Ok(v)
}

/// The occluder displacement that moves its shadow on the wall by one wall
/// element: the natural unit of the search (the shadow of a point at depth
/// `a` from the scene plane, seen from the scene, moves `D / a` as fast).
pub(crate) fn shadow_pitch(scene: &Scene, selected: &[usize]) -> f64 {
    let (wall, hidden) = (&scene.wall().plane, &scene.hidden().plane);
    let n = hidden.normal;
    let (lo, hi) = bounds(scene, selected);
    let centre = (Vec3::from(lo) + Vec3::from(hi)) * 0.5;
    let depth = n.dot(&(centre - hidden.center)).abs();
    let d = n.dot(&(wall.center - hidden.center)).abs();
    let pitch = wall.size[0] / wall.grid.nu as f64;
    if d > 0.0 && depth > 0.0 {
        pitch * (depth / d).min(1.0)
    } else {
        pitch
    }
}

/// The lowest and highest corner of the selected occluders' bounding box.
pub fn bounds(scene: &Scene, selected: &[usize]) -> ([f64; 3], [f64; 3]) {
    let mut lo = Vec3::repeat(f64::INFINITY);
    let mut hi = Vec3::repeat(f64::NEG_INFINITY);
    let mut add = |p: Vec3| {
        lo = lo.inf(&p);
        hi = hi.sup(&p);
    };
    for &i in selected {
        match scene.occluders().get(i) {
            Some(Occluder::Rect {
                center,
                half_u,
                half_v,
            }) => {
                let e = half_u.abs() + half_v.abs();
                add(center - e);
                add(center + e);
            }
            Some(Occluder::Sphere { center, radius }) => {
                add(center - Vec3::repeat(*radius));
                add(center + Vec3::repeat(*radius));
            }
            Some(Occluder::Mesh(m)) => m.triangles().iter().flatten().for_each(|p| add(*p)),
            None => {}
        }
    }
    (lo.into(), hi.into())
}

/// The selected occluders of `p` moved by `d`: a rect's or sphere's centre,
/// a mesh's triangles and its `offset`.
fn translate(p: &mut SceneParts, selected: &[usize], d: Vec3) {
    for &i in selected {
        match p.occluders.get_mut(i) {
            Some(Occluder::Rect { center, .. } | Occluder::Sphere { center, .. }) => *center += d,
            Some(Occluder::Mesh(m)) => {
                let tri = m.triangles().iter().map(|t| t.map(|p| p + d)).collect();
                let mut source = m.source().clone();
                let o = source.offset.unwrap_or([0.0; 3]);
                source.offset = Some([o[0] + d.x, o[1] + d.y, o[2] + d.z]);
                *m = std::sync::Arc::new(Mesh::new(tri, source));
            }
            None => {}
        }
    }
}

/// `scene` with the selected occluders moved by `d` and the hidden scene
/// sampled `supersample` times per side, its shadows as `shadows` says.
pub fn moved(
    scene: &Scene,
    selected: &[usize],
    d: [f64; 3],
    supersample: usize,
    shadows: ShadowModel,
) -> Result<Scene, SceneError> {
    scene.clone().edit(|p| {
        p.hidden.plane.supersample = supersample;
        p.hidden.shadows = shadows;
        translate(p, selected, Vec3::from(d));
    })
}

/// The objective at one translation: `T` of the moved scene, then the
/// least-squares misfit of the data term of differences of each channel
/// ([`least_squares_misfits`]), summed per photo: `channels` holds every
/// photo's channels in turn, `per_photo` how many are each photo's.
fn objective(
    scene: &Scene,
    selected: &[usize],
    (channels, per_photo): (&[Vec<f64>], &[usize]),
    d: [f64; 3],
    supersample: usize,
    options: &OccluderOptions,
) -> Result<Vec<f64>, OccluderError> {
    let t = build(
        &moved(scene, selected, d, supersample, options.shadows)?,
        options.budget,
    )?;
    let misfits = least_squares_misfits(&t, DataTerm::Differences, channels)?;
    let mut rest = misfits.as_slice();
    Ok(per_photo
        .iter()
        .map(|&n| {
            let (mine, after) = rest.split_at(n.min(rest.len()));
            rest = after;
            mine.iter().sum()
        })
        .collect())
}

/// A positive, finite option or an error naming it.
fn positive(name: &'static str, value: f64) -> Result<f64, OccluderError> {
    if value.is_finite() && value > 0.0 {
        Ok(value)
    } else {
        Err(OccluderError::Parameter {
            name,
            value,
            reason: "must be a positive number of metres",
        })
    }
}

/// Checks the photos against the scene: at least one photo, each with at
/// least one channel, each channel with one value per row of `T`.
fn check_photos(scene: &Scene, photos: &[Vec<Vec<f64>>]) -> Result<(), OccluderError> {
    if photos.is_empty() {
        return Err(OccluderError::NoPhotos);
    }
    let rows = scene.rows();
    for (photo, channels) in photos.iter().enumerate() {
        if channels.is_empty() {
            return Err(OccluderError::NoChannels { photo });
        }
        if let Some((channel, c)) = channels.iter().enumerate().find(|(_, c)| c.len() != rows) {
            return Err(OccluderError::Rows {
                photo,
                channel,
                got: c.len(),
                rows,
            });
        }
    }
    Ok(())
}

/// Checks that `variances` has a photo for each photo and a channel for
/// each of its channels (their rows and values are checked with the fit).
fn check_variances(
    photos: &[Vec<Vec<f64>>],
    variances: &[Vec<Vec<f64>>],
) -> Result<(), OccluderError> {
    if variances.len() != photos.len() {
        return Err(OccluderError::Variances {
            photo: None,
            got: variances.len(),
            want: photos.len(),
        });
    }
    for (photo, (v, p)) in variances.iter().zip(photos).enumerate() {
        if v.len() != p.len() {
            return Err(OccluderError::Variances {
                photo: Some(photo),
                got: v.len(),
                want: p.len(),
            });
        }
    }
    Ok(())
}

/// Checks the tolerance, the starts and the evaluation cap of `options`.
fn check_counts(options: &OccluderOptions) -> Result<(), OccluderError> {
    if !(options.tolerance.is_finite() && options.tolerance >= 0.0) {
        return Err(OccluderError::Parameter {
            name: "tolerance",
            value: options.tolerance,
            reason: "must be a fraction >= 0 of the lowest misfit",
        });
    }
    for (name, n) in [
        ("starts", options.starts),
        ("max-evaluations", options.max_evaluations),
    ] {
        if n == 0 {
            return Err(OccluderError::Parameter {
                name,
                value: 0.0,
                reason: "must be at least 1",
            });
        }
    }
    Ok(())
}

/// The first and last step: `options`' own, or `STEP_SHADOW_PITCHES`
/// shadow pitches and one, checked against each other and the range.
fn steps(
    scene: &Scene,
    selected: &[usize],
    options: &OccluderOptions,
    range: f64,
) -> Result<(f64, f64), OccluderError> {
    let pitch = shadow_pitch(scene, selected);
    let min_step = positive("min-step", options.min_step.unwrap_or(pitch))?;
    let step = positive(
        "step",
        options.step.unwrap_or(STEP_SHADOW_PITCHES * min_step),
    )?;
    if step < min_step || step > range {
        return Err(OccluderError::Parameter {
            name: "step",
            value: step,
            reason: "must lie between min-step and range",
        });
    }
    Ok((step, min_step))
}

/// Fits the translation of the selected occluders that minimizes the
/// photos' misfit summed (the module's doc), by a lattice search (`search`); `photos` holds
/// each photo's colour channels, all of the same bench.
pub fn fit_occluder(
    scene: &Scene,
    photos: &[Vec<Vec<f64>>],
    options: &OccluderOptions,
) -> Result<OccluderFit, OccluderError> {
    let start = Instant::now();
    let selected = selection(scene, options.selected.as_deref())?;
    check_photos(scene, photos)?;
    if let Some(v) = &options.variances {
        check_variances(photos, v)?;
    }
    let range = positive("range", options.range)?;
    check_counts(options)?;
    let (step, min_step) = steps(scene, &selected, options, range)?;
    let supersample = options.supersample.unwrap_or(match options.shadows {
        ShadowModel::Area => 1,
        ShadowModel::Point | ShadowModel::Auto => scene.hidden().plane.supersample.max(SUPERSAMPLE),
    });
    // The misfit per degree of freedom: rows of differences less the unknowns, per channel.
    let g = scene.wall().plane.grid;
    let rows_per_channel =
        scene.block_count() * (g.nu.saturating_sub(1) * g.nv + g.nu * g.nv.saturating_sub(1));
    let channels: usize = photos.iter().map(Vec::len).sum();
    let rows = rows_per_channel * channels;
    let dof = rows.saturating_sub(scene.cols() * channels).max(1);
    // Every photo's channels in one list, made once for every evaluation.
    let flat: Vec<Vec<f64>> = photos.iter().flatten().cloned().collect();
    let per_photo: Vec<usize> = photos.iter().map(Vec::len).collect();
    let mut probes: Vec<Probe> = Vec::new();
    let mut f = |d: [f64; 3]| {
        if let Some(p) = probes.iter().find(|p| p.translation == d) {
            return Ok(p.objective);
        }
        let each = objective(
            scene,
            &selected,
            (&flat, &per_photo),
            d,
            supersample,
            options,
        )?;
        let v = each.iter().sum();
        probes.push(Probe {
            translation: d,
            objective: v,
            photos: each,
        });
        Ok::<f64, OccluderError>(v)
    };
    let search_options = SearchOptions {
        step,
        min_step,
        range,
        relative_threshold: options.tolerance.max(1.0 / dof as f64),
        max_evaluations: options.max_evaluations,
        starts: options.starts,
    };
    let found = search_refined(&mut f, &search_options, options.min_step.is_none())?;
    let s2 = found.value / dof as f64;
    let sd_noise = found.curvature.map(|c| {
        if c > 0.0 {
            (2.0 * s2 / c).sqrt()
        } else {
            f64::INFINITY
        }
    });
    let at = |d: [f64; 3]| probes.iter().find(|p| p.translation == d);
    let photo_misfits = |d| at(d).map_or(vec![f64::NAN; photos.len()], |p| p.photos.clone());
    let objective_photos = photo_misfits([0.0; 3])
        .into_iter()
        .zip(photo_misfits(found.point))
        .map(|(a, b)| [a, b])
        .collect();
    let objective_start = at([0.0; 3]).map_or(f64::NAN, |p| p.objective);
    let mut warnings = found.warnings;
    let ripple = found.ripple / found.value.abs().max(f64::MIN_POSITIVE);
    if ripple > ROUGH_RIPPLE {
        warnings.push(FitWarning::Rough { ripple });
    }
    let (noise_misfit, model_error) =
        model_check(scene, &selected, found.point, supersample, options, &flat)?;
    if let Some(ratio) = model_error.filter(|r| *r > MODEL_ERROR) {
        warnings.push(FitWarning::ModelError { ratio });
    }
    let (lo, _) = bounds(scene, &selected);
    Ok(OccluderFit {
        selected,
        translation: found.point,
        uncertainty: found.extent.map(|[a, b]| a.max(b)),
        extent: found.extent,
        threshold: found.threshold,
        relative_threshold: found.threshold / found.value.abs().max(f64::MIN_POSITIVE),
        tolerance: options.tolerance,
        ripple: found.ripple,
        sd_noise,
        curvature: found.curvature,
        noise_misfit,
        model_error,
        noise_from: if options.variances.is_some() {
            NoiseFrom::Variance
        } else {
            NoiseFrom::Roughness
        },
        warnings,
        corner_start: lo,
        corner_end: [0, 1, 2].map(|a| lo[a] + found.point[a]),
        objective_start,
        objective_end: found.value,
        objective_photos,
        rows,
        steps: [step, found.last_step],
        supersample,
        builds: probes.len(),
        seconds: start.elapsed().as_secs_f64(),
        probes,
    })
}

/// [`search`], and where `refine` and the misfit ripples at the end by more
/// than `ROUGH_RIPPLE` of its value, the search again with the last step
/// halved: a rough misfit can hide its low between the lattice's points.
/// Each point of the first lattice is one of the second, so an objective
/// that remembers what it built pays only for the new points.
fn search_refined<E>(
    f: &mut dyn FnMut([f64; 3]) -> Result<f64, E>,
    options: &SearchOptions,
    refine: bool,
) -> Result<Found, E> {
    let found = search(f, options)?;
    if refine && found.ripple > ROUGH_RIPPLE * found.value.abs() {
        return search(
            f,
            &SearchOptions {
                min_step: options.min_step / 2.0,
                ..*options
            },
        );
    }
    Ok(found)
}

/// The model check at `d`: the misfit the photos' noise alone would leave
/// (their variances, or each channel's residual's roughness), and the
/// misfit over it ([`noise_checks`]; neither on a wall with no more rows of
/// differences than the scene has cells). One more `T` build.
fn model_check(
    scene: &Scene,
    selected: &[usize],
    d: [f64; 3],
    supersample: usize,
    options: &OccluderOptions,
    channels: &[Vec<f64>],
) -> Result<(Option<f64>, Option<f64>), OccluderError> {
    let t = build(
        &moved(scene, selected, d, supersample, options.shadows)?,
        options.budget,
    )?;
    let variances: Option<Vec<Vec<f64>>> = options
        .variances
        .as_ref()
        .map(|v| v.iter().flatten().cloned().collect());
    let checks = noise_checks(&t, DataTerm::Differences, channels, variances.as_deref())?;
    let noise_misfit = checks.iter().map(|c| c.noise_misfit).sum::<Option<f64>>();
    let model_error = noise_misfit
        .filter(|n| *n > 0.0)
        .map(|n| checks.iter().map(|c| c.misfit).sum::<f64>() / n);
    Ok((noise_misfit, model_error))
}

/// How [`search`] runs.
#[derive(Debug, Clone, Copy)]
pub(crate) struct SearchOptions {
    /// First step, metres.
    pub step: f64,
    /// Smallest step, metres; the last step is `step` halved while it stays
    /// at least this.
    pub min_step: f64,
    /// Largest distance from the origin along each axis, metres.
    pub range: f64,
    /// The uncertainty region: points whose value is within this fraction
    /// of the lowest value's magnitude.
    pub relative_threshold: f64,
    /// Most evaluations of the objective.
    pub max_evaluations: usize,
    /// Descents: the first from the origin, the others from two first
    /// steps (at most half the range) out along the cube's diagonals
    /// (`START_DIRECTIONS`).
    pub starts: usize,
}

/// The directions of the extra starts, in order: the cube's diagonals,
/// each followed by its opposite.
pub(crate) const START_DIRECTIONS: [[i64; 3]; 4] =
    [[1, 1, 1], [-1, -1, -1], [1, -1, -1], [-1, 1, 1]];

/// Where [`search`] ended.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct Found {
    /// The evaluated point of lowest value: on the last step's lattice,
    /// within the range.
    pub point: [f64; 3],
    /// Its value: the lowest evaluated.
    pub value: f64,
    /// The uncertainty region's threshold above `value` (absolute): the
    /// larger of the relative threshold and [`RIPPLE_FACTOR`] ripples.
    pub threshold: f64,
    /// The objective's ripple near `point`: per axis over `RIPPLE_REACH` (3)
    /// steps each side, the smaller of the RMS of its residuals from a
    /// parabola and its largest fall walking out; the RMS over the axes.
    pub ripple: f64,
    /// Per axis, the distance below and above `point` to the first
    /// evaluated point past the region (or to the range's edge), metres.
    pub extent: [[f64; 2]; 3],
    /// Per axis, the second difference through `point` and its evaluated
    /// neighbours at the last step, per metre² (0 when not convex or a
    /// neighbour is missing).
    pub curvature: [f64; 3],
    /// The last step, metres.
    pub last_step: f64,
    /// Evaluations made.
    pub evaluations: usize,
    /// Where each descent started and ended, from the origin (metres),
    /// and the end's value.
    pub starts: Vec<([f64; 3], [f64; 3], f64)>,
    /// Why the extent cannot be trusted; empty when it can.
    pub warnings: Vec<FitWarning>,
}

/// Rounds of walks and refinement before the profile is taken as it is.
const PROFILE_ROUNDS: usize = 4;
/// Steps on each side of the lowest point along each axis whose parabola
/// fit measures the objective's ripple.
const RIPPLE_REACH: i64 = 3;
/// The threshold is at least this many times the ripple's RMS: above the
/// ripple's peaks (a sine's peak to peak is 2.8 RMS), so that the walks
/// pass them and the region spans the valleys the ripple makes equal.
pub const RIPPLE_FACTOR: f64 = 3.0;

/// The objective on a lattice: every point `k h` with integer `k` within
/// the range, each evaluated once, at most `cap` of them.
struct Lattice<'a, E> {
    f: &'a mut dyn FnMut([f64; 3]) -> Result<f64, E>,
    /// The lattice's step, metres.
    h: f64,
    /// The largest `|k|` along an axis within the range.
    reach: i64,
    seen: HashMap<[i64; 3], f64>,
    /// Points in evaluation order: ties go to the first evaluated.
    order: Vec<[i64; 3]>,
    cap: usize,
    capped: bool,
}

/// `v` as an ordering key: NaN counts as the highest value.
fn key(v: f64) -> f64 {
    if v.is_nan() {
        f64::INFINITY
    } else {
        v
    }
}

/// `k` moved by `by` along axis `a`.
fn shift(mut k: [i64; 3], a: usize, by: i64) -> [i64; 3] {
    k[a] += by;
    k
}

impl<E> Lattice<'_, E> {
    fn point(&self, k: [i64; 3]) -> [f64; 3] {
        k.map(|x| x as f64 * self.h)
    }

    /// The value at `k`: `None` outside the range or once the cap is spent.
    fn value(&mut self, k: [i64; 3]) -> Result<Option<f64>, E> {
        if k.iter().any(|x| x.abs() > self.reach) {
            return Ok(None);
        }
        if let Some(v) = self.seen.get(&k) {
            return Ok(Some(*v));
        }
        if self.order.len() >= self.cap {
            self.capped = true;
            return Ok(None);
        }
        let at = self.point(k);
        let v = (self.f)(at)?;
        self.seen.insert(k, v);
        self.order.push(k);
        Ok(Some(v))
    }

    /// The evaluated point of lowest value (the first of equals).
    fn best(&self) -> ([i64; 3], f64) {
        let mut best = (self.order[0], self.seen[&self.order[0]]);
        for k in &self.order[1..] {
            let v = self.seen[k];
            if key(v) < key(best.1) {
                best = (*k, v);
            }
        }
        best
    }

    /// Compass search at step `s` from `p`: each axis in turn tries `± s`
    /// and keeps stepping while the value falls. Where it ended.
    fn compass(&mut self, mut p: [i64; 3], s: i64) -> Result<[i64; 3], E> {
        let Some(mut fp) = self.value(p)? else {
            return Ok(p);
        };
        loop {
            let mut moved = false;
            for a in 0..3 {
                let mut down: Option<(i64, f64)> = None;
                for dir in [1, -1] {
                    if let Some(v) = self.value(shift(p, a, dir * s))? {
                        if key(v) < key(fp) && down.is_none_or(|(_, b)| key(v) < key(b)) {
                            down = Some((dir, v));
                        }
                    }
                }
                let Some((dir, v)) = down else { continue };
                (p, fp, moved) = (shift(p, a, dir * s), v, true);
                while let Some(v) = self.value(shift(p, a, dir * s))? {
                    if key(v) >= key(fp) {
                        break;
                    }
                    (p, fp) = (shift(p, a, dir * s), v);
                }
            }
            if !moved {
                return Ok(p);
            }
        }
    }

    /// Probes `± 2 s` along each axis from `p`, past the next ridge of a
    /// rough objective: the lowest probe below `p`'s value, if any.
    fn escape(&mut self, p: [i64; 3], s: i64) -> Result<Option<[i64; 3]>, E> {
        let Some(fp) = self.value(p)? else {
            return Ok(None);
        };
        let mut lower: Option<([i64; 3], f64)> = None;
        for a in 0..3 {
            for dir in [1, -1] {
                let k = shift(p, a, 2 * dir * s);
                if let Some(v) = self.value(k)? {
                    if key(v) < key(fp) && lower.is_none_or(|(_, b)| key(v) < key(b)) {
                        lower = Some((k, v));
                    }
                }
            }
        }
        Ok(lower.map(|(k, _)| k))
    }

    /// Coarse to fine from `p`: at each step from `s` down to 1 (halving),
    /// compass search and escape probes until neither finds a lower point.
    /// Where it ended.
    fn descend(&mut self, mut p: [i64; 3], mut s: i64) -> Result<[i64; 3], E> {
        loop {
            loop {
                p = self.compass(p, s)?;
                match self.escape(p, s)? {
                    Some(lower) => p = lower,
                    None => break,
                }
            }
            if s <= 1 {
                return Ok(p);
            }
            s /= 2;
        }
    }

    /// The objective's ripple near `b`: along each axis, over the points
    /// within [`RIPPLE_REACH`] steps of `b` (evaluating those missing), the
    /// smaller of the RMS of their residuals from a parabola and the largest
    /// fall met walking out from `b`; the RMS of that over the axes.
    ///
    /// Why: a rough objective leaves both (its valleys are not a parabola's,
    /// and walking out one climbs and falls again); a sharp but smooth
    /// minimum leaves only the first, a smooth slope only neither.
    fn ripple(&mut self, b: [i64; 3]) -> Result<f64, E> {
        let (mut sum, mut axes) = (0.0, 0usize);
        for a in 0..3 {
            let mut pts = Vec::new();
            for j in -RIPPLE_REACH..=RIPPLE_REACH {
                if let Some(v) = self.value(shift(b, a, j))? {
                    if v.is_finite() {
                        pts.push((j, v));
                    }
                }
            }
            if pts.len() < 4 {
                continue;
            }
            let mut m = nalgebra::Matrix3::<f64>::zeros();
            let mut r = nalgebra::Vector3::<f64>::zeros();
            for &(j, v) in &pts {
                let x = j as f64;
                let basis = nalgebra::Vector3::new(1.0, x, x * x);
                m += basis * basis.transpose();
                r += basis * v;
            }
            let Some(c) = m.try_inverse().map(|inv| inv * r) else {
                continue;
            };
            let rss = pts
                .iter()
                .map(|&(j, v)| {
                    let x = j as f64;
                    (v - c[0] - c[1] * x - c[2] * x * x).powi(2)
                })
                .sum::<f64>();
            let parabola = (rss / (pts.len() - 3) as f64).sqrt();
            let mut fall = 0.0f64;
            for side in [-1, 1] {
                let mut last: Option<f64> = None;
                for k in 0..=RIPPLE_REACH {
                    let Some(&(_, v)) = pts.iter().find(|(j, _)| *j == side * k) else {
                        break;
                    };
                    if let Some(l) = last {
                        fall = fall.max(l - v);
                    }
                    last = Some(v);
                }
            }
            sum += parabola.min(fall).powi(2);
            axes += 1;
        }
        Ok(if axes > 0 {
            (sum / axes as f64).sqrt()
        } else {
            0.0
        })
    }

    /// Walks from `b` along axis `a` towards `side`, one step then `p` at a
    /// time, until the value exceeds `level` twice in a row (or
    /// `2 level - fb` once).
    fn walk(
        &mut self,
        b: [i64; 3],
        a: usize,
        side: i64,
        p: i64,
        level: f64,
        fb: f64,
    ) -> Result<Reach, E> {
        let mut first_above: Option<i64> = None;
        let (mut d, mut last) = (1, 0);
        loop {
            let k = shift(b, a, side * d);
            let Some(v) = self.value(k)? else {
                return Ok(match first_above {
                    Some(f) => Reach::Bracketed(f),
                    None if self.capped && k[a].abs() <= self.reach => Reach::Budget(last),
                    None => Reach::Edge(self.reach - side * b[a]),
                });
            };
            if key(v) <= level {
                first_above = None;
            } else if let Some(f) = first_above {
                return Ok(Reach::Bracketed(f));
            } else {
                first_above = Some(d);
                if key(v) > 2.0 * level - fb {
                    return Ok(Reach::Bracketed(d));
                }
            }
            last = d;
            d = if d < p { p } else { d + p };
        }
    }
}

/// How far a walk found the region to reach, in lattice steps.
#[derive(Debug, Clone, Copy)]
enum Reach {
    /// To the first point past the region.
    Bracketed(i64),
    /// To the range's edge, still within the region.
    Edge(i64),
    /// As far as the evaluation cap let it walk, still within.
    Budget(i64),
}

/// The lowest point after the profile walks, and how far the region
/// around it reaches along each axis.
struct Profile {
    /// The lowest evaluated point.
    b: [i64; 3],
    /// Its value.
    fb: f64,
    /// The region's level: `fb` plus the threshold.
    level: f64,
    /// The objective's ripple near `b` ([`Found::ripple`]).
    ripple: f64,
    /// Per axis, below and above: how far the walks found the region.
    reaches: [[Reach; 2]; 3],
}

impl<E> Lattice<'_, E> {
    /// Walks from `b` along every axis, both ways, at `level`.
    fn walks(&mut self, b: [i64; 3], p: i64, level: f64, fb: f64) -> Result<[[Reach; 2]; 3], E> {
        let mut reaches = [[Reach::Edge(0); 2]; 3];
        for (a, r) in reaches.iter_mut().enumerate() {
            for (s, side) in [-1, 1].into_iter().enumerate() {
                r[s] = self.walk(b, a, side, p, level, fb)?;
            }
        }
        Ok(reaches)
    }

    /// From the best point: the ripple, the threshold, and walks along
    /// each axis; a walk that finds a lower point starts the descent again
    /// from it (at most [`PROFILE_ROUNDS`] times), and the walks are taken
    /// again from the lowest point evaluated, so that the profile is always
    /// measured from the end.
    fn profile(&mut self, p: i64, relative_threshold: f64) -> Result<Profile, E> {
        let level_of = |fb: f64, ripple: f64| {
            key(fb) + (relative_threshold * key(fb).abs()).max(RIPPLE_FACTOR * ripple)
        };
        let mut b = self.best().0;
        let mut round = 0;
        loop {
            let ripple = self.ripple(b)?;
            let fb;
            (b, fb) = self.best();
            let level = level_of(fb, ripple);
            let reaches = self.walks(b, p, level, key(fb))?;
            round += 1;
            let (b_end, f_end) = self.best();
            if b_end == b {
                return Ok(Profile {
                    b,
                    fb,
                    level,
                    ripple,
                    reaches,
                });
            }
            if round == PROFILE_ROUNDS || self.capped {
                // The rounds (or the cap) ran out just as a walk found a
                // lower point: the walks start again from it.
                let level = level_of(f_end, ripple);
                let reaches = self.walks(b_end, p, level, key(f_end))?;
                return Ok(Profile {
                    b: b_end,
                    fb: f_end,
                    level,
                    ripple,
                    reaches,
                });
            }
            self.descend(self.best().0, p)?;
            b = self.best().0;
        }
    }

    /// The region's extent per axis, in lattice steps (the walks' reach,
    /// widened to every evaluated point within the level), and the warnings
    /// it gives: an end on the range's edge, a region flat to the edge, a
    /// separated low, a walk the cap cut short.
    fn region(&self, profile: &Profile) -> ([[i64; 2]; 3], Vec<FitWarning>) {
        let Profile {
            b, level, reaches, ..
        } = profile;
        let b = *b;
        let mut warnings = Vec::new();
        let mut extent = [[0i64; 2]; 3];
        for a in 0..3 {
            if b[a].abs() == self.reach && self.reach > 0 {
                warnings.push(FitWarning::AtEdge { axis: a });
            }
            for (s, side) in [-1i8, 1].into_iter().enumerate() {
                extent[a][s] = match reaches[a][s] {
                    Reach::Bracketed(d) => d,
                    Reach::Edge(d) => {
                        if d > 0 {
                            warnings.push(FitWarning::Flat { axis: a, side });
                        }
                        d
                    }
                    Reach::Budget(d) => d + 1,
                };
            }
        }
        // Every evaluated point within the level widens the extent; one
        // outside the walks' box is a separated low.
        let walked = extent;
        let mut separated: Option<([i64; 3], f64)> = None;
        for k in &self.order {
            let v = self.seen[k];
            if key(v) > *level {
                continue;
            }
            let mut outside = false;
            for a in 0..3 {
                let d = k[a] - b[a];
                let s = usize::from(d > 0);
                if d == 0 {
                    continue;
                }
                if d.abs() > walked[a][s] {
                    outside = true;
                }
                extent[a][s] = extent[a][s].max(d.abs() + 1);
            }
            let far = |q: [i64; 3]| (0..3).map(|a| (q[a] - b[a]).pow(2)).sum::<i64>();
            if outside && separated.is_none_or(|(q, _)| far(*k) > far(q)) {
                separated = Some((*k, v));
            }
        }
        if let Some((k, v)) = separated {
            warnings.push(FitWarning::Separated {
                at: [0, 1, 2].map(|a| (k[a] - b[a]) as f64 * self.h),
                objective: v,
            });
        }
        if self.capped
            && reaches
                .iter()
                .flatten()
                .any(|r| matches!(r, Reach::Budget(_)))
        {
            warnings.push(FitWarning::Budget {
                evaluations: self.order.len(),
            });
        }
        (extent, warnings)
    }
}

/// Minimizes `f` over a lattice of translations within `range` of the
/// origin along each axis and measures the region where `f` stays within
/// its threshold of the minimum.
///
/// Coarse to fine: compass searches (each axis in turn, stepping on while
/// `f` falls) with probes two steps out, from `step` halving down to the
/// last step. Then from the lowest point: the ripple ([`Found::ripple`]),
/// the threshold
/// (the larger of `relative_threshold` of the lowest value and
/// [`RIPPLE_FACTOR`] ripples), and walks along each axis (one step, then
/// at twice the last step or half the first) until `f` leaves the
/// threshold; a walk that finds a lower point starts the descent again from
/// it. It ends on the lowest point evaluated. The region's extent per axis
/// is the walks' reach, widened to every evaluated point within the
/// threshold (a point outside the walks' box is a separated low, and a
/// warning).
///
/// Why: `f` costs one `T` build per point and is rough at the few-millimetre
/// scale (its ripple follows the scene's blocks), so the search moves on a
/// lattice (no point is evaluated twice), looks past the next ridge, and
/// reports what it evaluated rather than an interpolation; a threshold
/// below the ripple would stop the walks at its first peak.
pub(crate) fn search<E>(
    f: &mut dyn FnMut([f64; 3]) -> Result<f64, E>,
    options: &SearchOptions,
) -> Result<Found, E> {
    let SearchOptions {
        step,
        min_step,
        range,
        relative_threshold,
        max_evaluations,
        starts,
    } = *options;
    let mut levels = 0u32;
    while levels < 30 && step / 2f64.powi(levels as i32 + 1) >= min_step * (1.0 - 1e-9) {
        levels += 1;
    }
    let h = step / 2f64.powi(levels as i32);
    let mut reach = (range / h + 1e-9).floor() as i64;
    if reach as f64 * h > range {
        reach -= 1;
    }
    let mut lattice = Lattice {
        f,
        h,
        reach: reach.max(0),
        seen: HashMap::new(),
        order: Vec::new(),
        cap: max_evaluations.max(1),
        capped: false,
    };
    let top = 1i64 << levels;
    // The descents: from the origin, then from two first steps out along
    // the diagonals (at most half the range), each on the same lattice.
    let mut descents = Vec::with_capacity(starts.max(1));
    for k in 0..starts.max(1) {
        let from = match k {
            0 => [0; 3],
            _ => START_DIRECTIONS[(k - 1) % START_DIRECTIONS.len()]
                .map(|d| d * (2 * top).min(lattice.reach / 2)),
        };
        if lattice.value(from)?.is_none() {
            break;
        }
        let end = lattice.descend(from, top)?;
        descents.push((from, end));
    }
    let p = (top / 2).clamp(1, 2);
    let profile = lattice.profile(p, relative_threshold)?;
    let (extent, mut warnings) = lattice.region(&profile);
    let Profile {
        b,
        fb,
        level,
        ripple,
        ..
    } = profile;
    // A descent that ended in another low, above the region and outside
    // it: where the fit ends depends on where it starts. (One that ended
    // on the range's edge found no low, only the edge.)
    for &(from, end) in &descents {
        if end.iter().any(|x| x.abs() >= lattice.reach) {
            continue;
        }
        let v = lattice.seen.get(&end).copied().unwrap_or(f64::NAN);
        let outside = (0..3).any(|a| {
            let d = end[a] - b[a];
            d != 0 && d.abs() >= extent[a][usize::from(d > 0)]
        });
        if outside && key(v) > level {
            warnings.push(FitWarning::OtherLow {
                start: lattice.point(from),
                at: [0, 1, 2].map(|a| (end[a] - b[a]) as f64 * h),
                objective: v,
                above: v / fb - 1.0,
            });
        }
    }
    let starts = descents
        .iter()
        .map(|&(from, end)| {
            (
                lattice.point(from),
                lattice.point(end),
                lattice.seen.get(&end).copied().unwrap_or(f64::NAN),
            )
        })
        .collect();
    let curvature = [0, 1, 2].map(|a| {
        match (
            lattice.seen.get(&shift(b, a, -1)),
            lattice.seen.get(&shift(b, a, 1)),
        ) {
            (Some(lo), Some(hi)) => ((lo + hi - 2.0 * fb) / (h * h)).max(0.0),
            _ => 0.0,
        }
    });
    Ok(Found {
        point: lattice.point(b),
        value: fb,
        threshold: level - fb,
        ripple,
        extent: extent.map(|e| e.map(|d| d as f64 * h)),
        curvature,
        last_step: h,
        evaluations: lattice.order.len(),
        starts,
        warnings,
    })
}

/// The scene file's text with the selected `[[occluder]]` entries moved by
/// `d`, for a file written in `to_dir`: the text (a file in `from_dir`,
/// where its relative mesh paths are read from) keeps its other tables as
/// they are, and its `[[occluder]]` entries are the moved scene's as the
/// scene writes them ([`Scene::occluder_tables`]), each relative mesh path
/// rewritten relative to `to_dir` (absolute where no relative path leads
/// there). The result is validated as a file in `to_dir`.
pub fn scene_with_occluders_moved(
    scene_toml: &str,
    from_dir: &Path,
    selected: &[usize],
    d: [f64; 3],
    to_dir: &Path,
) -> Result<String, OccluderError> {
    let bad = |m: String| OccluderError::SceneFile(m);
    let mut table: toml::Table = toml::from_str(scene_toml).map_err(|e| bad(e.to_string()))?;
    let scene = Scene::from_toml_str_in(scene_toml, from_dir)?;
    let count = scene.occluders().len();
    if count == 0 {
        return Err(OccluderError::NoOccluders);
    }
    if let Some(&index) = selected.iter().find(|&&i| i >= count) {
        return Err(OccluderError::Index { index, count });
    }
    let moved = scene.edit(|p| translate(p, selected, Vec3::from(d)))?;
    let mut paths = HashMap::new();
    for (index, o) in moved.occluders().iter().enumerate() {
        if let Occluder::Mesh(m) = o {
            paths.insert(index, rebase(index, &m.source().path, from_dir, to_dir)?);
        }
    }
    let tables = moved
        .occluder_tables(&mut |i, p| Ok(paths.get(&i).cloned().unwrap_or_else(|| p.to_string())))?;
    table.insert(
        "occluder".into(),
        toml::Value::Array(tables.into_iter().map(toml::Value::Table).collect()),
    );
    let text = toml::to_string_pretty(&table).map_err(|e| bad(e.to_string()))?;
    let written = Scene::from_toml_str_in(&text, to_dir)?;
    if !same_places(written.occluders(), moved.occluders()) {
        return Err(bad(format!(
            "the occluders written for {} are not the moved ones",
            to_dir.display()
        )));
    }
    Ok(text)
}

/// Whether two occluder lists stand in the same places (a mesh by its
/// triangles, whatever its path).
fn same_places(a: &[Occluder], b: &[Occluder]) -> bool {
    a.len() == b.len()
        && a.iter().zip(b).all(|pair| match pair {
            (Occluder::Mesh(x), Occluder::Mesh(y)) => x.triangles() == y.triangles(),
            (x, y) => x == y,
        })
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    /// A small scene with two rect occluders and one sphere.
    const SCENE: &str = r#"
[wall]
center = [0.0, 0.0, 0.0]
normal = [0.0, 0.0, 1.0]
u_axis = [1.0, 0.0, 0.0]
size = [0.4, 0.4]
grid = [4, 4]
roughness = 1.0
ior = 1.5
ks = 0.0
kd = 1.0
diffuse = "lambert"

[scene]
center = [0.0, 0.0, 1.0]
normal = [0.0, 0.0, -1.0]
u_axis = [1.0, 0.0, 0.0]
size = [0.2, 0.2]
grid = [2, 2]

[[pose]]
name = "A"
camera = [0.0, -0.3, 0.5]
polarizer_deg = []

[[occluder]]
rect = { center = [0.0, 0.0, 0.5], half_u = [0.02, 0, 0], half_v = [0, 0.03, 0] }
[[occluder]]
sphere = { center = [0.05, 0.0, 0.25], radius = 0.01 }
[[occluder]]
rect = { center = [-0.05, 0.0, 0.5], half_u = [0.01, 0, 0], half_v = [0, 0.01, 0] }
"#;

    /// Search options with a threshold of `rel` and no practical cap.
    fn options(step: f64, min_step: f64, range: f64, rel: f64) -> SearchOptions {
        SearchOptions {
            step,
            min_step,
            range,
            relative_threshold: rel,
            max_evaluations: 10_000,
            starts: 1,
        }
    }

    #[test]
    fn the_search_finds_the_minimum_of_a_tilted_bowl_to_within_its_last_step() {
        // A bowl with a valley across x and y, its minimum off every lattice point.
        let m = [0.0137, -0.0071, 0.0029];
        let mut calls = 0;
        let mut f = |p: [f64; 3]| -> Result<f64, ()> {
            calls += 1;
            let d = [p[0] - m[0], p[1] - m[1], p[2] - m[2]];
            Ok(1.0 + d[0] * d[0] + 2.0 * d[1] * d[1] + 0.5 * d[2] * d[2] + 0.8 * d[0] * d[1])
        };
        let found = search(&mut f, &options(0.008, 0.002, 0.05, 1e-5)).unwrap();
        for ((p, m), c) in found.point.iter().zip(m).zip(found.curvature) {
            assert!((p - m).abs() <= 0.002 && c > 0.0, "{found:?}");
        }
        assert_eq!(found.last_step, 0.002);
        assert!(found.warnings.is_empty(), "{found:?}");
        // The region f <= 1.00001: |dz| <= 4.5 mm along z alone, bracketed by the walks.
        assert!(
            found.extent[2].iter().all(|e| (0.004..=0.01).contains(e)),
            "{found:?}"
        );
        assert!(calls < 100, "{calls} evaluations");
    }

    #[test]
    fn the_search_stays_within_its_range_and_says_so_at_its_edge() {
        let mut f = |p: [f64; 3]| -> Result<f64, ()> { Ok(-p[0] + p[1] * p[1] + p[2] * p[2]) };
        let found = search(&mut f, &options(0.01, 0.005, 0.03, 0.01)).unwrap();
        assert!((found.point[0] - 0.03).abs() < 1e-12, "{found:?}");
        assert!(found.warnings.contains(&FitWarning::AtEdge { axis: 0 }));
        // A failing objective ends the search with its error.
        let mut bad = |_: [f64; 3]| -> Result<f64, &str> { Err("no T") };
        assert_eq!(
            search(&mut bad, &options(0.01, 0.005, 0.03, 0.01)),
            Err("no T")
        );
    }

    /// Issue 47: with range, step and last step all 2 mm the search wrote
    /// (-4, -2, +4) mm, outside the range and never evaluated, with another
    /// point's objective. Now it ends on the lowest point it evaluated.
    #[test]
    fn the_search_ends_on_an_evaluated_point_when_the_range_is_one_step() {
        let m = [-0.005, -0.003, 0.006];
        let mut seen = Vec::new();
        let mut f = |p: [f64; 3]| -> Result<f64, ()> {
            let v = (0..3).map(|a| (p[a] - m[a]).powi(2)).sum::<f64>();
            seen.push((p, v));
            Ok(v)
        };
        let found = search(&mut f, &options(0.002, 0.002, 0.002, 0.02)).unwrap();
        assert_eq!(found.point, [-0.002, -0.002, 0.002]);
        let low = seen.iter().map(|s| s.1).fold(f64::INFINITY, f64::min);
        assert_eq!(found.value, low);
        assert!(seen.iter().all(|(p, _)| p.iter().all(|x| x.abs() <= 0.002)));
        for axis in 0..3 {
            assert!(found.warnings.contains(&FitWarning::AtEdge { axis }));
        }
    }

    /// A rough objective (a bowl and a ripple) within the threshold over
    /// two ripples: the extent spans both, and a low outside the walks'
    /// reach is a separated low.
    #[test]
    fn the_extent_covers_every_evaluated_point_within_the_threshold() {
        let mut f = |p: [f64; 3]| -> Result<f64, ()> {
            let ripple = 0.004 * (std::f64::consts::TAU * p[0] / 0.005).cos();
            Ok(1.0 + 40.0 * (p[0] * p[0] + p[1] * p[1] + p[2] * p[2]) - ripple)
        };
        let found = search(&mut f, &options(0.008, 0.001, 0.05, 0.01)).unwrap();
        assert!(found.point[0].abs() < 1e-12, "{found:?}");
        // 1 + 40 x^2 - ripple <= 1.0 + 0.01 (1 - 0.004) holds at x = +-5 mm.
        assert!(found.extent[0].iter().all(|e| *e > 0.005), "{found:?}");
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(64))]

        /// Whatever the objective and options, the search ends on a point it
        /// evaluated, on its last step's lattice, within its range, whose
        /// value is the lowest it evaluated; it evaluates no point twice and
        /// no more than its cap.
        #[test]
        fn the_search_ends_on_its_lowest_evaluated_point_within_its_range(
            m in prop::array::uniform3(-0.08f64..0.08),
            w in prop::array::uniform3(0.1f64..10.0),
            ripple in 0.0f64..0.01,
            period in 0.001f64..0.02,
            halvings in 0i32..4,
            range in 0.002f64..0.06,
            fraction in 0.05f64..1.0,
            rel in 0.0f64..0.2,
            cap in 1usize..120,
        ) {
            let step = range * fraction;
            let min_step = step / 2f64.powi(halvings);
            let mut seen: Vec<([f64; 3], f64)> = Vec::new();
            let mut f = |p: [f64; 3]| -> Result<f64, ()> {
                let bowl = (0..3).map(|a| w[a] * (p[a] - m[a]).powi(2)).sum::<f64>();
                let v = 0.01 + bowl + ripple * (std::f64::consts::TAU * (p[0] + p[2]) / period).sin();
                seen.push((p, v));
                Ok(v)
            };
            let o = SearchOptions { step, min_step, range, relative_threshold: rel, max_evaluations: cap, starts: 1 };
            let found = search(&mut f, &o).unwrap();
            prop_assert!(!seen.is_empty() && seen.len() <= cap);
            prop_assert_eq!(found.evaluations, seen.len());
            for (i, (p, _)) in seen.iter().enumerate() {
                prop_assert!(p.iter().all(|x| x.abs() <= range), "{:?} outside {}", p, range);
                prop_assert!(seen[..i].iter().all(|(q, _)| q != p), "{:?} twice", p);
            }
            let low = seen.iter().map(|s| s.1).fold(f64::INFINITY, f64::min);
            prop_assert_eq!(found.value, low);
            prop_assert!(seen.iter().any(|(p, v)| *p == found.point && *v == found.value));
            for x in found.point {
                let k = x / found.last_step;
                prop_assert!((k - k.round()).abs() < 1e-9, "{} off the lattice", x);
            }
            prop_assert!(found.last_step >= min_step * (1.0 - 1e-9) && found.last_step <= step);
            prop_assert!(found.extent.iter().flatten().all(|e| e.is_finite() && *e >= 0.0));
            let want = (rel * low.abs()).max(RIPPLE_FACTOR * found.ripple);
            prop_assert!((found.threshold - want).abs() <= 1e-12 * want.max(1e-300) + 1e-15);
        }
    }

    #[test]
    fn bad_selections_photos_and_options_are_errors_naming_them() {
        let scene = Scene::from_toml_str(SCENE).unwrap();
        let photo = vec![vec![vec![0.0; 16]]];
        let fit = |sel: Option<Vec<usize>>, photos: &[Vec<Vec<f64>>], range: f64| {
            let o = OccluderOptions {
                selected: sel,
                range,
                ..OccluderOptions::default()
            };
            fit_occluder(&scene, photos, &o).unwrap_err().to_string()
        };
        let e = fit(Some(vec![0, 3]), &photo, 0.05);
        assert!(e.contains("occluder 3") && e.contains("has 3"), "{e}");
        assert!(fit(Some(vec![]), &photo, 0.05).contains("empty"));
        let two = vec![photo[0].clone(), vec![vec![0.0; 16], vec![0.0; 15]]];
        let e = fit(None, &two, 0.05);
        assert!(
            e.contains("photo 1 channel 1 has 15") && e.contains("16 rows"),
            "{e}"
        );
        assert!(fit(None, &[vec![]], 0.05).contains("photo 0 has no channel"));
        assert!(fit(None, &[], 0.05).contains("no photo"));
        let e = fit(None, &photo, -0.01);
        assert!(e.starts_with("range = -0.01"), "{e}");
        assert!(fit(None, &photo, f64::NAN).starts_with("range = NaN"));
        let o = OccluderOptions {
            tolerance: -1.0,
            ..OccluderOptions::default()
        };
        let e = fit_occluder(&scene, &photo, &o).unwrap_err().to_string();
        assert!(e.starts_with("tolerance = -1"), "{e}");
        let bare = scene.clone().edit(|p| p.occluders.clear()).unwrap();
        let e = fit_occluder(&bare, &photo, &OccluderOptions::default()).unwrap_err();
        assert!(e.to_string().contains("no [[occluder]]"), "{e}");
    }

    #[test]
    fn moving_occluders_moves_only_the_selected_in_the_scene_and_its_file() {
        let scene = Scene::from_toml_str(SCENE).unwrap();
        let d = [0.01, -0.02, 0.005];
        let m = moved(&scene, &[0, 1], d, 1, ShadowModel::Point).unwrap();
        let here = Path::new("");
        let text = scene_with_occluders_moved(SCENE, here, &[0, 1], d, here).unwrap();
        let written = Scene::from_toml_str(&text).unwrap();
        assert_eq!(written.occluders(), m.occluders());
        assert_eq!(written.wall(), scene.wall());
        let (lo, hi) = bounds(&scene, &[0, 1]);
        let (lo2, hi2) = bounds(&m, &[0, 1]);
        for a in 0..3 {
            assert!((lo2[a] - lo[a] - d[a]).abs() < 1e-12);
            assert!((hi2[a] - hi[a] - d[a]).abs() < 1e-12);
        }
        assert_eq!(m.occluders()[2], scene.occluders()[2]);
        assert_eq!(lo, [-0.02, -0.03, 0.24]);
        let e = scene_with_occluders_moved(SCENE, here, &[5], d, here).unwrap_err();
        assert!(e.to_string().contains("occluder 5"), "{e}");
        // The rect at depth 0.5 of a 1 m gap casts a shadow 2x its motion:
        // half a wall element (0.1 m) per shadow pitch.
        assert!((shadow_pitch(&scene, &[0]) - 0.05).abs() < 1e-12);
    }

    /// A relative mesh path follows the scene to the new file's folder; an
    /// absolute one stays as it is.
    #[test]
    fn a_moved_scene_written_elsewhere_loads_its_meshes_from_there() {
        let root = tempfile::tempdir().unwrap();
        let (from, to) = (root.path().join("a/scenes"), root.path().join("b"));
        std::fs::create_dir_all(from.join("meshes")).unwrap();
        std::fs::create_dir_all(&to).unwrap();
        let obj = "v 0 0 0.5\nv 0.01 0 0.5\nv 0 0.01 0.5\nf 1 2 3\n";
        std::fs::write(from.join("meshes/t.obj"), obj).unwrap();
        std::fs::write(root.path().join("abs.obj"), obj).unwrap();
        let abs = root.path().join("abs.obj").canonicalize().unwrap();
        let text = format!(
            "{}\n[[occluder]]\nmesh = \"meshes/t.obj\"\noffset = [0.0, 0.001, 0.0]\n[[occluder]]\nmesh = {:?}\n",
            SCENE.split("[[occluder]]").next().unwrap(),
            abs.to_str().unwrap()
        );
        let scene = Scene::from_toml_str_in(&text, &from).unwrap();
        let d = [0.002, 0.0, -0.001];
        let out = scene_with_occluders_moved(&text, &from, &[0], d, &to).unwrap();
        assert!(out.contains("mesh = \"../a/scenes/meshes/t.obj\""), "{out}");
        assert!(
            out.contains(&format!("mesh = {:?}", abs.to_str().unwrap())),
            "{out}"
        );
        let written = Scene::from_toml_str_in(&out, &to).unwrap();
        let want = moved(&scene, &[0], d, 1, ShadowModel::Auto).unwrap();
        assert!(same_places(written.occluders(), want.occluders()));
        assert!(!same_places(written.occluders(), scene.occluders()));
        // Written in its own folder, the path is as it was.
        let same = scene_with_occluders_moved(&text, &from, &[0], d, &from).unwrap();
        assert!(same.contains("mesh = \"meshes/t.obj\""), "{same}");
    }
}
