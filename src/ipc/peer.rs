//! Helper processes for tests and `cell bench ipc`: the `cell` binary runs one with
//! the hidden subcommand `cell ipc-peer '<json PeerSpec>'`.
//!
//! Roles: an echo (copies each camera cloud to the echo topic), a camera stand-in
//! (answers each trial request with a cloud of a known pattern), and the benchmark's
//! receiver. Every role gives up after `idle_timeout_s` without input. After its work
//! a peer waits for its standard input to close (the parent's [`PeerProcess::finish`],
//! or the parent's death), so its exit never races with the delivery of what it sent.

use super::bench;
use super::domain::{Domain, DomainSpec};
use super::payloads::{CloudHeader, Frame, Intrinsics, Point, TrialRequest};
use super::services::CloudTopic;
use super::stage::Stage;
use super::{monotonic_now_ns, IpcError};
use crate::geometry::Pose;
use serde::{Deserialize, Serialize};
use std::io::Read;
use std::path::{Path, PathBuf};
use std::process::{Child, ChildStdin, Command, ExitStatus, Stdio};
use std::time::{Duration, Instant};

/// The hidden subcommand of the `cell` binary that runs a peer.
pub const PEER_SUBCOMMAND: &str = "ipc-peer";

/// What a peer process does.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "role", rename_all = "snake_case", deny_unknown_fields)]
pub enum PeerRole {
    /// Copies `count` camera clouds to the echo topic, then exits.
    Echo {
        /// Clouds to echo.
        count: usize,
    },
    /// Answers `count` trial requests, each with a `width` x `height` cloud made by
    /// [`pattern_point`] for the request's trial id, then exits.
    Camera {
        /// Requests to answer.
        count: usize,
        /// Columns of each cloud.
        width: u32,
        /// Rows of each cloud.
        height: u32,
    },
    /// The receiving side of `cell bench ipc` ([`bench::run_receiver`]).
    BenchReceiver(bench::ReceiverSpec),
}

/// A peer process's instructions.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PeerSpec {
    /// The domain to join.
    pub domain: DomainSpec,
    /// Longest wait for input before giving up (s).
    pub idle_timeout_s: f64,
    /// What to do.
    pub role: PeerRole,
}

/// Point `i` of the camera peer's cloud for trial `trial_id`:
/// `(i, trial_id, -i)` as f32 (exact for up to 2^24 points).
pub fn pattern_point(trial_id: u64, i: usize) -> Point {
    Point::new(i as f32, trial_id as f32, -(i as f32))
}

/// Header of the camera peer's clouds.
fn pattern_header(trial_id: u64, width: u32, height: u32) -> CloudHeader {
    let intrinsics = Intrinsics {
        fx: 525.0,
        fy: 525.0,
        cx: (width as f64 - 1.0) / 2.0,
        cy: (height as f64 - 1.0) / 2.0,
    };
    CloudHeader::new(
        trial_id,
        monotonic_now_ns(),
        width,
        height,
        intrinsics,
        Frame::CameraOptical,
        &Pose::identity(),
    )
}

/// Runs the peer described by `spec`: its work, then waiting for standard input to
/// close, with its ports still open.
pub fn run(spec: &PeerSpec) -> Result<(), IpcError> {
    let domain = Domain::from_spec(&spec.domain)?;
    let idle = Duration::from_secs_f64(spec.idle_timeout_s.max(0.0));
    let stage = match &spec.role {
        PeerRole::Echo { count } => echo(&domain, *count, idle)?,
        PeerRole::Camera {
            count,
            width,
            height,
        } => camera(&domain, *count, *width, *height, idle)?,
        PeerRole::BenchReceiver(receiver) => bench::run_receiver(&domain, receiver, idle)?,
    };
    let mut rest = Vec::new();
    std::io::stdin()
        .read_to_end(&mut rest)
        .map_err(|source| IpcError::Io {
            path: PathBuf::from("/dev/stdin"),
            source,
        })?;
    drop(stage);
    Ok(())
}

/// What a finished role keeps alive until the peer exits (its node and ports).
pub(crate) type Linger = Box<dyn std::any::Any>;

fn echo(domain: &Domain, count: usize, idle: Duration) -> Result<Linger, IpcError> {
    let stage = Stage::start(domain, "echo")?;
    let clouds = stage.cloud_subscriber(CloudTopic::Camera)?;
    let echoes = stage.cloud_publisher(CloudTopic::Echo)?;
    for n in 0..count {
        let cloud = clouds
            .receive_timeout(idle)?
            .ok_or_else(|| IpcError::Peer(format!("echo: no cloud {n} within {idle:?}")))?;
        echoes.send_copy(*cloud.header(), cloud.points())?;
    }
    Ok(Box::new((clouds, echoes, stage)))
}

fn camera(
    domain: &Domain,
    count: usize,
    width: u32,
    height: u32,
    idle: Duration,
) -> Result<Linger, IpcError> {
    let stage = Stage::start(domain, "camera")?;
    let requests = stage.subscriber::<TrialRequest>()?;
    let clouds = stage.cloud_publisher(CloudTopic::Camera)?;
    for n in 0..count {
        let request = requests.receive_timeout(idle)?.ok_or_else(|| {
            IpcError::Peer(format!("camera: no trial request {n} within {idle:?}"))
        })?;
        let trial_id = request.trial_id;
        clouds
            .loan_with(pattern_header(trial_id, width, height), |i| {
                pattern_point(trial_id, i)
            })?
            .send()?;
    }
    Ok(Box::new((requests, clouds, stage)))
}

/// A running peer process; dropping it kills (SIGKILL) and reaps the process.
#[derive(Debug)]
pub struct PeerProcess {
    child: Child,
    stdin: Option<ChildStdin>,
}

impl PeerProcess {
    /// Starts `cell_exe ipc-peer '<spec as JSON>'` (stderr inherited for its logs).
    pub fn spawn(cell_exe: &Path, spec: &PeerSpec) -> Result<PeerProcess, IpcError> {
        let json = serde_json::to_string(spec)
            .map_err(|e| IpcError::Peer(format!("peer spec to JSON: {e}")))?;
        let mut child = Command::new(cell_exe)
            .arg(PEER_SUBCOMMAND)
            .arg(json)
            .stdin(Stdio::piped())
            .stdout(Stdio::null())
            .stderr(Stdio::inherit())
            .spawn()
            .map_err(|source| IpcError::Io {
                path: cell_exe.to_path_buf(),
                source,
            })?;
        let stdin = child.stdin.take();
        Ok(PeerProcess { child, stdin })
    }

    /// Tells the peer to exit (closes its standard input) and waits up to `timeout`
    /// for it; an error if it is still running or failed.
    pub fn finish(&mut self, timeout: Duration) -> Result<ExitStatus, IpcError> {
        drop(self.stdin.take());
        match self.wait_timeout(timeout)? {
            Some(status) if status.success() => Ok(status),
            Some(status) => Err(IpcError::Peer(format!(
                "peer (pid {}) failed: {status}",
                self.id()
            ))),
            None => Err(IpcError::Peer(format!(
                "peer (pid {}) still running after {timeout:?}",
                self.id()
            ))),
        }
    }

    /// The process id.
    pub fn id(&self) -> u32 {
        self.child.id()
    }

    /// Kills the process with SIGKILL (no cleanup in the process) and reaps it.
    pub fn kill(&mut self) -> Result<ExitStatus, IpcError> {
        self.child.kill().map_err(|e| self.io_error(e))?;
        self.child.wait().map_err(|e| self.io_error(e))
    }

    /// Its exit status if it has ended.
    pub fn try_wait(&mut self) -> Result<Option<ExitStatus>, IpcError> {
        self.child.try_wait().map_err(|e| self.io_error(e))
    }

    /// Waits up to `timeout` for the process to end (checking every millisecond);
    /// `None` if it is still running.
    pub fn wait_timeout(&mut self, timeout: Duration) -> Result<Option<ExitStatus>, IpcError> {
        let deadline = Instant::now() + timeout;
        loop {
            if let Some(status) = self.try_wait()? {
                return Ok(Some(status));
            }
            if Instant::now() >= deadline {
                return Ok(None);
            }
            std::thread::sleep(Duration::from_millis(1));
        }
    }

    fn io_error(&self, source: std::io::Error) -> IpcError {
        IpcError::Io {
            path: PathBuf::from(format!("/proc/{}", self.child.id())),
            source,
        }
    }
}

impl Drop for PeerProcess {
    fn drop(&mut self) {
        if let Ok(None) = self.child.try_wait() {
            let _ = self.child.kill();
            let _ = self.child.wait();
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn peer_specs_round_trip_through_json() {
        let domain = Domain::temporary("peer-spec").unwrap();
        let spec = PeerSpec {
            domain: domain.spec(),
            idle_timeout_s: 2.5,
            role: PeerRole::Camera {
                count: 3,
                width: 640,
                height: 480,
            },
        };
        let json = serde_json::to_string(&spec).unwrap();
        assert!(json.contains("\"role\":\"camera\""), "{json}");
        assert_eq!(serde_json::from_str::<PeerSpec>(&json).unwrap(), spec);
        assert!(serde_json::from_str::<PeerSpec>(&json.replace("\"count\"", "\"cnt\"")).is_err());
    }

    #[test]
    fn pattern_is_exact_for_a_full_cloud() {
        let last = crate::ipc::MAX_CLOUD_POINTS - 1;
        assert_eq!(
            pattern_point(9, last),
            Point::new(307_199.0, 9.0, -307_199.0)
        );
        pattern_header(1, 640, 480).validate(last + 1).unwrap();
    }
}
