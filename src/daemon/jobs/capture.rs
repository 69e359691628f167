//! Capture jobs: the worker that runs them one at a time and streams each
//! frame to disk while it arrives (the request is checked in
//! [`crate::daemon::requests::validate`] before it is queued).
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
use tracing::Instrument;

use super::progressive;
use super::{finish_job, Ending, JobContext, JobError};
use crate::camera::{Acquisition, CameraError, FrameCounts, RawFrame};
use crate::daemon::runtime::camera::CameraService;
use crate::daemon::runtime::config::{LostFrames, Saturated};
use crate::daemon::runtime::events::Step;
use crate::daemon::runtime::queue::CaptureQueue;
use crate::daemon::Event;
use crate::measure::FrameStack;
use crate::rig::{Aid, Rig, RigError};
use crate::scene::Frame;
use crate::store::{
    write_frames, write_summary, CaptureFiles, CaptureKind, CaptureRecord, FrameMeta, JobState,
};

/// Least time between two frames kept for the live view (`/camera/frame.png`).
const LIVE_EVERY: std::time::Duration = std::time::Duration::from_millis(200);

/// Frames in flight between the camera thread and the writer.
const FRAME_QUEUE: usize = 4;

/// The capture worker and what it uses: the job services, the camera and
/// the capture queue (for the disk reservations and progressive specs).
pub(in crate::daemon) struct CaptureWorker {
    pub(in crate::daemon) jobs: JobContext,
    pub(in crate::daemon) camera: Arc<CameraService>,
    /// The bench's devices: the camera to the capture's pose, the polarizer
    /// to its angle, the hidden scene's light off for darks.
    pub(in crate::daemon) rig: Arc<Rig>,
    pub(in crate::daemon) queue: Arc<CaptureQueue>,
    /// What a capture that lost frames does.
    pub(in crate::daemon) lost_frames: LostFrames,
    /// What a capture with saturated pixels does, above which share of a frame.
    pub(in crate::daemon) saturated: (Saturated, f64),
    /// How far beyond twice its frames' time an acquisition may run.
    pub(in crate::daemon) stall_slack: std::time::Duration,
    /// The live view, run between captures.
    pub(in crate::daemon) live: Arc<crate::daemon::runtime::live::Live>,
}

impl CaptureWorker {
    /// Runs captures one at a time (one camera) until the daemon stops, and
    /// the live view while no capture waits.
    pub(in crate::daemon) async fn run(mut self, mut rx: mpsc::Receiver<i64>) {
        let mut stopped = self.jobs.registry.stopped();
        let mut live_changed = self.live.subscribe();
        loop {
            // Each capture (and live segment) keeps the scenes as it started.
            self.jobs = self.jobs.with_current_scenes();
            let w = &self;
            if w.queue.depth() == 0 && !w.jobs.registry.is_stopping() && w.live.wanted().is_some() {
                // Returns when a capture is queued, the session changes, or the daemon stops.
                live_changed.borrow_and_update();
                let run = super::live::LiveRun {
                    jobs: &w.jobs,
                    camera: &w.camera,
                    rig: &w.rig,
                    queue: &w.queue,
                };
                super::live::segment(&run, &w.live).await;
                continue;
            }
            // Biased towards the stop: a job still queued when the drain
            // starts stays queued, however ready the queue is.
            let id = tokio::select! {
                biased;
                _ = stopped.wait_for(|s| *s) => None,
                id = rx.recv() => id,
                _ = live_changed.changed() => continue,
            };
            let Some(id) = id else { return };
            let job = format!("capture-{id}");
            if let Some((session, ..)) = w.live.wanted() {
                w.live.set_state(
                    session,
                    crate::daemon::runtime::live::LiveState::Paused,
                    Some(job.clone()),
                );
            }
            let start = Instant::now();
            // Held for the whole capture: settings changes answer 409 meanwhile.
            let lease = w.camera.lease(&job).await;
            if w.jobs.registry.is_stopping() {
                // The drain began while this capture waited for the camera.
                w.queue.release(id);
                return;
            }
            let result = match w.jobs.store.capture_running(id) {
                // Cancelled while it waited in the queue.
                Ok(false) => {
                    w.queue.release(id);
                    w.jobs.registry.forget(&job);
                    continue;
                }
                Ok(true) => {
                    tracing::info!("{job} started");
                    let span = tracing::info_span!("job", id = %job);
                    run_capture(w, id, &w.jobs.registry.cancel_flag(&job))
                        .instrument(span)
                        .await
                }
                Err(e) => Err(JobError::Store(w.jobs.store.describe(&e))),
            };
            drop(lease);
            let store = &w.jobs.store;
            let result = result.and_then(|t| {
                store
                    .capture_done(id, &t.camera_id, &t.counters, t.counts, t.clipping)
                    .map_err(|e| JobError::Store(store.describe(&e)))
            });
            w.queue.release(id);
            let m = &w.jobs.metrics;
            let counters = (&m.captures_done, &m.captures_failed, &m.capture_micros);
            finish_job(&w.jobs, job, start, result, counters, |end| match end {
                Ending::Failed(e) => store.capture_failed(id, e),
                Ending::Cancelled => store.capture_cancelled(id).map(|_| ()),
                Ending::Interrupted => store.interrupted(crate::store::Table::Captures, id),
            });
        }
    }
}

/// What a capture's record gets once its files are durable and the camera
/// is released ([`run_capture`]'s result).
struct Taken {
    camera_id: String,
    counters: String,
    counts: FrameCounts,
    clipping: crate::measure::Clipping,
}

/// Takes capture `id` and writes its files; the caller records it done
/// after releasing the camera, so that a client told "done" finds the
/// camera free (a settings change right after a capture once got 409).
async fn run_capture(w: &CaptureWorker, id: i64, cancel: &AtomicBool) -> Result<Taken, JobError> {
    let store_err = |e: crate::store::StoreError| JobError::Store(w.jobs.store.describe(&e));
    let c = w.jobs.store.capture(id).map_err(store_err)?;
    w.jobs
        .events
        .job(format!("capture-{id}"), JobState::Running, None);
    // The settings recorded when it was accepted.
    let acquisition = Acquisition::try_from(&c).map_err(|e| JobError::Capture {
        id,
        reason: e.to_string(),
    })?;
    move_camera(w, &c).await?;
    turn_polarizer(w, &c).await?;
    super::wait_for_camera(&w.camera).await;
    let camera_id = w.camera.status().info.map(|i| i.id).unwrap_or_default();
    let meta = super::meta_of(&c, acquisition, &camera_id);
    let dir = w.jobs.store.capture_dir(id);
    std::fs::create_dir_all(&dir)
        .map_err(|e| JobError::Store(w.jobs.store.describe_io(&dir, &e)))?;
    w.rig.show_block(&c.pose, c.sheet_deg());
    let stream = Stream {
        w,
        id,
        settings: &acquisition,
        meta: &meta,
        total: (c.frames + c.dark_frames) as usize,
        cancel,
    };
    let spec = w.queue.take_progressive(id);
    let (dark, dark_counts) = dark_reference(w, &c, &stream).await?;
    let scene_off = meta.kind == CaptureKind::Dark && w.rig.switches_scene();
    if scene_off {
        scene_light(w, id, false).await?;
    }
    let aid = match meta.kind {
        CaptureKind::Target => Some(w.rig.showing(Aid::Target)),
        CaptureKind::Source => Some(w.rig.showing(Aid::Source)),
        _ => None,
    };
    let (n, offset) = (c.frames as usize, c.dark_frames as usize);
    let (dark, dark_variance) = dark.map_or((None, None), |(m, v)| (Some(m), v));
    let progressive = spec.map(|s| {
        progressive::start(
            &w.jobs,
            c.clone(),
            &s,
            (dark.clone(), dark_variance.clone()),
        )
    });
    let snapshots = progressive.as_ref().map(|(tx, _)| tx.clone());
    let frames = stream
        .take(CaptureFiles::FRAMES, "frames", n, offset, snapshots)
        .await
        .and_then(|(f, light)| {
            let counts = dark_counts + light;
            lost(w, id, counts).map(|()| (f, counts))
        });
    let relit = if scene_off {
        scene_light(w, id, true).await
    } else {
        Ok(())
    };
    drop(aid);
    if let Some((tx, steps)) = progressive {
        finish_progressive(w, id, frames.as_ref().ok().map(|(f, _)| f), tx, steps).await;
    }
    // Frames taken while the scene may not have come back on are kept only
    // when it did.
    let (frames, counts) = match frames.and_then(|f| relit.map(|()| f)) {
        Ok(f) => f,
        Err(e) => {
            // Cancelled or failed: its dark frames are of no use either.
            crate::store::remove_raw(&dir);
            return Err(e);
        }
    };
    let clipping = frames.clipping;
    if let Err(e) = saturated(w, id, &c, clipping) {
        crate::store::remove_raw(&dir);
        return Err(e);
    }
    let store = w.jobs.store.clone();
    tokio::task::spawn_blocking(move || {
        write_summary(&dir, &frames, dark.as_ref(), dark_variance.as_ref(), &meta)
            .map_err(|e| JobError::Store(store.describe(&e)))
    })
    .await??;
    tracing::info!(
        "{} frames received, {} dropped, {} broken",
        counts.received,
        counts.dropped,
        counts.broken
    );
    let counters = serde_json::to_string(&w.camera.status().counters).unwrap_or_default();
    Ok(Taken {
        camera_id,
        counters,
        counts,
        clipping,
    })
}

/// Applies the saturation policy to a capture's frames: beyond the
/// configured share of a frame at full scale, a warning in the log (the
/// record keeps the counts) or the capture's failure; those pixels' means
/// are biased low.
fn saturated(
    w: &CaptureWorker,
    id: i64,
    c: &CaptureRecord,
    clipping: crate::measure::Clipping,
) -> Result<(), JobError> {
    let (policy, share) = w.saturated;
    if clipping.saturated == 0 || clipping.saturated_share() <= share {
        return Ok(());
    }
    let what = format!("saturated: {}", clipping.saturation(&c.scene));
    match policy {
        Saturated::Warn => {
            tracing::warn!(capture = id, "capture-{id} {what}");
            Ok(())
        }
        Saturated::Fail => Err(JobError::Capture {
            id,
            reason: format!("{what}, or set [camera] saturated = \"warn\" to keep such captures"),
        }),
    }
}

/// Applies the lost-frames policy to a capture's counts: a warning in the
/// log (the record keeps the counts), or the capture's failure.
fn lost(w: &CaptureWorker, id: i64, c: FrameCounts) -> Result<(), JobError> {
    let Some(what) = c.losses() else {
        return Ok(());
    };
    match w.lost_frames {
        LostFrames::Warn => {
            tracing::warn!(capture = id, "capture-{id} {what}; kept the whole ones ([camera] lost_frames = \"warn\")");
            Ok(())
        }
        LostFrames::Fail => Err(JobError::Capture {
            id,
            reason: format!("{what}; check the camera's link and packet size, or set [camera] lost_frames = \"warn\" to keep such captures"),
        }),
    }
}

/// Gives the progressive solver the final mean (so the last step is always
/// solved) and waits for it; a capture that did not finish keeps none of its
/// progressive files.
async fn finish_progressive(
    w: &CaptureWorker,
    id: i64,
    frames: Option<&FrameStack>,
    tx: progressive::Snapshots,
    steps: tokio::task::JoinHandle<Vec<Step>>,
) {
    if let Some(st) = frames {
        let _ = tokio::task::spawn_blocking(tx.send_last(st)).await;
    } else {
        drop(tx);
    }
    let steps = steps.await.unwrap_or_default();
    tracing::info!("capture-{id}: {} progressive steps", steps.len());
    if frames.is_none() {
        progressive::remove_files(&w.jobs.store, id);
    }
}

/// The dark level to subtract, with the variance of that mean when known:
/// the mean of dark frames taken now with the scene switched off (only on a
/// bench that can, checked at acceptance), or a dark capture's mean frame,
/// or none; and what taking dark frames now received and lost.
async fn dark_reference(
    w: &CaptureWorker,
    c: &CaptureRecord,
    stream: &Stream<'_>,
) -> Result<(Option<(Frame, Option<Frame>)>, FrameCounts), JobError> {
    if c.dark_frames > 0 {
        scene_light(w, c.id, false).await?;
        let n = c.dark_frames as usize;
        let r = stream.take(CaptureFiles::DARK, "dark", n, 0, None).await;
        scene_light(w, c.id, true).await?;
        let (st, counts) = r.map_err(|e| match e {
            JobError::Cancelled => JobError::Cancelled,
            e => JobError::Capture {
                id: c.id,
                reason: format!("dark frames: {e}"),
            },
        })?;
        let mean = Frame {
            width: st.width,
            height: st.height,
            pixels: st.mean.iter().map(|&v| v as f32).collect(),
        };
        return Ok((Some((mean, st.variance_frame())), counts));
    }
    let dark = match c.dark_capture {
        Some(dc) => Some(super::dark_capture(&w.jobs.store, dc)?),
        None => None,
    };
    Ok((dark, FrameCounts::default()))
}

/// The longest an acquisition of `n` frames of `exposure_us` may take before
/// its capture fails as stalled: twice its frames' time plus `slack`
/// (`[camera] stall_slack_s`, a minute by default: beyond the camera
/// thread's own timeouts, and a machine under load).
fn stall_limit(exposure_us: f64, n: usize, slack: std::time::Duration) -> std::time::Duration {
    let frames = 2.0 * n as f64 * (exposure_us * 1e-6).max(1e-3);
    std::time::Duration::from_secs_f64(frames) + slack
}

/// Switches the hidden scene's light for capture `id` through the rig.
async fn scene_light(w: &CaptureWorker, id: i64, on: bool) -> Result<(), JobError> {
    w.rig.scene_light(on).await.map_err(|e| rig_failed(id, e))
}

/// A capture failed by the rig, in its words.
fn rig_failed(id: i64, e: RigError) -> JobError {
    JobError::Capture {
        id,
        reason: e.to_string(),
    }
}

/// Moves the camera to the capture's pose ([`super::move_to_pose`]).
async fn move_camera(w: &CaptureWorker, c: &CaptureRecord) -> Result<(), JobError> {
    super::move_to_pose(&w.rig, &w.jobs.scenes, &c.scene, &c.pose)
        .await
        .map_err(|e| JobError::Capture {
            id: c.id,
            reason: e.to_string(),
        })
}

/// Turns the mount to the capture's polarizer angle and records the angle
/// read back; a capture without an angle, or a bench without a mount
/// (whose angle is set by hand and trusted), records none.
async fn turn_polarizer(w: &CaptureWorker, c: &CaptureRecord) -> Result<(), JobError> {
    let Some(deg) = c.sheet_deg() else {
        return Ok(());
    };
    let Some(measured) = w.rig.turn_to(deg).await.map_err(|e| rig_failed(c.id, e))? else {
        return Ok(());
    };
    tracing::info!(
        "polarizer at {measured:.3}° from crossed (asked {deg}°), read back from the mount"
    );
    w.jobs
        .store
        .capture_polarizer_measured(c.id, measured)
        .map_err(|e| JobError::Store(w.jobs.store.describe(&e)))
}

/// One acquisition of a capture, streamed to one file.
struct Stream<'a> {
    w: &'a CaptureWorker,
    id: i64,
    settings: &'a Acquisition,
    meta: &'a FrameMeta,
    total: usize,
    /// Set by `DELETE /jobs/capture-<id>`: the writer stops at the next frame.
    cancel: &'a AtomicBool,
}

impl Stream<'_> {
    /// Acquires `n` frames into the capture's file `name`, while a blocking
    /// writer puts each on disk and adds it to the running mean; progress
    /// counts from `offset`. Returns the frames' running sums and what the
    /// camera received and lost.
    async fn take(
        &self,
        name: &str,
        kind: &'static str,
        n: usize,
        offset: usize,
        snapshots: Option<progressive::Snapshots>,
    ) -> Result<(FrameStack, FrameCounts), JobError> {
        let (id, total, w) = (self.id, self.total, self.w);
        if self.cancel.load(Ordering::SeqCst) {
            return Err(JobError::Cancelled);
        }
        let (frame_tx, frame_rx) = std::sync::mpsc::sync_channel::<RawFrame>(FRAME_QUEUE);
        let (progress_tx, mut progress_rx) = mpsc::unbounded_channel::<usize>();
        let path = w.jobs.store.capture_dir(id).join(name);
        let meta = self.meta.clone();
        let store = w.jobs.store.clone();
        let cancel = w.jobs.registry.cancel_flag(&format!("capture-{id}"));
        let stalled = Arc::new(AtomicBool::new(false));
        let stop = stalled.clone();
        let live = w.camera.clone();
        let writer = tokio::task::spawn_blocking(move || {
            let mut shown = None;
            // A cancelled capture ends its stream at the next frame: the file
            // is incomplete, so it is removed, and the camera stops when its
            // next frame finds the channel closed.
            let frames = frame_rx
                .into_iter()
                .take_while(|_| !cancel.load(Ordering::SeqCst) && !stop.load(Ordering::SeqCst))
                .inspect(|f| {
                    // The live view polls once a second: copy a frame for it
                    // at most every LIVE_EVERY, not every frame.
                    if shown.is_none_or(|t: Instant| t.elapsed() >= LIVE_EVERY) {
                        shown = Some(Instant::now());
                        live.show(Arc::new(f.clone()));
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
        let (events, catalogue) = (w.jobs.events.clone(), w.jobs.store.clone());
        let progress = tokio::spawn(async move {
            while let Some(taken) = progress_rx.recv().await {
                events.emit(Event::Frame {
                    job: format!("capture-{id}"),
                    taken,
                    total,
                });
                let store = catalogue.clone();
                let _ =
                    tokio::task::spawn_blocking(move || store.capture_progress(id, taken)).await;
            }
        });
        let acquire = w.camera.handle().acquire(*self.settings, n, frame_tx);
        // The camera thread bounds every wait on the camera; this bounds the
        // whole acquisition too, so that a capture can never hold the queue.
        let limit = stall_limit(self.settings.exposure_us, n, w.stall_slack);
        let acquired = match tokio::time::timeout(limit, acquire).await {
            Ok(r) => r,
            Err(_) => {
                // The writer stops at its next frame; it is not waited for.
                stalled.store(true, Ordering::SeqCst);
                let taken = w
                    .jobs
                    .store
                    .capture(id)
                    .map(|c| c.frames_taken)
                    .unwrap_or(0);
                return Err(JobError::Capture {
                    id,
                    reason: format!(
                        "the camera stalled: {taken} of {total} frames after {:.0} s, for {n} {kind} frames of {} us; the capture failed (its acquisition stops at its next frame), and the queue goes on",
                        limit.as_secs_f64(),
                        self.settings.exposure_us
                    ),
                });
            }
        };
        let written = writer.await.map_err(JobError::from).and_then(|r| r);
        let _ = progress.await;
        if self.cancel.load(Ordering::SeqCst) && written.is_err() {
            return Err(JobError::Cancelled);
        }
        match (acquired, written) {
            (Ok(counts), Ok(stack)) => Ok((stack, counts)),
            // The writer stopped first (a full disk): its reason is the one that matters.
            (Err(CameraError::Stopped(_)), Err(w)) | (Ok(_), Err(w)) => Err(w),
            (Err(e), _) => Err(e.into()),
        }
    }
}
