//! Stability ranges of a grasp (specs/method.md): the grasp's pose (palm in the object
//! frame) is moved along one DOF at a time — translation along the object frame's x,
//! y, z, and rotation about the palm's **own** x, y, z axes (the components of the
//! rotation vector `log(R_theta^T R)` the planner's kernels measure,
//! [`crate::plan::chart`]; never a difference of Euler angles, which at pitch -90 deg
//! would turn the hand about one axis twice and never about the other) — in both
//! directions, in fixed steps, re-simulating the auto-grasp each time,
//! until the grasp is no longer force closure, or a cap is reached. A displaced
//! hand whose open pre-shape would intersect the object is backed off along its
//! approach axis until clear (by at most [`StabilityOptions::retreat_m`]), as the
//! arm's approach along the palm's z stops at contact; beyond that it counts as
//! unstable. Without this, every grasp with the palm on the object would have a
//! range of half a step toward it. The range in one direction is the midpoint between the last stable
//! and the first unstable displacement (so at least half a step), or the cap when
//! every step up to it is stable; `Delta_d = (Delta_d1 + Delta_d2) / 2` and
//! `sigma_d = Delta_d / c` with `c = 3` (the three-sigma rule).
//!
//! The ranges presume the grasp itself is force closure; check that first.

use super::autograsp::{
    evaluate_grasp, retreat_until_clear, AutoGraspOptions, GraspObject, GraspSimError,
};
use super::QualityParams;
use crate::geometry::{pose_from_params, Pose, PoseParams};
use crate::robot::hand::HandModel;
use crate::robot::HandPose;
use nalgebra::{UnitQuaternion, Vector3};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

/// Steps and caps of the stability search.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct StabilityOptions {
    /// Translation step (m).
    pub step_m: f64,
    /// Rotation step (rad).
    pub step_rad: f64,
    /// Largest translation tried (m).
    pub cap_m: f64,
    /// Largest rotation tried (rad).
    pub cap_rad: f64,
    /// sigma = Delta / c.
    pub sigma_divisor: f64,
    /// Largest back-off along the palm's -z of a displaced hand that starts in
    /// collision (m); 0 makes any such start unstable.
    pub retreat_m: f64,
}

impl Default for StabilityOptions {
    fn default() -> Self {
        StabilityOptions {
            step_m: 0.002,
            step_rad: 2f64.to_radians(),
            cap_m: 0.03,
            cap_rad: 30f64.to_radians(),
            sigma_divisor: 3.0,
            retreat_m: 0.02,
        }
    }
}

impl StabilityOptions {
    /// Checks that steps, caps and the divisor are positive and finite, caps >= steps.
    pub fn validate(&self) -> Result<(), GraspSimError> {
        let fields = [
            ("step_m", self.step_m),
            ("step_rad", self.step_rad),
            ("cap_m", self.cap_m),
            ("cap_rad", self.cap_rad),
            ("sigma_divisor", self.sigma_divisor),
        ];
        for (field, value) in fields {
            if !(value.is_finite() && value > 0.0) {
                return Err(GraspSimError::Option {
                    field,
                    value,
                    problem: "must be finite and > 0",
                });
            }
        }
        if !(self.retreat_m.is_finite() && self.retreat_m >= 0.0) {
            return Err(GraspSimError::Option {
                field: "retreat_m",
                value: self.retreat_m,
                problem: "must be finite and >= 0",
            });
        }
        if self.cap_m < self.step_m || self.cap_rad < self.step_rad {
            return Err(GraspSimError::Option {
                field: "cap_m/cap_rad",
                value: self.cap_m.min(self.cap_rad),
                problem: "each cap must be at least its step",
            });
        }
        Ok(())
    }

    fn step_and_cap(&self, dof: usize) -> (f64, f64) {
        if dof < 3 {
            (self.step_m, self.cap_m)
        } else {
            (self.step_rad, self.cap_rad)
        }
    }
}

/// Per-DOF stability ranges, in order `[x, y, z, rx, ry, rz]`: translation along the
/// object frame's axes (m), rotation about the palm's own axes (rad).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct StabilityRange {
    /// Range in the negative direction, Delta_d1.
    pub minus: [f64; 6],
    /// Range in the positive direction, Delta_d2.
    pub plus: [f64; 6],
    /// Delta_d = (Delta_d1 + Delta_d2) / 2.
    pub delta: [f64; 6],
    /// sigma_d = Delta_d / c.
    pub sigma: [f64; 6],
}

/// The pose of `params` moved by `offset` along DOF `dof`: translation along the object
/// frame's axis `dof` (0..3), or rotation about the palm's own axis `dof - 3`.
pub fn displaced(params: &PoseParams, dof: usize, offset: f64) -> Pose {
    let pose = pose_from_params(params);
    if dof < 3 {
        let mut p = pose;
        p.translation.vector[dof] += offset;
        p
    } else {
        let mut w = Vector3::zeros();
        w[dof - 3] = offset;
        pose * UnitQuaternion::from_scaled_axis(w)
    }
}

/// The stability ranges of the grasp at `params` (palm in the object frame) from
/// `preshape` (spread and flex before closing); the twelve directions run in
/// parallel.
pub fn stability_range(
    hand: &HandModel,
    object: &GraspObject,
    params: &PoseParams,
    preshape: &HandPose,
    grasp: &AutoGraspOptions,
    quality: &QualityParams,
    options: &StabilityOptions,
) -> Result<StabilityRange, GraspSimError> {
    options.validate()?;
    let stable = |p: &Pose| -> Result<bool, GraspSimError> {
        let Some(pose) = retreat_until_clear(hand, object, p, preshape, options.retreat_m) else {
            return Ok(false);
        };
        let e = evaluate_grasp(hand, object, &pose, preshape, grasp, quality, false)?;
        Ok(e.outcome.collision_at_start.is_none() && e.force_closure)
    };
    let ranges: Vec<f64> = (0..12)
        .into_par_iter()
        .map(|i| {
            let (dof, sign) = (i / 2, if i % 2 == 0 { -1.0 } else { 1.0 });
            let (step, cap) = options.step_and_cap(dof);
            let mut k = 1usize;
            loop {
                let offset = k as f64 * step;
                if offset > cap * (1.0 + 1e-9) {
                    return Ok(cap);
                }
                if !stable(&displaced(params, dof, sign * offset))? {
                    return Ok(offset - 0.5 * step);
                }
                k += 1;
            }
        })
        .collect::<Result<_, GraspSimError>>()?;
    let mut range = StabilityRange {
        minus: [0.0; 6],
        plus: [0.0; 6],
        delta: [0.0; 6],
        sigma: [0.0; 6],
    };
    for d in 0..6 {
        range.minus[d] = ranges[2 * d];
        range.plus[d] = ranges[2 * d + 1];
        range.delta[d] = 0.5 * (range.minus[d] + range.plus[d]);
        range.sigma[d] = range.delta[d] / options.sigma_divisor;
    }
    Ok(range)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::quality::autograsp::tests::{cylinder, hand_of, side_pose};
    use crate::robot::shipped_robot;
    use std::path::Path;

    #[test]
    fn rotations_turn_the_hand_about_its_own_axes_even_at_pitch_minus_90() {
        // A side grasp at the rpy singularity: each rotation DOF turns the palm by
        // exactly the offset, about three different axes.
        let params = [0.0, 0.08, 0.06, -1.571, -1.552, -1.571];
        let base = pose_from_params(&params);
        let mut axes = Vec::new();
        for dof in 3..6 {
            let moved = displaced(&params, dof, 0.05);
            let (dp, dr) = crate::geometry::pose_error(&base, &moved);
            assert!(dp < 1e-12 && (dr - 0.05).abs() < 1e-9, "{dof}: {dp} {dr}");
            let turn = base.rotation.inverse() * moved.rotation;
            axes.push(turn.axis().unwrap().into_inner());
        }
        for (i, a) in axes.iter().enumerate() {
            assert!((a[i] - 1.0).abs() < 1e-9, "{i}: {a}");
        }
        let moved = displaced(&params, 1, -0.01);
        assert!((moved.translation.y - 0.07).abs() < 1e-12);
    }

    #[test]
    fn side_grasp_of_a_long_cylinder_is_more_stable_along_its_axis() {
        let robot = shipped_robot();
        let hand = hand_of(&robot);
        let radius = 0.035;
        let object = GraspObject::new(&cylinder(radius, 0.4, 96), Path::new("cylinder")).unwrap();
        let params = crate::geometry::params_from_pose(&side_pose(radius, 2e-4));
        let options = StabilityOptions::default();
        let r = stability_range(
            &hand,
            &object,
            &params,
            &HandPose::open(0.0),
            &AutoGraspOptions::default(),
            &QualityParams::default(),
            &options,
        )
        .unwrap();
        // Translation along the axis of a long cylinder leaves the grasp as it is:
        // the cap in both directions.
        assert_eq!(
            (r.minus[2], r.plus[2]),
            (options.cap_m, options.cap_m),
            "{r:?}"
        );
        // Along the approach (x) the palm leaves the surface one way (no closure
        // from the fingers alone) and the approach stops at contact the other way
        // (up to the retreat limit): less than along the axis.
        assert!(r.delta[0] < r.delta[2], "{r:?}");
        assert!(r.minus[0] < r.plus[0], "{r:?}");
        for d in 0..6 {
            assert!(r.delta[d] > 0.0 && (r.sigma[d] - r.delta[d] / 3.0).abs() < 1e-15);
            assert!((r.delta[d] - 0.5 * (r.minus[d] + r.plus[d])).abs() < 1e-15);
        }
    }

    #[test]
    fn ranges_are_multiples_of_the_step_midpoints_or_the_cap() {
        let robot = shipped_robot();
        let hand = hand_of(&robot);
        let radius = 0.035;
        let object = GraspObject::new(&cylinder(radius, 0.1, 64), Path::new("cylinder")).unwrap();
        let params = crate::geometry::params_from_pose(&side_pose(radius, 2e-4));
        let options = StabilityOptions {
            step_m: 0.005,
            step_rad: 0.1,
            cap_m: 0.05,
            cap_rad: 0.5,
            ..StabilityOptions::default()
        };
        let r = stability_range(
            &hand,
            &object,
            &params,
            &HandPose::open(0.0),
            &AutoGraspOptions::default(),
            &QualityParams::default(),
            &options,
        )
        .unwrap();
        for d in 0..6 {
            let (step, cap) = if d < 3 { (0.005, 0.05) } else { (0.1, 0.5) };
            for v in [r.minus[d], r.plus[d]] {
                let k = v / step - 0.5;
                assert!(v == cap || (k - k.round()).abs() < 1e-9, "dof {d}: {v}");
            }
        }
        // Mirror symmetry about the cylinder's mid-plane.
        assert_eq!(r.minus[2], r.plus[2]);
        let bad = StabilityOptions {
            cap_m: 0.001,
            ..options
        };
        assert!(bad.validate().unwrap_err().to_string().contains("cap"));
    }
}
