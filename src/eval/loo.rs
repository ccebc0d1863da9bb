//! Leave-one-out over a category (the paper's Figures 5 and 6): each model in turn
//! is the test object, the others form the database; per task and kernel, the share
//! of runs where our grasp is better / equal / worse than best single, and the mean
//! epsilons.

use super::compare::{Pair, Tally};
use super::experiment::{
    run_target, steps_per_target, Registrar, RegistrationStats, Setup, Target, TargetReport,
    Training,
};
use super::view::ViewKind;
use super::{check_request, EvalError};
use crate::category::CategoryDb;
use crate::plan::Kernel;
use rayon::prelude::*;
use serde::Serialize;

/// The tally of one task (or `all`) and kernel.
#[derive(Debug, Clone, Serialize)]
pub struct TallyRow {
    /// The task, or `all` over the tasks.
    pub task: String,
    /// The kernel's name.
    pub kernel: &'static str,
    /// Counts and means.
    #[serde(flatten)]
    pub tally: Tally,
    /// Runs where our open hand collided at the grasp (not cleared by the retreat;
    /// in the paper's scoring, every collision).
    pub collisions: usize,
    /// Runs where best single's open hand collided.
    pub collisions_single: usize,
}

/// The result of a leave-one-out experiment.
#[derive(Debug, Clone, Serialize)]
pub struct LooReport {
    /// The database directory.
    pub database: String,
    /// The category.
    pub category: String,
    /// Complete or partial views.
    pub view: ViewKind,
    /// The tasks run.
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
    /// Models in the database (each held out in turn).
    pub models: usize,
    /// Placements of each held-out model.
    pub placements: usize,
    /// Runs simulated (targets x tasks x kernels that ran).
    pub runs: usize,
    /// Tasks or targets that could not run.
    pub skipped: usize,
    /// How well the training models registered to the targets.
    pub registration: RegistrationStats,
    /// One row per task and kernel, then one per kernel over all tasks (`all`).
    pub rows: Vec<TallyRow>,
    /// Per target: pose, fits, every run.
    pub targets: Vec<TargetReport>,
}

/// Tallies of `targets`' runs per task and kernel, then per kernel over all tasks.
pub fn tally_rows(
    targets: &[TargetReport],
    tasks: &[String],
    kernels: &[Kernel],
    tolerance: f64,
) -> Vec<TallyRow> {
    let runs = || targets.iter().flat_map(|t| &t.runs);
    let pairs = |task: Option<&str>, kernel: &str| -> Vec<Pair> {
        runs()
            .filter(|r| r.kernel == kernel && task.is_none_or(|t| r.task == t))
            .map(|r| Pair {
                ours: r.epsilon,
                single: r.epsilon_single,
            })
            .collect()
    };
    let mut rows = Vec::new();
    let mut all_tasks: Vec<Option<&str>> = tasks.iter().map(|t| Some(t.as_str())).collect();
    if tasks.len() > 1 {
        all_tasks.push(None);
    }
    for task in all_tasks {
        for kernel in kernels {
            let of =
                || runs().filter(|r| r.kernel == kernel.name() && task.is_none_or(|t| r.task == t));
            rows.push(TallyRow {
                task: task.unwrap_or("all").to_string(),
                kernel: kernel.name(),
                tally: Tally::of(pairs(task, kernel.name()), tolerance),
                collisions: of().filter(|r| r.ours.retreat_m.is_none()).count(),
                collisions_single: of().filter(|r| r.single.retreat_m.is_none()).count(),
            });
        }
    }
    rows
}

/// Runs leave-one-out over `db` for `tasks` (empty: the database's) and `kernels`;
/// targets run in parallel; `progress` advances per registration and per run.
pub fn leave_one_out(
    setup: &Setup,
    db: &CategoryDb,
    tasks: &[String],
    kernels: &[Kernel],
    registrar: &dyn Registrar,
    progress: Option<&indicatif::ProgressBar>,
) -> Result<LooReport, EvalError> {
    setup.validate()?;
    if db.file.models.len() < 2 {
        return Err(EvalError::TooFewModels {
            database: db.dir.display().to_string(),
            count: db.file.models.len(),
        });
    }
    let tasks = check_request(db, tasks, kernels)?;
    if let Some(p) = progress {
        p.set_length(
            (db.file.models.len() * setup.placements) as u64
                * steps_per_target(tasks.len(), kernels.len()),
        );
    }
    let n = db.file.models.len();
    // Placement-major: the first placement of every model gets the same seeds
    // whatever the number of placements.
    let targets: Vec<TargetReport> = (0..n * setup.placements)
        .into_par_iter()
        .map(|ordinal| {
            let index = ordinal % n;
            let name = &db.file.models[index].name;
            let target = Target {
                db,
                index,
                ordinal: ordinal as u64,
            };
            let training = Training {
                db,
                exclude: Some(name),
                registrar,
            };
            run_target(setup, target, &training, &tasks, kernels, progress)
        })
        .collect::<Result<_, _>>()?;
    Ok(LooReport {
        database: db.dir.display().to_string(),
        category: db.file.category.name().to_string(),
        view: setup.view,
        rows: tally_rows(&targets, &tasks, kernels, setup.equal_tolerance),
        runs: targets.iter().map(|t| t.runs.len()).sum(),
        skipped: targets.iter().map(|t| t.skipped.len()).sum(),
        registration: RegistrationStats::of(&targets),
        tasks,
        kernels: kernels.to_vec(),
        equal_tolerance: setup.equal_tolerance,
        reachability: setup.reach.is_some(),
        paper: setup.paper,
        seed: setup.seed,
        models: n,
        placements: setup.placements,
        targets,
    })
}
