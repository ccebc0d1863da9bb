//! The classic CAN data frame: an 11-bit standard identifier and 0-8 data bytes.

use super::CanError;
use std::fmt;

/// Largest standard (11-bit) identifier.
pub const MAX_STANDARD_ID: u16 = 0x7FF;

/// Most data bytes in a classic CAN frame.
pub const MAX_DATA_LEN: usize = 8;

/// A classic CAN data frame with a standard identifier; valid by construction.
#[derive(Clone, Copy, PartialEq, Eq, Hash)]
pub struct CanFrame {
    id: u16,
    len: u8,
    data: [u8; MAX_DATA_LEN],
}

impl CanFrame {
    /// A frame with identifier `id` (at most 0x7FF) and `data` (at most 8 bytes).
    pub fn new(id: u16, data: &[u8]) -> Result<CanFrame, CanError> {
        if id > MAX_STANDARD_ID {
            return Err(CanError::InvalidId { id: u32::from(id) });
        }
        if data.len() > MAX_DATA_LEN {
            return Err(CanError::TooLong { len: data.len() });
        }
        let mut bytes = [0; MAX_DATA_LEN];
        bytes[..data.len()].copy_from_slice(data);
        Ok(CanFrame {
            id,
            len: data.len() as u8,
            data: bytes,
        })
    }

    /// The 11-bit identifier.
    pub fn id(&self) -> u16 {
        self.id
    }

    /// The data bytes (0 to 8).
    pub fn data(&self) -> &[u8] {
        &self.data[..usize::from(self.len)]
    }

    /// The data length code (number of data bytes).
    pub fn len(&self) -> usize {
        usize::from(self.len)
    }

    /// True when the frame carries no data.
    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// The same frame with `len` data bytes (a shorter DLC keeps the first bytes).
    pub fn truncated(&self, len: usize) -> CanFrame {
        let mut frame = *self;
        let len = len.min(self.len());
        frame.len = len as u8;
        frame.data[len..].fill(0);
        frame
    }

    /// The same frame with bit `bit` (0 = least significant bit of byte 0) of the data
    /// inverted; a bit beyond the data is ignored.
    pub fn with_bit_flipped(&self, bit: usize) -> CanFrame {
        let mut frame = *self;
        if bit / 8 < frame.len() {
            frame.data[bit / 8] ^= 1 << (bit % 8);
        }
        frame
    }
}

/// candump's compact form: `405#9D00120000` (identifier in 3 hex digits, data in hex).
impl fmt::Display for CanFrame {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{:03X}#", self.id)?;
        for byte in self.data() {
            write!(f, "{byte:02X}")?;
        }
        Ok(())
    }
}

impl fmt::Debug for CanFrame {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "CanFrame({self})")
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn new_validates_id_and_length() {
        assert!(CanFrame::new(0x7FF, &[0; 8]).is_ok());
        assert!(CanFrame::new(0, &[]).unwrap().is_empty());
        let err = CanFrame::new(0x800, &[]).unwrap_err().to_string();
        assert!(err.contains("0x800"), "{err}");
        let err = CanFrame::new(1, &[0; 9]).unwrap_err().to_string();
        assert!(err.contains('9'), "{err}");
    }

    #[test]
    fn display_is_candump_compact_form() {
        let frame = CanFrame::new(0x405, &[0x9D, 0x00, 0x12, 0x00, 0x00]).unwrap();
        assert_eq!(frame.to_string(), "405#9D00120000");
        assert_eq!(CanFrame::new(0xB, &[]).unwrap().to_string(), "00B#");
    }

    #[test]
    fn corruption_helpers_change_only_what_they_say() {
        let frame = CanFrame::new(0x566, &[0x81, 0x00, 0x05, 0x08]).unwrap();
        assert_eq!(frame.truncated(2).data(), &[0x81, 0x00]);
        assert_eq!(frame.truncated(9).data(), frame.data());
        assert_eq!(frame.with_bit_flipped(17).data(), &[0x81, 0x00, 0x07, 0x08]);
        assert_eq!(frame.with_bit_flipped(40), frame);
        // Equality sees only the visible bytes.
        assert_eq!(
            frame.truncated(2),
            CanFrame::new(0x566, &[0x81, 0x00]).unwrap()
        );
    }
}
