//! Orientation on the rotation group: the difference between a candidate palm pose
//! and an example grasp, and the local charts the optimiser searches in.
//!
//! **The difference `d`** (eq. 5): translation `t_X - t_theta` in the model frame
//! (m), and orientation the rotation vector `log(R_theta^T R_X)` (rad), i.e. the
//! rotation that takes the example grasp's orientation to the candidate's, expressed
//! about the example grasp's own axes (x, y, z of its palm frame). Its norm is the
//! angle between the two orientations, whatever their Euler angles: two grasps 5 deg
//! apart are 5 deg apart also at pitch -90 deg, where roll and yaw are ill-defined
//! and a difference of rpy angles can read several radians. This is the paper's
//! intent, a distance in orientation, for every kernel and method; the stability
//! ranges of the database are measured along the same axes
//! ([`crate::quality::stability`]).
//!
//! **The search chart.** Each Nelder–Mead run searches `[x, y, u, r1, r2, r3]`
//! around a centre orientation `R_0`: position `(x, y, z_min + u^2)` (the paper's
//! transformation of the table bound) and orientation `R_0 exp([r]_x)`. Centred on
//! the run's start, a search never crosses a singularity of a parametrisation (the
//! chart is smooth for |r| < pi, far more than a local search moves).
//!
//! Plain arrays, not nalgebra matrices, in the hot loop of the objective.

use crate::geometry::Pose;
use nalgebra::{Isometry3, Quaternion, Translation3, UnitQuaternion, Vector3};

/// A rotation matrix, by rows.
pub type Mat3 = [[f64; 3]; 3];

/// `a * b`.
#[inline]
pub fn mul(a: &Mat3, b: &Mat3) -> Mat3 {
    std::array::from_fn(|i| {
        std::array::from_fn(|j| a[i][0] * b[0][j] + a[i][1] * b[1][j] + a[i][2] * b[2][j])
    })
}

/// `a^T * b`.
#[inline]
pub fn mul_transposed(a: &Mat3, b: &Mat3) -> Mat3 {
    std::array::from_fn(|i| {
        std::array::from_fn(|j| a[0][i] * b[0][j] + a[1][i] * b[1][j] + a[2][i] * b[2][j])
    })
}

/// `R = Rz(az) Ry(ay) Rx(ax)` as rows (the URDF rpy convention of
/// [`crate::geometry::pose_from_params`]).
#[inline]
pub fn rotation_from_rpy(ax: f64, ay: f64, az: f64) -> Mat3 {
    let (sr, cr) = ax.sin_cos();
    let (sp, cp) = ay.sin_cos();
    let (sy, cy) = az.sin_cos();
    [
        [cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
        [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
        [-sp, cp * sr, cp * cr],
    ]
}

/// The rotation matrix of a pose, by rows.
#[inline]
pub fn matrix_of(pose: &Pose) -> Mat3 {
    let r = pose.rotation.to_rotation_matrix();
    std::array::from_fn(|i| std::array::from_fn(|j| r[(i, j)]))
}

/// The rotation vector (axis times angle, angle in `[0, pi]`) of a rotation matrix:
/// the logarithm map of SO(3). Through the quaternion (Shepperd's method), so it is
/// accurate at every angle, 0 and pi included.
#[inline]
pub fn rotation_vector(m: &Mat3) -> [f64; 3] {
    let trace = m[0][0] + m[1][1] + m[2][2];
    // The unit quaternion (w, x, y, z), up to its sign.
    let (w, x, y, z) = if trace > 0.0 {
        let s = (trace + 1.0).sqrt() * 2.0;
        (
            0.25 * s,
            (m[2][1] - m[1][2]) / s,
            (m[0][2] - m[2][0]) / s,
            (m[1][0] - m[0][1]) / s,
        )
    } else if m[0][0] > m[1][1] && m[0][0] > m[2][2] {
        let s = (1.0 + m[0][0] - m[1][1] - m[2][2]).sqrt() * 2.0;
        (
            (m[2][1] - m[1][2]) / s,
            0.25 * s,
            (m[0][1] + m[1][0]) / s,
            (m[0][2] + m[2][0]) / s,
        )
    } else if m[1][1] > m[2][2] {
        let s = (1.0 + m[1][1] - m[0][0] - m[2][2]).sqrt() * 2.0;
        (
            (m[0][2] - m[2][0]) / s,
            (m[0][1] + m[1][0]) / s,
            0.25 * s,
            (m[1][2] + m[2][1]) / s,
        )
    } else {
        let s = (1.0 + m[2][2] - m[0][0] - m[1][1]).sqrt() * 2.0;
        (
            (m[1][0] - m[0][1]) / s,
            (m[0][2] + m[2][0]) / s,
            (m[1][2] + m[2][1]) / s,
            0.25 * s,
        )
    };
    // The representative with w >= 0 gives the angle in [0, pi].
    let (w, x, y, z) = if w < 0.0 {
        (-w, -x, -y, -z)
    } else {
        (w, x, y, z)
    };
    let n = (x * x + y * y + z * z).sqrt();
    if n < 1e-300 {
        return [0.0; 3];
    }
    // angle = 2 atan2(|v|, w).
    let k = 2.0 * n.atan2(w) / n;
    [k * x, k * y, k * z]
}

/// The difference `d` of eq. 5 between the candidate palm pose in the model frame,
/// `model_from_palm` (rotation `r`, translation `t`), and an example grasp
/// (rotation `theta_r`, translation `theta_t`): `[t - theta_t, log(theta_r^T r)]`.
#[inline]
pub fn difference(r: &Mat3, t: &[f64; 3], theta_r: &Mat3, theta_t: &[f64; 3]) -> [f64; 6] {
    let w = rotation_vector(&mul_transposed(theta_r, r));
    [
        t[0] - theta_t[0],
        t[1] - theta_t[1],
        t[2] - theta_t[2],
        w[0],
        w[1],
        w[2],
    ]
}

/// [`difference`] of two poses (candidate and example grasp, both in the model frame).
pub fn pose_difference(model_from_palm: &Pose, theta: &Pose) -> [f64; 6] {
    let t = model_from_palm.translation.vector;
    let tt = theta.translation.vector;
    difference(
        &matrix_of(model_from_palm),
        &[t.x, t.y, t.z],
        &matrix_of(theta),
        &[tt.x, tt.y, tt.z],
    )
}

/// The pose turned by the rotation vector `w` about its own axes: `pose * exp([w]_x)`.
pub fn rotated_about_own_axes(pose: &Pose, w: [f64; 3]) -> Pose {
    pose * UnitQuaternion::from_scaled_axis(Vector3::from(w))
}

/// A local chart of palm poses (see the module doc): `[x, y, u, r1, r2, r3]` with
/// `z = z_min + u^2` and orientation `centre * exp([r]_x)`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Chart {
    /// The orientation at `r = 0`.
    pub centre: UnitQuaternion<f64>,
    /// Lowest palm height (m).
    pub z_min_m: f64,
}

impl Chart {
    /// The chart centred on `pose`'s orientation.
    pub fn at(pose: &Pose, z_min_m: f64) -> Chart {
        Chart {
            centre: pose.rotation,
            z_min_m,
        }
    }

    /// The pose of chart coordinates `x` (six of them).
    pub fn pose(&self, x: &[f64]) -> Pose {
        let r = Vector3::new(x[3], x[4], x[5]);
        Isometry3::from_parts(
            Translation3::new(x[0], x[1], self.z_min_m + x[2] * x[2]),
            self.centre * UnitQuaternion::from_scaled_axis(r),
        )
    }

    /// The chart coordinates of `pose` (`u = sqrt(z - z_min)`, 0 below the bound;
    /// the rotation vector of `centre^-1 * R`, the shortest one).
    pub fn coordinates(&self, pose: &Pose) -> [f64; 6] {
        let t = pose.translation.vector;
        let q = self.centre.inverse() * pose.rotation;
        let q: Quaternion<f64> = *q.quaternion();
        let q = if q.w < 0.0 { -q } else { q };
        let v = q.imag();
        let n = v.norm();
        let w = if n < 1e-300 {
            Vector3::zeros()
        } else {
            v * (2.0 * n.atan2(q.w) / n)
        };
        [
            t.x,
            t.y,
            (t.z - self.z_min_m).max(0.0).sqrt(),
            w.x,
            w.y,
            w.z,
        ]
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::{params_from_pose, pose_error, pose_from_params};
    use rand::{Rng, SeedableRng};
    use std::f64::consts::PI;

    fn random_rotation(rng: &mut impl Rng) -> UnitQuaternion<f64> {
        let q = Quaternion::new(
            rng.gen_range(-1.0..1.0),
            rng.gen_range(-1.0..1.0),
            rng.gen_range(-1.0..1.0),
            rng.gen_range(-1.0..1.0),
        );
        UnitQuaternion::from_quaternion(q)
    }

    #[test]
    fn plain_rotations_match_nalgebra() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(11);
        for i in 0..1000 {
            let mut p: [f64; 3] = std::array::from_fn(|_| rng.gen_range(-PI..PI));
            if i % 10 == 0 {
                p[1] = if i % 20 == 0 { PI / 2.0 } else { -PI / 2.0 }; // gimbal lock
            }
            let m = rotation_from_rpy(p[0], p[1], p[2]);
            let r = nalgebra::Rotation3::from_euler_angles(p[0], p[1], p[2]);
            let pose = pose_from_params(&[0.0, 0.0, 0.0, p[0], p[1], p[2]]);
            let n = matrix_of(&pose);
            for a in 0..3 {
                for b in 0..3 {
                    assert!((m[a][b] - r[(a, b)]).abs() < 1e-15);
                    assert!((n[a][b] - r[(a, b)]).abs() < 1e-12);
                }
            }
        }
    }

    #[test]
    fn the_rotation_vector_inverts_the_exponential_at_every_angle() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(5);
        for i in 0..2000 {
            let axis = random_rotation(&mut rng) * Vector3::x();
            // Angles over (0, pi], with the ends and tiny ones included.
            let angle = match i % 5 {
                0 => PI,
                1 => PI - 1e-9,
                2 => 1e-9,
                _ => rng.gen_range(0.0..PI),
            };
            let w = axis * angle;
            let q = UnitQuaternion::from_scaled_axis(w);
            let pose = Isometry3::from_parts(Translation3::identity(), q);
            let got = Vector3::from(rotation_vector(&matrix_of(&pose)));
            if angle > PI - 1e-6 {
                // At pi, w and -w are the same rotation.
                let e = (got - w).norm().min((got + w).norm());
                assert!(e < 1e-6, "{angle}: {got} vs {w}");
            } else {
                assert!((got - w).norm() < 1e-9, "{angle}: {got} vs {w}");
            }
        }
    }

    #[test]
    fn the_difference_is_the_angle_between_orientations_even_at_gimbal_lock() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
        for _ in 0..200 {
            let theta = pose_from_params(&[
                0.01,
                0.08,
                0.06,
                rng.gen_range(-PI..PI),
                -89f64.to_radians(),
                rng.gen_range(-PI..PI),
            ]);
            let axis = random_rotation(&mut rng) * Vector3::x();
            let w = axis * 5f64.to_radians();
            let x = rotated_about_own_axes(&theta, [w.x, w.y, w.z]);
            // Through the rpy parameters, as a database stores them.
            let x = pose_from_params(&params_from_pose(&x));
            let d = pose_difference(&x, &theta);
            let got = Vector3::new(d[3], d[4], d[5]);
            assert!((got - w).norm() < 1e-9, "{got} vs {w}");
            assert!(d[..3].iter().all(|v| v.abs() < 1e-12));
        }
    }

    #[test]
    fn charts_round_trip_and_are_centred() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(9);
        for _ in 0..200 {
            let centre =
                Isometry3::from_parts(Translation3::new(0.6, 0.1, 0.3), random_rotation(&mut rng));
            let chart = Chart::at(&centre, 0.05);
            let c = chart.coordinates(&centre);
            assert!(c[3..].iter().all(|v| v.abs() < 1e-12));
            assert!((c[2] * c[2] + 0.05 - 0.3).abs() < 1e-12);
            let x: [f64; 6] = std::array::from_fn(|i| c[i] + rng.gen_range(-0.5..0.5));
            let pose = chart.pose(&x);
            let back = chart.coordinates(&pose);
            for i in 0..6 {
                let x2 = if i == 2 { x[2].abs() } else { x[i] };
                assert!((back[i] - x2).abs() < 1e-9, "{i}: {back:?} vs {x:?}");
            }
            let (dp, dr) = pose_error(&chart.pose(&back), &pose);
            assert!(dp < 1e-12 && dr < 1e-9);
        }
    }
}
