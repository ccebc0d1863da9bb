//! A kernel SocketCAN interface (`can0`, `vcan0`) through the `socketcan` crate.
//!
//! The socket receives the kernel's error frames; they update [`CanBus::state`]
//! (warning, passive, bus-off, restarted) instead of being returned as frames.
//! While bus-off, `send` and `recv` fail with [`CanError::BusOff`]. Extended and
//! remote frames (not used by the puck protocol) are skipped.

use super::{BusState, CanBus, CanError, CanFrame, SEND_TIMEOUT};
use embedded_can::blocking::Can;
use embedded_can::{Frame as _, Id, StandardId};
use socketcan::errors::ControllerProblems;
use socketcan::{CanSocket, ShouldRetry, Socket, SocketOptions};
use std::time::{Duration, Instant};

/// One node on a SocketCAN interface.
pub struct SocketCanBus {
    socket: CanSocket,
    interface: String,
    state: BusState,
}

impl SocketCanBus {
    /// Opens `interface`; fails with [`CanError::Open`] naming the interface and the
    /// operating system's error (e.g. "No such device" without kernel CAN).
    pub fn open(interface: &str) -> Result<SocketCanBus, CanError> {
        let open_err = |source| CanError::Open {
            interface: interface.to_string(),
            error: source,
        };
        let socket = CanSocket::open(interface).map_err(open_err)?;
        socket.set_error_filter_accept_all().map_err(open_err)?;
        socket
            .set_write_timeout(Some(SEND_TIMEOUT))
            .map_err(open_err)?;
        Ok(SocketCanBus {
            socket,
            interface: interface.to_string(),
            state: BusState::ErrorActive,
        })
    }

    fn bus_off(&self) -> CanError {
        CanError::BusOff {
            interface: self.interface.clone(),
        }
    }

    /// Folds one kernel error frame into the state.
    fn observe(&mut self, error: &socketcan::CanError) {
        let before = self.state;
        if error.is_bus_off() {
            self.state = BusState::BusOff;
        } else if error.is_restarted() {
            self.state = BusState::ErrorActive;
        } else if let Some(problems) = error.controller() {
            if problems.intersects(ControllerProblems::TX_PASSIVE | ControllerProblems::RX_PASSIVE)
            {
                self.state = BusState::ErrorPassive;
            } else if problems
                .intersects(ControllerProblems::TX_WARNING | ControllerProblems::RX_WARNING)
            {
                self.state = BusState::ErrorWarning;
            } else if problems.contains(ControllerProblems::ACTIVE) {
                self.state = BusState::ErrorActive;
            }
        }
        if self.state != before {
            tracing::warn!(interface = %self.interface, ?before, after = ?self.state, "CAN state change: {error}");
        }
    }
}

impl CanBus for SocketCanBus {
    fn send(&mut self, frame: &CanFrame) -> Result<(), CanError> {
        if self.state == BusState::BusOff {
            return Err(self.bus_off());
        }
        let id = StandardId::new(frame.id()).ok_or(CanError::InvalidId {
            id: u32::from(frame.id()),
        })?;
        let raw = socketcan::CanFrame::new(id, frame.data())
            .ok_or(CanError::TooLong { len: frame.len() })?;
        match self.socket.write_frame(&raw) {
            Ok(()) => Ok(()),
            Err(e) if e.should_retry() => Err(CanError::SendTimeout {
                interface: self.interface.clone(),
                frame: *frame,
                timeout_s: SEND_TIMEOUT.as_secs_f64(),
            }),
            Err(source) => Err(CanError::Io {
                interface: self.interface.clone(),
                operation: "send",
                error: source,
            }),
        }
    }

    fn recv(&mut self, timeout: Duration) -> Result<Option<CanFrame>, CanError> {
        let deadline = Instant::now() + timeout;
        loop {
            if self.state == BusState::BusOff {
                return Err(self.bus_off());
            }
            let remaining = deadline.saturating_duration_since(Instant::now());
            if remaining.is_zero() {
                return Ok(None);
            }
            self.socket
                .set_read_timeout(Some(remaining))
                .map_err(|source| CanError::Io {
                    interface: self.interface.clone(),
                    operation: "set read timeout",
                    error: source,
                })?;
            match self.socket.receive() {
                Ok(socketcan::CanFrame::Data(data)) => match data.id() {
                    Id::Standard(id) => {
                        return CanFrame::new(id.as_raw(), data.data()).map(Some);
                    }
                    Id::Extended(id) => {
                        tracing::debug!(interface = %self.interface, id = id.as_raw(), "skipped extended frame");
                    }
                },
                Ok(other) => {
                    tracing::debug!(interface = %self.interface, "skipped non-data frame {other:?}");
                }
                Err(socketcan::Error::Can(error)) => self.observe(&error),
                Err(socketcan::Error::Io(e)) if e.should_retry() => {}
                Err(socketcan::Error::Io(source)) => {
                    return Err(CanError::Io {
                        interface: self.interface.clone(),
                        operation: "receive",
                        error: source,
                    })
                }
            }
        }
    }

    fn state(&self) -> BusState {
        self.state
    }

    fn interface(&self) -> &str {
        &self.interface
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn missing_interface_fails_naming_it_and_the_os_error() {
        // No such interface exists anywhere (and this kernel has no CAN at all).
        let err = SocketCanBus::open("gcnocan9").err().unwrap();
        let text = err.to_string();
        assert!(text.contains("`gcnocan9`"), "{text}");
        let CanError::Open { error: source, .. } = &err else {
            panic!("not an open error: {text}");
        };
        assert!(source.raw_os_error().is_some(), "{text}");
        assert!(text.contains("os error"), "{text}");
    }
}
