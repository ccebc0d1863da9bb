//! The surface the camera saw as an obstacle (issue 17): the open hand at the grasp,
//! and at every point of its approach from the pre-grasp, must not reach into the
//! object's segmented points (robot base frame) deeper than a tolerance.
//!
//! The planner checks it wherever it checks reachability ([`super::planner`]: the
//! optimum, the starting points of the constrained search and every repaired pose
//! of it), so a grasp whose open palm starts inside the object is refused and the
//! search moves to the nearest grasp that clears the seen surface. It applies when
//! reachability is checked (the cell's setting).
//!
//! The cloud is thinned on a voxel grid first (a point per `voxel_m` cube); the
//! approach is sampled every `step_m` from the grasp back to the pre-grasp. Per hand
//! shape, only the points inside its box swept along the approach are tested
//! exactly (inside the shape by more than `tolerance_m`).

use super::PlanError;
use crate::cloud::PointCloud;
use crate::geometry::Pose;
use crate::robot::hand::HandModel;
use crate::robot::HandPose;
use nalgebra::{Point3, Translation3};
use parry3d_f64::bounding_volume::BoundingVolume;
use serde::Serialize;

/// Settings of the seen-surface check.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct SeenSurfaceOptions {
    /// How deep a point may lie inside the open hand (m): the sensor's noise.
    pub tolerance_m: f64,
    /// Length of the approach checked behind the grasp (m): the pre-grasp offset.
    pub approach_m: f64,
    /// Spacing of the poses sampled along the approach (m).
    pub step_m: f64,
    /// Voxel size of the thinned cloud (m).
    pub voxel_m: f64,
    /// The approach stops at first contact (the executor's approach to contact), so
    /// only its start, the pre-grasp, must be clear; otherwise the whole approach
    /// down to the grasp (the paper's execution, which closes where planned).
    pub contact_stops_approach: bool,
}

impl Default for SeenSurfaceOptions {
    /// 3 mm tolerance, a 0.1 m approach in 1 cm steps, 4 mm voxels, the whole
    /// approach checked.
    fn default() -> Self {
        SeenSurfaceOptions {
            tolerance_m: 0.003,
            approach_m: 0.10,
            step_m: 0.01,
            voxel_m: 0.004,
            contact_stops_approach: false,
        }
    }
}

impl SeenSurfaceOptions {
    /// The default settings with the approach of `plan` (its pre-grasp offset), for
    /// an execution that stops at first contact or not.
    pub fn along_approach(
        plan: &super::PlanOptions,
        contact_stops_approach: bool,
    ) -> SeenSurfaceOptions {
        SeenSurfaceOptions {
            approach_m: plan.pregrasp_offset_m,
            contact_stops_approach,
            ..SeenSurfaceOptions::default()
        }
    }
}

/// Where the open hand reaches into the seen surface.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Intrusion {
    /// The hand link.
    pub link: String,
    /// Points inside it by more than the tolerance.
    pub points: usize,
    /// The deepest of them (m).
    pub depth_m: f64,
    /// How far behind the grasp, along the approach, the hand was (m; 0 = at it).
    pub behind_grasp_m: f64,
}

impl std::fmt::Display for Intrusion {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "the open hand's {} reaches {:.1} mm into {} seen points, {:.0} mm before the grasp",
            self.link,
            self.depth_m * 1e3,
            self.points,
            self.behind_grasp_m * 1e3
        )
    }
}

/// The object's seen points and the hand that must not enter them.
#[derive(Debug, Clone)]
pub struct SeenSurface<'a> {
    hand: &'a HandModel,
    points: Vec<Point3<f64>>,
    options: SeenSurfaceOptions,
}

/// Height above the table of the seen solid's margin (m): a solid needs some
/// thickness everywhere.
pub const SOLID_SKIRT_M: f64 = 0.001;

impl<'a> SeenSurface<'a> {
    /// The seen surface of `cloud` (base frame) for `hand`. Errors: an empty cloud
    /// or a non-finite or non-positive setting.
    pub fn new(
        hand: &'a HandModel,
        cloud: &PointCloud,
        options: SeenSurfaceOptions,
    ) -> Result<SeenSurface<'a>, PlanError> {
        let check = super::objective::check_value;
        check("seen surface tolerance_m", options.tolerance_m, false)?;
        check("seen surface approach_m", options.approach_m, false)?;
        check("seen surface step_m", options.step_m, true)?;
        check("seen surface voxel_m", options.voxel_m, true)?;
        let thinned = crate::cloud::voxel::voxel_downsample(cloud, options.voxel_m);
        let points: Vec<Point3<f64>> = thinned
            .points
            .iter()
            .map(|p| Point3::new(p.x as f64, p.y as f64, p.z as f64))
            .filter(|p| p.coords.iter().all(|v| v.is_finite()))
            .collect();
        if points.is_empty() {
            return Err(PlanError::BadValue {
                what: "seen surface cloud points".into(),
                value: 0.0,
                problem: "the object's cloud has no finite point",
            });
        }
        Ok(SeenSurface {
            hand,
            points,
            options,
        })
    }

    /// Points kept after thinning.
    pub fn len(&self) -> usize {
        self.points.len()
    }

    /// Always false (a seen surface has points).
    pub fn is_empty(&self) -> bool {
        self.points.is_empty()
    }

    /// The solid under the seen surface: the thinned points' height map over squares
    /// of `cell_m`, its corners as high as the highest point of the squares around
    /// them, extruded down to the table top at `table_height_m` (base frame, m).
    /// A closed, outward mesh in the base frame. It is the object as far as the
    /// camera shows it: a wall that slopes out towards the foot is there where the
    /// camera saw it, which the registered models may not have. A margin of one
    /// square around the points stands `SOLID_SKIRT_M` above the table.
    pub fn solid(&self, table_height_m: f64, cell_m: f64) -> crate::mesh::TriMesh {
        let floor = table_height_m + SOLID_SKIRT_M;
        let (mut lo, mut hi) = (self.points[0], self.points[0]);
        for p in &self.points {
            lo = lo.inf(p);
            hi = hi.sup(p);
        }
        // Cells, with one empty cell of margin on every side.
        let nx = ((hi.x - lo.x) / cell_m).floor() as usize + 3;
        let ny = ((hi.y - lo.y) / cell_m).floor() as usize + 3;
        let (x0, y0) = (lo.x - cell_m, lo.y - cell_m);
        let mut cell_top = vec![floor; nx * ny];
        for p in &self.points {
            let i = ((p.x - x0) / cell_m) as usize;
            let j = ((p.y - y0) / cell_m) as usize;
            let top = &mut cell_top[j * nx + i];
            *top = top.max(p.z);
        }
        // Corner heights; corner (i, j) touches cells (i-1..=i, j-1..=j).
        let corner = |i: usize, j: usize| -> f64 {
            let mut h = floor;
            for ci in i.saturating_sub(1)..(i + 1).min(nx) {
                for cj in j.saturating_sub(1)..(j + 1).min(ny) {
                    h = h.max(cell_top[cj * nx + ci]);
                }
            }
            h
        };
        let (cx, cy) = (nx + 1, ny + 1);
        let mut vertices = Vec::with_capacity(2 * cx * cy);
        for z in [None, Some(table_height_m)] {
            for j in 0..cy {
                for i in 0..cx {
                    let (x, y) = (x0 + i as f64 * cell_m, y0 + j as f64 * cell_m);
                    vertices.push(Point3::new(x, y, z.unwrap_or_else(|| corner(i, j))));
                }
            }
        }
        let top = |i: usize, j: usize| (j * cx + i) as u32;
        let bottom = |i: usize, j: usize| (cx * cy + j * cx + i) as u32;
        let mut triangles = Vec::with_capacity(4 * nx * ny + 4 * (nx + ny));
        for j in 0..ny {
            for i in 0..nx {
                let [a, b, c, d] = [(i, j), (i + 1, j), (i + 1, j + 1), (i, j + 1)];
                triangles.push([top(a.0, a.1), top(b.0, b.1), top(c.0, c.1)]);
                triangles.push([top(a.0, a.1), top(c.0, c.1), top(d.0, d.1)]);
                triangles.push([bottom(a.0, a.1), bottom(c.0, c.1), bottom(b.0, b.1)]);
                triangles.push([bottom(a.0, a.1), bottom(d.0, d.1), bottom(c.0, c.1)]);
            }
        }
        // The rim's corners counter-clockwise seen from above; each edge's wall faces
        // out (to its right).
        let rim: Vec<(usize, usize)> = (0..nx)
            .map(|i| (i, 0))
            .chain((0..ny).map(|j| (nx, j)))
            .chain((1..=nx).rev().map(|i| (i, ny)))
            .chain((1..=ny).rev().map(|j| (0, j)))
            .collect();
        for (k, &p) in rim.iter().enumerate() {
            let q = rim[(k + 1) % rim.len()];
            triangles.push([bottom(p.0, p.1), bottom(q.0, q.1), top(q.0, q.1)]);
            triangles.push([bottom(p.0, p.1), top(q.0, q.1), top(p.0, p.1)]);
        }
        crate::mesh::TriMesh {
            vertices,
            triangles,
        }
    }

    /// The settings.
    pub fn options(&self) -> &SeenSurfaceOptions {
        &self.options
    }

    /// The first intrusion of the hand in its pre-shape `hand` (open, or fingers
    /// partly closed) into the seen points, at the grasp `palm` or along its
    /// approach (at its start only when contact stops the approach); `None` when it
    /// stays clear.
    pub fn intrusion(&self, palm: &Pose, hand: &HandPose) -> Option<Intrusion> {
        let o = &self.options;
        let steps = (o.approach_m / o.step_m).ceil() as usize;
        let back = |k: usize| -> Pose {
            let d = (k as f64 * o.step_m).min(o.approach_m);
            palm * Translation3::new(0.0, 0.0, -d)
        };
        let pre = back(steps);
        let first = if o.contact_stops_approach { steps } else { 0 };
        for (link, link_pose) in self.hand.link_poses(hand) {
            for (link_from_shape, shape) in &link.shapes {
                let local = link_pose * link_from_shape;
                // The box swept by the shape along the approach (a translation).
                let swept = shape
                    .compute_aabb(&(back(first) * local))
                    .merged(&shape.compute_aabb(&(pre * local)));
                let inside: Vec<&Point3<f64>> = self
                    .points
                    .iter()
                    .filter(|p| swept.contains_local_point(p))
                    .collect();
                if inside.is_empty() {
                    continue;
                }
                for k in first..=steps {
                    let world_from_shape = back(k) * local;
                    let mut count = 0;
                    let mut depth: f64 = 0.0;
                    for p in &inside {
                        let q = world_from_shape.inverse_transform_point(p);
                        let proj = shape.project_local_point(&q, false);
                        if proj.is_inside {
                            let d = (proj.point - q).norm();
                            if d > o.tolerance_m {
                                count += 1;
                                depth = depth.max(d);
                            }
                        }
                    }
                    if count > 0 {
                        return Some(Intrusion {
                            link: link.name.clone(),
                            points: count,
                            depth_m: depth,
                            behind_grasp_m: (k as f64 * o.step_m).min(o.approach_m),
                        });
                    }
                }
            }
        }
        None
    }
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use crate::geometry::pose_from_params;
    use crate::robot::shipped_robot;
    use std::path::Path;

    /// Points on a vertical cylinder (radius 4 cm, 10 cm tall) at (0.6, 0, 0).
    pub(crate) fn cylinder_cloud() -> PointCloud {
        let mut points = Vec::new();
        for i in 0..60 {
            for j in 0..20 {
                let a = i as f64 / 60.0 * std::f64::consts::TAU;
                points.push(Point3::new(
                    (0.6 + 0.04 * a.cos()) as f32,
                    (0.04 * a.sin()) as f32,
                    (j as f64 * 0.005) as f32,
                ));
            }
        }
        PointCloud::from_points(points)
    }

    #[test]
    fn a_palm_inside_the_points_intrudes_and_one_beside_them_does_not() {
        let robot = shipped_robot();
        let hand = crate::quality::autograsp::tests::hand_of(&robot);
        let seen =
            SeenSurface::new(&hand, &cylinder_cloud(), SeenSurfaceOptions::default()).unwrap();
        // Palm z (approach) along +x toward the cylinder's axis, palm at the axis.
        let inside = pose_from_params(&[0.6, 0.0, 0.05, 0.0, std::f64::consts::FRAC_PI_2, 0.0]);
        let hit = seen
            .intrusion(&inside, &HandPose::OPEN)
            .expect("the palm is in the cylinder");
        assert!(hit.depth_m > 0.003 && hit.points > 0, "{hit:?}");
        assert!(hit.to_string().contains("mm"), "{hit}");
        // The same orientation 0.25 m back: clear, and so is its approach.
        let clear = pose_from_params(&[0.35, 0.0, 0.05, 0.0, std::f64::consts::FRAC_PI_2, 0.0]);
        assert_eq!(seen.intrusion(&clear, &HandPose::OPEN), None);
        // Clear at the grasp but not along the approach: the first palm position
        // beyond the cylinder where the hand itself is clear, come through it.
        let at_grasp_only = SeenSurfaceOptions {
            approach_m: 0.0,
            ..SeenSurfaceOptions::default()
        };
        let only = SeenSurface::new(&hand, &cylinder_cloud(), at_grasp_only).unwrap();
        let beyond =
            |x: f64| pose_from_params(&[x, 0.0, 0.05, 0.0, std::f64::consts::FRAC_PI_2, 0.0]);
        let clear_x = (0..60)
            .map(|k| 0.6 + 0.005 * k as f64)
            .find(|&x| only.intrusion(&beyond(x), &HandPose::OPEN).is_none())
            .expect("the hand clears the cylinder somewhere beyond it");
        assert!(clear_x < 0.6 + 0.1, "{clear_x}");
        let hit = seen
            .intrusion(&beyond(clear_x), &HandPose::OPEN)
            .expect("the approach crosses it");
        assert!(hit.behind_grasp_m > 0.0, "{hit:?}");
        let empty = PointCloud::from_points(Vec::new());
        assert!(SeenSurface::new(&hand, &empty, SeenSurfaceOptions::default()).is_err());
    }

    #[test]
    fn the_seen_solid_is_closed_stands_on_the_table_and_keeps_a_slope() {
        // A frustum narrowing upwards (the held-apart conical mug: radius 49 mm at
        // the foot, 29 mm at the top, 105 mm tall) at (0.6, 0) on a table at z = 0.
        let (foot, top, height) = (0.049, 0.029, 0.105);
        let mut points = Vec::new();
        for i in 0..90 {
            let a = i as f64 / 90.0 * std::f64::consts::TAU;
            for j in 0..=30 {
                let f = j as f64 / 30.0;
                let r = foot + (top - foot) * f;
                points.push(Point3::new(0.6 + r * a.cos(), r * a.sin(), height * f));
                let r_top = top * f;
                points.push(Point3::new(0.6 + r_top * a.cos(), r_top * a.sin(), height));
            }
        }
        let cloud = PointCloud::from_points(
            points
                .iter()
                .map(|p| Point3::new(p.x as f32, p.y as f32, p.z as f32))
                .collect(),
        );
        let robot = shipped_robot();
        let hand = crate::quality::autograsp::tests::hand_of(&robot);
        let seen = SeenSurface::new(&hand, &cloud, SeenSurfaceOptions::default()).unwrap();
        let solid = seen.solid(0.0, 0.004);
        let object = crate::quality::autograsp::GraspObject::new(&solid, Path::new("solid"))
            .expect("a closed, outward mesh");
        // Its volume is the frustum's, grown by at most a square on every side.
        let frustum = std::f64::consts::PI * height / 3.0 * (foot * foot + foot * top + top * top);
        let volume = crate::mesh::topology::signed_volume(&solid);
        assert!(
            volume > frustum && volume < 1.6 * frustum,
            "{volume} against {frustum}"
        );
        assert!(
            object.centroid.z > 0.02 && object.centroid.z < 0.05,
            "{:?}",
            object.centroid
        );
        let lowest = solid.vertices.iter().map(|v| v.z).fold(f64::MAX, f64::min);
        let highest = solid.vertices.iter().map(|v| v.z).fold(f64::MIN, f64::max);
        assert_eq!(lowest, 0.0);
        assert!((highest - height).abs() < 1e-6, "{highest}");
        // Between the top's and the foot's radius the solid is as low as the slope
        // (a cylinder around the top would stand 105 mm there).
        let on_slope = solid
            .vertices
            .iter()
            .filter(|v| v.z > 0.0 && ((v.x - 0.6).hypot(v.y) - 0.044).abs() < 0.0015)
            .map(|v| v.z)
            .fold(0.0, f64::max);
        assert!(on_slope > 0.01 && on_slope < 0.08, "{on_slope}");
    }

    #[test]
    fn when_contact_stops_the_approach_only_its_start_must_be_clear() {
        let robot = shipped_robot();
        let hand = crate::quality::autograsp::tests::hand_of(&robot);
        let stopping = SeenSurfaceOptions {
            contact_stops_approach: true,
            ..SeenSurfaceOptions::default()
        };
        let seen = SeenSurface::new(&hand, &cylinder_cloud(), stopping).unwrap();
        let approaching_x =
            |x: f64| pose_from_params(&[x, 0.0, 0.05, 0.0, std::f64::consts::FRAC_PI_2, 0.0]);
        // Planned 2 cm into the cylinder: the palm will stop at its surface.
        assert_eq!(seen.intrusion(&approaching_x(0.58), &HandPose::OPEN), None);
        // Planned so deep that the pre-grasp, 10 cm back, starts inside it.
        let hit = seen
            .intrusion(&approaching_x(0.7), &HandPose::OPEN)
            .expect("the approach starts inside the cylinder");
        assert!((hit.behind_grasp_m - 0.1).abs() < 1e-9, "{hit:?}");
    }
}
