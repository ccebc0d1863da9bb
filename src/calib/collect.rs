//! The calibration routine: choose diverse robot poses that show the calibration
//! sphere to the camera, move through them, find the sphere in each depth cloud,
//! and return point samples (`base_from_flange`, `target_point_camera_m`).
//!
//! # Devices
//!
//! The arm and the camera are behind two small traits, [`ArmMover`] (move to joints,
//! read the joints and `base_from_flange`) and [`TargetCamera`] (capture a cloud in
//! the camera's optical frame), each call with a timeout. The simulated
//! implementations are in [`super::sim_rig`]. The hardware ones come later: the arm
//! over FRI (move along a joint trajectory, then read the *measured* joints, since
//! the commanded ones are not where the arm is, and compute `base_from_flange` by
//! forward kinematics), the camera from the depth device.
//!
//! # Choosing poses ([`plan_poses`])
//!
//! Candidates are drawn at random (seeded): a sphere centre in a box over the table,
//! the rig turned so that its outward direction (flange origin to sphere centre)
//! points at the camera within [`CollectOptions::max_tilt_deg`] and rolled by any
//! angle about it. All that the planner knows of the camera is the prior (the
//! nominal mount and the intrinsics). A candidate is kept when
//! - the sphere projects inside the image with [`CollectOptions::image_margin_px`]
//!   to spare and lies within the sensor's range and [`CollectOptions::max_distance_m`];
//! - the sphere clears the table by [`CollectOptions::rig_clearance_m`];
//! - the palm pose is reachable ([`Robot::reach`]: IK within the joint limits, no
//!   collision of arm or hand with the table or itself), and the sphere clears the
//!   arm's links;
//! - nothing of the robot hides the sphere: rays from the camera to nine points of
//!   its visible cap miss every collision primitive of the arm and hand.
//!
//! From the feasible pool, poses are chosen greedily (D-optimal): each step adds the
//! candidate that maximises `log det(M/P + ε_r I) + log det(C + ε_p I)`, where `M =
//! Σ v vᵀ` over the `P` pairs of chosen poses, `v` the rotation vector of the
//! flange's relative rotation (base frame), and `C` the covariance of the sphere
//! centres; `ε_r = (5°)²`, `ε_p = (1 cm)²`. Large relative rotations about axes
//! spread in every direction determine the camera rotation and the sphere's offset
//! on the flange; spread centres keep the point solver well conditioned. The chosen
//! poses are visited in nearest-neighbour order (joint space) from the start; each
//! move is a straight line in joint space checked every
//! [`CollectOptions::max_joint_step_rad`] for collisions (robot and sphere), or,
//! failing that, goes through the home configuration; a pose with neither is
//! dropped. [`Diversity`] reports how spread the result is.
//!
//! # Finding the sphere ([`find_target`])
//!
//! The sphere's expected centre in the camera follows from the prior mount, the
//! flange pose and the rig's nominal offset. The points within
//! [`CollectOptions::search_radius_m`] of it are searched for a sphere of the known
//! radius ([`fit_sphere`]: RANSAC, geometric least squares, a free-radius check),
//! and the fit must cover at least [`CollectOptions::min_coverage`] of the disc the
//! sphere covers in the image. A pose whose sphere is not found is skipped and
//! reported; fewer than three usable samples is an error, and nothing is written.

use super::motions::measure_motions;
use super::sphere_fit::{fit_sphere, SphereFitError, SphereFitOptions};
use super::{CalibError, PointSample};
use crate::cloud::PointCloud;
use crate::config::TableConfig;
use crate::geometry::Pose;
use crate::robot::collision::parry_shape;
use crate::robot::kinematics::{joint_distance_rad, ArmJoints, ARM_DOF};
use crate::robot::{HandPose, Robot, RobotError};
use crate::sim::camera::Intrinsics;
use nalgebra::{Isometry3, Matrix3, Point3, SymmetricEigen, Translation3, UnitQuaternion, Vector3};
use parry3d_f64::query::{self, Ray};
use parry3d_f64::shape::{Ball, SharedShape};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::Serialize;

/// Fewest usable samples a collection must give.
pub const MIN_USABLE_SAMPLES: usize = 3;
/// Regularisation of the rotation term of the selection (rad², (5°)²).
const SELECT_EPS_ROTATION_RAD2: f64 = 0.0076;
/// Regularisation of the position term of the selection (m², (1 cm)²).
const SELECT_EPS_POSITION_M2: f64 = 1e-4;
/// Angle of the ring of visibility rays from the direction to the camera (deg).
const VISIBILITY_RING_DEG: f64 = 55.0;

/// Errors of the calibration routine.
#[derive(Debug, thiserror::Error)]
pub enum CollectError {
    /// An option is out of range.
    #[error("{option} = {value}: {problem}")]
    BadOption {
        /// The option.
        option: &'static str,
        /// Its value, as text.
        value: String,
        /// What is wrong and what to give.
        problem: String,
    },
    /// A device failed or did not answer in time.
    #[error("{device}: {message}")]
    Device {
        /// Which device.
        device: &'static str,
        /// What happened.
        message: String,
    },
    /// Too few candidates passed the checks.
    #[error("only {feasible} of {candidates} candidate poses are feasible, need at least {need} ({rejections}): check the camera prior (camera.base_from_camera), the region and the rig, or ask for fewer poses")]
    TooFewFeasible {
        /// Feasible candidates.
        feasible: usize,
        /// Candidates tried.
        candidates: usize,
        /// Poses needed.
        need: usize,
        /// Why the others failed.
        rejections: Rejections,
    },
    /// Too few poses gave a usable observation.
    #[error("only {usable} of {planned} poses gave a usable observation of the sphere, need at least {need}; skipped: {skipped}. Check that the sphere is mounted, lit and in view, that camera.base_from_camera is within a few cm and degrees, and the rig's radius and offset")]
    TooFewUsable {
        /// Usable samples.
        usable: usize,
        /// Poses visited.
        planned: usize,
        /// Samples needed.
        need: usize,
        /// The skipped poses and why.
        skipped: String,
    },
    /// The planner would not use a configuration.
    #[error("configuration rejected: {0}")]
    Rejected(Rejection),
    /// The robot model refused a configuration.
    #[error(transparent)]
    Robot(#[from] RobotError),
    /// Writing or checking samples failed.
    #[error(transparent)]
    Calib(#[from] CalibError),
}

/// The arm, as the collector drives it. Hardware: FRI joint trajectory, measured joints.
pub trait ArmMover {
    /// Moves to `joints` (rad) and returns once there, or fails after `timeout_s`.
    fn move_to(&mut self, joints: &ArmJoints, timeout_s: f64) -> Result<(), CollectError>;
    /// The arm's joints now (measured on hardware).
    fn joints(&mut self, timeout_s: f64) -> Result<ArmJoints, CollectError>;
    /// The flange pose now, by forward kinematics of the measured joints.
    fn base_from_flange(&mut self, timeout_s: f64) -> Result<Pose, CollectError>;
}

/// The depth camera, as the collector uses it.
pub trait TargetCamera {
    /// One depth frame as a cloud in the optical frame (NaN where no return).
    fn capture(&mut self, timeout_s: f64) -> Result<PointCloud, CollectError>;
}

/// The calibration target: a sphere on a stalk fixed to the flange.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TargetRig {
    /// Sphere radius (m).
    pub radius_m: f64,
    /// The sphere's centre in the flange frame (m); nominal for the collector.
    pub flange_from_centre_m: Vector3<f64>,
    /// Where the stalk leaves the hand, flange frame (m).
    pub stalk_base_m: Vector3<f64>,
    /// Stalk radius (m).
    pub stalk_radius_m: f64,
}

impl TargetRig {
    /// A 40 mm sphere 14 cm out along the approach axis and 10 cm to the side (palm
    /// +x, clear of the open fingers, which lie along ±y), on a 6 mm stalk from the
    /// palm's side: seen from the camera's side of the hand, the hand is behind it.
    pub fn standard() -> TargetRig {
        TargetRig {
            radius_m: 0.04,
            flange_from_centre_m: Vector3::new(0.10, 0.0, 0.14),
            stalk_base_m: Vector3::new(0.044, 0.0, 0.045),
            stalk_radius_m: 0.006,
        }
    }

    /// The same rig with the sphere elsewhere on the flange (e.g. the true mount of
    /// a simulation, off the nominal one).
    pub fn with_centre(self, flange_from_centre_m: Vector3<f64>) -> TargetRig {
        TargetRig {
            flange_from_centre_m,
            ..self
        }
    }
}

/// What the collector knows of the camera before calibrating.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CameraPrior {
    /// Pinhole intrinsics and range.
    pub intrinsics: Intrinsics,
    /// The nominal (or last calibrated) mount.
    pub base_from_camera: Pose,
}

impl CameraPrior {
    /// Pixel coordinates and depth of a camera-frame point.
    fn project(&self, p: &Point3<f64>) -> (f64, f64, f64) {
        let i = &self.intrinsics;
        (
            i.fx_px * p.x / p.z + i.cx_px,
            i.fy_px * p.y / p.z + i.cy_px,
            p.z,
        )
    }

    fn focal_px(&self) -> f64 {
        (self.intrinsics.fx_px * self.intrinsics.fy_px).sqrt()
    }
}

/// Options of the routine; [`CollectOptions::new`] gives the defaults.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CollectOptions {
    /// Poses to visit.
    pub poses: usize,
    /// Seed of the candidate draw and the RANSAC.
    pub seed: u64,
    /// Most candidates drawn.
    pub max_candidates: usize,
    /// Drawing stops when this many times `poses` candidates are feasible.
    pub pool_factor: usize,
    /// Sphere centres are drawn in this box, base frame (m): lower corner.
    pub region_min_m: [f64; 3],
    /// Upper corner (m).
    pub region_max_m: [f64; 3],
    /// Largest angle between the rig's outward direction and the camera (deg).
    pub max_tilt_deg: f64,
    /// The sphere's image must stay this far inside the image (px).
    pub image_margin_px: f64,
    /// Farthest sphere from the camera (m): the depth noise grows with z².
    pub max_distance_m: f64,
    /// Clearance of the sphere from the table and the arm (m).
    pub rig_clearance_m: f64,
    /// The hand's joints during the collection.
    pub hand: HandPose,
    /// The home configuration moves may pass through.
    pub home: ArmJoints,
    /// Collision checks along a move every this much joint motion (rad).
    pub max_joint_step_rad: f64,
    /// Points within this of the expected centre are searched (m).
    pub search_radius_m: f64,
    /// The fit's inliers must cover this fraction of the sphere's image disc.
    pub min_coverage: f64,
    /// The sphere fit.
    pub fit: SphereFitOptions,
    /// Timeout of one move (s).
    pub move_timeout_s: f64,
    /// Timeout of one capture or joint read (s).
    pub capture_timeout_s: f64,
}

impl CollectOptions {
    /// Defaults for `poses` poses, a sphere of `radius_m`, seed `seed`.
    pub fn new(poses: usize, radius_m: f64, seed: u64) -> CollectOptions {
        CollectOptions {
            poses,
            seed,
            max_candidates: 200 * poses.max(1),
            pool_factor: 5,
            region_min_m: [0.35, -0.35, 0.15],
            region_max_m: [0.85, 0.35, 0.55],
            max_tilt_deg: 70.0,
            image_margin_px: 40.0,
            max_distance_m: 1.6,
            rig_clearance_m: 0.03,
            hand: HandPose::OPEN,
            home: [0.0; ARM_DOF],
            max_joint_step_rad: 0.05,
            search_radius_m: 0.12,
            min_coverage: 0.4,
            fit: SphereFitOptions::kinect(radius_m),
            move_timeout_s: 60.0,
            capture_timeout_s: 5.0,
        }
    }

    fn check(&self) -> Result<(), CollectError> {
        let bad = |option, value: String, problem: &str| CollectError::BadOption {
            option,
            value,
            problem: problem.to_string(),
        };
        if self.poses < MIN_USABLE_SAMPLES {
            return Err(bad(
                "poses",
                self.poses.to_string(),
                "need at least 3 (10–30 are typical; the unknown sphere offset needs 5)",
            ));
        }
        if !(self.fit.radius_m.is_finite() && self.fit.radius_m > 0.0) {
            return Err(bad(
                "sphere radius",
                self.fit.radius_m.to_string(),
                "must be a finite number > 0 (m)",
            ));
        }
        for i in 0..3 {
            if self.region_min_m[i].partial_cmp(&self.region_max_m[i])
                != Some(std::cmp::Ordering::Less)
            {
                return Err(bad(
                    "region",
                    format!("{:?}..{:?}", self.region_min_m, self.region_max_m),
                    "each lower bound must be below its upper bound",
                ));
            }
        }
        Ok(())
    }
}

/// How many candidates failed each check.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize)]
pub struct Rejections {
    /// The sphere would be outside the image or the range.
    pub out_of_view: usize,
    /// The sphere would touch the table or the arm.
    pub rig_collision: usize,
    /// The palm pose is not reachable (IK, limits, collision).
    pub unreachable: usize,
    /// The robot would hide the sphere.
    pub occluded: usize,
    /// No collision-free move to the pose (dropped after selection).
    pub no_path: usize,
}

impl std::fmt::Display for Rejections {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "{} out of view, {} sphere collisions, {} unreachable, {} occluded, {} without a path",
            self.out_of_view, self.rig_collision, self.unreachable, self.occluded, self.no_path
        )
    }
}

/// How spread a set of poses is.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Diversity {
    /// Spread of the relative rotation axes (deg; 90 for axes spread in every
    /// direction), as [`measure_motions`] reports it.
    pub axis_spread_deg: f64,
    /// Square roots of the eigenvalues of the mean `v vᵀ` over pairs, `v` the
    /// relative rotation vector, largest first (deg): the RMS relative rotation about
    /// each principal axis. The last is the weakest direction.
    pub rotation_rms_deg: [f64; 3],
    /// Median rotation between two poses (deg).
    pub median_pair_rotation_deg: f64,
    /// Standard deviations of the sphere centres along their principal axes (m).
    pub position_spread_m: [f64; 3],
}

/// The flange's relative rotation vector between two poses (base frame, rad).
fn relative_rotation(a: &UnitQuaternion<f64>, b: &UnitQuaternion<f64>) -> Vector3<f64> {
    (b * a.inverse()).scaled_axis()
}

/// Sorted (descending) eigenvalues of a symmetric matrix, clamped at zero.
fn eigenvalues_desc(m: &Matrix3<f64>) -> [f64; 3] {
    let mut e: Vec<f64> = SymmetricEigen::new(*m)
        .eigenvalues
        .iter()
        .map(|v| v.max(0.0))
        .collect();
    e.sort_by(|a, b| b.total_cmp(a));
    [e[0], e[1], e[2]]
}

fn covariance(points: &[Point3<f64>]) -> Matrix3<f64> {
    let n = points.len().max(1) as f64;
    let mean = points.iter().map(|p| p.coords).sum::<Vector3<f64>>() / n;
    points
        .iter()
        .map(|p| (p.coords - mean) * (p.coords - mean).transpose())
        .sum::<Matrix3<f64>>()
        / n
}

/// The diversity of flange poses and sphere centres (at least 3 of each).
pub fn diversity(base_from_flange: &[Pose], centres: &[Point3<f64>]) -> Diversity {
    let axis_spread_deg = measure_motions(base_from_flange).map_or(0.0, |c| c.axis_spread_deg);
    let mut scatter = Matrix3::zeros();
    let mut angles = Vec::new();
    for (i, a) in base_from_flange.iter().enumerate() {
        for b in &base_from_flange[i + 1..] {
            let v = relative_rotation(&a.rotation, &b.rotation);
            scatter += v * v.transpose();
            angles.push(v.norm().to_degrees());
        }
    }
    let pairs = angles.len().max(1) as f64;
    let e = eigenvalues_desc(&(scatter / pairs));
    let p = eigenvalues_desc(&covariance(centres));
    Diversity {
        axis_spread_deg,
        rotation_rms_deg: e.map(|v| v.sqrt().to_degrees()),
        median_pair_rotation_deg: if angles.is_empty() {
            0.0
        } else {
            crate::stats::median(&mut angles)
        },
        position_spread_m: p.map(f64::sqrt),
    }
}

/// Greedy D-optimal choice of `n` of the poses (flange rotations and sphere
/// centres); returns their indices in the order chosen (see the module doc).
pub fn select_diverse(
    rotations: &[UnitQuaternion<f64>],
    centres: &[Point3<f64>],
    n: usize,
) -> Vec<usize> {
    let count = rotations.len().min(centres.len());
    if count == 0 || n == 0 {
        return Vec::new();
    }
    let mut chosen = vec![0];
    let mut taken = vec![false; count];
    taken[0] = true;
    let mut scatter = Matrix3::zeros();
    let mut pairs = 0usize;
    let eps_r = Matrix3::identity() * SELECT_EPS_ROTATION_RAD2;
    let eps_p = Matrix3::identity() * SELECT_EPS_POSITION_M2;
    while chosen.len() < n.min(count) {
        let mut best: Option<(f64, usize, Matrix3<f64>)> = None;
        for k in (0..count).filter(|&k| !taken[k]) {
            let mut m = scatter;
            for &i in &chosen {
                let v = relative_rotation(&rotations[i], &rotations[k]);
                m += v * v.transpose();
            }
            let p = (pairs + chosen.len()) as f64;
            let mut points: Vec<Point3<f64>> = chosen.iter().map(|&i| centres[i]).collect();
            points.push(centres[k]);
            let score = (m / p + eps_r).determinant().ln()
                + (covariance(&points) + eps_p).determinant().ln();
            if best.as_ref().is_none_or(|(s, _, _)| score > *s) {
                best = Some((score, k, m));
            }
        }
        let Some((_, k, m)) = best else { break };
        pairs += chosen.len();
        scatter = m;
        chosen.push(k);
        taken[k] = true;
    }
    chosen
}

/// One pose of the plan.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PlannedPose {
    /// Joints (rad).
    pub joints: ArmJoints,
    /// The flange pose by forward kinematics.
    pub base_from_flange: Pose,
    /// The sphere centre expected there (base frame, nominal rig).
    pub centre_base_m: Point3<f64>,
    /// The move there goes through the home configuration.
    pub via_home: bool,
}

/// The chosen poses, in visiting order, and how they were found.
#[derive(Debug, Clone, PartialEq)]
pub struct Plan {
    /// The poses, in visiting order.
    pub poses: Vec<PlannedPose>,
    /// The home configuration moves may pass through.
    pub home: ArmJoints,
    /// Candidates drawn.
    pub candidates: usize,
    /// Candidates that passed every check.
    pub feasible: usize,
    /// Why the others failed.
    pub rejections: Rejections,
    /// The spread of the chosen poses.
    pub diversity: Diversity,
}

/// Progress of a long step, for a progress bar.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Progress {
    /// Candidates drawn so far, of at most this many; feasible so far.
    Planning {
        /// Candidates drawn.
        drawn: usize,
        /// Most candidates.
        max: usize,
        /// Feasible so far.
        feasible: usize,
    },
    /// Poses visited, of this many.
    Capturing {
        /// Poses visited.
        done: usize,
        /// Poses planned.
        total: usize,
    },
}

/// Collision and visibility geometry of the robot for the planner.
struct RobotGeometry<'a> {
    robot: &'a Robot,
    /// Per link: its shapes (link_from_shape, shape).
    shapes: Vec<Vec<(Pose, SharedShape)>>,
    /// Links that do not move with the flange (the sphere may hit them).
    not_on_flange: Vec<usize>,
}

impl<'a> RobotGeometry<'a> {
    fn new(robot: &'a Robot, flange_link: usize) -> RobotGeometry<'a> {
        let d = &robot.description;
        let shapes = d
            .links
            .iter()
            .map(|l| {
                l.shapes
                    .iter()
                    .map(|s| {
                        let (shape, local) = parry_shape(&s.primitive);
                        (s.link_from_shape * local, shape)
                    })
                    .collect()
            })
            .collect();
        let to_flange = d.path_to(flange_link);
        let not_on_flange = (0..d.links.len())
            .filter(|&l| l != flange_link && !d.path_to(l).starts_with(&to_flange))
            .collect();
        RobotGeometry {
            robot,
            shapes,
            not_on_flange,
        }
    }

    /// True when a ball at `centre` of `radius` touches a link not on the flange.
    fn ball_hits_arm(&self, poses: &[Pose], centre: &Point3<f64>, radius: f64) -> bool {
        let ball = Ball::new(radius);
        let at = Isometry3::translation(centre.x, centre.y, centre.z);
        self.not_on_flange.iter().any(|&l| {
            self.shapes[l].iter().any(|(local, shape)| {
                query::intersection_test(&at, &ball, &(poses[l] * local), shape.as_ref())
                    .unwrap_or(true)
            })
        })
    }

    /// True when any link shape blocks the segment from `eye` to `target`.
    fn blocks(&self, poses: &[Pose], eye: &Point3<f64>, target: &Point3<f64>) -> bool {
        let ray = Ray::new(*eye, target - eye);
        let limit = 1.0 - 1e-3 / (target - eye).norm().max(1e-9);
        self.shapes.iter().enumerate().any(|(l, shapes)| {
            shapes.iter().any(|(local, shape)| {
                shape
                    .cast_ray(&(poses[l] * local), &ray, limit, true)
                    .is_some()
            })
        })
    }
}

/// The planner's per-candidate checks.
struct Checker<'a> {
    geometry: RobotGeometry<'a>,
    camera: &'a CameraPrior,
    rig: &'a TargetRig,
    table: &'a TableConfig,
    options: &'a CollectOptions,
    flange_from_palm: Pose,
}

impl Checker<'_> {
    /// Whether the sphere centre is in view of the prior camera.
    fn in_view(&self, centre: &Point3<f64>) -> bool {
        let p = self.camera.base_from_camera.inverse() * centre;
        if p.z <= 0.0 {
            return false;
        }
        let i = &self.camera.intrinsics;
        let r = self.rig.radius_m;
        let (u, v, z) = self.camera.project(&p);
        let radius_px = self.camera.focal_px() * r / z;
        let m = self.options.image_margin_px + radius_px;
        u >= m
            && v >= m
            && u <= f64::from(i.width_px) - 1.0 - m
            && v <= f64::from(i.height_px) - 1.0 - m
            && z - r >= i.min_range_m
            && z + r <= i.max_range_m
            && p.coords.norm() <= self.options.max_distance_m
    }

    fn above_table(&self, centre: &Point3<f64>) -> bool {
        centre.z - self.rig.radius_m - self.options.rig_clearance_m > self.table.height_m
    }

    fn centre_at(&self, base_from_flange: &Pose) -> Point3<f64> {
        base_from_flange * Point3::from(self.rig.flange_from_centre_m)
    }

    /// Whether the robot at `q` leaves the sphere visible from the prior camera.
    fn visible(&self, poses: &[Pose], centre: &Point3<f64>) -> bool {
        let eye = Point3::from(self.camera.base_from_camera.translation.vector);
        let d = (eye - centre).normalize();
        let e1 = d
            .cross(&Vector3::z())
            .try_normalize(1e-9)
            .unwrap_or(Vector3::x());
        let e2 = d.cross(&e1);
        let r = self.rig.radius_m;
        let a = VISIBILITY_RING_DEG.to_radians();
        let mut points = vec![centre + d * r];
        for k in 0..8 {
            let b = std::f64::consts::TAU * k as f64 / 8.0;
            points.push(centre + (d * a.cos() + (e1 * b.cos() + e2 * b.sin()) * a.sin()) * r);
        }
        !points.iter().any(|p| self.geometry.blocks(poses, &eye, p))
    }

    /// Whether the robot at `q` is free of collisions, the sphere included.
    fn clear(&self, q: &ArmJoints) -> bool {
        let robot = self.geometry.robot;
        let poses = robot.link_poses(q, &self.options.hand);
        if robot.collision.check(&poses).is_some() {
            return false;
        }
        let flange = robot.arm().flange_and_palm(q).0;
        let centre = self.centre_at(&flange);
        self.above_table(&centre)
            && !self.geometry.ball_hits_arm(
                &poses,
                &centre,
                self.rig.radius_m + self.options.rig_clearance_m,
            )
    }

    /// Whether the straight joint-space move from `a` to `b` is collision-free.
    fn path_clear(&self, a: &ArmJoints, b: &ArmJoints) -> bool {
        let span = joint_distance_rad(a, b);
        let steps = (span / self.options.max_joint_step_rad).ceil().max(1.0) as usize;
        (1..=steps).all(|s| {
            let t = s as f64 / steps as f64;
            let q: ArmJoints = std::array::from_fn(|i| a[i] + t * (b[i] - a[i]));
            self.clear(&q)
        })
    }

    /// The checks of a configuration the IK found: the flange pose and sphere
    /// centre, or why the planner would not use it.
    fn check_joints(&self, q: &ArmJoints) -> Result<(Pose, Point3<f64>), Rejection> {
        // The flange where the arm actually is (IK is within 1 mm, 0.01 rad).
        let flange = self.geometry.robot.arm().flange_and_palm(q).0;
        let centre = self.centre_at(&flange);
        if !self.clear(q) {
            return Err(Rejection::RigCollision);
        }
        if !self.in_view(&centre) {
            return Err(Rejection::OutOfView);
        }
        let poses = self.geometry.robot.link_poses(q, &self.options.hand);
        if !self.visible(&poses, &centre) {
            return Err(Rejection::Occluded);
        }
        Ok((flange, centre))
    }

    /// A random candidate flange pose.
    fn draw(&self, rng: &mut ChaCha8Rng) -> (Pose, Point3<f64>) {
        let (lo, hi) = (self.options.region_min_m, self.options.region_max_m);
        let centre = Point3::from(Vector3::from_fn(|i, _| rng.gen_range(lo[i]..=hi[i])));
        let eye = Point3::from(self.camera.base_from_camera.translation.vector);
        let d = (eye - centre).normalize();
        // Tilt away from the camera direction (uniform over the spherical cap), then roll.
        let cos_max = self.options.max_tilt_deg.to_radians().cos();
        let tilt = rng.gen_range(cos_max..=1.0f64).acos();
        let perp = loop {
            let v = Vector3::from_fn(|_, _| rng.gen_range(-1.0..=1.0));
            if let Some(p) = (v - d * v.dot(&d)).try_normalize(1e-6) {
                break p;
            }
        };
        let facing =
            UnitQuaternion::from_axis_angle(&nalgebra::Unit::new_normalize(d.cross(&perp)), tilt)
                * d;
        let outward = self.rig.flange_from_centre_m.normalize();
        let align = UnitQuaternion::rotation_between(&outward, &facing).unwrap_or_else(|| {
            UnitQuaternion::from_axis_angle(&Vector3::x_axis(), std::f64::consts::PI)
        });
        let roll = UnitQuaternion::from_axis_angle(
            &nalgebra::Unit::new_normalize(facing),
            rng.gen_range(-std::f64::consts::PI..std::f64::consts::PI),
        );
        let rotation = roll * align;
        let flange = Isometry3::from_parts(
            Translation3::from(centre.coords - rotation * self.rig.flange_from_centre_m),
            rotation,
        );
        (flange, centre)
    }
}

/// Why the planner would not use a configuration.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum Rejection {
    /// The sphere is outside the image, the range or the distance limit.
    #[error("the sphere is out of view")]
    OutOfView,
    /// The robot collides, or the sphere touches the table or the arm.
    #[error("the robot or the sphere collides")]
    RigCollision,
    /// The robot hides the sphere from the camera.
    #[error("the robot hides the sphere")]
    Occluded,
}

/// Everything the planner needs to know about the cell.
#[derive(Debug, Clone, Copy)]
pub struct PlannerCell<'a> {
    /// The robot.
    pub robot: &'a Robot,
    /// The URDF name of the flange link (the sample frame).
    pub flange_link: &'a str,
    /// The camera prior.
    pub camera: &'a CameraPrior,
    /// The nominal rig.
    pub rig: &'a TargetRig,
    /// The table.
    pub table: &'a TableConfig,
}

impl<'a> PlannerCell<'a> {
    fn checker(&self, options: &'a CollectOptions) -> Result<Checker<'a>, CollectError> {
        let robot = self.robot;
        let flange_index = robot
            .description
            .link_index(self.flange_link)
            .ok_or_else(|| CollectError::BadOption {
                option: "robot.flange_link",
                value: self.flange_link.to_string(),
                problem: "is not a link of the URDF".into(),
            })?;
        let (flange0, palm0) = robot.arm().flange_and_palm(&[0.0; ARM_DOF]);
        Ok(Checker {
            geometry: RobotGeometry::new(robot, flange_index),
            camera: self.camera,
            rig: self.rig,
            table: self.table,
            options,
            flange_from_palm: flange0.inverse() * palm0,
        })
    }
}

/// The planner's checks of one configuration (collisions of robot and sphere,
/// sphere in view, not hidden by the robot): the sphere's expected centre (base
/// frame), or why the planner would not use it.
pub fn check_configuration(
    cell: &PlannerCell,
    options: &CollectOptions,
    joints: &ArmJoints,
) -> Result<Point3<f64>, CollectError> {
    let checker = cell.checker(options)?;
    checker
        .check_joints(joints)
        .map(|(_, centre)| centre)
        .map_err(CollectError::Rejected)
}

/// Draws candidates, keeps the feasible ones, chooses `options.poses` diverse ones
/// and orders them into collision-free moves from `start` (see the module doc).
pub fn plan_poses(
    cell: &PlannerCell,
    start: &ArmJoints,
    options: &CollectOptions,
    progress: &mut dyn FnMut(Progress),
) -> Result<Plan, CollectError> {
    options.check()?;
    let robot = cell.robot;
    let checker = cell.checker(options)?;
    let mut rng = ChaCha8Rng::seed_from_u64(options.seed);
    let mut rejections = Rejections::default();
    let mut pool: Vec<PlannedPose> = Vec::new();
    let want = options.poses * options.pool_factor.max(1);
    let mut drawn = 0;
    while drawn < options.max_candidates && pool.len() < want {
        drawn += 1;
        if drawn % 16 == 0 {
            progress(Progress::Planning {
                drawn,
                max: options.max_candidates,
                feasible: pool.len(),
            });
        }
        let (flange, centre) = checker.draw(&mut rng);
        if !checker.in_view(&centre) {
            rejections.out_of_view += 1;
            continue;
        }
        if !checker.above_table(&centre) {
            rejections.rig_collision += 1;
            continue;
        }
        let palm = flange * checker.flange_from_palm;
        let seeds = [*start, options.home];
        let Ok(solution) = robot.reach(&palm, &options.hand, &seeds) else {
            rejections.unreachable += 1;
            continue;
        };
        let q = solution.joints;
        let (flange, centre) = match checker.check_joints(&q) {
            Ok(found) => found,
            Err(Rejection::OutOfView) => {
                rejections.out_of_view += 1;
                continue;
            }
            Err(Rejection::RigCollision) => {
                rejections.rig_collision += 1;
                continue;
            }
            Err(Rejection::Occluded) => {
                rejections.occluded += 1;
                continue;
            }
        };
        pool.push(PlannedPose {
            joints: q,
            base_from_flange: flange,
            centre_base_m: centre,
            via_home: false,
        });
    }
    progress(Progress::Planning {
        drawn,
        max: options.max_candidates,
        feasible: pool.len(),
    });
    let feasible = pool.len();
    if feasible < MIN_USABLE_SAMPLES.max(options.poses.min(5)) {
        return Err(CollectError::TooFewFeasible {
            feasible,
            candidates: drawn,
            need: MIN_USABLE_SAMPLES.max(options.poses.min(5)),
            rejections,
        });
    }
    let rotations: Vec<UnitQuaternion<f64>> =
        pool.iter().map(|p| p.base_from_flange.rotation).collect();
    let centres: Vec<Point3<f64>> = pool.iter().map(|p| p.centre_base_m).collect();
    let chosen = select_diverse(&rotations, &centres, options.poses);
    // Visit in nearest-neighbour order (largest joint difference) from the start.
    let mut left: Vec<PlannedPose> = chosen.iter().map(|&i| pool[i]).collect();
    let mut order = Vec::with_capacity(left.len());
    let mut at = *start;
    while !left.is_empty() {
        let (k, _) = left
            .iter()
            .enumerate()
            .map(|(k, p)| (k, joint_distance_rad(&at, &p.joints)))
            .min_by(|a, b| a.1.total_cmp(&b.1))
            .expect("not empty");
        let mut pose = left.swap_remove(k);
        if checker.path_clear(&at, &pose.joints) {
            // Straight there.
        } else if checker.path_clear(&at, &options.home)
            && checker.path_clear(&options.home, &pose.joints)
        {
            pose.via_home = true;
        } else {
            rejections.no_path += 1;
            continue;
        }
        at = pose.joints;
        order.push(pose);
    }
    let flanges: Vec<Pose> = order.iter().map(|p| p.base_from_flange).collect();
    let centres: Vec<Point3<f64>> = order.iter().map(|p| p.centre_base_m).collect();
    Ok(Plan {
        diversity: diversity(&flanges, &centres),
        poses: order,
        home: options.home,
        candidates: drawn,
        feasible,
        rejections,
    })
}

/// Why a capture gave no sample.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum TargetMissing {
    /// Too few points near the expected centre.
    #[error("{found} points within {search_mm:.0} mm of the expected sphere centre (need {need}): the sphere is out of view, hidden, or the camera prior is off")]
    NoPoints {
        /// Points found.
        found: usize,
        /// Points needed.
        need: usize,
        /// The search radius (mm).
        search_mm: f64,
    },
    /// The sphere fit failed.
    #[error("sphere fit: {0}")]
    Fit(#[from] SphereFitError),
    /// Too little of the sphere was seen.
    #[error("only {coverage_pct:.0} % of the sphere's image is on the fitted sphere (need {need_pct:.0} %): partly hidden")]
    PartlyHidden {
        /// Fraction seen (%).
        coverage_pct: f64,
        /// Fraction needed (%).
        need_pct: f64,
    },
}

/// The sphere found in one capture.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct TargetFound {
    /// Its centre (camera frame, m).
    pub centre_camera_m: Point3<f64>,
    /// Inlier points.
    pub inliers: usize,
    /// RMS distance of the inliers from the sphere (mm).
    pub rms_mm: f64,
    /// Inliers over the pixels of the sphere's image disc.
    pub coverage: f64,
    /// Distance from the expected centre (mm): how far off the prior is.
    pub from_expected_mm: f64,
}

/// Finds the sphere of `options.fit.radius_m` near `expected` (camera frame) in
/// `cloud` (see the module doc).
pub fn find_target(
    cloud: &PointCloud,
    expected: &Point3<f64>,
    camera: &CameraPrior,
    options: &CollectOptions,
    rng: &mut ChaCha8Rng,
) -> Result<TargetFound, TargetMissing> {
    let search2 = options.search_radius_m.powi(2);
    let points: Vec<Point3<f64>> = cloud
        .valid_points()
        .map(|p| Point3::new(f64::from(p.x), f64::from(p.y), f64::from(p.z)))
        .filter(|p| (p - expected).norm_squared() <= search2)
        .collect();
    let need = options.fit.min_inliers;
    if points.len() < need {
        return Err(TargetMissing::NoPoints {
            found: points.len(),
            need,
            search_mm: options.search_radius_m * 1e3,
        });
    }
    let fit = fit_sphere(&points, &options.fit, rng)?;
    let r_px = camera.focal_px() * options.fit.radius_m / fit.centre.z;
    let coverage = fit.inliers as f64 / (std::f64::consts::PI * r_px * r_px);
    if coverage < options.min_coverage {
        return Err(TargetMissing::PartlyHidden {
            coverage_pct: coverage * 100.0,
            need_pct: options.min_coverage * 100.0,
        });
    }
    Ok(TargetFound {
        centre_camera_m: fit.centre,
        inliers: fit.inliers,
        rms_mm: fit.rms_m * 1e3,
        coverage,
        from_expected_mm: (fit.centre - expected).norm() * 1e3,
    })
}

/// What happened at one pose.
#[derive(Debug, Clone, PartialEq)]
pub struct Capture {
    /// Index of the pose in the plan.
    pub pose: usize,
    /// The measured joints.
    pub joints: ArmJoints,
    /// The flange pose read from the arm.
    pub base_from_flange: Pose,
    /// The sphere, or why it was not found.
    pub outcome: Result<TargetFound, TargetMissing>,
}

/// The result of visiting the plan's poses.
#[derive(Debug, Clone, PartialEq)]
pub struct Collection {
    /// The usable samples, in capture order.
    pub samples: Vec<PointSample>,
    /// Every pose visited and what came of it.
    pub captures: Vec<Capture>,
    /// The spread of the usable samples' poses.
    pub diversity: Diversity,
}

/// Moves through the plan, captures and finds the sphere at each pose; poses
/// without a usable sphere are skipped and reported; fewer than
/// [`MIN_USABLE_SAMPLES`] usable samples is an error.
pub fn run_collection(
    plan: &Plan,
    arm: &mut dyn ArmMover,
    camera: &mut dyn TargetCamera,
    prior: &CameraPrior,
    rig: &TargetRig,
    options: &CollectOptions,
    progress: &mut dyn FnMut(Progress),
) -> Result<Collection, CollectError> {
    let mut rng = ChaCha8Rng::seed_from_u64(options.seed ^ 0x5eed_5ca1_ab1e);
    let camera_from_base = prior.base_from_camera.inverse();
    let mut samples = Vec::new();
    let mut captures = Vec::new();
    let total = plan.poses.len();
    for (index, pose) in plan.poses.iter().enumerate() {
        progress(Progress::Capturing { done: index, total });
        if pose.via_home {
            arm.move_to(&plan.home, options.move_timeout_s)?;
        }
        arm.move_to(&pose.joints, options.move_timeout_s)?;
        let joints = arm.joints(options.capture_timeout_s)?;
        let base_from_flange = arm.base_from_flange(options.capture_timeout_s)?;
        let cloud = camera.capture(options.capture_timeout_s)?;
        let expected =
            camera_from_base * (base_from_flange * Point3::from(rig.flange_from_centre_m));
        let outcome = find_target(&cloud, &expected, prior, options, &mut rng);
        match &outcome {
            Ok(found) => samples.push(PointSample {
                base_from_flange,
                target_point_camera_m: found.centre_camera_m,
            }),
            Err(why) => tracing::warn!(pose = index, "skipped: {why}"),
        }
        captures.push(Capture {
            pose: index,
            joints,
            base_from_flange,
            outcome,
        });
    }
    progress(Progress::Capturing { done: total, total });
    if samples.len() < MIN_USABLE_SAMPLES {
        let skipped: Vec<String> = captures
            .iter()
            .filter_map(|c| match &c.outcome {
                Err(why) => Some(format!("pose {}: {why}", c.pose)),
                Ok(_) => None,
            })
            .collect();
        return Err(CollectError::TooFewUsable {
            usable: samples.len(),
            planned: total,
            need: MIN_USABLE_SAMPLES,
            skipped: skipped.join("; "),
        });
    }
    let flanges: Vec<Pose> = samples.iter().map(|s| s.base_from_flange).collect();
    let centres: Vec<Point3<f64>> = samples
        .iter()
        .map(|s| s.base_from_flange * Point3::from(rig.flange_from_centre_m))
        .collect();
    Ok(Collection {
        diversity: diversity(&flanges, &centres),
        samples,
        captures,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn rotation(axis: Vector3<f64>, deg: f64) -> UnitQuaternion<f64> {
        UnitQuaternion::from_axis_angle(&nalgebra::Unit::new_normalize(axis), deg.to_radians())
    }

    #[test]
    fn diversity_of_rotations_about_one_axis_has_no_spread() {
        let flanges: Vec<Pose> = (0..6)
            .map(|k| {
                Isometry3::from_parts(
                    Translation3::new(
                        0.1 * k as f64,
                        0.02 * (k * k) as f64,
                        0.03 * k as f64 % 0.07,
                    ),
                    rotation(Vector3::z(), 20.0 * k as f64),
                )
            })
            .collect();
        let centres: Vec<Point3<f64>> = flanges
            .iter()
            .map(|f| Point3::from(f.translation.vector))
            .collect();
        let d = diversity(&flanges, &centres);
        assert!(d.axis_spread_deg < 1e-6, "{d:?}");
        assert!(
            d.rotation_rms_deg[1] < 1e-6 && d.rotation_rms_deg[0] > 20.0,
            "{d:?}"
        );
    }

    /// From a pool where most rotations turn about z and the last ten about x or y,
    /// the greedy choice takes some of the ten: its weakest rotation direction turns
    /// by 10° RMS or more, where the first n of the pool (a naive choice) do not
    /// turn at all, and more than in 95 of 100 random choices.
    #[test]
    fn greedy_choice_spreads_the_axes() {
        let mut rng = ChaCha8Rng::seed_from_u64(5);
        let mut rotations = Vec::new();
        let mut centres = Vec::new();
        for k in 0..60 {
            let axis = if k < 50 {
                Vector3::z()
            } else if k % 2 == 0 {
                Vector3::x()
            } else {
                Vector3::y()
            };
            rotations.push(rotation(axis, rng.gen_range(-60.0..60.0)));
            centres.push(Point3::from(Vector3::from_fn(|_, _| {
                rng.gen_range(-0.2..0.2)
            })));
        }
        let n = 10;
        let chosen = select_diverse(&rotations, &centres, n);
        assert_eq!(chosen.len(), n);
        let mut unique = chosen.clone();
        unique.sort_unstable();
        unique.dedup();
        assert_eq!(unique.len(), n);
        let as_poses = |idx: &[usize]| -> (Vec<Pose>, Vec<Point3<f64>>) {
            (
                idx.iter()
                    .map(|&i| Isometry3::from_parts(Translation3::identity(), rotations[i]))
                    .collect(),
                idx.iter().map(|&i| centres[i]).collect(),
            )
        };
        let (f, c) = as_poses(&chosen);
        let greedy = diversity(&f, &c);
        let first: Vec<usize> = (0..n).collect();
        let (f, c) = as_poses(&first);
        let naive = diversity(&f, &c);
        assert!(naive.rotation_rms_deg[2] < 1e-6, "{naive:?}");
        assert!(greedy.rotation_rms_deg[2] > 10.0, "{greedy:?}");
        let mut random: Vec<f64> = (0..100)
            .map(|_| {
                let mut idx: Vec<usize> = (0..60).collect();
                for i in 0..n {
                    let j = rng.gen_range(i..60);
                    idx.swap(i, j);
                }
                let (f, c) = as_poses(&idx[..n]);
                diversity(&f, &c).rotation_rms_deg[2]
            })
            .collect();
        random.sort_by(f64::total_cmp);
        assert!(
            greedy.rotation_rms_deg[2] > random[95],
            "greedy {:.1}°, random 95th percentile {:.1}°",
            greedy.rotation_rms_deg[2],
            random[95]
        );
        assert!(
            chosen.iter().filter(|&&i| i >= 50).count() >= 2,
            "{chosen:?}"
        );
        assert!(greedy.axis_spread_deg > 45.0, "{greedy:?}");
    }
}
