//! The planner: multi-start Nelder–Mead over the palm pose, the table bound by a
//! variable transform, reachability of the grasp and the pre-grasp, and the
//! best-single baseline.
//!
//! **Search space.** The palm pose in the world, in a local chart around each run's
//! start ([`Chart`]): `[x, y, u, r1, r2, r3]` with `z = z_min + u^2` (the paper's
//! transformation of the bound `z >= z_min`; `z_min` is the table height plus the
//! palm clearance) and the orientation the start's turned by the rotation vector
//! `r`, so that no search crosses a singularity of Euler angles. The optimiser
//! minimises `-ln f` (eq. 2), which has the same argmax as `f` and stays finite far
//! from every grasp.
//!
//! **Starts.** One run from every example grasp of the task mapped into the world,
//! `T_i * theta_ik` (runs are independent; they go in parallel with `parallel`).
//!
//! **Reachability** is kept out of the inner loop, where it would cost a few hundred
//! microseconds per evaluation:
//! 1. optimise without it; take the best optimum and check the grasp and its
//!    pre-grasp (the grasp backed off along the palm's -z by `pregrasp_offset_m`) with
//!    the full check (all IK seeds, collisions). Reachable: done.
//! 2. Otherwise record it as the unconstrained optimum and look for reachable points
//!    (at most `feasibility_budget` full checks, until `constrained_starts` are found):
//!    the reachability's own projection of the optimum and of its pre-grasp (for the
//!    robot: the collision-free IK attempt nearest the pose), the other optima and
//!    the starts (best objective first), probes from the optimum along each world axis
//!    and about each of the palm's own axes (1, 3, 9, 27 cm or 0.1, 0.3, 0.9, 2.7 rad,
//!    nearest first), and the runs' intermediate best points; when none of those is
//!    reachable, with a budget of their own, the optimum turned about the object's
//!    vertical axis (30 and 60 degrees either way) and, when it approaches from the
//!    side, tilted to approach from above (22.5 and 45 degrees), which are taken
//!    without the constrained runs of step 3; plus the last reachable
//!    point on the segment from the best of those toward the unconstrained optimum
//!    (bisection, in the chart centred on the reachable point).
//! 3. From each of them, a constrained Nelder–Mead run (1 mm / 1e-3 tolerances,
//!    restarted from its result while it still gains): every evaluation *repairs* the
//!    candidate into a reachable pose near it ([`Reachability::repair_near`]; for the
//!    robot, local IK from nearby configurations, the pose it reaches when it cannot
//!    reach the candidate), scores the repaired pose's `-ln f` plus its distance to
//!    the candidate, and is `+inf` when nothing reachable is found — so an unreachable
//!    pose never scores, and the search slides along the boundary instead of stalling
//!    on it. A repaired pose better than the best so far must also pass the motions
//!    check (below), else it scores `+inf` too. The best repaired pose is the
//!    answer, confirmed by the full check and reported with the unconstrained
//!    optimum it replaces.
//!
//! **Motions.** Every check of a grasp whose two poses are reached ends with
//! [`Reachability::motions`]: whether the arm can move through them (to the
//! pre-grasp, along the approach, the lift). The robot alone accepts every pair; the
//! cell's protocol plans with the executor's own checks
//! ([`crate::cell::plan::ExecutorReach`]), so that an approach that would put the
//! forearm on the table is infeasible like an unreachable pose.
//!
//! The hand is in the pre-shape (open for most grasps) and at the spread of the
//! **dominant grasp** — the example grasp whose term of eq. 2 is largest at the
//! pose — at both the grasp and the pre-grasp.
//!
//! **Best single** (the baseline): the model with the largest fit weight `phi` that
//! has a grasp of the task; of its grasps of the task the one of highest quality `q`
//! (the first among equals), mapped into the world by that model's `T_i`.

use super::chart::{rotated_about_own_axes, Chart};
use super::nelder_mead::{nelder_mead_with_steps, NelderMeadOptions};
use super::objective::Objective;
use super::reach::Reachability;
use super::seen::{Intrusion, SeenSurface};
use super::{ExampleGrasp, Kernel, ModelFit, PlanError, Weights};
use crate::config::CellConfig;
use crate::geometry::{pose_error, pose_from_params, rotation_about, Pose, PoseJson};
use crate::robot::ik::IkSolution;
use crate::robot::kinematics::ArmJoints;
use crate::robot::{HandPose, PreshapeRad, UnreachableReason};
use nalgebra::Translation3;
use rayon::prelude::*;
use serde::{Serialize, Serializer};

/// Everything the planner needs besides the fits and grasps.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct PlanOptions {
    /// Task-compatibility density.
    pub kernel: Kernel,
    /// Stability and fit weights.
    pub weights: Weights,
    /// Lowest palm height (m, world z): the table height plus the palm clearance.
    pub z_min_m: f64,
    /// The pre-grasp backs off from the grasp along the palm's -z by this (m).
    pub pregrasp_offset_m: f64,
    /// Stopping rules of each unconstrained Nelder–Mead run (`fminsearch` defaults).
    #[serde(skip)]
    pub nelder_mead: NelderMeadOptions,
    /// Stopping rules of each constrained run (where every evaluation checks
    /// reachability): 1 mm and 1e-3 rad, the scale of the IK's own tolerances, and
    /// at most 400 evaluations.
    #[serde(skip)]
    pub constrained_nelder_mead: NelderMeadOptions,
    /// Run the unconstrained starts in parallel (rayon).
    pub parallel: bool,
    /// Constrained runs when the unconstrained optimum is unreachable (plus one from
    /// the bisection point).
    pub constrained_starts: usize,
    /// Most full reachability checks spent finding reachable starting points.
    pub feasibility_budget: usize,
    /// Repair unreachable grasps — the plan's optimum and the best-single grasp
    /// alike — by the constrained search (steps 2-3 of the module doc). Off in the
    /// paper's mode ([`super::mode::PlanMode`]): an unreachable grasp is returned
    /// marked unreachable.
    pub repair: bool,
    /// Repair the best-single grasp too (with `repair`). A caller that wants only
    /// the plan may turn this off to save the baseline's constrained search; the
    /// baseline is then checked but not repaired.
    pub repair_best_single: bool,
}

impl PlanOptions {
    /// Options for `kernel` in the cell of `config` (table, clearance, pre-grasp
    /// offset), with the default weights and stopping rules.
    pub fn new(kernel: Kernel, config: &CellConfig) -> PlanOptions {
        PlanOptions {
            z_min_m: config.table.height_m + config.table.palm_clearance_m,
            pregrasp_offset_m: config.robot.pregrasp_offset_m,
            ..PlanOptions::with_kernel(kernel)
        }
    }

    /// Options for `kernel` with a table at z = 0, the paper's 50 mm bound and a 0.1 m
    /// pre-grasp offset.
    pub fn with_kernel(kernel: Kernel) -> PlanOptions {
        PlanOptions {
            kernel,
            weights: Weights::default(),
            z_min_m: 0.05,
            pregrasp_offset_m: 0.10,
            nelder_mead: NelderMeadOptions::default(),
            constrained_nelder_mead: NelderMeadOptions {
                tol_x: 1e-3,
                tol_fun: 1e-3,
                max_iterations: None,
                max_evaluations: Some(400),
            },
            parallel: true,
            constrained_starts: 2,
            feasibility_budget: 48,
            repair: true,
            repair_best_single: true,
        }
    }
}

/// Serialises a pose as [`PoseJson`].
fn pose_json<S: Serializer>(pose: &Pose, s: S) -> Result<S::Ok, S::Error> {
    PoseJson::from(pose).serialize(s)
}

/// Which part of a grasp could not be done: one of its two poses, or the motions
/// through them.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Stage {
    /// The grasp pose.
    Grasp,
    /// The pre-grasp pose.
    Pregrasp,
    /// The move to the pre-grasp, the approach or the lift
    /// ([`Reachability::motions`]).
    Motions,
}

/// What stops a grasp.
#[derive(Debug, Clone, PartialEq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Blocked {
    /// The arm cannot reach the pose.
    Unreachable(UnreachableReason),
    /// The open hand enters the seen surface at the grasp or along its approach.
    SeenSurface(Intrusion),
    /// The arm reaches both poses but cannot move through them (why).
    Motions(String),
}

impl std::fmt::Display for Blocked {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Blocked::Unreachable(r) => write!(f, "unreachable: {r}"),
            Blocked::SeenSurface(i) => write!(f, "blocked by the seen surface: {i}"),
            Blocked::Motions(why) => write!(f, "refused: {why}"),
        }
    }
}

/// Why a grasp is infeasible.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Infeasible {
    /// The pose that failed.
    pub stage: Stage,
    /// Why.
    pub reason: Blocked,
}

impl std::fmt::Display for Infeasible {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let stage = match self.stage {
            Stage::Grasp => "grasp",
            Stage::Pregrasp => "pre-grasp",
            Stage::Motions => "motions",
        };
        write!(f, "{stage} {}", self.reason)
    }
}

/// A grasp pose with its pre-grasp, hand spread, reachability and objective.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct PlannedGrasp {
    /// Palm pose in the world.
    #[serde(serialize_with = "pose_json")]
    pub pose: Pose,
    /// Pre-grasp palm pose.
    #[serde(serialize_with = "pose_json")]
    pub pregrasp_pose: Pose,
    /// Hand spread (rad).
    pub spread_rad: f64,
    /// The pre-shape (each finger's flex before the approach, rad) of the model
    /// grasp the plan came from (the dominant one); open for most grasps, and then
    /// left out of the JSON.
    #[serde(skip_serializing_if = "PreshapeRad::is_open")]
    pub preshape_rad: PreshapeRad,
    /// How far beyond `pose` the approach to contact may go (m), when the model
    /// grasp names it; else the cell's `approach.max_overtravel_m` (and left out of
    /// the JSON).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub max_overtravel_m: Option<f64>,
    /// Arm joints at the grasp, when reachable.
    pub joints: Option<ArmJoints>,
    /// Arm joints at the pre-grasp, when reachable.
    pub pregrasp_joints: Option<ArmJoints>,
    /// Both poses were checked and are reachable.
    pub reachable: bool,
    /// Why not, when checked and unreachable.
    pub unreachable: Option<Infeasible>,
    /// Eq. 2 at the pose, with normalising constants (1/(m^3 rad^3)).
    pub objective: f64,
    /// Its natural logarithm (finite where `objective` underflows).
    pub log_objective: f64,
}

/// The best unconstrained optimum, reported when it was unreachable.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct UnconstrainedOptimum {
    /// Palm pose.
    #[serde(serialize_with = "pose_json")]
    pub pose: Pose,
    /// Eq. 2 there.
    pub objective: f64,
    /// Its logarithm.
    pub log_objective: f64,
    /// Why it cannot be used.
    pub unreachable: Infeasible,
}

/// The planned grasp.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct GraspPlan {
    /// The task.
    pub task: String,
    /// The density used.
    pub kernel: Kernel,
    /// The grasp (reachable unless no reachable point was found).
    #[serde(flatten)]
    pub grasp: PlannedGrasp,
    /// Index (into the grasps) of the dominant grasp, whose spread is used.
    pub dominant_grasp: usize,
    /// Each model's part of the objective at the pose (indexed like the fits; sums to
    /// `objective`).
    pub per_model_contribution: Vec<f64>,
    /// Whether reachability was checked (false in the paper's simulation setting).
    pub reachability_checked: bool,
    /// The best unconstrained optimum, when it was unreachable and the grasp above is
    /// the best reachable one found instead.
    pub unconstrained_optimum: Option<UnconstrainedOptimum>,
    /// Unconstrained runs (one per grasp of the task).
    pub starts: usize,
    /// Constrained runs.
    pub constrained_runs: usize,
    /// Objective evaluations over all runs.
    pub evaluations: usize,
    /// Reachability checks (grasp and pre-grasp each count).
    pub reach_checks: usize,
}

/// The best-single baseline.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct BestSingle {
    /// Index of the best-fitting model with a grasp of the task.
    pub model: usize,
    /// Its name.
    pub model_name: String,
    /// Index of its grasp used.
    pub grasp_index: usize,
    /// The grasp mapped into the world, its reachability and objective (or, when
    /// that was unreachable and repaired, the best reachable grasp near it).
    #[serde(flatten)]
    pub grasp: PlannedGrasp,
    /// The grasp as mapped, when it was unreachable and the grasp above is its
    /// repair.
    pub unrepaired: Option<UnconstrainedOptimum>,
    /// Constrained runs of the repair.
    pub constrained_runs: usize,
}

/// The planner's answer: the plan and the baseline.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct PlanOutcome {
    /// The planned grasp.
    pub plan: GraspPlan,
    /// The best-single baseline.
    pub best_single: BestSingle,
}

/// The initial simplex of a run in its chart ([`Chart`]): `fminsearch`'s rule (5 %,
/// or 0.00025 for a zero) on the position coordinates, as the paper's search had,
/// and [`INITIAL_STEP_RAD`] on each rotation coordinate (which start at 0, the
/// chart's centre).
fn initial_steps(x0: &[f64; 6]) -> [f64; 6] {
    std::array::from_fn(|i| {
        if i >= 3 {
            INITIAL_STEP_RAD
        } else if x0[i] != 0.0 {
            0.05 * x0[i]
        } else {
            0.00025
        }
    })
}

/// The initial simplex's step on each rotation coordinate (rad, about 3 deg).
pub const INITIAL_STEP_RAD: f64 = 0.05;

/// `pose` with its height raised to `z_min_m` when below it.
fn above(mut pose: Pose, z_min_m: f64) -> Pose {
    pose.translation.z = pose.translation.z.max(z_min_m);
    pose
}

/// The pre-grasp of a grasp: backed off along the palm's -z by `offset_m`.
pub fn pregrasp_pose(grasp: &Pose, offset_m: f64) -> Pose {
    grasp * Translation3::new(0.0, 0.0, -offset_m)
}

/// IK solutions of a feasible grasp and its pre-grasp.
#[derive(Debug, Clone, Copy)]
struct Feasible {
    grasp: IkSolution,
    pregrasp: IkSolution,
}

/// Checks grasp and pre-grasp: the full check (`quick = false`; `seeds` first) or the
/// quick one from the nearby configurations `seeds`. The pre-grasp is tried from the
/// grasp's solution first, then from `pre_seeds`.
#[derive(Clone, Copy)]
struct Checker<'a> {
    reach: &'a dyn Reachability,
    /// The seen surface the open hand must not enter (with its approach).
    seen: Option<&'a SeenSurface<'a>>,
    offset_m: f64,
    checks: usize,
}

impl Checker<'_> {
    /// `work` on each of `items` with a checker of its own (in parallel when
    /// `parallel`), results in the items' order; their checks are added to this one's.
    fn map_forked<T: Sync, R: Send>(
        &mut self,
        items: &[T],
        parallel: bool,
        work: impl Fn(&mut Checker, &T) -> R + Sync,
    ) -> Vec<R> {
        let fork = Checker { checks: 0, ..*self };
        let one = |item: &T| {
            let mut own = fork;
            let r = work(&mut own, item);
            (r, own.checks)
        };
        let done: Vec<(R, usize)> = if parallel && items.len() > 1 {
            items.par_iter().map(one).collect()
        } else {
            items.iter().map(one).collect()
        };
        self.checks += done.iter().map(|d| d.1).sum::<usize>();
        done.into_iter().map(|d| d.0).collect()
    }

    fn check(
        &mut self,
        pose: &Pose,
        hand: &HandPose,
        seeds: &[ArmJoints],
        pre_seeds: &[ArmJoints],
        quick: bool,
    ) -> Result<Feasible, Infeasible> {
        let fail = |stage| {
            move |u: crate::robot::Unreachable| Infeasible {
                stage,
                reason: Blocked::Unreachable(u.reason),
            }
        };
        if let Some(hit) = self.seen.and_then(|s| s.intrusion(pose, hand)) {
            return Err(Infeasible {
                stage: Stage::Grasp,
                reason: Blocked::SeenSurface(hit),
            });
        }
        let reach = |palm: &Pose, seeds: &[ArmJoints]| {
            if quick {
                self.reach.reach_near(palm, hand, seeds)
            } else {
                self.reach.reach(palm, hand, seeds)
            }
        };
        self.checks += 1;
        let grasp = reach(pose, seeds).map_err(fail(Stage::Grasp))?;
        self.checks += 1;
        let pre = pregrasp_pose(pose, self.offset_m);
        let pre_seeds: Vec<ArmJoints> = std::iter::once(grasp.joints)
            .chain(pre_seeds.iter().copied())
            .collect();
        let pregrasp = reach(&pre, &pre_seeds).map_err(fail(Stage::Pregrasp))?;
        self.motions(pose, &pre, hand, &grasp, &pregrasp)?;
        Ok(Feasible { grasp, pregrasp })
    }

    /// [`Reachability::motions`] through a grasp whose poses are reached.
    fn motions(
        &mut self,
        pose: &Pose,
        pre: &Pose,
        hand: &HandPose,
        grasp: &IkSolution,
        pregrasp: &IkSolution,
    ) -> Result<(), Infeasible> {
        self.reach
            .motions(pose, pre, hand, &grasp.joints, &pregrasp.joints)
            .map_err(|why| Infeasible {
                stage: Stage::Motions,
                reason: Blocked::Motions(why),
            })
    }

    /// The quick check with repair: a reachable grasp at or near `pose` (see
    /// [`Reachability::repair_near`]) whose pre-grasp passes the quick check. The
    /// motions through them are not checked here (see [`Problem::constrained_run`]).
    fn repair(
        &mut self,
        pose: &Pose,
        hand: &HandPose,
        seeds: &[ArmJoints],
        pre_seeds: &[ArmJoints],
    ) -> Option<(Pose, Feasible)> {
        self.checks += 1;
        let (reached, grasp) = self.reach.repair_near(pose, hand, seeds)?;
        if let Some(seen) = self.seen {
            if seen.intrusion(&reached, hand).is_some() {
                return None;
            }
        }
        self.checks += 1;
        let pre = pregrasp_pose(&reached, self.offset_m);
        let pre_seeds: Vec<ArmJoints> = std::iter::once(grasp.joints)
            .chain(pre_seeds.iter().copied())
            .collect();
        let pregrasp = self.reach.reach_near(&pre, hand, &pre_seeds).ok()?;
        Some((reached, Feasible { grasp, pregrasp }))
    }
}

/// One unconstrained run: its optimum and the points where its best value improved.
struct Run {
    optimum: Point,
    evaluations: usize,
    trail: Vec<Point>,
}

/// A palm pose with its `-ln f`.
#[derive(Debug, Clone, Copy)]
struct Point {
    g: f64,
    pose: Pose,
}

struct Problem<'a> {
    objective: Objective,
    grasps: &'a [ExampleGrasp],
    options: &'a PlanOptions,
    /// The object's vertical axis (x, y in the base frame): the mean origin of the
    /// fitted models.
    axis_xy: [f64; 2],
}

impl Problem<'_> {
    fn g(&self, pose: &Pose) -> f64 {
        -self.objective.log_value_at(pose)
    }

    fn point(&self, pose: Pose) -> Point {
        Point {
            g: self.g(&pose),
            pose,
        }
    }

    /// The hand at the grasp: the dominant grasp's pre-shape at its spread.
    fn hand_at(&self, pose: &Pose) -> HandPose {
        let dominant = &self.grasps[self.objective.dominant_grasp(pose)];
        dominant.preshape_rad.at_spread(dominant.spread_rad)
    }

    fn chart(&self, centre: &Pose) -> Chart {
        Chart::at(centre, self.options.z_min_m)
    }

    /// One unconstrained run in the chart centred on `start`.
    fn run(&self, start: &Pose) -> Run {
        let chart = self.chart(start);
        let x0 = chart.coordinates(start);
        let mut best = f64::INFINITY;
        let mut trail = Vec::new();
        let result = nelder_mead_with_steps(
            |x| {
                let pose = chart.pose(x);
                let g = self.g(&pose);
                if g < best {
                    best = g;
                    trail.push(Point { g, pose });
                }
                g
            },
            &x0,
            &initial_steps(&x0),
            &self.options.nelder_mead,
        );
        Run {
            optimum: Point {
                g: result.fx,
                pose: chart.pose(&result.x),
            },
            evaluations: result.evaluations,
            trail,
        }
    }

    /// Constrained runs from a reachable point. Each evaluation repairs the candidate
    /// into a reachable pose near it (from the last reachable configuration, the best
    /// one's and the start's; [`Checker::repair`]) and scores the repaired pose plus
    /// the distance to it (1 per cm and per 0.1 rad), so that the search slides along
    /// the boundary instead of stalling on it; `+inf` where nothing reachable is found
    /// (a barrier, the whole rule when the reachability cannot repair). Restarted from
    /// its result (a fresh simplex) while that gains more than `tol_fun`, at most
    /// `CONSTRAINED_RESTARTS` times. Returns the best reachable point seen, its IK
    /// solutions and the evaluations.
    fn constrained_run(
        &self,
        checker: &mut Checker,
        start: Point,
        feasible: Feasible,
    ) -> (Point, Feasible, usize) {
        let mut best = (start, feasible);
        let mut last = feasible;
        let mut evaluations = 0;
        for _ in 0..=CONSTRAINED_RESTARTS {
            let from = best.0;
            let chart = self.chart(&from.pose);
            let x0 = chart.coordinates(&from.pose);
            let result = nelder_mead_with_steps(
                |x| {
                    let pose = chart.pose(x);
                    let seeds = [last, best.1, feasible].map(|f| f.grasp.joints);
                    let pre_seeds = [last, best.1, feasible].map(|f| f.pregrasp.joints);
                    let Some((reached, f)) =
                        checker.repair(&pose, &self.hand_at(&pose), &seeds, &pre_seeds)
                    else {
                        return f64::INFINITY;
                    };
                    if reached.translation.z < self.options.z_min_m {
                        return f64::INFINITY;
                    }
                    let g = self.g(&reached);
                    if !g.is_finite() {
                        return f64::INFINITY;
                    }
                    if g < best.0.g {
                        // Only a pose that could become the answer pays for the
                        // check of the motions through it (the executor's, in the
                        // cell): one the arm cannot move through scores nothing.
                        let hand = self.hand_at(&reached);
                        let pre = pregrasp_pose(&reached, checker.offset_m);
                        if checker
                            .motions(&reached, &pre, &hand, &f.grasp, &f.pregrasp)
                            .is_err()
                        {
                            return f64::INFINITY;
                        }
                        best = (Point { g, pose: reached }, f);
                    }
                    last = f;
                    let (dp, dr) = pose_error(&pose, &reached);
                    g + dp / 0.01 + dr / 0.1
                },
                &x0,
                &initial_steps(&x0),
                &self.options.constrained_nelder_mead,
            );
            evaluations += result.evaluations;
            if from.g - best.0.g <= self.options.constrained_nelder_mead.tol_fun {
                break;
            }
        }
        (best.0, best.1, evaluations)
    }

    fn planned(&self, pose: Pose, feasible: Result<Option<Feasible>, Infeasible>) -> PlannedGrasp {
        let dominant = &self.grasps[self.objective.dominant_grasp(&pose)];
        self.planned_at(pose, dominant, feasible)
    }

    /// The plan of `pose` with the hand of `grasp` (its spread, pre-shape and
    /// overtravel).
    fn planned_at(
        &self,
        pose: Pose,
        grasp: &ExampleGrasp,
        feasible: Result<Option<Feasible>, Infeasible>,
    ) -> PlannedGrasp {
        let log_objective = self.objective.log_value_at(&pose);
        let (joints, pregrasp_joints, reachable, unreachable) = match feasible {
            Ok(Some(f)) => (Some(f.grasp.joints), Some(f.pregrasp.joints), true, None),
            Ok(None) => (None, None, false, None),
            Err(e) => (None, None, false, Some(e)),
        };
        PlannedGrasp {
            pose,
            pregrasp_pose: pregrasp_pose(&pose, self.options.pregrasp_offset_m),
            spread_rad: grasp.spread_rad,
            preshape_rad: grasp.preshape_rad,
            max_overtravel_m: grasp.max_overtravel_m,
            joints,
            pregrasp_joints,
            reachable,
            unreachable,
            objective: log_objective.exp(),
            log_objective,
        }
    }
}

/// Plans the grasp for `task` over `fits` and `grasps`, and the best-single baseline.
///
/// With `reach = None` only the table bound constrains the grasp (the paper's
/// simulation setting) and nothing is marked reachable.
pub fn plan(
    fits: &[ModelFit],
    grasps: &[ExampleGrasp],
    task: &str,
    options: &PlanOptions,
    reach: Option<&dyn Reachability>,
) -> Result<PlanOutcome, PlanError> {
    plan_with(fits, grasps, task, options, reach, None)
}

/// [`plan`] with the object's seen surface as an obstacle (when reachability is
/// checked): a grasp whose open hand enters it, at the grasp or along the
/// approach, is infeasible like an unreachable one, for the plan and best single.
pub fn plan_with(
    fits: &[ModelFit],
    grasps: &[ExampleGrasp],
    task: &str,
    options: &PlanOptions,
    reach: Option<&dyn Reachability>,
    seen: Option<&SeenSurface>,
) -> Result<PlanOutcome, PlanError> {
    if !options.z_min_m.is_finite() {
        return Err(PlanError::BadValue {
            what: "plan z_min_m".into(),
            value: options.z_min_m,
            problem: "must be finite",
        });
    }
    super::objective::check_value("plan pregrasp_offset_m", options.pregrasp_offset_m, false)?;
    let objective = Objective::new(fits, grasps, task, &options.kernel, &options.weights)?;
    let n = fits.len().max(1) as f64;
    let axis_xy = [0, 1].map(|k| {
        fits.iter()
            .map(|f| f.base_from_model.translation.vector[k])
            .sum::<f64>()
            / n
    });
    let problem = Problem {
        objective,
        grasps,
        options,
        axis_xy,
    };
    let z_min = options.z_min_m;
    let starts: Vec<Pose> = problem
        .objective
        .grasps()
        .map(|g| {
            let grasp = &grasps[g];
            let world =
                fits[grasp.model].base_from_model * pose_from_params(&grasp.model_from_palm);
            above(world, z_min)
        })
        .collect();
    let runs: Vec<Run> = if options.parallel {
        starts.par_iter().map(|x0| problem.run(x0)).collect()
    } else {
        starts.iter().map(|x0| problem.run(x0)).collect()
    };
    let mut evaluations: usize = runs.iter().map(|r| r.evaluations).sum();
    // Optima, best first (the earlier start among equals).
    let mut optima: Vec<Point> = runs.iter().map(|r| r.optimum).collect();
    optima.sort_by(|a, b| a.g.total_cmp(&b.g));
    let best = optima[0];

    let mut checker = reach.map(|reach| Checker {
        reach,
        seen,
        offset_m: options.pregrasp_offset_m,
        checks: 0,
    });
    let mut unconstrained_optimum = None;
    let mut constrained_runs = 0;
    let grasp = match checker.as_mut() {
        None => problem.planned(best.pose, Ok(None)),
        Some(checker) => {
            let pose = best.pose;
            match checker.check(&pose, &problem.hand_at(&pose), &[], &[], false) {
                Ok(f) => problem.planned(pose, Ok(Some(f))),
                Err(why) if !options.repair => problem.planned(pose, Err(why)),
                Err(why) => {
                    let top = problem.planned(pose, Err(why.clone()));
                    unconstrained_optimum = Some(UnconstrainedOptimum {
                        pose,
                        objective: top.objective,
                        log_objective: top.log_objective,
                        unreachable: why,
                    });
                    let mut from_starts: Vec<Point> =
                        starts.iter().map(|s| problem.point(*s)).collect();
                    from_starts.sort_by(|a, b| a.g.total_cmp(&b.g));
                    let mut trail: Vec<Point> =
                        runs.iter().flat_map(|r| r.trail.iter().copied()).collect();
                    trail.sort_by(|a, b| a.g.total_cmp(&b.g));
                    let found = best_reachable(
                        &problem,
                        checker,
                        &best,
                        vec![optima[1..].to_vec(), from_starts],
                        trail,
                        &mut evaluations,
                        &mut constrained_runs,
                    );
                    found.unwrap_or(top)
                }
            }
        }
    };
    let breakdown = problem.objective.breakdown(&grasp.pose);
    let plan = GraspPlan {
        task: task.to_string(),
        kernel: options.kernel,
        dominant_grasp: problem.objective.dominant_grasp(&grasp.pose),
        per_model_contribution: breakdown.per_model_log.iter().map(|l| l.exp()).collect(),
        grasp,
        reachability_checked: reach.is_some(),
        unconstrained_optimum,
        starts: starts.len(),
        constrained_runs,
        evaluations,
        reach_checks: 0,
    };
    let best_single = best_single(fits, grasps, &problem, checker.as_mut(), &mut evaluations);
    let reach_checks = checker.map_or(0, |c| c.checks);
    Ok(PlanOutcome {
        plan: GraspPlan {
            reach_checks,
            evaluations,
            ..plan
        },
        best_single,
    })
}

/// Restarts of a constrained run from its own result.
const CONSTRAINED_RESTARTS: usize = 2;

/// Turns of an unreachable optimum about the object's vertical axis (rad): 0, 30 and
/// 60 degrees either way.
const AXIS_TURNS_RAD: [f64; 5] = [0.0, -0.52, 0.52, -1.05, 1.05];

/// Tilts of an unreachable optimum's approach downward (rad): 0, 22.5 and 45 degrees.
const APPROACH_TILTS_RAD: [f64; 3] = [0.0, 0.39, 0.79];

/// The grasp `pose` from other sides of the object whose vertical axis passes
/// through `axis_xy`: turned about that axis, and, when it approaches from the side
/// (a horizontal side grasp of a short object puts the arm's wrist on the table),
/// tilted to approach from above about the point of its approach axis nearest the
/// object's axis, so that it still aims at the object. Nearest first, without
/// `pose` itself.
fn turned_and_tilted(pose: &Pose, axis_xy: [f64; 2]) -> Vec<Pose> {
    let z = nalgebra::Vector3::z();
    let approach = pose.rotation * z;
    let side = z.cross(&approach);
    let horizontal = side.norm() > 0.5;
    // The point of the approach axis nearest the object's axis (in plan view).
    let p = pose.translation.vector;
    let flat = nalgebra::Vector2::new(approach.x, approach.y);
    let toward = nalgebra::Vector2::new(axis_xy[0] - p.x, axis_xy[1] - p.y);
    let along = if flat.norm_squared() > 1e-9 {
        toward.dot(&flat) / flat.norm_squared()
    } else {
        0.0
    };
    let centre = p + approach * along;
    let axis = nalgebra::Vector3::new(axis_xy[0], axis_xy[1], 0.0);
    let by = nalgebra::UnitQuaternion::from_scaled_axis;
    let mut out: Vec<(f64, Pose)> = Vec::new();
    for &tilt in &APPROACH_TILTS_RAD {
        if tilt != 0.0 && !horizontal {
            continue;
        }
        let tilted = rotation_about(&centre, by(side.normalize() * tilt)) * pose;
        for &turn in &AXIS_TURNS_RAD {
            if tilt == 0.0 && turn == 0.0 {
                continue;
            }
            out.push((
                tilt.abs() + turn.abs(),
                rotation_about(&axis, by(z * turn)) * tilted,
            ));
        }
    }
    out.sort_by(|a, b| a.0.total_cmp(&b.0));
    out.into_iter().map(|(_, p)| p).collect()
}

/// Axis probes around an unreachable optimum: multiples of 1 cm and 0.1 rad.
const PROBE_SCALES: [f64; 4] = [1.0, 3.0, 9.0, 27.0];

/// Steps 2 and 3 of the module doc: the best reachable grasp found, if any.
/// `candidates` are groups of starting points tried in order after the projections
/// of the optimum (other optima, then starts, each best first); the axis probes
/// come next, then `trail` (the runs' intermediate best points, best first).
fn best_reachable(
    problem: &Problem,
    checker: &mut Checker,
    optimum: &Point,
    candidates: Vec<Vec<Point>>,
    trail: Vec<Point>,
    evaluations: &mut usize,
    constrained_runs: &mut usize,
) -> Option<PlannedGrasp> {
    let options = problem.options;
    let z_min = options.z_min_m;
    // First of all, the implementation's own projections of the optimum (its grasp,
    // and its pre-grasp moved forward by the offset).
    let pose = optimum.pose;
    let hand = problem.hand_at(&pose);
    let offset = Translation3::new(0.0, 0.0, options.pregrasp_offset_m);
    let mut projected = Vec::new();
    for (target, back) in [
        (pose, Translation3::identity()),
        (pregrasp_pose(&pose, options.pregrasp_offset_m), offset),
    ] {
        checker.checks += 1;
        if let Some((reached, _)) = checker.reach.nearest_reachable(&target, &hand) {
            projected.push(problem.point(above(reached * back, z_min)));
        }
    }
    let mut groups: Vec<Vec<Point>> = vec![projected];
    groups.extend(candidates);
    // Probes along each world axis and about each of the palm's own axes.
    let mut probes = Vec::new();
    for scale in PROBE_SCALES {
        for d in 0..6 {
            for sign in [-1.0, 1.0] {
                let probe = if d < 3 {
                    let mut p = pose;
                    p.translation.vector[d] += sign * scale * 0.01;
                    above(p, z_min)
                } else {
                    let mut w = [0.0; 3];
                    w[d - 3] = sign * scale * 0.1;
                    rotated_about_own_axes(&pose, w)
                };
                probes.push(problem.point(probe));
            }
        }
    }
    groups.push(probes);
    groups.push(trail);
    let mut checked: Vec<Pose> = vec![pose];
    let mut feasible: Vec<(Point, Feasible)> = Vec::new();
    // Checked in batches of one point per thread (in parallel with `parallel`) and
    // taken in order, so the points found do not depend on the threads; a batch may
    // check one point the serial search would not have needed.
    let batch_size = if options.parallel {
        rayon::current_num_threads().max(1)
    } else {
        1
    };
    let mut find = |points: Vec<Point>, budget: usize, feasible: &mut Vec<(Point, Feasible)>| {
        let mut budget = budget;
        let mut points = points.into_iter();
        while feasible.len() < options.constrained_starts && budget > 0 {
            let mut batch = Vec::new();
            for point in points.by_ref() {
                // Skip near-duplicates of points already checked.
                if checked.iter().any(|c| {
                    let (dp, dr) = pose_error(c, &point.pose);
                    dp < 2e-3 && dr < 2e-3
                }) {
                    continue;
                }
                checked.push(point.pose);
                batch.push(point);
                if batch.len() >= batch_size.min(budget) {
                    break;
                }
            }
            if batch.is_empty() {
                return;
            }
            budget -= batch.len();
            let checks = checker.map_forked(&batch, options.parallel, |c, point| {
                c.check(&point.pose, &problem.hand_at(&point.pose), &[], &[], false)
            });
            for (point, result) in batch.into_iter().zip(checks) {
                if let Ok(f) = result {
                    if feasible.len() < options.constrained_starts {
                        feasible.push((point, f));
                    }
                }
            }
        }
    };
    find(groups.concat(), options.feasibility_budget, &mut feasible);
    let other_side = feasible.is_empty();
    if other_side {
        // Nothing near it is reachable: the optimum from other sides of the object,
        // with a budget of their own.
        let turned: Vec<Point> = turned_and_tilted(&pose, problem.axis_xy)
            .into_iter()
            .map(|p| problem.point(above(p, z_min)))
            .collect();
        let budget = turned.len();
        find(turned, budget, &mut feasible);
    }
    feasible.sort_by(|a, b| a.0.g.total_cmp(&b.0.g));
    let (first, first_f) = *feasible.first()?;
    // The last reachable point on the way from the best reachable one to the optimum
    // (in the chart centred on the reachable point: the shortest rotation).
    let chart = problem.chart(&first.pose);
    let from = chart.coordinates(&first.pose);
    let target = chart.coordinates(&pose);
    let at = |t: f64| -> Pose {
        let x: [f64; 6] = std::array::from_fn(|i| from[i] + t * (target[i] - from[i]));
        chart.pose(&x)
    };
    let (mut lo, mut hi) = (0.0, 1.0);
    let mut lo_f = first_f;
    for _ in 0..10 {
        let t = 0.5 * (lo + hi);
        let p = at(t);
        match checker.check(
            &p,
            &problem.hand_at(&p),
            &[lo_f.grasp.joints, first_f.grasp.joints],
            &[lo_f.pregrasp.joints, first_f.pregrasp.joints],
            true,
        ) {
            Ok(f) => {
                lo = t;
                lo_f = f;
            }
            Err(_) => hi = t,
        }
    }
    if lo > 0.0 {
        feasible.push((problem.point(at(lo)), lo_f));
    }
    // From another side the grasp is taken as found: a constrained run would slide
    // it back along the boundary toward the unreachable side, at ten times the cost.
    // The runs are independent (in parallel with `parallel`).
    let found: Vec<(Point, Feasible)> = if other_side {
        feasible
    } else {
        let runs = checker.map_forked(&feasible, options.parallel, |c, &(point, f)| {
            problem.constrained_run(c, point, f)
        });
        *constrained_runs += runs.len();
        runs.into_iter()
            .map(|(found, found_f, used)| {
                *evaluations += used;
                (found, found_f)
            })
            .collect()
    };
    let mut best: Option<(Point, Feasible)> = None;
    for (found, found_f) in found {
        if best.as_ref().is_none_or(|b| found.g < b.0.g) {
            best = Some((found, found_f));
        }
    }
    let (Point { pose, .. }, f) = best?;
    // Confirm with the full check, seeded with the solution found.
    let confirmed = checker.check(
        &pose,
        &problem.hand_at(&pose),
        &[f.grasp.joints],
        &[f.pregrasp.joints],
        false,
    );
    Some(problem.planned(pose, confirmed.map(Some)))
}

/// The best-single baseline (see the module doc). When its grasp is unreachable and
/// the options repair, the same constrained search as the plan's runs on an
/// objective made of that grasp's term alone; the grasp's objective is reported
/// with the full eq. 2, as the plan's.
fn best_single(
    fits: &[ModelFit],
    grasps: &[ExampleGrasp],
    problem: &Problem,
    checker: Option<&mut Checker>,
    evaluations: &mut usize,
) -> BestSingle {
    let weights = &problem.options.weights;
    // The objective holds at least one grasp of the task.
    let mut best: Option<(f64, f64, usize)> = None; // (ln phi, q, grasp)
    for g in problem.objective.grasps() {
        let grasp = &grasps[g];
        let fit = &fits[grasp.model];
        let key = (weights.log_phi(fit.eps_m2, fit.sigma_m2), grasp.q);
        let better = match best {
            None => true,
            Some((phi, q, b)) => {
                key.0 > phi || (key.0 == phi && (key.1 > q || (key.1 == q && g < b)))
            }
        };
        if better {
            best = Some((key.0, key.1, g));
        }
    }
    let g = best.map(|b| b.2).unwrap_or(0);
    let grasp = &grasps[g];
    let pose = fits[grasp.model].base_from_model * pose_from_params(&grasp.model_from_palm);
    let mut unrepaired = None;
    let mut constrained_runs = 0;
    let planned = match checker {
        None => problem.planned_at(pose, grasp, Ok(None)),
        Some(c) => match c.check(
            &pose,
            &grasp.preshape_rad.at_spread(grasp.spread_rad),
            &[],
            &[],
            false,
        ) {
            Ok(f) => problem.planned_at(pose, grasp, Ok(Some(f))),
            Err(why) if !(problem.options.repair && problem.options.repair_best_single) => {
                problem.planned_at(pose, grasp, Err(why))
            }
            Err(why) => {
                let top = problem.planned_at(pose, grasp, Err(why.clone()));
                unrepaired = Some(UnconstrainedOptimum {
                    pose,
                    objective: top.objective,
                    log_objective: top.log_objective,
                    unreachable: why,
                });
                repair_single(
                    fits,
                    grasp,
                    problem,
                    c,
                    pose,
                    evaluations,
                    &mut constrained_runs,
                )
                .unwrap_or(top)
            }
        },
    };
    BestSingle {
        model: grasp.model,
        model_name: fits[grasp.model].name.clone(),
        grasp_index: g,
        grasp: planned,
        unrepaired,
        constrained_runs,
    }
}

/// The best reachable grasp near the best-single grasp `pose` (unreachable), by the
/// plan's constrained search on the objective of `grasp`'s term alone, reported
/// with the full objective of `problem`.
fn repair_single(
    fits: &[ModelFit],
    grasp: &ExampleGrasp,
    problem: &Problem,
    checker: &mut Checker,
    pose: Pose,
    evaluations: &mut usize,
    constrained_runs: &mut usize,
) -> Option<PlannedGrasp> {
    let options = problem.options;
    let alone = std::slice::from_ref(grasp);
    let objective =
        Objective::new(fits, alone, &grasp.task, &options.kernel, &options.weights).ok()?;
    let single = Problem {
        objective,
        grasps: alone,
        options,
        axis_xy: problem.axis_xy,
    };
    let start = single.point(above(pose, options.z_min_m));
    let found = best_reachable(
        &single,
        checker,
        &start,
        Vec::new(),
        Vec::new(),
        evaluations,
        constrained_runs,
    )?;
    let log_objective = problem.objective.log_value_at(&found.pose);
    Some(PlannedGrasp {
        objective: log_objective.exp(),
        log_objective,
        ..found
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    use crate::geometry::{params_from_pose, pose_from_params, wrap_angle, PoseParams};
    use crate::plan::test_support::grasp;
    use crate::robot::Unreachable;

    #[test]
    fn a_side_grasp_is_tried_from_other_sides_and_from_above_still_aiming_at_the_object() {
        // Approaching along +x, palm 5 cm before an object whose axis is at (0.65, 0).
        let side = pose_from_params(&[0.6, 0.0, 0.05, 0.0, std::f64::consts::FRAC_PI_2, 0.0]);
        let variants = turned_and_tilted(&side, [0.65, 0.0]);
        assert_eq!(variants.len(), 3 * 5 - 1);
        let aim = |p: &Pose| {
            // Distance from the object's axis point at the grasp's height to the
            // approach line, and the approach's downward slope.
            let a = p.rotation * nalgebra::Vector3::z();
            let c = nalgebra::Vector3::new(0.65, 0.0, 0.05) - p.translation.vector;
            ((c - a * c.dot(&a)).norm(), -a.z)
        };
        for v in &variants {
            let (miss, down) = aim(v);
            assert!(miss < 0.05, "{miss}");
            assert!(down > -1e-9, "never tilted upward: {down}");
        }
        let steepest = variants.iter().map(|v| aim(v).1).fold(0.0, f64::max);
        assert!((steepest - 0.79f64.sin()).abs() < 1e-6, "{steepest}");
        // Nearest first: the first variant is the smallest change of orientation.
        let turn = |v: &Pose| pose_error(&side, v).1;
        let least = variants.iter().map(turn).fold(f64::INFINITY, f64::min);
        assert!((turn(&variants[0]) - least).abs() < 1e-9, "{least}");
        // A top grasp is only turned.
        let top = pose_from_params(&[0.65, 0.0, 0.2, std::f64::consts::PI, 0.0, 0.0]);
        assert_eq!(turned_and_tilted(&top, [0.65, 0.0]).len(), 4);
    }
    use std::f64::consts::PI;

    fn fit(name: &str, p: PoseParams, eps_m2: f64) -> ModelFit {
        ModelFit {
            name: name.into(),
            base_from_model: pose_from_params(&p),
            eps_m2,
            sigma_m2: 0.2 * eps_m2,
        }
    }

    /// Two mugs, two top grasps each (roll near pi: on the wrap boundary).
    fn grid_database() -> (Vec<ModelFit>, Vec<ExampleGrasp>) {
        let fits = vec![
            fit("a", [0.6, 0.0, 0.0, 0.0, 0.0, 0.3], 1e-5),
            fit("b", [0.61, 0.01, 0.0, 0.0, 0.0, -0.2], 3e-5),
        ];
        let mut grasps = vec![
            grasp(0, "top", [0.01, 0.0, 0.15, PI, 0.0, 0.2], 0.2),
            grasp(0, "top", [0.0, 0.015, 0.16, PI - 0.1, 0.05, 0.35], 0.1),
            grasp(1, "top", [-0.01, 0.01, 0.14, -PI + 0.05, 0.05, 0.6], 0.15),
            grasp(1, "top", [0.0, -0.01, 0.145, PI, -0.05, 0.8], 0.25),
            grasp(1, "side", [0.0, 0.08, 0.06, PI / 2.0, 0.0, 0.0], 0.25),
        ];
        grasps[3].sigma = [0.015, 0.01, 0.012, 0.2, 0.1, 0.25];
        (fits, grasps)
    }

    /// Brute-force maximum of `ln f` over world parameters (z >= z_min): a 9^6 grid over
    /// the box `lo..hi`, then each of its best 4 points refined by successively finer
    /// 7^6 grids (one coarser step either side, step / 3 each level).
    fn grid_maximum(
        objective: &Objective,
        lo: [f64; 6],
        hi: [f64; 6],
        z_min: f64,
    ) -> (f64, PoseParams) {
        let grid = |centre: [f64; 6], half: [f64; 6], n: usize| -> Vec<(f64, PoseParams)> {
            (0..n.pow(6))
                .into_par_iter()
                .filter_map(|mut k| {
                    let mut p = [0.0; 6];
                    for d in 0..6 {
                        let t = (k % n) as f64 / (n - 1) as f64;
                        p[d] = centre[d] + half[d] * (2.0 * t - 1.0);
                        k /= n;
                    }
                    (p[2] >= z_min).then(|| (objective.log_value(&p), p))
                })
                .collect()
        };
        let centre: [f64; 6] = std::array::from_fn(|d| 0.5 * (lo[d] + hi[d]));
        let mut half: [f64; 6] = std::array::from_fn(|d| 0.5 * (hi[d] - lo[d]));
        let mut coarse = grid(centre, half, 9);
        coarse.sort_by(|a, b| b.0.total_cmp(&a.0));
        half.iter_mut().for_each(|h| *h /= 4.0);
        let mut best = (f64::NEG_INFINITY, [0.0; 6]);
        for start in coarse.iter().take(4) {
            let mut here = *start;
            let mut h = half;
            for _ in 0..6 {
                here = grid(here.1, h, 7)
                    .into_iter()
                    .fold(here, |a, b| if b.0 > a.0 { b } else { a });
                h.iter_mut().for_each(|v| *v /= 3.0);
            }
            if here.0 > best.0 {
                best = here;
            }
        }
        best
    }

    #[test]
    fn optimum_matches_a_brute_force_grid() {
        let (fits, grasps) = grid_database();
        for kernel in [
            Kernel::Gaussian,
            Kernel::GaussianR {
                s_translation_m2: 1e-4,
                s_rotation_rad2: 0.02,
            },
            Kernel::Laplace {
                b_translation_m: 0.02,
                b_rotation_rad: 0.3,
            },
        ] {
            let options = PlanOptions::with_kernel(kernel);
            let out = plan(&fits, &grasps, "top", &options, None).unwrap();
            let objective =
                Objective::new(&fits, &grasps, "top", &kernel, &options.weights).unwrap();
            // The box: the world grasps' parameters (yaw unwrapped near the first) +- margin.
            let world: Vec<PoseParams> = grasps[..4]
                .iter()
                .map(|g| {
                    params_from_pose(
                        &(fits[g.model].base_from_model * pose_from_params(&g.model_from_palm)),
                    )
                })
                .collect();
            let mut lo = [f64::INFINITY; 6];
            let mut hi = [f64::NEG_INFINITY; 6];
            for w in &world {
                for d in 0..6 {
                    let v = if d >= 3 {
                        world[0][d] + wrap_angle(w[d] - world[0][d])
                    } else {
                        w[d]
                    };
                    lo[d] = lo[d].min(v - if d < 3 { 0.01 } else { 0.1 });
                    hi[d] = hi[d].max(v + if d < 3 { 0.01 } else { 0.1 });
                }
            }
            let (grid_log, grid_p) = grid_maximum(&objective, lo, hi, options.z_min_m);
            let planned = params_from_pose(&out.plan.grasp.pose);
            let (dp, dr) = pose_error(&out.plan.grasp.pose, &pose_from_params(&grid_p));
            println!(
                "{}: plan ln f {:.6} at {planned:.4?}; grid {grid_log:.6} at {grid_p:.4?}; {dp:.2e} m {dr:.2e} rad; {} evaluations",
                kernel.name(),
                out.plan.grasp.log_objective,
                out.plan.evaluations
            );
            assert!((out.plan.grasp.log_objective - grid_log).abs() < 1e-3);
            assert!(dp < 1e-3 && dr < 1e-2, "{dp} m {dr} rad");
            assert!(out.plan.unconstrained_optimum.is_none());
            assert!(!out.plan.reachability_checked && !out.plan.grasp.reachable);
            assert_eq!(out.plan.starts, 4);
        }
    }

    /// Reachable exactly where `feasible(palm)` holds (joints: x, y, z of the palm).
    struct Region<F: Fn(&Pose) -> bool + Sync>(F);

    impl<F: Fn(&Pose) -> bool + Sync> Reachability for Region<F> {
        fn reach(
            &self,
            palm: &Pose,
            _hand: &HandPose,
            _seeds: &[ArmJoints],
        ) -> Result<IkSolution, Unreachable> {
            let t = palm.translation.vector;
            if (self.0)(palm) {
                Ok(IkSolution {
                    joints: [t.x, t.y, t.z, 0.0, 0.0, 0.0, 0.0],
                    pos_err_m: 0.0,
                    rot_err_rad: 0.0,
                    iterations: 0,
                })
            } else {
                Err(Unreachable {
                    reason: UnreachableReason::OutsideWorkspace {
                        palm_xyz_m: [t.x, t.y, t.z],
                    },
                    best: None,
                })
            }
        }
    }

    /// One model at (0.6, 0, 0), unrotated, one top grasp 5 cm along its x: in the world
    /// the density is separable in the parameters.
    fn single_grasp(sigma: [f64; 6]) -> (Vec<ModelFit>, Vec<ExampleGrasp>) {
        let fits = vec![fit("a", [0.6, 0.0, 0.0, 0.0, 0.0, 0.0], 1e-5)];
        let mut g = grasp(0, "top", [0.05, 0.0, 0.15, PI, 0.0, 0.3], 0.2);
        g.sigma = sigma;
        (fits, vec![g])
    }

    #[test]
    fn unreachable_optimum_gives_the_best_reachable_grasp_on_the_boundary() {
        let (fits, grasps) = single_grasp([0.01, 0.01, 0.01, 0.1, 0.1, 0.1]);
        let options = PlanOptions::with_kernel(Kernel::Gaussian);
        // The grasp is at x = 0.65; only x <= 0.63 is reachable.
        let region = Region(|p: &Pose| p.translation.x <= 0.63);
        let out = plan(&fits, &grasps, "top", &options, Some(&region)).unwrap();
        let p = params_from_pose(&out.plan.grasp.pose);
        let unc = out.plan.unconstrained_optimum.as_ref().expect("marked");
        println!(
            "{p:.5?} ln f {} (unconstrained {}), {} constrained runs, {} evaluations, {} checks",
            out.plan.grasp.log_objective,
            unc.log_objective,
            out.plan.constrained_runs,
            out.plan.evaluations,
            out.plan.reach_checks
        );
        assert!(out.plan.grasp.reachable && out.plan.grasp.joints.is_some());
        assert!(p[0] <= 0.63 && p[0] > 0.629, "{p:?}");
        let want = [0.63, 0.0, 0.15, PI, 0.0, 0.3];
        for d in 1..6 {
            let e = if d < 3 {
                p[d] - want[d]
            } else {
                wrap_angle(p[d] - want[d])
            };
            assert!(e.abs() < if d < 3 { 1e-3 } else { 1e-2 }, "{d}: {p:?}");
        }
        // 2 sigma off in x costs exactly 2 in ln f.
        assert!((unc.log_objective - out.plan.grasp.log_objective - 2.0).abs() < 0.02);
        assert!((unc.pose.translation.x - 0.65).abs() < 1e-3);
        assert_eq!(unc.unreachable.stage, Stage::Grasp);
        assert!(matches!(
            unc.unreachable.reason,
            Blocked::Unreachable(UnreachableReason::OutsideWorkspace { .. })
        ));
        // The baseline is the same grasp: repaired the same way.
        let single = &out.best_single;
        assert!(single.grasp.reachable && single.grasp.joints.is_some());
        let (dp, dr) = pose_error(&single.grasp.pose, &out.plan.grasp.pose);
        assert!(dp < 1e-3 && dr < 1e-2, "{dp} {dr}");
        assert_eq!(
            single.unrepaired.as_ref().unwrap().unreachable.stage,
            Stage::Grasp
        );
    }

    /// Reachable everywhere, but the arm cannot move through a grasp unless
    /// `movable(palm)`.
    struct Moves<F: Fn(&Pose) -> bool + Sync>(F);

    impl<F: Fn(&Pose) -> bool + Sync> Reachability for Moves<F> {
        fn reach(
            &self,
            palm: &Pose,
            hand: &HandPose,
            seeds: &[ArmJoints],
        ) -> Result<IkSolution, Unreachable> {
            Region(|_: &Pose| true).reach(palm, hand, seeds)
        }

        fn motions(
            &self,
            palm: &Pose,
            _pregrasp: &Pose,
            _hand: &HandPose,
            _at: &ArmJoints,
            _pre: &ArmJoints,
        ) -> Result<(), String> {
            if (self.0)(palm) {
                Ok(())
            } else {
                Err("approach refused".into())
            }
        }
    }

    /// A grasp whose poses the arm reaches but whose motions it cannot make (the
    /// executor refuses the approach) is infeasible like an unreachable one: the
    /// plan and best single take the best grasp the arm can move through.
    #[test]
    fn a_grasp_the_arm_cannot_move_through_is_infeasible() {
        let (fits, grasps) = single_grasp([0.01, 0.01, 0.01, 0.1, 0.1, 0.1]);
        let options = PlanOptions::with_kernel(Kernel::LAPLACE_DEFAULT);
        let free = plan(
            &fits,
            &grasps,
            "top",
            &options,
            Some(&Moves(|_: &Pose| true)),
        )
        .unwrap();
        assert!((free.plan.grasp.pose.translation.x - 0.65).abs() < 1e-3);
        assert!(free.plan.unconstrained_optimum.is_none());
        // The grasp is at x = 0.65; the arm moves through it only at x <= 0.63.
        let moves = Moves(|p: &Pose| p.translation.x <= 0.63);
        let out = plan(&fits, &grasps, "top", &options, Some(&moves)).unwrap();
        let unc = out.plan.unconstrained_optimum.as_ref().expect("refused");
        assert_eq!(unc.unreachable.stage, Stage::Motions);
        assert_eq!(
            unc.unreachable.reason,
            Blocked::Motions("approach refused".into())
        );
        assert_eq!(
            unc.unreachable.to_string(),
            "motions refused: approach refused"
        );
        for g in [&out.plan.grasp, &out.best_single.grasp] {
            assert!(g.reachable && g.joints.is_some(), "{g:?}");
            let x = g.pose.translation.x;
            assert!(x <= 0.63 && x > 0.62, "{x}");
        }
    }

    /// Issue 19: best single gets a reachable grasp where one exists near its
    /// optimum, exactly as the other methods do; in the paper's mode neither is
    /// repaired and both fail as unreachable.
    #[test]
    fn best_single_is_repaired_like_the_plan_and_not_in_the_paper_mode() {
        // Two models; the better-fitting one's grasp is out of reach (x > 0.63), and
        // the plan's optimum lies between the two grasps, out of reach too.
        let fits = vec![
            fit("near_best", [0.6, 0.0, 0.0, 0.0, 0.0, 0.0], 1e-6),
            fit("other", [0.6, 0.0, 0.0, 0.0, 0.0, 0.0], 2e-6),
        ];
        let sigma = [0.01, 0.01, 0.01, 0.1, 0.1, 0.1];
        let mut grasps = vec![
            grasp(0, "top", [0.06, 0.0, 0.15, PI, 0.0, 0.3], 0.2),
            grasp(1, "top", [0.05, 0.01, 0.15, PI, 0.0, 0.2], 0.2),
        ];
        grasps.iter_mut().for_each(|g| g.sigma = sigma);
        let region = Region(|p: &Pose| p.translation.x <= 0.63);
        for kernel in [Kernel::LAPLACE_DEFAULT, Kernel::GAUSSIAN_R_DEFAULT] {
            let options = PlanOptions::with_kernel(kernel);
            let out = plan(&fits, &grasps, "top", &options, Some(&region)).unwrap();
            let single = &out.best_single;
            assert_eq!(single.grasp_index, 0);
            let unrepaired = single
                .unrepaired
                .as_ref()
                .expect("the grasp was out of reach");
            assert!((unrepaired.pose.translation.x - 0.66).abs() < 1e-9);
            for g in [&single.grasp, &out.plan.grasp] {
                assert!(g.reachable && g.joints.is_some() && g.pregrasp_joints.is_some());
                let x = g.pose.translation.x;
                assert!(x <= 0.63 && x > 0.629, "{} {x}", kernel.name());
            }
            // The repair stays with its own grasp: same height, yaw and roll as it.
            let want = fits[0].base_from_model * pose_from_params(&grasps[0].model_from_palm);
            let mut moved = want;
            moved.translation.x = single.grasp.pose.translation.x;
            let (dp, dr) = pose_error(&single.grasp.pose, &moved);
            assert!(dp < 2e-3 && dr < 2e-2, "{} {dp} {dr}", kernel.name());
            assert!(single.constrained_runs > 0);

            let mut paper = options;
            crate::plan::PlanMode::Paper {
                protocol: crate::plan::PaperProtocol::Simulation,
            }
            .apply(&mut paper);
            let out = plan(&fits, &grasps, "top", &paper, Some(&region)).unwrap();
            for g in [&out.best_single.grasp, &out.plan.grasp] {
                assert!(!g.reachable && g.unreachable.is_some(), "{g:?}");
            }
            assert!(out.best_single.unrepaired.is_none());
            assert!(out.plan.unconstrained_optimum.is_none());
            assert_eq!(out.plan.constrained_runs, 0);
        }
    }

    /// Issue 17: a palm pose planned inside the object's seen points is rejected, for
    /// the plan and for best single; the grasp found instead clears the points along
    /// its whole approach.
    #[test]
    fn a_palm_inside_the_seen_points_is_rejected() {
        use crate::plan::seen::{tests::cylinder_cloud, SeenSurface, SeenSurfaceOptions};
        let robot = crate::robot::shipped_robot();
        let hand = crate::quality::autograsp::tests::hand_of(&robot);
        let cloud = cylinder_cloud();
        let seen = SeenSurface::new(&hand, &cloud, SeenSurfaceOptions::default()).unwrap();
        // The model's side grasp puts the palm on the cylinder's axis, facing +x.
        let fits = vec![fit("cyl", [0.6, 0.0, 0.0, 0.0, 0.0, 0.0], 1e-5)];
        let mut g = grasp(0, "side", [0.0, 0.0, 0.05, 0.0, PI / 2.0, 0.0], 0.2);
        g.sigma = [0.01, 0.01, 0.01, 0.1, 0.1, 0.1];
        let grasps = vec![g];
        let everywhere = Region(|_: &Pose| true);
        let options = PlanOptions::with_kernel(Kernel::LAPLACE_DEFAULT);
        let blind = plan(&fits, &grasps, "side", &options, Some(&everywhere)).unwrap();
        assert!(seen
            .intrusion(&blind.plan.grasp.pose, &HandPose::OPEN)
            .is_some());
        let out = plan_with(
            &fits,
            &grasps,
            "side",
            &options,
            Some(&everywhere),
            Some(&seen),
        )
        .unwrap();
        let unc = out.plan.unconstrained_optimum.as_ref().expect("rejected");
        assert!(
            matches!(unc.unreachable.reason, Blocked::SeenSurface(_)),
            "{unc:?}"
        );
        assert!(unc.unreachable.to_string().contains("seen surface"));
        for g in [&out.plan.grasp, &out.best_single.grasp] {
            assert!(g.reachable, "{g:?}");
            assert_eq!(
                seen.intrusion(&g.pose, &g.preshape_rad.at_spread(g.spread_rad)),
                None,
                "{g:?}"
            );
            assert!(g.log_objective < unc.log_objective);
        }
        // Moved out of the object, not far off.
        let (dp, _) = pose_error(&out.plan.grasp.pose, &unc.pose);
        assert!(dp > 0.01 && dp < 0.3, "{dp}");
    }

    #[test]
    fn unreachable_pregrasp_is_a_constraint_too() {
        // Stiff in rotation, so that lowering the grasp beats tilting it.
        let (fits, grasps) = single_grasp([0.01, 0.01, 0.01, 0.01, 0.01, 0.01]);
        let options = PlanOptions::with_kernel(Kernel::Gaussian);
        // A ceiling at z = 0.22: the grasp (z = 0.15) fits, its pre-grasp (0.25) does not.
        let region = Region(|p: &Pose| p.translation.z <= 0.22);
        let out = plan(&fits, &grasps, "top", &options, Some(&region)).unwrap();
        let unc = out.plan.unconstrained_optimum.as_ref().expect("marked");
        assert_eq!(unc.unreachable.stage, Stage::Pregrasp);
        let grasp_z = out.plan.grasp.pose.translation.z;
        let pre_z = out.plan.grasp.pregrasp_pose.translation.z;
        assert!(out.plan.grasp.reachable);
        assert!(
            pre_z <= 0.22 && (grasp_z - 0.12).abs() < 2e-3,
            "{grasp_z} {pre_z}"
        );
    }

    #[test]
    fn nothing_reachable_returns_the_optimum_marked_unreachable() {
        let (fits, grasps) = single_grasp([0.01, 0.01, 0.01, 0.1, 0.1, 0.1]);
        let options = PlanOptions::with_kernel(Kernel::LAPLACE_DEFAULT);
        let region = Region(|_: &Pose| false);
        let out = plan(&fits, &grasps, "top", &options, Some(&region)).unwrap();
        assert!(!out.plan.grasp.reachable && out.plan.grasp.joints.is_none());
        assert!(out.plan.grasp.unreachable.is_some());
        let unc = out.plan.unconstrained_optimum.as_ref().unwrap();
        assert_eq!(unc.pose, out.plan.grasp.pose);
        // The plan's search and best single's repair, each within its budget.
        assert!(out.plan.reach_checks <= 2 * (2 * (1 + options.feasibility_budget) + 2));
        assert!(!out.best_single.grasp.reachable && out.best_single.unrepaired.is_some());
    }

    #[test]
    fn grasps_at_plus_and_minus_pi_agree() {
        // Two models in the same place, top grasps 0.1 rad apart in yaw across +-pi.
        let fits = vec![
            fit("a", [0.6, 0.0, 0.0, 0.0, 0.0, 0.0], 1e-5),
            fit("b", [0.6, 0.0, 0.0, 0.0, 0.0, 0.0], 1e-5),
        ];
        let sigma = [0.01, 0.01, 0.01, 0.1, 0.1, 0.1];
        let mut grasps = vec![
            grasp(0, "top", [0.0, 0.0, 0.15, PI, 0.0, PI - 0.05], 0.2),
            grasp(1, "top", [0.0, 0.0, 0.15, PI, 0.0, -PI + 0.05], 0.2),
        ];
        grasps.iter_mut().for_each(|g| g.sigma = sigma);
        let options = PlanOptions::with_kernel(Kernel::Gaussian);
        let out = plan(&fits, &grasps, "top", &options, None).unwrap();
        let p = params_from_pose(&out.plan.grasp.pose);
        // The mixture of two Gaussians 1 sigma apart peaks half way: yaw = +-pi.
        assert!(wrap_angle(p[5] - PI).abs() < 2e-3, "{p:?}");
        assert!((p[0] - 0.6).abs() < 1e-3 && p[1].abs() < 1e-3 && (p[2] - 0.15).abs() < 1e-3);
        // Both grasps count equally there: 2 w N(0.05 rad off in yaw), written out.
        let w = (1.0 - (-options.weights.lambda_psi * 0.2).exp())
            * (-options.weights.lambda_eps_per_m2 * 1.2e-5).exp();
        let density = (-0.5 * 0.25f64).exp() / ((2.0 * PI).powi(3) * sigma.iter().product::<f64>());
        let want = 2.0 * w * density;
        assert!(
            (out.plan.grasp.objective / want - 1.0).abs() < 1e-4,
            "{} vs {want}",
            out.plan.grasp.objective
        );
        let c = &out.plan.per_model_contribution;
        assert!((c[0] / c[1] - 1.0).abs() < 1e-2, "{c:?}");
    }

    #[test]
    fn parallel_and_serial_plans_are_identical() {
        let (fits, grasps) = grid_database();
        let region = Region(|p: &Pose| p.translation.x <= 0.605);
        for reach in [None, Some(&region as &dyn Reachability)] {
            let mut options = PlanOptions::with_kernel(Kernel::GAUSSIAN_R_DEFAULT);
            let a = plan(&fits, &grasps, "top", &options, reach).unwrap();
            options.parallel = false;
            let mut b = plan(&fits, &grasps, "top", &options, reach).unwrap();
            // The parallel search checks its points in batches: a batch may check
            // points the serial one stopped before (at most one per thread beyond
            // each of the two searches' last).
            let threads = rayon::current_num_threads();
            assert!(a.plan.reach_checks >= b.plan.reach_checks);
            assert!(a.plan.reach_checks <= b.plan.reach_checks + 4 * threads);
            b.plan.reach_checks = a.plan.reach_checks;
            assert_eq!(a, b);
        }
    }

    #[test]
    fn best_single_is_the_best_fitting_model_with_a_task_grasp() {
        let (mut fits, grasps) = grid_database();
        let options = PlanOptions::with_kernel(Kernel::LAPLACE_DEFAULT);
        let out = plan(&fits, &grasps, "top", &options, None).unwrap();
        // Model a fits best; of its top grasps, grasp 0 has the higher q.
        assert_eq!((out.best_single.model, out.best_single.grasp_index), (0, 0));
        let want = fits[0].base_from_model * pose_from_params(&grasps[0].model_from_palm);
        let (dp, dr) = pose_error(&out.best_single.grasp.pose, &want);
        assert!(dp < 1e-12 && dr < 1e-9);
        assert_eq!(out.best_single.grasp.spread_rad, grasps[0].spread_rad);
        // Only model b has a side grasp.
        let out = plan(&fits, &grasps, "side", &options, None).unwrap();
        assert_eq!((out.best_single.model, out.best_single.grasp_index), (1, 4));
        // Model b fitting better: its best-quality top grasp (3).
        fits[1].eps_m2 = 1e-6;
        fits[1].sigma_m2 = 1e-7;
        let out = plan(&fits, &grasps, "top", &options, None).unwrap();
        assert_eq!((out.best_single.model, out.best_single.grasp_index), (1, 3));
        assert_eq!(out.best_single.model_name, "b");
    }

    #[test]
    fn a_plan_approaches_as_the_grasp_it_came_from() {
        let (fits, mut grasps) = grid_database();
        let options = PlanOptions::with_kernel(Kernel::LAPLACE_DEFAULT);
        let out = plan(&fits, &grasps, "top", &options, None).unwrap();
        assert_eq!(out.plan.grasp.max_overtravel_m, None);
        assert_eq!(out.best_single.grasp.max_overtravel_m, None);
        // Each top grasp names its own overtravel: the plan takes the dominant
        // grasp's (with its spread), best single its grasp's.
        for (i, g) in grasps.iter_mut().enumerate() {
            g.max_overtravel_m = Some(0.01 * i as f64);
        }
        let out = plan(&fits, &grasps, "top", &options, None).unwrap();
        let dominant = &grasps[out.plan.dominant_grasp];
        assert_eq!(out.plan.grasp.max_overtravel_m, dominant.max_overtravel_m);
        assert_eq!(out.plan.grasp.spread_rad, dominant.spread_rad);
        let single = &grasps[out.best_single.grasp_index];
        assert_eq!(
            out.best_single.grasp.max_overtravel_m,
            single.max_overtravel_m
        );
    }

    #[test]
    fn the_table_bound_holds() {
        // A grasp below the bound: the optimum sits on z = z_min, as the grid finds.
        let (fits, mut grasps) = single_grasp([0.01, 0.01, 0.01, 0.1, 0.1, 0.1]);
        grasps[0].model_from_palm[2] = 0.03;
        let options = PlanOptions::with_kernel(Kernel::GaussianR {
            s_translation_m2: 1e-4,
            s_rotation_rad2: 0.02,
        });
        let out = plan(&fits, &grasps, "top", &options, None).unwrap();
        let z = out.plan.grasp.pose.translation.z;
        assert!(z >= options.z_min_m && z - options.z_min_m < 1e-4, "{z}");
    }

    #[test]
    fn out_of_reach_on_the_real_arm_gives_the_best_reachable_grasp() {
        let robot = crate::robot::shipped_robot();
        // A mug at the far edge of the table, grasped from the top 0.25 m up: the wrist
        // would be out of the arm's reach.
        let fits = vec![fit("far", [0.98, 0.1, 0.0, 0.0, 0.0, 0.0], 1e-5)];
        let grasps = vec![grasp(0, "top", [0.0, 0.0, 0.25, PI, 0.0, 0.0], 0.2)];
        let options = PlanOptions::with_kernel(Kernel::LAPLACE_DEFAULT);
        let t = std::time::Instant::now();
        let out = plan(&fits, &grasps, "top", &options, Some(&robot)).unwrap();
        let unc = out.plan.unconstrained_optimum.as_ref().expect("marked");
        println!(
            "{:?}: {:.4?} ln f {} (unconstrained {} {:?}), {} constrained runs, {} evaluations, {} checks, {:?}",
            out.plan.grasp.reachable,
            params_from_pose(&out.plan.grasp.pose),
            out.plan.grasp.log_objective,
            unc.log_objective,
            unc.unreachable,
            out.plan.constrained_runs,
            out.plan.evaluations,
            out.plan.reach_checks,
            t.elapsed()
        );
        assert!(robot.reach(&unc.pose, &HandPose::OPEN, &[]).is_err());
        assert!(out.plan.grasp.reachable);
        // The joints reach grasp and pre-grasp, inside the limits, touching nothing.
        let hand = HandPose::open(out.plan.grasp.spread_rad);
        for (q, pose) in [
            (out.plan.grasp.joints.unwrap(), out.plan.grasp.pose),
            (
                out.plan.grasp.pregrasp_joints.unwrap(),
                out.plan.grasp.pregrasp_pose,
            ),
        ] {
            let (dp, dr) = pose_error(&robot.arm().palm(&q), &pose);
            assert!(dp < 1e-3 && dr < 1e-2, "{dp} {dr}");
            robot.check_limits(&q).unwrap();
            assert_eq!(robot.collision_at(&q, &hand), None);
            robot.reach(&pose, &hand, &[q]).unwrap();
        }
        assert!(out.plan.grasp.log_objective < unc.log_objective);
        // No reachable pose among random ones near the target beats it.
        let objective =
            Objective::new(&fits, &grasps, "top", &options.kernel, &options.weights).unwrap();
        let mut rng = <rand_chacha::ChaCha8Rng as rand::SeedableRng>::seed_from_u64(3);
        let centre = params_from_pose(&out.plan.grasp.pose);
        let mut best_sample = f64::NEG_INFINITY;
        let mut reachable_samples = 0;
        for _ in 0..300 {
            let p: PoseParams = std::array::from_fn(|d| {
                centre[d]
                    + rand::Rng::gen_range(&mut rng, -1.0..1.0) * if d < 3 { 0.05 } else { 0.4 }
            });
            let v = objective.log_value(&p);
            if v <= best_sample || p[2] < options.z_min_m {
                continue;
            }
            let pose = pose_from_params(&p);
            let hand = HandPose::open(grasps[0].spread_rad);
            let seed = out.plan.grasp.joints.unwrap();
            if let Ok(s) = robot.reach(&pose, &hand, &[seed]) {
                let pre = pregrasp_pose(&pose, options.pregrasp_offset_m);
                if robot.reach(&pre, &hand, &[s.joints]).is_err() {
                    continue;
                }
                best_sample = v;
                reachable_samples += 1;
            }
        }
        println!("best reachable sample ln f {best_sample} ({reachable_samples} improving)");
        assert!(reachable_samples > 0);
        assert!(out.plan.grasp.log_objective >= best_sample);
    }
}
