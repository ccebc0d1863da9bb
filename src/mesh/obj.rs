//! Wavefront OBJ: reading (`v` and `f` statements; faces as `i`, `i/t`, `i/t/n` or
//! `i//n`, negative indices relative to the vertices read so far, polygons
//! fan-triangulated; every other statement ignored) and writing.
//!
//! Coordinates are taken as metres; a caller scales millimetre files.

use super::{MeshError, TriMesh};
use crate::fsio::{FileError, FileOp};
use nalgebra::Point3;
use std::io::{BufRead, BufReader, Write};
use std::path::Path;

/// Reads an OBJ file and validates the mesh; errors name the file and line.
pub fn read_obj(path: &Path) -> Result<TriMesh, MeshError> {
    let file = crate::fsio::open(path)?;
    parse_obj(BufReader::new(file), path)
}

/// Parses OBJ text from `reader`; `path` names the input in errors.
pub fn parse_obj(reader: impl BufRead, path: &Path) -> Result<TriMesh, MeshError> {
    let parse_error = |line: usize, problem: String| MeshError::Parse {
        path: path.to_path_buf(),
        location: format!("line {line}"),
        problem,
    };
    let mut mesh = TriMesh::default();
    // Triangles with positive indices are checked once all vertices are known;
    // remember the line each came from.
    let mut triangle_lines: Vec<usize> = Vec::new();
    let mut corners: Vec<u32> = Vec::new();
    for (n, line) in reader.lines().enumerate() {
        let number = n + 1;
        let line = line.map_err(|e| parse_error(number, format!("unreadable text: {e}")))?;
        let statement = line.split('#').next().unwrap_or("");
        let mut words = statement.split_whitespace();
        match words.next() {
            Some("v") => {
                let mut xyz = [0.0; 3];
                for (k, c) in xyz.iter_mut().enumerate() {
                    let word = words.next().ok_or_else(|| {
                        parse_error(number, format!("vertex has {k} coordinates, needs 3"))
                    })?;
                    *c = word.parse::<f64>().map_err(|_| {
                        parse_error(
                            number,
                            format!("vertex coordinate {word:?} is not a number"),
                        )
                    })?;
                    if !c.is_finite() {
                        return Err(parse_error(
                            number,
                            format!("vertex coordinate {word:?} is not finite"),
                        ));
                    }
                }
                mesh.vertices.push(Point3::from(xyz));
            }
            Some("f") => {
                corners.clear();
                for word in words {
                    corners.push(face_index(word, mesh.vertices.len()).map_err(|problem| {
                        parse_error(number, format!("face corner {word:?}: {problem}"))
                    })?);
                }
                if corners.len() < 3 {
                    return Err(parse_error(
                        number,
                        format!("face has {} corners, needs at least 3", corners.len()),
                    ));
                }
                for k in 1..corners.len() - 1 {
                    mesh.triangles
                        .push([corners[0], corners[k], corners[k + 1]]);
                    triangle_lines.push(number);
                }
            }
            _ => {}
        }
    }
    let n = mesh.vertices.len();
    for (t, &line) in mesh.triangles.iter().zip(&triangle_lines) {
        if let Some(&i) = t.iter().find(|&&i| i as usize >= n) {
            return Err(parse_error(
                line,
                format!(
                    "face uses vertex {} but the file has only {n}",
                    i as u64 + 1
                ),
            ));
        }
    }
    mesh.validate(path)?;
    Ok(mesh)
}

/// Why a face corner names no vertex.
#[derive(Debug, thiserror::Error)]
enum FaceIndexError {
    /// The index is not a whole number.
    #[error("vertex index {0:?} is not an integer")]
    NotAnInteger(String),
    /// OBJ counts from 1.
    #[error("vertex index 0 (OBJ indices start at 1)")]
    Zero,
    /// A negative index reaching before the first vertex.
    #[error("relative index {index} reaches before the first vertex ({count} read so far)")]
    BeforeFirst {
        /// The relative index.
        index: i64,
        /// Vertices read so far.
        count: usize,
    },
    /// An index beyond what a mesh holds.
    #[error("vertex index {0} is too large")]
    TooLarge(i64),
}

/// The zero-based vertex index of one face corner `i`, `i/t`, `i/t/n` or `i//n`,
/// given `count` vertices read so far (for negative, relative indices).
fn face_index(word: &str, count: usize) -> Result<u32, FaceIndexError> {
    let first = word.split('/').next().unwrap_or("");
    let index: i64 = first
        .parse()
        .map_err(|_| FaceIndexError::NotAnInteger(first.to_string()))?;
    let zero_based = match index {
        0 => return Err(FaceIndexError::Zero),
        i if i > 0 => i - 1,
        i => {
            let k = count as i64 + i;
            if k < 0 {
                return Err(FaceIndexError::BeforeFirst { index: i, count });
            }
            k
        }
    };
    u32::try_from(zero_based).map_err(|_| FaceIndexError::TooLarge(index))
}

/// Writes `mesh` as OBJ text (`v` lines with round-trip exact numbers, then `f`).
pub fn write_obj_to(mut out: impl Write, mesh: &TriMesh) -> std::io::Result<()> {
    writeln!(
        out,
        "# graspcell mesh: {} vertices, {} triangles, metres",
        mesh.vertices.len(),
        mesh.triangles.len()
    )?;
    for v in &mesh.vertices {
        writeln!(out, "v {} {} {}", v.x, v.y, v.z)?;
    }
    for t in &mesh.triangles {
        writeln!(out, "f {} {} {}", t[0] + 1, t[1] + 1, t[2] + 1)?;
    }
    out.flush()
}

/// Writes `mesh` to an OBJ file atomically: a failure never leaves a half-written file.
pub fn write_obj(path: &Path, mesh: &TriMesh) -> Result<(), MeshError> {
    let mut bytes = Vec::new();
    write_obj_to(&mut bytes, mesh)
        .and_then(|()| crate::fsio::write_atomically(path, &bytes))
        .map_err(|source| FileError::new(FileOp::Write, path, source).into())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn parse(text: &str) -> Result<TriMesh, MeshError> {
        parse_obj(text.as_bytes(), Path::new("test.obj"))
    }

    #[test]
    fn corner_forms_negative_indices_and_polygons() {
        let text = "# a unit square and a triangle\n\
                    mtllib x.mtl\no thing\nvn 0 0 1\nvt 0 0\n\
                    v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0 1.0\n\
                    s off\nusemtl red\n\
                    f 1/1/1 2/1/1 3/1/1 4/1/1\n\
                    v 0 0 1\n\
                    f -1//1 -5/1 -4  # trailing comment\n";
        let mesh = parse(text).unwrap();
        assert_eq!(mesh.vertices.len(), 5);
        // The quad fans from its first corner; the last face resolves -1 -> 5, -5 -> 1, -4 -> 2.
        assert_eq!(mesh.triangles, vec![[0, 1, 2], [0, 2, 3], [4, 0, 1]]);
        assert_eq!(mesh.vertices[3], Point3::new(0.0, 1.0, 0.0));
    }

    #[test]
    fn malformed_lines_are_named() {
        let cases = [
            ("v 0 0 0\nv 1 0\n", "line 2", "2 coordinates"),
            ("v 0 0 0\nv 1 x 0\n", "line 2", "\"x\""),
            ("v 0 0 nan\n", "line 1", "not finite"),
            ("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2\n", "line 4", "2 corners"),
            ("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 0 2\n", "line 4", "index 0"),
            (
                "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 -4\n",
                "line 4",
                "before the first",
            ),
            (
                "v 0 0 0\nv 1 0 0\nv 0 1 0\n\nf 1 2 7\n",
                "line 5",
                "vertex 7",
            ),
            ("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 a/1\n", "line 4", "\"a\""),
            // Issue 21's trick on indices: the extremes of u32 and i64.
            (
                "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 4294967296\n",
                "line 4",
                "vertex 4294967296 but the file has only 3",
            ),
            (
                "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 4294967297\n",
                "line 4",
                "vertex index 4294967297 is too large",
            ),
            (
                "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 -9223372036854775808\n",
                "line 4",
                "before the first",
            ),
            (
                "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 9223372036854775808\n",
                "line 4",
                "not an integer",
            ),
        ];
        for (text, line, problem) in cases {
            let err = parse(text).unwrap_err().to_string();
            assert!(
                err.contains("test.obj") && err.contains(line) && err.contains(problem),
                "{text:?}: {err}"
            );
        }
        let err = parse("# nothing\nv 0 0 0\n").unwrap_err();
        assert!(
            matches!(
                err,
                MeshError::Empty {
                    vertices: 1,
                    triangles: 0,
                    ..
                }
            ),
            "{err}"
        );
    }

    #[test]
    fn non_utf8_is_an_error_not_a_panic() {
        let bytes: &[u8] = b"v 0 0 0\nv \xff 0 0\n";
        let err = parse_obj(bytes, Path::new("bin.obj"))
            .unwrap_err()
            .to_string();
        assert!(err.contains("bin.obj") && err.contains("line 2"), "{err}");
    }
}
