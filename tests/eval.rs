//! `cell eval loo` and `cell eval cross` on small inputs (2-3 models, one task,
//! complete views): the tallies add up, the held-out model never registers against
//! itself, epsilons are those of simulated grasps, the chart is written; and bad
//! requests are one clear error with a non-zero exit.

use crate::common::{cell, config_path, root};
use clap::Parser;
use graspcell::category::CategoryDb;
use graspcell::cli::{run, Cli};
use graspcell::config::CellConfig;
use graspcell::eval::experiment::Setup;
use graspcell::eval::{leave_one_out, CategoryRegistrar, PlacementRegion, ViewKind};
use graspcell::fsio::TempDir;
use graspcell::plan::{Kernel, PlanOptions};
use graspcell::robot::hand::HandModel;
use graspcell::sim::camera::DepthCamera;
use graspcell::sim::scene::TableBox;
use serde_json::Value;
use std::path::Path;

/// The error of running `args` in process, with its causes.
fn error_of(args: &[&str]) -> String {
    let config = config_path();
    let mut argv = vec!["cell", "--config", &config];
    argv.extend_from_slice(args);
    format!("{:#}", run(Cli::try_parse_from(argv).unwrap()).unwrap_err())
}

fn f(v: &Value) -> f64 {
    v.as_f64().unwrap_or_else(|| panic!("not a number: {v}"))
}

/// Every tally row: counts add up, percentages match them, means lie in [0, 1).
fn check_rows(rows: &[Value], runs_per_row: u64) {
    for row in rows {
        let n = row["runs"].as_u64().unwrap();
        assert_eq!(n, runs_per_row, "{row}");
        let (b, e, w) = (
            row["better"].as_u64().unwrap(),
            row["equal"].as_u64().unwrap(),
            row["worse"].as_u64().unwrap(),
        );
        assert_eq!(b + e + w, n, "{row}");
        let pct = |k: u64| 100.0 * k as f64 / n as f64;
        assert!((f(&row["better_pct"]) - pct(b)).abs() < 1e-9, "{row}");
        assert!((f(&row["worse_pct"]) - pct(w)).abs() < 1e-9, "{row}");
        for key in ["mean_epsilon", "mean_epsilon_single"] {
            let m = f(&row[key]);
            assert!((0.0..1.0).contains(&m), "{key} {m}: {row}");
        }
    }
}

/// One run: epsilons are the simulated grasps', the verdict follows them.
fn check_run(run: &Value, tolerance: f64) {
    for (key, grasp) in [("epsilon", "ours"), ("epsilon_single", "single")] {
        let eps = f(&run[key]);
        assert!((0.0..1.0).contains(&eps), "{key} {eps}: {run}");
        assert_eq!(eps, f(&run[grasp]["epsilon"]), "{run}");
        // Force closure exactly when epsilon is positive; a force-closure grasp
        // touches with at least two contacts.
        let fc = run[grasp]["force_closure"].as_bool().unwrap();
        assert_eq!(fc, eps > 0.0, "{run}");
        if fc {
            assert!(run[grasp]["contacts"].as_u64().unwrap() >= 2, "{run}");
        }
    }
    let d = f(&run["epsilon"]) - f(&run["epsilon_single"]);
    let expected = if d.abs() < tolerance || d == 0.0 {
        "equal"
    } else if d > 0.0 {
        "better"
    } else {
        "worse"
    };
    assert_eq!(run["verdict"], expected, "{run}");
}

#[test]
fn loo_on_three_mugs_tallies_simulated_grasps_and_never_registers_the_target() {
    let dir = TempDir::new("eval-loo").unwrap();
    let png = dir.join("chart.png");
    let models = ["mug_000", "mug_001", "mug_003"];
    let (ok, stdout, stderr) = cell(&[
        "eval",
        "loo",
        "--category",
        "mug",
        "--models",
        &models.join(","),
        "--tasks",
        "top",
        "--kernel",
        "laplace,gaussian",
        "--seed",
        "7",
        "--png",
        png.to_str().unwrap(),
        "--json",
    ]);
    assert!(ok, "{stderr}");
    let report: Value = serde_json::from_str(&stdout).unwrap();
    assert_eq!(report["seed"], 7);
    assert_eq!(report["category"], "mug");
    assert_eq!(report["view"], "complete");
    assert_eq!(report["tasks"], serde_json::json!(["top"]));
    assert_eq!(report["reachability"], false);
    let tolerance = f(&report["equal_tolerance"]);
    let targets = report["targets"].as_array().unwrap();
    let names: Vec<&str> = targets
        .iter()
        .map(|t| t["target"].as_str().unwrap())
        .collect();
    assert_eq!(names, models);
    // Complete mugs register; every target runs both kernels.
    assert_eq!(report["skipped"], 0, "{stdout}");
    assert_eq!(report["runs"], 6);
    let rows = report["rows"].as_array().unwrap();
    assert_eq!(rows.len(), 2, "one task: no `all` rows");
    assert_eq!(rows[0]["kernel"], "laplace");
    assert_eq!(rows[1]["kernel"], "gaussian");
    check_rows(rows, 3);
    let cell_config = CellConfig::load(Path::new(&config_path())).unwrap();
    for t in targets {
        let target = t["target"].as_str().unwrap();
        assert_eq!(t["view_points"], 3000);
        // On the table, inside the placement region in front of the robot.
        let xyz = &t["base_from_object"]["xyz"];
        let (x, y) = (f(&xyz[0]), f(&xyz[1]));
        assert!(
            (x - 0.6).abs() <= 0.1 + 1e-9 && y.abs() <= 0.15 + 1e-9,
            "{t}"
        );
        // Leave-one-out: the others are the database, never the target itself.
        let fits = t["fits"].as_array().unwrap();
        assert_eq!(fits.len(), 2, "{target}: {fits:?}");
        for fit in fits {
            assert_ne!(fit["model"], target);
            assert!(models.contains(&fit["model"].as_str().unwrap()));
            // Another mug fits a complete cloud to within ~3 cm rms (mugs differ by
            // up to ~1.5 cm in radius and height; a gross misregistration is worse).
            let eps = f(&fit["eps_m2"]);
            assert!(eps > 0.0 && eps < 1e-3, "{target}: {fit}");
        }
        let runs = t["runs"].as_array().unwrap();
        assert_eq!(runs.len(), 2);
        for r in runs {
            assert_eq!(r["target"], target);
            assert_ne!(r["best_single_model"], target);
            check_run(r, tolerance);
            // The planned palm stays above the table (z_min = table height) and
            // near the object (a top grasp over the mug).
            let p = &r["pose"]["xyz"];
            assert!(f(&p[2]) >= cell_config.table.height_m - 1e-9, "{r}");
            let dxy = (f(&p[0]) - x).hypot(f(&p[1]) - y);
            assert!(dxy < 0.1, "palm {dxy} m from the mug: {r}");
        }
        // Best single does not depend on the kernel.
        assert_eq!(runs[0]["epsilon_single"], runs[1]["epsilon_single"]);
    }
    // The chart is a PNG.
    let bytes = std::fs::read(&png).unwrap();
    assert_eq!(&bytes[..8], b"\x89PNG\r\n\x1a\n");

    // Human text: the seed and the table.
    let (ok, stdout, stderr) = cell(&[
        "eval",
        "loo",
        "--category",
        "mug",
        "--models",
        "mug_000,mug_001",
        "--tasks",
        "side",
        "--kernel",
        "gaussian-r",
        "--seed",
        "7",
    ]);
    assert!(ok, "{stderr}");
    assert!(stdout.contains("seed 7"), "{stdout}");
    let line = stdout
        .lines()
        .find(|l| l.starts_with("side") && l.contains("gaussian-r"))
        .unwrap_or_else(|| panic!("{stdout}"));
    assert!(line.contains('%'), "{line}");
}

/// The same seed gives the same experiment; the library path the CLI takes.
#[test]
fn loo_is_seeded() {
    let config = CellConfig::load(Path::new(&config_path())).unwrap();
    let hand = HandModel::load(&config).unwrap();
    let db = CategoryDb::load(&root().join("db/bottle")).unwrap();
    let db = graspcell::eval::subset(&db, &["bottle_001".into(), "bottle_006".into()]).unwrap();
    let registrar = CategoryRegistrar::new(&db, None).unwrap();
    let setup = |seed| Setup {
        hand: &hand,
        camera: DepthCamera::from_config(&config.camera, config.base_from_camera()),
        table: TableBox::from(&config.table),
        region: PlacementRegion::around([0.6, 0.0], config.table.height_m),
        view: ViewKind::Complete,
        complete_points: 1500,
        plan: PlanOptions::new(Kernel::LAPLACE_DEFAULT, &config),
        reach: None,
        equal_tolerance: 0.01,
        seed,
        placements: 1,
        paper: false,
    };
    let kernels = [Kernel::LAPLACE_DEFAULT];
    let a = leave_one_out(&setup(3), &db, &[], &kernels, &registrar, None).unwrap();
    let b = leave_one_out(&setup(3), &db, &[], &kernels, &registrar, None).unwrap();
    let c = leave_one_out(&setup(4), &db, &[], &kernels, &registrar, None).unwrap();
    let json = |r| serde_json::to_value(r).unwrap();
    assert_eq!(json(&a), json(&b));
    assert_ne!(
        json(&a)["targets"][0]["base_from_object"],
        json(&c)["targets"][0]["base_from_object"]
    );
    assert_eq!(a.tasks, ["side"]);
    assert_eq!(a.runs + a.skipped, 2);
}

#[test]
fn cross_hammer_to_knife_fills_table_1() {
    let (ok, stdout, stderr) = cell(&[
        "eval", "cross", "--train", "hammer", "--test", "knife", "--kernel", "laplace", "--json",
    ]);
    assert!(ok, "{stderr}");
    let report: Value = serde_json::from_str(&stdout).unwrap();
    assert_eq!(report["seed"], 1);
    assert_eq!(report["tasks"], serde_json::json!(["use"]));
    let tolerance = f(&report["equal_tolerance"]);
    let table = report["table"].as_array().unwrap();
    let skipped = report["skipped"].as_u64().unwrap() as usize;
    assert_eq!(table.len() + skipped, 2, "{stdout}");
    let hammers = ["hammer_000", "hammer_001", "hammer_002", "hammer_003"];
    for row in table {
        assert!(row["target"].as_str().unwrap().starts_with("knife_"));
        assert_eq!(row["task"], "use");
        assert!(hammers.contains(&row["best_single_model"].as_str().unwrap()));
        let eps = row["epsilon"].as_array().unwrap();
        assert_eq!(eps.len(), 1);
        assert_eq!(eps[0][0], "laplace");
        assert!((0.0..1.0).contains(&f(&eps[0][1])));
        assert!((0.0..1.0).contains(&f(&row["epsilon_single"])));
    }
    for t in report["targets"].as_array().unwrap() {
        for fit in t["fits"].as_array().unwrap() {
            assert!(hammers.contains(&fit["model"].as_str().unwrap()));
        }
        // A target no hammer registered to is skipped with every hammer's reason.
        for skip in t["skipped"].as_array().unwrap() {
            let reason = skip["reason"].as_str().unwrap();
            if reason.starts_with("registration: no model registered") {
                assert_eq!(t["unregistered"].as_array().unwrap().len(), 4, "{t}");
                for h in hammers {
                    assert!(reason.contains(&format!("{h} (")), "{reason}");
                }
            }
        }
        for r in t["runs"].as_array().unwrap() {
            check_run(r, tolerance);
        }
    }
    check_rows(report["rows"].as_array().unwrap(), table.len() as u64);
}

#[test]
fn bad_requests_are_one_clear_error() {
    // Unknown category: names it and the categories there are; non-zero exit.
    let (ok, stdout, stderr) = cell(&["eval", "loo", "--category", "teapot"]);
    assert!(!ok);
    assert!(stdout.is_empty(), "{stdout}");
    assert_eq!(stderr.lines().count(), 1, "{stderr}");
    assert!(
        stderr.contains("\"teapot\"") && stderr.contains("bottle, hammer, knife, mug"),
        "{stderr}"
    );
    let e = error_of(&["eval", "cross", "--train", "hammer", "--test", "spoon"]);
    assert!(e.contains("\"spoon\""), "{e}");

    // A task without grasps names the task and the tasks there are.
    let e = error_of(&["eval", "loo", "--category", "mug", "--tasks", "pour"]);
    assert!(
        e.contains("\"pour\"") && e.contains("handle, side, top"),
        "{e}"
    );
    let e = error_of(&[
        "eval", "cross", "--train", "hammer", "--test", "knife", "--tasks", "side",
    ]);
    assert!(e.contains("\"side\"") && e.contains("use"), "{e}");

    // Unknown model, too few models, a bad option.
    let e = error_of(&["eval", "loo", "--category", "mug", "--models", "mug_009"]);
    assert!(e.contains("mug_009") && e.contains("mug_000"), "{e}");
    let e = error_of(&["eval", "loo", "--category", "mug", "--models", "mug_002"]);
    assert!(e.contains("at least 2 models") && e.contains("1"), "{e}");
    let e = error_of(&["eval", "loo", "--category", "mug", "--equal-tolerance=-1"]);
    assert!(e.contains("equal tolerance") && e.contains("-1"), "{e}");
    let e = Cli::try_parse_from([
        "cell",
        "eval",
        "loo",
        "--category",
        "mug",
        "--kernel",
        "cauchy",
    ])
    .unwrap_err()
    .to_string();
    assert!(e.contains("cauchy"), "{e}");

    // An empty database.
    let dir = TempDir::new("eval-empty").unwrap();
    let mug = dir.join("mug");
    std::fs::create_dir_all(&mug).unwrap();
    let mut file: Value = serde_json::from_str(
        &std::fs::read_to_string(root().join("db/mug/category.json")).unwrap(),
    )
    .unwrap();
    file["models"] = Value::Array(Vec::new());
    file["grasps"] = Value::Array(Vec::new());
    std::fs::write(mug.join("category.json"), file.to_string()).unwrap();
    let e = error_of(&[
        "eval",
        "loo",
        "--category",
        "mug",
        "--db-dir",
        dir.to_str().unwrap(),
    ]);
    assert!(e.contains("no models") && e.contains("mug"), "{e}");
}

#[test]
fn objects_dirs_with_a_bad_manifest_mesh_or_category_are_one_error_naming_the_file() {
    let dir = TempDir::new("eval-objects").unwrap();
    let manifest = dir.join("objects.toml");
    let mesh = root().join("db/mug/models/mug_000.ply");
    std::fs::copy(&mesh, dir.join("mine.ply")).unwrap();
    let dir_arg = dir.to_string_lossy().into_owned();
    let cases = [
        (
            "[[object]\nfile = \"mine.ply\"\n",
            "malformed",
            manifest.clone(),
        ),
        (
            "[[object]]\nfile = \"gone.ply\"\ncategory = \"mug\"\n",
            "does not exist",
            dir.join("gone.ply"),
        ),
        (
            "[[object]]\nfile = \"mine.ply\"\ncategory = \"teapot\"\n",
            "\"teapot\"",
            manifest.clone(),
        ),
    ];
    for (text, what, file) in cases {
        std::fs::write(&manifest, text).unwrap();
        for command in [
            vec!["eval", "novel", "--objects", &dir_arg],
            vec![
                "campaign",
                "--objects",
                &dir_arg,
                "--log",
                "/nonexistent/x.sqlite",
            ],
            vec!["demo", "--objects", &dir_arg],
        ] {
            let e = error_of(&command);
            assert!(
                e.contains(what) && e.contains(&file.display().to_string()),
                "{command:?}: {e}"
            );
            assert_eq!(e.lines().count(), 1, "{e}");
        }
    }
    // The old count of `cell campaign --objects N` is now --instances: say so.
    let e = error_of(&["campaign", "--objects", "6"]);
    assert!(e.contains("--instances"), "{e}");
}

/// `cell eval novel --json` on mugs for the `top` task: its report.
fn novel_json(instances: &str, placements: &str, methods: &str) -> Value {
    let (ok, stdout, stderr) = cell(&[
        "eval",
        "novel",
        "--categories",
        "mug",
        "--instances",
        instances,
        "--placements",
        placements,
        "--tasks",
        "top",
        "--methods",
        methods,
        "--json",
    ]);
    assert!(ok, "{stderr}");
    serde_json::from_str(&stdout).unwrap()
}

#[test]
fn novel_runs_the_chain_and_every_trial_is_graded() {
    let report = novel_json("1", "1", "best-single,laplace");
    let trials = report["trials"].as_array().unwrap();
    assert_eq!(
        trials.len(),
        2,
        "1 object x 1 placement x 1 task x 2 methods"
    );
    for t in trials {
        let grade = t["grade"].as_str().unwrap();
        assert!(["success", "partial", "failure"].contains(&grade), "{t}");
        assert_eq!(t["task"], "top");
        // A held-apart mug, the lab's default errors.
        assert_eq!(t["origin"], "held-apart");
    }
    assert!((f(&report["lab"]["hand_eye_translation_m"]) - 0.003).abs() < 1e-12);
    let rows = report["rows"].as_array().unwrap();
    assert_eq!(rows.len(), 2, "one task: no `all` rows");
    for row in rows {
        let n = |k: &str| row[k].as_u64().unwrap();
        assert_eq!(n("trials"), 1);
        assert_eq!(n("success") + n("partial") + n("failure"), 1);
    }
}

/// An object's placements and grades depend on it and the seed only: a run over
/// fewer instances repeats the larger run's trials of the objects it keeps.
#[test]
fn novel_trials_of_an_object_do_not_depend_on_the_other_objects() {
    let run = |instances: &str| {
        novel_json(instances, "2", "best-single")["trials"]
            .as_array()
            .unwrap()
            .iter()
            .filter(|t| t["object"] == "squat-mug-1-0")
            .map(|t| {
                (
                    t["placement"].clone(),
                    t["base_from_object"].clone(),
                    t["grade"].clone(),
                    t["palm"].clone(),
                )
            })
            .collect::<Vec<_>>()
    };
    let alone = run("1");
    assert_eq!(alone.len(), 2, "{alone:?}");
    assert_eq!(alone, run("2"));
}
