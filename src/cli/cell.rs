//! `cell demo`, `cell run`, `cell trial` and `cell campaign`: the cell as processes.

use super::emit;
use crate::cell::campaign::{
    graded_trials, link_fault_of, CampaignSpec, NovelObject, PlannedTrial, TaskReport, LINK_FAULTS,
};
use crate::cell::harness::{novel_object, placement_rng, random_placement, Cell, HarnessOptions};
use crate::cell::plan::{Databases, METHODS};
use crate::cell::setup::{ObjectSource, TrialSetup};
use crate::cell::{span_ms, stop_requested, StageArgs, SYSTEM_IPC_PREFIX};
use crate::config::CellConfig;
use crate::fsio::TempDir;
use crate::ipc::{monotonic_now_ns, Domain, Stage, TrialRequest, TrialResult};
use crate::mesh::procedural::Category;
use crate::sim::lab::{LabDraw, LabErrors};
use crate::stats::finite_median;
use crate::trial::TrialLog;
use anyhow::Context;
use clap::Args;
use indicatif::{ProgressBar, ProgressStyle};
use serde::Serialize;
use std::collections::HashSet;
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::time::Duration;

/// Where the cell's IPC lives and its run directory (shared by the cell commands).
#[derive(Debug, Clone, Args)]
pub struct CellLocation {
    /// Cell instance name.
    #[arg(long, default_value = crate::cell::DEFAULT_INSTANCE)]
    pub instance: String,
    /// Root directory of the IPC domain (default: /run/graspcell when writable, else
    /// $XDG_RUNTIME_DIR/graspcell, else /tmp/graspcell-UID).
    #[arg(long, value_name = "DIR")]
    pub ipc_root: Option<PathBuf>,
    /// Directory of per-trial setup files and the default trial log.
    #[arg(long, default_value = "run")]
    pub run_dir: PathBuf,
}

impl CellLocation {
    fn stage_args(&self, config: &Path) -> StageArgs {
        StageArgs {
            config: config.to_path_buf(),
            instance: self.instance.clone(),
            ipc_root: self.ipc_root.clone(),
            ipc_prefix: SYSTEM_IPC_PREFIX.into(),
            run_dir: self.run_dir.clone(),
        }
    }
}

/// What every trial of a demo or campaign asks for.
#[derive(Debug, Clone, Args)]
pub struct TrialKind {
    /// Object category (a database under --db-dir).
    #[arg(long, default_value = "mug")]
    pub category: String,
    /// Directory of the category databases.
    #[arg(long, default_value = "db")]
    pub db_dir: PathBuf,
}

/// The simulated world of a demo or campaign: which novel objects, and the lab's
/// errors.
#[derive(Debug, Clone, Args)]
pub struct WorldArgs {
    /// Your own objects: a directory of OBJ/STL/PLY meshes with an `objects.toml`
    /// naming each file's category and scale (those of --category are used).
    #[arg(long, value_name = "DIR")]
    pub objects: Option<PathBuf>,
    /// Where procedural novel objects come from.
    #[arg(long, value_enum, default_value_t = super::eval::FamilyChoice::HeldApart)]
    pub family: super::eval::FamilyChoice,
    /// The lab's errors.
    #[command(flatten)]
    pub lab: super::eval::LabArgs,
}

/// The novel objects of a demo or campaign, in order, and the lab's errors.
struct World {
    objects: Vec<NovelObject>,
    lab: LabErrors,
}

impl World {
    /// `count` novel objects of `category` (the user's: all of that category).
    fn new(
        args: &WorldArgs,
        category: Category,
        count: usize,
        seed: u64,
        db: &crate::category::CategoryDb,
    ) -> anyhow::Result<World> {
        let lab = args.lab.errors()?;
        let objects = match &args.objects {
            Some(dir) => {
                if !dir.is_dir() && dir.to_string_lossy().parse::<u64>().is_ok() {
                    anyhow::bail!(
                        "--objects {}: takes a directory of meshes; the number of novel objects is --instances",
                        dir.display()
                    );
                }
                let mine: Vec<_> = crate::eval::objects::load_objects(dir)?
                    .into_iter()
                    .filter(|o| o.category == category)
                    .collect();
                anyhow::ensure!(
                    !mine.is_empty(),
                    "{}: no object of category {category}",
                    dir.join(crate::eval::objects::MANIFEST_FILE).display()
                );
                mine.into_iter().map(NovelObject::from_user).collect()
            }
            None => NovelObject::procedural(args.family.into(), category, seed, count, db),
        };
        Ok(World { objects, lab })
    }

    /// Object `i` (cycling through the user's objects).
    fn object(&self, i: usize) -> &NovelObject {
        &self.objects[i % self.objects.len()]
    }
}

/// Options of `cell demo`.
#[derive(Debug, Args)]
pub struct DemoArgs {
    /// Trials to run, each on a new novel object at a random placement.
    #[arg(long, default_value_t = 5)]
    pub trials: usize,
    #[command(flatten)]
    pub kind: TrialKind,
    /// Task (`top`, `side`, `handle` for mugs).
    #[arg(long, default_value = "top")]
    pub task: String,
    /// The novel objects and the lab's errors.
    #[command(flatten)]
    pub world: WorldArgs,
    /// Planning method: laplace, gaussian, gaussian-r, best-single (the paper's) or
    /// laplace-sim (Laplace refined in the grasp simulator).
    #[arg(long, default_value = "laplace")]
    pub method: String,
    /// Seed of objects, placements and noise.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Keep setup files and the trial log here (default: a temporary directory,
    /// removed at the end).
    #[arg(long)]
    pub run_dir: Option<PathBuf>,
    /// How long the executor holds each lifted object (s).
    #[arg(long, default_value_t = 0.3)]
    pub hold_s: f64,
    /// Who grades: the physics lift test or static epsilon (both verdicts are logged).
    #[arg(long, value_enum, default_value_t = crate::cell::log::ObserverKind::Physics)]
    pub observer: crate::cell::log::ObserverKind,
    /// Repeats of a trial that ended on a link fault (the robot dropped to monitor
    /// mode, or its measurements stopped): a lab resets the robot and runs it
    /// again, as `cell campaign` does; the summary counts the latest run.
    #[arg(long, default_value_t = 2)]
    pub link_fault_repeats: u32,
    /// Print one JSON document instead of lines.
    #[arg(long)]
    pub json: bool,
}

/// Options of `cell campaign`.
#[derive(Debug, Args)]
pub struct CampaignArgs {
    #[command(flatten)]
    pub kind: TrialKind,
    /// Tasks, comma-separated; each is its own campaign and report row (default:
    /// every task of the category's database, e.g. top, side and handle for mugs).
    #[arg(long = "task", value_delimiter = ',')]
    pub tasks: Vec<String>,
    /// The novel objects and the lab's errors.
    #[command(flatten)]
    pub world: WorldArgs,
    /// Novel objects (procedural; with --objects DIR, the directory's objects).
    #[arg(long, default_value_t = 6)]
    pub instances: usize,
    /// Placements per object.
    #[arg(long, default_value_t = 5)]
    pub placements: u32,
    /// Methods, comma-separated; every one runs on every object and placement.
    #[arg(
        long,
        value_delimiter = ',',
        default_value = "best-single,gaussian-r,laplace"
    )]
    pub methods: Vec<String>,
    /// The trial log (a campaign already in it is resumed: graded trials are kept).
    #[arg(long, default_value = "run/campaign.sqlite")]
    pub log: PathBuf,
    /// Campaign id (default: `<category>-<task>-seed<seed>`).
    #[arg(long)]
    pub campaign: Option<String>,
    /// Seed of objects, placements and noise.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Directory of setup files.
    #[arg(long, default_value = "run/campaign")]
    pub run_dir: PathBuf,
    /// How long the executor holds each lifted object (s).
    #[arg(long, default_value_t = 0.3)]
    pub hold_s: f64,
    /// Who grades: the physics lift test or static epsilon (both verdicts are logged).
    #[arg(long, value_enum, default_value_t = crate::cell::log::ObserverKind::Physics)]
    pub observer: crate::cell::log::ObserverKind,
    /// Rounds of repeats of trials that ended on a link fault (the robot dropped to
    /// monitor mode, or its measurements stopped): a lab resets the robot and runs
    /// such a trial again; the latest counts in the report.
    #[arg(long, default_value_t = 2)]
    pub link_fault_repeats: u32,
    /// The paper's robot protocol (issue 19) for perception and planning: one-sided
    /// fit score with poor fits kept, kernel scale s = b = 700, the paper's weights,
    /// and no reachability repair for any method (unreachable grasps fail as
    /// reachability and are counted apart). Default campaign ids end in `-paper`.
    #[arg(long)]
    pub paper: bool,
    /// Print one JSON document instead of lines.
    #[arg(long)]
    pub json: bool,
}

/// Options of `cell run`.
#[derive(Debug, Args)]
pub struct RunArgs {
    #[command(flatten)]
    pub location: CellLocation,
    /// Directory of the category databases.
    #[arg(long, default_value = "db")]
    pub db_dir: PathBuf,
    /// The trial log (default: `<run dir>/trials.sqlite`).
    #[arg(long)]
    pub log: Option<PathBuf>,
    /// How long the executor holds each lifted object (s).
    #[arg(long, default_value_t = 2.0)]
    pub hold_s: f64,
}

/// Options of `cell trial`.
#[derive(Debug, Args)]
pub struct TrialArgs {
    #[command(flatten)]
    pub location: CellLocation,
    /// Object category.
    #[arg(long)]
    pub category: String,
    /// Task.
    #[arg(long)]
    pub task: String,
    /// Planning method: laplace, gaussian, gaussian-r, best-single (the paper's) or
    /// laplace-sim (Laplace refined in the grasp simulator).
    #[arg(long, default_value = "laplace")]
    pub method: String,
    /// With a simulated camera: seed of the novel object, its placement and noise.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Longest wait for the result (s).
    #[arg(long, default_value_t = 180.0)]
    pub timeout_s: f64,
    /// Print JSON.
    #[arg(long)]
    pub json: bool,
}

/// One trial's line of output.
#[derive(Debug, Clone, Serialize)]
pub struct TrialLine {
    /// Trial id.
    pub trial_id: u64,
    /// Object name.
    pub object: String,
    /// Placement index.
    pub placement: u32,
    /// Object position x y (m) and yaw (rad).
    pub placement_xy_yaw: [f64; 3],
    /// Task.
    pub task: String,
    /// Method.
    pub method: String,
    /// The lab's errors in this trial (hand–eye error and joint errors).
    pub lab: Option<LabDraw>,
    /// Grade (`success`, `partial`, `failure`), or `lost` when the log died.
    pub grade: String,
    /// Cause of a non-success.
    pub cause: Option<String>,
    /// Snapshot to the first grasp command (ms).
    pub snapshot_to_grasp_command_ms: f64,
    /// Request to snapshot published (ms).
    pub capture_ms: f64,
    /// Snapshot to fits (ms).
    pub perceive_ms: f64,
    /// Fits to plan (ms).
    pub plan_ms: f64,
    /// Plan to the end of execution (ms).
    pub execute_ms: f64,
    /// Request to result (ms).
    pub total_ms: f64,
}

impl TrialLine {
    fn new(
        setup: &TrialSetup,
        task: &str,
        method: &str,
        result: Option<&TrialResult>,
    ) -> TrialLine {
        let pose = &setup.placement.base_from_object;
        let yaw = pose.rpy.map_or(0.0, |r| r[2]);
        let ms = |s: f64| s * 1e3;
        let (grade, cause, t) = match result {
            Some(r) => {
                let grade = r
                    .grade()
                    .map_or("?".into(), |g| format!("{g:?}").to_lowercase());
                let cause = r
                    .cause()
                    .ok()
                    .filter(|c| *c != crate::ipc::FailureCause::None)
                    .map(|c| format!("{c:?}"));
                (grade, cause, r.timings)
            }
            None => ("lost".to_string(), None, crate::ipc::Timings::default()),
        };
        TrialLine {
            trial_id: setup.trial_id,
            object: setup.object.name.clone(),
            placement: setup.placement.index,
            placement_xy_yaw: [pose.xyz[0], pose.xyz[1], yaw],
            task: task.to_string(),
            method: method.to_string(),
            lab: setup.lab,
            grade,
            cause,
            snapshot_to_grasp_command_ms: ms(t.snapshot_to_grasp_command_s),
            capture_ms: ms(t.capture_s),
            perceive_ms: ms(t.perceive_s),
            plan_ms: ms(t.plan_s),
            execute_ms: ms(t.execute_s),
            total_ms: ms(t.total_s),
        }
    }

    fn text(&self) -> String {
        let cause = self
            .cause
            .as_ref()
            .map_or(String::new(), |c| format!(" ({c})"));
        let command_ms = self.snapshot_to_grasp_command_ms - self.perceive_ms - self.plan_ms;
        let lab = self
            .lab
            .map_or(String::new(), |l| format!("  [lab: {}]", l.text()));
        // No grasp command (nothing planned): a dash, not NaN.
        let or_dash = |ms: f64| {
            if ms.is_finite() {
                format!("{ms:.0}")
            } else {
                "-".to_string()
            }
        };
        format!(
            "trial {} {} #{} at ({:.3}, {:.3}) yaw {:+.2} {} {}: {}{}  snapshot->grasp command {} ms [perceive {:.0}, plan {:.0}, to command {}; capture {:.0}]  execute {:.1} s{lab}",
            self.trial_id,
            self.object,
            self.placement,
            self.placement_xy_yaw[0],
            self.placement_xy_yaw[1],
            self.placement_xy_yaw[2],
            self.task,
            self.method,
            self.grade,
            cause,
            or_dash(self.snapshot_to_grasp_command_ms),
            self.perceive_ms,
            self.plan_ms,
            or_dash(command_ms),
            self.capture_ms,
            self.execute_ms * 1e-3
        )
    }
}

/// Counts and the median end-to-end time of a set of trials.
#[derive(Debug, Clone, Serialize)]
pub struct Summary {
    /// Trials run.
    pub trials: usize,
    /// Graded success.
    pub success: usize,
    /// Graded partial.
    pub partial: usize,
    /// Graded failure.
    pub failure: usize,
    /// Results lost (the log stage died).
    pub lost: usize,
    /// Trials whose grasp was commanded (the others have no command time).
    pub commanded: usize,
    /// Median snapshot-to-grasp-command time over the commanded trials (ms).
    pub median_snapshot_to_grasp_command_ms: Option<f64>,
    /// Median perception time (ms).
    pub median_perceive_ms: Option<f64>,
    /// Median planning time (ms).
    pub median_plan_ms: Option<f64>,
}

impl Summary {
    fn of(lines: &[TrialLine]) -> Summary {
        let count = |g: &str| lines.iter().filter(|l| l.grade == g).count();
        Summary {
            trials: lines.len(),
            success: count("success"),
            partial: count("partial"),
            failure: count("failure"),
            lost: count("lost"),
            commanded: lines
                .iter()
                .filter(|l| l.snapshot_to_grasp_command_ms.is_finite())
                .count(),
            median_snapshot_to_grasp_command_ms: finite_median(
                lines.iter().map(|l| l.snapshot_to_grasp_command_ms),
            ),
            median_perceive_ms: finite_median(lines.iter().map(|l| l.perceive_ms)),
            median_plan_ms: finite_median(lines.iter().map(|l| l.plan_ms)),
        }
    }

    fn text(&self) -> String {
        let ms = |v: Option<f64>| v.map_or("-".to_string(), |v| format!("{v:.0} ms"));
        format!(
            "{} trials: {} success, {} partial, {} failure{}; median snapshot->grasp command {} over {} commanded (perceive {}, plan {})\n",
            self.trials,
            self.success,
            self.partial,
            self.failure,
            if self.lost > 0 {
                format!(", {} lost", self.lost)
            } else {
                String::new()
            },
            ms(self.median_snapshot_to_grasp_command_ms),
            self.commanded,
            ms(self.median_perceive_ms),
            ms(self.median_plan_ms)
        )
    }
}

pub(super) fn check_method(method: &str) -> anyhow::Result<()> {
    anyhow::ensure!(
        METHODS.contains(&method),
        "--method {method:?}: unknown (use {})",
        METHODS.join(", ")
    );
    Ok(())
}

pub(super) fn progress(total: u64, json: bool) -> ProgressBar {
    let bar = if json {
        ProgressBar::hidden()
    } else {
        ProgressBar::new(total)
    };
    bar.set_style(
        ProgressStyle::with_template("{prefix} [{bar:30}] {pos}/{len} {elapsed} {msg}")
            .unwrap_or_else(|_| ProgressStyle::default_bar()),
    );
    bar.set_prefix("trials");
    bar
}

/// The run directory asked for, or (without `--run-dir`) a temporary one, removed
/// when the returned guard drops.
pub(super) fn run_dir_or_temp(
    asked: Option<&Path>,
    tag: &str,
) -> anyhow::Result<(PathBuf, Option<TempDir>)> {
    Ok(match asked {
        Some(dir) => (dir.to_path_buf(), None),
        None => {
            let temp =
                TempDir::new(tag).with_context(|| format!("creating the {tag}'s run directory"))?;
            (temp.to_path_buf(), Some(temp))
        }
    })
}

/// A fresh isolated domain and run directory for one demo or campaign.
fn private_domain(tag: &str) -> anyhow::Result<crate::ipc::domain::TemporaryDomain> {
    Ok(Domain::temporary(tag)?)
}

/// Runs `cell demo`.
pub fn demo(config_path: &Path, args: DemoArgs) -> anyhow::Result<ExitCode> {
    check_method(&args.method)?;
    anyhow::ensure!(args.trials > 0, "--trials must be at least 1");
    let config = CellConfig::load(config_path)?;
    let category: Category = args.kind.category.parse()?;
    let mut dbs = Databases::new(&args.kind.db_dir);
    let db = dbs.get(&args.kind.category)?.clone();
    let world = World::new(&args.world, category, args.trials, args.seed, &db)?;
    if !args.json {
        eprintln!("{}", world.lab.text());
    }
    let (run_dir, _temp_run) = run_dir_or_temp(args.run_dir.as_deref(), "demo")?;
    let domain = private_domain("demo")?;
    let stage = StageArgs::in_domain(config_path, &domain, &run_dir);
    let mut options = HarnessOptions::demo(stage)?;
    options.db_dir = args.kind.db_dir.clone();
    options.hold_s = args.hold_s;
    options.observer = args.observer;
    crate::cell::install_stop_handler();
    eprintln!("starting the cell (5 stages, simulated arm and hand) ...");
    let mut cell = Cell::start(options, (*domain).clone()).context("starting the cell")?;
    let bar = progress(args.trials as u64, args.json);
    let mut lines = Vec::new();
    let mut repeated = 0;
    'trials: for i in 0..args.trials {
        let novel = world.object(i);
        let mut rng = placement_rng(args.seed, i as u64);
        let trial_seed = args.seed.wrapping_mul(1000).wrapping_add(i as u64);
        let mut setup = TrialSetup {
            trial_id: 0,
            category,
            object: novel.object.clone(),
            placement: novel.on_table(random_placement(&config, &mut rng, 0)),
            campaign_id: None,
            noise_seed: trial_seed,
            perception_seed: trial_seed,
            source: novel.source.clone(),
            lab: world.lab.trial_draw(args.seed, trial_seed),
        };
        bar.set_message(setup.object.name.clone());
        for attempt in 0..=args.link_fault_repeats {
            if stop_requested() {
                break 'trials;
            }
            cell.supervise()?;
            setup.trial_id = cell.new_trial_id();
            let result = cell.run_trial(
                Some(&setup),
                setup.trial_id,
                &args.kind.category,
                &args.task,
                &args.method,
                &mut |_| {},
            )?;
            let line = TrialLine::new(&setup, &args.task, &args.method, result.as_ref());
            let fault = match result {
                Some(_) => link_fault_of(
                    &TrialLog::open_existing(cell.log_path())?.trials()?,
                    setup.trial_id,
                ),
                None => None,
            };
            let again = fault.is_some() && attempt < args.link_fault_repeats;
            if !args.json {
                let note = match fault {
                    Some(kind) if again => format!("  -- link fault ({kind}): running it again"),
                    Some(kind) => format!("  -- link fault ({kind}), the last repeat"),
                    None => String::new(),
                };
                bar.suspend(|| println!("{}{note}", line.text()));
            }
            if !again {
                lines.push(line);
                break;
            }
            repeated += 1;
        }
        bar.inc(1);
    }
    bar.finish_and_clear();
    let leftover = cell.stop()?;
    let removed = domain.remove().context("removing the demo's IPC domain")?;
    tracing::info!(removed, "demo domain removed");
    let summary = Summary::of(&lines);
    #[derive(Serialize)]
    struct DemoOutput {
        /// The latest run of each trial.
        trials: Vec<TrialLine>,
        summary: Summary,
        /// Runs repeated after a link fault (`--link-fault-repeats`).
        repeated: usize,
        leftover_shm_files: usize,
    }
    let out = DemoOutput {
        trials: lines,
        summary,
        repeated,
        leftover_shm_files: leftover.len(),
    };
    emit(args.json, &out, |o| {
        let repeats = match o.repeated {
            0 => String::new(),
            n => format!("{n} run(s) repeated after a link fault; the summary counts the latest\n"),
        };
        format!(
            "{}{repeats}stopped cleanly: {} leftover shared-memory files\n",
            o.summary.text(),
            o.leftover_shm_files
        )
    })?;
    Ok(ExitCode::SUCCESS)
}

/// Runs `cell campaign`.
pub fn campaign(config_path: &Path, args: CampaignArgs) -> anyhow::Result<ExitCode> {
    for m in &args.methods {
        check_method(m)?;
    }
    anyhow::ensure!(
        args.instances > 0 && args.placements > 0 && !args.methods.is_empty(),
        "--instances, --placements and --methods must not be empty"
    );
    let config = CellConfig::load(config_path)?;
    let category: Category = args.kind.category.parse()?;
    let mut dbs = Databases::new(&args.kind.db_dir);
    let db = dbs.get(&args.kind.category)?.clone();
    let tasks = if args.tasks.is_empty() {
        db.file.tasks.clone()
    } else {
        args.tasks.clone()
    };
    for task in &tasks {
        anyhow::ensure!(
            db.file.tasks.contains(task),
            "--task {task:?}: the {} database has tasks {}",
            args.kind.category,
            db.file.tasks.join(", ")
        );
    }
    let world = World::new(&args.world, category, args.instances, args.seed, &db)?;
    let spec = CampaignSpec {
        category: args.kind.category.clone(),
        tasks,
        objects: world.objects,
        placements: args.placements,
        methods: args.methods.clone(),
        campaign: args.campaign.clone(),
        seed: args.seed,
        paper: args.paper,
        lab: world.lab,
    };
    // Resume: trials of these campaigns already graded are not run again.
    let graded = if args.log.exists() {
        graded_trials(&TrialLog::open_existing(&args.log)?.trials()?)
    } else {
        HashSet::new()
    };
    let plan = spec.plan(&config, &graded);
    let total = spec.total();
    eprintln!(
        "campaigns {}: {} of {total} trials to run ({} already graded in {}); {}",
        spec.campaign_ids().join(", "),
        plan.len(),
        total - plan.len(),
        args.log.display(),
        spec.lab.text()
    );
    let domain = private_domain("campaign")?;
    let stage = StageArgs::in_domain(config_path, &domain, &args.run_dir);
    let mut options = HarnessOptions::demo(stage)?;
    options.db_dir = args.kind.db_dir.clone();
    options.hold_s = args.hold_s;
    options.observer = args.observer;
    options.log_path = args.log.clone();
    options.protocol = spec.protocol();
    crate::cell::install_stop_handler();
    let (lines, repeated) = {
        let mut cell = Cell::start(options, (*domain).clone()).context("starting the cell")?;
        let mut lines = run_campaign_trials(&mut cell, &args, category, &plan)?;
        let mut repeated = 0;
        for _ in 0..args.link_fault_repeats {
            let graded = graded_trials(&TrialLog::open_existing(&args.log)?.trials()?);
            let again = spec.plan(&config, &graded);
            if again.is_empty() || stop_requested() {
                break;
            }
            eprintln!(
                "running {} trial(s) again: they ended on a link fault ({}) or lost their result",
                again.len(),
                LINK_FAULTS.join(", ")
            );
            repeated += again.len();
            lines.extend(run_campaign_trials(&mut cell, &args, category, &again)?);
        }
        let leftover = cell.stop()?;
        if !leftover.is_empty() {
            tracing::warn!(files = leftover.len(), "shared memory left behind");
        }
        (lines, repeated)
    };
    domain.remove()?;
    let summary = Summary::of(&lines);
    let log = TrialLog::open_existing(&args.log)?;
    let trials = log.trials()?;
    let reports = spec.reports(&trials);
    #[derive(Serialize)]
    struct CampaignOutput {
        log: PathBuf,
        observer: crate::sim::observer::ObserverMode,
        lab: LabErrors,
        run: Vec<TrialLine>,
        summary: Summary,
        /// Trials of `run` that repeat an earlier one (`--link-fault-repeats`).
        repeated: usize,
        by_task: Vec<TaskRow>,
        tasks: Vec<TaskReport>,
    }
    let out = CampaignOutput {
        log: args.log.clone(),
        observer: args.observer.mode().unwrap_or_default(),
        lab: spec.lab,
        by_task: TaskRow::of(&latest_lines(&lines), &spec.tasks, &spec.methods),
        run: lines,
        summary,
        repeated,
        tasks: reports,
    };
    emit(args.json, &out, |o| {
        let mut text = format!("{}{}\n", o.summary.text(), o.lab.text());
        if o.repeated > 0 {
            text += &format!(
                "{} trial(s) run again after a link fault; the table counts the latest\n",
                o.repeated
            );
        }
        text += &TaskRow::table(&o.by_task);
        for t in &o.tasks {
            text += &format!(
                "\n== task {} ==\n{}{}graded by the {} observer; {}",
                t.task,
                t.report.to_text(),
                crate::trial::paper::comparison_text(&t.report),
                o.observer,
                t.verdicts.to_text()
            );
        }
        text
    })?;
    Ok(ExitCode::SUCCESS)
}

/// The latest line of each trial (task, object, placement, method) in `lines`, in
/// order: a repeat replaces the trial it repeats.
fn latest_lines(lines: &[TrialLine]) -> Vec<TrialLine> {
    let mut seen = HashSet::new();
    let mut latest: Vec<TrialLine> = lines
        .iter()
        .rev()
        .filter(|l| seen.insert((&l.task, &l.object, l.placement, &l.method)))
        .cloned()
        .collect();
    latest.reverse();
    latest
}

/// Grades of one task and method over the trials run now.
#[derive(Debug, Clone, Serialize)]
struct TaskRow {
    task: String,
    method: String,
    trials: usize,
    success: usize,
    partial: usize,
    failure: usize,
}

impl TaskRow {
    fn of(lines: &[TrialLine], tasks: &[String], methods: &[String]) -> Vec<TaskRow> {
        let mut rows = Vec::new();
        for task in tasks {
            for method in methods {
                let of: Vec<&TrialLine> = lines
                    .iter()
                    .filter(|l| &l.task == task && &l.method == method)
                    .collect();
                let count = |g: &str| of.iter().filter(|l| l.grade == g).count();
                rows.push(TaskRow {
                    task: task.clone(),
                    method: method.clone(),
                    trials: of.len(),
                    success: count("success"),
                    partial: count("partial"),
                    failure: count("failure"),
                });
            }
        }
        rows
    }

    fn table(rows: &[TaskRow]) -> String {
        let mut text = format!(
            "{:<8} {:<12} {:>6} {:>8} {:>8} {:>8}\n",
            "task", "method", "trials", "success", "partial", "failure"
        );
        for r in rows {
            text += &format!(
                "{:<8} {:<12} {:>6} {:>8} {:>8} {:>8}\n",
                r.task, r.method, r.trials, r.success, r.partial, r.failure
            );
        }
        text
    }
}

/// Runs the planned trials of a campaign; a lost result (the log stage died) is
/// reported and the stage restarted, so the rerun of the campaign redoes the trial.
fn run_campaign_trials(
    cell: &mut Cell,
    args: &CampaignArgs,
    category: Category,
    plan: &[PlannedTrial],
) -> anyhow::Result<Vec<TrialLine>> {
    let bar = progress(plan.len() as u64, args.json);
    let mut lines = Vec::new();
    for t in plan {
        if stop_requested() {
            break;
        }
        cell.supervise()?;
        let setup = t.setup(cell.new_trial_id(), category);
        bar.set_message(format!(
            "{} #{} {} {}",
            t.object.name, t.placement.index, t.task, t.method
        ));
        let result = cell.run_trial(
            Some(&setup),
            setup.trial_id,
            &args.kind.category,
            &t.task,
            &t.method,
            &mut |_| {},
        )?;
        let line = TrialLine::new(&setup, &t.task, &t.method, result.as_ref());
        if !args.json {
            bar.suspend(|| println!("{}", line.text()));
        }
        bar.inc(1);
        lines.push(line);
    }
    bar.finish_and_clear();
    Ok(lines)
}

/// Runs `cell run`: the cell with the configured backends in the system domain,
/// until SIGINT/SIGTERM; stages that exit are restarted.
pub fn run(config_path: &Path, args: RunArgs) -> anyhow::Result<ExitCode> {
    let config = CellConfig::load(config_path)?;
    let stage = args.location.stage_args(config_path);
    let domain = stage.domain()?;
    let mut options = HarnessOptions::demo(stage)?;
    options.db_dir = args.db_dir.clone();
    options.hold_s = args.hold_s;
    if let Some(log) = &args.log {
        options.log_path = log.clone();
    }
    options.simulated_devices = config.fri.backend == "sim";
    crate::cell::install_stop_handler();
    let mut cell = Cell::start(options, domain.clone()).context("starting the cell")?;
    eprintln!(
        "cell {} running (IPC under {}); send trials with `cell trial`; Ctrl-C stops",
        domain.services().instance(),
        domain.root().display()
    );
    while !stop_requested() {
        std::thread::sleep(Duration::from_millis(200));
        cell.supervise()?;
    }
    let leftover = cell.stop()?;
    eprintln!("stopped: {} leftover shared-memory files", leftover.len());
    Ok(ExitCode::SUCCESS)
}

/// Runs `cell trial`: one request to a running cell, then its result.
pub fn trial(config_path: &Path, args: TrialArgs) -> anyhow::Result<ExitCode> {
    check_method(&args.method)?;
    anyhow::ensure!(
        args.timeout_s.is_finite() && args.timeout_s > 0.0,
        "--timeout-s {}: must be a finite number > 0",
        args.timeout_s
    );
    let config = CellConfig::load(config_path)?;
    let stage = args.location.stage_args(config_path);
    let domain = stage.domain()?;
    let node = Stage::start(&domain, "operator")?;
    let results = node.subscriber::<TrialResult>()?;
    let requests = node.publisher::<TrialRequest>()?;
    anyhow::ensure!(
        node.stage_status("log")? == crate::ipc::StageStatus::Alive,
        "no cell {} running under {} (start it with `cell run`)",
        domain.services().instance(),
        domain.root().display()
    );
    let trial_id = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(1, |d| d.as_millis() as u64);
    let mut setup_written = None;
    if config.camera.backend == "sim" {
        let category: Category = args.category.parse()?;
        let mut dbs = Databases::new(Path::new("db"));
        let db = dbs.get(&args.category)?;
        let mut rng = placement_rng(args.seed, trial_id);
        let setup = TrialSetup {
            trial_id,
            category,
            object: novel_object(category, args.seed, trial_id % 1000, db),
            placement: random_placement(&config, &mut rng, 0),
            campaign_id: None,
            noise_seed: args.seed,
            perception_seed: args.seed,
            source: ObjectSource::Training,
            lab: None,
        };
        setup.write(&args.location.run_dir)?;
        setup_written = Some(setup);
    }
    let request = TrialRequest::new(
        trial_id,
        monotonic_now_ns(),
        &args.category,
        &args.task,
        &args.method,
    )?;
    let reached = requests.send(&request)?;
    tracing::info!(trial_id, reached, "trial request sent");
    let result = results
        .receive_timeout(Duration::from_secs_f64(args.timeout_s))?
        .filter(|r| r.trial_id == trial_id);
    let Some(result) = result else {
        anyhow::bail!("trial {trial_id}: no result within {} s", args.timeout_s);
    };
    let line = match &setup_written {
        Some(setup) => TrialLine::new(setup, &args.task, &args.method, Some(&result)),
        None => {
            let t = result.timings;
            TrialLine {
                trial_id,
                object: "(real object)".into(),
                placement: 0,
                placement_xy_yaw: [f64::NAN; 3],
                task: args.task.clone(),
                method: args.method.clone(),
                lab: None,
                grade: result
                    .grade()
                    .map_or("?".into(), |g| format!("{g:?}").to_lowercase()),
                cause: result.cause().ok().map(|c| format!("{c:?}")),
                snapshot_to_grasp_command_ms: t.snapshot_to_grasp_command_s * 1e3,
                capture_ms: t.capture_s * 1e3,
                perceive_ms: t.perceive_s * 1e3,
                plan_ms: t.plan_s * 1e3,
                execute_ms: t.execute_s * 1e3,
                total_ms: span_ms(request.stamp_ns, result.stamp_ns),
            }
        }
    };
    emit(args.json, &line, |l| format!("{}\n", l.text()))?;
    Ok(ExitCode::SUCCESS)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn line(grade: &str, command_ms: f64) -> TrialLine {
        TrialLine {
            trial_id: 1,
            object: "squat-mug-1-0".into(),
            placement: 0,
            placement_xy_yaw: [0.6, 0.0, 0.0],
            task: "side".into(),
            method: "laplace-sim".into(),
            lab: None,
            grade: grade.into(),
            cause: None,
            snapshot_to_grasp_command_ms: command_ms,
            capture_ms: 20.0,
            perceive_ms: 80.0,
            plan_ms: 90.0,
            execute_ms: 5000.0,
            total_ms: 5200.0,
        }
    }

    /// A trial refused before any command has no command time: the median is over
    /// the commanded trials, and the summary says how many those are.
    #[test]
    fn the_summary_counts_the_commanded_trials_of_its_median() {
        let summary = Summary::of(&[
            line("success", 180.0),
            line("failure", f64::NAN),
            line("success", 200.0),
            line("partial", 220.0),
        ]);
        assert_eq!((summary.trials, summary.commanded), (4, 3));
        assert_eq!(summary.median_snapshot_to_grasp_command_ms, Some(200.0));
        let text = summary.text();
        assert!(
            text.contains("4 trials: 2 success, 1 partial, 1 failure; median snapshot->grasp command 200 ms over 3 commanded"),
            "{text}"
        );
    }
}
