//! `cell fk`, `cell ik` and `cell bench ik`.

use super::bench::IkBenchArgs;
use clap::Args;
use std::path::Path;
use std::process::ExitCode;

/// Options of `cell fk`.
#[derive(Debug, Args)]
pub struct FkArgs {
    /// Seven arm joint angles A1,A2,E1,A3,A4,A5,A6 (rad).
    #[arg(long, allow_hyphen_values = true)]
    pub joints: String,
    /// Print JSON.
    #[arg(long)]
    pub json: bool,
}

/// Options of `cell ik`.
#[derive(Debug, Args)]
pub struct IkArgs {
    /// Palm pose x,y,z,roll,pitch,yaw (m, rad; URDF rpy) in the robot base frame.
    #[arg(long, allow_hyphen_values = true)]
    pub pose: String,
    /// Joint angles to start from (rad), e.g. the arm's current configuration.
    #[arg(long, allow_hyphen_values = true)]
    pub seed_joints: Option<String>,
    /// Print JSON.
    #[arg(long)]
    pub json: bool,
}

/// Runs `cell fk`.
pub fn fk(_config: &Path, _args: FkArgs) -> anyhow::Result<ExitCode> {
    anyhow::bail!("cell fk: robot module not wired yet")
}

/// Runs `cell ik`.
pub fn ik(_config: &Path, _args: IkArgs) -> anyhow::Result<ExitCode> {
    anyhow::bail!("cell ik: robot module not wired yet")
}

/// Runs `cell bench ik`.
pub fn bench_ik(_config: &Path, _args: IkBenchArgs) -> anyhow::Result<ExitCode> {
    anyhow::bail!("cell bench ik: robot module not wired yet")
}
