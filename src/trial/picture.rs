//! The picture of a trial: what the camera saw, which models were fitted where, and
//! where the hand went, drawn without a GPU.
//!
//! A [`TrialScene`] holds the trial's geometry in the robot base frame: the
//! segmented cloud, the registered models (the best fit and the others), the hand's
//! links at the executed grasp, the contacts and the table. [`render`] draws it from
//! the camera's viewpoint (zoomed onto the object) and from one side, with a caption,
//! by a small z-buffered rasteriser on the report's [`Canvas`] (flat shading, the
//! faint models blended over the opaque ones). [`crate::trial::glb`] writes the same
//! scene as binary glTF.

use super::plot::{Canvas, Rgb};
use super::TrialError;
use crate::geometry::{look_at_optical, Pose};
use crate::mesh::TriMesh;
use nalgebra::{Point3, Vector3};
use parry3d_f64::shape::{SharedShape, TypedShape};
use std::path::Path;

/// What a solid of the scene is; decides its colour.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum Part {
    /// The table top.
    Table,
    /// The registered model with the best fit (blue).
    BestModel,
    /// Another registered model (faint).
    OtherModel,
    /// A link of the hand (orange).
    Hand,
}

impl Part {
    /// The part's colour (RGB).
    pub fn colour(self) -> Rgb {
        match self {
            Part::Table => [205, 190, 160],
            Part::BestModel => [40, 100, 220],
            Part::OtherModel => [120, 150, 200],
            Part::Hand => [240, 140, 30],
        }
    }

    /// How opaque the part is drawn (1 = opaque).
    pub fn opacity(self) -> f64 {
        match self {
            Part::OtherModel => 0.3,
            _ => 1.0,
        }
    }
}

/// Colour of the segmented cloud's points (grey).
pub const CLOUD_COLOUR: Rgb = [110, 110, 110];
/// Colour of the contacts (red).
pub const CONTACT_COLOUR: Rgb = [220, 20, 20];
const BACKGROUND: Rgb = [245, 245, 245];

/// A named triangle soup in the robot base frame.
#[derive(Debug, Clone, PartialEq)]
pub struct Solid {
    /// Name (model or link name).
    pub name: String,
    /// What it is.
    pub part: Part,
    /// Triangles, corners counter-clockwise seen from outside (m, base frame).
    pub triangles: Vec<[Point3<f64>; 3]>,
}

impl Solid {
    /// The mesh placed at `base_from_mesh`.
    pub fn from_mesh(name: &str, part: Part, mesh: &TriMesh, base_from_mesh: &Pose) -> Solid {
        let placed: Vec<Point3<f64>> = mesh.vertices.iter().map(|v| base_from_mesh * v).collect();
        Solid {
            name: name.to_string(),
            part,
            triangles: mesh
                .triangles
                .iter()
                .filter_map(|t| {
                    let [a, b, c] = t.map(|i| placed.get(i as usize).copied());
                    Some([a?, b?, c?])
                })
                .collect(),
        }
    }

    /// A collision shape (box, cylinder, capsule, ball, convex hull or mesh) placed
    /// at `base_from_shape`, tessellated; `None` for a shape kind without a
    /// tessellation (a half-space, a compound).
    pub fn from_shape(
        name: &str,
        part: Part,
        shape: &SharedShape,
        base_from_shape: &Pose,
    ) -> Option<Solid> {
        let (vertices, indices) = match shape.as_typed_shape() {
            TypedShape::Cuboid(s) => s.to_trimesh(),
            TypedShape::Cylinder(s) => s.to_trimesh(24),
            TypedShape::Capsule(s) => s.to_trimesh(16, 8),
            TypedShape::Ball(s) => s.to_trimesh(16, 8),
            TypedShape::ConvexPolyhedron(s) => s.to_trimesh(),
            TypedShape::TriMesh(s) => (s.vertices().to_vec(), s.indices().to_vec()),
            _ => return None,
        };
        let mesh = TriMesh {
            vertices,
            triangles: indices,
        };
        Some(Solid::from_mesh(name, part, &mesh, base_from_shape))
    }

    /// The top face of an axis-aligned table box: two triangles at `height_m`.
    pub fn table(center_xy_m: [f64; 2], extent_xy_m: [f64; 2], height_m: f64) -> Solid {
        let [cx, cy] = center_xy_m;
        let [hx, hy] = extent_xy_m.map(|e| 0.5 * e);
        let p = |x: f64, y: f64| Point3::new(cx + x, cy + y, height_m);
        let (a, b, c, d) = (p(-hx, -hy), p(hx, -hy), p(hx, hy), p(-hx, hy));
        Solid {
            name: "table".to_string(),
            part: Part::Table,
            triangles: vec![[a, b, c], [a, c, d]],
        }
    }
}

/// A pinhole view: pose of its optical frame (z forward, x right, y down) in the
/// base frame, and intrinsics.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct View {
    /// Pose of the optical frame in the robot base frame.
    pub base_from_camera: Pose,
    /// Focal length along x (px).
    pub fx_px: f64,
    /// Focal length along y (px).
    pub fy_px: f64,
    /// Principal point x (px).
    pub cx_px: f64,
    /// Principal point y (px).
    pub cy_px: f64,
    /// Image width (px).
    pub width_px: usize,
    /// Image height (px).
    pub height_px: usize,
}

/// Nearest depth drawn (m); triangles reaching nearer are left out.
const NEAR_M: f64 = 0.02;
/// Size of each of the two views (px).
pub const PANEL_PX: (usize, usize) = (480, 360);
/// Width of the region around the object that fills a view (m).
const FIELD_M: f64 = 0.55;

impl View {
    /// The view from `base_from_camera` (the camera's pose), aimed and zoomed so that
    /// `FIELD_M` around `focus` fills a panel: same viewpoint, narrower field.
    pub fn zoomed(base_from_camera: &Pose, focus: &Point3<f64>) -> View {
        // Keep the camera's roll: its "up" is minus its optical y axis.
        let up = -(base_from_camera.rotation * Vector3::y());
        View::looking(base_from_camera.translation.vector, focus, up)
    }

    /// The side view: from the robot's left (+y), a little above `focus`, looking
    /// at it.
    pub fn side(focus: &Point3<f64>) -> View {
        View::looking(
            focus.coords + Vector3::new(0.0, 1.0, 0.3),
            focus,
            Vector3::z(),
        )
    }

    /// A panel-sized view from `eye` at `focus` with `up` up, `FIELD_M` wide at
    /// the focus.
    fn looking(eye: Vector3<f64>, focus: &Point3<f64>, up: Vector3<f64>) -> View {
        let (w, h) = PANEL_PX;
        let distance = (focus.coords - eye).norm().max(NEAR_M);
        let f = w as f64 * distance / FIELD_M;
        View {
            base_from_camera: look_at_optical(eye, focus.coords, up),
            fx_px: f,
            fy_px: f,
            cx_px: 0.5 * (w as f64 - 1.0),
            cy_px: 0.5 * (h as f64 - 1.0),
            width_px: w,
            height_px: h,
        }
    }

    /// Pixel coordinates and depth of a base-frame point, `None` when nearer than
    /// the near plane (or behind).
    fn project(&self, camera_from_base: &Pose, p: &Point3<f64>) -> Option<(f64, f64, f64)> {
        let c = camera_from_base * p;
        (c.z > NEAR_M).then(|| {
            (
                self.fx_px * c.x / c.z + self.cx_px,
                self.fy_px * c.y / c.z + self.cy_px,
                c.z,
            )
        })
    }
}

/// Everything drawn of one trial, in the robot base frame.
#[derive(Debug, Clone, PartialEq)]
pub struct TrialScene {
    /// The segmented object cloud (m).
    pub cloud_m: Vec<Point3<f64>>,
    /// Table, models and hand links.
    pub solids: Vec<Solid>,
    /// Contacts of the executed grasp where the simulator knows them (m).
    pub contacts_m: Vec<Point3<f64>>,
    /// Pose of the camera's optical frame.
    pub base_from_camera: Pose,
    /// The point both views look at (the object).
    pub focus_m: Point3<f64>,
    /// Caption lines (task, method, grade, epsilon, times).
    pub caption: Vec<String>,
}

/// A depth-buffered image being drawn.
struct Raster<'a> {
    canvas: &'a mut Canvas,
    /// Left edge of the panel on the canvas.
    x0: usize,
    view: View,
    camera_from_base: Pose,
    depth_m: Vec<f64>,
    /// Depth of the hand and the table alone: what hides the cloud (the cloud
    /// shows through the models, so a model that misses it is seen to).
    occluder_depth_m: Vec<f64>,
}

impl Raster<'_> {
    fn put(&mut self, x: usize, y: usize, colour: Rgb, opacity: f64) {
        let i = 3 * (y * self.canvas.width + self.x0 + x);
        if opacity >= 1.0 {
            self.canvas.rgb[i..i + 3].copy_from_slice(&colour);
            return;
        }
        for (dst, &c) in self.canvas.rgb[i..i + 3].iter_mut().zip(&colour) {
            let old = *dst as f64;
            *dst = (old + opacity * (c as f64 - old)).round() as u8;
        }
    }

    /// Fills a triangle of `part`, flat shaded by its angle to the optical axis
    /// (the table unshaded); `write` says whether it updates the depth buffer
    /// (opaque) or only blends (faint).
    fn triangle(&mut self, corners: &[Point3<f64>; 3], part: Part, write: bool) {
        let (colour, opacity, shaded) = (part.colour(), part.opacity(), part != Part::Table);
        let occludes = matches!(part, Part::Hand | Part::Table);
        let [a, b, c] = corners.map(|p| self.camera_from_base * p);
        if a.z <= NEAR_M || b.z <= NEAR_M || c.z <= NEAR_M {
            return;
        }
        let n = (b - a).cross(&(c - a));
        let n_norm = n.norm();
        if n_norm.is_nan() || n_norm <= 0.0 {
            return;
        }
        // A head light along the optical axis: the same for every triangle of a
        // plane, so flat surfaces show no seams.
        let light = if shaded {
            0.35 + 0.65 * (n.z / n_norm).abs()
        } else {
            1.0
        };
        let shade = colour.map(|v| (v as f64 * light).min(255.0) as u8);
        let v = self.view;
        let px = |p: &Point3<f64>| (v.fx_px * p.x / p.z + v.cx_px, v.fy_px * p.y / p.z + v.cy_px);
        let (pa, pb, pc) = (px(&a), px(&b), px(&c));
        let area = (pb.0 - pa.0) * (pc.1 - pa.1) - (pb.1 - pa.1) * (pc.0 - pa.0);
        if area.abs() < 1e-12 {
            return;
        }
        let (w, h) = (v.width_px as f64, v.height_px as f64);
        let xmin = pa.0.min(pb.0).min(pc.0).floor().max(0.0);
        let xmax = pa.0.max(pb.0).max(pc.0).ceil().min(w - 1.0);
        let ymin = pa.1.min(pb.1).min(pc.1).floor().max(0.0);
        let ymax = pa.1.max(pb.1).max(pc.1).ceil().min(h - 1.0);
        if xmin > xmax || ymin > ymax {
            return;
        }
        // Each barycentric weight is affine in the pixel: w = k0 + kx x + ky y.
        let edge = |p: (f64, f64), q: (f64, f64)| {
            let kx = -(q.1 - p.1) / area;
            let ky = (q.0 - p.0) / area;
            (-(kx * p.0 + ky * p.1), kx, ky)
        };
        let weights = [edge(pb, pc), edge(pc, pa), edge(pa, pb)];
        let inv_z = [1.0 / a.z, 1.0 / b.z, 1.0 / c.z];
        for y in ymin as usize..=ymax as usize {
            let fy = y as f64;
            let rows = weights.map(|(k0, _, ky)| k0 + ky * fy);
            for x in xmin as usize..=xmax as usize {
                let fx = x as f64;
                let wa = rows[0] + weights[0].1 * fx;
                let wb = rows[1] + weights[1].1 * fx;
                let wc = rows[2] + weights[2].1 * fx;
                if wa < 0.0 || wb < 0.0 || wc < 0.0 {
                    continue;
                }
                // Perspective-correct depth: interpolate 1/z.
                let z = 1.0 / (wa * inv_z[0] + wb * inv_z[1] + wc * inv_z[2]);
                let i = y * v.width_px + x;
                if write && occludes && z < self.occluder_depth_m[i] {
                    self.occluder_depth_m[i] = z;
                }
                if z < self.depth_m[i] {
                    if write {
                        self.depth_m[i] = z;
                    }
                    self.put(x, y, shade, opacity);
                }
            }
        }
    }

    /// A square dot of `size` px centred on `p`, depth-tested against the hand and
    /// the table with `bias_m` of slack (so points on the table show), or on top of
    /// everything.
    fn dot(&mut self, p: &Point3<f64>, size: i64, colour: Rgb, bias_m: Option<f64>) {
        let Some((u, v, z)) = self.view.project(&self.camera_from_base, p) else {
            return;
        };
        let (u, v) = (u.round() as i64, v.round() as i64);
        let r = size / 2;
        for y in v - r..v - r + size {
            for x in u - r..u - r + size {
                if x < 0
                    || y < 0
                    || x >= self.view.width_px as i64
                    || y >= self.view.height_px as i64
                {
                    continue;
                }
                let (x, y) = (x as usize, y as usize);
                let i = y * self.view.width_px + x;
                if bias_m.is_none_or(|b| z - b < self.occluder_depth_m[i]) {
                    self.put(x, y, colour, 1.0);
                }
            }
        }
    }
}

/// Draws `scene` from `view` into the panel of `canvas` whose left edge is `x0`.
fn draw_view(canvas: &mut Canvas, x0: usize, view: View, scene: &TrialScene, title: &str) {
    let (w, h) = (view.width_px, view.height_px);
    for y in 0..h {
        for x in 0..w {
            let i = 3 * (y * canvas.width + x0 + x);
            canvas.rgb[i..i + 3].copy_from_slice(&BACKGROUND);
        }
    }
    let mut raster = Raster {
        canvas,
        x0,
        view,
        camera_from_base: view.base_from_camera.inverse(),
        depth_m: vec![f64::INFINITY; w * h],
        occluder_depth_m: vec![f64::INFINITY; w * h],
    };
    let opaque = scene.solids.iter().filter(|s| s.part.opacity() >= 1.0);
    for solid in opaque {
        for t in &solid.triangles {
            raster.triangle(t, solid.part, true);
        }
    }
    for solid in scene.solids.iter().filter(|s| s.part.opacity() < 1.0) {
        for t in &solid.triangles {
            raster.triangle(t, solid.part, false);
        }
    }
    for p in &scene.cloud_m {
        raster.dot(p, 2, CLOUD_COLOUR, Some(CLOUD_BIAS_M));
    }
    for c in &scene.contacts_m {
        raster.dot(c, 9, [255, 255, 255], None);
        raster.dot(c, 7, CONTACT_COLOUR, None);
    }
    canvas.text(x0 as i64 + 8, 8, title, 2, [40, 40, 40]);
}

/// How far behind the hand or the table a cloud point still shows (m).
const CLOUD_BIAS_M: f64 = 0.012;

/// Height of the caption strip below the views (px).
const CAPTION_LINE_PX: usize = 22;

/// The trial's picture: the camera's view and the side view side by side, the
/// caption below.
pub fn render(scene: &TrialScene) -> Canvas {
    let (w, h) = PANEL_PX;
    let caption_h = 12 + CAPTION_LINE_PX * scene.caption.len().max(1);
    let mut canvas = Canvas::new(2 * w + 4, h + caption_h);
    canvas.fill_rect(w as i64, 0, 4, h as i64, [255, 255, 255]);
    draw_view(
        &mut canvas,
        0,
        View::zoomed(&scene.base_from_camera, &scene.focus_m),
        scene,
        "CAMERA VIEW",
    );
    draw_view(
        &mut canvas,
        w + 4,
        View::side(&scene.focus_m),
        scene,
        "SIDE VIEW",
    );
    for (k, line) in scene.caption.iter().enumerate() {
        canvas.text(
            10,
            (h + 8 + k * CAPTION_LINE_PX) as i64,
            line,
            2,
            [20, 20, 20],
        );
    }
    canvas
}

/// Renders `scene` and writes it as PNG to `path` (atomically).
pub fn write_png(scene: &TrialScene, path: &Path) -> Result<(), TrialError> {
    if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
        crate::fsio::create_dir_all(dir)?;
    }
    render(scene).save_png(path)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn cube(part: Part, at: [f64; 3], size_m: f64) -> Solid {
        let shape = SharedShape::cuboid(0.5 * size_m, 0.5 * size_m, 0.5 * size_m);
        let pose = Pose::translation(at[0], at[1], at[2]);
        Solid::from_shape("cube", part, &shape, &pose).unwrap()
    }

    fn scene() -> TrialScene {
        TrialScene {
            cloud_m: vec![Point3::new(0.6, 0.0, 0.2)],
            solids: vec![
                Solid::table([0.65, 0.0], [0.8, 1.2], 0.0),
                cube(Part::BestModel, [0.6, 0.0, 0.05], 0.1),
                cube(Part::Hand, [0.6, 0.0, 0.25], 0.06),
            ],
            contacts_m: vec![Point3::new(0.6, 0.05, 0.05)],
            base_from_camera: look_at_optical(
                Vector3::new(1.25, 0.0, 0.8),
                Vector3::new(0.6, 0.0, 0.05),
                Vector3::z(),
            ),
            focus_m: Point3::new(0.6, 0.0, 0.08),
            caption: vec!["MUG POUR / LAPLACE".into()],
        }
    }

    fn count(canvas: &Canvas, x0: usize, pred: impl Fn(Rgb) -> bool) -> usize {
        let (w, h) = PANEL_PX;
        (0..h)
            .flat_map(|y| (x0..x0 + w).map(move |x| (x, y)))
            .filter(|&(x, y)| pred(canvas.pixel(x, y)))
            .count()
    }

    #[test]
    fn both_views_show_the_model_the_hand_and_the_contact() {
        let canvas = render(&scene());
        let blue = |c: Rgb| c[2] > 100 && c[2] as i32 > c[0] as i32 + 60;
        let orange = |c: Rgb| c[0] > 120 && c[0] as i32 > c[2] as i32 + 80 && c[1] > 40;
        let red = |c: Rgb| c == CONTACT_COLOUR;
        for x0 in [0, PANEL_PX.0 + 4] {
            assert!(count(&canvas, x0, blue) > 500, "model in panel at {x0}");
            assert!(count(&canvas, x0, orange) > 200, "hand in panel at {x0}");
            assert!(count(&canvas, x0, red) >= 20, "contact in panel at {x0}");
        }
    }

    #[test]
    fn the_nearer_solid_hides_the_farther() {
        // From the side (+y), a hand cube in front of the model at the same height
        // hides the model's centre.
        let mut s = scene();
        s.solids[2] = cube(Part::Hand, [0.6, 0.12, 0.08], 0.06);
        s.contacts_m.clear();
        let canvas = render(&s);
        let (w, h) = PANEL_PX;
        let centre = canvas.pixel(w + 4 + w / 2, h / 2);
        assert!(centre[0] > centre[2], "hand in front: {centre:?}");
    }
}
