//! Progressive reconstruction while a capture accumulates frames: every
//! `every` frames the running mean (dark-subtracted) is sampled at the wall,
//! stacked with the other blocks' captures, and solved with ADMM-TV. Without
//! a λ in the request each step takes the final reconstruction's rule (the
//! resolved discrepancy of [`crate::solve::lambda`]) with the running
//! frame-to-frame variance, so a step is as good as reconstructing the same
//! frames afterwards; with a fixed λ (or a single frame, which has no
//! variance) it is warm-started from the previous step, its factorization
//! kept ([`AdmmState`]).
//! Each step is published: a `progressive` event, `progressive.png` (the
//! latest image) and `progressive.json` (every step) in the capture's folder.
//!
//! Steps run on their own thread and never hold the camera up: a snapshot
//! that arrives while a step is running is dropped; the final mean always
//! gets its step.

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc::{Receiver, SyncSender};
use std::sync::Arc;
use std::time::Instant;

use super::reconstruction::{load_capture, read_captures};
use super::{JobContext, JobError};
use crate::camera::{Acquisition, Frame};
use crate::daemon::requests::validate::ProgressiveSpec;
use crate::daemon::runtime::events::Step;
use crate::daemon::Event;
use crate::files::{image, json};
use crate::measure::FrameStack;
use crate::measure::{assemble_with, CaptureFrames, PixelMaps, Units};
use crate::scene::Scene;
use crate::solve::admm::{admm_tv_warm, AdmmSettings, AdmmState};
use crate::solve::gram::{adjoint, Normal};
use crate::solve::lambda::{admm_tv_resolved_prepared, NoiseLevel};
use crate::solve::reconstruct::AUTO_MAX_ITER;
use crate::solve::Reconstruction;
use crate::store::CaptureRecord;
use crate::store::Store;
use crate::transport::Transport;

/// File of the latest progressive image, in the capture's folder.
pub const IMAGE: &str = "progressive.png";
/// File of every progressive step, in the capture's folder.
pub const STEPS: &str = "progressive.json";

/// The running mean after some frames.
pub(in crate::daemon) struct Snapshot {
    /// Frames averaged.
    frames: usize,
    /// Per-pixel mean, DN (not dark-subtracted).
    mean: Vec<f64>,
    /// Per-pixel variance of that mean, DN², from 2 frames on.
    variance: Option<Vec<f64>>,
    /// Columns.
    width: usize,
    /// Rows.
    height: usize,
}

impl Snapshot {
    /// The mean of `frames` frames of `width` x `height` pixels (DN, not
    /// dark-subtracted) and the variance of that mean (from 2 frames on).
    pub(in crate::daemon) fn from_parts(
        frames: usize,
        mean: Vec<f64>,
        variance: Option<Vec<f64>>,
        width: usize,
        height: usize,
    ) -> Self {
        Self {
            frames,
            mean,
            variance,
            width,
            height,
        }
    }

    fn of(st: &FrameStack) -> Self {
        Self {
            frames: st.count,
            mean: st.mean.clone(),
            variance: st.variance_of_mean(),
            width: st.width,
            height: st.height,
        }
    }
}

/// Where a capture's frame writer hands the running mean to its progressive
/// solver: every `every` frames, and only when the solver is free (the mean
/// is copied only then), so the writer never waits.
#[derive(Clone)]
pub(in crate::daemon) struct Snapshots {
    tx: SyncSender<Snapshot>,
    /// A snapshot is waiting for the solver.
    pending: Arc<AtomicBool>,
    every: usize,
}

impl Snapshots {
    /// Offers the mean in `st` when it closes a step before frame `last`.
    pub(in crate::daemon) fn offer(&self, st: &FrameStack, last: usize) {
        if st.count % self.every != 0
            || st.count >= last
            || self.pending.swap(true, Ordering::SeqCst)
        {
            return;
        }
        if self.tx.try_send(Snapshot::of(st)).is_err() {
            self.pending.store(false, Ordering::SeqCst);
        }
    }

    /// The hand-over of the final mean, to run on a blocking thread: it
    /// waits for the solver, so the last step is always solved.
    pub(in crate::daemon) fn send_last(self, st: &FrameStack) -> impl FnOnce() + Send + 'static {
        let last = Snapshot::of(st);
        move || {
            let _ = self.tx.send(last);
        }
    }
}

/// A capture's progressive solver (also the live view's, over a capture
/// request that is never stored).
pub(in crate::daemon) struct Solver {
    t: Arc<Transport>,
    scene: Arc<Scene>,
    capture: CaptureRecord,
    /// The measurement with the other blocks' rows filled in, in units of `T l`.
    i: Vec<f64>,
    /// Its variance (the other blocks' from their captures), when every
    /// other block has one; this block's rows are filled at each step.
    variance: Option<Vec<f64>>,
    /// Singular values of `T`, for the automatic λ.
    singular_values: Arc<crate::solve::Conditioning>,
    /// This capture's blocks (one, or a mosaic pose's four), in `T`'s order.
    own: Vec<usize>,
    normal: Normal,
    state: AdmmState,
    settings: AdmmSettings<'static>,
    calibration: f64,
    /// The settings the capture is taken with.
    acquisition: Acquisition,
    /// Full scale of the capture's pixel format, DN.
    full_scale: f64,
    dark: Option<Frame>,
    /// The variance of the dark mean, added to each step's (MODEL.md `var_p`).
    dark_variance: Option<Frame>,
    truth: Option<Vec<f64>>,
    previous: Option<Vec<f64>>,
    steps: Vec<Step>,
    /// The pixel maps of the scene's poses, kept with the scene.
    maps: Arc<PixelMaps>,
    /// The scenes, for the model a step's noise asks for.
    scenes: Arc<crate::daemon::runtime::scenes::Scenes>,
    /// The key of the model `t` is (the scene's name, or a sampling variant's).
    key: String,
}

impl Solver {
    /// The solver of `capture`'s frames: its scene's cached `T`, Gram and
    /// conditioning, the other blocks' rows from `spec.captures`, and the
    /// dark mean (with its variance) subtracted from every snapshot.
    pub(in crate::daemon) fn new(
        d: &JobContext,
        capture: CaptureRecord,
        spec: &ProgressiveSpec,
        (dark, dark_variance): (Option<Frame>, Option<Frame>),
    ) -> Result<Self, JobError> {
        let scene = d.scenes.scene(&capture.scene)?;
        let t = d.scenes.transport(&capture.scene)?;
        let calibration = d.calibration.get(&capture.scene).copied().ok_or_else(|| {
            JobError::Capture {
                id: capture.id,
                reason: format!("progressive reconstruction needs the radiometric calibration of scene {:?} ([calibration] in the config)", capture.scene),
            }
        })?;
        let acquisition = Acquisition::try_from(&capture).map_err(|e| JobError::Capture {
            id: capture.id,
            reason: e.to_string(),
        })?;
        let full_scale = acquisition.pixel_format.full_scale();
        // This capture's block is filled at each step; the others come
        // from their captures, assembled as a reconstruction would.
        let own = crate::transport::Block::taken(t.blocks(), &capture.pose, &capture.channels);
        if own.len() != capture.channels.len() {
            return Err(JobError::Store("the capture's blocks are not in T".into()));
        }
        let mut warnings = Vec::new();
        let others = read_captures(&d.store, &spec.captures)?
            .into_iter()
            .map(|c| load_capture(&d.store, c, &scene, &mut warnings))
            .collect::<Result<Vec<_>, _>>()?;
        let other_blocks: Vec<_> = (0..t.blocks().len()).filter(|b| !own.contains(b)).collect();
        let blocks: Vec<_> = other_blocks
            .iter()
            .map(|&b| t.blocks()[b].clone())
            .collect();
        let maps = d.scenes.pixel_maps(&capture.scene);
        let mut m = assemble_with(&scene, &blocks, &others, &maps)?;
        Units::Calibrated(calibration).apply(&mut m);
        let mut i = vec![0.0; t.rows()];
        let mut variance = m.variance.as_ref().map(|_| vec![0.0; t.rows()]);
        let n = t.wall_grid().count();
        for (k, &b) in other_blocks.iter().enumerate() {
            i[t.block_rows(b)].copy_from_slice(&m.i[k * n..(k + 1) * n]);
            if let (Some(acc), Some(v)) = (variance.as_mut(), m.variance.as_ref()) {
                acc[t.block_rows(b)].copy_from_slice(&v[k * n..(k + 1) * n]);
            }
        }
        let normal = Normal::with(d.scenes.gram(&capture.scene)?, &t, &i);
        let truth = spec
            .truth
            .as_deref()
            .and_then(crate::simulate::patterns::Pattern::from_name)
            .map(|p| p.render(t.scene_grid()));
        let key = capture.scene.clone();
        Ok(Self {
            settings: AdmmSettings {
                lambda: spec.lambda,
                max_iter: spec.max_iter,
                ..AdmmSettings::default()
            },
            singular_values: d.scenes.conditioning(&capture.scene)?,
            variance,
            t,
            scene,
            capture,
            i,
            own,
            normal,
            state: AdmmState::default(),
            calibration,
            acquisition,
            full_scale,
            dark,
            dark_variance,
            truth,
            previous: None,
            steps: Vec::new(),
            maps,
            scenes: Arc::clone(&d.scenes),
            key,
        })
    }

    /// Solves from now on with the model cached under `key`: its `T`, Gram
    /// and conditioning, and a cold start (the old iterate fits another `T`).
    fn use_model(&mut self, key: String) -> Result<(), JobError> {
        self.t = self.scenes.transport(&key)?;
        self.normal = Normal::with(self.scenes.gram(&key)?, &self.t, &self.i);
        self.singular_values = self.scenes.conditioning(&key)?;
        self.state = AdmmState::default();
        self.key = key;
        Ok(())
    }

    /// Solves one snapshot; returns the step and the image.
    pub(in crate::daemon) fn step(&mut self, s: &Snapshot) -> Result<(Step, Vec<f64>), JobError> {
        let start = Instant::now();
        let own = self.own_frames(s);
        let noise = self.measure(own)?;
        let (r, lambda) = self.solve(noise)?;
        let step = self.record(s.frames, start, &r, lambda);
        Ok((step, r.image))
    }

    /// The scene grid its images are on.
    pub(in crate::daemon) fn grid(&self) -> crate::scene::Grid {
        self.t.scene_grid()
    }

    /// Forgets the steps recorded so far.
    /// Why: a live session solves for hours; only a capture keeps its steps.
    pub(in crate::daemon) fn forget_steps(&mut self) {
        self.steps.clear();
    }

    /// This capture's frames at snapshot `s`: the mean less the dark, its variance plus the dark's.
    /// Why: a step measures the running mean as a reconstruction measures a finished capture.
    fn own_frames(&self, s: &Snapshot) -> CaptureFrames {
        let pixels = s
            .mean
            .iter()
            .enumerate()
            .map(|(k, &v)| {
                let dark = self.dark.as_ref().and_then(|d| d.pixels.get(k)).copied();
                (v - f64::from(dark.unwrap_or(0.0))) as f32
            })
            .collect();
        let mean = Frame {
            width: s.width,
            height: s.height,
            pixels,
        };
        let dark_var = self
            .dark_variance
            .as_ref()
            .filter(|d| (d.width, d.height) == (s.width, s.height));
        let variance = s.variance.as_ref().map(|v| Frame {
            width: s.width,
            height: s.height,
            pixels: v
                .iter()
                .enumerate()
                .map(|(k, &x)| (x + dark_var.map_or(0.0, |d| f64::from(d.pixels[k]))) as f32)
                .collect(),
        });
        CaptureFrames {
            name: format!("capture {}", self.capture.id),
            pose: self.capture.pose.clone(),
            channels: self.capture.channels.clone(),
            mean,
            variance,
            frames: s.frames,
            full_scale: self.full_scale,
            exposure_us: self.acquisition.exposure_us,
            offset: [self.acquisition.region[0], self.acquisition.region[1]],
            binning: self.acquisition.binning,
            // An interim solve measures every pixel: a colour camera's raw
            // mean, as its grey.
            bayer: None,
        }
    }

    /// Fills this capture's rows of the measurement from `own`; returns the noise λ is chosen by.
    /// Why: the other blocks' rows stay as their captures set them; only this block moves.
    fn measure(&mut self, own: CaptureFrames) -> Result<Option<NoiseLevel>, JobError> {
        // This capture's blocks assembled as a reconstruction assembles them.
        let blocks: Vec<_> = self
            .own
            .iter()
            .map(|&k| self.t.blocks()[k].clone())
            .collect();
        let mut m = assemble_with(&self.scene, &blocks, &[own], &self.maps)?;
        Units::Calibrated(self.calibration).apply(&mut m);
        let n = self.t.wall_grid().count();
        for (k, &b) in self.own.iter().enumerate() {
            self.i[self.t.block_rows(b)].copy_from_slice(&m.i[k * n..(k + 1) * n]);
        }
        // The running variance of these blocks, beside the other blocks'.
        let noise = match (self.settings.lambda, m.variance, self.variance.as_mut()) {
            (None, Some(v), Some(all)) => {
                for (k, &b) in self.own.iter().enumerate() {
                    all[self.t.block_rows(b)].copy_from_slice(&v[k * n..(k + 1) * n]);
                }
                Some(NoiseLevel::measured(all.clone()))
            }
            _ => None,
        };
        Ok(noise)
    }

    /// Solves the measurement, λ resolved from `noise` if any, else warm-started; returns λ.
    /// Why: a step is as good as reconstructing the same frames afterwards.
    fn solve(
        &mut self,
        noise: Option<NoiseLevel>,
    ) -> Result<(Reconstruction, Option<f64>), JobError> {
        // The sampling the scene file leaves out, chosen from this step's noise
        // as a reconstruction of the same frames chooses it.
        if let Some(n) = &noise {
            let (key, _) = self.scenes.for_noise(&self.capture.scene, &n.variance)?;
            if key != self.key {
                self.use_model(key)?;
            }
        }
        self.normal.ti = adjoint(self.t.as_mat(), &self.i);
        Ok(match noise {
            Some(noise) => {
                let (r, choice) = admm_tv_resolved_prepared(
                    &self.t,
                    &self.i,
                    &self.normal,
                    &noise,
                    &self.singular_values.singular_values,
                    &AdmmSettings {
                        max_iter: self.settings.max_iter.max(AUTO_MAX_ITER),
                        ..self.settings
                    },
                )?;
                (r, Some(choice.lambda))
            }
            None => {
                let r = admm_tv_warm(
                    &self.t,
                    &self.i,
                    &self.normal,
                    &self.settings,
                    &mut self.state,
                )?;
                let lambda = r.stats.lambda;
                (r, lambda)
            }
        })
    }

    /// The step of solve `r` after `frames` frames, begun at `start`, kept with the others.
    /// Why: each step reports how far the image moved since the last one.
    fn record(
        &mut self,
        frames: usize,
        start: Instant,
        r: &Reconstruction,
        lambda: Option<f64>,
    ) -> Step {
        let norm = r
            .image
            .iter()
            .map(|v| v * v)
            .sum::<f64>()
            .sqrt()
            .max(1e-300);
        let change = self.previous.as_ref().map(|p| {
            p.iter()
                .zip(&r.image)
                .map(|(a, b)| (a - b) * (a - b))
                .sum::<f64>()
                .sqrt()
                / norm
        });
        let step = Step {
            frames,
            iterations: r.stats.iterations,
            converged: r.stats.converged,
            change,
            psnr_db: self
                .truth
                .as_ref()
                .map(|t| crate::solve::metrics::psnr(t, &r.image)),
            lambda,
            seconds: start.elapsed().as_secs_f64(),
        };
        self.previous = Some(r.image.clone());
        self.steps.push(step.clone());
        step
    }
}

/// Starts the progressive solver of capture `capture` (loading the other
/// blocks' captures and `T` on its own thread): returns where to send
/// snapshots, and the thread, which ends with every step when every
/// [`Snapshots`] is dropped (or at once, with none, if the solver cannot be
/// set up).
pub(in crate::daemon) fn start(
    d: &JobContext,
    capture: CaptureRecord,
    spec: &ProgressiveSpec,
    dark: (Option<Frame>, Option<Frame>),
) -> (Snapshots, tokio::task::JoinHandle<Vec<Step>>) {
    let (tx, rx) = std::sync::mpsc::sync_channel::<Snapshot>(1);
    let pending = Arc::new(AtomicBool::new(false));
    let snapshots = Snapshots {
        tx,
        pending: pending.clone(),
        every: spec.every,
    };
    let (d, spec) = (d.clone(), spec.clone());
    let handle = tokio::task::spawn_blocking(move || {
        let id = capture.id;
        match Solver::new(&d, capture, &spec, dark) {
            Ok(mut solver) => run(&d, &mut solver, rx, &pending),
            Err(e) => {
                tracing::warn!("capture-{id}: no progressive reconstruction: {e}");
                Vec::new()
            }
        }
    });
    (snapshots, handle)
}

fn run(
    d: &JobContext,
    solver: &mut Solver,
    rx: Receiver<Snapshot>,
    pending: &AtomicBool,
) -> Vec<Step> {
    let id = solver.capture.id;
    let dir = d.store.capture_dir(id);
    let grid = solver.t.scene_grid();
    for snapshot in rx {
        pending.store(false, Ordering::SeqCst);
        match solver.step(&snapshot) {
            Ok((step, img)) => {
                let png = image::write_png16(
                    &dir.join(IMAGE),
                    grid.nu,
                    grid.nv,
                    &image::unit_to_u16(&img),
                );
                let steps = json::write(&dir.join(STEPS), &solver.steps);
                if let Err(e) = png.and(steps) {
                    tracing::warn!("capture-{id}: progressive result not written: {e}");
                }
                d.events.emit(Event::Progressive {
                    job: format!("capture-{id}"),
                    step,
                });
            }
            Err(e) => {
                tracing::warn!("capture-{id}: progressive reconstruction stopped: {e}");
                break;
            }
        }
    }
    std::mem::take(&mut solver.steps)
}

/// Removes a capture's progressive files (when the capture did not finish).
pub(in crate::daemon) fn remove_files(store: &Store, id: i64) {
    let dir = store.capture_dir(id);
    let _ = std::fs::remove_file(dir.join(IMAGE));
    let _ = std::fs::remove_file(dir.join(STEPS));
}
