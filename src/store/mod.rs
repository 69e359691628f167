//! The durable catalogue of captures and reconstructions: SQLite (WAL,
//! synchronous FULL) for the rows, files under the data directory for the
//! images. A file is written to a temporary name, fsynced and renamed before
//! its row says it exists; a job that fails (a full disk, a lost camera) leaves
//! every earlier row and file as it was. On open, jobs that were queued or
//! running when the daemon stopped are marked `interrupted`.

mod files;
mod lock;
mod records;
mod retention;

use std::path::{Path, PathBuf};
use std::sync::Mutex;

use rusqlite::{params, Connection, OptionalExtension};

pub use files::{
    capture_bytes, read_mean, read_mean_variance, remove_raw, write_frames, write_summary,
    CaptureFiles, FrameMeta, TMP_MARK,
};
pub use lock::{remove_orphans, DirLock, LOCK_FILE};
pub use records::{
    CaptureKind, CaptureRecord, CaptureRequest, JobState, ReconstructionRecord,
    ReconstructionRequest,
};
pub use retention::{dir_bytes, Retention};

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

const SCHEMA: &str = "
CREATE TABLE IF NOT EXISTS captures (
    id INTEGER PRIMARY KEY,
    scene TEXT NOT NULL,
    pose TEXT NOT NULL,
    polarizer_deg REAL,
    exposure_us REAL NOT NULL,
    gain REAL NOT NULL,
    frames INTEGER NOT NULL,
    dark_frames INTEGER NOT NULL,
    pixel_format TEXT NOT NULL,
    state TEXT NOT NULL,
    error TEXT,
    created_at TEXT NOT NULL,
    started_at TEXT,
    finished_at TEXT,
    camera_id TEXT,
    counters TEXT,
    frames_taken INTEGER NOT NULL DEFAULT 0
);
CREATE TABLE IF NOT EXISTS reconstructions (
    id INTEGER PRIMARY KEY,
    scene TEXT NOT NULL,
    captures TEXT NOT NULL,
    solver TEXT NOT NULL,
    params TEXT NOT NULL,
    state TEXT NOT NULL,
    error TEXT,
    created_at TEXT NOT NULL,
    started_at TEXT,
    finished_at TEXT,
    kappa TEXT,
    report TEXT
);
CREATE TABLE IF NOT EXISTS issued_ids (
    kind TEXT PRIMARY KEY,
    last INTEGER NOT NULL
);
";

/// Ids are never issued twice in one data directory's life (a deleted or
/// retired capture's id would otherwise come back: `INTEGER PRIMARY KEY`
/// reuses the largest id once its row is gone, and lab notes and downloaded
/// files named by id would become ambiguous). The highest id issued per table
/// is kept in `issued_ids`, raised by a trigger on every insert, and a new
/// row takes the next one. A catalogue from before starts from its largest id.
const ID_SEQUENCES: &str = "
INSERT OR IGNORE INTO issued_ids (kind, last) SELECT 'captures', COALESCE(MAX(id), 0) FROM captures;
INSERT OR IGNORE INTO issued_ids (kind, last) SELECT 'reconstructions', COALESCE(MAX(id), 0) FROM reconstructions;
CREATE TRIGGER IF NOT EXISTS captures_issue_id AFTER INSERT ON captures BEGIN
    UPDATE issued_ids SET last = MAX(last, NEW.id) WHERE kind = 'captures';
END;
CREATE TRIGGER IF NOT EXISTS reconstructions_issue_id AFTER INSERT ON reconstructions BEGIN
    UPDATE issued_ids SET last = MAX(last, NEW.id) WHERE kind = 'reconstructions';
END;
";

/// Columns added after the first release: (table, column, declaration).
const ADDED_COLUMNS: [(&str, &str, &str); 6] = [
    ("captures", "kind", "TEXT NOT NULL DEFAULT 'light'"),
    ("captures", "region", "TEXT"),
    ("captures", "binning", "TEXT"),
    ("captures", "trigger", "TEXT"),
    ("captures", "dark_capture", "INTEGER"),
    ("captures", "frame_counts", "TEXT"),
];

/// Adds the columns a catalogue from an older polnlos lacks (rows kept).
fn migrate(conn: &Connection) -> rusqlite::Result<()> {
    for (table, column, decl) in ADDED_COLUMNS {
        let mut st = conn.prepare(&format!("PRAGMA table_info({table})"))?;
        let has = st
            .query_map([], |r| r.get::<_, String>(1))?
            .collect::<rusqlite::Result<Vec<_>>>()?
            .iter()
            .any(|c| c == column);
        if !has {
            conn.execute_batch(&format!("ALTER TABLE {table} ADD COLUMN {column} {decl}"))?;
        }
    }
    conn.execute_batch(ID_SEQUENCES)
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
pub fn timestamp(t: std::time::SystemTime) -> String {
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
    /// anything), removes temporaries a killed run left, and marks jobs left
    /// queued or running by a previous run as interrupted.
    pub fn open(dir: &Path) -> Result<Self, StoreError> {
        std::fs::create_dir_all(dir).map_err(|source| StoreError::DataDir {
            path: dir.to_path_buf(),
            source,
        })?;
        let lock = DirLock::acquire(dir)?;
        for sub in ["captures", "reconstructions"] {
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
        conn.execute_batch(SCHEMA).map_err(db)?;
        migrate(&conn).map_err(db)?;
        for table in ["captures", "reconstructions"] {
            conn.execute(
                &format!("UPDATE {table} SET state = 'interrupted', error = ?1, finished_at = ?2 WHERE state IN ('queued', 'running')"),
                params![INTERRUPTED, now()],
            )
            .map_err(db)?;
        }
        // A deletion a stopped daemon left half done: a folder renamed to
        // `<id>.deleting` is removed when its row is gone, renamed back when
        // the row's deletion never committed.
        for (table, sub) in [
            ("captures", "captures"),
            ("reconstructions", "reconstructions"),
        ] {
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
                    .query_row(
                        &format!("SELECT COUNT(*) FROM {table} WHERE id = ?1"),
                        [id],
                        |r| r.get::<_, i64>(0).map(|n| n > 0),
                    )
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

    /// Records a new capture job (state `queued`); returns its id.
    pub fn insert_capture(&self, r: &CaptureRequest) -> Result<i64, StoreError> {
        let a = &r.acquisition;
        self.with(|c| {
            c.execute(
                "INSERT INTO captures (id, scene, pose, polarizer_deg, exposure_us, gain, frames, dark_frames, pixel_format, state, created_at, kind, region, binning, trigger, dark_capture)
                 VALUES ((SELECT last + 1 FROM issued_ids WHERE kind = 'captures'), ?1, ?2, ?3, ?4, ?5, ?6, ?7, ?8, 'queued', ?9, ?10, ?11, ?12, ?13, ?14)",
                params![r.scene, r.pose, r.polarizer_deg, a.exposure_us, a.gain, r.frames as i64, r.dark_frames as i64, a.pixel_format.name(), now(),
                    r.kind.name(), serde_json::to_string(&a.region).unwrap_or_default(), serde_json::to_string(&a.binning).unwrap_or_default(), a.trigger.name(), r.dark_capture],
            )?;
            Ok(c.last_insert_rowid())
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

    /// Marks a queued or running job cancelled; false when it had already
    /// ended (done, failed, interrupted or cancelled). `table` is
    /// `captures` or `reconstructions`.
    fn cancel(&self, table: &str, id: i64, only_queued: bool) -> Result<bool, StoreError> {
        let states = if only_queued {
            "('queued')"
        } else {
            "('queued', 'running')"
        };
        self.with(|c| {
            c.execute(
                &format!("UPDATE {table} SET state = 'cancelled', finished_at = ?2 WHERE id = ?1 AND state IN {states}"),
                params![id, now()],
            )
            .map(|n| n == 1)
        })
    }

    /// Cancels a capture that is still queued; false when it is not queued.
    pub fn cancel_queued_capture(&self, id: i64) -> Result<bool, StoreError> {
        self.cancel("captures", id, true)
    }

    /// Records that a running capture stopped because it was cancelled.
    pub fn capture_cancelled(&self, id: i64) -> Result<bool, StoreError> {
        self.cancel("captures", id, false)
    }

    /// Cancels a reconstruction that is still queued; false when it is not queued.
    pub fn cancel_queued_reconstruction(&self, id: i64) -> Result<bool, StoreError> {
        self.cancel("reconstructions", id, true)
    }

    /// Records that a running job of `table` (`captures` or
    /// `reconstructions`) stopped because the daemon is stopping.
    pub fn interrupted(&self, table: &'static str, id: i64) -> Result<(), StoreError> {
        self.with(|c| {
            c.execute(
                &format!("UPDATE {table} SET state = 'interrupted', error = ?2, finished_at = ?3 WHERE id = ?1 AND state = 'running'"),
                params![id, INTERRUPTED, now()],
            )
            .map(|_| ())
        })
    }

    /// Records that a running reconstruction stopped because it was cancelled.
    pub fn reconstruction_cancelled(&self, id: i64) -> Result<bool, StoreError> {
        self.cancel("reconstructions", id, false)
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
    ) -> Result<(), StoreError> {
        let frames = serde_json::to_string(&frames).unwrap_or_default();
        self.with(|c| {
            c.execute(
                "UPDATE captures SET state = 'done', finished_at = ?2, camera_id = ?3, counters = ?4, frame_counts = ?5, error = NULL WHERE id = ?1",
                params![id, now(), camera_id, counters, frames],
            )
            .map(|_| ())
        })
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

    /// The capture running now, if any.
    pub fn running_capture(&self) -> Result<Option<i64>, StoreError> {
        self.with(|c| {
            c.query_row(
                "SELECT id FROM captures WHERE state = 'running' ORDER BY id DESC LIMIT 1",
                [],
                |r| r.get(0),
            )
            .optional()
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
    fn deletable_capture(
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

    /// Records a new reconstruction job (state `queued`).
    pub fn insert_reconstruction(&self, r: &ReconstructionRequest) -> Result<i64, StoreError> {
        let captures = serde_json::to_string(&r.captures).unwrap_or_else(|_| "[]".into());
        let params_json = serde_json::to_string(&r.params).unwrap_or_else(|_| "{}".into());
        self.with(|c| {
            c.execute(
                "INSERT INTO reconstructions (id, scene, captures, solver, params, state, created_at) VALUES ((SELECT last + 1 FROM issued_ids WHERE kind = 'reconstructions'), ?1, ?2, ?3, ?4, 'queued', ?5)",
                params![r.scene, captures, r.solver, params_json, now()],
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
            solver: "admm-tv".into(),
            params: serde_json::json!({}),
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
        // As an older polnlos left it: no sequence table, no triggers.
        let raw = Connection::open(dir.path().join("catalogue.sqlite")).unwrap();
        raw.execute_batch(
            "DROP TRIGGER captures_issue_id; DROP TRIGGER reconstructions_issue_id; DROP TABLE issued_ids;",
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
            solver: "admm-tv".into(),
            params: serde_json::json!({}),
        };
        let ids: Vec<i64> = (0..4)
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
        ] {
            raw.execute(sql, [id]).unwrap();
        }
        let page = store.reconstructions(10, 0).unwrap();
        let listed: Vec<i64> = page.records.iter().map(|r| r.id).collect();
        assert_eq!(listed, [ids[0]]);
        assert_eq!(page.unreadable, [ids[3], ids[2], ids[1]]);
        // A page that does not reach a damaged row does not name it.
        let last = store.reconstructions(1, 3).unwrap();
        assert!(last.unreadable.is_empty());
        assert_eq!(last.records[0].state, JobState::Queued);
        // One by one, each damaged row is an error naming what is wrong.
        let e = store.reconstruction(ids[2]).unwrap_err().to_string();
        assert!(e.contains("unknown job state \"finished\""), "{e}");
        let e = store.reconstruction(ids[3]).unwrap_err().to_string();
        assert!(e.contains("EOF while parsing"), "{e}");
    }

    #[test]
    fn stored_capture_settings_read_back_typed_or_not_at_all() {
        use crate::camera::{PixelFormat, TriggerMode};
        let dir = tempfile::tempdir().unwrap();
        let store = Store::open(dir.path()).unwrap();
        let example = CaptureRequest::example();
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
        assert_eq!(
            (back.kind, back.pixel_format, back.trigger),
            (
                CaptureKind::Dark,
                PixelFormat::Mono8,
                Some(TriggerMode::Software)
            )
        );
        let raw = Connection::open(dir.path().join("catalogue.sqlite")).unwrap();
        for (sql, id) in [
            (
                "UPDATE captures SET pixel_format = 'Mono10' WHERE id = ?1",
                ids[1],
            ),
            ("UPDATE captures SET kind = 'flat' WHERE id = ?1", ids[2]),
            (
                "UPDATE captures SET trigger = 'hardware' WHERE id = ?1",
                ids[3],
            ),
        ] {
            raw.execute(sql, [id]).unwrap();
        }
        // Before, these read back as Mono16, light and free.
        for (id, what) in [
            (ids[1], "unknown pixel format \"Mono10\""),
            (ids[2], "unknown capture kind \"flat\""),
            (ids[3], "unknown trigger mode \"hardware\""),
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
