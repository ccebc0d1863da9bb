//! The simulated world of one trial: which novel object stands where, and the seeds.
//!
//! The harness writes `<run dir>/trials/<trial id>.json` before it sends the trial
//! request; the simulated camera renders the object from it and the simulated
//! observer grades the executed grasp against the same true object and pose. With
//! real devices there is no setup file: the camera is real and a person grades.

use super::CellError;
use crate::config::CellConfig;
use crate::fsio::{FileError, FileOp};
use crate::geometry::{Pose, PoseJson};
use crate::mesh::procedural::held_apart::{generate_in, Family};
use crate::mesh::procedural::Category;
use crate::mesh::TriMesh;
use crate::sim::lab::LabDraw;
use crate::sim::scene::{Scene, TableBox};
use crate::trial::{ObjectRef, Placement};
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

/// What the simulated world holds for one trial.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TrialSetup {
    /// The trial id (as in the trial request).
    pub trial_id: u64,
    /// The object's category.
    pub category: Category,
    /// The object: a procedural instance (`seed` set) not in the database.
    pub object: ObjectRef,
    /// Where it stands: index among the object's placements and its pose.
    pub placement: Placement,
    /// Campaign the trial belongs to, if any (pairs methods in reports).
    pub campaign_id: Option<String>,
    /// Seed of the camera's noise (the same for every method of a placement).
    pub noise_seed: u64,
    /// Seed of perception's random choices (RANSAC).
    pub perception_seed: u64,
    /// Where the object's mesh comes from (default, for older files: the training
    /// generator).
    #[serde(default)]
    pub source: ObjectSource,
    /// The lab's errors in this trial: the camera's true mount and the executed
    /// joints' errors ([`crate::sim::lab`]); `None`: an exact cell.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub lab: Option<LabDraw>,
}

/// Where a trial's object mesh comes from.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "kebab-case", deny_unknown_fields)]
pub enum ObjectSource {
    /// The training generator, from the object's seed (the databases' family).
    #[default]
    Training,
    /// The held-apart family ([`crate::mesh::procedural::held_apart`]), from the
    /// object's seed.
    HeldApart,
    /// A user's mesh file (OBJ, STL, PLY), scaled to metres.
    File {
        /// The mesh file.
        path: PathBuf,
        /// Metres per file unit.
        scale: f64,
    },
}

impl ObjectSource {
    /// The procedural family, `None` for a file.
    pub fn family(&self) -> Option<Family> {
        match self {
            ObjectSource::Training => Some(Family::Training),
            ObjectSource::HeldApart => Some(Family::HeldApart),
            ObjectSource::File { .. } => None,
        }
    }

    /// The source of a procedural family.
    pub fn of_family(family: Family) -> ObjectSource {
        match family {
            Family::Training => ObjectSource::Training,
            Family::HeldApart => ObjectSource::HeldApart,
        }
    }
}

impl TrialSetup {
    /// The setup file of trial `trial_id` under `run_dir`.
    pub fn path(run_dir: &Path, trial_id: u64) -> PathBuf {
        run_dir.join("trials").join(format!("{trial_id}.json"))
    }

    /// Writes the setup file (atomically: a reader never sees half of it).
    pub fn write(&self, run_dir: &Path) -> Result<PathBuf, CellError> {
        let path = TrialSetup::path(run_dir, self.trial_id);
        if let Some(dir) = path.parent() {
            crate::fsio::create_dir_all(dir)?;
        }
        let text = serde_json::to_string_pretty(self).map_err(|e| CellError::Setup {
            path: path.clone(),
            problem: e.to_string(),
        })?;
        crate::fsio::write(&path, text.as_bytes())?;
        Ok(path)
    }

    /// Reads the setup of trial `trial_id`; `Ok(None)` when there is no file.
    pub fn read(run_dir: &Path, trial_id: u64) -> Result<Option<TrialSetup>, CellError> {
        let path = TrialSetup::path(run_dir, trial_id);
        let text = match std::fs::read_to_string(&path) {
            Ok(text) => text,
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(None),
            Err(source) => return Err(FileError::new(FileOp::Read, &path, source).into()),
        };
        let setup: TrialSetup = serde_json::from_str(&text).map_err(|e| CellError::Setup {
            path: path.clone(),
            problem: e.to_string(),
        })?;
        if setup.trial_id != trial_id {
            return Err(CellError::Setup {
                path,
                problem: format!("holds trial {} instead of {trial_id}", setup.trial_id),
            });
        }
        setup.base_from_object().map_err(|e| CellError::Setup {
            path: TrialSetup::path(run_dir, trial_id),
            problem: e.to_string(),
        })?;
        if setup.object.seed.is_none() && setup.source.family().is_some() {
            return Err(CellError::Setup {
                path: TrialSetup::path(run_dir, trial_id),
                problem: "the object has no generator seed".into(),
            });
        }
        Ok(Some(setup))
    }

    /// The object's true pose in the robot base frame.
    pub fn base_from_object(&self) -> Result<Pose, crate::geometry::GeometryError> {
        self.placement
            .base_from_object
            .to_pose("placement.base_from_object")
    }

    /// The object's true mesh (object frame).
    pub fn mesh(&self) -> Result<TriMesh, CellError> {
        match &self.source {
            ObjectSource::File { path, scale } => {
                crate::mesh::load_mesh(path, *scale).map_err(|e| CellError::Setup {
                    path: path.clone(),
                    problem: e.to_string(),
                })
            }
            source => {
                let family = source.family().unwrap_or(Family::Training);
                Ok(generate_in(family, self.category, self.object.seed.unwrap_or(0)).0)
            }
        }
    }

    /// The camera's true mount given the calibrated one the cell uses (they differ
    /// by the lab's hand–eye error).
    pub fn true_base_from_camera(&self, calibrated: &Pose) -> Pose {
        self.lab
            .map_or(*calibrated, |lab| lab.true_base_from_camera(calibrated))
    }

    /// The scene the camera sees: the configured table and the object.
    pub fn scene(&self, config: &CellConfig) -> Result<Scene, CellError> {
        let mut scene = Scene::new(Some(TableBox::from(&config.table)));
        let pose = self.base_from_object().map_err(|e| CellError::Setup {
            path: PathBuf::from(format!("trial {}", self.trial_id)),
            problem: e.to_string(),
        })?;
        scene
            .add(&self.object.name, self.mesh()?, pose)
            .map_err(|e| CellError::Setup {
                path: PathBuf::from(format!("trial {}", self.trial_id)),
                problem: e.to_string(),
            })?;
        Ok(scene)
    }
}

/// A novel object of `category` from `family`: instance `index` of the set
/// `set_seed`. Training-family instances are checked not to be one of the
/// database's models ([`super::harness::novel_object`]); held-apart instances lie
/// outside the training ranges by construction.
pub fn novel_object_in(
    family: Family,
    category: Category,
    set_seed: u64,
    index: u64,
    db: &crate::category::CategoryDb,
) -> (ObjectRef, ObjectSource) {
    match family {
        Family::Training => (
            super::harness::novel_object(category, set_seed, index, db),
            ObjectSource::Training,
        ),
        Family::HeldApart => {
            let (name, seed) =
                crate::mesh::procedural::held_apart::held_apart_instance(category, set_seed, index);
            (
                ObjectRef {
                    name,
                    seed: Some(seed),
                },
                ObjectSource::HeldApart,
            )
        }
    }
}

impl TrialSetup {
    /// Writes the trial's world as a scene file (the object at its pose; the table
    /// left to the configuration) for the simulated devices, which reload `path`
    /// when it changes ([`crate::sim::world::WorldWatch`]); atomically.
    /// A training-family object is named by category and seed; any other (held-apart,
    /// a user's mesh) is written next to the scene as `object-<trial id>.ply`, and
    /// the meshes of earlier trials' scenes there are removed (a campaign left one
    /// per trial, a quarter of a megabyte each).
    pub fn write_sim_scene(&self, path: &Path) -> Result<(), CellError> {
        let dir = path.parent().unwrap_or(Path::new("."));
        crate::fsio::create_dir_all(dir)?;
        let (mesh, category, seed) = match self.source {
            ObjectSource::Training => (None, Some(self.category), self.object.seed),
            _ => {
                let name = PathBuf::from(format!(
                    "{SCENE_MESH_PREFIX}{}{SCENE_MESH_SUFFIX}",
                    self.trial_id
                ));
                crate::mesh::write_mesh(&dir.join(&name), &self.mesh()?).map_err(|e| {
                    CellError::Setup {
                        path: dir.join(&name),
                        problem: e.to_string(),
                    }
                })?;
                (Some(name), None, None)
            }
        };
        let file = crate::sim::scene::SceneFile {
            base_from_camera: None,
            table: None,
            objects: vec![crate::sim::scene::ObjectEntry {
                mesh,
                scale: None,
                category,
                seed,
                pose: self.placement.base_from_object,
            }],
        };
        let text = toml::to_string(&file).map_err(|e| CellError::Setup {
            path: path.to_path_buf(),
            problem: e.to_string(),
        })?;
        crate::fsio::write(path, text.as_bytes())?;
        remove_earlier_meshes(dir, file.objects[0].mesh.as_deref());
        Ok(())
    }
}

/// A trial's scene object is `<prefix><trial id><suffix>`, `object-<trial id>.ply`.
const SCENE_MESH_PREFIX: &str = "object-";
const SCENE_MESH_SUFFIX: &str = ".ply";

/// Removes the `object-<trial id>.ply` meshes in `dir` but `keep`: earlier trials'
/// scene objects, which the scene just written no longer names. A file that cannot
/// be removed is logged and left.
fn remove_earlier_meshes(dir: &Path, keep: Option<&Path>) {
    let Ok(entries) = std::fs::read_dir(dir) else {
        return;
    };
    for entry in entries.flatten() {
        let name = entry.file_name();
        let earlier = keep.is_none_or(|k| k.as_os_str() != name)
            && name.to_str().is_some_and(|n| {
                n.starts_with(SCENE_MESH_PREFIX) && n.ends_with(SCENE_MESH_SUFFIX)
            });
        if earlier {
            if let Err(e) = std::fs::remove_file(entry.path()) {
                tracing::warn!("{}: not removed: {e}", entry.path().display());
            }
        }
    }
}

/// A placement pose: upright on the table top at `xy_m`, turned by `yaw_rad`.
pub fn upright_pose(config: &CellConfig, xy_m: [f64; 2], yaw_rad: f64) -> PoseJson {
    PoseJson {
        xyz: [xy_m[0], xy_m[1], config.table.height_m],
        rpy: Some([0.0, 0.0, yaw_rad]),
        quat_xyzw: None,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn setup_files_round_trip_and_bad_ones_are_named() {
        let dir = crate::fsio::TempDir::new("setup").unwrap();
        let config = CellConfig::load(Path::new("robot/cell.toml")).unwrap();
        let setup = TrialSetup {
            trial_id: 12,
            category: Category::Mug,
            object: ObjectRef {
                name: "mug-novel-0".into(),
                seed: Some(99),
            },
            placement: Placement {
                index: 2,
                base_from_object: upright_pose(&config, [0.6, 0.1], 0.5),
            },
            campaign_id: Some("c".into()),
            noise_seed: 5,
            perception_seed: 6,
            source: ObjectSource::Training,
            lab: None,
        };
        let path = setup.write(&dir).unwrap();
        assert_eq!(TrialSetup::read(&dir, 12).unwrap(), Some(setup.clone()));
        assert_eq!(TrialSetup::read(&dir, 13).unwrap(), None);
        let scene = setup.scene(&config).unwrap();
        assert_eq!(scene.objects.len(), 1);
        std::fs::write(&path, "{\"trial_id\": 12}").unwrap();
        let err = TrialSetup::read(&dir, 12).unwrap_err().to_string();
        assert!(
            err.contains("12.json") && err.contains("missing field"),
            "{err}"
        );
    }

    #[test]
    fn setups_carry_the_object_source_and_the_lab_draw() {
        let dir = crate::fsio::TempDir::new("setup-src").unwrap();
        let config = CellConfig::load(Path::new("robot/cell.toml")).unwrap();
        let db = crate::category::CategoryDb::load(Path::new("db/mug")).unwrap();
        let (object, source) = novel_object_in(Family::HeldApart, Category::Mug, 3, 0, &db);
        assert_eq!(source, ObjectSource::HeldApart);
        let lab = crate::sim::lab::LabErrors::default().draw(1, 2);
        let mut setup = TrialSetup {
            trial_id: 21,
            category: Category::Mug,
            object,
            placement: Placement {
                index: 0,
                base_from_object: upright_pose(&config, [0.6, 0.0], 0.0),
            },
            campaign_id: None,
            noise_seed: 1,
            perception_seed: 1,
            source,
            lab: Some(lab),
        };
        setup.write(&dir).unwrap();
        let back = TrialSetup::read(&dir, 21).unwrap().unwrap();
        assert_eq!(back, setup);
        let held_apart = back.mesh().unwrap();
        // The simulated devices' scene names the object's mesh beside it; the next
        // trial's scene replaces it.
        let scene = dir.join("sim").join("scene.toml");
        let meshes = || {
            let mut names: Vec<String> = std::fs::read_dir(dir.join("sim"))
                .unwrap()
                .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
                .filter(|n| n.ends_with(".ply"))
                .collect();
            names.sort();
            names
        };
        setup.write_sim_scene(&scene).unwrap();
        assert_eq!(meshes(), ["object-21.ply"]);
        let next = TrialSetup {
            trial_id: 22,
            ..setup.clone()
        };
        next.write_sim_scene(&scene).unwrap();
        assert_eq!(meshes(), ["object-22.ply"]);
        assert!(std::fs::read_to_string(&scene)
            .unwrap()
            .contains("object-22.ply"));
        assert_ne!(
            held_apart,
            generate_in(Family::Training, Category::Mug, 3).0
        );
        // The camera really stands where the lab's error puts it.
        let calibrated = config.base_from_camera();
        let (dp, _) =
            crate::geometry::pose_error(&calibrated, &back.true_base_from_camera(&calibrated));
        assert!((dp - 0.003).abs() < 1e-9, "{dp}");
        // A user's mesh file, and a missing one named in the error.
        let file = dir.join("mine.stl");
        crate::mesh::write_mesh(&file, &held_apart).unwrap();
        setup.source = ObjectSource::File {
            path: file.clone(),
            scale: 1.0,
        };
        setup.object.seed = None;
        setup.write(&dir).unwrap();
        let back = TrialSetup::read(&dir, 21).unwrap().unwrap();
        assert_eq!(
            back.mesh().unwrap().triangles.len(),
            held_apart.triangles.len()
        );
        std::fs::remove_file(&file).unwrap();
        let e = back.mesh().unwrap_err().to_string();
        assert!(e.contains("mine.stl"), "{e}");
        // Files written before the source and the lab existed read as training, exact.
        let old = r#"{"trial_id": 22, "category": "mug", "object": {"name": "m", "seed": 5},
            "placement": {"index": 0, "base_from_object": {"xyz": [0.6, 0, 0], "rpy": [0, 0, 0]}},
            "campaign_id": null, "noise_seed": 1, "perception_seed": 1}"#;
        std::fs::write(TrialSetup::path(&dir, 22), old).unwrap();
        let old = TrialSetup::read(&dir, 22).unwrap().unwrap();
        assert_eq!((old.source, old.lab), (ObjectSource::Training, None));
    }
}
