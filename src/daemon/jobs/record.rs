//! Recording a live session (`POST /live` with `record`): its first frames
//! after its dark frames, written as they arrive to the capture admission
//! reserved for them, page by page as the capture worker writes its frames
//! ([`crate::store::write_frames_upto`]), so that memory does not grow with
//! the count. The capture goes done when its frames are written; a session
//! that ends first keeps the frames it got, and the capture's `live` record
//! says why and of how many.
//!
//! Why beside the live view and not a queued capture: the frames are the
//! ones the live view solves, taken once; a capture would take the camera
//! from it.

use std::sync::atomic::Ordering;
use std::sync::mpsc::{Receiver, SyncSender};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use super::{JobContext, JobError};
use crate::camera::{Acquisition, FrameCounts, FrameIds, RawFrame};
use crate::daemon::runtime::camera::CameraService;
use crate::daemon::runtime::events::Events;
use crate::daemon::runtime::live::{Live, RecordingState};
use crate::daemon::runtime::queue::CaptureQueue;
use crate::daemon::Event;
use crate::measure::FrameStack;
use crate::scene::Frame;
use crate::store::{
    remove_raw, write_frames, write_frames_upto, write_summary, CaptureFiles, FrameMeta, JobState,
    LiveInfo, Store, StoreError,
};

/// Frames in flight between the live view's frame reader and the writer.
const FRAME_QUEUE: usize = 8;

/// Least time between two catalogue updates of a recording's progress.
const PROGRESS_EVERY: Duration = Duration::from_millis(250);

/// The frame reader's end of a recording: hands it the session's frames
/// until it has its count, then closes, so that the writer finishes it.
pub(super) struct Tap {
    tx: Option<SyncSender<RawFrame>>,
    left: usize,
}

impl Tap {
    /// Gives `f` to the recording while it wants frames (waiting for the
    /// writer when it is behind: a recording misses no frame); a writer
    /// that stopped (a full disk, a cancel) takes no more.
    pub(super) fn offer(&mut self, f: &RawFrame) {
        if self.left == 0 {
            return;
        }
        self.left -= 1;
        let sent = self
            .tx
            .as_ref()
            .is_some_and(|tx| tx.send(f.clone()).is_ok());
        if !sent || self.left == 0 {
            self.tx = None;
        }
    }
}

/// A recording under way, as the live segment ends it.
pub(super) struct Recorder {
    /// Why the session ended, set before the tap closes early.
    why: Arc<Mutex<Option<String>>>,
    writer: tokio::task::JoinHandle<()>,
}

impl Recorder {
    /// Ends the recording with its tap (if the reader still holds it): `why`
    /// the session ended names a capture that got fewer frames than asked.
    /// Waits for the writer to finish the capture.
    pub(super) async fn finish(self, tap: Option<Tap>, why: String) {
        *self.why.lock().unwrap_or_else(|e| e.into_inner()) = Some(why);
        drop(tap);
        if let Err(e) = self.writer.await {
            tracing::error!("live recording: its writer did not finish: {e}");
        }
    }
}

/// What a recording uses of the live segment's: the job services, the
/// camera (its id and counters) and the capture queue (its reservation).
#[derive(Clone, Copy)]
pub(super) struct Services<'a> {
    pub(super) jobs: &'a JobContext,
    pub(super) camera: &'a Arc<CameraService>,
    pub(super) queue: &'a Arc<CaptureQueue>,
}

/// Starts session `session`'s recording if it waits for its first frame:
/// its capture running, the segment's `dark` frames written as the
/// capture's, and a writer for its frames. None when there is none, or it
/// was cancelled or could not start (its capture then says why).
pub(super) async fn begin(
    w: Services<'_>,
    live: &Arc<Live>,
    session: u64,
    settings: Acquisition,
    dark: (&[RawFrame], &(Option<Frame>, Option<Frame>)),
) -> Option<(Tap, Recorder)> {
    let (id, n) = live.claim_recording(session)?;
    let writer = Writer {
        jobs: w.jobs.clone(),
        live: live.clone(),
        queue: w.queue.clone(),
        camera: w.camera.clone(),
        session,
        id,
        n,
        dark_count: dark.0.len(),
        dark: dark.1.clone(),
        why: Arc::new(Mutex::new(None)),
    };
    let store = &w.jobs.store;
    match store.capture_running(id) {
        Ok(true) => {}
        Ok(false) => {
            live.recording_ended(
                session,
                RecordingState::Cancelled,
                Some(format!("capture-{id} was cancelled before its first frame")),
            );
            writer.release();
            return None;
        }
        Err(e) => {
            writer.failed(store.describe(&e), 0);
            writer.release();
            return None;
        }
    }
    w.jobs
        .events
        .job(format!("capture-{id}"), JobState::Running, None);
    let meta = match prepare(w, id, settings, dark.0).await {
        Ok(meta) => meta,
        Err(e) => {
            writer.failed(format!("its dark frames: {e}"), 0);
            writer.release();
            return None;
        }
    };
    let (tx, rx) = std::sync::mpsc::sync_channel(FRAME_QUEUE);
    let why = writer.why.clone();
    let handle = tokio::task::spawn_blocking(move || writer.run(rx, &meta));
    tracing::info!("capture-{id}: recording live session {session}'s next {n} frames");
    let tap = Tap {
        tx: Some(tx),
        left: n,
    };
    Some((
        tap,
        Recorder {
            why,
            writer: handle,
        },
    ))
}

/// The recording's folder and its dark frames (when the session took
/// some); the metadata its pages carry.
async fn prepare(
    w: Services<'_>,
    id: i64,
    settings: Acquisition,
    dark: &[RawFrame],
) -> Result<FrameMeta, JobError> {
    let store = w.jobs.store.clone();
    let c = store
        .capture(id)
        .map_err(|e| JobError::Store(store.describe(&e)))?;
    let camera_id = w.camera.status().info.map(|i| i.id).unwrap_or_default();
    let meta = super::meta_of(&c, settings, &camera_id);
    let dir = store.capture_dir(id);
    std::fs::create_dir_all(&dir).map_err(|e| JobError::Store(store.describe_io(&dir, &e)))?;
    if dark.is_empty() {
        return Ok(meta);
    }
    let (frames, m) = (dark.to_vec(), meta.clone());
    tokio::task::spawn_blocking(move || {
        let path = dir.join(CaptureFiles::DARK);
        write_frames(&path, "dark", &m, frames.len(), frames, &mut |_| {})
            .map_err(|e| JobError::Store(store.describe(&e)))
    })
    .await??;
    Ok(meta)
}

/// What the recording's writer thread holds.
struct Writer {
    jobs: JobContext,
    live: Arc<Live>,
    queue: Arc<CaptureQueue>,
    camera: Arc<CameraService>,
    session: u64,
    id: i64,
    /// Frames asked for.
    n: usize,
    dark_count: usize,
    /// The dark mean and its variance the capture's mean subtracts.
    dark: (Option<Frame>, Option<Frame>),
    /// Why the session ended, when it ended first.
    why: Arc<Mutex<Option<String>>>,
}

impl Writer {
    /// Writes the frames `rx` brings (until it closes, `n` frames, or a
    /// cancel), then ends the capture: done with the frames it got, failed,
    /// or cancelled; its disk reservation is released.
    fn run(self, rx: Receiver<RawFrame>, meta: &FrameMeta) {
        let job = format!("capture-{}", self.id);
        let flag = self.jobs.registry.cancel_flag(&job);
        // A daemon that stops sets every job's flag: a recording then ends
        // as its session does, keeping its frames.
        let registry = &self.jobs.registry;
        let cancel = || flag.load(Ordering::SeqCst) && !registry.is_stopping();
        let (store, d) = (&self.jobs.store, self.dark_count);
        let mut ids = FrameIds::default();
        let mut dropped = 0;
        let mut got = 0;
        let mut saved: Option<Instant> = None;
        let frames = rx
            .into_iter()
            .take_while(|_| !cancel())
            .inspect(|f| dropped += ids.next(f.frame_id));
        let path = store.capture_dir(self.id).join(CaptureFiles::FRAMES);
        let written = write_frames_upto(&path, "frames", meta, self.n, frames, &mut |st| {
            got = st.count;
            self.live.recorded(self.session, got);
            self.jobs.events.emit(Event::Frame {
                job: job.clone(),
                taken: d + got,
                total: d + self.n,
            });
            if saved.is_none_or(|t| t.elapsed() >= PROGRESS_EVERY) || got == self.n {
                saved = Some(Instant::now());
                let _ = store.capture_progress(self.id, d + got);
            }
        });
        if cancel() {
            self.cancelled();
        } else {
            match written.and_then(|st| self.complete(st, dropped, meta)) {
                Ok(()) => {}
                Err(StoreError::Incomplete { got: 0, .. }) => self.failed(
                    format!(
                        "{} before its first frame: no frame was recorded",
                        self.why()
                    ),
                    0,
                ),
                Err(e) => self.failed(store.describe(&e), got),
            }
        }
        self.release();
    }

    /// Gives back the capture's disk reservation and its cancel flag: the
    /// recording has ended, however it ended.
    fn release(&self) {
        self.queue.release(self.id);
        self.jobs.registry.forget(&format!("capture-{}", self.id));
    }

    /// Why the session ended before the recording's count (said by the
    /// segment that ended it, else that it ended).
    fn why(&self) -> String {
        self.why
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .clone()
            .unwrap_or_else(|| "the live session ended".into())
    }

    /// Writes the capture's mean, variance and preview and records it done
    /// with the `st.count` frames it holds (and why not `n`, when fewer).
    fn complete(&self, st: FrameStack, dropped: u64, meta: &FrameMeta) -> Result<(), StoreError> {
        let (store, id, k) = (&self.jobs.store, self.id, st.count);
        let dir = store.capture_dir(id);
        write_summary(&dir, &st, self.dark.0.as_ref(), self.dark.1.as_ref(), meta)?;
        let ended = (k < self.n).then(|| format!("{} after {k} of {} frames", self.why(), self.n));
        let info = LiveInfo {
            session: self.session,
            frames_asked: self.n,
            ended: ended.clone(),
        };
        // Frames missing between those recorded (their ids skipped) count
        // as dropped: whether whole or broken, they never reached it.
        let counts = FrameCounts {
            received: (k + self.dark_count) as u64,
            dropped,
            broken: 0,
        };
        let counters = serde_json::to_string(&self.camera.status().counters).unwrap_or_default();
        let taken = (meta.camera_id.as_str(), counters.as_str(), counts);
        store.live_capture_done(id, k, &info, taken, st.clipping)?;
        let state = match &ended {
            Some(why) => {
                tracing::info!("capture-{id} (live session {}): {why}", self.session);
                RecordingState::Ended
            }
            None => {
                tracing::info!(
                    "capture-{id}: live session {}'s {k} frames recorded",
                    self.session
                );
                RecordingState::Done
            }
        };
        self.live.recording_ended(self.session, state, ended);
        self.jobs
            .events
            .job(format!("capture-{id}"), JobState::Done, None);
        Ok(())
    }

    /// The capture failed for `reason` after `got` frames: nothing of it is
    /// kept (its files would not make a whole capture). The caller releases it.
    fn failed(&self, reason: String, got: usize) {
        let (store, id) = (&self.jobs.store, self.id);
        remove_raw(&store.capture_dir(id));
        let reason = match got {
            0 => reason,
            got => format!("{reason} (after {got} of {} frames)", self.n),
        };
        tracing::warn!("capture-{id} (live recording) failed: {reason}");
        if let Err(e) = store.capture_failed(id, &reason) {
            tracing::error!("cannot record the failure of capture-{id}: {e}");
        }
        self.live
            .recording_ended(self.session, RecordingState::Failed, Some(reason.clone()));
        self.jobs
            .events
            .job(format!("capture-{id}"), JobState::Failed, Some(reason));
    }

    /// The capture was cancelled (`DELETE /jobs/capture-<id>`): it keeps no frame.
    fn cancelled(&self) {
        let (store, id) = (&self.jobs.store, self.id);
        remove_raw(&store.capture_dir(id));
        if let Err(e) = store.capture_cancelled(id) {
            tracing::error!("cannot record the cancellation of capture-{id}: {e}");
        }
        let reason = format!("capture-{id} was cancelled; it keeps no frame");
        self.live
            .recording_ended(self.session, RecordingState::Cancelled, Some(reason));
        self.jobs
            .events
            .job(format!("capture-{id}"), JobState::Cancelled, None);
    }
}

/// Ends recording capture `id`, to which no frame went, as failed for
/// `why` (its session was stopped, replaced or failed first), and releases
/// its disk; a capture cancelled meanwhile stays cancelled.
pub(in crate::daemon) fn unrecorded(
    store: &Store,
    queue: &CaptureQueue,
    events: &Events,
    id: i64,
    why: &str,
) {
    queue.release(id);
    if !store.capture(id).is_ok_and(|c| c.state == JobState::Queued) {
        return;
    }
    let reason = format!("{why} before its first frame: no frame was recorded");
    tracing::info!("capture-{id} (live recording): {reason}");
    match store.capture_failed(id, &reason) {
        Ok(()) => events.job(format!("capture-{id}"), JobState::Failed, Some(reason)),
        Err(e) => tracing::error!("cannot record the failure of capture-{id}: {e}"),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn frame(id: u64) -> RawFrame {
        RawFrame {
            width: 1,
            height: 1,
            bits: 16,
            pixels: vec![1],
            frame_id: id,
            system_timestamp_ns: 0,
        }
    }

    #[test]
    fn a_tap_passes_its_count_of_frames_then_closes() {
        let (tx, rx) = std::sync::mpsc::sync_channel(8);
        let mut tap = Tap {
            tx: Some(tx),
            left: 3,
        };
        for id in 1..=5 {
            tap.offer(&frame(id));
        }
        let ids: Vec<u64> = rx.iter().map(|f| f.frame_id).collect();
        assert_eq!(ids, [1, 2, 3], "the first three, and the channel closed");
    }

    #[test]
    fn a_tap_whose_writer_stopped_takes_no_more() {
        let (tx, rx) = std::sync::mpsc::sync_channel(8);
        let mut tap = Tap {
            tx: Some(tx),
            left: 3,
        };
        drop(rx);
        tap.offer(&frame(1));
        assert!(tap.tx.is_none());
        tap.offer(&frame(2));
    }
}
