//! Topology and size checks of triangle meshes: watertightness, signed volume,
//! bounding box.

use super::TriMesh;
use nalgebra::Point3;
use std::collections::HashMap;

/// How a mesh's edges are shared; a closed, consistently oriented 2-manifold has
/// every count zero.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct EdgeReport {
    /// Number of distinct undirected edges.
    pub edges: usize,
    /// Edges used by exactly one triangle (holes).
    pub boundary_edges: usize,
    /// Edges used by more than two triangles.
    pub non_manifold_edges: usize,
    /// Edges used by two triangles in the same direction (flipped neighbour).
    pub misoriented_edges: usize,
    /// Triangles that repeat a vertex index.
    pub degenerate_triangles: usize,
}

impl EdgeReport {
    /// True when every edge is shared by exactly two triangles in opposite
    /// directions and no triangle is degenerate.
    pub fn is_watertight(&self) -> bool {
        self.boundary_edges == 0
            && self.non_manifold_edges == 0
            && self.misoriented_edges == 0
            && self.degenerate_triangles == 0
    }
}

/// Counts how the triangles of `mesh` share their edges.
pub fn edge_report(mesh: &TriMesh) -> EdgeReport {
    // Per undirected edge (low, high): uses in the low->high and high->low directions.
    let mut uses: HashMap<(u32, u32), (u32, u32)> =
        HashMap::with_capacity(mesh.triangles.len() * 2);
    let mut report = EdgeReport::default();
    for t in &mesh.triangles {
        if t[0] == t[1] || t[1] == t[2] || t[2] == t[0] {
            report.degenerate_triangles += 1;
            continue;
        }
        for k in 0..3 {
            let (a, b) = (t[k], t[(k + 1) % 3]);
            let entry = uses.entry((a.min(b), a.max(b))).or_insert((0, 0));
            if a < b {
                entry.0 += 1;
            } else {
                entry.1 += 1;
            }
        }
    }
    report.edges = uses.len();
    for &(forward, backward) in uses.values() {
        match forward + backward {
            1 => report.boundary_edges += 1,
            2 if forward != 1 => report.misoriented_edges += 1,
            2 => {}
            _ => report.non_manifold_edges += 1,
        }
    }
    report
}

/// True when every edge is shared by exactly two triangles with opposite
/// orientation (a closed, consistently oriented surface).
pub fn is_watertight(mesh: &TriMesh) -> bool {
    edge_report(mesh).is_watertight()
}

/// Euler characteristic V - E + F over the vertices that triangles use
/// (2 for a closed sphere-like surface, 0 for one with a single handle).
pub fn euler_characteristic(mesh: &TriMesh) -> i64 {
    let mut used = vec![false; mesh.vertices.len()];
    for t in &mesh.triangles {
        for &i in t {
            if let Some(u) = used.get_mut(i as usize) {
                *u = true;
            }
        }
    }
    let v = used.iter().filter(|&&u| u).count() as i64;
    v - edge_report(mesh).edges as i64 + mesh.triangles.len() as i64
}

/// Signed volume (m^3) enclosed by the triangles (divergence theorem); positive
/// when a closed mesh's normals point outward.
pub fn signed_volume(mesh: &TriMesh) -> f64 {
    (0..mesh.triangles.len())
        .map(|i| {
            let [a, b, c] = mesh.corners(i);
            a.coords.dot(&b.coords.cross(&c.coords))
        })
        .sum::<f64>()
        / 6.0
}

/// Total area (m^2) of the triangles.
pub fn surface_area(mesh: &TriMesh) -> f64 {
    (0..mesh.triangles.len())
        .map(|i| {
            let [a, b, c] = mesh.corners(i);
            0.5 * (b - a).cross(&(c - a)).norm()
        })
        .sum()
}

/// Lower and upper corners of the axis-aligned box around the vertices that
/// triangles use; `None` for a mesh without triangles.
pub fn bounding_box(mesh: &TriMesh) -> Option<(Point3<f64>, Point3<f64>)> {
    let mut corners: Option<(Point3<f64>, Point3<f64>)> = None;
    for t in &mesh.triangles {
        for &i in t {
            let p = mesh.vertices[i as usize];
            corners = Some(match corners {
                None => (p, p),
                Some((lo, hi)) => (lo.inf(&p), hi.sup(&p)),
            });
        }
    }
    corners
}

/// Whether the mesh is a solid of revolution about its frame's z axis, within
/// `tolerance_m`: in every 5 mm slab of height holding vertices, the outermost vertex
/// of each of twelve 30 deg sectors lies at the same distance from the axis. A
/// bottle is; a mug with a handle, or a tool lying flat, is not (its rotation about
/// the axis matters).
pub fn is_axisymmetric(mesh: &TriMesh, tolerance_m: f64) -> bool {
    points_axisymmetric(mesh.vertices.iter().copied(), tolerance_m)
}

/// [`is_axisymmetric`] for points (a mesh's vertices, or a cloud sampled densely on
/// its surface).
pub fn points_axisymmetric(
    points: impl IntoIterator<Item = Point3<f64>>,
    tolerance_m: f64,
) -> bool {
    const SLAB_M: f64 = 0.005;
    const SECTORS: usize = 12;
    let mut slabs: std::collections::BTreeMap<i64, [f64; SECTORS]> = Default::default();
    for p in points {
        if !(p.x.is_finite() && p.y.is_finite() && p.z.is_finite()) {
            return false;
        }
        let r = p.x.hypot(p.y);
        let angle = p.y.atan2(p.x).rem_euclid(std::f64::consts::TAU);
        let sector = ((angle / std::f64::consts::TAU * SECTORS as f64) as usize).min(SECTORS - 1);
        let slab = slabs
            .entry((p.z / SLAB_M).floor() as i64)
            .or_insert([f64::NEG_INFINITY; SECTORS]);
        slab[sector] = slab[sector].max(r);
    }
    !slabs.is_empty()
        && slabs.values().all(|outer| {
            let lo = outer.iter().copied().fold(f64::INFINITY, f64::min);
            let hi = outer.iter().copied().fold(f64::NEG_INFINITY, f64::max);
            // An empty sector (-inf) next to a filled one is asymmetric.
            hi - lo <= tolerance_m
        })
}

/// Number of pairs of triangles that share no vertex yet intersect: zero for a
/// surface that does not pass through itself. `None` for an invalid mesh.
pub fn self_intersections(mesh: &TriMesh) -> Option<usize> {
    use parry3d_f64::query::intersection_test;
    use parry3d_f64::shape::Triangle;
    let shape = mesh.to_parry(std::path::Path::new("mesh")).ok()?;
    let identity = nalgebra::Isometry3::identity();
    let count = (0..mesh.triangles.len())
        .map(|i| {
            let [a, b, c] = mesh.corners(i);
            let tri = Triangle::new(a, b, c);
            let ti = mesh.triangles[i];
            shape
                .bvh()
                .intersect_aabb(&tri.local_aabb())
                .filter(|&j| j as usize > i)
                .filter(|&j| {
                    let tj = mesh.triangles[j as usize];
                    !tj.iter().any(|v| ti.contains(v))
                })
                .filter(|&j| {
                    let [d, e, f] = mesh.corners(j as usize);
                    intersection_test(&identity, &tri, &identity, &Triangle::new(d, e, f))
                        .unwrap_or(false)
                })
                .count()
        })
        .sum();
    Some(count)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_cylinder_is_axisymmetric_and_a_box_or_a_mug_is_not() {
        use crate::quality::autograsp::tests::{cuboid, cylinder};
        assert!(is_axisymmetric(&cylinder(0.04, 0.2, 32), 0.002));
        // Square: the corners lie 12 mm farther out than the faces' middles.
        assert!(!is_axisymmetric(
            &cuboid([0.0, 0.0, 0.05], [0.06, 0.06, 0.1]),
            0.002
        ));
        // A body with a handle on one side.
        let mut mug = cylinder(0.04, 0.1, 32);
        let handle = cuboid([0.05, 0.0, 0.0], [0.02, 0.01, 0.05]);
        let base = mug.vertices.len() as u32;
        mug.vertices.extend(handle.vertices);
        mug.triangles
            .extend(handle.triangles.iter().map(|t| t.map(|i| i + base)));
        assert!(!is_axisymmetric(&mug, 0.002));
        assert!(!is_axisymmetric(
            &TriMesh {
                vertices: vec![],
                triangles: vec![]
            },
            0.002
        ));
    }

    /// A unit-edge tetrahedron with outward winding, built by hand.
    fn tetrahedron() -> TriMesh {
        TriMesh {
            vertices: vec![
                Point3::new(0.0, 0.0, 0.0),
                Point3::new(1.0, 0.0, 0.0),
                Point3::new(0.0, 1.0, 0.0),
                Point3::new(0.0, 0.0, 1.0),
            ],
            triangles: vec![[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]],
        }
    }

    #[test]
    fn tetrahedron_is_closed_outward_with_known_volume() {
        let mesh = tetrahedron();
        assert!(is_watertight(&mesh), "{:?}", edge_report(&mesh));
        assert!((signed_volume(&mesh) - 1.0 / 6.0).abs() < 1e-15);
        assert_eq!(euler_characteristic(&mesh), 2);
        let area = 1.5 + 3f64.sqrt() / 2.0;
        assert!((surface_area(&mesh) - area).abs() < 1e-12);
        let (lo, hi) = bounding_box(&mesh).unwrap();
        assert_eq!((lo, hi), (Point3::origin(), Point3::new(1.0, 1.0, 1.0)));
    }

    #[test]
    fn crossing_triangles_are_found() {
        let mut mesh = tetrahedron();
        assert_eq!(self_intersections(&mesh), Some(0));
        // A separate triangle piercing the tetrahedron's x = 0 face.
        let base = mesh.vertices.len() as u32;
        mesh.vertices.extend([
            Point3::new(-0.5, 0.2, 0.2),
            Point3::new(0.5, 0.2, 0.2),
            Point3::new(0.5, 0.25, 0.15),
        ]);
        mesh.triangles.push([base, base + 1, base + 2]);
        assert_eq!(self_intersections(&mesh), Some(1));
    }

    #[test]
    fn defects_are_counted() {
        let mut flipped = tetrahedron();
        flipped.triangles[3] = [1, 3, 2];
        let r = edge_report(&flipped);
        assert_eq!(r.misoriented_edges, 3, "{r:?}");
        assert!(!r.is_watertight());

        let mut open = tetrahedron();
        open.triangles.pop();
        let r = edge_report(&open);
        assert_eq!(r.boundary_edges, 3, "{r:?}");

        let mut extra = tetrahedron();
        extra.vertices.push(Point3::new(1.0, 1.0, 1.0));
        extra.triangles.push([1, 2, 4]);
        assert_eq!(edge_report(&extra).non_manifold_edges, 1);

        let mut degenerate = tetrahedron();
        degenerate.triangles.push([0, 0, 1]);
        assert_eq!(edge_report(&degenerate).degenerate_triangles, 1);

        let inward = TriMesh {
            triangles: tetrahedron()
                .triangles
                .iter()
                .map(|&[a, b, c]| [a, c, b])
                .collect(),
            ..tetrahedron()
        };
        assert!(is_watertight(&inward));
        assert!(signed_volume(&inward) < 0.0);
        assert!(bounding_box(&TriMesh::default()).is_none());
    }
}
