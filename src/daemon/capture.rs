//! Capture jobs: the worker that runs them one at a time and streams each
//! frame to disk while it arrives (the request is checked in
//! [`super::validate`] before it is queued).
//!
//! Dark frames are never taken silently with the scene lit: a bench that can
//! switch the hidden scene off itself (the fake bench, a motorized shutter)
//! takes `dark_frames` within a capture; on a bench set by hand the user
//! switches the scene off and asks for a `"kind": "dark"` capture, then names
//! it in later captures as `dark_capture`.

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::Instant;

use tokio::sync::mpsc;

use super::jobs::{finish_job, job_event, Ending, JobError};
use super::progressive;
use super::{Daemon, Event};
use crate::camera::{Acquisition, CameraError, CameraSettings, Frame, RawFrame};
use crate::measure::FrameStack;
use crate::store::{
    read_mean, write_frames, write_summary, CaptureFiles, CaptureKind, CaptureRecord, FrameMeta,
    JobState,
};

/// Least time between two frames kept for the live view (`/camera/frame.png`).
const LIVE_EVERY: std::time::Duration = std::time::Duration::from_millis(200);

/// Frames in flight between the camera thread and the writer.
const FRAME_QUEUE: usize = 4;

/// How long a capture waits for a camera that is not connected.
const CAMERA_GRACE: std::time::Duration = std::time::Duration::from_secs(5);

/// Runs captures one at a time (one camera).
pub(super) async fn capture_worker(d: Arc<Daemon>, mut rx: mpsc::Receiver<i64>) {
    let mut stopped = d.stopped();
    loop {
        // Biased towards the stop: a job still queued when the drain
        // starts stays queued, however ready the queue is.
        let id = tokio::select! {
            biased;
            _ = stopped.wait_for(|s| *s) => None,
            id = rx.recv() => id,
        };
        let Some(id) = id else { return };
        let job = format!("capture-{id}");
        let start = Instant::now();
        // Held for the whole capture: settings changes answer 409 meanwhile.
        let camera = d.camera_gate.lock().await;
        if d.is_stopping() {
            // The drain began while this capture waited for the camera.
            d.release_capture(id);
            return;
        }
        let result = match d.store.capture_running(id) {
            // Cancelled while it waited in the queue.
            Ok(false) => {
                d.release_capture(id);
                d.forget_cancel(&job);
                continue;
            }
            Ok(true) => run_capture(&d, id, &d.cancel_flag(&job)).await,
            Err(e) => Err(JobError::Store(d.store.describe(&e))),
        };
        drop(camera);
        d.release_capture(id);
        let m = &d.metrics;
        let counters = (&m.captures_done, &m.captures_failed, &m.capture_micros);
        finish_job(&d, job, start, result, counters, |end| match end {
            Ending::Failed(e) => d.store.capture_failed(id, e),
            Ending::Cancelled => d.store.capture_cancelled(id).map(|_| ()),
            Ending::Interrupted => d.store.interrupted("captures", id),
        });
    }
}

async fn run_capture(d: &Arc<Daemon>, id: i64, cancel: &AtomicBool) -> Result<(), JobError> {
    let store_err = |e: crate::store::StoreError| JobError::Store(d.store.describe(&e));
    let c = d.store.capture(id).map_err(store_err)?;
    job_event(d, format!("capture-{id}"), JobState::Running, None);
    // The settings recorded when it was accepted.
    let acquisition = Acquisition::try_from(&c).map_err(|e| JobError::Capture {
        id,
        reason: e.to_string(),
    })?;
    let settings = CameraSettings::from(acquisition);
    wait_for_camera(d).await;
    let camera_id = d.camera.status().info.map(|i| i.id).unwrap_or_default();
    let meta = meta_of(&c, acquisition, &camera_id);
    let dir = d.store.capture_dir(id);
    std::fs::create_dir_all(&dir).map_err(|e| JobError::Store(d.store.describe_io(&dir, &e)))?;
    d.bench.select(&c.pose, c.polarizer_deg);
    let stream = Stream {
        d,
        id,
        settings: &settings,
        meta: &meta,
        total: (c.frames + c.dark_frames) as usize,
        cancel,
    };
    let spec = d
        .progressive
        .lock()
        .map(|mut m| m.remove(&id))
        .unwrap_or(None);
    let dark = dark_reference(d, &c, &stream).await?;
    let scene_off = meta.kind == CaptureKind::Dark && d.bench.switches_scene();
    if scene_off {
        d.bench.scene_on(false);
    }
    let target = meta.kind == CaptureKind::Target;
    if target {
        d.bench.show_target(true);
    }
    let source = meta.kind == CaptureKind::Source;
    if source {
        d.bench.show_source(true);
    }
    let (n, offset) = (c.frames as usize, c.dark_frames as usize);
    let progressive = spec.map(|s| progressive::start(d, c.clone(), &s, dark.clone()));
    let snapshots = progressive.as_ref().map(|(tx, _)| tx.clone());
    let frames = stream
        .take(CaptureFiles::FRAMES, "frames", n, offset, snapshots)
        .await;
    if scene_off {
        d.bench.scene_on(true);
    }
    if target {
        d.bench.show_target(false);
    }
    if source {
        d.bench.show_source(false);
    }
    if let Some((tx, steps)) = progressive {
        finish_progressive(d, id, frames.as_ref().ok(), tx, steps).await;
    }
    let frames = match frames {
        Ok(f) => f,
        Err(e) => {
            // Cancelled or failed: its dark frames are of no use either.
            crate::store::remove_raw(&dir);
            return Err(e);
        }
    };
    let store = d.store.clone();
    tokio::task::spawn_blocking(move || {
        write_summary(&dir, &frames, dark.as_ref(), &meta)
            .map_err(|e| JobError::Store(store.describe(&e)))
    })
    .await??;
    let counters = serde_json::to_string(&d.camera.status().counters).unwrap_or_default();
    d.store
        .capture_done(id, &camera_id, &counters)
        .map_err(store_err)
}

/// Gives the progressive solver the final mean (so the last step is always
/// solved) and waits for it; a capture that did not finish keeps none of its
/// progressive files.
async fn finish_progressive(
    d: &Daemon,
    id: i64,
    frames: Option<&FrameStack>,
    tx: progressive::Snapshots,
    steps: tokio::task::JoinHandle<Vec<progressive::Step>>,
) {
    if let Some(st) = frames {
        let _ = tokio::task::spawn_blocking(tx.send_last(st)).await;
    } else {
        drop(tx);
    }
    let steps = steps.await.unwrap_or_default();
    tracing::info!("capture-{id}: {} progressive steps", steps.len());
    if frames.is_none() {
        progressive::remove_files(d, id);
    }
}

/// A camera that is (re)connecting gets a short grace period before the capture fails.
async fn wait_for_camera(d: &Daemon) {
    let grace = Instant::now();
    while !d.camera.status().connected && grace.elapsed() < CAMERA_GRACE {
        tokio::time::sleep(std::time::Duration::from_millis(100)).await;
    }
}

/// What every page of the capture's files records about it.
fn meta_of(c: &CaptureRecord, acquisition: Acquisition, camera_id: &str) -> FrameMeta {
    FrameMeta {
        capture: c.id,
        kind: c.kind,
        scene: c.scene.clone(),
        pose: c.pose.clone(),
        polarizer_deg: c.polarizer_deg,
        acquisition,
        dark_capture: c.dark_capture,
        camera_id: camera_id.to_string(),
    }
}

/// The dark level to subtract: the mean of dark frames taken now with the
/// scene switched off (only on a bench that can, checked at acceptance), or
/// a dark capture's mean frame, or none.
async fn dark_reference(
    d: &Daemon,
    c: &CaptureRecord,
    stream: &Stream<'_>,
) -> Result<Option<Frame>, JobError> {
    if c.dark_frames > 0 {
        d.bench.scene_on(false);
        let n = c.dark_frames as usize;
        let r = stream.take(CaptureFiles::DARK, "dark", n, 0, None).await;
        d.bench.scene_on(true);
        let st = r.map_err(|e| match e {
            JobError::Cancelled => JobError::Cancelled,
            e => JobError::Capture {
                id: c.id,
                reason: format!("dark frames: {e}"),
            },
        })?;
        return Ok(Some(Frame {
            width: st.width,
            height: st.height,
            pixels: st.mean.iter().map(|&v| v as f32).collect(),
        }));
    }
    match c.dark_capture {
        Some(dc) => {
            let mean = read_mean(&d.store.capture_dir(dc)).map_err(|e| JobError::Capture {
                id: dc,
                reason: d.store.describe(&e),
            })?;
            Ok(Some(mean))
        }
        None => Ok(None),
    }
}

/// One acquisition of a capture, streamed to one file.
struct Stream<'a> {
    d: &'a Arc<Daemon>,
    id: i64,
    settings: &'a CameraSettings,
    meta: &'a FrameMeta,
    total: usize,
    /// Set by `DELETE /jobs/capture-<id>`: the writer stops at the next frame.
    cancel: &'a AtomicBool,
}

impl Stream<'_> {
    /// Acquires `n` frames into the capture's file `name`, while a blocking
    /// writer puts each on disk and adds it to the running mean; progress
    /// counts from `offset`.
    async fn take(
        &self,
        name: &str,
        kind: &'static str,
        n: usize,
        offset: usize,
        snapshots: Option<progressive::Snapshots>,
    ) -> Result<FrameStack, JobError> {
        let (id, total, d) = (self.id, self.total, self.d);
        if self.cancel.load(Ordering::SeqCst) {
            return Err(JobError::Cancelled);
        }
        let (frame_tx, frame_rx) = std::sync::mpsc::sync_channel::<RawFrame>(FRAME_QUEUE);
        let (progress_tx, mut progress_rx) = mpsc::unbounded_channel::<usize>();
        let path = d.store.capture_dir(id).join(name);
        let meta = self.meta.clone();
        let store = d.store.clone();
        let cancel = d.cancel_flag(&format!("capture-{id}"));
        let live = d.clone();
        let writer = tokio::task::spawn_blocking(move || {
            let mut shown = None;
            // A cancelled capture ends its stream at the next frame: the file
            // is incomplete, so it is removed, and the camera stops when its
            // next frame finds the channel closed.
            let frames = frame_rx
                .into_iter()
                .take_while(|_| !cancel.load(Ordering::SeqCst))
                .inspect(|f| {
                    // The live view polls once a second: copy a frame for it
                    // at most every LIVE_EVERY, not every frame.
                    if shown.is_none_or(|t: Instant| t.elapsed() >= LIVE_EVERY) {
                        shown = Some(Instant::now());
                        if let Ok(mut latest) = live.latest_frame.lock() {
                            *latest = Some(Arc::new(f.clone()));
                        }
                    }
                });
            write_frames(&path, kind, &meta, n, frames, &mut |st: &FrameStack| {
                let _ = progress_tx.send(offset + st.count);
                if let Some(s) = &snapshots {
                    s.offer(st, n);
                }
            })
            .map_err(|e| JobError::Store(store.describe(&e)))
        });
        let d2 = d.clone();
        let progress = tokio::spawn(async move {
            while let Some(taken) = progress_rx.recv().await {
                d2.emit(Event::Frame {
                    job: format!("capture-{id}"),
                    taken,
                    total,
                });
                let store = d2.store.clone();
                let _ =
                    tokio::task::spawn_blocking(move || store.capture_progress(id, taken)).await;
            }
        });
        let acquired = d.camera.acquire(self.settings.clone(), n, frame_tx).await;
        let written = writer.await.map_err(JobError::from).and_then(|r| r);
        let _ = progress.await;
        if self.cancel.load(Ordering::SeqCst) && written.is_err() {
            return Err(JobError::Cancelled);
        }
        match (acquired, written) {
            (Ok(()), Ok(stack)) => Ok(stack),
            // The writer stopped first (a full disk): its reason is the one that matters.
            (Err(CameraError::Stopped(_)), Err(w)) | (Ok(()), Err(w)) => Err(w),
            (Err(e), _) => Err(e.into()),
        }
    }
}
