//! Relative motions `A_ij X = X B_ij` and the checks that they can determine `X`.

use super::{CalibError, PoseSample};
use crate::geometry::Pose;
use nalgebra::{Matrix3, SymmetricEigen, UnitQuaternion, Vector3};
use serde::Serialize;

/// A pair of samples is used only if the flange turns by at least this (deg) between
/// them; below it the rotation axis is dominated by noise.
pub const MIN_PAIR_ROTATION_DEG: f64 = 5.0;
/// The relative rotation axes must spread by at least this (deg; for two axes, the
/// angle between them), or the camera's rotation about their common axis is unobservable.
pub const MIN_AXIS_SPREAD_DEG: f64 = 10.0;
/// Pairs turning between these angles (deg) are used for the frame check (outside,
/// the axis is ill-defined).
const FRAME_CHECK_ANGLES_DEG: (f64, f64) = (15.0, 165.0);
/// The frame check fails above this median rotation angle difference (deg)...
const MAX_ANGLE_MISMATCH_DEG: f64 = 2.0;
/// ... or above this median difference of translation along the screw axis (m).
const MAX_PITCH_MISMATCH_M: f64 = 0.02;

/// How well the robot's motions determine the calibration.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Conditioning {
    /// Number of samples.
    pub samples: usize,
    /// Pairs of samples turning by at least [`MIN_PAIR_ROTATION_DEG`].
    pub usable_pairs: usize,
    /// The largest rotation between two samples (deg).
    pub max_pair_rotation_deg: f64,
    /// Spread of the relative rotation axes (deg; for two axes, the angle between them).
    pub axis_spread_deg: f64,
    /// The principal relative rotation axis (unit, base frame).
    pub common_axis: [f64; 3],
}

/// One relative motion: `a = F_j F_i⁻¹` (base frame), `b = C_j C_i⁻¹` (camera frame).
#[derive(Debug, Clone, Copy)]
pub(super) struct MotionPair {
    pub a: Pose,
    pub b: Pose,
}

/// The unit axis and angle in `[0, pi]` of a rotation (axis x for no rotation).
pub(super) fn axis_angle(q: &UnitQuaternion<f64>) -> (Vector3<f64>, f64) {
    let (w, v) = (q.w, q.vector().into_owned());
    let (w, v) = if w < 0.0 { (-w, -v) } else { (w, v) };
    let s = v.norm();
    let angle = 2.0 * s.atan2(w);
    if s > 0.0 {
        (v / s, angle)
    } else {
        (Vector3::x(), 0.0)
    }
}

/// All pairs `i < j` of samples whose flange turns by at least [`MIN_PAIR_ROTATION_DEG`].
pub(super) fn motion_pairs(samples: &[PoseSample]) -> Vec<MotionPair> {
    let min = MIN_PAIR_ROTATION_DEG.to_radians();
    let mut pairs = Vec::new();
    for (i, si) in samples.iter().enumerate() {
        let flange_inv = si.base_from_flange.inverse();
        let target_inv = si.camera_from_target.inverse();
        for sj in &samples[i + 1..] {
            let a = sj.base_from_flange * flange_inv;
            if a.rotation.angle() >= min {
                pairs.push(MotionPair {
                    a,
                    b: sj.camera_from_target * target_inv,
                });
            }
        }
    }
    pairs
}

/// Checks that the flange poses can determine a calibration: at least 3 samples,
/// rotations of at least [`MIN_PAIR_ROTATION_DEG`] between some samples, and
/// rotation axes spread by at least [`MIN_AXIS_SPREAD_DEG`].
pub fn check_motions(base_from_flange: &[Pose]) -> Result<Conditioning, CalibError> {
    let c = measure_motions(base_from_flange)?;
    if c.usable_pairs == 0 {
        return Err(CalibError::RotationsTooSmall {
            max_deg: c.max_pair_rotation_deg,
            need_deg: MIN_PAIR_ROTATION_DEG,
        });
    }
    if c.axis_spread_deg < MIN_AXIS_SPREAD_DEG {
        return Err(CalibError::ParallelAxes {
            spread_deg: c.axis_spread_deg,
            need_deg: MIN_AXIS_SPREAD_DEG,
            axis: c.common_axis,
        });
    }
    Ok(c)
}

/// The conditioning of the flange poses without the rotation checks (at least 3
/// samples are still required); spread 0 when no pair turns enough.
pub fn measure_motions(base_from_flange: &[Pose]) -> Result<Conditioning, CalibError> {
    let n = base_from_flange.len();
    if n < super::samples::MIN_SAMPLES {
        return Err(CalibError::TooFewSamples {
            got: n,
            need: super::samples::MIN_SAMPLES,
            what: "samples".into(),
        });
    }
    let min = MIN_PAIR_ROTATION_DEG.to_radians();
    let mut max_angle: f64 = 0.0;
    let mut scatter = Matrix3::zeros();
    let mut usable = 0;
    for (i, fi) in base_from_flange.iter().enumerate() {
        for fj in &base_from_flange[i + 1..] {
            let (axis, angle) = axis_angle(&(fj.rotation * fi.rotation.inverse()));
            max_angle = max_angle.max(angle);
            if angle >= min {
                scatter += axis * axis.transpose();
                usable += 1;
            }
        }
    }
    let mut conditioning = Conditioning {
        samples: n,
        usable_pairs: usable,
        max_pair_rotation_deg: max_angle.to_degrees(),
        axis_spread_deg: 0.0,
        common_axis: [0.0, 0.0, 0.0],
    };
    if usable > 0 {
        let eig = SymmetricEigen::new(scatter / usable as f64);
        let mut order: Vec<usize> = (0..3).collect();
        order.sort_by(|&a, &b| eig.eigenvalues[b].total_cmp(&eig.eigenvalues[a]));
        let (l1, l2) = (
            eig.eigenvalues[order[0]],
            eig.eigenvalues[order[1]].max(0.0),
        );
        conditioning.axis_spread_deg = (2.0 * (l2 / l1).sqrt().atan()).to_degrees();
        let axis = eig.eigenvectors.column(order[0]);
        conditioning.common_axis = [axis[0], axis[1], axis[2]];
    }
    Ok(conditioning)
}

/// Median rotation-angle and screw-pitch differences (rad, m) between robot and
/// target motions, over pairs turning within [`FRAME_CHECK_ANGLES_DEG`].
fn congruence(pairs: impl Iterator<Item = (Pose, Pose)>) -> Option<(f64, f64, usize)> {
    let (lo, hi) = (
        FRAME_CHECK_ANGLES_DEG.0.to_radians(),
        FRAME_CHECK_ANGLES_DEG.1.to_radians(),
    );
    let mut angles = Vec::new();
    let mut pitches = Vec::new();
    for (a, b) in pairs {
        let (na, ta) = axis_angle(&a.rotation);
        if !(lo..=hi).contains(&ta) {
            continue;
        }
        let (nb, tb) = axis_angle(&b.rotation);
        angles.push((ta - tb).abs());
        pitches.push((a.translation.vector.dot(&na) - b.translation.vector.dot(&nb)).abs());
    }
    if angles.is_empty() {
        return None;
    }
    let n = angles.len();
    let med = |v: &mut Vec<f64>| crate::stats::median(v);
    Some((med(&mut angles), med(&mut pitches), n))
}

fn congruent(angle: f64, pitch: f64) -> bool {
    angle <= MAX_ANGLE_MISMATCH_DEG.to_radians() && pitch <= MAX_PITCH_MISMATCH_M
}

/// Checks that robot and target motions are congruent (`A = X B X⁻¹` turns by the
/// same angle and moves by the same amount along its axis as `B`), which catches
/// mismatched samples, a wrong quaternion order and mixed units before solving.
/// (Inverting every robot pose, or every observation, keeps each pair congruent;
/// [`solve`](super::solve) catches that by its residuals.)
pub fn check_frames(samples: &[PoseSample]) -> Result<(), CalibError> {
    let pairs = motion_pairs(samples);
    let Some((angle, pitch, n)) = congruence(pairs.iter().map(|p| (p.a, p.b))) else {
        return Ok(()); // No pair turns enough to judge; check_motions guards the rest.
    };
    if congruent(angle, pitch) {
        return Ok(());
    }
    let hint = if angle > MAX_ANGLE_MISMATCH_DEG.to_radians() {
        "check that each sample pairs the robot pose and the observation captured at the same moment, quaternions are x y z w, and rpy is fixed-axis X-Y-Z in radians"
    } else {
        "check that robot and camera translations are both in metres, each sample pairs the robot pose and observation of the same moment, and the target is rigid on the flange"
    }
    .to_string();
    Err(CalibError::FramesInconsistent {
        pairs: n,
        angle_deg: angle.to_degrees(),
        pitch_mm: pitch * 1e3,
        hint,
    })
}

/// The translation of `X` given its rotation: least squares over the pairs of
/// `(R_A − I) t_X = R_X t_B − t_A`.
pub(super) fn solve_translation(
    pairs: &[MotionPair],
    rotation: &UnitQuaternion<f64>,
) -> Result<Vector3<f64>, CalibError> {
    let mut ata = Matrix3::zeros();
    let mut atb = Vector3::zeros();
    for p in pairs {
        let m = p.a.rotation.to_rotation_matrix().into_inner() - Matrix3::identity();
        let rhs = rotation * p.b.translation.vector - p.a.translation.vector;
        ata += m.transpose() * m;
        atb += m.transpose() * rhs;
    }
    solve_3x3(&ata, &atb, "translation of base_from_camera")
}

/// Solves a symmetric positive semi-definite 3×3 system, or reports it singular.
pub(super) fn solve_3x3(
    m: &Matrix3<f64>,
    rhs: &Vector3<f64>,
    what: &'static str,
) -> Result<Vector3<f64>, CalibError> {
    let svd = m.svd(true, true);
    let max = svd.singular_values.max();
    let min = svd.singular_values.min();
    let condition = if max > 0.0 { min / max } else { 0.0 };
    if condition.is_nan() || condition <= 1e-10 {
        return Err(CalibError::Singular { what, condition });
    }
    svd.solve(rhs, 0.0)
        .map_err(|_| CalibError::Singular { what, condition })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::pose_from_params;

    fn about(axis: Vector3<f64>, angles_deg: &[f64]) -> Vec<Pose> {
        let base = pose_from_params(&[0.6, 0.0, 0.4, 3.1, 0.0, 0.0]);
        angles_deg
            .iter()
            .enumerate()
            .map(|(i, a)| {
                let r = UnitQuaternion::from_scaled_axis(axis.normalize() * a.to_radians());
                let mut p = base;
                p.rotation = r * base.rotation;
                p.translation.vector.x += 0.05 * i as f64;
                p
            })
            .collect()
    }

    #[test]
    fn axis_angle_takes_the_short_way() {
        let q = UnitQuaternion::from_scaled_axis(Vector3::new(0.0, 0.0, -0.5));
        let neg = UnitQuaternion::new_unchecked(-q.into_inner());
        for q in [q, neg] {
            let (n, a) = axis_angle(&q);
            assert!((a - 0.5).abs() < 1e-12 && (n + Vector3::z()).norm() < 1e-12);
        }
    }

    #[test]
    fn spread_of_two_axes_is_their_angle() {
        let mut poses = about(Vector3::z(), &[0.0, 20.0]);
        poses.extend(about(Vector3::new(0.0, 1.0, 1.0), &[20.0]));
        // Pairs: z (20°), (0,1,1)-ish, and the mixed one: the spread lies between.
        let c = check_motions(&poses).unwrap();
        assert_eq!(c.usable_pairs, 3);
        assert!(
            c.axis_spread_deg > 20.0 && c.axis_spread_deg < 90.0,
            "{c:?}"
        );
    }

    #[test]
    fn degenerate_motions_say_what_to_change() {
        let err = check_motions(&about(Vector3::z(), &[0.0, 30.0])).unwrap_err();
        assert!(matches!(
            err,
            CalibError::TooFewSamples {
                got: 2,
                need: 3,
                ..
            }
        ));
        let err = check_motions(&about(Vector3::z(), &[0.0, 30.0, 60.0, -45.0])).unwrap_err();
        let text = err.to_string();
        assert!(
            matches!(err, CalibError::ParallelAxes { spread_deg, axis, .. } if spread_deg < 1e-3 && axis[2].abs() > 1.0 - 1e-9),
            "{text}"
        );
        assert!(
            text.contains("add poses rotating about a different axis"),
            "{text}"
        );
        let err =
            check_motions(&about(Vector3::new(1.0, 2.0, 0.0), &[0.0, 1.0, 2.0, 3.0])).unwrap_err();
        assert!(
            matches!(err, CalibError::RotationsTooSmall { max_deg, .. } if (max_deg - 3.0).abs() < 1e-9),
            "{err}"
        );
        assert!(err.to_string().contains("rotate the hand"));
    }
}
