//! Exact Ferrari–Canny epsilon without building the whole hull.
//!
//! Epsilon is the distance from the origin to the nearest facet hyperplane of the convex
//! hull of the wrenches when the origin is strictly inside. This module finds it by
//! growing a hull best-first toward the origin (the idea of EPA, the expanding polytope
//! algorithm, in 6-D, started from any full-dimensional simplex of the points):
//!
//! 1. Start with a simplex of 7 points chosen greedily for volume, and keep a point
//!    strictly inside it (its vertex mean) to orient every facet normal outward.
//! 2. Pop the facet whose hyperplane is nearest the origin (smallest signed offset
//!    `<n, v>`; negative when the origin is beyond it) and evaluate the support function
//!    `h(n) = max_i <n, w_i>` in its normal direction.
//!    - `h(n) <= tol`: every wrench lies in the half-space `<n, x> <= 0`: the origin is
//!      not strictly inside; epsilon is 0.
//!    - `h(n) <= offset + tol`: the facet's hyperplane supports the whole hull. Every
//!      other facet of the partial hull is farther, so the ball of radius `offset` lies
//!      in the partial hull, hence in the hull, and the hyperplane bounds it: epsilon is
//!      `offset`, exact up to `tol` (0 unless it exceeds `tol`).
//!    - otherwise the support point lies beyond the facet: add it as in Quickhull
//!      (remove the facets it sees, cone the horizon to it) and repeat.
//!
//! Every step adds a new hull vertex, so it ends after at most `n` steps; usually only
//! the facets near the origin are ever built (on 3-6 contact grasps with 8-edge cones:
//! about 8 points added and 300 facets made, against about 1,400 facets in the full hull).
//! A new facet's hyperplane contains a horizon ridge shared by the two facets on either
//! side of it, so its normal is a combination of theirs (O(d) instead of an
//! orthogonalisation); a popped facet's hyperplane is recomputed from its vertices
//! before any decision is taken on it. Numerical trouble (a facet without a
//! well-defined hyperplane, a horizon that does not close) is reported, never hidden, so
//! the caller can fall back to qhull.

use super::gws::spanning_simplex;
use super::wrench::Wrench;
use std::cmp::Ordering;
use std::collections::BinaryHeap;

const DIM: usize = 6;

/// Tolerance relative to the largest wrench norm: points within it of a hyperplane
/// count as on it, and an epsilon not above it counts as 0.
pub const REL_TOL: f64 = 1e-9;

/// Where the origin lies relative to the convex hull of a wrench set.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum OriginDepth {
    /// The wrenches span fewer than 6 dimensions: the hull has no interior.
    Degenerate,
    /// The origin is outside or on the boundary: no force closure.
    NotInside,
    /// The origin is strictly inside.
    Inside {
        /// Distance from the origin to the nearest facet hyperplane.
        epsilon: f64,
        /// Outward unit normal of that facet: `<normal, w> <= epsilon` for every wrench.
        normal: Wrench,
    },
}

/// The expansion lost numerical consistency; the reason says where.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("best-first hull expansion failed: {reason}")]
pub struct HullFailure {
    /// What went wrong.
    pub reason: &'static str,
}

struct Facet {
    verts: [u32; DIM],
    /// `neighbors[k]` shares every vertex but `verts[k]`.
    neighbors: [u32; DIM],
    normal: Wrench,
    offset: f64,
    alive: bool,
}

/// A facet in the min-queue by offset.
struct Queued {
    offset: f64,
    facet: u32,
}

impl PartialEq for Queued {
    fn eq(&self, other: &Self) -> bool {
        self.cmp(other) == Ordering::Equal
    }
}
impl Eq for Queued {}
impl PartialOrd for Queued {
    fn partial_cmp(&self, other: &Self) -> Option<Ordering> {
        Some(self.cmp(other))
    }
}
impl Ord for Queued {
    fn cmp(&self, other: &Self) -> Ordering {
        // Reversed: BinaryHeap is a max-heap, we want the smallest offset first.
        other
            .offset
            .total_cmp(&self.offset)
            .then(other.facet.cmp(&self.facet))
    }
}

/// Where the origin lies relative to the hull of `points`, and epsilon when inside.
pub fn origin_depth(points: &[Wrench]) -> Result<OriginDepth, HullFailure> {
    let scale = points.iter().map(|p| p.norm()).fold(0.0, f64::max);
    let tol = REL_TOL * scale;
    let Some(simplex) = spanning_simplex(points, tol) else {
        return Ok(OriginDepth::Degenerate);
    };
    let mut hull = Hull::new(points, &simplex, tol)?;
    // Each step adds a point that is not yet a vertex, so there are at most n - 7.
    let mut added = 0;
    loop {
        let Some(Queued { facet, .. }) = hull.queue.pop() else {
            return Err(HullFailure {
                reason: "no facet left",
            });
        };
        if !hull.facets[facet as usize].alive {
            continue;
        }
        // New facets' planes come from a cheap update (see `add_point`); decide only on
        // a plane recomputed from the vertices.
        let (normal, offset) =
            hull.hyperplane(&hull.facets[facet as usize].verts)
                .ok_or(HullFailure {
                    reason: "facet without a well-defined hyperplane",
                })?;
        let f = &mut hull.facets[facet as usize];
        let drift = (offset - f.offset).abs();
        f.normal = normal;
        f.offset = offset;
        if drift > tol {
            hull.queue.push(Queued { offset, facet });
            continue;
        }
        let (best, h) = support(points, &normal);
        if h <= tol {
            return Ok(OriginDepth::NotInside);
        }
        if h <= offset + tol {
            return Ok(if offset > tol {
                OriginDepth::Inside {
                    epsilon: offset,
                    normal,
                }
            } else {
                OriginDepth::NotInside
            });
        }
        added += 1;
        if added > points.len() {
            return Err(HullFailure {
                reason: "more steps than points",
            });
        }
        hull.add_point(best, facet)?;
    }
}

/// The index and value of `max_i <u, w_i>`.
fn support(points: &[Wrench], u: &Wrench) -> (usize, f64) {
    let mut best = (0, f64::NEG_INFINITY);
    for (i, p) in points.iter().enumerate() {
        let v = u.dot(p);
        if v > best.1 {
            best = (i, v);
        }
    }
    best
}

struct Hull<'a> {
    points: &'a [Wrench],
    interior: Wrench,
    tol: f64,
    facets: Vec<Facet>,
    queue: BinaryHeap<Queued>,
    visible: Vec<bool>,
    /// Scratch buffers of `add_point`, kept to avoid reallocating.
    seen: Vec<u32>,
    ridges: Vec<Ridge>,
    table: Vec<u32>,
}

impl<'a> Hull<'a> {
    fn new(
        points: &'a [Wrench],
        simplex: &[usize; DIM + 1],
        tol: f64,
    ) -> Result<Self, HullFailure> {
        let interior = simplex.iter().map(|&i| points[i]).sum::<Wrench>() / (DIM + 1) as f64;
        let mut hull = Hull {
            points,
            interior,
            tol,
            facets: Vec::with_capacity(256),
            queue: BinaryHeap::with_capacity(256),
            visible: Vec::with_capacity(256),
            seen: Vec::new(),
            ridges: Vec::new(),
            table: Vec::new(),
        };
        // Facet i omits simplex[i]; across its vertex simplex[j] lies facet j. Every
        // facet keeps its vertices sorted (ridges of new facets are then sorted keys).
        let mut simplex = *simplex;
        simplex.sort_unstable();
        for omit in 0..=DIM {
            let mut verts = [0u32; DIM];
            let mut neighbors = [0u32; DIM];
            let mut k = 0;
            for (j, &v) in simplex.iter().enumerate() {
                if j != omit {
                    verts[k] = v as u32;
                    neighbors[k] = j as u32;
                    k += 1;
                }
            }
            let plane = hull.hyperplane(&verts).ok_or(HullFailure {
                reason: "initial simplex facet without a well-defined hyperplane",
            })?;
            hull.push_facet(verts, neighbors, plane);
        }
        Ok(hull)
    }

    fn push_facet(
        &mut self,
        verts: [u32; DIM],
        neighbors: [u32; DIM],
        plane: (Wrench, f64),
    ) -> u32 {
        let (normal, offset) = plane;
        let id = self.facets.len() as u32;
        self.facets.push(Facet {
            verts,
            neighbors,
            normal,
            offset,
            alive: true,
        });
        self.visible.push(false);
        self.queue.push(Queued { offset, facet: id });
        id
    }

    /// The outward unit normal and offset of the hyperplane through `verts`, oriented
    /// away from the interior point; None when the vertices are (nearly) dependent.
    fn hyperplane(&self, verts: &[u32; DIM]) -> Option<(Wrench, f64)> {
        let tiny = self.tol * 1e-3;
        let v0 = self.points[verts[0] as usize];
        let mut basis = [Wrench::zeros(); DIM - 1];
        for k in 1..DIM {
            let mut e = self.points[verts[k] as usize] - v0;
            // Modified Gram-Schmidt, twice for orthogonality.
            for _ in 0..2 {
                for q in &basis[..k - 1] {
                    e -= q * q.dot(&e);
                }
            }
            let len = e.norm();
            if len <= tiny {
                return None;
            }
            basis[k - 1] = e / len;
        }
        let mut r = self.interior - v0;
        for _ in 0..2 {
            for q in &basis {
                r -= q * q.dot(&r);
            }
        }
        let len = r.norm();
        if len <= tiny {
            return None;
        }
        let normal = -r / len;
        Some((normal, normal.dot(&v0)))
    }

    /// Adds point `index`, seen by facet `start`: removes the facets it sees and
    /// connects the horizon to it.
    fn add_point(&mut self, index: usize, start: u32) -> Result<(), HullFailure> {
        let p = self.points[index];
        let mut seen = std::mem::take(&mut self.seen);
        let mut ridges = std::mem::take(&mut self.ridges);
        seen.clear();
        ridges.clear();
        seen.push(start);
        self.visible[start as usize] = true;
        let mut next = 0;
        while next < seen.len() {
            let g = seen[next] as usize;
            next += 1;
            for k in 0..DIM {
                let nb = self.facets[g].neighbors[k] as usize;
                if !self.visible[nb] {
                    let f = &self.facets[nb];
                    if f.normal.dot(&p) - f.offset > self.tol {
                        self.visible[nb] = true;
                        seen.push(nb as u32);
                    }
                }
            }
        }
        // Cone every horizon ridge (between a seen and an unseen facet) to the point.
        let first_new = self.facets.len();
        for &g in &seen {
            for k in 0..DIM {
                let nb = self.facets[g as usize].neighbors[k];
                if self.visible[nb as usize] {
                    continue;
                }
                // Vertices stay sorted: the ridge (g's vertices but k) with the point
                // inserted in order; across the point's slot lies nb.
                let gv = self.facets[g as usize].verts;
                let mut verts = [0u32; DIM];
                let mut neighbors = [u32::MAX; DIM];
                let mut m = 0;
                let mut slot = DIM;
                for (i, &v) in gv.iter().enumerate() {
                    if i == k {
                        continue;
                    }
                    if slot == DIM && v > index as u32 {
                        slot = m;
                        m += 1;
                    }
                    verts[m] = v;
                    m += 1;
                }
                if slot == DIM {
                    slot = DIM - 1;
                }
                verts[slot] = index as u32;
                neighbors[slot] = nb;
                // The new hyperplane contains the horizon ridge, as do those of g and nb,
                // so its normal lies in the pencil spanned by theirs: the combination
                // that also passes through p (distance d_g > tol above g, d_nb <= tol
                // above nb). When p is (nearly) on nb's hyperplane the combination cancels
                // if g and nb are (nearly) coplanar: then use the vertices.
                let (fg, fnb) = (&self.facets[g as usize], &self.facets[nb as usize]);
                let d_g = fg.normal.dot(&p) - fg.offset;
                let d_nb = fnb.normal.dot(&p) - fnb.offset;
                let plane = if d_nb < -self.tol {
                    let normal = fg.normal * -d_nb + fnb.normal * d_g;
                    let offset = fg.offset * -d_nb + fnb.offset * d_g;
                    let len = normal.norm();
                    (normal / len, offset / len)
                } else {
                    self.hyperplane(&verts).ok_or(HullFailure {
                        reason: "new facet without a well-defined hyperplane",
                    })?
                };
                let id = self.push_facet(verts, neighbors, plane);
                let back = self.facets[nb as usize]
                    .neighbors
                    .iter()
                    .position(|&x| x == g)
                    .ok_or(HullFailure {
                        reason: "horizon neighbour does not point back",
                    })?;
                self.facets[nb as usize].neighbors[back] = id;
                // Each other ridge of the new facet (its vertices but one, the point
                // among them) is shared with exactly one other new facet.
                for omit in (0..DIM).filter(|&o| o != slot) {
                    ridges.push((ridge_key(&verts, omit), id, omit as u8));
                }
            }
        }
        for &g in &seen {
            self.facets[g as usize].alive = false;
            self.visible[g as usize] = false;
        }
        let result = self.link_new_facets(&ridges, first_new);
        self.seen = seen;
        self.ridges = ridges;
        result
    }

    /// Pairs the new facets across their shared ridges with an open-addressing table.
    fn link_new_facets(&mut self, ridges: &[Ridge], first_new: usize) -> Result<(), HullFailure> {
        const EMPTY: u32 = u32::MAX;
        const MATCHED: u32 = u32::MAX - 1;
        let size = (2 * ridges.len()).next_power_of_two().max(16);
        let mask = size - 1;
        self.table.clear();
        self.table.resize(size, EMPTY);
        for (e, &(key, facet, slot)) in ridges.iter().enumerate() {
            let mut h = hash_key(&key) & mask;
            loop {
                match self.table[h] {
                    EMPTY => {
                        self.table[h] = e as u32;
                        break;
                    }
                    MATCHED => {}
                    other => {
                        let (okey, ofacet, oslot) = ridges[other as usize];
                        if okey == key {
                            self.facets[facet as usize].neighbors[slot as usize] = ofacet;
                            self.facets[ofacet as usize].neighbors[oslot as usize] = facet;
                            self.table[h] = MATCHED;
                            break;
                        }
                    }
                }
                h = (h + 1) & mask;
            }
        }
        if self.facets[first_new..]
            .iter()
            .any(|f| f.neighbors.contains(&u32::MAX))
        {
            return Err(HullFailure {
                reason: "horizon does not close",
            });
        }
        Ok(())
    }
}

/// A ridge of a new facet: its sorted vertices but one, the facet, and the omitted slot.
type Ridge = ([u32; DIM - 1], u32, u8);

/// The vertices of `verts` (sorted) but slot `omit`: sorted.
fn ridge_key(verts: &[u32; DIM], omit: usize) -> [u32; DIM - 1] {
    let mut key = [0u32; DIM - 1];
    let mut j = 0;
    for (i, &v) in verts.iter().enumerate() {
        if i != omit {
            key[j] = v;
            j += 1;
        }
    }
    key
}

fn hash_key(key: &[u32; DIM - 1]) -> usize {
    let mut h: u64 = 0;
    for &v in key {
        h = (h ^ u64::from(v)).wrapping_mul(0x9E37_79B9_7F4A_7C15);
    }
    (h >> 32) as usize
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::quality::gws::hull_measures;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;
    use rand_distr::StandardNormal;

    fn random_points(rng: &mut ChaCha8Rng, n: usize, shift: f64) -> Vec<Wrench> {
        (0..n)
            .map(|_| {
                Wrench::from_fn(|k, _| {
                    rng.sample::<f64, _>(StandardNormal) + if k == 0 { shift } else { 0.0 }
                })
            })
            .collect()
    }

    fn hypercube(center: Wrench) -> Vec<Wrench> {
        (0..64u32)
            .map(|bits| {
                Wrench::from_fn(|k, _| center[k] + if bits & (1 << k) != 0 { 1.0 } else { -1.0 })
            })
            .collect()
    }

    #[test]
    fn closed_forms_on_highly_degenerate_sets() {
        // [-1, 1]^6 (32 points on every facet hyperplane): epsilon 1.
        let depth = origin_depth(&hypercube(Wrench::zeros())).unwrap();
        assert!(
            matches!(depth, OriginDepth::Inside { epsilon, .. } if (epsilon - 1.0).abs() < 1e-12),
            "{depth:?}"
        );
        // Shifted by (0.3, -0.6, 0, ...): nearest facet x_2 = -1 at 0.4.
        let depth = origin_depth(&hypercube(Wrench::new(0.3, -0.6, 0.0, 0.0, 0.0, 0.0))).unwrap();
        assert!(
            matches!(depth, OriginDepth::Inside { epsilon, .. } if (epsilon - 0.4).abs() < 1e-12),
            "{depth:?}"
        );
        // The origin on a facet, and outside.
        let on = hypercube(Wrench::new(0.0, 0.0, 0.0, 1.0, 0.0, 0.0));
        assert_eq!(origin_depth(&on).unwrap(), OriginDepth::NotInside);
        let out = hypercube(Wrench::new(0.0, 0.0, 0.0, 0.0, 0.0, -2.5));
        assert_eq!(origin_depth(&out).unwrap(), OriginDepth::NotInside);
        // Cross-polytope conv{+-e_k}: 1/sqrt(6); no 7 of its vertices hold the origin
        // strictly inside their simplex.
        let cross: Vec<Wrench> = (0..12)
            .map(|i| {
                let mut w = Wrench::zeros();
                w[i % 6] = if i < 6 { 1.0 } else { -1.0 };
                w
            })
            .collect();
        let depth = origin_depth(&cross).unwrap();
        assert!(
            matches!(depth, OriginDepth::Inside { epsilon, .. } if (epsilon - 6f64.sqrt().recip()).abs() < 1e-12),
            "{depth:?}"
        );
        // Lower-dimensional.
        assert_eq!(origin_depth(&cross[..6]).unwrap(), OriginDepth::Degenerate);
        assert_eq!(origin_depth(&[]).unwrap(), OriginDepth::Degenerate);
    }

    #[test]
    fn matches_qhull_on_random_sets() {
        let mut rng = ChaCha8Rng::seed_from_u64(7);
        let mut inside = 0;
        for trial in 0..300 {
            let n = 7 + trial % 50;
            let shift = [0.0, 0.5, 1.5][trial % 3];
            let points = random_points(&mut rng, n, shift);
            let reference = hull_measures(&points).unwrap().epsilon;
            let depth = origin_depth(&points).unwrap();
            let eps = match depth {
                OriginDepth::Inside { epsilon, normal } => {
                    // The certificate: the hyperplane supports every point.
                    assert!(points.iter().all(|p| normal.dot(p) <= epsilon + 1e-9));
                    inside += 1;
                    epsilon
                }
                _ => 0.0,
            };
            assert!(
                (eps - reference).abs() < 1e-9,
                "trial {trial}: {eps} vs qhull {reference}"
            );
        }
        assert!(inside > 50, "only {inside} sets contained the origin");
    }

    #[test]
    fn near_degenerate_sets_agree_with_qhull_or_report_failure() {
        // Thin hulls (one coordinate scaled down to 1e-10) and lattice points (many
        // coplanar and repeated): the expansion must agree with qhull or report its
        // failure (then `epsilon_of_wrenches` uses qhull), never return a wrong value.
        let mut rng = ChaCha8Rng::seed_from_u64(99);
        let mut failures = 0;
        let trials = 1000;
        for trial in 0..trials {
            let n = 7 + trial % 40;
            let thin = [1e-3, 1e-6, 1e-8, 1e-10, 1.0][trial % 5];
            let lattice = trial % 7 == 0;
            let points: Vec<Wrench> = (0..n)
                .map(|_| {
                    Wrench::from_fn(|k, _| {
                        let v: f64 = if lattice {
                            f64::from(rng.gen_range(-2i32..=2))
                        } else {
                            rng.sample(StandardNormal)
                        };
                        if k == 5 {
                            v * thin
                        } else {
                            v + 0.2
                        }
                    })
                })
                .collect();
            let reference = hull_measures(&points).unwrap().epsilon;
            match origin_depth(&points) {
                Err(_) => failures += 1,
                Ok(depth) => {
                    let eps = match depth {
                        OriginDepth::Inside { epsilon, .. } => epsilon,
                        _ => 0.0,
                    };
                    assert!(
                        (eps - reference).abs() <= 1e-8 * (1.0 + reference),
                        "trial {trial}: {eps} vs qhull {reference}"
                    );
                }
            }
            assert!(
                (crate::quality::epsilon_of_wrenches(&points) - reference).abs()
                    <= 1e-8 * (1.0 + reference)
            );
        }
        assert!(failures * 100 < trials, "{failures} failures in {trials}");
    }
}
