//! Forward kinematics and the arm's geometric Jacobian.
//!
//! The tree is evaluated by composing `parent_from_joint * rotation(axis, q)` from
//! the root down; the arm's serial path from the base to the palm is precomputed so
//! that inverse kinematics evaluates only the seven moving joints and the fixed
//! offsets between them.

use super::description::{Motion, RobotDescription};
use super::RobotError;
use crate::geometry::Pose;
use nalgebra::{Point3, Unit, UnitQuaternion, Vector3};
use std::path::Path;

/// Number of arm joints.
pub const ARM_DOF: usize = 7;

/// Seven arm joint angles (rad), A1 A2 E1 A3 A4 A5 A6.
pub type ArmJoints = [f64; ARM_DOF];

/// The 6x7 geometric Jacobian of the palm: rows vx vy vz wx wy wz (base frame).
pub type ArmJacobian = nalgebra::SMatrix<f64, 6, ARM_DOF>;

/// Poses of every link for a full variable vector (`description.variables` order).
pub fn link_poses(description: &RobotDescription, q: &[f64]) -> Vec<Pose> {
    let mut poses = vec![Pose::identity(); description.links.len()];
    for joint in &description.joints {
        let parent = poses[joint.parent_link];
        poses[joint.child_link] = parent * joint.parent_from_joint * joint_motion(&joint.motion, q);
    }
    poses
}

fn joint_motion(motion: &Motion, q: &[f64]) -> UnitQuaternion<f64> {
    match motion {
        Motion::Fixed => UnitQuaternion::identity(),
        Motion::Revolute {
            axis,
            variable,
            multiplier,
            offset,
        } => UnitQuaternion::from_axis_angle(axis, multiplier * q[*variable] + offset),
    }
}

/// One step of the arm's serial path: a fixed offset, then (for a moving joint) a
/// rotation about `axis` by one of the seven arm angles.
#[derive(Debug, Clone)]
struct Segment {
    origin: Pose,
    rotation: Option<(Unit<Vector3<f64>>, usize)>,
}

/// The largest difference of any joint between two configurations (rad).
pub fn joint_distance_rad(a: &ArmJoints, b: &ArmJoints) -> f64 {
    (0..ARM_DOF)
        .map(|j| (a[j] - b[j]).abs())
        .fold(0.0, f64::max)
}

/// The serial chain from the base to the palm through the seven arm joints.
#[derive(Debug, Clone)]
pub struct ArmKinematics {
    segments: Vec<Segment>,
    /// Number of segments up to and including the flange link's joint.
    flange_segments: usize,
    /// Joint limits (rad), lower and upper per arm joint.
    pub lower_rad: ArmJoints,
    /// Upper joint limits (rad).
    pub upper_rad: ArmJoints,
}

impl ArmKinematics {
    /// Extracts the path to `palm_link` through `flange_link`; every moving joint on
    /// it must be one of the first seven variables (the arm joints).
    pub fn new(
        description: &RobotDescription,
        flange_link: &str,
        palm_link: &str,
        path: &Path,
    ) -> Result<ArmKinematics, RobotError> {
        let missing = |link: &str| RobotError::MissingLink {
            path: path.to_path_buf(),
            link: link.to_string(),
        };
        let flange = description
            .link_index(flange_link)
            .ok_or_else(|| missing(flange_link))?;
        let palm = description
            .link_index(palm_link)
            .ok_or_else(|| missing(palm_link))?;
        let to_flange = description.path_to(flange);
        let to_palm = description.path_to(palm);
        if !to_palm.starts_with(&to_flange) {
            return Err(RobotError::Urdf {
                path: path.to_path_buf(),
                problem: format!("palm link {palm_link} is not below flange link {flange_link}"),
            });
        }
        let mut segments = Vec::new();
        let mut seen = [false; ARM_DOF];
        for &j in &to_palm {
            let joint = &description.joints[j];
            let rotation = match &joint.motion {
                Motion::Fixed => None,
                Motion::Revolute {
                    axis,
                    variable,
                    multiplier,
                    offset,
                } => {
                    if *variable >= ARM_DOF || *multiplier != 1.0 || *offset != 0.0 {
                        return Err(RobotError::BadJoint {
                            path: path.to_path_buf(),
                            joint: joint.name.clone(),
                            problem:
                                "moves on the path to the palm but is not one of robot.arm_joints"
                                    .into(),
                        });
                    }
                    seen[*variable] = true;
                    Some((*axis, *variable))
                }
            };
            segments.push(Segment {
                origin: joint.parent_from_joint,
                rotation,
            });
        }
        if let Some(i) = seen.iter().position(|s| !s) {
            return Err(RobotError::BadJoint {
                path: path.to_path_buf(),
                joint: description.variables[i].name.clone(),
                problem: format!("is not on the path from the base to {palm_link}"),
            });
        }
        let mut lower_rad = [0.0; ARM_DOF];
        let mut upper_rad = [0.0; ARM_DOF];
        for i in 0..ARM_DOF {
            lower_rad[i] = description.variables[i].lower_rad;
            upper_rad[i] = description.variables[i].upper_rad;
        }
        Ok(ArmKinematics {
            segments,
            flange_segments: to_flange.len(),
            lower_rad,
            upper_rad,
        })
    }

    /// Flange and palm poses in the base frame.
    pub fn flange_and_palm(&self, q: &ArmJoints) -> (Pose, Pose) {
        let mut pose = Pose::identity();
        let mut flange = Pose::identity();
        for (i, s) in self.segments.iter().enumerate() {
            pose *= s.origin;
            if let Some((axis, v)) = &s.rotation {
                pose *= UnitQuaternion::from_axis_angle(axis, q[*v]);
            }
            if i + 1 == self.flange_segments {
                flange = pose;
            }
        }
        (flange, pose)
    }

    /// Palm pose in the base frame.
    pub fn palm(&self, q: &ArmJoints) -> Pose {
        self.flange_and_palm(q).1
    }

    /// Palm pose and the geometric Jacobian of the palm origin.
    pub fn palm_and_jacobian(&self, q: &ArmJoints) -> (Pose, ArmJacobian) {
        let mut pose = Pose::identity();
        let mut axes = [(Vector3::zeros(), Point3::origin()); ARM_DOF];
        for s in &self.segments {
            pose *= s.origin;
            if let Some((axis, v)) = &s.rotation {
                axes[*v] = (
                    pose.rotation * axis.into_inner(),
                    Point3::from(pose.translation.vector),
                );
                pose *= UnitQuaternion::from_axis_angle(axis, q[*v]);
            }
        }
        let end = Point3::from(pose.translation.vector);
        let mut jacobian = ArmJacobian::zeros();
        for (i, (z, p)) in axes.iter().enumerate() {
            let v = z.cross(&(end - p));
            jacobian.fixed_view_mut::<3, 1>(0, i).copy_from(&v);
            jacobian.fixed_view_mut::<3, 1>(3, i).copy_from(z);
        }
        (pose, jacobian)
    }

    /// The first joint outside its limits, as (index, value).
    pub fn out_of_limits(&self, q: &ArmJoints) -> Option<(usize, f64)> {
        (0..ARM_DOF)
            .find(|&i| !(q[i] >= self.lower_rad[i] && q[i] <= self.upper_rad[i]))
            .map(|i| (i, q[i]))
    }

    /// The other configurations within the limits that put the palm where `q` does,
    /// nearest to `near` first (largest joint difference). In the LBR's chain (roll and
    /// pitch axes alternating on one line) each roll–pitch–roll triple — shoulder
    /// (joints 1–3), elbow (3–5), wrist (5–7) — gives the same motion with both rolls
    /// turned by half a turn and the pitch negated: `Rz(a + pi) Ry(-b) Rz(c + pi) =
    /// Rz(a) Ry(b) Rz(c)`. Only the links between the two rolls turn, about their own
    /// axis. Candidates are kept only where the palm pose matches `q`'s, so another
    /// chain simply has none.
    pub fn equivalents(&self, q: &ArmJoints, near: &ArmJoints) -> Vec<ArmJoints> {
        const TRIPLES: [usize; 3] = [0, 2, 4];
        let palm = self.palm(q);
        let mut found: Vec<ArmJoints> = Vec::new();
        for flips in 1u8..8 {
            let mut c = *q;
            let mut within = true;
            for (bit, &first) in TRIPLES.iter().enumerate() {
                if flips & (1 << bit) == 0 {
                    continue;
                }
                c[first + 1] = -c[first + 1];
                for roll in [first, first + 2] {
                    // Half a turn either way: the one within the limits nearest `near`.
                    let turned = [
                        c[roll] + std::f64::consts::PI,
                        c[roll] - std::f64::consts::PI,
                    ]
                    .into_iter()
                    .filter(|v| *v >= self.lower_rad[roll] && *v <= self.upper_rad[roll])
                    .min_by(|a, b| (a - near[roll]).abs().total_cmp(&(b - near[roll]).abs()));
                    match turned {
                        Some(v) => c[roll] = v,
                        None => within = false,
                    }
                }
            }
            let same = crate::geometry::pose_error(&self.palm(&c), &palm);
            if within && self.out_of_limits(&c).is_none() && same.0 < 1e-9 && same.1 < 1e-9 {
                found.push(c);
            }
        }
        found.sort_by(|a, b| joint_distance_rad(a, near).total_cmp(&joint_distance_rad(b, near)));
        found
    }

    /// `q` clamped into the joint limits.
    pub fn clamp(&self, q: &ArmJoints) -> ArmJoints {
        std::array::from_fn(|i| q[i].clamp(self.lower_rad[i], self.upper_rad[i]))
    }

    /// `q` clamped into the joint limits shrunk by `margin_rad` on each side (at most
    /// to the middle of the range).
    pub fn clamp_within(&self, q: &ArmJoints, margin_rad: f64) -> ArmJoints {
        std::array::from_fn(|i| {
            let (lo, hi) = (self.lower_rad[i], self.upper_rad[i]);
            let m = margin_rad.clamp(0.0, 0.5 * (hi - lo).max(0.0));
            q[i].clamp(lo + m, hi - m)
        })
    }

    /// World positions of the seven arm joints' frames.
    pub fn joint_positions(&self, q: &ArmJoints) -> [Point3<f64>; ARM_DOF] {
        let mut pose = Pose::identity();
        let mut positions = [Point3::origin(); ARM_DOF];
        for s in &self.segments {
            pose *= s.origin;
            if let Some((axis, v)) = &s.rotation {
                positions[*v] = Point3::from(pose.translation.vector);
                pose *= UnitQuaternion::from_axis_angle(axis, q[*v]);
            }
        }
        positions
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::robot::shipped_robot;
    use nalgebra::{Matrix3, Rotation3, Vector3};
    use rand::{Rng, SeedableRng};

    /// The spec's joint table (shared/specs/kuka-lbr4-fri.md): z offset from the
    /// previous joint and the axis, all origins unrotated.
    const SPEC: [(f64, [f64; 3]); 7] = [
        (0.11, [0.0, 0.0, 1.0]),
        (0.2005, [0.0, -1.0, 0.0]),
        (0.20, [0.0, 0.0, 1.0]),
        (0.20, [0.0, 1.0, 0.0]),
        (0.20, [0.0, 0.0, 1.0]),
        (0.19, [0.0, -1.0, 0.0]),
        (0.078, [0.0, 0.0, 1.0]),
    ];

    fn skew(w: &Vector3<f64>) -> Matrix3<f64> {
        Matrix3::new(0.0, -w.z, w.y, w.z, 0.0, -w.x, -w.y, w.x, 0.0)
    }

    /// Space-frame product of exponentials: T = exp(S1 q1) ... exp(S7 q7) M, with
    /// screw axes S_i = (w_i, -w_i x p_i) from the spec table at the zero pose.
    fn poe_flange(q: &ArmJoints) -> (Matrix3<f64>, Vector3<f64>) {
        let mut r = Matrix3::identity();
        let mut t = Vector3::zeros();
        let mut height = 0.0;
        for (i, (dz, axis)) in SPEC.iter().enumerate() {
            height += dz;
            let w = Vector3::from(*axis);
            let p = Vector3::new(0.0, 0.0, height);
            let v = -w.cross(&p);
            let k = skew(&w);
            let (s, c) = q[i].sin_cos();
            let ri = Matrix3::identity() + k * s + k * k * (1.0 - c);
            let ti = (Matrix3::identity() * q[i] + k * (1.0 - c) + k * k * (q[i] - s)) * v;
            // (r, t) <- (r, t) * (ri, ti)
            t += r * ti;
            r *= ri;
        }
        // M: the flange at the zero pose, unrotated, at the total height.
        (r, t + r * Vector3::new(0.0, 0.0, height))
    }

    #[test]
    fn flange_at_zero_is_1_1785_m_up() {
        let robot = shipped_robot();
        let (flange, palm) = robot.arm().flange_and_palm(&[0.0; ARM_DOF]);
        assert!((flange.translation.vector - Vector3::new(0.0, 0.0, 1.1785)).norm() < 1e-12);
        assert!(flange.rotation.angle() < 1e-12);
        // The palm frame sits on the 12 mm adapter plate.
        assert!((palm.translation.z - 1.1905).abs() < 1e-12);
    }

    #[test]
    fn fk_matches_product_of_exponentials_from_the_spec() {
        let robot = shipped_robot();
        let arm = robot.arm();
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
        for _ in 0..500 {
            let q: ArmJoints =
                std::array::from_fn(|i| rng.gen_range(arm.lower_rad[i]..=arm.upper_rad[i]));
            let (flange, _) = arm.flange_and_palm(&q);
            let (r, t) = poe_flange(&q);
            let rot = Rotation3::from_matrix_unchecked(r);
            assert!((flange.translation.vector - t).norm() < 1e-9, "{q:?}");
            let diff = flange.rotation.to_rotation_matrix().matrix() - rot.matrix();
            assert!(diff.norm() < 1e-9, "{q:?}");
        }
    }

    #[test]
    fn fk_matches_k_and_the_tree() {
        let robot = shipped_robot();
        let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("robot/lbr4_bh8_282.urdf");
        let chain = k::Chain::<f64>::from_urdf_file(&path).unwrap();
        let names = robot.arm_joint_names();
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
        let arm = robot.arm();
        for _ in 0..50 {
            let q: ArmJoints =
                std::array::from_fn(|i| rng.gen_range(arm.lower_rad[i]..=arm.upper_rad[i]));
            for (name, v) in names.iter().zip(q) {
                chain.find(name).unwrap().set_joint_position(v).unwrap();
            }
            chain.update_transforms();
            let palm_node = chain.find("bh_mount").unwrap();
            let k_palm = crate::robot::description::from_k(&palm_node.world_transform().unwrap());
            let (_, palm) = arm.flange_and_palm(&q);
            let (dp, dr) = crate::geometry::pose_error(&palm, &k_palm);
            assert!(dp < 1e-9 && dr < 1e-9);
            // The full tree gives the same palm.
            let tree = robot.link_poses(&q, &crate::robot::HandPose::OPEN);
            let palm_index = robot.description.link_index("bh_palm").unwrap();
            let (dp, dr) = crate::geometry::pose_error(&palm, &tree[palm_index]);
            assert!(dp < 1e-12 && dr < 1e-9);
        }
    }

    #[test]
    fn jacobian_matches_finite_differences() {
        let robot = shipped_robot();
        let arm = robot.arm();
        let q = [0.3, -0.5, 0.2, 1.1, -0.4, 0.7, 0.1];
        let (palm, jacobian) = arm.palm_and_jacobian(&q);
        let h = 1e-7;
        for i in 0..ARM_DOF {
            let mut qh = q;
            qh[i] += h;
            let ph = arm.palm(&qh);
            let v = (ph.translation.vector - palm.translation.vector) / h;
            let w = (ph.rotation * palm.rotation.inverse()).scaled_axis() / h;
            assert!(
                (v - jacobian.fixed_view::<3, 1>(0, i)).norm() < 1e-5,
                "column {i}"
            );
            assert!(
                (w - jacobian.fixed_view::<3, 1>(3, i)).norm() < 1e-5,
                "column {i}"
            );
        }
    }

    #[test]
    fn fingers_point_outward_at_zero_and_close_over_the_palm() {
        let robot = shipped_robot();
        let d = &robot.description;
        let palm = d.link_index("bh_palm").unwrap();
        let f3 = d.link_index("bh_f3_proximal").unwrap();
        let open = robot.link_poses(&[0.0; ARM_DOF], &crate::robot::HandPose::OPEN);
        let rel = open[palm].inverse() * open[f3];
        // Spec: F3's flex axis at (0, 0.05, 0.0591) in the palm frame.
        assert!(
            // The URDF gives pi/2 to 6 decimals.
            (rel.translation.vector - Vector3::new(0.0, 0.05, 0.0591)).norm() < 1e-6,
            "{rel:?}"
        );
        // The link extends along its -x: outward (+y) at zero ...
        let dir = rel.rotation * -Vector3::x();
        assert!((dir - Vector3::y()).norm() < 1e-6, "{dir:?}");
        // ... and over the palm (toward -y, up) when closed.
        let closed = crate::robot::HandPose {
            spread_rad: 0.0,
            flex_rad: [2.44; 3],
        };
        let poses = robot.link_poses(&[0.0; ARM_DOF], &closed);
        let dir = (poses[palm].inverse() * poses[f3]).rotation * -Vector3::x();
        assert!(dir.y < -0.5 && dir.z > 0.5, "{dir:?}");
    }

    #[test]
    fn equivalent_configurations_put_the_palm_in_the_same_place_within_the_limits() {
        let robot = shipped_robot();
        let arm = robot.arm();
        let mut rng = rand::rngs::StdRng::seed_from_u64(17);
        let mut counted = 0;
        for _ in 0..200 {
            let q: ArmJoints = std::array::from_fn(|j| {
                rng.gen_range(0.6 * arm.lower_rad[j]..0.6 * arm.upper_rad[j])
            });
            let near = [0.0; ARM_DOF];
            let found = arm.equivalents(&q, &near);
            let palm = arm.palm(&q);
            for pair in found.windows(2) {
                assert!(joint_distance_rad(&pair[0], &near) <= joint_distance_rad(&pair[1], &near));
            }
            for c in &found {
                assert!(arm.out_of_limits(c).is_none());
                let (dp, dr) = crate::geometry::pose_error(&arm.palm(c), &palm);
                assert!(dp < 1e-9 && dr < 1e-9, "{c:?} of {q:?}: {dp} m, {dr} rad");
                assert!(joint_distance_rad(c, &q) > 1.0);
            }
            counted += found.len();
        }
        assert!(counted > 200, "{counted}");
        // Rolls at least 10 degrees off zero (the half turn fits within +-170
        // degrees) and pitches within the limits: all seven flips.
        let q = [1.0, -0.5, -1.0, 1.2, 2.0, -0.7, 0.5];
        assert_eq!(arm.equivalents(&q, &q).len(), 7);
    }
}
