//! Running a planned grasp in the grasp simulator on the test object at its true
//! pose: the palm pose (base frame) is expressed in the object's frame, the hand
//! approaches along the palm's z until the open hand is clear of the object and the
//! table (as the arm's approach stops at contact), closes (auto-grasp), and the
//! contacts give Ferrari–Canny epsilon.

use crate::geometry::Pose;
use crate::quality::autograsp::{
    evaluate_grasp, retreat_until_clear, AutoGraspOptions, GraspObject, GraspSimError,
};
use crate::quality::QualityParams;
use crate::robot::hand::HandModel;
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
}

/// The result of one simulated grasp.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct SimulatedGrasp {
    /// Ferrari–Canny epsilon (0: not force closure, or the hand collides).
    pub epsilon: f64,
    /// Whether the grasp is force closure.
    pub force_closure: bool,
    /// How far the hand was backed off along its approach axis to clear the object
    /// (m); `None` when even the largest retreat collides.
    pub retreat_m: Option<f64>,
    /// Contacts of the closed hand with the object.
    pub contacts: usize,
}

/// Simulates the palm at `base_from_palm` with `spread_rad` on `test`.
pub fn simulate(
    hand: &HandModel,
    test: &TestObject,
    base_from_palm: &Pose,
    spread_rad: f64,
    setup: &SimSetup,
) -> Result<SimulatedGrasp, GraspSimError> {
    let object_from_palm = test.base_from_object.inverse() * base_from_palm;
    let (lo, hi) = hand.spread_limits_rad;
    let spread_rad = spread_rad.clamp(lo, hi);
    let Some(clear) = retreat_until_clear(
        hand,
        &test.object,
        &object_from_palm,
        spread_rad,
        setup.max_retreat_m,
    ) else {
        return Ok(SimulatedGrasp {
            epsilon: 0.0,
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
        spread_rad,
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
