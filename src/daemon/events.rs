//! Server-sent events: job progress, frames taken, camera state changes.

use serde::Serialize;

/// One event on `GET /events`.
#[derive(Debug, Clone, Serialize)]
#[serde(tag = "type", rename_all = "snake_case")]
pub enum Event {
    /// A job changed state.
    Job {
        /// `capture-<id>` or `reconstruction-<id>`.
        job: String,
        /// New state.
        state: crate::store::JobState,
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
        step: super::progressive::Step,
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
    /// The camera connected or was lost.
    Camera {
        /// Whether a camera is open.
        connected: bool,
        /// Why not, when not.
        #[serde(skip_serializing_if = "Option::is_none")]
        error: Option<String>,
    },
}
