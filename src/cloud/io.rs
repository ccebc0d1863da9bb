//! Reading and writing point clouds: the error type, the format chosen by the file
//! extension (`.ply`, `.pcd`), and writes that never leave a half-written file.

use super::PointCloud;
use crate::fsio::FileError;
use crate::mesh::MeshError;
use std::path::{Path, PathBuf};

/// Errors of reading, writing or making point clouds; file errors name the file.
#[derive(Debug, thiserror::Error)]
pub enum CloudError {
    /// A file could not be read or written.
    #[error(transparent)]
    File(#[from] FileError),
    /// The file is malformed at `location` ("line 12", "point 7, byte offset 300",
    /// "header").
    #[error("{path}: {location}: {problem}")]
    Parse {
        /// The file.
        path: PathBuf,
        /// Where in the file.
        location: String,
        /// What is wrong.
        problem: String,
    },
    /// The file's extension names no supported format.
    #[error("{path}: unsupported point cloud format (use .ply or .pcd)")]
    UnsupportedFormat {
        /// The file.
        path: PathBuf,
    },
    /// The cloud cannot be written as it is (e.g. `width x height` is not its size).
    #[error("{path}: cannot write this cloud: {problem}")]
    Invalid {
        /// The file that was to be written.
        path: PathBuf,
        /// What is wrong with the cloud.
        problem: InvalidCloud,
    },
    /// A mesh to sample is invalid.
    #[error(transparent)]
    Mesh(#[from] MeshError),
    /// A mesh to sample has no area.
    #[error("mesh has no surface to sample: {triangles} triangles, total area {area_m2} m^2")]
    NoSurface {
        /// Number of triangles.
        triangles: usize,
        /// Their total area (m^2).
        area_m2: f64,
    },
}

/// Why a cloud cannot be encoded as it is.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum InvalidCloud {
    /// `width x height` is not the number of points.
    #[error("width {width} x height {height} = {cells}, but it has {points} points")]
    Grid {
        /// The cloud's width.
        width: u32,
        /// The cloud's height.
        height: u32,
        /// `width x height`.
        cells: u64,
        /// The number of points.
        points: usize,
    },
    /// Normals, but not one per point.
    #[error("{normals} normals for {points} points")]
    Normals {
        /// The number of normals.
        normals: usize,
        /// The number of points.
        points: usize,
    },
    /// The PLY encoder refused the cloud's columns (boxed: it is large, and rare).
    #[error(transparent)]
    Ply(Box<crate::ply::EncodeError>),
}

impl From<crate::ply::EncodeError> for InvalidCloud {
    fn from(e: crate::ply::EncodeError) -> InvalidCloud {
        InvalidCloud::Ply(Box::new(e))
    }
}

impl From<crate::ply::PlyError> for CloudError {
    fn from(e: crate::ply::PlyError) -> CloudError {
        match e {
            crate::ply::PlyError::File(e) => CloudError::File(e),
            crate::ply::PlyError::Parse {
                path,
                location,
                problem,
            } => CloudError::Parse {
                path,
                location,
                problem,
            },
        }
    }
}

/// How a cloud's values are written.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum CloudEncoding {
    /// Text, one point per line.
    Ascii,
    /// Packed little-endian binary: compact and bit-exact (the default).
    #[default]
    Binary,
}

/// A point cloud file format.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum CloudFormat {
    /// Stanford PLY, `vertex` element with `x y z [nx ny nz]`.
    Ply,
    /// PCL's PCD v0.7, `FIELDS x y z [normal_x normal_y normal_z]`.
    Pcd,
}

impl CloudFormat {
    /// The format named by `path`'s extension (case-insensitive).
    pub fn from_path(path: &Path) -> Result<CloudFormat, CloudError> {
        let ext = path
            .extension()
            .and_then(|e| e.to_str())
            .map(str::to_ascii_lowercase);
        match ext.as_deref() {
            Some("ply") => Ok(CloudFormat::Ply),
            Some("pcd") => Ok(CloudFormat::Pcd),
            _ => Err(CloudError::UnsupportedFormat {
                path: path.to_path_buf(),
            }),
        }
    }
}

/// Reads the cloud at `path`, PLY or PCD by extension.
pub fn read_cloud(path: &Path) -> Result<PointCloud, CloudError> {
    let format = CloudFormat::from_path(path)?;
    let bytes = crate::fsio::read(path)?;
    match format {
        CloudFormat::Ply => super::ply::parse_ply_cloud(&bytes, path),
        CloudFormat::Pcd => super::pcd::parse_pcd(&bytes, path),
    }
}

/// Writes `cloud` to `path`, PLY or PCD by extension, atomically (a temporary file
/// renamed into place).
pub fn write_cloud(
    path: &Path,
    cloud: &PointCloud,
    encoding: CloudEncoding,
) -> Result<(), CloudError> {
    let bytes = match CloudFormat::from_path(path)? {
        CloudFormat::Ply => super::ply::encode_ply_cloud(cloud, encoding),
        CloudFormat::Pcd => super::pcd::encode_pcd(cloud, encoding),
    }
    .map_err(|problem| CloudError::Invalid {
        path: path.to_path_buf(),
        problem,
    })?;
    Ok(crate::fsio::write(path, &bytes)?)
}

/// Checks that a cloud is consistent: `width x height` points, and one normal per
/// point when it has normals; says what is wrong otherwise.
pub fn check_shape(cloud: &PointCloud) -> Result<(), InvalidCloud> {
    let cells = cloud.width as u64 * cloud.height as u64;
    if cells != cloud.points.len() as u64 {
        return Err(InvalidCloud::Grid {
            width: cloud.width,
            height: cloud.height,
            cells,
            points: cloud.points.len(),
        });
    }
    if let Some(normals) = &cloud.normals {
        if normals.len() != cloud.points.len() {
            return Err(InvalidCloud::Normals {
                normals: normals.len(),
                points: cloud.points.len(),
            });
        }
    }
    Ok(())
}

/// Test helpers shared by the cloud and mesh file-format tests.
#[cfg(test)]
pub(crate) mod test_support {
    use super::PointCloud;
    use crate::mesh::TriMesh;
    use nalgebra::{Point3, Vector3};

    /// A unit cube's 8 corners and 12 outward triangles, built by hand.
    pub(crate) fn cube() -> TriMesh {
        let v = |x, y, z| Point3::new(x, y, z);
        TriMesh {
            vertices: vec![
                v(0.0, 0.0, 0.0),
                v(1.0, 0.0, 0.0),
                v(1.0, 1.0, 0.0),
                v(0.0, 1.0, 0.0),
                v(0.0, 0.0, 1.0),
                v(1.0, 0.0, 1.0),
                v(1.0, 1.0, 1.0),
                v(0.0, 1.0, 1.0),
            ],
            triangles: vec![
                [0, 2, 1],
                [0, 3, 2],
                [4, 5, 6],
                [4, 6, 7],
                [0, 1, 5],
                [0, 5, 4],
                [2, 3, 7],
                [2, 7, 6],
                [1, 2, 6],
                [1, 6, 5],
                [3, 0, 4],
                [3, 4, 7],
            ],
        }
    }

    /// A 3 x 2 organised cloud with a missing point and normals.
    pub(crate) fn organised() -> PointCloud {
        let nan = f32::NAN;
        PointCloud {
            points: vec![
                Point3::new(0.1, -0.2, 1.5),
                Point3::new(nan, nan, nan),
                Point3::new(1e-8, 3.0e7, -0.0),
                Point3::new(0.3, 0.3, 0.3),
                Point3::new(-1.25, 2.5, 0.7),
                Point3::new(f32::MIN_POSITIVE, -f32::MAX, 1.0 / 3.0),
            ],
            normals: Some(vec![
                Vector3::new(0.0, 0.0, 1.0),
                Vector3::new(nan, nan, nan),
                Vector3::new(0.6, 0.8, 0.0),
                Vector3::new(-1.0, 0.0, 0.0),
                Vector3::new(0.0, -0.6, 0.8),
                Vector3::new(0.2672612, 0.5345225, 0.8017837),
            ]),
            width: 3,
            height: 2,
        }
    }

    /// Asserts that two clouds are the same to the bit (NaN payloads and signs of
    /// zero included).
    pub(crate) fn assert_bit_exact(a: &PointCloud, b: &PointCloud) {
        assert_eq!((a.width, a.height), (b.width, b.height));
        let bits = |c: &PointCloud| {
            let mut v: Vec<u32> = c
                .points
                .iter()
                .flat_map(|p| p.coords.iter().map(|x| x.to_bits()).collect::<Vec<_>>())
                .collect();
            if let Some(n) = &c.normals {
                v.extend(
                    n.iter()
                        .flat_map(|p| p.iter().map(|x| x.to_bits()).collect::<Vec<_>>()),
                );
            }
            (v, c.normals.is_some())
        };
        assert_eq!(bits(a), bits(b));
    }
}

#[cfg(test)]
mod tests {
    use super::test_support::*;
    use super::*;
    use crate::fsio::TempDir;

    #[test]
    fn extension_picks_the_format() {
        assert_eq!(
            CloudFormat::from_path(Path::new("a/b.PLY")).unwrap(),
            CloudFormat::Ply
        );
        assert_eq!(
            CloudFormat::from_path(Path::new("b.pcd")).unwrap(),
            CloudFormat::Pcd
        );
        let err = read_cloud(Path::new("scan.xyz")).unwrap_err().to_string();
        assert_eq!(
            err,
            "scan.xyz: unsupported point cloud format (use .ply or .pcd)"
        );
    }

    #[test]
    fn every_format_and_encoding_round_trips_through_files() {
        let dir = TempDir::new("cloud-io").unwrap();
        let mut cloud = organised();
        // Give the NaN point a payload: binary files must keep it.
        cloud.points[1].x = f32::from_bits(0x7fc0_1234);
        for name in ["c.ply", "c.pcd"] {
            for encoding in [CloudEncoding::Ascii, CloudEncoding::Binary] {
                let path = dir.join(name);
                write_cloud(&path, &cloud, encoding).unwrap();
                let back = read_cloud(&path).unwrap();
                if encoding == CloudEncoding::Binary {
                    assert_bit_exact(&back, &cloud);
                } else {
                    // Text keeps every finite value exactly, and NaN as NaN.
                    assert_eq!((back.width, back.height), (3, 2));
                    for (p, q) in back.points.iter().zip(&cloud.points) {
                        for (x, y) in p.coords.iter().zip(q.coords.iter()) {
                            assert!(x.to_bits() == y.to_bits() || (x.is_nan() && y.is_nan()));
                        }
                    }
                }
                let temporary: Vec<_> = std::fs::read_dir(&*dir)
                    .unwrap()
                    .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
                    .filter(|name| name.contains(".tmp"))
                    .collect();
                assert!(temporary.is_empty(), "temporary files left: {temporary:?}");
            }
        }
    }

    #[test]
    fn inconsistent_cloud_is_refused_and_nothing_is_written() {
        let dir = TempDir::new("cloud-invalid").unwrap();
        let mut cloud = organised();
        cloud.width = 4;
        let path = dir.join("bad.pcd");
        let err = write_cloud(&path, &cloud, CloudEncoding::Binary)
            .unwrap_err()
            .to_string();
        assert!(
            err.contains("bad.pcd") && err.contains("width 4 x height 2 = 8, but it has 6 points"),
            "{err}"
        );
        assert!(!path.exists());
        let mut cloud = organised();
        cloud.normals.as_mut().unwrap().pop();
        let err = write_cloud(&dir.join("bad.ply"), &cloud, CloudEncoding::Ascii)
            .unwrap_err()
            .to_string();
        assert!(err.contains("5 normals for 6 points"), "{err}");
        // A refused write leaves an existing file as it was.
        let good = dir.join("good.ply");
        write_cloud(&good, &organised(), CloudEncoding::Binary).unwrap();
        let before = std::fs::read(&good).unwrap();
        assert!(write_cloud(&good, &cloud, CloudEncoding::Binary).is_err());
        assert_eq!(std::fs::read(&good).unwrap(), before);
        let err = write_cloud(
            &dir.join("missing/x.ply"),
            &organised(),
            CloudEncoding::Binary,
        )
        .unwrap_err()
        .to_string();
        assert!(err.contains("missing/x.ply"), "{err}");
    }
}
