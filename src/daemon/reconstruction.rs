//! Reconstructions: the request, its validation (one done light capture of
//! the scene per (pose, angle) block, taken at the frame the pose's
//! homography maps to), and the worker that turns the captures into a
//! measurement and runs [`crate::solve::reconstruct`] on it.

use std::sync::Arc;
use std::time::Instant;

use serde::Deserialize;
use tokio::sync::{mpsc, Mutex};

use super::jobs::{block_label, finish_job, job_event, same_angle, JobError};
use super::{Daemon, RequestError};
use crate::camera::PixelFormat;
use crate::files::{image, json, npy};
use crate::measure::sample_wall;
use crate::solve::lambda::NoiseLevel;
use crate::solve::reconstruct::Context;
use crate::solve::{reconstruct, tikhonov, SolveRequest, Solver};
use crate::store::{read_mean, JobState, ReconstructionRequest};

/// `POST /reconstructions` body.
#[derive(Debug, Clone, Deserialize, serde::Serialize, utoipa::ToSchema)]
#[serde(deny_unknown_fields)]
pub struct ReconstructionBody {
    /// Scene name.
    pub scene: String,
    /// One finished capture per (pose, polarizer angle) block of the scene.
    pub captures: Vec<i64>,
    /// `admm-tv` (default), `fista-tv`, `tikhonov` or `lsq`.
    #[serde(default)]
    pub solver: Solver,
    /// Regularization weight (MODEL.md units). Default for the TV solvers:
    /// chosen from the noise (resolved-discrepancy rule; `lambda_choice` in
    /// the report says how), the frame-to-frame noise when every capture has
    /// 2 frames or more, else the noise in the measurement's residual.
    pub lambda: Option<f64>,
    /// ADMM penalty.
    pub rho: Option<f64>,
    /// Iteration cap (1-100000).
    pub max_iter: Option<usize>,
    /// Tolerance in (0, 1).
    pub tol: Option<f64>,
    /// Relative singular-value cut-off of `lsq`.
    pub rcond: Option<f64>,
    /// Known truth, as a test pattern name (`disk`, `bars`, `letter`): the
    /// report then carries PSNR, ZNCC and SSIM (e.g. against the fake camera's demo scene).
    pub truth: Option<String>,
}

impl ReconstructionBody {
    /// The solver part of the request.
    pub fn solve_request(&self) -> SolveRequest {
        SolveRequest {
            solver: self.solver,
            lambda: self.lambda,
            rho: self.rho,
            max_iter: self.max_iter,
            tol: self.tol,
            rcond: self.rcond,
        }
    }
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
    let solve = b.solve_request();
    solve
        .check()
        .map_err(|e| RequestError::Invalid(e.to_string()))?;
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
            "scene {:?} has {} (pose, polarizer) blocks ({}); give exactly one capture for each ({} given)",
            b.scene,
            blocks.len(),
            blocks
                .iter()
                .map(|(p, a)| block_label(p, *a))
                .collect::<Vec<_>>()
                .join("; "),
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
                "capture {id} is {}, not done",
                c.state.name()
            )));
        }
        if c.is_dark() {
            return Err(RequestError::Invalid(format!(
                "capture {id} is a dark capture; give light captures (subtract darks with dark_capture when capturing)"
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
                    "capture {id} ({}) is not a block of scene {:?}",
                    block_label(&c.pose, c.polarizer_deg),
                    b.scene
                ))
            })?;
        if covered[k] {
            return Err(RequestError::Invalid(format!(
                "two captures for block {}; give one per block",
                block_label(&blocks[k].0, blocks[k].1)
            )));
        }
        if let Some(frame) = scene.pose(&c.pose).and_then(|p| p.frame) {
            if (c.region, c.binning) != (Some(frame.region), Some(frame.binning)) {
                return Err(RequestError::Invalid(format!(
                    "capture {id} was taken at region {} binning {}, but pose {:?}'s homography maps the wall into region {:?} binning {:?} (scene file keys region and binning): sampling it would read the wrong pixels; capture again with that region and binning, or calibrate the pose for this frame",
                    c.region.map_or("unknown".into(), |r| format!("{r:?}")),
                    c.binning.map_or("unknown".into(), |r| format!("{r:?}")),
                    c.pose,
                    frame.region,
                    frame.binning
                )));
            }
        }
        covered[k] = true;
    }
    Ok(ReconstructionRequest {
        scene: b.scene.clone(),
        captures: b.captures.clone(),
        solver: b.solver.name().to_string(),
        params: {
            let mut p = serde_json::to_value(&solve).unwrap_or_default();
            p["truth"] = serde_json::to_value(&b.truth).unwrap_or_default();
            p
        },
    })
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
            .map_err(JobError::from)
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
fn run_reconstruction(d: &Daemon, id: i64) -> Result<(), JobError> {
    let store = |e: crate::store::StoreError| JobError::Store(d.store.describe(&e));
    let rec = d.store.reconstruction(id).map_err(store)?;
    let scene = d.scenes.scene(&rec.scene)?;
    let t0 = Instant::now();
    let t = d.scenes.transport(&rec.scene)?;
    let transport_seconds = t0.elapsed().as_secs_f64();
    let Stacked {
        mut i,
        mut var,
        mut warnings,
    } = stack_captures(d, &rec, &scene, &t)?;
    if let Some(w) = scale(d, &rec.scene, &t, &mut i, &mut var)? {
        warnings.push(w);
    }
    let cond = d.scenes.conditioning(&rec.scene)?;
    // The stored request (older rows: the same keys, solver in its own column).
    let mut solve: SolveRequest = serde_json::from_value(rec.params.clone()).unwrap_or_default();
    solve.solver =
        serde_json::from_value(serde_json::Value::String(rec.solver.clone())).map_err(|_| {
            JobError::Store(format!("solver {:?} is not one polnlos knows", rec.solver))
        })?;
    let truth = rec
        .params
        .get("truth")
        .and_then(|v| v.as_str())
        .and_then(crate::simulate::patterns::Pattern::from_name)
        .map(|pat| pat.render(t.scene_grid));
    // Frame-to-frame noise when every capture has it; else reconstruct
    // estimates it from the measurement itself.
    let context = Context {
        scene: rec.scene.clone(),
        transport_seconds,
        truth: truth.as_deref(),
    };
    let solved = reconstruct(
        &t,
        &i,
        var.map(NoiseLevel::measured),
        &cond,
        &solve,
        context,
    )?;
    let (image, mut report) = (solved.image, solved.report);
    report.warnings.splice(0..0, warnings);
    let grid = t.scene_grid;
    let dir = d.store.reconstruction_dir(id);
    std::fs::create_dir_all(&dir).map_err(|e| JobError::Store(d.store.describe_io(&dir, &e)))?;
    let file = |e: crate::files::FileError| JobError::Store(d.store.redact_paths(&e.to_string()));
    npy::write_f64(&dir.join("recovered.npy"), &[grid.nv, grid.nu], &image).map_err(file)?;
    image::write_png16(
        &dir.join("image.png"),
        grid.nu,
        grid.nv,
        &image::unit_to_u16(&image),
    )
    .map_err(file)?;
    json::write(&dir.join("report.json"), &report).map_err(file)?;
    let text = serde_json::to_string(&report).map_err(|e| JobError::Store(e.to_string()))?;
    d.store
        .reconstruction_done(id, cond.kappa, &text)
        .map_err(store)
}

/// A reconstruction's measurement: the captures stacked in block order, the
/// variance of each element when every capture has it, and what the user
/// should know about the captures.
struct Stacked {
    i: Vec<f64>,
    var: Option<Vec<f64>>,
    warnings: Vec<String>,
}

/// Samples each capture's mean frame at the wall elements through its pose's
/// homography, in MODEL.md row order, in fractions of full scale per µs.
fn stack_captures(
    d: &Daemon,
    rec: &crate::store::ReconstructionRecord,
    scene: &crate::scene::Scene,
    t: &crate::transport::Transport,
) -> Result<Stacked, JobError> {
    // Stack the captures in block order: MODEL.md row order. The frame-to-frame
    // variance of each capture gives the measurement's noise, when there are
    // at least two frames per capture.
    let mut i = vec![0.0; t.rows()];
    let mut var = Some(vec![0.0; t.rows()]);
    let mut frame_warnings = Vec::new();
    for (b, block) in t.blocks.iter().enumerate() {
        let cap = rec
            .captures
            .iter()
            .filter_map(|&cid| d.store.capture(cid).ok())
            .find(|c| c.pose == block.pose && same_angle(c.polarizer_deg, block.polarizer_deg))
            .ok_or_else(|| JobError::Store(format!("no capture for block {}", block.label())))?;
        let capture = |reason: String| JobError::Capture { id: cap.id, reason };
        let pose = scene
            .pose(&block.pose)
            .ok_or_else(|| capture(format!("scene has no pose {:?} any more", block.pose)))?;
        let mean =
            read_mean(&d.store.capture_dir(cap.id)).map_err(|e| capture(d.store.describe(&e)))?;
        if let Some([_, _, w, h]) = cap.region {
            if (mean.width, mean.height) != (w as usize, h as usize) {
                return Err(capture(format!(
                    "its mean frame is {}x{}, but the capture recorded a {w}x{h} region; the files do not belong to this row",
                    mean.width, mean.height
                )));
            }
        }
        if cap.dark_frames == 0 && cap.dark_capture.is_none() {
            frame_warnings.push(format!(
                "capture {} has no dark subtraction: the camera's dark level is an offset that T cannot explain, and it can dominate the result; take dark_frames, or a dark capture named in dark_capture",
                cap.id
            ));
        }
        if pose.frame.is_none() {
            frame_warnings.push(format!(
                "pose {:?} does not say which camera frame its homography maps to (scene file keys region and binning), so capture {}'s frame ({}) could not be checked against it",
                pose.name,
                cap.id,
                cap.region.map_or("unknown region".into(), |r| format!("region {r:?}"))
            ));
        }
        let h =
            pose.homography
                .as_ref()
                .ok_or_else(|| crate::measure::MeasureError::NoHomography {
                    pose: pose.name.clone(),
                })?;
        let wall = sample_wall(&mean, h, &scene.wall.plane, &pose.name)
            .map_err(|e| capture(e.to_string()))?;
        let full = PixelFormat::from_name(&cap.pixel_format)
            .unwrap_or(PixelFormat::Mono16)
            .full_scale();
        // Fraction of full scale per microsecond: captures of different exposures compare.
        let to_units = 1.0 / full / cap.exposure_us;
        for (dst, v) in i[t.block_rows(b)].iter_mut().zip(wall) {
            *dst = v * to_units;
        }
        let frame_var = crate::store::read_mean_variance(&d.store.capture_dir(cap.id))
            .map_err(|e| capture(d.store.describe(&e)))?;
        match (frame_var, var.as_mut()) {
            (Some(fv), Some(acc)) => {
                let wall_var = sample_wall(&fv, h, &scene.wall.plane, &pose.name)
                    .map_err(|e| capture(e.to_string()))?;
                for (dst, v) in acc[t.block_rows(b)].iter_mut().zip(wall_var) {
                    *dst = v * to_units * to_units;
                }
            }
            _ => var = None,
        }
    }
    Ok(Stacked {
        i,
        var,
        warnings: frame_warnings,
    })
}

/// Puts the measurement (and its variance) in units of `T l`: by the
/// radiometric calibration, or, without one, so that the brightest element of
/// a Tikhonov solution is 1 (the box constraint needs some scale), which the
/// returned warning says.
fn scale(
    d: &Daemon,
    scene: &str,
    t: &crate::transport::Transport,
    i: &mut [f64],
    var: &mut Option<Vec<f64>>,
) -> Result<Option<String>, JobError> {
    if let Some(&c) = d.calibration.get(scene).filter(|c| **c > 0.0) {
        i.iter_mut().for_each(|v| *v /= c);
        var.iter_mut().flatten().for_each(|v| *v /= c * c);
        return Ok(None);
    }
    let probe = tikhonov(t, i, None)?;
    let unclipped_max = probe.image.iter().copied().fold(0.0, f64::max).max(1e-300);
    let fit = t.apply(&probe.image);
    let lsq_scale = fit
        .iter()
        .zip(i.iter())
        .map(|(a, b)| a * b)
        .sum::<f64>()
        .max(1e-300)
        / fit.iter().map(|a| a * a).sum::<f64>().max(1e-300);
    let s = lsq_scale * unclipped_max;
    i.iter_mut().for_each(|v| *v /= s);
    var.iter_mut().flatten().for_each(|v| *v /= s * s);
    Ok(Some("no radiometric calibration for this scene: the measurement was scaled so that the brightest element is about 1".to_string()))
}
