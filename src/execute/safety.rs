//! The safety layer: a wrapper around the arm that refuses any trajectory leaving
//! the URDF's joint limits, the configured velocity and acceleration limits, the
//! workspace box, or the space above the table, whatever the planner sent.
//!
//! [`SafeArm::check`] samples the whole time-parametrised trajectory every
//! [`SafetyLimits::check_period_s`] (and at its end), not only its endpoints. Joint
//! paths are straight lines between rest points, so position extremes lie at the
//! waypoints, where the arm is at rest; a sample misses one by at most
//! `a dt^2 / 2` (2.5e-5 rad at 2 rad/s^2 and 5 ms), far inside the margin.
//! Collisions are checked by distance moved, not by time: at the samples that keep
//! every point of the robot within [`SafetyLimits::collision_step_m`] of the last
//! checked configuration (bounded by [`Robot::max_point_motion_m`]), and at every sample
//! where one period moves it farther. A slow approach is not checked forty times
//! per centimetre, and a fast move no more coarsely than before.
//!
//! The checks run in order of cost, and within each the worst sample is reported:
//! joint positions, velocities, accelerations; then palm height and workspace; then
//! collision of every link with the table and with each other. One exception: a
//! trajectory that starts with only the hand touching the table (fingers closed
//! onto it around a low object) may lift the hand off — the hand may touch the
//! table while the palm is no lower than at the start; the arm never may.

use super::arm::Arm;
use crate::config::CellConfig;
use crate::hw::fri::{FriError, JOINTS};
use crate::robot::collision::Collision;
use crate::robot::kinematics::ArmJoints;
use crate::robot::{HandPose, Robot};
use crate::trajectory::{JointLimits, JointSample, Trajectory, TrajectoryError};
use std::sync::Arc;

/// Relative slack on velocity and acceleration checks, for rounding in profiles
/// built exactly at the limit.
const RATE_SLACK: f64 = 1e-9;

/// A trajectory the safety layer refuses; every variant carries the numbers and the
/// trajectory time of the worst (or first) offending sample.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum SafetyError {
    /// A joint position beyond its URDF limit (less the margin).
    #[error("joint {joint} at {position_rad:.4} rad (t = {t_s:.3} s) is beyond its limit {limit_rad:.4} rad (URDF limit less a {margin_rad} rad margin)")]
    OutOfLimit {
        /// The joint's URDF name.
        joint: String,
        /// The commanded position (rad).
        position_rad: f64,
        /// The limit it passes, margin included (rad).
        limit_rad: f64,
        /// The margin kept inside the URDF limit (rad).
        margin_rad: f64,
        /// Trajectory time of the sample (s).
        t_s: f64,
    },
    /// A joint speed above the URDF limit times `limits.joint_velocity_scale`.
    #[error("joint {joint} at {velocity_rad_s:.4} rad/s (t = {t_s:.3} s) exceeds its limit {limit_rad_s:.4} rad/s")]
    VelocityOutOfLimit {
        /// The joint's URDF name.
        joint: String,
        /// The commanded speed (rad/s, signed).
        velocity_rad_s: f64,
        /// The allowed speed (rad/s).
        limit_rad_s: f64,
        /// Trajectory time of the sample (s).
        t_s: f64,
    },
    /// A joint acceleration above `limits.joint_acceleration_rad_s2`.
    #[error("joint {joint} at {acceleration_rad_s2:.4} rad/s^2 (t = {t_s:.3} s) exceeds its limit {limit_rad_s2:.4} rad/s^2")]
    AccelerationOutOfLimit {
        /// The joint's URDF name.
        joint: String,
        /// The commanded acceleration (rad/s^2, signed).
        acceleration_rad_s2: f64,
        /// The allowed acceleration (rad/s^2).
        limit_rad_s2: f64,
        /// Trajectory time of the sample (s).
        t_s: f64,
    },
    /// The palm below the table top plus the palm clearance.
    #[error("palm at z = {palm_z_m:.4} m (t = {t_s:.3} s) is below the table clearance z >= {min_z_m:.4} m")]
    BelowTable {
        /// Palm height (m).
        palm_z_m: f64,
        /// Lowest allowed palm height (m).
        min_z_m: f64,
        /// Trajectory time of the sample (s).
        t_s: f64,
    },
    /// The palm outside the workspace box.
    #[error("palm at {palm_xyz_m:.4?} m (t = {t_s:.3} s) is outside the workspace box {min_m:?}..{max_m:?} m")]
    OutsideWorkspace {
        /// Palm position (m).
        palm_xyz_m: [f64; 3],
        /// Lower corner of the box (m).
        min_m: [f64; 3],
        /// Upper corner of the box (m).
        max_m: [f64; 3],
        /// Trajectory time of the sample (s).
        t_s: f64,
    },
    /// A link touches the table or another link.
    #[error("{collision} at t = {t_s:.3} s, joints {joints_rad:.4?} rad")]
    Collision {
        /// What touches what.
        collision: Collision,
        /// The configuration (rad).
        joints_rad: ArmJoints,
        /// Trajectory time of the sample (s).
        t_s: f64,
    },
}

/// Errors of commanding through the safety layer.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum SafeArmError {
    /// The trajectory was refused; nothing was sent.
    #[error("refused by the safety layer: {0}")]
    Unsafe(#[from] SafetyError),
    /// The arm refused or failed.
    #[error(transparent)]
    Arm(#[from] FriError),
}

/// What the safety layer enforces.
#[derive(Debug, Clone, PartialEq)]
pub struct SafetyLimits {
    /// URDF names of the seven arm joints.
    pub joint_names: [String; JOINTS],
    /// URDF lower position limits (rad).
    pub lower_rad: [f64; JOINTS],
    /// URDF upper position limits (rad).
    pub upper_rad: [f64; JOINTS],
    /// Margin kept inside the position limits (rad); the FRI robot drops to monitor
    /// at a limit.
    pub margin_rad: f64,
    /// Joint speed limits: URDF velocity times `limits.joint_velocity_scale` (rad/s).
    pub velocity_rad_s: [f64; JOINTS],
    /// Joint acceleration limits (rad/s^2).
    pub acceleration_rad_s2: [f64; JOINTS],
    /// Lower corner of the palm's workspace box (m).
    pub workspace_min_m: [f64; 3],
    /// Upper corner of the palm's workspace box (m).
    pub workspace_max_m: [f64; 3],
    /// Lowest palm height: table top plus palm clearance (m).
    pub min_palm_z_m: f64,
    /// Sampling period of the checks, in trajectory time (s).
    pub check_period_s: f64,
    /// Collisions are checked at samples no point of the robot moves farther apart
    /// than this (m), or at every sample where one period moves it farther.
    pub collision_step_m: f64,
}

impl SafetyLimits {
    /// The limits of the cell: URDF joint limits of `robot`, scaled velocities,
    /// acceleration, workspace and table from `config`.
    pub fn from_cell(config: &CellConfig, robot: &Robot) -> SafetyLimits {
        let arm = &robot.description.variables[..JOINTS];
        SafetyLimits {
            joint_names: std::array::from_fn(|j| arm[j].name.clone()),
            lower_rad: std::array::from_fn(|j| arm[j].lower_rad),
            upper_rad: std::array::from_fn(|j| arm[j].upper_rad),
            margin_rad: 0.01,
            velocity_rad_s: std::array::from_fn(|j| {
                arm[j].velocity_rad_s * config.limits.joint_velocity_scale
            }),
            acceleration_rad_s2: [config.limits.joint_acceleration_rad_s2; JOINTS],
            workspace_min_m: config.workspace.min_m,
            workspace_max_m: config.workspace.max_m,
            min_palm_z_m: config.table.height_m + config.table.palm_clearance_m,
            check_period_s: 0.005,
            collision_step_m: 0.002,
        }
    }

    /// The velocity and acceleration limits trajectories are built with.
    pub fn joint_limits(&self) -> Result<JointLimits<JOINTS>, TrajectoryError> {
        JointLimits::new(self.velocity_rad_s, self.acceleration_rad_s2)
    }
}

/// The safety checks without an arm: what [`SafeArm`] enforces, for validating
/// motions ahead of time (the planner checks the grasp's motions with it too).
#[derive(Debug, Clone)]
pub struct SafetyCheck {
    robot: Arc<Robot>,
    limits: SafetyLimits,
}

impl SafetyCheck {
    /// Checks of `robot`'s motions against `limits`.
    pub fn new(robot: Arc<Robot>, limits: SafetyLimits) -> SafetyCheck {
        SafetyCheck { robot, limits }
    }

    /// The limits enforced.
    pub fn limits(&self) -> &SafetyLimits {
        &self.limits
    }

    /// The robot whose kinematics and collision model are used.
    pub fn robot(&self) -> &Robot {
        &self.robot
    }

    /// Checks `trajectory` with the hand shaped as `hand`.
    pub fn check_with(
        &self,
        trajectory: &Trajectory<JOINTS>,
        hand: &HandPose,
    ) -> Result<(), SafetyError> {
        let samples = self.samples(trajectory);
        self.check_joints(&samples)?;
        self.check_palm(&samples)?;
        // The arm moves the hand as one body: its links against each other are not
        // checked (fingers closed until they meet lift like any other grasp). A hand
        // resting on the table (fingers closed onto it) may lift off: while the palm
        // is no lower than at the start, only its touching the table is allowed.
        let robot = &self.robot;
        let start = &samples[0].1.position;
        let resting = robot.collision_in_arm_motion(start, hand, false).is_some()
            && robot.collision_in_arm_motion(start, hand, true).is_none();
        let start_z = robot.arm().palm(start).translation.z;
        for k in self.collision_samples(&samples) {
            let (t_s, s) = &samples[k];
            let lifting_off =
                resting && robot.arm().palm(&s.position).translation.z >= start_z - 1e-9;
            let collision = robot.collision_in_arm_motion(&s.position, hand, lifting_off);
            if let Some(collision) = collision {
                return Err(SafetyError::Collision {
                    collision,
                    joints_rad: s.position,
                    t_s: *t_s,
                });
            }
        }
        Ok(())
    }

    /// Checks one configuration, held still, with the hand shaped as `hand`: what
    /// [`SafetyCheck::check_with`] checks at each sample of a motion (joint limits
    /// with the margin, palm height and workspace, collisions), but no rates.
    pub fn check_configuration(
        &self,
        joints: &[f64; JOINTS],
        hand: &HandPose,
    ) -> Result<(), SafetyError> {
        let still = [(
            0.0,
            JointSample {
                position: *joints,
                velocity: [0.0; JOINTS],
                acceleration: [0.0; JOINTS],
            },
        )];
        self.check_joints(&still)?;
        self.check_palm(&still)?;
        match self.robot.collision_in_arm_motion(joints, hand, false) {
            Some(collision) => Err(SafetyError::Collision {
                collision,
                joints_rad: *joints,
                t_s: 0.0,
            }),
            None => Ok(()),
        }
    }

    /// The indices of `samples` whose collisions are checked: the first, the last,
    /// and each one after which the next sample would be more than
    /// `collision_step_m` from the last one checked (an upper bound on how far any
    /// point of the robot moved, [`Robot::max_point_motion_m`]).
    fn collision_samples(&self, samples: &[(f64, JointSample<JOINTS>)]) -> Vec<usize> {
        let mut checked: Vec<usize> = Vec::new();
        for k in 0..samples.len() {
            let within = match (checked.last(), samples.get(k + 1)) {
                (Some(&last), Some((_, next))) => {
                    // NaN never compares within: such a sample is checked.
                    self.robot
                        .max_point_motion_m(&samples[last].1.position, &next.position)
                        <= self.limits.collision_step_m
                }
                _ => false,
            };
            if !within {
                checked.push(k);
            }
        }
        checked
    }

    /// Samples every `check_period_s` from 0, and the end.
    fn samples(&self, trajectory: &Trajectory<JOINTS>) -> Vec<(f64, JointSample<JOINTS>)> {
        let dt = self.limits.check_period_s;
        let duration = trajectory.duration_s();
        let steps = (duration / dt).floor() as usize;
        let mut samples: Vec<(f64, JointSample<JOINTS>)> = (0..=steps)
            .map(|k| k as f64 * dt)
            .map(|t| (t, trajectory.sample(t)))
            .collect();
        if samples.last().is_none_or(|(t, _)| *t < duration) {
            samples.push((duration, trajectory.sample(duration)));
        }
        samples
    }

    fn check_joints(&self, samples: &[(f64, JointSample<JOINTS>)]) -> Result<(), SafetyError> {
        let l = &self.limits;
        let name = |j: usize| l.joint_names[j].clone();
        // (excess, error) of the worst sample per kind.
        let mut position: Option<(f64, SafetyError)> = None;
        let mut velocity: Option<(f64, SafetyError)> = None;
        let mut acceleration: Option<(f64, SafetyError)> = None;
        let worse =
            |slot: &mut Option<(f64, SafetyError)>, excess: f64, make: &dyn Fn() -> SafetyError| {
                // NaN (a NaN position, velocity or acceleration) is the worst excess.
                let excess = if excess.is_nan() {
                    f64::INFINITY
                } else {
                    excess
                };
                if excess > 0.0 && slot.as_ref().is_none_or(|(e, _)| excess > *e) {
                    *slot = Some((excess, make()));
                }
            };
        for &(t_s, ref s) in samples {
            for j in 0..JOINTS {
                let q = s.position[j];
                let (lo, hi) = (l.lower_rad[j] + l.margin_rad, l.upper_rad[j] - l.margin_rad);
                let (excess, limit_rad) = if q < lo { (lo - q, lo) } else { (q - hi, hi) };
                worse(&mut position, excess, &|| SafetyError::OutOfLimit {
                    joint: name(j),
                    position_rad: q,
                    limit_rad,
                    margin_rad: l.margin_rad,
                    t_s,
                });
                let v = s.velocity[j];
                let limit_rad_s = l.velocity_rad_s[j];
                worse(
                    &mut velocity,
                    v.abs() - limit_rad_s * (1.0 + RATE_SLACK),
                    &|| SafetyError::VelocityOutOfLimit {
                        joint: name(j),
                        velocity_rad_s: v,
                        limit_rad_s,
                        t_s,
                    },
                );
                let a = s.acceleration[j];
                let limit_rad_s2 = l.acceleration_rad_s2[j];
                worse(
                    &mut acceleration,
                    a.abs() - limit_rad_s2 * (1.0 + RATE_SLACK),
                    &|| SafetyError::AccelerationOutOfLimit {
                        joint: name(j),
                        acceleration_rad_s2: a,
                        limit_rad_s2,
                        t_s,
                    },
                );
            }
        }
        match position.or(velocity).or(acceleration) {
            Some((_, error)) => Err(error),
            None => Ok(()),
        }
    }

    fn check_palm(&self, samples: &[(f64, JointSample<JOINTS>)]) -> Result<(), SafetyError> {
        let l = &self.limits;
        let mut below: Option<(f64, SafetyError)> = None;
        let mut outside: Option<(f64, SafetyError)> = None;
        for &(t_s, ref s) in samples {
            let p = self.robot.arm().palm(&s.position).translation.vector;
            let palm_xyz_m = [p.x, p.y, p.z];
            let excess = l.min_palm_z_m - p.z;
            if excess > 0.0 && below.as_ref().is_none_or(|(e, _)| excess > *e) {
                below = Some((
                    excess,
                    SafetyError::BelowTable {
                        palm_z_m: p.z,
                        min_z_m: l.min_palm_z_m,
                        t_s,
                    },
                ));
            }
            let excess = (0..3)
                .map(|i| (l.workspace_min_m[i] - p[i]).max(p[i] - l.workspace_max_m[i]))
                .fold(f64::NEG_INFINITY, f64::max);
            if excess > 0.0 && outside.as_ref().is_none_or(|(e, _)| excess > *e) {
                outside = Some((
                    excess,
                    SafetyError::OutsideWorkspace {
                        palm_xyz_m,
                        min_m: l.workspace_min_m,
                        max_m: l.workspace_max_m,
                        t_s,
                    },
                ));
            }
        }
        match below.or(outside) {
            Some((_, error)) => Err(error),
            None => Ok(()),
        }
    }
}

/// The arm behind the safety layer: every trajectory is checked before it is sent.
///
/// Collision checks use the hand's current shape, which the owner keeps up to date
/// with [`SafeArm::set_hand`].
pub struct SafeArm<A> {
    arm: A,
    check: SafetyCheck,
    hand: HandPose,
}

impl<A: Arm> SafeArm<A> {
    /// Wraps `arm`; the hand is assumed open until told otherwise.
    pub fn new(arm: A, robot: Arc<Robot>, limits: SafetyLimits) -> SafeArm<A> {
        SafeArm {
            arm,
            check: SafetyCheck::new(robot, limits),
            hand: HandPose::OPEN,
        }
    }

    /// The limits enforced.
    pub fn limits(&self) -> &SafetyLimits {
        self.check.limits()
    }

    /// The checks applied to every trajectory.
    pub fn safety(&self) -> &SafetyCheck {
        &self.check
    }

    /// The hand shape collision checks use.
    pub fn hand(&self) -> HandPose {
        self.hand
    }

    /// Sets the hand shape collision checks use.
    pub fn set_hand(&mut self, hand: HandPose) {
        self.hand = hand;
    }

    /// The wrapped arm, for reading only: status and stop never move it unsafely.
    pub fn arm(&self) -> &A {
        &self.arm
    }

    /// Checks `trajectory` with the current hand shape.
    pub fn check(&self, trajectory: &Trajectory<JOINTS>) -> Result<(), SafetyError> {
        self.check.check_with(trajectory, &self.hand)
    }

    /// Checks `trajectory` with the hand shaped as `hand`.
    pub fn check_with(
        &self,
        trajectory: &Trajectory<JOINTS>,
        hand: &HandPose,
    ) -> Result<(), SafetyError> {
        self.check.check_with(trajectory, hand)
    }

    /// Checks `trajectory`, then starts it on the arm.
    pub fn start_trajectory(&self, trajectory: Trajectory<JOINTS>) -> Result<u64, SafeArmError> {
        self.check(&trajectory)?;
        Ok(self.arm.start_trajectory(trajectory)?)
    }

    /// Checks `trajectory`, then starts it on the arm guarded by `guard` (it
    /// stops at contact); the whole trajectory is checked, as if no contact came.
    pub fn start_guarded_trajectory(
        &self,
        trajectory: Trajectory<JOINTS>,
        guard: crate::hw::fri::ForceGuard,
    ) -> Result<u64, SafeArmError> {
        self.check(&trajectory)?;
        Ok(self.arm.start_guarded_trajectory(trajectory, guard)?)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::hw::fri::FriStatus;
    use crate::robot::shipped_robot;
    use std::sync::Mutex;

    /// An arm that records what reaches it.
    #[derive(Default)]
    struct Recorder {
        started: Mutex<Vec<Trajectory<JOINTS>>>,
    }

    impl Arm for Recorder {
        fn status(&self) -> FriStatus {
            unimplemented!("not used")
        }
        fn start_trajectory(&self, trajectory: Trajectory<JOINTS>) -> Result<u64, FriError> {
            let mut started = self.started.lock().unwrap();
            started.push(trajectory);
            Ok(started.len() as u64)
        }
        fn start_guarded_trajectory(
            &self,
            trajectory: Trajectory<JOINTS>,
            _guard: crate::hw::fri::ForceGuard,
        ) -> Result<u64, FriError> {
            self.start_trajectory(trajectory)
        }
        fn motion_outcome(&self, _id: u64) -> Option<Result<(), FriError>> {
            None
        }
        fn stop(&self) {}
    }

    fn cell() -> CellConfig {
        let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
            .join(crate::config::DEFAULT_CONFIG_PATH);
        CellConfig::load(&path).unwrap()
    }

    fn safe_arm() -> SafeArm<Recorder> {
        let robot = shipped_robot();
        let limits = SafetyLimits::from_cell(&cell(), &robot);
        SafeArm::new(Recorder::default(), Arc::new(robot), limits)
    }

    /// A configuration with the palm over the table, pointing down.
    const OVER_TABLE: ArmJoints = [0.0, -0.6, 0.0, 1.2, 0.0, -0.8, 0.0];

    #[test]
    fn limits_come_from_the_urdf_and_the_config() {
        let arm = safe_arm();
        let l = arm.limits();
        // URDF: lbr_a2 +-2.094395 rad, 1.919862 rad/s; cell.toml: scale 0.5, 2 rad/s^2.
        assert_eq!(l.joint_names[1], "lbr_a2");
        assert_eq!((l.lower_rad[1], l.upper_rad[1]), (-2.094395, 2.094395));
        assert_eq!(l.velocity_rad_s[1], 1.919862 * 0.5);
        assert_eq!(l.acceleration_rad_s2, [2.0; JOINTS]);
        assert_eq!(l.min_palm_z_m, 0.05);
        assert_eq!(l.workspace_max_m, [1.10, 0.70, 1.00]);
    }

    #[test]
    fn a_safe_trajectory_passes_and_reaches_the_arm() {
        let arm = safe_arm();
        let limits = arm.limits().joint_limits().unwrap();
        let start = [0.0, -0.3, 0.0, 1.6, 0.0, -0.8, 0.0];
        let t = Trajectory::point_to_point(start, OVER_TABLE, &limits).unwrap();
        assert_eq!(arm.start_trajectory(t.clone()), Ok(1));
        assert_eq!(*arm.arm().started.lock().unwrap(), [t]);
    }

    #[test]
    fn joint_beyond_its_limit_is_refused_with_the_numbers() {
        let arm = safe_arm();
        let limits = arm.limits().joint_limits().unwrap();
        let mut goal = OVER_TABLE;
        goal[1] = 2.3;
        let t = Trajectory::point_to_point(OVER_TABLE, goal, &limits).unwrap();
        let err = arm.start_trajectory(t.clone()).unwrap_err();
        let SafeArmError::Unsafe(SafetyError::OutOfLimit {
            joint,
            position_rad,
            limit_rad,
            t_s,
            ..
        }) = &err
        else {
            panic!("{err}");
        };
        // The worst sample is the end, 2.3 rad against 2.094395 - 0.01.
        assert_eq!(joint, "lbr_a2");
        assert_eq!(*position_rad, 2.3);
        assert!((limit_rad - 2.084395).abs() < 1e-12, "{limit_rad}");
        assert_eq!(*t_s, t.duration_s());
        assert!(err.to_string().contains("lbr_a2 at 2.3000 rad"), "{err}");
        assert!(arm.arm().started.lock().unwrap().is_empty(), "nothing sent");
    }

    #[test]
    fn speed_above_the_scaled_limit_is_caught_between_the_endpoints() {
        let arm = safe_arm();
        // Built at twice the allowed speed: endpoints at rest, the middle too fast.
        let l = arm.limits();
        let full =
            JointLimits::new(l.velocity_rad_s.map(|v| 2.0 * v), l.acceleration_rad_s2).unwrap();
        let mut goal = OVER_TABLE;
        goal[0] += 1.0;
        let t = Trajectory::point_to_point(OVER_TABLE, goal, &full).unwrap();
        let err = arm.check(&t).unwrap_err();
        let SafetyError::VelocityOutOfLimit {
            joint,
            velocity_rad_s,
            limit_rad_s,
            t_s,
        } = &err
        else {
            panic!("{err}");
        };
        assert_eq!(joint, "lbr_a1");
        // A triangular profile over 1 rad at 2 rad/s^2 peaks at sqrt(2) rad/s (between
        // samples 5 ms apart: within 0.01), against 0.959931 rad/s allowed.
        assert!(
            *velocity_rad_s <= 2f64.sqrt() && *velocity_rad_s > 2f64.sqrt() - 0.01,
            "{err}"
        );
        assert_eq!(*limit_rad_s, 0.959931);
        assert!(*t_s > 0.0 && *t_s < t.duration_s(), "{err}");
        // The endpoints alone are fine.
        arm.check(&Trajectory::point_to_point(goal, goal, &full).unwrap())
            .unwrap();
    }

    #[test]
    fn palm_below_the_table_and_outside_the_workspace_are_refused() {
        let arm = safe_arm();
        let limits = arm.limits().joint_limits().unwrap();
        let robot = shipped_robot();
        // Fold A2 forward until the palm is low: find the sample independently.
        let mut low = OVER_TABLE;
        low[1] = -1.25;
        let palm_z = robot.arm().palm(&low).translation.z;
        assert!(palm_z < 0.05, "test setup: palm at {palm_z}");
        let t = Trajectory::point_to_point(OVER_TABLE, low, &limits).unwrap();
        match arm.check(&t).unwrap_err() {
            SafetyError::BelowTable {
                palm_z_m, min_z_m, ..
            } => {
                assert!((palm_z_m - palm_z).abs() < 1e-9, "{palm_z_m} vs {palm_z}");
                assert_eq!(min_z_m, 0.05);
            }
            other => panic!("{other}"),
        }
        // Straight up: the palm is above the workspace's 1.0 m ceiling.
        let up = [0.0; JOINTS];
        let top = robot.arm().palm(&up).translation.vector;
        assert!(top.z > 1.0 && top.x < 0.15, "test setup: palm at {top:?}");
        let t = Trajectory::point_to_point(OVER_TABLE, up, &limits).unwrap();
        match arm.check(&t).unwrap_err() {
            SafetyError::OutsideWorkspace {
                palm_xyz_m, max_m, ..
            } => {
                assert_eq!(max_m, [1.10, 0.70, 1.00]);
                assert!(
                    palm_xyz_m[2] > 1.0 || palm_xyz_m[0] < 0.15,
                    "{palm_xyz_m:?}"
                );
            }
            other => panic!("{other}"),
        }
    }

    #[test]
    fn a_hand_resting_on_the_table_may_lift_off_but_not_press_down() {
        let arm = safe_arm();
        let robot = shipped_robot();
        let limits = arm.limits().joint_limits().unwrap();
        let open = HandPose {
            spread_rad: 0.0,
            flex_rad: [0.0; 3],
        };
        let solve = |z: f64| {
            let palm =
                crate::geometry::pose_from_params(&[0.6, 0.0, z, std::f64::consts::PI, 0.0, 0.0]);
            robot.ik.solve(&palm, &[OVER_TABLE]).unwrap().joints
        };
        // Palm down, lowered until the open fingers touch the table (nothing else).
        let (mut z, mut resting) = (0.30, None);
        while z > 0.06 {
            let q = solve(z);
            if robot.collision_at(&q, &open).is_some() {
                assert_eq!(robot.collision_in_arm_motion(&q, &open, true), None);
                resting = Some((z, q));
                break;
            }
            z -= 0.005;
        }
        let (z, on_table) = resting.expect("test setup: the fingers reach the table");
        let above = solve(z + 0.08);
        let lift = Trajectory::point_to_point(on_table, above, &limits).unwrap();
        arm.check_with(&lift, &open).unwrap();
        // Pressing further down is refused, and so is moving down onto the table.
        let lower = solve(z - 0.01);
        let press = Trajectory::point_to_point(on_table, lower, &limits).unwrap();
        assert!(matches!(
            arm.check_with(&press, &open),
            Err(SafetyError::Collision { .. })
        ));
        let descend = Trajectory::point_to_point(above, on_table, &limits).unwrap();
        assert!(matches!(
            arm.check_with(&descend, &open),
            Err(SafetyError::Collision { .. })
        ));
    }

    /// Collisions are checked by distance moved: on a slow move far fewer
    /// configurations than the samples, none two checked more than
    /// `collision_step_m` apart (by the levers' bound) unless one period moves
    /// farther; the first and the last always. A fast move is checked at every
    /// sample, as before.
    #[test]
    fn collisions_are_checked_by_distance_moved() {
        let arm = safe_arm();
        let check = &arm.check;
        let moved = |a: &ArmJoints, b: &ArmJoints| check.robot().max_point_motion_m(a, b);
        let step = check.limits().collision_step_m;
        let fast = arm.limits().joint_limits().unwrap();
        let slow = JointLimits::new([0.02; JOINTS], [0.5; JOINTS]).unwrap();
        let end = [0.05, -0.55, 0.0, 1.15, 0.0, -0.75, 0.0];
        for (limits, slow_move) in [(slow, true), (fast, false)] {
            let t = Trajectory::point_to_point(OVER_TABLE, end, &limits).unwrap();
            let samples = check.samples(&t);
            let checked = check.collision_samples(&samples);
            assert_eq!(checked[0], 0);
            assert_eq!(*checked.last().unwrap(), samples.len() - 1);
            for w in checked.windows(2) {
                let (a, b) = (&samples[w[0]].1.position, &samples[w[1]].1.position);
                assert!(w[1] == w[0] + 1 || moved(a, b) <= step, "{w:?}");
            }
            if slow_move {
                assert!(
                    4 * checked.len() < samples.len(),
                    "{} of {}",
                    checked.len(),
                    samples.len()
                );
            } else {
                let far = samples
                    .windows(2)
                    .filter(|w| moved(&w[0].1.position, &w[1].1.position) > step)
                    .count();
                assert!(
                    checked.len() > far,
                    "{} checked, {far} far steps",
                    checked.len()
                );
            }
        }
    }

    /// A hand closed until its fingers meet (their boxes overlap) is lifted: the
    /// arm does not move the fingers against each other. Against the arm or the
    /// table the same motion is still checked.
    #[test]
    fn a_hand_whose_fingers_meet_may_be_lifted() {
        let arm = safe_arm();
        let robot = shipped_robot();
        let limits = arm.limits().joint_limits().unwrap();
        let solve = |z: f64| {
            let palm =
                crate::geometry::pose_from_params(&[0.6, 0.0, z, std::f64::consts::PI, 0.0, 0.0]);
            robot.ik.solve(&palm, &[OVER_TABLE]).unwrap().joints
        };
        let (low, high) = (solve(0.35), solve(0.45));
        // A closed hand whose own links collide, high above the table.
        let meeting = (0..=20)
            .flat_map(|i| (0..=4).map(move |j| (i, j)))
            .map(|(i, j)| HandPose {
                spread_rad: std::f64::consts::PI * f64::from(j) / 4.0,
                flex_rad: [1.2 + 0.06 * f64::from(i); 3],
            })
            .find(|h| {
                matches!(
                    robot.collision_at(&low, h),
                    Some(Collision::SelfCollision { ref a, ref b })
                        if a.starts_with("bh_") && b.starts_with("bh_")
                )
            })
            .expect("test setup: some closed hand's fingers meet");
        assert_eq!(robot.collision_in_arm_motion(&low, &meeting, false), None);
        let lift = Trajectory::point_to_point(low, high, &limits).unwrap();
        arm.check_with(&lift, &meeting).unwrap();
    }
}
