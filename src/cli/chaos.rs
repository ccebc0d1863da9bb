//! `cell chaos`: the fault campaign (see [`crate::cell::chaos`]).

use super::cell::{check_method, progress, run_dir_or_temp, TrialKind};
use super::emit;
use crate::cell::chaos::{ChaosOptions, ChaosSummary, ChaosTrial, FaultKind};
use crate::cell::harness::HarnessOptions;
use crate::cell::StageArgs;
use crate::ipc::Domain;
use anyhow::Context;
use clap::Args;
use serde::Serialize;
use std::path::{Path, PathBuf};
use std::process::ExitCode;

/// Options of `cell chaos`.
#[derive(Debug, Args)]
pub struct ChaosArgs {
    /// Trials, each with one fault.
    #[arg(long, default_value_t = 100)]
    pub trials: u32,
    /// Seed of the faults (kind order, strength, timing), objects and placements.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    #[command(flatten)]
    pub kind: TrialKind,
    /// Task.
    #[arg(long, default_value = "top")]
    pub task: String,
    /// Planning method.
    #[arg(long, default_value = "laplace")]
    pub method: String,
    /// Fault kinds to draw from, comma-separated (default: all): none (a control
    /// trial), kill, can-loss, can-corruption, fri-withheld, fri-late, fri-spoof,
    /// shm-corrupt, disk-full.
    #[arg(long, value_delimiter = ',', value_parser = parse_kind)]
    pub faults: Vec<FaultKind>,
    /// Keep the trial log, the processes' standard error and the simulators' state
    /// here (default: a temporary directory, removed at the end).
    #[arg(long)]
    pub run_dir: Option<PathBuf>,
    /// Print one JSON document instead of lines.
    #[arg(long)]
    pub json: bool,
}

/// A fault kind `cell chaos` does not know.
#[derive(Debug, thiserror::Error)]
#[error("unknown fault {text:?} (use {})", fault_names())]
struct UnknownFault {
    text: String,
}

/// The fault kinds' names, comma-separated.
fn fault_names() -> String {
    let names: Vec<&str> = FaultKind::ALL.iter().map(|k| k.name()).collect();
    names.join(", ")
}

fn parse_kind(text: &str) -> Result<FaultKind, UnknownFault> {
    FaultKind::ALL
        .into_iter()
        .find(|k| k.name() == text)
        .ok_or_else(|| UnknownFault {
            text: text.to_string(),
        })
}

/// Runs `cell chaos`; exits non-zero when a trial hung, a process panicked, an
/// unsafe command reached the robot or an answered trial is missing from the log.
pub fn run(config_path: &Path, args: ChaosArgs) -> anyhow::Result<ExitCode> {
    check_method(&args.method)?;
    anyhow::ensure!(args.trials > 0, "--trials must be at least 1");
    let db = crate::cell::load_category(&args.kind.db_dir, &args.kind.category)?;
    let (run_dir, _temp_run) = run_dir_or_temp(args.run_dir.as_deref(), "chaos")?;
    let domain = Domain::temporary("chaos")?;
    let stage = StageArgs::in_domain(config_path, &domain, &run_dir);
    let mut harness = HarnessOptions::demo(stage)?;
    harness.db_dir = args.kind.db_dir.clone();
    harness.hold_s = 0.1;
    harness.trial_timeout_s = 60.0;
    let options = ChaosOptions {
        trials: args.trials,
        seed: args.seed,
        category: args.kind.category.clone(),
        task: args.task.clone(),
        method: args.method.clone(),
        kinds: if args.faults.is_empty() {
            FaultKind::ALL.to_vec()
        } else {
            args.faults.clone()
        },
    };
    crate::cell::install_stop_handler();
    eprintln!("starting the cell (5 stages, simulated arm and hand, faulty links) ...");
    let bar = progress(args.trials as u64, args.json);
    let mut trials = Vec::new();
    let summary = crate::cell::chaos::run(harness, (*domain).clone(), &db, &options, &mut |t| {
        if !args.json {
            bar.suspend(|| println!("{}", t.text()));
        }
        bar.inc(1);
        trials.push(t.clone());
    })
    .context("fault campaign")?;
    bar.finish_and_clear();
    domain
        .remove()
        .context("removing the campaign's IPC domain")?;
    let clean = summary.unsafe_commands == 0
        && summary.log_rows_lost == 0
        && summary.panics == 0
        && summary.hangs == 0;
    #[derive(Serialize)]
    struct ChaosOutput {
        trials: Vec<ChaosTrial>,
        summary: ChaosSummary,
    }
    let out = ChaosOutput { trials, summary };
    emit(args.json, &out, |o| o.summary.text())?;
    Ok(if clean {
        ExitCode::SUCCESS
    } else {
        ExitCode::FAILURE
    })
}
