//! Snapshots of the link and the arm: [`FriStatus`] and the cumulative
//! [`DriverCounters`].

use crate::hw::fri::datagram::{ControlMode, FriState, LinkStats, Quality};
use crate::hw::fri::JOINTS;
use serde::Serialize;

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
