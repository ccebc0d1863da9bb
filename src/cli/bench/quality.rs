//! `cell bench quality`: auto-grasp and epsilon evaluations on a mug mesh, and physics lifts.

use super::cpu_ms;
use crate::config::CellConfig;
use crate::quality::autograsp::{evaluate_grasp, AutoGraspOptions, GraspObject};
use crate::quality::QualityParams;
use crate::robot::hand::HandModel;
use crate::robot::HandPose;
use crate::sim::physics::{lift_test, LiftOutcome, LiftScene, PhysicsObject, PhysicsOptions};
use crate::stats::median;
use clap::Args;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::Serialize;
use std::path::Path;
use std::process::ExitCode;
use std::time::Instant;

/// Options of `cell bench quality`.
#[derive(Debug, Args)]
pub struct QualityBenchArgs {
    /// Grasp poses per repeat (around the mug's top, side and handle grasps).
    #[arg(long, default_value_t = 1500)]
    pub grasps: usize,
    /// Timed repeats over all poses (the median is reported).
    #[arg(long, default_value_t = 5)]
    pub repeats: usize,
    /// Seed of the mug and the pose perturbations.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Worker threads for the parallel run (0 = one per core).
    #[arg(long, default_value_t = 0)]
    pub threads: usize,
    /// Physics lift tests per repeat (the first poses of --grasps; 0 skips them).
    #[arg(long, default_value_t = 40)]
    pub lifts: usize,
    /// Print JSON (always JSON; accepted for uniformity).
    #[arg(long)]
    pub json: bool,
}

/// The physics part of `cell bench quality`: the observer's lift test.
#[derive(Debug, Serialize)]
struct LiftBench {
    workload: String,
    lifts: usize,
    /// Convex parts of the mug's decomposition.
    convex_parts: usize,
    /// Time of the decomposition, done once per mesh (s).
    decomposition_s: f64,
    success_fraction: f64,
    partial_fraction: f64,
    start_collision_fraction: f64,
    mean_steps: f64,
    /// Lift tests per second, parallel over all threads (the figure the goal is about).
    lift_tests_per_s: f64,
    lift_tests_per_s_one_thread: f64,
    /// CPU time of one lift test on one thread (ms, median over repeats): its cost
    /// whatever else the machine is doing.
    lift_cpu_ms_one_thread: f64,
    /// Lift tests per CPU-second of one thread times the threads of the parallel
    /// run: the rate the cores give when the machine is otherwise idle.
    lift_tests_per_s_cpu_bound: f64,
    goal_per_s: f64,
    meets_goal: bool,
}

/// The result of `cell bench quality`.
#[derive(Debug, Serialize)]
struct GraspBench {
    workload: String,
    seed: u64,
    mug_seed: u64,
    mug_triangles: usize,
    grasps: usize,
    repeats: usize,
    threads: usize,
    force_closure_fraction: f64,
    collision_at_start_fraction: f64,
    mean_contacts: f64,
    /// Auto-grasp + epsilon, parallel over all threads (the figure the goal is about).
    grasps_per_s: f64,
    /// Auto-grasp + epsilon on one thread: the baseline.
    grasps_per_s_one_thread: f64,
    parallel_speedup: f64,
    /// Auto-grasp alone on one thread.
    auto_grasp_per_s_one_thread: f64,
    /// Median time of one auto-grasp + epsilon on one thread (us).
    grasp_us_one_thread: f64,
    /// CPU time of one auto-grasp + epsilon on one thread (us, median over
    /// repeats): its cost whatever else the machine is doing.
    grasp_cpu_us_one_thread: f64,
    /// Evaluations per CPU-second of one thread times the threads of the
    /// parallel run: the rate the cores give when the machine is otherwise idle.
    grasps_per_s_cpu_bound: f64,
    goal_per_s: f64,
    meets_goal: bool,
    /// The physics lift tests (absent with --lifts 0).
    #[serde(skip_serializing_if = "Option::is_none")]
    physics: Option<LiftBench>,
    /// 1, 5 and 15 minute load averages at the end of the run.
    load_average: Option<[f64; 3]>,
}

/// Times the physics lift test at the first `count` of `poses` (object frame, table
/// at z = 0, the mug upright).
fn bench_lifts(
    hand: &HandModel,
    mesh: &crate::mesh::TriMesh,
    poses: &[(crate::geometry::Pose, HandPose)],
    count: usize,
    repeats: usize,
    pool: &rayon::ThreadPool,
) -> anyhow::Result<LiftBench> {
    use rayon::prelude::*;
    let options = PhysicsOptions::default();
    let start = Instant::now();
    let body = PhysicsObject::new(mesh, Path::new("<bench mug>"), &options)?;
    let decomposition_s = start.elapsed().as_secs_f64();
    let poses = &poses[..count.min(poses.len())];
    let lift = |(pose, preshape): &(crate::geometry::Pose, HandPose)| {
        let scene = LiftScene {
            base_from_object: crate::geometry::Pose::identity(),
            base_from_palm: *pose,
            preshape: *preshape,
            table_height_m: Some(0.0),
        };
        lift_test(hand, &body, &scene, &options)
    };
    let outcomes: Vec<LiftOutcome> =
        pool.install(|| poses.par_iter().map(lift).collect::<Result<_, _>>())?;
    let n = poses.len() as f64;
    let share =
        |f: &dyn Fn(&LiftOutcome) -> bool| outcomes.iter().filter(|o| f(o)).count() as f64 / n;
    let (mut parallel, mut single, mut cpu) = (Vec::new(), Vec::new(), Vec::new());
    for _ in 0..repeats {
        let start = Instant::now();
        let steps: usize = pool.install(|| {
            poses
                .par_iter()
                .map(|p| lift(p).map_or(0, |o| o.steps))
                .sum()
        });
        std::hint::black_box(steps);
        parallel.push(n / start.elapsed().as_secs_f64());
        let (start, cpu_start) = (Instant::now(), cpu_ms(true));
        let steps: usize = poses.iter().map(|p| lift(p).map_or(0, |o| o.steps)).sum();
        std::hint::black_box(steps);
        single.push(n / start.elapsed().as_secs_f64());
        cpu.push((cpu_ms(true) - cpu_start) / n);
    }
    let lift_tests_per_s = median(&mut parallel);
    let lift_cpu_ms = median(&mut cpu);
    Ok(LiftBench {
        workload: format!(
            "physics lift test (rapier3d, {:.0} Hz step, {} solver iterations): close, lift {} m, \
             hold {} s, at the first poses of the auto-grasp figures on the same mug",
            1.0 / options.step_s,
            options.solver_iterations,
            options.lift_m,
            options.hold_s
        ),
        lifts: poses.len(),
        convex_parts: body.parts(),
        decomposition_s,
        success_fraction: share(&|o| o.grade == crate::trial::Grade::Success),
        partial_fraction: share(&|o| o.grade == crate::trial::Grade::Partial),
        start_collision_fraction: share(&|o| o.start_collision.is_some()),
        mean_steps: outcomes.iter().map(|o| o.steps).sum::<usize>() as f64 / n,
        lift_tests_per_s,
        lift_tests_per_s_one_thread: median(&mut single),
        lift_cpu_ms_one_thread: lift_cpu_ms,
        lift_tests_per_s_cpu_bound: pool.current_num_threads() as f64 * 1e3 / lift_cpu_ms,
        goal_per_s: 20.0,
        meets_goal: lift_tests_per_s >= 20.0,
    })
}

/// Runs `cell bench quality`.
pub fn bench_grasp(config: &Path, args: QualityBenchArgs) -> anyhow::Result<ExitCode> {
    use crate::category::suggest::{standoff_m, templates};
    use crate::mesh::procedural::{generate, instance_seed, Category, Params};
    use crate::quality::autograsp::close_hand;
    use rayon::prelude::*;
    anyhow::ensure!(
        args.grasps > 0 && args.repeats > 0,
        "--grasps and --repeats must be > 0"
    );
    let hand = HandModel::load(&CellConfig::load(config)?)?;
    // The first mug of the seed's set that has a handle.
    let (mug_seed, mesh, params) = (0..)
        .map(|i| {
            let s = instance_seed(args.seed, i);
            let (mesh, params) = generate(Category::Mug, s);
            (s, mesh, params)
        })
        .find(|(_, _, p)| matches!(p, Params::Mug(m) if m.handle.is_some()))
        .expect("some mug has a handle");
    let object = GraspObject::new(&mesh, Path::new("<bench mug>"))?.with_table(Some(0.0));
    let options = AutoGraspOptions::default();
    let quality = QualityParams::default();
    let mut rng = ChaCha8Rng::seed_from_u64(args.seed);
    let templates = templates(&hand, &params, &mesh);
    let mut poses = Vec::with_capacity(args.grasps);
    let mut attempts = 0;
    while poses.len() < args.grasps {
        attempts += 1;
        anyhow::ensure!(attempts < 100 * args.grasps, "cannot place bench grasps");
        let t = &templates[rng.gen_range(0..templates.len())];
        let u = t.sample(&mut rng);
        if let Some(p) = t.place(&hand, &object, &u, standoff_m(&object)) {
            poses.push(p);
        }
    }
    let evaluate = |(pose, preshape): &(crate::geometry::Pose, HandPose)| {
        evaluate_grasp(&hand, &object, pose, preshape, &options, &quality, false)
    };
    let results: Vec<_> = poses.iter().map(evaluate).collect::<Result<_, _>>()?;
    let n = args.grasps as f64;
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(args.threads)
        .build()?;
    let threads = pool.current_num_threads();
    let progress = indicatif::ProgressBar::new(3 * args.repeats as u64);
    let (mut parallel, mut single, mut closing) = (Vec::new(), Vec::new(), Vec::new());
    let mut single_cpu = Vec::new();
    for _ in 0..args.repeats {
        let start = Instant::now();
        let sum: f64 = pool.install(|| {
            poses
                .par_iter()
                .map(|p| evaluate(p).map_or(0.0, |e| e.epsilon))
                .sum()
        });
        std::hint::black_box(sum);
        parallel.push(n / start.elapsed().as_secs_f64());
        progress.inc(1);
        let (start, cpu) = (Instant::now(), cpu_ms(true));
        let sum: f64 = poses
            .iter()
            .map(|p| evaluate(p).map_or(0.0, |e| e.epsilon))
            .sum();
        std::hint::black_box(sum);
        single.push(n / start.elapsed().as_secs_f64());
        single_cpu.push((cpu_ms(true) - cpu) * 1e3 / n);
        progress.inc(1);
        let start = Instant::now();
        let count: usize = poses
            .iter()
            .map(|(pose, preshape)| {
                close_hand(&hand, &object, pose, preshape, &options).map_or(0, |o| o.contacts.len())
            })
            .sum();
        std::hint::black_box(count);
        closing.push(n / start.elapsed().as_secs_f64());
        progress.inc(1);
    }
    progress.finish_and_clear();
    let physics = if args.lifts > 0 {
        Some(bench_lifts(
            &hand,
            &mesh,
            &poses,
            args.lifts,
            args.repeats,
            &pool,
        )?)
    } else {
        None
    };
    let grasps_per_s = median(&mut parallel);
    let one = median(&mut single);
    let grasp_cpu_us = median(&mut single_cpu);
    let report = GraspBench {
        workload: "auto-grasp (BH8-282, 0.04 rad steps, bisection to 1e-4 rad) + fast epsilon \
                   (mu 0.5, 8 edges) at seeded poses around a procedural mug's top, side and \
                   handle grasps (approached to contact, table at z = 0)"
            .into(),
        seed: args.seed,
        mug_seed,
        mug_triangles: mesh.triangles.len(),
        grasps: args.grasps,
        repeats: args.repeats,
        threads,
        force_closure_fraction: results.iter().filter(|e| e.force_closure).count() as f64 / n,
        collision_at_start_fraction: results
            .iter()
            .filter(|e| e.outcome.collision_at_start.is_some())
            .count() as f64
            / n,
        mean_contacts: results
            .iter()
            .map(|e| e.outcome.contacts.len())
            .sum::<usize>() as f64
            / n,
        grasps_per_s,
        grasps_per_s_one_thread: one,
        parallel_speedup: grasps_per_s / one,
        auto_grasp_per_s_one_thread: median(&mut closing),
        grasp_us_one_thread: 1e6 / one,
        grasp_cpu_us_one_thread: grasp_cpu_us,
        grasps_per_s_cpu_bound: threads as f64 * 1e6 / grasp_cpu_us,
        goal_per_s: 1000.0,
        meets_goal: grasps_per_s >= 1000.0,
        physics,
        load_average: super::load_average(),
    };
    crate::cli::emit(true, &report, |_| String::new())?;
    Ok(ExitCode::SUCCESS)
}
