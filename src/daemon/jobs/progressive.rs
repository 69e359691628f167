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
//! A scene whose radiometry is fitted (no calibrated gain, colours with no
//! colour calibration, or `"radiometry": "fitted"` asked) has each step fit
//! gain and background per colour with the scene, as its reconstruction
//! does ([`PhotoStream`]): λ searched on the first step, then kept while the
//! data hold, each step started from where that search ended.
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
use crate::daemon::runtime::events::{FittedStep, Step};
use crate::daemon::runtime::scenes::Scenes;
use crate::daemon::Event;
use crate::files::{image, json};
use crate::measure::colour::Colour;
use crate::measure::FrameStack;
use crate::measure::{assemble_colour, CaptureFrames, PixelMaps, Units};
use crate::scene::{Frame, Scene};
use crate::solve::gram::{adjoint, Normal};
use crate::solve::lambda::{admm_tv_resolved_prepared, NoiseLevel};
use crate::solve::photo::{photo_transport, PhotoSettings, PhotoStream};
use crate::solve::radiometry::{Known, Radiometry, RadiometryChoice};
use crate::solve::solvers::Warm;
use crate::solve::Reconstruction;
use crate::solve::{AdmmSettings, Solver};
use crate::solve::{AUTO_MAX_ITER, LAMBDA_KEPT};
use crate::stop::Stop;
use crate::store::Store;
use crate::store::{CaptureRecord, ColourCalibrationRow};
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
    /// When its frames were taken: their mean arrival time, Unix seconds
    /// (a live window's; a capture's snapshots have none).
    time_s: Option<f64>,
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
            time_s: None,
        }
    }

    /// The same snapshot, its frames taken at `time_s` (Unix seconds).
    pub(in crate::daemon) fn at(mut self, time_s: f64) -> Self {
        self.time_s = Some(time_s);
        self
    }

    /// When its frames were taken, Unix seconds (a live window's).
    pub(in crate::daemon) fn time_s(&self) -> Option<f64> {
        self.time_s
    }

    fn of(st: &FrameStack) -> Self {
        Self {
            frames: st.count,
            mean: st.mean.clone(),
            variance: st.variance_of_mean(),
            width: st.width,
            height: st.height,
            time_s: None,
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
    /// Live view's difference mode: how the running background is kept.
    difference: Option<Background>,
    /// The radiometry of every step, and why.
    radiometry: RadiometryChoice,
    /// A fitted radiometry's fit of the stream of steps, formed at its
    /// first step (which settles the scene's shadows, as a reconstruction's
    /// photo does).
    stream: Option<PhotoStream<Arc<Transport>>>,
    /// Calibrated colours: solved together at one λ, as a reconstruction
    /// solves them (docs/guide.md, "Colours solved together"), from this
    /// state of the last step's joint solve and the key of the model it
    /// was on (a new model starts cold). `None`: each colour alone.
    together: Option<(Warm, String)>,
}

/// How far below zero difference mode's images may go, in MODEL.md
/// radiance units (`Channel::solve`): a change of radiances in `[0, 1]`.
const DIFFERENCE_OFFSET: f64 = 1.0;

/// Live view's difference mode: each window's measurement of this
/// capture's blocks less a running background of the windows before it
/// (kept per colour in [`Channel::background`]) is solved, so the image is
/// the scene's change (`T` is linear).
///
/// The background is the plain mean of the windows so far until they span
/// about `tau_s` (weight `1 / n` for the `n`-th window), then an exponential
/// running mean with time constant `tau_s` (weight `1 - exp(-dt / tau_s)`,
/// `dt` the time since the window before): whichever weight is larger.
/// Why: the plain mean settles at once, an exponential one started from
/// the first window would keep that window's object for `tau_s`; the
/// exponential one then forgets a scene that changed for good.
struct Background {
    /// Time constant, seconds.
    tau_s: f64,
    /// Windows taken into it.
    windows: u64,
    /// The newest window's time, Unix seconds.
    last_s: Option<f64>,
    /// The background's noise variance over a window's (windows taken as
    /// independent: an upper bound when they share frames).
    carried: f64,
    /// Whether the newest difference stood out of its noise (`None`: no
    /// variance to tell by, or the first window).
    moved: Option<bool>,
}

impl Background {
    /// The weight the window taken at `time_s` has in the background, and
    /// the variance of its difference from the background over the
    /// window's own (`1 +` the background's share).
    fn weigh(&mut self, time_s: Option<f64>) -> (f64, f64) {
        let dt = match (self.last_s, time_s) {
            (Some(a), Some(b)) => (b - a).max(0.0),
            _ => 0.0,
        };
        self.windows += 1;
        self.last_s = time_s.or(self.last_s);
        let w = (1.0 / self.windows as f64).max(-(-dt / self.tau_s).exp_m1());
        let spread = 1.0 + self.carried;
        self.carried = (1.0 - w).powi(2) * self.carried + w * w;
        (w, spread)
    }

    /// Records the difference's chi-square `chi2` over `rows` rows: a
    /// change when it exceeds its expectation under noise alone (`rows`)
    /// by [`CHANGE_SIGMAS`] of its standard deviation (`sqrt(2 rows)`).
    fn judge(&mut self, chi2: Option<(f64, usize)>) {
        self.moved = chi2.map(|(c, m)| c > m as f64 + CHANGE_SIGMAS * (2.0 * m as f64).sqrt());
    }
}

/// How far above noise alone (in standard deviations of its chi-square) a
/// difference must be to be a change.
/// Why 3: noise alone passes it at about 0.1 % of windows (the Gaussian
/// tail; the chi-square of a thousand rows is near Gaussian).
const CHANGE_SIGMAS: f64 = 3.0;

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
    /// The λ the last search chose, and the mean noise variance and the
    /// measurement's norm it chose it at: a window whose noise and norm are
    /// within [`LAMBDA_KEPT`] of them keeps it.
    chosen: Option<(f64, f64, f64)>,
    /// Difference mode's running background of this capture's rows (in the
    /// order of `own`; NaN until a window measured the row).
    background: Vec<f64>,
    /// `T 1`, the wall image of a uniform unit scene under the model in
    /// use: difference mode's offset (`Channel::solve`), formed once a model.
    t_ones: Option<Vec<f64>>,
}

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
        let calibration = d.calibration.get(&capture.scene).copied();
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
        let radiometry = choose_radiometry(spec, &capture, calibration, colours.len(), &balance);
        // Calibrated: divided by the gain; fitted: as measured (the fit
        // finds the gain).
        let calibration = match radiometry.mode {
            Radiometry::Fitted => 1.0,
            Radiometry::Calibrated => calibration.ok_or_else(|| JobError::Capture {
                id: capture.id,
                reason: format!("a calibrated progressive reconstruction needs the radiometric calibration of scene {:?} ([calibration] in the config)", capture.scene),
            })?,
        };
        let balance = balance.filter(|_| radiometry.mode == Radiometry::Calibrated);
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
                background: Vec::new(),
                t_ones: None,
            });
        }
        let together = (balance.is_some() && channels.len() > 1)
            .then(|| (Warm::default(), capture.scene.clone()));
        // A difference image is the scene's change, not the pattern.
        let truth = spec
            .truth
            .as_deref()
            .filter(|_| spec.difference.is_none())
            .and_then(crate::simulate::patterns::Pattern::from_name)
            .map(|p| p.render(t.scene_grid()));
        Ok(Self {
            settings: AdmmSettings {
                lambda: spec.lambda,
                max_iter: spec.max_iter,
                // A change of radiances in [0, 1] is in [-1, 1]: the box
                // [0, 2] on the image plus 1 (`Channel::solve`).
                upper: match spec.difference {
                    Some(_) => 2.0 * DIFFERENCE_OFFSET,
                    None => 1.0,
                },
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
            difference: spec.difference.map(|tau_s| Background {
                tau_s,
                windows: 0,
                last_s: None,
                carried: 0.0,
                moved: None,
            }),
            stream: None,
            together,
            radiometry,
        })
    }

    /// The radiometry of its steps, and why.
    pub(in crate::daemon) fn radiometry(&self) -> &RadiometryChoice {
        &self.radiometry
    }

    /// Solves one snapshot; returns the step and the image (a colour
    /// camera's colours interleaved, red, green, blue per element).
    /// In difference mode the first window only starts the background: its
    /// image is zero, unsolved.
    pub(in crate::daemon) fn step(
        &mut self,
        s: &Snapshot,
        stop: Stop<'_>,
    ) -> Result<(Step, Vec<f64>), JobError> {
        let start = Instant::now();
        let own = self.own_frames(s);
        let blocks: Vec<_> = self
            .own
            .iter()
            .map(|&k| self.channels[0].t.blocks()[k].clone())
            .collect();
        let weight = self.difference.as_mut().map(|b| b.weigh(s.time_s));
        let offset = match self.difference {
            Some(_) => DIFFERENCE_OFFSET,
            None => 0.0,
        };
        // A colour camera's colours are independent solves: in parallel.
        let (scene, maps, own_blocks) = (&self.scene, &self.maps, &self.own);
        let settings = AdmmSettings {
            stop,
            ..self.settings
        };
        let (scenes, name, settings) = (&self.scenes, &self.capture.scene, &settings);
        let fitted = self.radiometry.mode == Radiometry::Fitted;
        let noises = self
            .channels
            .par_iter_mut()
            .map(|ch| {
                let m =
                    assemble_colour(scene, &blocks, std::slice::from_ref(&own), maps, ch.colour)?;
                let noise = ch.measure(m, own_blocks, settings.lambda.is_none() && !fitted);
                let chi2 = weight.and_then(|(w, spread)| ch.difference(own_blocks, w, spread));
                Ok((noise, chi2))
            })
            .collect::<Result<Vec<_>, JobError>>()?;
        let (noises, chi2): (Vec<_>, Vec<_>) = noises.into_iter().unzip();
        if let Some(b) = self.difference.as_mut() {
            let all = chi2
                .iter()
                .try_fold((0.0, 0), |(c, m), x| x.map(|(a, n)| (c + a, m + n)));
            b.judge(all.filter(|_| b.windows > 1));
            if b.windows == 1 {
                return Ok(self.unsolved(s.frames, start));
            }
        }
        if fitted {
            return self.fitted_step(s.frames, start, stop);
        }
        // Colours solved together are on one model: the one the least noisy
        // colour's noise asks for, as a reconstruction chooses it (chosen
        // once here; alone, each colour's noise chooses its own).
        let key = match self.together {
            Some(_) => {
                crate::solve::lambda::least_noisy(noises.iter().flatten().map(|n| &n.variance[..]))
                    .map(|v| scenes.for_noise(name, v).map(|(key, _)| key))
                    .transpose()?
            }
            None => None,
        };
        let mut solved = self
            .channels
            .par_iter_mut()
            .zip(noises)
            .map(|(ch, noise)| ch.solve(noise, key.as_deref(), scenes, name, settings, offset))
            .collect::<Result<Vec<_>, JobError>>()?;
        self.solve_together(&mut solved, settings, offset)?;
        // A colour image is interleaved once, for the step and the caller.
        let colour = (solved.len() > 1).then(|| {
            let images: Vec<&[f64]> = solved.iter().map(|(r, _)| &r.image[..]).collect();
            interleave(&images)
        });
        let image = colour.as_deref().unwrap_or(&solved[0].0.image);
        let summary = Solved {
            iterations: solved
                .iter()
                .map(|(r, _)| r.stats.iterations)
                .max()
                .unwrap_or(0),
            converged: solved.iter().all(|(r, _)| r.stats.converged),
            // The middle colour's (green's) λ: one number per step.
            lambda: solved.get(solved.len() / 2).and_then(|s| s.1),
            fitted: None,
        };
        let step = self.record(s.frames, start, summary, image);
        let image = colour.unwrap_or_else(|| solved.swap_remove(0).0.image);
        Ok((step, image))
    }

    /// The step of a fitted radiometry: every colour's measurement (its
    /// rows as measured, the other blocks' from their captures) fitted
    /// with its gain and background ([`PhotoStream`]), the stream formed
    /// at the first step.
    fn fitted_step(
        &mut self,
        frames: usize,
        start: Instant,
        stop: Stop<'_>,
    ) -> Result<(Step, Vec<f64>), JobError> {
        let channels: Vec<Vec<f64>> = self.channels.iter().map(|c| c.i.clone()).collect();
        let settings = PhotoSettings {
            lambda: self.settings.lambda,
            iterations: self
                .settings
                .max_iter
                .min(PhotoSettings::default().iterations),
            stop,
            ..PhotoSettings::default()
        };
        let stream = match &mut self.stream {
            Some(s) => s,
            slot => {
                let (scenes, name) = (&self.scenes, &self.capture.scene);
                let chosen = photo_transport(
                    &self.scene,
                    Arc::clone(&self.channels[0].t),
                    || -> Result<_, JobError> {
                        Ok(scenes.transport(&scenes.with_area_shadows(name)?)?)
                    },
                    &channels,
                    &settings,
                )?;
                slot.insert(chosen.stream(&channels, settings.data_term))
            }
        };
        let mut fit = stream.fit(&channels, &settings)?;
        let image = match fit.images.len() {
            1 => fit.images.swap_remove(0),
            _ => interleave(&fit.images.iter().map(Vec::as_slice).collect::<Vec<_>>()),
        };
        let summary = Solved {
            iterations: fit.iterations,
            converged: fit.converged,
            lambda: fit.lambdas.get(fit.lambdas.len() / 2).copied(),
            fitted: Some(FittedStep {
                gain: fit.gains,
                background: fit.backgrounds,
                shadows: stream.shadows().model.name().to_string(),
                lambda_searched: fit.searched,
            }),
        };
        let step = self.record(frames, start, summary, &image);
        Ok((step, image))
    }

    /// Calibrated colours solved again together ([`Solver::solve_colours`],
    /// the colour TV) at the one λ: the request's, else the largest of the
    /// colours' own (their solves in `solved`, replaced), warm from the last
    /// step's joint solve. Nothing for one colour, or colours whose models
    /// differ (none chosen from the noise in one of them).
    /// Why: a step is the reconstruction of its frames, and a reconstruction
    /// solves calibrated colours together.
    fn solve_together(
        &mut self,
        solved: &mut [(Reconstruction, Option<f64>)],
        settings: &AdmmSettings<'_>,
        offset: f64,
    ) -> Result<(), JobError> {
        let Some((warm, key)) = self.together.as_mut() else {
            return Ok(());
        };
        let lambda = settings
            .lambda
            .or_else(|| solved.iter().filter_map(|s| s.1).reduce(f64::max));
        let channels = &mut self.channels;
        let one_gram = crate::solve::gram::off_gram(channels.iter().map(|c| &c.normal)).is_none();
        let (Some(lambda), true) = (lambda, one_gram) else {
            return Ok(());
        };
        if *key != channels[0].key {
            *warm = Warm::default();
            key.clone_from(&channels[0].key);
        }
        for ch in channels.iter_mut() {
            ch.shift(offset, 1.0);
            ch.normal.ti = adjoint(ch.t.as_mat(), &ch.i);
        }
        let at = AdmmSettings {
            lambda: Some(lambda),
            max_iter: settings.max_iter.max(AUTO_MAX_ITER),
            ..*settings
        };
        let first = &channels[0];
        let p = at.problem(&first.t, &first.i, &first.normal);
        let inputs: Vec<(&[f64], &Normal)> =
            channels.iter().map(|c| (&c.i[..], &c.normal)).collect();
        let joint = Solver::ADMM_TV.solve_colours(&p, &inputs, Some(warm));
        for ch in channels.iter_mut() {
            ch.shift(offset, -1.0);
        }
        let Some(joint) = joint else {
            return Ok(());
        };
        for (s, mut r) in solved.iter_mut().zip(joint?) {
            r.image.iter_mut().for_each(|v| *v -= offset);
            *s = (r, Some(lambda));
        }
        Ok(())
    }

    /// The zero image of a window that only started the background, and its step.
    fn unsolved(&mut self, frames: usize, start: Instant) -> (Step, Vec<f64>) {
        let image = vec![0.0; self.grid().count() * self.colours()];
        let nothing = Solved {
            iterations: 0,
            converged: true,
            lambda: None,
            fitted: None,
        };
        let step = self.record(frames, start, nothing, &image);
        (step, image)
    }

    /// Difference mode: whether the newest window's change stood out of its
    /// noise in the measurement (`None`: no variance to tell by).
    pub(in crate::daemon) fn moved(&self) -> Option<bool> {
        self.difference.as_ref().and_then(|b| b.moved)
    }

    /// The hidden-scene plane its images are on (where the tracker places them).
    pub(in crate::daemon) fn scene_plane(&self) -> &crate::scene::Plane {
        &self.scene.hidden().plane
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
    fn record(&mut self, frames: usize, start: Instant, solved: Solved, image: &[f64]) -> Step {
        let norm = image.iter().map(|v| v * v).sum::<f64>().sqrt().max(1e-300);
        let change = self.previous.as_ref().map(|p| {
            p.iter()
                .zip(image)
                .map(|(a, b)| (a - b) * (a - b))
                .sum::<f64>()
                .sqrt()
                / norm
        });
        let c = self.channels.len();
        let step = Step {
            frames,
            iterations: solved.iterations,
            converged: solved.converged,
            change,
            psnr_db: self.truth.as_ref().map(|t| {
                let each: Vec<f64> = t.iter().flat_map(|&v| std::iter::repeat_n(v, c)).collect();
                crate::solve::metrics::psnr(&each, image)
            }),
            lambda: solved.lambda,
            seconds: start.elapsed().as_secs_f64(),
            fitted: solved.fitted,
        };
        self.previous = Some(image.to_vec());
        self.steps.push(step.clone());
        step
    }
}

/// What a step's solves give its record beside the image.
struct Solved {
    /// The most iterations a colour took.
    iterations: usize,
    /// Whether every colour's solve met its tolerance.
    converged: bool,
    /// The middle colour's (green's) λ: one number per step (none for a
    /// window nothing was solved for).
    lambda: Option<f64>,
    /// A fitted radiometry's gains and backgrounds.
    fitted: Option<FittedStep>,
}

/// The radiometry of a progressive or live solve of `capture`: the
/// request's, else a reconstruction's rule ([`RadiometryChoice::choose`]);
/// difference mode's is calibrated (its running background is in the
/// scene's units; admission refuses it fitted).
fn choose_radiometry(
    spec: &ProgressiveSpec,
    capture: &CaptureRecord,
    gain: Option<f64>,
    colours: usize,
    balance: &Option<ColourCalibrationRow>,
) -> RadiometryChoice {
    if spec.difference.is_some() {
        return RadiometryChoice {
            mode: Radiometry::Calibrated,
            given: spec.radiometry.is_some(),
            reason:
                "difference mode: the running background is kept in the scene's calibrated units"
                    .into(),
        };
    }
    let label = balance.as_ref().map(ColourCalibrationRow::label);
    RadiometryChoice::choose(
        spec.radiometry,
        Known {
            imported: None,
            gain,
            scene: &capture.scene,
            colours,
            colour_calibration: label.as_deref(),
        },
    )
}

/// The colours' images interleaved: red, green, blue per element.
fn interleave(images: &[&[f64]]) -> Vec<f64> {
    let n = images.first().map_or(0, |i| i.len());
    (0..n)
        .flat_map(|k| images.iter().map(move |i| i[k]))
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
        wants_noise: bool,
    ) -> Option<NoiseLevel> {
        Units::Calibrated(self.gain).apply(&mut m);
        let n = self.t.wall_grid().count();
        for (k, &b) in own.iter().enumerate() {
            self.i[self.t.block_rows(b)].copy_from_slice(&m.i[k * n..(k + 1) * n]);
        }
        // The running variance of these blocks, beside the other blocks'
        // (difference mode's test of a change reads it with a fixed λ too).
        let (Some(v), Some(all)) = (m.variance, self.variance.as_mut()) else {
            return None;
        };
        for (k, &b) in own.iter().enumerate() {
            all[self.t.block_rows(b)].copy_from_slice(&v[k * n..(k + 1) * n]);
        }
        wants_noise.then(|| NoiseLevel::measured(all.clone()))
    }

    /// Replaces this capture's rows by their difference from the running
    /// background, and moves the background towards them by `weight`
    /// ([`Background`]); a row the background has no value of yet takes
    /// this window's (its difference zero), an unmeasured (NaN) row stays
    /// unmeasured and leaves the background as it was. Returns the
    /// difference's chi-square against its noise (each row's variance
    /// times `spread`, the background's share added) and the rows in it,
    /// when the rows have a variance.
    fn difference(&mut self, own: &[usize], weight: f64, spread: f64) -> Option<(f64, usize)> {
        let n = self.t.wall_grid().count();
        if self.background.len() != own.len() * n {
            self.background = vec![f64::NAN; own.len() * n];
        }
        let (mut chi2, mut rows_in) = (0.0, 0usize);
        for (k, &b) in own.iter().enumerate() {
            let rows = self.t.block_rows(b);
            let variance = self.variance.as_ref().map(|v| &v[rows.clone()]);
            let background = &mut self.background[k * n..(k + 1) * n];
            for (r, (x, bg)) in self.i[rows].iter_mut().zip(background).enumerate() {
                if !x.is_finite() {
                    continue;
                }
                if !bg.is_finite() {
                    *bg = *x;
                }
                let d = *x - *bg;
                *bg += weight * d;
                *x = d;
                if let Some(&v) = variance.and_then(|v| v.get(r)).filter(|v| **v > 0.0) {
                    chi2 += d * d / (v * spread);
                    rows_in += 1;
                }
            }
        }
        (rows_in > 0).then_some((chi2, rows_in))
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
        self.t_ones = None;
        Ok(())
    }

    /// Solves the measurement, λ resolved from `noise` if any (or the last
    /// search's λ, warm-started, while the noise stays within
    /// [`LAMBDA_KEPT`] of the noise it was searched at), else warm-started;
    /// returns λ.
    /// Why: a step is as good as reconstructing the same frames afterwards.
    ///
    /// With an `offset` (difference mode) it solves for the image plus
    /// `offset` everywhere, from the measurement plus `offset T 1`, and
    /// takes the offset off again: the same fit and the same TV (a constant
    /// has none), with the box `[0, upper]` moved to `[-offset, upper -
    /// offset]`, so a change may be negative.
    fn solve(
        &mut self,
        noise: Option<NoiseLevel>,
        model: Option<&str>,
        scenes: &Scenes,
        scene: &str,
        settings: &AdmmSettings<'_>,
        offset: f64,
    ) -> Result<(Reconstruction, Option<f64>), JobError> {
        // The sampling the scene file leaves out: the `model` key given
        // (colours solved together), else chosen from this step's noise as
        // a reconstruction of the same frames chooses it.
        let key = match (model, &noise) {
            (Some(k), _) => Some(k.to_string()),
            (None, Some(n)) => Some(scenes.for_noise(scene, &n.variance)?.0),
            (None, None) => None,
        };
        if let Some(key) = key.filter(|k| *k != self.key) {
            self.use_model(scenes, key)?;
        }
        let norm = self
            .i
            .iter()
            .filter(|x| x.is_finite())
            .map(|x| x * x)
            .sum::<f64>()
            .sqrt();
        self.shift(offset, 1.0);
        let solved = self.solve_at(noise, norm, settings);
        self.shift(offset, -1.0);
        let (mut r, lambda) = solved?;
        r.image.iter_mut().for_each(|v| *v -= offset);
        Ok((r, lambda))
    }

    /// Adds `sign offset T 1` to the measurement (difference mode's offset,
    /// [`Channel::solve`]; nothing without one), `T 1` formed once a model.
    fn shift(&mut self, offset: f64, sign: f64) {
        if offset == 0.0 {
            return;
        }
        let t = &self.t;
        let ones = self
            .t_ones
            .get_or_insert_with(|| t.apply(&vec![1.0; t.cols()]));
        for (x, s) in self.i.iter_mut().zip(ones.iter()) {
            *x += sign * offset * s;
        }
    }

    /// [`Channel::solve`] of the measurement as it is, whose norm is `norm`.
    fn solve_at(
        &mut self,
        noise: Option<NoiseLevel>,
        norm: f64,
        settings: &AdmmSettings<'_>,
    ) -> Result<(Reconstruction, Option<f64>), JobError> {
        self.normal.ti = adjoint(self.t.as_mat(), &self.i);
        let near = |a: f64, b: f64| (a / b - 1.0).abs() <= LAMBDA_KEPT;
        let kept = match (&noise, self.chosen) {
            (Some(n), Some((lambda, at, was))) => {
                (near(n.mean_variance(), at) && near(norm, was)).then_some(lambda)
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
                self.chosen = Some((choice.lambda, noise.mean_variance(), norm));
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
        match solver.step(&snapshot, Stop::default()) {
            Ok((step, img)) => {
                // Shown as people look at it: the plane's top (+v) first.
                let pixels = image::unit_to_u16(&grid.to_top_first(&img, colours.max(1)));
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
