//! `cell bench ...`: benchmarks that print one JSON document with medians.
//!
//! Speed is measured here, never asserted in tests. Each benchmark states its
//! workload, repeats it, and reports medians (and ratios to a baseline measured in the
//! same run where there is one).

use clap::{Args, Subcommand};
use std::path::Path;
use std::process::ExitCode;

/// The benchmarks.
#[derive(Debug, Subcommand)]
pub enum BenchCommand {
    /// Inverse kinematics: median solve time and success rate over seeded random poses.
    Ik(IkBenchArgs),
    /// Point cloud latency between processes: iceoryx2 against a Unix domain socket.
    Ipc(super::ipc::IpcBenchArgs),
}

/// Options of `cell bench ik`.
#[derive(Debug, Args)]
pub struct IkBenchArgs {
    /// Number of random reachable poses to solve.
    #[arg(long, default_value_t = 1000)]
    pub poses: usize,
    /// Seed of the random configurations.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Print JSON (always JSON; accepted for uniformity).
    #[arg(long)]
    pub json: bool,
}

/// Runs one benchmark.
pub fn run(config: &Path, which: BenchCommand) -> anyhow::Result<ExitCode> {
    match which {
        BenchCommand::Ik(args) => super::robot::bench_ik(config, args),
        BenchCommand::Ipc(args) => super::ipc::bench_ipc(args),
    }
}

/// Median of a sample (sorts it); NaN for an empty sample.
pub fn median(samples: &mut [f64]) -> f64 {
    percentile(samples, 0.5)
}

/// The `p`-quantile (0..=1, nearest rank) of a sample (sorts it); NaN when empty.
pub fn percentile(samples: &mut [f64], p: f64) -> f64 {
    if samples.is_empty() {
        return f64::NAN;
    }
    samples.sort_by(|a, b| a.total_cmp(b));
    let rank = ((samples.len() - 1) as f64 * p.clamp(0.0, 1.0)).round() as usize;
    samples[rank]
}
