//! `cell-sim-hand`: the BH8-282 puck emulator as its own process on a CAN bus.
//!
//! Prints `ready INTERFACE` on stdout once it is on the bus, then serves until
//! killed or the bus goes away.

use anyhow::Context;
use clap::Parser;
use graspcell::clock::SystemClock;
use graspcell::hw::can::open_bus_logged;
use graspcell::hw::hand::Puck;
use graspcell::sim::puck::{HandEmulator, HandEmulatorConfig};
use std::io::Write;
use std::path::PathBuf;
use std::process::ExitCode;
use std::sync::atomic::AtomicBool;
use std::sync::Arc;
use std::time::Duration;

/// Emulates the four pucks of a Barrett BH8-282 hand on a CAN bus.
#[derive(Debug, Parser)]
#[command(name = "cell-sim-hand", version)]
struct Args {
    /// CAN interface: `virtual:NAME` (cross-process virtual bus) or a SocketCAN
    /// interface such as `vcan0`.
    #[arg(long, default_value = "virtual:hand")]
    interface: String,
    /// Log every frame sent and received to FILE in candump's log format.
    #[arg(long, value_name = "FILE")]
    candump: Option<PathBuf>,
    /// Object contact: proximal joint angles (rad) of F1,F2,F3 where closing stalls.
    #[arg(long, value_name = "F1,F2,F3", conflicts_with = "scene")]
    contact_rad: Option<String>,
    /// Cell configuration (hand model, table), for --scene.
    #[arg(long, value_name = "CELL_TOML")]
    config: Option<PathBuf>,
    /// Scene file (`cell camera render` format) of the objects the hand feels:
    /// each finger stalls where the grasp simulator closes it on the object at
    /// the palm pose `cell-sim-arm` publishes, or runs to its limit on air; an
    /// object not held in force closure slips out when the arm moves away.
    /// Reloaded whenever it changes; needs --config.
    #[arg(long, requires = "config")]
    scene: Option<PathBuf>,
    /// Directory of the state shared with `cell-sim-arm` (palm pose in, hand
    /// joints out); default: the scene file's directory.
    #[arg(long, requires = "scene")]
    state_dir: Option<PathBuf>,
    /// A puck that is absent and never answers (F1, F2, F3 or spread); repeatable.
    #[arg(long, value_name = "PUCK")]
    absent: Vec<String>,
    /// Time a puck takes to boot after STAT = 2 (s).
    #[arg(long, default_value_t = 0.3)]
    boot_s: f64,
}

fn main() -> ExitCode {
    graspcell::logging::init_logging();
    match run(Args::parse()) {
        Ok(()) => ExitCode::SUCCESS,
        Err(err) => {
            eprintln!("error: {}", graspcell::cli::error_chain(&err));
            ExitCode::FAILURE
        }
    }
}

fn run(args: Args) -> anyhow::Result<()> {
    let mut config = HandEmulatorConfig::default();
    if let Some(text) = &args.contact_rad {
        let angles = graspcell::geometry::parse_numbers(text, 3, "--contact-rad")?;
        for (slot, angle) in config.contact_rad.iter_mut().zip(angles) {
            *slot = Some(angle);
        }
    }
    for name in &args.absent {
        let puck = Puck::from_name(name)
            .with_context(|| format!("--absent {name}: not a puck (F1, F2, F3, spread)"))?;
        config.present[puck.index()] = false;
    }
    anyhow::ensure!(
        args.boot_s.is_finite() && args.boot_s >= 0.0,
        "--boot-s {}: must be a finite number >= 0",
        args.boot_s
    );
    config.boot = Duration::from_secs_f64(args.boot_s);
    let mut emulator = HandEmulator::new(config, Arc::new(SystemClock::new()))?;
    if let (Some(scene), Some(path)) = (&args.scene, &args.config) {
        use graspcell::sim::world::{HandContact, WorldWatch};
        let cell = graspcell::config::CellConfig::load(path)?;
        let hand = Arc::new(graspcell::robot::hand::HandModel::load(&cell)?);
        // Whether the object comes up with the hand is the physics lift test's.
        let physics = Some(graspcell::sim::physics::PhysicsOptions::default());
        let (world, link, _) =
            WorldWatch::for_simulator(scene, args.state_dir.as_deref(), cell, hand, physics)?;
        emulator = emulator.with_feel(Box::new(HandContact::new(world, link)));
    }
    let mut bus = open_bus_logged(&args.interface, args.candump.as_deref())?;
    println!("ready {}", args.interface);
    std::io::stdout().flush()?;
    tracing::info!(interface = %args.interface, "hand emulator serving");
    emulator.run(&mut bus, &AtomicBool::new(false))?;
    Ok(())
}
