//! `cell calibrate ...` (hand–eye calibration); `cell bench calib` is in `bench::calib`.

use crate::calib::collect::{
    plan_poses, run_collection, ArmMover, CameraPrior, CollectOptions, Diversity, PlannerCell,
    Progress, Rejections, TargetFound, TargetRig,
};
use crate::calib::sim_rig::{simulated_rig, SimTruth};
use crate::calib::{
    solve, Conditioning, HandEyeResult, Method, ResidualStats, Sample, SampleFile, SampleResidual,
    Solution, SolveOptions, Weights,
};
use crate::clock::{format_utc, unix_ms_now, UtcPrecision};
use crate::config::CellConfig;
use crate::geometry::{matrix_rows, parse_numbers, pose_from_params, PoseJson};
use crate::robot::Robot;
use crate::sim::camera::Intrinsics;
use anyhow::Context;
use clap::{Args, Subcommand};
use nalgebra::{Isometry3, Vector3};
use serde::Serialize;
use std::fmt::Write as _;
use std::path::Path;
use std::path::PathBuf;
use std::process::ExitCode;
use std::sync::Arc;
use std::time::Instant;

/// The calibration subcommands.
#[derive(Debug, Subcommand)]
pub enum CalibrateCommand {
    /// Move the arm through diverse poses chosen automatically, find the calibration
    /// sphere in the depth cloud at each, and write the samples (simulation for now).
    Collect(CollectArgs),
    /// Solve base_from_camera from a sample file; print residuals and the method
    /// comparison; write calib/hand_eye.toml.
    Solve(SolveArgs),
}

/// Options of `cell calibrate solve`.
#[derive(Debug, Args)]
pub struct SolveArgs {
    /// Sample file (JSON: base_from_flange with camera_from_target or
    /// target_point_camera_m per sample; see the README).
    #[arg(long)]
    pub samples: PathBuf,
    /// Closed-form solver; `all` runs every one the samples allow. The best is then
    /// refined by nonlinear least squares over all samples.
    #[arg(long, value_enum, default_value_t = Method::All)]
    pub method: Method,
    /// The target's position in the flange frame x,y,z (m), if measured; estimated otherwise.
    #[arg(long, allow_hyphen_values = true)]
    pub target_in_flange: Option<String>,
    /// Skip the nonlinear refinement (report the best closed form).
    #[arg(long)]
    pub no_refine: bool,
    /// Result file to write (atomically).
    #[arg(long, default_value = "calib/hand_eye.toml")]
    pub out: PathBuf,
    /// Print the result without writing the result file.
    #[arg(long)]
    pub dry_run: bool,
    /// Print JSON.
    #[arg(long)]
    pub json: bool,
}

/// Options of `cell calibrate collect`.
#[derive(Debug, Args)]
pub struct CollectArgs {
    /// Number of poses to visit (10–30 are typical; the solver needs at least 5
    /// usable ones with the sphere's offset unknown).
    #[arg(long, default_value_t = 25)]
    pub poses: usize,
    /// Sample file to write (atomically); default calib/samples-<UTC date-time>.json.
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Seed of the pose draw, the sphere fit and the simulated sensor noise.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Radius of the calibration sphere (m).
    #[arg(long, default_value_t = 0.04)]
    pub sphere_radius: f64,
    /// The sphere centre's nominal position in the flange frame x,y,z (m); used to
    /// plan poses and to look for the sphere, not by the solver.
    #[arg(long, allow_hyphen_values = true, default_value = "0.10,0.0,0.14")]
    pub target_in_flange: String,
    /// Simulation: the camera's true mount is the configured one moved by this,
    /// x,y,z,roll,pitch,yaw (m, rad; base frame), so that the calibration has
    /// something to find.
    #[arg(long, allow_hyphen_values = true)]
    pub sim_camera_error: Option<String>,
    /// Simulation: the sphere's true centre is the nominal one moved by x,y,z (m).
    #[arg(long, allow_hyphen_values = true)]
    pub sim_target_error: Option<String>,
    /// Print JSON.
    #[arg(long)]
    pub json: bool,
}

/// Runs one calibration subcommand.
pub fn run(config: &Path, which: CalibrateCommand) -> anyhow::Result<ExitCode> {
    match which {
        CalibrateCommand::Collect(args) => collect_command(config, args),
        CalibrateCommand::Solve(args) => solve_command(args),
    }
}

/// One visited pose in the collect report.
#[derive(Debug, Serialize)]
struct CaptureRow {
    pose: usize,
    via_home: bool,
    joints_rad: [f64; 7],
    base_from_flange: PoseJson,
    #[serde(skip_serializing_if = "Option::is_none")]
    found: Option<TargetFound>,
    #[serde(skip_serializing_if = "Option::is_none")]
    skipped: Option<String>,
}

/// The simulation's truth, for comparing with `cell calibrate solve`.
#[derive(Debug, Serialize)]
struct SimulationReport {
    nominal_base_from_camera: PoseJson,
    true_base_from_camera: PoseJson,
    true_from_nominal_mm: f64,
    true_from_nominal_deg: f64,
    true_target_in_flange_m: [f64; 3],
}

/// What `cell calibrate collect` prints.
#[derive(Debug, Serialize)]
struct CollectReport {
    samples_file: String,
    seed: u64,
    poses_requested: usize,
    poses_planned: usize,
    usable_samples: usize,
    candidates: usize,
    feasible: usize,
    rejections: Rejections,
    planned_diversity: Diversity,
    sample_diversity: Diversity,
    sphere_radius_m: f64,
    nominal_target_in_flange_m: [f64; 3],
    captures: Vec<CaptureRow>,
    simulation: SimulationReport,
    plan_s: f64,
    capture_s: f64,
    next: String,
}

fn collect_command(config_path: &Path, args: CollectArgs) -> anyhow::Result<ExitCode> {
    let config = CellConfig::load(config_path)?;
    anyhow::ensure!(
        config.camera.backend == "sim" && config.fri.backend == "sim",
        "{}: camera.backend = {:?}, fri.backend = {:?}: `cell calibrate collect` drives only the simulated arm and camera so far (the hardware ArmMover and TargetCamera are not written yet); set both to \"sim\"",
        config_path.display(),
        config.camera.backend,
        config.fri.backend
    );
    anyhow::ensure!(
        args.sphere_radius.is_finite() && args.sphere_radius > 0.0,
        "--sphere-radius {}: must be a finite number > 0 (m)",
        args.sphere_radius
    );
    let v = parse_numbers(&args.target_in_flange, 3, "--target-in-flange x,y,z")?;
    let rig = TargetRig {
        radius_m: args.sphere_radius,
        flange_from_centre_m: Vector3::new(v[0], v[1], v[2]),
        ..TargetRig::standard()
    };
    let nominal = config.base_from_camera();
    let camera_error = match &args.sim_camera_error {
        Some(text) => {
            let e = parse_numbers(text, 6, "--sim-camera-error x,y,z,roll,pitch,yaw")?;
            pose_from_params(&[e[0], e[1], e[2], e[3], e[4], e[5]])
        }
        None => Isometry3::identity(),
    };
    let target_error = match &args.sim_target_error {
        Some(text) => {
            let e = parse_numbers(text, 3, "--sim-target-error x,y,z")?;
            Vector3::new(e[0], e[1], e[2])
        }
        None => Vector3::zeros(),
    };
    let truth = SimTruth::with_errors(&nominal, rig, &camera_error, &target_error);
    let robot = Arc::new(Robot::load(&config)?);
    let prior = CameraPrior {
        intrinsics: Intrinsics::from(&config.camera),
        base_from_camera: nominal,
    };
    let options = CollectOptions::new(args.poses, rig.radius_m, args.seed);
    let (mut arm, mut camera) = simulated_rig(
        &config,
        Arc::clone(&robot),
        &truth,
        options.hand,
        options.home,
        args.seed,
    )?;
    let start = arm.joints(options.capture_timeout_s)?;

    let bar = indicatif::ProgressBar::new(options.max_candidates as u64);
    bar.set_message("planning poses");
    let started = Instant::now();
    let cell = PlannerCell {
        robot: &robot,
        flange_link: &config.robot.flange_link,
        camera: &prior,
        rig: &rig,
        table: &config.table,
    };
    let plan = plan_poses(&cell, &start, &options, &mut |p| update_bar(&bar, p))?;
    let plan_s = started.elapsed().as_secs_f64();
    tracing::info!(
        poses = plan.poses.len(),
        feasible = plan.feasible,
        candidates = plan.candidates,
        "planned"
    );
    bar.set_length(plan.poses.len() as u64);
    bar.set_position(0);
    bar.set_message("capturing");
    let started = Instant::now();
    let collection = run_collection(
        &plan,
        &mut arm,
        &mut camera,
        &prior,
        &rig,
        &options,
        &mut |p| update_bar(&bar, p),
    )?;
    let capture_s = started.elapsed().as_secs_f64();
    bar.finish_and_clear();

    let created = utc_now_rfc3339();
    let out = args.out.clone().unwrap_or_else(|| {
        PathBuf::from(format!("calib/samples-{}.json", created.replace(':', "-")))
    });
    let file = SampleFile {
        created,
        comment: Some(format!(
            "cell calibrate collect: simulation, seed {}, {} poses, sphere radius {} m, nominal centre in flange {:?} m",
            args.seed,
            plan.poses.len(),
            rig.radius_m,
            v
        )),
        samples: collection.samples.iter().copied().map(Sample::Point).collect(),
    };
    file.save(&out)?;
    let samples_file = out.display().to_string();
    let (dp, dr) = truth.camera_error_from(&nominal);
    let report = CollectReport {
        next: format!("cell calibrate solve --samples {samples_file} --method points"),
        samples_file,
        seed: args.seed,
        poses_requested: args.poses,
        poses_planned: plan.poses.len(),
        usable_samples: collection.samples.len(),
        candidates: plan.candidates,
        feasible: plan.feasible,
        rejections: plan.rejections,
        planned_diversity: plan.diversity,
        sample_diversity: collection.diversity,
        sphere_radius_m: rig.radius_m,
        nominal_target_in_flange_m: rig.flange_from_centre_m.into(),
        captures: collection
            .captures
            .iter()
            .map(|c| CaptureRow {
                pose: c.pose,
                via_home: plan.poses[c.pose].via_home,
                joints_rad: c.joints,
                base_from_flange: PoseJson::from(&c.base_from_flange),
                found: c.outcome.as_ref().ok().copied(),
                skipped: c.outcome.as_ref().err().map(|e| e.to_string()),
            })
            .collect(),
        simulation: SimulationReport {
            nominal_base_from_camera: PoseJson::from(&nominal),
            true_base_from_camera: PoseJson::from(&truth.base_from_camera),
            true_from_nominal_mm: dp * 1e3,
            true_from_nominal_deg: dr.to_degrees(),
            true_target_in_flange_m: truth.rig.flange_from_centre_m.into(),
        },
        plan_s,
        capture_s,
    };
    super::emit(args.json, &report, human_collect)?;
    Ok(ExitCode::SUCCESS)
}

fn update_bar(bar: &indicatif::ProgressBar, progress: Progress) {
    match progress {
        Progress::Planning { drawn, .. } => bar.set_position(drawn as u64),
        Progress::Capturing { done, .. } => bar.set_position(done as u64),
    }
}

fn human_collect(r: &CollectReport) -> String {
    let mut s = String::new();
    let _ = writeln!(
        s,
        "planned {} poses (of {} requested) from {} feasible of {} candidates ({}) in {:.1} s",
        r.poses_planned, r.poses_requested, r.feasible, r.candidates, r.rejections, r.plan_s
    );
    let d = &r.planned_diversity;
    let _ = writeln!(
        s,
        "diversity: rotation axis spread {:.1}°, RMS relative rotation about the principal axes {:.1}° / {:.1}° / {:.1}°, median pair rotation {:.1}°, sphere centres spread {:.0} / {:.0} / {:.0} mm",
        d.axis_spread_deg,
        d.rotation_rms_deg[0],
        d.rotation_rms_deg[1],
        d.rotation_rms_deg[2],
        d.median_pair_rotation_deg,
        d.position_spread_m[0] * 1e3,
        d.position_spread_m[1] * 1e3,
        d.position_spread_m[2] * 1e3
    );
    let _ = writeln!(
        s,
        "captured {} usable samples of {} poses in {:.1} s",
        r.usable_samples, r.poses_planned, r.capture_s
    );
    let _ = writeln!(s, "  pose  inliers  rms_mm  coverage  from_expected_mm");
    for c in &r.captures {
        match (&c.found, &c.skipped) {
            (Some(f), _) => {
                let _ = writeln!(
                    s,
                    "  {:>4}  {:>7}  {:>6.2}  {:>8.2}  {:>16.1}",
                    c.pose, f.inliers, f.rms_mm, f.coverage, f.from_expected_mm
                );
            }
            (None, Some(why)) => {
                let _ = writeln!(s, "  {:>4}  skipped: {why}", c.pose);
            }
            (None, None) => {}
        }
    }
    let sim = &r.simulation;
    let _ = writeln!(
        s,
        "simulation: true camera mount {:.1} mm / {:.2}° from the nominal one; true sphere centre in flange {} m",
        sim.true_from_nominal_mm,
        sim.true_from_nominal_deg,
        fmt3(&sim.true_target_in_flange_m)
    );
    let _ = writeln!(s, "wrote {}\nnext: {}", r.samples_file, r.next);
    s
}

/// One method's line in the comparison.
#[derive(Debug, Serialize)]
struct ComparisonRow {
    method: String,
    base_from_camera: PoseJson,
    residuals: ResidualStats,
    weighted_cost: f64,
    from_selected_mm: f64,
    from_selected_deg: f64,
}

/// What `cell calibrate solve` prints.
#[derive(Debug, Serialize)]
struct SolveReport {
    samples_file: String,
    sample_count: usize,
    pose_samples: usize,
    point_samples: usize,
    method: String,
    base_from_camera: PoseJson,
    base_from_camera_matrix: [[f64; 4]; 4],
    target_in_flange_m: [f64; 3],
    #[serde(skip_serializing_if = "Option::is_none")]
    flange_from_target: Option<PoseJson>,
    residual_stats: ResidualStats,
    residuals: Vec<SampleResidual>,
    comparison: Vec<ComparisonRow>,
    weights: Weights,
    conditioning: Conditioning,
    warnings: Vec<String>,
    written: Option<String>,
}

fn solve_command(args: SolveArgs) -> anyhow::Result<ExitCode> {
    let file = SampleFile::load(&args.samples)?;
    let known_target_point = match &args.target_in_flange {
        Some(text) => {
            let v = parse_numbers(text, 3, "--target-in-flange x,y,z")?;
            Some(Vector3::new(v[0], v[1], v[2]))
        }
        None => None,
    };
    let options = SolveOptions {
        method: args.method,
        refine: !args.no_refine,
        known_target_point,
        weights: Weights::default(),
    };
    let solution = solve(&file.samples, &options)
        .with_context(|| format!("cannot calibrate from {}", args.samples.display()))?;
    for w in &solution.warnings {
        tracing::warn!("{w}");
    }
    let samples_file = args.samples.display().to_string();
    let result = HandEyeResult::from_solution(
        &solution,
        &samples_file,
        file.samples.len(),
        &utc_now_rfc3339(),
    );
    let written = if args.dry_run {
        None
    } else {
        result.save(&args.out)?;
        Some(args.out.display().to_string())
    };
    let report = report(
        &file,
        &solution,
        &result,
        samples_file,
        written,
        options.weights,
    );
    super::emit(args.json, &report, human_report)?;
    Ok(ExitCode::SUCCESS)
}

fn report(
    file: &SampleFile,
    solution: &Solution,
    result: &HandEyeResult,
    samples_file: String,
    written: Option<String>,
    weights: Weights,
) -> SolveReport {
    let best = solution.best();
    let pose_samples = file
        .samples
        .iter()
        .filter(|s| matches!(s, Sample::Pose(_)))
        .count();
    SolveReport {
        samples_file,
        sample_count: file.samples.len(),
        pose_samples,
        point_samples: file.samples.len() - pose_samples,
        method: best.name.clone(),
        base_from_camera: result.base_from_camera,
        base_from_camera_matrix: matrix_rows(&best.evaluation.hand_eye.base_from_camera),
        target_in_flange_m: result.target_in_flange_m,
        flange_from_target: result.flange_from_target,
        residual_stats: best.evaluation.stats,
        residuals: best.evaluation.residuals.clone(),
        comparison: solution
            .results
            .iter()
            .map(|r| ComparisonRow {
                method: r.name.clone(),
                base_from_camera: PoseJson::from(&r.evaluation.hand_eye.base_from_camera),
                residuals: r.evaluation.stats,
                weighted_cost: r.evaluation.cost,
                from_selected_mm: r.from_selected.0,
                from_selected_deg: r.from_selected.1,
            })
            .collect(),
        weights,
        conditioning: solution.conditioning,
        warnings: solution.warnings.clone(),
        written,
    }
}

fn fmt3(v: &[f64]) -> String {
    let parts: Vec<String> = v.iter().map(|x| format!("{x:.5}")).collect();
    format!("[{}]", parts.join(", "))
}

fn opt(v: Option<f64>, precision: usize) -> String {
    v.map(|v| format!("{v:.precision$}"))
        .unwrap_or_else(|| "-".into())
}

fn human_report(r: &SolveReport) -> String {
    let mut s = String::new();
    let _ = writeln!(
        s,
        "hand-eye calibration from {} ({} samples: {} pose, {} point)",
        r.samples_file, r.sample_count, r.pose_samples, r.point_samples
    );
    let _ = writeln!(s, "method: {}", r.method);
    let p = &r.base_from_camera;
    let _ = writeln!(
        s,
        "base_from_camera: xyz {} m, rpy {} rad, quat_xyzw {}",
        fmt3(&p.xyz),
        fmt3(&p.rpy.unwrap_or_default()),
        fmt3(&p.quat_xyzw.unwrap_or_default())
    );
    for row in &r.base_from_camera_matrix {
        let _ = writeln!(
            s,
            "  [{:>9.5} {:>9.5} {:>9.5} {:>9.5}]",
            row[0], row[1], row[2], row[3]
        );
    }
    let _ = writeln!(s, "target in flange: {} m", fmt3(&r.target_in_flange_m));
    let _ = writeln!(
        s,
        "residuals per sample:\n  sample  translation_mm  rotation_deg"
    );
    for e in &r.residuals {
        let _ = writeln!(
            s,
            "  {:>6}  {:>14.3}  {:>12}",
            e.index,
            e.translation_mm,
            opt(e.rotation_deg, 3)
        );
    }
    let st = &r.residual_stats;
    let _ = writeln!(
        s,
        "  rms {:.3} mm, median {:.3} mm, max {:.3} mm; rms {} deg, max {} deg",
        st.rms_mm,
        st.median_mm,
        st.max_mm,
        opt(st.rms_deg, 3),
        opt(st.max_deg, 3)
    );
    let _ = writeln!(
        s,
        "method comparison (residuals over all samples; distance of base_from_camera from the selected result):\n  {:<20} {:>8} {:>8} {:>8} {:>8} {:>10} {:>10}",
        "method", "rms_mm", "max_mm", "rms_deg", "max_deg", "d_sel_mm", "d_sel_deg"
    );
    for c in &r.comparison {
        let _ = writeln!(
            s,
            "  {:<20} {:>8.3} {:>8.3} {:>8} {:>8} {:>10.3} {:>10.4}",
            c.method,
            c.residuals.rms_mm,
            c.residuals.max_mm,
            opt(c.residuals.rms_deg, 3),
            opt(c.residuals.max_deg, 3),
            c.from_selected_mm,
            c.from_selected_deg
        );
    }
    let c = &r.conditioning;
    let _ = writeln!(
        s,
        "conditioning: {} sample pairs rotating >= {}°, largest rotation {:.1}°, rotation axis spread {:.1}°",
        c.usable_pairs,
        crate::calib::MIN_PAIR_ROTATION_DEG,
        c.max_pair_rotation_deg,
        c.axis_spread_deg
    );
    for w in &r.warnings {
        let _ = writeln!(s, "warning: {w}");
    }
    match &r.written {
        Some(path) => {
            let _ = writeln!(s, "wrote {path}");
        }
        None => {
            let _ = writeln!(s, "dry run: nothing written");
        }
    }
    s
}

/// The current UTC time as RFC 3339 (`2025-01-31T10:00:00Z`).
fn utc_now_rfc3339() -> String {
    format_utc(unix_ms_now(), UtcPrecision::Seconds)
}
