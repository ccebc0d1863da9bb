//! `cell-execute`: the execution stage of the cell (see `graspcell::cell::execute`).

use clap::Parser;
use graspcell::cell::{execute, stage_main, CellError, StageArgs};
use graspcell::config::CellConfig;

/// Executes every grasp plan on the arm (FRI) and the hand (CAN) behind the safety
/// layer; publishes the phases and joint states. Backends: `fri.backend` and
/// `can.interface` in the configuration.
#[derive(Debug, Parser)]
#[command(name = "cell-execute", version)]
struct Args {
    #[command(flatten)]
    stage: StageArgs,
    /// Local UDP address of the FRI driver (default: `fri.bind_addr`).
    #[arg(long, value_name = "ADDR")]
    fri_bind: Option<String>,
    /// The robot controller the FRI driver answers, IP or IP:port (default:
    /// `fri.robot_addr`).
    #[arg(long, value_name = "ADDR")]
    fri_robot: Option<String>,
    /// CAN interface of the hand (default: `can.interface`).
    #[arg(long, value_name = "INTERFACE")]
    can_interface: Option<String>,
    /// How long to hold the lifted object (s).
    #[arg(long, default_value_t = 2.0)]
    hold_s: f64,
}

fn main() -> std::process::ExitCode {
    let args = Args::parse();
    stage_main("execute", || {
        if !(args.hold_s.is_finite() && args.hold_s >= 0.0) {
            return Err(CellError::Invalid(format!(
                "--hold-s {}: must be a finite number >= 0",
                args.hold_s
            )));
        }
        let config = CellConfig::load(&args.stage.config)?;
        let options = execute::ExecuteOptions {
            fri_bind: args.fri_bind.clone(),
            fri_robot: args.fri_robot.clone(),
            can_interface: args.can_interface.clone(),
            hold_s: args.hold_s,
        };
        execute::run(&config, &args.stage.domain()?, &options)
    })
}
