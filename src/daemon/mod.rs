//! The acquisition daemon: wires the camera thread, the bench, the store, the
//! scene registry and the job queues together, and hands a typed state to the
//! HTTP routes in [`crate::api`].
//!
//! Captures queue for the single camera and run one at a time; reconstructions
//! queue for a small worker pool and run their maths on blocking threads. Both
//! queues are bounded: a full queue is refused at once (HTTP 429), never waited on.

mod capture;
mod capture_request;
pub mod config;
mod demo;
pub mod events;
mod jobs;
pub mod metrics;
mod reconstruction;
pub mod scenes;

use std::collections::BTreeMap;
use std::sync::Arc;

use tokio::sync::{broadcast, mpsc, Mutex};

pub use capture_request::{validate_capture, AutoExposure, CaptureBody};
pub use config::Config;
pub use events::Event;
pub use jobs::{camera_limits, exposure_plan, RequestError};
pub use reconstruction::{validate_reconstruction, ReconstructionBody};

use crate::camera::aravis::AravisCamera;
use crate::camera::fake::{Bench, FakeBench, ManualBench};
use crate::camera::hotplug::Hotplug;
use crate::camera::worker::CameraHandle;
use crate::camera::{CameraDevice, CameraInfo, CameraSettings};
use crate::store::{CaptureRequest, Store};
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

/// Everything the routes and the jobs share.
pub struct Daemon {
    /// Configuration in force.
    pub config: Config,
    /// Bearer token ("" = none).
    pub token: String,
    /// Catalogue.
    pub store: Arc<Store>,
    /// Known scenes.
    pub scenes: Arc<Scenes>,
    /// The camera thread.
    pub camera: CameraHandle,
    /// The bench (pose/polarizer selection, scene on/off).
    pub bench: Arc<dyn Bench>,
    /// Capture queue.
    pub captures: mpsc::Sender<i64>,
    /// Reconstruction queue.
    pub reconstructions: mpsc::Sender<i64>,
    /// Event stream.
    pub events: broadcast::Sender<Event>,
    /// Counters.
    pub metrics: Metrics,
    /// Fraction of full scale per microsecond per unit of `T l`, per scene.
    pub calibration: BTreeMap<String, f64>,
    /// Held by the capture worker for a whole capture: a settings change
    /// that cannot have the camera answers 409 instead of waiting.
    camera_gate: tokio::sync::Mutex<()>,
    /// Settings from the last `PUT /camera/settings`, inherited by captures
    /// that do not state their own (None: the camera's read-back ones).
    defaults: std::sync::Mutex<Option<CameraSettings>>,
    /// Disk bytes reserved by queued and running captures, by capture id.
    reserved: std::sync::Mutex<BTreeMap<i64, u64>>,
    _hotplug: Option<Hotplug>,
    _fake: Option<Arc<FakeBench>>,
}

impl Daemon {
    /// Starts the camera thread, the fake bench (if configured) and the job workers.
    pub async fn start(config: Config) -> Result<Arc<Self>, DaemonError> {
        config.validate()?;
        let token = config.resolved_token()?;
        let store = Arc::new(Store::open(&config.data_dir)?);
        let scenes = Arc::new(Scenes::load(&config.scene_files)?);
        let mut calibration = config.calibration.clone();

        let (bench, fake): (Arc<dyn Bench>, Option<Arc<FakeBench>>) = if config.camera.fake {
            let address = config
                .camera
                .address
                .clone()
                .unwrap_or_else(|| "127.0.0.1".into());
            let scenes2 = scenes.clone();
            let demo = config.demo.clone();
            let (frames, c) = tokio::task::spawn_blocking(move || demo::frames(&scenes2, &demo))
                .await
                .map_err(|e| DaemonError::Demo(e.to_string()))??;
            for name in scenes.names() {
                calibration.entry(name).or_insert(c);
            }
            let mut fake =
                FakeBench::start(&address, "POLNLOS-DEMO", frames, DEMO_REFERENCE_EXPOSURE_US)?;
            if !config.demo.bench_switches_scene {
                fake = fake.operated_by_hand();
            }
            let fake = Arc::new(fake);
            tracing::info!(
                address,
                "Aravis GigE Vision fake camera started (demo scene {:?}, pattern {:?})",
                config.demo.scene,
                config.demo.pattern
            );
            (fake.clone(), Some(fake))
        } else {
            (Arc::new(ManualBench), None)
        };

        let target = config
            .camera
            .id
            .clone()
            .or(config.camera.address.clone())
            .unwrap_or_default();
        let camera = CameraHandle::spawn(Box::new(move || {
            AravisCamera::open(&target).map(|c| Box::new(c) as Box<dyn CameraDevice>)
        }));
        let rescan = camera.clone();
        let hotplug = Hotplug::start(move || rescan.rescan());

        let (capture_tx, capture_rx) = mpsc::channel(config.queue.captures);
        let (recon_tx, recon_rx) = mpsc::channel(config.queue.reconstructions);
        let (events, _) = broadcast::channel(1024);
        let workers = config.queue.reconstruction_workers;
        let daemon = Arc::new(Self {
            config,
            token,
            store,
            scenes,
            camera,
            bench,
            captures: capture_tx,
            reconstructions: recon_tx,
            events,
            metrics: Metrics::default(),
            calibration,
            camera_gate: tokio::sync::Mutex::new(()),
            defaults: std::sync::Mutex::new(None),
            reserved: std::sync::Mutex::new(BTreeMap::new()),
            _hotplug: hotplug,
            _fake: fake,
        });
        tokio::spawn(capture::capture_worker(daemon.clone(), capture_rx));
        let shared = Arc::new(Mutex::new(recon_rx));
        for _ in 0..workers {
            tokio::spawn(reconstruction::reconstruction_worker(
                daemon.clone(),
                shared.clone(),
            ));
        }
        tokio::spawn(watch_camera(daemon.clone()));
        Ok(daemon)
    }

    /// The settings a capture inherits for what it does not state: the last
    /// `PUT /camera/settings`, else what the camera reported (`info`).
    pub fn capture_defaults(&self, info: Option<&CameraInfo>) -> CameraSettings {
        let put = self.defaults.lock().map(|g| g.clone()).unwrap_or(None);
        let camera = info.map(|i| i.settings.clone());
        match (put, camera) {
            (Some(mut p), Some(c)) => {
                p.region = p.region.or(c.region);
                p.binning = p.binning.or(c.binning);
                p
            }
            (Some(p), None) => p,
            (None, Some(c)) => c,
            (None, None) => CameraSettings::default(),
        }
    }

    /// Applies camera settings now and makes them the defaults later
    /// captures inherit. Refused (not waited for) while a capture has the camera.
    pub async fn put_camera_settings(
        &self,
        s: CameraSettings,
    ) -> Result<CameraInfo, SettingsError> {
        let Ok(_camera) = self.camera_gate.try_lock() else {
            return Err(SettingsError::Busy);
        };
        if let Some(info) = self.camera.status().info {
            let binning = s.binning.or(info.settings.binning).unwrap_or([1, 1]);
            if let Some(region) = s.region.or(info.settings.region) {
                info.limits.check(region, binning)?;
            }
        }
        self.camera.configure(s.clone()).await?;
        let info = self.camera.describe().await?;
        if let Ok(mut d) = self.defaults.lock() {
            *d = Some(info.settings.clone());
        }
        Ok(info)
    }

    /// The camera as it is now: read from it when no capture has it, else the
    /// settings read back when that capture configured it, and the capture's job.
    pub async fn camera_now(&self) -> (crate::camera::worker::CameraStatus, Option<String>) {
        if let Ok(_camera) = self.camera_gate.try_lock() {
            if self.camera.status().connected {
                let _ =
                    tokio::time::timeout(std::time::Duration::from_secs(2), self.camera.describe())
                        .await;
            }
            return (self.camera.status(), None);
        }
        let running = self.store.running_capture().ok().flatten();
        (
            self.camera.status(),
            running.map(|id| format!("capture-{id}")),
        )
    }

    /// Admits a validated capture: room in the queue and on the disk (its
    /// files, plus what queued captures reserved, plus the configured
    /// reserve), then records and queues it.
    pub fn submit_capture(&self, req: &CaptureRequest) -> Result<i64, SubmitError> {
        let need = capture_request::request_bytes(req);
        let free = crate::files::space::free_disk_bytes(self.store.dir())
            .map_err(|e| SubmitError::Store(self.store.describe_io(self.store.dir(), &e)))?;
        let mut reserved = self.reserved.lock().unwrap_or_else(|e| e.into_inner());
        let held: u64 = reserved.values().sum();
        let keep = self.config.queue.reserve_free_mib << 20;
        if need.saturating_add(held).saturating_add(keep) > free {
            return Err(SubmitError::Disk {
                need,
                free,
                held,
                keep,
            });
        }
        let permit = self.captures.try_reserve().map_err(|_| {
            self.metrics
                .rejected_full
                .fetch_add(1, std::sync::atomic::Ordering::Relaxed);
            SubmitError::QueueFull {
                retry_after: (req.exposure_us * 1e-6 * (req.frames + req.dark_frames) as f64)
                    .ceil()
                    .max(1.0) as u64,
            }
        })?;
        let id = self
            .store
            .insert_capture(req)
            .map_err(|e| SubmitError::Store(self.store.describe(&e)))?;
        reserved.insert(id, need);
        permit.send(id);
        Ok(id)
    }

    /// Frees the disk reservation of a capture that ended.
    fn release_capture(&self, id: i64) {
        if let Ok(mut r) = self.reserved.lock() {
            r.remove(&id);
        }
    }

    /// Publishes an event (nobody listening is fine).
    pub fn emit(&self, e: Event) {
        let _ = self.events.send(e);
    }

    /// Stops the camera thread.
    pub fn shutdown(&self) {
        self.camera.shutdown();
    }
}

/// Why a settings change was refused.
#[derive(Debug, thiserror::Error)]
pub enum SettingsError {
    /// A capture has the camera (HTTP 409).
    #[error("a capture is using the camera; settings are not changed during a capture (give them in the capture request instead, or retry when it ends)")]
    Busy,
    /// A region or binning the sensor cannot deliver (422).
    #[error(transparent)]
    Geometry(#[from] crate::camera::GeometryError),
    /// The camera refused or is gone.
    #[error(transparent)]
    Camera(#[from] crate::camera::CameraError),
}

/// Why a capture was not admitted.
#[derive(Debug, thiserror::Error)]
pub enum SubmitError {
    /// Its files would not fit on the disk (HTTP 507).
    #[error("this capture needs {} MiB of disk, but the data directory has {} MiB free, of which queued captures reserve {} MiB and {} MiB are kept free ([queue] reserve_free_mib); take fewer frames or a smaller region, or free disk space", mib(*.need), mib(*.free), mib(*.held), mib(*.keep))]
    Disk {
        /// Bytes its files take at most.
        need: u64,
        /// Bytes free now.
        free: u64,
        /// Bytes reserved by queued captures.
        held: u64,
        /// Bytes kept free.
        keep: u64,
    },
    /// The queue is full (HTTP 429).
    #[error("the capture queue is full; retry after {retry_after} s")]
    QueueFull {
        /// Seconds to wait.
        retry_after: u64,
    },
    /// The catalogue could not record it.
    #[error("{0}")]
    Store(String),
}

fn mib(bytes: u64) -> String {
    format!("{:.1}", bytes as f64 / (1u64 << 20) as f64)
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
