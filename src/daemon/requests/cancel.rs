//! Cancelling jobs (`DELETE /jobs/{id}`): a queued job is marked cancelled
//! in the store and skipped by its worker; a running one gets its flag set
//! and stops at the next point it checks (a capture at its next frame,
//! keeping nothing half-written; a reconstruction between its stages).

use std::sync::atomic::Ordering;
use std::time::{Duration, Instant};

use super::admission::Admission;
use crate::store::{JobState, StoreError};

/// How long `DELETE /jobs/{id}` waits for a running job to stop.
const STOP_WAIT: Duration = Duration::from_secs(5);

/// Which queue a job is in.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum JobKind {
    /// `capture-<n>`.
    Capture,
    /// `reconstruction-<n>`.
    Reconstruction,
    /// `scene-fit-<n>`: a scene calibration (`POST /calibrations/scene`).
    SceneFit,
}

impl JobKind {
    /// `capture` or `reconstruction`.
    pub fn name(self) -> &'static str {
        match self {
            JobKind::Capture => "capture",
            JobKind::Reconstruction => "reconstruction",
            JobKind::SceneFit => "scene-fit",
        }
    }
}

/// Why a job could not be cancelled.
#[derive(Debug, thiserror::Error)]
pub enum CancelError {
    /// No such job (404).
    #[error("no {kind} with id {id}")]
    NotFound {
        /// `capture` or `reconstruction`.
        kind: &'static str,
        /// The id asked for.
        id: i64,
    },
    /// It already ended (409).
    #[error("{kind}-{id} is {}; only queued or running jobs can be cancelled", state.name())]
    Ended {
        /// `capture` or `reconstruction`.
        kind: &'static str,
        /// Its id.
        id: i64,
        /// How it ended.
        state: JobState,
    },
    /// The catalogue failed.
    #[error("{0}")]
    Store(String),
}

impl Admission {
    /// Deletes capture `id` (and, with `with_reconstructions`, the
    /// reconstructions that use it) on a client's request; returns those
    /// reconstructions.
    pub(crate) fn delete_capture(
        &self,
        id: i64,
        with_reconstructions: bool,
    ) -> Result<Vec<i64>, StoreError> {
        crate::daemon::runtime::retention::delete_capture(
            &self.store,
            &self.events,
            id,
            with_reconstructions,
            "request",
        )
    }

    /// Deletes reconstruction `id` on a client's request.
    pub(crate) fn delete_reconstruction(&self, id: i64) -> Result<(), StoreError> {
        self.store.delete_reconstruction(id)?;
        self.events.emit(crate::daemon::Event::Deleted {
            kind: "reconstruction",
            id,
            reason: "request",
        });
        Ok(())
    }

    fn job_state(&self, kind: JobKind, id: i64) -> Result<JobState, CancelError> {
        let r = match kind {
            JobKind::Capture => self.store.capture(id).map(|c| c.state),
            JobKind::Reconstruction => self.store.reconstruction(id).map(|r| r.state),
            JobKind::SceneFit => self.store.scene_fit(id).map(|r| r.state),
        };
        r.map_err(|e| match e {
            StoreError::NotFound { .. } => CancelError::NotFound {
                kind: kind.name(),
                id,
            },
            e => CancelError::Store(self.store.describe(&e)),
        })
    }

    /// Cancels a queued or running job; returns its state when this returns:
    /// `cancelled`, or still `running` if it did not stop within 5 s (it
    /// will, at its next check).
    pub(crate) async fn cancel_job(&self, kind: JobKind, id: i64) -> Result<JobState, CancelError> {
        let job = format!("{}-{id}", kind.name());
        let state = self.job_state(kind, id)?;
        if !matches!(state, JobState::Queued | JobState::Running) {
            return Err(CancelError::Ended {
                kind: kind.name(),
                id,
                state,
            });
        }
        let store_err = |e: StoreError| CancelError::Store(self.store.describe(&e));
        let cancelled_queued = match kind {
            JobKind::Capture => self.store.cancel_queued_capture(id),
            JobKind::Reconstruction => self.store.cancel_queued_reconstruction(id),
            // Its thread starts with it: it is never left queued.
            JobKind::SceneFit => Ok(false),
        }
        .map_err(store_err)?;
        if cancelled_queued {
            if kind == JobKind::Capture {
                self.captures.release(id);
            }
            self.metrics.jobs_cancelled.fetch_add(1, Ordering::Relaxed);
            tracing::info!("{job} cancelled while queued");
            self.events.job(job, JobState::Cancelled, None);
            return Ok(JobState::Cancelled);
        }
        // Running (or it started just now): the worker sees the flag.
        tracing::info!("{job}: cancel asked while it runs");
        self.registry
            .cancel_flag(&job)
            .store(true, Ordering::SeqCst);
        let start = Instant::now();
        loop {
            let state = self.job_state(kind, id)?;
            if state != JobState::Running || start.elapsed() > STOP_WAIT {
                return Ok(state);
            }
            tokio::time::sleep(Duration::from_millis(50)).await;
        }
    }
}
