//! What the simulated robot saw or did: events, why it left command mode, how each
//! received datagram was classified, the commands it received and its counters.

use crate::hw::fri::datagram::{DatagramError, FriState, Quality};
use crate::hw::fri::JOINTS;
use serde::Serialize;
use std::fmt;

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
    ///
    /// [`RELEASE_BIT`]: crate::hw::fri::RELEASE_BIT
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
