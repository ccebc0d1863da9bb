//! `cell execute`: one planned grasp on the configured arm and hand.
//!
//! With `fri.backend = "sim"` the FRI robot simulator runs in this process (joint
//! limits from the URDF), and with a `virtual:NAME` CAN interface so does the puck
//! emulator (this process opens the bus first, so it hosts the bus's hub), unless
//! `--external-sims` says `cell-sim-arm` and `cell-sim-hand` already run.

use crate::clock::{Clock, SystemClock};
use crate::config::CellConfig;
use crate::execute::{
    ExecutionReport, ExecutionRequest, Executor, ExecutorConfig, Outcome, ParkReport, SafetyLimits,
};
use crate::hw::can::{open_bus, open_bus_logged, parse_interface, InterfaceKind};
use crate::hw::fri::{DriverConfig, FriDriver, JOINTS};
use crate::hw::hand::{Hand, HandTiming};
use crate::robot::Robot;
use crate::sim::fri::{spawn_udp, QualityThresholds, SimConfig};
use crate::sim::puck::{HandEmulator, HandEmulatorConfig};
use anyhow::Context;
use clap::Args;
use indicatif::{ProgressBar, ProgressStyle};
use serde::Serialize;
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::sync::Arc;
use std::time::Duration;

/// Options of `cell execute`.
#[derive(Debug, Args)]
pub struct ExecuteArgs {
    /// The grasp plan: JSON with palm and pregrasp poses, joints_rad,
    /// pregrasp_joints_rad and spread_rad.
    #[arg(long, value_name = "PLAN_JSON")]
    pub plan: PathBuf,
    /// Do not start simulators in this process: cell-sim-arm and cell-sim-hand
    /// already serve the configured FRI address and CAN bus.
    #[arg(long)]
    pub external_sims: bool,
    /// Joints A1,A2,E1,A3,A4,A5,A6 (rad) the in-process arm simulator starts at.
    /// Default: the configured park joints (`robot.park_joints_rad`).
    #[arg(long, allow_hyphen_values = true, value_name = "A1,A2,E1,A3,A4,A5,A6")]
    pub sim_initial_joints: Option<String>,
    /// Joint angles (rad) of F1,F2,F3 where the in-process hand emulator's object
    /// stops the closing fingers.
    #[arg(long, value_name = "F1,F2,F3", default_value = "1.0,1.0,1.0")]
    pub sim_contact_rad: String,
    /// Link quality levels of the in-process arm simulator: highest miss rates (over
    /// the last 100 cycles) still PERFECT, OK and BAD.
    #[arg(long, value_name = "PERFECT,OK,BAD", default_value = "0.01,0.05,0.2")]
    pub sim_miss_rates: String,
    /// Misses in a row from which the in-process arm simulator's quality is at most
    /// BAD, and from which it is UNACCEPTABLE (it drops to monitor).
    #[arg(long, value_name = "BAD,UNACCEPTABLE", default_value = "2,5")]
    pub sim_consecutive_misses: String,
    /// How long to hold the lifted object (s).
    #[arg(long, default_value_t = 2.0)]
    pub hold_s: f64,
    /// After the grasp (held, closed on air or lost), put the object down where it
    /// was lifted from, open the hand, back out along the approach and move to the
    /// park joints (`robot.park_joints_rad`), as the cell does after every trial.
    /// Without it the arm and hand stay as the grasp left them. Nothing is released
    /// after a device fault or a refused plan.
    #[arg(long)]
    pub park: bool,
    /// Log every CAN frame of the executor to FILE in candump's log format.
    #[arg(long, value_name = "FILE")]
    pub candump: Option<PathBuf>,
    /// Print the execution report as JSON.
    #[arg(long)]
    pub json: bool,
}

/// What `cell execute` prints: the grasp's report and, with `--park`, what
/// releasing and parking did.
#[derive(Serialize)]
struct ExecuteOutput {
    #[serde(flatten)]
    report: ExecutionReport,
    /// The release and park, when it ran.
    park: Option<ParkReport>,
    /// Why it failed (the arm and hand then hold where they stopped).
    park_error: Option<String>,
}

impl ExecuteOutput {
    fn human(&self) -> String {
        let mut text = self.report.human();
        if let Some(park) = &self.park {
            text += &format!("released and parked in {:.2} s\n", park.total_s);
        }
        if let Some(e) = &self.park_error {
            text += &format!(
                "release and park FAILED: {e}; the arm and hand hold where they stopped\n"
            );
        }
        text
    }
}

/// Runs `cell execute`; exits non-zero when the grasp failed (the report says why).
pub fn run(config_path: &Path, args: ExecuteArgs) -> anyhow::Result<ExitCode> {
    let cell = CellConfig::load(config_path)?;
    let robot = Robot::load(&cell)?;
    let request = ExecutionRequest::load(&args.plan)?;
    request.validate()?;
    anyhow::ensure!(
        args.hold_s.is_finite() && args.hold_s >= 0.0,
        "--hold-s {}: must be a finite number >= 0",
        args.hold_s
    );
    let clock: Arc<dyn Clock> = Arc::new(SystemClock::new());

    let driver = FriDriver::start(DriverConfig::from_cell(&cell.fri)?, Arc::clone(&clock))
        .context("starting the FRI driver")?;
    let arm_sim = if cell.fri.backend == "sim" && !args.external_sims {
        let initial_joints_rad = match &args.sim_initial_joints {
            Some(text) => {
                let q = crate::geometry::parse_numbers(text, JOINTS, "--sim-initial-joints")?;
                std::array::from_fn(|j| q[j])
            }
            None => cell.robot.park_joints_rad,
        };
        let config = SimConfig {
            cycle_s: cell.fri.cycle_s,
            initial_joints_rad,
            quality: QualityThresholds::from_text(
                &args.sim_miss_rates,
                &args.sim_consecutive_misses,
            )?,
            ..SimConfig::from_robot(&robot)
        };
        tracing::info!("starting the FRI robot simulator in this process");
        Some(spawn_udp(
            config,
            "127.0.0.1:0".parse()?,
            driver.local_addr(),
            Arc::clone(&clock),
        )?)
    } else {
        None
    };

    // Open the bus before the emulator does, so this process hosts a virtual bus.
    let bus = open_bus_logged(&cell.can.interface, args.candump.as_deref())?;
    let _hand_sim = match parse_interface(&cell.can.interface)? {
        InterfaceKind::Virtual(_) if !args.external_sims => {
            let angles =
                crate::geometry::parse_numbers(&args.sim_contact_rad, 3, "--sim-contact-rad")?;
            let config = HandEmulatorConfig {
                contact_rad: [Some(angles[0]), Some(angles[1]), Some(angles[2]), None],
                ..HandEmulatorConfig::default()
            };
            tracing::info!("starting the hand emulator in this process");
            let node = open_bus(&cell.can.interface)?;
            Some(HandEmulator::new(config, Arc::clone(&clock))?.spawn(node))
        }
        _ => None,
    };

    let hand = Hand::new(bus, Arc::clone(&clock), HandTiming::from_config(&cell.can));
    let robot = Arc::new(robot);
    let limits = SafetyLimits::from_cell(&cell, &robot);
    let config = ExecutorConfig {
        hold_s: args.hold_s,
        ..ExecutorConfig::from_cell(&cell)
    };
    let mut executor = Executor::new(&driver, hand, robot, limits, config, clock);
    let bar = ProgressBar::new_spinner();
    bar.set_style(
        ProgressStyle::with_template("execute {spinner} {elapsed} {msg}")
            .unwrap_or_else(|_| ProgressStyle::default_spinner()),
    );
    bar.enable_steady_tick(Duration::from_millis(100));
    let report =
        executor.execute_observed(&request, &mut |phase| bar.set_message(phase.to_string()));
    let mut output = ExecuteOutput {
        report,
        park: None,
        park_error: None,
    };
    if args.park {
        bar.set_message("release and park");
        match executor.release_and_park(&cell.robot.park_joints_rad) {
            Ok(park) => output.park = park,
            Err(e) => output.park_error = Some(e.to_string()),
        }
    }
    bar.finish_and_clear();
    drop(executor);
    // The simulated robot stops first, so it does not see the driver go silent.
    drop(arm_sim);
    if let Err(e) = driver.shutdown(1.0) {
        tracing::warn!("FRI driver shutdown: {e}");
    }
    super::emit(args.json, &output, ExecuteOutput::human)?;
    Ok(
        if output.report.outcome == Outcome::Success && output.park_error.is_none() {
            ExitCode::SUCCESS
        } else {
            ExitCode::FAILURE
        },
    )
}
