//! Point clouds as PCD v0.7 files (the Point Cloud Library's format, which Open3D
//! reads too): `FIELDS x y z [normal_x normal_y normal_z]` of 4-byte floats,
//! `WIDTH`/`HEIGHT` for the organisation, `DATA ascii` or `DATA binary`
//! (little-endian, point after point). Missing points are NaN, as PCL writes them.
//!
//! Reading accepts any field list with `I`/`U`/`F` types of the PCD sizes and
//! `COUNT`s (other fields are skipped); `DATA binary_compressed` is refused with a
//! clear error. `VIEWPOINT` is checked but not kept: points stay in the file's frame.

use super::io::{check_shape, CloudEncoding, CloudError, InvalidCloud};
use super::PointCloud;
use crate::ply::push_float_text;
use nalgebra::{Point3, Vector3};
use std::fmt::Write as _;
use std::path::Path;

/// A PCD field's storage type.
#[derive(Debug, Clone, Copy, PartialEq)]
enum FieldType {
    /// Signed integer of the field's size.
    I,
    /// Unsigned integer of the field's size.
    U,
    /// IEEE float of the field's size (4 or 8).
    F,
}

/// One field of a PCD point.
#[derive(Debug, Clone)]
struct Field {
    name: String,
    size: usize,
    kind: FieldType,
    count: usize,
    /// Byte offset of the field in a binary point.
    offset: usize,
}

impl Field {
    /// Decodes the first value of this field from a binary point as `f32`
    /// (bit-exact for 4-byte floats).
    fn decode(&self, point: &[u8]) -> f32 {
        let b = &point[self.offset..self.offset + self.size];
        match (self.kind, self.size) {
            (FieldType::F, 4) => f32::from_le_bytes(b.try_into().expect("4 bytes")),
            (FieldType::F, _) => f64::from_le_bytes(b.try_into().expect("8 bytes")) as f32,
            (FieldType::I, 1) => b[0] as i8 as f32,
            (FieldType::I, 2) => i16::from_le_bytes(b.try_into().expect("2 bytes")) as f32,
            (FieldType::I, 4) => i32::from_le_bytes(b.try_into().expect("4 bytes")) as f32,
            (FieldType::I, _) => i64::from_le_bytes(b.try_into().expect("8 bytes")) as f32,
            (FieldType::U, 1) => b[0] as f32,
            (FieldType::U, 2) => u16::from_le_bytes(b.try_into().expect("2 bytes")) as f32,
            (FieldType::U, 4) => u32::from_le_bytes(b.try_into().expect("4 bytes")) as f32,
            (FieldType::U, _) => u64::from_le_bytes(b.try_into().expect("8 bytes")) as f32,
        }
    }

    /// Parses one ASCII value of this field as `f32` (the exact text for floats).
    fn parse_text(&self, token: &str) -> Result<f32, BadValue> {
        let parsed = match (self.kind, self.size) {
            (FieldType::F, 4) => token.parse::<f32>().ok(),
            (FieldType::F, _) => token.parse::<f64>().ok().map(|v| v as f32),
            (FieldType::I, _) => token
                .parse::<i64>()
                .ok()
                .filter(|&v| fits_signed(v, self.size))
                .map(|v| v as f32),
            (FieldType::U, _) => token
                .parse::<u64>()
                .ok()
                .filter(|&v| self.size == 8 || v < 1 << (8 * self.size))
                .map(|v| v as f32),
        };
        parsed.ok_or_else(|| BadValue {
            field: self.name.clone(),
            token: token.to_string(),
            kind: self.kind,
            size: self.size,
        })
    }
}

/// An ASCII value that is not one of its field's type and size.
#[derive(Debug, thiserror::Error)]
#[error("field `{field}`: `{token}` is not a {kind:?}{size} value")]
struct BadValue {
    field: String,
    token: String,
    kind: FieldType,
    size: usize,
}

/// True when `v` fits a signed integer of `size` bytes.
fn fits_signed(v: i64, size: usize) -> bool {
    size == 8 || (-(1i64 << (8 * size - 1))..(1i64 << (8 * size - 1))).contains(&v)
}

/// The parsed header: the fields, the organisation and the data encoding.
struct Header {
    fields: Vec<Field>,
    width: u32,
    height: u32,
    points: usize,
    binary: bool,
    /// Number of header lines (the data starts on the next line).
    lines: usize,
    /// Byte offset of the data.
    data_start: usize,
}

impl Header {
    /// Bytes per point in binary data.
    fn point_size(&self) -> usize {
        self.fields.iter().map(|f| f.size * f.count).sum()
    }

    /// Values per point in ASCII data.
    fn values_per_point(&self) -> usize {
        self.fields.iter().map(|f| f.count).sum()
    }

    /// The field called `name`.
    fn field(&self, name: &str) -> Option<&Field> {
        self.fields.iter().find(|f| f.name == name)
    }
}

/// Parses the header; errors carry a 1-based line number (0: the header as a whole).
fn parse_header(bytes: &[u8]) -> Result<Header, (usize, String)> {
    let mut cursor = HeaderCursor {
        bytes,
        pos: 0,
        line_no: 0,
    };
    let mut read = HeaderLines::default();
    let binary = loop {
        let line = cursor.next_line()?;
        if line.is_empty() || line.starts_with('#') {
            continue;
        }
        if let Some(binary) = read.read(cursor.line_no, line)? {
            break binary;
        }
    };
    let fields = read.fields()?;
    let (width, height, points) = read.organisation()?;
    Ok(Header {
        fields,
        width,
        height,
        points,
        binary,
        lines: cursor.line_no,
        data_start: cursor.pos,
    })
}

/// Walks the header line by line.
struct HeaderCursor<'a> {
    bytes: &'a [u8],
    /// Byte offset of the next line.
    pos: usize,
    /// Lines read so far.
    line_no: usize,
}

impl<'a> HeaderCursor<'a> {
    /// The next line, trimmed; an error at the end of the file or on a line that is not text.
    fn next_line(&mut self) -> Result<&'a str, (usize, String)> {
        let bytes = self.bytes;
        if self.pos >= bytes.len() {
            return Err((
                0,
                format!(
                    "file ends after {} header lines without a DATA line (truncated?)",
                    self.line_no
                ),
            ));
        }
        let end = bytes[self.pos..]
            .iter()
            .position(|&b| b == b'\n')
            .map_or(bytes.len(), |i| self.pos + i);
        self.line_no += 1;
        let raw = &bytes[self.pos..end];
        self.pos = (end + 1).min(bytes.len());
        Ok(std::str::from_utf8(raw)
            .map_err(|_| (self.line_no, "header line is not text".to_string()))?
            .trim())
    }
}

/// One header line: `KEY values...`.
struct HeaderLine<'a> {
    line_no: usize,
    key: &'a str,
    values: Vec<&'a str>,
}

impl HeaderLine<'_> {
    /// `problem` at this line.
    fn err(&self, problem: String) -> (usize, String) {
        (self.line_no, problem)
    }

    /// All values as non-negative integers.
    fn numbers(&self, what: &str) -> Result<Vec<usize>, (usize, String)> {
        self.values
            .iter()
            .map(|v| {
                v.parse::<usize>().map_err(|_| {
                    self.err(format!("{what} value `{v}` is not a non-negative integer"))
                })
            })
            .collect()
    }

    /// The one value, a non-negative integer.
    fn single(&self, what: &str) -> Result<usize, (usize, String)> {
        match self.numbers(what)?[..] {
            [n] => Ok(n),
            _ => Err(self.err(format!("{what} needs one value, has {}", self.values.len()))),
        }
    }

    /// An error when this key was `seen` before.
    fn once(&self, seen: bool) -> Result<(), (usize, String)> {
        if seen {
            Err(self.err(format!("{} given twice", self.key)))
        } else {
            Ok(())
        }
    }

    /// The values as field types.
    fn types(&self) -> Result<Vec<FieldType>, (usize, String)> {
        self.values
            .iter()
            .map(|t| match *t {
                "I" => Ok(FieldType::I),
                "U" => Ok(FieldType::U),
                "F" => Ok(FieldType::F),
                other => Err(self.err(format!("unknown TYPE `{other}` (use I, U or F)"))),
            })
            .collect()
    }

    /// Checks the VIEWPOINT's seven numbers.
    fn viewpoint(&self) -> Result<(), (usize, String)> {
        if self.values.len() != 7 || self.values.iter().any(|v| v.parse::<f64>().is_err()) {
            return Err(self.err(format!(
                "VIEWPOINT needs 7 numbers (tx ty tz qw qx qy qz), has `{}`",
                self.values.join(" ")
            )));
        }
        Ok(())
    }

    /// The DATA encoding: binary or not.
    fn data_binary(&self) -> Result<bool, (usize, String)> {
        match self.values[..] {
            ["ascii"] => Ok(false),
            ["binary"] => Ok(true),
            ["binary_compressed"] => Err(self.err(
                "DATA binary_compressed is not supported (save as binary or ascii)".to_string(),
            )),
            _ => Err(self.err(format!("unknown DATA encoding `{}`", self.values.join(" ")))),
        }
    }
}

/// The header's values as read, before they are checked against each other.
#[derive(Default)]
struct HeaderLines {
    version: bool,
    names: Option<Vec<String>>,
    sizes: Option<Vec<usize>>,
    types: Option<Vec<FieldType>>,
    counts: Option<Vec<usize>>,
    width: Option<usize>,
    height: Option<usize>,
    points: Option<usize>,
    viewpoint: bool,
}

impl HeaderLines {
    /// Reads one line (neither empty nor a comment); at the DATA line, whether the data is binary.
    fn read(&mut self, line_no: usize, line: &str) -> Result<Option<bool>, (usize, String)> {
        let mut words = line.split_whitespace();
        let key = words.next().expect("non-empty line");
        let line = HeaderLine {
            line_no,
            key,
            values: words.collect(),
        };
        match key {
            "VERSION" => {
                line.once(self.version)?;
                match line.values[..] {
                    ["0.7"] | [".7"] => self.version = true,
                    _ => {
                        return Err(line.err(format!(
                            "unsupported PCD version `{}` (only 0.7)",
                            line.values.join(" ")
                        )))
                    }
                }
            }
            "FIELDS" => {
                line.once(self.names.is_some())?;
                self.names = Some(line.values.iter().map(|s| s.to_string()).collect());
            }
            "SIZE" => {
                line.once(self.sizes.is_some())?;
                self.sizes = Some(line.numbers("SIZE")?);
            }
            "TYPE" => {
                line.once(self.types.is_some())?;
                self.types = Some(line.types()?);
            }
            "COUNT" => {
                line.once(self.counts.is_some())?;
                self.counts = Some(line.numbers("COUNT")?);
            }
            "WIDTH" => {
                line.once(self.width.is_some())?;
                self.width = Some(line.single("WIDTH")?);
            }
            "HEIGHT" => {
                line.once(self.height.is_some())?;
                self.height = Some(line.single("HEIGHT")?);
            }
            "POINTS" => {
                line.once(self.points.is_some())?;
                self.points = Some(line.single("POINTS")?);
            }
            "VIEWPOINT" => {
                line.once(self.viewpoint)?;
                self.viewpoint = true;
                line.viewpoint()?;
            }
            "DATA" => return line.data_binary().map(Some),
            other => return Err(line.err(format!("unknown header keyword `{other}`"))),
        }
        Ok(None)
    }

    /// The fields, laid out: VERSION, FIELDS, SIZE and TYPE given, one value per field each.
    fn fields(&mut self) -> Result<Vec<Field>, (usize, String)> {
        if !self.version {
            return Err(missing("VERSION"));
        }
        let names = self.names.take().ok_or_else(|| missing("FIELDS"))?;
        let sizes = self.sizes.take().ok_or_else(|| missing("SIZE"))?;
        let types = self.types.take().ok_or_else(|| missing("TYPE"))?;
        let counts = self.counts.take().unwrap_or_else(|| vec![1; names.len()]);
        if sizes.len() != names.len() || types.len() != names.len() || counts.len() != names.len() {
            return Err((
                0,
                format!(
                    "{} FIELDS but {} SIZE, {} TYPE and {} COUNT values",
                    names.len(),
                    sizes.len(),
                    types.len(),
                    counts.len()
                ),
            ));
        }
        lay_out_fields(names, sizes, types, counts)
    }

    /// WIDTH, HEIGHT and POINTS, checked against each other.
    fn organisation(&self) -> Result<(u32, u32, usize), (usize, String)> {
        let width = self.width.ok_or_else(|| missing("WIDTH"))?;
        let height = self.height.ok_or_else(|| missing("HEIGHT"))?;
        let (Ok(width), Ok(height)) = (u32::try_from(width), u32::try_from(height)) else {
            return Err((0, format!("WIDTH {width} x HEIGHT {height} is too large")));
        };
        let cells = width as usize * height as usize;
        let points = self.points.unwrap_or(cells);
        if points != cells {
            return Err((
                0,
                format!("POINTS {points} is not WIDTH {width} x HEIGHT {height} = {cells}"),
            ));
        }
        Ok((width, height, points))
    }
}

/// The error for a header without a `what` line.
fn missing(what: &str) -> (usize, String) {
    (0, format!("the header has no {what} line"))
}

/// The fields with their byte offsets; an error for a type and size PCD does not
/// allow, a zero count, or a point size that overflows.
fn lay_out_fields(
    names: Vec<String>,
    sizes: Vec<usize>,
    types: Vec<FieldType>,
    counts: Vec<usize>,
) -> Result<Vec<Field>, (usize, String)> {
    let mut fields = Vec::with_capacity(names.len());
    let mut offset = 0;
    for (((name, size), kind), count) in names.into_iter().zip(sizes).zip(types).zip(counts) {
        let size_ok = match kind {
            FieldType::F => size == 4 || size == 8,
            FieldType::I | FieldType::U => matches!(size, 1 | 2 | 4 | 8),
        };
        if !size_ok || count == 0 {
            return Err((
                0,
                format!("field `{name}` has TYPE {kind:?} SIZE {size} COUNT {count}, which PCD does not allow"),
            ));
        }
        let end = size
            .checked_mul(count)
            .and_then(|bytes| bytes.checked_add(offset))
            .ok_or_else(|| {
                (
                    0,
                    format!("field `{name}`: SIZE {size} x COUNT {count} overflows a point's size"),
                )
            })?;
        fields.push(Field {
            name,
            size,
            kind,
            count,
            offset,
        });
        offset = end;
    }
    Ok(fields)
}

/// Parses a PCD point cloud; `source` names the file in errors.
pub fn parse_pcd(bytes: &[u8], source: &Path) -> Result<PointCloud, CloudError> {
    let err = |location: String, problem: String| CloudError::Parse {
        path: source.to_path_buf(),
        location,
        problem,
    };
    let header = parse_header(bytes).map_err(|(line, problem)| {
        let location = if line == 0 {
            "header".to_string()
        } else {
            format!("line {line}")
        };
        err(location, problem)
    })?;
    let find = |names: [&str; 3]| -> Result<Option<[Field; 3]>, CloudError> {
        let found: Vec<Field> = names
            .iter()
            .filter_map(|n| header.field(n).cloned())
            .collect();
        match <[Field; 3]>::try_from(found) {
            Ok(fields) => Ok(Some(fields)),
            Err(found) if found.is_empty() => Ok(None),
            Err(_) => Err(err(
                "header".to_string(),
                format!("FIELDS has only some of {names:?}"),
            )),
        }
    };
    let xyz = find(["x", "y", "z"])?
        .ok_or_else(|| err("header".to_string(), "FIELDS has no `x y z`".to_string()))?;
    let normal = find(["normal_x", "normal_y", "normal_z"])?;
    let n = header.points;
    let data = &bytes[header.data_start..];
    let mut points = Vec::with_capacity(n.min(data.len() / 2 + 1));
    let mut normals = normal
        .as_ref()
        .map(|_| Vec::with_capacity(n.min(data.len() / 2 + 1)));
    if header.binary {
        let size = header.point_size();
        let Some(expected) = n.checked_mul(size) else {
            return Err(err(
                "header".to_string(),
                format!("POINTS {n} of {size} bytes each overflows the data size"),
            ));
        };
        if data.len() != expected {
            let (location, problem) = if data.len() < expected {
                let i = data.len() / size;
                (
                    format!("point {i}, byte offset {}", header.data_start + i * size),
                    format!(
                        "file ends (truncated): {n} points of {size} bytes need {expected} bytes, the data has {}",
                        data.len()
                    ),
                )
            } else {
                (
                    format!("byte offset {}", header.data_start + expected),
                    format!(
                        "{} bytes after the {n} points (POINTS wrong?)",
                        data.len() - expected
                    ),
                )
            };
            return Err(err(location, problem));
        }
        for point in data.chunks_exact(size.max(1)).take(n) {
            let [x, y, z] = &xyz;
            points.push(Point3::new(
                x.decode(point),
                y.decode(point),
                z.decode(point),
            ));
            if let (Some(normals), Some([a, b, c])) = (normals.as_mut(), normal.as_ref()) {
                normals.push(Vector3::new(
                    a.decode(point),
                    b.decode(point),
                    c.decode(point),
                ));
            }
        }
    } else {
        // Index of the first value of each wanted field within a text row.
        let mut starts = Vec::with_capacity(header.fields.len());
        let mut at = 0;
        for f in &header.fields {
            starts.push(at);
            at += f.count;
        }
        let column = |f: &Field| {
            let i = header
                .fields
                .iter()
                .position(|g| g.name == f.name)
                .expect("own field");
            starts[i]
        };
        let per_point = header.values_per_point();
        let mut lines = data
            .split(|&b| b == b'\n')
            .enumerate()
            .map(|(i, l)| (header.lines + 1 + i, l))
            .filter(|(_, l)| l.iter().any(|b| !b.is_ascii_whitespace()));
        let last_line = header.lines + data.split(|&b| b == b'\n').count();
        for i in 0..n {
            let Some((line_no, raw)) = lines.next() else {
                return Err(err(
                    format!("line {last_line}"),
                    format!("file ends at point {i} of {n} (truncated?)"),
                ));
            };
            let location = || format!("line {line_no}");
            let text = std::str::from_utf8(raw)
                .map_err(|_| err(location(), "line is not text".to_string()))?;
            let tokens: Vec<&str> = text.split_ascii_whitespace().collect();
            if tokens.len() != per_point {
                return Err(err(
                    location(),
                    format!(
                        "point {i} has {} values, FIELDS declare {per_point}",
                        tokens.len()
                    ),
                ));
            }
            let value = |f: &Field| {
                f.parse_text(tokens[column(f)])
                    .map_err(|problem| err(location(), format!("point {i}: {problem}")))
            };
            let [x, y, z] = &xyz;
            points.push(Point3::new(value(x)?, value(y)?, value(z)?));
            if let (Some(normals), Some([a, b, c])) = (normals.as_mut(), normal.as_ref()) {
                normals.push(Vector3::new(value(a)?, value(b)?, value(c)?));
            }
        }
        if let Some((line_no, _)) = lines.next() {
            return Err(err(
                format!("line {line_no}"),
                format!("data after the {n} points (POINTS wrong?)"),
            ));
        }
    }
    Ok(PointCloud {
        points,
        normals,
        width: header.width,
        height: header.height,
    })
}

/// Encodes `cloud` as a PCD v0.7 file (ASCII, or binary); says what is wrong with an
/// inconsistent cloud.
pub fn encode_pcd(cloud: &PointCloud, encoding: CloudEncoding) -> Result<Vec<u8>, InvalidCloud> {
    check_shape(cloud)?;
    let (fields, sizes, types, counts) = if cloud.normals.is_some() {
        (
            "x y z normal_x normal_y normal_z",
            "4 4 4 4 4 4",
            "F F F F F F",
            "1 1 1 1 1 1",
        )
    } else {
        ("x y z", "4 4 4", "F F F", "1 1 1")
    };
    let data = match encoding {
        CloudEncoding::Ascii => "ascii",
        CloudEncoding::Binary => "binary",
    };
    let header = format!(
        "# .PCD v0.7 - Point Cloud Data file format\nVERSION 0.7\nFIELDS {fields}\nSIZE {sizes}\nTYPE {types}\nCOUNT {counts}\nWIDTH {}\nHEIGHT {}\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS {}\nDATA {data}\n",
        cloud.width,
        cloud.height,
        cloud.len()
    );
    let mut out = header.into_bytes();
    let values = |i: usize| {
        let p = &cloud.points[i];
        let n = cloud.normals.as_ref().map(|n| n[i]);
        [p.x, p.y, p.z]
            .into_iter()
            .chain(n.into_iter().flat_map(|n| [n.x, n.y, n.z]))
    };
    match encoding {
        CloudEncoding::Binary => {
            let per_point = if cloud.normals.is_some() { 24 } else { 12 };
            out.reserve(cloud.len() * per_point);
            for i in 0..cloud.len() {
                for v in values(i) {
                    out.extend_from_slice(&v.to_le_bytes());
                }
            }
        }
        CloudEncoding::Ascii => {
            let mut text = String::with_capacity(cloud.len() * 32);
            for i in 0..cloud.len() {
                for (k, v) in values(i).enumerate() {
                    if k > 0 {
                        text.push(' ');
                    }
                    push_float_text(&mut text, v);
                }
                let _ = writeln!(text);
            }
            out.extend_from_slice(text.as_bytes());
        }
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::cloud::io::test_support::*;
    use crate::cloud::io::{read_cloud, write_cloud};
    use crate::fsio::TempDir;

    const HEADER: &str = "# .PCD v0.7 - Point Cloud Data file format\nVERSION 0.7\nFIELDS x y z normal_x normal_y normal_z\nSIZE 4 4 4 4 4 4\nTYPE F F F F F F\nCOUNT 1 1 1 1 1 1\nWIDTH 3\nHEIGHT 2\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS 6\n";

    #[test]
    fn binary_pcd_is_bit_exact_and_laid_out_as_pcl_does() {
        let cloud = organised();
        let bytes = encode_pcd(&cloud, CloudEncoding::Binary).unwrap();
        let head = format!("{HEADER}DATA binary\n");
        assert!(bytes.starts_with(head.as_bytes()));
        // Point after point, x y z nx ny nz, little-endian: built independently.
        let mut body = Vec::new();
        for (p, n) in cloud.points.iter().zip(cloud.normals.as_ref().unwrap()) {
            for v in p.iter().chain(n.iter()) {
                body.extend_from_slice(&v.to_le_bytes());
            }
        }
        assert_eq!(&bytes[head.len()..], &body[..]);
        let back = parse_pcd(&bytes, Path::new("c.pcd")).unwrap();
        assert_bit_exact(&back, &cloud);
        assert!(back.points[1].x.is_nan() && back.is_organised());
    }

    #[test]
    fn ascii_pcd_writes_nan_as_pcl_does() {
        let bytes = encode_pcd(&organised(), CloudEncoding::Ascii).unwrap();
        let text = String::from_utf8(bytes).unwrap();
        let lines: Vec<&str> = text.lines().collect();
        assert_eq!(lines[10], "DATA ascii");
        assert_eq!(lines[11], "0.1 -0.2 1.5 0 0 1");
        assert_eq!(lines[12], "nan nan nan nan nan nan");
        assert_eq!(lines.len(), 17);
    }

    #[test]
    fn pcl_style_file_with_extra_fields_is_read() {
        // PointXYZRGBNormal-like: rgb packed in a float, curvature, a padding field
        // of COUNT 3, an 8-byte x; no POINTS line (it defaults to WIDTH x HEIGHT).
        let head = "VERSION .7\nFIELDS x rgb y z _ normal_x normal_y normal_z curvature\nSIZE 8 4 4 4 1 4 4 4 4\nTYPE F F F F U F F F F\nCOUNT 1 1 1 1 3 1 1 1 1\nWIDTH 2\nHEIGHT 1\nDATA binary\n";
        let mut bytes = head.as_bytes().to_vec();
        for (x, y, z, n) in [(0.5f64, 1.0f32, -2.0f32, 1.0f32), (-0.25, 3.0, 4.0, 0.0)] {
            bytes.extend_from_slice(&x.to_le_bytes());
            bytes.extend_from_slice(&7.0f32.to_le_bytes());
            bytes.extend_from_slice(&y.to_le_bytes());
            bytes.extend_from_slice(&z.to_le_bytes());
            bytes.extend_from_slice(&[1, 2, 3]);
            for v in [0.0f32, n, 1.0 - n, 0.5] {
                bytes.extend_from_slice(&v.to_le_bytes());
            }
        }
        let cloud = parse_pcd(&bytes, Path::new("pcl.pcd")).unwrap();
        assert_eq!(
            cloud.points,
            vec![Point3::new(0.5, 1.0, -2.0), Point3::new(-0.25, 3.0, 4.0)]
        );
        assert_eq!(
            cloud.normals.unwrap(),
            vec![Vector3::new(0.0, 1.0, 0.0), Vector3::new(0.0, 0.0, 1.0)]
        );
        // The same as text, with integer fields.
        let text = "VERSION 0.7\nFIELDS i x y z\nSIZE 2 4 4 4\nTYPE I F F F\nCOUNT 1 1 1 1\nWIDTH 1\nHEIGHT 1\nPOINTS 1\nDATA ascii\n-7 1 2 nan\n";
        let cloud = parse_pcd(text.as_bytes(), Path::new("t.pcd")).unwrap();
        assert_eq!(cloud.points[0].x, 1.0);
        assert!(cloud.points[0].z.is_nan() && cloud.normals.is_none());
    }

    #[test]
    fn malformed_and_truncated_pcd_name_file_and_place() {
        let dir = TempDir::new("cloud-pcd-bad").unwrap();
        let binary = encode_pcd(&organised(), CloudEncoding::Binary).unwrap();
        let text =
            String::from_utf8(encode_pcd(&organised(), CloudEncoding::Ascii).unwrap()).unwrap();
        let data_start = HEADER.len() + "DATA binary\n".len();
        let cases: Vec<(&str, Vec<u8>, String)> = vec![
            ("trunc.pcd", binary[..binary.len() - 30].to_vec(), format!("point 4, byte offset {}: file ends (truncated): 6 points of 24 bytes need 144 bytes, the data has 114", data_start + 96)),
            ("long.pcd", [&binary[..], &[0u8; 4]].concat(), format!("byte offset {}: 4 bytes after the 6 points", data_start + 144)),
            ("trunc_text.pcd", text.lines().take(14).collect::<Vec<_>>().join("\n").into_bytes(), "line 14: file ends at point 3 of 6".into()),
            ("number.pcd", text.replacen("0.3 0.3 0.3", "0.3 0,3 0.3", 1).into_bytes(), "line 15: point 3: field `y`: `0,3` is not a F4 value".into()),
            ("values.pcd", text.replacen("0.3 0.3 0.3 -1 0 0", "0.3 0.3 0.3 -1 0", 1).into_bytes(), "line 15: point 3 has 5 values, FIELDS declare 6".into()),
            ("extra.pcd", format!("{text}1 2 3 4 5 6\n").into_bytes(), "line 18: data after the 6 points".into()),
            ("points.pcd", text.replacen("POINTS 6", "POINTS 7", 1).into_bytes(), "header: POINTS 7 is not WIDTH 3 x HEIGHT 2 = 6".into()),
            ("version.pcd", text.replacen("VERSION 0.7", "VERSION 0.5", 1).into_bytes(), "line 2: unsupported PCD version `0.5`".into()),
            ("compressed.pcd", text.replacen("DATA ascii", "DATA binary_compressed", 1).into_bytes(), "line 11: DATA binary_compressed is not supported".into()),
            ("type.pcd", text.replacen("TYPE F F F F F F", "TYPE F F F F F X", 1).into_bytes(), "line 5: unknown TYPE `X`".into()),
            ("size.pcd", text.replacen("SIZE 4 4 4 4 4 4", "SIZE 4 4 4 4 4 3", 1).into_bytes(), "header: field `normal_z` has TYPE F SIZE 3".into()),
            ("fields.pcd", text.replacen("SIZE 4 4 4 4 4 4", "SIZE 4 4 4 4 4", 1).into_bytes(), "header: 6 FIELDS but 5 SIZE".into()),
            ("noy.pcd", text.replacen("FIELDS x y", "FIELDS x q", 1).into_bytes(), "header: FIELDS has only some of [\"x\", \"y\", \"z\"]".into()),
            ("nodata.pcd", HEADER.as_bytes().to_vec(), "header: file ends after 10 header lines without a DATA line".into()),
            ("width.pcd", text.replacen("WIDTH 3", "WIDTH -3", 1).into_bytes(), "line 7: WIDTH value `-3` is not a non-negative integer".into()),
            // Header counts whose products wrap: SIZE x COUNT (issue 21's crafted file) and
            // POINTS x point size.
            ("count.pcd", [&b"VERSION 0.7\nFIELDS x y z\nSIZE 4 4 8\nTYPE F F F\nCOUNT 1 1 2305843009213693952\nWIDTH 2\nHEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS 2\nDATA binary\n"[..], &[0u8; 16]].concat(), "header: field `z`: SIZE 8 x COUNT 2305843009213693952 overflows".into()),
            ("cells.pcd", [&b"VERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\nWIDTH 4294967295\nHEIGHT 4294967295\nPOINTS 18446744065119617025\nDATA binary\n"[..], &[0u8; 12]].concat(), "header: POINTS 18446744065119617025 of 12 bytes each overflows".into()),
        ];
        for (name, bytes, expected) in cases {
            let path = dir.join(name);
            std::fs::write(&path, bytes).unwrap();
            let err = read_cloud(&path).unwrap_err().to_string();
            assert!(err.starts_with(&path.display().to_string()), "{err}");
            assert!(err.contains(&expected), "{name}: {err}");
        }
    }

    #[test]
    fn unorganised_cloud_without_normals_round_trips_in_both_encodings() {
        let dir = TempDir::new("cloud-pcd").unwrap();
        let cloud = PointCloud::from_points(vec![
            Point3::new(1.5, -2.0, 0.25),
            Point3::new(1e-3, 7.0, 9.5),
        ]);
        for encoding in [CloudEncoding::Ascii, CloudEncoding::Binary] {
            let path = dir.join("u.pcd");
            write_cloud(&path, &cloud, encoding).unwrap();
            assert_eq!(read_cloud(&path).unwrap(), cloud);
        }
    }
}
