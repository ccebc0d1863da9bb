//! A user's own objects: a directory of OBJ, STL or PLY meshes with a small TOML
//! manifest, `objects.toml`, naming each file's category and scale, so a lab can run
//! `cell eval novel`, `cell campaign` and `cell demo` on its own object scans.
//!
//! ```toml
//! [[object]]
//! file = "blue_mug.stl"   # relative to the directory
//! category = "mug"        # mug, bottle, hammer or knife
//! scale = 0.001           # metres per file unit (a millimetre scan); default 1
//! name = "blue-mug"       # optional; default: the file's stem
//! ```
//!
//! Meshes are in the object frame the categories share: z up with the object
//! standing (or lying, for tools) on `z = min z`; a mug's handle, if any, anywhere.
//! A malformed manifest, a missing or unreadable mesh, or an unknown category is one
//! error naming the file.

use crate::mesh::procedural::Category;
use crate::mesh::{load_mesh, MeshError, TriMesh};
use serde::Deserialize;
use std::path::{Path, PathBuf};

/// The manifest's file name inside the objects directory.
pub const MANIFEST_FILE: &str = "objects.toml";

/// Errors of reading an objects directory; each names the file at fault.
#[derive(Debug, thiserror::Error)]
pub enum ObjectsError {
    /// The manifest could not be read.
    #[error("{}: cannot read the objects manifest: {}", .0.path.display(), .0.source)]
    Read(crate::fsio::FileError),
    /// The manifest is not valid TOML or has unknown or missing fields.
    #[error("{path}: malformed objects manifest: {message}")]
    Malformed {
        /// The manifest.
        path: PathBuf,
        /// The parser's message.
        message: String,
    },
    /// The manifest lists no object.
    #[error("{path}: the manifest lists no [[object]]")]
    Empty {
        /// The manifest.
        path: PathBuf,
    },
    /// An entry names a category the cell has no model for.
    #[error(
        "{path}: object {file}: unknown category {category:?} (use mug, bottle, hammer or knife)"
    )]
    UnknownCategory {
        /// The manifest.
        path: PathBuf,
        /// The entry's mesh file.
        file: String,
        /// The category given.
        category: String,
    },
    /// An entry's mesh file does not exist.
    #[error("{mesh}: mesh listed in {path} does not exist")]
    MissingMesh {
        /// The manifest.
        path: PathBuf,
        /// The mesh file.
        mesh: PathBuf,
    },
    /// An entry's mesh could not be loaded (format, scale, contents).
    #[error("{0}")]
    Mesh(#[from] MeshError),
    /// Two entries have the same name.
    #[error("{path}: two objects are named {name:?}")]
    DuplicateName {
        /// The manifest.
        path: PathBuf,
        /// The name.
        name: String,
    },
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct Manifest {
    #[serde(default)]
    object: Vec<Entry>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct Entry {
    file: String,
    category: String,
    #[serde(default = "one")]
    scale: f64,
    name: Option<String>,
}

fn one() -> f64 {
    1.0
}

/// One of the user's objects, loaded.
#[derive(Debug, Clone)]
pub struct UserObject {
    /// Its name (the manifest's, else the file's stem).
    pub name: String,
    /// Its category.
    pub category: Category,
    /// The mesh file.
    pub path: PathBuf,
    /// Metres per file unit.
    pub scale: f64,
    /// The scaled mesh (object frame).
    pub mesh: TriMesh,
}

/// Reads `<dir>/objects.toml` and loads every mesh it lists.
pub fn load_objects(dir: &Path) -> Result<Vec<UserObject>, ObjectsError> {
    let path = dir.join(MANIFEST_FILE);
    let text = crate::fsio::read_to_string(&path).map_err(ObjectsError::Read)?;
    let manifest: Manifest = toml::from_str(&text).map_err(|e| ObjectsError::Malformed {
        path: path.clone(),
        message: e.to_string().trim().replace('\n', " "),
    })?;
    if manifest.object.is_empty() {
        return Err(ObjectsError::Empty { path });
    }
    let mut out: Vec<UserObject> = Vec::new();
    for entry in manifest.object {
        let category: Category =
            entry
                .category
                .parse()
                .map_err(|_| ObjectsError::UnknownCategory {
                    path: path.clone(),
                    file: entry.file.clone(),
                    category: entry.category.clone(),
                })?;
        let mesh_path = dir.join(&entry.file);
        if !mesh_path.is_file() {
            return Err(ObjectsError::MissingMesh {
                path: path.clone(),
                mesh: mesh_path,
            });
        }
        let mesh = load_mesh(&mesh_path, entry.scale)?;
        let name = entry.name.unwrap_or_else(|| {
            Path::new(&entry.file)
                .file_stem()
                .map_or(entry.file.clone(), |s| s.to_string_lossy().into_owned())
        });
        if out.iter().any(|o| o.name == name) {
            return Err(ObjectsError::DuplicateName { path, name });
        }
        out.push(UserObject {
            name,
            category,
            path: mesh_path,
            scale: entry.scale,
            mesh,
        });
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::fsio::TempDir;
    use crate::mesh::procedural::generate;

    /// A fresh directory with a generated mug mesh (millimetres) and `manifest`.
    fn fixture(tag: &str, manifest: &str) -> TempDir {
        let dir = TempDir::new(&format!("objects-{tag}")).unwrap();
        let (mut mesh, _) = generate(Category::Mug, 3);
        for v in &mut mesh.vertices {
            v.coords *= 1000.0;
        }
        crate::mesh::write_mesh(&dir.join("mug.stl"), &mesh).unwrap();
        std::fs::write(dir.join(MANIFEST_FILE), manifest).unwrap();
        dir
    }

    #[test]
    fn a_manifest_loads_scaled_meshes_with_their_categories() {
        let dir = fixture(
            "ok",
            "[[object]]\nfile = \"mug.stl\"\ncategory = \"mug\"\nscale = 0.001\n",
        );
        let objects = load_objects(&dir).unwrap();
        assert_eq!(objects.len(), 1);
        let o = &objects[0];
        assert_eq!((o.name.as_str(), o.category), ("mug", Category::Mug));
        let (want, _) = generate(Category::Mug, 3);
        let top = |m: &TriMesh| m.vertices.iter().map(|v| v.z).fold(f64::MIN, f64::max);
        assert!((top(&o.mesh) - top(&want)).abs() < 1e-6);
    }

    #[test]
    fn bad_manifests_give_one_error_naming_the_file() {
        let manifest = |dir: &Path| dir.join(MANIFEST_FILE).display().to_string();
        // Malformed TOML.
        let dir = fixture("toml", "[[object]\nfile = \"mug.stl\"\n");
        let e = load_objects(&dir).unwrap_err().to_string();
        assert!(
            e.contains(&manifest(&dir)) && e.contains("malformed"),
            "{e}"
        );
        // A field the manifest does not know.
        let dir = fixture(
            "field",
            "[[object]]\nfile = \"mug.stl\"\ncategory = \"mug\"\nsize = 2\n",
        );
        let e = load_objects(&dir).unwrap_err().to_string();
        assert!(e.contains(&manifest(&dir)) && e.contains("size"), "{e}");
        // A missing mesh.
        let dir = fixture(
            "missing",
            "[[object]]\nfile = \"cup.obj\"\ncategory = \"mug\"\n",
        );
        let e = load_objects(&dir).unwrap_err().to_string();
        assert!(
            e.contains(&dir.join("cup.obj").display().to_string()) && e.contains("does not exist"),
            "{e}"
        );
        // An unknown category.
        let dir = fixture(
            "category",
            "[[object]]\nfile = \"mug.stl\"\ncategory = \"teapot\"\n",
        );
        let e = load_objects(&dir).unwrap_err().to_string();
        assert!(
            e.contains(&manifest(&dir)) && e.contains("mug.stl") && e.contains("\"teapot\""),
            "{e}"
        );
        // No manifest at all.
        let empty = TempDir::new("objects-none").unwrap();
        let e = load_objects(&empty).unwrap_err().to_string();
        assert!(e.contains(&manifest(&empty)), "{e}");
    }
}
