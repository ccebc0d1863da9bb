//! What registration reports: per model its status, pose and scores, and the
//! stage times.

use crate::geometry::Pose;
use serde::Serialize;

/// Whether a model registered.
#[derive(Debug, Clone, PartialEq, Serialize)]
#[serde(tag = "status", content = "reason", rename_all = "snake_case")]
pub enum RegistrationStatus {
    /// A transform was found and fits.
    Ok,
    /// No usable transform, and why.
    Failed(String),
}

/// One model's registration onto the target.
#[derive(Debug, Clone, PartialEq)]
pub struct ModelRegistration {
    /// The model's name.
    pub model: String,
    /// Ok, or failed with a reason.
    pub status: RegistrationStatus,
    /// The model frame in the target's frame (identity when failed early).
    pub target_from_model: Pose,
    /// Mean squared distance of target points to the registered model (m²).
    pub eps_m2: f64,
    /// Standard deviation of those squared distances (m²).
    pub sigma_m2: f64,
    /// Fraction of target points within `inlier_distance_m` of the model.
    pub inlier_fraction: f64,
    /// RMS distance of the inliers (m).
    pub rmse_m: f64,
    /// ICP iterations of the winning candidate (coarse + exact).
    pub iterations: usize,
    /// Time spent on this model (ms).
    pub time_ms: f64,
    /// Time per stage for this model (ms).
    pub stages: ModelStageTimes,
}

impl ModelRegistration {
    /// A failed registration of `model`, for `reason`.
    pub(super) fn failed(model: &str, reason: String) -> ModelRegistration {
        ModelRegistration {
            model: model.to_string(),
            status: RegistrationStatus::Failed(reason),
            target_from_model: Pose::identity(),
            eps_m2: f64::NAN,
            sigma_m2: f64::NAN,
            inlier_fraction: 0.0,
            rmse_m: f64::NAN,
            iterations: 0,
            time_ms: 0.0,
            stages: ModelStageTimes::default(),
        }
    }
}

/// Per-model stage times (ms).
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize)]
pub struct ModelStageTimes {
    /// Descriptor matching.
    pub matching_ms: f64,
    /// RANSAC.
    pub ransac_ms: f64,
    /// Coarse search: field ICP and ranking of every start.
    pub coarse_ms: f64,
    /// Exact ICP and ranking of the best candidates.
    pub icp_ms: f64,
    /// Final scores over all target points.
    pub scoring_ms: f64,
}

/// Stage times of one [`register_all`] call (ms). The target's stages run once;
/// the model stages are summed over models (CPU time, models run in parallel).
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize)]
pub struct RegisterTimings {
    /// Voxel downsampling of the target.
    pub downsample_ms: f64,
    /// Target normals.
    pub normals_ms: f64,
    /// Target FPFH descriptors.
    pub fpfh_ms: f64,
    /// Descriptor matching, summed over models.
    pub matching_ms: f64,
    /// RANSAC, summed over models.
    pub ransac_ms: f64,
    /// Coarse search, summed over models.
    pub coarse_ms: f64,
    /// Exact ICP, summed over models.
    pub icp_ms: f64,
    /// Final scoring, summed over models.
    pub scoring_ms: f64,
    /// Wall-clock time of the whole call.
    pub total_ms: f64,
}
