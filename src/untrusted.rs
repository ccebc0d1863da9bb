//! Every decoder of outside bytes, by name: what the fuzz targets (`fuzz/`) and the
//! regression replay (`tests/fuzz_regressions.rs`) run, so both use one mapping.
//!
//! [`decode`] runs the same parsing and validation a command or a stage does on the
//! bytes of a file, a datagram, a CAN frame or a shared-memory message, and returns
//! its error as a [`DecodeError`]. Whatever the bytes, it returns `Ok` or `Err`: a
//! panic, a hang or an allocation sized by a header alone is a bug in the decoder.

use crate::config::{CellConfig, BUILTIN_CONFIG};
use crate::ipc::payloads::{
    from_wire_bytes, CameraStatus, CloudAck, CloudHeader, ExecutionStatus, Fits, GraspPlan,
    JointStates, Point, TrialRequest, TrialResult, MAX_CLOUD_POINTS,
};
use std::path::Path;
use std::sync::OnceLock;

/// The names of the decoders, one fuzz target each.
pub const TARGETS: &[&str] = &[
    "pcd",
    "ply",
    "obj",
    "stl",
    "fri",
    "puck",
    "ipc",
    "urdf",
    "cell_toml",
    "scene_toml",
    "teach_toml",
    "category_json",
    "calib_json",
    "grade_csv",
];

/// Why [`decode`] refused its bytes.
#[derive(Debug, thiserror::Error)]
pub enum DecodeError {
    /// No decoder has this name.
    #[error("unknown decoder `{target}` (one of {TARGETS:?})")]
    UnknownTarget {
        /// The name asked for.
        target: String,
    },
    /// A text format's bytes are not UTF-8.
    #[error("not UTF-8: {0}")]
    NotUtf8(#[from] std::str::Utf8Error),
    /// Too few bytes for a CAN frame's identifier.
    #[error("{len} bytes: no CAN identifier")]
    NoCanId {
        /// The number of bytes given.
        len: usize,
    },
    /// A shared-memory message without even its topic byte.
    #[error("empty message")]
    EmptyMessage,
    /// The decoder's own error (its type depends on the decoder).
    #[error("{0}")]
    Rejected(Box<dyn std::error::Error + Send + Sync>),
}

/// Decodes `bytes` with the decoder `target` names (one of [`TARGETS`]). An unknown
/// target is an error too.
pub fn decode(target: &str, bytes: &[u8]) -> Result<(), DecodeError> {
    let text = || std::str::from_utf8(bytes).map_err(DecodeError::from);
    let path = |name: &str| Path::new("fuzz-input").join(name);
    match target {
        "pcd" => crate::cloud::pcd::parse_pcd(bytes, &path("in.pcd"))
            .map(drop)
            .map_err(rejected),
        "ply" => {
            // The same bytes as a cloud and as a mesh (the shared PLY reader under both).
            let cloud = crate::cloud::ply::parse_ply_cloud(bytes, &path("in.ply")).map(drop);
            let mesh = crate::mesh::ply::parse_ply_mesh(bytes, &path("in.ply"))
                .and_then(|m| m.validate(&path("in.ply")));
            cloud.map_err(rejected).and(mesh.map_err(rejected))
        }
        "obj" => {
            let p = path("in.obj");
            crate::mesh::obj::parse_obj(bytes, &p)
                .and_then(|m| m.to_parry(&p).map(drop))
                .map_err(rejected)
        }
        "stl" => {
            let p = path("in.stl");
            crate::mesh::stl::parse_stl(bytes, &p)
                .and_then(|m| m.to_parry(&p).map(drop))
                .map_err(rejected)
        }
        "fri" => {
            // Both directions: what the driver receives and what the robot (simulator)
            // receives.
            use crate::hw::fri::datagram::{CommandDatagram, MeasurementDatagram};
            let measurement = MeasurementDatagram::decode(bytes).map(drop);
            let command = CommandDatagram::decode(bytes).map(drop);
            measurement.map_err(rejected).and(command.map_err(rejected))
        }
        "puck" => decode_can(bytes),
        "ipc" => decode_payload(bytes),
        "urdf" => {
            let joints = &builtin_config().robot.arm_joints;
            crate::robot::description::RobotDescription::parse(text()?, &path("in.urdf"), joints)
                .map(drop)
                .map_err(rejected)
        }
        "cell_toml" => CellConfig::parse(text()?, &path("cell.toml"))
            .map(drop)
            .map_err(rejected),
        "scene_toml" => {
            crate::sim::scene::parse_scene(text()?, &path("scene.toml"), builtin_config())
                .map(drop)
                .map_err(rejected)
        }
        "teach_toml" => crate::category::teach::TeachFile::parse_text(text()?, &path("teach.toml"))
            .map(drop)
            .map_err(rejected),
        "category_json" => crate::category::DatabaseFile::parse(text()?, &path("category.json"))
            .map(drop)
            .map_err(rejected),
        "calib_json" => crate::calib::SampleFile::parse(text()?, &path("samples.json"))
            .map(drop)
            .map_err(rejected),
        "grade_csv" => crate::trial::csv::check_grades_csv(text()?, &path("grades.csv"))
            .map(drop)
            .map_err(rejected),
        other => Err(DecodeError::UnknownTarget {
            target: other.to_string(),
        }),
    }
}

/// A decoder's error as a [`DecodeError::Rejected`].
fn rejected(e: impl std::error::Error + Send + Sync + 'static) -> DecodeError {
    DecodeError::Rejected(Box::new(e))
}

/// The built-in configuration (what the URDF and scene decoders need beside the bytes).
fn builtin_config() -> &'static CellConfig {
    static CONFIG: OnceLock<CellConfig> = OnceLock::new();
    CONFIG.get_or_init(|| {
        CellConfig::load(Path::new(BUILTIN_CONFIG)).expect("the built-in configuration is valid")
    })
}

/// A CAN frame (2 bytes of identifier, then up to 8 of data) as the hand driver and
/// the puck emulator decode it.
fn decode_can(bytes: &[u8]) -> Result<(), DecodeError> {
    use crate::hw::hand::puck;
    let (id, data) = match bytes {
        [a, b, data @ ..] => (u16::from_le_bytes([*a, *b]), data),
        _ => return Err(DecodeError::NoCanId { len: bytes.len() }),
    };
    let frame = crate::hw::can::CanFrame::new(id, data).map_err(rejected)?;
    let _ = puck::split_id(frame.id());
    let request = puck::decode_request(frame.data()).map(drop);
    let reply = puck::decode_property_reply(frame.data()).map(drop);
    let position = puck::decode_position(frame.data()).map(drop);
    request
        .map_err(rejected)
        .and(reply.map_err(rejected))
        .and(position.map_err(rejected))
}

/// A shared-memory message (the first byte chooses the topic) checked as the stage
/// that receives it does, up to the request the executor would run.
fn decode_payload(bytes: &[u8]) -> Result<(), DecodeError> {
    let Some((&topic, body)) = bytes.split_first() else {
        return Err(DecodeError::EmptyMessage);
    };
    match topic % 10 {
        0 => {
            let m: TrialRequest = from_wire_bytes(body);
            m.check().map_err(rejected)?;
        }
        1 => {
            let header_size = std::mem::size_of::<CloudHeader>();
            let header: CloudHeader = from_wire_bytes(body);
            let rest = body.get(header_size..).unwrap_or(&[]);
            let points: Vec<Point> = rest
                .chunks(std::mem::size_of::<Point>())
                .take(MAX_CLOUD_POINTS + 1)
                .map(from_wire_bytes)
                .collect();
            header.validate(points.len()).map_err(rejected)?;
        }
        2 => {
            let m: Fits = from_wire_bytes(body);
            for fit in m.fits().map_err(rejected)? {
                fit.check().map_err(rejected)?;
            }
        }
        3 => {
            let m: GraspPlan = from_wire_bytes(body);
            m.failure().map_err(rejected)?;
            m.reachable().map_err(rejected)?;
            crate::cell::execute::execution_request(&m)
                .map_err(rejected)?
                .validate()
                .map_err(rejected)?;
        }
        4 => {
            let m: JointStates = from_wire_bytes(body);
            m.joints.check().map_err(rejected)?;
        }
        5 => {
            let m: ExecutionStatus = from_wire_bytes(body);
            m.phase().map_err(rejected)?;
            m.joints.check().map_err(rejected)?;
        }
        6 => {
            let m: TrialResult = from_wire_bytes(body);
            m.grade().map_err(rejected)?;
            m.cause().map_err(rejected)?;
        }
        7 => {
            let m: CameraStatus = from_wire_bytes(body);
            m.fault().map_err(rejected)?;
        }
        _ => {
            let _: CloudAck = from_wire_bytes(body);
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_target_decodes_garbage_to_an_error_and_unknown_targets_are_refused() {
        for target in TARGETS {
            for bytes in [&b""[..], b"\xff\x00garbage", &[0u8; 64]] {
                // Must return, whatever it returns.
                let _ = decode(target, bytes);
            }
        }
        let unknown = decode("nope", b"").unwrap_err();
        assert!(matches!(&unknown, DecodeError::UnknownTarget { target } if target == "nope"));
        assert!(unknown.to_string().contains("unknown decoder"));
    }
}
