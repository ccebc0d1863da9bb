//! The simulated observer: grades an executed grasp as the paper's observer did —
//! success, partial or failure, and a failure's cause — on the object's true mesh at
//! its true pose. Two verdicts are computed for every executed grasp and both are
//! reported; [`ObserverMode`] says which one is the grade.
//!
//! # Physics (the default): does the object come up and stay put?
//! [`crate::sim::physics::lift_test`]: the hand closes at the executed palm pose and
//! spread around the free object on the table (rapier3d), lifts 0.10 m and holds 2 s.
//! Success: the object moved under 1 cm and 10 deg relative to the palm; partial:
//! lifted but slipped or turned more; failure: not lifted, dropped, pushed away, or an
//! open hand that already intersects the object or the table.
//! The test runs three times, at the nominal friction and 10 % below and above it
//! ([`FRICTION_FACTORS`]), and the verdict is the median grade: a grasp that holds
//! only by chance in one of them is not graded by that one run.
//!
//! # Static (`--observer static`, the earlier grading, for comparison)
//! The hand closes (auto-grasp, [`crate::quality::autograsp`]) around the object held
//! fixed, with the table as an obstacle, and the Ferrari–Canny epsilon of the
//! contacts is computed (mu 0.5, 8-edge cones, torque scale the object's radius: the
//! training database's metric). Contacts are counted per hand part (palm, F1, F2, F3),
//! not per contact point.
//! - **success**: force closure with a margin, `epsilon >= `[`SUCCESS_EPSILON`] (0.05).
//! - **partial**: force closure below that margin, or three or more parts touching
//!   without force closure.
//! - **failure**: the open hand collides, fewer than two parts touch (missed), or two
//!   parts touch without force closure (the object would fall).
//!
//! Not executed (unreachable, no registration) or stopped by the executor: failure
//! in both verdicts.
//!
//! # Causes (of anything but a success), with the rule that named them
//! - not planned: the planner's cause ([`CauseRule::Planner`]);
//! - stopped by the executor: execution ([`CauseRule::Executor`]);
//! - executed: registration when the best-fitting model's origin lies more than
//!   [`REGISTRATION_TOLERANCE_M`] (2 cm) from the object's true origin, or its tilt
//!   or yaw ([`crate::geometry::tilt_and_yaw_deg`]) is off by more than
//!   [`REGISTRATION_TOLERANCE_DEG`] (30 deg; the yaw not for a solid of revolution,
//!   a bottle) — the models and objects share the
//!   procedural frame: base centre, z up, a mug's handle along +x; else shape
//!   dissimilarity (the models were in place; their shape misled the grasp).

use crate::config::CellConfig;
use crate::geometry::{tilt_and_yaw_deg, Pose};
use crate::mesh::topology::is_axisymmetric;
use crate::mesh::TriMesh;
use crate::quality::autograsp::{
    evaluate_grasp, retreat_until_clear, AutoGraspOptions, GraspObject, GraspSimError,
};
use crate::quality::QualityParams;
use crate::robot::hand::HandModel;
use crate::robot::{PreshapeRad, RobotError};
use crate::sim::physics::{
    lift_test, LiftOutcome, LiftRule, LiftScene, PhysicsError, PhysicsObject, PhysicsOptions,
    TABLE_GIVE_M,
};
use crate::trial::{FailureCause, Grade};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use std::collections::HashMap;
use std::hash::{Hash, Hasher};
use std::path::Path;
use std::sync::{Arc, Mutex};

/// Epsilon from which a force-closure grasp counts as a success.
pub const SUCCESS_EPSILON: f64 = 0.05;

/// Registration error (m) above which a failed grasp is blamed on registration.
pub const REGISTRATION_TOLERANCE_M: f64 = 0.02;

/// How far (m) an object may depart from a solid of revolution and still have its
/// yaw ignored by the blame ([`is_axisymmetric`]).
const AXISYMMETRY_TOLERANCE_M: f64 = 0.002;

/// Tilt or yaw error (deg) of the best fit above which a failed grasp is blamed on
/// registration.
pub const REGISTRATION_TOLERANCE_DEG: f64 = 30.0;

/// Hand parts (palm, fingers) that must touch the object to hold it at all.
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
    /// The physics simulation failed.
    #[error("observer: physics of {object}: {source}")]
    Physics {
        /// The object.
        object: String,
        /// Why.
        source: PhysicsError,
    },
}

/// Which verdict is the grade.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize, clap::ValueEnum)]
#[serde(rename_all = "snake_case")]
pub enum ObserverMode {
    /// The rigid-body lift test.
    #[default]
    Physics,
    /// Static force closure (Ferrari–Canny epsilon), the earlier grading.
    Static,
}

impl std::fmt::Display for ObserverMode {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            ObserverMode::Physics => "physics",
            ObserverMode::Static => "static",
        })
    }
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
        /// Each finger's flex before closing (rad): the plan's pre-shape.
        preshape_rad: PreshapeRad,
        /// Pose of the best-fitting model (lowest eps), for the cause of a failure.
        best_fit: Option<Pose>,
        /// The executor's error kind when it closed the hand there and then stopped
        /// (it felt too few fingers, or lost them in the hold): the object was not
        /// lifted, so the trial failed whatever the grasp would have done.
        stopped_after_closing: Option<String>,
    },
}

/// The rule that decided a grade.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum GradeRule {
    /// No grasp was executed.
    NotPlanned,
    /// The executor stopped the grasp.
    ExecutionStopped,
    /// Static: the open hand collides with the object or the table.
    StartCollision,
    /// Static: fewer than two hand parts touch.
    Missed,
    /// Static: two hand parts touch without force closure.
    TwoPartsWithoutForceClosure,
    /// Static: three or more parts touch without force closure.
    NoForceClosure,
    /// Static: force closure below [`SUCCESS_EPSILON`].
    BelowMargin,
    /// Static: force closure with the margin.
    ForceClosure,
    /// Physics: the lift test's rule.
    Lift(LiftRule),
}

/// The rule that named a cause.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum CauseRule {
    /// The planner's cause.
    Planner,
    /// The executor stopped.
    Executor,
    /// The best fit's origin is off by more than [`REGISTRATION_TOLERANCE_M`].
    RegistrationOffset,
    /// The best fit's tilt is off by more than [`REGISTRATION_TOLERANCE_DEG`].
    RegistrationTilt,
    /// The best fit's yaw is off by more than [`REGISTRATION_TOLERANCE_DEG`].
    RegistrationYaw,
    /// The models were in place: shape dissimilarity.
    Shape,
}

/// One verdict: the grade, its cause and the rules behind both.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Verdict {
    /// The grade.
    pub grade: Grade,
    /// Why it was not a success (`None` for a success).
    pub cause: Option<FailureCause>,
    /// The rule that decided the grade.
    pub rule: GradeRule,
    /// The rule that named the cause.
    pub cause_rule: Option<CauseRule>,
}

/// How far the best fit was from the object's true pose.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct RegistrationError {
    /// Distance of the origins (m).
    pub offset_m: f64,
    /// Tilt between the z axes (deg).
    pub tilt_deg: f64,
    /// Rotation about the object's z axis (deg).
    pub yaw_deg: f64,
    /// The object is a solid of revolution about its z axis (a bottle): its yaw
    /// does not matter and does not blame the registration.
    pub axisymmetric: bool,
}

impl RegistrationError {
    /// The error of `best_fit` against the true pose of an object that is
    /// `axisymmetric` or not ([`crate::mesh::topology::is_axisymmetric`]).
    pub fn of(best_fit: &Pose, base_from_object: &Pose, axisymmetric: bool) -> RegistrationError {
        let (tilt_deg, yaw_deg) = tilt_and_yaw_deg(base_from_object, best_fit);
        RegistrationError {
            offset_m: (best_fit.translation.vector - base_from_object.translation.vector).norm(),
            tilt_deg,
            yaw_deg,
            axisymmetric,
        }
    }

    /// The cause of a failed executed grasp and the rule that named it.
    pub fn blame(error: Option<&RegistrationError>) -> (FailureCause, CauseRule) {
        match error {
            Some(e) if e.offset_m > REGISTRATION_TOLERANCE_M => {
                (FailureCause::Registration, CauseRule::RegistrationOffset)
            }
            Some(e) if e.tilt_deg > REGISTRATION_TOLERANCE_DEG => {
                (FailureCause::Registration, CauseRule::RegistrationTilt)
            }
            Some(e) if e.yaw_deg > REGISTRATION_TOLERANCE_DEG && !e.axisymmetric => {
                (FailureCause::Registration, CauseRule::RegistrationYaw)
            }
            _ => (FailureCause::ShapeDissimilarity, CauseRule::Shape),
        }
    }
}

/// The observer's verdicts on one trial.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Observation {
    /// Which verdict is the grade.
    pub mode: ObserverMode,
    /// The grade (of `mode`'s verdict).
    pub grade: Grade,
    /// Why it was not a success (`None` for a success).
    pub cause: Option<FailureCause>,
    /// The physics verdict.
    pub physics: Verdict,
    /// The static (epsilon) verdict.
    pub static_epsilon: Verdict,
    /// The lift test's numbers (`None` when nothing was executed).
    pub lift: Option<LiftOutcome>,
    /// Epsilon of the static grasp (0 when not simulated or no force closure).
    pub epsilon: f64,
    /// Hand parts (palm, F1, F2, F3) touching the object in the static grasp.
    pub contacts: usize,
    /// Distance of the best fit's origin from the true origin (m), when known.
    pub registration_error_m: Option<f64>,
    /// The best fit's full error, when known.
    pub registration: Option<RegistrationError>,
    /// One line for the trial log's observer note.
    pub note: String,
}

impl Observation {
    /// The verdict of `mode`.
    pub fn verdict(&self, mode: ObserverMode) -> &Verdict {
        match mode {
            ObserverMode::Physics => &self.physics,
            ObserverMode::Static => &self.static_epsilon,
        }
    }
}

/// The static verdict's grade and rule from the closing simulation.
fn static_rule(collides: bool, parts: usize, force_closure: bool, epsilon: f64) -> GradeRule {
    if collides {
        GradeRule::StartCollision
    } else if parts < HOLDING_CONTACTS {
        GradeRule::Missed
    } else if force_closure && epsilon >= SUCCESS_EPSILON {
        GradeRule::ForceClosure
    } else if force_closure {
        GradeRule::BelowMargin
    } else if parts == HOLDING_CONTACTS {
        GradeRule::TwoPartsWithoutForceClosure
    } else {
        GradeRule::NoForceClosure
    }
}

impl GradeRule {
    /// The grade this rule gives.
    pub fn grade(self) -> Grade {
        match self {
            GradeRule::ForceClosure => Grade::Success,
            GradeRule::BelowMargin | GradeRule::NoForceClosure => Grade::Partial,
            GradeRule::Lift(rule) => rule.grade(),
            _ => Grade::Failure,
        }
    }

    /// A short phrase for notes.
    pub fn phrase(self) -> &'static str {
        match self {
            GradeRule::NotPlanned => "not executed",
            GradeRule::ExecutionStopped => "execution stopped",
            GradeRule::StartCollision => "open hand collides",
            GradeRule::Missed => "missed",
            GradeRule::TwoPartsWithoutForceClosure => "two parts without force closure",
            GradeRule::NoForceClosure => "contacts without force closure",
            GradeRule::BelowMargin => "force closure below the margin",
            GradeRule::ForceClosure => "force closure with margin",
            GradeRule::Lift(LiftRule::Held) => "lifted and held",
            GradeRule::Lift(LiftRule::Slipped) => "lifted but slipped",
            GradeRule::Lift(LiftRule::StartCollision) => "open hand collides",
            GradeRule::Lift(LiftRule::PushedAway) => "pushed away while closing",
            GradeRule::Lift(LiftRule::Dropped) => "dropped during the hold",
            GradeRule::Lift(LiftRule::NotLifted) => "not lifted",
        }
    }
}

impl Verdict {
    /// This verdict of a grasp the executor stopped after closing: a failure, of
    /// the verdict's own cause when the grasp would have failed anyway, else of the
    /// execution.
    fn stopped(self) -> Verdict {
        Verdict {
            grade: Grade::Failure,
            cause: Some(self.cause.unwrap_or(FailureCause::Execution)),
            rule: GradeRule::ExecutionStopped,
            cause_rule: Some(self.cause_rule.unwrap_or(CauseRule::Executor)),
        }
    }
}

/// A verdict from a rule, with the cause of anything but a success.
fn verdict(rule: GradeRule, blame: (FailureCause, CauseRule)) -> Verdict {
    let grade = rule.grade();
    let failed = grade != Grade::Success;
    Verdict {
        grade,
        cause: failed.then_some(blame.0),
        rule,
        cause_rule: failed.then_some(blame.1),
    }
}

/// A key for a mesh's prepared physics object: its name and a hash of its data.
fn mesh_key(object: &str, mesh: &TriMesh) -> u64 {
    let mut h = std::collections::hash_map::DefaultHasher::new();
    object.hash(&mut h);
    for v in &mesh.vertices {
        for c in v.iter() {
            c.to_bits().hash(&mut h);
        }
    }
    mesh.triangles.hash(&mut h);
    h.finish()
}

/// How far into the object a palm may stand and still count as touching it (m):
/// what a guarded approach's stop leaves (a few tenths of a millimetre at the
/// contact threshold, more while braking).
pub const PRESSED_M: f64 = 0.003;

/// The simulated observer of a cell.
#[derive(Debug, Clone)]
pub struct Observer {
    hand: HandModel,
    table_height_m: f64,
    params: QualityParams,
    options: AutoGraspOptions,
    physics: PhysicsOptions,
    mode: ObserverMode,
    /// Prepared physics objects (convex decompositions) by mesh.
    prepared: Arc<Mutex<HashMap<u64, Arc<PhysicsObject>>>>,
    /// The physics verdict's runs, each at the nominal friction times one of these.
    friction_factors: Vec<f64>,
}

/// The physics verdict's runs by default: the lift test at the nominal friction,
/// 10 % below and 10 % above it. The verdict is their median grade. A fingertip
/// grasp near the limits of its hold is chaotic: one run held while the same
/// grasp 10 % less or more slippery dropped; one run would grade it by chance.
pub const FRICTION_FACTORS: [f64; 3] = [1.0, 0.9, 1.1];

/// The index of the run of median grade among `grades` (not empty): the first
/// such, so the nominal run when it has it; of an even count, the better middle.
fn median_run(grades: &[Grade]) -> usize {
    let mut sorted = grades.to_vec();
    sorted.sort_unstable();
    let median = sorted[(sorted.len() - 1) / 2];
    grades.iter().position(|&g| g == median).unwrap_or(0)
}

impl Observer {
    /// The observer of the cell in `config` (hand model and table), grading by physics.
    pub fn new(config: &CellConfig) -> Result<Observer, ObserverError> {
        Ok(Observer::from_hand(
            HandModel::load(config)?,
            config.table.height_m,
        ))
    }

    /// An observer of `hand` over a table at `table_height_m` (base z), grading by
    /// physics with the default options.
    pub fn from_hand(hand: HandModel, table_height_m: f64) -> Observer {
        Observer {
            hand,
            table_height_m,
            params: QualityParams::default(),
            options: AutoGraspOptions::default(),
            physics: PhysicsOptions::default(),
            mode: ObserverMode::default(),
            prepared: Arc::default(),
            friction_factors: FRICTION_FACTORS.to_vec(),
        }
    }

    /// The same observer running the lift test once per factor of the nominal
    /// friction, the verdict their median grade (`[1.0]`: one run).
    pub fn with_friction_factors(mut self, factors: &[f64]) -> Observer {
        if !factors.is_empty() {
            self.friction_factors = factors.to_vec();
        }
        self
    }

    /// The same observer grading by `mode`.
    pub fn with_mode(mut self, mode: ObserverMode) -> Observer {
        self.mode = mode;
        self
    }

    /// The same observer with these physics options (checked at the first grade).
    pub fn with_physics(mut self, options: PhysicsOptions) -> Observer {
        self.physics = options;
        self.prepared = Arc::default();
        self
    }

    /// Which verdict is the grade.
    pub fn mode(&self) -> ObserverMode {
        self.mode
    }

    /// The prepared physics object of `mesh` (decomposed once, then cached).
    fn prepared(&self, object: &str, mesh: &TriMesh) -> Result<Arc<PhysicsObject>, ObserverError> {
        let key = mesh_key(object, mesh);
        if let Some(p) = self.prepared.lock().ok().and_then(|m| m.get(&key).cloned()) {
            return Ok(p);
        }
        let p = Arc::new(
            PhysicsObject::new(mesh, Path::new(object), &self.physics).map_err(|source| {
                ObserverError::Physics {
                    object: object.to_string(),
                    source,
                }
            })?,
        );
        if let Ok(mut m) = self.prepared.lock() {
            m.insert(key, p.clone());
        }
        Ok(p)
    }

    /// Grades `attempt` on the object `mesh` (named `object`) standing upright at
    /// `base_from_object` on the table: both verdicts, the grade of the observer's mode.
    pub fn grade(
        &self,
        object: &str,
        mesh: &TriMesh,
        base_from_object: &Pose,
        attempt: &Attempt,
    ) -> Result<Observation, ObserverError> {
        let (base_from_palm, preshape, best_fit, stopped) = match attempt {
            Attempt::NotPlanned { cause, detail } => {
                return Ok(self.unexecuted(
                    GradeRule::NotPlanned,
                    (*cause, CauseRule::Planner),
                    format!("not executed: {detail}"),
                ))
            }
            Attempt::Stopped { kind } => {
                return Ok(self.unexecuted(
                    GradeRule::ExecutionStopped,
                    (FailureCause::Execution, CauseRule::Executor),
                    format!("execution stopped: {kind}"),
                ))
            }
            Attempt::Executed {
                base_from_palm,
                spread_rad,
                preshape_rad,
                best_fit,
                stopped_after_closing,
            } => (
                base_from_palm,
                preshape_rad.at_spread(*spread_rad),
                best_fit,
                stopped_after_closing,
            ),
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
        // A hand stopped by its guarded approach presses into the surface it
        // touched (the force threshold over the contact stiffness, and the
        // braking): it closes from where it touched, not from inside. Deeper is a
        // start collision.
        let pressed = base_from_object.inverse() * base_from_palm;
        let object_from_palm =
            retreat_until_clear(&self.hand, &grasp_object, &pressed, &preshape, PRESSED_M)
                .unwrap_or(pressed);
        let base_from_palm = &(base_from_object * object_from_palm);
        let evaluation = evaluate_grasp(
            &self.hand,
            &grasp_object,
            &object_from_palm,
            &preshape,
            &self.options,
            &self.params,
            false,
        )
        .map_err(simulation)?;
        let contacts = contact_parts(&self.hand, &evaluation.outcome.contacts);
        let epsilon = evaluation.epsilon;
        let registration = best_fit.as_ref().map(|fit| {
            RegistrationError::of(
                fit,
                base_from_object,
                is_axisymmetric(mesh, AXISYMMETRY_TOLERANCE_M),
            )
        });
        let blame = RegistrationError::blame(registration.as_ref());
        let static_epsilon = verdict(
            static_rule(
                evaluation.outcome.collision_at_start.is_some(),
                contacts,
                evaluation.force_closure,
                epsilon,
            ),
            blame,
        );

        let body = self.prepared(object, mesh)?;
        let scene = LiftScene {
            base_from_object: *base_from_object,
            base_from_palm: *base_from_palm,
            preshape,
            table_height_m: Some(self.table_height_m),
        };
        let runs = self
            .friction_factors
            .par_iter()
            .map(|factor| {
                let options = PhysicsOptions {
                    friction: self.physics.friction * factor,
                    ..self.physics
                };
                lift_test(&self.hand, &body, &scene, &options)
            })
            .collect::<Result<Vec<_>, _>>()
            .map_err(|source| ObserverError::Physics {
                object: object.to_string(),
                source,
            })?;
        let grades: Vec<Grade> = runs.iter().map(|r| r.grade).collect();
        let lift = runs[median_run(&grades)].clone();
        let run_grades = if runs.len() > 1 {
            format!(
                "; median of {} runs at friction x{}: {}",
                runs.len(),
                self.friction_factors
                    .iter()
                    .map(|f| format!("{f}"))
                    .collect::<Vec<_>>()
                    .join("/"),
                grades
                    .iter()
                    .map(|g| format!("{g:?}").to_lowercase())
                    .collect::<Vec<_>>()
                    .join("/")
            )
        } else {
            String::new()
        };
        let physics = verdict(GradeRule::Lift(lift.rule), blame);
        let stopped_note = stopped.as_ref().map_or(String::new(), |kind| {
            format!("execution stopped after closing ({kind}), not lifted; had it been lifted: ")
        });
        let reg = registration.map_or(String::new(), |e| {
            format!(
                "; best fit {:.1} mm, tilt {:.0} deg, yaw {:.0} deg off",
                e.offset_m * 1e3,
                e.tilt_deg,
                e.yaw_deg
            )
        });
        let in_table = if lift.table_penetration_m >= TABLE_GIVE_M {
            format!(
                ", the hand {:.1} mm into the table while closing",
                lift.table_penetration_m * 1e3
            )
        } else {
            String::new()
        };
        let note = format!(
            "{} observer: {stopped_note}physics {:?} ({}: rose {:.0} mm, slip {:.1} mm, turn {:.1} deg, touching {}{in_table}{run_grades});              static {:?} ({}: epsilon {epsilon:.3}, {contacts} parts){reg}",
            self.mode,
            physics.grade,
            physics.rule.phrase(),
            lift.lift_height_m * 1e3,
            lift.slip_m * 1e3,
            lift.turn_rad.to_degrees(),
            if lift.contacts.is_empty() {
                "nothing".to_string()
            } else {
                lift.contacts.join(" ")
            },
            static_epsilon.grade,
            static_epsilon.rule.phrase(),
        );
        // What each verdict says of the trial: a grasp the executor stopped was
        // never lifted; the simulation only names why it failed.
        let (physics, static_epsilon) = match stopped {
            Some(_) => (physics.stopped(), static_epsilon.stopped()),
            None => (physics, static_epsilon),
        };
        let chosen = match self.mode {
            ObserverMode::Physics => physics,
            ObserverMode::Static => static_epsilon,
        };
        Ok(Observation {
            mode: self.mode,
            grade: chosen.grade,
            cause: chosen.cause,
            physics,
            static_epsilon,
            lift: Some(lift),
            epsilon,
            contacts,
            registration_error_m: registration.map(|r| r.offset_m),
            registration,
            note,
        })
    }

    /// The observation of a grasp that was not executed: failure in both verdicts.
    fn unexecuted(
        &self,
        rule: GradeRule,
        blame: (FailureCause, CauseRule),
        note: String,
    ) -> Observation {
        let v = verdict(rule, blame);
        Observation {
            mode: self.mode,
            grade: v.grade,
            cause: v.cause,
            physics: v,
            static_epsilon: v,
            lift: None,
            epsilon: 0.0,
            contacts: 0,
            registration_error_m: None,
            registration: None,
            note,
        }
    }
}

/// Hand parts (palm, F1, F2, F3) with at least one contact.
pub fn contact_parts(
    hand: &HandModel,
    contacts: &[crate::quality::autograsp::LinkContact],
) -> usize {
    let palm = contacts.iter().any(|c| c.link == hand.palm.name);
    let fingers = hand
        .fingers
        .iter()
        .filter(|f| {
            contacts
                .iter()
                .any(|c| c.link == f.proximal.name || c.link == f.distal.name)
        })
        .count();
    usize::from(palm) + fingers
}

/// How often the two verdicts agree: counts of (physics grade, static grade) pairs.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize)]
pub struct Agreement {
    /// `counts[p][s]`: trials graded `p` by physics and `s` by static epsilon, in
    /// the order success, partial, failure.
    pub counts: [[usize; 3]; 3],
    /// Trials with both verdicts.
    pub total: usize,
    /// Trials where they agree.
    pub agree: usize,
}

impl Agreement {
    fn index(grade: Grade) -> usize {
        match grade {
            Grade::Success => 0,
            Grade::Partial => 1,
            Grade::Failure => 2,
        }
    }

    /// Counts one trial.
    pub fn add(&mut self, physics: Grade, statics: Grade) {
        self.counts[Self::index(physics)][Self::index(statics)] += 1;
        self.total += 1;
        self.agree += usize::from(physics == statics);
    }

    /// The matrix as text: rows physics, columns static.
    pub fn to_text(&self) -> String {
        let mut text = format!(
            "verdicts: physics (rows) against static epsilon (columns), {} of {} agree\n{:>18} {:>8} {:>8} {:>8}\n",
            self.agree, self.total, "", "success", "partial", "failure"
        );
        for (name, row) in ["success", "partial", "failure"].iter().zip(&self.counts) {
            text += &format!(
                "{:>18} {:>8} {:>8} {:>8}\n",
                format!("physics {name}"),
                row[0],
                row[1],
                row[2]
            );
        }
        text
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

    /// The best side grasp of the database, its model's index, and where the
    /// model stands on the table.
    fn best_side_grasp(db: &CategoryDb) -> (&crate::category::GraspEntry, usize, Pose) {
        let grasp = db
            .grasps_for("side")
            .max_by(|a, b| a.q.total_cmp(&b.q))
            .unwrap();
        let model = db.model_index(&grasp.model).unwrap();
        (
            grasp,
            model,
            pose_from_params(&[0.6, 0.1, 0.0, 0.0, 0.0, 0.7]),
        )
    }

    #[test]
    fn a_trained_grasp_on_its_own_model_succeeds_and_a_far_one_misses() {
        let (observer, db) = observer();
        // The best side grasp of the database on its own model, placed on the table.
        let (grasp, model, base_from_object) = best_side_grasp(&db);
        let model_from_palm = grasp.pose.to_pose("grasp").unwrap();
        let executed = Attempt::Executed {
            base_from_palm: base_from_object * model_from_palm,
            spread_rad: grasp.spread_rad,
            preshape_rad: grasp.preshape_rad,
            best_fit: Some(base_from_object),
            stopped_after_closing: None,
        };
        let seen = observer
            .grade("model", &db.meshes[model], &base_from_object, &executed)
            .unwrap();
        assert_eq!(seen.mode, ObserverMode::Physics);
        assert_eq!(seen.static_epsilon.grade, Grade::Success, "{seen:?}");
        assert_eq!(seen.static_epsilon.rule, GradeRule::ForceClosure);
        assert!(seen.epsilon >= SUCCESS_EPSILON && seen.static_epsilon.cause.is_none());
        let lift = seen
            .lift
            .as_ref()
            .expect("executed grasps get the lift test");
        assert_eq!(seen.physics.rule, GradeRule::Lift(lift.rule));
        assert_eq!(seen.grade, seen.physics.grade);
        assert!(seen.note.contains("physics") && seen.note.contains("static"));

        // The same grasp 30 cm beside the object: no contact; the fit was 30 cm off.
        let beside = pose_from_params(&[0.0, 0.3, 0.0, 0.0, 0.0, 0.0]);
        let missed = Attempt::Executed {
            base_from_palm: beside * base_from_object * model_from_palm,
            spread_rad: grasp.spread_rad,
            preshape_rad: grasp.preshape_rad,
            best_fit: Some(beside * base_from_object),
            stopped_after_closing: None,
        };
        let seen = observer
            .grade("model", &db.meshes[model], &base_from_object, &missed)
            .unwrap();
        assert_eq!(seen.grade, Grade::Failure);
        assert_eq!(seen.cause, Some(FailureCause::Registration));
        assert_eq!(seen.physics.rule, GradeRule::Lift(LiftRule::NotLifted));
        assert_eq!(seen.static_epsilon.rule, GradeRule::Missed);
        assert_eq!(seen.physics.cause_rule, Some(CauseRule::RegistrationOffset));
        assert!(seen.note.contains("missed"), "{}", seen.note);
        // The static grade of the same trial, from an observer in static mode.
        let statics = observer
            .clone()
            .with_mode(ObserverMode::Static)
            .grade("model", &db.meshes[model], &base_from_object, &missed)
            .unwrap();
        assert_eq!(statics.grade, statics.static_epsilon.grade);

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

    #[test]
    fn a_grasp_the_executor_stopped_after_closing_fails_and_the_simulation_names_why() {
        let (observer, db) = observer();
        let (grasp, model, base_from_object) = best_side_grasp(&db);
        let attempt = |offset: Pose, stopped: Option<&str>| Attempt::Executed {
            base_from_palm: offset * base_from_object * grasp.pose.to_pose("grasp").unwrap(),
            spread_rad: grasp.spread_rad,
            preshape_rad: grasp.preshape_rad,
            best_fit: Some(offset * base_from_object),
            stopped_after_closing: stopped.map(str::to_string),
        };
        let grade = |a: &Attempt| {
            observer
                .grade("model", &db.meshes[model], &base_from_object, a)
                .unwrap()
        };
        // A grasp that holds when lifted, stopped by the executor (it felt one
        // finger): never lifted, a failure of the execution in both verdicts.
        let on_model = Pose::identity();
        assert_eq!(
            grade(&attempt(on_model, None)).static_epsilon.grade,
            Grade::Success
        );
        let seen = grade(&attempt(on_model, Some("no_contact")));
        for v in [&seen.physics, &seen.static_epsilon] {
            assert_eq!(v.grade, Grade::Failure, "{seen:?}");
            assert_eq!(v.rule, GradeRule::ExecutionStopped);
            assert_eq!(v.cause, Some(FailureCause::Execution));
            assert_eq!(v.cause_rule, Some(CauseRule::Executor));
        }
        assert_eq!(
            (seen.grade, seen.cause),
            (Grade::Failure, Some(FailureCause::Execution))
        );
        assert!(
            seen.note.contains("no_contact") && seen.note.contains("static Success"),
            "{}",
            seen.note
        );
        // A grasp that would have failed anyway keeps the simulation's cause.
        let beside = pose_from_params(&[0.0, 0.3, 0.0, 0.0, 0.0, 0.0]);
        let seen = grade(&attempt(beside, Some("no_contact")));
        assert_eq!(
            (seen.grade, seen.cause),
            (Grade::Failure, Some(FailureCause::Registration))
        );
        assert_eq!(seen.physics.cause_rule, Some(CauseRule::RegistrationOffset));
    }

    #[test]
    fn agreement_counts_pairs() {
        let mut a = Agreement::default();
        a.add(Grade::Success, Grade::Failure);
        a.add(Grade::Success, Grade::Success);
        a.add(Grade::Partial, Grade::Failure);
        assert_eq!((a.total, a.agree), (3, 1));
        assert_eq!(a.counts[0], [1, 0, 1]);
        assert_eq!(a.counts[1][2], 1);
        assert!(a.to_text().contains("1 of 3 agree"), "{}", a.to_text());
    }

    #[test]
    fn two_parts_without_force_closure_fail_and_turned_fits_are_blamed_on_registration() {
        assert_eq!(
            static_rule(false, 2, false, 0.0),
            GradeRule::TwoPartsWithoutForceClosure
        );
        assert_eq!(
            GradeRule::TwoPartsWithoutForceClosure.grade(),
            Grade::Failure
        );
        assert_eq!(static_rule(false, 3, false, 0.0).grade(), Grade::Partial);
        assert_eq!(static_rule(false, 1, false, 0.0), GradeRule::Missed);
        assert_eq!(static_rule(false, 3, true, 0.02).grade(), Grade::Partial);
        assert_eq!(static_rule(false, 2, true, 0.08).grade(), Grade::Success);
        let object = pose_from_params(&[0.6, 0.1, 0.0, 0.0, 0.0, 0.3]);
        let blame = |fit: &Pose| {
            RegistrationError::blame(Some(&RegistrationError::of(fit, &object, false)))
        };
        // In place: shape. Turned 40 deg about the vertical (a handle the wrong
        // way): registration by yaw. Tipped 40 deg: by tilt. 3 cm off: by offset.
        assert_eq!(blame(&object).1, CauseRule::Shape);
        let turned = object * pose_from_params(&[0.0, 0.0, 0.0, 0.0, 0.0, 0.7]);
        assert_eq!(
            blame(&turned),
            (FailureCause::Registration, CauseRule::RegistrationYaw)
        );
        let tipped = object * pose_from_params(&[0.0, 0.0, 0.0, 0.7, 0.0, 0.0]);
        assert_eq!(blame(&tipped).1, CauseRule::RegistrationTilt);
        let shifted = pose_from_params(&[0.0, 0.03, 0.0, 0.0, 0.0, 0.0]) * object;
        assert_eq!(blame(&shifted).1, CauseRule::RegistrationOffset);
        // A bottle turned about its axis is the same bottle.
        let bottle = RegistrationError::of(&turned, &object, true);
        assert_eq!(RegistrationError::blame(Some(&bottle)).1, CauseRule::Shape);
        assert_eq!(
            RegistrationError::blame(None).0,
            FailureCause::ShapeDissimilarity
        );
    }

    #[test]
    fn the_physics_verdict_is_the_median_run_the_nominal_one_first() {
        use Grade::{Failure as F, Partial as P, Success as S};
        assert_eq!(median_run(&[S, F, P]), 2);
        assert_eq!(median_run(&[S, S, F]), 0);
        assert_eq!(median_run(&[F, S, S]), 1);
        assert_eq!(median_run(&[F, F, S]), 0);
        assert_eq!(median_run(&[P]), 0);
    }
}
