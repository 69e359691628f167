//! Progressive reconstruction while a capture accumulates frames: every
//! `every` frames the running mean (dark-subtracted) is sampled at the wall,
//! stacked with the other blocks' captures, and solved with ADMM-TV. Without
//! a λ in the request each step takes the final reconstruction's rule (the
//! resolved discrepancy of [`crate::solve::lambda`]) with the running
//! frame-to-frame variance, so a step is as good as reconstructing the same
//! frames afterwards (the λ a search chose is kept, warm-started, while the
//! noise stays within [`LAMBDA_KEPT`] of the noise it was chosen at: a live
//! view's windows all have one noise); with a fixed λ (or a single frame, which has no
//! variance) it is warm-started from the previous step, its factorization
//! kept ([`Warm`]).
//! Each step is published: a `progressive` event, `progressive.png` (the
//! latest image) and `progressive.json` (every step) in the capture's folder.
//!
//! Steps run on their own thread and never hold the camera up: a snapshot
//! that arrives while a step is running is dropped; the final mean always
//! gets its step.

use rayon::prelude::*;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc::{Receiver, SyncSender};
use std::sync::Arc;
use std::time::Instant;

use super::reconstruction::{load_capture, read_captures};
use super::{JobContext, JobError};
use crate::camera::Acquisition;
use crate::daemon::requests::validate::ProgressiveSpec;
use crate::daemon::runtime::events::Step;
use crate::daemon::runtime::scenes::Scenes;
use crate::daemon::Event;
use crate::files::{image, json};
use crate::measure::colour::Colour;
use crate::measure::FrameStack;
use crate::measure::{assemble_colour, CaptureFrames, PixelMaps, Units};
use crate::scene::{Frame, Scene};
use crate::solve::gram::{adjoint, Normal};
use crate::solve::lambda::{admm_tv_resolved_prepared, NoiseLevel};
use crate::solve::solvers::Warm;
use crate::solve::Reconstruction;
use crate::solve::AUTO_MAX_ITER;
use crate::solve::{AdmmSettings, Solver};
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
        if !st.count.is_multiple_of(self.every)
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
pub(in crate::daemon) struct Progressive {
    scene: Arc<Scene>,
    capture: CaptureRecord,
    /// One solve per colour of a colour camera (red, green, blue), else one.
    channels: Vec<Channel>,
    /// This capture's blocks (one, or a mosaic pose's four), in `T`'s order.
    own: Vec<usize>,
    settings: AdmmSettings<'static>,
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
    scenes: Arc<Scenes>,
}

/// One colour's solve (a grey camera's only one): its measurement, its
/// model and the solver's state between steps.
struct Channel {
    /// The Bayer colour measured, `None` for every pixel as it is.
    colour: Option<Colour>,
    /// Its radiometric gain: the scene's, times the colour's ratio when the
    /// scene has a colour calibration.
    gain: f64,
    t: Arc<Transport>,
    /// The measurement with the other blocks' rows filled in, in units of `T l`.
    i: Vec<f64>,
    /// Its variance (the other blocks' from their captures), when every
    /// other block has one; this block's rows are filled at each step.
    variance: Option<Vec<f64>>,
    /// Singular values of `T`, for the automatic λ.
    singular_values: Arc<crate::solve::Conditioning>,
    normal: Normal,
    state: Warm,
    /// The key of the model `t` is (the scene's name, or a sampling variant's).
    key: String,
    /// The λ the last search chose and the mean noise variance it chose it
    /// at: a window whose noise is within [`LAMBDA_KEPT`] of it keeps it.
    chosen: Option<(f64, f64)>,
}

/// How far (relative) a step's mean noise variance may move from the one
/// its λ was searched at before λ is searched again.
/// Why: a search is about twenty solves; a live view's windows (the same
/// frames count, the same exposure) all have one noise, and a λ within a
/// few percent of the search's gives the same image. On a chair-size scene
/// (1044 unknowns, three colours) the search of every window held live
/// view to 0.16 results a second.
const LAMBDA_KEPT: f64 = 0.1;

impl Progressive {
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
        // A colour camera's steps are in colour, as its reconstruction is,
        // when every other block's capture is in colour too.
        let colours: Vec<Option<Colour>> = match acquisition.pixel_format.bayer().is_some()
            && others.iter().all(|c| c.bayer.is_some())
        {
            true => Colour::ALL.map(Some).to_vec(),
            false => vec![None],
        };
        let balance = match colours.len() {
            1 => None,
            _ => d
                .store
                .colour_calibration(&capture.scene)
                .map_err(|e| JobError::Store(e.to_string()))?,
        };
        let other_blocks: Vec<_> = (0..t.blocks().len()).filter(|b| !own.contains(b)).collect();
        let blocks: Vec<_> = other_blocks
            .iter()
            .map(|&b| t.blocks()[b].clone())
            .collect();
        let maps = d.scenes.pixel_maps(&capture.scene);
        let gram = d.scenes.gram(&capture.scene)?;
        let singular_values = d.scenes.conditioning(&capture.scene)?;
        let n = t.wall_grid().count();
        let mut channels = Vec::with_capacity(colours.len());
        for colour in colours {
            let gain = match (&balance, colour) {
                (Some(b), Some(c)) => b.balance.gain(c, calibration),
                _ => calibration,
            };
            let mut m = assemble_colour(&scene, &blocks, &others, &maps, colour)?;
            Units::Calibrated(gain).apply(&mut m);
            let mut i = vec![0.0; t.rows()];
            let mut variance = m.variance.as_ref().map(|_| vec![0.0; t.rows()]);
            for (k, &b) in other_blocks.iter().enumerate() {
                i[t.block_rows(b)].copy_from_slice(&m.i[k * n..(k + 1) * n]);
                if let (Some(acc), Some(v)) = (variance.as_mut(), m.variance.as_ref()) {
                    acc[t.block_rows(b)].copy_from_slice(&v[k * n..(k + 1) * n]);
                }
            }
            channels.push(Channel {
                colour,
                gain,
                normal: Normal::with(Arc::clone(&gram), &t, &i),
                t: Arc::clone(&t),
                i,
                variance,
                singular_values: Arc::clone(&singular_values),
                state: Warm::default(),
                key: capture.scene.clone(),
                chosen: None,
            });
        }
        let truth = spec
            .truth
            .as_deref()
            .and_then(crate::simulate::patterns::Pattern::from_name)
            .map(|p| p.render(t.scene_grid()));
        Ok(Self {
            settings: AdmmSettings {
                lambda: spec.lambda,
                max_iter: spec.max_iter,
                ..AdmmSettings::default()
            },
            channels,
            scene,
            capture,
            own,
            acquisition,
            full_scale,
            dark,
            dark_variance,
            truth,
            previous: None,
            steps: Vec::new(),
            maps,
            scenes: Arc::clone(&d.scenes),
        })
    }

    /// Solves one snapshot; returns the step and the image (a colour
    /// camera's colours interleaved, red, green, blue per element).
    pub(in crate::daemon) fn step(&mut self, s: &Snapshot) -> Result<(Step, Vec<f64>), JobError> {
        let start = Instant::now();
        let own = self.own_frames(s);
        let blocks: Vec<_> = self
            .own
            .iter()
            .map(|&k| self.channels[0].t.blocks()[k].clone())
            .collect();
        // A colour camera's colours are independent solves: in parallel.
        let (scene, maps, own_blocks) = (&self.scene, &self.maps, &self.own);
        let (scenes, name, settings) = (&self.scenes, &self.capture.scene, &self.settings);
        let mut solved = self
            .channels
            .par_iter_mut()
            .map(|ch| {
                let m =
                    assemble_colour(scene, &blocks, std::slice::from_ref(&own), maps, ch.colour)?;
                let noise = ch.measure(m, own_blocks, settings.lambda);
                ch.solve(noise, scenes, name, settings)
            })
            .collect::<Result<Vec<_>, JobError>>()?;
        // A colour image is interleaved once, for the step and the caller.
        let colour = (solved.len() > 1).then(|| interleave(&solved));
        let image = colour.as_deref().unwrap_or(&solved[0].0.image);
        let step = self.record(s.frames, start, &solved, image);
        let image = colour.unwrap_or_else(|| solved.swap_remove(0).0.image);
        Ok((step, image))
    }

    /// The scene grid its images are on.
    pub(in crate::daemon) fn grid(&self) -> crate::scene::Grid {
        self.channels[0].t.scene_grid()
    }

    /// Colours in each image element: 3 for a colour camera, else 1.
    pub(in crate::daemon) fn colours(&self) -> usize {
        self.channels.len()
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
            // A colour camera's mean is measured per colour.
            bayer: match self.channels.len() {
                1 => None,
                _ => self.acquisition.pixel_format.bayer(),
            },
        }
    }

    /// The step of the colours' solves `solved` (their `image`, interleaved) after `frames` frames,
    /// begun at `start`, kept with the others.
    /// Why: each step reports how far the image moved since the last one.
    fn record(
        &mut self,
        frames: usize,
        start: Instant,
        solved: &[(Reconstruction, Option<f64>)],
        image: &[f64],
    ) -> Step {
        let norm = image.iter().map(|v| v * v).sum::<f64>().sqrt().max(1e-300);
        let change = self.previous.as_ref().map(|p| {
            p.iter()
                .zip(image)
                .map(|(a, b)| (a - b) * (a - b))
                .sum::<f64>()
                .sqrt()
                / norm
        });
        let c = solved.len();
        let step = Step {
            frames,
            iterations: solved
                .iter()
                .map(|(r, _)| r.stats.iterations)
                .max()
                .unwrap_or(0),
            converged: solved.iter().all(|(r, _)| r.stats.converged),
            change,
            psnr_db: self.truth.as_ref().map(|t| {
                let each: Vec<f64> = t.iter().flat_map(|&v| std::iter::repeat_n(v, c)).collect();
                crate::solve::metrics::psnr(&each, image)
            }),
            // The middle colour's (green's) λ: one number per step.
            lambda: solved[c / 2].1,
            seconds: start.elapsed().as_secs_f64(),
        };
        self.previous = Some(image.to_vec());
        self.steps.push(step.clone());
        step
    }
}

/// The colours' images interleaved: red, green, blue per element.
fn interleave(solved: &[(Reconstruction, Option<f64>)]) -> Vec<f64> {
    let n = solved[0].0.image.len();
    (0..n)
        .flat_map(|k| solved.iter().map(move |(r, _)| r.image[k]))
        .collect()
}

impl Channel {
    /// Fills this capture's rows of the measurement from `m` (this
    /// capture's blocks, in the order of `own`); returns the noise λ is
    /// chosen by (none with a fixed `lambda`).
    /// Why: the other blocks' rows stay as their captures set them; only this block moves.
    fn measure(
        &mut self,
        mut m: crate::measure::Measurement,
        own: &[usize],
        lambda: Option<f64>,
    ) -> Option<NoiseLevel> {
        Units::Calibrated(self.gain).apply(&mut m);
        let n = self.t.wall_grid().count();
        for (k, &b) in own.iter().enumerate() {
            self.i[self.t.block_rows(b)].copy_from_slice(&m.i[k * n..(k + 1) * n]);
        }
        // The running variance of these blocks, beside the other blocks'.
        match (lambda, m.variance, self.variance.as_mut()) {
            (None, Some(v), Some(all)) => {
                for (k, &b) in own.iter().enumerate() {
                    all[self.t.block_rows(b)].copy_from_slice(&v[k * n..(k + 1) * n]);
                }
                Some(NoiseLevel::measured(all.clone()))
            }
            _ => None,
        }
    }

    /// Solves from now on with the model cached under `key`: its `T`, Gram
    /// and conditioning, and a cold start (the old iterate fits another `T`).
    fn use_model(&mut self, scenes: &Scenes, key: String) -> Result<(), JobError> {
        self.t = scenes.transport(&key)?;
        self.normal = Normal::with(scenes.gram(&key)?, &self.t, &self.i);
        self.singular_values = scenes.conditioning(&key)?;
        self.state = Warm::default();
        self.key = key;
        self.chosen = None;
        Ok(())
    }

    /// Solves the measurement, λ resolved from `noise` if any (or the last
    /// search's λ, warm-started, while the noise stays within
    /// [`LAMBDA_KEPT`] of the noise it was searched at), else warm-started;
    /// returns λ.
    /// Why: a step is as good as reconstructing the same frames afterwards.
    fn solve(
        &mut self,
        noise: Option<NoiseLevel>,
        scenes: &Scenes,
        scene: &str,
        settings: &AdmmSettings<'static>,
    ) -> Result<(Reconstruction, Option<f64>), JobError> {
        // The sampling the scene file leaves out, chosen from this step's noise
        // as a reconstruction of the same frames chooses it.
        if let Some(n) = &noise {
            let (key, _) = scenes.for_noise(scene, &n.variance)?;
            if key != self.key {
                self.use_model(scenes, key)?;
            }
        }
        self.normal.ti = adjoint(self.t.as_mat(), &self.i);
        let kept = match (&noise, self.chosen) {
            (Some(n), Some((lambda, at))) => {
                ((n.mean_variance() / at - 1.0).abs() <= LAMBDA_KEPT).then_some(lambda)
            }
            _ => None,
        };
        Ok(match (noise, kept) {
            (Some(_), Some(lambda)) => {
                let at = AdmmSettings {
                    lambda: Some(lambda),
                    max_iter: settings.max_iter.max(AUTO_MAX_ITER),
                    ..*settings
                };
                let p = at.problem(&self.t, &self.i, &self.normal);
                let r = Solver::ADMM_TV.solve(&p, &mut self.state)?;
                (r, Some(lambda))
            }
            (Some(noise), None) => {
                let (r, choice) = admm_tv_resolved_prepared(
                    &self.t,
                    &self.i,
                    &self.normal,
                    &noise,
                    &self.singular_values.singular_values,
                    &AdmmSettings {
                        max_iter: settings.max_iter.max(AUTO_MAX_ITER),
                        ..*settings
                    },
                )?;
                self.chosen = Some((choice.lambda, noise.mean_variance()));
                (r, Some(choice.lambda))
            }
            (None, _) => {
                let p = settings.problem(&self.t, &self.i, &self.normal);
                let r = Solver::ADMM_TV.solve(&p, &mut self.state)?;
                let lambda = r.stats.lambda;
                (r, lambda)
            }
        })
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
        match Progressive::new(&d, capture, &spec, dark) {
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
    solver: &mut Progressive,
    rx: Receiver<Snapshot>,
    pending: &AtomicBool,
) -> Vec<Step> {
    let id = solver.capture.id;
    let dir = d.store.capture_dir(id);
    let grid = solver.grid();
    let colours = solver.colours();
    for snapshot in rx {
        pending.store(false, Ordering::SeqCst);
        match solver.step(&snapshot) {
            Ok((step, img)) => {
                let pixels = image::unit_to_u16(&img);
                let path = dir.join(IMAGE);
                let png = match colours {
                    3 => image::write_png_rgb16(&path, grid.nu, grid.nv, &pixels),
                    _ => image::write_png16(&path, grid.nu, grid.nv, &pixels),
                };
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
