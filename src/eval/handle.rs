//! Whether a mug's handle is in a view, so that the yaw error of a registration
//! (where the model's handle ends up) is reported for the fits where it can be
//! judged.
//!
//! The procedural mugs share a canonical frame: base centre at the origin, z up,
//! the handle on the +x side. The body's radius is the largest distance from the
//! axis on the side away from the handle; the handle is what lies more than
//! [`HANDLE_MARGIN_M`] beyond it on the handle's side.

use crate::cloud::PointCloud;
use crate::geometry::Pose;
use crate::mesh::TriMesh;
use nalgebra::Point3;

/// How far beyond the body's radius a point must lie to be on the handle (m).
pub const HANDLE_MARGIN_M: f64 = 0.004;

/// Fewest view points on the handle for it to count as visible.
pub const MIN_HANDLE_POINTS: usize = 15;

/// A mug's handle region in its own frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct HandleRegion {
    /// The body's largest radius (m).
    pub body_radius_m: f64,
}

impl HandleRegion {
    /// The handle region of `mesh` (canonical mug frame); `None` when no vertex
    /// lies on a handle (a mug without one, or another shape).
    pub fn of(mesh: &TriMesh) -> Option<HandleRegion> {
        let radial = |v: &Point3<f64>| v.x.hypot(v.y);
        let body_radius_m = mesh
            .vertices
            .iter()
            .filter(|v| v.x <= 0.0)
            .map(radial)
            .fold(0.0, f64::max);
        let region = HandleRegion { body_radius_m };
        mesh.vertices
            .iter()
            .any(|v| region.contains(v))
            .then_some(region)
    }

    /// Whether `p` (object frame) lies on the handle.
    pub fn contains(&self, p: &Point3<f64>) -> bool {
        p.x > 0.0 && p.x.hypot(p.y) > self.body_radius_m + HANDLE_MARGIN_M
    }

    /// View points (base frame) on the handle of the object at `base_from_object`.
    pub fn points_in(&self, view_base: &PointCloud, base_from_object: &Pose) -> usize {
        let object_from_base = base_from_object.inverse();
        view_base
            .points
            .iter()
            .filter(|p| self.contains(&(object_from_base * p.cast::<f64>())))
            .count()
    }
}

/// Whether the handle of `mesh`, placed at `base_from_object`, is visible in
/// `view_base`: it has one, and at least [`MIN_HANDLE_POINTS`] view points lie on it.
pub fn handle_visible(mesh: &TriMesh, base_from_object: &Pose, view_base: &PointCloud) -> bool {
    HandleRegion::of(mesh)
        .is_some_and(|h| h.points_in(view_base, base_from_object) >= MIN_HANDLE_POINTS)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mesh::procedural::{generate, Category, Params};

    fn mug(with_handle: bool) -> TriMesh {
        (0..)
            .map(|s| generate(Category::Mug, s))
            .find(|(_, p)| matches!(p, Params::Mug(m) if m.handle.is_some() == with_handle))
            .unwrap()
            .0
    }

    #[test]
    fn a_handle_is_found_only_on_a_mug_that_has_one() {
        let with = HandleRegion::of(&mug(true)).unwrap();
        assert!(
            with.body_radius_m > 0.03 && with.body_radius_m < 0.06,
            "{with:?}"
        );
        assert!(HandleRegion::of(&mug(false)).is_none());
    }

    #[test]
    fn the_handle_is_visible_from_its_side_and_hidden_from_the_other() {
        let mesh = mug(true);
        let cloud = crate::cloud::sample::sample_surface(&mesh, 4000, 1).unwrap();
        // What a sensor far along +x or -x sees, roughly: the points facing it.
        let facing = |sign: f32| {
            PointCloud::from_points(
                cloud
                    .points
                    .iter()
                    .zip(cloud.normals.as_ref().unwrap())
                    .filter(|(p, n)| n.x * sign > 0.3 && p.x * sign > 0.0)
                    .map(|(p, _)| *p)
                    .collect(),
            )
        };
        let pose = Pose::translation(0.6, 0.1, 0.0);
        let moved = |c: PointCloud| crate::eval::view::transform_cloud(&c, &pose);
        assert!(handle_visible(&mesh, &pose, &moved(facing(1.0))));
        assert!(!handle_visible(&mesh, &pose, &moved(facing(-1.0))));
        assert!(!handle_visible(&mug(false), &pose, &moved(facing(1.0))));
    }
}
