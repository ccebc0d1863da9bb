//! The simulated observer: grades an executed grasp as the paper's observer did —
//! success, partial or failure, and a failure's cause — from the grasp simulator on
//! the object's true mesh at its true pose.
//!
//! # Grading
//! The hand is closed (auto-grasp, [`crate::quality::autograsp`]) at the executed
//! palm pose and spread around the true object, with the table as an obstacle, and
//! the Ferrari–Canny epsilon of the contacts is computed (mu 0.5, 8-edge cones,
//! torque scale the object's radius: the training database's metric).
//!
//! - **success**: force closure with a margin, `epsilon >= `[`SUCCESS_EPSILON`]
//!   (0.05). The training grasps of the mug database have q = 0.09 to 0.28; below
//!   0.05 a grasp resists only a small fraction of the unit wrench ball and a real
//!   hand lifting a real mug would be seen to let it turn or slip.
//! - **partial**: the fingers hold the object (at least two contacts) but without
//!   that margin (force closure below 0.05, or none): lifted, but it moves in the
//!   hand.
//! - **failure**: the open hand collides with the object or the table at the grasp
//!   (it would push the object away), fewer than two fingers touch it (missed), no
//!   plan was executed (unreachable, no registration) or the execution stopped.
//!
//! # Causes
//! - not planned: the planner's cause (reachability, registration);
//! - execution stopped by the executor (its safety layer, a device fault, no
//!   contact, grasp lost): execution;
//! - executed but not a success: registration when the best-fitting model's origin
//!   lies more than [`REGISTRATION_TOLERANCE_M`] (2 cm) from the object's true
//!   origin (the models and objects share the procedural frame: base centre, z up),
//!   else shape dissimilarity (the models were in place; their shape misled the
//!   grasp).

use crate::config::CellConfig;
use crate::geometry::Pose;
use crate::mesh::TriMesh;
use crate::quality::autograsp::{evaluate_grasp, AutoGraspOptions, GraspObject, GraspSimError};
use crate::quality::QualityParams;
use crate::robot::hand::HandModel;
use crate::robot::RobotError;
use crate::trial::{FailureCause, Grade};
use serde::Serialize;
use std::path::Path;

/// Epsilon from which a force-closure grasp counts as a success.
pub const SUCCESS_EPSILON: f64 = 0.05;

/// Registration error (m) above which a failed grasp is blamed on registration.
pub const REGISTRATION_TOLERANCE_M: f64 = 0.02;

/// Contacts needed to hold the object at all.
pub const HOLDING_CONTACTS: usize = 2;

/// Errors of the observer.
#[derive(Debug, thiserror::Error)]
pub enum ObserverError {
    /// The hand model could not be loaded.
    #[error("observer: {0}")]
    Robot(#[from] RobotError),
    /// The grasp simulation failed (e.g. a mesh that is not closed).
    #[error("observer: grasp simulation of {object}: {source}")]
    Simulation {
        /// The object.
        object: String,
        /// Why.
        source: GraspSimError,
    },
}

/// What happened to the trial before the observer looks.
#[derive(Debug, Clone, PartialEq)]
pub enum Attempt {
    /// No grasp was executed: the planner's (or perception's) cause.
    NotPlanned {
        /// The cause.
        cause: FailureCause,
        /// Detail for the note.
        detail: String,
    },
    /// The executor stopped the grasp (error kind of the executor).
    Stopped {
        /// The executor's error kind.
        kind: String,
    },
    /// The grasp sequence ran to the end at this palm pose and spread.
    Executed {
        /// Palm pose when the hand closed (robot base frame).
        base_from_palm: Pose,
        /// Hand spread (rad).
        spread_rad: f64,
        /// Pose of the best-fitting model (lowest eps), for the cause of a failure.
        best_fit: Option<Pose>,
    },
}

/// The observer's verdict.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Observation {
    /// The grade.
    pub grade: Grade,
    /// Why it was not a success (`None` for a success).
    pub cause: Option<FailureCause>,
    /// Epsilon of the simulated grasp (0 when not simulated or no force closure).
    pub epsilon: f64,
    /// Contacts of the simulated grasp.
    pub contacts: usize,
    /// Distance of the best fit's origin from the true origin (m), when known.
    pub registration_error_m: Option<f64>,
    /// One line for the trial log's observer note.
    pub note: String,
}

/// The simulated observer of a cell.
#[derive(Debug, Clone)]
pub struct Observer {
    hand: HandModel,
    table_height_m: f64,
    params: QualityParams,
    options: AutoGraspOptions,
}

impl Observer {
    /// The observer of the cell in `config` (hand model and table).
    pub fn new(config: &CellConfig) -> Result<Observer, ObserverError> {
        Ok(Observer {
            hand: HandModel::load(config)?,
            table_height_m: config.table.height_m,
            params: QualityParams::default(),
            options: AutoGraspOptions::default(),
        })
    }

    /// Grades `attempt` on the object `mesh` (named `object`) standing at
    /// `base_from_object`.
    pub fn grade(
        &self,
        object: &str,
        mesh: &TriMesh,
        base_from_object: &Pose,
        attempt: &Attempt,
    ) -> Result<Observation, ObserverError> {
        let (base_from_palm, spread_rad, best_fit) = match attempt {
            Attempt::NotPlanned { cause, detail } => {
                return Ok(Observation {
                    grade: Grade::Failure,
                    cause: Some(*cause),
                    epsilon: 0.0,
                    contacts: 0,
                    registration_error_m: None,
                    note: format!("not executed: {detail}"),
                })
            }
            Attempt::Stopped { kind } => {
                return Ok(Observation {
                    grade: Grade::Failure,
                    cause: Some(FailureCause::Execution),
                    epsilon: 0.0,
                    contacts: 0,
                    registration_error_m: None,
                    note: format!("execution stopped: {kind}"),
                })
            }
            Attempt::Executed {
                base_from_palm,
                spread_rad,
                best_fit,
            } => (base_from_palm, *spread_rad, best_fit),
        };
        let simulation = |source| ObserverError::Simulation {
            object: object.to_string(),
            source,
        };
        // The table top in the object frame: below its origin by the object's height
        // above the table (objects stand upright in the cell).
        let table_in_object = self.table_height_m - base_from_object.translation.vector.z;
        let grasp_object = GraspObject::new(mesh, Path::new(object))
            .map_err(simulation)?
            .with_table(Some(table_in_object));
        let object_from_palm = base_from_object.inverse() * base_from_palm;
        let evaluation = evaluate_grasp(
            &self.hand,
            &grasp_object,
            &object_from_palm,
            spread_rad,
            &self.options,
            &self.params,
            false,
        )
        .map_err(simulation)?;
        let contacts = evaluation.outcome.contacts.len();
        let epsilon = evaluation.epsilon;
        let registration_error_m = best_fit
            .as_ref()
            .map(|fit| (fit.translation.vector - base_from_object.translation.vector).norm());
        let blame = || match registration_error_m {
            Some(e) if e > REGISTRATION_TOLERANCE_M => FailureCause::Registration,
            _ => FailureCause::ShapeDissimilarity,
        };
        let (grade, cause, what) = if let Some(collision) = &evaluation.outcome.collision_at_start {
            (
                Grade::Failure,
                Some(blame()),
                format!("open hand collides ({collision:?})"),
            )
        } else if contacts < HOLDING_CONTACTS {
            (
                Grade::Failure,
                Some(blame()),
                format!("missed: {contacts} contact(s)"),
            )
        } else if evaluation.force_closure && epsilon >= SUCCESS_EPSILON {
            (
                Grade::Success,
                None,
                "force closure with margin".to_string(),
            )
        } else if evaluation.force_closure {
            (
                Grade::Partial,
                Some(blame()),
                format!("force closure below the {SUCCESS_EPSILON} margin"),
            )
        } else {
            (
                Grade::Partial,
                Some(blame()),
                "contacts without force closure".to_string(),
            )
        };
        let reg = registration_error_m.map_or(String::new(), |e| {
            format!(", best fit {:.1} mm off", e * 1e3)
        });
        Ok(Observation {
            grade,
            cause,
            epsilon,
            contacts,
            registration_error_m,
            note: format!(
                "simulated observer: {what} (epsilon {epsilon:.3}, {contacts} contacts{reg})"
            ),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::category::CategoryDb;
    use crate::geometry::pose_from_params;

    fn observer() -> (Observer, CategoryDb) {
        let config = CellConfig::load(Path::new("robot/cell.toml")).unwrap();
        let db = CategoryDb::load(Path::new("db/mug")).unwrap();
        (Observer::new(&config).unwrap(), db)
    }

    #[test]
    fn a_trained_grasp_on_its_own_model_succeeds_and_a_far_one_misses() {
        let (observer, db) = observer();
        // The best side grasp of the database on its own model, placed on the table.
        let grasp = db
            .grasps_for("side")
            .max_by(|a, b| a.q.total_cmp(&b.q))
            .unwrap();
        let model = db.model_index(&grasp.model).unwrap();
        let base_from_object = pose_from_params(&[0.6, 0.1, 0.0, 0.0, 0.0, 0.7]);
        let model_from_palm = grasp.pose.to_pose("grasp").unwrap();
        let executed = Attempt::Executed {
            base_from_palm: base_from_object * model_from_palm,
            spread_rad: grasp.spread_rad,
            best_fit: Some(base_from_object),
        };
        let seen = observer
            .grade("model", &db.meshes[model], &base_from_object, &executed)
            .unwrap();
        assert_eq!(seen.grade, Grade::Success, "{seen:?}");
        assert!(seen.epsilon >= SUCCESS_EPSILON && seen.cause.is_none());

        // The same grasp 30 cm beside the object: no contact; the fit was 30 cm off.
        let beside = pose_from_params(&[0.0, 0.3, 0.0, 0.0, 0.0, 0.0]);
        let missed = Attempt::Executed {
            base_from_palm: beside * base_from_object * model_from_palm,
            spread_rad: grasp.spread_rad,
            best_fit: Some(beside * base_from_object),
        };
        let seen = observer
            .grade("model", &db.meshes[model], &base_from_object, &missed)
            .unwrap();
        assert_eq!(seen.grade, Grade::Failure);
        assert_eq!(seen.cause, Some(FailureCause::Registration));
        assert!(seen.note.contains("missed"), "{}", seen.note);

        let stopped = observer
            .grade(
                "model",
                &db.meshes[model],
                &base_from_object,
                &Attempt::Stopped {
                    kind: "unsafe_motion".into(),
                },
            )
            .unwrap();
        assert_eq!(
            (stopped.grade, stopped.cause),
            (Grade::Failure, Some(FailureCause::Execution))
        );
    }
}
