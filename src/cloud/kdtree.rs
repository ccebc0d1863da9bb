//! Nearest-neighbour search over 3-D points: a thin wrapper of kiddo's immutable
//! k-d tree that keeps kiddo's API in one place and handles the empty cloud.

use kiddo::immutable::float::kdtree::ImmutableKdTree;
use kiddo::SquaredEuclidean;
use nalgebra::Point3;
use std::num::NonZero;

type Tree = ImmutableKdTree<f32, u32, 3, 32>;

/// A k-d tree over a fixed set of points; items are indices into that set.
pub struct KdIndex {
    tree: Option<Tree>,
    len: usize,
}

impl std::fmt::Debug for KdIndex {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("KdIndex").field("len", &self.len).finish()
    }
}

impl KdIndex {
    /// Builds the tree over `points` (all finite).
    pub fn new(points: &[Point3<f32>]) -> KdIndex {
        let coords: Vec<[f32; 3]> = points.iter().map(|p| [p.x, p.y, p.z]).collect();
        KdIndex {
            tree: (!coords.is_empty()).then(|| Tree::new_from_slice(&coords)),
            len: coords.len(),
        }
    }

    /// Number of indexed points.
    pub fn len(&self) -> usize {
        self.len
    }

    /// True when no point is indexed.
    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// The nearest point to `q`: its index and squared distance (m^2).
    pub fn nearest(&self, q: &Point3<f32>) -> Option<(usize, f32)> {
        let nn = self
            .tree
            .as_ref()?
            .nearest_one::<SquaredEuclidean>(&[q.x, q.y, q.z]);
        Some((nn.item as usize, nn.distance))
    }

    /// The `k` nearest points to `q`, nearest first: index and squared distance.
    pub fn knn(&self, q: &Point3<f32>, k: usize) -> Vec<(usize, f32)> {
        match (self.tree.as_ref(), NonZero::new(k)) {
            (Some(tree), Some(k)) => tree
                .nearest_n::<SquaredEuclidean>(&[q.x, q.y, q.z], k)
                .into_iter()
                .map(|nn| (nn.item as usize, nn.distance))
                .collect(),
            _ => Vec::new(),
        }
    }

    /// Indices of the points within `radius_m` of `q`, in no particular order.
    pub fn within(&self, q: &Point3<f32>, radius_m: f32) -> Vec<usize> {
        match self.tree.as_ref() {
            Some(tree) => tree
                .within_unsorted::<SquaredEuclidean>(&[q.x, q.y, q.z], radius_m * radius_m)
                .into_iter()
                .map(|nn| nn.item as usize)
                .collect(),
            None => Vec::new(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn queries_match_brute_force() {
        // A deterministic scatter with repeated coordinates on each axis.
        let points: Vec<Point3<f32>> = (0..500)
            .map(|i| {
                let i = i as f32;
                Point3::new(
                    (i * 0.37) % 1.0,
                    ((i * 0.61) % 1.0).round() * 0.5,
                    (i * 0.13) % 0.7,
                )
            })
            .collect();
        let index = KdIndex::new(&points);
        let q = Point3::new(0.3, 0.2, 0.1);
        let mut brute: Vec<(usize, f32)> = points
            .iter()
            .enumerate()
            .map(|(i, p)| (i, (p - q).norm_squared()))
            .collect();
        brute.sort_by(|a, b| a.1.total_cmp(&b.1));
        assert!((index.nearest(&q).unwrap().1 - brute[0].1).abs() < 1e-7);
        let knn = index.knn(&q, 5);
        for (got, want) in knn.iter().zip(&brute) {
            assert!((got.1 - want.1).abs() < 1e-7);
        }
        let mut within = index.within(&q, 0.2);
        within.sort();
        let mut want: Vec<usize> = brute.iter().filter(|b| b.1 <= 0.04).map(|b| b.0).collect();
        want.sort();
        assert_eq!(within, want);
    }

    #[test]
    fn empty_index_answers_nothing() {
        let index = KdIndex::new(&[]);
        assert!(index.is_empty());
        assert!(index.nearest(&Point3::origin()).is_none());
        assert!(index.knn(&Point3::origin(), 3).is_empty());
        assert!(index.within(&Point3::origin(), 1.0).is_empty());
    }
}
