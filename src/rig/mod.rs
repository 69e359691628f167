//! The rig: the bench's devices around the camera (the camera stage, the
//! rotation mount, the light relay, and the fake bench's switchable scene)
//! behind what a capture, a plan or a calibration needs of them. The capture
//! worker and the plans ask the rig, never a device; what is simulated stays
//! in the simulated devices.

pub mod bench;
pub mod mount;
pub mod relay;
pub(crate) mod serial;
pub mod stage;

use std::sync::Arc;

use crate::scene::Pose;
use bench::Bench;
use mount::MountError;
use relay::RelayError;
use stage::StageError;

/// A `[mount]`, `[stage]` or `[light]` value a config file got wrong: the
/// section and key, and what the value must be (the config loader names it).
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("[{section}] {key} {reason}")]
pub struct RigConfigError {
    /// The config file's section: `mount`, `stage` or `light`.
    pub section: &'static str,
    /// The key, with the value given where it has one (`relay = 9`).
    pub key: String,
    /// What is wrong with it.
    pub reason: String,
}

impl RigConfigError {
    fn new(section: &'static str, key: impl Into<String>, reason: impl Into<String>) -> Self {
        Self {
            section,
            key: key.into(),
            reason: reason.into(),
        }
    }
}

/// Why the rig could not do what a capture asked of it.
#[derive(Debug, thiserror::Error)]
pub(crate) enum RigError {
    /// A device's blocking command panicked or was cancelled.
    #[error("the {device}'s task failed: {reason}")]
    Task {
        /// "rotation mount", "camera stage" or "light relay".
        device: &'static str,
        /// What the runtime said.
        reason: String,
    },
    /// The stage did not reach the pose.
    #[error(transparent)]
    Stage(#[from] StageError),
    /// The mount did not turn the polarizer.
    #[error("the polarizer could not be turned to {deg}° from crossed: {source}")]
    Mount {
        /// The angle asked for, degrees from crossed.
        deg: f64,
        /// Why.
        source: MountError,
    },
    /// The relay did not switch the hidden scene's light.
    #[error("the hidden scene could not be switched {}: {source}", if *on { "on" } else { "off" })]
    Light {
        /// The state asked for.
        on: bool,
        /// Why.
        source: RelayError,
    },
}

/// What a bench does by itself, so that a plan needs no operator for it.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Automated {
    /// A mount turns the polarizer.
    pub mount: bool,
    /// A stage moves the camera between poses.
    pub stage: bool,
    /// The bench switches the hidden scene off for darks.
    pub switches_scene: bool,
}

/// The bench's devices, each present or not, and the fake bench's scene.
pub(crate) struct Rig {
    mount: Arc<mount::MountService>,
    stage: Arc<stage::StageService>,
    light: Arc<relay::LightService>,
    bench: Arc<dyn Bench>,
}

impl Rig {
    /// The rig of started device services and the bench the camera shows.
    pub(crate) fn new(
        mount: mount::MountService,
        stage: stage::StageService,
        light: relay::LightService,
        bench: Arc<dyn Bench>,
    ) -> Self {
        Self {
            mount: Arc::new(mount),
            stage: Arc::new(stage),
            light: Arc::new(light),
            bench,
        }
    }

    /// What this bench does by itself (a plan asks the operator for the rest).
    pub fn automated(&self) -> Automated {
        Automated {
            mount: self.mount.present(),
            stage: self.stage.present(),
            switches_scene: self.switches_scene(),
        }
    }

    /// Whether dark frames need no operator: a relay, or the fake bench's
    /// own switch, turns the hidden scene off.
    pub fn switches_scene(&self) -> bool {
        self.light.switches_scene(self.bench.as_ref())
    }

    /// The rotation mount's service (views, its zero and its sweep).
    pub fn mount(&self) -> &Arc<mount::MountService> {
        &self.mount
    }

    /// The rotation mount: where it is now (read from it within 2 s unless
    /// a capture is turning it, then as last read).
    pub async fn mount_view(&self) -> mount::MountView {
        let m = self.mount.clone();
        if m.present() {
            let read = tokio::task::spawn_blocking(move || {
                let _ = m.read();
            });
            let _ = tokio::time::timeout(std::time::Duration::from_secs(2), read).await;
        }
        self.mount.view()
    }

    /// The stage as last seen.
    pub fn stage_view(&self) -> stage::StageView {
        self.stage.view()
    }

    /// The light relay as last seen.
    pub fn light_view(&self) -> relay::LightView {
        self.light.view()
    }

    /// Moves the camera to `pose` and returns where the stage read it back;
    /// `None` without a stage (the operator moves it and the pose is trusted).
    pub async fn move_to(&self, pose: &Pose) -> Result<Option<[f64; 3]>, RigError> {
        if !self.stage.present() {
            return Ok(None);
        }
        let (stage, pose) = (self.stage.clone(), pose.clone());
        let at = off_runtime("camera stage", move || stage.move_to(&pose)).await??;
        Ok(Some(at))
    }

    /// Turns the polarizer to `deg` from crossed and returns the angle read
    /// back; `None` without a mount (the angle is set by hand and trusted).
    pub async fn turn_to(&self, deg: f64) -> Result<Option<f64>, RigError> {
        if !self.mount.present() {
            return Ok(None);
        }
        let mount = self.mount.clone();
        let read = off_runtime("rotation mount", move || mount.turn_to(deg)).await?;
        read.map(Some)
            .map_err(|source| RigError::Mount { deg, source })
    }

    /// Shows the block of `pose` at polarizer angle `deg` (from crossed) on
    /// the fake bench: at the simulated mount's true angle where it has one,
    /// as a real polarizer would sit, else at `deg`. A real bench ignores it.
    pub fn show_block(&self, pose: &str, deg: Option<f64>) {
        let shown = deg.map(|d| self.mount.simulated_truth_deg().unwrap_or(d));
        self.bench.select(pose, shown);
    }

    /// Switches the hidden scene's light: through the relay when there is
    /// one (the fake bench then shows what the relay reads back), else
    /// through the fake bench's own switch (or the operator, who was asked).
    pub async fn scene_light(&self, on: bool) -> Result<(), RigError> {
        if !self.light.present() {
            self.bench.scene_on(on);
            return Ok(());
        }
        let light = self.light.clone();
        let read = off_runtime("light relay", move || light.set(on))
            .await?
            .map_err(|source| RigError::Light { on, source })?;
        self.bench.scene_on(read);
        Ok(())
    }

    /// Puts `aid` in front of the wall (the fake bench's; a real one is
    /// placed by the operator) until the guard drops, so that a capture or a
    /// sweep that ends early (an error, a cancel) leaves the bench as it found it.
    pub fn showing(&self, aid: Aid) -> Showing<'_> {
        self.show(aid, true);
        Showing(self, aid)
    }

    fn show(&self, aid: Aid, on: bool) {
        match aid {
            Aid::Target => self.bench.show_target(on),
            Aid::Source => self.bench.show_source(on),
        }
    }
}

/// A calibration aid the fake bench can show instead of the hidden scene.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Aid {
    /// The calibration target (dots on the wall).
    Target,
    /// The calibration source lighting the wall.
    Source,
}

/// An aid shown by [`Rig::showing`]; dropping it takes the aid away.
pub(crate) struct Showing<'a>(&'a Rig, Aid);

impl Drop for Showing<'_> {
    fn drop(&mut self) {
        self.0.show(self.1, false);
    }
}

/// Runs a device's blocking command (serial I/O of up to seconds) off the
/// runtime; a task that did not finish names `device`.
async fn off_runtime<T: Send + 'static>(
    device: &'static str,
    command: impl FnOnce() -> T + Send + 'static,
) -> Result<T, RigError> {
    tokio::task::spawn_blocking(command)
        .await
        .map_err(|e| RigError::Task {
            device,
            reason: e.to_string(),
        })
}
