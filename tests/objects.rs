//! Procedural category models and OBJ files: closed, outward, in range, varied,
//! deterministic; OBJ round trip and errors; `cell objects generate`.

use clap::Parser;
use graspcell::cli::{run, Cli};
use graspcell::fsio::TempDir;
use graspcell::mesh::obj::{parse_obj, read_obj, write_obj};
use graspcell::mesh::procedural::held_apart::{generate_in, held_apart_instance, Family};
use graspcell::mesh::procedural::{
    generate, instance_seed, Category, HandleShape, MugParams, Params,
};
use graspcell::mesh::topology::{
    bounding_box, edge_report, euler_characteristic, self_intersections, signed_volume,
};
use graspcell::mesh::{MeshError, TriMesh};
use std::f64::consts::PI;
use std::path::Path;

/// `lo <= value <= hi` (a rounding margin of 1e-12 m).
fn within(value: f64, lo: f64, hi: f64) -> bool {
    (lo - 1e-12..=hi + 1e-12).contains(&value)
}

fn size(mesh: &TriMesh) -> [f64; 3] {
    let (lo, hi) = bounding_box(mesh).unwrap();
    [hi.x - lo.x, hi.y - lo.y, hi.z - lo.z]
}

/// Volume of a truncated cone of height `h` and end radii `r0`, `r1`.
fn frustum(h: f64, r0: f64, r1: f64) -> f64 {
    PI * h / 3.0 * (r0 * r0 + r0 * r1 + r1 * r1)
}

/// Checks one mug against the ranges, from its parameters and its mesh.
fn check_mug(p: &MugParams, mesh: &TriMesh, what: &str) {
    assert!(within(p.height_m, 0.070, 0.120), "{what}: {p:?}");
    assert!(within(p.radius_top_m, 0.035, 0.050), "{what}: {p:?}");
    let taper = p.radius_bottom_m / p.radius_top_m;
    assert!(taper == 1.0 || within(taper, 0.78, 0.92), "{what}: {p:?}");
    assert!(within(p.wall_thickness_m, 0.003, 0.006), "{what}: {p:?}");
    assert!(within(p.bottom_thickness_m, 0.004, 0.008), "{what}: {p:?}");
    assert!(
        within(p.bottom_fillet_radius_m, 0.003, 0.010),
        "{what}: {p:?}"
    );
    let (lo, hi) = bounding_box(mesh).unwrap();
    // Standing on the table, as tall as stated, round about the z axis.
    assert!(
        lo.z.abs() < 1e-12 && (hi.z - p.height_m).abs() < 1e-9,
        "{what}: {lo} {hi}"
    );
    let rim_radius = p.radius_bottom_m
        + (p.radius_top_m - p.radius_bottom_m) * (1.0 - p.wall_thickness_m / 2.0 / p.height_m);
    assert!(
        within(hi.y, rim_radius * (PI / 60.0).cos(), rim_radius),
        "{what}: {hi}"
    );
    assert!(
        within(-lo.y, rim_radius * (PI / 60.0).cos(), rim_radius),
        "{what}: {lo}"
    );
    assert!(
        within(-lo.x, rim_radius * (PI / 60.0).cos(), rim_radius),
        "{what}: {lo}"
    );
    // Hollow: the volume is the wall's, not the solid's (fillets and rim round
    // off a little; a handle adds a little).
    let t = p.wall_thickness_m;
    let body = frustum(p.height_m, p.radius_bottom_m, p.radius_top_m);
    let inner_at =
        |z: f64| p.radius_bottom_m + (p.radius_top_m - p.radius_bottom_m) * z / p.height_m - t;
    let cavity = frustum(
        p.height_m - p.bottom_thickness_m,
        inner_at(p.bottom_thickness_m),
        inner_at(p.height_m),
    );
    let shell = body - cavity;
    let volume = signed_volume(mesh);
    assert!(
        volume > 0.8 * shell && volume < 1.25 * shell,
        "{what}: {volume} vs shell {shell}"
    );
    match &p.handle {
        Some(h) => {
            assert!(within(h.width_m, 0.008, 0.016), "{what}: {h:?}");
            assert!(within(h.thickness_m, 0.006, 0.012), "{what}: {h:?}");
            assert!(within(h.clearance_m, 0.015, 0.030), "{what}: {h:?}");
            assert!(
                h.lower_z_m - h.thickness_m / 2.0 > p.bottom_fillet_radius_m,
                "{what}: {h:?}"
            );
            assert!(
                h.upper_z_m + h.thickness_m / 2.0 < p.height_m - t,
                "{what}: {h:?}"
            );
            // The handle's outside is clearance + thickness beyond the wall at mid-height.
            let zm = (h.lower_z_m + h.upper_z_m) / 2.0;
            let wall = inner_at(zm) + t;
            let reach = hi.x - wall;
            let expected = h.clearance_m + h.thickness_m;
            assert!(
                (reach - expected).abs() < 1.5e-3,
                "{what}: reach {reach} vs {expected}"
            );
            // One tunnel: a genus-1 surface.
            assert_eq!(euler_characteristic(mesh), 0, "{what}");
        }
        None => {
            assert!(hi.x <= rim_radius + 1e-12, "{what}: {hi}");
            assert_eq!(euler_characteristic(mesh), 2, "{what}");
        }
    }
}

fn check_in_range(params: &Params, mesh: &TriMesh, what: &str) {
    let [sx, sy, sz] = size(mesh);
    let (lo, hi) = bounding_box(mesh).unwrap();
    match params {
        Params::Mug(p) => check_mug(p, mesh, what),
        Params::Bottle(p) => {
            assert!(within(p.height_m, 0.18, 0.32), "{what}: {p:?}");
            assert!(within(p.body_radius_m, 0.030, 0.045), "{what}: {p:?}");
            assert!(within(p.neck_radius_m, 0.010, 0.016), "{what}: {p:?}");
            assert!(within(p.neck_length_m, 0.02, 0.07), "{what}: {p:?}");
            assert!(within(p.shoulder_height_m, 0.02, 0.07), "{what}: {p:?}");
            assert!(p.body_height_m >= 0.5 * p.height_m - 1e-12, "{what}: {p:?}");
            let sum = p.body_height_m + p.shoulder_height_m + p.neck_length_m;
            assert!((sum - p.height_m).abs() < 1e-12, "{what}: {p:?}");
            assert!(
                lo.z.abs() < 1e-12 && (sz - p.height_m).abs() < 1e-9,
                "{what}: {sz}"
            );
            assert!(
                within(
                    sx / 2.0,
                    p.body_radius_m * (PI / 64.0).cos(),
                    p.body_radius_m
                ),
                "{what}"
            );
            // Solid: between the body cylinder and the full-height cylinder.
            let v = signed_volume(mesh);
            let r2 = PI * p.body_radius_m * p.body_radius_m;
            assert!(
                v > 0.95 * r2 * p.body_height_m && v < r2 * p.height_m,
                "{what}: {v}"
            );
            assert_eq!(euler_characteristic(mesh), 2, "{what}");
        }
        Params::Hammer(p) => {
            assert!(within(p.head_length_m, 0.09, 0.14), "{what}: {p:?}");
            assert!(within(p.head_section_m, 0.022, 0.032), "{what}: {p:?}");
            assert!(within(p.handle_length_m, 0.22, 0.34), "{what}: {p:?}");
            assert!(within(p.handle_width_m, 0.024, 0.034), "{what}: {p:?}");
            assert!(
                within(p.handle_thickness_m / p.head_section_m, 0.55, 0.70),
                "{what}: {p:?}"
            );
            // Lying on its side: head along y, handle along +x, footprint centred.
            assert!((sy - p.head_length_m).abs() < 1e-9, "{what}: {sy}");
            assert!((sz - p.head_section_m).abs() < 1e-9, "{what}: {sz}");
            let length = p.head_section_m + p.handle_length_m;
            assert!((sx - length).abs() < 2e-3, "{what}: {sx} vs {length}");
            assert!(
                (lo.x + hi.x).abs() < 1e-12 && (lo.y + hi.y).abs() < 1e-12 && lo.z.abs() < 1e-12
            );
            assert_eq!(euler_characteristic(mesh), 2, "{what}");
        }
        Params::Knife(p) => {
            assert!(within(p.blade_length_m, 0.08, 0.20), "{what}: {p:?}");
            assert!(within(p.blade_width_m, 0.018, 0.045), "{what}: {p:?}");
            assert!(within(p.blade_thickness_m, 0.0015, 0.003), "{what}: {p:?}");
            assert!(within(p.handle_length_m, 0.09, 0.13), "{what}: {p:?}");
            assert!(within(p.handle_width_m, 0.018, 0.026), "{what}: {p:?}");
            assert!(within(p.handle_thickness_m, 0.012, 0.020), "{what}: {p:?}");
            let length = p.blade_length_m + p.bolster_length_m + p.handle_length_m;
            assert!((sx - length).abs() < 1e-9, "{what}: {sx} vs {length}");
            let width = p.handle_width_m.max(p.blade_width_m);
            assert!((sy - width).abs() < 1e-9, "{what}: {sy} vs {width}");
            assert!((sz - p.handle_thickness_m).abs() < 1e-9, "{what}: {sz}");
            assert!(
                (lo.x + hi.x).abs() < 1e-12 && (lo.y + hi.y).abs() < 1e-12 && lo.z.abs() < 1e-12
            );
            assert_eq!(euler_characteristic(mesh), 2, "{what}");
        }
    }
}

#[test]
fn instances_are_watertight_outward_and_in_range() {
    for category in Category::ALL {
        let count = if category == Category::Mug { 24 } else { 10 };
        for i in 0..count {
            let seed = instance_seed(7, i);
            let what = format!("{category} {i} (seed {seed})");
            let (mesh, params) = generate(category, seed);
            assert_eq!(params.category(), category);
            mesh.validate(Path::new(&what)).unwrap();
            let report = edge_report(&mesh);
            assert!(report.is_watertight(), "{what}: {report:?}");
            assert!(signed_volume(&mesh) > 0.0, "{what}: inward");
            check_in_range(&params, &mesh, &what);
        }
    }
}

#[test]
fn surfaces_do_not_pass_through_themselves() {
    // The handle meets the body only at its stitched ends; no tube folds over.
    let mut checked = 0;
    for category in Category::ALL {
        for i in 0..3 {
            let (mesh, _) = generate(category, instance_seed(11, i));
            assert_eq!(self_intersections(&mesh), Some(0), "{category} {i}");
            checked += 1;
        }
    }
    // Every handle shape, with the thickest handle the ranges allow.
    for (i, shape) in [
        HandleShape::TorusArc,
        HandleShape::DShape,
        HandleShape::SquareIsh,
    ]
    .into_iter()
    .enumerate()
    {
        let mug = (0..200)
            .map(|k| generate(Category::Mug, instance_seed(12 + i as u64, k)).1)
            .find_map(|p| match p {
                Params::Mug(m) if m.handle.as_ref().is_some_and(|h| h.shape == shape) => Some(m),
                _ => None,
            })
            .expect("every handle shape occurs");
        assert_eq!(self_intersections(&mug.build()), Some(0), "{shape:?}");
        checked += 1;
    }
    assert_eq!(checked, 15);
}

#[test]
fn mugs_vary_in_body_and_handle() {
    let mugs: Vec<MugParams> = (0..60)
        .map(|i| match generate(Category::Mug, instance_seed(3, i)).1 {
            Params::Mug(m) => m,
            other => panic!("{other:?}"),
        })
        .collect();
    let handleless = mugs.iter().filter(|m| m.handle.is_none()).count();
    // About one in six: 10 expected of 60.
    assert!(
        (3..=20).contains(&handleless),
        "{handleless} of 60 without a handle"
    );
    for shape in [
        HandleShape::TorusArc,
        HandleShape::DShape,
        HandleShape::SquareIsh,
    ] {
        let n = mugs
            .iter()
            .filter(|m| m.handle.as_ref().is_some_and(|h| h.shape == shape))
            .count();
        assert!(n >= 5, "{shape:?}: {n}");
    }
    let tapered = mugs
        .iter()
        .filter(|m| m.radius_bottom_m < m.radius_top_m)
        .count();
    assert!((10..=50).contains(&tapered), "{tapered} tapered");
    let spread = |f: &dyn Fn(&MugParams) -> Option<f64>| {
        let v: Vec<f64> = mugs.iter().filter_map(f).collect();
        v.iter().cloned().fold(f64::MIN, f64::max) - v.iter().cloned().fold(f64::MAX, f64::min)
    };
    assert!(spread(&|m| Some(m.height_m)) > 0.035);
    assert!(spread(&|m| m.handle.as_ref().map(|h| h.thickness_m)) > 0.004);
    assert!(spread(&|m| m.handle.as_ref().map(|h| h.width_m)) > 0.005);
    assert!(spread(&|m| m.handle.as_ref().map(|h| h.upper_z_m - h.lower_z_m)) > 0.02);
    assert!(spread(&|m| m.handle.as_ref().map(|h| h.lower_z_m)) > 0.01);
}

#[test]
fn generation_is_deterministic_and_instances_differ() {
    for category in Category::ALL {
        let (a, pa) = generate(category, 42);
        let (b, pb) = generate(category, 42);
        assert_eq!(a, b, "{category}: same seed, different mesh");
        assert_eq!(pa, pb);
        let sizes: Vec<[f64; 3]> = (0..7)
            .map(|i| size(&generate(category, instance_seed(1, i)).0))
            .collect();
        let params: Vec<Params> = (0..7)
            .map(|i| generate(category, instance_seed(1, i)).1)
            .collect();
        for i in 0..7 {
            for j in i + 1..7 {
                assert_ne!(params[i], params[j], "{category} {i} and {j}");
                let differ = (0..3).any(|k| (sizes[i][k] - sizes[j][k]).abs() > 1e-4);
                assert!(
                    differ,
                    "{category} {i} and {j}: {:?} {:?}",
                    sizes[i], sizes[j]
                );
            }
        }
    }
}

#[test]
fn obj_round_trip_is_exact() {
    let dir = TempDir::new("objects-round-trip").unwrap();
    for category in Category::ALL {
        let (mesh, _) = generate(category, 5);
        let path = dir.join(format!("{category}.obj"));
        write_obj(&path, &mesh).unwrap();
        let back = read_obj(&path).unwrap();
        assert_eq!(back.triangles, mesh.triangles);
        assert_eq!(back.vertices.len(), mesh.vertices.len());
        for (a, b) in back.vertices.iter().zip(&mesh.vertices) {
            for k in 0..3 {
                assert_eq!(a[k].to_bits(), b[k].to_bits());
            }
        }
    }
    // No temporary files are left beside the outputs.
    let names: Vec<String> = std::fs::read_dir(&dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    assert_eq!(names.len(), 4, "{names:?}");
}

#[test]
fn truncated_and_malformed_obj_files_name_file_and_line() {
    let dir = TempDir::new("objects-truncated").unwrap();
    let (mesh, _) = generate(Category::Mug, 9);
    let path = dir.join("mug.obj");
    write_obj(&path, &mesh).unwrap();
    let text = std::fs::read_to_string(&path).unwrap();
    let lines: Vec<&str> = text.lines().collect();

    // Cut inside the last face, after two corners.
    let last = lines.len();
    let face: Vec<&str> = lines[last - 1].split(' ').collect();
    let cut = format!(
        "{}\n{} {} {}",
        lines[..last - 1].join("\n"),
        face[0],
        face[1],
        face[2]
    );
    let bad = dir.join("cut_face.obj");
    std::fs::write(&bad, cut).unwrap();
    let err = read_obj(&bad).unwrap_err().to_string();
    assert!(
        err.contains("cut_face.obj") && err.contains(&format!("line {last}:")),
        "{err}"
    );
    assert!(err.contains("2 corners"), "{err}");

    // Cut inside a vertex line, after two coordinates: the faces are gone too.
    let v_line = 1 + mesh.vertices.len() / 2;
    let coords: Vec<&str> = lines[v_line].split(' ').collect();
    let cut = format!(
        "{}\n{} {} {}",
        lines[..v_line].join("\n"),
        coords[0],
        coords[1],
        coords[2]
    );
    let bad = dir.join("cut_vertex.obj");
    std::fs::write(&bad, cut).unwrap();
    let err = read_obj(&bad).unwrap_err().to_string();
    assert!(
        err.contains("cut_vertex.obj") && err.contains(&format!("line {}:", v_line + 1)),
        "{err}"
    );

    // Faces kept but half the vertices lost: an index out of range, with its line.
    let mut kept: Vec<&str> = lines[..1 + mesh.vertices.len() / 2].to_vec();
    kept.extend(&lines[1 + mesh.vertices.len()..]);
    let bad = dir.join("lost_vertices.obj");
    std::fs::write(&bad, kept.join("\n")).unwrap();
    let err = read_obj(&bad).unwrap_err().to_string();
    assert!(
        err.contains("lost_vertices.obj") && err.contains("but the file has only"),
        "{err}"
    );

    // Cutting anywhere never panics: either a valid prefix or a named error.
    for k in 1..40 {
        let at = text.len() * k / 40;
        let at = (0..=at).rev().find(|&i| text.is_char_boundary(i)).unwrap();
        match parse_obj(&text.as_bytes()[..at], Path::new("prefix.obj")) {
            Ok(m) => assert!(m.validate(Path::new("prefix.obj")).is_ok()),
            Err(e) => assert!(e.to_string().contains("prefix.obj"), "{e}"),
        }
    }

    // Empty, and NaN written as a number.
    let empty = dir.join("empty.obj");
    std::fs::write(&empty, "# nothing here\n").unwrap();
    assert!(matches!(read_obj(&empty), Err(MeshError::Empty { .. })));
    let nan = dir.join("nan.obj");
    std::fs::write(&nan, "v 0 0 0\nv 1 NaN 0\nv 0 1 0\nf 1 2 3\n").unwrap();
    let err = read_obj(&nan).unwrap_err().to_string();
    assert!(err.contains("nan.obj") && err.contains("line 2"), "{err}");
    // A missing file and an unwritable destination are named.
    let err = read_obj(&dir.join("absent.obj")).unwrap_err().to_string();
    assert!(err.contains("absent.obj"), "{err}");
    let err = write_obj(&dir.join("no/such/dir/x.obj"), &mesh)
        .unwrap_err()
        .to_string();
    assert!(err.contains("x.obj"), "{err}");
}

#[test]
fn cli_generates_meshes_and_params() {
    let dir = TempDir::new("objects-cli").unwrap();
    // `cell objects generate --category mug --out DIR` with `extra`.
    let generate_mugs = |out: &Path, extra: &[&str]| {
        let mut args = vec!["cell", "objects", "generate", "--category", "mug"];
        args.extend_from_slice(extra);
        args.extend(["--out", out.to_str().unwrap()]);
        run(Cli::try_parse_from(args).unwrap()).unwrap();
    };
    let out = dir.join("mugs");
    generate_mugs(&out, &["--count", "3", "--seed", "1", "--json"]);
    let listing: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("params.json")).unwrap()).unwrap();
    assert_eq!(listing["category"], "mug");
    assert_eq!(listing["count"], 3);
    for i in 0..3 {
        let entry = &listing["instances"][i];
        let seed = instance_seed(1, i as u64);
        assert_eq!(entry["seed"].as_u64(), Some(seed));
        assert_eq!(entry["file"], format!("mug_{i:03}.obj"));
        assert_eq!(entry["params"]["category"], "mug");
        let mesh = read_obj(&out.join(format!("mug_{i:03}.obj"))).unwrap();
        assert!(edge_report(&mesh).is_watertight());
        // The file holds the instance its seed generates.
        assert_eq!(mesh.triangles, generate(Category::Mug, seed).0.triangles);
        let height = entry["params"]["height_m"].as_f64().unwrap();
        assert!((size(&mesh)[2] - height).abs() < 1e-9);
    }
    // The held-apart family: the objects of `cell eval novel`, named as its
    // trials name them.
    let held = dir.join("held");
    generate_mugs(&held, &["--count", "2", "--family", "held-apart"]);
    let listing: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(held.join("params.json")).unwrap()).unwrap();
    assert_eq!(listing["family"], "held-apart");
    for i in 0..2u64 {
        let (name, seed) = held_apart_instance(Category::Mug, 1, i);
        let entry = &listing["instances"][i as usize];
        assert_eq!(entry["file"], format!("{name}.obj"));
        assert_eq!(entry["seed"].as_u64(), Some(seed));
        let mesh = read_obj(&held.join(format!("{name}.obj"))).unwrap();
        assert_eq!(
            mesh.triangles,
            generate_in(Family::HeldApart, Category::Mug, seed)
                .0
                .triangles
        );
    }
    let bad = Cli::try_parse_from([
        "cell",
        "objects",
        "generate",
        "--category",
        "cup",
        "--out",
        "x",
    ]);
    assert!(bad.unwrap_err().to_string().contains("cup"));
}
