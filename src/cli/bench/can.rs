//! `cell bench can`: request/reply round trips of the hand driver against the puck
//! emulator on each bus backend.

use crate::clock::SystemClock;
use crate::hw::can::{CanBus, Hub, UnixBus, VirtualBus};
use crate::hw::hand::puck::Property;
use crate::hw::hand::{Hand, HandTiming, Puck};
use crate::sim::puck::{HandEmulator, HandEmulatorConfig};
use clap::Args;
use indicatif::{ProgressBar, ProgressStyle};
use serde::Serialize;
use std::process::ExitCode;
use std::sync::Arc;
use std::time::{Duration, Instant};

/// Options of `cell bench can`.
#[derive(Debug, Args)]
pub struct CanBenchArgs {
    /// Round trips (get P from F1) measured per backend.
    #[arg(long, default_value_t = 2000)]
    pub round_trips: usize,
    /// Print JSON (always JSON; accepted for uniformity).
    #[arg(long)]
    pub json: bool,
}

/// Round-trip figures of one backend.
#[derive(Debug, Serialize)]
struct BackendFigures {
    backend: &'static str,
    round_trips: usize,
    median_us: f64,
    p99_us: f64,
    max_us: f64,
    /// Median relative to the in-process bus measured in the same run.
    median_ratio_to_in_process: f64,
}

/// The benchmark's JSON document.
#[derive(Debug, Serialize)]
struct CanBench {
    workload: String,
    backends: Vec<BackendFigures>,
}

/// Runs the benchmark and prints one JSON document.
pub fn bench(args: CanBenchArgs) -> anyhow::Result<ExitCode> {
    anyhow::ensure!(args.round_trips > 0, "--round-trips must be at least 1");
    let total = 2 * args.round_trips as u64;
    let progress = ProgressBar::new(total)
        .with_style(ProgressStyle::with_template("{msg} {bar:40} {pos}/{len}")?);
    let inproc = VirtualBus::new(&format!("bench-{}", std::process::id()));
    progress.set_message("in-process");
    let mut in_process = measure(
        Box::new(inproc.endpoint()),
        Box::new(inproc.endpoint()),
        args.round_trips,
        &progress,
    )?;
    let name = format!("bench-{}", std::process::id());
    // A hub of our own: dropping it removes its socket before the process exits.
    let hub = Hub::bind(&name)?;
    progress.set_message("cross-process");
    let mut cross_process = measure(
        Box::new(UnixBus::connect(&name)?),
        Box::new(UnixBus::connect(&name)?),
        args.round_trips,
        &progress,
    )?;
    drop(hub);
    progress.finish_and_clear();
    let base = crate::stats::median(&mut in_process);
    let figures = |backend, samples: &mut Vec<f64>| BackendFigures {
        backend,
        round_trips: samples.len(),
        median_us: crate::stats::median(samples),
        p99_us: crate::stats::percentile(samples, 0.99),
        max_us: crate::stats::percentile(samples, 1.0),
        median_ratio_to_in_process: crate::stats::median(samples) / base,
    };
    let report = CanBench {
        workload: format!(
            "{} gets of P from F1 (request, emulator thread, 6-byte reply) per backend",
            args.round_trips
        ),
        backends: vec![
            figures("in-process", &mut in_process),
            figures("cross-process (AF_UNIX hub)", &mut cross_process),
        ],
    };
    crate::cli::emit(true, &report, |_| String::new())?;
    Ok(ExitCode::SUCCESS)
}

/// Wakes an emulated hand on the bus and times `count` round trips (us).
fn measure(
    emulator_node: Box<dyn CanBus>,
    driver_node: Box<dyn CanBus>,
    count: usize,
    progress: &ProgressBar,
) -> anyhow::Result<Vec<f64>> {
    let clock = Arc::new(SystemClock::new());
    let config = HandEmulatorConfig {
        boot: Duration::from_millis(20),
        ..HandEmulatorConfig::default()
    };
    let emulator = HandEmulator::new(config, clock.clone())?.spawn(emulator_node);
    let timing = HandTiming {
        wake_settle: Duration::from_millis(50),
        ..HandTiming::default()
    };
    let mut hand = Hand::new(driver_node, clock, timing);
    hand.wake(Duration::from_secs(5))?;
    let mut samples = Vec::with_capacity(count);
    for _ in 0..count {
        let start = Instant::now();
        hand.get_property(Puck::F1, Property::P, Duration::from_secs(1))?;
        samples.push(start.elapsed().as_secs_f64() * 1e6);
        progress.inc(1);
    }
    drop(emulator);
    Ok(samples)
}
