//! The LBR4+ with the BH8-282: kinematics, inverse kinematics, reachability and
//! collision with the table and itself.
//!
//! [`Robot::load`] reads the URDF named in `robot/cell.toml` (urdf-rs), builds the `k`
//! chain, and flattens it for fast evaluation. A palm pose is *reachable* when IK
//! converges within 1 mm and 0.01 rad inside the joint limits, the palm is inside
//! the workspace box and above the table by the configured clearance, and neither
//! arm nor hand touches the table or itself.

pub mod collision;
pub mod description;
pub mod hand;
pub mod ik;
pub mod kinematics;

use crate::config::{CellConfig, TableConfig, WorkspaceConfig};
use crate::fsio::FileError;
use crate::geometry::Pose;
use collision::{Collision, CollisionModel};
use description::{Motion, RobotDescription};
use ik::{IkOptions, IkSolution, IkSolver};
use kinematics::{link_poses, ArmJoints, ArmKinematics, ARM_DOF};
use nalgebra::Point3;
use serde::Serialize;
use std::path::PathBuf;

/// The hand's actuated joints, in [`HandPose`] order: spread, then F1, F2, F3 flex.
pub const HAND_JOINTS: [&str; 4] = ["bh_j11", "bh_j12", "bh_j22", "bh_j32"];

/// Errors of loading the robot or checking joint vectors.
#[derive(Debug, thiserror::Error)]
pub enum RobotError {
    /// The URDF could not be read.
    #[error("cannot read URDF {}: {}", .0.path.display(), .0.source)]
    Read(FileError),
    /// The URDF does not parse or is inconsistent.
    #[error("URDF {path}: {problem}")]
    Urdf {
        /// The file.
        path: PathBuf,
        /// What is wrong.
        problem: String,
    },
    /// A joint named in the configuration is not in the URDF.
    #[error("URDF {path} has no joint named {joint}")]
    MissingJoint {
        /// The file.
        path: PathBuf,
        /// The joint name.
        joint: String,
    },
    /// A link named in the configuration is not in the URDF.
    #[error("URDF {path} has no link named {link}")]
    MissingLink {
        /// The file.
        path: PathBuf,
        /// The link name.
        link: String,
    },
    /// A joint exists but cannot serve its role.
    #[error("URDF {path}: joint {joint} {problem}")]
    BadJoint {
        /// The file.
        path: PathBuf,
        /// The joint name.
        joint: String,
        /// What is wrong.
        problem: String,
    },
    /// A joint value is outside its limits.
    #[error("joint {joint} = {value} rad is outside its limits [{lower}, {upper}] rad")]
    JointOutOfLimits {
        /// The joint name.
        joint: String,
        /// The value given.
        value: f64,
        /// Lower limit.
        lower: f64,
        /// Upper limit.
        upper: f64,
    },
    /// The configuration file failed.
    #[error(transparent)]
    Config(#[from] crate::config::ConfigError),
}

/// The hand's joint angles (rad): spread and the three flex (proximal) joints.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, serde::Deserialize)]
pub struct HandPose {
    /// Spread of F1 and F2 about the palm normal (0..pi).
    pub spread_rad: f64,
    /// Flex of F1, F2, F3 (0 = open, 2.44 = closed).
    pub flex_rad: [f64; 3],
}

impl HandPose {
    /// Fingers open and straight, spread 0 (F1 and F2 opposite F3).
    pub const OPEN: HandPose = HandPose {
        spread_rad: 0.0,
        flex_rad: [0.0; 3],
    };

    /// The open hand (every finger at flex 0) at `spread_rad`: the pre-shape of a
    /// grasp that names none.
    pub const fn open(spread_rad: f64) -> HandPose {
        HandPose {
            spread_rad,
            flex_rad: [0.0; 3],
        }
    }

    /// Whether every finger is at flex 0.
    pub fn is_open(&self) -> bool {
        self.flex_rad == [0.0; 3]
    }
}

/// The BH8-282's flex range (rad), each finger: open (0) to folded over the palm
/// (140 deg). Category files and grasp messages are checked against it where no
/// hand model is loaded (as the spread against 0..=pi); where one is, its
/// [`hand::HandModel::flex_limits_rad`] from the URDF applies (a unit test keeps
/// the shipped URDF equal to this).
pub const FLEX_LIMITS_RAD: (f64, f64) = (0.0, 2.44);

/// A grasp's pre-shape: each finger's flex before the approach (rad), F1 F2 F3.
/// Zero is the open hand, the default. The BH8-282 positions each finger's puck
/// on its own, so the fingers may differ; written as one number when they agree
/// (`preshape_rad = 0.9`) and as three otherwise (`preshape_rad = [0.9, 0.9, 1.1]`).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct PreshapeRad(pub [f64; 3]);

impl PreshapeRad {
    /// The open hand.
    pub const OPEN: PreshapeRad = PreshapeRad([0.0; 3]);

    /// Whether every finger is open (the default, left out of files).
    pub fn is_open(&self) -> bool {
        self.0 == [0.0; 3]
    }

    /// The hand at `spread_rad` in this pre-shape.
    pub fn at_spread(&self, spread_rad: f64) -> HandPose {
        HandPose {
            spread_rad,
            flex_rad: self.0,
        }
    }

    /// Why the pre-shape is unusable: a flex that is not finite or outside
    /// `limits_rad` (each finger's flex range), named by finger; `None` when fine.
    pub fn problem(&self, limits_rad: (f64, f64)) -> Option<String> {
        let (lo, hi) = limits_rad;
        self.0.iter().enumerate().find_map(|(i, &f)| {
            (!(f.is_finite() && f >= lo && f <= hi)).then(|| {
                format!(
                    "preshape_rad of F{} = {f} is outside the flex range [{lo}, {hi}] rad",
                    i + 1
                )
            })
        })
    }
}

impl Serialize for PreshapeRad {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        let [a, b, c] = self.0;
        if a == b && b == c {
            s.serialize_f64(a)
        } else {
            self.0.serialize(s)
        }
    }
}

impl<'de> serde::Deserialize<'de> for PreshapeRad {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        #[derive(serde::Deserialize)]
        #[serde(untagged)]
        enum Form {
            All(f64),
            Each([f64; 3]),
        }
        Ok(
            match Form::deserialize(d).map_err(|_| {
                serde::de::Error::custom(
                    "preshape_rad must be one flex for every finger or three (F1, F2, F3), rad",
                )
            })? {
                Form::All(f) => PreshapeRad([f; 3]),
                Form::Each(f) => PreshapeRad(f),
            },
        )
    }
}

/// Why a palm pose cannot be reached.
#[derive(Debug, Clone, PartialEq, Serialize)]
#[serde(tag = "kind", rename_all = "snake_case")]
pub enum UnreachableReason {
    /// The palm is below the table plus the required clearance.
    BelowTable {
        /// Palm height (m).
        palm_z_m: f64,
        /// Lowest allowed palm height (m).
        min_z_m: f64,
    },
    /// The palm is outside the workspace box.
    OutsideWorkspace {
        /// Palm position (m).
        palm_xyz_m: [f64; 3],
    },
    /// The hand at this pose touches the table, whatever the arm does.
    HandOnTable {
        /// The hand link that touches.
        link: String,
    },
    /// The wrist would be farther from the shoulder than the arm is long.
    OutOfReach {
        /// Distance from shoulder to wrist centre (m).
        wrist_distance_m: f64,
        /// The arm's reach from shoulder to wrist centre (m).
        max_reach_m: f64,
    },
    /// No seed converged within tolerance inside the joint limits.
    NoIkSolution {
        /// Position error of the best attempt (m).
        pos_err_m: f64,
        /// Rotation error of the best attempt (rad).
        rot_err_rad: f64,
    },
    /// Every converged solution collides.
    Collision(Collision),
}

impl std::fmt::Display for UnreachableReason {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Self::BelowTable { palm_z_m, min_z_m } => write!(
                f,
                "palm at z = {palm_z_m:.3} m is below the table clearance (z >= {min_z_m:.3} m)"
            ),
            Self::OutsideWorkspace { palm_xyz_m } => {
                write!(f, "palm at {palm_xyz_m:.3?} m is outside the workspace box")
            }
            Self::HandOnTable { link } => write!(f, "hand link {link} would touch the table"),
            Self::OutOfReach {
                wrist_distance_m,
                max_reach_m,
            } => write!(
                f,
                "outside the arm's reach: wrist centre {wrist_distance_m:.3} m from the shoulder, reach {max_reach_m:.3} m"
            ),
            Self::NoIkSolution {
                pos_err_m,
                rot_err_rad,
            } => write!(
                f,
                "no IK solution within joint limits (best: {:.1} mm, {rot_err_rad:.4} rad)",
                pos_err_m * 1e3
            ),
            Self::Collision(c) => write!(f, "every IK solution collides: {c}"),
        }
    }
}

/// An unreachable pose: the reason and, when IK ran, its best attempt.
#[derive(Debug, Clone, PartialEq)]
pub struct Unreachable {
    /// Why.
    pub reason: UnreachableReason,
    /// The best IK attempt, if IK was tried.
    pub best: Option<Box<IkSolution>>,
}

/// The robot of the cell, loaded and ready for kinematics queries.
#[derive(Debug, Clone)]
pub struct Robot {
    /// The flattened URDF.
    pub description: RobotDescription,
    /// Inverse kinematics (owns the arm chain).
    pub ik: IkSolver,
    /// Table and self collision.
    pub collision: CollisionModel,
    hand_variables: [usize; 4],
    hand_links: Vec<usize>,
    palm_link: usize,
    table: TableConfig,
    workspace: WorkspaceConfig,
    shoulder: Point3<f64>,
    wrist_in_palm: Point3<f64>,
    max_reach_m: f64,
    arm_levers_m: ArmJoints,
}

/// The levers of [`Robot::max_point_motion_m`]: per arm joint, the reach of the links below it from its
/// axis, bounded through the tree (a joint's offset from its parent's origin plus
/// the reach below it, by the triangle inequality, whatever the angles between).
fn arm_levers_m(description: &RobotDescription, collision: &CollisionModel) -> ArmJoints {
    // reach[l]: the farthest any point of link l or of a link below it can be from
    // l's origin.
    let mut reach: Vec<f64> = (0..description.links.len())
        .map(|l| collision.link_reach_m(l))
        .collect();
    // Joints are listed parents first: backwards, a child's reach is final before
    // its parent takes it.
    for joint in description.joints.iter().rev() {
        let below = joint.parent_from_joint.translation.vector.norm() + reach[joint.child_link];
        reach[joint.parent_link] = reach[joint.parent_link].max(below);
    }
    let mut levers = [0.0; ARM_DOF];
    for joint in &description.joints {
        if let Motion::Revolute {
            variable,
            multiplier,
            ..
        } = joint.motion
        {
            if variable < ARM_DOF {
                // The joint turns its child about an axis through the child's origin
                // (a variable driving several joints moves a point by their sum).
                levers[variable] += multiplier.abs() * reach[joint.child_link];
            }
        }
    }
    levers
}

impl Robot {
    /// Loads the URDF named by the configuration and prepares kinematics and collision.
    pub fn load(config: &CellConfig) -> Result<Robot, RobotError> {
        let path = &config.robot.urdf;
        let description = RobotDescription::load(path, &config.robot.arm_joints)?;
        let arm = ArmKinematics::new(
            &description,
            &config.robot.flange_link,
            &config.robot.palm_link,
            path,
        )?;
        let mut hand_variables = [0; 4];
        for (slot, name) in hand_variables.iter_mut().zip(HAND_JOINTS) {
            *slot = description
                .variable_index(name)
                .ok_or_else(|| RobotError::MissingJoint {
                    path: path.clone(),
                    joint: name.to_string(),
                })?;
        }
        let palm_link = description
            .link_index(&config.robot.palm_link)
            .expect("checked by ArmKinematics::new");
        let hand_links = (0..description.links.len())
            .filter(|&l| {
                l == palm_link
                    || description
                        .path_to(l)
                        .iter()
                        .any(|&j| description.joints[j].parent_link == palm_link)
            })
            .collect();
        let zero = [0.0; ARM_DOF];
        let joints = arm.joint_positions(&zero);
        // LBR4+: shoulder at A2, wrist centre at A5; straight at zero = longest.
        let (shoulder, wrist) = (joints[1], joints[5]);
        let wrist_in_palm = arm.palm(&zero).inverse_transform_point(&wrist);
        let collision = CollisionModel::new(&description, &config.table);
        let arm_levers_m = arm_levers_m(&description, &collision);
        Ok(Robot {
            ik: IkSolver::new(arm, IkOptions::default()),
            collision,
            hand_variables,
            hand_links,
            palm_link,
            table: config.table.clone(),
            workspace: config.workspace.clone(),
            shoulder,
            wrist_in_palm,
            max_reach_m: (wrist - shoulder).norm(),
            arm_levers_m,
            description,
        })
    }

    /// An upper bound on how far any point of the robot moves between arm
    /// configurations `a` and `b`, whatever the hand's shape (m): `sum_j |dq_j| *
    /// lever_j`, where a joint's lever is the farthest any point it moves can be
    /// from its axis.
    pub fn max_point_motion_m(&self, a: &ArmJoints, b: &ArmJoints) -> f64 {
        (0..ARM_DOF)
            .map(|j| (a[j] - b[j]).abs() * self.arm_levers_m[j])
            .sum()
    }

    /// The arm chain.
    pub fn arm(&self) -> &ArmKinematics {
        self.ik.arm()
    }

    /// Names of the seven arm joints.
    pub fn arm_joint_names(&self) -> Vec<&str> {
        self.description.variables[..ARM_DOF]
            .iter()
            .map(|v| v.name.as_str())
            .collect()
    }

    /// Checks seven joint values against the limits; the error names the joint.
    pub fn check_limits(&self, q: &ArmJoints) -> Result<(), RobotError> {
        match self.arm().out_of_limits(q) {
            None => Ok(()),
            Some((i, value)) => Err(RobotError::JointOutOfLimits {
                joint: self.description.variables[i].name.clone(),
                value,
                lower: self.arm().lower_rad[i],
                upper: self.arm().upper_rad[i],
            }),
        }
    }

    /// The full variable vector for an arm configuration and a hand pose.
    pub fn variables(&self, arm: &ArmJoints, hand: &HandPose) -> Vec<f64> {
        let mut q = vec![0.0; self.description.variables.len()];
        q[..ARM_DOF].copy_from_slice(arm);
        let values = [
            hand.spread_rad,
            hand.flex_rad[0],
            hand.flex_rad[1],
            hand.flex_rad[2],
        ];
        for (&v, value) in self.hand_variables.iter().zip(values) {
            q[v] = value;
        }
        q
    }

    /// Poses of every link (base frame).
    pub fn link_poses(&self, arm: &ArmJoints, hand: &HandPose) -> Vec<Pose> {
        link_poses(&self.description, &self.variables(arm, hand))
    }

    /// The first link of the robot at this configuration that stands in the line
    /// of sight `from`–`to` (base frame), if any.
    pub fn link_on_segment(
        &self,
        arm: &ArmJoints,
        hand: &HandPose,
        from: &nalgebra::Point3<f64>,
        to: &nalgebra::Point3<f64>,
    ) -> Option<&str> {
        self.collision
            .link_on_segment(&self.link_poses(arm, hand), from, to)
    }

    /// The first collision of the robot at this configuration, if any.
    pub fn collision_at(&self, arm: &ArmJoints, hand: &HandPose) -> Option<Collision> {
        self.collision.check(&self.link_poses(arm, hand))
    }

    /// The first collision at this configuration that an arm motion could cause:
    /// the hand's links against each other are not checked (the arm does not move
    /// the fingers; a hand closed until its fingers meet is no hazard to lift), and
    /// with `hand_on_table` the hand may touch the table.
    pub fn collision_in_arm_motion(
        &self,
        arm: &ArmJoints,
        hand: &HandPose,
        hand_on_table: bool,
    ) -> Option<Collision> {
        let exempt: &[usize] = if hand_on_table { &self.hand_links } else { &[] };
        self.collision
            .check_except(&self.link_poses(arm, hand), exempt, &self.hand_links)
    }

    /// [`UnreachableReason::OutOfReach`] when the wrist centre of the palm pose
    /// `palm` is farther from the shoulder than the arm is long (no joint values
    /// reach it, whatever the limits and collisions); `None` otherwise.
    pub fn out_of_reach(&self, palm: &Pose) -> Option<UnreachableReason> {
        let wrist = palm * self.wrist_in_palm;
        let wrist_distance_m = (wrist - self.shoulder).norm();
        (wrist_distance_m > self.max_reach_m + self.ik.options().accept_position_m).then_some(
            UnreachableReason::OutOfReach {
                wrist_distance_m,
                max_reach_m: self.max_reach_m,
            },
        )
    }

    /// Whether the palm pose is reachable with the hand in `hand`; `seeds` are tried
    /// first (e.g. the current configuration, the previous solution).
    pub fn reach(
        &self,
        palm: &Pose,
        hand: &HandPose,
        seeds: &[ArmJoints],
    ) -> Result<IkSolution, Unreachable> {
        let not = |reason| Unreachable { reason, best: None };
        let p = palm.translation.vector;
        let min_z_m = self.table.height_m + self.table.palm_clearance_m;
        if p.z < min_z_m {
            return Err(not(UnreachableReason::BelowTable {
                palm_z_m: p.z,
                min_z_m,
            }));
        }
        let (lo, hi) = (&self.workspace.min_m, &self.workspace.max_m);
        if (0..3).any(|i| p[i] < lo[i] || p[i] > hi[i]) {
            return Err(not(UnreachableReason::OutsideWorkspace {
                palm_xyz_m: [p.x, p.y, p.z],
            }));
        }
        // The hand's pose follows from the palm pose alone.
        let zero = [0.0; ARM_DOF];
        let poses = self.link_poses(&zero, hand);
        let world_from_palm0 = *palm * poses[self.palm_link].inverse();
        let hand_poses: Vec<Pose> = poses.iter().map(|p| world_from_palm0 * p).collect();
        if let Some(Collision::Table { link }) =
            self.collision.first_on_table(&self.hand_links, &hand_poses)
        {
            return Err(not(UnreachableReason::HandOnTable { link }));
        }
        if let Some(out) = self.out_of_reach(palm) {
            return Err(not(out));
        }
        let mut first_collision = None;
        let result =
            self.ik
                .solve_with(palm, seeds, |s| match self.collision_at(&s.joints, hand) {
                    None => true,
                    Some(c) => {
                        first_collision.get_or_insert(c);
                        false
                    }
                });
        result.map_err(|best| Unreachable {
            reason: match first_collision {
                Some(c) => UnreachableReason::Collision(c),
                None => UnreachableReason::NoIkSolution {
                    pos_err_m: best.pos_err_m,
                    rot_err_rad: best.rot_err_rad,
                },
            },
            best: Some(Box::new(best)),
        })
    }
}

/// The robot of the shipped `robot/cell.toml`, for tests.
#[cfg(test)]
pub(crate) fn shipped_robot() -> Robot {
    let path =
        std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join(crate::config::DEFAULT_CONFIG_PATH);
    Robot::load(&CellConfig::load(&path).unwrap()).unwrap()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::{pose_from_params, PoseParams};
    use std::f64::consts::PI;

    fn top_down(x: f64, y: f64, z: f64) -> Pose {
        pose_from_params(&[x, y, z, std::f64::consts::PI, 0.0, 0.0])
    }

    #[test]
    fn top_grasp_over_the_table_is_reachable_and_collision_free() {
        let robot = shipped_robot();
        let s = robot
            .reach(&top_down(0.6, 0.0, 0.25), &HandPose::OPEN, &[])
            .unwrap();
        assert!(s.pos_err_m < 1e-3 && s.rot_err_rad < 0.01);
        robot.check_limits(&s.joints).unwrap();
        assert_eq!(robot.collision_at(&s.joints, &HandPose::OPEN), None);
        let (dp, dr) =
            crate::geometry::pose_error(&robot.arm().palm(&s.joints), &top_down(0.6, 0.0, 0.25));
        assert!(dp < 1e-3 && dr < 0.01);
    }

    #[test]
    fn unreachable_poses_have_reasons() {
        let robot = shipped_robot();
        let reason = |p: PoseParams| {
            robot
                .reach(&pose_from_params(&p), &HandPose::OPEN, &[])
                .unwrap_err()
                .reason
        };
        assert!(matches!(
            reason([0.6, 0.0, 0.02, PI, 0.0, 0.0]),
            UnreachableReason::BelowTable { .. }
        ));
        assert!(matches!(
            reason([1.08, 0.0, 0.9, 0.0, 1.57, 0.0]),
            UnreachableReason::OutOfReach { wrist_distance_m, max_reach_m } if wrist_distance_m > max_reach_m
        ));
        assert!(matches!(
            reason([3.0, 0.0, 0.5, 0.0, 0.0, 0.0]),
            UnreachableReason::OutsideWorkspace { .. }
        ));
        // Palm facing down 6 cm above the table: the open fingers lie on it.
        assert!(matches!(
            reason([0.6, 0.0, 0.06, PI, 0.0, 0.0]),
            UnreachableReason::HandOnTable { .. }
        ));
    }

    #[test]
    fn arm_into_the_table_collides() {
        let robot = shipped_robot();
        assert_eq!(robot.collision_at(&[0.0; 7], &HandPose::OPEN), None);
        // A2 tilts the upper arm forward (-A2 about -y is toward +x) and down into the table.
        let q = [0.0, -2.0, 0.0, 0.0, 0.0, 0.0, 0.0];
        assert!(matches!(
            robot.collision_at(&q, &HandPose::OPEN),
            Some(Collision::Table { .. })
        ));
    }

    #[test]
    fn the_wrist_bends_to_100_deg_without_self_collision_and_folds_into_the_forearm_at_the_limit() {
        let robot = shipped_robot();
        // Arm upright, A5 (index 5) bent both ways: the flange and hand clear the forearm.
        for a5 in [-100f64, -60.0, 60.0, 100.0] {
            let mut q = [0.0; 7];
            q[5] = a5.to_radians();
            assert_eq!(robot.collision_at(&q, &HandPose::OPEN), None, "A5 {a5} deg");
        }
        // A5 at its 120 deg limit folds the palm back onto the forearm.
        let mut q = [0.0; 7];
        q[5] = 2.09;
        assert!(matches!(
            robot.collision_at(&q, &HandPose::OPEN),
            Some(Collision::SelfCollision { .. })
        ));
    }

    #[test]
    fn joint_limits_are_named() {
        let robot = shipped_robot();
        let err = robot
            .check_limits(&[0.0, 2.5, 0.0, 0.0, 0.0, 0.0, 0.0])
            .unwrap_err()
            .to_string();
        assert!(err.contains("lbr_a2") && err.contains("2.5"), "{err}");
    }

    /// No point of the robot (any point within a link's reach of its origin, the
    /// hand open or closed) moves farther than the levers' bound between two arm
    /// configurations; and the bound is not loose by more than a factor of three
    /// for some of them.
    #[test]
    fn the_arm_levers_bound_how_far_any_point_moves() {
        use rand::{Rng, SeedableRng};
        let robot = shipped_robot();
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
        let (lower, upper) = (robot.arm().lower_rad, robot.arm().upper_rad);
        let directions = [
            nalgebra::Vector3::x(),
            nalgebra::Vector3::y(),
            nalgebra::Vector3::z(),
            -nalgebra::Vector3::x(),
            -nalgebra::Vector3::y(),
            -nalgebra::Vector3::z(),
        ];
        let mut tightest: f64 = 0.0;
        for _ in 0..300 {
            let a: ArmJoints = std::array::from_fn(|j| rng.gen_range(lower[j]..upper[j]));
            let step = rng.gen_range(0.001..0.2);
            let b: ArmJoints = std::array::from_fn(|j| a[j] + rng.gen_range(-step..step));
            let hand = HandPose {
                spread_rad: rng.gen_range(0.0..PI),
                flex_rad: std::array::from_fn(|_| rng.gen_range(0.0..2.4)),
            };
            let bound = robot.max_point_motion_m(&a, &b);
            let (pa, pb) = (robot.link_poses(&a, &hand), robot.link_poses(&b, &hand));
            for l in 0..pa.len() {
                let reach = robot.collision.link_reach_m(l);
                for d in &directions {
                    let point = nalgebra::Point3::from(d * reach);
                    let moved = (pa[l] * point - pb[l] * point).norm();
                    assert!(moved <= bound + 1e-12, "link {l}: {moved} > {bound}");
                    tightest = tightest.max(moved / bound);
                }
            }
        }
        assert!(tightest > 1.0 / 3.0, "{tightest}");
    }
}
