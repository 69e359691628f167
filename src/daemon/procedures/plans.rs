//! Acquisition plans: one request that captures every (pose, angle) block
//! of a scene, light and dark, and then reconstructs; the steps a bench
//! cannot do by itself (moving the camera, turning a polarizer by hand,
//! switching the hidden scene off) wait for the operator's Continue.
//!
//! Why a plan is a catalogue row walked by one runner: a daemon stopped in
//! the middle resumes at the step it was at, with the captures its finished
//! steps took (a capture the stop interrupted is taken again; none that
//! finished is), and plans share the one bench in the order they came.

use std::ops::ControlFlow;
use std::sync::Arc;
use std::time::Duration;

use serde::Serialize;

use crate::daemon::requests::{CaptureBody, PlanBody, ReconstructionBody};
use crate::daemon::runtime::events::Event;
use crate::rig::Automated;

use crate::daemon::requests::admission::Admission;
use crate::daemon::{JobKind, RequestError, SubmitError};
use crate::scene::{Channel, Scene};
use crate::store::{CaptureKind, JobState, PlanCapture, PlanInterim, PlanRow, PlanState};

/// How often a plan looks at the job its step waits on.
const POLL: Duration = Duration::from_millis(200);

/// One step of a plan.
#[derive(Debug, Clone, PartialEq, Serialize, utoipa::ToSchema)]
#[serde(tag = "kind", rename_all = "snake_case")]
pub enum PlanStep {
    /// The operator does something, then `POST /plans/{id}/continue`.
    Operator {
        /// What to do.
        prompt: String,
    },
    /// A capture of one block.
    Capture {
        /// Pose name.
        pose: String,
        /// Polarizer angle from crossed (None: the pose has no polarizer).
        polarizer_deg: Option<f64>,
        /// `light` or `dark`.
        capture: CaptureKind,
        /// The step of the dark capture subtracted from this one.
        dark_step: Option<usize>,
    },
    /// The scene's geometry fitted to the light captures (a calibration shot).
    FitGeometry,
    /// The reconstruction from the light captures, in the scene's block order.
    Reconstruct,
}

/// A plan as `GET /plans/{id}` shows it: its row and its steps.
#[derive(Debug, Clone, Serialize, utoipa::ToSchema)]
pub struct PlanView {
    /// The plan's row: state, the step it is at, the prompt, the captures taken.
    #[serde(flatten)]
    pub plan: PlanRow,
    /// Every step, in order (empty when its scene is no longer known).
    pub steps: Vec<PlanStep>,
}

/// Why a stored plan's steps cannot be made again (after a restart, or
/// when it goes on): the plan is interrupted with this as its reason.
#[derive(Debug, thiserror::Error)]
enum StoredPlanError {
    /// The request stored with the plan no longer parses as a plan body.
    #[error("its stored request cannot be read ({0})")]
    Request(#[from] serde_json::Error),
    /// The plan's scene is not among the daemon's scenes now.
    #[error("its scene is no longer known ({0})")]
    Scene(#[from] crate::daemon::runtime::scenes::ScenesError),
}

/// Why a plan request could not be done.
#[derive(Debug, thiserror::Error)]
pub enum PlanError {
    /// No plan with that id (404).
    #[error("no plan with id {0}")]
    NotFound(i64),
    /// `continue` on a plan that is not waiting for the operator (409).
    #[error("plan {id} is {}, not waiting for the operator", state.name())]
    NotWaiting {
        /// The plan.
        id: i64,
        /// Where it is.
        state: PlanState,
    },
    /// The plan already ended (409).
    #[error("plan {id} is {}; only a plan that has not ended can be cancelled", state.name())]
    Ended {
        /// The plan.
        id: i64,
        /// How it ended.
        state: PlanState,
    },
    /// The request itself is wrong (422/404/503 as for a capture).
    #[error(transparent)]
    Submit(#[from] SubmitError),
}

/// The steps of a plan over `scene`: its blocks in order (all angles of a
/// pose together, poses in file order), an operator step before each pose
/// after the first when no stage moves the camera, one before each angle
/// when no mount turns the polarizer, and operator steps around a dark
/// capture when the bench cannot switch the hidden scene off by itself;
/// then the reconstruction.
pub fn steps_of(scene: &Scene, body: &PlanBody, bench: Automated) -> Vec<PlanStep> {
    let Automated {
        mount,
        stage,
        switches_scene,
    } = bench;
    let mut steps = Vec::new();
    let mut last_pose: Option<String> = None;
    for block in crate::transport::blocks_of(scene) {
        // One mosaic frame holds all of its pose's blocks: one capture, at its first.
        if matches!(block.channel, Channel::Mosaic { deg } if deg != 0.0) {
            continue;
        }
        if !stage && last_pose.as_ref().is_some_and(|p| *p != block.pose) {
            steps.push(PlanStep::Operator {
                prompt: format!(
                    "move the camera to pose {}, then press Continue",
                    block.pose
                ),
            });
        }
        if let (Some(deg), false) = (block.channel.sheet_deg(), mount) {
            steps.push(PlanStep::Operator {
                prompt: format!(
                    "turn the polarizer of pose {} to {deg}° from crossed, then press Continue",
                    block.pose
                ),
            });
        }
        let capture = |kind, dark_step| PlanStep::Capture {
            pose: block.pose.clone(),
            polarizer_deg: block.channel.sheet_deg(),
            capture: kind,
            dark_step,
        };
        if body.dark_frames > 0 && !switches_scene {
            steps.push(PlanStep::Operator {
                prompt: "switch the hidden scene off, then press Continue".into(),
            });
            let dark = steps.len();
            steps.push(capture(CaptureKind::Dark, None));
            steps.push(PlanStep::Operator {
                prompt: "switch the hidden scene on again, then press Continue".into(),
            });
            steps.push(capture(CaptureKind::Light, Some(dark)));
        } else {
            steps.push(capture(CaptureKind::Light, None));
        }
        last_pose = Some(block.pose);
    }
    if body.calibrate_scene.is_some() {
        steps.push(PlanStep::FitGeometry);
    }
    steps.push(PlanStep::Reconstruct);
    steps
}

/// The capture request of a capture step.
fn capture_body(
    scene: &str,
    body: &PlanBody,
    step: &PlanStep,
    dark_capture: Option<i64>,
    switches_scene: bool,
) -> Option<CaptureBody> {
    let PlanStep::Capture {
        pose,
        polarizer_deg,
        capture,
        ..
    } = step
    else {
        return None;
    };
    let dark = *capture == CaptureKind::Dark;
    Some(CaptureBody {
        kind: Some(*capture),
        scene: scene.to_string(),
        pose: pose.clone(),
        polarizer_deg: *polarizer_deg,
        settings: body.settings,
        exposure: body.exposure,
        target: None,
        frames: if dark {
            Some(body.dark_frames.max(1))
        } else {
            body.frames
        },
        dark_frames: if !dark && switches_scene {
            body.dark_frames
        } else {
            0
        },
        dark_capture,
        progressive: None,
        difference: None,
        record: None,
    })
}

/// The progressive re-solve of the plan's last light capture: every other
/// block's capture is taken by then, so the whole scene can be solved from
/// them and the running mean (None for other steps, or when not asked).
fn last_block_progressive(
    body: &PlanBody,
    steps: &[PlanStep],
    plan: &PlanRow,
    at: usize,
) -> Option<crate::daemon::requests::ProgressiveBody> {
    let every = body.reconstruct.progressive_every?;
    let last = steps.iter().rposition(is_light)?;
    if last != at {
        return None;
    }
    let r = &body.reconstruct;
    Some(crate::daemon::requests::ProgressiveBody {
        every: Some(every),
        captures: reconstruction_body(plan, body, steps, at).captures,
        lambda: r.solve.lambda,
        max_iter: r.solve.max_iter,
        truth: r.truth.clone(),
        radiometry: r.radiometry,
    })
}

/// Whether `s` is a light capture step.
fn is_light(s: &PlanStep) -> bool {
    matches!(
        s,
        PlanStep::Capture {
            capture: CaptureKind::Light,
            ..
        }
    )
}

/// The reconstruction of the light captures `plan` took in its steps before
/// `upto`, in the scene's block order: the plan's final one when every step
/// is before it, else an interim one from the blocks taken so far (`partial`).
fn reconstruction_body(
    plan: &PlanRow,
    body: &PlanBody,
    steps: &[PlanStep],
    upto: usize,
) -> ReconstructionBody {
    let captures = steps[..upto.min(steps.len())]
        .iter()
        .enumerate()
        .filter(|(_, s)| is_light(s))
        .filter_map(|(k, _)| plan.captures.iter().find(|c| c.step == k))
        .map(|c| c.capture)
        .collect();
    let r = &body.reconstruct;
    ReconstructionBody {
        scene: plan.scene.clone(),
        captures,
        solve: r.solve,
        truth: r.truth.as_deref().map(crate::store::Truth::from),
        partial: upto < steps.len(),
        radiometry: r.radiometry,
    }
}

/// Where a step's job is.
enum Waited {
    Done,
    Failed(String),
    PlanEnded,
    Stopping,
}

/// The plans' handle: what the runner and the plan requests share. The
/// runner holds this, never the daemon; it posts its steps' jobs through
/// [`Admission`] as a client would.
pub(crate) struct Plans {
    /// The store, scenes, rig, calibration, registry and events plans read,
    /// and the door their steps' jobs go through.
    admission: Arc<Admission>,
    /// Wakes the runner: a plan was posted, continued or cancelled.
    wake: tokio::sync::Notify,
}

impl Plans {
    /// The plans over the services `admission` shares with them.
    pub(in crate::daemon) fn new(admission: Arc<Admission>) -> Self {
        Self {
            admission,
            wake: tokio::sync::Notify::new(),
        }
    }

    fn plan_steps(&self, plan: &PlanRow) -> Result<(PlanBody, Vec<PlanStep>), StoredPlanError> {
        let body: PlanBody = serde_json::from_value(plan.request.clone())?;
        let scene = self.admission.scenes.now().scene(&plan.scene)?;
        Ok((
            body.clone(),
            steps_of(&scene, &body, self.admission.rig.automated()),
        ))
    }

    /// Checks a plan request (every capture it will post, as `POST
    /// /captures` would) and records it; the runner starts it when the
    /// plans before it have ended.
    pub(crate) async fn submit_plan(
        self: &Arc<Self>,
        body: PlanBody,
    ) -> Result<PlanView, PlanError> {
        let scene = self
            .admission
            .scenes
            .now()
            .scene(&body.scene)
            .map_err(|e| SubmitError::from(RequestError::from(e)))?;
        if body.settings.exposure_us.is_some() && body.exposure.is_some() {
            return Err(SubmitError::from(RequestError::Invalid(
                "give either exposure_us or \"exposure\": \"auto\", not both".into(),
            ))
            .into());
        }
        // The reconstruction's parameters now, not after every capture.
        if let Err(e) = body.reconstruct.solve.check() {
            return Err(
                SubmitError::from(RequestError::Invalid(format!("reconstruct.{e}"))).into(),
            );
        }
        if body.reconstruct.progressive_every.is_some() {
            self.admission
                .needs_gain(
                    "reconstruct.progressive_every",
                    &body.scene,
                    body.reconstruct.radiometry,
                    false,
                )
                .map_err(SubmitError::from)?;
        }
        if let (Some(every), Some(frames)) = (body.reconstruct.progressive_every, body.frames) {
            if every > frames {
                return Err(SubmitError::from(RequestError::Invalid(format!(
                    "reconstruct.progressive_every = {every}: the last block takes only {frames} frames; give at most {frames}"
                )))
                .into());
            }
        }
        let bench = self.admission.rig.automated();
        let steps = steps_of(&scene, &body, bench);
        for step in &steps {
            // A dark capture stands in for the one a light step will name.
            if let Some(b) = capture_body(&body.scene, &body, step, None, bench.switches_scene) {
                let a = self.admission.clone();
                tokio::task::spawn_blocking(move || a.check_capture(&b))
                    .await
                    .map_err(|e| SubmitError::Internal(format!("plan validation: {e}")))?
                    .map_err(SubmitError::from)?;
            }
        }
        let request = serde_json::to_value(&body)
            .map_err(|e| SubmitError::Internal(format!("plan request: {e}")))?;
        let id = self
            .admission
            .store
            .insert_plan(&body.scene, &request)
            .map_err(|e| SubmitError::Internal(self.admission.store.describe(&e)))?;
        tracing::info!("plan-{id} queued: {}, {} steps", body.scene, steps.len());
        self.plan_event(id, PlanState::Queued, 0, None);
        self.wake.notify_one();
        self.plan_view(id)
    }

    /// A plan with its steps.
    pub(crate) fn plan_view(&self, id: i64) -> Result<PlanView, PlanError> {
        let plan = self.plan_row(id)?;
        let steps = self.plan_steps(&plan).map(|(_, s)| s).unwrap_or_default();
        Ok(PlanView { plan, steps })
    }

    /// Plan `id`'s row, or 404.
    fn plan_row(&self, id: i64) -> Result<PlanRow, PlanError> {
        self.admission
            .store
            .plan(id)
            .map_err(|e| self.plan_store_error(e))?
            .ok_or(PlanError::NotFound(id))
    }

    fn plan_store_error(&self, e: crate::store::StoreError) -> PlanError {
        SubmitError::Internal(self.admission.store.describe(&e)).into()
    }

    /// The operator did what the prompt asked: the plan goes on.
    pub(crate) fn continue_plan(&self, id: i64) -> Result<PlanView, PlanError> {
        let store_err = |e| self.plan_store_error(e);
        let plan = self.plan_row(id)?;
        if plan.state != PlanState::WaitingForOperator {
            return Err(PlanError::NotWaiting {
                id,
                state: plan.state,
            });
        }
        // An operator step is done; a capture step that paused on a failure
        // is taken again.
        let steps = self.plan_steps(&plan).map(|(_, s)| s).unwrap_or_default();
        let next = match steps.get(plan.step) {
            Some(PlanStep::Operator { .. }) => plan.step + 1,
            _ => plan.step,
        };
        self.admission
            .store
            .plan_step(id, next, &plan.captures)
            .map_err(store_err)?;
        self.admission
            .store
            .plan_state(id, PlanState::Running, None, None)
            .map_err(store_err)?;
        tracing::info!("plan-{id}: the operator continued at step {}", plan.step);
        self.plan_event(id, PlanState::Running, next, None);
        self.wake.notify_one();
        self.plan_view(id)
    }

    /// Cancels a plan that has not ended, and the capture or reconstruction
    /// its current step waits on; the captures it took are kept.
    pub(crate) async fn cancel_plan(&self, id: i64) -> Result<PlanView, PlanError> {
        let store_err = |e| self.plan_store_error(e);
        let plan = self.plan_row(id)?;
        if plan.state.is_final()
            || !self
                .admission
                .store
                .plan_state(
                    id,
                    PlanState::Cancelled,
                    None,
                    Some("cancelled by a client"),
                )
                .map_err(store_err)?
        {
            return Err(PlanError::Ended {
                id,
                state: plan.state,
            });
        }
        if let Some(c) = plan.captures.iter().find(|c| c.step == plan.step) {
            let _ = self.admission.cancel_job(JobKind::Capture, c.capture).await;
        }
        if let Some(r) = plan.reconstruction {
            let _ = self.admission.cancel_job(JobKind::Reconstruction, r).await;
        }
        tracing::info!("plan-{id} cancelled");
        self.plan_event(id, PlanState::Cancelled, plan.step, None);
        self.wake.notify_one();
        self.plan_view(id)
    }

    /// After light capture step `at` of a plan asking for `interim` results
    /// (and not its last light step), queues a reconstruction from the blocks
    /// taken so far, once: the image sharpens as the plan walks the scene. A
    /// refusal is logged and the plan goes on (its captures are the point).
    fn queue_interim(&self, plan: &mut PlanRow, body: &PlanBody, steps: &[PlanStep], at: usize) {
        let last_light = steps.iter().rposition(is_light);
        if !body.reconstruct.interim
            || !steps.get(at).is_some_and(is_light)
            || last_light == Some(at)
            || plan.interim.iter().any(|r| r.step == at)
        {
            return;
        }
        let id = plan.id;
        match self
            .admission
            .submit_reconstruction(&reconstruction_body(plan, body, steps, at + 1))
        {
            Ok(r) => {
                plan.interim.push(PlanInterim {
                    step: at,
                    reconstruction: r,
                });
                if let Err(e) = self.admission.store.plan_interim(id, &plan.interim) {
                    tracing::warn!(
                        "plan-{id}: interim reconstruction-{r} not recorded: {}",
                        self.admission.store.describe(&e)
                    );
                }
                tracing::info!("plan-{id}: interim reconstruction-{r} after step {at}");
            }
            Err(e) => tracing::warn!("plan-{id}: no interim reconstruction after step {at}: {e}"),
        }
    }

    fn plan_event(&self, plan: i64, state: PlanState, step: usize, prompt: Option<String>) {
        self.admission.events.emit(Event::Plan {
            plan,
            state,
            step,
            prompt,
        });
    }

    /// Whether plan `id` has ended (or is gone): a cancel while a step waits.
    fn plan_ended(&self, id: i64) -> bool {
        self.admission
            .store
            .plan(id)
            .ok()
            .flatten()
            .is_none_or(|p| p.state.is_final())
    }

    /// Posts a step's capture; while the camera has not reported itself (a
    /// daemon that just started) or the queue is full, tries again every
    /// second. `None` when the plan ended or the daemon stops meanwhile.
    async fn submit_until_admitted(
        self: &Arc<Self>,
        plan: i64,
        body: CaptureBody,
    ) -> Option<Result<i64, SubmitError>> {
        loop {
            match self.admission.submit_capture(body.clone()).await {
                Ok((c, _)) => return Some(Ok(c)),
                Err(
                    SubmitError::Request(RequestError::Unavailable(_))
                    | SubmitError::QueueFull { .. },
                ) => {}
                Err(e) => return Some(Err(e)),
            }
            tokio::time::sleep(Duration::from_secs(1)).await;
            if self.plan_ended(plan) || self.admission.registry.is_stopping() {
                return None;
            }
        }
    }

    /// Waits until capture or reconstruction `id` ends, the plan ends (a
    /// cancel) or the daemon stops.
    async fn wait_job(&self, plan: i64, kind: JobKind, id: i64) -> Waited {
        loop {
            if self.admission.registry.is_stopping() {
                return Waited::Stopping;
            }
            if self.plan_ended(plan) {
                return Waited::PlanEnded;
            }
            let state = match kind {
                JobKind::Capture => self.admission.store.capture(id).map(|c| (c.state, c.error)),
                JobKind::Reconstruction => self
                    .admission
                    .store
                    .reconstruction(id)
                    .map(|r| (r.state, r.error)),
                JobKind::SceneFit => self
                    .admission
                    .store
                    .scene_fit(id)
                    .map(|r| (r.state, r.error)),
            };
            match state {
                Ok((JobState::Done, _)) => return Waited::Done,
                Ok((JobState::Queued | JobState::Running, _)) => {}
                Ok((s, e)) => {
                    return Waited::Failed(format!(
                        "{}-{id} {}{}",
                        kind.name(),
                        s.name(),
                        e.map(|e| format!(": {e}")).unwrap_or_default()
                    ))
                }
                Err(e) => return Waited::Failed(self.admission.store.describe(&e)),
            }
            tokio::time::sleep(POLL).await;
        }
    }

    /// Walks plan `id` from the step it is at until it ends, waits for the
    /// operator, or the daemon stops.
    async fn run_plan(self: &Arc<Self>, id: i64) {
        let Some((mut plan, body, steps)) = self.resume_plan(id) else {
            return;
        };
        let switches = self.admission.rig.automated().switches_scene;
        while let Some(step) = steps.get(plan.step) {
            let at = plan.step;
            let walked = match step {
                PlanStep::Operator { prompt } => {
                    self.wait_for_operator(id, at, prompt);
                    ControlFlow::Break(())
                }
                PlanStep::Capture { .. } => {
                    self.capture_step(&mut plan, &body, &steps, at, switches)
                        .await
                }
                PlanStep::FitGeometry => self.fit_geometry_step(&plan, &body, &steps, at).await,
                PlanStep::Reconstruct => self.reconstruct_step(&mut plan, &body, &steps, at).await,
            };
            if walked.is_break() {
                return;
            }
            plan.step = at + 1;
            let _ = self
                .admission
                .store
                .plan_step(id, plan.step, &plan.captures);
            self.plan_event(id, PlanState::Running, plan.step, None);
        }
        self.finish_plan(&plan);
    }

    /// Plan `id`'s row, request and steps, marked running if queued; `None`: nothing to walk.
    /// Why: a plan whose request or scene can no longer be read is interrupted, not walked.
    fn resume_plan(&self, id: i64) -> Option<(PlanRow, PlanBody, Vec<PlanStep>)> {
        let Ok(Some(plan)) = self.admission.store.plan(id) else {
            return None;
        };
        let (body, steps) = match self.plan_steps(&plan) {
            Ok(s) => s,
            Err(why) => {
                let why = why.to_string();
                let _ =
                    self.admission
                        .store
                        .plan_state(id, PlanState::Interrupted, None, Some(&why));
                self.plan_event(id, PlanState::Interrupted, plan.step, None);
                return None;
            }
        };
        if plan.state == PlanState::WaitingForOperator {
            return None;
        }
        if plan.state == PlanState::Queued {
            let _ = self
                .admission
                .store
                .plan_state(id, PlanState::Running, None, None);
            tracing::info!("plan-{id} started");
            self.plan_event(id, PlanState::Running, plan.step, None);
        }
        Some((plan, body, steps))
    }

    /// Puts plan `id` on hold at operator step `at`, showing its prompt.
    /// Why: the bench cannot do this step; the operator's Continue walks on.
    fn wait_for_operator(&self, id: i64, at: usize, prompt: &str) {
        let _ =
            self.admission
                .store
                .plan_state(id, PlanState::WaitingForOperator, Some(prompt), None);
        tracing::info!("plan-{id} waits for the operator: {prompt}");
        self.plan_event(
            id,
            PlanState::WaitingForOperator,
            at,
            Some(prompt.to_string()),
        );
    }

    /// Runs capture step `at`: keeps or takes its capture and waits for it; `Break` stops the walk.
    /// Why: the step resumes, retakes and pauses, cases that read best apart from the walk.
    async fn capture_step(
        self: &Arc<Self>,
        plan: &mut PlanRow,
        body: &PlanBody,
        steps: &[PlanStep],
        at: usize,
        switches: bool,
    ) -> ControlFlow<()> {
        let capture = match self.kept_capture(plan, at) {
            Some(c) => c,
            None => match self.take_capture(plan, body, steps, at, switches).await {
                Some(c) => c,
                None => return ControlFlow::Break(()),
            },
        };
        match self.wait_job(plan.id, JobKind::Capture, capture).await {
            Waited::Done => self.queue_interim(plan, body, steps, at),
            Waited::Failed(why) => {
                self.pause_failed_step(plan.id, at, &why);
                return ControlFlow::Break(());
            }
            Waited::PlanEnded | Waited::Stopping => return ControlFlow::Break(()),
        }
        ControlFlow::Continue(())
    }

    /// The capture step `at` took before a resume, if done or still going.
    /// Why: a resumed plan keeps what its steps took; a capture that did not finish is retaken.
    fn kept_capture(&self, plan: &PlanRow, at: usize) -> Option<i64> {
        plan.captures
            .iter()
            .find(|c| c.step == at)
            .map(|c| c.capture)
            .filter(|&c| {
                self.admission.store.capture(c).is_ok_and(|r| {
                    matches!(
                        r.state,
                        JobState::Done | JobState::Queued | JobState::Running
                    )
                })
            })
    }

    /// Posts capture step `at`'s capture and records it in the plan; `None` stops the walk.
    /// Why: the plan must hold the new capture (and mark the old one retaken) before it waits.
    async fn take_capture(
        self: &Arc<Self>,
        plan: &mut PlanRow,
        body: &PlanBody,
        steps: &[PlanStep],
        at: usize,
        switches: bool,
    ) -> Option<i64> {
        let id = plan.id;
        let step = steps.get(at)?;
        let PlanStep::Capture { dark_step, .. } = step else {
            return None;
        };
        let dark = dark_step.and_then(|s| {
            plan.captures
                .iter()
                .find(|c| c.step == s)
                .map(|c| c.capture)
        });
        let mut b = capture_body(&plan.scene, body, step, dark, switches)?;
        b.progressive = last_block_progressive(body, steps, plan, at);
        let c = match self.submit_until_admitted(id, b).await? {
            Ok(c) => c,
            Err(e) => {
                self.fail_plan(plan, format!("step {at}: {e}"));
                return None;
            }
        };
        for old in plan.captures.iter().filter(|o| o.step == at) {
            let said = format!("plan {id} took this step again as capture {c}");
            if let Err(e) = self.admission.store.capture_retaken(old.capture, &said) {
                tracing::warn!("plan-{id}: capture-{}: {e}", old.capture);
            }
        }
        plan.captures.retain(|c| c.step != at);
        plan.captures.push(PlanCapture {
            step: at,
            capture: c,
        });
        let _ = self.admission.store.plan_step(id, at, &plan.captures);
        Some(c)
    }

    /// Puts plan `id` on hold after capture step `at` failed for `why`.
    /// Why: a camera lost, a mount that missed, frames lost: the bench needs a look.
    fn pause_failed_step(&self, id: i64, at: usize, why: &str) {
        let prompt = format!(
            "step {at} failed ({why}); fix the bench, then press Continue to take it again"
        );
        tracing::warn!("plan-{id} paused: {prompt}");
        let _ =
            self.admission
                .store
                .plan_state(id, PlanState::WaitingForOperator, Some(&prompt), None);
        self.plan_event(id, PlanState::WaitingForOperator, at, Some(prompt));
    }

    /// Runs reconstruct step `at`: queues the reconstruction (once), waits; `Break` stops the walk.
    /// Why: a resumed plan waits on the reconstruction it queued before the stop.
    async fn reconstruct_step(
        &self,
        plan: &mut PlanRow,
        body: &PlanBody,
        steps: &[PlanStep],
        at: usize,
    ) -> ControlFlow<()> {
        let id = plan.id;
        let rid = match plan.reconstruction {
            Some(r) => r,
            None => {
                let b = reconstruction_body(plan, body, steps, steps.len());
                let rid = match self.admission.submit_reconstruction(&b) {
                    Ok(r) => r,
                    Err(e) => {
                        self.fail_plan(plan, format!("step {at}: {e}"));
                        return ControlFlow::Break(());
                    }
                };
                let _ = self.admission.store.plan_reconstruction(id, rid);
                plan.reconstruction = Some(rid);
                rid
            }
        };
        self.wait_step(plan, at, JobKind::Reconstruction, rid).await
    }

    /// Waits for job `job` of step `at`; `Break` stops the walk (and a
    /// failed job fails the plan).
    async fn wait_step(
        &self,
        plan: &PlanRow,
        at: usize,
        kind: JobKind,
        job: i64,
    ) -> ControlFlow<()> {
        match self.wait_job(plan.id, kind, job).await {
            Waited::Done => ControlFlow::Continue(()),
            Waited::Failed(why) => {
                self.fail_plan(plan, format!("step {at}: {why}"));
                ControlFlow::Break(())
            }
            Waited::PlanEnded | Waited::Stopping => ControlFlow::Break(()),
        }
    }

    /// Runs the calibration shot's fit on the plan's light captures and
    /// waits for it; `Break` stops the walk.
    /// Why: the reconstruction after it is to use the fitted geometry.
    async fn fit_geometry_step(
        &self,
        plan: &PlanRow,
        body: &PlanBody,
        steps: &[PlanStep],
        at: usize,
    ) -> ControlFlow<()> {
        let captures = reconstruction_body(plan, body, steps, steps.len()).captures;
        let b = crate::daemon::SceneFitBody::of_plan(body, captures);
        let procedures = super::Procedures::new(self.admission.clone());
        let started = tokio::task::spawn_blocking(move || procedures.fit_scene(&b)).await;
        match started
            .map_err(|e| e.to_string())
            .and_then(|r| r.map_err(|e| e.to_string()))
        {
            Ok(row) => self.wait_step(plan, at, JobKind::SceneFit, row.id).await,
            Err(why) => {
                self.fail_plan(plan, format!("step {at}: {why}"));
                ControlFlow::Break(())
            }
        }
    }

    /// Marks `plan` failed at the step it is at, for `why`.
    /// Why: a refused request or a failed reconstruction is not the operator's to mend.
    fn fail_plan(&self, plan: &PlanRow, why: String) {
        let id = plan.id;
        tracing::warn!("plan-{id} failed at step {}: {why}", plan.step);
        let _ = self
            .admission
            .store
            .plan_state(id, PlanState::Failed, None, Some(&why));
        self.plan_event(id, PlanState::Failed, plan.step, None);
    }

    /// Marks `plan` done once it has walked every step.
    /// Why: only a plan that has not ended becomes done (a cancel may have come first).
    fn finish_plan(&self, plan: &PlanRow) {
        let id = plan.id;
        if self
            .admission
            .store
            .plan_state(id, PlanState::Done, None, None)
            .unwrap_or(false)
        {
            tracing::info!("plan-{id} done");
            self.plan_event(id, PlanState::Done, plan.step, None);
        }
    }
}

/// Runs the plans one at a time, oldest first, until the daemon stops: a
/// plan waiting for the operator holds the bench until it is continued or
/// cancelled.
pub(in crate::daemon) async fn run(plans: Arc<Plans>) {
    let registry = plans.admission.registry.clone();
    loop {
        if registry.is_stopping() {
            return;
        }
        let notified = plans.wake.notified();
        let next = plans
            .admission
            .store
            .unfinished_plans()
            .ok()
            .and_then(|p| p.first().copied());
        // Nothing to run, or the oldest plan holds the bench for its operator.
        let waiting = match next {
            None => true,
            Some(id) => {
                plans.run_plan(id).await;
                plans
                    .admission
                    .store
                    .plan(id)
                    .ok()
                    .flatten()
                    .is_some_and(|p| p.state == PlanState::WaitingForOperator)
            }
        };
        let mut stopped = registry.stopped();
        if waiting {
            tokio::select! {
                _ = notified => {}
                _ = stopped.wait_for(|s| *s) => return,
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn scene(name: &str) -> Scene {
        let text = crate::scene::builtin::text(name).unwrap();
        Scene::from_toml_str(text).unwrap()
    }

    fn body(dark_frames: usize) -> PlanBody {
        serde_json::from_value(serde_json::json!({
            "scene": "brewster-multi", "exposure_us": 1000, "dark_frames": dark_frames
        }))
        .unwrap()
    }

    fn prompts(steps: &[PlanStep]) -> Vec<String> {
        steps
            .iter()
            .map(|s| match s {
                PlanStep::Operator { prompt } => prompt.clone(),
                PlanStep::Capture {
                    pose,
                    polarizer_deg,
                    capture,
                    ..
                } => format!("{} {pose} {polarizer_deg:?}", capture.name()),
                PlanStep::FitGeometry => "fit geometry".into(),
                PlanStep::Reconstruct => "reconstruct".into(),
            })
            .collect()
    }

    #[test]
    fn a_bench_that_does_everything_waits_only_to_move_the_camera() {
        let scene = scene("brewster-multi");
        let steps = steps_of(&scene, &body(2), bench(true, false, true));
        let p = prompts(&steps);
        let first = format!("light {} Some(0.0)", scene.poses()[0].name);
        assert_eq!(p.first(), Some(&first));
        assert_eq!(p.last().map(String::as_str), Some("reconstruct"));
        let waits: Vec<&String> = p.iter().filter(|s| s.contains("Continue")).collect();
        assert_eq!(waits.len(), scene.poses().len() - 1, "{p:?}");
        assert!(waits.iter().all(|w| w.contains("move the camera")), "{p:?}");
        let captures = p.iter().filter(|s| s.starts_with("light ")).count();
        assert_eq!(captures, scene.block_count());
    }

    #[test]
    fn a_bench_set_by_hand_waits_for_each_angle_and_around_each_dark() {
        let scene = scene("brewster-rotating");
        let steps = steps_of(&scene, &body(2), bench(false, false, false));
        let p = prompts(&steps);
        let blocks = scene.block_count();
        assert_eq!(
            p.iter()
                .filter(|s| s.contains("turn the polarizer"))
                .count(),
            blocks
        );
        assert_eq!(p.iter().filter(|s| s.starts_with("dark ")).count(), blocks);
        assert_eq!(
            p.iter()
                .filter(|s| s.contains("switch the hidden scene off"))
                .count(),
            blocks
        );
        // Each light capture subtracts the dark taken just before it.
        for (k, s) in steps.iter().enumerate() {
            if let PlanStep::Capture {
                capture: CaptureKind::Light,
                dark_step: Some(d),
                ..
            } = s
            {
                assert!(matches!(
                    steps[*d],
                    PlanStep::Capture {
                        capture: CaptureKind::Dark,
                        ..
                    }
                ));
                assert_eq!(*d + 2, k);
            }
        }
        // Without darks, no scene switching.
        let steps = steps_of(&scene, &body(0), bench(false, false, false));
        assert!(prompts(&steps).iter().all(|s| !s.contains("hidden scene")));
    }

    #[test]
    fn the_plans_radiometry_reaches_its_last_blocks_progressive_steps() {
        use crate::solve::radiometry::Radiometry;
        let scene = scene("brewster-multi");
        let body: PlanBody = serde_json::from_value(serde_json::json!({
            "scene": "brewster-multi", "exposure_us": 1000, "dark_frames": 0,
            "reconstruct": {"progressive_every": 4, "radiometry": "fitted", "lambda": 0.01}
        }))
        .unwrap();
        let steps = steps_of(&scene, &body, bench(true, true, false));
        let lights: Vec<usize> = (0..steps.len()).filter(|&k| is_light(&steps[k])).collect();
        let plan = PlanRow {
            id: 1,
            scene: "brewster-multi".into(),
            request: serde_json::Value::Null,
            state: crate::store::PlanState::Running,
            step: 0,
            prompt: None,
            captures: lights[..lights.len() - 1]
                .iter()
                .enumerate()
                .map(|(n, &step)| crate::store::PlanCapture {
                    step,
                    capture: 10 + n as i64,
                })
                .collect(),
            reconstruction: None,
            interim: Vec::new(),
            error: None,
            created_at: String::new(),
            started_at: None,
            finished_at: None,
        };
        let last = *lights.last().unwrap();
        let p = last_block_progressive(&body, &steps, &plan, last).expect("the last block's");
        assert_eq!(p.radiometry, Some(Radiometry::Fitted));
        assert_eq!((p.every, p.lambda), (Some(4), Some(0.01)));
        // Every other block's capture, in step order, is solved with it.
        let others: Vec<i64> = (0..lights.len() as i64 - 1).map(|n| 10 + n).collect();
        assert_eq!(p.captures, others);
        // Only the last light capture re-solves as its frames arrive.
        assert!(last_block_progressive(&body, &steps, &plan, lights[0]).is_none());
    }

    fn bench(mount: bool, stage: bool, switches_scene: bool) -> Automated {
        Automated {
            mount,
            stage,
            switches_scene,
        }
    }

    #[test]
    fn a_bench_with_a_stage_walks_every_pose_without_the_operator() {
        let scene = scene("brewster-multi");
        let steps = steps_of(&scene, &body(2), bench(true, true, true));
        let p = prompts(&steps);
        assert!(p.iter().all(|s| !s.contains("Continue")), "{p:?}");
        let poses: Vec<&str> = steps
            .iter()
            .filter_map(|s| match s {
                PlanStep::Capture { pose, .. } => Some(pose.as_str()),
                _ => None,
            })
            .collect();
        assert_eq!(poses, ["B", "C"]);
    }
}
