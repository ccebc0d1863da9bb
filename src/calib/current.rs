//! The camera mount perception should use: the calibration result if there is a
//! valid one, else the configuration's nominal mount (with a warning).

use super::HandEyeResult;
use crate::config::CellConfig;
use crate::geometry::{pose_error, Pose};
use serde::Serialize;
use std::path::{Path, PathBuf};

/// Where `cell calibrate solve` writes its result and perception looks for it
/// (relative to the working directory, like [`crate::config::DEFAULT_CONFIG_PATH`]).
pub const DEFAULT_RESULT_PATH: &str = "calib/hand_eye.toml";
/// A calibrated mount further than this from the nominal one (m) gets a warning.
const WARN_FROM_NOMINAL_M: f64 = 0.2;
/// ... or than this (deg).
const WARN_FROM_NOMINAL_DEG: f64 = 20.0;

/// Where a camera mount came from.
#[derive(Debug, Clone, PartialEq, Serialize)]
#[serde(tag = "kind", rename_all = "snake_case")]
pub enum MountSource {
    /// A hand–eye calibration result file.
    Calibrated {
        /// The result file.
        path: PathBuf,
        /// When it was solved (RFC 3339).
        created: String,
        /// The method that produced it.
        method: String,
        /// Its RMS translation residual (mm).
        rms_mm: f64,
        /// Its distance from the nominal mount (mm, deg).
        from_nominal_mm_deg: (f64, f64),
    },
    /// The configuration's nominal `camera.base_from_camera`.
    Nominal {
        /// Why the result file was not used.
        reason: String,
    },
}

/// The camera mount to use and where it came from.
#[derive(Debug, Clone, PartialEq)]
pub struct CameraMount {
    /// The camera's optical frame in the robot base frame.
    pub base_from_camera: Pose,
    /// Where it came from.
    pub source: MountSource,
}

/// The mount perception should use: `result_path`'s `base_from_camera` (usually
/// [`DEFAULT_RESULT_PATH`]) when the file exists and is valid — logged with its
/// date, method and residual — else `config`'s nominal mount, with a warning that
/// says why and how to calibrate. Never fails: a cell without a calibration still runs.
pub fn current_base_from_camera(config: &CellConfig, result_path: &Path) -> CameraMount {
    let nominal = config.base_from_camera();
    let fallback = |reason: String| {
        tracing::warn!(
            "using the nominal camera mount of the cell configuration: {reason}; run `cell calibrate collect` and `cell calibrate solve` to calibrate"
        );
        CameraMount {
            base_from_camera: nominal,
            source: MountSource::Nominal { reason },
        }
    };
    if !result_path.exists() {
        return fallback(format!(
            "no calibration result at {}",
            result_path.display()
        ));
    }
    let result = match HandEyeResult::load(result_path) {
        Ok(r) => r,
        Err(e) => return fallback(format!("the calibration result is invalid: {e}")),
    };
    let pose = match result.base_from_camera() {
        Ok(p) => p,
        Err(e) => return fallback(format!("{}: base_from_camera: {e}", result_path.display())),
    };
    let (dp, dr) = pose_error(&pose, &nominal);
    let from_nominal_mm_deg = (dp * 1e3, dr.to_degrees());
    tracing::info!(
        path = %result_path.display(),
        created = %result.created,
        method = %result.method,
        rms_mm = result.residuals.rms_mm,
        from_nominal_mm = from_nominal_mm_deg.0,
        from_nominal_deg = from_nominal_mm_deg.1,
        "camera mount from the hand-eye calibration"
    );
    if dp > WARN_FROM_NOMINAL_M || dr.to_degrees() > WARN_FROM_NOMINAL_DEG {
        tracing::warn!(
            "the calibrated camera mount ({}) is {:.0} mm / {:.1}° from the configured nominal one: check that the camera has not been moved, or update camera.base_from_camera",
            result_path.display(),
            from_nominal_mm_deg.0,
            from_nominal_mm_deg.1
        );
    }
    CameraMount {
        base_from_camera: pose,
        source: MountSource::Calibrated {
            path: result_path.to_path_buf(),
            created: result.created,
            method: result.method,
            rms_mm: result.residuals.rms_mm,
            from_nominal_mm_deg,
        },
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::calib::synthetic::{point_samples, Noise, SyntheticScene};
    use crate::calib::{solve, Sample, SolveOptions};

    fn config() -> CellConfig {
        let path = Path::new(env!("CARGO_MANIFEST_DIR")).join(crate::config::DEFAULT_CONFIG_PATH);
        CellConfig::load(&path).unwrap()
    }

    #[test]
    fn valid_result_is_used_and_missing_or_bad_falls_back_to_nominal() {
        let config = config();
        let dir = crate::fsio::TempDir::new("calib-current-use").unwrap();
        let path = dir.join("hand_eye.toml");
        // Missing.
        let mount = current_base_from_camera(&config, &path);
        assert_eq!(mount.base_from_camera, config.base_from_camera());
        assert!(
            matches!(&mount.source, MountSource::Nominal { reason } if reason.contains("no calibration result")),
            "{:?}",
            mount.source
        );
        // Valid: solved from samples of a known scene.
        let scene = SyntheticScene::nominal();
        let samples: Vec<Sample> = point_samples(&scene, 12, &Noise::typical(), 4)
            .into_iter()
            .map(Sample::Point)
            .collect();
        let solution = solve(&samples, &SolveOptions::default()).unwrap();
        HandEyeResult::from_solution(&solution, "s.json", 12, "2025-01-02T03:04:05Z")
            .save(&path)
            .unwrap();
        let mount = current_base_from_camera(&config, &path);
        let (dp, dr) = pose_error(&mount.base_from_camera, &scene.base_from_camera);
        assert!(dp < 2e-3 && dr < 0.3f64.to_radians(), "{dp} {dr}");
        match &mount.source {
            MountSource::Calibrated {
                created,
                from_nominal_mm_deg,
                ..
            } => {
                assert_eq!(created, "2025-01-02T03:04:05Z");
                let (dp, dr) = pose_error(&mount.base_from_camera, &config.base_from_camera());
                assert!((from_nominal_mm_deg.0 - dp * 1e3).abs() < 1e-9);
                assert!((from_nominal_mm_deg.1 - dr.to_degrees()).abs() < 1e-9);
            }
            other => panic!("{other:?}"),
        }
        // Invalid: garbled.
        std::fs::write(&path, "base_from_camera = 3\n").unwrap();
        let mount = current_base_from_camera(&config, &path);
        assert_eq!(mount.base_from_camera, config.base_from_camera());
        assert!(
            matches!(&mount.source, MountSource::Nominal { reason } if reason.contains("invalid") && reason.contains("hand_eye.toml")),
            "{:?}",
            mount.source
        );
    }
}
