//! Rows of the catalogue and the requests that create them.

use rusqlite::Row;
use serde::{Deserialize, Serialize};

use crate::camera::{Acquisition, PixelFormat, TriggerMode};

/// Whether a capture shows the hidden scene, is a dark capture taken with
/// the scene switched off (to be subtracted from light captures), or shows
/// the calibration target on the wall (for `POST /calibrations`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, utoipa::ToSchema)]
#[serde(rename_all = "lowercase")]
pub enum CaptureKind {
    /// The hidden scene on.
    Light,
    /// The hidden scene off (the user switched it off, or the bench did).
    Dark,
    /// The calibration target on the wall, the hidden scene hidden by it.
    Target,
    /// A point source at a known place instead of the hidden scene (wall calibration).
    Source,
}

impl CaptureKind {
    /// The name stored and shown.
    pub fn name(self) -> &'static str {
        match self {
            CaptureKind::Light => "light",
            CaptureKind::Dark => "dark",
            CaptureKind::Target => "target",
            CaptureKind::Source => "source",
        }
    }

    /// The kind of a name (as [`CaptureKind::name`] writes it).
    pub fn from_name(name: &str) -> Option<Self> {
        [Self::Light, Self::Dark, Self::Target, Self::Source]
            .into_iter()
            .find(|k| k.name() == name)
    }
}

/// Life of a job.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, utoipa::ToSchema)]
#[serde(rename_all = "lowercase")]
pub enum JobState {
    /// Accepted, waiting in the queue.
    Queued,
    /// Being worked on.
    Running,
    /// Finished; its files are durable.
    Done,
    /// Finished with an error (see `error`).
    Failed,
    /// The daemon stopped while it was queued or running.
    Interrupted,
    /// Cancelled by a client (`DELETE /jobs/{id}`); nothing half-written is kept.
    Cancelled,
}

impl JobState {
    /// The name stored and shown.
    pub fn name(self) -> &'static str {
        match self {
            JobState::Queued => "queued",
            JobState::Running => "running",
            JobState::Done => "done",
            JobState::Failed => "failed",
            JobState::Interrupted => "interrupted",
            JobState::Cancelled => "cancelled",
        }
    }

    /// The state named `s`; `None` for a name the daemon never writes.
    fn parse(s: &str) -> Option<Self> {
        [
            JobState::Queued,
            JobState::Running,
            JobState::Done,
            JobState::Failed,
            JobState::Interrupted,
            JobState::Cancelled,
        ]
        .into_iter()
        .find(|j| j.name() == s)
    }
}

/// A damaged column of row `r`: the row is unreadable, not quietly defaulted.
fn damaged(
    idx: usize,
    what: impl Into<Box<dyn std::error::Error + Send + Sync>>,
) -> rusqlite::Error {
    rusqlite::Error::FromSqlConversionFailure(idx, rusqlite::types::Type::Text, what.into())
}

/// Column `idx` as a job state; an unknown name makes the row unreadable
/// (before, it read as `failed`, hiding a done capture behind a wrong state).
fn state_column(r: &Row<'_>, idx: usize) -> rusqlite::Result<JobState> {
    let s: String = r.get(idx)?;
    JobState::parse(&s).ok_or_else(|| damaged(idx, format!("unknown job state {s:?}")))
}

/// Column `idx` as the value `parse` reads from its text: a name this
/// version does not know makes the row unreadable, never a silent default.
fn named_column<T>(
    r: &Row<'_>,
    idx: usize,
    what: &str,
    parse: impl Fn(&str) -> Option<T>,
) -> rusqlite::Result<T> {
    let s: String = r.get(idx)?;
    parse(&s).ok_or_else(|| damaged(idx, format!("unknown {what} {s:?}")))
}

/// Column `idx` as JSON, `None` when NULL; malformed JSON makes the row
/// unreadable (before, a damaged region or report read as absent).
fn json_column<T: serde::de::DeserializeOwned>(
    r: &Row<'_>,
    idx: usize,
) -> rusqlite::Result<Option<T>> {
    r.get::<_, Option<String>>(idx)?
        .map(|s| serde_json::from_str(&s).map_err(|e| damaged(idx, e)))
        .transpose()
}

/// A validated capture request: every camera setting it uses is its own,
/// stated in the request or inherited when it was accepted.
#[derive(Debug, Clone, PartialEq)]
pub struct CaptureRequest {
    /// Light or dark.
    pub kind: CaptureKind,
    /// Scene name.
    pub scene: String,
    /// Pose name in that scene.
    pub pose: String,
    /// Polarizer angle (None: the pose has no polarizer).
    pub polarizer_deg: Option<f64>,
    /// Camera settings.
    pub acquisition: Acquisition,
    /// Frames to average.
    pub frames: usize,
    /// Dark frames (scene off) to average and subtract.
    pub dark_frames: usize,
    /// A done dark capture whose mean is subtracted from this one.
    pub dark_capture: Option<i64>,
}

#[cfg(test)]
impl CaptureRequest {
    /// A light capture of `brewster-crossed` pose A at 0°: one 4x4 Mono16
    /// frame of 1 ms, free running (tests override what they need).
    pub(crate) fn example() -> Self {
        Self {
            kind: CaptureKind::Light,
            scene: "brewster-crossed".into(),
            pose: "A".into(),
            polarizer_deg: Some(0.0),
            acquisition: Acquisition {
                exposure_us: 1000.0,
                gain: 0.0,
                pixel_format: PixelFormat::Mono16,
                region: [0, 0, 4, 4],
                binning: [1, 1],
                trigger: TriggerMode::Free,
            },
            frames: 1,
            dark_frames: 0,
            dark_capture: None,
        }
    }
}

/// A capture as the API shows it.
#[derive(Debug, Clone, Serialize, utoipa::ToSchema)]
pub struct CaptureRecord {
    /// Id.
    pub id: i64,
    /// Scene name.
    pub scene: String,
    /// Pose name.
    pub pose: String,
    /// Polarizer angle, degrees (null: no polarizer).
    pub polarizer_deg: Option<f64>,
    /// Exposure, microseconds.
    pub exposure_us: f64,
    /// Gain.
    pub gain: f64,
    /// Frames averaged.
    pub frames: i64,
    /// Dark frames subtracted.
    pub dark_frames: i64,
    /// Pixel format.
    pub pixel_format: PixelFormat,
    /// Light, dark, target or source.
    pub kind: CaptureKind,
    /// Region of interest `[x, y, width, height]` (null for captures made
    /// before it was recorded).
    pub region: Option<[u32; 4]>,
    /// Binning `[x, y]`.
    pub binning: Option<[u32; 2]>,
    /// Trigger mode (null for captures made before it was recorded).
    pub trigger: Option<TriggerMode>,
    /// The dark capture subtracted from this one.
    pub dark_capture: Option<i64>,
    /// Job state.
    pub state: JobState,
    /// Why it failed or was interrupted.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub error: Option<String>,
    /// When it was requested.
    pub created_at: String,
    /// When it started.
    pub started_at: Option<String>,
    /// When it ended.
    pub finished_at: Option<String>,
    /// Camera that took it.
    pub camera_id: Option<String>,
    /// The camera's counters since the daemon started, as they stood when
    /// the capture ended (cumulative: see `frame_counts` for this capture's own).
    #[schema(value_type = Object)]
    pub counters: Option<serde_json::Value>,
    /// Frames taken so far.
    pub frames_taken: i64,
    /// What this capture's acquisitions (light and dark) received, dropped
    /// and got broken; null for captures not done, and for those made
    /// before it was recorded.
    pub frame_counts: Option<crate::camera::FrameCounts>,
}

pub(super) const CAPTURE_SELECT: &str = "SELECT id, scene, pose, polarizer_deg, exposure_us, gain, frames, dark_frames, pixel_format, state, error, created_at, started_at, finished_at, camera_id, counters, frames_taken, kind, region, binning, trigger, dark_capture, frame_counts FROM captures";

pub(super) fn capture_row(r: &Row<'_>) -> rusqlite::Result<CaptureRecord> {
    Ok(CaptureRecord {
        id: r.get(0)?,
        scene: r.get(1)?,
        pose: r.get(2)?,
        polarizer_deg: r.get(3)?,
        exposure_us: r.get(4)?,
        gain: r.get(5)?,
        frames: r.get(6)?,
        dark_frames: r.get(7)?,
        pixel_format: named_column(r, 8, "pixel format", PixelFormat::from_name)?,
        state: state_column(r, 9)?,
        error: r.get(10)?,
        created_at: r.get(11)?,
        started_at: r.get(12)?,
        finished_at: r.get(13)?,
        camera_id: r.get(14)?,
        counters: json_column(r, 15)?,
        frames_taken: r.get(16)?,
        kind: named_column(r, 17, "capture kind", CaptureKind::from_name)?,
        region: json_column(r, 18)?,
        binning: json_column(r, 19)?,
        trigger: r
            .get::<_, Option<String>>(20)?
            .map(|s| {
                TriggerMode::from_name(&s)
                    .ok_or_else(|| damaged(20, format!("unknown trigger mode {s:?}")))
            })
            .transpose()?,
        dark_capture: r.get(21)?,
        frame_counts: json_column(r, 22)?,
    })
}

/// A capture row that lacks a setting its acquisition needs (rows from
/// before region, binning and trigger were recorded).
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("capture {id} records no {missing}; its settings cannot be reused (take it again)")]
pub struct IncompleteRecord {
    /// The capture.
    pub id: i64,
    /// The settings it lacks, e.g. `region, trigger`.
    pub missing: String,
}

impl TryFrom<&CaptureRecord> for Acquisition {
    type Error = IncompleteRecord;

    fn try_from(c: &CaptureRecord) -> Result<Self, IncompleteRecord> {
        match (c.region, c.binning, c.trigger) {
            (Some(region), Some(binning), Some(trigger)) => Ok(Acquisition {
                exposure_us: c.exposure_us,
                gain: c.gain,
                pixel_format: c.pixel_format,
                region,
                binning,
                trigger,
            }),
            (region, binning, trigger) => Err(IncompleteRecord {
                id: c.id,
                missing: [
                    region.is_none().then_some("region"),
                    binning.is_none().then_some("binning"),
                    trigger.is_none().then_some("trigger"),
                ]
                .into_iter()
                .flatten()
                .collect::<Vec<_>>()
                .join(", "),
            }),
        }
    }
}

impl CaptureRecord {
    /// Whether this is a dark capture.
    pub fn is_dark(&self) -> bool {
        self.kind == CaptureKind::Dark
    }

    /// Whether this is a capture of the hidden scene (not dark, not target).
    pub fn is_light(&self) -> bool {
        self.kind == CaptureKind::Light
    }
}

/// A validated reconstruction request.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct ReconstructionRequest {
    /// Scene name.
    pub scene: String,
    /// Capture ids, one per (pose, angle) block.
    pub captures: Vec<i64>,
    /// `admm-tv`, `tikhonov` or `lsq`.
    pub solver: String,
    /// Solver parameters as given.
    pub params: serde_json::Value,
}

/// A reconstruction as the API shows it.
#[derive(Debug, Clone, Serialize, utoipa::ToSchema)]
pub struct ReconstructionRecord {
    /// Id.
    pub id: i64,
    /// Scene name.
    pub scene: String,
    /// Capture ids used.
    pub captures: Vec<i64>,
    /// Solver.
    pub solver: String,
    /// Solver parameters.
    #[schema(value_type = Object)]
    pub params: serde_json::Value,
    /// Job state.
    pub state: JobState,
    /// Why it failed or was interrupted.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub error: Option<String>,
    /// When it was requested.
    pub created_at: String,
    /// When it started.
    pub started_at: Option<String>,
    /// When it ended.
    pub finished_at: Option<String>,
    /// Condition number of the stacked T (`"inf"` when rank-deficient).
    #[schema(schema_with = kappa_schema)]
    pub kappa: Option<serde_json::Value>,
    /// The full report (same format as `polnlos reconstruct`'s report.json).
    #[schema(value_type = Object)]
    pub report: Option<serde_json::Value>,
}

/// The schema of a stored condition number: a number, the string `"inf"`
/// (rank-deficient `T`), or null before the reconstruction has one.
fn kappa_schema() -> utoipa::openapi::schema::Schema {
    use utoipa::openapi::schema::{ObjectBuilder, OneOfBuilder, Type};
    OneOfBuilder::new()
        .item(ObjectBuilder::new().schema_type(Type::Number))
        .item(
            ObjectBuilder::new()
                .schema_type(Type::String)
                .enum_values(Some(["inf"])),
        )
        .item(ObjectBuilder::new().schema_type(Type::Null))
        .description(Some(
            "kappa(T): a number, \"inf\" when rank-deficient, null until known",
        ))
        .build()
        .into()
}

pub(super) const RECON_SELECT: &str = "SELECT id, scene, captures, solver, params, state, error, created_at, started_at, finished_at, kappa, report FROM reconstructions";

pub(super) fn recon_row(r: &Row<'_>) -> rusqlite::Result<ReconstructionRecord> {
    let kappa: Option<String> = r.get(10)?;
    Ok(ReconstructionRecord {
        id: r.get(0)?,
        scene: r.get(1)?,
        captures: json_column(r, 2)?.unwrap_or_default(),
        solver: r.get(3)?,
        params: json_column(r, 4)?.unwrap_or(serde_json::Value::Null),
        state: state_column(r, 5)?,
        error: r.get(6)?,
        created_at: r.get(7)?,
        started_at: r.get(8)?,
        finished_at: r.get(9)?,
        kappa: kappa.map(|k| {
            k.parse::<f64>()
                .map(serde_json::Value::from)
                .unwrap_or(serde_json::Value::String(k))
        }),
        report: json_column(r, 11)?,
    })
}
