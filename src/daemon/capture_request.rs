//! The capture request and its validation: every camera setting the capture
//! uses is resolved and recorded when it is accepted, so a later
//! `PUT /camera/settings` cannot change it; a dark capture must match the
//! light capture it is subtracted from; dark frames within a capture only on
//! a bench that switches the scene off itself.

use serde::Deserialize;

use super::jobs::{camera_limits, exposure_plan, same_angle};
use super::{Daemon, RequestError};
use crate::camera::{PixelFormat, TriggerMode};
use crate::measure::exposure::ExposureTarget;
use crate::store::{capture_bytes, CaptureKind, CaptureRequest, JobState};

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
    /// Exposure per frame, microseconds; omit it and give `"exposure": "auto"`
    /// to have it planned (see `GET /scenes/{name}/exposure`).
    pub exposure_us: Option<f64>,
    /// `"auto"`: plan the exposure (and, unless `frames` is given, the frame
    /// count) from the scene, the radiometric calibration and the camera limits.
    pub exposure: Option<AutoExposure>,
    /// Target of an automatic exposure (default: peak at 0.8 of full scale, SNR 100).
    pub target: Option<ExposureTarget>,
    /// Gain (camera units).
    #[serde(default)]
    pub gain: f64,
    /// Frames to average (1 to `max_frames_per_capture`); default 1, or the
    /// plan's with `"exposure": "auto"`.
    pub frames: Option<usize>,
    /// Dark frames taken within this capture with the scene switched off by
    /// the bench itself (only on a bench that can: the fake camera's). On a
    /// bench set by hand, take a `"kind": "dark"` capture instead.
    #[serde(default)]
    pub dark_frames: usize,
    /// A done dark capture (same exposure, gain, pixel format, region and
    /// binning) whose mean is subtracted from this capture's.
    pub dark_capture: Option<i64>,
    /// Pixel format (default: the camera's current settings).
    pub pixel_format: Option<PixelFormat>,
    /// Region `[x, y, width, height]` (default: the current settings).
    pub region: Option<[u32; 4]>,
    /// Binning `[x, y]` (default: the current settings).
    pub binning: Option<[u32; 2]>,
    /// `free` or `software` (default: the current settings).
    pub trigger: Option<TriggerMode>,
}

/// The only automatic exposure mode.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize, utoipa::ToSchema)]
#[serde(rename_all = "lowercase")]
pub enum AutoExposure {
    /// Plan from the scene (see [`crate::measure::exposure`]).
    Auto,
}

fn invalid(m: impl Into<String>) -> RequestError {
    RequestError::Invalid(m.into())
}

/// Checks that `polarizer_deg` is a setting of the pose (or absent for a pose without polarizer).
fn check_block(
    scene_name: &str,
    pose: &crate::scene::Pose,
    polarizer_deg: Option<f64>,
) -> Result<(), RequestError> {
    let angles: Vec<f64> = pose.analyzers.iter().map(|a| a.angle_deg).collect();
    let list = || {
        angles
            .iter()
            .map(|a| a.to_string())
            .collect::<Vec<_>>()
            .join(", ")
    };
    match (polarizer_deg, angles.is_empty()) {
        (None, true) => Ok(()),
        (Some(a), false) if angles.iter().any(|x| same_angle(Some(*x), Some(a))) => Ok(()),
        (None, false) => Err(invalid(format!(
            "pose {:?} of scene {scene_name:?} has a polarizer: give polarizer_deg, one of {}",
            pose.name,
            list()
        ))),
        (Some(a), true) => Err(invalid(format!(
            "pose {:?} of scene {scene_name:?} has no polarizer, but polarizer_deg = {a} was given",
            pose.name
        ))),
        (Some(a), false) => Err(invalid(format!(
            "polarizer_deg = {a} is not an angle of pose {:?} (scene {scene_name:?}): {}",
            pose.name,
            list()
        ))),
    }
}

/// Checks a capture request against the scene, the camera's ranges and the
/// bench, and resolves every camera setting it will use.
pub fn validate_capture(d: &Daemon, b: &CaptureBody) -> Result<CaptureRequest, RequestError> {
    let scene = d.scenes.get(&b.scene).ok_or_else(|| {
        RequestError::NotFound(format!(
            "unknown scene {:?}; known: {}",
            b.scene,
            d.scenes.names().join(", ")
        ))
    })?;
    let pose = scene.pose(&b.pose).ok_or_else(|| {
        invalid(format!(
            "scene {:?} has no pose {:?}; its poses: {}",
            b.scene,
            b.pose,
            scene
                .poses
                .iter()
                .map(|p| p.name.as_str())
                .collect::<Vec<_>>()
                .join(", ")
        ))
    })?;
    check_block(&b.scene, pose, b.polarizer_deg)?;
    let kind = b.kind.unwrap_or(CaptureKind::Light);
    let info = d.camera.status().info;
    let limits = camera_limits(d, info.as_ref());
    let (lo, hi) = limits.exposure_us;
    let (exposure_us, planned) = match (b.exposure_us, b.exposure) {
        (Some(_), Some(_)) => {
            return Err(invalid(
                "give either exposure_us or \"exposure\": \"auto\", not both",
            ))
        }
        (None, None) => {
            return Err(invalid(
                "exposure_us is missing: give it in microseconds, or \"exposure\": \"auto\"",
            ))
        }
        (Some(e), None) => {
            if b.target.is_some() {
                return Err(invalid("target is only for \"exposure\": \"auto\""));
            }
            (e, None)
        }
        (None, Some(AutoExposure::Auto)) => {
            let plan = exposure_plan(d, &b.scene, &b.target.unwrap_or_default(), &limits)?;
            let block = plan
                .into_iter()
                .find(|p| p.pose == b.pose && same_angle(p.polarizer_deg, b.polarizer_deg))
                .ok_or_else(|| {
                    invalid(format!(
                        "the exposure plan of scene {:?} has no block for pose {:?}",
                        b.scene, b.pose
                    ))
                })?;
            (block.exposure_us, Some(block))
        }
    };
    if !(exposure_us >= lo && exposure_us <= hi) {
        return Err(invalid(format!(
            "exposure_us = {exposure_us}: must be from {lo} to {hi} microseconds"
        )));
    }
    let frames = b
        .frames
        .unwrap_or_else(|| planned.as_ref().map(|p| p.frames).unwrap_or(1));
    let (glo, ghi) = info.as_ref().map(|i| i.gain).unwrap_or((0.0, f64::MAX));
    if !(b.gain >= glo && b.gain <= ghi) {
        return Err(invalid(format!(
            "gain = {}: must be from {glo} to {ghi}",
            b.gain
        )));
    }
    let max = d.config.queue.max_frames_per_capture;
    if frames == 0 || frames.saturating_add(b.dark_frames) > max {
        return Err(invalid(format!(
            "frames = {frames}, dark_frames = {}: need at least 1 frame and at most {max} in all ([queue] max_frames_per_capture)",
            b.dark_frames
        )));
    }
    if b.dark_frames > 0 && !d.bench.switches_scene() {
        return Err(invalid(
            "this bench cannot switch the hidden scene off by itself, so dark frames cannot be taken within a capture: switch the scene off, POST a capture with \"kind\": \"dark\", switch it back on, and give that capture's id as dark_capture",
        ));
    }
    if kind == CaptureKind::Dark && (b.dark_frames > 0 || b.dark_capture.is_some()) {
        return Err(invalid(
            "a dark capture takes no dark_frames and no dark_capture of its own",
        ));
    }
    if b.dark_frames > 0 && b.dark_capture.is_some() {
        return Err(invalid("give dark_frames or dark_capture, not both"));
    }
    // Everything the capture does not state, it inherits now and records.
    let current = d.capture_defaults(info.as_ref());
    let binning = b.binning.or(current.binning).unwrap_or([1, 1]);
    let region = b.region.or(current.region).ok_or_else(|| {
        RequestError::Unavailable(
            "the camera has not reported its region yet: give region = [x, y, width, height], or retry when GET /camera shows it connected".into(),
        )
    })?;
    if let Some(i) = &info {
        i.limits
            .check(region, binning)
            .map_err(|e| invalid(e.to_string()))?;
    }
    let request = CaptureRequest {
        kind,
        scene: b.scene.clone(),
        pose: b.pose.clone(),
        polarizer_deg: b.polarizer_deg,
        exposure_us,
        gain: b.gain,
        frames,
        dark_frames: b.dark_frames,
        pixel_format: b.pixel_format.unwrap_or(current.pixel_format),
        region,
        binning,
        trigger: b.trigger.unwrap_or(current.trigger),
        dark_capture: b.dark_capture,
    };
    if let Some(id) = b.dark_capture {
        check_dark_capture(d, id, &request)?;
    }
    Ok(request)
}

/// A dark capture fits a light one when it is done, dark, and taken with the
/// same exposure, gain, pixel format, region and binning.
fn check_dark_capture(d: &Daemon, id: i64, r: &CaptureRequest) -> Result<(), RequestError> {
    let c = d.store.capture(id).map_err(|_| {
        RequestError::NotFound(format!("dark_capture {id}: no capture with that id"))
    })?;
    if !c.is_dark() || c.state != JobState::Done {
        return Err(invalid(format!(
            "dark_capture {id} is a {} capture in state {}; it must be a done dark capture",
            c.kind,
            c.state.name()
        )));
    }
    let same = c.exposure_us == r.exposure_us
        && c.gain == r.gain
        && c.pixel_format == r.pixel_format.name()
        && c.region == Some(r.region)
        && c.binning == Some(r.binning);
    if !same {
        return Err(invalid(format!(
            "dark_capture {id} was taken at exposure_us {}, gain {}, {}, region {:?}, binning {:?}; this capture asks for {}, {}, {}, {:?}, {:?}: take a dark capture with the same settings",
            c.exposure_us, c.gain, c.pixel_format, c.region, c.binning,
            r.exposure_us, r.gain, r.pixel_format.name(), r.region, r.binning
        )));
    }
    Ok(())
}

/// Disk bytes a capture request's files take at most.
pub fn request_bytes(r: &CaptureRequest) -> u64 {
    capture_bytes(r.region[2], r.region[3], r.frames, r.dark_frames)
}
