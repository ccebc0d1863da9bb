//! Table-top segmentation: the object's points out of a camera snapshot.
//!
//! The camera's points are moved into the robot base frame and cropped to the
//! workspace box; the supporting plane is found by RANSAC on a voxel-downsampled
//! copy (normals within a tilt limit of the base frame's +z, refined by least
//! squares on its inliers), and the plane with everything below it is removed.
//! The rest is split into Euclidean clusters and the cluster whose centroid is
//! nearest the workspace centre (in x-y) is the object. Organised or not; missing
//! (NaN) points are ignored. Seeded.

use super::kdtree::KdIndex;
use super::voxel::voxel_downsample_points;
use super::PointCloud;
use crate::config::CellConfig;
use crate::geometry::Pose;
use nalgebra::{Point3, Vector3};
use rand::Rng;
use rand_chacha::rand_core::SeedableRng;
use rand_chacha::ChaCha8Rng;

/// Errors of segmentation; each names the numbers that failed.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum SegmentError {
    /// The snapshot has no finite point.
    #[error("cloud has no valid points ({total} points, all missing or non-finite)")]
    NoValidPoints {
        /// Points in the cloud, missing ones included.
        total: usize,
    },
    /// No point lies in the workspace box.
    #[error("none of the {valid} valid points lies in the workspace box {min_m:?}..{max_m:?} m (base frame); is base_from_camera right?")]
    EmptyWorkspace {
        /// Valid points of the snapshot.
        valid: usize,
        /// Workspace lower corner (m).
        min_m: [f64; 3],
        /// Workspace upper corner (m).
        max_m: [f64; 3],
    },
    /// Nothing is left above the table.
    #[error("no object on the table: {above} points above the plane, no cluster of at least {min_points} points")]
    NoObject {
        /// Points left above the plane.
        above: usize,
        /// The minimum cluster size.
        min_points: usize,
    },
    /// A parameter is out of range.
    #[error("segment parameter {name} = {value} is invalid: {problem}")]
    BadParameter {
        /// The parameter.
        name: &'static str,
        /// Its value.
        value: f64,
        /// What is wrong.
        problem: &'static str,
    },
}

/// Settings of [`segment_object`].
#[derive(Debug, Clone, PartialEq)]
pub struct SegmentParams {
    /// Expected table height in the base frame (m): the fallback plane when RANSAC
    /// finds none.
    pub table_height_m: f64,
    /// Workspace box, lower corner (base frame, m).
    pub workspace_min_m: [f64; 3],
    /// Workspace box, upper corner (base frame, m).
    pub workspace_max_m: [f64; 3],
    /// Cell of the voxel grid the plane is fitted on (m).
    pub plane_voxel_m: f64,
    /// Plane inlier distance; points up to this far above the plane are removed (m).
    pub plane_distance_m: f64,
    /// Largest angle between the plane's normal and the base +z (rad).
    pub plane_max_tilt_rad: f64,
    /// RANSAC iterations for the plane.
    pub plane_iterations: usize,
    /// Least fraction of the downsampled points a plane must hold to be the table.
    pub plane_min_fraction: f64,
    /// Two points closer than this join one cluster (m).
    pub cluster_tolerance_m: f64,
    /// Smallest cluster that can be the object.
    pub min_cluster_points: usize,
    /// Other clusters whose footprint (the box of their points seen from above)
    /// comes within this of the object's join it (m): one object seen in pieces,
    /// e.g. a handle cut off by depth-edge dropouts, or a mug's inside, seen through
    /// its opening, cut off from its outer wall by the lost edge pixels at the rim.
    pub part_gap_m: f64,
    /// Seed of the plane RANSAC.
    pub seed: u64,
}

impl Default for SegmentParams {
    fn default() -> SegmentParams {
        SegmentParams {
            table_height_m: 0.0,
            workspace_min_m: [-1.5, -1.5, -0.5],
            workspace_max_m: [1.5, 1.5, 1.5],
            plane_voxel_m: 0.01,
            plane_distance_m: 0.008,
            plane_max_tilt_rad: 15f64.to_radians(),
            plane_iterations: 200,
            plane_min_fraction: 0.2,
            cluster_tolerance_m: 0.01,
            min_cluster_points: 50,
            part_gap_m: 0.02,
            seed: 0,
        }
    }
}

impl SegmentParams {
    /// The defaults with the cell's table height and workspace box
    /// (`robot/cell.toml`); the workspace floor is lowered to 5 cm under the table
    /// so that the table itself is seen and fitted.
    pub fn for_cell(config: &CellConfig) -> SegmentParams {
        let mut min = config.workspace.min_m;
        min[2] = min[2].min(config.table.height_m - 0.05);
        SegmentParams {
            table_height_m: config.table.height_m,
            workspace_min_m: min,
            workspace_max_m: config.workspace.max_m,
            ..SegmentParams::default()
        }
    }

    fn check(&self) -> Result<(), SegmentError> {
        let positive = [
            ("plane_voxel_m", self.plane_voxel_m),
            ("plane_distance_m", self.plane_distance_m),
            ("cluster_tolerance_m", self.cluster_tolerance_m),
            ("part_gap_m", self.part_gap_m),
        ];
        for (name, value) in positive {
            if !(value > 0.0 && value.is_finite()) {
                return Err(SegmentError::BadParameter {
                    name,
                    value,
                    problem: "must be a positive number",
                });
            }
        }
        if !self.table_height_m.is_finite() {
            return Err(SegmentError::BadParameter {
                name: "table_height_m",
                value: self.table_height_m,
                problem: "must be finite",
            });
        }
        for k in 0..3 {
            // Also false for NaN.
            let ordered = self.workspace_min_m[k].partial_cmp(&self.workspace_max_m[k])
                == Some(std::cmp::Ordering::Less);
            if !ordered {
                return Err(SegmentError::BadParameter {
                    name: "workspace_min_m",
                    value: self.workspace_min_m[k],
                    problem: "must be below workspace_max_m on every axis",
                });
            }
        }
        Ok(())
    }
}

/// A plane `normal . p + offset = 0` with a unit normal.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Plane {
    /// Unit normal (pointing up, away from the table's underside).
    pub normal: Vector3<f64>,
    /// Offset (m).
    pub offset_m: f64,
}

impl Plane {
    /// Signed distance of `p` above the plane (m).
    pub fn distance(&self, p: &Point3<f32>) -> f64 {
        self.normal.dot(&p.coords.cast::<f64>()) + self.offset_m
    }
}

/// The least-squares plane through `points` (PCA), normal oriented to `up`.
fn fit_plane_lsq(points: &[Point3<f32>], up: &Vector3<f64>) -> Option<Plane> {
    let idx: Vec<usize> = (0..points.len()).collect();
    let n = super::normals::pca_normal(points, &idx)?.cast::<f64>();
    let n = if n.dot(up) < 0.0 { -n } else { n };
    let mean = points
        .iter()
        .fold(Vector3::zeros(), |s, p| s + p.coords.cast::<f64>())
        / points.len() as f64;
    Some(Plane {
        normal: n,
        offset_m: -n.dot(&mean),
    })
}

/// RANSAC for the dominant plane of `points` whose normal is within `max_tilt_rad`
/// of `up`, refined on its inliers; `None` when no plane holds `min_inliers`.
pub fn fit_support_plane(
    points: &[Point3<f32>],
    up: &Vector3<f64>,
    params: &SegmentParams,
    min_inliers: usize,
) -> Option<Plane> {
    if points.len() < 3 {
        return None;
    }
    let mut rng = ChaCha8Rng::seed_from_u64(params.seed);
    let cos_tilt = params.plane_max_tilt_rad.cos();
    let mut best: Option<(usize, Plane)> = None;
    for _ in 0..params.plane_iterations {
        let a = points[rng.gen_range(0..points.len())].coords.cast::<f64>();
        let b = points[rng.gen_range(0..points.len())].coords.cast::<f64>();
        let c = points[rng.gen_range(0..points.len())].coords.cast::<f64>();
        let Some(n) = (b - a).cross(&(c - a)).try_normalize(1e-12) else {
            continue;
        };
        let n = if n.dot(up) < 0.0 { -n } else { n };
        if n.dot(up) < cos_tilt {
            continue;
        }
        let plane = Plane {
            normal: n,
            offset_m: -n.dot(&a),
        };
        let count = points
            .iter()
            .filter(|p| plane.distance(p).abs() <= params.plane_distance_m)
            .count();
        let better = match &best {
            None => true,
            Some((c, _)) => count > *c,
        };
        if better {
            best = Some((count, plane));
        }
    }
    let (count, plane) = best?;
    if count < min_inliers.max(3) {
        return None;
    }
    let inliers: Vec<Point3<f32>> = points
        .iter()
        .filter(|p| plane.distance(p).abs() <= params.plane_distance_m)
        .copied()
        .collect();
    let refined = fit_plane_lsq(&inliers, up).unwrap_or(plane);
    (refined.normal.dot(up) >= cos_tilt)
        .then_some(refined)
        .or(Some(plane))
}

/// Euclidean clusters of `points`: connected components of the graph joining
/// points closer than `tolerance_m`; each cluster is a list of indices, largest first.
pub fn euclidean_clusters(points: &[Point3<f32>], tolerance_m: f64) -> Vec<Vec<usize>> {
    let index = KdIndex::new(points);
    let mut label = vec![usize::MAX; points.len()];
    let mut clusters = Vec::new();
    for seed in 0..points.len() {
        if label[seed] != usize::MAX {
            continue;
        }
        let id = clusters.len();
        label[seed] = id;
        let mut members = vec![seed];
        let mut next = 0;
        while next < members.len() {
            let p = points[members[next]];
            next += 1;
            for j in index.within(&p, tolerance_m as f32) {
                if label[j] == usize::MAX {
                    label[j] = id;
                    members.push(j);
                }
            }
        }
        clusters.push(members);
    }
    clusters.sort_by(|a, b| b.len().cmp(&a.len()).then(a[0].cmp(&b[0])));
    clusters
}

/// The object among `clusters` of `points`: of the clusters with at least
/// `min_cluster_points` and a fair share (a quarter) of the largest one's points, the
/// one whose centroid is nearest the workspace centre (x, y) — so a handle or a
/// speck cut off by depth-edge dropouts is never taken for the object — together
/// with its other pieces (footprints within `part_gap_m`).
/// Sorted indices into `points`; `None` when no cluster is large enough.
fn choose_object(
    points: &[Point3<f32>],
    clusters: &[Vec<usize>],
    [lo, hi]: [[f64; 3]; 2],
    params: &SegmentParams,
) -> Option<Vec<usize>> {
    let largest = clusters.iter().map(Vec::len).max()?;
    let centre = [(lo[0] + hi[0]) / 2.0, (lo[1] + hi[1]) / 2.0];
    let main = clusters
        .iter()
        .enumerate()
        .filter(|(_, c)| c.len() >= params.min_cluster_points && 4 * c.len() >= largest)
        .map(|(k, c)| {
            let (sx, sy) = c.iter().fold((0.0, 0.0), |(sx, sy), &i| {
                (sx + points[i].x as f64, sy + points[i].y as f64)
            });
            let n = c.len() as f64;
            (
                (sx / n - centre[0]).powi(2) + (sy / n - centre[1]).powi(2),
                k,
            )
        })
        .min_by(|a, b| a.0.total_cmp(&b.0))
        .map(|(_, k)| k)?;
    // Join the object's other pieces: clusters whose footprint comes within
    // `part_gap_m` of the object's (grown with every piece joined), until none is left.
    let footprint = |c: &[usize]| {
        c.iter()
            .fold([f32::MAX, f32::MAX, f32::MIN, f32::MIN], |b, &i| {
                let p = &points[i];
                [b[0].min(p.x), b[1].min(p.y), b[2].max(p.x), b[3].max(p.y)]
            })
    };
    let gap = params.part_gap_m as f32;
    let mut joined = vec![false; clusters.len()];
    joined[main] = true;
    let mut indices = clusters[main].clone();
    let mut bounds = footprint(&indices);
    loop {
        let before = indices.len();
        for (k, c) in clusters.iter().enumerate() {
            if joined[k] {
                continue;
            }
            let b = footprint(c);
            if b[0] <= bounds[2] + gap
                && bounds[0] <= b[2] + gap
                && b[1] <= bounds[3] + gap
                && bounds[1] <= b[3] + gap
            {
                joined[k] = true;
                indices.extend_from_slice(c);
                bounds = footprint(&indices);
            }
        }
        if indices.len() == before {
            break;
        }
    }
    indices.sort_unstable();
    Some(indices)
}

/// The object's points, in the robot base frame, out of the camera's snapshot
/// `cloud_camera` (optical frame) seen from `base_from_camera`.
pub fn segment_object(
    cloud_camera: &PointCloud,
    base_from_camera: &Pose,
    params: &SegmentParams,
) -> Result<PointCloud, SegmentError> {
    params.check()?;
    let transform = base_from_camera.cast::<f32>();
    let (lo, hi) = (params.workspace_min_m, params.workspace_max_m);
    let mut valid = 0;
    let inside: Vec<Point3<f32>> = cloud_camera
        .valid_points()
        .map(|p| transform * p)
        .inspect(|_| valid += 1)
        .filter(|p| (0..3).all(|k| (lo[k]..=hi[k]).contains(&(p[k] as f64))))
        .collect();
    if valid == 0 {
        return Err(SegmentError::NoValidPoints {
            total: cloud_camera.len(),
        });
    }
    if inside.is_empty() {
        return Err(SegmentError::EmptyWorkspace {
            valid,
            min_m: lo,
            max_m: hi,
        });
    }
    let up = Vector3::z();
    let coarse = voxel_downsample_points(&inside, params.plane_voxel_m);
    let min_inliers = (params.plane_min_fraction * coarse.len() as f64).ceil() as usize;
    let plane = fit_support_plane(&coarse.points, &up, params, min_inliers).unwrap_or(Plane {
        normal: up,
        offset_m: -params.table_height_m,
    });
    tracing::debug!(
        normal = ?plane.normal.as_slice(),
        offset_m = plane.offset_m,
        "support plane"
    );
    let above: Vec<Point3<f32>> = inside
        .into_iter()
        .filter(|p| plane.distance(p) > params.plane_distance_m)
        .collect();
    let clusters = euclidean_clusters(&above, params.cluster_tolerance_m);
    let indices =
        choose_object(&above, &clusters, [lo, hi], params).ok_or(SegmentError::NoObject {
            above: above.len(),
            min_points: params.min_cluster_points,
        })?;
    Ok(PointCloud::from_points(
        indices.iter().map(|&i| above[i]).collect(),
    ))
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Translation3, UnitQuaternion};

    /// An 80 x 80 cm table grid at z = 0, 1 cm spacing, in the base frame.
    fn table_grid() -> Vec<Point3<f32>> {
        let mut pts = Vec::new();
        for i in 0..80 {
            for j in 0..80 {
                pts.push(Point3::new(
                    0.2 + i as f32 * 0.01,
                    -0.4 + j as f32 * 0.01,
                    0.0,
                ));
            }
        }
        pts
    }

    /// A table grid at z = 0 plus a 4 cm cube of points centred at (0.6, 0, 0.03)
    /// and a small far cluster, in the base frame.
    fn scene_points() -> (Vec<Point3<f32>>, usize) {
        let mut pts = table_grid();
        let mut object = 0;
        for i in 0..20 {
            for j in 0..20 {
                for k in 0..20 {
                    if i == 0 || i == 19 || j == 0 || j == 19 || k == 19 {
                        pts.push(Point3::new(
                            0.58 + i as f32 * 0.002,
                            -0.02 + j as f32 * 0.002,
                            0.012 + k as f32 * 0.002,
                        ));
                        object += 1;
                    }
                }
            }
        }
        pts.push(Point3::new(0.25, 0.35, 0.05));
        (pts, object)
    }

    #[test]
    fn a_cut_off_handle_joins_its_body_and_a_speck_at_the_centre_is_not_the_object() {
        // Body: 400 points around (0.70, 0.15); handle: 60 points 1.5 cm beside it;
        // speck: 60 points right at the workspace centre; far box: 500 points 30 cm away.
        let grid = |x0: f32, y0: f32, nx: usize, ny: usize| -> Vec<Point3<f32>> {
            (0..nx * ny)
                .map(|k| {
                    let (i, j) = (k % nx, k / nx);
                    Point3::new(x0 + i as f32 * 0.002, y0, 0.02 + j as f32 * 0.002)
                })
                .collect()
        };
        let mut points = grid(0.68, 0.15, 20, 20);
        let handle_start = points.len();
        points.extend(grid(0.68 + 0.038 + 0.015, 0.15, 6, 10));
        let speck_start = points.len();
        points.extend(grid(0.62, 0.0, 6, 10));
        let far_start = points.len();
        points.extend(grid(0.30, -0.30, 25, 20));
        let clusters = euclidean_clusters(&points, 0.01);
        assert_eq!(clusters.len(), 4, "test setup");
        let box_ = [[0.15, -0.7, -0.05], [1.1, 0.7, 1.0]];
        let params = SegmentParams {
            min_cluster_points: 50,
            ..SegmentParams::default()
        };
        let object = choose_object(&points, &clusters, box_, &params).unwrap();
        let expected: Vec<usize> = (0..speck_start).collect();
        assert_eq!(
            object, expected,
            "body and handle, not the speck or the far box"
        );
        assert!(object.contains(&handle_start) && !object.contains(&far_start));
        // With the handle farther than the merge distance it stays out.
        let apart = SegmentParams {
            part_gap_m: 0.01,
            ..params
        };
        let object = choose_object(&points, &clusters, box_, &apart).unwrap();
        assert_eq!(object, (0..handle_start).collect::<Vec<_>>());
    }

    #[test]
    fn finds_the_object_above_the_table() {
        let (pts, object) = scene_points();
        let base_from_camera = Pose::from_parts(
            Translation3::new(1.2, 0.1, 0.8),
            UnitQuaternion::from_euler_angles(-2.4, 0.0, 1.57),
        );
        let camera_from_base = base_from_camera.inverse().cast::<f32>();
        let mut camera: Vec<Point3<f32>> = pts.iter().map(|p| camera_from_base * p).collect();
        camera.push(Point3::new(f32::NAN, f32::NAN, f32::NAN));
        let params = SegmentParams {
            workspace_min_m: [0.0, -1.0, -0.1],
            workspace_max_m: [1.2, 1.0, 1.0],
            ..SegmentParams::default()
        };
        let seg =
            segment_object(&PointCloud::from_points(camera), &base_from_camera, &params).unwrap();
        // The cube's points more than 8 mm above the table: all of them (lowest 12 mm).
        assert_eq!(seg.len(), object);
        assert!(seg
            .points
            .iter()
            .all(|p| (p.x - 0.6).abs() < 0.03 && p.y.abs() < 0.03 && p.z > 0.008));
    }

    #[test]
    fn an_object_seen_in_pieces_is_joined() {
        // A table, an open box's wall (4 x 4 cm, 1.2..5 cm high) and, 2 cm below its
        // rim and cut off from the wall by a 1.2 cm gap, the floor seen inside it
        // (nearer the workspace centre than the wall); and another object 10 cm away.
        let mut pts = table_grid();
        let mut object = 0;
        for i in 0..21 {
            for j in 0..21 {
                for k in 0..20 {
                    if i == 0 || i == 20 || j == 0 || j == 20 {
                        pts.push(Point3::new(
                            0.58 + i as f32 * 0.002,
                            -0.02 + j as f32 * 0.002,
                            0.012 + k as f32 * 0.002,
                        ));
                        object += 1;
                    }
                }
                if (6..=14).contains(&i) && (6..=14).contains(&j) {
                    pts.push(Point3::new(
                        0.58 + i as f32 * 0.002,
                        -0.02 + j as f32 * 0.002,
                        0.03,
                    ));
                    object += 1;
                }
            }
        }
        for i in 0..10 {
            for k in 0..10 {
                pts.push(Point3::new(
                    0.7,
                    0.1 + i as f32 * 0.002,
                    0.012 + k as f32 * 0.002,
                ));
            }
        }
        let params = SegmentParams {
            workspace_min_m: [0.0, -1.0, -0.1],
            workspace_max_m: [1.2, 1.0, 1.0],
            ..SegmentParams::default()
        };
        let seg =
            segment_object(&PointCloud::from_points(pts), &Pose::identity(), &params).unwrap();
        assert_eq!(seg.len(), object);
        assert!(seg.points.iter().all(|p| p.x < 0.63 && p.y < 0.03));
    }

    #[test]
    fn tilted_plane_is_found() {
        let tilt = 0.1f64;
        let pts: Vec<Point3<f32>> = (0..400)
            .map(|i| {
                let (x, y) = ((i % 20) as f64 * 0.02, (i / 20) as f64 * 0.02);
                Point3::new(x as f32, y as f32, (0.3 + x * tilt.tan()) as f32)
            })
            .collect();
        let plane = fit_support_plane(&pts, &Vector3::z(), &SegmentParams::default(), 100).unwrap();
        let want = Vector3::new(-tilt.sin(), 0.0, tilt.cos());
        assert!((plane.normal - want).norm() < 1e-4, "{:?}", plane.normal);
        assert!(pts.iter().all(|p| plane.distance(p).abs() < 1e-4));
    }

    #[test]
    fn bad_inputs_are_errors() {
        let params = SegmentParams::default();
        let nan = PointCloud::from_points(vec![Point3::new(f32::NAN, 0.0, 0.0); 5]);
        assert_eq!(
            segment_object(&nan, &Pose::identity(), &params),
            Err(SegmentError::NoValidPoints { total: 5 })
        );
        let far = PointCloud::from_points(vec![Point3::new(9.0, 0.0, 0.0)]);
        assert!(matches!(
            segment_object(&far, &Pose::identity(), &params),
            Err(SegmentError::EmptyWorkspace { valid: 1, .. })
        ));
        // Only a table: nothing above it.
        let table: Vec<Point3<f32>> = (0..400)
            .map(|i| Point3::new((i % 20) as f32 * 0.01, (i / 20) as f32 * 0.01, 0.0))
            .collect();
        let err = segment_object(&PointCloud::from_points(table), &Pose::identity(), &params)
            .unwrap_err();
        assert!(
            matches!(err, SegmentError::NoObject { above: 0, .. }),
            "{err}"
        );
        assert!(err.to_string().starts_with("no object on the table"));
        let bad = SegmentParams {
            cluster_tolerance_m: 0.0,
            ..params
        };
        assert!(matches!(
            segment_object(
                &PointCloud::from_points(vec![Point3::origin()]),
                &Pose::identity(),
                &bad
            ),
            Err(SegmentError::BadParameter {
                name: "cluster_tolerance_m",
                ..
            })
        ));
    }

    #[test]
    fn clusters_split_by_gap() {
        let pts = vec![
            Point3::new(0.0, 0.0, 0.0),
            Point3::new(0.005, 0.0, 0.0),
            Point3::new(0.1, 0.0, 0.0),
        ];
        assert_eq!(euclidean_clusters(&pts, 0.01), vec![vec![0, 1], vec![2]]);
    }
}
