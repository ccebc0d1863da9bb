//! The category database: the training models of a category and their
//! task-labelled example grasps, each with its quality `q` (Ferrari–Canny epsilon)
//! and per-DOF stability range (`Delta`, `sigma = Delta / 3`), as the planner needs
//! them (specs/method.md).
//!
//! A database is a directory: `category.json` (human-readable, listing models and
//! grasps) and `models/<name>.ply` (each model's mesh, binary PLY). Model point clouds
//! are not stored: [`CategoryDb::model_cloud`] samples them from the mesh with the
//! point count and seed recorded in the database, which is deterministic and takes
//! milliseconds (a stored cloud file is used instead when the database names one).
//! [`train`] builds a database from a teach-in file ([`teach`]); [`suggest`]
//! proposes teach-in grasps for procedural models.

pub mod calibrate;
pub mod suggest;
pub mod teach;
pub mod train;

use crate::cloud::PointCloud;
use crate::fsio::FileError;
use crate::geometry::{params_from_pose, Pose, PoseJson, PoseParams};
use crate::mesh::procedural::Category;
use crate::mesh::TriMesh;
use crate::quality::autograsp::{AutoGraspOptions, GraspObject, GraspSimError};
use crate::quality::stability::StabilityOptions;
use crate::quality::QualityParams;
use crate::robot::PreshapeRad;
use serde::{Deserialize, Serialize};
use std::collections::HashSet;
use std::path::{Path, PathBuf};
use std::sync::OnceLock;

/// The database file inside a database directory.
pub const DATABASE_FILE: &str = "category.json";

/// The version of the database format this code reads and writes.
pub const FORMAT_VERSION: u32 = 1;

/// The tasks of each category (the paper's): mug `top`, `side` (opposite the
/// handle), `handle`; bottle `side`; hammer and knife `use` (by the handle).
pub fn tasks_of(category: Category) -> &'static [&'static str] {
    match category {
        Category::Mug => &["top", "side", "handle"],
        Category::Bottle => &["side"],
        Category::Hammer | Category::Knife => &["use"],
    }
}

/// Errors of reading, checking, training or writing a category database; each
/// names the file, model or grasp at fault.
#[derive(Debug, thiserror::Error)]
pub enum CategoryError {
    /// A file could not be read or written.
    #[error(transparent)]
    File(#[from] FileError),
    /// A file does not parse.
    #[error("{path}: {message}")]
    Parse {
        /// The file.
        path: PathBuf,
        /// The parser's message.
        message: String,
    },
    /// A database written by another format version.
    #[error("{path}: format {found}, this program reads format {expected}")]
    Format {
        /// The file.
        path: PathBuf,
        /// The version found.
        found: u32,
        /// The version understood.
        expected: u32,
    },
    /// The teach file is for another category.
    #[error("teach file is for category {file}, but training was asked for {asked}")]
    CategoryMismatch {
        /// The file's category.
        file: Category,
        /// The category asked for.
        asked: Category,
    },
    /// Two models or two grasps share a name (or a name is empty).
    #[error("{what} name {name:?} is empty or used twice")]
    DuplicateName {
        /// `model` or `grasp`.
        what: &'static str,
        /// The name.
        name: String,
    },
    /// A grasp's model (or its mesh file) does not exist.
    #[error("grasp {grasp}: model {model} is missing ({path})")]
    MissingModel {
        /// The grasp.
        grasp: String,
        /// The model name.
        model: String,
        /// The mesh file looked for.
        path: PathBuf,
    },
    /// A grasp's task is not one of its category's.
    #[error("grasp {grasp}: unknown task {task:?} for category {category} (tasks: {known})")]
    UnknownTask {
        /// The grasp.
        grasp: String,
        /// The task given.
        task: String,
        /// The category.
        category: Category,
        /// The known tasks, comma-separated.
        known: String,
    },
    /// A grasp is unusable as given (bad pose, spread, the hand in the object).
    #[error("grasp {grasp}: {problem}")]
    Grasp {
        /// The grasp.
        grasp: String,
        /// What is wrong.
        problem: String,
    },
    /// Example grasps without force closure: the user must fix them.
    #[error("{} grasp(s) not force closure (epsilon = 0), fix or remove them: {}", .grasps.len(), .grasps.join(", "))]
    NotForceClosure {
        /// Names of the failing grasps.
        grasps: Vec<String>,
    },
    /// A model's mesh is unusable.
    #[error("model {model}: {source}")]
    Model {
        /// The model.
        model: String,
        /// The mesh problem.
        source: GraspSimError,
    },
    /// The grasp simulation failed for a grasp.
    #[error("grasp {grasp}: {source}")]
    Simulation {
        /// The grasp.
        grasp: String,
        /// The simulator's error.
        source: GraspSimError,
    },
    /// A value of a database or teach file is out of range.
    #[error("{what}: {field} = {value}: {problem}")]
    Invalid {
        /// The file, model or grasp.
        what: String,
        /// The field.
        field: String,
        /// The value, as text.
        value: String,
        /// What is wrong.
        problem: String,
    },
    /// A model cloud could not be read or sampled.
    #[error("model {model}: cloud: {source}")]
    Cloud {
        /// The model.
        model: String,
        /// The cloud problem.
        source: crate::cloud::io::CloudError,
    },
}

/// The quality-metric settings a database was trained with.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MetricSettings {
    /// Friction coefficient.
    pub mu: f64,
    /// Edges of the friction pyramid.
    pub cone_edges: usize,
}

impl MetricSettings {
    /// The metric parameters (centroid and torque scale come from each model).
    pub fn params(&self) -> QualityParams {
        QualityParams {
            mu: self.mu,
            cone_edges: self.cone_edges,
            ..QualityParams::default()
        }
    }
}

/// The closing-simulation settings a database was trained with.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SimSettings {
    /// Joint step (rad).
    pub step_rad: f64,
    /// Bisection tolerance (rad).
    pub tolerance_rad: f64,
    /// Contact distance (m).
    pub contact_distance_m: f64,
    /// Contact merge distance per link (m).
    pub merge_distance_m: f64,
}

impl From<AutoGraspOptions> for SimSettings {
    fn from(o: AutoGraspOptions) -> Self {
        SimSettings {
            step_rad: o.step_rad,
            tolerance_rad: o.tolerance_rad,
            contact_distance_m: o.contact_distance_m,
            merge_distance_m: o.merge_distance_m,
        }
    }
}

impl From<SimSettings> for AutoGraspOptions {
    fn from(s: SimSettings) -> Self {
        AutoGraspOptions {
            step_rad: s.step_rad,
            tolerance_rad: s.tolerance_rad,
            contact_distance_m: s.contact_distance_m,
            merge_distance_m: s.merge_distance_m,
        }
    }
}

/// How a model's point cloud is obtained.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CloudSpec {
    /// Points sampled uniformly by area over the mesh.
    pub points: usize,
    /// Seed of the sampling.
    pub seed: u64,
    /// A stored cloud file (PLY/PCD, relative to the database directory); when
    /// absent the cloud is sampled from the mesh.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub file: Option<PathBuf>,
}

/// A training model.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ModelEntry {
    /// Unique name.
    pub name: String,
    /// Mesh file, relative to the database directory.
    pub mesh: PathBuf,
    /// The model's point cloud.
    pub cloud: CloudSpec,
    /// Triangles of the mesh.
    pub triangles: usize,
    /// Centroid of the enclosed volume (model frame, m): the torque reference.
    pub centroid_m: [f64; 3],
    /// Torque scale of the quality metric (m).
    pub torque_scale_m: f64,
}

/// A task-labelled example grasp with its quality and stability.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct GraspEntry {
    /// Unique name (from the teach file).
    pub name: String,
    /// The model's name.
    pub model: String,
    /// The task.
    pub task: String,
    /// Palm pose in the model's frame.
    pub pose: PoseJson,
    /// Spread (rad).
    pub spread_rad: f64,
    /// Pre-shape: each finger's flex before the approach (rad); open (absent) by
    /// default.
    #[serde(default, skip_serializing_if = "PreshapeRad::is_open")]
    pub preshape_rad: PreshapeRad,
    /// How far beyond `pose` the approach to contact may go (m); the cell's
    /// `approach.max_overtravel_m` when absent (the teach file's value).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub max_overtravel_m: Option<f64>,
    /// Quality: Ferrari–Canny epsilon (> 0).
    pub q: f64,
    /// Grasp wrench space volume.
    pub volume: f64,
    /// Number of contacts of the closed hand.
    pub contacts: usize,
    /// Stability range per DOF, Delta_d (m, rad).
    pub delta: [f64; 6],
    /// Standard deviation per DOF, sigma_d = Delta_d / 3 (m, rad).
    pub sigma: [f64; 6],
}

/// The content of `category.json`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DatabaseFile {
    /// Format version ([`FORMAT_VERSION`]).
    pub format: u32,
    /// The category.
    pub category: Category,
    /// The category's tasks.
    pub tasks: Vec<String>,
    /// Table top height in the models' frame during training (m), if any.
    pub table_height_m: Option<f64>,
    /// Quality metric settings.
    pub metric: MetricSettings,
    /// Closing-simulation settings.
    pub simulation: SimSettings,
    /// Stability search settings.
    pub stability: StabilityOptions,
    /// Training models.
    pub models: Vec<ModelEntry>,
    /// Example grasps.
    pub grasps: Vec<GraspEntry>,
    /// The weights of eq. 2 calibrated for this category, with the numbers they came
    /// from (`cell train`); absent in databases trained before calibration.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub weights: Option<calibrate::WeightCalibration>,
}

/// A loaded, validated category database.
#[derive(Debug, Clone)]
pub struct CategoryDb {
    /// The database directory.
    pub dir: PathBuf,
    /// The database file's content.
    pub file: DatabaseFile,
    /// Each model's mesh, in `file.models` order.
    pub meshes: Vec<TriMesh>,
    /// Each model's grasp object, prepared on first use ([`CategoryDb::grasp_object`]).
    objects: Vec<OnceLock<GraspObject>>,
}

impl CategoryDb {
    /// Loads `dir/category.json` and every model mesh, and validates them: format,
    /// tasks, unique names, every grasp's model present, finite poses, q > 0,
    /// non-negative finite ranges.
    pub fn load(dir: &Path) -> Result<CategoryDb, CategoryError> {
        let path = dir.join(DATABASE_FILE);
        let text = crate::fsio::read_to_string(&path)?;
        let file = DatabaseFile::parse(&text, &path)?;
        let meshes = file
            .models
            .iter()
            .map(|m| {
                crate::mesh::load_mesh(&dir.join(&m.mesh), 1.0).map_err(|e| CategoryError::Model {
                    model: m.name.clone(),
                    source: GraspSimError::Mesh(e),
                })
            })
            .collect::<Result<Vec<_>, _>>()?;
        Ok(CategoryDb {
            dir: dir.to_path_buf(),
            file,
            objects: meshes.iter().map(|_| OnceLock::new()).collect(),
            meshes,
        })
    }

    /// The grasp object of model `index` (its mesh with the tree and normals the
    /// grasp simulator queries, no table), prepared once and kept: a planner that
    /// simulates grasps on every trial does not rebuild it each time.
    pub fn grasp_object(&self, index: usize) -> Result<&GraspObject, GraspSimError> {
        let cell = &self.objects[index];
        if let Some(object) = cell.get() {
            return Ok(object);
        }
        let path = self.dir.join(&self.file.models[index].mesh);
        let object = GraspObject::new(&self.meshes[index], &path)?;
        Ok(cell.get_or_init(|| object))
    }

    /// The grasps of `task`.
    pub fn grasps_for<'a>(&'a self, task: &'a str) -> impl Iterator<Item = &'a GraspEntry> + 'a {
        self.file.grasps.iter().filter(move |g| g.task == task)
    }

    /// Index of the model called `name`.
    pub fn model_index(&self, name: &str) -> Option<usize> {
        self.file.models.iter().position(|m| m.name == name)
    }

    /// The point cloud of model `index`: its stored file, or sampled from its mesh
    /// with the recorded count and seed (with normals).
    pub fn model_cloud(&self, index: usize) -> Result<PointCloud, CategoryError> {
        let model = &self.file.models[index];
        let err = |source| CategoryError::Cloud {
            model: model.name.clone(),
            source,
        };
        match &model.cloud.file {
            Some(f) => crate::cloud::io::read_cloud(&self.dir.join(f)).map_err(err),
            None => crate::cloud::sample::sample_surface(
                &self.meshes[index],
                model.cloud.points,
                model.cloud.seed,
            )
            .map_err(err),
        }
    }
}

impl GraspEntry {
    /// The palm pose parameters `[x, y, z, ax, ay, az]` in the model's frame (the
    /// pose is checked finite when the database loads).
    pub fn params(&self) -> PoseParams {
        let pose = self
            .pose
            .to_pose(&self.name)
            .unwrap_or_else(|_| Pose::identity());
        params_from_pose(&pose)
    }

    /// The hand's shape before the approach: the spread and the pre-shape.
    pub fn preshape(&self) -> crate::robot::HandPose {
        self.preshape_rad.at_spread(self.spread_rad)
    }
}

impl DatabaseFile {
    /// Parses and validates `category.json` text read from `path` (which names it in
    /// errors); the meshes are not loaded.
    pub fn parse(text: &str, path: &Path) -> Result<DatabaseFile, CategoryError> {
        let value: serde_json::Value =
            serde_json::from_str(text).map_err(|e| CategoryError::Parse {
                path: path.to_path_buf(),
                message: e.to_string(),
            })?;
        let found = value.get("format").and_then(|v| v.as_u64()).unwrap_or(0);
        if found != u64::from(FORMAT_VERSION) {
            return Err(CategoryError::Format {
                path: path.to_path_buf(),
                found: u32::try_from(found).unwrap_or(u32::MAX),
                expected: FORMAT_VERSION,
            });
        }
        let file: DatabaseFile =
            serde_json::from_value(value).map_err(|e| CategoryError::Parse {
                path: path.to_path_buf(),
                message: e.to_string(),
            })?;
        file.validate(path)?;
        Ok(file)
    }

    /// Checks the content; `path` names the file in errors.
    pub fn validate(&self, path: &Path) -> Result<(), CategoryError> {
        let invalid = |what: String, field: &str, value: String, problem: &str| {
            Err(CategoryError::Invalid {
                what,
                field: field.into(),
                value,
                problem: problem.into(),
            })
        };
        let file = path.display().to_string();
        if let Some(w) = &self.weights {
            w.validate(&file)?;
        }
        let known = tasks_of(self.category);
        if let Some(t) = self.tasks.iter().find(|t| !known.contains(&t.as_str())) {
            return invalid(file, "tasks", t.clone(), "not a task of the category");
        }
        let mut names = HashSet::new();
        for m in &self.models {
            if m.name.is_empty() || !names.insert(m.name.as_str()) {
                return Err(CategoryError::DuplicateName {
                    what: "model",
                    name: m.name.clone(),
                });
            }
            if !(m.torque_scale_m.is_finite() && m.torque_scale_m > 0.0) {
                return invalid(
                    format!("{file}: model {}", m.name),
                    "torque_scale_m",
                    m.torque_scale_m.to_string(),
                    "must be finite and > 0",
                );
            }
            if m.cloud.points == 0 && m.cloud.file.is_none() {
                return invalid(
                    format!("{file}: model {}", m.name),
                    "cloud.points",
                    "0".into(),
                    "must be > 0",
                );
            }
        }
        let mut grasp_names = HashSet::new();
        for g in &self.grasps {
            let what = || format!("{file}: grasp {}", g.name);
            if g.name.is_empty() || !grasp_names.insert(g.name.as_str()) {
                return Err(CategoryError::DuplicateName {
                    what: "grasp",
                    name: g.name.clone(),
                });
            }
            if !names.contains(g.model.as_str()) {
                return Err(CategoryError::MissingModel {
                    grasp: g.name.clone(),
                    model: g.model.clone(),
                    path: path.to_path_buf(),
                });
            }
            if !self.tasks.contains(&g.task) {
                return Err(CategoryError::UnknownTask {
                    grasp: g.name.clone(),
                    task: g.task.clone(),
                    category: self.category,
                    known: self.tasks.join(", "),
                });
            }
            if let Err(e) = g.pose.to_pose(&what()) {
                return Err(CategoryError::Grasp {
                    grasp: g.name.clone(),
                    problem: e.to_string(),
                });
            }
            if !g.spread_rad.is_finite() {
                return invalid(
                    what(),
                    "spread_rad",
                    g.spread_rad.to_string(),
                    "must be finite",
                );
            }
            if let Some(problem) = g
                .preshape_rad
                .problem(crate::robot::FLEX_LIMITS_RAD)
                .or_else(|| crate::quality::approach::overtravel_problem(g.max_overtravel_m))
            {
                return Err(CategoryError::Grasp {
                    grasp: what(),
                    problem,
                });
            }
            if !(g.q > 0.0 && g.q.is_finite()) {
                return invalid(what(), "q", g.q.to_string(), "must be finite and > 0");
            }
            for (field, values) in [("delta", &g.delta), ("sigma", &g.sigma)] {
                if let Some(v) = values.iter().find(|v| !(v.is_finite() && **v > 0.0)) {
                    return invalid(what(), field, v.to_string(), "must be finite and > 0");
                }
            }
        }
        Ok(())
    }
}
