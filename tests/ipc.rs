//! iceoryx2 between real processes: the test is one process, the `cell` binary in its
//! hidden `ipc-peer` mode the other. Each test has its own isolated domain (root
//! directory, file prefix and instance name from the process id, a counter and the
//! test name), removed at the end even when the test fails; waits are bounded.

use graspcell::geometry::pose_from_params;
use graspcell::ipc::peer::{PeerProcess, PeerRole, PeerSpec};
use graspcell::ipc::stage::poll_until;
use graspcell::ipc::{
    CloudHeader, CloudTopic, Domain, Frame, Intrinsics, Peers, Point, Stage, StageStatus,
    TrialRequest, MAX_CLOUD_POINTS,
};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use std::path::{Path, PathBuf};
use std::time::Duration;

/// Longest wait for another process at any step (a watchdog, not a speed limit).
const WAIT: Duration = Duration::from_secs(30);

fn cell_exe() -> &'static Path {
    Path::new(env!("CARGO_BIN_EXE_cell"))
}

fn spec(domain: &Domain, role: PeerRole) -> PeerSpec {
    PeerSpec {
        domain: domain.spec(),
        idle_timeout_s: WAIT.as_secs_f64(),
        role,
    }
}

fn header(trial_id: u64, width: u32, height: u32, seed: u64) -> CloudHeader {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let intrinsics = Intrinsics {
        fx: rng.gen_range(400.0..600.0),
        fy: rng.gen_range(400.0..600.0),
        cx: rng.gen_range(300.0..340.0),
        cy: rng.gen_range(220.0..260.0),
    };
    let base_from_camera = pose_from_params(&[
        rng.gen_range(-1.0..1.0),
        rng.gen_range(-1.0..1.0),
        rng.gen_range(0.5..2.0),
        rng.gen_range(-3.0..3.0),
        rng.gen_range(-1.5..1.5),
        rng.gen_range(-3.0..3.0),
    ]);
    CloudHeader::new(
        trial_id,
        seed * 1000,
        width,
        height,
        intrinsics,
        Frame::CameraOptical,
        &base_from_camera,
    )
}

/// Random points with every 97th point missing (NaN), as a depth camera gives.
fn random_points(n: usize, seed: u64) -> Vec<Point> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    (0..n)
        .map(|i| {
            if i % 97 == 5 {
                Point::new(f32::NAN, f32::NAN, f32::NAN)
            } else {
                Point::new(
                    rng.gen_range(-1.0..1.0),
                    rng.gen_range(-1.0..1.0),
                    rng.gen_range(0.3..3.0),
                )
            }
        })
        .collect()
}

fn bits(p: &Point) -> [u32; 3] {
    [p.x.to_bits(), p.y.to_bits(), p.z.to_bits()]
}

fn assert_same_points(got: &[Point], want: &[Point]) {
    assert_eq!(got.len(), want.len());
    if let Some(i) = (0..want.len()).find(|&i| bits(&got[i]) != bits(&want[i])) {
        panic!("point {i}: got {:?}, sent {:?}", got[i], want[i]);
    }
}

#[test]
fn a_full_cloud_crosses_to_another_process_and_back_unchanged() {
    let domain = &Domain::temporary("ipc-echo").unwrap();
    {
        let stage = Stage::start(domain, "test").unwrap();
        let clouds = stage.cloud_publisher(CloudTopic::Camera).unwrap();
        let echoes = stage.cloud_subscriber(CloudTopic::Echo).unwrap();
        let mut peer =
            PeerProcess::spawn(cell_exe(), &spec(domain, PeerRole::Echo { count: 2 })).unwrap();
        assert!(
            poll_until(WAIT, || Ok(clouds.subscriber_peers()?.alive == 1)).unwrap(),
            "echo peer did not subscribe"
        );

        let sent = [
            (header(11, 640, 480, 1), random_points(MAX_CLOUD_POINTS, 1)),
            (header(12, 7, 3, 2), random_points(21, 2)),
        ];
        for (h, points) in &sent {
            assert_eq!(clouds.send_copy(*h, points).unwrap(), 1);
            let echo = echoes
                .receive_timeout(WAIT)
                .unwrap()
                .expect("no echo within the watchdog time");
            echo.validate().unwrap();
            assert_eq!(echo.header(), h);
            assert_eq!(echo.header().frame().unwrap(), Frame::CameraOptical);
            assert_same_points(echo.points(), points);
        }
        assert_eq!(
            echoes.publisher_peers().unwrap(),
            Peers { alive: 1, dead: 0 }
        );
        peer.finish(WAIT).unwrap();
        assert_eq!(echoes.publisher_peers().unwrap(), Peers::default());
    }
    assert_eq!(domain.alive_nodes().unwrap(), 0);
    assert_eq!(domain.leftover_files().unwrap(), Vec::<PathBuf>::new());
    domain.remove().unwrap();
    assert!(domain.files().unwrap().is_empty());
}

/// The camera peer's cloud for `trial_id`, computed here independently.
fn assert_camera_pattern(points: &[Point], trial_id: u64) {
    assert_eq!(points.len(), MAX_CLOUD_POINTS);
    for (i, p) in points.iter().enumerate() {
        let want = [i as f32, trial_id as f32, -(i as f32)];
        assert_eq!([p.x, p.y, p.z], want, "point {i} of trial {trial_id}");
    }
}

#[test]
fn a_killed_publisher_is_noticed_cleaned_and_replaced_without_resubscribing() {
    let domain = &Domain::temporary("ipc-kill").unwrap();
    let camera = |count| PeerRole::Camera {
        count,
        width: 640,
        height: 480,
    };
    {
        let stage = Stage::start(domain, "operator").unwrap();
        let requests = stage.publisher::<TrialRequest>().unwrap();
        let clouds = stage.cloud_subscriber(CloudTopic::Camera).unwrap();
        let ask = |trial_id| {
            let request = TrialRequest::new(trial_id, 0, "mug", "top", "laplace").unwrap();
            assert_eq!(requests.send(&request).unwrap(), 1);
            let cloud = clouds.receive_timeout(WAIT).unwrap();
            cloud.unwrap_or_else(|| panic!("no cloud for trial {trial_id}"))
        };

        let mut first = PeerProcess::spawn(cell_exe(), &spec(domain, camera(100))).unwrap();
        assert!(poll_until(WAIT, || Ok(requests.subscriber_peers()?.alive == 1)).unwrap());
        let cloud = ask(1);
        assert_eq!(cloud.header().trial_id, 1);
        assert_camera_pattern(cloud.points(), 1);
        drop(cloud);
        assert_eq!(stage.stage_status("camera").unwrap(), StageStatus::Alive);

        first.kill().unwrap();
        // The dead process is noticed from its ports and its node.
        let dead = Peers { alive: 0, dead: 1 };
        assert_eq!(clouds.publisher_peers().unwrap(), dead);
        assert_eq!(requests.subscriber_peers().unwrap(), dead);
        assert_eq!(stage.stage_status("camera").unwrap(), StageStatus::Dead);
        assert!(!domain.leftover_files().unwrap().is_empty());

        // Any stage that starts removes the dead node's resources.
        let janitor = Stage::start(domain, "janitor").unwrap();
        assert_eq!(janitor.dead_nodes_cleaned_at_start(), 1);
        assert_eq!(clouds.publisher_peers().unwrap(), Peers::default());
        assert_eq!(stage.stage_status("camera").unwrap(), StageStatus::Missing);
        drop(janitor);

        // A new camera process serves the same, never re-created, subscriber.
        let mut second = PeerProcess::spawn(cell_exe(), &spec(domain, camera(1))).unwrap();
        assert!(poll_until(WAIT, || Ok(clouds.publisher_peers()?.alive == 1)).unwrap());
        assert_eq!(
            requests.subscriber_peers().unwrap(),
            Peers { alive: 1, dead: 0 }
        );
        let cloud = ask(2);
        assert_eq!(cloud.header().trial_id, 2);
        assert_camera_pattern(cloud.points(), 2);
        drop(cloud);
        second.finish(WAIT).unwrap();
    }
    // Nothing of the killed process is left once everyone is gone.
    assert_eq!(domain.alive_nodes().unwrap(), 0);
    assert_eq!(domain.leftover_files().unwrap(), Vec::<PathBuf>::new());
    domain.remove().unwrap();
}

#[test]
fn bench_ipc_runs_between_two_processes_and_reports_json() {
    let out = std::process::Command::new(cell_exe())
        .args(["bench", "ipc", "--rounds", "3", "--warmup", "1", "--json"])
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let report: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(report["workload"]["points"], 307_200);
    assert_eq!(report["workload"]["bytes_per_message"], 192 + 307_200 * 12);
    for transport in [
        "iceoryx2_zero_copy",
        "iceoryx2_copy_in",
        "unix_socket",
        "iceoryx2_zero_copy_polling",
    ] {
        let median = report[transport]["median_us"].as_f64().unwrap();
        assert!(median > 0.0, "{transport}: {median}");
    }
    assert!(report["ratio_socket_over_iceoryx2_zero_copy"]["median"]
        .as_f64()
        .unwrap()
        .is_finite());
}
