//! `cell eval loo` and `cell eval cross`: the paper's simulation experiments
//! (Nikandrova & Kyrki 2015, §4.3 Figures 5 and 6, §5 Table 1) on the shipped
//! category databases, each grasp run in the grasp simulator on the test object.

use super::emit;
use super::plan::FitWeightName;
use crate::category::CategoryDb;
use crate::config::CellConfig;
use crate::eval::chart::{write_grade_chart, write_verdict_chart};
use crate::eval::experiment::Setup;
use crate::eval::loo::TallyRow;
use crate::eval::novel::{
    run_novel, CategoryModels, NovelCell, NovelObject, NovelOptions, NovelReport,
};
use crate::eval::{
    cross_category, leave_one_out, subset, CategoryRegistrar, CrossReport, LooReport,
    PlacementRegion, ViewKind, DEFAULT_EQUAL_TOLERANCE,
};
use crate::mesh::procedural::Category;
use crate::plan::{FitWeight, Kernel, PaperProtocol, PlanMode, PlanOptions, Reachability};
use crate::robot::hand::HandModel;
use crate::robot::Robot;
use crate::sim::camera::DepthCamera;
use crate::sim::scene::TableBox;
use anyhow::Context;
use clap::{Args, Subcommand, ValueEnum};
use indicatif::{ProgressBar, ProgressStyle};
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::time::Instant;

/// The experiments.
#[derive(Debug, Subcommand)]
pub enum EvalCommand {
    /// Leave-one-out over a category (the paper's Figures 5 and 6).
    ///
    /// Each model in turn is the novel object, seen at a seeded random placement on
    /// the table, and the other models are the database (registered to the view).
    /// Per task and kernel, our planned grasp and the best-single grasp are simulated
    /// on the held-out mesh (approach until clear, auto-grasp, Ferrari–Canny
    /// epsilon); the table gives the share of runs where ours is better / equal /
    /// worse than best single, the mean epsilons and the force-closure rates.
    #[command(
        after_help = "Example: cell eval loo --category mug --kernel all --png mug.png\n\
                      Bottles (the paper's Figure 6): cell eval loo --category bottle --kernel laplace,gaussian-r"
    )]
    Loo(LooArgs),
    /// Cross-category generalisation (the paper's §5, Table 1).
    ///
    /// The database of one category (e.g. hammers, `use` grasps by the handle) plans
    /// grasps on every model of another (e.g. knives); per test object the epsilon
    /// of our grasp with each kernel and of best single, simulated on it.
    #[command(after_help = "Example: cell eval cross --train hammer --test knife")]
    Cross(CrossArgs),
    /// The end-to-end novel-object experiment (issue 17): novel objects through the
    /// cell's own chain.
    ///
    /// Novel instances of each category (by default the held-apart family the
    /// databases never saw; seeds disjoint from them) stand at seeded placements.
    /// Each is rendered by the simulated camera from its true mount (the lab's
    /// hand–eye error), segmented and registered as the perception stage does,
    /// planned per task and method as the plan stage does, executed at the chosen
    /// joints plus the lab's joint noise, and graded by the simulated observer on the
    /// true mesh with the table. Per task and method: success / partial / failure,
    /// failure causes, force closure, collisions of the open hand.
    #[command(
        after_help = "Example: cell eval novel --instances 10 --placements 3 --json\n\
                      Your own scans: cell eval novel --objects scans/ (scans/objects.toml names each file's category and scale)"
    )]
    Novel(NovelArgs),
}

/// The lab's errors on the command line (`cell demo`, `cell campaign`, `cell eval
/// novel`).
#[derive(Debug, Clone, Args)]
pub struct LabArgs {
    /// Hand–eye translation error (mm), drawn once per campaign in a seeded
    /// direction.
    #[arg(long, default_value_t = crate::sim::lab::DEFAULT_HAND_EYE_TRANSLATION_M * 1e3)]
    pub hand_eye_error_mm: f64,
    /// Hand–eye rotation error (degrees), drawn once per campaign about a seeded axis.
    #[arg(long, default_value_t = crate::sim::lab::DEFAULT_HAND_EYE_ROTATION_RAD.to_degrees())]
    pub hand_eye_error_deg: f64,
    /// Executed joints' noise (rad, standard deviation), drawn per trial; default the
    /// LBR4+'s repeatability (0.05 mm) over a 1 m lever.
    #[arg(long, default_value_t = crate::sim::lab::DEFAULT_JOINT_NOISE_RAD)]
    pub joint_noise_rad: f64,
    /// An exact cell: no hand–eye or execution error.
    #[arg(long)]
    pub exact: bool,
}

impl LabArgs {
    /// The lab errors these options ask for.
    pub fn errors(&self) -> anyhow::Result<crate::sim::lab::LabErrors> {
        let lab = if self.exact {
            crate::sim::lab::LabErrors::NONE
        } else {
            crate::sim::lab::LabErrors {
                hand_eye_translation_m: self.hand_eye_error_mm * 1e-3,
                hand_eye_rotation_rad: self.hand_eye_error_deg.to_radians(),
                joint_noise_rad: self.joint_noise_rad,
            }
        };
        lab.validate().map_err(|e| {
            anyhow::anyhow!("--hand-eye-error-mm / --hand-eye-error-deg / --joint-noise-rad: {e}")
        })?;
        Ok(lab)
    }
}

/// Where novel objects come from, on the command line.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum FamilyChoice {
    /// Shapes the databases never saw (squat, tall, conical, barrel, square-handled
    /// and handle-less mugs; bottles with other shoulders and necks).
    HeldApart,
    /// Fresh seeds of the databases' own generator and ranges.
    Training,
}

impl From<FamilyChoice> for crate::mesh::procedural::held_apart::Family {
    fn from(c: FamilyChoice) -> Self {
        match c {
            FamilyChoice::HeldApart => Self::HeldApart,
            FamilyChoice::Training => Self::Training,
        }
    }
}

/// The methods `cell eval novel` compares by default, those the plan stage knows.
pub fn default_methods() -> Vec<String> {
    ["best-single", "gaussian-r", "laplace", "laplace-sim"]
        .into_iter()
        .filter(|m| crate::cell::plan::method_kernel(m).is_some())
        .map(str::to_string)
        .collect()
}

/// Options of `cell eval novel`.
#[derive(Debug, Args)]
pub struct NovelArgs {
    /// Directory holding one category database per subdirectory (db/mug, ...).
    #[arg(long, default_value = "db")]
    pub db_dir: PathBuf,
    /// Categories of procedural novel objects, comma-separated.
    #[arg(long, value_delimiter = ',', default_value = "mug,bottle,hammer")]
    pub categories: Vec<String>,
    /// Novel instances per category.
    #[arg(long, default_value_t = 10)]
    pub instances: usize,
    /// Seeded placements of every object.
    #[arg(long, default_value_t = 3)]
    pub placements: usize,
    /// Where the procedural objects come from.
    #[arg(long, value_enum, default_value_t = FamilyChoice::HeldApart)]
    pub family: FamilyChoice,
    /// Your own objects instead: a directory of OBJ/STL/PLY meshes with an
    /// `objects.toml` naming each file's category and scale.
    #[arg(long, value_name = "DIR")]
    pub objects: Option<PathBuf>,
    /// Methods of the plan stage, comma-separated (default: best-single,
    /// gaussian-r, laplace, and laplace-sim where the planner has it).
    #[arg(long, value_delimiter = ',')]
    pub methods: Vec<String>,
    /// Only these tasks, comma-separated (default: every task of each category).
    #[arg(long, value_delimiter = ',')]
    pub tasks: Vec<String>,
    /// The paper's setting: no approach to contact, collisions of the open hand
    /// fail and are counted per method.
    #[arg(long)]
    pub paper: bool,
    /// The lab's errors.
    #[command(flatten)]
    pub lab: LabArgs,
    /// Seed of objects, placements, noise, registration and the lab's errors.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Write the success / partial / failure chart (PNG) here.
    #[arg(long)]
    pub png: Option<PathBuf>,
    /// Print JSON: the rows and every trial.
    #[arg(long)]
    pub json: bool,
}

/// A kernel, or all three, on the command line.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum KernelChoice {
    /// Laplace, Gaussian-R and Gaussian.
    All,
    /// Laplace (5c).
    Laplace,
    /// Regularised Gaussian (5b).
    GaussianR,
    /// Gaussian (5a).
    Gaussian,
}

/// How the test object is seen, on the command line.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum ViewChoice {
    /// Points sampled over the whole mesh (the paper's simulation).
    Complete,
    /// One frame of the simulated depth camera (Kinect noise), the object's points.
    Partial,
}

/// The sensor position registration orients the target's normals towards.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum NormalsFrom {
    /// The configured camera.
    Camera,
    /// 1 m above the object's centroid.
    Above,
}

/// Options shared by both experiments.
#[derive(Debug, Args)]
pub struct ExperimentArgs {
    /// Directory holding one category database per subdirectory (db/mug, ...).
    #[arg(long, default_value = "db")]
    pub db_dir: PathBuf,
    /// Kernels to compare, comma-separated or repeated: all, laplace, gaussian-r,
    /// gaussian.
    #[arg(long, value_enum, value_delimiter = ',', default_value = "all")]
    pub kernel: Vec<KernelChoice>,
    /// The paper's scalar s (Gaussian-R) and b (Laplace), mm and rad mixed: 50 in its
    /// simulation. Default: our scales (Laplace 0.05 m / 0.5 rad, Gaussian-R
    /// 5e-5 m^2 / 0.05 rad^2).
    #[arg(long)]
    pub paper_scale: Option<f64>,
    /// How the test object is seen.
    #[arg(long, value_enum, default_value_t = ViewChoice::Complete)]
    pub views: ViewChoice,
    /// Points of a complete view.
    #[arg(long, default_value_t = 3000)]
    pub complete_points: usize,
    /// Where registration takes the sensor to be, to orient the target's normals:
    /// `camera` (the configured camera) or `above` (1 m above the object). Default:
    /// camera for partial views, above for complete ones. A complete cloud has no
    /// single sensor, so either orients part of its normals inward.
    #[arg(long, value_enum)]
    pub normals_from: Option<NormalsFrom>,
    /// Tasks to run, comma-separated (default: every task of the database).
    #[arg(long, value_delimiter = ',')]
    pub tasks: Vec<String>,
    /// Fit weight (default: eps for complete views, as the paper's simulation;
    /// eps-sigma for partial views, as its robot experiment).
    #[arg(long, value_enum)]
    pub fit_weight: Option<FitWeightName>,
    /// Lowest palm centre above the table top (m). The paper's simulation had no
    /// workspace limits; the cell's planner uses the configured clearance (0.05 m).
    #[arg(long, default_value_t = 0.0)]
    pub palm_clearance_m: f64,
    /// Constrain the grasps to what the arm reaches (IK for the grasp and the
    /// pre-grasp), as the cell does; off in the paper's simulation.
    #[arg(long)]
    pub reach: bool,
    /// Epsilon difference below which our grasp and best single count as equal.
    #[arg(long, default_value_t = DEFAULT_EQUAL_TOLERANCE)]
    pub equal_tolerance: f64,
    /// Seed of placements, views and registration (printed with the results).
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Seeded placements of every test object (the paper: 1); more placements give
    /// more runs and steadier shares.
    #[arg(long, default_value_t = 1)]
    pub placements: usize,
    /// The paper's setting (issue 19): no retreat of a colliding hand, a colliding
    /// grasp scores -1 (unstable, Table 1) and collisions are counted per method;
    /// the paper's kernel scale s = b = 50 unless --paper-scale says otherwise, its
    /// weights, no reachability repair for any method (with --reach), and its
    /// one-sided fit score with poor registrations kept.
    #[arg(long)]
    pub paper: bool,
    /// Write the better / equal / worse bar chart (PNG) here.
    #[arg(long)]
    pub png: Option<PathBuf>,
    /// Print JSON: the tallies, and per target its pose, fits and every run.
    #[arg(long)]
    pub json: bool,
}

impl ExperimentArgs {
    /// The kernels' paper scale: `--paper-scale`, else with `--paper` the paper's
    /// simulation value, else none (the cell's own scales).
    pub fn kernel_scale(&self) -> Option<f64> {
        self.paper_scale
            .or(self.paper.then(|| PaperProtocol::Simulation.scale()))
    }
}

/// Options of `cell eval loo`.
#[derive(Debug, Args)]
pub struct LooArgs {
    /// The category (its database is <db-dir>/<category>): mug, bottle, hammer, knife.
    #[arg(long)]
    pub category: String,
    /// Only these models, comma-separated (a quick run on a few).
    #[arg(long, value_delimiter = ',')]
    pub models: Vec<String>,
    /// Experiment options.
    #[command(flatten)]
    pub experiment: ExperimentArgs,
}

/// Options of `cell eval cross`.
#[derive(Debug, Args)]
pub struct CrossArgs {
    /// The training category (its grasps are planned over), e.g. hammer.
    #[arg(long)]
    pub train: String,
    /// The test category (its models are the novel objects), e.g. knife.
    #[arg(long)]
    pub test: String,
    /// Experiment options.
    #[command(flatten)]
    pub experiment: ExperimentArgs,
}

/// Runs `cell eval ...`.
pub fn run(config: &Path, which: EvalCommand) -> anyhow::Result<ExitCode> {
    match which {
        EvalCommand::Loo(args) => loo(config, args),
        EvalCommand::Cross(args) => cross(config, args),
        EvalCommand::Novel(args) => novel(config, args),
    }
}

/// The kernels of `choices` (duplicates dropped, `all` expanded), with the paper's
/// scalar scale when given.
pub fn kernels(choices: &[KernelChoice], paper_scale: Option<f64>) -> anyhow::Result<Vec<Kernel>> {
    if let Some(s) = paper_scale {
        anyhow::ensure!(
            s.is_finite() && s > 0.0,
            "--paper-scale {s}: must be a finite number > 0"
        );
    }
    let laplace = paper_scale.map_or(Kernel::LAPLACE_DEFAULT, Kernel::paper_laplace);
    let gaussian_r = paper_scale.map_or(Kernel::GAUSSIAN_R_DEFAULT, Kernel::paper_gaussian_r);
    let mut out: Vec<Kernel> = Vec::new();
    for choice in choices {
        let add: &[Kernel] = match choice {
            KernelChoice::All => &[laplace, gaussian_r, Kernel::Gaussian],
            KernelChoice::Laplace => &[laplace],
            KernelChoice::GaussianR => &[gaussian_r],
            KernelChoice::Gaussian => &[Kernel::Gaussian],
        };
        for k in add {
            if !out.iter().any(|o| o.name() == k.name()) {
                out.push(*k);
            }
        }
    }
    anyhow::ensure!(!out.is_empty(), "--kernel: give at least one kernel");
    Ok(out)
}

/// Loads the database of `category` under `db_dir`; an unknown category names the
/// categories there are.
pub fn load_category_db(db_dir: &Path, category: &str) -> anyhow::Result<CategoryDb> {
    let dir = db_dir.join(category);
    if !dir.join(crate::category::DATABASE_FILE).is_file() {
        let mut known: Vec<String> = std::fs::read_dir(db_dir)
            .map(|entries| {
                entries
                    .filter_map(|e| e.ok())
                    .filter(|e| e.path().join(crate::category::DATABASE_FILE).is_file())
                    .map(|e| e.file_name().to_string_lossy().into_owned())
                    .collect()
            })
            .unwrap_or_default();
        known.sort();
        anyhow::bail!(
            "category {category:?}: no database {} (categories under {}: {})",
            dir.join(crate::category::DATABASE_FILE).display(),
            db_dir.display(),
            if known.is_empty() {
                "none".to_string()
            } else {
                known.join(", ")
            }
        );
    }
    Ok(crate::cell::load_category(db_dir, category)?)
}

/// What an experiment needs from the cell: the hand, the camera, the table and,
/// with `--reach`, the robot.
struct Cell {
    config: CellConfig,
    hand: HandModel,
    robot: Option<Robot>,
}

impl Cell {
    fn load(path: &Path, reach: bool) -> anyhow::Result<Cell> {
        let config = CellConfig::load(path)?;
        let hand = HandModel::load(&config)?;
        let robot = if reach {
            Some(Robot::load(&config)?)
        } else {
            None
        };
        Ok(Cell {
            config,
            hand,
            robot,
        })
    }

    /// The experiment's setup; the kernel of `plan` is replaced per run.
    fn setup(&self, args: &ExperimentArgs) -> anyhow::Result<Setup<'_>> {
        let c = &self.config;
        anyhow::ensure!(
            args.palm_clearance_m.is_finite(),
            "--palm-clearance-m {}: must be finite",
            args.palm_clearance_m
        );
        let view = match args.views {
            ViewChoice::Complete => ViewKind::Complete,
            ViewChoice::Partial => ViewKind::Partial,
        };
        let mut plan = PlanOptions::new(Kernel::LAPLACE_DEFAULT, c);
        plan.z_min_m = c.table.height_m + args.palm_clearance_m;
        if args.paper {
            // The paper's weights and no repair; the kernels come per run.
            PlanMode::Paper {
                protocol: PaperProtocol::Simulation,
            }
            .apply(&mut plan);
        }
        plan.weights.fit = match (args.fit_weight, view) {
            (Some(FitWeightName::Eps), _) | (None, ViewKind::Complete) => FitWeight::Eps,
            (Some(FitWeightName::EpsSigma), _) | (None, ViewKind::Partial) => FitWeight::EpsSigma,
        };
        // Test objects go where the camera looks (0.6 m in front of the base).
        let center = [0.6, 0.0];
        Ok(Setup {
            hand: &self.hand,
            camera: DepthCamera::from_config(&c.camera, c.base_from_camera()),
            table: TableBox::from(&c.table),
            region: PlacementRegion::around(center, c.table.height_m),
            view,
            complete_points: args.complete_points,
            plan,
            reach: self.robot.as_ref().map(|r| r as &dyn Reachability),
            equal_tolerance: args.equal_tolerance,
            seed: args.seed,
            placements: args.placements,
            paper: args.paper,
        })
    }

    /// The registration's viewpoint: `choice`, else the camera for partial views
    /// and a point above the object (`None`) for complete ones.
    fn viewpoint(&self, view: ViewKind, choice: Option<NormalsFrom>) -> Option<[f64; 3]> {
        let camera = match choice {
            Some(c) => c == NormalsFrom::Camera,
            None => view == ViewKind::Partial,
        };
        camera.then(|| {
            let eye = self.config.base_from_camera().translation.vector;
            [eye.x, eye.y, eye.z]
        })
    }
}

fn progress_bar(label: &str) -> ProgressBar {
    let bar = ProgressBar::new(0);
    bar.set_style(
        ProgressStyle::with_template("{prefix} [{bar:30}] {pos}/{len} {elapsed} (eta {eta})")
            .unwrap_or_else(|_| ProgressStyle::default_bar())
            .progress_chars("=> "),
    );
    bar.set_prefix(label.to_string());
    bar
}

/// The tally rows as a text table.
fn tally_table(rows: &[TallyRow]) -> String {
    let mut text = format!(
        "{:<8} {:<11} {:>4} {:>7} {:>7} {:>7} {:>8} {:>9} {:>9} {:>6} {:>6} {:>5} {:>6}\n",
        "task",
        "kernel",
        "runs",
        "better",
        "equal",
        "worse",
        "sign p",
        "eps",
        "eps 1",
        "FC%",
        "FC% 1",
        "coll",
        "coll 1"
    );
    for r in rows {
        let t = &r.tally;
        text += &format!(
            "{:<8} {:<11} {:>4} {:>6.1}% {:>6.1}% {:>6.1}% {:>8.2e} {:>9.4} {:>9.4} {:>5.0}% {:>5.0}% {:>5} {:>6}\n",
            r.task,
            r.kernel,
            t.runs,
            t.better_pct,
            t.equal_pct,
            t.worse_pct,
            t.sign_test_p,
            t.mean_epsilon,
            t.mean_epsilon_single,
            t.force_closure_pct,
            t.force_closure_single_pct,
            r.collisions,
            r.collisions_single
        );
    }
    text += "(sign p: two-sided exact sign test, better against worse; eps: mean epsilon of our grasps; eps 1 / FC% 1 / coll 1: of best single; FC: force closure; coll: open hand colliding at the grasp)\n";
    text
}

fn registration_text(r: &crate::eval::experiment::RegistrationStats) -> String {
    format!(
        "registration: {}/{} models registered; from the true pose: median {:.1} mm, tilt {:.1} deg, yaw {:.1} deg; tilt > 30 deg: {}, yaw > 30 deg: {}\n",
        r.registered,
        r.attempted,
        r.median_offset_mm,
        r.median_tilt_deg,
        r.median_yaw_deg,
        r.tilt_over_30_deg,
        r.yaw_over_30_deg
    ) + &yaw_text(r)
}

/// The yaw error distribution, and its share over 30 degrees where the handle is
/// visible.
fn yaw_text(r: &crate::eval::experiment::RegistrationStats) -> String {
    use crate::eval::experiment::YAW_BIN_EDGES_DEG;
    let mut lower = 0.0;
    let bins: Vec<String> = YAW_BIN_EDGES_DEG
        .iter()
        .zip(r.yaw_bins)
        .map(|(&edge, n)| {
            let bin = format!("{lower:.0}-{edge:.0}: {n}");
            lower = edge;
            bin
        })
        .collect();
    let share = 100.0 * r.handle_visible_yaw_over_30_deg as f64 / r.handle_visible.max(1) as f64;
    format!(
        "yaw error (deg) {}; handle visible in {} fits, yaw > 30 deg in {} ({share:.0} %)\n",
        bins.join(", "),
        r.handle_visible,
        r.handle_visible_yaw_over_30_deg
    )
}

/// What both experiments' text reports end with: registration, tallies, skipped
/// targets, and the chart's path.
fn common_text(
    registration: &crate::eval::experiment::RegistrationStats,
    rows: &[TallyRow],
    targets: &[crate::eval::TargetReport],
    png: Option<&Path>,
) -> String {
    let mut text = registration_text(registration);
    text += &tally_table(rows);
    text += &skipped_text(targets);
    if let Some(p) = png {
        text += &format!("chart: {}\n", p.display());
    }
    text
}

fn skipped_text(targets: &[crate::eval::TargetReport]) -> String {
    let mut text = String::new();
    for t in targets {
        for s in &t.skipped {
            text += &format!(
                "skipped: {}{}: {}\n",
                s.target,
                s.task
                    .as_deref()
                    .map(|task| format!(" task {task}"))
                    .unwrap_or_default(),
                s.reason
            );
        }
    }
    text
}

/// How collisions were scored.
fn scoring(paper: bool) -> &'static str {
    if paper {
        "paper (no retreat; a colliding grasp scores -1)"
    } else {
        "cell (a colliding hand backs off up to the database's retreat; collisions score 0)"
    }
}

fn kernel_names(kernels: &[Kernel]) -> String {
    kernels
        .iter()
        .map(|k| k.name())
        .collect::<Vec<_>>()
        .join(", ")
}

/// Runs `cell eval loo`.
pub fn loo(config: &Path, args: LooArgs) -> anyhow::Result<ExitCode> {
    let e = &args.experiment;
    let kernels = kernels(&e.kernel, e.kernel_scale())?;
    let mut db = load_category_db(&e.db_dir, &args.category)?;
    if !args.models.is_empty() {
        db = subset(&db, &args.models)?;
    }
    let cell = Cell::load(config, e.reach)?;
    let setup = cell.setup(e)?;
    // Bad requests fail before the models are prepared for registration.
    setup.validate()?;
    crate::eval::check_request(&db, &e.tasks, &kernels)?;
    if db.file.models.len() < 2 {
        return Err(crate::eval::EvalError::TooFewModels {
            database: db.dir.display().to_string(),
            count: db.file.models.len(),
        }
        .into());
    }
    tracing::info!(seed = e.seed, category = %args.category, "leave-one-out");
    let started = Instant::now();
    let registrar = CategoryRegistrar::new(&db, cell.viewpoint(setup.view, e.normals_from))
        .with_context(|| format!("{}: preparing the models", db.dir.display()))?
        .for_view(setup.view)
        .paper(e.paper);
    let bar = progress_bar(&format!("loo {}", args.category));
    let report = leave_one_out(&setup, &db, &e.tasks, &kernels, &registrar, Some(&bar));
    bar.finish_and_clear();
    let report = report?;
    let title = format!(
        "LEAVE-ONE-OUT {} ({} VIEWS, SEED {})",
        report.category.to_uppercase(),
        report.view.name().to_uppercase(),
        report.seed
    );
    chart_and_print(e, &report, &report.rows, &title, started, loo_text)
}

/// Draws the verdict chart titled `title` (with `--png`), then prints `report` with
/// the wall-clock time since `started`: JSON, or `text`.
fn chart_and_print<T: serde::Serialize>(
    e: &ExperimentArgs,
    report: &T,
    rows: &[TallyRow],
    title: &str,
    started: Instant,
    text: impl FnOnce(&T, f64, Option<&Path>) -> String,
) -> anyhow::Result<ExitCode> {
    let seconds = started.elapsed().as_secs_f64();
    if let Some(png) = &e.png {
        write_verdict_chart(png, title, rows).with_context(|| format!("{}", png.display()))?;
    }
    let out = Timed { report, seconds };
    emit(e.json, &out, |o| {
        text(o.report, o.seconds, e.png.as_deref())
    })?;
    Ok(ExitCode::SUCCESS)
}

/// A report with the wall-clock time it took.
#[derive(serde::Serialize)]
struct Timed<'a, T> {
    #[serde(flatten)]
    report: &'a T,
    /// Wall-clock time of the experiment (s), registration model preparation included.
    seconds: f64,
}

fn loo_text(r: &LooReport, seconds: f64, png: Option<&Path>) -> String {
    let mut text = format!(
        "leave-one-out: {} ({}), {} models x {} placements, tasks {}; kernels {}; {} views; reach {}; seed {}\n",
        r.category,
        r.database,
        r.models,
        r.placements,
        r.tasks.join(", "),
        kernel_names(&r.kernels),
        r.view.name(),
        if r.reachability { "on" } else { "off" },
        r.seed
    );
    text += &format!(
        "{} runs simulated in {:.1} s; equal within epsilon {}; scoring: {}\n",
        r.runs,
        seconds,
        r.equal_tolerance,
        scoring(r.paper)
    );
    text += &common_text(&r.registration, &r.rows, &r.targets, png);
    text
}

/// Runs `cell eval cross`.
pub fn cross(config: &Path, args: CrossArgs) -> anyhow::Result<ExitCode> {
    let e = &args.experiment;
    let kernels = kernels(&e.kernel, e.kernel_scale())?;
    let train = load_category_db(&e.db_dir, &args.train)?;
    let test = load_category_db(&e.db_dir, &args.test)?;
    let cell = Cell::load(config, e.reach)?;
    let setup = cell.setup(e)?;
    setup.validate()?;
    crate::eval::check_request(&train, &e.tasks, &kernels)?;
    if test.file.models.is_empty() {
        return Err(crate::eval::EvalError::EmptyDatabase {
            database: test.dir.display().to_string(),
        }
        .into());
    }
    tracing::info!(seed = e.seed, train = %args.train, test = %args.test, "cross-category");
    let started = Instant::now();
    let registrar = CategoryRegistrar::new(&train, cell.viewpoint(setup.view, e.normals_from))
        .with_context(|| format!("{}: preparing the models", train.dir.display()))?
        .for_view(setup.view)
        .paper(e.paper);
    let bar = progress_bar(&format!("cross {} -> {}", args.train, args.test));
    let report = cross_category(
        &setup,
        &train,
        &test,
        &e.tasks,
        &kernels,
        &registrar,
        Some(&bar),
    );
    bar.finish_and_clear();
    let report = report?;
    let title = format!(
        "CROSS-CATEGORY {} TO {} (SEED {})",
        args.train.to_uppercase(),
        args.test.to_uppercase(),
        report.seed
    );
    chart_and_print(e, &report, &report.rows, &title, started, cross_text)
}

fn cross_text(r: &CrossReport, seconds: f64, png: Option<&Path>) -> String {
    let mut text = format!(
        "cross-category: train {} ({}), test {} ({}); tasks {}; {} views; reach {}; seed {}\n",
        r.train_category,
        r.train,
        r.test_category,
        r.test,
        r.tasks.join(", "),
        r.view.name(),
        if r.reachability { "on" } else { "off" },
        r.seed
    );
    text += &format!(
        "{} targets ({} placements each) in {:.1} s; scoring: {}\n",
        r.targets.len(),
        r.placements,
        seconds,
        scoring(r.paper)
    );
    text += &format!("{:<12} {:<6}", "test object", "task");
    for k in &r.kernels {
        text += &format!(" {:>10}", k.name());
    }
    text += &format!(" {:>11}  {}\n", "best single", "(from model)");
    for row in &r.table {
        let name = if r.placements > 1 {
            format!("{} #{}", row.target, row.placement)
        } else {
            row.target.clone()
        };
        text += &format!("{:<12} {:<6}", name, row.task);
        for k in &r.kernels {
            let eps = row
                .epsilon
                .iter()
                .find(|(name, _)| name == k.name())
                .map(|(_, e)| format!("{e:>10.4}"))
                .unwrap_or_else(|| format!("{:>10}", "-"));
            text += &format!(" {eps}");
        }
        text += &format!(
            " {:>11.4}  ({})\n",
            row.epsilon_single, row.best_single_model
        );
    }
    text += "(epsilon of the grasp simulated on the test object; 0 = not force closure or a collision)\n";
    text += &common_text(&r.registration, &r.rows, &r.targets, png);
    text
}

/// The objects of `cell eval novel`: the user's (`--objects`) or procedural novel
/// instances of each category.
fn novel_objects(
    args: &NovelArgs,
    dbs: &mut crate::cell::plan::Databases,
) -> anyhow::Result<Vec<NovelObject>> {
    if let Some(dir) = &args.objects {
        let objects = crate::eval::objects::load_objects(dir)?;
        return Ok(objects.iter().map(NovelObject::from_user).collect());
    }
    anyhow::ensure!(args.instances > 0, "--instances must be at least 1");
    let mut out = Vec::new();
    for name in &args.categories {
        let category: Category = name.parse()?;
        let db = dbs.get(name)?.clone();
        for i in 0..args.instances {
            out.push(NovelObject::procedural(
                args.family.into(),
                category,
                args.seed,
                i as u64,
                &db,
            )?);
        }
    }
    Ok(out)
}

/// Runs `cell eval novel`.
pub fn novel(config_path: &Path, args: NovelArgs) -> anyhow::Result<ExitCode> {
    let methods = if args.methods.is_empty() {
        default_methods()
    } else {
        args.methods.clone()
    };
    let lab = args.lab.errors()?;
    let config = CellConfig::load(config_path)?;
    let mut dbs = crate::cell::plan::Databases::new(&args.db_dir);
    let objects = novel_objects(&args, &mut dbs)?;
    let mut categories: Vec<Category> = objects.iter().map(|o| o.category).collect();
    categories.sort_by_key(|c| c.name());
    categories.dedup();
    let started = Instant::now();
    let mut models = std::collections::HashMap::new();
    for category in categories {
        models.insert(
            category,
            CategoryModels::load(&mut dbs, category, &args.tasks)?,
        );
    }
    let robot = std::sync::Arc::new(Robot::load(&config)?);
    let hand = HandModel::load(&config)?;
    let observer = crate::sim::observer::Observer::new(&config)?;
    let cell = NovelCell {
        config: &config,
        robot,
        hand: &hand,
        observer: &observer,
    };
    let options = NovelOptions {
        placements: args.placements,
        seed: args.seed,
        methods,
        tasks: args.tasks.clone(),
        lab,
        paper: args.paper,
    };
    tracing::info!(seed = args.seed, objects = objects.len(), "novel objects");
    if !args.json {
        eprintln!(
            "{} objects x {} placements; {}",
            objects.len(),
            args.placements,
            lab.text()
        );
    }
    let bar = if args.json {
        ProgressBar::hidden()
    } else {
        progress_bar("novel")
    };
    let report = run_novel(&cell, &mut dbs, &models, &objects, &options, Some(&bar));
    bar.finish_and_clear();
    let report = report?;
    let seconds = started.elapsed().as_secs_f64();
    if let Some(png) = &args.png {
        let title = format!(
            "NOVEL OBJECTS ({} PLACEMENTS, SEED {}{})",
            report.placements,
            report.seed,
            if report.paper { ", PAPER" } else { "" }
        );
        write_grade_chart(png, &title, &report.rows)
            .with_context(|| format!("{}", png.display()))?;
    }
    let out = Timed {
        report: &report,
        seconds,
    };
    emit(args.json, &out, |o| {
        let mut text = novel_text(o.report, o.seconds);
        if let Some(p) = &args.png {
            text += &format!("chart: {}\n", p.display());
        }
        text
    })?;
    Ok(ExitCode::SUCCESS)
}

/// The rows of a novel-object report as a text table.
fn novel_text(r: &NovelReport, seconds: f64) -> String {
    let mut text = format!(
        "novel objects: {} objects x {} placements, tasks {}; methods {}; seed {}{}\n",
        r.objects.len(),
        r.placements,
        r.tasks.join(", "),
        r.methods.join(", "),
        r.seed,
        if r.paper { "; paper setting" } else { "" }
    );
    text += &format!(
        "{}; drawn hand-eye error {:.1} mm / {:.2} deg; approach to contact: {}\n",
        r.lab.text(),
        nalgebra::Vector3::new(
            r.hand_eye_error[0],
            r.hand_eye_error[1],
            r.hand_eye_error[2]
        )
        .norm()
            * 1e3,
        nalgebra::Vector3::new(
            r.hand_eye_error[3],
            r.hand_eye_error[4],
            r.hand_eye_error[5]
        )
        .norm()
        .to_degrees(),
        if r.approach_to_contact { "on" } else { "off" }
    );
    text += &format!("{} trials in {:.1} s\n", r.trials.len(), seconds);
    text += &format!(
        "{:<12} {:<12} {:>6} {:>8} {:>8} {:>8} {:>5} {:>8} {:>6} {:>4} {:>6} {:>6} {:>5} {:>5} {:>7}  {}\n",
        "task",
        "method",
        "trials",
        "success",
        "partial",
        "failure",
        "unrch",
        "succ|rch",
        "phys%",
        "tbl",
        "stat%",
        "FC%",
        "agree",
        "coll",
        "eps",
        "failure causes"
    );
    for row in &r.rows {
        let causes: Vec<String> = row.causes.iter().map(|(c, n)| format!("{c} {n}")).collect();
        text += &format!(
            "{:<12} {:<12} {:>6} {:>7.0}% {:>7.0}% {:>7.0}% {:>5} {:>7.0}% {:>5.0}% {:>4} {:>5.0}% {:>5.0}% {:>5} {:>5} {:>7.4}  {}\n",
            row.task,
            row.method,
            row.trials,
            row.success_pct,
            row.partial_pct,
            row.failure_pct,
            row.out_of_reach,
            row.success_in_reach_pct,
            row.physics_success_pct,
            row.physics_success_in_table,
            row.static_success_pct,
            row.force_closure_pct,
            row.verdicts.agree,
            row.collisions,
            row.mean_epsilon,
            causes.join(", ")
        );
    }
    let mut verdicts = crate::sim::observer::Agreement::default();
    for t in &r.trials {
        verdicts.add(t.physics_grade, t.static_grade);
    }
    text += &verdicts.to_text();
    text += "(success / partial / failure: the observer's grades; unrch: trials whose task no example grasp reaches at the object's true pose (any method fails them), succ|rch: success over the others; phys% / stat%: successes by the rigid-body lift test and by static epsilon, tbl: physics successes whose hand went 1 mm or more into the table while closing (the solver's give), agree: trials both grade alike; FC: force closure; coll: open hand colliding at the executed pose)\n";
    text
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn kernel_choices_expand_in_order_without_duplicates() {
        let k = kernels(&[KernelChoice::All], None).unwrap();
        let names: Vec<&str> = k.iter().map(|k| k.name()).collect();
        assert_eq!(names, ["laplace", "gaussian-r", "gaussian"]);
        let k = kernels(
            &[
                KernelChoice::Gaussian,
                KernelChoice::All,
                KernelChoice::Gaussian,
            ],
            Some(50.0),
        )
        .unwrap();
        let names: Vec<&str> = k.iter().map(|k| k.name()).collect();
        assert_eq!(names, ["gaussian", "laplace", "gaussian-r"]);
        assert_eq!(k[1], Kernel::paper_laplace(50.0));
        assert!(kernels(&[KernelChoice::Laplace], Some(f64::NAN)).is_err());
        assert!(kernels(&[], None).is_err());
    }

    #[test]
    fn an_unknown_category_names_the_known_ones() {
        let db_dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("db");
        let e = load_category_db(&db_dir, "teapot").unwrap_err().to_string();
        assert!(
            e.contains("\"teapot\"") && e.contains("bottle, hammer, knife, mug"),
            "{e}"
        );
        let e = load_category_db(&db_dir, "../db/mug").unwrap_err();
        assert!(format!("{e:#}").contains("not a category name"), "{e:#}");
    }
}
