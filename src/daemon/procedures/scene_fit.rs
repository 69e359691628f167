//! `POST /calibrations/scene`: a scene's geometry fitted to its captures
//! (`polnlos calibrate scene` as a job), stored as a scene calibration and
//! served to every later reconstruction of the scene until deleted.
//!
//! Why a job on its own thread: a fit builds `T` dozens of times (minutes
//! on a large wall); the request answers at once, `/events` tells its
//! progress and `DELETE /jobs/scene-fit-N` stops it.

use std::sync::atomic::AtomicBool;
use std::sync::Arc;

use serde::Deserialize;

use crate::calibrate::scene::{Freedom, SceneFitError, SceneFitOptions, Shot};
use crate::daemon::requests::validate::RequestError;
use crate::daemon::runtime::scene_registry::FittedGeometry;
use crate::daemon::Event;
use crate::scene::Scene;
use crate::stop::Stop;
use crate::store::{CaptureKind, JobState, SceneFitRow, Truth};

/// Most captures one scene calibration fits to.
pub(crate) const MAX_SCENE_FIT_CAPTURES: usize = 16;

/// Held while a scene calibration is checked and recorded.
static STARTING: std::sync::Mutex<()> = std::sync::Mutex::new(());

/// `POST /calibrations/scene` body.
#[derive(Debug, Clone, Deserialize, utoipa::ToSchema)]
#[serde(deny_unknown_fields)]
pub(crate) struct SceneFitBody {
    /// The scene whose geometry is fitted (its file's geometry is the first guess).
    pub scene: String,
    /// Done light captures of the scene (photos imported or taken), which
    /// share one geometry.
    #[serde(deserialize_with = "crate::integral::ints")]
    #[schema(min_items = 1, max_items = 16)]
    pub captures: Vec<i64>,
    /// What is fitted: occluder-x, occluder-y, occluder-z, scene-u,
    /// scene-v, distance, occluder-yaw, wall-u, wall-v (default the first six).
    pub free: Option<Vec<String>>,
    /// The image the hidden monitor showed in every capture (a calibration
    /// shot: a pattern name or an image, top row first), which poses the
    /// fit far better; absent: the scene is unknown and fitted with the geometry.
    pub known: Option<Truth>,
    /// Largest offset of a length from the file's value, metres (default 0.03).
    pub range_m: Option<f64>,
    /// Most `T` builds the fit may spend (default 80).
    pub max_evaluations: Option<usize>,
}

impl SceneFitBody {
    /// The calibration shot of plan `body` on its light `captures`.
    pub(crate) fn of_plan(body: &crate::daemon::requests::PlanBody, captures: Vec<i64>) -> Self {
        let shot = body.calibrate_scene.clone();
        let (known, free) = shot.map_or((None, None), |s| (s.known, s.free));
        Self {
            scene: body.scene.clone(),
            captures,
            free,
            known,
            range_m: None,
            max_evaluations: None,
        }
    }
}

/// A scene calibration's inputs, checked: what its thread runs.
struct Prepared {
    name: String,
    scene: Scene,
    source: String,
    folder: std::path::PathBuf,
    shots: Vec<Shot>,
    options: SceneFitOptions,
    free: Vec<String>,
}

impl super::Procedures {
    /// Checks `b`, records the scene calibration and starts its fit;
    /// returns its row (queued).
    pub fn fit_scene(&self, b: &SceneFitBody) -> Result<SceneFitRow, RequestError> {
        let store = &self.services.store;
        let described = |e: crate::store::StoreError| RequestError::Store(store.describe(&e));
        // Held from the look for a running fit to its row's insert, so two
        // requests at once do not both start one.
        let _one = STARTING.lock().unwrap_or_else(|e| e.into_inner());
        if let Some(r) = store
            .scene_fits()
            .map_err(described)?
            .into_iter()
            .find(|r| matches!(r.state, JobState::Queued | JobState::Running))
        {
            return Err(RequestError::Busy(format!(
                "scene calibration {} (scene {:?}) is {}: one fit runs at a time; wait for it or cancel it (DELETE /jobs/scene-fit-{})",
                r.id, r.scene, r.state.name(), r.id
            )));
        }
        let p = self.prepare_fit(b)?;
        let row = store
            .insert_scene_fit(&b.scene, &b.captures, &p.free, &p.source)
            .map_err(described)?;
        let this = self.clone();
        let id = row.id;
        let spawned = std::thread::Builder::new()
            .name(format!("scene-fit-{id}"))
            .spawn(move || this.run_fit(id, p));
        if let Err(e) = spawned {
            let why = format!("the fit's thread could not start: {e}");
            store
                .scene_fit_ended(id, JobState::Failed, &why)
                .map_err(described)?;
            return Err(RequestError::Unavailable(why));
        }
        Ok(row)
    }

    /// The scene, its captures as shots and the fit's options, or why not.
    fn prepare_fit(&self, b: &SceneFitBody) -> Result<Prepared, RequestError> {
        let invalid = RequestError::Invalid;
        if b.captures.is_empty() || b.captures.len() > MAX_SCENE_FIT_CAPTURES {
            return Err(invalid(format!(
                "captures: {} given; a scene calibration fits 1 to {MAX_SCENE_FIT_CAPTURES} captures of one bench",
                b.captures.len()
            )));
        }
        let now = self.services.scenes.now();
        let entry = now
            .entry(&b.scene)
            .ok_or_else(|| RequestError::NotFound(format!("no scene {:?}", b.scene)))?
            .as_written()
            .map_err(|e| invalid(format!("scene {:?}: {e}", b.scene)))?;
        let free = match &b.free {
            None => Freedom::DEFAULT.to_vec(),
            Some(names) => names
                .iter()
                .map(|n| {
                    Freedom::parse(n.trim()).ok_or_else(|| {
                        invalid(format!(
                            "free: {n:?} is not a freedom; they are {}",
                            Freedom::ALL.map(Freedom::name).join(", ")
                        ))
                    })
                })
                .collect::<Result<_, _>>()?,
        };
        let defaults = SceneFitOptions::default();
        let range = b.range_m.unwrap_or(defaults.range);
        if !(range > 0.0 && range <= 0.2) {
            return Err(invalid(format!(
                "range_m = {range}: must be above 0 and at most 0.2 (metres)"
            )));
        }
        let max_evaluations = b.max_evaluations.unwrap_or(defaults.max_evaluations);
        if !(8..=400).contains(&max_evaluations) {
            return Err(invalid(format!(
                "max_evaluations = {max_evaluations}: must be 8 to 400 T builds"
            )));
        }
        let shots = self.shots(&b.scene, &entry.scene, &b.captures, b.known.as_ref())?;
        Ok(Prepared {
            name: b.scene.clone(),
            scene: (*entry.scene).clone(),
            source: entry.source.clone(),
            folder: entry.folder.clone(),
            shots,
            options: SceneFitOptions {
                free: free.clone(),
                range,
                max_evaluations,
                budget: now.budget(),
                ..defaults
            },
            free: free.iter().map(|f| f.name().to_string()).collect(),
        })
    }

    /// Each capture's measurement in `T`'s row order, every row measured,
    /// with the known image where one is given.
    fn shots(
        &self,
        name: &str,
        scene: &Scene,
        ids: &[i64],
        known: Option<&Truth>,
    ) -> Result<Vec<Shot>, RequestError> {
        let invalid = RequestError::Invalid;
        let blocks = crate::transport::blocks_of(scene);
        let mut shots = Vec::with_capacity(ids.len());
        for &id in ids {
            let c = self.services.require_capture(id)?;
            if c.kind != CaptureKind::Light || c.state != JobState::Done || c.scene != name {
                return Err(invalid(format!(
                    "capture {id} is a {} capture of scene {:?} in state {}; a scene calibration needs done light captures of scene {name:?}",
                    c.kind.name(),
                    c.scene,
                    c.state.name()
                )));
            }
            let store = &self.services.store;
            let stacked = match c.is_imported() {
                true => crate::daemon::jobs::reconstruction::stack_imports(
                    store,
                    std::slice::from_ref(&c),
                    &blocks,
                    scene.wall().plane.grid.count(),
                ),
                false => crate::daemon::jobs::reconstruction::stack_records(
                    store,
                    vec![c],
                    scene,
                    &blocks,
                    &self.services.scenes.now().pixel_maps(name),
                    true,
                    true,
                ),
            }
            .map_err(|e| invalid(format!("capture {id}: {e}")))?;
            let channels: Vec<Vec<f64>> = stacked.measurements.into_iter().map(|m| m.i).collect();
            if let Some(bad) = channels
                .iter()
                .map(|ch| ch.iter().filter(|v| !v.is_finite()).count())
                .find(|&n| n > 0)
            {
                return Err(invalid(format!(
                    "capture {id} leaves {bad} of the scene's {} rows unmeasured (off the frame, saturated or lost): a scene calibration needs every row; take it with every block of the scene in view",
                    scene.rows()
                )));
            }
            let known = known
                .map(|k| k.channels(scene.hidden().plane.grid, channels.len(), "known"))
                .transpose()
                .map_err(|e| invalid(e.to_string()))?;
            shots.push(Shot { channels, known });
        }
        Ok(shots)
    }

    /// Runs scene calibration `id`'s fit to its end: stored, served and told.
    fn run_fit(&self, id: i64, p: Prepared) {
        let s = &self.services;
        let job = format!("scene-fit-{id}");
        let flag: Arc<AtomicBool> = s.registry.cancel_flag(&job);
        if let Err(e) = s.store.scene_fit_running(id) {
            tracing::error!("{job}: {}", s.store.describe(&e));
        }
        s.events.job(job.clone(), JobState::Running, None);
        tracing::info!(
            "{job} started: scene, {} captures, {:?}",
            p.shots.len(),
            p.free
        );
        let tell = |progress: crate::calibrate::scene::FitProgress| {
            s.events.emit(Event::SceneFit {
                job: job.clone(),
                builds: progress.builds,
                max_builds: progress.max_builds,
            })
        };
        let fitted = p
            .options
            .fit_telling(&p.scene, &p.shots, Stop::on(&flag), &tell)
            .and_then(|fit| {
                let placed = fit.placed_file(&p.source, &p.folder, &p.folder)?;
                Ok((fit, placed))
            });
        let ended = match fitted {
            Ok((fit, placed)) => self.fit_done(id, &p, &fit, placed),
            Err(SceneFitError::Stopped) if s.registry.is_stopping() => Err((
                JobState::Interrupted,
                "the daemon stopped during the fit; post it again".into(),
            )),
            Err(SceneFitError::Stopped) => Err((JobState::Cancelled, "cancelled".into())),
            Err(e) => Err((JobState::Failed, e.to_string())),
        };
        match ended {
            Ok(()) => s.events.job(job.clone(), JobState::Done, None),
            Err((state, why)) => {
                tracing::warn!("{job} {}: {why}", state.name());
                if let Err(e) = s.store.scene_fit_ended(id, state, &why) {
                    tracing::error!("{job}: {}", s.store.describe(&e));
                }
                s.events.job(job.clone(), state, Some(why));
            }
        }
        s.registry.forget(&job);
    }

    /// Stores a done fit and serves its geometry.
    fn fit_done(
        &self,
        id: i64,
        p: &Prepared,
        fit: &crate::calibrate::scene::SceneFit,
        placed: String,
    ) -> Result<(), (JobState, String)> {
        let s = &self.services;
        let failed = |why: String| (JobState::Failed, why);
        let mut report = serde_json::to_value(fit).map_err(|e| failed(e.to_string()))?;
        // The warnings in words too, for the page and a person reading the JSON.
        report["messages"] = fit.warnings.iter().map(|w| w.to_string()).collect();
        s.store
            .scene_fit_done(id, &placed, &report)
            .map_err(|e| failed(s.store.describe(&e)))?;
        s.scenes.set_fitted(
            &p.name,
            Some(FittedGeometry {
                calibration: id,
                source: p.source.clone(),
                placed,
            }),
        );
        tracing::info!(
            "scene-fit-{id}: scene {:?} placed, misfit {:.4e} -> {:.4e}, {} T builds in {:.1} s",
            p.name,
            fit.misfit_as_written,
            fit.misfit_fitted,
            fit.evaluations,
            fit.seconds
        );
        Ok(())
    }

    /// Deletes scene calibration `id`; its scene serves the geometry of
    /// the newest done one left, or its file's.
    pub fn delete_scene_fit(&self, id: i64) -> Result<(), RequestError> {
        let s = &self.services;
        let row = s.store.delete_scene_fit(id).map_err(|e| match e {
            crate::store::StoreError::NotFound { .. } => RequestError::NotFound(e.to_string()),
            crate::store::StoreError::InUse { .. } => RequestError::Busy(e.to_string()),
            e => RequestError::Store(s.store.describe(&e)),
        })?;
        let in_force = s
            .store
            .scene_fits_in_force()
            .map_err(|e| RequestError::Store(s.store.describe(&e)))?
            .into_iter()
            .find(|r| r.scene == row.scene);
        s.scenes
            .set_fitted(&row.scene, in_force.and_then(fitted_geometry));
        Ok(())
    }
}

/// Serves each scene with the geometry of its newest done scene calibration
/// (at the daemon's start).
pub(crate) fn place_fitted_scenes(
    store: &crate::store::Store,
    scenes: &crate::daemon::SceneRegistry,
) {
    match store.scene_fits_in_force() {
        Ok(rows) => {
            for row in rows {
                let name = row.scene.clone();
                scenes.set_fitted(&name, fitted_geometry(row));
            }
        }
        Err(e) => tracing::error!(
            "the scene calibrations could not be read ({}); scenes serve as written",
            store.describe(&e)
        ),
    }
}

/// A done scene calibration's geometry, as the scene registry serves it.
fn fitted_geometry(row: SceneFitRow) -> Option<FittedGeometry> {
    Some(FittedGeometry {
        calibration: row.id,
        placed: row.placed_toml?,
        source: row.source_toml,
    })
}
