//! `cell bench ...`: benchmarks that print one JSON document with medians.
//!
//! Speed is measured here, never asserted in tests. Each benchmark states its
//! workload, repeats it, and reports medians (and ratios to a baseline measured in the
//! same run where there is one).

pub use crate::stats::{median, percentile};
use clap::{Args, Subcommand};
use std::path::Path;
use std::process::ExitCode;

/// The benchmarks.
#[derive(Debug, Subcommand)]
pub enum BenchCommand {
    /// Inverse kinematics: median solve time and success rate over seeded random poses.
    Ik(IkBenchArgs),
    /// Hand–eye calibration: median solve time of each method on synthetic samples.
    Calib(CalibBenchArgs),
    /// Depth camera: median time to render a 640x480 frame of the table and a mug.
    Render(RenderBenchArgs),
    /// FRI: the arm driver against the robot simulator over loopback UDP; answer latency and missed cycles.
    Fri(super::fri::FriBenchArgs),
    /// CAN: hand driver round trips against the puck emulator, per bus backend.
    Can(super::can::CanBenchArgs),
    /// Grasp quality metric: epsilon (and volume) evaluations per second on 3-finger contact sets.
    QualityMetric(QualityMetricBenchArgs),
    /// Grasp simulation: auto-grasp + epsilon evaluations per second on a mug mesh.
    Quality(super::quality::QualityBenchArgs),
    /// Point cloud latency between processes: iceoryx2 against a Unix domain socket.
    Ipc(super::ipc::IpcBenchArgs),
    /// Grasp planning: median time for 7 models x 3 grasps with reachability, per kernel.
    Plan(super::plan::PlanBenchArgs),
    /// Kinect camera backend: conversion cost per 640x480 frame and the frame rate delivered from fakenect.
    Camera(super::camera::CameraBenchArgs),
    /// Registration: one partial mug view (~6k and ~28k points) against 11 models; per-stage medians.
    Register(super::perceive::RegisterBenchArgs),
    /// Trial picture: median time to render one logged trial's picture (both views,
    /// caption) and to encode it as PNG; the scene's assembly timed apart.
    Picture(super::trial::PictureBenchArgs),
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
    /// Print JSON (the benchmark always prints JSON; accepted for uniformity).
    #[arg(long)]
    pub json: bool,
}

/// Options of `cell bench calib`.
#[derive(Debug, Args)]
pub struct CalibBenchArgs {
    /// Number of synthetic samples per solve.
    #[arg(long, default_value_t = 30)]
    pub samples: usize,
    /// Solves per method (the median is reported).
    #[arg(long, default_value_t = 100)]
    pub repeats: usize,
    /// Seed of the synthetic samples.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Simulated collections (plan + capture of --samples poses) timed; 0 skips them.
    #[arg(long, default_value_t = 3)]
    pub collect_repeats: usize,
    /// Print JSON (always JSON; accepted for uniformity).
    #[arg(long)]
    pub json: bool,
}

/// Options of `cell bench render`.
#[derive(Debug, Args)]
pub struct RenderBenchArgs {
    /// Number of timed renders.
    #[arg(long, default_value_t = 20)]
    pub repeats: usize,
    /// Seed of the mug model and the first frame's noise.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Print JSON (always JSON; accepted for uniformity).
    #[arg(long)]
    pub json: bool,
}

/// Options of `cell bench quality-metric`.
#[derive(Debug, Args)]
pub struct QualityMetricBenchArgs {
    /// Number of random contact sets per repeat.
    #[arg(long, default_value_t = 500)]
    pub sets: usize,
    /// Timed repeats over all sets (the median is reported).
    #[arg(long, default_value_t = 5)]
    pub repeats: usize,
    /// Seed of the random contact sets.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Print JSON (always JSON; accepted for uniformity).
    #[arg(long)]
    pub json: bool,
}

/// The system's 1, 5 and 15 minute load averages (`/proc/loadavg`), printed with a
/// benchmark so its figures can be read against how busy the machine was; None
/// where the file does not exist.
pub fn load_average() -> Option<[f64; 3]> {
    parse_load_average(&std::fs::read_to_string("/proc/loadavg").ok()?)
}

/// The three load averages at the start of a `/proc/loadavg` line.
fn parse_load_average(text: &str) -> Option<[f64; 3]> {
    let mut fields = text.split_whitespace().map(str::parse::<f64>);
    let mut next = || fields.next()?.ok();
    Some([next()?, next()?, next()?])
}

/// CPU time (ms) of the calling thread (`per_thread`) or of the whole process.
pub fn cpu_ms(per_thread: bool) -> f64 {
    crate::sys::cpu_time_ms(per_thread)
}

/// Runs one benchmark.
pub fn run(config: &Path, which: BenchCommand) -> anyhow::Result<ExitCode> {
    match which {
        BenchCommand::Ik(args) => super::robot::bench_ik(config, args),
        BenchCommand::Calib(args) => super::calibrate::bench_calib(config, args),
        BenchCommand::Render(args) => super::camera::bench_render(config, args),
        BenchCommand::Fri(args) => super::fri::bench_fri(config, args),
        BenchCommand::Can(args) => super::can::bench(args),
        BenchCommand::QualityMetric(args) => super::quality::bench_metric(args),
        BenchCommand::Quality(args) => super::quality::bench_grasp(config, args),
        BenchCommand::Ipc(args) => super::ipc::bench_ipc(args),
        BenchCommand::Plan(args) => super::plan::bench(config, args),
        BenchCommand::Register(args) => super::perceive::bench(config, args),
        BenchCommand::Camera(args) => super::camera::bench_camera(config, args),
        BenchCommand::Picture(args) => super::trial::bench_picture(config, args),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn load_average_line_is_parsed_or_refused() {
        assert_eq!(
            parse_load_average("2.06 0.95 0.37 3/412 1234\n"),
            Some([2.06, 0.95, 0.37])
        );
        assert_eq!(parse_load_average("2.06 0.95"), None);
        assert_eq!(parse_load_average("high 0.95 0.37"), None);
    }
}
