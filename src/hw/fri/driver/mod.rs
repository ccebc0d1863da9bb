//! The PC side of FRI 1.x: answers every measurement of the LBR4+ within its cycle and
//! streams the joint positions of a time-parametrised [`Trajectory`].
//!
//! [`DriverCore`] is the protocol logic as a pure state machine (measurement and time
//! in, command and events out), tested without sockets. [`FriDriver`] runs it on a
//! UDP socket in a background thread that answers each measurement as soon as it
//! arrives, and offers blocking calls that all take a timeout.
//!
//! # Commanding
//! The driver sends its own joint positions only while the robot is in command mode,
//! its drives are powered and the link quality is at least
//! [`DriverConfig::min_command_quality`]. The default is BAD (issue 7: no commands
//! below quality BAD): the robot refuses commands only at UNACCEPTABLE, and
//! at BAD it still follows them, bridging a single missing answer by extrapolation.
//! The minimum may be raised to OK or PERFECT, never lowered below BAD.
//! Otherwise the driver mirrors the robot's own command, `cmdJntPos + cmdJntPosFriOffset`,
//! which moves nothing. On entering command mode it holds the mirrored position, so
//! the first command matches what the robot is doing. Trajectory time advances by
//! one measurement period per measurement (by the sequence-number gap when some were
//! lost), i.e. on the robot's clock.
//!
//! # Whom the driver answers
//! Only the robot controller: [`DriverConfig::robot`] (`fri.robot_addr` in
//! `robot/cell.toml`) names its IP address, or its address and port. A datagram
//! from any other sender is dropped before it is decoded, counted
//! ([`DriverCounters::foreign_datagrams`], reported as [`FriEvent::ForeignDatagram`]
//! at the 1st, 2nd, 4th, 8th, ... drop) and never answered, so no other process on
//! the KRC network can steer the commanded joint stream. A measurement whose
//! `sendSeqCount` is not newer than the last accepted one (equal, or up to half the
//! 16-bit range behind it, counting across the 65535 -> 0 wrap) is a replay or out of
//! order: it is dropped, counted ([`DriverCounters::stale_measurements`]) and not
//! answered, and it neither advances the trajectory nor changes the driver's view of
//! the robot.
//!
//! # What "stop" does to the hardware
//! - [`FriDriver::stop`] ends a motion with a synchronised deceleration within the
//!   trajectory's acceleration limits, then holds the rest position. The driver keeps
//!   answering every measurement: the drives stay powered and the brakes open, and
//!   the KRC's joint position (or impedance) controller holds the arm there. The
//!   driver never switches drives off or closes brakes; that is the KRC's business
//!   (`friStop`/`friClose` in the KRL program, or the operator's emergency stop).
//! - No measurement for `timeout_s` (a late packet) is a safe stop: the driver cannot
//!   send without a measurement to answer, so it reports
//!   [`FriEvent::MeasurementLate`], aborts the motion with [`FriError::MeasurementLate`]
//!   and stops it as [`FriDriver::stop`] does: when the link returns with the robot
//!   still commanding, the answers decelerate from the last command within the
//!   limits and then hold (holding the last command at once would be a step in
//!   velocity, which the KRC faults on). The robot bridges one
//!   missing answer by extrapolation and then, as link quality falls, drops to
//!   monitor mode and stops the arm under its own control.
//! - When the robot leaves command mode (reported as [`FriEvent::DroppedToMonitor`])
//!   or the quality falls below the minimum, the motion is aborted and the driver
//!   mirrors the robot, which has already stopped the arm.
//! - Dropping the [`FriDriver`] stops answering; the robot then drops to monitor mode
//!   within a few cycles and holds. [`FriDriver::shutdown`] first stops any motion,
//!   then releases the robot: its commands set [`RELEASE_BIT`] of `boolData`
//!   (`$FRI_FRM_BOOL[1]` in KRL), and the cell's KRL program answers with `friStop`,
//!   so the robot leaves command mode on request instead of by a failing link.
//!
//! # Modules
//! - `error`: [`FriError`], what can go wrong.
//! - `config`: [`DriverConfig`] and the robot it answers, [`RobotPeer`].
//! - `event`: [`FriEvent`], what the driver saw or did.
//! - `status`: [`FriStatus`] and [`DriverCounters`], snapshots of the link.
//! - `core`: [`DriverCore`], the protocol state machine, and [`ForceGuard`].
//! - this module: [`FriDriver`], the socket and its thread.

mod config;
mod core;
mod error;
mod event;
mod status;

pub use self::core::{DriverCore, ForceGuard};
pub use config::{DriverConfig, RobotPeer};
pub use error::FriError;
pub use event::FriEvent;
pub use status::{DriverCounters, FriStatus};

use super::JOINTS;
use crate::clock::Clock;
use crate::trajectory::Trajectory;
use std::net::{IpAddr, Ipv4Addr, SocketAddr, UdpSocket};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Condvar, Mutex, MutexGuard};
use std::thread::JoinHandle;
use std::time::Duration;

/// Bit of the command's KRL `boolData` (`$FRI_FRM_BOOL[1]`) by which the PC releases
/// the robot: the cell's KRL program calls `friStop` while it is set, and `friStart`
/// again (once quality is PERFECT) only when it is clear. graspcell's convention,
/// not part of FRI.
pub const RELEASE_BIT: u16 = 1 << 0;

struct Shared {
    core: Mutex<DriverCore>,
    changed: Condvar,
    stop: AtomicBool,
    alive: AtomicBool,
}

impl Shared {
    fn lock(&self) -> MutexGuard<'_, DriverCore> {
        self.core.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// Waits until `done` holds or `timeout_s` passes; `None` on timeout.
    fn wait<R>(
        &self,
        timeout_s: f64,
        mut done: impl FnMut(&mut DriverCore) -> Option<R>,
    ) -> Result<Option<R>, FriError> {
        let deadline = std::time::Instant::now() + Duration::from_secs_f64(timeout_s.max(0.0));
        let mut core = self.lock();
        loop {
            if let Some(r) = done(&mut core) {
                return Ok(Some(r));
            }
            if !self.alive.load(Ordering::Relaxed) {
                return Err(FriError::ShutDown);
            }
            let now = std::time::Instant::now();
            if now >= deadline {
                return Ok(None);
            }
            // Wake at least every 50 ms to notice a dead thread.
            let wait = (deadline - now).min(Duration::from_millis(50));
            core = self
                .changed
                .wait_timeout(core, wait)
                .unwrap_or_else(|e| e.into_inner())
                .0;
        }
    }
}

/// The FRI driver on a UDP socket, answering measurements in a background thread.
pub struct FriDriver {
    shared: Arc<Shared>,
    local_addr: SocketAddr,
    thread: Option<JoinHandle<()>>,
}

impl std::fmt::Debug for FriDriver {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("FriDriver")
            .field("local_addr", &self.local_addr)
            .finish_non_exhaustive()
    }
}

fn io_error(op: &'static str, addr: SocketAddr, e: &std::io::Error) -> FriError {
    FriError::Io {
        op,
        addr,
        kind: e.kind(),
        message: e.to_string(),
    }
}

impl FriDriver {
    /// Binds `config.bind_addr` and starts answering measurements; `clock` times
    /// the late-measurement check.
    pub fn start(config: DriverConfig, clock: Arc<dyn Clock>) -> Result<FriDriver, FriError> {
        let core = DriverCore::new(config)?;
        let socket = UdpSocket::bind(config.bind_addr)
            .map_err(|e| io_error("bind", config.bind_addr, &e))?;
        let local_addr = socket
            .local_addr()
            .map_err(|e| io_error("query local address of", config.bind_addr, &e))?;
        // Wake often enough to notice a late measurement and a shutdown.
        let poll = Duration::from_secs_f64((config.timeout_s / 4.0).clamp(0.001, 0.02));
        socket
            .set_read_timeout(Some(poll))
            .map_err(|e| io_error("set read timeout on", local_addr, &e))?;
        let shared = Arc::new(Shared {
            core: Mutex::new(core),
            changed: Condvar::new(),
            stop: AtomicBool::new(false),
            alive: AtomicBool::new(true),
        });
        let thread = {
            let shared = Arc::clone(&shared);
            std::thread::Builder::new()
                .name("fri-driver".into())
                .spawn(move || {
                    serve(&shared, &socket, clock.as_ref());
                    shared.alive.store(false, Ordering::Relaxed);
                    shared.changed.notify_all();
                })
                .map_err(|e| io_error("start thread for", local_addr, &e))?
        };
        Ok(FriDriver {
            shared,
            local_addr,
            thread: Some(thread),
        })
    }

    /// The bound UDP address (the robot sends measurements here).
    pub fn local_addr(&self) -> SocketAddr {
        self.local_addr
    }

    /// A snapshot of the link and the arm.
    pub fn status(&self) -> FriStatus {
        self.shared.lock().status()
    }

    /// Waits until the driver can command (robot in CMD, powered, quality at least the
    /// minimum).
    pub fn wait_until_commanding(&self, timeout_s: f64) -> Result<FriStatus, FriError> {
        self.shared
            .wait(timeout_s, |core| {
                let status = core.status();
                status.commanding.then_some(status)
            })?
            .ok_or_else(|| {
                let s = self.status();
                FriError::Timeout {
                    what: format!(
                        "command mode (robot {:?}, quality {:?}, power {:#06x})",
                        s.state, s.quality, s.power
                    ),
                    timeout_s,
                }
            })
    }

    /// Starts following `trajectory`; see [`DriverCore::start_trajectory`].
    pub fn start_trajectory(&self, trajectory: Trajectory<JOINTS>) -> Result<u64, FriError> {
        self.shared.lock().start_trajectory(trajectory)
    }

    /// Starts a guarded trajectory; see [`DriverCore::start_guarded_trajectory`].
    pub fn start_guarded_trajectory(
        &self,
        trajectory: Trajectory<JOINTS>,
        guard: ForceGuard,
    ) -> Result<u64, FriError> {
        self.shared
            .lock()
            .start_guarded_trajectory(trajectory, guard)
    }

    /// Waits for motion `id` to end and returns how it ended. On timeout the motion
    /// is stopped (decelerate, then hold) and [`FriError::Timeout`] returned.
    pub fn wait_motion(&self, id: u64, timeout_s: f64) -> Result<(), FriError> {
        match self.shared.wait(timeout_s, |core| core.outcome(id))? {
            Some(result) => result,
            None => {
                self.stop();
                Err(FriError::Timeout {
                    what: format!("motion {id} to finish"),
                    timeout_s,
                })
            }
        }
    }

    /// How motion `id` ended, or `None` while it runs (does not wait).
    pub fn motion_outcome(&self, id: u64) -> Option<Result<(), FriError>> {
        self.shared.lock().outcome(id)
    }

    /// Follows `trajectory` to its end, or returns why it could not; stops the motion
    /// when `timeout_s` passes first.
    pub fn execute(&self, trajectory: Trajectory<JOINTS>, timeout_s: f64) -> Result<(), FriError> {
        let id = self.start_trajectory(trajectory)?;
        self.wait_motion(id, timeout_s)
    }

    /// Stops the running motion: decelerate within limits, then hold.
    pub fn stop(&self) {
        self.shared.lock().stop();
        self.shared.changed.notify_all();
    }

    /// Withholds (`true`) or resumes answers: fault injection for tests, to make the
    /// robot see a failing link.
    pub fn set_withhold_answers(&self, withhold: bool) {
        self.shared.lock().set_withhold_answers(withhold);
    }

    /// Removes and returns the events so far (oldest first).
    pub fn take_events(&self) -> Vec<FriEvent> {
        self.shared.lock().take_events()
    }

    /// Waits for an event that `wanted` accepts and returns it; events before it are
    /// consumed. `None` when `timeout_s` passes first.
    pub fn wait_event(
        &self,
        timeout_s: f64,
        mut wanted: impl FnMut(&FriEvent) -> bool,
    ) -> Result<Option<FriEvent>, FriError> {
        self.shared.wait(timeout_s, |core| {
            while let Some(event) = core.events.pop_front() {
                if wanted(&event) {
                    return Some(event);
                }
            }
            None
        })
    }

    /// Stops any motion, waits (up to `timeout_s`) for the arm to come to rest,
    /// releases the robot and waits (up to `timeout_s` again) for it to leave
    /// command mode, then stops answering. A KRL program that ignores
    /// [`RELEASE_BIT`] makes this a [`FriError::Timeout`]; the robot then drops to
    /// monitor mode as answers stop, and holds.
    pub fn shutdown(mut self, timeout_s: f64) -> Result<(), FriError> {
        self.stop();
        let rested = self
            .shared
            .wait(timeout_s, |core| (!core.is_moving()).then_some(()));
        let released = match &rested {
            Ok(Some(())) => {
                self.shared.lock().release();
                self.shared
                    .wait(timeout_s, |core| core.is_released().then_some(()))
            }
            other => other.clone(),
        };
        self.end_thread();
        match (rested, released) {
            (Ok(None), _) => Err(FriError::Timeout {
                what: "the arm to come to rest before shutdown".into(),
                timeout_s,
            }),
            (_, Ok(None)) => Err(FriError::Timeout {
                what: "the robot to leave command mode (a KRL program that calls friStop \
                       on $FRI_FRM_BOOL[1])"
                    .into(),
                timeout_s,
            }),
            (_, Ok(Some(()))) | (_, Err(FriError::ShutDown)) => Ok(()),
            (_, Err(e)) => Err(e),
        }
    }

    fn end_thread(&mut self) {
        self.shared.stop.store(true, Ordering::Relaxed);
        if let Some(thread) = self.thread.take() {
            let _ = thread.join();
        }
    }
}

impl Drop for FriDriver {
    fn drop(&mut self) {
        self.end_thread();
    }
}

/// The driver thread: answer each measurement at once; check for late ones.
fn serve(shared: &Shared, socket: &UdpSocket, clock: &dyn Clock) {
    crate::hw::realtime::request_device_cycle_priority("FRI driver");
    let mut buf = [0u8; 2048];
    while !shared.stop.load(Ordering::Relaxed) {
        let received = socket.recv_from(&mut buf);
        let now = clock.now();
        let mut core = shared.lock();
        match received {
            Ok((n, from)) => {
                if let Some(command) = core.on_datagram(&buf[..n], from, now) {
                    if let Err(e) = socket.send_to(&command.encode(), from) {
                        let error = io_error("send command to", from, &e);
                        core.push(FriEvent::SocketError { error });
                    }
                }
            }
            Err(e) if super::is_quiet_receive(&e) => {}
            Err(e) => {
                let error = io_error("receive on", socket.local_addr().unwrap_or(UNSPECIFIED), &e);
                core.push(FriEvent::SocketError { error });
            }
        }
        core.check_late(now);
        drop(core);
        shared.changed.notify_all();
    }
}

const UNSPECIFIED: SocketAddr = SocketAddr::new(IpAddr::V4(Ipv4Addr::UNSPECIFIED), 0);
