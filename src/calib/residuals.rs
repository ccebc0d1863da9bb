//! Residuals of `F_i Y = X C_i` per sample, and the best target pose for a camera pose.

use super::{HandEye, Sample, Weights};
use crate::geometry::mean_rotation;
use crate::geometry::Pose;
use nalgebra::{DVector, Isometry3, Point3, Translation3, Vector3};
use serde::{Deserialize, Serialize};

/// The misfit of one sample: target via the robot (`F_i Y`) against via the camera (`X C_i`).
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct SampleResidual {
    /// Zero-based sample index.
    pub index: usize,
    /// Distance between the two target positions (mm).
    pub translation_mm: f64,
    /// Angle between the two target orientations (deg); none for point samples.
    pub rotation_deg: Option<f64>,
}

/// Summary of the residuals over all samples.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ResidualStats {
    /// Root mean square translation residual (mm).
    pub rms_mm: f64,
    /// Median translation residual (mm).
    pub median_mm: f64,
    /// Largest translation residual (mm).
    pub max_mm: f64,
    /// Root mean square rotation residual (deg); none without pose samples.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub rms_deg: Option<f64>,
    /// Largest rotation residual (deg); none without pose samples.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub max_deg: Option<f64>,
}

/// A solution evaluated on the samples.
#[derive(Debug, Clone, PartialEq)]
pub struct Evaluation {
    /// The solution.
    pub hand_eye: HandEye,
    /// Residual of every sample, in order.
    pub residuals: Vec<SampleResidual>,
    /// Their summary.
    pub stats: ResidualStats,
    /// The weighted cost the refinement minimises (sum of squares, see [`Weights`]).
    pub cost: f64,
}

/// The `flange_from_target` that best fits a given `base_from_camera`: the chordal
/// mean of `R_F⁻¹ R_X R_C` over pose samples (identity without any) and the mean of
/// `F⁻¹ X p` over all samples (the least-squares position), unless
/// `known_target_point` (flange frame, m) fixes it.
pub fn fit_target(
    samples: &[Sample],
    base_from_camera: &Pose,
    known_target_point: Option<Vector3<f64>>,
) -> Pose {
    let rotation = mean_rotation(samples.iter().filter_map(|s| match s {
        Sample::Pose(p) => Some(
            p.base_from_flange.rotation.inverse()
                * base_from_camera.rotation
                * p.camera_from_target.rotation,
        ),
        Sample::Point(_) => None,
    }));
    let position = known_target_point.unwrap_or_else(|| {
        let sum: Vector3<f64> = samples
            .iter()
            .map(|s| {
                s.base_from_flange()
                    .inverse_transform_point(&(base_from_camera * s.target_point_camera()))
                    .coords
            })
            .sum();
        sum / samples.len().max(1) as f64
    });
    Isometry3::from_parts(Translation3::from(position), rotation)
}

/// Translation (m, base frame) and rotation (rotation vector, rad) residual of one sample.
pub(super) fn sample_residual(
    sample: &Sample,
    he: &HandEye,
) -> (Vector3<f64>, Option<Vector3<f64>>) {
    let flange = sample.base_from_flange();
    match sample {
        Sample::Pose(p) => {
            let via_robot = flange * he.flange_from_target;
            let via_camera = he.base_from_camera * p.camera_from_target;
            (
                via_robot.translation.vector - via_camera.translation.vector,
                Some((via_camera.rotation.inverse() * via_robot.rotation).scaled_axis()),
            )
        }
        Sample::Point(p) => {
            let via_robot = flange * Point3::from(he.flange_from_target.translation.vector);
            let via_camera = he.base_from_camera * p.target_point_camera_m;
            (via_robot - via_camera, None)
        }
    }
}

/// All residuals divided by their weights, stacked (the refinement's residual vector).
pub(super) fn weighted_residuals(
    samples: &[Sample],
    he: &HandEye,
    weights: &Weights,
) -> DVector<f64> {
    let mut out = Vec::with_capacity(samples.len() * 6);
    for s in samples {
        let (t, r) = sample_residual(s, he);
        out.extend((t / weights.translation_m).iter());
        if let Some(r) = r {
            out.extend((r / weights.rotation_rad).iter());
        }
    }
    DVector::from_vec(out)
}

/// Evaluates a solution on every sample.
pub fn evaluate(samples: &[Sample], hand_eye: &HandEye, weights: &Weights) -> Evaluation {
    let residuals: Vec<SampleResidual> = samples
        .iter()
        .enumerate()
        .map(|(index, s)| {
            let (t, r) = sample_residual(s, hand_eye);
            SampleResidual {
                index,
                translation_mm: t.norm() * 1e3,
                rotation_deg: r.map(|r| r.norm().to_degrees()),
            }
        })
        .collect();
    let rms = |v: &[f64]| (v.iter().map(|x| x * x).sum::<f64>() / v.len().max(1) as f64).sqrt();
    let mut mm: Vec<f64> = residuals.iter().map(|r| r.translation_mm).collect();
    let deg: Vec<f64> = residuals.iter().filter_map(|r| r.rotation_deg).collect();
    let stats = ResidualStats {
        rms_mm: rms(&mm),
        max_mm: mm.iter().copied().fold(0.0, f64::max),
        median_mm: crate::stats::median(&mut mm),
        rms_deg: (!deg.is_empty()).then(|| rms(&deg)),
        max_deg: (!deg.is_empty()).then(|| deg.iter().copied().fold(0.0, f64::max)),
    };
    Evaluation {
        hand_eye: *hand_eye,
        residuals,
        stats,
        cost: weighted_residuals(samples, hand_eye, weights).norm_squared(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::calib::synthetic::{point_samples, pose_samples, Noise, SyntheticScene};
    use crate::geometry::pose_error;

    #[test]
    fn exact_solution_has_zero_residuals_and_fits_the_target() {
        let scene = SyntheticScene::nominal();
        let mut samples: Vec<Sample> = pose_samples(&scene, 5, &Noise::none(), 1)
            .into_iter()
            .map(Sample::Pose)
            .collect();
        samples.extend(
            point_samples(&scene, 3, &Noise::none(), 2)
                .into_iter()
                .map(Sample::Point),
        );
        let y = fit_target(&samples, &scene.base_from_camera, None);
        let (dp, dr) = pose_error(&y, &scene.flange_from_target);
        assert!(dp < 1e-12 && dr < 1e-9);
        let e = evaluate(&samples, &scene.hand_eye(), &Weights::default());
        assert!(e.stats.max_mm < 1e-9 && e.stats.max_deg.unwrap() < 1e-7 && e.cost < 1e-12);
        assert_eq!(e.residuals.len(), 8);
        assert!(e.residuals[5].rotation_deg.is_none() && e.residuals[4].rotation_deg.is_some());
    }

    #[test]
    fn a_known_camera_error_shows_in_mm_and_degrees() {
        // Shift the camera 3 mm along x and turn it 0.5° about its z axis: every pose
        // sample's target turns by 0.5°, and moves by 3 mm plus the turn's lever arm.
        let scene = SyntheticScene::nominal();
        let samples: Vec<Sample> = pose_samples(&scene, 6, &Noise::none(), 4)
            .into_iter()
            .map(Sample::Pose)
            .collect();
        let shift = Isometry3::translation(0.003, 0.0, 0.0);
        let mut he = scene.hand_eye();
        he.base_from_camera = shift * he.base_from_camera;
        let e = evaluate(&samples, &he, &Weights::default());
        for r in &e.residuals {
            assert!((r.translation_mm - 3.0).abs() < 1e-9 && r.rotation_deg.unwrap() < 1e-9);
        }
        let turn =
            nalgebra::UnitQuaternion::from_axis_angle(&Vector3::z_axis(), 0.5f64.to_radians());
        let mut he = scene.hand_eye();
        he.base_from_camera.rotation *= turn;
        let e = evaluate(&samples, &he, &Weights::default());
        for (r, s) in e.residuals.iter().zip(&samples) {
            let Sample::Pose(p) = s else { unreachable!() };
            let lever = p.camera_from_target.translation.vector;
            let moved = (turn * lever - lever).norm() * 1e3;
            assert!((r.rotation_deg.unwrap() - 0.5).abs() < 1e-9);
            assert!((r.translation_mm - moved).abs() < 1e-9);
        }
    }
}
