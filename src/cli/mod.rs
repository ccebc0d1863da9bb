//! The `cell` command line: one subcommand per task an operator or developer runs.
//!
//! Every subcommand that computes something prints one JSON document on stdout with
//! `--json` and human-readable text otherwise; logs go to stderr.

pub mod bench;
mod calibrate;
mod camera;
mod cell;
mod chaos;
mod eval;
mod execute;
pub mod ipc;
mod objects;
mod output;
mod perceive;
mod plan;
mod quality;
mod robot;
mod train;
mod trial;

use clap::{Parser, Subcommand};
use std::path::PathBuf;
use std::process::ExitCode;

pub use output::emit;
pub use output::{error_chain, write_stdout};

/// Controller for the graspcell grasping cell (KUKA LBR4+, Barrett BH8-282, RGB-D camera).
#[derive(Debug, Parser)]
#[command(name = "cell", version, about, long_about = None)]
pub struct Cli {
    /// Cell configuration file. Default: $GRASPCELL_CONFIG, else ./robot/cell.toml, else
    /// /etc/graspcell/cell.toml, else the built-in defaults (`builtin:cell.toml`);
    /// `cell print-config` names the one used.
    #[arg(long, global = true, default_value_os_t = crate::config::default_config_path())]
    pub config: PathBuf,
    /// What to do.
    #[command(subcommand)]
    pub command: Command,
}

/// The subcommands.
#[derive(Debug, Subcommand)]
pub enum Command {
    /// Forward kinematics: flange and palm poses for seven joint angles.
    Fk(robot::FkArgs),
    /// Inverse kinematics: joint angles that put the palm at a pose, or why none do.
    Ik(robot::IkArgs),
    /// Print the effective cell configuration (defaults and file) as TOML.
    PrintConfig,
    /// Grade a trial: success, partial or failure, and a failure's cause.
    Grade(trial::GradeArgs),
    /// Report on the trial log: rates per method, failure causes, sign tests, charts.
    Report(trial::ReportArgs),
    /// The trial log's grades kept on paper: CSV import and export.
    #[command(subcommand)]
    Log(trial::LogCommand),
    /// Hand–eye calibration of the fixed camera (base_from_camera).
    #[command(subcommand)]
    Calibrate(calibrate::CalibrateCommand),
    /// Procedural object models: write category instances as mesh files.
    #[command(subcommand)]
    Objects(objects::ObjectsCommand),
    /// The simulated depth camera: render scenes to point clouds.
    #[command(subcommand)]
    Camera(camera::CameraCommand),
    /// Grasp quality (Ferrari–Canny epsilon, wrench-space volume) of given contacts, or of
    /// the hand closed around an object mesh at a palm pose (auto-grasp).
    Quality(quality::QualityArgs),
    /// Execute one planned grasp (pre-grasp, approach, close, lift, hold) and report.
    Execute(execute::ExecuteArgs),
    /// Plan a grasp: maximise eq. 2 over every model's task grasps, reachable, with the best-single baseline.
    Plan(plan::PlanArgs),
    /// Build a category database (models, task-labelled grasps, q, stability ranges)
    /// from a teach-in file.
    Train(train::TrainArgs),
    /// Benchmarks that print JSON: medians and ratios measured in one run.
    #[command(subcommand)]
    Bench(bench::BenchCommand),
    /// Run the whole simulated cell as processes for N trials on novel objects and
    /// print a line per trial (grade, cause, snapshot-to-grasp-command time).
    Demo(cell::DemoArgs),
    /// The fault campaign: whole simulated trials, each with one fault injected at
    /// random (kill -9 of a stage, CAN loss and corruption, withheld, late and
    /// spoofed FRI datagrams, corrupted shared-memory payloads, a full log disk);
    /// reports completed and failed trials, unsafe commands, lost log rows, panics
    /// and hangs, and exits non-zero on any of the last four.
    Chaos(chaos::ChaosArgs),
    /// Run the cell with the configured backends until Ctrl-C; `cell trial` sends it work.
    Run(cell::RunArgs),
    /// Send one trial request to a running cell (`cell run`) and print its result;
    /// `cell trial show ID --png FILE --glb FILE` draws a recorded trial.
    Trial(trial::TrialCommandArgs),
    /// The grading page and the report in a browser, over a trial log.
    Serve(trial::ServeArgs),
    /// The paper's robot protocol in the simulated cell: novel objects x placements x
    /// methods, paired, graded by the simulated observer, resumable.
    Campaign(cell::CampaignArgs),
    /// Segment the object out of a camera snapshot: table plane removed, the cluster
    /// nearest the workspace centre, written in the robot base frame.
    Segment(perceive::SegmentArgs),
    /// The paper's simulation experiments: leave-one-out (Figs. 5, 6) and cross-category (Table 1).
    #[command(subcommand)]
    Eval(eval::EvalCommand),
    /// Register every model onto a segmented object: FPFH + RANSAC + ICP; per model
    /// the transform, fitting error eps and sigma, inlier fraction, RMSE, time.
    Register(perceive::RegisterArgs),
    /// Helper process of tests and benchmarks (internal).
    #[command(hide = true)]
    IpcPeer(ipc::PeerArgs),
}

/// Entry point of the `cell` binary: parses arguments, runs, prints the error chain.
pub fn main() -> ExitCode {
    crate::logging::init_logging();
    let cli = Cli::parse();
    match run(cli) {
        Ok(code) => code,
        Err(err) => {
            eprintln!("error: {}", error_chain(&err));
            ExitCode::FAILURE
        }
    }
}

/// Runs one parsed command line.
pub fn run(cli: Cli) -> anyhow::Result<ExitCode> {
    match cli.command {
        Command::Fk(args) => robot::fk(&cli.config, args),
        Command::Ik(args) => robot::ik(&cli.config, args),
        Command::PrintConfig => {
            let config = crate::config::CellConfig::load(&cli.config)?;
            let located = crate::config::locate();
            let rule = if located.path == cli.config {
                located.rule
            } else {
                "--config"
            };
            let header = format!("# configuration: {} ({rule})\n", cli.config.display());
            write_stdout(&(header + &toml::to_string_pretty(&config)?))?;
            Ok(ExitCode::SUCCESS)
        }
        Command::Grade(args) => trial::grade(args),
        Command::Report(args) => trial::report(args),
        Command::Log(which) => trial::log(which),
        Command::Calibrate(which) => calibrate::run(&cli.config, which),
        Command::Objects(which) => objects::run(which),
        Command::Camera(which) => camera::run(&cli.config, which),
        Command::Execute(args) => execute::run(&cli.config, args),
        Command::Plan(args) => plan::run(&cli.config, args),
        Command::Quality(args) => quality::run(&cli.config, args),
        Command::Train(args) => train::run(&cli.config, args),
        Command::Bench(which) => bench::run(&cli.config, which),
        Command::IpcPeer(args) => ipc::run_peer(args),
        Command::Demo(args) => cell::demo(&cli.config, args),
        Command::Run(args) => cell::run(&cli.config, args),
        Command::Chaos(args) => chaos::run(&cli.config, args),
        Command::Trial(args) => trial::trial_command(&cli.config, args),
        Command::Serve(args) => trial::serve(args),
        Command::Campaign(args) => cell::campaign(&cli.config, args),
        Command::Segment(args) => perceive::segment(&cli.config, args),
        Command::Register(args) => perceive::register(&cli.config, args),
        Command::Eval(which) => eval::run(&cli.config, which),
    }
}
