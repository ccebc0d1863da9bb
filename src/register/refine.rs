//! The exact ICP stage: the best few candidates of the coarse search refined with
//! near-exact nearest points (the field's answer improved by a walk over the
//! model's neighbour graph) in two passes, the second with a tight rejection
//! distance; the cheapest wins.

use super::icp::{icp, IcpSettings};
use super::model::PreparedModel;
use super::score::candidate_cost;
use super::search::{best_distinct, Candidate};
use super::target::PreparedTarget;
use super::RegisterParams;

/// The exact ICP settings of the first (wide) pass.
fn exact_settings(params: &RegisterParams) -> IcpSettings {
    IcpSettings {
        max_iterations: params.icp_iterations,
        max_distance_m: params.icp_max_distance_m,
        metric: params.icp_metric,
        point_weight: params.icp_point_weight,
        converge_translation_m: 5e-5,
        converge_rotation_rad: 5e-4,
        min_normal_cos: params.icp_min_normal_cos as f32,
    }
}

/// One candidate refined in both passes on the target's ICP cloud, and its cost.
pub(super) fn refine_one(
    target: &PreparedTarget,
    model: &PreparedModel,
    params: &RegisterParams,
    candidate: &Candidate,
) -> Candidate {
    let exact = exact_settings(params);
    let nearest = |p: &nalgebra::Point3<f32>| {
        Some(
            model
                .lookup
                .nearest_within(p, params.icp_max_distance_m as f32)
                .0,
        )
    };
    let run = |start, settings: &IcpSettings| {
        icp(
            &target.icp,
            Some(&target.icp_normals),
            &model.points,
            &model.normals,
            nearest,
            start,
            settings,
        )
    };
    let wide = run(&candidate.model_from_target, &exact);
    // Then with a tight rejection distance, so that sensor artefacts at the
    // silhouette and surface the model lacks do not pull the fit.
    let mut r = run(
        &wide.model_from_target,
        &IcpSettings {
            max_distance_m: params.icp_fine_distance_m,
            ..exact
        },
    );
    r.iterations += wide.iterations;
    let cost = candidate_cost(
        target,
        model,
        params,
        &r.model_from_target,
        &target.icp,
        true,
    );
    tracing::trace!(
        cost,
        target_from_model = ?crate::geometry::params_from_pose(&r.model_from_target.inverse()),
        "refined candidate"
    );
    Candidate {
        model_from_target: r.model_from_target,
        cost,
        iterations: candidate.iterations + r.iterations,
    }
}

/// The best `refine_best` distinct of `candidates` refined exactly; the cheapest
/// (`None` for no candidates).
pub(super) fn refine(
    target: &PreparedTarget,
    model: &PreparedModel,
    params: &RegisterParams,
    candidates: Vec<Candidate>,
) -> Option<Candidate> {
    best_distinct(candidates, params.refine_best)
        .iter()
        .map(|c| refine_one(target, model, params, c))
        .min_by(|a, b| a.cost.total_cmp(&b.cost))
}

#[cfg(test)]
mod tests {
    use super::super::fixture;
    use super::*;
    use crate::geometry::{pose_error, Pose};
    use nalgebra::{Translation3, UnitQuaternion, Vector3};

    #[test]
    fn a_near_start_converges_and_the_cheapest_wins() {
        let truth = Pose::from_parts(
            Translation3::new(0.0, 0.01, 0.0),
            UnitQuaternion::from_axis_angle(&Vector3::z_axis(), -0.5),
        );
        let (model, target) = fixture::prepared(&truth);
        let params = fixture::params();
        // 3 mm and 3 degrees off; and a far-off start with the handle elsewhere.
        let near = Pose::translation(0.003, 0.0, 0.0)
            * truth
            * Pose::rotation(Vector3::z() * 3f64.to_radians());
        let far = truth * Pose::rotation(Vector3::z() * 2.0);
        let start = |pose: Pose, cost| Candidate {
            model_from_target: pose.inverse(),
            cost,
            iterations: 4,
        };
        let best = refine(
            &target,
            &model,
            &params,
            vec![start(far, 0.0), start(near, 1.0)],
        )
        .unwrap();
        let (dp, dr) = pose_error(&best.model_from_target.inverse(), &truth);
        assert!(dp < 0.001 && dr < 1f64.to_radians(), "{dp} m, {dr} rad");
        assert!(best.iterations > 4);
        assert!(refine(&target, &model, &params, Vec::new()).is_none());
    }
}
