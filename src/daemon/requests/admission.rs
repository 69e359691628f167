//! Admission: a request body in, a queued job out. [`Admission`] gathers
//! what [`super::validate`] needs (the scene, the camera's ranges and
//! current settings, the captures named), then admits the request by queue
//! room and, for captures, disk space; it also cancels jobs (`cancel`).
//!
//! Why a handle of its own: the HTTP API and the plan runner both post
//! captures and reconstructions; the runner holds this, never the daemon.

use std::collections::BTreeMap;
use std::sync::atomic::Ordering;
use std::sync::Arc;

use super::validate::{self, CameraContext, ProgressiveSpec, RequestError};
use super::{AutoExposure, CaptureBody, ReconstructionBody};
use crate::camera::settings::EXPOSURE;
use crate::camera::CameraInfo;
use crate::daemon::runtime::camera::CameraService;
use crate::daemon::runtime::events::Events;
use crate::daemon::runtime::metrics::Metrics;
use crate::daemon::runtime::queue::{CaptureQueue, DiskNeed, Queue, SubmitError};
use crate::daemon::runtime::registry::JobRegistry;
use crate::daemon::runtime::scene_registry::SceneRegistry;
use crate::daemon::Config;
use crate::measure::exposure::{plan_exposure, BlockExposure, CameraLimits, ExposureTarget};
use crate::rig::Rig;
use crate::solve::radiometry::Radiometry;
use crate::store::{capture_bytes, CaptureRequest, Store};

/// What admitting and cancelling jobs needs: the services it reads and the
/// queues it pushes to, shared with the daemon.
pub(crate) struct Admission {
    pub(in crate::daemon) config: Arc<Config>,
    pub(in crate::daemon) store: Arc<Store>,
    pub(in crate::daemon) scenes: Arc<SceneRegistry>,
    /// Fraction of full scale per microsecond per unit of `T l`, per scene.
    pub(in crate::daemon) calibration: Arc<BTreeMap<String, f64>>,
    pub(in crate::daemon) camera: Arc<CameraService>,
    pub(in crate::daemon) rig: Arc<Rig>,
    pub(in crate::daemon) captures: Arc<CaptureQueue>,
    pub(in crate::daemon) reconstructions: Queue,
    pub(in crate::daemon) registry: Arc<JobRegistry>,
    pub(in crate::daemon) events: Events,
    pub(in crate::daemon) metrics: Arc<Metrics>,
    /// The live view, whose sessions are admitted here.
    pub(in crate::daemon) live: Arc<crate::daemon::runtime::live::Live>,
}

impl Admission {
    /// Starts the live view repeating capture body `b` (a running session
    /// is replaced), with the capture its `record` writes reserved; the
    /// capture worker runs it while no capture waits.
    pub(crate) async fn start_live(
        self: &Arc<Self>,
        b: CaptureBody,
    ) -> Result<crate::daemon::runtime::live::LiveView, SubmitError> {
        let a = self.clone();
        let (request, spec, record) = tokio::task::spawn_blocking(move || a.check_live(&b))
            .await
            .map_err(|e| RequestError::Unavailable(format!("live view validation: {e}")))??;
        let session = self.live.issue_id();
        let recording = match record {
            Some(n) => Some((self.reserve_recording(&request, n, session)?, n)),
            None => None,
        };
        tracing::info!(
            "live view started: {} {}, windows of {} frames of {} us",
            request.scene,
            crate::daemon::jobs::capture_label(&request.pose, &request.channels),
            request.frames,
            request.acquisition.exposure_us
        );
        let (view, replaced) = self.live.start(session, request, spec, recording);
        if let Some(id) = replaced {
            self.end_unrecorded(id, "a new live session (POST /live) replaced its session");
        }
        Ok(view)
    }

    /// Stops the live view; its last state, as `off`.
    pub(crate) fn stop_live(&self) -> crate::daemon::runtime::live::LiveView {
        let (view, waiting) = self.live.stop();
        if let Some(id) = waiting {
            self.end_unrecorded(id, "DELETE /live stopped its session");
        }
        tracing::info!("live view stopped after {} results", view.results);
        view
    }

    /// Ends recording capture `id`, to which no frame went, as failed for `why`.
    fn end_unrecorded(&self, id: i64, why: &str) {
        crate::daemon::jobs::record::unrecorded(&self.store, &self.captures, &self.events, id, why);
    }

    /// Capture `id` from the catalogue for a request's checks: `None` when
    /// there is no such capture; a catalogue that cannot be read is a 500
    /// with the store's reason, not "no capture".
    pub(in crate::daemon) fn lookup_capture(
        &self,
        id: i64,
    ) -> Result<Option<crate::store::CaptureRecord>, RequestError> {
        match self.store.capture(id) {
            Ok(c) => Ok(Some(c)),
            Err(crate::store::StoreError::NotFound { .. }) => Ok(None),
            Err(e) => Err(RequestError::Store(format!(
                "capture {id}: the catalogue could not be read: {}",
                self.store.describe(&e)
            ))),
        }
    }

    /// Capture `id`, which the request needs to exist ([`Self::lookup_capture`]).
    pub(in crate::daemon) fn require_capture(
        &self,
        id: i64,
    ) -> Result<crate::store::CaptureRecord, RequestError> {
        self.lookup_capture(id)?
            .ok_or_else(|| RequestError::NotFound(format!("no capture with id {id}")))
    }

    /// The camera limits exposure planning works with: the camera's exposure
    /// range when connected (`info`), the configured sensor noise, the frame cap.
    pub(crate) fn camera_limits(&self, info: Option<&CameraInfo>) -> CameraLimits {
        CameraLimits {
            exposure_us: EXPOSURE.allowed(info.map(|i| &i.ranges)),
            max_frames: self.config.queue.max_frames_per_capture,
            full_well_e: self.config.camera.full_well_e,
            read_noise_e: self.config.camera.read_noise_e,
        }
    }

    /// The exposure and frame count of every block of a scene for the
    /// camera as it is now. Builds the scene's `T` on first use: call it off
    /// the async runtime.
    pub(crate) fn block_exposures(
        &self,
        scene: &str,
        target: &ExposureTarget,
    ) -> Result<Vec<BlockExposure>, RequestError> {
        let limits = self.camera_limits(self.camera.status().info.as_ref());
        self.exposures_with(scene, target, &limits)
    }

    fn exposures_with(
        &self,
        scene: &str,
        target: &ExposureTarget,
        limits: &CameraLimits,
    ) -> Result<Vec<BlockExposure>, RequestError> {
        let t = self.scenes.now().transport(scene)?;
        let cal = self.calibration.get(scene).copied().ok_or_else(|| {
            RequestError::Invalid(format!(
                "no radiometric calibration for scene {scene:?}, so exposures cannot be planned: add `{scene} = <fraction of full scale per microsecond per unit of T l>` under [calibration] in the config, or give exposure_us"
            ))
        })?;
        // Each element is measured from all its pixels: their photons count.
        let pixels = crate::scene::effective_pixels(&*self.scenes.now().scene(scene)?)
            .map_err(|e| RequestError::Invalid(e.to_string()))?;
        plan_exposure(&t, cal, limits, target, pixels.as_deref())
            .map_err(|e| RequestError::Invalid(e.to_string()))
    }

    /// What a capture is checked against now.
    fn camera_context(&self, info: Option<&CameraInfo>) -> CameraContext {
        CameraContext {
            limits: self.camera_limits(info),
            ranges: info.map(|i| i.ranges.clone()),
            sensor: info.map(|i| i.limits),
            defaults: self.camera.capture_defaults(info),
            pixel_formats: info.map(|i| i.pixel_formats.clone()),
            bench_switches_scene: self.rig.switches_scene(),
            max_frames: self.config.queue.max_frames_per_capture,
        }
    }

    /// Validates a capture body (planning its exposure when asked, which may
    /// build the scene's `T`, off the runtime) and admits it.
    pub(crate) async fn submit_capture(
        self: &Arc<Self>,
        body: CaptureBody,
    ) -> Result<(i64, CaptureRequest), SubmitError> {
        let d = self.clone();
        let (request, progressive) = tokio::task::spawn_blocking(move || d.check_capture(&body))
            .await
            .map_err(|e| SubmitError::Internal(format!("capture validation: {e}")))??;
        if let Some(p) = &progressive {
            self.needs_gain("progressive", &request.scene, p.radiometry, false)?;
        }
        let id = self.admit_capture(&request, progressive)?;
        Ok((id, request))
    }

    /// Whether `what` (a progressive or live solve) of `scene` can have the
    /// radiometry it asks for: `calibrated` (asked, or difference mode's,
    /// whose running background must be in the scene's units) needs the
    /// scene's calibrated gain; `fitted` needs none, and no difference mode.
    pub(in crate::daemon) fn needs_gain(
        &self,
        what: &str,
        scene: &str,
        radiometry: Option<Radiometry>,
        difference: bool,
    ) -> Result<(), RequestError> {
        if difference && radiometry == Some(Radiometry::Fitted) {
            return Err(RequestError::Invalid(format!(
                "{what}: difference mode subtracts a running background, which a fitted radiometry would fit away: leave radiometry out, or ask \"calibrated\""
            )));
        }
        let calibrated = difference || radiometry == Some(Radiometry::Calibrated);
        if calibrated && !self.calibration.contains_key(scene) {
            let (asks, or) = match difference {
                true => ("difference mode", ""),
                false => (
                    "a calibrated radiometry",
                    ", or ask \"radiometry\": \"fitted\" (gain and background fitted with the scene)",
                ),
            };
            return Err(RequestError::Invalid(format!(
                "{what}: {asks} needs the radiometric calibration of scene {scene:?}: add it under [calibration] in the config{or}"
            )));
        }
        Ok(())
    }

    pub(in crate::daemon) fn check_capture(
        &self,
        b: &CaptureBody,
    ) -> Result<(CaptureRequest, Option<ProgressiveSpec>), RequestError> {
        if b.difference.is_some() || b.record.is_some() {
            let field = if b.difference.is_some() {
                "difference"
            } else {
                "record"
            };
            return Err(RequestError::Invalid(format!(
                "{field} is live view's (POST /live): leave it out of a capture"
            )));
        }
        let scene = self.scenes.now().scene(&b.scene)?;
        let info = self.camera.status().info;
        let cam = self.camera_context(info.as_ref());
        let plan = || match b.exposure {
            Some(AutoExposure::Auto) => {
                self.exposures_with(&b.scene, &b.target.unwrap_or_default(), &cam.limits)
            }
            None => Ok(Vec::new()),
        };
        let lookup = |id| self.lookup_capture(id);
        let request = validate::capture(b, &scene, &cam, plan, lookup)?;
        let progressive = match &b.progressive {
            Some(p) => Some(validate::progressive(p, &request, &scene, lookup)?),
            None => None,
        };
        Ok((request, progressive))
    }

    /// Validates the capture request a live view repeats: a light capture
    /// whose `frames` is the window (1 to [`MAX_WINDOW`]), solved as a
    /// progressive reconstruction (`progressive` gives λ, the truth and the
    /// other blocks' captures), which needs the scene's radiometric
    /// calibration; and the frames to record, when asked (`record`).
    ///
    /// [`MAX_WINDOW`]: crate::measure::window::MAX_WINDOW
    pub(in crate::daemon) fn check_live(
        &self,
        b: &CaptureBody,
    ) -> Result<(CaptureRequest, ProgressiveSpec, Option<usize>), RequestError> {
        use crate::measure::window::MAX_WINDOW;
        if b.kind
            .is_some_and(|k| k != crate::store::CaptureKind::Light)
        {
            return Err(RequestError::Invalid(
                "live view repeats a light capture: leave kind out".into(),
            ));
        }
        if let Some(n) = b.frames.filter(|&n| n > MAX_WINDOW) {
            return Err(RequestError::Invalid(format!(
                "frames = {n}: a live window is 1 to {MAX_WINDOW} frames"
            )));
        }
        self.scenes.now().scene(&b.scene)?;
        let difference = b
            .difference
            .as_ref()
            .map(validate::difference)
            .transpose()?;
        let radiometry = b.progressive.as_ref().and_then(|p| p.radiometry);
        self.needs_gain("live view", &b.scene, radiometry, difference.is_some())?;
        if difference.is_some()
            && b.progressive
                .as_ref()
                .is_some_and(|p| !p.captures.is_empty())
        {
            return Err(RequestError::Invalid(
                "difference mode reconstructs the live block's change alone (the other blocks' captures do not change with it): leave progressive.captures out".into(),
            ));
        }
        let mut body = b.clone();
        body.difference = None;
        body.record = None;
        body.progressive.get_or_insert(super::ProgressiveBody {
            every: None,
            captures: Vec::new(),
            lambda: None,
            max_iter: None,
            truth: None,
            radiometry: None,
        });
        let (request, spec) = self.check_capture(&body)?;
        let mut spec =
            spec.ok_or_else(|| RequestError::Invalid("live view: no solver settings".into()))?;
        spec.difference = difference;
        let max = self.config.queue.max_frames_per_capture;
        let record = b
            .record
            .as_ref()
            .map(|r| validate::recording(r, request.dark_frames, max))
            .transpose()?;
        Ok((request, spec, record))
    }

    /// The disk capture `req`'s files need, against what the data
    /// directory's disk has free and keeps free.
    fn disk_need(&self, req: &CaptureRequest) -> Result<DiskNeed, SubmitError> {
        let need = capture_bytes(
            req.acquisition.region[2],
            req.acquisition.region[3],
            req.frames,
            req.dark_frames,
        );
        let free = crate::files::space::free_disk_bytes(self.store.dir())
            .map_err(|e| SubmitError::Internal(self.store.describe_io(self.store.dir(), &e)))?;
        Ok(DiskNeed {
            need,
            free,
            keep: self.config.queue.reserve_free_mib << 20,
        })
    }

    /// Records the capture live session `session` records its first
    /// `frames` frames into, its disk reserved as a queued capture's (507
    /// when it does not fit); the live view's worker writes it.
    fn reserve_recording(
        &self,
        live: &CaptureRequest,
        frames: usize,
        session: u64,
    ) -> Result<i64, SubmitError> {
        let req = CaptureRequest {
            frames,
            ..live.clone()
        };
        let info = crate::store::LiveInfo {
            session,
            frames_asked: frames,
            ended: None,
        };
        let disk = self.disk_need(&req)?;
        let id = self.captures.reserve(disk, || {
            self.store
                .insert_live_capture(&req, &info)
                .map_err(|e| SubmitError::Internal(self.store.describe(&e)))
        })?;
        tracing::info!(
            "capture-{id} reserved for live session {session}'s first {frames} frames (+ {} dark)",
            req.dark_frames
        );
        self.events.job(
            format!("capture-{id}"),
            crate::store::JobState::Queued,
            None,
        );
        Ok(id)
    }

    /// Admits a validated capture: room in the queue and on the disk (its
    /// files, plus what queued captures reserved, plus the configured
    /// reserve), then records and queues it.
    fn admit_capture(
        &self,
        req: &CaptureRequest,
        progressive: Option<ProgressiveSpec>,
    ) -> Result<i64, SubmitError> {
        let disk = self.disk_need(req)?;
        let seconds = req.acquisition.exposure_us * 1e-6 * (req.frames + req.dark_frames) as f64;
        let retry_after = seconds.ceil().max(1.0) as u64;
        let insert = || {
            self.store
                .insert_capture(req)
                .map_err(|e| SubmitError::Internal(self.store.describe(&e)))
        };
        let pushed = self.captures.push(disk, retry_after, progressive, insert);
        if let Ok(id) = &pushed {
            let a = &req.acquisition;
            tracing::info!(
                "capture-{id} queued: {} {}, {} frames + {} dark of {} us",
                req.scene,
                crate::daemon::jobs::capture_label(&req.pose, &req.channels),
                req.frames,
                req.dark_frames,
                a.exposure_us
            );
        }
        self.count_refusal(pushed)
    }

    /// Validates a reconstruction body against its scene and captures and queues it.
    pub(crate) fn submit_reconstruction(&self, b: &ReconstructionBody) -> Result<i64, SubmitError> {
        let scene = self
            .scenes
            .now()
            .scene(&b.scene)
            .map_err(RequestError::from)?;
        let request = validate::reconstruction(b, &scene, |id| self.lookup_capture(id))?;
        let pushed = self.reconstructions.push(5, || {
            self.store
                .insert_reconstruction(&request)
                .map_err(|e| SubmitError::Internal(self.store.describe(&e)))
        });
        if let Ok(id) = &pushed {
            tracing::info!(
                "reconstruction-{id} queued: {} of captures {:?}, {}",
                b.scene,
                b.captures,
                request.params.solve.solver.name()
            );
        }
        self.count_refusal(pushed)
    }

    /// Counts a full queue's refusal in the metrics.
    fn count_refusal(&self, pushed: Result<i64, SubmitError>) -> Result<i64, SubmitError> {
        if let Err(SubmitError::QueueFull { .. }) = pushed {
            self.metrics.rejected_full.fetch_add(1, Ordering::Relaxed);
        }
        pushed
    }
}
