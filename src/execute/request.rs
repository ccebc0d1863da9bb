//! What the executor is asked to do: one grasp, as the planner chose it.

use crate::geometry::{check_finite, Pose, PoseJson};
use crate::hw::fri::JOINTS;
use crate::plan::PlannedGrasp;
use crate::quality::approach::overtravel_problem;
use crate::robot::PreshapeRad;
use serde::{Deserialize, Serialize};
use std::f64::consts::PI;
use std::path::Path;

/// Errors of reading or validating a request; each names the field.
#[derive(Debug, thiserror::Error)]
pub enum RequestError {
    /// The file could not be read.
    #[error("cannot read plan {}: {}", .0.path.display(), .0.source)]
    Read(crate::fsio::FileError),
    /// The JSON does not match the schema.
    #[error("plan {path}: {message}")]
    Parse {
        /// The file.
        path: std::path::PathBuf,
        /// The parser's message, with line and column.
        message: String,
    },
    /// A value is not usable.
    #[error("plan field {field}: {problem}")]
    Invalid {
        /// The field.
        field: &'static str,
        /// What is wrong.
        problem: String,
    },
}

/// One grasp to execute: palm poses (robot base frame) and the planner's joint
/// solutions for them, and the hand's spread.
///
/// This is the one plan schema: the planner stage's message converts into it, `cell
/// plan --out` writes it and `cell execute --plan` reads it. As JSON it is
/// `{"task": t, "method": m, "palm": pose, "pregrasp": pose, "joints_rad": [7],
/// "pregrasp_joints_rad": [7], "spread_rad": s}` with poses as
/// `{"xyz": [..], "rpy": [..]}`; `task` and `method` are optional and informational.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ExecutionRequest {
    /// Palm pose at the grasp: `base_from_palm`.
    pub palm: PoseJson,
    /// Palm pose before the approach, backed off along the palm's -z.
    pub pregrasp: PoseJson,
    /// Arm joints (A1, A2, E1, A3, A4, A5, A6) that put the palm at `palm` (rad).
    pub joints_rad: [f64; JOINTS],
    /// Arm joints that put the palm at `pregrasp` (rad).
    pub pregrasp_joints_rad: [f64; JOINTS],
    /// Spread of F1 and F2 (0 to pi rad) to pre-shape before the approach.
    pub spread_rad: f64,
    /// Each finger's flex before the approach (rad): one number or three (F1, F2,
    /// F3); open (absent) by default.
    #[serde(default, skip_serializing_if = "PreshapeRad::is_open")]
    pub preshape_rad: PreshapeRad,
    /// How far beyond `palm` the approach to contact may go (m); the cell's
    /// `approach.max_overtravel_m` when absent.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub max_overtravel_m: Option<f64>,
    /// The task the grasp was planned for.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub task: Option<String>,
    /// The planning method (kernel or baseline) that chose it.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub method: Option<String>,
}

/// A validated request with its poses decoded.
#[derive(Debug, Clone, PartialEq)]
pub struct ValidRequest {
    /// Palm at the grasp.
    pub palm: Pose,
    /// Palm before the approach.
    pub pregrasp: Pose,
    /// Joints at the grasp (rad).
    pub joints_rad: [f64; JOINTS],
    /// Joints at the pre-grasp (rad).
    pub pregrasp_joints_rad: [f64; JOINTS],
    /// Spread (rad).
    pub spread_rad: f64,
    /// Each finger's flex before the approach (rad).
    pub preshape_rad: PreshapeRad,
    /// The grasp's own overtravel of the approach (m), if it names one.
    pub max_overtravel_m: Option<f64>,
}

impl ExecutionRequest {
    /// The request for a planned grasp: its poses, spread and joint solutions, which
    /// a grasp planned without reachability does not have (an error naming them).
    pub fn from_planned(
        grasp: &PlannedGrasp,
        task: &str,
        method: &str,
    ) -> Result<ExecutionRequest, RequestError> {
        let missing = |field| RequestError::Invalid {
            field,
            problem: "the planned grasp has no joint solution (planned without reachability, \
                      or unreachable)"
                .into(),
        };
        Ok(ExecutionRequest {
            palm: PoseJson::from(&grasp.pose),
            pregrasp: PoseJson::from(&grasp.pregrasp_pose),
            joints_rad: grasp.joints.ok_or_else(|| missing("joints_rad"))?,
            pregrasp_joints_rad: grasp
                .pregrasp_joints
                .ok_or_else(|| missing("pregrasp_joints_rad"))?,
            spread_rad: grasp.spread_rad,
            preshape_rad: grasp.preshape_rad,
            max_overtravel_m: grasp.max_overtravel_m,
            task: Some(task.to_string()),
            method: Some(method.to_string()),
        })
    }

    /// Reads a request from a JSON file.
    pub fn load(path: &Path) -> Result<ExecutionRequest, RequestError> {
        let text = crate::fsio::read_to_string(path).map_err(RequestError::Read)?;
        serde_json::from_str(&text).map_err(|e| RequestError::Parse {
            path: path.to_path_buf(),
            message: e.to_string(),
        })
    }

    /// Checks every number is finite and the spread in range; decodes the poses.
    pub fn validate(&self) -> Result<ValidRequest, RequestError> {
        let invalid = |field, problem: String| RequestError::Invalid { field, problem };
        let palm = self
            .palm
            .to_pose("palm")
            .map_err(|e| invalid("palm", e.to_string()))?;
        let pregrasp = self
            .pregrasp
            .to_pose("pregrasp")
            .map_err(|e| invalid("pregrasp", e.to_string()))?;
        check_finite(&self.joints_rad, "joints_rad")
            .map_err(|e| invalid("joints_rad", e.to_string()))?;
        check_finite(&self.pregrasp_joints_rad, "pregrasp_joints_rad")
            .map_err(|e| invalid("pregrasp_joints_rad", e.to_string()))?;
        if !(0.0..=PI).contains(&self.spread_rad) {
            return Err(invalid(
                "spread_rad",
                format!("{} rad is outside 0..=pi", self.spread_rad),
            ));
        }
        if let Some(problem) = self.preshape_rad.problem(crate::robot::FLEX_LIMITS_RAD) {
            return Err(invalid("preshape_rad", problem));
        }
        if let Some(problem) = overtravel_problem(self.max_overtravel_m) {
            return Err(invalid("max_overtravel_m", problem));
        }
        Ok(ValidRequest {
            palm,
            pregrasp,
            joints_rad: self.joints_rad,
            pregrasp_joints_rad: self.pregrasp_joints_rad,
            spread_rad: self.spread_rad,
            preshape_rad: self.preshape_rad,
            max_overtravel_m: self.max_overtravel_m,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn request() -> ExecutionRequest {
        ExecutionRequest {
            palm: PoseJson {
                xyz: [0.6, 0.0, 0.15],
                rpy: Some([PI, 0.0, PI]),
                quat_xyzw: None,
            },
            pregrasp: PoseJson {
                xyz: [0.6, 0.0, 0.25],
                rpy: Some([PI, 0.0, PI]),
                quat_xyzw: None,
            },
            joints_rad: [0.0, -1.0, 0.0, 1.4, 0.0, -0.74, 0.0],
            pregrasp_joints_rad: [0.0, -0.83, 0.0, 1.41, 0.0, -0.9, 0.0],
            spread_rad: 0.5,
            preshape_rad: crate::robot::PreshapeRad::OPEN,
            max_overtravel_m: None,
            task: Some("top".into()),
            method: None,
        }
    }

    #[test]
    fn json_round_trip_and_bad_fields_are_named() {
        let r = request();
        let text = serde_json::to_string(&r).unwrap();
        assert_eq!(serde_json::from_str::<ExecutionRequest>(&text).unwrap(), r);
        let v = r.validate().unwrap();
        assert_eq!(v.palm.translation.vector.z, 0.15);
        let mut bad = r.clone();
        bad.spread_rad = 4.0;
        let err = bad.validate().unwrap_err().to_string();
        assert!(err.contains("spread_rad") && err.contains('4'), "{err}");
        let mut bad = r.clone();
        bad.pregrasp_joints_rad[3] = f64::NAN;
        let err = bad.validate().unwrap_err().to_string();
        assert!(err.contains("pregrasp_joints_rad"), "{err}");
        let err = serde_json::from_str::<ExecutionRequest>(&text.replace("spread_rad", "sprd"))
            .unwrap_err()
            .to_string();
        assert!(err.contains("sprd"), "{err}");
    }

    #[test]
    fn a_preshape_is_optional_and_checked() {
        let r = request();
        let text = serde_json::to_string(&r).unwrap();
        // An open hand writes no pre-shape: plan files stay as they were.
        assert!(!text.contains("preshape_rad"), "{text}");
        let with = text.replace(
            "\"spread_rad\":0.5",
            "\"spread_rad\":0.5,\"preshape_rad\":1.2",
        );
        let parsed: ExecutionRequest = serde_json::from_str(&with).unwrap();
        assert_eq!(parsed.preshape_rad, PreshapeRad([1.2; 3]));
        assert_eq!(
            parsed.validate().unwrap().preshape_rad,
            PreshapeRad([1.2; 3])
        );
        let mut bad = r.clone();
        bad.preshape_rad = PreshapeRad([0.0, 0.0, 2.6]);
        let err = bad.validate().unwrap_err().to_string();
        assert!(err.contains("preshape_rad") && err.contains("F3"), "{err}");
    }

    #[test]
    fn a_grasps_own_overtravel_is_optional_and_checked() {
        let r = request();
        let text = serde_json::to_string(&r).unwrap();
        assert!(!text.contains("max_overtravel_m"), "{text}");
        let with = text.replace(
            "\"spread_rad\":0.5",
            "\"spread_rad\":0.5,\"max_overtravel_m\":0.0",
        );
        let parsed: ExecutionRequest = serde_json::from_str(&with).unwrap();
        assert_eq!(parsed.validate().unwrap().max_overtravel_m, Some(0.0));
        for bad_value in [-0.01, f64::NAN, f64::INFINITY] {
            let mut bad = r.clone();
            bad.max_overtravel_m = Some(bad_value);
            let err = bad.validate().unwrap_err().to_string();
            assert!(err.contains("max_overtravel_m"), "{err}");
        }
    }
}
