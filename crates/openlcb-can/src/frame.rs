//! [`CanFrame`]: an identifier and up to 8 data bytes, inline, `Copy`, no heap.

use embedded_can::{ExtendedId, Id, StandardId};

use crate::header::{CanHeader, HeaderError};

/// One CAN frame. OpenLCB sends only extended data frames; standard and remote frames can be
/// represented because a bus carries them and a driver hands them over (they are ignored).
#[derive(Clone, Copy, PartialEq, Eq, Hash)]
pub struct CanFrame {
    /// The raw identifier (29 or 11 bits) with the [`EXTENDED`] and [`REMOTE`] flags above
    /// it: one word, cheaper to build, test and copy than an [`Id`] and a flag.
    id: u32,
    len: u8,
    data: [u8; 8],
}

/// The flag bit of [`CanFrame::id`] for an extended (29-bit) identifier.
const EXTENDED: u32 = 1 << 31;
/// The flag bit of [`CanFrame::id`] for a remote frame.
const REMOTE: u32 = 1 << 30;
/// The identifier bits of [`CanFrame::id`].
const ID_BITS: u32 = 0x1FFF_FFFF;

impl CanFrame {
    /// The most data bytes a classic CAN frame carries.
    pub const MAX_DATA: usize = 8;

    /// An extended data frame with the 29-bit `id` (bits above 28 are dropped) and `data`,
    /// or `None` if `data` is longer than 8 bytes.
    pub fn extended(id: u32, data: &[u8]) -> Option<Self> {
        Self::with_raw(id & ID_BITS | EXTENDED, data)
    }

    /// A standard (11-bit) data frame, or `None` if `id` exceeds 11 bits or `data` 8 bytes.
    /// OpenLCB never sends one; a bus may carry them.
    pub fn standard(id: u16, data: &[u8]) -> Option<Self> {
        Self::with_raw(u32::from(StandardId::new(id)?.as_raw()), data)
    }

    /// The data frame for an OpenLCB header.
    pub fn from_header(header: &CanHeader, data: &[u8]) -> Option<Self> {
        Self::extended(header.to_id(), data)
    }

    /// A data frame with `id` as stored in [`CanFrame::id`].
    fn with_raw(id: u32, data: &[u8]) -> Option<Self> {
        let mut frame = CanFrame { id, len: 0, data: [0; 8] };
        frame.data.get_mut(..data.len())?.copy_from_slice(data);
        frame.len = data.len() as u8;
        Some(frame)
    }

    /// An extended frame whose data is `head` then `body`, cut at 8 bytes. Builds frames
    /// without a staging buffer.
    pub(crate) fn build(id: u32, head: &[u8], body: &[u8]) -> Self {
        let mut data = [0u8; 8];
        let at = copy_into(&mut data, 0, head);
        let len = copy_into(&mut data, at, body) as u8;
        CanFrame { id: id & ID_BITS | EXTENDED, len, data }
    }

    /// The raw identifier: 29 bits for an extended frame, 11 for a standard one.
    pub fn raw_id(&self) -> u32 {
        self.id & ID_BITS
    }

    /// The OpenLCB view of an extended data frame's identifier.
    pub fn header(&self) -> Result<CanHeader, FrameError> {
        if self.id & EXTENDED == 0 {
            Err(FrameError::Standard)
        } else if self.id & REMOTE != 0 {
            Err(FrameError::Remote)
        } else {
            CanHeader::parse(self.raw_id()).map_err(FrameError::Header)
        }
    }

    /// The data bytes.
    pub fn payload(&self) -> &[u8] {
        self.data.get(..usize::from(self.len)).unwrap_or(&[])
    }
}

/// `id` as stored in [`CanFrame::id`].
fn stored_id(id: Id) -> u32 {
    match id {
        Id::Extended(id) => id.as_raw() | EXTENDED,
        Id::Standard(id) => u32::from(id.as_raw()),
    }
}

/// Copies `bytes` to `data[at..]` as far as it fits and returns the length used.
fn copy_into(data: &mut [u8; 8], at: usize, bytes: &[u8]) -> usize {
    let Some(room) = data.get_mut(at..) else {
        return at.min(CanFrame::MAX_DATA);
    };
    let n = room.len().min(bytes.len());
    if let (Some(to), Some(from)) = (room.get_mut(..n), bytes.get(..n)) {
        to.copy_from_slice(from);
    }
    at + n
}

impl core::fmt::Debug for CanFrame {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        if self.id & EXTENDED != 0 {
            write!(f, "CanFrame(X{:08X}", self.raw_id())?;
        } else {
            write!(f, "CanFrame(S{:03X}", self.raw_id())?;
        }
        f.write_str(if self.id & REMOTE != 0 { " R" } else { " N" })?;
        for byte in self.payload() {
            write!(f, "{byte:02X}")?;
        }
        f.write_str(")")
    }
}

/// Why a frame is not an OpenLCB frame.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
pub enum FrameError {
    /// An 11-bit standard frame (CFT §4: tolerate, ignore).
    #[error("standard (11-bit) frame")]
    Standard,
    /// A remote (RTR) frame (CFT §4: never sent by OpenLCB).
    #[error("remote frame")]
    Remote,
    /// The identifier is not a valid OpenLCB header.
    #[error("bad header: {0}")]
    Header(HeaderError),
}

impl embedded_can::Frame for CanFrame {
    fn new(id: impl Into<Id>, data: &[u8]) -> Option<Self> {
        Self::with_raw(stored_id(id.into()), data)
    }

    fn new_remote(id: impl Into<Id>, dlc: usize) -> Option<Self> {
        if dlc > Self::MAX_DATA {
            return None;
        }
        Some(CanFrame { id: stored_id(id.into()) | REMOTE, len: dlc as u8, data: [0; 8] })
    }

    fn is_extended(&self) -> bool {
        self.id & EXTENDED != 0
    }

    fn is_remote_frame(&self) -> bool {
        self.id & REMOTE != 0
    }

    fn id(&self) -> Id {
        // The stored bits always fit: the fallbacks are never taken.
        if self.is_extended() {
            Id::Extended(ExtendedId::new(self.raw_id()).unwrap_or(ExtendedId::ZERO))
        } else {
            Id::Standard(StandardId::new(self.raw_id() as u16).unwrap_or(StandardId::ZERO))
        }
    }

    fn dlc(&self) -> usize {
        usize::from(self.len)
    }

    /// The data bytes (empty for a remote frame, whose DLC only states a length).
    fn data(&self) -> &[u8] {
        if self.is_remote_frame() { &[] } else { self.payload() }
    }
}

#[cfg(test)]
mod tests {
    use embedded_can::Frame;

    use super::*;
    use crate::header::FrameKind;

    #[test]
    fn extended_frame_accessors() {
        let frame = CanFrame::extended(0x1F22_522A, &[0x55, 0x41, 0x42, 0x43]).unwrap();
        assert!(frame.is_extended() && frame.is_data_frame());
        assert_eq!(frame.dlc(), 4);
        assert_eq!(frame.data(), &[0x55, 0x41, 0x42, 0x43]);
        assert_eq!(frame.raw_id(), 0x1F22_522A);
        assert!(matches!(frame.header().unwrap().kind, FrameKind::StreamData { .. }));
        assert_eq!(format!("{frame:?}"), "CanFrame(X1F22522A N55414243)");
        assert_eq!(CanFrame::extended(0x1F22_522A, &[0; 9]), None);
    }

    #[test]
    fn standard_and_remote_frames_are_not_openlcb() {
        let standard = <CanFrame as Frame>::new(StandardId::new(0x72D).unwrap(), &[1, 2]).unwrap();
        assert!(standard.is_standard());
        assert_eq!(standard.header(), Err(FrameError::Standard));
        let remote = CanFrame::new_remote(ExtendedId::new(0x1910_0123).unwrap(), 3).unwrap();
        assert!(remote.is_remote_frame());
        assert_eq!(remote.dlc(), 3);
        assert_eq!(remote.data(), &[] as &[u8]);
        assert_eq!(remote.header(), Err(FrameError::Remote));
        assert_eq!(CanFrame::new_remote(ExtendedId::ZERO, 9), None);
    }
}
