//! Auto-grasp of the BH8-282, as GraspIt!'s: the palm is placed at a pose relative
//! to the object, the spread is set, and every finger closes from its pre-shape.
//!
//! The pre-shape ([`HandPose`]: the spread and each finger's flex before the hand
//! closes) is the open hand ([`HandPose::open`], every flex at its lower limit) unless
//! a grasp names one: a flat tool on a table needs its fingers partly closed before
//! the approach, or the open fingers meet the table first. The BH8-282 positions each
//! finger's puck on its own, so each finger has its own flex; its distal link is
//! coupled (the hand reaches the pre-shape by moving freely).
//!
//! Each finger's flex joint advances from its pre-shape in steps of
//! [`AutoGraspOptions::step_rad`] (the steps are short enough that a link, 21 mm thick
//! in its direction of motion, cannot pass through a surface between two of them);
//! when a link would intersect the object or the table, the angle is bisected down
//! to [`AutoGraspOptions::tolerance_rad`] and the finger stops there, just short of
//! contact. A proximal link that meets resistance stops and holds while its distal
//! link keeps closing (the TorqueSwitch breakaway) until it too is blocked or reaches
//! its limit; a distal link that is blocked first stops the whole finger. Fingers do
//! not see each other (the object is fixed, so the order of closing does not matter).
//!
//! A hand that already intersects the object (or the table) in its pre-shape,
//! or whose palm or links sit inside the closed object, is an invalid start and is
//! reported as such. After closing, every link within
//! [`AutoGraspOptions::contact_distance_m`] of the object contributes contacts: the
//! nearest point of each nearby triangle, merged within
//! [`AutoGraspOptions::merge_distance_m`] per link, with the inward surface normal
//! (from the link into the object). Contacts with the table carry no load in the
//! quality metric and are not reported.

use super::{Contact, GraspQuality, QualityError, QualityParams};
use crate::geometry::Pose;
use crate::mesh::{MeshError, TriMesh};
use crate::robot::hand::{Finger, HandLink, HandModel};
use crate::robot::HandPose;
use nalgebra::{Point3, Vector3};
use parry3d_f64::bounding_volume::BoundingVolume;
use parry3d_f64::query::{DefaultQueryDispatcher, QueryDispatcher};
use parry3d_f64::shape::TriMeshFlags;
use serde::Serialize;
use std::path::Path;

/// Errors of setting up or running a grasp simulation.
#[derive(Debug, thiserror::Error)]
pub enum GraspSimError {
    /// The object mesh is unusable.
    #[error(transparent)]
    Mesh(#[from] MeshError),
    /// The object mesh encloses no volume (open, inside-out or flat).
    #[error("{path}: the mesh encloses no volume ({volume_m3} m^3); a grasp needs a closed, outward mesh")]
    NoVolume {
        /// The mesh file (or a description of its source).
        path: String,
        /// The signed volume (m^3).
        volume_m3: f64,
    },
    /// The spread is outside the joint's range.
    #[error("spread {spread_rad} rad is outside the joint range [{lower_rad}, {upper_rad}] rad")]
    Spread {
        /// The spread asked for (rad).
        spread_rad: f64,
        /// Lower limit (rad).
        lower_rad: f64,
        /// Upper limit (rad).
        upper_rad: f64,
    },
    /// A finger's pre-shape flex is outside the joint's range (or not finite).
    #[error("pre-shape flex of finger F{finger} {flex_rad} rad is outside the joint range [{lower_rad}, {upper_rad}] rad")]
    Preshape {
        /// The finger, 1..3.
        finger: usize,
        /// The flex asked for (rad).
        flex_rad: f64,
        /// Lower limit (rad).
        lower_rad: f64,
        /// Upper limit (rad).
        upper_rad: f64,
    },
    /// The palm pose has a NaN or infinite component.
    #[error("palm pose is not finite: {pose}")]
    Pose {
        /// The pose, printed.
        pose: String,
    },
    /// An option is out of range.
    #[error("auto-grasp option {field} = {value}: {problem}")]
    Option {
        /// The option.
        field: &'static str,
        /// Its value.
        value: f64,
        /// What is wrong.
        problem: &'static str,
    },
    /// The quality metric rejected its inputs.
    #[error(transparent)]
    Quality(#[from] QualityError),
}

/// An object to grasp: its mesh with a BVH, the reference point and torque scale of
/// the quality metric, and optionally the table it stands on. Clones share the mesh.
#[derive(Clone)]
pub struct GraspObject {
    mesh: std::sync::Arc<parry3d_f64::shape::TriMesh>,
    /// Centroid of the enclosed volume (object frame, m): the torque reference.
    pub centroid: Point3<f64>,
    /// Largest distance from the centroid to a vertex (m): the torque scale r.
    pub torque_scale_m: f64,
    /// Height of the table top in the object frame (m), if the table is an obstacle.
    pub table_height_m: Option<f64>,
}

impl std::fmt::Debug for GraspObject {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("GraspObject")
            .field("triangles", &self.mesh.indices().len())
            .field("centroid", &self.centroid)
            .field("torque_scale_m", &self.torque_scale_m)
            .field("table_height_m", &self.table_height_m)
            .finish()
    }
}

impl GraspObject {
    /// Prepares a closed, outward mesh (object frame); `source` names it in errors.
    pub fn new(mesh: &TriMesh, source: &Path) -> Result<GraspObject, GraspSimError> {
        let mut parry = mesh.to_parry(source)?;
        // Pseudo-normals let point queries tell inside from outside.
        parry
            .set_flags(TriMeshFlags::ORIENTED)
            .map_err(|e| MeshError::Parse {
                path: source.to_path_buf(),
                location: "mesh".into(),
                problem: format!("cannot orient the mesh: {e:?}"),
            })?;
        let (volume, moment) = (0..mesh.triangles.len()).fold(
            (0.0, Vector3::zeros()),
            |(v, m): (f64, Vector3<f64>), i| {
                let [a, b, c] = mesh.corners(i);
                let six_v = a.coords.dot(&b.coords.cross(&c.coords));
                (v + six_v, m + (a.coords + b.coords + c.coords) * six_v)
            },
        );
        if !(volume > 0.0 && volume.is_finite()) {
            return Err(GraspSimError::NoVolume {
                path: source.display().to_string(),
                volume_m3: volume / 6.0,
            });
        }
        let centroid = Point3::from(moment / (4.0 * volume));
        let torque_scale_m = mesh
            .vertices
            .iter()
            .map(|v| (v - centroid).norm())
            .fold(0.0, f64::max);
        Ok(GraspObject {
            mesh: std::sync::Arc::new(parry),
            centroid,
            torque_scale_m,
            table_height_m: None,
        })
    }

    /// The same object standing on a table whose top is at `height_m` (object frame z).
    pub fn with_table(mut self, height_m: Option<f64>) -> GraspObject {
        self.table_height_m = height_m;
        self
    }

    /// The metric's parameters for this object: `base` with the centroid and torque
    /// scale filled in.
    pub fn quality_params(&self, base: &QualityParams) -> QualityParams {
        QualityParams {
            centroid: Some(self.centroid),
            torque_scale_m: Some(self.torque_scale_m),
            ..*base
        }
    }

    /// Whether `point` (object frame) is inside the closed mesh.
    pub fn contains(&self, point: &Point3<f64>) -> bool {
        use parry3d_f64::query::PointQuery;
        // Outside the bounding box is outside, without a nearest-point search.
        self.mesh.local_aabb().contains_local_point(point) && self.mesh.contains_local_point(point)
    }

    /// The outward unit surface normal at `point` on triangle `id` (`triangle`):
    /// the face normal inside the face, the pseudo-normal on an edge or a vertex.
    pub fn surface_normal(
        &self,
        id: u32,
        triangle: &parry3d_f64::shape::Triangle,
        point: &Point3<f64>,
    ) -> Option<Vector3<f64>> {
        use parry3d_f64::query::PointQueryWithLocation;
        use parry3d_f64::shape::TrianglePointLocation;
        let (_, location) = triangle.project_local_point_and_get_location(point, false);
        let pseudo = self.mesh.pseudo_normals();
        let n = match (location, pseudo) {
            (TrianglePointLocation::OnEdge(i, _), Some(p)) => p
                .edges_pseudo_normal
                .get(id as usize)
                .map(|e| e[i as usize]),
            (TrianglePointLocation::OnVertex(i), Some(p)) => {
                let v = self.mesh.indices()[id as usize][i as usize];
                p.vertices_pseudo_normal.get(v as usize).copied()
            }
            _ => Some(triangle.scaled_normal()),
        }?;
        let norm = n.norm();
        (norm > 0.0 && norm.is_finite()).then(|| n / norm)
    }

    /// The parry mesh (object frame).
    pub fn mesh(&self) -> &parry3d_f64::shape::TriMesh {
        &self.mesh
    }
}

/// Tuning of the closing simulation.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct AutoGraspOptions {
    /// Joint step while closing (rad); 0.04 rad moves a fingertip about 5 mm.
    pub step_rad: f64,
    /// Bisection ends when the bracket is this narrow (rad).
    pub tolerance_rad: f64,
    /// A link this close to the object is in contact (m).
    pub contact_distance_m: f64,
    /// Contacts of one link closer than this are merged into the nearest (m).
    pub merge_distance_m: f64,
}

impl Default for AutoGraspOptions {
    fn default() -> Self {
        AutoGraspOptions {
            step_rad: 0.04,
            tolerance_rad: 1e-4,
            contact_distance_m: 5e-4,
            merge_distance_m: 0.01,
        }
    }
}

impl AutoGraspOptions {
    /// Checks the ranges.
    pub fn validate(&self) -> Result<(), GraspSimError> {
        let check = |field, value: f64, ok: bool, problem| {
            if ok && value.is_finite() {
                Ok(())
            } else {
                Err(GraspSimError::Option {
                    field,
                    value,
                    problem,
                })
            }
        };
        check(
            "step_rad",
            self.step_rad,
            self.step_rad > 0.0 && self.step_rad <= 0.1,
            "must be in (0, 0.1] rad so links cannot pass through a surface",
        )?;
        check(
            "tolerance_rad",
            self.tolerance_rad,
            self.tolerance_rad > 0.0 && self.tolerance_rad < self.step_rad,
            "must be > 0 and below step_rad",
        )?;
        check(
            "contact_distance_m",
            self.contact_distance_m,
            self.contact_distance_m > 0.0,
            "must be > 0",
        )?;
        check(
            "merge_distance_m",
            self.merge_distance_m,
            self.merge_distance_m >= 0.0,
            "must be >= 0",
        )
    }
}

/// What a link ran into.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Obstacle {
    /// The object's surface.
    Object,
    /// The object's inside: the link (or palm) sits within the closed mesh.
    InsideObject,
    /// The table.
    Table,
}

/// Where the open hand already collides.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct StartCollision {
    /// The first link found colliding.
    pub link: String,
    /// What it collides with.
    pub with: Obstacle,
}

impl std::fmt::Display for StartCollision {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let what = match self.with {
            Obstacle::Object => "intersects the object",
            Obstacle::InsideObject => "is inside the object",
            Obstacle::Table => "intersects the table",
        };
        write!(f, "link {} {what} in the open hand", self.link)
    }
}

/// Why a finger stopped.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum FingerStop {
    /// Both links reached their limits.
    Limit,
    /// The distal link was blocked before the proximal one.
    DistalBlocked,
    /// The proximal link was blocked; the distal closed on until blocked.
    BreakawayDistalBlocked,
    /// The proximal link was blocked; the distal reached its limit.
    BreakawayDistalLimit,
}

/// A contact between a hand link and the object (object frame).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct LinkContact {
    /// The hand link.
    pub link: String,
    /// The contact point on the object's surface (m).
    pub point: Point3<f64>,
    /// The inward surface normal (unit, pointing into the object).
    pub normal: Vector3<f64>,
    /// Distance between link and surface there (m).
    pub distance_m: f64,
}

impl LinkContact {
    /// The contact as the quality metric takes it.
    pub fn contact(&self) -> Contact {
        Contact {
            point: self.point,
            normal: self.normal,
        }
    }
}

/// The state of the hand after auto-grasp.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct GraspOutcome {
    /// Set when the open hand collides: nothing was closed, no contacts.
    pub collision_at_start: Option<StartCollision>,
    /// Final spread and flex angles (rad).
    pub hand: HandPose,
    /// Final distal joint angles (rad), F1 F2 F3.
    pub distal_rad: [f64; 3],
    /// Why each finger stopped.
    pub stops: [FingerStop; 3],
    /// Contacts with the object.
    pub contacts: Vec<LinkContact>,
}

impl GraspOutcome {
    /// The contacts as the quality metric takes them.
    pub fn metric_contacts(&self) -> Vec<Contact> {
        self.contacts.iter().map(LinkContact::contact).collect()
    }
}

/// Checks a pre-shape against the hand's joint ranges: the spread and each
/// finger's flex.
pub fn validate_preshape(hand: &HandModel, preshape: &HandPose) -> Result<(), GraspSimError> {
    let (lower_rad, upper_rad) = hand.spread_limits_rad;
    let spread_rad = preshape.spread_rad;
    if !(spread_rad >= lower_rad && spread_rad <= upper_rad) {
        return Err(GraspSimError::Spread {
            spread_rad,
            lower_rad,
            upper_rad,
        });
    }
    for (i, (f, &flex_rad)) in hand.fingers.iter().zip(&preshape.flex_rad).enumerate() {
        let (lower_rad, upper_rad) = f.flex_limits_rad;
        if !(flex_rad >= lower_rad && flex_rad <= upper_rad) {
            return Err(GraspSimError::Preshape {
                finger: i + 1,
                flex_rad,
                lower_rad,
                upper_rad,
            });
        }
    }
    Ok(())
}

/// Closes the hand at `object_from_palm` around `object` from `preshape` (its
/// spread, and each finger's flex at the start; [`HandPose::open`] for the open
/// hand).
pub fn close_hand(
    hand: &HandModel,
    object: &GraspObject,
    object_from_palm: &Pose,
    preshape: &HandPose,
    options: &AutoGraspOptions,
) -> Result<GraspOutcome, GraspSimError> {
    options.validate()?;
    validate_preshape(hand, preshape)?;
    let spread_rad = preshape.spread_rad;
    let finite = object_from_palm
        .translation
        .vector
        .iter()
        .all(|v| v.is_finite())
        && object_from_palm
            .rotation
            .coords
            .iter()
            .all(|v| v.is_finite());
    if !finite {
        return Err(GraspSimError::Pose {
            pose: format!("{object_from_palm:?}"),
        });
    }
    let sim = Sim {
        object,
        options,
        dispatcher: DefaultQueryDispatcher,
    };
    let bases: Vec<Pose> = hand
        .fingers
        .iter()
        .map(|f| object_from_palm * f.palm_from_flex_base(spread_rad))
        .collect();
    let mut outcome = GraspOutcome {
        collision_at_start: None,
        hand: HandPose {
            spread_rad,
            flex_rad: [0.0; 3],
        },
        distal_rad: [0.0; 3],
        stops: [FingerStop::Limit; 3],
        contacts: Vec::new(),
    };
    for (i, f) in hand.fingers.iter().enumerate() {
        let start = start_flex(f, preshape.flex_rad[i]);
        outcome.hand.flex_rad[i] = start;
        outcome.distal_rad[i] = f.coupled_distal_rad(start);
    }
    if let Some(c) = open_hand_collision(hand, object, object_from_palm, preshape) {
        outcome.collision_at_start = Some(c);
        return Ok(outcome);
    }
    let mut final_links = vec![(&hand.palm, *object_from_palm)];
    for (i, f) in hand.fingers.iter().enumerate() {
        let start = start_flex(f, preshape.flex_rad[i]);
        let (flex, distal, stop) = sim.close_finger(f, &bases[i], start);
        outcome.hand.flex_rad[i] = flex;
        outcome.distal_rad[i] = distal;
        outcome.stops[i] = stop;
        let (p, d) = f.link_poses_from_base(&bases[i], flex, distal);
        final_links.push((&f.proximal, p));
        final_links.push((&f.distal, d));
    }
    for (link, pose) in final_links {
        sim.contacts_of(link, &pose, &mut outcome.contacts);
    }
    Ok(outcome)
}

/// A finger's flex at the start of closing: the pre-shape's, never below the
/// joint's lower limit (so the open pre-shape, flex 0, is the lower limit).
fn start_flex(finger: &Finger, preshape_flex_rad: f64) -> f64 {
    let (lo, hi) = finger.flex_limits_rad;
    preshape_flex_rad.clamp(lo, hi)
}

/// The links of the hand in `preshape` (each finger at its pre-shape flex, distal
/// links coupled) with `object_from_palm`: palm, then each finger's proximal and
/// distal link.
fn open_hand_links<'h>(
    hand: &'h HandModel,
    object_from_palm: &Pose,
    preshape: &HandPose,
) -> Vec<(&'h HandLink, Pose)> {
    let mut links: Vec<(&HandLink, Pose)> = vec![(&hand.palm, *object_from_palm)];
    for (f, &flex) in hand.fingers.iter().zip(&preshape.flex_rad) {
        let base = object_from_palm * f.palm_from_flex_base(preshape.spread_rad);
        let lo = start_flex(f, flex);
        let (p, d) = f.link_poses_from_base(&base, lo, f.coupled_distal_rad(lo));
        links.push((&f.proximal, p));
        links.push((&f.distal, d));
    }
    links
}

/// The first collision of the hand in its pre-shape (the open hand of
/// [`HandPose::open`]: fingers at their lower flex limits) at `object_from_palm`
/// with the object or the table, or the palm inside the object.
pub fn open_hand_collision(
    hand: &HandModel,
    object: &GraspObject,
    object_from_palm: &Pose,
    preshape: &HandPose,
) -> Option<StartCollision> {
    let options = AutoGraspOptions::default();
    let sim = Sim {
        object,
        options: &options,
        dispatcher: DefaultQueryDispatcher,
    };
    open_hand_links(hand, object_from_palm, preshape)
        .into_iter()
        .find_map(|(link, pose)| {
            sim.hits(link, &pose).map(|with| StartCollision {
                link: link.name.clone(),
                with,
            })
        })
        .or_else(|| {
            // A hand clear of the surface may still be inside a closed object (a
            // link wholly inside is joined to the palm through the surface, which
            // the links would cross): the palm's shape centres tell.
            hand.palm
                .shapes
                .iter()
                .any(|(local, _)| {
                    object.contains(&Point3::from((object_from_palm * local).translation.vector))
                })
                .then(|| StartCollision {
                    link: hand.palm.name.clone(),
                    with: Obstacle::InsideObject,
                })
        })
}

/// True when every link of the hand in `preshape` at `object_from_palm` is
/// provably farther than `margin_m` from the object and the table (conservative:
/// false may still be clear).
pub fn open_hand_clear_by(
    hand: &HandModel,
    object: &GraspObject,
    object_from_palm: &Pose,
    preshape: &HandPose,
    margin_m: f64,
) -> bool {
    let options = AutoGraspOptions::default();
    let sim = Sim {
        object,
        options: &options,
        dispatcher: DefaultQueryDispatcher,
    };
    open_hand_links(hand, object_from_palm, preshape)
        .iter()
        .all(|(link, pose)| sim.clear_by(link, pose, margin_m))
}

/// The pose backed off from `object_from_palm` along the palm's -z (the approach
/// axis) just far enough that the hand in `preshape` is clear, at most `max_retreat_m`:
/// where an approach along z would have stopped at contact. The pose itself when
/// it is clear; None when even the largest retreat collides.
pub fn retreat_until_clear(
    hand: &HandModel,
    object: &GraspObject,
    object_from_palm: &Pose,
    preshape: &HandPose,
    max_retreat_m: f64,
) -> Option<Pose> {
    let back = |d: f64| object_from_palm * Pose::translation(0.0, 0.0, -d);
    let collides = |d: f64| open_hand_collision(hand, object, &back(d), preshape).is_some();
    if !collides(0.0) {
        return Some(*object_from_palm);
    }
    if max_retreat_m <= 0.0 || collides(max_retreat_m) {
        return None;
    }
    let (mut a, mut b) = (0.0, max_retreat_m);
    while b - a > 5e-5 {
        let mid = 0.5 * (a + b);
        if collides(mid) {
            a = mid;
        } else {
            b = mid;
        }
    }
    // 20 um clear of the contact, so that rounding cannot make it touch.
    Some(back(b + 2e-5))
}

/// The quality of a grasp: Ferrari–Canny epsilon (and the wrench-space volume when
/// asked), with the contacts that gave it.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct GraspEvaluation {
    /// Epsilon (0 without force closure or with a collision at the start).
    pub epsilon: f64,
    /// Wrench-space volume (qhull), when asked for.
    pub volume: Option<f64>,
    /// Whether the grasp is force closure.
    pub force_closure: bool,
    /// The closing simulation.
    pub outcome: GraspOutcome,
    /// Where the approach to contact stopped, when the grasp was approached
    /// ([`evaluate_approached_grasp`]); `None`: closed at the given pose.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub approach: Option<super::approach::ApproachStop>,
}

/// Auto-grasp at `object_from_palm` from `preshape` and the quality of the result;
/// `with_volume` adds the qhull volume (slower).
pub fn evaluate_grasp(
    hand: &HandModel,
    object: &GraspObject,
    object_from_palm: &Pose,
    preshape: &HandPose,
    options: &AutoGraspOptions,
    params: &QualityParams,
    with_volume: bool,
) -> Result<GraspEvaluation, GraspSimError> {
    let outcome = close_hand(hand, object, object_from_palm, preshape, options)?;
    let params = object.quality_params(params);
    params.validate()?;
    let contacts = outcome.metric_contacts();
    let (epsilon, volume) = if contacts.is_empty() {
        (0.0, with_volume.then_some(0.0))
    } else if with_volume {
        let GraspQuality {
            epsilon, volume, ..
        } = super::evaluate(&contacts, &params)?;
        (epsilon, Some(volume))
    } else {
        (super::epsilon(&contacts, &params)?, None)
    };
    Ok(GraspEvaluation {
        epsilon,
        volume,
        force_closure: epsilon > 0.0,
        outcome,
        approach: None,
    })
}

/// A grasp to evaluate with its approach: where the palm is planned, the hand's
/// pre-shape (spread and flex), and how the palm is brought there
/// ([`evaluate_approached_grasp`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ApproachedGrasp {
    /// The planned palm pose in the object frame.
    pub object_from_palm: Pose,
    /// The spread and each finger's flex before closing ([`HandPose::open`]: open).
    pub preshape: HandPose,
    /// How the palm is brought to `object_from_palm`.
    pub approach: GraspApproach,
}

/// [`evaluate_grasp`] after the palm is brought to the grasp as `grasp.approach`
/// says: with approach to contact, from the pre-grasp along the approach axis
/// through `grasp.object_from_palm` until first contact
/// ([`super::approach::approach_to_contact`]), then closed where it stopped; with
/// [`GraspApproach::AtPose`] (the paper's setting) closed at `grasp.object_from_palm`
/// itself. A pre-grasp that already collides is reported as a collision at the
/// start, like an open hand that collides.
pub fn evaluate_approached_grasp(
    hand: &HandModel,
    object: &GraspObject,
    grasp: &ApproachedGrasp,
    options: &AutoGraspOptions,
    params: &QualityParams,
    with_volume: bool,
) -> Result<GraspEvaluation, GraspSimError> {
    let ApproachedGrasp {
        object_from_palm,
        preshape,
        approach,
    } = grasp;
    let GraspApproach::ToContact(approach) = approach else {
        return evaluate_grasp(
            hand,
            object,
            object_from_palm,
            preshape,
            options,
            params,
            with_volume,
        );
    };
    let stop =
        super::approach::approach_to_contact(hand, object, object_from_palm, preshape, approach)?;
    let mut e = evaluate_grasp(
        hand,
        object,
        &stop.object_from_palm,
        preshape,
        options,
        params,
        with_volume,
    )?;
    if let Some(c) = &stop.start_collision {
        // The pre-grasp collides: nothing to approach or close.
        e.outcome.collision_at_start = Some(c.clone());
        e.outcome.contacts.clear();
        e.epsilon = 0.0;
        e.volume = with_volume.then_some(0.0);
        e.force_closure = false;
    }
    e.approach = Some(stop);
    Ok(e)
}

/// How a grasp simulation brings the palm to the planned pose.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum GraspApproach {
    /// The palm is placed at the planned pose (the paper's experiments).
    AtPose,
    /// Approach to contact along the palm's approach axis (as the executor does).
    ToContact(super::approach::ApproachOptions),
}

/// A lower bound on the distance between a box of half extents `half` (centred
/// in its frame) and `triangle` (object frame): the largest gap along the box's
/// axes and the triangle's normal (separating axes).
fn box_triangle_gap(
    box_from_object: &Pose,
    half: &Vector3<f64>,
    triangle: &parry3d_f64::shape::Triangle,
) -> f64 {
    let v = [triangle.a, triangle.b, triangle.c].map(|p| box_from_object * p);
    let mut gap = f64::NEG_INFINITY;
    for k in 0..3 {
        let lo = v[0][k].min(v[1][k]).min(v[2][k]);
        let hi = v[0][k].max(v[1][k]).max(v[2][k]);
        gap = gap.max(lo - half[k]).max(-half[k] - hi);
    }
    let n = (v[1] - v[0]).cross(&(v[2] - v[0]));
    let norm = n.norm();
    if norm > 0.0 {
        let n = n / norm;
        gap = gap.max(n.dot(&v[0].coords).abs() - half.dot(&n.abs()));
    }
    gap
}

/// Clearance (m) below which the closing fingers step and test exactly; farther
/// from everything they jump by as much as keeps every point within it.
pub(crate) const FREE_MARGIN_M: f64 = 0.015;

/// An oriented box in the object frame, to prune the mesh's BVH and test
/// triangles: a node is kept unless one of the three world axes or the box's
/// three axes separates the two (conservative: no false negatives). Plain arrays
/// with the box's world extent precomputed: this runs for every BVH node visited.
struct Obb {
    centre: [f64; 3],
    /// `axes[i][k]`: component `i` (object frame) of the box's axis `k`.
    axes: [[f64; 3]; 3],
    abs_axes: [[f64; 3]; 3],
    half: [f64; 3],
    /// Half extent of the box along each object axis: `sum_k |axes[i][k]| half[k]`.
    extent: [f64; 3],
}

impl Obb {
    fn new(object_from_box: &Pose, half: Vector3<f64>) -> Obb {
        let m = object_from_box.rotation.to_rotation_matrix().into_inner();
        let axes = [0, 1, 2].map(|i| [m[(i, 0)], m[(i, 1)], m[(i, 2)]]);
        let abs_axes = axes.map(|row| row.map(f64::abs));
        let half = [half.x, half.y, half.z];
        let extent = abs_axes.map(|row| row[0] * half[0] + row[1] * half[1] + row[2] * half[2]);
        let t = &object_from_box.translation.vector;
        Obb {
            centre: [t.x, t.y, t.z],
            axes,
            abs_axes,
            half,
            extent,
        }
    }

    fn overlaps(&self, aabb: &parry3d_f64::bounding_volume::Aabb) -> bool {
        let (lo, hi) = (&aabb.mins, &aabb.maxs);
        let mut d = [0.0; 3];
        let mut e = [0.0; 3];
        // World axes: the box's extent along each is `extent`.
        for i in 0..3 {
            e[i] = 0.5 * (hi[i] - lo[i]);
            d[i] = 0.5 * (hi[i] + lo[i]) - self.centre[i];
            if d[i].abs() > e[i] + self.extent[i] {
                return false;
            }
        }
        // Box axes: the AABB's extent along axis k is sum_i |R_ik| e_i.
        (0..3).all(|k| {
            let (a, b) = (&self.axes, &self.abs_axes);
            let d_box = a[0][k] * d[0] + a[1][k] * d[1] + a[2][k] * d[2];
            let aabb_extent = b[0][k] * e[0] + b[1][k] * e[1] + b[2][k] * e[2];
            d_box.abs() <= self.half[k] + aabb_extent
        })
    }

    /// `p` (object frame) in the box's frame.
    fn to_box(&self, p: &Point3<f64>) -> [f64; 3] {
        let d = [
            p.x - self.centre[0],
            p.y - self.centre[1],
            p.z - self.centre[2],
        ];
        let a = &self.axes;
        [0, 1, 2].map(|k| a[0][k] * d[0] + a[1][k] * d[1] + a[2][k] * d[2])
    }

    /// Whether the box and the triangle `a b c` (object frame) intersect: the
    /// separating-axis test over the box's 3 axes, the triangle's normal and the
    /// 9 cross products of box axes and triangle edges (exact, touching counts).
    fn intersects_triangle(&self, a: &Point3<f64>, b: &Point3<f64>, c: &Point3<f64>) -> bool {
        let v = [self.to_box(a), self.to_box(b), self.to_box(c)];
        let h = &self.half;
        // Box axes: the triangle's bounding box against the box.
        for k in 0..3 {
            let (lo, hi) = (
                v[0][k].min(v[1][k]).min(v[2][k]),
                v[0][k].max(v[1][k]).max(v[2][k]),
            );
            if lo > h[k] || hi < -h[k] {
                return false;
            }
        }
        let sub = |p: &[f64; 3], q: &[f64; 3]| [p[0] - q[0], p[1] - q[1], p[2] - q[2]];
        let dot = |p: &[f64; 3], q: &[f64; 3]| p[0] * q[0] + p[1] * q[1] + p[2] * q[2];
        let cross = |p: &[f64; 3], q: &[f64; 3]| {
            [
                p[1] * q[2] - p[2] * q[1],
                p[2] * q[0] - p[0] * q[2],
                p[0] * q[1] - p[1] * q[0],
            ]
        };
        let edges = [sub(&v[1], &v[0]), sub(&v[2], &v[1]), sub(&v[0], &v[2])];
        // The triangle's plane.
        let n = cross(&edges[0], &edges[1]);
        let radius =
            |axis: &[f64; 3]| h[0] * axis[0].abs() + h[1] * axis[1].abs() + h[2] * axis[2].abs();
        if dot(&n, &v[0]).abs() > radius(&n) {
            return false;
        }
        // Box axis x triangle edge.
        for edge in &edges {
            for k in 0..3 {
                let mut unit = [0.0; 3];
                unit[k] = 1.0;
                let axis = cross(&unit, edge);
                let p = v.map(|q| dot(&axis, &q));
                let (lo, hi) = (p[0].min(p[1]).min(p[2]), p[0].max(p[1]).max(p[2]));
                let r = radius(&axis);
                if lo > r || hi < -r {
                    return false;
                }
            }
        }
        true
    }
}

struct Sim<'a> {
    object: &'a GraspObject,
    options: &'a AutoGraspOptions,
    dispatcher: DefaultQueryDispatcher,
}

impl Sim<'_> {
    /// What the link at `object_from_link` intersects, if anything.
    fn hits(&self, link: &HandLink, object_from_link: &Pose) -> Option<Obstacle> {
        for (local, shape) in &link.shapes {
            let pose = object_from_link * local;
            if let Some(h) = self.object.table_height_m {
                if shape.compute_aabb(&pose).mins.z < h {
                    return Some(Obstacle::Table);
                }
            }
            let mesh = self.object.mesh();
            let hit = match shape.as_cuboid() {
                // A box: prune the BVH with the oriented box, then exact SAT per triangle.
                Some(cuboid) => {
                    let obb = Obb::new(&pose, cuboid.half_extents);
                    let (vertices, indices) = (mesh.vertices(), mesh.indices());
                    mesh.bvh()
                        .leaves(|node| obb.overlaps(&node.aabb()))
                        .any(|id| {
                            let [a, b, c] = indices[id as usize].map(|i| &vertices[i as usize]);
                            obb.intersects_triangle(a, b, c)
                        })
                }
                // The shape at `pose` relative to the mesh; unsupported counts as a hit.
                None => self
                    .dispatcher
                    .intersection_test(&pose, mesh, shape.as_ref())
                    .unwrap_or(true),
            };
            if hit {
                return Some(Obstacle::Object);
            }
        }
        None
    }

    /// True when the link at `object_from_link` is provably farther than `margin_m`
    /// from the object and the table (no BVH leaf box near its grown box); false
    /// when it may not be (or for shapes other than boxes).
    fn clear_by(&self, link: &HandLink, object_from_link: &Pose, margin_m: f64) -> bool {
        link.shapes.iter().all(|(local, shape)| {
            let pose = object_from_link * local;
            if let Some(h) = self.object.table_height_m {
                if shape.compute_aabb(&pose).mins.z < h + margin_m {
                    return false;
                }
            }
            let Some(cuboid) = shape.as_cuboid() else {
                return false;
            };
            let obb = Obb::new(&pose, cuboid.half_extents.add_scalar(margin_m));
            self.object
                .mesh
                .bvh()
                .leaves(|node| obb.overlaps(&node.aabb()))
                .next()
                .is_none()
        })
    }

    /// Whether the proximal and the distal link (in that order) intersect
    /// anything; the distal is not tested when the proximal hits (reported as
    /// not hitting): callers need only whether either hits and whether the
    /// proximal does.
    fn any_hit(&self, [(proximal, p), (distal, d)]: [(&HandLink, Pose); 2]) -> [bool; 2] {
        if self.hits(proximal, &p).is_some() {
            [true, false]
        } else {
            [false, self.hits(distal, &d).is_some()]
        }
    }

    /// Closes one finger from flex `start`: returns the flex and distal angles and
    /// why it stopped.
    fn close_finger(&self, finger: &Finger, base: &Pose, start: f64) -> (f64, f64, FingerStop) {
        let step = self.options.step_rad;
        let tol = self.options.tolerance_rad;
        let (lo, hi) = finger.flex_limits_rad;
        let coupled = |flex: f64| {
            let (p, d) = finger.link_poses_from_base(base, flex, finger.coupled_distal_rad(flex));
            self.any_hit([(&finger.proximal, p), (&finger.distal, d)])
        };
        let coupled_reach = finger
            .reach
            .proximal_m
            .max(finger.reach.distal_coupled_m(finger.distal_ratio));
        let coupled_clear = |flex: f64| {
            let (p, d) = finger.link_poses_from_base(base, flex, finger.coupled_distal_rad(flex));
            self.clear_by(&finger.proximal, &p, FREE_MARGIN_M)
                && self.clear_by(&finger.distal, &d, FREE_MARGIN_M)
        };
        let mut free = start.max(lo);
        let proximal_stop = loop {
            if free >= hi {
                return (hi, finger.coupled_distal_rad(hi), FingerStop::Limit);
            }
            // Far from everything: a jump no point can cover more than the margin.
            if coupled_clear(free) {
                free = (free + FREE_MARGIN_M / coupled_reach).min(hi);
                continue;
            }
            let next = (free + step).min(hi);
            let hit = coupled(next);
            if hit == [false, false] {
                free = next;
                continue;
            }
            let (mut a, mut b, mut hit_b) = (free, next, hit);
            while b - a > tol {
                let mid = 0.5 * (a + b);
                let h = coupled(mid);
                if h == [false, false] {
                    a = mid;
                } else {
                    (b, hit_b) = (mid, h);
                }
            }
            if hit_b[0] {
                break a;
            }
            return (a, finger.coupled_distal_rad(a), FingerStop::DistalBlocked);
        };
        // Breakaway: the proximal link holds, the distal closes on alone.
        let (dlo, dhi) = finger.distal_limits_rad;
        let distal_hit = |angle: f64| {
            let (_, d) = finger.link_poses_from_base(base, proximal_stop, angle);
            self.hits(&finger.distal, &d).is_some()
        };
        let distal_clear = |angle: f64| {
            let (_, d) = finger.link_poses_from_base(base, proximal_stop, angle);
            self.clear_by(&finger.distal, &d, FREE_MARGIN_M)
        };
        let mut free = finger.coupled_distal_rad(proximal_stop).clamp(dlo, dhi);
        loop {
            if free >= dhi {
                return (proximal_stop, dhi, FingerStop::BreakawayDistalLimit);
            }
            if distal_clear(free) {
                free = (free + FREE_MARGIN_M / finger.reach.distal_own_m).min(dhi);
                continue;
            }
            let next = (free + step).min(dhi);
            if !distal_hit(next) {
                free = next;
                continue;
            }
            let (mut a, mut b) = (free, next);
            while b - a > tol {
                let mid = 0.5 * (a + b);
                if distal_hit(mid) {
                    b = mid;
                } else {
                    a = mid;
                }
            }
            return (proximal_stop, a, FingerStop::BreakawayDistalBlocked);
        }
    }

    /// Appends the contacts of `link` at `object_from_link` with the object.
    fn contacts_of(&self, link: &HandLink, object_from_link: &Pose, out: &mut Vec<LinkContact>) {
        let reach = self.options.contact_distance_m;
        let merge = self.options.merge_distance_m;
        let mesh = self.object.mesh();
        let mut found: Vec<LinkContact> = Vec::new();
        for (local, shape) in &link.shapes {
            let pose = object_from_link * local;
            // Candidate triangles with a cheap lower bound on their distance.
            let mut candidates: Vec<(f64, u32)> = match shape.as_cuboid() {
                Some(cuboid) => {
                    let obb = Obb::new(&pose, cuboid.half_extents.add_scalar(reach));
                    let box_from_object = pose.inverse();
                    mesh.bvh()
                        .leaves(|node| obb.overlaps(&node.aabb()))
                        .filter_map(|id| {
                            let gap = box_triangle_gap(
                                &box_from_object,
                                &cuboid.half_extents,
                                &mesh.triangle(id),
                            );
                            (gap <= reach).then_some((gap, id))
                        })
                        .collect()
                }
                None => {
                    let aabb = shape.compute_aabb(&pose).loosened(reach);
                    mesh.bvh()
                        .intersect_aabb(&aabb)
                        .map(|id| (0.0, id))
                        .collect()
                }
            };
            candidates.sort_by(|a, b| a.0.total_cmp(&b.0));
            for (_, id) in candidates {
                let triangle = mesh.triangle(id);
                // A triangle within the merge distance of a contact found already
                // would be merged into it: skip the exact query.
                let covered = found.iter().any(|c| {
                    [triangle.a, triangle.b, triangle.c]
                        .iter()
                        .all(|v| (v - c.point).norm() < merge)
                });
                if covered {
                    continue;
                }
                let Ok(Some(c)) = self
                    .dispatcher
                    .contact(&pose, &triangle, shape.as_ref(), reach)
                else {
                    continue;
                };
                if c.dist < -reach {
                    continue;
                }
                // The finger pushes into the object along the object's surface
                // normal there: the face's, or at an edge or vertex the mesh's
                // angle-weighted pseudo-normal.
                let Some(outward) = self.object.surface_normal(id, &triangle, &c.point1) else {
                    continue;
                };
                found.push(LinkContact {
                    link: link.name.clone(),
                    point: c.point1,
                    normal: -outward,
                    distance_m: c.dist,
                });
            }
        }
        found.sort_by(|a, b| a.distance_m.total_cmp(&b.distance_m));
        let start = out.len();
        for c in found {
            let merged = out[start..]
                .iter()
                .any(|k| (k.point - c.point).norm() < self.options.merge_distance_m);
            if !merged {
                out.push(c);
            }
        }
    }
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use crate::robot::description::Primitive;
    use crate::robot::{shipped_robot, Robot};
    use nalgebra::{Rotation3, UnitQuaternion};
    use std::f64::consts::TAU;

    /// A closed, outward cylinder about z, centred on the origin.
    pub(crate) fn cylinder(radius: f64, height: f64, segments: usize) -> TriMesh {
        let mut vertices = vec![
            Point3::new(0.0, 0.0, -height / 2.0),
            Point3::new(0.0, 0.0, height / 2.0),
        ];
        for k in 0..segments {
            let a = TAU * k as f64 / segments as f64;
            let (x, y) = (radius * a.cos(), radius * a.sin());
            vertices.push(Point3::new(x, y, -height / 2.0));
            vertices.push(Point3::new(x, y, height / 2.0));
        }
        let mut triangles = Vec::new();
        for k in 0..segments as u32 {
            let n = segments as u32;
            let (b0, t0) = (2 + 2 * k, 3 + 2 * k);
            let (b1, t1) = (2 + 2 * ((k + 1) % n), 3 + 2 * ((k + 1) % n));
            triangles.extend([[b0, b1, t1], [b0, t1, t0], [0, b1, b0], [1, t0, t1]]);
        }
        TriMesh {
            vertices,
            triangles,
        }
    }

    /// An axis-aligned closed box with its centre at `centre`.
    pub(crate) fn cuboid(centre: [f64; 3], size: [f64; 3]) -> TriMesh {
        let h = Vector3::from(size) / 2.0;
        let c = Vector3::from(centre);
        let vertices = (0..8)
            .map(|i| {
                let s = Vector3::new(
                    if i & 1 == 0 { -1.0 } else { 1.0 },
                    if i & 2 == 0 { -1.0 } else { 1.0 },
                    if i & 4 == 0 { -1.0 } else { 1.0 },
                );
                Point3::from(c + s.component_mul(&h))
            })
            .collect();
        let triangles = vec![
            [0, 2, 1],
            [1, 2, 3],
            [4, 5, 6],
            [5, 7, 6], // -z, +z
            [0, 1, 4],
            [1, 5, 4],
            [2, 6, 3],
            [3, 6, 7], // -y, +y
            [0, 4, 2],
            [2, 4, 6],
            [1, 3, 5],
            [3, 7, 5], // -x, +x
        ];
        TriMesh {
            vertices,
            triangles,
        }
    }

    pub(crate) fn hand_of(robot: &Robot) -> HandModel {
        HandModel::from_description(&robot.description, "bh_palm", Path::new("shipped")).unwrap()
    }

    /// Palm pose for a side grasp of a z-axis cylinder of `radius`: approach along
    /// +x, the fingers' closing plane horizontal (palm x = object z), palm surface
    /// `gap_m` from the cylinder.
    pub(crate) fn side_pose(radius: f64, gap_m: f64) -> Pose {
        let rot = Rotation3::from_basis_unchecked(&[Vector3::z(), -Vector3::y(), Vector3::x()]);
        Pose::from_parts(
            nalgebra::Translation3::new(-(radius + 0.060 + gap_m), 0.0, 0.0),
            UnitQuaternion::from_rotation_matrix(&rot),
        )
    }

    fn object(mesh: &TriMesh) -> GraspObject {
        GraspObject::new(mesh, Path::new("test mesh")).unwrap()
    }

    #[test]
    fn side_grasp_of_a_35_mm_cylinder_touches_with_three_fingers_and_is_force_closure() {
        let robot = shipped_robot();
        let hand = hand_of(&robot);
        let radius = 0.035;
        let obj = object(&cylinder(radius, 0.2, 96));
        let e = evaluate_grasp(
            &hand,
            &obj,
            &side_pose(radius, 2e-4),
            &HandPose::open(0.0),
            &AutoGraspOptions::default(),
            &QualityParams::default(),
            true,
        )
        .unwrap();
        let o = &e.outcome;
        assert_eq!(o.collision_at_start, None);
        for finger in ["bh_f1", "bh_f2", "bh_f3"] {
            assert!(
                o.contacts.iter().any(|c| c.link.starts_with(finger)),
                "{finger} does not touch: {:#?}",
                o.contacts
            );
        }
        assert!(o.contacts.iter().any(|c| c.link == "bh_palm"));
        for c in &o.contacts {
            // On the cylinder's side (96 facets: within 0.02 mm of the radius),
            // the normal radial and inward.
            let r = c.point.coords.xy().norm();
            assert!((r - radius).abs() < 2e-4, "{c:?}: r = {r}");
            let radial = -c.point.coords.xy().normalize();
            let n = c.normal.xy();
            assert!(c.normal.z.abs() < 1e-3 && n.dot(&radial) > 0.99, "{c:?}");
            assert!(c.distance_m.abs() < 5e-4);
        }
        assert!(e.force_closure && e.epsilon > 0.01, "{e:?}");
        assert!(e.volume.unwrap() > 0.0);
    }

    #[test]
    fn closing_on_empty_space_gives_no_contacts_and_zero_epsilon() {
        let robot = shipped_robot();
        let hand = hand_of(&robot);
        let obj = object(&cylinder(0.035, 0.2, 32));
        let far = Pose::translation(1.0, 0.0, 0.0) * side_pose(0.035, 0.0);
        let e = evaluate_grasp(
            &hand,
            &obj,
            &far,
            &HandPose::open(0.5),
            &AutoGraspOptions::default(),
            &QualityParams::default(),
            false,
        )
        .unwrap();
        assert!(e.outcome.contacts.is_empty());
        assert_eq!(e.epsilon, 0.0);
        assert!(!e.force_closure);
        assert_eq!(e.outcome.stops, [FingerStop::Limit; 3]);
        assert_eq!(e.outcome.hand.flex_rad, [2.44; 3]);
    }

    #[test]
    fn a_hand_intersecting_at_the_start_is_reported() {
        let robot = shipped_robot();
        let hand = hand_of(&robot);
        let radius = 0.035;
        let obj = object(&cylinder(radius, 0.2, 32));
        let into = Pose::translation(0.01, 0.0, 0.0) * side_pose(radius, 0.0);
        let o = close_hand(
            &hand,
            &obj,
            &into,
            &HandPose::open(0.0),
            &AutoGraspOptions::default(),
        )
        .unwrap();
        assert_eq!(
            o.collision_at_start,
            Some(StartCollision {
                link: "bh_palm".into(),
                with: Obstacle::Object
            })
        );
        assert!(o.contacts.is_empty());
        // The whole hand inside a big block: nothing intersects a triangle, but the
        // palm is inside.
        let block = object(&cuboid([0.0; 3], [1.0; 3]));
        let o = close_hand(
            &hand,
            &block,
            &Pose::identity(),
            &HandPose::open(0.0),
            &AutoGraspOptions::default(),
        )
        .unwrap();
        assert_eq!(o.collision_at_start.unwrap().with, Obstacle::InsideObject);
        // Clear of the object but the fingers in the table.
        let obj = object(&cylinder(radius, 0.2, 32)).with_table(Some(-0.0));
        let low = Pose::translation(0.0, 0.0, -0.1) * side_pose(radius, 1e-3);
        let o = close_hand(
            &hand,
            &obj,
            &low,
            &HandPose::open(0.0),
            &AutoGraspOptions::default(),
        )
        .unwrap();
        assert_eq!(o.collision_at_start.unwrap().with, Obstacle::Table);
    }

    /// The corners of a link's box shapes in the palm frame, from the full robot's FK.
    fn corners(
        robot: &Robot,
        link: &str,
        hand: &HandPose,
        distal_override: Option<f64>,
    ) -> Vec<Point3<f64>> {
        let d = &robot.description;
        let mut q = robot.variables(&[0.0; 7], hand);
        let poses = crate::robot::kinematics::link_poses(d, &q);
        let palm = poses[d.link_index("bh_palm").unwrap()];
        let li = d.link_index(link).unwrap();
        let mut pose = palm.inverse() * poses[li];
        if let Some(angle) = distal_override {
            // Re-pose the distal link about its own joint with the given angle.
            let j = d.links[li].parent_joint.unwrap();
            let joint = &d.joints[j];
            let parent = palm.inverse() * poses[joint.parent_link];
            let crate::robot::description::Motion::Revolute { axis, .. } = &joint.motion else {
                panic!()
            };
            pose = parent * joint.parent_from_joint * UnitQuaternion::from_axis_angle(axis, angle);
        }
        q.clear();
        let mut out = Vec::new();
        for s in &d.links[li].shapes {
            let Primitive::Box { size_m } = s.primitive else {
                panic!("box links only")
            };
            for i in 0..8 {
                let c = Vector3::new(
                    size_m[0] / 2.0 * if i & 1 == 0 { -1.0 } else { 1.0 },
                    size_m[1] / 2.0 * if i & 2 == 0 { -1.0 } else { 1.0 },
                    size_m[2] / 2.0 * if i & 4 == 0 { -1.0 } else { 1.0 },
                );
                out.push(pose * s.link_from_shape * Point3::from(c));
            }
        }
        out
    }

    #[test]
    fn fingers_stop_where_their_corners_first_reach_a_plate() {
        // A plate over the palm at z = h: each finger closes upward into it. The
        // first contact angle is found here by scanning the box corners (from the
        // full-tree FK and the URDF's box sizes), independent of parry.
        let robot = shipped_robot();
        let hand = hand_of(&robot);
        let h = 0.125;
        let plate = object(&cuboid([0.0, 0.0, h + 0.01], [0.6, 0.6, 0.02]));
        let o = close_hand(
            &hand,
            &plate,
            &Pose::identity(),
            &HandPose::open(0.3),
            &AutoGraspOptions::default(),
        )
        .unwrap();
        assert_eq!(o.collision_at_start, None);
        for (i, f) in ["bh_f1", "bh_f2", "bh_f3"].iter().enumerate() {
            let top = |flex: f64, link: &str| {
                let mut pose = HandPose {
                    spread_rad: 0.3,
                    flex_rad: [0.0; 3],
                };
                pose.flex_rad[i] = flex;
                corners(&robot, link, &pose, None)
                    .iter()
                    .map(|c| c.z)
                    .fold(f64::MIN, f64::max)
            };
            let (prox, dist) = (format!("{f}_proximal"), format!("{f}_distal"));
            let mut flex = 0.0;
            while top(flex, &prox) < h && top(flex, &dist) < h {
                flex += 1e-5;
            }
            assert!(
                (o.hand.flex_rad[i] - flex).abs() < 3e-4,
                "{f}: simulated {} rad, scanned {flex} rad",
                o.hand.flex_rad[i]
            );
            let proximal_first = top(flex, &prox) >= h;
            assert_eq!(
                o.stops[i] != FingerStop::DistalBlocked,
                proximal_first,
                "{f}: {:?}",
                o.stops[i]
            );
            if proximal_first {
                // Breakaway: the distal turns on alone until its corners reach h.
                let mut pose = HandPose {
                    spread_rad: 0.3,
                    flex_rad: [0.0; 3],
                };
                pose.flex_rad[i] = o.hand.flex_rad[i];
                let mut angle = 0.3443 * o.hand.flex_rad[i];
                let top_d = |a: f64| {
                    corners(&robot, &dist, &pose, Some(a))
                        .iter()
                        .map(|c| c.z)
                        .fold(f64::MIN, f64::max)
                };
                while top_d(angle) < h && angle < 0.84 {
                    angle += 1e-5;
                }
                assert!((o.distal_rad[i] - angle.min(0.84)).abs() < 3e-4, "{f}");
            }
            assert!(o.contacts.iter().any(|c| c.link.starts_with(f)));
        }
        for c in &o.contacts {
            assert!((c.point.z - h).abs() < 1e-6, "{c:?}");
            assert!((c.normal - Vector3::z()).norm() < 1e-6, "{c:?}");
        }
    }

    #[test]
    fn box_triangle_test_agrees_with_parry() {
        use parry3d_f64::shape::{Cuboid, Triangle};
        use rand::{Rng, SeedableRng};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(5);
        let (mut hits, mut misses) = (0, 0);
        for _ in 0..20_000 {
            let half = Vector3::new(
                rng.gen_range(0.005..0.04),
                rng.gen_range(0.005..0.04),
                rng.gen_range(0.005..0.04),
            );
            let pose = Pose::new(
                Vector3::new(
                    rng.gen_range(-0.02..0.02),
                    rng.gen_range(-0.02..0.02),
                    rng.gen_range(-0.02..0.02),
                ),
                Vector3::new(
                    rng.gen_range(-3.0..3.0),
                    rng.gen_range(-3.0..3.0),
                    rng.gen_range(-3.0..3.0),
                ),
            );
            let mut corner = || {
                Point3::new(
                    rng.gen_range(-0.06..0.06),
                    rng.gen_range(-0.06..0.06),
                    rng.gen_range(-0.06..0.06),
                )
            };
            let (a, b, c) = (corner(), corner(), corner());
            let ours = Obb::new(&pose, half).intersects_triangle(&a, &b, &c);
            let theirs = parry3d_f64::query::details::intersection_test_cuboid_triangle(
                &pose.inverse(),
                &Cuboid::new(half),
                &Triangle::new(a, b, c),
            );
            assert_eq!(ours, theirs, "{pose:?} {half:?} {a} {b} {c}");
            if ours {
                hits += 1;
            } else {
                misses += 1;
            }
        }
        assert!(hits > 2000 && misses > 2000, "{hits} hits, {misses} misses");
    }

    #[test]
    fn options_are_validated() {
        let bad = AutoGraspOptions {
            step_rad: 0.5,
            ..AutoGraspOptions::default()
        };
        assert!(bad.validate().unwrap_err().to_string().contains("step_rad"));
        AutoGraspOptions::default().validate().unwrap();
    }
}
