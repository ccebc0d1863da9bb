//! Every decoder of outside bytes, by name: what the fuzz targets (`fuzz/`) and the
//! regression replay (`tests/fuzz_regressions.rs`) run, so both use one mapping.
//!
//! [`decode`] runs the same parsing and validation a command or a stage does on the
//! bytes of a file, a datagram, a CAN frame or a shared-memory message, and turns
//! its error into text. Whatever the bytes, it returns `Ok` or `Err`: a panic, a
//! hang or an allocation sized by a header alone is a bug in the decoder.

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

/// Decodes `bytes` with the decoder `target` names (one of [`TARGETS`]); the error
/// as text. An unknown target is an error too.
pub fn decode(target: &str, bytes: &[u8]) -> Result<(), String> {
    let text = || std::str::from_utf8(bytes).map_err(|e| format!("not UTF-8: {e}"));
    let path = |name: &str| Path::new("fuzz-input").join(name);
    match target {
        "pcd" => crate::cloud::pcd::parse_pcd(bytes, &path("in.pcd"))
            .map(drop)
            .map_err(text_of),
        "ply" => {
            // The same bytes as a cloud and as a mesh (the shared PLY reader under both).
            let cloud = crate::cloud::ply::parse_ply_cloud(bytes, &path("in.ply")).map(drop);
            let mesh = crate::mesh::ply::parse_ply_mesh(bytes, &path("in.ply"))
                .and_then(|m| m.validate(&path("in.ply")));
            cloud.map_err(text_of).and(mesh.map_err(text_of))
        }
        "obj" => {
            let p = path("in.obj");
            crate::mesh::obj::parse_obj(bytes, &p)
                .and_then(|m| m.to_parry(&p).map(drop))
                .map_err(text_of)
        }
        "stl" => {
            let p = path("in.stl");
            crate::mesh::stl::parse_stl(bytes, &p)
                .and_then(|m| m.to_parry(&p).map(drop))
                .map_err(text_of)
        }
        "fri" => {
            // Both directions: what the driver receives and what the robot (simulator)
            // receives.
            use crate::hw::fri::datagram::{CommandDatagram, MeasurementDatagram};
            let measurement = MeasurementDatagram::decode(bytes).map(drop);
            let command = CommandDatagram::decode(bytes).map(drop);
            measurement.map_err(text_of).and(command.map_err(text_of))
        }
        "puck" => decode_can(bytes),
        "ipc" => decode_payload(bytes),
        "urdf" => {
            let joints = &builtin_config().robot.arm_joints;
            crate::robot::description::RobotDescription::parse(text()?, &path("in.urdf"), joints)
                .map(drop)
                .map_err(text_of)
        }
        "cell_toml" => CellConfig::parse(text()?, &path("cell.toml"))
            .map(drop)
            .map_err(text_of),
        "scene_toml" => {
            crate::sim::scene::parse_scene(text()?, &path("scene.toml"), builtin_config())
                .map(drop)
                .map_err(text_of)
        }
        "teach_toml" => crate::category::teach::TeachFile::parse_text(text()?, &path("teach.toml"))
            .map(drop)
            .map_err(text_of),
        "category_json" => crate::category::DatabaseFile::parse(text()?, &path("category.json"))
            .map(drop)
            .map_err(text_of),
        "calib_json" => crate::calib::SampleFile::parse(text()?, &path("samples.json"))
            .map(drop)
            .map_err(text_of),
        "grade_csv" => crate::trial::csv::check_grades_csv(text()?, &path("grades.csv"))
            .map(drop)
            .map_err(text_of),
        other => Err(format!("unknown decoder `{other}` (one of {TARGETS:?})")),
    }
}

/// An error as one line of text.
fn text_of(e: impl std::fmt::Display) -> String {
    e.to_string()
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
fn decode_can(bytes: &[u8]) -> Result<(), String> {
    use crate::hw::hand::puck;
    let (id, data) = match bytes {
        [a, b, data @ ..] => (u16::from_le_bytes([*a, *b]), data),
        _ => return Err(format!("{} bytes: no CAN identifier", bytes.len())),
    };
    let frame = crate::hw::can::CanFrame::new(id, data).map_err(text_of)?;
    let _ = puck::split_id(frame.id());
    let request = puck::decode_request(frame.data()).map(drop);
    let reply = puck::decode_property_reply(frame.data()).map(drop);
    let position = puck::decode_position(frame.data()).map(drop);
    request
        .map_err(text_of)
        .and(reply.map_err(text_of))
        .and(position.map_err(text_of))
}

/// A shared-memory message (the first byte chooses the topic) checked as the stage
/// that receives it does, up to the request the executor would run.
fn decode_payload(bytes: &[u8]) -> Result<(), String> {
    let Some((&topic, body)) = bytes.split_first() else {
        return Err("empty message".to_string());
    };
    match topic % 10 {
        0 => {
            let m: TrialRequest = from_wire_bytes(body);
            m.check().map_err(text_of)?;
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
            header.validate(points.len()).map_err(text_of)?;
        }
        2 => {
            let m: Fits = from_wire_bytes(body);
            for fit in m.fits().map_err(text_of)? {
                fit.check().map_err(text_of)?;
            }
        }
        3 => {
            let m: GraspPlan = from_wire_bytes(body);
            m.failure().map_err(text_of)?;
            m.reachable().map_err(text_of)?;
            crate::cell::execute::execution_request(&m)
                .map_err(text_of)?
                .validate()
                .map_err(text_of)?;
        }
        4 => {
            let m: JointStates = from_wire_bytes(body);
            m.joints.check().map_err(text_of)?;
        }
        5 => {
            let m: ExecutionStatus = from_wire_bytes(body);
            m.phase().map_err(text_of)?;
            m.joints.check().map_err(text_of)?;
        }
        6 => {
            let m: TrialResult = from_wire_bytes(body);
            m.grade().map_err(text_of)?;
            m.cause().map_err(text_of)?;
        }
        7 => {
            let m: CameraStatus = from_wire_bytes(body);
            m.fault().map_err(text_of)?;
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
        assert!(decode("nope", b"").unwrap_err().contains("unknown decoder"));
    }
}
