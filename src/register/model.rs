//! The model set: each model of a category prepared once (ICP cloud and normals,
//! nearest-point lookup, sparse subsample for the visibility term, FPFH
//! descriptors) and shared by every target.

use super::field::SurfaceLookup;
use super::fpfh::{compute_fpfh, Fpfh};
use super::points::{bbox_diagonal, centroid};
use super::{RegisterError, RegisterParams};
use crate::category::CategoryDb;
use crate::cloud::kdtree::KdIndex;
use crate::cloud::normals::{estimate_normals, Orientation};
use crate::cloud::voxel::voxel_downsample;
use crate::cloud::PointCloud;
use nalgebra::{Point3, Vector3};
use rayon::prelude::*;
use std::sync::Arc;

/// A model prepared for registration: clouds, normals, descriptors, search structures.
#[derive(Debug)]
pub(super) struct PreparedModel {
    /// ICP cloud (model frame) and its outward normals.
    pub(super) points: Vec<Point3<f32>>,
    pub(super) normals: Vec<Vector3<f32>>,
    /// Nearest points: the field (coarse) and the graph walk (exact, nearly).
    pub(super) lookup: SurfaceLookup,
    /// A spread subsample of `points` for the visibility term.
    pub(super) sparse: Vec<Point3<f32>>,
    /// FPFH cloud and its descriptors.
    pub(super) feature_points: Vec<Point3<f32>>,
    pub(super) features: Vec<Fpfh>,
    /// Centroid of `points`.
    pub(super) centre: Point3<f32>,
    /// Bounding-box diagonal (m).
    pub(super) extent_m: f64,
    /// Whether its turn about its z axis matters (it is no solid of revolution):
    /// it takes part in the heading consensus.
    pub(super) has_heading: bool,
}

/// How far (m) a model's outline may stray from a solid of revolution's and still
/// count as one (sampled surface points; a mug's handle stands out 2-4 cm).
const AXISYMMETRIC_TOLERANCE_M: f64 = 0.003;

#[derive(Debug)]
pub(super) struct ModelEntry {
    pub(super) name: String,
    pub(super) prepared: Result<PreparedModel, ModelUnusable>,
}

/// Why a model cannot be prepared for registration (it is kept as a failed entry).
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub(super) enum ModelUnusable {
    /// Too few valid (finite) points.
    #[error("model cloud has {got} valid points, fewer than {need}")]
    FewValidPoints {
        /// Valid points.
        got: usize,
        /// Points needed.
        need: usize,
    },
    /// Too few points left after downsampling for the descriptors.
    #[error("model cloud has {got} points after downsampling to {voxel_mm} mm, fewer than {need} for FPFH")]
    FewFeaturePoints {
        /// Points after downsampling.
        got: usize,
        /// The voxel size (mm).
        voxel_mm: f64,
        /// Points needed.
        need: usize,
    },
    /// The nearest-point field would be too large.
    #[error("model is too large for registration: bounding box diagonal {extent_m:.3} m")]
    TooLarge {
        /// Bounding-box diagonal (m).
        extent_m: f64,
    },
}

/// The models of a category, prepared once and reused for many targets.
#[derive(Debug, Clone)]
pub struct ModelSet {
    pub(super) models: Vec<Arc<ModelEntry>>,
}

/// Largest nearest-point field (cells); a bigger model is far off scale.
const MAX_FIELD_CELLS: usize = 8_000_000;

pub(super) fn prepare_model(
    cloud: &PointCloud,
    params: &RegisterParams,
) -> Result<PreparedModel, ModelUnusable> {
    let valid = voxel_downsample(cloud, 0.0);
    if valid.len() < params.min_feature_points {
        return Err(ModelUnusable::FewValidPoints {
            got: valid.len(),
            need: params.min_feature_points,
        });
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
        return Err(ModelUnusable::FewFeaturePoints {
            got: feature_points.len(),
            voxel_mm: params.feature_voxel_m * 1e3,
            need: params.min_feature_points,
        });
    }
    let index = KdIndex::new(&points);
    let lookup = SurfaceLookup::new(
        &points,
        &index,
        params.field_cell_m as f32,
        params.field_margin_m as f32,
        MAX_FIELD_CELLS,
    )
    .ok_or(ModelUnusable::TooLarge { extent_m })?;
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
    let has_heading = !crate::mesh::topology::points_axisymmetric(
        points.iter().map(|p| p.cast::<f64>()),
        AXISYMMETRIC_TOLERANCE_M,
    );
    Ok(PreparedModel {
        has_heading,
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
#[cfg(test)]
mod tests {
    use super::*;

    /// A closed box's surface, `n` points a side, `size_m` wide.
    fn box_cloud(size_m: f32, n: usize) -> PointCloud {
        let mut points = Vec::new();
        let step = size_m / (n - 1) as f32;
        for i in 0..n {
            for j in 0..n {
                let (a, b) = (i as f32 * step, j as f32 * step);
                for fixed in [0.0, size_m] {
                    points.push(Point3::new(a, b, fixed));
                    points.push(Point3::new(a, fixed, b));
                    points.push(Point3::new(fixed, a, b));
                }
            }
        }
        PointCloud::from_points(points)
    }

    #[test]
    fn a_model_is_prepared_with_outward_normals_and_its_size() {
        let params = RegisterParams::default();
        let model = prepare_model(&box_cloud(0.08, 21), &params).unwrap();
        assert!((model.extent_m - 0.08 * 3f64.sqrt()).abs() < 1e-6);
        assert!((model.centre - Point3::new(0.04, 0.04, 0.04)).norm() < 1e-3);
        assert_eq!(model.points.len(), model.normals.len());
        assert_eq!(model.feature_points.len(), model.features.len());
        // Outward: a normal on a face points away from the centre.
        let outward = model
            .points
            .iter()
            .zip(&model.normals)
            .filter(|(p, n)| (*p - model.centre).dot(n) > 0.0)
            .count();
        assert!(outward as f64 > 0.95 * model.points.len() as f64);
        // The sparse subsample: one point per 8 mm voxel, all on the model.
        assert!(model.sparse.len() < model.points.len() && model.sparse.len() > 100);
        assert!(model.sparse.iter().all(|s| model.points.contains(s)));
    }

    #[test]
    fn a_model_with_too_few_points_is_a_failed_entry_not_an_error() {
        let params = RegisterParams::default();
        let tiny = PointCloud::from_points(vec![Point3::origin(); 3]);
        let set = ModelSet::from_clouds(
            vec![("box".into(), box_cloud(0.08, 21)), ("tiny".into(), tiny)],
            &params,
        )
        .unwrap();
        assert_eq!(set.names(), ["box", "tiny"]);
        assert!(set.models[0].prepared.is_ok());
        let reason = set.models[1].prepared.as_ref().unwrap_err();
        assert!(
            matches!(reason, ModelUnusable::FewValidPoints { .. }),
            "{reason:?}"
        );
        assert!(reason.to_string().contains("valid points"), "{reason}");
        assert_eq!(set.without("box").names(), ["tiny"]);
    }

    #[test]
    fn no_models_and_duplicate_names_are_errors() {
        let params = RegisterParams::default();
        assert!(matches!(
            ModelSet::from_clouds(Vec::new(), &params),
            Err(RegisterError::NoModels)
        ));
        let twice = vec![
            ("a".into(), box_cloud(0.05, 11)),
            ("a".into(), box_cloud(0.06, 11)),
        ];
        assert!(matches!(
            ModelSet::from_clouds(twice, &params),
            Err(RegisterError::DuplicateModel(name)) if name == "a"
        ));
    }
}
