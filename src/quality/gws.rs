//! The grasp wrench space (GWS): the 6-D convex hull of the contact wrenches, by qhull.
//!
//! This is the L1 ("sum") GWS of Ferrari & Canny and GraspIt!: the hull of the union
//! of all friction-cone edge wrenches. qhull (the C library, as GraspIt! uses) gives the
//! full hull, hence its volume and the distance from the origin to every facet.
//!
//! Degenerate inputs (fewer than 7 affinely independent wrenches, e.g. coplanar contacts
//! or frictionless contacts whose wrenches span a subspace) have no 6-D interior: they
//! are detected before qhull by [`spanning_simplex`] and give volume 0 and epsilon 0. qhull
//! runs in its default mode (facet merging, no joggle: `QJ` would perturb the input and
//! make the volume and epsilon depend on a random seed) with `Qt` (triangulated output,
//! so every facet is a simplex whose cone to an interior point sums to the volume). Any
//! qhull error left after the rank check (a precision failure on a nearly flat hull) is
//! caught and reported as [`GwsError`]; callers treat such a hull as degenerate.

use super::epsilon::REL_TOL;
use super::wrench::Wrench;
use nalgebra::Matrix6;
use qhull::Qh;

const DIM: usize = 6;

/// The hull measures of a wrench set.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct HullMeasures {
    /// Distance from the origin to the nearest facet hyperplane when the origin is
    /// strictly inside, else 0.
    pub epsilon: f64,
    /// The 6-D volume of the hull (0 when degenerate).
    pub volume: f64,
    /// Number of (triangulated) facets.
    pub facets: usize,
}

impl HullMeasures {
    /// The measures of a hull without interior.
    pub const DEGENERATE: HullMeasures = HullMeasures {
        epsilon: 0.0,
        volume: 0.0,
        facets: 0,
    };
}

/// qhull could not build the hull.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("qhull failed on {points} wrenches: {message}")]
pub struct GwsError {
    /// Number of input wrenches.
    pub points: usize,
    /// qhull's message.
    pub message: String,
}

/// Indices of 7 affinely independent points chosen greedily for a large simplex (the
/// point farthest from the mean, then repeatedly the point farthest from the affine
/// hull of those chosen); None when every remaining point is within `tol` of that
/// affine hull, i.e. the set has no 6-D interior at that tolerance.
pub fn spanning_simplex(points: &[Wrench], tol: f64) -> Option<[usize; DIM + 1]> {
    if points.len() < DIM + 1 {
        return None;
    }
    let mean = points.iter().sum::<Wrench>() / points.len() as f64;
    let farthest = |vectors: &[Wrench]| {
        vectors
            .iter()
            .map(|v| v.norm())
            .enumerate()
            .max_by(|a, b| a.1.total_cmp(&b.1))
    };
    let centred: Vec<Wrench> = points.iter().map(|p| p - mean).collect();
    let (i0, _) = farthest(&centred)?;
    let mut chosen = [i0; DIM + 1];
    // Residuals of p - p0 off the span of the chosen edges, updated per new direction.
    let mut residuals: Vec<Wrench> = points.iter().map(|p| p - points[i0]).collect();
    let mut basis: Vec<Wrench> = Vec::with_capacity(DIM);
    for slot in chosen.iter_mut().skip(1) {
        let (i, dist) = farthest(&residuals)?;
        if dist <= tol {
            return None;
        }
        // Orthogonalise once more for accuracy before using it as a direction.
        let mut q = residuals[i];
        for b in &basis {
            q -= b * b.dot(&q);
        }
        q.normalize_mut();
        for r in &mut residuals {
            *r -= q * q.dot(r);
        }
        basis.push(q);
        *slot = i;
    }
    Some(chosen)
}

/// Epsilon, volume and facet count of the hull of `wrenches`, by qhull.
pub fn hull_measures(wrenches: &[Wrench]) -> Result<HullMeasures, GwsError> {
    let scale = wrenches.iter().map(|w| w.norm()).fold(0.0, f64::max);
    let tol = REL_TOL * scale;
    if spanning_simplex(wrenches, tol).is_none() {
        return Ok(HullMeasures::DEGENERATE);
    }
    let mut coords: Vec<f64> = wrenches.iter().flat_map(|w| w.iter().copied()).collect();
    let failed = |message: String| GwsError {
        points: wrenches.len(),
        message,
    };
    let qh = Qh::builder()
        .qhull_args(["Qt"])
        .map_err(|e| failed(e.to_string()))?
        .build(DIM, &mut coords)
        .map_err(|e| failed(e.to_string()))?;
    // The mean of a full-dimensional point set is interior to its hull.
    let interior = wrenches.iter().sum::<Wrench>() / wrenches.len() as f64;
    let mut nearest = f64::INFINITY;
    let mut volume = 0.0;
    let mut facets = 0;
    for facet in qh.facets() {
        facets += 1;
        // qhull's hyperplane: normal . x + offset = 0, normal outward; the origin's
        // distance inside it is -offset.
        nearest = nearest.min(-facet.offset());
        let vertices = facet
            .vertices()
            .ok_or_else(|| failed(format!("facet {} has no vertices", facet.id())))?;
        let mut m = Matrix6::zeros();
        let mut count = 0;
        for v in vertices.iter() {
            let p = v
                .point()
                .ok_or_else(|| failed(format!("a vertex of facet {} has no point", facet.id())))?;
            if count < DIM {
                for (k, x) in p.iter().enumerate() {
                    m[(k, count)] = x - interior[k];
                }
            }
            count += 1;
        }
        if count != DIM {
            return Err(failed(format!(
                "facet {} has {count} vertices, not a simplex",
                facet.id()
            )));
        }
        volume += m.determinant().abs();
    }
    // 720 = 6!: the volume of a simplex is |det| / d!.
    volume /= 720.0;
    Ok(HullMeasures {
        epsilon: if nearest > tol { nearest } else { 0.0 },
        volume,
        facets,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn hypercube(center: Wrench, half: f64) -> Vec<Wrench> {
        (0..64)
            .map(|bits: u32| {
                Wrench::from_fn(|k, _| center[k] + if bits & (1 << k) != 0 { half } else { -half })
            })
            .collect()
    }

    fn cross_polytope() -> Vec<Wrench> {
        (0..12)
            .map(|i| {
                let mut w = Wrench::zeros();
                w[i % 6] = if i < 6 { 1.0 } else { -1.0 };
                w
            })
            .collect()
    }

    #[test]
    fn hypercube_closed_form() {
        // [-1, 1]^6: every facet at distance 1, volume 2^6.
        let m = hull_measures(&hypercube(Wrench::zeros(), 1.0)).unwrap();
        assert!((m.epsilon - 1.0).abs() < 1e-12, "{m:?}");
        assert!((m.volume - 64.0).abs() < 1e-9, "{m:?}");
        // Shifted by 0.5 along x: nearest facet at 0.5.
        let shifted = hypercube(Wrench::new(0.5, 0.0, 0.0, 0.0, 0.0, 0.0), 1.0);
        let m = hull_measures(&shifted).unwrap();
        assert!((m.epsilon - 0.5).abs() < 1e-12, "{m:?}");
    }

    #[test]
    fn cross_polytope_closed_form() {
        // conv{+-e_k}: facets x . s = 1 with s in {+-1}^6, distance 1/sqrt(6);
        // volume 2^6 / 6!.
        let m = hull_measures(&cross_polytope()).unwrap();
        assert!((m.epsilon - 1.0 / 6f64.sqrt()).abs() < 1e-12, "{m:?}");
        assert!((m.volume - 64.0 / 720.0).abs() < 1e-12, "{m:?}");
        assert_eq!(m.facets, 64);
    }

    #[test]
    fn origin_outside_or_on_boundary_gives_zero() {
        let outside = hypercube(Wrench::new(0.0, 0.0, 3.0, 0.0, 0.0, 0.0), 1.0);
        let m = hull_measures(&outside).unwrap();
        assert_eq!(m.epsilon, 0.0);
        assert!((m.volume - 64.0).abs() < 1e-9);
        let touching = hypercube(Wrench::new(0.0, 0.0, 0.0, 0.0, 1.0, 0.0), 1.0);
        assert_eq!(hull_measures(&touching).unwrap().epsilon, 0.0);
    }

    #[test]
    fn lower_dimensional_sets_are_degenerate_not_errors() {
        // The hypercube's points with the last coordinate zeroed span 5 dimensions.
        let flat: Vec<Wrench> = hypercube(Wrench::zeros(), 1.0)
            .into_iter()
            .map(|mut w| {
                w[5] = 0.0;
                w
            })
            .collect();
        assert_eq!(hull_measures(&flat).unwrap(), HullMeasures::DEGENERATE);
        assert!(spanning_simplex(&flat, 1e-9).is_none());
        assert_eq!(hull_measures(&[]).unwrap(), HullMeasures::DEGENERATE);
        assert_eq!(
            hull_measures(&cross_polytope()[..6]).unwrap(),
            HullMeasures::DEGENERATE
        );
    }

    #[test]
    fn spanning_simplex_is_affinely_independent() {
        let points = hypercube(Wrench::zeros(), 1.0);
        let s = spanning_simplex(&points, 1e-9).unwrap();
        let m = Matrix6::from_fn(|r, c| points[s[c + 1]][r] - points[s[0]][r]);
        // The largest simplex in a cube has volume well above 0.
        assert!(m.determinant().abs() > 1.0);
    }
}
