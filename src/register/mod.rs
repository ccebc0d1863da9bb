//! Registration: every model of a category onto one partial view of a novel object.
//!
//! Per model (all in parallel with rayon), in stages, one file each:
//!
//! - [`params`]: the settings and their check.
//! - [`model`]: the model set, each model prepared once — descriptors, normals, a
//!   nearest-point field and neighbour graph ([`field`]), a sparse subsample.
//! - [`target`]: the target prepared once for all models — voxel-downsampled,
//!   normals towards the sensor, FPFH descriptors ([`fpfh`]), a range image.
//! - [`matching`]: correspondences, nearest neighbours in descriptor space (one
//!   matrix product for all pairs), kept only when mutual (all if too few are).
//! - [`ransac`]: correspondence RANSAC in the spirit of PCL's
//!   SampleConsensusPrerejective; the best few distinct hypotheses.
//! - [`search`]: hypotheses and the yaw sweep — seeds (each hypothesis, the same
//!   flipped upside down, the model standing upright behind the target) settled
//!   on the field, every distinct placement swept about the table normal, the
//!   best turns polished on the field. Beyond the paper, placements tilted more
//!   than `max_tilt_deg` from upright are dropped (the object stands on the table
//!   as its models do).
//! - [`refine`]: exact ICP ([`icp`]) of the best few in two passes, the second
//!   with a tight rejection distance.
//! - [`score`]: candidates are ranked in both directions — the truncated fitting
//!   error of the target's points (target to model) plus a visibility term (model
//!   to target, [`visibility`]): the fraction of the placed model that the
//!   sensor's view contradicts, because it lies in front of what the sensor saw (a
//!   mug fitted upside down) or where the sensor saw past the object (a handle
//!   turned away from where the sensor saw it). Then the winner's scores: `eps` =
//!   mean squared distance to the nearest model point (m²), `sigma` = standard
//!   deviation of those squared distances, inlier fraction and inlier RMSE.
//!
//! - [`consensus`] (beyond the paper; off in its setting): the models agree on
//!   the object's heading, and a model that turned its fit away from the others'
//!   is refined again from theirs.
//!
//! Seeded and deterministic: a model's random stream depends only on the seed and
//! the model's name, so leaving a model out does not change the others' results
//! (except through the heading consensus).

mod consensus;
pub mod field;
pub mod fpfh;
pub mod icp;
mod matching;
mod model;
mod params;
mod points;
mod ransac;
mod refine;
mod result;
mod score;
mod search;
mod target;
pub mod visibility;

#[cfg(test)]
mod fixture;

pub use model::ModelSet;
pub use params::{FitScore, RegisterParams};
pub use result::{ModelRegistration, ModelStageTimes, RegisterTimings, RegistrationStatus};

use crate::cloud::segment::{segment_object, SegmentError, SegmentParams};
use crate::cloud::PointCloud;
use crate::geometry::Pose;
use model::PreparedModel;
use rand_chacha::rand_core::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;
use std::time::Instant;
use target::{prepare_target, PreparedTarget};

/// Errors of registration that concern the target (or the model set) as a whole;
/// a single model's failure is a [`RegistrationStatus::Failed`] entry instead.
#[derive(Debug, thiserror::Error)]
pub enum RegisterError {
    /// The target cloud has no points at all.
    #[error("target cloud is empty")]
    EmptyTarget,
    /// The target cloud's points are all missing (NaN) or non-finite.
    #[error("target cloud has no valid points: all {total} points are NaN or non-finite")]
    NoValidPoints {
        /// Points in the cloud.
        total: usize,
    },
    /// Too few points to describe the target's shape.
    #[error("target cloud has too few points for {what}: {got} < {need}")]
    TooFewPoints {
        /// What needed them ("registration", "FPFH after downsampling to 5 mm").
        what: String,
        /// Points available.
        got: usize,
        /// Points needed.
        need: usize,
    },
    /// No models to register.
    #[error("no models to register against")]
    NoModels,
    /// Two models share a name.
    #[error("model name {0:?} appears twice")]
    DuplicateModel(String),
    /// A model of a category database could not be loaded.
    #[error("model {model}: {message}")]
    Model {
        /// The model.
        model: String,
        /// What went wrong.
        message: String,
    },
    /// A parameter is out of range.
    #[error("register parameter {name} = {value} is invalid: {problem}")]
    BadParameter {
        /// The parameter.
        name: &'static str,
        /// Its value.
        value: f64,
        /// What is wrong.
        problem: &'static str,
    },
    /// Segmentation of the snapshot failed.
    #[error("segmentation: {0}")]
    Segment(#[from] SegmentError),
}

fn ms(since: Instant) -> f64 {
    since.elapsed().as_secs_f64() * 1e3
}

/// A model's random seed: the run's seed mixed with the model's name.
fn model_seed(seed: u64, name: &str) -> u64 {
    crate::mesh::procedural::instance_seed(seed, crate::hash::fnv1a(name.as_bytes()))
}

/// The scale check: a model whose size differs from the target's by more than
/// `max_scale_ratio` fails, and why.
fn scale_mismatch(
    model: &PreparedModel,
    target: &PreparedTarget,
    params: &RegisterParams,
) -> Option<String> {
    let ratio = model.extent_m.max(target.extent_m) / model.extent_m.min(target.extent_m).max(1e-9);
    (ratio > params.max_scale_ratio).then(|| {
        format!(
            "scale mismatch: model extent {:.3} m vs target extent {:.3} m (ratio {:.1} > {})",
            model.extent_m, target.extent_m, ratio, params.max_scale_ratio
        )
    })
}

/// Registers one prepared model onto the prepared target: matching, RANSAC, the
/// coarse search with the yaw sweep, exact ICP, scoring.
fn register_one(
    name: &str,
    model: &PreparedModel,
    target: &PreparedTarget,
    params: &RegisterParams,
    seed: u64,
) -> ModelRegistration {
    let _span = tracing::trace_span!("register", model = name).entered();
    let started = Instant::now();
    let mut stages = ModelStageTimes::default();
    if let Some(reason) = scale_mismatch(model, target, params) {
        return ModelRegistration::failed(name, reason);
    }
    let mut rng = ChaCha8Rng::seed_from_u64(model_seed(seed, name));
    let t0 = Instant::now();
    let pairs = matching::correspondences(target, model);
    stages.matching_ms = ms(t0);
    let t0 = Instant::now();
    let hypotheses = ransac::ransac(target, model, &pairs, params, &mut rng);
    for h in &hypotheses {
        tracing::trace!(target_from_model = ?crate::geometry::params_from_pose(h), "RANSAC hypothesis");
    }
    stages.ransac_ms = ms(t0);
    let t1 = Instant::now();
    let candidates = search::upright(
        search::coarse_search(target, model, params, &hypotheses),
        params,
        |c| c.model_from_target.inverse(),
    );
    stages.coarse_ms = ms(t1);
    let t2 = Instant::now();
    let best = refine::refine(target, model, params, candidates);
    stages.icp_ms = ms(t2);
    let Some(best) = best else {
        return ModelRegistration::failed(name, "no candidate pose".into());
    };
    scored(name, model, target, params, &best, started, stages)
}

/// The registration of `name` at the refined candidate `best`: its final scores
/// and status; `started` and `stages` time it.
fn scored(
    name: &str,
    model: &PreparedModel,
    target: &PreparedTarget,
    params: &RegisterParams,
    best: &search::Candidate,
    started: Instant,
    mut stages: ModelStageTimes,
) -> ModelRegistration {
    let t3 = Instant::now();
    let scores = score::final_scores(target, model, params, &best.model_from_target);
    stages.scoring_ms = ms(t3);
    let status = if scores.inlier_fraction < params.min_inlier_fraction && !params.keep_poor_fits {
        RegistrationStatus::Failed(format!(
            "poor fit: {:.0}% of target points within {} mm of the model (need {:.0}%)",
            scores.inlier_fraction * 100.0,
            params.inlier_distance_m * 1e3,
            params.min_inlier_fraction * 100.0
        ))
    } else {
        RegistrationStatus::Ok
    };
    ModelRegistration {
        model: name.to_string(),
        status,
        target_from_model: best.model_from_target.inverse(),
        eps_m2: scores.eps_m2,
        sigma_m2: scores.sigma_m2,
        inlier_fraction: scores.inlier_fraction,
        rmse_m: scores.rmse_m,
        iterations: best.iterations,
        time_ms: ms(started),
        stages,
    }
}

/// Registers every model of `models` onto `target_base` (the object's points in the
/// robot base frame) with the random stream of `seed`; one entry per model, in the
/// set's order. Errors only when the target itself is unusable.
pub fn register_all(
    target_base: &PointCloud,
    models: &ModelSet,
    params: &RegisterParams,
    seed: u64,
) -> Result<Vec<ModelRegistration>, RegisterError> {
    register_all_timed(target_base, models, params, seed).map(|(r, _)| r)
}

/// [`register_all`] with its stage timings.
pub fn register_all_timed(
    target_base: &PointCloud,
    models: &ModelSet,
    params: &RegisterParams,
    seed: u64,
) -> Result<(Vec<ModelRegistration>, RegisterTimings), RegisterError> {
    let started = Instant::now();
    params.check()?;
    if models.is_empty() {
        return Err(RegisterError::NoModels);
    }
    let mut timings = RegisterTimings::default();
    let target = prepare_target(target_base, params, &mut timings)?;
    let results: Vec<ModelRegistration> = models
        .models
        .par_iter()
        .map(|entry| match &entry.prepared {
            Ok(model) => register_one(&entry.name, model, &target, params, seed),
            Err(reason) => ModelRegistration::failed(&entry.name, reason.to_string()),
        })
        .collect();
    let mut results = results;
    if params.heading_consensus {
        let prepared: Vec<Option<&PreparedModel>> = models
            .models
            .iter()
            .map(|entry| entry.prepared.as_ref().ok())
            .collect();
        consensus::agree_on_heading(&mut results, &prepared, &target, params);
    }
    for r in &results {
        timings.matching_ms += r.stages.matching_ms;
        timings.ransac_ms += r.stages.ransac_ms;
        timings.coarse_ms += r.stages.coarse_ms;
        timings.icp_ms += r.stages.icp_ms;
        timings.scoring_ms += r.stages.scoring_ms;
    }
    timings.total_ms = ms(started);
    tracing::debug!(?timings, models = results.len(), "registered");
    Ok((results, timings))
}

/// The perception stage's result: the object's points and every model's fit.
#[derive(Debug, Clone)]
pub struct Perception {
    /// The segmented object, robot base frame.
    pub object_base: PointCloud,
    /// One registration per model.
    pub registrations: Vec<ModelRegistration>,
    /// Segmentation time (ms).
    pub segment_ms: f64,
    /// Registration stage times (ms).
    pub register: RegisterTimings,
    /// Wall-clock time of both (ms).
    pub total_ms: f64,
}

/// Segments the object out of a camera snapshot and registers every model to it;
/// target normals are oriented towards the camera.
pub fn perceive(
    cloud_camera: &PointCloud,
    base_from_camera: &Pose,
    segment: &SegmentParams,
    models: &ModelSet,
    params: &RegisterParams,
    seed: u64,
) -> Result<Perception, RegisterError> {
    let started = Instant::now();
    let object_base = segment_object(cloud_camera, base_from_camera, segment)?;
    let segment_ms = ms(started);
    let eye = base_from_camera.translation.vector;
    let params = RegisterParams {
        viewpoint_m: Some([eye.x, eye.y, eye.z]),
        ..params.clone()
    };
    let (registrations, register) = register_all_timed(&object_base, models, &params, seed)?;
    Ok(Perception {
        object_base,
        registrations,
        segment_ms,
        register,
        total_ms: ms(started),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn keep_poor_fits_keeps_a_poor_registration_with_its_eps() {
        let truth = Pose::identity();
        let view = fixture::seen(&fixture::mug_cloud(1.0), &truth);
        let strict = RegisterParams {
            // Nothing is this close: every registration is a poor fit.
            inlier_distance_m: 1e-6,
            ..fixture::params()
        };
        let set =
            ModelSet::from_clouds(vec![("mug".into(), fixture::mug_cloud(1.0))], &strict).unwrap();
        let failed = register_all(&view, &set, &strict, 1).unwrap().remove(0);
        assert!(
            matches!(&failed.status, RegistrationStatus::Failed(why) if why.starts_with("poor fit")),
            "{failed:?}"
        );
        let kept = register_all(
            &view,
            &set,
            &RegisterParams {
                keep_poor_fits: true,
                ..strict
            },
            1,
        )
        .unwrap()
        .remove(0);
        assert_eq!(kept.status, RegistrationStatus::Ok);
        assert!(kept.eps_m2.is_finite() && kept.eps_m2 == failed.eps_m2);
        assert_eq!(kept.target_from_model, failed.target_from_model);
    }
}
