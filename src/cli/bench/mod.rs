//! `cell bench ...`: benchmarks that print one JSON document with medians.
//!
//! Speed is measured here, never asserted in tests. Each benchmark states its
//! workload, repeats it, and reports medians (and ratios to a baseline measured in the
//! same run where there is one).

mod calib;
mod camera;
mod can;
mod fri;
mod ik;
mod ipc;
mod picture;
mod plan;
mod quality;
mod quality_metric;
mod register;
mod render;

use clap::Subcommand;
use std::path::Path;
use std::process::ExitCode;

/// The benchmarks.
#[derive(Debug, Subcommand)]
pub enum BenchCommand {
    /// Inverse kinematics: median solve time and success rate over seeded random poses.
    Ik(ik::IkBenchArgs),
    /// Hand–eye calibration: median solve time of each method on synthetic samples.
    Calib(calib::CalibBenchArgs),
    /// Depth camera: median time to render a 640x480 frame of the table and a mug.
    Render(render::RenderBenchArgs),
    /// FRI: the arm driver against the robot simulator over loopback UDP; answer latency and missed cycles.
    Fri(fri::FriBenchArgs),
    /// CAN: hand driver round trips against the puck emulator, per bus backend.
    Can(can::CanBenchArgs),
    /// Grasp quality metric: epsilon (and volume) evaluations per second on 3-finger contact sets.
    QualityMetric(quality_metric::QualityMetricBenchArgs),
    /// Grasp simulation: auto-grasp + epsilon evaluations per second on a mug mesh.
    Quality(quality::QualityBenchArgs),
    /// Point cloud latency between processes: iceoryx2 against a Unix domain socket.
    Ipc(ipc::IpcBenchArgs),
    /// Grasp planning: median time for 7 models x 3 grasps with reachability, per kernel.
    Plan(plan::PlanBenchArgs),
    /// Kinect camera backend: conversion cost per 640x480 frame and the frame rate delivered from fakenect.
    Camera(camera::CameraBenchArgs),
    /// Registration: one partial mug view (~6k and ~28k points) against 11 models; per-stage medians.
    Register(register::RegisterBenchArgs),
    /// Trial picture: median time to render one logged trial's picture (both views,
    /// caption) and to encode it as PNG; the scene's assembly timed apart.
    Picture(picture::PictureBenchArgs),
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
/// The 64-bit FNV-1a hash of `bytes` as 16 hex digits: a bench's fingerprint of
/// what it computed, equal before and after a change that must not change it.
pub fn digest(bytes: &[u8]) -> String {
    format!("{:016x}", crate::hash::fnv1a(bytes))
}

pub fn run(config: &Path, which: BenchCommand) -> anyhow::Result<ExitCode> {
    match which {
        BenchCommand::Ik(args) => ik::bench_ik(config, args),
        BenchCommand::Calib(args) => calib::bench_calib(config, args),
        BenchCommand::Render(args) => render::bench_render(config, args),
        BenchCommand::Fri(args) => fri::bench_fri(config, args),
        BenchCommand::Can(args) => can::bench(args),
        BenchCommand::QualityMetric(args) => quality_metric::bench_metric(args),
        BenchCommand::Quality(args) => quality::bench_grasp(config, args),
        BenchCommand::Ipc(args) => ipc::bench_ipc(args),
        BenchCommand::Plan(args) => plan::bench(config, args),
        BenchCommand::Register(args) => register::bench(config, args),
        BenchCommand::Camera(args) => camera::bench_camera(config, args),
        BenchCommand::Picture(args) => picture::bench_picture(config, args),
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
