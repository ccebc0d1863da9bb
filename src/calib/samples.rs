//! Calibration samples and the sample file (`calib/samples-DATE.json`).

use super::CalibError;
use crate::fsio::{FileError, FileOp};
use crate::geometry::{GeometryError, Pose, PoseJson};
use nalgebra::{Point3, Quaternion, UnitQuaternion};
use serde::{Deserialize, Serialize};
use std::path::Path;

/// Quaternions in files must have a norm within this of 1.
const QUAT_NORM_TOLERANCE: f64 = 1e-3;
/// `rpy` and `quat_xyzw` given together must agree within this (rad).
const RPY_QUAT_TOLERANCE_RAD: f64 = 1e-3;
/// A sample file must hold at least this many samples.
pub(super) const MIN_SAMPLES: usize = 3;

/// A sample with a full target pose (e.g. a board).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PoseSample {
    /// The flange pose from forward kinematics.
    pub base_from_flange: Pose,
    /// The target pose seen by the camera.
    pub camera_from_target: Pose,
}

/// A sample with a target point only (e.g. a sphere centre from the depth cloud).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PointSample {
    /// The flange pose from forward kinematics.
    pub base_from_flange: Pose,
    /// The target point in the camera frame (m).
    pub target_point_camera_m: Point3<f64>,
}

/// One calibration sample: a robot pose and what the camera saw at it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Sample {
    /// Full target pose.
    Pose(PoseSample),
    /// Target point only.
    Point(PointSample),
}

impl Sample {
    /// The flange pose.
    pub fn base_from_flange(&self) -> &Pose {
        match self {
            Sample::Pose(s) => &s.base_from_flange,
            Sample::Point(s) => &s.base_from_flange,
        }
    }

    /// The target origin in the camera frame (the pose's translation, or the point).
    pub fn target_point_camera(&self) -> Point3<f64> {
        match self {
            Sample::Pose(s) => Point3::from(s.camera_from_target.translation.vector),
            Sample::Point(s) => s.target_point_camera_m,
        }
    }

    /// The sample as a point sample (a pose sample contributes its target origin).
    pub fn as_point_sample(&self) -> PointSample {
        PointSample {
            base_from_flange: *self.base_from_flange(),
            target_point_camera_m: self.target_point_camera(),
        }
    }

    /// Fails on the first NaN or infinite number (`index` names the sample).
    pub fn check_finite(&self, index: usize) -> Result<(), CalibError> {
        let flange = pose_numbers(self.base_from_flange());
        let (field, values): (&'static str, Vec<f64>) = match self {
            Sample::Pose(s) => ("camera_from_target", pose_numbers(&s.camera_from_target)),
            Sample::Point(s) => (
                "target_point_camera_m",
                s.target_point_camera_m.coords.iter().copied().collect(),
            ),
        };
        for (field, values) in [("base_from_flange", flange), (field, values)] {
            if let Some(value) = values.iter().copied().find(|v| !v.is_finite()) {
                return Err(CalibError::NotFinite {
                    index,
                    field,
                    value,
                });
            }
        }
        Ok(())
    }
}

fn pose_numbers(pose: &Pose) -> Vec<f64> {
    let q = pose.rotation.quaternion();
    let t = pose.translation.vector;
    vec![t.x, t.y, t.z, q.i, q.j, q.k, q.w]
}

/// The samples of one calibration run, as stored in a sample file.
#[derive(Debug, Clone, PartialEq)]
pub struct SampleFile {
    /// When the samples were captured (RFC 3339, UTC).
    pub created: String,
    /// Free text: where the samples come from.
    pub comment: Option<String>,
    /// The samples, in capture order.
    pub samples: Vec<Sample>,
}

/// The file's top level; samples are decoded one by one to name the bad one.
#[derive(Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct FileJson<S> {
    created: String,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    comment: Option<String>,
    samples: Vec<S>,
}

#[derive(Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct SampleJson {
    base_from_flange: PoseJson,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    camera_from_target: Option<PoseJson>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    target_point_camera_m: Option<[f64; 3]>,
}

impl SampleFile {
    /// Reads and validates a sample file (see the module doc for the format).
    pub fn load(path: &Path) -> Result<SampleFile, CalibError> {
        let text = crate::fsio::read_to_string(path)?;
        Self::parse(&text, path)
    }

    /// Parses and validates the text of a sample file (`path` names it in errors).
    pub fn parse(text: &str, path: &Path) -> Result<SampleFile, CalibError> {
        let file: FileJson<serde_json::Value> =
            serde_json::from_str(text).map_err(|e| CalibError::Parse {
                path: path.to_path_buf(),
                message: json_message(&e, text),
            })?;
        let bad = |index: usize, problem: String| CalibError::BadSample {
            path: path.to_path_buf(),
            index,
            problem,
        };
        let mut samples = Vec::with_capacity(file.samples.len());
        for (index, value) in file.samples.into_iter().enumerate() {
            let json: SampleJson =
                serde_json::from_value(value).map_err(|e| bad(index, e.to_string()))?;
            let base_from_flange = pose_from_json(&json.base_from_flange, "base_from_flange")
                .map_err(|p| bad(index, p.to_string()))?;
            let sample = match (json.camera_from_target, json.target_point_camera_m) {
                (Some(pose), None) => Sample::Pose(PoseSample {
                    base_from_flange,
                    camera_from_target: pose_from_json(&pose, "camera_from_target")
                        .map_err(|p| bad(index, p.to_string()))?,
                }),
                (None, Some(p)) => {
                    if let Some(v) = p.iter().find(|v| !v.is_finite()) {
                        return Err(bad(
                            index,
                            format!("target_point_camera_m: {v} is not a finite number"),
                        ));
                    }
                    Sample::Point(PointSample {
                        base_from_flange,
                        target_point_camera_m: Point3::from(p),
                    })
                }
                (Some(_), Some(_)) => {
                    return Err(bad(
                        index,
                        "has both camera_from_target and target_point_camera_m; give one".into(),
                    ))
                }
                (None, None) => {
                    return Err(bad(
                        index,
                        "has neither camera_from_target nor target_point_camera_m".into(),
                    ))
                }
            };
            samples.push(sample);
        }
        if samples.len() < MIN_SAMPLES {
            return Err(CalibError::Parse {
                path: path.to_path_buf(),
                message: format!(
                    "{} samples, need at least {MIN_SAMPLES}: capture more poses (10–30 are typical)",
                    samples.len()
                ),
            });
        }
        Ok(SampleFile {
            created: file.created,
            comment: file.comment,
            samples,
        })
    }

    /// The file's JSON text.
    pub fn to_json(&self) -> String {
        let samples = self
            .samples
            .iter()
            .map(|s| match s {
                Sample::Pose(p) => SampleJson {
                    base_from_flange: PoseJson::from(&p.base_from_flange),
                    camera_from_target: Some(PoseJson::from(&p.camera_from_target)),
                    target_point_camera_m: None,
                },
                Sample::Point(p) => SampleJson {
                    base_from_flange: PoseJson::from(&p.base_from_flange),
                    camera_from_target: None,
                    target_point_camera_m: Some(p.target_point_camera_m.coords.into()),
                },
            })
            .collect();
        let file = FileJson {
            created: self.created.clone(),
            comment: self.comment.clone(),
            samples,
        };
        // Plain data of strings and finite numbers: serialisation cannot fail.
        serde_json::to_string_pretty(&file).unwrap_or_default() + "\n"
    }

    /// Writes the file atomically (temporary file, then rename).
    pub fn save(&self, path: &Path) -> Result<(), CalibError> {
        crate::fsio::create_parent_dir(path)
            .and_then(|()| crate::fsio::write_atomically(path, self.to_json().as_bytes()))
            .map_err(|source| FileError::new(FileOp::Write, path, source).into())
    }
}

/// A message for a JSON syntax error, with a hint for NaN/Infinity (not JSON).
fn json_message(e: &serde_json::Error, text: &str) -> String {
    let mut message = e.to_string();
    if e.line() > 0 {
        let rest = text
            .lines()
            .nth(e.line() - 1)
            .and_then(|l| l.get(e.column().saturating_sub(1)..))
            .unwrap_or("");
        let rest = rest.trim_start_matches('-');
        if rest.starts_with("NaN") || rest.starts_with("Infinity") || rest.starts_with("inf") {
            message.push_str(": a non-finite number (NaN/Infinity) in the samples; remove or re-capture that sample");
        }
    }
    message
}

/// Why a pose of a samples or result file is refused; each names the pose.
#[derive(Debug, PartialEq, thiserror::Error)]
pub(super) enum BadPose {
    /// Not finite, or the wrong number of values.
    #[error(transparent)]
    Geometry(#[from] GeometryError),
    /// `quat_xyzw` is not a unit quaternion.
    #[error("{what}: quat_xyzw {quat_xyzw:?} has norm {norm:.4}, not 1: is it a unit quaternion in x y z w order?")]
    NotUnit {
        /// The pose.
        what: String,
        /// The quaternion given.
        quat_xyzw: [f64; 4],
        /// Its norm.
        norm: f64,
    },
    /// `rpy` and `quat_xyzw` are both given and name different rotations.
    #[error(
        "{what}: rpy {rpy:?} and quat_xyzw {quat_xyzw:?} disagree by {:.3}°: give one, or check the quaternion order (x y z w) and that rpy is fixed-axis X-Y-Z in radians",
        .angle_rad.to_degrees()
    )]
    Disagree {
        /// The pose.
        what: String,
        /// The roll, pitch, yaw given (rad).
        rpy: [f64; 3],
        /// The quaternion given.
        quat_xyzw: [f64; 4],
        /// The angle between the two rotations (rad).
        angle_rad: f64,
    },
    /// Neither `rpy` nor `quat_xyzw`.
    #[error("{what}: no rotation (give rpy or quat_xyzw)")]
    NoRotation {
        /// The pose.
        what: String,
    },
}

/// A validated pose: finite, with a rotation, a unit quaternion, `rpy` and
/// `quat_xyzw` agreeing when both are given. The error names `what`.
pub(super) fn pose_from_json(json: &PoseJson, what: &str) -> Result<Pose, BadPose> {
    let pose = json.to_pose(what)?;
    if let Some(q) = json.quat_xyzw {
        let norm = Quaternion::new(q[3], q[0], q[1], q[2]).norm();
        if (norm - 1.0).abs() > QUAT_NORM_TOLERANCE {
            return Err(BadPose::NotUnit {
                what: what.to_string(),
                quat_xyzw: q,
                norm,
            });
        }
        if let Some(r) = json.rpy {
            let from_rpy = UnitQuaternion::from_euler_angles(r[0], r[1], r[2]);
            let angle = from_rpy.angle_to(&pose.rotation);
            if angle > RPY_QUAT_TOLERANCE_RAD {
                return Err(BadPose::Disagree {
                    what: what.to_string(),
                    rpy: r,
                    quat_xyzw: q,
                    angle_rad: angle,
                });
            }
        }
    } else if json.rpy.is_none() {
        return Err(BadPose::NoRotation {
            what: what.to_string(),
        });
    }
    Ok(pose)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::{pose_error, pose_from_params};

    fn parse(text: &str) -> Result<SampleFile, CalibError> {
        SampleFile::parse(text, Path::new("s.json"))
    }

    const FLANGE: &str = r#"{"xyz": [0.5, 0.0, 0.4], "rpy": [3.0, 0.1, 0.2]}"#;

    fn file_with(samples: &[String]) -> String {
        format!(
            r#"{{"created": "now", "samples": [{}]}}"#,
            samples.join(",")
        )
    }

    fn point_sample(p: &str) -> String {
        format!(r#"{{"base_from_flange": {FLANGE}, "target_point_camera_m": {p}}}"#)
    }

    #[test]
    fn json_round_trip_keeps_samples() {
        let a = pose_from_params(&[0.5, 0.1, 0.4, 3.0, 0.2, -0.4]);
        let b = pose_from_params(&[0.1, -0.05, 0.9, 2.8, -0.1, 1.0]);
        let file = SampleFile {
            created: "2025-01-01T00:00:00Z".into(),
            comment: Some("test".into()),
            samples: vec![
                Sample::Pose(PoseSample {
                    base_from_flange: a,
                    camera_from_target: b,
                }),
                Sample::Point(PointSample {
                    base_from_flange: b,
                    target_point_camera_m: Point3::new(0.1, 0.2, 1.1),
                }),
                Sample::Pose(PoseSample {
                    base_from_flange: b,
                    camera_from_target: a,
                }),
            ],
        };
        let back = parse(&file.to_json()).unwrap();
        assert_eq!(back.created, file.created);
        assert_eq!(back.comment, file.comment);
        assert_eq!(back.samples.len(), 3);
        for (x, y) in file.samples.iter().zip(&back.samples) {
            let (dp, dr) = pose_error(x.base_from_flange(), y.base_from_flange());
            assert!(dp < 1e-12 && dr < 1e-9);
            assert!((x.target_point_camera() - y.target_point_camera()).norm() < 1e-12);
            if let (Sample::Pose(x), Sample::Pose(y)) = (x, y) {
                let (dp, dr) = pose_error(&x.camera_from_target, &y.camera_from_target);
                assert!(dp < 1e-12 && dr < 1e-9);
            }
        }
    }

    #[test]
    fn bad_samples_name_the_index() {
        let good = point_sample("[0.1, 0.2, 1.0]");
        let cases = [
            (point_sample("[0.1, null, 1.0]"), "sample 2: invalid type: null"),
            (
                format!(r#"{{"base_from_flange": {FLANGE}}}"#),
                "sample 2: has neither",
            ),
            (
                format!(
                    r#"{{"base_from_flange": {FLANGE}, "target_point_camera_m": [0,0,1], "camera_from_target": {FLANGE}}}"#
                ),
                "sample 2: has both",
            ),
            (
                r#"{"base_from_flange": {"xyz": [0,0,0], "quat_xyzw": [0, 0, 0, 0.5]}, "target_point_camera_m": [0,0,1]}"#
                    .to_string(),
                "sample 2: base_from_flange: quat_xyzw [0.0, 0.0, 0.0, 0.5] has norm 0.5000",
            ),
            (
                r#"{"base_from_flange": {"xyz": [0,0,0], "rpy": [0, 0, 0], "quat_xyzw": [1, 0, 0, 0]}, "target_point_camera_m": [0,0,1]}"#
                    .to_string(),
                "disagree by 180.000°",
            ),
            (
                r#"{"base_from_flange": {"xyz": [0,0,0]}, "target_point_camera_m": [0,0,1]}"#.to_string(),
                "sample 2: base_from_flange: no rotation",
            ),
            (
                format!(r#"{{"base_from_flange": {FLANGE}, "target_point_m": [0,0,1]}}"#),
                "sample 2: unknown field `target_point_m`",
            ),
        ];
        for (bad, want) in cases {
            let text = file_with(&[good.clone(), good.clone(), bad, good.clone()]);
            let err = parse(&text).unwrap_err().to_string();
            assert!(err.starts_with("s.json: "), "{err}");
            assert!(err.contains(want), "{err} lacks {want}");
        }
    }

    #[test]
    fn nan_too_few_and_syntax_are_reported() {
        let good = point_sample("[0.1, 0.2, 1.0]");
        let err = parse(&file_with(&[good.clone(), good.clone()]))
            .unwrap_err()
            .to_string();
        assert!(err.contains("2 samples, need at least 3"), "{err}");
        let err = parse(&file_with(&[
            good.clone(),
            good.clone(),
            point_sample("[NaN, 0, 1]"),
        ]))
        .unwrap_err()
        .to_string();
        assert!(
            err.starts_with("s.json: ") && err.contains("NaN/Infinity"),
            "{err}"
        );
        let err = parse(r#"{"created": "x", "samples": [], "extra": 1}"#)
            .unwrap_err()
            .to_string();
        assert!(err.contains("unknown field `extra`"), "{err}");
    }

    #[test]
    fn in_memory_nan_is_named() {
        let s = Sample::Point(PointSample {
            base_from_flange: Pose::identity(),
            target_point_camera_m: Point3::new(0.0, f64::NAN, 1.0),
        });
        let err = s.check_finite(7).unwrap_err().to_string();
        assert!(
            err.starts_with("sample 7: target_point_camera_m holds a non-finite value (NaN)"),
            "{err}"
        );
    }
}
