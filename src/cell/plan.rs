//! `cell-plan`: the grasp for each trial from the fits of every category model.
//!
//! For a trial request (category, task, method) and the trial's fits it maximises
//! eq. 2 over the task's example grasps of every registered model with the method's
//! kernel (`laplace`, `gaussian`, `gaussian-r`), or takes the best-single baseline
//! (`best-single`), subject to the table and to inverse-kinematic reachability of
//! the grasp and its pre-grasp ([`crate::plan::plan`]); in the cell's protocol a
//! grasp whose motions the executor refuses is planned again with the executor's
//! checks in that constraint ([`plan_trial`]). It publishes the palm poses with the
//! joint solutions, or a plan marked failed with the cause: registration (no usable
//! fit), reachability (nothing reachable) or other (bad request).

use super::notify::{self, Watchdog};
use super::{stop_requested, ByTrial, CellError, TICK};
use crate::category::CategoryDb;
use crate::cloud::PointCloud;
use crate::config::CellConfig;
use crate::execute::{
    pregrasp_line_end, validate_grasp, ExecutionRequest, ExecutorConfig, SafetyCheck, SafetyLimits,
};
use crate::geometry::{Pose, PoseJson};
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
use crate::robot::ik::IkSolution;
use crate::robot::kinematics::ArmJoints;
use crate::robot::{HandPose, PreshapeRad, Robot, Unreachable};
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

/// Plans trial `request` from `fits` for the cell's arm and `hand`: the grasp to
/// execute, with joints whose motions `executor` accepts
/// ([`TrialPlan::executable`]), or why there is none. The planner checks that the
/// arm reaches the grasp and its pre-grasp (IK, collisions); in the cell's protocol
/// the open hand must also clear the seen surface the fits carry
/// ([`crate::plan::seen`]), and when the executor refuses the motions of the grasp
/// planned so, the trial is planned again with the executor's checks in the
/// planner's constraint ([`ExecutorReach`]): the best grasp the arm can also move
/// through. Only a refused plan pays for that search. The paper's protocol plans as
/// published, without either.
pub fn plan_trial(
    config: &CellConfig,
    executor: &ExecutorReach,
    hand: &HandModel,
    dbs: &mut Databases,
    request: &TrialRequest,
    fits: &Fits,
) -> Result<PlannedGrasp, PlanFailure> {
    let protocol = request.protocol().map_err(|e| PlanFailure {
        cause: FailureCause::Other,
        detail: e.to_string(),
    })?;
    let planned = plan_method(config, executor.robot, hand, dbs, request, fits)?;
    let refusal = match planned.executable(executor) {
        Err(refusal) if !protocol.is_paper() => refusal,
        done => return done,
    };
    let again = plan_method(config, executor, hand, dbs, request, fits)
        .and_then(|plan| plan.executable(executor));
    again.map_err(|second| PlanFailure {
        cause: refusal.cause,
        detail: format!(
            "{}; planned again for motions the executor accepts: {}",
            refusal.detail, second.detail
        ),
    })
}

/// [`plan_trial`]'s planning with the arm's reach `reach`: the method's grasp (and
/// `laplace-sim`'s fallback), not yet checked by the executor.
fn plan_method(
    config: &CellConfig,
    reach: &dyn Reachability,
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
    let reach = Some(reach);
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
    /// The method's grasp with joints whose motions the executor accepts
    /// ([`executable_joints`]), else the fallback's; the refusal of the method's
    /// grasp when neither is accepted.
    pub fn executable(self, executor: &ExecutorReach) -> Result<PlannedGrasp, PlanFailure> {
        let mut grasp = self.grasp;
        let refusal = match executable_joints(executor, &mut grasp) {
            Ok(()) => return Ok(grasp),
            Err(refusal) => refusal,
        };
        let Some(mut start) = self.fallback else {
            return Err(refusal);
        };
        match executable_joints(executor, &mut start) {
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

/// Picks joint solutions for `grasp` whose motions the executor will accept
/// ([`ExecutorReach::accepted`]); a reachability failure, with the executor's
/// refusal of the first candidate, when none is accepted.
pub fn executable_joints(
    executor: &ExecutorReach,
    grasp: &mut PlannedGrasp,
) -> Result<(), PlanFailure> {
    let hand = grasp.preshape_rad.at_spread(grasp.spread_rad);
    let (pre, at) = executor
        .accepted(
            &grasp.pose,
            &grasp.pregrasp_pose,
            &hand,
            grasp.pregrasp_joints,
            grasp.joints,
        )
        .map_err(|detail| PlanFailure {
            cause: FailureCause::Reachability,
            detail,
        })?;
    grasp.pregrasp_joints = Some(pre);
    grasp.joints = Some(at);
    Ok(())
}

/// The arm's reach as the executor judges it: the robot's checks of each pose, and
/// for a grasp whose poses pass them, the executor's acceptance of the motions
/// through them from the arm at `current` ([`Reachability::motions`]). The planner
/// needs only some IK solution of each pose, and a straight approach from it may
/// still put the forearm on the table; planning with this (the cell's protocol)
/// returns an optimum the executor takes. The paper's protocol plans with the
/// robot alone.
#[derive(Clone, Copy)]
pub struct ExecutorReach<'a> {
    /// The arm.
    pub robot: &'a Robot,
    /// The executor's safety checks.
    pub check: &'a SafetyCheck,
    /// The executor's motion settings.
    pub config: &'a ExecutorConfig,
    /// The arm's joints where the trial's motions start (rad).
    pub current: ArmJoints,
}

impl ExecutorReach<'_> {
    /// Joint solutions (pre-grasp, grasp) of the grasp at `palm` with its pre-grasp
    /// `pregrasp` and `hand` whose motions from `current` the executor accepts
    /// ([`validate_grasp`]: pre-grasp move, approach, lift, with its safety checks),
    /// or the executor's refusal of the first candidate. From its generic seeds the
    /// planner may have found an IK solution on another branch (shoulder turned by
    /// half a turn) that the executor's joint-space move could not reach safely, so
    /// pre-grasp solutions are tried seeded first with `current`, the planner's
    /// solution `planned_pre` and its equivalents
    /// ([`crate::robot::kinematics::ArmKinematics::equivalents`]), the end of the
    /// palm's straight line from `current` ([`pregrasp_line_end`]), then the IK's
    /// spread of seeds; the grasp is solved near each (and near `planned_at`).
    pub fn accepted(
        &self,
        palm: &Pose,
        pregrasp: &Pose,
        hand: &HandPose,
        planned_pre: Option<ArmJoints>,
        planned_at: Option<ArmJoints>,
    ) -> Result<(ArmJoints, ArmJoints), String> {
        let (robot, current) = (self.robot, &self.current);
        let mut seeds = vec![*current];
        if let Some(planned) = planned_pre {
            // The planner's solution, then its equivalents (the same pose with a
            // shoulder, elbow or wrist flipped) nearest the arm first: the IK's
            // generic seeds may have found the branch half a turn away.
            seeds.push(planned);
            seeds.extend(robot.arm().equivalents(&planned, current));
        }
        // Then the end of the palm's straight line from where it is: a pre-grasp the
        // executor can reach along the line where a joint-space swing is refused.
        seeds.extend(pregrasp_line_end(robot, self.config, current, pregrasp));
        let mut first_refusal = None;
        let mut accepted = None;
        let _ = robot.ik.solve_with(pregrasp, &seeds, |pre| {
            match self.accepted_from(palm, pregrasp, hand, &pre.joints, planned_at) {
                Ok(joints) => accepted = Some(joints),
                Err(refusal) => {
                    first_refusal = first_refusal.take().or(refusal);
                }
            }
            accepted.is_some()
        });
        accepted.ok_or_else(|| refused(first_refusal))
    }

    /// The grasp's joints near `planned_at` and `pre` (a pre-grasp solution) when
    /// the executor accepts the motions from `pre`; else the executor's refusal, if
    /// the poses are collision-free.
    fn accepted_from(
        &self,
        palm: &Pose,
        pregrasp: &Pose,
        hand: &HandPose,
        pre: &ArmJoints,
        planned_at: Option<ArmJoints>,
    ) -> Result<(ArmJoints, ArmJoints), Option<String>> {
        let robot = self.robot;
        if robot.collision_at(pre, hand).is_some() {
            return Err(None);
        }
        let mut near = vec![*pre];
        near.extend(planned_at);
        let at = robot.reach(palm, hand, &near).map_err(|_| None)?;
        let request = ExecutionRequest {
            palm: PoseJson::from(palm),
            pregrasp: PoseJson::from(pregrasp),
            joints_rad: at.joints,
            pregrasp_joints_rad: *pre,
            spread_rad: hand.spread_rad,
            preshape_rad: PreshapeRad(hand.flex_rad),
            max_overtravel_m: None,
            task: None,
            method: None,
        };
        validate_grasp(self.check, self.config, &request, &self.current)
            .map(|_| (*pre, at.joints))
            .map_err(|e| Some(e.to_string()))
    }
}

/// Why no joint solution of a grasp was accepted, from the executor's first refusal.
fn refused(first_refusal: Option<String>) -> String {
    match first_refusal {
        Some(refusal) => format!("no joint solution the executor accepts: {refusal}"),
        None => "no collision-free joint solution of the pre-grasp and grasp poses".into(),
    }
}

impl Reachability for ExecutorReach<'_> {
    fn reach(
        &self,
        palm: &Pose,
        hand: &HandPose,
        seeds: &[ArmJoints],
    ) -> Result<IkSolution, Unreachable> {
        Reachability::reach(self.robot, palm, hand, seeds)
    }

    fn reach_near(
        &self,
        palm: &Pose,
        hand: &HandPose,
        seeds: &[ArmJoints],
    ) -> Result<IkSolution, Unreachable> {
        self.robot.reach_near(palm, hand, seeds)
    }

    fn repair_near(
        &self,
        palm: &Pose,
        hand: &HandPose,
        seeds: &[ArmJoints],
    ) -> Option<(Pose, IkSolution)> {
        self.robot.repair_near(palm, hand, seeds)
    }

    fn nearest_reachable(&self, palm: &Pose, hand: &HandPose) -> Option<(Pose, IkSolution)> {
        self.robot.nearest_reachable(palm, hand)
    }

    /// The motions from the planner's own solutions `pre` and `at`, else from a
    /// pre-grasp solved near `current`: a quick check, as the planner asks it of
    /// every candidate. [`ExecutorReach::accepted`] then searches wider for the
    /// joints of the chosen grasp (the same first candidates, then more).
    fn motions(
        &self,
        palm: &Pose,
        pregrasp: &Pose,
        hand: &HandPose,
        at: &ArmJoints,
        pre: &ArmJoints,
    ) -> Result<(), String> {
        let planned = self.accepted_from(palm, pregrasp, hand, pre, Some(*at));
        let Err(first_refusal) = planned else {
            return Ok(());
        };
        let near_arm = self.robot.ik.solve_from(pregrasp, &self.current);
        if near_arm.converged(self.robot.ik.options()) {
            let from_arm = self.accepted_from(palm, pregrasp, hand, &near_arm.joints, Some(*at));
            if from_arm.is_ok() {
                return Ok(());
            }
        }
        Err(refused(first_refusal))
    }
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
            let executor = ExecutorReach {
                robot: &robot,
                check: &safety,
                config: &motions,
                current: arm_now,
            };
            let planned = plan_trial(config, &executor, &hand, &mut dbs, &request, &fits);
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

    /// The shipped robot with the executor's checks and settings of the default
    /// configuration, parked.
    struct Rig {
        config: CellConfig,
        robot: Arc<Robot>,
        check: SafetyCheck,
        motions: ExecutorConfig,
    }

    impl Rig {
        fn new() -> Rig {
            let config = CellConfig::load(Path::new(crate::config::DEFAULT_CONFIG_PATH)).unwrap();
            let robot = Arc::new(crate::robot::shipped_robot());
            let check =
                SafetyCheck::new(Arc::clone(&robot), SafetyLimits::from_cell(&config, &robot));
            let motions = ExecutorConfig::from_cell(&config);
            Rig {
                config,
                robot,
                check,
                motions,
            }
        }

        /// The executor's safety layer with the palm forbidden below `z_m`.
        fn palm_above(&self, z_m: f64) -> SafetyCheck {
            let mut limits = SafetyLimits::from_cell(&self.config, &self.robot);
            limits.min_palm_z_m = z_m;
            SafetyCheck::new(Arc::clone(&self.robot), limits)
        }

        fn executor(&self) -> ExecutorReach<'_> {
            ExecutorReach {
                robot: &self.robot,
                check: &self.check,
                config: &self.motions,
                current: self.config.robot.park_joints_rad,
            }
        }
    }

    /// A top-down grasp over the table at `xyz` with its pre-grasp 10 cm above.
    fn top_grasp(xyz: [f64; 3]) -> PlannedGrasp {
        let pose = crate::geometry::pose_from_params(&[xyz[0], xyz[1], xyz[2], PI, 0.0, 0.0]);
        PlannedGrasp {
            pose,
            pregrasp_pose: nalgebra::Translation3::new(0.0, 0.0, 0.1) * pose,
            spread_rad: 0.0,
            preshape_rad: crate::robot::PreshapeRad::OPEN,
            max_overtravel_m: None,
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
        let rig = Rig::new();
        let (robot, check, motions) = (&rig.robot, &rig.check, &rig.motions);
        let home = rig.config.robot.park_joints_rad;
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
            max_overtravel_m: None,
            task: None,
            method: None,
        };
        assert!(
            validate_grasp(check, motions, &from_far, &home).is_err(),
            "test setup: the far branch is refused"
        );
        executable_joints(&rig.executor(), &mut grasp).unwrap();
        let request = ExecutionRequest {
            palm: PoseJson::from(&grasp.pose),
            pregrasp: PoseJson::from(&grasp.pregrasp_pose),
            joints_rad: grasp.joints.unwrap(),
            pregrasp_joints_rad: grasp.pregrasp_joints.unwrap(),
            spread_rad: 0.0,
            preshape_rad: crate::robot::PreshapeRad::OPEN,
            max_overtravel_m: None,
            task: None,
            method: None,
        };
        validate_grasp(check, motions, &request, &home).unwrap();
        // A grasp with the palm in the table has no solution: a reachability failure.
        let mut low = top_grasp([0.6, 0.1, 0.01]);
        let failure = executable_joints(&rig.executor(), &mut low).unwrap_err();
        assert_eq!(failure.cause, FailureCause::Reachability, "{failure:?}");
        assert!(low.joints.is_none());
    }

    /// The cell plans with the executor's judgement of the motions: a top grasp the
    /// arm reaches, with its pre-grasp, is refused when the safety layer forbids the
    /// palm on the way down (its lowest palm height raised above the grasp), and
    /// the refusal names the approach; with the cell's own limits it is accepted.
    /// The approach goes as far beyond the grasp as the safety layer allows, a
    /// quarter of the configured overtravel at a time: all of it high over the
    /// table, less where the open fingers would end in it, none where only the
    /// planned pose itself is allowed.
    #[test]
    fn the_approach_overtravel_is_the_longest_the_safety_layer_allows() {
        let rig = Rig::new();
        let max = rig.motions.approach.max_overtravel_m;
        let overtravel_of = |z: f64, own: Option<f64>| {
            let mut grasp = top_grasp([0.6, 0.0, z]);
            grasp.max_overtravel_m = own;
            executable_joints(&rig.executor(), &mut grasp).unwrap();
            let request = ExecutionRequest::from_planned(&grasp, "top", "laplace").unwrap();
            let home = rig.config.robot.park_joints_rad;
            validate_grasp(&rig.check, &rig.motions, &request, &home)
                .unwrap()
                .overtravel_m
        };
        let overtravel = |z: f64| overtravel_of(z, None);
        // The open fingers reach about 0.1 m below the palm, and the palm may go
        // no lower than 0.05 m.
        for (z, quarters) in [
            (0.2, 4.0),
            (0.15, 3.0),
            (0.13, 2.0),
            (0.12, 1.0),
            (0.11, 0.0),
        ] {
            let expected = quarters / 4.0 * max;
            assert!((overtravel(z) - expected).abs() < 1e-12, "palm at z = {z}");
        }
        // A grasp that names its own overtravel (the mug's rim pinches: none) goes
        // no farther, high over the table or not; a longer one is cut the same way.
        assert_eq!(overtravel_of(0.2, Some(0.0)), 0.0);
        assert!((overtravel_of(0.2, Some(0.02)) - 0.02).abs() < 1e-12);
        assert!((overtravel_of(0.13, Some(0.08)) - 0.02).abs() < 1e-12);
    }

    #[test]
    fn the_executors_reach_refuses_a_grasp_the_arm_reaches_but_cannot_move_through() {
        let rig = Rig::new();
        let grasp = top_grasp([0.6, 0.1, 0.2]);
        let hand = HandPose::OPEN;
        let at = Reachability::reach(&*rig.robot, &grasp.pose, &hand, &[]).unwrap();
        let pre =
            Reachability::reach(&*rig.robot, &grasp.pregrasp_pose, &hand, &[at.joints]).unwrap();
        let motions = |executor: &ExecutorReach| {
            executor.motions(
                &grasp.pose,
                &grasp.pregrasp_pose,
                &hand,
                &at.joints,
                &pre.joints,
            )
        };
        motions(&rig.executor()).unwrap();
        let strict = rig.palm_above(0.25);
        let executor = ExecutorReach {
            check: &strict,
            ..rig.executor()
        };
        let why = motions(&executor).unwrap_err();
        assert!(why.contains("approach"), "{why}");
        let failure = executable_joints(&executor, &mut grasp.clone()).unwrap_err();
        assert_eq!(failure.cause, FailureCause::Reachability);
        assert!(failure.detail.contains("approach"), "{}", failure.detail);
    }

    /// A refined grasp the executor refuses falls back to its start (the Laplace
    /// optimum) when the executor accepts that; without a fallback, or when the
    /// fallback is refused too, the refusal is the refined grasp's.
    #[test]
    fn a_refused_refined_grasp_falls_back_to_its_start() {
        let rig = Rig::new();
        let executor = rig.executor();
        let in_table = top_grasp([0.6, 0.1, 0.01]);
        let start = top_grasp([0.6, 0.1, 0.2]);
        let refused_alone = executable_joints(&executor, &mut in_table.clone()).unwrap_err();
        let plan = |fallback| TrialPlan {
            grasp: in_table.clone(),
            fallback,
        };
        let executed = plan(Some(start.clone())).executable(&executor).unwrap();
        assert_eq!(executed.pose, start.pose);
        assert!(executed.joints.is_some() && executed.pregrasp_joints.is_some());
        let alone = plan(None).executable(&executor).unwrap_err();
        assert_eq!(alone, refused_alone);
        let both = plan(Some(top_grasp([0.6, -0.1, 0.01])))
            .executable(&executor)
            .unwrap_err();
        assert_eq!(both, refused_alone);
    }

    /// Three mug models fitted at (0.6, 0) on the table, turned by 0.3 rad.
    fn mug_fits() -> Fits {
        let on_table = crate::geometry::pose_from_params(&[0.6, 0.0, 0.0, 0.0, 0.0, 0.3]);
        let fits: Vec<crate::ipc::ModelFit> = (0..3)
            .map(|i| crate::ipc::ModelFit::new(i, FitStatus::Converged, &on_table, 1e-5, 1e-5, 0.9))
            .collect();
        Fits::new(7, 0, &fits).unwrap()
    }

    /// Trial 7's request: the mug's top grasp by Laplace, under `protocol`.
    fn mug_top(protocol: Protocol) -> TrialRequest {
        TrialRequest::new(7, 0, "mug", "top", "laplace")
            .unwrap()
            .with_protocol(protocol)
    }

    /// A plan the executor refuses is planned again with the executor's checks in
    /// the planner's constraint, in the cell's protocol: with a safety layer that
    /// forbids the palm below 0.25 m, the mug's top grasp (palm lower) is refused,
    /// and the trial gets a grasp the executor moves through instead. The paper's
    /// protocol does not plan again: the refusal is its failure.
    #[test]
    fn a_refused_plan_is_planned_again_for_motions_the_executor_accepts() {
        let rig = Rig::new();
        let hand = crate::quality::autograsp::tests::hand_of(&rig.robot);
        let mut dbs = Databases::new(Path::new("db"));
        let fits = mug_fits();
        let free = plan_trial(
            &rig.config,
            &rig.executor(),
            &hand,
            &mut dbs,
            &mug_top(Protocol::Cell),
            &fits,
        )
        .unwrap();
        assert!(
            free.pose.translation.z < 0.25,
            "test setup: {:?}",
            free.pose
        );
        let strict = rig.palm_above(0.25);
        let executor = ExecutorReach {
            check: &strict,
            ..rig.executor()
        };
        assert!(executable_joints(&executor, &mut free.clone()).is_err());
        let again = plan_trial(
            &rig.config,
            &executor,
            &hand,
            &mut dbs,
            &mug_top(Protocol::Cell),
            &fits,
        )
        .unwrap();
        assert!(again.pose.translation.z >= 0.25, "{:?}", again.pose);
        assert!(again.joints.is_some() && again.pregrasp_joints.is_some());
        let mut check = again.clone();
        executable_joints(&executor, &mut check).unwrap();
        let paper = plan_trial(
            &rig.config,
            &executor,
            &hand,
            &mut dbs,
            &mug_top(Protocol::PaperRobot),
            &fits,
        )
        .unwrap_err();
        assert_eq!(paper.cause, FailureCause::Reachability);
        assert!(
            paper.detail.contains("executor accepts"),
            "{}",
            paper.detail
        );
    }

    #[test]
    fn the_cell_plans_clear_of_the_seen_surface_and_the_papers_protocol_ignores_it() {
        let rig = Rig::new();
        let (config, executor) = (&rig.config, rig.executor());
        let hand = crate::quality::autograsp::tests::hand_of(&rig.robot);
        let mut dbs = Databases::new(Path::new("db"));
        let fits = mug_fits();
        let request = mug_top;
        let free = plan_trial(
            config,
            &executor,
            &hand,
            &mut dbs,
            &request(Protocol::Cell),
            &fits,
        )
        .unwrap();
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
            config,
            &executor,
            &hand,
            &mut dbs,
            &request(Protocol::Cell),
            &blocked,
        ) {
            Ok(clear) => assert_eq!(
                seen.intrusion(&clear.pose, &clear.preshape_rad.at_spread(clear.spread_rad)),
                None
            ),
            Err(failure) => assert_eq!(failure.cause, FailureCause::Reachability),
        }
        let paper = Protocol::PaperRobot;
        let as_published = plan_trial(
            config,
            &executor,
            &hand,
            &mut dbs,
            &request(paper),
            &blocked,
        )
        .unwrap();
        let unblocked =
            plan_trial(config, &executor, &hand, &mut dbs, &request(paper), &fits).unwrap();
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
