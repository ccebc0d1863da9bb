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
//! The fits may also be what `cell register --json` prints: an array with one entry
//! per model, `{"model", "status": "ok" | "failed", "reason", "target_from_model"
//! (4x4 rows; the target is in the base frame, so this is `base_from_model`), "eps",
//! "sigma", ...}`. Failed models are left out (and listed), as the planner leaves out
//! a model whose registration failed.
//!
//! Poses are [`PoseJson`] (`quat_xyzw` wins over `rpy`). A number written as `null`
//! (how JSON writers print NaN) reads as NaN and is reported by field.

use super::objective::check_value;
use super::{ExampleGrasp, ModelFit, PlanError};
use crate::geometry::{params_from_pose, PoseJson};
use crate::register::{ModelRegistration, RegistrationStatus};
use serde::{Deserialize, Deserializer, Serialize};
use std::path::Path;

/// A number that reads `null` as NaN, so that validation can name the field.
fn nullable_f64<'de, D: Deserializer<'de>>(d: D) -> Result<f64, D::Error> {
    Ok(Option::<f64>::deserialize(d)?.unwrap_or(f64::NAN))
}

fn nullable_matrix<'de, D: Deserializer<'de>>(d: D) -> Result<[[f64; 4]; 4], D::Error> {
    let rows: [[Option<f64>; 4]; 4] = Deserialize::deserialize(d)?;
    Ok(rows.map(|r| r.map(|x| x.unwrap_or(f64::NAN))))
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

/// One model's entry of `cell register --json` (fields the planner does not use,
/// such as the inlier fraction and timings, are ignored).
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct RegistrationLineJson {
    /// The model's name.
    pub model: String,
    /// `ok` or `failed`.
    pub status: String,
    /// Why the registration failed.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub reason: Option<String>,
    /// The model frame in the target's (= base) frame: a 4x4 homogeneous matrix as rows.
    #[serde(deserialize_with = "nullable_matrix")]
    pub target_from_model: [[f64; 4]; 4],
    /// Fitting error (m^2); `null` when the registration failed.
    #[serde(deserialize_with = "nullable_f64")]
    pub eps: f64,
    /// Standard deviation of the squared distances (m^2); `null` when failed.
    #[serde(deserialize_with = "nullable_f64")]
    pub sigma: f64,
}

/// A model left out of the fits because its registration failed.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Unregistered {
    /// The model.
    pub model: String,
    /// Why (the registration's reason).
    pub reason: String,
}

/// The fits read from a file, and the models whose registration had failed.
#[derive(Debug, Clone, PartialEq)]
pub struct FitsInput {
    /// One fit per registered model.
    pub fits: Vec<ModelFit>,
    /// Models of a `cell register --json` file that did not register.
    pub unregistered: Vec<Unregistered>,
}

impl FitsInput {
    /// The models that did not register, with their reasons: `name (reason), ...`.
    pub fn unregistered_text(&self) -> String {
        let failed: Vec<String> = self
            .unregistered
            .iter()
            .map(|u| format!("{} ({})", u.model, u.reason))
            .collect();
        failed.join(", ")
    }
}

impl ModelFit {
    /// The fit the planner uses from a registration (the target is in the base
    /// frame, so `base_from_model = target_from_model`); `None` when it failed.
    pub fn from_registration(r: &ModelRegistration) -> Option<ModelFit> {
        match r.status {
            RegistrationStatus::Ok => Some(ModelFit {
                name: r.model.clone(),
                base_from_model: r.target_from_model,
                eps_m2: r.eps_m2,
                sigma_m2: r.sigma_m2,
            }),
            RegistrationStatus::Failed(_) => None,
        }
    }
}

/// The planner's input from `registrations`: the fits of the models that registered,
/// and the others with the reasons they failed.
pub fn fits_input(registrations: &[ModelRegistration]) -> FitsInput {
    FitsInput {
        fits: registrations
            .iter()
            .filter_map(ModelFit::from_registration)
            .collect(),
        unregistered: registrations
            .iter()
            .filter_map(|r| match &r.status {
                RegistrationStatus::Failed(why) => Some(Unregistered {
                    model: r.model.clone(),
                    reason: why.clone(),
                }),
                RegistrationStatus::Ok => None,
            })
            .collect(),
    }
}

/// Largest deviation from a rigid transform accepted in a registration's matrix
/// (rotation orthonormality, bottom row), well above what printing 17 digits loses.
const RIGID_TOLERANCE: f64 = 1e-6;

/// Checks that `rows` is a finite rigid homogeneous transform; `what` names it.
fn rigid_from_rows(rows: &[[f64; 4]; 4], what: &str) -> Result<crate::geometry::Pose, PlanError> {
    for (r, row) in rows.iter().enumerate() {
        for (c, v) in row.iter().enumerate() {
            if !v.is_finite() {
                return Err(PlanError::BadValue {
                    what: format!("{what}[{r}][{c}]"),
                    value: *v,
                    problem: "must be a finite number",
                });
            }
        }
    }
    for (c, expected) in [0.0, 0.0, 0.0, 1.0].iter().enumerate() {
        if (rows[3][c] - expected).abs() > RIGID_TOLERANCE {
            return Err(PlanError::BadValue {
                what: format!("{what}[3][{c}]"),
                value: rows[3][c],
                problem: "the bottom row of a homogeneous transform must be 0 0 0 1",
            });
        }
    }
    let m = nalgebra::Matrix3::from_fn(|r, c| rows[r][c]);
    let off = (m.transpose() * m - nalgebra::Matrix3::identity())
        .abs()
        .max();
    if off > RIGID_TOLERANCE * 10.0 {
        return Err(PlanError::BadValue {
            what: format!("{what} rotation (largest |R^T R - I| entry)"),
            value: off,
            problem: "the rotation block must be orthonormal",
        });
    }
    let det = m.determinant();
    if det <= 0.0 {
        return Err(PlanError::BadValue {
            what: format!("{what} rotation determinant"),
            value: det,
            problem: "must be +1 (a rotation, not a reflection)",
        });
    }
    Ok(crate::geometry::pose_from_matrix_rows(rows))
}

/// Converts and checks the lines of `cell register --json` (`path` names the file
/// in errors): each `ok` model becomes a fit, each `failed` one is listed.
pub fn fits_from_registrations(
    lines: &[RegistrationLineJson],
    path: &Path,
) -> Result<FitsInput, PlanError> {
    let parse = |message: String| PlanError::Parse {
        path: path.to_path_buf(),
        message,
    };
    if lines.is_empty() {
        return Err(parse("no fits: the list of registrations is empty".into()));
    }
    let mut input = FitsInput {
        fits: Vec::new(),
        unregistered: Vec::new(),
    };
    for (i, l) in lines.iter().enumerate() {
        let what =
            |field: &str| format!("{}: registration {i} ({}) {field}", path.display(), l.model);
        if lines[..i].iter().any(|o| o.model == l.model) {
            return Err(parse(format!(
                "registration {i}: a model named {:?} appears twice",
                l.model
            )));
        }
        match l.status.as_str() {
            "ok" => {
                let base_from_model =
                    rigid_from_rows(&l.target_from_model, &what("target_from_model"))?;
                check_value(&what("eps"), l.eps, false)?;
                check_value(&what("sigma"), l.sigma, false)?;
                input.fits.push(ModelFit {
                    name: l.model.clone(),
                    base_from_model,
                    eps_m2: l.eps,
                    sigma_m2: l.sigma,
                });
            }
            "failed" => input.unregistered.push(Unregistered {
                model: l.model.clone(),
                reason: l.reason.clone().unwrap_or_else(|| "no reason given".into()),
            }),
            other => {
                return Err(parse(format!(
                    "registration {i} ({}): status {other:?} is neither \"ok\" nor \"failed\"",
                    l.model
                )))
            }
        }
    }
    if input.fits.is_empty() {
        return Err(parse(format!(
            "no fits: no model registered: {}",
            input.unregistered_text()
        )));
    }
    Ok(input)
}

fn read_json<T: serde::de::DeserializeOwned>(path: &Path) -> Result<T, PlanError> {
    let text = crate::fsio::read_to_string(path)?;
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
            preshape_rad: crate::robot::PreshapeRad::OPEN,
            max_overtravel_m: None,
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

/// Reads and checks a fits file: `{"fits": [...]}` or the array `cell register
/// --json` prints.
pub fn read_fits_input(path: &Path) -> Result<FitsInput, PlanError> {
    let value: serde_json::Value = read_json(path)?;
    let parse = |e: serde_json::Error| PlanError::Parse {
        path: path.to_path_buf(),
        message: e.to_string(),
    };
    if value.is_array() {
        let lines: Vec<RegistrationLineJson> = serde_json::from_value(value).map_err(parse)?;
        fits_from_registrations(&lines, path)
    } else if value.is_object() {
        let file: FitsFile = serde_json::from_value(value).map_err(parse)?;
        Ok(FitsInput {
            fits: fits_from_json(&file, path)?,
            unregistered: Vec::new(),
        })
    } else {
        Err(PlanError::Parse {
            path: path.to_path_buf(),
            message: "expected {\"fits\": [...]} or the array of `cell register --json`".into(),
        })
    }
}

/// Reads and checks a fits file (either format; see [`read_fits_input`]).
pub fn read_fits(path: &Path) -> Result<Vec<ModelFit>, PlanError> {
    Ok(read_fits_input(path)?.fits)
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::{matrix_rows, pose_error, pose_from_params};

    fn line(model: &str, status: &str, pose: &[f64; 6], eps: f64) -> RegistrationLineJson {
        RegistrationLineJson {
            model: model.into(),
            status: status.into(),
            reason: (status == "failed").then(|| "too few inliers".into()),
            target_from_model: matrix_rows(&pose_from_params(pose)),
            eps,
            sigma: eps / 2.0,
        }
    }

    #[test]
    fn registrations_become_fits_and_failures_are_listed() {
        let pose = [0.6, -0.1, 0.0, 0.0, 0.0, 2.5];
        let lines = vec![
            line("mug_000", "ok", &pose, 2e-6),
            line("mug_001", "failed", &[0.0; 6], f64::NAN),
            line("mug_002", "ok", &[0.5, 0.0, 0.0, 0.0, 0.0, -1.0], 9e-6),
        ];
        let input = fits_from_registrations(&lines, Path::new("r.json")).unwrap();
        assert_eq!(input.fits.len(), 2);
        assert_eq!(input.fits[0].name, "mug_000");
        assert_eq!(input.fits[1].name, "mug_002");
        assert_eq!(input.fits[1].eps_m2, 9e-6);
        assert_eq!(input.fits[1].sigma_m2, 4.5e-6);
        let (dp, dr) = pose_error(&input.fits[0].base_from_model, &pose_from_params(&pose));
        assert!(dp < 1e-12 && dr < 1e-9, "{dp} {dr}");
        assert_eq!(
            input.unregistered,
            vec![Unregistered {
                model: "mug_001".into(),
                reason: "too few inliers".into()
            }]
        );
    }

    #[test]
    fn bad_registrations_name_the_file_model_and_field() {
        let path = Path::new("reg.json");
        let err = |lines: Vec<RegistrationLineJson>| {
            fits_from_registrations(&lines, path)
                .unwrap_err()
                .to_string()
        };
        let e = err(vec![line("mug_003", "ok", &[0.0; 6], f64::NAN)]);
        assert!(
            e.contains("reg.json") && e.contains("(mug_003) eps") && e.contains("NaN"),
            "{e}"
        );
        let mut l = line("mug_003", "ok", &[0.0; 6], 1e-6);
        l.target_from_model[1][3] = f64::NAN;
        let e = err(vec![l]);
        assert!(e.contains("target_from_model[1][3]"), "{e}");
        let mut l = line("mug_003", "ok", &[0.0; 6], 1e-6);
        l.target_from_model[0][0] = 2.0;
        let e = err(vec![l]);
        assert!(e.contains("orthonormal"), "{e}");
        let mut l = line("mug_003", "ok", &[0.0; 6], 1e-6);
        l.target_from_model[2][2] = -1.0;
        l.target_from_model[1][1] = 1.0;
        let e = err(vec![l]);
        assert!(e.contains("determinant"), "{e}");
        let e = err(vec![line("mug_003", "maybe", &[0.0; 6], 1e-6)]);
        assert!(e.contains("\"maybe\""), "{e}");
        let e = err(vec![line("mug_003", "failed", &[0.0; 6], f64::NAN)]);
        assert!(
            e.contains("no model registered") && e.contains("mug_003 (too few inliers)"),
            "{e}"
        );
        let e = err(vec![
            line("mug_003", "ok", &[0.0; 6], 1e-6),
            line("mug_003", "ok", &[0.0; 6], 1e-6),
        ]);
        assert!(e.contains("twice"), "{e}");
        assert!(err(Vec::new()).contains("empty"));
    }
}
