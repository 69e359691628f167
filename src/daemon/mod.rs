//! The acquisition daemon: wires the camera thread, the bench, the store, the
//! scene registry and the job queues together into a typed state, [`Daemon`],
//! that a front end drives. The HTTP API is one such front end; it depends on
//! this module, never the reverse.
//!
//! Captures queue for the single camera and run one at a time; reconstructions
//! queue for a small worker pool and run their maths on blocking threads. Both
//! queues are bounded: a full queue is refused at once (HTTP 429), never waited on.
//!
//! - [`Daemon::start`] opens what the config names; [`Daemon::start_with`]
//!   takes any camera ([`CameraSetup`]), e.g. the in-process synthetic one.
//! - Four folders, each a handful of small handles that own their state:
//!   - `runtime`: the config, the bounded job queues and the disk
//!     captures reserved, the registry (cancel flags and the stop), the
//!     event stream, the metrics, retention, the scenes (their `T` and
//!     Gram, cached), the camera service (`CameraService`: the camera,
//!     who holds it, the settings captures inherit, the live view) and the
//!     fake camera's demo;
//!   - `requests`: what clients ask for (capture, reconstruction and
//!     calibration bodies), checked by `requests::validate`, admitted by
//!     `Admission` (disk space and queue room) and cancelled through it;
//!   - `jobs`: the capture, reconstruction and progressive workers and
//!     what they share (`JobContext`);
//!   - `procedures`: plans, the pose and wall calibrations and the mount's
//!     zero, which string jobs together.
//! - The bench's devices are the rig ([`crate::rig`]), beside the camera.
//!   Workers hold the handles they use, never the daemon.

pub(crate) mod jobs;
pub(crate) mod procedures;
pub(crate) mod requests;
pub(crate) mod runtime;

use std::collections::BTreeMap;
use std::sync::Arc;

use tokio::sync::Mutex;

pub use crate::rig::Automated;
pub(crate) use jobs::progressive::{IMAGE as PROGRESSIVE_IMAGE, STEPS as PROGRESSIVE_STEPS};
pub use procedures::calibration::RadiometricGain;
pub(crate) use procedures::calibration::{
    Calibrations, FittedPosition, GeometryCalibration, SourcePosition, WallCalibration,
};
pub(crate) use procedures::colour::ColourCalibration;
pub(crate) use procedures::mount_zero::{SweepPoint, ZeroFit};
pub use procedures::plans::{steps_of, PlanStep};
pub(crate) use procedures::plans::{PlanError, PlanView};
pub(crate) use procedures::scene_fit::SceneFitBody;
pub(crate) use requests::cancel::{CancelError, JobKind};
pub(crate) use requests::validate::RequestError;
pub use requests::validate::{
    capture as validate_capture, reconstruction as validate_reconstruction, CameraContext,
};
pub(crate) use requests::{ZeroBody, ZeroLight};
pub(crate) use runtime::camera::{CameraService, CameraView, DemoView, SettingsError};
pub use runtime::config::{log_targets, Config, ConfigError, DEFAULT_TOML};
pub use runtime::events::Event;
pub(crate) use runtime::events::{Events, Step as ProgressiveStep};
pub(crate) use runtime::queue::SubmitError;

use crate::camera::aravis::AravisCamera;
use crate::camera::fake::FakeBench;
use crate::camera::hotplug::Hotplug;
use crate::camera::synthetic::SyntheticBench;
use crate::camera::worker::{CameraHandle, Opener};
use crate::camera::CameraDevice;
use crate::rig;
use crate::rig::bench::{Bench, ManualBench};
use crate::store::Store;
use crate::transport::MemoryBudget;
use runtime::metrics::Metrics;
use runtime::queue::{CaptureQueue, Queue};
use runtime::registry::JobRegistry;
pub use runtime::scene_registry::SceneRegistry;
pub use runtime::scenes::Scenes;

/// Exposure at which the fake camera's demo image fills 80 % of full scale
/// (unpolarized peak), microseconds.
pub(crate) const DEMO_REFERENCE_EXPOSURE_US: f64 = 20_000.0;
const DEMO_PEAK_FRACTION: f64 = 0.8;

/// Why the daemon could not start.
#[derive(Debug, thiserror::Error)]
pub enum DaemonError {
    /// Bad configuration.
    #[error(transparent)]
    Config(#[from] runtime::config::ConfigError),
    /// A scene file is wrong.
    #[error(transparent)]
    Scene(#[from] crate::scene::SceneError),
    /// The store cannot be opened.
    #[error(transparent)]
    Store(#[from] crate::store::StoreError),
    /// The demo scene could not be rendered.
    #[error("demo scene: {0}")]
    Demo(String),
    /// The fake camera did not start.
    #[error(transparent)]
    Fake(#[from] crate::camera::fake::FakeError),
    /// The simulated rotation mount did not start.
    #[error(transparent)]
    Mount(#[from] crate::rig::mount::MountError),
    /// The simulated relay did not start.
    #[error(transparent)]
    Light(#[from] crate::rig::relay::RelayError),
}

/// The daemon's camera: how to open it, the bench around it, and the
/// radiometric calibration a demo bench implies.
pub struct CameraSetup {
    /// Opens the camera, and again after it was lost.
    pub opener: Opener,
    /// Moves the bench and switches the hidden scene.
    pub bench: Arc<dyn Bench>,
    /// Calibration of a demo bench, for scenes the config does not calibrate.
    pub demo_calibration: Option<f64>,
    /// Rescan for cameras when a USB device arrives (real cameras only).
    pub watch_usb: bool,
}

impl CameraSetup {
    /// What the config names: an Aravis camera by id or address, and with
    /// `[camera] fake = true` Aravis's fake camera showing the demo scene.
    pub async fn configured(config: &Config, scenes: &Arc<Scenes>) -> Result<Self, DaemonError> {
        let target = config.camera.id.clone().or(config.camera.address.clone());
        let (bench, demo_calibration): (Arc<dyn Bench>, _) = if config.camera.fake {
            let address = config
                .camera
                .address
                .clone()
                .unwrap_or_else(|| "127.0.0.1".into());
            let (frames, c) = demo_frames(&config.demo, scenes).await?;
            let mut fake = FakeBench::start_with(
                &address,
                "POLNLOS-DEMO",
                frames,
                DEMO_REFERENCE_EXPOSURE_US,
                config.camera.fake_sensor,
            )?;
            if !config.demo.bench_switches_scene {
                fake = fake.operated_by_hand();
            }
            if config.demo.sensor_noise {
                fake =
                    fake.with_sensor_noise(config.camera.full_well_e, config.camera.read_noise_e);
            }
            tracing::info!(
                address,
                sensor = ?config.camera.fake_sensor,
                "Aravis GigE Vision fake camera started (demo scene {:?}, pattern {:?})",
                config.demo.scene,
                config.demo.pattern
            );
            (Arc::new(fake), Some(c))
        } else {
            (Arc::new(ManualBench), None)
        };
        let target = target.unwrap_or_default();
        Ok(Self {
            opener: Box::new(move || {
                AravisCamera::open(&target).map(|c| Box::new(c) as Box<dyn CameraDevice>)
            }),
            bench,
            demo_calibration,
            watch_usb: true,
        })
    }

    /// An in-process camera showing the config's demo scene, no Aravis
    /// involved (see `crate::camera::synthetic`).
    pub async fn synthetic(config: &Config, scenes: &Arc<Scenes>) -> Result<Self, DaemonError> {
        let (frames, c) = demo_frames(&config.demo, scenes).await?;
        let mut bench = SyntheticBench::new(frames, DEMO_REFERENCE_EXPOSURE_US);
        if config.demo.sensor_noise {
            bench = bench.with_sensor_noise(config.camera.full_well_e, config.camera.read_noise_e);
        }
        Ok(Self {
            opener: bench.opener(),
            bench: Arc::new(bench),
            demo_calibration: Some(c),
            watch_usb: false,
        })
    }
}

/// The demo scene's wall images, rendered off the async runtime.
async fn demo_frames(
    demo: &runtime::config::DemoConfig,
    scenes: &Arc<Scenes>,
) -> Result<(crate::camera::BenchImages, f64), DaemonError> {
    let (scenes, demo) = (scenes.clone(), demo.clone());
    tokio::task::spawn_blocking(move || runtime::demo::frames(&scenes, &demo))
        .await
        .map_err(|e| DaemonError::Demo(e.to_string()))?
}

/// The daemon as a front end sees it: the configuration and the services,
/// each owning its state and its lock. Workers get only the services they
/// use (`JobContext`, the camera, the capture queue, the plan runner's
/// `Plans`), never this.
pub struct Daemon {
    config: Arc<Config>,
    /// Bearer token ("" = none).
    token: String,
    store: Arc<Store>,
    scenes: Arc<SceneRegistry>,
    /// Fraction of full scale per microsecond per unit of `T l`, per scene.
    calibration: Arc<BTreeMap<String, f64>>,
    camera: Arc<CameraService>,
    /// The bench's devices: stage, rotation mount, light relay.
    rig: Arc<rig::Rig>,
    /// Admits and cancels captures and reconstructions.
    admission: Arc<requests::admission::Admission>,
    /// The acquisition plans and their runner's state.
    plans: Arc<procedures::plans::Plans>,
    /// The calibrations and the mount's zero.
    procedures: procedures::Procedures,
    captures: Arc<CaptureQueue>,
    reconstructions: Queue,
    registry: Arc<JobRegistry>,
    events: Events,
    metrics: Arc<Metrics>,
    /// The live view: started and stopped over HTTP, run by the capture worker.
    live: Arc<runtime::live::Live>,
    /// The job workers and background tasks, joined by [`Daemon::drain`].
    workers: std::sync::Mutex<tokio::task::JoinSet<()>>,
}

impl Daemon {
    /// Starts with the camera the config names (see [`CameraSetup::configured`]).
    /// The data directory is opened, and locked, before any camera starts: a
    /// second daemon on the same directory stops there, touching nothing.
    /// Every scene's `T` is built within `budget`.
    pub async fn start(config: Config, budget: MemoryBudget) -> Result<Arc<Self>, DaemonError> {
        config.validate()?;
        let store = Store::open(&config.data_dir)?;
        let scenes = Arc::new(SceneRegistry::open(
            &config.scene_files,
            &config.data_dir,
            budget,
        )?);
        let camera = CameraSetup::configured(&config, &scenes.now()).await?;
        Self::start_with(config, store, scenes, camera).await
    }

    /// Starts the camera thread on `camera` and the job workers, over an
    /// open store (`Store::open` of the config's data directory).
    pub async fn start_with(
        config: Config,
        store: Store,
        scenes: Arc<SceneRegistry>,
        camera: CameraSetup,
    ) -> Result<Arc<Self>, DaemonError> {
        config.validate()?;
        let token = config.resolved_token()?;
        let mut calibration = config.calibration.clone();
        if let Some(c) = camera.demo_calibration {
            for name in scenes.now().names() {
                calibration.entry(name).or_insert(c);
            }
        }
        procedures::scene_fit::place_fitted_scenes(&store, &scenes);
        let handle = CameraHandle::spawn(camera.opener);
        let hotplug = if camera.watch_usb {
            let rescan = handle.clone();
            Hotplug::start(move || rescan.rescan())
        } else {
            None
        };
        let zero_file = store.dir().join("mount-zero.json");
        let rig = Arc::new(rig::Rig::new(
            rig::mount::MountService::start(&config.mount, Some(zero_file))?,
            rig::stage::StageService::start(&config.stage),
            rig::relay::LightService::start(&config.light)?,
            camera.bench.clone(),
        ));
        let (captures, capture_rx) = CaptureQueue::new(config.queue.captures);
        let (reconstructions, recon_rx) =
            Queue::new("reconstruction", config.queue.reconstructions);
        let pool = config.queue.reconstruction_workers;
        let config = Arc::new(config);
        let store = Arc::new(store);
        let calibration = Arc::new(calibration);
        let demo = camera.demo_calibration.map(|_| runtime::camera::DemoView {
            scene: config.demo.scene.clone(),
            pattern: config.demo.pattern.clone(),
        });
        let camera = Arc::new(CameraService::new(handle, hotplug, demo));
        let captures = Arc::new(captures);
        let registry = Arc::new(JobRegistry::default());
        let events = Events::new(1024);
        let metrics = Arc::new(Metrics::default());
        let live = Arc::new(runtime::live::Live::default());
        let admission = Arc::new(requests::admission::Admission {
            config: config.clone(),
            store: store.clone(),
            scenes: scenes.clone(),
            calibration: calibration.clone(),
            camera: camera.clone(),
            rig: rig.clone(),
            captures: captures.clone(),
            reconstructions: reconstructions.clone(),
            registry: registry.clone(),
            events: events.clone(),
            metrics: metrics.clone(),
            live: live.clone(),
        });
        let plans = Arc::new(procedures::plans::Plans::new(admission.clone()));
        let procedures = procedures::Procedures::new(admission.clone());
        let daemon = Arc::new(Self {
            config,
            token,
            store,
            scenes,
            calibration,
            camera,
            rig,
            admission,
            plans,
            procedures,
            captures,
            reconstructions,
            registry,
            events,
            metrics,
            live,
            workers: std::sync::Mutex::new(tokio::task::JoinSet::new()),
        });
        {
            let d = &daemon;
            let mut set = d.workers.lock().unwrap_or_else(|e| e.into_inner());
            let capture = jobs::capture::CaptureWorker {
                jobs: d.job_context(),
                camera: d.camera.clone(),
                rig: d.rig.clone(),
                queue: d.captures.clone(),
                lost_frames: d.config.camera.lost_frames,
                // Checked to be 0..=1 by Config::validate.
                saturated: (d.config.camera.saturated, d.config.camera.saturated_share),
                // Checked to be 0..=86400 by Config::validate.
                stall_slack: std::time::Duration::from_secs_f64(
                    d.config.camera.stall_slack_s.clamp(0.0, 86_400.0),
                ),
                live: d.live.clone(),
            };
            set.spawn(capture.run(capture_rx));
            let shared = Arc::new(Mutex::new(recon_rx));
            for _ in 0..pool {
                set.spawn(jobs::reconstruction::reconstruction_worker(
                    d.job_context(),
                    shared.clone(),
                ));
            }
            let stopped = d.registry.stopped();
            let camera = watch_camera(d.camera.clone(), d.events.clone());
            set.spawn(until_stopped(stopped.clone(), camera));
            let retention = runtime::retention::retention_task(
                d.store.clone(),
                d.events.clone(),
                d.config.retention.clone(),
            );
            set.spawn(until_stopped(stopped, retention));
            set.spawn(procedures::plans::run(d.plans.clone()));
        }
        daemon.resume_reconstructions();
        Ok(daemon)
    }

    /// Queues again the reconstructions a previous run left queued or
    /// running (the store put them back: their inputs are stored captures);
    /// one the queue has no room for is recorded interrupted, with why.
    fn resume_reconstructions(&self) {
        let ids = match self.store.queued_reconstructions() {
            Ok(ids) => ids,
            Err(e) => {
                tracing::error!("cannot list the reconstructions to resume: {e}");
                return;
            }
        };
        for id in ids {
            match self.reconstructions.push(0, || Ok(id)) {
                Ok(_) => {
                    tracing::info!("reconstruction-{id} resumed: queued again after a restart")
                }
                Err(e) => {
                    tracing::warn!("reconstruction-{id} not resumed: {e}");
                    let why = "the reconstruction queue was full when the daemon started again; submit it again";
                    if let Err(se) = self.store.reconstruction_not_resumed(id, why) {
                        tracing::error!(
                            "cannot record that reconstruction-{id} was not resumed: {se}"
                        );
                    }
                }
            }
        }
    }

    /// The services a job worker holds.
    fn job_context(&self) -> jobs::JobContext {
        jobs::JobContext {
            store: self.store.clone(),
            scenes: self.scenes.now(),
            scene_registry: self.scenes.clone(),
            calibration: self.calibration.clone(),
            registry: self.registry.clone(),
            events: self.events.clone(),
            metrics: self.metrics.clone(),
        }
    }

    /// Configuration in force.
    pub fn config(&self) -> &Config {
        &self.config
    }

    /// Bearer token clients must send ("" = none).
    pub fn token(&self) -> &str {
        &self.token
    }

    /// The door every capture, reconstruction, import, block exposure and
    /// cancel goes through, from a client or a plan.
    pub(crate) fn requests(&self) -> &Arc<requests::admission::Admission> {
        &self.admission
    }

    /// The live view's state and newest image.
    pub fn live(&self) -> &runtime::live::Live {
        &self.live
    }

    /// The calibrations (pose, wall, colour) and the mount's zero.
    pub(crate) fn procedures(&self) -> &procedures::Procedures {
        &self.procedures
    }

    /// The bench plans: their requests, views and runner's state.
    pub(crate) fn plans(&self) -> &Arc<procedures::plans::Plans> {
        &self.plans
    }

    /// The catalogue of captures and reconstructions.
    pub fn store(&self) -> &Store {
        &self.store
    }

    /// The camera: its settings, state, live view.
    pub fn camera(&self) -> &CameraService {
        &self.camera
    }

    /// The bench's devices beside the camera: the rotation mount, the
    /// camera stage, the light relay.
    pub(crate) fn rig(&self) -> &rig::Rig {
        &self.rig
    }

    /// The scenes the daemon knows now, with their `T`s and pixel maps.
    pub fn scenes(&self) -> Arc<Scenes> {
        self.scenes.now()
    }

    /// The scenes, to change (`POST /scenes`, SIGHUP).
    pub fn scene_registry(&self) -> &SceneRegistry {
        &self.scenes
    }

    /// Reads every scene file again (SIGHUP), running jobs untouched.
    pub fn reload_scenes(&self) -> Vec<runtime::scenes::SceneListing> {
        let listing = self.scenes.reload();
        let broken = listing.iter().filter(|l| l.error.is_some()).count();
        tracing::info!(
            "scenes read again: {} served, {broken} not loaded",
            listing.len() - broken
        );
        listing
    }

    /// Job, frame and camera events from now on.
    pub fn subscribe(&self) -> tokio::sync::broadcast::Receiver<Event> {
        self.events.subscribe()
    }

    /// Ends the open event streams (the HTTP server is stopping).
    pub fn close_streams(&self) {
        self.events.close();
    }

    /// Resolves once [`Daemon::close_streams`] was called.
    pub fn streams_closed(&self) -> impl std::future::Future<Output = ()> + Send + 'static {
        self.events.closed()
    }

    /// Stops the camera thread.
    pub fn shutdown(&self) {
        self.camera.shutdown();
    }

    /// Whether [`Daemon::drain`] has started.
    pub fn is_stopping(&self) -> bool {
        self.registry.is_stopping()
    }

    /// Stops for good: no job is taken from the queues any more, the
    /// running ones are stopped (recorded `interrupted`, their partial files
    /// removed as a cancellation removes them), the workers are joined
    /// within `grace` (those still busy after it are aborted), then the
    /// camera thread stops. Queued jobs stay queued in the catalogue; the
    /// next start marks them `interrupted`.
    pub async fn drain(&self, grace: std::time::Duration) {
        self.registry.stop_all();
        let mut set = std::mem::take(&mut *self.workers.lock().unwrap_or_else(|e| e.into_inner()));
        let joined =
            tokio::time::timeout(grace, async { while set.join_next().await.is_some() {} }).await;
        if joined.is_err() {
            tracing::warn!(
                "{} workers still busy {:.1} s after the stop; aborting them",
                set.len(),
                grace.as_secs_f64()
            );
            set.shutdown().await;
        }
        self.camera.shutdown();
    }
}

/// Runs `task` until the daemon starts draining.
async fn until_stopped(
    mut stopped: tokio::sync::watch::Receiver<bool>,
    task: impl std::future::Future<Output = ()>,
) {
    tokio::select! {
        () = task => {}
        _ = stopped.wait_for(|s| *s) => {}
    }
}

/// Emits camera connect/lose events.
async fn watch_camera(camera: Arc<CameraService>, events: Events) {
    let mut last = None;
    loop {
        let s = camera.status();
        if last != Some(s.connected) {
            events.emit(Event::Camera {
                connected: s.connected,
                error: s.last_error.clone(),
            });
            last = Some(s.connected);
        }
        tokio::time::sleep(std::time::Duration::from_millis(250)).await;
    }
}
