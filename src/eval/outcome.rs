//! Running a planned grasp in the grasp simulator on the test object at its true
//! pose: the palm pose (base frame) is expressed in the object's frame, the hand
//! approaches along the palm's z until the open hand is clear of the object and the
//! table (as the arm's approach stops at contact), closes (auto-grasp), and the
//! contacts give Ferrari–Canny epsilon.
//!
//! The paper's scoring ([`SimSetup::paper`], issue 19): no retreat, and a hand that
//! collides at the planned pose scores [`PAPER_COLLISION_EPSILON`] (−1, "unstable"
//! in its Table 1) instead of being backed off.

use crate::geometry::Pose;
use crate::quality::autograsp::{
    evaluate_grasp, retreat_until_clear, AutoGraspOptions, GraspObject, GraspSimError,
};
use crate::quality::QualityParams;
use crate::robot::hand::HandModel;
use crate::robot::HandPose;
use serde::Serialize;

/// The test object as the grasp simulator sees it.
#[derive(Debug, Clone)]
pub struct TestObject {
    /// The object's name (for messages).
    pub name: String,
    /// Mesh, metric reference and, if the category stands on it, the table
    /// (object frame).
    pub object: GraspObject,
    /// The object's true pose in the base frame.
    pub base_from_object: Pose,
}

/// The simulator's settings: closing, metric, and the approach allowance.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SimSetup {
    /// Closing simulation.
    pub closing: AutoGraspOptions,
    /// Quality metric (centroid and torque scale come from each object).
    pub metric: QualityParams,
    /// How far the hand may be backed off along its approach axis to clear the
    /// object (m); farther than that the grasp counts as a collision.
    pub max_retreat_m: f64,
    /// The epsilon a colliding grasp scores: 0 (the cell's setting: not force
    /// closure) or [`PAPER_COLLISION_EPSILON`] (the paper's).
    pub collision_epsilon: f64,
}

/// The score of a colliding grasp in the paper's Table 1: unstable, −1.
pub const PAPER_COLLISION_EPSILON: f64 = -1.0;

impl SimSetup {
    /// The cell's own setting: back off up to `max_retreat_m`, collisions score 0.
    pub fn cell(closing: AutoGraspOptions, metric: QualityParams, max_retreat_m: f64) -> SimSetup {
        SimSetup {
            closing,
            metric,
            max_retreat_m,
            collision_epsilon: 0.0,
        }
    }

    /// The paper's setting: no retreat (the hand closes where it was planned), and
    /// a colliding grasp scores [`PAPER_COLLISION_EPSILON`].
    pub fn paper(closing: AutoGraspOptions, metric: QualityParams) -> SimSetup {
        SimSetup {
            closing,
            metric,
            max_retreat_m: 0.0,
            collision_epsilon: PAPER_COLLISION_EPSILON,
        }
    }
}

/// The result of one simulated grasp.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct SimulatedGrasp {
    /// Ferrari–Canny epsilon (0: not force closure; a colliding hand scores the
    /// setup's `collision_epsilon`, 0 or the paper's −1).
    pub epsilon: f64,
    /// Whether the grasp is force closure.
    pub force_closure: bool,
    /// How far the hand was backed off along its approach axis to clear the object
    /// (m); `None` when even the largest retreat collides.
    pub retreat_m: Option<f64>,
    /// Contacts of the closed hand with the object.
    pub contacts: usize,
}

/// Simulates the palm at `base_from_palm` with the hand's `preshape` (spread and
/// each finger's flex before closing) on `test`.
pub fn simulate(
    hand: &HandModel,
    test: &TestObject,
    base_from_palm: &Pose,
    preshape: &HandPose,
    setup: &SimSetup,
) -> Result<SimulatedGrasp, GraspSimError> {
    let object_from_palm = test.base_from_object.inverse() * base_from_palm;
    let (lo, hi) = hand.spread_limits_rad;
    let preshape = HandPose {
        spread_rad: preshape.spread_rad.clamp(lo, hi),
        ..*preshape
    };
    let Some(clear) = retreat_until_clear(
        hand,
        &test.object,
        &object_from_palm,
        &preshape,
        setup.max_retreat_m,
    ) else {
        return Ok(SimulatedGrasp {
            epsilon: setup.collision_epsilon,
            force_closure: false,
            retreat_m: None,
            contacts: 0,
        });
    };
    let retreat_m = (clear.translation.vector - object_from_palm.translation.vector).norm();
    let e = evaluate_grasp(
        hand,
        &test.object,
        &clear,
        &preshape,
        &setup.closing,
        &setup.metric,
        false,
    )?;
    Ok(SimulatedGrasp {
        epsilon: e.epsilon,
        force_closure: e.force_closure,
        retreat_m: Some(retreat_m),
        contacts: e.outcome.contacts.len(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::category::CategoryDb;
    use crate::config::CellConfig;
    use crate::geometry::pose_from_params;
    use std::path::Path;

    #[test]
    fn paper_scoring_of_a_colliding_grasp_gives_minus_one() {
        let config = CellConfig::load(Path::new("robot/cell.toml")).unwrap();
        let hand = HandModel::load(&config).unwrap();
        let db = CategoryDb::load(Path::new("db/mug")).unwrap();
        let grasp = db
            .grasps_for("side")
            .max_by(|a, b| a.q.total_cmp(&b.q))
            .unwrap();
        let model = db.model_index(&grasp.model).unwrap();
        let base_from_object = pose_from_params(&[0.6, 0.1, 0.0, 0.0, 0.0, 0.7]);
        let object = GraspObject::new(&db.meshes[model], Path::new("mug"))
            .unwrap()
            .with_table(Some(0.0));
        let test = TestObject {
            name: "mug".into(),
            object,
            base_from_object,
        };
        // The trained grasp pushed 3 cm further along its approach axis: the palm
        // is inside the mug.
        let model_from_palm = grasp.pose.to_pose("grasp").unwrap();
        let inside = base_from_object * model_from_palm * Pose::translation(0.0, 0.0, 0.03);
        let closing = db.file.simulation.into();
        let metric = db.file.metric.params();
        let paper = simulate(
            &hand,
            &test,
            &inside,
            &grasp.preshape(),
            &SimSetup::paper(closing, metric),
        )
        .unwrap();
        assert_eq!(paper.epsilon, PAPER_COLLISION_EPSILON, "{paper:?}");
        assert_eq!((paper.retreat_m, paper.force_closure), (None, false));
        // The cell's setting backs the hand off and closes it.
        let cell = simulate(
            &hand,
            &test,
            &inside,
            &grasp.preshape(),
            &SimSetup::cell(closing, metric, 0.05),
        )
        .unwrap();
        let retreat = cell.retreat_m.expect("backed off clear");
        assert!(retreat > 0.0 && retreat <= 0.05, "{cell:?}");
        assert!(cell.epsilon >= 0.0);
        // The trained grasp itself does not collide: the paper scores it as it is.
        let at = simulate(
            &hand,
            &test,
            &(base_from_object * model_from_palm),
            &grasp.preshape(),
            &SimSetup::paper(closing, metric),
        )
        .unwrap();
        assert_eq!(at.retreat_m, Some(0.0));
        assert!(at.epsilon > 0.0, "{at:?}");
    }
}
