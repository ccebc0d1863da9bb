//! Teach-in grasps proposed for procedural models, as a starting point for the
//! user-editable `grasps.toml` (`cell train suggest-grasps`).
//!
//! Each task has a template built from the instance's procedural parameters: an
//! approach direction, a palm orientation, a target point and a spread (mug `top`:
//! from above over the opening, fingers spread about 60 deg around the rim and
//! clear of the handle; mug and bottle `side`: from the side opposite the handle,
//! the fingers wrapping the body; mug `handle`: from the handle's side, the fingers
//! around its bar; hammer and knife `use`: from above, the fingers around the
//! handle). A candidate varies the template by a lateral offset, three angles,
//! the spread and the pre-shape; the palm then approaches along its z axis until
//! the hand in its pre-shape touches (GraspIt!'s "approach to contact") and the
//! hand closes (auto-grasp).
//!
//! Hammers and knives lie flat, and with the table present (`--table-z`) the open
//! fingers meet it before anything else: their templates pre-shape the fingers
//! (every flex about 1.2 rad, just past the fingertips' lowest point, so that
//! closing sweeps the tips inward and up from the table) and pinch the hammer's
//! head across (F3 on the face side, F1 and F2 spread about the handle) and the
//! knife's handle across. A pinch of a hammer's handle does not hold: the distal
//! links, bent inward, meet its upper edges first and push it down.
//! A seeded random search followed by a pattern search maximises epsilon within the
//! template's bounds, so the suggestion stays a grasp of the intended kind.

use super::teach::{TeachFile, TeachGrasp, TeachModel};
use crate::geometry::{params_from_pose, pose_from_params, Pose, PoseJson, PoseParams};
use crate::mesh::procedural::{Category, Params};
use crate::mesh::TriMesh;
use crate::quality::autograsp::{
    evaluate_grasp, open_hand_collision, AutoGraspOptions, GraspObject,
};
use crate::quality::QualityParams;
use crate::robot::hand::HandModel;
use crate::robot::{HandPose, PreshapeRad};
use nalgebra::{Point2, Point3, Rotation3, Translation3, UnitQuaternion, Vector3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use std::f64::consts::PI;
use std::path::PathBuf;

/// A kind of grasp for one instance: where the palm aims and how far it may vary.
#[derive(Debug, Clone, PartialEq)]
pub struct Template {
    /// The task.
    pub task: &'static str,
    /// Object frame from the palm's nominal orientation (translation unused).
    pub orientation: UnitQuaternion<f64>,
    /// The point the palm's centre line aims at (object frame, m).
    pub target: Point3<f64>,
    /// Nominal spread (rad).
    pub spread_rad: f64,
    /// Nominal pre-shape: every finger's flex before the approach (rad; 0 open).
    pub preshape_rad: f64,
    /// Ranges of the search ([`Offsets`]): half-ranges of the lateral offset (m),
    /// roll/pitch/yaw about the palm axes (rad) and spread (rad), the largest
    /// back-off from contact (m), and the half-range of the pre-shape (rad).
    pub bounds: Offsets,
}

/// A candidate's offsets from its template: lateral x, y (m, palm frame), roll,
/// pitch, yaw (rad, palm axes), spread (rad), back-off from contact along the
/// approach (m, >= 0), pre-shape flex (rad).
pub type Offsets = [f64; 8];

/// Settings of the search.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SuggestOptions {
    /// Seed of the random search.
    pub seed: u64,
    /// Random candidates before the pattern search.
    pub samples: usize,
    /// Most evaluations of the pattern search.
    pub refine_evaluations: usize,
}

impl Default for SuggestOptions {
    fn default() -> Self {
        SuggestOptions {
            seed: 1,
            samples: 300,
            refine_evaluations: 200,
        }
    }
}

/// A suggested grasp and its quality.
#[derive(Debug, Clone, PartialEq)]
pub struct Suggestion {
    /// The task.
    pub task: &'static str,
    /// Palm pose parameters in the object frame.
    pub params: PoseParams,
    /// Spread (rad).
    pub spread_rad: f64,
    /// Pre-shape (rad).
    pub preshape_rad: PreshapeRad,
    /// Epsilon of the grasp.
    pub epsilon: f64,
}

fn basis(x: Vector3<f64>, y: Vector3<f64>, z: Vector3<f64>) -> UnitQuaternion<f64> {
    UnitQuaternion::from_rotation_matrix(&Rotation3::from_basis_unchecked(&[x, y, z]))
}

/// Bounds of the vertices of `mesh` within `half_width_m` of `x_m` along x:
/// (min, max) corners.
fn slice_bounds(mesh: &TriMesh, x_m: f64, half_width_m: f64) -> Option<(Point3<f64>, Point3<f64>)> {
    let mut it = mesh
        .vertices
        .iter()
        .filter(|v| (v.x - x_m).abs() <= half_width_m);
    let first = *it.next()?;
    Some(it.fold((first, first), |(lo, hi), v| (lo.inf(v), hi.sup(v))))
}

/// The centre of the circle through the three flex axes at `spread_rad` (palm xy).
pub fn finger_circle_centre(hand: &HandModel, spread_rad: f64) -> Point2<f64> {
    let p: Vec<Point2<f64>> = hand
        .fingers
        .iter()
        .map(|f| {
            let t = f.palm_from_flex_base(spread_rad).translation.vector;
            Point2::new(t.x, t.y)
        })
        .collect();
    let (a, b, c) = (p[0], p[1], p[2]);
    let d = 2.0 * (a.x * (b.y - c.y) + b.x * (c.y - a.y) + c.x * (a.y - b.y));
    if d.abs() < 1e-12 {
        return Point2::from((a.coords + b.coords + c.coords) / 3.0);
    }
    let n = |q: Point2<f64>| q.coords.norm_squared();
    Point2::new(
        (n(a) * (b.y - c.y) + n(b) * (c.y - a.y) + n(c) * (a.y - b.y)) / d,
        (n(a) * (c.x - b.x) + n(b) * (a.x - c.x) + n(c) * (b.x - a.x)) / d,
    )
}

/// A top-grasp yaw that keeps every finger's direction farthest from +x (the
/// handle), on a 1-degree grid.
fn yaw_clear_of_handle(hand: &HandModel, spread_rad: f64) -> f64 {
    let centre = finger_circle_centre(hand, spread_rad);
    let directions: Vec<f64> = hand
        .fingers
        .iter()
        .map(|f| {
            let t = f.palm_from_flex_base(spread_rad).translation.vector;
            // Palm -> object under rpy (pi, 0, 0): (x, y) -> (x, -y).
            (-(t.y - centre.y)).atan2(t.x - centre.x)
        })
        .collect();
    (0..360)
        .map(|k| (k as f64).to_radians())
        .max_by(|a, b| {
            let clearance = |yaw: f64| {
                directions
                    .iter()
                    .map(|d| crate::geometry::wrap_angle(d + yaw).abs())
                    .fold(f64::INFINITY, f64::min)
            };
            clearance(*a).total_cmp(&clearance(*b))
        })
        .unwrap_or(0.0)
}

/// The templates of an instance (object frame of its procedural mesh).
pub fn templates(hand: &HandModel, params: &Params, mesh: &TriMesh) -> Vec<Template> {
    let side = basis(Vector3::z(), -Vector3::y(), Vector3::x());
    let narrow = [0.008, 0.008, 0.15, 0.15, 0.15, 0.2, 0.0, 0.0];
    match params {
        Params::Mug(m) => {
            let spread = 0.5;
            let mut out = vec![
                Template {
                    task: "top",
                    orientation: UnitQuaternion::from_euler_angles(
                        PI,
                        0.0,
                        yaw_clear_of_handle(hand, spread),
                    ),
                    target: Point3::new(0.0, 0.0, m.height_m),
                    spread_rad: spread,
                    preshape_rad: 0.0,
                    bounds: [0.008, 0.008, 0.12, 0.12, 0.3, 0.5, 0.06, 0.0],
                },
                Template {
                    task: "side",
                    orientation: side,
                    target: Point3::new(0.0, 0.0, (0.5 * m.height_m).max(0.05)),
                    spread_rad: 0.0,
                    preshape_rad: 0.0,
                    bounds: narrow,
                },
            ];
            if let Some(h) = &m.handle {
                out.push(Template {
                    task: "handle",
                    orientation: basis(Vector3::z(), Vector3::y(), -Vector3::x()),
                    target: Point3::new(0.0, 0.0, 0.5 * (h.lower_z_m + h.upper_z_m)),
                    spread_rad: 0.0,
                    preshape_rad: 0.0,
                    bounds: narrow,
                });
            }
            out
        }
        Params::Bottle(b) => vec![Template {
            task: "side",
            orientation: side,
            target: Point3::new(
                0.0,
                0.0,
                (0.5 * b.body_height_m).clamp(0.05, (b.body_height_m - 0.03).max(0.05)),
            ),
            spread_rad: 0.0,
            preshape_rad: 0.0,
            bounds: narrow,
        }],
        Params::Hammer(h) => {
            // The head (along y at the -x end) pinched across from above: palm y
            // along -x puts F3 on the face side, F1 and F2 (spread apart) on the
            // handle's side, one either side of it.
            let (lo, hi) = crate::mesh::topology::bounding_box(mesh)
                .unwrap_or((Point3::origin(), Point3::origin()));
            let x = lo.x + 0.5 * h.head_section_m;
            vec![Template {
                task: "use",
                orientation: UnitQuaternion::from_euler_angles(PI, 0.0, -0.5 * PI),
                target: Point3::new(x, 0.0, hi.z),
                spread_rad: 0.3,
                preshape_rad: 1.2,
                bounds: [0.01, 0.004, 0.1, 0.1, 0.1, 0.15, 0.01, 0.1],
            }]
        }
        Params::Knife(k) => {
            // The handle, across, at the middle of its length.
            let (lo, hi) = crate::mesh::topology::bounding_box(mesh)
                .unwrap_or((Point3::origin(), Point3::origin()));
            let x = hi.x - 0.5 * k.handle_length_m;
            let (slo, shi) = slice_bounds(mesh, x, 0.005).unwrap_or((lo, hi));
            vec![Template {
                task: "use",
                orientation: UnitQuaternion::from_euler_angles(PI, 0.0, 0.0),
                target: Point3::new(x, 0.5 * (slo.y + shi.y), shi.z),
                spread_rad: 0.0,
                preshape_rad: 1.35,
                bounds: [0.03, 0.006, 0.15, 0.15, 0.15, 0.3, 0.01, 0.15],
            }]
        }
    }
}

impl Template {
    /// The range of offset `i`.
    pub fn range(&self, i: usize) -> (f64, f64) {
        if i == 6 {
            (0.0, self.bounds[6])
        } else {
            (-self.bounds[i], self.bounds[i])
        }
    }

    /// Offsets drawn uniformly within the ranges.
    pub fn sample(&self, rng: &mut impl Rng) -> Offsets {
        std::array::from_fn(|i| {
            let (lo, hi) = self.range(i);
            if hi > lo {
                rng.gen_range(lo..=hi)
            } else {
                lo
            }
        })
    }

    /// The palm pose and the hand's pre-shape (spread and flex) of candidate `u`
    /// (offsets from the template: lateral x, y (m), roll, pitch, yaw (rad), spread
    /// (rad), back-off (m), pre-shape (rad)) after approaching `object` to contact
    /// from `standoff_m` away; None when the hand never touches or starts in
    /// collision.
    pub fn place(
        &self,
        hand: &HandModel,
        object: &GraspObject,
        u: &Offsets,
        standoff_m: f64,
    ) -> Option<(Pose, HandPose)> {
        let spread =
            (self.spread_rad + u[5]).clamp(hand.spread_limits_rad.0, hand.spread_limits_rad.1);
        let (flex_lo, flex_hi) = hand.flex_limits_rad();
        let preshape =
            PreshapeRad([(self.preshape_rad + u[7]).clamp(flex_lo, flex_hi); 3]).at_spread(spread);
        let rotation = self.orientation * UnitQuaternion::from_euler_angles(u[2], u[3], u[4]);
        let centre = finger_circle_centre(hand, spread);
        // The finger circle's centre (palm xy) on the line through the target.
        let lateral = rotation * Vector3::new(centre.x - u[0], centre.y - u[1], 0.0);
        let z = rotation * Vector3::z();
        let at = |travel: f64| {
            Pose::from_parts(
                Translation3::from(self.target.coords - lateral - z * (standoff_m - travel)),
                rotation,
            )
        };
        let collides =
            |travel: f64| open_hand_collision(hand, object, &at(travel), &preshape).is_some();
        if collides(0.0) {
            return None;
        }
        // 10 mm steps: thinner than any hand link along the approach.
        let step = 0.01;
        let mut free = 0.0;
        while free < 2.0 * standoff_m {
            let next = free + step;
            if collides(next) {
                let (mut a, mut b) = (free, next);
                while b - a > 5e-5 {
                    let mid = 0.5 * (a + b);
                    if collides(mid) {
                        b = mid;
                    } else {
                        a = mid;
                    }
                }
                // 20 um short of the contact, so that rounding cannot make it touch.
                return Some((at(a - 2e-5 - u[6]), preshape));
            }
            free = next;
        }
        None
    }
}

/// A standoff from which the open hand clears `object` (m).
pub fn standoff_m(object: &GraspObject) -> f64 {
    2.0 * object.torque_scale_m + 0.25
}

/// Evaluates candidates of one template on one object.
struct Search<'a> {
    hand: &'a HandModel,
    object: &'a GraspObject,
    template: &'a Template,
    standoff_m: f64,
    options: AutoGraspOptions,
    quality: QualityParams,
}

impl Search<'_> {
    fn place(&self, u: &Offsets) -> Option<(Pose, HandPose)> {
        self.template
            .place(self.hand, self.object, u, self.standoff_m)
    }

    /// Epsilon when force closure; otherwise a negative score that grows with the
    /// number of fingers (and the palm) touching, to lead the search toward closure.
    fn score_pose(&self, pose: &Pose, preshape: &HandPose) -> f64 {
        let Ok(e) = evaluate_grasp(
            self.hand,
            self.object,
            pose,
            preshape,
            &self.options,
            &self.quality,
            false,
        ) else {
            return -1.0;
        };
        if e.outcome.collision_at_start.is_some() {
            return -1.0;
        }
        if e.epsilon > 0.0 {
            return e.epsilon;
        }
        let touching = |prefix: &str| {
            e.outcome
                .contacts
                .iter()
                .any(|c| c.link.starts_with(prefix))
        };
        let fingers = self
            .hand
            .fingers
            .iter()
            .filter(|f| touching(&f.proximal.name) || touching(&f.distal.name))
            .count();
        -0.5 + 0.1 * fingers as f64 + 0.05 * f64::from(u8::from(touching(&self.hand.palm.name)))
    }

    fn score(&self, u: &Offsets) -> f64 {
        match self.place(u) {
            Some((pose, preshape)) => self.score_pose(&pose, &preshape),
            None => -1.0,
        }
    }
}

/// The best grasp found for `template` on `object`, if any is force closure.
pub fn suggest_grasp(
    hand: &HandModel,
    object: &GraspObject,
    template: &Template,
    quality: &QualityParams,
    options: &SuggestOptions,
) -> Option<Suggestion> {
    let search = Search {
        hand,
        object,
        template,
        standoff_m: standoff_m(object),
        options: AutoGraspOptions::default(),
        quality: *quality,
    };
    let mut rng = ChaCha8Rng::seed_from_u64(options.seed);
    let mut best_u = [0.0; 8];
    let mut best = search.score(&best_u);
    for _ in 0..options.samples {
        let u = template.sample(&mut rng);
        let s = search.score(&u);
        if s > best {
            (best, best_u) = (s, u);
        }
    }
    // Pattern search: try +- step along each coordinate, halve when nothing helps.
    let mut step: Offsets = std::array::from_fn(|i| {
        let (lo, hi) = template.range(i);
        (hi - lo) / 8.0
    });
    let first = step;
    let mut evaluations = 0;
    while evaluations < options.refine_evaluations && step[0] > first[0] / 32.0 {
        let mut improved = false;
        for i in 0..8 {
            if step[i] <= 0.0 {
                continue;
            }
            for sign in [-1.0, 1.0] {
                let (lo, hi) = template.range(i);
                let mut u = best_u;
                u[i] = (u[i] + sign * step[i]).clamp(lo, hi);
                evaluations += 1;
                let s = search.score(&u);
                if s > best {
                    (best, best_u, improved) = (s, u, true);
                }
            }
        }
        if !improved {
            step.iter_mut().for_each(|s| *s *= 0.5);
        }
    }
    if best <= 0.0 {
        return None;
    }
    let (pose, preshape) = search.place(&best_u)?;
    // Rounded for the file (0.01 mm, 1e-5 rad), kept only if still as good.
    let exact = params_from_pose(&pose);
    let rounded = exact.map(|v| (v * 1e5).round() / 1e5);
    let round = |v: f64| (v * 1e5).round() / 1e5;
    let preshape_rounded = HandPose {
        spread_rad: round(preshape.spread_rad),
        flex_rad: preshape.flex_rad.map(round),
    };
    let eps_rounded = search.score_pose(&pose_from_params(&rounded), &preshape_rounded);
    let eps_exact = search.score_pose(&pose, &preshape);
    let (params, preshape, epsilon) = if eps_rounded > 0.0 {
        (rounded, preshape_rounded, eps_rounded)
    } else {
        (exact, preshape, eps_exact)
    };
    (epsilon > 0.0).then_some(Suggestion {
        task: template.task,
        params,
        spread_rad: preshape.spread_rad,
        preshape_rad: PreshapeRad(preshape.flex_rad),
        epsilon,
    })
}

/// One model for [`suggest_teach_file`]: its mesh file (relative to the models
/// directory), mesh and procedural parameters.
#[derive(Debug, Clone)]
pub struct SuggestModel {
    /// Mesh file, relative to the models directory.
    pub file: PathBuf,
    /// The mesh.
    pub mesh: TriMesh,
    /// Its procedural parameters.
    pub params: Params,
}

/// What was suggested for one template.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct SuggestReport {
    /// Grasp name.
    pub name: String,
    /// Task.
    pub task: String,
    /// Epsilon of the suggestion, None when no force-closure grasp was found.
    pub epsilon: Option<f64>,
}

/// A teach file with the best grasp per model and task (models in order), and a
/// report per template; `tick` is called after each model.
pub fn suggest_teach_file(
    hand: &HandModel,
    category: Category,
    models: &[SuggestModel],
    table_height_m: Option<f64>,
    quality: &QualityParams,
    options: &SuggestOptions,
    tick: &(dyn Fn() + Sync),
) -> Result<(TeachFile, Vec<SuggestReport>), super::CategoryError> {
    use rayon::prelude::*;
    let per_model: Vec<Result<(TeachModel, Vec<SuggestReport>), super::CategoryError>> = models
        .par_iter()
        .map(|m| {
            let stem = m
                .file
                .file_stem()
                .map(|s| s.to_string_lossy().into_owned())
                .unwrap_or_default();
            let object = GraspObject::new(&m.mesh, &m.file)
                .map_err(|source| super::CategoryError::Model {
                    model: stem.clone(),
                    source,
                })?
                .with_table(table_height_m);
            let mut grasps = Vec::new();
            let mut reports = Vec::new();
            for t in templates(hand, &m.params, &m.mesh) {
                let name = format!("{stem}/{}", t.task);
                let s = suggest_grasp(hand, &object, &t, &object.quality_params(quality), options);
                reports.push(SuggestReport {
                    name: name.clone(),
                    task: t.task.to_string(),
                    epsilon: s.as_ref().map(|s| s.epsilon),
                });
                if let Some(s) = s {
                    grasps.push(TeachGrasp {
                        name,
                        task: s.task.to_string(),
                        pose: PoseJson {
                            xyz: [s.params[0], s.params[1], s.params[2]],
                            rpy: Some([s.params[3], s.params[4], s.params[5]]),
                            quat_xyzw: None,
                        },
                        spread_rad: s.spread_rad,
                        preshape_rad: s.preshape_rad,
                        max_overtravel_m: None,
                    });
                }
            }
            tick();
            Ok((
                TeachModel {
                    mesh: m.file.clone(),
                    name: None,
                    grasps,
                },
                reports,
            ))
        })
        .collect();
    let mut file = TeachFile {
        category: Some(category),
        table_height_m,
        models: Vec::new(),
    };
    let mut reports = Vec::new();
    for r in per_model {
        let (model, rep) = r?;
        file.models.push(model);
        reports.extend(rep);
    }
    Ok((file, reports))
}
