//! The reconstructions aggregate: a reconstruction job's row from queued to
//! done, failed, cancelled or deleted, and its list.

use rusqlite::{params, OptionalExtension};

use super::records::{self, JobState, ReconstructionRecord, ReconstructionRequest};
use super::schema::Table;
use super::{finish, now, park, Listing, Store, StoreError};

impl Store {
    /// Records a new reconstruction job (state `queued`).
    pub fn insert_reconstruction(&self, r: &ReconstructionRequest) -> Result<i64, StoreError> {
        let captures = serde_json::to_string(&r.captures).unwrap_or_else(|_| "[]".into());
        let params_json = serde_json::to_string(&r.params).unwrap_or_else(|_| "{}".into());
        self.with(|c| {
            c.execute(
                "INSERT INTO reconstructions (id, scene, captures, params, state, created_at) VALUES ((SELECT last + 1 FROM issued_ids WHERE kind = 'reconstructions'), ?1, ?2, ?3, 'queued', ?4)",
                params![r.scene, captures, params_json, now()],
            )?;
            Ok(c.last_insert_rowid())
        })
    }

    /// Marks a reconstruction running.
    /// Returns false (and changes nothing) when it is no longer queued: a
    /// client cancelled it meanwhile.
    pub fn reconstruction_running(&self, id: i64) -> Result<bool, StoreError> {
        self.with(|c| {
            c.execute(
                "UPDATE reconstructions SET state = 'running', started_at = ?2 WHERE id = ?1 AND state = 'queued'",
                params![id, now()],
            )
            .map(|n| n == 1)
        })
    }

    /// Ids of the reconstructions waiting to run, oldest first: what a start
    /// queues again (the previous run stopped before they ended).
    pub fn queued_reconstructions(&self) -> Result<Vec<i64>, StoreError> {
        self.with(|c| {
            let mut st =
                c.prepare("SELECT id FROM reconstructions WHERE state = 'queued' ORDER BY id")?;
            let ids = st.query_map([], |r| r.get::<_, i64>(0))?;
            ids.collect()
        })
    }

    /// Puts a running reconstruction back in the queue because the daemon is
    /// stopping: the next start runs it again.
    pub fn reconstruction_requeued(&self, id: i64) -> Result<(), StoreError> {
        self.with(|c| {
            c.execute(Table::REQUEUE_RECONSTRUCTION, params![id])
                .map(|_| ())
        })
    }

    /// Records that a queued reconstruction could not be queued again at a
    /// start, and `why`.
    pub fn reconstruction_not_resumed(&self, id: i64, why: &str) -> Result<(), StoreError> {
        self.with(|c| {
            c.execute(
                "UPDATE reconstructions SET state = 'interrupted', error = ?2, finished_at = ?3 WHERE id = ?1 AND state = 'queued'",
                params![id, why, now()],
            )
            .map(|_| ())
        })
    }

    /// Cancels a reconstruction that is still queued; false when it is not queued.
    pub fn cancel_queued_reconstruction(&self, id: i64) -> Result<bool, StoreError> {
        self.cancel(Table::Reconstructions, id, true)
    }

    /// Records that a running reconstruction stopped because it was cancelled.
    pub fn reconstruction_cancelled(&self, id: i64) -> Result<bool, StoreError> {
        self.cancel(Table::Reconstructions, id, false)
    }

    /// Marks a reconstruction done with its kappa and report; call after its files are durable.
    pub fn reconstruction_done(&self, id: i64, kappa: f64, report: &str) -> Result<(), StoreError> {
        let kappa = if kappa.is_finite() {
            kappa.to_string()
        } else {
            "inf".into()
        };
        self.with(|c| {
            c.execute(
                "UPDATE reconstructions SET state = 'done', finished_at = ?2, kappa = ?3, report = ?4, error = NULL WHERE id = ?1",
                params![id, now(), kappa, report],
            )
            .map(|_| ())
        })
    }

    /// Marks a reconstruction failed.
    pub fn reconstruction_failed(&self, id: i64, error: &str) -> Result<(), StoreError> {
        self.with(|c| c.execute("UPDATE reconstructions SET state = 'failed', finished_at = ?2, error = ?3 WHERE id = ?1", params![id, now(), error]).map(|_| ()))
    }

    /// One reconstruction.
    pub fn reconstruction(&self, id: i64) -> Result<ReconstructionRecord, StoreError> {
        self.with(|c| {
            c.query_row(
                &format!("{} WHERE id = ?1", records::RECON_SELECT),
                [id],
                records::recon_row,
            )
            .optional()
        })?
        .ok_or(StoreError::NotFound {
            kind: "reconstruction",
            id,
        })
    }

    /// Reconstructions, newest first.
    pub fn reconstructions(
        &self,
        limit: usize,
        offset: usize,
    ) -> Result<Listing<ReconstructionRecord>, StoreError> {
        self.page(
            records::RECON_SELECT,
            records::recon_row,
            "reconstruction",
            limit,
            offset,
        )
    }

    /// Deletes reconstruction `id`, its row then its folder; refused while
    /// it is queued or running.
    pub fn delete_reconstruction(&self, id: i64) -> Result<(), StoreError> {
        let state = self.reconstruction(id)?.state;
        if matches!(state, JobState::Queued | JobState::Running) {
            return Err(StoreError::InUse {
                kind: "reconstruction",
                id,
                reason: format!(
                    "it is {}; cancel it first (DELETE /jobs/reconstruction-{id})",
                    state.name()
                ),
            });
        }
        let parked = park(&[self.reconstruction_dir(id)]);
        let deleted = self.with(|c| {
            c.execute(
                "DELETE FROM reconstructions WHERE id = ?1 AND state NOT IN ('queued', 'running')",
                [id],
            )
        });
        finish(&parked, matches!(deleted, Ok(1)));
        deleted?;
        Ok(())
    }
}
