//! PLY meshes: a `vertex` element with `x y z` and a `face` element with a
//! `vertex_indices` (or `vertex_index`) list; polygons are fanned into triangles.
//! Written as `double x y z` and `list uchar int vertex_indices`, so coordinates
//! round-trip exactly.

use super::{EncodeError, MeshError, TriMesh};
use crate::ply::{self, Column, Element, Format, Ply, PlyError, Property, ScalarType, Values};
use nalgebra::Point3;
use std::path::Path;

impl From<PlyError> for MeshError {
    fn from(e: PlyError) -> MeshError {
        match e {
            PlyError::File(e) => MeshError::File(e),
            PlyError::Parse {
                path,
                location,
                problem,
            } => MeshError::Parse {
                path,
                location,
                problem,
            },
        }
    }
}

/// Reads the PLY mesh at `path` (any PLY encoding) and validates it.
pub fn read_ply_mesh(path: &Path) -> Result<TriMesh, MeshError> {
    let bytes = crate::fsio::read(path)?;
    parse_ply_mesh(&bytes, path)
}

/// Parses PLY bytes into a validated mesh; `source` names the file in errors.
pub fn parse_ply_mesh(bytes: &[u8], source: &Path) -> Result<TriMesh, MeshError> {
    let ply = ply::parse(bytes, source)?;
    let err = |location: String, problem: String| MeshError::Parse {
        path: source.to_path_buf(),
        location,
        problem,
    };
    let vertex = ply
        .element("vertex")
        .ok_or_else(|| err("header".into(), "no `vertex` element".into()))?;
    let coordinate = |name: &str| match vertex.property(name) {
        Some(Column::Scalar(values)) => Ok(values.to_f64_vec()),
        Some(Column::List { .. }) => Err(err(
            "header".into(),
            format!("vertex property `{name}` is a list, expected a number"),
        )),
        None => Err(err(
            "header".into(),
            format!("vertex has no `{name}` property"),
        )),
    };
    let (x, y, z) = (coordinate("x")?, coordinate("y")?, coordinate("z")?);
    let vertices: Vec<Point3<f64>> = (0..vertex.count)
        .map(|i| Point3::new(x[i], y[i], z[i]))
        .collect();
    let mut triangles = Vec::new();
    if let Some(face) = ply.element("face") {
        let Some(Column::List { starts, items, .. }) = face
            .property("vertex_indices")
            .or_else(|| face.property("vertex_index"))
        else {
            return Err(err(
                "header".into(),
                "face has no `vertex_indices` list".into(),
            ));
        };
        if !items.scalar_type().is_integer() {
            return Err(err(
                "header".into(),
                format!(
                    "face vertex indices are {}, not integers",
                    items.scalar_type().name()
                ),
            ));
        }
        triangles.reserve(face.count);
        let mut corners = Vec::new();
        for f in 0..face.count {
            corners.clear();
            for k in starts[f]..starts[f + 1] {
                let index = items.get_i64(k).expect("integer items");
                let index = u32::try_from(index)
                    .ok()
                    .filter(|&i| (i as usize) < vertices.len())
                    .ok_or_else(|| {
                        err(
                            format!("face {f}"),
                            format!(
                                "vertex index {index} is out of range ({} vertices)",
                                vertices.len()
                            ),
                        )
                    })?;
                corners.push(index);
            }
            if corners.len() < 3 {
                return Err(err(
                    format!("face {f}"),
                    format!("{} vertices, a face needs 3", corners.len()),
                ));
            }
            for k in 1..corners.len() - 1 {
                triangles.push([corners[0], corners[k], corners[k + 1]]);
            }
        }
    }
    let mesh = TriMesh {
        vertices,
        triangles,
    };
    mesh.validate(source)?;
    Ok(mesh)
}

/// Writes `mesh` to `path` as a PLY file in `format` (binary little-endian is the
/// usual choice), atomically; the mesh must be valid.
pub fn write_ply_mesh(path: &Path, mesh: &TriMesh, format: Format) -> Result<(), MeshError> {
    mesh.validate(path)?;
    let bytes = encode_ply_mesh(mesh, format).map_err(|problem| MeshError::Encode {
        path: path.to_path_buf(),
        problem,
    })?;
    Ok(crate::fsio::write(path, &bytes)?)
}

/// Encodes `mesh` as a PLY file in `format`; fails only when the mesh is too big
/// for `int` indices.
pub fn encode_ply_mesh(mesh: &TriMesh, format: Format) -> Result<Vec<u8>, EncodeError> {
    if mesh.vertices.len() > i32::MAX as usize {
        return Err(EncodeError::TooManyVertices {
            vertices: mesh.vertices.len(),
        });
    }
    let axis = |i: usize| Property {
        name: ["x", "y", "z"][i].to_string(),
        column: Column::Scalar(Values::Double(mesh.vertices.iter().map(|v| v[i]).collect())),
    };
    let indices = Column::List {
        count_type: ScalarType::UChar,
        starts: (0..=mesh.triangles.len()).map(|i| 3 * i).collect(),
        items: Values::Int(mesh.triangles.iter().flatten().map(|&i| i as i32).collect()),
    };
    ply::encode(&Ply {
        format,
        comments: vec!["graspcell mesh (m)".to_string()],
        obj_info: Vec::new(),
        elements: vec![
            Element {
                name: "vertex".into(),
                count: mesh.vertices.len(),
                properties: vec![axis(0), axis(1), axis(2)],
            },
            Element {
                name: "face".into(),
                count: mesh.triangles.len(),
                properties: vec![Property {
                    name: "vertex_indices".into(),
                    column: indices,
                }],
            },
        ],
    })
    .map_err(EncodeError::from)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::cloud::io::test_support::cube;
    use crate::fsio::TempDir;

    #[test]
    fn ascii_and_binary_round_trip_exactly() {
        let dir = TempDir::new("mesh-ply").unwrap();
        let mut mesh = cube();
        mesh.vertices[3] = Point3::new(0.1, 1.0 / 3.0, -0.0);
        for format in [
            Format::Ascii,
            Format::BinaryLittleEndian,
            Format::BinaryBigEndian,
        ] {
            let path = dir.join("m.ply");
            write_ply_mesh(&path, &mesh, format).unwrap();
            let back = read_ply_mesh(&path).unwrap();
            assert_eq!(back, mesh, "{format:?}");
            assert_eq!(back.vertices[3].z.to_bits(), (-0.0f64).to_bits());
        }
    }

    #[test]
    fn binary_layout_matches_hand_encoding() {
        let mesh = TriMesh {
            vertices: vec![
                Point3::new(1.0, 2.0, 3.0),
                Point3::new(4.0, 5.0, 6.0),
                Point3::new(7.0, 8.0, 9.5),
            ],
            triangles: vec![[0, 1, 2]],
        };
        let bytes = encode_ply_mesh(&mesh, Format::BinaryLittleEndian).unwrap();
        let header = "ply\nformat binary_little_endian 1.0\ncomment graspcell mesh (m)\nelement vertex 3\nproperty double x\nproperty double y\nproperty double z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n";
        assert!(bytes.starts_with(header.as_bytes()));
        let mut body = Vec::new();
        for v in [1.0f64, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0, 8.0, 9.5] {
            body.extend_from_slice(&v.to_le_bytes());
        }
        body.push(3);
        for i in [0i32, 1, 2] {
            body.extend_from_slice(&i.to_le_bytes());
        }
        assert_eq!(&bytes[header.len()..], &body[..]);
    }

    #[test]
    fn foreign_ascii_ply_with_polygons_is_fanned() {
        // float coordinates, `vertex_index` (as some exporters name it), a quad
        // and a triangle, extra vertex properties.
        let text = "ply\nformat ascii 1.0\ncomment from elsewhere\nelement vertex 5\nproperty float32 x\nproperty float32 y\nproperty float32 z\nproperty uint8 red\nelement face 2\nproperty list uint8 uint32 vertex_index\nend_header\n0 0 0 1\n1 0 0 1\n1 1 0 1\n0 1 0 1\n0.5 0.5 1 1\n4 0 1 2 3\n3 0 1 4\n";
        let mesh = parse_ply_mesh(text.as_bytes(), Path::new("quad.ply")).unwrap();
        assert_eq!(mesh.vertices.len(), 5);
        assert_eq!(mesh.vertices[4], Point3::new(0.5, 0.5, 1.0));
        assert_eq!(mesh.triangles, vec![[0, 1, 2], [0, 2, 3], [0, 1, 4]]);
    }

    #[test]
    fn malformed_and_truncated_ply_meshes_name_file_and_place() {
        let dir = TempDir::new("mesh-ply-bad").unwrap();
        let text = String::from_utf8(encode_ply_mesh(&cube(), Format::Ascii).unwrap()).unwrap();
        let binary = encode_ply_mesh(&cube(), Format::BinaryLittleEndian).unwrap();
        let header_len = binary
            .windows(11)
            .position(|w| w == b"end_header\n")
            .unwrap()
            + 11;
        let cases: Vec<(&str, Vec<u8>, String)> = vec![
            (
                "trunc.ply",
                binary[..binary.len() - 5].to_vec(),
                format!(
                    "element `face` row 11, byte offset {}: file ends (truncated)",
                    header_len + 8 * 24 + 11 * 13
                ),
            ),
            (
                "range.ply",
                text.replacen("3 4 6 7", "3 4 6 8", 1).into_bytes(),
                "face 3: vertex index 8 is out of range (8 vertices)".into(),
            ),
            (
                "two.ply",
                text.replacen("3 4 6 7", "2 4 6", 1).into_bytes(),
                "face 3: 2 vertices, a face needs 3".into(),
            ),
            (
                "nan.ply",
                text.replacen("1 1 0\n", "1 nan 0\n", 1).into_bytes(),
                "vertex 2 has a non-finite coordinate NaN".into(),
            ),
            (
                "number.ply",
                text.replacen("1 1 0\n", "1 1 0,5\n", 1).into_bytes(),
                "line 13: element `vertex` row 2, property `z`: `0,5` is not a double".into(),
            ),
            (
                "count.ply",
                text.replacen("element face 12", "element face 13", 1)
                    .into_bytes(),
                "line 31: file ends in element `face` row 12 of 13".into(),
            ),
            (
                "noz.ply",
                text.replacen("property double z", "property double w", 1)
                    .into_bytes(),
                "header: vertex has no `z` property".into(),
            ),
            (
                "faces.ply",
                text.replacen("vertex_indices", "corners", 1).into_bytes(),
                "header: face has no `vertex_indices` list".into(),
            ),
            (
                "empty.ply",
                text.replacen("element face 12", "element face 0", 1)
                    .lines()
                    .take(10)
                    .collect::<Vec<_>>()
                    .join("\n")
                    .replace("element vertex 8", "element vertex 0")
                    .into_bytes(),
                "mesh is empty (0 vertices, 0 triangles)".into(),
            ),
        ];
        for (name, bytes, expected) in cases {
            let path = dir.join(name);
            std::fs::write(&path, bytes).unwrap();
            let err = read_ply_mesh(&path).unwrap_err().to_string();
            assert!(err.starts_with(&path.display().to_string()), "{err}");
            assert!(err.contains(&expected), "{name}: {err}");
        }
    }
}
