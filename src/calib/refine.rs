//! Nonlinear least-squares refinement of `X` and `Y` over all samples.

use super::lm::levenberg_marquardt;
use super::residuals::weighted_residuals;
use super::{HandEye, Sample};
use nalgebra::{DVector, UnitQuaternion, Vector3};
use serde::{Deserialize, Serialize};

/// Most Levenberg–Marquardt steps taken.
const MAX_ITERATIONS: usize = 100;

/// How translation and rotation residuals are weighed against each other: each is
/// divided by its scale before squaring, so a residual of `translation_m` costs as
/// much as one of `rotation_rad`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Weights {
    /// Translation residual scale (m).
    pub translation_m: f64,
    /// Rotation residual scale (rad).
    pub rotation_rad: f64,
}

impl Default for Weights {
    /// 0.5 mm weighs as much as 0.2°: the noise of a board detector at about 1 m
    /// (per axis), as in [`Noise::typical`](super::synthetic::Noise::typical).
    fn default() -> Self {
        Weights {
            translation_m: 0.5e-3,
            rotation_rad: 0.2f64.to_radians(),
        }
    }
}

/// The outcome of [`refine`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Refined {
    /// The refined solution (the start itself if no step lowered the cost).
    pub hand_eye: HandEye,
    /// Weighted cost (sum of squares) at the start.
    pub start_cost: f64,
    /// Weighted cost at the result; never above `start_cost`.
    pub cost: f64,
    /// Accepted Levenberg–Marquardt steps.
    pub iterations: usize,
}

/// Refines `start` by Levenberg–Marquardt on the weighted residuals of
/// `F_i Y = X C_i` (translation and rotation for pose samples, translation for point
/// samples). Parameters: `X`'s rotation (perturbed in the base frame) and
/// translation, `Y`'s translation (unless `known_target_point` fixes it, flange
/// frame, m) and `Y`'s rotation (only with pose samples; points cannot see it).
/// Only cost-lowering steps are taken, so the result is never worse than `start`.
pub fn refine(
    samples: &[Sample],
    start: &HandEye,
    known_target_point: Option<Vector3<f64>>,
    weights: &Weights,
) -> Refined {
    let mut start = *start;
    if let Some(p) = known_target_point {
        start.flange_from_target.translation.vector = p;
    }
    let free_position = known_target_point.is_none();
    let free_rotation = samples.iter().any(|s| matches!(s, Sample::Pose(_)));
    let n = 6 + 3 * usize::from(free_position) + 3 * usize::from(free_rotation);
    let retract = |he: &HandEye, d: &DVector<f64>| {
        let mut out = *he;
        let v = |k: usize| Vector3::new(d[k], d[k + 1], d[k + 2]);
        out.base_from_camera.rotation =
            UnitQuaternion::from_scaled_axis(v(0)) * out.base_from_camera.rotation;
        out.base_from_camera.translation.vector += v(3);
        let mut k = 6;
        if free_position {
            out.flange_from_target.translation.vector += v(k);
            k += 3;
        }
        if free_rotation {
            out.flange_from_target.rotation *= UnitQuaternion::from_scaled_axis(v(k));
        }
        out
    };
    let outcome = levenberg_marquardt(
        start,
        n,
        |he| weighted_residuals(samples, he, weights),
        retract,
        MAX_ITERATIONS,
    );
    Refined {
        hand_eye: outcome.state,
        start_cost: outcome.start_cost,
        cost: outcome.cost,
        iterations: outcome.iterations,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::calib::synthetic::{pose_samples, Noise, SyntheticScene};
    use crate::geometry::{pose_error, pose_from_params};

    #[test]
    fn converges_from_a_poor_start_on_exact_samples() {
        let scene = SyntheticScene::nominal();
        let samples: Vec<Sample> = pose_samples(&scene, 10, &Noise::none(), 5)
            .into_iter()
            .map(Sample::Pose)
            .collect();
        // 5 cm and ~6° off on the camera, 2 cm and ~6° off on the target.
        let mut start = scene.hand_eye();
        start.base_from_camera =
            pose_from_params(&[0.03, -0.04, 0.0, 0.05, -0.08, 0.0]) * start.base_from_camera;
        start.flange_from_target *= pose_from_params(&[0.0, 0.02, 0.0, 0.0, 0.1, 0.0]);
        let r = refine(&samples, &start, None, &Weights::default());
        let (dp, dr) = pose_error(&r.hand_eye.base_from_camera, &scene.base_from_camera);
        assert!(
            dp < 1e-7 && dr < 1e-8,
            "{dp} m, {dr} rad after {} steps",
            r.iterations
        );
        let (dp, dr) = pose_error(&r.hand_eye.flange_from_target, &scene.flange_from_target);
        assert!(dp < 1e-7 && dr < 1e-8);
        assert!(r.cost < 1e-9 * r.start_cost);
    }
}
