//! `cell eval loo` and `cell eval cross`: the paper's simulation experiments
//! (Nikandrova & Kyrki 2015, §4.3 Figures 5 and 6, §5 Table 1) on the shipped
//! category databases, each grasp run in the grasp simulator on the test object.

use super::emit;
use super::plan::FitWeightName;
use crate::category::CategoryDb;
use crate::config::CellConfig;
use crate::eval::chart::write_verdict_chart;
use crate::eval::experiment::Setup;
use crate::eval::loo::TallyRow;
use crate::eval::{
    cross_category, leave_one_out, subset, CategoryRegistrar, CrossReport, LooReport,
    PlacementRegion, ViewKind, DEFAULT_EQUAL_TOLERANCE,
};
use crate::plan::{FitWeight, Kernel, PlanOptions, Reachability};
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
    /// Write the better / equal / worse bar chart (PNG) here.
    #[arg(long)]
    pub png: Option<PathBuf>,
    /// Print JSON: the tallies, and per target its pose, fits and every run.
    #[arg(long)]
    pub json: bool,
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
        "{:<8} {:<11} {:>4} {:>7} {:>7} {:>7} {:>9} {:>9} {:>6} {:>6}\n",
        "task", "kernel", "runs", "better", "equal", "worse", "eps", "eps 1", "FC%", "FC% 1"
    );
    for r in rows {
        let t = &r.tally;
        text += &format!(
            "{:<8} {:<11} {:>4} {:>6.1}% {:>6.1}% {:>6.1}% {:>9.4} {:>9.4} {:>5.0}% {:>5.0}%\n",
            r.task,
            r.kernel,
            t.runs,
            t.better_pct,
            t.equal_pct,
            t.worse_pct,
            t.mean_epsilon,
            t.mean_epsilon_single,
            t.force_closure_pct,
            t.force_closure_single_pct
        );
    }
    text += "(eps: mean epsilon of our grasps; eps 1 / FC% 1: of best single; FC: force closure)\n";
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
    let kernels = kernels(&e.kernel, e.paper_scale)?;
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
        .for_view(setup.view);
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
        "{} runs simulated in {:.1} s; equal within epsilon {}\n",
        r.runs, seconds, r.equal_tolerance
    );
    text += &common_text(&r.registration, &r.rows, &r.targets, png);
    text
}

/// Runs `cell eval cross`.
pub fn cross(config: &Path, args: CrossArgs) -> anyhow::Result<ExitCode> {
    let e = &args.experiment;
    let kernels = kernels(&e.kernel, e.paper_scale)?;
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
        .for_view(setup.view);
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
        "{} targets ({} placements each) in {:.1} s\n",
        r.targets.len(),
        r.placements,
        seconds
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
