//! The hand alone, for grasp simulation: the palm and each finger's short kinematic
//! chain (spread, flex, distal), taken from the [`RobotDescription`] so that the
//! URDF stays the one source of the hand's geometry.
//!
//! A finger is found from its flex variable (`bh_j12`, `bh_j22`, `bh_j32`): the joint
//! that variable drives directly carries the proximal link; the revolute joint below
//! it that mimics the same variable carries the distal link. Joints between the palm
//! and the flex joint must be fixed or driven by the spread variable (`bh_j11`).
//! Poses are in the palm frame; the distal angle is an input of its own so that a
//! simulator can let it move on after the TorqueSwitch breakaway.

use super::collision::parry_shape;
use super::description::{Motion, RobotDescription};
use super::{RobotError, HAND_JOINTS};
use crate::geometry::Pose;
use nalgebra::{Unit, UnitQuaternion, Vector3};
use parry3d_f64::shape::SharedShape;
use std::path::Path;

/// A rigid link of the hand with its collision shapes.
#[derive(Clone)]
pub struct HandLink {
    /// URDF link name.
    pub name: String,
    /// Collision shapes as `(link_from_shape, shape)` (parry's own axis convention
    /// already folded into the pose).
    pub shapes: Vec<(Pose, SharedShape)>,
}

impl std::fmt::Debug for HandLink {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("HandLink")
            .field("name", &self.name)
            .field("shapes", &self.shapes.len())
            .finish()
    }
}

/// A joint on a finger's chain above its flex joint: a fixed offset, then a rotation
/// by `multiplier * spread + offset` about `axis` when the joint follows the spread.
#[derive(Debug, Clone)]
struct BaseStep {
    origin: Pose,
    rotation: Option<(Unit<Vector3<f64>>, f64, f64)>,
}

/// Bounds on how fast a finger's links sweep: the largest distance of any point of
/// a link from the axis it turns about (m), so that turning by `a` rad moves no
/// point farther than `a` times the bound.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FingerReach {
    /// Proximal link about the flex axis.
    pub proximal_m: f64,
    /// Distal link about the flex axis (any distal angle).
    pub distal_about_flex_m: f64,
    /// Distal link about its own axis.
    pub distal_own_m: f64,
}

impl FingerReach {
    /// Bound for the distal link while coupled: flex by `a` turns it by `a` about
    /// the flex axis and by `ratio * a` about its own.
    pub fn distal_coupled_m(&self, ratio: f64) -> f64 {
        self.distal_about_flex_m + ratio.abs() * self.distal_own_m
    }
}

/// Largest distance of `link`'s shapes (bounding spheres, link frame) from the
/// axis through `origin` along `axis` (link frame).
fn reach_about(link: &HandLink, origin: &Pose, axis: &Unit<Vector3<f64>>) -> f64 {
    link.shapes
        .iter()
        .map(|(local, shape)| {
            let sphere = shape.compute_bounding_sphere(&(origin * local));
            let c = sphere.center().coords;
            (c - axis.into_inner() * c.dot(axis)).norm() + sphere.radius()
        })
        .fold(0.0, f64::max)
}

/// One finger: the chain palm -> knuckle (spread) -> proximal (flex) -> distal.
#[derive(Debug, Clone)]
pub struct Finger {
    /// The flex joint's name (e.g. `bh_j12`).
    pub flex_joint: String,
    base: Vec<BaseStep>,
    flex_axis: Unit<Vector3<f64>>,
    distal_origin: Pose,
    distal_axis: Unit<Vector3<f64>>,
    /// The distal joint's angle per radian of flex while the links are coupled.
    pub distal_ratio: f64,
    /// The distal joint's angle offset while coupled (rad).
    pub distal_offset_rad: f64,
    /// Flex (proximal) joint limits (rad).
    pub flex_limits_rad: (f64, f64),
    /// Distal joint limits (rad), from the URDF's mimic joint.
    pub distal_limits_rad: (f64, f64),
    /// The flex joint's torque limit (N m, the URDF's effort).
    pub flex_effort_nm: f64,
    /// The flex joint's speed limit (rad/s, the URDF's velocity).
    pub flex_velocity_rad_s: f64,
    /// The proximal link.
    pub proximal: HandLink,
    /// The distal link.
    pub distal: HandLink,
    /// Sweep bounds of the links.
    pub reach: FingerReach,
}

impl Finger {
    /// The flex joint's frame before its rotation (palm frame), at `spread_rad`.
    pub fn palm_from_flex_base(&self, spread_rad: f64) -> Pose {
        self.base.iter().fold(Pose::identity(), |acc, step| {
            let motion = match &step.rotation {
                Some((axis, m, o)) => UnitQuaternion::from_axis_angle(axis, m * spread_rad + o),
                None => UnitQuaternion::identity(),
            };
            acc * step.origin * motion
        })
    }

    /// Proximal and distal link poses (palm frame) from the flex base of
    /// [`Finger::palm_from_flex_base`], the flex angle and the distal joint angle.
    pub fn link_poses_from_base(
        &self,
        palm_from_flex_base: &Pose,
        flex_rad: f64,
        distal_rad: f64,
    ) -> (Pose, Pose) {
        let proximal =
            palm_from_flex_base * UnitQuaternion::from_axis_angle(&self.flex_axis, flex_rad);
        let distal = proximal
            * self.distal_origin
            * UnitQuaternion::from_axis_angle(&self.distal_axis, distal_rad);
        (proximal, distal)
    }

    /// The flex joint's axis (unit, in the flex base frame and the proximal link's).
    pub fn flex_axis(&self) -> Unit<Vector3<f64>> {
        self.flex_axis
    }

    /// The distal joint's frame before its rotation, in the proximal link's frame.
    pub fn proximal_from_distal_base(&self) -> Pose {
        self.distal_origin
    }

    /// The distal joint's axis (unit, in its base frame and the distal link's).
    pub fn distal_axis(&self) -> Unit<Vector3<f64>> {
        self.distal_axis
    }

    /// The distal joint's angle while coupled to the flex joint.
    pub fn coupled_distal_rad(&self, flex_rad: f64) -> f64 {
        self.distal_ratio * flex_rad + self.distal_offset_rad
    }

    /// Proximal and distal link poses (palm frame) with the links coupled.
    pub fn link_poses(&self, spread_rad: f64, flex_rad: f64) -> (Pose, Pose) {
        self.link_poses_from_base(
            &self.palm_from_flex_base(spread_rad),
            flex_rad,
            self.coupled_distal_rad(flex_rad),
        )
    }
}

/// The BH8-282 as the grasp simulator sees it: the palm and three fingers, F1 F2 F3
/// in [`HAND_JOINTS`] order.
#[derive(Debug, Clone)]
pub struct HandModel {
    /// The palm link (the frame of all poses here).
    pub palm: HandLink,
    /// The fingers.
    pub fingers: [Finger; 3],
    /// Spread joint limits (rad).
    pub spread_limits_rad: (f64, f64),
}

impl HandModel {
    /// Extracts the hand below `palm_link` from the description; `path` names the URDF
    /// in errors.
    pub fn from_description(
        description: &RobotDescription,
        palm_link: &str,
        path: &Path,
    ) -> Result<HandModel, RobotError> {
        let bad = |joint: &str, problem: String| RobotError::BadJoint {
            path: path.to_path_buf(),
            joint: joint.to_string(),
            problem,
        };
        let palm = description
            .link_index(palm_link)
            .ok_or_else(|| RobotError::MissingLink {
                path: path.to_path_buf(),
                link: palm_link.to_string(),
            })?;
        let variable = |name: &str| {
            description
                .variable_index(name)
                .ok_or_else(|| RobotError::MissingJoint {
                    path: path.to_path_buf(),
                    joint: name.to_string(),
                })
        };
        let spread_var = variable(HAND_JOINTS[0])?;
        let spread = &description.variables[spread_var];
        let link = |index: usize| {
            let spec = &description.links[index];
            HandLink {
                name: spec.name.clone(),
                shapes: spec
                    .shapes
                    .iter()
                    .map(|s| {
                        let (shape, local) = parry_shape(&s.primitive);
                        (s.link_from_shape * local, shape)
                    })
                    .collect(),
            }
        };
        let palm_path = description.path_to(palm);
        let mut fingers = Vec::with_capacity(3);
        for flex_name in &HAND_JOINTS[1..] {
            let flex_var = variable(flex_name)?;
            let flex_index = description
                .joints
                .iter()
                .position(|j| &j.name == flex_name)
                .ok_or_else(|| bad(flex_name, "is not in the kinematic tree".into()))?;
            let flex = &description.joints[flex_index];
            let Motion::Revolute {
                axis: flex_axis, ..
            } = flex.motion
            else {
                return Err(bad(flex_name, "must be revolute".into()));
            };
            let proximal = flex.child_link;
            let distal_joint = description
                .joints
                .iter()
                .find(|j| {
                    j.parent_link == proximal
                        && matches!(j.motion, Motion::Revolute { variable, .. } if variable == flex_var)
                })
                .ok_or_else(|| {
                    bad(
                        flex_name,
                        "has no distal joint below it that mimics it".into(),
                    )
                })?;
            let Motion::Revolute {
                axis: distal_axis,
                multiplier,
                offset,
                ..
            } = distal_joint.motion
            else {
                unreachable!("matched as revolute above")
            };
            let to_flex = description.path_to(proximal);
            if !to_flex.starts_with(&palm_path) {
                return Err(bad(
                    flex_name,
                    format!("is not below the palm link {palm_link}"),
                ));
            }
            let mut base = Vec::new();
            for &j in &to_flex[palm_path.len()..to_flex.len() - 1] {
                let joint = &description.joints[j];
                let rotation = match &joint.motion {
                    Motion::Fixed => None,
                    Motion::Revolute {
                        axis,
                        variable,
                        multiplier,
                        offset,
                    } if *variable == spread_var => Some((*axis, *multiplier, *offset)),
                    Motion::Revolute { .. } => {
                        return Err(bad(
                            &joint.name,
                            format!(
                            "moves between the palm and {flex_name} but does not follow the spread"
                        ),
                        ))
                    }
                };
                base.push(BaseStep {
                    origin: joint.parent_from_joint,
                    rotation,
                });
            }
            base.push(BaseStep {
                origin: flex.parent_from_joint,
                rotation: None,
            });
            // The distal joint's own limits are in the URDF but not among the
            // variables (it is a mimic); its coupled range is the flex range mapped.
            let flex_limits = (
                description.variables[flex_var].lower_rad,
                description.variables[flex_var].upper_rad,
            );
            let ends = [
                multiplier * flex_limits.0 + offset,
                multiplier * flex_limits.1 + offset,
            ];
            let (proximal_link, distal_link) = (link(proximal), link(distal_joint.child_link));
            let origin = distal_joint.parent_from_joint.translation.vector;
            let reach = FingerReach {
                proximal_m: reach_about(&proximal_link, &Pose::identity(), &flex_axis),
                distal_about_flex_m: (origin - flex_axis.into_inner() * origin.dot(&flex_axis))
                    .norm()
                    + distal_link
                        .shapes
                        .iter()
                        .map(|(local, shape)| {
                            let s = shape.compute_bounding_sphere(local);
                            s.center().coords.norm() + s.radius()
                        })
                        .fold(0.0, f64::max),
                distal_own_m: reach_about(&distal_link, &Pose::identity(), &distal_axis),
            };
            fingers.push(Finger {
                reach,
                flex_joint: flex_name.to_string(),
                base,
                flex_axis,
                distal_origin: distal_joint.parent_from_joint,
                distal_axis,
                distal_ratio: multiplier,
                distal_offset_rad: offset,
                flex_limits_rad: flex_limits,
                distal_limits_rad: (ends[0].min(ends[1]), ends[0].max(ends[1])),
                flex_effort_nm: description.variables[flex_var].effort_nm,
                flex_velocity_rad_s: description.variables[flex_var].velocity_rad_s,
                proximal: proximal_link,
                distal: distal_link,
            });
        }
        let fingers: [Finger; 3] = fingers.try_into().expect("three flex joints");
        Ok(HandModel {
            palm: link(palm),
            fingers,
            spread_limits_rad: (spread.lower_rad, spread.upper_rad),
        })
    }

    /// Loads the URDF of the cell configuration and extracts the hand.
    pub fn load(config: &crate::config::CellConfig) -> Result<HandModel, RobotError> {
        let path = &config.robot.urdf;
        let description = RobotDescription::load(path, &config.robot.arm_joints)?;
        HandModel::from_description(&description, &config.robot.palm_link, path)
    }

    /// The flex range every finger allows (rad): the intersection of the fingers'
    /// URDF limits, the range a pre-shape must keep to.
    pub fn flex_limits_rad(&self) -> (f64, f64) {
        self.fingers
            .iter()
            .fold((f64::MIN, f64::MAX), |(lo, hi), f| {
                (lo.max(f.flex_limits_rad.0), hi.min(f.flex_limits_rad.1))
            })
    }

    /// Every link of the hand at `hand` (palm frame): the palm, then each finger's
    /// proximal and distal links (coupled).
    pub fn link_poses(&self, hand: &super::HandPose) -> Vec<(&HandLink, Pose)> {
        let mut out = vec![(&self.palm, Pose::identity())];
        for (finger, &flex) in self.fingers.iter().zip(&hand.flex_rad) {
            let (p, d) = finger.link_poses(hand.spread_rad, flex);
            out.push((&finger.proximal, p));
            out.push((&finger.distal, d));
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::robot::{shipped_robot, HandPose};

    #[test]
    fn finger_poses_match_the_full_tree() {
        let robot = shipped_robot();
        let d = &robot.description;
        let hand = HandModel::from_description(d, "bh_palm", Path::new("shipped")).unwrap();
        let palm = d.link_index("bh_palm").unwrap();
        for pose in [
            HandPose::OPEN,
            HandPose {
                spread_rad: 0.7,
                flex_rad: [0.3, 1.1, 2.4],
            },
        ] {
            let all = robot.link_poses(&[0.1, -0.4, 0.2, 1.0, 0.0, -0.5, 0.3], &pose);
            let palm_from_base = all[palm].inverse();
            for (link, got) in hand.link_poses(&pose) {
                let want = palm_from_base * all[d.link_index(&link.name).unwrap()];
                let (dp, dr) = crate::geometry::pose_error(&got, &want);
                assert!(dp < 1e-12 && dr < 1e-9, "{}: {dp} m, {dr} rad", link.name);
            }
        }
        assert_eq!(hand.fingers[0].proximal.name, "bh_f1_proximal");
        assert_eq!(hand.fingers[2].distal.name, "bh_f3_distal");
        assert!((hand.fingers[1].distal_ratio - 0.3443).abs() < 1e-12);
        assert!((hand.fingers[1].distal_limits_rad.1 - 0.84).abs() < 1e-3);
    }

    /// Files and messages are checked against the BH8-282's flex range without a
    /// URDF at hand; the shipped URDF must agree with it.
    #[test]
    fn the_shipped_urdf_has_the_bh8_282_flex_range() {
        let robot = shipped_robot();
        let hand =
            HandModel::from_description(&robot.description, "bh_palm", Path::new("x")).unwrap();
        assert_eq!(hand.flex_limits_rad(), crate::robot::FLEX_LIMITS_RAD);
    }

    #[test]
    fn flex_axes_sit_where_the_spec_puts_them() {
        // Spec: flex axes at zero at (+-0.025, -0.05, 0.0591) for F1/F2, (0, 0.05, 0.0591) for F3.
        let robot = shipped_robot();
        let hand =
            HandModel::from_description(&robot.description, "bh_palm", Path::new("x")).unwrap();
        let want = [
            [-0.025, -0.05, 0.0591],
            [0.025, -0.05, 0.0591],
            [0.0, 0.05, 0.0591],
        ];
        for (finger, w) in hand.fingers.iter().zip(want) {
            let t = finger.palm_from_flex_base(0.0).translation.vector;
            assert!(
                (t - Vector3::from(w)).norm() < 1e-4,
                "{}: {t:?}",
                finger.flex_joint
            );
        }
    }
}
