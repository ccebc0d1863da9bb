//! Building blocks of closed procedural surfaces: quad grids (lathes and lofts),
//! pole caps, rectangular holes cut out of a grid, and tubes swept along a path
//! whose ends are stitched into such holes.
//!
//! One winding rule makes everything consistent: a grid's vertex `(i, j)` (ring
//! `i`, position `j` around the ring, wrapping) forms the quad
//! `(i,j) (i,j+1) (i+1,j+1) (i+1,j)`, whose normal is `d/dj x d/di`. Rings are
//! therefore ordered counter-clockwise about the direction in which `i` grows,
//! and every surface built here is outward. A hole's boundary keeps the removed
//! quads' edge directions, so a tube whose first ring is that boundary (ordered
//! counter-clockwise about the hole's outward normal) closes it exactly.

use crate::mesh::TriMesh;
use nalgebra::{Matrix3, Point3, Vector3};
use std::f64::consts::TAU;

/// Vertices and triangles under construction.
#[derive(Debug, Default)]
pub(super) struct Builder {
    vertices: Vec<Point3<f64>>,
    triangles: Vec<[u32; 3]>,
}

impl Builder {
    /// Adds a vertex and returns its index.
    pub fn vertex(&mut self, p: Point3<f64>) -> u32 {
        self.vertices.push(p);
        (self.vertices.len() - 1) as u32
    }

    /// Position of vertex `i`.
    pub fn position(&self, i: u32) -> Point3<f64> {
        self.vertices[i as usize]
    }

    /// Adds a ring of vertices.
    pub fn ring(&mut self, points: impl IntoIterator<Item = Point3<f64>>) -> Vec<u32> {
        points.into_iter().map(|p| self.vertex(p)).collect()
    }

    fn quad(&mut self, a: u32, b: u32, c: u32, d: u32) {
        self.triangles.push([a, b, c]);
        self.triangles.push([a, c, d]);
    }

    /// Quads between consecutive rings (all of one length, wrapping around),
    /// except the cells `(i, j)` for which `skip` is true.
    pub fn stitch(&mut self, rings: &[Vec<u32>], skip: impl Fn(usize, usize) -> bool) {
        for i in 0..rings.len().saturating_sub(1) {
            let (lo, hi) = (&rings[i], &rings[i + 1]);
            debug_assert_eq!(lo.len(), hi.len());
            let n = lo.len();
            for j in 0..n {
                if !skip(i, j) {
                    let k = (j + 1) % n;
                    self.quad(lo[j], lo[k], hi[k], hi[j]);
                }
            }
        }
    }

    /// Closes the start of a grid (the side `i` grows away from) with a fan to `pole`.
    pub fn cap_start(&mut self, pole: u32, ring: &[u32]) {
        for j in 0..ring.len() {
            self.triangles
                .push([pole, ring[(j + 1) % ring.len()], ring[j]]);
        }
    }

    /// Closes the end of a grid (the side `i` grows toward) with a fan to `pole`.
    pub fn cap_end(&mut self, ring: &[u32], pole: u32) {
        for j in 0..ring.len() {
            self.triangles
                .push([ring[j], ring[(j + 1) % ring.len()], pole]);
        }
    }

    /// The finished mesh, without vertices no triangle uses.
    pub fn finish(self) -> TriMesh {
        let mut new_index = vec![u32::MAX; self.vertices.len()];
        let mut vertices = Vec::with_capacity(self.vertices.len());
        let triangles = self
            .triangles
            .iter()
            .map(|t| {
                t.map(|i| {
                    let slot = &mut new_index[i as usize];
                    if *slot == u32::MAX {
                        *slot = vertices.len() as u32;
                        vertices.push(self.vertices[i as usize]);
                    }
                    *slot
                })
            })
            .collect();
        TriMesh {
            vertices,
            triangles,
        }
    }
}

/// A block of grid cells `[i0, i0 + ni) x [j0, j0 + nj)` (`j` wrapping) cut out
/// of a grid to make a hole.
#[derive(Debug, Clone, Copy)]
pub(super) struct Hole {
    /// First ring of the block.
    pub i0: usize,
    /// Number of cells along `i`.
    pub ni: usize,
    /// First ring position of the block.
    pub j0: usize,
    /// Number of cells along `j`.
    pub nj: usize,
}

impl Hole {
    /// True when grid cell `(i, j)` of a grid with rings of `n` vertices lies in the hole.
    pub fn contains(&self, i: usize, j: usize, n: usize) -> bool {
        (self.i0..self.i0 + self.ni).contains(&i) && (j + n - self.j0) % n < self.nj
    }

    /// The boundary as `(di, dj)` offsets from the corner `(i0, j0)`, in the
    /// direction the removed cells' edges ran: `+j` along the first ring, `+i`,
    /// `-j` along the last ring, `-i` back (counter-clockwise about the outward normal).
    pub fn boundary_offsets(&self) -> Vec<(usize, usize)> {
        let (ni, nj) = (self.ni, self.nj);
        let mut cycle = Vec::with_capacity(2 * (ni + nj));
        cycle.extend((0..nj).map(|dj| (0, dj)));
        cycle.extend((0..ni).map(|di| (di, nj)));
        cycle.extend((1..=nj).rev().map(|dj| (ni, dj)));
        cycle.extend((1..=ni).rev().map(|di| (di, 0)));
        cycle
    }

    /// The boundary's vertex ids in `rings`, counter-clockwise about the outward normal.
    pub fn boundary(&self, rings: &[Vec<u32>]) -> Vec<u32> {
        self.boundary_offsets()
            .into_iter()
            .map(|(di, dj)| self.id(rings, di, dj))
            .collect()
    }

    /// The boundary of this hole ordered to match `other`'s boundary after
    /// mirroring along `i` (offset `(di, dj)` of `other` pairs with `(ni - di, dj)`
    /// here). That order is clockwise about this hole's outward normal: the far
    /// ring of a tube that leaves through `other` and comes back in through here.
    pub fn mirrored_boundary(&self, rings: &[Vec<u32>], other: &Hole) -> Vec<u32> {
        debug_assert_eq!((self.ni, self.nj), (other.ni, other.nj));
        other
            .boundary_offsets()
            .into_iter()
            .map(|(di, dj)| self.id(rings, self.ni - di, dj))
            .collect()
    }

    fn id(&self, rings: &[Vec<u32>], di: usize, dj: usize) -> u32 {
        let ring = &rings[self.i0 + di];
        ring[(self.j0 + dj) % ring.len()]
    }
}

/// One end of a swept tube.
#[derive(Debug, Clone, Copy)]
pub(super) enum TubeEnd<'a> {
    /// Existing vertices (a hole's boundary) ordered counter-clockwise about the
    /// sweep direction at that end.
    Ring(&'a [u32]),
    /// A single vertex at the centre of the end section.
    Pole,
}

/// A tube swept along `path` (ring centres, start to end): each intermediate ring
/// is `section(t, theta)` in the local frame (`b` along `side` made normal to the
/// path, `n = tangent x b`), where `t` is the arc-length fraction. Near a `Ring` end
/// the rings blend from that ring's own shape into the section over `blend_m`.
pub(super) struct Sweep<'a> {
    /// Ring centres (m), at least three.
    pub path: Vec<Point3<f64>>,
    /// Reference direction for the section's `b` axis.
    pub side: Vector3<f64>,
    /// Section offset `(b, n)` (m) at arc fraction `t` and angle `theta`.
    pub section: &'a dyn Fn(f64, f64) -> [f64; 2],
    /// Arc length (m) over which an end ring's shape blends into the section.
    pub blend_m: f64,
    /// Vertices per ring when neither end is a `Ring`.
    pub ring_len: usize,
}

impl Sweep<'_> {
    /// Adds the tube's vertices and triangles to `builder`.
    pub fn build(&self, builder: &mut Builder, start: TubeEnd, end: TubeEnd) {
        let m = self.path.len() - 1;
        let mut arc = vec![0.0; m + 1];
        for k in 1..=m {
            arc[k] = arc[k - 1] + (self.path[k] - self.path[k - 1]).norm();
        }
        let length = arc[m];
        let frames: Vec<Matrix3<f64>> = (0..=m).map(|k| self.frame(k)).collect();
        let local = |k: usize, p: Point3<f64>| frames[k].transpose() * (p - self.path[k]);
        let start_offsets: Option<Vec<Vector3<f64>>> = match start {
            TubeEnd::Ring(ids) => {
                Some(ids.iter().map(|&i| local(0, builder.position(i))).collect())
            }
            TubeEnd::Pole => None,
        };
        let end_offsets: Option<Vec<Vector3<f64>>> = match end {
            TubeEnd::Ring(ids) => {
                Some(ids.iter().map(|&i| local(m, builder.position(i))).collect())
            }
            TubeEnd::Pole => None,
        };
        let ring_len = start_offsets
            .as_ref()
            .or(end_offsets.as_ref())
            .map_or(self.ring_len, Vec::len);
        // Each ring position keeps the angle it has at the start (or end) ring.
        let angles: Vec<f64> = match start_offsets.as_ref().or(end_offsets.as_ref()) {
            Some(offsets) => offsets.iter().map(|o| o.z.atan2(o.y)).collect(),
            None => (0..ring_len)
                .map(|s| TAU * s as f64 / ring_len as f64)
                .collect(),
        };
        let mut rings: Vec<Vec<u32>> = Vec::with_capacity(m + 1);
        if let TubeEnd::Ring(ids) = start {
            rings.push(ids.to_vec());
        }
        for k in 1..m {
            let t = arc[k] / length;
            let w_start = match start {
                TubeEnd::Ring(_) => 1.0 - smoothstep(arc[k] / self.blend_m),
                TubeEnd::Pole => 0.0,
            };
            let w_end = match end {
                TubeEnd::Ring(_) => 1.0 - smoothstep((length - arc[k]) / self.blend_m),
                TubeEnd::Pole => 0.0,
            };
            let ring = (0..ring_len).map(|s| {
                let [b, n] = (self.section)(t, angles[s]);
                let mut offset = Vector3::new(0.0, b, n) * (1.0 - w_start - w_end);
                if let Some(o) = &start_offsets {
                    offset += o[s] * w_start;
                }
                if let Some(o) = &end_offsets {
                    offset += o[s] * w_end;
                }
                self.path[k] + frames[k] * offset
            });
            rings.push(builder.ring(ring));
        }
        if let TubeEnd::Ring(ids) = end {
            rings.push(ids.to_vec());
        }
        builder.stitch(&rings, |_, _| false);
        let pole_at = |k: usize, t: f64| {
            let mean = angles
                .iter()
                .map(|&a| {
                    let [b, n] = (self.section)(t, a);
                    Vector3::new(0.0, b, n)
                })
                .sum::<Vector3<f64>>()
                / ring_len as f64;
            self.path[k] + frames[k] * mean
        };
        if let TubeEnd::Pole = start {
            let pole = builder.vertex(pole_at(0, 0.0));
            builder.cap_start(pole, &rings[0]);
        }
        if let TubeEnd::Pole = end {
            let pole = builder.vertex(pole_at(m, 1.0));
            builder.cap_end(&rings[rings.len() - 1], pole);
        }
    }

    /// Columns: tangent, `b`, `n` at path point `k`.
    fn frame(&self, k: usize) -> Matrix3<f64> {
        let last = self.path.len() - 1;
        let (a, b) = (k.saturating_sub(1), (k + 1).min(last));
        let t = (self.path[b] - self.path[a]).normalize();
        let side = (self.side - t * t.dot(&self.side)).normalize();
        Matrix3::from_columns(&[t, side, t.cross(&side)])
    }
}

/// `3x^2 - 2x^3` on `[0, 1]`, clamped outside.
pub(super) fn smoothstep(x: f64) -> f64 {
    let x = x.clamp(0.0, 1.0);
    x * x * (3.0 - 2.0 * x)
}

/// `count + 1` points equally spaced by arc length along the polyline `dense`.
pub(super) fn resample_by_arc_length(dense: &[Point3<f64>], count: usize) -> Vec<Point3<f64>> {
    let mut arc = vec![0.0; dense.len()];
    for k in 1..dense.len() {
        arc[k] = arc[k - 1] + (dense[k] - dense[k - 1]).norm();
    }
    let length = arc[dense.len() - 1];
    let mut out = Vec::with_capacity(count + 1);
    let mut seg = 0;
    for i in 0..=count {
        let target = length * i as f64 / count as f64;
        while seg + 2 < dense.len() && arc[seg + 1] < target {
            seg += 1;
        }
        let span = arc[seg + 1] - arc[seg];
        let f = if span > 0.0 {
            ((target - arc[seg]) / span).clamp(0.0, 1.0)
        } else {
            0.0
        };
        out.push(dense[seg] + (dense[seg + 1] - dense[seg]) * f);
    }
    out
}

/// A surface of revolution about +z through the profile `(r, z)`: the first and
/// last points lie on the axis (poles), the others become rings at `angles`
/// (increasing, radians). Cells in `holes` are left open. Returns the rings.
pub(super) fn lathe(
    builder: &mut Builder,
    profile: &[[f64; 2]],
    angles: &[f64],
    holes: &[Hole],
) -> Vec<Vec<u32>> {
    let n = profile.len();
    let bottom = builder.vertex(Point3::new(0.0, 0.0, profile[0][1]));
    let rings: Vec<Vec<u32>> = profile[1..n - 1]
        .iter()
        .map(|&[r, z]| {
            builder.ring(
                angles
                    .iter()
                    .map(|&a| Point3::new(r * a.cos(), r * a.sin(), z)),
            )
        })
        .collect();
    let top = builder.vertex(Point3::new(0.0, 0.0, profile[n - 1][1]));
    builder.cap_start(bottom, &rings[0]);
    builder.stitch(&rings, |i, j| {
        holes.iter().any(|h| h.contains(i, j, angles.len()))
    });
    builder.cap_end(&rings[rings.len() - 1], top);
    rings
}

/// Superellipse coordinate: `sign(v) |v|^(2/p)` (`p = 2` is the circle).
pub(super) fn superellipse(v: f64, p: f64) -> f64 {
    v.signum() * v.abs().powf(2.0 / p)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mesh::topology::{edge_report, euler_characteristic, signed_volume};

    #[test]
    fn lathe_of_a_cylinder_is_closed_with_its_volume() {
        let mut b = Builder::default();
        let (r, h) = (0.5, 2.0);
        let profile = [[0.0, 0.0], [r, 0.0], [r, h], [0.0, h]];
        let n = 256;
        let angles: Vec<f64> = (0..n).map(|j| TAU * j as f64 / n as f64).collect();
        lathe(&mut b, &profile, &angles, &[]);
        let mesh = b.finish();
        assert!(
            edge_report(&mesh).is_watertight(),
            "{:?}",
            edge_report(&mesh)
        );
        // Inscribed polygon area: n/2 r^2 sin(2 pi / n).
        let expected = n as f64 / 2.0 * r * r * (TAU / n as f64).sin() * h;
        assert!((signed_volume(&mesh) - expected).abs() < 1e-12);
    }

    #[test]
    fn hole_boundary_is_a_cycle_of_the_right_length() {
        let hole = Hole {
            i0: 1,
            ni: 2,
            j0: 5,
            nj: 3,
        };
        let cycle = hole.boundary_offsets();
        assert_eq!(cycle.len(), 10);
        for k in 0..cycle.len() {
            let (a, b) = (cycle[k], cycle[(k + 1) % cycle.len()]);
            let step = a.0.abs_diff(b.0) + a.1.abs_diff(b.1);
            assert_eq!(step, 1, "{a:?} -> {b:?}");
        }
        assert!(hole.contains(2, 7, 8) && hole.contains(1, 5, 8) && !hole.contains(3, 5, 8));
        let wrap = Hole {
            i0: 0,
            ni: 1,
            j0: 7,
            nj: 2,
        };
        assert!(wrap.contains(0, 0, 8) && wrap.contains(0, 7, 8) && !wrap.contains(0, 1, 8));
    }

    #[test]
    fn tube_between_two_holes_makes_a_closed_torus() {
        // A cylinder with two holes on its side joined by a C-shaped tube: genus 1.
        let mut b = Builder::default();
        let r = 0.05;
        let zs: Vec<f64> = (0..=20).map(|k| 0.01 * k as f64).collect();
        let mut profile = vec![[0.0, 0.0]];
        profile.extend(zs.iter().map(|&z| [r, z]));
        profile.push([0.0, 0.2]);
        let n = 48;
        let angles: Vec<f64> = (0..n).map(|j| TAU * (j as f64 - 1.0) / n as f64).collect();
        // Rings are profile[1..]: ring k is at z = 0.01 k.
        let lower = Hole {
            i0: 4,
            ni: 2,
            j0: 0,
            nj: 2,
        };
        let upper = Hole {
            i0: 14,
            ni: 2,
            j0: 0,
            nj: 2,
        };
        let rings = lathe(&mut b, &profile, &angles, &[lower, upper]);
        let start = lower.boundary(&rings);
        let end = upper.mirrored_boundary(&rings, &lower);
        let centre = |ids: &[u32], b: &Builder| {
            Point3::from(
                ids.iter()
                    .map(|&i| b.position(i).coords)
                    .sum::<Vector3<f64>>()
                    / ids.len() as f64,
            )
        };
        let (p0, p1) = (centre(&start, &b), centre(&end, &b));
        let dense: Vec<Point3<f64>> = (0..=200)
            .map(|k| {
                let a = std::f64::consts::PI * k as f64 / 200.0;
                let x = p0.x + 0.04 * a.sin();
                Point3::new(x, 0.0, (p0.z + p1.z) / 2.0 - (p1.z - p0.z) / 2.0 * a.cos())
            })
            .collect();
        let section = |_t: f64, a: f64| [0.006 * a.cos(), 0.006 * a.sin()];
        Sweep {
            path: resample_by_arc_length(&dense, 30),
            side: Vector3::y(),
            section: &section,
            blend_m: 0.01,
            ring_len: 0,
        }
        .build(&mut b, TubeEnd::Ring(&start), TubeEnd::Ring(&end));
        let mesh = b.finish();
        let report = edge_report(&mesh);
        assert!(report.is_watertight(), "{report:?}");
        assert_eq!(euler_characteristic(&mesh), 0);
        assert!(signed_volume(&mesh) > 0.0);
    }
}
