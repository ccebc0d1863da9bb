//! Perception: segmentation of a simulated snapshot and registration of every model
//! of the category onto it (issue 4).

use graspcell::category::CategoryDb;
use graspcell::cloud::segment::SegmentParams;
use graspcell::config::CellConfig;
use graspcell::fsio::TempDir;
use graspcell::geometry::{pose_error, pose_from_params, Pose};
use graspcell::plan::input::fits_input;
use graspcell::plan::ModelFit;
use graspcell::register::{perceive, ModelSet, RegisterParams, RegistrationStatus};
use graspcell::sim::camera::DepthCamera;
use graspcell::sim::scene::{Scene, TableBox};
use std::path::{Path, PathBuf};
use std::sync::OnceLock;

fn root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).to_path_buf()
}

fn config() -> CellConfig {
    CellConfig::load(&root().join("robot/cell.toml")).unwrap()
}

/// Runs a `OnceLock` initialiser on a rayon pool of its own. On the global pool it
/// could deadlock: the accuracy test's trials run on the global workers and wait
/// for the lock, so the initialiser's parallel work would wait for them in turn.
/// (The accuracy test also builds them before its trials start: a global worker
/// must never be the one that initialises.)
fn on_own_pool<T: Send>(init: impl FnOnce() -> T + Send) -> T {
    rayon::ThreadPoolBuilder::new()
        .num_threads(2)
        .build()
        .unwrap()
        .install(init)
}

fn mug_db() -> &'static CategoryDb {
    static DB: OnceLock<CategoryDb> = OnceLock::new();
    DB.get_or_init(|| on_own_pool(|| CategoryDb::load(&root().join("db/mug")).unwrap()))
}

fn mug_models() -> &'static ModelSet {
    static SET: OnceLock<ModelSet> = OnceLock::new();
    SET.get_or_init(|| {
        on_own_pool(|| ModelSet::from_category(mug_db(), &RegisterParams::default()).unwrap())
    })
}

/// Whether mug `index` of the database is a surface of revolution about its z axis
/// (a mug without a handle): its surface turned by 1 rad about z lies on itself,
/// fewer than 1 % of 2000 sample points farther than 2 mm from a dense sample of
/// the unturned surface (a handle, a tenth of the surface, misses by centimetres).
fn symmetric_about_z(index: usize) -> bool {
    use graspcell::cloud::kdtree::KdIndex;
    static SYMMETRIC: OnceLock<Vec<bool>> = OnceLock::new();
    SYMMETRIC.get_or_init(|| {
        on_own_pool(|| {
            let db = mug_db();
            (0..db.meshes.len())
                .map(|i| {
                    let dense = graspcell::cloud::sample::sample_surface(&db.meshes[i], 40_000, 5)
                        .unwrap()
                        .points;
                    let index = KdIndex::new(&dense);
                    let turn =
                        nalgebra::Rotation3::from_axis_angle(&nalgebra::Vector3::z_axis(), 1.0);
                    let far = graspcell::cloud::sample::sample_surface(&db.meshes[i], 2000, 6)
                        .unwrap()
                        .points
                        .iter()
                        .filter(|p| index.nearest(&(turn * *p)).unwrap().1.sqrt() > 0.002)
                        .count();
                    far < 20
                })
                .collect()
        })
    })[index]
}

/// The pose error (m, rad) of `estimate` against `truth` for mug `index`: for a
/// mug that is a surface of revolution the turn about its own axis is not
/// observable, so the error is the least over such turns of `estimate`.
fn mug_pose_error(index: usize, estimate: &Pose, truth: &Pose) -> (f64, f64) {
    if !symmetric_about_z(index) {
        return pose_error(estimate, truth);
    }
    let turned = |a: f64| {
        let turn = nalgebra::UnitQuaternion::from_axis_angle(&nalgebra::Vector3::z_axis(), a);
        pose_error(&(estimate * turn), truth)
    };
    // Coarse over the circle, then fine around the best.
    let coarse = (0..720)
        .map(|k| k as f64 * 0.5f64.to_radians())
        .min_by(|a, b| turned(*a).1.total_cmp(&turned(*b).1))
        .unwrap();
    (-100..=100)
        .map(|k| turned(coarse + k as f64 * 0.005f64.to_radians()))
        .min_by(|a, b| a.1.total_cmp(&b.1))
        .unwrap()
}

/// The camera's organised view of model `index` of the mug database standing on the
/// cell's table at `base_from_object`.
fn render_mug(
    index: usize,
    base_from_object: &Pose,
    seed: u64,
) -> (graspcell::cloud::PointCloud, Pose) {
    let config = config();
    let camera = DepthCamera::from_config(&config.camera, config.base_from_camera());
    let mut scene = Scene::new(Some(TableBox::from(&config.table)));
    let db = mug_db();
    scene
        .add(
            &db.file.models[index].name,
            db.meshes[index].clone(),
            *base_from_object,
        )
        .unwrap();
    (
        camera.render(&scene, seed).to_cloud(),
        camera.base_from_camera,
    )
}

#[test]
fn sim_view_of_a_mug_registers_to_its_own_model_within_5_mm_and_5_deg() {
    graspcell::logging::init_logging();
    let config = config();
    // Handle visible: it points sideways-towards the camera (yaw 60 deg; the
    // camera looks along -x from x = 1.25 m).
    let truth = pose_from_params(&[0.62, 0.04, config.table.height_m, 0.0, 0.0, 1.05]);
    let (cloud, base_from_camera) = render_mug(2, &truth, 7);
    let models = mug_models();
    let p = perceive(
        &cloud,
        &base_from_camera,
        &SegmentParams::for_cell(&config),
        models,
        &RegisterParams::default(),
        1,
    )
    .unwrap();
    assert_eq!(p.registrations.len(), models.len());
    assert!(
        p.object_base.len() > 1000,
        "{} object points",
        p.object_base.len()
    );
    let own = p
        .registrations
        .iter()
        .find(|r| r.model == "mug_002")
        .unwrap();
    let (lo, hi) = p
        .object_base
        .points
        .iter()
        .fold((f32::MAX, f32::MIN), |(lo, hi), q| {
            (lo.min(q.z), hi.max(q.z))
        });
    eprintln!(
        "object z {lo}..{hi}, {} points; truth {:?}",
        p.object_base.len(),
        graspcell::geometry::params_from_pose(&truth)
    );
    for r in &p.registrations {
        eprintln!(
            "{} {:?} eps {:.3e} in {:.2} {:?}",
            r.model,
            r.status,
            r.eps_m2,
            r.inlier_fraction,
            graspcell::geometry::params_from_pose(&r.target_from_model)
        );
    }
    assert_eq!(own.status, RegistrationStatus::Ok);
    let (dp, dr) = pose_error(&own.target_from_model, &truth);
    assert!(
        dp < 0.005 && dr < 5f64.to_radians(),
        "own model off by {:.1} mm, {:.1} deg",
        dp * 1e3,
        dr.to_degrees()
    );
    // eps is two-sided (issue 19): the target's side alone was under 4e-6; the
    // side of the model points the camera should see adds to it (measured 1.09e-5
    // in all).
    assert!(own.eps_m2 < 2e-5 && own.inlier_fraction > 0.9, "{own:?}");
    assert_eq!(fits_input(&p.registrations).fits.len(), models.len());
}

/// One seeded trial of the accuracy test: model `index` at a random pose on the
/// table with its handle visible (a mug without a handle is scored up to the turn
/// about its axis, [`mug_pose_error`]); returns (position error m, rotation error
/// rad, own model ranks first by eps).
fn accuracy_trial(trial: u64) -> (f64, f64, bool) {
    use rand::{Rng, SeedableRng};
    let config = config();
    let db = mug_db();
    let index = (trial as usize) % db.file.models.len();
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(1000 + trial);
    // Handle visible: yaw within +-100 deg of pointing at the camera (+x), so it is
    // never hidden behind the body. Position: anywhere in a 30 x 40 cm patch of the
    // table in front of the camera.
    let yaw = rng.gen_range(-100f64..100.0).to_radians();
    let x = rng.gen_range(0.45..0.75);
    let y = rng.gen_range(-0.2..0.2);
    let truth = pose_from_params(&[x, y, config.table.height_m, 0.0, 0.0, yaw]);
    let (cloud, base_from_camera) = render_mug(index, &truth, trial);
    let p = perceive(
        &cloud,
        &base_from_camera,
        &SegmentParams::for_cell(&config),
        mug_models(),
        &RegisterParams::default(),
        trial,
    )
    .unwrap();
    let name = &db.file.models[index].name;
    let own = p.registrations.iter().find(|r| &r.model == name).unwrap();
    let (dp, dr) = mug_pose_error(index, &own.target_from_model, &truth);
    let first = p
        .registrations
        .iter()
        .filter(|r| r.status == RegistrationStatus::Ok)
        .all(|r| r.eps_m2 >= own.eps_m2);
    (dp, dr, first)
}

/// The accuracy test: 100 seeded trials (run in parallel), the 7 database
/// mugs in turn, each at a random pose with the handle visible; mug_004 has no
/// handle and is scored up to the turn about its axis.
#[test]
fn accuracy_100_trials_handle_visible() {
    use rayon::prelude::*;
    // Built here, before the trials run on the global pool's workers: a worker that
    // built them would, while waiting for that work, take up another trial that
    // waits for the very lock the worker holds.
    let _ = (mug_models(), symmetric_about_z(0));
    let results: Vec<(u64, (f64, f64, bool))> = (0..100u64)
        .into_par_iter()
        .map(|t| (t, accuracy_trial(t)))
        .collect();
    let mut within = 0;
    let mut first = 0;
    let mut misses = Vec::new();
    for (t, (dp, dr, is_first)) in results {
        if dp < 0.005 && dr < 5f64.to_radians() {
            within += 1;
        } else {
            misses.push(format!(
                "trial {t} (mug_{:03}): {:.1} mm {:.1} deg",
                t % 7,
                dp * 1e3,
                dr.to_degrees()
            ));
        }
        first += usize::from(is_first);
    }
    eprintln!("{within}/100 within 5 mm / 5 deg, own model first by eps in {first}/100; misses {misses:?}");
    // Within 5 mm and 5 deg in at least 95 % (measured: 98; the misses: trial 36
    // at 5.3 mm / 0.3 deg, trial 69 with the handle turned 66 deg) ...
    assert!(within >= 95, "{within}/100 within 5 mm / 5 deg; {misses:?}");
    // ... and the own model ranks first by fitting error in at least 90 %
    // (measured: 99).
    assert!(first >= 90, "own model first in {first}/100");
}

fn mug_cloud(index: usize) -> graspcell::cloud::PointCloud {
    graspcell::cloud::sample::sample_surface(&mug_db().meshes[index], 6000, 3).unwrap()
}

#[test]
fn bad_targets_are_clear_errors() {
    use graspcell::cloud::PointCloud;
    use graspcell::register::{register_all, RegisterError};
    use nalgebra::Point3;
    let models = mug_models();
    let params = RegisterParams::default();
    // Empty cloud after segmentation: a table and no object.
    let config = config();
    let camera = DepthCamera::from_config(&config.camera, config.base_from_camera());
    let table_only = camera
        .render(&Scene::new(Some(TableBox::from(&config.table))), 1)
        .to_cloud();
    let err = perceive(
        &table_only,
        &camera.base_from_camera,
        &SegmentParams::for_cell(&config),
        models,
        &params,
        0,
    )
    .unwrap_err();
    assert!(
        err.to_string()
            .starts_with("segmentation: no object on the table"),
        "{err}"
    );
    // Empty and all-NaN targets.
    let err = register_all(&PointCloud::default(), models, &params, 0).unwrap_err();
    assert!(matches!(err, RegisterError::EmptyTarget), "{err}");
    let nan = PointCloud::from_points(vec![Point3::new(f32::NAN, 0.0, 1.0); 500]);
    let err = register_all(&nan, models, &params, 0).unwrap_err();
    assert_eq!(
        err.to_string(),
        "target cloud has no valid points: all 500 points are NaN or non-finite"
    );
    // 60 points in a 1 cm cube: enough points, but two 5 mm cells' worth for FPFH.
    let tiny = PointCloud::from_points(
        (0..60)
            .map(|i| {
                Point3::new(
                    0.6 + (i % 4) as f32 * 0.002,
                    (i / 4 % 4) as f32 * 0.002,
                    (i / 16) as f32 * 0.002,
                )
            })
            .collect(),
    );
    let err = register_all(&tiny, models, &params, 0)
        .unwrap_err()
        .to_string();
    assert!(
        err.starts_with("target cloud has too few points for FPFH after downsampling to 5 mm"),
        "{err}"
    );
    let few = PointCloud::from_points(vec![Point3::new(0.6, 0.0, 0.05); 5]);
    let err = register_all(&few, models, &params, 0)
        .unwrap_err()
        .to_string();
    assert_eq!(
        err,
        "target cloud has too few points for registration: 5 < 30"
    );
}

#[test]
fn a_model_at_a_wildly_different_scale_fails_alone() {
    use graspcell::register::register_all;
    let params = RegisterParams::default();
    let good = mug_cloud(2);
    let mut millimetres = good.clone();
    millimetres
        .points
        .iter_mut()
        .for_each(|p| p.coords *= 1000.0);
    let set = ModelSet::from_clouds(
        vec![
            ("mug_002".into(), good.clone()),
            ("mug_002_mm".into(), millimetres),
        ],
        &params,
    )
    .unwrap();
    // The target: the model itself moved onto the table, seen whole.
    let truth = pose_from_params(&[0.6, 0.1, 0.0, 0.0, 0.0, 0.7]);
    let t = truth.cast::<f32>();
    let target = graspcell::cloud::PointCloud::from_points(
        graspcell::cloud::sample::sample_surface(&mug_db().meshes[2], 3000, 9)
            .unwrap()
            .points
            .iter()
            .map(|p| t * p)
            .collect(),
    );
    let r = register_all(&target, &set, &params, 4).unwrap();
    assert_eq!(r.len(), 2);
    assert_eq!(r[0].status, RegistrationStatus::Ok, "{:?}", r[0]);
    let (dp, dr) = pose_error(&r[0].target_from_model, &truth);
    assert!(dp < 0.003 && dr < 3f64.to_radians(), "{dp} m {dr} rad");
    match &r[1].status {
        RegistrationStatus::Failed(reason) => assert!(
            reason.starts_with("model is too large for registration")
                || reason.starts_with("scale mismatch"),
            "{reason}"
        ),
        other => panic!("{other:?}"),
    }
    assert!(
        ModelFit::from_registration(&r[1]).is_none()
            && ModelFit::from_registration(&r[0]).is_some()
    );
    // Leave-one-out keeps the other model's result unchanged (per-model seeds).
    let alone = register_all(&target, &set.without("mug_002_mm"), &params, 4).unwrap();
    assert_eq!(alone.len(), 1);
    assert_eq!(alone[0].target_from_model, r[0].target_from_model);
}

#[test]
fn flat_knives_register_to_every_hammer_without_sliding_away() {
    // The cross-category experiment's case: a knife (12 mm thick) seen whole
    // against hammer models. The knife's faces barely constrain a slide along its
    // length; plain point-to-plane ICP let the rim pairs of the unlike shapes pull
    // three of four hammers 0.4-0.6 m off knife_001 (0 % inliers). Both categories
    // are built centred with the handle toward +x, so a right fit stays near the
    // identity.
    use graspcell::register::register_all;
    let params = RegisterParams::default();
    let hammers = ModelSet::from_category(
        &CategoryDb::load(&root().join("db/hammer")).unwrap(),
        &params,
    )
    .unwrap();
    let knives = CategoryDb::load(&root().join("db/knife")).unwrap();
    for (i, mesh) in knives.meshes.iter().enumerate() {
        let target = graspcell::cloud::sample::sample_surface(mesh, 3000, 1).unwrap();
        for r in register_all(&target, &hammers, &params, 1).unwrap() {
            let knife = &knives.file.models[i].name;
            let offset_m = r.target_from_model.translation.vector.norm();
            assert_eq!(r.status, RegistrationStatus::Ok, "{knife}: {r:?}");
            assert!(
                r.inlier_fraction > 0.5 && offset_m < 0.06,
                "{knife} / {}: {:.0} % inliers, {:.0} mm off",
                r.model,
                r.inlier_fraction * 100.0,
                offset_m * 1e3
            );
        }
    }
}

#[test]
fn cli_segment_then_register_prints_one_json_entry_per_model() {
    use graspcell::cloud::io::{write_cloud, CloudEncoding};
    let dir = TempDir::new("perceive-cli").unwrap();
    let config = config();
    let truth = pose_from_params(&[0.6, -0.05, config.table.height_m, 0.0, 0.0, 0.5]);
    let (cloud, _) = render_mug(4, &truth, 11);
    let scene = dir.join("scene.ply");
    write_cloud(&scene, &cloud, CloudEncoding::Binary).unwrap();
    let cell = |args: &[&str]| {
        std::process::Command::new(env!("CARGO_BIN_EXE_cell"))
            .current_dir(env!("CARGO_MANIFEST_DIR"))
            .args(args)
            .output()
            .unwrap()
    };
    let object = dir.join("object.ply");
    let out = cell(&[
        "segment",
        "--cloud",
        scene.to_str().unwrap(),
        "--out",
        object.to_str().unwrap(),
        "--json",
    ]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let report: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert!(report["object_points"].as_u64().unwrap() > 1000, "{report}");
    // Two model files: the right mug and another.
    for i in [4, 0] {
        let name = &mug_db().file.models[i].name;
        write_cloud(
            &dir.join(format!("{name}.ply")),
            &mug_cloud(i),
            CloudEncoding::Binary,
        )
        .unwrap();
    }
    let out = cell(&[
        "register",
        "--target",
        object.to_str().unwrap(),
        "--model",
        dir.join("mug_004.ply").to_str().unwrap(),
        "--model",
        dir.join("mug_000.ply").to_str().unwrap(),
        "--seed",
        "3",
        "--json",
    ]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let lines: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    let lines = lines.as_array().unwrap();
    assert_eq!(lines.len(), 2);
    assert_eq!(lines[0]["model"], "mug_004");
    assert_eq!(lines[0]["status"], "ok");
    for key in ["eps", "sigma", "inlier_fraction", "rmse", "time_ms"] {
        assert!(lines[0][key].as_f64().is_some(), "{key}: {}", lines[0]);
    }
    let rows: Vec<[f64; 4]> =
        serde_json::from_value(lines[0]["target_from_model"].clone()).unwrap();
    let pose = graspcell::geometry::pose_from_matrix_rows(&[rows[0], rows[1], rows[2], rows[3]]);
    // mug_004 has no handle: its turn about its axis is not observable.
    assert!(symmetric_about_z(4));
    let (dp, dr) = mug_pose_error(4, &pose, &truth);
    assert!(dp < 0.005 && dr < 5f64.to_radians(), "{dp} m {dr} rad");

    // Bad input: an all-NaN target is a one-line error and a non-zero exit.
    let nan = dir.join("nan.ply");
    write_cloud(
        &nan,
        &graspcell::cloud::PointCloud::from_points(vec![
            nalgebra::Point3::new(f32::NAN, 0.0, 0.0);
            10
        ]),
        CloudEncoding::Ascii,
    )
    .unwrap();
    let model = dir.join("mug_004.ply");
    let out = cell(&[
        "register",
        "--target",
        nan.to_str().unwrap(),
        "--model",
        model.to_str().unwrap(),
    ]);
    assert!(!out.status.success());
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(
        stderr.contains("nan.ply") && stderr.contains("no valid points"),
        "{stderr}"
    );
    // A scene with no object: segmentation says so and writes nothing.
    let table_only = dir.join("table.ply");
    let camera = DepthCamera::from_config(&config.camera, config.base_from_camera());
    write_cloud(
        &table_only,
        &camera
            .render(&Scene::new(Some(TableBox::from(&config.table))), 2)
            .to_cloud(),
        CloudEncoding::Binary,
    )
    .unwrap();
    let none = dir.join("none.ply");
    let out = cell(&[
        "segment",
        "--cloud",
        table_only.to_str().unwrap(),
        "--out",
        none.to_str().unwrap(),
    ]);
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("no object on the table"));
    assert!(!none.exists());
}
