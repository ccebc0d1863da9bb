//! `cell-log`: the trial log stage of the cell (see `graspcell::cell::log`).

use clap::Parser;
use graspcell::cell::log::{LogOptions, ObserverKind};
use graspcell::cell::{log, stage_main, StageArgs};
use graspcell::config::CellConfig;
use std::path::PathBuf;

/// Follows every trial, has it graded (simulated observer or the person at the
/// terminal), records it in the SQLite trial log and publishes the result.
#[derive(Debug, Parser)]
#[command(name = "cell-log", version)]
struct Args {
    #[command(flatten)]
    stage: StageArgs,
    /// The trial log (default: `<run dir>/trials.sqlite`).
    #[arg(long, value_name = "FILE")]
    log: Option<PathBuf>,
    /// Who grades the trials: the simulated observer by physics (default) or by
    /// static epsilon (both verdicts are logged either way), or a person.
    #[arg(long, value_enum, default_value_t = ObserverKind::Physics)]
    observer: ObserverKind,
    /// Longest a trial may take before it is recorded as timed out (s).
    #[arg(long, default_value_t = 120.0)]
    trial_timeout_s: f64,
    /// Directory of the category databases (model meshes for the trial pictures).
    #[arg(long, default_value = "db")]
    db_dir: PathBuf,
}

fn main() -> std::process::ExitCode {
    let args = Args::parse();
    stage_main("log", || {
        let config = CellConfig::load(&args.stage.config)?;
        let options = LogOptions {
            log_path: args
                .log
                .clone()
                .unwrap_or_else(|| log::default_log_path(&args.stage.run_dir)),
            run_dir: args.stage.run_dir.clone(),
            observer: args.observer,
            trial_timeout_s: args.trial_timeout_s,
            db_dir: args.db_dir.clone(),
        };
        log::run(&config, &args.stage.domain()?, options)
    })
}
