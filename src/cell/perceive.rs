//! `cell-perceive`: the fits of every category model for each trial's snapshot.
//!
//! For each cloud from the camera (matched to its trial request by trial id) it
//! segments the object from the table and registers every model of the requested
//! category to it ([`crate::register::perceive`]), then publishes one [`ModelFit`]
//! per model: `T_i` (`base_from_model`), `eps_i`, `sigma_i`, the inlier fraction and
//! whether it converged. A model that could not be registered is published as
//! failed; a snapshot without an object (segmentation failed) gets fits with no
//! model, which the planner reports as a registration failure.
//!
//! The camera mount is the hand–eye calibration result when there is a valid one
//! ([`crate::calib::current_base_from_camera`]), else the nominal mount of the cell
//! configuration; with the simulated camera it is always the configured mount (the
//! one the simulator renders from). Model sets are prepared (sampled, FPFH) once per category and
//! kept. The random stream of registration is the trial setup's `perception_seed`
//! when the simulated world has a setup file, else the trial id: every trial can be
//! reproduced.

use super::notify::{self, Watchdog};
use super::setup::TrialSetup;
use super::{stop_requested, ByTrial, CellError, TICK};
use crate::cloud::segment::SegmentParams;
use crate::cloud::PointCloud;
use crate::config::CellConfig;
use crate::fsio::{FileError, FileOp};
use crate::geometry::Pose;
use crate::ipc::{
    monotonic_now_ns, wait_any, CloudTopic, Domain, FitStatus, Fits, ModelFit, Point, Protocol,
    Stage, TrialRequest, Wakeable, MAX_FITS, MAX_SEEN_POINTS,
};
use crate::register::{perceive, ModelSet, RegisterParams, RegistrationStatus};
use std::collections::HashMap;
use std::path::PathBuf;

/// What perception needs besides the configuration.
#[derive(Debug, Clone)]
pub struct PerceiveOptions {
    /// Directory of the category databases (`<dir>/<category>/`).
    pub db_dir: PathBuf,
    /// The hand–eye calibration result (used when present and valid, and the camera
    /// is not simulated).
    pub hand_eye: PathBuf,
    /// Directory of per-trial setup files (for the trial's perception seed).
    pub run_dir: PathBuf,
}

/// The prepared model sets of the categories seen so far, with their databases'
/// model counts (fits are published by model index).
struct ModelSets {
    db_dir: PathBuf,
    params: RegisterParams,
    loaded: HashMap<String, ModelSet>,
}

impl ModelSets {
    fn get(&mut self, category: &str) -> Result<&ModelSet, CellError> {
        if !self.loaded.contains_key(category) {
            let db = super::load_category(&self.db_dir, category)?;
            if db.file.models.len() > MAX_FITS {
                return Err(CellError::Invalid(format!(
                    "category {category:?}: {} models, more than the {MAX_FITS} a fits message holds",
                    db.file.models.len()
                )));
            }
            let set = ModelSet::from_category(&db, &self.params)
                .map_err(|e| CellError::Invalid(format!("category {category:?}: models: {e}")))?;
            tracing::info!(category, models = set.len(), "model set prepared");
            self.loaded.insert(category.to_string(), set);
        }
        Ok(&self.loaded[category])
    }
}

/// The categories of the databases under `db_dir` (directories with a
/// `category.json`), sorted.
pub fn categories(db_dir: &std::path::Path) -> Result<Vec<String>, CellError> {
    let entries = std::fs::read_dir(db_dir)
        .map_err(|source| FileError::new(FileOp::ListDir, db_dir, source))?;
    let mut names: Vec<String> = entries
        .flatten()
        .filter(|e| e.path().join("category.json").is_file())
        .filter_map(|e| e.file_name().to_str().map(str::to_string))
        .collect();
    names.sort();
    Ok(names)
}

/// The registration parameters of a trial under `protocol`: the defaults, or
/// scored as the paper did ([`RegisterParams::paper`]).
pub fn register_params(protocol: Protocol) -> RegisterParams {
    let params = RegisterParams::default();
    if protocol.is_paper() {
        params.paper()
    } else {
        params
    }
}

/// Segments and registers one snapshot; the fits message for `trial_id`. A
/// snapshot in which no object can be found gives fits with no model.
pub fn perceive_trial(
    trial_id: u64,
    cloud_camera: &PointCloud,
    base_from_camera: &Pose,
    segment: &SegmentParams,
    models: &ModelSet,
    params: &RegisterParams,
    seed: u64,
) -> Result<Fits, CellError> {
    let perception = match perceive(
        cloud_camera,
        base_from_camera,
        segment,
        models,
        params,
        seed,
    ) {
        Ok(p) => p,
        Err(e) => {
            tracing::warn!(trial_id, "perception failed: {e}");
            return Ok(Fits::new(trial_id, monotonic_now_ns(), &[])?);
        }
    };
    let fits: Vec<ModelFit> = perception
        .registrations
        .iter()
        .enumerate()
        .map(|(i, r)| {
            let status = match r.status {
                RegistrationStatus::Ok => FitStatus::Converged,
                RegistrationStatus::Failed(ref why) => {
                    tracing::warn!(trial_id, model = %r.model, "registration failed: {why}");
                    FitStatus::Failed
                }
            };
            ModelFit::new(
                i as u32,
                status,
                &r.target_from_model,
                r.eps_m2,
                r.sigma_m2,
                r.inlier_fraction,
            )
        })
        .collect();
    tracing::info!(
        trial_id,
        object_points = perception.object_base.len(),
        segment_ms = perception.segment_ms,
        register_ms = perception.register.total_ms,
        "perceived"
    );
    // The seen surface, on the planner's grid (coarser if it would not fit).
    let seen = crate::cloud::voxel::voxel_downsample_to(
        &perception.object_base,
        crate::plan::SeenSurfaceOptions::default().voxel_m,
        MAX_SEEN_POINTS,
    );
    let seen: Vec<Point> = seen.points.iter().map(|&p| Point::from(p)).collect();
    Ok(Fits::new(trial_id, monotonic_now_ns(), &fits)?.with_seen(&seen)?)
}

/// Runs the perception stage until SIGTERM/SIGINT.
pub fn run(
    config: &CellConfig,
    domain: &Domain,
    options: &PerceiveOptions,
) -> Result<(), CellError> {
    // The simulated camera renders from the configured mount, so that is its true
    // mount; a calibration result (of a real camera) applies to real clouds only.
    let base_from_camera = if config.camera.backend == "sim" {
        tracing::info!("simulated camera: its mount is the configured camera.base_from_camera");
        config.base_from_camera()
    } else {
        crate::calib::current_base_from_camera(config, &options.hand_eye).base_from_camera
    };
    let segment = SegmentParams::for_cell(config);
    let mut sets = ModelSets {
        db_dir: options.db_dir.clone(),
        params: RegisterParams::default(),
        loaded: HashMap::new(),
    };
    // Every category's models are prepared before the stage reports ready, so no
    // trial waits for them.
    for category in categories(&options.db_dir)? {
        let started = std::time::Instant::now();
        if let Err(e) = sets.get(&category) {
            tracing::error!("{e}");
        } else {
            tracing::info!(%category, ms = started.elapsed().as_secs_f64() * 1e3, "models ready");
        }
    }
    let stage = Stage::start(domain, "perceive")?;
    let fits_out = stage.publisher::<Fits>()?;
    let clouds = stage.cloud_subscriber(CloudTopic::Camera)?;
    let requests = stage.subscriber::<TrialRequest>()?;
    notify::ready("perceive waiting for snapshots");
    let mut watchdog = Watchdog::from_env();
    let mut pending: ByTrial<PointCloud> = ByTrial::default();
    while !stop_requested() {
        watchdog.ping();
        let inputs: [&dyn Wakeable; 2] = [&requests, &clouds];
        match wait_any(&inputs, TICK) {
            Ok(_) => {}
            Err(_) if stop_requested() => break,
            Err(e) => return Err(e.into()),
        }
        while let Some(r) = requests.try_receive()? {
            // Prepare the category's models as soon as it is asked for, while the
            // camera takes its snapshot.
            if let Ok(category) = r.category() {
                if let Err(e) = sets.get(category) {
                    tracing::error!(trial_id = r.trial_id, "{e}");
                }
            }
            pending.request(r);
        }
        while let Some(sample) = clouds.try_receive()? {
            if let Err(e) = sample.validate() {
                tracing::error!(trial_id = sample.header().trial_id, "bad cloud: {e}");
                continue;
            }
            pending.input(sample.header().trial_id, sample.to_cloud());
        }
        for (request, cloud) in pending.take_ready() {
            let trial_id = request.trial_id;
            let seed = TrialSetup::read(&options.run_dir, trial_id)
                .ok()
                .flatten()
                .map_or(trial_id, |s| s.perception_seed);
            let wanted = request.protocol().map_err(CellError::from).and_then(|p| {
                let models = sets.get(request.category()?)?;
                Ok((models, register_params(p)))
            });
            let fits = match wanted {
                Ok((models, params)) => perceive_trial(
                    trial_id,
                    &cloud,
                    &base_from_camera,
                    &segment,
                    models,
                    &params,
                    seed,
                )?,
                Err(e) => {
                    tracing::error!(trial_id, "no models: {e}");
                    Fits::new(trial_id, monotonic_now_ns(), &[])?
                }
            };
            fits_out.send(&fits)?;
        }
    }
    notify::stopping();
    Ok(())
}
