//! `cell-plan`: the planning stage of the cell (see `graspcell::cell::plan`).

use clap::Parser;
use graspcell::cell::{plan, stage_main, StageArgs};
use graspcell::config::CellConfig;
use std::path::PathBuf;

/// Plans the grasp of every trial from its fits (eq. 2 with the requested kernel, or
/// the best-single baseline), reachable by the arm; publishes the grasp plan.
#[derive(Debug, Parser)]
#[command(name = "cell-plan", version)]
struct Args {
    #[command(flatten)]
    stage: StageArgs,
    /// Directory of the category databases (`<dir>/<category>/category.json`).
    #[arg(long, default_value = "db")]
    db_dir: PathBuf,
}

fn main() -> std::process::ExitCode {
    let args = Args::parse();
    stage_main("plan", || {
        let config = CellConfig::load(&args.stage.config)?;
        plan::run(&config, &args.stage.domain()?, &args.db_dir)
    })
}
