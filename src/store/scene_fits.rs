//! Scene calibrations: each scene's geometry fitted to its captures
//! (`POST /calibrations/scene`), the newest done one in force.
//!
//! Why in the catalogue: a fit takes minutes and is the bench's geometry
//! until the next one; it must outlive restarts and the captures it came
//! from, and say which file text it placed (a changed file voids it).

use rusqlite::{params, OptionalExtension, Row};

use super::{now, JobState, Store, StoreError};

/// One scene calibration as stored.
#[derive(Debug, Clone, serde::Serialize, utoipa::ToSchema)]
pub(crate) struct SceneFitRow {
    /// Its id (its job is `scene-fit-<id>`).
    pub id: i64,
    /// The scene fitted.
    pub scene: String,
    /// The captures it was fitted to.
    pub captures: Vec<i64>,
    /// What was fitted (freedom names, `polnlos calibrate scene --free`).
    pub free: Vec<String>,
    /// Queued, running, done, failed, cancelled or interrupted.
    #[schema(value_type = String)]
    pub state: JobState,
    /// Why it failed, when it did.
    pub error: Option<String>,
    /// When it was asked for.
    pub created_at: String,
    /// When it ended.
    pub finished_at: Option<String>,
    /// The scene file's text it placed (a scene whose file reads otherwise
    /// now is not placed by it).
    #[serde(skip)]
    pub source_toml: String,
    /// The scene file with the fitted geometry (done only), a file in the
    /// same folder as the scene's.
    pub placed_toml: Option<String>,
    /// The fit as `polnlos calibrate scene --report` writes it (done only):
    /// each freedom's offset and uncertainty, the misfits, the warnings.
    #[schema(value_type = Object)]
    pub fit: Option<serde_json::Value>,
}

/// Why a scene calibration stopped before it was done.
const INTERRUPTED: &str =
    "the daemon stopped before this scene calibration finished; post it again";

const COLUMNS: &str =
    "id, scene, captures, free, state, error, created_at, finished_at, source_toml, placed_toml, fit";

impl Store {
    /// Records a scene calibration of `scene` from `captures`, queued.
    pub(crate) fn insert_scene_fit(
        &self,
        scene: &str,
        captures: &[i64],
        free: &[String],
        source_toml: &str,
    ) -> Result<SceneFitRow, StoreError> {
        // Numbers and names: they always serialize.
        let (c, f) = (
            serde_json::to_string(captures).unwrap_or_default(),
            serde_json::to_string(free).unwrap_or_default(),
        );
        let id = self.with(|conn| {
            conn.execute(
                "INSERT INTO scene_fits (scene, captures, free, state, created_at, source_toml) VALUES (?1, ?2, ?3, 'queued', ?4, ?5)",
                params![scene, c, f, now(), source_toml],
            )?;
            Ok(conn.last_insert_rowid())
        })?;
        self.scene_fit(id)
    }

    /// Scene calibration `id`.
    pub(crate) fn scene_fit(&self, id: i64) -> Result<SceneFitRow, StoreError> {
        self.with(|c| {
            c.query_row(
                &format!("SELECT {COLUMNS} FROM scene_fits WHERE id = ?1"),
                [id],
                fit_row,
            )
            .optional()
        })?
        .ok_or(StoreError::NotFound {
            kind: "scene calibration",
            id,
        })
    }

    /// Every scene calibration, newest first.
    pub(crate) fn scene_fits(&self) -> Result<Vec<SceneFitRow>, StoreError> {
        self.fit_rows("ORDER BY id DESC")
    }

    /// Each scene's newest done calibration: the geometry in force.
    pub(crate) fn scene_fits_in_force(&self) -> Result<Vec<SceneFitRow>, StoreError> {
        self.fit_rows("WHERE id IN (SELECT MAX(id) FROM scene_fits WHERE state = 'done' GROUP BY scene) ORDER BY scene")
    }

    /// The rows `tail` (a WHERE and ORDER BY) selects.
    fn fit_rows(&self, tail: &str) -> Result<Vec<SceneFitRow>, StoreError> {
        self.with(|c| {
            let mut st = c.prepare(&format!("SELECT {COLUMNS} FROM scene_fits {tail}"))?;
            let rows = st.query_map([], fit_row)?.collect();
            rows
        })
    }

    /// Scene calibration `id` has started.
    pub(crate) fn scene_fit_running(&self, id: i64) -> Result<(), StoreError> {
        self.with(|c| {
            c.execute(
                "UPDATE scene_fits SET state = 'running' WHERE id = ?1 AND state = 'queued'",
                [id],
            )
        })
        .map(|_| ())
    }

    /// Scene calibration `id` is done: the placed file and the fit.
    pub(crate) fn scene_fit_done(
        &self,
        id: i64,
        placed_toml: &str,
        fit: &serde_json::Value,
    ) -> Result<(), StoreError> {
        let fit = fit.to_string();
        self.with(|c| {
            c.execute(
                "UPDATE scene_fits SET state = 'done', finished_at = ?2, placed_toml = ?3, fit = ?4 WHERE id = ?1",
                params![id, now(), placed_toml, fit],
            )
        })
        .map(|_| ())
    }

    /// Scene calibration `id` ended without a fit (`state` failed,
    /// cancelled or interrupted), with why.
    pub(crate) fn scene_fit_ended(
        &self,
        id: i64,
        state: JobState,
        error: &str,
    ) -> Result<(), StoreError> {
        self.with(|c| {
            c.execute(
                "UPDATE scene_fits SET state = ?2, error = ?3, finished_at = ?4 WHERE id = ?1",
                params![id, state.name(), error, now()],
            )
        })
        .map(|_| ())
    }

    /// Deletes scene calibration `id` (not while it is queued or running).
    pub(crate) fn delete_scene_fit(&self, id: i64) -> Result<SceneFitRow, StoreError> {
        let row = self.scene_fit(id)?;
        if matches!(row.state, JobState::Queued | JobState::Running) {
            return Err(StoreError::InUse {
                kind: "scene calibration",
                id,
                reason: format!(
                    "it is {}; cancel it first (DELETE /jobs/scene-fit-{id})",
                    row.state.name()
                ),
            });
        }
        self.with(|c| c.execute("DELETE FROM scene_fits WHERE id = ?1", [id]))?;
        Ok(row)
    }

    /// Marks scene calibrations a stopped daemon left queued or running interrupted.
    pub(super) fn interrupt_scene_fits(conn: &rusqlite::Connection) -> rusqlite::Result<usize> {
        conn.execute(
            "UPDATE scene_fits SET state = 'interrupted', error = ?1, finished_at = ?2 WHERE state IN ('queued', 'running')",
            params![INTERRUPTED, now()],
        )
    }
}

/// A `scene_fits` row (an unreadable column makes the row an error, never a default).
fn fit_row(r: &Row<'_>) -> rusqlite::Result<SceneFitRow> {
    let state: String = r.get("state")?;
    let bad =
        |col: &str| rusqlite::Error::InvalidColumnType(0, col.into(), rusqlite::types::Type::Text);
    Ok(SceneFitRow {
        id: r.get("id")?,
        scene: r.get("scene")?,
        captures: super::records::json_column(r, "captures")?.ok_or_else(|| bad("captures"))?,
        free: super::records::json_column(r, "free")?.ok_or_else(|| bad("free"))?,
        state: JobState::parse(&state).ok_or_else(|| bad("state"))?,
        error: r.get("error")?,
        created_at: r.get("created_at")?,
        finished_at: r.get("finished_at")?,
        source_toml: r.get("source_toml")?,
        placed_toml: r.get("placed_toml")?,
        fit: super::records::json_column(r, "fit")?,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_newest_done_calibration_of_each_scene_is_in_force_across_a_reopen() {
        let dir = tempfile::tempdir().unwrap();
        let store = Store::open(dir.path()).unwrap();
        let free = ["occluder-x".to_string()];
        let a = store
            .insert_scene_fit("bench", &[1, 2], &free, "text a")
            .unwrap();
        assert_eq!(
            (a.state, a.captures.clone()),
            (JobState::Queued, vec![1, 2])
        );
        let refused = store.delete_scene_fit(a.id);
        assert!(
            matches!(refused, Err(StoreError::InUse { .. })),
            "{refused:?}"
        );
        store.scene_fit_running(a.id).unwrap();
        let fit = serde_json::json!({"fitted": []});
        store.scene_fit_done(a.id, "placed a", &fit).unwrap();
        let b = store
            .insert_scene_fit("bench", &[3], &free, "text b")
            .unwrap();
        store.scene_fit_ended(b.id, JobState::Failed, "no").unwrap();
        let c = store
            .insert_scene_fit("other", &[4], &free, "text c")
            .unwrap();
        store.scene_fit_running(c.id).unwrap();
        drop(store);
        // Reopened: the running one was interrupted, the done one is in force.
        let store = Store::open(dir.path()).unwrap();
        let c = store.scene_fit(c.id).unwrap();
        assert_eq!(c.state, JobState::Interrupted);
        assert!(c.error.unwrap().contains("post it again"));
        let in_force = store.scene_fits_in_force().unwrap();
        assert_eq!(in_force.len(), 1);
        assert_eq!(in_force[0].id, a.id);
        assert_eq!(in_force[0].placed_toml.as_deref(), Some("placed a"));
        assert_eq!(in_force[0].source_toml, "text a");
        assert_eq!(in_force[0].fit, Some(fit));
        assert_eq!(store.scene_fits().unwrap().len(), 3);
        store.delete_scene_fit(a.id).unwrap();
        assert!(store.scene_fits_in_force().unwrap().is_empty());
        assert!(matches!(
            store.scene_fit(a.id),
            Err(StoreError::NotFound { .. })
        ));
    }
}
