//! Live reconstruction: the capture worker streams the camera between
//! captures and solves the newest window of frames after every frame it can,
//! with the scene's cached `T`, Gram and conditioning and the progressive
//! solver ([`super::progressive`]): λ from the window's noise, or a fixed λ
//! warm-started from the previous result. Each result is published on
//! `/events` (`live`) and as `GET /live/image.png`.
//!
//! The camera comes first to captures: a queued capture ends the live
//! segment at the next frame, runs, and live view resumes after it (state
//! `paused` meanwhile). Frames that arrive while a solve runs only join the
//! window, so live view never falls behind the camera, and its memory is the
//! window's frames and a few images however long it runs.
//!
//! In difference mode ([`super::progressive`]'s `Background`) each image is
//! the scene's change against a running background, and the tracker
//! ([`super::track`]) places the moving object in it; each result's window
//! time and centroid go on `/events`, in `GET /live` and in the track
//! (`GET /live/track.csv`).

use std::collections::VecDeque;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc::{Receiver, RecvTimeoutError, SyncSender};
use std::sync::Arc;
use std::time::{Duration, Instant};

use super::progressive::{Progressive, Snapshot};
use super::{JobContext, JobError};
use crate::camera::{Acquisition, RawFrame};
use crate::daemon::requests::validate::ProgressiveSpec;
use crate::daemon::runtime::camera::{CameraLease, CameraService};
use crate::daemon::runtime::live::{Live, LiveState};
use crate::daemon::runtime::queue::CaptureQueue;
use crate::daemon::Event;
use crate::measure::window::Window;
use crate::measure::FrameStack;
use crate::rig::Rig;
use crate::scene::Frame;
use crate::store::{CaptureRecord, CaptureRequest, JobState};

/// Frames one acquisition of a live segment asks for; a segment that reaches
/// it starts another.
const SEGMENT_FRAMES: usize = 1 << 20;

/// How often the frame reader looks at its stop flag while no frame comes.
const POLL: Duration = Duration::from_millis(50);

/// What a live segment uses of the capture worker's: the job services, the
/// camera, the bench's devices and the capture queue it gives way to.
pub(in crate::daemon) struct LiveRun<'a> {
    pub(in crate::daemon) jobs: &'a JobContext,
    pub(in crate::daemon) camera: &'a Arc<CameraService>,
    pub(in crate::daemon) rig: &'a Arc<Rig>,
    pub(in crate::daemon) queue: &'a Arc<CaptureQueue>,
}

/// Runs the wanted live session until a capture is queued, another user
/// (a mount sweep) asks for the camera, the session changes or the daemon
/// stops; returns at once when none is wanted.
pub(in crate::daemon) async fn segment(w: &LiveRun<'_>, live: &Arc<Live>) {
    let Some((session, request, spec)) = live.wanted() else {
        return;
    };
    let lease = w.camera.lease("live").await;
    if let Err(e) = run(w, live, session, &request, &spec, lease).await {
        tracing::warn!("live view stopped: {e}");
        live.fail(session, e.to_string());
        let why = format!("live view failed ({e})");
        if let Some(id) = live.fail_waiting(session, &why) {
            let (store, events) = (&w.jobs.store, &w.jobs.events);
            super::record::unrecorded(store, w.queue, events, id, &why);
        }
    }
}

/// One live segment under the camera's `lease`, which it gives back as soon
/// as the stream ends: the recording's writer and the solver's step in hand
/// finish without the camera.
async fn run(
    w: &LiveRun<'_>,
    live: &Arc<Live>,
    session: u64,
    request: &CaptureRequest,
    spec: &ProgressiveSpec,
    lease: CameraLease<'_>,
) -> Result<(), JobError> {
    live.set_state(session, LiveState::Starting, None);
    let c = request.unstored(JobState::Running);
    super::move_to_pose(w.rig, &w.jobs.scenes, &c.scene, &c.pose)
        .await
        .map_err(|e| JobError::Live(e.to_string()))?;
    if let Some(deg) = c.sheet_deg() {
        w.rig
            .turn_to(deg)
            .await
            .map_err(|e| JobError::Live(e.to_string()))?;
    }
    super::wait_for_camera(w.camera).await;
    w.rig.show_block(&c.pose, c.sheet_deg());
    let settings = Acquisition::try_from(&c).map_err(|e| JobError::Live(e.to_string()))?;
    let (dark_frames, dark) = dark(w, &c, settings).await?;
    let solver = {
        let (d, c, spec, dark) = (w.jobs.clone(), c.clone(), spec.clone(), dark.clone());
        tokio::task::spawn_blocking(move || Progressive::new(&d, c, &spec, dark)).await??
    };
    live.set_radiometry(session, solver.radiometry().clone());
    // A watcher sets the stop flag when a capture is queued, the session
    // changes or the daemon stops.
    // Set when the segment must end; the frame reader checks it at every frame.
    let stop = Arc::new(AtomicBool::new(false));
    let watcher = {
        let (stop, live, queue) = (stop.clone(), live.clone(), w.queue.clone());
        let camera = w.camera.clone();
        let mut changed = live.subscribe();
        let mut stopped = w.jobs.registry.stopped();
        tokio::spawn(async move {
            loop {
                if queue.depth() > 0
                    || camera.waiting() > 0
                    || !live.is_current(session)
                    || *stopped.borrow()
                {
                    stop.store(true, Ordering::SeqCst);
                    return;
                }
                tokio::select! {
                    _ = changed.changed() => {}
                    _ = stopped.changed() => {}
                    _ = tokio::time::sleep(POLL) => {}
                }
            }
        })
    };
    // The recording, if one waits: its first frame is the stream's first.
    let services = super::record::Services {
        jobs: w.jobs,
        camera: w.camera,
        queue: w.queue,
    };
    let dark_both = (&dark_frames[..], &dark);
    let recording = super::record::begin(services, live, session, settings, dark_both).await;
    let (tap, recorder) = recording.map_or((None, None), |(t, r)| (Some(t), Some(r)));
    live.set_state(session, LiveState::Running, None);
    let (snap_tx, snap_rx) = std::sync::mpsc::sync_channel::<(Snapshot, Instant)>(1);
    let busy = Arc::new(AtomicBool::new(false));
    let solving = {
        let (live, busy, events) = (live.clone(), busy.clone(), w.jobs.events.clone());
        let differences = spec.difference.is_some();
        let stop = stop.clone();
        tokio::task::spawn_blocking(move || {
            let ends = Ends {
                busy: &busy,
                stop: &stop,
            };
            solve(solver, differences, snap_rx, ends, &live, session, &events)
        })
    };
    let streams = Streams {
        stop: stop.clone(),
        busy,
        snap_tx,
    };
    let (ended, tap) = stream(w, live, session, request, settings, &streams, tap).await;
    stop.store(true, Ordering::SeqCst);
    watcher.abort();
    // Why the segment ended is read while it still holds the camera: once
    // given back, the sweep that waited for it no longer waits.
    let why = recorder
        .is_some()
        .then(|| why_ended(w, live, session, &ended));
    if ended.is_ok() && live.is_current(session) && w.camera.waiting() > 0 {
        live.set_state(session, LiveState::Paused, Some("a mount sweep".into()));
    }
    // Given back now, not after the solver's step in hand: a mount sweep
    // waits at most 5 s for the camera, and a window's solve (a fitted
    // first window's λ search, the area-shadow `T` it may build) can take
    // longer.
    drop(lease);
    if let (Some(recorder), Some(why)) = (recorder, why) {
        recorder.finish(tap, why).await;
    }
    drop(streams);
    let _ = solving.await;
    ended
}

/// What the frame reader shares with the segment: its stop flag, the
/// solver's busy flag and the solver's channel.
struct Streams {
    stop: Arc<AtomicBool>,
    busy: Arc<AtomicBool>,
    snap_tx: SyncSender<(Snapshot, Instant)>,
}

/// Streams the camera into the window (and the recording's `tap`) until
/// the stop flag is set or the camera or the window fails; returns how it
/// ended and the tap, if the recording still wants frames.
async fn stream(
    w: &LiveRun<'_>,
    live: &Arc<Live>,
    session: u64,
    request: &CaptureRequest,
    settings: Acquisition,
    s: &Streams,
    mut tap: Option<super::record::Tap>,
) -> (Result<(), JobError>, Option<super::record::Tap>) {
    while !s.stop.load(Ordering::SeqCst) {
        let (frame_tx, frame_rx) = std::sync::mpsc::sync_channel::<RawFrame>(4);
        let reader = {
            let (stop, live, busy, snap_tx) = (
                s.stop.clone(),
                live.clone(),
                s.busy.clone(),
                s.snap_tx.clone(),
            );
            let (window, mut tap) = (request.frames, tap.take());
            tokio::task::spawn_blocking(move || {
                let r = read(
                    frame_rx,
                    window,
                    &stop,
                    (&live, session),
                    &busy,
                    &snap_tx,
                    &mut tap,
                );
                (r, tap)
            })
        };
        let acquired = w
            .camera
            .handle()
            .acquire(settings, SEGMENT_FRAMES, frame_tx)
            .await;
        let read = match reader.await {
            Ok((r, back)) => {
                tap = back;
                r
            }
            Err(e) => Err(e.into()),
        };
        match (acquired, read) {
            (_, Err(e)) => return (Err(e), tap),
            (Err(_), Ok(())) if s.stop.load(Ordering::SeqCst) => break,
            (Err(e), Ok(())) => return (Err(e.into()), tap),
            (Ok(_), Ok(())) => {}
        }
    }
    (Ok(()), tap)
}

/// Why a live segment ended, in the words a recording it cut short keeps.
fn why_ended(w: &LiveRun<'_>, live: &Live, session: u64, ended: &Result<(), JobError>) -> String {
    if let Err(e) = ended {
        return format!("live view failed ({e})");
    }
    let view = live.view();
    let why = if w.jobs.registry.is_stopping() {
        "the daemon stopped"
    } else if view.session == session && view.state == LiveState::Failed {
        return format!("live view failed ({})", view.error.unwrap_or_default());
    } else if !live.is_current(session) {
        "live view was stopped or replaced"
    } else if w.queue.depth() > 0 {
        "a queued capture paused live view"
    } else if w.camera.waiting() > 0 {
        "a mount sweep took the camera"
    } else {
        "the live stream ended"
    };
    why.to_string()
}

/// The dark frames taken now with the scene switched off (none with a dark
/// capture or none asked), and the dark mean (and its variance) the
/// session subtracts: theirs, or a dark capture's, or none.
async fn dark(
    w: &LiveRun<'_>,
    c: &CaptureRecord,
    settings: Acquisition,
) -> Result<DarkFrames, JobError> {
    if c.dark_frames > 0 {
        let n = usize::try_from(c.dark_frames).unwrap_or(1);
        w.rig
            .scene_light(false)
            .await
            .map_err(|e| JobError::Live(e.to_string()))?;
        let frames = w.camera.handle().collect(settings, n).await;
        w.rig
            .scene_light(true)
            .await
            .map_err(|e| JobError::Live(e.to_string()))?;
        let frames = frames?;
        let first = frames
            .first()
            .ok_or_else(|| JobError::Live("no dark frame arrived".into()))?;
        let mut st = FrameStack::new(first.width, first.height);
        for f in frames
            .iter()
            .filter(|f| (f.width, f.height) == (first.width, first.height))
        {
            st.push_raw(&f.pixels, f.bits);
        }
        let mean = st.mean_minus(None)?;
        let variance = st.variance_frame();
        return Ok((frames, (Some(mean), variance)));
    }
    match c.dark_capture {
        Some(dc) => {
            let (mean, variance) = super::dark_capture(&w.jobs.store, dc)?;
            Ok((Vec::new(), (Some(mean), variance)))
        }
        None => Ok((Vec::new(), (None, None))),
    }
}

/// Dark frames taken, and the dark mean and its variance.
type DarkFrames = (Vec<RawFrame>, (Option<Frame>, Option<Frame>));

/// Adds each frame to the window (and gives it to the recording's `tap`)
/// and hands the newest window to the solver whenever it is free; ends
/// when the stop flag is set (dropping the receiver, which stops the
/// camera) or the acquisition ends.
fn read(
    frames: Receiver<RawFrame>,
    n: usize,
    stop: &AtomicBool,
    (live, session): (&Live, u64),
    busy: &AtomicBool,
    solver: &SyncSender<(Snapshot, Instant)>,
    tap: &mut Option<super::record::Tap>,
) -> Result<(), JobError> {
    let mut window: Option<Window> = None;
    // The window's frames' arrival times, Unix seconds.
    let mut times: VecDeque<f64> = VecDeque::with_capacity(n);
    while !stop.load(Ordering::SeqCst) {
        let f = match frames.recv_timeout(POLL) {
            Ok(f) => f,
            Err(RecvTimeoutError::Timeout) => continue,
            Err(RecvTimeoutError::Disconnected) => break,
        };
        let arrived = Instant::now();
        if let Some(tap) = tap.as_mut() {
            tap.offer(&f);
        }
        let win = match window.as_mut() {
            Some(w) if w.size() == (f.width, f.height) => w,
            _ => {
                times.clear();
                window.insert(
                    Window::new(n, f.width, f.height).map_err(|e| JobError::Live(e.to_string()))?,
                )
            }
        };
        if times.len() == n {
            times.pop_front();
        }
        times.push_back(unix_seconds(f.system_timestamp_ns));
        win.push(f.width, f.height, &f.pixels)
            .map_err(|e| JobError::Live(e.to_string()))?;
        // Solve once the window is full, whenever the solver is free.
        let solved = win.count() == n && !busy.swap(true, Ordering::SeqCst);
        if solved {
            let snapshot = Snapshot::from_parts(
                win.count(),
                win.mean(),
                win.variance_of_mean(),
                f.width,
                f.height,
            )
            .at(times.iter().sum::<f64>() / times.len().max(1) as f64);
            if solver.send((snapshot, arrived)).is_err() {
                break;
            }
        }
        live.frame(session, solved);
    }
    Ok(())
}

/// A frame's arrival time in Unix seconds (now, for a frame that has none).
fn unix_seconds(ns: u64) -> f64 {
    match ns {
        0 => std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map_or(0.0, |d| d.as_secs_f64()),
        ns => ns as f64 * 1e-9,
    }
}

/// The solver thread's two flags: `busy` while it solves a window, and the
/// segment's `stop`, which ends the window in hand within
/// [`crate::stop::Stop::EVERY`] iterations.
struct Ends<'a> {
    busy: &'a AtomicBool,
    stop: &'a AtomicBool,
}

/// Solves each window it is handed and publishes the result, with the
/// moving object's centroid in difference mode. A window the segment's
/// stop cut short is dropped without a result: the segment is ending (a
/// capture queued, the session changed, the daemon stopping), and neither
/// waits for it.
fn solve(
    mut solver: Progressive,
    differences: bool,
    snapshots: Receiver<(Snapshot, Instant)>,
    ends: Ends<'_>,
    live: &Live,
    session: u64,
    events: &crate::daemon::runtime::events::Events,
) {
    let (grid, colours) = (solver.grid(), solver.colours());
    let tracking = differences.then(|| solver.scene_plane().clone());
    for (snapshot, arrived) in snapshots {
        let result = solver.step(&snapshot, crate::stop::Stop::on(ends.stop));
        solver.forget_steps();
        match result {
            Ok((step, image)) => {
                let track = tracking.as_ref().map(|plane| {
                    let time = snapshot.time_s().unwrap_or(f64::NAN);
                    (
                        time,
                        crate::solve::track::centroid(&image, colours, plane, solver.moved()),
                    )
                });
                let latency = arrived.elapsed().as_secs_f64();
                live.result(
                    session,
                    step.clone(),
                    (grid.nu, grid.nv, image),
                    latency,
                    track,
                );
                events.emit(Event::Live {
                    session,
                    latency_ms: latency * 1e3,
                    time_s: track.map(|(t, _)| t),
                    centroid: track.and_then(|(_, c)| c),
                    step,
                });
            }
            Err(_) if ends.stop.load(Ordering::SeqCst) => {
                tracing::debug!("live view: the window in hand was dropped as the segment ended");
            }
            Err(e) => {
                tracing::warn!("live view: a window was not solved: {e}");
                live.fail(session, format!("a window was not solved: {e}"));
            }
        }
        ends.busy.store(false, Ordering::SeqCst);
    }
}
