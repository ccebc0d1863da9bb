//! Procedural category models and OBJ files: closed, outward, in range, varied,
//! deterministic; OBJ round trip and errors.

use graspcell::mesh::obj::{read_obj, write_obj};
use graspcell::mesh::procedural::{generate, instance_seed, Category, HandleShape, Params};
use graspcell::mesh::topology::{
    bounding_box, edge_report, euler_characteristic, self_intersections, signed_volume,
};
use graspcell::mesh::{MeshError, TriMesh};
use std::f64::consts::PI;
use std::path::PathBuf;

/// A fresh directory for one test, removed by the test.
fn temp_dir(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("graspcell-objects-{name}-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

fn within(value: f64, lo: f64, hi: f64) -> bool {
    (lo - 1e-12..=hi + 1e-12).contains(&value)
}

#[test]
fn print_stats() {
    for c in Category::ALL {
        for i in 0..4 {
            let (mesh, params) = generate(c, instance_seed(7, i));
            let (lo, hi) = bounding_box(&mesh).unwrap();
            println!(
                "{c} {i}: {} tris, vol {:.3e}, chi {}, {:?} lo {:?} hi {:?} {:?}",
                mesh.triangles.len(),
                signed_volume(&mesh),
                euler_characteristic(&mesh),
                edge_report(&mesh),
                lo,
                hi,
                params
            );
        }
    }
}
