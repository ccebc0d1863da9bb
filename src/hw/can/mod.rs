//! The CAN bus: a [`CanBus`] trait over [`CanFrame`]s, with backends
//!
//! - [`SocketCanBus`]: a kernel SocketCAN interface (`can0`, `vcan0`).
//! - [`VirtualBus`]: an in-process bus with many endpoints and injectable faults.
//! - [`UnixBus`]: a cross-process bus without kernel CAN, a [`Hub`] rebroadcasting
//!   frames between processes over AF_UNIX sequenced-packet sockets.
//! - [`CandumpBus`]: wraps any bus and logs every frame in candump's log format.
//!
//! [`open_bus`] picks the backend from the interface name in `robot/cell.toml`:
//! `virtual:NAME` is the cross-process bus `NAME`; anything else is a SocketCAN
//! interface.
//!
//! Every backend behaves like CAN without loopback: a node never receives its own
//! frames, every other node receives each frame once, in the order sent.

mod candump;
mod frame;
mod socketcan_bus;
mod unix_bus;
mod virtual_bus;

pub use candump::{candump_line, CandumpBus};
pub use frame::{CanFrame, MAX_DATA_LEN, MAX_STANDARD_ID};
pub use socketcan_bus::SocketCanBus;
pub use unix_bus::{hub_socket_path, Hub, UnixBus};
pub use virtual_bus::{
    Corruption, FaultConfig, FaultCounts, IdleProbe, VirtualBus, VirtualEndpoint,
};

use std::path::Path;
use std::time::Duration;

/// The longest a backend lets [`CanBus::send`] block before reporting
/// [`CanError::SendTimeout`].
pub const SEND_TIMEOUT: Duration = Duration::from_millis(100);

/// Prefix of a cross-process virtual bus in an interface name: `virtual:NAME`.
pub const VIRTUAL_PREFIX: &str = "virtual:";

/// Errors of the CAN layer; each names the interface (or file) involved.
///
/// Operating-system errors are part of the message (field `error`), not a
/// separate cause, so an error chain prints them once.
#[derive(Debug, thiserror::Error)]
pub enum CanError {
    /// An identifier does not fit in 11 bits.
    #[error("CAN identifier {id:#x} exceeds the 11-bit maximum 0x7ff")]
    InvalidId {
        /// The identifier.
        id: u32,
    },
    /// More than 8 data bytes.
    #[error("CAN frame with {len} data bytes (at most 8)")]
    TooLong {
        /// The number of bytes given.
        len: usize,
    },
    /// The interface name cannot name any backend.
    #[error("CAN interface `{interface}`: {problem}")]
    BadInterface {
        /// The interface name as given.
        interface: String,
        /// What is wrong with it.
        problem: String,
    },
    /// The interface could not be opened.
    #[error("cannot open CAN interface `{interface}`: {error}")]
    Open {
        /// The interface.
        interface: String,
        /// The operating system's error.
        error: std::io::Error,
    },
    /// An operating-system error while using an open bus.
    #[error("CAN interface `{interface}`: {operation} failed: {error}")]
    Io {
        /// The interface.
        interface: String,
        /// What was being done (`send`, `receive`, ...).
        operation: &'static str,
        /// The operating system's error.
        error: std::io::Error,
    },
    /// The frame could not be queued within [`SEND_TIMEOUT`].
    #[error("CAN interface `{interface}`: send of {frame} timed out after {timeout_s} s")]
    SendTimeout {
        /// The interface.
        interface: String,
        /// The frame not sent.
        frame: CanFrame,
        /// How long it waited (s).
        timeout_s: f64,
    },
    /// The controller is bus-off: it neither sends nor receives until restarted.
    #[error("CAN interface `{interface}` is bus-off")]
    BusOff {
        /// The interface.
        interface: String,
    },
    /// The virtual medium is gone (hub process ended, bus dropped).
    #[error("CAN interface `{interface}`: bus disconnected ({reason})")]
    Disconnected {
        /// The interface.
        interface: String,
        /// Why.
        reason: String,
    },
    /// A packet from the cross-process hub is not one encoded frame.
    #[error("CAN interface `{interface}`: garbled packet of {len} bytes from the hub: {problem}")]
    BadPacket {
        /// The interface.
        interface: String,
        /// Packet length in bytes.
        len: usize,
        /// What is wrong with it.
        problem: PacketError,
    },
    /// Writing the candump log failed.
    #[error("candump log {}: {}", .0.path.display(), .0.source)]
    Candump(crate::fsio::FileError),
}

/// What is wrong with a packet from the cross-process hub ([`CanError::BadPacket`]).
#[derive(Debug, thiserror::Error)]
pub enum PacketError {
    /// Not the length of one encoded frame.
    #[error("expected {expected} bytes")]
    Length {
        /// The length of an encoded frame.
        expected: usize,
    },
    /// The identifier word is not an 11-bit data frame's.
    #[error("identifier word {raw_id:#010x} is not a standard data frame")]
    NotStandard {
        /// The identifier word.
        raw_id: u32,
    },
    /// More than 8 data bytes.
    #[error("DLC {dlc} exceeds 8")]
    Dlc {
        /// The data length code.
        dlc: usize,
    },
    /// The frame itself is invalid.
    #[error(transparent)]
    Frame(Box<CanError>),
    /// The first packet of a connection is not the hub's greeting.
    #[error("expected the hub's greeting (not a graspcell CAN hub?)")]
    NotGreeting,
}

/// Error state of a CAN node, as CAN controllers report it.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
pub enum BusState {
    /// Normal operation.
    ErrorActive,
    /// An error counter passed 96: still working, but errors are piling up.
    ErrorWarning,
    /// An error counter passed 127: the node sends only passive error flags.
    ErrorPassive,
    /// Transmit error counter passed 255: the node is off the bus.
    BusOff,
    /// The virtual medium is gone (no hub, bus dropped).
    Disconnected,
}

/// A CAN bus as one node sees it.
///
/// No loopback: a node does not receive the frames it sends. Blocking is bounded:
/// `recv` by its timeout, `send` by [`SEND_TIMEOUT`].
pub trait CanBus: Send {
    /// Puts `frame` on the bus.
    fn send(&mut self, frame: &CanFrame) -> Result<(), CanError>;
    /// The next frame sent by another node, or `None` when none arrives within
    /// `timeout` (of the operating system's clock: this is where I/O waits).
    fn recv(&mut self, timeout: Duration) -> Result<Option<CanFrame>, CanError>;
    /// The node's error state as last observed.
    fn state(&self) -> BusState;
    /// The interface name, for messages and logs.
    fn interface(&self) -> &str;
}

impl<B: CanBus + ?Sized> CanBus for Box<B> {
    fn send(&mut self, frame: &CanFrame) -> Result<(), CanError> {
        (**self).send(frame)
    }

    fn recv(&mut self, timeout: Duration) -> Result<Option<CanFrame>, CanError> {
        (**self).recv(timeout)
    }

    fn state(&self) -> BusState {
        (**self).state()
    }

    fn interface(&self) -> &str {
        (**self).interface()
    }
}

/// Which backend an interface name selects.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum InterfaceKind {
    /// `virtual:NAME`: the cross-process bus `NAME`.
    Virtual(String),
    /// A kernel SocketCAN interface (`can0`, `vcan0`).
    SocketCan(String),
}

/// Parses an interface name: `virtual:NAME` (NAME of letters, digits, `-`, `_`,
/// `.`, at most 64) or a kernel interface name (at most 15 bytes, no `/`, `:` or
/// whitespace).
pub fn parse_interface(interface: &str) -> Result<InterfaceKind, CanError> {
    let bad = |problem: &str| CanError::BadInterface {
        interface: interface.to_string(),
        problem: problem.to_string(),
    };
    if let Some(name) = interface.strip_prefix(VIRTUAL_PREFIX) {
        if name.is_empty() || name.len() > 64 {
            return Err(bad("the virtual bus name must have 1 to 64 characters"));
        }
        if !name
            .chars()
            .all(|c| c.is_ascii_alphanumeric() || matches!(c, '-' | '_' | '.'))
            || name.starts_with('.')
        {
            return Err(bad(
                "the virtual bus name may use only letters, digits, '-', '_' and '.' (not first)",
            ));
        }
        return Ok(InterfaceKind::Virtual(name.to_string()));
    }
    if interface.is_empty() || interface.len() > 15 {
        return Err(bad(
            "a SocketCAN interface name has 1 to 15 bytes (or use virtual:NAME)",
        ));
    }
    if interface
        .chars()
        .any(|c| c == '/' || c == ':' || c.is_whitespace())
    {
        return Err(bad(
            "a SocketCAN interface name has no '/', ':' or whitespace (or use virtual:NAME)",
        ));
    }
    Ok(InterfaceKind::SocketCan(interface.to_string()))
}

/// Opens the bus an interface name selects (see [`parse_interface`]).
///
/// `virtual:NAME` connects to the hub of bus `NAME`, starting one in this process
/// when none runs (see [`UnixBus::open`]).
pub fn open_bus(interface: &str) -> Result<Box<dyn CanBus>, CanError> {
    match parse_interface(interface)? {
        InterfaceKind::Virtual(name) => Ok(Box::new(UnixBus::open(&name)?)),
        InterfaceKind::SocketCan(name) => Ok(Box::new(SocketCanBus::open(&name)?)),
    }
}

/// [`open_bus`], then, with `candump` given, logs every frame to that file.
pub fn open_bus_logged(
    interface: &str,
    candump: Option<&Path>,
) -> Result<Box<dyn CanBus>, CanError> {
    let bus = open_bus(interface)?;
    match candump {
        Some(path) => Ok(Box::new(CandumpBus::create(bus, path)?)),
        None => Ok(bus),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn interface_names_select_backends() {
        assert_eq!(
            parse_interface("virtual:hand").unwrap(),
            InterfaceKind::Virtual("hand".into())
        );
        assert_eq!(
            parse_interface("vcan0").unwrap(),
            InterfaceKind::SocketCan("vcan0".into())
        );
        for bad in [
            "",
            "virtual:",
            "virtual:a/b",
            "virtual:..",
            "can0/x",
            "sixteen_chars_xx",
        ] {
            let err = parse_interface(bad).unwrap_err().to_string();
            assert!(err.contains(&format!("`{bad}`")), "{bad}: {err}");
        }
    }

    #[test]
    fn shipped_config_interface_parses() {
        let path = Path::new(env!("CARGO_MANIFEST_DIR")).join(crate::config::DEFAULT_CONFIG_PATH);
        let config = crate::config::CellConfig::load(&path).unwrap();
        parse_interface(&config.can.interface).unwrap();
    }
}
