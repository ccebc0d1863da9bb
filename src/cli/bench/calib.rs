//! `cell bench calib`: hand–eye solvers on synthetic samples and simulated collections.

use crate::calib::collect::{
    plan_poses, run_collection, CameraPrior, CollectOptions, PlannerCell, TargetRig,
};
use crate::calib::sim_rig::{simulated_rig, SimTruth};
use crate::calib::synthetic::{point_samples, pose_samples, Noise, SyntheticScene};
use crate::calib::{
    daniilidis, fit_target, kabsch, park_martin, point_solver, refine, solve, tsai_lenz, HandEye,
    Sample, SolveOptions, Weights,
};
use crate::config::CellConfig;
use crate::robot::Robot;
use crate::sim::camera::Intrinsics;
use crate::stats::median;
use anyhow::Context;
use clap::Args;
use nalgebra::Point3;
use serde::Serialize;
use std::path::Path;
use std::process::ExitCode;
use std::sync::Arc;
use std::time::Instant;

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

/// One benchmarked solver.
#[derive(Debug, Serialize)]
struct BenchRow {
    method: &'static str,
    median_us: f64,
    ratio_to_tsai: f64,
}

/// What `cell bench calib` prints.
#[derive(Debug, Serialize)]
struct BenchReport {
    benchmark: &'static str,
    workload: String,
    samples: usize,
    repeats: usize,
    seed: u64,
    baseline: &'static str,
    results: Vec<BenchRow>,
    #[serde(skip_serializing_if = "Option::is_none")]
    collect: Option<CollectBench>,
}

/// The simulated collection's timing in `cell bench calib`.
#[derive(Debug, Serialize)]
struct CollectBench {
    workload: String,
    repeats: usize,
    plan_ms_median: f64,
    capture_ms_per_pose_median: f64,
    render_ms_median: f64,
    capture_ratio_to_render: f64,
    usable_samples_min: usize,
}

/// Times `repeats` simulated collections of `poses` poses (seeds `seed..`): the
/// planning, the capture with sphere fit per pose, and a bare render of the same
/// scene as the baseline.
fn bench_collect(
    config_path: &Path,
    poses: usize,
    repeats: usize,
    seed: u64,
) -> anyhow::Result<CollectBench> {
    let config = CellConfig::load(config_path)?;
    let robot = Arc::new(Robot::load(&config)?);
    let rig = TargetRig::standard();
    let prior = CameraPrior {
        intrinsics: Intrinsics::from(&config.camera),
        base_from_camera: config.base_from_camera(),
    };
    let cell = PlannerCell {
        robot: &robot,
        flange_link: &config.robot.flange_link,
        camera: &prior,
        rig: &rig,
        table: &config.table,
    };
    let truth = SimTruth::exact(prior.base_from_camera, rig);
    let (mut plan_ms, mut capture_ms, mut render_ms) = (Vec::new(), Vec::new(), Vec::new());
    let mut usable_min = usize::MAX;
    let bar = indicatif::ProgressBar::new(repeats as u64);
    for r in 0..repeats as u64 {
        let options = CollectOptions::new(poses, rig.radius_m, seed + r);
        let (mut arm, mut camera) = simulated_rig(
            &config,
            Arc::clone(&robot),
            &truth,
            options.hand,
            options.home,
            seed + r,
        )?;
        let start = Instant::now();
        let plan = plan_poses(&cell, &options.home, &options, &mut |_| {})?;
        plan_ms.push(start.elapsed().as_secs_f64() * 1e3);
        let start = Instant::now();
        let collection = run_collection(
            &plan,
            &mut arm,
            &mut camera,
            &prior,
            &rig,
            &options,
            &mut |_| {},
        )?;
        capture_ms.push(start.elapsed().as_secs_f64() * 1e3 / plan.poses.len().max(1) as f64);
        usable_min = usable_min.min(collection.samples.len());
        let start = Instant::now();
        camera.frame();
        render_ms.push(start.elapsed().as_secs_f64() * 1e3);
        bar.inc(1);
    }
    bar.finish_and_clear();
    let capture = median(&mut capture_ms);
    let render = median(&mut render_ms);
    Ok(CollectBench {
        workload: format!(
            "simulated collection of {poses} poses (sphere on the hand, Kinect noise, {}x{} px), seeds {seed}..{}; plan = candidate draw + IK + checks + greedy selection; capture = move + render + sphere fit per pose; baseline: one render of the same scene",
            config.camera.width_px,
            config.camera.height_px,
            seed + repeats as u64 - 1
        ),
        repeats,
        plan_ms_median: median(&mut plan_ms),
        capture_ms_per_pose_median: capture,
        render_ms_median: render,
        capture_ratio_to_render: capture / render,
        usable_samples_min: usable_min,
    })
}

/// Runs `cell bench calib`: median solve time of each method on synthetic samples,
/// and the timing of simulated collections.
pub fn bench_calib(config: &Path, args: CalibBenchArgs) -> anyhow::Result<ExitCode> {
    anyhow::ensure!(
        args.samples >= 5,
        "--samples {}: need at least 5",
        args.samples
    );
    anyhow::ensure!(args.repeats >= 1, "--repeats must be at least 1");
    let scene = SyntheticScene::nominal();
    let noise = Noise::typical();
    let poses = pose_samples(&scene, args.samples, &noise, args.seed);
    let points = point_samples(&scene, args.samples, &noise, args.seed);
    let pose_set: Vec<Sample> = poses.iter().copied().map(Sample::Pose).collect();
    let point_set: Vec<Sample> = points.iter().copied().map(Sample::Point).collect();
    let weights = Weights::default();
    let y = scene.flange_from_target.translation.vector;
    let tsai_start = {
        let x = tsai_lenz(&poses)?;
        HandEye {
            base_from_camera: x,
            flange_from_target: fit_target(&pose_set, &x, None),
        }
    };
    let camera: Vec<Point3<f64>> = points.iter().map(|s| s.target_point_camera_m).collect();
    let base: Vec<Point3<f64>> = points
        .iter()
        .map(|s| s.base_from_flange * Point3::from(y))
        .collect();
    type Job<'a> = Box<dyn Fn() -> anyhow::Result<()> + 'a>;
    let jobs: Vec<(&'static str, Job)> = vec![
        (
            "tsai",
            Box::new(|| tsai_lenz(&poses).map(drop).map_err(Into::into)),
        ),
        (
            "park",
            Box::new(|| park_martin(&poses).map(drop).map_err(Into::into)),
        ),
        (
            "daniilidis",
            Box::new(|| daniilidis(&poses).map(drop).map_err(Into::into)),
        ),
        (
            "refine (from tsai, pose samples)",
            Box::new(|| {
                refine(&pose_set, &tsai_start, None, &weights);
                Ok(())
            }),
        ),
        (
            "points (unknown target position, point samples)",
            Box::new(|| {
                point_solver(&points, None, &weights)
                    .map(drop)
                    .map_err(Into::into)
            }),
        ),
        (
            "kabsch (known target position)",
            Box::new(|| kabsch(&camera, &base).map(drop).map_err(Into::into)),
        ),
        (
            "solve all + refine, pose samples (cell calibrate solve)",
            Box::new(|| {
                solve(&pose_set, &SolveOptions::default())
                    .map(drop)
                    .map_err(Into::into)
            }),
        ),
        (
            "solve all + refine, point samples (cell calibrate solve)",
            Box::new(|| {
                solve(&point_set, &SolveOptions::default())
                    .map(drop)
                    .map_err(Into::into)
            }),
        ),
    ];
    let bar = indicatif::ProgressBar::new((jobs.len() * args.repeats) as u64);
    let mut medians = Vec::new();
    for (name, job) in &jobs {
        job().with_context(|| format!("bench calib: {name} failed"))?;
        let mut times_us = Vec::with_capacity(args.repeats);
        for _ in 0..args.repeats {
            let start = Instant::now();
            job()?;
            times_us.push(start.elapsed().as_secs_f64() * 1e6);
            bar.inc(1);
        }
        medians.push((*name, median(&mut times_us)));
    }
    bar.finish_and_clear();
    let tsai_us = medians[0].1;
    let collect = if args.collect_repeats > 0 {
        Some(bench_collect(
            config,
            args.samples,
            args.collect_repeats,
            args.seed,
        )?)
    } else {
        None
    };
    let report = BenchReport {
        collect,
        benchmark: "calib",
        workload: format!(
            "{} synthetic samples (seed {}, noise {} mm / {}° per axis), each method solved {} times; median wall time",
            args.samples,
            args.seed,
            noise.translation_m * 1e3,
            noise.rotation_rad.to_degrees(),
            args.repeats
        ),
        samples: args.samples,
        repeats: args.repeats,
        seed: args.seed,
        baseline: "tsai",
        results: medians
            .into_iter()
            .map(|(method, median_us)| BenchRow {
                method,
                median_us: (median_us * 100.0).round() / 100.0,
                ratio_to_tsai: (median_us / tsai_us * 1000.0).round() / 1000.0,
            })
            .collect(),
    };
    crate::cli::emit(true, &report, |_| String::new())?;
    Ok(ExitCode::SUCCESS)
}
