//! Capture and reconstruction jobs: request validation (so that a bad request
//! is refused before it is queued) and the workers that run them.

use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Arc;
use std::time::Instant;

use serde::Deserialize;
use tokio::sync::{mpsc, Mutex};

use super::{Daemon, Event};
use crate::camera::settings::EXPOSURE_RANGE_US;
use crate::camera::{CameraInfo, CameraSettings, PixelFormat, TriggerMode};
use crate::files::{image, json, npy};
use crate::measure::exposure::{plan_exposure, BlockExposure, CameraLimits, ExposureTarget};
use crate::measure::sample_wall;
use crate::solve::lambda::{admm_tv_resolved, NoiseLevel};
use crate::solve::report::Report;
use crate::solve::report::{mean_snr, snr_warnings};
use crate::solve::{admm_tv, least_squares, tikhonov, AdmmSettings};
use crate::store::{
    read_mean, write_capture_files, CaptureRequest, FrameMeta, JobState, ReconstructionRequest,
};

/// `POST /captures` body.
#[derive(Debug, Clone, Deserialize, utoipa::ToSchema)]
#[serde(deny_unknown_fields)]
pub struct CaptureBody {
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
    /// Frames to average (1-1000); default 1, or the plan's with `"exposure": "auto"`.
    pub frames: Option<usize>,
    /// Dark frames with the scene off, averaged and subtracted (0-1000).
    #[serde(default)]
    pub dark_frames: usize,
    /// Pixel format (default Mono16).
    pub pixel_format: Option<PixelFormat>,
}

/// ADMM iteration cap of an automatic-lambda reconstruction unless the request sets one.
const AUTO_MAX_ITER: usize = 5000;

/// The only automatic exposure mode.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize, utoipa::ToSchema)]
#[serde(rename_all = "lowercase")]
pub enum AutoExposure {
    /// Plan from the scene (see [`crate::measure::exposure`]).
    Auto,
}

/// The camera limits exposure planning works with: the camera's exposure
/// range when connected (`info`, from one status read), the configured
/// sensor noise, 1000 frames.
pub fn camera_limits(d: &Daemon, info: Option<&CameraInfo>) -> CameraLimits {
    let (mut lo, mut hi) = EXPOSURE_RANGE_US;
    if let Some(i) = info {
        lo = lo.max(i.exposure_us.0);
        hi = hi.min(i.exposure_us.1);
    }
    CameraLimits {
        exposure_us: (lo, hi),
        max_frames: 1000,
        full_well_e: d.config.camera.full_well_e,
        read_noise_e: d.config.camera.read_noise_e,
    }
}

/// The exposure plan of every block of a scene under `limits` (see [`camera_limits`]).
pub fn exposure_plan(
    d: &Daemon,
    scene: &str,
    target: &ExposureTarget,
    limits: &CameraLimits,
) -> Result<Vec<BlockExposure>, RequestError> {
    let t = d
        .scenes
        .transport(scene)
        .ok_or_else(|| {
            RequestError::NotFound(format!(
                "unknown scene {scene:?}; known: {}",
                d.scenes.names().join(", ")
            ))
        })?
        .map_err(|e| RequestError::Invalid(format!("scene {scene:?}: {e}")))?;
    let cal = d.calibration.get(scene).copied().ok_or_else(|| {
        RequestError::Invalid(format!(
            "no radiometric calibration for scene {scene:?}, so exposures cannot be planned: add `{scene} = <fraction of full scale per microsecond per unit of T l>` under [calibration] in the config, or give exposure_us"
        ))
    })?;
    plan_exposure(&t, cal, limits, target).map_err(|e| RequestError::Invalid(e.to_string()))
}

/// `POST /reconstructions` body.
#[derive(Debug, Clone, Deserialize, serde::Serialize, utoipa::ToSchema)]
#[serde(deny_unknown_fields)]
pub struct ReconstructionBody {
    /// Scene name.
    pub scene: String,
    /// One finished capture per (pose, polarizer angle) block of the scene.
    pub captures: Vec<i64>,
    /// `admm-tv` (default), `tikhonov` or `lsq`.
    #[serde(default = "admm")]
    pub solver: String,
    /// Regularization weight (MODEL.md units). Default: chosen from the
    /// frame-to-frame noise of the captures (resolved-discrepancy rule, see
    /// `lambda_choice` in the report) when every capture has 2 frames or
    /// more, else as `polnlos reconstruct`.
    pub lambda: Option<f64>,
    /// ADMM penalty.
    pub rho: Option<f64>,
    /// ADMM iteration cap (1-100000).
    pub max_iter: Option<usize>,
    /// ADMM tolerance.
    pub tol: Option<f64>,
    /// Known truth, as a test pattern name (`disk`, `bars`, `letter`): the
    /// report then carries PSNR, ZNCC and SSIM (e.g. against the fake camera's demo scene).
    pub truth: Option<String>,
}

fn admm() -> String {
    "admm-tv".into()
}

/// A request that cannot be accepted: status 404 (unknown thing) or 422.
#[derive(Debug, thiserror::Error)]
pub enum RequestError {
    /// A referenced thing does not exist.
    #[error("{0}")]
    NotFound(String),
    /// A value is out of range or inconsistent.
    #[error("{0}")]
    Invalid(String),
}

/// Checks a capture request against the scene and the camera's ranges.
pub fn validate_capture(d: &Daemon, b: &CaptureBody) -> Result<CaptureRequest, RequestError> {
    let scene = d.scenes.get(&b.scene).ok_or_else(|| {
        RequestError::NotFound(format!(
            "unknown scene {:?}; known: {}",
            b.scene,
            d.scenes.names().join(", ")
        ))
    })?;
    let pose = scene.pose(&b.pose).ok_or_else(|| {
        RequestError::Invalid(format!(
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
    let angles: Vec<f64> = pose.analyzers.iter().map(|a| a.angle_deg).collect();
    match (b.polarizer_deg, angles.is_empty()) {
        (None, true) => {}
        (Some(a), false) if angles.iter().any(|x| (x - a).abs() < 1e-6) => {}
        (None, false) => {
            return Err(RequestError::Invalid(format!(
                "pose {:?} of scene {:?} has a polarizer: give polarizer_deg, one of {angles:?}",
                b.pose, b.scene
            )))
        }
        (Some(a), true) => {
            return Err(RequestError::Invalid(format!(
                "pose {:?} of scene {:?} has no polarizer, but polarizer_deg = {a} was given",
                b.pose, b.scene
            )))
        }
        (Some(a), false) => {
            return Err(RequestError::Invalid(format!(
                "polarizer_deg = {a} is not an angle of pose {:?} (scene {:?}): {angles:?}",
                b.pose, b.scene
            )))
        }
    }
    let info = d.camera.status().info;
    let limits = camera_limits(d, info.as_ref());
    let (lo, hi) = limits.exposure_us;
    let (exposure_us, planned) = match (b.exposure_us, b.exposure) {
        (Some(_), Some(_)) => {
            return Err(RequestError::Invalid(
                "give either exposure_us or \"exposure\": \"auto\", not both".into(),
            ))
        }
        (None, None) => {
            return Err(RequestError::Invalid(
                "exposure_us is missing: give it in microseconds, or \"exposure\": \"auto\"".into(),
            ))
        }
        (Some(e), None) => {
            if b.target.is_some() {
                return Err(RequestError::Invalid(
                    "target is only for \"exposure\": \"auto\"".into(),
                ));
            }
            (e, None)
        }
        (None, Some(AutoExposure::Auto)) => {
            let plan = exposure_plan(d, &b.scene, &b.target.unwrap_or_default(), &limits)?;
            let block = plan
                .into_iter()
                .find(|p| {
                    p.pose == b.pose
                        && match (p.polarizer_deg, b.polarizer_deg) {
                            (None, None) => true,
                            (Some(x), Some(y)) => (x - y).abs() < 1e-6,
                            _ => false,
                        }
                })
                .ok_or_else(|| {
                    RequestError::Invalid(format!(
                        "no block ({}, {:?}) in scene {:?}",
                        b.pose, b.polarizer_deg, b.scene
                    ))
                })?;
            (block.exposure_us, Some(block))
        }
    };
    if !(exposure_us >= lo && exposure_us <= hi) {
        return Err(RequestError::Invalid(format!(
            "exposure_us = {exposure_us}: must be from {lo} to {hi} microseconds"
        )));
    }
    let frames = b
        .frames
        .unwrap_or_else(|| planned.as_ref().map(|p| p.frames).unwrap_or(1));
    let (glo, ghi) = info.as_ref().map(|i| i.gain).unwrap_or((0.0, f64::MAX));
    if !(b.gain >= glo && b.gain <= ghi) {
        return Err(RequestError::Invalid(format!(
            "gain = {}: must be from {glo} to {ghi}",
            b.gain
        )));
    }
    if !(1..=1000).contains(&frames) {
        return Err(RequestError::Invalid(format!(
            "frames = {frames}: must be from 1 to 1000"
        )));
    }
    if b.dark_frames > 1000 {
        return Err(RequestError::Invalid(format!(
            "dark_frames = {}: must be from 0 to 1000",
            b.dark_frames
        )));
    }
    Ok(CaptureRequest {
        scene: b.scene.clone(),
        pose: b.pose.clone(),
        polarizer_deg: b.polarizer_deg,
        exposure_us,
        gain: b.gain,
        frames,
        dark_frames: b.dark_frames,
        pixel_format: b.pixel_format.unwrap_or(PixelFormat::Mono16),
    })
}

/// Checks a reconstruction request: solver parameters, and one finished
/// capture of this scene for every (pose, angle) block.
pub fn validate_reconstruction(
    d: &Daemon,
    b: &ReconstructionBody,
) -> Result<ReconstructionRequest, RequestError> {
    let scene = d
        .scenes
        .get(&b.scene)
        .ok_or_else(|| RequestError::NotFound(format!("unknown scene {:?}", b.scene)))?;
    if !["admm-tv", "tikhonov", "lsq"].contains(&b.solver.as_str()) {
        return Err(RequestError::Invalid(format!(
            "solver = {:?}: must be admm-tv, tikhonov or lsq",
            b.solver
        )));
    }
    if let Some(l) = b.lambda {
        if !(l >= 0.0 && l.is_finite()) {
            return Err(RequestError::Invalid(format!(
                "lambda = {l}: must be a finite number >= 0"
            )));
        }
    }
    if let Some(r) = b.rho {
        if !(r > 0.0 && r.is_finite()) {
            return Err(RequestError::Invalid(format!(
                "rho = {r}: must be a finite number > 0"
            )));
        }
    }
    if let Some(m) = b.max_iter {
        if !(1..=100_000).contains(&m) {
            return Err(RequestError::Invalid(format!(
                "max_iter = {m}: must be from 1 to 100000"
            )));
        }
    }
    if let Some(t) = b.tol {
        if !(t > 0.0 && t < 1.0) {
            return Err(RequestError::Invalid(format!(
                "tol = {t}: must be in (0, 1)"
            )));
        }
    }
    if let Some(t) = &b.truth {
        if crate::simulate::patterns::Pattern::from_name(t).is_none() {
            return Err(RequestError::Invalid(format!(
                "truth = {t:?}: must be a test pattern name (disk, bars, letter)"
            )));
        }
    }
    let mut blocks: Vec<(String, Option<f64>)> = Vec::new();
    for p in &scene.poses {
        if p.analyzers.is_empty() {
            blocks.push((p.name.clone(), None));
        }
        for a in &p.analyzers {
            blocks.push((p.name.clone(), Some(a.angle_deg)));
        }
    }
    if b.captures.len() != blocks.len() {
        return Err(RequestError::Invalid(format!(
            "scene {:?} has {} (pose, polarizer) blocks {blocks:?}; give exactly one capture for each ({} given)",
            b.scene,
            blocks.len(),
            b.captures.len()
        )));
    }
    let mut covered = vec![false; blocks.len()];
    for &id in &b.captures {
        let c = d
            .store
            .capture(id)
            .map_err(|_| RequestError::NotFound(format!("no capture with id {id}")))?;
        if c.state != JobState::Done {
            return Err(RequestError::Invalid(format!(
                "capture {id} is {:?}, not done",
                c.state
            )));
        }
        if c.scene != b.scene {
            return Err(RequestError::Invalid(format!(
                "capture {id} belongs to scene {:?}, not {:?}",
                c.scene, b.scene
            )));
        }
        let k = blocks
            .iter()
            .position(|(p, a)| *p == c.pose && same_angle(*a, c.polarizer_deg))
            .ok_or_else(|| {
                RequestError::Invalid(format!(
                    "capture {id} (pose {:?}, polarizer {:?}) is not a block of scene {:?}",
                    c.pose, c.polarizer_deg, b.scene
                ))
            })?;
        if covered[k] {
            return Err(RequestError::Invalid(format!(
                "two captures for block {:?}; give one per block",
                blocks[k]
            )));
        }
        covered[k] = true;
    }
    Ok(ReconstructionRequest {
        scene: b.scene.clone(),
        captures: b.captures.clone(),
        solver: b.solver.clone(),
        params: serde_json::json!({ "lambda": b.lambda, "rho": b.rho, "max_iter": b.max_iter, "tol": b.tol, "truth": b.truth }),
    })
}

/// Whether two polarizer settings are the same block (both absent, or equal angles).
fn same_angle(a: Option<f64>, b: Option<f64>) -> bool {
    match (a, b) {
        (None, None) => true,
        (Some(x), Some(y)) => (x - y).abs() < 1e-6,
        _ => false,
    }
}

/// Largest least-squares RMS error (fraction of the radiance range) before a
/// reconstruction warns that its grid is too fine (as `polnlos plan`).
const PLAN_TOLERANCE: f64 = 0.1;

/// How long a capture waits for a camera that is not connected.
const CAMERA_GRACE: std::time::Duration = std::time::Duration::from_secs(5);

fn job_event(d: &Daemon, job: String, state: JobState, error: Option<String>) {
    d.emit(Event::Job { job, state, error });
}

/// Runs captures one at a time (one camera).
/// Records how a job ended: its time and done/failed counters, the failure
/// in the store, and the job event.
fn finish_job(
    d: &Daemon,
    job: String,
    start: Instant,
    result: Result<(), String>,
    (done, failed, micros): (&AtomicU64, &AtomicU64, &AtomicU64),
    store_failure: impl FnOnce(&str) -> Result<(), crate::store::StoreError>,
) {
    micros.fetch_add(start.elapsed().as_micros() as u64, Ordering::Relaxed);
    match result {
        Ok(()) => {
            done.fetch_add(1, Ordering::Relaxed);
            job_event(d, job, JobState::Done, None);
        }
        Err(e) => {
            tracing::warn!("{job} failed: {e}");
            failed.fetch_add(1, Ordering::Relaxed);
            if let Err(se) = store_failure(&e) {
                tracing::error!("cannot record the failure of {job}: {se}");
            }
            job_event(d, job, JobState::Failed, Some(e));
        }
    }
}

pub(super) async fn capture_worker(d: Arc<Daemon>, mut rx: mpsc::Receiver<i64>) {
    while let Some(id) = rx.recv().await {
        let job = format!("capture-{id}");
        let start = Instant::now();
        let result = run_capture(&d, id).await;
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
    let pixel_format = PixelFormat::from_name(&c.pixel_format).unwrap_or(PixelFormat::Mono16);
    let settings = CameraSettings {
        exposure_us: c.exposure_us,
        gain: c.gain,
        pixel_format,
        region: None,
        binning: None,
        trigger: TriggerMode::Free,
    };
    let total = (c.frames + c.dark_frames) as usize;
    // The camera thread only sends a number; the store write and the event
    // happen here, off the thread that pops buffers.
    let (tx, mut rx) = mpsc::unbounded_channel::<usize>();
    let d2 = d.clone();
    let progress_task = tokio::spawn(async move {
        while let Some(taken) = rx.recv().await {
            d2.emit(Event::Frame {
                job: format!("capture-{id}"),
                taken,
                total,
            });
            let store = d2.store.clone();
            let _ = tokio::task::spawn_blocking(move || store.capture_progress(id, taken)).await;
        }
    });
    let progress = |offset: usize| {
        let tx = tx.clone();
        Box::new(move |k: usize| {
            let _ = tx.send(offset + k);
        }) as Box<dyn FnMut(usize) + Send>
    };
    // A camera that is (re)connecting gets a short grace period before the capture fails.
    let grace = Instant::now();
    while !d.camera.status().connected && grace.elapsed() < CAMERA_GRACE {
        tokio::time::sleep(std::time::Duration::from_millis(100)).await;
    }
    d.bench.select(&c.pose, c.polarizer_deg);
    let mut dark = Vec::new();
    if c.dark_frames > 0 {
        d.bench.scene_on(false);
        let r = d
            .camera
            .acquire(settings.clone(), c.dark_frames as usize, progress(0))
            .await;
        d.bench.scene_on(true);
        dark = r.map_err(|e| format!("dark frames: {e}"))?;
    }
    let frames = d
        .camera
        .acquire(
            settings,
            c.frames as usize,
            progress(c.dark_frames as usize),
        )
        .await;
    drop(tx);
    let _ = progress_task.await;
    let frames = frames.map_err(|e| e.to_string())?;
    let status = d.camera.status();
    let camera_id = status
        .info
        .as_ref()
        .map(|i| i.id.clone())
        .unwrap_or_default();
    let meta = FrameMeta {
        capture: id,
        scene: c.scene.clone(),
        pose: c.pose.clone(),
        polarizer_deg: c.polarizer_deg,
        exposure_us: c.exposure_us,
        gain: c.gain,
        camera_id: camera_id.clone(),
        counters: status.counters,
    };
    let dir = d.store.capture_dir(id);
    tokio::task::spawn_blocking(move || write_capture_files(&dir, &frames, &dark, &meta))
        .await
        .map_err(|e| e.to_string())?
        .map_err(|e| e.to_string())?;
    let counters = serde_json::to_string(&status.counters).unwrap_or_default();
    d.store
        .capture_done(id, &camera_id, &counters)
        .map_err(|e| e.to_string())
}

/// Takes reconstructions from the shared queue.
pub(super) async fn reconstruction_worker(d: Arc<Daemon>, rx: Arc<Mutex<mpsc::Receiver<i64>>>) {
    loop {
        let Some(id) = rx.lock().await.recv().await else {
            return;
        };
        let job = format!("reconstruction-{id}");
        let start = Instant::now();
        if let Err(e) = d.store.reconstruction_running(id) {
            tracing::error!("{job}: {e}");
            continue;
        }
        job_event(&d, job.clone(), JobState::Running, None);
        let d2 = d.clone();
        let r = tokio::task::spawn_blocking(move || run_reconstruction(&d2, id))
            .await
            .map_err(|e| e.to_string())
            .and_then(|r| r);
        let m = &d.metrics;
        let counters = (
            &m.reconstructions_done,
            &m.reconstructions_failed,
            &m.reconstruction_micros,
        );
        finish_job(&d, job, start, r, counters, |e| {
            d.store.reconstruction_failed(id, e)
        });
    }
}

/// Frames to `i` through the homographies, the solve, and the files.
fn run_reconstruction(d: &Daemon, id: i64) -> Result<(), String> {
    let rec = d.store.reconstruction(id).map_err(|e| e.to_string())?;
    let scene = d
        .scenes
        .get(&rec.scene)
        .ok_or_else(|| format!("scene {:?} is no longer configured", rec.scene))?;
    let t0 = Instant::now();
    let t = d
        .scenes
        .transport(&rec.scene)
        .ok_or("scene vanished")?
        .map_err(|e| e.to_string())?;
    let transport_seconds = t0.elapsed().as_secs_f64();
    // Stack the captures in block order: MODEL.md row order. The frame-to-frame
    // variance of each capture gives the measurement's noise, when there are
    // at least two frames per capture.
    let mut i = vec![0.0; t.rows()];
    let mut var = Some(vec![0.0; t.rows()]);
    for (b, block) in t.blocks.iter().enumerate() {
        let cap = rec
            .captures
            .iter()
            .filter_map(|&cid| d.store.capture(cid).ok())
            .find(|c| c.pose == block.pose && same_angle(c.polarizer_deg, block.polarizer_deg))
            .ok_or_else(|| format!("no capture for block {}", block.label()))?;
        let pose = scene.pose(&block.pose).ok_or("pose vanished")?;
        let mean = read_mean(&d.store.capture_dir(cap.id))
            .map_err(|e| format!("capture {}: {e}", cap.id))?;
        let h = pose.homography.as_ref().ok_or_else(|| {
            crate::measure::MeasureError::NoHomography {
                pose: pose.name.clone(),
            }
            .to_string()
        })?;
        let wall = sample_wall(&mean, h, &scene.wall.plane, &pose.name)
            .map_err(|e| format!("capture {}: {e}", cap.id))?;
        let full = PixelFormat::from_name(&cap.pixel_format)
            .unwrap_or(PixelFormat::Mono16)
            .full_scale();
        // Fraction of full scale per microsecond: captures of different exposures compare.
        let to_units = 1.0 / full / cap.exposure_us;
        for (dst, v) in i[t.block_rows(b)].iter_mut().zip(wall) {
            *dst = v * to_units;
        }
        let frame_var = crate::store::read_mean_variance(&d.store.capture_dir(cap.id))
            .map_err(|e| format!("capture {}: {e}", cap.id))?;
        match (frame_var, var.as_mut()) {
            (Some(fv), Some(acc)) => {
                let wall_var = sample_wall(&fv, h, &scene.wall.plane, &pose.name)
                    .map_err(|e| format!("capture {}: {e}", cap.id))?;
                for (dst, v) in acc[t.block_rows(b)].iter_mut().zip(wall_var) {
                    *dst = v * to_units * to_units;
                }
            }
            _ => var = None,
        }
    }
    let mut warnings = Vec::new();
    match d.calibration.get(&rec.scene) {
        Some(&c) if c > 0.0 => {
            i.iter_mut().for_each(|v| *v /= c);
            var.iter_mut().flatten().for_each(|v| *v /= c * c);
        }
        _ => {
            // No calibration: scale so that the brightest element of a Tikhonov
            // solution is 1 (the box constraint needs some scale).
            let probe = tikhonov(&t, &i, None).map_err(|e| e.to_string())?;
            let unclipped_max = probe.image.iter().copied().fold(0.0, f64::max).max(1e-300);
            let lsq_scale = t
                .apply(&probe.image)
                .iter()
                .zip(&i)
                .map(|(a, b)| a * b)
                .sum::<f64>()
                .max(1e-300)
                / t.apply(&probe.image)
                    .iter()
                    .map(|a| a * a)
                    .sum::<f64>()
                    .max(1e-300);
            let s = lsq_scale * unclipped_max;
            i.iter_mut().for_each(|v| *v /= s);
            var.iter_mut().flatten().for_each(|v| *v /= s * s);
            warnings.push("no radiometric calibration for this scene: the measurement was scaled so that the brightest element is about 1".to_string());
        }
    }
    let p = &rec.params;
    let lambda = p.get("lambda").and_then(|v| v.as_f64());
    let cond = d
        .scenes
        .conditioning(&rec.scene)
        .ok_or("scene vanished")??;
    let settings = AdmmSettings {
        lambda,
        rho: p.get("rho").and_then(|v| v.as_f64()),
        max_iter: p
            .get("max_iter")
            .and_then(|v| v.as_u64())
            .map(|v| v as usize)
            .unwrap_or(AdmmSettings::default().max_iter),
        tol: p
            .get("tol")
            .and_then(|v| v.as_f64())
            .unwrap_or(AdmmSettings::default().tol),
    };
    let mut lambda_choice = None;
    let r = match (rec.solver.as_str(), lambda, &var) {
        ("tikhonov", _, _) => tikhonov(&t, &i, lambda),
        ("lsq", _, _) => least_squares(&t, &i, None),
        // No lambda given and a noise level from the frames: choose it from the noise.
        (_, None, Some(v)) => admm_tv_resolved(
            &t,
            &i,
            &NoiseLevel {
                variance: v.clone(),
            },
            &cond.singular_values,
            &AdmmSettings {
                // Low-noise captures lead to small lambdas, which converge slowly.
                max_iter: p
                    .get("max_iter")
                    .and_then(|v| v.as_u64())
                    .map(|v| v as usize)
                    .unwrap_or(AUTO_MAX_ITER),
                ..settings
            },
        )
        .map(|(r, c)| {
            lambda_choice = Some(c);
            r
        }),
        _ => admm_tv(&t, &i, &settings),
    }
    .map_err(|e| e.to_string())?;
    let grid = t.scene_grid;
    if let Some(v) = &var {
        warnings.extend(snr_warnings(mean_snr(&i, v)));
        // The least-squares error the noise implies (see `polnlos plan`).
        let sigma = (v.iter().sum::<f64>() / v.len().max(1) as f64).sqrt();
        let amp = if cond.is_rank_deficient() {
            f64::INFINITY
        } else {
            sigma
                * (cond
                    .singular_values
                    .iter()
                    .map(|s| 1.0 / (s * s))
                    .sum::<f64>()
                    / t.cols() as f64)
                    .sqrt()
        };
        if amp > PLAN_TOLERANCE {
            warnings.push(format!(
                "the {}x{} scene grid is finer than this measurement supports: the frame-to-frame noise alone gives a least-squares RMS error of {amp:.2e} of the radiance range (> {PLAN_TOLERANCE}); `polnlos plan` suggests a coarser grid, or take more frames",
                grid.nu, grid.nv
            ));
        }
    }
    let truth = p
        .get("truth")
        .and_then(|v| v.as_str())
        .and_then(crate::simulate::patterns::Pattern::from_name)
        .map(|pat| pat.render(grid));
    let image = r.image.clone();
    let mut report = Report::new(
        rec.scene.clone(),
        &t,
        transport_seconds,
        &cond,
        r,
        truth.as_deref(),
        lambda_choice,
    );
    report.warnings.splice(0..0, warnings);
    let dir = d.store.reconstruction_dir(id);
    std::fs::create_dir_all(&dir).map_err(|e| format!("{}: {e}", dir.display()))?;
    npy::write_f64(&dir.join("recovered.npy"), &[grid.nv, grid.nu], &image)
        .map_err(|e| e.to_string())?;
    image::write_png16(
        &dir.join("image.png"),
        grid.nu,
        grid.nv,
        &image::unit_to_u16(&image),
    )
    .map_err(|e| e.to_string())?;
    json::write(&dir.join("report.json"), &report).map_err(|e| e.to_string())?;
    let text = serde_json::to_string(&report).map_err(|e| e.to_string())?;
    d.store
        .reconstruction_done(id, cond.kappa, &text)
        .map_err(|e| e.to_string())
}
