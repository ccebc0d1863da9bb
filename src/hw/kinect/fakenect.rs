//! Recordings in fakenect's directory format, which libfreenect's `fakenect`
//! library plays back in place of a device (`FAKENECT_PATH=DIR`).
//!
//! The format (libfreenect `fakenect/record.c`): `INDEX.txt` lists one file name
//! per line in playback order; a name is `T-SECONDS-TIMESTAMP.EXT` with `T` the
//! kind (`d` depth, `r` colour, `a` accelerometer), `SECONDS` the wall time of
//! the record with six decimals (playback keeps the recorded spacing) and
//! `TIMESTAMP` the device's frame counter. A depth file is `P5 640 480 65535\n`
//! then 640 x 480 raw 11-bit values as native (little-endian) `u16`; a colour
//! file `P6 640 480 255\n` then 640 x 480 RGB bytes; an accelerometer file
//! (`.dump`) the 12 bytes of `freenect_raw_tilt_state` (x, y, z counts as `i16`,
//! the tilt angle as `i8`, a pad byte, the tilt status as `i32`).
//!
//! Newer fakenect versions also read `device.json`, the device's registration
//! data (`reg_info.zero_plane_info`, `const_shift`); the writer records it, and
//! the `kinect` backend reads it when the library it runs on (fakenect) cannot
//! report the registration itself.

use super::gravity::AccelCounts;
use super::registration::{Registration, ZeroPlane};
use super::KinectError;
use crate::fsio::{FileError, FileOp};
use std::io::Write;
use std::path::{Path, PathBuf};

/// The index file's name.
pub const INDEX_FILE: &str = "INDEX.txt";

/// The registration file's name.
pub const DEVICE_FILE: &str = "device.json";

/// Size of an accelerometer record (`sizeof(freenect_raw_tilt_state)`).
pub const ACCEL_RECORD_BYTES: usize = 12;

/// Writes a fakenect directory, record by record.
#[derive(Debug)]
pub struct FakenectWriter {
    dir: PathBuf,
    index: std::io::BufWriter<std::fs::File>,
    records: usize,
}

fn io_error(op: FileOp, path: &Path, source: std::io::Error) -> KinectError {
    FileError::new(op, path, source).into()
}

impl FakenectWriter {
    /// Creates `dir` (and its parents) and its index; refuses a directory that
    /// already holds a recording, as libfreenect's `record` does.
    pub fn create(dir: &Path) -> Result<FakenectWriter, KinectError> {
        crate::fsio::create_dir_all(dir)?;
        let index_path = dir.join(INDEX_FILE);
        let file = std::fs::OpenOptions::new()
            .write(true)
            .create_new(true)
            .open(&index_path)
            .map_err(|e| {
                if e.kind() == std::io::ErrorKind::AlreadyExists {
                    KinectError::Recording {
                        path: index_path.clone(),
                        problem: "a recording is already there (use another directory)".into(),
                    }
                } else {
                    io_error(FileOp::Write, &index_path, e)
                }
            })?;
        Ok(FakenectWriter {
            dir: dir.to_path_buf(),
            index: std::io::BufWriter::new(file),
            records: 0,
        })
    }

    /// The recording's directory.
    pub fn dir(&self) -> &Path {
        &self.dir
    }

    fn record(
        &mut self,
        kind: char,
        time_s: f64,
        timestamp: u32,
        ext: &str,
        header: &[u8],
        data: &[u8],
    ) -> Result<(), KinectError> {
        let name = format!("{kind}-{time_s:.6}-{timestamp}.{ext}");
        let path = self.dir.join(&name);
        let mut bytes = Vec::with_capacity(header.len() + data.len());
        bytes.extend_from_slice(header);
        bytes.extend_from_slice(data);
        std::fs::write(&path, bytes).map_err(|e| io_error(FileOp::Write, &path, e))?;
        // The index line goes last: a reader never meets a name without its file.
        writeln!(self.index, "{name}")
            .and_then(|()| self.index.flush())
            .map_err(|e| io_error(FileOp::Write, &self.dir.join(INDEX_FILE), e))?;
        self.records += 1;
        Ok(())
    }

    /// Appends a depth frame of raw 11-bit values (`width * height` of them).
    pub fn depth(
        &mut self,
        time_s: f64,
        timestamp: u32,
        width: u32,
        height: u32,
        raw: &[u16],
    ) -> Result<(), KinectError> {
        check_len("depth frame", raw.len(), width, height, 1)?;
        let data: Vec<u8> = raw.iter().flat_map(|v| v.to_le_bytes()).collect();
        let header = format!("P5 {width} {height} 65535\n");
        self.record('d', time_s, timestamp, "pgm", header.as_bytes(), &data)
    }

    /// Appends a colour frame (`width * height * 3` RGB bytes).
    pub fn rgb(
        &mut self,
        time_s: f64,
        timestamp: u32,
        width: u32,
        height: u32,
        rgb: &[u8],
    ) -> Result<(), KinectError> {
        check_len("colour frame", rgb.len(), width, height, 3)?;
        let header = format!("P6 {width} {height} 255\n");
        self.record('r', time_s, timestamp, "ppm", header.as_bytes(), rgb)
    }

    /// Appends an accelerometer record.
    pub fn accel(
        &mut self,
        time_s: f64,
        timestamp: u32,
        counts: AccelCounts,
    ) -> Result<(), KinectError> {
        self.record('a', time_s, timestamp, "dump", &[], &accel_record(counts))
    }

    /// Writes `device.json` with the registration data.
    pub fn registration(&self, registration: &Registration) -> Result<(), KinectError> {
        let z = &registration.zero_plane;
        let json = serde_json::json!({
            "reg_info": {
                "zero_plane_info": {
                    "dcmos_emitter_distance": z.dcmos_emitter_dist,
                    "dcmos_rcmos_distance": z.dcmos_rcmos_dist,
                    "reference_distance": z.reference_distance,
                    "reference_pixel_size": z.reference_pixel_size,
                },
                "pad_info": {"start_lines": 0, "end_lines": 0, "cropping_lines": 0},
            },
            "const_shift": registration.const_shift,
        });
        let path = self.dir.join(DEVICE_FILE);
        let text = serde_json::to_string_pretty(&json).unwrap_or_default();
        std::fs::write(&path, text).map_err(|e| io_error(FileOp::Write, &path, e))
    }

    /// Number of records written.
    pub fn records(&self) -> usize {
        self.records
    }
}

fn check_len(
    what: &'static str,
    len: usize,
    width: u32,
    height: u32,
    per_pixel: usize,
) -> Result<(), KinectError> {
    let expected = width as usize * height as usize * per_pixel;
    if len != expected {
        return Err(KinectError::FrameSize {
            what,
            len,
            expected,
        });
    }
    Ok(())
}

/// The 12 bytes of `freenect_raw_tilt_state` for a reading (tilt 0, stopped).
pub fn accel_record(counts: AccelCounts) -> [u8; ACCEL_RECORD_BYTES] {
    let mut b = [0u8; ACCEL_RECORD_BYTES];
    b[0..2].copy_from_slice(&counts.x.to_le_bytes());
    b[2..4].copy_from_slice(&counts.y.to_le_bytes());
    b[4..6].copy_from_slice(&counts.z.to_le_bytes());
    b
}

/// The reading of an accelerometer record.
pub fn parse_accel_record(bytes: &[u8]) -> Option<AccelCounts> {
    if bytes.len() != ACCEL_RECORD_BYTES {
        return None;
    }
    let i = |k: usize| i16::from_le_bytes([bytes[k], bytes[k + 1]]);
    Some(AccelCounts {
        x: i(0),
        y: i(2),
        z: i(4),
    })
}

/// One snapshot of a Kinect (or of any camera as a Kinect would see it): what a
/// trial keeps so it can be replayed through the `kinect` backend and fakenect.
#[derive(Debug, Clone, PartialEq)]
pub struct RawFrame {
    /// Raw 11-bit depth, `width * height`, row-major.
    pub depth_raw: Vec<u16>,
    /// RGB bytes (`width * height * 3`), when there is colour.
    pub rgb: Option<Vec<u8>>,
    /// The accelerometer reading, when there is one.
    pub accel: Option<AccelCounts>,
    /// The depth model.
    pub registration: Registration,
    /// Image width (px).
    pub width: u32,
    /// Image height (px).
    pub height: u32,
}

impl RawFrame {
    /// Appends the frame to a recording at `time_s` (accelerometer first, so
    /// fakenect's state holds it when the depth frame is delivered, then depth,
    /// then colour), with `timestamp` as the device timestamp.
    pub fn append(
        &self,
        writer: &mut FakenectWriter,
        time_s: f64,
        timestamp: u32,
    ) -> Result<(), KinectError> {
        if let Some(a) = self.accel {
            writer.accel(time_s, timestamp, a)?;
        }
        writer.depth(time_s, timestamp, self.width, self.height, &self.depth_raw)?;
        if let Some(rgb) = &self.rgb {
            writer.rgb(time_s, timestamp, self.width, self.height, rgb)?;
        }
        Ok(())
    }

    /// Writes the frame as a recording of its own in `dir` (replaced if there),
    /// `repeat` times at 30 frames/s (the `kinect` backend drops settling frames
    /// before the one it keeps), with its `device.json`.
    pub fn write_recording(&self, dir: &Path, repeat: usize) -> Result<(), KinectError> {
        if dir.exists() {
            std::fs::remove_dir_all(dir).map_err(|e| io_error(FileOp::Remove, dir, e))?;
        }
        let mut w = FakenectWriter::create(dir)?;
        w.registration(&self.registration)?;
        for i in 0..repeat {
            self.append(&mut w, 1.0 + i as f64 / 30.0, i as u32 * 2_000_000)?;
        }
        Ok(())
    }
}

/// Reads a recording's `device.json` (`Ok(None)` when it has none).
pub fn read_registration(dir: &Path) -> Result<Option<Registration>, KinectError> {
    let path = dir.join(DEVICE_FILE);
    let text = match std::fs::read_to_string(&path) {
        Ok(t) => t,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(None),
        Err(e) => return Err(io_error(FileOp::Read, &path, e)),
    };
    let bad = |problem: String| KinectError::Recording {
        path: path.clone(),
        problem,
    };
    let json: serde_json::Value =
        serde_json::from_str(&text).map_err(|e| bad(format!("not JSON: {e}")))?;
    let zp = &json["reg_info"]["zero_plane_info"];
    let number = |v: &serde_json::Value, key: &str| {
        v[key]
            .as_f64()
            .ok_or_else(|| bad(format!("{key}: missing or not a number")))
    };
    let registration = Registration {
        zero_plane: ZeroPlane {
            dcmos_emitter_dist: number(zp, "dcmos_emitter_distance")?,
            dcmos_rcmos_dist: number(zp, "dcmos_rcmos_distance")?,
            reference_distance: number(zp, "reference_distance")?,
            reference_pixel_size: number(zp, "reference_pixel_size")?,
        },
        const_shift: number(&json, "const_shift")?,
    };
    registration.validate().map_err(|e| bad(e.to_string()))?;
    Ok(Some(registration))
}

/// One record of a recording's index.
#[derive(Debug, Clone, PartialEq)]
pub struct IndexEntry {
    /// `d`, `r` or `a`.
    pub kind: char,
    /// Recorded wall time (s).
    pub time_s: f64,
    /// Device timestamp.
    pub timestamp: u32,
    /// The file, relative to the directory.
    pub file: String,
}

/// Reads and checks a recording's index: every line parses as fakenect parses it
/// and names a file that exists.
pub fn read_index(dir: &Path) -> Result<Vec<IndexEntry>, KinectError> {
    let path = dir.join(INDEX_FILE);
    let text = crate::fsio::read_to_string(&path)?;
    text.lines()
        .enumerate()
        .map(|(i, line)| {
            let bad = |problem: &str| KinectError::Recording {
                path: path.clone(),
                problem: format!("line {}: {line:?}: {problem}", i + 1),
            };
            let mut parts = line.splitn(3, '-');
            let kind = parts
                .next()
                .and_then(|k| k.chars().next())
                .ok_or_else(|| bad("no kind"))?;
            let time_s: f64 = parts
                .next()
                .and_then(|t| t.parse().ok())
                .ok_or_else(|| bad("no time"))?;
            let timestamp: u32 = parts
                .next()
                .and_then(|t| t.split('.').next())
                .and_then(|t| t.parse().ok())
                .ok_or_else(|| bad("no timestamp"))?;
            if !matches!(kind, 'd' | 'r' | 'a') {
                return Err(bad("kind is not d, r or a"));
            }
            if !dir.join(line).is_file() {
                return Err(bad("file missing"));
            }
            Ok(IndexEntry {
                kind,
                time_s,
                timestamp,
                file: line.to_string(),
            })
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_written_recording_reads_back_in_fakenects_format() {
        let tmp = crate::fsio::TempDir::new("fakenect").unwrap();
        let dir = tmp.join("recording");
        let mut w = FakenectWriter::create(&dir).unwrap();
        let raw: Vec<u16> = (0..6).map(|i| 600 + i).collect();
        w.depth(1.5, 10, 3, 2, &raw).unwrap();
        w.rgb(1.5, 10, 3, 2, &[7u8; 18]).unwrap();
        let counts = AccelCounts {
            x: -3,
            y: 800,
            z: 120,
        };
        w.accel(1.5, 10, counts).unwrap();
        assert!(w.depth(1.6, 11, 3, 3, &raw).is_err());
        w.registration(&Registration::with_focal(525.0)).unwrap();
        drop(w);
        let index = read_index(&dir).unwrap();
        assert_eq!(index.len(), 3);
        assert_eq!(index[0].file, "d-1.500000-10.pgm");
        assert_eq!((index[2].kind, index[2].timestamp), ('a', 10));
        let depth = std::fs::read(dir.join(&index[0].file)).unwrap();
        let header = b"P5 3 2 65535\n";
        assert_eq!(&depth[..header.len()], header);
        assert_eq!(
            &depth[header.len()..header.len() + 2],
            &600u16.to_le_bytes()
        );
        let accel = std::fs::read(dir.join(&index[2].file)).unwrap();
        assert_eq!(parse_accel_record(&accel), Some(counts));
        assert_eq!(
            read_registration(&dir).unwrap(),
            Some(Registration::with_focal(525.0))
        );
        // A second recording into the same directory is refused.
        assert!(FakenectWriter::create(&dir)
            .unwrap_err()
            .to_string()
            .contains("already"));
    }
}
