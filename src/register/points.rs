//! Point-set helpers shared by the stages: size, centroid and spread subsamples.

use nalgebra::{Point3, Vector3};

/// The diagonal of the axis-aligned bounding box of `points` (m; 0 for none).
pub(super) fn bbox_diagonal(points: &[Point3<f32>]) -> f64 {
    let Some(first) = points.first() else {
        return 0.0;
    };
    let (mut lo, mut hi) = (first.coords, first.coords);
    for p in points {
        lo = lo.inf(&p.coords);
        hi = hi.sup(&p.coords);
    }
    (hi - lo).norm() as f64
}

/// The mean of `points`, summed in f64 (the origin for none).
pub(super) fn centroid(points: &[Point3<f32>]) -> Point3<f32> {
    let sum = points
        .iter()
        .fold(Vector3::<f64>::zeros(), |s, p| s + p.coords.cast::<f64>());
    Point3::from((sum / points.len().max(1) as f64).cast::<f32>())
}

/// Indices of every `len / n`-th item (all when there are fewer than `n`).
pub(super) fn subsample_indices(len: usize, n: usize) -> Vec<usize> {
    if len <= n {
        return (0..len).collect();
    }
    (0..n).map(|k| k * len / n).collect()
}

/// Every `len / n`-th point (all when there are fewer than `n`).
pub(super) fn subsample(points: &[Point3<f32>], n: usize) -> Vec<Point3<f32>> {
    subsample_indices(points.len(), n)
        .into_iter()
        .map(|i| points[i])
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn size_and_centre_of_a_few_points() {
        let points = [
            Point3::new(0.0, 0.0, 0.0),
            Point3::new(0.3, 0.0, 0.0),
            Point3::new(0.0, 0.4, 0.0),
            Point3::new(0.3, 0.4, 0.0),
        ];
        assert!((bbox_diagonal(&points) - 0.5).abs() < 1e-6);
        assert!((centroid(&points) - Point3::new(0.15, 0.2, 0.0)).norm() < 1e-6);
        assert_eq!(bbox_diagonal(&[]), 0.0);
        assert_eq!(centroid(&[]), Point3::origin());
    }

    #[test]
    fn subsamples_are_spread_and_never_larger_than_asked() {
        assert_eq!(subsample_indices(10, 5), [0, 2, 4, 6, 8]);
        assert_eq!(subsample_indices(3, 5), [0, 1, 2]);
        assert_eq!(subsample_indices(7, 3), [0, 2, 4]);
        let points: Vec<Point3<f32>> = (0..9).map(|i| Point3::new(i as f32, 0.0, 0.0)).collect();
        let picked = subsample(&points, 3);
        assert_eq!(
            picked.iter().map(|p| p.x).collect::<Vec<_>>(),
            [0.0, 3.0, 6.0]
        );
    }
}
