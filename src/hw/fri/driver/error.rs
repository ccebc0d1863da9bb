//! [`FriError`]: the errors of the FRI driver, each with the numbers that explain it.

use crate::hw::fri::datagram::{FriState, Quality};
use std::net::SocketAddr;

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
