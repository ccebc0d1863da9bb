//! `cell fk` and `cell ik` (`cell bench ik` is in `bench::ik`).

use super::emit;
use crate::config::CellConfig;
use crate::geometry::{parse_numbers, parse_pose, PoseJson};
use crate::robot::kinematics::{ArmJoints, ARM_DOF};
use crate::robot::{HandPose, Robot};
use anyhow::Context;
use clap::Args;
use serde::Serialize;
use std::path::Path;
use std::process::ExitCode;

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

pub(super) fn load_robot(config: &Path) -> anyhow::Result<Robot> {
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
