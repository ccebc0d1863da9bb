//! The [`TrialScene`] of a recorded trial, rebuilt from its log row and files.
//!
//! - the segmented cloud: the trial's snapshot (camera frame) segmented as the
//!   perceive stage does ([`crate::cloud::segment::segment_object`]);
//! - the models: each fit of the row (`fits`: model index, status, pose, eps) with
//!   the category database's mesh; the usable fit with the lowest eps is the best;
//! - the hand: the arm joints the executor reached (`outcome.closing_joints_rad`,
//!   else the planned joints) through the URDF's forward kinematics, the fingers
//!   closed on the true object by the grasp simulator with the executed spread
//!   (`outcome.spread_rad`) where the object is a procedural one the simulator
//!   knows, else open; the simulator's contacts with it;
//! - the table from the cell configuration, and a caption.
//!
//! Every piece that is missing (no snapshot, no database, no plan) is left out of
//! the picture and named in its caption rather than failing it.

use super::log::TrialRecord;
use super::picture::{Part, Solid, TrialScene};
use crate::category::CategoryDb;
use crate::config::CellConfig;
use crate::geometry::Pose;
use crate::mesh::procedural::{generate, Category};
use crate::quality::autograsp::{close_hand, AutoGraspOptions, GraspObject};
use crate::robot::{HandPose, Robot};
use nalgebra::Point3;
use serde_json::Value;
use std::path::Path;

/// What a trial's scene is built with besides its row.
pub struct SceneInputs<'a> {
    /// The cell (table, camera mount, segmentation workspace).
    pub config: &'a CellConfig,
    /// The robot (arm kinematics and hand links).
    pub robot: &'a Robot,
    /// The hand model of the grasp simulator.
    pub hand: &'a crate::robot::hand::HandModel,
    /// The trial category's database (model meshes), if available.
    pub db: Option<&'a CategoryDb>,
    /// Pose of the camera that took the snapshot.
    pub base_from_camera: Pose,
}

/// One registered model of the row's `fits`.
#[derive(Debug, Clone, PartialEq)]
pub struct FitEntry {
    /// Index of the model in the category database.
    pub model_id: usize,
    /// The registered pose.
    pub base_from_model: Pose,
    /// Fitting error (m^2).
    pub eps_m2: f64,
}

/// The usable fits of a row (registered pose, status not `Failed`, finite eps),
/// best (lowest eps) first.
pub fn usable_fits(fits: &Value) -> Vec<FitEntry> {
    let mut out: Vec<FitEntry> = fits
        .as_array()
        .into_iter()
        .flatten()
        .filter(|f| f.get("status").and_then(Value::as_str) != Some("Failed"))
        .filter_map(|f| {
            let model_id = f.get("model_id")?.as_u64()? as usize;
            let pose: crate::geometry::PoseJson =
                serde_json::from_value(f.get("base_from_model")?.clone()).ok()?;
            let eps_m2 = f.get("eps_m2")?.as_f64().filter(|e| e.is_finite())?;
            Some(FitEntry {
                model_id,
                base_from_model: pose.to_pose("fit").ok()?,
                eps_m2,
            })
        })
        .collect();
    out.sort_by(|a, b| a.eps_m2.total_cmp(&b.eps_m2));
    out
}

fn numbers<const N: usize>(value: Option<&Value>) -> Option<[f64; N]> {
    let list = value?.as_array()?;
    if list.len() != N {
        return None;
    }
    let mut out = [0.0; N];
    for (o, v) in out.iter_mut().zip(list) {
        *o = v.as_f64().filter(|x| x.is_finite())?;
    }
    Some(out)
}

/// The caption of a trial: what, how, graded how, and how fast.
pub fn caption(record: &TrialRecord, notes: &[String]) -> Vec<String> {
    let t = &record.trial;
    let outcome = t.outcome.as_ref();
    let epsilon = outcome
        .and_then(|o| o.get("epsilon"))
        .and_then(Value::as_f64)
        .map_or("-".to_string(), |e| format!("{e:.3}"));
    let command_s = outcome
        .and_then(|o| o.pointer("/timings_s/snapshot_to_grasp_command_s"))
        .and_then(Value::as_f64)
        .filter(|s| *s > 0.0)
        .map_or("-".to_string(), |s| format!("{s:.2} S"));
    let grade = record
        .grading
        .as_ref()
        .map_or("UNGRADED".to_string(), |g| match g.cause {
            Some(c) => format!("{} ({c})", g.grade),
            None => g.grade.to_string(),
        });
    let mut lines = vec![
        format!(
            "TRIAL {}  {} / {}  METHOD {}  OBJECT {} P{}",
            record.id, t.category, t.task, t.method, t.object.name, t.placement.index
        ),
        format!("GRADE {grade}  EPS {epsilon}  SNAPSHOT-COMMAND {command_s}"),
    ];
    if !notes.is_empty() {
        lines.push(notes.join("; "));
    }
    lines
}

/// Builds the scene of `record`; what cannot be shown is named in the caption.
pub fn trial_scene(record: &TrialRecord, inputs: &SceneInputs<'_>) -> TrialScene {
    let t = &record.trial;
    let mut notes: Vec<String> = Vec::new();
    let table = &inputs.config.table;
    let mut solids = vec![Solid::table(
        table.center_xy_m,
        table.extent_xy_m,
        table.height_m,
    )];

    // The segmented cloud.
    let cloud_m: Vec<Point3<f64>> = match &t.snapshot_path {
        None => {
            notes.push("NO SNAPSHOT".into());
            Vec::new()
        }
        Some(path) => match crate::cloud::io::read_cloud(path)
            .map_err(|e| e.to_string())
            .and_then(|cloud| {
                crate::cloud::segment::segment_object(
                    &cloud,
                    &inputs.base_from_camera,
                    &crate::cloud::segment::SegmentParams::for_cell(inputs.config),
                )
                .map_err(|e| e.to_string())
            }) {
            Ok(object) => object
                .valid_points()
                .map(|p| Point3::new(p.x as f64, p.y as f64, p.z as f64))
                .collect(),
            Err(e) => {
                tracing::warn!(trial = record.id, "snapshot {}: {e}", path.display());
                notes.push("NO SEGMENTED CLOUD".into());
                Vec::new()
            }
        },
    };

    // The models.
    let fits = usable_fits(&t.fits);
    match inputs.db {
        Some(db) => {
            for (rank, fit) in fits.iter().enumerate() {
                let (Some(mesh), Some(entry)) = (
                    db.meshes.get(fit.model_id),
                    db.file.models.get(fit.model_id),
                ) else {
                    continue;
                };
                let part = if rank == 0 {
                    Part::BestModel
                } else {
                    Part::OtherModel
                };
                solids.push(Solid::from_mesh(
                    &entry.name,
                    part,
                    mesh,
                    &fit.base_from_model,
                ));
            }
        }
        None if !fits.is_empty() => notes.push("NO MODEL DATABASE".into()),
        None => {}
    }
    if fits.is_empty() {
        notes.push("NO REGISTERED MODEL".into());
    }

    // The hand and contacts.
    let outcome = t.outcome.as_ref();
    let joints = numbers::<7>(outcome.and_then(|o| o.get("closing_joints_rad"))).or_else(|| {
        t.planned_joints
            .as_ref()
            .and_then(|q| <[f64; 7]>::try_from(q.as_slice()).ok())
    });
    let spread_rad = outcome
        .and_then(|o| o.get("spread_rad"))
        .and_then(Value::as_f64)
        .filter(|s| s.is_finite())
        .unwrap_or(0.0);
    let mut contacts_m = Vec::new();
    match joints {
        None => notes.push("NOT EXECUTED".into()),
        Some(q) => {
            let base_from_palm = inputs.robot.arm().palm(&q);
            let mut hand = HandPose {
                spread_rad,
                flex_rad: [0.0; 3],
            };
            match simulated_grasp(record, inputs, &base_from_palm, spread_rad) {
                Some((closed, contacts)) => {
                    hand = closed;
                    contacts_m = contacts;
                }
                None => notes.push("FINGERS NOT SIMULATED".into()),
            }
            for (link, palm_from_link) in inputs.hand.link_poses(&hand) {
                let base_from_link = base_from_palm * palm_from_link;
                for (link_from_shape, shape) in &link.shapes {
                    if let Some(s) = Solid::from_shape(
                        &link.name,
                        Part::Hand,
                        shape,
                        &(base_from_link * link_from_shape),
                    ) {
                        solids.push(s);
                    }
                }
            }
        }
    }

    let focus_m = fits
        .first()
        .map(|f| Point3::from(f.base_from_model.translation.vector))
        .or_else(|| centroid(&cloud_m))
        .unwrap_or_else(|| {
            let p = &t.placement.base_from_object.xyz;
            Point3::new(p[0], p[1], p[2])
        })
        + nalgebra::Vector3::new(0.0, 0.0, 0.06);
    TrialScene {
        cloud_m,
        solids,
        contacts_m,
        base_from_camera: inputs.base_from_camera,
        focus_m,
        caption: caption(record, &notes),
    }
}

fn centroid(points: &[Point3<f64>]) -> Option<Point3<f64>> {
    (!points.is_empty()).then(|| {
        Point3::from(
            points
                .iter()
                .map(|p| p.coords)
                .sum::<nalgebra::Vector3<f64>>()
                / points.len() as f64,
        )
    })
}

/// The fingers closed on the true object (a procedural object of the row's
/// category and seed at its placement) and the contacts (base frame), as the
/// simulated observer closes them; `None` when the object is not known to the
/// simulator or the simulation fails.
fn simulated_grasp(
    record: &TrialRecord,
    inputs: &SceneInputs<'_>,
    base_from_palm: &Pose,
    spread_rad: f64,
) -> Option<(HandPose, Vec<Point3<f64>>)> {
    let t = &record.trial;
    let category: Category = t.category.parse().ok()?;
    let seed = t.object.seed?;
    let base_from_object = t.placement.base_from_object.to_pose("placement").ok()?;
    let mesh = generate(category, seed).0;
    let table_in_object = inputs.config.table.height_m - base_from_object.translation.vector.z;
    let object = GraspObject::new(&mesh, Path::new(&t.object.name))
        .ok()?
        .with_table(Some(table_in_object));
    let object_from_palm = base_from_object.inverse() * base_from_palm;
    let outcome = close_hand(
        inputs.hand,
        &object,
        &object_from_palm,
        &crate::robot::HandPose::open(spread_rad),
        &AutoGraspOptions::default(),
    )
    .map_err(|e| tracing::warn!(trial = record.id, "grasp simulation: {e}"))
    .ok()?;
    let contacts = outcome
        .contacts
        .iter()
        .map(|c| base_from_object * c.point)
        .collect();
    Some((outcome.hand, contacts))
}
