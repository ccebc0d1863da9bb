//! The simulator on a UDP socket with a real clock (`cell-sim-arm`).

use super::{FriSimulator, SimConfig, SimError, SimSummary};
use crate::clock::Clock;
use std::net::{SocketAddr, UdpSocket};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex, MutexGuard};
use std::thread::JoinHandle;
use std::time::Duration;

fn lock(sim: &Mutex<FriSimulator>) -> MutexGuard<'_, FriSimulator> {
    sim.lock().unwrap_or_else(|e| e.into_inner())
}

/// Runs `sim` on `socket` until `stop` is set or the clock passes `until`: sends each
/// due measurement to `pc_addr` and feeds every received datagram, stamped on arrival,
/// to the simulator. A receiving thread blocks on the socket; this thread sleeps
/// until each measurement is due.
pub fn run_udp(
    sim: &Mutex<FriSimulator>,
    socket: &UdpSocket,
    pc_addr: SocketAddr,
    clock: &dyn Clock,
    stop: &AtomicBool,
    until: Option<Duration>,
) -> Result<(), SimError> {
    let local = socket.local_addr().map_err(|source| SimError::Io {
        op: "query local address of",
        addr: pc_addr,
        source,
    })?;
    let io = |op, source| SimError::Io {
        op,
        addr: local,
        source,
    };
    socket
        .set_read_timeout(Some(Duration::from_millis(20)))
        .map_err(|e| io("set read timeout on", e))?;
    std::thread::scope(|scope| {
        let receiver = scope.spawn(|| -> Result<(), SimError> {
            crate::hw::realtime::request_device_cycle_priority("FRI sim receiver");
            let mut buf = [0u8; 2048];
            while !stop.load(Ordering::Relaxed) {
                match socket.recv_from(&mut buf) {
                    Ok((n, _from)) => {
                        let now = clock.now();
                        lock(sim).receive(&buf[..n], now);
                    }
                    Err(e) if crate::hw::fri::is_quiet_receive(&e) => {}
                    Err(e) => return Err(io("receive on", e)),
                }
            }
            Ok(())
        });
        // The sending loop runs here (the robot's real-time cycle); it ends at `stop`,
        // at `until`, or when the receiver fails.
        crate::hw::realtime::request_device_cycle_priority("FRI sim sender");
        while !stop.load(Ordering::Relaxed) && !receiver.is_finished() {
            let now = clock.now();
            if until.is_some_and(|end| now >= end) {
                break;
            }
            let (measurement, next) = {
                let mut sim = lock(sim);
                let m = sim.poll(now);
                (m, sim.next_send_time())
            };
            if let Some(m) = measurement {
                if let Err(e) = socket.send_to(&m.encode(), pc_addr) {
                    // The robot keeps sending whether or not anyone listens.
                    tracing::debug!("FRI sim: send to {pc_addr}: {e}");
                }
            }
            let wait = next.saturating_sub(clock.now());
            if !wait.is_zero() {
                std::thread::sleep(wait);
            }
        }
        stop.store(true, Ordering::Relaxed);
        receiver.join().unwrap_or(Ok(()))
    })
}

/// A simulator running on its own threads; see [`spawn_udp`].
#[derive(Debug)]
pub struct SimHandle {
    sim: Arc<Mutex<FriSimulator>>,
    stop: Arc<AtomicBool>,
    local_addr: SocketAddr,
    thread: Option<JoinHandle<Result<(), SimError>>>,
}

impl SimHandle {
    /// The robot's UDP address.
    pub fn local_addr(&self) -> SocketAddr {
        self.local_addr
    }

    /// Runs `f` on the simulator (briefly: the robot's cycle waits for it).
    pub fn with<R>(&self, f: impl FnOnce(&mut FriSimulator) -> R) -> R {
        f(&mut lock(&self.sim))
    }

    /// Stops sending and receiving and returns the final simulator.
    pub fn stop(mut self) -> Result<SimSummary, SimError> {
        self.stop.store(true, Ordering::Relaxed);
        if let Some(thread) = self.thread.take() {
            thread.join().unwrap_or(Ok(()))?;
        }
        Ok(lock(&self.sim).summary())
    }
}

impl Drop for SimHandle {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        if let Some(thread) = self.thread.take() {
            let _ = thread.join();
        }
    }
}

/// Binds `bind` and runs a simulator on background threads, sending measurements
/// to `pc_addr` on `clock`'s time, until [`SimHandle::stop`] or drop.
pub fn spawn_udp(
    config: SimConfig,
    bind: SocketAddr,
    pc_addr: SocketAddr,
    clock: Arc<dyn Clock>,
) -> Result<SimHandle, SimError> {
    let sim = Arc::new(Mutex::new(FriSimulator::new(config)?));
    let socket = UdpSocket::bind(bind).map_err(|source| SimError::Io {
        op: "bind",
        addr: bind,
        source,
    })?;
    let local_addr = socket.local_addr().map_err(|source| SimError::Io {
        op: "query local address of",
        addr: bind,
        source,
    })?;
    let stop = Arc::new(AtomicBool::new(false));
    let thread = {
        let (sim, stop) = (Arc::clone(&sim), Arc::clone(&stop));
        std::thread::Builder::new()
            .name("fri-sim".into())
            .spawn(move || run_udp(&sim, &socket, pc_addr, clock.as_ref(), &stop, None))
            .map_err(|source| SimError::Io {
                op: "start thread for",
                addr: local_addr,
                source,
            })?
    };
    Ok(SimHandle {
        sim,
        stop,
        local_addr,
        thread: Some(thread),
    })
}
