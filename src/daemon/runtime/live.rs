//! The live view's state: the capture request it repeats, whether it runs,
//! waits for a capture or failed, and what it has given so far
//! (`GET /live`), with the newest image.
//!
//! Why a handle of its own: the API starts and stops it, the capture worker
//! runs it between captures, and its solver thread records each result;
//! none of them owns the others.

use std::collections::VecDeque;
use std::sync::Mutex;
use std::time::Instant;

use serde::Serialize;

use crate::daemon::requests::validate::ProgressiveSpec;
use crate::daemon::runtime::events::{Centroid, Step};
use crate::solve::radiometry::RadiometryChoice;
use crate::store::CaptureRequest;

/// Results whose latency and timing the statistics keep.
const KEPT: usize = 256;

/// Rows the track keeps (the newest): 10,000 results, under four minutes at
/// 44 results a second, 400 kB.
const TRACK_KEPT: usize = 10_000;

/// One result's row of the track: the window's time (the mean arrival time
/// of its frames, Unix seconds) and the centroid, if anything moved.
pub(crate) type TrackRow = (f64, Option<Centroid>);

/// Where the live view is.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, utoipa::ToSchema)]
#[serde(rename_all = "lowercase")]
pub enum LiveState {
    /// Not started, or stopped by `DELETE /live`.
    Off,
    /// Waiting for the camera, moving the bench or taking its dark frames.
    Starting,
    /// Streaming and solving.
    Running,
    /// A queued capture has the camera; live view resumes after it.
    Paused,
    /// The camera or the solver failed (`error` says how); `POST /live` again to retry.
    Failed,
}

/// Where a live session's recording is.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, utoipa::ToSchema)]
#[serde(rename_all = "lowercase")]
pub enum RecordingState {
    /// Waiting for the session's first frame (after its dark frames).
    Waiting,
    /// Writing each frame as it arrives.
    Recording,
    /// All its frames are written; the capture is done.
    Done,
    /// The session ended first: the capture is done with the frames it got.
    Ended,
    /// Nothing usable was written (`reason` says why); the capture failed.
    Failed,
    /// Cancelled (`DELETE /jobs/capture-<id>`); the capture keeps no frame.
    Cancelled,
}

/// A live session's recording as `GET /live` shows it.
#[derive(Debug, Clone, Serialize, utoipa::ToSchema)]
pub struct RecordingView {
    /// The capture it writes (`GET /captures/{id}`).
    pub capture: i64,
    /// Frames written so far.
    pub frames: usize,
    /// Frames asked for (`record.frames`).
    pub of: usize,
    /// Where it is.
    pub state: RecordingState,
    /// Why it ended early, failed or was cancelled.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub reason: Option<String>,
}

/// What `GET /live` answers.
#[derive(Debug, Clone, Serialize, utoipa::ToSchema)]
pub struct LiveView {
    /// Where it is.
    pub state: LiveState,
    /// The session's number (each `POST /live` starts a new one).
    pub session: u64,
    /// Scene, pose and the blocks it measures (null when off).
    pub scene: Option<String>,
    /// Pose name.
    pub pose: Option<String>,
    /// Frames per window (the capture request's `frames`).
    pub window: Option<usize>,
    /// Exposure per frame, microseconds.
    pub exposure_us: Option<f64>,
    /// The capture that paused it, while paused (`capture-<id>`).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub paused_by: Option<String>,
    /// Why it failed.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub error: Option<String>,
    /// Frames received in this session.
    pub frames: u64,
    /// Results published in this session.
    pub results: u64,
    /// Frames that arrived while the solver was busy and were only added to
    /// the window (each result solves the newest window).
    pub frames_not_solved: u64,
    /// Results per second over the last results kept (up to 256).
    pub results_per_second: Option<f64>,
    /// Median time from a frame's arrival to its result's publication, ms.
    pub median_latency_ms: Option<f64>,
    /// The newest result's numbers.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub last: Option<Step>,
    /// Difference mode's background time constant, seconds (absent: each
    /// window is solved as it is).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub difference_background_s: Option<f64>,
    /// Difference mode: the newest result's window time, Unix seconds.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub last_time_s: Option<f64>,
    /// Difference mode: the moving object's centroid in the newest result
    /// (absent when nothing stood out of its noise).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub centroid: Option<Centroid>,
    /// The recording asked for with `record`: its capture, frames written,
    /// of how many, and its state.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub recording: Option<RecordingView>,
    /// How each window is put into the model's units (`calibrated` or
    /// `fitted`, with each result's gain and background in `last.fitted`),
    /// and why; known once the session's solver is set up.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub radiometry: Option<RadiometryChoice>,
}

/// A started session: what it repeats and what it gave.
pub(crate) struct Session {
    pub(crate) id: u64,
    pub(crate) request: CaptureRequest,
    pub(crate) spec: ProgressiveSpec,
    state: LiveState,
    paused_by: Option<String>,
    error: Option<String>,
    frames: u64,
    results: u64,
    not_solved: u64,
    /// Arrival-to-result latencies, seconds, and when each result came.
    latencies: VecDeque<f64>,
    times: VecDeque<Instant>,
    last: Option<Step>,
    /// The newest result's track row (difference mode).
    last_track: Option<TrackRow>,
    /// Newest image: columns, rows, values.
    image: Option<(usize, usize, Vec<f64>)>,
    /// The recording asked for, if any.
    recording: Option<RecordingView>,
    /// Its solver's radiometry, once set up.
    radiometry: Option<RadiometryChoice>,
}

impl Session {
    /// The capture of its recording while no frame went to it.
    fn waiting(&self) -> Option<i64> {
        self.recording
            .as_ref()
            .filter(|r| r.state == RecordingState::Waiting)
            .map(|r| r.capture)
    }
}

/// The live view: at most one session.
pub struct Live {
    session: Mutex<Option<Session>>,
    /// The newest session's track (difference mode), kept after it stops
    /// until the next starts; locked after `session` when both are.
    track: Mutex<VecDeque<TrackRow>>,
    next: Mutex<u64>,
    /// Bumped on every start and stop, so the capture worker wakes.
    changed: tokio::sync::watch::Sender<u64>,
}

impl Default for Live {
    fn default() -> Self {
        Self {
            session: Mutex::new(None),
            track: Mutex::new(VecDeque::new()),
            next: Mutex::new(0),
            changed: tokio::sync::watch::channel(0).0,
        }
    }
}

/// The median of `v` (None when empty).
fn median(v: &VecDeque<f64>) -> Option<f64> {
    let mut s: Vec<f64> = v.iter().copied().collect();
    s.sort_by(f64::total_cmp);
    let n = s.len();
    match n {
        0 => None,
        _ if n % 2 == 1 => Some(s[n / 2]),
        _ => Some(0.5 * (s[n / 2 - 1] + s[n / 2])),
    }
}

impl Live {
    fn lock(&self) -> std::sync::MutexGuard<'_, Option<Session>> {
        self.session.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// A new session's number, for [`Live::start`] (and the recording's
    /// capture, which names it, before the session starts).
    pub(crate) fn issue_id(&self) -> u64 {
        let mut next = self.next.lock().unwrap_or_else(|e| e.into_inner());
        *next += 1;
        *next
    }

    /// Starts session `id` repeating `request`, recording its first frames
    /// to `recording` (a capture and its frame count) when given; a replaced
    /// session ends. Returns the view and the capture of the replaced
    /// session's recording if no frame went to it yet (the caller ends it).
    pub(crate) fn start(
        &self,
        id: u64,
        request: CaptureRequest,
        spec: ProgressiveSpec,
        recording: Option<(i64, usize)>,
    ) -> (LiveView, Option<i64>) {
        let mut session = self.lock();
        let replaced = session.as_ref().and_then(Session::waiting);
        self.track.lock().unwrap_or_else(|e| e.into_inner()).clear();
        *session = Some(Session {
            id,
            request,
            spec,
            state: LiveState::Starting,
            paused_by: None,
            error: None,
            frames: 0,
            results: 0,
            not_solved: 0,
            latencies: VecDeque::with_capacity(KEPT),
            times: VecDeque::with_capacity(KEPT),
            last: None,
            last_track: None,
            image: None,
            recording: recording.map(|(capture, of)| RecordingView {
                capture,
                frames: 0,
                of,
                state: RecordingState::Waiting,
                reason: None,
            }),
            radiometry: None,
        });
        drop(session);
        self.changed.send_modify(|g| *g += 1);
        (self.view(), replaced)
    }

    /// Stops the session; its last view, as `off`, and the capture of its
    /// recording if no frame went to it yet (the caller ends it).
    pub(crate) fn stop(&self) -> (LiveView, Option<i64>) {
        let mut view = self.view();
        let waiting = self.lock().take().and_then(|s| s.waiting());
        self.changed.send_modify(|g| *g += 1);
        view.state = LiveState::Off;
        view.paused_by = None;
        (view, waiting)
    }

    /// Session `id`'s recording, when it waits for its first frame: now
    /// recording; its capture and frame count. Once only: a session resumed
    /// after a capture does not record again.
    pub(crate) fn claim_recording(&self, id: u64) -> Option<(i64, usize)> {
        let mut guard = self.lock();
        let r = guard
            .as_mut()
            .filter(|s| s.id == id && s.state != LiveState::Failed)?
            .recording
            .as_mut()
            .filter(|r| r.state == RecordingState::Waiting)?;
        r.state = RecordingState::Recording;
        Some((r.capture, r.of))
    }

    /// Session `id`'s recording's capture if no frame went to it yet, now
    /// failed for `reason` (the session failed before its first frame).
    pub(crate) fn fail_waiting(&self, id: u64, reason: &str) -> Option<i64> {
        let mut capture = None;
        self.with(id, |s| {
            capture = s.waiting();
            if let Some(r) = s.recording.as_mut().filter(|_| capture.is_some()) {
                r.state = RecordingState::Failed;
                r.reason = Some(reason.to_string());
            }
        });
        capture
    }

    /// Session `id`'s recording wrote `frames` frames so far.
    pub(crate) fn recorded(&self, id: u64, frames: usize) {
        self.with(id, |s| {
            s.recording.iter_mut().for_each(|r| r.frames = frames)
        });
    }

    /// Session `id`'s recording ended in `state`, for `reason` when not done.
    pub(crate) fn recording_ended(&self, id: u64, state: RecordingState, reason: Option<String>) {
        self.with(id, |s| {
            if let Some(r) = s.recording.as_mut() {
                (r.state, r.reason) = (state, reason);
            }
        });
    }

    /// A receiver that sees every start and stop.
    pub(crate) fn subscribe(&self) -> tokio::sync::watch::Receiver<u64> {
        self.changed.subscribe()
    }

    /// The session the camera should run now: its id, request and solver
    /// spec, unless it is off or failed.
    pub(crate) fn wanted(&self) -> Option<(u64, CaptureRequest, ProgressiveSpec)> {
        self.lock()
            .as_ref()
            .filter(|s| s.state != LiveState::Failed)
            .map(|s| (s.id, s.request.clone(), s.spec.clone()))
    }

    /// Whether session `id` is still the one wanted.
    pub(crate) fn is_current(&self, id: u64) -> bool {
        self.lock()
            .as_ref()
            .is_some_and(|s| s.id == id && s.state != LiveState::Failed)
    }

    /// Runs `f` on session `id` if it is the current one.
    fn with(&self, id: u64, f: impl FnOnce(&mut Session)) {
        if let Some(s) = self.lock().as_mut().filter(|s| s.id == id) {
            f(s);
        }
    }

    /// Session `id` moved to `state` (paused by `by`, when paused).
    pub(crate) fn set_state(&self, id: u64, state: LiveState, by: Option<String>) {
        self.with(id, |s| {
            s.state = state;
            s.paused_by = by;
        });
    }

    /// Session `id`'s solver puts its windows into the model's units with `radiometry`.
    pub(crate) fn set_radiometry(&self, id: u64, radiometry: RadiometryChoice) {
        self.with(id, |s| s.radiometry = Some(radiometry));
    }

    /// Session `id` failed for `reason`.
    pub(crate) fn fail(&self, id: u64, reason: String) {
        self.with(id, |s| {
            s.state = LiveState::Failed;
            s.error = Some(reason);
        });
    }

    /// Session `id` received a frame, solved (`solved`) or only added to the window.
    pub(crate) fn frame(&self, id: u64, solved: bool) {
        self.with(id, |s| {
            s.frames += 1;
            s.not_solved += u64::from(!solved);
        });
    }

    /// Session `id` published `step` and its image, `latency` seconds after
    /// its newest frame arrived, with its track row in difference mode.
    pub(crate) fn result(
        &self,
        id: u64,
        step: Step,
        image: (usize, usize, Vec<f64>),
        latency: f64,
        track: Option<TrackRow>,
    ) {
        self.with(id, |s| {
            if let Some(row) = track {
                let mut rows = self.track.lock().unwrap_or_else(|e| e.into_inner());
                if rows.len() == TRACK_KEPT {
                    rows.pop_front();
                }
                rows.push_back(row);
            }
            s.last_track = track;
            s.results += 1;
            if s.latencies.len() == KEPT {
                s.latencies.pop_front();
                s.times.pop_front();
            }
            s.latencies.push_back(latency);
            s.times.push_back(Instant::now());
            s.last = Some(step);
            s.image = Some(image);
        });
    }

    /// The track as CSV: a header, then one row per result of difference
    /// mode (the newest [`TRACK_KEPT`]): the window's time (Unix seconds),
    /// the centroid and its standard deviations (metres; empty when nothing
    /// moved).
    pub fn track_csv(&self) -> String {
        let rows = self.track.lock().unwrap_or_else(|e| e.into_inner());
        let mut out = String::from("time_s,u_m,v_m,sigma_u_m,sigma_v_m\n");
        for (t, c) in rows.iter() {
            let line = match c {
                Some(c) => format!(
                    "{t:.6},{:.6},{:.6},{:.6},{:.6}\n",
                    c.u_m, c.v_m, c.sigma_u_m, c.sigma_v_m
                ),
                None => format!("{t:.6},,,,\n"),
            };
            out.push_str(&line);
        }
        out
    }

    /// The newest image: columns, rows, values (None before the first result).
    pub fn image(&self) -> Option<(usize, usize, Vec<f64>)> {
        self.lock().as_ref().and_then(|s| s.image.clone())
    }

    /// What `GET /live` shows.
    pub fn view(&self) -> LiveView {
        let guard = self.lock();
        let Some(s) = guard.as_ref() else {
            return LiveView {
                state: LiveState::Off,
                session: *self.next.lock().unwrap_or_else(|e| e.into_inner()),
                scene: None,
                pose: None,
                window: None,
                exposure_us: None,
                paused_by: None,
                error: None,
                frames: 0,
                results: 0,
                frames_not_solved: 0,
                results_per_second: None,
                median_latency_ms: None,
                last: None,
                difference_background_s: None,
                last_time_s: None,
                centroid: None,
                recording: None,
                radiometry: None,
            };
        };
        let rate = match (s.times.front(), s.times.back()) {
            (Some(a), Some(b)) if s.times.len() >= 2 => {
                let span = b.duration_since(*a).as_secs_f64();
                (span > 0.0).then(|| (s.times.len() - 1) as f64 / span)
            }
            _ => None,
        };
        LiveView {
            state: s.state,
            session: s.id,
            scene: Some(s.request.scene.clone()),
            pose: Some(s.request.pose.clone()),
            window: Some(s.request.frames),
            exposure_us: Some(s.request.acquisition.exposure_us),
            paused_by: s.paused_by.clone(),
            error: s.error.clone(),
            frames: s.frames,
            results: s.results,
            frames_not_solved: s.not_solved,
            results_per_second: rate,
            median_latency_ms: median(&s.latencies).map(|v| v * 1e3),
            last: s.last.clone(),
            difference_background_s: s.spec.difference,
            last_time_s: s.last_track.map(|(t, _)| t),
            centroid: s.last_track.and_then(|(_, c)| c),
            recording: s.recording.clone(),
            radiometry: s.radiometry.clone(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A live session's spec: every window solved, difference mode or not.
    fn spec(difference: Option<f64>) -> ProgressiveSpec {
        ProgressiveSpec {
            every: 1,
            captures: Vec::new(),
            lambda: None,
            max_iter: 10,
            truth: None,
            difference,
            radiometry: None,
        }
    }

    #[test]
    fn the_track_has_a_row_per_result_and_outlives_its_session_until_the_next() {
        let live = Live::default();
        let spec = spec(Some(10.0));
        let id = live.issue_id();
        let id = live
            .start(id, CaptureRequest::example(), spec.clone(), None)
            .0
            .session;
        let step = Step {
            frames: 8,
            iterations: 1,
            converged: true,
            change: None,
            psnr_db: None,
            lambda: None,
            seconds: 0.0,
            fitted: None,
        };
        let c = Centroid {
            u_m: 0.01,
            v_m: -0.02,
            sigma_u_m: 0.007,
            sigma_v_m: 0.008,
        };
        let image = (1, 1, vec![0.0]);
        live.result(id, step.clone(), image.clone(), 0.01, Some((1.5, Some(c))));
        live.result(id, step.clone(), image.clone(), 0.01, Some((2.5, None)));
        // A result of a session that was replaced leaves no row.
        live.result(id + 1, step, image, 0.01, Some((3.5, None)));
        let csv = "time_s,u_m,v_m,sigma_u_m,sigma_v_m\n1.500000,0.010000,-0.020000,0.007000,0.008000\n2.500000,,,,\n";
        assert_eq!(live.track_csv(), csv);
        let v = live.view();
        assert_eq!(v.difference_background_s, Some(10.0));
        assert_eq!(v.last_time_s, Some(2.5));
        assert!(v.centroid.is_none(), "the newest result found nothing");
        live.stop();
        assert_eq!(live.track_csv(), csv);
        live.start(live.issue_id(), CaptureRequest::example(), spec, None);
        assert_eq!(live.track_csv(), "time_s,u_m,v_m,sigma_u_m,sigma_v_m\n");
    }

    #[test]
    fn a_recording_is_claimed_once_and_a_waiting_one_goes_back_to_whoever_ends_it() {
        let live = Live::default();
        let spec = spec(None);
        let start = |recording| {
            let id = live.issue_id();
            let (view, replaced) =
                live.start(id, CaptureRequest::example(), spec.clone(), recording);
            (id, view, replaced)
        };
        let (one, view, replaced) = start(Some((7, 16)));
        assert!(replaced.is_none());
        let r = view.recording.expect("a recording");
        assert_eq!((r.capture, r.frames, r.of), (7, 0, 16));
        assert_eq!(r.state, RecordingState::Waiting);
        // Replaced before its first frame: its capture goes back.
        let (two, _, replaced) = start(Some((8, 4)));
        assert_eq!(replaced, Some(7));
        assert_eq!(live.claim_recording(one), None, "not the session any more");
        assert_eq!(live.claim_recording(two), Some((8, 4)));
        assert_eq!(live.claim_recording(two), None, "claimed once");
        live.recorded(two, 3);
        assert_eq!(live.view().recording.map(|r| r.frames), Some(3));
        // Recording: whoever stops the session does not end it (its writer does).
        assert_eq!(live.stop().1, None);
        let (three, _, _) = start(Some((9, 4)));
        assert_eq!(live.fail_waiting(three, "the camera went"), Some(9));
        let r = live.view().recording.expect("a recording");
        assert_eq!(r.state, RecordingState::Failed);
        assert_eq!(live.fail_waiting(three, "again"), None);
        assert_eq!(live.stop().1, None);
        let (_, view, _) = start(None);
        assert!(view.recording.is_none());
    }

    #[test]
    fn the_median_of_odd_and_even_counts() {
        assert_eq!(median(&VecDeque::new()), None);
        assert_eq!(median(&[3.0, 1.0, 2.0].into_iter().collect()), Some(2.0));
        assert_eq!(
            median(&[4.0, 1.0, 3.0, 2.0].into_iter().collect()),
            Some(2.5)
        );
    }
}
