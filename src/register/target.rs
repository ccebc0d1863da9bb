//! Target preparation: the object's points, prepared once for every model — valid
//! points, the ICP cloud and its normals towards the sensor, the scoring subsample,
//! FPFH descriptors, and the range image the visibility term reads.

use super::fpfh::{compute_fpfh, Fpfh};
use super::points::{bbox_diagonal, centroid, subsample_indices};
use super::visibility::RangeImage;
use super::{ms, RegisterError, RegisterParams, RegisterTimings};
use crate::cloud::kdtree::KdIndex;
use crate::cloud::normals::{estimate_normals, Orientation};
use crate::cloud::voxel::voxel_downsample;
use crate::cloud::PointCloud;
use nalgebra::{Point3, Vector3};
use std::time::Instant;

/// The target, prepared once for all models.
pub(super) struct PreparedTarget {
    /// All valid points, and their index.
    pub(super) all: Vec<Point3<f32>>,
    pub(super) all_index: KdIndex,
    /// ICP cloud and its normals (towards the sensor).
    pub(super) icp: Vec<Point3<f32>>,
    pub(super) icp_normals: Vec<Vector3<f32>>,
    /// Scoring subsample and its normals.
    pub(super) score: Vec<Point3<f32>>,
    pub(super) score_normals: Vec<Vector3<f32>>,
    pub(super) feature_points: Vec<Point3<f32>>,
    pub(super) features: Vec<Fpfh>,
    /// Spread subsample of the feature points matched against the models.
    pub(super) match_picks: Vec<usize>,
    pub(super) centroid: Point3<f32>,
    pub(super) extent_m: f64,
    /// The table normal.
    pub(super) up: Vector3<f32>,
    /// Lowest height of the target along `up` (m): model points below it are under
    /// the table's cut and unseen.
    pub(super) floor_m: f32,
    /// The sensor's position.
    pub(super) eye: Point3<f32>,
    /// The target seen from the viewpoint, for the visibility term.
    pub(super) range_image: Option<RangeImage>,
}

/// The target's valid (finite) points; errors when there are none or too few.
fn valid_points(target: &PointCloud, params: &RegisterParams) -> Result<PointCloud, RegisterError> {
    if target.is_empty() {
        return Err(RegisterError::EmptyTarget);
    }
    let valid = voxel_downsample(&PointCloud::from_points(target.points.clone()), 0.0);
    if valid.is_empty() {
        return Err(RegisterError::NoValidPoints {
            total: target.len(),
        });
    }
    if valid.len() < params.min_target_points {
        return Err(RegisterError::TooFewPoints {
            what: "registration".into(),
            got: valid.len(),
            need: params.min_target_points,
        });
    }
    Ok(valid)
}

/// Normals of `points` (indexed by `tree`), oriented towards `viewpoint`.
fn normals_towards(
    points: &[Point3<f32>],
    tree: &KdIndex,
    params: &RegisterParams,
    viewpoint: Point3<f32>,
) -> Vec<Vector3<f32>> {
    estimate_normals(
        points,
        tree,
        params.normal_k,
        params.normal_radius_m as f32,
        Orientation::TowardsViewpoint(viewpoint),
    )
}

/// Prepares `target` (any frame; `params.up` and `params.viewpoint_m` in it),
/// recording the target's stage times in `timings`.
pub(super) fn prepare_target(
    target: &PointCloud,
    params: &RegisterParams,
    timings: &mut RegisterTimings,
) -> Result<PreparedTarget, RegisterError> {
    let t0 = Instant::now();
    let valid = valid_points(target, params)?;
    let icp_cloud = voxel_downsample(&valid, params.icp_voxel_m);
    let feature_cloud = voxel_downsample(&valid, params.feature_voxel_m);
    timings.downsample_ms = ms(t0);
    if feature_cloud.len() < params.min_feature_points {
        return Err(RegisterError::TooFewPoints {
            what: format!(
                "FPFH after downsampling to {} mm",
                params.feature_voxel_m * 1e3
            ),
            got: feature_cloud.len(),
            need: params.min_feature_points,
        });
    }
    let t1 = Instant::now();
    let centroid = centroid(&valid.points);
    let viewpoint = match params.viewpoint_m {
        Some(v) => Point3::from(Vector3::from(v).cast::<f32>()),
        None => centroid + Vector3::from(params.up).normalize().cast::<f32>(),
    };
    let feature_tree = KdIndex::new(&feature_cloud.points);
    let normals = normals_towards(&feature_cloud.points, &feature_tree, params, viewpoint);
    timings.normals_ms = ms(t1);
    let t2 = Instant::now();
    let features = compute_fpfh(
        &feature_cloud.points,
        &normals,
        &feature_tree,
        params.fpfh_radius_m as f32,
    );
    timings.fpfh_ms = ms(t2);
    let t3 = Instant::now();
    let icp_tree = KdIndex::new(&icp_cloud.points);
    let icp_normals = normals_towards(&icp_cloud.points, &icp_tree, params, viewpoint);
    timings.normals_ms += ms(t3);
    // At most `icp_points` for ICP, spread over the cloud.
    let keep = subsample_indices(icp_cloud.len(), params.icp_points);
    let icp_normals: Vec<Vector3<f32>> = keep.iter().map(|&i| icp_normals[i]).collect();
    let icp_points: Vec<Point3<f32>> = keep.iter().map(|&i| icp_cloud.points[i]).collect();
    let picks = subsample_indices(icp_points.len(), params.score_points);
    let up = Vector3::from(params.up).normalize().cast::<f32>();
    let floor_m = valid
        .points
        .iter()
        .map(|p| p.coords.dot(&up))
        .fold(f32::INFINITY, f32::min);
    Ok(PreparedTarget {
        match_picks: subsample_indices(feature_cloud.len(), params.match_points),
        up,
        floor_m,
        eye: viewpoint,
        score_normals: picks.iter().map(|&i| icp_normals[i]).collect(),
        icp_normals,
        extent_m: bbox_diagonal(&valid.points),
        range_image: RangeImage::new(&valid.points, viewpoint, params.range_bin_m as f32),
        score: picks.iter().map(|&i| icp_points[i]).collect(),
        icp: icp_points,
        all_index: KdIndex::new(&valid.points),
        all: valid.points,
        feature_points: feature_cloud.points,
        features,
        centroid,
    })
}

#[cfg(test)]
pub(super) mod tests {
    use super::*;

    /// A half cylinder (the front half seen from +x), radius 4 cm, 10 cm tall, on
    /// the table at z = 0, its axis through the origin.
    pub(in crate::register) fn half_cylinder() -> PointCloud {
        let mut points = Vec::new();
        for i in 0..40 {
            for k in 0..50 {
                let a = -std::f32::consts::FRAC_PI_2 + std::f32::consts::PI * i as f32 / 39.0;
                points.push(Point3::new(
                    0.04 * a.cos(),
                    0.04 * a.sin(),
                    0.002 * k as f32,
                ));
            }
        }
        PointCloud::from_points(points)
    }

    #[test]
    fn bad_targets_are_named_errors() {
        let params = RegisterParams::default();
        let mut timings = RegisterTimings::default();
        let mut prepare = |c: &PointCloud| prepare_target(c, &params, &mut timings).err();
        assert!(matches!(
            prepare(&PointCloud::from_points(Vec::new())),
            Some(RegisterError::EmptyTarget)
        ));
        let nan = PointCloud::from_points(vec![Point3::new(f32::NAN, 0.0, 0.0); 50]);
        assert!(matches!(
            prepare(&nan),
            Some(RegisterError::NoValidPoints { total: 50 })
        ));
        let few = PointCloud::from_points(vec![Point3::origin(); 5]);
        assert!(matches!(
            prepare(&few),
            Some(RegisterError::TooFewPoints {
                got: 5,
                need: 30,
                ..
            })
        ));
        // Enough points, but all in one 5 mm voxel: too few for FPFH.
        let clump = PointCloud::from_points(
            (0..40)
                .map(|i| Point3::new(0.0001 * i as f32, 0.0, 0.0))
                .collect(),
        );
        assert!(matches!(
            prepare(&clump),
            Some(RegisterError::TooFewPoints { need: 10, .. })
        ));
    }

    #[test]
    fn normals_face_the_sensor_and_subsamples_respect_their_limits() {
        let params = RegisterParams {
            viewpoint_m: Some([1.0, 0.0, 0.05]),
            ..RegisterParams::default()
        };
        let mut timings = RegisterTimings::default();
        let t = prepare_target(&half_cylinder(), &params, &mut timings).unwrap();
        assert_eq!(t.all.len(), 2000);
        assert!(t.icp.len() <= params.icp_points && t.icp.len() == t.icp_normals.len());
        assert!(t.score.len() <= params.score_points && t.score.len() == t.score_normals.len());
        assert!(t.match_picks.len() <= params.match_points);
        assert_eq!(t.feature_points.len(), t.features.len());
        let eye = Point3::new(1.0f32, 0.0, 0.05);
        assert_eq!(t.eye, eye);
        assert!(t
            .icp
            .iter()
            .zip(&t.icp_normals)
            .all(|(p, n)| (eye - p).dot(n) > 0.0));
        assert!(t.floor_m.abs() < 1e-6);
        assert!(t.range_image.is_some());
        assert!((t.centroid.z - 0.049).abs() < 1e-3);
    }
}
