//! Small generated fixtures for the stages' unit tests: a procedural mug with a
//! handle sampled as a model, and the part of it a sensor sees.

use super::model::{prepare_model, PreparedModel};
use super::target::{prepare_target, PreparedTarget};
use super::{RegisterParams, RegisterTimings};
use crate::cloud::PointCloud;
use crate::geometry::Pose;
use crate::mesh::procedural::{generate, Category, Params};
use nalgebra::{Isometry3, Point3};

/// Where the fixtures' sensor sits (target frame): 60 cm in front of the object
/// (+x) and 40 cm above the table.
pub(super) const EYE: [f64; 3] = [0.6, 0.0, 0.4];

/// Points sampled over a procedural mug with a handle (along +x), model frame.
pub(super) fn mug_cloud(scale: f64) -> PointCloud {
    mug_cloud_scaled(scale, scale)
}

/// [`mug_cloud`] scaled by `across` in x and y and by `height` in z (normals kept:
/// close enough for a fixture).
pub(super) fn mug_cloud_scaled(across: f64, height: f64) -> PointCloud {
    mug_sample(across, height, 6000, 1)
}

/// `points` points sampled over the mug with `seed`, scaled as [`mug_cloud_scaled`].
pub(super) fn mug_sample(across: f64, height: f64, points: usize, seed: u64) -> PointCloud {
    let mesh_seed = (0..)
        .find(|&s| matches!(generate(Category::Mug, s).1, Params::Mug(ref m) if m.handle.is_some()))
        .unwrap();
    let (mesh, _) = generate(Category::Mug, mesh_seed);
    let mut cloud = crate::cloud::sample::sample_surface(&mesh, points, seed).unwrap();
    for p in &mut cloud.points {
        p.x *= across as f32;
        p.y *= across as f32;
        p.z *= height as f32;
    }
    cloud
}

/// The points of `model` (model frame, with normals) that a sensor at [`EYE`]
/// sees when the model stands at `target_from_model`: facing the sensor and
/// nearest along their ray (a coarse z-buffer of 0.3 degree bins).
pub(super) fn seen(model: &PointCloud, target_from_model: &Pose) -> PointCloud {
    let iso: Isometry3<f32> = nalgebra::convert(*target_from_model);
    let eye = Point3::from(nalgebra::Vector3::from(EYE).cast::<f32>());
    let normals = model.normals.as_ref().unwrap();
    let placed: Vec<(Point3<f32>, [i32; 2], f32)> = model
        .points
        .iter()
        .zip(normals)
        .map(|(p, n)| (iso * p, iso.rotation * n))
        .filter(|(p, n)| (eye - p).dot(n) > 0.0)
        .map(|(p, _)| {
            let d = p - eye;
            let bin = 0.3f32.to_radians();
            let azimuth = d.y.atan2(-d.x);
            let elevation = d.z.atan2(d.xy().norm());
            let key = [
                (azimuth / bin).floor() as i32,
                (elevation / bin).floor() as i32,
            ];
            (p, key, d.norm())
        })
        .collect();
    let mut nearest = std::collections::HashMap::new();
    for (_, key, range) in &placed {
        let slot = nearest.entry(*key).or_insert(f32::INFINITY);
        *slot = slot.min(*range);
    }
    PointCloud::from_points(
        placed
            .iter()
            .filter(|(_, key, range)| *range <= nearest[key] + 0.004)
            .map(|(p, _, _)| *p)
            .collect(),
    )
}

/// The fixtures' parameters: the sensor at [`EYE`].
pub(super) fn params() -> RegisterParams {
    RegisterParams {
        viewpoint_m: Some(EYE),
        ..RegisterParams::default()
    }
}

/// The mug prepared as a model, and its view at `target_from_model` prepared as
/// the target.
pub(super) fn prepared(target_from_model: &Pose) -> (PreparedModel, PreparedTarget) {
    let params = params();
    let cloud = mug_cloud(1.0);
    let model = prepare_model(&cloud, &params).unwrap();
    let view = seen(&cloud, target_from_model);
    let target = prepare_target(&view, &params, &mut RegisterTimings::default()).unwrap();
    (model, target)
}
