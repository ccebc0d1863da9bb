//! The category database: every shipped database loads and its grasps are force
//! closure on the stored meshes (re-simulated here); training writes a database
//! that loads, and rejects bad teach files by the grasp's name, writing nothing.

use crate::grasp::{cylinder, shipped_hand, side_pose};
use graspcell::category::teach::{TeachFile, TeachGrasp, TeachModel};
use graspcell::category::train::{train, TrainOptions};
use graspcell::category::{tasks_of, CategoryDb, CategoryError, DATABASE_FILE};
use graspcell::fsio::TempDir;
use graspcell::geometry::{Pose, PoseJson};
use graspcell::mesh::obj::write_obj;
use graspcell::mesh::procedural::Category;
use graspcell::mesh::topology::bounding_box;
use graspcell::quality::autograsp::{evaluate_grasp, GraspObject};
use graspcell::quality::stability::StabilityOptions;
use std::path::{Path, PathBuf};

fn shipped(category: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("db")
        .join(category)
}

#[test]
fn every_shipped_database_loads_and_its_grasps_are_force_closure() {
    let hand = shipped_hand();
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("db");
    let mut found = Vec::new();
    for entry in std::fs::read_dir(&root).unwrap() {
        let dir = entry.unwrap().path();
        if !dir.is_dir() {
            continue;
        }
        let db = CategoryDb::load(&dir).unwrap_or_else(|e| panic!("{}: {e}", dir.display()));
        assert!(
            dir.join("grasps.toml").is_file(),
            "{}: no teach file",
            dir.display()
        );
        let params = db.file.metric.params();
        let options = db.file.simulation.into();
        for g in &db.file.grasps {
            assert!(g.q > 0.0, "{}: q = {}", g.name, g.q);
            let m = db.model_index(&g.model).unwrap();
            let object = GraspObject::new(&db.meshes[m], Path::new(&g.model))
                .unwrap()
                .with_table(db.file.table_height_m);
            let pose = g.pose.to_pose(&g.name).unwrap();
            let e = evaluate_grasp(
                &hand,
                &object,
                &pose,
                &g.preshape(),
                &options,
                &params,
                false,
            )
            .unwrap();
            assert!(
                e.force_closure && (e.epsilon - g.q).abs() <= 1e-6 * g.q.max(1.0),
                "{}: stored q {} but simulated {e:?}",
                g.name,
                g.q
            );
            for d in 0..6 {
                assert!((g.sigma[d] - g.delta[d] / 3.0).abs() < 1e-12, "{}", g.name);
            }
        }
        for m in 0..db.file.models.len() {
            let cloud = db.model_cloud(m).unwrap();
            assert_eq!(cloud.len(), db.file.models[m].cloud.points);
            // The same cloud every time.
            assert_eq!(cloud, db.model_cloud(m).unwrap());
        }
        found.push(db);
    }
    let by = |c: Category| found.iter().find(|db| db.file.category == c).unwrap();
    let mugs = by(Category::Mug);
    assert!(mugs.file.models.len() >= 7);
    for task in tasks_of(Category::Mug) {
        assert!(mugs.grasps_for(task).count() >= 6, "mug {task}");
    }
    // A mug without a handle: its mesh is as wide along +x (the handle side) as
    // along the other directions, and it has no handle grasp.
    let handleless: Vec<&str> = mugs
        .file
        .models
        .iter()
        .zip(&mugs.meshes)
        .filter(|(_, mesh)| {
            let (lo, hi) = bounding_box(mesh).unwrap();
            (hi.x + lo.x).abs() < 1e-3 && (hi.x - hi.y).abs() < 1e-3
        })
        .map(|(m, _)| m.name.as_str())
        .collect();
    assert!(!handleless.is_empty());
    for name in &handleless {
        let tasks: Vec<&str> = mugs
            .file
            .grasps
            .iter()
            .filter(|g| g.model == *name)
            .map(|g| g.task.as_str())
            .collect();
        assert!(
            !tasks.contains(&"handle") && tasks.contains(&"top"),
            "{name}: {tasks:?}"
        );
    }
    assert!(by(Category::Bottle).file.models.len() >= 11);
    assert!(by(Category::Bottle).grasps_for("side").count() >= 11);
    assert!(by(Category::Hammer).grasps_for("use").count() >= 4);
    assert!(by(Category::Knife).file.models.len() >= 2);
}

/// A models directory with one cylinder and a teach file naming `grasps`.
fn fixture(name: &str, grasps: Vec<TeachGrasp>) -> (TempDir, TeachFile) {
    let dir = TempDir::new(&format!("category-{name}")).unwrap();
    write_obj(&dir.join("can.obj"), &cylinder(0.035, 0.25, 72)).unwrap();
    let teach = TeachFile {
        category: Some(Category::Bottle),
        table_height_m: None,
        models: vec![TeachModel {
            mesh: "can.obj".into(),
            name: None,
            grasps,
        }],
    };
    (dir, teach)
}

fn grasp(name: &str, task: &str, pose: &Pose) -> TeachGrasp {
    TeachGrasp {
        name: name.into(),
        task: task.into(),
        pose: PoseJson::from(pose),
        spread_rad: 0.0,
        preshape_rad: graspcell::robot::PreshapeRad::OPEN,
        max_overtravel_m: None,
    }
}

fn quick() -> TrainOptions {
    TrainOptions {
        stability: StabilityOptions {
            step_m: 0.005,
            step_rad: 0.1,
            cap_m: 0.01,
            cap_rad: 0.2,
            ..StabilityOptions::default()
        },
        cloud_points: 300,
        ..TrainOptions::default()
    }
}

#[test]
fn training_writes_a_database_that_loads() {
    let hand = shipped_hand();
    let good = side_pose(0.035, 1e-4);
    let (dir, teach) = fixture("train-ok", vec![grasp("can/side", "side", &good)]);
    let out = dir.join("db");
    let options = TrainOptions {
        write_clouds: true,
        ..quick()
    };
    let db = train(&hand, Category::Bottle, &teach, &dir, &out, &options, None).unwrap();
    let back = CategoryDb::load(&out).unwrap();
    assert_eq!(back.file, db.file);
    let g = &back.file.grasps[0];
    assert_eq!(
        (g.name.as_str(), g.model.as_str(), g.task.as_str()),
        ("can/side", "can", "side")
    );
    assert!(g.q > 0.0 && g.contacts >= 4);
    // Along the cylinder's axis (z) the grasp is unchanged: the cap both ways.
    assert_eq!(g.delta[2], 0.01);
    assert_eq!(back.file.models[0].mesh, Path::new("models/can.ply"));
    assert_eq!(back.model_cloud(0).unwrap().len(), 300);
    assert!(out.join("clouds/can.ply").is_file());
    // The written file is the human-readable JSON described in the module docs.
    let text = std::fs::read_to_string(out.join(DATABASE_FILE)).unwrap();
    assert!(text.contains("\"task\": \"side\"") && text.contains("\"sigma\""));
}

#[test]
fn training_rejects_a_grasp_without_force_closure_by_name_and_writes_nothing() {
    let hand = shipped_hand();
    let good = side_pose(0.035, 1e-4);
    // 10 mm off the surface: the fingers close, but the palm does not press.
    let off = Pose::translation(-0.01, 0.0, 0.0) * good;
    let (dir, teach) = fixture(
        "train-fc",
        vec![
            grasp("can/good", "side", &good),
            grasp("can/loose", "side", &off),
        ],
    );
    let out = dir.join("db");
    let err = train(&hand, Category::Bottle, &teach, &dir, &out, &quick(), None).unwrap_err();
    match &err {
        CategoryError::NotForceClosure { grasps } => assert_eq!(grasps, &["can/loose"]),
        other => panic!("{other}"),
    }
    assert!(err.to_string().contains("can/loose"));
    assert!(!out.join(DATABASE_FILE).exists());

    // The same through the CLI: a non-zero exit and the name on stderr.
    let grasps = dir.join("grasps.toml");
    std::fs::write(&grasps, teach.to_toml("test")).unwrap();
    let output = std::process::Command::new(env!("CARGO_BIN_EXE_cell"))
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .args(["train", "--category", "bottle", "--models"])
        .arg(&dir)
        .arg("--grasps")
        .arg(&grasps)
        .arg("--out")
        .arg(&out)
        .output()
        .unwrap();
    assert!(!output.status.success());
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert!(
        stderr.contains("can/loose") && !stderr.contains("can/good"),
        "{stderr}"
    );
    assert!(!out.join(DATABASE_FILE).exists());
}

#[test]
fn bad_teach_files_are_errors_naming_the_grasp() {
    let hand = shipped_hand();
    let good = side_pose(0.035, 1e-4);
    let check = |name: &str, teach: &TeachFile, dir: &Path, want: &[&str]| {
        let out = dir.join("db");
        let err = train(&hand, Category::Bottle, teach, dir, &out, &quick(), None)
            .unwrap_err()
            .to_string();
        for w in want {
            assert!(err.contains(w), "{name}: {err}");
        }
        assert!(!out.join(DATABASE_FILE).exists(), "{name}");
    };
    // The palm through the surface.
    let through = Pose::translation(0.01, 0.0, 0.0) * good;
    let (dir, teach) = fixture("bad", vec![grasp("can/through", "side", &through)]);
    check(
        "through",
        &teach,
        &dir,
        &["can/through", "intersects the object"],
    );
    // A task the category does not have.
    let t = fixture_like(&teach, vec![grasp("can/pour", "pour", &good)]);
    check("task", &t, &dir, &["can/pour", "pour", "side"]);
    // A missing model file.
    let mut t = fixture_like(&teach, vec![grasp("gone/side", "side", &good)]);
    t.models[0].mesh = "gone.obj".into();
    check("missing", &t, &dir, &["gone/side", "gone.obj"]);
    // The same name twice.
    let t = fixture_like(
        &teach,
        vec![
            grasp("can/side", "side", &good),
            grasp("can/side", "side", &good),
        ],
    );
    check("duplicate", &t, &dir, &["can/side"]);
    // Another category's file.
    let mut t = teach.clone();
    t.category = Some(Category::Mug);
    check("category", &t, &dir, &["mug", "bottle"]);
    // A file that does not parse names the file and the field.
    let path = dir.join("typo.toml");
    std::fs::write(&path, "[[model]]\nmesh = \"can.obj\"\n[[model.grasp]]\nname = \"a\"\ntask = \"side\"\npose = { xyz = [0, 0, 0] }\nspred_rad = 1.0\n").unwrap();
    let err = TeachFile::load(&path).unwrap_err().to_string();
    assert!(
        err.contains("typo.toml") && err.contains("spred_rad"),
        "{err}"
    );
}

fn fixture_like(teach: &TeachFile, grasps: Vec<TeachGrasp>) -> TeachFile {
    let mut t = teach.clone();
    t.models[0].grasps = grasps;
    t
}

#[test]
fn a_damaged_database_is_an_error_naming_the_problem() {
    let dir = TempDir::new("category-damaged").unwrap();
    let src = shipped("hammer");
    std::fs::create_dir_all(dir.join("models")).unwrap();
    for entry in std::fs::read_dir(src.join("models")).unwrap() {
        let p = entry.unwrap().path();
        std::fs::copy(&p, dir.join("models").join(p.file_name().unwrap())).unwrap();
    }
    let text = std::fs::read_to_string(src.join(DATABASE_FILE)).unwrap();
    let load_with = |text: &str| {
        std::fs::write(dir.join(DATABASE_FILE), text).unwrap();
        CategoryDb::load(&dir).map(|_| ()).unwrap_err().to_string()
    };
    let mut v: serde_json::Value = serde_json::from_str(&text).unwrap();
    v["grasps"][0]["q"] = serde_json::json!(0.0);
    let name = v["grasps"][0]["name"].as_str().unwrap().to_string();
    let err = load_with(&v.to_string());
    assert!(err.contains(&name) && err.contains("q"), "{err}");
    let mut v: serde_json::Value = serde_json::from_str(&text).unwrap();
    v["grasps"][0]["task"] = serde_json::json!("hammering");
    assert!(load_with(&v.to_string()).contains("hammering"));
    let mut v: serde_json::Value = serde_json::from_str(&text).unwrap();
    v["format"] = serde_json::json!(99);
    assert!(load_with(&v.to_string()).contains("format 99"));
    std::fs::remove_file(dir.join("models/hammer_000.ply")).unwrap();
    let err = load_with(&text);
    assert!(err.contains("hammer_000"), "{err}");
}
