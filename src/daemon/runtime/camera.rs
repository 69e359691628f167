//! The camera service: the one camera and who has it. It owns the settings captures inherit, `PUT /camera/settings`
//! (refused, not waited for, during a capture), the state `GET /camera`
//! shows and the live view's latest frame.

use std::sync::{Arc, Mutex};

use crate::camera::hotplug::Hotplug;
use crate::camera::worker::{CameraHandle, CameraStatus};
use crate::camera::{Acquisition, CameraError, CameraInfo, CameraSettings, RawFrame};

/// Why a settings change was refused.
#[derive(Debug, thiserror::Error)]
pub enum SettingsError {
    /// A capture or the live view has the camera (HTTP 409).
    #[error("a capture or the live view is using the camera (GET /camera's busy says which); settings are not changed meanwhile (give them in the capture or live request instead, stop the live view with DELETE /live, or retry when the capture ends)")]
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
    /// What the demo bench's camera shows (the fake or synthetic camera);
    /// null for a real camera. Why: its pattern is the truth of every result.
    pub demo: Option<DemoView>,
}

/// The demo bench's hidden scene: a known pattern on a known scene (`[demo]`).
#[derive(Debug, Clone, serde::Serialize, utoipa::ToSchema)]
pub struct DemoView {
    /// The scene the fake camera's frames are rendered from.
    pub scene: String,
    /// The pattern it shows: `disk`, `bars`, `letter` or `flat`.
    pub pattern: String,
}

/// The camera thread's handle and the state around it; each
/// piece behind its own lock, none held across an await but the gate.
pub struct CameraService {
    handle: CameraHandle,
    /// Held by a capture for its whole run: a settings change that cannot
    /// have the camera answers 409 instead of waiting.
    gate: tokio::sync::Mutex<()>,
    /// The job holding the gate (`capture-<n>`), for `GET /camera`.
    holder: Mutex<Option<String>>,
    /// Leases asked for and not yet granted: the live view gives the camera
    /// up when one is.
    waiting: std::sync::atomic::AtomicUsize,
    /// Settings from the last `PUT /camera/settings`, inherited by captures
    /// that do not state their own (None: the camera's read-back ones).
    defaults: Mutex<Option<CameraSettings>>,
    /// The latest frame a capture or the live view received.
    latest: Mutex<Option<Arc<RawFrame>>>,
    /// What a demo bench's camera shows, for `GET /camera`.
    demo: Option<DemoView>,
    _hotplug: Option<Hotplug>,
}

/// The camera, held by one capture until dropped.
pub(crate) struct CameraLease<'a> {
    _gate: tokio::sync::MutexGuard<'a, ()>,
    holder: &'a Mutex<Option<String>>,
}

impl Drop for CameraLease<'_> {
    fn drop(&mut self) {
        *self.holder.lock().unwrap_or_else(|e| e.into_inner()) = None;
    }
}

impl CameraService {
    /// The service over a started camera thread; `hotplug` (kept alive
    /// here) rescans when a USB device arrives; `demo`: what a demo bench shows.
    pub(crate) fn new(
        handle: CameraHandle,
        hotplug: Option<Hotplug>,
        demo: Option<DemoView>,
    ) -> Self {
        Self {
            handle,
            gate: tokio::sync::Mutex::new(()),
            holder: Mutex::new(None),
            waiting: std::sync::atomic::AtomicUsize::new(0),
            defaults: Mutex::new(None),
            latest: Mutex::new(None),
            demo,
            _hotplug: hotplug,
        }
    }

    /// The camera thread (acquisition, configuration, status).
    pub(crate) fn handle(&self) -> &CameraHandle {
        &self.handle
    }

    /// Connection, identity, ranges, settings read back and counters now.
    pub fn status(&self) -> CameraStatus {
        self.handle.status()
    }

    /// Waits for the camera and holds it for `job` until the lease drops.
    pub(crate) async fn lease(&self, job: &str) -> CameraLease<'_> {
        use std::sync::atomic::Ordering;
        /// Counts a lease asked for until it is granted or given up.
        struct Asking<'a>(&'a std::sync::atomic::AtomicUsize);
        impl Drop for Asking<'_> {
            fn drop(&mut self) {
                self.0.fetch_sub(1, Ordering::SeqCst);
            }
        }
        self.waiting.fetch_add(1, Ordering::SeqCst);
        let asking = Asking(&self.waiting);
        let gate = self.gate.lock().await;
        drop(asking);
        *self.holder.lock().unwrap_or_else(|e| e.into_inner()) = Some(job.to_string());
        CameraLease {
            _gate: gate,
            holder: &self.holder,
        }
    }

    /// `n` frames at `settings`, the last one shown in the live view, for a
    /// caller that holds the camera's lease (the live view, a sweep).
    pub(crate) async fn collect(
        &self,
        settings: Acquisition,
        n: usize,
    ) -> Result<Vec<RawFrame>, CameraError> {
        let frames = self.handle.collect(settings, n).await?;
        if let Some(f) = frames.last() {
            self.show(Arc::new(f.clone()));
        }
        Ok(frames)
    }

    /// Leases asked for and not yet granted.
    pub(crate) fn waiting(&self) -> usize {
        self.waiting.load(std::sync::atomic::Ordering::SeqCst)
    }

    /// The latest frame a capture or the live view received, if any.
    pub fn latest_frame(&self) -> Option<Arc<RawFrame>> {
        self.latest
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .clone()
    }

    /// Shows `frame` in the live view.
    pub(crate) fn show(&self, frame: Arc<RawFrame>) {
        *self.latest.lock().unwrap_or_else(|e| e.into_inner()) = Some(frame);
    }

    /// Stops the camera thread.
    pub(crate) fn shutdown(&self) {
        self.handle.shutdown();
    }

    /// The settings a capture inherits for what it does not state: the last
    /// `PUT /camera/settings`, else what the camera reported the first time
    /// the daemon saw it (`info`), latched then.
    ///
    /// Why latched: a capture configures the camera with its own settings,
    /// and reading the camera back afterwards would hand them to every later
    /// capture that states none (a Mono8 capture turning the next ones Mono8).
    /// A capture's settings belong to it; defaults change only by a PUT.
    pub fn capture_defaults(&self, info: Option<&CameraInfo>) -> CameraSettings {
        let camera = info.map(|i| CameraSettings::from(i.settings));
        let latched = {
            let mut d = self.defaults.lock().unwrap_or_else(|e| e.into_inner());
            if d.is_none() {
                d.clone_from(&camera);
            }
            *d
        };
        latched.unwrap_or_else(CameraSettings::builtin)
    }

    /// `stated` over the capture defaults, on this camera: what neither
    /// states is the camera's own (read back in `info`), so nothing is missing.
    pub(crate) fn settings_on(&self, stated: CameraSettings, info: &CameraInfo) -> Acquisition {
        stated
            .over(&self.capture_defaults(Some(info)))
            .over(&info.settings.into())
            .complete()
            .unwrap_or(info.settings)
    }

    /// Applies a change of the settings (what it leaves out keeps its
    /// current default) and makes the result the defaults later captures
    /// inherit. Refused (not waited for) while a capture has the camera.
    pub async fn put_settings(&self, change: CameraSettings) -> Result<CameraInfo, SettingsError> {
        let Ok(_camera) = self.gate.try_lock() else {
            return Err(SettingsError::Busy);
        };
        let info = self.status().info.ok_or_else(|| {
            CameraError::Disconnected("settings are applied to a connected camera".into())
        })?;
        let s = self.settings_on(change, &info);
        info.limits.check(s.region, s.binning)?;
        self.handle.configure(s).await?;
        let info = self.handle.describe().await?;
        *self.defaults.lock().unwrap_or_else(|e| e.into_inner()) = Some(info.settings.into());
        Ok(info)
    }

    /// The camera as it is now: read from it when no capture has it, else the
    /// settings read back when that capture configured it, and the capture's job.
    pub async fn now(&self) -> CameraView {
        let busy = if let Ok(_camera) = self.gate.try_lock() {
            if self.status().connected {
                let describe = self.handle.describe();
                let _ = tokio::time::timeout(std::time::Duration::from_secs(2), describe).await;
            }
            None
        } else {
            self.holder
                .lock()
                .unwrap_or_else(|e| e.into_inner())
                .clone()
        };
        let status = self.status();
        let capture_defaults = self.capture_defaults(status.info.as_ref());
        CameraView {
            status,
            busy,
            capture_defaults,
            demo: self.demo.clone(),
        }
    }

    /// A frame for the live view: while no capture has the camera, a fresh
    /// one at the capture defaults (the bench can be aimed and focused before
    /// any capture); while a capture runs, its latest frame (the preview
    /// never takes the camera from a capture). `None` before any frame.
    pub async fn live_frame(&self) -> Option<Arc<RawFrame>> {
        if let Ok(_camera) = self.gate.try_lock() {
            let status = self.status();
            if let Some(info) = status.info.as_ref().filter(|_| status.connected) {
                let s = self.settings_on(CameraSettings::default(), info);
                let exposure = s.exposure_us.max(0.0) * 1e-6;
                let within = std::time::Duration::from_secs_f64(exposure.min(60.0) + 3.0);
                // `collect` shows the frame it got.
                match tokio::time::timeout(within, self.collect(s, 1)).await {
                    Ok(Ok(_)) => {}
                    Ok(Err(e)) => tracing::debug!("live view: {e}"),
                    Err(_) => tracing::debug!("live view: no frame within {within:?}"),
                }
            }
        }
        self.latest_frame()
    }
}
