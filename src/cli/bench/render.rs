//! `cell bench render`: the simulated depth camera over a table and a mug.

use super::{cpu_ms, load_average};
use crate::config::CellConfig;
use crate::geometry::Pose;
use crate::mesh::procedural::{generate, Category};
use crate::sim::camera::{DepthCamera, DepthFrame, Return, Surface};
use crate::sim::scene::{Scene, TableBox};
use crate::stats::{median, percentile};
use anyhow::Context;
use clap::Args;
use serde::Serialize;
use std::path::Path;
use std::process::ExitCode;
use std::time::Instant;

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

/// What `cell bench render` reports.
#[derive(Debug, Serialize)]
struct RenderBench {
    workload: String,
    width_px: u32,
    height_px: u32,
    threads: usize,
    repeats: usize,
    seed: u64,
    scene_build_ms: f64,
    /// Median time of one frame of the table and the mug on all threads (ms): the
    /// figure the goal is about.
    render_ms_median: f64,
    render_ms_p90: f64,
    /// CPU time of the process (all threads) per frame on all threads (ms):
    /// what a frame costs whatever else the machine is doing.
    render_cpu_ms_median: f64,
    /// The same frame on one thread (ms): the baseline of the parallel render.
    render_ms_median_one_thread: f64,
    /// CPU time of the one thread per frame (ms).
    render_cpu_ms_median_one_thread: f64,
    parallel_speedup: f64,
    /// The same frame with the mug ray cast through its BVH pixel by pixel
    /// instead of rasterised, on all threads (ms): the earlier method.
    ray_cast_ms_median: f64,
    ratio_to_ray_cast: f64,
    /// Fraction of pixels whose surface and status agree between the
    /// rasterised and the ray-cast frame.
    ray_cast_agreement: f64,
    table_only_ms_median: f64,
    ratio_to_table_only: f64,
    /// Minor page faults per frame on all threads (fresh output buffers).
    page_faults_per_frame: f64,
    valid_fraction: f64,
    object_hit_fraction: f64,
    object_valid_fraction: f64,
    /// Whether the frames rendered on one thread equal those on all threads.
    one_thread_frames_identical: bool,
    goal_ms: f64,
    meets_goal: bool,
    /// 1, 5 and 15 minute load averages at the end of the run.
    load_average: Option<[f64; 3]>,
}

/// Minor page faults of the process so far (0 if getrusage fails).
fn minor_page_faults() -> u64 {
    crate::sys::resource_usage().map_or(0, |u| u.minor_page_faults)
}

/// Whether two frames agree bit for bit (NaN depths compare by their bits).
fn frames_identical(a: &DepthFrame, b: &DepthFrame) -> bool {
    a.status == b.status
        && a.surface == b.surface
        && a.depth_m.len() == b.depth_m.len()
        && a.depth_m
            .iter()
            .zip(&b.depth_m)
            .all(|(x, y)| x.to_bits() == y.to_bits())
}

/// Frame time goal of `cell bench render` (ms): about the Kinect's frame period.
const RENDER_GOAL_MS: f64 = 30.0;

/// Runs `cell bench render`: the configured camera over a table and a mug.
pub fn bench_render(config_path: &Path, args: RenderBenchArgs) -> anyhow::Result<ExitCode> {
    anyhow::ensure!(args.repeats > 0, "--repeats must be at least 1");
    let config = CellConfig::load(config_path)?;
    let table = TableBox::from(&config.table);
    let start = Instant::now();
    let (mug, _) = generate(Category::Mug, args.seed);
    let mut scene = Scene::new(Some(table));
    // The mug at the table's centre, turned so its handle shows to the camera.
    let base_from_mug = Pose::new(
        nalgebra::Vector3::new(table.center_xy_m[0], table.center_xy_m[1], table.height_m),
        nalgebra::Vector3::z() * 1.2,
    );
    scene
        .add(&format!("mug seed {}", args.seed), mug, base_from_mug)
        .context("bench scene")?;
    let scene_build_ms = start.elapsed().as_secs_f64() * 1e3;
    let table_only = Scene::new(Some(table));
    let camera = DepthCamera::from_config(&config.camera, config.base_from_camera());

    // Wall time, CPU time (of this thread or the process) and the frame.
    let time = |scene: &Scene, seed: u64, per_thread: bool| {
        let (start, cpu) = (Instant::now(), cpu_ms(per_thread));
        let frame = camera.render(scene, seed);
        let cpu = cpu_ms(per_thread) - cpu;
        (start.elapsed().as_secs_f64() * 1e3, cpu, frame)
    };
    // Warm up the thread pool and caches.
    let (_, _, frame) = time(&scene, args.seed, false);
    let one_thread = rayon::ThreadPoolBuilder::new().num_threads(1).build()?;
    let mut with_mug = Vec::with_capacity(args.repeats);
    let mut with_mug_cpu = Vec::with_capacity(args.repeats);
    let mut baseline = Vec::with_capacity(args.repeats);
    let mut single = Vec::with_capacity(args.repeats);
    let mut single_cpu = Vec::with_capacity(args.repeats);
    let mut ray_cast = Vec::with_capacity(args.repeats);
    let mut faults = 0;
    let mut identical = true;
    let mut agreement = 1f64;
    let progress = indicatif::ProgressBar::new(args.repeats as u64);
    for k in 0..args.repeats as u64 {
        let seed = args.seed + k;
        let faults_before = minor_page_faults();
        let (ms, cpu, parallel_frame) = time(&scene, seed, false);
        faults += minor_page_faults() - faults_before;
        with_mug.push(ms);
        with_mug_cpu.push(cpu);
        baseline.push(time(&table_only, seed, false).0);
        // Timed on the pool's own thread, so its CPU clock is the render's.
        let (ms, cpu, single_frame) = one_thread.install(|| time(&scene, seed, true));
        single.push(ms);
        single_cpu.push(cpu);
        identical &= frames_identical(&parallel_frame, &single_frame);
        drop(single_frame);
        let start = Instant::now();
        let cast_frame = camera.render_ray_cast(&scene, seed);
        ray_cast.push(start.elapsed().as_secs_f64() * 1e3);
        let agree = parallel_frame
            .status
            .iter()
            .zip(&parallel_frame.surface)
            .zip(cast_frame.status.iter().zip(&cast_frame.surface))
            .filter(|(a, b)| a == b)
            .count();
        agreement = agreement.min(agree as f64 / parallel_frame.status.len() as f64);
        progress.inc(1);
    }
    progress.finish_and_clear();
    let pixels = frame.depth_m.len() as f64;
    let object = Surface::Object(0);
    let render_ms_median = median(&mut with_mug);
    let table_only_ms_median = median(&mut baseline);
    let render_ms_median_one_thread = median(&mut single);
    let ray_cast_ms_median = median(&mut ray_cast);
    let report = RenderBench {
        workload: format!(
            "{}x{} frame of the table and a procedural mug (seed {}) from the configured camera, Kinect v1 noise",
            config.camera.width_px, config.camera.height_px, args.seed
        ),
        width_px: config.camera.width_px,
        height_px: config.camera.height_px,
        threads: rayon::current_num_threads(),
        repeats: args.repeats,
        seed: args.seed,
        scene_build_ms,
        render_ms_median,
        render_ms_p90: percentile(&mut with_mug, 0.9),
        render_cpu_ms_median: median(&mut with_mug_cpu),
        render_ms_median_one_thread,
        render_cpu_ms_median_one_thread: median(&mut single_cpu),
        parallel_speedup: render_ms_median_one_thread / render_ms_median,
        ray_cast_ms_median,
        ratio_to_ray_cast: render_ms_median / ray_cast_ms_median,
        ray_cast_agreement: agreement,
        table_only_ms_median,
        ratio_to_table_only: render_ms_median / table_only_ms_median,
        page_faults_per_frame: faults as f64 / args.repeats as f64,
        valid_fraction: frame.valid_fraction(),
        object_hit_fraction: frame.count(|_, s| s == object) as f64 / pixels,
        object_valid_fraction: frame.count(|r, s| s == object && r == Return::Valid) as f64 / pixels,
        one_thread_frames_identical: identical,
        goal_ms: RENDER_GOAL_MS,
        meets_goal: render_ms_median < RENDER_GOAL_MS,
        load_average: load_average(),
    };
    crate::cli::emit(true, &report, |_| String::new())?;
    Ok(ExitCode::SUCCESS)
}
