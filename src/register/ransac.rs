//! RANSAC over descriptor correspondences, in the spirit of PCL's
//! SampleConsensusPrerejective: three correspondences, rejected unless their edge
//! lengths agree; the rigid fit is scored by how many target points land near the
//! model (the nearest-point field). The best few distinct hypotheses are kept.

use super::icp::rigid_fit;
use super::model::PreparedModel;
use super::points::subsample;
use super::target::PreparedTarget;
use super::RegisterParams;
use crate::geometry::Pose;
use nalgebra::Point3;
use rand::Rng;
use rand_chacha::ChaCha8Rng;

/// Whether two poses differ by more than 5 mm or 5 degrees.
pub(super) fn distinct(a: &Pose, b: &Pose) -> bool {
    let (dp, dr) = crate::geometry::pose_error(a, b);
    dp > 0.005 || dr > 5f64.to_radians()
}

/// RANSAC over descriptor correspondences `pairs`: the best distinct
/// `target_from_model` hypotheses, best first.
pub(super) fn ransac(
    target: &PreparedTarget,
    model: &PreparedModel,
    pairs: &[(usize, usize)],
    params: &RegisterParams,
    rng: &mut ChaCha8Rng,
) -> Vec<Pose> {
    let inlier2 = (params.ransac_inlier_m * params.ransac_inlier_m) as f32;
    let check: Vec<Point3<f32>> = subsample(&target.score, 150);
    let mut best: Vec<(usize, Pose)> = Vec::new();
    if pairs.len() < 3 {
        return Vec::new();
    }
    for _ in 0..params.ransac_iterations {
        let mut pick = [0usize; 3];
        for slot in &mut pick {
            *slot = rng.gen_range(0..pairs.len());
        }
        if pick[0] == pick[1] || pick[1] == pick[2] || pick[0] == pick[2] {
            continue;
        }
        let t: Vec<Point3<f64>> = pick
            .iter()
            .map(|&k| target.feature_points[pairs[k].0].cast::<f64>())
            .collect();
        let m: Vec<Point3<f64>> = pick
            .iter()
            .map(|&k| model.feature_points[pairs[k].1].cast::<f64>())
            .collect();
        // Pre-rejection: corresponding edges must have similar lengths.
        let ok = [(0, 1), (1, 2), (0, 2)].iter().all(|&(a, b)| {
            let dt = (t[a] - t[b]).norm();
            let dm = (m[a] - m[b]).norm();
            dt >= params.min_edge_m && dm.min(dt) >= params.edge_similarity * dm.max(dt)
        });
        if !ok {
            continue;
        }
        let Some(target_from_model) = rigid_fit(&m, &t) else {
            continue;
        };
        let pose = target_from_model.inverse().cast::<f32>();
        let inliers = check
            .iter()
            .filter(|q| {
                let p = pose * *q;
                (model.points[model.lookup.coarse(&p)] - p).norm_squared() <= inlier2
            })
            .count();
        if best.len() == params.hypotheses && inliers <= best[best.len() - 1].0 {
            continue;
        }
        // Replace a near-duplicate that scored lower, or insert.
        if let Some(k) = best
            .iter()
            .position(|(_, b)| !distinct(b, &target_from_model))
        {
            if best[k].0 >= inliers {
                continue;
            }
            best.remove(k);
        }
        let at = best.partition_point(|(c, _)| *c >= inliers);
        best.insert(at, (inliers, target_from_model));
        best.truncate(params.hypotheses);
    }
    best.into_iter().map(|(_, p)| p).collect()
}

#[cfg(test)]
mod tests {
    use super::super::fixture;
    use super::super::matching::correspondences;
    use super::*;
    use nalgebra::{Translation3, UnitQuaternion, Vector3};
    use rand_chacha::rand_core::SeedableRng;

    #[test]
    fn distinct_means_more_than_5_mm_or_5_degrees() {
        let a = Pose::identity();
        assert!(!distinct(&a, &Pose::translation(0.004, 0.0, 0.0)));
        assert!(distinct(&a, &Pose::translation(0.006, 0.0, 0.0)));
        let turn = |deg: f64| Pose::rotation(Vector3::z() * deg.to_radians());
        assert!(!distinct(&a, &turn(4.0)));
        assert!(distinct(&a, &turn(6.0)));
    }

    #[test]
    fn a_hypothesis_lands_near_the_true_pose() {
        let truth = Pose::from_parts(
            Translation3::new(0.02, -0.01, 0.0),
            UnitQuaternion::from_axis_angle(&Vector3::z_axis(), 0.7),
        );
        let (model, target) = fixture::prepared(&truth);
        let params = fixture::params();
        let pairs = correspondences(&target, &model);
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        let hypotheses = ransac(&target, &model, &pairs, &params, &mut rng);
        assert!(!hypotheses.is_empty() && hypotheses.len() <= params.hypotheses);
        for (i, a) in hypotheses.iter().enumerate() {
            assert!(hypotheses[..i].iter().all(|b| distinct(a, b)));
        }
        // Near: the model's centroid within 2 cm of where it belongs (the turn
        // about the axis is the yaw sweep's job).
        let centre = model.centre.cast::<f64>();
        let best = hypotheses
            .iter()
            .map(|h| (h * centre - truth * centre).norm())
            .fold(f64::INFINITY, f64::min);
        assert!(best < 0.02, "nearest hypothesis {best} m off");
        // Too few correspondences: none.
        assert!(ransac(&target, &model, &pairs[..2], &params, &mut rng).is_empty());
    }
}
