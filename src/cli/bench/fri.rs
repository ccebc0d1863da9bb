//! `cell bench fri`: the FRI driver against the robot simulator over loopback UDP.

use crate::clock::{Clock, SystemClock};
use crate::config::CellConfig;
use crate::hw::fri::driver::DriverCounters;
use crate::hw::fri::{DriverConfig, FriDriver, FriState, Quality, JOINTS};
use crate::sim::fri::{spawn_udp, DropReason, SimConfig, SimCounters, LBR4_VELOCITY_LIMIT_RAD_S};
use crate::stats::percentile;
use crate::trajectory::{JointLimits, Trajectory};
use anyhow::Context;
use clap::Args;
use indicatif::{ProgressBar, ProgressStyle};
use serde::Serialize;
use std::path::Path;
use std::process::ExitCode;
use std::sync::Arc;
use std::time::{Duration, Instant};

/// Options of `cell bench fri`.
#[derive(Debug, Args)]
pub struct FriBenchArgs {
    /// How long to stream trajectories (s).
    #[arg(long, default_value_t = 30.0)]
    pub seconds: f64,
    /// FRI cycle (ms): the simulator sends one measurement per cycle.
    #[arg(long, default_value_t = 1.0)]
    pub cycle_ms: f64,
    /// Longest wait for the robot to enter command mode (s).
    #[arg(long, default_value_t = 10.0)]
    pub start_timeout_s: f64,
    /// Print JSON.
    #[arg(long)]
    pub json: bool,
}

/// Answer latency percentiles (µs), measured at the simulator.
#[derive(Debug, Serialize)]
pub struct LatencyUs {
    /// Answers timed.
    pub samples: usize,
    /// Median.
    pub p50: f64,
    /// 99th percentile.
    pub p99: f64,
    /// Maximum.
    pub max: f64,
}

/// The result of `cell bench fri`.
#[derive(Debug, Serialize)]
pub struct FriBenchReport {
    /// Workload description.
    pub workload: String,
    /// FRI cycle (s).
    pub cycle_s: f64,
    /// Streaming time asked for (s).
    pub seconds_requested: f64,
    /// Streaming time achieved (s, wall clock).
    pub streamed_s: f64,
    /// Time from start to command mode (s, wall clock).
    pub time_to_command_mode_s: f64,
    /// Round trips run to their end.
    pub round_trips_completed: u64,
    /// Motions that ended early (quality, drop to monitor, late measurement).
    pub motions_aborted: u64,
    /// Times the KRL program was restarted after a drop to monitor.
    pub krl_restarts: u64,
    /// Times the robot dropped to monitor mode while streaming.
    pub drops_to_monitor: u64,
    /// Measurement sent -> command received at the simulator, while streaming.
    pub answer_latency_us: LatencyUs,
    /// Measurements sent while streaming.
    pub measurements: u64,
    /// Measurements not answered within their cycle, while streaming.
    pub missed_cycles: u64,
    /// Answers that came after the next measurement, while streaming.
    pub late_answers: u64,
    /// Cycles the simulator itself sent late (its thread stalled), while streaming.
    pub simulator_overruns: u64,
    /// The driver's counters over the whole run.
    pub driver: DriverCounters,
    /// The robot's state at the end.
    pub final_state: FriState,
    /// The link quality at the end.
    pub final_quality: Quality,
    /// Why the robot last dropped to monitor, if it did.
    pub drop_reason: Option<DropReason>,
    /// Why the last aborted motion ended, if any did.
    pub last_motion_error: Option<String>,
}

/// Runs `cell bench fri`.
pub fn bench_fri(config: &Path, args: FriBenchArgs) -> anyhow::Result<ExitCode> {
    let report = run_bench(config, &args)?;
    crate::cli::emit(args.json, &report, |r| {
        format!(
            "FRI at {:.0} Hz for {:.1} s: answer latency p50 {:.0} µs, p99 {:.0} µs, max {:.0} µs \
             ({} answers); {} missed cycles of {}; {} round trips, {} aborted, {} drops to monitor; \
             final state {:?} ({:?}){}\n",
            1.0 / r.cycle_s,
            r.streamed_s,
            r.answer_latency_us.p50,
            r.answer_latency_us.p99,
            r.answer_latency_us.max,
            r.answer_latency_us.samples,
            r.missed_cycles,
            r.measurements,
            r.round_trips_completed,
            r.motions_aborted,
            r.drops_to_monitor,
            r.final_state,
            r.final_quality,
            r.drop_reason
                .map(|d| format!("; dropped to monitor: {d}"))
                .unwrap_or_default(),
        )
    })?;
    Ok(ExitCode::SUCCESS)
}

fn run_bench(config_path: &Path, args: &FriBenchArgs) -> anyhow::Result<FriBenchReport> {
    anyhow::ensure!(
        args.seconds.is_finite() && args.seconds > 0.0,
        "--seconds {}: must be a finite number > 0",
        args.seconds
    );
    let cell = CellConfig::load(config_path)?;
    let limits = JointLimits::new(
        LBR4_VELOCITY_LIMIT_RAD_S.map(|v| v * cell.limits.joint_velocity_scale),
        [cell.limits.joint_acceleration_rad_s2; JOINTS],
    )?;
    let cycle_s = args.cycle_ms / 1000.0;
    let clock: Arc<dyn Clock> = Arc::new(SystemClock::new());
    let driver = FriDriver::start(
        DriverConfig {
            bind_addr: "127.0.0.1:0".parse()?,
            timeout_s: cell.fri.timeout_s,
            ..DriverConfig::default()
        },
        Arc::clone(&clock),
    )?;
    let sim = spawn_udp(
        SimConfig {
            cycle_s,
            record_latencies: true,
            // The robot enforces the URDF's joint limits.
            ..SimConfig::from_robot(&crate::robot::Robot::load(&cell)?)
        },
        "127.0.0.1:0".parse()?,
        driver.local_addr(),
        clock,
    )?;
    let began = Instant::now();
    let status = driver
        .wait_until_commanding(args.start_timeout_s)
        .context("waiting for the simulated robot to enter command mode")?;
    let time_to_command_mode_s = began.elapsed().as_secs_f64();

    // Count only the streaming phase.
    let before: SimCounters = sim.with(|s| {
        s.take_latencies_s();
        s.counters()
    });
    let home = status.commanded_rad;
    let away: [f64; JOINTS] = std::array::from_fn(|j| home[j] + SWING_RAD[j]);
    let round_trip = Trajectory::through(&[home, away, home], &limits)?;
    let workload = format!(
        "driver and simulator threads over 127.0.0.1 UDP; repeated round trips between {home:.3?} and {away:.3?} rad ({:.2} s each) at {} x the LBR4+ speed limits and {} rad/s^2; after an abort the arm returns home, after a drop to monitor the KRL program is restarted",
        round_trip.duration_s(),
        cell.limits.joint_velocity_scale,
        cell.limits.joint_acceleration_rad_s2
    );
    let bar = ProgressBar::new((args.seconds * 10.0).ceil() as u64);
    bar.set_style(
        ProgressStyle::with_template("bench fri {bar:40} {elapsed}/{duration} {msg}")
            .unwrap_or_else(|_| ProgressStyle::default_bar()),
    );
    let streaming = Instant::now();
    let (mut completed, mut aborted, mut restarts) = (0, 0, 0);
    let mut last_motion_error = None;
    while streaming.elapsed().as_secs_f64() < args.seconds {
        bar.set_position((streaming.elapsed().as_secs_f64() * 10.0) as u64);
        let status = driver.status();
        if !status.commanding {
            // After a drop to monitor the operator restarts the KRL program.
            let restarted = sim.with(|s| {
                let restart = s.state() == FriState::Monitor && !s.start_requested();
                if restart {
                    s.request_start();
                }
                restart
            });
            restarts += u64::from(restarted);
            driver
                .wait_until_commanding(args.start_timeout_s)
                .context("waiting for the simulated robot to return to command mode")?;
            continue;
        }
        let from = status.commanded_rad;
        let at_home = (0..JOINTS).all(|j| (from[j] - home[j]).abs() < 1e-3);
        let trajectory = if at_home {
            round_trip.clone()
        } else {
            Trajectory::through(&[from, home], &limits)?
        };
        let outcome = driver.start_trajectory(trajectory).and_then(|id| loop {
            bar.set_position((streaming.elapsed().as_secs_f64() * 10.0) as u64);
            match driver.motion_outcome(id) {
                None => std::thread::sleep(Duration::from_millis(20)),
                Some(result) => break result,
            }
        });
        match outcome {
            Ok(()) => completed += u64::from(at_home),
            Err(e) => {
                aborted += 1;
                last_motion_error = Some(e.to_string());
                // Let the link settle before trying again.
                std::thread::sleep(Duration::from_millis(20));
            }
        }
    }
    let streamed_s = streaming.elapsed().as_secs_f64();
    bar.finish_and_clear();

    let (mut latencies, after) = sim.with(|s| (s.take_latencies_s(), s.counters()));
    let summary = sim.stop()?;
    let driver_status = driver.status();
    driver.shutdown(1.0)?;
    let us = |p: f64, l: &mut [f64]| percentile(l, p) * 1e6;
    Ok(FriBenchReport {
        workload,
        cycle_s,
        seconds_requested: args.seconds,
        streamed_s,
        time_to_command_mode_s,
        round_trips_completed: completed,
        motions_aborted: aborted,
        krl_restarts: restarts,
        drops_to_monitor: after.drops_to_monitor - before.drops_to_monitor,
        answer_latency_us: LatencyUs {
            samples: latencies.len(),
            p50: us(0.5, &mut latencies),
            p99: us(0.99, &mut latencies),
            max: us(1.0, &mut latencies),
        },
        measurements: after.measurements_sent - before.measurements_sent,
        missed_cycles: after.misses - before.misses,
        late_answers: after.late_answers - before.late_answers,
        simulator_overruns: after.overruns - before.overruns,
        driver: driver_status.counters,
        final_state: summary.state,
        final_quality: summary.quality,
        drop_reason: summary.drop_reason,
        last_motion_error,
    })
}

/// How far each joint swings from where the arm starts (rad).
const SWING_RAD: [f64; JOINTS] = [0.6, 0.4, -0.5, -0.6, 0.8, 0.5, -0.9];
