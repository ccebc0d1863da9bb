//! The held-apart family: novel objects of shapes the category databases never saw
//! (issue 20, "a cell as hard as a lab"). The paper's test mugs came from a shop,
//! not from its training set's generator; these instances stand in for them.
//!
//! - Mugs: squat, tall, conical (strongly tapered either way), barrel-shaped
//!   (bulging wall), square-handled (a large square handle) and handle-less wide
//!   bowls.
//! - Bottles: a long sloping shoulder, an abrupt shoulder, a wide neck, a long neck.
//!
//! Every instance has at least one parameter outside the training sampler's range
//! ([`MugParams::within_training_ranges`], [`BottleParams::within_training_ranges`]);
//! the training ranges themselves are unchanged. Hammers and knives have no
//! held-apart family: [`generate_in`] gives them the training generator.

use super::{
    generate, BottleParams, Category, HandleParams, HandleShape, MugParams, Params, TriMesh,
};
use rand::Rng;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

/// Where novel instances come from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Family {
    /// The training generator and ranges (fresh seeds of the databases' family).
    Training,
    /// The held-apart shapes (mugs and bottles; hammers and knives as training):
    /// the default of `cell demo`, `cell campaign` and `cell eval novel`.
    HeldApart,
}

impl Family {
    /// `training` or `held-apart`.
    pub fn name(self) -> &'static str {
        match self {
            Family::Training => "training",
            Family::HeldApart => "held-apart",
        }
    }
}

/// The shape kind of a held-apart instance.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Kind {
    /// A low, wide mug.
    SquatMug,
    /// A tall, narrow mug.
    TallMug,
    /// A mug whose wall tapers far more than any training mug (either way).
    ConicalMug,
    /// A mug whose wall bulges at mid-height.
    BarrelMug,
    /// A mug with a large, square handle.
    SquareHandledMug,
    /// A wide mug without a handle.
    HandlelessMug,
    /// A bottle with a long, sloping shoulder.
    SlopingShoulderBottle,
    /// A bottle whose shoulder steps abruptly to the neck.
    AbruptShoulderBottle,
    /// A bottle with a wide neck.
    WideNeckBottle,
    /// A bottle with a long neck.
    LongNeckBottle,
}

impl Kind {
    /// The mug kinds.
    pub const MUGS: [Kind; 6] = [
        Kind::SquatMug,
        Kind::TallMug,
        Kind::ConicalMug,
        Kind::BarrelMug,
        Kind::SquareHandledMug,
        Kind::HandlelessMug,
    ];
    /// The bottle kinds.
    pub const BOTTLES: [Kind; 4] = [
        Kind::SlopingShoulderBottle,
        Kind::AbruptShoulderBottle,
        Kind::WideNeckBottle,
        Kind::LongNeckBottle,
    ];

    /// The kebab-case name (`squat-mug`, `long-neck-bottle`, ...).
    pub fn name(self) -> &'static str {
        match self {
            Kind::SquatMug => "squat-mug",
            Kind::TallMug => "tall-mug",
            Kind::ConicalMug => "conical-mug",
            Kind::BarrelMug => "barrel-mug",
            Kind::SquareHandledMug => "square-handled-mug",
            Kind::HandlelessMug => "handleless-mug",
            Kind::SlopingShoulderBottle => "sloping-shoulder-bottle",
            Kind::AbruptShoulderBottle => "abrupt-shoulder-bottle",
            Kind::WideNeckBottle => "wide-neck-bottle",
            Kind::LongNeckBottle => "long-neck-bottle",
        }
    }

    /// The kinds of `category` (empty for hammers and knives).
    pub fn of(category: Category) -> &'static [Kind] {
        match category {
            Category::Mug => &Kind::MUGS,
            Category::Bottle => &Kind::BOTTLES,
            Category::Hammer | Category::Knife => &[],
        }
    }

    /// Samples an instance of this kind.
    pub fn sample(self, rng: &mut impl Rng) -> Params {
        match self {
            Kind::SquatMug => {
                let r = rng.gen_range(0.046..=0.058);
                Params::Mug(mug(rng.gen_range(0.050..=0.064), r, r, rng))
            }
            Kind::TallMug => {
                let r = rng.gen_range(0.034..=0.042);
                Params::Mug(mug(rng.gen_range(0.130..=0.160), r, r, rng))
            }
            Kind::ConicalMug => {
                let wide = rng.gen_range(0.042..=0.052);
                let narrow = wide * rng.gen_range(0.55..=0.72);
                let (top, bottom) = if rng.gen_bool(0.5) {
                    (wide, narrow)
                } else {
                    (narrow, wide)
                };
                Params::Mug(mug(rng.gen_range(0.080..=0.110), top, bottom, rng))
            }
            Kind::BarrelMug => {
                let r = rng.gen_range(0.034..=0.042);
                let mut m = mug(rng.gen_range(0.085..=0.115), r, r, rng);
                m.bulge_m = rng.gen_range(0.006..=0.012);
                m.handle = Some(m.sample_handle(rng));
                Params::Mug(m)
            }
            Kind::SquareHandledMug => {
                let r = rng.gen_range(0.036..=0.046);
                let mut m = mug(rng.gen_range(0.085..=0.115), r, r, rng);
                m.handle = Some(square_handle(&m, rng));
                Params::Mug(m)
            }
            Kind::HandlelessMug => {
                let r = rng.gen_range(0.052..=0.058);
                let mut m = mug(rng.gen_range(0.070..=0.100), r, r * 0.9, rng);
                m.handle = None;
                Params::Mug(m)
            }
            Kind::SlopingShoulderBottle => {
                let h = rng.gen_range(0.24..=0.30);
                bottle(
                    h,
                    rng.gen_range(0.08..=0.10),
                    rng.gen_range(0.012..=0.015),
                    rng.gen_range(0.03..=0.05),
                    rng,
                )
            }
            Kind::AbruptShoulderBottle => {
                let h = rng.gen_range(0.20..=0.28);
                bottle(
                    h,
                    rng.gen_range(0.008..=0.015),
                    rng.gen_range(0.011..=0.015),
                    rng.gen_range(0.03..=0.06),
                    rng,
                )
            }
            Kind::WideNeckBottle => {
                let h = rng.gen_range(0.20..=0.28);
                bottle(
                    h,
                    rng.gen_range(0.02..=0.04),
                    rng.gen_range(0.019..=0.024),
                    rng.gen_range(0.03..=0.05),
                    rng,
                )
            }
            Kind::LongNeckBottle => {
                let h = rng.gen_range(0.26..=0.32);
                bottle(
                    h,
                    rng.gen_range(0.03..=0.05),
                    rng.gen_range(0.011..=0.014),
                    rng.gen_range(0.085..=0.11),
                    rng,
                )
            }
        }
    }
}

/// A mug with the training ranges' wall, bottom and fillet and the given size; a
/// training-range handle (most kinds set their own afterwards).
fn mug(height_m: f64, radius_top_m: f64, radius_bottom_m: f64, rng: &mut impl Rng) -> MugParams {
    let mut m = MugParams {
        height_m,
        radius_top_m,
        radius_bottom_m,
        wall_thickness_m: rng.gen_range(0.003..=0.006),
        bottom_thickness_m: rng.gen_range(0.004..=0.008),
        bottom_fillet_radius_m: rng.gen_range(0.003..=0.008),
        handle: None,
        bulge_m: 0.0,
    };
    m.handle = Some(m.sample_handle(rng));
    m
}

/// A large square handle: wider and farther out than any training handle.
fn square_handle(m: &MugParams, rng: &mut impl Rng) -> HandleParams {
    for _ in 0..200 {
        let thickness_m: f64 = rng.gen_range(0.007..=0.010);
        let (lo, hi) = m.attachment_range(thickness_m);
        let span = (hi - lo) * rng.gen_range(0.75..=0.95);
        let lower_z_m = lo + (hi - lo - span) * rng.gen_range(0.0..=1.0);
        let handle = HandleParams {
            shape: HandleShape::SquareIsh,
            lower_z_m,
            upper_z_m: lower_z_m + span,
            width_m: rng.gen_range(0.018..=0.024),
            thickness_m,
            clearance_m: rng.gen_range(0.032..=0.040),
        };
        if m.handle_curvature_ok(&handle) {
            return handle;
        }
    }
    let (lo, hi) = m.attachment_range(0.007);
    HandleParams {
        shape: HandleShape::SquareIsh,
        lower_z_m: lo,
        upper_z_m: hi,
        width_m: 0.020,
        thickness_m: 0.007,
        clearance_m: 0.032,
    }
}

/// A bottle of total height `height_m` with the given shoulder, neck radius and
/// neck length; body radius, lip and fillet from the training ranges.
fn bottle(
    height_m: f64,
    shoulder_height_m: f64,
    neck_radius_m: f64,
    neck_length_m: f64,
    rng: &mut impl Rng,
) -> Params {
    Params::Bottle(BottleParams {
        height_m,
        body_radius_m: rng.gen_range(0.030..=0.045),
        body_height_m: height_m - neck_length_m - shoulder_height_m,
        shoulder_height_m,
        neck_radius_m,
        neck_length_m,
        lip_m: rng.gen_range(0.001..=0.003),
        bottom_fillet_radius_m: rng.gen_range(0.003..=0.008),
    })
}

/// The kind of the held-apart instance of `category` from `seed` (`None` for
/// hammers and knives), without building it.
pub fn held_apart_kind(category: Category, seed: u64) -> Option<Kind> {
    let kinds = Kind::of(category);
    if kinds.is_empty() {
        return None;
    }
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    Some(kinds[rng.gen_range(0..kinds.len())])
}

/// A held-apart instance of `category` from `seed`: mesh, parameters and kind
/// (`None` for hammers and knives, which come from the training generator).
pub fn generate_held_apart(category: Category, seed: u64) -> (TriMesh, Params, Option<Kind>) {
    let kinds = Kind::of(category);
    if kinds.is_empty() {
        let (mesh, params) = generate(category, seed);
        return (mesh, params, None);
    }
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let kind = kinds[rng.gen_range(0..kinds.len())];
    let params = kind.sample(&mut rng);
    (params.build(), params, Some(kind))
}

/// The seed of held-apart instance `index` of the set `set_seed`: the first seed of
/// the set's stream whose kind is the `index`-th in turn, so that any run of
/// consecutive instances covers the kinds evenly (10 mugs: every kind once or
/// twice).
pub fn held_apart_seed(category: Category, set_seed: u64, index: u64) -> u64 {
    let kinds = Kind::of(category);
    let first = super::instance_seed(set_seed, index);
    if kinds.is_empty() {
        return first;
    }
    let want = kinds[(index % kinds.len() as u64) as usize];
    (0..)
        .map(|k| super::instance_seed(set_seed, index + k * 1_000_003))
        .find(|&s| held_apart_kind(category, s) == Some(want))
        .unwrap_or(first)
}

/// Held-apart instance `index` of the set `set_seed`, as the novel-object
/// experiments draw it (`cell eval novel`, campaigns with `--family held-apart`):
/// its name (`squat-mug-1-0`: kind, set, index) and generator seed.
pub fn held_apart_instance(category: Category, set_seed: u64, index: u64) -> (String, u64) {
    let seed = held_apart_seed(category, set_seed ^ 0x6865_6c64_6170_6172, index);
    let name = match held_apart_kind(category, seed) {
        Some(k) => format!("{}-{set_seed}-{index}", k.name()),
        None => format!("{category}-novel-{set_seed}-{index}"),
    };
    (name, seed)
}

/// An instance of `category` from `seed` in `family`: mesh and parameters.
pub fn generate_in(family: Family, category: Category, seed: u64) -> (TriMesh, Params) {
    match family {
        Family::Training => generate(category, seed),
        Family::HeldApart => {
            let (mesh, params, _) = generate_held_apart(category, seed);
            (mesh, params)
        }
    }
}

fn within(x: f64, lo: f64, hi: f64) -> bool {
    // The samplers' bounds are inclusive; derived values may be off by rounding.
    x >= lo - 1e-12 && x <= hi + 1e-12
}

impl MugParams {
    /// Whether every parameter lies within the training sampler's range
    /// ([`MugParams::sample`]).
    pub fn within_training_ranges(&self) -> bool {
        let taper = self.radius_bottom_m / self.radius_top_m;
        let handle_ok = self.handle.as_ref().is_none_or(|h| {
            within(h.width_m, 0.008, 0.016)
                && within(h.thickness_m, 0.006, 0.012)
                && within(h.clearance_m, 0.015, 0.030)
        });
        within(self.height_m, 0.070, 0.120)
            && within(self.radius_top_m, 0.035, 0.050)
            && (taper == 1.0 || within(taper, 0.78, 0.92))
            && within(self.wall_thickness_m, 0.003, 0.006)
            && within(self.bottom_thickness_m, 0.004, 0.008)
            && within(self.bottom_fillet_radius_m, 0.003, 0.010)
            && self.bulge_m == 0.0
            && handle_ok
    }
}

impl BottleParams {
    /// Whether every parameter lies within the training sampler's range
    /// ([`BottleParams::sample`]).
    pub fn within_training_ranges(&self) -> bool {
        within(self.height_m, 0.18, 0.32)
            && within(self.body_radius_m, 0.030, 0.045)
            && within(self.shoulder_height_m, 0.02, 0.07)
            && within(self.neck_radius_m, 0.010, 0.016)
            && within(self.neck_length_m, 0.02, 0.07)
            && within(self.lip_m, 0.001, 0.003)
            && within(self.bottom_fillet_radius_m, 0.003, 0.008)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mesh::procedural::instance_seed;
    use crate::mesh::topology::{edge_report, signed_volume};

    fn outside_training(params: &Params) -> bool {
        match params {
            Params::Mug(m) => !m.within_training_ranges(),
            Params::Bottle(b) => !b.within_training_ranges(),
            _ => false,
        }
    }

    #[test]
    fn training_instances_lie_within_their_ranges() {
        for i in 0..200 {
            for category in [Category::Mug, Category::Bottle] {
                let (_, params) = generate(category, instance_seed(11, i));
                assert!(!outside_training(&params), "{params:?}");
            }
        }
    }

    #[test]
    fn every_held_apart_kind_is_watertight_outward_and_outside_the_training_ranges() {
        for category in [Category::Mug, Category::Bottle] {
            for &kind in Kind::of(category) {
                for i in 0..4 {
                    let mut rng = ChaCha8Rng::seed_from_u64(instance_seed(5, i));
                    let params = kind.sample(&mut rng);
                    assert_eq!(params.category(), category);
                    assert!(outside_training(&params), "{kind:?}: {params:?}");
                    let mesh = params.build();
                    let report = edge_report(&mesh);
                    assert!(report.is_watertight(), "{kind:?} #{i}: {report:?}");
                    assert!(signed_volume(&mesh) > 0.0, "{kind:?} #{i}");
                }
            }
        }
    }

    #[test]
    fn held_apart_sets_cover_every_kind_and_leave_tools_alone() {
        let kinds: std::collections::HashSet<Kind> = (0..60)
            .filter_map(|i| generate_held_apart(Category::Mug, instance_seed(2, i)).2)
            .collect();
        assert_eq!(kinds.len(), Kind::MUGS.len(), "{kinds:?}");
        let (a, _, kind) = generate_held_apart(Category::Hammer, 9);
        assert_eq!(kind, None);
        assert_eq!(a, generate(Category::Hammer, 9).0);
        let (b, _) = generate_in(Family::Training, Category::Mug, 9);
        assert_eq!(b, generate(Category::Mug, 9).0);
    }

    #[test]
    fn consecutive_instances_cover_the_kinds_evenly() {
        let kinds: Vec<Option<Kind>> = (0..12)
            .map(|i| held_apart_kind(Category::Mug, held_apart_seed(Category::Mug, 4, i)))
            .collect();
        for (i, k) in kinds.iter().enumerate() {
            assert_eq!(*k, Some(Kind::MUGS[i % 6]), "instance {i}");
        }
        let bottles: std::collections::HashSet<_> = (0..4)
            .map(|i| {
                generate_held_apart(Category::Bottle, held_apart_seed(Category::Bottle, 4, i)).2
            })
            .collect();
        assert_eq!(bottles.len(), 4);
    }

    #[test]
    fn a_barrel_bulges_beyond_its_rim_and_base() {
        let mut rng = ChaCha8Rng::seed_from_u64(4);
        let Params::Mug(m) = Kind::BarrelMug.sample(&mut rng) else {
            panic!("a barrel is a mug");
        };
        let mid = m.outer_radius(m.height_m / 2.0);
        assert!((mid - m.radius_top_m - m.bulge_m).abs() < 1e-12);
        let mesh = m.build();
        // The widest body point (the handle lies along +x: look along -x).
        let widest = mesh
            .vertices
            .iter()
            .filter(|v| v.x < 0.0)
            .map(|v| (v.x * v.x + v.y * v.y).sqrt())
            .fold(0.0, f64::max);
        assert!(widest > m.radius_top_m + 0.8 * m.bulge_m, "{widest} {m:?}");
    }
}
