//! `cell bench ipc`: point cloud latency between processes, iceoryx2 against a Unix socket.

use crate::cli::emit;
use crate::ipc::bench::{run_sender, BenchOptions, BenchSamples};
use crate::ipc::payloads::{MAX_CLOUD_HEIGHT, MAX_CLOUD_WIDTH};
use crate::stats::{median, percentile};
use anyhow::Context;
use clap::Args;
use serde::Serialize;
use std::process::ExitCode;
use std::time::Duration;

/// Latency ratio (socket / iceoryx2, medians) the issue asks for.
const GOAL_RATIO: f64 = 50.0;

/// Options of `cell bench ipc`.
#[derive(Debug, Args)]
pub struct IpcBenchArgs {
    /// Measured rounds; each sends one cloud per transport.
    #[arg(long, default_value_t = 200)]
    pub rounds: usize,
    /// Rounds before measuring (not reported).
    #[arg(long, default_value_t = 20)]
    pub warmup: usize,
    /// Points of each cloud the receiver reads (spread evenly, first and last included).
    #[arg(long, default_value_t = 16)]
    pub touch_points: usize,
    /// Seed of the random cloud.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Longest wait for the receiving process at any step (s).
    #[arg(long, default_value_t = 10.0)]
    pub timeout_s: f64,
    /// Print JSON.
    #[arg(long)]
    pub json: bool,
}

/// Summary of one transport's latencies (microseconds).
#[derive(Debug, Serialize)]
struct Latency {
    median_us: f64,
    p99_us: f64,
    min_us: f64,
    max_us: f64,
}

impl Latency {
    fn of(samples_ns: &[u64]) -> Latency {
        let mut us: Vec<f64> = samples_ns.iter().map(|&ns| ns as f64 / 1e3).collect();
        Latency {
            median_us: median(&mut us),
            p99_us: percentile(&mut us, 0.99),
            min_us: us.first().copied().unwrap_or(f64::NAN),
            max_us: us.last().copied().unwrap_or(f64::NAN),
        }
    }
}

#[derive(Debug, Serialize)]
struct Ratio {
    median: f64,
    p99: f64,
}

impl Ratio {
    fn of(socket: &Latency, other: &Latency) -> Ratio {
        Ratio {
            median: socket.median_us / other.median_us,
            p99: socket.p99_us / other.p99_us,
        }
    }
}

#[derive(Debug, Serialize)]
struct Workload {
    width: u32,
    height: u32,
    points: usize,
    bytes_per_message: usize,
    rounds: usize,
    warmup: usize,
    touch_points: usize,
    seed: u64,
}

#[derive(Debug, Serialize)]
struct Goal {
    ratio_socket_over_iceoryx2_median_at_least: f64,
    /// With the receiver blocking on the wake-up event, as the cell's stages do.
    met: bool,
    /// With the receiver polling (the transport alone).
    met_by_polling_receiver: bool,
}

#[derive(Debug, Serialize)]
struct Report {
    benchmark: &'static str,
    workload: Workload,
    method: &'static str,
    receiver_reads: String,
    iceoryx2_zero_copy: Latency,
    iceoryx2_copy_in: Latency,
    unix_socket: Latency,
    iceoryx2_zero_copy_polling: Latency,
    ratio_socket_over_iceoryx2_zero_copy: Ratio,
    ratio_socket_over_iceoryx2_copy_in: Ratio,
    ratio_socket_over_iceoryx2_zero_copy_polling: Ratio,
    goal: Goal,
}

const METHOD: &str = "one-way latency between two processes: the sender stamps CLOCK_MONOTONIC \
into the message just before handing it over (iceoryx2_zero_copy: after the cloud was written \
into the loaned shared-memory sample; iceoryx2_copy_in: before copying it there; unix_socket: \
before one write_all of the same bytes on a SOCK_STREAM socket), the receiver subtracts its own \
stamp after reading. The receiver blocks (iceoryx2 event listener; blocking read) except for \
iceoryx2_zero_copy_polling, where it spins on try_receive. One message in flight; transports \
interleaved round by round.";

fn report(args: &IpcBenchArgs, samples: &BenchSamples) -> Report {
    let zero_copy = Latency::of(&samples.iceoryx2_zero_copy_ns);
    let copy_in = Latency::of(&samples.iceoryx2_copy_in_ns);
    let socket = Latency::of(&samples.unix_socket_ns);
    let ratio_zero_copy = Ratio::of(&socket, &zero_copy);
    let ratio_copy_in = Ratio::of(&socket, &copy_in);
    let polling = Latency::of(&samples.iceoryx2_zero_copy_polling_ns);
    let ratio_polling = Ratio::of(&socket, &polling);
    Report {
        benchmark: "ipc",
        workload: Workload {
            width: MAX_CLOUD_WIDTH,
            height: MAX_CLOUD_HEIGHT,
            points: samples.points,
            bytes_per_message: samples.bytes,
            rounds: args.rounds,
            warmup: args.warmup,
            touch_points: args.touch_points,
            seed: args.seed,
        },
        method: METHOD,
        receiver_reads: format!(
            "the header and {} points spread over the cloud (first and last included), summed \
             and checked by the sender; the socket receiver has in addition copied every byte \
             into its buffer, which a stream socket requires",
            args.touch_points.min(samples.points)
        ),
        goal: Goal {
            ratio_socket_over_iceoryx2_median_at_least: GOAL_RATIO,
            met: ratio_zero_copy.median >= GOAL_RATIO,
            met_by_polling_receiver: ratio_polling.median >= GOAL_RATIO,
        },
        iceoryx2_zero_copy: zero_copy,
        iceoryx2_copy_in: copy_in,
        unix_socket: socket,
        iceoryx2_zero_copy_polling: polling,
        ratio_socket_over_iceoryx2_zero_copy: ratio_zero_copy,
        ratio_socket_over_iceoryx2_copy_in: ratio_copy_in,
        ratio_socket_over_iceoryx2_zero_copy_polling: ratio_polling,
    }
}

/// Runs `cell bench ipc`.
pub fn bench_ipc(args: IpcBenchArgs) -> anyhow::Result<ExitCode> {
    anyhow::ensure!(args.rounds > 0, "--rounds must be at least 1");
    anyhow::ensure!(
        args.timeout_s.is_finite() && args.timeout_s > 0.0,
        "--timeout-s must be a positive number of seconds, got {}",
        args.timeout_s
    );
    let options = BenchOptions {
        rounds: args.rounds,
        warmup: args.warmup,
        touch_points: args.touch_points.max(1),
        seed: args.seed,
        timeout: Duration::from_secs_f64(args.timeout_s),
    };
    let exe = std::env::current_exe().context("locating the cell executable")?;
    let progress = indicatif::ProgressBar::new((args.rounds + args.warmup) as u64);
    progress.set_message("ipc rounds");
    let samples = run_sender(&exe, &options, &mut || progress.inc(1)).context("cell bench ipc")?;
    progress.finish_and_clear();
    let report = report(&args, &samples);
    emit(args.json, &report, |r| {
        let line = |name: &str, l: &Latency| {
            format!(
                "{name:<20} median {:>9.1} us  p99 {:>9.1} us\n",
                l.median_us, l.p99_us
            )
        };
        let met = |m: bool| if m { "met" } else { "not met" };
        format!(
            "{} points ({} bytes), {} rounds, one-way latency\n{}{}{}{}\
             socket / iceoryx2 zero-copy:   {:.0}x median, {:.0}x p99 (goal {GOAL_RATIO}x: {})\n\
             socket / iceoryx2 polling:     {:.0}x median, {:.0}x p99 (goal {GOAL_RATIO}x: {})\n\
             socket / iceoryx2 copy-in:     {:.1}x median, {:.1}x p99\n",
            r.workload.points,
            r.workload.bytes_per_message,
            r.workload.rounds,
            line("iceoryx2 zero-copy", &r.iceoryx2_zero_copy),
            line("iceoryx2 polling", &r.iceoryx2_zero_copy_polling),
            line("iceoryx2 copy-in", &r.iceoryx2_copy_in),
            line("unix socket", &r.unix_socket),
            r.ratio_socket_over_iceoryx2_zero_copy.median,
            r.ratio_socket_over_iceoryx2_zero_copy.p99,
            met(r.goal.met),
            r.ratio_socket_over_iceoryx2_zero_copy_polling.median,
            r.ratio_socket_over_iceoryx2_zero_copy_polling.p99,
            met(r.goal.met_by_polling_receiver),
            r.ratio_socket_over_iceoryx2_copy_in.median,
            r.ratio_socket_over_iceoryx2_copy_in.p99,
        )
    })?;
    Ok(ExitCode::SUCCESS)
}
