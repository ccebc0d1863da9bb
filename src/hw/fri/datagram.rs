//! FRI 1.x datagrams: the 916-byte measurement (robot -> PC, id 0x2006) and the
//! 376-byte command (PC -> robot, id 0x1005), encoded field by field at the offsets
//! of KUKA's `friComm.h` (little-endian, `f32` IEEE-754, structs padded to 4 bytes).
//!
//! Decoding never trusts a datagram: the size, `datagramId`, header `packetSize`,
//! every enumeration and every `f32` (must be finite) are checked, and a failure is
//! a [`DatagramError`] carrying the offending numbers.

use super::JOINTS;
use serde::Serialize;
use std::fmt;

/// Size of a measurement datagram (bytes).
pub const MEASUREMENT_SIZE: usize = 916;
/// `datagramId` of a measurement datagram.
pub const MEASUREMENT_ID: u16 = 0x2006;
/// Size of a command datagram (bytes).
pub const COMMAND_SIZE: usize = 376;
/// `datagramId` of a command datagram.
pub const COMMAND_ID: u16 = 0x1005;
/// Number of values in each KRL exchange array (`FRI_USER_SIZE`).
pub const USER_SIZE: usize = 16;
/// Floats in a Cartesian frame: a 3x4 `[R|p]` matrix, row-major.
pub const FRAME_SIZE: usize = 12;
/// Floats in a Cartesian vector (force/torque, stiffness, damping).
pub const CART_VEC_SIZE: usize = 6;

// Byte offsets (friComm.h rev 1.17). Header, both directions.
const SEND_SEQ: usize = 0;
const REFL_SEQ: usize = 2;
const PACKET_SIZE: usize = 4;
const DATAGRAM_ID: usize = 6;
// KRL exchange block, both directions.
const KRL_REAL: usize = 8;
const KRL_INT: usize = 72;
const KRL_BOOL: usize = 136;
const KRL_FILL: usize = 138;
// Measurement: interface state.
const TIMESTAMP: usize = 140;
const STATE: usize = 144;
const QUALITY: usize = 146;
const DESIRED_MSR_SAMPLE_TIME: usize = 148;
const DESIRED_CMD_SAMPLE_TIME: usize = 152;
const SAFETY_LIMITS: usize = 156;
const ANSWER_RATE: usize = 160;
const LATENCY: usize = 164;
const JITTER: usize = 168;
const MISS_RATE: usize = 172;
const MISS_COUNTER: usize = 176;
// Measurement: robot state.
const POWER: usize = 180;
const CONTROL: usize = 182;
const ERROR: usize = 184;
const WARNING: usize = 186;
const TEMPERATURE: usize = 188;
// Measurement: robot data.
const MSR_JNT_POS: usize = 216;
const MSR_CART_POS: usize = 244;
const CMD_JNT_POS: usize = 292;
const CMD_JNT_POS_FRI_OFFSET: usize = 320;
const CMD_CART_POS: usize = 348;
const CMD_CART_POS_FRI_OFFSET: usize = 396;
const MSR_JNT_TRQ: usize = 444;
const EST_EXT_JNT_TRQ: usize = 472;
const EST_EXT_TCP_FT: usize = 500;
const JACOBIAN: usize = 524;
const MASS_MATRIX: usize = 692;
const GRAVITY: usize = 888;
// Command.
const CMD_FLAGS: usize = 140;
const JNT_POS: usize = 144;
const CART_POS: usize = 172;
const ADD_JNT_TRQ: usize = 220;
const ADD_TCP_FT: usize = 248;
const JNT_STIFFNESS: usize = 272;
const JNT_DAMPING: usize = 300;
const CART_STIFFNESS: usize = 328;
const CART_DAMPING: usize = 352;

// The layout is contiguous: each block ends where the next begins.
const _: () = {
    assert!(KRL_REAL + 4 * USER_SIZE == KRL_INT);
    assert!(KRL_INT + 4 * USER_SIZE == KRL_BOOL);
    assert!(MISS_COUNTER + 4 == POWER);
    assert!(TEMPERATURE + 4 * JOINTS == MSR_JNT_POS);
    assert!(MSR_JNT_POS + 4 * 175 == MEASUREMENT_SIZE);
    assert!(JACOBIAN + 4 * 6 * JOINTS == MASS_MATRIX);
    assert!(MASS_MATRIX + 4 * JOINTS * JOINTS == GRAVITY);
    assert!(GRAVITY + 4 * JOINTS == MEASUREMENT_SIZE);
    assert!(CART_DAMPING + 4 * CART_VEC_SIZE == COMMAND_SIZE);
};

/// Which datagram a message or error is about.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum DatagramKind {
    /// Robot -> PC.
    Measurement,
    /// PC -> robot.
    Command,
}

impl fmt::Display for DatagramKind {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            DatagramKind::Measurement => "FRI measurement",
            DatagramKind::Command => "FRI command",
        })
    }
}

/// Why bytes are not a valid datagram.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum DatagramError {
    /// The datagram has the wrong length.
    #[error("{kind} datagram: {actual} bytes, expected {expected}")]
    WrongSize {
        /// The expected datagram.
        kind: DatagramKind,
        /// Its size (bytes).
        expected: usize,
        /// The received length (bytes).
        actual: usize,
    },
    /// The header's `datagramId` is not the expected one.
    #[error("{kind} datagram: datagramId {actual:#06x}, expected {expected:#06x}")]
    WrongId {
        /// The expected datagram.
        kind: DatagramKind,
        /// Its id.
        expected: u16,
        /// The id in the header.
        actual: u16,
    },
    /// The header's `packetSize` disagrees with the datagram's size.
    #[error("{kind} datagram: header packetSize {actual}, expected {expected}")]
    WrongPacketSize {
        /// The expected datagram.
        kind: DatagramKind,
        /// Its size (bytes).
        expected: u16,
        /// The header's value.
        actual: u16,
    },
    /// An enumeration or flag field holds a value the protocol does not define.
    #[error("{kind} datagram: {field} = {value:#x} is not a defined value")]
    UnknownValue {
        /// The datagram.
        kind: DatagramKind,
        /// The field (friComm.h name).
        field: &'static str,
        /// The raw value.
        value: u32,
    },
    /// A float field is NaN or infinite.
    #[error("{kind} datagram: {field} at byte {offset} is {value}, not a finite number")]
    NonFinite {
        /// The datagram.
        kind: DatagramKind,
        /// The field (friComm.h name).
        field: &'static str,
        /// Byte offset of the value.
        offset: usize,
        /// The value.
        value: f32,
    },
}

/// The FRI interface state.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize)]
pub enum FriState {
    /// Not valid (-1).
    Invalid,
    /// FRI closed (0).
    #[default]
    Off,
    /// Monitor mode (1): the robot follows its own (KRL) command; PC commands are ignored.
    Monitor,
    /// Command mode (2): the robot follows the PC's commands.
    Command,
}

impl FriState {
    /// Decodes the wire value (`-1` is `0xffff`).
    pub fn from_raw(raw: u16) -> Option<FriState> {
        match raw as i16 {
            -1 => Some(FriState::Invalid),
            0 => Some(FriState::Off),
            1 => Some(FriState::Monitor),
            2 => Some(FriState::Command),
            _ => None,
        }
    }

    /// The wire value.
    pub fn raw(self) -> u16 {
        (match self {
            FriState::Invalid => -1i16,
            FriState::Off => 0,
            FriState::Monitor => 1,
            FriState::Command => 2,
        }) as u16
    }
}

/// The link quality the robot computes; ordered from worst to best.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Default, Serialize)]
pub enum Quality {
    /// Not valid (-1).
    Invalid,
    /// The robot refuses to be commanded (0).
    #[default]
    Unacceptable,
    /// Poor link (1).
    Bad,
    /// Good link (2).
    Ok,
    /// Excellent link (3); the KRL program waits for it before `friStart()`.
    Perfect,
}

impl Quality {
    /// Decodes the wire value (`-1` is `0xffff`).
    pub fn from_raw(raw: u16) -> Option<Quality> {
        match raw as i16 {
            -1 => Some(Quality::Invalid),
            0 => Some(Quality::Unacceptable),
            1 => Some(Quality::Bad),
            2 => Some(Quality::Ok),
            3 => Some(Quality::Perfect),
            _ => None,
        }
    }

    /// The wire value.
    pub fn raw(self) -> u16 {
        (match self {
            Quality::Invalid => -1i16,
            Quality::Unacceptable => 0,
            Quality::Bad => 1,
            Quality::Ok => 2,
            Quality::Perfect => 3,
        }) as u16
    }
}

/// The robot's active controller.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize)]
pub enum ControlMode {
    /// Another controller (0).
    #[default]
    Other,
    /// Joint position control (1).
    Position,
    /// Cartesian impedance control (2).
    CartesianImpedance,
    /// Joint impedance control (3).
    JointImpedance,
}

impl ControlMode {
    /// Decodes the wire value.
    pub fn from_raw(raw: u16) -> Option<ControlMode> {
        match raw {
            0 => Some(ControlMode::Other),
            1 => Some(ControlMode::Position),
            2 => Some(ControlMode::CartesianImpedance),
            3 => Some(ControlMode::JointImpedance),
            _ => None,
        }
    }

    /// The wire value.
    pub fn raw(self) -> u16 {
        match self {
            ControlMode::Other => 0,
            ControlMode::Position => 1,
            ControlMode::CartesianImpedance => 2,
            ControlMode::JointImpedance => 3,
        }
    }
}

/// Which command fields the robot uses (`cmdFlags`); may only change in monitor mode.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize)]
pub struct CmdFlags(u32);

impl CmdFlags {
    /// No command field.
    pub const NONE: CmdFlags = CmdFlags(0);
    /// `jntPos` is used.
    pub const JNT_POS: CmdFlags = CmdFlags(0x0001);
    /// `addJntTrq` is used.
    pub const JNT_TRQ: CmdFlags = CmdFlags(0x0004);
    /// `jntStiffness` is used.
    pub const JNT_STIFF: CmdFlags = CmdFlags(0x0010);
    /// `jntDamping` is used.
    pub const JNT_DAMP: CmdFlags = CmdFlags(0x0020);
    /// `cartPos` is used.
    pub const CART_POS: CmdFlags = CmdFlags(0x0100);
    /// `addTcpFT` is used.
    pub const TCP_FT: CmdFlags = CmdFlags(0x0400);
    /// `cartStiffness` is used.
    pub const CART_STIFF: CmdFlags = CmdFlags(0x1000);
    /// `cartDamping` is used.
    pub const CART_DAMP: CmdFlags = CmdFlags(0x2000);
    const ALL: u32 = 0x0001 | 0x0004 | 0x0010 | 0x0020 | 0x0100 | 0x0400 | 0x1000 | 0x2000;

    /// Decodes the wire value; `None` when an undefined bit is set.
    pub fn from_raw(raw: u32) -> Option<CmdFlags> {
        (raw & !CmdFlags::ALL == 0).then_some(CmdFlags(raw))
    }

    /// The wire value.
    pub fn raw(self) -> u32 {
        self.0
    }

    /// Whether every flag of `other` is set.
    pub fn contains(self, other: CmdFlags) -> bool {
        self.0 & other.0 == other.0
    }
}

impl std::ops::BitOr for CmdFlags {
    type Output = CmdFlags;
    fn bitor(self, rhs: CmdFlags) -> CmdFlags {
        CmdFlags(self.0 | rhs.0)
    }
}

/// The KRL exchange block (`$FRI_TO_...` / `$FRI_FRM_...` variables).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct KrlData {
    /// `realData`.
    pub real: [f32; USER_SIZE],
    /// `intData`.
    pub int: [i32; USER_SIZE],
    /// `boolData`: 16 booleans, bit i = variable i.
    pub bools: u16,
}

/// The robot's link statistics over the last 100 packets.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize)]
pub struct LinkStats {
    /// Fraction of measurements answered in time (0..=1).
    pub answer_rate: f32,
    /// Mean answer latency (s).
    pub latency_s: f32,
    /// Spread of the answer latency (s).
    pub jitter_s: f32,
    /// Fraction of measurements not answered in time (0..=1).
    pub miss_rate: f32,
    /// Measurements not answered in time since `friOpen`.
    pub miss_counter: u32,
}

/// The interface-state block of a measurement.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct InterfaceState {
    /// Robot time stamp (s).
    pub timestamp_s: f32,
    /// Monitor or command mode.
    pub state: FriState,
    /// Link quality.
    pub quality: Quality,
    /// Measurement period (s).
    pub desired_msr_sample_time_s: f32,
    /// Command period (s).
    pub desired_cmd_sample_time_s: f32,
    /// `safetyLimits` as the robot reports it.
    pub safety_limits: f32,
    /// Link statistics.
    pub stats: LinkStats,
}

/// The robot-state block of a measurement.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct RobotState {
    /// Drive power, one bit per drive; non-zero means powered.
    pub power: u16,
    /// Active controller.
    pub control: ControlMode,
    /// Error bits.
    pub error: u16,
    /// Warning bits.
    pub warning: u16,
    /// Drive temperatures as the robot reports them.
    pub temperature: [f32; JOINTS],
}

/// The robot-data block of a measurement (joint values in rad and Nm).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RobotData {
    /// Measured joint positions (rad).
    pub msr_jnt_pos: [f32; JOINTS],
    /// Measured Cartesian pose, 3x4 row-major.
    pub msr_cart_pos: [f32; FRAME_SIZE],
    /// The robot's own (KRL) commanded joint positions (rad).
    pub cmd_jnt_pos: [f32; JOINTS],
    /// Offset FRI adds to `cmd_jnt_pos` (rad).
    pub cmd_jnt_pos_fri_offset: [f32; JOINTS],
    /// Commanded Cartesian pose, 3x4 row-major.
    pub cmd_cart_pos: [f32; FRAME_SIZE],
    /// Offset FRI adds to `cmd_cart_pos`.
    pub cmd_cart_pos_fri_offset: [f32; FRAME_SIZE],
    /// Measured joint torques (Nm).
    pub msr_jnt_trq: [f32; JOINTS],
    /// Estimated external joint torques (Nm).
    pub est_ext_jnt_trq: [f32; JOINTS],
    /// Estimated external force/torque at the TCP (Fx Fy Fz Tz Ty Tx).
    pub est_ext_tcp_ft: [f32; CART_VEC_SIZE],
    /// Jacobian, 6x7 row-major, rows X Y Z RZ RY RX.
    pub jacobian: [f32; 6 * JOINTS],
    /// Mass matrix, 7x7 row-major.
    pub mass_matrix: [f32; JOINTS * JOINTS],
    /// Gravity torques (Nm).
    pub gravity: [f32; JOINTS],
}

impl Default for RobotData {
    fn default() -> RobotData {
        RobotData {
            msr_jnt_pos: [0.0; JOINTS],
            msr_cart_pos: [0.0; FRAME_SIZE],
            cmd_jnt_pos: [0.0; JOINTS],
            cmd_jnt_pos_fri_offset: [0.0; JOINTS],
            cmd_cart_pos: [0.0; FRAME_SIZE],
            cmd_cart_pos_fri_offset: [0.0; FRAME_SIZE],
            msr_jnt_trq: [0.0; JOINTS],
            est_ext_jnt_trq: [0.0; JOINTS],
            est_ext_tcp_ft: [0.0; CART_VEC_SIZE],
            jacobian: [0.0; 6 * JOINTS],
            mass_matrix: [0.0; JOINTS * JOINTS],
            gravity: [0.0; JOINTS],
        }
    }
}

/// Robot -> PC, once per cycle: 916 bytes, `datagramId` 0x2006.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct MeasurementDatagram {
    /// The robot's sequence counter (wraps 65535 -> 0).
    pub send_seq_count: u16,
    /// The `sendSeqCount` of the last command the robot received.
    pub refl_seq_count: u16,
    /// KRL exchange variables.
    pub krl: KrlData,
    /// Interface state.
    pub interface: InterfaceState,
    /// Robot state.
    pub robot: RobotState,
    /// Measured and commanded values.
    pub data: RobotData,
}

/// PC -> robot, once per measurement: 376 bytes, `datagramId` 0x1005.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct CommandDatagram {
    /// The PC's sequence counter (wraps 65535 -> 0).
    pub send_seq_count: u16,
    /// The `sendSeqCount` of the measurement this answers.
    pub refl_seq_count: u16,
    /// KRL exchange variables.
    pub krl: KrlData,
    /// Which fields the robot uses.
    pub cmd_flags: CmdFlags,
    /// Joint positions (rad).
    pub jnt_pos: [f32; JOINTS],
    /// Cartesian pose, 3x4 row-major.
    pub cart_pos: [f32; FRAME_SIZE],
    /// Additional joint torques (Nm).
    pub add_jnt_trq: [f32; JOINTS],
    /// Additional TCP force/torque.
    pub add_tcp_ft: [f32; CART_VEC_SIZE],
    /// Joint stiffness (Nm/rad).
    pub jnt_stiffness: [f32; JOINTS],
    /// Joint damping (normalised).
    pub jnt_damping: [f32; JOINTS],
    /// Cartesian stiffness.
    pub cart_stiffness: [f32; CART_VEC_SIZE],
    /// Cartesian damping (normalised).
    pub cart_damping: [f32; CART_VEC_SIZE],
}

/// How many steps `newer` is ahead of `older` on the wrapping 16-bit counter.
pub fn seq_ahead(newer: u16, older: u16) -> u16 {
    newer.wrapping_sub(older)
}

struct Writer<'a>(&'a mut [u8]);

impl Writer<'_> {
    fn u16(&mut self, at: usize, v: u16) {
        self.0[at..at + 2].copy_from_slice(&v.to_le_bytes());
    }
    fn u32(&mut self, at: usize, v: u32) {
        self.0[at..at + 4].copy_from_slice(&v.to_le_bytes());
    }
    fn f32(&mut self, at: usize, v: f32) {
        self.0[at..at + 4].copy_from_slice(&v.to_le_bytes());
    }
    fn f32s(&mut self, at: usize, values: &[f32]) {
        for (i, v) in values.iter().enumerate() {
            self.f32(at + 4 * i, *v);
        }
    }
    fn header(&mut self, send: u16, refl: u16, size: usize, id: u16) {
        self.u16(SEND_SEQ, send);
        self.u16(REFL_SEQ, refl);
        self.u16(PACKET_SIZE, size as u16);
        self.u16(DATAGRAM_ID, id);
    }
    fn krl(&mut self, krl: &KrlData) {
        self.f32s(KRL_REAL, &krl.real);
        for (i, v) in krl.int.iter().enumerate() {
            self.0[KRL_INT + 4 * i..KRL_INT + 4 * i + 4].copy_from_slice(&v.to_le_bytes());
        }
        self.u16(KRL_BOOL, krl.bools);
        self.u16(KRL_FILL, 0);
    }
}

struct Reader<'a> {
    bytes: &'a [u8],
    kind: DatagramKind,
}

impl<'a> Reader<'a> {
    /// Checks id, length and packetSize, in that order.
    fn new(
        bytes: &'a [u8],
        kind: DatagramKind,
        size: usize,
        id: u16,
    ) -> Result<Reader<'a>, DatagramError> {
        let wrong_size = || DatagramError::WrongSize {
            kind,
            expected: size,
            actual: bytes.len(),
        };
        if bytes.len() < DATAGRAM_ID + 2 {
            return Err(wrong_size());
        }
        let reader = Reader { bytes, kind };
        let actual_id = reader.u16(DATAGRAM_ID);
        if actual_id != id {
            return Err(DatagramError::WrongId {
                kind,
                expected: id,
                actual: actual_id,
            });
        }
        if bytes.len() != size {
            return Err(wrong_size());
        }
        let packet_size = reader.u16(PACKET_SIZE);
        if usize::from(packet_size) != size {
            return Err(DatagramError::WrongPacketSize {
                kind,
                expected: size as u16,
                actual: packet_size,
            });
        }
        Ok(reader)
    }
    fn u16(&self, at: usize) -> u16 {
        u16::from_le_bytes([self.bytes[at], self.bytes[at + 1]])
    }
    fn u32(&self, at: usize) -> u32 {
        u32::from_le_bytes(self.bytes[at..at + 4].try_into().expect("4 bytes"))
    }
    fn f32(&self, at: usize, field: &'static str) -> Result<f32, DatagramError> {
        let value = f32::from_le_bytes(self.bytes[at..at + 4].try_into().expect("4 bytes"));
        if value.is_finite() {
            Ok(value)
        } else {
            Err(DatagramError::NonFinite {
                kind: self.kind,
                field,
                offset: at,
                value,
            })
        }
    }
    fn f32s<const N: usize>(
        &self,
        at: usize,
        field: &'static str,
    ) -> Result<[f32; N], DatagramError> {
        let mut out = [0.0; N];
        for (i, v) in out.iter_mut().enumerate() {
            *v = self.f32(at + 4 * i, field)?;
        }
        Ok(out)
    }
    fn unknown(&self, field: &'static str, value: u32) -> DatagramError {
        DatagramError::UnknownValue {
            kind: self.kind,
            field,
            value,
        }
    }
    fn krl(&self) -> Result<KrlData, DatagramError> {
        let mut int = [0i32; USER_SIZE];
        for (i, v) in int.iter_mut().enumerate() {
            *v = self.u32(KRL_INT + 4 * i) as i32;
        }
        Ok(KrlData {
            real: self.f32s(KRL_REAL, "krl.realData")?,
            int,
            bools: self.u16(KRL_BOOL),
        })
    }
}

impl MeasurementDatagram {
    /// The 916 bytes on the wire.
    pub fn encode(&self) -> [u8; MEASUREMENT_SIZE] {
        let mut bytes = [0u8; MEASUREMENT_SIZE];
        let mut w = Writer(&mut bytes);
        w.header(
            self.send_seq_count,
            self.refl_seq_count,
            MEASUREMENT_SIZE,
            MEASUREMENT_ID,
        );
        w.krl(&self.krl);
        let i = &self.interface;
        w.f32(TIMESTAMP, i.timestamp_s);
        w.u16(STATE, i.state.raw());
        w.u16(QUALITY, i.quality.raw());
        w.f32(DESIRED_MSR_SAMPLE_TIME, i.desired_msr_sample_time_s);
        w.f32(DESIRED_CMD_SAMPLE_TIME, i.desired_cmd_sample_time_s);
        w.f32(SAFETY_LIMITS, i.safety_limits);
        w.f32(ANSWER_RATE, i.stats.answer_rate);
        w.f32(LATENCY, i.stats.latency_s);
        w.f32(JITTER, i.stats.jitter_s);
        w.f32(MISS_RATE, i.stats.miss_rate);
        w.u32(MISS_COUNTER, i.stats.miss_counter);
        let r = &self.robot;
        w.u16(POWER, r.power);
        w.u16(CONTROL, r.control.raw());
        w.u16(ERROR, r.error);
        w.u16(WARNING, r.warning);
        w.f32s(TEMPERATURE, &r.temperature);
        let d = &self.data;
        w.f32s(MSR_JNT_POS, &d.msr_jnt_pos);
        w.f32s(MSR_CART_POS, &d.msr_cart_pos);
        w.f32s(CMD_JNT_POS, &d.cmd_jnt_pos);
        w.f32s(CMD_JNT_POS_FRI_OFFSET, &d.cmd_jnt_pos_fri_offset);
        w.f32s(CMD_CART_POS, &d.cmd_cart_pos);
        w.f32s(CMD_CART_POS_FRI_OFFSET, &d.cmd_cart_pos_fri_offset);
        w.f32s(MSR_JNT_TRQ, &d.msr_jnt_trq);
        w.f32s(EST_EXT_JNT_TRQ, &d.est_ext_jnt_trq);
        w.f32s(EST_EXT_TCP_FT, &d.est_ext_tcp_ft);
        w.f32s(JACOBIAN, &d.jacobian);
        w.f32s(MASS_MATRIX, &d.mass_matrix);
        w.f32s(GRAVITY, &d.gravity);
        bytes
    }

    /// Parses and checks 916 bytes.
    pub fn decode(bytes: &[u8]) -> Result<MeasurementDatagram, DatagramError> {
        let r = Reader::new(
            bytes,
            DatagramKind::Measurement,
            MEASUREMENT_SIZE,
            MEASUREMENT_ID,
        )?;
        let state_raw = r.u16(STATE);
        let quality_raw = r.u16(QUALITY);
        let control_raw = r.u16(CONTROL);
        let interface = InterfaceState {
            timestamp_s: r.f32(TIMESTAMP, "timestamp")?,
            state: FriState::from_raw(state_raw)
                .ok_or_else(|| r.unknown("state", state_raw.into()))?,
            quality: Quality::from_raw(quality_raw)
                .ok_or_else(|| r.unknown("quality", quality_raw.into()))?,
            desired_msr_sample_time_s: r.f32(DESIRED_MSR_SAMPLE_TIME, "desiredMsrSampleTime")?,
            desired_cmd_sample_time_s: r.f32(DESIRED_CMD_SAMPLE_TIME, "desiredCmdSampleTime")?,
            safety_limits: r.f32(SAFETY_LIMITS, "safetyLimits")?,
            stats: LinkStats {
                answer_rate: r.f32(ANSWER_RATE, "answerRate")?,
                latency_s: r.f32(LATENCY, "latency")?,
                jitter_s: r.f32(JITTER, "jitter")?,
                miss_rate: r.f32(MISS_RATE, "missRate")?,
                miss_counter: r.u32(MISS_COUNTER),
            },
        };
        let robot = RobotState {
            power: r.u16(POWER),
            control: ControlMode::from_raw(control_raw)
                .ok_or_else(|| r.unknown("control", control_raw.into()))?,
            error: r.u16(ERROR),
            warning: r.u16(WARNING),
            temperature: r.f32s(TEMPERATURE, "temperature")?,
        };
        let data = RobotData {
            msr_jnt_pos: r.f32s(MSR_JNT_POS, "msrJntPos")?,
            msr_cart_pos: r.f32s(MSR_CART_POS, "msrCartPos")?,
            cmd_jnt_pos: r.f32s(CMD_JNT_POS, "cmdJntPos")?,
            cmd_jnt_pos_fri_offset: r.f32s(CMD_JNT_POS_FRI_OFFSET, "cmdJntPosFriOffset")?,
            cmd_cart_pos: r.f32s(CMD_CART_POS, "cmdCartPos")?,
            cmd_cart_pos_fri_offset: r.f32s(CMD_CART_POS_FRI_OFFSET, "cmdCartPosFriOffset")?,
            msr_jnt_trq: r.f32s(MSR_JNT_TRQ, "msrJntTrq")?,
            est_ext_jnt_trq: r.f32s(EST_EXT_JNT_TRQ, "estExtJntTrq")?,
            est_ext_tcp_ft: r.f32s(EST_EXT_TCP_FT, "estExtTcpFT")?,
            jacobian: r.f32s(JACOBIAN, "jacobian")?,
            mass_matrix: r.f32s(MASS_MATRIX, "massMatrix")?,
            gravity: r.f32s(GRAVITY, "gravity")?,
        };
        Ok(MeasurementDatagram {
            send_seq_count: r.u16(SEND_SEQ),
            refl_seq_count: r.u16(REFL_SEQ),
            krl: r.krl()?,
            interface,
            robot,
            data,
        })
    }

    /// The position the robot itself commands, `cmdJntPos + cmdJntPosFriOffset` (rad):
    /// what the PC must send back to leave the arm where the robot holds it.
    pub fn mirrored_jnt_pos(&self) -> [f32; JOINTS] {
        std::array::from_fn(|j| self.data.cmd_jnt_pos[j] + self.data.cmd_jnt_pos_fri_offset[j])
    }
}

impl CommandDatagram {
    /// The 376 bytes on the wire.
    pub fn encode(&self) -> [u8; COMMAND_SIZE] {
        let mut bytes = [0u8; COMMAND_SIZE];
        let mut w = Writer(&mut bytes);
        w.header(
            self.send_seq_count,
            self.refl_seq_count,
            COMMAND_SIZE,
            COMMAND_ID,
        );
        w.krl(&self.krl);
        w.u32(CMD_FLAGS, self.cmd_flags.raw());
        w.f32s(JNT_POS, &self.jnt_pos);
        w.f32s(CART_POS, &self.cart_pos);
        w.f32s(ADD_JNT_TRQ, &self.add_jnt_trq);
        w.f32s(ADD_TCP_FT, &self.add_tcp_ft);
        w.f32s(JNT_STIFFNESS, &self.jnt_stiffness);
        w.f32s(JNT_DAMPING, &self.jnt_damping);
        w.f32s(CART_STIFFNESS, &self.cart_stiffness);
        w.f32s(CART_DAMPING, &self.cart_damping);
        bytes
    }

    /// Parses and checks 376 bytes.
    pub fn decode(bytes: &[u8]) -> Result<CommandDatagram, DatagramError> {
        let r = Reader::new(bytes, DatagramKind::Command, COMMAND_SIZE, COMMAND_ID)?;
        let flags_raw = r.u32(CMD_FLAGS);
        Ok(CommandDatagram {
            send_seq_count: r.u16(SEND_SEQ),
            refl_seq_count: r.u16(REFL_SEQ),
            krl: r.krl()?,
            cmd_flags: CmdFlags::from_raw(flags_raw)
                .ok_or_else(|| r.unknown("cmdFlags", flags_raw))?,
            jnt_pos: r.f32s(JNT_POS, "jntPos")?,
            cart_pos: r.f32s(CART_POS, "cartPos")?,
            add_jnt_trq: r.f32s(ADD_JNT_TRQ, "addJntTrq")?,
            add_tcp_ft: r.f32s(ADD_TCP_FT, "addTcpFT")?,
            jnt_stiffness: r.f32s(JNT_STIFFNESS, "jntStiffness")?,
            jnt_damping: r.f32s(JNT_DAMPING, "jntDamping")?,
            cart_stiffness: r.f32s(CART_STIFFNESS, "cartStiffness")?,
            cart_damping: r.f32s(CART_DAMPING, "cartDamping")?,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn f(bytes: &[u8], at: usize) -> f32 {
        f32::from_le_bytes(bytes[at..at + 4].try_into().unwrap())
    }
    fn h(bytes: &[u8], at: usize) -> u16 {
        u16::from_le_bytes([bytes[at], bytes[at + 1]])
    }

    /// A measurement whose every field holds a distinct value.
    fn measurement() -> MeasurementDatagram {
        let mut m = MeasurementDatagram {
            send_seq_count: 0xfffe,
            refl_seq_count: 0x1234,
            ..Default::default()
        };
        m.krl.real = std::array::from_fn(|i| 100.0 + i as f32);
        m.krl.int = std::array::from_fn(|i| -(i as i32) - 1);
        m.krl.bools = 0b1010_0000_0000_0101;
        m.interface = InterfaceState {
            timestamp_s: 12.5,
            state: FriState::Command,
            quality: Quality::Perfect,
            desired_msr_sample_time_s: 0.001,
            desired_cmd_sample_time_s: 0.002,
            safety_limits: 0.75,
            stats: LinkStats {
                answer_rate: 0.99,
                latency_s: 0.0002,
                jitter_s: 0.00005,
                miss_rate: 0.01,
                miss_counter: 0x0102_0304,
            },
        };
        m.robot = RobotState {
            power: 0x7f,
            control: ControlMode::JointImpedance,
            error: 0x0a0b,
            warning: 0x0c0d,
            temperature: std::array::from_fn(|i| 30.0 + i as f32),
        };
        let d = &mut m.data;
        d.msr_jnt_pos = std::array::from_fn(|i| 0.1 * (i as f32 + 1.0));
        d.msr_cart_pos = std::array::from_fn(|i| 1.0 + i as f32);
        d.cmd_jnt_pos = std::array::from_fn(|i| -0.2 * (i as f32 + 1.0));
        d.cmd_jnt_pos_fri_offset = std::array::from_fn(|i| 0.01 * (i as f32 + 1.0));
        d.cmd_cart_pos = std::array::from_fn(|i| 20.0 + i as f32);
        d.cmd_cart_pos_fri_offset = std::array::from_fn(|i| 40.0 + i as f32);
        d.msr_jnt_trq = std::array::from_fn(|i| 60.0 + i as f32);
        d.est_ext_jnt_trq = std::array::from_fn(|i| 70.0 + i as f32);
        d.est_ext_tcp_ft = std::array::from_fn(|i| 80.0 + i as f32);
        d.jacobian = std::array::from_fn(|i| 1000.0 + i as f32);
        d.mass_matrix = std::array::from_fn(|i| 2000.0 + i as f32);
        d.gravity = std::array::from_fn(|i| 3000.0 + i as f32);
        m
    }

    #[test]
    fn measurement_fields_sit_at_documented_offsets() {
        let b = measurement().encode();
        assert_eq!(b.len(), 916);
        assert_eq!(h(&b, 0), 0xfffe);
        assert_eq!(h(&b, 2), 0x1234);
        assert_eq!(h(&b, 4), 916);
        assert_eq!(h(&b, 6), 0x2006);
        assert_eq!(f(&b, 8), 100.0);
        assert_eq!(f(&b, 8 + 4 * 15), 115.0);
        assert_eq!(i32::from_le_bytes(b[72..76].try_into().unwrap()), -1);
        assert_eq!(i32::from_le_bytes(b[132..136].try_into().unwrap()), -16);
        assert_eq!(h(&b, 136), 0b1010_0000_0000_0101);
        assert_eq!(h(&b, 138), 0);
        assert_eq!(f(&b, 140), 12.5);
        assert_eq!(h(&b, 144), 2);
        assert_eq!(h(&b, 146), 3);
        assert_eq!(f(&b, 148), 0.001);
        assert_eq!(f(&b, 152), 0.002);
        assert_eq!(f(&b, 156), 0.75);
        assert_eq!(f(&b, 160), 0.99);
        assert_eq!(f(&b, 164), 0.0002);
        assert_eq!(f(&b, 168), 0.00005);
        assert_eq!(f(&b, 172), 0.01);
        assert_eq!(&b[176..180], &[0x04, 0x03, 0x02, 0x01]);
        assert_eq!(h(&b, 180), 0x7f);
        assert_eq!(h(&b, 182), 3);
        assert_eq!(h(&b, 184), 0x0a0b);
        assert_eq!(h(&b, 186), 0x0c0d);
        assert_eq!(f(&b, 188), 30.0);
        assert_eq!(f(&b, 212), 36.0);
        // Robot data: first and last element of each array.
        let arrays: [(usize, usize, f32, f32); 12] = [
            (216, 7, 0.1, 0.7),
            (244, 12, 1.0, 12.0),
            (292, 7, -0.2, -1.4),
            (320, 7, 0.01, 0.07),
            (348, 12, 20.0, 31.0),
            (396, 12, 40.0, 51.0),
            (444, 7, 60.0, 66.0),
            (472, 7, 70.0, 76.0),
            (500, 6, 80.0, 85.0),
            (524, 42, 1000.0, 1041.0),
            (692, 49, 2000.0, 2048.0),
            (888, 7, 3000.0, 3006.0),
        ];
        for (at, n, first, last) in arrays {
            assert!((f(&b, at) - first).abs() < 1e-6, "first at {at}");
            assert!(
                (f(&b, at + 4 * (n - 1)) - last).abs() < 1e-4,
                "last at {at}"
            );
        }
        assert_eq!(888 + 4 * 7, 916);
    }

    #[test]
    fn measurement_round_trips() {
        let m = measurement();
        assert_eq!(MeasurementDatagram::decode(&m.encode()).unwrap(), m);
    }

    #[test]
    fn command_fields_sit_at_documented_offsets() {
        let c = CommandDatagram {
            send_seq_count: 65535,
            refl_seq_count: 7,
            cmd_flags: CmdFlags::JNT_POS | CmdFlags::JNT_STIFF,
            jnt_pos: std::array::from_fn(|i| 0.5 + i as f32),
            cart_pos: std::array::from_fn(|i| 10.0 + i as f32),
            add_jnt_trq: std::array::from_fn(|i| 30.0 + i as f32),
            add_tcp_ft: std::array::from_fn(|i| 40.0 + i as f32),
            jnt_stiffness: std::array::from_fn(|i| 50.0 + i as f32),
            jnt_damping: std::array::from_fn(|i| 60.0 + i as f32),
            cart_stiffness: std::array::from_fn(|i| 70.0 + i as f32),
            cart_damping: std::array::from_fn(|i| 80.0 + i as f32),
            ..Default::default()
        };
        let b = c.encode();
        assert_eq!(b.len(), 376);
        assert_eq!(&b[0..8], &[0xff, 0xff, 7, 0, 0x78, 0x01, 0x05, 0x10]);
        assert_eq!(&b[140..144], &[0x11, 0, 0, 0]);
        let arrays: [(usize, usize, f32); 8] = [
            (144, 7, 0.5),
            (172, 12, 10.0),
            (220, 7, 30.0),
            (248, 6, 40.0),
            (272, 7, 50.0),
            (300, 7, 60.0),
            (328, 6, 70.0),
            (352, 6, 80.0),
        ];
        for (at, n, first) in arrays {
            assert_eq!(f(&b, at), first, "first at {at}");
            assert_eq!(
                f(&b, at + 4 * (n - 1)),
                first + (n - 1) as f32,
                "last at {at}"
            );
        }
        assert_eq!(CommandDatagram::decode(&b).unwrap(), c);
    }

    #[test]
    fn wrong_size_id_and_packet_size_are_reported_with_numbers() {
        let b = measurement().encode();
        assert_eq!(
            MeasurementDatagram::decode(&b[..915]),
            Err(DatagramError::WrongSize {
                kind: DatagramKind::Measurement,
                expected: 916,
                actual: 915
            })
        );
        assert!(matches!(
            MeasurementDatagram::decode(&b[..3]),
            Err(DatagramError::WrongSize { actual: 3, .. })
        ));
        let c = CommandDatagram::default().encode();
        assert_eq!(
            MeasurementDatagram::decode(&c),
            Err(DatagramError::WrongId {
                kind: DatagramKind::Measurement,
                expected: 0x2006,
                actual: 0x1005
            })
        );
        let mut bad = b;
        bad[4..6].copy_from_slice(&900u16.to_le_bytes());
        let err = MeasurementDatagram::decode(&bad).unwrap_err();
        assert_eq!(
            err,
            DatagramError::WrongPacketSize {
                kind: DatagramKind::Measurement,
                expected: 916,
                actual: 900
            }
        );
        assert!(err.to_string().contains("900"), "{err}");
        let mut long = c.to_vec();
        long.push(0);
        assert!(matches!(
            CommandDatagram::decode(&long),
            Err(DatagramError::WrongSize {
                expected: 376,
                actual: 377,
                ..
            })
        ));
    }

    #[test]
    fn unknown_enumerations_and_non_finite_floats_are_rejected() {
        let b = measurement().encode();
        for (at, field, value) in [
            (144, "state", 3u16),
            (146, "quality", 4),
            (182, "control", 4),
        ] {
            let mut bad = b;
            bad[at..at + 2].copy_from_slice(&value.to_le_bytes());
            assert_eq!(
                MeasurementDatagram::decode(&bad),
                Err(DatagramError::UnknownValue {
                    kind: DatagramKind::Measurement,
                    field,
                    value: value.into()
                })
            );
        }
        // -1 (INVALID) is a defined value.
        let mut invalid = b;
        invalid[144..146].copy_from_slice(&0xffffu16.to_le_bytes());
        invalid[146..148].copy_from_slice(&0xffffu16.to_le_bytes());
        let m = MeasurementDatagram::decode(&invalid).unwrap();
        assert_eq!(m.interface.state, FriState::Invalid);
        assert_eq!(m.interface.quality, Quality::Invalid);
        let mut nan = b;
        nan[220..224].copy_from_slice(&f32::NAN.to_le_bytes());
        assert!(matches!(
            MeasurementDatagram::decode(&nan),
            Err(DatagramError::NonFinite {
                field: "msrJntPos",
                offset: 220,
                ..
            })
        ));
        let mut flags = CommandDatagram::default().encode();
        flags[140..144].copy_from_slice(&0x0002u32.to_le_bytes()); // a velocity flag
        assert!(matches!(
            CommandDatagram::decode(&flags),
            Err(DatagramError::UnknownValue {
                field: "cmdFlags",
                value: 2,
                ..
            })
        ));
    }

    #[test]
    fn quality_orders_worst_to_best() {
        assert!(Quality::Invalid < Quality::Unacceptable);
        assert!(Quality::Unacceptable < Quality::Bad);
        assert!(Quality::Bad < Quality::Ok);
        assert!(Quality::Ok < Quality::Perfect);
    }

    #[test]
    fn sequence_distance_wraps() {
        assert_eq!(seq_ahead(0, 65535), 1);
        assert_eq!(seq_ahead(3, 65534), 5);
        assert_eq!(seq_ahead(10, 10), 0);
        assert_eq!(65535u16.wrapping_add(1), 0);
    }

    #[test]
    fn mirror_adds_the_fri_offset() {
        let m = measurement();
        let q = m.mirrored_jnt_pos();
        assert!((q[0] - (-0.2 + 0.01)).abs() < 1e-6);
        assert!((q[6] - (-1.4 + 0.07)).abs() < 1e-6);
    }
}
