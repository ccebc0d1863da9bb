//! A simulated Kinect-class depth camera: the first surface of a [`Scene`] along
//! each pixel's ray from a pinhole camera (the table analytically, objects
//! rasterised with exact per-pixel ray-triangle tests, or ray cast through their
//! BVH where they reach behind the camera), then the sensor's error model, giving
//! an organised point cloud in the camera optical frame (z forward, x right,
//! y down; NaN where there is no return).
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
//! Noise is seeded: a frame is a function of the scene, the camera and the seed.
//! Each pixel draws from its own counter-based generator keyed by the seed and the
//! pixel's index, so rows render in parallel and the thread count does not matter.

use super::scene::{Scene, SceneObject, TableBox};
use crate::cloud::PointCloud;
use crate::config::CameraConfig;
use crate::geometry::Pose;
use nalgebra::{Point3, Vector3};
use parry3d_f64::query::{Ray, RayCast};
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

/// An object's nearest hits over the pixel rectangle its vertices project into
/// (row-major within the rectangle): depth along the optical axis (m; infinite
/// where its surface is not hit within range) and the cosine of incidence.
struct ObjectHits {
    /// The object's label: its index in the scene.
    label: Surface,
    columns: std::ops::Range<usize>,
    rows: std::ops::Range<usize>,
    z_m: Vec<f64>,
    cos_incidence: Vec<f64>,
}

impl ObjectHits {
    fn empty(
        label: Surface,
        columns: std::ops::Range<usize>,
        rows: std::ops::Range<usize>,
    ) -> Self {
        let n = columns.len() * rows.len();
        ObjectHits {
            label,
            columns,
            rows,
            z_m: vec![f64::INFINITY; n],
            cos_incidence: vec![0.0; n],
        }
    }

    /// Keeps the hit at depth `z_m` of pixel `(u, v)` if it is nearer than the
    /// one there (the first of equal depths stays).
    fn offer(&mut self, (u, v): (usize, usize), z_m: f64, cos_incidence: f64) {
        let i = (v - self.rows.start) * self.columns.len() + (u - self.columns.start);
        if z_m < self.z_m[i] {
            self.z_m[i] = z_m;
            self.cos_incidence[i] = cos_incidence;
        }
    }
}

/// How the renderer finds an object's hits.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum ObjectMethod {
    /// Rasterise its triangles (exact per-pixel ray tests).
    Rasterise,
    /// Ray cast every pixel of its rectangle through its BVH.
    RayCast,
}

/// Triangles rasterised by one task.
const RASTER_CHUNK_TRIANGLES: usize = 2048;

/// A mesh's vertices in the camera frame and projected to pixels.
struct Projected<'a> {
    vertices: &'a [Point3<f64>],
    /// Pixel coordinates `(u, v)` of each vertex.
    pixels: &'a [[f64; 2]],
    max_z: f64,
}

impl Projected<'_> {
    /// Offers `hits` the first hit of each of its pixels' rays `(x, y, 1)` (`xs`
    /// by `ys`) on `triangles`. A ray is inside a triangle when it lies on the
    /// inner side of the three planes through the camera and an edge; shared
    /// edges give the same plane with the opposite sign, bit for bit, so a closed
    /// surface has no cracks. It meets the triangle's plane at depth
    /// `z = (n . a) / (n . d)`.
    fn rasterise(&self, triangles: &[[u32; 3]], hits: &mut ObjectHits, (xs, ys): (&[f64], &[f64])) {
        let (columns, rows) = (hits.columns.clone(), hits.rows.clone());
        // Candidate pixels: the pixel centres within the triangle's image grown
        // by a thousandth of a pixel (far above the projection's rounding; the
        // exact test decides), within the object's rectangle.
        let span = |[p, q, r]: [f64; 3], range: &std::ops::Range<usize>| {
            let (lo, hi) = (min3(p, q, r), max3(p, q, r));
            let first = (lo - 1e-3).ceil().max(range.start as f64);
            let last = (hi + 1e-3).floor().min(range.end as f64 - 1.0);
            (first <= last).then_some(first as usize..=last as usize)
        };
        for triangle in triangles {
            let [pa, pb, pc] = triangle.map(|i| self.pixels[i as usize]);
            let Some(us) = span([pa[0], pb[0], pc[0]], &columns) else {
                continue;
            };
            let Some(vs) = span([pa[1], pb[1], pc[1]], &rows) else {
                continue;
            };
            let [a, b, c] = triangle.map(|i| self.vertices[i as usize].coords);
            let n = (b - a).cross(&(c - a));
            let n_norm_squared = n.norm_squared();
            // Degenerate (or non-finite) triangles have no plane to hit.
            if !n_norm_squared.is_normal() {
                continue;
            }
            let n_dot_a = n.dot(&a);
            let edges = [a.cross(&b), b.cross(&c), c.cross(&a)];
            for v in vs {
                let y = ys[v];
                for u in us.clone() {
                    let d = Vector3::new(xs[u], y, 1.0);
                    let [s0, s1, s2] = edges.map(|e| e.dot(&d));
                    let inside = (s0 >= 0.0 && s1 >= 0.0 && s2 >= 0.0)
                        || (s0 <= 0.0 && s1 <= 0.0 && s2 <= 0.0);
                    let n_dot_d = n.dot(&d);
                    if !inside || n_dot_d == 0.0 {
                        continue;
                    }
                    let z = n_dot_a / n_dot_d;
                    if z > 0.0 && z <= self.max_z {
                        let cos = n_dot_d.abs() / (n_norm_squared * d.norm_squared()).sqrt();
                        hits.offer((u, v), z, cos);
                    }
                }
            }
        }
    }
}

/// The least of three numbers (plain comparisons: no NaN handling needed).
fn min3(a: f64, b: f64, c: f64) -> f64 {
    let ab = if a < b { a } else { b };
    if ab < c {
        ab
    } else {
        c
    }
}

/// The greatest of three numbers.
fn max3(a: f64, b: f64, c: f64) -> f64 {
    let ab = if a > b { a } else { b };
    if ab > c {
        ab
    } else {
        c
    }
}

/// Per-frame constants of the error model's second pass.
struct Measure {
    min_range_m: f64,
    max_range_m: f64,
    sigma_per_m: f64,
    /// `f b` (px m): disparity times depth.
    fb: f64,
    step_px: f64,
    /// The quantised depth of each whole number of disparity steps, computed as
    /// [`NoiseModel::quantise`] does (so the values are the same bits): one
    /// division per pixel instead of two. Empty without quantisation.
    depth_of_steps: Vec<f64>,
}

impl Measure {
    fn new(intr: &Intrinsics, noise: &NoiseModel) -> Measure {
        let fb = intr.fx_px * noise.baseline_m;
        let step_px = noise.disparity_step_px;
        let depth_of_steps = if step_px > 0.0 {
            // Enough steps for every depth down to the minimum range (a noisy
            // depth below it falls outside the table and is computed directly).
            let top = (fb / (intr.min_range_m.max(1e-3) * step_px)).ceil() + 2.0;
            let top = top.min(1e6) as u64;
            (0..=top)
                .map(|steps| fb / (steps as f64 * step_px))
                .collect()
        } else {
            Vec::new()
        };
        Measure {
            min_range_m: intr.min_range_m,
            max_range_m: intr.max_range_m,
            sigma_per_m: noise.sigma_per_m,
            fb,
            step_px,
            depth_of_steps,
        }
    }

    /// [`NoiseModel::quantise`] with the table.
    fn quantise(&self, z_m: f64) -> f64 {
        if self.step_px <= 0.0 {
            return z_m;
        }
        // As i64 (one conversion instruction; u64 takes several): positive and
        // far below 2^63 for any depth in range.
        let steps = (self.fb / (z_m * self.step_px) + 0.5) as i64;
        match usize::try_from(steps)
            .ok()
            .and_then(|k| self.depth_of_steps.get(k))
        {
            Some(&z) => z,
            None => self.fb / (steps.max(0) as f64 * self.step_px),
        }
    }
}

/// The per-pixel random numbers: a counter-based generator. A frame's noise is
/// one SplitMix64 sequence (output `k` is `mix64(key + k G)`, the key a hash of
/// the seed), and pixel `i` draws from its own stretch of it, starting at
/// position `i 2^PIXEL_STREAM_BITS`: disjoint for any pixel that draws fewer
/// than 2^32 numbers (the normal sampler takes one, rarely a few). So a
/// pixel's draws depend only on the seed and the pixel, never on which thread
/// renders it or in what order, and each costs one mix.
struct PixelRng {
    state: u64,
}

/// SplitMix64's increment (the golden ratio in 64 bits).
const GOLDEN_GAMMA: u64 = 0x9E37_79B9_7F4A_7C15;

/// Positions of the frame's sequence that each pixel owns, as a power of two
/// (2^32 pixels of 2^32 draws each fill the 2^64 period).
const PIXEL_STREAM_BITS: u32 = 32;

/// SplitMix64's output mix (Stafford's variant 13): a bijection on `u64` that
/// spreads every input bit over the output.
fn mix64(mut z: u64) -> u64 {
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

impl PixelRng {
    /// The key of a frame's noise drawn from `seed`.
    fn frame_key(seed: u64) -> u64 {
        mix64(seed.wrapping_add(GOLDEN_GAMMA))
    }

    /// Pixel `index`'s generator under the frame key `key`.
    fn new(key: u64, index: u64) -> PixelRng {
        PixelRng {
            state: key.wrapping_add((index << PIXEL_STREAM_BITS).wrapping_mul(GOLDEN_GAMMA)),
        }
    }
}

impl rand::RngCore for PixelRng {
    fn next_u32(&mut self) -> u32 {
        (self.next_u64() >> 32) as u32
    }

    fn next_u64(&mut self) -> u64 {
        self.state = self.state.wrapping_add(GOLDEN_GAMMA);
        mix64(self.state)
    }

    fn fill_bytes(&mut self, dest: &mut [u8]) {
        for chunk in dest.chunks_mut(8) {
            let bytes = self.next_u64().to_le_bytes();
            chunk.copy_from_slice(&bytes[..chunk.len()]);
        }
    }

    fn try_fill_bytes(&mut self, dest: &mut [u8]) -> Result<(), rand::Error> {
        self.fill_bytes(dest);
        Ok(())
    }
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
    ///
    /// First every object's nearest hits over the rectangle its vertices project
    /// into: rasterised, each triangle testing exactly the pixel rays its image
    /// covers (an object reaching behind the camera is ray cast instead). Then
    /// two passes over the image rows, each parallel over rows: the true first
    /// hit of every pixel's ray (the table analytically, then the objects' hits)
    /// with the geometric dropouts (range, grazing); then depth edges (which need
    /// the neighbouring rows' true depths) and the noise of the pixels that
    /// return, each drawn from a generator keyed by the seed and the pixel alone.
    /// The frame is therefore the same on any number of threads.
    pub fn render(&self, scene: &Scene, seed: u64) -> DepthFrame {
        self.render_with(scene, seed, ObjectMethod::Rasterise)
    }

    /// [`DepthCamera::render`] with every object ray cast through its BVH, pixel
    /// by pixel, instead of rasterised: the reference the rasteriser is checked
    /// and benchmarked against (same error model and noise; slower).
    pub fn render_ray_cast(&self, scene: &Scene, seed: u64) -> DepthFrame {
        self.render_with(scene, seed, ObjectMethod::RayCast)
    }

    fn render_with(&self, scene: &Scene, seed: u64, method: ObjectMethod) -> DepthFrame {
        let intr = self.intrinsics;
        let (width, height) = (intr.width_px as usize, intr.height_px as usize);
        let camera_from_base = self.base_from_camera.inverse();
        // The rays' directions (x, y, 1) by column and row.
        let xs: Vec<f64> = (0..intr.width_px)
            .map(|u| (u as f64 - intr.cx_px) / intr.fx_px)
            .collect();
        let ys: Vec<f64> = (0..intr.height_px)
            .map(|v| (v as f64 - intr.cy_px) / intr.fy_px)
            .collect();
        let objects: Vec<ObjectHits> = scene
            .objects
            .par_iter()
            .enumerate()
            .filter_map(|(index, o)| {
                let camera_from_object = camera_from_base * o.base_from_object;
                let label = Surface::Object(index as u16);
                self.object_hits(o, &camera_from_object, label, method, (&xs, &ys))
            })
            .collect();

        // Pass 1: true first hits and the dropouts that follow from them alone.
        let min_cos_incidence = self.noise.max_incidence_rad.cos();
        let table = scene
            .table
            .as_ref()
            .map(|t| TableInCamera::new(t, &self.base_from_camera, min_cos_incidence));
        let n = width * height;
        // The true depths go into the depth buffer; pass 3 replaces them.
        let mut depth_m = filled(n, f32::NAN);
        let mut surface = filled(n, Surface::None);
        let mut status = filled(n, Return::NoSurface);
        depth_m
            .par_chunks_mut(width)
            .zip(surface.par_chunks_mut(width))
            .zip(status.par_chunks_mut(width))
            .enumerate()
            .for_each(|(v, ((z_row, surface_row), status_row))| {
                let row = Row {
                    z: z_row,
                    surface: surface_row,
                    status: status_row,
                };
                self.cast_row(
                    (v, ys[v]),
                    &xs,
                    table.as_ref(),
                    &objects,
                    min_cos_incidence,
                    row,
                );
            });

        // Pass 2: depth edges, from the rows above and below (statuses only).
        let true_z = &depth_m;
        let edge_jump_fraction = self.noise.edge_jump_fraction;
        status
            .par_chunks_mut(width)
            .enumerate()
            .for_each(|(v, status_row)| {
                let z_rows = (
                    (v > 0).then(|| &true_z[(v - 1) * width..v * width]),
                    &true_z[v * width..(v + 1) * width],
                    (v + 1 < height).then(|| &true_z[(v + 1) * width..(v + 2) * width]),
                );
                mark_edges(edge_jump_fraction, z_rows, status_row);
            });

        // Pass 3: the measured depths of the pixels that return, in place.
        let measure = Measure::new(&intr, &self.noise);
        let key = PixelRng::frame_key(seed);
        depth_m
            .par_chunks_mut(width)
            .zip(status.par_chunks_mut(width))
            .enumerate()
            .for_each(|(v, (depth_row, status_row))| {
                measure_row(&measure, key, (v * width) as u64, depth_row, status_row);
            });
        DepthFrame {
            intrinsics: intr,
            depth_m,
            surface,
            status,
        }
    }

    /// Pass 1 over image row `v` (rays `(x, y, 1)` for `x` in `xs`): the
    /// table's hit in every pixel, then each object's over the columns it
    /// covers, nearer hits replacing farther ones (the first of equal ones stays).
    fn cast_row(
        &self,
        (v, y): (usize, f64),
        xs: &[f64],
        table: Option<&TableInCamera>,
        objects: &[ObjectHits],
        min_cos_incidence: f64,
        row: Row,
    ) {
        let intr = &self.intrinsics;
        let max_z = intr.max_range_m;
        // Range first, then incidence; the cosine goes through f32 as the hit
        // used to store it (so statuses do not hang on its last bits).
        let classify = |z: f32, facing: bool| {
            let z = f64::from(z);
            if z < intr.min_range_m || z > max_z {
                Return::OutOfRange
            } else if !facing {
                Return::Grazing
            } else {
                Return::Valid
            }
        };
        if let Some(table) = table {
            let dy = table.row_offset(y);
            for (u, &x) in xs.iter().enumerate() {
                if let Some((z, facing)) = table.cast(x, &dy) {
                    let z = z as f32;
                    if f64::from(z) <= max_z {
                        row.z[u] = z;
                        row.surface[u] = Surface::Table;
                        row.status[u] = classify(z, facing);
                    }
                }
            }
        }
        for o in objects {
            if !o.rows.contains(&v) {
                continue;
            }
            let start = (v - o.rows.start) * o.columns.len();
            let z_m = &o.z_m[start..start + o.columns.len()];
            let cos = &o.cos_incidence[start..start + o.columns.len()];
            for ((u, &z), &cos) in o.columns.clone().zip(z_m).zip(cos) {
                let best = row.z[u];
                let limit = if best.is_nan() {
                    max_z
                } else {
                    f64::from(best)
                };
                if z < limit {
                    let z = z as f32;
                    row.z[u] = z;
                    row.surface[u] = o.label;
                    row.status[u] = classify(z, cos >= min_cos_incidence);
                }
            }
        }
    }

    /// `object`'s nearest hits at `camera_from_object` over the pixels its
    /// vertices project into, for the rays `(x, y, 1)` of `xs` by `ys`; None when
    /// it lies outside the image. An object wholly in front of the camera is
    /// rasterised: each triangle tests the rays of the pixel centres its image
    /// covers exactly ([`Projected::rasterise`]). One reaching behind the camera
    /// is ray cast through its BVH, pixel by pixel.
    fn object_hits(
        &self,
        object: &SceneObject,
        camera_from_object: &Pose,
        label: Surface,
        method: ObjectMethod,
        (xs, ys): (&[f64], &[f64]),
    ) -> Option<ObjectHits> {
        let max_z = self.intrinsics.max_range_m;
        let shape = &object.shape;
        let vertices: Vec<Point3<f64>> = shape
            .vertices()
            .iter()
            .map(|p| camera_from_object * p)
            .collect();
        let Some((columns, rows)) = self.pixel_rect(&vertices) else {
            let everywhere = (0..xs.len(), 0..ys.len());
            return Some(self.cast_object(shape, camera_from_object, label, everywhere, (xs, ys)));
        };
        if columns.is_empty() || rows.is_empty() {
            return None;
        }
        if method == ObjectMethod::RayCast {
            let rect = (columns, rows);
            return Some(self.cast_object(shape, camera_from_object, label, rect, (xs, ys)));
        }
        let intr = &self.intrinsics;
        let pixels: Vec<[f64; 2]> = vertices
            .iter()
            .map(|p| {
                [
                    intr.fx_px * p.x / p.z + intr.cx_px,
                    intr.fy_px * p.y / p.z + intr.cy_px,
                ]
            })
            .collect();
        let mesh = Projected {
            vertices: &vertices,
            pixels: &pixels,
            max_z,
        };
        // Chunks of triangles in parallel, each into its own buffer; merged in
        // chunk order, so the first of equal depths is the same as in one pass.
        let mut chunks: Vec<ObjectHits> = shape
            .indices()
            .par_chunks(RASTER_CHUNK_TRIANGLES)
            .map(|triangles| {
                let mut hits = ObjectHits::empty(label, columns.clone(), rows.clone());
                mesh.rasterise(triangles, &mut hits, (xs, ys));
                hits
            })
            .collect();
        let mut hits = chunks.remove(0);
        for chunk in chunks {
            for (i, (&z, &cos)) in chunk.z_m.iter().zip(&chunk.cos_incidence).enumerate() {
                if z < hits.z_m[i] {
                    hits.z_m[i] = z;
                    hits.cos_incidence[i] = cos;
                }
            }
        }
        Some(hits)
    }

    /// The nearest hits of `shape` at `camera_from_object` over the pixels
    /// `columns` by `rows` by ray casts through its BVH.
    fn cast_object(
        &self,
        shape: &parry3d_f64::shape::TriMesh,
        camera_from_object: &Pose,
        label: Surface,
        (columns, rows): (std::ops::Range<usize>, std::ops::Range<usize>),
        (xs, ys): (&[f64], &[f64]),
    ) -> ObjectHits {
        let max_z = self.intrinsics.max_range_m;
        let (xs, ys) = (&xs[columns.clone()], &ys[rows.clone()]);
        let mut hits = ObjectHits::empty(label, columns, rows);
        // The rays in the object frame: pixel (x, y)'s direction is x ax + y ay + az.
        let object_from_camera = camera_from_object.inverse();
        let origin = Point3::from(object_from_camera.translation.vector);
        let r = object_from_camera.rotation.to_rotation_matrix();
        let [ax, ay, az] = [0, 1, 2].map(|k| r.matrix().column(k).into_owned());
        hits.z_m
            .par_chunks_mut(xs.len())
            .zip(hits.cos_incidence.par_chunks_mut(xs.len()))
            .zip(ys)
            .for_each(|((z_row, cos_row), &y)| {
                let along_y = ay * y + az;
                for (u, &x) in xs.iter().enumerate() {
                    let dir = ax * x + along_y;
                    let ray = Ray::new(origin, dir);
                    if let Some(hit) = shape.cast_local_ray_and_get_normal(&ray, max_z, true) {
                        if hit.time_of_impact <= max_z {
                            let norm = (x * x + y * y + 1.0).sqrt();
                            z_row[u] = hit.time_of_impact;
                            cos_row[u] = hit.normal.dot(&dir).abs() / norm;
                        }
                    }
                }
            });
        hits
    }

    /// Columns and rows of the pixels whose rays may meet a mesh with `vertices`
    /// (camera frame): the bounding rectangle of the projected vertices (every
    /// triangle projects inside it), a pixel wider each side; None when a vertex
    /// is not in front of the camera.
    fn pixel_rect(
        &self,
        vertices: &[Point3<f64>],
    ) -> Option<(std::ops::Range<usize>, std::ops::Range<usize>)> {
        let intr = &self.intrinsics;
        let (mut u0, mut u1, mut v0, mut v1) = (f64::MAX, f64::MIN, f64::MAX, f64::MIN);
        for p in vertices {
            if p.z.is_nan() || p.z <= 1e-6 {
                return None;
            }
            let u = intr.fx_px * p.x / p.z + intr.cx_px;
            let v = intr.fy_px * p.y / p.z + intr.cy_px;
            (u0, u1, v0, v1) = (u0.min(u), u1.max(u), v0.min(v), v1.max(v));
        }
        if vertices.is_empty() {
            return Some((0..0, 0..0));
        }
        let clamp = |x: f64, n: u32| x.clamp(0.0, n as f64) as usize;
        Some((
            clamp(u0.floor() - 1.0, intr.width_px)..clamp(u1.ceil() + 2.0, intr.width_px),
            clamp(v0.floor() - 1.0, intr.height_px)..clamp(v1.ceil() + 2.0, intr.height_px),
        ))
    }
}

/// A vector of `n` copies of `value`, written in parallel: a frame's buffers
/// are fresh pages, and faulting them in is a good part of a frame's cost.
fn filled<T: Copy + Send + Sync>(n: usize, value: T) -> Vec<T> {
    let mut out = Vec::with_capacity(n);
    out.par_extend(rayon::iter::repeat_n(value, n));
    out
}

/// One image row's pass-1 outputs.
struct Row<'a> {
    z: &'a mut [f32],
    surface: &'a mut [Surface],
    status: &'a mut [Return],
}

/// Pass 2 over one row: a pixel that pass 1 left valid drops out on a depth
/// edge, where a 4-neighbour has no surface or one more than `edge_jump_fraction`
/// of the depth nearer or farther. `z_rows` are the true depths of the rows
/// above (None at the top), of this row and below (None at the bottom).
fn mark_edges(
    edge_jump_fraction: f64,
    (above, here, below): (Option<&[f32]>, &[f32], Option<&[f32]>),
    status_row: &mut [Return],
) {
    let width = here.len();
    for u in 0..width {
        if status_row[u] != Return::Valid {
            continue;
        }
        let z = f64::from(here[u]);
        let jump = edge_jump_fraction * z;
        // A missing neighbour (NaN) breaks too.
        let breaks = |n: f32| {
            let d = (f64::from(n) - z).abs();
            d.is_nan() || d > jump
        };
        let on_edge = (u > 0 && breaks(here[u - 1]))
            || (u + 1 < width && breaks(here[u + 1]))
            || above.is_some_and(|r| breaks(r[u]))
            || below.is_some_and(|r| breaks(r[u]));
        if on_edge {
            status_row[u] = Return::Edge;
        }
    }
}

/// Pass 3 over one row: each pixel still valid gets its noisy, quantised depth
/// in place of the true one (or drops out if that leaves the range); every other
/// pixel's depth becomes NaN. `first` is the index of the row's first pixel.
fn measure_row(
    m: &Measure,
    key: u64,
    first: u64,
    depth_row: &mut [f32],
    status_row: &mut [Return],
) {
    for (u, (depth, status)) in depth_row.iter_mut().zip(status_row.iter_mut()).enumerate() {
        if *status != Return::Valid {
            *depth = f32::NAN;
            continue;
        }
        let z = f64::from(*depth);
        let mut rng = PixelRng::new(key, first + u as u64);
        let noise: f64 = StandardNormal.sample(&mut rng);
        let noisy = z + m.sigma_per_m * z * z * noise;
        let measured = m.quantise(noisy);
        if measured >= m.min_range_m && measured <= m.max_range_m {
            *depth = measured as f32;
        } else {
            *status = Return::OutOfRange;
            *depth = f32::NAN;
        }
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
    /// Depth of the camera below the table's bottom over its depth below the
    /// top (both planes are horizontal, so a ray's parameters at the two are in
    /// this ratio).
    bottom_over_top: f64,
    /// Cosine of the largest incidence angle that returns, and its square.
    min_cos_incidence: f64,
    min_cos_incidence_squared: f64,
}

impl TableInCamera {
    fn new(table: &TableBox, base_from_camera: &Pose, min_cos_incidence: f64) -> TableInCamera {
        let (lo, hi) = table.corners();
        let m = base_from_camera.rotation.to_rotation_matrix().into_inner();
        TableInCamera {
            origin: base_from_camera.translation.vector.into(),
            rows: [0, 1, 2].map(|r| [m[(r, 0)], m[(r, 1)], m[(r, 2)]]),
            bottom_over_top: (lo[2] - base_from_camera.translation.z)
                / (hi[2] - base_from_camera.translation.z),
            lo,
            hi,
            min_cos_incidence,
            min_cos_incidence_squared: min_cos_incidence * min_cos_incidence,
        }
    }

    /// The base-frame direction of the optical-frame ray `(x, y, 1)` is
    /// `x c0 + dy` with `c0` the first column of `base_from_camera`: `dy` for
    /// the row at `y`.
    fn row_offset(&self, y: f64) -> [f64; 3] {
        self.rows.map(|r| r[1] * y + r[2])
    }

    /// The depth of the hit of the optical-frame ray `(x, y, 1)` (`dy` its
    /// row's [`TableInCamera::row_offset`]) and whether the ray meets the face
    /// within the largest incidence angle.
    fn cast(&self, x: f64, dy: &[f64; 3]) -> Option<(f64, bool)> {
        let r = &self.rows;
        let d = [
            r[0][0] * x + dy[0],
            r[1][0] * x + dy[1],
            r[2][0] * x + dy[2],
        ];
        let (o, lo, hi) = (&self.origin, &self.lo, &self.hi);
        // A camera above the top looking down meets the top's plane first; where
        // that point lies on the top it is the hit (one division, no slabs).
        let (z_m, axis) = if o[2] > hi[2] && d[2] < 0.0 {
            let t = (hi[2] - o[2]) / d[2];
            let (px, py) = (o[0] + t * d[0], o[1] + t * d[1]);
            if px >= lo[0] && px <= hi[0] && py >= lo[1] && py <= hi[1] {
                (t, 2)
            } else {
                // Between the top's plane and the bottom's (at `k t`, the planes
                // being horizontal) the ray runs straight from (px, py) to
                // (qx, qy): beyond one side of the footprint at both ends, it
                // passes the slab without entering the box.
                let kt = self.bottom_over_top * t;
                let (qx, qy) = (o[0] + kt * d[0], o[1] + kt * d[1]);
                if (px < lo[0] && qx < lo[0])
                    || (px > hi[0] && qx > hi[0])
                    || (py < lo[1] && qy < lo[1])
                    || (py > hi[1] && qy > hi[1])
                {
                    return None;
                }
                ray_box(self.origin, d, self.lo, self.hi)?
            }
        } else {
            ray_box(self.origin, d, self.lo, self.hi)?
        };
        // The face normal is a base axis, so its cosine with the ray is the
        // ray's base-frame component over its length: compared squared (no root,
        // no division per pixel).
        let facing = self.min_cos_incidence <= 0.0
            || d[axis] * d[axis]
                >= self.min_cos_incidence_squared * (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]);
        Some((z_m, facing))
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
    fn pixel_noise_is_standard_normal_and_uncorrelated_between_pixels() {
        // Neighbouring pixels and neighbouring seeds: zero mean, unit variance,
        // no correlation (each estimate within about 5 standard errors).
        let n = 200_000u64;
        let draw = |key: u64, i: u64| -> f64 { StandardNormal.sample(&mut PixelRng::new(key, i)) };
        for seed in [0, 1, 2] {
            let key = PixelRng::frame_key(seed);
            let x: Vec<f64> = (0..n).map(|i| draw(key, i)).collect();
            let mean = x.iter().sum::<f64>() / n as f64;
            let var = x.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / n as f64;
            let lag = |k: usize| {
                x.iter()
                    .zip(&x[k..])
                    .map(|(a, b)| (a - mean) * (b - mean))
                    .sum::<f64>()
                    / (n as usize - k) as f64
                    / var
            };
            let se = 1.0 / (n as f64).sqrt();
            assert!(mean.abs() < 5.0 * se, "seed {seed}: mean {mean}");
            assert!(
                (var - 1.0).abs() < 5.0 * 2f64.sqrt() * se,
                "seed {seed}: var {var}"
            );
            // The next pixel in the row and the one below it (640 wide).
            for k in [1, 640] {
                assert!(lag(k).abs() < 5.0 * se, "seed {seed}: lag {k}: {}", lag(k));
            }
            // The same pixel under the next seed.
            let next = PixelRng::frame_key(seed + 1);
            let cross = (0..n).map(|i| x[i as usize] * draw(next, i)).sum::<f64>() / n as f64;
            assert!(cross.abs() < 5.0 * se, "seed {seed}: across seeds {cross}");
        }
        // A pixel's draws are fixed by the key and the pixel alone.
        let key = PixelRng::frame_key(7);
        assert_eq!(draw(key, 12345).to_bits(), draw(key, 12345).to_bits());
    }

    #[test]
    fn the_quantisation_table_gives_the_same_depths_as_the_formula() {
        let intr = Intrinsics {
            width_px: 640,
            height_px: 480,
            fx_px: 525.0,
            fy_px: 525.0,
            cx_px: 319.5,
            cy_px: 239.5,
            min_range_m: 0.5,
            max_range_m: 4.0,
        };
        let noise = NoiseModel::kinect_v1();
        let m = Measure::new(&intr, &noise);
        let mut z = 0.3;
        while z < 6.0 {
            let want = noise.quantise(z, intr.fx_px);
            assert_eq!(m.quantise(z).to_bits(), want.to_bits(), "{z}");
            z += 1.3e-4;
        }
        let ideal = Measure::new(&intr, &NoiseModel::ideal());
        assert_eq!(ideal.quantise(1.234), 1.234);
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
