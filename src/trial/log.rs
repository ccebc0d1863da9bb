//! The SQLite trial log: one row per trial, durable across crashes.
//!
//! Durability: the database runs in WAL mode with `synchronous=FULL`, and every write
//! (a new trial, a plan, an outcome, a grade, a whole CSV import) is one `BEGIN
//! IMMEDIATE` transaction. In WAL mode a process crash never loses a committed
//! transaction even with `synchronous=NORMAL`; `FULL` additionally fsyncs the WAL at
//! every commit, so a power cut or kernel panic cannot lose one either. An observer's
//! grade cannot be re-created after the fact, and a trial takes tens of seconds, so
//! one fsync per commit is a price worth paying.
//!
//! Safety of existing files: before SQLite may write anything, [`TrialLog::open`]
//! checks the SQLite header, the `application_id`, the schema version and
//! `PRAGMA quick_check`; a file that fails any of them is reported and left as it was.
//!
//! Schema changes are numbered migrations (`MIGRATIONS`), applied in order inside one
//! transaction and recorded in the `schema_version` table.

use super::grade::{FailureCause, Grade, GradeSource, Grading};
use super::time::UtcTimestamp;
use super::{software_version, TrialError};
use crate::fsio::{FileError, FileOp};
use crate::geometry::PoseJson;
use rusqlite::{
    params, Connection, OpenFlags, OptionalExtension, Transaction, TransactionBehavior,
};
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::time::Duration;

/// The id of a trial: the log's row id, assigned on insertion, never reused.
pub type TrialId = i64;

/// `PRAGMA application_id` of a graspcell trial log ("GCTR").
pub const APPLICATION_ID: i32 = 0x4743_5452;

/// The default trial log path, relative to the working directory.
pub const DEFAULT_LOG_PATH: &str = "trials/trials.sqlite";

/// How long a writer waits for another process's transaction to finish.
const BUSY_TIMEOUT: Duration = Duration::from_secs(10);

/// One schema migration: applied to a log at `version - 1` to bring it to `version`.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Migration {
    /// The version after this migration.
    pub version: i64,
    /// What it does (recorded in `schema_version`).
    pub description: &'static str,
    /// The SQL, run as one batch inside the migration transaction.
    pub sql: &'static str,
}

/// The schema's history; the last entry is the current version.
pub(crate) const MIGRATIONS: &[Migration] = &[
    Migration {
        version: 1,
        description: "trials and grade_history",
        sql: r#"
CREATE TABLE trials (
    id               INTEGER PRIMARY KEY AUTOINCREMENT,
    started_at       TEXT    NOT NULL,
    category         TEXT    NOT NULL,
    task             TEXT    NOT NULL,
    method           TEXT    NOT NULL,
    object_name      TEXT    NOT NULL,
    object_seed      TEXT,
    placement_index  INTEGER NOT NULL CHECK (placement_index >= 0),
    placement_pose   TEXT    NOT NULL,
    campaign_id      TEXT,
    snapshot_path    TEXT,
    fits             TEXT    NOT NULL,
    planned_pose     TEXT,
    planned_joints   TEXT,
    outcome          TEXT,
    grade            TEXT CHECK (grade IN ('success', 'partial', 'failure')),
    failure_cause    TEXT CHECK (failure_cause IN
                         ('reachability', 'registration', 'shape-dissimilarity', 'execution', 'other')),
    observer_note    TEXT,
    graded_at        TEXT,
    grade_source     TEXT,
    software_version TEXT    NOT NULL,
    seeds            TEXT    NOT NULL,
    CHECK (grade IS NOT 'failure' OR failure_cause IS NOT NULL),
    CHECK (grade IS NOT 'success' OR failure_cause IS NULL),
    CHECK ((grade IS NULL) = (graded_at IS NULL))
);
CREATE INDEX trials_pairing ON trials (campaign_id, object_name, object_seed, placement_index);
CREATE TABLE grade_history (
    id            INTEGER PRIMARY KEY AUTOINCREMENT,
    trial_id      INTEGER NOT NULL REFERENCES trials (id),
    grade         TEXT    NOT NULL CHECK (grade IN ('success', 'partial', 'failure')),
    failure_cause TEXT,
    observer_note TEXT,
    graded_at     TEXT    NOT NULL,
    source        TEXT    NOT NULL
);
CREATE INDEX grade_history_trial ON grade_history (trial_id);
"#,
    },
    Migration {
        version: 2,
        description: "trial picture path",
        sql: "ALTER TABLE trials ADD COLUMN picture_path TEXT;",
    },
];

/// The newest schema version this build writes.
pub const SCHEMA_VERSION: i64 = MIGRATIONS[MIGRATIONS.len() - 1].version;

/// The object of a trial: a novel object of the category, named, with its
/// generator seed when it is procedural.
#[derive(Debug, Clone, PartialEq, Eq, PartialOrd, Ord, Hash, Serialize, Deserialize)]
pub struct ObjectRef {
    /// Object name (e.g. `mug-novel-3`).
    pub name: String,
    /// Seed of the procedural generator, if the object is generated.
    pub seed: Option<u64>,
}

/// Where the object stood: the placement's index in the campaign and its pose.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Placement {
    /// Index of the placement (0-based) within the object's placements.
    pub index: u32,
    /// The object's pose in the robot base frame.
    pub base_from_object: PoseJson,
}

/// A trial as recorded when it starts (grading comes later).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct NewTrial {
    /// When the trial started.
    pub started_at: UtcTimestamp,
    /// Object category (e.g. `mug`).
    pub category: String,
    /// Task (e.g. `pour`).
    pub task: String,
    /// Planning method (e.g. `best-single`, `gaussian-r`, `laplace`).
    pub method: String,
    /// The object.
    pub object: ObjectRef,
    /// The object's placement.
    pub placement: Placement,
    /// The campaign this trial belongs to, if any.
    pub campaign_id: Option<String>,
    /// The depth snapshot's file.
    pub snapshot_path: Option<PathBuf>,
    /// Registration fits (per model: transform, eps, sigma), as JSON.
    pub fits: serde_json::Value,
    /// The planned palm pose in the base frame.
    pub planned_pose: Option<PoseJson>,
    /// The planned arm joint angles (rad).
    pub planned_joints: Option<Vec<f64>>,
    /// The execution outcome, as JSON.
    pub outcome: Option<serde_json::Value>,
    /// Every seed the trial used, by name.
    pub seeds: BTreeMap<String, u64>,
}

/// The key that pairs trials of different methods: same campaign, object and placement.
#[derive(Debug, Clone, PartialEq, Eq, PartialOrd, Ord, Hash, Serialize)]
pub struct PairingKey {
    /// Campaign id.
    pub campaign_id: Option<String>,
    /// Object.
    pub object: ObjectRef,
    /// Placement index.
    pub placement_index: u32,
}

/// One row of the trial log.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct TrialRecord {
    /// The trial's id.
    pub id: TrialId,
    /// What was recorded about the trial.
    #[serde(flatten)]
    pub trial: NewTrial,
    /// The software version that recorded it.
    pub software_version: String,
    /// The current grade, if graded.
    pub grading: Option<Grading>,
    /// When the current grade was given.
    pub graded_at: Option<UtcTimestamp>,
    /// Who gave the current grade.
    pub grade_source: Option<GradeSource>,
}

impl TrialRecord {
    /// The key pairing this trial with the other methods' trials.
    pub fn pairing_key(&self) -> PairingKey {
        PairingKey {
            campaign_id: self.trial.campaign_id.clone(),
            object: self.trial.object.clone(),
            placement_index: self.trial.placement.index,
        }
    }
}

/// An open trial log.
#[derive(Debug)]
pub struct TrialLog {
    pub(super) conn: Connection,
    pub(super) path: PathBuf,
}

/// What [`TrialLog::open`] found when it checked the file.
enum Found {
    Fresh,
    Ours,
}

fn check_sqlite_header(path: &Path) -> Result<(), TrialError> {
    use std::io::Read;
    let mut file = match std::fs::File::open(path) {
        Ok(f) => f,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(()),
        Err(source) => return Err(FileError::new(FileOp::Read, path, source).into()),
    };
    let mut header = Vec::with_capacity(16);
    file.by_ref()
        .take(16)
        .read_to_end(&mut header)
        .map_err(FileError::of(FileOp::Read, path))?;
    if header.is_empty() || header == b"SQLite format 3\0" {
        return Ok(());
    }
    let shown: String = header
        .iter()
        .map(|&b| {
            if b.is_ascii_graphic() || b == b' ' {
                b as char
            } else {
                '.'
            }
        })
        .collect();
    Err(TrialError::NotSqlite {
        path: path.to_path_buf(),
        detail: format!("starts with {shown:?}, not \"SQLite format 3\""),
    })
}

impl TrialLog {
    /// Opens the log at `path`, creating it (and its directory) if it does not exist,
    /// and migrating an older schema. A file that is not a graspcell trial log, has a
    /// newer schema, or is damaged gives an error and is not modified.
    pub fn open(path: impl AsRef<Path>) -> Result<Self, TrialError> {
        let path = path.as_ref();
        if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
            crate::fsio::create_dir_all(dir)?;
        }
        Self::open_with(path, OpenFlags::SQLITE_OPEN_CREATE, MIGRATIONS)
    }

    /// Opens an existing log (an error names the path if there is none); migrates an
    /// older schema as [`TrialLog::open`] does.
    pub fn open_existing(path: impl AsRef<Path>) -> Result<Self, TrialError> {
        let path = path.as_ref();
        if !path.exists() {
            return Err(TrialError::Missing {
                path: path.to_path_buf(),
            });
        }
        Self::open_with(path, OpenFlags::empty(), MIGRATIONS)
    }

    pub(crate) fn open_with(
        path: &Path,
        create: OpenFlags,
        migrations: &[Migration],
    ) -> Result<Self, TrialError> {
        check_sqlite_header(path)?;
        let sql = |op: &'static str| {
            let path = path.to_path_buf();
            move |source| TrialError::Sqlite { path, op, source }
        };
        let flags = OpenFlags::SQLITE_OPEN_READ_WRITE
            | OpenFlags::SQLITE_OPEN_NO_MUTEX
            | OpenFlags::SQLITE_OPEN_URI
            | create;
        let conn = Connection::open_with_flags(path, flags).map_err(sql("open"))?;
        conn.busy_timeout(BUSY_TIMEOUT)
            .map_err(sql("busy_timeout"))?;
        let log = TrialLog {
            conn,
            path: path.to_path_buf(),
        };
        let found = log.inspect(migrations)?;
        if matches!(found, Found::Ours) {
            let check = log.quick_check()?;
            if check != "ok" {
                return Err(TrialError::Corrupt {
                    path: path.to_path_buf(),
                    detail: format!("quick_check: {check}"),
                });
            }
        }
        // From here on SQLite may write to the file.
        let mode: String = log
            .conn
            .pragma_update_and_check(None, "journal_mode", "WAL", |row| row.get(0))
            .map_err(sql("journal_mode=WAL"))?;
        if !mode.eq_ignore_ascii_case("wal") {
            tracing::warn!(
                "{}: journal mode is {mode}, not WAL (the file system may not support it)",
                path.display()
            );
        }
        log.conn
            .pragma_update(None, "synchronous", "FULL")
            .map_err(sql("synchronous=FULL"))?;
        log.conn
            .pragma_update(None, "foreign_keys", "ON")
            .map_err(sql("foreign_keys=ON"))?;
        let mut log = log;
        log.migrate(migrations)?;
        Ok(log)
    }

    /// Classifies the file by reading only: fresh, ours at a known version, or an error.
    fn inspect(&self, migrations: &[Migration]) -> Result<Found, TrialError> {
        let corrupt = |source: rusqlite::Error| self.classify_read_error("read header", source);
        let app_id: i32 = self
            .conn
            .pragma_query_value(None, "application_id", |row| row.get(0))
            .map_err(corrupt)?;
        let mut stmt = self
            .conn
            .prepare("SELECT name FROM sqlite_master WHERE type = 'table' AND name NOT LIKE 'sqlite_%' ORDER BY name")
            .map_err(corrupt)?;
        let tables: Vec<String> = stmt
            .query_map([], |row| row.get(0))
            .and_then(|rows| rows.collect())
            .map_err(corrupt)?;
        drop(stmt);
        if tables.is_empty() && app_id == 0 {
            return Ok(Found::Fresh);
        }
        if app_id != APPLICATION_ID {
            return Err(TrialError::ForeignSchema {
                path: self.path.clone(),
                detail: format!(
                    "application_id {app_id:#x}, expected {APPLICATION_ID:#x}; tables: {}",
                    if tables.is_empty() {
                        "none".to_string()
                    } else {
                        tables.join(", ")
                    }
                ),
            });
        }
        if !tables.iter().any(|t| t == "schema_version") {
            return Err(TrialError::ForeignSchema {
                path: self.path.clone(),
                detail: "graspcell application_id but no schema_version table".to_string(),
            });
        }
        let found = self.schema_version()?;
        let supported = migrations.last().map_or(0, |m| m.version);
        if found > supported {
            return Err(TrialError::NewerSchema {
                path: self.path.clone(),
                found,
                supported,
            });
        }
        Ok(Found::Ours)
    }

    fn classify_read_error(&self, op: &'static str, source: rusqlite::Error) -> TrialError {
        use rusqlite::ErrorCode;
        match source.sqlite_error_code() {
            Some(ErrorCode::NotADatabase) | Some(ErrorCode::DatabaseCorrupt) => {
                TrialError::Corrupt {
                    path: self.path.clone(),
                    detail: source.to_string(),
                }
            }
            _ => TrialError::Sqlite {
                path: self.path.clone(),
                op,
                source,
            },
        }
    }

    fn sql_err(&self, op: &'static str) -> impl Fn(rusqlite::Error) -> TrialError + '_ {
        move |source| self.classify_read_error(op, source)
    }

    /// Applies every migration newer than the file's version, in one transaction.
    /// A log already at the newest version is not written to at all.
    fn migrate(&mut self, migrations: &[Migration]) -> Result<(), TrialError> {
        let supported = migrations.last().map_or(0, |m| m.version);
        if self.schema_version()? == supported {
            return Ok(());
        }
        let path = self.path.clone();
        self.write("migrate schema", |tx| {
            let sql = |op: &'static str| {
                let path = path.clone();
                move |source| TrialError::Sqlite { path, op, source }
            };
            tx.execute_batch(
                "CREATE TABLE IF NOT EXISTS schema_version (
                     version          INTEGER PRIMARY KEY,
                     applied_at       TEXT NOT NULL,
                     software_version TEXT NOT NULL,
                     description      TEXT NOT NULL
                 );",
            )
            .map_err(sql("create schema_version"))?;
            tx.pragma_update(None, "application_id", APPLICATION_ID)
                .map_err(sql("set application_id"))?;
            let current: i64 = tx
                .query_row(
                    "SELECT COALESCE(MAX(version), 0) FROM schema_version",
                    [],
                    |row| row.get(0),
                )
                .map_err(sql("read schema version"))?;
            // Another process may have migrated between the check above and this
            // transaction; the version read here, under the write lock, decides.
            if current > supported {
                return Err(TrialError::NewerSchema {
                    path: path.clone(),
                    found: current,
                    supported,
                });
            }
            for m in migrations.iter().filter(|m| m.version > current) {
                tracing::info!(
                    "{}: migrating trial log to schema {} ({})",
                    path.display(),
                    m.version,
                    m.description
                );
                tx.execute_batch(m.sql).map_err(sql("apply migration"))?;
                tx.execute(
                    "INSERT INTO schema_version (version, applied_at, software_version, description)
                     VALUES (?1, ?2, ?3, ?4)",
                    params![
                        m.version,
                        UtcTimestamp::now().to_string(),
                        software_version(),
                        m.description
                    ],
                )
                .map_err(sql("record migration"))?;
            }
            Ok(())
        })
    }

    /// Runs `f` in one `BEGIN IMMEDIATE` transaction and commits; any error rolls back.
    pub(super) fn write<T>(
        &mut self,
        op: &'static str,
        f: impl FnOnce(&Transaction<'_>) -> Result<T, TrialError>,
    ) -> Result<T, TrialError> {
        let path = self.path.clone();
        let tx = self
            .conn
            .transaction_with_behavior(TransactionBehavior::Immediate)
            .map_err(|source| TrialError::Sqlite {
                path: path.clone(),
                op,
                source,
            })?;
        let value = f(&tx)?;
        tx.commit()
            .map_err(|source| TrialError::Sqlite { path, op, source })?;
        Ok(value)
    }

    /// The log's file.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// The schema version of the file (0 for a fresh file).
    pub fn schema_version(&self) -> Result<i64, TrialError> {
        let exists: bool = self
            .conn
            .query_row(
                "SELECT COUNT(*) > 0 FROM sqlite_master WHERE type = 'table' AND name = 'schema_version'",
                [],
                |row| row.get(0),
            )
            .map_err(self.sql_err("read schema version"))?;
        if !exists {
            return Ok(0);
        }
        self.conn
            .query_row(
                "SELECT COALESCE(MAX(version), 0) FROM schema_version",
                [],
                |row| row.get(0),
            )
            .map_err(self.sql_err("read schema version"))
    }

    /// `PRAGMA quick_check`: `"ok"` or SQLite's list of problems.
    pub fn quick_check(&self) -> Result<String, TrialError> {
        self.check_pragma("quick_check")
    }

    /// `PRAGMA integrity_check`: `"ok"` or SQLite's list of problems.
    pub fn integrity_check(&self) -> Result<String, TrialError> {
        self.check_pragma("integrity_check")
    }

    fn check_pragma(&self, pragma: &'static str) -> Result<String, TrialError> {
        let mut stmt = self
            .conn
            .prepare(&format!("PRAGMA {pragma}"))
            .map_err(self.sql_err(pragma))?;
        let lines: Vec<String> = stmt
            .query_map([], |row| row.get(0))
            .and_then(|rows| rows.collect())
            .map_err(self.sql_err(pragma))?;
        Ok(lines.join("; "))
    }

    /// Records a new trial in one transaction and returns its id.
    pub fn record_trial(&mut self, trial: &NewTrial) -> Result<TrialId, TrialError> {
        validate_trial(trial)?;
        let path = self.path.clone();
        self.write("record trial", |tx| insert_trial(tx, &path, trial))
    }

    /// Records a trial and its grade in one transaction: both are in the file, or
    /// neither is (a full disk leaves no ungraded row behind to be recorded twice).
    pub fn record_graded_trial(
        &mut self,
        trial: &NewTrial,
        grading: &super::grade::Grading,
        source: super::grade::GradeSource,
        at: UtcTimestamp,
    ) -> Result<TrialId, TrialError> {
        validate_trial(trial)?;
        let path = self.path.clone();
        self.write("record graded trial", |tx| {
            let id = insert_trial(tx, &path, trial)?;
            super::grade::apply_grade(tx, &path, id, grading, source, at)?;
            Ok(id)
        })
    }

    /// Records the planned palm pose and arm joints of a trial.
    pub fn set_plan(
        &mut self,
        id: TrialId,
        planned_pose: &PoseJson,
        planned_joints: &[f64],
    ) -> Result<(), TrialError> {
        check_finite_field("planned_pose", pose_numbers(planned_pose))?;
        check_finite_field("planned_joints", planned_joints.iter().copied())?;
        self.update_one(
            id,
            "record plan",
            "UPDATE trials SET planned_pose = ?2, planned_joints = ?3 WHERE id = ?1",
            params![id, to_json(planned_pose), to_json(&planned_joints)],
        )
    }

    /// Records the execution outcome of a trial.
    pub fn set_outcome(
        &mut self,
        id: TrialId,
        outcome: &serde_json::Value,
    ) -> Result<(), TrialError> {
        self.update_one(
            id,
            "record outcome",
            "UPDATE trials SET outcome = ?2 WHERE id = ?1",
            params![id, to_json(outcome)],
        )
    }

    fn update_one(
        &mut self,
        id: TrialId,
        op: &'static str,
        sql: &str,
        params: &[&dyn rusqlite::ToSql],
    ) -> Result<(), TrialError> {
        let path = self.path.clone();
        self.write(op, |tx| {
            let changed = tx
                .execute(sql, params)
                .map_err(|source| TrialError::Sqlite {
                    path: path.clone(),
                    op,
                    source,
                })?;
            if changed == 0 {
                return Err(TrialError::UnknownTrial {
                    path: path.clone(),
                    id,
                });
            }
            Ok(())
        })
    }

    /// Names the trial's picture (PNG) in its row.
    pub fn set_picture(&mut self, id: TrialId, path: &Path) -> Result<(), TrialError> {
        self.update_one(
            id,
            "record picture",
            "UPDATE trials SET picture_path = ?2 WHERE id = ?1",
            params![id, path.to_string_lossy().into_owned()],
        )
    }

    /// The picture named in trial `id`'s row, if any.
    pub fn picture_path(&self, id: TrialId) -> Result<Option<PathBuf>, TrialError> {
        let path: Option<Option<String>> = self
            .conn
            .query_row(
                "SELECT picture_path FROM trials WHERE id = ?1",
                [id],
                |row| row.get(0),
            )
            .optional()
            .map_err(self.sql_err("read picture path"))?;
        match path {
            Some(p) => Ok(p.map(PathBuf::from)),
            None => Err(TrialError::UnknownTrial {
                path: self.path.clone(),
                id,
            }),
        }
    }

    /// The trial with id `id`.
    pub fn trial(&self, id: TrialId) -> Result<TrialRecord, TrialError> {
        let sql = format!("SELECT {TRIAL_COLUMNS} FROM trials WHERE id = ?1");
        let raw = self
            .conn
            .query_row(&sql, [id], RawRow::read)
            .optional()
            .map_err(self.sql_err("read trial"))?;
        match raw {
            Some(raw) => raw.decode(&self.path),
            None => Err(TrialError::UnknownTrial {
                path: self.path.clone(),
                id,
            }),
        }
    }

    /// Every trial, in id order.
    pub fn trials(&self) -> Result<Vec<TrialRecord>, TrialError> {
        let sql = format!("SELECT {TRIAL_COLUMNS} FROM trials ORDER BY id");
        let mut stmt = self
            .conn
            .prepare(&sql)
            .map_err(self.sql_err("read trials"))?;
        let raws: Vec<RawRow> = stmt
            .query_map([], RawRow::read)
            .and_then(|rows| rows.collect())
            .map_err(self.sql_err("read trials"))?;
        raws.into_iter().map(|raw| raw.decode(&self.path)).collect()
    }

    /// Number of trials in the log.
    pub fn trial_count(&self) -> Result<u64, TrialError> {
        self.conn
            .query_row("SELECT COUNT(*) FROM trials", [], |row| row.get(0))
            .map_err(self.sql_err("count trials"))
    }
}

fn to_json<T: Serialize + ?Sized>(value: &T) -> String {
    // Serialising these types (plain data, finite numbers checked) cannot fail.
    serde_json::to_string(value).unwrap_or_else(|_| "null".to_string())
}

fn pose_numbers(pose: &PoseJson) -> impl Iterator<Item = f64> + '_ {
    pose.xyz
        .iter()
        .chain(pose.rpy.iter().flatten())
        .chain(pose.quat_xyzw.iter().flatten())
        .copied()
}

fn check_finite_field(
    field: &'static str,
    mut values: impl Iterator<Item = f64>,
) -> Result<(), TrialError> {
    match values.find(|v| !v.is_finite()) {
        Some(v) => Err(TrialError::InvalidTrial {
            field,
            detail: format!("non-finite number {v}"),
        }),
        None => Ok(()),
    }
}

fn json_numbers_finite(value: &serde_json::Value) -> bool {
    match value {
        serde_json::Value::Number(n) => n.as_f64().is_none_or(f64::is_finite),
        serde_json::Value::Array(items) => items.iter().all(json_numbers_finite),
        serde_json::Value::Object(map) => map.values().all(json_numbers_finite),
        _ => true,
    }
}

fn validate_trial(trial: &NewTrial) -> Result<(), TrialError> {
    for (field, text) in [
        ("category", &trial.category),
        ("task", &trial.task),
        ("method", &trial.method),
        ("object.name", &trial.object.name),
    ] {
        if text.trim().is_empty() {
            return Err(TrialError::InvalidTrial {
                field,
                detail: "empty".to_string(),
            });
        }
    }
    check_finite_field("placement", pose_numbers(&trial.placement.base_from_object))?;
    if let Some(pose) = &trial.planned_pose {
        check_finite_field("planned_pose", pose_numbers(pose))?;
    }
    if let Some(joints) = &trial.planned_joints {
        check_finite_field("planned_joints", joints.iter().copied())?;
    }
    for (field, value) in [
        ("fits", Some(&trial.fits)),
        ("outcome", trial.outcome.as_ref()),
    ] {
        if value.is_some_and(|v| !json_numbers_finite(v)) {
            return Err(TrialError::InvalidTrial {
                field,
                detail: "non-finite number".to_string(),
            });
        }
    }
    Ok(())
}

/// Columns read for a [`TrialRecord`], in [`RawRow::read`]'s order.
const TRIAL_COLUMNS: &str = "id, started_at, category, task, method, object_name, object_seed, \
     placement_index, placement_pose, campaign_id, snapshot_path, fits, planned_pose, \
     planned_joints, outcome, grade, failure_cause, observer_note, graded_at, grade_source, \
     software_version, seeds";

/// A trial row as SQLite stores it, before decoding.
struct RawRow {
    id: TrialId,
    started_at: String,
    category: String,
    task: String,
    method: String,
    object_name: String,
    object_seed: Option<String>,
    placement_index: i64,
    placement_pose: String,
    campaign_id: Option<String>,
    snapshot_path: Option<String>,
    fits: String,
    planned_pose: Option<String>,
    planned_joints: Option<String>,
    outcome: Option<String>,
    grade: Option<String>,
    failure_cause: Option<String>,
    observer_note: Option<String>,
    graded_at: Option<String>,
    grade_source: Option<String>,
    software_version: String,
    seeds: String,
}

impl RawRow {
    fn read(row: &rusqlite::Row<'_>) -> rusqlite::Result<Self> {
        Ok(RawRow {
            id: row.get(0)?,
            started_at: row.get(1)?,
            category: row.get(2)?,
            task: row.get(3)?,
            method: row.get(4)?,
            object_name: row.get(5)?,
            object_seed: row.get(6)?,
            placement_index: row.get(7)?,
            placement_pose: row.get(8)?,
            campaign_id: row.get(9)?,
            snapshot_path: row.get(10)?,
            fits: row.get(11)?,
            planned_pose: row.get(12)?,
            planned_joints: row.get(13)?,
            outcome: row.get(14)?,
            grade: row.get(15)?,
            failure_cause: row.get(16)?,
            observer_note: row.get(17)?,
            graded_at: row.get(18)?,
            grade_source: row.get(19)?,
            software_version: row.get(20)?,
            seeds: row.get(21)?,
        })
    }

    fn decode(self, path: &Path) -> Result<TrialRecord, TrialError> {
        let id = self.id;
        let bad = |field: &'static str, detail: String| TrialError::BadRow {
            path: path.to_path_buf(),
            id,
            field,
            detail,
        };
        fn json<T: serde::de::DeserializeOwned>(
            text: &str,
            field: &'static str,
            bad: &impl Fn(&'static str, String) -> TrialError,
        ) -> Result<T, TrialError> {
            serde_json::from_str(text).map_err(|e| bad(field, e.to_string()))
        }
        fn opt_json<T: serde::de::DeserializeOwned>(
            text: Option<String>,
            field: &'static str,
            bad: &impl Fn(&'static str, String) -> TrialError,
        ) -> Result<Option<T>, TrialError> {
            text.map(|t| json(&t, field, bad)).transpose()
        }
        let started_at = self
            .started_at
            .parse()
            .map_err(|e: TrialError| bad("started_at", e.to_string()))?;
        let object_seed = self
            .object_seed
            .map(|s| {
                s.parse::<u64>()
                    .map_err(|e| bad("object_seed", format!("{s:?}: {e}")))
            })
            .transpose()?;
        let placement_index = u32::try_from(self.placement_index)
            .map_err(|_| bad("placement_index", self.placement_index.to_string()))?;
        let grade = self
            .grade
            .map(|g| g.parse::<Grade>().map_err(|e| bad("grade", e.to_string())))
            .transpose()?;
        let cause = self
            .failure_cause
            .map(|c| {
                c.parse::<FailureCause>()
                    .map_err(|e| bad("failure_cause", e.to_string()))
            })
            .transpose()?;
        let grading = grade
            .map(|g| {
                Grading::new(g, cause, self.observer_note).map_err(|e| bad("grade", e.to_string()))
            })
            .transpose()?;
        let graded_at = self
            .graded_at
            .map(|t| {
                t.parse()
                    .map_err(|e: TrialError| bad("graded_at", e.to_string()))
            })
            .transpose()?;
        let grade_source = self
            .grade_source
            .map(|s| {
                s.parse()
                    .map_err(|e: TrialError| bad("grade_source", e.to_string()))
            })
            .transpose()?;
        Ok(TrialRecord {
            id,
            trial: NewTrial {
                started_at,
                category: self.category,
                task: self.task,
                method: self.method,
                object: ObjectRef {
                    name: self.object_name,
                    seed: object_seed,
                },
                placement: Placement {
                    index: placement_index,
                    base_from_object: json(&self.placement_pose, "placement_pose", &bad)?,
                },
                campaign_id: self.campaign_id,
                snapshot_path: self.snapshot_path.map(PathBuf::from),
                fits: json(&self.fits, "fits", &bad)?,
                planned_pose: opt_json(self.planned_pose, "planned_pose", &bad)?,
                planned_joints: opt_json(self.planned_joints, "planned_joints", &bad)?,
                outcome: opt_json(self.outcome, "outcome", &bad)?,
                seeds: json(&self.seeds, "seeds", &bad)?,
            },
            software_version: self.software_version,
            grading,
            graded_at,
            grade_source,
        })
    }
}

/// Inserts one trial row; returns its id.
fn insert_trial(
    tx: &Transaction<'_>,
    path: &Path,
    trial: &NewTrial,
) -> Result<TrialId, TrialError> {
    tx.execute(
        "INSERT INTO trials (started_at, category, task, method, object_name, object_seed,
             placement_index, placement_pose, campaign_id, snapshot_path, fits,
             planned_pose, planned_joints, outcome, software_version, seeds)
         VALUES (?1, ?2, ?3, ?4, ?5, ?6, ?7, ?8, ?9, ?10, ?11, ?12, ?13, ?14, ?15, ?16)",
        params![
            trial.started_at.to_string(),
            trial.category,
            trial.task,
            trial.method,
            trial.object.name,
            trial.object.seed.map(|s| s.to_string()),
            trial.placement.index,
            to_json(&trial.placement.base_from_object),
            trial.campaign_id,
            trial
                .snapshot_path
                .as_ref()
                .map(|p| p.to_string_lossy().into_owned()),
            to_json(&trial.fits),
            trial.planned_pose.as_ref().map(to_json),
            trial.planned_joints.as_ref().map(to_json),
            trial.outcome.as_ref().map(to_json),
            software_version(),
            to_json(&trial.seeds),
        ],
    )
    .map_err(|source| TrialError::Sqlite {
        path: path.to_path_buf(),
        op: "insert trial",
        source,
    })?;
    Ok(tx.last_insert_rowid())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::fsio::TempDir;

    fn sample_trial() -> NewTrial {
        NewTrial {
            started_at: "2025-03-01T14:05:09.250Z".parse().unwrap(),
            category: "mug".into(),
            task: "pour".into(),
            method: "laplace".into(),
            object: ObjectRef {
                name: "mug-novel-3".into(),
                seed: Some(u64::MAX),
            },
            placement: Placement {
                index: 4,
                base_from_object: PoseJson {
                    xyz: [0.55, -0.1, 0.02],
                    rpy: Some([0.0, 0.0, 1.2]),
                    quat_xyzw: None,
                },
            },
            campaign_id: Some("c-2025-03-01".into()),
            snapshot_path: Some(PathBuf::from("snapshots/t1.pcd")),
            fits: serde_json::json!([{"model": "mug-1", "eps": 0.004, "sigma": 0.01}]),
            planned_pose: None,
            planned_joints: None,
            outcome: None,
            seeds: [("registration".to_string(), 7_u64), ("plan".to_string(), 9)].into(),
        }
    }

    /// A full disk (here a page limit) fails the write of a graded trial as a
    /// whole: no row, no grade; once there is room, the same write succeeds once.
    #[test]
    fn a_graded_trial_is_recorded_whole_or_not_at_all() {
        let dir = TempDir::new("full").unwrap();
        let mut log = TrialLog::open(dir.join("trials.sqlite")).unwrap();
        let grading =
            super::super::grade::Grading::new(super::super::grade::Grade::Success, None, None)
                .unwrap();
        let source = super::super::grade::GradeSource::Simulated;
        let at: UtcTimestamp = "2025-03-01T14:06:00Z".parse().unwrap();
        let pages: i64 = log
            .conn
            .query_row("PRAGMA page_count", [], |r| r.get(0))
            .unwrap();
        log.conn
            .query_row(&format!("PRAGMA max_page_count = {pages}"), [], |_| Ok(()))
            .unwrap();
        let mut big = sample_trial();
        big.outcome = Some(serde_json::json!({ "note": "x".repeat(64 * 1024) }));
        let err = log
            .record_graded_trial(&big, &grading, source, at)
            .unwrap_err()
            .to_string();
        assert!(
            err.contains("trials.sqlite") && err.contains("full"),
            "{err}"
        );
        assert_eq!(log.trial_count().unwrap(), 0);
        log.conn
            .query_row("PRAGMA max_page_count = 1000000", [], |_| Ok(()))
            .unwrap();
        let id = log.record_graded_trial(&big, &grading, source, at).unwrap();
        assert_eq!(log.trial_count().unwrap(), 1);
        assert_eq!(log.grade_history(id).unwrap().len(), 1);
    }

    #[test]
    fn records_and_reads_back_every_field() {
        let dir = TempDir::new("roundtrip").unwrap();
        let path = dir.join("sub/trials.sqlite");
        let mut log = TrialLog::open(&path).unwrap();
        assert_eq!(log.schema_version().unwrap(), SCHEMA_VERSION);
        let mode: String = log
            .conn
            .pragma_query_value(None, "journal_mode", |r| r.get(0))
            .unwrap();
        assert_eq!(mode, "wal");
        let sync: i64 = log
            .conn
            .pragma_query_value(None, "synchronous", |r| r.get(0))
            .unwrap();
        assert_eq!(sync, 2, "synchronous=FULL");
        let trial = sample_trial();
        let id = log.record_trial(&trial).unwrap();
        let pose = PoseJson {
            xyz: [0.5, 0.0, 0.3],
            rpy: Some([3.1, 0.0, 0.0]),
            quat_xyzw: None,
        };
        log.set_plan(id, &pose, &[0.1, -0.2, 0.3, 1.4, 0.0, -0.5, 0.6])
            .unwrap();
        log.set_outcome(id, &serde_json::json!({"lifted": true, "hold_s": 2.0}))
            .unwrap();
        drop(log);

        let log = TrialLog::open_existing(&path).unwrap();
        let got = log.trial(id).unwrap();
        let mut want = trial;
        want.planned_pose = Some(pose);
        want.planned_joints = Some(vec![0.1, -0.2, 0.3, 1.4, 0.0, -0.5, 0.6]);
        want.outcome = Some(serde_json::json!({"lifted": true, "hold_s": 2.0}));
        assert_eq!(got.trial, want);
        assert_eq!(got.software_version, software_version());
        assert_eq!(got.grading, None);
        assert_eq!(log.trials().unwrap().len(), 1);
        drop(log);
        // Opening and reading an up-to-date log writes nothing.
        let before = std::fs::read(&path).unwrap();
        let log = TrialLog::open(&path).unwrap();
        assert_eq!(log.trial(id).unwrap().trial, want);
        drop(log);
        assert_eq!(std::fs::read(&path).unwrap(), before);
        let log = TrialLog::open_existing(&path).unwrap();
        assert!(matches!(
            log.trial(id + 1),
            Err(TrialError::UnknownTrial { id: i, .. }) if i == id + 1
        ));
    }

    #[test]
    fn updates_of_unknown_trials_and_invalid_trials_are_refused() {
        let dir = TempDir::new("invalid").unwrap();
        let mut log = TrialLog::open(dir.join("t.sqlite")).unwrap();
        assert!(matches!(
            log.set_outcome(42, &serde_json::Value::Null),
            Err(TrialError::UnknownTrial { id: 42, .. })
        ));
        let mut t = sample_trial();
        t.method = " ".into();
        assert!(matches!(
            log.record_trial(&t),
            Err(TrialError::InvalidTrial {
                field: "method",
                ..
            })
        ));
        let mut t = sample_trial();
        t.placement.base_from_object.xyz[1] = f64::NAN;
        assert!(matches!(
            log.record_trial(&t),
            Err(TrialError::InvalidTrial {
                field: "placement",
                ..
            })
        ));
        assert_eq!(log.trial_count().unwrap(), 0);
    }

    const FAKE: [Migration; 2] = [
        Migration {
            version: 1,
            description: "a",
            sql: "CREATE TABLE a (x INTEGER);",
        },
        Migration {
            version: 2,
            description: "a.y",
            sql: "ALTER TABLE a ADD COLUMN y TEXT; INSERT INTO a (x, y) VALUES (1, 'migrated');",
        },
    ];

    #[test]
    fn migrations_apply_in_order_once_and_refuse_newer_files() {
        let dir = TempDir::new("migrate").unwrap();
        let path = dir.join("m.sqlite");
        let create = OpenFlags::SQLITE_OPEN_CREATE;
        let log = TrialLog::open_with(&path, create, &FAKE[..1]).unwrap();
        assert_eq!(log.schema_version().unwrap(), 1);
        drop(log);
        for _ in 0..2 {
            let log = TrialLog::open_with(&path, create, &FAKE).unwrap();
            assert_eq!(log.schema_version().unwrap(), 2);
            let rows: i64 = log
                .conn
                .query_row("SELECT COUNT(*) FROM a WHERE y = 'migrated'", [], |r| {
                    r.get(0)
                })
                .unwrap();
            assert_eq!(rows, 1, "the v2 migration ran exactly once");
            let versions: i64 = log
                .conn
                .query_row("SELECT COUNT(*) FROM schema_version", [], |r| r.get(0))
                .unwrap();
            assert_eq!(versions, 2);
        }
        let before = std::fs::read(&path).unwrap();
        match TrialLog::open_with(&path, create, &FAKE[..1]) {
            Err(TrialError::NewerSchema {
                found: 2,
                supported: 1,
                ..
            }) => {}
            other => panic!("{other:?}"),
        }
        assert_eq!(std::fs::read(&path).unwrap(), before);
    }

    #[test]
    fn a_version_1_log_gains_the_picture_column_and_keeps_its_trials() {
        let dir = TempDir::new("picture-migration").unwrap();
        let path = dir.join("v1.sqlite");
        let create = OpenFlags::SQLITE_OPEN_CREATE;
        let mut log = TrialLog::open_with(&path, create, &MIGRATIONS[..1]).unwrap();
        let id = log.record_trial(&sample_trial()).unwrap();
        drop(log);
        let mut log = TrialLog::open_existing(&path).unwrap();
        assert_eq!(log.schema_version().unwrap(), 2);
        assert_eq!(log.trial(id).unwrap().trial, sample_trial());
        assert_eq!(log.picture_path(id).unwrap(), None);
        log.set_picture(id, Path::new("pictures/1.png")).unwrap();
        assert_eq!(
            log.picture_path(id).unwrap(),
            Some(PathBuf::from("pictures/1.png"))
        );
        assert!(matches!(
            log.set_picture(id + 1, Path::new("x.png")),
            Err(TrialError::UnknownTrial { .. })
        ));
    }

    #[test]
    fn other_sqlite_databases_are_refused_and_left_alone() {
        let dir = TempDir::new("foreign").unwrap();
        let path = dir.join("other.sqlite");
        {
            let conn = Connection::open(&path).unwrap();
            conn.execute_batch(
                "CREATE TABLE photos (id INTEGER, name TEXT); INSERT INTO photos VALUES (1, 'x');",
            )
            .unwrap();
        }
        let before = std::fs::read(&path).unwrap();
        let err = TrialLog::open(&path).unwrap_err();
        assert!(matches!(err, TrialError::ForeignSchema { .. }), "{err:?}");
        let msg = err.to_string();
        assert!(
            msg.contains("other.sqlite") && msg.contains("photos"),
            "{msg}"
        );
        assert_eq!(std::fs::read(&path).unwrap(), before);
        assert!(matches!(
            TrialLog::open_existing(dir.join("absent.sqlite")),
            Err(TrialError::Missing { .. })
        ));
        assert!(!dir.join("absent.sqlite").exists());
    }
}
