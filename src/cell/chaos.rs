//! The fault campaign (`cell chaos`): whole simulated trials, each with one fault
//! injected at random, and an account of what the faults did: trials completed,
//! trials failed and why, unsafe commands the robot received, log rows lost,
//! panics and hangs.
//!
//! The faults, one per trial (kinds in a shuffled round robin, so that every kind
//! comes up; their strength and timing drawn at random), beside control trials
//! without a fault (`none`), whose failures are the grasps' own:
//! - `kill`: SIGKILL of a random stage, 0 to 3 s into the trial;
//! - `can-loss`, `can-corruption`: frames of the hand's bus lost or damaged
//!   (the harness hosts the bus, [`crate::hw::can::Hub::set_faults`]);
//! - `fri-withheld`, `fri-late`: the PC's answers never reach the robot, or reach it
//!   late (the harness relays FRI, [`crate::sim::fri_link`]);
//! - `fri-spoof`: a third host sends the executor forged measurements;
//! - `shm-corrupt`: a buggy peer publishes random bytes as every message type the
//!   stages receive (half of them with the running trial's id), and a cloud of
//!   garbage numbers;
//! - `disk-full`: the log's file system (a 16 MiB tmpfs, mounted when permitted) is
//!   filled while the trial runs and freed 8 to 15 s into it (after most trials
//!   have ended: their rows wait, unanswered, until there is room).
//!
//! What counts:
//! - unsafe commands: the arm simulator's audit ([`crate::sim::audit`]) of every
//!   command it received;
//! - lost log rows: trials requested whose row is not in the log file at the end
//!   (a killed log stage's successor records the trials it was following, from its
//!   journal, [`super::log::journal_dir`]; a full disk holds rows until there is
//!   room);
//! - panics: "panicked at" in any process's standard error;
//! - hangs: trials with no result within the trial timeout, devices not ready
//!   again within 30 s of a trial, and processes that did not stop on SIGTERM.

use super::harness::{placement_rng, random_placement, Cell, HarnessOptions};
use super::setup::{novel_object_in, TrialSetup};
use super::{CellError, STAGES};
use crate::category::CategoryDb;
use crate::fsio::{FileError, FileOp};
use crate::hw::can::{Corruption, FaultConfig};
use crate::ipc::{
    from_wire_bytes, AnyBitPattern, CameraStatus, CloudHeader, CloudTopic, Domain, ExecutionStatus,
    Fits, GraspPlan, JointStates, Message, Point, Stage, TrialRequest,
};
use crate::mesh::procedural::held_apart::Family;
use crate::mesh::procedural::{instance_seed, Category};
use crate::sim::fri_link::LinkFaults;
use rand::seq::SliceRandom;
use rand::{Rng, RngCore, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::Serialize;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::time::Duration;

/// How long the devices may take to recover after a trial's fault.
pub const DEVICES_RECOVER: Duration = Duration::from_secs(30);

/// One kind of fault.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum FaultKind {
    /// No fault: a control trial.
    None,
    /// SIGKILL of a stage mid-trial.
    Kill,
    /// CAN frames lost.
    CanLoss,
    /// CAN frames damaged.
    CanCorruption,
    /// FRI answers withheld.
    FriWithheld,
    /// FRI answers late.
    FriLate,
    /// Forged FRI measurements from a third host.
    FriSpoof,
    /// Random bytes published as messages.
    ShmCorrupt,
    /// The log's file system full.
    DiskFull,
}

impl FaultKind {
    /// Every kind.
    pub const ALL: [FaultKind; 9] = [
        FaultKind::None,
        FaultKind::Kill,
        FaultKind::CanLoss,
        FaultKind::CanCorruption,
        FaultKind::FriWithheld,
        FaultKind::FriLate,
        FaultKind::FriSpoof,
        FaultKind::ShmCorrupt,
        FaultKind::DiskFull,
    ];

    /// The kind's name (as in the report).
    pub fn name(self) -> &'static str {
        match self {
            FaultKind::None => "none",
            FaultKind::Kill => "kill",
            FaultKind::CanLoss => "can-loss",
            FaultKind::CanCorruption => "can-corruption",
            FaultKind::FriWithheld => "fri-withheld",
            FaultKind::FriLate => "fri-late",
            FaultKind::FriSpoof => "fri-spoof",
            FaultKind::ShmCorrupt => "shm-corrupt",
            FaultKind::DiskFull => "disk-full",
        }
    }
}

/// One fault, drawn: its kind, strength and timing.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Fault {
    /// The kind.
    pub kind: FaultKind,
    /// The stage killed (`kill`).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub stage: Option<&'static str>,
    /// Loss or corruption probability of CAN frames, or of a withheld FRI answer,
    /// or of a forged measurement per real one.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub probability: Option<f64>,
    /// Delay of late FRI answers (s).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub delay_s: Option<f64>,
    /// When after the request it strikes (`kill`), or is lifted (`disk-full`) (s).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub at_s: Option<f64>,
    /// Messages published (`shm-corrupt`).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub messages: Option<u32>,
}

impl Fault {
    /// A fault of `kind` with its strength and timing drawn from `rng`.
    pub fn draw(kind: FaultKind, rng: &mut ChaCha8Rng) -> Fault {
        let mut fault = Fault {
            kind,
            stage: None,
            probability: None,
            delay_s: None,
            at_s: None,
            messages: None,
        };
        match kind {
            FaultKind::None => {}
            FaultKind::Kill => {
                fault.stage = STAGES.choose(rng).copied();
                fault.at_s = Some(rng.gen_range(0.0..3.0));
            }
            FaultKind::CanLoss | FaultKind::CanCorruption => {
                fault.probability = Some(rng.gen_range(0.02..0.3))
            }
            FaultKind::FriWithheld => fault.probability = Some(rng.gen_range(0.02..0.6)),
            FaultKind::FriLate => fault.delay_s = Some(rng.gen_range(0.001..0.02)),
            FaultKind::FriSpoof => fault.probability = Some(rng.gen_range(0.1..1.0)),
            FaultKind::ShmCorrupt => fault.messages = Some(rng.gen_range(20..200)),
            FaultKind::DiskFull => fault.at_s = Some(rng.gen_range(8.0..15.0)),
        }
        fault
    }

    /// One line: the kind and its parameters.
    pub fn text(&self) -> String {
        let mut parts = vec![self.kind.name().to_string()];
        if let Some(s) = self.stage {
            parts.push(format!("cell-{s}"));
        }
        if let Some(p) = self.probability {
            parts.push(format!("p {p:.2}"));
        }
        if let Some(d) = self.delay_s {
            parts.push(format!("{:.1} ms", d * 1e3));
        }
        if let Some(t) = self.at_s {
            parts.push(format!("at {t:.1} s"));
        }
        if let Some(m) = self.messages {
            parts.push(format!("{m} messages"));
        }
        parts.join(" ")
    }
}

/// The kinds of `n` trials: `kinds` in turn, shuffled every round.
pub fn schedule(kinds: &[FaultKind], n: u32, rng: &mut ChaCha8Rng) -> Vec<FaultKind> {
    let mut out = Vec::with_capacity(n as usize);
    while out.len() < n as usize && !kinds.is_empty() {
        let mut round = kinds.to_vec();
        round.shuffle(rng);
        out.extend(round);
    }
    out.truncate(n as usize);
    out
}

/// What a fault campaign runs.
#[derive(Debug, Clone)]
pub struct ChaosOptions {
    /// Trials.
    pub trials: u32,
    /// Seed of the faults, objects and placements.
    pub seed: u64,
    /// Object category.
    pub category: String,
    /// Task.
    pub task: String,
    /// Planning method.
    pub method: String,
    /// Kinds of fault to draw from.
    pub kinds: Vec<FaultKind>,
}

/// One trial of a fault campaign.
#[derive(Debug, Clone, Serialize)]
pub struct ChaosTrial {
    /// Index in the campaign.
    pub index: u32,
    /// The cell's trial id.
    pub trial_id: u64,
    /// The fault injected.
    pub fault: Fault,
    /// `completed` (graded success or partial), `failed`, or `hang`.
    pub outcome: &'static str,
    /// Why it failed (the result's cause, or what became of the result).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub cause: Option<String>,
    /// Unsafe commands the robot received during the trial.
    pub unsafe_commands: u64,
}

impl ChaosTrial {
    /// One line of text.
    pub fn text(&self) -> String {
        format!(
            "{:>3} {:<40} {}{}{}",
            self.index,
            self.fault.text(),
            self.outcome,
            self.cause
                .as_ref()
                .map(|c| format!(" ({c})"))
                .unwrap_or_default(),
            if self.unsafe_commands > 0 {
                format!(", {} UNSAFE commands", self.unsafe_commands)
            } else {
                String::new()
            }
        )
    }
}

/// The account of a fault campaign.
#[derive(Debug, Clone, Default, Serialize)]
pub struct ChaosSummary {
    /// Trials run.
    pub trials: u32,
    /// Trials graded success or partial.
    pub completed: u32,
    /// Trials failed, by cause.
    pub failed: BTreeMap<String, u32>,
    /// Trials per fault kind.
    pub faults: BTreeMap<FaultKind, u32>,
    /// Commands the robot received, all audited.
    pub commands_audited: u64,
    /// Commands that broke a limit.
    pub unsafe_commands: u64,
    /// Why the first unsafe command was unsafe.
    pub first_unsafe: Option<String>,
    /// Trials requested that are not in the log file at the end.
    pub log_rows_lost: u32,
    /// Trials whose result the operator never got because their log stage was
    /// killed (failed; recorded by its successor).
    pub results_lost_with_log: u32,
    /// Rows in the log for this campaign's trials at the end.
    pub log_rows: u32,
    /// "panicked at" lines in the processes' standard error.
    pub panics: u32,
    /// The first panic message.
    pub first_panic: Option<String>,
    /// Trials without a result within the timeout, plus processes that did not stop
    /// on SIGTERM.
    pub hangs: u32,
    /// Stage restarts (after kills and any crash).
    pub restarts: u32,
    /// CAN frames sent, lost and corrupted on the hand's bus.
    pub can_frames: [u64; 3],
    /// FRI answers withheld and delayed, and forged measurements sent.
    pub fri_withheld_delayed_spoofed: [u64; 3],
    /// How the full disk was made (a tmpfs), or why it could not be.
    pub disk_full: String,
    /// The log file, `<run dir>/chaos.sqlite` (copied out of the tmpfs at the end).
    pub log_path: PathBuf,
}

impl ChaosSummary {
    /// The summary as text.
    pub fn text(&self) -> String {
        let failed: u32 = self.failed.values().sum();
        let causes = self
            .failed
            .iter()
            .map(|(c, n)| format!("{n} {c}"))
            .collect::<Vec<_>>()
            .join(", ");
        let faults = self
            .faults
            .iter()
            .map(|(k, n)| format!("{n} {}", k.name()))
            .collect::<Vec<_>>()
            .join(", ");
        format!(
            "{} trials ({faults}): {} completed, {failed} failed{}\n\
             unsafe commands: {} of {} audited{}\n\
             log rows lost: {} ({} rows recorded; {} results not answered because the log stage was killed, their rows written by its successor)\n\
             panics: {}{}\n\
             hangs: {}\n\
             stage restarts: {}; CAN frames sent/lost/corrupted {:?}; FRI answers withheld/delayed, forged measurements {:?}\n\
             disk full: {}\n\
             log: {}\n",
            self.trials,
            self.completed,
            if causes.is_empty() {
                String::new()
            } else {
                format!(" ({causes})")
            },
            self.unsafe_commands,
            self.commands_audited,
            self.first_unsafe
                .as_ref()
                .map(|f| format!(", first: {f}"))
                .unwrap_or_default(),
            self.log_rows_lost,
            self.log_rows,
            self.results_lost_with_log,
            self.panics,
            self.first_panic
                .as_ref()
                .map(|p| format!(", first: {p}"))
                .unwrap_or_default(),
            self.hangs,
            self.restarts,
            self.can_frames,
            self.fri_withheld_delayed_spoofed,
            self.disk_full,
            self.log_path.display(),
        )
    }
}

/// The log's own small file system, which a fault can fill.
struct LogDisk {
    mount: PathBuf,
    ballast: PathBuf,
}

impl LogDisk {
    /// Mounts a 16 MiB tmpfs at `dir` (needs CAP_SYS_ADMIN).
    fn mount(dir: &Path) -> Result<LogDisk, CellError> {
        crate::fsio::create_dir_all(dir)?;
        let out = std::process::Command::new("mount")
            .args(["-t", "tmpfs", "-o", "size=16m,mode=0700", "graspcell-chaos"])
            .arg(dir)
            .output()
            .map_err(|e| CellError::Process {
                name: "mount".to_string(),
                detail: e.to_string(),
            })?;
        if !out.status.success() {
            return Err(CellError::Process {
                name: "mount".to_string(),
                detail: format!(
                    "-t tmpfs on {}: {}",
                    dir.display(),
                    String::from_utf8_lossy(&out.stderr).trim()
                ),
            });
        }
        Ok(LogDisk {
            mount: dir.to_path_buf(),
            ballast: dir.join("ballast"),
        })
    }

    /// Fills the file system to the last byte.
    fn fill(&self) -> Result<(), CellError> {
        use std::io::Write;
        let io = |source| CellError::from(FileError::new(FileOp::Write, &self.ballast, source));
        let mut file = std::fs::File::create(&self.ballast).map_err(io)?;
        let block = vec![0u8; 64 * 1024];
        let mut size = block.len();
        while size > 0 {
            match file.write(&block[..size]) {
                Ok(0) => break,
                Ok(_) => {}
                Err(e) if e.kind() == std::io::ErrorKind::StorageFull => size /= 2,
                Err(e) => return Err(io(e)),
            }
        }
        Ok(())
    }

    /// Frees what [`LogDisk::fill`] took.
    fn free(&self) {
        let _ = std::fs::remove_file(&self.ballast);
    }
}

impl Drop for LogDisk {
    fn drop(&mut self) {
        self.free();
        let _ = std::process::Command::new("umount")
            .arg(&self.mount)
            .status();
    }
}

/// A peer that publishes random bytes as the messages the stages receive.
struct BuggyPeer {
    stage: Stage,
}

impl BuggyPeer {
    fn send<M: Message + AnyBitPattern>(
        &self,
        rng: &mut ChaCha8Rng,
        trial_id: u64,
        set_id: impl Fn(&mut M, u64),
    ) -> Result<(), CellError> {
        let mut bytes = vec![0u8; std::mem::size_of::<M>()];
        rng.fill_bytes(&mut bytes);
        let mut message: M = from_wire_bytes(&bytes);
        if rng.gen_bool(0.5) {
            set_id(&mut message, trial_id);
        }
        self.stage.publisher::<M>()?.send(&message)?;
        Ok(())
    }

    /// `n` random messages of random types, and a cloud of garbage numbers.
    fn publish(&self, n: u32, trial_id: u64, rng: &mut ChaCha8Rng) -> Result<(), CellError> {
        for _ in 0..n {
            match rng.gen_range(0..6) {
                0 => self.send::<TrialRequest>(rng, trial_id, |m, id| m.trial_id = id)?,
                1 => self.send::<Fits>(rng, trial_id, |m, id| m.trial_id = id)?,
                2 => self.send::<GraspPlan>(rng, trial_id, |m, id| m.trial_id = id)?,
                3 => self.send::<JointStates>(rng, trial_id, |_, _| {})?,
                4 => self.send::<ExecutionStatus>(rng, trial_id, |m, id| m.trial_id = id)?,
                _ => self.send::<CameraStatus>(rng, trial_id, |m, id| m.trial_id = id)?,
            }
        }
        let mut header_bytes = vec![0u8; std::mem::size_of::<CloudHeader>()];
        rng.fill_bytes(&mut header_bytes);
        let mut header: CloudHeader = from_wire_bytes(&header_bytes);
        header.trial_id = trial_id;
        header.width = 64;
        header.height = 1;
        let points: Vec<Point> = (0..64)
            .map(|_| {
                let mut b = vec![0u8; std::mem::size_of::<Point>()];
                rng.fill_bytes(&mut b);
                from_wire_bytes(&b)
            })
            .collect();
        // The cloud's publisher only while it sends (the camera needs the topic's
        // other publisher slot when it restarts).
        let clouds = self.stage.cloud_publisher(CloudTopic::Camera)?;
        if let Err(e) = clouds.send_copy(header, &points) {
            tracing::debug!("garbage cloud not sent: {e}");
        }
        Ok(())
    }
}

/// Counts "panicked at" lines in every `*.log` under `dir`; returns the count and
/// the first.
fn panics_in(dir: &Path) -> (u32, Option<String>) {
    let mut count = 0;
    let mut first = None;
    let Ok(entries) = std::fs::read_dir(dir) else {
        return (0, None);
    };
    for entry in entries.flatten() {
        let path = entry.path();
        let Ok(text) = std::fs::read_to_string(&path) else {
            continue;
        };
        for line in text.lines().filter(|l| l.contains("panicked at")) {
            count += 1;
            first.get_or_insert_with(|| {
                format!(
                    "{}: {line}",
                    path.file_name().unwrap_or_default().to_string_lossy()
                )
            });
        }
    }
    (count, first)
}

/// Takes the run directory for one campaign (created if missing): two would share
/// the simulators' state, the log and the tmpfs. The lock lasts as long as the file.
fn lock_run_dir(run_dir: &Path) -> Result<std::fs::File, CellError> {
    crate::fsio::create_dir_all(run_dir)?;
    let lock_path = run_dir.join("chaos.lock");
    let lock = std::fs::File::create(&lock_path)
        .map_err(|source| FileError::new(FileOp::Write, &lock_path, source))?;
    let locked = crate::sys::try_lock_file_exclusive(&lock)
        .map_err(|source| FileError::new(FileOp::Write, &lock_path, source))?;
    if !locked {
        return Err(CellError::Invalid(format!(
            "{}: another fault campaign runs in this directory",
            run_dir.display()
        )));
    }
    Ok(lock)
}

/// The small file system the log is kept on for `disk-full` faults (an earlier
/// campaign's rows copied onto it); without one (not root) the fault is dropped from
/// `kinds` and the summary says why.
fn log_disk(
    run_dir: &Path,
    harness: &mut HarnessOptions,
    kinds: &mut Vec<FaultKind>,
    summary: &mut ChaosSummary,
) -> Result<Option<LogDisk>, CellError> {
    Ok(match LogDisk::mount(&run_dir.join("logfs")) {
        Ok(disk) => {
            harness.log_path = disk.mount.join("chaos.sqlite");
            if summary.log_path.is_file() {
                std::fs::copy(&summary.log_path, &harness.log_path)
                    .map_err(|source| FileError::new(FileOp::Write, &harness.log_path, source))?;
            }
            summary.disk_full = "a 16 MiB tmpfs under the log, filled to the last byte".into();
            Some(disk)
        }
        Err(e) => {
            kinds.retain(|k| *k != FaultKind::DiskFull);
            summary.disk_full = format!("not injected ({e})");
            None
        }
    })
}

/// Sets the CAN and FRI links' faults of `fault` for the trial.
fn set_link_faults(cell: &Cell, fault: &Fault) -> Result<(), CellError> {
    let Some(links) = cell.faulty_links() else {
        return Ok(());
    };
    let kind = &fault.kind;
    let p = fault.probability.unwrap_or(0.0);
    let can = FaultConfig {
        loss_probability: if *kind == FaultKind::CanLoss { p } else { 0.0 },
        corrupt_probability: if *kind == FaultKind::CanCorruption {
            p
        } else {
            0.0
        },
        corruption: Corruption::Either,
        ..FaultConfig::default()
    };
    links
        .can
        .set_faults(&can)
        .map_err(|e| CellError::Invalid(e.to_string()))?;
    let fri = LinkFaults {
        withhold_probability: if *kind == FaultKind::FriWithheld {
            p
        } else {
            0.0
        },
        answer_delay_s: fault.delay_s.unwrap_or(0.0),
        spoof_probability: if *kind == FaultKind::FriSpoof { p } else { 0.0 },
    };
    links
        .fri
        .set_faults(fri)
        .map_err(|e| CellError::Invalid(e.to_string()))?;
    Ok(())
}

/// What became of a trial (`completed`, `failed` or `hang`) and the failure's cause,
/// counted in `summary`.
fn account(
    outcome: Result<Option<crate::ipc::TrialResult>, CellError>,
    summary: &mut ChaosSummary,
) -> Result<(&'static str, Option<String>), CellError> {
    let (outcome, cause) = match outcome {
        Ok(Some(result)) => {
            let grade = result.grade().ok();
            let cause = result.cause().ok();
            match (grade, cause) {
                (Some(g), _) if g != crate::ipc::Grade::Failure => ("completed", None),
                (_, Some(c)) => ("failed", Some(format!("{c:?}"))),
                _ => ("failed", Some("unreadable result".to_string())),
            }
        }
        Ok(None) => {
            summary.results_lost_with_log += 1;
            ("failed", Some("log stage killed".to_string()))
        }
        Err(CellError::Timeout { .. }) => {
            summary.hangs += 1;
            (
                "hang",
                Some("no result within the trial timeout".to_string()),
            )
        }
        Err(e) => return Err(e),
    };
    match outcome {
        "completed" => summary.completed += 1,
        _ => {
            *summary
                .failed
                .entry(cause.clone().unwrap_or_default())
                .or_default() += 1
        }
    }
    Ok((outcome, cause))
}

/// Strikes trial `trial_id` with `fault` once its request is out: kills a stage,
/// publishes garbage, or frees the full disk a while later (the links' faults are
/// set before, [`set_link_faults`]).
fn strike(
    cell: &mut Cell,
    fault: &Fault,
    peer: &BuggyPeer,
    disk: Option<&LogDisk>,
    trial_id: u64,
    rng: &mut ChaCha8Rng,
) -> Result<(), CellError> {
    match fault.kind {
        FaultKind::Kill => {
            std::thread::sleep(Duration::from_secs_f64(fault.at_s.unwrap_or(0.0)));
            cell.kill(fault.stage.unwrap_or("plan"))
        }
        FaultKind::ShmCorrupt => peer.publish(fault.messages.unwrap_or(0), trial_id, rng),
        FaultKind::DiskFull => {
            // The disk is freed a while into the trial (before the
            // result, which waits for the row to be written).
            let (at, ballast) = (fault.at_s.unwrap_or(0.0), disk.map(|d| d.ballast.clone()));
            std::thread::spawn(move || {
                std::thread::sleep(Duration::from_secs_f64(at));
                if let Some(b) = ballast {
                    let _ = std::fs::remove_file(b);
                }
            });
            Ok(())
        }
        _ => Ok(()),
    }
}

/// Runs a fault campaign on a cell started from `harness` (simulated devices) in
/// `domain`; calls `on_trial` after each trial.
pub fn run(
    mut harness: HarnessOptions,
    domain: Domain,
    db: &CategoryDb,
    options: &ChaosOptions,
    on_trial: &mut dyn FnMut(&ChaosTrial),
) -> Result<ChaosSummary, CellError> {
    let category: Category = options
        .category
        .parse()
        .map_err(|e| CellError::Invalid(format!("category {:?}: {e}", options.category)))?;
    let run_dir = harness.stage.run_dir.clone();
    let lock = lock_run_dir(&run_dir)?;
    let mut summary = ChaosSummary::default();
    let mut kinds = options.kinds.clone();
    // The log: <run dir>/chaos.sqlite, kept on the small file system while the
    // campaign runs (an earlier campaign's rows go along, and come back with the
    // new ones).
    summary.log_path = run_dir.join("chaos.sqlite");
    harness.log_path = summary.log_path.clone();
    let disk = if kinds.contains(&FaultKind::DiskFull) {
        log_disk(&run_dir, &mut harness, &mut kinds, &mut summary)?
    } else {
        summary.disk_full = "not asked for".into();
        None
    };
    harness.simulated_devices = true;
    harness.faulty_links = true;
    let stderr_dir = run_dir.join("stderr");
    let _ = std::fs::remove_dir_all(&stderr_dir);
    harness.stderr_dir = Some(stderr_dir.clone());
    let config = crate::config::CellConfig::load(&harness.stage.config)?;
    let campaign_id = format!("chaos-seed{}", options.seed);
    let mut rng = ChaCha8Rng::seed_from_u64(instance_seed(options.seed, 0xc4a0));
    let plan = schedule(&kinds, options.trials, &mut rng);
    let mut cell = Cell::start(harness, domain.clone())?;
    let peer = BuggyPeer {
        stage: Stage::start(&domain, "buggy-peer")?,
    };
    let mut requested = Vec::new();
    let mut audited_unsafe = 0;
    for (index, kind) in plan.iter().enumerate() {
        let index = index as u32;
        if super::stop_requested() {
            break;
        }
        let mut trial_rng = ChaCha8Rng::seed_from_u64(instance_seed(options.seed, index.into()));
        let fault = Fault::draw(*kind, &mut trial_rng);
        *summary.faults.entry(*kind).or_default() += 1;
        let mut placements = placement_rng(options.seed, index.into());
        let trial_seed = options.seed.wrapping_mul(1000).wrapping_add(index.into());
        // The demo's novel objects: the held-apart family.
        let (object, source) =
            novel_object_in(Family::HeldApart, category, options.seed, index.into(), db);
        let setup = TrialSetup {
            trial_id: cell.new_trial_id(),
            category,
            object: object.clone(),
            placement: random_placement(&config, &mut placements, index),
            campaign_id: Some(campaign_id.clone()),
            noise_seed: trial_seed,
            perception_seed: trial_seed,
            source,
            lab: None,
        };
        // Faults of the links and the disk last the trial.
        set_link_faults(&cell, &fault)?;
        if *kind == FaultKind::DiskFull {
            if let Some(disk) = &disk {
                disk.fill()?;
            }
        }
        requested.push(setup.trial_id);
        let mut strike_error = None;
        let outcome = cell.run_trial(
            Some(&setup),
            setup.trial_id,
            &options.category,
            &options.task,
            &options.method,
            &mut |cell| {
                if let Err(e) = strike(
                    cell,
                    &fault,
                    &peer,
                    disk.as_ref(),
                    setup.trial_id,
                    &mut trial_rng,
                ) {
                    strike_error = Some(e);
                }
            },
        );
        if let Some(e) = strike_error {
            return Err(e);
        }
        let (outcome, cause) = account(outcome, &mut summary)?;
        // Back to a healthy cell before the next trial.
        if let Some(links) = cell.faulty_links() {
            let _ = links.can.set_faults(&FaultConfig::default());
            let _ = links.fri.set_faults(LinkFaults::default());
        }
        if let Some(disk) = &disk {
            disk.free();
        }
        let restarted = cell.supervise()?;
        summary.restarts += restarted.len() as u32;
        // As an operator would: the next trial starts once the arm commands again
        // (after a drop to monitor mode) and the hand is initialised; a cell that
        // does not recover hangs.
        match cell.wait_devices_ready(DEVICES_RECOVER) {
            Ok(()) => {}
            Err(CellError::Timeout { what, .. }) => {
                summary.hangs += 1;
                tracing::error!("devices not ready after trial {index}: {what}");
            }
            Err(e) => return Err(e),
        }
        // The simulator's audit file is rewritten every 100 ms.
        std::thread::sleep(Duration::from_millis(250));
        let audit = cell.audit()?.unwrap_or_default();
        let trial = ChaosTrial {
            index,
            trial_id: setup.trial_id,
            fault,
            outcome,
            cause,
            unsafe_commands: audit.unsafe_commands - audited_unsafe,
        };
        audited_unsafe = audit.unsafe_commands;
        summary.trials += 1;
        on_trial(&trial);
    }
    let audit = cell.audit()?.unwrap_or_default();
    summary.commands_audited = audit.commands;
    summary.unsafe_commands = audit.unsafe_commands;
    summary.first_unsafe = audit.first_unsafe;
    if let Some(links) = cell.faulty_links() {
        let c = links.can.fault_counts();
        summary.can_frames = [c.sent, c.lost, c.corrupted];
        let f = links.fri.counts();
        summary.fri_withheld_delayed_spoofed = [f.withheld, f.delayed, f.spoofed];
    }
    let log_path = cell.log_path().to_path_buf();
    drop(peer);
    let stop = cell.stop_with_report()?;
    summary.hangs += stop.killed_after_sigterm.len() as u32;
    // The log's rows: every requested trial must be there.
    let log = crate::trial::TrialLog::open_existing(&log_path)?;
    let recorded: Vec<u64> = log
        .trials()?
        .into_iter()
        .filter(|r| r.trial.campaign_id.as_deref() == Some(campaign_id.as_str()))
        .filter_map(|r| r.trial.outcome?.get("cell_trial_id")?.as_u64())
        .filter(|id| requested.contains(id))
        .collect();
    summary.log_rows = recorded.len() as u32;
    summary.log_rows_lost = requested.iter().filter(|id| !recorded.contains(id)).count() as u32;
    drop(log);
    let (panics, first_panic) = panics_in(&stderr_dir);
    summary.panics = panics;
    summary.first_panic = first_panic;
    // Back out of the small file system.
    if log_path != summary.log_path {
        std::fs::copy(&log_path, &summary.log_path)
            .map_err(|source| FileError::new(FileOp::Write, &summary.log_path, source))?;
    }
    drop(disk);
    drop(lock);
    Ok(summary)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_kind_comes_up_in_each_round_and_draws_are_reproducible() {
        let mut rng = ChaCha8Rng::seed_from_u64(1);
        let plan = schedule(&FaultKind::ALL, 20, &mut rng);
        assert_eq!(plan.len(), 20);
        for round in plan.chunks(FaultKind::ALL.len()).take(2) {
            let mut sorted = round.to_vec();
            sorted.sort();
            assert_eq!(sorted, FaultKind::ALL.to_vec());
        }
        let again = schedule(&FaultKind::ALL, 20, &mut ChaCha8Rng::seed_from_u64(1));
        assert_eq!(plan, again);
        let draw = |k| Fault::draw(k, &mut ChaCha8Rng::seed_from_u64(5));
        let kill = draw(FaultKind::Kill);
        assert!(STAGES.contains(&kill.stage.unwrap()));
        assert!((0.0..3.0).contains(&kill.at_s.unwrap()));
        assert_eq!(kill, draw(FaultKind::Kill));
        let late = draw(FaultKind::FriLate);
        assert!(late.delay_s.unwrap() > 0.0 && late.probability.is_none());
        assert!(late.text().starts_with("fri-late ") && late.text().ends_with(" ms"));
        assert!(schedule(&[], 5, &mut rng).is_empty());
    }

    #[test]
    fn panics_are_counted_in_every_processs_standard_error() {
        let dir = crate::fsio::TempDir::new("chaos-panics").unwrap();
        std::fs::write(
            dir.join("cell-plan.log"),
            "ok\nthread 'main' panicked at src/x.rs:1:2:\nboom\n",
        )
        .unwrap();
        std::fs::write(dir.join("cell-log.log"), "fine\n").unwrap();
        let (n, first) = panics_in(&dir);
        assert_eq!(n, 1);
        assert!(first
            .unwrap()
            .starts_with("cell-plan.log: thread 'main' panicked"));
    }
}
