//! `cell quality` (`cell bench quality-metric` and `cell bench quality` are in `bench`).

use crate::config::CellConfig;
use crate::geometry::PoseJson;
use crate::geometry::{params_from_pose, parse_pose};
use crate::mesh::load_mesh;
use crate::quality::approach::{overtravel_problem, ApproachOptions, ApproachStop};
use crate::quality::autograsp::{
    evaluate_approached_grasp, ApproachedGrasp, AutoGraspOptions, FingerStop, GraspApproach,
    GraspObject, Obstacle, StartCollision,
};
use crate::quality::stability::{stability_range, StabilityOptions, StabilityRange};
use crate::quality::{self, Contact, GraspQuality, QualityParams};
use crate::robot::hand::HandModel;
use crate::robot::HandPose;
use crate::sim::physics::{lift_test, LiftOutcome, LiftScene, PhysicsObject, PhysicsOptions};
use anyhow::Context;
use clap::Args;
use nalgebra::Point3;
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};
use std::process::ExitCode;

/// Options of `cell quality`.
#[derive(Debug, Args)]
pub struct QualityArgs {
    /// Contacts file (JSON): {"mu": 0.5, "torque_scale": 0.05, "contacts": [{"point":
    /// [x,y,z], "normal": [nx,ny,nz]}], "centroid": [x,y,z], "cone_edges": 8}; metres,
    /// inward normals. Optional: mu (0.5), cone_edges (8), centroid (mean of the contact
    /// points), torque_scale (largest distance of a contact from the centroid).
    #[arg(long, required_unless_present = "object", conflicts_with = "object")]
    pub contacts: Option<PathBuf>,
    /// Object mesh (OBJ, STL or PLY; metres, closed and outward) to close the hand
    /// around (auto-grasp); needs --pose.
    #[arg(long, requires = "pose")]
    pub object: Option<PathBuf>,
    /// Palm pose (bh_palm) in the object's frame: x,y,z,roll,pitch,yaw (m, rad, URDF rpy).
    #[arg(long, requires = "object", allow_hyphen_values = true)]
    pub pose: Option<String>,
    /// Spread of F1 and F2 about the palm normal (rad, 0..pi).
    #[arg(
        long,
        default_value_t = 0.0,
        requires = "object",
        allow_hyphen_values = true
    )]
    pub spread: f64,
    /// Pre-shape: each finger's flex before the approach and the closing (rad), one
    /// value for F1, F2 and F3 or three (F1,F2,F3); 0 is the open hand (default).
    /// The BH8-282 positions each finger's puck, so each may differ. A flat tool
    /// on a table needs the fingers partly closed, or they meet the table first.
    #[arg(
        long,
        requires = "object",
        value_delimiter = ',',
        allow_hyphen_values = true
    )]
    pub preshape_rad: Option<Vec<f64>>,
    /// Height of a table top in the object's frame (m): the table becomes an obstacle.
    #[arg(long, requires = "object", allow_hyphen_values = true)]
    pub table_z: Option<f64>,
    /// Friction coefficient for --object.
    #[arg(long, default_value_t = 0.5, requires = "object")]
    pub mu: f64,
    /// Also compute the stability ranges (Delta, sigma per DOF) for --object.
    #[arg(long, requires = "object")]
    pub stability: bool,
    /// Approach to contact before closing (as the executor does): from the
    /// pre-grasp (robot.pregrasp_offset_m back along the palm's -z) the open hand
    /// moves along +z through --pose, at most approach.max_overtravel_m beyond it,
    /// and stops at first contact. Without it the hand closes at --pose (the
    /// paper's setting).
    #[arg(long, requires = "object")]
    pub approach_to_contact: bool,
    /// The grasp's own overtravel for --approach-to-contact (m), as a database grasp
    /// names it (`max_overtravel_m`; 0 for the mug's rim pinches): it replaces
    /// approach.max_overtravel_m.
    #[arg(long, requires = "approach_to_contact")]
    pub max_overtravel_m: Option<f64>,
    /// Also run the physics lift test (rapier3d) for --object: close, lift 0.10 m,
    /// hold 2 s, with the object free on the table (--table-z) and friction --mu.
    /// The object frame must be upright (z up). Prints the verdict, lift height,
    /// slip and the hand parts touching.
    #[arg(long, requires = "object")]
    pub lift: bool,
    /// Print JSON.
    #[arg(long)]
    pub json: bool,
}

/// The contacts file of `cell quality --contacts`.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ContactsFile {
    /// Friction coefficient.
    #[serde(default = "default_mu")]
    pub mu: f64,
    /// Torque scale (m).
    #[serde(default)]
    pub torque_scale: Option<f64>,
    /// The contacts.
    pub contacts: Vec<Contact>,
    /// Reference point for torques (m).
    #[serde(default)]
    pub centroid: Option<Point3<f64>>,
    /// Edges of the friction pyramid.
    #[serde(default = "default_cone_edges")]
    pub cone_edges: usize,
}

fn default_mu() -> f64 {
    QualityParams::default().mu
}

fn default_cone_edges() -> usize {
    QualityParams::default().cone_edges
}

impl ContactsFile {
    /// The metric parameters the file asks for.
    pub fn params(&self) -> QualityParams {
        QualityParams {
            mu: self.mu,
            cone_edges: self.cone_edges,
            torque_scale_m: self.torque_scale,
            centroid: self.centroid,
        }
    }
}

/// The hand's pre-shape from `--spread` and `--preshape-rad` (none: open; one
/// value: every finger; three: F1, F2, F3).
fn preshape_of(spread_rad: f64, flex: Option<&[f64]>) -> anyhow::Result<HandPose> {
    let flex_rad = match flex {
        None => [0.0; 3],
        Some(&[all]) => [all; 3],
        Some(&[f1, f2, f3]) => [f1, f2, f3],
        Some(other) => anyhow::bail!(
            "--preshape-rad takes one flex for every finger or three (F1,F2,F3), not {}",
            other.len()
        ),
    };
    Ok(HandPose {
        spread_rad,
        flex_rad,
    })
}

/// Runs `cell quality`.
pub fn run(config: &Path, args: QualityArgs) -> anyhow::Result<ExitCode> {
    if let Some(object) = &args.object {
        return run_object(config, object, &args);
    }
    let path = args
        .contacts
        .as_deref()
        .context("--contacts or --object is required")?;
    let q = evaluate_file(path)?;
    super::emit(args.json, &q, |q: &GraspQuality| {
        format!(
            "epsilon {:.6}, volume {:.6e}, force closure: {}\n",
            q.epsilon,
            q.volume,
            if q.force_closure { "yes" } else { "no" }
        )
    })?;
    Ok(ExitCode::SUCCESS)
}

/// A contact in the output of `cell quality --object`.
#[derive(Debug, Serialize)]
struct ContactJson {
    link: String,
    point: [f64; 3],
    normal: [f64; 3],
}

/// The output of `cell quality --object`.
#[derive(Debug, Serialize)]
struct AutoGraspReport {
    epsilon: f64,
    volume: f64,
    force_closure: bool,
    collision_at_start: bool,
    /// Which link collides with what, when collision_at_start.
    start_collision: Option<StartCollision>,
    contacts: Vec<ContactJson>,
    spread_rad: f64,
    flex_rad: [f64; 3],
    distal_rad: [f64; 3],
    stops: [FingerStop; 3],
    #[serde(skip_serializing_if = "Option::is_none")]
    stability: Option<StabilityRange>,
    /// Where the palm stopped, with --approach-to-contact.
    #[serde(skip_serializing_if = "Option::is_none")]
    approach: Option<ApproachStop>,
    /// The physics lift test, with --lift.
    #[serde(skip_serializing_if = "Option::is_none")]
    lift: Option<LiftOutcome>,
}

fn run_object(config: &Path, object: &Path, args: &QualityArgs) -> anyhow::Result<ExitCode> {
    let text = args.pose.as_deref().context("--object needs --pose")?;
    let pose = parse_pose(text).with_context(|| format!("--pose {text}"))?;
    let config = CellConfig::load(config)?;
    let hand = HandModel::load(&config)?;
    let mesh = load_mesh(object, 1.0)?;
    let grasp_object = GraspObject::new(&mesh, object)?.with_table(args.table_z);
    let options = AutoGraspOptions::default();
    let params = QualityParams {
        mu: args.mu,
        ..QualityParams::default()
    };
    let preshape = preshape_of(args.spread, args.preshape_rad.as_deref())?;
    if let Some(problem) = overtravel_problem(args.max_overtravel_m) {
        anyhow::bail!("--max-overtravel-m: {problem}");
    }
    let approach = if args.approach_to_contact {
        GraspApproach::ToContact(
            ApproachOptions::from_cell(&config).for_grasp(args.max_overtravel_m),
        )
    } else {
        GraspApproach::AtPose
    };
    let e = evaluate_approached_grasp(
        &hand,
        &grasp_object,
        &ApproachedGrasp {
            object_from_palm: pose,
            preshape,
            approach,
        },
        &options,
        &params,
        true,
    )
    .with_context(|| format!("grasp of {}", object.display()))?;
    let stability = if args.stability {
        Some(stability_range(
            &hand,
            &grasp_object,
            &params_from_pose(&pose),
            &preshape,
            &options,
            &params,
            &StabilityOptions::default(),
        )?)
    } else {
        None
    };
    let lift = if args.lift {
        let options = PhysicsOptions {
            friction: args.mu,
            ..PhysicsOptions::default()
        };
        let body = PhysicsObject::new(&mesh, object, &options)?;
        // The hand closes where the approach stopped, as the executor's does.
        let closed_at = e.approach.as_ref().map_or(pose, |a| a.object_from_palm);
        let scene = LiftScene {
            base_from_object: crate::geometry::Pose::identity(),
            base_from_palm: closed_at,
            preshape,
            table_height_m: args.table_z,
        };
        Some(
            lift_test(&hand, &body, &scene, &options)
                .with_context(|| format!("lift test of {}", object.display()))?,
        )
    } else {
        None
    };
    let o = e.outcome;
    let report = AutoGraspReport {
        epsilon: e.epsilon,
        volume: e.volume.unwrap_or(0.0),
        force_closure: e.force_closure,
        collision_at_start: o.collision_at_start.is_some(),
        start_collision: o.collision_at_start,
        contacts: o
            .contacts
            .iter()
            .map(|c| ContactJson {
                link: c.link.clone(),
                point: c.point.into(),
                normal: c.normal.into(),
            })
            .collect(),
        spread_rad: o.hand.spread_rad,
        flex_rad: o.hand.flex_rad,
        distal_rad: o.distal_rad,
        stops: o.stops,
        stability,
        approach: e.approach,
        lift,
    };
    super::emit(args.json, &report, |r: &AutoGraspReport| {
        let mut text = match &r.approach {
            Some(a) => {
                let p = PoseJson::from(&a.object_from_palm);
                format!(
                    "approach: palm stopped at {:.4},{:.4},{:.4} m ({:+.1} mm beyond --pose, {:.1} mm from the pre-grasp): {}\n",
                    p.xyz[0],
                    p.xyz[1],
                    p.xyz[2],
                    1e3 * a.beyond_plan_m,
                    1e3 * a.travel_m,
                    match (&a.start_collision, &a.contact) {
                        (Some(c), _) => format!("the pre-grasp collides: {c}"),
                        (None, Some(c)) => format!("first contact: link {} with the {}", c.link, match c.with {
                            Obstacle::Table => "table",
                            _ => "object",
                        }),
                        (None, None) => "no contact within the overtravel".to_string(),
                    }
                )
            }
            None => String::new(),
        };
        text += &match &r.start_collision {
            Some(c) => format!("invalid start: {c}\n"),
            None => format!(
                "epsilon {:.6}, volume {:.6e}, force closure: {}, {} contacts\n",
                r.epsilon,
                r.volume,
                if r.force_closure { "yes" } else { "no" },
                r.contacts.len()
            ),
        };
        for c in &r.contacts {
            text += &format!(
                "  {:<16} point {:>7.1} {:>7.1} {:>7.1} mm  normal {:>6.3} {:>6.3} {:>6.3}\n",
                c.link,
                1e3 * c.point[0],
                1e3 * c.point[1],
                1e3 * c.point[2],
                c.normal[0],
                c.normal[1],
                c.normal[2]
            );
        }
        if let Some(l) = &r.lift {
            text += &format!(
                "physics: {:?} ({:?}): rose {:.1} mm, slip {:.1} mm, turn {:.1} deg, touching {}; \
                 mass {:.3} kg, closed in {:.2} s, {} steps, the hand {:.1} mm into the table\n",
                l.grade,
                l.rule,
                1e3 * l.lift_height_m,
                1e3 * l.slip_m,
                l.turn_rad.to_degrees(),
                if l.contacts.is_empty() {
                    "nothing".to_string()
                } else {
                    l.contacts.join(" ")
                },
                l.mass_kg,
                l.close_s,
                l.steps,
                1e3 * l.table_penetration_m
            );
            if let Some(c) = &l.start_collision {
                text += &format!("  invalid start: {c}\n");
            }
        }
        if let Some(s) = &r.stability {
            text += &format!(
                "  Delta x y z {:.1} {:.1} {:.1} mm, ax ay az {:.1} {:.1} {:.1} deg\n",
                1e3 * s.delta[0],
                1e3 * s.delta[1],
                1e3 * s.delta[2],
                s.delta[3].to_degrees(),
                s.delta[4].to_degrees(),
                s.delta[5].to_degrees()
            );
        }
        text
    })?;
    Ok(ExitCode::SUCCESS)
}

/// Reads and evaluates a contacts file.
fn evaluate_file(path: &Path) -> anyhow::Result<GraspQuality> {
    let text = std::fs::read_to_string(path)
        .with_context(|| format!("cannot read contacts file {}", path.display()))?;
    let file: ContactsFile =
        serde_json::from_str(&text).with_context(|| format!("contacts file {}", path.display()))?;
    quality::evaluate(&file.contacts, &file.params())
        .with_context(|| format!("contacts file {}", path.display()))
}
