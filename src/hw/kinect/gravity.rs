//! The camera's gravity direction from the Kinect's accelerometer, and the check of
//! the calibrated camera mount against it.
//!
//! At rest the accelerometer measures the reaction to gravity: `+g` along the
//! sensor's "up". libfreenect reports it in counts ([`COUNTS_PER_G`] per g) on the
//! KXSD9's axes, which on the Kinect are x to the sensor's left (seen from behind),
//! y up and z forward along the optical axis. The camera optical frame is x right,
//! y down, z forward, so optical = (-x, -y, z) of the accelerometer, and gravity
//! (downwards) in the optical frame is the negated, normalised reading mapped so.
//!
//! The check: the mount `base_from_camera` (the hand–eye calibration) predicts
//! gravity in the camera frame as `camera_from_base * (0, 0, -1)`; the angle
//! between that and the measured direction is the check's angle. Beyond the
//! configured limit the camera was bumped or the calibration is stale.

use crate::geometry::Pose;
use nalgebra::Vector3;
use serde::{Deserialize, Serialize};

/// Accelerometer counts per g (libfreenect's `FREENECT_COUNTS_PER_G`, KXSD9).
pub const COUNTS_PER_G: f64 = 819.0;

/// Standard gravity (m/s^2), libfreenect's `GRAVITY`.
pub const STANDARD_GRAVITY_M_S2: f64 = 9.80665;

/// One accelerometer reading in raw counts on the sensor's axes.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
pub struct AccelCounts {
    /// Sensor x (left).
    pub x: i16,
    /// Sensor y (up).
    pub y: i16,
    /// Sensor z (forward).
    pub z: i16,
}

impl AccelCounts {
    /// The reading in m/s^2 on the sensor's axes (libfreenect's
    /// `freenect_get_mks_accel`).
    pub fn m_s2(&self) -> Vector3<f64> {
        Vector3::new(f64::from(self.x), f64::from(self.y), f64::from(self.z))
            * (STANDARD_GRAVITY_M_S2 / COUNTS_PER_G)
    }

    /// Gravity (m/s^2, pointing down) in the camera optical frame; `None` for a
    /// reading too small to give a direction (no accelerometer data).
    pub fn gravity_camera_m_s2(&self) -> Option<Vector3<f64>> {
        let a = self.m_s2();
        if a.norm() < 0.1 * STANDARD_GRAVITY_M_S2 {
            return None;
        }
        // Reaction in the optical frame is (-ax, -ay, az); gravity is its negation.
        Some(Vector3::new(a.x, a.y, -a.z))
    }

    /// The counts a sensor at rest reads when gravity in the camera optical frame
    /// points along `gravity_camera` (any length): the inverse of
    /// [`AccelCounts::gravity_camera_m_s2`], 1 g long, rounded.
    pub fn at_rest(gravity_camera: &Vector3<f64>) -> AccelCounts {
        let g = gravity_camera.normalize() * COUNTS_PER_G;
        let count = |v: f64| v.round().clamp(f64::from(i16::MIN), f64::from(i16::MAX)) as i16;
        AccelCounts {
            x: count(g.x),
            y: count(g.y),
            z: count(-g.z),
        }
    }
}

/// Gravity (unit, pointing down) in the camera optical frame that the mount
/// `base_from_camera` predicts.
pub fn expected_gravity_camera(base_from_camera: &Pose) -> Vector3<f64> {
    base_from_camera.rotation.inverse() * Vector3::new(0.0, 0.0, -1.0)
}

/// The outcome of comparing a measured gravity direction with the mount.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct GravityCheck {
    /// Measured gravity in the camera optical frame (m/s^2).
    pub gravity_camera_m_s2: [f64; 3],
    /// Angle between the measured and the predicted direction (rad).
    pub angle_rad: f64,
    /// The limit it was checked against (rad).
    pub max_rad: f64,
}

impl GravityCheck {
    /// Compares `gravity_camera_m_s2` with what `base_from_camera` predicts.
    pub fn new(
        gravity_camera_m_s2: &Vector3<f64>,
        base_from_camera: &Pose,
        max_rad: f64,
    ) -> GravityCheck {
        let expected = expected_gravity_camera(base_from_camera);
        let angle_rad = gravity_camera_m_s2.angle(&expected);
        GravityCheck {
            gravity_camera_m_s2: [
                gravity_camera_m_s2.x,
                gravity_camera_m_s2.y,
                gravity_camera_m_s2.z,
            ],
            angle_rad,
            max_rad,
        }
    }

    /// True when the angle exceeds the limit: the camera was bumped or the
    /// calibration is stale.
    pub fn exceeded(&self) -> bool {
        // NaN (no direction) counts as exceeded.
        !matches!(
            self.angle_rad.partial_cmp(&self.max_rad),
            Some(std::cmp::Ordering::Less | std::cmp::Ordering::Equal)
        )
    }

    /// The warning to log when [`GravityCheck::exceeded`].
    pub fn warning(&self) -> String {
        format!(
            "gravity check: the camera's accelerometer and the calibrated mount disagree by {:.2} deg \
             (limit {:.2} deg): the camera was bumped or the hand-eye calibration is stale",
            self.angle_rad.to_degrees(),
            self.max_rad.to_degrees()
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::pose_from_params;

    #[test]
    fn a_level_kinect_reads_one_g_up_and_gravity_is_optical_plus_y() {
        // Looking horizontally: optical z along base x, y down = base -z.
        let level = pose_from_params(&[
            0.0,
            0.0,
            1.0,
            -std::f64::consts::FRAC_PI_2,
            0.0,
            -std::f64::consts::FRAC_PI_2,
        ]);
        let g = expected_gravity_camera(&level);
        assert!((g - Vector3::y()).norm() < 1e-9, "{g:?}");
        let counts = AccelCounts::at_rest(&g);
        assert_eq!(counts, AccelCounts { x: 0, y: 819, z: 0 });
        let measured = counts.gravity_camera_m_s2().unwrap();
        assert!((measured.norm() - STANDARD_GRAVITY_M_S2).abs() < 1e-9);
        let check = GravityCheck::new(&measured, &level, 2f64.to_radians());
        assert!(check.angle_rad < 1e-9 && !check.exceeded());
        assert!(AccelCounts::default().gravity_camera_m_s2().is_none());
    }

    #[test]
    fn a_mount_tilted_by_five_degrees_exceeds_two() {
        let mount = pose_from_params(&[1.25, 0.0, 0.8, -2.42787, 0.0, std::f64::consts::FRAC_PI_2]);
        let counts = AccelCounts::at_rest(&expected_gravity_camera(&mount));
        let tilted = mount * pose_from_params(&[0.0, 0.0, 0.0, 5f64.to_radians(), 0.0, 0.0]);
        let measured = counts.gravity_camera_m_s2().unwrap();
        let ok = GravityCheck::new(&measured, &mount, 2f64.to_radians());
        assert!(ok.angle_rad.to_degrees() < 0.2 && !ok.exceeded(), "{ok:?}");
        let bad = GravityCheck::new(&measured, &tilted, 2f64.to_radians());
        assert!(
            (bad.angle_rad.to_degrees() - 5.0).abs() < 0.2 && bad.exceeded(),
            "{bad:?}"
        );
        assert!(bad.warning().contains("stale"));
    }
}
