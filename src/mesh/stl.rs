//! STL meshes: ASCII and binary reading, binary writing.
//!
//! An STL file is a triangle soup; reading welds vertices that are exactly equal
//! (same bits, with `-0.0` taken as `0.0`) so the mesh is indexed and a closed
//! surface stays closed. Binary is recognised by its size (`84 + 50 n` bytes for the
//! `n` triangles in its header), since binary files may begin with `solid` too.
//! Binary STL stores `f32`, so writing rounds coordinates to `f32`.

use super::{EncodeError, MeshError, TriMesh};
use nalgebra::{Point3, Vector3};
use std::collections::HashMap;
use std::path::Path;

/// Bytes of a binary STL header plus triangle count.
const HEADER_BYTES: usize = 84;
/// Bytes of one binary STL triangle record.
const RECORD_BYTES: usize = 50;

/// Reads the STL file at `path` (ASCII or binary) and validates the mesh.
pub fn read_stl(path: &Path) -> Result<TriMesh, MeshError> {
    let bytes = crate::fsio::read(path)?;
    parse_stl(&bytes, path)
}

/// Parses STL bytes (ASCII or binary) into a welded, validated mesh; `source` names
/// the file in errors.
pub fn parse_stl(bytes: &[u8], source: &Path) -> Result<TriMesh, MeshError> {
    let mesh = if is_binary(bytes) {
        parse_binary(bytes, source)?
    } else {
        parse_ascii(bytes, source)?
    };
    mesh.validate(source)?;
    Ok(mesh)
}

/// Writes `mesh` to `path` as binary STL (facet normals from the winding),
/// atomically; the mesh must be valid.
pub fn write_stl(path: &Path, mesh: &TriMesh) -> Result<(), MeshError> {
    mesh.validate(path)?;
    let bytes = encode_stl(mesh).map_err(|problem| MeshError::Encode {
        path: path.to_path_buf(),
        problem,
    })?;
    Ok(crate::fsio::write(path, &bytes)?)
}

/// Encodes `mesh` (assumed valid) as binary STL; fails only with more triangles
/// than the format counts.
pub fn encode_stl(mesh: &TriMesh) -> Result<Vec<u8>, EncodeError> {
    let n = u32::try_from(mesh.triangles.len()).map_err(|_| EncodeError::TooManyTriangles {
        triangles: mesh.triangles.len(),
    })?;
    let mut out = Vec::with_capacity(HEADER_BYTES + RECORD_BYTES * mesh.triangles.len());
    // The header must not start with "solid", or some readers take it for ASCII.
    let mut header = [b' '; 80];
    let title = b"graspcell binary STL (m)";
    header[..title.len()].copy_from_slice(title);
    out.extend_from_slice(&header);
    out.extend_from_slice(&n.to_le_bytes());
    for i in 0..mesh.triangles.len() {
        let [a, b, c] = mesh.corners(i);
        let normal = (b - a)
            .cross(&(c - a))
            .try_normalize(0.0)
            .unwrap_or_else(Vector3::zeros);
        for v in normal
            .iter()
            .chain(a.iter())
            .chain(b.iter())
            .chain(c.iter())
        {
            out.extend_from_slice(&(*v as f32).to_le_bytes());
        }
        out.extend_from_slice(&0u16.to_le_bytes());
    }
    Ok(out)
}

/// True when `bytes` are a binary STL. ASCII STL is text that starts with `solid`;
/// binary files may start with `solid` too, but hold NUL bytes (zero floats and
/// attribute words). A size of exactly `84 + 50 n` means binary unless the file is
/// such text with facets.
fn is_binary(bytes: &[u8]) -> bool {
    let textual = bytes.trim_ascii_start().starts_with(b"solid")
        && !bytes.contains(&0)
        && std::str::from_utf8(bytes).is_ok();
    if bytes.len() >= HEADER_BYTES {
        let n = u32::from_le_bytes(bytes[80..84].try_into().expect("4 bytes")) as u64;
        if HEADER_BYTES as u64 + RECORD_BYTES as u64 * n == bytes.len() as u64 {
            return !(textual && bytes.windows(5).any(|w| w == b"facet"));
        }
    }
    !textual
}

/// Collects vertices, giving each distinct position one index.
#[derive(Default)]
struct Welder {
    index: HashMap<[u64; 3], u32>,
    mesh: TriMesh,
}

impl Welder {
    /// The index of `p`, adding it if new.
    fn vertex(&mut self, p: Point3<f64>) -> u32 {
        // Adding 0.0 turns -0.0 into 0.0, so the two zeros weld.
        let key = [
            (p.x + 0.0).to_bits(),
            (p.y + 0.0).to_bits(),
            (p.z + 0.0).to_bits(),
        ];
        let vertices = &mut self.mesh.vertices;
        *self.index.entry(key).or_insert_with(|| {
            vertices.push(p);
            (vertices.len() - 1) as u32
        })
    }

    /// Adds the polygon `corners` as a fan of triangles.
    fn polygon(&mut self, corners: &[Point3<f64>]) {
        let ids: Vec<u32> = corners.iter().map(|&p| self.vertex(p)).collect();
        for k in 1..ids.len() - 1 {
            self.mesh.triangles.push([ids[0], ids[k], ids[k + 1]]);
        }
    }
}

/// Parses a binary STL; errors name the facet and its byte offset.
fn parse_binary(bytes: &[u8], source: &Path) -> Result<TriMesh, MeshError> {
    let err = |location: String, problem: String| MeshError::Parse {
        path: source.to_path_buf(),
        location,
        problem,
    };
    if bytes.len() < HEADER_BYTES {
        return Err(err(
            "header".to_string(),
            format!(
                "{} bytes: not ASCII STL (no `solid`), and too short for binary STL (84 bytes at least)",
                bytes.len()
            ),
        ));
    }
    let n = u32::from_le_bytes(bytes[80..84].try_into().expect("4 bytes")) as usize;
    let expected = HEADER_BYTES as u64 + RECORD_BYTES as u64 * n as u64;
    let have = bytes.len() as u64;
    if have < expected {
        let facet = (bytes.len() - HEADER_BYTES) / RECORD_BYTES;
        return Err(err(
            format!("facet {facet}, byte offset {}", HEADER_BYTES + facet * RECORD_BYTES),
            format!("file ends (truncated): the header declares {n} triangles ({expected} bytes), the file has {have} bytes"),
        ));
    }
    if have > expected {
        return Err(err(
            format!("byte offset {expected}"),
            format!(
                "{} bytes after the {n} triangles the header declares (wrong count?)",
                have - expected
            ),
        ));
    }
    let mut welder = Welder::default();
    welder.mesh.triangles.reserve(n);
    for (facet, record) in bytes[HEADER_BYTES..].chunks_exact(RECORD_BYTES).enumerate() {
        let value = |k: usize| {
            let at = 12 + 4 * k;
            f32::from_le_bytes(record[at..at + 4].try_into().expect("4 bytes")) as f64
        };
        let corners: Vec<Point3<f64>> = (0..3)
            .map(|c| Point3::new(value(3 * c), value(3 * c + 1), value(3 * c + 2)))
            .collect();
        if let Some(bad) = corners
            .iter()
            .flat_map(|p| p.iter())
            .find(|v| !v.is_finite())
        {
            return Err(err(
                format!(
                    "facet {facet}, byte offset {}",
                    HEADER_BYTES + facet * RECORD_BYTES
                ),
                format!("non-finite vertex coordinate {bad}"),
            ));
        }
        welder.polygon(&corners);
    }
    Ok(welder.mesh)
}

/// Parses an ASCII STL (one or more `solid`s; loops of three or more vertices are
/// fanned into triangles); errors name the line.
fn parse_ascii(bytes: &[u8], source: &Path) -> Result<TriMesh, MeshError> {
    let err = |line: usize, problem: String| MeshError::Parse {
        path: source.to_path_buf(),
        location: format!("line {line}"),
        problem,
    };
    let text = std::str::from_utf8(bytes).map_err(|e| {
        let line = 1 + bytes[..e.valid_up_to()]
            .iter()
            .filter(|&&b| b == b'\n')
            .count();
        err(line, "not text: neither ASCII nor binary STL".to_string())
    })?;
    let last_line = text.lines().count().max(1);
    // Tokens with their line; `solid` and `endsolid` take the rest of their line
    // (the name) with them.
    let mut tokens = Vec::new();
    for (i, line) in text.lines().enumerate() {
        for word in line.split_whitespace() {
            tokens.push((word, i + 1));
            if word == "solid" || word == "endsolid" {
                break;
            }
        }
    }
    let mut tokens = tokens.into_iter().peekable();
    let mut next = |wanted: &str| {
        tokens.next().ok_or_else(|| {
            err(
                last_line,
                format!("file ends where `{wanted}` was expected (truncated?)"),
            )
        })
    };
    let mut welder = Welder::default();
    let (first, line) = next("solid")?;
    if first != "solid" {
        return Err(err(line, format!("expected `solid`, found `{first}`")));
    }
    loop {
        let (word, line) = next("facet or endsolid")?;
        match word {
            "endsolid" => match next("solid or end of file") {
                Err(_) => break,
                Ok(("solid", _)) => continue,
                Ok((other, line)) => {
                    return Err(err(
                        line,
                        format!("expected `solid` or the end of the file, found `{other}`"),
                    ))
                }
            },
            "facet" => {
                let expect = |found: (&str, usize), wanted: &str| {
                    if found.0 == wanted {
                        Ok(())
                    } else {
                        Err(err(
                            found.1,
                            format!("expected `{wanted}`, found `{}`", found.0),
                        ))
                    }
                };
                expect(next("normal")?, "normal")?;
                // The stored normal is not used: the winding defines the outside.
                for _ in 0..3 {
                    next("a normal component")?;
                }
                expect(next("outer")?, "outer")?;
                expect(next("loop")?, "loop")?;
                let mut corners = Vec::with_capacity(3);
                loop {
                    let (word, line) = next("vertex or endloop")?;
                    match word {
                        "vertex" => {
                            let mut p = [0.0; 3];
                            for c in &mut p {
                                let (text, line) = next("a vertex coordinate")?;
                                *c = text.parse::<f64>().map_err(|_| {
                                    err(line, format!("vertex coordinate `{text}` is not a number"))
                                })?;
                                if !c.is_finite() {
                                    return Err(err(
                                        line,
                                        format!("non-finite vertex coordinate {text}"),
                                    ));
                                }
                            }
                            corners.push(Point3::from(p));
                        }
                        "endloop" => {
                            if corners.len() < 3 {
                                return Err(err(
                                    line,
                                    format!("facet loop has {} vertices, needs 3", corners.len()),
                                ));
                            }
                            break;
                        }
                        other => {
                            return Err(err(
                                line,
                                format!("expected `vertex` or `endloop`, found `{other}`"),
                            ))
                        }
                    }
                }
                expect(next("endfacet")?, "endfacet")?;
                welder.polygon(&corners);
            }
            other => {
                return Err(err(
                    line,
                    format!("expected `facet` or `endsolid`, found `{other}`"),
                ))
            }
        }
    }
    Ok(welder.mesh)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::cloud::io::test_support::cube;
    use crate::fsio::TempDir;

    /// An ASCII STL of `mesh`'s triangles, as an exporter writes a triangle soup.
    fn ascii_of(mesh: &TriMesh) -> String {
        let mut s = String::from("solid cube exported by hand\n");
        for i in 0..mesh.triangles.len() {
            s.push_str("  facet normal 0 0 0\n    outer loop\n");
            for p in mesh.corners(i) {
                s.push_str(&format!("      vertex {} {} {}\n", p.x, p.y, p.z));
            }
            s.push_str("    endloop\n  endfacet\n");
        }
        s.push_str("endsolid cube exported by hand\n");
        s
    }

    #[test]
    fn ascii_soup_is_welded_into_the_indexed_cube() {
        let cube = cube();
        let mesh = parse_stl(ascii_of(&cube).as_bytes(), Path::new("c.stl")).unwrap();
        assert_same_triangles(&mesh, &cube);
    }

    /// Asserts that two meshes have the same vertices and the same triangles as
    /// corner positions (welding numbers vertices in first-seen order).
    fn assert_same_triangles(a: &TriMesh, b: &TriMesh) {
        assert_eq!(a.vertices.len(), b.vertices.len());
        assert_eq!(a.triangles.len(), b.triangles.len());
        for i in 0..a.triangles.len() {
            assert_eq!(a.corners(i), b.corners(i), "triangle {i}");
        }
    }

    #[test]
    fn binary_write_read_round_trips_and_has_specified_layout() {
        let dir = TempDir::new("stl").unwrap();
        let mut cube = cube();
        cube.vertices[6] = Point3::new(1.0, 1.0, 1.25); // not axis-aligned any more
        let path = dir.join("cube.stl");
        write_stl(&path, &cube).unwrap();
        let bytes = std::fs::read(&path).unwrap();
        assert_eq!(bytes.len(), 84 + 50 * 12);
        assert!(!bytes.starts_with(b"solid"));
        assert_eq!(&bytes[80..84], &12u32.to_le_bytes());
        // Facet 1 = [0, 3, 2]: normal -z, then the corners as f32.
        let f32_at = |at: usize| f32::from_le_bytes(bytes[at..at + 4].try_into().unwrap());
        let facet1: Vec<f32> = (0..12).map(|k| f32_at(84 + 50 + 4 * k)).collect();
        assert_eq!(
            facet1,
            [0.0, 0.0, -1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 1.0, 1.0, 0.0]
        );
        assert_same_triangles(&read_stl(&path).unwrap(), &cube);
    }

    #[test]
    fn binary_file_starting_with_solid_is_read_as_binary() {
        let mut bytes = encode_stl(&cube()).unwrap();
        bytes[..11].copy_from_slice(b"solid cube ");
        assert_same_triangles(&parse_stl(&bytes, Path::new("b.stl")).unwrap(), &cube());
        // Truncated, it is still recognised as binary and reported as truncated.
        let err = parse_stl(&bytes[..bytes.len() - 50], Path::new("b.stl"))
            .unwrap_err()
            .to_string();
        assert!(
            err.contains("facet 11, byte offset 634: file ends (truncated)"),
            "{err}"
        );
    }

    #[test]
    fn negative_zero_welds_with_zero_and_quads_are_fanned() {
        let text = "solid q\nfacet normal 0 0 1\nouter loop\nvertex 0 0 0\nvertex 1 0 0\nvertex 1 1 0\nvertex 0 1 0\nendloop\nendfacet\nfacet normal 0 0 1\nouter loop\nvertex -0 -0 0\nvertex 0 1 0\nvertex -1 0 0\nendloop\nendfacet\nendsolid q\nsolid second\nendsolid\n";
        let mesh = parse_stl(text.as_bytes(), Path::new("q.stl")).unwrap();
        assert_eq!(mesh.vertices.len(), 5);
        assert_eq!(mesh.triangles, vec![[0, 1, 2], [0, 2, 3], [0, 3, 4]]);
    }

    #[test]
    fn malformed_and_truncated_stl_name_file_and_place() {
        let dir = TempDir::new("stl-bad").unwrap();
        let ascii = ascii_of(&cube());
        let binary = encode_stl(&cube()).unwrap();
        let mut nan = binary.clone();
        nan[84 + 50 * 3 + 12 + 4..84 + 50 * 3 + 20].copy_from_slice(&f32::NAN.to_le_bytes());
        let cases: Vec<(&str, Vec<u8>, &str)> = vec![
            ("trunc.stl", binary[..binary.len() - 60].to_vec(), "facet 10, byte offset 584: file ends (truncated): the header declares 12 triangles (684 bytes), the file has 624 bytes"),
            ("long.stl", [&binary[..], &[0u8; 3]].concat(), "byte offset 684: 3 bytes after the 12 triangles"),
            // Issue 21's trick on the triangle count: the largest count, one record.
            ("count.stl", [&binary[..80], &u32::MAX.to_le_bytes()[..], &binary[84..134]].concat(), "facet 1, byte offset 134: file ends (truncated): the header declares 4294967295 triangles (214748364834 bytes), the file has 134 bytes"),
            ("short.stl", b"garbage".to_vec(), "header: 7 bytes: not ASCII STL"),
            ("nan.stl", nan, "facet 3, byte offset 234: non-finite vertex coordinate NaN"),
            ("empty.stl", [&binary[..80], &0u32.to_le_bytes()[..]].concat(), "mesh is empty (0 vertices, 0 triangles)"),
            ("trunc_text.stl", ascii.lines().take(20).collect::<Vec<_>>().join("\n").into_bytes(), "line 20: file ends where `vertex or endloop` was expected"),
            ("number.stl", ascii.replacen("vertex 1 0 0", "vertex 1 O 0", 1).into_bytes(), "line 6: vertex coordinate `O` is not a number"),
            ("nan_text.stl", ascii.replacen("vertex 1 0 0", "vertex 1 nan 0", 1).into_bytes(), "line 6: non-finite vertex coordinate nan"),
            ("keyword.stl", ascii.replacen("endloop", "endlop", 1).into_bytes(), "line 7: expected `vertex` or `endloop`, found `endlop`"),
            ("two.stl", ascii.replacen("      vertex 1 0 0\n", "", 1).into_bytes(), "line 6: facet loop has 2 vertices, needs 3"),
            ("after.stl", format!("{ascii}facet\n").into_bytes(), "line 87: expected `solid` or the end of the file, found `facet`"),
        ];
        for (name, bytes, expected) in cases {
            let path = dir.join(name);
            std::fs::write(&path, bytes).unwrap();
            let err = read_stl(&path).unwrap_err().to_string();
            assert!(err.starts_with(&path.display().to_string()), "{err}");
            assert!(err.contains(expected), "{name}: {err}");
        }
    }
}
