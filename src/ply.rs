//! The PLY polygon file format, shared by meshes and point clouds: the header, typed
//! columns, and the ASCII and binary (little- and big-endian) encodings of the body.
//!
//! A file is a header (`ply`, `format`, `comment`, `obj_info`, `element` and
//! `property` lines, up to `end_header`) and a body holding each element's rows in
//! header order, one row per line in ASCII (as every common writer does).
//! [`parse`] gives every property of every element as a typed [`Column`];
//! [`encode`] writes the same structure back. Errors name the source and the place:
//! a header or body line for ASCII, an element row and byte offset for binary.

use crate::fsio::FileError;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

/// Errors of reading or encoding a PLY file; each names the file.
#[derive(Debug, thiserror::Error)]
pub enum PlyError {
    /// A file could not be read or written.
    #[error(transparent)]
    File(#[from] FileError),
    /// The file is malformed at `location` ("line 7", "element vertex row 3, byte
    /// offset 120").
    #[error("{path}: {location}: {problem}")]
    Parse {
        /// The file.
        path: PathBuf,
        /// Where in the file.
        location: String,
        /// What is wrong.
        problem: String,
    },
}

/// Why a [`Ply`] cannot be encoded ([`encode`]); each names the element, property
/// or header line concerned.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum EncodeError {
    /// A comment or `obj_info` line holds a line break.
    #[error("header line {line:?} contains a line break")]
    LineBreak {
        /// The line.
        line: String,
    },
    /// An element name is empty or holds whitespace.
    #[error("element name {element:?} is not one word")]
    ElementName {
        /// The element's name.
        element: String,
    },
    /// A property name is empty or holds whitespace.
    #[error("element `{element}` property {property:?}: name is not one word")]
    PropertyName {
        /// The element.
        element: String,
        /// The property's name.
        property: String,
    },
    /// A column's row count differs from its element's.
    #[error("element `{element}` property {property:?}: {rows} rows, element has {count}")]
    RowCount {
        /// The element.
        element: String,
        /// The property.
        property: String,
        /// Rows in the column.
        rows: usize,
        /// Rows the element declares.
        count: usize,
    },
    /// A list's count type is a floating-point type.
    #[error("element `{element}` property {property:?}: list count type must be an integer type")]
    ListCountType {
        /// The element.
        element: String,
        /// The property.
        property: String,
    },
    /// A list's offsets do not match its items.
    #[error("element `{element}` property {property:?}: list offsets do not match its items")]
    ListOffsets {
        /// The element.
        element: String,
        /// The property.
        property: String,
    },
    /// A list is longer than its count type holds.
    #[error(
        "element `{element}` property {property:?}: a list of {items} items does not fit a {} length",
        .count_type.name()
    )]
    ListTooLong {
        /// The element.
        element: String,
        /// The property.
        property: String,
        /// Items in the list.
        items: usize,
        /// The count type.
        count_type: ScalarType,
    },
}

/// The body encoding named by the header's `format` line (always version 1.0).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Format {
    /// Whitespace-separated text, one element row per line.
    Ascii,
    /// Packed binary, little-endian (what we write by default).
    #[default]
    BinaryLittleEndian,
    /// Packed binary, big-endian.
    BinaryBigEndian,
}

impl Format {
    /// The header keyword of this format.
    pub fn keyword(self) -> &'static str {
        match self {
            Format::Ascii => "ascii",
            Format::BinaryLittleEndian => "binary_little_endian",
            Format::BinaryBigEndian => "binary_big_endian",
        }
    }
}

/// A PLY scalar type; the header accepts both the classic names (`uchar`) and the
/// sized aliases (`uint8`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ScalarType {
    /// `char` / `int8`.
    Char,
    /// `uchar` / `uint8`.
    UChar,
    /// `short` / `int16`.
    Short,
    /// `ushort` / `uint16`.
    UShort,
    /// `int` / `int32`.
    Int,
    /// `uint` / `uint32`.
    UInt,
    /// `float` / `float32`.
    Float,
    /// `double` / `float64`.
    Double,
}

impl ScalarType {
    /// The type named `name` in a header, if any.
    pub fn from_name(name: &str) -> Option<ScalarType> {
        Some(match name {
            "char" | "int8" => ScalarType::Char,
            "uchar" | "uint8" => ScalarType::UChar,
            "short" | "int16" => ScalarType::Short,
            "ushort" | "uint16" => ScalarType::UShort,
            "int" | "int32" => ScalarType::Int,
            "uint" | "uint32" => ScalarType::UInt,
            "float" | "float32" => ScalarType::Float,
            "double" | "float64" => ScalarType::Double,
            _ => return None,
        })
    }

    /// The classic name we write (`char`, `uchar`, ..., `double`).
    pub fn name(self) -> &'static str {
        match self {
            ScalarType::Char => "char",
            ScalarType::UChar => "uchar",
            ScalarType::Short => "short",
            ScalarType::UShort => "ushort",
            ScalarType::Int => "int",
            ScalarType::UInt => "uint",
            ScalarType::Float => "float",
            ScalarType::Double => "double",
        }
    }

    /// Bytes per value in a binary body.
    pub fn size(self) -> usize {
        match self {
            ScalarType::Char | ScalarType::UChar => 1,
            ScalarType::Short | ScalarType::UShort => 2,
            ScalarType::Int | ScalarType::UInt | ScalarType::Float => 4,
            ScalarType::Double => 8,
        }
    }

    /// True for the integer types (the only ones allowed as list counts).
    pub fn is_integer(self) -> bool {
        !matches!(self, ScalarType::Float | ScalarType::Double)
    }
}

/// The values of one scalar property (or the items of a list property), typed as
/// the file declares them.
#[derive(Debug, Clone, PartialEq)]
pub enum Values {
    /// `char` values.
    Char(Vec<i8>),
    /// `uchar` values.
    UChar(Vec<u8>),
    /// `short` values.
    Short(Vec<i16>),
    /// `ushort` values.
    UShort(Vec<u16>),
    /// `int` values.
    Int(Vec<i32>),
    /// `uint` values.
    UInt(Vec<u32>),
    /// `float` values.
    Float(Vec<f32>),
    /// `double` values.
    Double(Vec<f64>),
}

/// Applies `$body` to the vector inside any [`Values`] variant.
macro_rules! each_values {
    ($values:expr, $v:ident => $body:expr) => {
        match $values {
            Values::Char($v) => $body,
            Values::UChar($v) => $body,
            Values::Short($v) => $body,
            Values::UShort($v) => $body,
            Values::Int($v) => $body,
            Values::UInt($v) => $body,
            Values::Float($v) => $body,
            Values::Double($v) => $body,
        }
    };
}

/// Appends one value decoded from `bytes` (exactly its size) to a vector.
macro_rules! push_binary {
    ($v:ident, $t:ty, $bytes:expr, $big:expr) => {{
        let raw: [u8; std::mem::size_of::<$t>()] = $bytes.try_into().expect("sized slice");
        $v.push(if $big {
            <$t>::from_be_bytes(raw)
        } else {
            <$t>::from_le_bytes(raw)
        })
    }};
}

/// Appends the value at byte `$offset` of every `$row_size`-byte row of `$rows`.
macro_rules! extend_strided {
    ($v:ident, $t:ty, $rows:expr, $row_size:expr, $offset:expr, $big:expr) => {{
        const N: usize = std::mem::size_of::<$t>();
        let field =
            |row: &[u8]| -> [u8; N] { row[$offset..$offset + N].try_into().expect("sized slice") };
        let rows = $rows.chunks_exact($row_size);
        if $big {
            $v.extend(rows.map(|row| <$t>::from_be_bytes(field(row))));
        } else {
            $v.extend(rows.map(|row| <$t>::from_le_bytes(field(row))));
        }
    }};
}

impl Values {
    /// An empty column of type `ty` with room for `capacity` values.
    pub fn with_capacity(ty: ScalarType, capacity: usize) -> Values {
        match ty {
            ScalarType::Char => Values::Char(Vec::with_capacity(capacity)),
            ScalarType::UChar => Values::UChar(Vec::with_capacity(capacity)),
            ScalarType::Short => Values::Short(Vec::with_capacity(capacity)),
            ScalarType::UShort => Values::UShort(Vec::with_capacity(capacity)),
            ScalarType::Int => Values::Int(Vec::with_capacity(capacity)),
            ScalarType::UInt => Values::UInt(Vec::with_capacity(capacity)),
            ScalarType::Float => Values::Float(Vec::with_capacity(capacity)),
            ScalarType::Double => Values::Double(Vec::with_capacity(capacity)),
        }
    }

    /// The declared type of the values.
    pub fn scalar_type(&self) -> ScalarType {
        match self {
            Values::Char(_) => ScalarType::Char,
            Values::UChar(_) => ScalarType::UChar,
            Values::Short(_) => ScalarType::Short,
            Values::UShort(_) => ScalarType::UShort,
            Values::Int(_) => ScalarType::Int,
            Values::UInt(_) => ScalarType::UInt,
            Values::Float(_) => ScalarType::Float,
            Values::Double(_) => ScalarType::Double,
        }
    }

    /// Number of values.
    pub fn len(&self) -> usize {
        each_values!(self, v => v.len())
    }

    /// True when there are no values.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Value `i` as `f64` (exact for every PLY type).
    #[allow(clippy::unnecessary_cast)] // one arm of the macro is f64 already
    pub fn get_f64(&self, i: usize) -> f64 {
        each_values!(self, v => v[i] as f64)
    }

    /// Value `i` as an integer, or `None` for the float types.
    pub fn get_i64(&self, i: usize) -> Option<i64> {
        match self {
            Values::Float(_) | Values::Double(_) => None,
            Values::Char(v) => Some(v[i] as i64),
            Values::UChar(v) => Some(v[i] as i64),
            Values::Short(v) => Some(v[i] as i64),
            Values::UShort(v) => Some(v[i] as i64),
            Values::Int(v) => Some(v[i] as i64),
            Values::UInt(v) => Some(v[i] as i64),
        }
    }

    /// All values as `f32`: bit-exact for `float` columns (NaN payloads included),
    /// rounded for `double`.
    #[allow(clippy::unnecessary_cast)] // the macro's `Float` arm is taken above
    pub fn to_f32_vec(&self) -> Vec<f32> {
        match self {
            Values::Float(v) => v.clone(),
            other => each_values!(other, v => v.iter().map(|&x| x as f32).collect()),
        }
    }

    /// All values as `f64` (exact).
    #[allow(clippy::unnecessary_cast)] // one arm of the macro is f64 already
    pub fn to_f64_vec(&self) -> Vec<f64> {
        each_values!(self, v => v.iter().map(|&x| x as f64).collect())
    }

    /// Appends the value at byte `offset` of every `row_size`-byte row of `rows`
    /// (the column of a fixed-size binary element).
    fn extend_strided(&mut self, rows: &[u8], row_size: usize, offset: usize, big_endian: bool) {
        match self {
            Values::Char(v) => extend_strided!(v, i8, rows, row_size, offset, big_endian),
            Values::UChar(v) => extend_strided!(v, u8, rows, row_size, offset, big_endian),
            Values::Short(v) => extend_strided!(v, i16, rows, row_size, offset, big_endian),
            Values::UShort(v) => extend_strided!(v, u16, rows, row_size, offset, big_endian),
            Values::Int(v) => extend_strided!(v, i32, rows, row_size, offset, big_endian),
            Values::UInt(v) => extend_strided!(v, u32, rows, row_size, offset, big_endian),
            Values::Float(v) => extend_strided!(v, f32, rows, row_size, offset, big_endian),
            Values::Double(v) => extend_strided!(v, f64, rows, row_size, offset, big_endian),
        }
    }

    /// Writes the values at byte `offset` of successive `row_size`-byte rows of
    /// `rows` (the inverse of [`Values::extend_strided`]).
    fn write_strided(&self, rows: &mut [u8], row_size: usize, offset: usize, big_endian: bool) {
        each_values!(self, v => {
            for (row, x) in rows.chunks_exact_mut(row_size).zip(v) {
                let bytes = if big_endian { x.to_be_bytes() } else { x.to_le_bytes() };
                row[offset..offset + bytes.len()].copy_from_slice(&bytes);
            }
        })
    }

    /// Appends the value encoded in `bytes` (exactly [`ScalarType::size`] bytes).
    fn push_binary(&mut self, bytes: &[u8], big_endian: bool) {
        match self {
            Values::Char(v) => push_binary!(v, i8, bytes, big_endian),
            Values::UChar(v) => push_binary!(v, u8, bytes, big_endian),
            Values::Short(v) => push_binary!(v, i16, bytes, big_endian),
            Values::UShort(v) => push_binary!(v, u16, bytes, big_endian),
            Values::Int(v) => push_binary!(v, i32, bytes, big_endian),
            Values::UInt(v) => push_binary!(v, u32, bytes, big_endian),
            Values::Float(v) => push_binary!(v, f32, bytes, big_endian),
            Values::Double(v) => push_binary!(v, f64, bytes, big_endian),
        }
    }

    /// Appends the value written as `token`; the error says why it does not parse.
    fn push_text(&mut self, token: &str) -> Result<(), ValueError> {
        let name = self.scalar_type().name();
        let bad = || ValueError::NotA {
            token: token.to_string(),
            type_name: name,
        };
        match self {
            Values::Float(v) => v.push(token.parse().map_err(|_| bad())?),
            Values::Double(v) => v.push(token.parse().map_err(|_| bad())?),
            Values::Char(v) => v.push(token.parse().map_err(|_| bad())?),
            Values::UChar(v) => v.push(token.parse().map_err(|_| bad())?),
            Values::Short(v) => v.push(token.parse().map_err(|_| bad())?),
            Values::UShort(v) => v.push(token.parse().map_err(|_| bad())?),
            Values::Int(v) => v.push(token.parse().map_err(|_| bad())?),
            Values::UInt(v) => v.push(token.parse().map_err(|_| bad())?),
        }
        Ok(())
    }

    /// Appends value `i` to a binary body.
    fn encode_binary(&self, i: usize, big_endian: bool, out: &mut Vec<u8>) {
        each_values!(self, v => {
            if big_endian {
                out.extend_from_slice(&v[i].to_be_bytes())
            } else {
                out.extend_from_slice(&v[i].to_le_bytes())
            }
        })
    }

    /// Appends value `i` to an ASCII row; floats round-trip exactly (NaN as `nan`).
    fn encode_text(&self, i: usize, out: &mut String) {
        match self {
            Values::Float(v) => push_float_text(out, v[i]),
            Values::Double(v) => push_float_text(out, v[i]),
            other => each_values!(other, v => { let _ = write!(out, "{}", v[i]); }),
        }
    }
}

/// Appends a float as text that parses back to the same bits (except NaN
/// payloads): the shortest round-trip decimal, in exponent form for magnitudes
/// outside 1e-5..1e16, or `nan`, `inf`, `-inf` as C's printf writes them (which
/// PCL, Open3D and `strtod` read).
pub(crate) fn push_float_text<T>(out: &mut String, x: T)
where
    T: Copy + Into<f64> + std::fmt::Display + std::fmt::LowerExp,
{
    let v: f64 = x.into();
    if v.is_nan() {
        out.push_str("nan");
    } else if v.is_infinite() {
        out.push_str(if v > 0.0 { "inf" } else { "-inf" });
    } else if v == 0.0 || (1e-5..1e16).contains(&v.abs()) {
        let _ = write!(out, "{x}");
    } else {
        let _ = write!(out, "{x:e}");
    }
}

/// The data of one property of an element: a value per row, or a list per row.
#[derive(Debug, Clone, PartialEq)]
pub enum Column {
    /// One value per row.
    Scalar(Values),
    /// A variable-length list per row: row `i` holds `items[starts[i]..starts[i + 1]]`.
    List {
        /// The integer type of each row's length.
        count_type: ScalarType,
        /// `rows + 1` offsets into `items`, starting at 0.
        starts: Vec<usize>,
        /// The items of all rows, concatenated.
        items: Values,
    },
}

impl Column {
    /// An empty column for a header's property declaration.
    fn empty(kind: PropertyKind, capacity: usize) -> Column {
        match kind {
            PropertyKind::Scalar(ty) => Column::Scalar(Values::with_capacity(ty, capacity)),
            PropertyKind::List { count, item } => {
                let mut starts = Vec::with_capacity(capacity + 1);
                starts.push(0);
                Column::List {
                    count_type: count,
                    starts,
                    items: Values::with_capacity(item, 3 * capacity),
                }
            }
        }
    }

    /// Number of rows.
    pub fn rows(&self) -> usize {
        match self {
            Column::Scalar(v) => v.len(),
            Column::List { starts, .. } => starts.len().saturating_sub(1),
        }
    }

    /// The declaration of this column in a header (`float`, `list uchar int`).
    fn declaration(&self) -> String {
        match self {
            Column::Scalar(v) => v.scalar_type().name().to_string(),
            Column::List {
                count_type, items, ..
            } => format!("list {} {}", count_type.name(), items.scalar_type().name()),
        }
    }
}

/// The type of a property as declared in a header.
#[derive(Debug, Clone, Copy)]
enum PropertyKind {
    Scalar(ScalarType),
    List { count: ScalarType, item: ScalarType },
}

/// One named property of an element.
#[derive(Debug, Clone, PartialEq)]
pub struct Property {
    /// The property name (`x`, `vertex_indices`, ...).
    pub name: String,
    /// Its values, one entry per row of the element.
    pub column: Column,
}

/// One element (`vertex`, `face`, ...) with its rows.
#[derive(Debug, Clone, PartialEq)]
pub struct Element {
    /// The element name.
    pub name: String,
    /// Number of rows (every property has this many).
    pub count: usize,
    /// The properties, in header order.
    pub properties: Vec<Property>,
}

impl Element {
    /// The column of property `name`, if the element has it.
    pub fn property(&self, name: &str) -> Option<&Column> {
        self.properties
            .iter()
            .find(|p| p.name == name)
            .map(|p| &p.column)
    }
}

/// A whole PLY file: header information and every element's data.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Ply {
    /// The body encoding.
    pub format: Format,
    /// `comment` lines, without the keyword.
    pub comments: Vec<String>,
    /// `obj_info` lines, without the keyword.
    pub obj_info: Vec<String>,
    /// The elements, in file order.
    pub elements: Vec<Element>,
}

impl Ply {
    /// The element called `name`, if the file has it.
    pub fn element(&self, name: &str) -> Option<&Element> {
        self.elements.iter().find(|e| e.name == name)
    }
}

/// Reads and parses the PLY file at `path`.
pub fn read(path: &Path) -> Result<Ply, PlyError> {
    let bytes = crate::fsio::read(path)?;
    parse(&bytes, path)
}

/// Parses a PLY file's bytes; `source` names it in errors.
pub fn parse(bytes: &[u8], source: &Path) -> Result<Ply, PlyError> {
    let err = |location: String, problem: String| PlyError::Parse {
        path: source.to_path_buf(),
        location,
        problem,
    };
    let (mut ply, body_start, header_lines) = parse_header(bytes).map_err(|(line, problem)| {
        let location = if line == 0 {
            "header".to_string()
        } else {
            format!("line {line}")
        };
        err(location, problem)
    })?;
    let body = &bytes[body_start..];
    match ply.format {
        Format::Ascii => parse_ascii_body(&mut ply, body, header_lines)
            .map_err(|(line, problem)| err(format!("line {line}"), problem)),
        Format::BinaryLittleEndian | Format::BinaryBigEndian => {
            let big = ply.format == Format::BinaryBigEndian;
            parse_binary_body(&mut ply, body, body_start, big)
                .map_err(|(location, problem)| err(location, problem))
        }
    }?;
    Ok(ply)
}

/// Parses the header; returns the elements with empty columns, the byte offset of
/// the body and the number of header lines. Errors carry a 1-based line (0 when the
/// header as a whole is wrong).
fn parse_header(bytes: &[u8]) -> Result<(Ply, usize, usize), (usize, String)> {
    let mut ply = Ply::default();
    let mut format = None;
    let mut pos = 0;
    let mut line_no = 0;
    loop {
        if pos >= bytes.len() {
            return Err((
                0,
                format!("file ends after {line_no} header lines without `end_header` (truncated?)"),
            ));
        }
        let end = bytes[pos..]
            .iter()
            .position(|&b| b == b'\n')
            .map_or(bytes.len(), |i| pos + i);
        line_no += 1;
        let raw = &bytes[pos..end];
        pos = (end + 1).min(bytes.len());
        let line = std::str::from_utf8(raw)
            .map_err(|_| (line_no, "header line is not text".to_string()))?
            .trim_end_matches('\r');
        if line_no == 1 {
            if line.trim_end() != "ply" {
                return Err((1, "not a PLY file: the first line is not `ply`".to_string()));
            }
            continue;
        }
        let mut words = line.split_whitespace();
        let keyword = words.next().unwrap_or("");
        match keyword {
            "" => {}
            "comment" => ply.comments.push(rest_after(line, "comment")),
            "obj_info" => ply.obj_info.push(rest_after(line, "obj_info")),
            "format" => {
                let words: Vec<&str> = words.collect();
                let [name, version] = words[..] else {
                    return Err((
                        line_no,
                        format!("`{line}`: expected `format <encoding> 1.0`"),
                    ));
                };
                format = Some(match name {
                    "ascii" => Format::Ascii,
                    "binary_little_endian" => Format::BinaryLittleEndian,
                    "binary_big_endian" => Format::BinaryBigEndian,
                    other => return Err((line_no, format!("unknown PLY format `{other}`"))),
                });
                if version != "1.0" && version != "1" {
                    return Err((
                        line_no,
                        format!("unsupported PLY version {version} (only 1.0)"),
                    ));
                }
            }
            "element" => {
                let words: Vec<&str> = words.collect();
                let [name, count] = words[..] else {
                    return Err((
                        line_no,
                        format!("`{line}`: expected `element <name> <count>`"),
                    ));
                };
                let count = count.parse::<usize>().map_err(|_| {
                    (
                        line_no,
                        format!("element `{name}` count `{count}` is not a non-negative integer"),
                    )
                })?;
                if ply.elements.iter().any(|e| e.name == name) {
                    return Err((line_no, format!("element `{name}` declared twice")));
                }
                ply.elements.push(Element {
                    name: name.to_string(),
                    count,
                    properties: Vec::new(),
                });
            }
            "property" => {
                let words: Vec<&str> = words.collect();
                let type_of = |name: &str| {
                    ScalarType::from_name(name)
                        .ok_or_else(|| (line_no, format!("unknown property type `{name}`")))
                };
                let (kind, name) = match words[..] {
                    ["list", count, item, name] => {
                        let count = type_of(count)?;
                        if !count.is_integer() {
                            return Err((
                                line_no,
                                format!("list `{name}` has a non-integer count type `{}`", count.name()),
                            ));
                        }
                        (PropertyKind::List { count, item: type_of(item)? }, name)
                    }
                    [ty, name] if ty != "list" => (PropertyKind::Scalar(type_of(ty)?), name),
                    _ => {
                        return Err((
                            line_no,
                            format!("`{line}`: expected `property <type> <name>` or `property list <count type> <item type> <name>`"),
                        ))
                    }
                };
                let Some(element) = ply.elements.last_mut() else {
                    return Err((line_no, format!("property `{name}` before any element")));
                };
                if element.property(name).is_some() {
                    return Err((
                        line_no,
                        format!(
                            "property `{name}` declared twice in element `{}`",
                            element.name
                        ),
                    ));
                }
                element.properties.push(Property {
                    name: name.to_string(),
                    column: Column::empty(kind, 0),
                });
            }
            "end_header" => break,
            other => return Err((line_no, format!("unknown header keyword `{other}`"))),
        }
    }
    ply.format = format.ok_or((0, "the header has no `format` line".to_string()))?;
    Ok((ply, pos, line_no))
}

/// The text of a header line after its keyword and one separating space.
fn rest_after(line: &str, keyword: &str) -> String {
    let rest = line.trim_start()[keyword.len()..].to_string();
    rest.strip_prefix(' ').map_or(rest.clone(), str::to_string)
}

/// Reserves room for `count` rows in every column of an element, bounded by what
/// `available` bytes could hold so a lying header cannot exhaust memory.
fn reserve_rows(element: &mut Element, available: usize) {
    let rows = element.count.min(available / 2 + 1);
    for property in &mut element.properties {
        let kind = match &property.column {
            Column::Scalar(v) => PropertyKind::Scalar(v.scalar_type()),
            Column::List {
                count_type, items, ..
            } => PropertyKind::List {
                count: *count_type,
                item: items.scalar_type(),
            },
        };
        property.column = Column::empty(kind, rows);
    }
}

/// Parses an ASCII body (one row per line, blank lines skipped); errors carry the
/// 1-based line number in the file.
fn parse_ascii_body(
    ply: &mut Ply,
    body: &[u8],
    header_lines: usize,
) -> Result<(), (usize, String)> {
    let mut lines = body
        .split(|&b| b == b'\n')
        .enumerate()
        .map(|(i, l)| (header_lines + 1 + i, l))
        .filter(|(_, l)| l.iter().any(|b| !b.is_ascii_whitespace()));
    let last_line = header_lines + body.split(|&b| b == b'\n').count();
    for element in &mut ply.elements {
        reserve_rows(element, body.len());
        let name = element.name.clone();
        for row in 0..element.count {
            let Some((line_no, raw)) = lines.next() else {
                return Err((
                    last_line,
                    format!(
                        "file ends in element `{name}` row {row} of {} (truncated?)",
                        element.count
                    ),
                ));
            };
            let text =
                std::str::from_utf8(raw).map_err(|_| (line_no, "line is not text".to_string()))?;
            let tokens: Vec<&str> = text.split_ascii_whitespace().collect();
            let mut next = 0;
            let mut take = |what: &str| {
                let token = tokens.get(next).copied().ok_or_else(|| {
                    (
                        line_no,
                        format!(
                            "element `{name}` row {row}: line ends after {} values, missing {what}",
                            tokens.len()
                        ),
                    )
                })?;
                next += 1;
                Ok::<&str, (usize, String)>(token)
            };
            for property in &mut element.properties {
                let context = |problem: ValueError| {
                    (
                        line_no,
                        format!(
                            "element `{name}` row {row}, property `{}`: {problem}",
                            property.name
                        ),
                    )
                };
                match &mut property.column {
                    Column::Scalar(values) => {
                        values
                            .push_text(take(&format!("`{}`", property.name))?)
                            .map_err(context)?;
                    }
                    Column::List {
                        count_type,
                        starts,
                        items,
                    } => {
                        let token = take(&format!("the length of `{}`", property.name))?;
                        let mut count = Values::with_capacity(*count_type, 1);
                        count.push_text(token).map_err(context)?;
                        let n = list_length(&count).map_err(context)?;
                        for _ in 0..n {
                            items
                                .push_text(take(&format!("an item of `{}`", property.name))?)
                                .map_err(context)?;
                        }
                        starts.push(items.len());
                    }
                }
            }
            if next != tokens.len() {
                return Err((
                    line_no,
                    format!(
                        "element `{name}` row {row}: {} values, but the header declares {next}",
                        tokens.len()
                    ),
                ));
            }
        }
    }
    if let Some((line_no, _)) = lines.next() {
        return Err((
            line_no,
            "data after the last element (header counts wrong?)".to_string(),
        ));
    }
    Ok(())
}

/// The list length held in a one-value count column; negative lengths are errors.
fn list_length(count: &Values) -> Result<usize, ValueError> {
    let n = count.get_i64(0).expect("list counts are integers");
    usize::try_from(n).map_err(|_| ValueError::NegativeListLength(n))
}

/// Why a value of a PLY body is not one of its property's.
#[derive(Debug, thiserror::Error)]
enum ValueError {
    /// The text is not a number of the property's type.
    #[error("`{token}` is not a {type_name}")]
    NotA {
        token: String,
        type_name: &'static str,
    },
    /// A list's length is negative.
    #[error("negative list length {0}")]
    NegativeListLength(i64),
}

/// Parses a binary body; errors carry "element `e` row r, byte offset o" (offsets
/// from the start of the file).
fn parse_binary_body(
    ply: &mut Ply,
    body: &[u8],
    body_start: usize,
    big_endian: bool,
) -> Result<(), (String, String)> {
    let mut pos = 0usize;
    for element in &mut ply.elements {
        reserve_rows(element, body.len() - pos);
        let name = element.name.clone();
        if let Some(row_size) = fixed_row_size(element) {
            // Fixed-size rows: check the length once, then decode column by column.
            let available = body.len() - pos;
            let needed = element.count.checked_mul(row_size);
            if needed.is_none_or(|needed| needed > available) {
                let row = available / row_size.max(1);
                return Err((
                    format!("element `{name}` row {row}, byte offset {}", body_start + pos + row * row_size),
                    format!(
                        "file ends (truncated): {} rows of {row_size} bytes declared, {available} bytes remain",
                        element.count
                    ),
                ));
            }
            let rows = &body[pos..pos + element.count * row_size];
            let mut offset = 0;
            for property in &mut element.properties {
                if let Column::Scalar(values) = &mut property.column {
                    values.extend_strided(rows, row_size, offset, big_endian);
                    offset += values.scalar_type().size();
                }
            }
            pos += rows.len();
            continue;
        }
        for row in 0..element.count {
            let row_start = pos;
            let location = || {
                format!(
                    "element `{name}` row {row}, byte offset {}",
                    body_start + row_start
                )
            };
            let mut take = |size: Option<usize>| {
                let end = size.and_then(|size| pos.checked_add(size));
                let bytes = end.and_then(|end| body.get(pos..end)).ok_or_else(|| {
                    (
                        location(),
                        format!(
                            "file ends (truncated) inside this row ({} rows declared)",
                            element.count
                        ),
                    )
                })?;
                pos += bytes.len();
                Ok::<&[u8], (String, String)>(bytes)
            };
            for property in &mut element.properties {
                match &mut property.column {
                    Column::Scalar(values) => {
                        let size = values.scalar_type().size();
                        values.push_binary(take(Some(size))?, big_endian);
                    }
                    Column::List {
                        count_type,
                        starts,
                        items,
                    } => {
                        let mut count = Values::with_capacity(*count_type, 1);
                        count.push_binary(take(Some(count_type.size()))?, big_endian);
                        let n = list_length(&count).map_err(|problem| {
                            (
                                location(),
                                format!("property `{}`: {problem}", property.name),
                            )
                        })?;
                        let size = items.scalar_type().size();
                        // A list length near the count type's maximum must not wrap
                        // `n x size` to a small number of bytes.
                        let bytes = take(n.checked_mul(size))?;
                        for chunk in bytes.chunks_exact(size) {
                            items.push_binary(chunk, big_endian);
                        }
                        starts.push(items.len());
                    }
                }
            }
        }
    }
    if pos != body.len() {
        return Err((
            format!("byte offset {}", body_start + pos),
            format!(
                "{} bytes after the last element (header counts wrong?)",
                body.len() - pos
            ),
        ));
    }
    Ok(())
}

/// Bytes per row of an element whose properties are all scalars (`None` when it has
/// lists, whose rows vary in size).
fn fixed_row_size(element: &Element) -> Option<usize> {
    element
        .properties
        .iter()
        .map(|p| match &p.column {
            Column::Scalar(values) => Some(values.scalar_type().size()),
            Column::List { .. } => None,
        })
        .sum()
}

/// Encodes `ply` as a file. Fails (saying why) when it is inconsistent: a column
/// whose row count differs from its element's, list offsets that do not match their
/// items, a list longer than its count type holds, or a name or comment that would
/// break the header.
pub fn encode(ply: &Ply) -> Result<Vec<u8>, EncodeError> {
    check_consistent(ply)?;
    let mut header = format!("ply\nformat {} 1.0\n", ply.format.keyword());
    for comment in &ply.comments {
        let _ = writeln!(header, "comment {comment}");
    }
    for info in &ply.obj_info {
        let _ = writeln!(header, "obj_info {info}");
    }
    for element in &ply.elements {
        let _ = writeln!(header, "element {} {}", element.name, element.count);
        for property in &element.properties {
            let _ = writeln!(
                header,
                "property {} {}",
                property.column.declaration(),
                property.name
            );
        }
    }
    header.push_str("end_header\n");
    let mut out = header.into_bytes();
    match ply.format {
        Format::Ascii => {
            let mut text = String::new();
            for element in &ply.elements {
                for row in 0..element.count {
                    let mut first = true;
                    let mut separate = |text: &mut String| {
                        if !first {
                            text.push(' ');
                        }
                        first = false;
                    };
                    for property in &element.properties {
                        match &property.column {
                            Column::Scalar(values) => {
                                separate(&mut text);
                                values.encode_text(row, &mut text);
                            }
                            Column::List { starts, items, .. } => {
                                separate(&mut text);
                                let _ = write!(text, "{}", starts[row + 1] - starts[row]);
                                for i in starts[row]..starts[row + 1] {
                                    separate(&mut text);
                                    items.encode_text(i, &mut text);
                                }
                            }
                        }
                    }
                    text.push('\n');
                }
            }
            out.extend_from_slice(text.as_bytes());
        }
        Format::BinaryLittleEndian | Format::BinaryBigEndian => {
            let big = ply.format == Format::BinaryBigEndian;
            for element in &ply.elements {
                if let Some(row_size) = fixed_row_size(element) {
                    let start = out.len();
                    out.resize(start + element.count * row_size, 0);
                    let mut offset = 0;
                    for property in &element.properties {
                        if let Column::Scalar(values) = &property.column {
                            values.write_strided(&mut out[start..], row_size, offset, big);
                            offset += values.scalar_type().size();
                        }
                    }
                    continue;
                }
                for row in 0..element.count {
                    for property in &element.properties {
                        match &property.column {
                            Column::Scalar(values) => values.encode_binary(row, big, &mut out),
                            Column::List {
                                count_type,
                                starts,
                                items,
                            } => {
                                let n = starts[row + 1] - starts[row];
                                encode_count(*count_type, n, big, &mut out);
                                for i in starts[row]..starts[row + 1] {
                                    items.encode_binary(i, big, &mut out);
                                }
                            }
                        }
                    }
                }
            }
        }
    }
    Ok(out)
}

/// Appends a list length `n` (already checked to fit) as `count_type`.
fn encode_count(count_type: ScalarType, n: usize, big_endian: bool, out: &mut Vec<u8>) {
    let one = match count_type {
        ScalarType::Char => Values::Char(vec![n as i8]),
        ScalarType::UChar => Values::UChar(vec![n as u8]),
        ScalarType::Short => Values::Short(vec![n as i16]),
        ScalarType::UShort => Values::UShort(vec![n as u16]),
        ScalarType::Int => Values::Int(vec![n as i32]),
        ScalarType::UInt => Values::UInt(vec![n as u32]),
        ScalarType::Float | ScalarType::Double => unreachable!("checked integer count type"),
    };
    one.encode_binary(0, big_endian, out);
}

/// The largest list length a count type holds.
fn max_list_length(count_type: ScalarType) -> usize {
    match count_type {
        ScalarType::Char => i8::MAX as usize,
        ScalarType::UChar => u8::MAX as usize,
        ScalarType::Short => i16::MAX as usize,
        ScalarType::UShort => u16::MAX as usize,
        ScalarType::Int => i32::MAX as usize,
        ScalarType::UInt => u32::MAX as usize,
        ScalarType::Float | ScalarType::Double => 0,
    }
}

/// Checks that `ply` can be encoded (see [`encode`]).
fn check_consistent(ply: &Ply) -> Result<(), EncodeError> {
    let is_word = |s: &str| !s.is_empty() && !s.chars().any(|c| c.is_whitespace());
    if let Some(line) = ply
        .comments
        .iter()
        .chain(&ply.obj_info)
        .find(|l| l.contains(['\n', '\r']))
    {
        return Err(EncodeError::LineBreak { line: line.clone() });
    }
    for element in &ply.elements {
        if !is_word(&element.name) {
            return Err(EncodeError::ElementName {
                element: element.name.clone(),
            });
        }
        for property in &element.properties {
            let element_name = || element.name.clone();
            let property_name = || property.name.clone();
            if !is_word(&property.name) {
                return Err(EncodeError::PropertyName {
                    element: element_name(),
                    property: property_name(),
                });
            }
            if property.column.rows() != element.count {
                return Err(EncodeError::RowCount {
                    element: element_name(),
                    property: property_name(),
                    rows: property.column.rows(),
                    count: element.count,
                });
            }
            if let Column::List {
                count_type,
                starts,
                items,
            } = &property.column
            {
                if !count_type.is_integer() {
                    return Err(EncodeError::ListCountType {
                        element: element_name(),
                        property: property_name(),
                    });
                }
                if starts.first() != Some(&0)
                    || starts.last() != Some(&items.len())
                    || starts.windows(2).any(|w| w[1] < w[0])
                {
                    return Err(EncodeError::ListOffsets {
                        element: element_name(),
                        property: property_name(),
                    });
                }
                let max = max_list_length(*count_type);
                if let Some(n) = starts.windows(2).map(|w| w[1] - w[0]).find(|&n| n > max) {
                    return Err(EncodeError::ListTooLong {
                        element: element_name(),
                        property: property_name(),
                        items: n,
                        count_type: *count_type,
                    });
                }
            }
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn source() -> &'static Path {
        Path::new("test.ply")
    }

    /// One element of every scalar type plus a list, with awkward values.
    fn sample(format: Format) -> Ply {
        let scalar = |name: &str, values: Values| Property {
            name: name.to_string(),
            column: Column::Scalar(values),
        };
        Ply {
            format,
            comments: vec!["made by  a test".into()],
            obj_info: vec!["width 2".into()],
            elements: vec![
                Element {
                    name: "thing".into(),
                    count: 2,
                    properties: vec![
                        scalar("a", Values::Char(vec![-128, 127])),
                        scalar("b", Values::UChar(vec![0, 255])),
                        scalar("c", Values::Short(vec![-32768, 32767])),
                        scalar("d", Values::UShort(vec![0, 65535])),
                        scalar("e", Values::Int(vec![i32::MIN, i32::MAX])),
                        scalar("f", Values::UInt(vec![0, u32::MAX])),
                        scalar("g", Values::Float(vec![0.1, -f32::MIN_POSITIVE / 3.0])),
                        scalar("h", Values::Double(vec![1e300, -0.0])),
                        Property {
                            name: "l".into(),
                            column: Column::List {
                                count_type: ScalarType::UChar,
                                starts: vec![0, 3, 3],
                                items: Values::Int(vec![7, -1, 9]),
                            },
                        },
                    ],
                },
                Element {
                    name: "empty".into(),
                    count: 0,
                    properties: vec![scalar("z", Values::Float(vec![]))],
                },
            ],
        }
    }

    #[test]
    fn every_format_round_trips_every_type_exactly() {
        for format in [
            Format::Ascii,
            Format::BinaryLittleEndian,
            Format::BinaryBigEndian,
        ] {
            let ply = sample(format);
            let bytes = encode(&ply).unwrap();
            let back = parse(&bytes, source()).unwrap();
            assert_eq!(back, ply, "{format:?}");
            // PartialEq treats 0.0 == -0.0; check the sign bit survived too.
            let Some(Column::Scalar(Values::Double(h))) = back.elements[0].property("h") else {
                panic!("h is not double");
            };
            assert_eq!(h[1].to_bits(), (-0.0f64).to_bits(), "{format:?}");
        }
    }

    #[test]
    fn float_text_is_short_and_conventional() {
        let text = |x: f32| {
            let mut s = String::new();
            push_float_text(&mut s, x);
            s
        };
        assert_eq!(text(0.1), "0.1");
        assert_eq!(text(-0.0), "-0");
        assert_eq!(text(1e-8), "1e-8");
        assert_eq!(text(f32::MAX), "3.4028235e38");
        assert_eq!(text(f32::NAN), "nan");
        assert_eq!(text(f32::NEG_INFINITY), "-inf");
    }

    proptest::proptest! {
        #[test]
        fn float_text_round_trips_every_f32(bits in proptest::num::u32::ANY) {
            let x = f32::from_bits(bits);
            let mut s = String::new();
            push_float_text(&mut s, x);
            let back: f32 = s.parse().unwrap();
            proptest::prop_assert!(back.to_bits() == bits || (x.is_nan() && back.is_nan()), "{s}");
        }

        #[test]
        fn float_text_round_trips_every_f64(bits in proptest::num::u64::ANY) {
            let x = f64::from_bits(bits);
            let mut s = String::new();
            push_float_text(&mut s, x);
            let back: f64 = s.parse().unwrap();
            proptest::prop_assert!(back.to_bits() == bits || (x.is_nan() && back.is_nan()), "{s}");
        }
    }

    #[test]
    fn binary_layout_matches_hand_encoding() {
        // Independent check of byte order and layout against bytes built by hand:
        // an element with a list (row by row) and a fixed-size one (column decoding).
        let mut bytes =
            b"ply\nformat binary_big_endian 1.0\nelement v 1\nproperty float32 x\nproperty list uint8 uint16 i\nelement w 2\nproperty int16 s\nproperty float t\nend_header\n".to_vec();
        bytes.extend_from_slice(&[0x3f, 0x80, 0, 0]); // 1.0f32 big-endian
        bytes.extend_from_slice(&[2, 0x01, 0x02, 0xff, 0xfe]);
        bytes.extend_from_slice(&[0xff, 0xfe, 0x40, 0, 0, 0]); // -2i16, 2.0f32
        bytes.extend_from_slice(&[0x01, 0x00, 0xc0, 0x40, 0, 0]); // 256i16, -3.0f32
        let ply = parse(&bytes, source()).unwrap();
        let v = ply.element("v").unwrap();
        assert_eq!(
            v.property("x"),
            Some(&Column::Scalar(Values::Float(vec![1.0])))
        );
        assert_eq!(
            v.property("i"),
            Some(&Column::List {
                count_type: ScalarType::UChar,
                starts: vec![0, 2],
                items: Values::UShort(vec![0x0102, 0xfffe]),
            })
        );
        let w = ply.element("w").unwrap();
        assert_eq!(
            w.property("s"),
            Some(&Column::Scalar(Values::Short(vec![-2, 256])))
        );
        assert_eq!(
            w.property("t"),
            Some(&Column::Scalar(Values::Float(vec![2.0, -3.0])))
        );
        // Our big-endian writer gives back the same body; the little-endian one
        // puts every value the other way round.
        let out = encode(&ply).unwrap();
        assert_eq!(&out[out.len() - 21..], &bytes[bytes.len() - 21..]);
        let mut le = ply.clone();
        le.format = Format::BinaryLittleEndian;
        let out = encode(&le).unwrap();
        assert_eq!(
            &out[out.len() - 21..],
            &[
                0, 0, 0x80, 0x3f, 2, 0x02, 0x01, 0xfe, 0xff, 0xfe, 0xff, 0, 0, 0, 0x40, 0x00, 0x01,
                0, 0, 0x40, 0xc0
            ]
        );
    }

    #[test]
    fn header_keeps_comments_obj_info_and_aliases() {
        let text = "ply\r\nformat ascii 1.0\r\ncomment hello world\r\nobj_info width 3\r\nelement p 1\r\nproperty int8 a\r\nproperty uint32 b\r\nproperty float64 c\r\nend_header\r\n-1 4000000000 2.5\r\n";
        let ply = parse(text.as_bytes(), source()).unwrap();
        assert_eq!(ply.comments, vec!["hello world"]);
        assert_eq!(ply.obj_info, vec!["width 3"]);
        let p = ply.element("p").unwrap();
        assert_eq!(
            p.property("a"),
            Some(&Column::Scalar(Values::Char(vec![-1])))
        );
        assert_eq!(
            p.property("b"),
            Some(&Column::Scalar(Values::UInt(vec![4_000_000_000])))
        );
        assert_eq!(
            p.property("c"),
            Some(&Column::Scalar(Values::Double(vec![2.5])))
        );
    }

    fn parse_err(text: &[u8]) -> String {
        parse(text, source()).unwrap_err().to_string()
    }

    #[test]
    fn malformed_headers_name_the_line() {
        let head = "ply\nformat ascii 1.0\nelement v 1\nproperty float x\n";
        let cases: Vec<(String, &str)> = vec![
            ("plx\n".into(), "test.ply: line 1: not a PLY file"),
            (
                "ply\nformat ascii 2.0\n".into(),
                "line 2: unsupported PLY version 2.0",
            ),
            (
                "ply\nformat text 1.0\n".into(),
                "line 2: unknown PLY format `text`",
            ),
            (
                format!("{head}property half y\nend_header\n"),
                "line 5: unknown property type `half`",
            ),
            (
                format!("{head}property list float int y\nend_header\n"),
                "line 5: list `y` has a non-integer count type",
            ),
            (
                format!("{head}element w -2\nend_header\n"),
                "line 5: element `w` count `-2`",
            ),
            (
                format!("{head}property float x\nend_header\n"),
                "line 5: property `x` declared twice",
            ),
            (
                "ply\nformat ascii 1.0\nproperty float x\n".into(),
                "line 3: property `x` before any element",
            ),
            (
                format!("{head}bogus\n"),
                "line 5: unknown header keyword `bogus`",
            ),
            (
                head.into(),
                "header: file ends after 4 header lines without `end_header`",
            ),
            (
                "ply\nelement v 0\nend_header\n".into(),
                "header: the header has no `format` line",
            ),
        ];
        for (text, expected) in cases {
            let err = parse_err(text.as_bytes());
            assert!(err.contains(expected), "{text:?}: {err}");
        }
    }

    #[test]
    fn malformed_ascii_bodies_name_the_line() {
        let head = "ply\nformat ascii 1.0\ncomment c\nelement v 2\nproperty float x\nproperty list uchar int i\nend_header\n";
        let cases = [
            ("1 1 0\n", "line 9: file ends in element `v` row 1 of 2"),
            ("1 1 0\n2 1 0\n3\n", "line 10: data after the last element"),
            (
                "1 1 0\n2 1 0 7\n",
                "line 9: element `v` row 1: 4 values, but the header declares 3",
            ),
            (
                "1 2 0\n2 1 0\n",
                "line 8: element `v` row 0: line ends after 3 values, missing an item of `i`",
            ),
            (
                "abc 0\n2 1 0\n",
                "line 8: element `v` row 0, property `x`: `abc` is not a float",
            ),
            (
                "1 -1\n2 0\n",
                "line 8: element `v` row 0, property `i`: `-1` is not a uchar",
            ),
            (
                "1 1 2.5\n2 0\n",
                "line 8: element `v` row 0, property `i`: `2.5` is not a int",
            ),
        ];
        for (body, expected) in cases {
            let err = parse_err(format!("{head}{body}").as_bytes());
            assert!(err.starts_with("test.ply: "), "{err}");
            assert!(err.contains(expected), "{body:?}: {err}");
        }
        // Blank lines are allowed and counted.
        let ply = parse(format!("{head}\n1 0\n\n2 1 5\n").as_bytes(), source()).unwrap();
        assert_eq!(ply.elements[0].count, 2);
    }

    #[test]
    fn truncated_and_overlong_binary_bodies_name_row_and_offset() {
        let ply = sample(Format::BinaryLittleEndian);
        let bytes = encode(&ply).unwrap();
        let header_len = bytes
            .windows(11)
            .position(|w| w == b"end_header\n")
            .unwrap()
            + 11;
        // Row size: 1+1+2+2+4+4+4+8 = 26 bytes + list (1 + 3*4) = 39 for row 0.
        let row1 = header_len + 39;
        let err = parse_err(&bytes[..bytes.len() - 1]);
        assert!(
            err.contains(&format!(
                "element `thing` row 1, byte offset {row1}: file ends (truncated)"
            )),
            "{err}"
        );
        let err = parse_err(&bytes[..header_len + 10]);
        assert!(
            err.contains(&format!("row 0, byte offset {header_len}")),
            "{err}"
        );
        let mut long = bytes.clone();
        long.extend_from_slice(&[0, 0]);
        let err = parse_err(&long);
        assert!(
            err.contains(&format!(
                "byte offset {}: 2 bytes after the last element",
                bytes.len()
            )),
            "{err}"
        );
        // A header that claims a huge count fails on truncation, not on allocation.
        let huge = b"ply\nformat binary_little_endian 1.0\nelement v 4000000000000\nproperty double x\nend_header\n\0\0\0\0\0\0\0\0";
        let err = parse_err(huge);
        assert!(err.contains("element `v` row 1, byte offset"), "{err}");
        // Issue 21's trick on the other header counts: the largest list length of
        // the widest count type, of the widest items, and an element count that
        // times its row size passes usize, fail on truncation with row and offset.
        let list = b"ply\nformat binary_little_endian 1.0\nelement f 1\nproperty list uint double i\nend_header\n\xff\xff\xff\xff\0\0\0\0\0\0\0\0";
        let err = parse_err(list);
        assert!(
            err.contains(
                "element `f` row 0, byte offset 87: file ends (truncated) inside this row"
            ),
            "{err}"
        );
        let rows = b"ply\nformat binary_big_endian 1.0\nelement v 4611686018427387904\nproperty double x\nproperty double y\nend_header\n\0";
        let err = parse_err(rows);
        assert!(
            err.contains("element `v` row 0, byte offset 110: file ends (truncated): 4611686018427387904 rows of 16 bytes declared, 1 bytes remain"),
            "{err}"
        );
        let ascii = b"ply\nformat ascii 1.0\nelement f 18446744073709551615\nproperty list uint uchar i\nend_header\n4294967295 1 2\n";
        let err = parse_err(ascii);
        assert!(
            err.contains(
                "line 6: element `f` row 0: line ends after 3 values, missing an item of `i`"
            ),
            "{err}"
        );
        // Negative list lengths in a signed count type are caught.
        let neg = b"ply\nformat binary_little_endian 1.0\nelement f 1\nproperty list char int i\nend_header\n\xff";
        let err = parse_err(neg);
        assert!(
            err.contains("property `i`: negative list length -1"),
            "{err}"
        );
    }

    #[test]
    fn encode_rejects_inconsistent_data() {
        let mut ply = sample(Format::Ascii);
        ply.elements[0].count = 3;
        let e = encode(&ply).unwrap_err();
        assert!(matches!(
            e,
            EncodeError::RowCount {
                rows: 2,
                count: 3,
                ..
            }
        ));
        assert!(e.to_string().contains("2 rows, element has 3"), "{e}");
        let mut ply = sample(Format::Ascii);
        ply.elements[0].properties[8].column = Column::List {
            count_type: ScalarType::Char,
            starts: vec![0, 200, 200],
            items: Values::UChar(vec![0; 200]),
        };
        assert!(encode(&ply)
            .unwrap_err()
            .to_string()
            .contains("does not fit a char length"));
        let mut ply = sample(Format::Ascii);
        ply.comments.push("two\nlines".into());
        assert!(encode(&ply).unwrap_err().to_string().contains("line break"));
    }
}
