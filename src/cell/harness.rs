//! The whole cell as child processes on one machine: every stage binary (and, with
//! simulated devices, the FRI robot simulator `cell-sim-arm` and the puck emulator
//! `cell-sim-hand`), supervised like systemd's `Restart=on-failure`, plus an
//! operator node that sends trial requests and waits for their results.
//!
//! Stopping ([`Cell::stop`]) sends SIGTERM to every stage (each drops its iceoryx2
//! ports and exits), then to the simulators, and reports the domain's leftover
//! shared-memory files (none after a clean stop).

use super::setup::{upright_pose, TrialSetup};
use super::{CellError, StageArgs, STAGES};
use crate::config::CellConfig;
use crate::fsio::{FileError, FileOp};
use crate::hw::can::{FaultConfig, Hub};
use crate::ipc::{
    monotonic_now_ns, Domain, JointStates, MessagePublisher, MessageSubscriber, Protocol, Stage,
    TrialRequest, TrialResult,
};
use crate::mesh::procedural::{generate, instance_seed, Category};
use crate::sim::audit::AuditReport;
use crate::sim::fri_link::FaultyLink;
use crate::trial::{ObjectRef, Placement};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

/// How long the cell may take to come up (every stage subscribed).
pub const STARTUP_TIMEOUT: Duration = Duration::from_secs(60);

/// Longest wait for the simulated devices to load a trial's scene.
pub const SCENE_LOAD_TIMEOUT: Duration = Duration::from_secs(30);

/// How the harness starts the cell.
#[derive(Debug, Clone)]
pub struct HarnessOptions {
    /// Configuration, domain and run directory handed to every stage.
    pub stage: StageArgs,
    /// Directory of the `cell-*` binaries.
    pub bin_dir: PathBuf,
    /// Category databases (`<dir>/<category>/`).
    pub db_dir: PathBuf,
    /// The trial log file.
    pub log_path: PathBuf,
    /// How long the executor holds a lifted object (s).
    pub hold_s: f64,
    /// Longest trial before the log gives up on it (s).
    pub trial_timeout_s: f64,
    /// Start `cell-sim-arm` and `cell-sim-hand` (simulated devices).
    pub simulated_devices: bool,
    /// Who grades the trials (the log stage's `--observer`).
    pub observer: super::log::ObserverKind,
    /// Whose settings the trials' perception and planning use (the cell's, or the
    /// paper's robot protocol).
    pub protocol: Protocol,
    /// With simulated devices: host the CAN bus and relay FRI through links whose
    /// faults can be set while the cell runs ([`Cell::faulty_links`]).
    pub faulty_links: bool,
    /// Append each process's standard error to `<dir>/<process>.log` (else it is
    /// inherited).
    pub stderr_dir: Option<PathBuf>,
}

impl HarnessOptions {
    /// Options with the defaults of `cell demo`: binaries next to the running one,
    /// databases in `db/`, simulated devices.
    pub fn demo(stage: StageArgs) -> Result<HarnessOptions, CellError> {
        let exe = std::env::current_exe().map_err(|source| CellError::Io {
            path: PathBuf::from("/proc/self/exe"),
            source,
        })?;
        let bin_dir = exe.parent().map(Path::to_path_buf).unwrap_or_default();
        Ok(HarnessOptions {
            log_path: stage.run_dir.join("trials.sqlite"),
            stage,
            bin_dir,
            db_dir: PathBuf::from("db"),
            hold_s: 0.3,
            trial_timeout_s: 120.0,
            simulated_devices: true,
            observer: super::log::ObserverKind::default(),
            protocol: Protocol::Cell,
            faulty_links: false,
            stderr_dir: None,
        })
    }
}

/// One child process.
#[derive(Debug)]
struct Process {
    name: String,
    args: Vec<String>,
    child: Child,
    restarts: u32,
}

/// The running cell.
pub struct Cell {
    options: HarnessOptions,
    domain: Domain,
    stages: Vec<Process>,
    sims: Vec<Process>,
    fri_addr: String,
    /// The simulated robot's own address (`None` on hardware: `fri.robot_addr`).
    fri_robot_addr: Option<String>,
    fri_cycle_s: f64,
    /// Where the simulated arm starts (`robot.park_joints_rad`).
    park_joints_rad: [f64; 7],
    can_interface: String,
    operator: Option<Operator>,
    next_trial_id: u64,
    /// The CAN hub and FRI relay with settable faults ([`HarnessOptions::faulty_links`]).
    links: Option<FaultyLinks>,
    /// Processes that did not stop on SIGTERM and were killed.
    killed_at_stop: Vec<String>,
}

/// The device links of a cell started with [`HarnessOptions::faulty_links`].
pub struct FaultyLinks {
    /// The hand's CAN bus (loss and corruption: [`Hub::set_faults`]).
    pub can: Hub,
    /// The arm's FRI link (withheld, late and spoofed datagrams).
    pub fri: FaultyLink,
}

/// How the cell stopped.
#[derive(Debug, Clone, Default)]
pub struct StopReport {
    /// The domain's leftover shared-memory files (none after a clean stop).
    pub leftover_files: Vec<PathBuf>,
    /// Processes that did not stop on SIGTERM and were killed.
    pub killed_after_sigterm: Vec<String>,
}

struct Operator {
    requests: MessagePublisher<TrialRequest>,
    results: MessageSubscriber<TrialResult>,
    // Dropped last: the ports above belong to this node.
    _stage: Stage,
}

fn free_udp_port() -> Result<u16, CellError> {
    let socket = std::net::UdpSocket::bind("127.0.0.1:0").map_err(|source| CellError::Io {
        path: PathBuf::from("udp 127.0.0.1:0"),
        source,
    })?;
    socket
        .local_addr()
        .map(|a| a.port())
        .map_err(|source| CellError::Io {
            path: PathBuf::from("udp 127.0.0.1:0"),
            source,
        })
}

fn spawn(
    options: &HarnessOptions,
    name: &str,
    args: &[String],
    piped: bool,
) -> Result<Child, CellError> {
    let program = options.bin_dir.join(name);
    let stderr = match &options.stderr_dir {
        Some(dir) => {
            let path = dir.join(format!("{name}.log"));
            let file = std::fs::create_dir_all(dir)
                .and_then(|()| {
                    std::fs::OpenOptions::new()
                        .create(true)
                        .append(true)
                        .open(&path)
                })
                .map_err(|source| FileError::new(FileOp::Write, &path, source))?;
            Stdio::from(file)
        }
        None => Stdio::inherit(),
    };
    Command::new(&program)
        .args(args)
        .stdin(Stdio::null())
        .stdout(if piped { Stdio::piped() } else { Stdio::null() })
        .stderr(stderr)
        .spawn()
        .map_err(|e| CellError::Process {
            name: program.display().to_string(),
            detail: format!("cannot start: {e}"),
        })
}

/// The binaries the harness starts: every stage, and the simulators when asked.
fn needed_binaries(options: &HarnessOptions) -> Vec<String> {
    let mut names: Vec<String> = STAGES.iter().map(|s| format!("cell-{s}")).collect();
    if options.simulated_devices {
        names.extend(["cell-sim-arm".to_string(), "cell-sim-hand".to_string()]);
    }
    names
}

/// Fails before anything starts when a binary the cell needs is not in `bin_dir`,
/// naming the missing ones and the command that builds them (`cargo run --bin cell`
/// builds only `cell`).
fn check_binaries(options: &HarnessOptions) -> Result<(), CellError> {
    let missing: Vec<String> = needed_binaries(options)
        .into_iter()
        .filter(|name| !options.bin_dir.join(name).is_file())
        .collect();
    if missing.is_empty() {
        return Ok(());
    }
    Err(CellError::Process {
        name: missing.join(", "),
        detail: format!(
            "not found in {} (the cell runs each stage and simulator as its own binary); \
             build them all with `cargo build --release --bins`, or install them next to \
             `cell` (`cargo install --path .`)",
            options.bin_dir.display()
        ),
    })
}

/// Asks `child` to stop (SIGTERM), unless it has already been reaped (its PID may
/// then be another process's).
fn terminate(process: &mut Process) {
    if let Err(e) = crate::sys::terminate_child(&mut process.child) {
        tracing::warn!(process = %process.name, "cannot send SIGTERM: {e}");
    }
}

/// Waits up to `timeout` for `child` to exit; kills it after that.
fn reap(child: &mut Child, timeout: Duration) -> bool {
    let deadline = Instant::now() + timeout;
    while Instant::now() < deadline {
        if let Ok(Some(_)) = child.try_wait() {
            return true;
        }
        std::thread::sleep(Duration::from_millis(10));
    }
    let _ = child.kill();
    let _ = child.wait();
    false
}

impl Cell {
    /// Starts the simulators (if asked) and every stage in `domain`, and waits until
    /// all stages are up.
    pub fn start(options: HarnessOptions, domain: Domain) -> Result<Cell, CellError> {
        let config = CellConfig::load(&options.stage.config)?;
        check_binaries(&options)?;
        warn_if_parked_arm_in_view(&config);
        let tag = format!(
            "{}x{}",
            std::process::id(),
            domain.prefix().trim_end_matches('_')
        );
        // With simulated devices the executor's driver answers exactly the arm
        // simulator's address and port (pinned, as `fri.robot_addr` pins the KRC).
        let (fri_addr, fri_robot_addr, can_interface) = if options.simulated_devices {
            let pc_port = free_udp_port()?;
            let mut robot_port = free_udp_port()?;
            while robot_port == pc_port {
                robot_port = free_udp_port()?;
            }
            (
                format!("127.0.0.1:{pc_port}"),
                Some(format!("127.0.0.1:{robot_port}")),
                format!("virtual:cell-{tag}"),
            )
        } else {
            (
                config.fri.bind_addr.clone(),
                None,
                config.can.interface.clone(),
            )
        };
        let links = match (options.faulty_links, options.simulated_devices) {
            (false, _) => None,
            (true, false) => {
                return Err(CellError::Invalid(
                    "faulty links need simulated devices".into(),
                ))
            }
            (true, true) => {
                let bus = can_interface.trim_start_matches(crate::hw::can::VIRTUAL_PREFIX);
                let can = Hub::bind_with_faults(bus, FaultConfig::default()).map_err(|e| {
                    CellError::Device {
                        device: "CAN hub",
                        detail: e.to_string(),
                    }
                })?;
                let pc: std::net::SocketAddr = fri_addr
                    .parse()
                    .map_err(|e| CellError::Invalid(format!("FRI address {fri_addr}: {e}")))?;
                let fri = FaultyLink::start(pc, instance_seed(0x6c69_6e6b, pc.port().into()))
                    .map_err(|source| CellError::Io {
                        path: PathBuf::from("udp 127.0.0.1:0 (FRI relay)"),
                        source,
                    })?;
                Some(FaultyLinks { can, fri })
            }
        };
        let mut cell = Cell {
            options,
            domain,
            stages: Vec::new(),
            sims: Vec::new(),
            fri_addr,
            fri_robot_addr,
            fri_cycle_s: config.fri.cycle_s,
            park_joints_rad: config.robot.park_joints_rad,
            can_interface,
            operator: None,
            next_trial_id: 0,
            links,
            killed_at_stop: Vec::new(),
        };
        if let Err(e) = cell.start_all() {
            cell.shutdown();
            return Err(e);
        }
        Ok(cell)
    }

    fn start_all(&mut self) -> Result<(), CellError> {
        if self.options.simulated_devices {
            // The simulated devices feel the trial's object: a scene file per
            // trial (run_trial) and their shared state, in <run dir>/sim/.
            let _ = std::fs::remove_file(self.sim_scene_path());
            let hand_args = vec![
                "--interface".to_string(),
                self.can_interface.clone(),
                "--boot-s".into(),
                "0.05".into(),
            ]
            .into_iter()
            .chain(self.sim_world_args())
            .collect::<Vec<String>>();
            let mut hand = spawn(&self.options, "cell-sim-hand", &hand_args, true)?;
            // The emulator hosts the virtual bus: wait for its "ready" line.
            let mut line = String::new();
            if let Some(out) = hand.stdout.take() {
                let _ = BufReader::new(out).read_line(&mut line);
            }
            if !line.starts_with("ready") {
                let _ = hand.kill();
                let _ = hand.wait();
                return Err(CellError::Process {
                    name: "cell-sim-hand".into(),
                    detail: "exited before it was on the bus".into(),
                });
            }
            self.sims.push(Process {
                name: "cell-sim-hand".into(),
                args: hand_args,
                child: hand,
                restarts: 0,
            });
        }
        for stage in STAGES {
            let args = self.stage_args(stage);
            let child = spawn(&self.options, &format!("cell-{stage}"), &args, false)?;
            self.stages.push(Process {
                name: stage.to_string(),
                args,
                child,
                restarts: 0,
            });
        }
        let node = Stage::start(&self.domain, "operator")?;
        self.operator = Some(Operator {
            requests: node.publisher::<TrialRequest>()?,
            results: node.subscriber::<TrialResult>()?,
            _stage: node,
        });
        self.wait_ready(STARTUP_TIMEOUT)?;
        // The robot simulator last: it drops to monitor mode when its measurements go
        // unanswered, so the executor's FRI driver must already listen.
        if self.options.simulated_devices {
            let home: Vec<String> = self.park_joints_rad.iter().map(|q| q.to_string()).collect();
            // Through the relay, the robot sends to it and binds any port.
            let (sends_to, binds) = match &self.links {
                Some(links) => (
                    links.fri.robot_facing_addr().to_string(),
                    "127.0.0.1:0".to_string(),
                ),
                None => (
                    self.fri_addr.clone(),
                    self.fri_robot_addr
                        .clone()
                        .unwrap_or_else(|| "127.0.0.1:0".into()),
                ),
            };
            let arm_args = vec![
                "--pc-addr".to_string(),
                sends_to,
                "--bind".into(),
                binds,
                "--audit".into(),
                self.audit_path().display().to_string(),
                "--initial-joints".into(),
                home.join(","),
                "--cycle-ms".into(),
                (self.fri_cycle_s * 1e3).to_string(),
                "--restart-after-drop".into(),
            ]
            .into_iter()
            .chain(self.sim_world_args())
            .collect::<Vec<String>>();
            let arm = spawn(&self.options, "cell-sim-arm", &arm_args, false)?;
            self.sims.push(Process {
                name: "cell-sim-arm".into(),
                args: arm_args,
                child: arm,
                restarts: 0,
            });
        }
        self.wait_devices_ready(STARTUP_TIMEOUT)
    }

    /// Waits until the executor reports its devices ready (the arm in command mode,
    /// the hand initialised), so that no trial waits for them.
    pub fn wait_devices_ready(&mut self, timeout: Duration) -> Result<(), CellError> {
        let operator = self
            .operator
            .as_ref()
            .ok_or_else(|| CellError::Invalid("the operator node is not running".into()))?;
        let joints = operator._stage.subscriber::<JointStates>()?;
        let deadline = Instant::now() + timeout;
        let mut last = None;
        while Instant::now() < deadline {
            if let Some(j) = joints.receive_timeout(super::TICK)? {
                if j.devices_ready == 1 {
                    return Ok(());
                }
                last = Some(j);
            }
            for process in self.stages.iter_mut().chain(self.sims.iter_mut()) {
                if let Ok(Some(status)) = process.child.try_wait() {
                    return Err(CellError::Process {
                        name: process.name.clone(),
                        detail: format!("exited while the devices came up ({status})"),
                    });
                }
            }
        }
        Err(CellError::Timeout {
            what: match last {
                None => format!(
                    "the executor's joint states: no robot measurement reached its FRI driver at {} ({})",
                    self.fri_addr,
                    if self.options.simulated_devices {
                        "the arm simulator runs and sends there"
                    } else {
                        "is the robot's FRI configured to send there?"
                    }
                ),
                Some(_) => "the arm in command mode with the hand initialised".to_string(),
            },
            waited_s: timeout.as_secs_f64(),
        })
    }

    /// Where the arm simulator keeps its audit of the commands it received.
    fn audit_path(&self) -> PathBuf {
        self.sim_dir().join("audit.json")
    }

    /// The arm simulator's audit of every command it received so far (simulated
    /// devices only; `None` before its first report).
    pub fn audit(&self) -> Result<Option<AuditReport>, CellError> {
        let path = self.audit_path();
        match std::fs::read(&path) {
            Ok(bytes) => serde_json::from_slice(&bytes)
                .map(Some)
                .map_err(|e| CellError::Invalid(format!("{}: {e}", path.display()))),
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => Ok(None),
            Err(source) => Err(FileError::new(FileOp::Read, &path, source).into()),
        }
    }

    /// The CAN hub and FRI relay whose faults can be set
    /// ([`HarnessOptions::faulty_links`]).
    pub fn faulty_links(&self) -> Option<&FaultyLinks> {
        self.links.as_ref()
    }

    /// The executor's FRI address (where the robot's measurements go).
    pub fn fri_pc_addr(&self) -> &str {
        &self.fri_addr
    }

    /// The log file.
    pub fn log_path(&self) -> &Path {
        &self.options.log_path
    }

    /// Waits until every running simulated device has loaded the scene file just
    /// written, as a person puts the object on the table before the trial is
    /// asked for: a device preparing a scene (its physics takes a core for about
    /// half a second) would otherwise run beside the trial's perception and
    /// planning and slow them. A device that has not loaded it within
    /// [`SCENE_LOAD_TIMEOUT`] is logged; the trial goes ahead.
    fn wait_until_devices_feel_the_scene(&mut self) {
        let dir = self.sim_dir();
        let acks: Vec<PathBuf> = self
            .sims
            .iter_mut()
            .filter_map(|p| match p.child.try_wait() {
                Ok(None) => Some(crate::sim::world::scene_loaded_path(&dir, p.child.id())),
                _ => None,
            })
            .collect();
        let scene = self.sim_scene_path();
        if !crate::sim::world::wait_until_scene_loaded(&scene, &acks, SCENE_LOAD_TIMEOUT) {
            tracing::warn!(
                scene = %scene.display(),
                "the simulated devices have not loaded the scene within {} s; the trial goes ahead",
                SCENE_LOAD_TIMEOUT.as_secs_f64()
            );
        }
    }

    /// The simulated devices' directory: their scene file and shared state.
    fn sim_dir(&self) -> PathBuf {
        self.options.stage.run_dir.join("sim")
    }

    /// The scene file the simulated devices feel.
    fn sim_scene_path(&self) -> PathBuf {
        self.sim_dir().join("scene.toml")
    }

    /// `--config --scene --state-dir` of the simulated devices.
    fn sim_world_args(&self) -> Vec<String> {
        let dir = self.sim_dir();
        vec![
            "--config".into(),
            self.options.stage.config.display().to_string(),
            "--scene".into(),
            self.sim_scene_path().display().to_string(),
            "--state-dir".into(),
            dir.display().to_string(),
        ]
    }

    fn stage_args(&self, stage: &str) -> Vec<String> {
        let mut args = self.options.stage.to_command_args(&self.domain);
        match stage {
            "perceive" | "plan" => {
                args.extend(["--db-dir".into(), self.options.db_dir.display().to_string()])
            }
            "execute" => {
                args.extend([
                    "--fri-bind".into(),
                    self.fri_addr.clone(),
                    "--can-interface".into(),
                    self.can_interface.clone(),
                    "--hold-s".into(),
                    self.options.hold_s.to_string(),
                ]);
                let robot = match &self.links {
                    Some(links) => Some(links.fri.pc_facing_addr().to_string()),
                    None => self.fri_robot_addr.clone(),
                };
                if let Some(robot) = robot {
                    args.extend(["--fri-robot".into(), robot]);
                }
            }
            "log" => args.extend([
                "--log".into(),
                self.options.log_path.display().to_string(),
                "--trial-timeout-s".into(),
                self.options.trial_timeout_s.to_string(),
                "--db-dir".into(),
                self.options.db_dir.display().to_string(),
                "--observer".into(),
                self.options.observer.arg().into(),
            ]),
            _ => {}
        }
        args
    }

    /// The domain the cell runs in.
    pub fn domain(&self) -> &Domain {
        &self.domain
    }

    /// Process id of stage `stage`.
    pub fn pid(&self, stage: &str) -> Option<u32> {
        self.stages
            .iter()
            .find(|p| p.name == stage)
            .map(|p| p.child.id())
    }

    /// How often stage `stage` was restarted.
    pub fn restarts(&self, stage: &str) -> u32 {
        self.stages
            .iter()
            .find(|p| p.name == stage)
            .map_or(0, |p| p.restarts)
    }

    /// Kills stage `stage` with SIGKILL (a crash: it cleans nothing up).
    pub fn kill(&mut self, stage: &str) -> Result<(), CellError> {
        let process = self
            .stages
            .iter_mut()
            .find(|p| p.name == stage)
            .ok_or_else(|| CellError::Invalid(format!("no stage {stage:?}")))?;
        let _ = process.child.kill();
        let _ = process.child.wait();
        Ok(())
    }

    /// Restarts every stage whose process has exited (as systemd's
    /// `Restart=on-failure` would); returns the stages restarted.
    pub fn supervise(&mut self) -> Result<Vec<String>, CellError> {
        let mut restarted = Vec::new();
        for process in &mut self.stages {
            if let Ok(Some(status)) = process.child.try_wait() {
                tracing::warn!(stage = %process.name, %status, "stage exited: restarting");
                process.child = spawn(
                    &self.options,
                    &format!("cell-{}", process.name),
                    &process.args,
                    false,
                )?;
                process.restarts += 1;
                restarted.push(process.name.clone());
            }
        }
        for process in &mut self.sims {
            if let Ok(Some(status)) = process.child.try_wait() {
                return Err(CellError::Process {
                    name: process.name.clone(),
                    detail: format!("simulator exited ({status})"),
                });
            }
        }
        if !restarted.is_empty() {
            self.wait_ready(STARTUP_TIMEOUT)?;
        }
        Ok(restarted)
    }

    /// Waits until every stage's node is alive and subscribed to trial requests.
    pub fn wait_ready(&mut self, timeout: Duration) -> Result<(), CellError> {
        let started = Instant::now();
        let operator = self
            .operator
            .as_ref()
            .ok_or_else(|| CellError::Invalid("the operator node is not running".into()))?;
        loop {
            let subscribers = operator.requests.subscriber_peers()?;
            let mut all_alive = subscribers.alive >= STAGES.len();
            for stage in STAGES {
                all_alive &= operator._stage.stage_status(stage)? == crate::ipc::StageStatus::Alive;
            }
            if all_alive {
                return Ok(());
            }
            for process in &mut self.stages {
                if let Ok(Some(status)) = process.child.try_wait() {
                    return Err(CellError::Process {
                        name: format!("cell-{}", process.name),
                        detail: format!("exited while starting ({status})"),
                    });
                }
            }
            if started.elapsed() > timeout {
                return Err(CellError::Timeout {
                    what: format!(
                        "cell start-up ({} of {} stages subscribed)",
                        subscribers.alive,
                        STAGES.len()
                    ),
                    waited_s: timeout.as_secs_f64(),
                });
            }
            std::thread::sleep(Duration::from_millis(20));
        }
    }

    /// A fresh trial id (milliseconds since the epoch at the first, then counting).
    pub fn new_trial_id(&mut self) -> u64 {
        if self.next_trial_id == 0 {
            self.next_trial_id = std::time::SystemTime::now()
                .duration_since(std::time::UNIX_EPOCH)
                .map_or(1, |d| d.as_millis() as u64);
        }
        self.next_trial_id += 1;
        self.next_trial_id
    }

    /// Sends one trial request and waits for its result. `setup` (the simulated
    /// world of the trial) is written first. `after_send` runs once the request is
    /// out (tests use it to kill a stage mid-trial). If the log stage dies before it
    /// answers, the result is lost: `Ok(None)`.
    pub fn run_trial(
        &mut self,
        setup: Option<&TrialSetup>,
        trial_id: u64,
        category: &str,
        task: &str,
        method: &str,
        after_send: &mut dyn FnMut(&mut Cell),
    ) -> Result<Option<TrialResult>, CellError> {
        if let Some(setup) = setup {
            setup.write(&self.options.stage.run_dir)?;
            if self.options.simulated_devices {
                setup.write_sim_scene(&self.sim_scene_path())?;
                self.wait_until_devices_feel_the_scene();
            }
        }
        let request = TrialRequest::new(trial_id, monotonic_now_ns(), category, task, method)?
            .with_protocol(self.options.protocol);
        let operator = self
            .operator
            .as_ref()
            .ok_or_else(|| CellError::Invalid("the operator node is not running".into()))?;
        operator.requests.send(&request)?;
        after_send(self);
        let deadline =
            Instant::now() + Duration::from_secs_f64(self.options.trial_timeout_s + 30.0);
        loop {
            let operator = self
                .operator
                .as_ref()
                .ok_or_else(|| CellError::Invalid("the operator node is not running".into()))?;
            if let Some(result) = operator.results.receive_timeout(super::TICK)? {
                if result.trial_id == trial_id {
                    return Ok(Some(result));
                }
                continue;
            }
            let log = self.stages.iter_mut().find(|p| p.name == "log");
            if let Some(log) = log {
                if let Ok(Some(_)) = log.child.try_wait() {
                    tracing::warn!(trial_id, "the log stage died: the trial's result is lost");
                    return Ok(None);
                }
            }
            if Instant::now() > deadline {
                return Err(CellError::Timeout {
                    what: format!("result of trial {trial_id}"),
                    waited_s: self.options.trial_timeout_s + 30.0,
                });
            }
        }
    }

    fn shutdown(&mut self) {
        self.operator = None;
        for p in &mut self.stages {
            terminate(p);
        }
        for p in &mut self.stages {
            if !reap(&mut p.child, Duration::from_secs(10)) {
                tracing::warn!(stage = %p.name, "did not stop on SIGTERM: killed");
                self.killed_at_stop.push(p.name.clone());
            }
        }
        for p in &mut self.sims {
            terminate(p);
        }
        for p in &mut self.sims {
            if !reap(&mut p.child, Duration::from_secs(5)) {
                self.killed_at_stop.push(p.name.clone());
            }
        }
        self.stages.clear();
        self.sims.clear();
    }

    /// Stops every process; returns the domain's leftover shared-memory files
    /// (empty after a clean stop).
    pub fn stop(self) -> Result<Vec<PathBuf>, CellError> {
        Ok(self.stop_with_report()?.leftover_files)
    }

    /// Stops every process; reports leftover files and who had to be killed.
    pub fn stop_with_report(mut self) -> Result<StopReport, CellError> {
        self.shutdown();
        Ok(StopReport {
            leftover_files: self.domain.leftover_files()?,
            killed_after_sigterm: std::mem::take(&mut self.killed_at_stop),
        })
    }
}

impl Drop for Cell {
    fn drop(&mut self) {
        self.shutdown();
    }
}

/// A novel object of `category`: instance `index` of the set `set_seed`, checked
/// not to be one of the database's models (same triangles and vertices).
pub fn novel_object(
    category: Category,
    set_seed: u64,
    index: u64,
    db: &crate::category::CategoryDb,
) -> ObjectRef {
    let mut k = 0u64;
    loop {
        let seed = instance_seed(set_seed ^ 0x6e6f_7665_6c00, index + k * 1_000_003);
        let (mesh, _) = generate(category, seed);
        let known = db.meshes.iter().any(|m| {
            m.triangles.len() == mesh.triangles.len() && m.vertices.first() == mesh.vertices.first()
        });
        if !known {
            return ObjectRef {
                name: format!("{category}-novel-{set_seed}-{index}"),
                seed: Some(seed),
            };
        }
        k += 1;
    }
}

/// Where placements are drawn: the part of the table in front of the robot that the
/// arm reaches comfortably from above and from the side (base frame, m).
pub const PLACEMENT_X_M: (f64, f64) = (0.50, 0.68);
/// See [`PLACEMENT_X_M`].
pub const PLACEMENT_Y_M: (f64, f64) = (-0.18, 0.18);

/// Heights above the table (m) of the lines of sight [`arm_in_view`] checks: the
/// table, and the middle and top of a tall object.
const SIGHT_HEIGHTS_M: [f64; 3] = [0.0, 0.12, 0.25];

/// Spacing of [`arm_in_view`]'s grid over the placement area (m).
const SIGHT_GRID_M: f64 = 0.02;

/// Whether the arm at `joints` (hand open) stands between the camera at
/// `base_from_camera` and the placement area ([`PLACEMENT_X_M`] x
/// [`PLACEMENT_Y_M`], from the table up to 0.25 m above it, on a 2 cm grid): the
/// first link found in a line of sight, and the point (base frame, m) it hides.
/// `None`: the camera sees every placement past the arm. The park joints must give
/// `None`, since the snapshot is taken with the arm parked.
pub fn arm_in_view(
    config: &CellConfig,
    robot: &crate::robot::Robot,
    base_from_camera: &crate::geometry::Pose,
    joints: &crate::robot::kinematics::ArmJoints,
) -> Option<(String, [f64; 3])> {
    let camera = base_from_camera.translation.vector.into();
    let hand = crate::robot::HandPose::OPEN;
    let steps = |(lo, hi): (f64, f64)| ((hi - lo) / SIGHT_GRID_M).round() as usize;
    let (nx, ny) = (steps(PLACEMENT_X_M), steps(PLACEMENT_Y_M));
    (0..=nx)
        .flat_map(|i| (0..=ny).map(move |j| (i, j)))
        .flat_map(|(i, j)| SIGHT_HEIGHTS_M.map(|h| (i, j, h)))
        .find_map(|(i, j, h)| {
            let point = [
                PLACEMENT_X_M.0 + i as f64 * SIGHT_GRID_M,
                PLACEMENT_Y_M.0 + j as f64 * SIGHT_GRID_M,
                config.table.height_m + h,
            ];
            robot
                .link_on_segment(joints, &hand, &camera, &point.into())
                .map(|link| (link.to_string(), point))
        })
}

/// Warns when the arm at `robot.park_joints_rad` would stand in the configured
/// camera's view of the placement area ([`arm_in_view`]).
fn warn_if_parked_arm_in_view(config: &CellConfig) {
    let Ok(robot) = crate::robot::Robot::load(config) else {
        return; // The stages load it themselves and report why.
    };
    let camera = config.base_from_camera();
    if let Some((link, [x, y, z])) =
        arm_in_view(config, &robot, &camera, &config.robot.park_joints_rad)
    {
        tracing::warn!(
            "robot.park_joints_rad: the parked arm's {link} stands between the camera \
             (camera.base_from_camera) and the placement area, hiding ({x:.2}, {y:.2}, \
             {z:.2}) m; snapshots will show the arm. Choose park joints behind the table"
        );
    }
}

/// Placement `index` of an object, drawn from `rng`: upright, at a random point of
/// the comfortable area, turned by a random yaw.
pub fn random_placement(config: &CellConfig, rng: &mut ChaCha8Rng, index: u32) -> Placement {
    let x = rng.gen_range(PLACEMENT_X_M.0..PLACEMENT_X_M.1);
    let y = rng.gen_range(PLACEMENT_Y_M.0..PLACEMENT_Y_M.1);
    let yaw = rng.gen_range(-std::f64::consts::PI..std::f64::consts::PI);
    Placement {
        index,
        base_from_object: upright_pose(config, [x, y], yaw),
    }
}

/// The random generator of placements of object `object_index` under `seed`.
pub fn placement_rng(seed: u64, object_index: u64) -> ChaCha8Rng {
    ChaCha8Rng::seed_from_u64(instance_seed(seed ^ 0x706c_6163, object_index))
}

#[cfg(test)]
mod tests {
    use super::*;
    use clap::Parser;
    use std::f64::consts::PI;

    #[derive(Parser)]
    struct Args {
        #[command(flatten)]
        stage: StageArgs,
    }

    fn options_in(bin_dir: &Path) -> HarnessOptions {
        let mut options = HarnessOptions::demo(Args::parse_from(["t"]).stage).unwrap();
        options.bin_dir = bin_dir.to_path_buf();
        options
    }

    /// The snapshot is taken with the arm parked: the shipped park joints leave the
    /// camera a clear view of every placement, and an arm reaching out over the
    /// table does not.
    #[test]
    fn the_parked_arm_leaves_the_camera_a_clear_view_of_the_placements() {
        let path = Path::new(env!("CARGO_MANIFEST_DIR")).join(crate::config::DEFAULT_CONFIG_PATH);
        let config = CellConfig::load(&path).unwrap();
        let robot = crate::robot::Robot::load(&config).unwrap();
        let camera = config.base_from_camera();
        let park = config.robot.park_joints_rad;
        assert_eq!(arm_in_view(&config, &robot, &camera, &park), None);
        // With the palm 0.3 m above the placement area's middle, it hides some.
        let above = crate::geometry::pose_from_params(&[0.6, 0.0, 0.30, PI, 0.0, PI]);
        let hand = crate::robot::HandPose::OPEN;
        let reaching = robot.reach(&above, &hand, &[park]).unwrap().joints;
        let (link, point) = arm_in_view(&config, &robot, &camera, &reaching).expect("in view");
        assert!(
            link.starts_with("lbr_") || link.starts_with("bh_"),
            "{link}"
        );
        assert!(
            point[0] >= PLACEMENT_X_M.0 && point[0] <= PLACEMENT_X_M.1 + 1e-9,
            "{point:?}"
        );
    }

    #[test]
    fn missing_sibling_binaries_are_named_with_the_command_that_builds_them() {
        let dir = crate::fsio::TempDir::new("bins").unwrap();
        std::fs::write(dir.join("cell-camera"), b"").unwrap();
        let err = check_binaries(&options_in(&dir)).unwrap_err().to_string();
        assert!(
            err.contains("cell-sim-hand") && err.contains("cell-plan"),
            "{err}"
        );
        assert!(
            !err.contains("cell-camera,"),
            "present binary listed: {err}"
        );
        assert!(err.contains("cargo build --release --bins"), "{err}");
    }
}
