//! KUKA Fast Research Interface (FRI 1.x) to the LBR4+ arm: the UDP datagram codec
//! ([`datagram`]) and the PC-side driver ([`driver`]).
//!
//! The robot (KRC) sends a 916-byte measurement datagram every cycle (1 ms at
//! 1 kHz); the PC answers each one with a 376-byte command datagram. Outside command
//! mode the PC mirrors the robot's own command, so nothing moves; in command mode it
//! streams joint positions. The robot-side simulator that speaks the same protocol
//! is `crate::sim::fri`.

pub mod datagram;
pub mod driver;

pub use datagram::{
    CmdFlags, CommandDatagram, ControlMode, DatagramError, FriState, MeasurementDatagram, Quality,
};
pub use driver::{
    DriverConfig, ForceGuard, FriDriver, FriError, FriEvent, FriStatus, RobotPeer, RELEASE_BIT,
};

/// Number of joints of the LBR4+ (`LBR_MNJ`).
pub const JOINTS: usize = 7;

/// The FRI default UDP port the PC binds.
pub const DEFAULT_PORT: u16 = 49938;

/// Whether a failed UDP receive only means that nothing arrived in time (or that
/// the peer's port was closed, which Linux reports on the next receive), not a
/// socket fault.
pub fn is_quiet_receive(e: &std::io::Error) -> bool {
    matches!(
        e.kind(),
        std::io::ErrorKind::WouldBlock
            | std::io::ErrorKind::TimedOut
            | std::io::ErrorKind::ConnectionRefused
    )
}
