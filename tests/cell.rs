//! The whole cell as real processes over iceoryx2 (issue 8, issue 10): one simulated
//! trial end to end, a stage killed mid-trial, the log killed during a campaign, and
//! the systemd units against the binaries.

use graspcell::category::CategoryDb;
use graspcell::cell::harness::{
    novel_object, placement_rng, random_placement, Cell, HarnessOptions,
};
use graspcell::cell::setup::TrialSetup;
use graspcell::cell::StageArgs;
use graspcell::config::CellConfig;
use graspcell::fsio::TempDir;
use graspcell::ipc::{Domain, FailureCause, Grade, JointStates, Stage, TrialResult};
use graspcell::mesh::procedural::Category;
use graspcell::trial::TrialLog;
use std::path::{Path, PathBuf};
use std::time::Duration;

fn bin_dir() -> PathBuf {
    Path::new(env!("CARGO_BIN_EXE_cell-camera"))
        .parent()
        .unwrap()
        .to_path_buf()
}

struct Fixture {
    cell: Cell,
    config: CellConfig,
    db: CategoryDb,
    log_path: PathBuf,
    /// Removed when the fixture is dropped, after the cell.
    _run_dir: TempDir,
    n: u64,
}

fn start(tag: &str, domain: &Domain) -> Fixture {
    let run_dir = TempDir::new(&format!("cell-{tag}")).unwrap();
    let stage = StageArgs::in_domain(Path::new("robot/cell.toml"), domain, &run_dir);
    let log_path = run_dir.join("trials.sqlite");
    let options = HarnessOptions {
        stage,
        bin_dir: bin_dir(),
        db_dir: PathBuf::from("db"),
        log_path: log_path.clone(),
        hold_s: 0.1,
        trial_timeout_s: 120.0,
        simulated_devices: true,
        observer: Default::default(),
        protocol: graspcell::ipc::Protocol::Cell,
        faulty_links: false,
        stderr_dir: None,
    };
    Fixture {
        cell: Cell::start(options, domain.clone()).expect("cell starts"),
        config: CellConfig::load(Path::new("robot/cell.toml")).unwrap(),
        db: CategoryDb::load(Path::new("db/mug")).unwrap(),
        log_path,
        _run_dir: run_dir,
        n: 0,
    }
}

impl Fixture {
    fn setup(&mut self, campaign: Option<&str>) -> TrialSetup {
        let i = self.n;
        self.n += 1;
        let mut rng = placement_rng(7, i);
        TrialSetup {
            trial_id: self.cell.new_trial_id(),
            category: Category::Mug,
            object: novel_object(Category::Mug, 7, i, &self.db),
            placement: random_placement(&self.config, &mut rng, i as u32),
            campaign_id: campaign.map(str::to_string),
            noise_seed: i,
            perception_seed: i,
            source: graspcell::cell::setup::ObjectSource::Training,
            lab: None,
        }
    }

    fn trial(
        &mut self,
        setup: &TrialSetup,
        after_send: &mut dyn FnMut(&mut Cell),
    ) -> Option<TrialResult> {
        self.cell
            .run_trial(
                Some(setup),
                setup.trial_id,
                "mug",
                "top",
                "laplace",
                after_send,
            )
            .expect("trial runs")
    }

    fn finish(self) {
        let leftover = self.cell.stop().unwrap();
        assert_eq!(
            leftover,
            Vec::<PathBuf>::new(),
            "no shared memory left behind"
        );
    }
}

fn latest_joints(sub: &graspcell::ipc::MessageSubscriber<JointStates>) -> [f64; 7] {
    let mut last = None;
    // Drain the queue, then wait for a fresh one (the executor sends every 100 ms).
    while let Some(j) = sub.try_receive().unwrap() {
        last = Some(j);
    }
    if let Some(j) = sub.receive_timeout(Duration::from_secs(5)).unwrap() {
        last = Some(j);
    }
    last.expect("joint states from the executor").joints.arm_rad
}

#[test]
fn one_trial_through_every_process_then_a_killed_stage_fails_the_trial_and_rejoins() {
    let domain = Domain::temporary("cell-pipeline").unwrap();
    let mut f = start("pipeline", &domain);

    // 1. One simulated trial through camera, perceive, plan, execute and log.
    let setup = f.setup(None);
    let result = f.trial(&setup, &mut |_| {}).expect("a result");
    let grade = result.grade().unwrap();
    let cause = result.cause().unwrap();
    assert_ne!(cause, FailureCause::StageDied, "{result:?}");
    assert_ne!(cause, FailureCause::Timeout, "{result:?}");
    let t = result.timings;
    assert!(t.capture_s > 0.0 && t.perceive_s > 0.0, "{t:?}");
    if grade != Grade::Failure || cause == FailureCause::Execution {
        // It was executed: the grasp command came after the snapshot.
        assert!(t.snapshot_to_grasp_command_s > t.perceive_s, "{t:?}");
    }
    let log = TrialLog::open_existing(&f.log_path).unwrap();
    let rows = log.trials().unwrap();
    assert_eq!(rows.len(), 1);
    let row = &rows[0];
    assert_eq!(row.trial.object, setup.object);
    assert_eq!(row.trial.method, "laplace");
    let grading = row.grading.as_ref().expect("graded");
    assert_eq!(format!("{:?}", grading.grade), format!("{grade:?}"));
    // The snapshot is kept, organised, for replay.
    let snapshot = row.trial.snapshot_path.as_ref().expect("snapshot recorded");
    let cloud = graspcell::cloud::io::read_cloud(snapshot).unwrap();
    assert_eq!((cloud.width, cloud.height), (640, 480));
    assert!(cloud.valid_points().count() > 100_000);
    drop(log);

    // 2. kill -9 of perception mid-trial: the trial fails with that cause, the arm holds.
    let watcher = Stage::start(f.cell.domain(), "watcher").unwrap();
    let joints = watcher.subscriber::<JointStates>().unwrap();
    let before = latest_joints(&joints);
    let setup = f.setup(None);
    let result = f
        .trial(&setup, &mut |cell| cell.kill("perceive").unwrap())
        .expect("a result");
    assert_eq!(result.grade().unwrap(), Grade::Failure);
    assert_eq!(result.cause().unwrap(), FailureCause::StageDied);
    let after = latest_joints(&joints);
    for (a, b) in before.iter().zip(after) {
        assert!(
            (a - b).abs() < 1e-4,
            "the arm moved: {before:?} -> {after:?}"
        );
    }

    // 3. The restarted stage rejoins (it cleans the dead node's resources itself).
    assert_eq!(f.cell.supervise().unwrap(), vec!["perceive".to_string()]);
    let setup = f.setup(None);
    let result = f.trial(&setup, &mut |_| {}).expect("a result");
    assert_ne!(result.cause().unwrap(), FailureCause::StageDied);
    assert_eq!(f.cell.restarts("perceive"), 1);
    drop(joints);
    drop(watcher);
    f.finish();
}

/// Issue 21 item 7: one trial of every fault kind through the whole cell. Nothing
/// unsafe reaches the robot, no answered trial is missing from the log, nothing
/// panics or hangs, and every failed trial names its cause.
#[test]
fn a_fault_campaign_of_every_kind_is_safe_and_loses_nothing() {
    use graspcell::cell::chaos::{ChaosOptions, FaultKind};
    let domain = Domain::temporary("cell-chaos").unwrap();
    let run_dir = graspcell::fsio::TempDir::new("cell-chaos").unwrap();
    let stage = StageArgs::in_domain(Path::new("robot/cell.toml"), &domain, &run_dir);
    let mut harness = HarnessOptions::demo(stage).unwrap();
    harness.bin_dir = bin_dir();
    harness.hold_s = 0.1;
    harness.trial_timeout_s = 60.0;
    let db = CategoryDb::load(Path::new("db/mug")).unwrap();
    let options = ChaosOptions {
        trials: FaultKind::ALL.len() as u32,
        seed: 3,
        category: "mug".into(),
        task: "top".into(),
        method: "laplace".into(),
        kinds: FaultKind::ALL.to_vec(),
    };
    let mut trials = Vec::new();
    let summary =
        graspcell::cell::chaos::run(harness, (*domain).clone(), &db, &options, &mut |t| {
            trials.push(t.clone())
        })
        .unwrap();
    let text = summary.text();
    // The first unsafe command's reason leads: a CI log keeps the ends of a message.
    let first = summary.first_unsafe.as_deref().unwrap_or("-");
    assert_eq!(summary.unsafe_commands, 0, "first unsafe: {first}\n{text}");
    assert!(summary.commands_audited > 1000, "{text}");
    assert_eq!(summary.log_rows_lost, 0, "{text}");
    assert_eq!(summary.panics, 0, "{text}");
    assert_eq!(summary.hangs, 0, "{text}");
    let injected = if summary.disk_full.starts_with("not injected") {
        FaultKind::ALL.len() - 1
    } else {
        FaultKind::ALL.len()
    };
    assert_eq!(summary.faults.len(), injected, "{text}");
    for t in &trials {
        assert!(
            t.outcome == "completed" || t.cause.is_some(),
            "{}",
            t.text()
        );
    }
    let [_, lost, corrupted] = summary.can_frames;
    assert!(lost + corrupted > 0, "the CAN faults struck: {text}");
    let [withheld, delayed, spoofed] = summary.fri_withheld_delayed_spoofed;
    assert!(withheld > 0 && delayed > 0 && spoofed > 0, "{text}");
    let log = TrialLog::open_existing(&summary.log_path).unwrap();
    assert_eq!(log.trials().unwrap().len() as u32, summary.log_rows);
    drop(log);
    domain.remove().unwrap();
}

#[test]
fn killing_the_log_during_a_campaign_keeps_every_graded_trial() {
    let domain = Domain::temporary("cell-logkill").unwrap();
    let mut f = start("logkill", &domain);
    let mut results = Vec::new();
    for k in 0..3 {
        let setup = f.setup(Some("logkill"));
        f.cell.supervise().unwrap();
        let result = f.trial(&setup, &mut |cell| {
            if k == 1 {
                cell.kill("log").unwrap();
            }
        });
        results.push((setup, result));
    }
    assert!(results[1].1.is_none(), "the killed log answered");
    assert_eq!(f.cell.restarts("log"), 1);
    let log = TrialLog::open_existing(&f.log_path).unwrap();
    assert_eq!(log.integrity_check().unwrap(), "ok");
    let rows = log.trials().unwrap();
    // Every trial whose result was published is in the log with that grade.
    for (setup, result) in results.iter().filter(|(_, r)| r.is_some()) {
        let result = result.as_ref().unwrap();
        let row = rows
            .iter()
            .find(|r| {
                r.trial.object == setup.object && r.trial.placement.index == setup.placement.index
            })
            .unwrap_or_else(|| panic!("trial {} missing from the log", setup.trial_id));
        let grading = row.grading.as_ref().expect("graded");
        assert_eq!(
            format!("{:?}", grading.grade),
            format!("{:?}", result.grade().unwrap())
        );
        assert_eq!(row.trial.campaign_id.as_deref(), Some("logkill"));
    }
    assert!(
        rows.iter().all(|r| r.grading.is_some()),
        "no half-written trial"
    );
    drop(log);
    f.finish();
}

#[test]
fn every_systemd_unit_starts_a_stage_binary_with_arguments_it_accepts() {
    for stage in graspcell::cell::STAGES {
        let unit = std::fs::read_to_string(format!("systemd/cell-{stage}.service")).unwrap();
        let exec = unit
            .lines()
            .find_map(|l| l.strip_prefix("ExecStart="))
            .unwrap_or_else(|| panic!("cell-{stage}.service: no ExecStart"));
        let mut words = exec.split_whitespace();
        let program = words.next().unwrap();
        assert_eq!(program, format!("/usr/local/bin/cell-{stage}"));
        let binary = bin_dir().join(format!("cell-{stage}"));
        if !binary.exists() {
            panic!("{}: no such binary", binary.display());
        }
        let status = std::process::Command::new(&binary)
            .args(words)
            .arg("--help")
            .stdout(std::process::Stdio::null())
            .status()
            .unwrap();
        assert!(
            status.success(),
            "cell-{stage} rejects its unit's arguments"
        );
        assert!(unit.contains("Type=notify") && unit.contains("WatchdogSec="));
    }
}

#[test]
fn systemd_analyze_verify_passes_on_every_unit_with_the_binaries_installed() {
    // A root with the system's own units, ours in /etc/systemd/system and the stage
    // binaries in /usr/local/bin, as an installation has them.
    let analyze = Path::new("/usr/bin/systemd-analyze");
    assert!(
        analyze.exists(),
        "systemd-analyze is missing: install Debian's systemd package (.ci/run does)"
    );
    let root = TempDir::new("cell-systemd-root").unwrap();
    let units = root.join("etc/systemd/system");
    let bin = root.join("usr/local/bin");
    let system = root.join("usr/lib/systemd/system");
    for dir in [&units, &bin, &system] {
        std::fs::create_dir_all(dir).unwrap();
    }
    for entry in std::fs::read_dir("/usr/lib/systemd/system")
        .unwrap()
        .flatten()
    {
        let path = entry.path();
        if path.is_file() && !path.is_symlink() {
            std::fs::copy(&path, system.join(entry.file_name())).unwrap();
        }
    }
    let mut names = Vec::new();
    for entry in std::fs::read_dir("systemd").unwrap().flatten() {
        std::fs::copy(entry.path(), units.join(entry.file_name())).unwrap();
        names.push(entry.file_name().to_string_lossy().into_owned());
    }
    names.sort();
    for stage in graspcell::cell::STAGES {
        let name = format!("cell-{stage}");
        let target = bin.join(&name);
        if std::fs::hard_link(bin_dir().join(&name), &target).is_err() {
            std::fs::copy(bin_dir().join(&name), &target).unwrap();
        }
    }
    let out = std::process::Command::new(analyze)
        .arg("verify")
        .arg(format!("--root={}", root.display()))
        .args(&names)
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(
        out.status.success() && stderr.trim().is_empty(),
        "systemd-analyze verify {names:?}: {}\n{stderr}",
        out.status
    );
    assert_eq!(names.len(), graspcell::cell::STAGES.len() + 1, "{names:?}");
}

/// `systemd-analyze security --offline=true`: the four stages without real-time needs
/// at an exposure of at most 2.5, the executor (UDP, CAN, real-time priority) at most
/// 3.5 (each unit's comments say why for what remains).
#[test]
fn systemd_units_are_hardened_to_their_exposure_budget() {
    for stage in graspcell::cell::STAGES {
        let unit = format!("systemd/cell-{stage}.service");
        let out = std::process::Command::new("/usr/bin/systemd-analyze")
            .args(["security", "--offline=true", "--no-pager", &unit])
            .output()
            .expect("systemd-analyze (Debian's systemd package; .ci/setup installs it)");
        let text = String::from_utf8_lossy(&out.stdout);
        let exposure: f64 = text
            .lines()
            .find_map(|l| l.split("Overall exposure level for").nth(1))
            .and_then(|rest| rest.split(':').nth(1))
            .and_then(|rest| rest.split_whitespace().next())
            .and_then(|n| n.parse().ok())
            .unwrap_or_else(|| panic!("{unit}: no exposure level in:\n{text}"));
        let budget = if stage == "execute" { 3.5 } else { 2.5 };
        assert!(exposure <= budget, "{unit}: exposure {exposure} > {budget}");
    }
}
