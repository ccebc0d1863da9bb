//! A simulated Kinect-class depth camera: ray casting a [`Scene`] from a pinhole
//! camera, then the sensor's error model, giving an organised point cloud in the
//! camera optical frame (z forward, x right, y down; NaN where there is no return).
//!
//! The error model ([`NoiseModel::kinect_v1`]), applied to the true depth `z` of
//! each pixel's surface:
//! - depth noise: `z + N(0, sigma)` with `sigma = 1.5e-3 z^2` m; the point moves
//!   along its pixel's ray;
//! - quantisation: the structured-light disparity `d = f b / z` (px, baseline
//!   `b = 0.075` m) is rounded to 1/8 px and the depth recomputed as `f b / d`, so
//!   depth steps grow as `z^2 / (8 f b)` (3.2 mm at 1 m);
//! - missing returns: no surface within `[min_range_m, max_range_m]`, incidence
//!   angle (surface normal to ray) above 78 deg, and depth edges: a pixel whose
//!   4-neighbour's true depth differs by more than 2 % of its own (or has no
//!   surface) is dropped, as the projector's pattern breaks up there.
//!
//! Noise is seeded: a frame is a function of the scene, the camera and the seed
//! (each image row draws from its own ChaCha8 stream, so threads don't matter).

use super::scene::{Scene, TableBox};
use crate::cloud::PointCloud;
use crate::config::CameraConfig;
use crate::geometry::Pose;
use nalgebra::{Point3, Vector3};
use parry3d_f64::query::{Ray, RayCast};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, StandardNormal};
use rayon::prelude::*;

/// Pinhole intrinsics and the valid depth range.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Intrinsics {
    /// Image width (px).
    pub width_px: u32,
    /// Image height (px).
    pub height_px: u32,
    /// Focal length along x (px).
    pub fx_px: f64,
    /// Focal length along y (px).
    pub fy_px: f64,
    /// Principal point x (px); pixel `u` has its centre at `x = u`.
    pub cx_px: f64,
    /// Principal point y (px).
    pub cy_px: f64,
    /// Nearest depth the sensor returns (m).
    pub min_range_m: f64,
    /// Farthest depth the sensor returns (m).
    pub max_range_m: f64,
}

impl From<&CameraConfig> for Intrinsics {
    fn from(c: &CameraConfig) -> Self {
        Intrinsics {
            width_px: c.width_px,
            height_px: c.height_px,
            fx_px: c.fx_px,
            fy_px: c.fy_px,
            cx_px: c.cx_px,
            cy_px: c.cy_px,
            min_range_m: c.min_range_m,
            max_range_m: c.max_range_m,
        }
    }
}

impl Intrinsics {
    /// Direction of pixel `(u, v)`'s ray in the optical frame, scaled to `z = 1`
    /// (so a point at depth `z` is `z` times it).
    pub fn ray(&self, u: u32, v: u32) -> Vector3<f64> {
        Vector3::new(
            (u as f64 - self.cx_px) / self.fx_px,
            (v as f64 - self.cy_px) / self.fy_px,
            1.0,
        )
    }

    /// Number of pixels.
    pub fn pixels(&self) -> usize {
        self.width_px as usize * self.height_px as usize
    }
}

/// The depth error model (see the module doc).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct NoiseModel {
    /// Depth noise standard deviation per squared metre of depth (1/m).
    pub sigma_per_m: f64,
    /// Projector-camera baseline for the disparity quantisation (m).
    pub baseline_m: f64,
    /// Disparity rounding step (px); zero disables quantisation.
    pub disparity_step_px: f64,
    /// Largest incidence angle that still returns (rad).
    pub max_incidence_rad: f64,
    /// A neighbour's depth jump above this fraction of the depth drops the pixel;
    /// infinite disables edge dropping.
    pub edge_jump_fraction: f64,
}

impl NoiseModel {
    /// Kinect v1: `sigma = 1.5e-3 z^2`, 1/8 px disparity steps over a 7.5 cm
    /// baseline, no return beyond 78 deg incidence or across 2 % depth jumps.
    pub fn kinect_v1() -> NoiseModel {
        NoiseModel {
            sigma_per_m: 1.5e-3,
            baseline_m: 0.075,
            disparity_step_px: 0.125,
            max_incidence_rad: 78f64.to_radians(),
            edge_jump_fraction: 0.02,
        }
    }

    /// A perfect sensor: exact depths, every surface in range returns.
    pub fn ideal() -> NoiseModel {
        NoiseModel {
            sigma_per_m: 0.0,
            baseline_m: 0.075,
            disparity_step_px: 0.0,
            max_incidence_rad: std::f64::consts::FRAC_PI_2,
            edge_jump_fraction: f64::INFINITY,
        }
    }

    /// Standard deviation of the depth noise at depth `z_m` (m).
    pub fn sigma_m(&self, z_m: f64) -> f64 {
        self.sigma_per_m * z_m * z_m
    }

    /// The depth after rounding its disparity (`focal_px` is the focal length).
    pub fn quantise(&self, z_m: f64, focal_px: f64) -> f64 {
        if self.disparity_step_px <= 0.0 {
            return z_m;
        }
        let fb = focal_px * self.baseline_m;
        // Disparity in whole steps; positive, so truncating x + 0.5 rounds to
        // nearest (and stays inlined: this runs for every pixel).
        let steps = (fb / (z_m * self.disparity_step_px) + 0.5) as u64;
        fb / (steps as f64 * self.disparity_step_px)
    }

    /// The largest depth change quantisation makes at depth `z_m` (half a step, m).
    pub fn max_quantisation_error_m(&self, z_m: f64, focal_px: f64) -> f64 {
        if self.disparity_step_px <= 0.0 {
            return 0.0;
        }
        // z = fb/d, so |dz| = z^2 |dd| / fb, with |dd| at most half a step
        // (first order; the factor 1.01 covers the second-order term at short range).
        1.01 * z_m * z_m * self.disparity_step_px / 2.0 / (focal_px * self.baseline_m)
    }
}

/// What a pixel's ray hit first.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Surface {
    /// Nothing in range of the ray.
    None,
    /// The table.
    Table,
    /// The scene object of this index.
    Object(u16),
}

/// Why a pixel has (or lacks) a depth.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Return {
    /// A measured depth.
    Valid,
    /// The ray hit nothing.
    NoSurface,
    /// The surface is nearer than the minimum or beyond the maximum range.
    OutOfRange,
    /// The ray meets the surface too obliquely.
    Grazing,
    /// The pixel lies on a depth discontinuity.
    Edge,
}

/// One rendered frame: per pixel (row-major), the measured depth, the surface
/// hit and the return status.
#[derive(Debug, Clone, PartialEq)]
pub struct DepthFrame {
    /// The intrinsics it was rendered with.
    pub intrinsics: Intrinsics,
    /// Measured depth along the optical axis (m); NaN where missing.
    pub depth_m: Vec<f32>,
    /// The surface each pixel's ray hit (even where the return is missing).
    pub surface: Vec<Surface>,
    /// Why each pixel has a depth or not.
    pub status: Vec<Return>,
}

impl DepthFrame {
    /// The organised point cloud in the camera optical frame (NaN where missing).
    pub fn to_cloud(&self) -> PointCloud {
        let intr = &self.intrinsics;
        let width = intr.width_px as usize;
        let points = self
            .depth_m
            .iter()
            .enumerate()
            .map(|(i, &z)| {
                if z.is_finite() {
                    let ray = intr.ray((i % width) as u32, (i / width) as u32);
                    Point3::new((ray.x * z as f64) as f32, (ray.y * z as f64) as f32, z)
                } else {
                    Point3::new(f32::NAN, f32::NAN, f32::NAN)
                }
            })
            .collect();
        PointCloud {
            points,
            normals: None,
            width: intr.width_px,
            height: intr.height_px,
        }
    }

    /// Fraction of pixels with a measured depth.
    pub fn valid_fraction(&self) -> f64 {
        self.count(|s, _| s == Return::Valid) as f64 / self.status.len().max(1) as f64
    }

    /// Number of pixels for which `keep(status, surface)` holds.
    pub fn count(&self, keep: impl Fn(Return, Surface) -> bool) -> usize {
        self.status
            .iter()
            .zip(&self.surface)
            .filter(|(&r, &s)| keep(r, s))
            .count()
    }
}

/// A depth camera at a pose: intrinsics, error model, `base_from_camera`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DepthCamera {
    /// Pinhole intrinsics and range.
    pub intrinsics: Intrinsics,
    /// The error model.
    pub noise: NoiseModel,
    /// Pose of the optical frame in the robot base frame.
    pub base_from_camera: Pose,
}

/// The first hit of one ray: depth (m), cosine of incidence, surface.
#[derive(Debug, Clone, Copy)]
struct Hit {
    z_m: f32,
    cos_incidence: f32,
    surface: Surface,
}

/// An object as the renderer uses it: pose in the camera frame and the pixel
/// rectangle its bounding box covers.
struct Placed<'a> {
    shape: &'a parry3d_f64::shape::TriMesh,
    camera_from_object: Pose,
    columns: std::ops::Range<u32>,
    rows: std::ops::Range<u32>,
}

impl DepthCamera {
    /// The configured camera with the Kinect v1 error model.
    pub fn from_config(config: &CameraConfig, base_from_camera: Pose) -> DepthCamera {
        DepthCamera {
            intrinsics: Intrinsics::from(config),
            noise: NoiseModel::kinect_v1(),
            base_from_camera,
        }
    }

    /// Renders `scene` with noise drawn from `seed`.
    pub fn render(&self, scene: &Scene, seed: u64) -> DepthFrame {
        let intr = self.intrinsics;
        let (width, height) = (intr.width_px as usize, intr.height_px as usize);
        let camera_from_base = self.base_from_camera.inverse();
        let placed: Vec<Placed> = scene
            .objects
            .iter()
            .map(|o| {
                let camera_from_object = camera_from_base * o.base_from_object;
                let (columns, rows) = self.pixel_rect(&o.shape.aabb(&camera_from_object));
                Placed {
                    shape: &o.shape,
                    camera_from_object,
                    columns,
                    rows,
                }
            })
            .collect();

        // Pass 1: true first hits.
        let columns: Vec<f64> = (0..intr.width_px)
            .map(|u| (u as f64 - intr.cx_px) / intr.fx_px)
            .collect();
        let table = scene
            .table
            .as_ref()
            .map(|t| TableInCamera::new(t, &self.base_from_camera));
        let mut hits = vec![None; width * height];
        hits.par_chunks_mut(width).enumerate().for_each(|(v, row)| {
            let y = (v as f64 - intr.cy_px) / intr.fy_px;
            for (u, hit) in row.iter_mut().enumerate() {
                *hit = self.cast(
                    (u as u32, v as u32),
                    (columns[u], y),
                    table.as_ref(),
                    &placed,
                );
            }
        });

        // Pass 2: returns and noise.
        let min_cos_incidence = self.noise.max_incidence_rad.cos();
        let mut depth_m = vec![f32::NAN; width * height];
        let mut status = vec![Return::NoSurface; width * height];
        depth_m
            .par_chunks_mut(width)
            .zip(status.par_chunks_mut(width))
            .enumerate()
            .for_each(|(v, (depth_row, status_row))| {
                let mut rng = ChaCha8Rng::seed_from_u64(seed);
                rng.set_stream(v as u64);
                for u in 0..width {
                    let (return_, depth) = self.measure(&hits, (u, v), min_cos_incidence, &mut rng);
                    status_row[u] = return_;
                    depth_row[u] = depth;
                }
            });
        let surface = hits
            .iter()
            .map(|h| h.map_or(Surface::None, |h| h.surface))
            .collect();
        DepthFrame {
            intrinsics: intr,
            depth_m,
            surface,
            status,
        }
    }

    /// The status and measured depth of pixel `(u, v)` given every pixel's true hit.
    fn measure(
        &self,
        hits: &[Option<Hit>],
        (u, v): (usize, usize),
        min_cos_incidence: f64,
        rng: &mut ChaCha8Rng,
    ) -> (Return, f32) {
        let intr = &self.intrinsics;
        let (width, height) = (intr.width_px as usize, intr.height_px as usize);
        let Some(hit) = hits[v * width + u] else {
            return (Return::NoSurface, f32::NAN);
        };
        let z = f64::from(hit.z_m);
        if z < intr.min_range_m || z > intr.max_range_m {
            return (Return::OutOfRange, f32::NAN);
        }
        if f64::from(hit.cos_incidence) < min_cos_incidence {
            return (Return::Grazing, f32::NAN);
        }
        // Plain comparisons: this runs for every pixel of every frame.
        let jump = self.noise.edge_jump_fraction * z;
        let breaks = |n: usize| match hits[n] {
            Some(h) => (f64::from(h.z_m) - z).abs() > jump,
            None => true,
        };
        let i = v * width + u;
        let on_edge = (u > 0 && breaks(i - 1))
            || (u + 1 < width && breaks(i + 1))
            || (v > 0 && breaks(i - width))
            || (v + 1 < height && breaks(i + width));
        if on_edge {
            return (Return::Edge, f32::NAN);
        }
        let noise: f64 = StandardNormal.sample(rng);
        let noisy = z + self.noise.sigma_m(z) * noise;
        let measured = self.noise.quantise(noisy, intr.fx_px);
        if !(measured >= intr.min_range_m && measured <= intr.max_range_m) {
            return (Return::OutOfRange, f32::NAN);
        }
        (Return::Valid, measured as f32)
    }

    /// The first surface along pixel `(u, v)`'s ray `(x, y, 1)` (optical frame)
    /// within the maximum range.
    fn cast(
        &self,
        (u, v): (u32, u32),
        (x, y): (f64, f64),
        table: Option<&TableInCamera>,
        placed: &[Placed],
    ) -> Option<Hit> {
        let max_z = self.intrinsics.max_range_m;
        let norm = (x * x + y * y + 1.0).sqrt();
        let mut best: Option<Hit> = table
            .and_then(|t| t.cast(x, y, norm))
            .filter(|h| f64::from(h.z_m) <= max_z);
        for (index, p) in placed.iter().enumerate() {
            if !p.columns.contains(&u) || !p.rows.contains(&v) {
                continue;
            }
            let dir = Vector3::new(x, y, 1.0);
            let ray = Ray::new(Point3::origin(), dir);
            let limit = best.map_or(max_z, |b| f64::from(b.z_m));
            if let Some(hit) =
                p.shape
                    .cast_ray_and_get_normal(&p.camera_from_object, &ray, limit, true)
            {
                if hit.time_of_impact < limit {
                    best = Some(Hit {
                        z_m: hit.time_of_impact as f32,
                        cos_incidence: (hit.normal.dot(&dir).abs() / norm) as f32,
                        surface: Surface::Object(index as u16),
                    });
                }
            }
        }
        best
    }

    /// Columns and rows of the pixels whose rays may meet the camera-frame box
    /// `aabb` (the whole image when the box reaches behind the camera).
    fn pixel_rect(
        &self,
        aabb: &parry3d_f64::bounding_volume::Aabb,
    ) -> (std::ops::Range<u32>, std::ops::Range<u32>) {
        let intr = &self.intrinsics;
        let full = (0..intr.width_px, 0..intr.height_px);
        if aabb.mins.z <= 1e-6 {
            return full;
        }
        let (mut u0, mut u1, mut v0, mut v1) = (f64::MAX, f64::MIN, f64::MAX, f64::MIN);
        for corner in aabb.vertices() {
            let u = intr.fx_px * corner.x / corner.z + intr.cx_px;
            let v = intr.fy_px * corner.y / corner.z + intr.cy_px;
            (u0, u1, v0, v1) = (u0.min(u), u1.max(u), v0.min(v), v1.max(v));
        }
        let clamp = |x: f64, n: u32| x.clamp(0.0, n as f64) as u32;
        (
            clamp(u0.floor() - 1.0, intr.width_px)..clamp(u1.ceil() + 2.0, intr.width_px),
            clamp(v0.floor() - 1.0, intr.height_px)..clamp(v1.ceil() + 2.0, intr.height_px),
        )
    }
}

/// The table box seen from the camera: the camera's position and axes in the
/// base frame (where the box is axis-aligned) and the box's corners.
struct TableInCamera {
    origin: [f64; 3],
    /// Rows of the rotation `base_from_camera`.
    rows: [[f64; 3]; 3],
    lo: [f64; 3],
    hi: [f64; 3],
}

impl TableInCamera {
    fn new(table: &TableBox, base_from_camera: &Pose) -> TableInCamera {
        let (lo, hi) = table.corners();
        let m = base_from_camera.rotation.to_rotation_matrix().into_inner();
        TableInCamera {
            origin: base_from_camera.translation.vector.into(),
            rows: [0, 1, 2].map(|r| [m[(r, 0)], m[(r, 1)], m[(r, 2)]]),
            lo,
            hi,
        }
    }

    /// The hit of the optical-frame ray `(x, y, 1)` of length `norm`.
    fn cast(&self, x: f64, y: f64, norm: f64) -> Option<Hit> {
        let base_dir = self.rows.map(|r| r[0] * x + r[1] * y + r[2]);
        let (z_m, axis) = ray_box(self.origin, base_dir, self.lo, self.hi)?;
        // The face normal is a base axis, so its cosine with the ray is the
        // ray's base-frame component.
        Some(Hit {
            z_m: z_m as f32,
            cos_incidence: (base_dir[axis].abs() / norm) as f32,
            surface: Surface::Table,
        })
    }
}

/// The entry parameter `t` of the ray `origin + t dir` into the axis-aligned box
/// `[lo, hi]` and the axis of the face it enters through; `None` if it misses or
/// starts inside.
fn ray_box(origin: [f64; 3], dir: [f64; 3], lo: [f64; 3], hi: [f64; 3]) -> Option<(f64, usize)> {
    let (mut t_enter, mut t_exit, mut axis) = (f64::NEG_INFINITY, f64::INFINITY, 0);
    for k in 0..3 {
        if dir[k] == 0.0 {
            if origin[k] < lo[k] || origin[k] > hi[k] {
                return None;
            }
            continue;
        }
        let inv = 1.0 / dir[k];
        let (a, b) = ((lo[k] - origin[k]) * inv, (hi[k] - origin[k]) * inv);
        let (near, far) = if a < b { (a, b) } else { (b, a) };
        if near > t_enter {
            t_enter = near;
            axis = k;
        }
        t_exit = t_exit.min(far);
    }
    (t_enter > 0.0 && t_enter <= t_exit).then_some((t_enter, axis))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn quantisation_matches_disparity_steps() {
        let noise = NoiseModel::kinect_v1();
        let f = 525.0;
        for z in [0.6, 1.0, 1.7, 3.5] {
            let q = noise.quantise(z, f);
            // The quantised depth's disparity is a whole number of 1/8 px.
            let eighths = f * 0.075 / q * 8.0;
            assert!((eighths - eighths.round()).abs() < 1e-6, "{z}: {eighths}");
            assert!(
                (q - z).abs() <= noise.max_quantisation_error_m(z, f),
                "{z} -> {q}"
            );
        }
        // At 1 m a step is z^2 / (8 f b) = 1 / 315 m.
        let step = 1.0 / (8.0 * f * 0.075);
        assert!((2.0 * noise.max_quantisation_error_m(1.0, f) / 1.01 - step).abs() < 1e-12);
        assert_eq!(NoiseModel::ideal().quantise(1.234, f), 1.234);
    }

    #[test]
    fn ray_box_enters_through_the_right_face() {
        let table = TableBox {
            height_m: 0.0,
            center_xy_m: [0.0, 0.0],
            extent_xy_m: [1.0, 1.0],
            thickness_m: 0.1,
        };
        let (lo, hi) = table.corners();
        let ray_box = |o: Vector3<f64>, d: Vector3<f64>| ray_box(o.into(), d.into(), lo, hi);
        // From above, straight down: the top face (z axis) at t = 2.
        let hit = ray_box(Vector3::new(0.1, 0.1, 1.0), Vector3::new(0.0, 0.0, -0.5));
        assert_eq!(hit, Some((2.0, 2)));
        // From the side, level with the slab: the +x face.
        let hit = ray_box(Vector3::new(2.0, 0.0, -0.05), Vector3::new(-1.0, 0.0, 0.0));
        assert_eq!(hit, Some((1.5, 0)));
        // Missing and pointing away.
        assert_eq!(
            ray_box(Vector3::new(2.0, 0.0, 1.0), Vector3::new(0.0, 0.0, -1.0)),
            None
        );
        assert_eq!(
            ray_box(Vector3::new(0.0, 0.0, 1.0), Vector3::new(0.0, 0.0, 1.0)),
            None
        );
    }
}
