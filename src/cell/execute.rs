//! `cell-execute`: carries out each planned grasp with the executor
//! ([`crate::execute::Executor`]: safety layer, watchdog) on the FRI arm and the
//! CAN hand, and publishes its phases and the measured joints.
//!
//! Backends come from the configuration only: `fri.backend` is `sim` (the FRI
//! robot simulator `cell-sim-arm` answers at the configured address) or `hardware`
//! (the KRC), and `can.interface` a `virtual:NAME` bus with the puck emulator
//! `cell-sim-hand`, or a SocketCAN interface with the real hand. This process is the
//! same for both.
//!
//! Status: `MovingToPregrasp` when the grasp's first command goes out (pre-shaping
//! the hand after every motion was validated), then `Approaching`, `Closing`,
//! `Lifting`, `Holding`, and finally `Done` or `Stopped` with an error code
//! ([`error_code`]). A plan marked failed is answered with `Stopped` at once and
//! nothing moves. Between trials, and whenever a peer dies, the arm holds where it
//! is (the FRI driver keeps commanding its last position) and the hand keeps its
//! grip: nothing is released without a new plan.

use super::notify::{self, Watchdog};
use super::{stop_requested, CellError, TICK};
use crate::clock::{Clock, SystemClock};
use crate::config::CellConfig;
use crate::execute::{ExecutionRequest, Executor, ExecutorConfig, Outcome, Phase, SafetyLimits};
use crate::geometry::PoseJson;
use crate::hw::can::open_bus;
use crate::hw::fri::{DriverConfig, FriDriver};
use crate::hw::hand::{Hand, HandTiming};
use crate::ipc::{
    monotonic_now_ns, Domain, ExecutionStatus, FailureCause, GraspPlan, JointState, JointStates,
    Phase as IpcPhase, Stage, TrialRequest,
};
use crate::robot::Robot;
use std::sync::Arc;

/// Error codes of [`ExecutionStatus::error_code`]: the index of the kind here
/// (`ExecuteError::kind` names, plus the cell's own).
pub const ERROR_KINDS: [&str; 22] = [
    "none",
    "plan_failed",
    "bad_request",
    "plan_mismatch",
    "unsafe_motion",
    "no_straight_path",
    "bad_trajectory",
    "arm_not_ready",
    "arm_dropped_to_monitor",
    "arm_measurement_late",
    "arm_error",
    "phase_timeout",
    "hand_bus",
    "hand_no_reply",
    "hand_garbled_frame",
    "hand_unexpected_frame",
    "hand_timeout",
    "hand_command_ignored",
    "hand_set_not_applied",
    "hand_error",
    "no_contact",
    "grasp_lost",
];

/// The status code of an error kind (unknown kinds are `hand_error`'s neighbour
/// "other": the last code plus one).
pub fn error_code(kind: &str) -> u32 {
    ERROR_KINDS
        .iter()
        .position(|k| *k == kind)
        .unwrap_or(ERROR_KINDS.len()) as u32
}

/// The error kind of a status code (`"other"` for codes this build does not know).
pub fn error_kind(code: u32) -> &'static str {
    ERROR_KINDS.get(code as usize).copied().unwrap_or("other")
}

/// The status phase of an executor phase (`None`: not reported).
fn status_phase(phase: Phase) -> Option<IpcPhase> {
    match phase {
        Phase::ArmReady | Phase::Validate | Phase::HandBringup => None,
        Phase::Preshape | Phase::Pregrasp => Some(IpcPhase::MovingToPregrasp),
        Phase::Approach => Some(IpcPhase::Approaching),
        Phase::Close => Some(IpcPhase::Closing),
        Phase::Lift => Some(IpcPhase::Lifting),
        Phase::Hold => Some(IpcPhase::Holding),
        Phase::Park => None,
    }
}

/// The executor's request for a received plan, checked at the boundary
/// ([`ExecutionRequest::validate`]: finite numbers, rigid poses, the spread in
/// range), so a NaN or infinity in any field is refused before anything moves.
pub fn execution_request(plan: &GraspPlan) -> Result<ExecutionRequest, CellError> {
    let request = ExecutionRequest {
        palm: PoseJson::from(&plan.base_from_palm.to_pose("grasp plan palm")?),
        pregrasp: PoseJson::from(
            &plan
                .base_from_pregrasp_palm
                .to_pose("grasp plan pregrasp")?,
        ),
        joints_rad: plan.joints_rad,
        pregrasp_joints_rad: plan.pregrasp_joints_rad,
        spread_rad: plan.spread_rad,
        preshape_rad: crate::robot::PreshapeRad(plan.preshape_rad),
        max_overtravel_m: plan.overtravel()?,
        task: None,
        method: Some(plan.method()?.to_string()),
    };
    request
        .validate()
        .map_err(|e| CellError::Invalid(format!("grasp plan of trial {}: {e}", plan.trial_id)))?;
    Ok(request)
}

/// Options of the execute stage besides the configuration.
#[derive(Debug, Clone)]
pub struct ExecuteOptions {
    /// Local UDP address of the FRI driver (overrides `fri.bind_addr`).
    pub fri_bind: Option<String>,
    /// The robot controller the FRI driver answers (overrides `fri.robot_addr`).
    pub fri_robot: Option<String>,
    /// CAN interface (overrides `can.interface`).
    pub can_interface: Option<String>,
    /// How long the lifted object is held (s).
    pub hold_s: f64,
}

/// Runs the execute stage until SIGTERM/SIGINT.
pub fn run(
    config: &CellConfig,
    domain: &Domain,
    options: &ExecuteOptions,
) -> Result<(), CellError> {
    match config.fri.backend.as_str() {
        "sim" | "hardware" => {}
        other => {
            return Err(CellError::Backend {
                field: "fri.backend",
                value: other.to_string(),
                expected: "sim or hardware",
            })
        }
    }
    // Before any device thread starts (they inherit it): the control thread must not
    // be preempted by ordinary work while it holds the FRI driver's lock.
    crate::hw::realtime::request_priority("executor", crate::hw::realtime::CONTROL_PRIORITY);
    let robot = Arc::new(Robot::load(config)?);
    let clock: Arc<dyn Clock> = Arc::new(SystemClock::new());
    let mut fri = config.fri.clone();
    if let Some(bind) = &options.fri_bind {
        fri.bind_addr = bind.clone();
    }
    if let Some(robot) = &options.fri_robot {
        fri.robot_addr = robot.clone();
    }
    let device = |device: &'static str| {
        move |e: &dyn std::fmt::Display| CellError::Device {
            device,
            detail: e.to_string(),
        }
    };
    let driver_config = DriverConfig::from_cell(&fri).map_err(|e| device("arm")(&e))?;
    let driver =
        FriDriver::start(driver_config, Arc::clone(&clock)).map_err(|e| device("arm")(&e))?;
    let interface = options
        .can_interface
        .clone()
        .unwrap_or_else(|| config.can.interface.clone());
    let bus = open_bus(&interface).map_err(|e| device("hand")(&e))?;
    let hand = Hand::new(
        bus,
        Arc::clone(&clock),
        HandTiming::from_config(&config.can),
    );
    let limits = SafetyLimits::from_cell(config, &robot);
    let executor_config = ExecutorConfig {
        hold_s: options.hold_s,
        ..ExecutorConfig::from_cell(config)
    };
    let mut executor = Executor::new(
        &driver,
        hand,
        Arc::clone(&robot),
        limits,
        executor_config,
        clock,
    );

    let stage = Stage::start(domain, "execute")?;
    let status_pub = stage.publisher::<ExecutionStatus>()?;
    let joints_pub = stage.publisher::<JointStates>()?;
    let plans = stage.subscriber::<GraspPlan>()?;
    // Subscribed last: the harness counts request subscribers to know the cell is up.
    let requests = stage.subscriber::<TrialRequest>()?;
    notify::ready("execute waiting for grasp plans");
    tracing::info!(fri = %fri.bind_addr, robot = %driver_config.robot, can = %interface, "executor ready");
    let mut watchdog = Watchdog::from_env();
    let joints_now = |driver: &FriDriver| JointState {
        arm_rad: driver.status().measured_rad,
        hand_rad: [0.0; crate::ipc::HAND_JOINTS],
    };
    // The hand is brought up while the cell is idle, once the arm commands (its
    // fingers move while initialising); a failed attempt is retried a little later.
    let mut next_hand_attempt = std::time::Instant::now();
    while !stop_requested() {
        watchdog.ping();
        while requests.try_receive()?.is_some() {}
        if !executor.hand_ready()
            && driver.status().commanding
            && std::time::Instant::now() >= next_hand_attempt
        {
            match executor.prepare_hand() {
                Ok(()) => tracing::info!("hand ready"),
                Err(e) => {
                    tracing::warn!("hand bring-up: {e}; retrying in 5 s");
                    next_hand_attempt =
                        std::time::Instant::now() + std::time::Duration::from_secs(5);
                }
            }
        }
        // Only measured joints: none before the robot's first measurement.
        if driver.status().last_seq.is_some() {
            joints_pub.send(&JointStates::new(
                0,
                monotonic_now_ns(),
                joints_now(&driver),
                driver.status().commanding && executor.hand_ready(),
            ))?;
        }
        let plan = match plans.receive_timeout(TICK) {
            Ok(Some(plan)) => plan,
            Ok(None) => continue,
            Err(_) if stop_requested() => break,
            Err(e) => return Err(e.into()),
        };
        let trial_id = plan.trial_id;
        let send = |phase: IpcPhase, code: u32| {
            status_pub.send(&ExecutionStatus::new(
                trial_id,
                monotonic_now_ns(),
                phase,
                code,
                joints_now(&driver),
            ))
        };
        // Bytes that do not decode as a plan (a buggy peer) are no plan: dropped,
        // not reported as the trial's end.
        let failure = match plan.check().and_then(|()| plan.failure()) {
            Ok(f) => f,
            Err(e) => {
                tracing::error!(trial_id, "malformed plan ignored: {e}");
                continue;
            }
        };
        if failure != FailureCause::None {
            tracing::info!(trial_id, ?failure, "plan failed: holding still");
            send(IpcPhase::Stopped, error_code("plan_failed"))?;
            continue;
        }
        let request = match execution_request(&plan) {
            Ok(r) => r,
            Err(e) => {
                tracing::error!(trial_id, "bad plan: {e}");
                send(IpcPhase::Stopped, error_code("bad_request"))?;
                continue;
            }
        };
        let mut last = None;
        let mut send_error = None;
        let report = executor.execute_observed(&request, &mut |phase| {
            if let Some(p) = status_phase(phase) {
                if last != Some(p) {
                    last = Some(p);
                    if let Err(e) = send(p, 0) {
                        send_error = Some(e);
                    }
                }
            }
        });
        if let Some(e) = send_error {
            return Err(e.into());
        }
        // The trial ends with the arm parked, so the next one starts from there.
        match executor.release_and_park(&config.robot.park_joints_rad) {
            Ok(Some(park)) => {
                tracing::info!(trial_id, total_s = park.total_s, "released and parked")
            }
            Ok(None) => {}
            Err(e) => tracing::warn!(
                trial_id,
                "release and park failed: {e}; the arm holds where it stopped"
            ),
        }
        match report.outcome {
            Outcome::Success => send(IpcPhase::Done, 0)?,
            _ => {
                let kind = report.error_kind.unwrap_or("other");
                tracing::warn!(
                    trial_id,
                    kind,
                    "grasp not completed: {}",
                    report
                        .error
                        .as_ref()
                        .map_or(String::new(), |e| e.to_string())
                );
                send(IpcPhase::Stopped, error_code(kind))?
            }
        };
    }
    notify::stopping();
    drop(executor);
    if let Err(e) = driver.shutdown(1.0) {
        tracing::warn!("FRI driver shutdown: {e}");
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_plan_payload_with_nan_or_infinity_is_refused() {
        // Issue 21 item 4: a payload field.
        use std::f64::consts::PI;
        let palm = crate::geometry::pose_from_params(&[0.6, 0.0, 0.2, PI, 0.0, PI]);
        let pregrasp = crate::geometry::pose_from_params(&[0.6, 0.0, 0.3, PI, 0.0, PI]);
        let plan = |joints: [f64; 7], spread_rad: f64| {
            let grasp = crate::plan::PlannedGrasp {
                pose: palm,
                pregrasp_pose: pregrasp,
                spread_rad,
                preshape_rad: crate::robot::PreshapeRad::OPEN,
                max_overtravel_m: None,
                joints: Some(joints),
                pregrasp_joints: Some([0.1; 7]),
                reachable: true,
                unreachable: None,
                objective: 0.0,
                log_objective: f64::NEG_INFINITY,
            };
            GraspPlan::new(7, 0, &grasp, "ours").unwrap()
        };
        assert!(execution_request(&plan([0.1; 7], 0.0)).is_ok());
        let mut joints = [0.1; 7];
        joints[3] = f64::NAN;
        let err = execution_request(&plan(joints, 0.0))
            .unwrap_err()
            .to_string();
        assert!(
            err.contains("trial 7") && err.contains("joints_rad"),
            "{err}"
        );
        let err = execution_request(&plan([0.1; 7], f64::INFINITY))
            .unwrap_err()
            .to_string();
        assert!(err.contains("spread_rad"), "{err}");
        let mut bad_pose = plan([0.1; 7], 0.0);
        bad_pose.base_from_palm.rows[0][3] = f64::NEG_INFINITY;
        let err = execution_request(&bad_pose).unwrap_err().to_string();
        assert!(err.contains("palm"), "{err}");
    }

    #[test]
    fn error_codes_round_trip() {
        for (i, kind) in ERROR_KINDS.iter().enumerate() {
            assert_eq!(error_code(kind), i as u32);
            assert_eq!(error_kind(i as u32), *kind);
        }
        assert_eq!(error_kind(error_code("something new")), "other");
        assert_eq!(status_phase(Phase::Validate), None);
        assert_eq!(
            status_phase(Phase::Preshape),
            Some(IpcPhase::MovingToPregrasp)
        );
    }
}
