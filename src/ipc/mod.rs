//! Inter-process communication of the cell over iceoryx2 (zero-copy shared memory).
//!
//! - [`services`]: every service name of the cell, built from one cell instance name.
//! - [`payloads`]: the `#[repr(C)]` messages; each carries the trial id and a
//!   monotonic timestamp ([`monotonic_now_ns`]).
//! - [`domain`]: where a cell's shared-memory files live (isolated domains for tests).
//! - [`stage`]: a process's node ([`Stage`]), typed publishers and subscribers that
//!   wake their readers through event services, and liveness of peers.
//! - [`peer`] and [`bench`]: helper processes for tests and `cell bench ipc`.
//!
//! Stopping: dropping a [`Stage`] and its ports removes the process's resources; a
//! process killed with SIGKILL leaves them behind until the next [`Stage::start`] of
//! any process of the same domain cleans them.

pub mod bench;
pub mod domain;
pub mod payloads;
pub mod peer;
pub mod services;
pub mod stage;

pub use domain::Domain;
pub use payloads::*;
pub use services::{CloudTopic, Services, Topic};
pub use stage::{
    wait_any, CloudLoan, CloudPublisher, CloudSample, CloudSubscriber, MessagePublisher,
    MessageSubscriber, Peers, Stage, StageStatus, Wakeable,
};

use std::path::PathBuf;

/// Errors of the IPC layer; each names the input or the service concerned.
#[derive(Debug, thiserror::Error)]
pub enum IpcError {
    /// A cell instance name that cannot form service names.
    #[error("cell instance name {instance:?}: {reason}")]
    InvalidInstance {
        /// The rejected name.
        instance: String,
        /// Why it was rejected.
        reason: &'static str,
    },
    /// A stage (node) name that cannot be used.
    #[error("stage name {stage:?}: {reason}")]
    InvalidStage {
        /// The rejected name.
        stage: String,
        /// Why it was rejected.
        reason: &'static str,
    },
    /// A text too long for its fixed-size field.
    #[error("{field}: {len} bytes do not fit the {max}-byte field")]
    NameTooLong {
        /// The message field.
        field: &'static str,
        /// Length of the text in bytes.
        len: usize,
        /// Capacity of the field in bytes.
        max: usize,
    },
    /// A text with a NUL byte (NUL terminates fixed-size fields).
    #[error("{field}: NUL byte at offset {offset}")]
    NameHasNul {
        /// The message field.
        field: &'static str,
        /// Byte offset of the NUL.
        offset: usize,
    },
    /// A received fixed-size text that is not UTF-8.
    #[error("{field}: not UTF-8 (valid up to byte {valid_up_to})")]
    NameNotUtf8 {
        /// The message field.
        field: &'static str,
        /// Length of the valid prefix.
        valid_up_to: usize,
    },
    /// An enumeration code that names no variant.
    #[error("{field}: unknown code {code}")]
    UnknownCode {
        /// The message field.
        field: &'static str,
        /// The received code.
        code: u32,
    },
    /// A field the message needs is missing.
    #[error("{field}: missing")]
    Missing {
        /// The missing field.
        field: &'static str,
    },
    /// More items than a fixed-capacity message holds.
    #[error("{field}: {count} items exceed the capacity of {max}")]
    TooMany {
        /// The message field.
        field: &'static str,
        /// Number of items given or claimed.
        count: usize,
        /// Capacity.
        max: usize,
    },
    /// A cloud whose shape does not match its points.
    #[error("point cloud: width {width} x height {height} != {points} points (at most {max})")]
    CloudShape {
        /// Columns.
        width: u32,
        /// Rows.
        height: u32,
        /// Number of points.
        points: usize,
        /// Largest supported cloud.
        max: usize,
    },
    /// A value that must be finite and positive is not.
    #[error("{field}: {value} is not a finite positive number")]
    NotPositive {
        /// The message field.
        field: &'static str,
        /// The value.
        value: f64,
    },
    /// A 4x4 matrix that is not a rigid transform.
    #[error("{field}: not a rigid transform ({problem}, off by {error:e})")]
    NotRigid {
        /// The message field.
        field: &'static str,
        /// What is wrong (last row, rotation not orthonormal, ...).
        problem: &'static str,
        /// Size of the deviation.
        error: f64,
    },
    /// A non-finite number where a finite one is required.
    #[error(transparent)]
    Geometry(#[from] crate::geometry::GeometryError),
    /// An iceoryx2 call failed.
    #[error("iceoryx2 {operation} on {target:?}: {detail}")]
    Iceoryx {
        /// What was attempted.
        operation: &'static str,
        /// Service, node or domain concerned.
        target: String,
        /// The iceoryx2 error.
        detail: String,
    },
    /// A domain setting that iceoryx2 cannot use.
    #[error("ipc domain {field} {value:?}: {reason}")]
    InvalidDomain {
        /// `root` or `prefix`.
        field: &'static str,
        /// The rejected value.
        value: String,
        /// Why.
        reason: &'static str,
    },
    /// Removing a domain's files while processes still use it.
    #[error("ipc domain {root}: {alive} node(s) still alive, not removing its files")]
    DomainInUse {
        /// Root directory of the domain.
        root: PathBuf,
        /// Number of living nodes.
        alive: usize,
    },
    /// A file operation on a domain's files failed.
    #[error(transparent)]
    File(#[from] crate::fsio::FileError),
    /// An operating-system error outside files: a socket, a child process, stdin.
    #[error("{path}: {source}")]
    Io {
        /// The socket, program or stream.
        path: PathBuf,
        /// The error.
        source: std::io::Error,
    },
    /// A peer process misbehaved (wrong answer, unexpected end, ...).
    #[error("peer: {0}")]
    Peer(String),
}

impl IpcError {
    /// An [`IpcError::Iceoryx`] from any iceoryx2 error.
    pub(crate) fn iceoryx(
        operation: &'static str,
        target: impl Into<String>,
        err: impl std::fmt::Debug,
    ) -> IpcError {
        IpcError::Iceoryx {
            operation,
            target: target.into(),
            detail: format!("{err:?}"),
        }
    }
}

/// Nanoseconds of `CLOCK_MONOTONIC`: the stamp of every message.
///
/// The clock is system-wide on Linux, so stamps taken in different processes compare
/// (one-way latency = receiver's now - sender's stamp). It does not jump with wall
/// time and does not count suspend.
pub fn monotonic_now_ns() -> u64 {
    crate::sys::monotonic_ns()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn spin() {
        let mut x = 0u64;
        for k in 0..200_000u64 {
            x = std::hint::black_box(x.wrapping_add(k * k));
        }
    }

    #[test]
    fn monotonic_clock_counts_nanoseconds_like_instant() {
        // Outer interval by Instant, inner by ours, then the other way round.
        let outer = std::time::Instant::now();
        let a = monotonic_now_ns();
        spin();
        let b = monotonic_now_ns();
        let outer_ns = outer.elapsed().as_nanos() as u64;
        assert!(
            b > a && b - a <= outer_ns,
            "{} ns vs Instant {outer_ns} ns",
            b - a
        );

        let c = monotonic_now_ns();
        let inner = std::time::Instant::now();
        spin();
        let inner_ns = inner.elapsed().as_nanos() as u64;
        let d = monotonic_now_ns();
        assert!(d - c >= inner_ns, "{} ns vs Instant {inner_ns} ns", d - c);
    }
}
