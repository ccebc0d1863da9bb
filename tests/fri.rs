//! The FRI driver against the robot simulator over loopback UDP (ephemeral ports):
//! reaching command mode, tracking a trajectory, withheld answers, late measurements.
//!
//! Real threads and sockets run here, so the simulator is configured to tolerate
//! scheduling hiccups of a loaded machine (a 2 ms cycle and lenient quality levels);
//! every wait has a timeout and no test asserts how long anything took.

use graspcell::clock::{Clock, SystemClock};
use graspcell::hw::fri::{
    DriverConfig, FriDriver, FriError, FriEvent, FriState, MeasurementDatagram, Quality, RobotPeer,
};
use graspcell::sim::fri::{
    spawn_udp, DropReason, FriSimulator, QualityThresholds, SimConfig, SimHandle,
    LBR4_VELOCITY_LIMIT_RAD_S,
};
use graspcell::trajectory::{JointLimits, Trajectory};
use std::sync::Arc;
use std::time::{Duration, Instant};

const LOCALHOST_ANY_PORT: &str = "127.0.0.1:0";

fn lenient_sim(initial: [f64; 7]) -> SimConfig {
    SimConfig {
        cycle_s: 0.002,
        initial_joints_rad: initial,
        tracking_time_constant_s: 0.004,
        quality: QualityThresholds {
            perfect_max_miss_rate: 0.05,
            ok_max_miss_rate: 0.2,
            bad_max_miss_rate: 0.5,
            bad_consecutive_misses: 15,
            unacceptable_consecutive_misses: 30,
        },
        ..SimConfig::default()
    }
}

/// A driver on an ephemeral loopback port and a simulator sending to it.
fn rig(sim: SimConfig, timeout_s: f64) -> (FriDriver, SimHandle) {
    let clock: Arc<dyn Clock> = Arc::new(SystemClock::new());
    let driver = FriDriver::start(
        DriverConfig {
            bind_addr: LOCALHOST_ANY_PORT.parse().unwrap(),
            timeout_s,
            ..DriverConfig::default()
        },
        Arc::clone(&clock),
    )
    .unwrap();
    let handle = spawn_udp(
        sim,
        LOCALHOST_ANY_PORT.parse().unwrap(),
        driver.local_addr(),
        clock,
    )
    .unwrap();
    (driver, handle)
}

fn limits() -> JointLimits<7> {
    JointLimits::new(LBR4_VELOCITY_LIMIT_RAD_S.map(|v| 0.5 * v), [2.0; 7]).unwrap()
}

/// Polls `f` every 2 ms until it gives a value or `timeout_s` passes.
fn eventually<T>(timeout_s: f64, mut f: impl FnMut() -> Option<T>) -> Option<T> {
    let deadline = Instant::now() + Duration::from_secs_f64(timeout_s);
    loop {
        if let Some(v) = f() {
            return Some(v);
        }
        if Instant::now() >= deadline {
            return None;
        }
        std::thread::sleep(Duration::from_millis(2));
    }
}

#[test]
fn driver_reaches_command_mode_and_tracks_a_trajectory() {
    let q0 = [0.1, -0.3, 0.2, 0.5, -0.4, 0.3, 0.0];
    let (driver, sim) = rig(lenient_sim(q0), 0.5);
    let status = driver.wait_until_commanding(20.0).unwrap();
    assert_eq!(status.state, FriState::Command);
    assert!(status.quality >= Quality::Ok);
    // The held position is the robot's own command (the initial joints, as f32).
    let start = status.commanded_rad;
    for j in 0..7 {
        assert!(
            (start[j] - q0[j]).abs() < 1e-6,
            "joint {j}: {} vs {}",
            start[j],
            q0[j]
        );
    }
    let goal = [0.4, 0.1, -0.2, 0.8, 0.1, -0.2, 0.6];
    let via = [0.2, 0.0, 0.0, 0.6, 0.0, 0.0, 0.3];
    let traj = Trajectory::through(&[start, via, goal], &limits()).unwrap();
    let id = driver.start_trajectory(traj.clone()).unwrap();
    // While it moves, the arm follows the command closely (4 ms lag at <= 1.8 rad/s).
    let mut worst_rad: f64 = 0.0;
    let mut samples = 0;
    let outcome = eventually(traj.duration_s() + 20.0, || {
        let s = driver.status();
        for j in 0..7 {
            worst_rad = worst_rad.max((s.measured_rad[j] - s.commanded_rad[j]).abs());
        }
        samples += 1;
        driver.motion_outcome(id)
    })
    .expect("the motion ends");
    assert_eq!(outcome, Ok(()));
    assert!(samples > 10, "only {samples} status samples");
    assert!(worst_rad < 0.03, "tracking error {worst_rad} rad");
    // The arm settles at the goal; the robot stayed in command mode throughout.
    let settled = eventually(5.0, || {
        let q = sim.with(|s| s.joints_rad());
        (0..7).all(|j| (q[j] - goal[j]).abs() < 1e-5).then_some(q)
    });
    assert!(
        settled.is_some(),
        "arm at {:?}, goal {goal:?}",
        sim.with(|s| s.joints_rad())
    );
    let summary = sim.stop().unwrap();
    assert_eq!(summary.state, FriState::Command);
    assert_eq!(summary.drop_reason, None);
    assert!(summary.counters.answers_in_time > 100);
    driver.shutdown(1.0).unwrap();
}

#[test]
fn shutdown_releases_the_robot_to_monitor_mode_on_request() {
    let (driver, sim) = rig(lenient_sim([0.2; 7]), 0.5);
    driver.wait_until_commanding(20.0).unwrap();
    driver.shutdown(5.0).unwrap();
    let summary = sim.stop().unwrap();
    assert_eq!(summary.state, FriState::Monitor);
    assert_eq!(summary.drop_reason, Some(DropReason::Released));
    assert_eq!(summary.counters.drops_to_monitor, 1);
}

#[test]
fn withheld_answers_drop_the_robot_to_monitor_and_the_driver_reports_it() {
    let (driver, sim) = rig(lenient_sim([0.0; 7]), 0.5);
    let status = driver.wait_until_commanding(20.0).unwrap();
    let mut goal = status.commanded_rad;
    goal[0] += 1.5;
    goal[3] -= 1.0;
    let traj = Trajectory::point_to_point(status.commanded_rad, goal, &limits()).unwrap();
    let id = driver.start_trajectory(traj).unwrap();
    std::thread::sleep(Duration::from_millis(100));
    driver.take_events();
    driver.set_withhold_answers(true);
    let event = driver
        .wait_event(10.0, |e| matches!(e, FriEvent::DroppedToMonitor { .. }))
        .unwrap()
        .expect("the driver reports the drop to monitor");
    assert!(
        matches!(
            event,
            FriEvent::DroppedToMonitor {
                state: FriState::Monitor,
                quality: Quality::Unacceptable,
                during_motion: true,
                ..
            }
        ),
        "{event:?}"
    );
    // The driver commands down to quality BAD (15 misses in a row here), so the
    // motion runs until the robot drops at UNACCEPTABLE (30 in a row).
    assert_eq!(
        driver.wait_motion(id, 5.0),
        Err(FriError::LeftCommandMode {
            state: FriState::Monitor,
            quality: Quality::Unacceptable
        })
    );
    // The simulator says why, and the arm has stopped short of the goal.
    let reason = sim.with(|s| s.drop_reason());
    assert!(
        matches!(reason, Some(DropReason::LinkQuality { .. })),
        "{reason:?}"
    );
    let stopped = sim.with(|s| s.joints_rad());
    assert!(
        (stopped[0] - goal[0]).abs() > 0.1,
        "arm reached the goal anyway"
    );
    std::thread::sleep(Duration::from_millis(50));
    assert_eq!(
        sim.with(|s| s.joints_rad()),
        stopped,
        "arm moved after the drop"
    );
    assert!(!driver.status().commanding);
    let summary = sim.stop().unwrap();
    assert_eq!(summary.state, FriState::Monitor);
    assert!(summary.counters.misses >= 30);
}

#[test]
fn a_late_measurement_is_a_safe_stop() {
    let (driver, sim) = rig(lenient_sim([0.0; 7]), 0.05);
    let status = driver.wait_until_commanding(20.0).unwrap();
    let mut goal = status.commanded_rad;
    goal[1] += 1.0;
    let traj = Trajectory::point_to_point(status.commanded_rad, goal, &limits()).unwrap();
    let id = driver.start_trajectory(traj).unwrap();
    std::thread::sleep(Duration::from_millis(100));
    // The robot goes silent.
    sim.stop().unwrap();
    let result = driver.wait_motion(id, 10.0);
    match result {
        Err(FriError::MeasurementLate {
            waited_s,
            timeout_s,
        }) => {
            assert_eq!(timeout_s, 0.05);
            assert!(waited_s >= 0.05, "{waited_s}");
        }
        other => panic!("expected a late-measurement stop, got {other:?}"),
    }
    let status = driver.status();
    assert!(status.late);
    assert!(!status.commanding);
    assert_eq!(status.motion_id, None);
    assert!(status.counters.late >= 1);
    assert!(driver
        .take_events()
        .iter()
        .any(|e| matches!(e, FriEvent::MeasurementLate { .. })));
    // Nothing can be started until measurements return.
    let hold = Trajectory::through(&[status.commanded_rad], &limits()).unwrap();
    assert!(matches!(
        driver.start_trajectory(hold),
        Err(FriError::NotCommanding { .. })
    ));
}

#[test]
fn garbage_on_the_driver_port_is_reported_not_trusted() {
    let clock: Arc<dyn Clock> = Arc::new(SystemClock::new());
    let driver = FriDriver::start(
        DriverConfig {
            bind_addr: LOCALHOST_ANY_PORT.parse().unwrap(),
            ..DriverConfig::default()
        },
        clock,
    )
    .unwrap();
    let socket = std::net::UdpSocket::bind(LOCALHOST_ANY_PORT).unwrap();
    let mut bytes = [0u8; 916];
    bytes[4..6].copy_from_slice(&916u16.to_le_bytes());
    bytes[6..8].copy_from_slice(&0x1005u16.to_le_bytes());
    socket.send_to(&bytes, driver.local_addr()).unwrap();
    let event = driver
        .wait_event(5.0, |e| matches!(e, FriEvent::BadDatagram { .. }))
        .unwrap()
        .expect("reported");
    assert!(event_text(&event).contains("0x1005"), "{event:?}");
    assert_eq!(driver.status().counters.measurements, 0);
    assert_eq!(driver.status().state, FriState::Off);
}

fn event_text(event: &FriEvent) -> String {
    match event {
        FriEvent::BadDatagram { error } => error.to_string(),
        other => format!("{other:?}"),
    }
}

#[test]
fn simulator_process_drives_the_driver_into_command_mode() {
    let clock: Arc<dyn Clock> = Arc::new(SystemClock::new());
    let driver = FriDriver::start(
        DriverConfig {
            bind_addr: LOCALHOST_ANY_PORT.parse().unwrap(),
            timeout_s: 0.2,
            ..DriverConfig::default()
        },
        clock,
    )
    .unwrap();
    let mut child = std::process::Command::new(env!("CARGO_BIN_EXE_cell-sim-arm"))
        .args(["--pc-addr", &driver.local_addr().to_string()])
        .args(["--cycle-ms", "2", "--seconds", "60"])
        .args(["--initial-joints", "0.25,-0.5,0.125,1,-1,0.5,-0.75"])
        .stdout(std::process::Stdio::null())
        .spawn()
        .unwrap();
    let reached = driver.wait_until_commanding(20.0);
    let late = reached.as_ref().ok().map(|_| {
        // The robot process goes away: the driver reports a late measurement.
        child.kill().unwrap();
        driver.wait_event(10.0, |e| matches!(e, FriEvent::MeasurementLate { .. }))
    });
    let _ = child.kill();
    let _ = child.wait();
    let status = reached.unwrap();
    assert_eq!(status.state, FriState::Command);
    assert_eq!(
        status.measured_rad,
        [0.25, -0.5, 0.125, 1.0, -1.0, 0.5, -0.75]
    );
    assert!(
        matches!(late, Some(Ok(Some(FriEvent::MeasurementLate { .. })))),
        "{late:?}"
    );
}

/// A loopback address with a port nobody uses now (bound, then released).
fn free_loopback_addr() -> std::net::SocketAddr {
    let socket = std::net::UdpSocket::bind(LOCALHOST_ANY_PORT).unwrap();
    socket.local_addr().unwrap()
}

/// A well-formed measurement of a robot in command mode at PERFECT quality whose
/// joints are at `q`: what a spoofer on the KRC network would send (a second
/// simulated robot's measurement, promoted to command mode).
fn forged_measurement(q: [f64; 7]) -> MeasurementDatagram {
    let mut robot = FriSimulator::new(SimConfig {
        initial_joints_rad: q,
        ..SimConfig::default()
    })
    .unwrap();
    let mut m = robot.poll(Duration::ZERO).expect("the first measurement");
    m.interface.state = FriState::Command;
    m.interface.quality = Quality::Perfect;
    m
}

/// Issue 21 item 3: while the arm moves, a second socket on the same host sends
/// valid command-mode measurements to the driver, numbered ahead of the robot's
/// (accepted, they would jump the trajectory's time, make the robot's own
/// measurements stale, and mirror the forged joints). The driver is pinned to the
/// simulator's address: the spoofer gets no answer, the drop counter rises, and the
/// commands the simulated robot received (its datagram-level record) are exactly
/// the planned trajectory on the robot's own sequence clock, as without a spoofer.
#[test]
fn a_second_sender_cannot_steer_the_commanded_stream() {
    let robot_addr = free_loopback_addr();
    let clock: Arc<dyn Clock> = Arc::new(SystemClock::new());
    let driver = FriDriver::start(
        DriverConfig {
            bind_addr: LOCALHOST_ANY_PORT.parse().unwrap(),
            robot: RobotPeer::Exact(robot_addr),
            timeout_s: 0.5,
            ..DriverConfig::default()
        },
        Arc::clone(&clock),
    )
    .unwrap();
    let q0 = [0.1, -0.3, 0.2, 0.5, -0.4, 0.3, 0.0];
    let sim = spawn_udp(lenient_sim(q0), robot_addr, driver.local_addr(), clock).unwrap();
    sim.with(|s| s.record_commands(true));
    let start = driver.wait_until_commanding(20.0).unwrap().commanded_rad;
    let goal = [0.4, 0.1, -0.2, 0.8, 0.1, -0.2, 0.6];
    let traj = Trajectory::through(&[start, goal], &limits()).unwrap();

    let spoofer = std::net::UdpSocket::bind(LOCALHOST_ANY_PORT).unwrap();
    spoofer
        .set_read_timeout(Some(Duration::from_millis(1)))
        .unwrap();
    let done = std::sync::atomic::AtomicBool::new(false);
    let (outcome, (sent, replies)) = std::thread::scope(|scope| {
        let spoofing = scope.spawn(|| {
            let (mut sent, mut replies) = (0u32, 0u32);
            let mut buf = [0u8; 2048];
            let mut forged = forged_measurement([1.0; 7]);
            while !done.load(std::sync::atomic::Ordering::Relaxed) {
                // Numbered ahead of the robot's latest measurement.
                let seq = driver.status().last_seq.unwrap_or(0);
                forged.send_seq_count = seq.wrapping_add(100 + sent as u16 % 50);
                spoofer
                    .send_to(&forged.encode(), driver.local_addr())
                    .unwrap();
                sent += 1;
                if spoofer.recv_from(&mut buf).is_ok() {
                    replies += 1;
                }
            }
            (sent, replies)
        });
        let id = driver.start_trajectory(traj.clone()).unwrap();
        let outcome = eventually(traj.duration_s() + 20.0, || driver.motion_outcome(id));
        done.store(true, std::sync::atomic::Ordering::Relaxed);
        (outcome, spoofing.join().unwrap())
    });
    assert_eq!(outcome, Some(Ok(())));
    let status = driver.status();
    let summary_commands = sim.with(|s| s.take_commands());
    let summary = sim.stop().unwrap();
    assert!(sent > 10, "the spoofer sent only {sent} datagrams");
    assert_eq!(replies, 0, "the driver answered the spoofer");
    assert!(
        status.counters.foreign_datagrams >= u64::from(sent) / 2
            && status.counters.foreign_datagrams > 0,
        "{sent} sent, {:?}",
        status.counters
    );
    assert_eq!(
        status.counters.stale_measurements, 0,
        "{:?}",
        status.counters
    );
    assert_eq!(summary.drop_reason, None);
    assert_eq!(summary.state, FriState::Command);

    // The robot's record: hold at the start, then the trajectory sample by sample.
    let dt = 0.002;
    let f32s = |q: [f64; 7]| q.map(|v| f64::from(v as f32));
    let commands: Vec<_> = summary_commands
        .iter()
        .filter(|c| c.state == FriState::Command)
        .collect();
    let first_move = commands
        .iter()
        .position(|c| c.jnt_pos_rad != f32s(start))
        .expect("the arm was commanded to move");
    assert!(first_move > 0);
    let close = |a: [f64; 7], b: [f64; 7]| (0..7).all(|j| (a[j] - b[j]).abs() < 1e-6);
    let s0 = commands[first_move].refl_seq_count;
    // The first moving command is the sample one period (or a few, after a lost
    // measurement) into the trajectory.
    let k0 = (1..=10)
        .find(|&k| {
            close(
                commands[first_move].jnt_pos_rad,
                f32s(traj.sample(k as f64 * dt).position),
            )
        })
        .expect("the first moving command is on the trajectory");
    for c in &commands[first_move..] {
        let k = k0 + usize::from(c.refl_seq_count.wrapping_sub(s0));
        let t = k as f64 * dt;
        let expected = if t >= traj.duration_s() {
            traj.end()
        } else {
            traj.sample(t).position
        };
        assert!(
            close(c.jnt_pos_rad, f32s(expected)),
            "seq {}: commanded {:?}, planned {expected:?}",
            c.refl_seq_count,
            c.jnt_pos_rad
        );
    }
    assert!(close(commands.last().unwrap().jnt_pos_rad, f32s(goal)));
    driver.shutdown(1.0).unwrap();
}
