//! The target of one simulated experiment: the test object at a seeded random
//! placement on the table, seen either completely (points sampled from its whole
//! surface) or as the sim camera's single partial view, segmented from the table.

use super::EvalError;
use crate::cloud::PointCloud;
use crate::geometry::Pose;
use crate::mesh::TriMesh;
use crate::sim::camera::{DepthCamera, Return, Surface};
use crate::sim::scene::{Scene, TableBox};
use nalgebra::{Isometry3, Point3, Translation3, UnitQuaternion};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

/// How the target object is seen.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ViewKind {
    /// Points sampled uniformly over the whole mesh (the paper's complete clouds).
    Complete,
    /// One depth frame of the sim camera (Kinect error model), the object's points
    /// only.
    Partial,
}

impl ViewKind {
    /// `complete` or `partial`.
    pub fn name(self) -> &'static str {
        match self {
            ViewKind::Complete => "complete",
            ViewKind::Partial => "partial",
        }
    }
}

/// Where on the table test objects are placed: a box of positions and any yaw.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct PlacementRegion {
    /// Centre of the region on the table, x y (m, base frame).
    pub center_xy_m: [f64; 2],
    /// Half extents of the region along x and y (m).
    pub half_extent_xy_m: [f64; 2],
    /// Height of the table top (m, base frame).
    pub table_height_m: f64,
}

impl PlacementRegion {
    /// A 0.2 m x 0.3 m region around `center_xy_m`, in front of the robot and well
    /// inside the camera's view, on a table at `table_height_m`.
    pub fn around(center_xy_m: [f64; 2], table_height_m: f64) -> PlacementRegion {
        PlacementRegion {
            center_xy_m,
            half_extent_xy_m: [0.10, 0.15],
            table_height_m,
        }
    }

    /// A seeded random placement of `mesh`: uniform in the region, uniform yaw in
    /// [-pi, pi), the mesh's lowest vertex on the table top.
    pub fn place(&self, mesh: &TriMesh, seed: u64) -> Pose {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let [cx, cy] = self.center_xy_m;
        let [hx, hy] = self.half_extent_xy_m;
        let x = cx + rng.gen_range(-1.0..=1.0) * hx;
        let y = cy + rng.gen_range(-1.0..=1.0) * hy;
        let yaw = rng.gen_range(-std::f64::consts::PI..std::f64::consts::PI);
        let min_z = mesh
            .vertices
            .iter()
            .map(|v| v.z)
            .fold(f64::INFINITY, f64::min);
        Isometry3::from_parts(
            Translation3::new(x, y, self.table_height_m - min_z),
            UnitQuaternion::from_euler_angles(0.0, 0.0, yaw),
        )
    }
}

/// `cloud` with every point moved by `target_from_source` (normals rotated).
pub fn transform_cloud(cloud: &PointCloud, target_from_source: &Pose) -> PointCloud {
    let iso: Isometry3<f32> = nalgebra::convert(*target_from_source);
    PointCloud {
        points: cloud.points.iter().map(|p| iso * p).collect(),
        normals: cloud
            .normals
            .as_ref()
            .map(|n| n.iter().map(|v| iso.rotation * v).collect()),
        width: cloud.width,
        height: cloud.height,
    }
}

/// The complete view: `points` sampled (seeded) over the mesh, in the base frame.
pub fn complete_view(
    name: &str,
    mesh: &TriMesh,
    base_from_object: &Pose,
    points: usize,
    seed: u64,
) -> Result<PointCloud, EvalError> {
    let cloud =
        crate::cloud::sample::sample_surface(mesh, points, seed).map_err(|e| EvalError::View {
            target: name.to_string(),
            problem: e.to_string(),
        })?;
    Ok(transform_cloud(&cloud, base_from_object))
}

/// Fewest object points a partial view must have to be registered.
pub const MIN_VIEW_POINTS: usize = 50;

/// The partial view: the object at `base_from_object` on `table`, rendered by
/// `camera` with noise from `seed`; the object's valid returns (the renderer's
/// per-pixel labels: a perfect segmentation), in the base frame, unorganised.
pub fn partial_view(
    name: &str,
    mesh: &TriMesh,
    base_from_object: &Pose,
    camera: &DepthCamera,
    table: TableBox,
    seed: u64,
) -> Result<PointCloud, EvalError> {
    let mut scene = Scene::new(Some(table));
    scene
        .add(name, mesh.clone(), *base_from_object)
        .map_err(|e| EvalError::View {
            target: name.to_string(),
            problem: e.to_string(),
        })?;
    let frame = camera.render(&scene, seed);
    let camera_cloud = frame.to_cloud();
    let points: Vec<Point3<f32>> = camera_cloud
        .points
        .iter()
        .zip(frame.status.iter().zip(&frame.surface))
        .filter(|(_, (r, s))| **r == Return::Valid && **s == Surface::Object(0))
        .map(|(p, _)| *p)
        .collect();
    if points.len() < MIN_VIEW_POINTS {
        return Err(EvalError::View {
            target: name.to_string(),
            problem: format!(
                "the camera sees only {} points of the object (at least {MIN_VIEW_POINTS} needed)",
                points.len()
            ),
        });
    }
    Ok(transform_cloud(
        &PointCloud::from_points(points),
        &camera.base_from_camera,
    ))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mesh::procedural::{generate, Category};

    #[test]
    fn placement_is_seeded_on_the_table_and_inside_the_region() {
        let (mesh, _) = generate(Category::Mug, 3);
        let region = PlacementRegion::around([0.6, 0.0], 0.1);
        let a = region.place(&mesh, 7);
        assert_eq!(a, region.place(&mesh, 7));
        assert_ne!(a, region.place(&mesh, 8));
        for seed in 0..20 {
            let p = region.place(&mesh, seed);
            let t = p.translation.vector;
            assert!((t.x - 0.6).abs() <= 0.1 + 1e-12 && t.y.abs() <= 0.15 + 1e-12);
            let lowest = mesh
                .vertices
                .iter()
                .map(|v| (p * v).z)
                .fold(f64::INFINITY, f64::min);
            assert!((lowest - 0.1).abs() < 1e-9, "lowest point at {lowest}");
        }
    }

    #[test]
    fn complete_view_lies_on_the_placed_mesh() {
        let (mesh, _) = generate(Category::Bottle, 1);
        let pose = PlacementRegion::around([0.6, 0.0], 0.0).place(&mesh, 2);
        let cloud = complete_view("bottle", &mesh, &pose, 300, 1).unwrap();
        assert_eq!(cloud.len(), 300);
        let placed = mesh.transformed(&pose);
        let (lo, hi) = placed.vertices.iter().fold(
            ([f64::INFINITY; 3], [f64::NEG_INFINITY; 3]),
            |(lo, hi), v| {
                (
                    [lo[0].min(v.x), lo[1].min(v.y), lo[2].min(v.z)],
                    [hi[0].max(v.x), hi[1].max(v.y), hi[2].max(v.z)],
                )
            },
        );
        for p in &cloud.points {
            for k in 0..3 {
                assert!(p[k] as f64 >= lo[k] - 1e-4 && p[k] as f64 <= hi[k] + 1e-4);
            }
        }
    }
}
