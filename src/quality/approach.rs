//! Approach to contact, as GraspIt! and the executor do it: the hand, open or in
//! the grasp's pre-shape (fingers partly closed, for a flat tool on a table), starts
//! at the pre-grasp, `pregrasp_m` back from the planned palm pose along the palm's
//! -z, and moves along +z (the approach axis) through the planned pose, at most
//! `max_overtravel_m` beyond it; it stops just short of the first contact of any
//! hand link with the object or the table. The hand then closes there.
//!
//! The parameters are the cell's (`robot.pregrasp_offset_m` and `[approach]` in
//! `robot/cell.toml`, [`ApproachOptions::from_cell`]), the same the executor's
//! guarded move uses, so simulated and executed grasps stop alike.
//!
//! The search moves in jumps of [`FREE_MARGIN_M`] while every link is provably
//! farther than that from everything, then in steps of [`STEP_M`] (shorter than
//! any link's extent along the approach axis, so no surface is passed between two
//! tests), and bisects the first colliding step down to [`TOLERANCE_M`].

use super::autograsp::{
    open_hand_clear_by, open_hand_collision, GraspObject, GraspSimError, StartCollision,
    FREE_MARGIN_M,
};
use crate::config::CellConfig;
use crate::geometry::Pose;
use crate::robot::hand::HandModel;
use crate::robot::HandPose;
use serde::Serialize;

/// Step of the search near obstacles (m).
pub const STEP_M: f64 = 0.002;
/// Width of the bracket the contact is bisected to (m).
pub const TOLERANCE_M: f64 = 5e-5;
/// How far short of the bracketed contact the palm stops (m), so that rounding
/// cannot make the stopped hand touch.
const BACKOFF_M: f64 = 2e-5;

/// What is wrong with a grasp's own overtravel (m), if anything: it must be a
/// finite distance >= 0.
pub fn overtravel_problem(max_overtravel_m: Option<f64>) -> Option<String> {
    let v = max_overtravel_m?;
    (!(v.is_finite() && v >= 0.0))
        .then(|| format!("max_overtravel_m = {v} must be a finite distance >= 0 (m)"))
}

/// The approach's geometry.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct ApproachOptions {
    /// Distance of the pre-grasp behind the planned pose, along the palm's -z (m).
    pub pregrasp_m: f64,
    /// Farthest the palm goes beyond the planned pose (m).
    pub max_overtravel_m: f64,
}

impl Default for ApproachOptions {
    /// The shipped configuration's values: 0.10 m and 0.05 m.
    fn default() -> Self {
        ApproachOptions {
            pregrasp_m: 0.10,
            max_overtravel_m: 0.05,
        }
    }
}

impl ApproachOptions {
    /// The cell's: `robot.pregrasp_offset_m` and `approach.max_overtravel_m`.
    pub fn from_cell(config: &CellConfig) -> ApproachOptions {
        ApproachOptions {
            pregrasp_m: config.robot.pregrasp_offset_m,
            max_overtravel_m: config.approach.max_overtravel_m,
        }
    }

    /// These options for a grasp that names its own overtravel (a fingertip pinch
    /// taught with the palm clear of the object goes no farther than its pose);
    /// `None` keeps this one.
    pub fn for_grasp(self, max_overtravel_m: Option<f64>) -> ApproachOptions {
        ApproachOptions {
            max_overtravel_m: max_overtravel_m.unwrap_or(self.max_overtravel_m),
            ..self
        }
    }

    /// Checks the ranges.
    pub fn validate(&self) -> Result<(), GraspSimError> {
        for (field, value) in [
            ("pregrasp_m", self.pregrasp_m),
            ("max_overtravel_m", self.max_overtravel_m),
        ] {
            if !(value.is_finite() && value >= 0.0) {
                return Err(GraspSimError::Option {
                    field,
                    value,
                    problem: "must be a finite distance >= 0",
                });
            }
        }
        Ok(())
    }

    /// The pre-grasp of `object_from_palm` (the planned pose).
    pub fn pregrasp(&self, object_from_palm: &Pose) -> Pose {
        object_from_palm * Pose::translation(0.0, 0.0, -self.pregrasp_m)
    }
}

/// Where an approach stopped.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct ApproachStop {
    /// The palm where it stopped (object frame): the pre-grasp when it collides.
    #[serde(serialize_with = "serialize_pose")]
    pub object_from_palm: Pose,
    /// Distance travelled from the pre-grasp (m).
    pub travel_m: f64,
    /// Signed distance beyond the planned pose (m): negative when the palm
    /// stopped short of it.
    pub beyond_plan_m: f64,
    /// The link that touched first and what it touched; `None` when the palm
    /// went the whole overtravel without contact.
    pub contact: Option<StartCollision>,
    /// Set when the open hand already collides at the pre-grasp (nothing moved).
    pub start_collision: Option<StartCollision>,
}

fn serialize_pose<S: serde::Serializer>(pose: &Pose, s: S) -> Result<S::Ok, S::Error> {
    crate::geometry::PoseJson::from(pose).serialize(s)
}

/// Approaches `object_from_palm` (the planned palm pose, object frame) to
/// contact with the hand in `preshape` ([`HandPose::open`]: the open hand at a
/// spread); see the module documentation.
pub fn approach_to_contact(
    hand: &HandModel,
    object: &GraspObject,
    object_from_palm: &Pose,
    preshape: &HandPose,
    options: &ApproachOptions,
) -> Result<ApproachStop, GraspSimError> {
    options.validate()?;
    super::autograsp::validate_preshape(hand, preshape)?;
    let pregrasp = options.pregrasp(object_from_palm);
    let at = |travel: f64| pregrasp * Pose::translation(0.0, 0.0, travel);
    let collision = |travel: f64| open_hand_collision(hand, object, &at(travel), preshape);
    let stop = |travel: f64, contact| ApproachStop {
        object_from_palm: at(travel),
        travel_m: travel,
        beyond_plan_m: travel - options.pregrasp_m,
        contact,
        start_collision: None,
    };
    if let Some(c) = collision(0.0) {
        return Ok(ApproachStop {
            start_collision: Some(c),
            ..stop(0.0, None)
        });
    }
    let end = options.pregrasp_m + options.max_overtravel_m;
    let mut free = 0.0;
    while free < end {
        if open_hand_clear_by(hand, object, &at(free), preshape, FREE_MARGIN_M) {
            free = (free + FREE_MARGIN_M).min(end);
            continue;
        }
        let next = (free + STEP_M).min(end);
        let Some(mut hit) = collision(next) else {
            free = next;
            continue;
        };
        let (mut a, mut b) = (free, next);
        while b - a > TOLERANCE_M {
            let mid = 0.5 * (a + b);
            match collision(mid) {
                Some(c) => (b, hit) = (mid, c),
                None => a = mid,
            }
        }
        return Ok(stop((a - BACKOFF_M).max(0.0), Some(hit)));
    }
    Ok(stop(end, None))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::quality::autograsp::tests::{cuboid, hand_of};
    use crate::quality::autograsp::{
        evaluate_approached_grasp, ApproachedGrasp, AutoGraspOptions, GraspApproach, Obstacle,
    };
    use crate::quality::QualityParams;
    use crate::robot::shipped_robot;
    use std::path::Path;

    /// The lowest point (palm frame z) of the open hand's link boxes: how far the
    /// fingertips reach ahead of the palm along the approach axis, found from the
    /// box corners (independent of the collision code).
    fn reach_ahead(hand: &HandModel, spread: f64) -> f64 {
        let mut top = f64::MIN;
        let open = crate::robot::HandPose {
            spread_rad: spread,
            flex_rad: [0.0; 3],
        };
        for (link, pose) in hand.link_poses(&open) {
            for (local, shape) in &link.shapes {
                let c = shape.as_cuboid().unwrap();
                for i in 0..8 {
                    let h = c.half_extents;
                    let corner = nalgebra::Point3::new(
                        if i & 1 == 0 { -h.x } else { h.x },
                        if i & 2 == 0 { -h.y } else { h.y },
                        if i & 4 == 0 { -h.z } else { h.z },
                    );
                    top = top.max((pose * local * corner).z);
                }
            }
        }
        top
    }

    #[test]
    fn the_approach_stops_at_first_contact_with_a_box_at_a_known_distance() {
        let robot = shipped_robot();
        let hand = hand_of(&robot);
        let spread = 0.0;
        let ahead = reach_ahead(&hand, spread);
        // A wide box whose near face is 30 mm beyond the planned pose's farthest
        // hand point: the palm approaches along +z (object frame = palm frame at
        // the plan), so it must stop 30 mm beyond the plan.
        let face = ahead + 0.030;
        let block = GraspObject::new(
            &cuboid([0.0, 0.0, face + 0.05], [0.4, 0.4, 0.1]),
            Path::new("block"),
        )
        .unwrap();
        let options = ApproachOptions::default();
        let stop = approach_to_contact(
            &hand,
            &block,
            &Pose::identity(),
            &HandPose::open(spread),
            &options,
        )
        .unwrap();
        assert_eq!(stop.start_collision, None);
        let contact = stop.contact.as_ref().expect("touches the block");
        assert_eq!(contact.with, Obstacle::Object);
        assert!(
            (stop.beyond_plan_m - 0.030).abs() < 1e-4,
            "stopped {} m beyond the plan",
            stop.beyond_plan_m
        );
        assert!((stop.travel_m - 0.130).abs() < 1e-4, "{stop:?}");
        let z = stop.object_from_palm.translation.z;
        assert!((z - 0.030).abs() < 1e-4, "palm at z = {z}");

        // Beyond the overtravel (60 mm > 50 mm): no contact, the palm goes the
        // whole way.
        let far = GraspObject::new(
            &cuboid([0.0, 0.0, ahead + 0.060 + 0.05], [0.4, 0.4, 0.1]),
            Path::new("far block"),
        )
        .unwrap();
        let stop = approach_to_contact(
            &hand,
            &far,
            &Pose::identity(),
            &HandPose::open(spread),
            &options,
        )
        .unwrap();
        assert_eq!(stop.contact, None);
        assert!((stop.beyond_plan_m - 0.05).abs() < 1e-12, "{stop:?}");

        // A block nearer than the plan: the palm stops short of it (negative).
        let near = GraspObject::new(
            &cuboid([0.0, 0.0, ahead - 0.040 + 0.05], [0.4, 0.4, 0.1]),
            Path::new("near block"),
        )
        .unwrap();
        let stop = approach_to_contact(
            &hand,
            &near,
            &Pose::identity(),
            &HandPose::open(spread),
            &options,
        )
        .unwrap();
        assert!((stop.beyond_plan_m + 0.040).abs() < 1e-4, "{stop:?}");

        // A table across the path stops it too.
        let table_z = ahead + 0.020;
        let over_table = GraspObject::new(
            &cuboid([1.0, 1.0, 0.0], [0.01, 0.01, 0.01]),
            Path::new("pebble"),
        )
        .unwrap()
        .with_table(Some(-table_z));
        // Palm pointing down (-z object) at the plan: rotate by pi about x.
        let down = Pose::from_parts(
            nalgebra::Translation3::identity(),
            nalgebra::UnitQuaternion::from_euler_angles(std::f64::consts::PI, 0.0, 0.0),
        );
        let stop =
            approach_to_contact(&hand, &over_table, &down, &HandPose::open(spread), &options)
                .unwrap();
        assert_eq!(
            stop.contact.as_ref().unwrap().with,
            Obstacle::Table,
            "{stop:?}"
        );
        assert!((stop.beyond_plan_m - 0.020).abs() < 1e-4, "{stop:?}");
    }

    #[test]
    fn a_grasps_own_overtravel_replaces_the_cells() {
        let robot = shipped_robot();
        let hand = hand_of(&robot);
        let ahead = reach_ahead(&hand, 0.0);
        // The box's face 30 mm beyond the plan: within the cell's 50 mm.
        let block = GraspObject::new(
            &cuboid([0.0, 0.0, ahead + 0.030 + 0.05], [0.4, 0.4, 0.1]),
            Path::new("block"),
        )
        .unwrap();
        let cell = ApproachOptions::default();
        let beyond = |own: Option<f64>| {
            let stop = approach_to_contact(
                &hand,
                &block,
                &Pose::identity(),
                &HandPose::open(0.0),
                &cell.for_grasp(own),
            )
            .unwrap();
            (stop.beyond_plan_m, stop.contact.is_some())
        };
        let (at_contact, touched) = beyond(None);
        assert!((at_contact - 0.030).abs() < 1e-4 && touched, "{at_contact}");
        // A rim pinch's 0: the hand stops at its pose, clear of the box.
        assert_eq!(beyond(Some(0.0)), (0.0, false));
        let (short, touched) = beyond(Some(0.02));
        assert!((short - 0.02).abs() < 1e-12 && !touched, "{short}");
        // It still stops at a contact before its end.
        let (long, touched) = beyond(Some(0.04));
        assert!((long - 0.030).abs() < 1e-4 && touched, "{long}");
        assert_eq!(cell.for_grasp(None), cell);
        for bad in [-0.01, f64::NAN, f64::INFINITY] {
            let problem = overtravel_problem(Some(bad)).unwrap();
            assert!(problem.contains("max_overtravel_m"), "{problem}");
        }
        assert_eq!(overtravel_problem(Some(0.0)), None);
        assert_eq!(overtravel_problem(None), None);
    }

    #[test]
    fn approached_grasps_close_where_the_approach_stopped_and_the_paper_setting_stays() {
        let robot = shipped_robot();
        let hand = hand_of(&robot);
        let radius = 0.035;
        let obj = GraspObject::new(
            &crate::quality::autograsp::tests::cylinder(radius, 0.2, 64),
            Path::new("cylinder"),
        )
        .unwrap();
        // Planned 15 mm inside the cylinder: placed there, the open hand collides;
        // approached, it stops at the surface and grasps.
        let inside = Pose::translation(0.015, 0.0, 0.0)
            * crate::quality::autograsp::tests::side_pose(radius, 0.0);
        let (opts, params) = (AutoGraspOptions::default(), QualityParams::default());
        let at_pose = evaluate_approached_grasp(
            &hand,
            &obj,
            &ApproachedGrasp {
                object_from_palm: inside,
                preshape: HandPose::open(0.0),
                approach: GraspApproach::AtPose,
            },
            &opts,
            &params,
            false,
        )
        .unwrap();
        assert!(at_pose.outcome.collision_at_start.is_some());
        assert_eq!(at_pose.approach, None);
        let approached = evaluate_approached_grasp(
            &hand,
            &obj,
            &ApproachedGrasp {
                object_from_palm: inside,
                preshape: HandPose::open(0.0),
                approach: GraspApproach::ToContact(ApproachOptions::default()),
            },
            &opts,
            &params,
            false,
        )
        .unwrap();
        let stop = approached.approach.as_ref().unwrap();
        assert!(stop.contact.is_some(), "{stop:?}");
        assert!(stop.beyond_plan_m < -0.014, "{stop:?}");
        assert_eq!(approached.outcome.collision_at_start, None);
        assert!(approached.force_closure, "{approached:?}");
        // A pre-grasp inside the object is a collision at the start.
        let deep = Pose::translation(0.2, 0.0, 0.0)
            * crate::quality::autograsp::tests::side_pose(radius, 0.0);
        let e = evaluate_approached_grasp(
            &hand,
            &obj,
            &ApproachedGrasp {
                object_from_palm: deep,
                preshape: HandPose::open(0.0),
                approach: GraspApproach::ToContact(ApproachOptions::default()),
            },
            &opts,
            &params,
            false,
        )
        .unwrap();
        assert!(
            e.outcome.collision_at_start.is_some() && e.epsilon == 0.0,
            "{e:?}"
        );
        assert!(ApproachOptions {
            pregrasp_m: -1.0,
            max_overtravel_m: 0.05
        }
        .validate()
        .unwrap_err()
        .to_string()
        .contains("pregrasp_m"));
    }

    #[test]
    fn a_preshaped_hand_pinches_a_flat_box_on_the_table_where_the_open_hand_closes_on_the_table() {
        let robot = shipped_robot();
        let hand = hand_of(&robot);
        // A bar 25 mm high and 25 mm wide lying on the table (z = 0), a top-down
        // grasp across it: F3 on one side, F1 and F2 on the other.
        let bar = GraspObject::new(
            &cuboid([0.0, 0.0, 0.0125], [0.12, 0.025, 0.025]),
            Path::new("bar"),
        )
        .unwrap()
        .with_table(Some(0.0));
        let down = |z: f64| {
            Pose::from_parts(
                nalgebra::Translation3::new(0.0, 0.0, z),
                nalgebra::UnitQuaternion::from_euler_angles(std::f64::consts::PI, 0.0, 0.0),
            )
        };
        let (opts, params) = (AutoGraspOptions::default(), QualityParams::default());
        let grasp = |z: f64, preshape: HandPose| {
            evaluate_approached_grasp(
                &hand,
                &bar,
                &ApproachedGrasp {
                    object_from_palm: down(z),
                    preshape,
                    approach: GraspApproach::ToContact(ApproachOptions::default()),
                },
                &opts,
                &params,
                false,
            )
            .unwrap()
        };
        // Open: the horizontal fingers meet the table with the palm 0.10 m up, then
        // close into it.
        let open = grasp(0.15, HandPose::open(0.0));
        let stop = open.approach.as_ref().unwrap();
        assert_eq!(
            stop.contact.as_ref().unwrap().with,
            Obstacle::Table,
            "{stop:?}"
        );
        assert!(
            open.outcome.contacts.is_empty() && open.epsilon == 0.0,
            "{open:?}"
        );
        // Pre-shaped (every flex 1.15 rad, past the fingertips' lowest point): the
        // tips meet the table outside the bar, then sweep inward and up onto its sides.
        let preshape = HandPose {
            spread_rad: 0.0,
            flex_rad: [1.15; 3],
        };
        let pinch = grasp(0.2, preshape);
        let stop = pinch.approach.as_ref().unwrap();
        assert_eq!(stop.start_collision, None);
        assert_eq!(
            stop.contact.as_ref().unwrap().with,
            Obstacle::Table,
            "{stop:?}"
        );
        assert!(pinch.force_closure && pinch.epsilon > 0.0, "{pinch:?}");
        for f in ["bh_f1", "bh_f2", "bh_f3"] {
            assert!(
                pinch.outcome.contacts.iter().any(|c| c.link.starts_with(f)),
                "{f}"
            );
        }
        for c in &pinch.outcome.contacts {
            // On the bar's long sides, pushing across it.
            assert!((c.point.y.abs() - 0.0125).abs() < 1e-3, "{c:?}");
            assert!(c.normal.z.abs() < 0.1, "{c:?}");
        }
        // Closing started from the pre-shape, and the flexed fingers reach farther
        // ahead of the palm than open ones: the palm stops higher.
        assert!(pinch.outcome.hand.flex_rad.iter().all(|&f| f > 1.15));
        let (z_open, z_pinch) = (
            open.approach.unwrap().object_from_palm.translation.z,
            stop.object_from_palm.translation.z,
        );
        assert!(z_pinch > z_open + 0.05, "{z_pinch} vs {z_open}");
        // A flex outside the joint's range is refused, naming the finger.
        let bad = HandPose {
            spread_rad: 0.0,
            flex_rad: [0.0, 3.0, 0.0],
        };
        let err = approach_to_contact(&hand, &bar, &down(0.2), &bad, &ApproachOptions::default())
            .unwrap_err()
            .to_string();
        assert!(err.contains("F2") && err.contains('3'), "{err}");
    }
}
