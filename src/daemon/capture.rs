//! Captures: the request, its validation (every camera setting the capture
//! uses is resolved and recorded when it is accepted, so a later
//! `PUT /camera/settings` cannot change it), and the worker that streams its
//! frames to disk while they arrive.
//!
//! Dark frames are never taken silently with the scene lit: a bench that can
//! switch the hidden scene off itself (the fake bench, a motorized shutter)
//! takes `dark_frames` within a capture; on a bench set by hand the user
//! switches the scene off and asks for a `"kind": "dark"` capture, then names
//! it in later captures as `dark_capture`.

use std::sync::Arc;
use std::time::Instant;

use serde::Deserialize;
use tokio::sync::mpsc;

use super::jobs::{camera_limits, exposure_plan, finish_job, job_event, same_angle};
use super::{Daemon, Event, RequestError};
use crate::camera::{CameraError, CameraSettings, Frame, PixelFormat, RawFrame, TriggerMode};
use crate::measure::exposure::ExposureTarget;
use crate::store::{
    capture_bytes, read_mean, write_frames, write_summary, CaptureFiles, CaptureKind,
    CaptureRequest, FrameMeta, FrameStack, JobState,
};

/// `POST /captures` body.
#[derive(Debug, Clone, Deserialize, utoipa::ToSchema)]
#[serde(deny_unknown_fields)]
pub struct CaptureBody {
    /// `light` (default: the hidden scene on) or `dark` (the scene switched
    /// off by the user; subtract it from later captures with `dark_capture`).
    pub kind: Option<CaptureKind>,
    /// Scene name.
    pub scene: String,
    /// Pose name in the scene.
    pub pose: String,
    /// Polarizer angle of the pose, degrees (omit or null for a pose without polarizer).
    pub polarizer_deg: Option<f64>,
    /// Exposure per frame, microseconds; omit it and give `"exposure": "auto"`
    /// to have it planned (see `GET /scenes/{name}/exposure`).
    pub exposure_us: Option<f64>,
    /// `"auto"`: plan the exposure (and, unless `frames` is given, the frame
    /// count) from the scene, the radiometric calibration and the camera limits.
    pub exposure: Option<AutoExposure>,
    /// Target of an automatic exposure (default: peak at 0.8 of full scale, SNR 100).
    pub target: Option<ExposureTarget>,
    /// Gain (camera units).
    #[serde(default)]
    pub gain: f64,
    /// Frames to average (1 to `max_frames_per_capture`); default 1, or the
    /// plan's with `"exposure": "auto"`.
    pub frames: Option<usize>,
    /// Dark frames taken within this capture with the scene switched off by
    /// the bench itself (only on a bench that can: the fake camera's). On a
    /// bench set by hand, take a `"kind": "dark"` capture instead.
    #[serde(default)]
    pub dark_frames: usize,
    /// A done dark capture (same exposure, gain, pixel format, region and
    /// binning) whose mean is subtracted from this capture's.
    pub dark_capture: Option<i64>,
    /// Pixel format (default: the camera's current settings).
    pub pixel_format: Option<PixelFormat>,
    /// Region `[x, y, width, height]` (default: the current settings).
    pub region: Option<[u32; 4]>,
    /// Binning `[x, y]` (default: the current settings).
    pub binning: Option<[u32; 2]>,
    /// `free` or `software` (default: the current settings).
    pub trigger: Option<TriggerMode>,
}

/// The only automatic exposure mode.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize, utoipa::ToSchema)]
#[serde(rename_all = "lowercase")]
pub enum AutoExposure {
    /// Plan from the scene (see [`crate::measure::exposure`]).
    Auto,
}

/// Frames in flight between the camera thread and the writer.
const FRAME_QUEUE: usize = 4;

/// How long a capture waits for a camera that is not connected.
const CAMERA_GRACE: std::time::Duration = std::time::Duration::from_secs(5);

fn invalid(m: impl Into<String>) -> RequestError {
    RequestError::Invalid(m.into())
}

/// Checks that `polarizer_deg` is a setting of the pose (or absent for a pose without polarizer).
fn check_block(
    scene_name: &str,
    pose: &crate::scene::Pose,
    polarizer_deg: Option<f64>,
) -> Result<(), RequestError> {
    let angles: Vec<f64> = pose.analyzers.iter().map(|a| a.angle_deg).collect();
    let list = || {
        angles
            .iter()
            .map(|a| a.to_string())
            .collect::<Vec<_>>()
            .join(", ")
    };
    match (polarizer_deg, angles.is_empty()) {
        (None, true) => Ok(()),
        (Some(a), false) if angles.iter().any(|x| same_angle(Some(*x), Some(a))) => Ok(()),
        (None, false) => Err(invalid(format!(
            "pose {:?} of scene {scene_name:?} has a polarizer: give polarizer_deg, one of {}",
            pose.name,
            list()
        ))),
        (Some(a), true) => Err(invalid(format!(
            "pose {:?} of scene {scene_name:?} has no polarizer, but polarizer_deg = {a} was given",
            pose.name
        ))),
        (Some(a), false) => Err(invalid(format!(
            "polarizer_deg = {a} is not an angle of pose {:?} (scene {scene_name:?}): {}",
            pose.name,
            list()
        ))),
    }
}

/// Checks a capture request against the scene, the camera's ranges and the
/// bench, and resolves every camera setting it will use.
pub fn validate_capture(d: &Daemon, b: &CaptureBody) -> Result<CaptureRequest, RequestError> {
    let scene = d.scenes.get(&b.scene).ok_or_else(|| {
        RequestError::NotFound(format!(
            "unknown scene {:?}; known: {}",
            b.scene,
            d.scenes.names().join(", ")
        ))
    })?;
    let pose = scene.pose(&b.pose).ok_or_else(|| {
        invalid(format!(
            "scene {:?} has no pose {:?}; its poses: {}",
            b.scene,
            b.pose,
            scene
                .poses
                .iter()
                .map(|p| p.name.as_str())
                .collect::<Vec<_>>()
                .join(", ")
        ))
    })?;
    check_block(&b.scene, pose, b.polarizer_deg)?;
    let kind = b.kind.unwrap_or(CaptureKind::Light);
    let info = d.camera.status().info;
    let limits = camera_limits(d, info.as_ref());
    let (lo, hi) = limits.exposure_us;
    let (exposure_us, planned) = match (b.exposure_us, b.exposure) {
        (Some(_), Some(_)) => {
            return Err(invalid(
                "give either exposure_us or \"exposure\": \"auto\", not both",
            ))
        }
        (None, None) => {
            return Err(invalid(
                "exposure_us is missing: give it in microseconds, or \"exposure\": \"auto\"",
            ))
        }
        (Some(e), None) => {
            if b.target.is_some() {
                return Err(invalid("target is only for \"exposure\": \"auto\""));
            }
            (e, None)
        }
        (None, Some(AutoExposure::Auto)) => {
            let plan = exposure_plan(d, &b.scene, &b.target.unwrap_or_default(), &limits)?;
            let block = plan
                .into_iter()
                .find(|p| p.pose == b.pose && same_angle(p.polarizer_deg, b.polarizer_deg))
                .ok_or_else(|| {
                    invalid(format!(
                        "the exposure plan of scene {:?} has no block for pose {:?}",
                        b.scene, b.pose
                    ))
                })?;
            (block.exposure_us, Some(block))
        }
    };
    if !(exposure_us >= lo && exposure_us <= hi) {
        return Err(invalid(format!(
            "exposure_us = {exposure_us}: must be from {lo} to {hi} microseconds"
        )));
    }
    let frames = b
        .frames
        .unwrap_or_else(|| planned.as_ref().map(|p| p.frames).unwrap_or(1));
    let (glo, ghi) = info.as_ref().map(|i| i.gain).unwrap_or((0.0, f64::MAX));
    if !(b.gain >= glo && b.gain <= ghi) {
        return Err(invalid(format!(
            "gain = {}: must be from {glo} to {ghi}",
            b.gain
        )));
    }
    let max = d.config.queue.max_frames_per_capture;
    if frames == 0 || frames.saturating_add(b.dark_frames) > max {
        return Err(invalid(format!(
            "frames = {frames}, dark_frames = {}: need at least 1 frame and at most {max} in all ([queue] max_frames_per_capture)",
            b.dark_frames
        )));
    }
    if b.dark_frames > 0 && !d.bench.switches_scene() {
        return Err(invalid(
            "this bench cannot switch the hidden scene off by itself, so dark frames cannot be taken within a capture: switch the scene off, POST a capture with \"kind\": \"dark\", switch it back on, and give that capture's id as dark_capture",
        ));
    }
    if kind == CaptureKind::Dark && (b.dark_frames > 0 || b.dark_capture.is_some()) {
        return Err(invalid(
            "a dark capture takes no dark_frames and no dark_capture of its own",
        ));
    }
    if b.dark_frames > 0 && b.dark_capture.is_some() {
        return Err(invalid("give dark_frames or dark_capture, not both"));
    }
    // Everything the capture does not state, it inherits now and records.
    let current = d.capture_defaults(info.as_ref());
    let binning = b.binning.or(current.binning).unwrap_or([1, 1]);
    let region = b.region.or(current.region).ok_or_else(|| {
        RequestError::Unavailable(
            "the camera has not reported its region yet: give region = [x, y, width, height], or retry when GET /camera shows it connected".into(),
        )
    })?;
    if let Some(i) = &info {
        i.limits
            .check(region, binning)
            .map_err(|e| invalid(e.to_string()))?;
    }
    let request = CaptureRequest {
        kind,
        scene: b.scene.clone(),
        pose: b.pose.clone(),
        polarizer_deg: b.polarizer_deg,
        exposure_us,
        gain: b.gain,
        frames,
        dark_frames: b.dark_frames,
        pixel_format: b.pixel_format.unwrap_or(current.pixel_format),
        region,
        binning,
        trigger: b.trigger.unwrap_or(current.trigger),
        dark_capture: b.dark_capture,
    };
    if let Some(id) = b.dark_capture {
        check_dark_capture(d, id, &request)?;
    }
    Ok(request)
}

/// A dark capture fits a light one when it is done, dark, and taken with the
/// same exposure, gain, pixel format, region and binning.
fn check_dark_capture(d: &Daemon, id: i64, r: &CaptureRequest) -> Result<(), RequestError> {
    let c = d.store.capture(id).map_err(|_| {
        RequestError::NotFound(format!("dark_capture {id}: no capture with that id"))
    })?;
    if !c.is_dark() || c.state != JobState::Done {
        return Err(invalid(format!(
            "dark_capture {id} is a {} capture in state {}; it must be a done dark capture",
            c.kind,
            c.state.name()
        )));
    }
    let same = c.exposure_us == r.exposure_us
        && c.gain == r.gain
        && c.pixel_format == r.pixel_format.name()
        && c.region == Some(r.region)
        && c.binning == Some(r.binning);
    if !same {
        return Err(invalid(format!(
            "dark_capture {id} was taken at exposure_us {}, gain {}, {}, region {:?}, binning {:?}; this capture asks for {}, {}, {}, {:?}, {:?}: take a dark capture with the same settings",
            c.exposure_us, c.gain, c.pixel_format, c.region, c.binning,
            r.exposure_us, r.gain, r.pixel_format.name(), r.region, r.binning
        )));
    }
    Ok(())
}

/// Runs captures one at a time (one camera).
pub(super) async fn capture_worker(d: Arc<Daemon>, mut rx: mpsc::Receiver<i64>) {
    while let Some(id) = rx.recv().await {
        let job = format!("capture-{id}");
        let start = Instant::now();
        let result = {
            // Held for the whole capture: settings changes answer 409 meanwhile.
            let _camera = d.camera_gate.lock().await;
            run_capture(&d, id).await
        };
        d.release_capture(id);
        let m = &d.metrics;
        let counters = (&m.captures_done, &m.captures_failed, &m.capture_micros);
        finish_job(&d, job, start, result, counters, |e| {
            d.store.capture_failed(id, e)
        });
    }
}

async fn run_capture(d: &Arc<Daemon>, id: i64) -> Result<(), String> {
    let c = d.store.capture(id).map_err(|e| e.to_string())?;
    d.store.capture_running(id).map_err(|e| e.to_string())?;
    job_event(d, format!("capture-{id}"), JobState::Running, None);
    let (Some(region), Some(binning)) = (c.region, c.binning) else {
        return Err(format!("capture {id} records no region or binning"));
    };
    let settings = CameraSettings {
        exposure_us: c.exposure_us,
        gain: c.gain,
        pixel_format: PixelFormat::from_name(&c.pixel_format).unwrap_or(PixelFormat::Mono16),
        region: Some(region),
        binning: Some(binning),
        trigger: if c.trigger.as_deref() == Some(TriggerMode::Software.name()) {
            TriggerMode::Software
        } else {
            TriggerMode::Free
        },
    };
    // A camera that is (re)connecting gets a short grace period before the capture fails.
    let grace = Instant::now();
    while !d.camera.status().connected && grace.elapsed() < CAMERA_GRACE {
        tokio::time::sleep(std::time::Duration::from_millis(100)).await;
    }
    let camera_id = d.camera.status().info.map(|i| i.id).unwrap_or_default();
    let kind = if c.is_dark() {
        CaptureKind::Dark
    } else {
        CaptureKind::Light
    };
    let meta = FrameMeta {
        capture: id,
        kind,
        scene: c.scene.clone(),
        pose: c.pose.clone(),
        polarizer_deg: c.polarizer_deg,
        exposure_us: c.exposure_us,
        gain: c.gain,
        pixel_format: settings.pixel_format.name().into(),
        region,
        binning,
        trigger: settings.trigger.name().into(),
        dark_capture: c.dark_capture,
        camera_id: camera_id.clone(),
    };
    let dir = d.store.capture_dir(id);
    std::fs::create_dir_all(&dir).map_err(|e| d.store.describe_io(&dir, &e))?;
    d.bench.select(&c.pose, c.polarizer_deg);
    let total = (c.frames + c.dark_frames) as usize;
    let stream = Stream {
        d,
        id,
        settings: &settings,
        meta: &meta,
        total,
    };
    // Dark frames within the capture: only on a bench that switches the scene
    // itself (checked when the capture was accepted).
    let mut dark: Option<Frame> = None;
    if c.dark_frames > 0 {
        d.bench.scene_on(false);
        let r = stream
            .take(CaptureFiles::DARK, "dark", c.dark_frames as usize, 0)
            .await;
        d.bench.scene_on(true);
        let st = r.map_err(|e| format!("dark frames: {e}"))?;
        dark = Some(Frame {
            width: st.width,
            height: st.height,
            pixels: st.mean.iter().map(|&v| v as f32).collect(),
        });
    }
    if let Some(dc) = c.dark_capture {
        dark = Some(
            read_mean(&d.store.capture_dir(dc))
                .map_err(|e| format!("dark capture {dc}: {}", d.store.describe(&e)))?,
        );
    }
    let scene_off = kind == CaptureKind::Dark && d.bench.switches_scene();
    if scene_off {
        d.bench.scene_on(false);
    }
    let frames = stream
        .take(
            CaptureFiles::FRAMES,
            "frames",
            c.frames as usize,
            c.dark_frames as usize,
        )
        .await;
    if scene_off {
        d.bench.scene_on(true);
    }
    let frames = frames?;
    let store = d.store.clone();
    let dir2 = dir.clone();
    tokio::task::spawn_blocking(move || {
        write_summary(&dir2, &frames, dark.as_ref(), &meta).map_err(|e| store.describe(&e))
    })
    .await
    .map_err(|e| e.to_string())??;
    let status = d.camera.status();
    let counters = serde_json::to_string(&status.counters).unwrap_or_default();
    d.store
        .capture_done(id, &camera_id, &counters)
        .map_err(|e| e.to_string())
}

/// One acquisition of a capture, streamed to one file.
struct Stream<'a> {
    d: &'a Arc<Daemon>,
    id: i64,
    settings: &'a CameraSettings,
    meta: &'a FrameMeta,
    total: usize,
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
    ) -> Result<FrameStack, String> {
        let (id, total, d) = (self.id, self.total, self.d);
        let (frame_tx, frame_rx) = std::sync::mpsc::sync_channel::<RawFrame>(FRAME_QUEUE);
        let (progress_tx, mut progress_rx) = mpsc::unbounded_channel::<usize>();
        let path = d.store.capture_dir(id).join(name);
        let meta = self.meta.clone();
        let store = d.store.clone();
        let writer = tokio::task::spawn_blocking(move || {
            write_frames(&path, kind, &meta, n, frame_rx, &mut |k| {
                let _ = progress_tx.send(offset + k);
            })
            .map_err(|e| store.describe(&e))
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
        let written = writer.await.map_err(|e| e.to_string()).and_then(|r| r);
        let _ = progress.await;
        match (acquired, written) {
            (Ok(()), Ok(stack)) => Ok(stack),
            // The writer stopped first (a full disk): its reason is the one that matters.
            (Err(CameraError::Stopped(_)), Err(w)) | (Ok(()), Err(w)) => Err(w),
            (Err(e), _) => Err(e.to_string()),
        }
    }
}

/// Disk bytes a capture request's files take at most.
pub fn request_bytes(r: &CaptureRequest) -> u64 {
    capture_bytes(r.region[2], r.region[3], r.frames, r.dark_frames)
}
