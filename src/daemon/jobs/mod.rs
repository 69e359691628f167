//! What capture and reconstruction jobs share: the services a worker
//! holds (`JobContext`), the job error, block labels and the bookkeeping
//! of a job that ended.

pub(crate) mod capture;
pub(crate) mod live;
pub(crate) mod progressive;
pub(crate) mod reconstruction;
pub(crate) mod record;

use std::collections::BTreeMap;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Arc;
use std::time::Instant;

use crate::daemon::runtime::events::Events;
use crate::daemon::runtime::metrics::Metrics;
use crate::daemon::runtime::registry::JobRegistry;
use crate::daemon::runtime::scenes::{Scenes, ScenesError};
use crate::scene::Channel;
use crate::store::{JobState, Store};

/// The services every job worker holds, and nothing else of the daemon:
/// the catalogue, the scenes with their radiometric calibration, the job
/// registry, the event stream and the counters.
#[derive(Clone)]
pub(in crate::daemon) struct JobContext {
    pub(in crate::daemon) store: Arc<Store>,
    /// The scenes as the job started: a change of them does not touch it.
    pub(in crate::daemon) scenes: Arc<Scenes>,
    /// The scenes now, for the next job's snapshot.
    pub(in crate::daemon) scene_registry:
        Arc<crate::daemon::runtime::scene_registry::SceneRegistry>,
    /// Fraction of full scale per microsecond per unit of `T l`, per scene.
    pub(in crate::daemon) calibration: Arc<BTreeMap<String, f64>>,
    pub(in crate::daemon) registry: Arc<JobRegistry>,
    pub(in crate::daemon) events: Events,
    pub(in crate::daemon) metrics: Arc<Metrics>,
}

impl JobContext {
    /// This context with the scenes as they are now: what a job starting keeps.
    pub(in crate::daemon) fn with_current_scenes(&self) -> Self {
        Self {
            scenes: self.scene_registry.now(),
            ..self.clone()
        }
    }
}

/// Why a capture or reconstruction job failed: what the job's `error` says.
#[derive(Debug, thiserror::Error)]
pub(crate) enum JobError {
    /// The catalogue or a capture's files (the text has no absolute paths).
    #[error("{0}")]
    Store(String),
    /// The camera.
    #[error(transparent)]
    Camera(#[from] crate::camera::CameraError),
    /// The scene's `T` or its conditioning.
    #[error(transparent)]
    Scene(ScenesError),
    /// Frames to wall measurements.
    #[error(transparent)]
    Measure(#[from] crate::measure::MeasureError),
    /// The solver.
    #[error(transparent)]
    Solve(crate::solve::SolveError),
    /// A capture cannot serve this reconstruction (its frame, its files).
    #[error("capture {id}: {reason}")]
    Capture {
        /// The capture.
        id: i64,
        /// What is wrong with it.
        reason: String,
    },
    /// The live view's bench, window or camera (`GET /live` shows it).
    #[error("live view: {0}")]
    Live(String),
    /// The truth to score against does not fit the scene.
    #[error(transparent)]
    Truth(#[from] crate::files::truth::TruthError),
    /// No row of the measurement was usable: nothing to reconstruct.
    #[error("no wall element was measured, so there is nothing to reconstruct: {0}")]
    Unmeasured(String),
    /// A blocking task did not finish (it panicked or was cancelled).
    #[error("internal: {0}")]
    Task(String),
    /// A client cancelled the job while it ran (`DELETE /jobs/{id}`).
    #[error("cancelled")]
    Cancelled,
}

/// A solve stopped by its job's cancel flag is the job's cancellation.
impl From<crate::solve::SolveError> for JobError {
    fn from(e: crate::solve::SolveError) -> Self {
        match e {
            crate::solve::SolveError::Stopped { .. } => JobError::Cancelled,
            e => JobError::Solve(e),
        }
    }
}

/// A build of `T` or its Gram stopped by the job's cancel flag is the
/// job's cancellation.
impl From<ScenesError> for JobError {
    fn from(e: ScenesError) -> Self {
        match e {
            ScenesError::Stopped => JobError::Cancelled,
            e => JobError::Scene(e),
        }
    }
}

impl From<tokio::task::JoinError> for JobError {
    fn from(e: tokio::task::JoinError) -> Self {
        JobError::Task(e.to_string())
    }
}

/// A block as people read it: `pose A at 0°`, `pose A without polarizer`,
/// `pose A's 45° micro-polarizers`.
pub(in crate::daemon) fn block_label(pose: &str, channel: Channel) -> String {
    match channel {
        Channel::Sheet { deg } => format!("pose {pose} at {deg}°"),
        Channel::None => format!("pose {pose} without polarizer"),
        Channel::Mosaic { deg } => format!("pose {pose}'s {deg}° micro-polarizers"),
    }
}

/// What a capture yields, as people read it: its one block, or `pose A's
/// mosaic (4 blocks)`.
pub(in crate::daemon) fn capture_label(pose: &str, channels: &[Channel]) -> String {
    match channels {
        [one] => block_label(pose, *one),
        many => format!("pose {pose}'s mosaic ({} blocks)", many.len()),
    }
}

/// How a job that did not finish ended, for the store.
pub(in crate::daemon) enum Ending<'a> {
    /// With this error (paths redacted).
    Failed(&'a str),
    /// Cancelled by a client while it ran.
    Cancelled,
    /// Stopped because the daemon is stopping ([`crate::daemon::Daemon::drain`]).
    Interrupted,
}

/// Seconds to 10 ms, for a log field.
fn round2(seconds: f64) -> f64 {
    (seconds * 100.0).round() / 100.0
}

/// Records how a job ended: its time and done/failed counters, the failure
/// or cancellation in the store (`record`), and the job event.
pub(in crate::daemon) fn finish_job(
    d: &JobContext,
    job: String,
    start: Instant,
    result: Result<(), JobError>,
    (done, failed, micros): (&AtomicU64, &AtomicU64, &AtomicU64),
    record: impl FnOnce(Ending<'_>) -> Result<(), crate::store::StoreError>,
) {
    let took = start.elapsed();
    micros.fetch_add(took.as_micros() as u64, Ordering::Relaxed);
    let took = took.as_secs_f64();
    d.registry.forget(&job);
    match result {
        Ok(()) => {
            tracing::info!(job = %job, outcome = "done", seconds = round2(took), "job ended");
            done.fetch_add(1, Ordering::Relaxed);
            d.events.job(job, JobState::Done, None);
        }
        Err(JobError::Cancelled) if d.registry.is_stopping() => {
            tracing::info!(job = %job, outcome = "interrupted", seconds = round2(took), "job ended: the daemon is stopping");
            if let Err(se) = record(Ending::Interrupted) {
                tracing::error!("cannot record the interruption of {job}: {se}");
            }
            d.events.job(job, JobState::Interrupted, None);
        }
        Err(JobError::Cancelled) => {
            tracing::info!(job = %job, outcome = "cancelled", seconds = round2(took), "job ended");
            d.metrics.jobs_cancelled.fetch_add(1, Ordering::Relaxed);
            if let Err(se) = record(Ending::Cancelled) {
                tracing::error!("cannot record the cancellation of {job}: {se}");
            }
            d.events.job(job, JobState::Cancelled, None);
        }
        Err(e) => {
            tracing::warn!(job = %job, outcome = "failed", seconds = round2(took), error = %e, "job ended");
            // What clients read says where inside the data directory, not where it is.
            let e = d.store.redact_paths(&e.to_string());
            failed.fetch_add(1, Ordering::Relaxed);
            if let Err(se) = record(Ending::Failed(&e)) {
                tracing::error!("cannot record the failure of {job}: {se}");
            }
            d.events.job(job, JobState::Failed, Some(e));
        }
    }
}

/// How long a job waits for a camera that is not connected.
const CAMERA_GRACE: std::time::Duration = std::time::Duration::from_secs(5);

/// A camera that is (re)connecting gets a short grace period before the
/// capture (or live view) that needs it fails.
pub(in crate::daemon) async fn wait_for_camera(
    camera: &crate::daemon::runtime::camera::CameraService,
) {
    let grace = Instant::now();
    while !camera.status().connected && grace.elapsed() < CAMERA_GRACE {
        tokio::time::sleep(std::time::Duration::from_millis(100)).await;
    }
}

/// Moves the camera to pose `pose` of scene `scene`; a bench without a
/// stage (whose camera the operator moves, and the pose is trusted) does
/// nothing. The error says what went wrong, for the job to name itself.
pub(in crate::daemon) async fn move_to_pose(
    rig: &crate::rig::Rig,
    scenes: &Scenes,
    scene: &str,
    pose: &str,
) -> Result<(), PoseMoveError> {
    if !rig.automated().stage {
        return Ok(());
    }
    let s = scenes.scene(scene)?;
    let Some(p) = s.poses().iter().find(|p| p.name == pose) else {
        return Err(PoseMoveError::NoPose {
            scene: scene.to_string(),
            pose: pose.to_string(),
        });
    };
    if let Some(at) = rig.move_to(p).await? {
        tracing::info!("camera at pose {pose} ({at:?} m), read back from the stage");
    }
    Ok(())
}

/// Why the camera could not be moved to a job's pose.
#[derive(Debug, thiserror::Error)]
pub(in crate::daemon) enum PoseMoveError {
    /// The job's scene is not known (any more).
    #[error(transparent)]
    Scene(#[from] crate::daemon::runtime::scenes::ScenesError),
    /// The scene has no pose of that name.
    #[error("scene {scene:?} has no pose {pose:?}")]
    NoPose {
        /// The scene's name.
        scene: String,
        /// The pose asked for.
        pose: String,
    },
    /// The stage failed to move or to read back.
    #[error(transparent)]
    Rig(#[from] crate::rig::RigError),
}

/// Dark capture `id`'s mean frame and the variance of that mean (when it
/// recorded one), to subtract from a capture's or a live window's mean.
pub(in crate::daemon) fn dark_capture(
    store: &Store,
    id: i64,
) -> Result<(crate::scene::Frame, Option<crate::scene::Frame>), JobError> {
    let dir = store.capture_dir(id);
    let failed = |e: crate::store::StoreError| JobError::Capture {
        id,
        reason: store.describe(&e),
    };
    let mean = crate::store::read_mean(&dir).map_err(failed)?;
    let variance = crate::store::read_mean_variance(&dir).map_err(failed)?;
    Ok((mean, variance))
}

/// What every page of the capture's files records about it.
pub(in crate::daemon) fn meta_of(
    c: &crate::store::CaptureRecord,
    acquisition: crate::camera::Acquisition,
    camera_id: &str,
) -> crate::store::FrameMeta {
    crate::store::FrameMeta {
        capture: c.id,
        kind: c.kind,
        scene: c.scene.clone(),
        pose: c.pose.clone(),
        channels: c.channels.clone(),
        acquisition,
        dark_capture: c.dark_capture,
        camera_id: camera_id.to_string(),
    }
}
