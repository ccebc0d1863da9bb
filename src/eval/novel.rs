//! The end-to-end novel-object experiment (issue 17, item 6): objects the databases
//! never saw stand at seeded placements on the table and go through the cell's own
//! chain, per task and method, as in a campaign but without processes:
//!
//! 1. the simulated camera renders the scene (table and object) from the camera's
//!    *true* mount, which differs from the calibrated one by the lab's hand–eye
//!    error ([`crate::sim::lab`]);
//! 2. perception segments the object and registers every model of the category
//!    ([`crate::cell::perceive::perceive_trial`], with the calibrated mount);
//! 3. the plan stage's planning ([`crate::cell::plan::plan_trial`]: the method, the
//!    table, reachability) and its choice of joints the executor accepts
//!    ([`crate::cell::plan::TrialPlan::executable`]);
//! 4. execution at those joints plus the lab's joint errors;
//! 5. the simulated observer's grade of the grasp on the object's true mesh with
//!    the table ([`crate::sim::observer::Observer::grade`]): success / partial /
//!    failure and the cause, with epsilon (force closure when > 0).
//!
//! Methods are the plan stage's names ([`crate::cell::plan::METHODS`]), an open
//! list: whatever the plan stage accepts, this experiment runs.

use super::objects::UserObject;
use crate::category::CategoryDb;
use crate::cell::perceive::{perceive_trial, register_params};
use crate::cell::plan::{plan_trial, Databases, ExecutorReach, PlanFailure};
use crate::cell::setup::novel_object_in;
use crate::cloud::segment::SegmentParams;
use crate::config::CellConfig;
use crate::execute::{ExecutorConfig, SafetyCheck, SafetyLimits};
use crate::geometry::{pose_error, Pose, PoseJson};
use crate::ipc::{FitStatus, Fits, Protocol, TrialRequest};
use crate::mesh::procedural::held_apart::Family;
use crate::mesh::procedural::{instance_seed, Category};
use crate::mesh::TriMesh;
use crate::plan::PlannedGrasp;
use crate::quality::approach::{approach_to_contact, ApproachOptions};
use crate::quality::autograsp::{open_hand_collision, GraspObject};
use crate::register::{ModelSet, RegisterParams};
use crate::robot::hand::HandModel;
use crate::robot::{HandPose, PreshapeRad, Robot};
use crate::sim::camera::DepthCamera;
use crate::sim::lab::{LabDraw, LabErrors};
use crate::sim::observer::{Agreement, Attempt, Observation, Observer};
use crate::sim::physics::TABLE_GIVE_M;
use crate::sim::scene::{Scene, TableBox};
use crate::trial::{FailureCause, Grade};
use serde::Serialize;
use std::collections::{BTreeMap, HashMap};
use std::path::Path;
use std::sync::Arc;

use super::view::PlacementRegion;

/// Errors of the novel-object experiment; each names what is at fault.
#[derive(Debug, thiserror::Error)]
pub enum NovelError {
    /// An option is out of range.
    #[error("{what}: {problem}")]
    Option {
        /// The option.
        what: String,
        /// What is wrong.
        problem: String,
    },
    /// A category's database or models could not be prepared.
    #[error("category {category}: {problem}")]
    Category {
        /// The category.
        category: String,
        /// What went wrong.
        problem: String,
    },
    /// The cell (robot, observer, scene) failed on an object.
    #[error("object {object}: {problem}")]
    Object {
        /// The object.
        object: String,
        /// What went wrong.
        problem: String,
    },
}

/// A novel object: its mesh and where it came from.
#[derive(Debug, Clone)]
pub struct NovelObject {
    /// Its name.
    pub name: String,
    /// Its category.
    pub category: Category,
    /// `training`, `held-apart` or `file`.
    pub origin: &'static str,
    /// The mesh (object frame).
    pub mesh: TriMesh,
}

impl NovelObject {
    /// Instance `index` of the novel set `set_seed` of `category` in `family`: the
    /// same objects `cell campaign` and `cell demo` draw.
    pub fn procedural(
        family: Family,
        category: Category,
        set_seed: u64,
        index: u64,
        db: &CategoryDb,
    ) -> Result<NovelObject, NovelError> {
        let (object, source) = novel_object_in(family, category, set_seed, index, db);
        let setup = crate::cell::setup::TrialSetup {
            trial_id: 0,
            category,
            object: object.clone(),
            placement: crate::trial::Placement {
                index: 0,
                base_from_object: PoseJson::from(&Pose::identity()),
            },
            campaign_id: None,
            noise_seed: 0,
            perception_seed: 0,
            source,
            lab: None,
        };
        let mesh = setup.mesh().map_err(|e| NovelError::Object {
            object: object.name.clone(),
            problem: e.to_string(),
        })?;
        Ok(NovelObject {
            name: object.name,
            category,
            origin: family.name(),
            mesh,
        })
    }

    /// A user's object ([`super::objects`]).
    pub fn from_user(object: &UserObject) -> NovelObject {
        NovelObject {
            name: object.name.clone(),
            category: object.category,
            origin: "file",
            mesh: object.mesh.clone(),
        }
    }
}

/// What the experiment runs.
#[derive(Debug, Clone)]
pub struct NovelOptions {
    /// Placements of every object.
    pub placements: usize,
    /// Seed of placements, camera noise, registration and the lab's errors.
    pub seed: u64,
    /// The plan stage's methods to compare (e.g. `best-single`, `gaussian-r`,
    /// `laplace`).
    pub methods: Vec<String>,
    /// Only these tasks (empty: every task of each category's database).
    pub tasks: Vec<String>,
    /// The lab's errors.
    pub lab: LabErrors,
    /// The paper's setting: its robot protocol for perception and planning
    /// ([`Protocol::PaperRobot`]: one-sided fit score, poor fits kept, s = b = 700,
    /// no reachability repair for any method), no approach to contact (the hand
    /// closes at the planned pose, see [`executed_palm`]) and collisions of the
    /// open hand fail (the observer's rule) and are counted per method.
    pub paper: bool,
}

/// One task, method, object and placement, as graded.
#[derive(Debug, Clone, Serialize)]
pub struct NovelTrial {
    /// The object.
    pub object: String,
    /// Its category.
    pub category: Category,
    /// `training`, `held-apart` or `file`.
    pub origin: &'static str,
    /// Placement index.
    pub placement: usize,
    /// The object's true pose.
    pub base_from_object: PoseJson,
    /// The task.
    pub task: String,
    /// The method.
    pub method: String,
    /// The observer's grade (the verdict of its mode, physics by default).
    pub grade: Grade,
    /// Its cause of a non-success.
    pub cause: Option<FailureCause>,
    /// The rigid-body lift test's grade.
    pub physics_grade: Grade,
    /// The static (epsilon) grade.
    pub static_grade: Grade,
    /// Ferrari–Canny epsilon of the executed grasp (0: none or not force closure).
    pub epsilon: f64,
    /// Whether the executed grasp is force closure (`epsilon > 0`).
    pub force_closure: bool,
    /// Whether the open hand collides with the object or the table at the executed
    /// palm pose (the paper's "initial collision"); `false` when nothing was executed.
    pub collision: bool,
    /// Whether a grasp was executed (planned, reachable).
    pub executed: bool,
    /// Whether the task can be reached at all at this placement
    /// ([`task_in_reach`]): `false` marks a case the arm cannot do whatever the
    /// planner does (a handle facing away beyond its reach).
    pub task_in_reach: bool,
    /// The observer's note (or the planner's reason).
    pub note: String,
    /// The executed palm pose, when executed.
    pub palm: Option<PoseJson>,
    /// The executed spread (rad), when executed: with `palm`, `preshape_rad` and
    /// the object's pose, `cell quality --object … --pose … --spread …
    /// --preshape-rad … --lift` replays the grade.
    pub spread_rad: Option<f64>,
    /// The executed pre-shape (each finger's flex before the approach, rad), when
    /// executed.
    pub preshape_rad: Option<PreshapeRad>,
    /// Best fit's origin from the object's true origin (mm), when any model registered.
    pub best_fit_offset_mm: Option<f64>,
    /// Planning time of this method (ms).
    pub plan_ms: f64,
    /// How deep the hand went into the table while closing in the lift test (mm,
    /// the median run), when executed: the physics' give at the table
    /// ([`crate::sim::physics::LiftOutcome::table_penetration_m`]).
    pub table_penetration_mm: Option<f64>,
}

/// Counts over a set of trials of one task (or all) and method.
#[derive(Debug, Clone, Serialize)]
pub struct NovelRow {
    /// `category task`, or `all`.
    pub task: String,
    /// The method.
    pub method: String,
    /// Trials.
    pub trials: usize,
    /// Observer's successes.
    pub success: usize,
    /// Observer's partials.
    pub partial: usize,
    /// Observer's failures.
    pub failure: usize,
    /// `success / trials` in percent.
    pub success_pct: f64,
    /// `partial / trials` in percent.
    pub partial_pct: f64,
    /// `failure / trials` in percent.
    pub failure_pct: f64,
    /// Force closure in percent of trials.
    pub force_closure_pct: f64,
    /// Trials whose open hand collided at the executed pose.
    pub collisions: usize,
    /// Mean epsilon.
    pub mean_epsilon: f64,
    /// Non-successes by cause (`reachability`, `registration`, ...).
    pub causes: BTreeMap<String, usize>,
    /// Trials whose task no example grasp reaches at the object's true pose
    /// ([`task_in_reach`]).
    pub out_of_reach: usize,
    /// Observer's successes in percent of the trials whose task is in reach.
    pub success_in_reach_pct: f64,
    /// Successes by the physics verdict, in percent of trials.
    pub physics_success_pct: f64,
    /// Successes by the static (epsilon) verdict, in percent of trials.
    pub static_success_pct: f64,
    /// Physics successes whose hand went [`TABLE_GIVE_M`] or more into the table
    /// while closing.
    pub physics_success_in_table: usize,
    /// The two verdicts side by side (rows physics, columns static).
    pub verdicts: Agreement,
}

impl NovelRow {
    fn of<'a>(task: &str, method: &str, trials: impl Iterator<Item = &'a NovelTrial>) -> NovelRow {
        let mut row = NovelRow {
            task: task.to_string(),
            method: method.to_string(),
            trials: 0,
            success: 0,
            partial: 0,
            failure: 0,
            success_pct: 0.0,
            partial_pct: 0.0,
            failure_pct: 0.0,
            force_closure_pct: 0.0,
            collisions: 0,
            mean_epsilon: 0.0,
            causes: BTreeMap::new(),
            out_of_reach: 0,
            success_in_reach_pct: 0.0,
            physics_success_pct: 0.0,
            static_success_pct: 0.0,
            physics_success_in_table: 0,
            verdicts: Agreement::default(),
        };
        let (mut fc, mut eps, mut physics_ok, mut static_ok) = (0usize, 0.0, 0usize, 0usize);
        let mut success_in_reach = 0usize;
        for t in trials {
            row.trials += 1;
            match t.grade {
                Grade::Success => row.success += 1,
                Grade::Partial => row.partial += 1,
                Grade::Failure => row.failure += 1,
            }
            if let Some(c) = t.cause {
                *row.causes.entry(c.as_str().to_string()).or_default() += 1;
            }
            fc += usize::from(t.force_closure);
            row.collisions += usize::from(t.collision);
            eps += t.epsilon;
            row.verdicts.add(t.physics_grade, t.static_grade);
            physics_ok += usize::from(t.physics_grade == Grade::Success);
            row.physics_success_in_table += usize::from(
                t.physics_grade == Grade::Success
                    && t.table_penetration_mm
                        .is_some_and(|mm| mm >= TABLE_GIVE_M * 1e3),
            );
            row.out_of_reach += usize::from(!t.task_in_reach);
            success_in_reach += usize::from(t.task_in_reach && t.grade == Grade::Success);
            static_ok += usize::from(t.static_grade == Grade::Success);
        }
        if row.trials > 0 {
            let n = row.trials as f64;
            let pct = |k: usize| 100.0 * k as f64 / n;
            row.success_pct = pct(row.success);
            row.partial_pct = pct(row.partial);
            row.failure_pct = pct(row.failure);
            row.force_closure_pct = pct(fc);
            row.mean_epsilon = eps / n;
            row.physics_success_pct = pct(physics_ok);
            let in_reach = row.trials - row.out_of_reach;
            if in_reach > 0 {
                row.success_in_reach_pct = 100.0 * success_in_reach as f64 / in_reach as f64;
            }
            row.static_success_pct = pct(static_ok);
        }
        row
    }
}

/// The rows of `trials`: per task (`category task`) and method, then per method
/// over every task (`all`).
pub fn novel_rows(trials: &[NovelTrial], tasks: &[String], methods: &[String]) -> Vec<NovelRow> {
    let mut rows = Vec::new();
    for task in tasks {
        for method in methods {
            rows.push(NovelRow::of(
                task,
                method,
                trials
                    .iter()
                    .filter(|t| &t.method == method && &task_label(t.category, &t.task) == task),
            ));
        }
    }
    if tasks.len() > 1 {
        for method in methods {
            rows.push(NovelRow::of(
                "all",
                method,
                trials.iter().filter(|t| &t.method == method),
            ));
        }
    }
    rows
}

/// `mug top`, `bottle side`, ...
pub fn task_label(category: Category, task: &str) -> String {
    format!("{category} {task}")
}

/// The result of the experiment.
#[derive(Debug, Clone, Serialize)]
pub struct NovelReport {
    /// The seed.
    pub seed: u64,
    /// Placements per object.
    pub placements: usize,
    /// The methods.
    pub methods: Vec<String>,
    /// The tasks (`category task`).
    pub tasks: Vec<String>,
    /// The objects: name, category and origin.
    pub objects: Vec<ObjectSummary>,
    /// The lab's error sizes.
    pub lab: LabErrors,
    /// The hand–eye error drawn for this run (`[x, y, z, rx, ry, rz]`, m and rad).
    pub hand_eye_error: [f64; 6],
    /// The paper's setting (no approach to contact, collisions fail).
    pub paper: bool,
    /// Whether the hand approached to contact before closing.
    pub approach_to_contact: bool,
    /// One row per task and method, then per method over all tasks.
    pub rows: Vec<NovelRow>,
    /// Every trial.
    pub trials: Vec<NovelTrial>,
}

/// An object as reported.
#[derive(Debug, Clone, Serialize)]
pub struct ObjectSummary {
    /// Its name.
    pub name: String,
    /// Its category.
    pub category: Category,
    /// Where it came from.
    pub origin: &'static str,
}

/// One category's database, its prepared models and its tasks.
pub struct CategoryModels {
    /// The database.
    pub db: CategoryDb,
    /// The models prepared for registration.
    pub models: ModelSet,
    /// The tasks run on this category.
    pub tasks: Vec<String>,
}

impl CategoryModels {
    /// Loads `category` from `dbs` and prepares its models; `tasks` filters its
    /// database's tasks (empty: all).
    pub fn load(
        dbs: &mut Databases,
        category: Category,
        tasks: &[String],
    ) -> Result<CategoryModels, NovelError> {
        let fail = |problem: String| NovelError::Category {
            category: category.to_string(),
            problem,
        };
        let db = dbs
            .get(category.name())
            .map_err(|e| fail(e.to_string()))?
            .clone();
        let models = ModelSet::from_category(&db, &RegisterParams::default())
            .map_err(|e| fail(format!("models: {e}")))?;
        let tasks: Vec<String> = db
            .file
            .tasks
            .iter()
            .filter(|t| tasks.is_empty() || tasks.contains(t))
            .cloned()
            .collect();
        Ok(CategoryModels { db, models, tasks })
    }
}

/// The cell the experiment runs in.
pub struct NovelCell<'a> {
    /// The configuration.
    pub config: &'a CellConfig,
    /// The robot (planning, joints, forward kinematics).
    pub robot: Arc<Robot>,
    /// The hand (collision of the open hand).
    pub hand: &'a HandModel,
    /// The simulated observer.
    pub observer: &'a Observer,
}

/// The palm pose at which the hand closes, from the pose the arm reached: with
/// `approach` the executor's approach to contact ([`approach_to_contact`]: from the
/// pre-grasp along the palm's axis through `reached`, up to the overtravel, stopping
/// at first contact); without it (the paper's setting) the hand closes at `reached`.
/// An open hand that already collides at the pre-grasp closes at `reached`, where the
/// observer fails it as a start collision.
pub fn executed_palm(
    hand: &HandModel,
    object: &GraspObject,
    base_from_object: &Pose,
    reached: &Pose,
    preshape: &HandPose,
    approach: Option<&ApproachOptions>,
) -> Pose {
    let Some(options) = approach else {
        return *reached;
    };
    let object_from_palm = base_from_object.inverse() * reached;
    match approach_to_contact(hand, object, &object_from_palm, preshape, options) {
        Ok(stop) if stop.start_collision.is_none() => base_from_object * stop.object_from_palm,
        _ => *reached,
    }
}

/// Turns about the object's vertical axis tried by [`task_in_reach`] (rad): up to
/// 30 degrees either way, beyond what the planner's local search moves a grasp.
const REACH_TURNS_RAD: [f64; 5] = [-0.52, -0.26, 0.0, 0.26, 0.52];

/// Offsets along the palm's approach axis tried by [`task_in_reach`] (m): the
/// approach to contact's and the refinement's range.
const REACH_DEPTHS_M: [f64; 3] = [-0.05, 0.0, 0.05];

/// Whether the arm could reach `task` on an object standing at `base_from_object`
/// at all. It is `false` only when it is proved impossible: for every example grasp
/// of the task of every model of `db`, placed on the object's true pose, turned up
/// to 30 degrees about its vertical axis and moved 5 cm either way along its
/// approach axis, the wrist centre lies farther from the shoulder than the arm is
/// long ([`Robot::out_of_reach`]), so no joint values reach it. Such a trial (a
/// handle facing away, out at the table's far edge) no method can do; it is
/// reported apart.
pub fn task_in_reach(robot: &Robot, db: &CategoryDb, task: &str, base_from_object: &Pose) -> bool {
    db.file.grasps.iter().filter(|g| g.task == task).any(|g| {
        let Ok(object_from_palm) = g.pose.to_pose("grasp") else {
            return true;
        };
        REACH_TURNS_RAD.iter().any(|&turn| {
            let turned = Pose::rotation(nalgebra::Vector3::z() * turn);
            REACH_DEPTHS_M.iter().any(|&depth| {
                let palm = base_from_object
                    * turned
                    * object_from_palm
                    * Pose::translation(0.0, 0.0, depth);
                robot.out_of_reach(&palm).is_none()
            })
        })
    })
}

/// Seeds of placement `placement` of the object named `object`: placement, camera
/// noise, registration, joints. They depend on the object and the placement only,
/// not on which other objects the run holds, so a run over a subset (`--categories
/// hammer`, fewer `--instances`) repeats the full run's trials of those objects.
fn placement_seeds(seed: u64, object: &str, placement: usize) -> [u64; 4] {
    let name = crate::hash::fnv1a(object.as_bytes());
    [0, 1, 2, 3].map(|k| {
        instance_seed(
            seed ^ 0x006e_6f76_656c ^ instance_seed(name, 0),
            placement as u64 * 4 + k,
        )
    })
}

/// The cell's placement area ([`crate::cell::harness::PLACEMENT_X_M`], `_Y_M`).
pub fn placement_region(config: &CellConfig) -> PlacementRegion {
    use crate::cell::harness::{PLACEMENT_X_M, PLACEMENT_Y_M};
    PlacementRegion {
        center_xy_m: [
            (PLACEMENT_X_M.0 + PLACEMENT_X_M.1) / 2.0,
            (PLACEMENT_Y_M.0 + PLACEMENT_Y_M.1) / 2.0,
        ],
        half_extent_xy_m: [
            (PLACEMENT_X_M.1 - PLACEMENT_X_M.0) / 2.0,
            (PLACEMENT_Y_M.1 - PLACEMENT_Y_M.0) / 2.0,
        ],
        table_height_m: config.table.height_m,
    }
}

/// Progress steps of one object placement: one per task and method.
pub fn steps_per_placement(tasks: usize, methods: usize) -> u64 {
    (tasks * methods) as u64
}

/// Runs every object at `options.placements` placements through the chain;
/// `models` holds each object's category; `progress` advances per task and method.
pub fn run_novel(
    cell: &NovelCell,
    dbs: &mut Databases,
    models: &HashMap<Category, CategoryModels>,
    objects: &[NovelObject],
    options: &NovelOptions,
    progress: Option<&indicatif::ProgressBar>,
) -> Result<NovelReport, NovelError> {
    check_options(options)?;
    let tasks = task_labels(models, objects)?;
    if let Some(p) = progress {
        let steps: u64 = objects
            .iter()
            .map(|o| steps_per_placement(models[&o.category].tasks.len(), options.methods.len()))
            .sum();
        p.set_length(steps * options.placements as u64);
    }
    let run = NovelRun::new(cell, options);
    let mut trials = Vec::new();
    for (o, object) in objects.iter().enumerate() {
        let category = &models[&object.category];
        for placement in 0..options.placements {
            let trial_id = (placement * objects.len() + o) as u64;
            let placed = run.place(object, category, placement, trial_id)?;
            for task in &category.tasks {
                let in_reach =
                    task_in_reach(&cell.robot, &category.db, task, &placed.base_from_object);
                for method in &options.methods {
                    trials.push(run.trial(dbs, &placed, task, method, in_reach)?);
                    if let Some(p) = progress {
                        p.inc(1);
                    }
                }
            }
        }
    }
    Ok(NovelReport {
        seed: options.seed,
        placements: options.placements,
        methods: options.methods.clone(),
        rows: novel_rows(&trials, &tasks, &options.methods),
        tasks,
        objects: objects
            .iter()
            .map(|o| ObjectSummary {
                name: o.name.clone(),
                category: o.category,
                origin: o.origin,
            })
            .collect(),
        lab: options.lab,
        hand_eye_error: run.hand_eye_error,
        paper: options.paper,
        approach_to_contact: !options.paper,
        trials,
    })
}

/// Checks the placements, the methods (the plan stage's names) and the lab's errors.
fn check_options(options: &NovelOptions) -> Result<(), NovelError> {
    let bad = |what: &str, problem: &str| NovelError::Option {
        what: what.to_string(),
        problem: problem.to_string(),
    };
    if options.placements == 0 {
        return Err(bad("placements", "must be at least 1"));
    }
    if options.methods.is_empty() {
        return Err(bad("methods", "give at least one method"));
    }
    for m in &options.methods {
        if crate::cell::plan::method_kernel(m).is_none() {
            return Err(bad(
                &format!("method {m:?}"),
                &format!("unknown (use {})", crate::cell::plan::METHODS.join(", ")),
            ));
        }
    }
    options
        .lab
        .validate()
        .map_err(|e| bad("lab errors", &e.to_string()))
}

/// The tasks run on `objects` ([`task_label`]s, in order of first appearance); an
/// error when an object's category has no models or no task is left.
fn task_labels(
    models: &HashMap<Category, CategoryModels>,
    objects: &[NovelObject],
) -> Result<Vec<String>, NovelError> {
    let mut tasks: Vec<String> = Vec::new();
    for object in objects {
        let m = models
            .get(&object.category)
            .ok_or_else(|| NovelError::Category {
                category: object.category.to_string(),
                problem: "no database loaded".into(),
            })?;
        for t in &m.tasks {
            let label = task_label(object.category, t);
            if !tasks.contains(&label) {
                tasks.push(label);
            }
        }
    }
    if tasks.is_empty() {
        return Err(NovelError::Option {
            what: "tasks".to_string(),
            problem: "no task of the objects' categories was asked for".to_string(),
        });
    }
    Ok(tasks)
}

impl NovelObject {
    /// The cell failed on this object.
    fn fail(&self, problem: String) -> NovelError {
        NovelError::Object {
            object: self.name.clone(),
            problem,
        }
    }
}

/// What stays the same over a run: the lab's hand–eye error and the cell's
/// perception, planning and execution settings for the run's protocol.
struct NovelRun<'a> {
    cell: &'a NovelCell<'a>,
    options: &'a NovelOptions,
    hand_eye_error: [f64; 6],
    region: PlacementRegion,
    segment: SegmentParams,
    calibrated: Pose,
    safety: SafetyCheck,
    motions: ExecutorConfig,
    approach: Option<ApproachOptions>,
    protocol: Protocol,
    register: RegisterParams,
}

/// One object at one placement, seen and registered.
struct Placed<'a> {
    object: &'a NovelObject,
    placement: usize,
    trial_id: u64,
    base_from_object: Pose,
    lab: LabDraw,
    fits: Fits,
    best_fit: Option<Pose>,
    best_fit_offset_mm: Option<f64>,
    grasp_object: GraspObject,
}

impl<'a> NovelRun<'a> {
    fn new(cell: &'a NovelCell<'a>, options: &'a NovelOptions) -> NovelRun<'a> {
        let protocol = if options.paper {
            Protocol::PaperRobot
        } else {
            Protocol::Cell
        };
        NovelRun {
            cell,
            options,
            hand_eye_error: options.lab.draw_hand_eye(options.seed),
            region: placement_region(cell.config),
            segment: SegmentParams::for_cell(cell.config),
            calibrated: cell.config.base_from_camera(),
            safety: SafetyCheck::new(
                Arc::clone(&cell.robot),
                SafetyLimits::from_cell(cell.config, &cell.robot),
            ),
            motions: ExecutorConfig::from_cell(cell.config),
            approach: (!options.paper).then(|| ApproachOptions::from_cell(cell.config)),
            protocol,
            register: register_params(protocol),
        }
    }

    /// Steps 1 and 2: `object` placed (placement `placement`, its messages' id `trial_id`),
    /// rendered from the camera's true mount and registered with the calibrated one.
    fn place<'o>(
        &self,
        object: &'o NovelObject,
        category: &CategoryModels,
        placement: usize,
        trial_id: u64,
    ) -> Result<Placed<'o>, NovelError> {
        let config = self.cell.config;
        let [place_seed, noise_seed, register_seed, joint_seed] =
            placement_seeds(self.options.seed, &object.name, placement);
        let lab = LabDraw {
            calibrated_from_true_camera: self.hand_eye_error,
            joint_error_rad: self.options.lab.draw_joints(joint_seed),
        };
        let base_from_object = self.region.place(&object.mesh, place_seed);
        // 1. The camera, from its true mount.
        let mut scene = Scene::new(Some(TableBox::from(&config.table)));
        scene
            .add(&object.name, object.mesh.clone(), base_from_object)
            .map_err(|e| object.fail(e.to_string()))?;
        let camera =
            DepthCamera::from_config(&config.camera, lab.true_base_from_camera(&self.calibrated));
        let cloud = camera.render(&scene, noise_seed).to_cloud();
        // 2. Perception, with the calibrated mount.
        let fits = perceive_trial(
            trial_id,
            &cloud,
            &self.calibrated,
            &self.segment,
            &category.models,
            &self.register,
            register_seed,
        )
        .map_err(|e| object.fail(format!("perception: {e}")))?;
        let best_fit = best_fit(&fits);
        let best_fit_offset_mm = best_fit
            .as_ref()
            .map(|f| pose_error(f, &base_from_object).0 * 1e3);
        let grasp_object = GraspObject::new(&object.mesh, Path::new(&object.name))
            .map_err(|e| object.fail(e.to_string()))?
            .with_table(Some(
                config.table.height_m - base_from_object.translation.vector.z,
            ));
        Ok(Placed {
            object,
            placement,
            trial_id,
            base_from_object,
            lab,
            fits,
            best_fit,
            best_fit_offset_mm,
            grasp_object,
        })
    }

    /// Steps 3 to 5 for `task` and `method` on `placed`: plan, execute, grade.
    fn trial(
        &self,
        dbs: &mut Databases,
        placed: &Placed,
        task: &str,
        method: &str,
        in_reach: bool,
    ) -> Result<NovelTrial, NovelError> {
        let (cell, object) = (self.cell, placed.object);
        let started = std::time::Instant::now();
        let planned = self.plan(dbs, placed, task, method)?;
        let plan_ms = started.elapsed().as_secs_f64() * 1e3;
        let (attempt, palm) = match planned {
            Err(failure) => (
                Attempt::NotPlanned {
                    cause: failure.cause.into(),
                    detail: failure.detail,
                },
                None,
            ),
            Ok(grasp) => self.execute(placed, &grasp),
        };
        // 5. The observer.
        let seen: Observation = cell
            .observer
            .grade(
                &object.name,
                &object.mesh,
                &placed.base_from_object,
                &attempt,
            )
            .map_err(|e| object.fail(e.to_string()))?;
        let collision = palm.is_some_and(|(p, preshape)| {
            let object_from_palm = placed.base_from_object.inverse() * p;
            open_hand_collision(
                cell.hand,
                &placed.grasp_object,
                &object_from_palm,
                &preshape,
            )
            .is_some()
        });
        Ok(NovelTrial {
            object: object.name.clone(),
            category: object.category,
            origin: object.origin,
            placement: placed.placement,
            base_from_object: PoseJson::from(&placed.base_from_object),
            task: task.to_string(),
            method: method.to_string(),
            grade: seen.grade,
            cause: seen.cause,
            physics_grade: seen.physics.grade,
            static_grade: seen.static_epsilon.grade,
            epsilon: seen.epsilon,
            force_closure: seen.epsilon > 0.0,
            collision,
            executed: palm.is_some(),
            task_in_reach: in_reach,
            note: seen.note,
            palm: palm.map(|(p, _)| PoseJson::from(&p)),
            spread_rad: palm.map(|(_, hand)| hand.spread_rad),
            preshape_rad: palm.map(|(_, hand)| PreshapeRad(hand.flex_rad)),
            best_fit_offset_mm: placed.best_fit_offset_mm,
            plan_ms,
            table_penetration_mm: seen.lift.as_ref().map(|l| l.table_penetration_m * 1e3),
        })
    }

    /// Step 3, planning `task` with `method` on `placed` as the plan stage does it:
    /// the grasp, with joints the executor accepts, or why there is none.
    fn plan(
        &self,
        dbs: &mut Databases,
        placed: &Placed,
        task: &str,
        method: &str,
    ) -> Result<Result<PlannedGrasp, PlanFailure>, NovelError> {
        let (cell, object) = (self.cell, placed.object);
        let request = TrialRequest::new(placed.trial_id, 0, object.category.name(), task, method)
            .map_err(|e| object.fail(e.to_string()))?
            .with_protocol(self.protocol);
        let executor = ExecutorReach {
            robot: &cell.robot,
            check: &self.safety,
            config: &self.motions,
            current: cell.config.robot.park_joints_rad,
        };
        Ok(plan_trial(
            cell.config,
            &executor,
            cell.hand,
            dbs,
            &request,
            &placed.fits,
        ))
    }

    /// Step 4, execution of `grasp` on `placed`: its joints plus the lab's errors,
    /// then the approach (if any). The attempt for the observer, and the palm pose
    /// and pre-shape (at the spread) where the hand closed.
    fn execute(
        &self,
        placed: &Placed,
        grasp: &PlannedGrasp,
    ) -> (Attempt, Option<(Pose, HandPose)>) {
        let reached = match grasp.joints {
            Some(q) => self.cell.robot.arm().palm(&placed.lab.executed_joints(&q)),
            None => grasp.pose,
        };
        let preshape = grasp.preshape_rad.at_spread(grasp.spread_rad);
        let palm = executed_palm(
            self.cell.hand,
            &placed.grasp_object,
            &placed.base_from_object,
            &reached,
            &preshape,
            self.approach
                .map(|a| a.for_grasp(grasp.max_overtravel_m))
                .as_ref(),
        );
        (
            Attempt::Executed {
                base_from_palm: palm,
                spread_rad: grasp.spread_rad,
                preshape_rad: grasp.preshape_rad,
                best_fit: placed.best_fit,
                stopped_after_closing: None,
            },
            Some((palm, preshape)),
        )
    }
}

/// The best-fitting model's pose (lowest eps among the registered), for the
/// observer's cause of a failure.
fn best_fit(fits: &Fits) -> Option<Pose> {
    fits.fits()
        .ok()?
        .iter()
        .filter(|f| f.status().is_ok_and(|s| s != FitStatus::Failed) && f.eps.is_finite())
        .min_by(|a, b| a.eps.total_cmp(&b.eps))
        .and_then(|f| f.base_from_model.to_pose("fit").ok())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn trial(task: &str, method: &str, grade: Grade, eps: f64, collision: bool) -> NovelTrial {
        NovelTrial {
            object: "o".into(),
            category: Category::Mug,
            origin: "held-apart",
            placement: 0,
            base_from_object: PoseJson::from(&Pose::identity()),
            task: task.into(),
            method: method.into(),
            grade,
            cause: (grade != Grade::Success).then_some(FailureCause::ShapeDissimilarity),
            physics_grade: grade,
            static_grade: if eps > 0.05 {
                Grade::Success
            } else {
                Grade::Failure
            },
            epsilon: eps,
            force_closure: eps > 0.0,
            collision,
            executed: true,
            task_in_reach: method != "best-single",
            note: String::new(),
            palm: None,
            spread_rad: None,
            preshape_rad: None,
            best_fit_offset_mm: None,
            plan_ms: 1.0,
            table_penetration_mm: Some(0.0),
        }
    }

    /// The reach check is exhaustive over the database's grasps: a mug in the
    /// middle of the table can be taken from the top, one 2 m away by no grasp.
    #[test]
    fn a_task_is_in_reach_on_the_table_and_out_of_reach_far_away() {
        let db = CategoryDb::load(&Path::new(env!("CARGO_MANIFEST_DIR")).join("db/mug")).unwrap();
        let robot = crate::robot::shipped_robot();
        let at = |x: f64| Pose::translation(x, 0.0, 0.0);
        assert!(task_in_reach(&robot, &db, "top", &at(0.6)));
        assert!(!task_in_reach(&robot, &db, "top", &at(2.0)));
        assert!(!task_in_reach(&robot, &db, "no-such-task", &at(0.6)));
    }

    #[test]
    fn rows_count_grades_causes_collisions_and_force_closure_per_task_and_method() {
        let trials = vec![
            trial("top", "laplace", Grade::Success, 0.1, false),
            trial("top", "laplace", Grade::Partial, 0.02, false),
            trial("top", "laplace", Grade::Failure, 0.0, true),
            NovelTrial {
                table_penetration_mm: Some(TABLE_GIVE_M * 1e3),
                ..trial("side", "laplace", Grade::Success, 0.2, false)
            },
            trial("top", "best-single", Grade::Failure, 0.0, true),
        ];
        let tasks = vec!["mug top".to_string(), "mug side".to_string()];
        let methods = vec!["laplace".to_string(), "best-single".to_string()];
        let rows = novel_rows(&trials, &tasks, &methods);
        assert_eq!(rows.len(), 6, "2 tasks x 2 methods, then all x 2");
        let top = &rows[0];
        assert_eq!(
            (top.task.as_str(), top.method.as_str()),
            ("mug top", "laplace")
        );
        assert_eq!(
            (top.trials, top.success, top.partial, top.failure),
            (3, 1, 1, 1)
        );
        assert_eq!(top.collisions, 1);
        assert!((top.force_closure_pct - 200.0 / 3.0).abs() < 1e-9);
        assert_eq!(top.causes.get("shape-dissimilarity"), Some(&2));
        let all = &rows[4];
        assert_eq!((all.task.as_str(), all.trials, all.success), ("all", 4, 2));
        assert_eq!(rows[5].collisions, 1);
        assert_eq!(
            (rows[5].out_of_reach, rows[5].success_in_reach_pct),
            (1, 0.0)
        );
        assert_eq!(rows[3].trials, 0, "best single had no side trial");
        // The side success went 1 mm into the table while closing; none on top.
        assert_eq!(
            (
                top.physics_success_in_table,
                rows[2].physics_success_in_table
            ),
            (0, 1)
        );
        assert_eq!(all.physics_success_in_table, 1);
        // Both verdicts: physics is the grade here; static succeeds above 0.05.
        assert!((top.physics_success_pct - 100.0 / 3.0).abs() < 1e-9);
        assert!((top.static_success_pct - 100.0 / 3.0).abs() < 1e-9);
        assert_eq!((top.verdicts.total, top.verdicts.agree), (3, 2));
        assert_eq!(
            (top.out_of_reach, top.success_in_reach_pct),
            (0, 100.0 / 3.0)
        );
        assert_eq!(
            top.verdicts.counts[1][2], 1,
            "physics partial, static failure"
        );
    }
}
