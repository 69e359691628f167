//! The acquisition daemon: wires the camera thread, the bench, the store, the
//! scene registry and the job queues together, and hands a typed state to the
//! HTTP routes in [`crate::api`].
//!
//! Captures queue for the single camera and run one at a time; reconstructions
//! queue for a small worker pool and run their maths on blocking threads. Both
//! queues are bounded: a full queue is refused at once (HTTP 429), never waited on.

pub mod config;
pub mod events;
mod jobs;
pub mod metrics;
pub mod scenes;

use std::collections::BTreeMap;
use std::sync::Arc;

use tokio::sync::{broadcast, mpsc, Mutex};

pub use config::Config;
pub use events::Event;
pub use jobs::{
    camera_limits, exposure_plan, validate_capture, validate_reconstruction, CaptureBody,
    ReconstructionBody, RequestError,
};

use crate::camera::aravis::AravisCamera;
use crate::camera::fake::{Bench, FakeBench, ManualBench};
use crate::camera::hotplug::Hotplug;
use crate::camera::worker::CameraHandle;
use crate::camera::{CameraDevice, Frame};
use crate::measure::render_wall;
use crate::simulate::patterns::Pattern;
use crate::store::Store;
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
            let (frames, c) = tokio::task::spawn_blocking(move || demo_frames(&scenes2, &demo))
                .await
                .map_err(|e| DaemonError::Demo(e.to_string()))??;
            for name in scenes.names() {
                calibration.entry(name).or_insert(c);
            }
            let fake = Arc::new(FakeBench::start(
                &address,
                "POLNLOS-DEMO",
                frames,
                DEMO_REFERENCE_EXPOSURE_US,
            )?);
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
            _hotplug: hotplug,
            _fake: fake,
        });
        tokio::spawn(jobs::capture_worker(daemon.clone(), capture_rx));
        let shared = Arc::new(Mutex::new(recon_rx));
        for _ in 0..workers {
            tokio::spawn(jobs::reconstruction_worker(daemon.clone(), shared.clone()));
        }
        tokio::spawn(watch_camera(daemon.clone()));
        Ok(daemon)
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

type DemoFrames = Vec<(String, Option<f64>, Frame)>;

/// Renders the fake camera's frame for every block of the demo scene (and of
/// every other scene on the same bench with poses of their own), normalized so
/// that the unpolarized peak is 80 % of full scale at the reference exposure.
/// Returns the frames and the calibration they imply (fraction of full scale
/// per microsecond per unit of T l).
fn demo_frames(
    scenes: &Scenes,
    demo: &config::DemoConfig,
) -> Result<(DemoFrames, f64), DaemonError> {
    let err = |m: String| DaemonError::Demo(m);
    let pattern = Pattern::from_name(&demo.pattern).ok_or_else(|| {
        err(format!(
            "pattern {:?} is not disk, bars or letter",
            demo.pattern
        ))
    })?;
    let scene = scenes
        .get(&demo.scene)
        .ok_or_else(|| err(format!("no scene {:?}", demo.scene)))?;
    let t = scenes
        .transport(&demo.scene)
        .ok_or_else(|| err("no scene".into()))?
        .map_err(|e| err(e.to_string()))?;
    let l = pattern.render(t.scene_grid);
    let peak = crate::simulate::unpolarized_peak(&scene, &t, &l).map_err(|e| err(e.to_string()))?;
    if peak <= 0.0 {
        return Err(err("the demo scene lights no wall element".into()));
    }
    let norm = DEMO_PEAK_FRACTION / peak;
    let mut frames: DemoFrames = Vec::new();
    // The demo scene first; then same-bench scenes add blocks it lacks (B, C, angles).
    let mut names = vec![demo.scene.clone()];
    names.extend(scenes.names().into_iter().filter(|n| {
        n != &demo.scene && same_bench(&scene, &scenes.get(n).unwrap_or_else(|| scene.clone()))
    }));
    for name in names {
        let (Some(s), Some(Ok(t))) = (scenes.get(&name), scenes.transport(&name)) else {
            continue;
        };
        let l = pattern.render(t.scene_grid);
        let i = t.apply(&l);
        for (b, block) in t.blocks.iter().enumerate() {
            if frames
                .iter()
                .any(|(p, a, _)| p == &block.pose && *a == block.polarizer_deg)
            {
                continue;
            }
            let Some(h) = s.pose(&block.pose).and_then(|p| p.homography) else {
                continue;
            };
            let values: Vec<f64> = i[t.block_rows(b)].iter().map(|v| v * norm).collect();
            frames.push((
                block.pose.clone(),
                block.polarizer_deg,
                render_wall(&values, &h, &s.wall.plane, 512, 512, 0.0),
            ));
        }
    }
    // Frame value v = norm T l at the reference exposure, as a fraction of full scale.
    let c = norm / DEMO_REFERENCE_EXPOSURE_US;
    Ok((frames, c))
}

/// Same wall, same hidden-scene plane, no occluder difference: frames can be shared.
fn same_bench(a: &crate::scene::Scene, b: &crate::scene::Scene) -> bool {
    a.wall.plane.center == b.wall.plane.center
        && a.wall.plane.size == b.wall.plane.size
        && a.wall.plane.grid == b.wall.plane.grid
        && a.wall.brdf == b.wall.brdf
        && a.scene.plane.center == b.scene.plane.center
        && a.scene.plane.size == b.scene.plane.size
        && a.occluders == b.occluders
}
