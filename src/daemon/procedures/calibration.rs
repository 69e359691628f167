//! `POST /calibrations`: a pose's homography from a done target capture
//! (the dot target on the wall, as the pose sees it), returned with the
//! reprojection error and the scene file rewritten with it, to review.

use serde::Serialize;

use crate::calibrate::geometry::{
    detect_with_variance, fit, scene_with_homography, SceneFolders, Target,
};
use crate::daemon::requests::validate::RequestError;
use crate::solve::adequacy::Adequacy;
use crate::store::{read_mean, read_mean_variance, JobState};

/// A fitted pose.
#[derive(Debug, Clone, Serialize, utoipa::ToSchema)]
pub struct GeometryCalibration {
    /// The target capture it came from.
    pub capture: i64,
    /// Scene of the capture.
    pub scene: String,
    /// Pose calibrated.
    pub pose: String,
    /// Wall metres → pixels of the capture's frame, row-major 3x3.
    pub homography: [[f64; 3]; 3],
    /// The camera frame the homography maps into (the capture's region).
    pub region: [u32; 4],
    /// Dots found and used.
    pub dots: usize,
    /// RMS reprojection error, pixels.
    pub rms_px: f64,
    /// Largest reprojection error, pixels.
    pub max_px: f64,
    /// Whether the homography explains the dots to their centroid noise
    /// (from the capture's frame variance; `explained` is null without one).
    #[schema(value_type = Object)]
    pub model_check: Adequacy,
    /// What the user should know before trusting the homography.
    pub warnings: Vec<String>,
    /// The scene file as written (comments, order) with only this pose's
    /// homography, region and binning replaced: review it, then load it as
    /// a scene file beside the original (its relative mesh paths are read
    /// from that folder).
    pub scene_toml: String,
}

/// The width in pixels of a wall element at the wall's centre under `h`
/// (NaN without the scene).
fn element_px(h: &crate::scene::Homography, scene: Option<&crate::scene::Scene>) -> f64 {
    let Some(s) = scene else { return f64::NAN };
    let p = &s.wall().plane;
    let du = p.size[0] / p.grid.nu as f64;
    match (h.apply(0.0, 0.0), h.apply(du, 0.0)) {
        (Some(a), Some(b)) => (b.0 - a.0).hypot(b.1 - a.1),
        _ => f64::NAN,
    }
}

/// One scene's radiometric gain, as reconstructions of it use it.
#[derive(Debug, Clone, Serialize, utoipa::ToSchema)]
pub struct RadiometricGain {
    /// The scene.
    pub scene: String,
    /// Fraction of the camera's full scale per microsecond of exposure per
    /// unit of `T l`, at the camera gain the calibration was made with: a
    /// measurement is divided by it into units of `T l`. `polnlos measure
    /// --gain` with this number gives the daemon's measurement offline.
    pub gain: f64,
    /// `config` (the daemon's `[calibration]`) or `fake camera` (the demo
    /// bench's known one).
    pub source: String,
}

/// What `GET /calibrations` shows: the radiometric gains reconstructions use.
#[derive(Debug, Clone, Serialize, utoipa::ToSchema)]
pub struct Calibrations {
    /// Per scene with a gain; scenes without one are scaled so that the
    /// brightest recovered element is about 1 (relative units).
    pub radiometric: Vec<RadiometricGain>,
    /// Each scene's colour calibration in force (`POST /calibrations/colour`):
    /// the gain of each colour of a colour camera.
    pub colour: Vec<crate::daemon::ColourCalibration>,
}

impl super::Procedures {
    /// The radiometric gains in use, per scene, and where each came from.
    pub fn calibrations(&self) -> Result<Calibrations, RequestError> {
        let radiometric = self
            .services
            .calibration
            .iter()
            .map(|(scene, &gain)| RadiometricGain {
                scene: scene.clone(),
                gain,
                source: if self.services.config.calibration.contains_key(scene) {
                    "config"
                } else {
                    "fake camera"
                }
                .to_string(),
            })
            .collect();
        let rows = self.services.store.colour_calibrations().map_err(|e| {
            RequestError::Store(format!(
                "the colour calibrations could not be read: {}",
                self.services.store.describe(&e)
            ))
        })?;
        let colour = rows
            .into_iter()
            .map(|r| {
                let gain = self.services.calibration.get(&r.scene).copied();
                crate::daemon::ColourCalibration::of(r, gain, Vec::new())
            })
            .collect();
        Ok(Calibrations {
            radiometric,
            colour,
        })
    }

    /// Fits the pose of target capture `capture` to `target` (TOML text;
    /// default: the shipped `config/targets/dots-5x5.toml`).
    pub fn calibrate_geometry(
        &self,
        capture: i64,
        target: Option<&str>,
    ) -> Result<GeometryCalibration, RequestError> {
        let invalid = RequestError::Invalid;
        let c = self.services.require_capture(capture)?;
        if c.kind != crate::store::CaptureKind::Target || c.state != JobState::Done {
            return Err(invalid(format!(
                "capture {capture} is a {} capture in state {}; calibration needs a done \"kind\": \"target\" capture of the dot target on the wall",
                c.kind.name(),
                c.state.name()
            )));
        }
        let target = match target {
            Some(t) => Target::from_toml_str(t).map_err(|e| invalid(e.to_string()))?,
            None => Target::default_target(),
        };
        let dir = self.services.store.capture_dir(capture);
        let unreadable = |e| {
            invalid(format!(
                "capture {capture}: {}",
                self.services.store.describe(&e)
            ))
        };
        let mean = read_mean(&dir).map_err(unreadable)?;
        // The digitizer's rounding bias counts as noise too (measure::stack).
        let variance = read_mean_variance(&dir).map_err(unreadable)?.map(|mut v| {
            let n = c.frames as f64;
            for p in &mut v.pixels {
                *p = crate::measure::with_rounding_bias(f64::from(*p), n) as f32;
            }
            v
        });
        let f = fit(&target, &detect_with_variance(&mean, variance.as_ref()))
            .map_err(|e| invalid(format!("capture {capture}: {e}")))?;
        let mut warnings: Vec<String> = f
            .model_check
            .warning_with_causes(
                "the dots of the target capture",
                "dot centroids biased by blur or perspective, lens distortion, a target that is not flat on the wall or not the target file given",
            )
            .map(|w| {
                format!(
                    "{w} (reprojection RMS {:.3} px against a centroid noise of {:.1e} px: with a wall element {:.0} px wide, an error well below a pixel still places every element)",
                    f.rms_px,
                    f.model_check.noise_rms.unwrap_or(f64::NAN),
                    element_px(&f.homography, self.services.scenes.now().scene(&c.scene).ok().as_deref()),
                )
            })
            .into_iter()
            .collect();
        if variance.is_none() {
            warnings.push(format!(
                "capture {capture} has a single frame, so the dots' centroid noise is unknown and the fit cannot say whether the homography explains them; capture 2 frames or more"
            ));
        }
        let region = c
            .settings
            .region
            .unwrap_or([0, 0, mean.width as u32, mean.height as u32]);
        let scenes = self.services.scenes.now();
        let source = scenes
            .source(&c.scene)
            .ok_or_else(|| invalid(format!("the text of scene {:?} is not available", c.scene)))?;
        // Its relative mesh paths read from the scene file's folder, where
        // the calibrated file goes beside it.
        let folders = SceneFolders::same(scenes.folder(&c.scene));
        let scene_toml = scene_with_homography(source, &c.pose, &f.homography, region, folders)
            .map_err(|e| invalid(e.to_string()))?;
        Ok(GeometryCalibration {
            capture,
            scene: c.scene,
            pose: c.pose,
            homography: f.homography.matrix(),
            region,
            dots: f.dots,
            rms_px: f.rms_px,
            max_px: f.max_px,
            model_check: f.model_check,
            warnings,
            scene_toml,
        })
    }
}

/// A wall and radiometric fit from point-source captures.
#[derive(Debug, Clone, Serialize, utoipa::ToSchema)]
pub struct WallCalibration {
    /// The scene.
    pub scene: String,
    /// The source captures, in position order and in block order within each.
    pub captures: Vec<i64>,
    /// Each source position, its captures in block order and how much of
    /// its measurement the fit leaves unexplained.
    pub positions: Vec<FittedPosition>,
    /// Fitted alpha, ior, kd and gain (fraction of full scale per µs per
    /// unit of `T l`), with standard errors and the residual.
    #[schema(value_type = Object)]
    pub fit: crate::calibrate::wall::WallFit,
    /// The scene's `[calibration]` value in force now, for comparison.
    pub configured_gain: Option<f64>,
    /// What the user should know before trusting the fit: what the fit found
    /// (a model that does not explain the captures), then what loading the
    /// captures found (a capture without dark subtraction biases the gain).
    pub warnings: Vec<String>,
}

/// One source position of a wall calibration request: where the source was
/// and its captures (one per block, any order).
#[derive(Debug, Clone, PartialEq)]
pub struct SourcePosition {
    /// Where the source was.
    pub source: crate::calibrate::wall::PointSource,
    /// Its captures.
    pub captures: Vec<i64>,
}

/// One source position of a wall fit.
#[derive(Debug, Clone, Serialize, utoipa::ToSchema)]
pub struct FittedPosition {
    /// `[u, v]`, metres from the hidden-scene plane's centre.
    pub source: [f64; 2],
    /// Its captures, in block order.
    pub captures: Vec<i64>,
    /// `||i - model|| / ||i||` for this position.
    pub relative_residual: f64,
}

impl super::Procedures {
    /// Fits the wall of `scene` to the source captures of every position:
    /// one done `"kind": "source"` capture per (pose, angle) block of the
    /// point source at that position (hidden-plane metres), one gain for all.
    pub fn calibrate_wall(
        &self,
        scene_name: &str,
        positions: &[SourcePosition],
    ) -> Result<WallCalibration, RequestError> {
        use crate::calibrate::wall::{fit_sources_from_scene, SourceMeasurement};
        let invalid = RequestError::Invalid;
        let scene = self.services.scenes.now().scene(scene_name)?;
        // Each position's capture ids in block order, and its measurement.
        let mut ordered: Vec<Vec<i64>> = Vec::with_capacity(positions.len());
        let mut measured = Vec::with_capacity(positions.len());
        let mut warnings = Vec::new();
        for p in positions {
            let captures = self.source_captures(scene_name, &scene, &p.captures)?;
            ordered.push(captures.iter().map(|c| c.id).collect());
            let blocks = crate::transport::blocks_of(&scene);
            let mut stacked = crate::daemon::jobs::reconstruction::stack_records(
                &self.services.store,
                captures,
                &scene,
                &blocks,
                &self.services.scenes.now().pixel_maps(scene_name),
                false,
                false,
            )
            .map_err(|e| invalid(e.to_string()))?;
            // Colours not asked for: one grey measurement.
            let m = stacked.measurements.swap_remove(0);
            measured.push((m.i, m.variance));
            warnings.extend(stacked.warnings);
        }
        let sets: Vec<SourceMeasurement> = positions
            .iter()
            .zip(&measured)
            .map(|(p, (i, var))| SourceMeasurement {
                source: p.source,
                i,
                variance: var.as_deref(),
            })
            .collect();
        // A refused fit names what loading the captures found too: a missing
        // dark subtraction is a likelier cause than a misplaced source.
        let mut fit = fit_sources_from_scene(&scene, &sets, self.services.scenes.now().budget())
            .map_err(|e| match warnings.as_slice() {
                [] => invalid(e.to_string()),
                w => invalid(format!("{e}. Also: {}", w.join("; "))),
            })?;
        // What the fit itself found (a model that does not explain the
        // captures, a better polarizer model) comes first; the answer says
        // each warning once, here, not again inside `fit`.
        warnings.splice(0..0, std::mem::take(&mut fit.warnings));
        let captures = ordered.concat();
        let positions = positions
            .iter()
            .zip(ordered)
            .zip(&fit.source_residuals)
            .map(|((p, captures), &relative_residual)| FittedPosition {
                source: [p.source.u, p.source.v],
                captures,
                relative_residual,
            })
            .collect();
        Ok(WallCalibration {
            scene: scene_name.to_string(),
            captures,
            positions,
            fit,
            configured_gain: self.services.calibration.get(scene_name).copied(),
            warnings,
        })
    }

    /// The captures, in the order of the first block each serves (MODEL.md
    /// row order), together one for every block of the scene (a mosaic
    /// capture serves its pose's four), each a done source capture of the scene.
    fn source_captures(
        &self,
        scene_name: &str,
        scene: &crate::scene::Scene,
        captures: &[i64],
    ) -> Result<Vec<crate::store::CaptureRecord>, RequestError> {
        let invalid = RequestError::Invalid;
        let records: Vec<_> = captures
            .iter()
            .map(|&id| self.services.require_capture(id))
            .collect::<Result<_, _>>()?;
        let blocks = crate::transport::blocks_of(scene);
        let serves = |c: &crate::store::CaptureRecord, b: &crate::transport::Block| {
            b.taken_by(&c.pose, &c.channels)
        };
        if let Some(c) = records
            .iter()
            .find(|c| !blocks.iter().any(|b| serves(c, b)))
        {
            return Err(invalid(format!(
                "capture {} ({}) is not a block of scene {scene_name:?}",
                c.id,
                crate::daemon::jobs::capture_label(&c.pose, &c.channels)
            )));
        }
        let mut ordered: Vec<crate::store::CaptureRecord> = Vec::with_capacity(records.len());
        for block in &blocks {
            let mut serving = records.iter().filter(|c| serves(c, block));
            let c = serving.next().ok_or_else(|| {
                invalid(format!(
                    "no capture for block {}: give one \"kind\": \"source\" capture per block ({} captures for the {} blocks of scene {scene_name:?})",
                    crate::daemon::jobs::block_label(&block.pose, block.channel),
                    records.len(),
                    blocks.len()
                ))
            })?;
            if let Some(other) = serving.next() {
                return Err(invalid(format!(
                    "captures {} and {} are both for block {}: give exactly one \"kind\": \"source\" capture per block",
                    c.id,
                    other.id,
                    crate::daemon::jobs::block_label(&block.pose, block.channel)
                )));
            }
            if ordered.iter().any(|o| o.id == c.id) {
                continue;
            }
            if c.kind != crate::store::CaptureKind::Source
                || c.state != JobState::Done
                || c.scene != scene_name
            {
                return Err(invalid(format!(
                    "capture {} is a {} capture of scene {:?} in state {}; wall calibration needs done \"kind\": \"source\" captures of scene {scene_name:?}",
                    c.id, c.kind.name(), c.scene, c.state.name()
                )));
            }
            ordered.push(c.clone());
        }
        Ok(ordered)
    }
}
