//! The reconstruction worker: turns a reconstruction's captures into a
//! measurement (each mean frame sampled at the wall elements through its
//! pose's homography, stacked in MODEL.md row order, in units of `T l`) and
//! runs [`crate::solve::reconstruct`] on it.

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::Instant;

use tokio::sync::{mpsc, Mutex};

use super::{finish_job, Ending, JobContext, JobError};
use crate::files::{image, json, npy};
use crate::measure::{
    assemble_colour, load, to_model_units, CaptureFrames, CaptureInfo, CaptureSource, Measurement,
    PixelMaps,
};
use crate::scene::Frame;
use crate::solve::gram::Normal;
use crate::solve::lambda::NoiseLevel;
use crate::solve::photo::{photo_transport, OrientationCheck, PhotoReport, PhotoSettings};
use crate::solve::radiometry::{Known, Radiometry, RadiometryChoice};
use crate::solve::reconstruct::{reconstruct_colours, reconstruct_prepared, ColourInput, Context};
use crate::solve::{check_measurement, SolveRequest};
use crate::stop::Stop;
use crate::store::{read_mean, CaptureRecord, JobState, Store};
use crate::transport::Block;

/// Takes reconstructions from the shared queue.
pub(in crate::daemon) async fn reconstruction_worker(
    d: JobContext,
    rx: Arc<Mutex<mpsc::Receiver<i64>>>,
) {
    let mut stopped = d.registry.stopped();
    loop {
        // Biased towards the stop: a job still queued when the drain
        // starts stays queued, however ready the queue is.
        let id = tokio::select! {
            biased;
            _ = stopped.wait_for(|s| *s) => None,
            id = async { rx.lock().await.recv().await } => id,
        };
        let Some(id) = id else {
            return;
        };
        let job = format!("reconstruction-{id}");
        let start = Instant::now();
        match d.store.reconstruction_running(id) {
            Ok(true) => {}
            // Cancelled while it waited in the queue.
            Ok(false) => {
                d.registry.forget(&job);
                continue;
            }
            Err(e) => {
                tracing::error!("{job}: {e}");
                continue;
            }
        }
        d.events.job(job.clone(), JobState::Running, None);
        tracing::info!("{job} started");
        let (d2, cancel) = (d.with_current_scenes(), d.registry.cancel_flag(&job));
        let span = tracing::info_span!("job", id = %job);
        let r = tokio::task::spawn_blocking(move || {
            span.in_scope(|| run_reconstruction(&d2, id, &cancel))
        })
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
            // Its inputs are stored: the next start runs it again.
            Ending::Interrupted => d.store.reconstruction_requeued(id),
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
fn run_reconstruction(d: &JobContext, id: i64, cancel: &AtomicBool) -> Result<(), JobError> {
    let start = Instant::now();
    let store = |e: crate::store::StoreError| JobError::Store(d.store.describe(&e));
    let rec = d.store.reconstruction(id).map_err(store)?;
    let scene = d.scenes.scene(&rec.scene)?;
    let t0 = Instant::now();
    let t = d.scenes.transport_until(&rec.scene, Stop::on(cancel))?;
    let transport_seconds = t0.elapsed().as_secs_f64();
    check(cancel)?;
    let records = read_captures(&d.store, &rec.captures)?;
    // A partial reconstruction solves with the rows of the blocks it has.
    let part = rec
        .params
        .partial
        .then(|| Partial::of(t.blocks(), &records));
    let t = match &part {
        Some(p) if p.kept.is_empty() => {
            return Err(JobError::Store(
                "a partial reconstruction whose captures give no block of its scene".into(),
            ))
        }
        Some(p) => Arc::new(t.select_blocks(&p.kept)),
        None => t,
    };
    // What can leave a measurement without a usable row, said before the
    // records are consumed.
    let causes: Vec<String> = records.iter().filter_map(unmeasured_cause).collect();
    let imported = records
        .iter()
        .find(|r| r.is_imported())
        .map(|r| format!("capture {}", r.id));
    let calibration = d.calibration.get(&rec.scene).copied();
    let stacked = match imported {
        Some(_) => stack_imports(&d.store, &records, t.blocks(), t.wall_grid().count())?,
        None => stack_records(
            &d.store,
            records,
            &scene,
            t.blocks(),
            &d.scenes.pixel_maps(&rec.scene),
            true,
            true,
        )?,
    };
    // A colour camera's measurement: each colour's gain from the scene's
    // colour calibration, when it has one.
    let colours = stacked.measurements.len();
    let balance = match (colours > 1 && !stacked.imported, calibration) {
        (true, Some(_)) => d.store.colour_calibration(&rec.scene).map_err(store)?,
        _ => None,
    };
    let balance_label = balance
        .as_ref()
        .map(crate::store::ColourCalibrationRow::label);
    let radiometry = RadiometryChoice::choose(
        rec.params.radiometry,
        Known {
            imported: imported.as_deref(),
            gain: calibration,
            scene: &rec.scene,
            colours,
            colour_calibration: balance_label.as_deref(),
        },
    );
    let job = Job {
        d,
        rec: &rec,
        t: &t,
        part: part.as_ref(),
        transport_seconds,
        cancel,
        causes: &causes,
    };
    if radiometry.mode == Radiometry::Fitted {
        return job.fitted(id, stacked, radiometry, start);
    }
    // An imported measurement is in units of T l when it is not fitted.
    let gain = match stacked.imported {
        true => Some(1.0),
        false => calibration,
    };
    let gains: Vec<Option<f64>> = match &balance {
        Some(b) => crate::measure::colour::Colour::ALL
            .iter()
            .take(colours)
            .map(|&c| gain.map(|g| b.balance.gain(c, g)))
            .collect(),
        None => vec![gain; colours],
    };
    // Calibrated colours are in one unit: one λ for all of them keeps their
    // balance (a λ each dims the noisier colours more).
    let together = balance.is_some() && colours > 1;
    let mut solved = job.solve_all(stacked.measurements, &gains, together)?;
    let (image, measurement, mut report, kappa) = match solved.len() {
        1 => {
            let s = solved.swap_remove(0);
            (s.image, s.i, s.report, s.kappa)
        }
        _ => {
            let truth = grey_truth(&rec, t.scene_grid())?;
            colour_result(solved, truth.as_deref())
        }
    };
    report.warnings.splice(0..0, stacked.warnings);
    report.radiometry = Some(radiometry);
    let c = report.colours.len().max(1);
    log_summary(&report);
    let report = d
        .scenes
        .geometry(&rec.scene)
        .stamped(&report)
        .map_err(|e| JobError::Store(e.to_string()))?;
    write_result(d, id, t.scene_grid(), c, &image, &measurement, &report)?;
    d.store
        .reconstruction_done(id, kappa, &report.to_string())
        .map_err(store)
}

/// What solving one measurement of a reconstruction needs beside it.
struct Job<'a> {
    d: &'a JobContext,
    rec: &'a crate::store::ReconstructionRecord,
    /// `T` of the scene, the blocks a partial reconstruction keeps.
    t: &'a Arc<crate::transport::Transport>,
    part: Option<&'a Partial>,
    transport_seconds: f64,
    cancel: &'a AtomicBool,
    /// Why the captures may leave rows unmeasured ([`unmeasured_cause`]).
    causes: &'a [String],
}

/// One measurement solved: the image, the measurement in units of `T l`,
/// the report and `kappa(T)`.
struct Solution {
    image: Vec<f64>,
    i: Vec<f64>,
    report: crate::solve::report::Report,
    kappa: f64,
}

/// One measurement made ready to solve, as often as needed: its `T` (the
/// sampling its noise chose, unmeasured rows zeroed), values, variance,
/// conditioning and Gram, and what its report says beside the solve.
struct Prepared {
    t: Arc<crate::transport::Transport>,
    i: Vec<f64>,
    variance: Option<Vec<f64>>,
    cond: Arc<crate::solve::Conditioning>,
    normal: Option<Normal>,
    solve: SolveRequest,
    truth: Option<Vec<f64>>,
    /// Rows not measured (NaN in the stored measurement).
    missing: Vec<usize>,
    model: Option<crate::transport::choose::ModelChoice>,
    gain: crate::solve::report::Gain,
    warnings: Vec<String>,
    notes: Vec<String>,
}

/// One measurement in units of `T l`, its unmeasured rows zeroed (with
/// their rows of `t`), before its sampling is chosen.
struct InUnits {
    t: Arc<crate::transport::Transport>,
    measurement: Measurement,
    missing: Vec<usize>,
    units: crate::measure::Units,
    warnings: Vec<String>,
}

/// The scene key a measurement is solved on (the sampling its noise
/// chose, or the scene's own) and that choice for the report.
type ModelKey = (String, Option<crate::transport::choose::ModelChoice>);

impl Job<'_> {
    /// `measurement` (fractions of full scale per µs, one value per row of
    /// `t`) with its unmeasured rows dropped, divided by `gain` (`None`:
    /// scaled to a brightest element of about 1).
    fn in_units(
        &self,
        mut measurement: Measurement,
        gain: Option<f64>,
    ) -> Result<InUnits, JobError> {
        check(self.cancel)?;
        // Elements too saturated to measure: their rows of T and i are zero (no
        // part in any fit) and their variance 0 (no part in the noise).
        let missing = measurement.zero_unmeasured();
        if !missing.is_empty() && missing.len() == measurement.i.len() {
            return Err(JobError::Unmeasured(match self.causes.is_empty() {
                true => "every wall element's pixels were left out".into(),
                false => self.causes.join("; "),
            }));
        }
        let warnings: Vec<String> = crate::solve::unmeasured_warning(&missing, measurement.i.len())
            .into_iter()
            .collect();
        let t = match missing.is_empty() {
            true => self.t.clone(),
            false => Arc::new(self.t.with_rows_zeroed(&missing)),
        };
        let units = to_model_units(&t, &mut measurement, gain)?;
        Ok(InUnits {
            t,
            measurement,
            missing,
            units,
            warnings,
        })
    }

    /// The sampling the scene file left out, chosen from the noise
    /// `variance` (in units of `T l`; `None`: the scene's own). A partial
    /// measurement's rows stand at their blocks, the others unknown.
    fn model_for(&self, variance: Option<&[f64]>) -> Result<ModelKey, JobError> {
        let (d, rec) = (self.d, self.rec);
        Ok(match (variance, self.part) {
            (Some(v), None) => d.scenes.for_noise(&rec.scene, v)?,
            (Some(v), Some(p)) => d
                .scenes
                .for_noise(&rec.scene, &p.whole_rows(v, self.t.wall_grid().count()))?,
            (None, _) => (rec.scene.clone(), None),
        })
    }

    /// Prepares a measurement in units on the scene key `(key, model)`: its
    /// `T`, the conditioning and Gram, the solver the record asks for.
    fn prepare(&self, u: InUnits, (key, model): ModelKey) -> Result<Prepared, JobError> {
        let (d, rec) = (self.d, self.rec);
        let stop = Stop::on(self.cancel);
        let InUnits {
            t,
            measurement,
            missing,
            units,
            warnings,
        } = u;
        let mut notes: Vec<String> = units.note().into_iter().collect();
        if let Some(p) = self.part {
            notes.push(p.note());
        }
        let Measurement { i, variance: var } = measurement;
        let t = match (self.part, key == rec.scene) {
            (_, true) => t,
            (None, false) => d.scenes.transport_until(&key, stop)?,
            (Some(p), false) => {
                Arc::new(d.scenes.transport_until(&key, stop)?.select_blocks(&p.kept))
            }
        };
        let t = if missing.is_empty() || key == rec.scene {
            t
        } else {
            Arc::new(t.with_rows_zeroed(&missing))
        };
        // The scene's cached conditioning and Gram are those of every row of
        // every block.
        let whole = self.part.is_none() && missing.is_empty();
        let cond = match whole {
            true => d.scenes.conditioning_until(&key, stop)?,
            false => Arc::new(crate::solve::condition(&t)?),
        };
        check(self.cancel)?;
        let solve = rec.params.solve;
        let truth = grey_truth(rec, t.scene_grid())?;
        // A solver that needs the Gram solves on the scene's cached one: only
        // `T^T i` is new.
        let normal = match solve.solver.needs().gram {
            true => Some(normal_for(d, (&key, stop), whole, &t, &i)?),
            false => None,
        };
        Ok(Prepared {
            t,
            i,
            variance: var,
            cond,
            normal,
            solve,
            truth,
            missing,
            model,
            gain: gain_of(units),
            warnings,
            notes,
        })
    }

    /// Solves `p` with the record's solver, at `lambda` when given (else the
    /// record's λ, or its automatic choice).
    fn solve(&self, p: &Prepared, lambda: Option<f64>) -> Result<Solution, JobError> {
        check(self.cancel)?;
        let mut solve = p.solve;
        if lambda.is_some() {
            solve.lambda = lambda;
        }
        let solved = reconstruct_prepared(
            &p.t,
            &p.i,
            p.variance.clone().map(NoiseLevel::measured),
            &p.cond,
            p.normal.as_ref(),
            &solve,
            self.context(p),
        )?;
        check(self.cancel)?;
        Ok(solution(p, solved))
    }

    /// Where `p`'s report names the scene and what it is compared with.
    fn context<'a>(&'a self, p: &'a Prepared) -> Context<'a> {
        Context {
            scene: self.rec.scene.clone(),
            transport_seconds: self.transport_seconds,
            truth: p.truth.as_deref(),
            stop: Stop::on(self.cancel),
        }
    }
}

/// `solved` with what `p` knew beside the solve (its sampling, gain,
/// warnings and notes), and the measurement it solved with its unmeasured
/// rows NaN, as `polnlos measure` writes them: re-solved offline, they are
/// left out again.
fn solution(p: &Prepared, solved: crate::solve::reconstruct::Solved) -> Solution {
    let mut report = solved.report;
    report.model = p.model.clone();
    report.gain = Some(p.gain);
    report.warnings.splice(0..0, p.warnings.iter().cloned());
    report.notes.splice(0..0, p.notes.iter().cloned());
    let mut i = p.i.clone();
    p.missing.iter().for_each(|&j| i[j] = f64::NAN);
    Solution {
        image: solved.image,
        i,
        report,
        kappa: p.cond.kappa,
    }
}

impl Job<'_> {
    /// Each measurement (one, or a colour camera's three) solved with its
    /// gain; with `together` (calibrated colours), as one colour image
    /// ([`Job::solve_together`]).
    fn solve_all(
        &self,
        measurements: Vec<Measurement>,
        gains: &[Option<f64>],
        together: bool,
    ) -> Result<Vec<Solution>, JobError> {
        let units = measurements
            .into_iter()
            .zip(gains.iter().copied())
            .map(|(m, g)| self.in_units(m, g))
            .collect::<Result<Vec<_>, _>>()?;
        // One sampling for every colour: the one the least noisy colour's
        // noise asks for (the others' would be coarser), so that the colours
        // are solved on one T and differ only by what they measured.
        let least = crate::solve::lambda::least_noisy(
            units
                .iter()
                .filter_map(|u| u.measurement.variance.as_deref()),
        );
        let model = self.model_for(least)?;
        let prepared = units
            .into_iter()
            .map(|u| self.prepare(u, model.clone()))
            .collect::<Result<Vec<_>, _>>()?;
        let lambda = self.rec.params.solve.lambda;
        let mut solved = match (together, lambda) {
            (true, Some(_)) => Vec::new(),
            _ => prepared
                .iter()
                .map(|p| self.solve(p, None))
                .collect::<Result<Vec<_>, _>>()?,
        };
        if together {
            self.solve_together(&mut solved, &prepared)?;
        }
        Ok(solved)
    }

    /// Calibrated colours solved again as one colour image: at the record's
    /// λ, else at the largest of their own automatic choices (in `solved`),
    /// with ADMM-TV's colour TV where they share one `T` (each colour's
    /// edges then paid for by all; else each alone at that λ). One λ leaves
    /// the calibration alone to set the levels (a λ each dims the noisier
    /// colours more); each colour's report keeps its own choice and says so.
    fn solve_together(
        &self,
        solved: &mut Vec<Solution>,
        prepared: &[Prepared],
    ) -> Result<(), JobError> {
        let mut notes = Vec::new();
        let lambda = match self.rec.params.solve.lambda {
            Some(l) => l,
            None => {
                let chosen: Option<Vec<f64>> = solved
                    .iter()
                    .map(|s| s.report.lambda_choice.as_ref().map(|c| c.lambda))
                    .collect();
                let Some(chosen) = chosen else {
                    return Ok(());
                };
                let (largest, from) = chosen.iter().zip(crate::measure::colour::Colour::ALL).fold(
                    (0.0, None),
                    |(l, c), (&v, colour)| match v > l {
                        true => (v, Some(colour)),
                        false => (l, c),
                    },
                );
                let Some(from) = from else {
                    return Ok(());
                };
                notes.push(format!(
                    "one λ = {largest:.3e} for every colour, the largest of their own choices ({}'s): calibrated colours share it so that TV dims each alike",
                    from.name()
                ));
                largest
            }
        };
        let choices: Vec<Option<crate::solve::lambda::LambdaChoice>> = match solved.is_empty() {
            true => vec![None; prepared.len()],
            false => solved
                .iter_mut()
                .map(|s| s.report.lambda_choice.take())
                .collect(),
        };
        let solver = self.rec.params.solve.solver.name();
        let alone = format!("each colour solved alone: {solver} solves one image at a time (ADMM-TV solves colours together)");
        let normals: Option<Vec<&Normal>> = prepared.iter().map(|p| p.normal.as_ref()).collect();
        let together = match normals {
            None => Err(alone),
            Some(n) if crate::solve::gram::off_gram(n.iter().copied()).is_some() => Err("each colour solved alone: their T differ (rows unmeasured in some colours), so they cannot be solved together".to_string()),
            Some(n) => self.solve_colours(prepared, &n, lambda)?.ok_or(alone),
        };
        *solved = match together {
            Ok(colours) => {
                notes.push("the colours solved together, with the colour TV: an edge costs less where the colours share it (docs/guide.md, \"Colours solved together\")".into());
                colours
            }
            Err(why) => {
                notes.push(why);
                prepared
                    .iter()
                    .map(|p| self.solve(p, Some(lambda)))
                    .collect::<Result<Vec<_>, _>>()?
            }
        };
        for (s, choice) in solved.iter_mut().zip(choices) {
            s.report.lambda_choice = choice;
            s.report.notes.extend(notes.iter().cloned());
        }
        Ok(())
    }

    /// The colours of `prepared` (each on `normals`' one Gram) solved
    /// together at `lambda` ([`reconstruct_colours`]); `None` when the
    /// record's solver solves one image at a time.
    fn solve_colours(
        &self,
        prepared: &[Prepared],
        normals: &[&Normal],
        lambda: f64,
    ) -> Result<Option<Vec<Solution>>, JobError> {
        check(self.cancel)?;
        let first = &prepared[0];
        let inputs: Vec<ColourInput<'_>> = prepared
            .iter()
            .zip(normals)
            .map(|(p, &normal)| ColourInput {
                i: &p.i,
                noise: p.variance.clone().map(NoiseLevel::measured),
                normal,
            })
            .collect();
        let solved = reconstruct_colours(
            &first.t,
            &inputs,
            &first.cond,
            &first.solve,
            lambda,
            self.context(first),
        )?;
        check(self.cancel)?;
        Ok(solved.map(|s| {
            prepared
                .iter()
                .zip(s)
                .map(|(p, s)| solution(p, s))
                .collect()
        }))
    }

    /// Reconstructs the stacked measurement with its gain and background
    /// fitted (docs/realphoto.md), as `polnlos reconstruct --photo` does:
    /// the same function, settings and `T`, so the same numbers. Writes the
    /// files and marks the record done.
    fn fitted(
        &self,
        id: i64,
        stacked: Stacked,
        radiometry: RadiometryChoice,
        start: Instant,
    ) -> Result<(), JobError> {
        let (d, rec) = (self.d, self.rec);
        check(self.cancel)?;
        // A camera capture's rows are in the order its pose's homography fixed.
        let orientation = match stacked.imported {
            true => OrientationCheck::Check,
            false => OrientationCheck::Known,
        };
        let channels: Vec<Vec<f64>> = stacked.measurements.into_iter().map(|m| m.i).collect();
        if (0..self.t.rows()).all(|j| channels.iter().any(|c| !c[j].is_finite())) {
            return Err(JobError::Unmeasured(match self.causes.is_empty() {
                true => "every wall element's pixels were left out".into(),
                false => self.causes.join("; "),
            }));
        }
        let grid = self.t.scene_grid();
        let truth = rec
            .params
            .truth
            .as_ref()
            .map(|t| t.channels(grid, channels.len(), "truth"))
            .transpose()
            .map_err(JobError::Truth)?;
        let defaults = PhotoSettings::default();
        let settings = PhotoSettings {
            lambda: rec.params.solve.lambda,
            iterations: rec.params.solve.max_iter.unwrap_or(defaults.iterations),
            stop: Stop::on(self.cancel),
            orientation,
            ..defaults
        };
        // The scene left `shadows` out and its penumbra is not negligible:
        // the photo decides, as `polnlos reconstruct --photo` lets it (the
        // area-shadow T cached as the scene's own, the same blocks kept).
        let scene = d.scenes.scene(&rec.scene)?;
        let chosen = photo_transport(
            &scene,
            self.t.clone(),
            || -> Result<_, JobError> {
                let area = d.scenes.transport_until(
                    &d.scenes.with_area_shadows(&rec.scene)?,
                    Stop::on(self.cancel),
                )?;
                check(self.cancel)?;
                Ok(match self.part {
                    Some(p) => Arc::new(area.select_blocks(&p.kept)),
                    None => area,
                })
            },
            &channels,
            &settings,
        )?;
        check(self.cancel)?;
        // κ of the T it is solved with beside the solves: they leave a core
        // idle much of the time (three colours on two cores).
        let kappa = || self.kappa(chosen.chose_area(), &chosen.t);
        let (fitted, kappa) = rayon::join(
            || chosen.reconstruct(&channels, truth.as_deref(), &settings),
            kappa,
        );
        let (mut result, shadows) = (fitted?, chosen.shadows.clone());
        let kappa = kappa?;
        check(self.cancel)?;
        result.warnings.splice(0..0, stacked.warnings);
        if let Some(p) = self.part {
            result.warnings.push(p.note());
        }
        let report = PhotoReport {
            scene: rec.scene.clone(),
            radiometry,
            transport_seconds: self.transport_seconds,
            transport_cache: None,
            shadows: Some(shadows),
            total_seconds: start.elapsed().as_secs_f64(),
            result,
        };
        let r = &report.result;
        let c = r.channels.len();
        let interleave = |f: &dyn Fn(usize, usize) -> f64, n: usize| -> Vec<f64> {
            (0..n)
                .flat_map(|k| (0..c).map(move |ch| (k, ch)))
                .map(|(k, ch)| f(k, ch))
                .collect()
        };
        let image = interleave(&|k, ch| r.channels[ch].image[k], grid.count());
        let x = interleave(&|k, ch| r.channels[ch].x[k], grid.count());
        let measurement = interleave(&|j, ch| channels[ch][j], self.t.rows());
        let written = (d.scenes.geometry(&rec.scene).stamped(&report))
            .map_err(|e| JobError::Store(e.to_string()))?;
        write_result(d, id, grid, c, &image, &measurement, &written)?;
        let dir = d.store.reconstruction_dir(id);
        let file =
            |e: crate::files::FileError| JobError::Store(d.store.redact_paths(&e.to_string()));
        let mut shape = vec![grid.nv, grid.nu];
        if c > 1 {
            shape.push(c);
        }
        // Top row first, as recovered.npy and the CLI's fitted.npy.
        npy::write_f64(&dir.join("fitted.npy"), &shape, &grid.to_top_first(&x, c)).map_err(file)?;
        tracing::info!(
            "fitted: {} channel(s), gain {:.4e}, lambda {}; {} warnings",
            c,
            r.channels.first().map_or(0.0, |ch| ch.gain),
            r.channels
                .iter()
                .map(|ch| format!("{:.3e}", ch.lambda))
                .collect::<Vec<_>>()
                .join("/"),
            r.warnings.len()
        );
        d.store
            .reconstruction_done(id, kappa, &written.to_string())
            .map_err(|e| JobError::Store(d.store.describe(&e)))
    }
}

impl Job<'_> {
    /// κ of `t`, the `T` a fitted reconstruction is solved with: the scene's
    /// cached conditioning (of its area-shadow `T` where the photo chose
    /// `area`), or `t`'s own for a partial reconstruction.
    fn kappa(&self, area: bool, t: &crate::transport::Transport) -> Result<f64, JobError> {
        let (d, scene) = (self.d, &self.rec.scene);
        let stop = Stop::on(self.cancel);
        Ok(match (self.part, area) {
            (None, false) => d.scenes.conditioning_until(scene, stop)?.kappa,
            (None, true) => {
                d.scenes
                    .conditioning_until(&d.scenes.with_area_shadows(scene)?, stop)?
                    .kappa
            }
            (Some(_), _) => crate::solve::condition(t)?.kappa,
        })
    }
}

/// The truth of `rec` as one grey image on `grid` (a colour image's luma):
/// what a calibrated solve, grey or each colour's, is scored against.
fn grey_truth(
    rec: &crate::store::ReconstructionRecord,
    grid: crate::scene::Grid,
) -> Result<Option<Vec<f64>>, JobError> {
    rec.params
        .truth
        .as_ref()
        .map(|t| t.channels(grid, 1, "truth").map(|mut c| c.swap_remove(0)))
        .transpose()
        .map_err(JobError::Truth)
}

/// The red, green and blue solutions of a colour camera's captures as one
/// result: the images and measurements interleaved per element (`[.., 3]`),
/// and green's report (the colour with the most pixels) carrying every
/// colour's own fit in `colours`, their metrics combined (ZNCC over every
/// value of the image against the grey `truth` in each colour), their
/// warnings and notes (each named by its colour where not all three have it).
fn colour_result(
    solved: Vec<Solution>,
    truth: Option<&[f64]>,
) -> (Vec<f64>, Vec<f64>, crate::solve::report::Report, f64) {
    use crate::measure::colour::Colour;
    use crate::solve::report::ColourReport;
    let interleave = |f: &dyn Fn(&Solution) -> &Vec<f64>| -> Vec<f64> {
        let n = f(&solved[0]).len();
        (0..n)
            .flat_map(|k| solved.iter().map(move |s| f(s)[k]))
            .collect()
    };
    let image = interleave(&|s| &s.image);
    let i = interleave(&|s| &s.i);
    let kappa = solved[1].kappa;
    let mut report = solved[1].report.clone();
    report.colours = solved
        .iter()
        .zip(Colour::ALL)
        .map(|(s, colour)| ColourReport::of(colour, &s.report))
        .collect();
    report.metrics = ColourReport::combined(&report.colours).map(|m| match truth {
        Some(truth) => {
            let each: Vec<f64> = truth
                .iter()
                .flat_map(|&v| std::iter::repeat_n(v, solved.len()))
                .collect();
            crate::solve::metrics::Metrics {
                zncc: crate::solve::metrics::zncc(&each, &image),
                ..m
            }
        }
        None => m,
    });
    report.warnings = labelled(&solved, |s| &s.report.warnings);
    report.notes = labelled(&solved, |s| &s.report.notes);
    // Solved at one λ (calibrated colours), the choice of the colour that set it.
    let used = report.solver.lambda;
    if let Some(c) = report
        .colours
        .iter()
        .filter_map(|c| c.lambda_choice.as_ref())
        .find(|c| Some(c.lambda) == used)
    {
        report.lambda_choice = Some(c.clone());
    }
    (image, i, report, kappa)
}

/// The lines `of` each colour's solution says, each once: as it is when
/// every colour says it, else prefixed with the colour that does
/// (`red: ...`), so that no number is shown without its colour.
fn labelled(solved: &[Solution], of: impl Fn(&Solution) -> &Vec<String>) -> Vec<String> {
    use crate::measure::colour::Colour;
    let mut out = Vec::new();
    for (s, colour) in solved.iter().zip(Colour::ALL) {
        for line in of(s) {
            let everywhere = solved.iter().all(|o| of(o).contains(line));
            let line = match everywhere {
                true => line.clone(),
                false => format!("{}: {line}", colour.name()),
            };
            if !out.contains(&line) {
                out.push(line);
            }
        }
    }
    out
}

/// `T^T T` and `T^T i` for a solver that needs the Gram: the scene's cached
/// Gram when `T` has every row of every block (`whole`), else formed anew.
fn normal_for(
    d: &JobContext,
    (key, stop): (&str, Stop<'_>),
    whole: bool,
    t: &crate::transport::Transport,
    i: &[f64],
) -> Result<Normal, JobError> {
    check_measurement(t, i)?;
    Ok(match whole {
        true => Normal::with(d.scenes.gram_until(key, stop)?, t, i),
        false => Normal::of_until(t, i, stop).ok_or(JobError::Cancelled)?,
    })
}

/// The gain a measurement was divided by, and where it came from, for the report.
fn gain_of(units: crate::measure::Units) -> crate::solve::report::Gain {
    crate::solve::report::Gain {
        value: units.factor(),
        source: match units {
            crate::measure::Units::Calibrated(_) => "calibration",
            crate::measure::Units::Estimated(_) => "estimated",
        },
    }
}

/// Writes a finished reconstruction's files (the image, in the grid's
/// element order, as `.npy` and PNG top row first; the measurement it
/// solved; the report) and logs its summary; the record
/// is marked done only after they are durable.
fn write_result(
    d: &JobContext,
    id: i64,
    grid: crate::scene::Grid,
    c: usize,
    image: &[f64],
    measurement: &[f64],
    report: &impl serde::Serialize,
) -> Result<(), JobError> {
    let dir = d.store.reconstruction_dir(id);
    std::fs::create_dir_all(&dir).map_err(|e| JobError::Store(d.store.describe_io(&dir, &e)))?;
    let file = |e: crate::files::FileError| JobError::Store(d.store.redact_paths(&e.to_string()));
    // A colour result holds its `c` channels per element.
    let shape = |n: usize| match c {
        1 => vec![n],
        _ => vec![n, c],
    };
    let mut image_shape = vec![grid.nv, grid.nu];
    if c > 1 {
        image_shape.push(c);
    }
    // The image as people look at it: the plane's top (+v) in the first row.
    let image = &grid.to_top_first(image, c);
    npy::write_f64(&dir.join("recovered.npy"), &image_shape, image).map_err(file)?;
    // The stacked measurement it solved (units of T l, MODEL.md row order),
    // so a user can re-solve it offline with `polnlos reconstruct`.
    npy::write_f64(
        &dir.join("measurement.npy"),
        &shape(measurement.len() / c),
        measurement,
    )
    .map_err(file)?;
    match c {
        3 => image::write_png_rgb16(
            &dir.join("image.png"),
            grid.nu,
            grid.nv,
            &image::unit_to_u16(image),
        ),
        // Grey, or the first of 2 or 4 channels.
        _ => image::write_png16(
            &dir.join("image.png"),
            grid.nu,
            grid.nv,
            &image::unit_to_u16(&image.iter().step_by(c).copied().collect::<Vec<_>>()),
        ),
    }
    .map_err(file)?;
    json::write(&dir.join("report.json"), report).map_err(file)
}

/// Logs a calibrated reconstruction's summary.
fn log_summary(report: &crate::solve::report::Report) {
    tracing::info!(
        "{} rows x {} unknowns, {} iterations{}{}; {} warnings, {} notes",
        report.rows,
        report.cols,
        report.solver.iterations,
        report
            .lambda_choice
            .as_ref()
            .map(|l| format!(", lambda {:.3e} ({})", l.lambda, l.rule))
            .unwrap_or_default(),
        report
            .metrics
            .as_ref()
            .map(|m| format!(", PSNR {:.2} dB", m.psnr_db))
            .unwrap_or_default(),
        report.warnings.len(),
        report.notes.len()
    );
}

/// A reconstruction's measurement: the captures stacked in block order
/// (with the variance of each element when every capture has it), and what
/// the user should know about the captures.
pub(in crate::daemon) struct Stacked {
    /// The grey measurement over every pixel, or, when every capture came
    /// from a colour camera and colours were asked for, red, green and blue,
    /// each from its own pixels.
    pub(in crate::daemon) measurements: Vec<Measurement>,
    pub(in crate::daemon) warnings: Vec<String>,
    /// Whether the measurements are imported ones (`POST /captures/import`).
    pub(in crate::daemon) imported: bool,
}

/// The blocks a partial reconstruction's captures give, of the scene's.
struct Partial {
    /// Indices into the scene's blocks, ascending.
    kept: Vec<usize>,
    /// The scene's blocks.
    of: usize,
}

impl Partial {
    /// The blocks `records` serve among `blocks`.
    fn of(blocks: &[Block], records: &[CaptureRecord]) -> Self {
        let mut kept: Vec<usize> = records
            .iter()
            .flat_map(|c| Block::taken(blocks, &c.pose, &c.channels))
            .collect();
        kept.sort_unstable();
        kept.dedup();
        Self {
            kept,
            of: blocks.len(),
        }
    }

    /// What the report notes of it.
    fn note(&self) -> String {
        format!(
            "interim: solved from {} of the scene's {} blocks; the others are not captured yet",
            self.kept.len(),
            self.of
        )
    }

    /// A per-row `v` of the kept blocks placed at their rows of the whole
    /// scene (`n` rows a block), 0 (unknown) elsewhere.
    fn whole_rows(&self, v: &[f64], n: usize) -> Vec<f64> {
        let mut out = vec![0.0; self.of * n];
        for (k, &b) in self.kept.iter().enumerate() {
            out[b * n..(b + 1) * n].copy_from_slice(&v[k * n..(k + 1) * n]);
        }
        out
    }
}

/// Captures (each at its own pose) assembled into the measurement of
/// `blocks` with [`crate::measure::assemble_with`] and the scene's pixel
/// `maps`, in fractions of full scale per µs; the variance comes with it
/// when every capture has 2 frames or more. With `colours`, and every
/// capture from a colour camera, each colour's measurement too.
pub(in crate::daemon) fn stack_records(
    store: &Store,
    records: Vec<CaptureRecord>,
    scene: &crate::scene::Scene,
    blocks: &[crate::transport::Block],
    maps: &PixelMaps,
    in_range: bool,
    colours: bool,
) -> Result<Stacked, JobError> {
    // Saturation first: it biases the measurement before any model question.
    let mut warnings: Vec<String> = records
        .iter()
        .filter_map(|c| saturation_warning(c, in_range))
        .collect();
    warnings.extend(records.iter().filter_map(lost_frames_warning));
    let captures = records
        .into_iter()
        .map(|c| match in_range {
            true => load_capture_in_range(store, c, scene, &mut warnings),
            false => load_capture(store, c, scene, &mut warnings),
        })
        .collect::<Result<Vec<_>, _>>()?;
    let channels: Vec<Option<crate::measure::colour::Colour>> =
        match colours && captures.iter().all(|c| c.bayer.is_some()) {
            true => crate::measure::colour::Colour::ALL.map(Some).to_vec(),
            false => vec![None],
        };
    let measurements = channels
        .into_iter()
        .map(|c| assemble_colour(scene, blocks, &captures, maps, c))
        .collect::<Result<Vec<_>, _>>()?;
    Ok(Stacked {
        measurements,
        warnings,
        imported: false,
    })
}

/// Imported captures' measurements (each its pose's blocks, `[n]` or
/// `[n, C]` in the scene's row order, NaN where not measured) stacked in
/// the order of `blocks`, one measurement per colour channel.
pub(in crate::daemon) fn stack_imports(
    store: &Store,
    records: &[CaptureRecord],
    blocks: &[Block],
    nw: usize,
) -> Result<Stacked, JobError> {
    let mut colours: Option<usize> = None;
    let mut columns: Vec<Vec<f64>> = Vec::new();
    for (k, block) in blocks.iter().enumerate() {
        let (c, at) = records
            .iter()
            .find_map(|c| {
                c.channels
                    .iter()
                    .position(|ch| c.pose == block.pose && *ch == block.channel)
                    .map(|at| (c, at))
            })
            .ok_or_else(|| {
                JobError::Store(format!(
                    "no imported capture gives block {k} ({})",
                    block.label()
                ))
            })?;
        if !c.is_imported() {
            return Err(JobError::Capture {
                id: c.id,
                reason: "an imported capture and a camera capture cannot be reconstructed together; import every block, or capture every block".into(),
            });
        }
        let a = crate::store::read_imported(&store.capture_dir(c.id)).map_err(|e| {
            JobError::Capture {
                id: c.id,
                reason: store.describe(&e),
            }
        })?;
        let n = c.channels.len() * nw;
        let cc = match a.shape.as_slice() {
            [m] if *m == n => 1,
            [m, cc] if *m == n => *cc,
            s => {
                return Err(JobError::Capture {
                    id: c.id,
                    reason: format!(
                        "its measurement has shape {s:?}, not [{n}] or [{n}, C]: the file was changed after its import"
                    ),
                })
            }
        };
        if *colours.get_or_insert(cc) != cc {
            return Err(JobError::Capture {
                id: c.id,
                reason: format!(
                    "it has {cc} colour channel(s), the other imported captures {}",
                    colours.unwrap_or(cc)
                ),
            });
        }
        if columns.is_empty() {
            columns = vec![Vec::with_capacity(blocks.len() * nw); cc];
        }
        for (ch, col) in columns.iter_mut().enumerate() {
            col.extend((at * nw..(at + 1) * nw).map(|j| a.data[j * cc + ch]));
        }
    }
    Ok(Stacked {
        measurements: columns
            .into_iter()
            .map(|i| Measurement { i, variance: None })
            .collect(),
        warnings: Vec::new(),
        imported: true,
    })
}

/// What a reconstruction must say about a capture whose frames reached full
/// scale (its `clipping`): those pixels' means are lower bounds.
fn saturation_warning(c: &CaptureRecord, in_range: bool) -> Option<String> {
    let cl = c.clipping.filter(|cl| cl.saturated > 0)?;
    let what = if in_range {
        "their values are lower bounds: they are left out of their elements' means"
    } else {
        "their values are lower bounds and bias the measurement low"
    };
    Some(format!(
        "capture {} saturated: {}; {what}",
        c.id,
        cl.saturation(&c.scene)
    ))
}

/// What a reconstruction must say about a capture that lost frames (its
/// `frame_counts`): the same sentence its capture logged.
fn lost_frames_warning(c: &CaptureRecord) -> Option<String> {
    let losses = c.frame_counts?.losses()?;
    Some(format!(
        "capture {} {losses}: its mean is of those; a loss says the camera's link or the host did not keep up",
        c.id
    ))
}

/// Why capture `c` may leave wall elements unmeasured (its saturation, its
/// lost frames), for a reconstruction left with no usable row.
fn unmeasured_cause(c: &CaptureRecord) -> Option<String> {
    let saturated = c.clipping.filter(|cl| cl.saturated > 0);
    let lost = c.frame_counts.and_then(|f| f.losses());
    let what: Vec<String> = saturated
        .map(|cl| format!("saturated: {}", cl.saturation(&c.scene)))
        .into_iter()
        .chain(lost)
        .collect();
    (!what.is_empty()).then(|| format!("capture {} {}", c.id, what.join("; it ")))
}

/// The catalogue records of `ids`, each read once. A catalogue that cannot
/// be read is that error, not "no capture".
pub(in crate::daemon) fn read_captures(
    store: &Store,
    ids: &[i64],
) -> Result<Vec<CaptureRecord>, JobError> {
    ids.iter()
        .map(|&id| {
            store
                .capture(id)
                .map_err(|e| JobError::Store(format!("capture {id}: {}", store.describe(&e))))
        })
        .collect()
}

/// A done capture in the catalogue, read for a measurement from its files.
struct StoredCapture<'a> {
    store: &'a Store,
    record: CaptureRecord,
    info: CaptureInfo,
    /// Whether its mean leaves out (NaN) the pixels saturated in any frame.
    in_range: bool,
}

impl<'a> StoredCapture<'a> {
    /// The capture and what it recorded; its exposure and pixel format are
    /// needed (every capture records them; a row without is refused).
    fn new(store: &'a Store, record: CaptureRecord) -> Result<Self, JobError> {
        let c = &record;
        let s = &c.settings;
        let (Some(exposure_us), Some(pixel_format)) = (s.exposure_us, s.pixel_format) else {
            return Err(JobError::Capture {
                id: c.id,
                reason: "its row records no exposure_us or pixel_format".into(),
            });
        };
        let dark = c.dark_frames > 0 || c.dark_capture.is_some();
        let info = CaptureInfo {
            name: format!("capture {}", c.id),
            pose: c.pose.clone(),
            channels: c.channels.clone(),
            frames: c.frames as usize,
            full_scale: pixel_format.full_scale(),
            exposure_us,
            region: s.region,
            binning: s.binning,
            missing_dark: (!dark)
                .then_some("take dark_frames, or a dark capture named in dark_capture"),
            bayer: pixel_format.bayer(),
        };
        Ok(Self {
            store,
            record,
            info,
            in_range: false,
        })
    }
}

impl CaptureSource for StoredCapture<'_> {
    type Error = crate::store::StoreError;

    fn info(&self) -> CaptureInfo {
        self.info.clone()
    }

    fn mean(&self) -> Result<Frame, crate::store::StoreError> {
        let dir = self.store.capture_dir(self.record.id);
        if self.in_range {
            crate::store::read_mean_in_range(&dir)
        } else {
            read_mean(&dir)
        }
    }

    fn variance(&self) -> Result<Option<Frame>, crate::store::StoreError> {
        let dir = self.store.capture_dir(self.record.id);
        crate::store::read_mean_variance(&dir)
    }
}

/// Reads a capture's mean (and variance) frame for `scene` with
/// [`crate::measure::load`]: the same checks and warnings `polnlos measure` makes.
pub(in crate::daemon) fn load_capture(
    store: &Store,
    record: CaptureRecord,
    scene: &crate::scene::Scene,
    warnings: &mut Vec<String>,
) -> Result<CaptureFrames, JobError> {
    let source = StoredCapture::new(store, record)?;
    load(scene, &source, warnings).map_err(|e| redacted(store, e))
}

/// `e` with the data directory's path taken out of a file's name in it (a
/// reply names the capture and the file, not where the data lives).
fn redacted(store: &Store, e: crate::measure::MeasureError) -> JobError {
    use crate::measure::MeasureError;
    match e {
        MeasureError::Capture { capture, reason } => MeasureError::Capture {
            capture,
            reason: store.redact_paths(&reason),
        },
        e => e,
    }
    .into()
}

/// [`load_capture`] with the pixels saturated in any frame left out of the
/// mean (NaN), for a measurement that drops what it cannot trust.
fn load_capture_in_range(
    store: &Store,
    record: CaptureRecord,
    scene: &crate::scene::Scene,
    warnings: &mut Vec<String>,
) -> Result<CaptureFrames, JobError> {
    let mut source = StoredCapture::new(store, record)?;
    source.in_range = true;
    load(scene, &source, warnings).map_err(|e| redacted(store, e))
}
