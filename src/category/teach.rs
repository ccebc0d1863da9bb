//! The teach-in file (`grasps.toml`): per training model, the task-labelled example
//! grasps a user recorded, as the palm pose in the model's frame and the spread.
//!
//! ```toml
//! category = "mug"          # optional; must match `cell train --category`
//! table_height_m = 0.0      # optional: the table top in the models' frame
//!
//! [[model]]
//! mesh = "mug_000.obj"      # relative to `cell train --models DIR`
//! name = "mug_000"          # optional; the file stem by default
//!
//! [[model.grasp]]
//! name = "mug_000/top"      # unique over the file
//! task = "top"
//! pose = { xyz = [0.0, 0.0, 0.155], rpy = [3.14159, 0.0, 1.0472] }
//! spread_rad = 1.0472       # optional, 0 by default
//! preshape_rad = 0.0        # optional: each finger's flex before the approach (rad),
//!                           # one value or three [F1, F2, F3]; 0 (open) by default
//! max_overtravel_m = 0.0    # optional: how far beyond `pose` the approach to contact
//!                           # may go (m); the cell's approach.max_overtravel_m by default
//! ```
//!
//! A pre-shape (fingers partly closed before the approach) is what a tool lying
//! flat on the table needs: the open fingers would meet the table first. An
//! overtravel of 0 is what a fingertip pinch taught with the palm clear of the
//! object needs (a mug's top grasp by the rim): going on to contact would bring the
//! palm down on the rim, and the fingers would sweep past a short mug's body.

use super::CategoryError;
use crate::geometry::{params_from_pose, Pose, PoseJson, PoseParams};
use crate::mesh::procedural::Category;
use crate::quality::approach::overtravel_problem;
use crate::robot::hand::HandModel;
use crate::robot::PreshapeRad;
use serde::{Deserialize, Serialize};
use std::collections::HashSet;
use std::path::{Path, PathBuf};

/// The whole teach-in file.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TeachFile {
    /// The category the grasps are for.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub category: Option<Category>,
    /// Height of the table top in the models' frame (m); when given, the table is an
    /// obstacle while the hand closes.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub table_height_m: Option<f64>,
    /// The models and their grasps.
    #[serde(rename = "model", default)]
    pub models: Vec<TeachModel>,
}

/// One training model and its example grasps.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TeachModel {
    /// Mesh file (OBJ, STL or PLY), relative to the models directory.
    pub mesh: PathBuf,
    /// The model's name in the database (the mesh file's stem by default).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub name: Option<String>,
    /// The example grasps.
    #[serde(rename = "grasp", default)]
    pub grasps: Vec<TeachGrasp>,
}

/// One example grasp.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TeachGrasp {
    /// A name unique over the file; errors name the grasp by it.
    pub name: String,
    /// The task the grasp serves (one of the category's tasks).
    pub task: String,
    /// Palm (`bh_palm`) pose in the model's frame.
    pub pose: PoseJson,
    /// Spread of F1 and F2 (rad).
    #[serde(default)]
    pub spread_rad: f64,
    /// Each finger's flex before the approach (rad); open by default.
    #[serde(default, skip_serializing_if = "PreshapeRad::is_open")]
    pub preshape_rad: PreshapeRad,
    /// How far beyond `pose` the approach to contact may go (m); the cell's
    /// `approach.max_overtravel_m` when absent.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub max_overtravel_m: Option<f64>,
}

impl TeachModel {
    /// The model's name: `name`, else the mesh file's stem.
    pub fn name(&self) -> String {
        self.name.clone().unwrap_or_else(|| {
            self.mesh
                .file_stem()
                .map(|s| s.to_string_lossy().into_owned())
                .unwrap_or_default()
        })
    }
}

/// A grasp of the teach file, checked and resolved.
#[derive(Debug, Clone, PartialEq)]
pub struct CheckedGrasp {
    /// Its name.
    pub name: String,
    /// Index of its model in the file.
    pub model: usize,
    /// Its task.
    pub task: String,
    /// Palm pose in the model's frame.
    pub pose: Pose,
    /// The same as parameters `[x, y, z, ax, ay, az]`.
    pub params: PoseParams,
    /// Spread (rad).
    pub spread_rad: f64,
    /// Pre-shape: each finger's flex before the approach (rad).
    pub preshape_rad: PreshapeRad,
    /// Its own overtravel of the approach (m), if it names one.
    pub max_overtravel_m: Option<f64>,
}

impl TeachFile {
    /// Reads and parses `path`.
    pub fn load(path: &Path) -> Result<TeachFile, CategoryError> {
        let text = crate::fsio::read_to_string(path)?;
        Self::parse_text(&text, path)
    }

    /// Parses teach-in `text` read from `path` (which names it in errors).
    pub fn parse_text(text: &str, path: &Path) -> Result<TeachFile, CategoryError> {
        toml::from_str(text).map_err(|e| CategoryError::Parse {
            path: path.to_path_buf(),
            message: e.to_string().trim_end().replace('\n', " "),
        })
    }

    /// The file as TOML text, after a comment `header` (each line prefixed `# `),
    /// poses as inline tables so that each grasp reads as one block.
    pub fn to_toml(&self, header: &str) -> String {
        let string = |s: &str| toml::Value::String(s.to_string()).to_string();
        let float = |x: f64| toml::Value::Float(x).to_string();
        let list = |v: &[f64]| {
            let items: Vec<String> = v.iter().map(|&x| float(x)).collect();
            format!("[{}]", items.join(", "))
        };
        let mut text: String = header.lines().map(|l| format!("# {l}\n")).collect();
        if let Some(c) = self.category {
            text += &format!("\ncategory = {}\n", string(c.name()));
        }
        if let Some(h) = self.table_height_m {
            text += &format!("table_height_m = {}\n", float(h));
        }
        for m in &self.models {
            text += &format!(
                "\n[[model]]\nmesh = {}\n",
                string(&m.mesh.to_string_lossy())
            );
            if let Some(n) = &m.name {
                text += &format!("name = {}\n", string(n));
            }
            for g in &m.grasps {
                let mut pose = format!("xyz = {}", list(&g.pose.xyz));
                if let Some(r) = g.pose.rpy {
                    pose += &format!(", rpy = {}", list(&r));
                }
                if let Some(q) = g.pose.quat_xyzw {
                    pose += &format!(", quat_xyzw = {}", list(&q));
                }
                text += &format!(
                    "\n[[model.grasp]]\nname = {}\ntask = {}\npose = {{ {pose} }}\nspread_rad = {}\n",
                    string(&g.name),
                    string(&g.task),
                    float(g.spread_rad)
                );
                if !g.preshape_rad.is_open() {
                    let [a, b, c] = g.preshape_rad.0;
                    text += &if a == b && b == c {
                        format!("preshape_rad = {}\n", float(a))
                    } else {
                        format!("preshape_rad = {}\n", list(&g.preshape_rad.0))
                    };
                }
                if let Some(m) = g.max_overtravel_m {
                    text += &format!("max_overtravel_m = {}\n", float(m));
                }
            }
        }
        text
    }

    /// Checks names, tasks, poses and models against `category`, with mesh files
    /// under `models_dir`; returns the grasps in file order (a file of models
    /// without grasps, e.g. test objects, is valid). `hand`'s joint ranges bound
    /// the spread and the pre-shape.
    pub fn check(
        &self,
        category: Category,
        models_dir: &Path,
        hand: &HandModel,
    ) -> Result<Vec<CheckedGrasp>, CategoryError> {
        let spread_limits_rad = hand.spread_limits_rad;
        let flex_limits_rad = hand.flex_limits_rad();
        if let Some(c) = self.category {
            if c != category {
                return Err(CategoryError::CategoryMismatch {
                    file: c,
                    asked: category,
                });
            }
        }
        if let Some(h) = self.table_height_m {
            if !h.is_finite() {
                return Err(CategoryError::Invalid {
                    what: "teach file".into(),
                    field: "table_height_m".into(),
                    value: h.to_string(),
                    problem: "must be finite".into(),
                });
            }
        }
        let tasks = super::tasks_of(category);
        let mut model_names = HashSet::new();
        let mut grasp_names = HashSet::new();
        let mut out = Vec::new();
        for (m, model) in self.models.iter().enumerate() {
            let model_name = model.name();
            if model_name.is_empty() || !model_names.insert(model_name.clone()) {
                return Err(CategoryError::DuplicateName {
                    what: "model",
                    name: model_name,
                });
            }
            let mesh_path = models_dir.join(&model.mesh);
            if model.grasps.is_empty() && !mesh_path.is_file() {
                return Err(CategoryError::MissingModel {
                    grasp: "(none)".into(),
                    model: model_name,
                    path: mesh_path,
                });
            }
            for g in &model.grasps {
                if g.name.is_empty() || !grasp_names.insert(g.name.clone()) {
                    return Err(CategoryError::DuplicateName {
                        what: "grasp",
                        name: g.name.clone(),
                    });
                }
                if !mesh_path.is_file() {
                    return Err(CategoryError::MissingModel {
                        grasp: g.name.clone(),
                        model: model_name.clone(),
                        path: mesh_path,
                    });
                }
                if !tasks.contains(&g.task.as_str()) {
                    return Err(CategoryError::UnknownTask {
                        grasp: g.name.clone(),
                        task: g.task.clone(),
                        category,
                        known: tasks.join(", "),
                    });
                }
                let pose = g.pose.to_pose(&g.name).map_err(|e| CategoryError::Grasp {
                    grasp: g.name.clone(),
                    problem: e.to_string(),
                })?;
                let (lo, hi) = spread_limits_rad;
                if !(g.spread_rad >= lo && g.spread_rad <= hi) {
                    return Err(CategoryError::Grasp {
                        grasp: g.name.clone(),
                        problem: format!(
                            "spread_rad = {} is outside [{lo}, {hi}] rad",
                            g.spread_rad
                        ),
                    });
                }
                if let Some(problem) = g
                    .preshape_rad
                    .problem(flex_limits_rad)
                    .or_else(|| overtravel_problem(g.max_overtravel_m))
                {
                    return Err(CategoryError::Grasp {
                        grasp: g.name.clone(),
                        problem,
                    });
                }
                out.push(CheckedGrasp {
                    name: g.name.clone(),
                    model: m,
                    task: g.task.clone(),
                    params: params_from_pose(&pose),
                    pose,
                    spread_rad: g.spread_rad,
                    preshape_rad: g.preshape_rad,
                    max_overtravel_m: g.max_overtravel_m,
                });
            }
        }
        if self.models.is_empty() {
            return Err(CategoryError::Invalid {
                what: "teach file".into(),
                field: "model".into(),
                value: "[]".into(),
                problem: "lists no models".into(),
            });
        }
        Ok(out)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn parse(text: &str) -> Result<TeachFile, toml::de::Error> {
        toml::from_str(text)
    }

    #[test]
    fn the_documented_example_parses_and_names_default_to_the_stem() {
        let file = parse(
            r#"
            category = "mug"
            [[model]]
            mesh = "sub/mug_000.obj"
            [[model.grasp]]
            name = "mug_000/top"
            task = "top"
            pose = { xyz = [0.0, 0.0, 0.155], rpy = [3.14159, 0.0, 1.0472] }
            spread_rad = 1.0472
            "#,
        )
        .unwrap();
        assert_eq!(file.models[0].name(), "mug_000");
        assert_eq!(file.models[0].grasps[0].task, "top");
        let round: TeachFile = toml::from_str(&file.to_toml("a\nb")).unwrap();
        assert_eq!(round, file);
        assert!(parse("[[model]]\nmesh = \"a.obj\"\ncolour = 1\n")
            .unwrap_err()
            .to_string()
            .contains("colour"));
    }

    #[test]
    fn a_preshape_is_one_flex_or_three_and_out_of_range_names_the_grasp() {
        let text = |preshape: &str| {
            format!(
                "[[model]]\nmesh = \"h.obj\"\n[[model.grasp]]\nname = \"h/use\"\ntask = \"use\"\n\
                 pose = {{ xyz = [0.0, 0.0, 0.2], rpy = [3.14159, 0.0, 0.0] }}\n{preshape}"
            )
        };
        let grasp = |preshape: &str| parse(&text(preshape)).unwrap().models[0].grasps[0].clone();
        assert_eq!(grasp("").preshape_rad, PreshapeRad::OPEN);
        assert_eq!(
            grasp("preshape_rad = 1.2").preshape_rad,
            PreshapeRad([1.2; 3])
        );
        assert_eq!(
            grasp("preshape_rad = [1.0, 1.1, 1.2]").preshape_rad,
            PreshapeRad([1.0, 1.1, 1.2])
        );
        assert!(parse(&text("preshape_rad = [1.0, 1.1]"))
            .unwrap_err()
            .to_string()
            .contains("preshape_rad"));
        // Written back as it was given; open grasps write nothing.
        for given in ["preshape_rad = 1.2", "preshape_rad = [1.0, 1.1, 1.2]", ""] {
            let file = parse(&text(given)).unwrap();
            let written = file.to_toml("");
            assert_eq!(
                written.contains("preshape_rad"),
                !given.is_empty(),
                "{written}"
            );
            assert_eq!(parse(&written).unwrap(), file);
        }
        // Out of the flex range: the grasp and the finger are named.
        let dir = crate::fsio::TempDir::new("teach-preshape").unwrap();
        std::fs::write(dir.join("h.obj"), "").unwrap();
        let robot = crate::robot::shipped_robot();
        let hand =
            HandModel::from_description(&robot.description, "bh_palm", Path::new("x")).unwrap();
        // So is a grasp's own overtravel out of range.
        for (bad, field) in [
            ("preshape_rad = 2.5", "preshape_rad"),
            ("preshape_rad = [0.0, -0.1, 0.0]", "preshape_rad"),
            ("preshape_rad = nan", "preshape_rad"),
            ("max_overtravel_m = -0.01", "max_overtravel_m"),
            ("max_overtravel_m = nan", "max_overtravel_m"),
        ] {
            let err = parse(&text(bad))
                .unwrap()
                .check(Category::Hammer, &dir, &hand)
                .unwrap_err()
                .to_string();
            assert!(err.contains("h/use") && err.contains(field), "{bad}: {err}");
        }
        parse(&text("preshape_rad = 1.2"))
            .unwrap()
            .check(Category::Hammer, &dir, &hand)
            .unwrap();
        // A grasp's own overtravel: optional, written back, checked.
        let given = "max_overtravel_m = 0.0";
        let file = parse(&text(given)).unwrap();
        assert_eq!(file.models[0].grasps[0].max_overtravel_m, Some(0.0));
        assert!(file.to_toml("").contains(given));
        assert_eq!(parse(&file.to_toml("")).unwrap(), file);
        let checked = file.check(Category::Hammer, &dir, &hand).unwrap();
        assert_eq!(checked[0].max_overtravel_m, Some(0.0));
        assert_eq!(grasp("").max_overtravel_m, None);
    }
}
