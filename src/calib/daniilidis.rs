//! Daniilidis (1999): rotation and translation of `X` at once, by dual quaternions.

use super::motions::motion_pairs;
use super::{CalibError, PoseSample};
use crate::geometry::Pose;
use nalgebra::{
    Isometry3, Quaternion, SMatrix, SymmetricEigen, Translation3, UnitQuaternion, Vector3, Vector4,
};

/// The dual quaternion `(q, q')` of a pose, `q' = ½ (0, t) q`, with `w(q) ≥ 0`.
fn dual_quaternion(pose: &Pose) -> (Quaternion<f64>, Quaternion<f64>) {
    let mut q = *pose.rotation.quaternion();
    if q.w < 0.0 {
        q = -q;
    }
    let t = pose.translation.vector;
    let dual = Quaternion::new(0.0, t.x, t.y, t.z) * q * 0.5;
    (q, dual)
}

/// `base_from_camera` by Daniilidis' hand–eye calibration with dual quaternions
/// (eye-to-hand, see the module doc).
///
/// For each pair the vector parts of `a q − q b = 0` and `a' q + a q' − q' b − q b' = 0`
/// give six linear equations in the eight numbers of `(q, q')`:
/// `[a−b, [a+b]×, 0, 0; a'−b', [a'+b']×, a−b, [a+b]×] (q, q') = 0` (vector parts).
/// The solution lies in the span of the two right singular vectors with the smallest
/// singular values; `|q| = 1` and `q·q' = 0` fix the combination.
pub fn daniilidis(samples: &[PoseSample]) -> Result<Pose, CalibError> {
    let pairs = motion_pairs(samples);
    if pairs.len() < 2 {
        return Err(CalibError::TooFewSamples {
            got: pairs.len(),
            need: 2,
            what: format!(
                "sample pairs rotating by ≥ {}° for daniilidis",
                super::MIN_PAIR_ROTATION_DEG
            ),
        });
    }
    // Normal matrix TᵀT of the stacked 6n × 8 system: its eigenvectors are T's right
    // singular vectors.
    let mut normal = SMatrix::<f64, 8, 8>::zeros();
    for p in &pairs {
        let (a, a_d) = dual_quaternion(&p.a);
        let (b, b_d) = dual_quaternion(&p.b);
        let (av, bv) = (a.imag(), b.imag());
        let (adv, bdv) = (a_d.imag(), b_d.imag());
        let mut s = SMatrix::<f64, 6, 8>::zeros();
        s.fixed_view_mut::<3, 1>(0, 0).copy_from(&(av - bv));
        s.fixed_view_mut::<3, 3>(0, 1)
            .copy_from(&(av + bv).cross_matrix());
        s.fixed_view_mut::<3, 1>(3, 0).copy_from(&(adv - bdv));
        s.fixed_view_mut::<3, 3>(3, 1)
            .copy_from(&(adv + bdv).cross_matrix());
        s.fixed_view_mut::<3, 1>(3, 4).copy_from(&(av - bv));
        s.fixed_view_mut::<3, 3>(3, 5)
            .copy_from(&(av + bv).cross_matrix());
        normal += s.transpose() * s;
    }
    let eig = SymmetricEigen::new(normal);
    let mut order: Vec<usize> = (0..8).collect();
    order.sort_by(|&i, &j| eig.eigenvalues[i].total_cmp(&eig.eigenvalues[j]));
    // Two-dimensional null space expected: the third smallest must stand out.
    let (l2, l3) = (
        eig.eigenvalues[order[1]].max(0.0),
        eig.eigenvalues[order[2]],
    );
    let condition = (l2 / l3.max(f64::MIN_POSITIVE)).sqrt();
    if l3.is_nan() || l3 <= 0.0 || condition.is_nan() || condition > 0.5 {
        return Err(CalibError::Singular {
            what: "daniilidis null space",
            condition,
        });
    }
    let v1 = eig.eigenvectors.column(order[0]).into_owned();
    let v2 = eig.eigenvectors.column(order[1]).into_owned();
    let (u1, w1) = (
        v1.fixed_rows::<4>(0).into_owned(),
        v1.fixed_rows::<4>(4).into_owned(),
    );
    let (u2, w2) = (
        v2.fixed_rows::<4>(0).into_owned(),
        v2.fixed_rows::<4>(4).into_owned(),
    );
    // q = l1 v1 + l2 v2 with q·q' = 0: c11 l1² + c12 l1 l2 + c22 l2² = 0.
    let c11 = u1.dot(&w1);
    let c12 = u1.dot(&w2) + u2.dot(&w1);
    let c22 = u2.dot(&w2);
    let norm2 = |l1: f64, l2: f64| (u1 * l1 + u2 * l2).norm_squared();
    let candidates: Vec<(f64, f64)> = if c11.abs() >= c22.abs() && c11.abs() > 1e-15 {
        // s = l1 / l2 solves c11 s² + c12 s + c22 = 0.
        quadratic_roots(c11, c12, c22)
            .into_iter()
            .map(|s| (s, 1.0))
            .collect()
    } else if c22.abs() > 1e-15 {
        // t = l2 / l1 solves c22 t² + c12 t + c11 = 0.
        quadratic_roots(c22, c12, c11)
            .into_iter()
            .map(|t| (1.0, t))
            .collect()
    } else {
        // Only the cross term: l1 = 0 or l2 = 0.
        vec![(1.0, 0.0), (0.0, 1.0)]
    };
    let (l1, l2) = candidates
        .into_iter()
        .max_by(|a, b| norm2(a.0, a.1).total_cmp(&norm2(b.0, b.1)))
        .unwrap_or((1.0, 0.0));
    let scale = 1.0 / norm2(l1, l2).sqrt();
    let real: Vector4<f64> = (u1 * l1 + u2 * l2) * scale;
    let dual: Vector4<f64> = (w1 * l1 + w2 * l2) * scale;
    // Vector layout is (w, x, y, z).
    let q = Quaternion::new(real[0], real[1], real[2], real[3]);
    let q_d = Quaternion::new(dual[0], dual[1], dual[2], dual[3]);
    let t: Vector3<f64> = (q_d * q.conjugate() * 2.0).imag();
    if !t.iter().all(|v| v.is_finite()) {
        return Err(CalibError::Singular {
            what: "daniilidis",
            condition: 0.0,
        });
    }
    Ok(Isometry3::from_parts(
        Translation3::from(t),
        UnitQuaternion::from_quaternion(q),
    ))
}

/// Real roots of `a x² + b x + c = 0` (`a ≠ 0`); a slightly negative discriminant
/// (noise) counts as zero.
fn quadratic_roots(a: f64, b: f64, c: f64) -> Vec<f64> {
    let disc = (b * b - 4.0 * a * c).max(0.0).sqrt();
    // Numerically stable form.
    let q = -0.5 * (b + b.signum() * disc);
    let mut roots = vec![q / a];
    if q != 0.0 {
        roots.push(c / q);
    }
    roots
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::calib::synthetic::{pose_samples, Noise, SyntheticScene};
    use crate::geometry::pose_error;

    #[test]
    fn exact_samples_give_the_exact_transform() {
        let scene = SyntheticScene::nominal();
        for seed in 0..5 {
            let samples = pose_samples(&scene, 6, &Noise::none(), seed);
            let x = daniilidis(&samples).unwrap();
            let (dp, dr) = pose_error(&x, &scene.base_from_camera);
            assert!(dp < 1e-8 && dr < 1e-9, "seed {seed}: {dp} m {dr} rad");
        }
    }

    #[test]
    fn dual_quaternion_reproduces_the_translation() {
        let pose = crate::geometry::pose_from_params(&[0.3, -0.2, 0.9, 1.0, -0.5, 2.5]);
        let (q, d) = dual_quaternion(&pose);
        let t = (d * q.conjugate() * 2.0).imag();
        assert!((t - pose.translation.vector).norm() < 1e-12);
        assert!(q.w >= 0.0);
    }

    #[test]
    fn quadratic_roots_are_roots() {
        for (a, b, c) in [(1.0, -3.0, 2.0), (2.0, 0.0, -8.0), (1e-3, 5.0, 1.0)] {
            for x in quadratic_roots(a, b, c) {
                assert!((a * x * x + b * x + c).abs() < 1e-9, "{a} {b} {c}: {x}");
            }
        }
    }
}
