//! Checking requests: pure functions from a request body, the scene it names
//! and what the camera allows, to a request the daemon can queue.
//!
//! Nothing here reads the camera, the store or the clock: the daemon gathers
//! what a check needs ([`CameraContext`], a capture lookup, a lazily built
//! blocks' exposures) and these functions decide, so every rule has a unit test.
//! A capture lookup answers `Ok(None)` when there is no such capture and an
//! error when the catalogue cannot be read; the checks pass that error on
//! instead of calling the capture missing.
//! Every setting a capture uses is resolved here and recorded with it, so a
//! later `PUT /camera/settings` cannot change a queued capture.

mod capture;
mod progressive;
mod reconstruction;

pub use capture::capture;
pub(crate) use progressive::{difference, recording};
pub use progressive::{progressive, ProgressiveSpec};
pub use reconstruction::reconstruction;

use crate::camera::{CameraRanges, CameraSettings, SensorLimits};
use crate::measure::exposure::CameraLimits;

/// A request that cannot be accepted: status 404 (unknown thing), 422, or 503.
#[derive(Debug, thiserror::Error)]
pub enum RequestError {
    /// A referenced thing does not exist.
    #[error("{0}")]
    NotFound(String),
    /// A value is out of range or inconsistent.
    #[error("{0}")]
    Invalid(String),
    /// The camera cannot answer what the request needs yet (503).
    #[error("{0}")]
    Unavailable(String),
    /// The catalogue could not be read (500; the text has no absolute paths).
    #[error("{0}")]
    Store(String),
    /// It conflicts with what the daemon is doing (409).
    #[error("{0}")]
    Busy(String),
}

impl From<crate::daemon::runtime::scenes::ScenesError> for RequestError {
    fn from(e: crate::daemon::runtime::scenes::ScenesError) -> Self {
        match e {
            crate::daemon::runtime::scenes::ScenesError::Unknown { .. } => {
                RequestError::NotFound(e.to_string())
            }
            e => RequestError::Invalid(e.to_string()),
        }
    }
}

fn invalid(m: impl Into<String>) -> RequestError {
    RequestError::Invalid(m.into())
}

/// What a capture is checked against besides its scene: the camera's ranges
/// and current settings, the bench, and the configured frame cap.
#[derive(Debug, Clone)]
pub struct CameraContext {
    /// Exposure range and noise (`Admission::camera_limits`).
    pub limits: CameraLimits,
    /// The camera's range of each ranged setting, when it has reported them.
    pub ranges: Option<CameraRanges>,
    /// Region and binning limits, when the camera has reported them.
    pub sensor: Option<SensorLimits>,
    /// What a capture inherits for a setting it does not state.
    pub defaults: CameraSettings,
    /// The pixel formats the camera lists (GenICam names), when connected;
    /// an empty list (a camera that lists none) checks nothing.
    pub pixel_formats: Option<Vec<String>>,
    /// Whether the bench can switch the hidden scene off by itself.
    pub bench_switches_scene: bool,
    /// Frames plus dark frames a capture may take (`[queue] max_frames_per_capture`).
    pub max_frames: usize,
}

#[cfg(test)]
pub(crate) mod fixtures {
    //! What the tests of both checks share.
    use crate::scene::Scene;
    use crate::store::{CaptureRecord, JobState};

    /// The reference bench with poses B and C, crossed polarizer each.
    pub fn scene() -> Scene {
        match Scene::builtin("brewster-multi-3x3") {
            Some(Ok(s)) => s,
            _ => panic!("built-in scene"),
        }
    }

    /// A capture of pose B at 0° of that scene, full frame.
    pub fn record(id: i64, kind: &str, exposure_us: f64, state: JobState) -> CaptureRecord {
        let request = crate::store::CaptureRequest {
            kind: crate::store::CaptureKind::from_name(kind).expect("a capture kind"),
            scene: "brewster-multi-3x3".into(),
            pose: "B".into(),
            channels: vec![crate::scene::Channel::Sheet { deg: 0.0 }],
            acquisition: crate::camera::Acquisition {
                exposure_us,
                ..crate::camera::Acquisition::defaults_at([0, 0, 512, 512], [1, 1])
            },
            frames: 1,
            dark_frames: 0,
            dark_capture: None,
        };
        CaptureRecord {
            id,
            frames_taken: 1,
            ..request.unstored(state)
        }
    }
}
