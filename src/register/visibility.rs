//! Free-space reasoning for ranking poses: the target as the sensor saw it, a
//! range image around the viewing direction, and the fraction of a placed model's
//! points that lie clearly in front of the first surface the sensor saw along
//! their ray (the sensor looked through where the model claims a surface).
//!
//! Distances from target to model cannot tell a mug from the same mug upside down
//! when both cover the target's points; the upside-down mug's closed bottom then
//! sits in front of the inside the camera saw, and this term sees it.
//!
//! [`RangeImage::contradicted_fraction`] also counts model points that project
//! where the sensor saw no object at all (outside the target's silhouette, grown
//! by one bin for the sensor's lost edge pixels): there it saw past the object to
//! the table. This is what tells a mug's handle on the wrong side: turned away from
//! where the sensor saw it, the model's handle sticks out of the silhouette.

use nalgebra::{Point3, Vector3};

/// The nearest range the sensor measured per angular bin, seen from the viewpoint.
#[derive(Debug, Clone)]
pub struct RangeImage {
    eye: Point3<f32>,
    axes: [Vector3<f32>; 3],
    /// Bin size in the image plane at unit depth (rad, approximately).
    bin: f32,
    origin: [f32; 2],
    dims: [usize; 2],
    /// Nearest range per bin (m); infinity where no point fell.
    nearest_m: Vec<f32>,
    /// Per bin, how strongly a model point there contradicts the view when no
    /// target point is near: 0 within one bin of the silhouette (the sensor loses
    /// edge pixels), rising linearly to 1 at [`FULL_BINS`] bins outside it.
    outside: Vec<f32>,
}

/// Bins outside the silhouette at which a model point is fully contradicted.
const FULL_BINS: f32 = 4.0;

/// Empty bins around the target's silhouette, so that a model point just outside
/// it still falls in the image.
const PAD_BINS: f32 = 12.0;

impl RangeImage {
    /// The range image of `points` seen from `eye`, with bins about `bin_m` wide at
    /// the points' mean distance. `None` for no points or points at the eye.
    pub fn new(points: &[Point3<f32>], eye: Point3<f32>, bin_m: f32) -> Option<RangeImage> {
        let n = points.len();
        if n == 0 {
            return None;
        }
        let mean = points.iter().fold(Vector3::zeros(), |s, p| s + p.coords) / n as f32;
        let z = (Point3::from(mean) - eye).try_normalize(1e-9)?;
        let helper = if z.x.abs() < 0.9 {
            Vector3::x()
        } else {
            Vector3::y()
        };
        let x = z.cross(&helper).normalize();
        let y = z.cross(&x);
        let distance = (Point3::from(mean) - eye).norm().max(1e-3);
        let bin = bin_m / distance;
        let mut image = RangeImage {
            eye,
            axes: [x, y, z],
            bin,
            origin: [0.0; 2],
            dims: [0; 2],
            nearest_m: Vec::new(),
            outside: Vec::new(),
        };
        let projected: Vec<([f32; 2], f32)> =
            points.iter().filter_map(|p| image.project(p)).collect();
        if projected.is_empty() {
            return None;
        }
        let (mut lo, mut hi) = ([f32::MAX; 2], [f32::MIN; 2]);
        for (uv, _) in &projected {
            for k in 0..2 {
                lo[k] = lo[k].min(uv[k]);
                hi[k] = hi[k].max(uv[k]);
            }
        }
        image.origin = [lo[0] - PAD_BINS * bin, lo[1] - PAD_BINS * bin];
        image.dims = [
            ((hi[0] - lo[0]) / bin) as usize + 2 * PAD_BINS as usize + 1,
            ((hi[1] - lo[1]) / bin) as usize + 2 * PAD_BINS as usize + 1,
        ];
        // A degenerate spread (e.g. points stacked on one ray) cannot blow up memory.
        if image.dims[0].saturating_mul(image.dims[1]) > 4_000_000 {
            return None;
        }
        image.nearest_m = vec![f32::INFINITY; image.dims[0] * image.dims[1]];
        for (uv, range) in projected {
            if let Some(cell) = image.cell(uv) {
                let slot = &mut image.nearest_m[cell];
                *slot = slot.min(range);
            }
        }
        // Distance (bins) to the nearest filled bin.
        let mut d: Vec<f32> = image
            .nearest_m
            .iter()
            .map(|r| if r.is_finite() { 0.0 } else { f32::INFINITY })
            .collect();
        chamfer(&mut d, image.dims);
        image.outside = d
            .into_iter()
            .map(|bins| ((bins - 1.5) / (FULL_BINS - 1.5)).clamp(0.0, 1.0))
            .collect();
        Some(image)
    }

    /// Image-plane coordinates at unit depth and range of `p`; `None` behind the eye.
    fn project(&self, p: &Point3<f32>) -> Option<([f32; 2], f32)> {
        let d = p - self.eye;
        let depth = d.dot(&self.axes[2]);
        if depth <= 1e-6 {
            return None;
        }
        Some((
            [d.dot(&self.axes[0]) / depth, d.dot(&self.axes[1]) / depth],
            d.norm(),
        ))
    }

    fn cell(&self, uv: [f32; 2]) -> Option<usize> {
        let u = (uv[0] - self.origin[0]) / self.bin;
        let v = (uv[1] - self.origin[1]) / self.bin;
        if !(u >= 0.0 && v >= 0.0) {
            return None;
        }
        let (u, v) = (u as usize, v as usize);
        (u < self.dims[0] && v < self.dims[1]).then_some(u + self.dims[0] * v)
    }

    /// Of `points` (target frame), the fraction lying more than `margin_m` in front
    /// of the nearest surface seen along their ray, among those whose ray hit the
    /// target at all.
    pub fn seen_through_fraction(
        &self,
        points: impl Iterator<Item = Point3<f32>>,
        margin_m: f32,
    ) -> f64 {
        let (mut covered, mut through) = (0usize, 0usize);
        for p in points {
            let Some((uv, range)) = self.project(&p) else {
                continue;
            };
            let Some(cell) = self.cell(uv) else { continue };
            let seen = self.nearest_m[cell];
            if seen.is_finite() {
                covered += 1;
                if range + margin_m < seen {
                    through += 1;
                }
            }
        }
        through as f64 / covered.max(1) as f64
    }

    /// Whether `p` is within `margin_m` of the nearest surface along its ray (not
    /// hidden behind it); false for a point outside the image or behind the eye.
    pub fn is_front(&self, p: &Point3<f32>, margin_m: f32) -> bool {
        self.project(p)
            .and_then(|(uv, range)| Some((self.cell(uv)?, range)))
            .is_some_and(|(cell, range)| range <= self.nearest_m[cell] + margin_m)
    }

    /// Of `points` (target frame; the caller leaves out what the sensor could not
    /// have seen anyway, such as points below the table's cut), the fraction that
    /// the sensor's measurements contradict: more than `margin_m` in front of the
    /// nearest surface seen along their ray, or on a ray that passed beside the
    /// target (weighted from 0 within a bin or so of its silhouette, where the
    /// sensor loses edge pixels, to 1 from [`FULL_BINS`] bins out). Points behind
    /// the seen surface are occluded and count as consistent. 0 for no points.
    pub fn contradicted_fraction(
        &self,
        points: impl Iterator<Item = Point3<f32>>,
        margin_m: f32,
    ) -> f64 {
        let (mut total, mut contradicted) = (0usize, 0f64);
        for p in points {
            let Some((uv, range)) = self.project(&p) else {
                continue;
            };
            total += 1;
            let Some(cell) = self.cell(uv) else {
                contradicted += 1.0;
                continue;
            };
            let seen = self.nearest_m[cell];
            contradicted += if !seen.is_finite() {
                self.outside[cell] as f64
            } else if range + margin_m < seen {
                1.0
            } else {
                0.0
            };
        }
        contradicted / total.max(1) as f64
    }
}

/// The two-pass chamfer distance transform of `d` (row-major, `dims` = [width,
/// height]): each entry becomes the distance (bins; 1 along rows and columns,
/// sqrt 2 diagonally) to the nearest zero entry.
fn chamfer(d: &mut [f32], dims: [usize; 2]) {
    let [w, h] = dims;
    let diag = std::f32::consts::SQRT_2;
    for v in 0..h {
        for u in 0..w {
            let mut best = d[u + w * v];
            if u > 0 {
                best = best.min(d[u - 1 + w * v] + 1.0);
            }
            if v > 0 {
                best = best.min(d[u + w * (v - 1)] + 1.0);
                if u > 0 {
                    best = best.min(d[u - 1 + w * (v - 1)] + diag);
                }
                if u + 1 < w {
                    best = best.min(d[u + 1 + w * (v - 1)] + diag);
                }
            }
            d[u + w * v] = best;
        }
    }
    for v in (0..h).rev() {
        for u in (0..w).rev() {
            let mut best = d[u + w * v];
            if u + 1 < w {
                best = best.min(d[u + 1 + w * v] + 1.0);
            }
            if v + 1 < h {
                best = best.min(d[u + w * (v + 1)] + 1.0);
                if u + 1 < w {
                    best = best.min(d[u + 1 + w * (v + 1)] + diag);
                }
                if u > 0 {
                    best = best.min(d[u - 1 + w * (v + 1)] + diag);
                }
            }
            d[u + w * v] = best;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_surface_in_front_of_the_seen_one_is_seen_through() {
        // The sensor at the origin saw a wall at z = 1 m.
        let wall: Vec<Point3<f32>> = (0..400)
            .map(|i| {
                Point3::new(
                    (i % 20) as f32 * 0.005 - 0.05,
                    (i / 20) as f32 * 0.005 - 0.05,
                    1.0,
                )
            })
            .collect();
        let image = RangeImage::new(&wall, Point3::origin(), 0.006).unwrap();
        let at = |z: f32| {
            image.seen_through_fraction(
                (0..100).map(move |i| {
                    Point3::new(
                        (i % 10) as f32 * 0.008 - 0.04,
                        (i / 10) as f32 * 0.008 - 0.04,
                        z,
                    )
                }),
                0.01,
            )
        };
        assert_eq!(at(0.9), 1.0);
        assert_eq!(at(1.0), 0.0);
        // Behind the wall: occluded, not a contradiction.
        assert_eq!(at(1.2), 0.0);
        assert!(image.is_front(&Point3::new(0.0, 0.0, 1.0), 0.005));
        assert!(image.is_front(&Point3::new(0.0, 0.0, 0.9), 0.005));
        assert!(!image.is_front(&Point3::new(0.0, 0.0, 1.2), 0.005));
        assert!(!image.is_front(&Point3::new(0.0, 0.0, -1.0), 0.005));
        // Off to the side, where the sensor saw nothing: no evidence either way.
        let off = image.seen_through_fraction(std::iter::once(Point3::new(0.5, 0.0, 0.9)), 0.01);
        assert_eq!(off, 0.0);
    }

    #[test]
    fn points_beside_the_silhouette_are_contradicted() {
        // The sensor at the origin saw a 10 cm square wall at z = 1 m.
        let wall: Vec<Point3<f32>> = (0..441)
            .map(|i| {
                Point3::new(
                    (i % 21) as f32 * 0.005 - 0.05,
                    (i / 21) as f32 * 0.005 - 0.05,
                    1.0,
                )
            })
            .collect();
        let image = RangeImage::new(&wall, Point3::origin(), 0.004).unwrap();
        let one = |p: Point3<f32>| image.contradicted_fraction(std::iter::once(p), 0.005);
        // On the wall, or behind it: consistent.
        assert_eq!(one(Point3::new(0.0, 0.0, 1.0)), 0.0);
        assert_eq!(one(Point3::new(0.02, 0.0, 1.1)), 0.0);
        // In front of it: seen through.
        assert_eq!(one(Point3::new(0.0, 0.0, 0.95)), 1.0);
        // Just past its edge (within a bin): the edge may have been lost, consistent.
        assert_eq!(one(Point3::new(0.053, 0.0, 1.0)), 0.0);
        // Between: partly.
        let partly = one(Point3::new(0.061, 0.0, 1.0));
        assert!(partly > 0.0 && partly < 1.0, "{partly}");
        // Well beside it, and far outside the image: the sensor saw past.
        assert_eq!(one(Point3::new(0.07, 0.0, 1.0)), 1.0);
        assert_eq!(one(Point3::new(0.5, 0.0, 1.0)), 1.0);
        // Behind the eye: no evidence; the fraction is over the others.
        let mixed = image.contradicted_fraction(
            [
                Point3::new(0.0, 0.0, -1.0),
                Point3::new(0.0, 0.0, 1.0),
                Point3::new(0.09, 0.0, 1.0),
            ]
            .into_iter(),
            0.005,
        );
        assert_eq!(mixed, 0.5);
    }

    #[test]
    fn chamfer_distances_grow_from_the_filled_bins() {
        let inf = f32::INFINITY;
        let mut d = vec![inf, inf, inf, inf, 0.0, inf, inf, inf, inf, inf, inf, inf];
        chamfer(&mut d, [3, 4]);
        let s = std::f32::consts::SQRT_2;
        assert_eq!(
            d,
            [s, 1.0, s, 1.0, 0.0, 1.0, s, 1.0, s, 1.0 + s, 2.0, 1.0 + s]
        );
    }
}
