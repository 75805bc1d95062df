//! [`MemorySpace`]: what a server serves, and the ready-made spaces: RAM, a read-only blob
//! (the CDI), the ACDI layouts of SNIP (node-protocols.md §5.4).

use alloc::vec;
use alloc::vec::Vec;

use openlcb_stream::wire::ErrorCode;

use super::wire::codes;
use crate::SnipInfo;

/// Why a space refused a read or a write. The server turns it into the standard's code.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
pub enum SpaceError {
    /// The address lies beyond the space (0x1082).
    #[error("the address lies outside the space")]
    OutOfBounds,
    /// The space cannot be written (0x1083).
    #[error("the space is read-only")]
    ReadOnly,
    /// Anything else the medium reports, with the code to send (e.g. 0x2000 while flash is
    /// busy, 0x1089 for a corrupted image).
    #[error("the space failed with code 0x{:04X}", .0.0)]
    Failed(ErrorCode),
}

impl SpaceError {
    /// The error code the server sends for it.
    pub fn code(self) -> ErrorCode {
        match self {
            SpaceError::OutOfBounds => codes::OUT_OF_BOUNDS,
            SpaceError::ReadOnly => codes::READ_ONLY,
            SpaceError::Failed(code) => code,
        }
    }
}

/// One address space a node serves: flash, EEPROM, a file, a RAM buffer. The server asks
/// no more than this; it checks bounds and read-only itself before calling `read`/`write`,
/// so an implementation may stay simple, and a space may still refuse with a
/// [`SpaceError`].
pub trait MemorySpace {
    /// The size in bytes. Addresses `0..len` exist; a Get Address Space Information reply
    /// gives `len - 1` as the highest address.
    fn len(&self) -> u32;

    /// A space of no bytes (reads fail with out of bounds).
    fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Writes are refused with 0x1083 (a space is wholly read-only or not, MC §4.1).
    fn read_only(&self) -> bool;

    /// Reads are refused with 0x1040 (not implemented, node-protocols.md §2.3): a firmware
    /// space (0xEF) whose image cannot be read back. Get Address Space Information still
    /// reports the space; it has no flag for write-only.
    fn write_only(&self) -> bool {
        false
    }

    /// Fills `buf` from `address` and returns how many bytes it filled (fewer only at the
    /// end of the space). The server calls it with `address < len`.
    fn read(&mut self, address: u32, buf: &mut [u8]) -> Result<usize, SpaceError>;

    /// Stores `data` at `address`. The server calls it with the whole range inside the space.
    fn write(&mut self, address: u32, data: &[u8]) -> Result<(), SpaceError>;

    /// One write command is done: a Write datagram, or a whole Write Stream transfer (whose
    /// bytes came in [`write`](Self::write)s of a few hundred bytes), whether it ended well
    /// or not. A space whose medium is slow to update (a file replaced whole, a flash page)
    /// stores here what the command wrote, once. An error fails a datagram's write (Write
    /// Failed with its code) and a transfer still waiting for its reply.
    fn commit(&mut self) -> Result<(), SpaceError> {
        Ok(())
    }

    /// The most bytes a Write Stream to this space may have in flight (the window the server
    /// grants), for a medium that takes data in blocks (one flash page). `None`: the
    /// server's [`MemoryConfigOptions::write_stream_window`](super::MemoryConfigOptions::write_stream_window).
    fn write_window(&self) -> Option<u16> {
        None
    }

    /// Firmware space 0xEF only: the owner's Unfreeze came, and bytes `0..len` written while
    /// frozen are the image. Store it (flash it, save it) before returning; an error refuses
    /// the Unfreeze with its code and the node stays frozen, so the loader reports the
    /// failure instead of a success.
    fn complete(&mut self, len: u32) -> Result<(), SpaceError> {
        let _ = len;
        Ok(())
    }

    /// Firmware space 0xEF only: what was written is no image (a new Freeze, or a retry
    /// after an aborted transfer starts at offset 0 again); forget it.
    fn discard(&mut self) {}
}

/// Copies as much of `from` as fits into `to`; returns how many bytes.
pub(crate) fn copy_prefix(to: &mut [u8], from: &[u8]) -> usize {
    let n = to.len().min(from.len());
    if let (Some(to), Some(from)) = (to.get_mut(..n), from.get(..n)) {
        to.copy_from_slice(from);
    }
    n
}

/// Copies from `bytes` at `address` into `buf`, as a read of a byte-slice space.
pub(crate) fn read_slice(bytes: &[u8], address: u32, buf: &mut [u8]) -> Result<usize, SpaceError> {
    let tail = usize::try_from(address).ok().and_then(|at| bytes.get(at..)).ok_or(SpaceError::OutOfBounds)?;
    Ok(copy_prefix(buf, tail))
}

/// Copies `data` into `bytes` at `address`, as a write of a byte-slice space.
fn write_slice(bytes: &mut [u8], address: u32, data: &[u8]) -> Result<(), SpaceError> {
    let at = usize::try_from(address).map_err(|_| SpaceError::OutOfBounds)?;
    let end = at.checked_add(data.len()).ok_or(SpaceError::OutOfBounds)?;
    bytes.get_mut(at..end).ok_or(SpaceError::OutOfBounds)?.copy_from_slice(data);
    Ok(())
}

fn len_u32(bytes: &[u8]) -> u32 {
    u32::try_from(bytes.len()).unwrap_or(u32::MAX)
}

/// A read/write space in RAM, of a size fixed when it is made (so it is bounded): a
/// configuration space for tests and tools, or the receiving buffer of a firmware target.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct RamSpace {
    bytes: Vec<u8>,
    written: u32,
}

impl RamSpace {
    /// `size` bytes of zeros.
    pub fn new(size: u32) -> Self {
        RamSpace { bytes: vec![0; size as usize], written: 0 }
    }

    /// A space holding `bytes` (its size is theirs).
    pub fn from_bytes(bytes: Vec<u8>) -> Self {
        RamSpace { bytes, written: 0 }
    }

    /// The contents.
    pub fn as_bytes(&self) -> &[u8] {
        &self.bytes
    }

    /// One past the highest address written so far (a firmware image's length).
    pub fn written_len(&self) -> u32 {
        self.written
    }
}

impl MemorySpace for RamSpace {
    fn len(&self) -> u32 {
        len_u32(&self.bytes)
    }
    fn read_only(&self) -> bool {
        false
    }
    fn read(&mut self, address: u32, buf: &mut [u8]) -> Result<usize, SpaceError> {
        read_slice(&self.bytes, address, buf)
    }
    fn write(&mut self, address: u32, data: &[u8]) -> Result<(), SpaceError> {
        write_slice(&mut self.bytes, address, data)?;
        let end = address.saturating_add(len_u32(data));
        self.written = self.written.max(end);
        Ok(())
    }
}

/// A read-only space over fixed bytes: the CDI XML (space 0xFF), an FDI, a version blob.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ReadOnlySpace {
    bytes: Vec<u8>,
}

impl ReadOnlySpace {
    /// A space holding `bytes`.
    pub fn new(bytes: Vec<u8>) -> Self {
        ReadOnlySpace { bytes }
    }

    /// A CDI space: the XML text followed by the NUL that ends it (CDI §5.1).
    pub fn cdi(xml: &str) -> Self {
        let mut bytes = Vec::with_capacity(xml.len() + 1);
        bytes.extend_from_slice(xml.as_bytes());
        bytes.push(0);
        ReadOnlySpace { bytes }
    }
}

impl MemorySpace for ReadOnlySpace {
    fn len(&self) -> u32 {
        len_u32(&self.bytes)
    }
    fn read_only(&self) -> bool {
        true
    }
    fn read(&mut self, address: u32, buf: &mut [u8]) -> Result<usize, SpaceError> {
        read_slice(&self.bytes, address, buf)
    }
    fn write(&mut self, _address: u32, _data: &[u8]) -> Result<(), SpaceError> {
        Err(SpaceError::ReadOnly)
    }
}

/// Layout of the ACDI spaces (node-protocols.md §5.4): (offset, size) of each string slot.
const ACDI_MANUFACTURER_SLOTS: [(usize, usize); 4] = [(1, 41), (42, 41), (83, 21), (104, 21)];
const ACDI_USER_SLOTS: [(usize, usize); 2] = [(1, 63), (64, 64)];
/// Size of space 0xFC.
pub const ACDI_MANUFACTURER_LEN: usize = 125;
/// Size of space 0xFB.
pub const ACDI_USER_LEN: usize = 128;

fn put_slot(bytes: &mut [u8], (at, size): (usize, usize), value: &str) {
    let Some(slot) = bytes.get_mut(at..at + size) else { return };
    slot.fill(0);
    // The last byte of a slot is always the NUL.
    copy_prefix(slot.get_mut(..size.saturating_sub(1)).unwrap_or_default(), value.as_bytes());
}

fn get_slot(bytes: &[u8], (at, size): (usize, usize)) -> alloc::string::String {
    let slot = bytes.get(at..at + size).unwrap_or_default();
    // Up to the first NUL, borrowed: no copy to collect (flash).
    let len = slot.iter().position(|b| *b == 0).unwrap_or(slot.len());
    crate::snip::lossy_string(slot.get(..len).unwrap_or_default())
}

/// Space 0xFC as SNIP's manufacturer strings fill it: version 4, then manufacturer, model,
/// hardware and software version at their fixed offsets.
pub fn acdi_manufacturer_bytes(snip: &SnipInfo) -> Vec<u8> {
    let mut bytes = vec![0; ACDI_MANUFACTURER_LEN];
    if let Some(version) = bytes.first_mut() {
        *version = 4;
    }
    let values = [&snip.manufacturer, &snip.model, &snip.hardware_version, &snip.software_version];
    for (slot, value) in ACDI_MANUFACTURER_SLOTS.into_iter().zip(values) {
        put_slot(&mut bytes, slot, value);
    }
    bytes
}

/// Space 0xFB as SNIP's user strings fill it: version 2, user name, user description.
pub fn acdi_user_bytes(snip: &SnipInfo) -> Vec<u8> {
    let mut bytes = vec![0; ACDI_USER_LEN];
    if let Some(version) = bytes.first_mut() {
        *version = 2;
    }
    for (slot, value) in ACDI_USER_SLOTS.into_iter().zip([&snip.user_name, &snip.user_description]) {
        put_slot(&mut bytes, slot, value);
    }
    bytes
}

/// The user name and description space 0xFB holds.
pub fn acdi_user_strings(bytes: &[u8]) -> (alloc::string::String, alloc::string::String) {
    let [name, description] = ACDI_USER_SLOTS;
    (get_slot(bytes, name), get_slot(bytes, description))
}

#[cfg(test)]
mod tests {
    use super::*;
    use alloc::string::ToString;

    #[test]
    fn acdi_slots_sit_at_the_offsets_of_5_4() {
        let snip = SnipInfo {
            manufacturer: "Acme".to_string(),
            model: "Widget".to_string(),
            hardware_version: "1.0".to_string(),
            software_version: "2.3".to_string(),
            user_name: "Yard".to_string(),
            user_description: "West end".to_string(),
        };
        let fixed = acdi_manufacturer_bytes(&snip);
        assert_eq!(fixed.len(), 125);
        assert_eq!(fixed[0], 4);
        assert_eq!(&fixed[1..6], b"Acme\0");
        assert_eq!(&fixed[0x2A..0x31], b"Widget\0");
        assert_eq!(&fixed[0x53..0x57], b"1.0\0");
        assert_eq!(&fixed[0x68..0x6C], b"2.3\0");
        let user = acdi_user_bytes(&snip);
        assert_eq!(user.len(), 128);
        assert_eq!(user[0], 2);
        assert_eq!(&user[1..6], b"Yard\0");
        assert_eq!(&user[0x40..0x49], b"West end\0");
        assert_eq!(acdi_user_strings(&user), ("Yard".to_string(), "West end".to_string()));
    }

    #[test]
    fn a_long_string_keeps_its_slot_terminated() {
        let snip = SnipInfo { manufacturer: "M".repeat(60), ..SnipInfo::default() };
        let fixed = acdi_manufacturer_bytes(&snip);
        assert_eq!(fixed[41], 0, "the 41st byte of the slot is the NUL");
        assert_eq!(fixed[42], 0, "the model slot is untouched");
    }

    #[test]
    fn ram_and_read_only_spaces_keep_their_bounds() {
        let mut ram = RamSpace::new(10);
        assert_eq!(ram.write(8, &[1, 2]), Ok(()));
        assert_eq!(ram.write(9, &[1, 2]), Err(SpaceError::OutOfBounds));
        assert_eq!(ram.write(u32::MAX, &[1]), Err(SpaceError::OutOfBounds));
        assert_eq!(ram.written_len(), 10);
        let mut buf = [0; 4];
        assert_eq!(ram.read(8, &mut buf), Ok(2));
        assert_eq!(buf[..2], [1, 2]);
        assert_eq!(ram.read(11, &mut buf), Err(SpaceError::OutOfBounds));
        let mut cdi = ReadOnlySpace::cdi("<cdi/>");
        assert_eq!((cdi.len(), cdi.read_only()), (7, true));
        assert_eq!(cdi.write(0, &[1]), Err(SpaceError::ReadOnly));
        assert_eq!(cdi.read(5, &mut buf), Ok(2));
        assert_eq!(buf[..2], [b'>', 0]);
        assert_eq!(SpaceError::Failed(ErrorCode(0x1089)).code(), ErrorCode(0x1089));
    }
}
