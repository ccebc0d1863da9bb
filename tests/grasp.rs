//! Grasp simulation through the library and `cell quality --object`: a side grasp
//! of a cylinder closes all three fingers to force closure, empty space gives no
//! contacts, a hand in the object is reported; the contacts lie on the surface with
//! inward normals (checked against the cylinder's own geometry here).

use graspcell::config::CellConfig;
use graspcell::fsio::TempDir;
use graspcell::geometry::{params_from_pose, Pose};
use graspcell::mesh::obj::write_obj;
use graspcell::mesh::TriMesh;
use graspcell::quality::autograsp::{evaluate_grasp, AutoGraspOptions, GraspObject};
use graspcell::quality::QualityParams;
use graspcell::robot::hand::HandModel;
use nalgebra::{Point3, Rotation3, Translation3, UnitQuaternion, Vector3};
use std::f64::consts::TAU;
use std::path::Path;

/// A closed, outward cylinder about z, centred on the origin.
pub fn cylinder(radius: f64, height: f64, segments: u32) -> TriMesh {
    let mut vertices = vec![
        Point3::new(0.0, 0.0, -height / 2.0),
        Point3::new(0.0, 0.0, height / 2.0),
    ];
    for k in 0..segments {
        let a = TAU * k as f64 / segments as f64;
        vertices.push(Point3::new(
            radius * a.cos(),
            radius * a.sin(),
            -height / 2.0,
        ));
        vertices.push(Point3::new(
            radius * a.cos(),
            radius * a.sin(),
            height / 2.0,
        ));
    }
    let mut triangles = Vec::new();
    for k in 0..segments {
        let (b0, t0) = (2 + 2 * k, 3 + 2 * k);
        let (b1, t1) = (2 + 2 * ((k + 1) % segments), 3 + 2 * ((k + 1) % segments));
        triangles.extend([[b0, b1, t1], [b0, t1, t0], [0, b1, b0], [1, t0, t1]]);
    }
    TriMesh {
        vertices,
        triangles,
    }
}

/// The palm approaching a z-axis cylinder along +x, its flex axes (palm x) along
/// the cylinder's axis, the palm surface (z = 0.060 in the palm frame) `gap_m`
/// from the cylinder.
pub fn side_pose(radius: f64, gap_m: f64) -> Pose {
    let rot = Rotation3::from_basis_unchecked(&[Vector3::z(), -Vector3::y(), Vector3::x()]);
    Pose::from_parts(
        Translation3::new(-(radius + 0.060 + gap_m), 0.0, 0.0),
        UnitQuaternion::from_rotation_matrix(&rot),
    )
}

/// `x,y,z,roll,pitch,yaw` of a pose for the command line.
pub fn pose_arg(pose: &Pose) -> String {
    params_from_pose(pose).map(|v| format!("{v}")).join(",")
}

pub fn shipped_hand() -> HandModel {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("robot/cell.toml");
    HandModel::load(&CellConfig::load(&path).unwrap()).unwrap()
}

fn cell(args: &[&str]) -> std::process::Output {
    std::process::Command::new(env!("CARGO_BIN_EXE_cell"))
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .args(args)
        .output()
        .unwrap()
}

#[test]
fn library_side_grasp_of_a_35_mm_cylinder_is_force_closure_with_three_fingers() {
    let hand = shipped_hand();
    let radius = 0.035;
    let object = GraspObject::new(&cylinder(radius, 0.25, 72), Path::new("cylinder")).unwrap();
    // GraspIt!'s torque scale: the largest centroid-to-surface distance.
    assert!((object.torque_scale_m - radius.hypot(0.125)).abs() < 1e-12);
    assert!(object.centroid.coords.norm() < 1e-12);
    let e = evaluate_grasp(
        &hand,
        &object,
        &side_pose(radius, 1e-4),
        &graspcell::robot::HandPose::open(0.0),
        &AutoGraspOptions::default(),
        &QualityParams::default(),
        false,
    )
    .unwrap();
    assert!(e.force_closure, "{e:?}");
    let fingers: std::collections::BTreeSet<&str> =
        e.outcome.contacts.iter().map(|c| &c.link[..5]).collect();
    assert_eq!(
        fingers.into_iter().collect::<Vec<_>>(),
        ["bh_f1", "bh_f2", "bh_f3", "bh_pa"]
    );
}

#[test]
fn cli_closes_the_hand_around_a_cylinder_file() {
    let dir = TempDir::new("grasp-cli").unwrap();
    let radius = 0.035;
    let mesh_path = dir.join("cylinder.obj");
    write_obj(&mesh_path, &cylinder(radius, 0.25, 72)).unwrap();
    let mesh_arg = mesh_path.to_str().unwrap();
    let run = |pose: &Pose, extra: &[&str]| {
        let pose = pose_arg(pose);
        let mut args = vec!["quality", "--json", "--object", mesh_arg, "--pose", &pose];
        args.extend_from_slice(extra);
        let out = cell(&args);
        assert!(
            out.status.success(),
            "{}",
            String::from_utf8_lossy(&out.stderr)
        );
        serde_json::from_slice::<serde_json::Value>(&out.stdout).unwrap()
    };

    let v = run(&side_pose(radius, 1e-4), &["--spread", "0"]);
    assert_eq!(v["force_closure"], true);
    assert_eq!(v["collision_at_start"], false);
    assert!(v["epsilon"].as_f64().unwrap() > 0.0);
    assert!(v["volume"].as_f64().unwrap() > 0.0);
    let contacts = v["contacts"].as_array().unwrap();
    for finger in ["bh_f1", "bh_f2", "bh_f3"] {
        assert!(
            contacts
                .iter()
                .any(|c| c["link"].as_str().unwrap().starts_with(finger)),
            "{finger}: {contacts:?}"
        );
    }
    for c in contacts {
        let p: Vec<f64> = serde_json::from_value(c["point"].clone()).unwrap();
        let n: Vec<f64> = serde_json::from_value(c["normal"].clone()).unwrap();
        // On the 72-gon's side (within its 0.033 mm sagitta) with a unit normal
        // pointing at the axis.
        let r = p[0].hypot(p[1]);
        assert!((r - radius).abs() < 1e-4, "{c}");
        let radial = Vector3::new(-p[0], -p[1], 0.0) / r;
        let n = Vector3::new(n[0], n[1], n[2]);
        assert!(
            (n.norm() - 1.0).abs() < 1e-9 && n.dot(&radial) > 0.99,
            "{c}"
        );
    }

    // Far from the cylinder: no contacts, no closure.
    let far = Pose::translation(0.0, 0.5, 0.0) * side_pose(radius, 0.0);
    let v = run(&far, &[]);
    assert_eq!(v["contacts"].as_array().unwrap().len(), 0);
    assert_eq!(v["epsilon"], 0.0);
    assert_eq!(v["force_closure"], false);
    assert_eq!(v["flex_rad"], serde_json::json!([2.44, 2.44, 2.44]));

    // The palm 5 mm into the cylinder: reported, nothing closed.
    let into = Pose::translation(0.005, 0.0, 0.0) * side_pose(radius, 0.0);
    let v = run(&into, &[]);
    assert_eq!(v["collision_at_start"], true);
    assert_eq!(v["start_collision"]["link"], "bh_palm");
    assert_eq!(v["start_collision"]["with"], "object");
    assert_eq!(v["force_closure"], false);
    // Approached to contact, the lift test starts where the approach stopped
    // (clear of the cylinder), not at the colliding --pose.
    let v = run(&into, &["--approach-to-contact", "--lift"]);
    assert_eq!(v["collision_at_start"], false, "{v}");
    assert!(
        v["approach"]["beyond_plan_m"].as_f64().unwrap() < -0.004,
        "{v}"
    );
    assert_ne!(v["lift"]["rule"], "start_collision", "{v}");
    assert!(v["lift"]["steps"].as_u64().unwrap() > 0, "{v}");

    // With a table through the fingers: reported as the table.
    let v = run(&side_pose(radius, 1e-4), &["--table-z", "0.0"]);
    assert_eq!(v["start_collision"]["with"], "table");

    // The stability ranges on request, sigma = Delta / 3.
    let v = run(&side_pose(radius, 1e-4), &["--stability"]);
    let delta: Vec<f64> = serde_json::from_value(v["stability"]["delta"].clone()).unwrap();
    let sigma: Vec<f64> = serde_json::from_value(v["stability"]["sigma"].clone()).unwrap();
    assert_eq!(delta.len(), 6);
    for (d, s) in delta.iter().zip(&sigma) {
        assert!(*d > 0.0 && (s - d / 3.0).abs() < 1e-15);
    }

    // Bad input names what is wrong.
    let out = cell(&["quality", "--object", mesh_arg, "--pose", "0,0,nan,0,0,0"]);
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("pose"));
    let pose = pose_arg(&side_pose(radius, 1e-4));
    let out = cell(&[
        "quality", "--object", mesh_arg, "--pose", &pose, "--spread", "4",
    ]);
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("spread"));
    let missing = dir.join("none.obj");
    let out = cell(&[
        "quality",
        "--object",
        missing.to_str().unwrap(),
        "--pose",
        &pose,
    ]);
    assert!(String::from_utf8_lossy(&out.stderr).contains("none.obj"));
}

#[test]
fn bench_quality_reports_rates() {
    let out = cell(&[
        "bench",
        "quality",
        "--json",
        "--grasps",
        "12",
        "--repeats",
        "1",
    ]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert!(v["grasps_per_s"].as_f64().unwrap() > 0.0);
    assert!(v["grasps_per_s_one_thread"].as_f64().unwrap() > 0.0);
    assert!(v["grasp_cpu_us_one_thread"].as_f64().unwrap() > 0.0);
    assert!(v["grasps_per_s_cpu_bound"].as_f64().unwrap() > 0.0);
    assert_eq!(v["goal_per_s"], 1000.0);
    assert_eq!(v["grasps"], 12);
}
