//! `cell-sim-arm`: the LBR4+ FRI robot simulator as its own process. It sends a
//! measurement to the PC-side driver every cycle and follows its commands; see
//! `graspcell::sim::fri` for the model.

use anyhow::Context;
use clap::Parser;
use graspcell::clock::{Clock, SystemClock};
use graspcell::hw::fri::JOINTS;
use graspcell::sim::audit::CommandAudit;
use graspcell::sim::fri::{run_udp, FriSimulator, QualityThresholds, SimConfig};
use std::net::{SocketAddr, UdpSocket};
use std::path::PathBuf;
use std::process::ExitCode;
use std::sync::atomic::AtomicBool;
use std::sync::Mutex;
use std::time::Duration;

/// Simulated KUKA LBR4+ on FRI 1.x: measurements every cycle to the PC, commands back.
#[derive(Debug, Parser)]
#[command(name = "cell-sim-arm", version)]
struct Args {
    /// UDP address of the PC-side FRI driver (where measurements go).
    #[arg(long, default_value = "127.0.0.1:49938")]
    pc_addr: SocketAddr,
    /// Local UDP address of the simulated robot (port 0 picks a free one).
    #[arg(long, default_value = "127.0.0.1:0")]
    bind: SocketAddr,
    /// Measurement period (ms), 1 to 100.
    #[arg(long, default_value_t = 1.0)]
    cycle_ms: f64,
    /// Initial joint angles A1,A2,E1,A3,A4,A5,A6 (rad); all zero if not given.
    #[arg(long, allow_hyphen_values = true)]
    initial_joints: Option<String>,
    /// Time constant of the joints' lag behind the command (s); 0 tracks exactly.
    #[arg(long, default_value_t = 0.0)]
    tracking_time_constant_s: f64,
    /// Cell configuration whose URDF gives the joint position and velocity limits;
    /// without it the LBR4+ data-sheet limits apply.
    #[arg(long, value_name = "CELL_TOML")]
    config: Option<PathBuf>,
    /// Link quality levels: highest miss rates (0..=1, over the last 100 cycles)
    /// that are still PERFECT, OK and BAD.
    #[arg(long, value_name = "PERFECT,OK,BAD", default_value = "0.01,0.05,0.2")]
    miss_rates: String,
    /// Misses in a row from which quality is at most BAD, and from which it is
    /// UNACCEPTABLE (the robot drops to monitor).
    #[arg(long, value_name = "BAD,UNACCEPTABLE", default_value = "2,5")]
    consecutive_misses: String,
    /// The KRL program loops around `friStart`: after the link drops the robot to
    /// monitor mode it asks for command mode again (granted once quality is PERFECT).
    #[arg(long)]
    restart_after_drop: bool,
    /// Scene file (`cell camera render` format) of the objects the hand meets:
    /// `estExtTcpFT` becomes their contact force on the hand (penetration times
    /// approach.sim_contact_stiffness_n_per_m). Reloaded whenever it changes;
    /// needs --config.
    #[arg(long, requires = "config")]
    scene: Option<PathBuf>,
    /// Directory of the state shared with `cell-sim-hand` (palm pose out, hand
    /// joints in); default: the scene file's directory.
    #[arg(long, requires = "scene")]
    state_dir: Option<PathBuf>,
    /// Audit every command received against the cell's limits (URDF joint
    /// positions, configured velocity and acceleration, table clearance, workspace;
    /// `graspcell::sim::audit`) and keep the running report, as JSON, in FILE
    /// (rewritten atomically every 100 ms). Needs --config.
    #[arg(long, value_name = "FILE", requires = "config")]
    audit: Option<PathBuf>,
    /// Stop after this many seconds; runs until killed if not given.
    #[arg(long)]
    seconds: Option<f64>,
    /// Print the final summary as JSON (with --seconds).
    #[arg(long)]
    json: bool,
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
    let base = match &args.config {
        Some(path) => {
            let cell = graspcell::config::CellConfig::load(path)?;
            SimConfig::from_robot(&graspcell::robot::Robot::load(&cell)?)
        }
        None => SimConfig::default(),
    };
    let mut config = SimConfig {
        cycle_s: args.cycle_ms / 1000.0,
        tracking_time_constant_s: args.tracking_time_constant_s,
        quality: QualityThresholds::from_text(&args.miss_rates, &args.consecutive_misses)?,
        restart_after_drop: args.restart_after_drop,
        ..base
    };
    if let Some(text) = &args.initial_joints {
        let q = graspcell::geometry::parse_numbers(text, JOINTS, "--initial-joints")?;
        config.initial_joints_rad.copy_from_slice(&q);
    }
    if let Some(seconds) = args.seconds {
        anyhow::ensure!(
            seconds.is_finite() && seconds > 0.0,
            "--seconds {seconds}: must be a finite number > 0"
        );
    }
    let mut sim = FriSimulator::new(config)?;
    if let (Some(scene), Some(path)) = (&args.scene, &args.config) {
        use graspcell::sim::world::{ArmContact, WorldWatch};
        let cell = graspcell::config::CellConfig::load(path)?;
        let robot = std::sync::Arc::new(graspcell::robot::Robot::load(&cell)?);
        let hand = std::sync::Arc::new(graspcell::robot::hand::HandModel::load(&cell)?);
        let (world, link, dir) =
            WorldWatch::for_simulator(scene, args.state_dir.as_deref(), cell, hand, None)?;
        // The world's contact queries run beside the FRI cycle, never in it.
        let contact = ArmContact::new(robot, world, link);
        let force = graspcell::sim::fri::BackgroundForce::new(
            Box::new(contact),
            std::time::Duration::from_millis(1),
        )?;
        sim.set_external_force(Some(Box::new(force)));
        tracing::info!(scene = %scene.display(), state = %dir.display(), "contact forces from the scene");
    }
    if args.audit.is_some() {
        sim.record_commands(true);
    }
    let sim = Mutex::new(sim);
    let socket = UdpSocket::bind(args.bind).with_context(|| format!("bind {}", args.bind))?;
    tracing::info!(
        "cell-sim-arm: robot at {} sending to {} every {} ms",
        socket.local_addr()?,
        args.pc_addr,
        args.cycle_ms
    );
    let clock = SystemClock::new();
    let until = args
        .seconds
        .map(|s| clock.now() + Duration::from_secs_f64(s));
    let stop = AtomicBool::new(false);
    std::thread::scope(|scope| -> anyhow::Result<()> {
        let auditor = match (&args.audit, &args.config) {
            (Some(file), Some(config)) => {
                let (sim, stop) = (&sim, &stop);
                let cell = graspcell::config::CellConfig::load(config)?;
                let robot = graspcell::robot::Robot::load(&cell)?;
                Some(scope.spawn(move || audit_commands(sim, stop, file, &robot, &cell)))
            }
            _ => None,
        };
        let ran = run_udp(&sim, &socket, args.pc_addr, &clock, &stop, until);
        stop.store(true, std::sync::atomic::Ordering::Relaxed);
        if let Some(auditor) = auditor {
            auditor
                .join()
                .unwrap_or_else(|_| Err(anyhow::anyhow!("the auditor panicked")))?;
        }
        Ok(ran?)
    })?;
    let summary = sim.lock().unwrap_or_else(|e| e.into_inner()).summary();
    graspcell::cli::emit(args.json, &summary, |s| {
        format!(
            "state {:?}, quality {:?}, {} measurements, {} answered in time, {} missed{}\n",
            s.state,
            s.quality,
            s.counters.measurements_sent,
            s.counters.answers_in_time,
            s.counters.misses,
            s.drop_reason
                .map(|r| format!(", dropped to monitor: {r}"))
                .unwrap_or_default()
        )
    })
}

/// Feeds every command the simulator received to a [`CommandAudit`] and rewrites
/// `file` with the report every 100 ms until `stop`.
fn audit_commands(
    sim: &Mutex<FriSimulator>,
    stop: &AtomicBool,
    file: &std::path::Path,
    robot: &graspcell::robot::Robot,
    cell: &graspcell::config::CellConfig,
) -> anyhow::Result<()> {
    // It shares the simulator's lock with the robot's real-time cycle: ordinary
    // work must not preempt it while it holds the lock.
    graspcell::hw::realtime::request_priority(
        "FRI sim auditor",
        graspcell::hw::realtime::CONTROL_PRIORITY,
    );
    let lock = || sim.lock().unwrap_or_else(|e| e.into_inner());
    let dt_s = lock().config().cycle_s;
    let mut audit = CommandAudit::new(robot, cell, dt_s);
    if let Some(dir) = file.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir).with_context(|| format!("--audit {}", file.display()))?;
    }
    let mut written = None;
    loop {
        let done = stop.load(std::sync::atomic::Ordering::Relaxed);
        let commands = lock().take_commands();
        if let Some(why) = audit.check_all(&commands) {
            tracing::error!("unsafe command received: {why}");
        }
        if written.as_ref() != Some(audit.report()) {
            let json = serde_json::to_vec(audit.report())?;
            graspcell::fsio::write_atomically(file, &json)
                .with_context(|| format!("--audit {}", file.display()))?;
            written = Some(audit.report().clone());
        }
        if done {
            return Ok(());
        }
        std::thread::sleep(Duration::from_millis(100));
    }
}
