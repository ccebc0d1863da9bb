//! Hand–eye calibration: accuracy on synthetic samples, the refinement's guarantee,
//! degenerate input, file round trips, the CLI, and the files shipped under `calib/`.

use clap::Parser;
use graspcell::calib::synthetic::{point_samples, pose_samples, Noise, SyntheticScene};
use graspcell::calib::{
    daniilidis, evaluate, fit_target, park_martin, point_solver, refine, solve, tsai_lenz,
    CalibError, HandEye, HandEyeResult, Method, PointSample, PoseSample, Sample, SampleFile,
    SolveOptions, Weights,
};
use graspcell::fsio::TempDir;
use graspcell::geometry::{pose_error, pose_from_params, Pose};
use nalgebra::{Isometry3, UnitQuaternion, Vector3};
use std::path::{Path, PathBuf};

/// The synthetic samples' noise: 0.5 mm and 0.2° per axis on every observation.
fn noise() -> Noise {
    Noise::typical()
}

fn as_samples<T: Copy>(v: &[T], f: fn(T) -> Sample) -> Vec<Sample> {
    v.iter().copied().map(f).collect()
}

/// (mm, deg) between two poses.
fn error_mm_deg(a: &Pose, b: &Pose) -> (f64, f64) {
    let (dp, dr) = pose_error(a, b);
    (dp * 1e3, dr.to_degrees())
}

// Bounds for 20 samples with 0.5 mm / 0.2° noise per axis, over seeds 0..10.
// The closed forms estimate the rotation from relative motions only; their camera
// position error is about their rotation error times the ~1 m camera-to-target
// distance. The refinement and the point solver use every residual directly.
const CLOSED_FORM_MAX: (f64, f64) = (8.0, 0.8);
const CLOSED_FORM_MEAN: (f64, f64) = (4.0, 0.35);
const REFINED_MAX: (f64, f64) = (2.0, 0.2);
const REFINED_MEAN: (f64, f64) = (1.2, 0.1);
const SEEDS: u64 = 10;

fn check_bounds(name: &str, errors: &[(f64, f64)], max: (f64, f64), mean: (f64, f64)) {
    let worst = errors
        .iter()
        .fold((0.0f64, 0.0f64), |a, e| (a.0.max(e.0), a.1.max(e.1)));
    let n = errors.len() as f64;
    let avg = errors
        .iter()
        .fold((0.0, 0.0), |a, e| (a.0 + e.0 / n, a.1 + e.1 / n));
    eprintln!(
        "{name}: worst {:.2} mm {:.3}°, mean {:.2} mm {:.3}°",
        worst.0, worst.1, avg.0, avg.1
    );
    assert!(
        worst.0 < max.0 && worst.1 < max.1,
        "{name}: worst {worst:?} exceeds {max:?}"
    );
    assert!(
        avg.0 < mean.0 && avg.1 < mean.1,
        "{name}: mean {avg:?} exceeds {mean:?}"
    );
}

#[test]
fn every_pose_method_recovers_a_known_transform_from_noisy_samples() {
    let scene = SyntheticScene::nominal();
    let mut errors: Vec<(&str, Vec<(f64, f64)>)> = ["tsai", "park", "daniilidis", "refined"]
        .iter()
        .map(|n| (*n, Vec::new()))
        .collect();
    for seed in 0..SEEDS {
        let poses = pose_samples(&scene, 20, &noise(), seed);
        let estimates = [
            tsai_lenz(&poses).unwrap(),
            park_martin(&poses).unwrap(),
            daniilidis(&poses).unwrap(),
            solve(&as_samples(&poses, Sample::Pose), &SolveOptions::default())
                .unwrap()
                .best()
                .evaluation
                .hand_eye
                .base_from_camera,
        ];
        for (k, x) in estimates.iter().enumerate() {
            errors[k].1.push(error_mm_deg(x, &scene.base_from_camera));
        }
    }
    for (name, e) in &errors {
        let (max, mean) = if *name == "refined" {
            (REFINED_MAX, REFINED_MEAN)
        } else {
            (CLOSED_FORM_MAX, CLOSED_FORM_MEAN)
        };
        check_bounds(name, e, max, mean);
    }
}

#[test]
fn point_methods_recover_a_known_transform_from_noisy_points() {
    let scene = SyntheticScene::nominal();
    let y = scene.flange_from_target.translation.vector;
    let (mut unknown, mut known, mut offset_mm) = (Vec::new(), Vec::new(), 0.0f64);
    for seed in 0..SEEDS {
        let points = point_samples(&scene, 20, &noise(), seed);
        let he = point_solver(&points, None, &Weights::default()).unwrap();
        unknown.push(error_mm_deg(&he.base_from_camera, &scene.base_from_camera));
        offset_mm = offset_mm.max((he.flange_from_target.translation.vector - y).norm() * 1e3);
        let he = point_solver(&points, Some(y), &Weights::default()).unwrap();
        known.push(error_mm_deg(&he.base_from_camera, &scene.base_from_camera));
    }
    check_bounds(
        "points, unknown offset",
        &unknown,
        REFINED_MAX,
        REFINED_MEAN,
    );
    check_bounds(
        "points, known offset (kabsch)",
        &known,
        REFINED_MAX,
        REFINED_MEAN,
    );
    assert!(offset_mm < 2.0, "target offset off by {offset_mm} mm");
}

#[test]
fn a_known_target_position_needs_no_rotation() {
    // A sphere on a measured mount, moved by translation only: Kabsch applies, the
    // unknown-offset solver cannot tell the offset from the camera position.
    let scene = SyntheticScene::nominal();
    let orientation = pose_from_params(&[0.0, 0.0, 0.0, 3.1, 0.2, 0.5]).rotation;
    let y = scene.flange_from_target.translation.vector;
    let samples: Vec<Sample> = [
        [0.5, -0.2, 0.2],
        [0.7, 0.1, 0.3],
        [0.6, 0.2, 0.45],
        [0.55, 0.0, 0.35],
        [0.75, -0.15, 0.25],
    ]
    .iter()
    .map(|p| {
        let flange = Isometry3::from_parts(Vector3::from(*p).into(), orientation);
        Sample::Point(PointSample {
            base_from_flange: flange,
            target_point_camera_m: scene.base_from_camera.inverse()
                * (flange * nalgebra::Point3::from(y)),
        })
    })
    .collect();
    let known = SolveOptions {
        method: Method::Points,
        known_target_point: Some(y),
        ..SolveOptions::default()
    };
    let s = solve(&samples, &known).unwrap();
    let (mm, deg) = error_mm_deg(
        &s.best().evaluation.hand_eye.base_from_camera,
        &scene.base_from_camera,
    );
    assert!(mm < 1e-6 && deg < 1e-6, "{mm} mm {deg}°");
    assert!(s.warnings.is_empty(), "{:?}", s.warnings);
    let err = solve(&samples, &SolveOptions::default()).unwrap_err();
    assert!(matches!(err, CalibError::RotationsTooSmall { .. }), "{err}");
}

#[test]
fn refinement_is_never_worse_than_its_start() {
    let scene = SyntheticScene::nominal();
    let weights = Weights::default();
    for seed in 0..20 {
        let n = 5 + (seed as usize % 4) * 5;
        let poses = pose_samples(&scene, n, &noise(), 100 + seed);
        let samples = as_samples(&poses, Sample::Pose);
        let with_target = |x: Pose| HandEye {
            base_from_camera: x,
            flange_from_target: fit_target(&samples, &x, None),
        };
        let nudge = pose_from_params(&[0.02, -0.03, 0.01, 0.05, 0.02, -0.04]);
        let far = pose_from_params(&[0.3, 0.2, -0.2, 0.8, -0.6, 1.0]);
        let starts = [
            with_target(tsai_lenz(&poses).unwrap()),
            with_target(park_martin(&poses).unwrap()),
            with_target(daniilidis(&poses).unwrap()),
            scene.hand_eye(),
            with_target(nudge * scene.base_from_camera),
            with_target(far * scene.base_from_camera),
        ];
        for (k, start) in starts.iter().enumerate() {
            let start_cost = evaluate(&samples, start, &weights).cost;
            let r = refine(&samples, start, None, &weights);
            let cost = evaluate(&samples, &r.hand_eye, &weights).cost;
            assert!((r.start_cost - start_cost).abs() <= 1e-9 * start_cost);
            assert!(
                cost <= start_cost,
                "seed {seed} start {k}: {cost} > {start_cost}"
            );
            assert!((cost - r.cost).abs() <= 1e-9 * cost.max(1.0));
        }
    }
}

/// Samples whose flange only ever turns about the base z axis.
fn turning_about_z(angles_deg: &[f64]) -> Vec<Sample> {
    let scene = SyntheticScene::nominal();
    let base_target = pose_from_params(&[0.6, 0.0, 0.3, 0.3, 0.9, 0.2]);
    angles_deg
        .iter()
        .enumerate()
        .map(|(i, a)| {
            let mut target = base_target;
            target.rotation = UnitQuaternion::from_axis_angle(&Vector3::z_axis(), a.to_radians())
                * target.rotation;
            target.translation.vector +=
                Vector3::new(0.03 * i as f64, -0.02 * i as f64, 0.01 * (i % 3) as f64);
            Sample::Pose(PoseSample {
                base_from_flange: target * scene.flange_from_target.inverse(),
                camera_from_target: scene.base_from_camera.inverse() * target,
            })
        })
        .collect()
}

#[test]
fn degenerate_inputs_say_what_to_change() {
    let options = SolveOptions::default();
    let scene = SyntheticScene::nominal();
    let good = as_samples(&pose_samples(&scene, 12, &noise(), 4), Sample::Pose);

    let err = solve(&good[..2], &options).unwrap_err();
    assert!(
        matches!(
            err,
            CalibError::TooFewSamples {
                got: 2,
                need: 3,
                ..
            }
        ),
        "{err}"
    );
    assert!(err.to_string().contains("capture more poses"));

    let err = solve(&turning_about_z(&[0.0, 25.0, -30.0, 50.0, 10.0]), &options).unwrap_err();
    assert!(matches!(err, CalibError::ParallelAxes { .. }), "{err}");
    assert!(
        err.to_string()
            .contains("add poses rotating about a different axis"),
        "{err}"
    );

    let err = solve(&turning_about_z(&[0.0, 1.0, 2.0, 3.0]), &options).unwrap_err();
    assert!(matches!(err, CalibError::RotationsTooSmall { .. }), "{err}");
    assert!(
        err.to_string().contains("rotate the hand between poses"),
        "{err}"
    );

    let mut nan = good.clone();
    if let Sample::Pose(p) = &mut nan[3] {
        p.base_from_flange.translation.vector.z = f64::NAN;
    }
    let err = solve(&nan, &options).unwrap_err().to_string();
    assert!(
        err.starts_with("sample 3: base_from_flange holds a non-finite value (NaN)"),
        "{err}"
    );
}

#[test]
fn wrong_frames_are_caught_with_what_to_check() {
    let scene = SyntheticScene::nominal();
    let poses = pose_samples(&scene, 12, &noise(), 6);
    let options = SolveOptions::default();
    // Robot poses given as flange_from_base.
    let inverted: Vec<Sample> = poses
        .iter()
        .map(|p| {
            Sample::Pose(PoseSample {
                base_from_flange: p.base_from_flange.inverse(),
                ..*p
            })
        })
        .collect();
    let err = solve(&inverted, &options).unwrap_err();
    assert!(matches!(err, CalibError::ResidualsTooLarge { .. }), "{err}");
    assert!(
        err.to_string().contains(
            "with one side of each sample inverted: the robot poses are probably flange_from_base"
        ),
        "{err}"
    );
    // Observations given as target_from_camera.
    let inverted: Vec<Sample> = poses
        .iter()
        .map(|p| {
            Sample::Pose(PoseSample {
                camera_from_target: p.camera_from_target.inverse(),
                ..*p
            })
        })
        .collect();
    let err = solve(&inverted, &options).unwrap_err().to_string();
    assert!(
        err.contains("or the observations target_from_camera (not camera_from_target)"),
        "{err}"
    );
    // Observations paired with the wrong robot poses (shifted by one).
    let shifted: Vec<Sample> = (0..poses.len())
        .map(|i| {
            Sample::Pose(PoseSample {
                base_from_flange: poses[i].base_from_flange,
                camera_from_target: poses[(i + 1) % poses.len()].camera_from_target,
            })
        })
        .collect();
    let err = solve(&shifted, &options).unwrap_err();
    assert!(
        matches!(err, CalibError::FramesInconsistent { .. }),
        "{err}"
    );
    assert!(
        err.to_string().contains("captured at the same moment"),
        "{err}"
    );
    // Camera translations in millimetres, robot in metres.
    let millimetres: Vec<Sample> = poses
        .iter()
        .map(|p| {
            let mut c = p.camera_from_target;
            c.translation.vector *= 1e3;
            Sample::Pose(PoseSample {
                camera_from_target: c,
                ..*p
            })
        })
        .collect();
    let err = solve(&millimetres, &options).unwrap_err();
    assert!(
        matches!(err, CalibError::FramesInconsistent { .. }),
        "{err}"
    );
    assert!(err.to_string().contains("both in metres"), "{err}");
    // Eye-in-hand data (camera on the flange, target fixed): fits with the robot poses inverted.
    let flange_from_camera = pose_from_params(&[0.05, 0.0, 0.1, 0.0, 0.0, 1.57]);
    let base_from_target = pose_from_params(&[0.7, 0.1, 0.0, 0.0, 0.0, 0.3]);
    let eye_in_hand: Vec<Sample> = poses
        .iter()
        .map(|p| {
            Sample::Pose(PoseSample {
                base_from_flange: p.base_from_flange,
                camera_from_target: (p.base_from_flange * flange_from_camera).inverse()
                    * base_from_target,
            })
        })
        .collect();
    let err = solve(&eye_in_hand, &options).unwrap_err().to_string();
    assert!(err.contains("eye-in-hand"), "{err}");
    // Noisy but correct samples pass the check for every seed tried.
    for seed in 0..20 {
        let samples = as_samples(&pose_samples(&scene, 6, &noise(), seed), Sample::Pose);
        solve(&samples, &options).unwrap();
    }
}

#[test]
fn sample_file_round_trip_through_disk() {
    let dir = TempDir::new("calib-samples").unwrap();
    let scene = SyntheticScene::nominal();
    let mut samples = as_samples(&pose_samples(&scene, 5, &noise(), 1), Sample::Pose);
    samples.extend(as_samples(
        &point_samples(&scene, 3, &noise(), 2),
        Sample::Point,
    ));
    let file = SampleFile {
        created: "2025-01-01T00:00:00Z".into(),
        comment: None,
        samples,
    };
    let path = dir.join("calib").join("samples-test.json");
    file.save(&path).unwrap();
    let back = SampleFile::load(&path).unwrap();
    assert_eq!(back.samples.len(), 8);
    for (a, b) in file.samples.iter().zip(&back.samples) {
        let (dp, dr) = pose_error(a.base_from_flange(), b.base_from_flange());
        assert!(dp < 1e-12 && dr < 1e-9);
        assert!((a.target_point_camera() - b.target_point_camera()).norm() < 1e-12);
        assert_eq!(matches!(a, Sample::Pose(_)), matches!(b, Sample::Pose(_)));
    }
    let err = SampleFile::load(&dir.join("missing.json"))
        .unwrap_err()
        .to_string();
    assert!(
        err.starts_with("cannot read ") && err.contains("missing.json"),
        "{err}"
    );
}

fn cell(args: &[&str]) -> anyhow::Result<std::process::ExitCode> {
    let mut argv = vec!["cell"];
    argv.extend_from_slice(args);
    graspcell::cli::run(graspcell::cli::Cli::try_parse_from(argv)?)
}

fn write_samples(dir: &Path, samples: Vec<Sample>) -> PathBuf {
    let path = dir.join("samples.json");
    SampleFile {
        created: "2025-01-01T00:00:00Z".into(),
        comment: Some("synthetic".into()),
        samples,
    }
    .save(&path)
    .unwrap();
    path
}

#[test]
fn cli_solve_writes_a_result_perception_can_load() {
    let dir = TempDir::new("calib-cli").unwrap();
    let scene = SyntheticScene::nominal();
    let samples = write_samples(
        &dir,
        as_samples(&pose_samples(&scene, 20, &noise(), 11), Sample::Pose),
    );
    let out = dir.join("calib").join("hand_eye.toml");
    for method in ["all", "tsai", "park", "daniilidis", "points"] {
        let _ = std::fs::remove_file(&out);
        let args = [
            "calibrate",
            "solve",
            "--samples",
            samples.to_str().unwrap(),
            "--method",
            method,
            "--out",
            out.to_str().unwrap(),
            "--json",
        ];
        cell(&args).unwrap();
        let result = HandEyeResult::load(&out).unwrap();
        assert!(
            result.method.starts_with(method) || method == "all",
            "{}",
            result.method
        );
        assert!(result.method.ends_with("+refine"));
        assert_eq!(result.sample_count, 20);
        assert!(result.flange_from_target.is_some());
        let (mm, deg) = error_mm_deg(&result.base_from_camera().unwrap(), &scene.base_from_camera);
        assert!(
            mm < REFINED_MAX.0 && deg < REFINED_MAX.1,
            "{method}: {mm} mm {deg}°"
        );
        assert!(result.residuals.rms_mm < 2.0 && result.residuals.rms_deg.unwrap() < 0.6);
    }
    // Point samples with a known target position, no refinement, human output.
    let points = write_samples(
        &dir,
        as_samples(&point_samples(&scene, 10, &noise(), 3), Sample::Point),
    );
    let y = scene.flange_from_target.translation.vector;
    let offset = format!("{},{},{}", y.x, y.y, y.z);
    let args = [
        "calibrate",
        "solve",
        "--samples",
        points.to_str().unwrap(),
        "--method",
        "points",
        "--target-in-flange",
        &offset,
        "--no-refine",
        "--out",
        out.to_str().unwrap(),
    ];
    cell(&args).unwrap();
    let result = HandEyeResult::load(&out).unwrap();
    assert_eq!(result.method, "points");
    assert!(result.flange_from_target.is_none() && result.residuals.rms_deg.is_none());
    assert_eq!(result.target_in_flange_m, [y.x, y.y, y.z]);
    // --dry-run writes nothing.
    std::fs::remove_file(&out).unwrap();
    let args = [
        "calibrate",
        "solve",
        "--samples",
        points.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
        "--dry-run",
    ];
    cell(&args).unwrap();
    assert!(!out.exists());
}

#[test]
fn cli_rejects_bad_input_and_keeps_the_old_result() {
    let dir = TempDir::new("calib-cli-bad").unwrap();
    let out = dir.join("hand_eye.toml");
    std::fs::write(&out, "old").unwrap();
    let run = |samples: &Path, method: &str| {
        let args = [
            "calibrate",
            "solve",
            "--samples",
            samples.to_str().unwrap(),
            "--method",
            method,
            "--out",
            out.to_str().unwrap(),
        ];
        format!("{:#}", cell(&args).unwrap_err())
    };
    let degenerate = write_samples(&dir, turning_about_z(&[0.0, 25.0, -30.0, 50.0]));
    let err = run(&degenerate, "all");
    assert!(
        err.contains("samples.json") && err.contains("add poses rotating about a different axis"),
        "{err}"
    );
    let scene = SyntheticScene::nominal();
    let points = write_samples(
        &dir,
        as_samples(&point_samples(&scene, 6, &noise(), 1), Sample::Point),
    );
    let err = run(&points, "daniilidis");
    assert!(
        err.contains("needs pose samples") && err.contains("--method points"),
        "{err}"
    );
    let garbled = dir.join("garbled.json");
    std::fs::write(&garbled, "{\"created\": \"x\", \"samples\": [").unwrap();
    let err = run(&garbled, "all");
    assert!(err.contains("garbled.json") && err.contains("EOF"), "{err}");
    assert_eq!(std::fs::read_to_string(&out).unwrap(), "old");
    let names: Vec<_> = std::fs::read_dir(&*dir)
        .unwrap()
        .map(|e| e.unwrap().file_name())
        .collect();
    assert!(
        !names.iter().any(|n| n.to_string_lossy().contains(".tmp")),
        "{names:?}"
    );
}

/// The repository's `calib/` directory.
fn calib_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("calib")
}

/// Seed and size of the shipped example sample file.
const EXAMPLE_SEED: u64 = 2025;
const EXAMPLE_POSES: usize = 20;
const EXAMPLE_POINTS: usize = 4;

#[test]
fn every_shipped_calib_file_parses() {
    let mut checked = 0;
    for entry in std::fs::read_dir(calib_dir()).unwrap() {
        let path = entry.unwrap().path();
        match path.extension().and_then(|e| e.to_str()) {
            Some("json") => {
                SampleFile::load(&path).unwrap();
            }
            Some("toml") => {
                HandEyeResult::load(&path).unwrap();
            }
            _ => panic!(
                "{}: unexpected file under calib/ (samples are .json, results .toml)",
                path.display()
            ),
        }
        checked += 1;
    }
    assert!(checked >= 1, "calib/ ships no file");
}

#[test]
fn example_samples_solve_to_their_stated_truth() {
    let file = SampleFile::load(&calib_dir().join("samples-example.json")).unwrap();
    assert_eq!(file.samples.len(), EXAMPLE_POSES + EXAMPLE_POINTS);
    assert!(file.comment.as_deref().unwrap_or("").contains("Synthetic"));
    let s = solve(&file.samples, &SolveOptions::default()).unwrap();
    let scene = SyntheticScene::nominal();
    let (mm, deg) = error_mm_deg(
        &s.best().evaluation.hand_eye.base_from_camera,
        &scene.base_from_camera,
    );
    assert!(mm < REFINED_MAX.0 && deg < REFINED_MAX.1, "{mm} mm {deg}°");
    let only_points = SolveOptions {
        method: Method::Points,
        ..SolveOptions::default()
    };
    solve(&file.samples, &only_points).unwrap();
}

/// Regenerates `calib/samples-example.json`: `cargo test --test tests -- --ignored regenerate_example_samples`.
#[test]
#[ignore]
fn regenerate_example_samples() {
    let scene = SyntheticScene::nominal();
    let mut samples = as_samples(
        &pose_samples(&scene, EXAMPLE_POSES, &noise(), EXAMPLE_SEED),
        Sample::Pose,
    );
    samples.extend(as_samples(
        &point_samples(&scene, EXAMPLE_POINTS, &noise(), EXAMPLE_SEED + 1),
        Sample::Point,
    ));
    let json = |p: &Isometry3<f64>| {
        serde_json::to_string(&graspcell::geometry::PoseJson::from(p)).unwrap()
    };
    let file = SampleFile {
        created: "2025-01-01T00:00:00Z".into(),
        comment: Some(format!(
            "Synthetic example, not measured: {EXAMPLE_POSES} board (pose) samples and {EXAMPLE_POINTS} sphere (point) samples generated by tests/calib.rs regenerate_example_samples (seeds {EXAMPLE_SEED}, {}) with noise 0.5 mm / 0.2 deg per axis from base_from_camera {} and flange_from_target {}.",
            EXAMPLE_SEED + 1,
            json(&scene.base_from_camera),
            json(&scene.flange_from_target)
        )),
        samples,
    };
    file.save(&calib_dir().join("samples-example.json"))
        .unwrap();
}
