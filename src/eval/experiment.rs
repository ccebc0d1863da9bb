//! One target of an experiment, end to end: place the test object, see it (complete
//! or partial view), register the training models to the view, plan each task with
//! each kernel and take the best-single baseline, and run every grasp in the grasp
//! simulator on the test object at its true pose.
//!
//! Shared by the leave-one-out ([`super::loo`]) and cross-category
//! ([`super::cross`]) experiments, which differ only in where the test objects and
//! the training models come from.

use super::compare::{verdict, Verdict};
use super::outcome::{simulate, SimSetup, SimulatedGrasp, TestObject};
use super::view::{complete_view, partial_view, PlacementRegion, ViewKind};
use super::EvalError;
use crate::category::CategoryDb;
use crate::cloud::PointCloud;
use crate::geometry::{pose_error, Pose, PoseJson};
use crate::mesh::procedural::instance_seed;
use crate::mesh::TriMesh;
use crate::plan::category::example_grasps;
use crate::plan::{
    plan, Kernel, ModelFit, PlanError, PlanOptions, PlanOutcome, PlannedGrasp, Reachability,
};
use crate::robot::hand::HandModel;
use crate::sim::camera::DepthCamera;
use crate::sim::scene::TableBox;
use serde::Serialize;

/// Why no model of a category registered to a target.
#[derive(Debug, thiserror::Error)]
pub enum RegistrationFailure {
    /// The registration itself failed (e.g. an empty target).
    #[error(transparent)]
    Register(#[from] crate::register::RegisterError),
    /// Every model was tried and none registered.
    #[error("no model registered: {reasons}")]
    NoneRegistered {
        /// Each model's reason.
        reasons: String,
    },
}

/// Registration of a target cloud against a category's training models.
pub trait Registrar: Sync {
    /// The fits of every training model except the one named `exclude` (the held-out
    /// model of leave-one-out) to `target_base` (base frame), with randomness from
    /// `seed`; models that fail to register are left out. `Err` describes a failure of
    /// the whole registration (when no model registers, each model's reason).
    fn fits(
        &self,
        target_base: &PointCloud,
        exclude: Option<&str>,
        seed: u64,
    ) -> Result<Vec<ModelFit>, RegistrationFailure>;
}

/// Everything an experiment needs besides the databases and the registration.
#[derive(Clone, Copy)]
pub struct Setup<'a> {
    /// The hand, for the grasp simulator.
    pub hand: &'a HandModel,
    /// The sim camera (partial views).
    pub camera: DepthCamera,
    /// The table (partial views; its height also bounds the palm).
    pub table: TableBox,
    /// Where test objects are placed.
    pub region: PlacementRegion,
    /// Complete or partial views.
    pub view: ViewKind,
    /// Points of a complete view.
    pub complete_points: usize,
    /// Planner options; the kernel is replaced by each of the experiment's kernels.
    pub plan: PlanOptions,
    /// Arm reachability of the grasps (`None`: only the table bound, as the paper's
    /// simulation).
    pub reach: Option<&'a dyn Reachability>,
    /// Epsilon difference under which two grasps count as equal.
    pub equal_tolerance: f64,
    /// Seed of placements, views and registration.
    pub seed: u64,
    /// Placements (each with its own view and registration) of every test object.
    pub placements: usize,
    /// The paper's scoring ([`SimSetup::paper`]): no retreat, a colliding grasp
    /// scores −1.
    pub paper: bool,
}

impl Setup<'_> {
    /// Checks the numeric options.
    pub fn validate(&self) -> Result<(), EvalError> {
        let bad = |what: &str, value: f64, problem: &'static str| {
            Err(EvalError::Option {
                what: what.to_string(),
                value,
                problem,
            })
        };
        if !(self.equal_tolerance.is_finite() && self.equal_tolerance >= 0.0) {
            return bad(
                "equal tolerance",
                self.equal_tolerance,
                "must be finite and >= 0",
            );
        }
        if self.placements == 0 {
            return bad("placements", 0.0, "must be >= 1");
        }
        if self.view == ViewKind::Complete && self.complete_points == 0 {
            return bad("complete-view points", 0.0, "must be > 0");
        }
        let [hx, hy] = self.region.half_extent_xy_m;
        if !(hx.is_finite() && hy.is_finite() && hx >= 0.0 && hy >= 0.0) {
            return bad(
                "placement half extent (m)",
                hx.min(hy),
                "must be finite and >= 0",
            );
        }
        Ok(())
    }
}

/// One task, kernel and target: our grasp and best single, simulated.
#[derive(Debug, Clone, Serialize)]
pub struct RunRecord {
    /// The test object.
    pub target: String,
    /// The task.
    pub task: String,
    /// The kernel's name.
    pub kernel: &'static str,
    /// Epsilon of our grasp on the test object.
    pub epsilon: f64,
    /// Epsilon of the best-single grasp.
    pub epsilon_single: f64,
    /// Ours against best single.
    pub verdict: Verdict,
    /// Our grasp, simulated.
    pub ours: SimulatedGrasp,
    /// Best single, simulated.
    pub single: SimulatedGrasp,
    /// Our palm pose (base frame).
    pub pose: PoseJson,
    /// Our hand spread (rad).
    pub spread_rad: f64,
    /// Best single's palm pose (base frame).
    pub single_pose: PoseJson,
    /// Best single's hand spread (rad).
    pub single_spread_rad: f64,
    /// The model best single took its grasp from.
    pub best_single_model: String,
    /// The objective of eq. 2 at our grasp.
    pub objective: f64,
    /// Whether our grasp is reachable (`None`: not checked).
    pub reachable: Option<bool>,
    /// Whether best single is reachable (`None`: not checked).
    pub single_reachable: Option<bool>,
}

/// A task (or a whole target) that could not be run, and why.
#[derive(Debug, Clone, Serialize)]
pub struct Skipped {
    /// The test object.
    pub target: String,
    /// The task (`None`: every task of the target).
    pub task: Option<String>,
    /// Why (e.g. the registration failed).
    pub reason: String,
}

/// The fit of one training model to a target, as reported.
#[derive(Debug, Clone, Serialize)]
pub struct FitSummary {
    /// The model.
    pub model: String,
    /// The registered model frame in the base frame (`T_i`).
    pub base_from_model: PoseJson,
    /// Fitting error (m^2).
    pub eps_m2: f64,
    /// Standard deviation of the squared distances (m^2).
    pub sigma_m2: f64,
    /// Distance of `T_i`'s origin from the test object's true pose (mm). The
    /// procedural models of a category share a canonical frame (base centre at the
    /// origin, z up, a mug's handle along +x), so this, [`Self::tilt_deg`] and
    /// [`Self::yaw_deg`] measure the registration's error, up to the shapes'
    /// differences.
    pub offset_mm: f64,
    /// Angle between the registered model's z axis and the object's (deg): 0 upright,
    /// 90 lying on its side, 180 upside down.
    pub tilt_deg: f64,
    /// Rotation of the registered model about the object's z axis (deg, 0..180; the
    /// twist of the swing-twist decomposition): where a mug's handle ends up.
    /// Irrelevant for a rotationally symmetric object (a bottle).
    pub yaw_deg: f64,
    /// The test object's handle is in the view and the model has one
    /// ([`super::handle`]): the yaw error is where the handle ends up.
    pub handle_visible: bool,
}

/// Tilt and yaw (deg) of `model` relative to `object`, as [`FitSummary`] defines
/// them (the measure lives in [`crate::geometry`], where the observer uses it too).
pub use crate::geometry::tilt_and_yaw_deg;

/// Registration over the targets of an experiment, in the units a reader checks.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize)]
pub struct RegistrationStats {
    /// Registrations attempted (targets seen x training models).
    pub attempted: usize,
    /// Of those, the ones that registered.
    pub registered: usize,
    /// Median [`FitSummary::offset_mm`] over the registered (NaN: none).
    pub median_offset_mm: f64,
    /// Median [`FitSummary::tilt_deg`] over the registered.
    pub median_tilt_deg: f64,
    /// Median [`FitSummary::yaw_deg`] over the registered.
    pub median_yaw_deg: f64,
    /// Registered fits more than 30 degrees from upright (lying, upside down).
    pub tilt_over_30_deg: usize,
    /// Registered fits turned more than 30 degrees about the vertical (for a mug: the
    /// handle elsewhere).
    pub yaw_over_30_deg: usize,
    /// Registered fits per yaw error bin: up to each of [`YAW_BIN_EDGES_DEG`].
    pub yaw_bins: [usize; YAW_BINS],
    /// Registered fits where the handle is visible ([`FitSummary::handle_visible`]).
    pub handle_visible: usize,
    /// Of those, the fits turned more than 30 degrees.
    pub handle_visible_yaw_over_30_deg: usize,
}

/// Bins of the yaw error distribution.
pub const YAW_BINS: usize = 6;

/// Upper edges of the yaw error bins (deg); the first bin starts at 0.
pub const YAW_BIN_EDGES_DEG: [f64; YAW_BINS] = [10.0, 20.0, 30.0, 60.0, 120.0, 180.0];

/// How many of `yaw_deg` fall in each bin up to [`YAW_BIN_EDGES_DEG`].
pub fn yaw_bins(yaw_deg: &[f64]) -> [usize; YAW_BINS] {
    let mut bins = [0; YAW_BINS];
    for &d in yaw_deg {
        let k = YAW_BIN_EDGES_DEG
            .iter()
            .position(|&edge| d <= edge)
            .unwrap_or(YAW_BINS - 1);
        bins[k] += 1;
    }
    bins
}

impl RegistrationStats {
    /// The statistics of `targets`' fits.
    pub fn of(targets: &[TargetReport]) -> RegistrationStats {
        let fits = || targets.iter().flat_map(|t| &t.fits);
        let mut mm: Vec<f64> = fits().map(|f| f.offset_mm).collect();
        let mut tilt: Vec<f64> = fits().map(|f| f.tilt_deg).collect();
        let mut yaw: Vec<f64> = fits().map(|f| f.yaw_deg).collect();
        let registered = mm.len();
        RegistrationStats {
            attempted: registered + targets.iter().map(|t| t.unregistered.len()).sum::<usize>(),
            registered,
            median_offset_mm: crate::stats::median(&mut mm),
            median_tilt_deg: crate::stats::median(&mut tilt),
            median_yaw_deg: crate::stats::median(&mut yaw),
            tilt_over_30_deg: tilt.iter().filter(|&&d| d > 30.0).count(),
            yaw_over_30_deg: yaw.iter().filter(|&&d| d > 30.0).count(),
            yaw_bins: yaw_bins(&yaw),
            handle_visible: fits().filter(|f| f.handle_visible).count(),
            handle_visible_yaw_over_30_deg: fits()
                .filter(|f| f.handle_visible && f.yaw_deg > 30.0)
                .count(),
        }
    }
}

/// Everything that happened to one target.
#[derive(Debug, Clone, Serialize)]
pub struct TargetReport {
    /// The test object.
    pub target: String,
    /// Which of its placements (0-based).
    pub placement: usize,
    /// Its true pose.
    pub base_from_object: PoseJson,
    /// Points of its view.
    pub view_points: usize,
    /// The registered training models.
    pub fits: Vec<FitSummary>,
    /// Training models that did not register (left out of the planning).
    pub unregistered: Vec<String>,
    /// One record per task and kernel that ran.
    pub runs: Vec<RunRecord>,
    /// What could not run.
    pub skipped: Vec<Skipped>,
}

/// A test object: its database and index there.
#[derive(Clone, Copy)]
pub struct Target<'a> {
    /// The database holding the test object's mesh.
    pub db: &'a CategoryDb,
    /// Index of the model in that database.
    pub index: usize,
    /// Position in the experiment (seeds derive from it): `placement * models +
    /// index`.
    pub ordinal: u64,
}

/// Seeds of one target: placement, view noise, registration.
fn seeds(seed: u64, ordinal: u64) -> [u64; 3] {
    [0, 1, 2].map(|k| instance_seed(seed, ordinal * 3 + k))
}

fn is_skippable(e: &PlanError) -> bool {
    matches!(
        e,
        PlanError::NoFits
            | PlanError::NoGraspsForTask { .. }
            | PlanError::NoFitForTask { .. }
            | PlanError::ZeroWeight { .. }
    )
}

/// Progress steps of one target: its registration, then one per task and kernel.
pub fn steps_per_target(tasks: usize, kernels: usize) -> u64 {
    1 + (tasks * kernels) as u64
}

/// Advances a progress bar through one target's steps; whatever is left (skipped
/// tasks, an early return) is counted when it is dropped, so the bar ends full.
struct Steps<'a> {
    bar: Option<&'a indicatif::ProgressBar>,
    left: u64,
}

impl Steps<'_> {
    fn tick(&mut self) {
        if self.left > 0 {
            self.left -= 1;
            if let Some(bar) = self.bar {
                bar.inc(1);
            }
        }
    }
}

impl Drop for Steps<'_> {
    fn drop(&mut self) {
        if let Some(bar) = self.bar {
            bar.inc(self.left);
        }
    }
}

/// What a target is registered to and planned from.
#[derive(Clone, Copy)]
pub struct Training<'a> {
    /// The training models and their grasps.
    pub db: &'a CategoryDb,
    /// A model of `db` left out (the target itself in leave-one-out).
    pub exclude: Option<&'a str>,
    /// The registration to the training models.
    pub registrar: &'a dyn Registrar,
}

/// Runs one target against `training`, for every task and kernel. `progress`
/// advances by [`steps_per_target`] over the call.
pub fn run_target(
    setup: &Setup,
    target: Target,
    training: &Training,
    tasks: &[String],
    kernels: &[Kernel],
    progress: Option<&indicatif::ProgressBar>,
) -> Result<TargetReport, EvalError> {
    let mut steps = Steps {
        bar: progress,
        left: steps_per_target(tasks.len(), kernels.len()),
    };
    let entry = &target.db.file.models[target.index];
    let name = entry.name.clone();
    let mesh = &target.db.meshes[target.index];
    let [placement_seed, view_seed, register_seed] = seeds(setup.seed, target.ordinal);
    let base_from_object = setup.region.place(mesh, placement_seed);
    let mut report = TargetReport {
        target: name.clone(),
        placement: (target.ordinal / target.db.file.models.len() as u64) as usize,
        base_from_object: PoseJson::from(&base_from_object),
        view_points: 0,
        fits: Vec::new(),
        unregistered: Vec::new(),
        runs: Vec::new(),
        skipped: Vec::new(),
    };
    let cloud = match view_of(setup, &name, mesh, &base_from_object, view_seed) {
        Ok(c) => c,
        Err(e) => {
            report.skip_all(e.to_string());
            return Ok(report);
        }
    };
    report.view_points = cloud.len();
    let registered = training
        .registrar
        .fits(&cloud, training.exclude, register_seed);
    steps.tick();
    let fits = match registered {
        Ok(f) if f.is_empty() => {
            report.skip_all("registration: no model registered".into());
            return Ok(report);
        }
        Ok(f) => f,
        Err(e) => {
            report.unregistered = training.unregistered(&[]);
            report.skip_all(format!("registration: {e}"));
            return Ok(report);
        }
    };
    report.fits = fit_summaries(training.db, mesh, &base_from_object, &cloud, &fits);
    report.unregistered = training.unregistered(&fits);

    let runs = TaskRuns {
        setup,
        train: training.db,
        fits: &fits,
        kernels,
        test: test_object(setup, target, name, base_from_object)?,
        sim: sim_setup(setup, training.db),
    };
    for task in tasks {
        runs.run(task, &mut report, &mut steps)?;
    }
    Ok(report)
}

/// The test object `name` of `target` at `base_from_object`, for the grasp simulator
/// (on the table when its category stands on one).
fn test_object(
    setup: &Setup,
    target: Target,
    name: String,
    base_from_object: Pose,
) -> Result<TestObject, EvalError> {
    let object = target
        .db
        .grasp_object(target.index)
        .map_err(|source| EvalError::Simulation {
            target: name.clone(),
            source,
        })?
        .clone()
        .with_table(
            target
                .db
                .file
                .table_height_m
                .map(|_| setup.region.table_height_m - base_from_object.translation.vector.z),
        );
    Ok(TestObject {
        name,
        object,
        base_from_object,
    })
}

/// The view of the test object `name` at `base_from_object` that the setup asks for.
fn view_of(
    setup: &Setup,
    name: &str,
    mesh: &TriMesh,
    base_from_object: &Pose,
    view_seed: u64,
) -> Result<PointCloud, EvalError> {
    match setup.view {
        ViewKind::Complete => complete_view(
            name,
            mesh,
            base_from_object,
            setup.complete_points,
            view_seed,
        ),
        ViewKind::Partial => partial_view(
            name,
            mesh,
            base_from_object,
            &setup.camera,
            setup.table,
            view_seed,
        ),
    }
}

impl TargetReport {
    /// Records that none of the target's tasks could run, and why.
    fn skip_all(&mut self, reason: String) {
        self.skipped.push(Skipped {
            target: self.target.clone(),
            task: None,
            reason,
        });
    }

    /// Records that `task` could not run, and why.
    fn skip_task(&mut self, task: &str, reason: String) {
        self.skipped.push(Skipped {
            target: self.target.clone(),
            task: Some(task.to_string()),
            reason,
        });
    }
}

impl Training<'_> {
    /// The training models (but the held-out one) without a fit.
    fn unregistered(&self, fits: &[ModelFit]) -> Vec<String> {
        self.db
            .file
            .models
            .iter()
            .map(|m| &m.name)
            .filter(|n| Some(n.as_str()) != self.exclude && !fits.iter().any(|f| &f.name == *n))
            .cloned()
            .collect()
    }
}

/// Each fit of a training model of `train` to the view `cloud` of the test object
/// `mesh` at `base_from_object`, as reported.
fn fit_summaries(
    train: &CategoryDb,
    mesh: &TriMesh,
    base_from_object: &Pose,
    cloud: &PointCloud,
    fits: &[ModelFit],
) -> Vec<FitSummary> {
    let target_handle = super::handle::handle_visible(mesh, base_from_object, cloud);
    let model_handle = |model: &str| {
        train
            .file
            .models
            .iter()
            .position(|m| m.name == model)
            .is_some_and(|i| super::handle::HandleRegion::of(&train.meshes[i]).is_some())
    };
    fits.iter()
        .map(|f| {
            let (dp, _) = pose_error(&f.base_from_model, base_from_object);
            let (tilt_deg, yaw_deg) = tilt_and_yaw_deg(base_from_object, &f.base_from_model);
            FitSummary {
                model: f.name.clone(),
                base_from_model: PoseJson::from(&f.base_from_model),
                eps_m2: f.eps_m2,
                sigma_m2: f.sigma_m2,
                offset_mm: dp * 1e3,
                tilt_deg,
                yaw_deg,
                handle_visible: target_handle && model_handle(&f.name),
            }
        })
        .collect()
}

/// The grasp simulator's setting for grasps planned from `train`.
fn sim_setup(setup: &Setup, train: &CategoryDb) -> SimSetup {
    if setup.paper {
        SimSetup::paper(train.file.simulation.into(), train.file.metric.params())
    } else {
        SimSetup::cell(
            train.file.simulation.into(),
            train.file.metric.params(),
            train.file.stability.retreat_m,
        )
    }
}

/// The tasks of one registered target: plan with each kernel, take best single,
/// simulate both on the test object.
struct TaskRuns<'a> {
    setup: &'a Setup<'a>,
    train: &'a CategoryDb,
    fits: &'a [ModelFit],
    kernels: &'a [Kernel],
    test: TestObject,
    sim: SimSetup,
}

impl TaskRuns<'_> {
    /// Runs `task` with every kernel into `report`; a task the planner cannot do
    /// with these fits is skipped.
    fn run(
        &self,
        task: &str,
        report: &mut TargetReport,
        steps: &mut Steps,
    ) -> Result<(), EvalError> {
        let grasps = match example_grasps(self.train, self.fits, task) {
            Ok(g) => g,
            Err(e) if is_skippable(&e) => {
                report.skip_task(task, e.to_string());
                return Ok(());
            }
            Err(source) => return Err(self.plan_error(task, "-", source)),
        };
        let mut single: Option<SimulatedGrasp> = None;
        for kernel in self.kernels {
            let options = PlanOptions {
                kernel: *kernel,
                parallel: false,
                ..self.setup.plan
            };
            let outcome = match plan(self.fits, &grasps, task, &options, self.setup.reach) {
                Ok(o) => o,
                Err(e) if is_skippable(&e) => {
                    report.skip_task(task, e.to_string());
                    break;
                }
                Err(source) => return Err(self.plan_error(task, kernel.name(), source)),
            };
            let ours = self.simulate(&outcome.plan.grasp)?;
            steps.tick();
            // Best single does not depend on the kernel: simulate it once per task.
            let single = match single {
                Some(s) => s,
                None => *single.insert(self.simulate(&outcome.best_single.grasp)?),
            };
            report
                .runs
                .push(self.record(task, kernel, &outcome, ours, single));
        }
        Ok(())
    }

    /// `grasp` in the grasp simulator on the test object.
    fn simulate(&self, grasp: &PlannedGrasp) -> Result<SimulatedGrasp, EvalError> {
        simulate(
            self.setup.hand,
            &self.test,
            &grasp.pose,
            &grasp.preshape_rad.at_spread(grasp.spread_rad),
            &self.sim,
        )
        .map_err(|source| EvalError::Simulation {
            target: self.test.name.clone(),
            source,
        })
    }

    fn plan_error(&self, task: &str, kernel: &'static str, source: PlanError) -> EvalError {
        EvalError::Plan {
            target: self.test.name.clone(),
            task: task.to_string(),
            kernel,
            source,
        }
    }

    /// The record of our grasp against best single.
    fn record(
        &self,
        task: &str,
        kernel: &Kernel,
        outcome: &PlanOutcome,
        ours: SimulatedGrasp,
        single: SimulatedGrasp,
    ) -> RunRecord {
        let checked = outcome.plan.reachability_checked;
        RunRecord {
            target: self.test.name.clone(),
            task: task.to_string(),
            kernel: kernel.name(),
            epsilon: ours.epsilon,
            epsilon_single: single.epsilon,
            verdict: verdict(ours.epsilon, single.epsilon, self.setup.equal_tolerance),
            ours,
            single,
            pose: PoseJson::from(&outcome.plan.grasp.pose),
            spread_rad: outcome.plan.grasp.spread_rad,
            single_pose: PoseJson::from(&outcome.best_single.grasp.pose),
            single_spread_rad: outcome.best_single.grasp.spread_rad,
            best_single_model: outcome.best_single.model_name.clone(),
            objective: outcome.plan.grasp.objective,
            reachable: checked.then_some(outcome.plan.grasp.reachable),
            single_reachable: checked.then_some(outcome.best_single.grasp.reachable),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::pose_from_params;
    use std::f64::consts::FRAC_PI_2;

    #[test]
    fn tilt_and_yaw_separate_lying_from_turned() {
        let object = pose_from_params(&[0.6, 0.1, 0.0, 0.0, 0.0, 1.0]);
        let close = |(t, y): (f64, f64), (et, ey): (f64, f64)| {
            assert!((t - et).abs() < 1e-9 && (y - ey).abs() < 1e-9, "{t} {y}");
        };
        close(tilt_and_yaw_deg(&object, &object), (0.0, 0.0));
        // Turned about the object's vertical by 120 degrees (either way).
        let turned = object * pose_from_params(&[0.0, 0.0, 0.0, 0.0, 0.0, 2.0944]);
        close(
            tilt_and_yaw_deg(&object, &turned),
            (0.0, 2.0944f64.to_degrees()),
        );
        let turned = object * pose_from_params(&[0.0, 0.0, 0.0, 0.0, 0.0, -2.0944]);
        close(
            tilt_and_yaw_deg(&object, &turned),
            (0.0, 2.0944f64.to_degrees()),
        );
        // Lying on its side (about x), no twist about the vertical.
        let lying = object * pose_from_params(&[0.0, 0.0, 0.0, FRAC_PI_2, 0.0, 0.0]);
        close(
            tilt_and_yaw_deg(&object, &lying),
            (FRAC_PI_2.to_degrees(), 0.0),
        );
        // Upside down.
        let (t, _) = tilt_and_yaw_deg(
            &object,
            &(object * pose_from_params(&[0.0, 0.0, 0.0, 0.0, std::f64::consts::PI, 0.0])),
        );
        assert!((t - 180.0).abs() < 1e-6, "{t}");
    }

    #[test]
    fn registration_stats_count_and_take_medians() {
        let fit = |mm: f64, tilt: f64, yaw: f64| FitSummary {
            model: "m".into(),
            base_from_model: PoseJson::from(&Pose::identity()),
            eps_m2: 1e-5,
            sigma_m2: 1e-6,
            offset_mm: mm,
            tilt_deg: tilt,
            yaw_deg: yaw,
            handle_visible: tilt < 10.0,
        };
        let target = |fits: Vec<FitSummary>, unregistered: usize| TargetReport {
            target: "t".into(),
            placement: 0,
            base_from_object: PoseJson::from(&Pose::identity()),
            view_points: 100,
            fits,
            unregistered: vec!["x".into(); unregistered],
            runs: Vec::new(),
            skipped: Vec::new(),
        };
        let stats = RegistrationStats::of(&[
            target(vec![fit(1.0, 2.0, 40.0), fit(3.0, 90.0, 1.0)], 1),
            target(vec![fit(2.0, 1.0, 170.0)], 2),
        ]);
        assert_eq!((stats.attempted, stats.registered), (6, 3));
        assert_eq!(stats.median_offset_mm, 2.0);
        assert_eq!(stats.median_tilt_deg, 2.0);
        assert_eq!(stats.median_yaw_deg, 40.0);
        assert_eq!((stats.tilt_over_30_deg, stats.yaw_over_30_deg), (1, 2));
        assert_eq!(stats.yaw_bins, [1, 0, 0, 1, 0, 1]);
        assert_eq!(
            (stats.handle_visible, stats.handle_visible_yaw_over_30_deg),
            (2, 2)
        );
        let none = RegistrationStats::of(&[target(Vec::new(), 2)]);
        assert_eq!((none.attempted, none.registered), (2, 0));
        assert!(none.median_offset_mm.is_nan());
    }
}
