//! Rows of the catalogue and the requests that create them.

use rusqlite::Row;
use serde::{Deserialize, Serialize};

use crate::camera::{Acquisition, CameraSettings};
use crate::scene::Channel;
use crate::solve::SolveRequest;

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
    pub(super) fn parse(s: &str) -> Option<Self> {
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

/// A damaged column `col` of row `r`: the row is unreadable, not quietly
/// defaulted. The error carries the column's index in the row, as rusqlite's own do.
fn damaged(
    r: &Row<'_>,
    col: &str,
    what: impl Into<Box<dyn std::error::Error + Send + Sync>>,
) -> rusqlite::Error {
    let idx = r.as_ref().column_index(col).unwrap_or_default();
    rusqlite::Error::FromSqlConversionFailure(idx, rusqlite::types::Type::Text, what.into())
}

/// Column `col` as a job state; an unknown name makes the row unreadable
/// (before, it read as `failed`, hiding a done capture behind a wrong state).
fn state_column(r: &Row<'_>, col: &str) -> rusqlite::Result<JobState> {
    named_column(r, col, "job state", JobState::parse)
}

/// Column `col` as the value `parse` reads from its text: a name this
/// version does not know makes the row unreadable, never a silent default.
pub(super) fn named_column<T>(
    r: &Row<'_>,
    col: &str,
    what: &str,
    parse: impl Fn(&str) -> Option<T>,
) -> rusqlite::Result<T> {
    let s: String = r.get(col)?;
    parse(&s).ok_or_else(|| damaged(r, col, format!("unknown {what} {s:?}")))
}

/// Column `col` as JSON, `None` when NULL; malformed JSON makes the row
/// unreadable (before, a damaged region or report read as absent).
pub(super) fn json_column<T: serde::de::DeserializeOwned>(
    r: &Row<'_>,
    col: &str,
) -> rusqlite::Result<Option<T>> {
    r.get::<_, Option<String>>(col)?
        .map(|s| serde_json::from_str(&s).map_err(|e| damaged(r, col, e)))
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
    /// The blocks its frames hold: one through a sheet (or none), four
    /// from a mosaic sensor.
    pub channels: Vec<Channel>,
    /// Camera settings.
    pub acquisition: Acquisition,
    /// Frames to average.
    pub frames: usize,
    /// Dark frames (scene off) to average and subtract.
    pub dark_frames: usize,
    /// A done dark capture whose mean is subtracted from this one.
    pub dark_capture: Option<i64>,
}

impl CaptureRequest {
    /// The record of this request as if accepted, never stored (id 0), in
    /// `state`: what the live view's solver and bench moves read.
    pub fn unstored(&self, state: JobState) -> CaptureRecord {
        CaptureRecord {
            id: 0,
            scene: self.scene.clone(),
            pose: self.pose.clone(),
            channels: self.channels.clone(),
            polarizer_measured_deg: None,
            settings: CameraSettings::from(self.acquisition),
            frames: i64::try_from(self.frames).unwrap_or(i64::MAX),
            dark_frames: i64::try_from(self.dark_frames).unwrap_or(i64::MAX),
            kind: self.kind,
            dark_capture: self.dark_capture,
            state,
            error: None,
            created_at: String::new(),
            started_at: None,
            finished_at: None,
            camera_id: None,
            counters: None,
            frames_taken: 0,
            frame_counts: None,
            clipping: None,
            import: None,
            live: None,
            progressive: false,
        }
    }
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
            channels: vec![Channel::Sheet { deg: 0.0 }],
            acquisition: Acquisition {
                exposure_us: 1000.0,
                ..Acquisition::defaults_at([0, 0, 4, 4], [1, 1])
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
    /// The blocks its frames hold, in the order it yields them: one
    /// through a polarizer sheet (`{"analyzer": "sheet", "deg": 0}`) or
    /// none (`{"analyzer": "none"}`); four from a polarizer-mosaic camera
    /// (`{"analyzer": "mosaic", "deg": 0}`, 45, 90, 135).
    #[schema(value_type = Vec<Object>)]
    pub channels: Vec<Channel>,
    /// The polarizer angle the rotation mount read back before the first
    /// frame, degrees from crossed (null: no mount, the sheet's angle was
    /// set by hand and is trusted; or not taken yet).
    pub polarizer_measured_deg: Option<f64>,
    /// The camera settings it was taken with, every one resolved when it was
    /// accepted (null only for a setting polnlos did not yet record then:
    /// region, binning and trigger of old captures).
    #[serde(flatten)]
    pub settings: CameraSettings,
    /// Frames averaged.
    pub frames: i64,
    /// Dark frames subtracted.
    pub dark_frames: i64,
    /// Light, dark, target or source.
    pub kind: CaptureKind,
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
    #[schema(value_type = Option<Object>)]
    pub counters: Option<serde_json::Value>,
    /// Frames taken so far.
    pub frames_taken: i64,
    /// What this capture's acquisitions (light and dark) received, dropped
    /// and got broken; null for captures not done, and for those made
    /// before it was recorded.
    pub frame_counts: Option<crate::camera::FrameCounts>,
    /// Pixels at full scale and at zero in this capture's light frames (the
    /// most in one frame); null for captures not done, and for those made
    /// before it was recorded.
    pub clipping: Option<crate::measure::Clipping>,
    /// Where an imported capture came from (`POST /captures/import`): a
    /// measurement or photo taken elsewhere; null for the camera's own.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub import: Option<ImportInfo>,
    /// Where a live view's recording came from (`POST /live` with
    /// `record`): its session, the frames asked and why it ended early;
    /// null for a capture taken as one.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub live: Option<LiveInfo>,
    /// Whether its folder holds progressive steps (`progressive.json`,
    /// `progressive.png`), as `GET /captures` and `GET /captures/{id}` find it.
    /// Why: a client asks for the steps of the captures that have them only.
    pub progressive: bool,
}

/// The provenance of a capture a live session recorded: which session, how
/// many frames it asked for, and why it holds fewer when it does.
///
/// Why: a recording that ended early is kept with the frames it got, and
/// its record must say so rather than pass for a capture of fewer frames.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
pub struct LiveInfo {
    /// The live session (`GET /live`'s `session`) whose frames it holds.
    pub session: u64,
    /// Frames the recording asked for (`record.frames`); `frames` says how
    /// many it holds.
    pub frames_asked: usize,
    /// Why the recording ended before `frames_asked` frames, when it did.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub ended: Option<String>,
}

/// The provenance of an imported capture: what was sent, and what polnlos
/// made of it.
///
/// Why: an imported photo has no camera, exposure or dark frames; its
/// reconstruction fits its gain and background, and a lab's notes must be
/// able to tell which file it was.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
pub struct ImportInfo {
    /// The file's format: `npy` (a measurement in polnlos's row order),
    /// `tiff` or `png` (an image sampled through the pose's homography).
    pub format: String,
    /// The file's name as the client gave it (`?name=`), if it did.
    pub name: Option<String>,
    /// Bytes received.
    pub bytes: u64,
    /// SHA-256 of the bytes received, hex.
    pub sha256: String,
    /// Colour channels of the stored measurement (1 grey, 3 red, green, blue).
    pub colours: usize,
    /// The Bayer pattern of a raw colour frame (`RG`, `GR`, `GB`, `BG`).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub bayer: Option<String>,
}

pub(super) const CAPTURE_SELECT: &str = "SELECT * FROM captures";

/// What the `settings` column holds: a capture's camera settings as one
/// typed JSON document, with the version of its layout.
///
/// Why a document: a new camera setting is a new field of
/// [`CameraSettings`] and needs no column (rows written before it read it
/// back as null); `version` says which layout a row has, so a later
/// polnlos can migrate one it reads differently.
#[derive(Debug, Serialize, Deserialize)]
pub(super) struct SettingsDocument {
    /// Layout of the document ([`SettingsDocument::VERSION`]).
    pub version: u32,
    /// The settings.
    #[serde(flatten)]
    pub settings: CameraSettings,
}

impl SettingsDocument {
    /// The layout this polnlos writes and reads.
    pub const VERSION: u32 = 1;

    /// The document of a capture's settings, as the catalogue stores it.
    pub fn of(a: &Acquisition) -> String {
        let doc = SettingsDocument {
            version: Self::VERSION,
            settings: (*a).into(),
        };
        // A struct of numbers, names and arrays always serializes.
        serde_json::to_string(&doc).unwrap_or_default()
    }

    /// The document of a capture no camera took (an import): every setting null.
    pub fn none() -> String {
        let doc = SettingsDocument {
            version: Self::VERSION,
            settings: CameraSettings::default(),
        };
        serde_json::to_string(&doc).unwrap_or_default()
    }
}

/// Column `col` as a settings document of the version this polnlos reads.
fn settings_column(r: &Row<'_>, col: &str) -> rusqlite::Result<CameraSettings> {
    let doc: SettingsDocument =
        json_column(r, col)?.ok_or_else(|| damaged(r, col, "no settings document"))?;
    layout(r, col, "settings", doc.version, SettingsDocument::VERSION)?;
    Ok(doc.settings)
}

/// A capture's channels as the catalogue stores them (a JSON list).
pub(super) fn channels_document(channels: &[Channel]) -> String {
    // A list of tagged numbers always serializes.
    serde_json::to_string(channels).unwrap_or_default()
}

/// Column `col` as a capture's channels: a JSON list of at least one.
fn channels_column(r: &Row<'_>, col: &str) -> rusqlite::Result<Vec<Channel>> {
    let channels: Vec<Channel> =
        json_column(r, col)?.ok_or_else(|| damaged(r, col, "no channels"))?;
    if channels.is_empty() {
        return Err(damaged(r, col, "an empty list of channels"));
    }
    Ok(channels)
}

/// A document in column `col` is of the layout this polnlos reads, else
/// its row is damaged (a newer polnlos wrote it).
fn layout(r: &Row<'_>, col: &str, what: &str, found: u32, reads: u32) -> rusqlite::Result<()> {
    if found == reads {
        return Ok(());
    }
    Err(damaged(
        r,
        col,
        format!(
            "{what} document version {found} (this polnlos reads version {reads}): open this data directory with the polnlos that wrote it"
        ),
    ))
}

pub(super) fn capture_row(r: &Row<'_>) -> rusqlite::Result<CaptureRecord> {
    Ok(CaptureRecord {
        id: r.get("id")?,
        scene: r.get("scene")?,
        pose: r.get("pose")?,
        channels: channels_column(r, "channels")?,
        settings: settings_column(r, "settings")?,
        frames: r.get("frames")?,
        dark_frames: r.get("dark_frames")?,
        state: state_column(r, "state")?,
        error: r.get("error")?,
        created_at: r.get("created_at")?,
        started_at: r.get("started_at")?,
        finished_at: r.get("finished_at")?,
        camera_id: r.get("camera_id")?,
        counters: json_column(r, "counters")?,
        frames_taken: r.get("frames_taken")?,
        kind: named_column(r, "kind", "capture kind", CaptureKind::from_name)?,
        dark_capture: r.get("dark_capture")?,
        frame_counts: json_column(r, "frame_counts")?,
        polarizer_measured_deg: r.get("polarizer_measured_deg")?,
        clipping: json_column(r, "clipping")?,
        import: json_column(r, "import")?,
        live: json_column(r, "live")?,
        progressive: false,
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
        c.settings.complete().map_err(|e| IncompleteRecord {
            id: c.id,
            missing: e.missing.join(", "),
        })
    }
}

impl CaptureRecord {
    /// The polarizer sheet's angle from crossed it was taken through, when
    /// it was (not without one, nor from a mosaic sensor).
    pub fn sheet_deg(&self) -> Option<f64> {
        self.channels.iter().find_map(|c| c.sheet_deg())
    }

    /// Whether this is a dark capture.
    pub fn is_dark(&self) -> bool {
        self.kind == CaptureKind::Dark
    }

    /// Whether this is a capture of the hidden scene (not dark, not target).
    pub fn is_light(&self) -> bool {
        self.kind == CaptureKind::Light
    }

    /// Whether it was imported (`POST /captures/import`), not taken.
    pub fn is_imported(&self) -> bool {
        self.import.is_some()
    }
}

/// A validated reconstruction request.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct ReconstructionRequest {
    /// Scene name.
    pub scene: String,
    /// Capture ids, one per (pose, angle) block.
    pub captures: Vec<i64>,
    /// The solver (`params.solve.solver`) and its parameters as given.
    pub params: ReconstructionParams,
}

/// What a reconstruction was asked to solve with: the one typed document of
/// its `params` column, shown as its `params`.
///
/// Why typed: the worker, the truth image and the API read the same
/// fields, and a row whose parameters do not read back is refused (named)
/// rather than solved with the defaults.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
pub struct ReconstructionParams {
    /// Layout of the document (1; rows from before it was versioned have
    /// the same layout and read as 1).
    #[serde(default = "ReconstructionParams::version_one")]
    pub version: u32,
    /// The solver and its parameters, as requested (absent: defaults).
    #[serde(flatten)]
    pub solve: SolveRequest,
    /// Known truth: a test pattern's name, or an image top row first.
    pub truth: Option<super::Truth>,
    /// Solved from the blocks its captures give, the scene's other blocks
    /// left out (an interim result while a plan captures).
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub partial: bool,
    /// The radiometry asked for (absent: chosen from what the daemon knows).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub radiometry: Option<crate::solve::radiometry::Radiometry>,
}

impl Default for ReconstructionParams {
    fn default() -> Self {
        Self::new(SolveRequest::default(), None)
    }
}

impl ReconstructionParams {
    /// The layout this polnlos writes and reads.
    pub const VERSION: u32 = 1;

    fn version_one() -> u32 {
        1
    }

    /// The parameters of a request: `solve` and the truth it names.
    pub fn new(solve: SolveRequest, truth: Option<super::Truth>) -> Self {
        Self {
            version: Self::VERSION,
            solve,
            truth,
            partial: false,
            radiometry: None,
        }
    }
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
    /// The solver's name, as its parameters name it (`params.solver`):
    /// shown here too, for a reader of the list.
    pub solver: String,
    /// Solver parameters.
    pub params: ReconstructionParams,
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
    #[schema(value_type = Option<Object>)]
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

/// Column `col` as the parameters document of the version this polnlos
/// reads (NULL: the defaults, as rows without parameters meant).
fn params_column(r: &Row<'_>, col: &str) -> rusqlite::Result<ReconstructionParams> {
    let params: ReconstructionParams = json_column(r, col)?.unwrap_or_default();
    layout(
        r,
        col,
        "parameters",
        params.version,
        ReconstructionParams::VERSION,
    )?;
    Ok(params)
}

pub(super) const RECON_SELECT: &str = "SELECT * FROM reconstructions";

pub(super) fn recon_row(r: &Row<'_>) -> rusqlite::Result<ReconstructionRecord> {
    let kappa: Option<String> = r.get("kappa")?;
    let params = params_column(r, "params")?;
    Ok(ReconstructionRecord {
        id: r.get("id")?,
        scene: r.get("scene")?,
        captures: json_column(r, "captures")?.unwrap_or_default(),
        solver: params.solve.solver.name().to_string(),
        params,
        state: state_column(r, "state")?,
        error: r.get("error")?,
        created_at: r.get("created_at")?,
        started_at: r.get("started_at")?,
        finished_at: r.get("finished_at")?,
        kappa: kappa.map(|k| {
            k.parse::<f64>()
                .map(serde_json::Value::from)
                .unwrap_or(serde_json::Value::String(k))
        }),
        report: json_column(r, "report")?,
    })
}
