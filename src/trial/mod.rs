//! The trial log: every grasp the cell attempts, the observer's grade, and the report.
//!
//! The paper's robot protocol (specs/method.md, "The paper's results"): an observer
//! grades each grasp success (+1) / partial (0) / failure (-1), failures are
//! attributed to a cause, and methods are compared by a sign test paired trial by
//! trial (same object, same placement). This module is that protocol's durable record:
//!
//! - [`log`]: the SQLite trial log (WAL, `synchronous=FULL`, schema versions), one
//!   row per trial; every write is one transaction, so a crash loses no committed
//!   trial or grade.
//! - [`grade`]: grades and failure causes, grading with history, the terminal prompt.
//! - [`stats`]: the exact two-sided paired sign test.
//! - [`report`]: rates per method, failure causes as a share of all trials (the
//!   paper's Table 2), pairwise sign tests.
//! - [`plot`]: the report's bar charts as PNG.
//! - [`csv`]: grades kept on paper in and out as CSV.
//! - [`time`]: UTC timestamps in ISO-8601.
//! - [`picture`], [`scene`], [`glb`]: the picture of a trial (camera and side
//!   views) and its 3-D scene as binary glTF.

pub mod csv;
pub mod glb;
pub mod grade;
pub mod log;
pub mod paper;
pub mod picture;
pub mod plot;
pub mod report;
pub mod scene;
pub mod stats;
pub mod time;

pub use grade::{prompt_grade, FailureCause, Grade, GradeEvent, GradeSource, Grading};
pub use log::{NewTrial, ObjectRef, Placement, TrialId, TrialLog, TrialRecord};
pub use report::{Report, Scope};
pub use stats::{sign_test, sign_test_p_value, SignTest};
pub use time::UtcTimestamp;

use crate::fsio::FileError;
use std::path::PathBuf;

/// Errors of the trial log, grading, import/export and reports.
#[derive(Debug, thiserror::Error)]
pub enum TrialError {
    /// The file exists but does not start with the SQLite header.
    #[error("{path}: not an SQLite database ({detail}); the file was left untouched")]
    NotSqlite {
        /// The log file.
        path: PathBuf,
        /// What was found instead.
        detail: String,
    },
    /// The file is an SQLite database, but not a graspcell trial log.
    #[error("{path}: an SQLite database but not a graspcell trial log ({detail}); the file was left untouched")]
    ForeignSchema {
        /// The log file.
        path: PathBuf,
        /// What was found.
        detail: String,
    },
    /// The log was written by a newer graspcell with a schema this one does not know.
    #[error("{path}: trial log schema version {found} is newer than this software supports ({supported}); the file was left untouched")]
    NewerSchema {
        /// The log file.
        path: PathBuf,
        /// Version in the file.
        found: i64,
        /// Newest version this build knows.
        supported: i64,
    },
    /// SQLite reports the database as damaged.
    #[error("{path}: trial log is corrupt ({detail}); the file was left untouched")]
    Corrupt {
        /// The log file.
        path: PathBuf,
        /// SQLite's diagnosis.
        detail: String,
    },
    /// No log file where one was expected.
    #[error("{path}: no trial log here (record trials first, or pass --log FILE)")]
    Missing {
        /// The path that was looked at.
        path: PathBuf,
    },
    /// An SQLite call failed.
    #[error("{path}: {op}: {source}")]
    Sqlite {
        /// The log file.
        path: PathBuf,
        /// What was being done.
        op: &'static str,
        /// The SQLite error.
        source: rusqlite::Error,
    },
    /// A file could not be read or written.
    #[error(transparent)]
    File(#[from] FileError),
    /// A grade refers to a trial id that is not in the log.
    #[error("{path}: no trial with id {id} in the log")]
    UnknownTrial {
        /// The log file.
        path: PathBuf,
        /// The id asked for.
        id: TrialId,
    },
    /// A grade string that is none of success / partial / failure.
    #[error("invalid grade {text:?} (expected success, partial or failure)")]
    InvalidGrade {
        /// The text given.
        text: String,
    },
    /// A failure-cause string that is not one of the causes.
    #[error("invalid failure cause {text:?} (expected reachability, registration, shape-dissimilarity, execution or other)")]
    InvalidCause {
        /// The text given.
        text: String,
    },
    /// A grade-source string that is not observer, command, import or simulated.
    #[error("invalid grade source {text:?} (expected observer, command, import or simulated)")]
    InvalidGradeSource {
        /// The text given.
        text: String,
    },
    /// A failure was graded without naming its cause.
    #[error("a failure needs a cause (reachability, registration, shape-dissimilarity, execution or other)")]
    CauseRequired,
    /// A success was graded with a failure cause.
    #[error("a success has no failure cause (got {cause})")]
    CauseOnSuccess {
        /// The cause given.
        cause: FailureCause,
    },
    /// A timestamp that is not `YYYY-MM-DDTHH:MM:SS[.fff]Z`.
    #[error("invalid UTC timestamp {text:?} (expected YYYY-MM-DDTHH:MM:SS[.fff]Z)")]
    BadTimestamp {
        /// The text given.
        text: String,
    },
    /// A trial to record with a missing or invalid field.
    #[error("invalid trial: {field}: {detail}")]
    InvalidTrial {
        /// The field.
        field: &'static str,
        /// What is wrong.
        detail: String,
    },
    /// A stored trial row whose field does not decode.
    #[error("{path}: trial {id}: field {field}: {detail}")]
    BadRow {
        /// The log file.
        path: PathBuf,
        /// The trial.
        id: TrialId,
        /// The column.
        field: &'static str,
        /// What is wrong.
        detail: String,
    },
    /// A CSV file with a bad line (1-based line number of the record's start).
    #[error("{path}:{line}: {detail}")]
    Csv {
        /// The CSV file.
        path: PathBuf,
        /// Line number where the bad record starts.
        line: usize,
        /// What is wrong.
        detail: String,
    },
    /// The observer's terminal closed before the grade was complete.
    #[error("grading prompt: input ended before the grade was complete")]
    PromptAborted,
    /// The observer's terminal could not be read or written.
    #[error("grading prompt: {0}")]
    PromptIo(std::io::Error),
    /// A glTF document could not be written.
    #[error("{path}: glTF: {detail}")]
    Glb {
        /// The GLB file.
        path: PathBuf,
        /// What failed.
        detail: String,
    },
    /// A PNG could not be encoded.
    #[error("{path}: PNG encoding: {detail}")]
    Png {
        /// The image file.
        path: PathBuf,
        /// The encoder's message.
        detail: String,
    },
}

/// The software version written into every trial: the crate version, plus the
/// `git describe` string when the build environment set `GRASPCELL_GIT_DESCRIBE`.
pub fn software_version() -> String {
    match option_env!("GRASPCELL_GIT_DESCRIBE") {
        Some(git) if !git.is_empty() => format!("{} ({git})", env!("CARGO_PKG_VERSION")),
        _ => env!("CARGO_PKG_VERSION").to_string(),
    }
}
