//! [`FriEvent`]: what the driver saw or did.

use super::{FriError, RobotPeer};
use crate::hw::fri::datagram::{DatagramError, FriState, Quality};
use std::net::SocketAddr;

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
    /// The robot left command mode as the driver asked ([`RELEASE_BIT`](super::RELEASE_BIT)).
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
