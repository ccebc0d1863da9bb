//! The arm motions of a grasp, built and checked before anything moves: the
//! move to the pre-grasp joints (one joint-space segment, or along the straight
//! palm line where the safety layer refuses that, see [`pregrasp_move`]), the
//! straight approach through the
//! grasp to the end of the overtravel (approach to contact: the executor runs it
//! as a guarded move that stops at contact) and the straight lift. The executor validates every request with
//! [`validate_grasp`]; the planner stage runs the same check on its candidates, so
//! a plan it publishes is one the executor accepts.

use super::executor::ExecutorConfig;
use super::path::{
    palm_speed_limited, peak_palm_speed, straight_line, PathTolerance, StraightPath,
};
use super::report::MotionReport;
use super::request::{ExecutionRequest, ValidRequest};
use super::safety::SafetyCheck;
use super::{ExecuteError, Phase};
use crate::geometry::{pose_error, Pose};
use crate::hw::fri::JOINTS;
use crate::robot::kinematics::{joint_distance_rad, ArmJoints};
use crate::robot::HandPose;
use crate::trajectory::Trajectory;
use nalgebra::Translation3;

/// A grasp whose motions passed the safety checks.
#[derive(Debug, Clone)]
pub struct GraspMotions {
    /// The checked request.
    pub request: ValidRequest,
    /// The hand's shape while approaching (the plan's spread and pre-shape; open
    /// unless the plan names a pre-shape).
    pub preshape: HandPose,
    /// The move from the current joints to the pre-grasp joints.
    pub pregrasp_move: MotionReport,
    /// Its configurations, starting with the current joints.
    pub pregrasp_waypoints: Vec<ArmJoints>,
    /// The straight palm line it follows, when it is not one joint-space segment.
    pub pregrasp_path: Option<StraightPath>,
    /// The straight approach, from the pre-grasp through the grasp to the end of
    /// the overtravel.
    pub approach: MotionReport,
    /// The joints at the end of the approach.
    pub approach_end_rad: ArmJoints,
    /// How far beyond the planned pose the approach may go (m): the configured
    /// overtravel, or less where the safety layer refuses the full one.
    pub overtravel_m: f64,
    /// The straight lift (checked with the open hand; the executor checks it again
    /// with the measured hand before lifting).
    pub lift: MotionReport,
}

/// `palm` moved straight up by the lift height.
pub fn lifted(config: &ExecutorConfig, palm: &Pose) -> Pose {
    Translation3::new(0.0, 0.0, config.lift_m) * palm
}

/// The peak palm speed of the approach (m/s): the guarded move's, at most the
/// general palm speed limit.
pub fn approach_speed_m_s(config: &ExecutorConfig) -> f64 {
    config.approach.speed_m_s.min(config.palm_speed_m_s)
}

/// `palm` moved along its approach axis (+z) by `distance_m`.
pub fn advanced(palm: &Pose, distance_m: f64) -> Pose {
    palm * Pose::translation(0.0, 0.0, distance_m)
}

/// The trajectory through `waypoints` within the joint limits of `check`; along a
/// straight palm `path`, also at most `palm_speed_m_s`.
pub fn motion(
    check: &SafetyCheck,
    palm_speed_m_s: f64,
    phase: Phase,
    waypoints: &[ArmJoints],
    path: Option<&StraightPath>,
) -> Result<(Trajectory<JOINTS>, MotionReport), ExecuteError> {
    let to_error = |source| ExecuteError::Trajectory { phase, source };
    let limits = check.limits().joint_limits().map_err(to_error)?;
    let period = check.limits().check_period_s;
    let robot = check.robot();
    let (trajectory, peak) = match path {
        Some(_) => palm_speed_limited(robot, waypoints, &limits, palm_speed_m_s, period)
            .map_err(to_error)?,
        None => {
            let t = Trajectory::through(waypoints, &limits).map_err(to_error)?;
            let peak = peak_palm_speed(robot, &t, period);
            (t, peak)
        }
    };
    let report = MotionReport {
        method: path.map(|p| p.method),
        waypoints: waypoints.len(),
        duration_s: trajectory.duration_s(),
        peak_palm_speed_m_s: peak,
        max_position_deviation_m: path.map(|p| p.max_position_deviation_m),
        max_rotation_deviation_rad: path.map(|p| p.max_rotation_deviation_rad),
    };
    Ok((trajectory, report))
}

/// [`motion`], checked by the safety layer with the hand shaped as `hand`.
pub fn checked_motion(
    check: &SafetyCheck,
    palm_speed_m_s: f64,
    phase: Phase,
    name: &'static str,
    waypoints: &[ArmJoints],
    path: Option<&StraightPath>,
    hand: &HandPose,
) -> Result<MotionReport, ExecuteError> {
    let (trajectory, report) = motion(check, palm_speed_m_s, phase, waypoints, path)?;
    check
        .check_with(&trajectory, hand)
        .map_err(|source| ExecuteError::Unsafe {
            phase,
            motion: name,
            source: Box::new(source),
        })?;
    Ok(report)
}

/// Builds and checks every arm motion of `request` from the arm at `current`: the
/// pre-grasp move, the approach and the lift; the planner's joints must put the
/// palm at its poses. Errors name the motion and carry the numbers.
pub fn validate_grasp(
    check: &SafetyCheck,
    config: &ExecutorConfig,
    request: &ExecutionRequest,
    current: &ArmJoints,
) -> Result<GraspMotions, ExecuteError> {
    const PHASE: Phase = Phase::Validate;
    let robot = check.robot();
    let request = request.validate()?;
    let preshape = request.preshape_rad.at_spread(request.spread_rad);
    let (pregrasp_move, pregrasp_waypoints, pregrasp_path) =
        pregrasp_move(check, config, &request, current, &preshape)?;
    for (which, joints, pose) in [
        ("pregrasp", &request.pregrasp_joints_rad, &request.pregrasp),
        ("grasp", &request.joints_rad, &request.palm),
    ] {
        let (pos_err_m, rot_err_rad) = pose_error(&robot.arm().palm(joints), pose);
        if pos_err_m > config.plan_tolerance_m || rot_err_rad > config.plan_tolerance_rad {
            return Err(ExecuteError::PlanMismatch {
                which,
                pos_err_m,
                rot_err_rad,
                max_pos_m: config.plan_tolerance_m,
                max_rot_rad: config.plan_tolerance_rad,
            });
        }
    }
    let path_error = |motion| {
        move |source| ExecuteError::Path {
            phase: PHASE,
            motion,
            source,
        }
    };
    // The full overtravel (the grasp's own, else the configured one), or as much
    // of it as the path and the safety layer allow (a quarter at a time), down to
    // none: then the plain approach's error.
    let max = request
        .max_overtravel_m
        .unwrap_or(config.approach.max_overtravel_m);
    let mut tried = [max, 0.75 * max, 0.5 * max, 0.25 * max, 0.0]
        .into_iter()
        .peekable();
    let (approach_path, approach, overtravel_m) = loop {
        let overtravel = tried.next().unwrap_or(0.0);
        let last = overtravel <= 0.0 || tried.peek().is_none();
        let attempt = straight_line(
            robot,
            &request.pregrasp_joints_rad,
            &advanced(&request.palm, overtravel),
            (overtravel <= 0.0).then_some(&request.joints_rad),
            &config.path,
        )
        .map_err(path_error("approach"))
        .and_then(|path| {
            // An approach longer than the last resort that ends where the safety
            // layer refuses the arm is refused as a whole without sampling it: its
            // error (where the motion first goes wrong) is not reported.
            if !last {
                check
                    .check_configuration(&path.end(), &preshape)
                    .map_err(|source| ExecuteError::Unsafe {
                        phase: PHASE,
                        motion: "approach",
                        source: Box::new(source),
                    })?;
            }
            let report = checked_motion(
                check,
                approach_speed_m_s(config),
                PHASE,
                "approach",
                &path.waypoints,
                Some(&path),
                &preshape,
            )?;
            Ok((path, report))
        });
        match attempt {
            Ok((path, report)) => break (path, report, overtravel),
            Err(e) if last => return Err(e),
            Err(e) => tracing::debug!(overtravel, "approach overtravel refused: {e}"),
        }
    };
    let lift_target = lifted(config, &robot.arm().palm(&approach_path.end()));
    let lift_path = straight_line(
        robot,
        &approach_path.end(),
        &lift_target,
        None,
        &config.path,
    )
    .map_err(path_error("lift"))?;
    let lift = checked_motion(
        check,
        config.palm_speed_m_s,
        PHASE,
        "lift",
        &lift_path.waypoints,
        Some(&lift_path),
        &preshape,
    )?;
    Ok(GraspMotions {
        approach_end_rad: approach_path.end(),
        request,
        preshape,
        pregrasp_move,
        pregrasp_waypoints,
        pregrasp_path,
        approach,
        overtravel_m,
        lift,
    })
}

/// How far the pre-grasp move's palm may stray from its straight line (m, rad): it
/// moves through free space, so the line only keeps it inside the workspace; the
/// safety layer checks the motion itself.
const PREGRASP_LINE_POSITION_M: f64 = 0.02;
const PREGRASP_LINE_ROTATION_RAD: f64 = 0.2;

/// The checked move from `current` to the pre-grasp joints, with its waypoints and
/// its straight palm line when it has one. One joint-space segment when the safety
/// layer accepts it; a large shoulder turn in joint space can sweep the palm behind
/// the base or under the table clearance. Else the palm's straight line from where
/// it is to the pre-grasp pose, which stays between its two ends (inside the convex
/// workspace box, above the table), solved continuously from `current` and ending
/// on the planned joints; a line that ends on another branch of the arm's
/// redundancy is refused. When the line fails too, the joint-space segment's
/// refusal is the error. [`pregrasp_line_end`] gives the planner pre-grasp joints
/// on the line's branch.
pub fn pregrasp_move(
    check: &SafetyCheck,
    config: &ExecutorConfig,
    request: &ValidRequest,
    current: &ArmJoints,
    hand: &HandPose,
) -> Result<(MotionReport, Vec<ArmJoints>, Option<StraightPath>), ExecuteError> {
    free_move(
        check,
        config,
        (Phase::Validate, "pregrasp move"),
        current,
        (&request.pregrasp_joints_rad, &request.pregrasp),
        hand,
    )
}

/// The checked move through free space from `current` to the joints `target` (the
/// palm at its pose): as [`pregrasp_move`], one joint-space segment, or else the
/// palm's straight line ending on the target joints. `motion` names the phase and
/// the move in errors.
pub fn free_move(
    check: &SafetyCheck,
    config: &ExecutorConfig,
    motion: (Phase, &'static str),
    current: &ArmJoints,
    target: (&ArmJoints, &Pose),
    hand: &HandPose,
) -> Result<(MotionReport, Vec<ArmJoints>, Option<StraightPath>), ExecuteError> {
    let (phase, name) = motion;
    let (target, target_pose) = (*target.0, target.1);
    let direct = [*current, target];
    let refusal = match checked_motion(
        check,
        config.palm_speed_m_s,
        phase,
        name,
        &direct,
        None,
        hand,
    ) {
        Ok(report) => return Ok((report, direct.to_vec(), None)),
        Err(e) => e,
    };
    let tolerance = pregrasp_tolerance(config);
    let Ok(mut path) = straight_line(
        check.robot(),
        current,
        target_pose,
        Some(&target),
        &tolerance,
    ) else {
        return Err(refusal);
    };
    // The line's last IK solution is the planned configuration up to the solver's
    // tolerance, or (on the same branch) close to it; another branch is refused.
    let end = path.end();
    let apart_rad = joint_distance_rad(&end, &target);
    if apart_rad > config.path.max_joint_step_rad {
        return Err(refusal);
    }
    if apart_rad > 0.0 {
        path.waypoints.push(target);
    }
    match checked_motion(
        check,
        config.palm_speed_m_s,
        phase,
        name,
        &path.waypoints,
        Some(&path),
        hand,
    ) {
        Ok(report) => Ok((report, path.waypoints.clone(), Some(path))),
        Err(e) => {
            tracing::debug!("{name} along the palm line refused too: {e}");
            Err(refusal)
        }
    }
}

/// The configuration at which the palm's straight line from `current` to `pregrasp`
/// ends, solved continuously from `current` with the pre-grasp move's tolerance:
/// pre-grasp joints that [`pregrasp_move`] can reach along the line. `None` where
/// the line has no continuous solution.
pub fn pregrasp_line_end(
    robot: &crate::robot::Robot,
    config: &ExecutorConfig,
    current: &ArmJoints,
    pregrasp: &crate::geometry::Pose,
) -> Option<ArmJoints> {
    straight_line(robot, current, pregrasp, None, &pregrasp_tolerance(config))
        .ok()
        .map(|path| path.end())
}

/// The pre-grasp move's straight-line tolerance: loose, through free space.
fn pregrasp_tolerance(config: &ExecutorConfig) -> PathTolerance {
    PathTolerance {
        position_m: PREGRASP_LINE_POSITION_M.max(config.path.position_m),
        rotation_rad: PREGRASP_LINE_ROTATION_RAD.max(config.path.rotation_rad),
        ..config.path
    }
}
