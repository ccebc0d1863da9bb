//! The simulated calibration rig: a sphere on a stalk mounted on the hand, the arm
//! that moves it ([`SimArm`]) and the depth camera that sees it ([`SimTargetCamera`]).
//!
//! The camera renders the table, the sphere and its stalk, and every collision
//! primitive of the arm and hand (boxes, cylinders, capsules and spheres as
//! triangle meshes) as occluders, from the camera's *true* mount with the sensor's
//! noise model. The true mount and the true sphere position on the flange are given
//! to the simulation only; the collector and the solver never see them.
//!
//! The arm is ideal: it reaches the commanded joints at once, and its flange pose is
//! the forward kinematics of them. Timeouts are accepted and never reached.

use super::collect::{ArmMover, CollectError, TargetCamera, TargetRig};
use crate::cloud::PointCloud;
use crate::config::CellConfig;
use crate::geometry::Pose;
use crate::mesh::TriMesh;
use crate::robot::description::Primitive;
use crate::robot::kinematics::ArmJoints;
use crate::robot::{HandPose, Robot};
use crate::sim::camera::{DepthCamera, DepthFrame};
use crate::sim::scene::{Scene, TableBox};
use nalgebra::{Isometry3, Point3, Translation3, UnitQuaternion, Vector3};
use std::f64::consts::{PI, TAU};
use std::sync::{Arc, Mutex};

/// A UV sphere of radius `r` centred on the origin.
pub fn uv_sphere(r: f64, rings: usize, segments: usize) -> TriMesh {
    let rings = rings.max(2);
    let segments = segments.max(3);
    let mut vertices = vec![Point3::new(0.0, 0.0, r)];
    for i in 1..rings {
        let theta = PI * i as f64 / rings as f64;
        for j in 0..segments {
            let phi = TAU * j as f64 / segments as f64;
            vertices.push(Point3::new(
                r * theta.sin() * phi.cos(),
                r * theta.sin() * phi.sin(),
                r * theta.cos(),
            ));
        }
    }
    vertices.push(Point3::new(0.0, 0.0, -r));
    let south = (vertices.len() - 1) as u32;
    let ring = |i: usize, j: usize| (1 + (i - 1) * segments + j % segments) as u32;
    let mut triangles = Vec::new();
    for j in 0..segments {
        triangles.push([0, ring(1, j), ring(1, j + 1)]);
        triangles.push([south, ring(rings - 1, j + 1), ring(rings - 1, j)]);
    }
    for i in 1..rings - 1 {
        for j in 0..segments {
            let (a, b, c, d) = (
                ring(i, j),
                ring(i, j + 1),
                ring(i + 1, j + 1),
                ring(i + 1, j),
            );
            triangles.push([a, d, c]);
            triangles.push([a, c, b]);
        }
    }
    TriMesh {
        vertices,
        triangles,
    }
}

/// A closed cylinder of `radius` along z from `z0` to `z1`.
pub fn cylinder(radius: f64, z0: f64, z1: f64, segments: usize) -> TriMesh {
    let segments = segments.max(3);
    let mut vertices = vec![Point3::new(0.0, 0.0, z0), Point3::new(0.0, 0.0, z1)];
    for j in 0..segments {
        let phi = TAU * j as f64 / segments as f64;
        let (x, y) = (radius * phi.cos(), radius * phi.sin());
        vertices.push(Point3::new(x, y, z0));
        vertices.push(Point3::new(x, y, z1));
    }
    let bottom = |j: usize| (2 + 2 * (j % segments)) as u32;
    let top = |j: usize| (3 + 2 * (j % segments)) as u32;
    let mut triangles = Vec::new();
    for j in 0..segments {
        triangles.push([0, bottom(j + 1), bottom(j)]);
        triangles.push([1, top(j), top(j + 1)]);
        triangles.push([bottom(j), bottom(j + 1), top(j + 1)]);
        triangles.push([bottom(j), top(j + 1), top(j)]);
    }
    TriMesh {
        vertices,
        triangles,
    }
}

/// An axis-aligned box with full side lengths `size`, centred on the origin.
pub fn cuboid(size: [f64; 3]) -> TriMesh {
    let h = Vector3::from(size) * 0.5;
    let vertices = (0..8)
        .map(|i| {
            Point3::new(
                if i & 1 == 0 { -h.x } else { h.x },
                if i & 2 == 0 { -h.y } else { h.y },
                if i & 4 == 0 { -h.z } else { h.z },
            )
        })
        .collect();
    let triangles = vec![
        [0, 2, 1],
        [1, 2, 3],
        [4, 5, 6],
        [5, 7, 6],
        [0, 1, 4],
        [1, 5, 4],
        [2, 6, 3],
        [3, 6, 7],
        [0, 4, 2],
        [2, 4, 6],
        [1, 3, 5],
        [3, 7, 5],
    ];
    TriMesh {
        vertices,
        triangles,
    }
}

/// Appends `b` to `a`.
fn merge(a: &mut TriMesh, b: TriMesh) {
    let offset = a.vertices.len() as u32;
    a.vertices.extend(b.vertices);
    a.triangles
        .extend(b.triangles.iter().map(|t| t.map(|i| i + offset)));
}

/// A triangle mesh of a URDF collision primitive, in the primitive's frame
/// (cylinders and capsules along z), faceted finely enough for occlusion.
pub fn primitive_mesh(primitive: &Primitive) -> TriMesh {
    match *primitive {
        Primitive::Box { size_m } => cuboid(size_m),
        Primitive::Cylinder { radius_m, length_m } => {
            cylinder(radius_m, -0.5 * length_m, 0.5 * length_m, 32)
        }
        Primitive::Capsule { radius_m, length_m } => {
            let mut mesh = cylinder(radius_m, -0.5 * length_m, 0.5 * length_m, 32);
            for z in [-0.5 * length_m, 0.5 * length_m] {
                merge(
                    &mut mesh,
                    uv_sphere(radius_m, 16, 32).transformed(&Isometry3::translation(0.0, 0.0, z)),
                );
            }
            mesh
        }
        Primitive::Sphere { radius_m } => uv_sphere(radius_m, 16, 32),
    }
}

/// A closed cylinder of `radius` from `a` to `b`.
fn cylinder_between(a: &Vector3<f64>, b: &Vector3<f64>, radius: f64) -> TriMesh {
    let axis = b - a;
    let rotation = UnitQuaternion::rotation_between(&Vector3::z(), &axis)
        .unwrap_or_else(|| UnitQuaternion::from_axis_angle(&Vector3::x_axis(), PI));
    cylinder(radius, 0.0, axis.norm(), 16)
        .transformed(&Isometry3::from_parts(Translation3::from(*a), rotation))
}

/// The simulated arm: reaches commanded joints at once; shares its joints with the
/// simulated camera, which renders the arm where it is.
#[derive(Debug, Clone)]
pub struct SimArm {
    robot: Arc<Robot>,
    joints: Arc<Mutex<ArmJoints>>,
}

impl SimArm {
    fn current(&self) -> ArmJoints {
        *self.joints.lock().unwrap_or_else(|e| e.into_inner())
    }
}

impl ArmMover for SimArm {
    fn move_to(&mut self, joints: &ArmJoints, _timeout_s: f64) -> Result<(), CollectError> {
        self.robot.check_limits(joints)?;
        *self.joints.lock().unwrap_or_else(|e| e.into_inner()) = *joints;
        Ok(())
    }

    fn joints(&mut self, _timeout_s: f64) -> Result<ArmJoints, CollectError> {
        Ok(self.current())
    }

    fn base_from_flange(&mut self, _timeout_s: f64) -> Result<Pose, CollectError> {
        Ok(self.robot.arm().flange_and_palm(&self.current()).0)
    }
}

/// The simulated depth camera at its true mount, looking at the table, the arm,
/// the hand and the calibration sphere where the [`SimArm`] has put them.
pub struct SimTargetCamera {
    camera: DepthCamera,
    scene: Scene,
    robot: Arc<Robot>,
    hand: HandPose,
    joints: Arc<Mutex<ArmJoints>>,
    /// (link index, scene object index) of every link with collision shapes.
    links: Vec<(usize, usize)>,
    sphere: usize,
    stalk: usize,
    flange_from_centre: Pose,
    seed: u64,
    frames: u64,
}

impl SimTargetCamera {
    /// The camera model rendering the frames (true mount, intrinsics, noise).
    pub fn camera(&self) -> &DepthCamera {
        &self.camera
    }

    /// The scene as last rendered: table, one object per robot link (named as in
    /// the URDF), the sphere and its stalk.
    pub fn scene(&self) -> &Scene {
        &self.scene
    }

    /// Renders the scene with the arm where it is now (the next frame's noise seed).
    pub fn frame(&mut self) -> DepthFrame {
        self.place();
        let frame = self
            .camera
            .render(&self.scene, self.seed.wrapping_add(self.frames));
        self.frames += 1;
        frame
    }

    /// Frames captured so far.
    pub fn frames(&self) -> u64 {
        self.frames
    }

    /// The sphere centre's true position in the base frame, now.
    pub fn true_centre_base(&self) -> Point3<f64> {
        let q = *self.joints.lock().unwrap_or_else(|e| e.into_inner());
        let flange = self.robot.arm().flange_and_palm(&q).0;
        Point3::from((flange * self.flange_from_centre).translation.vector)
    }

    fn place(&mut self) {
        let q = *self.joints.lock().unwrap_or_else(|e| e.into_inner());
        let poses = self.robot.link_poses(&q, &self.hand);
        for &(link, object) in &self.links {
            self.scene.objects[object].base_from_object = poses[link];
        }
        let flange = self.robot.arm().flange_and_palm(&q).0;
        self.scene.objects[self.sphere].base_from_object = flange * self.flange_from_centre;
        self.scene.objects[self.stalk].base_from_object = flange;
    }
}

impl TargetCamera for SimTargetCamera {
    fn capture(&mut self, _timeout_s: f64) -> Result<PointCloud, CollectError> {
        Ok(self.frame().to_cloud())
    }
}

/// What the simulation knows and the calibration must find.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SimTruth {
    /// The camera's true mount.
    pub base_from_camera: Pose,
    /// The true rig (sphere centre on the flange).
    pub rig: TargetRig,
}

impl SimTruth {
    /// The truth of an exact cell: the camera where the configuration says, the
    /// sphere where the rig says.
    pub fn exact(nominal_base_from_camera: Pose, nominal_rig: TargetRig) -> SimTruth {
        SimTruth {
            base_from_camera: nominal_base_from_camera,
            rig: nominal_rig,
        }
    }

    /// The truth of a cell whose camera is mounted `camera_error` off the nominal
    /// `base_from_camera` (its translation added, its rotation applied, both in the
    /// base frame) and whose sphere centre is `target_error_m` (flange frame) off the
    /// nominal rig's.
    pub fn with_errors(
        nominal_base_from_camera: &Pose,
        nominal_rig: TargetRig,
        camera_error: &Pose,
        target_error_m: &Vector3<f64>,
    ) -> SimTruth {
        SimTruth {
            base_from_camera: Isometry3::from_parts(
                Translation3::from(
                    nominal_base_from_camera.translation.vector + camera_error.translation.vector,
                ),
                camera_error.rotation * nominal_base_from_camera.rotation,
            ),
            rig: nominal_rig.with_centre(nominal_rig.flange_from_centre_m + target_error_m),
        }
    }

    /// How far the true camera mount is from `nominal_base_from_camera`: translation
    /// (m) and rotation (rad).
    pub fn camera_error_from(&self, nominal_base_from_camera: &Pose) -> (f64, f64) {
        crate::geometry::pose_error(&self.base_from_camera, nominal_base_from_camera)
    }
}

/// A simulated arm at `start` and a camera at the true mount seeing the true rig,
/// the hand in `hand`, noise seeded from `seed` (frame `k` uses `seed + k`).
pub fn simulated_rig(
    config: &CellConfig,
    robot: Arc<Robot>,
    truth: &SimTruth,
    hand: HandPose,
    start: ArmJoints,
    seed: u64,
) -> Result<(SimArm, SimTargetCamera), CollectError> {
    robot.check_limits(&start)?;
    let joints = Arc::new(Mutex::new(start));
    let mut scene = Scene::new(Some(TableBox::from(&config.table)));
    let scene_error = |e: crate::sim::scene::SceneError| CollectError::Device {
        device: "simulated camera",
        message: e.to_string(),
    };
    let mut links = Vec::new();
    for (index, link) in robot.description.links.iter().enumerate() {
        if link.shapes.is_empty() {
            continue;
        }
        let mut mesh = TriMesh::default();
        for shape in &link.shapes {
            merge(
                &mut mesh,
                primitive_mesh(&shape.primitive).transformed(&shape.link_from_shape),
            );
        }
        links.push((index, scene.objects.len()));
        scene
            .add(&link.name, mesh, Pose::identity())
            .map_err(scene_error)?;
    }
    let rig = truth.rig;
    let sphere = scene.objects.len();
    scene
        .add(
            "calibration sphere",
            uv_sphere(rig.radius_m, 48, 96),
            Pose::identity(),
        )
        .map_err(scene_error)?;
    let stalk = scene.objects.len();
    scene
        .add(
            "calibration stalk",
            cylinder_between(
                &rig.stalk_base_m,
                &rig.flange_from_centre_m,
                rig.stalk_radius_m,
            ),
            Pose::identity(),
        )
        .map_err(scene_error)?;
    let c = rig.flange_from_centre_m;
    let camera = SimTargetCamera {
        camera: DepthCamera::from_config(&config.camera, truth.base_from_camera),
        scene,
        robot: Arc::clone(&robot),
        hand,
        joints: Arc::clone(&joints),
        links,
        sphere,
        stalk,
        flange_from_centre: Isometry3::translation(c.x, c.y, c.z),
        seed,
        frames: 0,
    };
    Ok((SimArm { robot, joints }, camera))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mesh::topology::{is_watertight, signed_volume};

    #[test]
    fn the_truth_reproduces_the_configured_errors() {
        let nominal = Isometry3::from_parts(
            Translation3::new(0.6, -0.1, 1.2),
            UnitQuaternion::from_euler_angles(PI, 0.1, -0.4),
        );
        let rig = TargetRig::standard();
        let exact = SimTruth::exact(nominal, rig);
        let (dp, dr) = exact.camera_error_from(&nominal);
        assert!(dp == 0.0 && dr < 1e-12, "{dp} {dr}");
        let zero = SimTruth::with_errors(&nominal, rig, &Pose::identity(), &Vector3::zeros());
        assert_eq!(zero, exact);

        // 15 mm and 2° about an oblique axis; the sphere 7 mm off.
        let axis = Vector3::new(1.0, -2.0, 0.5).normalize();
        let camera_error = Isometry3::from_parts(
            Translation3::new(0.010, -0.005, 0.010),
            UnitQuaternion::from_scaled_axis(axis * 2f64.to_radians()),
        );
        let target_error = Vector3::new(0.003, -0.004, 0.005);
        let truth = SimTruth::with_errors(&nominal, rig, &camera_error, &target_error);
        let (dp, dr) = truth.camera_error_from(&nominal);
        assert!((dp - 0.015).abs() < 1e-12, "{dp}");
        assert!((dr.to_degrees() - 2.0).abs() < 1e-9, "{}", dr.to_degrees());
        // The error is in the base frame: true = error's rotation * nominal.
        let turn = truth.base_from_camera.rotation * nominal.rotation.inverse();
        assert!(turn.angle_to(&camera_error.rotation) < 1e-12);
        assert!(
            (truth.base_from_camera.translation.vector
                - nominal.translation.vector
                - camera_error.translation.vector)
                .norm()
                < 1e-15
        );
        assert!(
            (truth.rig.flange_from_centre_m - rig.flange_from_centre_m - target_error).norm()
                < 1e-15
        );
        assert_eq!(truth.rig.radius_m, rig.radius_m);
        assert_eq!(truth.rig.stalk_base_m, rig.stalk_base_m);
        assert_eq!(truth.rig.stalk_radius_m, rig.stalk_radius_m);
    }

    #[test]
    fn primitive_meshes_are_closed_with_the_right_volume() {
        let cases = [
            (
                Primitive::Box {
                    size_m: [0.1, 0.2, 0.3],
                },
                0.006,
                1e-12,
            ),
            (
                Primitive::Cylinder {
                    radius_m: 0.05,
                    length_m: 0.2,
                },
                PI * 0.05 * 0.05 * 0.2,
                0.01,
            ),
            (
                Primitive::Sphere { radius_m: 0.05 },
                4.0 / 3.0 * PI * 0.05f64.powi(3),
                0.03,
            ),
        ];
        for (primitive, volume, rel) in cases {
            let mesh = primitive_mesh(&primitive);
            assert!(is_watertight(&mesh), "{primitive:?}");
            let v = signed_volume(&mesh);
            assert!(
                ((v - volume) / volume).abs() < rel,
                "{primitive:?}: {v} vs {volume}"
            );
        }
        let fine = uv_sphere(0.04, 48, 96);
        assert!(is_watertight(&fine));
        // Every vertex on the sphere; faceting keeps the faces within 0.05 mm of it.
        assert!(fine
            .vertices
            .iter()
            .all(|v| (v.coords.norm() - 0.04).abs() < 1e-12));
        let v = signed_volume(&fine);
        assert!((v - 4.0 / 3.0 * PI * 0.04f64.powi(3)) / v < 0.005);
    }
}
