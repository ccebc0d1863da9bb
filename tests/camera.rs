//! The simulated depth camera: points of known shapes lie on their visible
//! surfaces within the noise model; dropouts follow the geometry; frames are
//! seeded; scene files and `cell camera render`.

use clap::Parser;
use graspcell::cli::{run, Cli};
use graspcell::config::CellConfig;
use graspcell::fsio::TempDir;
use graspcell::geometry::{look_at_optical, pose_from_params, Pose};
use graspcell::mesh::obj::write_obj;
use graspcell::mesh::procedural::{generate, Category};
use graspcell::mesh::topology::bounding_box;
use graspcell::mesh::TriMesh;
use graspcell::sim::camera::{DepthCamera, DepthFrame, NoiseModel, Return, Surface};
use graspcell::sim::scene::{load_scene, Scene, TableBox};
use nalgebra::{Point3, Vector3};
use std::f64::consts::PI;
use std::path::{Path, PathBuf};

fn config_path() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("robot/cell.toml")
}

fn config() -> CellConfig {
    CellConfig::load(&config_path()).unwrap()
}

/// A latitude-longitude sphere of radius `r` about the origin, outward winding.
fn uv_sphere(r: f64, rings: usize, segments: usize) -> TriMesh {
    let mut vertices = vec![Point3::new(0.0, 0.0, -r)];
    for i in 1..rings {
        let polar = PI * i as f64 / rings as f64;
        for j in 0..segments {
            let a = 2.0 * PI * j as f64 / segments as f64;
            vertices.push(Point3::new(
                r * polar.sin() * a.cos(),
                r * polar.sin() * a.sin(),
                -r * polar.cos(),
            ));
        }
    }
    vertices.push(Point3::new(0.0, 0.0, r));
    let top = (vertices.len() - 1) as u32;
    let id = |i: usize, j: usize| (1 + (i - 1) * segments + j % segments) as u32;
    let mut triangles = Vec::new();
    for j in 0..segments {
        triangles.push([0, id(1, j + 1), id(1, j)]);
        triangles.push([id(rings - 1, j), id(rings - 1, j + 1), top]);
    }
    for i in 1..rings - 1 {
        for j in 0..segments {
            let (a, b, c, d) = (id(i, j), id(i, j + 1), id(i + 1, j + 1), id(i + 1, j));
            triangles.push([a, b, c]);
            triangles.push([a, c, d]);
        }
    }
    TriMesh {
        vertices,
        triangles,
    }
}

/// An axis-aligned box of half sizes `h` about the origin, outward winding.
fn cuboid(h: [f64; 3]) -> TriMesh {
    let vertices = (0..8)
        .map(|k| {
            Point3::new(
                if k & 1 == 0 { -h[0] } else { h[0] },
                if k & 2 == 0 { -h[1] } else { h[1] },
                if k & 4 == 0 { -h[2] } else { h[2] },
            )
        })
        .collect();
    let triangles = vec![
        [0, 2, 3],
        [0, 3, 1], // -z
        [4, 5, 7],
        [4, 7, 6], // +z
        [0, 1, 5],
        [0, 5, 4], // -y
        [2, 6, 7],
        [2, 7, 3], // +y
        [0, 4, 6],
        [0, 6, 2], // -x
        [1, 3, 7],
        [1, 7, 5], // +x
    ];
    TriMesh {
        vertices,
        triangles,
    }
}

/// Pixel `i`'s ray (optical frame, z = 1) and its measured point, if valid.
fn pixel(frame: &DepthFrame, i: usize) -> (Vector3<f64>, Option<Point3<f64>>) {
    let intr = &frame.intrinsics;
    let (u, v) = (i % intr.width_px as usize, i / intr.width_px as usize);
    let ray = Vector3::new(
        (u as f64 - intr.cx_px) / intr.fx_px,
        (v as f64 - intr.cy_px) / intr.fy_px,
        1.0,
    );
    let z = frame.depth_m[i];
    (ray, z.is_finite().then(|| Point3::from(ray * z as f64)))
}

/// The largest depth error the Kinect model allows at 4 sigma: noise plus half a
/// quantisation step, `4 (1.5e-3 z^2) + z^2 / (2 * 8 * 525 * 0.075)`.
fn depth_bound(z: f64) -> f64 {
    4.0 * 1.5e-3 * z * z + 1.01 * z * z / (2.0 * 8.0 * 525.0 * 0.075)
}

/// Depth of the first intersection of the optical-frame ray `ray` (z = 1) with
/// the sphere of centre `c` and radius `r`.
fn sphere_depth(ray: &Vector3<f64>, c: &Vector3<f64>, r: f64) -> Option<f64> {
    let (a, b, k) = (ray.norm_squared(), ray.dot(c), c.norm_squared() - r * r);
    let disc = b * b - a * k;
    (disc >= 0.0).then(|| (b - disc.sqrt()) / a)
}

#[test]
fn sphere_points_lie_on_its_visible_surface_within_the_noise_model() {
    let config = config();
    let camera = DepthCamera::from_config(&config.camera, config.base_from_camera());
    let (r, centre) = (0.06, Vector3::new(0.62, 0.04, 0.15));
    let mut scene = Scene::new(Some(TableBox::from(&config.table)));
    scene
        .add(
            "sphere",
            uv_sphere(r, 64, 128),
            Pose::translation(centre.x, centre.y, centre.z),
        )
        .unwrap();
    let frame = camera.render(&scene, 11);
    let camera_from_base = camera.base_from_camera.inverse();
    let c = (camera_from_base * Point3::from(centre)).coords;
    let eye = camera.base_from_camera.translation.vector;
    // Mesh facets lie inside the true sphere by at most r (1 - cos(pi/64)),
    // more along an oblique ray (the renderer drops rays beyond 78 deg).
    let facet = r * (1.0 - (PI / 64.0).cos()) / 78f64.to_radians().cos();

    let (mut within, mut total, mut far_side) = (0, 0, 0);
    let mut normalised = Vec::new();
    for i in 0..frame.depth_m.len() {
        if frame.surface[i] != Surface::Object(0) || frame.status[i] != Return::Valid {
            continue;
        }
        let (ray, point) = pixel(&frame, i);
        let p = point.unwrap();
        total += 1;
        let truth =
            sphere_depth(&ray, &c, r).expect("a valid sphere pixel whose ray misses the sphere");
        let error = p.z - truth;
        let bound = depth_bound(truth) + facet;
        // Distance from the surface is at most the error along the ray.
        let radial = ((p.coords - c).norm() - r).abs();
        if error.abs() <= bound && radial <= bound * ray.norm() {
            within += 1;
        }
        let sigma = 1.5e-3 * truth * truth;
        let step = truth * truth / (8.0 * 525.0 * 0.075);
        normalised.push(error / (sigma * sigma + step * step / 12.0).sqrt());
        // The outward normal at the point faces the camera.
        let base = camera.base_from_camera * p;
        let normal = (base.coords - centre) / r;
        if normal.dot(&(eye - base.coords).normalize()) <= 0.0 {
            far_side += 1;
        }
    }
    assert!(total > 2000, "only {total} sphere points");
    assert!(
        within as f64 >= 0.99 * total as f64,
        "{within} of {total} within 4 sigma"
    );
    assert_eq!(far_side, 0, "points on the far hemisphere");
    // The errors have the model's spread (noise plus uniform quantisation) and no bias.
    let n = normalised.len() as f64;
    let mean = normalised.iter().sum::<f64>() / n;
    let std = (normalised.iter().map(|e| (e - mean).powi(2)).sum::<f64>() / n).sqrt();
    assert!(mean.abs() < 0.1, "bias {mean} (in model sigmas)");
    assert!((0.8..1.2).contains(&std), "spread {std} model sigmas");

    // Coverage: pixels well inside the sphere's image, facing the camera, return.
    let intr = frame.intrinsics;
    let w = intr.width_px as usize;
    let (mut expected, mut returned) = (0, 0);
    for i in w..frame.depth_m.len() - w {
        let hits = [i, i - 1, i + 1, i - w, i + w]
            .iter()
            .all(|&k| sphere_depth(&pixel(&frame, k).0, &c, r).is_some());
        let (ray, _) = pixel(&frame, i);
        let Some(z) = sphere_depth(&ray, &c, r) else {
            continue;
        };
        let normal = (ray * z - c) / r;
        if hits && normal.dot(&-ray.normalize()) > 70f64.to_radians().cos() {
            expected += 1;
            if frame.status[i] == Return::Valid && frame.surface[i] == Surface::Object(0) {
                returned += 1;
            }
        }
    }
    assert!(
        expected > 2000 && returned == expected,
        "{returned} of {expected}"
    );
}

#[test]
fn box_points_lie_on_its_camera_facing_faces() {
    let config = config();
    let camera = DepthCamera::from_config(&config.camera, config.base_from_camera());
    let half = [0.05, 0.03, 0.04];
    let base_from_box = pose_from_params(&[0.6, -0.1, 0.14, 0.3, -0.2, 0.7]);
    let mut scene = Scene::new(Some(TableBox::from(&config.table)));
    scene.add("box", cuboid(half), base_from_box).unwrap();
    let frame = camera.render(&scene, 3);
    let box_from_base = base_from_box.inverse();
    let eye = box_from_base * Point3::from(camera.base_from_camera.translation.vector);
    // Faces (axis, side) with the camera outside their plane are visible.
    let faces: Vec<(usize, f64)> = (0..3).flat_map(|k| [(k, -1.0), (k, 1.0)]).collect();
    let visible: Vec<(usize, f64)> = faces
        .iter()
        .copied()
        .filter(|&(k, s)| s * eye[k] > half[k])
        .collect();
    let hidden: Vec<(usize, f64)> = faces
        .iter()
        .copied()
        .filter(|f| !visible.contains(f))
        .collect();
    assert!(visible.len() >= 2 && hidden.len() >= 3, "{visible:?}");
    // Distance from q (box frame) to the rectangle of face (k, s).
    let to_face = |q: &Point3<f64>, (k, s): (usize, f64)| {
        let mut d2 = (q[k] - s * half[k]).powi(2);
        for j in (0..3).filter(|&j| j != k) {
            d2 += (q[j].abs() - half[j]).max(0.0).powi(2);
        }
        d2.sqrt()
    };
    let (mut total, mut near_visible, mut on_hidden_only) = (0, 0, 0);
    let mut faces_seen = std::collections::HashSet::new();
    for i in 0..frame.depth_m.len() {
        if frame.surface[i] != Surface::Object(0) || frame.status[i] != Return::Valid {
            continue;
        }
        let (_, point) = pixel(&frame, i);
        let p = point.unwrap();
        let q = box_from_base * (camera.base_from_camera * p);
        let bound = depth_bound(p.z);
        let d_visible = visible
            .iter()
            .map(|&f| to_face(&q, f))
            .fold(f64::MAX, f64::min);
        let d_hidden = hidden
            .iter()
            .map(|&f| to_face(&q, f))
            .fold(f64::MAX, f64::min);
        total += 1;
        if d_visible <= bound {
            near_visible += 1;
        }
        if d_hidden < d_visible - 1e-9 && d_visible > bound {
            on_hidden_only += 1;
        }
        if let Some(&f) = visible.iter().find(|&&f| to_face(&q, f) <= bound) {
            faces_seen.insert(f.0 * 2 + (f.1 > 0.0) as usize);
        }
    }
    assert!(total > 1000, "only {total} box points");
    assert!(
        near_visible as f64 >= 0.99 * total as f64,
        "{near_visible} of {total}"
    );
    assert_eq!(on_hidden_only, 0);
    assert_eq!(
        faces_seen.len(),
        visible.len(),
        "every visible face returns points"
    );
}

#[test]
fn table_seen_from_above_returns_everywhere_at_its_height() {
    let config = config();
    let eye = Vector3::new(0.6, 0.0, 1.2);
    let camera = DepthCamera {
        base_from_camera: look_at_optical(eye, Vector3::new(0.6, 0.0, 0.0), Vector3::x()),
        ..DepthCamera::from_config(&config.camera, Pose::identity())
    };
    let table = TableBox {
        height_m: 0.1,
        center_xy_m: [0.6, 0.0],
        extent_xy_m: [4.0, 4.0],
        thickness_m: 0.05,
    };
    let frame = camera.render(&Scene::new(Some(table)), 1);
    assert_eq!(frame.valid_fraction(), 1.0);
    // Depth is 1.1 m everywhere; the error along the ray bounds the height error.
    // Of 307,200 Gaussian draws about 20 pass 4 sigma; none should pass 6.
    let six_sigma = 6.0 * 1.5e-3 * 1.1 * 1.1 + 1.01 * 1.1 * 1.1 / (2.0 * 8.0 * 525.0 * 0.075);
    let mut within = 0;
    for i in 0..frame.depth_m.len() {
        let (_, p) = pixel(&frame, i);
        let error = ((camera.base_from_camera * p.unwrap()).z - 0.1).abs();
        assert!(error <= six_sigma, "pixel {i}: height error {error}");
        within += (error <= depth_bound(1.1)) as usize;
    }
    assert!(
        within as f64 >= 0.999 * frame.depth_m.len() as f64,
        "{within}"
    );
    let cloud = frame.to_cloud();
    assert_eq!(
        (cloud.width, cloud.height, cloud.len()),
        (640, 480, 640 * 480)
    );
}

#[test]
fn grazing_rays_and_depth_edges_drop_out_where_the_geometry_says() {
    let config = config();
    // Low over a large table, looking far across it: incidence passes 78 deg.
    let eye = Vector3::new(0.0, 0.0, 0.45);
    let camera = DepthCamera {
        base_from_camera: look_at_optical(eye, Vector3::new(1.5, 0.0, 0.0), Vector3::z()),
        ..DepthCamera::from_config(&config.camera, Pose::identity())
    };
    let table = TableBox {
        height_m: 0.0,
        center_xy_m: [2.0, 0.0],
        extent_xy_m: [4.0, 6.0],
        thickness_m: 0.05,
    };
    let frame = camera.render(&Scene::new(Some(table)), 2);
    let limit = 78f64.to_radians();
    let (mut grazing, mut facing) = (0, 0);
    for i in 0..frame.depth_m.len() {
        let (ray, _) = pixel(&frame, i);
        let dir = camera.base_from_camera.rotation * ray;
        if dir.z >= 0.0 {
            continue;
        }
        // The table top's incidence angle along this ray, and its depth.
        let incidence = (dir.z.abs() / dir.norm()).acos();
        let depth = eye.z / -dir.z;
        let in_range = (0.5..=4.0).contains(&depth);
        if !in_range || frame.surface[i] != Surface::Table {
            continue;
        }
        if incidence > limit + 1e-6 {
            grazing += 1;
            assert_eq!(
                frame.status[i],
                Return::Grazing,
                "pixel {i}: {} deg",
                incidence.to_degrees()
            );
        } else if incidence < limit - 1e-6 {
            facing += 1;
            assert_ne!(
                frame.status[i],
                Return::Grazing,
                "pixel {i}: {} deg",
                incidence.to_degrees()
            );
        }
    }
    assert!(
        grazing > 1000 && facing > 1000,
        "{grazing} grazing, {facing} facing"
    );

    // A sphere floating over the table: every valid sphere pixel is surrounded
    // by sphere pixels (the silhouette, where depth jumps to the table, drops).
    let config_camera = DepthCamera::from_config(&config.camera, config.base_from_camera());
    let mut scene = Scene::new(Some(TableBox::from(&config.table)));
    scene
        .add(
            "sphere",
            uv_sphere(0.05, 32, 64),
            Pose::translation(0.65, 0.0, 0.2),
        )
        .unwrap();
    let frame = config_camera.render(&scene, 4);
    let w = frame.intrinsics.width_px as usize;
    let (mut silhouette, mut edges) = (0, 0);
    for i in w..frame.depth_m.len() - w {
        if frame.surface[i] != Surface::Object(0) {
            continue;
        }
        let boundary = [i - 1, i + 1, i - w, i + w]
            .iter()
            .any(|&k| frame.surface[k] != Surface::Object(0));
        if boundary {
            silhouette += 1;
            // Dropped: as an edge, or earlier as grazing (the rim of a sphere is both).
            assert!(
                matches!(frame.status[i], Return::Edge | Return::Grazing),
                "pixel {i}: {:?}",
                frame.status[i]
            );
            edges += (frame.status[i] == Return::Edge) as usize;
        }
    }
    assert!(
        silhouette > 50 && edges > 10,
        "{silhouette} silhouette, {edges} edges"
    );
}

#[test]
fn frames_are_determined_by_the_seed() {
    let config = config();
    let camera = DepthCamera::from_config(&config.camera, config.base_from_camera());
    let mut scene = Scene::new(Some(TableBox::from(&config.table)));
    let (mug, _) = generate(Category::Mug, 2);
    scene
        .add("mug", mug, Pose::translation(0.65, 0.0, 0.0))
        .unwrap();
    let bits = |f: &DepthFrame| f.depth_m.iter().map(|z| z.to_bits()).collect::<Vec<u32>>();
    let a = camera.render(&scene, 5);
    let b = camera.render(&scene, 5);
    assert_eq!(bits(&a), bits(&b));
    assert_eq!(a.status, b.status);
    let c = camera.render(&scene, 6);
    assert_eq!(
        a.status, c.status,
        "dropouts depend on geometry, not the seed"
    );
    let differing = a
        .depth_m
        .iter()
        .zip(&c.depth_m)
        .filter(|(x, y)| x.is_finite() && x != y)
        .count();
    let valid = a.depth_m.iter().filter(|z| z.is_finite()).count();
    // Quantisation steps are about twice the noise sigma, so two draws often land
    // on the same level; about half the depths differ.
    assert!(
        differing as f64 > 0.3 * valid as f64,
        "{differing} of {valid} differ"
    );
    // The ideal sensor has no noise at all: two seeds agree.
    let ideal = DepthCamera {
        noise: NoiseModel::ideal(),
        ..camera
    };
    assert_eq!(
        bits(&ideal.render(&scene, 1)),
        bits(&ideal.render(&scene, 2))
    );
}

fn write_scene(dir: &Path, text: &str) -> PathBuf {
    let path = dir.join("scene.toml");
    std::fs::write(&path, text).unwrap();
    path
}

#[test]
fn scene_files_load_meshes_and_name_what_is_wrong() {
    let config = config();
    let dir = TempDir::new("camera-scene").unwrap();
    // A millimetre OBJ file, scaled back to metres by the scene.
    let (mug, _) = generate(Category::Mug, 8);
    let mm = TriMesh {
        vertices: mug.vertices.iter().map(|v| v * 1000.0).collect(),
        triangles: mug.triangles.clone(),
    };
    std::fs::create_dir_all(dir.join("models")).unwrap();
    write_obj(&dir.join("models/mug_mm.obj"), &mm).unwrap();
    let path = write_scene(
        &dir,
        r#"
[[objects]]
mesh = "models/mug_mm.obj"
scale = 0.001
pose = { xyz = [0.6, 0.1, 0.0], rpy = [0.0, 0.0, 1.0] }

[[objects]]
category = "bottle"
seed = 4
pose = { xyz = [0.7, -0.1, 0.0] }
"#,
    );
    let loaded = load_scene(&path, &config).unwrap();
    assert_eq!(loaded.scene.objects.len(), 2);
    let (lo, hi) = bounding_box(&loaded.scene.objects[0].mesh).unwrap();
    let (lo0, hi0) = bounding_box(&mug).unwrap();
    assert!((lo - lo0).norm() < 1e-12 && (hi - hi0).norm() < 1e-12);
    assert_eq!(
        loaded.scene.objects[1].mesh,
        generate(Category::Bottle, 4).0
    );
    assert_eq!(loaded.base_from_camera, config.base_from_camera());
    assert_eq!(loaded.scene.table, Some(TableBox::from(&config.table)));
    let frame =
        DepthCamera::from_config(&config.camera, loaded.base_from_camera).render(&loaded.scene, 0);
    for k in 0..2 {
        assert!(
            frame.count(|r, s| r == Return::Valid && s == Surface::Object(k)) > 200,
            "object {k}"
        );
    }

    let cases = [
        (
            "[[objects]]\nmesh = \"models/absent.obj\"\npose = { xyz = [0.6, 0.0, 0.0] }\n",
            vec!["scene.toml", "objects[0]", "absent.obj"],
        ),
        (
            "[[objects]]\nmesh = \"models/mug_mm.obj\"\ncategory = \"mug\"\npose = { xyz = [0.6, 0.0, 0.0] }\n",
            vec!["objects[0]", "either mesh or category"],
        ),
        (
            "[[objects]]\ncategory = \"mug\"\npose = { xyz = [0.6, 0.0, 0.0] }\n",
            vec!["objects[0]", "needs a seed"],
        ),
        (
            "[[objects]]\ncategory = \"cup\"\nseed = 1\npose = { xyz = [0.6, 0.0, 0.0] }\n",
            vec!["scene.toml", "cup"],
        ),
        (
            "[[objects]]\nmesh = \"models/mug_mm.obj\"\nscale = -1.0\npose = { xyz = [0.6, 0.0, 0.0] }\n",
            vec!["objects[0]", "scale = -1"],
        ),
        (
            "[[objects]]\ncategory = \"mug\"\nseed = 1\nposition = [0.6, 0.0, 0.0]\npose = { xyz = [0.6, 0.0, 0.0] }\n",
            vec!["scene.toml", "position"],
        ),
        (
            "[table]\nheight_m = 0.0\ncenter_xy_m = [0.6, 0.0]\nextent_xy_m = [0.0, 1.0]\n",
            vec!["table.extent_xy_m[0]"],
        ),
        (
            "[[objects]]\ncategory = \"mug\"\nseed = 1\npose = { xyz = [0.6, 0.0, nan] }\n",
            vec!["objects[0].pose", "NaN"],
        ),
    ];
    for (text, words) in cases {
        let path = write_scene(&dir, text);
        let err = load_scene(&path, &config).unwrap_err().to_string();
        for word in words {
            assert!(err.contains(word), "{text}\n-> {err}\n(missing {word:?})");
        }
    }
    // A malformed mesh file is named with its line.
    std::fs::write(dir.join("models/broken.obj"), "v 0 0 0\nv 1 0 0\nv 0 1\n").unwrap();
    let path = write_scene(
        &dir,
        "[[objects]]\nmesh = \"models/broken.obj\"\npose = { xyz = [0.6, 0.0, 0.0] }\n",
    );
    let err = load_scene(&path, &config).unwrap_err().to_string();
    assert!(
        err.contains("broken.obj") && err.contains("line 3"),
        "{err}"
    );
    let err = load_scene(&dir.join("nowhere.toml"), &config)
        .unwrap_err()
        .to_string();
    assert!(err.contains("nowhere.toml"), "{err}");
}

#[test]
fn cli_renders_a_cloud_and_a_readable_depth_image() {
    let dir = TempDir::new("camera-cli").unwrap();
    let scene = write_scene(
        &dir,
        "[[objects]]\ncategory = \"mug\"\nseed = 1\npose = { xyz = [0.65, 0.0, 0.0], rpy = [0.0, 0.0, 1.2] }\n",
    );
    let (cloud, png) = (dir.join("cloud.ply"), dir.join("depth.png"));
    let cli = Cli::try_parse_from([
        "cell",
        "--config",
        config_path().to_str().unwrap(),
        "camera",
        "render",
        "--scene",
        scene.to_str().unwrap(),
        "--out",
        cloud.to_str().unwrap(),
        "--png",
        png.to_str().unwrap(),
        "--seed",
        "3",
        "--json",
    ])
    .unwrap();
    run(cli).unwrap();
    let bytes = std::fs::read(&cloud).unwrap();
    assert!(bytes.starts_with(b"ply\nformat binary_little_endian 1.0\n"));
    let back = graspcell::cloud::io::read_cloud(&cloud).unwrap();
    assert_eq!((back.width, back.height, back.len()), (640, 480, 307_200));
    assert!(
        back.points.iter().any(|p| p.x.is_nan()),
        "missing returns stay in place"
    );
    assert!(back.valid_points().count() > 100_000);
    let decoder = png::Decoder::new(std::fs::File::open(&png).unwrap());
    let reader = decoder.read_info().unwrap();
    let info = reader.info();
    assert_eq!((info.width, info.height), (640, 494));
    assert_eq!(info.color_type, png::ColorType::Rgb);

    let missing = Cli::try_parse_from([
        "cell",
        "--config",
        config_path().to_str().unwrap(),
        "camera",
        "render",
        "--scene",
        dir.join("absent.toml").to_str().unwrap(),
        "--out",
        dir.join("never.ply").to_str().unwrap(),
    ])
    .unwrap();
    let err = format!("{:#}", run(missing).unwrap_err());
    assert!(err.contains("absent.toml"), "{err}");
    assert!(!dir.join("never.ply").exists());
}

#[test]
fn frames_do_not_depend_on_the_thread_count() {
    let config = config();
    let camera = DepthCamera::from_config(&config.camera, config.base_from_camera());
    let mut scene = Scene::new(Some(TableBox::from(&config.table)));
    let (mug, _) = generate(Category::Mug, 3);
    scene
        .add("mug", mug, Pose::translation(0.65, 0.05, 0.0))
        .unwrap();
    let render_on = |threads: usize| {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap();
        pool.install(|| camera.render(&scene, 9))
    };
    let bits = |f: &DepthFrame| f.depth_m.iter().map(|z| z.to_bits()).collect::<Vec<u32>>();
    let one = render_on(1);
    assert!(one.valid_fraction() > 0.5);
    for threads in [2, 3] {
        let many = render_on(threads);
        assert_eq!(bits(&one), bits(&many), "{threads} threads");
        assert_eq!(one.status, many.status, "{threads} threads");
        assert_eq!(one.surface, many.surface, "{threads} threads");
    }
}

/// Pixels whose surface or status differ between two frames, and the largest
/// depth difference over the pixels valid in both (m).
fn frame_difference(a: &DepthFrame, b: &DepthFrame) -> (usize, f64) {
    let differing = (0..a.status.len())
        .filter(|&i| a.status[i] != b.status[i] || a.surface[i] != b.surface[i])
        .count();
    let largest = a
        .depth_m
        .iter()
        .zip(&b.depth_m)
        .filter(|(x, y)| x.is_finite() && y.is_finite())
        .map(|(x, y)| (x - y).abs() as f64)
        .fold(0.0, f64::max);
    (differing, largest)
}

#[test]
fn rasterised_objects_match_ray_casting_their_bvh() {
    // Several objects, one partly hiding another, from the configured camera:
    // the rasteriser and per-pixel BVH ray casts (the reference) see the same
    // surfaces with the same dropouts, and the same noise draws give the same
    // depths up to the last bits of the true depth (at most one disparity step
    // where those bits move a depth across a rounding boundary).
    let config = config();
    let camera = DepthCamera::from_config(&config.camera, config.base_from_camera());
    let mut scene = Scene::new(Some(TableBox::from(&config.table)));
    let (mug, _) = generate(Category::Mug, 5);
    scene
        .add(
            "mug",
            mug,
            pose_from_params(&[0.62, 0.02, 0.0, 0.0, 0.0, 2.0]),
        )
        .unwrap();
    scene
        .add(
            "sphere",
            uv_sphere(0.04, 24, 48),
            Pose::translation(0.75, 0.05, 0.05),
        )
        .unwrap();
    scene
        .add(
            "box",
            cuboid([0.05, 0.03, 0.04]),
            pose_from_params(&[0.55, -0.15, 0.04, 0.3, -0.2, 0.7]),
        )
        .unwrap();
    let raster = camera.render(&scene, 21);
    let cast = camera.render_ray_cast(&scene, 21);
    for k in 0..3 {
        let object = Surface::Object(k);
        assert!(
            raster.count(|r, s| s == object && r == Return::Valid) > 300,
            "object {k}"
        );
    }
    let (differing, largest) = frame_difference(&raster, &cast);
    let step = 1.01 * 1.3f64.powi(2) / (8.0 * 525.0 * 0.075);
    assert!(differing <= 3, "{differing} pixels differ");
    assert!(largest <= step, "depths differ by {largest} m");

    // An object reaching behind the camera (a large box around it) is ray cast
    // in either mode: every pixel sees its inside, the same both ways.
    let eye = camera.base_from_camera.translation.vector;
    let mut around = Scene::new(None);
    around
        .add(
            "room",
            cuboid([1.0, 1.0, 1.0]),
            Pose::translation(eye.x, eye.y, eye.z),
        )
        .unwrap();
    let raster = camera.render(&around, 3);
    let cast = camera.render_ray_cast(&around, 3);
    assert_eq!(
        raster.count(|_, s| s == Surface::Object(0)),
        raster.status.len()
    );
    assert_eq!(frame_difference(&raster, &cast), (0, 0.0));
}

#[test]
fn bench_render_reports_medians_and_a_one_thread_baseline() {
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_cell"))
        .arg("--config")
        .arg(config_path())
        .args(["bench", "render", "--repeats", "2", "--json"])
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{stderr}");
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(
        (v["width_px"].as_u64(), v["height_px"].as_u64()),
        (Some(640), Some(480))
    );
    for key in [
        "render_ms_median",
        "render_ms_median_one_thread",
        "table_only_ms_median",
    ] {
        assert!(v[key].as_f64().unwrap() > 0.0, "{key}: {v}");
    }
    assert_eq!(v["one_thread_frames_identical"], true, "{v}");
    for key in [
        "render_cpu_ms_median",
        "render_cpu_ms_median_one_thread",
        "ray_cast_ms_median",
    ] {
        assert!(v[key].as_f64().unwrap() > 0.0, "{key}: {v}");
    }
    // The rasteriser sees what the BVH ray casts see.
    assert!(v["ray_cast_agreement"].as_f64().unwrap() > 0.9999, "{v}");
    assert!(v["object_valid_fraction"].as_f64().unwrap() > 0.001, "{v}");
    assert_eq!(v["goal_ms"].as_f64(), Some(30.0));
}
