//! Uniform random sampling of a mesh surface: each point lands on a triangle chosen
//! with probability proportional to its area, uniformly within it, and carries the
//! triangle's outward unit normal. Seeded, so the same seed gives the same cloud.

use super::io::CloudError;
use super::PointCloud;
use crate::mesh::TriMesh;
use nalgebra::{Point3, Vector3};
use rand::Rng;
use rand_chacha::rand_core::SeedableRng;
use rand_chacha::ChaCha8Rng;
use std::path::Path;

/// `n` points sampled uniformly by area over `mesh`'s surface with the random
/// stream of `seed`, with the outward normals of their triangles (unorganised).
/// Fails for an invalid mesh or one without area.
pub fn sample_surface(mesh: &TriMesh, n: usize, seed: u64) -> Result<PointCloud, CloudError> {
    mesh.validate(Path::new("<mesh to sample>"))?;
    // Cumulative areas (twice the area: the cross product's norm) and unit normals.
    let mut cumulative = Vec::with_capacity(mesh.triangles.len());
    let mut normals = Vec::with_capacity(mesh.triangles.len());
    let mut total = 0.0;
    for i in 0..mesh.triangles.len() {
        let [a, b, c] = mesh.corners(i);
        let cross = (b - a).cross(&(c - a));
        let double_area = cross.norm();
        total += double_area;
        cumulative.push(total);
        normals.push(if double_area > 0.0 {
            cross / double_area
        } else {
            Vector3::zeros()
        });
    }
    if !(total > 0.0 && total.is_finite()) {
        return Err(CloudError::NoSurface {
            triangles: mesh.triangles.len(),
            area_m2: total / 2.0,
        });
    }
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut points = Vec::with_capacity(n);
    let mut point_normals = Vec::with_capacity(n);
    for _ in 0..n {
        let target = rng.gen::<f64>() * total;
        // First triangle whose cumulative area exceeds the target; zero-area
        // triangles never are.
        let i = cumulative
            .partition_point(|&c| c <= target)
            .min(cumulative.len() - 1);
        let [a, b, c] = mesh.corners(i);
        // Uniform in the triangle: s = sqrt(u) spreads mass evenly along the
        // a -> (b, c) direction, v splits it between b and c.
        let s = rng.gen::<f64>().sqrt();
        let v = rng.gen::<f64>();
        let p = a.coords * (1.0 - s) + b.coords * (s * (1.0 - v)) + c.coords * (s * v);
        points.push(Point3::from(p.cast::<f32>()));
        point_normals.push(normals[i].cast::<f32>());
    }
    let mut cloud = PointCloud::from_points(points);
    cloud.normals = Some(point_normals);
    Ok(cloud)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::cloud::io::test_support::cube;

    #[test]
    fn cube_samples_lie_on_its_faces_with_outward_normals() {
        let n = 6000;
        let cloud = sample_surface(&cube(), n, 7).unwrap();
        assert_eq!(cloud.len(), n);
        let normals = cloud.normals.as_ref().unwrap();
        let mut per_side = [0usize; 6];
        for (p, normal) in cloud.points.iter().zip(normals) {
            // Independent geometry: a point of the unit cube's surface is inside
            // [0, 1]^3 with one coordinate at 0 or 1, and the normal points along
            // that axis, away from the centre.
            let p = p.cast::<f64>();
            assert!(p.iter().all(|&c| (-1e-7..=1.0 + 1e-7).contains(&c)), "{p}");
            let (axis, distance) = (0..3)
                .map(|k| (k, p[k].abs().min((1.0 - p[k]).abs())))
                .min_by(|a, b| a.1.total_cmp(&b.1))
                .unwrap();
            assert!(distance < 1e-6, "{p} is {distance} m off the surface");
            let outward = if p[axis] > 0.5 { 1.0 } else { -1.0 };
            let mut expected = Vector3::<f32>::zeros();
            expected[axis] = outward;
            assert!((normal - expected).norm() < 1e-6, "{p}: {normal}");
            per_side[2 * axis + usize::from(outward > 0.0)] += 1;
        }
        // Equal areas, equal shares: binomial sd = sqrt(6000 * 1/6 * 5/6) = 28.9.
        for count in per_side {
            assert!((count as f64 - 1000.0).abs() < 5.0 * 28.9, "{per_side:?}");
        }
    }

    #[test]
    fn counts_follow_area_one_to_three() {
        // Two triangles in z = 0: areas 0.5 and 1.5.
        let mesh = TriMesh {
            vertices: vec![
                Point3::new(0.0, 0.0, 0.0),
                Point3::new(1.0, 0.0, 0.0),
                Point3::new(0.0, 1.0, 0.0),
                Point3::new(2.0, 0.0, 0.0),
                Point3::new(5.0, 0.0, 0.0),
                Point3::new(2.0, 1.0, 0.0),
            ],
            triangles: vec![[0, 1, 2], [3, 4, 5]],
        };
        let n = 40_000;
        let cloud = sample_surface(&mesh, n, 11).unwrap();
        let small: Vec<_> = cloud.points.iter().filter(|p| p.x < 1.5).collect();
        // Points are inside their triangle (x + y <= 1, or within the big one).
        for p in &cloud.points {
            assert_eq!(p.z, 0.0);
            if p.x < 1.5 {
                assert!(p.x >= 0.0 && p.y >= 0.0 && p.x + p.y <= 1.0 + 1e-6, "{p}");
            } else {
                assert!(
                    p.x >= 2.0 && p.y >= 0.0 && (p.x - 2.0) / 3.0 + p.y <= 1.0 + 1e-6,
                    "{p}"
                );
            }
        }
        // Chi-square with one degree of freedom against 1:3; 10.83 is p = 0.001.
        let observed = [small.len() as f64, (n - small.len()) as f64];
        let expected = [n as f64 / 4.0, 3.0 * n as f64 / 4.0];
        let chi2: f64 = observed
            .iter()
            .zip(expected)
            .map(|(o, e)| (o - e).powi(2) / e)
            .sum();
        assert!(chi2 < 10.83, "chi2 = {chi2}, counts {observed:?}");
        // Uniform within a triangle: the mean is the centroid (1/3, 1/3).
        let mean = small
            .iter()
            .fold(Vector3::zeros(), |s, p| s + p.coords.cast::<f64>())
            / small.len() as f64;
        assert!(
            (mean.x - 1.0 / 3.0).abs() < 0.01 && (mean.y - 1.0 / 3.0).abs() < 0.01,
            "{mean}"
        );
        // Normals of a counter-clockwise triangle seen from +z point up.
        assert!(cloud.normals.unwrap().iter().all(|n| *n == Vector3::z()));
    }

    #[test]
    fn same_seed_same_cloud_other_seed_other_cloud() {
        let a = sample_surface(&cube(), 100, 3).unwrap();
        assert_eq!(a, sample_surface(&cube(), 100, 3).unwrap());
        assert_ne!(a, sample_surface(&cube(), 100, 4).unwrap());
    }

    #[test]
    fn degenerate_and_invalid_meshes_are_errors() {
        let flat = TriMesh {
            vertices: vec![
                Point3::origin(),
                Point3::new(1.0, 0.0, 0.0),
                Point3::new(2.0, 0.0, 0.0),
            ],
            triangles: vec![[0, 1, 2]],
        };
        let err = sample_surface(&flat, 10, 0).unwrap_err().to_string();
        assert!(
            err.contains("no surface to sample: 1 triangles, total area 0"),
            "{err}"
        );
        let mut bad = cube();
        bad.triangles[0][1] = 99;
        let err = sample_surface(&bad, 10, 0).unwrap_err().to_string();
        assert!(err.contains("triangle 0 uses vertex 99"), "{err}");
    }
}
