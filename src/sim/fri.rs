//! A robot-side FRI 1.x simulator of the LBR4+ (KRC with a KRL program that calls
//! `friOpen`, waits for quality PERFECT, then `friStart`).
//!
//! [`FriSimulator`] is a pure state machine: its behaviour is a function of the times
//! passed to [`FriSimulator::poll`] and the bytes (and arrival times) passed to
//! [`FriSimulator::receive`], so tests drive it without sockets or sleeping.
//! [`spawn_udp`] / [`run_udp`] put it on a UDP socket with a real clock
//! (`cell-sim-arm`).
//!
//! Model (the simulator's own choices where the spec gives no numbers):
//! - One measurement every `cycle_s`. A measurement counts as answered in time when a
//!   command reflecting its `sendSeqCount` arrives before the next measurement is
//!   sent; otherwise it is a miss. Statistics cover the last 100 measurements:
//!   `answerRate`, `missRate`, `latency` (mean, s), `jitter` (max - min latency, s),
//!   and `missCounter` (misses since `friOpen`).
//! - Quality ([`QualityThresholds`]): PERFECT needs a full window with miss rate at
//!   most 1 % and the last answer in time; then OK (<= 5 %, at most one consecutive
//!   miss), BAD (<= 20 %, fewer than 5 consecutive misses), else UNACCEPTABLE.
//! - The KRL program calls `friStart` after quality has been PERFECT for
//!   `start_after_perfect_cycles` cycles: the state goes MON -> CMD and `cmdFlags` are
//!   latched from the last answer.
//! - In CMD the arm tracks the commanded `jntPos` (directly, or with a first-order lag).
//!   A single missing answer is bridged by extrapolating the last commanded velocity;
//!   further misses hold the command.
//! - The robot drops to MON and stops the arm where it is (its own command becomes the
//!   measured position, offset zero) when quality falls below BAD, when a commanded
//!   position is at or beyond a joint limit, when a commanded step implies a speed at
//!   or above a joint's velocity limit, or when `cmdFlags` change in CMD. The KRL
//!   program does not call `friStart` again unless [`FriSimulator::request_start`].
//! - The KRL program calls `friStop` when a command sets [`RELEASE_BIT`] of
//!   `boolData` (the PC is done), and does not call `friStart` while it is set.
//! - `estExtTcpFT` comes from an [`ExternalForce`] model when one is set
//!   ([`FriSimulator::set_external_force`]; `cell-sim-arm --scene` uses the
//!   simulated world's contact force, [`crate::sim::world::ArmContact`]), evaluated
//!   at the measured joints every cycle; zero otherwise.
//! - Not simulated (sent as zeros): Cartesian poses, torques, Jacobian, mass matrix,
//!   gravity. Drive temperatures are a constant ambient value.

use crate::clock::Clock;
use crate::hw::fri::datagram::{
    seq_ahead, CmdFlags, CommandDatagram, ControlMode, DatagramError, FriState, InterfaceState,
    LinkStats, MeasurementDatagram, Quality, RobotData, RobotState,
};
use crate::hw::fri::{JOINTS, RELEASE_BIT};
use serde::Serialize;
use std::collections::VecDeque;
use std::fmt;
use std::net::{SocketAddr, UdpSocket};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex, MutexGuard};
use std::thread::JoinHandle;
use std::time::Duration;

/// Number of measurements the link statistics cover.
pub const STATS_WINDOW: usize = 100;

/// LBR4+ joint position limits, symmetric about zero (rad): ±170°, ±120° alternating.
pub const LBR4_POSITION_LIMIT_RAD: [f64; JOINTS] = [
    2.967_060, 2.094_395, 2.967_060, 2.094_395, 2.967_060, 2.094_395, 2.967_060,
];

/// LBR4+ joint velocity limits (rad/s): 110, 110, 128, 128, 204, 184, 184 deg/s.
pub const LBR4_VELOCITY_LIMIT_RAD_S: [f64; JOINTS] = [
    1.919_862, 1.919_862, 2.234_021, 2.234_021, 3.560_472, 3.211_406, 3.211_406,
];

/// Drive temperature the simulator reports.
const AMBIENT_TEMPERATURE: f32 = 25.0;
/// All seven drives powered, one bit each.
const POWER_ALL_DRIVES: u16 = 0x7f;
/// Most recent events kept; older ones are counted and dropped.
const EVENT_CAPACITY: usize = 1024;

/// Errors of configuring or running the simulator.
#[derive(Debug, thiserror::Error)]
pub enum SimError {
    /// A configuration value is out of range.
    #[error("FRI simulator: {field} = {value}: {problem}")]
    BadConfig {
        /// The field.
        field: String,
        /// The offending value, as text.
        value: String,
        /// What is wrong with it.
        problem: &'static str,
    },
    /// A socket operation failed.
    #[error("FRI simulator: {op} {addr}: {source}")]
    Io {
        /// What was being done.
        op: &'static str,
        /// The address involved.
        addr: SocketAddr,
        /// The I/O error.
        source: std::io::Error,
    },
}

/// When link quality is good enough for each level.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct QualityThresholds {
    /// Highest miss rate (0..=1) over a full window that is still PERFECT.
    pub perfect_max_miss_rate: f64,
    /// Highest miss rate that is still OK.
    pub ok_max_miss_rate: f64,
    /// Highest miss rate that is still BAD.
    pub bad_max_miss_rate: f64,
    /// Consecutive misses from which quality is at most BAD (one miss is bridged).
    pub bad_consecutive_misses: u32,
    /// Consecutive misses from which quality is UNACCEPTABLE.
    pub unacceptable_consecutive_misses: u32,
}

impl QualityThresholds {
    /// Thresholds from command-line text: miss rates `PERFECT,OK,BAD` (fractions)
    /// and consecutive misses `BAD,UNACCEPTABLE` (whole numbers). Checked fully by
    /// [`SimConfig::validate`].
    pub fn from_text(miss_rates: &str, consecutive_misses: &str) -> Result<Self, SimError> {
        let bad = |field: &str, value: &str, problem| SimError::BadConfig {
            field: field.to_string(),
            value: value.to_string(),
            problem,
        };
        let rates = crate::geometry::parse_numbers(miss_rates, 3, "miss rates")
            .map_err(|_| bad("quality miss rates", miss_rates, "expected PERFECT,OK,BAD"))?;
        let counts: Vec<u32> = consecutive_misses
            .split(',')
            .map(|t| t.trim().parse::<u32>())
            .collect::<Result<_, _>>()
            .ok()
            .filter(|c: &Vec<u32>| c.len() == 2)
            .ok_or_else(|| {
                bad(
                    "quality consecutive misses",
                    consecutive_misses,
                    "expected two whole numbers BAD,UNACCEPTABLE",
                )
            })?;
        Ok(QualityThresholds {
            perfect_max_miss_rate: rates[0],
            ok_max_miss_rate: rates[1],
            bad_max_miss_rate: rates[2],
            bad_consecutive_misses: counts[0],
            unacceptable_consecutive_misses: counts[1],
        })
    }
}

impl Default for QualityThresholds {
    fn default() -> QualityThresholds {
        QualityThresholds {
            perfect_max_miss_rate: 0.01,
            ok_max_miss_rate: 0.05,
            bad_max_miss_rate: 0.20,
            bad_consecutive_misses: 2,
            unacceptable_consecutive_misses: 5,
        }
    }
}

/// The simulated robot and KRL program.
#[derive(Debug, Clone, PartialEq)]
pub struct SimConfig {
    /// Measurement period (s); FRI allows 0.001 to 0.1.
    pub cycle_s: f64,
    /// Joint positions at start (rad).
    pub initial_joints_rad: [f64; JOINTS],
    /// Lower joint limits (rad).
    pub position_min_rad: [f64; JOINTS],
    /// Upper joint limits (rad).
    pub position_max_rad: [f64; JOINTS],
    /// Joint speed limits (rad/s).
    pub velocity_limit_rad_s: [f64; JOINTS],
    /// Time constant of the joints' first-order lag behind the command (s); 0 tracks
    /// the command exactly.
    pub tracking_time_constant_s: f64,
    /// Cycles of PERFECT quality after which the KRL program calls `friStart`.
    pub start_after_perfect_cycles: u32,
    /// Whether the KRL program calls `friStart` at all (else the robot stays in MON).
    pub auto_start: bool,
    /// Whether the KRL program calls `friStart` again after the link dropped the
    /// robot to monitor mode, or after the PC released it ([`RELEASE_BIT`]) and a
    /// PC clears the bit again (a loop around `friStart`, as cell programs have): it
    /// is back in command mode once quality has been PERFECT for
    /// `start_after_perfect_cycles` cycles. `friStop` and limit violations still end
    /// command mode for good.
    pub restart_after_drop: bool,
    /// Quality levels.
    pub quality: QualityThresholds,
    /// `sendSeqCount` of the first measurement.
    pub initial_seq_count: u16,
    /// Keep every answer latency (for benchmarks; grows without bound).
    pub record_latencies: bool,
}

impl Default for SimConfig {
    fn default() -> SimConfig {
        SimConfig {
            cycle_s: 0.001,
            initial_joints_rad: [0.0; JOINTS],
            position_min_rad: LBR4_POSITION_LIMIT_RAD.map(|l| -l),
            position_max_rad: LBR4_POSITION_LIMIT_RAD,
            velocity_limit_rad_s: LBR4_VELOCITY_LIMIT_RAD_S,
            tracking_time_constant_s: 0.0,
            start_after_perfect_cycles: 10,
            auto_start: true,
            restart_after_drop: false,
            quality: QualityThresholds::default(),
            initial_seq_count: 0,
            record_latencies: false,
        }
    }
}

impl SimConfig {
    /// Defaults with the joint position and velocity limits of `robot`'s URDF (the
    /// seven arm joints) instead of the LBR4+ data-sheet constants.
    pub fn from_robot(robot: &crate::robot::Robot) -> SimConfig {
        let arm = &robot.description.variables[..JOINTS];
        SimConfig {
            position_min_rad: std::array::from_fn(|j| arm[j].lower_rad),
            position_max_rad: std::array::from_fn(|j| arm[j].upper_rad),
            velocity_limit_rad_s: std::array::from_fn(|j| arm[j].velocity_rad_s),
            ..SimConfig::default()
        }
    }

    /// Checks every value is in range.
    pub fn validate(&self) -> Result<(), SimError> {
        let bad = |field: String, value: f64, problem| SimError::BadConfig {
            field,
            value: value.to_string(),
            problem,
        };
        if !(self.cycle_s.is_finite() && (0.001..=0.1).contains(&self.cycle_s)) {
            return Err(bad(
                "cycle_s".into(),
                self.cycle_s,
                "FRI cycles are 0.001 to 0.1 s",
            ));
        }
        if !(self.tracking_time_constant_s.is_finite() && self.tracking_time_constant_s >= 0.0) {
            return Err(bad(
                "tracking_time_constant_s".into(),
                self.tracking_time_constant_s,
                "must be a finite number >= 0",
            ));
        }
        for j in 0..JOINTS {
            let v = self.velocity_limit_rad_s[j];
            if !(v.is_finite() && v > 0.0) {
                return Err(bad(
                    format!("velocity_limit_rad_s[{j}]"),
                    v,
                    "must be a finite number > 0",
                ));
            }
            let (lo, hi) = (self.position_min_rad[j], self.position_max_rad[j]);
            if !(lo.is_finite() && hi.is_finite() && lo < hi) {
                return Err(bad(
                    format!("position_min_rad[{j}]"),
                    lo,
                    "must be finite and below position_max_rad",
                ));
            }
            let q = self.initial_joints_rad[j];
            if !(q > lo && q < hi) {
                return Err(bad(
                    format!("initial_joints_rad[{j}]"),
                    q,
                    "must lie strictly inside the joint limits",
                ));
            }
        }
        let t = &self.quality;
        for (field, rate) in [
            ("quality.perfect_max_miss_rate", t.perfect_max_miss_rate),
            ("quality.ok_max_miss_rate", t.ok_max_miss_rate),
            ("quality.bad_max_miss_rate", t.bad_max_miss_rate),
        ] {
            if !(0.0..=1.0).contains(&rate) {
                return Err(bad(field.into(), rate, "must be a fraction in 0..=1"));
            }
        }
        if t.bad_consecutive_misses < 2
            || t.unacceptable_consecutive_misses <= t.bad_consecutive_misses
        {
            return Err(bad(
                "quality.unacceptable_consecutive_misses".into(),
                t.unacceptable_consecutive_misses.into(),
                "need 2 <= bad_consecutive_misses < unacceptable_consecutive_misses",
            ));
        }
        Ok(())
    }
}

/// Why the robot left command mode.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub enum DropReason {
    /// Link quality fell below BAD.
    LinkQuality {
        /// The quality reached.
        quality: Quality,
        /// Unanswered measurements in a row.
        consecutive_misses: u32,
        /// Answer rate over the statistics window.
        answer_rate: f64,
    },
    /// A commanded position is at or beyond a joint limit.
    JointLimit {
        /// Zero-based joint index.
        joint: usize,
        /// The commanded position (rad).
        commanded_rad: f64,
        /// The limit reached (rad).
        limit_rad: f64,
    },
    /// A commanded step implies a speed at or above the joint's limit.
    VelocityLimit {
        /// Zero-based joint index.
        joint: usize,
        /// The implied speed (rad/s).
        speed_rad_s: f64,
        /// The limit (rad/s).
        limit_rad_s: f64,
    },
    /// `cmdFlags` changed in command mode.
    FlagsChanged {
        /// Flags latched at `friStart`.
        latched: u32,
        /// Flags received.
        received: u32,
    },
    /// The KRL program called `friStop`.
    FriStop,
    /// The KRL program called `friStop` because the PC released the robot
    /// ([`RELEASE_BIT`] in its commands): the normal end of a session.
    Released,
}

impl fmt::Display for DropReason {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match *self {
            DropReason::LinkQuality {
                quality,
                consecutive_misses,
                answer_rate,
            } => write!(
                f,
                "link quality {quality:?} ({consecutive_misses} answers missed in a row, answer rate {answer_rate:.2})"
            ),
            DropReason::JointLimit {
                joint,
                commanded_rad,
                limit_rad,
            } => write!(
                f,
                "joint {joint} commanded to {commanded_rad} rad, at or beyond its limit {limit_rad} rad"
            ),
            DropReason::VelocityLimit {
                joint,
                speed_rad_s,
                limit_rad_s,
            } => write!(
                f,
                "joint {joint} commanded at {speed_rad_s} rad/s, at or above its limit {limit_rad_s} rad/s"
            ),
            DropReason::FlagsChanged { latched, received } => write!(
                f,
                "cmdFlags changed in command mode from {latched:#x} to {received:#x}"
            ),
            DropReason::FriStop => f.write_str("friStop"),
            DropReason::Released => f.write_str("friStop on the PC's release request"),
        }
    }
}

/// Something the simulated robot did or saw, with the simulator time (s since `friOpen`).
#[derive(Debug, Clone, PartialEq)]
pub enum SimEvent {
    /// The link quality changed.
    QualityChanged {
        /// Before.
        from: Quality,
        /// After.
        to: Quality,
        /// When (s).
        at_s: f64,
    },
    /// `friStart`: MON -> CMD.
    StartedCommanding {
        /// When (s).
        at_s: f64,
    },
    /// CMD -> MON, arm stopped.
    DroppedToMonitor {
        /// Why.
        reason: DropReason,
        /// When (s).
        at_s: f64,
    },
    /// A datagram that is not a valid command was received (and ignored).
    BadDatagram {
        /// What was wrong.
        error: DatagramError,
        /// When (s).
        at_s: f64,
    },
    /// A command reflecting no recently sent measurement (ignored).
    UnexpectedAnswer {
        /// Its `reflSeqCount`.
        refl_seq_count: u16,
        /// When (s).
        at_s: f64,
    },
}

/// How one received datagram was classified.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Answer {
    /// Answers the latest measurement before the next one was due.
    InTime {
        /// Measurement sent -> command received (s).
        latency_s: f64,
    },
    /// Answers an older measurement.
    Late {
        /// Measurement sent -> command received (s).
        latency_s: f64,
    },
    /// Answers a measurement already answered.
    Duplicate,
    /// Reflects no recently sent measurement.
    Unexpected,
    /// Not a valid command datagram.
    Garbled,
}

/// A command as the robot received it ([`FriSimulator::record_commands`]): the
/// record of what left the PC, at the datagram level.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct ReceivedCommand {
    /// The measurement it answers (`reflSeqCount`).
    pub refl_seq_count: u16,
    /// The robot's state when it arrived (only in CMD does the arm follow it).
    pub state: FriState,
    /// Its `cmdFlags`.
    pub cmd_flags: u32,
    /// Its joint positions (rad), as the f32 on the wire.
    pub jnt_pos_rad: [f64; JOINTS],
}

/// Cumulative counters since `friOpen`.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize)]
pub struct SimCounters {
    /// Measurements sent.
    pub measurements_sent: u64,
    /// Measurements answered in time.
    pub answers_in_time: u64,
    /// Measurements not answered in time (`missCounter`).
    pub misses: u64,
    /// Answers that arrived after the next measurement.
    pub late_answers: u64,
    /// Second answers to the same measurement.
    pub duplicate_answers: u64,
    /// Answers reflecting no recent measurement.
    pub unexpected_answers: u64,
    /// Datagrams that failed to decode.
    pub bad_datagrams: u64,
    /// Times a measurement went out more than a cycle late (the simulator stalled).
    pub overruns: u64,
    /// Times the robot dropped from command to monitor mode.
    pub drops_to_monitor: u64,
    /// Events discarded because nobody collected them.
    pub events_discarded: u64,
}

/// What the environment does to the simulated arm: the force and torque at the
/// tool that FRI reports as `estExtTcpFT`.
pub trait ExternalForce: Send {
    /// Fx Fy Fz (N) Tz Ty Tx (N m) at the tool, tool frame, with the arm at
    /// `measured_rad`.
    fn tcp_ft(&mut self, measured_rad: &[f64; JOINTS]) -> [f64; 6];
}

/// A force model evaluated beside the simulator's cycle: [`ExternalForce::tcp_ft`]
/// answers at once with the latest force a worker thread computed from the
/// latest measured joints, so an expensive model (the simulated world's contact
/// queries) never delays a measurement or an answer's reception. The force lags
/// the arm by one evaluation of the model (about a millisecond). For lockstep
/// tests, plug the model in directly instead.
pub struct BackgroundForce {
    shared: std::sync::Arc<std::sync::Mutex<BackgroundState>>,
    stop: std::sync::Arc<std::sync::atomic::AtomicBool>,
    worker: Option<std::thread::JoinHandle<()>>,
}

/// The joints handed to the worker and the force it last computed.
#[derive(Default)]
struct BackgroundState {
    joints: Option<[f64; JOINTS]>,
    tcp_ft: [f64; 6],
}

impl BackgroundForce {
    /// Runs `model` on a thread of its own (lowest ordinary priority), evaluating
    /// it whenever new joints arrive, at most every `period`.
    pub fn new(mut model: Box<dyn ExternalForce>, period: Duration) -> std::io::Result<Self> {
        use std::sync::atomic::Ordering;
        let shared = std::sync::Arc::new(std::sync::Mutex::new(BackgroundState::default()));
        let stop = std::sync::Arc::new(std::sync::atomic::AtomicBool::new(false));
        let (state, quit) = (shared.clone(), stop.clone());
        let worker = std::thread::Builder::new()
            .name("external-force".into())
            .spawn(move || {
                crate::hw::realtime::lower_thread_priority();
                while !quit.load(Ordering::Relaxed) {
                    let joints = state
                        .lock()
                        .unwrap_or_else(|e| e.into_inner())
                        .joints
                        .take();
                    if let Some(q) = joints {
                        let f = model.tcp_ft(&q);
                        state.lock().unwrap_or_else(|e| e.into_inner()).tcp_ft = f;
                    }
                    std::thread::sleep(period);
                }
            })?;
        Ok(BackgroundForce {
            shared,
            stop,
            worker: Some(worker),
        })
    }
}

impl ExternalForce for BackgroundForce {
    fn tcp_ft(&mut self, measured_rad: &[f64; JOINTS]) -> [f64; 6] {
        let mut state = self.shared.lock().unwrap_or_else(|e| e.into_inner());
        state.joints = Some(*measured_rad);
        state.tcp_ft
    }
}

impl Drop for BackgroundForce {
    fn drop(&mut self) {
        self.stop.store(true, std::sync::atomic::Ordering::Relaxed);
        if let Some(w) = self.worker.take() {
            let _ = w.join();
        }
    }
}

/// The optional force model, printable.
struct ForceModel(Option<Box<dyn ExternalForce>>);

impl fmt::Debug for ForceModel {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(if self.0.is_some() { "Some(..)" } else { "None" })
    }
}

/// The robot-side FRI state machine.
#[derive(Debug)]
pub struct FriSimulator {
    /// Source of `estExtTcpFT`.
    force_model: ForceModel,
    /// `estExtTcpFT` of the current cycle.
    ext_tcp_ft: [f64; 6],
    config: SimConfig,
    /// Time of `friOpen` (the first measurement).
    opened_at: Option<Duration>,
    next_send: Duration,
    last_step: Duration,
    state: FriState,
    quality: Quality,
    /// `sendSeqCount` of the latest measurement.
    seq: u16,
    /// Send times of the last measurements.
    sent: VecDeque<(u16, Duration)>,
    /// Newest measurement answered so far.
    last_answered: Option<u16>,
    /// Latency of the answer to the latest measurement, if it came.
    current_latency_s: Option<f64>,
    /// Per finished measurement: the latency when answered in time, else a miss.
    window: VecDeque<Option<f64>>,
    consecutive_misses: u32,
    msr_rad: [f64; JOINTS],
    /// The robot's own (KRL) command.
    krl_rad: [f64; JOINTS],
    /// The command the arm tracks in CMD (received or extrapolated).
    target_rad: [f64; JOINTS],
    prev_target_rad: [f64; JOINTS],
    /// The last received command and the measurement it reflected.
    last_cmd_rad: [f64; JOINTS],
    last_applied: Option<u16>,
    new_command: bool,
    latched_flags: CmdFlags,
    last_monitor_flags: CmdFlags,
    perfect_cycles: u32,
    start_requested: bool,
    /// The last command carried [`RELEASE_BIT`].
    release_requested: bool,
    drop_reason: Option<DropReason>,
    events: VecDeque<SimEvent>,
    counters: SimCounters,
    latencies_s: Vec<f64>,
    /// Every answer received, when recording ([`FriSimulator::record_commands`]).
    commands: Option<Vec<ReceivedCommand>>,
}

impl FriSimulator {
    /// A robot at `config.initial_joints_rad`, FRI not yet open (it opens in MON at
    /// the first [`poll`](FriSimulator::poll)).
    pub fn new(config: SimConfig) -> Result<FriSimulator, SimError> {
        config.validate()?;
        let q = config.initial_joints_rad;
        Ok(FriSimulator {
            force_model: ForceModel(None),
            ext_tcp_ft: [0.0; 6],
            opened_at: None,
            next_send: Duration::ZERO,
            last_step: Duration::ZERO,
            state: FriState::Off,
            quality: Quality::Unacceptable,
            seq: config.initial_seq_count.wrapping_sub(1),
            sent: VecDeque::with_capacity(STATS_WINDOW),
            last_answered: None,
            current_latency_s: None,
            window: VecDeque::with_capacity(STATS_WINDOW),
            consecutive_misses: 0,
            msr_rad: q,
            krl_rad: q,
            target_rad: q,
            prev_target_rad: q,
            last_cmd_rad: q,
            last_applied: None,
            new_command: false,
            latched_flags: CmdFlags::NONE,
            last_monitor_flags: CmdFlags::NONE,
            perfect_cycles: 0,
            start_requested: config.auto_start,
            release_requested: false,
            drop_reason: None,
            events: VecDeque::new(),
            counters: SimCounters::default(),
            latencies_s: Vec::new(),
            commands: None,
            config,
        })
    }

    /// The configuration.
    pub fn config(&self) -> &SimConfig {
        &self.config
    }

    /// Sets (or removes) the model of `estExtTcpFT`.
    pub fn set_external_force(&mut self, model: Option<Box<dyn ExternalForce>>) {
        self.force_model = ForceModel(model);
    }

    /// `estExtTcpFT` of the latest measurement (Fx Fy Fz N, Tz Ty Tx N m).
    pub fn ext_tcp_ft(&self) -> [f64; 6] {
        self.ext_tcp_ft
    }

    /// Monitor or command mode (OFF before the first poll).
    pub fn state(&self) -> FriState {
        self.state
    }

    /// The current link quality.
    pub fn quality(&self) -> Quality {
        self.quality
    }

    /// Measured joint positions (rad).
    pub fn joints_rad(&self) -> [f64; JOINTS] {
        self.msr_rad
    }

    /// Why the robot last dropped to MON, if it did.
    pub fn drop_reason(&self) -> Option<DropReason> {
        self.drop_reason
    }

    /// Cumulative counters.
    pub fn counters(&self) -> SimCounters {
        self.counters
    }

    /// Every answer latency so far (s), when `record_latencies` is set.
    pub fn latencies_s(&self) -> &[f64] {
        &self.latencies_s
    }

    /// Removes and returns the answer latencies recorded so far (s).
    pub fn take_latencies_s(&mut self) -> Vec<f64> {
        std::mem::take(&mut self.latencies_s)
    }

    /// Starts (or stops, `false`) keeping every command that answers a measurement
    /// ([`ReceivedCommand`]; grows without bound while on).
    pub fn record_commands(&mut self, on: bool) {
        self.commands = on.then(|| self.commands.take().unwrap_or_default());
    }

    /// Removes and returns the commands recorded so far (oldest first).
    pub fn take_commands(&mut self) -> Vec<ReceivedCommand> {
        self.commands
            .as_mut()
            .map(std::mem::take)
            .unwrap_or_default()
    }

    /// When the next measurement is due (clock time).
    pub fn next_send_time(&self) -> Duration {
        self.next_send
    }

    /// Removes and returns the events so far (oldest first).
    pub fn take_events(&mut self) -> Vec<SimEvent> {
        self.events.drain(..).collect()
    }

    /// Whether the KRL program will call `friStart` once quality allows.
    pub fn start_requested(&self) -> bool {
        self.start_requested
    }

    /// The KRL program asks for `friStart` again: it happens once quality has been
    /// PERFECT for `start_after_perfect_cycles` cycles.
    pub fn request_start(&mut self) {
        self.start_requested = true;
    }

    /// The KRL program calls `friStop`: CMD -> MON, the arm stops where it is.
    pub fn request_stop(&mut self, now: Duration) {
        self.start_requested = false;
        if self.state == FriState::Command {
            self.drop_to_monitor(DropReason::FriStop, now);
        }
    }

    /// The link statistics over the last [`STATS_WINDOW`] measurements.
    pub fn link_stats(&self) -> LinkStats {
        let n = self.window.len();
        let latencies: Vec<f64> = self.window.iter().flatten().copied().collect();
        let answered = latencies.len();
        let (answer_rate, miss_rate) = if n == 0 {
            (0.0, 0.0)
        } else {
            let rate = answered as f64 / n as f64;
            (rate, 1.0 - rate)
        };
        let (mean, spread) = if latencies.is_empty() {
            (0.0, 0.0)
        } else {
            let max = latencies.iter().copied().fold(f64::MIN, f64::max);
            let min = latencies.iter().copied().fold(f64::MAX, f64::min);
            (latencies.iter().sum::<f64>() / answered as f64, max - min)
        };
        LinkStats {
            answer_rate: answer_rate as f32,
            latency_s: mean as f32,
            jitter_s: spread as f32,
            miss_rate: miss_rate as f32,
            miss_counter: self.counters.misses as u32,
        }
    }

    fn at_s(&self, now: Duration) -> f64 {
        now.saturating_sub(self.opened_at.unwrap_or(now))
            .as_secs_f64()
    }

    fn push_event(&mut self, event: SimEvent) {
        match &event {
            SimEvent::DroppedToMonitor {
                reason: DropReason::Released,
                at_s,
            } => tracing::info!("FRI sim: released to monitor at {at_s:.3} s"),
            SimEvent::DroppedToMonitor { reason, at_s } => {
                tracing::warn!("FRI sim: dropped to monitor at {at_s:.3} s: {reason}")
            }
            SimEvent::BadDatagram { error, .. } => tracing::warn!("FRI sim: {error}"),
            other => tracing::info!("FRI sim: {other:?}"),
        }
        if self.events.len() == EVENT_CAPACITY {
            self.events.pop_front();
            self.counters.events_discarded += 1;
        }
        self.events.push_back(event);
    }

    /// Advances the robot to `now`; when a measurement is due, returns it (to be sent
    /// at once). The first call opens FRI in MON.
    pub fn poll(&mut self, now: Duration) -> Option<MeasurementDatagram> {
        let cycle = Duration::from_nanos((self.config.cycle_s * 1e9).round() as u64);
        if self.opened_at.is_none() {
            self.opened_at = Some(now);
            self.state = FriState::Monitor;
            self.last_step = now;
            self.next_send = now;
        }
        if now < self.next_send {
            return None;
        }
        if self.counters.measurements_sent > 0 {
            self.finish_cycle();
            self.step_arm(now);
        }
        self.update_quality(now);
        self.run_state_machine(now);
        if let Some(model) = &mut self.force_model.0 {
            self.ext_tcp_ft = model.tcp_ft(&self.msr_rad);
        }

        self.seq = self.seq.wrapping_add(1);
        if self.sent.len() == STATS_WINDOW {
            self.sent.pop_front();
        }
        self.sent.push_back((self.seq, now));
        self.current_latency_s = None;
        self.new_command = false;
        self.counters.measurements_sent += 1;
        self.next_send += cycle;
        if self.next_send <= now {
            self.counters.overruns += 1;
            self.next_send = now + cycle;
        }
        Some(self.measurement(now))
    }

    /// Books the latest measurement as answered in time or missed.
    fn finish_cycle(&mut self) {
        if self.window.len() == STATS_WINDOW {
            self.window.pop_front();
        }
        self.window.push_back(self.current_latency_s);
        if self.current_latency_s.is_some() {
            self.consecutive_misses = 0;
            self.counters.answers_in_time += 1;
        } else {
            self.consecutive_misses += 1;
            self.counters.misses += 1;
        }
    }

    /// Moves the arm from the last step to `now`.
    fn step_arm(&mut self, now: Duration) {
        let dt = now.saturating_sub(self.last_step).as_secs_f64();
        self.last_step = now;
        let desired = if self.state == FriState::Command {
            if !self.new_command && self.consecutive_misses == 1 {
                // Bridge a single missing answer with the last commanded velocity.
                let next: [f64; JOINTS] =
                    std::array::from_fn(|j| 2.0 * self.target_rad[j] - self.prev_target_rad[j]);
                self.prev_target_rad = self.target_rad;
                self.target_rad = next;
                if let Some(reason) = self.limit_violation(&next) {
                    self.drop_to_monitor(reason, now);
                    return;
                }
            }
            self.target_rad
        } else {
            self.krl_rad
        };
        let tau = self.config.tracking_time_constant_s;
        let alpha = if tau == 0.0 {
            1.0
        } else {
            1.0 - (-dt / tau).exp()
        };
        for (msr, goal) in self.msr_rad.iter_mut().zip(desired) {
            *msr += alpha * (goal - *msr);
        }
    }

    fn update_quality(&mut self, now: Duration) {
        let t = self.config.quality;
        let n = self.window.len();
        let misses = self.window.iter().filter(|l| l.is_none()).count();
        let miss_rate = if n == 0 {
            1.0
        } else {
            misses as f64 / n as f64
        };
        let c = self.consecutive_misses;
        let quality = if n == 0
            || c >= t.unacceptable_consecutive_misses
            || miss_rate > t.bad_max_miss_rate
        {
            Quality::Unacceptable
        } else if c >= t.bad_consecutive_misses || miss_rate > t.ok_max_miss_rate {
            Quality::Bad
        } else if c >= 1 || miss_rate > t.perfect_max_miss_rate || n < STATS_WINDOW {
            Quality::Ok
        } else {
            Quality::Perfect
        };
        if quality != self.quality {
            let at_s = self.at_s(now);
            self.push_event(SimEvent::QualityChanged {
                from: self.quality,
                to: quality,
                at_s,
            });
            self.quality = quality;
        }
    }

    fn run_state_machine(&mut self, now: Duration) {
        match self.state {
            FriState::Command if self.quality < Quality::Bad => {
                let answered = self.window.iter().filter(|l| l.is_some()).count();
                let reason = DropReason::LinkQuality {
                    quality: self.quality,
                    consecutive_misses: self.consecutive_misses,
                    answer_rate: answered as f64 / self.window.len().max(1) as f64,
                };
                self.drop_to_monitor(reason, now);
            }
            FriState::Monitor => {
                self.perfect_cycles = if self.quality == Quality::Perfect {
                    self.perfect_cycles + 1
                } else {
                    0
                };
                if self.start_requested
                    && !self.release_requested
                    && self.perfect_cycles >= self.config.start_after_perfect_cycles
                {
                    self.start_requested = false;
                    self.state = FriState::Command;
                    self.latched_flags = self.last_monitor_flags;
                    self.target_rad = self.krl_rad;
                    self.prev_target_rad = self.krl_rad;
                    self.last_cmd_rad = self.krl_rad;
                    self.last_applied = None;
                    let at_s = self.at_s(now);
                    self.push_event(SimEvent::StartedCommanding { at_s });
                }
            }
            _ => {}
        }
    }

    fn drop_to_monitor(&mut self, reason: DropReason, now: Duration) {
        self.state = FriState::Monitor;
        // Stop where the arm is: the KRL command takes over at the measured position.
        self.krl_rad = self.msr_rad;
        self.target_rad = self.msr_rad;
        self.prev_target_rad = self.msr_rad;
        self.last_cmd_rad = self.msr_rad;
        self.last_applied = None;
        self.perfect_cycles = 0;
        if self.config.restart_after_drop
            && matches!(
                reason,
                DropReason::LinkQuality { .. } | DropReason::Released
            )
        {
            self.start_requested = true;
        }
        self.drop_reason = Some(reason);
        self.counters.drops_to_monitor += 1;
        let at_s = self.at_s(now);
        self.push_event(SimEvent::DroppedToMonitor { reason, at_s });
    }

    fn limit_violation(&self, q: &[f64; JOINTS]) -> Option<DropReason> {
        (0..JOINTS).find_map(|joint| {
            let (lo, hi) = (
                self.config.position_min_rad[joint],
                self.config.position_max_rad[joint],
            );
            let limit_rad = if q[joint] <= lo {
                lo
            } else if q[joint] >= hi {
                hi
            } else {
                return None;
            };
            Some(DropReason::JointLimit {
                joint,
                commanded_rad: q[joint],
                limit_rad,
            })
        })
    }

    /// Takes in one datagram from the PC that arrived at `now`.
    pub fn receive(&mut self, bytes: &[u8], now: Duration) -> Answer {
        let command = match CommandDatagram::decode(bytes) {
            Ok(command) => command,
            Err(error) => {
                self.counters.bad_datagrams += 1;
                let at_s = self.at_s(now);
                self.push_event(SimEvent::BadDatagram { error, at_s });
                return Answer::Garbled;
            }
        };
        let refl = command.refl_seq_count;
        let Some(&(_, sent_at)) = self.sent.iter().rev().find(|(seq, _)| *seq == refl) else {
            self.counters.unexpected_answers += 1;
            let at_s = self.at_s(now);
            self.push_event(SimEvent::UnexpectedAnswer {
                refl_seq_count: refl,
                at_s,
            });
            return Answer::Unexpected;
        };
        if let Some(last) = self.last_answered {
            let ahead = seq_ahead(refl, last);
            if ahead == 0 || ahead > u16::MAX / 2 {
                self.counters.duplicate_answers += 1;
                return Answer::Duplicate;
            }
        }
        self.last_answered = Some(refl);
        if let Some(commands) = &mut self.commands {
            commands.push(ReceivedCommand {
                refl_seq_count: refl,
                state: self.state,
                cmd_flags: command.cmd_flags.raw(),
                jnt_pos_rad: command.jnt_pos.map(f64::from),
            });
        }
        let latency_s = now.saturating_sub(sent_at).as_secs_f64();
        if self.config.record_latencies {
            self.latencies_s.push(latency_s);
        }
        let answer = if refl == self.seq {
            self.current_latency_s = Some(latency_s);
            Answer::InTime { latency_s }
        } else {
            self.counters.late_answers += 1;
            Answer::Late { latency_s }
        };
        self.apply(&command, now);
        answer
    }

    fn apply(&mut self, command: &CommandDatagram, now: Duration) {
        let refl = command.refl_seq_count;
        // The KRL program's loop: friStop while the PC releases the robot.
        self.release_requested = command.krl.bools & RELEASE_BIT != 0;
        if self.release_requested && self.state == FriState::Command {
            self.drop_to_monitor(DropReason::Released, now);
            return;
        }
        match self.state {
            FriState::Monitor => {
                self.last_monitor_flags = command.cmd_flags;
                return;
            }
            FriState::Command => {}
            _ => return,
        }
        if command.cmd_flags != self.latched_flags {
            let reason = DropReason::FlagsChanged {
                latched: self.latched_flags.raw(),
                received: command.cmd_flags.raw(),
            };
            self.drop_to_monitor(reason, now);
            return;
        }
        let cycles = self.last_applied.map_or(1, |last| seq_ahead(refl, last));
        self.last_applied = Some(refl);
        if !self.latched_flags.contains(CmdFlags::JNT_POS) {
            return;
        }
        let q: [f64; JOINTS] = command.jnt_pos.map(f64::from);
        if let Some(reason) = self.limit_violation(&q) {
            self.drop_to_monitor(reason, now);
            return;
        }
        let dt = f64::from(cycles) * self.config.cycle_s;
        for (joint, (qj, last)) in q.iter().zip(self.last_cmd_rad).enumerate() {
            let speed_rad_s = (qj - last).abs() / dt;
            let limit_rad_s = self.config.velocity_limit_rad_s[joint];
            if speed_rad_s >= limit_rad_s {
                let reason = DropReason::VelocityLimit {
                    joint,
                    speed_rad_s,
                    limit_rad_s,
                };
                self.drop_to_monitor(reason, now);
                return;
            }
        }
        self.last_cmd_rad = q;
        self.prev_target_rad = self.target_rad;
        self.target_rad = q;
        self.new_command = true;
    }

    /// The measurement for the current cycle.
    fn measurement(&self, now: Duration) -> MeasurementDatagram {
        let commanding = self.state == FriState::Command;
        let to_f32 = |q: [f64; JOINTS]| q.map(|v| v as f32);
        let krl = to_f32(self.krl_rad);
        let offset: [f32; JOINTS] = if commanding {
            std::array::from_fn(|j| self.target_rad[j] as f32 - krl[j])
        } else {
            [0.0; JOINTS]
        };
        MeasurementDatagram {
            send_seq_count: self.seq,
            refl_seq_count: self.last_answered.unwrap_or(0),
            krl: Default::default(),
            interface: InterfaceState {
                timestamp_s: self.at_s(now) as f32,
                state: self.state,
                quality: self.quality,
                desired_msr_sample_time_s: self.config.cycle_s as f32,
                desired_cmd_sample_time_s: self.config.cycle_s as f32,
                safety_limits: 0.0,
                stats: self.link_stats(),
            },
            robot: RobotState {
                power: POWER_ALL_DRIVES,
                control: ControlMode::Position,
                error: 0,
                warning: 0,
                temperature: [AMBIENT_TEMPERATURE; JOINTS],
            },
            data: RobotData {
                msr_jnt_pos: to_f32(self.msr_rad),
                cmd_jnt_pos: krl,
                cmd_jnt_pos_fri_offset: offset,
                est_ext_tcp_ft: self.ext_tcp_ft.map(|v| v as f32),
                ..Default::default()
            },
        }
    }

    /// A summary for reports.
    pub fn summary(&self) -> SimSummary {
        SimSummary {
            state: self.state,
            quality: self.quality,
            joints_rad: self.msr_rad,
            drop_reason: self.drop_reason,
            counters: self.counters,
            link: self.link_stats(),
        }
    }
}

/// The simulator's state for reports.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct SimSummary {
    /// Monitor or command mode.
    pub state: FriState,
    /// Link quality.
    pub quality: Quality,
    /// Measured joint positions (rad).
    pub joints_rad: [f64; JOINTS],
    /// Why it last dropped to MON, if it did.
    pub drop_reason: Option<DropReason>,
    /// Cumulative counters.
    pub counters: SimCounters,
    /// Statistics over the last 100 measurements.
    pub link: LinkStats,
}

fn lock(sim: &Mutex<FriSimulator>) -> MutexGuard<'_, FriSimulator> {
    sim.lock().unwrap_or_else(|e| e.into_inner())
}

/// Runs `sim` on `socket` until `stop` is set or the clock passes `until`: sends each
/// due measurement to `pc_addr` and feeds every received datagram, stamped on arrival,
/// to the simulator. A receiving thread blocks on the socket; this thread sleeps
/// until each measurement is due.
pub fn run_udp(
    sim: &Mutex<FriSimulator>,
    socket: &UdpSocket,
    pc_addr: SocketAddr,
    clock: &dyn Clock,
    stop: &AtomicBool,
    until: Option<Duration>,
) -> Result<(), SimError> {
    let local = socket.local_addr().map_err(|source| SimError::Io {
        op: "query local address of",
        addr: pc_addr,
        source,
    })?;
    let io = |op, source| SimError::Io {
        op,
        addr: local,
        source,
    };
    socket
        .set_read_timeout(Some(Duration::from_millis(20)))
        .map_err(|e| io("set read timeout on", e))?;
    std::thread::scope(|scope| {
        let receiver = scope.spawn(|| -> Result<(), SimError> {
            crate::hw::realtime::request_device_cycle_priority("FRI sim receiver");
            let mut buf = [0u8; 2048];
            while !stop.load(Ordering::Relaxed) {
                match socket.recv_from(&mut buf) {
                    Ok((n, _from)) => {
                        let now = clock.now();
                        lock(sim).receive(&buf[..n], now);
                    }
                    Err(e) if crate::hw::fri::is_quiet_receive(&e) => {}
                    Err(e) => return Err(io("receive on", e)),
                }
            }
            Ok(())
        });
        // The sending loop runs here (the robot's real-time cycle); it ends at `stop`,
        // at `until`, or when the receiver fails.
        crate::hw::realtime::request_device_cycle_priority("FRI sim sender");
        while !stop.load(Ordering::Relaxed) && !receiver.is_finished() {
            let now = clock.now();
            if until.is_some_and(|end| now >= end) {
                break;
            }
            let (measurement, next) = {
                let mut sim = lock(sim);
                let m = sim.poll(now);
                (m, sim.next_send_time())
            };
            if let Some(m) = measurement {
                if let Err(e) = socket.send_to(&m.encode(), pc_addr) {
                    // The robot keeps sending whether or not anyone listens.
                    tracing::debug!("FRI sim: send to {pc_addr}: {e}");
                }
            }
            let wait = next.saturating_sub(clock.now());
            if !wait.is_zero() {
                std::thread::sleep(wait);
            }
        }
        stop.store(true, Ordering::Relaxed);
        receiver.join().unwrap_or(Ok(()))
    })
}

/// A simulator running on its own threads; see [`spawn_udp`].
#[derive(Debug)]
pub struct SimHandle {
    sim: Arc<Mutex<FriSimulator>>,
    stop: Arc<AtomicBool>,
    local_addr: SocketAddr,
    thread: Option<JoinHandle<Result<(), SimError>>>,
}

impl SimHandle {
    /// The robot's UDP address.
    pub fn local_addr(&self) -> SocketAddr {
        self.local_addr
    }

    /// Runs `f` on the simulator (briefly: the robot's cycle waits for it).
    pub fn with<R>(&self, f: impl FnOnce(&mut FriSimulator) -> R) -> R {
        f(&mut lock(&self.sim))
    }

    /// Stops sending and receiving and returns the final simulator.
    pub fn stop(mut self) -> Result<SimSummary, SimError> {
        self.stop.store(true, Ordering::Relaxed);
        if let Some(thread) = self.thread.take() {
            thread.join().unwrap_or(Ok(()))?;
        }
        Ok(lock(&self.sim).summary())
    }
}

impl Drop for SimHandle {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        if let Some(thread) = self.thread.take() {
            let _ = thread.join();
        }
    }
}

/// Binds `bind` and runs a simulator on background threads, sending measurements
/// to `pc_addr` on `clock`'s time, until [`SimHandle::stop`] or drop.
pub fn spawn_udp(
    config: SimConfig,
    bind: SocketAddr,
    pc_addr: SocketAddr,
    clock: Arc<dyn Clock>,
) -> Result<SimHandle, SimError> {
    let sim = Arc::new(Mutex::new(FriSimulator::new(config)?));
    let socket = UdpSocket::bind(bind).map_err(|source| SimError::Io {
        op: "bind",
        addr: bind,
        source,
    })?;
    let local_addr = socket.local_addr().map_err(|source| SimError::Io {
        op: "query local address of",
        addr: bind,
        source,
    })?;
    let stop = Arc::new(AtomicBool::new(false));
    let thread = {
        let (sim, stop) = (Arc::clone(&sim), Arc::clone(&stop));
        std::thread::Builder::new()
            .name("fri-sim".into())
            .spawn(move || run_udp(&sim, &socket, pc_addr, clock.as_ref(), &stop, None))
            .map_err(|source| SimError::Io {
                op: "start thread for",
                addr: local_addr,
                source,
            })?
    };
    Ok(SimHandle {
        sim,
        stop,
        local_addr,
        thread: Some(thread),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    const MS: Duration = Duration::from_millis(1);

    /// The PC's answer to `m`: mirror, or `q` when given (in CMD).
    fn answer(m: &MeasurementDatagram, seq: u16, q: Option<[f64; JOINTS]>) -> Vec<u8> {
        CommandDatagram {
            send_seq_count: seq,
            refl_seq_count: m.send_seq_count,
            cmd_flags: CmdFlags::JNT_POS,
            jnt_pos: q.map_or_else(|| m.mirrored_jnt_pos(), |q| q.map(|v| v as f32)),
            ..Default::default()
        }
        .encode()
        .to_vec()
    }

    /// Runs `cycles` cycles of 1 ms answering each measurement after 100 µs with `q(k)`
    /// (None = mirror, or no answer when `answer_if` says so). Returns the last
    /// measurement.
    fn run(
        sim: &mut FriSimulator,
        t: &mut Duration,
        cycles: usize,
        mut q: impl FnMut(usize, &MeasurementDatagram) -> Option<Option<[f64; JOINTS]>>,
    ) -> MeasurementDatagram {
        let mut last = None;
        for k in 0..cycles {
            let m = sim.poll(*t).expect("a measurement is due every cycle");
            if let Some(cmd) = q(k, &m) {
                let bytes = answer(&m, m.send_seq_count, cmd);
                sim.receive(&bytes, *t + Duration::from_micros(100));
            }
            assert!(sim.poll(*t + Duration::from_micros(500)).is_none());
            *t += MS;
            last = Some(m);
        }
        last.expect("at least one cycle")
    }

    fn started() -> (FriSimulator, Duration) {
        let mut sim = FriSimulator::new(SimConfig {
            initial_joints_rad: [0.1, -0.2, 0.3, 0.4, -0.5, 0.6, 0.0],
            ..Default::default()
        })
        .unwrap();
        let mut t = Duration::from_secs(3);
        run(&mut sim, &mut t, 150, |_, _| Some(None));
        assert_eq!(sim.state(), FriState::Command);
        sim.take_events();
        (sim, t)
    }

    #[test]
    fn quality_thresholds_parse_from_text() {
        assert_eq!(
            QualityThresholds::from_text("0.01,0.05,0.2", "2,5").unwrap(),
            QualityThresholds::default()
        );
        for (rates, misses) in [
            ("0.1,0.2", "2,5"),
            ("0.01,0.05,0.2", "2.5,5"),
            ("a,b,c", "2,5"),
        ] {
            let err = QualityThresholds::from_text(rates, misses)
                .unwrap_err()
                .to_string();
            assert!(err.contains("quality"), "{err}");
        }
    }

    #[test]
    fn limits_from_the_robot_are_the_urdf_limits_of_the_arm_joints() {
        let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
            .join(crate::config::DEFAULT_CONFIG_PATH);
        let cell = crate::config::CellConfig::load(&path).unwrap();
        let robot = crate::robot::Robot::load(&cell).unwrap();
        let config = SimConfig::from_robot(&robot);
        config.validate().unwrap();
        // Read the URDF again, independently of the robot module.
        let urdf = urdf_rs::read_file(&cell.robot.urdf).unwrap();
        for (j, name) in cell.robot.arm_joints.iter().enumerate() {
            let joint = urdf.joints.iter().find(|x| &x.name == name).unwrap();
            assert_eq!(config.position_min_rad[j], joint.limit.lower, "{name}");
            assert_eq!(config.position_max_rad[j], joint.limit.upper, "{name}");
            assert_eq!(
                config.velocity_limit_rad_s[j], joint.limit.velocity,
                "{name}"
            );
        }
        assert_eq!(config.cycle_s, SimConfig::default().cycle_s);
    }

    #[test]
    fn opens_in_monitor_and_starts_commanding_after_perfect_quality() {
        let mut sim = FriSimulator::new(SimConfig::default()).unwrap();
        let mut t = Duration::from_secs(1);
        assert_eq!(sim.state(), FriState::Off);
        let first = sim.poll(t).unwrap();
        assert_eq!(first.interface.state, FriState::Monitor);
        assert_eq!(first.interface.quality, Quality::Unacceptable);
        sim.receive(&answer(&first, 0, None), t + Duration::from_micros(50));
        t += MS;
        // 99 more cycles: OK while the window fills, PERFECT once it holds 100.
        let m = run(&mut sim, &mut t, 99, |_, _| Some(None));
        assert_eq!(m.interface.quality, Quality::Ok);
        assert_eq!(m.interface.state, FriState::Monitor);
        let m = run(&mut sim, &mut t, 1, |_, _| Some(None));
        assert_eq!(m.interface.quality, Quality::Perfect);
        // friStart on the 10th PERFECT cycle.
        let m = run(&mut sim, &mut t, 8, |_, _| Some(None));
        assert_eq!(m.interface.state, FriState::Monitor);
        let m = run(&mut sim, &mut t, 1, |_, _| Some(None));
        assert_eq!(m.interface.state, FriState::Command);
        let events = sim.take_events();
        assert!(events.iter().any(
            |e| matches!(e, SimEvent::StartedCommanding { at_s } if (*at_s - 0.109).abs() < 1e-9)
        ));
        assert_eq!(m.interface.stats.answer_rate, 1.0);
        assert!((m.interface.stats.latency_s - 100e-6).abs() < 1e-9);
        assert_eq!(m.interface.stats.miss_counter, 0);
        assert!((m.interface.timestamp_s - 0.109).abs() < 1e-6);
    }

    #[test]
    fn measurements_go_out_once_per_cycle_with_wrapping_sequence_numbers() {
        let mut sim = FriSimulator::new(SimConfig {
            initial_seq_count: 65534,
            cycle_s: 0.002,
            ..Default::default()
        })
        .unwrap();
        let t0 = Duration::from_millis(10);
        assert_eq!(sim.poll(t0).unwrap().send_seq_count, 65534);
        assert!(sim.poll(t0 + Duration::from_micros(1999)).is_none());
        assert_eq!(sim.next_send_time(), t0 + 2 * MS);
        assert_eq!(sim.poll(t0 + 2 * MS).unwrap().send_seq_count, 65535);
        assert_eq!(sim.poll(t0 + 4 * MS).unwrap().send_seq_count, 0);
        assert_eq!(sim.poll(t0 + 6 * MS).unwrap().send_seq_count, 1);
        // A stalled simulator sends one measurement and reschedules.
        let m = sim.poll(t0 + 20 * MS).unwrap();
        assert_eq!(m.send_seq_count, 2);
        assert_eq!(sim.counters().overruns, 1);
        assert_eq!(sim.next_send_time(), t0 + 22 * MS);
        assert_eq!(m.interface.desired_msr_sample_time_s, 0.002);
    }

    #[test]
    fn answers_across_the_wrap_are_matched() {
        let mut sim = FriSimulator::new(SimConfig {
            initial_seq_count: 65535,
            ..Default::default()
        })
        .unwrap();
        let mut t = Duration::ZERO;
        let m = run(&mut sim, &mut t, 3, |_, _| Some(None));
        assert_eq!(m.send_seq_count, 1);
        assert_eq!(sim.counters().duplicate_answers, 0);
        let m = sim.poll(t).unwrap();
        assert_eq!(m.refl_seq_count, 1);
        assert_eq!(m.interface.stats.answer_rate, 1.0);
    }

    #[test]
    fn command_mode_tracks_commands_and_reports_the_fri_offset() {
        let (mut sim, mut t) = started();
        let q0 = sim.joints_rad();
        // Move joint 0 at 0.5 rad/s for 100 ms.
        let m = run(&mut sim, &mut t, 100, |k, _| {
            let mut q = q0;
            q[0] += 0.5 * 0.001 * (k + 1) as f64;
            Some(Some(q))
        });
        // The measurement of cycle k shows the command of cycle k-1 (direct tracking).
        assert!((m.data.msr_jnt_pos[0] as f64 - (q0[0] + 0.5 * 0.099)).abs() < 1e-6);
        let m = sim.poll(t).unwrap();
        assert!((m.data.msr_jnt_pos[0] as f64 - (q0[0] + 0.05)).abs() < 1e-6);
        // The robot's own command stays; FRI adds the offset.
        assert!((m.data.cmd_jnt_pos[0] as f64 - q0[0]).abs() < 1e-6);
        assert!((m.data.cmd_jnt_pos_fri_offset[0] - 0.05).abs() < 1e-6);
        assert!((m.mirrored_jnt_pos()[0] as f64 - (q0[0] + 0.05)).abs() < 1e-6);
        assert_eq!(sim.state(), FriState::Command);
    }

    #[test]
    fn first_order_lag_approaches_the_command() {
        let mut sim = FriSimulator::new(SimConfig {
            tracking_time_constant_s: 0.01,
            ..Default::default()
        })
        .unwrap();
        let mut t = Duration::ZERO;
        run(&mut sim, &mut t, 150, |_, _| Some(None));
        assert_eq!(sim.state(), FriState::Command);
        let mut q = [0.0; JOINTS];
        // Ramp joint 2 to 0.01 rad, then hold for 10 ms (one time constant).
        run(&mut sim, &mut t, 10, |k, _| {
            q[2] = 0.001 * (k + 1) as f64;
            Some(Some(q))
        });
        let before = sim.joints_rad()[2];
        assert!(before < 0.01, "{before}");
        run(&mut sim, &mut t, 10, |_, _| Some(Some(q)));
        let after = sim.joints_rad()[2];
        let target = f64::from(0.01f32);
        let expected = target - (target - before) * (-1.0f64).exp();
        assert!((after - expected).abs() < 1e-9, "{after} vs {expected}");
    }

    #[test]
    fn withheld_answers_drop_to_monitor_and_stop_the_arm() {
        let (mut sim, mut t) = started();
        let q0 = sim.joints_rad();
        let mut q = q0;
        run(&mut sim, &mut t, 20, |_, _| {
            q[1] += 0.001; // 1 rad/s
            Some(Some(q))
        });
        // One missing answer is bridged by extrapolation: still CMD, still moving.
        let last_sent = f64::from(q[1] as f32);
        let m = run(&mut sim, &mut t, 2, |k, _| {
            if k == 0 {
                return None; // no answer
            }
            q[1] += 0.002;
            Some(Some(q))
        });
        assert_eq!(m.interface.state, FriState::Command);
        assert!((sim.joints_rad()[1] - (last_sent + 0.001)).abs() < 1e-6);
        assert!(sim
            .take_events()
            .iter()
            .all(|e| !matches!(e, SimEvent::DroppedToMonitor { .. })));
        // Answers stop: BAD after 2 misses, UNACCEPTABLE (drop) after 5.
        let mut states = Vec::new();
        run(&mut sim, &mut t, 7, |_, m| {
            states.push((m.interface.state, m.interface.quality));
            None
        });
        assert_eq!(states[2], (FriState::Command, Quality::Bad));
        assert_eq!(states[4], (FriState::Command, Quality::Bad));
        assert_eq!(states[5], (FriState::Monitor, Quality::Unacceptable));
        let reason = sim.drop_reason().unwrap();
        assert!(matches!(
            reason,
            DropReason::LinkQuality {
                quality: Quality::Unacceptable,
                consecutive_misses: 5,
                ..
            }
        ));
        // The arm stays where it stopped, and the robot's own command is that position.
        let stopped = sim.joints_rad();
        let m = run(&mut sim, &mut t, 50, |_, _| Some(Some(q0)));
        assert_eq!(sim.joints_rad(), stopped);
        assert_eq!(m.interface.state, FriState::Monitor);
        assert_eq!(m.data.cmd_jnt_pos, stopped.map(|v| v as f32));
        assert_eq!(m.data.cmd_jnt_pos_fri_offset, [0.0; JOINTS]);
        assert!(m.interface.stats.miss_counter >= 5);
        assert_eq!(sim.counters().drops_to_monitor, 1);
        // The KRL program does not restart by itself.
        run(&mut sim, &mut t, 200, |_, _| Some(None));
        assert_eq!(sim.state(), FriState::Monitor);
        sim.request_start();
        run(&mut sim, &mut t, 20, |_, _| Some(None));
        assert_eq!(sim.state(), FriState::Command);
    }

    /// A simulator whose KRL program loops around `friStart`, in command mode.
    fn looping_krl_in_command_mode() -> (FriSimulator, Duration) {
        let mut sim = FriSimulator::new(SimConfig {
            restart_after_drop: true,
            ..Default::default()
        })
        .unwrap();
        let mut t = Duration::from_secs(3);
        run(&mut sim, &mut t, 150, |_, _| Some(None));
        assert_eq!(sim.state(), FriState::Command);
        (sim, t)
    }

    #[test]
    fn a_krl_loop_restarts_command_mode_after_a_link_drop_only() {
        let (mut sim, mut t) = looping_krl_in_command_mode();
        // Five answers missed: the link drops the robot to monitor mode ...
        run(&mut sim, &mut t, 6, |_, _| None);
        assert_eq!(sim.state(), FriState::Monitor);
        let stopped = sim.joints_rad();
        // ... and the loop asks again: command mode once the misses left the window,
        // at the position where the arm stopped.
        run(&mut sim, &mut t, 50, |_, _| Some(None));
        assert_eq!(sim.state(), FriState::Monitor, "quality is not PERFECT yet");
        run(&mut sim, &mut t, 150, |_, _| Some(None));
        assert_eq!(sim.state(), FriState::Command);
        assert_eq!(sim.joints_rad(), stopped);
        assert_eq!(sim.counters().drops_to_monitor, 1);
        // friStop ends command mode for good.
        sim.request_stop(t);
        run(&mut sim, &mut t, 300, |_, _| Some(None));
        assert_eq!(sim.state(), FriState::Monitor);
    }

    #[test]
    fn a_release_request_stops_command_mode_until_it_clears() {
        let (mut sim, mut t) = looping_krl_in_command_mode();
        sim.take_events();
        // Mirroring answers with the release bit: friStop at the first, and no
        // friStart while the bit stays set, however good the link.
        let released = |sim: &mut FriSimulator, t: &mut Duration, cycles: usize| {
            for _ in 0..cycles {
                let m = sim.poll(*t).unwrap();
                let mut command =
                    CommandDatagram::decode(&answer(&m, m.send_seq_count, None)).unwrap();
                command.krl.bools = RELEASE_BIT;
                sim.receive(&command.encode(), *t + Duration::from_micros(100));
                *t += MS;
            }
        };
        released(&mut sim, &mut t, 1);
        assert_eq!(sim.state(), FriState::Monitor);
        assert_eq!(sim.drop_reason(), Some(DropReason::Released));
        released(&mut sim, &mut t, 300);
        assert_eq!(sim.state(), FriState::Monitor);
        assert_eq!(sim.counters().drops_to_monitor, 1);
        // A new session (bit clear): the KRL loop starts command mode again.
        run(&mut sim, &mut t, 150, |_, _| Some(None));
        assert_eq!(sim.state(), FriState::Command);
    }

    #[test]
    fn commands_at_joint_or_velocity_limits_drop_to_monitor() {
        let (mut sim, mut t) = started();
        let mut q = sim.joints_rad();
        q[3] = LBR4_POSITION_LIMIT_RAD[3] + 0.001;
        run(&mut sim, &mut t, 1, |_, _| Some(Some(q)));
        assert_eq!(
            sim.drop_reason(),
            Some(DropReason::JointLimit {
                joint: 3,
                commanded_rad: f64::from(q[3] as f32),
                limit_rad: LBR4_POSITION_LIMIT_RAD[3],
            })
        );
        assert_eq!(sim.state(), FriState::Monitor);

        let (mut sim, mut t) = started();
        let mut q = sim.joints_rad();
        // 0.004 rad in one 1 ms cycle is 4 rad/s, over joint 5's 3.21 rad/s.
        q[5] += 0.004;
        run(&mut sim, &mut t, 1, |_, _| Some(Some(q)));
        match sim.drop_reason() {
            Some(DropReason::VelocityLimit {
                joint: 5,
                speed_rad_s,
                limit_rad_s,
            }) => {
                assert!((speed_rad_s - 4.0).abs() < 1e-3, "{speed_rad_s}");
                assert_eq!(limit_rad_s, LBR4_VELOCITY_LIMIT_RAD_S[5]);
            }
            other => panic!("expected a velocity drop, got {other:?}"),
        }
        // Just under the limit is accepted.
        let (mut sim, mut t) = started();
        let mut q = sim.joints_rad();
        run(&mut sim, &mut t, 20, |_, _| {
            q[5] += 0.0032;
            Some(Some(q))
        });
        assert_eq!(sim.state(), FriState::Command);
    }

    #[test]
    fn flag_changes_in_command_mode_and_garbage_are_handled() {
        let (mut sim, mut t) = started();
        let m = sim.poll(t).unwrap();
        assert_eq!(sim.receive(&[1, 2, 3], t), Answer::Garbled);
        assert_eq!(sim.counters().bad_datagrams, 1);
        let mut cmd = CommandDatagram::decode(&answer(&m, 9, None)).unwrap();
        cmd.refl_seq_count = m.send_seq_count.wrapping_add(500);
        assert_eq!(sim.receive(&cmd.encode(), t), Answer::Unexpected);
        cmd.refl_seq_count = m.send_seq_count;
        cmd.cmd_flags = CmdFlags::JNT_POS | CmdFlags::JNT_STIFF;
        assert!(matches!(
            sim.receive(&cmd.encode(), t),
            Answer::InTime { .. }
        ));
        assert_eq!(sim.receive(&cmd.encode(), t), Answer::Duplicate);
        assert_eq!(
            sim.drop_reason(),
            Some(DropReason::FlagsChanged {
                latched: 0x1,
                received: 0x11
            })
        );
        t += MS;
        let _ = sim.poll(t);
        let events = sim.take_events();
        assert!(events
            .iter()
            .any(|e| matches!(e, SimEvent::BadDatagram { .. })));
        assert!(events
            .iter()
            .any(|e| matches!(e, SimEvent::UnexpectedAnswer { .. })));
    }

    #[test]
    fn late_answers_count_as_misses_but_are_timed() {
        let mut sim = FriSimulator::new(SimConfig {
            record_latencies: true,
            ..Default::default()
        })
        .unwrap();
        let t = Duration::ZERO;
        let m0 = sim.poll(t).unwrap();
        let _m1 = sim.poll(t + MS).unwrap();
        let late = sim.receive(&answer(&m0, 0, None), t + Duration::from_micros(1300));
        assert_eq!(late, Answer::Late { latency_s: 0.0013 });
        let m2 = sim.poll(t + 2 * MS).unwrap();
        assert_eq!(m2.interface.stats.miss_counter, 2);
        assert_eq!(m2.interface.stats.answer_rate, 0.0);
        assert_eq!(sim.latencies_s(), &[0.0013]);
        assert_eq!(sim.counters().late_answers, 1);
    }

    #[test]
    fn bad_configuration_is_named() {
        let err = FriSimulator::new(SimConfig {
            cycle_s: 0.0005,
            ..Default::default()
        })
        .unwrap_err();
        assert!(err.to_string().contains("cycle_s"), "{err}");
        let mut q = [0.0; JOINTS];
        q[1] = 2.5;
        let err = FriSimulator::new(SimConfig {
            initial_joints_rad: q,
            ..Default::default()
        })
        .unwrap_err();
        assert!(err.to_string().contains("initial_joints_rad[1]"), "{err}");
    }
}
