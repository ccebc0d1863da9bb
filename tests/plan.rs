//! `cell plan` end to end over fits and grasps files, and the errors of bad input:
//! NaN in the fits, a task without grasps, an empty database, unknown models.

use crate::common::{cell as cell_bin, config_path};
use clap::Parser;
use graspcell::cli::{run, Cli};
use graspcell::fsio::TempDir;
use graspcell::geometry::pose_from_params;
use graspcell::plan::input::{read_fits, read_grasps, FitJson, FitsFile, GraspJson, GraspsFile};
use graspcell::plan::synthetic::{synthetic_problem, SyntheticSpec};
use graspcell::plan::{plan, ExampleGrasp, Kernel, ModelFit, PlanError, PlanOptions};
use std::path::{Path, PathBuf};

fn problem() -> (Vec<ModelFit>, Vec<ExampleGrasp>) {
    synthetic_problem(&SyntheticSpec {
        models: 3,
        grasps_per_model: 2,
        object_xy_m: [0.6, 0.0],
        seed: 5,
    })
}

/// Writes the fits and grasps files; returns their paths.
fn write_files(dir: &Path, fits: &[ModelFit], grasps: &[ExampleGrasp]) -> (PathBuf, PathBuf) {
    let fits_file = FitsFile {
        fits: fits.iter().map(FitJson::from_fit).collect(),
    };
    let grasps_file = GraspsFile {
        grasps: grasps
            .iter()
            .map(|g| GraspJson::from_grasp(g, fits))
            .collect(),
    };
    let (f, g) = (dir.join("fits.json"), dir.join("grasps.json"));
    std::fs::write(&f, serde_json::to_string_pretty(&fits_file).unwrap()).unwrap();
    std::fs::write(&g, serde_json::to_string_pretty(&grasps_file).unwrap()).unwrap();
    (f, g)
}

fn cell_plan(fits: &Path, grasps: &Path, task: &str, extra: &[&str]) -> anyhow::Result<()> {
    let config = config_path();
    let mut argv = vec![
        "cell",
        "--config",
        &config,
        "plan",
        "--fits",
        fits.to_str().unwrap(),
        "--grasps",
        grasps.to_str().unwrap(),
        "--task",
        task,
    ];
    argv.extend_from_slice(extra);
    run(Cli::try_parse_from(argv)?).map(|_| ())
}

#[test]
fn files_round_trip_and_plan_the_same() {
    let dir = TempDir::new("plan-round-trip").unwrap();
    let (fits, grasps) = problem();
    let (f, g) = write_files(&dir, &fits, &grasps);
    let fits_back = read_fits(&f).unwrap();
    let grasps_back = read_grasps(&g, &fits_back).unwrap();
    assert_eq!(fits_back.len(), fits.len());
    assert_eq!(grasps_back.len(), grasps.len());
    // serde_json's default float parsing may differ in the last bit.
    let close = |a: f64, b: f64| (a - b).abs() <= 1e-15 * a.abs().max(b.abs());
    for (a, b) in fits.iter().zip(&fits_back) {
        assert_eq!(a.name, b.name);
        assert!(close(a.eps_m2, b.eps_m2) && close(a.sigma_m2, b.sigma_m2));
        let (dp, dr) = graspcell::geometry::pose_error(&a.base_from_model, &b.base_from_model);
        assert!(dp < 1e-12 && dr < 1e-9);
    }
    for (a, b) in grasps.iter().zip(&grasps_back) {
        assert_eq!((a.model, &a.task), (b.model, &b.task));
        assert!(close(a.q, b.q) && (0..6).all(|d| close(a.sigma[d], b.sigma[d])));
        let (dp, dr) = graspcell::geometry::pose_error(
            &pose_from_params(&a.model_from_palm),
            &pose_from_params(&b.model_from_palm),
        );
        assert!(dp < 1e-12 && dr < 1e-9);
    }
    // The plan from the files is the plan from the values (the representation of the
    // angles may differ; the objective canonicalises them).
    let options = PlanOptions {
        parallel: false,
        ..PlanOptions::with_kernel(Kernel::LAPLACE_DEFAULT)
    };
    let a = plan(&fits, &grasps, "top", &options, None).unwrap();
    let b = plan(&fits_back, &grasps_back, "top", &options, None).unwrap();
    assert!((a.plan.grasp.log_objective - b.plan.grasp.log_objective).abs() < 1e-9);
}

#[test]
fn cli_plans_with_each_kernel_and_the_robot() {
    let dir = TempDir::new("plan-cli").unwrap();
    let (fits, grasps) = problem();
    let (f, g) = write_files(&dir, &fits, &grasps);
    cell_plan(&f, &g, "top", &["--json"]).unwrap();
    cell_plan(
        &f,
        &g,
        "top",
        &["--kernel", "gaussian-r", "--paper-scale", "50"],
    )
    .unwrap();
    cell_plan(
        &f,
        &g,
        "side",
        &["--kernel", "gaussian", "--no-reach", "--serial"],
    )
    .unwrap();
    let err = Cli::try_parse_from([
        "cell", "plan", "--fits", "a", "--grasps", "b", "--task", "top", "--kernel", "cauchy",
    ])
    .unwrap_err()
    .to_string();
    assert!(err.contains("cauchy"), "{err}");
}

#[test]
fn bad_input_gives_one_clear_error() {
    let dir = TempDir::new("plan-bad").unwrap();
    let (fits, grasps) = problem();
    let (f, g) = write_files(&dir, &fits, &grasps);
    let error = |fits: &Path, grasps: &Path, task: &str| {
        format!(
            "{:#}",
            cell_plan(fits, grasps, task, &["--no-reach"]).unwrap_err()
        )
    };

    // A task without grasps names the task and the tasks there are.
    let err = error(&f, &g, "handle");
    assert!(
        err.contains("\"handle\"") && err.contains("side, top"),
        "{err}"
    );

    // NaN in the fits (JSON writers print NaN as null).
    let text = std::fs::read_to_string(&f).unwrap();
    let eps = format!(
        "\"eps_m2\": {}",
        serde_json::to_string(&fits[1].eps_m2).unwrap()
    );
    assert!(text.contains(&eps), "{text}");
    let nan = dir.join("nan.json");
    std::fs::write(&nan, text.replacen(&eps, "\"eps_m2\": null", 1)).unwrap();
    let err = error(&nan, &g, "top");
    assert!(
        err.contains("nan.json") && err.contains("fit 1 (model_001) eps_m2") && err.contains("NaN"),
        "{err}"
    );

    // An empty database: no fits, or no grasps.
    let empty = dir.join("empty_fits.json");
    std::fs::write(&empty, r#"{"fits": []}"#).unwrap();
    let err = error(&empty, &g, "top");
    assert!(
        err.contains("empty_fits.json") && err.contains("no fits"),
        "{err}"
    );
    let empty = dir.join("empty_grasps.json");
    std::fs::write(&empty, r#"{"grasps": []}"#).unwrap();
    let err = error(&f, &empty, "top");
    assert!(
        err.contains("empty_grasps.json") && err.contains("no grasps"),
        "{err}"
    );

    // A grasp of a model without a fit; a malformed file; a missing file.
    let text = std::fs::read_to_string(&g).unwrap();
    let unknown = dir.join("unknown.json");
    std::fs::write(&unknown, text.replacen("model_002", "model_009", 1)).unwrap();
    let err = error(&f, &unknown, "top");
    assert!(
        err.contains("unknown.json") && err.contains("model_009"),
        "{err}"
    );
    let broken = dir.join("broken.json");
    std::fs::write(&broken, &text[..text.len() / 2]).unwrap();
    let err = error(&f, &broken, "top");
    assert!(err.contains("broken.json") && err.contains("line"), "{err}");
    let err = error(&dir.join("missing.json"), &g, "top");
    assert!(err.contains("missing.json"), "{err}");

    // A negative sigma, caught by the library too.
    let mut bad = grasps.clone();
    bad[0].sigma[2] = -0.01;
    let err = plan(
        &fits,
        &bad,
        "top",
        &PlanOptions::with_kernel(Kernel::Gaussian),
        None,
    )
    .unwrap_err();
    assert!(matches!(err, PlanError::BadValue { .. }));
    assert!(
        err.to_string().contains("grasp 0") && err.to_string().contains("sigma[2]"),
        "{err}"
    );
}

/// `cell plan --db`: the shipped mug database, every model registered at the same pose
/// (within comfortable reach, handle turned away from the far side), plans a reachable
/// handle grasp; an unknown task names the tasks.
#[test]
fn plans_from_the_shipped_category_database() {
    let dir = TempDir::new("plan-db").unwrap();
    let db_dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("db/mug");
    let db = graspcell::category::CategoryDb::load(&db_dir).unwrap();
    let fits: Vec<ModelFit> = db
        .file
        .models
        .iter()
        .enumerate()
        .map(|(i, m)| ModelFit {
            name: m.name.clone(),
            base_from_model: pose_from_params(&[0.5, 0.0, 0.0, 0.0, 0.0, 2.0]),
            eps_m2: 1e-5 * (1 + i) as f64,
            sigma_m2: 2e-6,
        })
        .collect();
    let fits_file = FitsFile {
        fits: fits.iter().map(FitJson::from_fit).collect(),
    };
    let f = dir.join("fits.json");
    std::fs::write(&f, serde_json::to_string(&fits_file).unwrap()).unwrap();
    let config = config_path();
    let argv = [
        "cell",
        "--config",
        &config,
        "plan",
        "--db",
        db_dir.to_str().unwrap(),
        "--fits",
        f.to_str().unwrap(),
        "--task",
        "handle",
    ];
    run(Cli::try_parse_from(argv).unwrap()).unwrap();
    // The library path the CLI takes, checked for content.
    let grasps = graspcell::plan::category::example_grasps(&db, &fits, "handle").unwrap();
    assert_eq!(grasps.len(), db.grasps_for("handle").count());
    let cell = graspcell::config::CellConfig::load(Path::new(&config)).unwrap();
    let robot = graspcell::robot::Robot::load(&cell).unwrap();
    let outcome = plan(
        &fits,
        &grasps,
        "handle",
        &PlanOptions::new(Kernel::LAPLACE_DEFAULT, &cell),
        Some(&robot),
    )
    .unwrap();
    assert!(
        outcome.plan.grasp.reachable,
        "{:?}",
        outcome.plan.grasp.unreachable
    );
    assert!(outcome.plan.grasp.objective > 0.0);
    let argv = [
        "cell",
        "--config",
        &config,
        "plan",
        "--db",
        db_dir.to_str().unwrap(),
        "--fits",
        f.to_str().unwrap(),
        "--task",
        "pour",
    ];
    let e = format!("{:#}", run(Cli::try_parse_from(argv).unwrap()).unwrap_err());
    assert!(e.contains("pour") && e.contains("handle"), "{e}");
}

/// A category database of `models` of the shipped mug database (and their grasps),
/// written under `dir`: a small database for registration in tests.
fn mug_subset_db(dir: &Path, models: &[&str]) -> PathBuf {
    let src = Path::new(env!("CARGO_MANIFEST_DIR")).join("db/mug");
    let out = dir.join("mug");
    std::fs::create_dir_all(out.join("models")).unwrap();
    let mut file: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(src.join("category.json")).unwrap()).unwrap();
    let keep = |v: &serde_json::Value, key: &str| models.contains(&v[key].as_str().unwrap());
    let kept: Vec<serde_json::Value> = file["models"]
        .as_array()
        .unwrap()
        .iter()
        .filter(|m| keep(m, "name"))
        .cloned()
        .collect();
    for m in &kept {
        let mesh = m["mesh"].as_str().unwrap();
        std::fs::copy(src.join(mesh), out.join(mesh)).unwrap();
    }
    file["models"] = serde_json::Value::Array(kept);
    let grasps: Vec<serde_json::Value> = file["grasps"]
        .as_array()
        .unwrap()
        .iter()
        .filter(|g| keep(g, "model"))
        .cloned()
        .collect();
    file["grasps"] = serde_json::Value::Array(grasps);
    std::fs::write(out.join("category.json"), file.to_string()).unwrap();
    out
}

fn pose_of(v: &serde_json::Value) -> graspcell::geometry::Pose {
    serde_json::from_value::<graspcell::geometry::PoseJson>(v.clone())
        .unwrap()
        .to_pose("test")
        .unwrap()
}

/// `cell plan --cloud`: a sim camera view of mug_003 registers every model of a
/// two-mug database; mug_003 fits best, so best single is its own top grasp at the
/// true pose. `cell register --json` output given as `--fits` plans the same grasp.
#[test]
fn plans_from_a_cloud_and_from_register_output() {
    use graspcell::cloud::io::{write_cloud, CloudEncoding};
    let dir = TempDir::new("plan-cloud").unwrap();
    let db_dir = mug_subset_db(&dir, &["mug_000", "mug_003"]);
    let db = graspcell::category::CategoryDb::load(&db_dir).unwrap();
    let cell = graspcell::config::CellConfig::load(Path::new(&config_path())).unwrap();
    // Handle towards the camera's side, in comfortable reach.
    let truth = pose_from_params(&[0.6, 0.03, cell.table.height_m, 0.0, 0.0, 0.87]);
    let index = db.model_index("mug_003").unwrap();
    let view = graspcell::eval::view::partial_view(
        "mug_003",
        &db.meshes[index],
        &truth,
        &graspcell::sim::camera::DepthCamera::from_config(&cell.camera, cell.base_from_camera()),
        graspcell::sim::scene::TableBox::from(&cell.table),
        5,
    )
    .unwrap();
    let cloud = dir.join("object.ply");
    write_cloud(&cloud, &view, CloudEncoding::Binary).unwrap();
    let (db_s, cloud_s) = (db_dir.to_str().unwrap(), cloud.to_str().unwrap());

    let (ok, stdout, stderr) = cell_bin(&[
        "plan", "--db", db_s, "--cloud", cloud_s, "--task", "top", "--seed", "2", "--json",
    ]);
    assert!(ok, "{stderr}");
    let report: serde_json::Value = serde_json::from_str(&stdout).unwrap();
    assert_eq!(report["seed"], 2);
    let regs = report["registrations"].as_array().unwrap();
    let names: Vec<&str> = regs.iter().map(|r| r["model"].as_str().unwrap()).collect();
    assert_eq!(names, ["mug_000", "mug_003"]);
    let own = &regs[1];
    assert_eq!(own["status"], "ok", "{own}");
    if regs[0]["status"] == "ok" {
        assert!(
            own["eps_m2"].as_f64().unwrap() < regs[0]["eps_m2"].as_f64().unwrap(),
            "{regs:?}"
        );
    }
    // Best single: mug_003's top grasp, at the registered pose (close to the truth).
    let best = &report["best_single"];
    assert_eq!(best["model_name"], "mug_003");
    let theta = db
        .grasps_for("top")
        .find(|g| g.model == "mug_003")
        .unwrap()
        .params();
    let expected = truth * pose_from_params(&theta);
    let (dp, dr) = graspcell::geometry::pose_error(&pose_of(&best["pose"]), &expected);
    assert!(dp < 0.01 && dr < 10f64.to_radians(), "{dp} m, {dr} rad");
    // The plan: reachable, above the table bound, near the mug.
    let planned = pose_of(&report["plan"]["pose"]);
    assert_eq!(report["plan"]["reachable"], true, "{}", report["plan"]);
    let z_min = cell.table.height_m + cell.table.palm_clearance_m;
    assert!(planned.translation.z >= z_min - 1e-9);
    let dxy = (planned.translation.vector - truth.translation.vector)
        .xy()
        .norm();
    assert!(dxy < 0.05, "planned palm {dxy} m off the mug's axis");

    // The same registration through `cell register --json` and `--fits`: the
    // register output, as written to `file` in the test directory, planned over.
    let (ok, reg_json, stderr) = cell_bin(&[
        "register", "--target", cloud_s, "--models", db_s, "--seed", "2", "--json",
    ]);
    assert!(ok, "{stderr}");
    let plan_fits = |file: &str, fits: &str| {
        let path = dir.join(file);
        std::fs::write(&path, fits).unwrap();
        cell_bin(&[
            "plan",
            "--db",
            db_s,
            "--fits",
            path.to_str().unwrap(),
            "--task",
            "top",
            "--json",
        ])
    };
    let (ok, stdout, stderr) = plan_fits("registered.json", &reg_json);
    assert!(ok, "{stderr}");
    let from_fits: serde_json::Value = serde_json::from_str(&stdout).unwrap();
    assert!(from_fits.get("registrations").is_none());
    let (dp, dr) = graspcell::geometry::pose_error(&pose_of(&from_fits["plan"]["pose"]), &planned);
    assert!(dp < 1e-3 && dr < 1e-3, "{dp} m, {dr} rad");
    assert_eq!(from_fits["best_single"]["model_name"], "mug_003");

    // NaN in register output: named by file, model and field.
    let mut lines: serde_json::Value = serde_json::from_str(&reg_json).unwrap();
    lines[1]["eps"] = serde_json::Value::Null;
    let (ok, _, stderr) = plan_fits("nan.json", &lines.to_string());
    assert!(!ok);
    assert!(
        stderr.contains("nan.json") && stderr.contains("(mug_003) eps") && stderr.contains("NaN"),
        "{stderr}"
    );
    // Every model failed: nothing to plan over, and the reasons are given.
    for l in lines.as_array_mut().unwrap() {
        l["status"] = "failed".into();
        l["reason"] = "too few inliers".into();
    }
    let (ok, _, stderr) = plan_fits("failed.json", &lines.to_string());
    assert!(!ok);
    assert!(
        stderr.contains("failed.json")
            && stderr.contains("no model registered")
            && stderr.contains("mug_000 (too few inliers)"),
        "{stderr}"
    );
}

#[test]
fn bad_cloud_requests_are_clear_errors() {
    let dir = TempDir::new("plan-cloud-bad").unwrap();
    let config = config_path();
    let plan_err = |args: &[&str]| {
        let mut argv = vec!["cell", "--config", &config, "plan"];
        argv.extend_from_slice(args);
        format!("{:#}", run(Cli::try_parse_from(argv).unwrap()).unwrap_err())
    };
    let db_dir = mug_subset_db(&dir, &["mug_000", "mug_001"]);
    let db_s = db_dir.to_str().unwrap();
    // --cloud needs the database whose models it registers.
    let e = plan_err(&["--cloud", "o.ply", "--grasps", "g.json", "--task", "top"]);
    assert!(e.contains("--cloud o.ply") && e.contains("--db"), "{e}");
    // A task without grasps fails before any registration (the cloud is not read).
    let missing = dir.join("missing.ply");
    let e = plan_err(&[
        "--db",
        db_s,
        "--cloud",
        missing.to_str().unwrap(),
        "--task",
        "pour",
    ]);
    assert!(
        e.contains("\"pour\"") && e.contains("handle, side, top"),
        "{e}"
    );
    // The cloud itself: missing, or without valid points.
    let e = plan_err(&[
        "--db",
        db_s,
        "--cloud",
        missing.to_str().unwrap(),
        "--task",
        "top",
    ]);
    assert!(e.contains("missing.ply"), "{e}");
    let nan = dir.join("nan.ply");
    graspcell::cloud::io::write_cloud(
        &nan,
        &graspcell::cloud::PointCloud::from_points(vec![
            nalgebra::Point3::new(f32::NAN, 0.0, 0.0);
            10
        ]),
        graspcell::cloud::io::CloudEncoding::Ascii,
    )
    .unwrap();
    let e = plan_err(&[
        "--db",
        db_s,
        "--cloud",
        nan.to_str().unwrap(),
        "--task",
        "top",
    ]);
    assert!(
        e.contains("nan.ply") && e.contains("no valid points"),
        "{e}"
    );
    // An empty database.
    let empty = mug_subset_db(&dir.join("empty"), &[]);
    let e = plan_err(&[
        "--db",
        empty.to_str().unwrap(),
        "--cloud",
        nan.to_str().unwrap(),
        "--task",
        "top",
    ]);
    assert!(e.contains("has no models"), "{e}");
}
