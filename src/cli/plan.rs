//! `cell plan` (`cell bench plan` is in `bench::plan`).

use super::emit;
use crate::category::CategoryDb;
use crate::cell::plan::{ExecutorReach, TrialPlan};
use crate::cloud::io::read_cloud;
use crate::config::CellConfig;
use crate::execute::{ExecutionRequest, ExecutorConfig, SafetyCheck, SafetyLimits};
use crate::fsio::write_atomically;
use crate::geometry::parse_numbers;
use crate::geometry::{params_from_pose, Pose};
use crate::plan::category::example_grasps;
use crate::plan::input::{fits_input, read_fits_input, read_grasps, FitsInput, Unregistered};
use crate::plan::refine::{refine_over_db, DbProblem, Refined, SimRefineOptions};
use crate::plan::{
    plan_with, FitWeight, Kernel, PaperProtocol, PlanMode, PlanOptions, PlanOutcome, PlannedGrasp,
    Reachability, SeenSurface, SeenSurfaceOptions,
};
use crate::register::{register_all, ModelSet, RegisterParams, RegistrationStatus};
use crate::robot::hand::HandModel;
use crate::robot::kinematics::ArmJoints;
use crate::robot::Robot;
use anyhow::Context;
use clap::{Args, ValueEnum};
use serde::Serialize;
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::sync::Arc;

/// The density family on the command line.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum KernelName {
    /// Laplace (5c): fat tails; the paper's best.
    Laplace,
    /// Gaussian (5a) over the grasps' own Sigma.
    Gaussian,
    /// Regularised Gaussian (5b): Sigma + s.
    GaussianR,
}

/// The fit weight on the command line.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum FitWeightName {
    /// (4a) exp(-lambda_eps eps).
    Eps,
    /// (4b) exp(-lambda_eps (eps + sigma)): robust for partial clouds.
    EpsSigma,
}

/// The kernel options shared by `cell plan` and the evaluations that call the planner.
#[derive(Debug, Clone, Args)]
pub struct KernelArgs {
    /// Task-compatibility density.
    #[arg(long, value_enum, default_value_t = KernelName::Laplace)]
    pub kernel: KernelName,
    /// The paper's scalar s (Gaussian-R, mm^2 and rad^2 mixed) or b (Laplace, mm and rad
    /// mixed): 50 in its simulation, 700 on its robot. Sets both SI scales: translation
    /// s*1e-6 m^2 or b*1e-3 m, rotation s rad^2 or b rad.
    #[arg(long)]
    pub paper_scale: Option<f64>,
    /// Gaussian-R: regulariser on translation (m^2) [default 5e-5].
    #[arg(long)]
    pub s_translation_m2: Option<f64>,
    /// Gaussian-R: regulariser on rotation (rad^2) [default 0.05].
    #[arg(long)]
    pub s_rotation_rad2: Option<f64>,
    /// Laplace: scale of translation (m) [default 0.05].
    #[arg(long)]
    pub b_translation_m: Option<f64>,
    /// Laplace: scale of rotation (rad) [default 0.5].
    #[arg(long)]
    pub b_rotation_rad: Option<f64>,
}

impl KernelArgs {
    /// The kernel these options describe (scales from `--paper-scale`, then the
    /// individual flags, then the defaults).
    pub fn kernel(&self) -> Kernel {
        match self.kernel {
            KernelName::Gaussian => Kernel::Gaussian,
            KernelName::GaussianR => {
                let Kernel::GaussianR {
                    s_translation_m2,
                    s_rotation_rad2,
                } = self
                    .paper_scale
                    .map_or(Kernel::GAUSSIAN_R_DEFAULT, Kernel::paper_gaussian_r)
                else {
                    unreachable!("a Gaussian-R kernel")
                };
                Kernel::GaussianR {
                    s_translation_m2: self.s_translation_m2.unwrap_or(s_translation_m2),
                    s_rotation_rad2: self.s_rotation_rad2.unwrap_or(s_rotation_rad2),
                }
            }
            KernelName::Laplace => {
                let Kernel::Laplace {
                    b_translation_m,
                    b_rotation_rad,
                } = self
                    .paper_scale
                    .map_or(Kernel::LAPLACE_DEFAULT, Kernel::paper_laplace)
                else {
                    unreachable!("a Laplace kernel")
                };
                Kernel::Laplace {
                    b_translation_m: self.b_translation_m.unwrap_or(b_translation_m),
                    b_rotation_rad: self.b_rotation_rad.unwrap_or(b_rotation_rad),
                }
            }
        }
    }
}

/// Options of `cell plan`.
///
/// The target is given either as model fits (`--fits`, e.g. `cell register --json`
/// output) or as the object's segmented cloud (`--cloud`), which is registered
/// against every model of `--db` first.
#[derive(Debug, Args)]
#[command(group(clap::ArgGroup::new("target").required(true).args(["fits", "cloud"])))]
#[command(group(clap::ArgGroup::new("examples").required(true).args(["db", "grasps"])))]
pub struct PlanArgs {
    /// Model fits: the array `cell register --json` prints (failed models are left
    /// out), or {"fits": [{"name", "base_from_model", "eps_m2", "sigma_m2"}]}.
    #[arg(long)]
    pub fits: Option<PathBuf>,
    /// The object's segmented cloud (PLY/PCD, robot base frame, e.g. from `cell
    /// segment`): every model of --db is registered to it (FPFH + RANSAC + ICP) and
    /// the fits of those that register are planned over.
    #[arg(long)]
    pub cloud: Option<PathBuf>,
    /// Seed of the registration's RANSAC (--cloud).
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Sensor position `x,y,z` (base frame) for the cloud's normals (--cloud);
    /// default: the configured camera's position.
    #[arg(long)]
    pub viewpoint: Option<String>,
    /// Category database directory (e.g. db/mug): the example grasps of the task for
    /// every model that has a fit (and, with --cloud, the models to register).
    #[arg(long)]
    pub db: Option<PathBuf>,
    /// Example grasps (JSON: {"grasps": [{"model", "task", "model_from_palm",
    /// "spread_rad", "q", "sigma_m_rad"}]}); `model` names a fit. Instead of --db.
    #[arg(long)]
    pub grasps: Option<PathBuf>,
    /// The task (e.g. top, side, handle, use).
    #[arg(long)]
    pub task: String,
    /// Density options.
    #[command(flatten)]
    pub kernel: KernelArgs,
    /// Fit weight.
    #[arg(long, value_enum, default_value_t = FitWeightName::EpsSigma)]
    pub fit_weight: FitWeightName,
    /// lambda_psi of the stability weight psi(q) = 1 - exp(-lambda_psi q)
    /// [default: the database's calibrated value, else 10].
    #[arg(long)]
    pub lambda_psi: Option<f64>,
    /// lambda_eps of the fit weight (1/m^2) [default: the database's calibrated
    /// value, else 1e4].
    #[arg(long)]
    pub lambda_eps_per_m2: Option<f64>,
    /// Skip reachability (the paper's simulation setting: only the table bound).
    #[arg(long, conflicts_with = "out")]
    pub no_reach: bool,
    /// Write the planned grasp as a plan for `cell execute --plan` (the executor's
    /// schema), with joint solutions the executor accepts from --from-joints. When
    /// the executor refuses the motions of the planned grasp (e.g. an approach that
    /// puts the forearm on the table), the task is planned again with the
    /// executor's checks in the planner's constraint, as `cell demo` and campaigns
    /// do (not with --paper, which reports the refusal).
    #[arg(long, value_name = "PLAN_JSON")]
    pub out: Option<PathBuf>,
    /// Arm joints A1,A2,E1,A3,A4,A5,A6 (rad) the grasp will start from (--out's
    /// joints are ones whose motions from there the executor accepts); default: the
    /// park position.
    #[arg(
        long,
        value_name = "Q1,...,Q7",
        allow_hyphen_values = true,
        requires = "out"
    )]
    pub from_joints: Option<String>,
    /// The paper's settings: its kernel scale (s = b = 50 for `simulation`, 700 for
    /// `robot`), its fixed weights, no reachability repair for any method (an
    /// unreachable grasp is reported as such), and with --cloud its one-sided fit
    /// score with poor registrations kept. Without a value: `simulation`.
    #[arg(long, value_enum, num_args = 0..=1, default_missing_value = "simulation")]
    pub paper: Option<PaperProtocol>,
    /// With --cloud: do not treat the seen points as an obstacle of the open hand.
    /// (They are one at the pre-grasp, where the approach to contact starts, and,
    /// with --paper, which closes the hand where planned, along the whole approach.)
    #[arg(long)]
    pub no_seen_surface: bool,
    /// Also refine the plan in the grasp simulator over every fitted model
    /// (`laplace-sim`; needs --db for the meshes).
    #[arg(long)]
    pub refine_sim: bool,
    /// Run the starts one after another instead of in parallel.
    #[arg(long)]
    pub serial: bool,
    /// Print JSON: {"fits", "grasps", "options", "plan", "best_single"}.
    #[arg(long)]
    pub json: bool,
}

/// One model's registration, as `cell plan --cloud` reports it.
#[derive(Serialize)]
struct RegistrationSummary {
    model: String,
    status: &'static str,
    #[serde(skip_serializing_if = "Option::is_none")]
    reason: Option<String>,
    /// Fitting error (m^2); `null` when failed.
    eps_m2: Option<f64>,
    /// Standard deviation of the squared distances (m^2); `null` when failed.
    sigma_m2: Option<f64>,
}

#[derive(Serialize)]
struct PlanReport<'a> {
    /// The fits file, or the cloud that was registered.
    fits: &'a Path,
    /// The grasps file or the category database the example grasps came from.
    grasps: &'a Path,
    /// Seed of the registration (--cloud only).
    #[serde(skip_serializing_if = "Option::is_none")]
    seed: Option<u64>,
    /// Every model's registration (--cloud only).
    #[serde(skip_serializing_if = "Option::is_none")]
    registrations: Option<Vec<RegistrationSummary>>,
    /// Models left out because their registration failed.
    unregistered: Vec<Unregistered>,
    options: PlanOptions,
    /// The paper's mode, when set.
    paper: Option<PaperProtocol>,
    /// Points of the seen surface (after thinning), when it was an obstacle.
    seen_points: Option<usize>,
    /// The plan refined in the simulator (--refine-sim).
    laplace_sim: Option<Refined>,
    /// With --out: the executor's refusal of the first plan's motions, when the
    /// task was planned again with them in the planner's constraint (the plan
    /// reported is the second).
    #[serde(skip_serializing_if = "Option::is_none")]
    planned_again_after: Option<String>,
    #[serde(flatten)]
    outcome: PlanOutcome,
}

/// Loads a category database for planning, refusing one without models.
pub(super) fn load_db(dir: &Path) -> anyhow::Result<CategoryDb> {
    let db = CategoryDb::load(dir)?;
    anyhow::ensure!(
        !db.file.models.is_empty(),
        "{}: the category database has no models",
        dir.display()
    );
    Ok(db)
}

/// Registers every model of `db` to the cloud at `path`: the fits of the models that
/// registered and a summary of all.
fn register_cloud(
    cell: &CellConfig,
    db: &CategoryDb,
    path: &Path,
    args: &PlanArgs,
) -> anyhow::Result<(FitsInput, Vec<RegistrationSummary>)> {
    let viewpoint = match &args.viewpoint {
        Some(text) => {
            let v = parse_numbers(text, 3, "--viewpoint")?;
            [v[0], v[1], v[2]]
        }
        None => {
            let eye = cell.base_from_camera().translation.vector;
            [eye.x, eye.y, eye.z]
        }
    };
    let mut params = RegisterParams {
        viewpoint_m: Some(viewpoint),
        ..RegisterParams::default()
    };
    if args.paper.is_some() {
        params = params.paper();
    }
    let target = read_cloud(path)?;
    let models = ModelSet::from_category(db, &params)
        .with_context(|| format!("{}: preparing the models", db.dir.display()))?;
    let registrations = register_all(&target, &models, &params, args.seed)
        .with_context(|| format!("{}", path.display()))?;
    let summary: Vec<RegistrationSummary> = registrations
        .iter()
        .map(|r| {
            let (status, reason) = match &r.status {
                RegistrationStatus::Ok => ("ok", None),
                RegistrationStatus::Failed(why) => ("failed", Some(why.clone())),
            };
            RegistrationSummary {
                model: r.model.clone(),
                status,
                reason,
                eps_m2: r.eps_m2.is_finite().then_some(r.eps_m2),
                sigma_m2: r.sigma_m2.is_finite().then_some(r.sigma_m2),
            }
        })
        .collect();
    let input = fits_input(&registrations);
    if input.fits.is_empty() {
        anyhow::bail!(
            "{}: no model of {} registered: {}",
            path.display(),
            db.dir.display(),
            input.unregistered_text()
        );
    }
    Ok((input, summary))
}

fn pose_text(pose: &Pose) -> String {
    let p = params_from_pose(pose);
    format!(
        "xyz = [{:.4}, {:.4}, {:.4}] m  rpy = [{:.4}, {:.4}, {:.4}] rad",
        p[0], p[1], p[2], p[3], p[4], p[5]
    )
}

fn grasp_text(name: &str, g: &PlannedGrasp) -> String {
    let reach = match (&g.unreachable, g.reachable) {
        (_, true) => "reachable".to_string(),
        (Some(why), false) => why.to_string(),
        (None, false) => "reachability not checked".to_string(),
    };
    format!(
        "{name:<12} {}  spread {:.3} rad\n{:<12} objective {:.4e} (ln {:.4}); {reach}\n",
        pose_text(&g.pose),
        g.spread_rad,
        "",
        g.objective,
        g.log_objective
    )
}

/// Runs `cell plan`.
pub fn run(config: &Path, args: PlanArgs) -> anyhow::Result<ExitCode> {
    let cell = CellConfig::load(config)?;
    if let (Some(cloud), None) = (&args.cloud, &args.db) {
        anyhow::bail!(
            "--cloud {}: give --db, the category database whose models are registered to it",
            cloud.display()
        );
    }
    let db = args.db.as_deref().map(load_db).transpose()?;
    if let (Some(db), Some(_)) = (&db, &args.cloud) {
        // A task without grasps is an error before the registration runs.
        if let Err(e @ crate::plan::PlanError::NoGraspsForTask { .. }) =
            example_grasps(db, &[], &args.task)
        {
            return Err(anyhow::Error::new(e).context(format!(
                "{}: task {:?}",
                db.dir.display(),
                args.task
            )));
        }
    }
    let (fits_path, input, registrations) = match (&args.fits, &args.cloud, &db) {
        (Some(file), _, _) => (file.as_path(), read_fits_input(file)?, None),
        (None, Some(cloud), Some(db)) => {
            let (input, summary) = register_cloud(&cell, db, cloud, &args)?;
            (cloud.as_path(), input, Some(summary))
        }
        _ => unreachable!("clap requires --fits or --cloud; --cloud without --db returned above"),
    };
    let fits = input.fits;
    let (grasps_path, grasps) = match (&db, &args.grasps) {
        (Some(db), _) => {
            let grasps = example_grasps(db, &fits, &args.task)
                .with_context(|| format!("{}: task {:?}", db.dir.display(), args.task))?;
            (db.dir.as_path(), grasps)
        }
        (None, Some(file)) => (file.as_path(), read_grasps(file, &fits)?),
        (None, None) => unreachable!("clap requires --db or --grasps"),
    };
    let mut options = PlanOptions::new(args.kernel.kernel(), &cell);
    if let Some(db) = &db {
        options.weights = crate::plan::category::weights(db);
    }
    if let Some(l) = args.lambda_psi {
        options.weights.lambda_psi = l;
    }
    if let Some(l) = args.lambda_eps_per_m2 {
        options.weights.lambda_eps_per_m2 = l;
    }
    options.weights.fit = match args.fit_weight {
        FitWeightName::Eps => FitWeight::Eps,
        FitWeightName::EpsSigma => FitWeight::EpsSigma,
    };
    options.parallel = !args.serial;
    if let Some(protocol) = args.paper {
        PlanMode::Paper { protocol }.apply(&mut options);
    }
    let robot = if args.no_reach {
        None
    } else {
        Some(Arc::new(Robot::load(&cell)?))
    };
    // Where the grasp's motions start (--out), checked before any planning.
    let current: ArmJoints = match args.from_joints.as_deref() {
        Some(text) => parse_numbers(text, 7, "--from-joints")?
            .try_into()
            .expect("seven numbers"),
        None => cell.robot.park_joints_rad,
    };
    if let Some(robot) = &robot {
        robot
            .check_limits(&current)
            .context("--from-joints: the arm's joints where the grasp starts")?;
    }
    let hand = HandModel::load(&cell)?;
    let target = match (&args.cloud, args.no_seen_surface) {
        (Some(path), false) => Some(read_cloud(path)?),
        _ => None,
    };
    let seen = target
        .as_ref()
        .map(|c| {
            SeenSurface::new(
                &hand,
                c,
                SeenSurfaceOptions::along_approach(&options, args.paper.is_none()),
            )
        })
        .transpose()?;
    // The planner's reach is the arm's (IK, collisions); with --out, a plan whose
    // motions the executor refuses is planned again with the executor's checks in
    // the planner's constraint, as the plan stage does ([`plan_trial`]).
    let plan =
        |reach: Option<&dyn Reachability>| -> anyhow::Result<(PlanOutcome, Option<Refined>)> {
            let outcome = plan_with(&fits, &grasps, &args.task, &options, reach, seen.as_ref())
                .with_context(|| format!("planning task {:?}", args.task))?;
            let refined = match (args.refine_sim, &db) {
                (false, _) => None,
                (true, None) => anyhow::bail!("--refine-sim needs --db (the models' meshes)"),
                (true, Some(db)) => {
                    let problem = DbProblem {
                        db,
                        fits: &fits,
                        grasps: &grasps,
                        task: &args.task,
                        options: &options,
                        hand: &hand,
                        reach,
                        seen: seen.as_ref(),
                        table_height_m: Some(cell.table.height_m),
                    };
                    let sim = SimRefineOptions::for_cell(&cell);
                    Some(refine_over_db(&problem, &outcome.plan.grasp, &sim)?)
                }
            };
            Ok((outcome, refined))
        };
    let (mut outcome, mut refined) = plan(robot.as_deref().map(|r| r as &dyn Reachability))?;
    let mut first_refusal = None;
    if let (Some(out), Some(robot)) = (&args.out, &robot) {
        let check = SafetyCheck::new(Arc::clone(robot), SafetyLimits::from_cell(&cell, robot));
        let executor = ExecutorReach {
            robot,
            check: &check,
            config: &ExecutorConfig::from_cell(&cell),
            current,
        };
        let grasp = match trial_plan(&outcome, &refined).executable(&executor) {
            Ok(grasp) => grasp,
            Err(refusal) if args.paper.is_none() => {
                (outcome, refined) = plan(Some(&executor))?;
                let again = trial_plan(&outcome, &refined).executable(&executor);
                let grasp = again.map_err(|second| {
                    anyhow::anyhow!(
                        "--out {}: {}; planned again for motions the executor accepts: {}",
                        out.display(),
                        refusal.detail,
                        second.detail
                    )
                })?;
                first_refusal = Some(refusal.detail);
                grasp
            }
            Err(refusal) => anyhow::bail!("--out {}: {}", out.display(), refusal.detail),
        };
        let method = match &refined {
            Some(_) => "laplace-sim",
            None => outcome.plan.kernel.name(),
        };
        let request = ExecutionRequest::from_planned(&grasp, &outcome.plan.task, method)?;
        write_atomically(out, serde_json::to_string_pretty(&request)?.as_bytes())
            .with_context(|| format!("writing {}", out.display()))?;
    }
    let report = PlanReport {
        fits: fits_path,
        grasps: grasps_path,
        seed: args.cloud.is_some().then_some(args.seed),
        registrations,
        unregistered: input.unregistered,
        options,
        paper: args.paper,
        seen_points: seen.as_ref().map(|s| s.len()),
        laplace_sim: refined,
        planned_again_after: first_refusal,
        outcome,
    };
    emit(args.json, &report, |r| {
        let plan = &r.outcome.plan;
        let mut text = String::new();
        if let (Some(regs), Some(seed)) = (&r.registrations, r.seed) {
            text += &format!(
                "registered {} models to {} (seed {seed}):\n",
                regs.len(),
                r.fits.display()
            );
            for g in regs {
                text += &format!(
                    "  {:<16} {:<6} eps {:>9.3} mm^2  sigma {:>9.3} mm^2{}\n",
                    g.model,
                    g.status,
                    g.eps_m2.unwrap_or(f64::NAN) * 1e6,
                    g.sigma_m2.unwrap_or(f64::NAN) * 1e6,
                    g.reason
                        .as_deref()
                        .map(|why| format!("  ({why})"))
                        .unwrap_or_default()
                );
            }
        } else if !r.unregistered.is_empty() {
            let names: Vec<&str> = r.unregistered.iter().map(|u| u.model.as_str()).collect();
            text += &format!("left out (registration failed): {}\n", names.join(", "));
        }
        if let Some(refusal) = &r.planned_again_after {
            text += &format!(
                "first plan refused by the executor ({refusal}); planned again for motions it accepts\n"
            );
        }
        text += &format!(
            "task {} with {} over {} grasps ({} evaluations, {} reach checks)\n",
            plan.task,
            plan.kernel.name(),
            plan.starts,
            plan.evaluations,
            plan.reach_checks
        );
        text += &grasp_text("planned", &plan.grasp);
        if let Some(u) = &plan.unconstrained_optimum {
            text += &format!(
                "{:<12} {}\n{:<12} objective {:.4e} (ln {:.4}); {}\n",
                "unconstrained",
                pose_text(&u.pose),
                "",
                u.objective,
                u.log_objective,
                u.unreachable
            );
        }
        text += &format!(
            "best single  model {} grasp {}\n",
            r.outcome.best_single.model_name, r.outcome.best_single.grasp_index
        );
        text += &grasp_text("", &r.outcome.best_single.grasp);
        if let Some(l) = &r.laplace_sim {
            text += &format!(
                "laplace-sim  mean simulated epsilon {:.4} -> {:.4} ({} evaluations)\n",
                l.start_mean_epsilon, l.mean_epsilon, l.evaluations
            );
            text += &grasp_text("", &l.grasp);
        }
        text
    })?;
    Ok(ExitCode::SUCCESS)
}

/// The plan `cell plan --out` executes: `laplace-sim`'s grasp with the Laplace
/// optimum as its fallback when refined, else the kernel's grasp.
fn trial_plan(outcome: &PlanOutcome, refined: &Option<Refined>) -> TrialPlan {
    match refined {
        Some(r) => TrialPlan {
            grasp: r.grasp.clone(),
            fallback: Some(outcome.plan.grasp.clone()),
        },
        None => TrialPlan {
            grasp: outcome.plan.grasp.clone(),
            fallback: None,
        },
    }
}
