//! Hypotheses and the yaw sweep: the coarse search on the nearest-point field.
//!
//! Symmetric objects are not lost to the first local optimum. Seeds: each RANSAC
//! hypothesis, the same flipped upside down, and the model standing upright behind
//! the target. Each seed settles with a few ICP iterations on the field; every
//! distinct placement is then swept about the table normal through the model's
//! centroid (`yaw_steps` turns), each turn refined briefly on the field, and the
//! best few distinct ones refined longer.

use super::icp::{icp, IcpSettings};
use super::model::PreparedModel;
use super::points::subsample_indices;
use super::ransac::distinct;
use super::score::candidate_cost;
use super::target::PreparedTarget;
use super::RegisterParams;
use crate::geometry::{rotation_about, Pose};
use nalgebra::{Point3, Translation3, UnitQuaternion, Vector3};

/// A scored hypothesis `model_from_target`.
#[derive(Debug, Clone, Copy)]
pub(super) struct Candidate {
    pub(super) model_from_target: Pose,
    /// Lower is better.
    pub(super) cost: f64,
    pub(super) iterations: usize,
}

/// The best `n` mutually distinct candidates, best first.
pub(super) fn best_distinct(mut candidates: Vec<Candidate>, n: usize) -> Vec<Candidate> {
    candidates.sort_by(|a, b| a.cost.total_cmp(&b.cost));
    let mut chosen: Vec<Candidate> = Vec::with_capacity(n);
    for cand in candidates {
        if chosen.len() == n {
            break;
        }
        if chosen
            .iter()
            .all(|c| distinct(&c.model_from_target, &cand.model_from_target))
        {
            chosen.push(cand);
        }
    }
    chosen
}

/// The seeds (`target_from_model`) of the candidate search: each RANSAC
/// hypothesis, upright and flipped (a half turn about a horizontal axis through the
/// placed model's centroid), and the model standing upright behind the target's
/// centroid as the sensor sees it.
fn seeds(
    hypotheses: &[Pose],
    target: &PreparedTarget,
    model: &PreparedModel,
    params: &RegisterParams,
) -> Vec<Pose> {
    let up = nalgebra::Unit::new_normalize(Vector3::from(params.up));
    let side = nalgebra::Unit::new_normalize(
        up.cross(&Vector3::x())
            .try_normalize(1e-6)
            .unwrap_or_else(|| up.cross(&Vector3::y())),
    );
    let model_centre = Point3::from(model.centre.coords.cast::<f64>());
    let mut seeds: Vec<Pose> = Vec::with_capacity(2 * hypotheses.len() + 1);
    for h in hypotheses {
        let c = h * model_centre;
        let flip = rotation_about(
            &c.coords,
            UnitQuaternion::from_axis_angle(&side, std::f64::consts::PI),
        );
        seeds.push(*h);
        seeds.push(flip * h);
    }
    // Upright: the model's +z along the table normal, its centroid a quarter of
    // its size behind the target's centroid (a view sees the front half).
    let upright = UnitQuaternion::rotation_between(&Vector3::z(), &up)
        .unwrap_or_else(UnitQuaternion::identity);
    let c_target = target.centroid.coords.cast::<f64>();
    let mut away = c_target - target.eye.coords.cast::<f64>();
    away -= up.into_inner() * away.dot(&up);
    let away = away.try_normalize(1e-9).unwrap_or_else(Vector3::zeros);
    let centre = c_target + away * (0.15 * model.extent_m);
    seeds.push(Pose::from_parts(
        Translation3::from(centre - upright * model_centre.coords),
        upright,
    ));
    seeds
}

/// Whether two placements `target_from_model` differ by no more than a turn about
/// the table normal `up` (and 5 mm, 3 deg): the yaw sweep of one covers the other.
fn same_but_yaw(a: &Pose, b: &Pose, centre: &Point3<f64>, up: &Vector3<f64>) -> bool {
    let tilt = (a.rotation * b.rotation.inverse()) * up;
    (a * centre - b * centre).norm() < 0.005 && tilt.dot(up) > 3f64.to_radians().cos()
}

/// The starting poses (`model_from_target`): each placement `target_from_model`
/// at `yaw_steps` turns about the table normal through the placed model's centroid.
fn yaw_sweep(placements: &[Pose], model: &PreparedModel, params: &RegisterParams) -> Vec<Pose> {
    let up = nalgebra::Unit::new_normalize(Vector3::from(params.up));
    let model_centre = Point3::from(model.centre.coords.cast::<f64>());
    let mut out = Vec::with_capacity(placements.len() * params.yaw_steps);
    for h in placements {
        let c = (h * model_centre).coords;
        for k in 0..params.yaw_steps {
            let angle = std::f64::consts::TAU * k as f64 / params.yaw_steps as f64;
            let rot = UnitQuaternion::from_axis_angle(&up, angle);
            let about_c = rotation_about(&c, rot);
            out.push((about_c * h).inverse());
        }
    }
    out
}

/// The tilt (rad) of a placement `target_from_model`: the angle between the
/// model's +z and the table normal `up`.
pub(super) fn tilt_rad(target_from_model: &Pose, up: &[f64; 3]) -> f64 {
    (target_from_model.rotation * Vector3::z()).angle(&Vector3::from(*up))
}

/// The items whose placement (`target_from_model` of each) is tilted at most
/// [`RegisterParams::max_tilt_deg`] from upright; all of them when none is, or
/// without the limit.
pub(super) fn upright<T>(
    items: Vec<T>,
    params: &RegisterParams,
    placement: impl Fn(&T) -> Pose,
) -> Vec<T> {
    let Some(max_deg) = params.max_tilt_deg else {
        return items;
    };
    let max = max_deg.to_radians();
    if items
        .iter()
        .any(|i| tilt_rad(&placement(i), &params.up) <= max)
    {
        items
            .into_iter()
            .filter(|i| tilt_rad(&placement(i), &params.up) <= max)
            .collect()
    } else {
        items
    }
}

/// Coarse ICP on the model's nearest-point field, scored by the candidate cost.
struct Coarse<'a> {
    target: &'a PreparedTarget,
    model: &'a PreparedModel,
    params: &'a RegisterParams,
}

impl Coarse<'_> {
    /// `iterations` of coarse ICP of `points` (with `normals`) from
    /// `model_from_target`, and the cost of where they end.
    fn run(
        &self,
        start: &Pose,
        iterations: usize,
        points: &[Point3<f32>],
        normals: &[Vector3<f32>],
    ) -> Candidate {
        let params = self.params;
        let settings = IcpSettings {
            max_iterations: iterations,
            max_distance_m: 2.0 * params.icp_max_distance_m,
            metric: params.icp_metric,
            point_weight: params.icp_coarse_point_weight,
            converge_translation_m: 1e-4,
            converge_rotation_rad: 1e-3,
            min_normal_cos: params.icp_min_normal_cos as f32,
        };
        let model = self.model;
        let r = icp(
            points,
            Some(normals),
            &model.points,
            &model.normals,
            |p| Some(model.lookup.coarse(p)),
            start,
            &settings,
        );
        Candidate {
            model_from_target: r.model_from_target,
            cost: candidate_cost(
                self.target,
                model,
                params,
                &r.model_from_target,
                points,
                false,
            ),
            iterations: r.iterations,
        }
    }

    /// Each seed settled on the field (`target_from_model`), seeds that settle to
    /// the same placement up to a turn about the table normal kept once; and the
    /// most iterations a seed took.
    fn settle(
        &self,
        seeds: Vec<Pose>,
        points: &[Point3<f32>],
        normals: &[Vector3<f32>],
    ) -> (Vec<Pose>, usize) {
        let up = Vector3::from(self.params.up).normalize();
        let centre = Point3::from(self.model.centre.coords.cast::<f64>());
        let mut placements: Vec<Pose> = Vec::new();
        let mut most_iterations = 0;
        for seed in seeds {
            let settled = self.run(
                &seed.inverse(),
                self.params.settle_iterations,
                points,
                normals,
            );
            most_iterations = settled.iterations.max(most_iterations);
            let placed = settled.model_from_target.inverse();
            if !placements
                .iter()
                .any(|p| same_but_yaw(p, &placed, &centre, &up))
            {
                placements.push(placed);
            }
        }
        (placements, most_iterations)
    }
}

/// The coarse search from the RANSAC `hypotheses` (`target_from_model`): seeds
/// settled, swept about the table normal on a spread subsample of the scoring
/// points, and the best `polish_best` distinct turns refined further on all of
/// them. The candidates (`model_from_target`), unsorted.
pub(super) fn coarse_search(
    target: &PreparedTarget,
    model: &PreparedModel,
    params: &RegisterParams,
    hypotheses: &[Pose],
) -> Vec<Candidate> {
    let coarse = Coarse {
        target,
        model,
        params,
    };
    let picks = subsample_indices(target.score.len(), params.sweep_points);
    let sweep: Vec<Point3<f32>> = picks.iter().map(|&i| target.score[i]).collect();
    let sweep_normals: Vec<Vector3<f32>> = picks.iter().map(|&i| target.score_normals[i]).collect();
    let (placements, settle_iterations) = coarse.settle(
        seeds(hypotheses, target, model, params),
        &sweep,
        &sweep_normals,
    );
    let placements = upright(placements, params, |p| *p);
    let first: Vec<Candidate> = yaw_sweep(&placements, model, params)
        .iter()
        .map(|s| {
            let mut c = coarse.run(s, params.coarse_iterations, &sweep, &sweep_normals);
            c.iterations += settle_iterations;
            c
        })
        .collect();
    best_distinct(first, params.polish_best)
        .into_iter()
        .map(|c| {
            let mut r = coarse.run(
                &c.model_from_target,
                params.polish_iterations,
                &target.score,
                &target.score_normals,
            );
            r.iterations += c.iterations;
            r
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::super::fixture;
    use super::*;

    fn turned(yaw: f64) -> Pose {
        Pose::from_parts(
            Translation3::new(0.01, 0.02, 0.0),
            UnitQuaternion::from_axis_angle(&Vector3::z_axis(), yaw),
        )
    }

    fn candidate(pose: Pose, cost: f64) -> Candidate {
        Candidate {
            model_from_target: pose,
            cost,
            iterations: 0,
        }
    }

    #[test]
    fn best_distinct_keeps_the_cheapest_of_near_duplicates() {
        let a = Pose::identity();
        let near_a = Pose::translation(0.001, 0.0, 0.0);
        let b = Pose::translation(0.05, 0.0, 0.0);
        let c = Pose::translation(0.1, 0.0, 0.0);
        let chosen = best_distinct(
            vec![
                candidate(near_a, 2.0),
                candidate(c, 3.0),
                candidate(a, 1.0),
                candidate(b, 2.5),
            ],
            2,
        );
        let costs: Vec<f64> = chosen.iter().map(|c| c.cost).collect();
        assert_eq!(costs, [1.0, 2.5]);
    }

    #[test]
    fn the_sweep_turns_each_placement_about_the_vertical_through_its_centre() {
        let params = RegisterParams {
            yaw_steps: 8,
            ..fixture::params()
        };
        let (model, _) = fixture::prepared(&Pose::identity());
        let placement = turned(0.3);
        let starts = yaw_sweep(&[placement], &model, &params);
        assert_eq!(starts.len(), 8);
        let centre = Point3::from(model.centre.coords.cast::<f64>());
        let up = Vector3::z();
        for (k, start) in starts.iter().enumerate() {
            let placed = start.inverse();
            // The centre stays, the axis stays vertical, the turn is k/8 of a turn.
            assert!((placed * centre - placement * centre).norm() < 1e-9);
            assert!(same_but_yaw(&placed, &placement, &centre, &up));
            let turn = placed.rotation * placement.rotation.inverse();
            let angle = turn.scaled_axis().dot(&up);
            let want = crate::geometry::wrap_angle(std::f64::consts::TAU * k as f64 / 8.0);
            assert!(
                (crate::geometry::wrap_angle(angle - want)).abs() < 1e-9,
                "{k}: {angle}"
            );
        }
        // Tilted or moved is not the same up to yaw.
        let tilted = Pose::rotation(Vector3::x() * 0.2) * placement;
        assert!(!same_but_yaw(&tilted, &placement, &centre, &up));
        let moved = Pose::translation(0.01, 0.0, 0.0) * placement;
        assert!(!same_but_yaw(&moved, &placement, &centre, &up));
    }

    #[test]
    fn seeds_are_each_hypothesis_upright_and_flipped_and_one_standing_behind() {
        let (model, target) = fixture::prepared(&Pose::identity());
        let params = fixture::params();
        let h = turned(1.0);
        let s = seeds(&[h], &target, &model, &params);
        assert_eq!(s.len(), 3);
        assert_eq!(s[0], h);
        let centre = Point3::from(model.centre.coords.cast::<f64>());
        // Flipped: the same centre, upside down.
        assert!((s[1] * centre - h * centre).norm() < 1e-9);
        assert!(((s[1].rotation * Vector3::z()).z + 1.0).abs() < 1e-9);
        // Standing: upright, behind the target's centroid as the sensor sees it.
        assert!(((s[2].rotation * Vector3::z()).z - 1.0).abs() < 1e-9);
        let behind = s[2] * centre;
        assert!(behind.x < target.centroid.x as f64);
    }

    #[test]
    fn the_coarse_search_finds_the_true_turn_among_its_candidates() {
        let truth = turned(2.0);
        let (model, target) = fixture::prepared(&truth);
        let params = fixture::params();
        // A hypothesis with the right place but the handle half a turn away.
        let wrong = Pose::from_parts(
            truth.translation,
            UnitQuaternion::from_axis_angle(&Vector3::z_axis(), 2.0 + std::f64::consts::PI),
        );
        let found = coarse_search(&target, &model, &params, &[wrong]);
        assert!(!found.is_empty() && found.len() <= params.polish_best);
        let best = found
            .iter()
            .min_by(|a, b| a.cost.total_cmp(&b.cost))
            .unwrap();
        let (dp, dr) = crate::geometry::pose_error(&best.model_from_target.inverse(), &truth);
        assert!(dp < 0.005 && dr < 5f64.to_radians(), "{dp} m, {dr} rad");
    }

    #[test]
    fn placements_tilted_beyond_the_limit_are_dropped_unless_none_is_upright() {
        let tilted = |deg: f64| {
            Pose::from_parts(
                Translation3::new(0.6, 0.0, 0.05),
                UnitQuaternion::from_axis_angle(&Vector3::x_axis(), deg.to_radians()),
            )
        };
        let params = RegisterParams::default();
        assert_eq!(params.max_tilt_deg, Some(30.0));
        let tilts = |kept: Vec<Pose>| -> Vec<f64> {
            kept.iter()
                .map(|p| tilt_rad(p, &params.up).to_degrees().round())
                .collect()
        };
        let all = vec![tilted(0.0), tilted(175.0), tilted(25.0), tilted(40.0)];
        assert_eq!(tilts(upright(all.clone(), &params, |p| *p)), [0.0, 25.0]);
        // A lying object still registers: nothing upright, nothing dropped.
        let lying = vec![tilted(90.0), tilted(100.0)];
        assert_eq!(tilts(upright(lying, &params, |p| *p)), [90.0, 100.0]);
        // The paper's setting keeps every tilt.
        let paper = params.clone().paper();
        assert_eq!(upright(all.clone(), &paper, |p| *p).len(), 4);
    }
}
