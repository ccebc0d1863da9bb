//! Finding a calibration sphere of known radius in a depth cloud: RANSAC over
//! three-point samples, then geometric least squares on the inliers.
//!
//! Points are in the camera frame (the camera at the origin). A depth camera sees
//! the near side of the sphere, so the centre lies beyond the surface: of the two
//! spheres of radius `r` through three points, the one whose centre is farther along
//! the points' line of sight is taken, and a point counts as an inlier only when
//! its distance from the centre is within the tolerance of `r` *and* it lies on the
//! camera-facing half (`(p − c)·p < 0`). The tolerance grows with depth like the
//! Kinect's noise: `inlier_base_m + inlier_per_m * z²`.
//!
//! The refinement minimises `Σ (‖p_i − c‖ − r)²` over the inliers (Gauss–Newton on
//! the three coordinates of `c`), re-selecting the inliers after each round.

use nalgebra::{Matrix3, Point3, Vector3};
use rand::Rng;
use serde::Serialize;

/// Options of [`fit_sphere`].
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct SphereFitOptions {
    /// The sphere's known radius (m).
    pub radius_m: f64,
    /// RANSAC samples drawn.
    pub iterations: usize,
    /// Inlier tolerance at zero depth (m).
    pub inlier_base_m: f64,
    /// Inlier tolerance growth with the squared depth (1/m): `base + this * z²`.
    pub inlier_per_m: f64,
    /// Fewest inliers for a fit.
    pub min_inliers: usize,
    /// Rounds of inlier re-selection and Gauss–Newton refinement.
    pub refine_rounds: usize,
    /// The inliers' free-radius fit must be within this fraction of the radius (a
    /// flat patch fits a sphere of known radius within the tolerance, never one of
    /// free radius).
    pub max_radius_error: f64,
}

impl SphereFitOptions {
    /// Defaults for a Kinect-class camera at 0.5–2 m: tolerance 2 mm + 5 mm/m² · z²
    /// (about 3σ of the depth noise plus quantisation), 300 samples, 30 inliers.
    pub fn kinect(radius_m: f64) -> SphereFitOptions {
        SphereFitOptions {
            radius_m,
            iterations: 300,
            inlier_base_m: 2e-3,
            inlier_per_m: 5e-3,
            min_inliers: 30,
            refine_rounds: 3,
            max_radius_error: 0.25,
        }
    }

    /// The inlier tolerance at point `p` (m).
    pub fn tolerance_m(&self, p: &Point3<f64>) -> f64 {
        self.inlier_base_m + self.inlier_per_m * p.z * p.z
    }
}

/// A sphere found in a cloud.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct SphereFit {
    /// The centre (camera frame, m).
    pub centre: Point3<f64>,
    /// Inliers of the final fit.
    pub inliers: usize,
    /// RMS of `‖p − c‖ − r` over the inliers (m).
    pub rms_m: f64,
    /// Points the fit considered.
    pub points: usize,
}

/// The centre and radius of the sphere `‖p‖² + d·p + g = 0` fitted to the points by
/// linear least squares (Kåsa's algebraic fit); `None` when the points do not
/// determine one (e.g. they lie on a plane).
pub fn free_radius_fit(points: &[Point3<f64>]) -> Option<(Point3<f64>, f64)> {
    if points.len() < 4 {
        return None;
    }
    let mean = points.iter().map(|p| p.coords).sum::<Vector3<f64>>() / points.len() as f64;
    let mut ata = nalgebra::Matrix4::<f64>::zeros();
    let mut atb = nalgebra::Vector4::<f64>::zeros();
    for p in points {
        let q = p.coords - mean;
        let row = nalgebra::Vector4::new(q.x, q.y, q.z, 1.0);
        ata += row * row.transpose();
        atb -= row * q.norm_squared();
    }
    let svd = ata.svd(true, true);
    let max = svd.singular_values.max();
    let min = svd.singular_values.min();
    if min.is_nan() || min <= 1e-12 * max {
        return None;
    }
    let x = svd.solve(&atb, 0.0).ok()?;
    let centre = Vector3::new(x[0], x[1], x[2]) * -0.5;
    let r2 = centre.norm_squared() - x[3];
    (r2 > 0.0).then(|| (Point3::from(centre + mean), r2.sqrt()))
}

/// Why no sphere was found.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum SphereFitError {
    /// Too few points to fit anything.
    #[error("only {got} points near the expected sphere position (need at least {need})")]
    TooFewPoints {
        /// Points given.
        got: usize,
        /// Points needed.
        need: usize,
    },
    /// No sphere of the radius has enough inliers.
    #[error("no sphere of radius {radius_mm:.1} mm with at least {need} inliers among {points} points (best {best})")]
    NotFound {
        /// The radius looked for (mm).
        radius_mm: f64,
        /// Most inliers of any candidate.
        best: usize,
        /// Inliers needed.
        need: usize,
        /// Points considered.
        points: usize,
    },
    /// The best candidate's inliers are not a sphere of the radius.
    #[error("the best candidate ({inliers} inliers) is not a sphere of radius {radius_mm:.1} mm: its points fit radius {free_radius_mm:.1} mm")]
    WrongShape {
        /// The radius looked for (mm).
        radius_mm: f64,
        /// The free-radius fit of the inliers (mm; infinite for a plane).
        free_radius_mm: f64,
        /// Inliers of the candidate.
        inliers: usize,
    },
}

/// The centres of the spheres of radius `r` through three points, the one farther
/// from the origin (camera) first; `None` when the points are (nearly) collinear or
/// their circumcircle is wider than the sphere.
pub fn sphere_centres_through(p: [&Point3<f64>; 3], r: f64) -> Option<(Point3<f64>, Point3<f64>)> {
    let a = p[0] - p[2];
    let b = p[1] - p[2];
    let axb = a.cross(&b);
    let n2 = axb.norm_squared();
    if n2 < 1e-18 {
        return None;
    }
    let o = p[2] + (b * a.norm_squared() - a * b.norm_squared()).cross(&axb) / (2.0 * n2);
    let rho2 = (o - p[2]).norm_squared();
    if rho2 > r * r {
        return None;
    }
    let h = (r * r - rho2).sqrt();
    let n = axb / n2.sqrt();
    let (c1, c2) = (o + n * h, o - n * h);
    // Farther along the line of sight to the circle's centre.
    if (c1 - o).dot(&o.coords) >= 0.0 {
        Some((c1, c2))
    } else {
        Some((c2, c1))
    }
}

fn is_inlier(p: &Point3<f64>, c: &Point3<f64>, options: &SphereFitOptions) -> bool {
    let d = p - c;
    ((d.norm() - options.radius_m).abs() <= options.tolerance_m(p)) && d.dot(&p.coords) < 0.0
}

fn count_inliers(points: &[Point3<f64>], c: &Point3<f64>, options: &SphereFitOptions) -> usize {
    points.iter().filter(|p| is_inlier(p, c, options)).count()
}

/// Gauss–Newton on `Σ (‖p − c‖ − r)²` from `c` (a few steps).
fn least_squares_centre(points: &[Point3<f64>], mut c: Point3<f64>, r: f64) -> Point3<f64> {
    for _ in 0..20 {
        let mut jtj = Matrix3::zeros();
        let mut jtr = Vector3::zeros();
        for p in points {
            let d = p - c;
            let dist = d.norm();
            if dist < 1e-12 {
                continue;
            }
            let j = -d / dist; // d(residual)/dc
            jtj += j * j.transpose();
            jtr += j * (dist - r);
        }
        let Some(step) = jtj.try_inverse().map(|inv| -(inv * jtr)) else {
            break;
        };
        c += step;
        if step.norm() < 1e-9 {
            break;
        }
    }
    c
}

/// Finds a sphere of radius `options.radius_m` among `points` (camera frame).
pub fn fit_sphere(
    points: &[Point3<f64>],
    options: &SphereFitOptions,
    rng: &mut impl Rng,
) -> Result<SphereFit, SphereFitError> {
    let need = options.min_inliers.max(3);
    if points.len() < need {
        return Err(SphereFitError::TooFewPoints {
            got: points.len(),
            need,
        });
    }
    let r = options.radius_m;
    // Samples whose points are closer than this are too ill-conditioned to try.
    let min_side = 0.3 * r;
    let mut best: Option<(usize, Point3<f64>)> = None;
    for _ in 0..options.iterations {
        let i = rng.gen_range(0..points.len());
        let j = rng.gen_range(0..points.len());
        let k = rng.gen_range(0..points.len());
        let (a, b, c) = (&points[i], &points[j], &points[k]);
        if (a - b).norm() < min_side || (b - c).norm() < min_side || (a - c).norm() < min_side {
            continue;
        }
        let Some((centre, _)) = sphere_centres_through([a, b, c], r) else {
            continue;
        };
        let n = count_inliers(points, &centre, options);
        if best.is_none_or(|(m, _)| n > m) {
            best = Some((n, centre));
        }
    }
    let not_found = |best: usize| SphereFitError::NotFound {
        radius_mm: r * 1e3,
        best,
        need,
        points: points.len(),
    };
    let Some((n, mut centre)) = best else {
        return Err(not_found(0));
    };
    if n < need {
        return Err(not_found(n));
    }
    for _ in 0..options.refine_rounds.max(1) {
        let inliers: Vec<Point3<f64>> = points
            .iter()
            .filter(|p| is_inlier(p, &centre, options))
            .copied()
            .collect();
        if inliers.len() < need {
            return Err(not_found(inliers.len()));
        }
        centre = least_squares_centre(&inliers, centre, r);
    }
    let inliers: Vec<Point3<f64>> = points
        .iter()
        .filter(|p| is_inlier(p, &centre, options))
        .copied()
        .collect();
    if inliers.len() < need {
        return Err(not_found(inliers.len()));
    }
    let free_radius_mm = free_radius_fit(&inliers).map_or(f64::INFINITY, |(_, r)| r * 1e3);
    let radius_error = (free_radius_mm * 1e-3 - r).abs();
    if radius_error.is_nan() || radius_error > options.max_radius_error * r {
        return Err(SphereFitError::WrongShape {
            radius_mm: r * 1e3,
            free_radius_mm,
            inliers: inliers.len(),
        });
    }
    let rms_m = (inliers
        .iter()
        .map(|p| ((p - centre).norm() - r).powi(2))
        .sum::<f64>()
        / inliers.len() as f64)
        .sqrt();
    Ok(SphereFit {
        centre,
        inliers: inliers.len(),
        rms_m,
        points: points.len(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;
    use rand_chacha::ChaCha8Rng;
    use rand_distr::{Distribution, Normal};

    /// Points on the camera-facing cap of a sphere (within `cap_deg` of the direction
    /// to the camera), with Gaussian noise along the line of sight, plus a plane of
    /// clutter behind it.
    fn noisy_cap(
        centre: Point3<f64>,
        r: f64,
        cap_deg: f64,
        sigma_m: f64,
        n: usize,
        rng: &mut ChaCha8Rng,
    ) -> Vec<Point3<f64>> {
        let noise = Normal::new(0.0, sigma_m).unwrap();
        let to_camera = -centre.coords.normalize();
        let mut points = Vec::new();
        while points.len() < n {
            let v = Vector3::from_fn(|_, _| rng.gen_range(-1.0..1.0));
            if v.norm() > 1.0 || v.norm() < 1e-3 {
                continue;
            }
            let v = v.normalize();
            if v.angle(&to_camera).to_degrees() > cap_deg {
                continue;
            }
            let p = centre + v * r;
            let ray = p.coords.normalize();
            points.push(p + ray * noise.sample(rng));
        }
        points
    }

    #[test]
    fn free_radius_fit_recovers_a_sphere_and_rejects_a_plane() {
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        let c = Point3::new(0.05, 0.02, 0.9);
        let cap = noisy_cap(c, 0.04, 70.0, 0.0, 200, &mut rng);
        let (centre, r) = free_radius_fit(&cap).unwrap();
        assert!((centre - c).norm() < 1e-9 && (r - 0.04).abs() < 1e-9);
        let plane: Vec<Point3<f64>> = (0..100)
            .map(|i| Point3::new((i % 10) as f64 * 0.01, (i / 10) as f64 * 0.01, 1.0))
            .collect();
        assert!(free_radius_fit(&plane).is_none_or(|(_, r)| r > 1.0));
    }

    #[test]
    fn three_points_give_the_far_centre_first() {
        let c = Point3::new(0.1, -0.05, 1.0);
        let r = 0.04;
        let to_cam = -c.coords.normalize();
        let e1 = to_cam.cross(&Vector3::x()).normalize();
        let e2 = to_cam.cross(&e1);
        let on = |a: f64, b: f64| c + (to_cam * 0.8 + e1 * a + e2 * b).normalize() * r;
        let (p, q, s) = (on(0.5, 0.0), on(-0.3, 0.4), on(-0.2, -0.5));
        let (far, near) = sphere_centres_through([&p, &q, &s], r).unwrap();
        assert!((far - c).norm() < 1e-12, "{far} vs {c}");
        assert!(near.coords.norm() < far.coords.norm());
        // Collinear points and a too-wide circle have no sphere.
        let line = [
            Point3::new(0.0, 0.0, 1.0),
            Point3::new(0.01, 0.0, 1.0),
            Point3::new(0.02, 0.0, 1.0),
        ];
        assert!(sphere_centres_through([&line[0], &line[1], &line[2]], r).is_none());
        let wide = [
            Point3::new(-0.1, 0.0, 1.0),
            Point3::new(0.1, 0.0, 1.0),
            Point3::new(0.0, 0.1, 1.0),
        ];
        assert!(sphere_centres_through([&wide[0], &wide[1], &wide[2]], r).is_none());
    }

    /// A 40 mm sphere 1.2 m away, 60° cap seen, 2.5 mm noise along the rays (the
    /// Kinect's at 1.2 m plus quantisation), 800 points, with 3000 points of a plane
    /// behind it and 100 uniform outliers: the centre is within 0.6 mm over 10 seeds
    /// (an independent bound: 2.5 mm / sqrt(800) ≈ 0.09 mm per axis for a full
    /// hemisphere, times the cap's conditioning, with margin).
    #[test]
    fn noisy_partial_sphere_with_clutter_is_found_within_bound() {
        let r = 0.04;
        let options = SphereFitOptions::kinect(r);
        let mut worst: f64 = 0.0;
        for seed in 0..10 {
            let mut rng = ChaCha8Rng::seed_from_u64(seed);
            let centre = Point3::new(
                rng.gen_range(-0.2..0.2),
                rng.gen_range(-0.2..0.2),
                rng.gen_range(1.0..1.4),
            );
            let mut points = noisy_cap(centre, r, 60.0, 2.5e-3, 800, &mut rng);
            // A plane 5 cm behind the sphere, facing the camera.
            let n = -centre.coords.normalize();
            let e1 = n.cross(&Vector3::y()).normalize();
            let e2 = n.cross(&e1);
            for _ in 0..3000 {
                let (a, b) = (rng.gen_range(-0.12..0.12), rng.gen_range(-0.12..0.12));
                let p = centre - n * (r + 0.05) + e1 * a + e2 * b;
                // Only what the sphere does not hide.
                let ray = p.coords.normalize();
                let closest = centre.coords.dot(&ray);
                if (centre.coords - ray * closest).norm() > r {
                    points.push(p);
                }
            }
            for _ in 0..100 {
                points.push(centre + Vector3::from_fn(|_, _| rng.gen_range(-0.1..0.1)));
            }
            let fit = fit_sphere(&points, &options, &mut rng).unwrap();
            let err = (fit.centre - centre).norm();
            worst = worst.max(err);
            assert!(fit.inliers >= 760, "seed {seed}: {} inliers", fit.inliers);
            assert!(fit.rms_m < 3.5e-3, "seed {seed}: rms {}", fit.rms_m);
        }
        assert!(worst < 0.6e-3, "worst centre error {:.3} mm", worst * 1e3);
    }

    #[test]
    fn a_plane_alone_or_too_few_points_is_not_a_sphere() {
        let options = SphereFitOptions::kinect(0.04);
        let mut rng = ChaCha8Rng::seed_from_u64(1);
        let plane: Vec<Point3<f64>> = (0..2000)
            .map(|_| Point3::new(rng.gen_range(-0.1..0.1), rng.gen_range(-0.1..0.1), 1.0))
            .collect();
        // A disc of the plane lies within the tolerance of a sphere of known radius;
        // its free-radius fit shows it is flat.
        let err = fit_sphere(&plane, &options, &mut rng).unwrap_err();
        assert!(matches!(err, SphereFitError::WrongShape { .. }), "{err}");
        let err = fit_sphere(&plane[..10], &options, &mut rng).unwrap_err();
        assert_eq!(err, SphereFitError::TooFewPoints { got: 10, need: 30 });
    }
}
