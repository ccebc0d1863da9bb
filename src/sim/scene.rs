//! What the simulated camera sees: a table (an axis-aligned box in the robot base
//! frame) and object meshes at poses, built in code or read from a `scene.toml`:
//!
//! ```toml
//! base_from_camera = { xyz = [1.25, 0.0, 0.8], rpy = [-2.43, 0.0, 1.57] }  # optional
//! [table]                       # optional; default: the cell config's table
//! height_m = 0.0
//! center_xy_m = [0.65, 0.0]
//! extent_xy_m = [0.8, 1.2]
//! thickness_m = 0.05
//! [[objects]]
//! mesh = "models/cup.obj"       # OBJ, STL or PLY, relative to this file
//! scale = 0.001                 # optional: a millimetre file
//! pose = { xyz = [0.6, 0.1, 0.0], rpy = [0.0, 0.0, 1.0] }
//! [[objects]]
//! category = "mug"              # a procedural model
//! seed = 3
//! pose = { xyz = [0.7, -0.1, 0.0] }
//! ```

use crate::config::{CellConfig, TableConfig};
use crate::fsio::FileError;
use crate::geometry::{GeometryError, Pose, PoseJson};
use crate::mesh::procedural::{generate, Category};
use crate::mesh::{MeshError, TriMesh};
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

/// Errors of building or loading a scene; each names the scene file or object.
#[derive(Debug, thiserror::Error)]
pub enum SceneError {
    /// The scene file could not be read.
    #[error("cannot read scene {}: {}", .0.path.display(), .0.source)]
    Read(FileError),
    /// The scene file is not valid TOML for the scene schema.
    #[error("scene {path}: {message}")]
    Parse {
        /// The scene file.
        path: PathBuf,
        /// The parser's message, with line and column.
        message: String,
    },
    /// An object entry is inconsistent (e.g. both `mesh` and `category`).
    #[error("scene {path}: objects[{index}]: {problem}")]
    Object {
        /// The scene file.
        path: PathBuf,
        /// Zero-based index of the object entry.
        index: usize,
        /// What is wrong.
        problem: String,
    },
    /// An object's mesh could not be loaded or is unusable.
    #[error("scene {path}: objects[{index}]: {error}")]
    Mesh {
        /// The scene file (or "<code>" for a scene built in code).
        path: PathBuf,
        /// Zero-based index of the object.
        index: usize,
        /// The mesh error, naming the mesh file.
        error: MeshError,
    },
    /// A pose in the scene is not finite or not a rotation.
    #[error("scene {path}: {field}: {error}")]
    Pose {
        /// The scene file.
        path: PathBuf,
        /// Which pose (e.g. "objects[2].pose").
        field: String,
        /// The pose error.
        error: GeometryError,
    },
    /// A table dimension is out of range.
    #[error("scene {path}: table.{field} = {value}: must be finite and positive")]
    Table {
        /// The scene file.
        path: PathBuf,
        /// The offending field.
        field: String,
        /// The offending value.
        value: f64,
    },
}

/// The table top: a horizontal box in the robot base frame.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TableBox {
    /// Height of the top surface above the robot base (m).
    pub height_m: f64,
    /// Centre of the top, x y (m).
    pub center_xy_m: [f64; 2],
    /// Size along x and y (m).
    pub extent_xy_m: [f64; 2],
    /// Thickness of the slab below the top (m).
    #[serde(default = "default_thickness_m")]
    pub thickness_m: f64,
}

fn default_thickness_m() -> f64 {
    0.05
}

impl From<&TableConfig> for TableBox {
    fn from(t: &TableConfig) -> Self {
        TableBox {
            height_m: t.height_m,
            center_xy_m: t.center_xy_m,
            extent_xy_m: t.extent_xy_m,
            thickness_m: t.thickness_m,
        }
    }
}

impl TableBox {
    /// Lower and upper corners in the base frame (m).
    pub fn corners(&self) -> ([f64; 3], [f64; 3]) {
        let [cx, cy] = self.center_xy_m;
        let [ex, ey] = self.extent_xy_m;
        (
            [
                cx - ex / 2.0,
                cy - ey / 2.0,
                self.height_m - self.thickness_m,
            ],
            [cx + ex / 2.0, cy + ey / 2.0, self.height_m],
        )
    }

    fn check(&self, path: &Path) -> Result<(), SceneError> {
        let fields = [
            ("height_m", self.height_m, false),
            ("center_xy_m[0]", self.center_xy_m[0], false),
            ("center_xy_m[1]", self.center_xy_m[1], false),
            ("extent_xy_m[0]", self.extent_xy_m[0], true),
            ("extent_xy_m[1]", self.extent_xy_m[1], true),
            ("thickness_m", self.thickness_m, true),
        ];
        for (field, value, positive) in fields {
            if !value.is_finite() || (positive && value <= 0.0) {
                return Err(SceneError::Table {
                    path: path.to_path_buf(),
                    field: field.to_string(),
                    value,
                });
            }
        }
        Ok(())
    }
}

/// One object of a scene: its mesh (object frame) and where it is.
#[derive(Clone)]
pub struct SceneObject {
    /// A name for logs (file name or category and seed).
    pub name: String,
    /// Pose of the object frame in the robot base frame.
    pub base_from_object: Pose,
    /// The mesh in the object frame (m).
    pub mesh: TriMesh,
    /// The same mesh with its BVH, for ray casts.
    pub(crate) shape: parry3d_f64::shape::TriMesh,
}

impl std::fmt::Debug for SceneObject {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("SceneObject")
            .field("name", &self.name)
            .field("base_from_object", &self.base_from_object)
            .field("triangles", &self.mesh.triangles.len())
            .finish()
    }
}

/// A table and objects, in the robot base frame.
#[derive(Debug, Clone, Default)]
pub struct Scene {
    /// The table, if any.
    pub table: Option<TableBox>,
    /// The objects; a camera labels pixels by their index here.
    pub objects: Vec<SceneObject>,
}

impl Scene {
    /// A scene with `table` and no objects.
    pub fn new(table: Option<TableBox>) -> Scene {
        Scene {
            table,
            objects: Vec::new(),
        }
    }

    /// Adds `mesh` (object frame) at `base_from_object`; builds its BVH.
    pub fn add(
        &mut self,
        name: &str,
        mesh: TriMesh,
        base_from_object: Pose,
    ) -> Result<(), SceneError> {
        let shape = mesh
            .to_parry(Path::new(name))
            .map_err(|error| SceneError::Mesh {
                path: PathBuf::from("<code>"),
                index: self.objects.len(),
                error,
            })?;
        self.objects.push(SceneObject {
            name: name.to_string(),
            base_from_object,
            mesh,
            shape,
        });
        Ok(())
    }
}

/// A scene file's content, as written (see the module doc).
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SceneFile {
    /// Camera pose; default: the cell configuration's.
    #[serde(default)]
    pub base_from_camera: Option<PoseJson>,
    /// The table; default: the cell configuration's.
    #[serde(default)]
    pub table: Option<TableBox>,
    /// The objects.
    #[serde(default)]
    pub objects: Vec<ObjectEntry>,
}

/// One object of a scene file: a mesh file (optionally scaled) or a procedural
/// model (category and seed), at a pose in the base frame.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ObjectEntry {
    /// Mesh file, relative to the scene file.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub mesh: Option<PathBuf>,
    /// Factor applied to the mesh file's coordinates (e.g. 0.001 for millimetres).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub scale: Option<f64>,
    /// Procedural model category.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub category: Option<Category>,
    /// Seed of the procedural model.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub seed: Option<u64>,
    /// Pose of the object frame in the base frame.
    pub pose: PoseJson,
}

/// A scene read from a file, with the camera pose it asks for.
#[derive(Debug, Clone)]
pub struct LoadedScene {
    /// The scene.
    pub scene: Scene,
    /// The camera pose (the file's, else the configuration's).
    pub base_from_camera: Pose,
}

/// Reads a scene file; tables and camera pose default to `config`'s.
pub fn load_scene(path: &Path, config: &CellConfig) -> Result<LoadedScene, SceneError> {
    let text = crate::fsio::read_to_string(path).map_err(SceneError::Read)?;
    parse_scene(&text, path, config)
}

/// Parses scene `text` read from `path` (which names it in errors; object meshes are
/// relative to it); tables and camera pose default to `config`'s.
pub fn parse_scene(
    text: &str,
    path: &Path,
    config: &CellConfig,
) -> Result<LoadedScene, SceneError> {
    let file: SceneFile = toml::from_str(text).map_err(|e| SceneError::Parse {
        path: path.to_path_buf(),
        message: e.to_string().trim().replace('\n', " "),
    })?;
    let pose_error = |field: String, error| SceneError::Pose {
        path: path.to_path_buf(),
        field,
        error,
    };
    let base_from_camera = match &file.base_from_camera {
        Some(pose) => pose
            .to_pose("base_from_camera")
            .map_err(|e| pose_error("base_from_camera".into(), e))?,
        None => config.base_from_camera(),
    };
    let table = file.table.unwrap_or_else(|| TableBox::from(&config.table));
    table.check(path)?;
    let dir = path.parent().unwrap_or(Path::new("."));
    let mut scene = Scene::new(Some(table));
    for (index, entry) in file.objects.iter().enumerate() {
        let object_error = |problem: &str| SceneError::Object {
            path: path.to_path_buf(),
            index,
            problem: problem.to_string(),
        };
        let field = format!("objects[{index}].pose");
        let pose = entry
            .pose
            .to_pose(&field)
            .map_err(|e| pose_error(field, e))?;
        let (name, mesh) = match (&entry.mesh, entry.category) {
            (Some(file), None) => {
                if entry.seed.is_some() {
                    return Err(object_error("seed goes with category, not mesh"));
                }
                let scale = entry.scale.unwrap_or(1.0);
                if !(scale.is_finite() && scale > 0.0) {
                    return Err(object_error(&format!(
                        "scale = {scale}: must be finite and > 0"
                    )));
                }
                let file = dir.join(file);
                let mesh =
                    crate::mesh::load_mesh(&file, scale).map_err(|error| SceneError::Mesh {
                        path: path.to_path_buf(),
                        index,
                        error,
                    })?;
                (file.display().to_string(), mesh)
            }
            (None, Some(category)) => {
                if entry.scale.is_some() {
                    return Err(object_error("scale goes with mesh, not category"));
                }
                let seed = entry
                    .seed
                    .ok_or_else(|| object_error("category needs a seed"))?;
                (
                    format!("{category} seed {seed}"),
                    generate(category, seed).0,
                )
            }
            (Some(_), Some(_)) => {
                return Err(object_error("give either mesh or category, not both"))
            }
            (None, None) => return Err(object_error("give mesh = \"file\" or category and seed")),
        };
        let shape = mesh
            .to_parry(Path::new(&name))
            .map_err(|error| SceneError::Mesh {
                path: path.to_path_buf(),
                index,
                error,
            })?;
        scene.objects.push(SceneObject {
            name,
            base_from_object: pose,
            mesh,
            shape,
        });
    }
    Ok(LoadedScene {
        scene,
        base_from_camera,
    })
}
