//! The plans aggregate: an acquisition plan's row from queued to done,
//! failed, cancelled or interrupted, with the step it is at, the operator's
//! prompt it waits on, the captures its steps took and its reconstruction.
//!
//! Why a row per plan with its step: a daemon restarted in the middle of a
//! plan resumes at the step it was at, with the captures its finished
//! steps took; nothing finished is captured twice.

use rusqlite::{params, OptionalExtension, Row};
use serde::{Deserialize, Serialize};

use super::records::{json_column, named_column};
use super::{now, Listing, Store, StoreError};

/// Where a plan is.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, utoipa::ToSchema)]
#[serde(rename_all = "snake_case")]
pub enum PlanState {
    /// Accepted; another plan has the bench.
    Queued,
    /// Walking its steps.
    Running,
    /// At an operator step: its `prompt` says what to do, then `POST /plans/{id}/continue`.
    WaitingForOperator,
    /// Every capture taken and its reconstruction done.
    Done,
    /// A step failed (see `error`); the captures taken are kept.
    Failed,
    /// Cancelled by `DELETE /plans/{id}`.
    Cancelled,
    /// Stopped by the daemon and not resumable (its scene is gone).
    Interrupted,
}

impl PlanState {
    const ALL: [PlanState; 7] = [
        PlanState::Queued,
        PlanState::Running,
        PlanState::WaitingForOperator,
        PlanState::Done,
        PlanState::Failed,
        PlanState::Cancelled,
        PlanState::Interrupted,
    ];

    /// The name stored and shown.
    pub fn name(self) -> &'static str {
        match self {
            PlanState::Queued => "queued",
            PlanState::Running => "running",
            PlanState::WaitingForOperator => "waiting_for_operator",
            PlanState::Done => "done",
            PlanState::Failed => "failed",
            PlanState::Cancelled => "cancelled",
            PlanState::Interrupted => "interrupted",
        }
    }

    /// The state of a name (as [`PlanState::name`] writes it).
    pub fn from_name(name: &str) -> Option<Self> {
        Self::ALL.into_iter().find(|s| s.name() == name)
    }

    /// Whether the plan has ended (nothing more will happen to it).
    pub fn is_final(self) -> bool {
        matches!(
            self,
            PlanState::Done | PlanState::Failed | PlanState::Cancelled | PlanState::Interrupted
        )
    }
}

/// One capture a plan's step took.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, utoipa::ToSchema)]
pub struct PlanCapture {
    /// The step (index into the plan's steps).
    pub step: usize,
    /// The capture's id.
    pub capture: i64,
}

/// An interim reconstruction a plan queued after one of its capture steps.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, utoipa::ToSchema)]
pub struct PlanInterim {
    /// The capture step after which it was queued.
    pub step: usize,
    /// The reconstruction's id (partial: the blocks captured by then).
    pub reconstruction: i64,
}

/// A plan as the catalogue keeps it.
#[derive(Debug, Clone, PartialEq, Serialize, utoipa::ToSchema)]
pub struct PlanRow {
    /// Id (never reused).
    pub id: i64,
    /// Scene name.
    pub scene: String,
    /// The request, as accepted (`POST /plans` body).
    #[schema(value_type = Object)]
    pub request: serde_json::Value,
    /// Where it is.
    pub state: PlanState,
    /// The step it is at (the next to run; the number of steps when all ran).
    pub step: usize,
    /// What the operator is asked to do (while waiting for the operator).
    pub prompt: Option<String>,
    /// The captures its steps took, in step order.
    pub captures: Vec<PlanCapture>,
    /// The reconstruction it queued.
    pub reconstruction: Option<i64>,
    /// The interim reconstructions it queued (`reconstruct.interim`), in step order.
    pub interim: Vec<PlanInterim>,
    /// Why it failed or was interrupted.
    pub error: Option<String>,
    /// When it was requested.
    pub created_at: String,
    /// When it started.
    pub started_at: Option<String>,
    /// When it ended.
    pub finished_at: Option<String>,
}

const PLAN_SELECT: &str = "SELECT * FROM plans";

fn plan_row(r: &Row<'_>) -> rusqlite::Result<PlanRow> {
    Ok(PlanRow {
        id: r.get("id")?,
        scene: r.get("scene")?,
        request: json_column(r, "request")?.unwrap_or(serde_json::Value::Null),
        state: named_column(r, "state", "plan state", PlanState::from_name)?,
        step: r.get::<_, i64>("step")?.max(0) as usize,
        prompt: r.get("prompt")?,
        captures: json_column(r, "captures")?.unwrap_or_default(),
        reconstruction: r.get("reconstruction")?,
        error: r.get("error")?,
        created_at: r.get("created_at")?,
        started_at: r.get("started_at")?,
        finished_at: r.get("finished_at")?,
        interim: json_column(r, "interim")?.unwrap_or_default(),
    })
}

impl Store {
    /// Records a new plan (state `queued`, step 0); returns its id.
    pub fn insert_plan(&self, scene: &str, request: &serde_json::Value) -> Result<i64, StoreError> {
        let request = request.to_string();
        self.with(|c| {
            c.execute(
                "INSERT INTO plans (scene, request, state, step, captures, created_at) VALUES (?1, ?2, 'queued', 0, '[]', ?3)",
                params![scene, request, now()],
            )?;
            Ok(c.last_insert_rowid())
        })
    }

    /// One plan, `None` when there is no such id.
    pub fn plan(&self, id: i64) -> Result<Option<PlanRow>, StoreError> {
        self.with(|c| {
            c.query_row(&format!("{PLAN_SELECT} WHERE id = ?1"), [id], plan_row)
                .optional()
        })
    }

    /// Plans, newest first.
    pub fn plans(&self, limit: usize, offset: usize) -> Result<Listing<PlanRow>, StoreError> {
        self.page(PLAN_SELECT, plan_row, "plan", limit, offset)
    }

    /// Ids of the plans that have not ended, oldest first (what a start resumes).
    pub fn unfinished_plans(&self) -> Result<Vec<i64>, StoreError> {
        self.with(|c| {
            let mut st = c.prepare(
                "SELECT id FROM plans WHERE state IN ('queued', 'running', 'waiting_for_operator') ORDER BY id",
            )?;
            let ids = st.query_map([], |r| r.get(0))?.collect();
            ids
        })
    }

    /// Sets a plan's state (and prompt and error); the start and end times
    /// follow. Returns false when the plan has ended (a cancel won the race).
    pub fn plan_state(
        &self,
        id: i64,
        state: PlanState,
        prompt: Option<&str>,
        error: Option<&str>,
    ) -> Result<bool, StoreError> {
        let t = now();
        self.with(|c| {
            c.execute(
                "UPDATE plans SET state = ?2, prompt = ?3, error = ?4,
                    started_at = COALESCE(started_at, CASE WHEN ?2 = 'queued' THEN NULL ELSE ?5 END),
                    finished_at = CASE WHEN ?2 IN ('done', 'failed', 'cancelled', 'interrupted') THEN ?5 ELSE NULL END
                 WHERE id = ?1 AND state NOT IN ('done', 'failed', 'cancelled', 'interrupted')",
                params![id, state.name(), prompt, error, t],
            )
            .map(|n| n == 1)
        })
    }

    /// Records that a plan's steps before `step` ran, with the captures they took.
    pub fn plan_step(
        &self,
        id: i64,
        step: usize,
        captures: &[PlanCapture],
    ) -> Result<(), StoreError> {
        let captures = serde_json::to_string(captures).unwrap_or_else(|_| "[]".into());
        self.with(|c| {
            c.execute(
                "UPDATE plans SET step = ?2, captures = ?3 WHERE id = ?1",
                params![id, step as i64, captures],
            )
            .map(|_| ())
        })
    }

    /// Records the interim reconstructions a plan queued.
    pub fn plan_interim(&self, id: i64, interim: &[PlanInterim]) -> Result<(), StoreError> {
        let interim = serde_json::to_string(interim).unwrap_or_else(|_| "[]".into());
        self.with(|c| {
            c.execute(
                "UPDATE plans SET interim = ?2 WHERE id = ?1",
                params![id, interim],
            )
            .map(|_| ())
        })
    }

    /// Records the reconstruction a plan queued.
    pub fn plan_reconstruction(&self, id: i64, reconstruction: i64) -> Result<(), StoreError> {
        self.with(|c| {
            c.execute(
                "UPDATE plans SET reconstruction = ?2 WHERE id = ?1",
                params![id, reconstruction],
            )
            .map(|_| ())
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_plan_keeps_its_step_and_captures_across_a_reopen_and_ends_once() {
        let dir = tempfile::tempdir().unwrap();
        let id = {
            let store = Store::open(dir.path()).unwrap();
            let id = store
                .insert_plan(
                    "brewster-multi",
                    &serde_json::json!({"scene": "brewster-multi"}),
                )
                .unwrap();
            assert!(store
                .plan_state(id, PlanState::Running, None, None)
                .unwrap());
            let taken = [PlanCapture {
                step: 0,
                capture: 4,
            }];
            store.plan_step(id, 1, &taken).unwrap();
            let prompt = "move the camera to pose B, then press Continue";
            assert!(store
                .plan_state(id, PlanState::WaitingForOperator, Some(prompt), None)
                .unwrap());
            id
        };
        let store = Store::open(dir.path()).unwrap();
        assert_eq!(store.unfinished_plans().unwrap(), [id]);
        let p = store.plan(id).unwrap().unwrap();
        assert_eq!((p.state, p.step), (PlanState::WaitingForOperator, 1));
        assert_eq!(
            p.captures,
            [PlanCapture {
                step: 0,
                capture: 4
            }]
        );
        assert!(p.prompt.unwrap().contains("pose B"));
        assert!(p.interim.is_empty());
        let interim = [PlanInterim {
            step: 0,
            reconstruction: 7,
        }];
        store.plan_interim(id, &interim).unwrap();
        assert_eq!(store.plan(id).unwrap().unwrap().interim, interim);
        assert!(store
            .plan_state(id, PlanState::Cancelled, None, None)
            .unwrap());
        // Ended: a late state change does nothing.
        assert!(!store.plan_state(id, PlanState::Done, None, None).unwrap());
        let p = store.plan(id).unwrap().unwrap();
        assert_eq!(p.state, PlanState::Cancelled);
        assert!(p.finished_at.is_some() && p.started_at.is_some());
        assert!(store.unfinished_plans().unwrap().is_empty());
        // Ids are not reused after a deletion of the newest.
        let next = store.insert_plan("s", &serde_json::json!({})).unwrap();
        assert!(next > id);
        for s in PlanState::ALL {
            assert_eq!(PlanState::from_name(s.name()), Some(s));
        }
    }
}
