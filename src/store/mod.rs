//! The durable catalogue of captures and reconstructions: SQLite (WAL,
//! synchronous FULL) for the rows, files under the data directory for the
//! images. A file is written to a temporary name, fsynced and renamed before
//! its row says it exists; a job that fails (a full disk, a lost camera) leaves
//! every earlier row and file as it was. On open, jobs that were queued or
//! running when the daemon stopped are marked `interrupted`.

mod calibrations;
mod captures;
mod files;
mod lock;
mod plans;
mod reconstructions;
mod records;
mod retention;
mod scene_fits;
mod schema;
mod truth;

use std::path::{Path, PathBuf};
use std::sync::Mutex;

use rusqlite::{params, Connection};

pub(crate) use calibrations::ColourCalibrationRow;
pub(crate) use files::FrameMeta;
pub(crate) use files::{
    capture_bytes, read_imported, read_mean_in_range, read_mean_variance, remove_raw,
    write_frames_upto, write_summary, CaptureFiles, TMP_MARK,
};
pub use files::{read_mean, write_frames};
pub(crate) use lock::{remove_orphans, DirLock};
pub(crate) use plans::{PlanCapture, PlanInterim, PlanRow, PlanState};
pub use records::ReconstructionParams;
pub(crate) use records::{
    CaptureKind, CaptureRecord, CaptureRequest, ImportInfo, JobState, LiveInfo,
    ReconstructionRecord, ReconstructionRequest,
};
pub(crate) use retention::Retention;
pub(crate) use scene_fits::SceneFitRow;
pub use schema::Table;
pub use truth::{Pixel, Truth, TruthImage};

/// What can go wrong with the store, naming the path or the row.
#[derive(Debug, thiserror::Error)]
pub enum StoreError {
    /// The database could not be opened or used.
    #[error("catalogue {path}: {source}")]
    Database {
        /// Database file.
        path: PathBuf,
        /// SQLite's error.
        source: rusqlite::Error,
    },
    /// A file could not be written or read (full disk, read-only folder, ...).
    #[error(transparent)]
    File(#[from] crate::files::FileError),
    /// The catalogue's schema cannot be used by this polnlos.
    #[error("catalogue {path}: {reason}")]
    Schema {
        /// Database file.
        path: PathBuf,
        /// Why, and what to do.
        reason: String,
    },
    /// The data directory cannot be created or written.
    #[error("data directory {path}: {source}; check that it exists, is writable by the polnlos user and has free space")]
    DataDir {
        /// The directory.
        path: PathBuf,
        /// Underlying error.
        source: std::io::Error,
    },
    /// A frame stream ended before all its frames were written.
    #[error("{path}: only {got} of {wanted} frames arrived; nothing was kept")]
    Incomplete {
        /// The file that was being written.
        path: PathBuf,
        /// Frames written.
        got: usize,
        /// Frames expected.
        wanted: usize,
    },
    /// Another process holds the data directory.
    #[error("data directory {dir} is in use by another polnlos (pid {}); stop it, or give this one another --data-dir", holder.map_or_else(|| "unknown".to_string(), |p| p.to_string()))]
    Locked {
        /// The data directory.
        dir: PathBuf,
        /// The lock holder's PID, as it wrote it.
        holder: Option<u32>,
    },
    /// A row that may not be deleted now (HTTP 409): still queued or
    /// running, or used by reconstructions that are kept.
    #[error("{kind} {id} cannot be deleted: {reason}")]
    InUse {
        /// `capture` or `reconstruction`.
        kind: &'static str,
        /// Its id.
        id: i64,
        /// Why, naming what uses it.
        reason: String,
    },
    /// No such row.
    #[error("no {kind} with id {id}")]
    NotFound {
        /// `capture` or `reconstruction`.
        kind: &'static str,
        /// The id asked for.
        id: i64,
    },
}

/// Suffix of a folder whose row is being deleted.
const DELETING: &str = ".deleting";

/// Renames each existing folder to `<name>.deleting`; returns (parked, original).
fn park(folders: &[PathBuf]) -> Vec<(PathBuf, PathBuf)> {
    folders
        .iter()
        .filter_map(|f| {
            let parked =
                f.with_file_name(format!("{}{DELETING}", f.file_name()?.to_string_lossy()));
            std::fs::rename(f, &parked)
                .ok()
                .map(|()| (parked, f.clone()))
        })
        .collect()
}

/// Removes the parked folders once their rows are gone, or puts them back.
fn finish(parked: &[(PathBuf, PathBuf)], deleted: bool) {
    for (p, original) in parked {
        if deleted {
            remove_folder(p);
        } else if let Err(e) = std::fs::rename(p, original) {
            tracing::error!("cannot put {} back ({e}); the next start does", p.display());
        }
    }
}

/// Removes a job's folder; a failure is logged (the row is already gone,
/// and the next start removes the folder).
fn remove_folder(path: &Path) {
    if let Err(e) = std::fs::remove_dir_all(path) {
        if e.kind() != std::io::ErrorKind::NotFound {
            tracing::warn!(
                "cannot remove {} ({e}); the next start removes it",
                path.display()
            );
        }
    }
}

/// The catalogue and its data directory.
pub struct Store {
    dir: PathBuf,
    db_path: PathBuf,
    ballast: PathBuf,
    conn: Mutex<Connection>,
    _lock: DirLock,
}

/// A file of zeros kept in the data directory and given up when the disk is
/// full, so that the catalogue can still record that jobs failed.
const BALLAST_FILE: &str = "catalogue.reserve";
const BALLAST_BYTES: u64 = 4 << 20;

fn lay_ballast(path: &Path) -> std::io::Result<()> {
    if std::fs::metadata(path).is_ok_and(|m| m.len() == BALLAST_BYTES) {
        return Ok(());
    }
    let result = (|| {
        use std::io::Write;
        let mut f = std::fs::File::create(path)?;
        let zeros = vec![0u8; 1 << 20];
        for _ in 0..(BALLAST_BYTES >> 20) {
            f.write_all(&zeros)?;
        }
        f.sync_all()
    })();
    if result.is_err() {
        let _ = std::fs::remove_file(path);
    }
    result
}

fn is_disk_full<T>(r: &rusqlite::Result<T>) -> bool {
    matches!(r, Err(rusqlite::Error::SqliteFailure(e, _)) if e.code == rusqlite::ErrorCode::DiskFull)
}

/// Current UTC time, RFC 3339.
pub fn now() -> String {
    timestamp(std::time::SystemTime::now())
}

/// A time as the catalogue stores it: UTC, RFC 3339 with milliseconds, so
/// that stored times compare as strings.
pub(crate) fn timestamp(t: std::time::SystemTime) -> String {
    let d = t.duration_since(std::time::UNIX_EPOCH).unwrap_or_default();
    let secs = d.as_secs() as i64;
    let (days, rem) = (secs.div_euclid(86_400), secs.rem_euclid(86_400));
    // Civil date from days since 1970-01-01 (Howard Hinnant's algorithm).
    let z = days + 719_468;
    let era = z.div_euclid(146_097);
    let doe = z.rem_euclid(146_097);
    let yoe = (doe - doe / 1460 + doe / 36_524 - doe / 146_096) / 365;
    let doy = doe - (365 * yoe + yoe / 4 - yoe / 100);
    let mp = (5 * doy + 2) / 153;
    let day = doy - (153 * mp + 2) / 5 + 1;
    let month = if mp < 10 { mp + 3 } else { mp - 9 };
    let year = yoe + era * 400 + i64::from(month <= 2);
    format!(
        "{year:04}-{month:02}-{day:02}T{:02}:{:02}:{:02}.{:03}Z",
        rem / 3600,
        rem % 3600 / 60,
        rem % 60,
        d.subsec_millis()
    )
}

/// Why a job is `interrupted`.
const INTERRUPTED: &str = "the daemon stopped before this job finished; submit it again";

impl Store {
    /// Opens (creating if needed) the catalogue under `dir`: takes the data
    /// directory's lock first (a second daemon is refused before it touches
    /// anything), removes temporaries a killed run left, marks captures left
    /// queued or running by a previous run interrupted (their frames are
    /// gone), and puts reconstructions left so back in the queue
    /// ([`Store::queued_reconstructions`]: their inputs are stored).
    pub fn open(dir: &Path) -> Result<Self, StoreError> {
        std::fs::create_dir_all(dir).map_err(|source| StoreError::DataDir {
            path: dir.to_path_buf(),
            source,
        })?;
        let lock = DirLock::acquire(dir)?;
        for sub in Table::ALL.map(Table::name) {
            std::fs::create_dir_all(dir.join(sub)).map_err(|source| StoreError::DataDir {
                path: dir.join(sub),
                source,
            })?;
        }
        for p in remove_orphans(dir) {
            tracing::info!(
                "removed {}, left by a run that was stopped mid-write",
                p.display()
            );
        }
        let ballast = dir.join(BALLAST_FILE);
        if let Err(e) = lay_ballast(&ballast) {
            tracing::warn!("cannot reserve {} MiB for the catalogue ({e}); on a full disk job states may not be recorded", BALLAST_BYTES >> 20);
        }
        let db_path = dir.join("catalogue.sqlite");
        let db = |source| StoreError::Database {
            path: db_path.clone(),
            source,
        };
        let conn = Connection::open(&db_path).map_err(db)?;
        conn.pragma_update(None, "journal_mode", "WAL")
            .map_err(db)?;
        conn.pragma_update(None, "synchronous", "FULL")
            .map_err(db)?;
        conn.busy_timeout(std::time::Duration::from_secs(5))
            .map_err(db)?;
        schema::migrate(&conn).map_err(|e| match e {
            schema::MigrateError::Sql(source) => db(source),
            newer => StoreError::Schema {
                path: db_path.clone(),
                reason: newer.to_string(),
            },
        })?;
        conn.execute(Table::Captures.interrupt_all(), params![INTERRUPTED, now()])
            .map_err(db)?;
        conn.execute(Table::REQUEUE_RECONSTRUCTIONS, [])
            .map_err(db)?;
        Self::interrupt_scene_fits(&conn).map_err(db)?;
        // A deletion a stopped daemon left half done: a folder renamed to
        // `<id>.deleting` is removed when its row is gone, renamed back when
        // the row's deletion never committed.
        for table in Table::ALL {
            let sub = table.name();
            let Ok(entries) = std::fs::read_dir(dir.join(sub)) else {
                continue;
            };
            for e in entries.flatten() {
                let name = e.file_name().to_string_lossy().into_owned();
                let Some(id) = name
                    .strip_suffix(DELETING)
                    .and_then(|n| n.parse::<i64>().ok())
                else {
                    continue;
                };
                let kept: bool = conn
                    .query_row(table.count_id(), [id], |r| {
                        r.get::<_, i64>(0).map(|n| n > 0)
                    })
                    .map_err(db)?;
                if kept {
                    let _ = std::fs::rename(e.path(), dir.join(sub).join(id.to_string()));
                } else {
                    remove_folder(&e.path());
                }
            }
        }
        // Captures that did not finish keep no raw frames (a run killed
        // mid-capture, or one that could not remove them when cancelled).
        let unfinished: Vec<i64> = conn
            .prepare("SELECT id FROM captures WHERE state IN ('interrupted', 'cancelled')")
            .and_then(|mut st| {
                st.query_map([], |r| r.get(0))?
                    .collect::<Result<Vec<i64>, _>>()
            })
            .map_err(db)?;
        for id in unfinished {
            for p in files::remove_raw(&dir.join("captures").join(id.to_string())) {
                tracing::info!("removed {}: capture {id} did not finish", p.display());
            }
        }
        Ok(Self {
            dir: dir.to_path_buf(),
            db_path,
            ballast,
            conn: Mutex::new(conn),
            _lock: lock,
        })
    }

    /// The data directory.
    pub fn dir(&self) -> &Path {
        &self.dir
    }

    /// An error as a job or an HTTP client should read it: paths inside the
    /// data directory relative to it, never absolute.
    pub fn describe(&self, e: &StoreError) -> String {
        self.redact_paths(&e.to_string())
    }

    /// An I/O error on `path` (inside the data directory), described as [`Store::describe`] does.
    pub fn describe_io(&self, path: &Path, e: &std::io::Error) -> String {
        self.redact_paths(&format!("{}: {e}", path.display()))
    }

    /// `text` with the data directory's path taken out of the paths in it.
    pub fn redact_paths(&self, text: &str) -> String {
        let base = self.dir.display().to_string();
        let abs = std::fs::canonicalize(&self.dir)
            .map(|p| p.display().to_string())
            .unwrap_or_default();
        let mut out = text.to_string();
        for prefix in [abs, base] {
            if !prefix.is_empty() {
                out = out
                    .replace(&format!("{prefix}/"), "")
                    .replace(&prefix, "data directory");
            }
        }
        out
    }

    /// Folder of capture `id`.
    pub fn capture_dir(&self, id: i64) -> PathBuf {
        self.dir.join("captures").join(id.to_string())
    }

    /// Folder of reconstruction `id`.
    pub fn reconstruction_dir(&self, id: i64) -> PathBuf {
        self.dir.join("reconstructions").join(id.to_string())
    }

    fn with<T>(&self, f: impl Fn(&Connection) -> rusqlite::Result<T>) -> Result<T, StoreError> {
        let conn = self.conn.lock().unwrap_or_else(|e| e.into_inner());
        let mut result = f(&conn);
        // A full disk: give up the ballast so that job states can still be recorded.
        if is_disk_full(&result) && std::fs::remove_file(&self.ballast).is_ok() {
            tracing::warn!(
                "the data directory's disk is full: released the catalogue's {} MiB reserve to record job states; free space and restart to lay it again",
                BALLAST_BYTES >> 20
            );
            result = f(&conn);
        }
        result.map_err(|source| StoreError::Database {
            path: self.db_path.clone(),
            source,
        })
    }

    /// Marks a queued (`only_queued`) or a queued or running job of
    /// `table` cancelled; false when it had already ended (done, failed,
    /// interrupted or cancelled), or was running and `only_queued`.
    fn cancel(&self, table: Table, id: i64, only_queued: bool) -> Result<bool, StoreError> {
        self.with(|c| {
            c.execute(table.cancel(only_queued), params![id, now()])
                .map(|n| n == 1)
        })
    }

    /// Records that a running job of `table` stopped because the daemon is stopping.
    pub fn interrupted(&self, table: Table, id: i64) -> Result<(), StoreError> {
        self.with(|c| {
            c.execute(table.interrupt_one(), params![id, INTERRUPTED, now()])
                .map(|_| ())
        })
    }

    /// One page of `select`'s rows, newest first, decoded row by row: a row
    /// that does not decode (a column of the wrong type, written by
    /// something else) is logged with its id and listed in
    /// [`Listing::unreadable`], so one damaged row does not hide the whole
    /// catalogue. A failing query is still an error.
    fn page<T>(
        &self,
        select: &str,
        row: fn(&rusqlite::Row<'_>) -> rusqlite::Result<T>,
        kind: &str,
        limit: usize,
        offset: usize,
    ) -> Result<Listing<T>, StoreError> {
        self.with(|c| {
            let mut st = c.prepare(&format!("{select} ORDER BY id DESC LIMIT ?1 OFFSET ?2"))?;
            let rows = st.query_map(params![limit as i64, offset as i64], |r| {
                Ok((r.get::<_, i64>(0)?, row(r)))
            })?;
            let mut out = Listing {
                records: Vec::new(),
                unreadable: Vec::new(),
            };
            for decoded in rows {
                match decoded? {
                    (_, Ok(v)) => out.records.push(v),
                    (id, Err(e)) => {
                        tracing::error!(
                            "catalogue: {kind} {id} cannot be read ({e}); left out of the list"
                        );
                        out.unreadable.push(id);
                    }
                }
            }
            Ok(out)
        })
    }
}

/// One page of a list: the rows that could be read, and the ids of those
/// that could not.
///
/// A damaged row is reported, not silently dropped, so that a user who
/// misses a capture learns it is still in the catalogue.
#[derive(Debug, Clone, PartialEq)]
pub struct Listing<T> {
    /// The rows that decode, in the list's order.
    pub records: Vec<T>,
    /// Ids of the rows of this page that do not decode.
    pub unreadable: Vec<i64>,
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn an_id_is_never_issued_twice_across_deletion_and_restart() {
        let dir = tempfile::tempdir().unwrap();
        let request = CaptureRequest::example();
        let rec = |captures: Vec<i64>| ReconstructionRequest {
            scene: "brewster-crossed".into(),
            captures,
            params: ReconstructionParams::default(),
        };
        let (a, b, r) = {
            let store = Store::open(dir.path()).unwrap();
            let a = store.insert_capture(&request).unwrap();
            let b = store.insert_capture(&request).unwrap();
            let r = store.insert_reconstruction(&rec(vec![a])).unwrap();
            store.capture_failed(b, "test").unwrap();
            store.reconstruction_failed(r, "test").unwrap();
            // The newest of each deleted: INTEGER PRIMARY KEY alone would issue them again.
            assert_eq!(store.delete_capture(b, false).unwrap(), Vec::<i64>::new());
            store.delete_reconstruction(r).unwrap();
            assert_eq!(store.insert_capture(&request).unwrap(), b + 1);
            assert_eq!(store.insert_reconstruction(&rec(vec![a])).unwrap(), r + 1);
            (a, b, r)
        };
        // Reopened (a daemon restart), after the newest are deleted again.
        let store = Store::open(dir.path()).unwrap();
        store.capture_failed(b + 1, "test").unwrap();
        store.delete_capture(b + 1, true).unwrap();
        assert_eq!(store.insert_capture(&request).unwrap(), b + 2);
        assert_eq!(store.insert_reconstruction(&rec(vec![a])).unwrap(), r + 2);
    }

    #[test]
    fn a_catalogue_from_before_issued_ids_starts_after_its_largest_id() {
        let dir = tempfile::tempdir().unwrap();
        {
            let store = Store::open(dir.path()).unwrap();
            for _ in 0..3 {
                store.insert_capture(&CaptureRequest::example()).unwrap();
            }
        }
        // As an older polnlos left it: no sequence table, no triggers, the
        // solver in its own column.
        let raw = Connection::open(dir.path().join("catalogue.sqlite")).unwrap();
        raw.execute_batch(
            "DROP TRIGGER captures_issue_id; DROP TRIGGER reconstructions_issue_id; DROP TABLE issued_ids; ALTER TABLE reconstructions ADD COLUMN solver TEXT NOT NULL DEFAULT 'admm-tv'; PRAGMA user_version = 0;",
        )
        .unwrap();
        drop(raw);
        let store = Store::open(dir.path()).unwrap();
        assert_eq!(store.insert_capture(&CaptureRequest::example()).unwrap(), 4);
    }

    #[test]
    fn a_row_that_cannot_be_read_is_named_not_hidden() {
        let dir = tempfile::tempdir().unwrap();
        let store = Store::open(dir.path()).unwrap();
        let request = ReconstructionRequest {
            scene: "brewster-crossed".into(),
            captures: vec![1],
            params: ReconstructionParams::default(),
        };
        let ids: Vec<i64> = (0..6)
            .map(|_| store.insert_reconstruction(&request).unwrap())
            .collect();
        let raw = Connection::open(dir.path().join("catalogue.sqlite")).unwrap();
        for (sql, id) in [
            (
                "UPDATE reconstructions SET scene = X'FF' WHERE id = ?1",
                ids[1],
            ),
            (
                "UPDATE reconstructions SET state = 'finished' WHERE id = ?1",
                ids[2],
            ),
            (
                "UPDATE reconstructions SET report = '{\"psnr\": 1' WHERE id = ?1",
                ids[3],
            ),
            (
                "UPDATE reconstructions SET params = '{\"lambda\": \"much\"}' WHERE id = ?1",
                ids[4],
            ),
            (
                "UPDATE reconstructions SET params = '{\"version\": 2}' WHERE id = ?1",
                ids[5],
            ),
        ] {
            raw.execute(sql, [id]).unwrap();
        }
        let page = store.reconstructions(10, 0).unwrap();
        let listed: Vec<i64> = page.records.iter().map(|r| r.id).collect();
        assert_eq!(listed, [ids[0]]);
        assert_eq!(page.unreadable, [ids[5], ids[4], ids[3], ids[2], ids[1]]);
        // A page that does not reach a damaged row does not name it.
        let last = store.reconstructions(1, 5).unwrap();
        assert!(last.unreadable.is_empty());
        assert_eq!(last.records[0].state, JobState::Queued);
        // One by one, each damaged row is an error naming what is wrong.
        let e = store.reconstruction(ids[2]).unwrap_err().to_string();
        assert!(e.contains("unknown job state \"finished\""), "{e}");
        let e = store.reconstruction(ids[3]).unwrap_err().to_string();
        assert!(e.contains("EOF while parsing"), "{e}");
        // A damaged λ is an error naming the row, never the automatic λ.
        let e = store.reconstruction(ids[4]).unwrap_err().to_string();
        assert!(e.contains("invalid type: string \"much\""), "{e}");
        let e = store.reconstruction(ids[5]).unwrap_err().to_string();
        assert!(e.contains("parameters document version 2"), "{e}");
        // Parameters as an older polnlos stored them (no version) read back.
        raw.execute(
            "UPDATE reconstructions SET params = '{\"lambda\": 0.5, \"truth\": \"disk\"}' WHERE id = ?1",
            [ids[0]],
        )
        .unwrap();
        let old = store.reconstruction(ids[0]).unwrap().params;
        assert_eq!((old.version, old.solve.lambda), (1, Some(0.5)));
        assert_eq!(old.truth.as_ref().and_then(|t| t.pattern()), Some("disk"));
    }

    #[test]
    fn stored_capture_settings_read_back_typed_or_not_at_all() {
        use crate::camera::{PixelFormat, TriggerMode};
        let dir = tempfile::tempdir().unwrap();
        let store = Store::open(dir.path()).unwrap();
        let example = CaptureRequest::example();
        // Before, these read back as Mono16, light and version 1.
        let request = CaptureRequest {
            kind: CaptureKind::Dark,
            acquisition: crate::camera::Acquisition {
                pixel_format: PixelFormat::Mono8,
                trigger: TriggerMode::Software,
                ..example.acquisition
            },
            ..example
        };
        let ids: Vec<i64> = (0..4)
            .map(|_| store.insert_capture(&request).unwrap())
            .collect();
        let back = store.capture(ids[0]).unwrap();
        assert_eq!(back.kind, CaptureKind::Dark);
        assert_eq!(
            crate::camera::Acquisition::try_from(&back).unwrap(),
            request.acquisition
        );
        let raw = Connection::open(dir.path().join("catalogue.sqlite")).unwrap();
        for (sql, id) in [
            (
                "UPDATE captures SET settings = json_set(settings, '$.pixel_format', 'Mono10') WHERE id = ?1",
                ids[1],
            ),
            ("UPDATE captures SET kind = 'flat' WHERE id = ?1", ids[2]),
            (
                "UPDATE captures SET settings = json_set(settings, '$.version', 2) WHERE id = ?1",
                ids[3],
            ),
        ] {
            raw.execute(sql, [id]).unwrap();
        }
        for (id, what) in [
            (ids[1], "unknown variant `Mono10`"),
            (ids[2], "unknown capture kind \"flat\""),
            (ids[3], "settings document version 2"),
        ] {
            let e = store.capture(id).unwrap_err().to_string();
            assert!(e.contains(what), "{e}");
        }
        let page = store.captures(10, 0).unwrap();
        assert_eq!(page.records.len(), 1);
        assert_eq!(page.unreadable.len(), 3);
    }

    #[test]
    fn timestamps_are_rfc3339() {
        let t = now();
        assert_eq!(t.len(), 24, "{t}");
        assert!(t.starts_with("20") && t.ends_with('Z') && &t[10..11] == "T");
    }
}
