//! Voxel-grid downsampling: one point per occupied cubic cell, the centroid of the
//! cell's points (and their mean normal, renormalised, when the cloud has normals;
//! the first point's normal where they disagree).
//! Missing (NaN) points are ignored; the output is unorganised and its order is
//! deterministic (cells sorted by their integer coordinates).

use super::PointCloud;
use nalgebra::{Point3, Vector3};
use std::collections::HashMap;
use std::hash::{BuildHasherDefault, Hash, Hasher};

/// The integer cell of `p` for cells of `voxel_m`.
fn cell_of(p: &Point3<f32>, voxel_m: f32) -> [i32; 3] {
    [
        (p.x / voxel_m).floor() as i32,
        (p.y / voxel_m).floor() as i32,
        (p.z / voxel_m).floor() as i32,
    ]
}

/// Downsamples `cloud` to one point per occupied cell of edge `voxel_m` (m).
/// A non-positive or non-finite `voxel_m` only drops the missing points.
pub fn voxel_downsample(cloud: &PointCloud, voxel_m: f64) -> PointCloud {
    let normals = cloud
        .normals
        .as_deref()
        .filter(|n| n.len() == cloud.points.len());
    downsample(&cloud.points, normals, voxel_m)
}

/// [`voxel_downsample`] of bare points (no normals), without copying them into a
/// cloud first.
pub fn voxel_downsample_points(points: &[Point3<f32>], voxel_m: f64) -> PointCloud {
    downsample(points, None, voxel_m)
}

/// [`voxel_downsample`] of `points` with their `normals`, if any (one per point).
fn downsample(
    points: &[Point3<f32>],
    normals: Option<&[Vector3<f32>]>,
    voxel_m: f64,
) -> PointCloud {
    let valid = points
        .iter()
        .enumerate()
        .filter(|(_, p)| p.x.is_finite() && p.y.is_finite() && p.z.is_finite());
    if !(voxel_m > 0.0 && voxel_m.is_finite()) {
        let valid: Vec<usize> = valid.map(|(i, _)| i).collect();
        let mut out = PointCloud::from_points(valid.iter().map(|&i| points[i]).collect());
        out.normals = normals.map(|n| valid.iter().map(|&i| n[i]).collect());
        return out;
    }
    let voxel = voxel_m as f32;
    // Each cell's sums in index order (as a sort by cell and index would add them),
    // then the cells in order of their coordinates.
    let mut cells: HashMap<CellKey, Cell, BuildHasherDefault<CellHasher>> = HashMap::default();
    for (i, p) in valid {
        let cell = cells.entry(CellKey(cell_of(p, voxel))).or_insert(Cell {
            sum: Vector3::zeros(),
            normal: Vector3::zeros(),
            count: 0,
            first: i,
        });
        cell.sum += p.coords.cast::<f64>();
        if let Some(n) = normals {
            cell.normal += n[i];
        }
        cell.count += 1;
    }
    let mut cells: Vec<(CellKey, Cell)> = cells.into_iter().collect();
    cells.sort_unstable_by_key(|(key, _)| key.0);
    let out_points = cells
        .iter()
        .map(|(_, c)| Point3::from((c.sum / c.count as f64).cast::<f32>()))
        .collect();
    // Normals that disagree in one cell (both sides of a thin wall) keep the first
    // one rather than a meaningless mean.
    let out_normals = normals.map(|n| {
        cells
            .iter()
            .map(|(_, c)| {
                if c.normal.norm() >= 0.5 * c.count as f32 {
                    c.normal.normalize()
                } else {
                    n[c.first]
                }
            })
            .collect()
    });
    let mut out = PointCloud::from_points(out_points);
    out.normals = out_normals;
    out
}

/// The points of one occupied cell so far.
struct Cell {
    sum: Vector3<f64>,
    normal: Vector3<f32>,
    count: usize,
    /// The cell's first point.
    first: usize,
}

/// A cell's integer coordinates, hashed in one multiply-mix.
#[derive(Clone, Copy, PartialEq, Eq)]
struct CellKey([i32; 3]);

impl Hash for CellKey {
    fn hash<H: Hasher>(&self, state: &mut H) {
        let [x, y, z] = self.0.map(|c| u64::from(c as u32));
        state.write_u64(x ^ y.rotate_left(21) ^ z.rotate_left(42));
    }
}

/// The hasher of [`CellKey`]: a multiplicative mix of its one word.
#[derive(Default)]
struct CellHasher(u64);

impl Hasher for CellHasher {
    fn write(&mut self, bytes: &[u8]) {
        for &b in bytes {
            self.write_u64(u64::from(b));
        }
    }

    fn write_u64(&mut self, word: u64) {
        self.0 = (self.0 ^ word).wrapping_mul(0x9e37_79b9_7f4a_7c15);
    }

    fn finish(&self) -> u64 {
        self.0 ^ (self.0 >> 29)
    }
}

/// Downsamples `cloud` on cells of `voxel_m` (m), doubled until at most `max_points`
/// remain (at least one point per cell of the final size). With a non-positive or
/// non-finite `voxel_m` or no `max_points`, the result of [`voxel_downsample`].
pub fn voxel_downsample_to(cloud: &PointCloud, voxel_m: f64, max_points: usize) -> PointCloud {
    let mut voxel = voxel_m;
    loop {
        let out = voxel_downsample(cloud, voxel);
        if out.len() <= max_points || max_points == 0 || !(voxel > 0.0 && voxel.is_finite()) {
            return out;
        }
        voxel *= 2.0;
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};

    /// The definition: every valid point sorted by (cell, index), each run of one
    /// cell summed in that order.
    fn by_sorting(cloud: &PointCloud, voxel_m: f64) -> PointCloud {
        let normals = cloud.normals.as_ref().unwrap();
        let mut keyed: Vec<([i32; 3], usize)> = (0..cloud.len())
            .filter(|&i| cloud.points[i].iter().all(|c| c.is_finite()))
            .map(|i| (cell_of(&cloud.points[i], voxel_m as f32), i))
            .collect();
        keyed.sort_unstable();
        let (mut points, mut out_normals) = (Vec::new(), Vec::new());
        for run in keyed.chunk_by(|a, b| a.0 == b.0) {
            let sum: Vector3<f64> = run.iter().fold(Vector3::zeros(), |s, &(_, i)| {
                s + cloud.points[i].coords.cast::<f64>()
            });
            let normal: Vector3<f32> = run
                .iter()
                .fold(Vector3::zeros(), |s, &(_, i)| s + normals[i]);
            points.push(Point3::from((sum / run.len() as f64).cast::<f32>()));
            out_normals.push(if normal.norm() >= 0.5 * run.len() as f32 {
                normal.normalize()
            } else {
                normals[run[0].1]
            });
        }
        let mut out = PointCloud::from_points(points);
        out.normals = Some(out_normals);
        out
    }

    #[test]
    fn the_cells_are_those_of_sorting_every_point_by_cell() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
        let mut cloud = PointCloud::from_points(
            (0..20_000)
                .map(|_| {
                    Point3::new(
                        rng.gen_range(-0.3..0.3),
                        rng.gen_range(-0.3..0.3),
                        rng.gen_range(-0.05..0.05),
                    )
                })
                .collect(),
        );
        cloud.points[7] = Point3::new(f32::NAN, 0.0, 0.0);
        // Normals up or down at random: some cells agree, some do not.
        cloud.normals = Some(
            (0..cloud.len())
                .map(|_| Vector3::z() * if rng.gen_bool(0.8) { 1.0 } else { -1.0 })
                .collect(),
        );
        for voxel_m in [0.004, 0.01, 0.05] {
            assert_eq!(
                voxel_downsample(&cloud, voxel_m),
                by_sorting(&cloud, voxel_m)
            );
        }
    }

    #[test]
    fn a_cap_coarsens_the_grid_until_the_points_fit() {
        let line: Vec<Point3<f32>> = (0..1000)
            .map(|i| Point3::new(i as f32 * 1e-3, 0.0, 0.0))
            .collect();
        let cloud = PointCloud::from_points(line);
        assert_eq!(voxel_downsample_to(&cloud, 0.004, 1000).len(), 250);
        let capped = voxel_downsample_to(&cloud, 0.004, 100);
        assert!(
            capped.len() <= 100 && capped.len() >= 50,
            "{}",
            capped.len()
        );
        assert_eq!(
            voxel_downsample_to(&cloud, 0.0, 10).len(),
            1000,
            "no grid, no cap"
        );
    }

    #[test]
    fn one_centroid_per_cell_nan_ignored() {
        let cloud = PointCloud::from_points(vec![
            Point3::new(0.001, 0.001, 0.001),
            Point3::new(0.003, 0.003, 0.003),
            Point3::new(f32::NAN, 0.0, 0.0),
            Point3::new(0.011, 0.001, 0.001),
        ]);
        let out = voxel_downsample(&cloud, 0.01);
        assert_eq!(out.len(), 2);
        assert!((out.points[0] - Point3::new(0.002, 0.002, 0.002)).norm() < 1e-6);
        assert!((out.points[1] - Point3::new(0.011, 0.001, 0.001)).norm() < 1e-6);
    }

    #[test]
    fn normals_are_averaged_and_unit() {
        let mut cloud = PointCloud::from_points(vec![
            Point3::new(0.001, 0.0, 0.0),
            Point3::new(0.002, 0.0, 0.0),
        ]);
        cloud.normals = Some(vec![Vector3::x(), Vector3::y()]);
        let out = voxel_downsample(&cloud, 0.01);
        let n = out.normals.unwrap()[0];
        assert!((n.norm() - 1.0).abs() < 1e-6);
        assert!((n.x - n.y).abs() < 1e-6);
    }

    #[test]
    fn zero_voxel_keeps_every_valid_point() {
        let cloud =
            PointCloud::from_points(vec![Point3::origin(), Point3::new(f32::NAN, 0.0, 0.0)]);
        assert_eq!(voxel_downsample(&cloud, 0.0).len(), 1);
    }
}
