//! A precomputed nearest-point field: a voxel grid over a model's bounding box
//! (plus a margin) that stores, per cell, the index of the model point nearest the
//! cell's centre. Lookups are O(1), so hypotheses can be scored and coarsely refined
//! without tree searches; the answer is exact to within half a cell diagonal.

use crate::cloud::kdtree::KdIndex;
use nalgebra::{Point3, Vector3};
use rayon::prelude::*;

/// The field of one model.
#[derive(Debug, Clone)]
pub struct NearestField {
    origin: Point3<f32>,
    cell_m: f32,
    dims: [usize; 3],
    nearest: Vec<u32>,
}

impl NearestField {
    /// The field of `points` (indexed by `index`) with cells of `cell_m` over their
    /// bounding box grown by `margin_m`. `None` for an empty cloud or a grid of more
    /// than `max_cells` cells (a model far too large for the cell size).
    pub fn new(
        points: &[Point3<f32>],
        index: &KdIndex,
        cell_m: f32,
        margin_m: f32,
        max_cells: usize,
    ) -> Option<NearestField> {
        let first = points.first()?;
        let (mut lo, mut hi) = (first.coords, first.coords);
        for p in points {
            lo = lo.inf(&p.coords);
            hi = hi.sup(&p.coords);
        }
        let lo = lo - Vector3::repeat(margin_m);
        let hi = hi + Vector3::repeat(margin_m);
        let dims_f = (hi - lo) / cell_m;
        let dims = [
            dims_f.x.ceil().max(1.0) as usize,
            dims_f.y.ceil().max(1.0) as usize,
            dims_f.z.ceil().max(1.0) as usize,
        ];
        let cells = dims[0].checked_mul(dims[1])?.checked_mul(dims[2])?;
        if cells > max_cells {
            return None;
        }
        let origin = Point3::from(lo);
        let slice = dims[0] * dims[1];
        let mut nearest = vec![0u32; cells];
        nearest
            .par_chunks_mut(slice)
            .enumerate()
            .for_each(|(z, chunk)| {
                for (i, slot) in chunk.iter_mut().enumerate() {
                    let (x, y) = (i % dims[0], i / dims[0]);
                    let c = origin
                        + Vector3::new(x as f32 + 0.5, y as f32 + 0.5, z as f32 + 0.5) * cell_m;
                    *slot = index.nearest(&c).map_or(0, |(j, _)| j as u32);
                }
            });
        Some(NearestField {
            origin,
            cell_m,
            dims,
            nearest,
        })
    }

    /// The (approximately) nearest model point's index to `p`; points outside the
    /// grid use the nearest border cell.
    #[inline]
    pub fn nearest(&self, p: &Point3<f32>) -> usize {
        let d = (p - self.origin) / self.cell_m;
        let clamp = |v: f32, n: usize| {
            if v.is_nan() || v < 0.0 {
                0
            } else {
                (v as usize).min(n - 1)
            }
        };
        let (x, y, z) = (
            clamp(d.x, self.dims[0]),
            clamp(d.y, self.dims[1]),
            clamp(d.z, self.dims[2]),
        );
        self.nearest[x + self.dims[0] * (y + self.dims[1] * z)] as usize
    }

    /// Number of cells.
    pub fn cells(&self) -> usize {
        self.nearest.len()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn field_agrees_with_the_tree_within_half_a_cell_diagonal() {
        let points: Vec<Point3<f32>> = (0..300)
            .map(|i| {
                let a = i as f32 * 0.1;
                Point3::new(0.05 * a.cos(), 0.05 * a.sin(), i as f32 * 0.0003)
            })
            .collect();
        let index = KdIndex::new(&points);
        let cell = 0.004;
        let field = NearestField::new(&points, &index, cell, 0.02, 1 << 24).unwrap();
        let tol = cell * 3f32.sqrt();
        for k in 0..500 {
            let q = Point3::new(
                ((k * 37) % 100) as f32 * 0.0014 - 0.07,
                ((k * 53) % 100) as f32 * 0.0014 - 0.07,
                ((k * 71) % 100) as f32 * 0.0012 - 0.01,
            );
            let exact = index.nearest(&q).unwrap().1.sqrt();
            let approx = (points[field.nearest(&q)] - q).norm();
            assert!(approx <= exact + tol, "{q}: {approx} vs {exact}");
        }
        assert!(NearestField::new(&points, &index, 0.0001, 0.02, 1000).is_none());
        assert!(NearestField::new(&[], &KdIndex::new(&[]), cell, 0.02, 1000).is_none());
    }
}
