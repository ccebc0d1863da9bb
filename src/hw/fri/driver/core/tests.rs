//! Tests of [`DriverCore`] without sockets: measurements and times in, commands
//! and events out.

use super::*;
use crate::hw::fri::datagram::{ControlMode, InterfaceState, RobotData, RobotState};
use crate::hw::fri::RobotPeer;
use crate::trajectory::JointLimits;

const MS: Duration = Duration::from_millis(1);

fn measurement(
    seq: u16,
    state: FriState,
    quality: Quality,
    q: [f32; JOINTS],
) -> MeasurementDatagram {
    MeasurementDatagram {
        send_seq_count: seq,
        interface: InterfaceState {
            state,
            quality,
            desired_msr_sample_time_s: 0.001,
            desired_cmd_sample_time_s: 0.001,
            ..Default::default()
        },
        robot: RobotState {
            power: 0x7f,
            control: ControlMode::Position,
            ..Default::default()
        },
        data: RobotData {
            msr_jnt_pos: q,
            cmd_jnt_pos: q,
            ..Default::default()
        },
        ..Default::default()
    }
}

fn core() -> DriverCore {
    DriverCore::new(DriverConfig {
        timeout_s: 0.05,
        ..Default::default()
    })
    .unwrap()
}

fn limits() -> JointLimits<JOINTS> {
    JointLimits::new([1.0; JOINTS], [2.0; JOINTS]).unwrap()
}

#[test]
fn only_the_robot_is_answered() {
    let robot: SocketAddr = "192.168.0.10:49938".parse().unwrap();
    let stranger: SocketAddr = "192.168.0.11:49938".parse().unwrap();
    let other_port: SocketAddr = "192.168.0.10:50000".parse().unwrap();
    let mapped: SocketAddr = "[::ffff:192.168.0.10]:49938".parse().unwrap();
    let host: RobotPeer = "192.168.0.10".parse().unwrap();
    let exact: RobotPeer = "192.168.0.10:49938".parse().unwrap();
    assert_eq!(host, RobotPeer::Host(robot.ip()));
    assert_eq!(exact, RobotPeer::Exact(robot));
    assert!(host.admits(robot) && host.admits(other_port) && host.admits(mapped));
    assert!(!host.admits(stranger));
    assert!(exact.admits(robot) && exact.admits(mapped));
    assert!(!exact.admits(other_port) && !exact.admits(stranger));
    let err = "krc.local".parse::<RobotPeer>().unwrap_err();
    assert!(
        err.to_string().contains("fri.robot_addr = krc.local"),
        "{err}"
    );

    let mut d = DriverCore::new(DriverConfig {
        robot: exact,
        ..DriverConfig::default()
    })
    .unwrap();
    let q = [0.1; JOINTS];
    let bytes = |seq| measurement(seq, FriState::Monitor, Quality::Ok, q).encode();
    // A well-formed, newer measurement from anyone else: dropped, unanswered,
    // and not taken as the robot's (its sequence number does not count either).
    for (k, from) in [stranger, other_port, stranger].into_iter().enumerate() {
        assert!(d.on_datagram(&bytes(10 + k as u16), from, MS).is_none());
    }
    // Garbage from a stranger is foreign, not a bad datagram of the robot.
    assert!(d.on_datagram(&[0u8; 3], stranger, MS).is_none());
    let status = d.status();
    assert_eq!(status.last_seq, None);
    assert_eq!(status.counters.foreign_datagrams, 4);
    assert_eq!(status.counters.bad_datagrams, 0);
    assert_eq!(status.counters.measurements, 0);
    assert_eq!(status.counters.answers, 0);
    // Reported at the 1st, 2nd and 4th drop.
    let reported: Vec<u64> = d
        .take_events()
        .iter()
        .filter_map(|e| match e {
            FriEvent::ForeignDatagram { dropped, robot, .. } => {
                assert_eq!(*robot, exact);
                Some(*dropped)
            }
            _ => None,
        })
        .collect();
    assert_eq!(reported, [1, 2, 4]);
    // The robot is answered, and an older number from a stranger still is not.
    let c = d.on_datagram(&bytes(5), robot, MS).unwrap();
    assert_eq!(c.refl_seq_count, 5);
    assert!(d.on_datagram(&bytes(6), stranger, 2 * MS).is_none());
    assert!(d.on_datagram(&bytes(6), mapped, 2 * MS).is_some());
    assert_eq!(d.status().last_seq, Some(6));
}

#[test]
fn replayed_and_out_of_order_measurements_are_dropped_across_the_wrap() {
    let mut d = core();
    let q = [0.0f32; JOINTS];
    let m = |seq, q| measurement(seq, FriState::Command, Quality::Perfect, q);
    assert!(d.on_measurement(&m(65534, q), MS).is_some());
    assert!(d.on_measurement(&m(65535, q), 2 * MS).is_some());
    assert!(
        d.on_measurement(&m(0, q), 3 * MS).is_some(),
        "65535 -> 0 is newer"
    );
    let answers = d.status().counters.answers;
    // A replay of the last, of one before the wrap, and one far behind.
    for stale in [0, 65535, 65534, 40000] {
        assert!(d.on_measurement(&m(stale, [1.0; JOINTS]), 4 * MS).is_none());
    }
    let status = d.status();
    assert_eq!(status.counters.stale_measurements, 4);
    assert_eq!(status.counters.answers, answers);
    assert_eq!(status.last_seq, Some(0));
    assert_eq!(
        status.measured_rad, [0.0; JOINTS],
        "a stale measurement is not news"
    );
    assert!(d.take_events().contains(&FriEvent::StaleMeasurement {
        seq: 40000,
        latest_seq: 0
    }));
    // Up to half the range ahead is newer (the rest lost).
    assert!(d.on_measurement(&m(1, q), 5 * MS).is_some());
    assert!(d.on_measurement(&m(1 + 32767, q), 6 * MS).is_some());
    assert_eq!(d.status().counters.missed_measurements, 32766);
}

#[test]
fn answers_reflect_the_measurement_and_count_across_the_wrap() {
    let mut d = core();
    d.send_seq = 65534;
    let q = [0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7];
    let c = d
        .on_measurement(&measurement(65535, FriState::Monitor, Quality::Ok, q), MS)
        .unwrap();
    assert_eq!((c.send_seq_count, c.refl_seq_count), (65535, 65535));
    let bytes = c.encode();
    assert_eq!(&bytes[0..4], &[0xff, 0xff, 0xff, 0xff]);
    let c = d
        .on_measurement(&measurement(0, FriState::Monitor, Quality::Ok, q), 2 * MS)
        .unwrap();
    assert_eq!((c.send_seq_count, c.refl_seq_count), (0, 0));
    assert_eq!(c.cmd_flags, CmdFlags::JNT_POS);
    assert!(d
        .take_events()
        .iter()
        .all(|e| !matches!(e, FriEvent::MeasurementsMissed { .. })));
}

#[test]
fn outside_command_mode_the_robots_own_command_is_mirrored() {
    let mut d = core();
    let mut m = measurement(7, FriState::Monitor, Quality::Perfect, [0.5; JOINTS]);
    m.data.cmd_jnt_pos = [0.25, -0.5, 1.0, 0.0, 0.125, 2.0, -1.0];
    m.data.cmd_jnt_pos_fri_offset = [0.5, 0.25, -0.5, 0.0, 0.0, 0.0, 1.0];
    let c = d.on_measurement(&m, MS).unwrap();
    assert_eq!(c.jnt_pos, [0.75, -0.25, 0.5, 0.0, 0.125, 2.0, 0.0]);
    assert!(!d.status().commanding);
    // Powered off in CMD: still mirror.
    let mut off = m;
    off.send_seq_count = 8;
    off.interface.state = FriState::Command;
    off.robot.power = 0;
    let c = d.on_measurement(&off, 2 * MS).unwrap();
    assert_eq!(c.jnt_pos, [0.75, -0.25, 0.5, 0.0, 0.125, 2.0, 0.0]);
    assert!(!d.status().commanding);
}

#[test]
fn commands_only_at_the_minimum_quality_or_better() {
    // Default minimum BAD: refused at UNACCEPTABLE, allowed at BAD.
    let mut d = core();
    let q0 = [0.0f32; JOINTS];
    d.on_measurement(
        &measurement(1, FriState::Command, Quality::Unacceptable, q0),
        MS,
    );
    let traj = Trajectory::point_to_point([0.0; JOINTS], [0.1; JOINTS], &limits()).unwrap();
    assert_eq!(
        d.start_trajectory(traj.clone()),
        Err(FriError::QualityTooLow {
            quality: Quality::Unacceptable,
            min: Quality::Bad
        })
    );
    d.on_measurement(&measurement(2, FriState::Command, Quality::Bad, q0), 2 * MS);
    let id = d.start_trajectory(traj.clone()).unwrap();
    assert_eq!(d.start_trajectory(traj.clone()), Err(FriError::Busy { id }));
    // Quality falls to UNACCEPTABLE mid-motion: abort and mirror.
    let c = d
        .on_measurement(
            &measurement(3, FriState::Command, Quality::Unacceptable, [0.05; JOINTS]),
            3 * MS,
        )
        .unwrap();
    assert_eq!(c.jnt_pos, [0.05; JOINTS]);
    assert_eq!(
        d.outcome(id),
        Some(Err(FriError::QualityTooLow {
            quality: Quality::Unacceptable,
            min: Quality::Bad
        }))
    );
    // A stricter minimum (OK) refuses BAD.
    let mut strict = DriverCore::new(DriverConfig {
        min_command_quality: Quality::Ok,
        ..Default::default()
    })
    .unwrap();
    strict.on_measurement(&measurement(1, FriState::Command, Quality::Bad, q0), MS);
    assert_eq!(
        strict.start_trajectory(traj),
        Err(FriError::QualityTooLow {
            quality: Quality::Bad,
            min: Quality::Ok
        })
    );
    assert!(!strict.status().commanding);
    // Nothing below BAD may be configured.
    let low = DriverCore::new(DriverConfig {
        min_command_quality: Quality::Unacceptable,
        ..Default::default()
    });
    assert!(matches!(
        low,
        Err(FriError::BadConfig {
            field: "min_command_quality",
            ..
        })
    ));
}

#[test]
fn streams_the_trajectory_on_the_robots_clock() {
    let mut d = core();
    let q0 = [0.1f32, -0.2, 0.3, 0.0, 0.0, 0.0, 0.0];
    let start = q0.map(f64::from);
    let mut end = start;
    end[0] += 0.4;
    let traj = Trajectory::point_to_point(start, end, &limits()).unwrap();
    // MON: mirror; CMD at quality PERFECT: hold the mirrored position.
    d.on_measurement(
        &measurement(10, FriState::Monitor, Quality::Perfect, q0),
        MS,
    );
    let c = d
        .on_measurement(
            &measurement(11, FriState::Command, Quality::Perfect, q0),
            2 * MS,
        )
        .unwrap();
    assert_eq!(c.jnt_pos, q0);
    let id = d.start_trajectory(traj.clone()).unwrap();
    let c = d
        .on_measurement(
            &measurement(12, FriState::Command, Quality::Perfect, q0),
            3 * MS,
        )
        .unwrap();
    assert_eq!(c.jnt_pos, traj.sample(0.001).position.map(|v| v as f32));
    // Two measurements lost: time advances by three periods and the gap is reported.
    let c = d
        .on_measurement(
            &measurement(15, FriState::Command, Quality::Perfect, q0),
            6 * MS,
        )
        .unwrap();
    assert_eq!(c.jnt_pos, traj.sample(0.004).position.map(|v| v as f32));
    assert!(d.take_events().contains(&FriEvent::MeasurementsMissed {
        after_seq: 12,
        received_seq: 15,
        missed: 2
    }));
    assert_eq!(d.status().counters.missed_measurements, 2);
    // Run to the end: the last command is the end point exactly, then hold.
    let mut seq = 15u16;
    let mut last = c;
    while d.outcome(id).is_none() {
        seq += 1;
        last = d
            .on_measurement(
                &measurement(seq, FriState::Command, Quality::Perfect, q0),
                MS * u32::from(seq),
            )
            .unwrap();
        assert!(seq < 5000, "trajectory never ended");
    }
    assert_eq!(d.outcome(id), Some(Ok(())));
    assert_eq!(last.jnt_pos, end.map(|v| v as f32));
    let expected_cycles = (traj.duration_s() / 0.001).ceil() as u16;
    assert_eq!(seq - 11, expected_cycles);
    // A stale (repeated) measurement is not answered.
    assert!(d
        .on_measurement(
            &measurement(seq, FriState::Command, Quality::Perfect, q0),
            MS
        )
        .is_none());
}

#[test]
fn trajectory_must_start_at_the_commanded_position() {
    let mut d = core();
    d.on_measurement(
        &measurement(1, FriState::Command, Quality::Perfect, [0.0; JOINTS]),
        MS,
    );
    let mut start = [0.0; JOINTS];
    start[4] = 0.01;
    let traj = Trajectory::point_to_point(start, [0.2; JOINTS], &limits()).unwrap();
    assert_eq!(
        d.start_trajectory(traj),
        Err(FriError::StartMismatch {
            joint: 4,
            start_rad: 0.01,
            current_rad: 0.0,
            tolerance_rad: 1e-4
        })
    );
    let mut fresh = core();
    assert!(matches!(
        fresh.start_trajectory(Trajectory::through(&[[0.0; JOINTS]], &limits()).unwrap()),
        Err(FriError::NotCommanding {
            state: FriState::Off,
            ..
        })
    ));
}

#[test]
fn dropping_to_monitor_mid_motion_is_reported_and_aborts() {
    let mut d = core();
    let q0 = [0.0f32; JOINTS];
    d.on_measurement(&measurement(1, FriState::Command, Quality::Perfect, q0), MS);
    let traj = Trajectory::point_to_point([0.0; JOINTS], [0.3; JOINTS], &limits()).unwrap();
    let id = d.start_trajectory(traj).unwrap();
    d.on_measurement(
        &measurement(2, FriState::Command, Quality::Perfect, q0),
        2 * MS,
    );
    d.take_events();
    let m = measurement(3, FriState::Monitor, Quality::Unacceptable, [0.01; JOINTS]);
    let c = d.on_measurement(&m, 3 * MS).unwrap();
    assert_eq!(c.jnt_pos, [0.01; JOINTS]);
    let events = d.take_events();
    assert!(events.contains(&FriEvent::DroppedToMonitor {
        state: FriState::Monitor,
        quality: Quality::Unacceptable,
        during_motion: true,
        seq: 3
    }));
    let aborted = FriError::LeftCommandMode {
        state: FriState::Monitor,
        quality: Quality::Unacceptable,
    };
    assert!(events.contains(&FriEvent::MotionAborted {
        id,
        error: aborted.clone()
    }));
    assert_eq!(d.outcome(id), Some(Err(aborted)));
}

#[test]
fn a_late_measurement_is_a_safe_stop_then_the_link_recovers() {
    let mut d = core();
    let q0 = [0.0f32; JOINTS];
    assert!(
        !d.check_late(Duration::from_secs(100)),
        "no robot yet: nothing is late"
    );
    d.on_measurement(&measurement(1, FriState::Command, Quality::Perfect, q0), MS);
    let traj = Trajectory::point_to_point([0.0; JOINTS], [0.3; JOINTS], &limits()).unwrap();
    let id = d.start_trajectory(traj).unwrap();
    let c = d
        .on_measurement(
            &measurement(2, FriState::Command, Quality::Perfect, q0),
            2 * MS,
        )
        .unwrap();
    let held = c.jnt_pos;
    assert_ne!(held, q0);
    assert!(!d.check_late(2 * MS + Duration::from_micros(49_999)));
    assert!(d.check_late(52 * MS));
    assert!(!d.check_late(80 * MS), "reported once per outage");
    assert_eq!(
        d.outcome(id),
        Some(Err(FriError::MeasurementLate {
            waited_s: 0.05,
            timeout_s: 0.05
        }))
    );
    assert!(d.status().late);
    assert!(!d.status().commanding);
    let events = d.take_events();
    assert!(events.contains(&FriEvent::MeasurementLate {
        waited_s: 0.05,
        timeout_s: 0.05
    }));
    // The link returns with the robot still in CMD: the stop (here from a
    // standstill one cycle in) holds where the last command was.
    let c = d
        .on_measurement(
            &measurement(90, FriState::Command, Quality::Ok, q0),
            90 * MS,
        )
        .unwrap();
    assert!((c.jnt_pos[0] - held[0]).abs() < 1e-5);
    let c = d
        .on_measurement(
            &measurement(91, FriState::Command, Quality::Ok, q0),
            91 * MS,
        )
        .unwrap();
    assert!((c.jnt_pos[0] - held[0]).abs() < 1e-5);
    assert!(d
        .take_events()
        .contains(&FriEvent::LinkRestored { after_s: 0.088 }));
}

/// A measurement late in the middle of a fast motion, then the next one in the
/// robot's count (the whole PC stalled, the robot still commanding): the answers
/// go on from the last command, decelerating within the trajectory's limits, and
/// come to rest. Holding the last command at once was a step of 0.6 rad/s in one
/// cycle, 600 rad/s^2 (the fault campaign's audit caught one under load).
#[test]
fn a_late_measurement_mid_motion_decelerates_within_the_limits() {
    let mut d = core();
    let q0 = [0.0f32; JOINTS];
    let mut seq = 1u16;
    let mut now = MS;
    d.on_measurement(
        &measurement(seq, FriState::Command, Quality::Perfect, q0),
        now,
    );
    let traj = Trajectory::point_to_point([0.0; JOINTS], [1.0; JOINTS], &limits()).unwrap();
    let id = d.start_trajectory(traj).unwrap();
    let mut p = Vec::new();
    let step = |d: &mut DriverCore, now: Duration, seq: &mut u16| {
        *seq += 1;
        d.on_measurement(
            &measurement(*seq, FriState::Command, Quality::Perfect, q0),
            now,
        )
        .unwrap()
        .jnt_pos[0] as f64
    };
    for _ in 0..300 {
        now += MS;
        p.push(step(&mut d, now, &mut seq));
    }
    now += 60 * MS;
    assert!(d.check_late(now));
    assert!(matches!(
        d.outcome(id),
        Some(Err(FriError::MeasurementLate { .. }))
    ));
    now += MS;
    p.push(step(&mut d, now, &mut seq));
    // The link is back; nothing starts from rest while the arm still decelerates.
    let at = [p[300]; JOINTS];
    let next = Trajectory::point_to_point(at, [0.0; JOINTS], &limits()).unwrap();
    assert_eq!(d.start_trajectory(next), Err(FriError::Busy { id }));
    while d.is_moving() {
        now += MS;
        p.push(step(&mut d, now, &mut seq));
    }
    for _ in 0..5 {
        now += MS;
        p.push(step(&mut d, now, &mut seq));
    }
    for w in p.windows(3) {
        let a = (w[2] - 2.0 * w[1] + w[0]) / 1e-6;
        assert!(a.abs() <= 2.0 + 0.3, "acceleration {a} rad/s^2");
    }
    let n = p.len();
    assert_eq!(p[n - 1], p[n - 2], "at rest");
    assert!(
        p[n - 1] > p[299] + 0.05,
        "braked from 0.6 rad/s over 0.09 rad"
    );
}

/// FRI closed and reopened on the KRC: after the silence the robot counts from
/// 1 again. Two consecutive numbers start the new count; one old datagram alone,
/// or old numbers while the link is live, stay stale.
#[test]
fn the_robot_s_counter_starting_over_after_a_silence_is_followed() {
    let mut d = core();
    let q0 = [0.0f32; JOINTS];
    let m = |seq| measurement(seq, FriState::Monitor, Quality::Ok, q0);
    for seq in 30_000..30_005 {
        assert!(d
            .on_measurement(&m(seq), u32::from(seq - 29_999) * MS)
            .is_some());
    }
    // While live, old numbers are stale, however consecutive.
    assert!(d.on_measurement(&m(10), 6 * MS).is_none());
    assert!(d.on_measurement(&m(11), 7 * MS).is_none());
    // Silence, then the new count.
    assert!(d.check_late(2000 * MS));
    assert!(d.on_measurement(&m(1), 2100 * MS).is_none());
    let c = d.on_measurement(&m(2), 2101 * MS).expect("answered");
    assert_eq!(c.refl_seq_count, 2);
    assert!(d.on_measurement(&m(3), 2102 * MS).is_some());
    assert!(d.take_events().contains(&FriEvent::SequenceRestarted {
        seq: 2,
        latest_seq: 30_004
    }));
    assert_eq!(d.status().last_seq, Some(3));
}

#[test]
fn stop_decelerates_then_holds() {
    let mut d = core();
    let q0 = [0.0f32; JOINTS];
    d.on_measurement(&measurement(1, FriState::Command, Quality::Perfect, q0), MS);
    let l = limits();
    let traj = Trajectory::point_to_point([0.0; JOINTS], [1.0; JOINTS], &l).unwrap();
    let id = d.start_trajectory(traj.clone()).unwrap();
    let mut seq = 1u16;
    let mut step = |d: &mut DriverCore| {
        seq += 1;
        d.on_measurement(
            &measurement(seq, FriState::Command, Quality::Perfect, q0),
            MS,
        )
        .unwrap()
        .jnt_pos[0] as f64
    };
    let mut p = Vec::new();
    for _ in 0..300 {
        p.push(step(&mut d));
    }
    d.stop();
    assert_eq!(d.outcome(id), Some(Err(FriError::Stopped { id })));
    while d.is_moving() {
        p.push(step(&mut d));
    }
    for _ in 0..5 {
        p.push(step(&mut d));
    }
    // Velocity at 0.3 s is 0.6 rad/s; braking at 2 rad/s^2 takes 0.3 s and 0.09 rad.
    let v = traj.sample(0.3).velocity[0];
    let expected_rest = traj.sample(0.3).position[0] + v * v / (2.0 * 2.0);
    assert!((p.last().unwrap() - expected_rest).abs() < 1e-6);
    for w in p.windows(3) {
        let a = (w[2] - 2.0 * w[1] + w[0]) / 1e-6;
        assert!(a.abs() <= 2.0 + 0.3, "acceleration {a}");
    }
    assert!(!d.is_moving());
}
