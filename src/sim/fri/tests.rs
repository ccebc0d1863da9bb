use super::*;
use crate::hw::fri::datagram::{CmdFlags, CommandDatagram, FriState, MeasurementDatagram, Quality};
use crate::hw::fri::{JOINTS, RELEASE_BIT};
use std::time::Duration;

const MS: Duration = Duration::from_millis(1);

/// The PC's answer to `m`: mirror, or `q` when given (in CMD).
fn answer(m: &MeasurementDatagram, seq: u16, q: Option<[f64; JOINTS]>) -> Vec<u8> {
    CommandDatagram {
        send_seq_count: seq,
        refl_seq_count: m.send_seq_count,
        cmd_flags: CmdFlags::JNT_POS,
        jnt_pos: q.map_or_else(|| m.mirrored_jnt_pos(), |q| q.map(|v| v as f32)),
        ..Default::default()
    }
    .encode()
    .to_vec()
}

/// Runs `cycles` cycles of 1 ms answering each measurement after 100 µs with `q(k)`
/// (None = mirror, or no answer when `answer_if` says so). Returns the last
/// measurement.
fn run(
    sim: &mut FriSimulator,
    t: &mut Duration,
    cycles: usize,
    mut q: impl FnMut(usize, &MeasurementDatagram) -> Option<Option<[f64; JOINTS]>>,
) -> MeasurementDatagram {
    let mut last = None;
    for k in 0..cycles {
        let m = sim.poll(*t).expect("a measurement is due every cycle");
        if let Some(cmd) = q(k, &m) {
            let bytes = answer(&m, m.send_seq_count, cmd);
            sim.receive(&bytes, *t + Duration::from_micros(100));
        }
        assert!(sim.poll(*t + Duration::from_micros(500)).is_none());
        *t += MS;
        last = Some(m);
    }
    last.expect("at least one cycle")
}

fn started() -> (FriSimulator, Duration) {
    let mut sim = FriSimulator::new(SimConfig {
        initial_joints_rad: [0.1, -0.2, 0.3, 0.4, -0.5, 0.6, 0.0],
        ..Default::default()
    })
    .unwrap();
    let mut t = Duration::from_secs(3);
    run(&mut sim, &mut t, 150, |_, _| Some(None));
    assert_eq!(sim.state(), FriState::Command);
    sim.take_events();
    (sim, t)
}

#[test]
fn quality_thresholds_parse_from_text() {
    assert_eq!(
        QualityThresholds::from_text("0.01,0.05,0.2", "2,5").unwrap(),
        QualityThresholds::default()
    );
    for (rates, misses) in [
        ("0.1,0.2", "2,5"),
        ("0.01,0.05,0.2", "2.5,5"),
        ("a,b,c", "2,5"),
    ] {
        let err = QualityThresholds::from_text(rates, misses)
            .unwrap_err()
            .to_string();
        assert!(err.contains("quality"), "{err}");
    }
}

#[test]
fn limits_from_the_robot_are_the_urdf_limits_of_the_arm_joints() {
    let path =
        std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join(crate::config::DEFAULT_CONFIG_PATH);
    let cell = crate::config::CellConfig::load(&path).unwrap();
    let robot = crate::robot::Robot::load(&cell).unwrap();
    let config = SimConfig::from_robot(&robot);
    config.validate().unwrap();
    // Read the URDF again, independently of the robot module.
    let urdf = urdf_rs::read_file(&cell.robot.urdf).unwrap();
    for (j, name) in cell.robot.arm_joints.iter().enumerate() {
        let joint = urdf.joints.iter().find(|x| &x.name == name).unwrap();
        assert_eq!(config.position_min_rad[j], joint.limit.lower, "{name}");
        assert_eq!(config.position_max_rad[j], joint.limit.upper, "{name}");
        assert_eq!(
            config.velocity_limit_rad_s[j], joint.limit.velocity,
            "{name}"
        );
    }
    assert_eq!(config.cycle_s, SimConfig::default().cycle_s);
}

#[test]
fn opens_in_monitor_and_starts_commanding_after_perfect_quality() {
    let mut sim = FriSimulator::new(SimConfig::default()).unwrap();
    let mut t = Duration::from_secs(1);
    assert_eq!(sim.state(), FriState::Off);
    let first = sim.poll(t).unwrap();
    assert_eq!(first.interface.state, FriState::Monitor);
    assert_eq!(first.interface.quality, Quality::Unacceptable);
    sim.receive(&answer(&first, 0, None), t + Duration::from_micros(50));
    t += MS;
    // 99 more cycles: OK while the window fills, PERFECT once it holds 100.
    let m = run(&mut sim, &mut t, 99, |_, _| Some(None));
    assert_eq!(m.interface.quality, Quality::Ok);
    assert_eq!(m.interface.state, FriState::Monitor);
    let m = run(&mut sim, &mut t, 1, |_, _| Some(None));
    assert_eq!(m.interface.quality, Quality::Perfect);
    // friStart on the 10th PERFECT cycle.
    let m = run(&mut sim, &mut t, 8, |_, _| Some(None));
    assert_eq!(m.interface.state, FriState::Monitor);
    let m = run(&mut sim, &mut t, 1, |_, _| Some(None));
    assert_eq!(m.interface.state, FriState::Command);
    let events = sim.take_events();
    assert!(events.iter().any(
        |e| matches!(e, SimEvent::StartedCommanding { at_s } if (*at_s - 0.109).abs() < 1e-9)
    ));
    assert_eq!(m.interface.stats.answer_rate, 1.0);
    assert!((m.interface.stats.latency_s - 100e-6).abs() < 1e-9);
    assert_eq!(m.interface.stats.miss_counter, 0);
    assert!((m.interface.timestamp_s - 0.109).abs() < 1e-6);
}

#[test]
fn measurements_go_out_once_per_cycle_with_wrapping_sequence_numbers() {
    let mut sim = FriSimulator::new(SimConfig {
        initial_seq_count: 65534,
        cycle_s: 0.002,
        ..Default::default()
    })
    .unwrap();
    let t0 = Duration::from_millis(10);
    assert_eq!(sim.poll(t0).unwrap().send_seq_count, 65534);
    assert!(sim.poll(t0 + Duration::from_micros(1999)).is_none());
    assert_eq!(sim.next_send_time(), t0 + 2 * MS);
    assert_eq!(sim.poll(t0 + 2 * MS).unwrap().send_seq_count, 65535);
    assert_eq!(sim.poll(t0 + 4 * MS).unwrap().send_seq_count, 0);
    assert_eq!(sim.poll(t0 + 6 * MS).unwrap().send_seq_count, 1);
    // A stalled simulator sends one measurement and reschedules.
    let m = sim.poll(t0 + 20 * MS).unwrap();
    assert_eq!(m.send_seq_count, 2);
    assert_eq!(sim.counters().overruns, 1);
    assert_eq!(sim.next_send_time(), t0 + 22 * MS);
    assert_eq!(m.interface.desired_msr_sample_time_s, 0.002);
}

#[test]
fn answers_across_the_wrap_are_matched() {
    let mut sim = FriSimulator::new(SimConfig {
        initial_seq_count: 65535,
        ..Default::default()
    })
    .unwrap();
    let mut t = Duration::ZERO;
    let m = run(&mut sim, &mut t, 3, |_, _| Some(None));
    assert_eq!(m.send_seq_count, 1);
    assert_eq!(sim.counters().duplicate_answers, 0);
    let m = sim.poll(t).unwrap();
    assert_eq!(m.refl_seq_count, 1);
    assert_eq!(m.interface.stats.answer_rate, 1.0);
}

#[test]
fn command_mode_tracks_commands_and_reports_the_fri_offset() {
    let (mut sim, mut t) = started();
    let q0 = sim.joints_rad();
    // Move joint 0 at 0.5 rad/s for 100 ms.
    let m = run(&mut sim, &mut t, 100, |k, _| {
        let mut q = q0;
        q[0] += 0.5 * 0.001 * (k + 1) as f64;
        Some(Some(q))
    });
    // The measurement of cycle k shows the command of cycle k-1 (direct tracking).
    assert!((m.data.msr_jnt_pos[0] as f64 - (q0[0] + 0.5 * 0.099)).abs() < 1e-6);
    let m = sim.poll(t).unwrap();
    assert!((m.data.msr_jnt_pos[0] as f64 - (q0[0] + 0.05)).abs() < 1e-6);
    // The robot's own command stays; FRI adds the offset.
    assert!((m.data.cmd_jnt_pos[0] as f64 - q0[0]).abs() < 1e-6);
    assert!((m.data.cmd_jnt_pos_fri_offset[0] - 0.05).abs() < 1e-6);
    assert!((m.mirrored_jnt_pos()[0] as f64 - (q0[0] + 0.05)).abs() < 1e-6);
    assert_eq!(sim.state(), FriState::Command);
}

#[test]
fn first_order_lag_approaches_the_command() {
    let mut sim = FriSimulator::new(SimConfig {
        tracking_time_constant_s: 0.01,
        ..Default::default()
    })
    .unwrap();
    let mut t = Duration::ZERO;
    run(&mut sim, &mut t, 150, |_, _| Some(None));
    assert_eq!(sim.state(), FriState::Command);
    let mut q = [0.0; JOINTS];
    // Ramp joint 2 to 0.01 rad, then hold for 10 ms (one time constant).
    run(&mut sim, &mut t, 10, |k, _| {
        q[2] = 0.001 * (k + 1) as f64;
        Some(Some(q))
    });
    let before = sim.joints_rad()[2];
    assert!(before < 0.01, "{before}");
    run(&mut sim, &mut t, 10, |_, _| Some(Some(q)));
    let after = sim.joints_rad()[2];
    let target = f64::from(0.01f32);
    let expected = target - (target - before) * (-1.0f64).exp();
    assert!((after - expected).abs() < 1e-9, "{after} vs {expected}");
}

#[test]
fn withheld_answers_drop_to_monitor_and_stop_the_arm() {
    let (mut sim, mut t) = started();
    let q0 = sim.joints_rad();
    let mut q = q0;
    run(&mut sim, &mut t, 20, |_, _| {
        q[1] += 0.001; // 1 rad/s
        Some(Some(q))
    });
    // One missing answer is bridged by extrapolation: still CMD, still moving.
    let last_sent = f64::from(q[1] as f32);
    let m = run(&mut sim, &mut t, 2, |k, _| {
        if k == 0 {
            return None; // no answer
        }
        q[1] += 0.002;
        Some(Some(q))
    });
    assert_eq!(m.interface.state, FriState::Command);
    assert!((sim.joints_rad()[1] - (last_sent + 0.001)).abs() < 1e-6);
    assert!(sim
        .take_events()
        .iter()
        .all(|e| !matches!(e, SimEvent::DroppedToMonitor { .. })));
    // Answers stop: BAD after 2 misses, UNACCEPTABLE (drop) after 5.
    let mut states = Vec::new();
    run(&mut sim, &mut t, 7, |_, m| {
        states.push((m.interface.state, m.interface.quality));
        None
    });
    assert_eq!(states[2], (FriState::Command, Quality::Bad));
    assert_eq!(states[4], (FriState::Command, Quality::Bad));
    assert_eq!(states[5], (FriState::Monitor, Quality::Unacceptable));
    let reason = sim.drop_reason().unwrap();
    assert!(matches!(
        reason,
        DropReason::LinkQuality {
            quality: Quality::Unacceptable,
            consecutive_misses: 5,
            ..
        }
    ));
    // The arm stays where it stopped, and the robot's own command is that position.
    let stopped = sim.joints_rad();
    let m = run(&mut sim, &mut t, 50, |_, _| Some(Some(q0)));
    assert_eq!(sim.joints_rad(), stopped);
    assert_eq!(m.interface.state, FriState::Monitor);
    assert_eq!(m.data.cmd_jnt_pos, stopped.map(|v| v as f32));
    assert_eq!(m.data.cmd_jnt_pos_fri_offset, [0.0; JOINTS]);
    assert!(m.interface.stats.miss_counter >= 5);
    assert_eq!(sim.counters().drops_to_monitor, 1);
    // The KRL program does not restart by itself.
    run(&mut sim, &mut t, 200, |_, _| Some(None));
    assert_eq!(sim.state(), FriState::Monitor);
    sim.request_start();
    run(&mut sim, &mut t, 20, |_, _| Some(None));
    assert_eq!(sim.state(), FriState::Command);
}

/// A simulator whose KRL program loops around `friStart`, in command mode.
fn looping_krl_in_command_mode() -> (FriSimulator, Duration) {
    let mut sim = FriSimulator::new(SimConfig {
        restart_after_drop: true,
        ..Default::default()
    })
    .unwrap();
    let mut t = Duration::from_secs(3);
    run(&mut sim, &mut t, 150, |_, _| Some(None));
    assert_eq!(sim.state(), FriState::Command);
    (sim, t)
}

#[test]
fn a_krl_loop_restarts_command_mode_after_a_link_drop_only() {
    let (mut sim, mut t) = looping_krl_in_command_mode();
    // Five answers missed: the link drops the robot to monitor mode ...
    run(&mut sim, &mut t, 6, |_, _| None);
    assert_eq!(sim.state(), FriState::Monitor);
    let stopped = sim.joints_rad();
    // ... and the loop asks again: command mode once the misses left the window,
    // at the position where the arm stopped.
    run(&mut sim, &mut t, 50, |_, _| Some(None));
    assert_eq!(sim.state(), FriState::Monitor, "quality is not PERFECT yet");
    run(&mut sim, &mut t, 150, |_, _| Some(None));
    assert_eq!(sim.state(), FriState::Command);
    assert_eq!(sim.joints_rad(), stopped);
    assert_eq!(sim.counters().drops_to_monitor, 1);
    // friStop ends command mode for good.
    sim.request_stop(t);
    run(&mut sim, &mut t, 300, |_, _| Some(None));
    assert_eq!(sim.state(), FriState::Monitor);
}

#[test]
fn a_release_request_stops_command_mode_until_it_clears() {
    let (mut sim, mut t) = looping_krl_in_command_mode();
    sim.take_events();
    // Mirroring answers with the release bit: friStop at the first, and no
    // friStart while the bit stays set, however good the link.
    let released = |sim: &mut FriSimulator, t: &mut Duration, cycles: usize| {
        for _ in 0..cycles {
            let m = sim.poll(*t).unwrap();
            let mut command = CommandDatagram::decode(&answer(&m, m.send_seq_count, None)).unwrap();
            command.krl.bools = RELEASE_BIT;
            sim.receive(&command.encode(), *t + Duration::from_micros(100));
            *t += MS;
        }
    };
    released(&mut sim, &mut t, 1);
    assert_eq!(sim.state(), FriState::Monitor);
    assert_eq!(sim.drop_reason(), Some(DropReason::Released));
    released(&mut sim, &mut t, 300);
    assert_eq!(sim.state(), FriState::Monitor);
    assert_eq!(sim.counters().drops_to_monitor, 1);
    // A new session (bit clear): the KRL loop starts command mode again.
    run(&mut sim, &mut t, 150, |_, _| Some(None));
    assert_eq!(sim.state(), FriState::Command);
}

#[test]
fn commands_at_joint_or_velocity_limits_drop_to_monitor() {
    let (mut sim, mut t) = started();
    let mut q = sim.joints_rad();
    q[3] = LBR4_POSITION_LIMIT_RAD[3] + 0.001;
    run(&mut sim, &mut t, 1, |_, _| Some(Some(q)));
    assert_eq!(
        sim.drop_reason(),
        Some(DropReason::JointLimit {
            joint: 3,
            commanded_rad: f64::from(q[3] as f32),
            limit_rad: LBR4_POSITION_LIMIT_RAD[3],
        })
    );
    assert_eq!(sim.state(), FriState::Monitor);

    let (mut sim, mut t) = started();
    let mut q = sim.joints_rad();
    // 0.004 rad in one 1 ms cycle is 4 rad/s, over joint 5's 3.21 rad/s.
    q[5] += 0.004;
    run(&mut sim, &mut t, 1, |_, _| Some(Some(q)));
    match sim.drop_reason() {
        Some(DropReason::VelocityLimit {
            joint: 5,
            speed_rad_s,
            limit_rad_s,
        }) => {
            assert!((speed_rad_s - 4.0).abs() < 1e-3, "{speed_rad_s}");
            assert_eq!(limit_rad_s, LBR4_VELOCITY_LIMIT_RAD_S[5]);
        }
        other => panic!("expected a velocity drop, got {other:?}"),
    }
    // Just under the limit is accepted.
    let (mut sim, mut t) = started();
    let mut q = sim.joints_rad();
    run(&mut sim, &mut t, 20, |_, _| {
        q[5] += 0.0032;
        Some(Some(q))
    });
    assert_eq!(sim.state(), FriState::Command);
}

#[test]
fn flag_changes_in_command_mode_and_garbage_are_handled() {
    let (mut sim, mut t) = started();
    let m = sim.poll(t).unwrap();
    assert_eq!(sim.receive(&[1, 2, 3], t), Answer::Garbled);
    assert_eq!(sim.counters().bad_datagrams, 1);
    let mut cmd = CommandDatagram::decode(&answer(&m, 9, None)).unwrap();
    cmd.refl_seq_count = m.send_seq_count.wrapping_add(500);
    assert_eq!(sim.receive(&cmd.encode(), t), Answer::Unexpected);
    cmd.refl_seq_count = m.send_seq_count;
    cmd.cmd_flags = CmdFlags::JNT_POS | CmdFlags::JNT_STIFF;
    assert!(matches!(
        sim.receive(&cmd.encode(), t),
        Answer::InTime { .. }
    ));
    assert_eq!(sim.receive(&cmd.encode(), t), Answer::Duplicate);
    assert_eq!(
        sim.drop_reason(),
        Some(DropReason::FlagsChanged {
            latched: 0x1,
            received: 0x11
        })
    );
    t += MS;
    let _ = sim.poll(t);
    let events = sim.take_events();
    assert!(events
        .iter()
        .any(|e| matches!(e, SimEvent::BadDatagram { .. })));
    assert!(events
        .iter()
        .any(|e| matches!(e, SimEvent::UnexpectedAnswer { .. })));
}

#[test]
fn late_answers_count_as_misses_but_are_timed() {
    let mut sim = FriSimulator::new(SimConfig {
        record_latencies: true,
        ..Default::default()
    })
    .unwrap();
    let t = Duration::ZERO;
    let m0 = sim.poll(t).unwrap();
    let _m1 = sim.poll(t + MS).unwrap();
    let late = sim.receive(&answer(&m0, 0, None), t + Duration::from_micros(1300));
    assert_eq!(late, Answer::Late { latency_s: 0.0013 });
    let m2 = sim.poll(t + 2 * MS).unwrap();
    assert_eq!(m2.interface.stats.miss_counter, 2);
    assert_eq!(m2.interface.stats.answer_rate, 0.0);
    assert_eq!(sim.latencies_s(), &[0.0013]);
    assert_eq!(sim.counters().late_answers, 1);
}

#[test]
fn bad_configuration_is_named() {
    let err = FriSimulator::new(SimConfig {
        cycle_s: 0.0005,
        ..Default::default()
    })
    .unwrap_err();
    assert!(err.to_string().contains("cycle_s"), "{err}");
    let mut q = [0.0; JOINTS];
    q[1] = 2.5;
    let err = FriSimulator::new(SimConfig {
        initial_joints_rad: q,
        ..Default::default()
    })
    .unwrap_err();
    assert!(err.to_string().contains("initial_joints_rad[1]"), "{err}");
}
