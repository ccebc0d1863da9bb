//! The calibration result file (`calib/hand_eye.toml`), read by perception at start.

use super::samples::{pose_from_json, MIN_SAMPLES};
use super::{CalibError, ResidualStats, Solution};
use crate::fsio::{FileError, FileOp};
use crate::geometry::{GeometryError, Pose, PoseJson};
use serde::{Deserialize, Serialize};
use std::path::Path;

/// Written at the top of every result file.
const HEADER: &str = "# Hand-eye calibration written by `cell calibrate solve`.\n\
# base_from_camera is the camera's pose in the robot base frame (m, rad; rpy is\n\
# fixed-axis X-Y-Z); perception loads it at start. Residuals: mm and degrees.\n";

/// A solved calibration as stored in `calib/hand_eye.toml`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct HandEyeResult {
    /// When it was solved (RFC 3339, UTC).
    pub created: String,
    /// The method that produced it, e.g. `daniilidis+refine`.
    pub method: String,
    /// The sample file it was solved from.
    pub samples_file: String,
    /// Number of samples used.
    pub sample_count: usize,
    /// The target's position in the flange frame (m).
    pub target_in_flange_m: [f64; 3],
    /// Residuals of the result over the samples.
    pub residuals: ResidualStats,
    /// The camera's pose in the robot base frame.
    pub base_from_camera: PoseJson,
    /// The target's pose on the flange (only when pose samples were used).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub flange_from_target: Option<PoseJson>,
}

impl HandEyeResult {
    /// The result file of a solution.
    pub fn from_solution(
        solution: &Solution,
        samples_file: &str,
        sample_count: usize,
        created: &str,
    ) -> Self {
        let best = solution.best();
        let he = &best.evaluation.hand_eye;
        let has_rotation = best.evaluation.stats.rms_deg.is_some();
        HandEyeResult {
            created: created.to_string(),
            method: best.name.clone(),
            samples_file: samples_file.to_string(),
            sample_count,
            target_in_flange_m: he.flange_from_target.translation.vector.into(),
            residuals: best.evaluation.stats,
            base_from_camera: PoseJson::from(&he.base_from_camera),
            flange_from_target: has_rotation.then(|| PoseJson::from(&he.flange_from_target)),
        }
    }

    /// Reads and validates a result file.
    pub fn load(path: &Path) -> Result<HandEyeResult, CalibError> {
        let text = crate::fsio::read_to_string(path)?;
        Self::parse(&text, path)
    }

    /// Parses and validates the text of a result file (`path` names it in errors).
    pub fn parse(text: &str, path: &Path) -> Result<HandEyeResult, CalibError> {
        let result: HandEyeResult = toml::from_str(text).map_err(|e| CalibError::Parse {
            path: path.to_path_buf(),
            message: e.to_string().trim().replace('\n', " "),
        })?;
        let bad = |field: &str, problem: String| CalibError::BadField {
            path: path.to_path_buf(),
            field: field.to_string(),
            problem,
        };
        pose_from_json(&result.base_from_camera, "base_from_camera")
            .map_err(|p| bad("base_from_camera", p.to_string()))?;
        if let Some(y) = &result.flange_from_target {
            pose_from_json(y, "flange_from_target")
                .map_err(|p| bad("flange_from_target", p.to_string()))?;
        }
        if let Some(v) = result.target_in_flange_m.iter().find(|v| !v.is_finite()) {
            return Err(bad(
                "target_in_flange_m",
                format!("{v} is not a finite number"),
            ));
        }
        let r = &result.residuals;
        for (field, v) in [
            ("residuals.rms_mm", Some(r.rms_mm)),
            ("residuals.median_mm", Some(r.median_mm)),
            ("residuals.max_mm", Some(r.max_mm)),
            ("residuals.rms_deg", r.rms_deg),
            ("residuals.max_deg", r.max_deg),
        ] {
            if let Some(v) = v.filter(|v| !(v.is_finite() && *v >= 0.0)) {
                return Err(bad(field, format!("{v} is not a finite number ≥ 0")));
            }
        }
        if result.sample_count < MIN_SAMPLES {
            return Err(bad(
                "sample_count",
                format!(
                    "{} samples cannot determine a calibration (need ≥ {MIN_SAMPLES})",
                    result.sample_count
                ),
            ));
        }
        Ok(result)
    }

    /// The file's TOML text, with a header comment.
    pub fn to_toml(&self) -> String {
        // Strings, finite numbers and tables: serialisation cannot fail.
        format!("{HEADER}{}", toml::to_string(self).unwrap_or_default())
    }

    /// Writes the file atomically (temporary file, then rename).
    pub fn save(&self, path: &Path) -> Result<(), CalibError> {
        crate::fsio::create_parent_dir(path)
            .and_then(|()| crate::fsio::write_atomically(path, self.to_toml().as_bytes()))
            .map_err(|source| FileError::new(FileOp::Write, path, source).into())
    }

    /// The camera's pose in the robot base frame.
    pub fn base_from_camera(&self) -> Result<Pose, GeometryError> {
        self.base_from_camera.to_pose("base_from_camera")
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::calib::synthetic::{pose_samples, Noise, SyntheticScene};
    use crate::calib::{solve, Sample, SolveOptions};
    use crate::geometry::pose_error;

    fn result() -> HandEyeResult {
        let scene = SyntheticScene::nominal();
        let samples: Vec<Sample> = pose_samples(&scene, 10, &Noise::typical(), 2)
            .into_iter()
            .map(Sample::Pose)
            .collect();
        let s = solve(&samples, &SolveOptions::default()).unwrap();
        HandEyeResult::from_solution(&s, "calib/samples-x.json", 10, "2025-01-01T00:00:00Z")
    }

    #[test]
    fn toml_round_trip() {
        let r = result();
        let text = r.to_toml();
        assert!(text.starts_with("# Hand-eye"));
        let back = HandEyeResult::parse(&text, Path::new("h.toml")).unwrap();
        assert_eq!(back.method, r.method);
        assert_eq!(back.residuals, r.residuals);
        let (dp, dr) = pose_error(
            &back.base_from_camera().unwrap(),
            &r.base_from_camera().unwrap(),
        );
        assert!(dp < 1e-12 && dr < 1e-9);
        let (dp, dr) = pose_error(
            &back.base_from_camera().unwrap(),
            &SyntheticScene::nominal().base_from_camera,
        );
        assert!(dp < 2e-3 && dr < 0.3f64.to_radians());
    }

    #[test]
    fn bad_result_files_name_the_field() {
        let text = result().to_toml();
        let cases = [
            (
                text.replace("sample_count = 10", "sample_count = 10\nsamples = 3"),
                "unknown field",
            ),
            (
                text.replace("sample_count = 10", "sample_count = 2"),
                "h.toml: sample_count: 2 samples",
            ),
            (
                text.replacen("rms_mm = ", "rms_mm = -", 1),
                "h.toml: residuals.rms_mm",
            ),
            (
                text.replacen("rms_mm = ", "rms_mm = nan #", 1),
                "h.toml: residuals.rms_mm: NaN",
            ),
        ];
        for (bad, want) in cases {
            let err = HandEyeResult::parse(&bad, Path::new("h.toml"))
                .unwrap_err()
                .to_string();
            assert!(err.contains(want), "{err} lacks {want}");
        }
        // A quaternion that disagrees with rpy.
        let mut r = result();
        if let Some(q) = &mut r.base_from_camera.quat_xyzw {
            q.swap(0, 3);
        }
        let err = HandEyeResult::parse(&r.to_toml(), Path::new("h.toml"))
            .unwrap_err()
            .to_string();
        assert!(
            err.starts_with("h.toml: base_from_camera: ") && err.contains("disagree"),
            "{err}"
        );
    }
}
