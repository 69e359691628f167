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
//! - [`requests`]: what clients ask for (capture, reconstruction and
//!   calibration bodies), checked by [`validate`] and admitted by
//!   `admission` (disk space and queue room); `capture`/`reconstruction`:
//!   the workers; `camera`: settings and what `GET /camera` shows;
//!   `metrics`: `/metrics` samples.

mod admission;
mod calibration;
mod camera;
mod cancel;
mod capture;
pub mod config;
mod demo;
pub mod events;
mod integral;
mod jobs;
pub mod metrics;
mod progressive;
mod reconstruction;
pub mod requests;
mod retention;
pub mod scenes;
pub mod validate;

use std::collections::BTreeMap;
use std::sync::Arc;

use tokio::sync::{broadcast, mpsc, Mutex};

pub use admission::SubmitError;
pub use calibration::{FittedPosition, GeometryCalibration, SourcePosition, WallCalibration};
pub use camera::{CameraView, SettingsError};
pub use cancel::{CancelError, JobKind};
pub use config::Config;
pub use demo::DEMO_SOURCE;
pub use events::Event;
pub use progressive::{
    Step as ProgressiveStep, IMAGE as PROGRESSIVE_IMAGE, STEPS as PROGRESSIVE_STEPS,
};
pub use validate::RequestError;

use crate::camera::aravis::AravisCamera;
use crate::camera::fake::{Bench, FakeBench, ManualBench};
use crate::camera::hotplug::Hotplug;
use crate::camera::synthetic::SyntheticBench;
use crate::camera::worker::{CameraHandle, Opener};
use crate::camera::{CameraDevice, CameraSettings};
use crate::store::Store;
use crate::transport::MemoryBudget;
use metrics::Metrics;
use scenes::Scenes;

/// Exposure at which the fake camera's demo image fills 80 % of full scale
/// (unpolarized peak), microseconds.
pub const DEMO_REFERENCE_EXPOSURE_US: f64 = 20_000.0;
const DEMO_PEAK_FRACTION: f64 = 0.8;

/// Why the daemon could not start.
#[derive(Debug, thiserror::Error)]
pub enum DaemonError {
    /// Bad configuration.
    #[error(transparent)]
    Config(#[from] config::ConfigError),
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
            let mut fake =
                FakeBench::start(&address, "POLNLOS-DEMO", frames, DEMO_REFERENCE_EXPOSURE_US)?;
            if !config.demo.bench_switches_scene {
                fake = fake.operated_by_hand();
            }
            tracing::info!(
                address,
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
    /// involved (see [`crate::camera::synthetic`]).
    pub async fn synthetic(config: &Config, scenes: &Arc<Scenes>) -> Result<Self, DaemonError> {
        let (frames, c) = demo_frames(&config.demo, scenes).await?;
        let bench = SyntheticBench::new(frames, DEMO_REFERENCE_EXPOSURE_US);
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
    demo: &config::DemoConfig,
    scenes: &Arc<Scenes>,
) -> Result<(crate::camera::BenchImages, f64), DaemonError> {
    let (scenes, demo) = (scenes.clone(), demo.clone());
    tokio::task::spawn_blocking(move || demo::frames(&scenes, &demo))
        .await
        .map_err(|e| DaemonError::Demo(e.to_string()))?
}

/// Everything the routes and the jobs share.
pub struct Daemon {
    config: Config,
    /// Bearer token ("" = none).
    token: String,
    store: Arc<Store>,
    scenes: Arc<Scenes>,
    camera: CameraHandle,
    bench: Arc<dyn Bench>,
    captures: mpsc::Sender<i64>,
    reconstructions: mpsc::Sender<i64>,
    events: broadcast::Sender<Event>,
    metrics: Metrics,
    /// Fraction of full scale per microsecond per unit of `T l`, per scene.
    calibration: BTreeMap<String, f64>,
    /// Held by the capture worker for a whole capture: a settings change
    /// that cannot have the camera answers 409 instead of waiting.
    camera_gate: tokio::sync::Mutex<()>,
    /// Settings from the last `PUT /camera/settings`, inherited by captures
    /// that do not state their own (None: the camera's read-back ones).
    defaults: std::sync::Mutex<Option<CameraSettings>>,
    /// Disk bytes reserved by queued and running captures, by capture id.
    reserved: std::sync::Mutex<BTreeMap<i64, u64>>,
    /// Progressive reconstructions asked for with queued captures, by capture id.
    progressive: std::sync::Mutex<BTreeMap<i64, validate::ProgressiveSpec>>,
    /// The latest frame a capture received (the page's live view).
    latest_frame: std::sync::Mutex<Option<Arc<crate::camera::RawFrame>>>,
    /// Cancel flags of running (or just cancelled) jobs, by job id.
    cancels: std::sync::Mutex<BTreeMap<String, Arc<std::sync::atomic::AtomicBool>>>,
    /// True once [`Daemon::drain`] starts: the workers stop taking jobs, and
    /// a job stopped from then on ends `interrupted`, not `cancelled`.
    stop: tokio::sync::watch::Sender<bool>,
    /// The job workers and background tasks, joined by [`Daemon::drain`].
    workers: std::sync::Mutex<tokio::task::JoinSet<()>>,
    _hotplug: Option<Hotplug>,
}

impl Daemon {
    /// Starts with the camera the config names (see [`CameraSetup::configured`]).
    /// The data directory is opened, and locked, before any camera starts: a
    /// second daemon on the same directory stops there, touching nothing.
    /// Every scene's `T` is built within `budget`.
    pub async fn start(config: Config, budget: MemoryBudget) -> Result<Arc<Self>, DaemonError> {
        config.validate()?;
        let store = Store::open(&config.data_dir)?;
        let scenes = Arc::new(Scenes::load(&config.scene_files, budget)?);
        let camera = CameraSetup::configured(&config, &scenes).await?;
        Self::start_with(config, store, scenes, camera).await
    }

    /// Starts the camera thread on `camera` and the job workers, over an
    /// open store (`Store::open` of the config's data directory).
    pub async fn start_with(
        config: Config,
        store: Store,
        scenes: Arc<Scenes>,
        camera: CameraSetup,
    ) -> Result<Arc<Self>, DaemonError> {
        config.validate()?;
        let token = config.resolved_token()?;
        let store = Arc::new(store);
        let mut calibration = config.calibration.clone();
        if let Some(c) = camera.demo_calibration {
            for name in scenes.names() {
                calibration.entry(name).or_insert(c);
            }
        }
        let handle = CameraHandle::spawn(camera.opener);
        let hotplug = if camera.watch_usb {
            let rescan = handle.clone();
            Hotplug::start(move || rescan.rescan())
        } else {
            None
        };
        let (capture_tx, capture_rx) = mpsc::channel(config.queue.captures);
        let (recon_tx, recon_rx) = mpsc::channel(config.queue.reconstructions);
        let workers = config.queue.reconstruction_workers;
        let daemon = Arc::new(Self {
            config,
            token,
            store,
            scenes,
            camera: handle,
            bench: camera.bench,
            captures: capture_tx,
            reconstructions: recon_tx,
            events: broadcast::channel(1024).0,
            metrics: Metrics::default(),
            calibration,
            camera_gate: tokio::sync::Mutex::new(()),
            defaults: std::sync::Mutex::new(None),
            reserved: std::sync::Mutex::new(BTreeMap::new()),
            progressive: std::sync::Mutex::new(BTreeMap::new()),
            latest_frame: std::sync::Mutex::new(None),
            cancels: std::sync::Mutex::new(BTreeMap::new()),
            stop: tokio::sync::watch::channel(false).0,
            workers: std::sync::Mutex::new(tokio::task::JoinSet::new()),
            _hotplug: hotplug,
        });
        {
            let mut set = daemon.workers.lock().unwrap_or_else(|e| e.into_inner());
            set.spawn(capture::capture_worker(daemon.clone(), capture_rx));
            let shared = Arc::new(Mutex::new(recon_rx));
            for _ in 0..workers {
                set.spawn(reconstruction::reconstruction_worker(
                    daemon.clone(),
                    shared.clone(),
                ));
            }
            set.spawn(until_stopped(daemon.clone(), watch_camera(daemon.clone())));
            set.spawn(until_stopped(
                daemon.clone(),
                retention::retention_task(daemon.clone()),
            ));
        }
        Ok(daemon)
    }

    /// Configuration in force.
    pub fn config(&self) -> &Config {
        &self.config
    }

    /// Bearer token clients must send ("" = none).
    pub fn token(&self) -> &str {
        &self.token
    }

    /// The catalogue of captures and reconstructions.
    pub fn store(&self) -> &Store {
        &self.store
    }

    /// Names of the scenes the daemon knows.
    pub fn scene_names(&self) -> Vec<String> {
        self.scenes.names()
    }

    /// Names of the poses of every scene the daemon knows, sorted, once each.
    pub fn pose_names(&self) -> Vec<String> {
        let mut names: Vec<String> = self
            .scenes
            .names()
            .iter()
            .filter_map(|n| self.scenes.get(n))
            .flat_map(|s| s.poses().iter().map(|p| p.name.clone()).collect::<Vec<_>>())
            .collect();
        names.sort();
        names.dedup();
        names
    }

    /// Whether the camera is open now.
    pub fn camera_connected(&self) -> bool {
        self.camera.status().connected
    }

    /// The latest frame a capture received, if any.
    pub fn latest_frame(&self) -> Option<Arc<crate::camera::RawFrame>> {
        self.latest_frame.lock().ok().and_then(|f| f.clone())
    }

    /// Job, frame and camera events from now on.
    pub fn subscribe(&self) -> broadcast::Receiver<Event> {
        self.events.subscribe()
    }

    /// Publishes an event (nobody listening is fine).
    fn emit(&self, e: Event) {
        let _ = self.events.send(e);
    }

    /// Stops the camera thread.
    pub fn shutdown(&self) {
        self.camera.shutdown();
    }

    /// Whether [`Daemon::drain`] has started.
    pub fn is_stopping(&self) -> bool {
        *self.stop.borrow()
    }

    /// A receiver that changes once [`Daemon::drain`] starts (for workers to
    /// stop waiting for jobs).
    pub(crate) fn stopped(&self) -> tokio::sync::watch::Receiver<bool> {
        self.stop.subscribe()
    }

    /// Stops for good: no job is taken from the queues any more, the
    /// running ones are stopped (recorded `interrupted`, their partial files
    /// removed as a cancellation removes them), the workers are joined
    /// within `grace` (those still busy after it are aborted), then the
    /// camera thread stops. Queued jobs stay queued in the catalogue; the
    /// next start marks them `interrupted`.
    pub async fn drain(&self, grace: std::time::Duration) {
        self.stop.send_replace(true);
        if let Ok(flags) = self.cancels.lock() {
            for flag in flags.values() {
                flag.store(true, std::sync::atomic::Ordering::SeqCst);
            }
        }
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
async fn until_stopped(d: Arc<Daemon>, task: impl std::future::Future<Output = ()>) {
    let mut stopped = d.stopped();
    tokio::select! {
        () = task => {}
        _ = stopped.wait_for(|s| *s) => {}
    }
}

/// Emits camera connect/lose events.
async fn watch_camera(d: Arc<Daemon>) {
    let mut last = None;
    loop {
        let s = d.camera.status();
        if last != Some(s.connected) {
            d.emit(Event::Camera {
                connected: s.connected,
                error: s.last_error.clone(),
            });
            last = Some(s.connected);
        }
        tokio::time::sleep(std::time::Duration::from_millis(250)).await;
    }
}
