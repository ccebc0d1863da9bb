//! `cell train`: a category database from a teach-in file.
//!
//! Every example grasp is simulated (auto-grasp) on its model; a grasp whose open
//! hand collides with the model (or the table), or that is not force closure, stops
//! training with its name, so that nothing is written for a database the planner
//! could not use. Then each grasp's stability range is searched (the slow part,
//! parallel over grasps and directions), and the database is written: meshes as
//! binary PLY under `models/`, optionally sampled clouds under `clouds/`, and
//! `category.json` last, each file atomically.

use super::teach::{CheckedGrasp, TeachFile};
use super::{
    tasks_of, CategoryDb, CategoryError, CloudSpec, DatabaseFile, GraspEntry, MetricSettings,
    ModelEntry, DATABASE_FILE, FORMAT_VERSION,
};
use crate::cloud::io::write_cloud;
use crate::geometry::{params_from_pose, PoseJson};
use crate::mesh::procedural::Category;
use crate::mesh::TriMesh;
use crate::quality::autograsp::{evaluate_grasp, AutoGraspOptions, GraspObject, GraspSimError};
use crate::quality::stability::{stability_range, StabilityOptions};
use crate::robot::hand::HandModel;
use rayon::prelude::*;
use std::path::Path;

/// Settings of training.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TrainOptions {
    /// Quality metric.
    pub metric: MetricSettings,
    /// Closing simulation.
    pub simulation: AutoGraspOptions,
    /// Stability search.
    pub stability: StabilityOptions,
    /// Points of each model's cloud.
    pub cloud_points: usize,
    /// Seed of the cloud sampling (the same for every model).
    pub cloud_seed: u64,
    /// Write the clouds as files under `clouds/` (else they are sampled at load).
    pub write_clouds: bool,
}

impl Default for TrainOptions {
    fn default() -> Self {
        TrainOptions {
            metric: MetricSettings {
                mu: 0.5,
                cone_edges: 8,
            },
            simulation: AutoGraspOptions::default(),
            stability: StabilityOptions::default(),
            cloud_points: 2000,
            cloud_seed: 1,
            write_clouds: false,
        }
    }
}

/// The simulated grasp of one example, before its stability search.
#[derive(Debug, Clone)]
struct Evaluated {
    q: f64,
    volume: f64,
    contacts: usize,
}

/// Models of the teach file, loaded: (name, mesh, grasp object).
type Loaded = Vec<(String, TriMesh, GraspObject)>;

/// Loads every model of `teach` from `models_dir` (in parallel).
fn load_models(teach: &TeachFile, models_dir: &Path) -> Result<Loaded, CategoryError> {
    teach
        .models
        .par_iter()
        .map(|m| {
            let name = m.name();
            let path = models_dir.join(&m.mesh);
            let model_err = |source| CategoryError::Model {
                model: name.clone(),
                source,
            };
            let mesh = crate::mesh::load_mesh(&path, 1.0)
                .map_err(|e| model_err(GraspSimError::Mesh(e)))?;
            let object = GraspObject::new(&mesh, &path)
                .map_err(model_err)?
                .with_table(teach.table_height_m);
            Ok((name, mesh, object))
        })
        .collect()
}

/// Simulates every grasp: a start collision fails at once (naming the first such
/// grasp in file order), grasps without force closure are listed together.
fn evaluate_all(
    hand: &HandModel,
    grasps: &[CheckedGrasp],
    models: &Loaded,
    options: &TrainOptions,
) -> Result<Vec<Evaluated>, CategoryError> {
    let params = options.metric.params();
    let results: Vec<Result<_, CategoryError>> = grasps
        .par_iter()
        .map(|g| {
            let e = evaluate_grasp(
                hand,
                &models[g.model].2,
                &g.pose,
                &g.preshape_rad.at_spread(g.spread_rad),
                &options.simulation,
                &params,
                true,
            )
            .map_err(|source| CategoryError::Simulation {
                grasp: g.name.clone(),
                source,
            })?;
            if let Some(c) = &e.outcome.collision_at_start {
                return Err(CategoryError::Grasp {
                    grasp: g.name.clone(),
                    problem: format!("invalid pose: {c}"),
                });
            }
            Ok(e)
        })
        .collect();
    let mut evaluated = Vec::with_capacity(grasps.len());
    let mut failing = Vec::new();
    for (g, r) in grasps.iter().zip(results) {
        let e = r?;
        if !e.force_closure {
            failing.push(g.name.clone());
        }
        evaluated.push(Evaluated {
            q: e.epsilon,
            volume: e.volume.unwrap_or(0.0),
            contacts: e.outcome.contacts.len(),
        });
    }
    if !failing.is_empty() {
        return Err(CategoryError::NotForceClosure { grasps: failing });
    }
    Ok(evaluated)
}

/// Trains the database of `category` from `teach` (meshes under `models_dir`) and
/// writes it to `out`; `progress` (if any) advances once per grasp's stability
/// search. Returns the database as loaded back from `out`.
pub fn train(
    hand: &HandModel,
    category: Category,
    teach: &TeachFile,
    models_dir: &Path,
    out: &Path,
    options: &TrainOptions,
    progress: Option<&indicatif::ProgressBar>,
) -> Result<CategoryDb, CategoryError> {
    options
        .simulation
        .validate()
        .and_then(|()| options.stability.validate())
        .and_then(|()| {
            options
                .metric
                .params()
                .validate()
                .map_err(GraspSimError::from)
        })
        .map_err(|source| CategoryError::Simulation {
            grasp: "(all)".into(),
            source,
        })?;
    if options.cloud_points == 0 {
        return Err(CategoryError::Invalid {
            what: "training".into(),
            field: "cloud_points".into(),
            value: "0".into(),
            problem: "must be > 0".into(),
        });
    }
    // Each pose exactly as the database stores it (and a planner reads it back),
    // so that q is what the stored pose gives, to the last bit.
    let mut grasps = teach.check(category, models_dir, hand)?;
    let stored: Vec<PoseJson> = grasps.iter().map(|g| PoseJson::from(&g.pose)).collect();
    for (g, json) in grasps.iter_mut().zip(&stored) {
        g.pose = json.to_pose(&g.name).map_err(|e| CategoryError::Grasp {
            grasp: g.name.clone(),
            problem: e.to_string(),
        })?;
        g.params = params_from_pose(&g.pose);
    }
    let models = load_models(teach, models_dir)?;
    let evaluated = evaluate_all(hand, &grasps, &models, options)?;
    if let Some(p) = progress {
        p.set_length(grasps.len() as u64);
    }
    let params = options.metric.params();
    let ranges = grasps
        .par_iter()
        .map(|g| {
            let r = stability_range(
                hand,
                &models[g.model].2,
                &g.params,
                &g.preshape_rad.at_spread(g.spread_rad),
                &options.simulation,
                &params,
                &options.stability,
            )
            .map_err(|source| CategoryError::Simulation {
                grasp: g.name.clone(),
                source,
            });
            if let Some(p) = progress {
                p.inc(1);
            }
            r
        })
        .collect::<Result<Vec<_>, _>>()?;

    let models_out = out.join("models");
    crate::fsio::create_dir_all(&models_out)?;
    let mut entries = Vec::with_capacity(models.len());
    for (name, mesh, object) in &models {
        let file = Path::new("models").join(format!("{name}.ply"));
        crate::mesh::ply::write_ply_mesh(
            &out.join(&file),
            mesh,
            crate::ply::Format::BinaryLittleEndian,
        )
        .map_err(|e| CategoryError::Model {
            model: name.clone(),
            source: GraspSimError::Mesh(e),
        })?;
        let mut cloud = CloudSpec {
            points: options.cloud_points,
            seed: options.cloud_seed,
            file: None,
        };
        if options.write_clouds {
            let cloud_err = |source| CategoryError::Cloud {
                model: name.clone(),
                source,
            };
            let sampled = crate::cloud::sample::sample_surface(mesh, cloud.points, cloud.seed)
                .map_err(cloud_err)?;
            let file = Path::new("clouds").join(format!("{name}.ply"));
            let dir = out.join("clouds");
            crate::fsio::create_dir_all(&dir)?;
            write_cloud(
                &out.join(&file),
                &sampled,
                crate::cloud::io::CloudEncoding::Binary,
            )
            .map_err(cloud_err)?;
            cloud.file = Some(file);
        }
        entries.push(ModelEntry {
            name: name.clone(),
            mesh: file,
            cloud,
            triangles: mesh.triangles.len(),
            centroid_m: object.centroid.into(),
            torque_scale_m: object.torque_scale_m,
        });
    }
    let grasp_entries = grasps
        .iter()
        .zip(&evaluated)
        .zip(&ranges)
        .zip(stored)
        .map(|(((g, e), r), pose)| GraspEntry {
            name: g.name.clone(),
            model: models[g.model].0.clone(),
            task: g.task.clone(),
            pose,
            spread_rad: g.spread_rad,
            preshape_rad: g.preshape_rad,
            max_overtravel_m: g.max_overtravel_m,
            q: e.q,
            volume: e.volume,
            contacts: e.contacts,
            delta: r.delta,
            sigma: r.sigma,
        })
        .collect();
    let db = DatabaseFile {
        format: FORMAT_VERSION,
        category,
        tasks: tasks_of(category).iter().map(|t| t.to_string()).collect(),
        table_height_m: teach.table_height_m,
        metric: options.metric,
        simulation: options.simulation.into(),
        stability: options.stability,
        models: entries,
        grasps: grasp_entries,
        weights: None,
    };
    write_database(out, &db)?;
    CategoryDb::load(out)
}

/// Writes `db` as `dir/category.json`, atomically (the meshes must be there already).
pub fn write_database(dir: &Path, db: &DatabaseFile) -> Result<(), CategoryError> {
    let path = dir.join(DATABASE_FILE);
    let text = serde_json::to_string_pretty(db).expect("the database serialises") + "\n";
    Ok(crate::fsio::write(&path, text.as_bytes())?)
}
