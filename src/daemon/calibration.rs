//! `POST /calibrations`: a pose's homography from a done target capture
//! (the dot target on the wall, as the pose sees it), returned with the
//! reprojection error and the scene file rewritten with it, to review.

use serde::Serialize;

use super::validate::RequestError;
use super::Daemon;
use crate::calibrate::geometry::{detect, fit, scene_with_homography, Target};
use crate::store::{read_mean, JobState};

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
    /// The scene file with this pose's homography, region and binning
    /// replaced (comments not kept): review it, then load it as a scene file.
    pub scene_toml: String,
}

impl Daemon {
    /// Fits the pose of target capture `capture` to `target` (TOML text;
    /// default: the shipped `config/targets/dots-5x5.toml`).
    pub fn calibrate_geometry(
        &self,
        capture: i64,
        target: Option<&str>,
    ) -> Result<GeometryCalibration, RequestError> {
        let invalid = RequestError::Invalid;
        let c = self
            .store
            .capture(capture)
            .map_err(|_| RequestError::NotFound(format!("no capture with id {capture}")))?;
        if c.kind != crate::store::CaptureKind::Target.name() || c.state != JobState::Done {
            return Err(invalid(format!(
                "capture {capture} is a {} capture in state {}; calibration needs a done \"kind\": \"target\" capture of the dot target on the wall",
                c.kind,
                c.state.name()
            )));
        }
        let target = match target {
            Some(t) => Target::from_toml_str(t).map_err(|e| invalid(e.to_string()))?,
            None => Target::default_target(),
        };
        let mean = read_mean(&self.store.capture_dir(capture))
            .map_err(|e| invalid(format!("capture {capture}: {}", self.store.describe(&e))))?;
        let f =
            fit(&target, &detect(&mean)).map_err(|e| invalid(format!("capture {capture}: {e}")))?;
        let region = c
            .region
            .unwrap_or([0, 0, mean.width as u32, mean.height as u32]);
        let source = self
            .scenes
            .source(&c.scene)
            .ok_or_else(|| invalid(format!("the text of scene {:?} is not available", c.scene)))?;
        let scene_toml = scene_with_homography(source, &c.pose, &f.homography, region)
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
            scene_toml,
        })
    }
}
