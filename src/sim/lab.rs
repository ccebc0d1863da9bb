//! The errors a real lab adds to a simulated cell (issue 20, "a cell as hard as a
//! lab"): the hand–eye calibration is never exact, and the arm does not return
//! exactly to the joints it was sent.
//!
//! - **Hand–eye error**: the camera's true mount differs from the calibrated one the
//!   cell uses by a rigid error of fixed size (default 3 mm and 0.5°) in a seeded
//!   random direction, drawn once per campaign (a calibration is done once and then
//!   used for every trial). The simulated camera renders from the true mount;
//!   perception converts with the calibrated one.
//! - **Execution error**: every executed joint is off by seeded Gaussian noise at the
//!   arm's repeatability, drawn per trial; the observer grades the palm where those
//!   joints put it.

use crate::geometry::Pose;
use nalgebra::{Isometry3, Translation3, Unit, UnitQuaternion, Vector3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal, UnitSphere};
use serde::{Deserialize, Serialize};

/// Default hand–eye translation error (m): a good calibration's residual.
pub const DEFAULT_HAND_EYE_TRANSLATION_M: f64 = 0.003;
/// Default hand–eye rotation error (rad): 0.5 degrees.
pub const DEFAULT_HAND_EYE_ROTATION_RAD: f64 = 0.5 * std::f64::consts::PI / 180.0;
/// The KUKA LBR4+'s pose repeatability (m, ISO 9283: +-0.05 mm).
pub const ARM_REPEATABILITY_M: f64 = 0.05e-3;
/// Default joint noise (rad, standard deviation per joint): the repeatability over
/// the arm's ~1 m lever from the base to the palm.
pub const DEFAULT_JOINT_NOISE_RAD: f64 = ARM_REPEATABILITY_M / 1.0;

/// Errors of the lab settings.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum LabError {
    /// A magnitude is negative or not finite.
    #[error("{what} = {value}: must be finite and >= 0")]
    Magnitude {
        /// The setting.
        what: &'static str,
        /// Its value.
        value: f64,
    },
}

/// How far the simulated lab departs from the ideal cell.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LabErrors {
    /// Size of the hand–eye translation error (m).
    pub hand_eye_translation_m: f64,
    /// Size of the hand–eye rotation error (rad).
    pub hand_eye_rotation_rad: f64,
    /// Standard deviation of each executed joint's error (rad).
    pub joint_noise_rad: f64,
}

impl Default for LabErrors {
    fn default() -> Self {
        LabErrors {
            hand_eye_translation_m: DEFAULT_HAND_EYE_TRANSLATION_M,
            hand_eye_rotation_rad: DEFAULT_HAND_EYE_ROTATION_RAD,
            joint_noise_rad: DEFAULT_JOINT_NOISE_RAD,
        }
    }
}

/// The errors of one campaign or trial, drawn from [`LabErrors`].
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LabDraw {
    /// The true camera mount from the calibrated one (camera optical frame):
    /// `true base_from_camera = calibrated base_from_camera * calibrated_from_true`,
    /// as `[x, y, z, rx, ry, rz]` (m, rotation vector in rad).
    pub calibrated_from_true_camera: [f64; 6],
    /// Each executed joint's error (rad).
    pub joint_error_rad: [f64; 7],
}

impl LabErrors {
    /// The ideal cell: no error at all.
    pub const NONE: LabErrors = LabErrors {
        hand_eye_translation_m: 0.0,
        hand_eye_rotation_rad: 0.0,
        joint_noise_rad: 0.0,
    };

    /// Checks the magnitudes.
    pub fn validate(&self) -> Result<(), LabError> {
        for (what, value) in [
            ("hand-eye translation (m)", self.hand_eye_translation_m),
            ("hand-eye rotation (rad)", self.hand_eye_rotation_rad),
            ("joint noise (rad)", self.joint_noise_rad),
        ] {
            if !(value.is_finite() && value >= 0.0) {
                return Err(LabError::Magnitude { what, value });
            }
        }
        Ok(())
    }

    /// The hand–eye error of a campaign seeded `seed`: exactly the configured sizes,
    /// in a random direction and about a random axis.
    pub fn draw_hand_eye(&self, seed: u64) -> [f64; 6] {
        let mut rng = ChaCha8Rng::seed_from_u64(seed ^ 0x0068_616e_6465_7965);
        let t: [f64; 3] = UnitSphere.sample(&mut rng);
        let r: [f64; 3] = UnitSphere.sample(&mut rng);
        let (dt, dr) = (self.hand_eye_translation_m, self.hand_eye_rotation_rad);
        [
            t[0] * dt,
            t[1] * dt,
            t[2] * dt,
            r[0] * dr,
            r[1] * dr,
            r[2] * dr,
        ]
    }

    /// The joint errors of a trial seeded `seed`.
    pub fn draw_joints(&self, seed: u64) -> [f64; 7] {
        let mut rng = ChaCha8Rng::seed_from_u64(seed ^ 0x6a6f_696e_7473);
        match Normal::new(0.0, self.joint_noise_rad) {
            Ok(normal) if self.joint_noise_rad > 0.0 => {
                std::array::from_fn(|_| normal.sample(&mut rng))
            }
            _ => {
                // Keep the stream's use independent of the size.
                let _: f64 = rng.gen();
                [0.0; 7]
            }
        }
    }

    /// The draw of one trial: the campaign's hand–eye error (`campaign_seed`) and the
    /// trial's joint errors (`trial_seed`).
    pub fn draw(&self, campaign_seed: u64, trial_seed: u64) -> LabDraw {
        LabDraw {
            calibrated_from_true_camera: self.draw_hand_eye(campaign_seed),
            joint_error_rad: self.draw_joints(trial_seed),
        }
    }

    /// [`LabErrors::draw`] of a trial, `None` for an exact cell (no errors).
    pub fn trial_draw(&self, campaign_seed: u64, trial_seed: u64) -> Option<LabDraw> {
        (*self != LabErrors::NONE).then(|| self.draw(campaign_seed, trial_seed))
    }

    /// One line for reports: `hand-eye 3.0 mm / 0.50 deg, joints 5.0e-5 rad`.
    pub fn text(&self) -> String {
        format!(
            "hand-eye error {:.1} mm / {:.2} deg (per campaign), joint noise {:.1e} rad (per trial)",
            self.hand_eye_translation_m * 1e3,
            self.hand_eye_rotation_rad.to_degrees(),
            self.joint_noise_rad
        )
    }
}

impl LabDraw {
    /// No error.
    pub const NONE: LabDraw = LabDraw {
        calibrated_from_true_camera: [0.0; 6],
        joint_error_rad: [0.0; 7],
    };

    /// The camera's true mount given the calibrated `base_from_camera`.
    pub fn true_base_from_camera(&self, calibrated: &Pose) -> Pose {
        let [x, y, z, rx, ry, rz] = self.calibrated_from_true_camera;
        let rotation = Vector3::new(rx, ry, rz);
        let r = match Unit::try_new(rotation, 1e-15) {
            Some(axis) => UnitQuaternion::from_axis_angle(&axis, rotation.norm()),
            None => UnitQuaternion::identity(),
        };
        calibrated * Isometry3::from_parts(Translation3::new(x, y, z), r)
    }

    /// The joints the arm really reaches when sent `commanded`.
    pub fn executed_joints(&self, commanded: &[f64; 7]) -> [f64; 7] {
        std::array::from_fn(|i| commanded[i] + self.joint_error_rad[i])
    }

    /// One line for logs: `hand-eye 3.0 mm / 0.50 deg, joints rms 4.1e-5 rad`.
    pub fn text(&self) -> String {
        let (t, r) = self.hand_eye_size();
        let rms = (self.joint_error_rad.iter().map(|e| e * e).sum::<f64>() / 7.0).sqrt();
        format!(
            "hand-eye {:.1} mm / {:.2} deg, joints rms {:.1e} rad",
            t * 1e3,
            r.to_degrees(),
            rms
        )
    }

    /// Size of the hand–eye error: translation (m) and rotation (rad).
    pub fn hand_eye_size(&self) -> (f64, f64) {
        let c = self.calibrated_from_true_camera;
        (
            Vector3::new(c[0], c[1], c[2]).norm(),
            Vector3::new(c[3], c[4], c[5]).norm(),
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_hand_eye_error_has_the_configured_size_and_is_seeded() {
        let lab = LabErrors::default();
        let a = lab.draw(7, 1);
        assert_eq!(a, lab.draw(7, 1));
        let (t, r) = a.hand_eye_size();
        assert!((t - 0.003).abs() < 1e-12 && (r - 0.5f64.to_radians()).abs() < 1e-12);
        // Another campaign: another direction; another trial: other joints, same mount.
        assert_ne!(
            a.calibrated_from_true_camera,
            lab.draw(8, 1).calibrated_from_true_camera
        );
        let b = lab.draw(7, 2);
        assert_eq!(a.calibrated_from_true_camera, b.calibrated_from_true_camera);
        assert_ne!(a.joint_error_rad, b.joint_error_rad);
        // The true mount is off the calibrated one by exactly that much.
        let calibrated = crate::geometry::pose_from_params(&[1.2, 0.0, 0.8, -2.4, 0.0, 1.57]);
        let real = a.true_base_from_camera(&calibrated);
        let (dp, dr) = crate::geometry::pose_error(&calibrated, &real);
        assert!((dp - 0.003).abs() < 1e-9, "{dp}");
        assert!((dr - 0.5f64.to_radians()).abs() < 1e-9, "{dr}");
    }

    #[test]
    fn joint_noise_has_the_configured_spread_and_none_is_exact() {
        let lab = LabErrors {
            joint_noise_rad: 0.01,
            ..LabErrors::NONE
        };
        let errors: Vec<f64> = (0..400).flat_map(|s| lab.draw_joints(s)).collect();
        let rms = (errors.iter().map(|e| e * e).sum::<f64>() / errors.len() as f64).sqrt();
        assert!((rms - 0.01).abs() < 0.001, "{rms}");
        let none = LabErrors::NONE.draw(3, 4);
        assert_eq!(none, LabDraw::NONE);
        let q = [0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7];
        assert_eq!(none.executed_joints(&q), q);
        assert!(LabErrors {
            joint_noise_rad: -1.0,
            ..LabErrors::NONE
        }
        .validate()
        .is_err());
    }
}
