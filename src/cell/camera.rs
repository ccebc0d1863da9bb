//! `cell-camera`: one depth snapshot per trial request, published as a point cloud
//! written in place in shared memory (no copy between processes).
//!
//! Backends (`camera.backend` in the cell configuration):
//! - `sim`: renders the trial's simulated world ([`TrialSetup`]) with the Kinect
//!   error model, noise seeded by the setup's `noise_seed`; its simulated
//!   accelerometer reads gravity through the configured mount.
//! - `replay`: publishes recorded clouds (PLY or PCD, camera optical frame) from
//!   `<run dir>/replay/`, the file `<trial id>.ply` / `.pcd` when present, else the
//!   recorded files in name order, one per request, round robin.
//! - `kinect` (cargo feature `kinect`): a Kinect v1 through libfreenect
//!   ([`crate::hw::kinect::device`]), or fakenect playing a recording when
//!   `LD_LIBRARY_PATH` puts fakenect's library first and `FAKENECT_PATH` names
//!   the recording. Raw 11-bit depth converted with the device's registration
//!   data; colour too when `camera.rgb`; the accelerometer with every snapshot.
//!   Each trial's raw frame is kept as a fakenect recording in
//!   [`raw_frame_dir`], so the trial can be replayed through `kinect` + fakenect.
//!
//! With every snapshot the stage publishes a [`CameraStatus`] for the log: the
//! measured gravity and the gravity check (the angle between it and the base's
//! -z through the calibrated mount; beyond `camera.gravity_check_max_deg` a
//! warning: the camera was bumped or the calibration is stale). The check also
//! runs at start. When there is no snapshot the status names the fault instead
//! (no device, vanished, stalled, failed) and the log fails the trial with the
//! cause `camera`. The `kinect` backend then closes the device and reopens it on
//! the next request: the stage recovers when the device returns. A missing
//! device at start is logged with what to check (USB, power, the udev rule) and
//! does not stop the stage.
//!
//! The header carries the trial id, the intrinsics, `base_from_camera` from the
//! configuration and the monotonic time at which the frame was complete.

use super::notify::{self, Watchdog};
use super::setup::TrialSetup;
use super::{stop_requested, CellError, TICK};
use crate::cloud::PointCloud;
use crate::config::CellConfig;
use crate::fsio::{FileError, FileOp};
use crate::geometry::Pose;
use crate::hw::kinect::fakenect::RawFrame;
use crate::hw::kinect::gravity::{expected_gravity_camera, GravityCheck, STANDARD_GRAVITY_M_S2};
use crate::ipc::{
    monotonic_now_ns, CameraFault, CameraStatus, CloudHeader, CloudTopic, Domain, Frame,
    Intrinsics, Point, Stage, TrialRequest,
};
use crate::sim::camera::DepthCamera;
use nalgebra::Vector3;
use std::path::{Path, PathBuf};

/// Depth frames the `kinect` backend drops before the one it keeps (a frame
/// buffered while nobody read the device may predate the request).
pub const KINECT_SETTLE_FRAMES: u32 = 1;

/// Where the raw frame of trial `trial_id` is kept: a fakenect recording of the
/// snapshot (`kinect` backend).
pub fn raw_frame_dir(run_dir: &Path, trial_id: u64) -> PathBuf {
    run_dir.join("frames").join(trial_id.to_string())
}

/// Why a backend gave no snapshot.
#[derive(Debug, thiserror::Error)]
#[error("camera fault {fault:?}: {message}")]
pub struct CameraFailure {
    /// The fault's kind.
    pub fault: CameraFault,
    /// What happened.
    pub message: String,
}

/// One snapshot.
#[derive(Debug, Clone)]
pub struct Snapshot {
    /// The organised cloud in the camera optical frame.
    pub cloud: PointCloud,
    /// The intrinsics it was taken with.
    pub intrinsics: Intrinsics,
    /// Gravity measured in the camera optical frame (m/s^2), when the camera
    /// has an accelerometer.
    pub gravity_camera_m_s2: Option<Vector3<f64>>,
    /// The raw frame to keep with the trial, when the backend has one.
    pub raw: Option<RawFrame>,
}

/// The `kinect` backend's state: the device while it answers.
#[cfg(feature = "kinect")]
#[derive(Debug)]
pub struct KinectBackend {
    device: Option<crate::hw::kinect::device::Kinect>,
    options: crate::hw::kinect::device::KinectOptions,
}

#[cfg(feature = "kinect")]
impl KinectBackend {
    fn fault_of(e: &crate::hw::kinect::KinectError) -> CameraFault {
        use crate::hw::kinect::KinectError as E;
        match e {
            E::NoDevice { .. } | E::Library { .. } | E::Driver { .. } => CameraFault::NoDevice,
            E::Vanished { .. } => CameraFault::Vanished,
            E::Stalled { .. } => CameraFault::Stalled,
            _ => CameraFault::Failed,
        }
    }

    /// Opens the device (at start, or again after a fault).
    fn open(&mut self) -> Result<&mut crate::hw::kinect::device::Kinect, CameraFailure> {
        if self.device.is_none() {
            let device =
                crate::hw::kinect::device::Kinect::open(self.options.clone()).map_err(|e| {
                    CameraFailure {
                        fault: Self::fault_of(&e),
                        message: e.to_string(),
                    }
                })?;
            tracing::info!("Kinect open");
            self.device = Some(device);
        }
        Ok(self.device.as_mut().expect("opened above"))
    }

    fn snapshot(&mut self, config: &CellConfig) -> Result<Snapshot, CameraFailure> {
        let device = self.open()?;
        let frame = match device.grab() {
            Ok(f) => f,
            Err(e) => {
                // Close it (libfreenect and fakenect start afresh on reopen).
                self.device = None;
                return Err(CameraFailure {
                    fault: Self::fault_of(&e),
                    message: e.to_string(),
                });
            }
        };
        let cam = &config.camera;
        let cloud = device.to_cloud(&frame, [cam.min_range_m as f32, cam.max_range_m as f32]);
        let k = device.intrinsics();
        Ok(Snapshot {
            cloud,
            intrinsics: Intrinsics {
                fx: k.focal_px,
                fy: k.focal_px,
                cx: k.cx_px,
                cy: k.cy_px,
            },
            gravity_camera_m_s2: frame.accel.and_then(|a| a.gravity_camera_m_s2()),
            raw: Some(RawFrame {
                depth_raw: frame.depth_raw,
                rgb: frame.rgb,
                accel: frame.accel,
                registration: *device.registration(),
                width: crate::hw::kinect::registration::FRAME_WIDTH,
                height: crate::hw::kinect::registration::FRAME_HEIGHT,
            }),
        })
    }
}

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
    /// A Kinect v1 through libfreenect (or fakenect).
    #[cfg(feature = "kinect")]
    Kinect(Box<KinectBackend>),
}

fn config_intrinsics(config: &CellConfig) -> Intrinsics {
    let cam = &config.camera;
    Intrinsics {
        fx: cam.fx_px,
        fy: cam.fy_px,
        cx: cam.cx_px,
        cy: cam.cy_px,
    }
}

impl CameraBackend {
    /// The backend `config.camera.backend` names. The `kinect` backend opens the
    /// device here; a missing device is logged (with what to check) and retried
    /// at each request, while a missing libfreenect is an error.
    pub fn from_config(config: &CellConfig, run_dir: &Path) -> Result<CameraBackend, CellError> {
        match config.camera.backend.as_str() {
            "sim" => Ok(CameraBackend::Sim {
                camera: DepthCamera::from_config(&config.camera, config.base_from_camera()),
            }),
            "replay" => Ok(CameraBackend::Replay {
                dir: run_dir.join("replay"),
                served: 0,
            }),
            #[cfg(feature = "kinect")]
            "kinect" => {
                let mut backend = KinectBackend {
                    device: None,
                    options: crate::hw::kinect::device::KinectOptions {
                        index: config.camera.kinect_index as i32,
                        rgb: config.camera.rgb,
                        frame_timeout_s: config.camera.frame_timeout_s,
                        settle_frames: KINECT_SETTLE_FRAMES,
                        library: None,
                    },
                };
                match backend.open() {
                    Ok(_) => {}
                    Err(e) if e.message.contains("could not be loaded") => {
                        return Err(CellError::Device {
                            device: "kinect",
                            detail: e.message,
                        })
                    }
                    Err(e) => tracing::error!("kinect: {}", e.message),
                }
                Ok(CameraBackend::Kinect(Box::new(backend)))
            }
            other => Err(CellError::Backend {
                field: "camera.backend",
                value: other.to_string(),
                expected: if cfg!(feature = "kinect") {
                    "sim, replay or kinect"
                } else {
                    "sim or replay; kinect needs a build with the kinect feature (cargo build --features kinect)"
                },
            }),
        }
    }

    /// The gravity the camera measures now, without taking a snapshot, when it
    /// can tell (the start check).
    pub fn gravity_now(&mut self) -> Option<Vector3<f64>> {
        match self {
            CameraBackend::Sim { camera } => Some(sim_gravity(&camera.base_from_camera)),
            CameraBackend::Replay { .. } => None,
            #[cfg(feature = "kinect")]
            CameraBackend::Kinect(k) => k.device.as_mut()?.accelerometer()?.gravity_camera_m_s2(),
        }
    }

    /// The snapshot for `trial_id`: the organised cloud in the camera optical frame.
    pub fn snapshot(
        &mut self,
        config: &CellConfig,
        run_dir: &Path,
        trial_id: u64,
    ) -> Result<Snapshot, CameraFailure> {
        let failed = |message: String| CameraFailure {
            fault: CameraFault::Failed,
            message,
        };
        match self {
            CameraBackend::Sim { camera } => {
                let setup = TrialSetup::read(run_dir, trial_id)
                    .map_err(|e| failed(e.to_string()))?
                    .ok_or_else(|| {
                        failed(format!(
                            "trial setup {}: missing: the simulated camera renders the trial's setup",
                            TrialSetup::path(run_dir, trial_id).display()
                        ))
                    })?;
                let scene = setup.scene(config).map_err(|e| failed(e.to_string()))?;
                // The lab's hand–eye error: the camera really stands elsewhere than
                // the calibrated mount the header (and perception) use.
                let real = DepthCamera {
                    base_from_camera: setup.true_base_from_camera(&camera.base_from_camera),
                    ..*camera
                };
                Ok(Snapshot {
                    cloud: real.render(&scene, setup.noise_seed).to_cloud(),
                    intrinsics: config_intrinsics(config),
                    gravity_camera_m_s2: Some(sim_gravity(&real.base_from_camera)),
                    raw: None,
                })
            }
            CameraBackend::Replay { dir, served } => {
                let file =
                    replay_file(dir, trial_id, *served).map_err(|e| failed(e.to_string()))?;
                *served += 1;
                let cloud = crate::cloud::io::read_cloud(&file)
                    .map_err(|e| failed(format!("replay camera: {e}")))?;
                Ok(Snapshot {
                    cloud,
                    intrinsics: config_intrinsics(config),
                    gravity_camera_m_s2: None,
                    raw: None,
                })
            }
            #[cfg(feature = "kinect")]
            CameraBackend::Kinect(k) => k.snapshot(config),
        }
    }
}

/// What the simulated camera's accelerometer measures: gravity through its mount.
fn sim_gravity(base_from_camera: &Pose) -> Vector3<f64> {
    expected_gravity_camera(base_from_camera) * STANDARD_GRAVITY_M_S2
}

fn replay_file(dir: &Path, trial_id: u64, served: usize) -> Result<PathBuf, CellError> {
    for ext in ["ply", "pcd"] {
        let own = dir.join(format!("{trial_id}.{ext}"));
        if own.exists() {
            return Ok(own);
        }
    }
    let mut files: Vec<PathBuf> = std::fs::read_dir(dir)
        .map_err(|source| FileError::new(FileOp::ListDir, dir, source))?
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

/// The gravity check of a measurement against the mount, logged as a warning
/// when it exceeds the configured limit.
pub fn check_gravity(
    config: &CellConfig,
    mount: &Pose,
    gravity_camera_m_s2: &Vector3<f64>,
) -> GravityCheck {
    let check = GravityCheck::new(
        gravity_camera_m_s2,
        mount,
        config.camera.gravity_check_max_deg.to_radians(),
    );
    if check.exceeded() {
        tracing::warn!("{}", check.warning());
    }
    check
}

/// Runs the camera stage until SIGTERM/SIGINT; `hand_eye` is the calibration
/// result the gravity check compares with (the configured mount for the
/// simulated camera, or when there is no valid result).
pub fn run(
    config: &CellConfig,
    domain: &Domain,
    run_dir: &Path,
    hand_eye: &Path,
) -> Result<(), CellError> {
    let mut backend = CameraBackend::from_config(config, run_dir)?;
    let mount = if config.camera.backend == "sim" {
        config.base_from_camera()
    } else {
        crate::calib::current_base_from_camera(config, hand_eye).base_from_camera
    };
    match backend.gravity_now() {
        Some(g) => {
            let check = check_gravity(config, &mount, &g);
            tracing::info!(
                angle_deg = check.angle_rad.to_degrees(),
                "gravity check at start"
            );
        }
        None => tracing::info!(
            "no accelerometer reading at start: the gravity check runs with each snapshot"
        ),
    }
    let stage = Stage::start(domain, "camera")?;
    let clouds = stage.cloud_publisher(CloudTopic::Camera)?;
    let statuses = stage.publisher::<CameraStatus>()?;
    let requests = stage.subscriber::<TrialRequest>()?;
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
        if let Err(e) = request.check() {
            tracing::warn!(trial_id, "ignoring a malformed trial request: {e}");
            continue;
        }
        let snapshot = match backend.snapshot(config, run_dir, trial_id) {
            Ok(s) => s,
            Err(e) => {
                // The log fails the trial with the cause `camera`.
                tracing::error!(trial_id, "snapshot failed: {e}");
                statuses.send(&CameraStatus::new(trial_id, monotonic_now_ns(), e.fault))?;
                continue;
            }
        };
        let stamp_ns = monotonic_now_ns();
        let mut status = CameraStatus::new(trial_id, stamp_ns, CameraFault::None);
        if let Some(g) = snapshot.gravity_camera_m_s2 {
            let check = check_gravity(config, &mount, &g);
            status.gravity_camera_m_s2 = check.gravity_camera_m_s2;
            status.gravity_angle_rad = check.angle_rad;
            status.gravity_warning = u32::from(check.exceeded());
        }
        if let Some(raw) = &snapshot.raw {
            let dir = raw_frame_dir(run_dir, trial_id);
            // One settling frame before the kept one, as the backend reads it.
            if let Err(e) = raw.write_recording(&dir, 1 + KINECT_SETTLE_FRAMES as usize) {
                tracing::error!(trial_id, "raw frame not kept: {e}");
            }
        }
        statuses.send(&status)?;
        let cloud = &snapshot.cloud;
        let header = CloudHeader::new(
            trial_id,
            stamp_ns,
            cloud.width,
            cloud.height,
            snapshot.intrinsics,
            Frame::CameraOptical,
            &base_from_camera,
        );
        let points = &cloud.points;
        let loan = clouds.loan_with(header, |i| Point::from(points[i]))?;
        let reached = loan.send()?;
        tracing::info!(
            trial_id,
            points = points.len(),
            reached,
            gravity_angle_deg = status.gravity_angle_rad.to_degrees(),
            "cloud published"
        );
    }
    notify::stopping();
    Ok(())
}
