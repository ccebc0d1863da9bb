//! The executor (`cell execute`): carries out one planned grasp on the arm and the
//! hand — pre-grasp, approach, close, lift, hold — behind a safety layer, under a
//! watchdog, and reports what happened.
//!
//! # Sequence
//! 1. [`Phase::ArmReady`]: wait until the FRI robot is in command mode.
//! 2. [`Phase::Validate`]: build every arm motion of the grasp and check each with
//!    the safety layer ([`SafeArm`]: URDF joint limits, scaled velocity limits,
//!    acceleration, workspace box, table, collisions) before anything moves: the
//!    joint-space move to the pre-grasp joints, the straight approach to the grasp
//!    and the straight lift. The planner's joints must put the palm at its poses.
//! 3. [`Phase::HandBringup`] (first run only): wake, identify, initialise (HI).
//! 4. [`Phase::Preshape`]: fingers open and spread to the plan's, before any arm
//!    motion, so the arm moves with the hand in its approach shape; the unloaded
//!    strain gauges are read as the baseline.
//! 5. [`Phase::Pregrasp`]: joint-space trajectory from the current joints to the
//!    planned pre-grasp joints.
//! 6. [`Phase::Approach`]: approach to contact. The palm moves in a straight line
//!    through the grasp pose up to `approach.max_overtravel_m` beyond it (less
//!    where the safety layer refuses the full overtravel; IK along the line seeded
//!    with the previous solution; a single joint-space segment when that keeps the
//!    palm within tolerance — see [`path`]), at most at `approach.speed_m_s`, as a
//!    guarded move: the FRI driver stops it (decelerate, then hold) at the first
//!    measurement whose estimated external TCP force (`estExtTcpFT`) exceeds its
//!    start value by `approach.contact_force_n`. Contact or not, the hand closes
//!    where the arm came to rest ([`ApproachReport`]).
//! 7. [`Phase::Close`]: [`Hand::close`](crate::hw::hand::Hand::close) with TSTOP; fingers that stalled short of
//!    their close target with a strain rise are in contact; too few is
//!    [`ExecuteError::NoContact`].
//! 8. [`Phase::Lift`]: straight up by [`ExecutorConfig::lift_m`].
//! 9. [`Phase::Hold`]: for [`ExecutorConfig::hold_s`], poll the strain gauges and
//!    finger positions; a finger losing its strain or slipping is
//!    [`ExecuteError::GraspLost`]. Then the [`ExecutionReport`].
//! 10. [`Phase::Park`] ([`Executor::release_and_park`], called by the cell after
//!     the grasp is reported): put the object down where the lift began, open the
//!     hand to the approach shape, back out along the approach to the pre-grasp and
//!     move to the park joints (`robot.park_joints_rad`), so that every snapshot sees
//!     the table without the arm and every plan starts from the same joints. Where
//!     neither the joint line nor the palm's line to the park is accepted (from a
//!     grasp on the shoulder's far branch the joint line swings the palm over the
//!     robot), the arm goes by a [`detour`](detour::detour) in joint space.
//!
//! # Watchdog and stop
//! Every phase has a deadline on the injected [`Clock`](crate::clock::Clock); arm motions get their
//! trajectory's duration times [`ExecutorConfig::motion_timeout_factor`] plus
//! [`ExecutorConfig::motion_timeout_margin_s`], every hand call
//! [`ExecutorConfig::hand_call_timeout_s`] (the driver retries lost frames within
//! it). While the arm moves the executor polls it every [`ExecutorConfig::poll_s`]
//! and between and during hand calls it checks the arm's link: a drop to monitor
//! mode, a late measurement, an arm error, a hand error or a missed deadline ends
//! the run with a named [`ExecuteError`] after stopping both devices. One
//! exception: before the grasp's first arm motion (hand bring-up, pre-shape) the
//! arm stands still, so a drop to monitor or a late measurement there interrupts
//! nothing; the pre-shape ends by waiting up to
//! [`ExecutorConfig::rejoin_timeout_s`] (default 5 s; 0 turns this off) for the
//! KRL program's `friStart` loop to bring the robot back, and the grasp goes on
//! from where the arm is ([`RejoinReport`]). If it does not return, the grasp fails
//! with the drop as found.
//!
//! - **Arm** ([`Arm::stop`], on the FRI driver): a running trajectory decelerates
//!   within its acceleration limits and the arm then holds that position under
//!   the KRC's joint controller, drives powered, brakes open; the driver keeps
//!   answering every measurement. If the robot has already dropped to monitor
//!   mode, the KRC has stopped and holds the arm itself and the driver mirrors its
//!   command; after a late measurement the driver holds its last command. Brakes
//!   and drive power are never touched (the KRL program and the operator own them).
//! - **Hand** ([`Hand::stop`](crate::hw::hand::Hand::stop)): MODE = 3 on all four pucks (group frame, then
//!   confirmed per puck): motion ends and each motor holds its position with up to
//!   its torque limit, so a grasped object stays gripped. An unreachable puck makes
//!   the stop report its error; the others still hold.
//!
//! Nothing is released after a device fault, a refusal or a missed deadline: opening
//! the hand or moving the arm away is then the operator's next decision, not the
//! executor's. Only a grasp that closed without contact or lost its object is
//! released and parked like a successful one.

pub mod arm;
pub mod detour;
pub mod executor;
pub mod motions;
pub mod path;
pub mod report;
pub mod request;
pub mod safety;

#[cfg(test)]
mod lockstep;

pub use arm::Arm;
pub use executor::{Executor, ExecutorConfig};
pub use motions::{pregrasp_line_end, validate_grasp, GraspMotions};
pub use path::{PathError, PathMethod, PathTolerance, StraightPath};
pub use report::{
    ApproachReport, ExecutionReport, MotionReport, Outcome, ParkReport, PhaseReport, RejoinReport,
    StopReport,
};
pub use request::{ExecutionRequest, RequestError, ValidRequest};
pub use safety::{SafeArm, SafeArmError, SafetyCheck, SafetyError, SafetyLimits};

use crate::hw::fri::{FriError, FriState, Quality};
use crate::hw::hand::{HandError, Puck};
use crate::trajectory::TrajectoryError;
use serde::Serialize;

/// A step of the grasp.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Phase {
    /// Waiting for the robot's command mode.
    ArmReady,
    /// Checking every planned motion before any moves.
    Validate,
    /// Waking, identifying and initialising the hand.
    HandBringup,
    /// Opening the fingers and setting the spread.
    Preshape,
    /// Moving to the pre-grasp joints.
    Pregrasp,
    /// Moving the palm straight to the grasp pose.
    Approach,
    /// Closing the fingers on the object.
    Close,
    /// Lifting the object.
    Lift,
    /// Holding it, checking the grasp.
    Hold,
    /// After the grasp: putting the object down, opening, backing out, parking.
    Park,
}

impl std::fmt::Display for Phase {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            Phase::ArmReady => "arm_ready",
            Phase::Validate => "validate",
            Phase::HandBringup => "hand_bringup",
            Phase::Preshape => "preshape",
            Phase::Pregrasp => "pregrasp",
            Phase::Approach => "approach",
            Phase::Close => "close",
            Phase::Lift => "lift",
            Phase::Hold => "hold",
            Phase::Park => "park",
        })
    }
}

/// Why a grasp was not completed; each names the phase and carries the numbers.
#[derive(Debug, thiserror::Error)]
pub enum ExecuteError {
    /// The request is malformed.
    #[error(transparent)]
    Request(#[from] RequestError),
    /// The planner's joints do not put the palm at its pose.
    #[error("plan: {which} joints put the palm {pos_err_m:.4} m and {rot_err_rad:.4} rad away from the {which} pose (at most {max_pos_m} m, {max_rot_rad} rad)")]
    PlanMismatch {
        /// `pregrasp` or `grasp`.
        which: &'static str,
        /// Position error (m).
        pos_err_m: f64,
        /// Rotation error (rad).
        rot_err_rad: f64,
        /// Allowed position error (m).
        max_pos_m: f64,
        /// Allowed rotation error (rad).
        max_rot_rad: f64,
    },
    /// The safety layer refused a motion.
    #[error("{phase}: {motion} refused by the safety layer: {source}")]
    Unsafe {
        /// The phase.
        phase: Phase,
        /// Which motion (`pregrasp move`, `approach`, `lift`).
        motion: &'static str,
        /// What was violated (boxed: it carries a configuration).
        source: Box<SafetyError>,
    },
    /// No straight palm path.
    #[error("{phase}: {motion}: {source}")]
    Path {
        /// The phase.
        phase: Phase,
        /// Which motion.
        motion: &'static str,
        /// Why.
        source: PathError,
    },
    /// A trajectory could not be built.
    #[error("{phase}: {source}")]
    Trajectory {
        /// The phase.
        phase: Phase,
        /// Why.
        source: TrajectoryError,
    },
    /// The robot did not reach command mode in time.
    #[error("arm_ready: robot not in command mode after {waited_s:.3} s (state {state:?}, quality {quality:?})")]
    ArmNotReady {
        /// How long it waited (s).
        waited_s: f64,
        /// The robot's FRI state.
        state: FriState,
        /// The link quality.
        quality: Quality,
    },
    /// The robot left command mode (it stops and holds the arm itself).
    #[error("{phase}: the robot dropped to monitor mode (state {state:?}, quality {quality:?}); the KRC holds the arm")]
    ArmDroppedToMonitor {
        /// The phase.
        phase: Phase,
        /// The robot's FRI state.
        state: FriState,
        /// The link quality.
        quality: Quality,
    },
    /// No measurement from the robot for the FRI timeout.
    #[error("{phase}: no FRI measurement {}; the driver holds the last command", late_detail(*waited_s, *timeout_s))]
    ArmMeasurementLate {
        /// The phase.
        phase: Phase,
        /// Time without a measurement (s), when the driver reported it with a motion.
        waited_s: Option<f64>,
        /// The configured timeout (s), likewise.
        timeout_s: Option<f64>,
    },
    /// Another arm error.
    #[error("{phase}: arm: {source}")]
    Arm {
        /// The phase.
        phase: Phase,
        /// The driver's error.
        source: FriError,
    },
    /// The watchdog: a phase ran past its deadline.
    #[error(
        "{phase}: watchdog: still running after {elapsed_s:.3} s (deadline {deadline_s:.3} s)"
    )]
    PhaseTimeout {
        /// The phase.
        phase: Phase,
        /// Time spent (s).
        elapsed_s: f64,
        /// The deadline (s after the phase began).
        deadline_s: f64,
    },
    /// The hand failed (the message names the puck).
    #[error("{phase}: hand: {source}")]
    Hand {
        /// The phase.
        phase: Phase,
        /// The driver's error.
        source: HandError,
    },
    /// Too few fingers stopped on the object.
    #[error("close: {in_contact} finger(s) in contact, {required} required (stalled {stalled:?}, strain rise {strain_rise:?}, threshold {threshold})")]
    NoContact {
        /// Fingers in contact.
        in_contact: usize,
        /// Fingers required.
        required: usize,
        /// Which of F1, F2, F3 stalled short of the close target.
        stalled: [bool; 3],
        /// Strain gauge rise over the open-hand baseline, F1, F2, F3.
        strain_rise: [i32; 3],
        /// The rise that counts as contact.
        threshold: i32,
    },
    /// A finger lost the object while holding.
    #[error("hold: {finger} lost contact {at_s:.3} s into the hold (strain rise {strain_rise}, threshold {threshold}; at {position_rad:.4} rad, contact at {contact_rad:.4} rad)")]
    GraspLost {
        /// The finger.
        finger: Puck,
        /// Time into the hold (s).
        at_s: f64,
        /// Its strain rise now.
        strain_rise: i32,
        /// The rise that counts as contact.
        threshold: i32,
        /// Its position now (rad).
        position_rad: f64,
        /// Where it stopped on the object (rad).
        contact_rad: f64,
    },
}

impl ExecuteError {
    /// A short stable name of the error, for reports and logs.
    pub fn kind(&self) -> &'static str {
        match self {
            ExecuteError::Request(_) => "bad_request",
            ExecuteError::PlanMismatch { .. } => "plan_mismatch",
            ExecuteError::Unsafe { .. } => "unsafe_motion",
            ExecuteError::Path { .. } => "no_straight_path",
            ExecuteError::Trajectory { .. } => "bad_trajectory",
            ExecuteError::ArmNotReady { .. } => "arm_not_ready",
            ExecuteError::ArmDroppedToMonitor { .. } => "arm_dropped_to_monitor",
            ExecuteError::ArmMeasurementLate { .. } => "arm_measurement_late",
            ExecuteError::Arm { .. } => "arm_error",
            ExecuteError::PhaseTimeout { .. } => "phase_timeout",
            ExecuteError::Hand { source, .. } => match source {
                HandError::Bus(_) => "hand_bus",
                HandError::NoReply { .. } => "hand_no_reply",
                HandError::Garbled { .. } => "hand_garbled_frame",
                HandError::Unexpected { .. } => "hand_unexpected_frame",
                HandError::Timeout { .. } => "hand_timeout",
                HandError::CommandIgnored { .. } => "hand_command_ignored",
                HandError::SetNotApplied { .. } => "hand_set_not_applied",
                _ => "hand_error",
            },
            ExecuteError::NoContact { .. } => "no_contact",
            ExecuteError::GraspLost { .. } => "grasp_lost",
        }
    }

    /// The phase it happened in.
    pub fn phase(&self) -> Phase {
        match self {
            ExecuteError::Request(_) | ExecuteError::PlanMismatch { .. } => Phase::Validate,
            ExecuteError::ArmNotReady { .. } => Phase::ArmReady,
            ExecuteError::NoContact { .. } => Phase::Close,
            ExecuteError::GraspLost { .. } => Phase::Hold,
            ExecuteError::Unsafe { phase, .. }
            | ExecuteError::Path { phase, .. }
            | ExecuteError::Trajectory { phase, .. }
            | ExecuteError::ArmDroppedToMonitor { phase, .. }
            | ExecuteError::ArmMeasurementLate { phase, .. }
            | ExecuteError::Arm { phase, .. }
            | ExecuteError::PhaseTimeout { phase, .. }
            | ExecuteError::Hand { phase, .. } => *phase,
        }
    }

    /// The safety limit a refused motion would have violated.
    pub fn safety_violation(&self) -> Option<&SafetyError> {
        match self {
            ExecuteError::Unsafe { source, .. } => Some(source),
            _ => None,
        }
    }

    /// The error of an arm motion that ended badly in `phase`.
    pub fn from_arm(phase: Phase, error: FriError) -> ExecuteError {
        match error {
            FriError::LeftCommandMode { state, quality } => ExecuteError::ArmDroppedToMonitor {
                phase,
                state,
                quality,
            },
            FriError::MeasurementLate {
                waited_s,
                timeout_s,
            } => ExecuteError::ArmMeasurementLate {
                phase,
                waited_s: Some(waited_s),
                timeout_s: Some(timeout_s),
            },
            source => ExecuteError::Arm { phase, source },
        }
    }
}

fn late_detail(waited_s: Option<f64>, timeout_s: Option<f64>) -> String {
    match (waited_s, timeout_s) {
        (Some(w), Some(t)) => format!("for {w:.3} s (timeout {t} s)"),
        _ => "within the FRI timeout".to_string(),
    }
}
