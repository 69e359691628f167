//! The captures aggregate: a capture job's row from queued to done, failed,
//! cancelled or deleted (with the reconstructions that use it), and its list.

use std::path::PathBuf;

use rusqlite::{params, OptionalExtension};

use super::records::{self, CaptureRecord, CaptureRequest, SettingsDocument};
use super::schema::Table;
use super::{finish, now, park, Listing, Store, StoreError};

impl Store {
    /// Records a new capture job (state `queued`); returns its id.
    pub fn insert_capture(&self, r: &CaptureRequest) -> Result<i64, StoreError> {
        self.insert_queued(r, None)
    }

    /// Records capture request `r` as queued, with a live recording's
    /// provenance `live` (a JSON document) when it is one.
    fn insert_queued(&self, r: &CaptureRequest, live: Option<String>) -> Result<i64, StoreError> {
        self.with(|c| {
            c.execute(
                "INSERT INTO captures (id, scene, pose, channels, settings, frames, dark_frames, state, created_at, kind, dark_capture, live)
                 VALUES ((SELECT last + 1 FROM issued_ids WHERE kind = 'captures'), ?1, ?2, ?3, ?4, ?5, ?6, 'queued', ?7, ?8, ?9, ?10)",
                params![r.scene, r.pose, records::channels_document(&r.channels), SettingsDocument::of(&r.acquisition), r.frames as i64, r.dark_frames as i64, now(),
                    r.kind.name(), r.dark_capture, live],
            )?;
            Ok(c.last_insert_rowid())
        })
    }

    /// Records the capture a live session records into (state `queued`
    /// until its first frame; [`Store::capture_running`] starts it), with
    /// its provenance in `live`. Returns its id.
    pub fn insert_live_capture(
        &self,
        r: &CaptureRequest,
        live: &records::LiveInfo,
    ) -> Result<i64, StoreError> {
        // A struct of numbers and a name always serializes.
        self.insert_queued(r, serde_json::to_string(live).ok())
    }

    /// Marks a live session's recording done with the `frames` it holds
    /// (fewer than asked when the session ended early: `live.ended` says
    /// why), in one transaction; call only after its files are durable.
    pub fn live_capture_done(
        &self,
        id: i64,
        frames: usize,
        live: &records::LiveInfo,
        taken: (&str, &str, crate::camera::FrameCounts),
        clipping: crate::measure::Clipping,
    ) -> Result<(), StoreError> {
        let info = serde_json::to_string(live).unwrap_or_default();
        let (camera_id, counters, counts) = taken;
        self.with(|c| {
            let tx = c.unchecked_transaction()?;
            tx.execute(
                "UPDATE captures SET frames = ?2, frames_taken = ?2 + dark_frames, live = ?3 WHERE id = ?1",
                params![id, frames as i64, info],
            )?;
            done_statement(&tx, id, camera_id, counters, counts, clipping)?;
            tx.commit()
        })
    }

    /// Records an imported capture (state `running` while its files are
    /// written; [`Store::import_done`] ends it): no camera settings, one
    /// frame, its provenance in `import`. Returns its id.
    pub fn insert_import(
        &self,
        scene: &str,
        pose: &str,
        channels: &[crate::scene::Channel],
        import: &records::ImportInfo,
    ) -> Result<i64, StoreError> {
        let settings = SettingsDocument::none();
        // A struct of names and numbers always serializes.
        let import = serde_json::to_string(import).unwrap_or_default();
        self.with(|c| {
            c.execute(
                "INSERT INTO captures (id, scene, pose, channels, settings, frames, dark_frames, state, created_at, started_at, kind, import)
                 VALUES ((SELECT last + 1 FROM issued_ids WHERE kind = 'captures'), ?1, ?2, ?3, ?4, 1, 0, 'running', ?5, ?5, 'light', ?6)",
                params![scene, pose, records::channels_document(channels), settings, now(), import],
            )?;
            Ok(c.last_insert_rowid())
        })
    }

    /// Marks an imported capture done; call only after its files are durable.
    pub fn import_done(&self, id: i64) -> Result<(), StoreError> {
        self.with(|c| {
            c.execute(
                "UPDATE captures SET state = 'done', finished_at = ?2, frames_taken = 1, error = NULL WHERE id = ?1 AND state = 'running'",
                params![id, now()],
            )
            .map(|_| ())
        })
    }

    /// Marks a capture running.
    /// Returns false (and changes nothing) when it is no longer queued: a
    /// client cancelled it meanwhile.
    pub fn capture_running(&self, id: i64) -> Result<bool, StoreError> {
        self.with(|c| {
            c.execute(
                "UPDATE captures SET state = 'running', started_at = ?2 WHERE id = ?1 AND state = 'queued'",
                params![id, now()],
            )
            .map(|n| n == 1)
        })
    }

    /// Cancels a capture that is still queued; false when it is not queued.
    pub fn cancel_queued_capture(&self, id: i64) -> Result<bool, StoreError> {
        self.cancel(Table::Captures, id, true)
    }

    /// Records that a running capture stopped because it was cancelled.
    pub fn capture_cancelled(&self, id: i64) -> Result<bool, StoreError> {
        self.cancel(Table::Captures, id, false)
    }

    /// Records the polarizer angle the mount read back for a capture.
    pub fn capture_polarizer_measured(&self, id: i64, deg: f64) -> Result<(), StoreError> {
        self.with(|c| {
            c.execute(
                "UPDATE captures SET polarizer_measured_deg = ?2 WHERE id = ?1",
                params![id, deg],
            )
            .map(|_| ())
        })
    }

    /// Records progress (frames taken so far).
    pub fn capture_progress(&self, id: i64, frames_taken: usize) -> Result<(), StoreError> {
        self.with(|c| {
            c.execute(
                "UPDATE captures SET frames_taken = ?2 WHERE id = ?1",
                params![id, frames_taken as i64],
            )
            .map(|_| ())
        })
    }

    /// Marks a capture done; call only after its files are durable.
    pub fn capture_done(
        &self,
        id: i64,
        camera_id: &str,
        counters: &str,
        frames: crate::camera::FrameCounts,
        clipping: crate::measure::Clipping,
    ) -> Result<(), StoreError> {
        self.with(|c| done_statement(c, id, camera_id, counters, frames, clipping))
    }

    /// Marks a capture failed with a reason.
    pub fn capture_failed(&self, id: i64, error: &str) -> Result<(), StoreError> {
        self.with(|c| {
            c.execute(
                "UPDATE captures SET state = 'failed', finished_at = ?2, error = ?3 WHERE id = ?1",
                params![id, now(), error],
            )
            .map(|_| ())
        })
    }

    /// Adds to an interrupted or failed capture's reason that its plan took
    /// the step again (`retaken`: "plan 3 took this step again as capture 9").
    ///
    /// Why: "submit it again" on a capture its plan already retook sends the
    /// user after work that is done.
    pub fn capture_retaken(&self, id: i64, retaken: &str) -> Result<(), StoreError> {
        self.with(|c| {
            c.execute(
                "UPDATE captures SET error = COALESCE(error || '; ', '') || ?2 WHERE id = ?1 AND state IN ('interrupted', 'failed')",
                params![id, retaken],
            )
            .map(|_| ())
        })
    }

    /// One capture.
    pub fn capture(&self, id: i64) -> Result<CaptureRecord, StoreError> {
        self.with(|c| {
            c.query_row(
                &format!("{} WHERE id = ?1", records::CAPTURE_SELECT),
                [id],
                records::capture_row,
            )
            .optional()
        })?
        .ok_or(StoreError::NotFound {
            kind: "capture",
            id,
        })
    }

    /// Deletes capture `id`: its row (and, with `with_reconstructions`, the
    /// rows of the reconstructions that use it) in one transaction, then
    /// their folders. Refused while it (or one of those reconstructions) is
    /// queued or running, and while a kept reconstruction uses it. Returns
    /// the reconstructions deleted with it.
    ///
    /// Why in three steps (folders renamed to `<id>.deleting`, rows deleted,
    /// folders removed): a daemon stopped between any two leaves a state the
    /// next start completes or undoes by the row ([`Store::open`]); no row is
    /// ever left without its files.
    pub fn delete_capture(
        &self,
        id: i64,
        with_reconstructions: bool,
    ) -> Result<Vec<i64>, StoreError> {
        let users = self.deletable_capture(id, with_reconstructions)?;
        let mut folders: Vec<PathBuf> = users.iter().map(|r| self.reconstruction_dir(*r)).collect();
        folders.push(self.capture_dir(id));
        let parked = park(&folders);
        let deleted = self.with(|c| {
            let tx = c.unchecked_transaction()?;
            for r in &users {
                tx.execute("DELETE FROM reconstructions WHERE id = ?1", [r])?;
            }
            tx.execute("DELETE FROM captures WHERE id = ?1", [id])?;
            tx.commit()
        });
        finish(&parked, deleted.is_ok());
        deleted?;
        Ok(users)
    }

    /// The reconstructions that go with capture `id`, or why it may not be deleted.
    pub(super) fn deletable_capture(
        &self,
        id: i64,
        with_reconstructions: bool,
    ) -> Result<Vec<i64>, StoreError> {
        let in_use = |reason: String| StoreError::InUse {
            kind: "capture",
            id,
            reason,
        };
        self.with(|c| {
            let state: Option<String> = c
                .query_row("SELECT state FROM captures WHERE id = ?1", [id], |r| r.get(0))
                .optional()?;
            let Some(state) = state else {
                return Ok(Err(StoreError::NotFound { kind: "capture", id }));
            };
            if state == "queued" || state == "running" {
                return Ok(Err(in_use(format!("it is {state}; cancel it first (DELETE /jobs/capture-{id})"))));
            }
            // A queued capture subtracts this dark capture when it runs.
            let waiting: Option<(i64, String)> = c
                .query_row(
                    "SELECT id, state FROM captures WHERE dark_capture = ?1 AND state IN ('queued', 'running') ORDER BY id LIMIT 1",
                    [id],
                    |r| Ok((r.get(0)?, r.get(1)?)),
                )
                .optional()?;
            if let Some((user, st)) = waiting {
                return Ok(Err(in_use(format!("capture {user}, {st}, subtracts it as its dark_capture"))));
            }
            let mut users: Vec<(i64, String)> = c
                .prepare("SELECT r.id, r.state FROM reconstructions r, json_each(r.captures) j WHERE j.value = ?1 ORDER BY r.id")?
                .query_map([id], |r| Ok((r.get(0)?, r.get(1)?)))?
                .collect::<rusqlite::Result<_>>()?;
            users.dedup();
            if let Some((r, st)) = users.iter().find(|(_, st)| st == "queued" || st == "running") {
                return Ok(Err(in_use(format!("reconstruction {r} that uses it is {st}"))));
            }
            if !users.is_empty() && !with_reconstructions {
                let ids: Vec<String> = users.iter().map(|(r, _)| r.to_string()).collect();
                return Ok(Err(in_use(format!(
                    "reconstruction{} {} use{} it; delete {} first, or ask for ?with_reconstructions=true",
                    if ids.len() == 1 { "" } else { "s" },
                    ids.join(", "),
                    if ids.len() == 1 { "s" } else { "" },
                    if ids.len() == 1 { "it" } else { "them" },
                ))));
            }
            Ok(Ok(users.into_iter().map(|(r, _)| r).collect::<Vec<i64>>()))
        })?
    }

    /// Captures, newest first.
    pub fn captures(
        &self,
        limit: usize,
        offset: usize,
    ) -> Result<Listing<CaptureRecord>, StoreError> {
        self.page(
            records::CAPTURE_SELECT,
            records::capture_row,
            "capture",
            limit,
            offset,
        )
    }
}

/// The statement that marks capture `id` done with what its camera said.
fn done_statement(
    c: &rusqlite::Connection,
    id: i64,
    camera_id: &str,
    counters: &str,
    frames: crate::camera::FrameCounts,
    clipping: crate::measure::Clipping,
) -> rusqlite::Result<()> {
    let frames = serde_json::to_string(&frames).unwrap_or_default();
    let clipping = serde_json::to_string(&clipping).unwrap_or_default();
    c.execute(
        "UPDATE captures SET state = 'done', finished_at = ?2, camera_id = ?3, counters = ?4, frame_counts = ?5, clipping = ?6, error = NULL WHERE id = ?1",
        params![id, now(), camera_id, counters, frames, clipping],
    )
    .map(|_| ())
}
