//! An in-process virtual CAN bus: many endpoints, broadcast like a real bus, with
//! injectable frame loss, corruption, latency and bus-off.
//!
//! Faults are drawn once per sent frame (every receiver sees the same loss or the
//! same corruption, as on a shared wire), from a ChaCha8 generator seeded by
//! [`FaultConfig::seed`]. Latency delays delivery in real time but never reorders
//! frames. As on CAN without loopback, a sender does not receive its own frames.

use super::{BusState, CanBus, CanError, CanFrame};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use std::collections::{HashMap, HashSet, VecDeque};
use std::ops::RangeInclusive;
use std::sync::{Arc, Condvar, Mutex, MutexGuard};
use std::time::{Duration, Instant};

/// How a corrupted frame is damaged.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Corruption {
    /// One random data bit inverted (frames without data pass unchanged).
    FlipBit,
    /// The DLC cut to a random shorter length (frames without data pass unchanged).
    Truncate,
    /// Either of the above, with equal probability.
    Either,
}

/// Faults injected into every frame sent on a [`VirtualBus`].
#[derive(Debug, Clone, PartialEq)]
pub struct FaultConfig {
    /// Probability (0..=1) that a frame reaches no receiver.
    pub loss_probability: f64,
    /// Probability (0..=1) that a delivered frame is corrupted.
    pub corrupt_probability: f64,
    /// How corrupted frames are damaged.
    pub corruption: Corruption,
    /// Delay between send and delivery.
    pub latency: Duration,
    /// Only frames with identifiers in this range suffer loss and corruption
    /// (`None`: all frames).
    pub affected_ids: Option<RangeInclusive<u16>>,
    /// Seed of the fault generator.
    pub seed: u64,
}

impl Default for FaultConfig {
    /// No faults, no latency, seed 0.
    fn default() -> Self {
        FaultConfig {
            loss_probability: 0.0,
            corrupt_probability: 0.0,
            corruption: Corruption::Either,
            latency: Duration::ZERO,
            affected_ids: None,
            seed: 0,
        }
    }
}

impl FaultConfig {
    pub(super) fn validate(&self, bus: &str) -> Result<(), CanError> {
        for (field, p) in [
            ("loss_probability", self.loss_probability),
            ("corrupt_probability", self.corrupt_probability),
        ] {
            if !(0.0..=1.0).contains(&p) {
                return Err(CanError::BadInterface {
                    interface: bus.to_string(),
                    problem: format!("fault {field} = {p} is not a probability in 0..=1"),
                });
            }
        }
        Ok(())
    }
}

/// What the fault injector did so far.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct FaultCounts {
    /// Frames sent on the bus.
    pub sent: u64,
    /// Frames lost.
    pub lost: u64,
    /// Frames corrupted.
    pub corrupted: u64,
}

/// An in-process CAN bus; [`VirtualBus::endpoint`] attaches a node. Clones share
/// the bus.
#[derive(Clone)]
pub struct VirtualBus {
    shared: Arc<Shared>,
}

struct Shared {
    interface: String,
    inner: Mutex<Inner>,
    arrived: Condvar,
}

struct Inner {
    queues: HashMap<u64, VecDeque<(Instant, CanFrame)>>,
    next_endpoint: u64,
    injector: FaultInjector,
    bus_off: bool,
    /// Endpoints blocked in `recv` right now.
    waiting: HashSet<u64>,
}

impl VirtualBus {
    /// A fault-free bus; `name` only labels it (`inproc:NAME` in messages).
    pub fn new(name: &str) -> VirtualBus {
        VirtualBus {
            shared: Arc::new(Shared {
                interface: format!("inproc:{name}"),
                inner: Mutex::new(Inner {
                    queues: HashMap::new(),
                    next_endpoint: 0,
                    injector: FaultInjector::new(FaultConfig::default()),
                    bus_off: false,
                    waiting: HashSet::new(),
                }),
                arrived: Condvar::new(),
            }),
        }
    }

    /// A bus with faults injected from the start.
    pub fn with_faults(name: &str, faults: FaultConfig) -> Result<VirtualBus, CanError> {
        let bus = VirtualBus::new(name);
        bus.set_faults(faults)?;
        Ok(bus)
    }

    /// Replaces the fault configuration and reseeds the generator from it.
    pub fn set_faults(&self, faults: FaultConfig) -> Result<(), CanError> {
        faults.validate(&self.shared.interface)?;
        tracing::info!(bus = %self.shared.interface, seed = faults.seed, ?faults, "CAN faults set");
        self.lock().injector = FaultInjector::new(faults);
        Ok(())
    }

    /// Puts every node into (or out of) bus-off: sends and receives then fail.
    pub fn set_bus_off(&self, bus_off: bool) {
        self.lock().bus_off = bus_off;
        self.shared.arrived.notify_all();
    }

    /// Counts of sent, lost and corrupted frames.
    pub fn fault_counts(&self) -> FaultCounts {
        self.lock().injector.counts
    }

    /// The interface label, `inproc:NAME`.
    pub fn interface(&self) -> &str {
        &self.shared.interface
    }

    /// Attaches a new node; it receives the frames sent after this call.
    pub fn endpoint(&self) -> VirtualEndpoint {
        let mut inner = self.lock();
        let id = inner.next_endpoint;
        inner.next_endpoint += 1;
        inner.queues.insert(id, VecDeque::new());
        VirtualEndpoint {
            shared: Arc::clone(&self.shared),
            id,
        }
    }

    fn lock(&self) -> MutexGuard<'_, Inner> {
        self.shared.lock()
    }
}

impl Shared {
    fn lock(&self) -> MutexGuard<'_, Inner> {
        self.inner.lock().unwrap_or_else(|e| e.into_inner())
    }
}

/// Draws the faults of a [`FaultConfig`] frame by frame (shared with the
/// cross-process hub, which applies them to every frame it forwards).
pub(super) struct FaultInjector {
    pub(super) faults: FaultConfig,
    rng: ChaCha8Rng,
    pub(super) counts: FaultCounts,
}

impl FaultInjector {
    /// An injector seeded from `faults.seed`; `faults` must have been validated.
    pub(super) fn new(faults: FaultConfig) -> FaultInjector {
        FaultInjector {
            rng: ChaCha8Rng::seed_from_u64(faults.seed),
            faults,
            counts: FaultCounts::default(),
        }
    }

    /// Takes the probabilities, corruption and affected identifiers of `faults`
    /// (validated), keeping the generator and the counts.
    pub(super) fn set(&mut self, faults: &FaultConfig) {
        self.faults = FaultConfig {
            seed: self.faults.seed,
            latency: self.faults.latency,
            ..faults.clone()
        };
    }

    /// Applies loss and corruption; `None` when the frame is lost.
    pub(super) fn inject(&mut self, frame: &CanFrame) -> Option<CanFrame> {
        self.counts.sent += 1;
        let affected = match &self.faults.affected_ids {
            Some(range) => range.contains(&frame.id()),
            None => true,
        };
        if !affected {
            return Some(*frame);
        }
        if self.faults.loss_probability > 0.0
            && self.rng.gen::<f64>() < self.faults.loss_probability
        {
            self.counts.lost += 1;
            return None;
        }
        if frame.is_empty()
            || !(self.faults.corrupt_probability > 0.0
                && self.rng.gen::<f64>() < self.faults.corrupt_probability)
        {
            return Some(*frame);
        }
        let truncate = match self.faults.corruption {
            Corruption::FlipBit => false,
            Corruption::Truncate => true,
            Corruption::Either => self.rng.gen::<bool>(),
        };
        self.counts.corrupted += 1;
        Some(if truncate {
            frame.truncated(self.rng.gen_range(0..frame.len()))
        } else {
            frame.with_bit_flipped(self.rng.gen_range(0..frame.len() * 8))
        })
    }
}

/// One node on a [`VirtualBus`].
pub struct VirtualEndpoint {
    shared: Arc<Shared>,
    id: u64,
}

impl VirtualEndpoint {
    fn bus_off(&self) -> CanError {
        CanError::BusOff {
            interface: self.shared.interface.clone(),
        }
    }
}

impl CanBus for VirtualEndpoint {
    fn send(&mut self, frame: &CanFrame) -> Result<(), CanError> {
        let mut inner = self.shared.lock();
        if inner.bus_off {
            return Err(self.bus_off());
        }
        let Some(frame) = inner.injector.inject(frame) else {
            return Ok(());
        };
        let deliver_at = Instant::now() + inner.injector.faults.latency;
        for (&id, queue) in inner.queues.iter_mut() {
            if id != self.id {
                // Never before the frame ahead of it: CAN does not reorder.
                let at = queue.back().map_or(deliver_at, |&(t, _)| t.max(deliver_at));
                queue.push_back((at, frame));
            }
        }
        drop(inner);
        self.shared.arrived.notify_all();
        Ok(())
    }

    fn recv(&mut self, timeout: Duration) -> Result<Option<CanFrame>, CanError> {
        let deadline = Instant::now() + timeout;
        let mut inner = self.shared.lock();
        let result = loop {
            if inner.bus_off {
                break Err(self.bus_off());
            }
            let now = Instant::now();
            let head = inner.queues.get(&self.id).and_then(|q| q.front().copied());
            let wake_at = match head {
                Some((at, frame)) if at <= now => {
                    if let Some(queue) = inner.queues.get_mut(&self.id) {
                        queue.pop_front();
                    }
                    break Ok(Some(frame));
                }
                Some((at, _)) => at.min(deadline),
                None => deadline,
            };
            if now >= deadline {
                break Ok(None);
            }
            if inner.waiting.insert(self.id) {
                // An idle probe may be waiting for this.
                self.shared.arrived.notify_all();
            }
            inner = self
                .shared
                .arrived
                .wait_timeout(inner, wake_at.saturating_duration_since(now))
                .unwrap_or_else(|e| e.into_inner())
                .0;
        };
        inner.waiting.remove(&self.id);
        result
    }

    fn state(&self) -> BusState {
        if self.shared.lock().bus_off {
            BusState::BusOff
        } else {
            BusState::ErrorActive
        }
    }

    fn interface(&self) -> &str {
        &self.shared.interface
    }
}

impl VirtualEndpoint {
    /// A handle that tells when this endpoint's owner has handled everything sent
    /// to it; see [`IdleProbe`].
    pub fn idle_probe(&self) -> IdleProbe {
        IdleProbe {
            shared: Arc::clone(&self.shared),
            id: self.id,
        }
    }
}

impl Drop for VirtualEndpoint {
    fn drop(&mut self) {
        self.shared.lock().queues.remove(&self.id);
        self.shared.arrived.notify_all();
    }
}

/// Watches one endpoint whose owner serves it in a receive loop (an emulator):
/// the owner is idle when it is blocked in `recv` with nothing queued, so it has
/// handled every frame sent to it so far.
///
/// Tests pair it with [`crate::clock::ManualClock::with_settle`], so virtual time
/// advances only after the emulator has seen what the driver sent.
#[derive(Clone)]
pub struct IdleProbe {
    shared: Arc<Shared>,
    id: u64,
}

impl IdleProbe {
    /// Waits until the endpoint is idle (or gone); false if `timeout` passed first.
    pub fn wait_idle(&self, timeout: Duration) -> bool {
        let deadline = Instant::now() + timeout;
        let mut inner = self.shared.lock();
        loop {
            let idle = match inner.queues.get(&self.id) {
                None => true,
                Some(queue) => queue.is_empty() && inner.waiting.contains(&self.id),
            };
            if idle {
                return true;
            }
            let now = Instant::now();
            if now >= deadline {
                return false;
            }
            inner = self
                .shared
                .arrived
                .wait_timeout(inner, deadline - now)
                .unwrap_or_else(|e| e.into_inner())
                .0;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn frame(id: u16, data: &[u8]) -> CanFrame {
        CanFrame::new(id, data).unwrap()
    }

    #[test]
    fn loss_rate_follows_probability_and_seed_reproduces() {
        let run = |seed| {
            let bus = VirtualBus::with_faults(
                "loss",
                FaultConfig {
                    loss_probability: 0.25,
                    seed,
                    ..FaultConfig::default()
                },
            )
            .unwrap();
            let mut a = bus.endpoint();
            let mut b = bus.endpoint();
            let mut got = Vec::new();
            for i in 0..2000u16 {
                a.send(&frame(i & 0x7FF, &i.to_le_bytes())).unwrap();
                if let Some(f) = b.recv(Duration::ZERO).unwrap() {
                    got.push(f);
                }
            }
            assert_eq!(bus.fault_counts().lost as usize, 2000 - got.len());
            got
        };
        let first = run(7);
        // Binomial(2000, 0.75): mean 1500, sd 19.4; +-5 sd.
        assert!((1403..=1597).contains(&first.len()), "{}", first.len());
        assert_eq!(first, run(7));
        assert_ne!(first, run(8));
    }

    #[test]
    fn corruption_only_hits_affected_ids_and_changes_the_frame() {
        let bus = VirtualBus::with_faults(
            "corrupt",
            FaultConfig {
                corrupt_probability: 1.0,
                corruption: Corruption::Truncate,
                affected_ids: Some(0x560..=0x57F),
                ..FaultConfig::default()
            },
        )
        .unwrap();
        let mut a = bus.endpoint();
        let mut b = bus.endpoint();
        let hit = frame(0x566, &[0x81, 0, 5, 8]);
        let spared = frame(0x586, &[0x81, 0, 5, 8]);
        a.send(&hit).unwrap();
        a.send(&spared).unwrap();
        let got = b.recv(Duration::ZERO).unwrap().unwrap();
        assert_eq!(got.id(), 0x566);
        assert!(got.len() < 4 && got.data() == &hit.data()[..got.len()]);
        assert_eq!(b.recv(Duration::ZERO).unwrap(), Some(spared));
        assert_eq!(bus.fault_counts().corrupted, 1);

        bus.set_faults(FaultConfig {
            corrupt_probability: 1.0,
            corruption: Corruption::FlipBit,
            ..FaultConfig::default()
        })
        .unwrap();
        a.send(&hit).unwrap();
        let got = b.recv(Duration::ZERO).unwrap().unwrap();
        let differing_bits: u32 = got
            .data()
            .iter()
            .zip(hit.data())
            .map(|(x, y)| (x ^ y).count_ones())
            .sum();
        assert_eq!((got.len(), differing_bits), (4, 1));
    }

    #[test]
    fn latency_delays_but_keeps_order() {
        let bus = VirtualBus::with_faults(
            "latency",
            FaultConfig {
                latency: Duration::from_millis(30),
                ..FaultConfig::default()
            },
        )
        .unwrap();
        let mut a = bus.endpoint();
        let mut b = bus.endpoint();
        let sent_at = Instant::now();
        a.send(&frame(1, &[1])).unwrap();
        a.send(&frame(2, &[2])).unwrap();
        assert_eq!(b.recv(Duration::ZERO).unwrap(), None);
        assert_eq!(b.recv(Duration::from_secs(5)).unwrap().unwrap().id(), 1);
        assert!(sent_at.elapsed() >= Duration::from_millis(30));
        assert_eq!(b.recv(Duration::from_secs(5)).unwrap().unwrap().id(), 2);
    }

    #[test]
    fn bus_off_is_reported_and_recovers() {
        let bus = VirtualBus::new("busoff");
        let mut a = bus.endpoint();
        bus.set_bus_off(true);
        assert_eq!(a.state(), BusState::BusOff);
        let err = a.send(&frame(1, &[])).unwrap_err().to_string();
        assert!(
            err.contains("inproc:busoff") && err.contains("bus-off"),
            "{err}"
        );
        assert!(a.recv(Duration::ZERO).is_err());
        bus.set_bus_off(false);
        assert_eq!(a.state(), BusState::ErrorActive);
        a.send(&frame(1, &[])).unwrap();
    }

    #[test]
    fn idle_probe_waits_until_the_server_has_handled_its_frames() {
        let bus = VirtualBus::new("idle");
        let mut client = bus.endpoint();
        let mut server = bus.endpoint();
        let probe = server.idle_probe();
        // Not yet serving: not idle.
        assert!(!probe.wait_idle(Duration::from_millis(10)));
        let handled = Arc::new(Mutex::new(Vec::new()));
        let log = Arc::clone(&handled);
        let thread = std::thread::spawn(move || {
            while let Some(f) = server.recv(Duration::from_millis(500)).unwrap() {
                log.lock().unwrap().push(f.id());
            }
        });
        for id in 1..=50 {
            client.send(&frame(id, &[])).unwrap();
            assert!(probe.wait_idle(Duration::from_secs(10)));
            assert_eq!(handled.lock().unwrap().len(), usize::from(id));
        }
        thread.join().unwrap();
        // Gone counts as idle.
        assert!(probe.wait_idle(Duration::ZERO));
    }

    #[test]
    fn bad_probability_is_rejected() {
        let err = VirtualBus::with_faults(
            "bad",
            FaultConfig {
                loss_probability: 1.5,
                ..FaultConfig::default()
            },
        )
        .err()
        .unwrap()
        .to_string();
        assert!(err.contains("loss_probability = 1.5"), "{err}");
    }
}
