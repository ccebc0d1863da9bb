//! Straight palm paths (approach and lift) as joint trajectories.
//!
//! [`straight_line`] interpolates palm poses from where the arm is to the target
//! (translation linearly, rotation by slerp, steps of at most
//! [`PathTolerance::step_m`] and [`PathTolerance::step_rad`]) and solves inverse
//! kinematics at each, seeded with the previous solution only, so the arm follows
//! one continuous branch of its redundancy. It then keeps as few of these
//! configurations as it can: a joint-space straight line between two kept ones must
//! hold the palm within [`PathTolerance::position_m`] and
//! [`PathTolerance::rotation_rad`] of the Cartesian line (checked on samples), else
//! the span is split at its middle (Douglas–Peucker style). When the planner's own
//! end configuration is given and the joint-space line to it already stays within
//! tolerance, that single segment is used ([`PathMethod::JointLine`]).
//!
//! The trajectory through the kept configurations stops at each of them (see
//! [`crate::trajectory`]); [`palm_speed_limited`] slows it until the palm's peak
//! speed is within the configured limit.

use crate::geometry::Pose;
use crate::hw::fri::JOINTS;
use crate::robot::kinematics::ArmJoints;
use crate::robot::Robot;
use crate::trajectory::{JointLimits, Trajectory, TrajectoryError};
use nalgebra::{Point3, Vector3};
use serde::Serialize;

/// Samples per joint-space segment when measuring its deviation from the line.
const DEVIATION_SAMPLES: usize = 24;

/// How straight the palm must go, and how finely the line is solved.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct PathTolerance {
    /// Largest palm distance from the straight line (m).
    pub position_m: f64,
    /// Largest palm rotation away from the interpolated orientation (rad).
    pub rotation_rad: f64,
    /// Longest palm step between IK solutions (m).
    pub step_m: f64,
    /// Largest palm rotation between IK solutions (rad).
    pub step_rad: f64,
    /// Largest joint change between successive IK solutions (rad); more means IK
    /// jumped to another branch.
    pub max_joint_step_rad: f64,
}

impl Default for PathTolerance {
    fn default() -> Self {
        PathTolerance {
            position_m: 0.002,
            rotation_rad: 0.02,
            step_m: 0.01,
            step_rad: 0.05,
            max_joint_step_rad: 0.2,
        }
    }
}

/// How the path is followed.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum PathMethod {
    /// One joint-space segment to the planner's configuration (within tolerance).
    JointLine,
    /// Joint-space segments between IK solutions along the Cartesian line.
    CartesianWaypoints,
}

/// A straight palm path as joint configurations to pass through (at rest).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct StraightPath {
    /// How it is followed.
    pub method: PathMethod,
    /// Configurations, starting with the start (rad).
    pub waypoints: Vec<ArmJoints>,
    /// IK solutions computed along the line.
    pub ik_solutions: usize,
    /// Largest palm distance from the line over the joint-space segments (m).
    pub max_position_deviation_m: f64,
    /// Largest palm rotation from the interpolated orientation (rad).
    pub max_rotation_deviation_rad: f64,
}

impl StraightPath {
    /// The final configuration (rad).
    pub fn end(&self) -> ArmJoints {
        *self.waypoints.last().expect("a path has its start")
    }
}

/// Why a straight palm path cannot be followed.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum PathError {
    /// Inverse kinematics did not converge at a point of the line.
    #[error("no IK solution at step {step} of {steps} of the straight line (palm {target_xyz_m:.4?} m; best {pos_err_m:.4} m, {rot_err_rad:.4} rad)")]
    IkFailed {
        /// The step (1-based).
        step: usize,
        /// Steps of the line.
        steps: usize,
        /// Palm position wanted (m).
        target_xyz_m: [f64; 3],
        /// Position error of the best solution (m).
        pos_err_m: f64,
        /// Rotation error of the best solution (rad).
        rot_err_rad: f64,
    },
    /// Successive IK solutions are too far apart: the arm would swing.
    #[error("IK jumps joint {joint} by {jump_rad:.4} rad at step {step} of {steps} (at most {max_rad} rad)")]
    JointJump {
        /// The step (1-based).
        step: usize,
        /// Steps of the line.
        steps: usize,
        /// Zero-based joint index.
        joint: usize,
        /// The change (rad).
        jump_rad: f64,
        /// The allowed change (rad).
        max_rad: f64,
    },
}

/// The palm pose at fraction `s` of the straight line from `a` to `b`.
pub fn interpolate(a: &Pose, b: &Pose, s: f64) -> Pose {
    let translation = a.translation.vector.lerp(&b.translation.vector, s);
    let rotation = a.rotation.slerp(&b.rotation, s);
    Pose::from_parts(translation.into(), rotation)
}

/// The straight palm path from configuration `from` to palm pose `to`; see the
/// module documentation. `preferred_end` is the planner's configuration at `to`.
pub fn straight_line(
    robot: &Robot,
    from: &ArmJoints,
    to: &Pose,
    preferred_end: Option<&ArmJoints>,
    tolerance: &PathTolerance,
) -> Result<StraightPath, PathError> {
    let start = robot.arm().palm(from);
    let distance_m = (to.translation.vector - start.translation.vector).norm();
    let angle_rad = start.rotation.angle_to(&to.rotation);
    // Less a hair (0.1 % of a step), so 0.1 m in 0.01 m steps is 10 steps, not 11
    // by rounding or IK error.
    let steps = ((distance_m / tolerance.step_m).max(angle_rad / tolerance.step_rad) - 1e-3)
        .ceil()
        .max(1.0) as usize;
    let options = *robot.ik.options();
    let mut chain = vec![*from];
    for step in 1..=steps {
        let target = interpolate(&start, to, step as f64 / steps as f64);
        let previous = chain[step - 1];
        let solution = robot.ik.solve_from(&target, &previous);
        if !solution.converged(&options) {
            let p = target.translation.vector;
            return Err(PathError::IkFailed {
                step,
                steps,
                target_xyz_m: [p.x, p.y, p.z],
                pos_err_m: solution.pos_err_m,
                rot_err_rad: solution.rot_err_rad,
            });
        }
        if let Some((joint, jump_rad)) = (0..JOINTS)
            .map(|j| (j, (solution.joints[j] - previous[j]).abs()))
            .find(|&(_, d)| d > tolerance.max_joint_step_rad)
        {
            return Err(PathError::JointJump {
                step,
                steps,
                joint,
                jump_rad,
                max_rad: tolerance.max_joint_step_rad,
            });
        }
        chain.push(solution.joints);
    }
    let line = Line::new(&start, to);
    if let Some(end) = preferred_end {
        let (dp, dr) = line.deviation(robot, from, end);
        if dp <= tolerance.position_m && dr <= tolerance.rotation_rad {
            return Ok(StraightPath {
                method: PathMethod::JointLine,
                waypoints: vec![*from, *end],
                ik_solutions: steps,
                max_position_deviation_m: dp,
                max_rotation_deviation_rad: dr,
            });
        }
    }
    let mut kept = vec![0];
    let mut worst = (0.0f64, 0.0f64);
    let reduction = ChainReduction {
        robot,
        line: &line,
        chain: &chain,
        tolerance,
    };
    reduction.reduce(0, steps, &mut kept, &mut worst);
    Ok(StraightPath {
        method: PathMethod::CartesianWaypoints,
        waypoints: kept.iter().map(|&i| chain[i]).collect(),
        ik_solutions: steps,
        max_position_deviation_m: worst.0,
        max_rotation_deviation_rad: worst.1,
    })
}

/// A chain of IK solutions along `line` to thin out to the waypoints that keep
/// the palm within `tolerance` of it.
#[derive(Clone, Copy)]
struct ChainReduction<'a> {
    robot: &'a Robot,
    line: &'a Line,
    chain: &'a [ArmJoints],
    tolerance: &'a PathTolerance,
}

impl ChainReduction<'_> {
    /// Appends the kept indices of `chain[i..=j]` after `i` to `kept`; `worst` is the
    /// largest (position, rotation) deviation of the joint-space segments kept.
    fn reduce(&self, i: usize, j: usize, kept: &mut Vec<usize>, worst: &mut (f64, f64)) {
        let (dp, dr) = self
            .line
            .deviation(self.robot, &self.chain[i], &self.chain[j]);
        if j == i + 1 || (dp <= self.tolerance.position_m && dr <= self.tolerance.rotation_rad) {
            worst.0 = worst.0.max(dp);
            worst.1 = worst.1.max(dr);
            kept.push(j);
            return;
        }
        let m = (i + j) / 2;
        self.reduce(i, m, kept, worst);
        self.reduce(m, j, kept, worst);
    }
}

/// The Cartesian segment the palm should follow.
struct Line {
    start: Pose,
    end: Pose,
}

impl Line {
    fn new(start: &Pose, end: &Pose) -> Line {
        Line {
            start: *start,
            end: *end,
        }
    }

    /// Largest palm distance from the segment and rotation from the interpolated
    /// orientation at the nearest point, over the joint-space line from `a` to `b`.
    fn deviation(&self, robot: &Robot, a: &ArmJoints, b: &ArmJoints) -> (f64, f64) {
        let p0 = Point3::from(self.start.translation.vector);
        let p1 = Point3::from(self.end.translation.vector);
        let axis: Vector3<f64> = p1 - p0;
        let length2 = axis.norm_squared();
        let mut worst = (0.0f64, 0.0f64);
        for k in 0..=DEVIATION_SAMPLES {
            let s = k as f64 / DEVIATION_SAMPLES as f64;
            let q: ArmJoints = std::array::from_fn(|j| (1.0 - s) * a[j] + s * b[j]);
            let palm = robot.arm().palm(&q);
            let p = Point3::from(palm.translation.vector);
            let u = if length2 > 0.0 {
                ((p - p0).dot(&axis) / length2).clamp(0.0, 1.0)
            } else {
                s
            };
            let nearest = p0 + axis * u;
            let wanted = self.start.rotation.slerp(&self.end.rotation, u);
            worst.0 = worst.0.max((p - nearest).norm());
            worst.1 = worst.1.max(palm.rotation.angle_to(&wanted));
        }
        worst
    }
}

/// A trajectory through `waypoints` within `limits`, slowed (velocity limits scaled
/// down) until the palm's peak speed, sampled every `period_s`, is at most
/// `palm_speed_m_s`. Returns it with that peak speed (m/s).
pub fn palm_speed_limited(
    robot: &Robot,
    waypoints: &[ArmJoints],
    limits: &JointLimits<JOINTS>,
    palm_speed_m_s: f64,
    period_s: f64,
) -> Result<(Trajectory<JOINTS>, f64), TrajectoryError> {
    let mut current = *limits;
    let mut trajectory = Trajectory::through(waypoints, &current)?;
    let mut peak = peak_palm_speed(robot, &trajectory, period_s);
    for _ in 0..8 {
        if peak <= palm_speed_m_s {
            break;
        }
        let scale = 0.98 * palm_speed_m_s / peak;
        current = JointLimits::new(
            current.velocity_rad_s.map(|v| v * scale),
            current.acceleration_rad_s2,
        )?;
        trajectory = Trajectory::through(waypoints, &current)?;
        peak = peak_palm_speed(robot, &trajectory, period_s);
    }
    Ok((trajectory, peak))
}

/// The palm's largest linear speed (m/s) over samples every `period_s`.
pub fn peak_palm_speed(robot: &Robot, trajectory: &Trajectory<JOINTS>, period_s: f64) -> f64 {
    let steps = (trajectory.duration_s() / period_s).ceil() as usize;
    (0..=steps)
        .map(|k| trajectory.sample(k as f64 * period_s))
        .map(|s| {
            let (_, jacobian) = robot.arm().palm_and_jacobian(&s.position);
            let qdot = nalgebra::SVector::<f64, JOINTS>::from(s.velocity);
            (jacobian.fixed_rows::<3>(0) * qdot).norm()
        })
        .fold(0.0, f64::max)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::pose_from_params;
    use crate::robot::shipped_robot;
    use std::f64::consts::PI;

    fn top_down(x: f64, y: f64, z: f64) -> Pose {
        pose_from_params(&[x, y, z, PI, 0.0, PI])
    }

    #[test]
    fn approach_path_keeps_the_palm_on_the_line() {
        let robot = shipped_robot();
        let pregrasp = top_down(0.6, 0.1, 0.25);
        let grasp = top_down(0.6, 0.1, 0.15);
        let from = robot.reach(&pregrasp, &Default::default(), &[]).unwrap();
        let tolerance = PathTolerance::default();
        let path = straight_line(&robot, &from.joints, &grasp, None, &tolerance).unwrap();
        assert_eq!(path.method, PathMethod::CartesianWaypoints);
        assert_eq!(path.ik_solutions, 10);
        assert_eq!(path.waypoints[0], from.joints);
        // It ends at the grasp pose (FK, independent of the path's bookkeeping).
        let (dp, dr) = crate::geometry::pose_error(&robot.arm().palm(&path.end()), &grasp);
        assert!(dp < 1e-3 && dr < 0.01, "{dp} m, {dr} rad");
        // Every point of the joint-space segments is near the line x = 0.6, y = 0.1.
        let mut worst: f64 = 0.0;
        for pair in path.waypoints.windows(2) {
            for k in 0..=50 {
                let s = k as f64 / 50.0;
                let q: ArmJoints = std::array::from_fn(|j| (1.0 - s) * pair[0][j] + s * pair[1][j]);
                let p = robot.arm().palm(&q).translation.vector;
                worst = worst.max(((p.x - 0.6).powi(2) + (p.y - 0.1).powi(2)).sqrt());
                assert!(p.z > 0.15 - 1e-3 && p.z < 0.25 + 1e-3, "{p:?}");
            }
        }
        assert!(
            worst <= tolerance.position_m + 1e-4,
            "{worst} m off the line"
        );
        assert!(path.max_position_deviation_m <= tolerance.position_m + 1e-4);
    }

    #[test]
    fn a_planned_end_within_tolerance_gives_one_joint_segment() {
        let robot = shipped_robot();
        let pregrasp = top_down(0.6, 0.0, 0.25);
        let grasp = top_down(0.6, 0.0, 0.24);
        let from = robot.reach(&pregrasp, &Default::default(), &[]).unwrap();
        let end = robot
            .reach(&grasp, &Default::default(), &[from.joints])
            .unwrap();
        let tolerance = PathTolerance::default();
        let path =
            straight_line(&robot, &from.joints, &grasp, Some(&end.joints), &tolerance).unwrap();
        assert_eq!(path.method, PathMethod::JointLine);
        assert_eq!(path.waypoints, vec![from.joints, end.joints]);
    }

    #[test]
    fn an_unreachable_line_names_the_step() {
        let robot = shipped_robot();
        let from = robot
            .reach(&top_down(0.6, 0.0, 0.25), &Default::default(), &[])
            .unwrap();
        // 3 m away: IK fails on the way.
        let err = straight_line(
            &robot,
            &from.joints,
            &top_down(3.6, 0.0, 0.25),
            None,
            &PathTolerance::default(),
        )
        .unwrap_err();
        assert!(
            matches!(err, PathError::IkFailed { steps: 300, step, .. } if step > 1 && step < 300),
            "{err}"
        );
    }

    #[test]
    fn palm_speed_is_limited() {
        let robot = shipped_robot();
        let a = robot
            .reach(&top_down(0.6, 0.0, 0.25), &Default::default(), &[])
            .unwrap()
            .joints;
        let up = robot.ik.solve_from(&top_down(0.6, 0.0, 0.35), &a);
        assert!(up.converged(robot.ik.options()));
        let b = up.joints;
        let limits = JointLimits::new([1.0; JOINTS], [2.0; JOINTS]).unwrap();
        let fast = Trajectory::through(&[a, b], &limits).unwrap();
        let fast_peak = peak_palm_speed(&robot, &fast, 0.005);
        assert!(fast_peak > 0.2, "test setup: {fast_peak}");
        let (slow, peak) = palm_speed_limited(&robot, &[a, b], &limits, 0.1, 0.005).unwrap();
        assert!(peak <= 0.1, "{peak}");
        // Independently: finite differences of the palm position.
        let dt = 0.001;
        let mut worst: f64 = 0.0;
        let mut t = 0.0;
        while t < slow.duration_s() {
            let p0 = robot
                .arm()
                .palm(&slow.sample(t).position)
                .translation
                .vector;
            let p1 = robot
                .arm()
                .palm(&slow.sample(t + dt).position)
                .translation
                .vector;
            worst = worst.max((p1 - p0).norm() / dt);
            t += dt;
        }
        assert!(worst <= 0.1 * 1.01, "finite-difference palm speed {worst}");
        assert!(slow.duration_s() > fast.duration_s());
    }
}
