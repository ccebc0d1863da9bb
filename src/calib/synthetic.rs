//! Synthetic calibration samples from a known transform, for tests, benchmarks and
//! the example sample file. Seeded: the same seed gives the same samples.
//!
//! Target poses are drawn in a 0.3 × 0.5 × 0.3 m box over the table, facing the
//! camera within ±40° about a random axis; the flange pose follows exactly
//! (`F = T Y⁻¹`, forward kinematics is taken as exact) and the camera observation
//! (`C = X⁻¹ T`) gets the noise: per axis, Gaussian translation noise and a
//! Gaussian rotation vector applied in the camera frame.

use super::{HandEye, PointSample, PoseSample};
use crate::geometry::{look_at_optical, pose_from_params, Pose};
use nalgebra::{Point3, UnitQuaternion, Vector3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};

/// Centre of the box the target is moved in (base frame, m).
const TARGET_BOX_CENTRE_M: [f64; 3] = [0.6, 0.0, 0.35];
/// Half extents of that box (m).
const TARGET_BOX_HALF_M: [f64; 3] = [0.15, 0.25, 0.15];
/// Largest tilt of the target away from facing the camera (deg).
const MAX_TILT_DEG: f64 = 40.0;

/// The true transforms samples are generated from.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SyntheticScene {
    /// The true camera mount.
    pub base_from_camera: Pose,
    /// The true target mount on the flange.
    pub flange_from_target: Pose,
}

impl SyntheticScene {
    /// A camera near the nominal mount of `robot/cell.toml` (1.25 m ahead, 0.80 m up,
    /// looking at the table) but off by about 1 cm and 1°, as a real mount is, and a
    /// target 9 cm ahead of the flange.
    pub fn nominal() -> Self {
        SyntheticScene {
            base_from_camera: pose_from_params(&[1.262, -0.011, 0.793, -2.41, 0.012, 1.585]),
            flange_from_target: pose_from_params(&[0.012, -0.021, 0.09, 0.05, -0.03, 0.3]),
        }
    }

    /// The true solution.
    pub fn hand_eye(&self) -> HandEye {
        HandEye {
            base_from_camera: self.base_from_camera,
            flange_from_target: self.flange_from_target,
        }
    }

    /// `n` target poses in the base frame, facing the camera within 40°.
    pub fn base_from_targets(&self, n: usize, rng: &mut ChaCha8Rng) -> Vec<Pose> {
        let eye = self.base_from_camera.translation.vector;
        (0..n)
            .map(|_| {
                let position = Vector3::from_fn(|i, _| {
                    TARGET_BOX_CENTRE_M[i] + rng.gen_range(-1.0..=1.0) * TARGET_BOX_HALF_M[i]
                });
                // z of the target toward the camera.
                let facing = look_at_optical(position, eye, Vector3::z());
                let axis = random_unit(rng);
                let tilt = rng.gen_range(-MAX_TILT_DEG..=MAX_TILT_DEG).to_radians();
                let mut pose = facing;
                pose.rotation = facing.rotation * UnitQuaternion::from_scaled_axis(axis * tilt);
                pose
            })
            .collect()
    }
}

/// Observation noise: standard deviations per axis.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Noise {
    /// Translation / point noise per axis (m).
    pub translation_m: f64,
    /// Rotation noise per axis of the rotation vector (rad).
    pub rotation_rad: f64,
}

impl Noise {
    /// No noise.
    pub fn none() -> Self {
        Noise {
            translation_m: 0.0,
            rotation_rad: 0.0,
        }
    }

    /// 0.5 mm and 0.2° per axis: a board detector at about 1 m.
    pub fn typical() -> Self {
        Noise {
            translation_m: 0.5e-3,
            rotation_rad: 0.2f64.to_radians(),
        }
    }
}

fn random_unit(rng: &mut ChaCha8Rng) -> Vector3<f64> {
    loop {
        let v = Vector3::from_fn(|_, _| rng.gen_range(-1.0..=1.0));
        let n: f64 = v.norm();
        if n > 1e-3 && n <= 1.0 {
            return v / n;
        }
    }
}

fn gaussian(rng: &mut ChaCha8Rng, sigma: f64) -> Vector3<f64> {
    match Normal::new(0.0, sigma) {
        Ok(d) if sigma > 0.0 => Vector3::from_fn(|_, _| d.sample(rng)),
        _ => Vector3::zeros(),
    }
}

/// `n` pose samples (board-like target) with observation noise, seeded.
pub fn pose_samples(scene: &SyntheticScene, n: usize, noise: &Noise, seed: u64) -> Vec<PoseSample> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let camera_from_base = scene.base_from_camera.inverse();
    let target_from_flange = scene.flange_from_target.inverse();
    scene
        .base_from_targets(n, &mut rng)
        .into_iter()
        .map(|target| {
            let mut seen = camera_from_base * target;
            seen.translation.vector += gaussian(&mut rng, noise.translation_m);
            seen.rotation =
                UnitQuaternion::from_scaled_axis(gaussian(&mut rng, noise.rotation_rad))
                    * seen.rotation;
            PoseSample {
                base_from_flange: target * target_from_flange,
                camera_from_target: seen,
            }
        })
        .collect()
}

/// `n` point samples (sphere-like target at the origin of `flange_from_target`) with
/// noise `noise.translation_m` per axis, seeded.
pub fn point_samples(
    scene: &SyntheticScene,
    n: usize,
    noise: &Noise,
    seed: u64,
) -> Vec<PointSample> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let camera_from_base = scene.base_from_camera.inverse();
    let target_from_flange = scene.flange_from_target.inverse();
    scene
        .base_from_targets(n, &mut rng)
        .into_iter()
        .map(|target| {
            let centre = camera_from_base * Point3::from(target.translation.vector);
            PointSample {
                base_from_flange: target * target_from_flange,
                target_point_camera_m: centre + gaussian(&mut rng, noise.translation_m),
            }
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn targets_are_in_front_of_the_camera_and_samples_are_seeded() {
        let scene = SyntheticScene::nominal();
        let a = pose_samples(&scene, 20, &Noise::typical(), 7);
        assert_eq!(a, pose_samples(&scene, 20, &Noise::typical(), 7));
        assert_ne!(a, pose_samples(&scene, 20, &Noise::typical(), 8));
        for s in &a {
            let t = s.camera_from_target.translation.vector;
            // In front (optical z forward), within the cell.toml range 0.5–4 m.
            assert!(t.z > 0.5 && t.norm() < 4.0, "{t:?}");
            // The target faces the camera within the tilt (plus the noise).
            let normal = s.camera_from_target.rotation * Vector3::z();
            let to_camera = -t.normalize();
            assert!(normal.angle(&to_camera).to_degrees() < MAX_TILT_DEG + 1.0);
        }
    }
}
