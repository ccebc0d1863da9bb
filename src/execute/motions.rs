//! The arm motions of a grasp, built and checked before anything moves: the
//! joint-space move to the pre-grasp joints, the straight approach to the grasp and
//! the straight lift. The executor validates every request with
//! [`validate_grasp`]; the planner stage runs the same check on its candidates, so
//! a plan it publishes is one the executor accepts.

use super::executor::ExecutorConfig;
use super::path::{palm_speed_limited, peak_palm_speed, straight_line, StraightPath};
use super::report::MotionReport;
use super::request::{ExecutionRequest, ValidRequest};
use super::safety::SafetyCheck;
use super::{ExecuteError, Phase};
use crate::geometry::{pose_error, Pose};
use crate::hw::fri::JOINTS;
use crate::robot::kinematics::ArmJoints;
use crate::robot::HandPose;
use crate::trajectory::Trajectory;
use nalgebra::Translation3;

/// A grasp whose motions passed the safety checks.
#[derive(Debug, Clone)]
pub struct GraspMotions {
    /// The checked request.
    pub request: ValidRequest,
    /// The hand's shape while approaching (open, at the plan's spread).
    pub preshape: HandPose,
    /// The move from the current joints to the pre-grasp joints.
    pub pregrasp_move: MotionReport,
    /// The straight approach.
    pub approach: MotionReport,
    /// The straight lift (checked with the open hand; the executor checks it again
    /// with the measured hand before lifting).
    pub lift: MotionReport,
}

/// `palm` moved straight up by the lift height.
pub fn lifted(config: &ExecutorConfig, palm: &Pose) -> Pose {
    Translation3::new(0.0, 0.0, config.lift_m) * palm
}

/// The trajectory through `waypoints` within the joint limits of `check`; along a
/// straight palm `path`, also at most `config.palm_speed_m_s`.
pub fn motion(
    check: &SafetyCheck,
    config: &ExecutorConfig,
    phase: Phase,
    waypoints: &[ArmJoints],
    path: Option<&StraightPath>,
) -> Result<(Trajectory<JOINTS>, MotionReport), ExecuteError> {
    let to_error = |source| ExecuteError::Trajectory { phase, source };
    let limits = check.limits().joint_limits().map_err(to_error)?;
    let period = check.limits().check_period_s;
    let robot = check.robot();
    let (trajectory, peak) = match path {
        Some(_) => palm_speed_limited(robot, waypoints, &limits, config.palm_speed_m_s, period)
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
    config: &ExecutorConfig,
    phase: Phase,
    name: &'static str,
    waypoints: &[ArmJoints],
    path: Option<&StraightPath>,
    hand: &HandPose,
) -> Result<MotionReport, ExecuteError> {
    let (trajectory, report) = motion(check, config, phase, waypoints, path)?;
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
    let preshape = HandPose {
        spread_rad: request.spread_rad,
        flex_rad: [0.0; 3],
    };
    let pregrasp_move = checked_motion(
        check,
        config,
        PHASE,
        "pregrasp move",
        &[*current, request.pregrasp_joints_rad],
        None,
        &preshape,
    )?;
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
    let approach_path = straight_line(
        robot,
        &request.pregrasp_joints_rad,
        &request.palm,
        Some(&request.joints_rad),
        &config.path,
    )
    .map_err(path_error("approach"))?;
    let approach = checked_motion(
        check,
        config,
        PHASE,
        "approach",
        &approach_path.waypoints,
        Some(&approach_path),
        &preshape,
    )?;
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
        config,
        PHASE,
        "lift",
        &lift_path.waypoints,
        Some(&lift_path),
        &preshape,
    )?;
    Ok(GraspMotions {
        request,
        preshape,
        pregrasp_move,
        approach,
        lift,
    })
}
