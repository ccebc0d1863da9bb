//! The systemd notify protocol (`sd_notify(3)`) without libsystemd: one datagram of
//! `KEY=VALUE` lines to the Unix socket named by `NOTIFY_SOCKET` (a path, or an
//! abstract name written with a leading `@`). Without `NOTIFY_SOCKET` (not started
//! by systemd) every call does nothing.
//!
//! The units in `systemd/` are `Type=notify` with `WatchdogSec=`: a stage sends
//! `READY=1` once its ports exist and [`Watchdog::ping`]s at half the interval
//! systemd asks for in `WATCHDOG_USEC`, from its main loop, so a hung loop gets the
//! process restarted.

use std::os::unix::net::UnixDatagram;
use std::time::{Duration, Instant};

/// Sends `state` (e.g. `READY=1`) to systemd; `Ok(false)` when not under systemd.
pub fn notify(state: &str) -> std::io::Result<bool> {
    let Some(path) = std::env::var_os("NOTIFY_SOCKET") else {
        return Ok(false);
    };
    let socket = UnixDatagram::unbound()?;
    let path = path.to_string_lossy().into_owned();
    if let Some(name) = path.strip_prefix('@') {
        use std::os::linux::net::SocketAddrExt;
        let addr = std::os::unix::net::SocketAddr::from_abstract_name(name.as_bytes())?;
        socket.send_to_addr(state.as_bytes(), &addr)?;
    } else {
        socket.send_to(state.as_bytes(), &path)?;
    }
    Ok(true)
}

/// Tells systemd the stage is up (`READY=1`), with a status line.
pub fn ready(status: &str) {
    if let Err(e) = notify(&format!("READY=1\nSTATUS={status}")) {
        tracing::warn!("sd_notify READY: {e}");
    }
}

/// Tells systemd the stage is stopping.
pub fn stopping() {
    let _ = notify("STOPPING=1");
}

/// The systemd watchdog of this process: pings at half of `WATCHDOG_USEC`.
#[derive(Debug)]
pub struct Watchdog {
    interval: Option<Duration>,
    last: Instant,
}

impl Watchdog {
    /// The watchdog systemd asked for (none without `WATCHDOG_USEC`, or when
    /// `WATCHDOG_PID` names another process).
    pub fn from_env() -> Watchdog {
        let for_us = std::env::var("WATCHDOG_PID")
            .ok()
            .and_then(|p| p.parse::<u32>().ok())
            .is_none_or(|pid| pid == std::process::id());
        let interval = std::env::var("WATCHDOG_USEC")
            .ok()
            .and_then(|u| u.parse::<u64>().ok())
            .filter(|&u| u > 0 && for_us)
            .map(|u| Duration::from_micros(u / 2));
        Watchdog {
            interval,
            last: Instant::now(),
        }
    }

    /// Half the watchdog interval, if systemd set one.
    pub fn interval(&self) -> Option<Duration> {
        self.interval
    }

    /// Sends `WATCHDOG=1` when half the interval has passed since the last ping.
    pub fn ping(&mut self) {
        if let Some(interval) = self.interval {
            if self.last.elapsed() >= interval {
                if let Err(e) = notify("WATCHDOG=1") {
                    tracing::warn!("sd_notify WATCHDOG: {e}");
                }
                self.last = Instant::now();
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn datagrams_reach_a_notify_socket() {
        let dir = crate::fsio::TempDir::new("notify").unwrap();
        let path = dir.join("notify.sock");
        let _ = std::fs::remove_file(&path);
        let server = UnixDatagram::bind(&path).unwrap();
        // The variable is process-wide: only this test sets it.
        std::env::set_var("NOTIFY_SOCKET", &path);
        assert!(notify("READY=1\nSTATUS=up").unwrap());
        std::env::remove_var("NOTIFY_SOCKET");
        let mut buf = [0u8; 64];
        let n = server.recv(&mut buf).unwrap();
        assert_eq!(&buf[..n], b"READY=1\nSTATUS=up");
        assert!(!notify("READY=1").unwrap());
    }
}
