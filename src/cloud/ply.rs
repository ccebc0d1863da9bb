//! Point clouds as PLY files: a `vertex` element with `float x y z` and optionally
//! `float nx ny nz`. An organised cloud keeps its shape in `obj_info width W` and
//! `obj_info height H` header lines (which Open3D and other readers ignore).
//!
//! Reading accepts any PLY encoding and any numeric type for the coordinates
//! (`double` is rounded to `f32`); other properties and elements are ignored.

use super::io::{check_shape, CloudEncoding, CloudError, InvalidCloud};
use super::PointCloud;
use crate::ply::{self, Column, Element, Format, Ply, Property, Values};
use nalgebra::{Point3, Vector3};
use std::path::Path;

/// Parses a PLY point cloud; `source` names the file in errors.
pub fn parse_ply_cloud(bytes: &[u8], source: &Path) -> Result<PointCloud, CloudError> {
    let ply = ply::parse(bytes, source)?;
    let header_error = |problem: String| CloudError::Parse {
        path: source.to_path_buf(),
        location: "header".to_string(),
        problem,
    };
    let vertex = ply
        .element("vertex")
        .ok_or_else(|| header_error("no `vertex` element".to_string()))?;
    let column = |name: &str| -> Result<Option<Vec<f32>>, CloudError> {
        match vertex.property(name) {
            None => Ok(None),
            Some(Column::Scalar(values)) => Ok(Some(values.to_f32_vec())),
            Some(Column::List { .. }) => Err(header_error(format!(
                "vertex property `{name}` is a list, expected a number"
            ))),
        }
    };
    let triple = |names: [&str; 3]| -> Result<Option<[Vec<f32>; 3]>, CloudError> {
        match (column(names[0])?, column(names[1])?, column(names[2])?) {
            (Some(a), Some(b), Some(c)) => Ok(Some([a, b, c])),
            (None, None, None) => Ok(None),
            _ => Err(header_error(format!(
                "vertex has only some of the properties {names:?}"
            ))),
        }
    };
    let [x, y, z] = triple(["x", "y", "z"])?
        .ok_or_else(|| header_error("vertex has no `x y z` properties".to_string()))?;
    let points = (0..vertex.count)
        .map(|i| Point3::new(x[i], y[i], z[i]))
        .collect();
    let normals = triple(["nx", "ny", "nz"])?.map(|[x, y, z]| {
        (0..vertex.count)
            .map(|i| Vector3::new(x[i], y[i], z[i]))
            .collect()
    });
    let (width, height) =
        organisation(&ply, vertex.count).map_err(|e| header_error(e.to_string()))?;
    Ok(PointCloud {
        points,
        normals,
        width,
        height,
    })
}

/// The `width x height` of `count` points from the `obj_info width W` / `obj_info
/// height H` lines: `count x 1` when there are none.
fn organisation(ply: &Ply, count: usize) -> Result<(u32, u32), OrganisationError> {
    let mut width = None;
    let mut height = None;
    for info in &ply.obj_info {
        let words: Vec<&str> = info.split_whitespace().collect();
        let slot = match words.first() {
            Some(&"width") => &mut width,
            Some(&"height") => &mut height,
            _ => continue,
        };
        let value = match words[1..] {
            [text] => text.parse::<u32>().ok(),
            _ => None,
        };
        *slot = Some(value.ok_or_else(|| OrganisationError::BadInfo {
            info: info.clone(),
            key: words[0].to_string(),
        })?);
    }
    let count_u32 = u32::try_from(count).map_err(|_| OrganisationError::TooMany { count })?;
    let (width, height) = match (width, height) {
        (None, None) => (count_u32, 1),
        (Some(w), None) => (w, 1),
        (None, Some(h)) => (count_u32.checked_div(h).unwrap_or(0), h),
        (Some(w), Some(h)) => (w, h),
    };
    if width as u64 * height as u64 != count as u64 {
        return Err(OrganisationError::Mismatch {
            width,
            height,
            count,
        });
    }
    Ok((width, height))
}

/// Why the `obj_info` lines give no organisation of the vertices.
#[derive(Debug, thiserror::Error)]
enum OrganisationError {
    /// A `width` or `height` line without one count.
    #[error("`obj_info {info}`: expected `obj_info {key} <count>`")]
    BadInfo { info: String, key: String },
    /// More vertices than a cloud's `u32` shape holds.
    #[error("{count} vertices is too many for a cloud")]
    TooMany { count: usize },
    /// The shape does not hold the vertices.
    #[error("obj_info width {width} x height {height} does not match {count} vertices")]
    Mismatch {
        width: u32,
        height: u32,
        count: usize,
    },
}

/// Encodes `cloud` as a PLY file (ASCII, or binary little-endian); says what is
/// wrong with an inconsistent cloud.
pub fn encode_ply_cloud(
    cloud: &PointCloud,
    encoding: CloudEncoding,
) -> Result<Vec<u8>, InvalidCloud> {
    check_shape(cloud)?;
    let float = |name: &str, values: Vec<f32>| Property {
        name: name.to_string(),
        column: Column::Scalar(Values::Float(values)),
    };
    let axis = |i: usize| cloud.points.iter().map(|p| p[i]).collect();
    let mut properties = vec![
        float("x", axis(0)),
        float("y", axis(1)),
        float("z", axis(2)),
    ];
    if let Some(normals) = &cloud.normals {
        for (i, name) in ["nx", "ny", "nz"].into_iter().enumerate() {
            properties.push(float(name, normals.iter().map(|n| n[i]).collect()));
        }
    }
    let obj_info = if cloud.is_organised() {
        vec![
            format!("width {}", cloud.width),
            format!("height {}", cloud.height),
        ]
    } else {
        Vec::new()
    };
    ply::encode(&Ply {
        format: match encoding {
            CloudEncoding::Ascii => Format::Ascii,
            CloudEncoding::Binary => Format::BinaryLittleEndian,
        },
        comments: vec!["graspcell point cloud (m)".to_string()],
        obj_info,
        elements: vec![Element {
            name: "vertex".to_string(),
            count: cloud.len(),
            properties,
        }],
    })
    .map_err(InvalidCloud::from)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::cloud::io::test_support::*;
    use crate::cloud::io::{read_cloud, write_cloud};
    use crate::fsio::TempDir;

    #[test]
    fn binary_ply_is_bit_exact_and_laid_out_as_specified() {
        let cloud = organised();
        let bytes = encode_ply_cloud(&cloud, CloudEncoding::Binary).unwrap();
        let text = String::from_utf8_lossy(&bytes);
        let header = "ply\nformat binary_little_endian 1.0\ncomment graspcell point cloud (m)\nobj_info width 3\nobj_info height 2\nelement vertex 6\nproperty float x\nproperty float y\nproperty float z\nproperty float nx\nproperty float ny\nproperty float nz\nend_header\n";
        assert!(text.starts_with(header), "{text}");
        // The body is the 6 floats of each point in order, little-endian: built here
        // independently of the codec.
        let mut body = Vec::new();
        let normals = cloud.normals.as_ref().unwrap();
        for (p, n) in cloud.points.iter().zip(normals) {
            for v in p.iter().chain(n.iter()) {
                body.extend_from_slice(&v.to_le_bytes());
            }
        }
        assert_eq!(&bytes[header.len()..], &body[..]);
        assert_bit_exact(
            &parse_ply_cloud(&bytes, Path::new("c.ply")).unwrap(),
            &cloud,
        );
    }

    #[test]
    fn ascii_ply_from_another_writer_is_read() {
        // As written by other tools: doubles, extra properties, a face element,
        // no organisation.
        let text = "ply\nformat ascii 1.0\nelement vertex 2\nproperty double x\nproperty double y\nproperty double z\nproperty uchar red\nelement face 0\nproperty list uchar int vertex_indices\nend_header\n0.5 -1 2e-3 255\nnan 0 0 7\n";
        let cloud = parse_ply_cloud(text.as_bytes(), Path::new("o.ply")).unwrap();
        assert_eq!((cloud.width, cloud.height), (2, 1));
        assert_eq!(cloud.points[0], Point3::new(0.5, -1.0, 0.002));
        assert!(cloud.points[1].x.is_nan());
        assert!(cloud.normals.is_none());
    }

    #[test]
    fn ascii_ply_round_trips_unorganised_cloud_without_obj_info() {
        let dir = TempDir::new("cloud-ply").unwrap();
        let cloud =
            PointCloud::from_points(vec![Point3::new(1.0, 2.0, 3.0), Point3::new(0.1, 0.2, 0.3)]);
        let path = dir.join("u.ply");
        write_cloud(&path, &cloud, CloudEncoding::Ascii).unwrap();
        let text = std::fs::read_to_string(&path).unwrap();
        assert!(
            !text.contains("obj_info") && text.ends_with("1 2 3\n0.1 0.2 0.3\n"),
            "{text}"
        );
        assert_eq!(read_cloud(&path).unwrap(), cloud);
    }

    #[test]
    fn malformed_and_truncated_ply_clouds_name_file_and_place() {
        let dir = TempDir::new("cloud-ply-bad").unwrap();
        let good = encode_ply_cloud(&organised(), CloudEncoding::Binary).unwrap();
        let good_text =
            String::from_utf8(encode_ply_cloud(&organised(), CloudEncoding::Ascii).unwrap())
                .unwrap();
        let header_len = good.windows(11).position(|w| w == b"end_header\n").unwrap() + 11;
        let cases: Vec<(&str, Vec<u8>, String)> = vec![
            (
                "trunc.ply",
                good[..good.len() - 3].to_vec(),
                format!(
                    "element `vertex` row 5, byte offset {}: file ends (truncated)",
                    header_len + 5 * 24
                ),
            ),
            (
                "trunc_text.ply",
                good_text
                    .lines()
                    .take(16)
                    .collect::<Vec<_>>()
                    .join("\n")
                    .into_bytes(),
                "line 16: file ends in element `vertex` row 3 of 6".into(),
            ),
            (
                "number.ply",
                good_text
                    .replacen("0.3 0.3 0.3", "0.3 0.3 O.3", 1)
                    .into_bytes(),
                "line 17: element `vertex` row 3, property `z`: `O.3` is not a float".into(),
            ),
            (
                "count.ply",
                good_text
                    .replacen("element vertex 6", "element vertex 5", 1)
                    .into_bytes(),
                "line 19: data after the last element".into(),
            ),
            (
                "shape.ply",
                good_text
                    .replacen("obj_info height 2", "obj_info height 3", 1)
                    .into_bytes(),
                "header: obj_info width 3 x height 3 does not match 6 vertices".into(),
            ),
            (
                "info.ply",
                good_text
                    .replacen("obj_info width 3", "obj_info width three", 1)
                    .into_bytes(),
                "header: `obj_info width three`".into(),
            ),
            (
                "nox.ply",
                good_text
                    .replacen("property float x\n", "property float q\n", 1)
                    .into_bytes(),
                "header: vertex has only some of the properties [\"x\", \"y\", \"z\"]".into(),
            ),
            (
                "version.ply",
                good_text.replacen("ascii 1.0", "ascii 1.1", 1).into_bytes(),
                "line 2: unsupported PLY version 1.1".into(),
            ),
        ];
        for (name, bytes, expected) in cases {
            let path = dir.join(name);
            std::fs::write(&path, bytes).unwrap();
            let err = read_cloud(&path).unwrap_err().to_string();
            assert!(err.starts_with(&path.display().to_string()), "{err}");
            assert!(err.contains(&expected), "{name}: {err}");
        }
        let missing = dir.join("none.ply");
        let err = read_cloud(&missing).unwrap_err().to_string();
        assert!(err.contains("none.ply"), "{err}");
    }
}
