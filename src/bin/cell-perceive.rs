//! `cell-perceive`: the perception stage of the cell (see `graspcell::cell::perceive`).

use clap::Parser;
use graspcell::cell::perceive::{self, PerceiveOptions};
use graspcell::cell::{stage_main, StageArgs};
use graspcell::config::CellConfig;
use std::path::PathBuf;

/// Segments the object out of every trial's snapshot and registers every model of
/// the requested category to it; publishes each model's transform and fitting error.
#[derive(Debug, Parser)]
#[command(name = "cell-perceive", version)]
struct Args {
    #[command(flatten)]
    stage: StageArgs,
    /// Directory of the category databases (`<dir>/<category>/category.json`).
    #[arg(long, default_value = "db")]
    db_dir: PathBuf,
    /// Hand–eye calibration result (`cell calibrate solve`); the configuration's
    /// nominal camera mount is used, with a warning, when it is missing or invalid.
    #[arg(long, default_value = graspcell::calib::DEFAULT_RESULT_PATH)]
    hand_eye: PathBuf,
}

fn main() -> std::process::ExitCode {
    let args = Args::parse();
    stage_main("perceive", || {
        let config = CellConfig::load(&args.stage.config)?;
        let options = PerceiveOptions {
            db_dir: args.db_dir.clone(),
            hand_eye: args.hand_eye.clone(),
            run_dir: args.stage.run_dir.clone(),
        };
        perceive::run(&config, &args.stage.domain()?, &options)
    })
}
