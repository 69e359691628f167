//! The reconstruction worker: turns a reconstruction's captures into a
//! measurement (each mean frame sampled at the wall elements through its
//! pose's homography, stacked in MODEL.md row order, in units of `T l`) and
//! runs [`crate::solve::reconstruct`] on it.

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::Instant;

use tokio::sync::{mpsc, Mutex};

use super::jobs::{finish_job, job_event, same_angle, Ending, JobError};
use super::Daemon;
use crate::camera::Frame;
use crate::camera::PixelFormat;
use crate::files::{image, json, npy};
use crate::measure::BlockFrames;
use crate::solve::lambda::NoiseLevel;
use crate::solve::reconstruct::Context;
use crate::solve::{reconstruct, tikhonov, SolveRequest, Stop};
use crate::store::{read_mean, JobState};

/// Takes reconstructions from the shared queue.
pub(super) async fn reconstruction_worker(d: Arc<Daemon>, rx: Arc<Mutex<mpsc::Receiver<i64>>>) {
    loop {
        let Some(id) = rx.lock().await.recv().await else {
            return;
        };
        let job = format!("reconstruction-{id}");
        let start = Instant::now();
        match d.store.reconstruction_running(id) {
            Ok(true) => {}
            // Cancelled while it waited in the queue.
            Ok(false) => {
                d.forget_cancel(&job);
                continue;
            }
            Err(e) => {
                tracing::error!("{job}: {e}");
                continue;
            }
        }
        job_event(&d, job.clone(), JobState::Running, None);
        let (d2, cancel) = (d.clone(), d.cancel_flag(&job));
        let r = tokio::task::spawn_blocking(move || run_reconstruction(&d2, id, &cancel))
            .await
            .map_err(JobError::from)
            .and_then(|r| r);
        let m = &d.metrics;
        let counters = (
            &m.reconstructions_done,
            &m.reconstructions_failed,
            &m.reconstruction_micros,
        );
        finish_job(&d, job, start, r, counters, |end| match end {
            Ending::Failed(e) => d.store.reconstruction_failed(id, e),
            Ending::Cancelled => d.store.reconstruction_cancelled(id).map(|_| ()),
        });
    }
}

/// `Err(Cancelled)` once a client has cancelled the job.
fn check(cancel: &AtomicBool) -> Result<(), JobError> {
    if cancel.load(Ordering::SeqCst) {
        Err(JobError::Cancelled)
    } else {
        Ok(())
    }
}

/// Frames to `i` through the homographies, the solve, and the files; a
/// cancellation is noticed between these stages and inside the solve (every
/// [`Stop::EVERY`] iterations), and nothing is written after it.
fn run_reconstruction(d: &Daemon, id: i64, cancel: &AtomicBool) -> Result<(), JobError> {
    let store = |e: crate::store::StoreError| JobError::Store(d.store.describe(&e));
    let rec = d.store.reconstruction(id).map_err(store)?;
    let scene = d.scenes.scene(&rec.scene)?;
    let t0 = Instant::now();
    let t = d.scenes.transport(&rec.scene)?;
    let transport_seconds = t0.elapsed().as_secs_f64();
    check(cancel)?;
    let Stacked {
        mut i,
        mut var,
        mut warnings,
    } = stack_captures(d, &rec, &scene, &t)?;
    if let Some(w) = scale(d, &rec.scene, &t, &mut i, &mut var)? {
        warnings.push(w);
    }
    let cond = d.scenes.conditioning(&rec.scene)?;
    check(cancel)?;
    let solve = stored_solve(&rec)?;
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
        stop: Stop::on(cancel),
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
    let measurement = i;
    check(cancel)?;
    report.warnings.splice(0..0, warnings);
    let grid = t.scene_grid;
    let dir = d.store.reconstruction_dir(id);
    std::fs::create_dir_all(&dir).map_err(|e| JobError::Store(d.store.describe_io(&dir, &e)))?;
    let file = |e: crate::files::FileError| JobError::Store(d.store.redact_paths(&e.to_string()));
    npy::write_f64(&dir.join("recovered.npy"), &[grid.nv, grid.nu], &image).map_err(file)?;
    // The stacked measurement it solved (units of T l, MODEL.md row order),
    // so a user can re-solve it offline with `polnlos reconstruct`.
    npy::write_f64(
        &dir.join("measurement.npy"),
        &[measurement.len()],
        &measurement,
    )
    .map_err(file)?;
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
pub(super) struct Stacked {
    pub(super) i: Vec<f64>,
    pub(super) var: Option<Vec<f64>>,
    pub(super) warnings: Vec<String>,
}

/// Reads each block's capture (in MODEL.md block order) and stacks them into
/// the measurement with [`stack_records`].
fn stack_captures(
    d: &Daemon,
    rec: &crate::store::ReconstructionRecord,
    scene: &crate::scene::Scene,
    t: &crate::transport::Transport,
) -> Result<Stacked, JobError> {
    let records = read_captures(d, &rec.captures)?;
    let ordered = t
        .blocks
        .iter()
        .map(|block| capture_for_block(&records, block).cloned())
        .collect::<Result<Vec<_>, _>>()?;
    stack_records(d, ordered, scene)
}

/// The solve a reconstruction row asks for: its parameters (the same keys
/// as [`SolveRequest`]; none stored means the defaults) and its solver
/// column. Parameters that do not read as a request are an error naming
/// the row, never silently the defaults: a stored λ must not turn automatic.
fn stored_solve(rec: &crate::store::ReconstructionRecord) -> Result<SolveRequest, JobError> {
    let mut solve: SolveRequest = match &rec.params {
        serde_json::Value::Null => SolveRequest::default(),
        p => serde_json::from_value(p.clone()).map_err(|e| {
            JobError::Store(format!(
                "reconstruction {}: its stored parameters cannot be read ({e})",
                rec.id
            ))
        })?,
    };
    solve.solver =
        serde_json::from_value(serde_json::Value::String(rec.solver.clone())).map_err(|_| {
            JobError::Store(format!("solver {:?} is not one polnlos knows", rec.solver))
        })?;
    Ok(solve)
}

/// Captures in block order (each at its own pose) stacked into the
/// measurement with [`crate::measure::stack`], in fractions of full scale
/// per µs; the variance comes with it when every capture has 2 frames or more.
pub(super) fn stack_records(
    d: &Daemon,
    ordered: Vec<crate::store::CaptureRecord>,
    scene: &crate::scene::Scene,
) -> Result<Stacked, JobError> {
    let mut warnings = Vec::new();
    let loaded = ordered
        .into_iter()
        .map(|c| load_capture(d, c, scene, &mut warnings))
        .collect::<Result<Vec<_>, _>>()?;
    let blocks: Vec<BlockFrames<'_>> = loaded.iter().map(Loaded::block).collect();
    let m = crate::measure::stack(&blocks, &scene.wall.plane)?;
    Ok(Stacked {
        i: m.i,
        var: m.variance,
        warnings,
    })
}

/// The catalogue records of `ids`, each read once. A catalogue that cannot
/// be read is that error, not "no capture".
pub(super) fn read_captures(
    d: &Daemon,
    ids: &[i64],
) -> Result<Vec<crate::store::CaptureRecord>, JobError> {
    ids.iter()
        .map(|&id| {
            d.store
                .capture(id)
                .map_err(|e| JobError::Store(format!("capture {id}: {}", d.store.describe(&e))))
        })
        .collect()
}

/// Whether capture `c` was taken at `block`'s pose and polarizer angle.
pub(super) fn serves(c: &crate::store::CaptureRecord, block: &crate::transport::Block) -> bool {
    c.pose == block.pose && same_angle(c.polarizer_deg, block.polarizer_deg)
}

/// The capture among `records` that serves `block`.
pub(super) fn capture_for_block<'r>(
    records: &'r [crate::store::CaptureRecord],
    block: &crate::transport::Block,
) -> Result<&'r crate::store::CaptureRecord, JobError> {
    records
        .iter()
        .find(|c| serves(c, block))
        .ok_or_else(|| JobError::Store(format!("no capture for block {}", block.label())))
}

/// A capture's files as a block of the measurement needs them.
pub(super) struct Loaded<'a> {
    capture: crate::store::CaptureRecord,
    pose: &'a crate::scene::Pose,
    homography: crate::scene::Homography,
    mean: Frame,
    variance: Option<Frame>,
}

impl Loaded<'_> {
    /// The block as [`crate::measure::stack`] takes it.
    pub(super) fn block(&self) -> BlockFrames<'_> {
        BlockFrames {
            pose: &self.pose.name,
            homography: &self.homography,
            mean: &self.mean,
            variance: self.variance.as_ref(),
            frames: self.capture.frames as usize,
            full_scale: PixelFormat::from_name(&self.capture.pixel_format)
                .unwrap_or(PixelFormat::Mono16)
                .full_scale(),
            exposure_us: self.capture.exposure_us,
        }
    }
}

/// Reads a capture's mean (and variance) frame, checks it is the frame the
/// capture recorded, and notes what the user should know about it; the
/// homography is that of the capture's own pose in `scene`.
pub(super) fn load_capture<'a>(
    d: &Daemon,
    cap: crate::store::CaptureRecord,
    scene: &'a crate::scene::Scene,
    warnings: &mut Vec<String>,
) -> Result<Loaded<'a>, JobError> {
    let id = cap.id;
    let capture = |reason: String| JobError::Capture { id, reason };
    let pose = scene
        .pose(&cap.pose)
        .ok_or_else(|| capture(format!("scene has no pose {:?} any more", cap.pose)))?;
    let homography = pose
        .homography
        .ok_or_else(|| crate::measure::MeasureError::NoHomography {
            pose: pose.name.clone(),
        })?;
    let dir = d.store.capture_dir(id);
    let mean = read_mean(&dir).map_err(|e| capture(d.store.describe(&e)))?;
    if let Some([_, _, w, h]) = cap.region {
        if (mean.width, mean.height) != (w as usize, h as usize) {
            return Err(capture(format!(
                "its mean frame is {}x{}, but the capture recorded a {w}x{h} region; the files do not belong to this row",
                mean.width, mean.height
            )));
        }
    }
    if cap.dark_frames == 0 && cap.dark_capture.is_none() {
        warnings.push(format!(
            "capture {id} has no dark subtraction: the camera's dark level is an offset that T cannot explain, and it can dominate the result; take dark_frames, or a dark capture named in dark_capture"
        ));
    }
    if pose.frame.is_none() {
        warnings.push(format!(
            "pose {:?} does not say which camera frame its homography maps to (scene file keys region and binning), so capture {id}'s frame ({}) could not be checked against it",
            pose.name,
            cap.region.map_or("unknown region".into(), |r| format!("region {r:?}"))
        ));
    }
    let variance =
        crate::store::read_mean_variance(&dir).map_err(|e| capture(d.store.describe(&e)))?;
    Ok(Loaded {
        capture: cap,
        pose,
        homography,
        mean,
        variance,
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::store::{JobState, ReconstructionRecord};

    fn row(solver: &str, params: serde_json::Value) -> ReconstructionRecord {
        ReconstructionRecord {
            id: 7,
            scene: "brewster-crossed".into(),
            captures: vec![1],
            solver: solver.into(),
            params,
            state: JobState::Queued,
            error: None,
            created_at: String::new(),
            started_at: None,
            finished_at: None,
            kappa: None,
            report: None,
        }
    }

    #[test]
    fn a_stored_request_is_read_back_or_refused_never_defaulted() {
        let s = stored_solve(&row(
            "fista-tv",
            serde_json::json!({"lambda": 0.25, "max_iter": 40, "truth": "disk"}),
        ))
        .unwrap();
        assert_eq!(s.solver, crate::solve::Solver::FistaTv);
        assert_eq!((s.lambda, s.max_iter), (Some(0.25), Some(40)));
        // No parameters stored: the defaults.
        let s = stored_solve(&row("admm-tv", serde_json::Value::Null)).unwrap();
        assert_eq!(s.lambda, None);
        // A damaged λ is an error naming the row, not the automatic λ.
        let e = stored_solve(&row("admm-tv", serde_json::json!({"lambda": "much"})))
            .unwrap_err()
            .to_string();
        assert!(
            e.starts_with("reconstruction 7: its stored parameters cannot be read"),
            "{e}"
        );
        let e = stored_solve(&row("sgd", serde_json::json!({}))).unwrap_err();
        assert_eq!(e.to_string(), "solver \"sgd\" is not one polnlos knows");
    }
}
