//! A faulty FRI network between the (simulated) robot and the PC: a UDP relay that
//! forwards the robot's measurements to the PC and the PC's answers back, and on
//! request withholds answers (they never reach the robot), delays them (they arrive
//! late), or lets a third host send forged measurements to the PC (a spoofed
//! sender). The fault campaign (`cell chaos`) puts it between `cell-sim-arm` and
//! `cell-execute`; the PC's driver is pinned to the relay's PC-facing address, as on
//! the real cell it is pinned to the KRC.

use crate::hw::fri::datagram::MeasurementDatagram;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use std::net::{SocketAddr, UdpSocket};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc;
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

/// What the link does wrong (all zero: a perfect link).
#[derive(Debug, Clone, Copy, Default, PartialEq, serde::Serialize)]
pub struct LinkFaults {
    /// Probability (0..=1) that an answer of the PC never reaches the robot.
    pub withhold_probability: f64,
    /// Delay (s) added to every answer of the PC on its way to the robot.
    pub answer_delay_s: f64,
    /// Probability (0..=1), per measurement, that a third host also sends the PC a
    /// forged measurement (the real one with every joint moved by 0.2 rad).
    pub spoof_probability: f64,
}

/// Link faults out of range: a probability outside 0..=1 or a delay outside 0..=1 s.
#[derive(Debug, Clone, Copy, PartialEq, thiserror::Error)]
#[error("FRI link faults {faults:?}: probabilities must lie in 0..=1 and the delay in 0..=1 s")]
pub struct BadLinkFaults {
    /// The faults asked for.
    pub faults: LinkFaults,
}

impl LinkFaults {
    fn validate(&self) -> Result<(), BadLinkFaults> {
        let p = |v: f64| (0.0..=1.0).contains(&v);
        if !(p(self.withhold_probability)
            && p(self.spoof_probability)
            && self.answer_delay_s.is_finite()
            && (0.0..=1.0).contains(&self.answer_delay_s))
        {
            return Err(BadLinkFaults { faults: *self });
        }
        Ok(())
    }
}

/// What the link has done so far.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, serde::Serialize)]
pub struct LinkCounts {
    /// Measurements forwarded to the PC.
    pub measurements: u64,
    /// Answers forwarded to the robot (in time or late).
    pub answers: u64,
    /// Answers withheld.
    pub withheld: u64,
    /// Answers delivered late.
    pub delayed: u64,
    /// Forged measurements sent to the PC from the third host.
    pub spoofed: u64,
}

#[derive(Default)]
struct Shared {
    faults: LinkFaults,
    counts: LinkCounts,
    /// Where the robot sends from (learned from its first measurement).
    robot: Option<SocketAddr>,
}

/// The running relay; stops on drop.
pub struct FaultyLink {
    robot_facing: SocketAddr,
    pc_facing: SocketAddr,
    shared: Arc<Mutex<Shared>>,
    stop: Arc<AtomicBool>,
    threads: Vec<JoinHandle<()>>,
}

fn lock(shared: &Mutex<Shared>) -> std::sync::MutexGuard<'_, Shared> {
    shared.lock().unwrap_or_else(|e| e.into_inner())
}

fn bind_local() -> std::io::Result<UdpSocket> {
    let socket = UdpSocket::bind("127.0.0.1:0")?;
    socket.set_read_timeout(Some(Duration::from_millis(20)))?;
    Ok(socket)
}

/// A relay thread at the device cycle's real-time priority: every datagram
/// received on `socket` goes to `forward` with its sender, until `stop`.
fn relay(
    name: &'static str,
    socket: Arc<UdpSocket>,
    stop: Arc<AtomicBool>,
    mut forward: impl FnMut(&[u8], SocketAddr) + Send + 'static,
) -> std::thread::JoinHandle<()> {
    std::thread::spawn(move || {
        crate::hw::realtime::request_device_cycle_priority(name);
        let mut buf = [0u8; 2048];
        while !stop.load(Ordering::Relaxed) {
            if let Ok((n, from)) = socket.recv_from(&mut buf) {
                forward(&buf[..n], from);
            }
        }
    })
}

impl FaultyLink {
    /// Starts a relay to the PC's driver at `pc_addr` on loopback ports of its own;
    /// faults are drawn from a generator seeded with `seed`.
    pub fn start(pc_addr: SocketAddr, seed: u64) -> std::io::Result<FaultyLink> {
        let robot_side = Arc::new(bind_local()?);
        let pc_side = Arc::new(bind_local()?);
        let spoofer = bind_local()?;
        let shared = Arc::new(Mutex::new(Shared::default()));
        let stop = Arc::new(AtomicBool::new(false));
        let (to_robot, due) = mpsc::channel::<(Instant, Vec<u8>)>();
        let mut link = FaultyLink {
            robot_facing: robot_side.local_addr()?,
            pc_facing: pc_side.local_addr()?,
            shared: shared.clone(),
            stop: stop.clone(),
            threads: Vec::new(),
        };
        // Robot -> PC: measurements, and now and then a forged one from a third host.
        // Every hop of the robot's cycle is as urgent as the threads either side.
        {
            let (pc_side, shared) = (pc_side.clone(), shared.clone());
            let mut rng = ChaCha8Rng::seed_from_u64(seed ^ 0x0053_706f_6f66);
            link.threads.push(relay(
                "FRI link to the PC",
                robot_side.clone(),
                stop.clone(),
                move |datagram, from| {
                    let _ = pc_side.send_to(datagram, pc_addr);
                    let spoof = {
                        let mut s = lock(&shared);
                        s.robot = Some(from);
                        s.counts.measurements += 1;
                        rng.gen_bool(s.faults.spoof_probability)
                    };
                    if let (true, Ok(mut forged)) = (spoof, MeasurementDatagram::decode(datagram)) {
                        for q in &mut forged.data.msr_jnt_pos {
                            *q += 0.2;
                        }
                        forged.send_seq_count = forged.send_seq_count.wrapping_add(1);
                        if spoofer.send_to(&forged.encode(), pc_addr).is_ok() {
                            lock(&shared).counts.spoofed += 1;
                        }
                    }
                },
            ));
        }
        // PC -> robot: answers, some withheld; on time straight to the robot, late
        // ones through the delivery thread.
        {
            let (robot_side, shared) = (robot_side.clone(), shared.clone());
            let mut rng = ChaCha8Rng::seed_from_u64(seed ^ 0x5769_7468);
            link.threads.push(relay(
                "FRI link to the robot",
                pc_side.clone(),
                stop.clone(),
                move |datagram, from| {
                    if from != pc_addr {
                        return;
                    }
                    let (delay, robot) = {
                        let mut s = lock(&shared);
                        if rng.gen_bool(s.faults.withhold_probability) {
                            s.counts.withheld += 1;
                            return;
                        }
                        (Duration::from_secs_f64(s.faults.answer_delay_s), s.robot)
                    };
                    if !delay.is_zero() {
                        lock(&shared).counts.delayed += 1;
                        // The delivery thread is gone only when the link stops.
                        let _ = to_robot.send((Instant::now() + delay, datagram.to_vec()));
                    } else if let Some(robot) = robot {
                        if robot_side.send_to(datagram, robot).is_ok() {
                            lock(&shared).counts.answers += 1;
                        }
                    }
                },
            ));
        }
        // Delivery of late answers to the robot when each is due (in order).
        {
            let (shared, stop) = (shared.clone(), stop.clone());
            link.threads.push(std::thread::spawn(move || {
                crate::hw::realtime::request_device_cycle_priority("FRI link, late answers");
                while !stop.load(Ordering::Relaxed) {
                    let Ok((at, bytes)) = due.recv_timeout(Duration::from_millis(20)) else {
                        continue;
                    };
                    std::thread::sleep(at.saturating_duration_since(Instant::now()));
                    let robot = lock(&shared).robot;
                    if let Some(robot) = robot {
                        if robot_side.send_to(&bytes, robot).is_ok() {
                            lock(&shared).counts.answers += 1;
                        }
                    }
                }
            }));
        }
        Ok(link)
    }

    /// Where the robot sends its measurements (the simulator's `--pc-addr`).
    pub fn robot_facing_addr(&self) -> SocketAddr {
        self.robot_facing
    }

    /// Where the PC's answers go, and the only sender its driver accepts (the
    /// executor's `--fri-robot`).
    pub fn pc_facing_addr(&self) -> SocketAddr {
        self.pc_facing
    }

    /// Sets the faults from now on.
    pub fn set_faults(&self, faults: LinkFaults) -> Result<(), BadLinkFaults> {
        faults.validate()?;
        lock(&self.shared).faults = faults;
        Ok(())
    }

    /// What the link has done so far.
    pub fn counts(&self) -> LinkCounts {
        lock(&self.shared).counts
    }
}

impl Drop for FaultyLink {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        for thread in self.threads.drain(..) {
            let _ = thread.join();
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::hw::fri::datagram::MeasurementDatagram;

    /// A robot socket and a PC socket either side of a link.
    fn ends() -> (UdpSocket, UdpSocket, FaultyLink) {
        let pc = bind_local().unwrap();
        let robot = bind_local().unwrap();
        let link = FaultyLink::start(pc.local_addr().unwrap(), 7).unwrap();
        (robot, pc, link)
    }

    fn exchange(robot: &UdpSocket, pc: &UdpSocket, link: &FaultyLink) -> (SocketAddr, bool) {
        let m = MeasurementDatagram::default().encode();
        robot.send_to(&m, link.robot_facing_addr()).unwrap();
        let mut buf = [0u8; 2048];
        let (_, from) = pc.recv_from(&mut buf).unwrap();
        pc.send_to(b"answer", from).unwrap();
        robot
            .set_read_timeout(Some(Duration::from_millis(100)))
            .unwrap();
        let answered = robot
            .recv_from(&mut buf)
            .is_ok_and(|(n, _)| &buf[..n] == b"answer");
        (from, answered)
    }

    #[test]
    fn the_link_relays_withholds_and_spoofs_from_another_address() {
        let (robot, pc, link) = ends();
        let (from, answered) = exchange(&robot, &pc, &link);
        assert_eq!(
            from,
            link.pc_facing_addr(),
            "the PC sees the relay as the robot"
        );
        assert!(answered);
        link.set_faults(LinkFaults {
            withhold_probability: 1.0,
            ..LinkFaults::default()
        })
        .unwrap();
        assert!(!exchange(&robot, &pc, &link).1, "withheld");
        link.set_faults(LinkFaults {
            spoof_probability: 1.0,
            ..LinkFaults::default()
        })
        .unwrap();
        assert!(exchange(&robot, &pc, &link).1);
        let mut buf = [0u8; 2048];
        let (n, spoofer) = pc.recv_from(&mut buf).unwrap();
        assert_ne!(spoofer, link.pc_facing_addr(), "forged from a third host");
        let forged = MeasurementDatagram::decode(&buf[..n]).unwrap();
        assert!((forged.data.msr_jnt_pos[0] - 0.2).abs() < 1e-6);
        let counts = link.counts();
        assert_eq!(
            (counts.measurements, counts.withheld, counts.spoofed),
            (3, 1, 1)
        );
        assert!(link
            .set_faults(LinkFaults {
                withhold_probability: f64::NAN,
                ..LinkFaults::default()
            })
            .is_err());
    }
}
