//! A bus wrapper that logs every frame passing through it in candump's log format
//! (`candump -L`), readable by `canplayer` and `log2asc`:
//!
//! ```text
//! (1699999999.123456) can0 405#9D0012000000
//! ```
//!
//! Frames this node sends and frames it receives are both logged (the bus has no
//! loopback, so this is all traffic the node takes part in or hears). Each line is
//! written whole and flushed at once, so a crash loses at most the frame in flight.

use super::{BusState, CanBus, CanError, CanFrame};
use crate::clock::{Clock, SystemClock};
use crate::fsio::{FileError, FileOp};
use std::fs::File;
use std::io::{LineWriter, Write};
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Duration;

/// One candump log line (without newline): `(SECONDS.MICROS) INTERFACE ID#DATA`.
///
/// Whitespace in the interface name would split the line's fields, so it is
/// replaced by `_`.
pub fn candump_line(time_since_epoch: Duration, interface: &str, frame: &CanFrame) -> String {
    let interface: String = interface
        .chars()
        .map(|c| if c.is_whitespace() { '_' } else { c })
        .collect();
    format!(
        "({}.{:06}) {interface} {frame}",
        time_since_epoch.as_secs(),
        time_since_epoch.subsec_micros()
    )
}

/// Wraps a bus and logs every frame it sends or receives.
pub struct CandumpBus<B> {
    inner: B,
    writer: LineWriter<File>,
    path: PathBuf,
    clock: Arc<dyn Clock>,
}

impl<B: CanBus> CandumpBus<B> {
    /// Logs to `path` (created or truncated), stamped with the Unix time of a
    /// [`SystemClock`].
    pub fn create(inner: B, path: &Path) -> Result<CandumpBus<B>, CanError> {
        CandumpBus::with_clock(inner, path, Arc::new(SystemClock::new()))
    }

    /// Logs to `path`, stamped with `clock` (seconds since its epoch).
    pub fn with_clock(
        inner: B,
        path: &Path,
        clock: Arc<dyn Clock>,
    ) -> Result<CandumpBus<B>, CanError> {
        let file = File::create(path)
            .map_err(|source| CanError::Candump(FileError::new(FileOp::Write, path, source)))?;
        Ok(CandumpBus {
            inner,
            writer: LineWriter::new(file),
            path: path.to_path_buf(),
            clock,
        })
    }

    /// The wrapped bus.
    pub fn inner(&self) -> &B {
        &self.inner
    }

    fn log(&mut self, frame: &CanFrame) -> Result<(), CanError> {
        let line = candump_line(self.clock.now(), self.inner.interface(), frame);
        writeln!(self.writer, "{line}")
            .map_err(|source| CanError::Candump(FileError::new(FileOp::Write, &self.path, source)))
    }
}

impl<B: CanBus> CanBus for CandumpBus<B> {
    fn send(&mut self, frame: &CanFrame) -> Result<(), CanError> {
        self.inner.send(frame)?;
        self.log(frame)
    }

    fn recv(&mut self, timeout: Duration) -> Result<Option<CanFrame>, CanError> {
        let frame = self.inner.recv(timeout)?;
        if let Some(frame) = &frame {
            self.log(frame)?;
        }
        Ok(frame)
    }

    fn state(&self) -> BusState {
        self.inner.state()
    }

    fn interface(&self) -> &str {
        self.inner.interface()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::clock::ManualClock;
    use crate::hw::can::VirtualBus;

    #[test]
    fn line_format_matches_candump() {
        let frame = CanFrame::new(0x405, &[0x9D, 0x00, 0x12, 0x00, 0x00]).unwrap();
        let time = Duration::new(1_699_999_999, 123_456_789);
        assert_eq!(
            candump_line(time, "can0", &frame),
            "(1699999999.123456) can0 405#9D00120000"
        );
        let empty = CanFrame::new(0x00B, &[]).unwrap();
        assert_eq!(
            candump_line(Duration::from_micros(5), "my bus", &empty),
            "(0.000005) my_bus 00B#"
        );
    }

    #[test]
    fn logs_sent_and_received_frames_in_order() {
        let dir = crate::fsio::TempDir::new("candump").unwrap();
        let path = dir.join("log.txt");
        let bus = VirtualBus::new("candump-unit");
        let clock = ManualClock::starting_at(Duration::from_secs(1_700_000_000));
        let mut logged =
            CandumpBus::with_clock(bus.endpoint(), &path, Arc::new(clock.clone())).unwrap();
        let mut peer = bus.endpoint();
        logged
            .send(&CanFrame::new(0x00B, &[0x30]).unwrap())
            .unwrap();
        clock.advance(Duration::from_micros(1500));
        peer.send(&CanFrame::new(0x566, &[0xB0, 0, 1, 0, 0, 0]).unwrap())
            .unwrap();
        assert!(logged.recv(Duration::from_secs(5)).unwrap().is_some());
        drop(logged);
        let text = std::fs::read_to_string(&path).unwrap();
        assert_eq!(
            text,
            "(1700000000.000000) inproc:candump-unit 00B#30\n\
             (1700000000.001500) inproc:candump-unit 566#B00001000000\n"
        );
    }
}
