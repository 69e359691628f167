//! The camera as clients see and set it: the settings captures inherit,
//! `PUT /camera/settings` (refused, not waited for, during a capture) and
//! the state `GET /camera` shows.

use super::Daemon;
use crate::camera::worker::CameraStatus;
use crate::camera::{CameraInfo, CameraSettings, SettingsChange};

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

/// The camera now, as `GET /camera` shows it.
#[derive(Debug, serde::Serialize, utoipa::ToSchema)]
pub struct CameraView {
    /// Connection, identity, ranges, settings read back, counters.
    #[serde(flatten)]
    pub status: CameraStatus,
    /// The capture job that has the camera (`capture-<n>`), if any.
    pub busy: Option<String>,
    /// What a capture that states no settings would use now.
    pub capture_defaults: CameraSettings,
}

impl Daemon {
    /// The settings a capture inherits for what it does not state: the last
    /// `PUT /camera/settings`, else what the camera reported the first time
    /// the daemon saw it (`info`), latched then.
    ///
    /// Why latched: a capture configures the camera with its own settings,
    /// and reading the camera back afterwards would hand them to every later
    /// capture that states none (a Mono8 capture turning the next ones Mono8).
    /// A capture's settings belong to it; defaults change only by a PUT.
    pub fn capture_defaults(&self, info: Option<&CameraInfo>) -> CameraSettings {
        let camera = info.map(|i| i.settings.clone());
        let latched = match self.defaults.lock() {
            Ok(mut d) => {
                if d.is_none() {
                    d.clone_from(&camera);
                }
                d.clone()
            }
            Err(_) => None,
        };
        match (latched, camera) {
            (Some(mut p), Some(c)) => {
                p.region = p.region.or(c.region);
                p.binning = p.binning.or(c.binning);
                p
            }
            (Some(p), None) => p,
            (None, _) => CameraSettings::default(),
        }
    }

    /// Applies a change of the settings (what it leaves out keeps its
    /// current default) and makes the result the defaults later captures
    /// inherit. Refused (not waited for) while a capture has the camera.
    pub async fn put_camera_settings(
        &self,
        change: SettingsChange,
    ) -> Result<CameraInfo, SettingsError> {
        let Ok(_camera) = self.camera_gate.try_lock() else {
            return Err(SettingsError::Busy);
        };
        let s = change.over(&self.capture_defaults(self.camera.status().info.as_ref()));
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
    pub async fn camera_now(&self) -> CameraView {
        let busy = if let Ok(_camera) = self.camera_gate.try_lock() {
            if self.camera.status().connected {
                let describe = self.camera.describe();
                let _ = tokio::time::timeout(std::time::Duration::from_secs(2), describe).await;
            }
            None
        } else {
            let running = self.store.running_capture().ok().flatten();
            running.map(|id| format!("capture-{id}"))
        };
        let status = self.camera.status();
        let capture_defaults = self.capture_defaults(status.info.as_ref());
        CameraView {
            status,
            busy,
            capture_defaults,
        }
    }

    /// A frame for the live view: while no capture has the camera, a fresh
    /// one at the capture defaults (the bench can be aimed and focused before
    /// any capture); while a capture runs, its latest frame (the preview
    /// never takes the camera from a capture). `None` before any frame.
    pub async fn live_frame(&self) -> Option<std::sync::Arc<crate::camera::RawFrame>> {
        if let Ok(_camera) = self.camera_gate.try_lock() {
            let status = self.camera.status();
            if status.connected {
                let s = self.capture_defaults(status.info.as_ref());
                let exposure = s.exposure_us.max(0.0) * 1e-6;
                let within = std::time::Duration::from_secs_f64(exposure.min(60.0) + 3.0);
                match tokio::time::timeout(within, self.camera.collect(s, 1)).await {
                    Ok(Ok(mut frames)) => {
                        if let (Some(f), Ok(mut latest)) = (frames.pop(), self.latest_frame.lock())
                        {
                            *latest = Some(std::sync::Arc::new(f));
                        }
                    }
                    Ok(Err(e)) => tracing::debug!("live view: {e}"),
                    Err(_) => tracing::debug!("live view: no frame within {within:?}"),
                }
            }
        }
        self.latest_frame()
    }
}
