//! Cross-category generalisation (the paper's §5, Table 1): the database of one
//! category (hammers, `use` grasps by the handle) plans grasps on the objects of
//! another (knives); per test object, the epsilon of our grasp with each kernel and
//! of best single.

use super::experiment::{
    run_target, steps_per_target, Registrar, RegistrationStats, Setup, Target, TargetReport,
    Training,
};
use super::loo::{tally_rows, TallyRow};
use super::view::ViewKind;
use super::{check_request, EvalError};
use crate::category::CategoryDb;
use crate::plan::Kernel;
use rayon::prelude::*;
use serde::Serialize;

/// One line of Table 1: a test object (at one placement) and task.
#[derive(Debug, Clone, Serialize)]
pub struct CrossRow {
    /// The test object.
    pub target: String,
    /// Its placement (0-based).
    pub placement: usize,
    /// The task.
    pub task: String,
    /// Epsilon of our grasp per kernel, in the report's kernel order.
    pub epsilon: Vec<(String, f64)>,
    /// Epsilon of best single.
    pub epsilon_single: f64,
    /// The training model best single took its grasp from.
    pub best_single_model: String,
}

/// The result of a cross-category experiment.
#[derive(Debug, Clone, Serialize)]
pub struct CrossReport {
    /// Training category.
    pub train_category: String,
    /// Training database directory.
    pub train: String,
    /// Test category.
    pub test_category: String,
    /// Test database directory (its meshes are the test objects).
    pub test: String,
    /// Complete or partial views.
    pub view: ViewKind,
    /// The tasks run (the training database's).
    pub tasks: Vec<String>,
    /// The kernels run.
    pub kernels: Vec<Kernel>,
    /// Epsilon difference under which grasps count as equal.
    pub equal_tolerance: f64,
    /// Whether the arm's reachability constrained the grasps.
    pub reachability: bool,
    /// The paper's scoring: no retreat, collisions score −1.
    pub paper: bool,
    /// The seed.
    pub seed: u64,
    /// Placements of each test object.
    pub placements: usize,
    /// Table 1: one row per test object and task that ran.
    pub table: Vec<CrossRow>,
    /// Better / equal / worse per task and kernel.
    pub rows: Vec<TallyRow>,
    /// Tasks or targets that could not run.
    pub skipped: usize,
    /// How well the training models registered to the targets.
    pub registration: RegistrationStats,
    /// Per target: pose, fits, every run.
    pub targets: Vec<TargetReport>,
}

/// Runs every model of `test` as a target against the models of `train`.
pub fn cross_category(
    setup: &Setup,
    train: &CategoryDb,
    test: &CategoryDb,
    tasks: &[String],
    kernels: &[Kernel],
    registrar: &dyn Registrar,
    progress: Option<&indicatif::ProgressBar>,
) -> Result<CrossReport, EvalError> {
    setup.validate()?;
    if test.file.models.is_empty() {
        return Err(EvalError::EmptyDatabase {
            database: test.dir.display().to_string(),
        });
    }
    let tasks = check_request(train, tasks, kernels)?;
    if let Some(p) = progress {
        p.set_length(
            (test.file.models.len() * setup.placements) as u64
                * steps_per_target(tasks.len(), kernels.len()),
        );
    }
    let n = test.file.models.len();
    // Placement-major: the first placement of every model gets the same seeds
    // whatever the number of placements.
    let targets: Vec<TargetReport> = (0..n * setup.placements)
        .into_par_iter()
        .map(|ordinal| {
            let index = ordinal % n;
            let target = Target {
                db: test,
                index,
                ordinal: ordinal as u64,
            };
            let training = Training {
                db: train,
                exclude: None,
                registrar,
            };
            run_target(setup, target, &training, &tasks, kernels, progress)
        })
        .collect::<Result<_, _>>()?;
    let mut table = Vec::new();
    for t in &targets {
        for task in &tasks {
            let runs: Vec<_> = t.runs.iter().filter(|r| &r.task == task).collect();
            let Some(first) = runs.first() else { continue };
            table.push(CrossRow {
                target: t.target.clone(),
                placement: t.placement,
                task: task.clone(),
                epsilon: runs
                    .iter()
                    .map(|r| (r.kernel.to_string(), r.epsilon))
                    .collect(),
                epsilon_single: first.epsilon_single,
                best_single_model: first.best_single_model.clone(),
            });
        }
    }
    Ok(CrossReport {
        train_category: train.file.category.name().to_string(),
        train: train.dir.display().to_string(),
        test_category: test.file.category.name().to_string(),
        test: test.dir.display().to_string(),
        view: setup.view,
        rows: tally_rows(&targets, &tasks, kernels, setup.equal_tolerance),
        skipped: targets.iter().map(|t| t.skipped.len()).sum(),
        registration: RegistrationStats::of(&targets),
        table,
        tasks,
        kernels: kernels.to_vec(),
        equal_tolerance: setup.equal_tolerance,
        reachability: setup.reach.is_some(),
        paper: setup.paper,
        seed: setup.seed,
        placements: setup.placements,
        targets,
    })
}
