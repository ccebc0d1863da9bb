//! Surface normals by principal component analysis of each point's neighbourhood:
//! the eigenvector of the smallest eigenvalue of the neighbours' covariance, oriented
//! towards a viewpoint (the sensor) or away from a centre (a closed model).

use super::kdtree::KdIndex;
use nalgebra::{Matrix3, Point3, SymmetricEigen, Vector3};
use rayon::prelude::*;

/// How estimated normals are oriented.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Orientation {
    /// Towards this point (the sensor origin for a camera's view).
    TowardsViewpoint(Point3<f32>),
    /// Away from this point (e.g. a model's centroid).
    AwayFrom(Point3<f32>),
}

/// The unit normal of `neighbours` (indices into `points`) by PCA, unoriented;
/// `None` for fewer than three points or a degenerate neighbourhood.
pub fn pca_normal(points: &[Point3<f32>], neighbours: &[usize]) -> Option<Vector3<f32>> {
    if neighbours.len() < 3 {
        return None;
    }
    let mean = neighbours.iter().fold(Vector3::<f64>::zeros(), |s, &i| {
        s + points[i].coords.cast::<f64>()
    }) / neighbours.len() as f64;
    let mut cov = Matrix3::<f64>::zeros();
    for &i in neighbours {
        let d = points[i].coords.cast::<f64>() - mean;
        cov += d * d.transpose();
    }
    let eigen = SymmetricEigen::new(cov);
    let (k, _) = eigen.eigenvalues.argmin();
    let n = eigen.eigenvectors.column(k).into_owned();
    n.try_normalize(1e-12).map(|n| n.cast::<f32>())
}

/// Normals of `points` from their `k` nearest neighbours within `radius_m`
/// (indexed by `index`, built over `points`), oriented as asked. A point with too
/// few neighbours gets the direction to the viewpoint (or away from the centre).
pub fn estimate_normals(
    points: &[Point3<f32>],
    index: &KdIndex,
    k: usize,
    radius_m: f32,
    orientation: Orientation,
) -> Vec<Vector3<f32>> {
    points
        .par_iter()
        .map(|p| {
            let toward = match orientation {
                Orientation::TowardsViewpoint(v) => v - p,
                Orientation::AwayFrom(c) => p - c,
            };
            let neighbours: Vec<usize> = index
                .knn(p, k)
                .into_iter()
                .filter(|&(_, d2)| d2 <= radius_m * radius_m)
                .map(|(i, _)| i)
                .collect();
            match pca_normal(points, &neighbours) {
                Some(n) if n.dot(&toward) < 0.0 => -n,
                Some(n) => n,
                None => toward.try_normalize(1e-9).unwrap_or_else(Vector3::z),
            }
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn plane_normals_point_to_the_viewpoint() {
        let points: Vec<Point3<f32>> = (0..100)
            .map(|i| Point3::new((i % 10) as f32 * 0.01, (i / 10) as f32 * 0.01, 0.0))
            .collect();
        let index = KdIndex::new(&points);
        let up = estimate_normals(
            &points,
            &index,
            8,
            0.05,
            Orientation::TowardsViewpoint(Point3::new(0.0, 0.0, 1.0)),
        );
        assert!(up.iter().all(|n| (n - Vector3::z()).norm() < 1e-5));
        let down = estimate_normals(
            &points,
            &index,
            8,
            0.05,
            Orientation::TowardsViewpoint(Point3::new(0.0, 0.0, -1.0)),
        );
        assert!(down.iter().all(|n| (n + Vector3::z()).norm() < 1e-5));
    }

    #[test]
    fn sphere_normals_point_outward() {
        // A Fibonacci sphere of radius 0.1 m about (1, 0, 0).
        let c = Point3::new(1.0f32, 0.0, 0.0);
        let n = 800;
        let points: Vec<Point3<f32>> = (0..n)
            .map(|i| {
                let z = 1.0 - 2.0 * (i as f32 + 0.5) / n as f32;
                let r = (1.0 - z * z).sqrt();
                let a = i as f32 * 2.399_963;
                c + Vector3::new(r * a.cos(), r * a.sin(), z) * 0.1
            })
            .collect();
        let index = KdIndex::new(&points);
        let normals = estimate_normals(&points, &index, 10, 0.05, Orientation::AwayFrom(c));
        for (p, n) in points.iter().zip(&normals) {
            let radial = (p - c).normalize();
            assert!(n.dot(&radial) > 0.98, "{p} {n}");
        }
    }
}
