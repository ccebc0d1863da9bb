//! Hand–eye calibration of the fixed camera: `base_from_camera` from robot poses and
//! target observations.
//!
//! # Setup (eye-to-hand)
//!
//! The camera is fixed; a target (a board, or a sphere whose centre is found in the
//! depth cloud) is rigidly attached to the flange. Sample `i` holds the flange pose
//! `F_i = base_from_flange_i` (forward kinematics) and what the camera saw: the full
//! pose `C_i = camera_from_target_i` or only the target point `p_i` (camera frame,
//! m). The unknowns are `X = base_from_camera` and `Y = flange_from_target`; the
//! two chains to the target agree:
//!
//! ```text
//! F_i Y = X C_i            (base_from_target_i, via the robot and via the camera)
//! ```
//!
//! # Relative motions (AX = XB)
//!
//! For samples `i` and `j`, `Y = F_i⁻¹ X C_i = F_j⁻¹ X C_j`; multiply on the left
//! by `F_j` and on the right by `C_i⁻¹`:
//!
//! ```text
//! F_j F_i⁻¹ X = X C_j C_i⁻¹    so    A_ij X = X B_ij   with
//! A_ij = base_from_flange_j * base_from_flange_i⁻¹   (the flange's motion, base frame)
//! B_ij = camera_from_target_j * camera_from_target_i⁻¹ (the target's motion, camera frame)
//! ```
//!
//! so the AX = XB solvers return `X = base_from_camera` directly (this is the
//! eye-in-hand formulation with every robot pose inverted). `Y` then follows from
//! `X` as the best fit of `F_i⁻¹ X C_i` over all samples ([`fit_target`]). Rotation
//! part: `R_A = R_X R_B R_Xᵀ`, so both turn by the same angle and `axis_A = R_X axis_B`;
//! translation part: `(R_A − I) t_X = R_X t_B − t_A`, linear in `t_X` once `R_X` is
//! known. Every pair `i < j` whose flange turns by at least [`MIN_PAIR_ROTATION_DEG`]
//! is used.
//!
//! # Solvers
//!
//! - [`tsai_lenz`]: rotation from the modified Rodrigues vectors `P = 2 sin(θ/2) n`
//!   of `A` and `B`: `[P_A + P_B]× r = P_B − P_A` (least squares) with
//!   `r = tan(θ_X/2) n_X`; translation from the linear equation above.
//! - [`park_martin`]: rotation from the logarithms `α = log R_A = R_X log R_B = R_X β`
//!   in closed form, `R_X = (MᵀM)^(-1/2) Mᵀ`, `M = Σ β αᵀ` (computed as the
//!   orthogonal polar factor by SVD, with the determinant fixed to +1); translation
//!   as Tsai–Lenz.
//! - [`daniilidis`]: rotation and translation together from the dual quaternions of
//!   `A` and `B` (`a q = q b`): the null space of the stacked 6×8 screw equations,
//!   with the unit-norm and orthogonality constraints fixing the combination.
//! - [`point_solver`]: target points only. With the target's position in the flange
//!   known it is [`kabsch`] between the points in the camera and in the base; with it
//!   unknown, linear least squares in `(y, vec R_X, t_X)` from
//!   `R_F y − R_X p − t_X = −t_F`, projection of `R_X` onto SO(3), then [`refine`].
//! - [`refine`]: Levenberg–Marquardt over all samples on the residuals of
//!   `F_i Y = X C_i`: translation `t(F_i Y) − t(X C_i)` divided by
//!   [`Weights::translation_m`] and rotation `log(R(X C_i)ᵀ R(F_i Y))` divided by
//!   [`Weights::rotation_rad`] (defaults: 0.5 mm weighs as much as 0.2°, the noise
//!   per axis of a board detector at about 1 m). Point samples contribute the translation
//!   residual only. Steps are accepted only when they lower the cost, so the result
//!   is never worse than the start.
//!
//! [`solve`] runs the chosen methods, evaluates each on every sample (translation
//! residual in mm, rotation residual in degrees), refines the best closed form and
//! returns the comparison.
//!
//! # Bad input
//!
//! Before solving, [`solve`] rejects NaN or infinite numbers (naming the sample) and
//! [`check_motions`] rejects fewer than 3 samples, flange rotations that are too small ([`MIN_PAIR_ROTATION_DEG`]) and relative rotation
//! axes that are (nearly) parallel ([`MIN_AXIS_SPREAD_DEG`]: the rotation of the
//! camera about that axis cannot be observed); only the point solver with a known
//! target position (Kabsch) needs no rotation. For pose samples [`check_frames`]
//! uses the screw congruence of `A` and `B` (same angle, same translation along the
//! axis) to catch mismatched samples, a wrong quaternion order and mixed units.
//! Inverting every robot pose or every observation keeps each pair congruent (the
//! screw invariants of `M` and `N M⁻¹ N⁻¹` agree), so [`solve`] catches those by
//! their residuals: when the best solution misses by more than
//! [`GROSS_RMS_MM`] or [`GROSS_RMS_DEG`] it solves again with the robot poses
//! inverted and, if that fits, says so: one side of each sample is inverted
//! (`flange_from_base`, `target_from_camera`; the two cannot be told apart, since
//! inverting both swaps `X` and `Y` and fits) or the data is eye-in-hand.
//! Each error says what to change.
//!
//! # Sample file (`calib/samples-DATE.json`)
//!
//! ```json
//! {
//!   "created": "2025-01-31T10:00:00Z",
//!   "comment": "optional free text",
//!   "samples": [
//!     {"base_from_flange": {"xyz": [0.6, 0.1, 0.4], "quat_xyzw": [1, 0, 0, 0]},
//!      "camera_from_target": {"xyz": [0.05, -0.02, 0.95], "rpy": [3.0, 0.1, -0.2]}},
//!     {"base_from_flange": {"xyz": [0.5, -0.1, 0.3], "rpy": [3.1, 0.2, 0.0]},
//!      "target_point_camera_m": [0.04, 0.01, 1.02]}
//!   ]
//! }
//! ```
//!
//! Poses are [`PoseJson`](crate::geometry::PoseJson) (metres; `rpy` fixed-axis X-Y-Z
//! radians and/or `quat_xyzw`, which must agree when both are given). Each sample has
//! `base_from_flange` (forward kinematics) and exactly one of `camera_from_target`
//! (full target pose) or `target_point_camera_m` (the target point, e.g. a sphere
//! centre, in the camera frame). Loading rejects unknown fields, non-finite numbers,
//! quaternions whose norm is not 1, fewer than 3 samples; errors name the file and
//! the sample index.
//!
//! # Result file (`calib/hand_eye.toml`)
//!
//! [`HandEyeResult`]: date, method, samples file, residual statistics and
//! `base_from_camera` as `{xyz, rpy, quat_xyzw}`. Perception gets its camera mount
//! from [`current_base_from_camera`]: this file's pose when it is present and valid
//! (logged with its date and method), else the configuration's nominal mount with a
//! warning.
//!
//! # Collecting samples (`cell calibrate collect`)
//!
//! [`collect`] chooses diverse, reachable poses that show a sphere on the hand to
//! the camera, moves through them ([`collect::ArmMover`]), captures
//! ([`collect::TargetCamera`]), finds the sphere centre by RANSAC and least squares
//! ([`sphere_fit`]) and returns point samples. [`sim_rig`] simulates the arm, the
//! sphere and the depth camera at a true mount the solver is not told.

pub mod collect;
mod current;
mod daniilidis;
mod lm;
mod motions;
mod points;
mod refine;
mod residuals;
mod result_file;
mod samples;
pub mod sim_rig;
mod solve;
pub mod sphere_fit;
pub mod synthetic;
mod tsai_park;

pub use current::{current_base_from_camera, CameraMount, MountSource, DEFAULT_RESULT_PATH};
pub use daniilidis::daniilidis;
pub use motions::{
    check_frames, check_motions, measure_motions, Conditioning, MIN_AXIS_SPREAD_DEG,
    MIN_PAIR_ROTATION_DEG,
};
pub use points::{kabsch, point_solver, umeyama, MIN_POINT_SPREAD_M};
pub use refine::{refine, Refined, Weights};
pub use residuals::{evaluate, fit_target, Evaluation, ResidualStats, SampleResidual};
pub use result_file::HandEyeResult;
pub use samples::{PointSample, PoseSample, Sample, SampleFile};
pub use solve::{solve, Method, MethodResult, Solution, SolveOptions, GROSS_RMS_DEG, GROSS_RMS_MM};
pub use tsai_park::{park_martin, tsai_lenz};

use crate::fsio::FileError;
use crate::geometry::Pose;
use std::path::PathBuf;

/// The two unknowns of eye-to-hand calibration.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct HandEye {
    /// The camera's pose in the robot base frame (the result perception needs).
    pub base_from_camera: Pose,
    /// The target's pose on the flange (rotation meaningful only when pose samples
    /// were used; point samples determine its position only).
    pub flange_from_target: Pose,
}

/// Errors of hand–eye calibration: bad files, bad samples, degenerate motions.
#[derive(Debug, thiserror::Error)]
pub enum CalibError {
    /// A file could not be read or written.
    #[error(transparent)]
    File(#[from] FileError),
    /// A file is not valid JSON/TOML for its schema.
    #[error("{path}: {message}")]
    Parse {
        /// The file.
        path: PathBuf,
        /// The parser's message (with line and column where known).
        message: String,
    },
    /// One sample of a sample file is invalid.
    #[error("{path}: sample {index}: {problem}")]
    BadSample {
        /// The file.
        path: PathBuf,
        /// Zero-based index of the sample.
        index: usize,
        /// What is wrong with it.
        problem: String,
    },
    /// A field of a result file is invalid.
    #[error("{path}: {field}: {problem}")]
    BadField {
        /// The file.
        path: PathBuf,
        /// The field.
        field: String,
        /// What is wrong with it.
        problem: String,
    },
    /// A sample given in memory holds NaN or infinity.
    #[error("sample {index}: {field} holds a non-finite value ({value}); remove or re-capture this sample")]
    NotFinite {
        /// Zero-based index of the sample.
        index: usize,
        /// Which part of the sample.
        field: &'static str,
        /// The offending value.
        value: f64,
    },
    /// Too few samples for the method.
    #[error("{got} {what}, need at least {need}: capture more poses (10–30 are typical)")]
    TooFewSamples {
        /// Samples available.
        got: usize,
        /// Samples needed.
        need: usize,
        /// Which samples were counted, for which method.
        what: String,
    },
    /// The method needs full target poses but the samples hold only points.
    #[error("method {method} needs pose samples (camera_from_target), the samples hold {points} point samples and {poses} pose samples; use --method points")]
    NeedsPoseSamples {
        /// The method asked for.
        method: String,
        /// Point samples present.
        points: usize,
        /// Pose samples present.
        poses: usize,
    },
    /// The flange hardly rotates between samples.
    #[error("the flange rotates by at most {max_deg:.2}° between any two samples (need ≥ {need_deg}° for some pairs): rotate the hand between poses, ideally by 30° or more")]
    RotationsTooSmall {
        /// Largest rotation between two samples (deg).
        max_deg: f64,
        /// The threshold (deg).
        need_deg: f64,
    },
    /// All relative rotations turn about (nearly) the same axis.
    #[error("all relative rotations turn about nearly the same axis [{:.3}, {:.3}, {:.3}] (base frame; axis spread {spread_deg:.2}° < {need_deg}°): add poses rotating about a different axis", axis[0], axis[1], axis[2])]
    ParallelAxes {
        /// Spread of the rotation axes (deg; for two axes, the angle between them).
        spread_deg: f64,
        /// The threshold (deg).
        need_deg: f64,
        /// The common axis (unit, base frame).
        axis: [f64; 3],
    },
    /// The robot and target motions are not congruent (wrong frames or mismatched samples).
    #[error("robot and target motions disagree (median over {pairs} pairs: rotation angle differs by {angle_deg:.2}°, translation along the axis by {pitch_mm:.1} mm): {hint}")]
    FramesInconsistent {
        /// Pairs compared.
        pairs: usize,
        /// Median difference of rotation angles (deg).
        angle_deg: f64,
        /// Median difference of translations along the screw axis (mm).
        pitch_mm: f64,
        /// What probably went wrong and what to check.
        hint: String,
    },
    /// Even the best solution misses the samples grossly.
    #[error("the best solution ({method}) misses the samples by {rms_mm:.1} mm{} RMS (limit {} mm, {}°): {hint}", .rms_deg.map(|d| format!(" / {d:.2}°")).unwrap_or_default(), GROSS_RMS_MM, GROSS_RMS_DEG)]
    ResidualsTooLarge {
        /// The method of the best solution.
        method: String,
        /// Its RMS translation residual (mm).
        rms_mm: f64,
        /// Its RMS rotation residual (deg), with pose samples.
        rms_deg: Option<f64>,
        /// What probably went wrong and what to check.
        hint: String,
    },
    /// Target points do not span enough space for the point solver.
    #[error(
        "target points are nearly {shape} (spread {spread_mm:.1} mm < {need_mm:.0} mm): {fix}"
    )]
    PointsDegenerate {
        /// "collinear" or "coplanar".
        shape: &'static str,
        /// The spread across the degenerate direction (mm).
        spread_mm: f64,
        /// The threshold (mm).
        need_mm: f64,
        /// What to change.
        fix: &'static str,
    },
    /// A linear system was singular despite the checks.
    #[error(
        "{what}: the equations are singular (condition {condition:.3e}); spread the poses further"
    )]
    Singular {
        /// Which solve.
        what: &'static str,
        /// Ratio of smallest to largest singular value.
        condition: f64,
    },
}
