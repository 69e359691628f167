//! The catalogue's schema: its tables, the columns later releases added
//! (and the migration that adds them to an older catalogue), the id
//! sequences, and the statements that work on either job table.

use rusqlite::Connection;

const SCHEMA: &str = "
CREATE TABLE IF NOT EXISTS captures (
    id INTEGER PRIMARY KEY,
    scene TEXT NOT NULL,
    pose TEXT NOT NULL,
    channels TEXT NOT NULL,
    settings TEXT NOT NULL,
    frames INTEGER NOT NULL,
    dark_frames INTEGER NOT NULL,
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
CREATE TABLE IF NOT EXISTS plans (
    id INTEGER PRIMARY KEY AUTOINCREMENT,
    scene TEXT NOT NULL,
    request TEXT NOT NULL,
    state TEXT NOT NULL,
    step INTEGER NOT NULL DEFAULT 0,
    prompt TEXT,
    captures TEXT NOT NULL DEFAULT '[]',
    reconstruction INTEGER,
    error TEXT,
    created_at TEXT NOT NULL,
    started_at TEXT,
    finished_at TEXT,
    interim TEXT NOT NULL DEFAULT '[]'
);
CREATE TABLE IF NOT EXISTS colour_calibrations (
    id INTEGER PRIMARY KEY AUTOINCREMENT,
    scene TEXT NOT NULL,
    capture INTEGER NOT NULL,
    balance TEXT NOT NULL,
    created_at TEXT NOT NULL
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

/// Columns added to `captures` after the first release: (column, the
/// statement that adds it).
const ADDED_CAPTURE_COLUMNS: [(&str, &str); 7] = [
    (
        "kind",
        "ALTER TABLE captures ADD COLUMN kind TEXT NOT NULL DEFAULT 'light'",
    ),
    (
        "dark_capture",
        "ALTER TABLE captures ADD COLUMN dark_capture INTEGER",
    ),
    (
        "frame_counts",
        "ALTER TABLE captures ADD COLUMN frame_counts TEXT",
    ),
    (
        "polarizer_measured_deg",
        "ALTER TABLE captures ADD COLUMN polarizer_measured_deg REAL",
    ),
    ("clipping", "ALTER TABLE captures ADD COLUMN clipping TEXT"),
    ("import", "ALTER TABLE captures ADD COLUMN import TEXT"),
    ("live", "ALTER TABLE captures ADD COLUMN live TEXT"),
];

/// Catalogues from before the settings document kept a capture's camera
/// settings in columns (region, binning and trigger added later, so absent
/// from the oldest): these are added where missing (rows read them as null)
/// before the columns move into the document.
const SETTINGS_COLUMNS: [(&str, &str); 3] = [
    ("region", "ALTER TABLE captures ADD COLUMN region TEXT"),
    ("binning", "ALTER TABLE captures ADD COLUMN binning TEXT"),
    ("trigger", "ALTER TABLE captures ADD COLUMN trigger TEXT"),
];

/// Moves the settings columns into one `settings` document (version 1, as
/// `records::SettingsDocument` reads it) and drops them, in one transaction:
/// a catalogue is either all old or all new.
const SETTINGS_TO_DOCUMENT: &str = "
BEGIN;
ALTER TABLE captures ADD COLUMN settings TEXT;
UPDATE captures SET settings = json_object(
    'version', 1,
    'exposure_us', exposure_us,
    'gain', gain,
    'pixel_format', pixel_format,
    'region', json(region),
    'binning', json(binning),
    'trigger', trigger);
ALTER TABLE captures DROP COLUMN exposure_us;
ALTER TABLE captures DROP COLUMN gain;
ALTER TABLE captures DROP COLUMN pixel_format;
ALTER TABLE captures DROP COLUMN region;
ALTER TABLE captures DROP COLUMN binning;
ALTER TABLE captures DROP COLUMN trigger;
COMMIT;
";

/// Catalogues from before a capture could yield several blocks kept its one
/// polarizer angle in a column: it becomes the capture's list of channels
/// (MODEL.md blocks: `none` without a polarizer, else the sheet's angle), as
/// `records::channels_column` reads it, and the column goes, in one transaction.
const ANGLE_TO_CHANNELS: &str = r#"
BEGIN;
ALTER TABLE captures ADD COLUMN channels TEXT;
UPDATE captures SET channels = CASE
    WHEN polarizer_deg IS NULL THEN json_array(json_object('analyzer', 'none'))
    ELSE json_array(json_object('analyzer', 'sheet', 'deg', polarizer_deg)) END;
ALTER TABLE captures DROP COLUMN polarizer_deg;
COMMIT;
"#;

/// The catalogue's schema version, kept in SQLite's `user_version`: 1 is
/// the layout [`SCHEMA`] creates, and each entry of [`MIGRATIONS`] is one
/// more. A change to the layout is a new entry, never an edit of an old one.
pub const VERSION: u32 = 3;

/// Version 2: a reconstruction's solver is stored once, in its parameters
/// document (`params.solver`, the typed [`crate::solve::Solver`] the worker
/// solves with), and the `solver` column that repeated it goes. The column
/// was the one the worker read, so it is what the document keeps. A row
/// whose parameters are not a JSON object was unreadable before and stays
/// so (named when read), and keeps its document as it was.
const SOLVER_INTO_PARAMS: &str = "
UPDATE reconstructions SET params = json_set(params, '$.solver', solver)
    WHERE json_valid(params) AND json_type(params) = 'object';
ALTER TABLE reconstructions DROP COLUMN solver
";

/// Version 3: scene calibrations (`POST /calibrations/scene`), each scene's
/// geometry fitted to its captures: the file text it placed, the placed
/// file and the fit's report.
const SCENE_FITS: &str = "
CREATE TABLE IF NOT EXISTS scene_fits (
    id INTEGER PRIMARY KEY AUTOINCREMENT,
    scene TEXT NOT NULL,
    captures TEXT NOT NULL,
    free TEXT NOT NULL,
    state TEXT NOT NULL,
    error TEXT,
    created_at TEXT NOT NULL,
    finished_at TEXT,
    source_toml TEXT NOT NULL,
    placed_toml TEXT,
    fit TEXT
)
";

/// The numbered migrations after version 1: `(n, statements)` brings a
/// catalogue at version `n - 1` to `n`, in one transaction with the version.
const MIGRATIONS: [(u32, &str); 2] = [(2, SOLVER_INTO_PARAMS), (3, SCENE_FITS)];

/// Why the catalogue cannot be brought to this polnlos's layout.
#[derive(Debug, thiserror::Error)]
pub enum MigrateError {
    /// SQLite refused a statement.
    #[error(transparent)]
    Sql(#[from] rusqlite::Error),
    /// The catalogue was written by a newer polnlos.
    #[error("its schema is version {found}, newer than this polnlos knows ({VERSION}): it was written by a newer polnlos; run that one, or give this one another data_dir (nothing was changed)")]
    Newer {
        /// The catalogue's version.
        found: u32,
    },
}

/// Brings the catalogue to [`VERSION`] and sets up the id sequences: a new
/// one is created at it; one from before numbered versions (0) has its
/// added columns found and brought to version 1 (rows kept); then each
/// numbered migration past its version runs in turn. A catalogue from a
/// newer polnlos is refused untouched.
pub(super) fn migrate(conn: &Connection) -> Result<(), MigrateError> {
    let found: u32 = conn.pragma_query_value(None, "user_version", |r| r.get(0))?;
    if found > VERSION {
        return Err(MigrateError::Newer { found });
    }
    if found == 0 {
        unversioned(conn)?;
        conn.pragma_update(None, "user_version", 1)?;
    }
    for (n, statements) in MIGRATIONS {
        if n > found.max(1) {
            conn.execute_batch(&format!(
                "BEGIN; {statements}; PRAGMA user_version = {n}; COMMIT;"
            ))
            .inspect_err(|_| {
                let _ = conn.execute_batch("ROLLBACK");
            })?;
        }
    }
    conn.execute_batch(ID_SEQUENCES)?;
    Ok(())
}

/// Creates the tables, and brings a catalogue from before numbered versions
/// to version 1: the columns later releases added are found by name and
/// added, the settings and angle columns moved into their documents.
fn unversioned(conn: &Connection) -> rusqlite::Result<()> {
    conn.execute_batch(SCHEMA)?;
    let mut st = conn.prepare("PRAGMA table_info(captures)")?;
    let has: Vec<String> = st
        .query_map([], |r| r.get::<_, String>(1))?
        .collect::<rusqlite::Result<_>>()?;
    for (column, add) in ADDED_CAPTURE_COLUMNS {
        if !has.iter().any(|c| c == column) {
            conn.execute_batch(add)?;
        }
    }
    if !has.iter().any(|c| c == "settings") {
        for (column, add) in SETTINGS_COLUMNS {
            if !has.iter().any(|c| c == column) {
                conn.execute_batch(add)?;
            }
        }
        conn.execute_batch(SETTINGS_TO_DOCUMENT).inspect_err(|_| {
            let _ = conn.execute_batch("ROLLBACK");
        })?;
    }
    // Plans from before interim reconstructions have none.
    let mut st = conn.prepare("PRAGMA table_info(plans)")?;
    let plan_has: Vec<String> = st
        .query_map([], |r| r.get::<_, String>(1))?
        .collect::<rusqlite::Result<_>>()?;
    if !plan_has.iter().any(|c| c == "interim") {
        conn.execute_batch("ALTER TABLE plans ADD COLUMN interim TEXT NOT NULL DEFAULT '[]'")?;
    }
    if !has.iter().any(|c| c == "channels") {
        conn.execute_batch(ANGLE_TO_CHANNELS).inspect_err(|_| {
            let _ = conn.execute_batch("ROLLBACK");
        })?;
    }
    Ok(())
}

/// The catalogue's job tables. Every statement that works on either is
/// written out here per table: no table name is spliced into SQL.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Table {
    /// `captures`.
    Captures,
    /// `reconstructions`.
    Reconstructions,
}

impl Table {
    /// Both tables.
    pub const ALL: [Table; 2] = [Table::Captures, Table::Reconstructions];

    /// The table's name, which is also its folder under the data directory.
    pub fn name(self) -> &'static str {
        match self {
            Table::Captures => "captures",
            Table::Reconstructions => "reconstructions",
        }
    }

    /// Marks every queued or running job interrupted (?1 error, ?2 time).
    pub(super) fn interrupt_all(self) -> &'static str {
        match self {
            Table::Captures => "UPDATE captures SET state = 'interrupted', error = ?1, finished_at = ?2 WHERE state IN ('queued', 'running')",
            Table::Reconstructions => "UPDATE reconstructions SET state = 'interrupted', error = ?1, finished_at = ?2 WHERE state IN ('queued', 'running')",
        }
    }

    /// Puts reconstructions left queued or running back in the queue: their
    /// inputs are stored captures, so a start runs them again.
    pub(super) const REQUEUE_RECONSTRUCTIONS: &'static str = "UPDATE reconstructions SET state = 'queued', started_at = NULL WHERE state IN ('queued', 'running')";

    /// Puts running reconstruction ?1 back in the queue.
    pub(super) const REQUEUE_RECONSTRUCTION: &'static str = "UPDATE reconstructions SET state = 'queued', started_at = NULL WHERE id = ?1 AND state = 'running'";

    /// Marks job ?1 interrupted if it runs (?2 error, ?3 time).
    pub(super) fn interrupt_one(self) -> &'static str {
        match self {
            Table::Captures => "UPDATE captures SET state = 'interrupted', error = ?2, finished_at = ?3 WHERE id = ?1 AND state = 'running'",
            Table::Reconstructions => "UPDATE reconstructions SET state = 'interrupted', error = ?2, finished_at = ?3 WHERE id = ?1 AND state = 'running'",
        }
    }

    /// Marks job ?1 cancelled at ?2 if it is queued (`only_queued`) or
    /// queued or running.
    pub(super) fn cancel(self, only_queued: bool) -> &'static str {
        match (self, only_queued) {
            (Table::Captures, true) => "UPDATE captures SET state = 'cancelled', finished_at = ?2 WHERE id = ?1 AND state IN ('queued')",
            (Table::Captures, false) => "UPDATE captures SET state = 'cancelled', finished_at = ?2 WHERE id = ?1 AND state IN ('queued', 'running')",
            (Table::Reconstructions, true) => "UPDATE reconstructions SET state = 'cancelled', finished_at = ?2 WHERE id = ?1 AND state IN ('queued')",
            (Table::Reconstructions, false) => "UPDATE reconstructions SET state = 'cancelled', finished_at = ?2 WHERE id = ?1 AND state IN ('queued', 'running')",
        }
    }

    /// Counts the rows with id ?1 (0 or 1).
    pub(super) fn count_id(self) -> &'static str {
        match self {
            Table::Captures => "SELECT COUNT(*) FROM captures WHERE id = ?1",
            Table::Reconstructions => "SELECT COUNT(*) FROM reconstructions WHERE id = ?1",
        }
    }
}

#[cfg(test)]
mod tests {
    use rusqlite::Connection;

    use crate::camera::{Acquisition, CameraSettings, PixelFormat, TriggerMode};
    use crate::scene::Channel;
    use crate::store::Store;

    /// The captures table as the first release made it.
    const FIRST_RELEASE: &str = "CREATE TABLE captures (
        id INTEGER PRIMARY KEY, scene TEXT NOT NULL, pose TEXT NOT NULL, polarizer_deg REAL,
        exposure_us REAL NOT NULL, gain REAL NOT NULL, frames INTEGER NOT NULL,
        dark_frames INTEGER NOT NULL, pixel_format TEXT NOT NULL, state TEXT NOT NULL,
        error TEXT, created_at TEXT NOT NULL, started_at TEXT, finished_at TEXT,
        camera_id TEXT, counters TEXT, frames_taken INTEGER NOT NULL DEFAULT 0);";

    const OLD_ROW: &str = "INSERT INTO captures (id, scene, pose, polarizer_deg, exposure_us, gain, frames, dark_frames, pixel_format, state, created_at)
        VALUES (?1, 'brewster-crossed', 'A', 0.0, 2500.0, 1.5, 3, 0, 'Mono8', 'done', '2026-01-01T00:00:00.000Z')";

    #[test]
    fn settings_columns_of_an_old_catalogue_move_into_the_document() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("catalogue.sqlite");
        {
            let raw = Connection::open(&path).unwrap();
            raw.execute_batch(FIRST_RELEASE).unwrap();
            raw.execute(OLD_ROW, [1]).unwrap();
            // A later release recorded the geometry and the trigger.
            raw.execute_batch("ALTER TABLE captures ADD COLUMN region TEXT; ALTER TABLE captures ADD COLUMN binning TEXT; ALTER TABLE captures ADD COLUMN trigger TEXT;").unwrap();
            raw.execute(OLD_ROW, [2]).unwrap();
            raw.execute(
                "UPDATE captures SET region = '[0,0,64,32]', binning = '[2,2]', trigger = 'software' WHERE id = 2",
                [],
            )
            .unwrap();
        }
        let store = Store::open(dir.path()).unwrap();
        let first = store.capture(1).unwrap();
        assert_eq!(
            first.settings,
            CameraSettings {
                exposure_us: Some(2500.0),
                gain: Some(1.5),
                pixel_format: Some(PixelFormat::Mono8),
                ..CameraSettings::default()
            }
        );
        let e = Acquisition::try_from(&first).unwrap_err().to_string();
        assert!(e.contains("records no region, binning, trigger"), "{e}");
        let second = Acquisition::try_from(&store.capture(2).unwrap()).unwrap();
        assert_eq!(
            second,
            Acquisition {
                exposure_us: 2500.0,
                gain: 1.5,
                pixel_format: PixelFormat::Mono8,
                trigger: TriggerMode::Software,
                ..Acquisition::defaults_at([0, 0, 64, 32], [2, 2])
            }
        );
        drop(store);
        let columns = columns(&Connection::open(&path).unwrap(), "captures");
        for gone in [
            "exposure_us",
            "gain",
            "pixel_format",
            "region",
            "binning",
            "trigger",
        ] {
            assert!(!columns.iter().any(|c| c == gone), "{gone} in {columns:?}");
        }
        assert!(!columns.iter().any(|c| c == "polarizer_deg"), "{columns:?}");
        // Opened again: already migrated, the rows unchanged.
        let store = Store::open(dir.path()).unwrap();
        assert_eq!(store.capture(1).unwrap().settings, first.settings);
    }

    #[test]
    fn an_old_capture_yields_the_one_block_its_angle_column_named() {
        let dir = tempfile::tempdir().unwrap();
        {
            let raw = Connection::open(dir.path().join("catalogue.sqlite")).unwrap();
            raw.execute_batch(FIRST_RELEASE).unwrap();
            raw.execute(OLD_ROW, [1]).unwrap();
            raw.execute(OLD_ROW, [2]).unwrap();
            raw.execute(OLD_ROW, [3]).unwrap();
            raw.execute("UPDATE captures SET polarizer_deg = NULL WHERE id = 2", [])
                .unwrap();
            raw.execute("UPDATE captures SET polarizer_deg = 22.5 WHERE id = 3", [])
                .unwrap();
        }
        let store = Store::open(dir.path()).unwrap();
        assert_eq!(
            store.capture(1).unwrap().channels,
            vec![Channel::Sheet { deg: 0.0 }]
        );
        assert_eq!(store.capture(2).unwrap().channels, vec![Channel::None]);
        assert_eq!(
            store.capture(3).unwrap().channels,
            vec![Channel::Sheet { deg: 22.5 }]
        );
    }

    #[test]
    fn a_plan_from_before_interim_reconstructions_reads_back_with_none() {
        let dir = tempfile::tempdir().unwrap();
        {
            let raw = Connection::open(dir.path().join("catalogue.sqlite")).unwrap();
            raw.execute_batch(FIRST_RELEASE).unwrap();
            raw.execute_batch(
                "CREATE TABLE plans (id INTEGER PRIMARY KEY AUTOINCREMENT, scene TEXT NOT NULL,
                 request TEXT NOT NULL, state TEXT NOT NULL, step INTEGER NOT NULL DEFAULT 0,
                 prompt TEXT, captures TEXT NOT NULL DEFAULT '[]', reconstruction INTEGER,
                 error TEXT, created_at TEXT NOT NULL, started_at TEXT, finished_at TEXT);
                 INSERT INTO plans (scene, request, state, step, captures, reconstruction, created_at)
                 VALUES ('brewster-rotating', '{}', 'done', 9, '[{\"step\":0,\"capture\":4}]', 5, '2026-01-01T00:00:00.000Z');",
            )
            .unwrap();
        }
        let store = Store::open(dir.path()).unwrap();
        let p = store.plan(1).unwrap().expect("the old plan");
        assert_eq!((p.step, p.reconstruction), (9, Some(5)));
        assert_eq!(p.captures.len(), 1);
        assert!(p.interim.is_empty());
    }

    #[test]
    fn version_2_keeps_a_reconstructions_solver_once_in_its_parameters() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("catalogue.sqlite");
        {
            // A version-1 catalogue: the solver in its column, and again
            // (or not) in the parameters; the column is what was solved with.
            let raw = Connection::open(&path).unwrap();
            raw.execute_batch(super::SCHEMA).unwrap();
            raw.pragma_update(None, "user_version", 1).unwrap();
            for (id, solver, params) in [
                (
                    1,
                    "fista-tv",
                    r#"{"version":1,"solver":"admm-tv","lambda":0.25,"max_iter":40,"truth":"disk"}"#,
                ),
                (2, "tikhonov", r#"{"version":1}"#),
                (3, "sgd", r#"{"version":1}"#),
                (4, "lsq", "not json"),
            ] {
                raw.execute(
                    "INSERT INTO reconstructions (id, scene, captures, solver, params, state, created_at) VALUES (?1, 'brewster-crossed', '[1]', ?2, ?3, 'done', '2026-01-01T00:00:00.000Z')",
                    rusqlite::params![id, solver, params],
                )
                .unwrap();
            }
        }
        let store = Store::open(dir.path()).unwrap();
        assert_eq!(version(dir.path()), super::VERSION);
        let first = store.reconstruction(1).unwrap();
        assert_eq!(first.params.solve.solver, crate::solve::Solver::FISTA_TV);
        assert_eq!(first.solver, "fista-tv");
        assert_eq!(
            (first.params.solve.lambda, first.params.solve.max_iter),
            (Some(0.25), Some(40))
        );
        assert_eq!(
            first.params.truth.as_ref().and_then(|t| t.pattern()),
            Some("disk")
        );
        let second = store.reconstruction(2).unwrap();
        assert_eq!(second.params.solve.solver, crate::solve::Solver::TIKHONOV);
        // A solver polnlos does not know makes its row unreadable, named.
        let e = store.reconstruction(3).unwrap_err().to_string();
        assert!(e.contains("unknown variant `sgd`"), "{e}");
        let page = store.reconstructions(10, 0).unwrap();
        assert_eq!(page.unreadable, [4, 3]);
        drop(store);
        let raw = Connection::open(&path).unwrap();
        let columns = columns(&raw, "reconstructions");
        assert!(!columns.iter().any(|c| c == "solver"), "{columns:?}");
        // The document that was not JSON is kept as it was.
        let kept: String = raw
            .query_row("SELECT params FROM reconstructions WHERE id = 4", [], |r| {
                r.get(0)
            })
            .unwrap();
        assert_eq!(kept, "not json");
    }

    /// The column names of `table` (one of the catalogue's own names).
    fn columns(raw: &Connection, table: &str) -> Vec<String> {
        let mut st = raw
            .prepare("SELECT name FROM pragma_table_info(?1)")
            .unwrap();
        st.query_map([table], |r| r.get(0))
            .unwrap()
            .collect::<Result<_, _>>()
            .unwrap()
    }

    /// `user_version` of the catalogue in `dir`.
    fn version(dir: &std::path::Path) -> u32 {
        Connection::open(dir.join("catalogue.sqlite"))
            .unwrap()
            .pragma_query_value(None, "user_version", |r| r.get(0))
            .unwrap()
    }

    #[test]
    fn a_catalogue_is_numbered_and_one_from_a_newer_polnlos_is_refused_untouched() {
        // A new catalogue is created at this version.
        let new = tempfile::tempdir().unwrap();
        drop(Store::open(new.path()).unwrap());
        assert_eq!(version(new.path()), super::VERSION);
        // One from before numbered versions is brought to version 1, rows kept.
        let old = tempfile::tempdir().unwrap();
        {
            let raw = Connection::open(old.path().join("catalogue.sqlite")).unwrap();
            raw.execute_batch(FIRST_RELEASE).unwrap();
            raw.execute(OLD_ROW, [7]).unwrap();
        }
        let store = Store::open(old.path()).unwrap();
        assert_eq!(store.capture(7).unwrap().frames, 3);
        drop(store);
        assert_eq!(version(old.path()), super::VERSION);
        // Opened again, nothing is migrated twice.
        drop(Store::open(old.path()).unwrap());
        assert_eq!(version(old.path()), super::VERSION);
        // A newer polnlos's catalogue: refused, naming what to do, and left as it was.
        let path = old.path().join("catalogue.sqlite");
        Connection::open(&path)
            .unwrap()
            .pragma_update(None, "user_version", super::VERSION + 1)
            .unwrap();
        let e = match Store::open(old.path()) {
            Ok(_) => panic!("a newer catalogue was opened"),
            Err(e) => e.to_string(),
        };
        assert!(
            e.contains(&format!(
                "version {}, newer than this polnlos knows",
                super::VERSION + 1
            )) && e.contains("another data_dir"),
            "{e}"
        );
        assert_eq!(version(old.path()), super::VERSION + 1);
        let rows: i64 = Connection::open(&path)
            .unwrap()
            .query_row("SELECT COUNT(*) FROM captures WHERE id = 7", [], |r| {
                r.get(0)
            })
            .unwrap();
        assert_eq!(rows, 1);
    }
}
