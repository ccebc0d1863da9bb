//! The Kinect v1 backend against fakenect recordings (issue 22): the simulated
//! camera records a mug at a known pose into a fakenect directory, the camera
//! stage plays it through libfreenect's fakenect library, and the cell's
//! perception registers the mug; the gravity check with a tilted calibration; no
//! device; a recording cut short mid-run. Needs `--features kinect` and Debian's
//! libfreenect-dev (`.ci/setup` installs it).

use crate::common::{cell, root};
use graspcell::calib::{HandEyeResult, ResidualStats};
use graspcell::category::CategoryDb;
use graspcell::cell::StageArgs;
use graspcell::cloud::segment::SegmentParams;
use graspcell::config::CellConfig;
use graspcell::fsio::TempDir;
use graspcell::geometry::{pose_error, pose_from_params, Pose, PoseJson};
use graspcell::hw::kinect::device::{Kinect, KinectOptions};
use graspcell::hw::kinect::KinectError;
use graspcell::ipc::stage::poll_until;
use graspcell::ipc::{
    monotonic_now_ns, CameraFault, CameraStatus, CloudSubscriber, CloudTopic, Domain, FailureCause,
    MessagePublisher, MessageSubscriber, Stage, TrialRequest, TrialResult,
};
use graspcell::register::{perceive, ModelSet, RegisterParams, RegistrationStatus};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::Duration;

/// Debian's fakenect library directory.
const FAKENECT_DIR: &str = "/usr/lib/x86_64-linux-gnu/fakenect";

fn config() -> CellConfig {
    CellConfig::load(&root().join("robot/cell.toml")).unwrap()
}

/// The shipped configuration with the `kinect` camera backend, written to `dir`.
fn kinect_config(dir: &Path) -> PathBuf {
    let text = std::fs::read_to_string(root().join("robot/cell.toml")).unwrap();
    let urdf = root().join("robot/lbr4_bh8_282.urdf");
    let text = text
        .replace(
            "[camera]\nbackend = \"sim\"",
            "[camera]\nbackend = \"kinect\"\nframe_timeout_s = 3.0\nrgb = true",
        )
        .replace(
            "urdf = \"lbr4_bh8_282.urdf\"",
            &format!("urdf = {:?}", urdf.display().to_string()),
        );
    assert!(
        text.contains("backend = \"kinect\""),
        "the camera section moved"
    );
    let path = dir.join("cell.toml");
    std::fs::write(&path, text).unwrap();
    CellConfig::load(&path).unwrap();
    path
}

/// Records `frames` frames of mug_002 of the database at `base_from_object` on the
/// cell's table with `cell camera record` (simulated camera); returns the directory.
fn record_mug(dir: &Path, base_from_object: &Pose, frames: usize) -> PathBuf {
    let mesh = root().join("db/mug/models/mug_002.ply");
    let pose = PoseJson::from(base_from_object);
    let scene = dir.join("scene.toml");
    std::fs::write(
        &scene,
        format!(
            "[[objects]]\nmesh = {:?}\npose = {{ xyz = {:?}, rpy = {:?} }}\n",
            mesh.display().to_string(),
            pose.xyz,
            pose.rpy.unwrap()
        ),
    )
    .unwrap();
    let out = dir.join("recording");
    let frames = frames.to_string();
    let (ok, stdout, stderr) = cell(&[
        "camera",
        "record",
        out.to_str().unwrap(),
        "--frames",
        &frames,
        "--scene",
        scene.to_str().unwrap(),
        "--seed",
        "7",
        "--json",
    ]);
    assert!(ok, "{stderr}");
    let report: serde_json::Value = serde_json::from_str(&stdout).unwrap();
    assert_eq!(report["backend"], "sim");
    assert_eq!(report["focal_px"].as_f64().unwrap().round(), 525.0);
    let index = graspcell::hw::kinect::fakenect::read_index(&out).unwrap();
    assert_eq!(
        index.len(),
        3 * frames.parse::<usize>().unwrap(),
        "a, d, r per frame"
    );
    out
}

/// A `cell-camera` (or `cell-log`) process of the test's domain; stopped on drop.
struct Process {
    child: Child,
    stderr: PathBuf,
}

impl Process {
    /// Starts `cell-<stage>` with `config`, in `domain`, with `env`.
    fn start(
        stage: &str,
        config: &Path,
        domain: &Domain,
        run_dir: &Path,
        extra: &[String],
        env: &[(&str, &Path)],
    ) -> Process {
        let args = StageArgs::in_domain(config, domain, run_dir);
        let stderr = run_dir.join(format!("{stage}.stderr"));
        std::fs::create_dir_all(run_dir).unwrap();
        let bin =
            Path::new(env!("CARGO_BIN_EXE_cell-camera")).with_file_name(format!("cell-{stage}"));
        let mut command = Command::new(bin);
        command
            .current_dir(root())
            .args(args.to_command_args(domain))
            .args(extra)
            .env_remove("LD_LIBRARY_PATH")
            .env_remove("FAKENECT_PATH")
            .env("FAKENECT_LOOP", "0")
            .env("RUST_LOG", "info")
            .stdout(Stdio::null())
            .stderr(std::fs::File::create(&stderr).unwrap());
        for (k, v) in env {
            command.env(k, v);
        }
        Process {
            child: command.spawn().unwrap(),
            stderr,
        }
    }

    fn stderr(&self) -> String {
        std::fs::read_to_string(&self.stderr).unwrap_or_default()
    }
}

impl Drop for Process {
    fn drop(&mut self) {
        // SAFETY: kill has no memory preconditions; the pid is our own child.
        unsafe { libc::kill(self.child.id() as i32, libc::SIGTERM) };
        let _ = self.child.wait();
    }
}

/// The camera stage playing `recording` through fakenect.
fn fakenect_camera(
    config: &Path,
    domain: &Domain,
    run_dir: &Path,
    recording: &Path,
    hand_eye: &Path,
) -> Process {
    Process::start(
        "camera",
        config,
        domain,
        run_dir,
        &["--hand-eye".into(), hand_eye.display().to_string()],
        &[
            ("LD_LIBRARY_PATH", Path::new(FAKENECT_DIR)),
            ("FAKENECT_PATH", recording),
        ],
    )
}

/// The test's own node: sends trial requests, reads clouds, camera statuses and
/// trial results.
struct Operator {
    _stage: Stage,
    requests: MessagePublisher<TrialRequest>,
    clouds: CloudSubscriber,
    statuses: MessageSubscriber<CameraStatus>,
    results: MessageSubscriber<TrialResult>,
}

impl Operator {
    fn new(domain: &Domain) -> Operator {
        let stage = Stage::start(domain, "operator").unwrap();
        Operator {
            requests: stage.publisher().unwrap(),
            clouds: stage.cloud_subscriber(CloudTopic::Camera).unwrap(),
            statuses: stage.subscriber().unwrap(),
            results: stage.subscriber().unwrap(),
            _stage: stage,
        }
    }

    /// Waits until `subscribers` processes listen to trial requests and the
    /// camera publishes.
    fn wait_for(&self, subscribers: usize, camera: &Process) {
        let up = poll_until(Duration::from_secs(60), || {
            Ok(self.requests.subscriber_peers()?.alive >= subscribers
                && self.statuses.publisher_peers()?.alive >= 1)
        })
        .unwrap();
        assert!(up, "the stages did not come up: {}", camera.stderr());
    }

    fn request(&self, trial_id: u64) {
        let r =
            TrialRequest::new(trial_id, monotonic_now_ns(), "mug", "handle", "laplace").unwrap();
        self.requests.send(&r).unwrap();
    }

    fn status(&self, camera: &Process) -> CameraStatus {
        self.statuses
            .receive_timeout(Duration::from_secs(30))
            .unwrap()
            .unwrap_or_else(|| panic!("no camera status: {}", camera.stderr()))
    }
}

#[test]
fn simulated_mug_recorded_for_fakenect_registers_through_the_kinect_backend_within_5_mm_and_5_deg()
{
    let dir = TempDir::new("kinect-e2e").unwrap();
    let config = config();
    // Handle visible: turned 60 deg towards the camera (as the perception tests).
    let truth = pose_from_params(&[0.62, 0.04, config.table.height_m, 0.0, 0.0, 1.05]);
    let recording = record_mug(&dir, &truth, 4);
    let domain = Domain::temporary("kinect-e2e").unwrap();
    let run_dir = dir.join("run");
    let camera = fakenect_camera(
        &kinect_config(&dir),
        &domain,
        &run_dir,
        &recording,
        &dir.join("no-hand-eye.toml"),
    );
    let operator = Operator::new(&domain);
    operator.wait_for(1, &camera);
    operator.request(1);
    let status = operator.status(&camera);
    assert_eq!(
        status.fault().unwrap(),
        CameraFault::None,
        "{}",
        camera.stderr()
    );
    // The recording's accelerometer agrees with the mount: the check passes.
    assert!(status.gravity_angle_rad.to_degrees() < 0.5, "{status:?}");
    assert_eq!(status.gravity_warning, 0);
    let sample = operator
        .clouds
        .receive_timeout(Duration::from_secs(30))
        .unwrap()
        .expect("a cloud");
    sample.validate().unwrap();
    let h = *sample.header();
    assert_eq!((h.trial_id, h.width, h.height), (1, 640, 480));
    assert!(
        (h.intrinsics.fx - 525.0).abs() < 1e-6 && h.intrinsics.cx == 320.0,
        "{h:?}"
    );
    let cloud = sample.to_cloud();
    drop(sample);
    // The trial's raw frame (settling frame and kept frame: accelerometer, depth,
    // colour each) is kept as a recording fakenect can play.
    let kept = graspcell::cell::camera::raw_frame_dir(&run_dir, 1);
    assert_eq!(
        graspcell::hw::kinect::fakenect::read_index(&kept)
            .unwrap()
            .len(),
        6
    );
    drop(camera);

    let db = CategoryDb::load(&root().join("db/mug")).unwrap();
    let models = ModelSet::from_category(&db, &RegisterParams::default()).unwrap();
    let p = perceive(
        &cloud,
        &config.base_from_camera(),
        &SegmentParams::for_cell(&config),
        &models,
        &RegisterParams::default(),
        1,
    )
    .unwrap();
    let own = p
        .registrations
        .iter()
        .find(|r| r.model == "mug_002")
        .unwrap();
    assert_eq!(own.status, RegistrationStatus::Ok);
    let (dp, dr) = pose_error(&own.target_from_model, &truth);
    eprintln!(
        "kinect + fakenect: mug_002 off by {:.2} mm, {:.2} deg",
        dp * 1e3,
        dr.to_degrees()
    );
    assert!(
        dp < 0.005 && dr < 5f64.to_radians(),
        "off by {:.1} mm, {:.1} deg",
        dp * 1e3,
        dr.to_degrees()
    );
}

#[test]
fn a_calibration_tilted_by_5_deg_fails_the_gravity_check_with_a_warning() {
    let dir = TempDir::new("kinect-gravity").unwrap();
    let config = config();
    let truth = pose_from_params(&[0.62, 0.04, config.table.height_m, 0.0, 0.0, 1.05]);
    let recording = record_mug(&dir, &truth, 2);
    // A calibration result whose mount is the true one pitched 5 deg (about the
    // optical x axis, square to gravity): the camera "was bumped".
    let tilted =
        config.base_from_camera() * pose_from_params(&[0.0, 0.0, 0.0, 5f64.to_radians(), 0.0, 0.0]);
    let hand_eye = dir.join("hand_eye.toml");
    HandEyeResult {
        created: "2026-11-25T10:00:00Z".into(),
        method: "test".into(),
        samples_file: "none".into(),
        sample_count: 25,
        target_in_flange_m: [0.0, 0.0, 0.1],
        residuals: ResidualStats {
            rms_mm: 1.0,
            median_mm: 1.0,
            max_mm: 2.0,
            rms_deg: None,
            max_deg: None,
        },
        base_from_camera: PoseJson::from(&tilted),
        flange_from_target: None,
    }
    .save(&hand_eye)
    .unwrap();
    let domain = Domain::temporary("kinect-gravity").unwrap();
    let camera = fakenect_camera(
        &kinect_config(&dir),
        &domain,
        &dir.join("run"),
        &recording,
        &hand_eye,
    );
    let operator = Operator::new(&domain);
    operator.wait_for(1, &camera);
    operator.request(1);
    let status = operator.status(&camera);
    assert_eq!(
        status.fault().unwrap(),
        CameraFault::None,
        "{}",
        camera.stderr()
    );
    let angle_deg = status.gravity_angle_rad.to_degrees();
    assert!((angle_deg - 5.0).abs() < 0.3, "{status:?}");
    assert_eq!(status.gravity_warning, 1);
    let seen = poll_until(Duration::from_secs(10), || {
        Ok(camera.stderr().contains(
            "gravity check: the camera's accelerometer and the calibrated mount disagree",
        ))
    })
    .unwrap();
    assert!(seen, "no warning: {}", camera.stderr());
}

#[test]
fn without_a_kinect_the_backend_names_the_usb_and_udev_checks() {
    // The real libfreenect (no fakenect on the search path) on a machine without a Kinect.
    let err = Kinect::open(KinectOptions {
        index: 0,
        rgb: false,
        frame_timeout_s: 1.0,
        settle_frames: 0,
        library: None,
    })
    .unwrap_err();
    assert!(matches!(err, KinectError::NoDevice { index: 0 }), "{err}");
    let text = err.to_string();
    assert!(
        text.contains("udev rule") && text.contains("045e:02ae") && text.contains("lsusb"),
        "{text}"
    );

    // The stage says so at start, stays up, and fails each trial with the fault.
    let dir = TempDir::new("kinect-nodevice").unwrap();
    let domain = Domain::temporary("kinect-nodevice").unwrap();
    let camera = Process::start(
        "camera",
        &kinect_config(&dir),
        &domain,
        &dir.join("run"),
        &[],
        &[],
    );
    let operator = Operator::new(&domain);
    operator.wait_for(1, &camera);
    assert!(
        camera.stderr().contains("no Kinect found"),
        "{}",
        camera.stderr()
    );
    operator.request(1);
    assert_eq!(
        operator.status(&camera).fault().unwrap(),
        CameraFault::NoDevice
    );
}

#[test]
fn a_recording_cut_short_fails_the_trial_with_cause_camera_and_the_stage_recovers() {
    let dir = TempDir::new("kinect-cut").unwrap();
    let config = config();
    let truth = pose_from_params(&[0.62, 0.04, config.table.height_m, 0.0, 0.0, 1.05]);
    // Two frames: one snapshot (a settling frame and the kept one), then the end.
    let recording = record_mug(&dir, &truth, 2);
    let config_path = kinect_config(&dir);
    let domain = Domain::temporary("kinect-cut").unwrap();
    let run_dir = dir.join("run");
    let camera = fakenect_camera(
        &config_path,
        &domain,
        &run_dir,
        &recording,
        &dir.join("none.toml"),
    );
    let log_path = run_dir.join("trials.sqlite");
    let log = Process::start(
        "log",
        &config_path,
        &domain,
        &run_dir,
        &[
            "--log".into(),
            log_path.display().to_string(),
            "--trial-timeout-s".into(),
            "60".into(),
        ],
        &[],
    );
    let operator = Operator::new(&domain);
    operator.wait_for(2, &camera);
    let up = poll_until(Duration::from_secs(60), || {
        Ok(operator.results.publisher_peers()?.alive >= 1)
    })
    .unwrap();
    assert!(up, "log: {}", log.stderr());

    // 1: the recording's one snapshot.
    operator.request(1);
    assert_eq!(operator.status(&camera).fault().unwrap(), CameraFault::None);
    let first = operator
        .clouds
        .receive_timeout(Duration::from_secs(30))
        .unwrap()
        .expect("cloud 1");
    assert_eq!(first.header().trial_id, 1);
    drop(first);
    // 2: the recording has ended mid-run: the device vanished.
    operator.request(2);
    assert_eq!(
        operator.status(&camera).fault().unwrap(),
        CameraFault::Vanished,
        "{}",
        camera.stderr()
    );
    let result = loop {
        let r = operator
            .results
            .receive_timeout(Duration::from_secs(60))
            .unwrap()
            .unwrap_or_else(|| panic!("no result for trial 2: {}", log.stderr()));
        if r.trial_id == 2 {
            break r;
        }
    };
    assert_eq!(result.cause().unwrap(), FailureCause::Camera, "{result:?}");
    // 3: the device "returns" (fakenect plays the recording again from its
    // start once the backend reopens it): the stage recovered.
    operator.request(3);
    assert_eq!(
        operator.status(&camera).fault().unwrap(),
        CameraFault::None,
        "{}",
        camera.stderr()
    );
    let again = operator
        .clouds
        .receive_timeout(Duration::from_secs(30))
        .unwrap()
        .expect("cloud 3");
    assert_eq!(again.header().trial_id, 3);
    assert!(
        again
            .to_cloud()
            .points
            .iter()
            .filter(|p| p.z.is_finite())
            .count()
            > 100_000
    );
    drop(again);
    drop(log);
    // The trial log names the camera's fault.
    let trials = graspcell::trial::TrialLog::open(&log_path)
        .unwrap()
        .trials()
        .unwrap();
    let noted = trials
        .iter()
        .any(|t| format!("{t:?}").contains("camera: the device vanished mid-run"));
    assert!(noted, "{trials:?}");
}
