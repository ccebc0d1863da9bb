//! Cross-model heading consensus (beyond the paper; off in its setting).
//!
//! A category's models share one canonical frame: upright, and the feature that
//! breaks their symmetry (a mug's handle, a tool's head) toward the same axis. So
//! every model registered onto one object should agree on its heading, the turn of
//! the model's x axis about the table normal. On a partial view a single model
//! can prefer a wrong turn: where its handle and the object's differ, hiding its
//! handle behind the body costs less than matching the object's (the yaw misses of
//! `cell eval loo --views partial`, docs/results.md). When the fits that have a
//! heading (not solids of revolution, not tipped over) agree by most of their
//! weight, each model that dissents is refined again from the agreed heading
//! (turned about the table normal through its own origin; one fitted tipped over,
//! a mug upside down, stood upright around its centroid), and keeps that fit with
//! its own scores, so the planner's fit weights see what it costs.
//!
//! Leaving a model out can change the others' fits through the consensus.

use super::model::PreparedModel;
use super::refine::refine_one;
use super::search::Candidate;
use super::target::PreparedTarget;
use super::{scored, ModelRegistration, ModelStageTimes, RegisterParams, RegistrationStatus};
use crate::geometry::{wrap_angle, Pose};
use nalgebra::{Translation3, Unit, UnitQuaternion, Vector3};
use rayon::prelude::*;
use std::time::Instant;

/// A fit tipped this far (rad) from upright has no heading.
const MAX_TILT_RAD: f64 = 0.5;
/// Share of the weight of the fits with a heading that the agreeing ones must exceed
/// (a near-even split, as of a knife against hammers end to end, is no consensus).
const MAJORITY: f64 = 0.6;
/// Fewest fits with a heading for a consensus.
const MIN_FITS: usize = 3;

/// The frame of headings in the plane normal to `up`: heading 0 along the first
/// axis (x's projection, or y's when `up` is near x), pi/2 along the second.
fn plane_axes(up: &Unit<Vector3<f64>>) -> (Vector3<f64>, Vector3<f64>) {
    let e1 = if up.x.abs() < 0.9 {
        Vector3::x()
    } else {
        Vector3::y()
    };
    let e1 = (e1 - up.into_inner() * e1.dot(up)).normalize();
    (e1, up.cross(&e1))
}

/// The heading (rad) of `target_from_model` about `up`: the turn of the model's x
/// axis, `None` when the model is tipped over.
fn heading(target_from_model: &Pose, up: &Unit<Vector3<f64>>) -> Option<f64> {
    let z = target_from_model.rotation * Vector3::z();
    if z.angle(up) > MAX_TILT_RAD {
        return None;
    }
    let x = target_from_model.rotation * Vector3::x();
    let (e1, e2) = plane_axes(up);
    Some(x.dot(&e2).atan2(x.dot(&e1)))
}

/// The upright orientation (model z along `up`) at `heading_rad`.
fn upright_at(heading_rad: f64, up: &Unit<Vector3<f64>>) -> UnitQuaternion<f64> {
    let (e1, e2) = plane_axes(up);
    let x = e1 * heading_rad.cos() + e2 * heading_rad.sin();
    let y = up.cross(&x);
    UnitQuaternion::from_rotation_matrix(&nalgebra::Rotation3::from_basis_unchecked(&[
        x,
        y,
        up.into_inner(),
    ]))
}

/// The agreed heading of `(heading, weight)` pairs: the weighted circular mean of
/// the largest group within `tolerance_rad` of one of them, when it holds more
/// than [`MAJORITY`] of the weight.
fn agreed(headings: &[(f64, f64)], tolerance_rad: f64) -> Option<f64> {
    let total: f64 = headings.iter().map(|h| h.1).sum();
    if headings.len() < MIN_FITS || total <= 0.0 {
        return None;
    }
    let group = |centre: f64| {
        headings
            .iter()
            .filter(move |(h, _)| wrap_angle(h - centre).abs() <= tolerance_rad)
    };
    let support = |centre: f64| group(centre).map(|h| h.1).sum::<f64>();
    let (best, weight) = headings
        .iter()
        .map(|&(h, _)| (h, support(h)))
        .max_by(|a, b| a.1.total_cmp(&b.1))?;
    if weight <= MAJORITY * total {
        return None;
    }
    let (s, c) = group(best).fold((0.0, 0.0), |(s, c), (h, w)| {
        (s + w * h.sin(), c + w * h.cos())
    });
    Some(s.atan2(c))
}

/// Brings the dissenting fits of `results` (one per entry of `models`, in order)
/// to the agreed heading; see the module documentation.
pub(super) fn agree_on_heading(
    results: &mut [ModelRegistration],
    models: &[Option<&PreparedModel>],
    target: &PreparedTarget,
    params: &RegisterParams,
) {
    let up = Unit::new_normalize(Vector3::from(params.up));
    let tolerance_rad = params.heading_consensus_deg.to_radians();
    let headings: Vec<Option<(f64, f64)>> = results
        .iter()
        .zip(models)
        .map(|(r, m)| {
            let model = (*m)?;
            if r.status != RegistrationStatus::Ok || !model.has_heading {
                return None;
            }
            heading(&r.target_from_model, &up).map(|h| (h, r.inlier_fraction))
        })
        .collect();
    let Some(centre) = agreed(
        &headings.iter().flatten().copied().collect::<Vec<_>>(),
        tolerance_rad,
    ) else {
        return;
    };
    // The dissenters and where each starts again.
    let starts: Vec<(usize, &PreparedModel, Pose)> = results
        .iter()
        .zip(models)
        .zip(&headings)
        .enumerate()
        .filter_map(|(i, ((r, m), h))| {
            let model = m.filter(|m| m.has_heading)?;
            if r.status != RegistrationStatus::Ok {
                return None;
            }
            let start = match h {
                // Upright, turned away: turned back about the table normal through
                // its origin.
                Some((h, _)) => {
                    let turn = wrap_angle(centre - h);
                    if turn.abs() <= tolerance_rad {
                        return None;
                    }
                    let origin = r.target_from_model.translation.vector;
                    Translation3::from(origin)
                        * UnitQuaternion::from_axis_angle(&up, turn)
                        * Translation3::from(-origin)
                        * r.target_from_model
                }
                // Tipped over (a mug fitted upside down): stood upright at the agreed
                // heading, its centroid where the fit put it.
                None => {
                    let centre_m = model.centre.cast::<f64>();
                    let rotation = upright_at(centre, &up);
                    let at = r.target_from_model * centre_m;
                    Pose::from_parts(
                        Translation3::from(at.coords - rotation * centre_m.coords),
                        rotation,
                    )
                }
            };
            tracing::debug!(
                model = %r.model,
                heading_deg = ?h.map(|(h, _)| h.to_degrees()),
                agreed_deg = centre.to_degrees(),
                "heading consensus: refitting from the agreed heading"
            );
            Some((i, model, start))
        })
        .collect();
    let refitted: Vec<(usize, ModelRegistration)> = starts
        .into_par_iter()
        .map(|(i, model, start)| {
            let refined = refine_one(
                target,
                model,
                params,
                &Candidate {
                    model_from_target: start.inverse(),
                    cost: f64::INFINITY,
                    iterations: 0,
                },
            );
            let refit = scored(
                &results[i].model,
                model,
                target,
                params,
                &refined,
                Instant::now(),
                ModelStageTimes::default(),
            );
            (i, refit)
        })
        .collect();
    for (i, r) in refitted {
        let time_ms = results[i].time_ms;
        results[i] = r;
        results[i].time_ms += time_ms;
    }
}

#[cfg(test)]
mod tests {
    use super::super::{fixture, ModelStageTimes};
    use super::*;
    use crate::geometry::pose_error;

    /// A registration at `pose` with finite scores.
    fn ok_fit(pose: Pose) -> ModelRegistration {
        ModelRegistration {
            model: "mug".into(),
            status: RegistrationStatus::Ok,
            target_from_model: pose,
            eps_m2: 1e-5,
            sigma_m2: 1e-5,
            inlier_fraction: 0.9,
            rmse_m: 0.001,
            iterations: 1,
            time_ms: 1.0,
            stages: ModelStageTimes::default(),
        }
    }

    /// Four registrations of the fixture mug (as if of four models): two at the
    /// truth, one turned 150 deg about the table normal, one upside down. The
    /// consensus brings both dissenters back to the truth, and leaves the others.
    #[test]
    fn dissenting_fits_are_refitted_from_the_agreed_heading() {
        let truth = Pose::translation(0.6, 0.05, 0.0) * Pose::rotation(Vector3::z() * 0.7);
        let (model, target) = fixture::prepared(&truth);
        assert!(model.has_heading, "the fixture mug has a handle");
        let params = fixture::params();
        let at = ok_fit;
        let turned = Pose::translation(0.6, 0.05, 0.0)
            * Pose::rotation(Vector3::z() * (0.7 + 150f64.to_radians()));
        let upside_down = Pose::translation(0.6, 0.05, 0.1)
            * Pose::rotation(Vector3::z() * 0.7)
            * Pose::rotation(Vector3::x() * std::f64::consts::PI);
        let mut results = vec![at(truth), at(truth), at(turned), at(upside_down)];
        let models = vec![Some(&model); 4];
        agree_on_heading(&mut results, &models, &target, &params);
        for (i, r) in results.iter().enumerate() {
            let (dp, dr) = pose_error(&r.target_from_model, &truth);
            assert!(dp < 0.005 && dr < 0.1, "fit {i}: {dp} m, {dr} rad");
        }
        assert_eq!(results[0], at(truth), "an agreeing fit is left alone");
        assert!(results[2].time_ms > 1.0 && results[2].eps_m2 < 1e-4);
    }

    /// Without a majority (two against two) nothing changes.
    #[test]
    fn a_split_leaves_every_fit_alone() {
        let truth = Pose::translation(0.6, 0.0, 0.0);
        let (model, target) = fixture::prepared(&truth);
        let params = fixture::params();
        let turned = truth * Pose::rotation(Vector3::z() * 2.5);
        let mut results: Vec<ModelRegistration> = [truth, truth, turned, turned]
            .into_iter()
            .map(ok_fit)
            .collect();
        let before = results.clone();
        agree_on_heading(&mut results, &[Some(&model); 4], &target, &params);
        assert_eq!(results, before);
    }

    #[test]
    fn the_heading_is_the_turn_of_the_x_axis_and_none_when_tipped() {
        let up = Vector3::z_axis();
        let turned = Pose::translation(0.5, 0.1, 0.0) * Pose::rotation(Vector3::z() * 2.0);
        assert!((heading(&turned, &up).unwrap() - 2.0).abs() < 1e-12);
        let tipped = Pose::rotation(Vector3::x() * 1.2);
        assert_eq!(heading(&tipped, &up), None);
    }

    #[test]
    fn upright_at_a_heading_has_that_heading() {
        for up in [
            Vector3::z_axis(),
            Unit::new_normalize(Vector3::new(0.2, -0.1, 1.0)),
        ] {
            for h in [-3.0, -1.0, 0.0, 0.4, 2.5] {
                let pose = Pose::from_parts(Translation3::identity(), upright_at(h, &up));
                let got = heading(&pose, &up).unwrap();
                assert!(wrap_angle(got - h).abs() < 1e-9, "{h} {got}");
                assert!((pose.rotation * Vector3::z() - up.into_inner()).norm() < 1e-9);
            }
        }
    }

    #[test]
    fn a_weighted_majority_agrees_and_a_split_does_not() {
        let tol = 30f64.to_radians();
        // Three near 0.1 rad (one across the wrap at pi is far), one at pi.
        let h = [(0.05, 1.0), (0.15, 1.0), (0.1, 1.0), (3.1, 1.0)];
        let c = agreed(&h, tol).unwrap();
        assert!((c - 0.1).abs() < 1e-9, "{c}");
        // Agreement across the +-pi wrap.
        let h = [(3.1, 1.0), (-3.1, 1.0), (3.0, 1.0), (0.0, 0.5)];
        let c = agreed(&h, tol).unwrap();
        assert!(wrap_angle(c - 3.1).abs() < 0.1, "{c}");
        // Half and half: no consensus; too few fits: none.
        assert_eq!(
            agreed(&[(0.0, 1.0), (0.1, 1.0), (3.0, 1.0), (3.1, 1.0)], tol),
            None
        );
        assert_eq!(agreed(&[(0.0, 1.0), (0.1, 1.0)], tol), None);
    }
}
