//! Point clouds: the camera's snapshot and the models' sampled surfaces.

pub mod io;
pub mod kdtree;
pub mod normals;
pub mod pcd;
pub mod ply;
pub mod sample;
pub mod segment;
pub mod voxel;

use nalgebra::{Point3, Vector3};

/// A point cloud in one frame (metres), organised (an image's grid, row-major,
/// `width` x `height`) or not (`height == 1`). A missing return of an organised
/// cloud is a point with NaN coordinates, as PCL and Open3D do.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct PointCloud {
    /// Positions (m); NaN marks a missing point.
    pub points: Vec<Point3<f32>>,
    /// Unit normals, one per point, when known.
    pub normals: Option<Vec<Vector3<f32>>>,
    /// Columns of an organised cloud, or the number of points.
    pub width: u32,
    /// Rows of an organised cloud, or 1.
    pub height: u32,
}

impl PointCloud {
    /// An unorganised cloud of `points`.
    pub fn from_points(points: Vec<Point3<f32>>) -> PointCloud {
        PointCloud {
            width: points.len() as u32,
            height: 1,
            points,
            normals: None,
        }
    }

    /// Number of points, missing ones included.
    pub fn len(&self) -> usize {
        self.points.len()
    }

    /// True when the cloud holds no points.
    pub fn is_empty(&self) -> bool {
        self.points.is_empty()
    }

    /// True for an image-shaped cloud (more than one row).
    pub fn is_organised(&self) -> bool {
        self.height > 1
    }

    /// The points that are present (finite), in order.
    pub fn valid_points(&self) -> impl Iterator<Item = &Point3<f32>> + '_ {
        self.points
            .iter()
            .filter(|p| p.x.is_finite() && p.y.is_finite() && p.z.is_finite())
    }
}
