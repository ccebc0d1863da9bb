//! Poses and their parametrisations.
//!
//! A pose is an [`Isometry3<f64>`] named `target_from_source`, so that
//! `base_from_camera * camera_from_object` reads right. The method's 6-DOF
//! parameter vector is `[x, y, z, ax, ay, az]`: metres, then fixed-axis X-Y-Z
//! Euler angles in radians (the URDF `rpy` convention, `R = Rz(az) Ry(ay) Rx(ax)`).

use nalgebra::{Isometry3, Matrix3, Matrix4, Rotation3, Translation3, UnitQuaternion, Vector3};
use serde::{Deserialize, Serialize};
use std::f64::consts::PI;

/// A rigid transform `target_from_source` (metres, radians).
pub type Pose = Isometry3<f64>;

/// The method's pose parameters `[x, y, z, ax, ay, az]` (m, rad; URDF rpy).
pub type PoseParams = [f64; 6];

/// Errors of parsing or validating poses and numeric lists.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum GeometryError {
    /// A list had the wrong number of values.
    #[error("{what}: expected {expected} comma-separated numbers, got {got}")]
    WrongCount {
        /// What was being parsed (e.g. "pose").
        what: String,
        /// The number of values wanted.
        expected: usize,
        /// The number of values given.
        got: usize,
    },
    /// A value did not parse as a number.
    #[error("{what}: value {index} ({text:?}) is not a number")]
    NotANumber {
        /// What was being parsed.
        what: String,
        /// Zero-based index of the bad value.
        index: usize,
        /// The offending text.
        text: String,
    },
    /// A value was NaN or infinite.
    #[error("{what}: value {index} is {value}, not a finite number")]
    NotFinite {
        /// What was being parsed.
        what: String,
        /// Zero-based index of the bad value.
        index: usize,
        /// The offending value.
        value: f64,
    },
    /// A quaternion that cannot be normalised.
    #[error("{what}: quaternion {quat_xyzw:?} has zero or non-finite norm")]
    BadQuaternion {
        /// What was being parsed.
        what: String,
        /// The offending quaternion, x y z w.
        quat_xyzw: [f64; 4],
    },
}

/// Wraps an angle into `[-pi, pi]`.
pub fn wrap_angle(a: f64) -> f64 {
    if (-PI..=PI).contains(&a) {
        return a;
    }
    // rem_euclid maps +pi to -pi; either is a valid representative.
    (a + PI).rem_euclid(2.0 * PI) - PI
}

/// The pose of parameters `[x, y, z, ax, ay, az]`.
pub fn pose_from_params(p: &PoseParams) -> Pose {
    Isometry3::from_parts(
        Translation3::new(p[0], p[1], p[2]),
        UnitQuaternion::from_euler_angles(p[3], p[4], p[5]),
    )
}

/// The parameters `[x, y, z, ax, ay, az]` of a pose (angles in `[-pi, pi]`).
pub fn params_from_pose(pose: &Pose) -> PoseParams {
    let t = pose.translation.vector;
    let (r, p, y) = pose.rotation.euler_angles();
    [t.x, t.y, t.z, r, p, y]
}

/// `a - b` per DOF, with the three angle differences wrapped into `[-pi, pi]`.
pub fn param_difference(a: &PoseParams, b: &PoseParams) -> PoseParams {
    let mut d = [0.0; 6];
    for i in 0..6 {
        d[i] = a[i] - b[i];
        if i >= 3 {
            d[i] = wrap_angle(d[i]);
        }
    }
    d
}

/// The rigid motion that turns by `rotation` about the point `centre` (which stays
/// where it is).
pub fn rotation_about(centre: &Vector3<f64>, rotation: UnitQuaternion<f64>) -> Pose {
    Translation3::from(*centre) * rotation * Translation3::from(-centre)
}

/// Position (m) and rotation (rad) distance between two poses.
pub fn pose_error(a: &Pose, b: &Pose) -> (f64, f64) {
    let dp = (a.translation.vector - b.translation.vector).norm();
    let dr = a.rotation.angle_to(&b.rotation);
    (dp, dr)
}

/// Parses `n` comma-separated finite numbers (`what` names the input in errors).
pub fn parse_numbers(text: &str, n: usize, what: &str) -> Result<Vec<f64>, GeometryError> {
    let parts: Vec<&str> = text.split(',').map(str::trim).collect();
    if parts.len() != n {
        return Err(GeometryError::WrongCount {
            what: what.to_string(),
            expected: n,
            got: parts.len(),
        });
    }
    let values = parts
        .iter()
        .enumerate()
        .map(|(index, s)| {
            s.parse::<f64>().map_err(|_| GeometryError::NotANumber {
                what: what.to_string(),
                index,
                text: s.to_string(),
            })
        })
        .collect::<Result<Vec<f64>, _>>()?;
    check_finite(&values, what)?;
    Ok(values)
}

/// Fails on the first NaN or infinite value.
pub fn check_finite(values: &[f64], what: &str) -> Result<(), GeometryError> {
    match values.iter().position(|v| !v.is_finite()) {
        Some(index) => Err(GeometryError::NotFinite {
            what: what.to_string(),
            index,
            value: values[index],
        }),
        None => Ok(()),
    }
}

/// Parses a command-line pose `x,y,z,roll,pitch,yaw` (m, rad, URDF rpy).
pub fn parse_pose(text: &str) -> Result<Pose, GeometryError> {
    let v = parse_numbers(text, 6, "pose x,y,z,roll,pitch,yaw")?;
    Ok(pose_from_params(&[v[0], v[1], v[2], v[3], v[4], v[5]]))
}

/// A pose as JSON: `{"xyz": [..], "rpy": [..], "quat_xyzw": [..]}`.
///
/// When read, `quat_xyzw` wins over `rpy` if both are given; one is required.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PoseJson {
    /// Translation (m).
    pub xyz: [f64; 3],
    /// Fixed-axis X-Y-Z Euler angles (rad).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub rpy: Option<[f64; 3]>,
    /// Unit quaternion, x y z w.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub quat_xyzw: Option<[f64; 4]>,
}

impl From<&Pose> for PoseJson {
    fn from(pose: &Pose) -> Self {
        let p = params_from_pose(pose);
        let q = pose.rotation.quaternion();
        PoseJson {
            xyz: [p[0], p[1], p[2]],
            rpy: Some([p[3], p[4], p[5]]),
            quat_xyzw: Some([q.i, q.j, q.k, q.w]),
        }
    }
}

impl PoseJson {
    /// The pose this JSON describes (`what` names it in errors).
    pub fn to_pose(&self, what: &str) -> Result<Pose, GeometryError> {
        check_finite(&self.xyz, what)?;
        let rotation = match (self.quat_xyzw, self.rpy) {
            (Some(q), _) => {
                check_finite(&q, what)?;
                let quat = nalgebra::Quaternion::new(q[3], q[0], q[1], q[2]);
                let norm = quat.norm();
                if norm <= 1e-9 || !norm.is_finite() {
                    return Err(GeometryError::BadQuaternion {
                        what: what.to_string(),
                        quat_xyzw: q,
                    });
                }
                UnitQuaternion::from_quaternion(quat)
            }
            (None, Some(r)) => {
                check_finite(&r, what)?;
                UnitQuaternion::from_euler_angles(r[0], r[1], r[2])
            }
            (None, None) => UnitQuaternion::identity(),
        };
        Ok(Isometry3::from_parts(
            Translation3::new(self.xyz[0], self.xyz[1], self.xyz[2]),
            rotation,
        ))
    }
}

/// The 4x4 homogeneous matrix of a pose, as rows.
pub fn matrix_rows(pose: &Pose) -> [[f64; 4]; 4] {
    let m: Matrix4<f64> = pose.to_homogeneous();
    let mut rows = [[0.0; 4]; 4];
    for (r, row) in rows.iter_mut().enumerate() {
        for (c, v) in row.iter_mut().enumerate() {
            *v = m[(r, c)];
        }
    }
    rows
}

/// The pose of a 4x4 homogeneous matrix given as rows (re-orthonormalised).
pub fn pose_from_matrix_rows(rows: &[[f64; 4]; 4]) -> Pose {
    let m = Matrix4::from_fn(|r, c| rows[r][c]);
    let rot = nalgebra::Rotation3::from_matrix(&m.fixed_view::<3, 3>(0, 0).into_owned());
    Isometry3::from_parts(
        Translation3::new(m[(0, 3)], m[(1, 3)], m[(2, 3)]),
        UnitQuaternion::from_rotation_matrix(&rot),
    )
}

/// A camera-style pose at `eye` looking at `target`: z forward, x right, y down
/// (the optical frame), with world `up` used to fix the roll.
pub fn look_at_optical(eye: Vector3<f64>, target: Vector3<f64>, up: Vector3<f64>) -> Pose {
    let z = (target - eye).normalize();
    let x = z.cross(&up).normalize();
    let y = z.cross(&x);
    let rot = nalgebra::Rotation3::from_basis_unchecked(&[x, y, z]);
    Isometry3::from_parts(
        Translation3::from(eye),
        UnitQuaternion::from_rotation_matrix(&rot),
    )
}

/// The rotation nearest (Frobenius) to `m`: the orthogonal polar factor `U Vᵀ` of
/// `m = U S Vᵀ`, with the last singular direction flipped if needed so det = +1.
/// This is also the maximiser of `tr(Rᵀ m)` over rotations.
pub fn project_to_so3(m: &Matrix3<f64>) -> UnitQuaternion<f64> {
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
pub fn mean_rotation(
    rotations: impl IntoIterator<Item = UnitQuaternion<f64>>,
) -> UnitQuaternion<f64> {
    let sum: Matrix3<f64> = rotations
        .into_iter()
        .map(|q| q.to_rotation_matrix().into_inner())
        .sum();
    project_to_so3(&sum)
}

/// Tilt and yaw (deg) of the frame `model` relative to `object`: the tilt is the
/// angle between their z axes (0 upright, 90 lying on its side, 180 upside down);
/// the yaw is the rotation about the object's z axis (0..180, the twist of the
/// swing-twist decomposition), e.g. where a mug's handle ends up. The measure of a
/// registration's orientation error for objects whose models share a canonical
/// frame (base centre at the origin, z up).
pub fn tilt_and_yaw_deg(object: &Pose, model: &Pose) -> (f64, f64) {
    let rel = object.rotation.inverse() * model.rotation;
    let z = Vector3::z();
    let tilt = (rel * z).angle(&z);
    let q = rel.quaternion();
    let yaw = wrap_angle(2.0 * q.k.atan2(q.w)).abs();
    (tilt.to_degrees(), yaw.to_degrees())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_rotation_about_a_point_keeps_the_point() {
        let c = Vector3::new(0.6, 0.1, 0.0);
        let turn = rotation_about(&c, UnitQuaternion::from_scaled_axis(Vector3::z() * 0.5));
        assert!((turn * nalgebra::Point3::from(c) - nalgebra::Point3::from(c)).norm() < 1e-12);
        let p = turn * nalgebra::Point3::new(0.7, 0.1, 0.2);
        assert!(((p.coords - c).xy().norm() - 0.1).abs() < 1e-12 && (p.z - 0.2).abs() < 1e-12);
    }

    #[test]
    fn params_round_trip() {
        let p = [0.1, -0.2, 0.3, 0.4, -0.5, 2.9];
        let q = params_from_pose(&pose_from_params(&p));
        for i in 0..6 {
            assert!((p[i] - q[i]).abs() < 1e-12, "{i}: {} vs {}", p[i], q[i]);
        }
    }

    #[test]
    fn rpy_is_fixed_axis_xyz() {
        // URDF rpy: R = Rz(yaw) * Ry(pitch) * Rx(roll).
        let (r, p, y) = (0.3, -0.7, 1.1);
        let expected = UnitQuaternion::from_axis_angle(&Vector3::z_axis(), y)
            * UnitQuaternion::from_axis_angle(&Vector3::y_axis(), p)
            * UnitQuaternion::from_axis_angle(&Vector3::x_axis(), r);
        let got = pose_from_params(&[0.0, 0.0, 0.0, r, p, y]).rotation;
        assert!(got.angle_to(&expected) < 1e-12);
    }

    #[test]
    fn wrapping_crosses_pi() {
        assert!((wrap_angle(3.0 * PI / 2.0) + PI / 2.0).abs() < 1e-12);
        assert!((wrap_angle(-3.0 * PI / 2.0) - PI / 2.0).abs() < 1e-12);
        let d = param_difference(&[0., 0., 0., 0., 0., 3.1], &[0., 0., 0., 0., 0., -3.1]);
        assert!((d[5] - (6.2 - 2.0 * PI)).abs() < 1e-12);
        assert_eq!(wrap_angle(1.0), 1.0);
    }

    #[test]
    fn bad_pose_text_is_named() {
        assert_eq!(
            parse_pose("1,2,3").unwrap_err(),
            GeometryError::WrongCount {
                what: "pose x,y,z,roll,pitch,yaw".into(),
                expected: 6,
                got: 3
            }
        );
        assert!(matches!(
            parse_pose("1,2,3,4,5,NaN"),
            Err(GeometryError::NotFinite { index: 5, .. })
        ));
        assert!(matches!(
            parse_pose("1,2,x,4,5,6"),
            Err(GeometryError::NotANumber { index: 2, .. })
        ));
    }

    #[test]
    fn pose_json_round_trip_and_matrix() {
        let pose = pose_from_params(&[0.5, 0.1, -0.2, 0.1, 0.2, -2.0]);
        let json = PoseJson::from(&pose);
        let text = serde_json::to_string(&json).unwrap();
        let back: PoseJson = serde_json::from_str(&text).unwrap();
        let (dp, dr) = pose_error(&pose, &back.to_pose("test").unwrap());
        assert!(dp < 1e-12 && dr < 1e-9);
        let (dp, dr) = pose_error(&pose, &pose_from_matrix_rows(&matrix_rows(&pose)));
        assert!(dp < 1e-12 && dr < 1e-9);
    }

    #[test]
    fn look_at_points_z_at_target() {
        let eye = Vector3::new(1.0, 0.0, 1.0);
        let target = Vector3::new(0.5, 0.0, 0.0);
        let pose = look_at_optical(eye, target, Vector3::z());
        let z = pose.rotation * Vector3::z();
        assert!((z - (target - eye).normalize()).norm() < 1e-12);
    }

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
