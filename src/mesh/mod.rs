//! Triangle meshes: the object models of each category.

use nalgebra::Point3;

/// An indexed triangle mesh in metres; triangles wind counter-clockwise seen from
/// outside, so normals point outward.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct TriMesh {
    /// Vertex positions (m).
    pub vertices: Vec<Point3<f64>>,
    /// Triangles as indices into `vertices`.
    pub triangles: Vec<[u32; 3]>,
}
