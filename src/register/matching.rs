//! Features and matching: correspondences between the target's FPFH descriptors
//! (a spread subsample of them) and a model's, nearest neighbours in descriptor
//! space kept when mutual.

use super::fpfh::{mutual_nearest, Fpfh};
use super::model::PreparedModel;
use super::target::PreparedTarget;

/// Correspondences `(target feature index, model feature index)` of a spread
/// subsample of the target's descriptors, kept when mutual (all when fewer than
/// 30 are).
pub(super) fn correspondences(
    target: &PreparedTarget,
    model: &PreparedModel,
) -> Vec<(usize, usize)> {
    let picked: Vec<Fpfh> = target
        .match_picks
        .iter()
        .map(|&i| target.features[i])
        .collect();
    let (forward, backward) = mutual_nearest(&picked, &model.features);
    let mutual: Vec<(usize, usize)> = forward
        .iter()
        .enumerate()
        .filter(|&(i, &j)| backward[j] == i)
        .map(|(i, &j)| (target.match_picks[i], j))
        .collect();
    if mutual.len() >= 30 {
        mutual
    } else {
        forward
            .iter()
            .enumerate()
            .map(|(i, &j)| (target.match_picks[i], j))
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::super::fixture;
    use super::super::points::subsample_indices;
    use super::*;
    use crate::geometry::Pose;

    #[test]
    fn identical_descriptors_pair_with_themselves() {
        let (model, mut target) = fixture::prepared(&Pose::identity());
        target.feature_points = model.feature_points.clone();
        target.features = model.features.clone();
        target.match_picks = subsample_indices(model.features.len(), 300);
        let pairs = correspondences(&target, &model);
        assert_eq!(pairs.len(), target.match_picks.len());
        let own = pairs.iter().filter(|(t, m)| t == m).count();
        assert!(own * 10 >= pairs.len() * 9, "{own} of {}", pairs.len());
    }

    #[test]
    fn a_view_gets_one_model_descriptor_per_pick_or_only_mutual_pairs() {
        let (model, target) = fixture::prepared(&Pose::identity());
        let pairs = correspondences(&target, &model);
        assert!(pairs
            .iter()
            .all(|&(t, m)| target.match_picks.contains(&t) && m < model.features.len()));
        // Fewer than 30 mutual pairs: every pick with its nearest; else the mutual.
        assert!(pairs.len() == target.match_picks.len() || pairs.len() >= 30);
        let mut picks: Vec<usize> = pairs.iter().map(|p| p.0).collect();
        picks.dedup();
        assert_eq!(picks.len(), pairs.len(), "one pair per pick");
    }
}
