//! `cell bench camera`: the Kinect backend's conversion cost and the fakenect frame rate.

use crate::cli::camera::sim_frames;
use crate::config::CellConfig;
use crate::geometry::Pose;
use crate::hw::kinect::convert::{depth_to_cloud, DepthEncoding};
use crate::hw::kinect::fakenect::RawFrame;
use crate::mesh::procedural::{generate, Category};
use crate::sim::scene::{Scene, TableBox};
use crate::stats::{median, percentile};
use anyhow::Context;
use clap::Args;
use serde::Serialize;
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::time::Instant;

/// Options of `cell bench camera`.
#[derive(Debug, Args)]
pub struct CameraBenchArgs {
    /// Timed conversions of one 640x480 frame (the median is reported).
    #[arg(long, default_value_t = 50)]
    pub repeats: usize,
    /// Frames of the fakenect recording the frame rate is measured on.
    #[arg(long, default_value_t = 60)]
    pub frames: usize,
    /// Seed of the mug model and the frame's noise.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Print JSON (always JSON; accepted for uniformity).
    #[arg(long)]
    pub json: bool,
}

/// What `cell bench camera` reports.
#[derive(Debug, Serialize)]
struct CameraBench {
    workload: String,
    width_px: u32,
    height_px: u32,
    repeats: usize,
    /// Median time (ms) to convert one raw 11-bit frame to an organised cloud.
    conversion_ms_median: f64,
    conversion_ms_p90: f64,
    /// Time (ms) to build the raw-to-metres table (once per device).
    table_build_ms: f64,
    conversion_goal_ms: f64,
    meets_conversion_goal: bool,
    /// The backend against fakenect: snapshots (grab + conversion) per second,
    /// each taking one frame of a recording made at `recorded_fps`.
    fakenect: Option<FakenectRate>,
    /// Why there is no fakenect figure (no `kinect` feature, no fakenect).
    fakenect_skipped: Option<String>,
    load_average: Option<[f64; 3]>,
}

/// The frame rate delivered from fakenect.
#[derive(Debug, Serialize)]
struct FakenectRate {
    library: PathBuf,
    frames: usize,
    recorded_fps: f64,
    delivered_fps: f64,
    /// Median time of one grab (wait for the frame, copy, accelerometer) (ms).
    grab_ms_median: f64,
}

/// Where Debian's fakenect library is.
#[cfg(feature = "kinect")]
pub const FAKENECT_LIBRARY: &str = "/usr/lib/x86_64-linux-gnu/fakenect/libfreenect.so.0.5";

/// Conversion cost goal of `cell bench camera` (ms per 640x480 frame).
const CONVERSION_GOAL_MS: f64 = 5.0;

/// Runs `cell bench camera`.
pub fn bench_camera(config_path: &Path, args: CameraBenchArgs) -> anyhow::Result<ExitCode> {
    anyhow::ensure!(args.repeats > 0, "--repeats must be at least 1");
    anyhow::ensure!(args.frames >= 2, "--frames must be at least 2");
    let config = CellConfig::load(config_path)?;
    let table = TableBox::from(&config.table);
    let (mug, _) = generate(Category::Mug, args.seed);
    let mut scene = Scene::new(Some(table));
    let base_from_mug = Pose::new(
        nalgebra::Vector3::new(table.center_xy_m[0], table.center_xy_m[1], table.height_m),
        nalgebra::Vector3::z() * 1.2,
    );
    scene
        .add("mug", mug, base_from_mug)
        .context("bench scene")?;
    let dir = crate::fsio::TempDir::new("bench-camera")?;
    let frame = sim_frames(&config, &scene, &config.base_from_camera(), 1, args.seed).remove(0);
    let (w, h) = (frame.width, frame.height);
    let started = Instant::now();
    let table_m = frame.registration.depth_table_m();
    let table_build_ms = started.elapsed().as_secs_f64() * 1e3;
    let encoding = DepthEncoding::Disparity11 { table_m };
    let k = frame.registration.intrinsics(w, h);
    let range = [
        config.camera.min_range_m as f32,
        config.camera.max_range_m as f32,
    ];
    let mut times = Vec::with_capacity(args.repeats);
    let mut valid = 0;
    for _ in 0..args.repeats {
        let started = Instant::now();
        let cloud = depth_to_cloud(&frame.depth_raw, w, &encoding, &k, range);
        times.push(started.elapsed().as_secs_f64() * 1e3);
        valid = std::hint::black_box(&cloud)
            .points
            .iter()
            .filter(|p| p.z.is_finite())
            .count();
    }
    let conversion_ms_median = median(&mut times);
    let (fakenect, fakenect_skipped) = match fakenect_rate(&frame, &dir, args.frames, range) {
        Ok(rate) => (Some(rate), None),
        Err(why) => (None, Some(why.to_string())),
    };
    let report = CameraBench {
        workload: format!(
            "one {w}x{h} raw 11-bit frame of a mug on the table ({valid} valid points) converted to an organised cloud"
        ),
        width_px: w,
        height_px: h,
        repeats: args.repeats,
        conversion_ms_median,
        conversion_ms_p90: percentile(&mut times, 0.9),
        table_build_ms,
        conversion_goal_ms: CONVERSION_GOAL_MS,
        meets_conversion_goal: conversion_ms_median < CONVERSION_GOAL_MS,
        fakenect,
        fakenect_skipped,
        load_average: super::load_average(),
    };
    println!("{}", serde_json::to_string_pretty(&report)?);
    Ok(ExitCode::SUCCESS)
}

/// Why there is no fakenect figure.
#[derive(Debug, thiserror::Error)]
enum FakenectSkipped {
    /// fakenect is not installed.
    #[cfg(feature = "kinect")]
    #[error("{}: missing (apt-get install libfreenect-dev)", library.display())]
    Missing { library: PathBuf },
    /// The recording or the backend failed.
    #[cfg(feature = "kinect")]
    #[error(transparent)]
    Kinect(#[from] crate::hw::kinect::KinectError),
    /// The backend is not built.
    #[cfg(not(feature = "kinect"))]
    #[error(
        "built without the kinect feature (cargo build --release --features kinect --bin cell)"
    )]
    NoKinectFeature,
}

#[cfg(feature = "kinect")]
fn fakenect_rate(
    frame: &RawFrame,
    dir: &Path,
    frames: usize,
    range: [f32; 2],
) -> Result<FakenectRate, FakenectSkipped> {
    use crate::hw::kinect::device::{Kinect, KinectOptions};
    let library = PathBuf::from(FAKENECT_LIBRARY);
    if !library.exists() {
        return Err(FakenectSkipped::Missing { library });
    }
    let recording = dir.join("recording");
    frame.write_recording(&recording, frames)?;
    // fakenect reads FAKENECT_PATH when it first plays; nothing else in this
    // process reads the environment concurrently.
    std::env::set_var("FAKENECT_PATH", &recording);
    std::env::set_var("FAKENECT_LOOP", "0");
    let mut kinect = Kinect::open(KinectOptions {
        index: 0,
        rgb: true,
        frame_timeout_s: 2.0,
        settle_frames: 0,
        library: Some(library.clone()),
    })?;
    // The first grab starts playback; time the rest.
    kinect.grab()?;
    let started = Instant::now();
    let mut grabs = Vec::with_capacity(frames);
    for _ in 1..frames {
        let t = Instant::now();
        let f = kinect.grab()?;
        std::hint::black_box(kinect.to_cloud(&f, range));
        grabs.push(t.elapsed().as_secs_f64() * 1e3);
    }
    let elapsed = started.elapsed().as_secs_f64();
    Ok(FakenectRate {
        library,
        frames,
        recorded_fps: 30.0,
        delivered_fps: (frames - 1) as f64 / elapsed,
        grab_ms_median: median(&mut grabs),
    })
}

#[cfg(not(feature = "kinect"))]
fn fakenect_rate(
    _frame: &RawFrame,
    _dir: &Path,
    _frames: usize,
    _range: [f32; 2],
) -> Result<FakenectRate, FakenectSkipped> {
    Err(FakenectSkipped::NoKinectFeature)
}
