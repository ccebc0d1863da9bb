//! Voxel-grid downsampling: one point per occupied cubic cell, the centroid of the
//! cell's points (and their mean normal, renormalised, when the cloud has normals;
//! the first point's normal where they disagree).
//! Missing (NaN) points are ignored; the output is unorganised and its order is
//! deterministic (cells sorted by their integer coordinates).

use super::PointCloud;
use nalgebra::{Point3, Vector3};

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
        .as_ref()
        .filter(|n| n.len() == cloud.points.len());
    let valid: Vec<usize> = (0..cloud.points.len())
        .filter(|&i| {
            let p = &cloud.points[i];
            p.x.is_finite() && p.y.is_finite() && p.z.is_finite()
        })
        .collect();
    if !(voxel_m > 0.0 && voxel_m.is_finite()) {
        let mut out = PointCloud::from_points(valid.iter().map(|&i| cloud.points[i]).collect());
        out.normals = normals.map(|n| valid.iter().map(|&i| n[i]).collect());
        return out;
    }
    let voxel = voxel_m as f32;
    let mut keyed: Vec<([i32; 3], usize)> = valid
        .iter()
        .map(|&i| (cell_of(&cloud.points[i], voxel), i))
        .collect();
    keyed.sort_unstable();
    let mut points = Vec::new();
    let mut out_normals = Vec::new();
    let mut start = 0;
    while start < keyed.len() {
        let key = keyed[start].0;
        let end = start + keyed[start..].partition_point(|(k, _)| *k == key);
        let mut sum = Vector3::<f64>::zeros();
        let mut normal = Vector3::<f32>::zeros();
        for &(_, i) in &keyed[start..end] {
            sum += cloud.points[i].coords.cast::<f64>();
            if let Some(n) = normals {
                normal += n[i];
            }
        }
        points.push(Point3::from((sum / (end - start) as f64).cast::<f32>()));
        if normals.is_some() {
            // Normals that disagree in one cell (both sides of a thin wall) keep
            // the first one rather than a meaningless mean.
            let first = normals.map(|n| n[keyed[start].1]).unwrap_or_default();
            let agree = normal.norm() >= 0.5 * (end - start) as f32;
            out_normals.push(if agree { normal.normalize() } else { first });
        }
        start = end;
    }
    let mut out = PointCloud::from_points(points);
    if normals.is_some() {
        out.normals = Some(out_normals);
    }
    out
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
