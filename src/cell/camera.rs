//! `cell-camera`: one depth snapshot per trial request, published as a point cloud
//! written in place in shared memory (no copy between processes).
//!
//! Backends (`camera.backend` in the cell configuration):
//! - `sim`: renders the trial's simulated world ([`TrialSetup`]) with the Kinect
//!   error model, noise seeded by the setup's `noise_seed`.
//! - `replay`: publishes recorded clouds (PLY or PCD, camera optical frame) from
//!   `<run dir>/replay/`, the file `<trial id>.ply` / `.pcd` when present, else the
//!   recorded files in name order, one per request, round robin.
//!
//! The header carries the trial id, the intrinsics, `base_from_camera` from the
//! configuration and the monotonic time at which the frame was complete.

use super::notify::{self, Watchdog};
use super::setup::TrialSetup;
use super::{stop_requested, CellError, TICK};
use crate::config::CellConfig;
use crate::ipc::{
    monotonic_now_ns, CloudHeader, CloudTopic, Domain, Frame, Intrinsics, Point, Stage,
    TrialRequest,
};
use crate::sim::camera::DepthCamera;
use std::path::{Path, PathBuf};

/// Where snapshots come from.
#[derive(Debug)]
pub enum CameraBackend {
    /// The simulated depth camera over each trial's setup.
    Sim {
        /// The camera model.
        camera: DepthCamera,
    },
    /// Recorded clouds.
    Replay {
        /// The recordings' directory.
        dir: PathBuf,
        /// Requests answered so far (selects the next file).
        served: usize,
    },
}

impl CameraBackend {
    /// The backend `config.camera.backend` names.
    pub fn from_config(config: &CellConfig, run_dir: &Path) -> Result<CameraBackend, CellError> {
        match config.camera.backend.as_str() {
            "sim" => Ok(CameraBackend::Sim {
                camera: DepthCamera::from_config(&config.camera, config.base_from_camera()),
            }),
            "replay" => Ok(CameraBackend::Replay {
                dir: run_dir.join("replay"),
                served: 0,
            }),
            other => Err(CellError::Backend {
                field: "camera.backend",
                value: other.to_string(),
                expected: "sim or replay",
            }),
        }
    }

    /// The snapshot for `trial_id`: the organised cloud in the camera optical frame.
    pub fn snapshot(
        &mut self,
        config: &CellConfig,
        run_dir: &Path,
        trial_id: u64,
    ) -> Result<crate::cloud::PointCloud, CellError> {
        match self {
            CameraBackend::Sim { camera } => {
                let setup =
                    TrialSetup::read(run_dir, trial_id)?.ok_or_else(|| CellError::Setup {
                        path: TrialSetup::path(run_dir, trial_id),
                        problem: "missing: the simulated camera renders the trial's setup".into(),
                    })?;
                let scene = setup.scene(config)?;
                // The lab's hand–eye error: the camera really stands elsewhere than
                // the calibrated mount the header (and perception) use.
                let real = DepthCamera {
                    base_from_camera: setup.true_base_from_camera(&camera.base_from_camera),
                    ..*camera
                };
                Ok(real.render(&scene, setup.noise_seed).to_cloud())
            }
            CameraBackend::Replay { dir, served } => {
                let file = replay_file(dir, trial_id, *served)?;
                *served += 1;
                crate::cloud::io::read_cloud(&file).map_err(|e| CellError::Device {
                    device: "replay camera",
                    detail: e.to_string(),
                })
            }
        }
    }
}

fn replay_file(dir: &Path, trial_id: u64, served: usize) -> Result<PathBuf, CellError> {
    for ext in ["ply", "pcd"] {
        let own = dir.join(format!("{trial_id}.{ext}"));
        if own.exists() {
            return Ok(own);
        }
    }
    let mut files: Vec<PathBuf> = std::fs::read_dir(dir)
        .map_err(|source| CellError::Io {
            path: dir.to_path_buf(),
            source,
        })?
        .flatten()
        .map(|e| e.path())
        .filter(|p| p.extension().is_some_and(|e| e == "ply" || e == "pcd"))
        .collect();
    files.sort();
    if files.is_empty() {
        return Err(CellError::Device {
            device: "replay camera",
            detail: format!("{}: no .ply or .pcd recordings", dir.display()),
        });
    }
    Ok(files[served % files.len()].clone())
}

/// Runs the camera stage until SIGTERM/SIGINT.
pub fn run(config: &CellConfig, domain: &Domain, run_dir: &Path) -> Result<(), CellError> {
    let mut backend = CameraBackend::from_config(config, run_dir)?;
    let stage = Stage::start(domain, "camera")?;
    let clouds = stage.cloud_publisher(CloudTopic::Camera)?;
    let requests = stage.subscriber::<TrialRequest>()?;
    let cam = &config.camera;
    let intrinsics = Intrinsics {
        fx: cam.fx_px,
        fy: cam.fy_px,
        cx: cam.cx_px,
        cy: cam.cy_px,
    };
    let base_from_camera = config.base_from_camera();
    notify::ready("camera waiting for trial requests");
    tracing::info!(backend = %config.camera.backend, "camera ready");
    let mut watchdog = Watchdog::from_env();
    while !stop_requested() {
        watchdog.ping();
        let request = match requests.receive_timeout(TICK) {
            Ok(Some(r)) => r,
            Ok(None) => continue,
            Err(_) if stop_requested() => break,
            Err(e) => return Err(e.into()),
        };
        let trial_id = request.trial_id;
        let cloud = match backend.snapshot(config, run_dir, trial_id) {
            Ok(cloud) => cloud,
            Err(e) => {
                // No cloud: the log notices the trial stalls at the camera and says why.
                tracing::error!(trial_id, "snapshot failed: {e}");
                continue;
            }
        };
        let header = CloudHeader::new(
            trial_id,
            monotonic_now_ns(),
            cloud.width,
            cloud.height,
            intrinsics,
            Frame::CameraOptical,
            &base_from_camera,
        );
        let points = &cloud.points;
        let loan = clouds.loan_with(header, |i| Point::from(points[i]))?;
        let reached = loan.send()?;
        tracing::info!(trial_id, points = points.len(), reached, "cloud published");
    }
    notify::stopping();
    Ok(())
}
