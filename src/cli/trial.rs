//! `cell grade`, `cell report`, `cell log import` and `cell log export`.

use crate::trial::csv::ImportSummary;
use crate::trial::log::DEFAULT_LOG_PATH;
use crate::trial::{
    plot, prompt_grade, GradeSource, Grading, Report, TrialId, TrialLog, UtcTimestamp,
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
    /// Also write the bar charts (outcomes.png, failure_causes.png) into this directory.
    #[arg(long)]
    pub png: Option<PathBuf>,
    /// Print JSON.
    #[arg(long)]
    pub json: bool,
    /// Also print the failure causes next to the paper's Table 2.
    #[arg(long)]
    pub paper: bool,
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
    let report = Report::from_trials(&trials, args.campaign.as_deref());
    let charts = match &args.png {
        Some(dir) => plot::write_charts(&report, dir)?,
        None => Vec::new(),
    };
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
                    crate::trial::write_atomically(path, csv.as_bytes())?;
                    eprintln!("wrote {} trials to {}", log.trial_count()?, path.display());
                }
                None => super::write_stdout(&csv)?,
            }
        }
    }
    Ok(ExitCode::SUCCESS)
}
