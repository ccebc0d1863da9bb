//! Hardware-in-loop tests of the executor: the hand emulator (`cell-sim-hand`) and
//! the FRI robot simulator (`cell-sim-arm`) run as separate processes; this process
//! runs the executor with the real drivers over a cross-process CAN bus (whose hub
//! this process hosts) and loopback UDP (ephemeral ports).
//!
//! Real time runs here, so the simulated robot uses a 2 ms cycle and lenient link
//! quality levels (a loaded machine must not drop it to monitor by accident); every
//! wait has a timeout and no test asserts how long anything took.

use graspcell::clock::{Clock, SystemClock};
use graspcell::config::{CellConfig, DEFAULT_CONFIG_PATH};
use graspcell::execute::{
    ExecuteError, ExecutionReport, ExecutionRequest, Executor, ExecutorConfig, Outcome, Phase,
    SafetyError, SafetyLimits,
};
use graspcell::fsio::TempDir;
use graspcell::geometry::{pose_from_params, Pose, PoseJson};
use graspcell::hw::can::{CanBus, FaultConfig, Hub, UnixBus};
use graspcell::hw::fri::{DriverConfig, FriDriver, FriState, Quality};
use graspcell::hw::hand::{Hand, HandError, HandTiming, Puck};
use graspcell::robot::kinematics::ArmJoints;
use graspcell::robot::Robot;
use std::f64::consts::PI;
use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::sync::atomic::{AtomicBool, AtomicU32, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

/// Where the simulated arm starts: palm about 0.49 m over the table, facing down.
const HOME: ArmJoints = graspcell::config::DEFAULT_PARK_JOINTS_RAD;
/// Where the emulated object stops F1, F2, F3 (rad).
const CONTACT_RAD: [f64; 3] = [1.0, 1.1, 1.2];

/// A name no other test (or parallel test run) uses.
fn unique(tag: &str) -> String {
    static COUNTER: AtomicU32 = AtomicU32::new(0);
    format!(
        "x-{tag}-{}-{}",
        std::process::id(),
        COUNTER.fetch_add(1, Ordering::SeqCst)
    )
}

fn config_path() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join(DEFAULT_CONFIG_PATH)
}

fn top_down(x: f64, y: f64, z: f64) -> Pose {
    pose_from_params(&[x, y, z, PI, 0.0, PI])
}

/// IK without the reachability checks (so unsafe plans can be made), must converge.
fn solve(robot: &Robot, pose: &Pose, seed: &ArmJoints) -> ArmJoints {
    let s = robot.ik.solve(pose, &[*seed]).unwrap_or_else(|best| {
        panic!("test setup: no IK for {pose:?}: {best:?}");
    });
    s.joints
}

/// A plan for a grasp at `palm`, pre-grasp `pregrasp`, solved independently.
fn plan(robot: &Robot, palm: &Pose, pregrasp: &Pose) -> ExecutionRequest {
    let pre = solve(robot, pregrasp, &HOME);
    let grasp = solve(robot, palm, &pre);
    ExecutionRequest {
        palm: PoseJson::from(palm),
        pregrasp: PoseJson::from(pregrasp),
        joints_rad: grasp,
        pregrasp_joints_rad: pre,
        spread_rad: 0.3,
        preshape_rad: graspcell::robot::PreshapeRad::OPEN,
        max_overtravel_m: None,
        task: None,
        method: None,
    }
}

/// The good grasp: top-down at (0.6, 0, 0.20), from 0.10 m above.
fn good_plan(robot: &Robot) -> ExecutionRequest {
    plan(robot, &top_down(0.6, 0.0, 0.20), &top_down(0.6, 0.0, 0.30))
}

/// Kills the child on every exit path.
struct ChildGuard(Child);

impl Drop for ChildGuard {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

/// How the hand's bus is set up.
enum Bus {
    /// Fault-free; this process hosts the hub by opening the bus first.
    Clean,
    /// This process binds a hub that loses frames, seeded.
    Lossy { loss: f64, seed: u64 },
}

/// The two simulator processes and the drivers of this process.
struct Rig {
    robot: Arc<Robot>,
    cell: CellConfig,
    driver: FriDriver,
    hand: Option<Hand<Box<dyn CanBus>>>,
    hub: Option<Hub>,
    candump: PathBuf,
    clock: Arc<dyn Clock>,
    // Dropped last: the processes outlive the drivers talking to them, and the
    // directory (the hand emulator's CAN log) the processes.
    _arm: ChildGuard,
    _hand: ChildGuard,
    _dir: TempDir,
}

impl Rig {
    fn new(bus: Bus, hand_flags: &[&str]) -> Rig {
        let cell = CellConfig::load(&config_path()).unwrap();
        let robot = Arc::new(Robot::load(&cell).unwrap());
        let clock: Arc<dyn Clock> = Arc::new(SystemClock::new());
        let dir = TempDir::new("execute-execute").unwrap();
        let candump = dir.join("hand.log");

        let driver = FriDriver::start(
            DriverConfig {
                bind_addr: "127.0.0.1:0".parse().unwrap(),
                timeout_s: 0.5,
                ..DriverConfig::default()
            },
            Arc::clone(&clock),
        )
        .unwrap();
        let home: Vec<String> = HOME.iter().map(|q| q.to_string()).collect();
        let arm = ChildGuard(
            Command::new(env!("CARGO_BIN_EXE_cell-sim-arm"))
                .arg("--pc-addr")
                .arg(driver.local_addr().to_string())
                .arg("--config")
                .arg(config_path())
                .arg(format!("--initial-joints={}", home.join(",")))
                .args(["--cycle-ms", "2"])
                .args(["--miss-rates", "0.05,0.2,0.5"])
                .args(["--consecutive-misses", "15,30"])
                .stdout(Stdio::null())
                .stderr(Stdio::null())
                .spawn()
                .unwrap(),
        );

        let name = unique("hand");
        let interface = format!("virtual:{name}");
        // This process opens the bus first, so the hub lives here.
        let (node, hub): (Box<dyn CanBus>, Option<Hub>) = match bus {
            Bus::Clean => (Box::new(UnixBus::open(&name).unwrap()), None),
            Bus::Lossy { loss, seed } => {
                let hub = Hub::bind_with_faults(
                    &name,
                    FaultConfig {
                        loss_probability: loss,
                        seed,
                        ..FaultConfig::default()
                    },
                )
                .unwrap();
                (Box::new(UnixBus::connect(&name).unwrap()), Some(hub))
            }
        };
        let contact: Vec<String> = CONTACT_RAD.iter().map(|c| c.to_string()).collect();
        let mut hand_child = ChildGuard(
            Command::new(env!("CARGO_BIN_EXE_cell-sim-hand"))
                .args(["--interface", &interface])
                .args(["--contact-rad", &contact.join(",")])
                .args(["--boot-s", "0.2"])
                .arg("--candump")
                .arg(&candump)
                .args(hand_flags)
                .stdout(Stdio::piped())
                .stderr(Stdio::null())
                .spawn()
                .unwrap(),
        );
        let mut ready = String::new();
        BufReader::new(hand_child.0.stdout.take().unwrap())
            .read_line(&mut ready)
            .unwrap();
        assert_eq!(ready.trim(), format!("ready {interface}"));
        let hand = Hand::new(node, Arc::clone(&clock), HandTiming::default());
        Rig {
            robot,
            cell,
            driver,
            hand: Some(hand),
            hub,
            candump,
            clock,
            _arm: arm,
            _hand: hand_child,
            _dir: dir,
        }
    }

    fn executor(&mut self) -> Executor<&FriDriver, Box<dyn CanBus>> {
        let config = ExecutorConfig {
            // Generous on a loaded machine; never asserted.
            arm_ready_timeout_s: 60.0,
            ..ExecutorConfig::from_cell(&self.cell)
        };
        Executor::new(
            &self.driver,
            self.hand.take().unwrap(),
            Arc::clone(&self.robot),
            SafetyLimits::from_cell(&self.cell, &self.robot),
            config,
            Arc::clone(&self.clock),
        )
    }

    /// The palm at the joints the simulator process last measured.
    fn measured_palm(&self) -> nalgebra::Vector3<f64> {
        let q = self.driver.status().measured_rad;
        self.robot.arm().palm(&q).translation.vector
    }

    fn candump_log(&self) -> String {
        std::fs::read_to_string(&self.candump).unwrap_or_default()
    }
}

fn assert_home(q: &ArmJoints) {
    assert!(
        (0..7).all(|j| (q[j] - HOME[j]).abs() < 1e-5),
        "the arm moved: {q:?}"
    );
}

/// What a successful run must show, checked against the simulators' own data.
fn assert_grasped(rig: &Rig, report: &ExecutionReport) {
    assert_eq!(report.outcome, Outcome::Success, "{}", report.human());
    assert_eq!(
        report.phases.iter().map(|p| p.phase).collect::<Vec<_>>(),
        [
            Phase::ArmReady,
            Phase::Validate,
            Phase::HandBringup,
            Phase::Preshape,
            Phase::Pregrasp,
            Phase::Approach,
            Phase::Close,
            Phase::Lift,
            Phase::Hold
        ]
    );
    // Measured by the arm process: 0.10 m above where the approach to contact
    // ended; nothing in the arm simulator's world, so the whole overtravel
    // (0.05 m) past the grasp at (0.6, 0, 0.20).
    let palm = rig.measured_palm();
    assert!(
        (palm - nalgebra::Vector3::new(0.6, 0.0, 0.25)).norm() < 2e-3,
        "palm at {palm:?}"
    );
    // Read from the hand process: every finger rests on the object.
    let hand = report.hand_positions.unwrap();
    for (got, want) in hand.fingers_rad.iter().zip(CONTACT_RAD) {
        assert!((got - want).abs() < 1e-3, "{hand:?}");
    }
    assert_eq!(report.fingers_in_contact, Puck::FINGERS.to_vec());
    let hold = report.phases.last().unwrap();
    assert!(hold.ok && hold.duration_s >= 2.0, "{hold:?}");
}

#[test]
fn executor_with_emulators_in_other_processes_completes_a_grasp() {
    let mut rig = Rig::new(Bus::Clean, &[]);
    let request = good_plan(&rig.robot);
    let report = rig.executor().execute(&request);
    eprintln!("{}", report.human());
    assert_grasped(&rig, &report);
    // The hand process logged CMD = C ([0x80|29, 0, 18, 0, 0, 0]) to F1, F2, F3.
    let log = rig.candump_log();
    for id in ["00B", "00C", "00D"] {
        let frame = format!(" {id}#9D0012000000");
        assert!(
            log.lines().any(|l| l.ends_with(&frame)),
            "no{frame} in the log"
        );
    }
}

#[test]
fn five_percent_can_loss_is_retried_or_fails_cleanly() {
    let mut completed = 0;
    for seed in 1..=3u64 {
        let mut rig = Rig::new(Bus::Lossy { loss: 0.05, seed }, &[]);
        let request = good_plan(&rig.robot);
        let report = rig.executor().execute(&request);
        let counts = rig.hub.as_ref().unwrap().fault_counts();
        assert!(counts.lost > 0, "seed {seed}: nothing lost: {counts:?}");
        match &report.error {
            None => {
                assert_grasped(&rig, &report);
                eprintln!(
                    "seed {seed}: completed in {:.2} s despite {} of {} frames lost",
                    report.total_s, counts.lost, counts.sent
                );
                completed += 1;
                break;
            }
            // Failing cleanly: a named hand error, then both devices stopped.
            Some(
                e @ ExecuteError::Hand {
                    source:
                        HandError::NoReply { .. }
                        | HandError::CommandIgnored { .. }
                        | HandError::SetNotApplied { .. }
                        | HandError::NotReady { .. },
                    ..
                },
            ) => {
                eprintln!("seed {seed}: failed cleanly after {counts:?}: {e}");
                assert!(report.stop.is_some());
            }
            Some(e) => panic!("seed {seed}: unclean failure after {counts:?}: {e}"),
        }
    }
    assert!(completed >= 1, "no run completed under 5 % loss");
}

#[test]
fn silent_puck_times_out_with_an_error_naming_it() {
    let mut rig = Rig::new(Bus::Clean, &["--absent", "F3"]);
    let request = good_plan(&rig.robot);
    let report = rig.executor().execute(&request);
    let err = report.error.as_ref().expect("it fails");
    assert!(
        matches!(
            err,
            ExecuteError::Hand {
                phase: Phase::HandBringup,
                source: HandError::NoReply {
                    puck: Puck::F3,
                    attempts: 5,
                    ..
                }
            }
        ),
        "{err}"
    );
    let text = err.to_string();
    assert!(
        text.contains("F3 (node 13)") && text.contains("hand_bringup"),
        "{text}"
    );
    assert_eq!(report.error_kind, Some("hand_no_reply"));
    assert!(report.stop.as_ref().unwrap().hand.contains("F3"));
    // The arm process reports the arm where it started.
    assert_home(&rig.driver.status().measured_rad);
}

#[test]
fn withheld_fri_answers_drop_the_robot_to_monitor_and_the_arm_holds() {
    let mut rig = Rig::new(Bus::Clean, &[]);
    let request = good_plan(&rig.robot);
    let approaching = AtomicBool::new(false);
    let driver = &rig.driver;
    let report = std::thread::scope(|scope| {
        // Once the approach motion runs, stop answering the robot.
        let fault = scope.spawn(|| {
            let deadline = Instant::now() + Duration::from_secs(120);
            while Instant::now() < deadline {
                if approaching.load(Ordering::SeqCst) && driver.status().motion_id.is_some() {
                    driver.set_withhold_answers(true);
                    return true;
                }
                std::thread::sleep(Duration::from_millis(1));
            }
            false
        });
        let mut ex = Executor::new(
            driver,
            rig.hand.take().unwrap(),
            Arc::clone(&rig.robot),
            SafetyLimits::from_cell(&rig.cell, &rig.robot),
            ExecutorConfig {
                arm_ready_timeout_s: 60.0,
                ..ExecutorConfig::from_cell(&rig.cell)
            },
            Arc::clone(&rig.clock),
        );
        let report = ex.execute_observed(&request, &mut |p| {
            if p == Phase::Approach {
                approaching.store(true, Ordering::SeqCst);
            }
        });
        approaching.store(true, Ordering::SeqCst);
        assert!(fault.join().unwrap(), "the approach never started");
        report
    });
    let err = report.error.as_ref().expect("it fails");
    assert!(
        matches!(
            err,
            ExecuteError::ArmDroppedToMonitor {
                phase: Phase::Approach,
                state: FriState::Monitor,
                quality: Quality::Unacceptable,
            }
        ),
        "{err}"
    );
    assert_eq!(report.error_kind, Some("arm_dropped_to_monitor"));
    // Stopped between pre-grasp and grasp, and the robot holds it there.
    let palm = rig.measured_palm();
    assert!(palm.z > 0.20 + 1e-3 && palm.z < 0.30 + 1e-3, "{palm:?}");
    let before = rig.driver.status();
    std::thread::sleep(Duration::from_millis(200));
    let after = rig.driver.status();
    assert_ne!(before.last_seq, after.last_seq, "measurements keep coming");
    assert_eq!(after.state, FriState::Monitor);
    assert_eq!(before.measured_rad, after.measured_rad, "the arm moved");
    assert!(report.stop.as_ref().unwrap().arm.contains("KRC holds"));
}

#[test]
fn unsafe_plans_are_refused_before_any_motion_with_the_numbers() {
    let mut rig = Rig::new(Bus::Clean, &[]);
    let robot = Arc::clone(&rig.robot);
    let mut ex = rig.executor();

    // A5 beyond its URDF limit (+-2.094395 rad) at the pre-grasp.
    let mut beyond = good_plan(&robot);
    beyond.pregrasp_joints_rad[5] = -2.2;
    beyond.pregrasp = PoseJson::from(&robot.arm().palm(&beyond.pregrasp_joints_rad));
    let report = ex.execute(&beyond);
    let err = report.error.as_ref().unwrap();
    assert_eq!(
        (err.kind(), err.phase()),
        ("unsafe_motion", Phase::Validate)
    );
    match err.safety_violation() {
        Some(SafetyError::OutOfLimit {
            joint,
            position_rad,
            limit_rad,
            ..
        }) => {
            assert_eq!(joint, "lbr_a5");
            assert_eq!(*position_rad, -2.2);
            assert!((limit_rad + 2.094395 - 0.01).abs() < 1e-9, "{limit_rad}");
        }
        _ => panic!("{err}"),
    }

    // The palm 3 cm over the table, below the 5 cm clearance.
    let low = plan(&robot, &top_down(0.6, 0.0, 0.03), &top_down(0.6, 0.0, 0.15));
    let report = ex.execute(&low);
    let err = report.error.as_ref().unwrap();
    assert!(
        matches!(
            err,
            ExecuteError::Unsafe {
                phase: Phase::Validate,
                motion: "approach",
                ..
            }
        ),
        "{err}"
    );
    match err.safety_violation() {
        Some(SafetyError::BelowTable {
            palm_z_m, min_z_m, ..
        }) => {
            assert!((palm_z_m - 0.03).abs() < 1e-3, "{palm_z_m}");
            assert_eq!(*min_z_m, 0.05);
        }
        _ => panic!("{err}"),
    }

    // The palm at x = 0.10, behind the workspace's x >= 0.15.
    let behind = plan(
        &robot,
        &top_down(0.10, 0.45, 0.30),
        &top_down(0.10, 0.45, 0.40),
    );
    let report = ex.execute(&behind);
    let err = report.error.as_ref().unwrap();
    assert_eq!(
        (err.kind(), err.phase()),
        ("unsafe_motion", Phase::Validate)
    );
    match err.safety_violation() {
        Some(SafetyError::OutsideWorkspace {
            palm_xyz_m, min_m, ..
        }) => {
            assert_eq!(min_m[0], 0.15);
            assert!(palm_xyz_m[0] <= 0.10 + 1e-3, "{palm_xyz_m:?}");
        }
        _ => panic!("{err}"),
    }
    for p in &report.phases {
        assert!(
            matches!(p.phase, Phase::ArmReady | Phase::Validate),
            "{p:?}"
        );
    }
    drop(ex);
    // Nothing moved: the arm process measures the start, the hand saw no frame.
    assert_home(&rig.driver.status().measured_rad);
    let log = rig.candump_log();
    assert!(log.trim().is_empty(), "the hand was addressed:\n{log}");
}

/// The shipped configuration with a free FRI port, a private bus and an absolute
/// URDF, written to `dir/cell.toml`.
fn private_config(dir: &Path, cell: &CellConfig) -> PathBuf {
    let text = std::fs::read_to_string(config_path()).unwrap();
    let text = text
        .replace(
            "urdf = \"lbr4_bh8_282.urdf\"",
            &format!("urdf = {:?}", cell.robot.urdf.display().to_string()),
        )
        .replace("127.0.0.1:49938", "127.0.0.1:0")
        .replace("timeout_s = 0.1", "timeout_s = 0.5")
        .replace(
            "\"virtual:hand\"",
            &format!("\"virtual:{}\"", unique("cli")),
        );
    let config = dir.join("cell.toml");
    std::fs::write(&config, text).unwrap();
    config
}

/// `cell execute --json --plan FILE` and `extra` options against in-process
/// simulators (fingers stop at 1.0, 1.1, 1.2 rad): success and the JSON report.
fn cell_execute(config: &Path, plan: &Path, extra: &[&str]) -> (bool, serde_json::Value) {
    let out = Command::new(env!("CARGO_BIN_EXE_cell"))
        .arg("--config")
        .arg(config)
        .args(["execute", "--json", "--hold-s", "0.5"])
        .args(extra)
        .args(["--sim-contact-rad", "1.0,1.1,1.2"])
        // Lenient link levels: a loaded machine must not drop the robot.
        .args(["--sim-miss-rates", "0.05,0.2,0.5"])
        .args(["--sim-consecutive-misses", "15,30"])
        .arg("--plan")
        .arg(plan)
        .stderr(Stdio::null())
        .output()
        .unwrap();
    let json: serde_json::Value = serde_json::from_slice(&out.stdout)
        .unwrap_or_else(|e| panic!("{e}: {}", String::from_utf8_lossy(&out.stdout)));
    (out.status.success(), json)
}

/// Fits of every model of the shipped mug database at `xyz` turned by `yaw_rad`,
/// written to `dir/name` for `cell plan --fits`.
fn mug_fits(dir: &Path, name: &str, xyz: [f64; 3], yaw_rad: f64) -> PathBuf {
    let db = Path::new(env!("CARGO_MANIFEST_DIR")).join("db/mug");
    let models = graspcell::category::CategoryDb::load(&db)
        .unwrap()
        .file
        .models;
    let fits: Vec<serde_json::Value> = models
        .iter()
        .map(|m| {
            serde_json::json!({
                "name": m.name,
                "base_from_model": {"xyz": xyz, "rpy": [0.0, 0.0, yaw_rad]},
                "eps_m2": 1e-5,
                "sigma_m2": 2e-6,
            })
        })
        .collect();
    let path = dir.join(name);
    std::fs::write(&path, serde_json::json!({ "fits": fits }).to_string()).unwrap();
    path
}

/// `cell plan --task TASK --db db/mug --fits FITS --out OUT` and `extra`: its exit
/// status, stdout and stderr.
fn cell_plan_out(
    config: &Path,
    task: &str,
    fits: &Path,
    out: &Path,
    extra: &[&str],
) -> (bool, String, String) {
    let out = Command::new(env!("CARGO_BIN_EXE_cell"))
        .arg("--config")
        .arg(config)
        .args(["plan", "--task", task, "--db"])
        .arg(Path::new(env!("CARGO_MANIFEST_DIR")).join("db/mug"))
        .arg("--fits")
        .arg(fits)
        .arg("--out")
        .arg(out)
        .args(extra)
        .output()
        .unwrap();
    let text = |b: &[u8]| String::from_utf8_lossy(b).into_owned();
    (out.status.success(), text(&out.stdout), text(&out.stderr))
}

/// Plan then execute: `cell plan --out p.json` writes the plan `cell execute --plan
/// p.json` runs, unchanged (one schema), on the shipped mug database.
#[test]
fn cell_plan_out_then_cell_execute_runs_the_planned_grasp() {
    let dir = TempDir::new("execute-plan-then-execute").unwrap();
    let cell = CellConfig::load(&config_path()).unwrap();
    let config = private_config(&dir, &cell);
    let fits_path = mug_fits(&dir, "fits.json", [0.55, 0.05, 0.0], 2.0);
    let plan_path = dir.join("p.json");
    let (ok, _, stderr) = cell_plan_out(&config, "top", &fits_path, &plan_path, &[]);
    assert!(ok, "{stderr}");
    let plan = ExecutionRequest::load(&plan_path).unwrap();
    assert_eq!(plan.task.as_deref(), Some("top"));
    assert_eq!(plan.method.as_deref(), Some("laplace"));
    let (ok, json) = cell_execute(&config, &plan_path, &[]);
    assert!(ok, "{json:#}");
    assert_eq!(json["outcome"], "success", "{json:#}");
    // The arm went where the plan said: the final palm is the lifted grasp pose.
    let palm = &json["final_palm"]["xyz"];
    for (axis, planned) in [(0, plan.palm.xyz[0]), (1, plan.palm.xyz[1])] {
        let reached = palm[axis].as_f64().unwrap();
        assert!(
            (reached - planned).abs() < 2e-3,
            "{palm} vs {:?}",
            plan.palm
        );
    }
}

/// A mug at x = 0.7 m with its handle turned to +y: the handle grasp the arm reaches
/// best is refused by the executor (its straight approach puts the forearm on the
/// table). `cell plan --out` plans again with the executor's checks in the
/// planner's constraint, as the plan stage does, and writes a plan `cell execute`
/// runs; with `--paper` the refusal is the answer, and nothing is written.
#[test]
fn cell_plan_out_plans_again_when_the_executor_refuses_the_motions() {
    let dir = TempDir::new("execute-plan-again").unwrap();
    let cell = CellConfig::load(&config_path()).unwrap();
    let config = private_config(&dir, &cell);
    let fits_path = mug_fits(&dir, "fits.json", [0.7, 0.0, 0.0], PI / 2.0);
    let plan_path = dir.join("p.json");
    let (ok, stdout, stderr) = cell_plan_out(&config, "handle", &fits_path, &plan_path, &[]);
    assert!(ok, "{stderr}");
    assert!(
        stdout.contains("first plan refused by the executor")
            && stdout.contains("lbr_link5 collides with the table"),
        "{stdout}"
    );
    let plan = ExecutionRequest::load(&plan_path).unwrap();
    assert_eq!(plan.task.as_deref(), Some("handle"));
    let (ok, json) = cell_execute(&config, &plan_path, &[]);
    assert!(ok, "{json:#}");
    assert_eq!(json["outcome"], "success", "{json:#}");

    let paper_path = dir.join("paper.json");
    let (ok, _, stderr) = cell_plan_out(
        &config,
        "handle",
        &fits_path,
        &paper_path,
        &["--paper", "robot"],
    );
    assert!(!ok, "the paper's protocol does not plan again");
    assert!(
        stderr.contains("executor accepts") || stderr.contains("joint solution"),
        "{stderr}"
    );
    assert!(!paper_path.exists());

    // Start joints beyond the arm's limits are refused before any planning.
    let (ok, _, stderr) = cell_plan_out(
        &config,
        "handle",
        &fits_path,
        &paper_path,
        &["--from-joints", "9,0,0,0,0,0,0"],
    );
    assert!(!ok);
    assert!(
        stderr.contains("--from-joints") && stderr.contains("lbr_a1"),
        "{stderr}"
    );
    assert!(!paper_path.exists());
}

#[test]
fn cell_execute_cli_runs_a_plan_against_in_process_simulators() {
    let dir = TempDir::new("execute-cli").unwrap();
    let cell = CellConfig::load(&config_path()).unwrap();
    let robot = Robot::load(&cell).unwrap();
    let config = private_config(&dir, &cell);
    let run = |plan: &ExecutionRequest, name: &str, extra: &[&str]| {
        let path = dir.join(name);
        std::fs::write(&path, serde_json::to_string(plan).unwrap()).unwrap();
        cell_execute(&config, &path, extra)
    };
    let (ok, json) = run(&good_plan(&robot), "good.json", &[]);
    assert!(ok, "{json:#}");
    assert_eq!(json["outcome"], "success");
    // Without --park nothing is released.
    assert!(
        json["park"].is_null() && json["park_error"].is_null(),
        "{json:#}"
    );
    let palm = &json["final_palm"]["xyz"];
    // The approach went the whole overtravel (nothing to touch), then the lift.
    assert!((palm[2].as_f64().unwrap() - 0.25).abs() < 2e-3, "{palm}");
    let fingers = &json["hand_positions"]["fingers_rad"];
    assert!(
        (fingers[2].as_f64().unwrap() - 1.2).abs() < 1e-3,
        "{fingers}"
    );

    let mut low = good_plan(&robot);
    low.palm.xyz[2] = 0.03;
    low.joints_rad = solve(&robot, &top_down(0.6, 0.0, 0.03), &low.pregrasp_joints_rad);
    let (ok, json) = run(&low, "low.json", &["--park"]);
    assert!(!ok, "an unsafe plan must exit non-zero");
    assert_eq!(json["outcome"], "failed");
    assert_eq!(json["error_kind"], "unsafe_motion");
    assert!(
        json["error"].as_str().unwrap().contains("below the table"),
        "{json:#}"
    );
    // A refused plan moved nothing, so --park has nothing to release.
    assert!(
        json["park"].is_null() && json["park_error"].is_null(),
        "{json:#}"
    );

    // With --park the held object is put down, the hand opens and the arm parks.
    let (ok, json) = run(&good_plan(&robot), "good.json", &["--park"]);
    assert!(ok, "{json:#}");
    assert_eq!(json["outcome"], "success");
    assert!(json["park_error"].is_null(), "{json:#}");
    for motion in ["put_down", "retreat", "park"] {
        let m = &json["park"][motion];
        assert!(
            m["duration_s"].as_f64().unwrap() > 0.0,
            "{motion}: {json:#}"
        );
    }
}
