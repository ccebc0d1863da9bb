//! Grasp planning (Nikandrova & Kyrki 2015, eqs. 1-5; `specs/method.md`): the palm
//! pose that maximises expected stability and task compatibility over every model of
//! the category, subject to the table and — beyond the paper — to the arm reaching the
//! grasp and its pre-grasp.
//!
//! - [`weights`]: `psi(q)` and `phi(eps)`, `phi(eps, sigma)`.
//! - [`chart`]: the pose difference `d` on the rotation group (rotation vectors, no
//!   gimbal lock) and the local charts the optimiser searches in.
//! - [`kernel`]: Gaussian, Gaussian-R and Laplace densities with separate translation
//!   and rotation scales (the paper's mixed mm/rad scalar by conversion).
//! - [`objective`]: eq. 2 over a task's grasps, with normalising constants, in log space.
//! - [`nelder_mead`]: the simplex search of Lagarias et al. (Matlab's `fminsearch`).
//! - [`planner`]: multi-start search, constraints, the plan and the best-single baseline.
//! - [`input`]: the JSON files of fits and grasps read by `cell plan`.
//! - [`synthetic`]: generated problems for benchmarks and tests.
//!
//! The planner's inputs are its own small types, [`ModelFit`] (one registered model)
//! and [`ExampleGrasp`] (one task-labelled grasp of a model), so that registration and
//! the category database can feed it, and an evaluation loop can call
//! [`planner::plan`] once per held-out model, task and kernel.

pub mod category;
pub mod chart;
pub mod input;
pub mod kernel;
pub mod mode;
pub mod nelder_mead;
pub mod objective;
pub mod planner;
pub mod reach;
pub mod refine;
pub mod seen;
pub mod synthetic;
pub mod weights;

pub use kernel::Kernel;
pub use mode::{PaperProtocol, PlanMode};
pub use planner::{plan, plan_with, BestSingle, GraspPlan, PlanOptions, PlanOutcome, PlannedGrasp};
pub use reach::Reachability;
pub use seen::{SeenSurface, SeenSurfaceOptions};
pub use weights::{FitWeight, Weights};

use crate::fsio::FileError;
use crate::geometry::{Pose, PoseParams};
use crate::robot::PreshapeRad;
use std::path::PathBuf;

/// One training model registered to the target cloud.
#[derive(Debug, Clone, PartialEq)]
pub struct ModelFit {
    /// The model's name (e.g. `mug_003`).
    pub name: String,
    /// `T_i`: the model frame in the robot base (world) frame.
    pub base_from_model: Pose,
    /// Fitting error `eps_i`: mean squared nearest-neighbour distance (m^2).
    pub eps_m2: f64,
    /// `sigma_i`: standard deviation of those squared distances (m^2).
    pub sigma_m2: f64,
}

/// One task-labelled example grasp of a model.
#[derive(Debug, Clone, PartialEq)]
pub struct ExampleGrasp {
    /// Index of the model in the fits.
    pub model: usize,
    /// The task (`top`, `side`, `handle`, `use`, ...).
    pub task: String,
    /// `theta_ik`: the palm pose in the model frame, `[x, y, z, ax, ay, az]` (m, rad;
    /// URDF rpy). Any representative of the rotation will do: only the rotation it
    /// stands for is used.
    pub model_from_palm: PoseParams,
    /// Hand spread of the grasp (rad).
    pub spread_rad: f64,
    /// Its pre-shape: each finger's flex before the approach (rad; open for most).
    pub preshape_rad: PreshapeRad,
    /// How far beyond the pose its approach to contact may go (m); the cell's when
    /// `None` (most grasps).
    pub max_overtravel_m: Option<f64>,
    /// Grasp quality `q_ik >= 0` (Ferrari–Canny epsilon; 0 = not force closure).
    pub q: f64,
    /// Per-DOF standard deviations `Delta_d / 3` (m, m, m, rad, rad, rad): along the
    /// model frame's axes, and about the grasp's own palm axes (the components of the
    /// rotation vector of [`chart`]); `Sigma_ik = diag(sigma^2)`.
    pub sigma: [f64; 6],
}

/// Errors of planning and of its input files.
#[derive(Debug, thiserror::Error)]
pub enum PlanError {
    /// No model fits were given.
    #[error("no model fits: the category database (or the registration) has no models")]
    NoFits,
    /// No example grasps were given.
    #[error("the category database has no example grasps")]
    NoGrasps,
    /// The task has no example grasp.
    #[error("no example grasp for task {task:?} (tasks in the database: {available})")]
    NoGraspsForTask {
        /// The requested task.
        task: String,
        /// The tasks that do have grasps, comma-separated.
        available: String,
    },
    /// A fit names a model the category database does not have.
    #[error("the fit of model {model:?} names no model of the database {database}")]
    UnknownModel {
        /// The fit's model name.
        model: String,
        /// The database directory.
        database: PathBuf,
    },
    /// The task has grasps, but none of their models has a fit.
    #[error(
        "no model with a grasp for task {task:?} has a fit (registration failed for {models})"
    )]
    NoFitForTask {
        /// The requested task.
        task: String,
        /// The models with grasps of the task, comma-separated.
        models: String,
    },
    /// Every grasp of the task weighs zero (q = 0), so the objective is 0 everywhere.
    #[error("every example grasp of task {task:?} has quality q = 0: nothing to optimise")]
    ZeroWeight {
        /// The task.
        task: String,
    },
    /// A number is NaN, infinite or out of range.
    #[error("{what} = {value}: {problem}")]
    BadValue {
        /// The input and field (e.g. `fit 2 (mug_003) eps_m2`).
        what: String,
        /// The offending value.
        value: f64,
        /// What is wrong with it.
        problem: &'static str,
    },
    /// A grasp refers to a model index that has no fit.
    #[error("grasp {grasp} refers to model {model}, but there are only {count} fits")]
    ModelIndex {
        /// The grasp's index.
        grasp: usize,
        /// Its model index.
        model: usize,
        /// The number of fits.
        count: usize,
    },
    /// A file could not be read or written.
    #[error(transparent)]
    File(#[from] FileError),
    /// An input file is malformed.
    #[error("{path}: {message}")]
    Parse {
        /// The file.
        path: PathBuf,
        /// What is wrong, with line and column where known.
        message: String,
    },
}

#[cfg(test)]
pub(crate) mod test_support {
    //! Small hand-made databases for the planner's tests.
    use super::*;
    use crate::geometry::pose_from_params;
    use std::f64::consts::FRAC_PI_2;

    /// A grasp of `model` for `task` at `theta` with quality `q`, sigma 1 cm / 0.15 rad.
    pub fn grasp(model: usize, task: &str, theta: PoseParams, q: f64) -> ExampleGrasp {
        ExampleGrasp {
            model,
            task: task.to_string(),
            model_from_palm: theta,
            spread_rad: 0.1 * model as f64,
            preshape_rad: PreshapeRad::OPEN,
            max_overtravel_m: None,
            q,
            sigma: [0.01, 0.012, 0.008, 0.15, 0.12, 0.2],
        }
    }

    /// Two mugs near (0.6, 0, 0), slightly differently registered; three `side` grasps
    /// (palm facing -y of the model) and one `top` grasp.
    pub fn two_model_database() -> (Vec<ModelFit>, Vec<ExampleGrasp>) {
        let fits = vec![
            ModelFit {
                name: "mug_a".into(),
                base_from_model: pose_from_params(&[0.6, 0.0, 0.0, 0.0, 0.0, 0.2]),
                eps_m2: 1e-5,
                sigma_m2: 2e-6,
            },
            ModelFit {
                name: "mug_b".into(),
                base_from_model: pose_from_params(&[0.62, 0.02, 0.0, 0.01, -0.02, -0.3]),
                eps_m2: 4e-5,
                sigma_m2: 1e-5,
            },
        ];
        let grasps = vec![
            grasp(0, "side", [0.0, 0.08, 0.06, FRAC_PI_2, 0.0, 0.0], 0.2),
            grasp(1, "side", [0.01, 0.085, 0.05, FRAC_PI_2, 0.05, -0.1], 0.15),
            grasp(
                0,
                "top",
                [0.0, 0.0, 0.2, std::f64::consts::PI, 0.0, 0.0],
                0.3,
            ),
            grasp(0, "side", [0.0, 0.075, 0.07, 1.5, 0.0, 0.1], 0.05),
        ];
        (fits, grasps)
    }
}
