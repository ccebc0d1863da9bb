//! The paper's simulation experiments (Nikandrova & Kyrki 2015, §5; issue 6):
//! leave-one-out over a category and cross-category generalisation, each grasp run
//! in the grasp simulator on the test object and compared with best single.
//!
//! - [`view`]: the test object's seeded placement on the table and its view
//!   (complete cloud or the sim camera's partial view).
//! - [`outcome`]: a planned palm pose simulated on the test object at its true pose
//!   (approach until clear, auto-grasp, Ferrari–Canny epsilon).
//! - [`compare`]: better / equal / worse against best single, and tallies.
//! - [`experiment`]: one target end to end (view, registration, planning per task
//!   and kernel, simulation); registration is a [`Registrar`].
//! - [`loo`]: leave-one-out (Figures 5 and 6); [`cross`]: cross-category (Table 1).
//! - [`handle`]: whether a mug's handle is in the view (its yaw error is judged).
//! - [`novel`]: the end-to-end novel-object experiment through the cell's chain
//!   (camera, perception, planning, execution with the lab's errors, observer);
//!   [`objects`]: a user's own meshes for it (a directory with `objects.toml`).
//! - [`chart`]: the better / equal / worse bar chart as PNG, and the observer's
//!   grades of the novel-object experiment.
//! - [`registration`]: the category's registration ([`crate::register`]) as the
//!   experiments' [`Registrar`].
//!
//! `cell eval loo`, `cell eval cross` and `cell eval novel` run them from the
//! command line.

pub mod chart;
pub mod compare;
pub mod cross;
pub mod experiment;
pub mod handle;
pub mod loo;
pub mod novel;
pub mod objects;
pub mod outcome;
pub mod registration;
pub mod view;

pub use compare::{Tally, Verdict, DEFAULT_EQUAL_TOLERANCE};
pub use cross::{cross_category, CrossReport};
pub use experiment::{Registrar, RunRecord, Setup, TargetReport};
pub use loo::{leave_one_out, LooReport};
pub use registration::CategoryRegistrar;
pub use view::{PlacementRegion, ViewKind};

use crate::category::CategoryDb;
use crate::plan::{Kernel, PlanError};
use crate::quality::autograsp::GraspSimError;

/// Errors of the experiments; each names the database, target or option at fault.
#[derive(Debug, thiserror::Error)]
pub enum EvalError {
    /// The database has no models.
    #[error("{database}: the database has no models")]
    EmptyDatabase {
        /// The database directory.
        database: String,
    },
    /// Leave-one-out needs a model to hold out and one to learn from.
    #[error("{database}: leave-one-out needs at least 2 models, the database has {count}")]
    TooFewModels {
        /// The database directory.
        database: String,
        /// Its model count.
        count: usize,
    },
    /// A requested task has no example grasp in the database.
    #[error("{database}: no example grasp for task {task:?} (tasks with grasps: {available})")]
    NoTaskGrasps {
        /// The database directory.
        database: String,
        /// The task.
        task: String,
        /// The tasks that have grasps, comma-separated.
        available: String,
    },
    /// No kernel was requested.
    #[error("no kernel to evaluate")]
    NoKernels,
    /// A model named on the command line is not in the database.
    #[error("{database}: no model named {name:?} (models: {available})")]
    UnknownModel {
        /// The database directory.
        database: String,
        /// The name asked for.
        name: String,
        /// The database's models, comma-separated.
        available: String,
    },
    /// An option is out of range.
    #[error("{what} = {value}: {problem}")]
    Option {
        /// The option.
        what: String,
        /// Its value.
        value: f64,
        /// What is wrong.
        problem: &'static str,
    },
    /// The target's view could not be made.
    #[error("target {target}: view: {problem}")]
    View {
        /// The test object.
        target: String,
        /// What went wrong.
        problem: String,
    },
    /// Planning failed on bad input (not a missing task or registration).
    #[error("target {target}, task {task}, kernel {kernel}: {source}")]
    Plan {
        /// The test object.
        target: String,
        /// The task.
        task: String,
        /// The kernel (`-` before any kernel ran).
        kernel: &'static str,
        /// The planner's error.
        source: PlanError,
    },
    /// The grasp simulator failed.
    #[error("target {target}: grasp simulation: {source}")]
    Simulation {
        /// The test object.
        target: String,
        /// The simulator's error.
        source: GraspSimError,
    },
    /// The chart could not be written.
    #[error("chart: {0}")]
    Chart(#[from] crate::trial::TrialError),
}

/// The tasks to run (`tasks`, or every task of `db` when empty), each checked to have
/// example grasps in `db`; and at least one kernel.
pub fn check_request(
    db: &CategoryDb,
    tasks: &[String],
    kernels: &[Kernel],
) -> Result<Vec<String>, EvalError> {
    let database = db.dir.display().to_string();
    if db.file.models.is_empty() {
        return Err(EvalError::EmptyDatabase { database });
    }
    if kernels.is_empty() {
        return Err(EvalError::NoKernels);
    }
    let mut available: Vec<&str> = db.file.grasps.iter().map(|g| g.task.as_str()).collect();
    available.sort_unstable();
    available.dedup();
    let tasks: Vec<String> = if tasks.is_empty() {
        db.file.tasks.clone()
    } else {
        tasks.to_vec()
    };
    for task in &tasks {
        if !available.contains(&task.as_str()) {
            return Err(EvalError::NoTaskGrasps {
                database,
                task: task.clone(),
                available: if available.is_empty() {
                    "none".into()
                } else {
                    available.join(", ")
                },
            });
        }
    }
    Ok(tasks)
}

/// `db` restricted to the models named in `names` (in the database's order) and
/// their grasps: a quick experiment on a few models.
pub fn subset(db: &CategoryDb, names: &[String]) -> Result<CategoryDb, EvalError> {
    for name in names {
        if db.model_index(name).is_none() {
            return Err(EvalError::UnknownModel {
                database: db.dir.display().to_string(),
                name: name.clone(),
                available: db
                    .file
                    .models
                    .iter()
                    .map(|m| m.name.as_str())
                    .collect::<Vec<_>>()
                    .join(", "),
            });
        }
    }
    let keep: Vec<usize> = (0..db.file.models.len())
        .filter(|&i| names.contains(&db.file.models[i].name))
        .collect();
    let mut out = db.clone();
    out.file.models = keep.iter().map(|&i| db.file.models[i].clone()).collect();
    out.meshes = keep.iter().map(|&i| db.meshes[i].clone()).collect();
    out.file.grasps.retain(|g| names.contains(&g.model));
    Ok(out)
}
