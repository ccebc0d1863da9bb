//! The Barrett "puck" CAN protocol: identifiers, property numbers, and the get, set,
//! property-reply and position-reply frame formats (motor-puck firmware >= 132).
//!
//! Identifier = `[group flag: bit 10][source node: bits 9..5][destination: bits
//! 4..0]`; the host is node 0. A get is `[p]`; a set is `[0x80|p, 0, v0..v3]`
//! (little-endian); a property reply is `[0x80|p, 0, v0, v1]` or six bytes with
//! `v0..v3`, sign-extended from its top byte; a position reply carries 22-bit
//! two's-complement counts, most significant 6 bits in byte 0 under a set bit 7.

use crate::hw::can::CanFrame;
use std::fmt;

/// The host's node number.
pub const HOST_NODE: u8 = 0;

/// Feedback and command groups.
pub mod group {
    /// Every puck except the safety puck.
    pub const ALL: u8 = 0;
    /// Replies to position requests (22-bit packed format).
    pub const POSITION_REPLY: u8 = 3;
    /// The four hand pucks (identifier 0x405).
    pub const HAND: u8 = 5;
    /// Replies to property gets.
    pub const PROPERTY_REPLY: u8 = 6;
    /// The hand pucks' GRPB.
    pub const HAND_SECONDARY: u8 = 7;
}

/// MODE values.
pub mod mode {
    /// Motor off.
    pub const IDLE: i32 = 0;
    /// Duty-cycle control.
    pub const DUTY: i32 = 1;
    /// Torque control (stream T).
    pub const TORQUE: i32 = 2;
    /// PID position hold (stream P).
    pub const PID: i32 = 3;
    /// Velocity control (stream V).
    pub const VELOCITY: i32 = 4;
    /// Trapezoidal move to E (also what CMD motions run in).
    pub const TRAPEZOIDAL: i32 = 5;
}

/// CMD values.
pub mod command {
    /// Reset the puck.
    pub const RESET: i32 = 2;
    /// Home.
    pub const HOME: i32 = 7;
    /// Hand initialise: find the encoder zero.
    pub const HI: i32 = 13;
    /// Incremental close by DS.
    pub const IC: i32 = 14;
    /// Incremental open by DS.
    pub const IO: i32 = 15;
    /// Torque close.
    pub const TC: i32 = 16;
    /// Torque open.
    pub const TO: i32 = 17;
    /// Close to CT.
    pub const C: i32 = 18;
    /// Move to DP.
    pub const M: i32 = 19;
    /// Open to OT.
    pub const O: i32 = 20;

    /// The command's name, for messages.
    pub fn name(value: i32) -> &'static str {
        match value {
            RESET => "RESET",
            HOME => "HOME",
            HI => "HI",
            IC => "IC",
            IO => "IO",
            TC => "TC",
            TO => "TO",
            C => "C",
            M => "M",
            O => "O",
            _ => "?",
        }
    }
}

/// STAT values.
pub mod status {
    /// Reset: the puck runs its monitor firmware.
    pub const RESET: i32 = 0;
    /// Ready: the motor firmware runs.
    pub const READY: i32 = 2;
}

/// ROLE bits.
pub mod role {
    /// Mask of the role number.
    pub const MASK: i32 = 0x1F;
    /// Role number of a hand puck.
    pub const HAND: i32 = 5;
    /// Option bit: strain gauge fitted.
    pub const STRAIN_GAUGE: i32 = 0x0800;
    /// Option bit: tactile sensors fitted.
    pub const TACTILE: i32 = 0x1000;
}

/// The four pucks of the BH8-282.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord, serde::Serialize)]
pub enum Puck {
    /// Finger 1 (node 11).
    F1,
    /// Finger 2 (node 12).
    F2,
    /// Finger 3, the fixed one (node 13).
    F3,
    /// The spread motor (node 14).
    Spread,
}

impl Puck {
    /// All four, in node order.
    pub const ALL: [Puck; 4] = [Puck::F1, Puck::F2, Puck::F3, Puck::Spread];
    /// The three fingers.
    pub const FINGERS: [Puck; 3] = [Puck::F1, Puck::F2, Puck::F3];

    /// CAN node number (11-14).
    pub fn node(self) -> u8 {
        11 + self.index() as u8
    }

    /// The puck with node number `node`, if it is a hand puck.
    pub fn from_node(node: u8) -> Option<Puck> {
        Puck::ALL.get(usize::from(node.checked_sub(11)?)).copied()
    }

    /// Index 0-3 (F1, F2, F3, spread).
    pub fn index(self) -> usize {
        self as usize
    }

    /// Short name: `F1`, `F2`, `F3`, `spread`.
    pub fn name(self) -> &'static str {
        match self {
            Puck::F1 => "F1",
            Puck::F2 => "F2",
            Puck::F3 => "F3",
            Puck::Spread => "spread",
        }
    }

    /// The puck named `name` (`F1`, `F2`, `F3`, `spread`; any case).
    pub fn from_name(name: &str) -> Option<Puck> {
        Puck::ALL
            .into_iter()
            .find(|p| p.name().eq_ignore_ascii_case(name.trim()))
    }

    /// True for F1-F3.
    pub fn is_finger(self) -> bool {
        self != Puck::Spread
    }

    /// Motor turns per joint turn: 125 for a finger's proximal joint, 17.5 for the
    /// spread.
    pub fn gear_ratio(self) -> f64 {
        if self.is_finger() {
            125.0
        } else {
            17.5
        }
    }

    /// Encoder counts per joint radian given the puck's CTS (counts per motor
    /// revolution): `CTS / 2 pi * gear ratio`.
    pub fn counts_per_rad(self, counts_per_rev: i32) -> f64 {
        f64::from(counts_per_rev) / std::f64::consts::TAU * self.gear_ratio()
    }

    /// Joint range (rad): 0..=2.44 for a finger's proximal joint, 0..=pi spread.
    pub fn range_rad(self) -> (f64, f64) {
        if self.is_finger() {
            (0.0, 2.44)
        } else {
            (0.0, std::f64::consts::PI)
        }
    }
}

impl fmt::Display for Puck {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{} (node {})", self.name(), self.node())
    }
}

macro_rules! properties {
    ($($variant:ident = $id:literal, $name:literal, $doc:literal;)*) => {
        /// Puck properties (numbers of motor-puck firmware >= 132).
        #[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
        pub enum Property {
            $(#[doc = $doc] $variant,)*
        }

        impl Property {
            /// Every property in the table.
            pub const ALL: &'static [Property] = &[$(Property::$variant,)*];

            /// The property number.
            pub fn id(self) -> u8 {
                match self {
                    $(Property::$variant => $id,)*
                }
            }

            /// The property's name as Barrett writes it.
            pub fn name(self) -> &'static str {
                match self {
                    $(Property::$variant => $name,)*
                }
            }

            /// The property with number `id`.
            pub fn from_id(id: u8) -> Option<Property> {
                match id {
                    $($id => Some(Property::$variant),)*
                    _ => None,
                }
            }
        }
    };
}

properties! {
    Vers = 0, "VERS", "Firmware version.";
    Role = 1, "ROLE", "Role (low 5 bits) and option bits.";
    Stat = 5, "STAT", "Status: 0 reset, 2 ready.";
    Mode = 8, "MODE", "Control mode.";
    Temp = 9, "TEMP", "Temperature.";
    Sg = 25, "SG", "Strain gauge, 0-4095, about 2000 unloaded.";
    Grpa = 26, "GRPA", "First group listened to.";
    Grpb = 27, "GRPB", "Second group listened to.";
    Grpc = 28, "GRPC", "Third group listened to.";
    Cmd = 29, "CMD", "Command.";
    Save = 30, "SAVE", "Save properties to EEPROM.";
    Load = 31, "LOAD", "Load properties from EEPROM.";
    T = 42, "T", "Torque command.";
    Mt = 43, "MT", "Maximum torque.";
    V = 44, "V", "Velocity command (counts/ms).";
    Mv = 45, "MV", "Maximum velocity (counts/ms).";
    Mcv = 46, "MCV", "Maximum close velocity (counts/ms).";
    Mov = 47, "MOV", "Maximum open velocity (counts/ms).";
    P = 48, "P", "Position (counts).";
    Dp = 50, "DP", "Default position, target of CMD M (counts).";
    E = 52, "E", "Endpoint of a trapezoidal move (counts).";
    Ot = 54, "OT", "Open target (counts).";
    Ct = 56, "CT", "Close target (counts).";
    M = 58, "M", "Move to position (counts).";
    Ds = 60, "DS", "Step of incremental open/close (counts).";
    Cts = 68, "CTS", "Encoder counts per motor revolution.";
    Hsg = 71, "HSG", "High strain stop threshold.";
    Lsg = 72, "LSG", "Low strain stop threshold.";
    Hold = 77, "HOLD", "Hold position (MODE 3) after a move when non-zero.";
    Tstop = 78, "TSTOP", "Stall time (ms) after which a move stops; 0 never.";
    Kp = 79, "KP", "Proportional gain.";
    Kd = 80, "KD", "Derivative gain.";
    Ki = 81, "KI", "Integral gain.";
    Accel = 82, "ACCEL", "Acceleration of trapezoidal moves.";
    Ipnm = 86, "IPNM", "Current per newton-metre.";
    Jp = 96, "JP", "Joint position.";
    Tact = 106, "TACT", "Tactile sensor mode.";
}

/// Numbers of the 32-bit properties (their replies have 6 bytes).
const WIDE_PROPERTIES: [u8; 12] = [48, 50, 52, 54, 56, 58, 66, 68, 74, 88, 96, 98];

/// True when property number `id` is 32 bits wide.
pub fn is_wide(id: u8) -> bool {
    WIDE_PROPERTIES.contains(&id)
}

impl fmt::Display for Property {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

/// Smallest and largest count a 22-bit position reply carries.
pub const POSITION_RANGE: (i32, i32) = (-(1 << 21), (1 << 21) - 1);

/// A frame that does not follow the puck protocol.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum PuckFrameError {
    /// Wrong number of data bytes.
    #[error("{len} data bytes where {expected} are expected")]
    Length {
        /// Bytes present.
        len: usize,
        /// Lengths allowed.
        expected: &'static str,
    },
    /// A reply or set whose first byte lacks the 0x80 flag.
    #[error("byte 0 = {byte:#04x} lacks the 0x80 set/reply flag")]
    NoSetFlag {
        /// The byte.
        byte: u8,
    },
    /// A get whose byte carries the 0x80 flag.
    #[error("a 1-byte get with byte 0 = {byte:#04x} carries the 0x80 flag")]
    GetWithFlag {
        /// The byte.
        byte: u8,
    },
    /// The second byte of a set or reply is not zero.
    #[error("byte 1 = {byte:#04x} where 0x00 is expected")]
    Padding {
        /// The byte.
        byte: u8,
    },
    /// A position reply's marker bit (bit 7 of byte 0 or 3) is clear.
    #[error("position byte {index} = {byte:#04x} lacks the 0x80 marker")]
    PositionMarker {
        /// Which byte.
        index: usize,
        /// The byte.
        byte: u8,
    },
    /// A count outside the 22-bit range.
    #[error("position {counts} outside the 22-bit range -2097152..=2097151")]
    PositionRange {
        /// The count.
        counts: i32,
    },
}

/// A request a puck receives.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Request {
    /// Get property number `.0`.
    Get(u8),
    /// Set property number `.0` to `.1`.
    Set(u8, i32),
}

/// Who sent a frame to whom.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Address {
    /// True when `destination` is a group.
    pub to_group: bool,
    /// Source node.
    pub source: u8,
    /// Destination node or group.
    pub destination: u8,
}

/// Identifier of a frame from the host to node `node`.
pub fn node_id(node: u8) -> u16 {
    u16::from(node & 0x1F)
}

/// Identifier of a frame from the host to group `group` (`0x400 | group`).
pub fn group_id(group: u8) -> u16 {
    0x400 | u16::from(group & 0x1F)
}

/// Identifier of a reply from node `source` to feedback group `group`.
pub fn reply_id(source: u8, group: u8) -> u16 {
    0x400 | (u16::from(source & 0x1F) << 5) | u16::from(group & 0x1F)
}

/// Splits an identifier into group flag, source and destination.
pub fn split_id(id: u16) -> Address {
    Address {
        to_group: id & 0x400 != 0,
        source: ((id >> 5) & 0x1F) as u8,
        destination: (id & 0x1F) as u8,
    }
}

fn frame(id: u16, data: &[u8]) -> CanFrame {
    // Identifiers built here are 11-bit and payloads at most 6 bytes.
    CanFrame::new(id & 0x7FF, &data[..data.len().min(8)]).unwrap_or_else(|_| unreachable!())
}

/// Get property `property` from identifier `to` (a node or group identifier).
pub fn get_frame(to: u16, property: Property) -> CanFrame {
    frame(to, &[property.id() & 0x7F])
}

/// Set property `property` to `value` at identifier `to`: 6 bytes.
pub fn set_frame(to: u16, property: Property, value: i32) -> CanFrame {
    let v = value.to_le_bytes();
    frame(to, &[0x80 | property.id(), 0x00, v[0], v[1], v[2], v[3]])
}

/// A puck's reply to a get: to group 6, 6 bytes for 32-bit properties, else 4.
pub fn property_reply_frame(source: u8, property: u8, value: i32) -> CanFrame {
    let v = value.to_le_bytes();
    let id = reply_id(source, group::PROPERTY_REPLY);
    if is_wide(property) {
        frame(id, &[0x80 | property, 0x00, v[0], v[1], v[2], v[3]])
    } else {
        frame(id, &[0x80 | property, 0x00, v[0], v[1]])
    }
}

/// A puck's position reply to group 3 (3 bytes).
pub fn position_reply_frame(source: u8, counts: i32) -> Result<CanFrame, PuckFrameError> {
    Ok(frame(
        reply_id(source, group::POSITION_REPLY),
        &encode_position(counts)?,
    ))
}

/// Decodes what a puck receives: a get (1 byte) or a set (4 or 6 bytes).
pub fn decode_request(data: &[u8]) -> Result<Request, PuckFrameError> {
    match data.len() {
        1 if data[0] & 0x80 == 0 => Ok(Request::Get(data[0])),
        1 => Err(PuckFrameError::GetWithFlag { byte: data[0] }),
        4 | 6 => {
            let (property, value) = decode_flagged_value(data)?;
            Ok(Request::Set(property, value))
        }
        len => Err(PuckFrameError::Length {
            len,
            expected: "1 (get), 4 or 6 (set)",
        }),
    }
}

/// Decodes a property reply: `(property number, value)`.
pub fn decode_property_reply(data: &[u8]) -> Result<(u8, i32), PuckFrameError> {
    match data.len() {
        4 | 6 => decode_flagged_value(data),
        len => Err(PuckFrameError::Length {
            len,
            expected: "4 or 6",
        }),
    }
}

/// `[0x80|p, 0, v0, v1(, v2, v3)]`, little-endian, sign-extended from the top byte.
fn decode_flagged_value(data: &[u8]) -> Result<(u8, i32), PuckFrameError> {
    if data[0] & 0x80 == 0 {
        return Err(PuckFrameError::NoSetFlag { byte: data[0] });
    }
    if data[1] != 0 {
        return Err(PuckFrameError::Padding { byte: data[1] });
    }
    let value = if data.len() == 6 {
        i32::from_le_bytes([data[2], data[3], data[4], data[5]])
    } else {
        i32::from(i16::from_le_bytes([data[2], data[3]]))
    };
    Ok((data[0] & 0x7F, value))
}

/// Encodes counts as a 22-bit position: `[0x80 | bits 21..16, bits 15..8, bits 7..0]`.
pub fn encode_position(counts: i32) -> Result<[u8; 3], PuckFrameError> {
    if !(POSITION_RANGE.0..=POSITION_RANGE.1).contains(&counts) {
        return Err(PuckFrameError::PositionRange { counts });
    }
    let bits = (counts as u32) & 0x3F_FFFF;
    Ok([0x80 | (bits >> 16) as u8, (bits >> 8) as u8, bits as u8])
}

/// Decodes a position reply: motor counts, and the secondary (breakaway) encoder
/// when the reply has 6 bytes.
pub fn decode_position(data: &[u8]) -> Result<(i32, Option<i32>), PuckFrameError> {
    let one = |bytes: &[u8], index: usize| -> Result<i32, PuckFrameError> {
        if bytes[0] & 0x80 == 0 {
            return Err(PuckFrameError::PositionMarker {
                index,
                byte: bytes[0],
            });
        }
        let raw =
            (i32::from(bytes[0] & 0x3F) << 16) | (i32::from(bytes[1]) << 8) | i32::from(bytes[2]);
        // Sign-extend from bit 21.
        Ok((raw << 10) >> 10)
    };
    match data.len() {
        3 => Ok((one(data, 0)?, None)),
        6 => Ok((one(&data[..3], 0)?, Some(one(&data[3..], 3)?))),
        len => Err(PuckFrameError::Length {
            len,
            expected: "3 or 6",
        }),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn identifiers_compose_as_specified() {
        assert_eq!(node_id(Puck::F1.node()), 11);
        assert_eq!(group_id(group::HAND), 0x405);
        // F1 replying to the property group: 0x400 | 11 << 5 | 6.
        assert_eq!(reply_id(11, group::PROPERTY_REPLY), 0x566);
        let position_ids: Vec<u16> = Puck::ALL
            .iter()
            .map(|p| reply_id(p.node(), group::POSITION_REPLY))
            .collect();
        assert_eq!(position_ids, [0x563, 0x583, 0x5A3, 0x5C3]);
        assert_eq!(
            split_id(0x5A6),
            Address {
                to_group: true,
                source: 13,
                destination: 6
            }
        );
        assert_eq!(Puck::from_node(14), Some(Puck::Spread));
        assert_eq!(Puck::from_node(10), None);
        assert_eq!(Puck::from_node(15), None);
    }

    #[test]
    fn get_and_set_frames_are_byte_exact() {
        let get = get_frame(node_id(11), Property::P);
        assert_eq!((get.id(), get.data()), (11, &[48u8][..]));
        let close = set_frame(group_id(group::HAND), Property::Cmd, command::C);
        assert_eq!(close.id(), 0x405);
        assert_eq!(close.data(), &[0x80 | 29, 0x00, 18, 0, 0, 0]);
        let negative = set_frame(12, Property::E, -2);
        assert_eq!(negative.data(), &[0x80 | 52, 0, 0xFE, 0xFF, 0xFF, 0xFF]);
        assert_eq!(decode_request(close.data()), Ok(Request::Set(29, 18)));
        assert_eq!(decode_request(negative.data()), Ok(Request::Set(52, -2)));
        assert_eq!(decode_request(&[48]), Ok(Request::Get(48)));
        assert!(decode_request(&[0xB0]).is_err());
        assert!(decode_request(&[0x9D, 0, 18]).is_err());
    }

    #[test]
    fn property_replies_decode_hand_computed_examples() {
        // ROLE = 0x0805 from F1, 4 bytes.
        let role = property_reply_frame(11, 1, 0x0805);
        assert_eq!(
            (role.id(), role.data()),
            (0x566, &[0x81, 0x00, 0x05, 0x08][..])
        );
        assert_eq!(decode_property_reply(role.data()), Ok((1, 0x0805)));
        // A 16-bit value sign-extends from its top byte: 0xFFFE = -2.
        assert_eq!(decode_property_reply(&[0x89, 0, 0xFE, 0xFF]), Ok((9, -2)));
        // P = -5000 = 0xFFFFEC78, 6 bytes little-endian.
        let p = property_reply_frame(11, 48, -5000);
        assert_eq!(p.data(), &[0xB0, 0x00, 0x78, 0xEC, 0xFF, 0xFF]);
        assert_eq!(decode_property_reply(p.data()), Ok((48, -5000)));
        assert_eq!(
            decode_property_reply(&[0x81, 0x00, 0x05]),
            Err(PuckFrameError::Length {
                len: 3,
                expected: "4 or 6"
            })
        );
        assert_eq!(
            decode_property_reply(&[0x01, 0, 5, 8]),
            Err(PuckFrameError::NoSetFlag { byte: 1 })
        );
        assert_eq!(
            decode_property_reply(&[0x81, 7, 5, 8]),
            Err(PuckFrameError::Padding { byte: 7 })
        );
    }

    #[test]
    fn position_codec_matches_hand_computed_22_bit_examples() {
        // (counts, bytes) worked out by hand: 22-bit two's complement, top 6 bits
        // in byte 0 under the 0x80 marker.
        let examples: [(i32, [u8; 3]); 7] = [
            (0, [0x80, 0x00, 0x00]),
            (1000, [0x80, 0x03, 0xE8]),       // 0x0003E8
            (195_000, [0x82, 0xF9, 0xB8]),    // 0x02F9B8
            (-1, [0xBF, 0xFF, 0xFF]),         // 0x3FFFFF
            (-1000, [0xBF, 0xFC, 0x18]),      // 0x400000 - 1000 = 0x3FFC18
            (-2_097_152, [0xA0, 0x00, 0x00]), // 0x200000
            (2_097_151, [0x9F, 0xFF, 0xFF]),  // 0x1FFFFF
        ];
        for (counts, bytes) in examples {
            assert_eq!(encode_position(counts), Ok(bytes), "{counts}");
            assert_eq!(decode_position(&bytes), Ok((counts, None)), "{bytes:02x?}");
        }
        // Bit 6 of byte 0 is ignored by the mask.
        assert_eq!(decode_position(&[0xC0, 0x03, 0xE8]), Ok((1000, None)));
        // Six bytes: motor then secondary encoder.
        assert_eq!(
            decode_position(&[0x80, 0x03, 0xE8, 0xBF, 0xFC, 0x18]),
            Ok((1000, Some(-1000)))
        );
        assert_eq!(
            decode_position(&[0x00, 0x03, 0xE8]),
            Err(PuckFrameError::PositionMarker { index: 0, byte: 0 })
        );
        assert_eq!(
            decode_position(&[0x80, 0x03]),
            Err(PuckFrameError::Length {
                len: 2,
                expected: "3 or 6"
            })
        );
        assert_eq!(
            encode_position(2_097_152),
            Err(PuckFrameError::PositionRange { counts: 2_097_152 })
        );
        let f3 = position_reply_frame(13, -1000).unwrap();
        assert_eq!(f3.to_string(), "5A3#BFFC18");
    }

    #[test]
    fn frames_of_every_length_are_decoded_or_refused_by_length() {
        // A frame's length comes from the bus (0 to 8 bytes): each decoder accepts
        // its lengths and names the others, never indexing past the data.
        for len in 0..=8 {
            let data = vec![0x80; len];
            let request = decode_request(&data);
            assert_eq!(
                matches!(request, Err(PuckFrameError::Length { .. })),
                !matches!(len, 1 | 4 | 6),
                "{len}"
            );
            let reply = decode_property_reply(&data);
            assert_eq!(
                matches!(reply, Err(PuckFrameError::Length { .. })),
                !matches!(len, 4 | 6),
                "{len}"
            );
            let position = decode_position(&data);
            assert_eq!(
                matches!(position, Err(PuckFrameError::Length { .. })),
                !matches!(len, 3 | 6),
                "{len}"
            );
        }
    }

    #[test]
    fn property_table_is_consistent() {
        for &p in Property::ALL {
            assert_eq!(Property::from_id(p.id()), Some(p));
        }
        assert_eq!(Property::Tstop.id(), 78);
        assert!(is_wide(Property::P.id()) && is_wide(Property::Cts.id()));
        assert!(!is_wide(Property::Cmd.id()));
        // Spec: about 195,000 counts over 140 degrees of the proximal joint.
        let finger = Puck::F1.counts_per_rad(4096) * 140f64.to_radians();
        assert!((finger - 195_000.0).abs() < 5_000.0, "{finger}");
        let spread = Puck::Spread.counts_per_rad(4096) * std::f64::consts::PI;
        assert!((spread - 36_000.0).abs() < 500.0, "{spread}");
    }
}
