//! Triangle meshes: the object models of each category.

pub mod obj;
pub mod ply;
pub mod procedural;
pub mod stl;
pub mod topology;

use crate::fsio::FileError;
use crate::geometry::Pose;
use nalgebra::Point3;
use std::path::{Path, PathBuf};

/// An indexed triangle mesh in metres; triangles wind counter-clockwise seen from
/// outside, so normals point outward.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct TriMesh {
    /// Vertex positions (m).
    pub vertices: Vec<Point3<f64>>,
    /// Triangles as indices into `vertices`.
    pub triangles: Vec<[u32; 3]>,
}

/// Why a mesh cannot be encoded in a file format (it is larger than the format
/// counts).
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum EncodeError {
    /// More vertices than PLY `int` indices address.
    #[error("{vertices} vertices is more than PLY `int` indices address")]
    TooManyVertices {
        /// The number of vertices.
        vertices: usize,
    },
    /// More triangles than binary STL counts.
    #[error("{triangles} triangles is more than binary STL holds")]
    TooManyTriangles {
        /// The number of triangles.
        triangles: usize,
    },
    /// The PLY encoder refused the mesh's columns (boxed: it is large, and rare).
    #[error(transparent)]
    Ply(Box<crate::ply::EncodeError>),
}

impl From<crate::ply::EncodeError> for EncodeError {
    fn from(e: crate::ply::EncodeError) -> EncodeError {
        EncodeError::Ply(Box::new(e))
    }
}

/// Errors of reading, writing or validating a mesh; each names the file.
#[derive(Debug, thiserror::Error)]
pub enum MeshError {
    /// A file could not be read or written.
    #[error(transparent)]
    File(#[from] FileError),
    /// The file's content is malformed at `location` (e.g. "line 12", "face 7").
    #[error("{path}: {location}: {problem}")]
    Parse {
        /// The file.
        path: PathBuf,
        /// Where in the file.
        location: String,
        /// What is wrong.
        problem: String,
    },
    /// The mesh cannot be written in the file's format.
    #[error("{path}: mesh: {problem}")]
    Encode {
        /// The file that was to be written.
        path: PathBuf,
        /// Why the format cannot hold the mesh.
        problem: EncodeError,
    },
    /// The file's extension names no supported format.
    #[error("{path}: unsupported mesh format (use .obj, .stl or .ply)")]
    UnsupportedFormat {
        /// The file.
        path: PathBuf,
    },
    /// The mesh has no triangles (or no vertices).
    #[error("{path}: mesh is empty ({vertices} vertices, {triangles} triangles)")]
    Empty {
        /// The file.
        path: PathBuf,
        /// Number of vertices.
        vertices: usize,
        /// Number of triangles.
        triangles: usize,
    },
    /// A vertex coordinate is NaN or infinite.
    #[error("{path}: vertex {vertex} has a non-finite coordinate {value}")]
    NonFinite {
        /// The file.
        path: PathBuf,
        /// Zero-based vertex index.
        vertex: usize,
        /// The offending coordinate.
        value: f64,
    },
    /// A triangle refers to a vertex that does not exist.
    #[error("{path}: triangle {triangle} uses vertex {index}, but there are only {vertices}")]
    IndexOutOfRange {
        /// The file.
        path: PathBuf,
        /// Zero-based triangle index.
        triangle: usize,
        /// The offending index.
        index: u32,
        /// Number of vertices.
        vertices: usize,
    },
}

/// Mesh file formats, chosen by file extension.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum MeshFormat {
    /// Wavefront OBJ (`.obj`).
    Obj,
    /// STL, ASCII or binary (`.stl`; written binary).
    Stl,
    /// PLY, ASCII or binary (`.ply`; written binary little-endian).
    Ply,
}

impl MeshFormat {
    /// The format of `path` by its extension.
    pub fn from_path(path: &Path) -> Result<MeshFormat, MeshError> {
        match path
            .extension()
            .and_then(|e| e.to_str())
            .map(str::to_ascii_lowercase)
            .as_deref()
        {
            Some("obj") => Ok(MeshFormat::Obj),
            Some("stl") => Ok(MeshFormat::Stl),
            Some("ply") => Ok(MeshFormat::Ply),
            _ => Err(MeshError::UnsupportedFormat {
                path: path.to_path_buf(),
            }),
        }
    }

    /// The file extension, without the dot.
    pub fn extension(self) -> &'static str {
        match self {
            MeshFormat::Obj => "obj",
            MeshFormat::Stl => "stl",
            MeshFormat::Ply => "ply",
        }
    }
}

/// Reads an OBJ, STL or PLY mesh (by extension), scales it (`scale` = 0.001 for a
/// millimetre file) and validates it; errors name the file.
pub fn load_mesh(path: &Path, scale: f64) -> Result<TriMesh, MeshError> {
    if !(scale.is_finite() && scale > 0.0) {
        return Err(MeshError::Parse {
            path: path.to_path_buf(),
            location: "scale".into(),
            problem: format!("scale {scale} must be finite and > 0"),
        });
    }
    let mut mesh = match MeshFormat::from_path(path)? {
        MeshFormat::Obj => obj::read_obj(path)?,
        MeshFormat::Stl => stl::read_stl(path)?,
        MeshFormat::Ply => ply::read_ply_mesh(path)?,
    };
    if scale != 1.0 {
        for v in &mut mesh.vertices {
            v.coords *= scale;
        }
    }
    mesh.validate(path)?;
    Ok(mesh)
}

/// Writes a mesh in the format its extension names, atomically.
pub fn write_mesh(path: &Path, mesh: &TriMesh) -> Result<(), MeshError> {
    match MeshFormat::from_path(path)? {
        MeshFormat::Obj => obj::write_obj(path, mesh),
        MeshFormat::Stl => stl::write_stl(path, mesh),
        MeshFormat::Ply => ply::write_ply_mesh(path, mesh, crate::ply::Format::BinaryLittleEndian),
    }
}

impl TriMesh {
    /// Checks that the mesh is non-empty, finite and its indices in range;
    /// `source` names it in errors.
    pub fn validate(&self, source: &Path) -> Result<(), MeshError> {
        if self.vertices.is_empty() || self.triangles.is_empty() {
            return Err(MeshError::Empty {
                path: source.to_path_buf(),
                vertices: self.vertices.len(),
                triangles: self.triangles.len(),
            });
        }
        for (vertex, v) in self.vertices.iter().enumerate() {
            if let Some(&value) = v.coords.iter().find(|c| !c.is_finite()) {
                return Err(MeshError::NonFinite {
                    path: source.to_path_buf(),
                    vertex,
                    value,
                });
            }
        }
        let n = self.vertices.len();
        for (triangle, t) in self.triangles.iter().enumerate() {
            if let Some(&index) = t.iter().find(|&&i| i as usize >= n) {
                return Err(MeshError::IndexOutOfRange {
                    path: source.to_path_buf(),
                    triangle,
                    index,
                    vertices: n,
                });
            }
        }
        Ok(())
    }

    /// The mesh with every vertex mapped by `target_from_mesh`.
    pub fn transformed(&self, target_from_mesh: &Pose) -> TriMesh {
        TriMesh {
            vertices: self.vertices.iter().map(|v| target_from_mesh * v).collect(),
            triangles: self.triangles.clone(),
        }
    }

    /// The mesh as a parry tri-mesh (with its BVH) for ray casts and collision
    /// queries; `source` names it in errors.
    pub fn to_parry(&self, source: &Path) -> Result<parry3d_f64::shape::TriMesh, MeshError> {
        self.validate(source)?;
        parry3d_f64::shape::TriMesh::new(self.vertices.clone(), self.triangles.clone()).map_err(
            |_| MeshError::Empty {
                path: source.to_path_buf(),
                vertices: self.vertices.len(),
                triangles: self.triangles.len(),
            },
        )
    }

    /// The three corners of triangle `i`.
    pub fn corners(&self, i: usize) -> [Point3<f64>; 3] {
        let [a, b, c] = self.triangles[i];
        [
            self.vertices[a as usize],
            self.vertices[b as usize],
            self.vertices[c as usize],
        ]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_format_loads_through_one_entry_with_scale() {
        let (mug, _) = procedural::generate(procedural::Category::Mug, 3);
        let dir = crate::fsio::TempDir::new("load-mesh").unwrap();
        for format in [MeshFormat::Obj, MeshFormat::Stl, MeshFormat::Ply] {
            let path = dir.join(format!("mug.{}", format.extension()));
            write_mesh(&path, &mug).unwrap();
            let back = load_mesh(&path, 1000.0).unwrap();
            assert_eq!(back.triangles.len(), mug.triangles.len(), "{format:?}");
            // Scaled by 1000 (a metre file read as millimetres); STL stores f32.
            let a = mug.vertices[mug.triangles[5][1] as usize] * 1000.0;
            let b = back.vertices[back.triangles[5][1] as usize];
            assert!((a - b).norm() < 1e-3, "{format:?}: {a} vs {b}");
        }
        let err = load_mesh(&dir.join("mug.dae"), 1.0)
            .unwrap_err()
            .to_string();
        assert!(
            err.contains("mug.dae") && err.contains("unsupported"),
            "{err}"
        );
        let err = load_mesh(&dir.join("mug.obj"), f64::NAN)
            .unwrap_err()
            .to_string();
        assert!(err.contains("scale"), "{err}");
    }

    #[test]
    fn validation_names_the_problem() {
        let path = Path::new("cup.obj");
        let mut mesh = TriMesh {
            vertices: vec![
                Point3::origin(),
                Point3::new(1.0, 0.0, 0.0),
                Point3::new(0.0, 1.0, 0.0),
            ],
            triangles: vec![[0, 1, 2]],
        };
        mesh.validate(path).unwrap();
        mesh.triangles.push([0, 1, 3]);
        let err = mesh.validate(path).unwrap_err().to_string();
        assert!(
            err.contains("cup.obj") && err.contains("triangle 1 uses vertex 3"),
            "{err}"
        );
        mesh.triangles.pop();
        mesh.vertices[1].y = f64::NAN;
        assert!(matches!(
            mesh.validate(path),
            Err(MeshError::NonFinite { vertex: 1, .. })
        ));
        assert!(matches!(
            TriMesh::default().validate(path),
            Err(MeshError::Empty { .. })
        ));
    }
}
