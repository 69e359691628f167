//! What goes over the wire: the queries clients send, the typed answers the
//! routes give back, and the request bodies.
//!
//! The bodies are the daemon's own types (`crate::daemon::requests`),
//! re-exported here: the daemon checks them (`crate::daemon::requests::validate`)
//! without depending on the HTTP layer, and routes and the OpenAPI document
//! name them from here as before.

use serde::{Deserialize, Serialize};

pub(crate) use crate::daemon::requests::ColourCalibrationBody;
pub use crate::daemon::requests::{
    CalibrationBody, CaptureBody, PlanBody, ReconstructionBody, SettingsBody, WallCalibrationBody,
    MAX_CAPTURES_PER_POSITION,
};
pub(crate) use crate::daemon::requests::{
    ImportQuery, PlanReconstruct, ProgressiveBody, SourcePositionBody,
};

use super::ApiError;
use crate::camera::Acquisition;
use crate::measure::exposure::ExposureTarget;
use crate::store::{CaptureKind, CaptureRequest};

/// Paging of list endpoints.
#[derive(Debug, Deserialize, utoipa::IntoParams)]
#[serde(deny_unknown_fields)]
pub struct Page {
    /// At most this many (1-1000, default 100).
    #[param(minimum = 1, maximum = 1000)]
    limit: Option<u64>,
    /// Skip this many (0 to 2^63 - 1).
    #[param(minimum = 0, maximum = 9223372036854775807_i64)]
    offset: Option<u64>,
}

impl Page {
    /// `(limit, offset)`, checked: SQLite's OFFSET is a signed 64-bit
    /// integer, so a larger one is refused rather than wrapped.
    pub fn get(&self) -> Result<(usize, usize), ApiError> {
        let limit = self.limit.unwrap_or(100);
        if !(1..=1000).contains(&limit) {
            return Err(ApiError::invalid(format!(
                "limit = {limit}: must be from 1 to 1000"
            )));
        }
        let offset = self.offset.unwrap_or(0);
        let offset = i64::try_from(offset)
            .ok()
            .and_then(|o| usize::try_from(o).ok())
            .ok_or_else(|| {
                ApiError::invalid(format!("offset = {offset}: must be from 0 to {}", i64::MAX))
            })?;
        Ok((limit as usize, offset))
    }
}

/// Target of the blocks' exposures (query of `GET /scenes/{name}/exposure`).
#[derive(Debug, Deserialize, utoipa::IntoParams)]
#[serde(deny_unknown_fields)]
pub(crate) struct TargetQuery {
    /// Brightest admissible wall element as a fraction of full scale (default 0.8).
    #[param(exclusive_minimum = 0.0, maximum = 1.0)]
    peak_fraction: Option<f64>,
    /// SNR wanted there after averaging (default 100).
    #[param(exclusive_minimum = 0.0)]
    snr: Option<f64>,
}

impl TargetQuery {
    /// The target, defaults filled in (its ranges are checked by the planner).
    pub fn target(&self) -> ExposureTarget {
        let mut target = ExposureTarget::default();
        if let Some(f) = self.peak_fraction {
            target.peak_fraction = f;
        }
        if let Some(s) = self.snr {
            target.snr = s;
        }
        target
    }
}

/// `GET /health` answer.
#[derive(Debug, Serialize, utoipa::ToSchema)]
pub(crate) struct Health {
    /// Always `ok` when the daemon answers.
    pub status: &'static str,
    /// Whether the camera is open now.
    pub camera_connected: bool,
    /// polnlos version.
    pub version: &'static str,
}

/// 202 answer to `POST /reconstructions`.
#[derive(Debug, Serialize, utoipa::ToSchema)]
pub struct Accepted {
    /// Id of the new capture or reconstruction.
    pub id: i64,
    /// `queued`.
    pub state: &'static str,
    /// Job id for `GET /jobs/{id}` and the event stream (`capture-<n>`, `reconstruction-<n>`).
    pub job: String,
}

impl Accepted {
    /// A queued job of this kind (`capture` or `reconstruction`).
    pub fn queued(kind: &str, id: i64) -> Self {
        Self {
            id,
            state: "queued",
            job: format!("{kind}-{id}"),
        }
    }
}

/// 202 answer to `POST /captures`: the job, and every setting the capture
/// will use, whether stated or inherited.
#[derive(Debug, Serialize, utoipa::ToSchema)]
pub struct CaptureAccepted {
    /// The queued job.
    #[serde(flatten)]
    pub job: Accepted,
    /// Light or dark.
    pub kind: CaptureKind,
    /// Camera settings.
    #[serde(flatten)]
    pub acquisition: Acquisition,
    /// Frames to average.
    pub frames: usize,
    /// Dark frames within the capture.
    pub dark_frames: usize,
    /// Dark capture subtracted.
    pub dark_capture: Option<i64>,
}

impl CaptureAccepted {
    /// The answer for capture `id`, queued with request `r`.
    pub fn new(id: i64, r: &CaptureRequest) -> Self {
        Self {
            job: Accepted::queued("capture", id),
            kind: r.kind,
            acquisition: r.acquisition,
            frames: r.frames,
            dark_frames: r.dark_frames,
            dark_capture: r.dark_capture,
        }
    }
}

/// Every error answer: a stable code and a sentence saying what to do.
#[derive(Debug, Serialize, utoipa::ToSchema)]
pub struct ErrorBody {
    /// Machine-readable code (`not_found`, `invalid`, `queue_full`, ...).
    pub error: String,
    /// What was wrong, with which input, and what to do.
    pub detail: String,
}
