//! `cell bench plan`: grasp planning time per kernel, with reachability.

use crate::cell::plan::{executable_joints, ExecutorReach};
use crate::cli::emit;
use crate::cli::plan::load_db;
use crate::config::CellConfig;
use crate::execute::{ExecutorConfig, SafetyCheck, SafetyLimits};
use crate::plan::category::example_grasps;
use crate::plan::refine::{refine_over_db, DbProblem, SimRefineOptions};
use crate::plan::synthetic::{synthetic_problem, SyntheticSpec};
use crate::plan::{plan, Kernel, PlanOptions, Reachability};
use crate::robot::hand::HandModel;
use crate::robot::Robot;
use crate::stats::{median, percentile};
use clap::Args;
use serde::Serialize;
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::sync::Arc;
use std::time::Instant;

/// Options of `cell bench plan`.
#[derive(Debug, Args)]
pub struct PlanBenchArgs {
    /// Models in each synthetic problem.
    #[arg(long, default_value_t = 7)]
    pub models: usize,
    /// Grasps of the task per model.
    #[arg(long, default_value_t = 3)]
    pub grasps_per_model: usize,
    /// Problems (each with its own seed) per kernel; medians over them.
    #[arg(long, default_value_t = 20)]
    pub repeats: usize,
    /// Problems with the object out of reach (the constrained path).
    #[arg(long, default_value_t = 5)]
    pub far_repeats: usize,
    /// Seed of the first problem (problem r uses seed + r).
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Problems of the Laplace / laplace-sim comparison on a category database
    /// (its models as the fits, at seeded placements).
    #[arg(long, default_value_t = 5)]
    pub sim_repeats: usize,
    /// The database of that comparison.
    #[arg(long, default_value = "db/mug")]
    pub sim_db: PathBuf,
    /// Its task.
    #[arg(long, default_value = "side")]
    pub sim_task: String,
    /// Print JSON (always JSON; accepted for uniformity).
    #[arg(long)]
    pub json: bool,
}

#[derive(Serialize)]
struct KernelBench {
    kernel: &'static str,
    /// Planning with reachability, starts in parallel.
    median_ms: f64,
    p90_ms: f64,
    /// The same, starts one after another.
    serial_median_ms: f64,
    /// CPU time of the serial runs (what they cost on an idle core).
    serial_median_cpu_ms: f64,
    /// Without reachability (the paper's simulation setting), in parallel.
    no_reach_median_ms: f64,
    /// CPU time per objective evaluation, from the serial runs without reachability.
    median_us_per_evaluation: f64,
    median_evaluations: f64,
    median_reach_checks: f64,
    reachable_rate: f64,
    unconstrained_optimum_unreachable_rate: f64,
    best_single_reachable_rate: f64,
}

#[derive(Serialize)]
struct PlanBench {
    models: usize,
    grasps_per_model: usize,
    starts: usize,
    repeats: usize,
    seed: u64,
    object_xy_m: [f64; 2],
    threads: usize,
    kernels: Vec<KernelBench>,
    far_object_xy_m: [f64; 2],
    far_repeats: usize,
    /// Laplace with the object at the far edge of the table: the unconstrained optimum
    /// is out of reach and the constrained search runs.
    far_median_ms: f64,
    /// CPU time of those runs (the constrained search is serial).
    far_median_cpu_ms: f64,
    far_reachable_rate: f64,
    far_unconstrained_unreachable_rate: f64,
    /// Laplace beside laplace-sim on a category database, in the same run.
    sim: SimBench,
}

/// Laplace and laplace-sim planned on the same problems.
#[derive(Serialize)]
struct SimBench {
    db: PathBuf,
    task: String,
    repeats: usize,
    /// Preparing the models' grasp objects, once per database (ms).
    grasp_objects_ms: f64,
    /// Plain Laplace (with reachability), ms.
    laplace_median_ms: f64,
    /// laplace-sim: Laplace plus the refinement, ms.
    laplace_sim_median_ms: f64,
    /// The refinement alone, ms.
    refine_median_ms: f64,
    /// laplace-sim on one thread (the baseline of the parallel search), ms.
    laplace_sim_one_thread_median_ms: f64,
    /// `laplace_sim_one_thread_median_ms / laplace_sim_median_ms`.
    laplace_sim_speedup: f64,
    /// The plans and refinements on one thread equal those in parallel (but for
    /// their count of reachability checks).
    same_on_one_thread: bool,
    /// Process CPU time of laplace-sim, all threads (ms): its cost whatever else
    /// the machine is doing.
    laplace_sim_median_cpu_ms: f64,
    /// Joint solutions the executor accepts for the laplace-sim grasp, from the
    /// cell's home configuration (`cell-plan`'s last step), ms.
    executable_median_ms: f64,
    /// Fit-weighted mean simulated epsilon before and after the refinement.
    median_start_mean_epsilon: f64,
    median_mean_epsilon: f64,
    median_refine_evaluations: f64,
    /// Digest of every planned grasp (Laplace, laplace-sim, and its executable
    /// joints) as JSON ([`super::digest`]).
    plans_digest: String,
}

/// Laplace and laplace-sim on `repeats` problems of the database at `dir`: every
/// model as a fit at a seeded placement near (0.6, 0), with a seeded fitting error.
fn sim_bench(
    cell: &CellConfig,
    robot: &Arc<Robot>,
    dir: &Path,
    task: &str,
    repeats: usize,
    seed: u64,
) -> anyhow::Result<SimBench> {
    use rand::{Rng, SeedableRng};
    let db = load_db(dir)?;
    let start = Instant::now();
    for i in 0..db.meshes.len() {
        db.grasp_object(i)?;
    }
    let grasp_objects_ms = start.elapsed().as_secs_f64() * 1e3;
    let hand = HandModel::load(cell)?;
    // As cell-plan plans a Laplace trial: the baseline is not repaired.
    let options = PlanOptions {
        weights: crate::plan::category::weights(&db),
        repair_best_single: false,
        ..PlanOptions::new(Kernel::LAPLACE_DEFAULT, cell)
    };
    let safety = SafetyCheck::new(Arc::clone(robot), SafetyLimits::from_cell(cell, robot));
    let motions = ExecutorConfig::from_cell(cell);
    let robot: &Robot = robot;
    // The executor's checks of the motions from the park position.
    let executor = ExecutorReach {
        robot,
        check: &safety,
        config: &motions,
        current: cell.robot.park_joints_rad,
    };
    let (mut plain, mut total, mut refine_ms) = (Vec::new(), Vec::new(), Vec::new());
    let (mut cpu_ms, mut executable_ms, mut planned) = (Vec::new(), Vec::new(), Vec::new());
    let (mut before, mut after, mut evals) = (Vec::new(), Vec::new(), Vec::new());
    let one_thread = rayon::ThreadPoolBuilder::new().num_threads(1).build()?;
    let (mut one_thread_ms, mut same_on_one_thread) = (Vec::new(), true);
    for r in 0..repeats {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed + r as u64);
        let fits: Vec<crate::plan::ModelFit> = db
            .file
            .models
            .iter()
            .map(|m| crate::plan::ModelFit {
                name: m.name.clone(),
                base_from_model: crate::geometry::pose_from_params(&[
                    0.6 + rng.gen_range(-0.005..0.005),
                    rng.gen_range(-0.005..0.005),
                    0.0,
                    0.0,
                    0.0,
                    rng.gen_range(-0.3..0.3),
                ]),
                eps_m2: rng.gen_range(5e-5..3e-4),
                sigma_m2: rng.gen_range(2e-5..1e-4),
            })
            .collect();
        let grasps = example_grasps(&db, &fits, task)?;
        // Laplace, then its refinement: (Laplace ms, refinement ms, plan, refined).
        let laplace_sim = || -> anyhow::Result<_> {
            let (t, out) = time_ms(|| {
                plan(
                    &fits,
                    &grasps,
                    task,
                    &options,
                    Some(robot as &dyn Reachability),
                )
            });
            let out = out?;
            let problem = DbProblem {
                db: &db,
                fits: &fits,
                grasps: &grasps,
                task,
                options: &options,
                hand: &hand,
                reach: Some(robot as &dyn Reachability),
                seen: None,
                table_height_m: Some(cell.table.height_m),
            };
            let (rt, refined) = time_ms(|| {
                refine_over_db(&problem, &out.plan.grasp, &SimRefineOptions::for_cell(cell))
            });
            Ok((t, rt, out, refined?))
        };
        let (t1, rt1, mut out1, refined1) = one_thread.install(laplace_sim)?;
        one_thread_ms.push(t1 + rt1);
        let cpu = super::cpu_ms(false);
        let (t, rt, out, refined) = laplace_sim()?;
        cpu_ms.push(super::cpu_ms(false) - cpu);
        // The parallel search checks reachability in batches (a few more checks).
        out1.plan.reach_checks = out.plan.reach_checks;
        same_on_one_thread &= out1 == out && refined1 == refined;
        plain.push(t);
        refine_ms.push(rt);
        total.push(t + rt);
        let mut grasp = refined.grasp.clone();
        let start = Instant::now();
        let executable = executable_joints(&executor, &mut grasp).is_ok();
        executable_ms.push(start.elapsed().as_secs_f64() * 1e3);
        planned.push((out.plan.grasp, grasp, executable));
        before.push(refined.start_mean_epsilon);
        after.push(refined.mean_epsilon);
        evals.push(refined.evaluations as f64);
    }
    Ok(SimBench {
        db: dir.to_path_buf(),
        task: task.to_string(),
        repeats,
        grasp_objects_ms,
        laplace_median_ms: median(&mut plain),
        laplace_sim_median_ms: median(&mut total),
        refine_median_ms: median(&mut refine_ms),
        laplace_sim_one_thread_median_ms: median(&mut one_thread_ms),
        laplace_sim_speedup: median(&mut one_thread_ms) / median(&mut total),
        same_on_one_thread,
        laplace_sim_median_cpu_ms: median(&mut cpu_ms),
        executable_median_ms: median(&mut executable_ms),
        median_start_mean_epsilon: median(&mut before),
        median_mean_epsilon: median(&mut after),
        median_refine_evaluations: median(&mut evals),
        plans_digest: super::digest(serde_json::to_string(&planned)?.as_bytes()),
    })
}

/// CPU time of the calling thread (ms): a serial run's cost whatever else the machine
/// is doing.
fn thread_cpu_ms() -> f64 {
    crate::sys::cpu_time_ms(true)
}

fn time_ms<T>(f: impl FnOnce() -> T) -> (f64, T) {
    let start = Instant::now();
    let out = f();
    (start.elapsed().as_secs_f64() * 1e3, out)
}

fn rate(flags: &[bool]) -> f64 {
    flags.iter().filter(|&&b| b).count() as f64 / flags.len().max(1) as f64
}

/// Runs `cell bench plan`: synthetic problems of `models` x `grasps_per_model` top
/// grasps with the object at (0.6, 0) on the table, planned with each kernel, with the
/// robot's reachability (in parallel and serially) and without; then the far object.
pub fn bench(config: &Path, args: PlanBenchArgs) -> anyhow::Result<ExitCode> {
    anyhow::ensure!(
        args.models > 0 && args.grasps_per_model > 0 && args.repeats > 0,
        "--models, --grasps-per-model and --repeats must be > 0"
    );
    let cell = CellConfig::load(config)?;
    let robot = Arc::new(Robot::load(&cell)?);
    let reach: Option<&dyn Reachability> = Some(robot.as_ref());
    let spec = |r: usize, object_xy_m: [f64; 2]| SyntheticSpec {
        models: args.models,
        grasps_per_model: args.grasps_per_model,
        object_xy_m,
        seed: args.seed + r as u64,
    };
    let near = [0.6, 0.0];
    let far = [0.98, 0.1];
    let mut kernels = Vec::new();
    for kernel in [
        Kernel::LAPLACE_DEFAULT,
        Kernel::GAUSSIAN_R_DEFAULT,
        Kernel::Gaussian,
    ] {
        let mut options = PlanOptions::new(kernel, &cell);
        let (mut ms, mut serial_ms, mut no_reach_ms, mut us_per_eval) =
            (Vec::new(), Vec::new(), Vec::new(), Vec::new());
        let mut serial_cpu_ms = Vec::new();
        let (mut evaluations, mut checks) = (Vec::new(), Vec::new());
        let (mut reachable, mut unc_unreachable, mut single_reachable) =
            (Vec::new(), Vec::new(), Vec::new());
        for r in 0..args.repeats {
            let (fits, grasps) = synthetic_problem(&spec(r, near));
            let run = |options: &PlanOptions, reach| {
                plan(&fits, &grasps, "top", options, reach).expect("synthetic problems are valid")
            };
            options.parallel = true;
            let (t, out) = time_ms(|| run(&options, reach));
            ms.push(t);
            evaluations.push(out.plan.evaluations as f64);
            checks.push(out.plan.reach_checks as f64);
            reachable.push(out.plan.grasp.reachable);
            unc_unreachable.push(out.plan.unconstrained_optimum.is_some());
            single_reachable.push(out.best_single.grasp.reachable);
            options.parallel = false;
            let cpu = thread_cpu_ms();
            serial_ms.push(time_ms(|| run(&options, reach)).0);
            serial_cpu_ms.push(thread_cpu_ms() - cpu);
            let cpu = thread_cpu_ms();
            let out = run(&options, None);
            us_per_eval.push((thread_cpu_ms() - cpu) * 1e3 / out.plan.evaluations as f64);
            options.parallel = true;
            no_reach_ms.push(time_ms(|| run(&options, None)).0);
        }
        kernels.push(KernelBench {
            kernel: kernel.name(),
            median_ms: median(&mut ms),
            p90_ms: percentile(&mut ms, 0.9),
            serial_median_ms: median(&mut serial_ms),
            serial_median_cpu_ms: median(&mut serial_cpu_ms),
            no_reach_median_ms: median(&mut no_reach_ms),
            median_us_per_evaluation: median(&mut us_per_eval),
            median_evaluations: median(&mut evaluations),
            median_reach_checks: median(&mut checks),
            reachable_rate: rate(&reachable),
            unconstrained_optimum_unreachable_rate: rate(&unc_unreachable),
            best_single_reachable_rate: rate(&single_reachable),
        });
    }
    let options = PlanOptions::new(Kernel::LAPLACE_DEFAULT, &cell);
    let (mut far_ms, mut far_reachable, mut far_unc) = (Vec::new(), Vec::new(), Vec::new());
    let mut far_cpu_ms = Vec::new();
    for r in 0..args.far_repeats {
        let (fits, grasps) = synthetic_problem(&spec(r, far));
        let options = PlanOptions {
            parallel: false,
            ..options
        };
        let cpu = thread_cpu_ms();
        let (t, out) = time_ms(|| {
            plan(&fits, &grasps, "top", &options, reach).expect("synthetic problems are valid")
        });
        far_cpu_ms.push(thread_cpu_ms() - cpu);
        far_ms.push(t);
        far_reachable.push(out.plan.grasp.reachable);
        far_unc.push(out.plan.unconstrained_optimum.is_some());
    }
    let sim = sim_bench(
        &cell,
        &robot,
        &args.sim_db,
        &args.sim_task,
        args.sim_repeats.max(1),
        args.seed,
    )?;
    let out = PlanBench {
        sim,
        models: args.models,
        grasps_per_model: args.grasps_per_model,
        starts: args.models * args.grasps_per_model,
        repeats: args.repeats,
        seed: args.seed,
        object_xy_m: near,
        threads: rayon::current_num_threads(),
        kernels,
        far_object_xy_m: far,
        far_repeats: args.far_repeats,
        far_median_ms: median(&mut far_ms),
        far_median_cpu_ms: median(&mut far_cpu_ms),
        far_reachable_rate: rate(&far_reachable),
        far_unconstrained_unreachable_rate: rate(&far_unc),
    };
    emit(true, &out, |_| String::new())?;
    Ok(ExitCode::SUCCESS)
}
