//! What clients ask the daemon for: the JSON bodies of `POST /captures`,
//! `/reconstructions`, `/calibrations` and `/calibrations/wall`, as serde
//! reads them.
//!
//! They live here, beside [`validate`] and the admission that take
//! them, so the service depends on no HTTP type; the HTTP layer re-exports
//! them in `api::bodies` and documents them in its OpenAPI document (hence
//! the schema derives). Bodies refuse unknown fields, so a misspelt key is a
//! 422 naming it rather than a silently ignored setting; a whole number may
//! be written `1` or `1.0`, as JSON Schema allows.

pub(crate) mod admission;
pub(crate) mod cancel;
pub(crate) mod flatten;
pub(crate) mod import;
pub mod validate;

use serde::{Deserialize, Serialize};

use crate::camera::CameraSettings;
use crate::measure::exposure::ExposureTarget;
use crate::solve::SolveRequest;
use crate::store::CaptureKind;

use crate::daemon::SourcePosition;

pub use import::ImportQuery;

/// `POST /captures` body.
#[derive(Debug, Clone, Deserialize, utoipa::ToSchema)]
#[serde(deny_unknown_fields)]
pub struct CaptureBody {
    /// `light` (default: the hidden scene on) or `dark` (the scene switched
    /// off by the user; subtract it from later captures with `dark_capture`).
    pub kind: Option<CaptureKind>,
    /// Scene name.
    pub scene: String,
    /// Pose name in the scene.
    pub pose: String,
    /// Polarizer angle of the pose, degrees (omit or null for a pose without polarizer).
    pub polarizer_deg: Option<f64>,
    /// The camera settings: exposure per frame (`exposure_us`), gain, pixel
    /// format, region, binning and trigger, each inheriting the capture
    /// defaults (`GET /camera`, set by `PUT /camera/settings`) when absent.
    /// For a planned exposure, leave `exposure_us` out and give `"exposure": "auto"`.
    #[serde(flatten, deserialize_with = "flatten::named")]
    pub settings: CameraSettings,
    /// `"auto"`: plan the exposure (and, unless `frames` is given, the frame
    /// count) from the scene, the radiometric calibration and the camera
    /// limits (see `GET /scenes/{name}/exposure`).
    pub exposure: Option<AutoExposure>,
    /// Target of an automatic exposure (default: peak at 0.8 of full scale, SNR 100).
    pub target: Option<ExposureTarget>,
    /// Frames to average (1 to `max_frames_per_capture`); default 1, or the
    /// plan's with `"exposure": "auto"`.
    #[serde(default, deserialize_with = "crate::integral::opt_count")]
    #[schema(minimum = 1)]
    pub frames: Option<usize>,
    /// Dark frames taken within this capture with the scene switched off by
    /// the bench itself (only on a bench that can: the fake camera's). On a
    /// bench set by hand, take a `"kind": "dark"` capture instead.
    #[serde(default, deserialize_with = "crate::integral::count")]
    pub dark_frames: usize,
    /// A done dark capture (same exposure, gain, pixel format, region and
    /// binning) whose mean is subtracted from this capture's.
    #[serde(default, deserialize_with = "crate::integral::opt_int")]
    pub dark_capture: Option<i64>,
    /// Re-solve the scene from the running mean while frames accumulate, and
    /// publish each intermediate result (event `progressive`,
    /// `/captures/{id}/progressive.png` and `.json`).
    pub progressive: Option<ProgressiveBody>,
    /// Live view only (`POST /live`; a capture refuses it): reconstruct each
    /// window against a running background, so that the image shows what
    /// moves, and track it (`GET /live/track.csv`).
    pub difference: Option<DifferenceBody>,
    /// Live view only (`POST /live`; a capture refuses it): store the first
    /// `frames` frames the session receives (after its dark frames) as a new
    /// light capture, so that it can be reconstructed again offline.
    pub record: Option<RecordBody>,
}

/// A live session's recording: its first frames written, as they arrive,
/// to a new capture of the same scene, pose and camera settings (its dark
/// frames the session's, or its `dark_capture`).
#[derive(Debug, Clone, Deserialize, utoipa::ToSchema)]
#[serde(deny_unknown_fields)]
pub struct RecordBody {
    /// Frames to record (1 to `max_frames_per_capture`, with the dark
    /// frames, as a capture's `frames`); a session that ends first keeps
    /// the frames it got, and the capture's `live` says so.
    #[serde(deserialize_with = "crate::integral::count")]
    #[schema(minimum = 1)]
    pub frames: usize,
}

/// Live view's difference mode: each window's measurement less a running
/// background of the windows before it is reconstructed (`T` is linear, so
/// the image is the scene's change), and the moving object's centroid is
/// tracked in it.
#[derive(Debug, Clone, Deserialize, utoipa::ToSchema)]
#[serde(deny_unknown_fields)]
pub struct DifferenceBody {
    /// The background's time constant, seconds (0.1 to 3600, default 10):
    /// the mean of the windows so far until they span it, then an
    /// exponential running mean that forgets with it.
    pub background_s: Option<f64>,
}

/// `PUT /camera/settings` body: any subset of the camera settings; what it
/// leaves out keeps its current default.
///
/// Why a subset: a client that means to change one setting must not have to
/// restate (and so risk resetting) the others.
#[derive(Debug, Clone, Deserialize, utoipa::ToSchema)]
#[serde(deny_unknown_fields)]
pub struct SettingsBody {
    /// The settings to change.
    #[serde(flatten, deserialize_with = "flatten::named")]
    pub change: CameraSettings,
}

/// Progressive reconstruction during a capture: ADMM-TV on the running mean
/// (dark-subtracted), warm-started from the previous result with its
/// factorization kept, so each step costs a few iterations.
#[derive(Debug, Clone, Deserialize, Serialize, PartialEq, utoipa::ToSchema)]
#[serde(deny_unknown_fields)]
pub struct ProgressiveBody {
    /// Re-solve after every this many frames (default: a tenth of the frames, at least 1).
    #[serde(default, deserialize_with = "crate::integral::opt_count")]
    #[schema(minimum = 1)]
    pub every: Option<usize>,
    /// Done light captures of the scene's other (pose, angle) blocks (none
    /// for a scene with one block, such as `brewster-crossed`).
    #[serde(default, deserialize_with = "crate::integral::ints")]
    pub captures: Vec<i64>,
    /// TV weight, MODEL.md units (default `1e-2 mean(diag(T^T T))`); the
    /// same at every step, so the steps compare.
    pub lambda: Option<f64>,
    /// Iteration cap of each step (1-100000, default 500).
    #[serde(default, deserialize_with = "crate::integral::opt_count")]
    #[schema(minimum = 1, maximum = 100000)]
    pub max_iter: Option<usize>,
    /// Known truth, as a test pattern name: each step then has its PSNR.
    pub truth: Option<String>,
    /// `calibrated` (divided by the scene's calibrated gain) or `fitted`
    /// (each step fits gain and background per colour with the scene, as a
    /// reconstruction with `"radiometry": "fitted"` does). Absent: chosen as
    /// the reconstruction chooses it (fitted for a scene with no calibrated
    /// gain, or colours with no colour calibration); difference mode needs
    /// a calibrated gain.
    #[serde(default)]
    pub radiometry: Option<crate::solve::radiometry::Radiometry>,
}

/// The only automatic exposure mode.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize, Serialize, utoipa::ToSchema)]
#[serde(rename_all = "lowercase")]
pub enum AutoExposure {
    /// Plan from the scene (see `crate::measure::exposure`).
    Auto,
}

/// `POST /reconstructions` body.
#[derive(Debug, Clone, Deserialize, Serialize, utoipa::ToSchema)]
#[serde(deny_unknown_fields)]
pub struct ReconstructionBody {
    /// Scene name.
    pub scene: String,
    /// One finished capture per (pose, polarizer angle) block of the scene.
    #[serde(deserialize_with = "crate::integral::ints")]
    #[schema(min_items = 1)]
    pub captures: Vec<i64>,
    /// The solver and its parameters: `solver` (`admm-tv` by default),
    /// `lambda`, `rho`, `max_iter`, `tol` and `rcond`, each absent for its
    /// default (see `SolveRequest`).
    #[serde(flatten, deserialize_with = "flatten::named")]
    pub solve: SolveRequest,
    /// Known truth: a test pattern's name (`disk`, `bars`, `letter`), or
    /// `{"image": [[...], ...]}`, an image on the scene's grid top row first
    /// (grey values, or `[red, green, blue]` a pixel): the report then
    /// carries PSNR, ZNCC and SSIM (e.g. against the fake camera's demo
    /// scene, or the picture a hidden screen showed).
    pub truth: Option<crate::store::Truth>,
    /// `true`: solve from the blocks these captures give and leave the
    /// scene's other blocks out (an interim image while blocks are still
    /// being captured; its κ and λ are those of the fewer rows). Default
    /// `false`: one capture for every block of the scene.
    #[serde(default)]
    pub partial: bool,
    /// `calibrated` (divided by the scene's calibrated gain, dark frames
    /// subtracted) or `fitted` (gain and background per channel fitted with
    /// the scene, as `polnlos reconstruct --photo`). Absent: fitted for
    /// imported captures and scenes with no calibrated gain, else
    /// calibrated; the report's `radiometry` says which and why.
    pub radiometry: Option<crate::solve::radiometry::Radiometry>,
}

/// `POST /plans` body: acquire every (pose, angle) block of a scene, then
/// reconstruct from the captures.
#[derive(Debug, Clone, Deserialize, Serialize, utoipa::ToSchema)]
#[serde(deny_unknown_fields)]
pub struct PlanBody {
    /// Scene name.
    pub scene: String,
    /// The camera settings of every capture it takes (exposure_us, gain,
    /// pixel format, region, binning, trigger), each inheriting the capture
    /// defaults when absent, as in `POST /captures`. For planned exposures,
    /// leave `exposure_us` out and give `"exposure": "auto"`.
    #[serde(flatten, deserialize_with = "flatten::named")]
    pub settings: CameraSettings,
    /// `"auto"`: each block's exposure and frame count planned from the scene.
    pub exposure: Option<AutoExposure>,
    /// Frames per block (default 1, or the plan's with `"exposure": "auto"`).
    #[serde(default, deserialize_with = "crate::integral::opt_count")]
    #[schema(minimum = 1)]
    pub frames: Option<usize>,
    /// Dark frames per block: taken within each capture on a bench that
    /// switches the scene off itself, else as a dark capture between two
    /// operator steps (scene off, scene on).
    #[serde(default, deserialize_with = "crate::integral::count")]
    pub dark_frames: usize,
    /// The reconstruction queued when every block is captured (default: ADMM-TV, automatic λ).
    #[serde(default)]
    pub reconstruct: PlanReconstruct,
    /// A calibration shot: once every block is captured, fit the scene's
    /// geometry to the light captures (`POST /calibrations/scene`) before
    /// the reconstruction, which then uses it (none unless set).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub calibrate_scene: Option<PlanSceneFit>,
}

/// A plan's calibration shot: what `POST /calibrations/scene` is asked
/// besides the scene and the plan's light captures.
#[derive(Debug, Clone, Deserialize, Serialize, utoipa::ToSchema)]
#[serde(deny_unknown_fields)]
pub struct PlanSceneFit {
    /// The image the hidden monitor shows (a pattern name or an image, top
    /// row first); absent: the scene is unknown and fitted with the geometry.
    pub known: Option<crate::store::Truth>,
    /// What is fitted (default: the occluders' translation, the hidden
    /// plane's offset and the distance).
    pub free: Option<Vec<String>>,
}

/// The reconstruction a plan ends with.
#[derive(Debug, Clone, Default, Deserialize, Serialize, utoipa::ToSchema)]
#[serde(deny_unknown_fields)]
pub struct PlanReconstruct {
    /// The solver and its parameters, as in `POST /reconstructions`:
    /// `solver`, `lambda`, `rho`, `max_iter`, `tol` and `rcond`.
    #[serde(flatten, deserialize_with = "flatten::named")]
    pub solve: SolveRequest,
    /// Known truth, as a test pattern name: the report then has PSNR.
    pub truth: Option<String>,
    /// `calibrated` or `fitted`, as in `POST /reconstructions` (absent:
    /// chosen from what the daemon knows of the scene).
    pub radiometry: Option<crate::solve::radiometry::Radiometry>,
    /// After each light block but the last, queue a reconstruction from the
    /// blocks captured so far (`partial`), so that the image sharpens as the
    /// plan walks the scene; the plan lists them as `interim`.
    #[serde(default)]
    pub interim: bool,
    /// Re-solve the whole scene while the last block's frames accumulate,
    /// every this many frames, from the other blocks' captures and the
    /// running mean (a progressive capture; needs the scene's `[calibration]`).
    #[serde(default, deserialize_with = "crate::integral::opt_count")]
    #[schema(minimum = 1)]
    pub progressive_every: Option<usize>,
}

/// `POST /mount/zero` body.
#[derive(Debug, Clone, Deserialize, utoipa::ToSchema)]
#[serde(deny_unknown_fields)]
pub struct ZeroBody {
    /// The pose the camera is at (its polarizer is the one the mount turns).
    pub pose: String,
    /// Scene the pose belongs to (the fake bench shows its light).
    pub scene: String,
    /// The camera settings of the sweep's frames (exposure_us, gain, ...),
    /// each inheriting the capture defaults when absent, as in `POST /captures`.
    #[serde(flatten, deserialize_with = "flatten::named")]
    pub settings: CameraSettings,
    /// Frames averaged per angle (1-100, default 8).
    #[serde(default, deserialize_with = "crate::integral::opt_count")]
    #[schema(minimum = 1, maximum = 100)]
    pub frames: Option<usize>,
    /// Half-width of the sweep around the current zero, degrees (1-45, default 30).
    pub span_deg: Option<f64>,
    /// Step of the sweep, degrees (0.1-10, default 5).
    pub step_deg: Option<f64>,
    /// The light swept: `source` (default), the calibration point source
    /// near the hidden scene's centre (as for a wall calibration), or
    /// `scene`, the hidden scene's own light.
    #[serde(default)]
    pub light: ZeroLight,
}

/// The light a zero sweep looks at.
///
/// Why the point source by default: crossed is defined for the path from
/// the scene's centre through the wall's (MODEL.md); light from an extended
/// scene arrives in other planes of incidence, and its least-light angle
/// sits off crossed (measured on the demo bench's letter: 1.4° at the wall
/// centre's pixels, 0.55° over the whole frame; the point source 3.6 cm
/// from the centre: 0.1°).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Deserialize, utoipa::ToSchema)]
#[serde(rename_all = "lowercase")]
pub enum ZeroLight {
    /// The point source in place of the hidden scene.
    #[default]
    Source,
    /// The hidden scene's own light.
    Scene,
}

/// `POST /calibrations` body.
#[derive(Debug, Clone, Deserialize, utoipa::ToSchema)]
#[serde(deny_unknown_fields)]
pub struct CalibrationBody {
    /// A done `"kind": "target"` capture of the dot target on the wall.
    #[serde(deserialize_with = "crate::integral::int")]
    pub capture: i64,
    /// The target as TOML text (`radius_m`, `dots` in wall metres); default
    /// the shipped `config/targets/dots-5x5.toml`, which the demo bench shows.
    pub target: Option<String>,
}

/// `POST /calibrations/colour` body.
#[derive(Debug, Clone, Deserialize, utoipa::ToSchema)]
#[serde(deny_unknown_fields)]
pub(crate) struct ColourCalibrationBody {
    /// A done light capture, through a colour camera, of a white or grey
    /// field (a white card on the hidden side, or the bench lit evenly).
    #[serde(deserialize_with = "crate::integral::int")]
    pub capture: i64,
}

/// `POST /calibrations/wall` body: one source position (`source` and
/// `captures`) or several positions of the same source (`sources`).
#[derive(Debug, Clone, Deserialize, utoipa::ToSchema)]
#[serde(deny_unknown_fields)]
pub struct WallCalibrationBody {
    /// Scene name (its wall, poses and hidden-scene plane).
    pub scene: String,
    /// One done `"kind": "source"` capture per (pose, angle) block.
    #[serde(default, deserialize_with = "crate::integral::ints")]
    pub captures: Vec<i64>,
    /// Source position `[u, v]`, metres from the hidden-scene plane's centre
    /// (the fake bench's source is at [0.03, -0.02]).
    #[schema(min_items = 2, max_items = 2)]
    pub source: Option<[f64; 2]>,
    /// Instead of `source` and `captures`: several positions of the same
    /// source (its radiance unchanged), fitted together with one gain.
    #[serde(default)]
    pub sources: Vec<SourcePositionBody>,
}

/// One source position of a wall calibration and its captures.
#[derive(Debug, Clone, Deserialize, utoipa::ToSchema)]
#[serde(deny_unknown_fields)]
pub struct SourcePositionBody {
    /// `[u, v]`, metres from the hidden-scene plane's centre.
    #[schema(min_items = 2, max_items = 2)]
    pub source: [f64; 2],
    /// One done `"kind": "source"` capture per (pose, angle) block.
    #[serde(deserialize_with = "crate::integral::ints")]
    #[schema(min_items = 1, max_items = 64)]
    pub captures: Vec<i64>,
}

/// Most captures per source position in a wall calibration request.
pub const MAX_CAPTURES_PER_POSITION: usize = 64;

/// Why a wall calibration's source positions are refused (naming the
/// position or the capture).
#[derive(Debug, thiserror::Error)]
pub enum PositionsError {
    /// Neither form was given.
    #[error("give \"source\" and \"captures\", or \"sources\" (several positions)")]
    NoForm,
    /// Both forms were given.
    #[error("give either \"source\" and \"captures\" or \"sources\", not both")]
    BothForms,
    /// More positions than are fitted together.
    #[error("{0} source positions; at most {max} are fitted together", max = crate::calibrate::wall::MAX_SOURCES)]
    TooMany(usize),
    /// A position with a coordinate that is not a finite number.
    #[error("source [{}, {}]: the position must be two finite numbers (metres)", .0[0], .0[1])]
    NotFinite([f64; 2]),
    /// A position with no capture, or more than one per block allows.
    #[error("source [{}, {}]: {count} captures; give 1 to {MAX_CAPTURES_PER_POSITION} (one per block)", at[0], at[1])]
    Captures {
        /// The position.
        at: [f64; 2],
        /// How many captures it was given.
        count: usize,
    },
    /// One capture given at two positions.
    #[error("capture {0} is given twice: one capture is of one position")]
    Twice(i64),
}

impl WallCalibrationBody {
    /// The source positions and their captures: exactly one of the two forms,
    /// 1 to [`MAX_SOURCES`](crate::calibrate::wall::MAX_SOURCES) positions of
    /// finite coordinates, each with 1 to [`MAX_CAPTURES_PER_POSITION`]
    /// captures, and no capture at two positions.
    pub fn positions(&self) -> Result<Vec<SourcePosition>, PositionsError> {
        use crate::calibrate::wall::{PointSource, MAX_SOURCES};
        let given: Vec<([f64; 2], &[i64])> = match (self.source, self.sources.is_empty()) {
            (Some(source), true) => vec![(source, &self.captures[..])],
            (None, false) if self.captures.is_empty() => self
                .sources
                .iter()
                .map(|p| (p.source, &p.captures[..]))
                .collect(),
            (None, true) => return Err(PositionsError::NoForm),
            _ => return Err(PositionsError::BothForms),
        };
        if given.len() > MAX_SOURCES {
            return Err(PositionsError::TooMany(given.len()));
        }
        let mut seen = std::collections::HashSet::new();
        given
            .into_iter()
            .map(|(source, captures)| {
                if source.iter().any(|x| !x.is_finite()) {
                    return Err(PositionsError::NotFinite(source));
                }
                if captures.is_empty() || captures.len() > MAX_CAPTURES_PER_POSITION {
                    return Err(PositionsError::Captures {
                        at: source,
                        count: captures.len(),
                    });
                }
                if let Some(&id) = captures.iter().find(|&&id| !seen.insert(id)) {
                    return Err(PositionsError::Twice(id));
                }
                Ok(SourcePosition {
                    source: PointSource {
                        u: source[0],
                        v: source[1],
                    },
                    captures: captures.to_vec(),
                })
            })
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// `json` read as the API reads a body, and its 422 detail.
    fn body<T: serde::de::DeserializeOwned>(json: &str) -> Result<T, String> {
        let v: serde_json::Value = serde_json::from_str(json).map_err(|e| e.to_string())?;
        serde_path_to_error::deserialize(v).map_err(|e| match e.path().to_string().as_str() {
            "." => e.inner().to_string(),
            path => format!("{path}: {}", e.inner()),
        })
    }

    #[test]
    fn the_solver_parameters_sit_in_the_bodies_as_before_and_errors_name_them() {
        use crate::solve::Solver;
        let b: ReconstructionBody = body(
            r#"{"scene": "s", "captures": [1, 2.0], "solver": "lsq", "lambda": 0.5, "rho": 2,
                "max_iter": 40.0, "tol": 1e-3, "rcond": 0.01, "truth": "disk", "partial": true}"#,
        )
        .unwrap();
        let want = SolveRequest {
            solver: Solver::LSQ,
            lambda: Some(0.5),
            rho: Some(2.0),
            max_iter: Some(40),
            tol: Some(1e-3),
            rcond: Some(0.01),
        };
        assert_eq!((&b.solve, b.captures.as_slice()), (&want, &[1, 2][..]));
        assert!(b.partial && b.truth.as_ref().and_then(|t| t.pattern()) == Some("disk"));
        let b: ReconstructionBody = body(r#"{"scene": "s", "captures": [1]}"#).unwrap();
        assert_eq!(b.solve, SolveRequest::default());
        // Written back with the same keys, side by side.
        let v = serde_json::to_value(&b).unwrap();
        for k in [
            "scene", "captures", "solver", "lambda", "rho", "max_iter", "tol", "rcond",
        ] {
            assert!(v.get(k).is_some(), "{k}: {v}");
        }
        for (json, says) in [
            (r#""max_iter": -1"#, "max_iter: -1 is negative"),
            (
                r#""max_iter": 1.5"#,
                "max_iter: invalid value: floating point `1.5`",
            ),
            (r#""solver": "cg""#, "solver: unknown variant `cg`"),
            (r#""lambda": "x""#, "lambda: invalid type: string"),
            (r#""colour": 1"#, "unknown field `colour`"),
        ] {
            let e = body::<ReconstructionBody>(&format!(
                r#"{{"scene": "s", "captures": [1], {json}}}"#
            ))
            .unwrap_err();
            assert!(e.contains(says), "{json}: {e}");
        }
        // A plan's reconstruction takes the same parameters (rho, tol and
        // rcond too), and reads back what it stored.
        let p: PlanBody = body(
            r#"{"scene": "s", "reconstruct": {"solver": "lsq", "lambda": 0.5, "rho": 2,
                "max_iter": 40, "tol": 1e-3, "rcond": 0.01, "truth": "disk", "interim": true}}"#,
        )
        .unwrap();
        assert_eq!(p.reconstruct.solve, want);
        assert!(p.reconstruct.interim);
        let back: PlanBody = serde_json::from_value(serde_json::to_value(&p).unwrap()).unwrap();
        assert_eq!(back.reconstruct.solve, want);
        let p: PlanBody = body(r#"{"scene": "s"}"#).unwrap();
        assert_eq!(p.reconstruct.solve, SolveRequest::default());
        for (json, says) in [
            (r#""max_iter": -1"#, "reconstruct: max_iter: -1 is negative"),
            (r#""colour": 1"#, "reconstruct: unknown field `colour`"),
        ] {
            let e = body::<PlanBody>(&format!(r#"{{"scene": "s", "reconstruct": {{{json}}}}}"#))
                .unwrap_err();
            assert!(e.contains(says), "{json}: {e}");
        }
    }

    fn wall(json: &str) -> Result<Vec<SourcePosition>, String> {
        serde_json::from_str::<WallCalibrationBody>(json)
            .map_err(|e| e.to_string())?
            .positions()
            .map_err(|e| e.to_string())
    }

    #[test]
    fn a_recording_is_a_whole_count_of_frames_and_names_its_field() {
        let b: CaptureBody =
            body(r#"{"scene": "s", "pose": "A", "record": {"frames": 16.0}}"#).unwrap();
        assert_eq!(b.record.map(|r| r.frames), Some(16));
        for (json, says) in [
            (r#"{"frames": -1}"#, "record.frames: -1 is negative"),
            (r#"{"frames": 1.5}"#, "record.frames: invalid value"),
            (r#"{}"#, "record: missing field `frames`"),
            (
                r#"{"frames": 2, "every": 1}"#,
                "record.every: unknown field `every`",
            ),
        ] {
            let e = body::<CaptureBody>(&format!(
                r#"{{"scene": "s", "pose": "A", "record": {json}}}"#
            ))
            .unwrap_err();
            assert!(e.contains(says), "{json}: {e}");
        }
    }

    #[test]
    fn a_wall_calibration_names_one_or_several_positions_but_not_both() {
        let one = wall(r#"{"scene": "s", "captures": [1, 2], "source": [0.03, -0.02]}"#).unwrap();
        assert_eq!(one.len(), 1);
        assert_eq!((one[0].source.u, one[0].source.v), (0.03, -0.02));
        assert_eq!(one[0].captures, [1, 2]);
        let two = wall(
            r#"{"scene": "s", "sources": [{"source": [0.03, -0.02], "captures": [1]}, {"source": [-0.06, 0.05], "captures": [2]}]}"#,
        )
        .unwrap();
        assert_eq!(two.len(), 2);
        assert_eq!(two[1].captures, [2]);
        assert_eq!(two[1].source.u, -0.06);
        for (json, says) in [
            (r#"{"scene": "s"}"#, "or \"sources\""),
            (r#"{"scene": "s", "captures": [1]}"#, "or \"sources\""),
            (
                r#"{"scene": "s", "captures": [1], "source": [0, 0], "sources": [{"source": [0, 0], "captures": [2]}]}"#,
                "not both",
            ),
            (
                r#"{"scene": "s", "captures": [1], "sources": [{"source": [0, 0], "captures": [2]}]}"#,
                "not both",
            ),
            (
                r#"{"scene": "s", "captures": [], "source": [0, 0]}"#,
                "0 captures",
            ),
            (
                r#"{"scene": "s", "sources": [{"source": [0, 0], "captures": [1]}, {"source": [0.01, 0], "captures": [1]}]}"#,
                "capture 1 is given twice",
            ),
            (
                r#"{"scene": "s", "captures": [1], "source": [0, 1e400]}"#,
                "number out of range",
            ),
            (
                r#"{"scene": "s", "captures": [1], "source": [0]}"#,
                "invalid length 1",
            ),
        ] {
            let e = wall(json).expect_err(json);
            assert!(e.contains(says), "{json}: {e}");
        }
        let many: Vec<String> = (0..=crate::calibrate::wall::MAX_SOURCES)
            .map(|k| format!(r#"{{"source": [0, 0], "captures": [{k}]}}"#))
            .collect();
        let e = wall(&format!(
            r#"{{"scene": "s", "sources": [{}]}}"#,
            many.join(",")
        ))
        .unwrap_err();
        assert!(e.contains("at most 16"), "{e}");
        let ids: Vec<String> = (0..=MAX_CAPTURES_PER_POSITION)
            .map(|k| k.to_string())
            .collect();
        let e = wall(&format!(
            r#"{{"scene": "s", "captures": [{}], "source": [0, 0]}}"#,
            ids.join(",")
        ))
        .unwrap_err();
        assert!(e.contains("65 captures"), "{e}");
    }
}
