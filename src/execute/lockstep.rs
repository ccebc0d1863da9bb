//! For unit tests: the FRI robot simulator and the driver's protocol core joined in
//! lockstep with an injected clock. Whenever the arm is asked anything, every
//! measurement due up to the clock's now is sent (encoded and decoded, as on the
//! wire) and answered at once, so a test on a manual clock runs the real protocol
//! deterministically, without sockets or threads.

use super::arm::Arm;
use crate::clock::Clock;
use crate::hw::fri::driver::DriverCore;
use crate::hw::fri::{DriverConfig, ForceGuard, FriError, FriStatus, MeasurementDatagram, JOINTS};
use crate::sim::fri::{FriSimulator, SimConfig};
use crate::trajectory::Trajectory;
use std::sync::{Arc, Mutex, MutexGuard};

struct Inner {
    sim: FriSimulator,
    core: DriverCore,
    opened: bool,
    silent: bool,
}

/// A simulated arm on a simulated link, advanced by the clock.
pub(crate) struct LockstepArm {
    inner: Mutex<Inner>,
    clock: Arc<dyn Clock>,
}

impl LockstepArm {
    /// The robot of `sim` and a driver with `timeout_s`, on `clock`.
    pub(crate) fn new(sim: SimConfig, timeout_s: f64, clock: Arc<dyn Clock>) -> LockstepArm {
        let core = DriverCore::new(DriverConfig {
            timeout_s,
            ..DriverConfig::default()
        })
        .unwrap();
        LockstepArm {
            inner: Mutex::new(Inner {
                sim: FriSimulator::new(sim).unwrap(),
                core,
                opened: false,
                silent: false,
            }),
            clock,
        }
    }

    /// Withholds (or resumes) the driver's answers.
    pub(crate) fn set_withhold_answers(&self, withhold: bool) {
        self.advance().core.set_withhold_answers(withhold);
    }

    /// Stops (or resumes) the robot's measurements: the link goes silent.
    pub(crate) fn set_silent(&self, silent: bool) {
        self.advance().silent = silent;
    }

    /// Runs `f` on the simulated robot, brought up to date.
    pub(crate) fn with_sim<R>(&self, f: impl FnOnce(&mut FriSimulator) -> R) -> R {
        f(&mut self.advance().sim)
    }

    /// Exchanges every datagram due up to now.
    fn advance(&self) -> MutexGuard<'_, Inner> {
        let now = self.clock.now();
        let mut guard = self.inner.lock().unwrap_or_else(|e| e.into_inner());
        let inner = &mut *guard;
        if !inner.silent {
            if !inner.opened {
                inner.opened = true;
                exchange(inner, now);
            }
            while inner.sim.next_send_time() <= now {
                let t = inner.sim.next_send_time();
                exchange(inner, t);
            }
        }
        inner.core.check_late(now);
        guard
    }
}

/// One measurement at `t`, answered at `t`.
fn exchange(inner: &mut Inner, t: std::time::Duration) {
    if let Some(m) = inner.sim.poll(t) {
        let received = MeasurementDatagram::decode(&m.encode()).unwrap();
        if let Some(command) = inner.core.on_measurement(&received, t) {
            inner.sim.receive(&command.encode(), t);
        }
    }
    inner.core.check_late(t);
}

impl Arm for LockstepArm {
    fn status(&self) -> FriStatus {
        self.advance().core.status()
    }

    fn start_trajectory(&self, trajectory: Trajectory<JOINTS>) -> Result<u64, FriError> {
        self.advance().core.start_trajectory(trajectory)
    }

    fn start_guarded_trajectory(
        &self,
        trajectory: Trajectory<JOINTS>,
        guard: ForceGuard,
    ) -> Result<u64, FriError> {
        self.advance()
            .core
            .start_guarded_trajectory(trajectory, guard)
    }

    fn motion_outcome(&self, id: u64) -> Option<Result<(), FriError>> {
        self.advance().core.outcome(id)
    }

    fn stop(&self) {
        self.advance().core.stop()
    }
}
