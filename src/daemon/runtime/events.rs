//! Server-sent events: job progress, frames taken, progressive steps,
//! deletions, camera state changes.
//! [`Events`] is the sending side every service holds a clone of.

use std::sync::Arc;

use serde::Serialize;
use tokio::sync::{broadcast, watch};

pub(crate) use crate::solve::track::Centroid;
use crate::store::JobState;

/// The event stream's sending side: cloned into each service that announces
/// something, so none of them needs the whole daemon to do it.
#[derive(Debug, Clone)]
pub struct Events {
    sender: broadcast::Sender<Event>,
    /// True once the HTTP server stops: open event streams end then.
    closed: Arc<watch::Sender<bool>>,
}

impl Events {
    /// A stream that keeps the last `capacity` events for slow listeners.
    pub fn new(capacity: usize) -> Self {
        Self {
            sender: broadcast::channel(capacity).0,
            closed: Arc::new(watch::channel(false).0),
        }
    }

    /// Publishes an event (nobody listening is fine).
    pub fn emit(&self, e: Event) {
        let _ = self.sender.send(e);
    }

    /// Ends every open event stream (and any opened later).
    ///
    /// Why: a stream never ends by itself, and the server's shutdown waits
    /// for open responses; `GET /events` clients held a SIGTERM 5 s longer.
    pub fn close(&self) {
        self.closed.send_replace(true);
    }

    /// Resolves once [`Events::close`] was called.
    pub fn closed(&self) -> impl std::future::Future<Output = ()> + Send + 'static {
        let mut rx = self.closed.subscribe();
        async move {
            let _ = rx.wait_for(|c| *c).await;
        }
    }

    /// Publishes a job's change of state.
    pub fn job(&self, job: String, state: JobState, error: Option<String>) {
        self.emit(Event::Job { job, state, error });
    }

    /// Events from now on.
    pub fn subscribe(&self) -> broadcast::Receiver<Event> {
        self.sender.subscribe()
    }
}

/// One event on `GET /events`.
#[derive(Debug, Clone, Serialize)]
#[serde(tag = "type", rename_all = "snake_case")]
pub enum Event {
    /// A job changed state.
    Job {
        /// `capture-<id>` or `reconstruction-<id>`.
        job: String,
        /// New state.
        state: JobState,
        /// Error, when failed.
        #[serde(skip_serializing_if = "Option::is_none")]
        error: Option<String>,
    },
    /// A capture received a frame.
    Frame {
        /// `capture-<id>`.
        job: String,
        /// Frames received so far (dark frames first).
        taken: usize,
        /// Frames in all.
        total: usize,
    },
    /// A progressive reconstruction step finished (see `/captures/{id}/progressive.json`).
    Progressive {
        /// `capture-<id>`.
        job: String,
        /// The step's numbers.
        #[serde(flatten)]
        step: Step,
    },
    /// A scene calibration built one more `T` (see `/calibrations/scene/{id}`).
    SceneFit {
        /// `scene-fit-<id>`.
        job: String,
        /// `T` builds done.
        builds: usize,
        /// Builds its search may spend.
        max_builds: usize,
    },
    /// The live view published a result (see `GET /live`).
    Live {
        /// The live session (each `POST /live` starts one).
        session: u64,
        /// From the arrival of the window's newest frame to this result, ms.
        latency_ms: f64,
        /// Difference mode: the window's time (the mean arrival time of its
        /// frames), Unix seconds.
        #[serde(skip_serializing_if = "Option::is_none")]
        time_s: Option<f64>,
        /// Difference mode: the moving object's centroid on the hidden-scene
        /// plane (absent when nothing stood out of the noise).
        #[serde(skip_serializing_if = "Option::is_none")]
        centroid: Option<Centroid>,
        /// The result's numbers (`frames`: the window).
        #[serde(flatten)]
        step: Step,
    },
    /// A capture or a reconstruction was deleted, row and files.
    Deleted {
        /// `capture` or `reconstruction`.
        kind: &'static str,
        /// Its id.
        id: i64,
        /// `request` (a client's DELETE) or `retention` (the policy in the config).
        reason: &'static str,
    },
    /// A plan moved: a step ended, it waits for the operator, or it ended.
    Plan {
        /// The plan's id.
        plan: i64,
        /// Where it is.
        state: crate::store::PlanState,
        /// The step it is at.
        step: usize,
        /// What the operator is asked to do (while waiting for the operator).
        #[serde(skip_serializing_if = "Option::is_none")]
        prompt: Option<String>,
    },
    /// The camera connected or was lost.
    Camera {
        /// Whether a camera is open.
        connected: bool,
        /// Why not, when not.
        #[serde(skip_serializing_if = "Option::is_none")]
        error: Option<String>,
    },
}

/// One published progressive step (what `progressive.json` lists and the
/// `progressive` event carries).
#[derive(Debug, Clone, Serialize, utoipa::ToSchema)]
pub struct Step {
    /// Frames in the mean it solved.
    pub frames: usize,
    /// ADMM iterations it took (warm-started from the previous step).
    pub iterations: usize,
    /// Whether ADMM met its tolerance.
    pub converged: bool,
    /// `||l_k - l_{k-1}|| / ||l_k||` against the previous step.
    pub change: Option<f64>,
    /// PSNR against the truth, when one was given, dB.
    pub psnr_db: Option<f64>,
    /// The TV weight the step used: the automatic rule's, from the running
    /// frame variance, unless the request fixed it.
    pub lambda: Option<f64>,
    /// Seconds the step took.
    pub seconds: f64,
    /// A fitted radiometry's gain and background per colour (absent when
    /// calibrated).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub fitted: Option<FittedStep>,
}

/// What a progressive or live step with a fitted radiometry fitted beside
/// the image (docs/realphoto.md's `i_c = g_c T l_c + b_{p,c}`), in the
/// measurement's units (fractions of full scale per microsecond).
#[derive(Debug, Clone, Serialize, utoipa::ToSchema)]
pub struct FittedStep {
    /// Each colour's gain `g_c` (one for a grey camera; red, green, blue).
    pub gain: Vec<f64>,
    /// Each colour's background (ambient light) per block of the scene.
    pub background: Vec<Vec<f64>>,
    /// The shadow model of the `T` it was fitted with: `point` or `area`.
    pub shadows: String,
    /// Whether this step searched λ (the first, or data that moved).
    pub lambda_searched: bool,
}
