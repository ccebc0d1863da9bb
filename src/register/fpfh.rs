//! Fast Point Feature Histograms (Rusu, Blodow & Beetz 2009), as PCL computes them:
//! for each point, the simplified histogram (SPFH) of the Darboux-frame angles
//! (alpha, phi, theta; 11 bins each) to its neighbours within a radius, then
//! FPFH(p) = SPFH(p) + mean over neighbours k of SPFH(k) / |p - k|, each of the
//! three sub-histograms scaled to sum to 100.

use crate::cloud::kdtree::KdIndex;
use nalgebra::{DMatrix, Point3, Vector3};
use rayon::prelude::*;
use std::f32::consts::PI;

/// Bins per angle.
pub const BINS: usize = 11;
/// Length of a descriptor.
pub const FPFH_LEN: usize = 3 * BINS;

/// One descriptor.
pub type Fpfh = [f32; FPFH_LEN];

/// The pair features `(f1, f2, f3)` of PCL's `computePairFeatures`: `f1` in
/// [-pi, pi], `f2`, `f3` in [-1, 1]; `None` for coincident points or a degenerate frame.
pub fn pair_features(
    p1: &Point3<f32>,
    n1: &Vector3<f32>,
    p2: &Point3<f32>,
    n2: &Vector3<f32>,
) -> Option<(f32, f32, f32)> {
    let mut dp = p2 - p1;
    let f4 = dp.norm();
    if f4 <= 0.0 {
        return None;
    }
    let (mut n1c, mut n2c) = (*n1, *n2);
    let angle1 = n1c.dot(&dp) / f4;
    let angle2 = n2c.dot(&dp) / f4;
    let f3 = if angle1.abs().acos() > angle2.abs().acos() {
        std::mem::swap(&mut n1c, &mut n2c);
        dp = -dp;
        -angle2
    } else {
        angle1
    };
    let v = dp.cross(&n1c).try_normalize(1e-12)?;
    let w = n1c.cross(&v);
    let f2 = v.dot(&n2c);
    let f1 = w.dot(&n2c).atan2(n1c.dot(&n2c));
    Some((f1, f2, f3))
}

fn bin(value: f32, lo: f32, hi: f32) -> usize {
    (((value - lo) / (hi - lo) * BINS as f32).floor().max(0.0) as usize).min(BINS - 1)
}

/// FPFH descriptors of `points` with unit `normals`, neighbours within `radius_m`
/// (indexed by `index`, built over `points`). A point without neighbours gets
/// all-zero histograms.
pub fn compute_fpfh(
    points: &[Point3<f32>],
    normals: &[Vector3<f32>],
    index: &KdIndex,
    radius_m: f32,
) -> Vec<Fpfh> {
    let neighbours: Vec<Vec<usize>> = points
        .par_iter()
        .enumerate()
        .map(|(i, p)| {
            let mut n = index.within(p, radius_m);
            n.retain(|&j| j != i);
            n.sort_unstable();
            n
        })
        .collect();
    let spfh: Vec<Fpfh> = (0..points.len())
        .into_par_iter()
        .map(|i| {
            let mut h = [0f32; FPFH_LEN];
            let mut count = 0usize;
            for &j in &neighbours[i] {
                if let Some((f1, f2, f3)) =
                    pair_features(&points[i], &normals[i], &points[j], &normals[j])
                {
                    h[bin(f1, -PI, PI)] += 1.0;
                    h[BINS + bin(f2, -1.0, 1.0)] += 1.0;
                    h[2 * BINS + bin(f3, -1.0, 1.0)] += 1.0;
                    count += 1;
                }
            }
            if count > 0 {
                let scale = 100.0 / count as f32;
                h.iter_mut().for_each(|v| *v *= scale);
            }
            h
        })
        .collect();
    (0..points.len())
        .into_par_iter()
        .map(|i| {
            let mut h = spfh[i];
            let mut acc = [0f32; FPFH_LEN];
            let mut weight_sum = 0.0;
            for &j in &neighbours[i] {
                let d = (points[j] - points[i]).norm();
                if d <= 0.0 {
                    continue;
                }
                let w = 1.0 / d;
                for (a, s) in acc.iter_mut().zip(&spfh[j]) {
                    *a += w * s;
                }
                weight_sum += w;
            }
            if weight_sum > 0.0 {
                // Mean over neighbours of SPFH / distance, then each sub-histogram
                // rescaled to sum to 100 (PCL's weightPointSPFHSignature).
                for (v, a) in h.iter_mut().zip(&acc) {
                    *v += a / neighbours[i].len() as f32;
                }
            }
            for part in h.chunks_mut(BINS) {
                let sum: f32 = part.iter().sum();
                if sum > 0.0 {
                    part.iter_mut().for_each(|v| *v *= 100.0 / sum);
                }
            }
            h
        })
        .collect()
}

/// Nearest-neighbour search among descriptors (Euclidean), by a k-d tree.
pub struct FeatureIndex {
    tree: Option<kiddo::immutable::float::kdtree::ImmutableKdTree<f32, u32, FPFH_LEN, 32>>,
}

impl std::fmt::Debug for FeatureIndex {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("FeatureIndex").finish_non_exhaustive()
    }
}

impl FeatureIndex {
    /// Indexes `features`.
    pub fn new(features: &[Fpfh]) -> FeatureIndex {
        FeatureIndex {
            tree: (!features.is_empty()).then(|| {
                kiddo::immutable::float::kdtree::ImmutableKdTree::new_from_slice(features)
            }),
        }
    }

    /// Index of the descriptor nearest `f`.
    pub fn nearest(&self, f: &Fpfh) -> Option<usize> {
        let tree = self.tree.as_ref()?;
        Some(tree.nearest_one::<kiddo::SquaredEuclidean>(f).item as usize)
    }
}

/// Nearest neighbours between two descriptor sets in both directions (Euclidean):
/// `forward[i]` is the `b` index nearest `a[i]`, `backward[j]` the `a` index
/// nearest `b[j]`. Descriptors are 33-dimensional, where k-d trees degrade to a
/// slow brute force; this is the brute force as one matrix product
/// (`|a - b|² = |a|² + |b|² - 2 a·b`, the product by nalgebra's blocked, vectorised
/// `gemm`). Empty when either set is.
pub fn mutual_nearest(a: &[Fpfh], b: &[Fpfh]) -> (Vec<usize>, Vec<usize>) {
    if a.is_empty() || b.is_empty() {
        return (Vec::new(), Vec::new());
    }
    let am = DMatrix::<f32>::from_row_iterator(a.len(), FPFH_LEN, a.iter().flatten().copied());
    let bm = DMatrix::<f32>::from_iterator(FPFH_LEN, b.len(), b.iter().flatten().copied());
    let dot = &am * &bm;
    let norm = |f: &Fpfh| f.iter().map(|v| v * v).sum::<f32>();
    let na: Vec<f32> = a.iter().map(norm).collect();
    let mut forward = vec![(f32::INFINITY, 0usize); a.len()];
    let mut backward = Vec::with_capacity(b.len());
    for (j, column) in dot.column_iter().enumerate() {
        let nb = norm(&b[j]);
        let mut best = (f32::INFINITY, 0usize);
        for (i, (&g, &ni)) in column.iter().zip(&na).enumerate() {
            let d = ni + nb - 2.0 * g;
            if d < best.0 {
                best = (d, i);
            }
            if d < forward[i].0 {
                forward[i] = (d, j);
            }
        }
        backward.push(best.1);
    }
    (forward.into_iter().map(|(_, j)| j).collect(), backward)
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Rotation3, Translation3};

    /// A Fibonacci sphere with outward normals.
    fn sphere(n: usize, r: f32) -> (Vec<Point3<f32>>, Vec<Vector3<f32>>) {
        (0..n)
            .map(|i| {
                let z = 1.0 - 2.0 * (i as f32 + 0.5) / n as f32;
                let s = (1.0 - z * z).sqrt();
                let a = i as f32 * 2.399_963;
                let d = Vector3::new(s * a.cos(), s * a.sin(), z);
                (Point3::from(d * r), d)
            })
            .unzip()
    }

    #[test]
    fn descriptors_are_invariant_to_rigid_motion() {
        let (pts, _) = sphere(400, 0.05);
        // Squash it to an ellipsoid so descriptors vary from point to point.
        let pts: Vec<Point3<f32>> = pts
            .iter()
            .map(|p| Point3::new(p.x, p.y * 0.5, p.z))
            .collect();
        let index = KdIndex::new(&pts);
        let normals = crate::cloud::normals::estimate_normals(
            &pts,
            &index,
            10,
            0.03,
            crate::cloud::normals::Orientation::AwayFrom(Point3::origin()),
        );
        let a = compute_fpfh(&pts, &normals, &index, 0.02);
        let rot = Rotation3::from_euler_angles(0.3, -0.7, 1.1);
        let moved: Vec<Point3<f32>> = pts
            .iter()
            .map(|p| Translation3::new(0.5, -0.2, 0.1) * (rot * p))
            .collect();
        let moved_normals: Vec<Vector3<f32>> = normals.iter().map(|n| rot * n).collect();
        let b = compute_fpfh(&moved, &moved_normals, &KdIndex::new(&moved), 0.02);
        for (x, y) in a.iter().zip(&b) {
            let diff: f32 = x.iter().zip(y).map(|(u, v)| (u - v).abs()).sum();
            assert!(diff < 1.0, "descriptor moved by {diff}");
        }
        // Each sub-histogram sums to 100.
        for h in &a {
            for part in h.chunks(BINS) {
                assert!((part.iter().sum::<f32>() - 100.0).abs() < 1e-2);
            }
        }
        // Not all equal: the ellipsoid's poles and equator differ.
        let spread: f32 = a[0].iter().zip(&a[200]).map(|(u, v)| (u - v).abs()).sum();
        assert!(spread > 5.0, "{spread}");
    }

    #[test]
    fn mutual_nearest_agrees_with_the_tree() {
        let (pts, nrm) = sphere(300, 0.05);
        let pts: Vec<Point3<f32>> = pts
            .iter()
            .map(|p| Point3::new(p.x, p.y * 0.6, p.z * 0.8))
            .collect();
        let index = KdIndex::new(&pts);
        let a = compute_fpfh(&pts, &nrm, &index, 0.02);
        let b: Vec<Fpfh> = a[..200].iter().rev().copied().collect();
        let (forward, backward) = mutual_nearest(&a, &b);
        assert_eq!((forward.len(), backward.len()), (a.len(), b.len()));
        let dist = |x: &Fpfh, y: &Fpfh| x.iter().zip(y).map(|(u, v)| (u - v).powi(2)).sum::<f32>();
        let tb = FeatureIndex::new(&b);
        for (i, &j) in forward.iter().enumerate() {
            let k = tb.nearest(&a[i]).unwrap();
            assert!(dist(&a[i], &b[j]) <= dist(&a[i], &b[k]) + 0.05);
        }
        let ta = FeatureIndex::new(&a);
        for (j, &i) in backward.iter().enumerate() {
            let k = ta.nearest(&b[j]).unwrap();
            assert!(dist(&b[j], &a[i]) <= dist(&b[j], &a[k]) + 0.05);
        }
        assert!(mutual_nearest(&[], &b).0.is_empty());
    }

    #[test]
    fn pair_features_of_parallel_normals_on_a_plane() {
        let (f1, f2, f3) = pair_features(
            &Point3::origin(),
            &Vector3::z(),
            &Point3::new(1.0, 0.0, 0.0),
            &Vector3::z(),
        )
        .unwrap();
        assert!(f1.abs() < 1e-6 && f2.abs() < 1e-6 && f3.abs() < 1e-6);
        assert!(pair_features(
            &Point3::origin(),
            &Vector3::z(),
            &Point3::origin(),
            &Vector3::z()
        )
        .is_none());
    }
}
