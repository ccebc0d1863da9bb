//! The environment's force on the simulated arm (`estExtTcpFT`): the model, and a
//! thread that evaluates an expensive model beside the simulator's cycle.

use crate::hw::fri::JOINTS;
use std::fmt;
use std::time::Duration;

/// What the environment does to the simulated arm: the force and torque at the
/// tool that FRI reports as `estExtTcpFT`.
pub trait ExternalForce: Send {
    /// Fx Fy Fz (N) Tz Ty Tx (N m) at the tool, tool frame, with the arm at
    /// `measured_rad`.
    fn tcp_ft(&mut self, measured_rad: &[f64; JOINTS]) -> [f64; 6];
}

/// A force model evaluated beside the simulator's cycle: [`ExternalForce::tcp_ft`]
/// answers at once with the latest force a worker thread computed from the
/// latest measured joints, so an expensive model (the simulated world's contact
/// queries) never delays a measurement or an answer's reception. The force lags
/// the arm by one evaluation of the model (about a millisecond). The cycle never
/// waits for the worker: should the worker (at the lowest priority) hold the
/// shared state, the cycle keeps the force it last read and hands the joints over
/// in a later cycle. For lockstep tests, plug the model in directly instead.
pub struct BackgroundForce {
    shared: std::sync::Arc<std::sync::Mutex<BackgroundState>>,
    /// The force the cycle last read.
    last_tcp_ft: [f64; 6],
    stop: std::sync::Arc<std::sync::atomic::AtomicBool>,
    worker: Option<std::thread::JoinHandle<()>>,
}

/// The joints handed to the worker and the force it last computed.
#[derive(Default)]
struct BackgroundState {
    joints: Option<[f64; JOINTS]>,
    tcp_ft: [f64; 6],
}

impl BackgroundForce {
    /// Runs `model` on a thread of its own (lowest ordinary priority), evaluating
    /// it whenever new joints arrive, at most every `period`.
    pub fn new(mut model: Box<dyn ExternalForce>, period: Duration) -> std::io::Result<Self> {
        use std::sync::atomic::Ordering;
        let shared = std::sync::Arc::new(std::sync::Mutex::new(BackgroundState::default()));
        let stop = std::sync::Arc::new(std::sync::atomic::AtomicBool::new(false));
        let (state, quit) = (shared.clone(), stop.clone());
        let worker = std::thread::Builder::new()
            .name("external-force".into())
            .spawn(move || {
                crate::hw::realtime::lower_thread_priority();
                while !quit.load(Ordering::Relaxed) {
                    let joints = state
                        .lock()
                        .unwrap_or_else(|e| e.into_inner())
                        .joints
                        .take();
                    if let Some(q) = joints {
                        let f = model.tcp_ft(&q);
                        state.lock().unwrap_or_else(|e| e.into_inner()).tcp_ft = f;
                    }
                    std::thread::sleep(period);
                }
            })?;
        Ok(BackgroundForce {
            shared,
            last_tcp_ft: [0.0; 6],
            stop,
            worker: Some(worker),
        })
    }
}

impl ExternalForce for BackgroundForce {
    fn tcp_ft(&mut self, measured_rad: &[f64; JOINTS]) -> [f64; 6] {
        let state = match self.shared.try_lock() {
            Ok(state) => Some(state),
            Err(std::sync::TryLockError::Poisoned(e)) => Some(e.into_inner()),
            Err(std::sync::TryLockError::WouldBlock) => None,
        };
        if let Some(mut state) = state {
            state.joints = Some(*measured_rad);
            self.last_tcp_ft = state.tcp_ft;
        }
        self.last_tcp_ft
    }
}

impl Drop for BackgroundForce {
    fn drop(&mut self) {
        self.stop.store(true, std::sync::atomic::Ordering::Relaxed);
        if let Some(w) = self.worker.take() {
            let _ = w.join();
        }
    }
}

/// The optional force model, printable.
pub(super) struct ForceModel(pub(super) Option<Box<dyn ExternalForce>>);

impl fmt::Debug for ForceModel {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(if self.0.is_some() { "Some(..)" } else { "None" })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::time::Instant;

    struct Constant;

    impl ExternalForce for Constant {
        fn tcp_ft(&mut self, _: &[f64; JOINTS]) -> [f64; 6] {
            [1.0, 2.0, 3.0, 0.0, 0.0, 0.0]
        }
    }

    #[test]
    fn the_cycle_never_waits_for_the_worker() {
        let mut force = BackgroundForce::new(Box::new(Constant), Duration::from_millis(1)).unwrap();
        let q = [0.0; JOINTS];
        let want = [1.0, 2.0, 3.0, 0.0, 0.0, 0.0];
        let deadline = Instant::now() + Duration::from_secs(5);
        while force.tcp_ft(&q) != want {
            assert!(Instant::now() < deadline, "the worker never computed");
            std::thread::sleep(Duration::from_millis(1));
        }
        // The shared state held (as by the worker, preempted inside it): the
        // cycle answers at once with the force it last read.
        let shared = std::sync::Arc::clone(&force.shared);
        let held = shared.lock().unwrap();
        let (send, answer) = std::sync::mpsc::channel();
        let cycle = std::thread::spawn(move || {
            send.send(force.tcp_ft(&q)).unwrap();
            force
        });
        assert_eq!(answer.recv_timeout(Duration::from_secs(5)), Ok(want));
        drop(held);
        drop(cycle.join().unwrap());
    }
}
