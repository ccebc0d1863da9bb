//! The JSON files `cell plan` reads: model fits and example grasps.
//!
//! `fits.json` (what registration produces for each model):
//!
//! ```json
//! {"fits": [{"name": "mug_000",
//!            "base_from_model": {"xyz": [0.6, 0.0, 0.0], "rpy": [0.0, 0.0, 0.3]},
//!            "eps_m2": 1.2e-5, "sigma_m2": 3.0e-6}]}
//! ```
//!
//! `grasps.json` (the category database's task-labelled grasps; `model` names a fit):
//!
//! ```json
//! {"grasps": [{"model": "mug_000", "task": "handle",
//!              "model_from_palm": {"xyz": [0.0, 0.09, 0.05], "rpy": [1.5708, 0.0, 0.0]},
//!              "spread_rad": 0.0, "q": 0.12,
//!              "sigma_m_rad": [0.01, 0.01, 0.008, 0.15, 0.12, 0.2]}]}
//! ```
//!
//! Poses are [`PoseJson`] (`quat_xyzw` wins over `rpy`). A number written as `null`
//! (how JSON writers print NaN) reads as NaN and is reported by field.

use super::objective::check_value;
use super::{ExampleGrasp, ModelFit, PlanError};
use crate::geometry::{params_from_pose, PoseJson};
use serde::{Deserialize, Deserializer, Serialize};
use std::path::Path;

/// A number that reads `null` as NaN, so that validation can name the field.
fn nullable_f64<'de, D: Deserializer<'de>>(d: D) -> Result<f64, D::Error> {
    Ok(Option::<f64>::deserialize(d)?.unwrap_or(f64::NAN))
}

fn nullable_f64_6<'de, D: Deserializer<'de>>(d: D) -> Result<[f64; 6], D::Error> {
    let v: [Option<f64>; 6] = Deserialize::deserialize(d)?;
    Ok(v.map(|x| x.unwrap_or(f64::NAN)))
}

/// The fits file.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FitsFile {
    /// One entry per model.
    pub fits: Vec<FitJson>,
}

/// One model's fit in the file.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FitJson {
    /// Model name, unique in the file.
    pub name: String,
    /// The model frame in the robot base frame.
    pub base_from_model: PoseJson,
    /// Mean squared nearest-neighbour distance (m^2).
    #[serde(deserialize_with = "nullable_f64")]
    pub eps_m2: f64,
    /// Standard deviation of the squared distances (m^2).
    #[serde(deserialize_with = "nullable_f64")]
    pub sigma_m2: f64,
}

/// The grasps file.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct GraspsFile {
    /// The example grasps, any task.
    pub grasps: Vec<GraspJson>,
}

/// One example grasp in the file.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct GraspJson {
    /// Name of the model (as in the fits).
    pub model: String,
    /// Task label.
    pub task: String,
    /// Palm pose in the model frame.
    pub model_from_palm: PoseJson,
    /// Hand spread (rad).
    #[serde(deserialize_with = "nullable_f64")]
    pub spread_rad: f64,
    /// Grasp quality (Ferrari–Canny epsilon, >= 0).
    #[serde(deserialize_with = "nullable_f64")]
    pub q: f64,
    /// Per-DOF standard deviations (m, m, m, rad, rad, rad).
    #[serde(deserialize_with = "nullable_f64_6")]
    pub sigma_m_rad: [f64; 6],
}

fn read_json<T: serde::de::DeserializeOwned>(path: &Path) -> Result<T, PlanError> {
    let text = std::fs::read_to_string(path).map_err(|source| PlanError::Read {
        path: path.to_path_buf(),
        source,
    })?;
    serde_json::from_str(&text).map_err(|e| PlanError::Parse {
        path: path.to_path_buf(),
        message: e.to_string(),
    })
}

/// Converts and checks the fits of a file (`path` names it in errors).
pub fn fits_from_json(file: &FitsFile, path: &Path) -> Result<Vec<ModelFit>, PlanError> {
    let mut fits = Vec::with_capacity(file.fits.len());
    for (i, f) in file.fits.iter().enumerate() {
        let what = |field: &str| format!("{}: fit {i} ({}) {field}", path.display(), f.name);
        if file.fits[..i].iter().any(|g| g.name == f.name) {
            return Err(PlanError::Parse {
                path: path.to_path_buf(),
                message: format!("fit {i}: a model named {:?} appears twice", f.name),
            });
        }
        let base_from_model = f
            .base_from_model
            .to_pose(&what("base_from_model"))
            .map_err(|e| PlanError::Parse {
                path: path.to_path_buf(),
                message: e.to_string(),
            })?;
        check_value(&what("eps_m2"), f.eps_m2, false)?;
        check_value(&what("sigma_m2"), f.sigma_m2, false)?;
        fits.push(ModelFit {
            name: f.name.clone(),
            base_from_model,
            eps_m2: f.eps_m2,
            sigma_m2: f.sigma_m2,
        });
    }
    if fits.is_empty() {
        return Err(PlanError::Parse {
            path: path.to_path_buf(),
            message: "no fits: the list is empty".into(),
        });
    }
    Ok(fits)
}

/// Converts and checks the grasps of a file against the fits' model names.
pub fn grasps_from_json(
    file: &GraspsFile,
    path: &Path,
    fits: &[ModelFit],
) -> Result<Vec<ExampleGrasp>, PlanError> {
    let mut grasps = Vec::with_capacity(file.grasps.len());
    for (i, g) in file.grasps.iter().enumerate() {
        let what = |field: &str| {
            format!(
                "{}: grasp {i} (model {}, task {}) {field}",
                path.display(),
                g.model,
                g.task
            )
        };
        let model =
            fits.iter()
                .position(|f| f.name == g.model)
                .ok_or_else(|| PlanError::Parse {
                    path: path.to_path_buf(),
                    message: format!("grasp {i} names model {:?}, which has no fit", g.model),
                })?;
        let pose = g
            .model_from_palm
            .to_pose(&what("model_from_palm"))
            .map_err(|e| PlanError::Parse {
                path: path.to_path_buf(),
                message: e.to_string(),
            })?;
        check_value(&what("q"), g.q, false)?;
        if !g.spread_rad.is_finite() {
            return Err(PlanError::BadValue {
                what: what("spread_rad"),
                value: g.spread_rad,
                problem: "must be finite",
            });
        }
        for (j, s) in g.sigma_m_rad.iter().enumerate() {
            check_value(&what(&format!("sigma_m_rad[{j}]")), *s, true)?;
        }
        grasps.push(ExampleGrasp {
            model,
            task: g.task.clone(),
            model_from_palm: params_from_pose(&pose),
            spread_rad: g.spread_rad,
            q: g.q,
            sigma: g.sigma_m_rad,
        });
    }
    if grasps.is_empty() {
        return Err(PlanError::Parse {
            path: path.to_path_buf(),
            message: "no grasps: the list is empty".into(),
        });
    }
    Ok(grasps)
}

/// Reads and checks a fits file.
pub fn read_fits(path: &Path) -> Result<Vec<ModelFit>, PlanError> {
    fits_from_json(&read_json(path)?, path)
}

/// Reads and checks a grasps file against the fits.
pub fn read_grasps(path: &Path, fits: &[ModelFit]) -> Result<Vec<ExampleGrasp>, PlanError> {
    grasps_from_json(&read_json(path)?, path, fits)
}

impl FitJson {
    /// The file entry of a fit.
    pub fn from_fit(fit: &ModelFit) -> FitJson {
        FitJson {
            name: fit.name.clone(),
            base_from_model: PoseJson::from(&fit.base_from_model),
            eps_m2: fit.eps_m2,
            sigma_m2: fit.sigma_m2,
        }
    }
}

impl GraspJson {
    /// The file entry of a grasp (`fits` gives the model's name).
    pub fn from_grasp(grasp: &ExampleGrasp, fits: &[ModelFit]) -> GraspJson {
        GraspJson {
            model: fits[grasp.model].name.clone(),
            task: grasp.task.clone(),
            model_from_palm: PoseJson::from(&crate::geometry::pose_from_params(
                &grasp.model_from_palm,
            )),
            spread_rad: grasp.spread_rad,
            q: grasp.q,
            sigma_m_rad: grasp.sigma,
        }
    }
}
