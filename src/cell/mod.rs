//! The running cell: one module per process (stage) of the data flow in
//! `ARCHITECTURE.md`, each with a `run` that the thin binaries `cell-<stage>` call,
//! and the harness that starts them all as child processes (`cell demo`, `cell run`,
//! `cell campaign`).
//!
//! ```text
//! trial request -> camera --cloud--> perceive --fits--> plan --grasp--> execute
//!                                                                          |
//! log <------------------------- every topic of the trial -----------------+
//! ```
//!
//! - [`camera`]: a depth snapshot per trial request (backends `sim`, `replay`).
//! - [`perceive`]: table segmentation and registration of every category model.
//! - [`plan`]: the grasp of eq. 2 (or the best-single baseline), reachable.
//! - [`execute`]: the grasp on the arm and the hand (emulated or hardware).
//! - [`log`]: waits for the end of each trial, has it graded by the observer
//!   (simulated or a person at the terminal), records it in the trial log and
//!   publishes the result.
//! - [`harness`]: child processes, supervision (restart on exit), trials.
//! - [`setup`]: what the simulated world holds for one trial (object, placement,
//!   seeds), written by the harness and read by the simulated camera and observer.
//! - [`campaign`]: which trials a campaign runs (objects, placements, tasks and
//!   methods, paired for the sign tests) and its ids.
//!
//! Every stage blocks on iceoryx2 events (never spins), notices a missing or dead
//! peer, cleans the stale resources of dead nodes at start ([`crate::ipc::Stage`]),
//! stops on SIGTERM / SIGINT by dropping its ports (no shared memory left), and
//! speaks the systemd notify protocol ([`notify`]) when `NOTIFY_SOCKET` is set.

pub mod camera;
pub mod campaign;
pub mod chaos;
pub mod execute;
pub mod harness;
pub mod log;
pub mod notify;
pub mod perceive;
pub mod plan;
pub mod setup;

use crate::fsio::FileError;
use crate::ipc::{Domain, IpcError};
use clap::Args;
use std::path::{Path, PathBuf};
use std::time::Duration;

/// The stages of the cell, in data-flow order (node names and binary suffixes).
pub const STAGES: [&str; 5] = ["camera", "perceive", "plan", "execute", "log"];

/// Default cell instance name (service names `graspcell/<instance>/...`).
pub const DEFAULT_INSTANCE: &str = "graspcell";

/// Root of the system domain's iceoryx2 files when it is writable (the systemd units
/// give every process a private /tmp, so /tmp cannot be shared between them).
pub const SYSTEM_IPC_ROOT: &str = "/run/graspcell";

/// File prefix of the cell's shared memory in the system domain.
pub const SYSTEM_IPC_PREFIX: &str = "graspcell_";

/// How long a stage blocks on its inputs before checking for a stop request and
/// pinging the watchdog.
pub const TICK: Duration = Duration::from_millis(100);

/// Errors of the cell's processes; each names the stage, file or input concerned.
#[derive(Debug, thiserror::Error)]
pub enum CellError {
    /// The IPC layer failed.
    #[error(transparent)]
    Ipc(#[from] IpcError),
    /// A configuration file could not be used.
    #[error(transparent)]
    Config(#[from] crate::config::ConfigError),
    /// The robot description could not be loaded.
    #[error(transparent)]
    Robot(#[from] crate::robot::RobotError),
    /// A category database could not be loaded.
    #[error("category {category:?}: {source}")]
    Category {
        /// The category.
        category: String,
        /// Why (boxed: it is large, and rare).
        source: Box<crate::category::CategoryError>,
    },
    /// A trial setup file is missing or malformed.
    #[error("trial setup {path}: {problem}")]
    Setup {
        /// The file.
        path: PathBuf,
        /// What is wrong.
        problem: String,
    },
    /// A backend name the configuration does not know.
    #[error("{field} = {value:?}: unknown backend (expected {expected})")]
    Backend {
        /// The configuration field.
        field: &'static str,
        /// The configured value.
        value: String,
        /// The backends there are.
        expected: &'static str,
    },
    /// A trial request names a planning method the cell does not have.
    #[error("method {method:?}: unknown (use {})", plan::METHODS.join(", "))]
    UnknownMethod {
        /// The method named.
        method: String,
    },
    /// A device (arm, hand, camera) could not be started.
    #[error("{device}: {detail}")]
    Device {
        /// The device.
        device: &'static str,
        /// Why.
        detail: String,
    },
    /// A file operation failed.
    #[error(transparent)]
    File(#[from] FileError),
    /// An operating-system error outside files: a socket, the program's own path,
    /// the working directory.
    #[error("{path}: {source}")]
    Io {
        /// What was used (a socket's address, a path).
        path: PathBuf,
        /// The error.
        source: std::io::Error,
    },
    /// A child process could not be started or misbehaved.
    #[error("process {name}: {detail}")]
    Process {
        /// The process.
        name: String,
        /// What happened.
        detail: String,
    },
    /// A stage did not come up or answer in time.
    #[error("{what}: no answer within {waited_s:.1} s")]
    Timeout {
        /// What was waited for.
        what: String,
        /// How long (s).
        waited_s: f64,
    },
    /// The trial log failed.
    #[error(transparent)]
    Trial(#[from] crate::trial::TrialError),
    /// A bad argument.
    #[error("{0}")]
    Invalid(String),
}

/// Options every stage binary takes: configuration and where the cell's IPC lives.
#[derive(Debug, Clone, Args)]
pub struct StageArgs {
    /// Cell configuration file (backends, devices, limits).
    #[arg(long, default_value_os_t = crate::config::default_config_path())]
    pub config: PathBuf,
    /// Cell instance name: cells with different names on one machine share nothing.
    #[arg(long, default_value = DEFAULT_INSTANCE)]
    pub instance: String,
    /// Root directory of the IPC domain's files (default: /run/graspcell when
    /// writable, else $XDG_RUNTIME_DIR/graspcell, else /tmp/graspcell-UID).
    #[arg(long, value_name = "DIR")]
    pub ipc_root: Option<PathBuf>,
    /// File prefix of the IPC domain's shared memory (1-32 letters, digits, '_').
    #[arg(long, default_value = SYSTEM_IPC_PREFIX)]
    pub ipc_prefix: String,
    /// Directory of per-trial setup files (simulated world) and snapshots.
    #[arg(long, default_value = "run")]
    pub run_dir: PathBuf,
}

impl StageArgs {
    /// Options naming `domain` (its instance, root and prefix), with `config` and
    /// `run_dir`.
    pub fn in_domain(config: &Path, domain: &Domain, run_dir: &Path) -> StageArgs {
        StageArgs {
            config: config.to_path_buf(),
            instance: domain.services().instance().to_string(),
            ipc_root: Some(domain.root()),
            ipc_prefix: domain.prefix(),
            run_dir: run_dir.to_path_buf(),
        }
    }

    /// The IPC domain these options name.
    pub fn domain(&self) -> Result<Domain, CellError> {
        let root = match &self.ipc_root {
            Some(root) => absolute(root)?,
            None => system_ipc_root()?,
        };
        Ok(Domain::isolated(&self.instance, &root, &self.ipc_prefix)?)
    }

    /// The arguments that give another process the same configuration and domain.
    pub fn to_command_args(&self, domain: &Domain) -> Vec<String> {
        vec![
            "--config".into(),
            self.config.display().to_string(),
            "--instance".into(),
            domain.services().instance().to_string(),
            "--ipc-root".into(),
            domain.root().display().to_string(),
            "--ipc-prefix".into(),
            domain.prefix(),
            "--run-dir".into(),
            self.run_dir.display().to_string(),
        ]
    }
}

fn absolute(path: &Path) -> Result<PathBuf, CellError> {
    if path.is_absolute() {
        return Ok(path.to_path_buf());
    }
    std::env::current_dir()
        .map(|d| d.join(path))
        .map_err(|source| CellError::Io {
            path: path.to_path_buf(),
            source,
        })
}

/// The system domain's root: [`SYSTEM_IPC_ROOT`] when it exists (or can be made)
/// and is writable, else `$XDG_RUNTIME_DIR/graspcell`, else `/tmp/graspcell-UID`.
pub fn system_ipc_root() -> Result<PathBuf, CellError> {
    let mut candidates = vec![PathBuf::from(SYSTEM_IPC_ROOT)];
    if let Some(dir) = std::env::var_os("XDG_RUNTIME_DIR") {
        candidates.push(PathBuf::from(dir).join("graspcell"));
    }
    let uid = crate::sys::user_id();
    candidates.push(std::env::temp_dir().join(format!("graspcell-{uid}")));
    for dir in &candidates {
        if writable_dir(dir) {
            return Ok(dir.clone());
        }
    }
    Err(CellError::Io {
        path: candidates.pop().unwrap_or_default(),
        source: std::io::Error::new(
            std::io::ErrorKind::PermissionDenied,
            "no writable directory for the cell's IPC files",
        ),
    })
}

fn writable_dir(dir: &Path) -> bool {
    if std::fs::create_dir_all(dir).is_err() {
        return false;
    }
    let probe = dir.join(format!(".probe-{}", std::process::id()));
    let ok = std::fs::write(&probe, b"").is_ok();
    let _ = std::fs::remove_file(&probe);
    ok
}

/// Makes SIGTERM and SIGINT request a clean stop ([`stop_requested`]) instead of
/// killing the process, so a stage drops its ports and leaves no shared memory
/// (`sigaction`, [`crate::sys::install_stop_signal_handler`]).
pub fn install_stop_handler() {
    if let Err(e) = crate::sys::install_stop_signal_handler() {
        tracing::warn!("cannot handle SIGTERM/SIGINT ({e}): a signal ends the process at once");
    }
}

/// True once SIGTERM or SIGINT arrived (after [`install_stop_handler`]).
pub fn stop_requested() -> bool {
    crate::sys::stop_signal_received()
}

/// Entry point of a stage binary: logging, the stop handler, `run`, the error chain
/// printed on one line and a non-zero exit on error.
pub fn stage_main(
    stage: &str,
    run: impl FnOnce() -> Result<(), CellError>,
) -> std::process::ExitCode {
    crate::logging::init_logging();
    install_stop_handler();
    match run() {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(err) => {
            let _ = notify::notify(&format!("STATUS=failed: {err}"));
            eprintln!("error: cell-{stage}: {err}");
            std::process::ExitCode::FAILURE
        }
    }
}

/// Loads the database of `category` from `db_dir/<category>/`, refusing names that
/// are not category names (they could point outside `db_dir`).
pub fn load_category(
    db_dir: &Path,
    category: &str,
) -> Result<crate::category::CategoryDb, CellError> {
    let valid = category
        .bytes()
        .all(|b| b.is_ascii_lowercase() || b == b'-' || b == b'_');
    if category.is_empty() || !valid {
        return Err(CellError::Invalid(format!(
            "category {category:?}: not a category name"
        )));
    }
    crate::category::CategoryDb::load(&db_dir.join(category)).map_err(|source| {
        CellError::Category {
            category: category.to_string(),
            source: Box::new(source),
        }
    })
}

/// Most trials whose request or input a stage keeps while waiting for the other.
pub const PENDING_TRIALS: usize = 16;

/// A stage's trial requests and its other input, paired by trial id: either may
/// arrive first; the [`PENDING_TRIALS`] that arrived last of each are kept while the
/// other is awaited. Kept by arrival, not by id: a peer's messages with huge ids
/// (random bytes) once evicted every real trial as it came and wedged the stage
/// (found by `cell chaos`). Requests whose texts do not decode are dropped.
#[derive(Debug)]
pub struct ByTrial<T> {
    requests: std::collections::BTreeMap<u64, (u64, crate::ipc::TrialRequest)>,
    inputs: std::collections::BTreeMap<u64, (u64, T)>,
    arrivals: u64,
}

impl<T> Default for ByTrial<T> {
    fn default() -> Self {
        ByTrial {
            requests: Default::default(),
            inputs: Default::default(),
            arrivals: 0,
        }
    }
}

impl<T> ByTrial<T> {
    /// A trial request arrived.
    pub fn request(&mut self, request: crate::ipc::TrialRequest) {
        if let Err(e) = request.check() {
            tracing::warn!(
                trial_id = request.trial_id,
                "ignoring a malformed trial request: {e}"
            );
            return;
        }
        self.arrivals += 1;
        self.requests
            .insert(request.trial_id, (self.arrivals, request));
        trim(&mut self.requests);
    }

    /// The other input of trial `trial_id` arrived.
    pub fn input(&mut self, trial_id: u64, input: T) {
        self.arrivals += 1;
        self.inputs.insert(trial_id, (self.arrivals, input));
        trim(&mut self.inputs);
    }

    /// Removes and returns the trials that have both, oldest first.
    pub fn take_ready(&mut self) -> Vec<(crate::ipc::TrialRequest, T)> {
        let ready: Vec<u64> = self
            .inputs
            .keys()
            .filter(|id| self.requests.contains_key(id))
            .copied()
            .collect();
        ready
            .into_iter()
            .filter_map(|id| Some((self.requests.remove(&id)?.1, self.inputs.remove(&id)?.1)))
            .collect()
    }
}

/// Keeps the [`PENDING_TRIALS`] entries that arrived last.
fn trim<T>(map: &mut std::collections::BTreeMap<u64, (u64, T)>) {
    while map.len() > PENDING_TRIALS {
        let Some(oldest) = map
            .iter()
            .min_by_key(|(_, (arrival, _))| *arrival)
            .map(|(id, _)| *id)
        else {
            return;
        };
        map.remove(&oldest);
    }
}

/// Nanoseconds between two monotonic stamps as milliseconds (NaN when either is 0
/// or they are out of order).
pub fn span_ms(from_ns: u64, to_ns: u64) -> f64 {
    if from_ns == 0 || to_ns == 0 || to_ns < from_ns {
        f64::NAN
    } else {
        (to_ns - from_ns) as f64 * 1e-6
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn requests_and_inputs_pair_by_trial_id_in_either_order_and_old_ones_go() {
        let request = |id| crate::ipc::TrialRequest::new(id, 0, "mug", "top", "laplace").unwrap();
        let mut pending = ByTrial::default();
        pending.input(2, "cloud 2");
        pending.request(request(1));
        assert!(pending.take_ready().is_empty());
        pending.request(request(2));
        pending.input(1, "cloud 1");
        let ready: Vec<(u64, &str)> = pending
            .take_ready()
            .into_iter()
            .map(|(r, c)| (r.trial_id, c))
            .collect();
        assert_eq!(ready, [(1, "cloud 1"), (2, "cloud 2")]);
        assert!(pending.take_ready().is_empty());
        for id in 10..50 {
            pending.request(request(id));
        }
        pending.input(10, "too late");
        assert!(
            pending.take_ready().is_empty(),
            "trial 10's request was dropped"
        );
        pending.input(49, "newest");
        assert_eq!(pending.take_ready().len(), 1);
        // Garbage with huge ids does not push out a real trial that comes later.
        for id in 0..40u64 {
            pending.request(request(u64::MAX - id));
            pending.input(u64::MAX / 2 - id, "garbage");
        }
        pending.request(request(60));
        pending.input(60, "real");
        let ready: Vec<u64> = pending
            .take_ready()
            .iter()
            .map(|(r, _)| r.trial_id)
            .collect();
        assert_eq!(ready, [60]);
        // A request whose texts do not decode is no request.
        let mut bytes = [0xffu8; std::mem::size_of::<crate::ipc::TrialRequest>()];
        bytes[..8].copy_from_slice(&61u64.to_le_bytes());
        pending.request(crate::ipc::from_wire_bytes(&bytes));
        pending.input(61, "orphan");
        assert!(pending.take_ready().is_empty());
    }

    #[test]
    fn spans_need_both_stamps_in_order() {
        assert_eq!(span_ms(1_000_000, 3_500_000), 2.5);
        assert!(span_ms(0, 5).is_nan());
        assert!(span_ms(5, 4).is_nan());
    }

    #[test]
    fn explicit_ipc_root_makes_an_isolated_domain() {
        let args = StageArgs {
            config: PathBuf::from("robot/cell.toml"),
            instance: "t1".into(),
            ipc_root: Some(PathBuf::from("/tmp/gc-cell-test")),
            ipc_prefix: "gct_".into(),
            run_dir: PathBuf::from("run"),
        };
        let d = args.domain().unwrap();
        assert_eq!(d.root(), PathBuf::from("/tmp/gc-cell-test/"));
        assert_eq!(d.prefix(), "gct_");
        let cmd = args.to_command_args(&d);
        assert_eq!(cmd[3], "t1");
        let bad = StageArgs {
            ipc_prefix: "a-b".into(),
            ..args
        };
        assert!(bad.domain().is_err());
        assert!(system_ipc_root().unwrap().is_absolute());
    }
}
