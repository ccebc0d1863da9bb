//! `cell bench ik`: inverse kinematics and reachability over seeded random poses.

use crate::cli::emit;
use crate::cli::robot::load_robot;
use crate::robot::kinematics::ArmJoints;
use crate::robot::HandPose;
use crate::stats::{median, percentile};
use clap::Args;
use rand::{Rng, SeedableRng};
use serde::Serialize;
use std::path::Path;
use std::process::ExitCode;
use std::time::Instant;

/// Options of `cell bench ik`.
#[derive(Debug, Args)]
pub struct IkBenchArgs {
    /// Number of random reachable poses to solve.
    #[arg(long, default_value_t = 1000)]
    pub poses: usize,
    /// Seed of the random configurations.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Print JSON (the benchmark always prints JSON; accepted for uniformity).
    #[arg(long)]
    pub json: bool,
}

#[derive(Serialize)]
struct IkBench {
    poses: usize,
    seed: u64,
    ik_median_us: f64,
    ik_p99_us: f64,
    ik_success_rate: f64,
    reach_median_us: f64,
    reach_reachable_rate: f64,
    median_iterations: f64,
}

/// Runs `cell bench ik`: IK of the FK palm pose of seeded random configurations,
/// solved from the fixed seed spread only (the true configuration is not given);
/// then the full reachability check (IK + table + self collision) of random grasp
/// poses over the table.
pub fn bench_ik(config: &Path, args: IkBenchArgs) -> anyhow::Result<ExitCode> {
    let robot = load_robot(config)?;
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(args.seed);
    let arm = robot.arm();
    let targets: Vec<_> = (0..args.poses)
        .map(|_| {
            let q: ArmJoints =
                std::array::from_fn(|i| rng.gen_range(arm.lower_rad[i]..=arm.upper_rad[i]));
            arm.palm(&q)
        })
        .collect();
    let mut ik_us = Vec::with_capacity(targets.len());
    let mut iterations = Vec::with_capacity(targets.len());
    let mut solved = 0;
    for target in &targets {
        let start = Instant::now();
        let result = robot.ik.solve(target, &[]);
        ik_us.push(start.elapsed().as_secs_f64() * 1e6);
        if let Ok(s) = result {
            solved += 1;
            iterations.push(s.iterations as f64);
        }
    }
    // Reachability of grasp-like palm poses over the table: approach within 60 deg
    // of straight down, any yaw, 0.1-0.35 m above the table.
    let grasps: Vec<_> = (0..args.poses)
        .map(|_| {
            let tilt = rng.gen_range(0.0..60f64.to_radians());
            let tilt_dir = rng.gen_range(-std::f64::consts::PI..std::f64::consts::PI);
            let yaw = rng.gen_range(-std::f64::consts::PI..std::f64::consts::PI);
            let rotation =
                nalgebra::UnitQuaternion::from_axis_angle(&nalgebra::Vector3::z_axis(), tilt_dir)
                    * nalgebra::UnitQuaternion::from_axis_angle(
                        &nalgebra::Vector3::x_axis(),
                        std::f64::consts::PI - tilt,
                    )
                    * nalgebra::UnitQuaternion::from_axis_angle(&nalgebra::Vector3::z_axis(), yaw);
            let xyz = nalgebra::Translation3::new(
                rng.gen_range(0.4..0.8),
                rng.gen_range(-0.3..0.3),
                rng.gen_range(0.1..0.35),
            );
            nalgebra::Isometry3::from_parts(xyz, rotation)
        })
        .collect();
    let mut reach_us = Vec::with_capacity(grasps.len());
    let mut reachable = 0;
    for target in &grasps {
        let start = Instant::now();
        let result = robot.reach(target, &HandPose::OPEN, &[]);
        reach_us.push(start.elapsed().as_secs_f64() * 1e6);
        reachable += usize::from(result.is_ok());
    }
    let n = targets.len().max(1) as f64;
    let out = IkBench {
        poses: targets.len(),
        seed: args.seed,
        ik_median_us: median(&mut ik_us),
        ik_p99_us: percentile(&mut ik_us, 0.99),
        ik_success_rate: solved as f64 / n,
        reach_median_us: median(&mut reach_us),
        reach_reachable_rate: reachable as f64 / n,
        median_iterations: median(&mut iterations),
    };
    emit(true, &out, |_| String::new())?;
    Ok(ExitCode::SUCCESS)
}
