//! `cell fk`, `cell ik` and `cell bench ik`.

use super::bench::{median, percentile, IkBenchArgs};
use super::emit;
use crate::config::CellConfig;
use crate::geometry::{parse_numbers, parse_pose, PoseJson};
use crate::robot::kinematics::{ArmJoints, ARM_DOF};
use crate::robot::{HandPose, Robot};
use anyhow::Context;
use clap::Args;
use rand::{Rng, SeedableRng};
use serde::Serialize;
use std::path::Path;
use std::process::ExitCode;
use std::time::Instant;

/// Options of `cell fk`.
#[derive(Debug, Args)]
pub struct FkArgs {
    /// Seven arm joint angles A1,A2,E1,A3,A4,A5,A6 (rad), inside the URDF limits.
    #[arg(long, allow_hyphen_values = true)]
    pub joints: String,
    /// Print JSON: {"flange": pose, "palm": pose, "joints": [...]}.
    #[arg(long)]
    pub json: bool,
}

/// Options of `cell ik`.
#[derive(Debug, Args)]
pub struct IkArgs {
    /// Palm pose x,y,z,roll,pitch,yaw (m, rad; URDF rpy) in the robot base frame.
    #[arg(long, allow_hyphen_values = true)]
    pub pose: String,
    /// Joint angles to try first (rad), e.g. the arm's current configuration.
    #[arg(long, allow_hyphen_values = true)]
    pub seed_joints: Option<String>,
    /// Print JSON: {"reachable", "joints", "pos_err_m", "rot_err_rad", "reason"}.
    #[arg(long)]
    pub json: bool,
}

fn load_robot(config: &Path) -> anyhow::Result<Robot> {
    let config = CellConfig::load(config)?;
    Ok(Robot::load(&config)?)
}

fn parse_joints(text: &str, what: &str) -> anyhow::Result<ArmJoints> {
    let v = parse_numbers(text, ARM_DOF, what)?;
    let mut q = [0.0; ARM_DOF];
    q.copy_from_slice(&v);
    Ok(q)
}

#[derive(Serialize)]
struct FkOutput {
    joints: ArmJoints,
    flange: PoseJson,
    palm: PoseJson,
}

/// Runs `cell fk`.
pub fn fk(config: &Path, args: FkArgs) -> anyhow::Result<ExitCode> {
    let robot = load_robot(config)?;
    let q = parse_joints(&args.joints, "--joints (7 angles, rad)")?;
    robot.check_limits(&q).context("--joints")?;
    let (flange, palm) = robot.arm().flange_and_palm(&q);
    let out = FkOutput {
        joints: q,
        flange: PoseJson::from(&flange),
        palm: PoseJson::from(&palm),
    };
    emit(args.json, &out, |o| {
        let line = |name: &str, p: &PoseJson| {
            let r = p.rpy.unwrap_or_default();
            format!(
                "{name:<7} xyz = [{:.4}, {:.4}, {:.4}] m   rpy = [{:.4}, {:.4}, {:.4}] rad\n",
                p.xyz[0], p.xyz[1], p.xyz[2], r[0], r[1], r[2]
            )
        };
        line("flange", &o.flange) + &line("palm", &o.palm)
    })?;
    Ok(ExitCode::SUCCESS)
}

#[derive(Serialize)]
struct IkOutput {
    reachable: bool,
    joints: Option<ArmJoints>,
    pos_err_m: Option<f64>,
    rot_err_rad: Option<f64>,
    reason: Option<String>,
    reason_detail: Option<crate::robot::UnreachableReason>,
}

/// Runs `cell ik`.
pub fn ik(config: &Path, args: IkArgs) -> anyhow::Result<ExitCode> {
    let robot = load_robot(config)?;
    let target = parse_pose(&args.pose).context("--pose")?;
    let seeds = match &args.seed_joints {
        Some(text) => vec![parse_joints(text, "--seed-joints (7 angles, rad)")?],
        None => Vec::new(),
    };
    let out = match robot.reach(&target, &HandPose::OPEN, &seeds) {
        Ok(s) => IkOutput {
            reachable: true,
            joints: Some(s.joints),
            pos_err_m: Some(s.pos_err_m),
            rot_err_rad: Some(s.rot_err_rad),
            reason: None,
            reason_detail: None,
        },
        Err(u) => IkOutput {
            reachable: false,
            joints: u.best.as_ref().map(|b| b.joints),
            pos_err_m: u.best.as_ref().map(|b| b.pos_err_m),
            rot_err_rad: u.best.as_ref().map(|b| b.rot_err_rad),
            reason: Some(u.reason.to_string()),
            reason_detail: Some(u.reason),
        },
    };
    emit(args.json, &out, |o| match (&o.joints, o.reachable) {
        (Some(q), true) => format!(
            "reachable: joints = {:.4?} rad (error {:.3} mm, {:.5} rad)\n",
            q,
            o.pos_err_m.unwrap_or(0.0) * 1e3,
            o.rot_err_rad.unwrap_or(0.0)
        ),
        _ => format!("unreachable: {}\n", o.reason.as_deref().unwrap_or("")),
    })?;
    Ok(ExitCode::SUCCESS)
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
