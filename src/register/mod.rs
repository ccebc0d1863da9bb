//! Registration: every model of a category onto one partial view of a novel object.
//!
//! Per model (all in parallel with rayon, model data precomputed once in a
//! [`ModelSet`]: descriptors, normals, a nearest-point field and neighbour graph,
//! a sparse subsample):
//!
//! 1. FPFH descriptors ([`fpfh`]) of the voxel-downsampled target (normals towards
//!    the sensor) and model (normals outward); correspondences are nearest
//!    neighbours in descriptor space (one matrix product for all pairs), kept only
//!    when mutual (all of them if too few are mutual).
//! 2. Correspondence RANSAC in the spirit of PCL's SampleConsensusPrerejective:
//!    three correspondences, rejected unless their edge lengths agree; the rigid fit
//!    is scored by how many target points land near the model, looked up in the
//!    precomputed nearest-point field ([`field`]). The best few distinct hypotheses
//!    are kept.
//! 3. Symmetric objects are not lost to the first local optimum. Seeds: each
//!    hypothesis, the same flipped upside down, and the model standing upright
//!    behind the target. Each seed settles with a few ICP iterations on the field;
//!    every distinct placement is then swept about the table normal through the
//!    model's centroid (`yaw_steps` turns), each turn refined briefly on the field,
//!    the best few refined longer, and the best of those with near-exact nearest
//!    points (the field's answer improved by a walk over the model's neighbour
//!    graph) in two ICP passes, the second with a tight rejection distance.
//!    Candidates are ranked in both directions: the truncated fitting error of the
//!    target's points (target to model) plus a visibility term (model to target,
//!    [`visibility`]): the fraction of the placed model that the sensor's view
//!    contradicts, because it lies in front of what the sensor saw (a mug fitted
//!    upside down, its closed bottom where the camera sees into the opening) or
//!    where the sensor saw past the object (a handle turned away from where the
//!    sensor saw it sticks out of the target's silhouette).
//! 4. Scores of the winner over all target points: `eps` = mean squared distance to
//!    the nearest model point (m²), `sigma` = standard deviation of those squared
//!    distances, inlier fraction and inlier RMSE.
//!
//! Seeded and deterministic: a model's random stream depends only on the seed and
//! the model's name, so leaving a model out does not change the others' results.

pub mod field;
pub mod fpfh;
pub mod icp;
pub mod visibility;

use crate::category::CategoryDb;
use crate::cloud::kdtree::KdIndex;
use crate::cloud::normals::{estimate_normals, Orientation};
use crate::cloud::segment::{segment_object, SegmentError, SegmentParams};
use crate::cloud::voxel::voxel_downsample;
use crate::cloud::PointCloud;
use crate::geometry::Pose;
use crate::plan::input::{FitsInput, Unregistered};
use crate::plan::ModelFit;
use field::SurfaceLookup;
use fpfh::{compute_fpfh, mutual_nearest, Fpfh};
use icp::{icp, rigid_fit, IcpMetric, IcpSettings};
use nalgebra::{Point3, Translation3, UnitQuaternion, Vector3};
use rand::Rng;
use rand_chacha::rand_core::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;
use serde::Serialize;
use std::sync::Arc;
use std::time::Instant;

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

/// Settings of registration. Lengths in metres.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct RegisterParams {
    /// Voxel for FPFH and RANSAC (m).
    pub feature_voxel_m: f64,
    /// Voxel for the target's ICP cloud (m).
    pub icp_voxel_m: f64,
    /// Neighbours for normal estimation.
    pub normal_k: usize,
    /// Radius for normal estimation (m).
    pub normal_radius_m: f64,
    /// FPFH neighbourhood radius (m).
    pub fpfh_radius_m: f64,
    /// Points sampled from a model's mesh (category databases).
    pub model_points: usize,
    /// RANSAC iterations per model.
    pub ransac_iterations: usize,
    /// Least ratio of corresponding edge lengths (0..1) of a RANSAC sample.
    pub edge_similarity: f64,
    /// Shortest edge of a RANSAC sample (m).
    pub min_edge_m: f64,
    /// A target point within this of the model is a RANSAC inlier (m).
    pub ransac_inlier_m: f64,
    /// Distinct RANSAC hypotheses kept.
    pub hypotheses: usize,
    /// Target descriptors (a spread subsample) matched against each model's.
    pub match_points: usize,
    /// Rotations about the table normal tried per hypothesis (1 = none).
    pub yaw_steps: usize,
    /// Coarse (field) ICP iterations that settle each seed before the yaw sweep.
    pub settle_iterations: usize,
    /// Coarse (field) ICP iterations per start of the sweep.
    pub coarse_iterations: usize,
    /// Best distinct starts refined further on the field.
    pub polish_best: usize,
    /// Further coarse ICP iterations of those.
    pub polish_iterations: usize,
    /// Candidates refined with exact ICP.
    pub refine_best: usize,
    /// Most target points in exact ICP (a spread subsample of the ICP cloud).
    pub icp_points: usize,
    /// Exact ICP iterations.
    pub icp_iterations: usize,
    /// ICP rejects pairs farther apart than this (m).
    pub icp_max_distance_m: f64,
    /// The last exact ICP pass rejects pairs farther apart than this (m).
    pub icp_fine_distance_m: f64,
    /// ICP rejects pairs whose normals' cosine is below this.
    pub icp_min_normal_cos: f64,
    /// A model point this far (m) in front of the surface the sensor saw along its
    /// ray counts as seen through.
    pub seen_through_margin_m: f64,
    /// ICP metric.
    pub icp_metric: IcpMetric,
    /// Point-to-plane coarse ICP: weight of its point-to-point term
    /// ([`icp::IcpSettings::point_weight`]), which keeps flat objects from sliding
    /// off unlike models.
    pub icp_coarse_point_weight: f64,
    /// Point-to-plane exact ICP: weight of its point-to-point term.
    pub icp_point_weight: f64,
    /// Target points used to score hypotheses and polish candidates.
    pub score_points: usize,
    /// Of those, the points used in the yaw sweep (a spread subsample).
    pub sweep_points: usize,
    /// Weight of the visibility term in ranking candidates: the fraction of the
    /// placed model's points that the sensor's view contradicts (seen through, or
    /// outside the target's silhouette), times `icp_max_distance_m^2`, is added to
    /// the truncated fitting error.
    pub unseen_weight: f64,
    /// Bin of the target's range image at the target's distance (m).
    pub range_bin_m: f64,
    /// Cell of the nearest-point field (m).
    pub field_cell_m: f64,
    /// Margin of the field around the model (m).
    pub field_margin_m: f64,
    /// A target point within this of the registered model is an inlier (m).
    pub inlier_distance_m: f64,
    /// A registration with a smaller inlier fraction is a failure.
    pub min_inlier_fraction: f64,
    /// A model whose size differs from the target's by more than this factor fails.
    pub max_scale_ratio: f64,
    /// Fewest valid target points.
    pub min_target_points: usize,
    /// Fewest downsampled target points for FPFH.
    pub min_feature_points: usize,
    /// The table normal in the target's frame (the rotation axis of the symmetric
    /// hypotheses).
    pub up: [f64; 3],
    /// The sensor origin in the target's frame, for normal orientation; `None`: a
    /// point 1 m above the target's centroid along `up`.
    pub viewpoint_m: Option<[f64; 3]>,
}

impl Default for RegisterParams {
    fn default() -> RegisterParams {
        RegisterParams {
            feature_voxel_m: 0.005,
            icp_voxel_m: 0.003,
            normal_k: 16,
            normal_radius_m: 0.015,
            fpfh_radius_m: 0.025,
            model_points: 12000,
            ransac_iterations: 3000,
            edge_similarity: 0.9,
            min_edge_m: 0.01,
            ransac_inlier_m: 0.006,
            hypotheses: 4,
            match_points: 300,
            yaw_steps: 24,
            settle_iterations: 6,
            coarse_iterations: 3,
            polish_best: 8,
            polish_iterations: 10,
            refine_best: 3,
            icp_points: 500,
            icp_iterations: 12,
            icp_max_distance_m: 0.01,
            icp_fine_distance_m: 0.004,
            icp_min_normal_cos: 0.5,
            seen_through_margin_m: 0.005,
            icp_metric: IcpMetric::PointToPlane,
            icp_coarse_point_weight: 0.05,
            icp_point_weight: 0.0,
            score_points: 400,
            sweep_points: 200,
            unseen_weight: 1.0,
            range_bin_m: 0.004,
            field_cell_m: 0.003,
            field_margin_m: 0.02,
            inlier_distance_m: 0.005,
            min_inlier_fraction: 0.3,
            max_scale_ratio: 4.0,
            min_target_points: 30,
            min_feature_points: 10,
            up: [0.0, 0.0, 1.0],
            viewpoint_m: None,
        }
    }
}

impl RegisterParams {
    /// Checks that every length is positive and every count usable.
    pub fn check(&self) -> Result<(), RegisterError> {
        let positive = [
            ("feature_voxel_m", self.feature_voxel_m),
            ("icp_voxel_m", self.icp_voxel_m),
            ("normal_radius_m", self.normal_radius_m),
            ("fpfh_radius_m", self.fpfh_radius_m),
            ("min_edge_m", self.min_edge_m),
            ("ransac_inlier_m", self.ransac_inlier_m),
            ("icp_max_distance_m", self.icp_max_distance_m),
            ("icp_fine_distance_m", self.icp_fine_distance_m),
            ("field_cell_m", self.field_cell_m),
            ("inlier_distance_m", self.inlier_distance_m),
            ("max_scale_ratio", self.max_scale_ratio),
            ("range_bin_m", self.range_bin_m),
            ("seen_through_margin_m", self.seen_through_margin_m),
        ];
        for (name, value) in positive {
            if !(value > 0.0 && value.is_finite()) {
                return Err(RegisterError::BadParameter {
                    name,
                    value,
                    problem: "must be a positive number",
                });
            }
        }
        let counts = [
            ("normal_k", self.normal_k, 3),
            ("model_points", self.model_points, 10),
            ("hypotheses", self.hypotheses, 1),
            ("yaw_steps", self.yaw_steps, 1),
            ("match_points", self.match_points, 3),
            ("polish_best", self.polish_best, 1),
            ("refine_best", self.refine_best, 1),
            ("icp_points", self.icp_points, 10),
            ("score_points", self.score_points, 10),
            ("sweep_points", self.sweep_points, 10),
            ("min_target_points", self.min_target_points, 3),
            ("min_feature_points", self.min_feature_points, 3),
        ];
        for (name, value, least) in counts {
            if value < least {
                return Err(RegisterError::BadParameter {
                    name,
                    value: value as f64,
                    problem: "is below its minimum",
                });
            }
        }
        let non_negative = [
            ("unseen_weight", self.unseen_weight),
            ("icp_coarse_point_weight", self.icp_coarse_point_weight),
            ("icp_point_weight", self.icp_point_weight),
        ];
        for (name, value) in non_negative {
            if !(value >= 0.0 && value.is_finite()) {
                return Err(RegisterError::BadParameter {
                    name,
                    value,
                    problem: "must be a non-negative number",
                });
            }
        }
        if Vector3::from(self.up).try_normalize(1e-9).is_none() {
            return Err(RegisterError::BadParameter {
                name: "up",
                value: Vector3::from(self.up).norm(),
                problem: "must be a non-zero direction",
            });
        }
        Ok(())
    }
}

/// A model prepared for registration: clouds, normals, descriptors, search structures.
#[derive(Debug)]
struct PreparedModel {
    /// ICP cloud (model frame) and its outward normals.
    points: Vec<Point3<f32>>,
    normals: Vec<Vector3<f32>>,
    /// Nearest points: the field (coarse) and the graph walk (exact, nearly).
    lookup: SurfaceLookup,
    /// A spread subsample of `points` for the visibility term.
    sparse: Vec<Point3<f32>>,
    /// FPFH cloud and its descriptors.
    feature_points: Vec<Point3<f32>>,
    features: Vec<Fpfh>,
    /// Centroid of `points`.
    centre: Point3<f32>,
    /// Bounding-box diagonal (m).
    extent_m: f64,
}

#[derive(Debug)]
struct ModelEntry {
    name: String,
    prepared: Result<PreparedModel, String>,
}

/// The models of a category, prepared once and reused for many targets.
#[derive(Debug, Clone)]
pub struct ModelSet {
    models: Vec<Arc<ModelEntry>>,
}

fn bbox_diagonal(points: &[Point3<f32>]) -> f64 {
    let Some(first) = points.first() else {
        return 0.0;
    };
    let (mut lo, mut hi) = (first.coords, first.coords);
    for p in points {
        lo = lo.inf(&p.coords);
        hi = hi.sup(&p.coords);
    }
    (hi - lo).norm() as f64
}

fn centroid(points: &[Point3<f32>]) -> Point3<f32> {
    let sum = points
        .iter()
        .fold(Vector3::<f64>::zeros(), |s, p| s + p.coords.cast::<f64>());
    Point3::from((sum / points.len().max(1) as f64).cast::<f32>())
}

/// Largest nearest-point field (cells); a bigger model is far off scale.
const MAX_FIELD_CELLS: usize = 8_000_000;

fn prepare_model(cloud: &PointCloud, params: &RegisterParams) -> Result<PreparedModel, String> {
    let valid = voxel_downsample(cloud, 0.0);
    if valid.len() < params.min_feature_points {
        return Err(format!(
            "model cloud has {} valid points, fewer than {}",
            valid.len(),
            params.min_feature_points
        ));
    }
    let extent_m = bbox_diagonal(&valid.points);
    let outward = Orientation::AwayFrom(centroid(&valid.points));
    // Normals: the cloud's own (a sampled mesh's) or estimated, pointing outward.
    let with_normals = |c: PointCloud| -> (Vec<Point3<f32>>, Vec<Vector3<f32>>) {
        let index = KdIndex::new(&c.points);
        let normals = match c.normals {
            Some(n) if n.len() == c.points.len() => n,
            _ => estimate_normals(
                &c.points,
                &index,
                params.normal_k,
                params.normal_radius_m as f32,
                outward,
            ),
        };
        (c.points, normals)
    };
    // The model's ICP cloud is all its points: downsampling would merge both sides
    // of thin walls.
    let (points, normals) = with_normals(valid.clone());
    let (feature_points, feature_normals) =
        with_normals(voxel_downsample(&valid, params.feature_voxel_m));
    if feature_points.len() < params.min_feature_points {
        return Err(format!(
            "model cloud has {} points after downsampling to {} mm, fewer than {} for FPFH",
            feature_points.len(),
            params.feature_voxel_m * 1e3,
            params.min_feature_points
        ));
    }
    let index = KdIndex::new(&points);
    let lookup = SurfaceLookup::new(
        &points,
        &index,
        params.field_cell_m as f32,
        params.field_margin_m as f32,
        MAX_FIELD_CELLS,
    )
    .ok_or_else(|| {
        format!("model is too large for registration: bounding box diagonal {extent_m:.3} m")
    })?;
    let feature_tree = KdIndex::new(&feature_points);
    let features = compute_fpfh(
        &feature_points,
        &feature_normals,
        &feature_tree,
        params.fpfh_radius_m as f32,
    );
    // The sparse subsample: one point per 8 mm voxel, nearest the voxel centroid.
    let sparse = voxel_downsample(&PointCloud::from_points(points.clone()), 0.008)
        .points
        .iter()
        .map(|c| points[index.nearest(c).map_or(0, |(j, _)| j)])
        .collect();
    Ok(PreparedModel {
        centre: centroid(&points),
        points,
        normals,
        lookup,
        sparse,
        feature_points,
        features,
        extent_m,
    })
}

impl ModelSet {
    /// Prepares `models` (name, cloud in the model frame) in parallel. A model that
    /// cannot be prepared (too few points, far too large) is kept and reported as a
    /// failed entry by [`register_all`]. Errors: no models, a duplicate name, bad
    /// parameters.
    pub fn from_clouds(
        models: Vec<(String, PointCloud)>,
        params: &RegisterParams,
    ) -> Result<ModelSet, RegisterError> {
        params.check()?;
        if models.is_empty() {
            return Err(RegisterError::NoModels);
        }
        for (i, (name, _)) in models.iter().enumerate() {
            if models[..i].iter().any(|(other, _)| other == name) {
                return Err(RegisterError::DuplicateModel(name.clone()));
            }
        }
        let models = models
            .into_par_iter()
            .map(|(name, cloud)| {
                let prepared = prepare_model(&cloud, params);
                if let Err(reason) = &prepared {
                    tracing::warn!(model = %name, %reason, "model not usable for registration");
                }
                Arc::new(ModelEntry { name, prepared })
            })
            .collect();
        Ok(ModelSet { models })
    }

    /// The models of a category database: each mesh sampled with
    /// `params.model_points` points (seeded by the database's cloud seed), or the
    /// stored cloud file when the database names one.
    pub fn from_category(
        db: &CategoryDb,
        params: &RegisterParams,
    ) -> Result<ModelSet, RegisterError> {
        let clouds = (0..db.file.models.len())
            .into_par_iter()
            .map(|i| {
                let entry = &db.file.models[i];
                let cloud = if entry.cloud.file.is_some() {
                    db.model_cloud(i).map_err(|e| e.to_string())
                } else {
                    crate::cloud::sample::sample_surface(
                        &db.meshes[i],
                        params.model_points.max(entry.cloud.points),
                        entry.cloud.seed,
                    )
                    .map_err(|e| e.to_string())
                };
                cloud
                    .map(|c| (entry.name.clone(), c))
                    .map_err(|message| RegisterError::Model {
                        model: entry.name.clone(),
                        message,
                    })
            })
            .collect::<Result<Vec<_>, _>>()?;
        ModelSet::from_clouds(clouds, params)
    }

    /// The set without the model called `name` (shares the prepared models).
    pub fn without(&self, name: &str) -> ModelSet {
        ModelSet {
            models: self
                .models
                .iter()
                .filter(|m| m.name != name)
                .cloned()
                .collect(),
        }
    }

    /// The models' names, in order.
    pub fn names(&self) -> Vec<&str> {
        self.models.iter().map(|m| m.name.as_str()).collect()
    }

    /// Number of models.
    pub fn len(&self) -> usize {
        self.models.len()
    }

    /// True when the set holds no model.
    pub fn is_empty(&self) -> bool {
        self.models.is_empty()
    }
}

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
    /// The fit the planner uses (the target is in the base frame, so
    /// `base_from_model = target_from_model`); `None` when registration failed.
    pub fn fit(&self) -> Option<ModelFit> {
        match self.status {
            RegistrationStatus::Ok => Some(ModelFit {
                name: self.model.clone(),
                base_from_model: self.target_from_model,
                eps_m2: self.eps_m2,
                sigma_m2: self.sigma_m2,
            }),
            RegistrationStatus::Failed(_) => None,
        }
    }

    fn failed(model: &str, reason: String) -> ModelRegistration {
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

/// The target, prepared once for all models.
struct PreparedTarget {
    /// All valid points.
    all: Vec<Point3<f32>>,
    /// ICP cloud and its normals (towards the sensor).
    icp: Vec<Point3<f32>>,
    icp_normals: Vec<Vector3<f32>>,
    /// Scoring subsample and its normals.
    score: Vec<Point3<f32>>,
    score_normals: Vec<Vector3<f32>>,
    feature_points: Vec<Point3<f32>>,
    features: Vec<Fpfh>,
    /// Spread subsample of the feature points matched against the models.
    match_picks: Vec<usize>,
    centroid: Point3<f32>,
    extent_m: f64,
    /// The table normal.
    up: Vector3<f32>,
    /// Lowest height of the target along `up` (m): model points below it are under
    /// the table's cut and unseen.
    floor_m: f32,
    /// The sensor's position.
    eye: Point3<f32>,
    /// The target seen from the viewpoint, for the visibility term.
    range_image: Option<visibility::RangeImage>,
}

fn ms(since: Instant) -> f64 {
    since.elapsed().as_secs_f64() * 1e3
}

/// Indices of every `len / n`-th item (all when there are fewer than `n`).
fn subsample_indices(len: usize, n: usize) -> Vec<usize> {
    if len <= n {
        return (0..len).collect();
    }
    (0..n).map(|k| k * len / n).collect()
}

/// Every `len / n`-th point (all when there are fewer than `n`).
fn subsample(points: &[Point3<f32>], n: usize) -> Vec<Point3<f32>> {
    subsample_indices(points.len(), n)
        .into_iter()
        .map(|i| points[i])
        .collect()
}

fn prepare_target(
    target: &PointCloud,
    params: &RegisterParams,
    timings: &mut RegisterTimings,
) -> Result<PreparedTarget, RegisterError> {
    if target.is_empty() {
        return Err(RegisterError::EmptyTarget);
    }
    let t0 = Instant::now();
    let valid = voxel_downsample(&PointCloud::from_points(target.points.clone()), 0.0);
    if valid.is_empty() {
        return Err(RegisterError::NoValidPoints {
            total: target.len(),
        });
    }
    if valid.len() < params.min_target_points {
        return Err(RegisterError::TooFewPoints {
            what: "registration".into(),
            got: valid.len(),
            need: params.min_target_points,
        });
    }
    let icp_cloud = voxel_downsample(&valid, params.icp_voxel_m);
    let feature_cloud = voxel_downsample(&valid, params.feature_voxel_m);
    timings.downsample_ms = ms(t0);
    if feature_cloud.len() < params.min_feature_points {
        return Err(RegisterError::TooFewPoints {
            what: format!(
                "FPFH after downsampling to {} mm",
                params.feature_voxel_m * 1e3
            ),
            got: feature_cloud.len(),
            need: params.min_feature_points,
        });
    }
    let t1 = Instant::now();
    let centroid = centroid(&valid.points);
    let viewpoint = match params.viewpoint_m {
        Some(v) => Point3::from(Vector3::from(v).cast::<f32>()),
        None => centroid + Vector3::from(params.up).normalize().cast::<f32>(),
    };
    let feature_tree = KdIndex::new(&feature_cloud.points);
    let normals = estimate_normals(
        &feature_cloud.points,
        &feature_tree,
        params.normal_k,
        params.normal_radius_m as f32,
        Orientation::TowardsViewpoint(viewpoint),
    );
    timings.normals_ms = ms(t1);
    let t2 = Instant::now();
    let features = compute_fpfh(
        &feature_cloud.points,
        &normals,
        &feature_tree,
        params.fpfh_radius_m as f32,
    );
    timings.fpfh_ms = ms(t2);
    let t3 = Instant::now();
    let icp_tree = KdIndex::new(&icp_cloud.points);
    let icp_normals = estimate_normals(
        &icp_cloud.points,
        &icp_tree,
        params.normal_k,
        params.normal_radius_m as f32,
        Orientation::TowardsViewpoint(viewpoint),
    );
    timings.normals_ms += ms(t3);
    // At most `icp_points` for ICP, spread over the cloud.
    let keep = subsample_indices(icp_cloud.len(), params.icp_points);
    let icp_normals: Vec<Vector3<f32>> = keep.iter().map(|&i| icp_normals[i]).collect();
    let icp_cloud = PointCloud::from_points(keep.iter().map(|&i| icp_cloud.points[i]).collect());
    let picks = subsample_indices(icp_cloud.len(), params.score_points);
    let up = Vector3::from(params.up).normalize().cast::<f32>();
    let floor_m = valid
        .points
        .iter()
        .map(|p| p.coords.dot(&up))
        .fold(f32::INFINITY, f32::min);
    Ok(PreparedTarget {
        match_picks: subsample_indices(feature_cloud.len(), params.match_points),
        up,
        floor_m,
        eye: viewpoint,
        score_normals: picks.iter().map(|&i| icp_normals[i]).collect(),
        icp_normals,
        extent_m: bbox_diagonal(&valid.points),
        range_image: visibility::RangeImage::new(
            &valid.points,
            viewpoint,
            params.range_bin_m as f32,
        ),
        score: picks.iter().map(|&i| icp_cloud.points[i]).collect(),
        icp: icp_cloud.points,
        all: valid.points,
        feature_points: feature_cloud.points,
        features,
        centroid,
    })
}

/// A model's random seed: the run's seed mixed with the model's name (FNV-1a).
fn model_seed(seed: u64, name: &str) -> u64 {
    let hash = name.bytes().fold(0xcbf2_9ce4_8422_2325u64, |h, b| {
        (h ^ b as u64).wrapping_mul(0x0100_0000_01b3)
    });
    crate::mesh::procedural::instance_seed(seed, hash)
}

/// A scored hypothesis `model_from_target`.
#[derive(Debug, Clone, Copy)]
struct Candidate {
    model_from_target: Pose,
    /// Lower is better.
    cost: f64,
    iterations: usize,
}

/// Model points this far (m) above the target's lowest point or lower are taken
/// as under the table's cut (segmentation removes the points near the table).
const FLOOR_MARGIN_M: f32 = 0.002;

/// Truncated mean squared distance of `points` (target frame) moved by
/// `model_from_target` to the model, the squared distance to the nearest model
/// point given by `nearest_d2`; each is capped at `cap_m²` so that a few outliers
/// cannot dominate.
fn truncated_cost(
    points: &[Point3<f32>],
    model_from_target: &Pose,
    cap_m: f64,
    nearest_d2: impl Fn(&Point3<f32>) -> f32,
) -> f64 {
    let pose = model_from_target.cast::<f32>();
    let cap2 = (cap_m * cap_m) as f32;
    let sum: f64 = points
        .iter()
        .map(|t| nearest_d2(&(pose * t)).min(cap2) as f64)
        .sum();
    sum / points.len().max(1) as f64
}

/// The fraction of the model's sparse points, placed by `model_from_target`, that
/// the target's range image contradicts (in front of what the sensor saw, or where
/// it saw past the object; see [`visibility`]). Points under the table's cut are
/// left out. 0 when the target has no range image.
fn contradicted(
    target: &PreparedTarget,
    model: &PreparedModel,
    model_from_target: &Pose,
    margin_m: f64,
) -> f64 {
    let Some(image) = &target.range_image else {
        return 0.0;
    };
    let target_from_model = model_from_target.inverse().cast::<f32>();
    let floor = target.floor_m + FLOOR_MARGIN_M;
    image.contradicted_fraction(
        model
            .sparse
            .iter()
            .map(|p| target_from_model * p)
            .filter(|p| p.coords.dot(&target.up) >= floor),
        margin_m as f32,
    )
}

/// How a candidate pose is ranked (lower is better): the truncated fitting error of
/// `points` (target to model) plus, weighted by `unseen_weight * cap²`, the
/// fraction of the model that the sensor's view contradicts (model to target). The
/// first term cannot see model surface the target lacks (a handle turned away from
/// where the sensor saw one); the second can. `exact` uses the graph walk for
/// nearest points, otherwise the field.
fn candidate_cost(
    target: &PreparedTarget,
    model: &PreparedModel,
    params: &RegisterParams,
    model_from_target: &Pose,
    points: &[Point3<f32>],
    exact: bool,
) -> f64 {
    let cap = params.icp_max_distance_m;
    let fit = if exact {
        truncated_cost(points, model_from_target, cap, |p| {
            model.lookup.nearest_within(p, cap as f32).1
        })
    } else {
        truncated_cost(points, model_from_target, cap, |p| {
            (model.points[model.lookup.coarse(p)] - p).norm_squared()
        })
    };
    fit + params.unseen_weight
        * cap
        * cap
        * contradicted(
            target,
            model,
            model_from_target,
            params.seen_through_margin_m,
        )
}

fn distinct(a: &Pose, b: &Pose) -> bool {
    let (dp, dr) = crate::geometry::pose_error(a, b);
    dp > 0.005 || dr > 5f64.to_radians()
}

/// The best `n` mutually distinct candidates, best first.
fn best_distinct(mut candidates: Vec<Candidate>, n: usize) -> Vec<Candidate> {
    candidates.sort_by(|a, b| a.cost.total_cmp(&b.cost));
    let mut chosen: Vec<Candidate> = Vec::with_capacity(n);
    for cand in candidates {
        if chosen.len() == n {
            break;
        }
        if chosen
            .iter()
            .all(|c| distinct(&c.model_from_target, &cand.model_from_target))
        {
            chosen.push(cand);
        }
    }
    chosen
}

/// Correspondences `(target feature index, model feature index)` of a spread
/// subsample of the target's descriptors, kept when mutual (all when fewer than
/// 30 are).
fn correspondences(target: &PreparedTarget, model: &PreparedModel) -> Vec<(usize, usize)> {
    let picked: Vec<Fpfh> = target
        .match_picks
        .iter()
        .map(|&i| target.features[i])
        .collect();
    let (forward, backward) = mutual_nearest(&picked, &model.features);
    let mutual: Vec<(usize, usize)> = forward
        .iter()
        .enumerate()
        .filter(|&(i, &j)| backward[j] == i)
        .map(|(i, &j)| (target.match_picks[i], j))
        .collect();
    if mutual.len() >= 30 {
        mutual
    } else {
        forward
            .iter()
            .enumerate()
            .map(|(i, &j)| (target.match_picks[i], j))
            .collect()
    }
}

/// RANSAC over descriptor correspondences `pairs`: the best distinct
/// `target_from_model` hypotheses, best first.
fn ransac(
    target: &PreparedTarget,
    model: &PreparedModel,
    pairs: &[(usize, usize)],
    params: &RegisterParams,
    rng: &mut ChaCha8Rng,
) -> Vec<Pose> {
    let inlier2 = (params.ransac_inlier_m * params.ransac_inlier_m) as f32;
    let check: Vec<Point3<f32>> = subsample(&target.score, 150);
    let mut best: Vec<(usize, Pose)> = Vec::new();
    if pairs.len() < 3 {
        return Vec::new();
    }
    for _ in 0..params.ransac_iterations {
        let mut pick = [0usize; 3];
        for slot in &mut pick {
            *slot = rng.gen_range(0..pairs.len());
        }
        if pick[0] == pick[1] || pick[1] == pick[2] || pick[0] == pick[2] {
            continue;
        }
        let t: Vec<Point3<f64>> = pick
            .iter()
            .map(|&k| target.feature_points[pairs[k].0].cast::<f64>())
            .collect();
        let m: Vec<Point3<f64>> = pick
            .iter()
            .map(|&k| model.feature_points[pairs[k].1].cast::<f64>())
            .collect();
        // Pre-rejection: corresponding edges must have similar lengths.
        let ok = [(0, 1), (1, 2), (0, 2)].iter().all(|&(a, b)| {
            let dt = (t[a] - t[b]).norm();
            let dm = (m[a] - m[b]).norm();
            dt >= params.min_edge_m && dm.min(dt) >= params.edge_similarity * dm.max(dt)
        });
        if !ok {
            continue;
        }
        let Some(target_from_model) = rigid_fit(&m, &t) else {
            continue;
        };
        let pose = target_from_model.inverse().cast::<f32>();
        let inliers = check
            .iter()
            .filter(|q| {
                let p = pose * *q;
                (model.points[model.lookup.coarse(&p)] - p).norm_squared() <= inlier2
            })
            .count();
        if best.len() == params.hypotheses && inliers <= best[best.len() - 1].0 {
            continue;
        }
        // Replace a near-duplicate that scored lower, or insert.
        if let Some(k) = best
            .iter()
            .position(|(_, b)| !distinct(b, &target_from_model))
        {
            if best[k].0 >= inliers {
                continue;
            }
            best.remove(k);
        }
        let at = best.partition_point(|(c, _)| *c >= inliers);
        best.insert(at, (inliers, target_from_model));
        best.truncate(params.hypotheses);
    }
    best.into_iter().map(|(_, p)| p).collect()
}

/// The seeds (`target_from_model`) of the candidate search: each RANSAC
/// hypothesis, upright and flipped (a half turn about a horizontal axis through the
/// placed model's centroid), and the model standing upright behind the target's
/// centroid as the sensor sees it.
fn seeds(
    hypotheses: &[Pose],
    target: &PreparedTarget,
    model: &PreparedModel,
    params: &RegisterParams,
) -> Vec<Pose> {
    let up = nalgebra::Unit::new_normalize(Vector3::from(params.up));
    let side = nalgebra::Unit::new_normalize(
        up.cross(&Vector3::x())
            .try_normalize(1e-6)
            .unwrap_or_else(|| up.cross(&Vector3::y())),
    );
    let model_centre = Point3::from(model.centre.coords.cast::<f64>());
    let mut seeds: Vec<Pose> = Vec::with_capacity(2 * hypotheses.len() + 1);
    for h in hypotheses {
        let c = h * model_centre;
        let flip = Translation3::from(c.coords)
            * UnitQuaternion::from_axis_angle(&side, std::f64::consts::PI)
            * Translation3::from(-c.coords);
        seeds.push(*h);
        seeds.push(flip * h);
    }
    // Upright: the model's +z along the table normal, its centroid a quarter of
    // its size behind the target's centroid (a view sees the front half).
    let upright = UnitQuaternion::rotation_between(&Vector3::z(), &up)
        .unwrap_or_else(UnitQuaternion::identity);
    let c_target = target.centroid.coords.cast::<f64>();
    let mut away = c_target - target.eye.coords.cast::<f64>();
    away -= up.into_inner() * away.dot(&up);
    let away = away.try_normalize(1e-9).unwrap_or_else(Vector3::zeros);
    let centre = c_target + away * (0.15 * model.extent_m);
    seeds.push(Pose::from_parts(
        Translation3::from(centre - upright * model_centre.coords),
        upright,
    ));
    seeds
}

/// Whether two placements `target_from_model` differ by no more than a turn about
/// the table normal `up` (and 5 mm, 3 deg): the yaw sweep of one covers the other.
fn same_but_yaw(a: &Pose, b: &Pose, centre: &Point3<f64>, up: &Vector3<f64>) -> bool {
    let tilt = (a.rotation * b.rotation.inverse()) * up;
    (a * centre - b * centre).norm() < 0.005 && tilt.dot(up) > 3f64.to_radians().cos()
}

/// The starting poses (`model_from_target`): each placement `target_from_model`
/// at `yaw_steps` turns about the table normal through the placed model's centroid.
fn yaw_sweep(placements: &[Pose], model: &PreparedModel, params: &RegisterParams) -> Vec<Pose> {
    let up = nalgebra::Unit::new_normalize(Vector3::from(params.up));
    let model_centre = Point3::from(model.centre.coords.cast::<f64>());
    let mut out = Vec::with_capacity(placements.len() * params.yaw_steps);
    for h in placements {
        let c = (h * model_centre).coords;
        for k in 0..params.yaw_steps {
            let angle = std::f64::consts::TAU * k as f64 / params.yaw_steps as f64;
            let rot = UnitQuaternion::from_axis_angle(&up, angle);
            let about_c = Translation3::from(c) * rot * Translation3::from(-c);
            out.push((about_c * h).inverse());
        }
    }
    out
}

/// Registers one prepared model onto the prepared target.
fn register_one(
    name: &str,
    model: &PreparedModel,
    target: &PreparedTarget,
    params: &RegisterParams,
    seed: u64,
) -> ModelRegistration {
    let started = Instant::now();
    let mut stages = ModelStageTimes::default();
    let ratio = model.extent_m.max(target.extent_m) / model.extent_m.min(target.extent_m).max(1e-9);
    if ratio > params.max_scale_ratio {
        return ModelRegistration::failed(
            name,
            format!(
                "scale mismatch: model extent {:.3} m vs target extent {:.3} m (ratio {:.1} > {})",
                model.extent_m, target.extent_m, ratio, params.max_scale_ratio
            ),
        );
    }
    let mut rng = ChaCha8Rng::seed_from_u64(model_seed(seed, name));
    let t0 = Instant::now();
    let pairs = correspondences(target, model);
    stages.matching_ms = ms(t0);
    let t0 = Instant::now();
    let hypotheses = ransac(target, model, &pairs, params, &mut rng);
    for h in &hypotheses {
        tracing::trace!(model = name, target_from_model = ?crate::geometry::params_from_pose(h), "RANSAC hypothesis");
    }
    stages.ransac_ms = ms(t0);

    // Coarse search on the field: every start a few ICP iterations, the best
    // distinct ones more, the best of those exact.
    let t1 = Instant::now();
    let coarse = |iterations: usize| IcpSettings {
        max_iterations: iterations,
        max_distance_m: 2.0 * params.icp_max_distance_m,
        metric: params.icp_metric,
        point_weight: params.icp_coarse_point_weight,
        converge_translation_m: 1e-4,
        converge_rotation_rad: 1e-3,
        min_normal_cos: params.icp_min_normal_cos as f32,
    };
    let sweep_picks = subsample_indices(target.score.len(), params.sweep_points);
    let sweep: Vec<Point3<f32>> = sweep_picks.iter().map(|&i| target.score[i]).collect();
    let sweep_normals: Vec<Vector3<f32>> = sweep_picks
        .iter()
        .map(|&i| target.score_normals[i])
        .collect();
    let coarse_icp =
        |start: &Pose, iterations: usize, points: &[Point3<f32>], normals: &[Vector3<f32>]| {
            let r = icp(
                points,
                Some(normals),
                &model.points,
                &model.normals,
                |p| Some(model.lookup.coarse(p)),
                start,
                &coarse(iterations),
            );
            Candidate {
                model_from_target: r.model_from_target,
                cost: candidate_cost(target, model, params, &r.model_from_target, points, false),
                iterations: r.iterations,
            }
        };
    // Each seed settles on the field first; seeds that settle to the same
    // placement up to a turn about the table normal are swept once.
    let up = Vector3::from(params.up).normalize();
    let centre = Point3::from(model.centre.coords.cast::<f64>());
    let mut placements: Vec<Pose> = Vec::new();
    let mut settle_iterations = 0;
    for seed in seeds(&hypotheses, target, model, params) {
        let settled = coarse_icp(
            &seed.inverse(),
            params.settle_iterations,
            &sweep,
            &sweep_normals,
        );
        settle_iterations = settled.iterations.max(settle_iterations);
        let placed = settled.model_from_target.inverse();
        if !placements
            .iter()
            .any(|p| same_but_yaw(p, &placed, &centre, &up))
        {
            placements.push(placed);
        }
    }
    let first: Vec<Candidate> = yaw_sweep(&placements, model, params)
        .iter()
        .map(|s| {
            let mut c = coarse_icp(s, params.coarse_iterations, &sweep, &sweep_normals);
            c.iterations += settle_iterations;
            c
        })
        .collect();
    let polished: Vec<Candidate> = best_distinct(first, params.polish_best)
        .into_iter()
        .map(|c| {
            let mut r = coarse_icp(
                &c.model_from_target,
                params.polish_iterations,
                &target.score,
                &target.score_normals,
            );
            r.iterations += c.iterations;
            r
        })
        .collect();
    stages.coarse_ms = ms(t1);
    let t2 = Instant::now();
    let exact = IcpSettings {
        max_iterations: params.icp_iterations,
        max_distance_m: params.icp_max_distance_m,
        metric: params.icp_metric,
        point_weight: params.icp_point_weight,
        converge_translation_m: 5e-5,
        converge_rotation_rad: 5e-4,
        min_normal_cos: params.icp_min_normal_cos as f32,
    };
    let nearest = |p: &Point3<f32>| {
        Some(
            model
                .lookup
                .nearest_within(p, params.icp_max_distance_m as f32)
                .0,
        )
    };
    let best = best_distinct(polished, params.refine_best)
        .iter()
        .map(|cand| {
            let wide = icp(
                &target.icp,
                Some(&target.icp_normals),
                &model.points,
                &model.normals,
                nearest,
                &cand.model_from_target,
                &exact,
            );
            // Then with a tight rejection distance, so that sensor artefacts at the
            // silhouette and surface the model lacks do not pull the fit.
            let mut r = icp(
                &target.icp,
                Some(&target.icp_normals),
                &model.points,
                &model.normals,
                nearest,
                &wide.model_from_target,
                &IcpSettings {
                    max_distance_m: params.icp_fine_distance_m,
                    ..exact
                },
            );
            r.iterations += wide.iterations;
            let cost = candidate_cost(target, model, params, &r.model_from_target, &target.icp, true);
            tracing::trace!(
                model = name,
                cost,
                target_from_model = ?crate::geometry::params_from_pose(&r.model_from_target.inverse()),
                "refined candidate"
            );
            Candidate {
                model_from_target: r.model_from_target,
                cost,
                iterations: cand.iterations + r.iterations,
            }
        })
        .min_by(|a, b| a.cost.total_cmp(&b.cost));
    stages.icp_ms = ms(t2);
    let Some(best) = best else {
        return ModelRegistration::failed(name, "no candidate pose".into());
    };

    let t3 = Instant::now();
    let pose = best.model_from_target.cast::<f32>();
    let d2: Vec<f64> = target
        .all
        .iter()
        .map(|t| model.lookup.nearest(&(pose * t)).1 as f64)
        .collect();
    let n = d2.len() as f64;
    let eps = d2.iter().sum::<f64>() / n;
    let sigma = (d2.iter().map(|v| (v - eps).powi(2)).sum::<f64>() / n).sqrt();
    let in2 = params.inlier_distance_m * params.inlier_distance_m;
    let inliers: Vec<f64> = d2.iter().copied().filter(|&v| v <= in2).collect();
    let inlier_fraction = inliers.len() as f64 / n;
    let rmse = if inliers.is_empty() {
        f64::NAN
    } else {
        (inliers.iter().sum::<f64>() / inliers.len() as f64).sqrt()
    };
    stages.scoring_ms = ms(t3);
    let status = if inlier_fraction < params.min_inlier_fraction {
        RegistrationStatus::Failed(format!(
            "poor fit: {:.0}% of target points within {} mm of the model (need {:.0}%)",
            inlier_fraction * 100.0,
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
        eps_m2: eps,
        sigma_m2: sigma,
        inlier_fraction,
        rmse_m: rmse,
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
            Err(reason) => ModelRegistration::failed(&entry.name, reason.clone()),
        })
        .collect();
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

/// The planner's input from `registrations`: the fits of the models that registered,
/// and the others with the reasons they failed.
pub fn fits_input(registrations: &[ModelRegistration]) -> FitsInput {
    FitsInput {
        fits: registrations.iter().filter_map(|r| r.fit()).collect(),
        unregistered: registrations
            .iter()
            .filter_map(|r| match &r.status {
                RegistrationStatus::Failed(why) => Some(Unregistered {
                    model: r.model.clone(),
                    reason: why.clone(),
                }),
                RegistrationStatus::Ok => None,
            })
            .collect(),
    }
}

impl Perception {
    /// The fits of the models that registered, for the planner.
    pub fn fits(&self) -> Vec<ModelFit> {
        self.registrations.iter().filter_map(|r| r.fit()).collect()
    }
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
