//! `cell grade`, `cell report`, `cell log import` and `cell log export`, `cell trial
//! show` (a trial's picture and 3-D scene) and `cell serve` (the grading page).

use crate::trial::csv::ImportSummary;
use crate::trial::log::DEFAULT_LOG_PATH;
use crate::trial::{
    plot, prompt_grade, GradeSource, Grading, Report, Scope, TrialId, TrialLog, UtcTimestamp,
};
use anyhow::Context;
use clap::{Args, Subcommand};
use serde::Serialize;
use std::path::PathBuf;
use std::process::ExitCode;

/// Options of `cell grade`.
#[derive(Debug, Args)]
pub struct GradeArgs {
    /// Id of the trial to grade (see `cell log export`).
    #[arg(long)]
    pub trial: TrialId,
    /// The grade: success, partial or failure (or s, p, f). Without it, the grade,
    /// cause and note are asked at the terminal.
    #[arg(long)]
    pub grade: Option<String>,
    /// Failure cause: reachability, registration, shape-dissimilarity, execution or
    /// other. Required for a failure, optional for a partial grasp.
    #[arg(long)]
    pub cause: Option<String>,
    /// The observer's note.
    #[arg(long)]
    pub note: Option<String>,
    /// Trial log file.
    #[arg(long, default_value = DEFAULT_LOG_PATH)]
    pub log: PathBuf,
    /// Print JSON.
    #[arg(long)]
    pub json: bool,
}

/// Options of `cell report`.
#[derive(Debug, Args)]
pub struct ReportArgs {
    /// Trial log file.
    #[arg(long, default_value = DEFAULT_LOG_PATH)]
    pub log: PathBuf,
    /// Report on this campaign only (default: every trial in the log).
    #[arg(long)]
    pub campaign: Option<String>,
    /// Report on this task only (`top`, `side`, `handle`, …; default: every task).
    #[arg(long)]
    pub task: Option<String>,
    /// Also write the bar charts (outcomes.png, failure_causes.png) into this directory.
    #[arg(long)]
    pub png: Option<PathBuf>,
    /// Print JSON.
    #[arg(long)]
    pub json: bool,
    /// Also print the failure causes next to the paper's Table 2.
    #[arg(long)]
    pub paper: bool,
    /// Also write the report as a static web page into this directory
    /// (index.html, the charts and every trial's picture).
    #[arg(long)]
    pub html: Option<PathBuf>,
}

/// `cell log ...`: grades kept on paper in and out.
#[derive(Debug, Subcommand)]
pub enum LogCommand {
    /// Import grades from CSV (columns trial_id,grade,cause,note): all rows or none.
    Import(LogImportArgs),
    /// Export every trial as CSV (stdout, or a file).
    Export(LogExportArgs),
}

/// Options of `cell log import`.
#[derive(Debug, Args)]
pub struct LogImportArgs {
    /// The CSV file (header trial_id,grade,cause,note; other columns are ignored).
    pub file: PathBuf,
    /// Trial log file.
    #[arg(long, default_value = DEFAULT_LOG_PATH)]
    pub log: PathBuf,
    /// Print JSON.
    #[arg(long)]
    pub json: bool,
}

/// Options of `cell log export`.
#[derive(Debug, Args)]
pub struct LogExportArgs {
    /// Write the CSV here (atomically) instead of stdout.
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Trial log file.
    #[arg(long, default_value = DEFAULT_LOG_PATH)]
    pub log: PathBuf,
}

#[derive(Serialize)]
struct GradeOutput<'a> {
    log: &'a std::path::Path,
    trial_id: TrialId,
    #[serde(flatten)]
    grading: &'a Grading,
    graded_at: UtcTimestamp,
    previous: Option<Grading>,
}

/// Runs `cell grade`.
pub fn grade(args: GradeArgs) -> anyhow::Result<ExitCode> {
    let mut log = TrialLog::open_existing(&args.log)?;
    let trial = log.trial(args.trial)?;
    let (grading, source) = match &args.grade {
        Some(grade) => (
            Grading::parse(grade, args.cause.as_deref(), args.note.clone())
                .with_context(|| format!("grading trial {}", args.trial))?,
            GradeSource::Command,
        ),
        None => {
            if args.cause.is_some() || args.note.is_some() {
                anyhow::bail!("--cause and --note need --grade (or give none to be asked)");
            }
            let t = &trial.trial;
            eprintln!(
                "Trial {}: {} {} / {}, object {} placement {}, method {}{}",
                trial.id,
                t.category,
                t.task,
                t.started_at,
                t.object.name,
                t.placement.index,
                t.method,
                trial
                    .grading
                    .as_ref()
                    .map(|g| format!(", currently {g}"))
                    .unwrap_or_default()
            );
            let stdin = std::io::stdin();
            let grading = prompt_grade(stdin.lock(), std::io::stderr())?;
            (grading, GradeSource::Observer)
        }
    };
    let at = UtcTimestamp::now();
    let previous = log.grade(args.trial, &grading, source, at)?;
    let out = GradeOutput {
        log: &args.log,
        trial_id: args.trial,
        grading: &grading,
        graded_at: at,
        previous,
    };
    super::emit(args.json, &out, |o| {
        let was = o
            .previous
            .as_ref()
            .map(|p| format!(" (was {p})"))
            .unwrap_or_default();
        format!("trial {}: {}{was}\n", o.trial_id, o.grading)
    })?;
    Ok(ExitCode::SUCCESS)
}

#[derive(Serialize)]
struct ReportOutput<'a> {
    log: &'a std::path::Path,
    #[serde(flatten)]
    report: &'a Report,
    charts: Vec<PathBuf>,
}

/// Runs `cell report`.
pub fn report(args: ReportArgs) -> anyhow::Result<ExitCode> {
    let log = TrialLog::open_existing(&args.log)?;
    let trials = log.trials()?;
    if let Some(task) = args.task.as_deref() {
        let tasks: std::collections::BTreeSet<&str> =
            trials.iter().map(|t| t.trial.task.as_str()).collect();
        if !tasks.contains(task) {
            anyhow::bail!(
                "{}: no trial of task {task:?}; the log's tasks: {}",
                args.log.display(),
                tasks.into_iter().collect::<Vec<_>>().join(", ")
            );
        }
    }
    let scope = Scope {
        campaign_id: args.campaign.as_deref(),
        task: args.task.as_deref(),
    };
    let report = Report::from_trials(&trials, scope);
    let charts = match &args.png {
        Some(dir) => plot::write_charts(&report, dir)?,
        None => Vec::new(),
    };
    let mut charts = charts;
    if let Some(dir) = &args.html {
        charts.push(write_html_report(&log, &trials, &report, dir)?);
    }
    for c in &charts {
        tracing::info!("wrote {}", c.display());
    }
    let paper = args.paper;
    let out = ReportOutput {
        log: &args.log,
        report: &report,
        charts,
    };
    super::emit(args.json, &out, |o| {
        let mut text = format!("Log: {}\n", o.log.display());
        text.push_str(&o.report.to_text());
        if paper {
            text.push_str(&crate::trial::paper::comparison_text(o.report));
        }
        for c in &o.charts {
            text.push_str(&format!("chart: {}\n", c.display()));
        }
        text
    })?;
    Ok(ExitCode::SUCCESS)
}

/// Runs `cell log import` or `cell log export`.
pub fn log(which: LogCommand) -> anyhow::Result<ExitCode> {
    match which {
        LogCommand::Import(args) => {
            let mut log = TrialLog::open_existing(&args.log)?;
            let summary = log.import_grades_csv(&args.file, UtcTimestamp::now())?;
            #[derive(Serialize)]
            struct Out<'a> {
                log: &'a std::path::Path,
                file: &'a std::path::Path,
                #[serde(flatten)]
                summary: ImportSummary,
            }
            let out = Out {
                log: &args.log,
                file: &args.file,
                summary,
            };
            super::emit(args.json, &out, |o| {
                format!(
                    "{}: {} rows: {} graded, {} unchanged, {} blank (skipped)\n",
                    o.file.display(),
                    o.summary.rows,
                    o.summary.graded,
                    o.summary.unchanged,
                    o.summary.blank
                )
            })?;
        }
        LogCommand::Export(args) => {
            let log = TrialLog::open_existing(&args.log)?;
            let csv = log.export_csv()?;
            match &args.out {
                Some(path) => {
                    crate::fsio::write_atomically(path, csv.as_bytes())
                        .with_context(|| format!("cannot write {}", path.display()))?;
                    eprintln!("wrote {} trials to {}", log.trial_count()?, path.display());
                }
                None => super::write_stdout(&csv)?,
            }
        }
    }
    Ok(ExitCode::SUCCESS)
}

/// `cell trial ...`: send a trial request to a running cell, or `show` a recorded one.
///
/// Parsed by hand (below): the request's arguments are required only without a
/// subcommand.
#[derive(Debug)]
pub struct TrialCommandArgs {
    /// What to do with a recorded trial.
    pub action: Option<TrialAction>,
    /// The trial request (without a subcommand).
    pub request: Option<super::cell::TrialArgs>,
}

impl clap::FromArgMatches for TrialCommandArgs {
    fn from_arg_matches(matches: &clap::ArgMatches) -> Result<Self, clap::Error> {
        Self::from_arg_matches_mut(&mut matches.clone())
    }

    fn from_arg_matches_mut(matches: &mut clap::ArgMatches) -> Result<Self, clap::Error> {
        if matches.subcommand_name().is_some() {
            Ok(TrialCommandArgs {
                action: Some(<TrialAction as clap::FromArgMatches>::from_arg_matches_mut(
                    matches,
                )?),
                request: None,
            })
        } else {
            Ok(TrialCommandArgs {
                action: None,
                request: Some(
                    <super::cell::TrialArgs as clap::FromArgMatches>::from_arg_matches_mut(
                        matches,
                    )?,
                ),
            })
        }
    }

    fn update_from_arg_matches(&mut self, matches: &clap::ArgMatches) -> Result<(), clap::Error> {
        *self = Self::from_arg_matches(matches)?;
        Ok(())
    }
}

impl clap::Args for TrialCommandArgs {
    fn augment_args(cmd: clap::Command) -> clap::Command {
        let cmd = <super::cell::TrialArgs as clap::Args>::augment_args(cmd);
        <TrialAction as clap::Subcommand>::augment_subcommands(cmd)
            .args_conflicts_with_subcommands(true)
            .subcommand_negates_reqs(true)
    }

    fn augment_args_for_update(cmd: clap::Command) -> clap::Command {
        Self::augment_args(cmd)
    }
}

/// Subcommands of `cell trial`.
#[derive(Debug, Subcommand)]
pub enum TrialAction {
    /// Draw a recorded trial (camera view and side view, PNG) and export its scene
    /// as binary glTF.
    Show(TrialShowArgs),
}

/// Options of `cell trial show`.
#[derive(Debug, Args)]
pub struct TrialShowArgs {
    /// The trial's id in the log.
    pub id: TrialId,
    /// Write the picture here (PNG).
    #[arg(long)]
    pub png: Option<PathBuf>,
    /// Write the 3-D scene here (binary glTF).
    #[arg(long)]
    pub glb: Option<PathBuf>,
    /// Trial log file.
    #[arg(long, default_value = DEFAULT_LOG_PATH)]
    pub log: PathBuf,
    /// Directory of the category databases (the models' meshes).
    #[arg(long, default_value = "db")]
    pub db_dir: PathBuf,
    /// Print JSON.
    #[arg(long)]
    pub json: bool,
}

/// Runs `cell trial`: a request to the running cell, or `show`.
pub fn trial_command(config: &std::path::Path, args: TrialCommandArgs) -> anyhow::Result<ExitCode> {
    match (args.action, args.request) {
        (Some(TrialAction::Show(show_args)), _) => show(config, show_args),
        (None, Some(request)) => super::cell::trial(config, request),
        (None, None) => anyhow::bail!(
            "cell trial: give --category and --task to run a trial, or `show ID` to draw a recorded one"
        ),
    }
}

/// What `cell trial show` wrote.
#[derive(Serialize)]
struct ShowOutput {
    trial_id: TrialId,
    png: Option<PathBuf>,
    glb: Option<PathBuf>,
    solids: usize,
    cloud_points: usize,
    contacts: usize,
    caption: Vec<String>,
}

/// The scene of trial `id` of `log`, with the cell configuration and databases.
pub(crate) fn trial_scene(
    config: &crate::config::CellConfig,
    db_dir: &std::path::Path,
    record: &crate::trial::TrialRecord,
) -> anyhow::Result<crate::trial::picture::TrialScene> {
    let robot = crate::robot::Robot::load(config)?;
    let hand = crate::robot::hand::HandModel::load(config)?;
    let db = match crate::cell::load_category(db_dir, &record.trial.category) {
        Ok(db) => Some(db),
        Err(e) => {
            tracing::warn!("trial {}: drawn without models: {e}", record.id);
            None
        }
    };
    let inputs = crate::trial::scene::SceneInputs {
        config,
        robot: &robot,
        hand: &hand,
        db: db.as_ref(),
        base_from_camera: config.base_from_camera(),
    };
    Ok(crate::trial::scene::trial_scene(record, &inputs))
}

/// Runs `cell trial show`.
pub fn show(config_path: &std::path::Path, args: TrialShowArgs) -> anyhow::Result<ExitCode> {
    anyhow::ensure!(
        args.png.is_some() || args.glb.is_some(),
        "cell trial show {}: give --png FILE and/or --glb FILE",
        args.id
    );
    let config = crate::config::CellConfig::load(config_path)?;
    let log = TrialLog::open_existing(&args.log)?;
    let record = log.trial(args.id)?;
    let scene = trial_scene(&config, &args.db_dir, &record)?;
    if let Some(png) = &args.png {
        crate::trial::picture::write_png(&scene, png)?;
    }
    if let Some(glb) = &args.glb {
        crate::trial::glb::write_glb(&scene, glb)?;
    }
    let out = ShowOutput {
        trial_id: args.id,
        png: args.png.clone(),
        glb: args.glb.clone(),
        solids: scene.solids.len(),
        cloud_points: scene.cloud_m.len(),
        contacts: scene.contacts_m.len(),
        caption: scene.caption.clone(),
    };
    super::emit(args.json, &out, |o| {
        let mut text = format!("trial {}: {}\n", o.trial_id, o.caption.join(" | "));
        for p in o.png.iter().chain(&o.glb) {
            text.push_str(&format!("wrote {}\n", p.display()));
        }
        text
    })?;
    Ok(ExitCode::SUCCESS)
}

/// Options of `cell serve`.
#[derive(Debug, Args)]
pub struct ServeArgs {
    /// Trial log file.
    #[arg(long, default_value = DEFAULT_LOG_PATH)]
    pub log: PathBuf,
    /// Address to listen on (only this one).
    #[arg(long, default_value = "127.0.0.1:8080")]
    pub bind: std::net::SocketAddr,
    /// Show this campaign only.
    #[arg(long)]
    pub campaign: Option<String>,
    /// Read the write token from the first line of this file (at least 16
    /// characters); without it a random token is made and printed at start.
    #[arg(long)]
    pub token_file: Option<PathBuf>,
}

/// Runs `cell serve` until Ctrl-C.
pub fn serve(args: ServeArgs) -> anyhow::Result<ExitCode> {
    // Fail early on a log that is not there or not ours.
    drop(TrialLog::open_existing(&args.log)?);
    let token = match &args.token_file {
        Some(path) => crate::serve::read_token_file(path)?,
        None => crate::serve::random_token(),
    };
    let server = crate::serve::Server::bind(crate::serve::ServeOptions {
        log_path: args.log.clone(),
        bind: args.bind,
        token: token.clone(),
        campaign: args.campaign.clone(),
    })?;
    crate::cell::install_stop_handler();
    let addr = server.local_addr();
    if args.token_file.is_some() {
        println!("grading page: http://{addr}/?token=<the token in the file>");
    } else {
        println!("write token: {token}");
        println!("grading page: http://{addr}/?token={token}");
    }
    println!("report: http://{addr}/report");
    use std::io::Write as _;
    let _ = std::io::stdout().flush();
    server.run(crate::cell::stop_requested);
    Ok(ExitCode::SUCCESS)
}

/// Writes the report as a static page: `DIR/index.html`, the charts and every
/// trial's picture (copied from the paths named in the log) under `DIR/pictures/`.
pub(crate) fn write_html_report(
    log: &TrialLog,
    trials: &[crate::trial::TrialRecord],
    report: &Report,
    dir: &std::path::Path,
) -> anyhow::Result<PathBuf> {
    let pictures_dir = dir.join("pictures");
    std::fs::create_dir_all(&pictures_dir)
        .with_context(|| format!("creating {}", pictures_dir.display()))?;
    let charts = plot::write_charts(report, dir)?;
    let campaign = report.campaign_id.as_deref();
    let shown: Vec<&crate::trial::TrialRecord> = trials
        .iter()
        .filter(|t| campaign.is_none() || t.trial.campaign_id.as_deref() == campaign)
        .collect();
    let mut srcs = Vec::new();
    for t in &shown {
        let src = match log.picture_path(t.id)? {
            Some(path) => {
                let name = format!("{}.png", t.id);
                match std::fs::read(&path) {
                    Ok(bytes) => {
                        let copy = pictures_dir.join(&name);
                        crate::fsio::write_atomically(&copy, &bytes)
                            .with_context(|| format!("cannot write {}", copy.display()))?;
                        Some(format!("pictures/{name}"))
                    }
                    Err(e) => {
                        tracing::warn!("trial {}: picture {}: {e}", t.id, path.display());
                        None
                    }
                }
            }
            None => None,
        };
        srcs.push(src);
    }
    let views: Vec<crate::serve::page::TrialView<'_>> = shown
        .iter()
        .zip(srcs)
        .map(|(record, picture_src)| crate::serve::page::TrialView {
            record,
            picture_src,
            history: &[],
        })
        .collect();
    let name = |p: &PathBuf| {
        p.file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_default()
    };
    let html = crate::serve::page::report_page(
        report,
        [name(&charts[0]).as_str(), name(&charts[1]).as_str()],
        &views,
    );
    let index = dir.join("index.html");
    crate::fsio::write_atomically(&index, html.as_bytes())
        .with_context(|| format!("cannot write {}", index.display()))?;
    Ok(index)
}
