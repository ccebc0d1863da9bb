//! Procedural object models of the categories the method grasps: mugs, bottles,
//! hammers and knives, deterministic from a seed, within realistic size ranges.
//!
//! [`generate`] samples a category's [`Params`] from a seed and builds the mesh.
//! Every mesh is closed (each edge shared by exactly two triangles with opposite
//! orientation) with outward normals. Frame: z up, the base on the table at
//! `z = 0`, a handle (if any) along +x. Mugs and bottles have their axis on the
//! z axis (the centre of the round base); hammers and knives lie flat with the
//! centre of their footprint's bounding box at the origin.

pub mod held_apart;
mod surface;

use super::TriMesh;
use nalgebra::{Point3, Vector3};
use rand::Rng;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};
use std::f64::consts::{FRAC_PI_2, PI, TAU};
use surface::{
    lathe, resample_by_arc_length, smoothstep, superellipse, Builder, Hole, Sweep, TubeEnd,
};

/// An object category with a procedural model.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Category {
    /// A drinking mug, hollow, most with a handle.
    Mug,
    /// A capped bottle.
    Bottle,
    /// A hammer lying on its side: handle and head.
    Hammer,
    /// A kitchen knife lying flat: handle and blade.
    Knife,
}

impl Category {
    /// Every category.
    pub const ALL: [Category; 4] = [
        Category::Mug,
        Category::Bottle,
        Category::Hammer,
        Category::Knife,
    ];

    /// The lower-case name (`mug`, `bottle`, `hammer`, `knife`).
    pub fn name(self) -> &'static str {
        match self {
            Category::Mug => "mug",
            Category::Bottle => "bottle",
            Category::Hammer => "hammer",
            Category::Knife => "knife",
        }
    }
}

impl std::fmt::Display for Category {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

/// An unknown category name.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("unknown object category {0:?} (use mug, bottle, hammer or knife)")]
pub struct UnknownCategory(pub String);

impl std::str::FromStr for Category {
    type Err = UnknownCategory;

    fn from_str(s: &str) -> Result<Self, Self::Err> {
        Category::ALL
            .into_iter()
            .find(|c| c.name() == s)
            .ok_or_else(|| UnknownCategory(s.to_string()))
    }
}

/// The shape of a mug handle's centre line, seen from the side.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum HandleShape {
    /// A round arc (a piece of a torus).
    TorusArc,
    /// A D: straighter top and bottom with rounded corners.
    DShape,
    /// Nearly square with small corner radii.
    SquareIsh,
}

impl HandleShape {
    /// Superellipse exponent of the centre line (2 is an ellipse).
    fn exponent(self) -> f64 {
        match self {
            HandleShape::TorusArc => 2.0,
            HandleShape::DShape => 3.0,
            HandleShape::SquareIsh => 4.5,
        }
    }
}

/// A mug's handle: a tube swept from a lower to an upper attachment on the +x side.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct HandleParams {
    /// Centre-line shape.
    pub shape: HandleShape,
    /// Height of the lower attachment's centre (m).
    pub lower_z_m: f64,
    /// Height of the upper attachment's centre (m).
    pub upper_z_m: f64,
    /// Extent across the handle, along y (m), 0.008–0.016.
    pub width_m: f64,
    /// Extent in the handle's plane (m), 0.006–0.012.
    pub thickness_m: f64,
    /// Gap between the body and the handle's inside at mid-height (m), 0.015–0.030.
    pub clearance_m: f64,
}

/// A mug: a hollow, straight or tapered body with a rounded bottom edge, a
/// rounded rim and an optional handle.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MugParams {
    /// Height from the base to the rim (m), 0.070–0.120.
    pub height_m: f64,
    /// Outer radius at the rim (m), 0.035–0.050.
    pub radius_top_m: f64,
    /// Outer radius at the base (m): equal to the top (straight) or 78–92 % of it (tapered).
    pub radius_bottom_m: f64,
    /// Wall thickness (m), 0.003–0.006.
    pub wall_thickness_m: f64,
    /// Thickness of the bottom (m), 0.004–0.008.
    pub bottom_thickness_m: f64,
    /// Radius of the rounded outer bottom edge (m), 0.003–0.010.
    pub bottom_fillet_radius_m: f64,
    /// The handle; about one mug in six has none.
    pub handle: Option<HandleParams>,
    /// How far the wall bulges out at mid-height beyond the straight or tapered
    /// line (m): 0 for the training mugs, 0.006–0.012 for the held-apart barrels
    /// ([`held_apart`]).
    #[serde(default, skip_serializing_if = "is_zero")]
    pub bulge_m: f64,
}

fn is_zero(x: &f64) -> bool {
    *x == 0.0
}

/// A capped bottle: a surface of revolution with body, shoulder, neck and lip.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct BottleParams {
    /// Total height (m), 0.18–0.32.
    pub height_m: f64,
    /// Radius of the body (m), 0.030–0.045.
    pub body_radius_m: f64,
    /// Height of the straight body (m), at least half the total.
    pub body_height_m: f64,
    /// Height over which the shoulder narrows to the neck (m), 0.02–0.07.
    pub shoulder_height_m: f64,
    /// Radius of the neck (m), 0.010–0.016.
    pub neck_radius_m: f64,
    /// Length of the neck including the lip (m), 0.02–0.07.
    pub neck_length_m: f64,
    /// How far the lip bead stands out of the neck (m), 0.001–0.003.
    pub lip_m: f64,
    /// Radius of the rounded bottom edge (m), 0.003–0.008.
    pub bottom_fillet_radius_m: f64,
}

/// A hammer lying on its side: a head along y and a handle along +x.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct HammerParams {
    /// Length of the head, face to peen (m), 0.09–0.14.
    pub head_length_m: f64,
    /// Side of the head's square cross-section (m), 0.022–0.032.
    pub head_section_m: f64,
    /// Length of the handle from the head to the butt (m), 0.22–0.34.
    pub handle_length_m: f64,
    /// Handle extent along the head's axis, y (m), 0.024–0.034.
    pub handle_width_m: f64,
    /// Handle extent across, z (m), 55–70 % of the head section.
    pub handle_thickness_m: f64,
}

/// A kitchen knife lying flat: a blade toward -x and a handle toward +x.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct KnifeParams {
    /// Blade length from tip to bolster (m), 0.08–0.20.
    pub blade_length_m: f64,
    /// Blade width, spine to edge (m), 0.018–0.045.
    pub blade_width_m: f64,
    /// Blade thickness at the heel (m), 0.0015–0.003.
    pub blade_thickness_m: f64,
    /// Length of the bolster joining blade and handle (m), 0.008–0.015.
    pub bolster_length_m: f64,
    /// Handle length (m), 0.09–0.13.
    pub handle_length_m: f64,
    /// Handle width, y (m), 0.018–0.026.
    pub handle_width_m: f64,
    /// Handle thickness, z (m), 0.012–0.020.
    pub handle_thickness_m: f64,
}

/// The parameters of one instance, tagged with its category.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "category", rename_all = "snake_case")]
pub enum Params {
    /// A mug.
    Mug(MugParams),
    /// A bottle.
    Bottle(BottleParams),
    /// A hammer.
    Hammer(HammerParams),
    /// A knife.
    Knife(KnifeParams),
}

impl Params {
    /// Samples an instance of `category` within its ranges.
    pub fn sample(category: Category, rng: &mut impl Rng) -> Params {
        match category {
            Category::Mug => Params::Mug(MugParams::sample(rng)),
            Category::Bottle => Params::Bottle(BottleParams::sample(rng)),
            Category::Hammer => Params::Hammer(HammerParams::sample(rng)),
            Category::Knife => Params::Knife(KnifeParams::sample(rng)),
        }
    }

    /// The category of these parameters.
    pub fn category(&self) -> Category {
        match self {
            Params::Mug(_) => Category::Mug,
            Params::Bottle(_) => Category::Bottle,
            Params::Hammer(_) => Category::Hammer,
            Params::Knife(_) => Category::Knife,
        }
    }

    /// The closed, outward mesh these parameters describe.
    pub fn build(&self) -> TriMesh {
        match self {
            Params::Mug(p) => p.build(),
            Params::Bottle(p) => p.build(),
            Params::Hammer(p) => p.build(),
            Params::Knife(p) => p.build(),
        }
    }
}

/// An instance of `category` from `seed`: its mesh and parameters.
pub fn generate(category: Category, seed: u64) -> (TriMesh, Params) {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let params = Params::sample(category, &mut rng);
    (params.build(), params)
}

/// The seed of instance `index` of a set generated from `seed` (SplitMix64 mixing,
/// so neighbouring seeds and indices give unrelated instances).
pub fn instance_seed(seed: u64, index: u64) -> u64 {
    splitmix64(seed ^ splitmix64(index.wrapping_add(0x5EED)))
}

fn splitmix64(x: u64) -> u64 {
    let mut z = x.wrapping_add(0x9E37_79B9_7F4A_7C15);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

/// Appends `(r, z)` points from the last one to `to` (exclusive of the last,
/// inclusive of `to`), in steps no longer than `step`.
fn push_line(profile: &mut Vec<[f64; 2]>, to: [f64; 2], step: f64) {
    let from = *profile.last().expect("profile starts with a point");
    let length = ((to[0] - from[0]).powi(2) + (to[1] - from[1]).powi(2)).sqrt();
    let n = ((length / step).ceil() as usize).max(1);
    for k in 1..=n {
        let f = k as f64 / n as f64;
        profile.push([
            from[0] + (to[0] - from[0]) * f,
            from[1] + (to[1] - from[1]) * f,
        ]);
    }
}

/// Appends an arc about `centre` of `radius` from angle `a0` (exclusive) to `a1`
/// (inclusive) in `n` steps.
fn push_arc(
    profile: &mut Vec<[f64; 2]>,
    centre: [f64; 2],
    radius: f64,
    a0: f64,
    a1: f64,
    n: usize,
) {
    for k in 1..=n {
        let a = a0 + (a1 - a0) * k as f64 / n as f64;
        profile.push([centre[0] + radius * a.cos(), centre[1] + radius * a.sin()]);
    }
}

/// Evenly spaced angles for a ring of about `n` segments.
fn uniform_angles(n: usize) -> Vec<f64> {
    (0..n).map(|j| TAU * j as f64 / n as f64).collect()
}

/// Moves a lying object so its footprint's bounding box is centred on the origin
/// and its lowest point is at `z = 0`.
fn place_on_table(mut mesh: TriMesh) -> TriMesh {
    if let Some((lo, hi)) = super::topology::bounding_box(&mesh) {
        let shift = Vector3::new(-(lo.x + hi.x) / 2.0, -(lo.y + hi.y) / 2.0, -lo.z);
        for v in &mut mesh.vertices {
            *v += shift;
        }
    }
    mesh
}

const RING_SEGMENTS: usize = 64;
/// Grid cells across a handle's attachment, in each direction.
const ATTACHMENT_CELLS: usize = 4;

impl MugParams {
    /// Samples a mug within the documented ranges.
    pub fn sample(rng: &mut impl Rng) -> MugParams {
        let height_m = rng.gen_range(0.070..=0.120);
        let radius_top_m = rng.gen_range(0.035..=0.050);
        let radius_bottom_m = if rng.gen_bool(0.4) {
            radius_top_m * rng.gen_range(0.78..=0.92)
        } else {
            radius_top_m
        };
        let mut mug = MugParams {
            height_m,
            radius_top_m,
            radius_bottom_m,
            wall_thickness_m: rng.gen_range(0.003..=0.006),
            bottom_thickness_m: rng.gen_range(0.004..=0.008),
            bottom_fillet_radius_m: rng.gen_range(0.003..=0.010),
            handle: None,
            bulge_m: 0.0,
        };
        if !rng.gen_bool(1.0 / 6.0) {
            mug.handle = Some(mug.sample_handle(rng));
        }
        mug
    }

    /// Samples a handle whose tube does not fold over itself (centre-line radius
    /// of curvature above its half-thickness), falling back to a small arc.
    fn sample_handle(&self, rng: &mut impl Rng) -> HandleParams {
        let shapes = [
            HandleShape::TorusArc,
            HandleShape::DShape,
            HandleShape::SquareIsh,
        ];
        for _ in 0..200 {
            let thickness_m: f64 = rng.gen_range(0.006..=0.012);
            let (lo, hi) = self.attachment_range(thickness_m);
            let span = (hi - lo) * rng.gen_range(0.55..=0.95);
            let lower_z_m = lo + (hi - lo - span) * rng.gen_range(0.0..=1.0);
            let handle = HandleParams {
                shape: shapes[rng.gen_range(0..shapes.len())],
                lower_z_m,
                upper_z_m: lower_z_m + span,
                width_m: rng.gen_range(0.008..=0.016),
                thickness_m,
                clearance_m: rng.gen_range(0.015..=0.030),
            };
            if self.handle_curvature_ok(&handle) {
                return handle;
            }
        }
        let thickness_m = 0.006;
        let (lo, hi) = self.attachment_range(thickness_m);
        HandleParams {
            shape: HandleShape::TorusArc,
            lower_z_m: lo,
            upper_z_m: hi,
            width_m: 0.010,
            thickness_m,
            clearance_m: 0.015,
        }
    }

    /// Lowest and highest attachment centre for a handle of `thickness` (m),
    /// clear of the bottom fillet and the rim by 4 mm.
    fn attachment_range(&self, thickness: f64) -> (f64, f64) {
        let lo = self.bottom_fillet_radius_m + thickness / 2.0 + 0.004;
        let hi = self.height_m - self.wall_thickness_m - thickness / 2.0 - 0.004;
        (lo, hi)
    }

    fn outer_radius(&self, z: f64) -> f64 {
        let u = z / self.height_m;
        let line = self.radius_bottom_m + (self.radius_top_m - self.radius_bottom_m) * u;
        if self.bulge_m == 0.0 {
            line
        } else {
            line + self.bulge_m * 4.0 * u.clamp(0.0, 1.0) * (1.0 - u.clamp(0.0, 1.0))
        }
    }

    /// Appends wall points `(radius(z), z)` from the profile's last point up or down
    /// to height `z`, in steps no longer than `step`: a straight line for a straight
    /// or tapered wall (as the training mugs were built), the curve for a barrel.
    fn push_wall(
        &self,
        profile: &mut Vec<[f64; 2]>,
        z: f64,
        step: f64,
        radius: impl Fn(f64) -> f64,
    ) {
        if self.bulge_m == 0.0 {
            push_line(profile, [radius(z), z], step);
            return;
        }
        let z0 = profile.last().expect("profile starts with a point")[1];
        let n = (((z - z0).abs() / step).ceil() as usize).max(1);
        for k in 1..=n {
            let zk = z0 + (z - z0) * k as f64 / n as f64;
            profile.push([radius(zk), zk]);
        }
    }

    fn handle_curvature_ok(&self, h: &HandleParams) -> bool {
        let (z0, z1) = (h.lower_z_m, h.upper_z_m);
        let path = self.handle_centre_line(
            h,
            Point3::new(self.outer_radius(z0), 0.0, z0),
            Point3::new(self.outer_radius(z1), 0.0, z1),
        );
        min_radius_of_curvature(&resample_by_arc_length(&path, 200)) > 0.65 * h.thickness_m
    }

    /// A dense centre line of the handle from `p0` (lower attachment) to `p1`,
    /// bulging along +x: a superellipse half-loop.
    fn handle_centre_line(
        &self,
        h: &HandleParams,
        p0: Point3<f64>,
        p1: Point3<f64>,
    ) -> Vec<Point3<f64>> {
        let p = h.shape.exponent();
        let (zm, hz) = ((p0.z + p1.z) / 2.0, (p1.z - p0.z) / 2.0);
        let reach =
            h.clearance_m + h.thickness_m / 2.0 + self.outer_radius(zm) - (p0.x + p1.x) / 2.0;
        (0..=2000)
            .map(|k| {
                let a = PI * k as f64 / 2000.0;
                let x =
                    p0.x + (p1.x - p0.x) * (1.0 - a.cos()) / 2.0 + reach * superellipse(a.sin(), p);
                Point3::new(x, 0.0, zm - hz * superellipse(a.cos(), p))
            })
            .collect()
    }

    /// The mug's mesh.
    pub fn build(&self) -> TriMesh {
        let h = self.height_m;
        let t = self.wall_thickness_m;
        let rb = self.bottom_fillet_radius_m;
        let tb = self.bottom_thickness_m;
        let z_rim = h - t / 2.0;
        let outer = |z: f64| self.outer_radius(z);
        let inner = |z: f64| self.outer_radius(z) - t;

        // Profile from the outer bottom's centre, out and up the outside, over the
        // rim, down the inside, to the inner bottom's centre.
        let mut profile = vec![[0.0, 0.0]];
        let r_flat = outer(rb) - rb;
        push_line(&mut profile, [r_flat, 0.0], 0.010);
        push_arc(&mut profile, [r_flat, rb], rb, -FRAC_PI_2, 0.0, 6);
        // Outer wall, with rows at the handle's attachments.
        let mut attachment_rings = Vec::new();
        if let Some(handle) = &self.handle {
            for zc in [handle.lower_z_m, handle.upper_z_m] {
                let z_lo = zc - handle.thickness_m / 2.0;
                self.push_wall(&mut profile, z_lo, 0.004, outer);
                attachment_rings.push(profile.len() - 2);
                let z_hi = zc + handle.thickness_m / 2.0;
                for k in 1..=ATTACHMENT_CELLS {
                    let z = z_lo + (z_hi - z_lo) * k as f64 / ATTACHMENT_CELLS as f64;
                    profile.push([outer(z), z]);
                }
            }
        }
        self.push_wall(&mut profile, z_rim, 0.004, outer);
        push_arc(
            &mut profile,
            [outer(z_rim) - t / 2.0, z_rim],
            t / 2.0,
            0.0,
            PI,
            8,
        );
        let rf = (0.6 * rb).clamp(0.002, 0.004);
        self.push_wall(&mut profile, tb + rf, 0.005, inner);
        let c_inner = [inner(tb + rf) - rf, tb + rf];
        push_arc(&mut profile, c_inner, rf, 0.0, -FRAC_PI_2, 4);
        push_line(&mut profile, [0.0, tb], 0.010);

        let mut builder = Builder::default();
        let Some(handle) = &self.handle else {
            lathe(&mut builder, &profile, &uniform_angles(RING_SEGMENTS), &[]);
            return builder.finish();
        };
        // Angles: the handle's width spans cells 0..ATTACHMENT_CELLS around +x.
        let zm = (handle.lower_z_m + handle.upper_z_m) / 2.0;
        let alpha = (handle.width_m / 2.0 / outer(zm)).asin();
        let rest = ((TAU - 2.0 * alpha) / (TAU / RING_SEGMENTS as f64)).round() as usize;
        let mut angles: Vec<f64> = (0..ATTACHMENT_CELLS)
            .map(|j| -alpha + 2.0 * alpha * j as f64 / ATTACHMENT_CELLS as f64)
            .collect();
        angles.extend((0..rest).map(|j| alpha + (TAU - 2.0 * alpha) * j as f64 / rest as f64));
        let holes: Vec<Hole> = attachment_rings
            .iter()
            .map(|&i0| Hole {
                i0,
                ni: ATTACHMENT_CELLS,
                j0: 0,
                nj: ATTACHMENT_CELLS,
            })
            .collect();
        let rings = lathe(&mut builder, &profile, &angles, &holes);
        let start = holes[0].boundary(&rings);
        let end = holes[1].mirrored_boundary(&rings, &holes[0]);
        let (p0, p1) = (centroid(&builder, &start), centroid(&builder, &end));
        let dense = self.handle_centre_line(handle, p0, p1);
        let length = polyline_length(&dense);
        let steps = ((length / 0.003).ceil() as usize).clamp(24, 96);
        let (half_w, half_t) = (handle.width_m / 2.0, handle.thickness_m / 2.0);
        let section = move |_t: f64, a: f64| [half_w * a.cos(), half_t * a.sin()];
        Sweep {
            path: resample_by_arc_length(&dense, steps),
            side: Vector3::y(),
            section: &section,
            blend_m: handle.thickness_m,
            ring_len: 0,
        }
        .build(&mut builder, TubeEnd::Ring(&start), TubeEnd::Ring(&end));
        builder.finish()
    }
}

fn centroid(builder: &Builder, ids: &[u32]) -> Point3<f64> {
    let sum: Vector3<f64> = ids.iter().map(|&i| builder.position(i).coords).sum();
    Point3::from(sum / ids.len() as f64)
}

fn polyline_length(points: &[Point3<f64>]) -> f64 {
    points.windows(2).map(|w| (w[1] - w[0]).norm()).sum()
}

/// Smallest radius of the circles through consecutive triples of `points`.
fn min_radius_of_curvature(points: &[Point3<f64>]) -> f64 {
    points
        .windows(3)
        .map(|w| {
            let (a, b, c) = (w[1] - w[0], w[2] - w[1], w[2] - w[0]);
            let twice_area = a.cross(&c).norm();
            if twice_area < 1e-15 {
                f64::INFINITY
            } else {
                a.norm() * b.norm() * c.norm() / (2.0 * twice_area)
            }
        })
        .fold(f64::INFINITY, f64::min)
}

impl BottleParams {
    /// Samples a bottle within the documented ranges.
    pub fn sample(rng: &mut impl Rng) -> BottleParams {
        let height_m: f64 = rng.gen_range(0.18..=0.32);
        let neck_length_m: f64 = rng.gen_range(0.02..=0.07);
        let shoulder_height_m = rng.gen_range(0.02..=(0.5 * height_m - neck_length_m).min(0.07));
        BottleParams {
            height_m,
            body_radius_m: rng.gen_range(0.030..=0.045),
            body_height_m: height_m - neck_length_m - shoulder_height_m,
            shoulder_height_m,
            neck_radius_m: rng.gen_range(0.010..=0.016),
            neck_length_m,
            lip_m: rng.gen_range(0.001..=0.003),
            bottom_fillet_radius_m: rng.gen_range(0.003..=0.008),
        }
    }

    /// The bottle's mesh.
    pub fn build(&self) -> TriMesh {
        let (r, rn, rb) = (
            self.body_radius_m,
            self.neck_radius_m,
            self.bottom_fillet_radius_m,
        );
        let z_body = self.body_height_m;
        let z_neck = z_body + self.shoulder_height_m;
        let lip_h = 0.006_f64.min(self.neck_length_m / 2.0);
        let z_lip = self.height_m - lip_h;
        let mut profile = vec![[0.0, 0.0]];
        push_line(&mut profile, [r - rb, 0.0], 0.010);
        push_arc(&mut profile, [r - rb, rb], rb, -FRAC_PI_2, 0.0, 6);
        push_line(&mut profile, [r, z_body], 0.008);
        for k in 1..=12 {
            let u = k as f64 / 12.0;
            let radius = rn + (r - rn) * (1.0 + (PI * u).cos()) / 2.0;
            profile.push([radius, z_body + self.shoulder_height_m * u]);
        }
        push_line(&mut profile, [rn, z_lip], 0.006);
        for k in 1..=6 {
            let u = k as f64 / 6.0;
            profile.push([rn + self.lip_m * (PI * u).sin(), z_lip + lip_h * u]);
        }
        push_line(&mut profile, [0.0, self.height_m], 0.006);
        debug_assert!(z_neck < z_lip);
        let mut builder = Builder::default();
        lathe(&mut builder, &profile, &uniform_angles(RING_SEGMENTS), &[]);
        builder.finish()
    }
}

/// A rounded-rectangle loop in section coordinates `(b, n)`, counter-clockwise
/// from +b toward +n, half sizes `half_b`, `half_n`, corner radius `radius`.
/// The +n side passes through `n_side_b` (decreasing b values, inside the
/// straight part); returns the loop and the index of `n_side_b[0]`.
fn rounded_rect_loop(
    half_b: f64,
    half_n: f64,
    radius: f64,
    n_side_b: &[f64],
) -> (Vec<[f64; 2]>, usize) {
    let (sb, sn) = (half_b - radius, half_n - radius);
    let step = 0.004;
    let mut points: Vec<[f64; 2]> = Vec::new();
    let side = |points: &mut Vec<[f64; 2]>, from: [f64; 2], to: [f64; 2]| {
        let length = ((to[0] - from[0]).powi(2) + (to[1] - from[1]).powi(2)).sqrt();
        let n = ((length / step).ceil() as usize).max(1);
        for k in 0..n {
            let f = k as f64 / n as f64;
            points.push([
                from[0] + (to[0] - from[0]) * f,
                from[1] + (to[1] - from[1]) * f,
            ]);
        }
    };
    let corner = |points: &mut Vec<[f64; 2]>, centre: [f64; 2], a0: f64| {
        for k in 0..4 {
            let a = a0 + FRAC_PI_2 * k as f64 / 4.0;
            points.push([centre[0] + radius * a.cos(), centre[1] + radius * a.sin()]);
        }
    };
    side(&mut points, [half_b, -sn], [half_b, sn]);
    corner(&mut points, [sb, sn], 0.0);
    // The +n side, through the requested b values.
    side(&mut points, [sb, half_n], [n_side_b[0], half_n]);
    let first = points.len();
    points.extend(n_side_b.iter().map(|&b| [b, half_n]));
    points.pop();
    side(
        &mut points,
        [n_side_b[n_side_b.len() - 1], half_n],
        [-sb, half_n],
    );
    corner(&mut points, [-sb, sn], FRAC_PI_2);
    side(&mut points, [-half_b, sn], [-half_b, -sn]);
    corner(&mut points, [-sb, -sn], PI);
    side(&mut points, [-sb, -half_n], [sb, -half_n]);
    corner(&mut points, [sb, -sn], 1.5 * PI);
    (points, first)
}

impl HammerParams {
    /// Samples a hammer within the documented ranges.
    pub fn sample(rng: &mut impl Rng) -> HammerParams {
        let head_section_m = rng.gen_range(0.022..=0.032);
        HammerParams {
            head_length_m: rng.gen_range(0.09..=0.14),
            head_section_m,
            handle_length_m: rng.gen_range(0.22..=0.34),
            handle_width_m: rng.gen_range(0.024..=0.034),
            handle_thickness_m: head_section_m * rng.gen_range(0.55..=0.70),
        }
    }

    /// The hammer's mesh.
    pub fn build(&self) -> TriMesh {
        let s = self.head_section_m;
        let (half_w, half_t) = (self.handle_width_m / 2.0, self.handle_thickness_m / 2.0);
        let n_side_b: Vec<f64> = (0..=ATTACHMENT_CELLS)
            .map(|k| half_t - 2.0 * half_t * k as f64 / ATTACHMENT_CELLS as f64)
            .collect();
        // Head section: b along z, n along x (so the loop runs counter-clockwise about +y).
        let (section, j0) = rounded_rect_loop(s / 2.0, s / 2.0, 0.12 * s, &n_side_b);
        // Stations along the head: (y, scale of b, scale of n); chamfered face at
        // -y, the handle's band around y = 0, a wedge-shaped peen toward +y.
        let l = self.head_length_m;
        let mut stations: Vec<(f64, f64, f64)> =
            vec![(-l / 2.0, 0.88, 0.88), (-l / 2.0 + 0.003, 1.0, 1.0)];
        let extend_to = |stations: &mut Vec<(f64, f64, f64)>, to: f64, cells: Option<usize>| {
            let from = stations[stations.len() - 1].0;
            let n = cells.unwrap_or((((to - from) / 0.006).ceil() as usize).max(1));
            for k in 1..=n {
                stations.push((from + (to - from) * k as f64 / n as f64, 1.0, 1.0));
            }
        };
        extend_to(&mut stations, -half_w, None);
        let band_ring = stations.len() - 1;
        extend_to(&mut stations, half_w, Some(ATTACHMENT_CELLS));
        let y_taper = (0.2 * l).max(half_w + 0.004);
        extend_to(&mut stations, y_taper, None);
        for k in 1..=6 {
            let u = k as f64 / 6.0;
            stations.push((
                y_taper + (l / 2.0 - y_taper) * u,
                1.0 - 0.1 * u,
                1.0 - 0.65 * smoothstep(u),
            ));
        }

        let centre_z = s / 2.0;
        let mut builder = Builder::default();
        let rings: Vec<Vec<u32>> = stations
            .iter()
            .map(|&(y, kb, kn)| {
                builder.ring(
                    section
                        .iter()
                        .map(|&[b, n]| Point3::new(n * kn, y, centre_z + b * kb)),
                )
            })
            .collect();
        let hole = Hole {
            i0: band_ring,
            ni: ATTACHMENT_CELLS,
            j0,
            nj: ATTACHMENT_CELLS,
        };
        let face = builder.vertex(Point3::new(0.0, -l / 2.0, centre_z));
        builder.cap_start(face, &rings[0]);
        builder.stitch(&rings, |i, j| hole.contains(i, j, section.len()));
        let peen = builder.vertex(Point3::new(0.0, l / 2.0, centre_z));
        builder.cap_end(&rings[rings.len() - 1], peen);

        // Handle: from the head's +x face along +x, sloping so the butt rests on the table.
        let start = hole.boundary(&rings);
        let p0 = centroid(&builder, &start);
        let grip = 1.12;
        let p1 = Point3::new(p0.x + self.handle_length_m, 0.0, half_t * grip);
        let steps = ((self.handle_length_m / 0.004).ceil() as usize).max(24);
        let path: Vec<Point3<f64>> = (0..=steps)
            .map(|k| p0 + (p1 - p0) * (k as f64 / steps as f64))
            .collect();
        let round_t = 1.0 - 0.8 * half_t * grip / self.handle_length_m;
        let section = move |t: f64, a: f64| {
            let swell = 1.0 + (grip - 1.0) * smoothstep(t / 0.6);
            let butt = if t > round_t {
                let u = (t - round_t) / (1.0 - round_t);
                (1.0 - u * u).max(0.0).sqrt()
            } else {
                1.0
            };
            let k = swell * butt;
            [
                k * half_w * superellipse(a.cos(), 2.5),
                k * half_t * superellipse(a.sin(), 2.5),
            ]
        };
        Sweep {
            path,
            side: Vector3::y(),
            section: &section,
            blend_m: self.handle_thickness_m,
            ring_len: 0,
        }
        .build(&mut builder, TubeEnd::Ring(&start), TubeEnd::Pole);
        place_on_table(builder.finish())
    }
}

/// A knife's cross-section at one station: centre, half sizes, superellipse
/// exponent, and how much thinner the -y side (the edge) is than the +y side.
#[derive(Debug, Clone, Copy)]
struct KnifeSection {
    centre_y: f64,
    centre_z: f64,
    half_y: f64,
    half_z: f64,
    exponent: f64,
    wedge: f64,
}

impl KnifeSection {
    fn lerp(&self, other: &KnifeSection, f: f64) -> KnifeSection {
        let mix = |a: f64, b: f64| a + (b - a) * f;
        KnifeSection {
            centre_y: mix(self.centre_y, other.centre_y),
            centre_z: mix(self.centre_z, other.centre_z),
            half_y: mix(self.half_y, other.half_y),
            half_z: mix(self.half_z, other.half_z),
            exponent: mix(self.exponent, other.exponent),
            wedge: mix(self.wedge, other.wedge),
        }
    }

    fn point(&self, a: f64) -> [f64; 2] {
        let taper = 1.0 - self.wedge + self.wedge * (1.0 + a.cos()) / 2.0;
        [
            self.centre_y + self.half_y * superellipse(a.cos(), self.exponent),
            self.centre_z + self.half_z * taper * superellipse(a.sin(), self.exponent),
        ]
    }
}

impl KnifeParams {
    /// Samples a knife within the documented ranges.
    pub fn sample(rng: &mut impl Rng) -> KnifeParams {
        KnifeParams {
            blade_length_m: rng.gen_range(0.08..=0.20),
            blade_width_m: rng.gen_range(0.018..=0.045),
            blade_thickness_m: rng.gen_range(0.0015..=0.003),
            bolster_length_m: rng.gen_range(0.008..=0.015),
            handle_length_m: rng.gen_range(0.09..=0.13),
            handle_width_m: rng.gen_range(0.018..=0.026),
            handle_thickness_m: rng.gen_range(0.012..=0.020),
        }
    }

    /// The cross-section at distance `x` (m) from the tip.
    fn section_at(&self, x: f64) -> KnifeSection {
        let lb = self.blade_length_m;
        let spine_y = self.handle_width_m / 2.0;
        let blade = |x: f64| {
            let curve = 0.35 * lb;
            let width = if x < curve {
                let u = x / curve;
                self.blade_width_m * (1.0 - (1.0 - u) * (1.0 - u))
            } else {
                self.blade_width_m
            };
            let half_z = self.blade_thickness_m / 2.0 * (0.6 + 0.4 * (x / lb).min(1.0));
            KnifeSection {
                centre_y: spine_y - width / 2.0,
                centre_z: half_z,
                half_y: width / 2.0,
                half_z,
                exponent: 2.0,
                wedge: 0.7,
            }
        };
        let handle = KnifeSection {
            centre_y: 0.0,
            centre_z: self.handle_thickness_m / 2.0,
            half_y: self.handle_width_m / 2.0,
            half_z: self.handle_thickness_m / 2.0,
            exponent: 3.0,
            wedge: 0.0,
        };
        let total = lb + self.bolster_length_m + self.handle_length_m;
        let butt_round = 0.4 * self.handle_thickness_m;
        if x <= lb {
            blade(x)
        } else if x <= lb + self.bolster_length_m {
            blade(lb).lerp(&handle, smoothstep((x - lb) / self.bolster_length_m))
        } else if x > total - butt_round {
            let u = ((x - (total - butt_round)) / butt_round).min(1.0);
            let k = (1.0 - u * u).max(0.0).sqrt();
            KnifeSection {
                half_y: handle.half_y * k,
                half_z: handle.half_z * k,
                ..handle
            }
        } else {
            handle
        }
    }

    /// The knife's mesh.
    pub fn build(&self) -> TriMesh {
        let lb = self.blade_length_m;
        let total = lb + self.bolster_length_m + self.handle_length_m;
        let butt_round = 0.4 * self.handle_thickness_m;
        // Stations: dense at the tip and the butt, 4 mm apart elsewhere.
        let mut xs: Vec<f64> = (0..12)
            .map(|k| 0.35 * lb * (k as f64 / 12.0).powi(2))
            .collect();
        let mut x = 0.35 * lb;
        let body_end = total - butt_round;
        let n = ((body_end - x) / 0.004).ceil() as usize;
        let step = (body_end - x) / n as f64;
        for _ in 0..n {
            xs.push(x);
            x += step;
        }
        xs.extend((0..=6).map(|k| body_end + butt_round * (FRAC_PI_2 * k as f64 / 6.0).sin()));
        let path: Vec<Point3<f64>> = xs.iter().map(|&x| Point3::new(x, 0.0, 0.0)).collect();
        let section = |t: f64, a: f64| self.section_at(t * total).point(a);
        let mut builder = Builder::default();
        Sweep {
            path,
            side: Vector3::y(),
            section: &section,
            blend_m: 0.0,
            ring_len: 32,
        }
        .build(&mut builder, TubeEnd::Pole, TubeEnd::Pole);
        place_on_table(builder.finish())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mesh::topology::{edge_report, signed_volume};

    #[test]
    fn category_names_round_trip() {
        for c in Category::ALL {
            assert_eq!(c.name().parse::<Category>(), Ok(c));
            assert_eq!(serde_json::to_string(&c).unwrap(), format!("\"{c}\""));
        }
        assert!("cup"
            .parse::<Category>()
            .unwrap_err()
            .to_string()
            .contains("cup"));
    }

    #[test]
    fn instance_seeds_differ() {
        let seeds: std::collections::HashSet<u64> = (0..1000)
            .flat_map(|i| [instance_seed(1, i), instance_seed(2, i)])
            .collect();
        assert_eq!(seeds.len(), 2000);
    }

    #[test]
    fn every_handle_shape_is_closed_and_outward() {
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        let mug = MugParams::sample(&mut rng);
        for shape in [
            HandleShape::TorusArc,
            HandleShape::DShape,
            HandleShape::SquareIsh,
        ] {
            let (lo, hi) = mug.attachment_range(0.008);
            let handle = HandleParams {
                shape,
                lower_z_m: lo,
                upper_z_m: hi,
                width_m: 0.012,
                thickness_m: 0.008,
                clearance_m: 0.02,
            };
            let mesh = MugParams {
                handle: Some(handle),
                ..mug.clone()
            }
            .build();
            let report = edge_report(&mesh);
            assert!(report.is_watertight(), "{shape:?}: {report:?}");
            assert!(signed_volume(&mesh) > 0.0);
        }
    }

    #[test]
    fn a_folding_handle_is_rejected_by_the_curvature_check() {
        // A thick, short, far-reaching square handle folds over itself at its
        // corners: the sampler's check refuses it, and the mesh shows why.
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        let mut mug = MugParams {
            height_m: 0.07,
            ..MugParams::sample(&mut rng)
        };
        let (lo, _) = mug.attachment_range(0.012);
        let folding = HandleParams {
            shape: HandleShape::SquareIsh,
            lower_z_m: lo,
            upper_z_m: lo + 0.02,
            width_m: 0.012,
            thickness_m: 0.012,
            clearance_m: 0.03,
        };
        assert!(!mug.handle_curvature_ok(&folding));
        mug.handle = Some(folding);
        let mesh = mug.build();
        assert!(crate::mesh::topology::is_watertight(&mesh));
        assert!(crate::mesh::topology::self_intersections(&mesh).unwrap() > 0);
    }

    #[test]
    fn params_serialise_with_their_category() {
        let (_, params) = generate(Category::Knife, 4);
        let text = serde_json::to_string(&params).unwrap();
        assert!(text.starts_with("{\"category\":\"knife\""), "{text}");
        let back: Params = serde_json::from_str(&text).unwrap();
        // serde_json's default float parsing may be one ulp off.
        let (Params::Knife(a), Params::Knife(b)) = (&params, &back) else {
            panic!("category changed: {back:?}");
        };
        for (x, y) in [
            (a.blade_length_m, b.blade_length_m),
            (a.handle_thickness_m, b.handle_thickness_m),
        ] {
            assert!((x - y).abs() <= 1e-15 * x.abs(), "{x} vs {y}");
        }
    }
}
