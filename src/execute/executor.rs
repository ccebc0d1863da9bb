//! The grasp sequence with its watchdog; see the module documentation of
//! [`crate::execute`].

use super::arm::Arm;
use super::detour::{detour, DetourOptions};
use super::motions::{advanced, approach_speed_m_s, lifted, validate_grasp, GraspMotions};
use super::path::{straight_line, PathTolerance, StraightPath};
use super::report::{
    ApproachReport, ExecutionReport, MotionReport, Outcome, ParkReport, PhaseReport, RejoinReport,
    StopReport,
};
use super::request::ExecutionRequest;
use super::safety::{SafeArm, SafeArmError, SafetyLimits};
use super::{ExecuteError, Phase};
use crate::clock::Clock;
use crate::config::{ApproachConfig, CellConfig};
use crate::geometry::PoseJson;
use crate::hw::can::CanBus;
use crate::hw::fri::{ForceGuard, FriError, FriState, FriStatus};
use crate::hw::hand::{Hand, HandPositions, Puck};
use crate::robot::kinematics::{joint_distance_rad, ArmJoints};
use crate::robot::{HandPose, Robot};
use nalgebra::Translation3;
use std::sync::Arc;
use std::time::Duration;

/// Settings of the executor.
#[derive(Debug, Clone, PartialEq)]
pub struct ExecutorConfig {
    /// How far the palm lifts the object, straight up (m).
    pub lift_m: f64,
    /// How long the object is held after the lift (s).
    pub hold_s: f64,
    /// Period of grasp checks while holding (s).
    pub hold_poll_s: f64,
    /// Period of polling the arm while it moves (s).
    pub poll_s: f64,
    /// Longest wait for the robot's command mode (s).
    pub arm_ready_timeout_s: f64,
    /// Longest wait for the robot to re-enter command mode after it left it while
    /// the arm stood still before a grasp's first arm motion (hand bring-up,
    /// pre-shape): nothing was interrupted, so the grasp goes on once the KRL
    /// program's `friStart` loop has the robot back (s). 0: such a drop fails the
    /// grasp, as one during a motion always does.
    pub rejoin_timeout_s: f64,
    /// Timeout of each hand bring-up call: wake, identify, initialise (s).
    pub hand_bringup_timeout_s: f64,
    /// Timeout of every other hand call (s).
    pub hand_call_timeout_s: f64,
    /// An arm motion's deadline is its duration times this ...
    pub motion_timeout_factor: f64,
    /// ... plus this (s).
    pub motion_timeout_margin_s: f64,
    /// Fingers that must stop on the object.
    pub min_contact_fingers: usize,
    /// Strain gauge rise over the open-hand baseline that counts as contact (counts).
    pub contact_strain_rise: i32,
    /// Largest finger movement while holding (rad).
    pub slip_tolerance_rad: f64,
    /// Time given to the arm to come to rest after a stop, before reporting (s).
    pub stop_settle_s: f64,
    /// Peak palm speed of the approach and the lift (m/s).
    pub palm_speed_m_s: f64,
    /// Straightness of approach and lift.
    pub path: PathTolerance,
    /// Largest distance between the palm at the planner's joints and its pose (m).
    pub plan_tolerance_m: f64,
    /// Largest rotation between the palm at the planner's joints and its pose (rad).
    pub plan_tolerance_rad: f64,
    /// Approach to contact: overtravel, contact force, speed.
    pub approach: ApproachConfig,
}

impl Default for ExecutorConfig {
    fn default() -> Self {
        ExecutorConfig {
            lift_m: 0.10,
            hold_s: 2.0,
            hold_poll_s: 0.1,
            poll_s: 0.01,
            arm_ready_timeout_s: 10.0,
            rejoin_timeout_s: 5.0,
            hand_bringup_timeout_s: 30.0,
            hand_call_timeout_s: 10.0,
            motion_timeout_factor: 1.5,
            motion_timeout_margin_s: 2.0,
            min_contact_fingers: 2,
            contact_strain_rise: 300,
            slip_tolerance_rad: 0.05,
            stop_settle_s: 0.5,
            palm_speed_m_s: 0.2,
            path: PathTolerance::default(),
            plan_tolerance_m: 1e-3,
            plan_tolerance_rad: 0.01,
            approach: ApproachConfig::default(),
        }
    }
}

impl ExecutorConfig {
    /// Defaults with the palm speed limit of the cell configuration.
    pub fn from_cell(config: &CellConfig) -> ExecutorConfig {
        ExecutorConfig {
            palm_speed_m_s: config.limits.palm_speed_m_s,
            approach: config.approach.clone(),
            ..ExecutorConfig::default()
        }
    }
}

/// Runs grasps on an arm (behind the safety layer) and a hand.
pub struct Executor<A, B> {
    arm: SafeArm<A>,
    hand: Hand<B>,
    robot: Arc<Robot>,
    clock: Arc<dyn Clock>,
    config: ExecutorConfig,
    /// The hand has been sent commands (bring-up began).
    hand_touched: bool,
    /// The hand has been brought up.
    hand_ready: bool,
    /// What the last grasp left to release, while it may be released.
    leftover: Option<Leftover>,
    /// What the link check found at the first loss of command mode while the arm
    /// stood still before this grasp's first motion, for [`Executor::rejoin`] (the
    /// grasp's error if the robot does not return).
    idle_drop: Option<ExecuteError>,
}

/// What a grasp leaves behind for [`Executor::release_and_park`]: where it came
/// from and, once lifted, where the object was lifted from.
#[derive(Debug, Clone)]
struct Leftover {
    /// The palm at the pre-grasp, where the approach began.
    pregrasp: crate::geometry::Pose,
    /// The hand's shape while approaching.
    preshape: HandPositions,
    /// The arm where the lift began.
    lifted_from: Option<ArmJoints>,
}

/// How far above where the lift began the object is put down (m), in the order
/// tried: the first height the safety layer accepts.
const PUT_DOWN_ABOVE_M: [f64; 4] = [0.01, 0.02, 0.04, 0.07];

fn secs(d: Duration) -> f64 {
    d.as_secs_f64()
}

impl<A: Arm, B: CanBus> Executor<A, B> {
    /// An executor; the arm is wrapped in the safety layer with `limits`. The hand is
    /// brought up on the first run.
    pub fn new(
        arm: A,
        hand: Hand<B>,
        robot: Arc<Robot>,
        limits: SafetyLimits,
        config: ExecutorConfig,
        clock: Arc<dyn Clock>,
    ) -> Executor<A, B> {
        Executor {
            arm: SafeArm::new(arm, Arc::clone(&robot), limits),
            hand,
            robot,
            clock,
            config,
            hand_touched: false,
            hand_ready: false,
            leftover: None,
            idle_drop: None,
        }
    }

    /// An executor with the cell's limits and settings.
    pub fn from_cell(
        arm: A,
        hand: Hand<B>,
        robot: Arc<Robot>,
        cell: &CellConfig,
        clock: Arc<dyn Clock>,
    ) -> Executor<A, B> {
        let limits = SafetyLimits::from_cell(cell, &robot);
        Executor::new(
            arm,
            hand,
            robot,
            limits,
            ExecutorConfig::from_cell(cell),
            clock,
        )
    }

    /// The arm behind its safety layer.
    pub fn safe_arm(&self) -> &SafeArm<A> {
        &self.arm
    }

    /// The hand driver.
    pub fn hand(&mut self) -> &mut Hand<B> {
        &mut self.hand
    }

    /// The settings.
    pub fn config(&self) -> &ExecutorConfig {
        &self.config
    }

    /// Whether the hand has been woken, identified and initialised.
    pub fn hand_ready(&self) -> bool {
        self.hand_ready
    }

    /// Brings the hand up (wake, identify, initialise) ahead of the first grasp, so
    /// that the grasp does not wait for it; needs the arm in command mode (the
    /// fingers move while initialising). A no-op once the hand is up.
    pub fn prepare_hand(&mut self) -> Result<(), ExecuteError> {
        if self.hand_ready {
            return Ok(());
        }
        self.check_arm(Phase::HandBringup)?;
        self.bring_up_hand()
    }

    /// Executes one grasp; the report says how it went (never panics on device
    /// faults: they end the run with a named error after stopping both devices).
    pub fn execute(&mut self, request: &ExecutionRequest) -> ExecutionReport {
        self.execute_observed(request, &mut |_| {})
    }

    /// [`Executor::execute`], calling `observer` as each phase begins.
    pub fn execute_observed(
        &mut self,
        request: &ExecutionRequest,
        observer: &mut dyn FnMut(Phase),
    ) -> ExecutionReport {
        let began = self.clock.now();
        let mut report = ExecutionReport::new();
        self.leftover = None;
        self.idle_drop = None;
        let result = self.run(request, &mut report, began, observer);
        match result {
            Ok(()) => report.outcome = Outcome::Success,
            Err(error) => {
                // A grasp that did not hold may be released; after a device fault or
                // a refusal nothing is (the operator's decision).
                if !matches!(
                    error,
                    ExecuteError::NoContact { .. } | ExecuteError::GraspLost { .. }
                ) {
                    self.leftover = None;
                }
                tracing::error!(kind = error.kind(), "grasp failed: {error}");
                report.failed_phase = Some(error.phase());
                report.error_kind = Some(error.kind());
                report.error = Some(error);
                report.stop = Some(self.stop_all());
                if self.hand_ready {
                    report.hand_positions = self.hand.positions(self.call_timeout()).ok();
                }
            }
        }
        let status = self.arm.arm().status();
        if status.last_seq.is_some() {
            report.final_joints_rad = Some(status.measured_rad);
            report.final_palm = Some(PoseJson::from(&self.robot.arm().palm(&status.measured_rad)));
        }
        report.total_s = secs(self.clock.now().saturating_sub(began));
        report
    }

    /// After a grasp that held, or one that did not (no contact, lost): puts the
    /// object down where it was lifted from, opens the hand to the approach shape,
    /// backs the palm out along the approach to the pre-grasp and moves the arm to
    /// `park_rad`, so that the next snapshot sees the table without the arm and the
    /// next plan starts from the same joints as every other. `Ok(None)` when there
    /// is nothing to release (no grasp yet, a refused plan, or a device fault: then
    /// the arm and hand stay as they are, for the operator). A failure stops both
    /// devices where they are.
    pub fn release_and_park(
        &mut self,
        park_rad: &ArmJoints,
    ) -> Result<Option<ParkReport>, ExecuteError> {
        let Some(left) = self.leftover.take() else {
            return Ok(None);
        };
        let began = self.clock.now();
        let result = self.park(&left, park_rad);
        if result.is_err() {
            self.stop_all();
        }
        let mut report = result?;
        report.total_s = secs(self.clock.now().saturating_sub(began));
        Ok(Some(report))
    }

    fn park(&mut self, left: &Leftover, park_rad: &ArmJoints) -> Result<ParkReport, ExecuteError> {
        const PHASE: Phase = Phase::Park;
        self.wait_arm_ready()?;
        let mut report = ParkReport::default();
        if let Some(from) = left.lifted_from {
            // Down to just above where the lift began: the closed fingers reach
            // under the object, and the safety layer keeps them off the table.
            let lift_start = self.robot.arm().palm(&from);
            let [first, fallbacks @ ..] =
                PUT_DOWN_ABOVE_M.map(|h| Translation3::new(0.0, 0.0, h) * lift_start);
            report.put_down = match self.first_line_accepted("put down", &first, &fallbacks) {
                Ok(motion) => Some(motion),
                // Refused before anything moved: released where it is held.
                Err(e @ (ExecuteError::Path { .. } | ExecuteError::Unsafe { .. })) => {
                    tracing::warn!("the object is released where it is held: {e}");
                    None
                }
                Err(e) => return Err(e),
            };
        }
        if self.hand_ready {
            self.shape_hand(PHASE, &left.preshape)?;
        }
        // Out of the object's way: back along the approach to the pre-grasp, or
        // else straight up by as much.
        let palm = self.robot.arm().palm(&self.commanded());
        let up = (left.pregrasp.translation.vector - palm.translation.vector).norm();
        let straight_up = Translation3::new(0.0, 0.0, up) * palm;
        report.retreat =
            Some(self.first_line_accepted("retreat", &left.pregrasp, &[straight_up])?);
        let start = self.commanded();
        let park_palm = self.robot.arm().palm(park_rad);
        let hand = self.arm.hand();
        let (waypoints, path) = match super::motions::free_move(
            self.arm.safety(),
            &self.config,
            (PHASE, "park"),
            &start,
            (park_rad, &park_palm),
            &hand,
        ) {
            Ok((_, waypoints, path)) => (waypoints, path),
            // Neither the joint line nor the palm's line: around, in joint space.
            Err(refusal) => {
                let options = DetourOptions::default();
                let Some(waypoints) = detour(self.arm.safety(), &hand, &start, park_rad, &options)
                else {
                    return Err(refusal);
                };
                tracing::info!(
                    waypoints = waypoints.len(),
                    "park: a detour where the straight move is refused ({refusal})"
                );
                (waypoints, None)
            }
        };
        report.park = Some(self.move_along(PHASE, "park", &waypoints, path.as_ref())?);
        Ok(report)
    }

    /// Moves the palm along the first straight line, from where it is to `target`
    /// or else to one of `fallbacks`, that the safety layer accepts with the hand
    /// as it is. When it accepts none, nothing moves and the line to `target` is
    /// the error.
    fn first_line_accepted(
        &mut self,
        motion: &'static str,
        target: &crate::geometry::Pose,
        fallbacks: &[crate::geometry::Pose],
    ) -> Result<MotionReport, ExecuteError> {
        let refusal = match self.checked_line(motion, target) {
            Ok(path) => return self.move_along(Phase::Park, motion, &path.waypoints, Some(&path)),
            Err(e) => e,
        };
        for target in fallbacks {
            match self.checked_line(motion, target) {
                Ok(path) => {
                    return self.move_along(Phase::Park, motion, &path.waypoints, Some(&path))
                }
                Err(e) => tracing::debug!("{motion} refused: {e}"),
            }
        }
        Err(refusal)
    }

    /// The palm's straight line from where the arm is to `target`, accepted by the
    /// safety layer with the hand as it is.
    fn checked_line(
        &self,
        motion: &'static str,
        target: &crate::geometry::Pose,
    ) -> Result<StraightPath, ExecuteError> {
        const PHASE: Phase = Phase::Park;
        let path = straight_line(
            &self.robot,
            &self.commanded(),
            target,
            None,
            &self.config.path,
        )
        .map_err(|source| ExecuteError::Path {
            phase: PHASE,
            motion,
            source,
        })?;
        super::motions::checked_motion(
            self.arm.safety(),
            self.config.palm_speed_m_s,
            PHASE,
            motion,
            &path.waypoints,
            Some(&path),
            &self.arm.hand(),
        )?;
        Ok(path)
    }

    fn call_timeout(&self) -> Duration {
        Duration::from_secs_f64(self.config.hand_call_timeout_s)
    }

    /// Runs `body` as `phase`, recording it.
    fn phase<T>(
        &mut self,
        phase: Phase,
        report: &mut ExecutionReport,
        began: Duration,
        observer: &mut dyn FnMut(Phase),
        body: impl FnOnce(&mut Self, &mut ExecutionReport) -> Result<T, ExecuteError>,
    ) -> Result<T, ExecuteError> {
        observer(phase);
        tracing::info!(%phase, "phase begins");
        let start = self.clock.now();
        let result = body(self, report);
        report.phases.push(PhaseReport {
            phase,
            started_s: secs(start.saturating_sub(began)),
            duration_s: secs(self.clock.now().saturating_sub(start)),
            ok: result.is_ok(),
        });
        result
    }

    fn run(
        &mut self,
        request: &ExecutionRequest,
        report: &mut ExecutionReport,
        began: Duration,
        observer: &mut dyn FnMut(Phase),
    ) -> Result<(), ExecuteError> {
        let status = self.phase(Phase::ArmReady, report, began, observer, |ex, _| {
            ex.wait_arm_ready()
        })?;
        let plan = self.phase(Phase::Validate, report, began, observer, |ex, report| {
            let motions =
                validate_grasp(ex.arm.safety(), &ex.config, request, &status.commanded_rad)?;
            report.pregrasp_move = Some(motions.pregrasp_move.clone());
            report.approach = Some(motions.approach.clone());
            report.lift = Some(motions.lift.clone());
            Ok(motions)
        })?;
        if !self.hand_ready {
            self.phase(Phase::HandBringup, report, began, observer, |ex, _| {
                ex.bring_up_hand()
            })?;
        }
        self.leftover = Some(Leftover {
            pregrasp: plan.request.pregrasp,
            preshape: preshape_positions(&plan),
            lifted_from: None,
        });
        self.phase(Phase::Preshape, report, began, observer, |ex, report| {
            ex.preshape(&plan, report)
        })?;
        self.phase(Phase::Pregrasp, report, began, observer, |ex, report| {
            // From where the arm is (the validated start: the pre-shape moves
            // only the hand).
            let mut waypoints = plan.pregrasp_waypoints.clone();
            waypoints[0] = ex.commanded();
            report.pregrasp_move = Some(ex.move_along(
                Phase::Pregrasp,
                "pregrasp move",
                &waypoints,
                plan.pregrasp_path.as_ref(),
            )?);
            Ok(())
        })?;
        self.phase(Phase::Approach, report, began, observer, |ex, report| {
            ex.approach(&plan, report)
        })?;
        let contacts = self.phase(Phase::Close, report, began, observer, |ex, report| {
            ex.close(report)
        })?;
        self.phase(Phase::Lift, report, began, observer, |ex, report| {
            let start = ex.commanded();
            if let Some(left) = &mut ex.leftover {
                left.lifted_from = Some(start);
            }
            let target = lifted(&ex.config, &ex.robot.arm().palm(&start));
            let path = straight_line(&ex.robot, &start, &target, None, &ex.config.path).map_err(
                |source| ExecuteError::Path {
                    phase: Phase::Lift,
                    motion: "lift",
                    source,
                },
            )?;
            report.lift = Some(ex.move_along(Phase::Lift, "lift", &path.waypoints, Some(&path))?);
            Ok(())
        })?;
        self.phase(Phase::Hold, report, began, observer, |ex, report| {
            ex.hold(&contacts, report)
        })
    }

    /// The guarded approach from where the arm is through the grasp to the end
    /// of the overtravel; returns once the arm is at rest, on contact or at the
    /// end.
    fn approach(
        &mut self,
        plan: &GraspMotions,
        report: &mut ExecutionReport,
    ) -> Result<(), ExecuteError> {
        const PHASE: Phase = Phase::Approach;
        let start = self.commanded();
        let end = advanced(&plan.request.palm, plan.overtravel_m);
        let path = straight_line(
            &self.robot,
            &start,
            &end,
            Some(&plan.approach_end_rad),
            &self.config.path,
        )
        .map_err(|source| ExecuteError::Path {
            phase: PHASE,
            motion: "approach",
            source,
        })?;
        let guard = ForceGuard {
            threshold_n: self.config.approach.contact_force_n,
        };
        let (motion, force_n) = self.move_along_guarded(
            PHASE,
            "approach",
            &path.waypoints,
            Some(&path),
            approach_speed_m_s(&self.config),
            Some(guard),
        )?;
        report.approach = Some(motion);
        // At rest where the arm stopped: how far along the approach axis.
        let palm = self.robot.arm().palm(&self.arm.arm().status().measured_rad);
        let beyond_plan_m = (plan.request.palm.inverse() * palm).translation.z;
        report.approach_stop = Some(ApproachReport {
            overtravel_m: plan.overtravel_m,
            contact: force_n.is_some(),
            contact_force_n: force_n,
            beyond_plan_m,
        });
        tracing::info!(contact = force_n.is_some(), beyond_plan_m, "approach ended");
        Ok(())
    }

    /// The joints the arm is commanded to now.
    fn commanded(&self) -> ArmJoints {
        self.arm.arm().status().commanded_rad
    }

    fn wait_arm_ready(&mut self) -> Result<FriStatus, ExecuteError> {
        let (status, waited_s) = self.wait_commanding(self.config.arm_ready_timeout_s);
        if status.commanding {
            Ok(status)
        } else {
            Err(ExecuteError::ArmNotReady {
                waited_s,
                state: status.state,
                quality: status.quality,
            })
        }
    }

    /// Waits up to `timeout_s` for the driver to command the arm; the last status
    /// (`commanding` says whether it does) and the time waited (s).
    fn wait_commanding(&mut self, timeout_s: f64) -> (FriStatus, f64) {
        let start = self.clock.now();
        let timeout = Duration::from_secs_f64(timeout_s);
        loop {
            let status = self.arm.arm().status();
            let waited = self.clock.now().saturating_sub(start);
            if status.commanding || waited >= timeout {
                return (status, secs(waited));
            }
            self.clock
                .sleep(Duration::from_secs_f64(self.config.poll_s));
        }
    }

    /// Moves the arm through `waypoints` (the first is where it is commanded),
    /// through the safety layer, under the watchdog.
    fn move_along(
        &mut self,
        phase: Phase,
        motion: &'static str,
        waypoints: &[ArmJoints],
        path: Option<&StraightPath>,
    ) -> Result<MotionReport, ExecuteError> {
        let speed = self.config.palm_speed_m_s;
        self.move_along_guarded(phase, motion, waypoints, path, speed, None)
            .map(|(report, _)| report)
    }

    /// [`Self::move_along`] at most at `palm_speed_m_s` on straight paths, and with
    /// `guard`: a motion stopped on contact ends well, once the arm is at rest,
    /// with the force that stopped it.
    fn move_along_guarded(
        &mut self,
        phase: Phase,
        motion: &'static str,
        waypoints: &[ArmJoints],
        path: Option<&StraightPath>,
        palm_speed_m_s: f64,
        guard: Option<ForceGuard>,
    ) -> Result<(MotionReport, Option<f64>), ExecuteError> {
        let (trajectory, report) =
            super::motions::motion(self.arm.safety(), palm_speed_m_s, phase, waypoints, path)?;
        let deadline_s = trajectory.duration_s() * self.config.motion_timeout_factor
            + self.config.motion_timeout_margin_s;
        let start = self.clock.now();
        let started = match guard {
            Some(guard) => self.arm.start_guarded_trajectory(trajectory, guard),
            None => self.arm.start_trajectory(trajectory),
        };
        let id = started.map_err(|e| match e {
            SafeArmError::Unsafe(source) => ExecuteError::Unsafe {
                phase,
                motion,
                source: Box::new(source),
            },
            SafeArmError::Arm(source) => ExecuteError::from_arm(phase, source),
        })?;
        let mut contact_n = None;
        loop {
            match self.arm.arm().motion_outcome(id) {
                Some(Err(FriError::Contact { force_n, .. })) if guard.is_some() => {
                    contact_n = Some(force_n);
                    // Braking: done once the arm is at rest.
                    if !self.arm.arm().status().moving {
                        return Ok((report, contact_n));
                    }
                }
                Some(outcome) if contact_n.is_none() => {
                    return outcome
                        .map(|()| (report, None))
                        .map_err(|e| ExecuteError::from_arm(phase, e));
                }
                _ => {}
            }
            let elapsed_s = secs(self.clock.now().saturating_sub(start));
            if elapsed_s > deadline_s {
                self.arm.arm().stop();
                return Err(ExecuteError::PhaseTimeout {
                    phase,
                    elapsed_s,
                    deadline_s,
                });
            }
            self.clock
                .sleep(Duration::from_secs_f64(self.config.poll_s));
        }
    }

    /// Fails when the arm is no longer commanded as it should be.
    fn check_arm(&self, phase: Phase) -> Result<FriStatus, ExecuteError> {
        let s = self.arm.arm().status();
        if s.late {
            Err(ExecuteError::ArmMeasurementLate {
                phase,
                waited_s: None,
                timeout_s: None,
            })
        } else if s.state != FriState::Command {
            Err(ExecuteError::ArmDroppedToMonitor {
                phase,
                state: s.state,
                quality: s.quality,
            })
        } else if !s.commanding {
            Err(ExecuteError::Arm {
                phase,
                source: FriError::NotCommanding {
                    state: s.state,
                    quality: s.quality,
                    power: s.power,
                },
            })
        } else {
            Ok(s)
        }
    }

    /// [`Executor::check_arm`] while the arm stands still before a grasp's first
    /// arm motion (hand bring-up, pre-shape): there a lost link (a drop to monitor,
    /// a late measurement) interrupts nothing, so it is noted for
    /// [`Executor::rejoin`] instead of failing, unless
    /// [`ExecutorConfig::rejoin_timeout_s`] is 0. In any other phase it is
    /// [`Executor::check_arm`].
    fn check_arm_still(&mut self, phase: Phase) -> Result<(), ExecuteError> {
        let before_motion = matches!(phase, Phase::HandBringup | Phase::Preshape);
        match self.check_arm(phase) {
            Err(
                error @ (ExecuteError::ArmDroppedToMonitor { .. }
                | ExecuteError::ArmMeasurementLate { .. }),
            ) if before_motion && self.config.rejoin_timeout_s > 0.0 => {
                if self.idle_drop.is_none() {
                    tracing::warn!(
                        "{error}; the arm stands still, so the grasp waits for command mode \
                         before the arm moves"
                    );
                    self.idle_drop = Some(error);
                }
                Ok(())
            }
            result => result.map(drop),
        }
    }

    /// Before a grasp's first arm motion: if the robot left command mode while the
    /// arm stood still, waits up to [`ExecutorConfig::rejoin_timeout_s`] for it to
    /// return (the KRL program's `friStart` loop), records how long that took and
    /// how far the arm's command moved from `validated_start` meanwhile (the next
    /// motion starts from where the arm is, through the safety layer), and fails
    /// with what the link check found if it does not return.
    fn rejoin(
        &mut self,
        validated_start: &ArmJoints,
        report: &mut ExecutionReport,
    ) -> Result<(), ExecuteError> {
        let Some(lost) = self.idle_drop.take() else {
            return Ok(());
        };
        let (status, waited_s) = self.wait_commanding(self.config.rejoin_timeout_s);
        if !status.commanding {
            return Err(lost);
        }
        let rejoin = RejoinReport {
            lost_in: lost.phase(),
            link: lost.to_string(),
            waited_s,
            drift_rad: joint_distance_rad(&status.commanded_rad, validated_start),
        };
        tracing::info!(
            ?rejoin,
            "the robot is back in command mode; the grasp goes on"
        );
        report.rejoin = Some(rejoin);
        Ok(())
    }

    fn hand_error(phase: Phase) -> impl Fn(crate::hw::hand::HandError) -> ExecuteError {
        move |source| ExecuteError::Hand { phase, source }
    }

    fn bring_up_hand(&mut self) -> Result<(), ExecuteError> {
        const PHASE: Phase = Phase::HandBringup;
        self.hand_touched = true;
        let timeout = Duration::from_secs_f64(self.config.hand_bringup_timeout_s);
        self.hand.wake(timeout).map_err(Self::hand_error(PHASE))?;
        self.check_arm_still(PHASE)?;
        let info = self
            .hand
            .identify(timeout)
            .map_err(Self::hand_error(PHASE))?;
        tracing::info!(?info, "hand identified");
        self.check_arm_still(PHASE)?;
        self.hand
            .initialise(timeout)
            .map_err(Self::hand_error(PHASE))?;
        self.check_arm_still(PHASE)?;
        self.hand_ready = true;
        Ok(())
    }

    fn preshape(
        &mut self,
        plan: &GraspMotions,
        report: &mut ExecutionReport,
    ) -> Result<(), ExecuteError> {
        const PHASE: Phase = Phase::Preshape;
        let timeout = self.call_timeout();
        let positions = self.shape_hand(PHASE, &preshape_positions(plan))?;
        report.hand_positions = Some(positions);
        report.strain_baseline = Some(self.hand.strain(timeout).map_err(Self::hand_error(PHASE))?);
        self.check_arm_still(PHASE)?;
        self.rejoin(&plan.pregrasp_waypoints[0], report)
    }

    /// Moves the fingers and spread to `target`; the safety layer's hand becomes
    /// the measured one, which is returned.
    fn shape_hand(
        &mut self,
        phase: Phase,
        target: &HandPositions,
    ) -> Result<HandPositions, ExecuteError> {
        let timeout = self.call_timeout();
        self.hand
            .move_to(target, timeout)
            .map_err(Self::hand_error(phase))?;
        self.check_arm_still(phase)?;
        let positions = self
            .hand
            .positions(timeout)
            .map_err(Self::hand_error(phase))?;
        self.arm.set_hand(hand_pose(&positions));
        Ok(positions)
    }

    /// Closes the hand; returns the fingers in contact with their positions (rad).
    fn close(&mut self, report: &mut ExecutionReport) -> Result<Vec<(Puck, f64)>, ExecuteError> {
        const PHASE: Phase = Phase::Close;
        let timeout = self.call_timeout();
        let outcomes = self.hand.close(timeout).map_err(Self::hand_error(PHASE))?;
        self.check_arm(PHASE)?;
        let positions = self
            .hand
            .positions(timeout)
            .map_err(Self::hand_error(PHASE))?;
        let strain = self.hand.strain(timeout).map_err(Self::hand_error(PHASE))?;
        self.check_arm(PHASE)?;
        self.arm.set_hand(hand_pose(&positions));
        let baseline = report.strain_baseline.unwrap_or([0; 3]);
        let strain_rise: [i32; 3] = std::array::from_fn(|i| strain[i] - baseline[i]);
        let stalled: [bool; 3] = std::array::from_fn(|i| {
            outcomes
                .iter()
                .find(|o| o.puck == Puck::FINGERS[i])
                .is_some_and(|o| !o.reached_target)
        });
        let threshold = self.config.contact_strain_rise;
        let contacts: Vec<(Puck, f64)> = (0..3)
            .filter(|&i| stalled[i] && strain_rise[i] >= threshold)
            .map(|i| (Puck::FINGERS[i], positions.fingers_rad[i]))
            .collect();
        report.close = outcomes;
        report.hand_positions = Some(positions);
        report.strain = Some(strain);
        report.fingers_in_contact = contacts.iter().map(|c| c.0).collect();
        if contacts.len() < self.config.min_contact_fingers {
            return Err(ExecuteError::NoContact {
                in_contact: contacts.len(),
                required: self.config.min_contact_fingers,
                stalled,
                strain_rise,
                threshold,
            });
        }
        Ok(contacts)
    }

    fn hold(
        &mut self,
        contacts: &[(Puck, f64)],
        report: &mut ExecutionReport,
    ) -> Result<(), ExecuteError> {
        const PHASE: Phase = Phase::Hold;
        let timeout = self.call_timeout();
        let start = self.clock.now();
        let end = start + Duration::from_secs_f64(self.config.hold_s);
        let baseline = report.strain_baseline.unwrap_or([0; 3]);
        let threshold = self.config.contact_strain_rise;
        loop {
            self.clock
                .sleep(Duration::from_secs_f64(self.config.hold_poll_s));
            self.check_arm(PHASE)?;
            let strain = self.hand.strain(timeout).map_err(Self::hand_error(PHASE))?;
            let positions = self
                .hand
                .positions(timeout)
                .map_err(Self::hand_error(PHASE))?;
            self.check_arm(PHASE)?;
            report.strain = Some(strain);
            report.hand_positions = Some(positions);
            let at_s = secs(self.clock.now().saturating_sub(start));
            for &(finger, contact_rad) in contacts {
                let i = finger.index();
                let strain_rise = strain[i] - baseline[i];
                let position_rad = positions.fingers_rad[i];
                if strain_rise < threshold
                    || (position_rad - contact_rad).abs() > self.config.slip_tolerance_rad
                {
                    return Err(ExecuteError::GraspLost {
                        finger,
                        at_s,
                        strain_rise,
                        threshold,
                        position_rad,
                        contact_rad,
                    });
                }
            }
            if self.clock.now() >= end {
                return Ok(());
            }
        }
    }

    /// Stops both devices (hold position) and says what that did.
    fn stop_all(&mut self) -> StopReport {
        self.arm.arm().stop();
        let hand = if !self.hand_touched {
            "never commanded: nothing to stop".to_string()
        } else {
            match self.hand.stop(self.call_timeout()) {
                Ok(()) => "holding: MODE 3 (PID position hold) on all four pucks".to_string(),
                Err(e) => format!("stop failed: {e}"),
            }
        };
        self.clock
            .sleep(Duration::from_secs_f64(self.config.stop_settle_s));
        let s = self.arm.arm().status();
        let arm = if s.last_seq.is_none() {
            "never heard from the robot: nothing was commanded".to_string()
        } else if s.late {
            format!(
                "no measurements: the driver holds its last command {:.4?} rad; the robot stops itself as the link fails",
                s.commanded_rad
            )
        } else if s.state != FriState::Command {
            format!(
                "robot in {:?} mode: the KRC holds the arm at {:.4?} rad",
                s.state, s.measured_rad
            )
        } else {
            format!(
                "holding at {:.4?} rad (commanded; measured {:.4?} rad)",
                s.commanded_rad, s.measured_rad
            )
        };
        StopReport { arm, hand }
    }
}

/// The hand's joints of `plan`'s approach shape.
fn preshape_positions(plan: &GraspMotions) -> HandPositions {
    HandPositions {
        fingers_rad: plan.preshape.flex_rad,
        spread_rad: plan.preshape.spread_rad,
    }
}

/// The hand shape for collision checks from measured positions.
fn hand_pose(positions: &HandPositions) -> HandPose {
    HandPose {
        spread_rad: positions.spread_rad,
        flex_rad: positions.fingers_rad,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::clock::ManualClock;
    use crate::execute::lockstep::LockstepArm;
    use crate::execute::path::PathMethod;
    use crate::execute::SafetyError;
    use crate::geometry::{pose_from_params, Pose};
    use crate::hw::can::{CanBus, VirtualBus};
    use crate::hw::fri::JOINTS;
    use crate::hw::fri::{FriStatus, Quality};
    use crate::hw::hand::{HandError, HandTiming};
    use crate::robot::shipped_robot;
    use crate::sim::fri::{DropReason, SimConfig};
    use crate::sim::puck::{EmulatorThread, HandEmulator, HandEmulatorConfig};
    use crate::trajectory::Trajectory;
    use std::f64::consts::PI;

    /// Where the simulated arm starts: palm about 0.48 m over the table, facing down.
    const HOME: ArmJoints = crate::config::DEFAULT_PARK_JOINTS_RAD;
    const CONTACT_RAD: [f64; 3] = [1.0, 1.1, 1.2];

    fn cell() -> CellConfig {
        let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
            .join(crate::config::DEFAULT_CONFIG_PATH);
        CellConfig::load(&path).unwrap()
    }

    /// A top-down grasp at (0.6, 0, 0.20) from 0.10 m above, solved independently
    /// of the executor.
    fn request(robot: &Robot) -> ExecutionRequest {
        request_between(
            robot,
            &pose_from_params(&[0.6, 0.0, 0.30, PI, 0.0, PI]),
            &pose_from_params(&[0.6, 0.0, 0.20, PI, 0.0, PI]),
        )
    }

    /// The grasp at `palm` from `pregrasp`, solved from home; spread 0.3 rad.
    fn request_between(robot: &Robot, pregrasp: &Pose, palm: &Pose) -> ExecutionRequest {
        let (pregrasp, palm) = (*pregrasp, *palm);
        let pre = robot.reach(&pregrasp, &HandPose::OPEN, &[HOME]).unwrap();
        let grasp = robot.reach(&palm, &HandPose::OPEN, &[pre.joints]).unwrap();
        ExecutionRequest {
            palm: PoseJson::from(&palm),
            pregrasp: PoseJson::from(&pregrasp),
            joints_rad: grasp.joints,
            pregrasp_joints_rad: pre.joints,
            spread_rad: 0.3,
            preshape_rad: crate::robot::PreshapeRad::OPEN,
            max_overtravel_m: None,
            task: None,
            method: None,
        }
    }

    struct Rig {
        arm: LockstepArm,
        hand: std::cell::RefCell<Option<Hand<Box<dyn CanBus>>>>,
        clock: Arc<dyn Clock>,
        robot: Arc<Robot>,
        _emulator: EmulatorThread,
    }

    impl Rig {
        fn new(emulator: HandEmulatorConfig) -> Rig {
            Rig::build(emulator, None, HOME)
        }

        /// [`Rig::new`] with the arm starting at `start`.
        fn starting_at(emulator: HandEmulatorConfig, start: ArmJoints) -> Rig {
            Rig::build(emulator, None, start)
        }

        /// Arm and hand in a simulated world of `scene`: the arm simulator reports
        /// its contact force, the hand emulator stalls where the grasp simulator
        /// closes on it.
        fn in_world(scene: &crate::sim::scene::Scene, name: &str) -> Rig {
            Rig::build(HandEmulatorConfig::default(), Some((scene, name)), HOME)
        }

        fn build(
            emulator: HandEmulatorConfig,
            world: Option<(&crate::sim::scene::Scene, &str)>,
            start: ArmJoints,
        ) -> Rig {
            use crate::sim::world::{ArmContact, HandContact, SimWorld, WorldLink, WorldWatch};
            let robot = Arc::new(shipped_robot());
            let link = WorldLink::memory();
            let watch = world.map(|(scene, _)| {
                let hand = crate::robot::hand::HandModel::from_description(
                    &robot.description,
                    "bh_palm",
                    std::path::Path::new("shipped"),
                )
                .unwrap();
                WorldWatch::fixed(Some(SimWorld::new(scene, Arc::new(hand), 2e4).unwrap()))
            });
            let bus = VirtualBus::new(world.map_or("execute-unit", |w| w.1));
            let node = bus.endpoint();
            let probe = node.idle_probe();
            let clock: Arc<dyn Clock> = Arc::new(ManualClock::new().with_settle(move || {
                probe.wait_idle(Duration::from_secs(5));
            }));
            let mut emulator = HandEmulator::new(emulator, Arc::clone(&clock)).unwrap();
            if let Some(watch) = &watch {
                emulator =
                    emulator.with_feel(Box::new(HandContact::new(watch.clone(), link.clone())));
            }
            let emulator = emulator.spawn(node);
            let hand = Hand::new(
                Box::new(bus.endpoint()) as Box<dyn CanBus>,
                Arc::clone(&clock),
                HandTiming::default(),
            );
            let arm = LockstepArm::new(
                SimConfig {
                    initial_joints_rad: start,
                    // The cell's KRL program loops around `friStart`.
                    restart_after_drop: true,
                    ..SimConfig::from_robot(&shipped_robot())
                },
                0.1,
                Arc::clone(&clock),
            );
            if let Some(watch) = watch {
                let contact = ArmContact::new(Arc::clone(&robot), watch, link);
                arm.with_sim(|s| s.set_external_force(Some(Box::new(contact))));
            }
            Rig {
                arm,
                hand: std::cell::RefCell::new(Some(hand)),
                clock,
                robot,
                _emulator: emulator,
            }
        }

        fn grasping() -> Rig {
            Rig::new(HandEmulatorConfig {
                contact_rad: [
                    Some(CONTACT_RAD[0]),
                    Some(CONTACT_RAD[1]),
                    Some(CONTACT_RAD[2]),
                    None,
                ],
                ..HandEmulatorConfig::default()
            })
        }

        fn executor<A: Arm>(&self, arm: A) -> Executor<A, Box<dyn CanBus>> {
            self.executor_with(arm, |_| {})
        }

        /// An executor with the cell's settings changed by `adjust`.
        fn executor_with<A: Arm>(
            &self,
            arm: A,
            adjust: impl FnOnce(&mut ExecutorConfig),
        ) -> Executor<A, Box<dyn CanBus>> {
            let cell = cell();
            let mut config = ExecutorConfig::from_cell(&cell);
            adjust(&mut config);
            Executor::new(
                arm,
                self.hand.borrow_mut().take().unwrap(),
                Arc::clone(&self.robot),
                SafetyLimits::from_cell(&cell, &self.robot),
                config,
                Arc::clone(&self.clock),
            )
        }

        fn sim_joints(&self) -> ArmJoints {
            self.arm.with_sim(|s| s.joints_rad())
        }

        /// Asserts that the simulated arm is within `tolerance_rad` of `joints`.
        fn assert_arm_at(&self, joints: &ArmJoints, tolerance_rad: f64) {
            let q = self.sim_joints();
            assert!(
                (0..7).all(|j| (q[j] - joints[j]).abs() < tolerance_rad),
                "arm at {q:?}, expected {joints:?}"
            );
        }
    }

    fn phases(report: &ExecutionReport) -> Vec<Phase> {
        report.phases.iter().map(|p| p.phase).collect()
    }

    #[test]
    fn completes_a_grasp_lifts_and_holds() {
        let rig = Rig::grasping();
        let robot = Arc::clone(&rig.robot);
        let req = request(&robot);
        let mut seen = Vec::new();
        let report = {
            let mut ex = rig.executor(&rig.arm);
            ex.execute_observed(&req, &mut |p| seen.push(p))
        };
        assert_eq!(report.outcome, Outcome::Success, "{}", report.human());
        let all = vec![
            Phase::ArmReady,
            Phase::Validate,
            Phase::HandBringup,
            Phase::Preshape,
            Phase::Pregrasp,
            Phase::Approach,
            Phase::Close,
            Phase::Lift,
            Phase::Hold,
        ];
        assert_eq!(phases(&report), all);
        assert_eq!(seen, all);
        assert!(report.phases.iter().all(|p| p.ok));
        let hold = report.phases.last().unwrap();
        assert!(hold.duration_s >= 2.0, "{hold:?}");
        // Nothing in the arm's world: the approach went the whole overtravel
        // (0.05 m past the grasp at z = 0.20), and the simulated robot (not the
        // driver's view) ends 0.10 m above that.
        let stop = report.approach_stop.as_ref().unwrap();
        assert!(
            !stop.contact && (stop.beyond_plan_m - 0.05).abs() < 1e-3,
            "{stop:?}"
        );
        let q = rig.sim_joints();
        let palm = robot.arm().palm(&q).translation.vector;
        assert!((palm.x - 0.6).abs() < 1e-3, "{palm:?}");
        assert!(palm.y.abs() < 1e-3, "{palm:?}");
        assert!((palm.z - 0.25).abs() < 1e-3, "{palm:?}");
        assert_eq!(rig.arm.with_sim(|s| s.drop_reason()), None);
        // Fingers stopped on the object, with strain; the spread as planned.
        assert_eq!(report.fingers_in_contact, Puck::FINGERS.to_vec());
        let hand = report.hand_positions.unwrap();
        for (got, want) in hand.fingers_rad.iter().zip(CONTACT_RAD) {
            assert!((got - want).abs() < 1e-3, "{hand:?}");
        }
        assert!((hand.spread_rad - 0.3).abs() < 1e-3, "{hand:?}");
        let rise: Vec<i32> = (0..3)
            .map(|i| report.strain.unwrap()[i] - report.strain_baseline.unwrap()[i])
            .collect();
        assert_eq!(rise, [900; 3]);
        // Approach and lift kept the palm speed limit.
        for m in [&report.approach, &report.lift] {
            let m = m.as_ref().unwrap();
            assert!(m.peak_palm_speed_m_s <= 0.2 + 1e-9, "{m:?}");
            assert!(m.method.is_some());
        }
        let json = serde_json::to_value(&report).unwrap();
        assert_eq!(json["outcome"], "success");
        assert_eq!(json["phases"].as_array().unwrap().len(), 9);
    }

    /// Runs a grasp whose answers the driver withholds from the start of phase
    /// `from` to the start of phase `until` (never resumed if `None`).
    fn grasp_with_answers_withheld(
        rig: &Rig,
        ex: &mut Executor<&LockstepArm, Box<dyn CanBus>>,
        from: Phase,
        until: Option<Phase>,
    ) -> ExecutionReport {
        let req = request(&rig.robot);
        let arm = &rig.arm;
        ex.execute_observed(&req, &mut |p| {
            if p == from {
                arm.set_withhold_answers(true);
            } else if Some(p) == until {
                arm.set_withhold_answers(false);
            }
        })
    }

    /// Asserts that the grasp failed on a drop to monitor found in `phase`.
    fn assert_dropped_in(report: &ExecutionReport, phase: Phase) {
        let err = report.error.as_ref().expect("an error");
        assert!(
            matches!(err, ExecuteError::ArmDroppedToMonitor { phase: p, .. } if *p == phase),
            "{err}"
        );
        assert_eq!(report.failed_phase, Some(phase));
    }

    #[test]
    fn a_drop_to_monitor_before_the_arm_moves_is_rejoined_and_the_grasp_goes_on() {
        let rig = Rig::grasping();
        let mut ex = rig.executor(&rig.arm);
        let report =
            grasp_with_answers_withheld(&rig, &mut ex, Phase::HandBringup, Some(Phase::Preshape));
        assert_eq!(report.outcome, Outcome::Success, "{:?}", report.error);
        // The robot did drop (the KRL program's loop brought it back) ...
        assert!(matches!(
            rig.arm.with_sim(|s| s.drop_reason()),
            Some(DropReason::LinkQuality { .. })
        ));
        // ... and the report says so.
        let rejoin = report.rejoin.as_ref().expect("a rejoin");
        assert_eq!(rejoin.lost_in, Phase::HandBringup);
        assert!(rejoin.link.contains("monitor"), "{rejoin:?}");
        assert!(rejoin.waited_s < 5.0, "{rejoin:?}");
        assert!(rejoin.drift_rad < 1e-9, "{rejoin:?}");
        assert!(report.human().contains("rejoined command mode"));
    }

    #[test]
    fn a_drop_to_monitor_before_the_arm_moves_fails_when_the_robot_does_not_return() {
        let rig = Rig::grasping();
        let mut ex = rig.executor(&rig.arm);
        let began = rig.clock.now();
        let report = grasp_with_answers_withheld(&rig, &mut ex, Phase::Preshape, None);
        assert_dropped_in(&report, Phase::Preshape);
        // It waited for the robot for the rejoin timeout, no longer.
        let waited_s = secs(rig.clock.now().saturating_sub(began));
        assert!((5.0..10.0).contains(&waited_s), "{waited_s} s");
        // The arm never moved, and nothing is released after a link fault.
        rig.assert_arm_at(&HOME, 1e-6);
        assert!(ex.release_and_park(&HOME).unwrap().is_none());
        rig.assert_arm_at(&HOME, 1e-6);
    }

    #[test]
    fn without_a_rejoin_timeout_a_drop_before_the_arm_moves_fails_the_grasp() {
        let rig = Rig::grasping();
        let mut ex = rig.executor_with(&rig.arm, |c| c.rejoin_timeout_s = 0.0);
        let report =
            grasp_with_answers_withheld(&rig, &mut ex, Phase::HandBringup, Some(Phase::Preshape));
        assert_dropped_in(&report, Phase::HandBringup);
        assert!(report.rejoin.is_none());
        rig.assert_arm_at(&HOME, 1e-6);
    }

    #[test]
    fn withheld_answers_drop_the_robot_to_monitor_and_the_arm_holds() {
        let rig = Rig::grasping();
        let req = request(&rig.robot);
        let arm = &rig.arm;
        let mut ex = rig.executor(arm);
        let report = ex.execute_observed(&req, &mut |p| {
            if p == Phase::Approach {
                arm.set_withhold_answers(true);
            }
        });
        let err = report.error.as_ref().unwrap();
        assert!(
            matches!(
                err,
                ExecuteError::ArmDroppedToMonitor {
                    phase: Phase::Approach,
                    state: FriState::Monitor,
                    quality: Quality::Unacceptable,
                }
            ),
            "{err}"
        );
        assert_eq!(report.error_kind, Some("arm_dropped_to_monitor"));
        assert!(matches!(
            arm.with_sim(|s| s.drop_reason()),
            Some(DropReason::LinkQuality { .. })
        ));
        // The arm stopped between pre-grasp and grasp, and stays there.
        let stopped = arm.with_sim(|s| s.joints_rad());
        let z = rig.robot.arm().palm(&stopped).translation.z;
        assert!(z > 0.20 + 1e-3 && z <= 0.30 + 1e-6, "palm at z = {z}");
        rig.clock.sleep(Duration::from_secs(1));
        assert_eq!(arm.with_sim(|s| s.joints_rad()), stopped);
        let stop = report.stop.as_ref().unwrap();
        assert!(stop.arm.contains("KRC holds"), "{stop:?}");
        assert!(stop.hand.starts_with("holding"), "{stop:?}");
        // After a device fault nothing is released: that is the operator's call.
        assert!(ex.release_and_park(&HOME).unwrap().is_none());
        assert_eq!(arm.with_sim(|s| s.joints_rad()), stopped);
    }

    #[test]
    fn a_silent_robot_is_a_late_measurement() {
        let rig = Rig::grasping();
        let req = request(&rig.robot);
        let arm = &rig.arm;
        let mut ex = rig.executor(arm);
        let report = ex.execute_observed(&req, &mut |p| {
            if p == Phase::Hold {
                arm.set_silent(true);
            }
        });
        let err = report.error.as_ref().unwrap();
        assert!(
            matches!(
                err,
                ExecuteError::ArmMeasurementLate {
                    phase: Phase::Hold,
                    ..
                }
            ),
            "{err}"
        );
        assert!(report
            .stop
            .as_ref()
            .unwrap()
            .arm
            .contains("no measurements"));
    }

    #[test]
    fn a_missing_puck_fails_bring_up_naming_it_before_the_arm_moves() {
        let rig = Rig::new(HandEmulatorConfig {
            present: [true, false, true, true],
            ..HandEmulatorConfig::default()
        });
        let req = request(&rig.robot);
        let report = rig.executor(&rig.arm).execute(&req);
        let err = report.error.as_ref().unwrap();
        assert!(
            matches!(
                err,
                ExecuteError::Hand {
                    phase: Phase::HandBringup,
                    source: HandError::NoReply { puck: Puck::F2, .. }
                }
            ),
            "{err}"
        );
        assert!(err.to_string().contains("F2 (node 12)"), "{err}");
        assert_eq!(report.error_kind, Some("hand_no_reply"));
        assert!(report.stop.as_ref().unwrap().hand.contains("F2"));
        rig.assert_arm_at(&HOME, 1e-6);
    }

    #[test]
    fn no_object_means_no_contact_and_the_arm_holds_at_the_grasp() {
        let rig = Rig::new(HandEmulatorConfig::default());
        let req = request(&rig.robot);
        let report = rig.executor(&rig.arm).execute(&req);
        let err = report.error.as_ref().unwrap();
        assert!(
            matches!(
                err,
                ExecuteError::NoContact {
                    in_contact: 0,
                    required: 2,
                    stalled: [false, false, false],
                    ..
                }
            ),
            "{err}"
        );
        // It holds where the approach ended: the whole overtravel past the grasp.
        let palm = rig.robot.arm().palm(&rig.sim_joints()).translation.vector;
        assert!((palm.z - 0.15).abs() < 1e-3, "{palm:?}");
    }

    #[test]
    fn an_unsafe_plan_is_refused_before_anything_moves() {
        let rig = Rig::grasping();
        let mut req = request(&rig.robot);
        req.pregrasp_joints_rad[5] = -2.2;
        req.pregrasp = PoseJson::from(&rig.robot.arm().palm(&req.pregrasp_joints_rad));
        let mut ex = rig.executor(&rig.arm);
        let report = ex.execute(&req);
        assert_eq!(phases(&report), [Phase::ArmReady, Phase::Validate]);
        let err = report.error.as_ref().unwrap();
        assert!(
            matches!(
                err,
                ExecuteError::Unsafe {
                    phase: Phase::Validate,
                    motion: "pregrasp move",
                    ..
                }
            ),
            "{err}"
        );
        let Some(SafetyError::OutOfLimit {
            joint,
            position_rad,
            limit_rad,
            ..
        }) = err.safety_violation()
        else {
            panic!("{err}");
        };
        assert_eq!(joint, "lbr_a5");
        assert_eq!(*position_rad, -2.2);
        assert!((limit_rad + 2.084395).abs() < 1e-12);
        // Nothing to release: nothing moves after the refusal either.
        assert!(ex.release_and_park(&HOME).unwrap().is_none());
        drop(ex);
        rig.assert_arm_at(&HOME, 1e-6);
        let emulator = rig._emulator.stop().unwrap().0;
        assert_eq!(emulator.stats().received, 0, "the hand was never addressed");
    }

    /// After a grasp that held: the object goes down just above where the lift
    /// began, the hand opens to its approach shape, the palm backs out to the
    /// pre-grasp and the arm parks; once parked, there is nothing left to release.
    #[test]
    fn a_held_object_is_put_down_released_and_the_arm_parks() {
        let rig = Rig::grasping();
        let req = request(&rig.robot);
        let mut ex = rig.executor(&rig.arm);
        let report = ex.execute(&req);
        assert_eq!(report.outcome, Outcome::Success, "{}", report.human());
        let park = ex.release_and_park(&HOME).unwrap().unwrap();
        assert!(park.put_down.is_some() && park.retreat.is_some() && park.park.is_some());
        assert!(park.total_s > 0.0, "{park:?}");
        let hand = ex.hand().positions(Duration::from_secs(1)).unwrap();
        for finger_rad in hand.fingers_rad {
            assert!(finger_rad.abs() < 1e-3, "opened: {hand:?}");
        }
        assert!(ex.release_and_park(&HOME).unwrap().is_none());
        drop(ex);
        rig.assert_arm_at(&HOME, 1e-3);
    }

    /// After a grasp on the far branch of the shoulder (the first joint half a turn
    /// from the park's), whose joint line to the park leaves the workspace, the arm
    /// parks by a detour.
    #[test]
    fn a_grasp_on_the_far_branch_of_the_shoulder_parks_by_a_detour() {
        let robot = shipped_robot();
        // Near a side grasp a campaign executed there (the arm leaning less, so
        // the fingers clear the table): the pre-grasp, and the grasp 10 cm ahead.
        let mut pre = [-2.7647, 1.2439, -0.2989, -1.7398, -2.9008, 1.1982, -2.8456];
        pre[1] -= 0.3;
        let pregrasp = robot.arm().palm(&pre);
        let palm = advanced(&pregrasp, 0.10);
        let grasp = robot.reach(&palm, &HandPose::OPEN, &[pre]).unwrap().joints;
        assert!(grasp[0] < -2.0, "the far branch: {grasp:?}");
        let rig = Rig::starting_at(HandEmulatorConfig::default(), pre);
        let req = ExecutionRequest {
            palm: PoseJson::from(&palm),
            pregrasp: PoseJson::from(&pregrasp),
            joints_rad: grasp,
            pregrasp_joints_rad: pre,
            ..request(&rig.robot)
        };
        let mut ex = rig.executor(&rig.arm);
        let report = ex.execute(&req);
        assert_eq!(report.error_kind, Some("no_contact"), "{}", report.human());
        // The straight move from the pre-grasp to the park is refused ...
        let check = ex.safe_arm().safety();
        let direct = crate::execute::motions::checked_motion(
            check,
            0.2,
            Phase::Park,
            "park",
            &[pre, HOME],
            None,
            &HandPose::OPEN,
        );
        assert!(direct.is_err());
        // ... and the arm parks all the same, through waypoints.
        let park = ex.release_and_park(&HOME).unwrap().unwrap();
        assert!(park.park.as_ref().unwrap().waypoints > 2, "{park:?}");
        drop(ex);
        rig.assert_arm_at(&HOME, 1e-3);
    }

    /// A grasp that closed on air is released and parked like one that held.
    #[test]
    fn a_grasp_without_contact_is_released_and_parked() {
        let rig = Rig::new(HandEmulatorConfig::default());
        let req = request(&rig.robot);
        let mut ex = rig.executor(&rig.arm);
        let report = ex.execute(&req);
        assert_eq!(report.error_kind, Some("no_contact"));
        let park = ex.release_and_park(&HOME).unwrap().unwrap();
        assert!(park.put_down.is_none(), "never lifted: {park:?}");
        assert!(park.retreat.is_some() && park.park.is_some());
        drop(ex);
        rig.assert_arm_at(&HOME, 1e-3);
    }

    #[test]
    fn a_plan_with_nan_or_infinity_is_refused_before_anything_moves() {
        // Issue 21 item 4: a plan (the executor's request, also the plan file).
        let good = request(&Rig::grasping().robot);
        let mut cases = Vec::new();
        let mut r = good.clone();
        r.joints_rad[1] = f64::NAN;
        cases.push((r, "joints_rad"));
        let mut r = good.clone();
        r.pregrasp_joints_rad[6] = f64::INFINITY;
        cases.push((r, "pregrasp_joints_rad"));
        let mut r = good.clone();
        r.palm.xyz[2] = f64::NAN;
        cases.push((r, "palm"));
        let mut r = good.clone();
        r.spread_rad = f64::NEG_INFINITY;
        cases.push((r, "spread_rad"));
        for (req, field) in cases {
            let rig = Rig::grasping();
            let report = rig.executor(&rig.arm).execute(&req);
            let err = report.error.as_ref().expect("refused");
            assert_eq!(err.kind(), "bad_request", "{field}: {err}");
            assert!(err.to_string().contains(field), "{field}: {err}");
            assert_ne!(report.outcome, Outcome::Success);
            rig.assert_arm_at(&HOME, 1e-6);
            let emulator = rig._emulator.stop().unwrap().0;
            assert_eq!(emulator.stats().received, 0, "the hand was never addressed");
        }
    }

    #[test]
    fn joints_that_miss_the_pose_are_a_plan_mismatch() {
        let rig = Rig::grasping();
        let mut req = request(&rig.robot);
        req.palm.xyz[1] += 0.05;
        let report = rig.executor(&rig.arm).execute(&req);
        let err = report.error.as_ref().unwrap();
        assert!(
            matches!(err, ExecuteError::PlanMismatch { which: "grasp", pos_err_m, .. } if (pos_err_m - 0.05).abs() < 1e-3),
            "{err}"
        );
    }

    /// How far the open hand (spread 0.3) reaches ahead of the palm along its
    /// approach axis: the largest palm-frame z of its link boxes.
    fn reach_ahead(robot: &Robot) -> f64 {
        let hand = crate::robot::hand::HandModel::from_description(
            &robot.description,
            "bh_palm",
            std::path::Path::new("shipped"),
        )
        .unwrap();
        let open = HandPose {
            spread_rad: 0.3,
            flex_rad: [0.0; 3],
        };
        hand.link_poses(&open)
            .iter()
            .flat_map(|(link, pose)| {
                link.shapes
                    .iter()
                    .map(move |(local, shape)| shape.compute_aabb(&(pose * local)).maxs.z)
            })
            .fold(f64::MIN, f64::max)
    }

    #[test]
    fn the_guarded_approach_stops_at_first_contact_with_a_box_through_the_fri_driver() {
        // A wide block under the top-down grasp at z = 0.20 whose top is 30 mm
        // beyond the open fingertips' reach at the planned pose: the approach
        // (pre-grasp at 0.30) must stop about 30 mm past the plan, on the arm
        // simulator's contact force, through the real FRI driver core.
        let robot = shipped_robot();
        let top = 0.20 - reach_ahead(&robot) - 0.030;
        let mut scene = crate::sim::scene::Scene::new(None);
        scene
            .add(
                "block",
                crate::quality::autograsp::tests::cuboid([0.0, 0.0, -0.05], [0.3, 0.3, 0.1]),
                Pose::translation(0.6, 0.0, top),
            )
            .unwrap();
        let rig = Rig::in_world(&scene, "execute-block");
        let req = request(&rig.robot);
        let report = rig.executor(&rig.arm).execute(&req);
        let stop = report
            .approach_stop
            .as_ref()
            .unwrap_or_else(|| panic!("{}", report.human()));
        assert!(stop.contact, "{stop:?}");
        assert!(stop.contact_force_n.unwrap() > 10.0, "{stop:?}");
        // First contact at 30 mm; the force reaches 10 N within 0.5 mm of
        // penetration and the arm brakes from 0.05 m/s within about 1 mm.
        assert!(
            stop.beyond_plan_m > 0.030 && stop.beyond_plan_m < 0.033,
            "stopped {} m beyond the plan",
            stop.beyond_plan_m
        );
        // The fingertips stood on the flat face: closing jams them there at
        // once (in contact, with strain), but the grasp is not force closure,
        // so the block stays behind when the arm lifts: the grasp is lost.
        assert_eq!(
            report.fingers_in_contact,
            Puck::FINGERS.to_vec(),
            "{}",
            report.human()
        );
        let err = report.error.as_ref().expect("no grasp on a flat face");
        assert!(
            matches!(err, ExecuteError::GraspLost { strain_rise: 0, .. }),
            "{}",
            report.human()
        );
        // The simulated robot itself lifted 0.10 m from where the approach stopped.
        let palm = rig.robot.arm().palm(&rig.sim_joints()).translation.vector;
        assert!(
            (palm.z - (0.30 - stop.beyond_plan_m)).abs() < 1e-3,
            "{palm:?}"
        );
    }

    #[test]
    fn closing_beside_a_thin_plate_touches_with_one_finger_only_and_is_no_contact() {
        // A thin vertical plate beside the palm axis of a top-down hand: the
        // approach stops on it, one finger closes on it, the others on air.
        let robot = shipped_robot();
        let mut scene = crate::sim::scene::Scene::new(None);
        scene
            .add(
                "plate",
                crate::quality::autograsp::tests::cuboid([0.0, 0.0, 0.0], [0.006, 0.2, 0.1]),
                Pose::translation(0.6 + 0.03, 0.0, 0.20 - reach_ahead(&robot) + 0.02),
            )
            .unwrap();
        let rig = Rig::in_world(&scene, "execute-plate");
        let req = request(&rig.robot);
        let report = rig.executor(&rig.arm).execute(&req);
        assert!(
            report.approach_stop.as_ref().unwrap().contact,
            "{}",
            report.human()
        );
        let err = report.error.as_ref().expect("the plate is not grasped");
        assert!(
            matches!(
                err,
                ExecuteError::NoContact {
                    in_contact: 1,
                    required: 2,
                    ..
                }
            ),
            "{}",
            report.human()
        );
    }

    /// An arm whose motions never end.
    struct Stuck<'a>(&'a LockstepArm);

    impl Arm for Stuck<'_> {
        fn status(&self) -> FriStatus {
            self.0.status()
        }
        fn start_trajectory(&self, t: Trajectory<JOINTS>) -> Result<u64, FriError> {
            self.0.start_trajectory(t)
        }
        fn start_guarded_trajectory(
            &self,
            t: Trajectory<JOINTS>,
            guard: crate::hw::fri::ForceGuard,
        ) -> Result<u64, FriError> {
            self.0.start_guarded_trajectory(t, guard)
        }
        fn motion_outcome(&self, _id: u64) -> Option<Result<(), FriError>> {
            None
        }
        fn stop(&self) {
            self.0.stop()
        }
    }

    #[test]
    fn the_watchdog_stops_a_motion_past_its_deadline() {
        let rig = Rig::grasping();
        let req = request(&rig.robot);
        let arm = &rig.arm;
        let mut ex = rig.executor(Stuck(arm));
        let report = ex.execute(&req);
        let pregrasp = report.pregrasp_move.as_ref().unwrap();
        let err = report.error.as_ref().unwrap();
        let ExecuteError::PhaseTimeout {
            phase: Phase::Pregrasp,
            elapsed_s,
            deadline_s,
        } = err
        else {
            panic!("{err}");
        };
        assert!((deadline_s - (pregrasp.duration_s * 1.5 + 2.0)).abs() < 1e-9);
        assert!(elapsed_s > deadline_s);
        assert!(report.stop.as_ref().unwrap().arm.starts_with("holding"));
        // The motion itself had ended: the arm is at the pre-grasp joints, holding.
        let q = arm.with_sim(|s| s.joints_rad());
        let want = req.pregrasp_joints_rad;
        assert!((0..7).all(|j| (q[j] - want[j]).abs() < 1e-5), "{q:?}");
    }

    /// Issue 21 item 5: the safety layer as a property, checked on what the
    /// simulated robot received (its datagram-level record of commands), not on the
    /// executor's own bookkeeping.
    mod safety_property {
        use super::*;
        use proptest::prelude::*;

        /// Any number, NaN and the infinities included.
        fn garbage() -> impl Strategy<Value = f64> {
            prop_oneof![
                4 => -4.0..4.0f64,
                1 => -1e9..1e9f64,
                1 => Just(f64::NAN),
                1 => Just(f64::INFINITY),
                1 => Just(f64::NEG_INFINITY),
            ]
        }

        /// A plan: numbers anywhere (kind 0); a palm pose somewhere around the
        /// table, pre-grasp backed off along its approach, joints by IK without any
        /// check (kind 1); or joints up to 1 rad from home with their own poses
        /// (kind 2).
        fn plan() -> impl Strategy<Value = (u8, [f64; 6], [f64; 7], [f64; 7], f64)> {
            (
                prop_oneof![Just(0u8), Just(1u8), Just(2u8), Just(2u8)],
                (
                    0.1..1.1f64,
                    -0.7..0.7f64,
                    -0.1..0.6f64,
                    PI - 0.8..PI + 0.8,
                    -0.8..0.8f64,
                    -PI..PI,
                )
                    .prop_map(|(x, y, z, r, p, w)| [x, y, z, r, p, w]),
                proptest::array::uniform7(garbage()),
                proptest::array::uniform7(-2.5..2.5f64),
                garbage(),
            )
        }

        fn request_of(
            robot: &Robot,
            (kind, palm, numbers, joints, spread): (u8, [f64; 6], [f64; 7], [f64; 7], f64),
        ) -> ExecutionRequest {
            let back = Pose::from_parts(
                nalgebra::Translation3::new(0.0, 0.0, -robot_offset()),
                nalgebra::UnitQuaternion::identity(),
            );
            match kind {
                0 => ExecutionRequest {
                    palm: PoseJson {
                        xyz: [numbers[0], numbers[1], numbers[2]],
                        rpy: Some([numbers[3], numbers[4], numbers[5]]),
                        quat_xyzw: None,
                    },
                    pregrasp: PoseJson {
                        xyz: [numbers[6], numbers[0], numbers[1]],
                        rpy: Some([numbers[2], numbers[3], numbers[4]]),
                        quat_xyzw: None,
                    },
                    joints_rad: numbers,
                    pregrasp_joints_rad: joints,
                    spread_rad: spread,
                    preshape_rad: crate::robot::PreshapeRad::OPEN,
                    max_overtravel_m: None,
                    task: None,
                    method: None,
                },
                1 => {
                    let palm = pose_from_params(&palm);
                    let pregrasp = palm * back;
                    let solve = |pose: &Pose, seed: &ArmJoints| match robot.ik.solve(pose, &[*seed])
                    {
                        Ok(s) | Err(s) => s.joints,
                    };
                    let pre = solve(&pregrasp, &HOME);
                    ExecutionRequest {
                        palm: PoseJson::from(&palm),
                        pregrasp: PoseJson::from(&pregrasp),
                        joints_rad: solve(&palm, &pre),
                        pregrasp_joints_rad: pre,
                        spread_rad: spread.clamp(0.0, PI),
                        preshape_rad: crate::robot::PreshapeRad::OPEN,
                        max_overtravel_m: None,
                        task: None,
                        method: None,
                    }
                }
                _ => {
                    // Mostly around the home pose, some joints beyond their limits.
                    let pre: ArmJoints = std::array::from_fn(|j| HOME[j] + 0.4 * joints[j]);
                    let grasp: ArmJoints = std::array::from_fn(|j| {
                        let step = if numbers[j].is_finite() {
                            numbers[j].clamp(-1.0, 1.0)
                        } else {
                            0.0
                        };
                        pre[j] + 0.1 * step
                    });
                    ExecutionRequest {
                        palm: PoseJson::from(&robot.arm().palm(&grasp)),
                        pregrasp: PoseJson::from(&robot.arm().palm(&pre)),
                        joints_rad: grasp,
                        pregrasp_joints_rad: pre,
                        spread_rad: 0.3,
                        preshape_rad: crate::robot::PreshapeRad::OPEN,
                        max_overtravel_m: None,
                        task: None,
                        method: None,
                    }
                }
            }
        }

        fn robot_offset() -> f64 {
            cell().robot.pregrasp_offset_m
        }

        proptest! {
            #![proptest_config(ProptestConfig { cases: 48, failure_persistence: None, ..ProptestConfig::default() })]

            #[test]
            fn every_command_the_robot_receives_is_within_the_limits(p in plan()) {
                let rig = Rig::grasping();
                let cell = cell();
                let req = request_of(&rig.robot, p);
                rig.arm.with_sim(|s| s.record_commands(true));
                let report = rig.executor(&rig.arm).execute(&req);
                let (commands, dt_s) = rig.arm.with_sim(|s| (s.take_commands(), s.config().cycle_s));
                prop_assert!(!commands.is_empty(), "the robot was answered");
                let verdict = crate::sim::audit::CommandAudit::new(&rig.robot, &cell, dt_s)
                    .check_all(&commands);
                prop_assert!(verdict.is_none(), "{}; {}", verdict.unwrap_or_default(), report.human());
            }
        }
    }

    #[test]
    fn a_pregrasp_move_refused_in_joint_space_goes_along_the_palm_line() {
        let rig = Rig::grasping();
        let robot = Arc::clone(&rig.robot);
        // A side grasp low over the table, the palm facing +y: the joint-space
        // swing from home drags the fingers through the table.
        let pregrasp = pose_from_params(&[0.5, 0.0, 0.09, 0.0, PI / 2.0, PI / 2.0]);
        let palm = pregrasp * Pose::translation(0.0, 0.0, 0.1);
        let req = request_between(&robot, &pregrasp, &palm);
        let mut ex = rig.executor(&rig.arm);
        let direct = super::super::motions::checked_motion(
            ex.arm.safety(),
            ex.config.palm_speed_m_s,
            Phase::Validate,
            "pregrasp move",
            &[HOME, req.pregrasp_joints_rad],
            None,
            &crate::robot::PreshapeRad::OPEN.at_spread(0.3),
        );
        assert!(
            matches!(&direct, Err(ExecuteError::Unsafe { .. })),
            "{direct:?}"
        );
        let report = ex.execute(&req);
        assert_eq!(report.outcome, Outcome::Success, "{}", report.human());
        let pregrasp_move = report.pregrasp_move.as_ref().unwrap();
        assert_eq!(
            pregrasp_move.method,
            Some(PathMethod::CartesianWaypoints),
            "{pregrasp_move:?}"
        );
        assert!(pregrasp_move.waypoints > 2, "{pregrasp_move:?}");
    }
}
