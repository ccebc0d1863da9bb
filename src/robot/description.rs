//! Loading the URDF: urdf-rs parses it, we validate it, `k` builds the kinematic
//! chain, and the chain is flattened into a [`RobotDescription`] (links in
//! topological order, joints with origins and axes, actuated variables with limits)
//! that the fast kinematics and the collision model work on.

use super::RobotError;
use crate::geometry::Pose;
use nalgebra::{Isometry3, Quaternion, Translation3, Unit, UnitQuaternion, Vector3};
use std::collections::{HashMap, HashSet};
use std::path::Path;

/// A collision primitive of a link, in the link's frame.
#[derive(Debug, Clone, PartialEq)]
pub enum Primitive {
    /// A box with full side lengths (m).
    Box {
        /// Side lengths x y z (m).
        size_m: [f64; 3],
    },
    /// A cylinder along the shape frame's z axis, centred on its origin.
    Cylinder {
        /// Radius (m).
        radius_m: f64,
        /// Length along z (m).
        length_m: f64,
    },
    /// A capsule along the shape frame's z axis (length between sphere centres).
    Capsule {
        /// Radius (m).
        radius_m: f64,
        /// Length of the segment between the cap centres (m).
        length_m: f64,
    },
    /// A sphere.
    Sphere {
        /// Radius (m).
        radius_m: f64,
    },
}

/// One collision primitive placed in its link.
#[derive(Debug, Clone, PartialEq)]
pub struct CollisionShape {
    /// Pose of the primitive in the link frame.
    pub link_from_shape: Pose,
    /// The primitive.
    pub primitive: Primitive,
}

/// A link: a rigid body with collision shapes.
#[derive(Debug, Clone)]
pub struct LinkSpec {
    /// URDF link name.
    pub name: String,
    /// The joint whose child this link is (`None` for the root).
    pub parent_joint: Option<usize>,
    /// Collision primitives.
    pub shapes: Vec<CollisionShape>,
}

/// How a joint moves.
#[derive(Debug, Clone, PartialEq)]
pub enum Motion {
    /// Rigid.
    Fixed,
    /// Rotation about `axis` (joint frame) by `multiplier * q[variable] + offset`.
    Revolute {
        /// Unit axis in the joint frame.
        axis: Unit<Vector3<f64>>,
        /// Index of the driving variable.
        variable: usize,
        /// Mimic multiplier (1 for an actuated joint).
        multiplier: f64,
        /// Mimic offset (rad).
        offset: f64,
    },
}

/// A joint between two links.
#[derive(Debug, Clone)]
pub struct JointSpec {
    /// URDF joint name.
    pub name: String,
    /// Index of the parent link.
    pub parent_link: usize,
    /// Index of the child link.
    pub child_link: usize,
    /// The joint's origin: parent link frame from joint frame at zero.
    pub parent_from_joint: Pose,
    /// How it moves.
    pub motion: Motion,
}

/// An actuated degree of freedom (a revolute joint that mimics no other).
#[derive(Debug, Clone, PartialEq)]
pub struct Variable {
    /// Name of the joint it drives.
    pub name: String,
    /// Lower limit (rad).
    pub lower_rad: f64,
    /// Upper limit (rad).
    pub upper_rad: f64,
    /// Velocity limit (rad/s).
    pub velocity_rad_s: f64,
    /// Effort limit (Nm).
    pub effort_nm: f64,
}

/// The robot as a flat kinematic tree.
#[derive(Debug, Clone)]
pub struct RobotDescription {
    /// Robot name from the URDF.
    pub name: String,
    /// Links; a parent always comes before its children; `links[0]` is the root.
    pub links: Vec<LinkSpec>,
    /// Joints; `joints[j]` is listed before any joint below its child link.
    pub joints: Vec<JointSpec>,
    /// Actuated variables: the arm joints first (in the configured order), then the rest.
    pub variables: Vec<Variable>,
}

impl RobotDescription {
    /// Loads and validates a URDF; `arm_joints` become variables 0..n in that order.
    pub fn load(path: &Path, arm_joints: &[String]) -> Result<RobotDescription, RobotError> {
        let text = if path == Path::new(crate::config::BUILTIN_URDF) {
            crate::config::BUILTIN_URDF_TEXT.to_string()
        } else {
            crate::fsio::read_to_string(path).map_err(RobotError::Read)?
        };
        Self::parse(&text, path, arm_joints)
    }

    /// Parses and validates URDF `text` read from `path` (which names it in errors).
    pub fn parse(
        text: &str,
        path: &Path,
        arm_joints: &[String],
    ) -> Result<RobotDescription, RobotError> {
        let urdf = urdf_rs::read_from_string(text).map_err(|e| RobotError::Urdf {
            path: path.to_path_buf(),
            problem: e.to_string().replace('\n', " "),
        })?;
        validate_urdf(&urdf, path)?;
        let chain = k::Chain::<f64>::from(&urdf);
        Self::from_chain(&urdf, &chain, arm_joints, path)
    }

    /// Index of the link called `name`.
    pub fn link_index(&self, name: &str) -> Option<usize> {
        self.links.iter().position(|l| l.name == name)
    }

    /// Index of the variable driving the joint called `name`.
    pub fn variable_index(&self, name: &str) -> Option<usize> {
        self.variables.iter().position(|v| v.name == name)
    }

    /// The joints from the root to `link`, in order.
    pub fn path_to(&self, link: usize) -> Vec<usize> {
        let mut path = Vec::new();
        let mut current = link;
        while let Some(j) = self.links[current].parent_joint {
            path.push(j);
            current = self.joints[j].parent_link;
        }
        path.reverse();
        path
    }

    /// Flattens the `k` chain, taking from urdf-rs what `k` does not keep
    /// (velocity and effort limits, mimic coefficients, collision geometry).
    fn from_chain(
        urdf: &urdf_rs::Robot,
        chain: &k::Chain<f64>,
        arm_joints: &[String],
        path: &Path,
    ) -> Result<RobotDescription, RobotError> {
        let urdf_joints: HashMap<&str, &urdf_rs::Joint> =
            urdf.joints.iter().map(|j| (j.name.as_str(), j)).collect();
        let urdf_links: HashMap<&str, &urdf_rs::Link> =
            urdf.links.iter().map(|l| (l.name.as_str(), l)).collect();

        for name in arm_joints {
            let joint = urdf_joints
                .get(name.as_str())
                .ok_or_else(|| RobotError::MissingJoint {
                    path: path.to_path_buf(),
                    joint: name.clone(),
                })?;
            if !matches!(joint.joint_type, urdf_rs::JointType::Revolute) || joint.mimic.is_some() {
                return Err(RobotError::BadJoint {
                    path: path.to_path_buf(),
                    joint: name.clone(),
                    problem: "an arm joint must be revolute, limited and not a mimic".into(),
                });
            }
        }

        // Variables: the arm joints in the configured order, then every other
        // actuated revolute joint in chain order.
        let mut variables: Vec<Variable> = Vec::new();
        let mut variable_of: HashMap<String, usize> = HashMap::new();
        let actuated_in_chain_order = chain
            .iter()
            .map(|node| node.joint().name.clone())
            .filter(|n| {
                urdf_joints.get(n.as_str()).is_some_and(|j| {
                    j.mimic.is_none()
                        && matches!(
                            j.joint_type,
                            urdf_rs::JointType::Revolute | urdf_rs::JointType::Continuous
                        )
                })
            })
            .filter(|n| !arm_joints.contains(n))
            .collect::<Vec<_>>();
        for name in arm_joints.iter().chain(actuated_in_chain_order.iter()) {
            let j = urdf_joints[name.as_str()];
            let (lower_rad, upper_rad) = match j.joint_type {
                urdf_rs::JointType::Continuous => (-std::f64::consts::PI, std::f64::consts::PI),
                _ => (j.limit.lower, j.limit.upper),
            };
            if lower_rad.partial_cmp(&upper_rad) != Some(std::cmp::Ordering::Less)
                || j.limit.velocity.partial_cmp(&0.0) != Some(std::cmp::Ordering::Greater)
            {
                return Err(RobotError::BadJoint {
                    path: path.to_path_buf(),
                    joint: name.clone(),
                    problem: format!(
                        "limits [{lower_rad}, {upper_rad}] rad, velocity {} rad/s: need lower < upper and velocity > 0",
                        j.limit.velocity
                    ),
                });
            }
            variable_of.insert(name.clone(), variables.len());
            variables.push(Variable {
                name: name.clone(),
                lower_rad,
                upper_rad,
                velocity_rad_s: j.limit.velocity,
                effort_nm: j.limit.effort,
            });
        }

        // Links and joints in the chain's depth-first order: parents first.
        let root_name = urdf_links
            .keys()
            .find(|l| !urdf.joints.iter().any(|j| j.child.link == **l))
            .map(|s| s.to_string())
            .ok_or_else(|| RobotError::Urdf {
                path: path.to_path_buf(),
                problem: "no root link (every link is some joint's child)".into(),
            })?;
        let mut links = vec![LinkSpec {
            name: root_name.clone(),
            parent_joint: None,
            shapes: shapes_of(urdf_links[root_name.as_str()], path)?,
        }];
        let mut link_index: HashMap<String, usize> = HashMap::from([(root_name, 0)]);
        let mut joints = Vec::new();
        for node in chain.iter() {
            // Copy out of the node: `node.joint()` holds the node's lock.
            let origin = from_k(&node.origin());
            let (name, joint_type) = {
                let joint = node.joint();
                (joint.name.clone(), joint.joint_type)
            };
            let Some(uj) = urdf_joints.get(name.as_str()) else {
                continue; // k's virtual root joint
            };
            let parent_link = *link_index
                .get(&uj.parent.link)
                .ok_or_else(|| RobotError::Urdf {
                    path: path.to_path_buf(),
                    problem: format!(
                        "joint {} comes before its parent link {}",
                        uj.name, uj.parent.link
                    ),
                })?;
            let motion = match &joint_type {
                k::JointType::Rotational { axis } => {
                    let axis = Unit::new_normalize(Vector3::new(axis.x, axis.y, axis.z));
                    match &uj.mimic {
                        Some(m) => Motion::Revolute {
                            axis,
                            variable: *variable_of.get(&m.joint).ok_or_else(|| {
                                RobotError::BadJoint {
                                    path: path.to_path_buf(),
                                    joint: uj.name.clone(),
                                    problem: format!(
                                        "mimics {}, which is not an actuated joint",
                                        m.joint
                                    ),
                                }
                            })?,
                            multiplier: m.multiplier.unwrap_or(1.0),
                            offset: m.offset.unwrap_or(0.0),
                        },
                        None => Motion::Revolute {
                            axis,
                            variable: variable_of[&uj.name],
                            multiplier: 1.0,
                            offset: 0.0,
                        },
                    }
                }
                k::JointType::Fixed => Motion::Fixed,
                k::JointType::Linear { .. } => {
                    return Err(RobotError::BadJoint {
                        path: path.to_path_buf(),
                        joint: uj.name.clone(),
                        problem: "prismatic joints are not supported".into(),
                    })
                }
            };
            let child_link = links.len();
            link_index.insert(uj.child.link.clone(), child_link);
            links.push(LinkSpec {
                name: uj.child.link.clone(),
                parent_joint: Some(joints.len()),
                shapes: shapes_of(urdf_links[uj.child.link.as_str()], path)?,
            });
            joints.push(JointSpec {
                name: uj.name.clone(),
                parent_link,
                child_link,
                parent_from_joint: origin,
                motion,
            });
        }
        Ok(RobotDescription {
            name: urdf.name.clone(),
            links,
            joints,
            variables,
        })
    }
}

/// Converts a pose of `k`'s nalgebra to ours (translation and quaternion).
pub(crate) fn from_k(iso: &k::Isometry3<f64>) -> Pose {
    let t = iso.translation.vector;
    let q = iso.rotation.quaternion();
    Isometry3::from_parts(
        Translation3::new(t.x, t.y, t.z),
        UnitQuaternion::from_quaternion(Quaternion::new(q.w, q.i, q.j, q.k)),
    )
}

/// Checks what `k` would otherwise panic on or silently accept: dangling links,
/// duplicate names, mimics of missing joints, non-finite numbers, a tree shape.
fn validate_urdf(urdf: &urdf_rs::Robot, path: &Path) -> Result<(), RobotError> {
    let err = |problem: String| RobotError::Urdf {
        path: path.to_path_buf(),
        problem,
    };
    let link_names: HashSet<&str> = urdf.links.iter().map(|l| l.name.as_str()).collect();
    if link_names.len() != urdf.links.len() {
        return Err(err("duplicate link names".into()));
    }
    let mut joint_names = HashSet::new();
    let mut children = HashSet::new();
    for j in &urdf.joints {
        if !joint_names.insert(j.name.as_str()) {
            return Err(err(format!("duplicate joint name {}", j.name)));
        }
        for l in [&j.parent.link, &j.child.link] {
            if !link_names.contains(l.as_str()) {
                return Err(err(format!("joint {} refers to missing link {l}", j.name)));
            }
        }
        if !children.insert(j.child.link.as_str()) {
            return Err(err(format!(
                "link {} is the child of two joints",
                j.child.link
            )));
        }
        let numbers = [
            &j.origin.xyz.0[..],
            &j.origin.rpy.0[..],
            &j.axis.xyz.0[..],
            &[
                j.limit.lower,
                j.limit.upper,
                j.limit.velocity,
                j.limit.effort,
            ][..],
        ]
        .concat();
        if numbers.iter().any(|v| !v.is_finite()) {
            return Err(err(format!("joint {} has a non-finite number", j.name)));
        }
        if matches!(
            j.joint_type,
            urdf_rs::JointType::Revolute | urdf_rs::JointType::Continuous
        ) && Vector3::from(j.axis.xyz.0).norm() < 1e-9
        {
            return Err(err(format!("joint {} has a zero axis", j.name)));
        }
    }
    for j in &urdf.joints {
        if let Some(m) = &j.mimic {
            if !joint_names.contains(m.joint.as_str()) {
                return Err(err(format!(
                    "joint {} mimics missing joint {}",
                    j.name, m.joint
                )));
            }
        }
    }
    let roots = urdf
        .links
        .iter()
        .filter(|l| !children.contains(l.name.as_str()))
        .count();
    if roots != 1 {
        return Err(err(format!("expected one root link, found {roots}")));
    }
    // One root and one parent per link still allows a detached joint cycle
    // (a -> b -> a beside the tree), which `k` would build as a reference cycle
    // and the flattening would silently drop: every link must hang from the root.
    let root = urdf
        .links
        .iter()
        .find(|l| !children.contains(l.name.as_str()))
        .map(|l| l.name.as_str());
    let mut reached: HashSet<&str> = root.into_iter().collect();
    let mut frontier: Vec<&str> = reached.iter().copied().collect();
    while let Some(link) = frontier.pop() {
        for j in urdf.joints.iter().filter(|j| j.parent.link == link) {
            if reached.insert(j.child.link.as_str()) {
                frontier.push(j.child.link.as_str());
            }
        }
    }
    if let Some(detached) = urdf
        .links
        .iter()
        .find(|l| !reached.contains(l.name.as_str()))
    {
        return Err(err(format!(
            "link {} is not below the root link (its joints form a cycle)",
            detached.name
        )));
    }
    Ok(())
}

fn shapes_of(link: &urdf_rs::Link, path: &Path) -> Result<Vec<CollisionShape>, RobotError> {
    link.collision
        .iter()
        .map(|c| {
            let primitive = match &c.geometry {
                urdf_rs::Geometry::Box { size } => Primitive::Box { size_m: size.0 },
                urdf_rs::Geometry::Cylinder { radius, length } => Primitive::Cylinder {
                    radius_m: *radius,
                    length_m: *length,
                },
                urdf_rs::Geometry::Capsule { radius, length } => Primitive::Capsule {
                    radius_m: *radius,
                    length_m: *length,
                },
                urdf_rs::Geometry::Sphere { radius } => Primitive::Sphere { radius_m: *radius },
                urdf_rs::Geometry::Mesh { filename, .. } => {
                    return Err(RobotError::Urdf {
                        path: path.to_path_buf(),
                        problem: format!(
                            "link {}: mesh collision geometry ({filename}) is not supported; use primitives",
                            link.name
                        ),
                    })
                }
            };
            let [x, y, z] = c.origin.xyz.0;
            let [r, p, yw] = c.origin.rpy.0;
            Ok(CollisionShape {
                link_from_shape: Isometry3::from_parts(
                    Translation3::new(x, y, z),
                    UnitQuaternion::from_euler_angles(r, p, yw),
                ),
                primitive,
            })
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn shipped_urdf() -> String {
        std::fs::read_to_string(
            Path::new(env!("CARGO_MANIFEST_DIR")).join("robot/lbr4_bh8_282.urdf"),
        )
        .unwrap()
    }

    fn arm_names() -> Vec<String> {
        [
            "lbr_a1", "lbr_a2", "lbr_e1", "lbr_a3", "lbr_a4", "lbr_a5", "lbr_a6",
        ]
        .map(String::from)
        .to_vec()
    }

    fn load_text(name: &str, text: &str, arm: &[String]) -> Result<RobotDescription, RobotError> {
        let dir = crate::fsio::TempDir::new("urdf").unwrap();
        let path = dir.join(format!("{name}.urdf"));
        std::fs::write(&path, text).unwrap();
        RobotDescription::load(&path, arm)
    }

    #[test]
    fn shipped_urdf_has_the_arm_and_hand() {
        let d = load_text("ok", &shipped_urdf(), &arm_names()).unwrap();
        assert_eq!(d.variables.len(), 11, "7 arm + spread + 3 flex");
        assert_eq!(d.variables[1].name, "lbr_a2");
        assert!((d.variables[1].upper_rad - 120f64.to_radians()).abs() < 1e-5);
        assert!((d.variables[4].velocity_rad_s - 204f64.to_radians()).abs() < 1e-5);
        for (i, j) in d.joints.iter().enumerate() {
            assert!(
                d.links[j.parent_link].parent_joint.is_none_or(|p| p < i),
                "topological order"
            );
        }
    }

    #[test]
    fn missing_arm_joint_is_named() {
        let err = load_text(
            "missing",
            &shipped_urdf().replace("lbr_e1", "lbr_x1"),
            &arm_names(),
        )
        .unwrap_err();
        assert!(
            matches!(&err, RobotError::MissingJoint { joint, .. } if joint == "lbr_e1"),
            "{err}"
        );
        assert!(err.to_string().contains("missing.urdf"));
    }

    #[test]
    fn malformed_urdf_is_an_error_naming_the_file() {
        let text = shipped_urdf();
        let err = load_text("truncated", &text[..text.len() / 2], &arm_names())
            .unwrap_err()
            .to_string();
        assert!(err.contains("truncated.urdf"), "{err}");
        let err = load_text(
            "mimic",
            &text.replace("mimic joint=\"bh_j12\"", "mimic joint=\"bh_j99\""),
            &arm_names(),
        )
        .unwrap_err()
        .to_string();
        assert!(err.contains("bh_j99"), "{err}");
        let err = load_text(
            "nan",
            &text.replace("xyz=\"0 0 0.2005\"", "xyz=\"0 0 NaN\""),
            &arm_names(),
        )
        .unwrap_err()
        .to_string();
        assert!(
            err.contains("lbr_a2") && err.contains("non-finite"),
            "{err}"
        );
    }

    /// The fuzzer's URDF crash (issue 21): two links that are each other's child
    /// beside the tree passed the one-root and one-parent checks; `k` leaked them
    /// as a reference cycle and the description silently lacked them.
    #[test]
    fn a_detached_joint_cycle_is_refused() {
        let cycle = r#"<link name="ring_a"/><link name="ring_b"/>
  <joint name="ring_ab" type="fixed"><parent link="ring_a"/><child link="ring_b"/></joint>
  <joint name="ring_ba" type="fixed"><parent link="ring_b"/><child link="ring_a"/></joint>
</robot>"#;
        let text = shipped_urdf().replace("</robot>", cycle);
        let err = load_text("cycle", &text, &arm_names())
            .unwrap_err()
            .to_string();
        assert!(
            err.contains("cycle.urdf") && err.contains("ring_a") && err.contains("cycle"),
            "{err}"
        );
    }
}
