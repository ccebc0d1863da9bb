//! Collision of the robot with the table and with itself (parry3d).
//!
//! Link shapes are the URDF's collision primitives. Pairs that may touch are
//! derived as a setup assistant would: links joined by one joint (adjacent, skipping
//! links without shapes) and links that already touch at the home (all-zero)
//! configuration. Every other pair is checked. Links fixed to the robot base are not
//! checked against the table (the base may stand on it).

use super::description::{Primitive, RobotDescription};
use super::kinematics::link_poses;
use crate::config::TableConfig;
use crate::geometry::Pose;
use nalgebra::{Isometry3, Translation3, UnitQuaternion, Vector3};
use parry3d_f64::query;
use parry3d_f64::shape::{Ball, Capsule, Cuboid, Cylinder, SharedShape};

/// How far apart two bounding spheres (or a sphere and the table box) must be for
/// the exact test to be skipped (m): far above the exact test's tolerance, so a
/// skipped pair is one it would have found apart.
pub const BROAD_PHASE_MARGIN_M: f64 = 1e-6;

/// One collision shape of a link.
#[derive(Clone)]
struct LinkShape {
    link_from_shape: Pose,
    shape: SharedShape,
    /// Centre of the shape's bounding sphere in the link frame.
    centre: nalgebra::Point3<f64>,
    radius_m: f64,
}

impl LinkShape {
    fn new(link_from_shape: Pose, shape: SharedShape) -> LinkShape {
        let sphere = shape.compute_local_bounding_sphere();
        LinkShape {
            centre: link_from_shape * sphere.center(),
            radius_m: sphere.radius(),
            link_from_shape,
            shape,
        }
    }
}

/// What a configuration collides with.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
#[serde(tag = "kind", rename_all = "snake_case")]
pub enum Collision {
    /// A link touches the table.
    Table {
        /// The link.
        link: String,
    },
    /// Two links touch each other.
    SelfCollision {
        /// One link.
        a: String,
        /// The other link.
        b: String,
    },
}

impl std::fmt::Display for Collision {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Collision::Table { link } => write!(f, "link {link} collides with the table"),
            Collision::SelfCollision { a, b } => write!(f, "links {a} and {b} collide"),
        }
    }
}

/// The table as a collision box: its top face at `height_m`.
pub fn table_box(table: &TableConfig) -> (Pose, Cuboid) {
    let half = Vector3::new(
        0.5 * table.extent_xy_m[0],
        0.5 * table.extent_xy_m[1],
        0.5 * table.thickness_m,
    );
    let pose = Isometry3::translation(
        table.center_xy_m[0],
        table.center_xy_m[1],
        table.height_m - half.z,
    );
    (pose, Cuboid::new(half))
}

/// A parry shape for a primitive, with the rotation that maps parry's y-axis
/// cylinders and capsules onto the URDF's z axis.
pub fn parry_shape(primitive: &Primitive) -> (SharedShape, Pose) {
    let y_to_z = Isometry3::from_parts(
        Translation3::identity(),
        UnitQuaternion::from_axis_angle(&Vector3::x_axis(), std::f64::consts::FRAC_PI_2),
    );
    match primitive {
        Primitive::Box { size_m } => (
            SharedShape::new(Cuboid::new(Vector3::from(*size_m) * 0.5)),
            Pose::identity(),
        ),
        Primitive::Cylinder { radius_m, length_m } => (
            SharedShape::new(Cylinder::new(0.5 * length_m, *radius_m)),
            y_to_z,
        ),
        Primitive::Capsule { radius_m, length_m } => (
            SharedShape::new(Capsule::new_y(0.5 * length_m, *radius_m)),
            y_to_z,
        ),
        Primitive::Sphere { radius_m } => {
            (SharedShape::new(Ball::new(*radius_m)), Pose::identity())
        }
    }
}

/// Shapes of every link and the pairs to check.
#[derive(Clone)]
pub struct CollisionModel {
    names: Vec<String>,
    /// Per link: its shapes.
    shapes: Vec<Vec<LinkShape>>,
    /// Links checked against the table.
    table_links: Vec<usize>,
    /// Link pairs checked against each other.
    pairs: Vec<(usize, usize)>,
    table: (Pose, Cuboid),
}

impl std::fmt::Debug for CollisionModel {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("CollisionModel")
            .field("links", &self.names)
            .field("pairs", &self.pairs.len())
            .finish()
    }
}

impl CollisionModel {
    /// Builds the model and its allowed-collision pairs.
    pub fn new(description: &RobotDescription, table: &TableConfig) -> CollisionModel {
        let shapes: Vec<Vec<LinkShape>> = description
            .links
            .iter()
            .map(|l| {
                l.shapes
                    .iter()
                    .map(|s| {
                        let (shape, local) = parry_shape(&s.primitive);
                        LinkShape::new(s.link_from_shape * local, shape)
                    })
                    .collect()
            })
            .collect();
        let names = description.links.iter().map(|l| l.name.clone()).collect();
        // Nearest ancestor with shapes, and whether a link moves relative to the root.
        let n = description.links.len();
        let mut shaped_parent = vec![None; n];
        let mut moves = vec![false; n];
        for joint in &description.joints {
            let p = joint.parent_link;
            let c = joint.child_link;
            shaped_parent[c] = if shapes[p].is_empty() {
                shaped_parent[p]
            } else {
                Some(p)
            };
            moves[c] = moves[p] || !matches!(joint.motion, super::description::Motion::Fixed);
        }
        let table_links = (0..n)
            .filter(|&l| moves[l] && !shapes[l].is_empty())
            .collect();
        let mut model = CollisionModel {
            names,
            shapes,
            table_links,
            pairs: Vec::new(),
            table: table_box(table),
        };
        let home = link_poses(description, &vec![0.0; description.variables.len()]);
        for a in 0..n {
            for b in (a + 1)..n {
                if model.shapes[a].is_empty() || model.shapes[b].is_empty() {
                    continue;
                }
                let adjacent = shaped_parent[b] == Some(a) || shaped_parent[a] == Some(b);
                if adjacent || model.links_touch(a, b, &home) {
                    continue;
                }
                model.pairs.push((a, b));
            }
        }
        model
    }

    /// Number of link pairs checked for self-collision.
    pub fn checked_pairs(&self) -> usize {
        self.pairs.len()
    }

    /// The farthest any point of link `link`'s shapes is from the link's origin (m;
    /// 0 for a link without shapes), by their bounding spheres.
    pub fn link_reach_m(&self, link: usize) -> f64 {
        self.shapes[link]
            .iter()
            .map(|s| s.centre.coords.norm() + s.radius_m)
            .fold(0.0, f64::max)
    }

    fn links_touch(&self, a: usize, b: usize, poses: &[Pose]) -> bool {
        self.shapes[a].iter().any(|sa| {
            let centre_a = poses[a] * sa.centre;
            self.shapes[b].iter().any(|sb| {
                let apart = sa.radius_m + sb.radius_m + BROAD_PHASE_MARGIN_M;
                (centre_a - poses[b] * sb.centre).norm_squared() <= apart * apart
                    && query::intersection_test(
                        &(poses[a] * sa.link_from_shape),
                        sa.shape.as_ref(),
                        &(poses[b] * sb.link_from_shape),
                        sb.shape.as_ref(),
                    )
                    .unwrap_or(true)
            })
        })
    }

    /// True when link `link` at pose `world_from_link` touches the table.
    pub fn link_hits_table(&self, link: usize, world_from_link: &Pose) -> bool {
        let (table_pose, table) = &self.table;
        self.shapes[link].iter().any(|s| {
            // How far the sphere's centre is outside the box, per axis of the box.
            let local = table_pose.inverse_transform_point(&(world_from_link * s.centre));
            let outside = (local.coords.abs() - table.half_extents).sup(&Vector3::zeros());
            let apart = s.radius_m + BROAD_PHASE_MARGIN_M;
            outside.norm_squared() <= apart * apart
                && query::intersection_test(
                    &(world_from_link * s.link_from_shape),
                    s.shape.as_ref(),
                    table_pose,
                    table,
                )
                .unwrap_or(true)
        })
    }

    /// The first collision of the links at `poses` (all links, from `link_poses`).
    pub fn check(&self, poses: &[Pose]) -> Option<Collision> {
        self.check_except_table(poses, &[])
    }

    /// [`CollisionModel::check`] with the links in `exempt` allowed to touch the table
    /// (they are still checked against the other links).
    pub fn check_except_table(&self, poses: &[Pose], exempt: &[usize]) -> Option<Collision> {
        self.check_except(poses, exempt, &[])
    }

    /// [`CollisionModel::check_except_table`] that also skips the pairs of links
    /// both in `rigid` (links whose relative poses a motion cannot change: the
    /// hand's, while the arm moves it).
    pub fn check_except(
        &self,
        poses: &[Pose],
        exempt: &[usize],
        rigid: &[usize],
    ) -> Option<Collision> {
        if let Some(&link) = self
            .table_links
            .iter()
            .find(|&&l| !exempt.contains(&l) && self.link_hits_table(l, &poses[l]))
        {
            return Some(Collision::Table {
                link: self.names[link].clone(),
            });
        }
        self.pairs
            .iter()
            .filter(|(a, b)| !(rigid.contains(a) && rigid.contains(b)))
            .find(|&&(a, b)| self.links_touch(a, b, poses))
            .map(|&(a, b)| Collision::SelfCollision {
                a: self.names[a].clone(),
                b: self.names[b].clone(),
            })
    }

    /// The link (at `poses`) nearest `from` on the straight segment `from`–`to`
    /// (base frame): what a camera at `from` sees instead of `to`.
    pub fn link_on_segment(
        &self,
        poses: &[Pose],
        from: &nalgebra::Point3<f64>,
        to: &nalgebra::Point3<f64>,
    ) -> Option<&str> {
        let length_m = (to - from).norm();
        if length_m <= 0.0 {
            return None;
        }
        let ray = query::Ray::new(*from, (to - from) / length_m);
        let hits = (0..self.shapes.len()).flat_map(|l| {
            self.shapes[l].iter().filter_map(move |s| {
                let world_from_shape = poses[l] * s.link_from_shape;
                s.shape
                    .cast_ray(&world_from_shape, &ray, length_m, true)
                    .map(|toi| (toi, l))
            })
        });
        hits.min_by(|a, b| a.0.total_cmp(&b.0))
            .map(|(_, l)| self.names[l].as_str())
    }

    /// The first of `links` (at `poses`) that touches the table.
    pub fn first_on_table(&self, links: &[usize], poses: &[Pose]) -> Option<Collision> {
        links
            .iter()
            .find(|&&l| !self.shapes[l].is_empty() && self.link_hits_table(l, &poses[l]))
            .map(|&l| Collision::Table {
                link: self.names[l].clone(),
            })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::robot::kinematics::ARM_DOF;
    use crate::robot::HandPose;
    use rand::{Rng, SeedableRng};

    /// The exact tests alone, without the bounding spheres.
    fn exact_touch(model: &CollisionModel, a: usize, b: usize, poses: &[Pose]) -> bool {
        model.shapes[a].iter().any(|sa| {
            model.shapes[b].iter().any(|sb| {
                query::intersection_test(
                    &(poses[a] * sa.link_from_shape),
                    sa.shape.as_ref(),
                    &(poses[b] * sb.link_from_shape),
                    sb.shape.as_ref(),
                )
                .unwrap_or(true)
            })
        })
    }

    fn exact_on_table(model: &CollisionModel, link: usize, pose: &Pose) -> bool {
        let (table_pose, table) = &model.table;
        model.shapes[link].iter().any(|s| {
            query::intersection_test(
                &(pose * s.link_from_shape),
                s.shape.as_ref(),
                table_pose,
                table,
            )
            .unwrap_or(true)
        })
    }

    #[test]
    fn a_line_of_sight_through_the_upright_arm_names_its_link_and_one_beside_it_none() {
        let robot = crate::robot::shipped_robot();
        let (q, hand) = ([0.0; ARM_DOF], HandPose::default());
        let seen = |from: [f64; 3], to: [f64; 3]| {
            robot
                .link_on_segment(&q, &hand, &from.into(), &to.into())
                .map(str::to_string)
        };
        // Across the upright arm's column at 0.5 m.
        let link = seen([1.0, 0.0, 0.5], [-1.0, 0.0, 0.5]).expect("a link");
        assert!(link.starts_with("lbr_"), "{link}");
        // The same line ending 0.3 m short of the column, and one 1 m to the side.
        assert_eq!(seen([1.0, 0.0, 0.5], [0.3, 0.0, 0.5]), None);
        assert_eq!(seen([1.0, 1.0, 0.5], [-1.0, 1.0, 0.5]), None);
        // Down onto the hand above the arm.
        let link = seen([0.0, 0.0, 2.0], [0.0, 0.0, 1.0]).expect("a link");
        assert!(link.starts_with("bh_"), "{link}");
        assert_eq!(seen([0.5, 0.5, 0.5], [0.5, 0.5, 0.5]), None);
    }

    /// Every pair's and every link's verdict is the exact test's, at random arm and
    /// hand configurations inside the limits (many of them colliding).
    #[test]
    fn bounding_spheres_never_change_a_verdict() {
        let robot = crate::robot::shipped_robot();
        let model = &robot.collision;
        let arm = robot.arm();
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
        let (mut touching, mut on_table) = (0, 0);
        for _ in 0..2000 {
            let mut q = [0.0; ARM_DOF];
            for (i, v) in q.iter_mut().enumerate() {
                *v = rng.gen_range(arm.lower_rad[i]..=arm.upper_rad[i]);
            }
            let hand = HandPose {
                spread_rad: rng.gen_range(0.0..std::f64::consts::PI),
                flex_rad: [(); 3].map(|()| rng.gen_range(0.0..2.44)),
            };
            let poses = robot.link_poses(&q, &hand);
            for &(a, b) in &model.pairs {
                let exact = exact_touch(model, a, b, &poses);
                assert_eq!(model.links_touch(a, b, &poses), exact, "{q:?} {a} {b}");
                touching += usize::from(exact);
            }
            for &l in &model.table_links {
                let exact = exact_on_table(model, l, &poses[l]);
                assert_eq!(model.link_hits_table(l, &poses[l]), exact, "{q:?} {l}");
                on_table += usize::from(exact);
            }
        }
        assert!(touching > 100 && on_table > 100, "{touching} {on_table}");
    }
}
