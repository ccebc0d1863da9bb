//! The simulated world of one trial: which novel object stands where, and the seeds.
//!
//! The harness writes `<run dir>/trials/<trial id>.json` before it sends the trial
//! request; the simulated camera renders the object from it and the simulated
//! observer grades the executed grasp against the same true object and pose. With
//! real devices there is no setup file: the camera is real and a person grades.

use super::CellError;
use crate::config::CellConfig;
use crate::geometry::{Pose, PoseJson};
use crate::mesh::procedural::{generate, Category};
use crate::mesh::TriMesh;
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
            std::fs::create_dir_all(dir).map_err(|source| CellError::Io {
                path: dir.to_path_buf(),
                source,
            })?;
        }
        let text = serde_json::to_string_pretty(self).map_err(|e| CellError::Setup {
            path: path.clone(),
            problem: e.to_string(),
        })?;
        crate::fsio::write_atomically(&path, text.as_bytes()).map_err(|source| CellError::Io {
            path: path.clone(),
            source,
        })?;
        Ok(path)
    }

    /// Reads the setup of trial `trial_id`; `Ok(None)` when there is no file.
    pub fn read(run_dir: &Path, trial_id: u64) -> Result<Option<TrialSetup>, CellError> {
        let path = TrialSetup::path(run_dir, trial_id);
        let text = match std::fs::read_to_string(&path) {
            Ok(text) => text,
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(None),
            Err(source) => return Err(CellError::Io { path, source }),
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
        if setup.object.seed.is_none() {
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
    pub fn mesh(&self) -> TriMesh {
        generate(self.category, self.object.seed.unwrap_or(0)).0
    }

    /// The scene the camera sees: the configured table and the object.
    pub fn scene(&self, config: &CellConfig) -> Result<Scene, CellError> {
        let mut scene = Scene::new(Some(TableBox::from(&config.table)));
        let pose = self.base_from_object().map_err(|e| CellError::Setup {
            path: PathBuf::from(format!("trial {}", self.trial_id)),
            problem: e.to_string(),
        })?;
        scene
            .add(&self.object.name, self.mesh(), pose)
            .map_err(|e| CellError::Setup {
                path: PathBuf::from(format!("trial {}", self.trial_id)),
                problem: e.to_string(),
            })?;
        Ok(scene)
    }
}

impl TrialSetup {
    /// Writes the trial's world as a scene file (the object at its pose; the table
    /// left to the configuration) for the simulated devices, which reload `path`
    /// when it changes ([`crate::sim::world::WorldWatch`]); atomically.
    pub fn write_sim_scene(&self, path: &Path) -> Result<(), CellError> {
        let file = crate::sim::scene::SceneFile {
            base_from_camera: None,
            table: None,
            objects: vec![crate::sim::scene::ObjectEntry {
                mesh: None,
                scale: None,
                category: Some(self.category),
                seed: self.object.seed,
                pose: self.placement.base_from_object,
            }],
        };
        let text = toml::to_string(&file).map_err(|e| CellError::Setup {
            path: path.to_path_buf(),
            problem: e.to_string(),
        })?;
        if let Some(dir) = path.parent() {
            std::fs::create_dir_all(dir).map_err(|source| CellError::Io {
                path: dir.to_path_buf(),
                source,
            })?;
        }
        crate::fsio::write_atomically(path, text.as_bytes()).map_err(|source| CellError::Io {
            path: path.to_path_buf(),
            source,
        })
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
        let dir = std::env::temp_dir().join(format!("gc-setup-{}", std::process::id()));
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
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
