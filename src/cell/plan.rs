//! `cell-plan`: the grasp for each trial from the fits of every category model.
//!
//! For a trial request (category, task, method) and the trial's fits it maximises
//! eq. 2 over the task's example grasps of every registered model with the method's
//! kernel (`laplace`, `gaussian`, `gaussian-r`), or takes the best-single baseline
//! (`best-single`), subject to the table and to inverse-kinematic reachability of
//! the grasp and its pre-grasp ([`crate::plan::plan`]). It publishes the palm poses
//! with the joint solutions, or a plan marked failed with the cause: registration
//! (no usable fit), reachability (nothing reachable) or other (bad request).

use super::notify::{self, Watchdog};
use super::{stop_requested, ByTrial, CellError, TICK};
use crate::category::CategoryDb;
use crate::cloud::PointCloud;
use crate::config::CellConfig;
use crate::execute::{
    pregrasp_line_end, validate_grasp, ExecutionRequest, ExecutorConfig, SafetyCheck, SafetyLimits,
};
use crate::geometry::PoseJson;
use crate::ipc::Domain;
use crate::ipc::{
    monotonic_now_ns, wait_any, FailureCause, FitStatus, Fits, GraspPlan, JointStates, Protocol,
    Stage, TrialRequest, Wakeable,
};
use crate::plan::refine::{refine_over_db, DbProblem, SimRefineOptions};
use crate::plan::{
    plan_with, Kernel, ModelFit, PlanOptions, PlannedGrasp, Reachability, SeenSurface,
    SeenSurfaceOptions,
};
use crate::robot::hand::HandModel;
use crate::robot::kinematics::ArmJoints;
use crate::robot::Robot;
use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::sync::Arc;

/// The methods a trial request may name: the paper's, and `laplace-sim` (beyond the
/// paper: the Laplace optimum refined in the grasp simulator over every registered
/// model, [`crate::plan::refine`]).
pub const METHODS: [&str; 5] = [
    "laplace",
    "gaussian",
    "gaussian-r",
    "best-single",
    "laplace-sim",
];

/// The kernel of `method`, and whether the best-single baseline is wanted.
pub fn method_kernel(method: &str) -> Option<(Kernel, bool)> {
    match method {
        "laplace" | "laplace-sim" => Some((Kernel::LAPLACE_DEFAULT, false)),
        "gaussian" => Some((Kernel::Gaussian, false)),
        "gaussian-r" => Some((Kernel::GAUSSIAN_R_DEFAULT, false)),
        "best-single" => Some((Kernel::LAPLACE_DEFAULT, true)),
        _ => None,
    }
}

/// Category databases loaded on first use, from `<db dir>/<category>/`.
#[derive(Debug)]
pub struct Databases {
    dir: PathBuf,
    loaded: HashMap<String, CategoryDb>,
}

impl Databases {
    /// Databases under `dir` (e.g. `db/`).
    pub fn new(dir: &Path) -> Databases {
        Databases {
            dir: dir.to_path_buf(),
            loaded: HashMap::new(),
        }
    }

    /// The database of `category`, loaded once.
    pub fn get(&mut self, category: &str) -> Result<&CategoryDb, CellError> {
        if !self.loaded.contains_key(category) {
            let db = super::load_category(&self.dir, category)?;
            self.loaded.insert(category.to_string(), db);
        }
        Ok(&self.loaded[category])
    }

    /// Loads every category's database and prepares its models' grasp objects
    /// (what `laplace-sim` simulates on), so that no trial waits for them. A
    /// database that fails is logged here and fails its trials when they come.
    pub fn preload(&mut self) -> Result<(), CellError> {
        for category in super::perceive::categories(&self.dir)? {
            let started = std::time::Instant::now();
            let prepared = self.get(&category).and_then(|db| {
                db.file
                    .models
                    .iter()
                    .enumerate()
                    .try_for_each(|(i, model)| {
                        db.grasp_object(i)
                            .map(|_| ())
                            .map_err(|source| CellError::Category {
                                category: category.clone(),
                                source: Box::new(crate::category::CategoryError::Model {
                                    model: model.name.clone(),
                                    source,
                                }),
                            })
                    })
            });
            match prepared {
                Ok(()) => tracing::info!(
                    %category,
                    ms = started.elapsed().as_secs_f64() * 1e3,
                    "database ready"
                ),
                Err(e) => tracing::error!(%category, "{e}"),
            }
        }
        Ok(())
    }
}

/// Why a trial got no plan to execute.
#[derive(Debug, Clone, PartialEq)]
pub struct PlanFailure {
    /// The cause, as the log records it.
    pub cause: FailureCause,
    /// What happened, for the log.
    pub detail: String,
}

/// The planner's fits from the received ones: converged or not-converged fits of
/// models the database has (failed registrations are left out).
pub fn planner_fits(db: &CategoryDb, fits: &Fits) -> Result<Vec<ModelFit>, CellError> {
    let mut out = Vec::new();
    for fit in fits.fits()? {
        if fit.status()? == FitStatus::Failed {
            continue;
        }
        fit.check()?;
        let Some(model) = db.file.models.get(fit.model_id as usize) else {
            return Err(CellError::Invalid(format!(
                "fit of model {} but the {} database has {} models",
                fit.model_id,
                db.file.category,
                db.file.models.len()
            )));
        };
        out.push(ModelFit {
            name: model.name.clone(),
            base_from_model: fit.base_from_model.to_pose("fit base_from_model")?,
            eps_m2: fit.eps,
            sigma_m2: fit.sigma,
        });
    }
    Ok(out)
}

/// The planner's options of `method` under `protocol`: the method's kernel with the
/// category's weights and the reachability repair (the cell's), or the paper's
/// kernel scale and weights without repair ([`crate::plan::PlanMode::apply`]).
pub fn trial_options(
    config: &CellConfig,
    db: &CategoryDb,
    method: &str,
    protocol: Protocol,
) -> Result<PlanOptions, CellError> {
    let (kernel, best_single) = method_kernel(method).ok_or_else(|| CellError::UnknownMethod {
        method: method.to_string(),
    })?;
    let mut options = PlanOptions {
        weights: crate::plan::category::weights(db),
        // The baseline's repair only when the baseline is the method.
        repair_best_single: best_single,
        ..PlanOptions::new(kernel, config)
    };
    protocol.plan_mode().apply(&mut options);
    Ok(options)
}

/// Plans trial `request` from `fits` for the cell's `robot` and `hand`: the grasp to
/// execute, or why there is none. In the cell's protocol the open hand must clear
/// the seen surface the fits carry ([`crate::plan::seen`]); the paper's protocol
/// plans as published, without it.
pub fn plan_trial(
    config: &CellConfig,
    robot: &Robot,
    hand: &HandModel,
    dbs: &mut Databases,
    request: &TrialRequest,
    fits: &Fits,
) -> Result<TrialPlan, PlanFailure> {
    let other = |detail: String| PlanFailure {
        cause: FailureCause::Other,
        detail,
    };
    let category = request.category().map_err(|e| other(e.to_string()))?;
    let task = request.task().map_err(|e| other(e.to_string()))?;
    let method = request.method().map_err(|e| other(e.to_string()))?;
    let db = dbs.get(category).map_err(|e| other(e.to_string()))?;
    let model_fits = planner_fits(db, fits).map_err(|e| other(e.to_string()))?;
    if model_fits.is_empty() {
        return Err(PlanFailure {
            cause: FailureCause::RegistrationFailure,
            detail: "no model was registered to the object".into(),
        });
    }
    let grasps = crate::plan::category::example_grasps(db, &model_fits, task)
        .map_err(|e| other(e.to_string()))?;
    let protocol = request.protocol().map_err(|e| other(e.to_string()))?;
    let options = trial_options(config, db, method, protocol).map_err(|e| other(e.to_string()))?;
    let seen_points = fits.seen().map_err(|e| other(e.to_string()))?;
    let seen = match protocol {
        Protocol::Cell if !seen_points.is_empty() => Some(
            SeenSurface::new(
                hand,
                &PointCloud::from_points(seen_points.iter().map(|&p| p.into()).collect()),
                SeenSurfaceOptions::along_approach(&options, true),
            )
            .map_err(|e| other(e.to_string()))?,
        ),
        _ => None,
    };
    let reach = Some(robot as &dyn Reachability);
    let outcome = plan_with(&model_fits, &grasps, task, &options, reach, seen.as_ref())
        .map_err(|e| other(e.to_string()))?;
    let mut fallback = None;
    let grasp = match method {
        "best-single" => outcome.best_single.grasp,
        // Beyond the paper: the Laplace grasp refined in the grasp simulator over
        // every fitted model, approaching to contact as the executor does.
        "laplace-sim" => {
            let started = std::time::Instant::now();
            let problem = DbProblem {
                db,
                fits: &model_fits,
                grasps: &grasps,
                task,
                options: &options,
                hand,
                reach,
                seen: seen.as_ref(),
                table_height_m: Some(config.table.height_m),
            };
            let refined = refine_over_db(
                &problem,
                &outcome.plan.grasp,
                &SimRefineOptions::for_cell(config),
            )
            .map_err(|e| other(e.to_string()))?;
            tracing::debug!(
                ms = started.elapsed().as_secs_f64() * 1e3,
                evaluations = refined.evaluations,
                infeasible = refined.infeasible,
                start_mean_epsilon = refined.start_mean_epsilon,
                mean_epsilon = refined.mean_epsilon,
                "laplace-sim refined"
            );
            let start = outcome.plan.grasp;
            if refined.grasp.pose != start.pose || refined.grasp.spread_rad != start.spread_rad {
                fallback = Some(start);
            }
            refined.grasp
        }
        _ => outcome.plan.grasp,
    };
    if !grasp.reachable {
        let why = grasp
            .unreachable
            .as_ref()
            .map_or("not reachable".to_string(), |u| u.to_string());
        return Err(PlanFailure {
            cause: FailureCause::Reachability,
            detail: why,
        });
    }
    Ok(TrialPlan { grasp, fallback })
}

/// A trial's plan: the method's grasp, and what to execute when the executor
/// refuses it.
#[derive(Debug, Clone, PartialEq)]
pub struct TrialPlan {
    /// The method's grasp.
    pub grasp: PlannedGrasp,
    /// `laplace-sim`'s start, the Laplace optimum, when the refinement moved it:
    /// the refinement checks each candidate's reachability with the planner's IK,
    /// not the executor's motions (pre-grasp move, approach, lift), so a refined
    /// grasp can be refused where its start is not.
    pub fallback: Option<PlannedGrasp>,
}

impl TrialPlan {
    /// The method's grasp with joints whose motions from `current` the executor
    /// accepts ([`executable_joints`]), else the fallback's; the refusal of the
    /// method's grasp when neither is accepted.
    pub fn executable(
        self,
        robot: &Robot,
        check: &SafetyCheck,
        config: &ExecutorConfig,
        current: &ArmJoints,
    ) -> Result<PlannedGrasp, PlanFailure> {
        let mut grasp = self.grasp;
        let refusal = match executable_joints(robot, check, config, &mut grasp, current) {
            Ok(()) => return Ok(grasp),
            Err(refusal) => refusal,
        };
        let Some(mut start) = self.fallback else {
            return Err(refusal);
        };
        match executable_joints(robot, check, config, &mut start, current) {
            Ok(()) => {
                tracing::debug!(
                    "refined grasp refused ({}); executing its start",
                    refusal.detail
                );
                Ok(start)
            }
            Err(_) => Err(refusal),
        }
    }
}

/// Picks joint solutions for `grasp` whose motions from the arm at `current` the
/// executor will accept ([`validate_grasp`]: pre-grasp move, approach, lift, with
/// its safety checks). The planner only needs some IK solution to know a pose is
/// reachable, and from its generic seeds it may find one on another branch
/// (shoulder turned by half a turn) that the executor's joint-space move could not
/// reach safely. Pre-grasp solutions are tried seeded first with `current`, the
/// planner's solution and its equivalents ([`crate::robot::kinematics::ArmKinematics::equivalents`]),
/// the end of the palm's straight line from `current` ([`pregrasp_line_end`]), then
/// the IK's spread of seeds; the grasp is solved near each.
/// A reachability failure, with the executor's refusal of the first candidate,
/// when none is accepted.
pub fn executable_joints(
    robot: &Robot,
    check: &SafetyCheck,
    config: &ExecutorConfig,
    grasp: &mut PlannedGrasp,
    current: &ArmJoints,
) -> Result<(), PlanFailure> {
    let hand = grasp.preshape_rad.at_spread(grasp.spread_rad);
    let mut seeds = vec![*current];
    if let Some(planned) = grasp.pregrasp_joints {
        // The planner's solution, then its equivalents (the same pose with a
        // shoulder, elbow or wrist flipped) nearest the arm first: the IK's generic
        // seeds may have found the branch half a turn away.
        seeds.push(planned);
        seeds.extend(robot.arm().equivalents(&planned, current));
    }
    // Then the end of the palm's straight line from where it is: a pre-grasp the
    // executor can reach along the line where a joint-space swing is refused.
    seeds.extend(pregrasp_line_end(
        robot,
        config,
        current,
        &grasp.pregrasp_pose,
    ));
    let mut first_refusal = None;
    let mut accepted = None;
    let _ = robot.ik.solve_with(&grasp.pregrasp_pose, &seeds, |pre| {
        if robot.collision_at(&pre.joints, &hand).is_some() {
            return false;
        }
        let mut near = vec![pre.joints];
        near.extend(grasp.joints);
        let Ok(at) = robot.reach(&grasp.pose, &hand, &near) else {
            return false;
        };
        let request = ExecutionRequest {
            palm: PoseJson::from(&grasp.pose),
            pregrasp: PoseJson::from(&grasp.pregrasp_pose),
            joints_rad: at.joints,
            pregrasp_joints_rad: pre.joints,
            spread_rad: grasp.spread_rad,
            preshape_rad: grasp.preshape_rad,
            task: None,
            method: None,
        };
        match validate_grasp(check, config, &request, current) {
            Ok(_) => {
                accepted = Some((pre.joints, at.joints));
                true
            }
            Err(e) => {
                first_refusal.get_or_insert(e);
                false
            }
        }
    });
    let Some((pre, at)) = accepted else {
        let detail = match first_refusal {
            Some(refusal) => format!("no joint solution the executor accepts: {refusal}"),
            None => "no collision-free joint solution of the pre-grasp and grasp poses".into(),
        };
        return Err(PlanFailure {
            cause: FailureCause::Reachability,
            detail,
        });
    };
    grasp.pregrasp_joints = Some(pre);
    grasp.joints = Some(at);
    Ok(())
}

/// Runs the plan stage until SIGTERM/SIGINT; databases come from `db_dir`.
pub fn run(config: &CellConfig, domain: &Domain, db_dir: &Path) -> Result<(), CellError> {
    let robot = Arc::new(Robot::load(config)?);
    let hand = HandModel::from_description(
        &robot.description,
        &config.robot.palm_link,
        &config.robot.urdf,
    )?;
    // The executor's own checks and settings: a plan is published only when the
    // executor will accept its motions.
    let safety = SafetyCheck::new(Arc::clone(&robot), SafetyLimits::from_cell(config, &robot));
    let motions = ExecutorConfig::from_cell(config);
    let mut dbs = Databases::new(db_dir);
    dbs.preload()?;
    let stage = Stage::start(domain, "plan")?;
    let plans = stage.publisher::<GraspPlan>()?;
    let fits_sub = stage.subscriber::<Fits>()?;
    let joints_sub = stage.subscriber::<JointStates>()?;
    let requests = stage.subscriber::<TrialRequest>()?;
    let mut arm_now: ArmJoints = config.robot.park_joints_rad;
    notify::ready("plan waiting for fits");
    let mut watchdog = Watchdog::from_env();
    let mut pending: ByTrial<Fits> = ByTrial::default();
    while !stop_requested() {
        watchdog.ping();
        let inputs: [&dyn Wakeable; 2] = [&requests, &fits_sub];
        match wait_any(&inputs, TICK) {
            Ok(_) => {}
            Err(_) if stop_requested() => break,
            Err(e) => return Err(e.into()),
        }
        while let Some(r) = requests.try_receive()? {
            pending.request(r);
        }
        while let Some(f) = fits_sub.try_receive()? {
            pending.input(f.trial_id, f);
        }
        while let Some(j) = joints_sub.try_receive()? {
            match j.joints.check() {
                Ok(()) => arm_now = j.joints.arm_rad,
                Err(e) => tracing::warn!("joint state ignored: {e}"),
            }
        }
        for (request, fits) in pending.take_ready() {
            let trial_id = request.trial_id;
            let method = request.method().unwrap_or("?").to_string();
            let started = std::time::Instant::now();
            let mut planned_ms = f64::NAN;
            let planned =
                plan_trial(config, &robot, &hand, &mut dbs, &request, &fits).and_then(|plan| {
                    planned_ms = started.elapsed().as_secs_f64() * 1e3;
                    plan.executable(&robot, &safety, &motions, &arm_now)
                });
            let msg = match planned {
                Ok(grasp) => GraspPlan::new(trial_id, monotonic_now_ns(), &grasp, &method)?,
                Err(failure) => {
                    tracing::warn!(trial_id, cause = ?failure.cause, "no plan: {}", failure.detail);
                    let method = if method.len() <= crate::ipc::NAME_CAPACITY {
                        method.as_str()
                    } else {
                        "?"
                    };
                    GraspPlan::failed(trial_id, monotonic_now_ns(), failure.cause, method)?
                }
            };
            plans.send(&msg)?;
            tracing::info!(
                trial_id,
                ms = started.elapsed().as_secs_f64() * 1e3,
                planned_ms,
                "plan published"
            );
        }
    }
    notify::stopping();
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::f64::consts::PI;

    #[test]
    fn methods_map_to_kernels() {
        for m in METHODS {
            assert!(method_kernel(m).is_some(), "{m}");
        }
        assert!(method_kernel("best-single").unwrap().1);
        assert!(!method_kernel("laplace").unwrap().1);
        assert!(method_kernel("nearest").is_none());
    }

    #[test]
    fn the_papers_protocol_plans_with_its_scale_and_weights_and_no_repair() {
        let config = crate::config::CellConfig::load(Path::new("robot/cell.toml")).unwrap();
        let mut dbs = Databases::new(Path::new("db"));
        let db = dbs.get("mug").unwrap();
        let cell = trial_options(&config, db, "gaussian-r", Protocol::Cell).unwrap();
        assert_eq!(cell.kernel, Kernel::GAUSSIAN_R_DEFAULT);
        assert_eq!(cell.weights, crate::plan::category::weights(db));
        assert!(cell.repair);
        let paper = trial_options(&config, db, "gaussian-r", Protocol::PaperRobot).unwrap();
        assert_eq!(paper.kernel, Kernel::paper_gaussian_r(700.0));
        assert_eq!(paper.weights, crate::plan::Weights::default());
        assert!(!paper.repair);
        let single = trial_options(&config, db, "best-single", Protocol::PaperRobot).unwrap();
        assert!(
            !single.repair,
            "no method is repaired in the paper's protocol"
        );
        assert!(trial_options(&config, db, "nearest", Protocol::Cell)
            .unwrap_err()
            .to_string()
            .contains("nearest"));
    }

    /// A top-down grasp over the table at `xyz` with its pre-grasp 10 cm above.
    fn top_grasp(xyz: [f64; 3]) -> PlannedGrasp {
        let pose = crate::geometry::pose_from_params(&[xyz[0], xyz[1], xyz[2], PI, 0.0, 0.0]);
        PlannedGrasp {
            pose,
            pregrasp_pose: nalgebra::Translation3::new(0.0, 0.0, 0.1) * pose,
            spread_rad: 0.0,
            preshape_rad: crate::robot::PreshapeRad::OPEN,
            joints: None,
            pregrasp_joints: None,
            reachable: true,
            unreachable: None,
            objective: 1.0,
            log_objective: 0.0,
        }
    }

    #[test]
    fn published_joints_are_ones_the_executor_accepts_even_from_a_far_branch() {
        let robot = Arc::new(crate::robot::shipped_robot());
        let config = crate::config::CellConfig::load(std::path::Path::new(
            crate::config::DEFAULT_CONFIG_PATH,
        ))
        .unwrap();
        let check = SafetyCheck::new(Arc::clone(&robot), SafetyLimits::from_cell(&config, &robot));
        let motions = ExecutorConfig::from_cell(&config);
        let home = config.robot.park_joints_rad;
        let mut grasp = top_grasp([0.6, 0.1, 0.2]);
        // The planner's solution on the branch with A1 turned by half a turn.
        let far = robot
            .ik
            .solve_from(&grasp.pregrasp_pose, &[-2.9, 0.6, 0.0, -1.2, 0.0, 0.8, 0.0]);
        grasp.pregrasp_joints = Some(far.joints);
        let far_grasp = robot.ik.solve_from(&grasp.pose, &far.joints);
        let from_far = ExecutionRequest {
            palm: PoseJson::from(&grasp.pose),
            pregrasp: PoseJson::from(&grasp.pregrasp_pose),
            joints_rad: far_grasp.joints,
            pregrasp_joints_rad: far.joints,
            spread_rad: 0.0,
            preshape_rad: crate::robot::PreshapeRad::OPEN,
            task: None,
            method: None,
        };
        assert!(
            validate_grasp(&check, &motions, &from_far, &home).is_err(),
            "test setup: the far branch is refused"
        );
        executable_joints(&robot, &check, &motions, &mut grasp, &home).unwrap();
        let request = ExecutionRequest {
            palm: PoseJson::from(&grasp.pose),
            pregrasp: PoseJson::from(&grasp.pregrasp_pose),
            joints_rad: grasp.joints.unwrap(),
            pregrasp_joints_rad: grasp.pregrasp_joints.unwrap(),
            spread_rad: 0.0,
            preshape_rad: crate::robot::PreshapeRad::OPEN,
            task: None,
            method: None,
        };
        validate_grasp(&check, &motions, &request, &home).unwrap();
        // A grasp with the palm in the table has no solution: a reachability failure.
        let mut low = top_grasp([0.6, 0.1, 0.01]);
        let failure = executable_joints(&robot, &check, &motions, &mut low, &home).unwrap_err();
        assert_eq!(failure.cause, FailureCause::Reachability, "{failure:?}");
        assert!(low.joints.is_none());
    }

    /// A refined grasp the executor refuses falls back to its start (the Laplace
    /// optimum) when the executor accepts that; without a fallback, or when the
    /// fallback is refused too, the refusal is the refined grasp's.
    #[test]
    fn a_refused_refined_grasp_falls_back_to_its_start() {
        let robot = Arc::new(crate::robot::shipped_robot());
        let config = CellConfig::load(Path::new(crate::config::DEFAULT_CONFIG_PATH)).unwrap();
        let check = SafetyCheck::new(Arc::clone(&robot), SafetyLimits::from_cell(&config, &robot));
        let motions = ExecutorConfig::from_cell(&config);
        let home = config.robot.park_joints_rad;
        let in_table = top_grasp([0.6, 0.1, 0.01]);
        let start = top_grasp([0.6, 0.1, 0.2]);
        let refused_alone =
            executable_joints(&robot, &check, &motions, &mut in_table.clone(), &home).unwrap_err();
        let plan = |fallback| TrialPlan {
            grasp: in_table.clone(),
            fallback,
        };
        let executed = plan(Some(start.clone()))
            .executable(&robot, &check, &motions, &home)
            .unwrap();
        assert_eq!(executed.pose, start.pose);
        assert!(executed.joints.is_some() && executed.pregrasp_joints.is_some());
        let alone = plan(None)
            .executable(&robot, &check, &motions, &home)
            .unwrap_err();
        assert_eq!(alone, refused_alone);
        let both = plan(Some(top_grasp([0.6, -0.1, 0.01])))
            .executable(&robot, &check, &motions, &home)
            .unwrap_err();
        assert_eq!(both, refused_alone);
    }

    #[test]
    fn the_cell_plans_clear_of_the_seen_surface_and_the_papers_protocol_ignores_it() {
        let config = CellConfig::load(Path::new(crate::config::DEFAULT_CONFIG_PATH)).unwrap();
        let robot = crate::robot::shipped_robot();
        let hand = crate::quality::autograsp::tests::hand_of(&robot);
        let mut dbs = Databases::new(Path::new("db"));
        let on_table = crate::geometry::pose_from_params(&[0.6, 0.0, 0.0, 0.0, 0.0, 0.3]);
        let fits: Vec<crate::ipc::ModelFit> = (0..3)
            .map(|i| crate::ipc::ModelFit::new(i, FitStatus::Converged, &on_table, 1e-5, 1e-5, 0.9))
            .collect();
        let fits = Fits::new(7, 0, &fits).unwrap();
        let request = |protocol| {
            TrialRequest::new(7, 0, "mug", "top", "laplace")
                .unwrap()
                .with_protocol(protocol)
        };
        let free = plan_trial(
            &config,
            &robot,
            &hand,
            &mut dbs,
            &request(Protocol::Cell),
            &fits,
        )
        .unwrap()
        .grasp;
        // Seen points filling a 10 cm cube around the free plan's pre-grasp.
        let c = free.pregrasp_pose.translation.vector;
        let mut wall = Vec::new();
        for i in 0..16 {
            for j in 0..16 {
                for k in 0..16 {
                    let d = |n: i32| (n as f32 - 7.5) * 0.0066;
                    wall.push(crate::ipc::Point::new(
                        c.x as f32 + d(i),
                        c.y as f32 + d(j),
                        c.z as f32 + d(k),
                    ));
                }
            }
        }
        let blocked = fits.with_seen(&wall).unwrap();
        let seen_cloud =
            PointCloud::from_points(blocked.seen().unwrap().iter().map(|&p| p.into()).collect());
        let options = SeenSurfaceOptions {
            contact_stops_approach: true,
            ..SeenSurfaceOptions::default()
        };
        let seen = SeenSurface::new(&hand, &seen_cloud, options).unwrap();
        assert!(
            seen.intrusion(&free.pose, &free.preshape_rad.at_spread(free.spread_rad))
                .is_some(),
            "test setup: the points block the free plan's approach"
        );
        match plan_trial(
            &config,
            &robot,
            &hand,
            &mut dbs,
            &request(Protocol::Cell),
            &blocked,
        ) {
            Ok(TrialPlan { grasp: clear, .. }) => assert_eq!(
                seen.intrusion(&clear.pose, &clear.preshape_rad.at_spread(clear.spread_rad)),
                None
            ),
            Err(failure) => assert_eq!(failure.cause, FailureCause::Reachability),
        }
        let paper = Protocol::PaperRobot;
        let as_published = plan_trial(&config, &robot, &hand, &mut dbs, &request(paper), &blocked)
            .unwrap()
            .grasp;
        let unblocked = plan_trial(&config, &robot, &hand, &mut dbs, &request(paper), &fits)
            .unwrap()
            .grasp;
        assert_eq!(
            as_published.pose, unblocked.pose,
            "the paper plans without it"
        );
    }

    #[test]
    fn unknown_categories_are_named() {
        let mut dbs = Databases::new(Path::new("db"));
        let err = dbs.get("../etc").unwrap_err().to_string();
        assert!(err.contains("../etc"), "{err}");
        let err = dbs.get("teapot").unwrap_err().to_string();
        assert!(err.contains("teapot"), "{err}");
    }
}
