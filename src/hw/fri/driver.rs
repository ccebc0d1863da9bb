//! The PC side of FRI 1.x: answers every measurement of the LBR4+ within its cycle and
//! streams the joint positions of a time-parametrised [`Trajectory`].
//!
//! [`DriverCore`] is the protocol logic as a pure state machine (measurement and time
//! in, command and events out), tested without sockets. [`FriDriver`] runs it on a
//! UDP socket in a background thread that answers each measurement as soon as it
//! arrives, and offers blocking calls that all take a timeout.
//!
//! # Commanding
//! The driver sends its own joint positions only while the robot is in command mode,
//! its drives are powered and the link quality is at least
//! [`DriverConfig::min_command_quality`]. The default is BAD (issue 7: no commands
//! below quality BAD): the robot refuses commands only at UNACCEPTABLE, and
//! at BAD it still follows them, bridging a single missing answer by extrapolation.
//! The minimum may be raised to OK or PERFECT, never lowered below BAD.
//! Otherwise the driver mirrors the robot's own command, `cmdJntPos + cmdJntPosFriOffset`,
//! which moves nothing. On entering command mode it holds the mirrored position, so
//! the first command matches what the robot is doing. Trajectory time advances by
//! one measurement period per measurement (by the sequence-number gap when some were
//! lost), i.e. on the robot's clock.
//!
//! # Whom the driver answers
//! Only the robot controller: [`DriverConfig::robot`] (`fri.robot_addr` in
//! `robot/cell.toml`) names its IP address, or its address and port. A datagram
//! from any other sender is dropped before it is decoded, counted
//! ([`DriverCounters::foreign_datagrams`], reported as [`FriEvent::ForeignDatagram`]
//! at the 1st, 2nd, 4th, 8th, ... drop) and never answered, so no other process on
//! the KRC network can steer the commanded joint stream. A measurement whose
//! `sendSeqCount` is not newer than the last accepted one (equal, or up to half the
//! 16-bit range behind it, counting across the 65535 -> 0 wrap) is a replay or out of
//! order: it is dropped, counted ([`DriverCounters::stale_measurements`]) and not
//! answered, and it neither advances the trajectory nor changes the driver's view of
//! the robot.
//!
//! # What "stop" does to the hardware
//! - [`FriDriver::stop`] ends a motion with a synchronised deceleration within the
//!   trajectory's acceleration limits, then holds the rest position. The driver keeps
//!   answering every measurement: the drives stay powered and the brakes open, and
//!   the KRC's joint position (or impedance) controller holds the arm there. The
//!   driver never switches drives off or closes brakes; that is the KRC's business
//!   (`friStop`/`friClose` in the KRL program, or the operator's emergency stop).
//! - No measurement for `timeout_s` (a late packet) is a safe stop: the driver cannot
//!   send without a measurement to answer, so it reports
//!   [`FriEvent::MeasurementLate`], aborts the motion with [`FriError::MeasurementLate`]
//!   and holds its last command for when the link returns. The robot bridges one
//!   missing answer by extrapolation and then, as link quality falls, drops to
//!   monitor mode and stops the arm under its own control.
//! - When the robot leaves command mode (reported as [`FriEvent::DroppedToMonitor`])
//!   or the quality falls below the minimum, the motion is aborted and the driver
//!   mirrors the robot, which has already stopped the arm.
//! - Dropping the [`FriDriver`] stops answering; the robot then drops to monitor mode
//!   within a few cycles and holds. [`FriDriver::shutdown`] first stops any motion,
//!   then releases the robot: its commands set [`RELEASE_BIT`] of `boolData`
//!   (`$FRI_FRM_BOOL[1]` in KRL), and the cell's KRL program answers with `friStop`,
//!   so the robot leaves command mode on request instead of by a failing link.

use super::datagram::{
    seq_ahead, CmdFlags, CommandDatagram, ControlMode, DatagramError, FriState, KrlData, LinkStats,
    MeasurementDatagram, Quality,
};
use super::{DEFAULT_PORT, JOINTS};
use crate::clock::Clock;
use crate::trajectory::{StopProfile, Trajectory};
use serde::Serialize;
use std::collections::VecDeque;
use std::net::{IpAddr, Ipv4Addr, SocketAddr, UdpSocket};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Condvar, Mutex, MutexGuard};
use std::thread::JoinHandle;
use std::time::Duration;

/// Bit of the command's KRL `boolData` (`$FRI_FRM_BOOL[1]`) by which the PC releases
/// the robot: the cell's KRL program calls `friStop` while it is set, and `friStart`
/// again (once quality is PERFECT) only when it is clear. graspcell's convention,
/// not part of FRI.
pub const RELEASE_BIT: u16 = 1 << 0;

/// Most recent events kept; older ones are counted and dropped.
const EVENT_CAPACITY: usize = 4096;

/// Errors of the FRI driver; each carries the numbers that explain it.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum FriError {
    /// A configuration value is out of range.
    #[error("FRI driver: {field} = {value}: {problem}")]
    BadConfig {
        /// The field.
        field: &'static str,
        /// The offending value, as text.
        value: String,
        /// What is wrong with it.
        problem: &'static str,
    },
    /// A socket operation failed.
    #[error("FRI driver: {op} {addr}: {message}")]
    Io {
        /// What was being done.
        op: &'static str,
        /// The address involved.
        addr: SocketAddr,
        /// The kind of I/O error.
        kind: std::io::ErrorKind,
        /// The I/O error's message.
        message: String,
    },
    /// No measurement arrived for `timeout_s`: the motion was aborted and the arm held.
    #[error("no FRI measurement for {waited_s:.3} s (timeout {timeout_s} s): motion aborted, holding the last command")]
    MeasurementLate {
        /// Time since the last measurement (s).
        waited_s: f64,
        /// The configured timeout (s).
        timeout_s: f64,
    },
    /// The robot left command mode during a motion (it stops the arm itself).
    #[error("robot left command mode (now {state:?}, quality {quality:?}): motion aborted")]
    LeftCommandMode {
        /// The robot's state now.
        state: FriState,
        /// The link quality now.
        quality: Quality,
    },
    /// The link quality is below the minimum for commanding.
    #[error("link quality {quality:?} is below {min:?}: not commanding")]
    QualityTooLow {
        /// The quality now.
        quality: Quality,
        /// The configured minimum.
        min: Quality,
    },
    /// The robot cannot be commanded now.
    #[error("robot not commandable: state {state:?}, quality {quality:?}, power {power:#06x}")]
    NotCommanding {
        /// The robot's state (OFF before the first measurement).
        state: FriState,
        /// The link quality.
        quality: Quality,
        /// The drive power bits (0 = unpowered).
        power: u16,
    },
    /// A motion is already running.
    #[error("motion {id} is still running; stop it or wait for it first")]
    Busy {
        /// The running motion.
        id: u64,
    },
    /// The trajectory does not start where the arm is commanded.
    #[error("trajectory starts joint {joint} at {start_rad} rad but it is commanded at {current_rad} rad (tolerance {tolerance_rad} rad)")]
    StartMismatch {
        /// Zero-based joint index.
        joint: usize,
        /// The trajectory's start (rad).
        start_rad: f64,
        /// The commanded position (rad).
        current_rad: f64,
        /// The allowed difference (rad).
        tolerance_rad: f64,
    },
    /// A blocking call ran out of time (a motion is stopped first).
    #[error("timed out after {timeout_s} s waiting for {what}")]
    Timeout {
        /// What was awaited.
        what: String,
        /// The timeout (s).
        timeout_s: f64,
    },
    /// The motion was stopped on request.
    #[error("motion {id} stopped on request")]
    Stopped {
        /// The motion.
        id: u64,
    },
    /// No such motion was started.
    #[error("no motion {id}")]
    UnknownMotion {
        /// The id asked about.
        id: u64,
    },
    /// The driver's thread has ended.
    #[error("FRI driver has shut down")]
    ShutDown,
    /// A guarded motion met its force threshold and was stopped (decelerate,
    /// then hold): contact.
    #[error("motion {id} stopped on contact: external TCP force {force_n:.2} N over its start (threshold {threshold_n} N)")]
    Contact {
        /// The motion.
        id: u64,
        /// Magnitude of the estimated external TCP force over its value at the
        /// motion's start (N).
        force_n: f64,
        /// The threshold (N).
        threshold_n: f64,
    },
}

/// A guard on a motion: stop (decelerate, then hold) at the first measurement
/// whose estimated external TCP force (`estExtTcpFT`, force part) differs from
/// its value at the motion's start by more than `threshold_n`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ForceGuard {
    /// The contact force (N), > 0.
    pub threshold_n: f64,
}

/// The force part of `estExtTcpFT` (N).
fn tcp_force(m: &MeasurementDatagram) -> [f64; 3] {
    std::array::from_fn(|i| f64::from(m.data.est_ext_tcp_ft[i]))
}

/// What the driver saw or did; also logged via `tracing`.
#[derive(Debug, Clone, PartialEq)]
pub enum FriEvent {
    /// The robot's FRI state changed.
    StateChanged {
        /// Before.
        from: FriState,
        /// After.
        to: FriState,
        /// `sendSeqCount` of the measurement that showed it.
        seq: u16,
    },
    /// The robot left command mode as the driver asked ([`RELEASE_BIT`]).
    Released {
        /// `sendSeqCount` of the measurement that showed it.
        seq: u16,
    },
    /// The robot left command mode.
    DroppedToMonitor {
        /// The robot's state now.
        state: FriState,
        /// The link quality now.
        quality: Quality,
        /// Whether a motion was running.
        during_motion: bool,
        /// `sendSeqCount` of the measurement that showed it.
        seq: u16,
    },
    /// The link quality changed.
    QualityChanged {
        /// Before.
        from: Quality,
        /// After.
        to: Quality,
        /// `sendSeqCount` of the measurement that showed it.
        seq: u16,
    },
    /// Sequence numbers were skipped: measurements were lost.
    MeasurementsMissed {
        /// The last measurement before the gap.
        after_seq: u16,
        /// The first after it.
        received_seq: u16,
        /// How many are missing.
        missed: u16,
    },
    /// A datagram from a sender other than the robot was dropped unanswered
    /// (reported at the 1st, 2nd, 4th, ... drop so a flood cannot flood the log).
    ForeignDatagram {
        /// Its sender.
        from: SocketAddr,
        /// The robot the driver is pinned to.
        robot: RobotPeer,
        /// Foreign datagrams dropped so far.
        dropped: u64,
    },
    /// A measurement older than or equal to the latest arrived and was ignored.
    StaleMeasurement {
        /// Its `sendSeqCount`.
        seq: u16,
        /// The latest `sendSeqCount`.
        latest_seq: u16,
    },
    /// After a silence the robot's sequence numbers started over (FRI reopened on
    /// the KRC); counting goes on from `seq`.
    SequenceRestarted {
        /// The first accepted `sendSeqCount` of the new count.
        seq: u16,
        /// The latest `sendSeqCount` of the old count.
        latest_seq: u16,
    },
    /// No measurement for `timeout_s`: motion aborted, holding.
    MeasurementLate {
        /// Time since the last measurement (s).
        waited_s: f64,
        /// The configured timeout (s).
        timeout_s: f64,
    },
    /// Measurements arrive again after being late.
    LinkRestored {
        /// Length of the gap (s).
        after_s: f64,
    },
    /// A received datagram was not a valid measurement (ignored).
    BadDatagram {
        /// What was wrong.
        error: DatagramError,
    },
    /// A measurement's sample time is unusable (ignored).
    BadSampleTime {
        /// `desiredMsrSampleTime` (s).
        value_s: f32,
    },
    /// Sending or receiving failed.
    SocketError {
        /// The error.
        error: FriError,
    },
    /// A motion reached its end.
    MotionFinished {
        /// The motion.
        id: u64,
    },
    /// A motion ended early.
    MotionAborted {
        /// The motion.
        id: u64,
        /// Why.
        error: FriError,
    },
}

/// The robot controller the driver answers: every datagram from anyone else is
/// dropped unanswered.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
pub enum RobotPeer {
    /// Any port of this IP address (`fri.robot_addr = "192.168.0.10"`).
    Host(IpAddr),
    /// Exactly this address and port (`fri.robot_addr = "192.168.0.10:49938"`).
    Exact(SocketAddr),
}

impl RobotPeer {
    /// Whether a datagram from `from` comes from the robot. IPv4 senders seen on a
    /// dual-stack IPv6 socket (`::ffff:a.b.c.d`) compare as IPv4.
    pub fn admits(&self, from: SocketAddr) -> bool {
        let ip = from.ip().to_canonical();
        match *self {
            RobotPeer::Host(host) => ip == host.to_canonical(),
            RobotPeer::Exact(addr) => ip == addr.ip().to_canonical() && from.port() == addr.port(),
        }
    }
}

impl std::str::FromStr for RobotPeer {
    type Err = FriError;

    fn from_str(text: &str) -> Result<RobotPeer, FriError> {
        let text = text.trim();
        if let Ok(addr) = text.parse::<SocketAddr>() {
            Ok(RobotPeer::Exact(addr))
        } else if let Ok(ip) = text.parse::<IpAddr>() {
            Ok(RobotPeer::Host(ip))
        } else {
            Err(FriError::BadConfig {
                field: "fri.robot_addr",
                value: text.to_string(),
                problem: "not an IP address (the robot controller's, e.g. 192.168.0.10) or an IP address with port (192.168.0.10:49938)",
            })
        }
    }
}

impl std::fmt::Display for RobotPeer {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            RobotPeer::Host(ip) => write!(f, "{ip} (any port)"),
            RobotPeer::Exact(addr) => write!(f, "{addr}"),
        }
    }
}

/// Settings of the driver.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DriverConfig {
    /// Local UDP address to bind (FRI default port 49938; port 0 picks a free one).
    pub bind_addr: SocketAddr,
    /// The robot controller; datagrams from anyone else are dropped unanswered.
    pub robot: RobotPeer,
    /// A measurement missing for this long is a safe stop (s).
    pub timeout_s: f64,
    /// Lowest link quality at which the driver commands (BAD, OK or PERFECT).
    pub min_command_quality: Quality,
    /// Largest distance between a trajectory's start and the commanded position (rad).
    pub start_tolerance_rad: f64,
}

impl Default for DriverConfig {
    fn default() -> DriverConfig {
        DriverConfig {
            bind_addr: SocketAddr::new(IpAddr::V4(Ipv4Addr::UNSPECIFIED), DEFAULT_PORT),
            // The simulator's host; a cell's configuration always names its robot.
            robot: RobotPeer::Host(IpAddr::V4(Ipv4Addr::LOCALHOST)),
            timeout_s: 0.1,
            min_command_quality: Quality::Bad,
            start_tolerance_rad: 1e-4,
        }
    }
}

impl DriverConfig {
    /// The driver settings of the cell configuration's `[fri]` section.
    pub fn from_cell(fri: &crate::config::FriConfig) -> Result<DriverConfig, FriError> {
        let bind_addr = fri.bind_addr.parse().map_err(|_| FriError::BadConfig {
            field: "fri.bind_addr",
            value: fri.bind_addr.clone(),
            problem: "not an IP address with port, e.g. 127.0.0.1:49938",
        })?;
        let config = DriverConfig {
            bind_addr,
            robot: fri.robot_addr.parse()?,
            timeout_s: fri.timeout_s,
            ..DriverConfig::default()
        };
        config.validate()?;
        Ok(config)
    }

    /// Checks every value is in range.
    pub fn validate(&self) -> Result<(), FriError> {
        if !(self.timeout_s.is_finite() && self.timeout_s > 0.0) {
            return Err(FriError::BadConfig {
                field: "timeout_s",
                value: self.timeout_s.to_string(),
                problem: "must be a finite number > 0",
            });
        }
        if self.min_command_quality < Quality::Bad {
            return Err(FriError::BadConfig {
                field: "min_command_quality",
                value: format!("{:?}", self.min_command_quality),
                problem: "never command below BAD",
            });
        }
        if !(self.start_tolerance_rad.is_finite() && self.start_tolerance_rad >= 0.0) {
            return Err(FriError::BadConfig {
                field: "start_tolerance_rad",
                value: self.start_tolerance_rad.to_string(),
                problem: "must be a finite number >= 0",
            });
        }
        Ok(())
    }
}

/// Cumulative counters of the driver.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize)]
pub struct DriverCounters {
    /// Valid measurements received.
    pub measurements: u64,
    /// Commands sent.
    pub answers: u64,
    /// Answers deliberately withheld (fault injection).
    pub withheld: u64,
    /// Measurements lost (sequence gaps).
    pub missed_measurements: u64,
    /// Times no measurement came for `timeout_s`.
    pub late: u64,
    /// Datagrams from the robot that were not valid measurements.
    pub bad_datagrams: u64,
    /// Datagrams from senders other than the robot (dropped unanswered).
    pub foreign_datagrams: u64,
    /// Measurements whose sequence number was not newer than the last accepted
    /// (replayed or out of order; dropped unanswered).
    pub stale_measurements: u64,
    /// Events discarded because nobody collected them.
    pub events_discarded: u64,
}

/// A snapshot of the link and the arm as the driver sees it.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct FriStatus {
    /// The robot's FRI state (OFF before the first measurement).
    pub state: FriState,
    /// Link quality.
    pub quality: Quality,
    /// Drive power bits (0 = unpowered).
    pub power: u16,
    /// The robot's controller.
    pub control: ControlMode,
    /// Whether the driver sends its own positions (else it mirrors the robot).
    pub commanding: bool,
    /// The running motion, if any.
    pub motion_id: Option<u64>,
    /// Measured joint positions (rad).
    pub measured_rad: [f64; JOINTS],
    /// The joint positions last sent (rad).
    pub commanded_rad: [f64; JOINTS],
    /// `sendSeqCount` of the last measurement.
    pub last_seq: Option<u16>,
    /// Whether measurements are overdue.
    pub late: bool,
    /// The robot's link statistics.
    pub link: LinkStats,
    /// Cumulative counters.
    pub counters: DriverCounters,
    /// The robot's estimated external force and torque at the tool
    /// (`estExtTcpFT`: Fx Fy Fz N, Tz Ty Tx N m) in the last measurement.
    pub est_ext_tcp_ft: [f64; 6],
    /// Whether the arm still moves under the driver's command (following a
    /// trajectory or braking to rest).
    pub moving: bool,
}

#[derive(Debug, Clone)]
enum Motion {
    /// Not commanding: mirror the robot.
    Mirror,
    /// Command a fixed position.
    Hold([f64; JOINTS]),
    /// Follow a trajectory; `t_s` is the time of the last commanded sample.
    Follow {
        id: u64,
        trajectory: Box<Trajectory<JOINTS>>,
        t_s: f64,
        /// The guard and the TCP force at the start.
        guard: Option<(ForceGuard, [f64; 3])>,
    },
    /// Decelerate to rest, then hold.
    Brake {
        profile: StopProfile<JOINTS>,
        t_s: f64,
    },
}

/// The driver's protocol logic: a pure function of measurements, times and requests.
#[derive(Debug)]
pub struct DriverCore {
    config: DriverConfig,
    send_seq: u16,
    last: Option<MeasurementDatagram>,
    last_rx: Option<Duration>,
    late: bool,
    /// While late: the last stale sequence number, the first of a possible restart.
    restart_seq: Option<u16>,
    motion: Motion,
    commanding: bool,
    commanded_rad: [f64; JOINTS],
    next_id: u64,
    /// Outcome of the most recent finished motion.
    outcome: Option<(u64, Result<(), FriError>)>,
    withhold: bool,
    /// Commands ask the KRL program to leave command mode ([`RELEASE_BIT`]).
    release: bool,
    events: VecDeque<FriEvent>,
    counters: DriverCounters,
}

impl DriverCore {
    /// A driver that has not yet seen the robot.
    pub fn new(config: DriverConfig) -> Result<DriverCore, FriError> {
        config.validate()?;
        Ok(DriverCore {
            config,
            send_seq: 0,
            last: None,
            last_rx: None,
            late: false,
            restart_seq: None,
            motion: Motion::Mirror,
            commanding: false,
            commanded_rad: [0.0; JOINTS],
            next_id: 1,
            outcome: None,
            withhold: false,
            release: false,
            events: VecDeque::new(),
            counters: DriverCounters::default(),
        })
    }

    /// The configuration.
    pub fn config(&self) -> &DriverConfig {
        &self.config
    }

    fn push(&mut self, event: FriEvent) {
        match &event {
            FriEvent::DroppedToMonitor { .. }
            | FriEvent::MeasurementLate { .. }
            | FriEvent::MotionAborted { .. }
            | FriEvent::SocketError { .. }
            | FriEvent::ForeignDatagram { .. }
            | FriEvent::BadDatagram { .. } => tracing::warn!("FRI: {event:?}"),
            _ => tracing::info!("FRI: {event:?}"),
        }
        if self.events.len() == EVENT_CAPACITY {
            self.events.pop_front();
            self.counters.events_discarded += 1;
        }
        self.events.push_back(event);
    }

    /// Removes and returns the events so far (oldest first).
    pub fn take_events(&mut self) -> Vec<FriEvent> {
        self.events.drain(..).collect()
    }

    fn finish(&mut self, id: u64, result: Result<(), FriError>) {
        match &result {
            Ok(()) => self.push(FriEvent::MotionFinished { id }),
            Err(error) => self.push(FriEvent::MotionAborted {
                id,
                error: error.clone(),
            }),
        }
        self.outcome = Some((id, result));
    }

    fn running_id(&self) -> Option<u64> {
        match self.motion {
            Motion::Follow { id, .. } => Some(id),
            _ => None,
        }
    }

    /// Ends a running trajectory (not a stop in progress) with `error`.
    fn abort(&mut self, error: FriError) {
        if let Some(id) = self.running_id() {
            self.finish(id, Err(error));
        }
    }

    /// Whether `m` lets the driver command, and if not, why.
    fn commandable(&self, m: &MeasurementDatagram) -> Result<(), FriError> {
        let (state, quality, power) = (m.interface.state, m.interface.quality, m.robot.power);
        if state != FriState::Command || power == 0 {
            Err(FriError::NotCommanding {
                state,
                quality,
                power,
            })
        } else if quality < self.config.min_command_quality {
            Err(FriError::QualityTooLow {
                quality,
                min: self.config.min_command_quality,
            })
        } else {
            Ok(())
        }
    }

    /// Takes in one measurement received at `now`; returns the command to send back
    /// to its sender, or `None` when it must not be answered (stale, unusable, or
    /// answers are being withheld).
    pub fn on_measurement(
        &mut self,
        m: &MeasurementDatagram,
        now: Duration,
    ) -> Option<CommandDatagram> {
        let seq = m.send_seq_count;
        let gap = match &self.last {
            Some(prev) => {
                let gap = seq_ahead(seq, prev.send_seq_count);
                let stale = gap == 0 || gap > u16::MAX / 2;
                // After a silence (the link is late: motion aborted, holding), two
                // consecutive "old" numbers are the robot's counter starting over
                // (FRI closed and reopened on the KRC), not stale datagrams.
                let restarted = stale
                    && self.late
                    && self.restart_seq.is_some_and(|r| seq == r.wrapping_add(1));
                if restarted {
                    self.push(FriEvent::SequenceRestarted {
                        seq,
                        latest_seq: prev.send_seq_count,
                    });
                    self.restart_seq = None;
                    1
                } else if stale {
                    self.restart_seq = self.late.then_some(seq);
                    self.counters.stale_measurements += 1;
                    self.push(FriEvent::StaleMeasurement {
                        seq,
                        latest_seq: prev.send_seq_count,
                    });
                    return None;
                } else {
                    gap
                }
            }
            None => 1,
        };
        self.restart_seq = None;
        // The period travels as f32; FRI periods are whole milliseconds, so round to µs.
        let dt_s = (f64::from(m.interface.desired_msr_sample_time_s) * 1e6).round() / 1e6;
        if !(dt_s > 0.0 && dt_s <= 1.0) {
            self.push(FriEvent::BadSampleTime {
                value_s: m.interface.desired_msr_sample_time_s,
            });
            return None;
        }
        self.counters.measurements += 1;
        if self.late {
            self.late = false;
            let after_s = now
                .saturating_sub(self.last_rx.unwrap_or(now))
                .as_secs_f64();
            self.push(FriEvent::LinkRestored { after_s });
        }
        let (prev_state, prev_quality, prev_seq) = self.last.as_ref().map_or(
            (FriState::Off, Quality::Unacceptable, seq.wrapping_sub(1)),
            |p| (p.interface.state, p.interface.quality, p.send_seq_count),
        );
        if gap > 1 {
            self.counters.missed_measurements += u64::from(gap - 1);
            self.push(FriEvent::MeasurementsMissed {
                after_seq: prev_seq,
                received_seq: seq,
                missed: gap - 1,
            });
        }
        let (state, quality) = (m.interface.state, m.interface.quality);
        if state != prev_state {
            self.push(FriEvent::StateChanged {
                from: prev_state,
                to: state,
                seq,
            });
            if prev_state == FriState::Command && self.release {
                self.push(FriEvent::Released { seq });
            } else if prev_state == FriState::Command {
                let during_motion = !matches!(self.motion, Motion::Mirror | Motion::Hold(_));
                self.push(FriEvent::DroppedToMonitor {
                    state,
                    quality,
                    during_motion,
                    seq,
                });
            }
        }
        if quality != prev_quality {
            self.push(FriEvent::QualityChanged {
                from: prev_quality,
                to: quality,
                seq,
            });
        }
        self.last = Some(*m);
        self.last_rx = Some(now);

        let mirrored = m.mirrored_jnt_pos().map(f64::from);
        let target = match self.commandable(m) {
            Err(why) => {
                if !matches!(self.motion, Motion::Mirror) {
                    let error = match why {
                        FriError::NotCommanding { state, quality, .. } => {
                            FriError::LeftCommandMode { state, quality }
                        }
                        other => other,
                    };
                    self.abort(error);
                    self.motion = Motion::Mirror;
                }
                self.commanding = false;
                mirrored
            }
            Ok(()) => {
                self.commanding = true;
                self.check_guard(m);
                self.advance(f64::from(gap) * dt_s, mirrored)
            }
        };
        self.commanded_rad = target.map(|v| f64::from(v as f32));
        self.send_seq = self.send_seq.wrapping_add(1);
        let command = CommandDatagram {
            send_seq_count: self.send_seq,
            refl_seq_count: seq,
            cmd_flags: CmdFlags::JNT_POS,
            jnt_pos: target.map(|v| v as f32),
            krl: KrlData {
                bools: if self.release { RELEASE_BIT } else { 0 },
                ..KrlData::default()
            },
            ..Default::default()
        };
        if self.withhold {
            self.counters.withheld += 1;
            None
        } else {
            self.counters.answers += 1;
            Some(command)
        }
    }

    /// Stops a guarded motion whose force threshold `m` exceeds.
    fn check_guard(&mut self, m: &MeasurementDatagram) {
        let Motion::Follow {
            id,
            guard: Some((guard, start)),
            ..
        } = &self.motion
        else {
            return;
        };
        let f = tcp_force(m);
        let force_n = (0..3)
            .map(|i| (f[i] - start[i]).powi(2))
            .sum::<f64>()
            .sqrt();
        if force_n > guard.threshold_n {
            let (id, threshold_n) = (*id, guard.threshold_n);
            self.brake();
            self.finish(
                id,
                Err(FriError::Contact {
                    id,
                    force_n,
                    threshold_n,
                }),
            );
        }
    }

    /// Moves the motion on by `dt_s` and returns the position to command.
    fn advance(&mut self, dt_s: f64, mirrored: [f64; JOINTS]) -> [f64; JOINTS] {
        match &mut self.motion {
            Motion::Mirror => {
                self.motion = Motion::Hold(mirrored);
                mirrored
            }
            Motion::Hold(q) => *q,
            Motion::Follow {
                id,
                trajectory,
                t_s,
                ..
            } => {
                *t_s += dt_s;
                if *t_s >= trajectory.duration_s() {
                    let (id, end) = (*id, trajectory.end());
                    self.motion = Motion::Hold(end);
                    self.finish(id, Ok(()));
                    end
                } else {
                    trajectory.sample(*t_s).position
                }
            }
            Motion::Brake { profile, t_s } => {
                *t_s += dt_s;
                let q = profile.sample(*t_s).position;
                if *t_s >= profile.duration_s() {
                    self.motion = Motion::Hold(q);
                }
                q
            }
        }
    }

    /// Takes in one datagram from `from` received at `now`: dropped (counted, never
    /// answered) unless it comes from the robot ([`DriverConfig::robot`]), then
    /// decoded and handled as [`DriverCore::on_measurement`]. Returns the command
    /// to send back to `from`, if any.
    pub fn on_datagram(
        &mut self,
        bytes: &[u8],
        from: SocketAddr,
        now: Duration,
    ) -> Option<CommandDatagram> {
        if !self.config.robot.admits(from) {
            self.counters.foreign_datagrams += 1;
            let dropped = self.counters.foreign_datagrams;
            if dropped.is_power_of_two() {
                self.push(FriEvent::ForeignDatagram {
                    from,
                    robot: self.config.robot,
                    dropped,
                });
            }
            return None;
        }
        match MeasurementDatagram::decode(bytes) {
            Ok(m) => self.on_measurement(&m, now),
            Err(error) => {
                self.on_bad_datagram(error);
                None
            }
        }
    }

    /// Reports a datagram that failed to decode.
    pub fn on_bad_datagram(&mut self, error: DatagramError) {
        self.counters.bad_datagrams += 1;
        self.push(FriEvent::BadDatagram { error });
    }

    /// Checks for a late measurement at `now`; the first time one is overdue by
    /// `timeout_s` this reports it, aborts the motion and holds. Returns whether it
    /// did so now.
    pub fn check_late(&mut self, now: Duration) -> bool {
        let Some(last_rx) = self.last_rx else {
            return false;
        };
        let waited_s = now.saturating_sub(last_rx).as_secs_f64();
        if self.late || waited_s < self.config.timeout_s {
            return false;
        }
        self.late = true;
        self.counters.late += 1;
        let timeout_s = self.config.timeout_s;
        self.push(FriEvent::MeasurementLate {
            waited_s,
            timeout_s,
        });
        self.abort(FriError::MeasurementLate {
            waited_s,
            timeout_s,
        });
        if !matches!(self.motion, Motion::Mirror) {
            self.motion = Motion::Hold(self.commanded_rad);
        }
        true
    }

    /// Starts following `trajectory` from the next measurement. It must start (within
    /// `start_tolerance_rad`) where the arm is commanded, the robot must be
    /// commandable and no other motion running. Returns the motion's id.
    pub fn start_trajectory(&mut self, trajectory: Trajectory<JOINTS>) -> Result<u64, FriError> {
        self.start_motion(trajectory, None)
    }

    /// [`DriverCore::start_trajectory`] with a force guard: the motion stops
    /// (decelerates, then holds) at the first measurement whose external TCP force
    /// exceeds `guard` over the force when it started, and ends with
    /// [`FriError::Contact`].
    pub fn start_guarded_trajectory(
        &mut self,
        trajectory: Trajectory<JOINTS>,
        guard: ForceGuard,
    ) -> Result<u64, FriError> {
        if !(guard.threshold_n.is_finite() && guard.threshold_n > 0.0) {
            return Err(FriError::BadConfig {
                field: "force guard threshold_n",
                value: guard.threshold_n.to_string(),
                problem: "must be a finite force > 0",
            });
        }
        self.start_motion(trajectory, Some(guard))
    }

    fn start_motion(
        &mut self,
        trajectory: Trajectory<JOINTS>,
        guard: Option<ForceGuard>,
    ) -> Result<u64, FriError> {
        if let Some(id) = self.running_id() {
            return Err(FriError::Busy { id });
        }
        let Some(m) = self.last.filter(|_| !self.late) else {
            return Err(FriError::NotCommanding {
                state: self.last.map_or(FriState::Off, |m| m.interface.state),
                quality: self
                    .last
                    .map_or(Quality::Unacceptable, |m| m.interface.quality),
                power: self.last.map_or(0, |m| m.robot.power),
            });
        };
        self.commandable(&m)?;
        let current = match &self.motion {
            Motion::Hold(q) => *q,
            _ => m.mirrored_jnt_pos().map(f64::from),
        };
        let start = trajectory.start();
        let tolerance_rad = self.config.start_tolerance_rad;
        for joint in 0..JOINTS {
            if (start[joint] - current[joint]).abs() > tolerance_rad {
                return Err(FriError::StartMismatch {
                    joint,
                    start_rad: start[joint],
                    current_rad: current[joint],
                    tolerance_rad,
                });
            }
        }
        let id = self.next_id;
        self.next_id += 1;
        self.motion = Motion::Follow {
            id,
            trajectory: Box::new(trajectory),
            t_s: 0.0,
            guard: guard.map(|g| (g, tcp_force(&m))),
        };
        Ok(id)
    }

    /// Stops a running trajectory: decelerates to rest within its acceleration
    /// limits, then holds. The motion ends with [`FriError::Stopped`].
    pub fn stop(&mut self) {
        if let Some(id) = self.brake() {
            self.finish(id, Err(FriError::Stopped { id }));
        }
    }

    /// Turns a running trajectory into a stop profile (decelerate within its
    /// limits, then hold); returns its id.
    fn brake(&mut self) -> Option<u64> {
        let Motion::Follow {
            id,
            trajectory,
            t_s,
            ..
        } = &self.motion
        else {
            return None;
        };
        let now = trajectory.sample(*t_s);
        let profile = StopProfile::new(now.position, now.velocity, trajectory.limits());
        let id = *id;
        self.motion = Motion::Brake { profile, t_s: 0.0 };
        Some(id)
    }

    /// Whether the arm is still moving under the driver's command (following or braking).
    pub fn is_moving(&self) -> bool {
        matches!(self.motion, Motion::Follow { .. } | Motion::Brake { .. })
    }

    /// The outcome of motion `id` once it has ended.
    pub fn outcome(&self, id: u64) -> Option<Result<(), FriError>> {
        if id == 0 || id >= self.next_id {
            return Some(Err(FriError::UnknownMotion { id }));
        }
        match &self.outcome {
            Some((done, result)) if *done == id => Some(result.clone()),
            // An older motion ended before the latest one started.
            Some((done, _)) if *done > id => Some(Ok(())),
            _ => None,
        }
    }

    /// Stops any motion and asks the robot to leave command mode ([`RELEASE_BIT`] in
    /// every command from now on).
    pub fn release(&mut self) {
        self.stop();
        self.release = true;
    }

    /// Whether the robot is released: the driver asked for it and the robot is out
    /// of command mode, or the link is gone (nothing left to release).
    pub fn is_released(&self) -> bool {
        self.release
            && (self.late
                || self
                    .last
                    .is_none_or(|m| m.interface.state != FriState::Command))
    }

    /// Withholds (`true`) or resumes answers: fault injection for tests.
    pub fn set_withhold_answers(&mut self, withhold: bool) {
        self.withhold = withhold;
    }

    /// A snapshot of the link and the arm.
    pub fn status(&self) -> FriStatus {
        let m = self.last.unwrap_or_default();
        FriStatus {
            state: m.interface.state,
            quality: m.interface.quality,
            power: m.robot.power,
            control: m.robot.control,
            commanding: self.commanding && !self.late,
            motion_id: self.running_id(),
            measured_rad: m.data.msr_jnt_pos.map(f64::from),
            commanded_rad: self.commanded_rad,
            last_seq: self.last.map(|m| m.send_seq_count),
            late: self.late,
            link: m.interface.stats,
            counters: self.counters,
            est_ext_tcp_ft: m.data.est_ext_tcp_ft.map(f64::from),
            moving: self.is_moving(),
        }
    }
}

struct Shared {
    core: Mutex<DriverCore>,
    changed: Condvar,
    stop: AtomicBool,
    alive: AtomicBool,
}

impl Shared {
    fn lock(&self) -> MutexGuard<'_, DriverCore> {
        self.core.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// Waits until `done` holds or `timeout_s` passes; `None` on timeout.
    fn wait<R>(
        &self,
        timeout_s: f64,
        mut done: impl FnMut(&mut DriverCore) -> Option<R>,
    ) -> Result<Option<R>, FriError> {
        let deadline = std::time::Instant::now() + Duration::from_secs_f64(timeout_s.max(0.0));
        let mut core = self.lock();
        loop {
            if let Some(r) = done(&mut core) {
                return Ok(Some(r));
            }
            if !self.alive.load(Ordering::Relaxed) {
                return Err(FriError::ShutDown);
            }
            let now = std::time::Instant::now();
            if now >= deadline {
                return Ok(None);
            }
            // Wake at least every 50 ms to notice a dead thread.
            let wait = (deadline - now).min(Duration::from_millis(50));
            core = self
                .changed
                .wait_timeout(core, wait)
                .unwrap_or_else(|e| e.into_inner())
                .0;
        }
    }
}

/// The FRI driver on a UDP socket, answering measurements in a background thread.
pub struct FriDriver {
    shared: Arc<Shared>,
    local_addr: SocketAddr,
    thread: Option<JoinHandle<()>>,
}

impl std::fmt::Debug for FriDriver {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("FriDriver")
            .field("local_addr", &self.local_addr)
            .finish_non_exhaustive()
    }
}

fn io_error(op: &'static str, addr: SocketAddr, e: &std::io::Error) -> FriError {
    FriError::Io {
        op,
        addr,
        kind: e.kind(),
        message: e.to_string(),
    }
}

impl FriDriver {
    /// Binds `config.bind_addr` and starts answering measurements; `clock` times
    /// the late-measurement check.
    pub fn start(config: DriverConfig, clock: Arc<dyn Clock>) -> Result<FriDriver, FriError> {
        let core = DriverCore::new(config)?;
        let socket = UdpSocket::bind(config.bind_addr)
            .map_err(|e| io_error("bind", config.bind_addr, &e))?;
        let local_addr = socket
            .local_addr()
            .map_err(|e| io_error("query local address of", config.bind_addr, &e))?;
        // Wake often enough to notice a late measurement and a shutdown.
        let poll = Duration::from_secs_f64((config.timeout_s / 4.0).clamp(0.001, 0.02));
        socket
            .set_read_timeout(Some(poll))
            .map_err(|e| io_error("set read timeout on", local_addr, &e))?;
        let shared = Arc::new(Shared {
            core: Mutex::new(core),
            changed: Condvar::new(),
            stop: AtomicBool::new(false),
            alive: AtomicBool::new(true),
        });
        let thread = {
            let shared = Arc::clone(&shared);
            std::thread::Builder::new()
                .name("fri-driver".into())
                .spawn(move || {
                    serve(&shared, &socket, clock.as_ref());
                    shared.alive.store(false, Ordering::Relaxed);
                    shared.changed.notify_all();
                })
                .map_err(|e| io_error("start thread for", local_addr, &e))?
        };
        Ok(FriDriver {
            shared,
            local_addr,
            thread: Some(thread),
        })
    }

    /// The bound UDP address (the robot sends measurements here).
    pub fn local_addr(&self) -> SocketAddr {
        self.local_addr
    }

    /// A snapshot of the link and the arm.
    pub fn status(&self) -> FriStatus {
        self.shared.lock().status()
    }

    /// Waits until the driver can command (robot in CMD, powered, quality at least the
    /// minimum).
    pub fn wait_until_commanding(&self, timeout_s: f64) -> Result<FriStatus, FriError> {
        self.shared
            .wait(timeout_s, |core| {
                let status = core.status();
                status.commanding.then_some(status)
            })?
            .ok_or_else(|| {
                let s = self.status();
                FriError::Timeout {
                    what: format!(
                        "command mode (robot {:?}, quality {:?}, power {:#06x})",
                        s.state, s.quality, s.power
                    ),
                    timeout_s,
                }
            })
    }

    /// Starts following `trajectory`; see [`DriverCore::start_trajectory`].
    pub fn start_trajectory(&self, trajectory: Trajectory<JOINTS>) -> Result<u64, FriError> {
        self.shared.lock().start_trajectory(trajectory)
    }

    /// Starts a guarded trajectory; see [`DriverCore::start_guarded_trajectory`].
    pub fn start_guarded_trajectory(
        &self,
        trajectory: Trajectory<JOINTS>,
        guard: ForceGuard,
    ) -> Result<u64, FriError> {
        self.shared
            .lock()
            .start_guarded_trajectory(trajectory, guard)
    }

    /// Waits for motion `id` to end and returns how it ended. On timeout the motion
    /// is stopped (decelerate, then hold) and [`FriError::Timeout`] returned.
    pub fn wait_motion(&self, id: u64, timeout_s: f64) -> Result<(), FriError> {
        match self.shared.wait(timeout_s, |core| core.outcome(id))? {
            Some(result) => result,
            None => {
                self.stop();
                Err(FriError::Timeout {
                    what: format!("motion {id} to finish"),
                    timeout_s,
                })
            }
        }
    }

    /// How motion `id` ended, or `None` while it runs (does not wait).
    pub fn motion_outcome(&self, id: u64) -> Option<Result<(), FriError>> {
        self.shared.lock().outcome(id)
    }

    /// Follows `trajectory` to its end, or returns why it could not; stops the motion
    /// when `timeout_s` passes first.
    pub fn execute(&self, trajectory: Trajectory<JOINTS>, timeout_s: f64) -> Result<(), FriError> {
        let id = self.start_trajectory(trajectory)?;
        self.wait_motion(id, timeout_s)
    }

    /// Stops the running motion: decelerate within limits, then hold.
    pub fn stop(&self) {
        self.shared.lock().stop();
        self.shared.changed.notify_all();
    }

    /// Withholds (`true`) or resumes answers: fault injection for tests, to make the
    /// robot see a failing link.
    pub fn set_withhold_answers(&self, withhold: bool) {
        self.shared.lock().set_withhold_answers(withhold);
    }

    /// Removes and returns the events so far (oldest first).
    pub fn take_events(&self) -> Vec<FriEvent> {
        self.shared.lock().take_events()
    }

    /// Waits for an event that `wanted` accepts and returns it; events before it are
    /// consumed. `None` when `timeout_s` passes first.
    pub fn wait_event(
        &self,
        timeout_s: f64,
        mut wanted: impl FnMut(&FriEvent) -> bool,
    ) -> Result<Option<FriEvent>, FriError> {
        self.shared.wait(timeout_s, |core| {
            while let Some(event) = core.events.pop_front() {
                if wanted(&event) {
                    return Some(event);
                }
            }
            None
        })
    }

    /// Stops any motion, waits (up to `timeout_s`) for the arm to come to rest,
    /// releases the robot and waits (up to `timeout_s` again) for it to leave
    /// command mode, then stops answering. A KRL program that ignores
    /// [`RELEASE_BIT`] makes this a [`FriError::Timeout`]; the robot then drops to
    /// monitor mode as answers stop, and holds.
    pub fn shutdown(mut self, timeout_s: f64) -> Result<(), FriError> {
        self.stop();
        let rested = self
            .shared
            .wait(timeout_s, |core| (!core.is_moving()).then_some(()));
        let released = match &rested {
            Ok(Some(())) => {
                self.shared.lock().release();
                self.shared
                    .wait(timeout_s, |core| core.is_released().then_some(()))
            }
            other => other.clone(),
        };
        self.end_thread();
        match (rested, released) {
            (Ok(None), _) => Err(FriError::Timeout {
                what: "the arm to come to rest before shutdown".into(),
                timeout_s,
            }),
            (_, Ok(None)) => Err(FriError::Timeout {
                what: "the robot to leave command mode (a KRL program that calls friStop \
                       on $FRI_FRM_BOOL[1])"
                    .into(),
                timeout_s,
            }),
            (_, Ok(Some(()))) | (_, Err(FriError::ShutDown)) => Ok(()),
            (_, Err(e)) => Err(e),
        }
    }

    fn end_thread(&mut self) {
        self.shared.stop.store(true, Ordering::Relaxed);
        if let Some(thread) = self.thread.take() {
            let _ = thread.join();
        }
    }
}

impl Drop for FriDriver {
    fn drop(&mut self) {
        self.end_thread();
    }
}

/// The driver thread: answer each measurement at once; check for late ones.
fn serve(shared: &Shared, socket: &UdpSocket, clock: &dyn Clock) {
    crate::hw::realtime::request_device_cycle_priority("FRI driver");
    let mut buf = [0u8; 2048];
    while !shared.stop.load(Ordering::Relaxed) {
        let received = socket.recv_from(&mut buf);
        let now = clock.now();
        let mut core = shared.lock();
        match received {
            Ok((n, from)) => {
                if let Some(command) = core.on_datagram(&buf[..n], from, now) {
                    if let Err(e) = socket.send_to(&command.encode(), from) {
                        let error = io_error("send command to", from, &e);
                        core.push(FriEvent::SocketError { error });
                    }
                }
            }
            Err(e)
                if matches!(
                    e.kind(),
                    std::io::ErrorKind::WouldBlock
                        | std::io::ErrorKind::TimedOut
                        | std::io::ErrorKind::ConnectionRefused
                ) => {}
            Err(e) => {
                let error = io_error("receive on", socket.local_addr().unwrap_or(UNSPECIFIED), &e);
                core.push(FriEvent::SocketError { error });
            }
        }
        core.check_late(now);
        drop(core);
        shared.changed.notify_all();
    }
}

const UNSPECIFIED: SocketAddr = SocketAddr::new(IpAddr::V4(Ipv4Addr::UNSPECIFIED), 0);

#[cfg(test)]
mod tests {
    use super::*;
    use crate::hw::fri::datagram::{InterfaceState, RobotData, RobotState};
    use crate::trajectory::JointLimits;

    const MS: Duration = Duration::from_millis(1);

    fn measurement(
        seq: u16,
        state: FriState,
        quality: Quality,
        q: [f32; JOINTS],
    ) -> MeasurementDatagram {
        MeasurementDatagram {
            send_seq_count: seq,
            interface: InterfaceState {
                state,
                quality,
                desired_msr_sample_time_s: 0.001,
                desired_cmd_sample_time_s: 0.001,
                ..Default::default()
            },
            robot: RobotState {
                power: 0x7f,
                control: ControlMode::Position,
                ..Default::default()
            },
            data: RobotData {
                msr_jnt_pos: q,
                cmd_jnt_pos: q,
                ..Default::default()
            },
            ..Default::default()
        }
    }

    fn core() -> DriverCore {
        DriverCore::new(DriverConfig {
            timeout_s: 0.05,
            ..Default::default()
        })
        .unwrap()
    }

    fn limits() -> JointLimits<JOINTS> {
        JointLimits::new([1.0; JOINTS], [2.0; JOINTS]).unwrap()
    }

    #[test]
    fn configuration_comes_from_the_cell_file() {
        let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
            .join(crate::config::DEFAULT_CONFIG_PATH);
        let cell = crate::config::CellConfig::load(&path).unwrap();
        let config = DriverConfig::from_cell(&cell.fri).unwrap();
        assert_eq!(config.bind_addr, "127.0.0.1:49938".parse().unwrap());
        assert_eq!(config.bind_addr.port(), DEFAULT_PORT);
        assert_eq!(config.timeout_s, cell.fri.timeout_s);
        assert_eq!(config.min_command_quality, Quality::Bad);
        let mut fri = cell.fri.clone();
        fri.bind_addr = "localhost".into();
        let err = DriverConfig::from_cell(&fri).unwrap_err();
        assert!(
            err.to_string().contains("fri.bind_addr = localhost"),
            "{err}"
        );
    }

    #[test]
    fn only_the_robot_is_answered() {
        let robot: SocketAddr = "192.168.0.10:49938".parse().unwrap();
        let stranger: SocketAddr = "192.168.0.11:49938".parse().unwrap();
        let other_port: SocketAddr = "192.168.0.10:50000".parse().unwrap();
        let mapped: SocketAddr = "[::ffff:192.168.0.10]:49938".parse().unwrap();
        let host: RobotPeer = "192.168.0.10".parse().unwrap();
        let exact: RobotPeer = "192.168.0.10:49938".parse().unwrap();
        assert_eq!(host, RobotPeer::Host(robot.ip()));
        assert_eq!(exact, RobotPeer::Exact(robot));
        assert!(host.admits(robot) && host.admits(other_port) && host.admits(mapped));
        assert!(!host.admits(stranger));
        assert!(exact.admits(robot) && exact.admits(mapped));
        assert!(!exact.admits(other_port) && !exact.admits(stranger));
        let err = "krc.local".parse::<RobotPeer>().unwrap_err();
        assert!(
            err.to_string().contains("fri.robot_addr = krc.local"),
            "{err}"
        );

        let mut d = DriverCore::new(DriverConfig {
            robot: exact,
            ..DriverConfig::default()
        })
        .unwrap();
        let q = [0.1; JOINTS];
        let bytes = |seq| measurement(seq, FriState::Monitor, Quality::Ok, q).encode();
        // A well-formed, newer measurement from anyone else: dropped, unanswered,
        // and not taken as the robot's (its sequence number does not count either).
        for (k, from) in [stranger, other_port, stranger].into_iter().enumerate() {
            assert!(d.on_datagram(&bytes(10 + k as u16), from, MS).is_none());
        }
        // Garbage from a stranger is foreign, not a bad datagram of the robot.
        assert!(d.on_datagram(&[0u8; 3], stranger, MS).is_none());
        let status = d.status();
        assert_eq!(status.last_seq, None);
        assert_eq!(status.counters.foreign_datagrams, 4);
        assert_eq!(status.counters.bad_datagrams, 0);
        assert_eq!(status.counters.measurements, 0);
        assert_eq!(status.counters.answers, 0);
        // Reported at the 1st, 2nd and 4th drop.
        let reported: Vec<u64> = d
            .take_events()
            .iter()
            .filter_map(|e| match e {
                FriEvent::ForeignDatagram { dropped, robot, .. } => {
                    assert_eq!(*robot, exact);
                    Some(*dropped)
                }
                _ => None,
            })
            .collect();
        assert_eq!(reported, [1, 2, 4]);
        // The robot is answered, and an older number from a stranger still is not.
        let c = d.on_datagram(&bytes(5), robot, MS).unwrap();
        assert_eq!(c.refl_seq_count, 5);
        assert!(d.on_datagram(&bytes(6), stranger, 2 * MS).is_none());
        assert!(d.on_datagram(&bytes(6), mapped, 2 * MS).is_some());
        assert_eq!(d.status().last_seq, Some(6));
    }

    #[test]
    fn replayed_and_out_of_order_measurements_are_dropped_across_the_wrap() {
        let mut d = core();
        let q = [0.0f32; JOINTS];
        let m = |seq, q| measurement(seq, FriState::Command, Quality::Perfect, q);
        assert!(d.on_measurement(&m(65534, q), MS).is_some());
        assert!(d.on_measurement(&m(65535, q), 2 * MS).is_some());
        assert!(
            d.on_measurement(&m(0, q), 3 * MS).is_some(),
            "65535 -> 0 is newer"
        );
        let answers = d.status().counters.answers;
        // A replay of the last, of one before the wrap, and one far behind.
        for stale in [0, 65535, 65534, 40000] {
            assert!(d.on_measurement(&m(stale, [1.0; JOINTS]), 4 * MS).is_none());
        }
        let status = d.status();
        assert_eq!(status.counters.stale_measurements, 4);
        assert_eq!(status.counters.answers, answers);
        assert_eq!(status.last_seq, Some(0));
        assert_eq!(
            status.measured_rad, [0.0; JOINTS],
            "a stale measurement is not news"
        );
        assert!(d.take_events().contains(&FriEvent::StaleMeasurement {
            seq: 40000,
            latest_seq: 0
        }));
        // Up to half the range ahead is newer (the rest lost).
        assert!(d.on_measurement(&m(1, q), 5 * MS).is_some());
        assert!(d.on_measurement(&m(1 + 32767, q), 6 * MS).is_some());
        assert_eq!(d.status().counters.missed_measurements, 32766);
    }

    #[test]
    fn answers_reflect_the_measurement_and_count_across_the_wrap() {
        let mut d = core();
        d.send_seq = 65534;
        let q = [0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7];
        let c = d
            .on_measurement(&measurement(65535, FriState::Monitor, Quality::Ok, q), MS)
            .unwrap();
        assert_eq!((c.send_seq_count, c.refl_seq_count), (65535, 65535));
        let bytes = c.encode();
        assert_eq!(&bytes[0..4], &[0xff, 0xff, 0xff, 0xff]);
        let c = d
            .on_measurement(&measurement(0, FriState::Monitor, Quality::Ok, q), 2 * MS)
            .unwrap();
        assert_eq!((c.send_seq_count, c.refl_seq_count), (0, 0));
        assert_eq!(c.cmd_flags, CmdFlags::JNT_POS);
        assert!(d
            .take_events()
            .iter()
            .all(|e| !matches!(e, FriEvent::MeasurementsMissed { .. })));
    }

    #[test]
    fn outside_command_mode_the_robots_own_command_is_mirrored() {
        let mut d = core();
        let mut m = measurement(7, FriState::Monitor, Quality::Perfect, [0.5; JOINTS]);
        m.data.cmd_jnt_pos = [0.25, -0.5, 1.0, 0.0, 0.125, 2.0, -1.0];
        m.data.cmd_jnt_pos_fri_offset = [0.5, 0.25, -0.5, 0.0, 0.0, 0.0, 1.0];
        let c = d.on_measurement(&m, MS).unwrap();
        assert_eq!(c.jnt_pos, [0.75, -0.25, 0.5, 0.0, 0.125, 2.0, 0.0]);
        assert!(!d.status().commanding);
        // Powered off in CMD: still mirror.
        let mut off = m;
        off.send_seq_count = 8;
        off.interface.state = FriState::Command;
        off.robot.power = 0;
        let c = d.on_measurement(&off, 2 * MS).unwrap();
        assert_eq!(c.jnt_pos, [0.75, -0.25, 0.5, 0.0, 0.125, 2.0, 0.0]);
        assert!(!d.status().commanding);
    }

    #[test]
    fn commands_only_at_the_minimum_quality_or_better() {
        // Default minimum BAD: refused at UNACCEPTABLE, allowed at BAD.
        let mut d = core();
        let q0 = [0.0f32; JOINTS];
        d.on_measurement(
            &measurement(1, FriState::Command, Quality::Unacceptable, q0),
            MS,
        );
        let traj = Trajectory::point_to_point([0.0; JOINTS], [0.1; JOINTS], &limits()).unwrap();
        assert_eq!(
            d.start_trajectory(traj.clone()),
            Err(FriError::QualityTooLow {
                quality: Quality::Unacceptable,
                min: Quality::Bad
            })
        );
        d.on_measurement(&measurement(2, FriState::Command, Quality::Bad, q0), 2 * MS);
        let id = d.start_trajectory(traj.clone()).unwrap();
        assert_eq!(d.start_trajectory(traj.clone()), Err(FriError::Busy { id }));
        // Quality falls to UNACCEPTABLE mid-motion: abort and mirror.
        let c = d
            .on_measurement(
                &measurement(3, FriState::Command, Quality::Unacceptable, [0.05; JOINTS]),
                3 * MS,
            )
            .unwrap();
        assert_eq!(c.jnt_pos, [0.05; JOINTS]);
        assert_eq!(
            d.outcome(id),
            Some(Err(FriError::QualityTooLow {
                quality: Quality::Unacceptable,
                min: Quality::Bad
            }))
        );
        // A stricter minimum (OK) refuses BAD.
        let mut strict = DriverCore::new(DriverConfig {
            min_command_quality: Quality::Ok,
            ..Default::default()
        })
        .unwrap();
        strict.on_measurement(&measurement(1, FriState::Command, Quality::Bad, q0), MS);
        assert_eq!(
            strict.start_trajectory(traj),
            Err(FriError::QualityTooLow {
                quality: Quality::Bad,
                min: Quality::Ok
            })
        );
        assert!(!strict.status().commanding);
        // Nothing below BAD may be configured.
        let low = DriverCore::new(DriverConfig {
            min_command_quality: Quality::Unacceptable,
            ..Default::default()
        });
        assert!(matches!(
            low,
            Err(FriError::BadConfig {
                field: "min_command_quality",
                ..
            })
        ));
    }

    #[test]
    fn streams_the_trajectory_on_the_robots_clock() {
        let mut d = core();
        let q0 = [0.1f32, -0.2, 0.3, 0.0, 0.0, 0.0, 0.0];
        let start = q0.map(f64::from);
        let mut end = start;
        end[0] += 0.4;
        let traj = Trajectory::point_to_point(start, end, &limits()).unwrap();
        // MON: mirror; CMD at quality PERFECT: hold the mirrored position.
        d.on_measurement(
            &measurement(10, FriState::Monitor, Quality::Perfect, q0),
            MS,
        );
        let c = d
            .on_measurement(
                &measurement(11, FriState::Command, Quality::Perfect, q0),
                2 * MS,
            )
            .unwrap();
        assert_eq!(c.jnt_pos, q0);
        let id = d.start_trajectory(traj.clone()).unwrap();
        let c = d
            .on_measurement(
                &measurement(12, FriState::Command, Quality::Perfect, q0),
                3 * MS,
            )
            .unwrap();
        assert_eq!(c.jnt_pos, traj.sample(0.001).position.map(|v| v as f32));
        // Two measurements lost: time advances by three periods and the gap is reported.
        let c = d
            .on_measurement(
                &measurement(15, FriState::Command, Quality::Perfect, q0),
                6 * MS,
            )
            .unwrap();
        assert_eq!(c.jnt_pos, traj.sample(0.004).position.map(|v| v as f32));
        assert!(d.take_events().contains(&FriEvent::MeasurementsMissed {
            after_seq: 12,
            received_seq: 15,
            missed: 2
        }));
        assert_eq!(d.status().counters.missed_measurements, 2);
        // Run to the end: the last command is the end point exactly, then hold.
        let mut seq = 15u16;
        let mut last = c;
        while d.outcome(id).is_none() {
            seq += 1;
            last = d
                .on_measurement(
                    &measurement(seq, FriState::Command, Quality::Perfect, q0),
                    MS * u32::from(seq),
                )
                .unwrap();
            assert!(seq < 5000, "trajectory never ended");
        }
        assert_eq!(d.outcome(id), Some(Ok(())));
        assert_eq!(last.jnt_pos, end.map(|v| v as f32));
        let expected_cycles = (traj.duration_s() / 0.001).ceil() as u16;
        assert_eq!(seq - 11, expected_cycles);
        // A stale (repeated) measurement is not answered.
        assert!(d
            .on_measurement(
                &measurement(seq, FriState::Command, Quality::Perfect, q0),
                MS
            )
            .is_none());
    }

    #[test]
    fn trajectory_must_start_at_the_commanded_position() {
        let mut d = core();
        d.on_measurement(
            &measurement(1, FriState::Command, Quality::Perfect, [0.0; JOINTS]),
            MS,
        );
        let mut start = [0.0; JOINTS];
        start[4] = 0.01;
        let traj = Trajectory::point_to_point(start, [0.2; JOINTS], &limits()).unwrap();
        assert_eq!(
            d.start_trajectory(traj),
            Err(FriError::StartMismatch {
                joint: 4,
                start_rad: 0.01,
                current_rad: 0.0,
                tolerance_rad: 1e-4
            })
        );
        let mut fresh = core();
        assert!(matches!(
            fresh.start_trajectory(Trajectory::through(&[[0.0; JOINTS]], &limits()).unwrap()),
            Err(FriError::NotCommanding {
                state: FriState::Off,
                ..
            })
        ));
    }

    #[test]
    fn dropping_to_monitor_mid_motion_is_reported_and_aborts() {
        let mut d = core();
        let q0 = [0.0f32; JOINTS];
        d.on_measurement(&measurement(1, FriState::Command, Quality::Perfect, q0), MS);
        let traj = Trajectory::point_to_point([0.0; JOINTS], [0.3; JOINTS], &limits()).unwrap();
        let id = d.start_trajectory(traj).unwrap();
        d.on_measurement(
            &measurement(2, FriState::Command, Quality::Perfect, q0),
            2 * MS,
        );
        d.take_events();
        let m = measurement(3, FriState::Monitor, Quality::Unacceptable, [0.01; JOINTS]);
        let c = d.on_measurement(&m, 3 * MS).unwrap();
        assert_eq!(c.jnt_pos, [0.01; JOINTS]);
        let events = d.take_events();
        assert!(events.contains(&FriEvent::DroppedToMonitor {
            state: FriState::Monitor,
            quality: Quality::Unacceptable,
            during_motion: true,
            seq: 3
        }));
        let aborted = FriError::LeftCommandMode {
            state: FriState::Monitor,
            quality: Quality::Unacceptable,
        };
        assert!(events.contains(&FriEvent::MotionAborted {
            id,
            error: aborted.clone()
        }));
        assert_eq!(d.outcome(id), Some(Err(aborted)));
    }

    #[test]
    fn a_late_measurement_is_a_safe_stop_then_the_link_recovers() {
        let mut d = core();
        let q0 = [0.0f32; JOINTS];
        assert!(
            !d.check_late(Duration::from_secs(100)),
            "no robot yet: nothing is late"
        );
        d.on_measurement(&measurement(1, FriState::Command, Quality::Perfect, q0), MS);
        let traj = Trajectory::point_to_point([0.0; JOINTS], [0.3; JOINTS], &limits()).unwrap();
        let id = d.start_trajectory(traj).unwrap();
        let c = d
            .on_measurement(
                &measurement(2, FriState::Command, Quality::Perfect, q0),
                2 * MS,
            )
            .unwrap();
        let held = c.jnt_pos;
        assert_ne!(held, q0);
        assert!(!d.check_late(2 * MS + Duration::from_micros(49_999)));
        assert!(d.check_late(52 * MS));
        assert!(!d.check_late(80 * MS), "reported once per outage");
        assert_eq!(
            d.outcome(id),
            Some(Err(FriError::MeasurementLate {
                waited_s: 0.05,
                timeout_s: 0.05
            }))
        );
        assert!(d.status().late);
        assert!(!d.status().commanding);
        let events = d.take_events();
        assert!(events.contains(&FriEvent::MeasurementLate {
            waited_s: 0.05,
            timeout_s: 0.05
        }));
        // The link returns with the robot still in CMD: hold the last command.
        let c = d
            .on_measurement(
                &measurement(90, FriState::Command, Quality::Ok, q0),
                90 * MS,
            )
            .unwrap();
        assert_eq!(c.jnt_pos, held);
        let c = d
            .on_measurement(
                &measurement(91, FriState::Command, Quality::Ok, q0),
                91 * MS,
            )
            .unwrap();
        assert_eq!(c.jnt_pos, held);
        assert!(d
            .take_events()
            .contains(&FriEvent::LinkRestored { after_s: 0.088 }));
    }

    /// FRI closed and reopened on the KRC: after the silence the robot counts from
    /// 1 again. Two consecutive numbers start the new count; one old datagram alone,
    /// or old numbers while the link is live, stay stale.
    #[test]
    fn the_robot_s_counter_starting_over_after_a_silence_is_followed() {
        let mut d = core();
        let q0 = [0.0f32; JOINTS];
        let m = |seq| measurement(seq, FriState::Monitor, Quality::Ok, q0);
        for seq in 30_000..30_005 {
            assert!(d
                .on_measurement(&m(seq), u32::from(seq - 29_999) * MS)
                .is_some());
        }
        // While live, old numbers are stale, however consecutive.
        assert!(d.on_measurement(&m(10), 6 * MS).is_none());
        assert!(d.on_measurement(&m(11), 7 * MS).is_none());
        // Silence, then the new count.
        assert!(d.check_late(2000 * MS));
        assert!(d.on_measurement(&m(1), 2100 * MS).is_none());
        let c = d.on_measurement(&m(2), 2101 * MS).expect("answered");
        assert_eq!(c.refl_seq_count, 2);
        assert!(d.on_measurement(&m(3), 2102 * MS).is_some());
        assert!(d.take_events().contains(&FriEvent::SequenceRestarted {
            seq: 2,
            latest_seq: 30_004
        }));
        assert_eq!(d.status().last_seq, Some(3));
    }

    #[test]
    fn stop_decelerates_then_holds() {
        let mut d = core();
        let q0 = [0.0f32; JOINTS];
        d.on_measurement(&measurement(1, FriState::Command, Quality::Perfect, q0), MS);
        let l = limits();
        let traj = Trajectory::point_to_point([0.0; JOINTS], [1.0; JOINTS], &l).unwrap();
        let id = d.start_trajectory(traj.clone()).unwrap();
        let mut seq = 1u16;
        let mut step = |d: &mut DriverCore| {
            seq += 1;
            d.on_measurement(
                &measurement(seq, FriState::Command, Quality::Perfect, q0),
                MS,
            )
            .unwrap()
            .jnt_pos[0] as f64
        };
        let mut p = Vec::new();
        for _ in 0..300 {
            p.push(step(&mut d));
        }
        d.stop();
        assert_eq!(d.outcome(id), Some(Err(FriError::Stopped { id })));
        while d.is_moving() {
            p.push(step(&mut d));
        }
        for _ in 0..5 {
            p.push(step(&mut d));
        }
        // Velocity at 0.3 s is 0.6 rad/s; braking at 2 rad/s^2 takes 0.3 s and 0.09 rad.
        let v = traj.sample(0.3).velocity[0];
        let expected_rest = traj.sample(0.3).position[0] + v * v / (2.0 * 2.0);
        assert!((p.last().unwrap() - expected_rest).abs() < 1e-6);
        for w in p.windows(3) {
            let a = (w[2] - 2.0 * w[1] + w[0]) / 1e-6;
            assert!(a.abs() <= 2.0 + 0.3, "acceleration {a}");
        }
        assert!(!d.is_moving());
    }
}
