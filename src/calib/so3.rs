//! Rotation helpers shared by the solvers.

use nalgebra::{Matrix3, Rotation3, UnitQuaternion};

/// The rotation nearest (Frobenius) to `m`: the orthogonal polar factor `U Vᵀ` of
/// `m = U S Vᵀ`, with the last singular direction flipped if needed so det = +1.
/// This is also the maximiser of `tr(Rᵀ m)` over rotations.
pub(crate) fn project_to_so3(m: &Matrix3<f64>) -> UnitQuaternion<f64> {
    let svd = m.svd(true, true);
    let (Some(u), Some(v_t)) = (svd.u, svd.v_t) else {
        return UnitQuaternion::identity();
    };
    let mut d = Matrix3::identity();
    if (u * v_t).determinant() < 0.0 {
        // nalgebra sorts singular values in decreasing order: flip the smallest.
        d[(2, 2)] = -1.0;
    }
    UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix_unchecked(u * d * v_t))
}

/// The chordal mean of rotations (identity for none).
pub(super) fn mean_rotation(
    rotations: impl IntoIterator<Item = UnitQuaternion<f64>>,
) -> UnitQuaternion<f64> {
    let sum: Matrix3<f64> = rotations
        .into_iter()
        .map(|q| q.to_rotation_matrix().into_inner())
        .sum();
    project_to_so3(&sum)
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Vector3;

    #[test]
    fn projection_recovers_a_noisy_rotation_and_never_reflects() {
        let r = UnitQuaternion::from_euler_angles(0.3, -1.0, 2.0);
        let noisy = r.to_rotation_matrix().into_inner() * 2.0 + Matrix3::repeat(1e-3);
        assert!(project_to_so3(&noisy).angle_to(&r) < 1e-3);
        // A reflection projects to a proper rotation.
        let reflect = Matrix3::from_diagonal(&Vector3::new(1.0, 1.0, -1.0));
        let q = project_to_so3(&reflect);
        assert!((q.to_rotation_matrix().matrix().determinant() - 1.0).abs() < 1e-12);
    }

    #[test]
    fn mean_of_symmetric_rotations_is_the_middle() {
        let mid = UnitQuaternion::from_euler_angles(0.1, 0.2, 0.3);
        let d = UnitQuaternion::from_axis_angle(&Vector3::x_axis(), 0.2);
        let mean = mean_rotation([mid * d, mid * d.inverse()]);
        assert!(mean.angle_to(&mid) < 1e-12);
    }
}
