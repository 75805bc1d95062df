//! Memory Configuration datagrams (node-protocols.md §3.3): every command and reply as a
//! typed value, parsed liberally where peers differ (§10, "Accept") and emitted strictly in
//! the form §10 says to send.

use alloc::vec::Vec;

use openlcb_stream::wire::ErrorCode;

/// Byte 0 of every Memory Configuration datagram (node-protocols.md §2.6).
pub const CONTENT_ID: u8 = 0x20;

/// The most data bytes one Read or Write datagram carries (MC §4.5, §4.8).
pub const MAX_DATA_LEN: usize = 64;

/// Space 0xFF: the CDI XML.
pub const SPACE_CDI: u8 = 0xFF;
/// Space 0xFE: all memory.
pub const SPACE_ALL: u8 = 0xFE;
/// Space 0xFD: the basic configuration space.
pub const SPACE_CONFIG: u8 = 0xFD;
/// Space 0xFC: ACDI manufacturer data (read-only, node-protocols.md §5.4).
pub const SPACE_ACDI_MANUFACTURER: u8 = 0xFC;
/// Space 0xFB: ACDI user data (read/write, node-protocols.md §5.4).
pub const SPACE_ACDI_USER: u8 = 0xFB;
/// Space 0xFA: the Function Description Information of a train (read-only XML).
pub const SPACE_FDI: u8 = 0xFA;
/// Space 0xF9: a train's function values.
pub const SPACE_FUNCTIONS: u8 = 0xF9;
/// Space 0xEF: the firmware, writable only while frozen (FWU §6.1).
pub const SPACE_FIRMWARE: u8 = 0xEF;

/// Error codes of Memory Configuration (node-protocols.md §3.6, §4.3).
pub mod codes {
    use openlcb_stream::wire::ErrorCode;
    /// Unknown command in byte 1 (MC-TN §2.4.3).
    pub const UNKNOWN_COMMAND: ErrorCode = ErrorCode(0x1041);
    /// Invalid arguments (a malformed command, a Factory Reset naming another node).
    pub const INVALID_ARGUMENTS: ErrorCode = ErrorCode(0x1080);
    /// The address space is not known.
    pub const UNKNOWN_SPACE: ErrorCode = ErrorCode(0x1081);
    /// The address lies outside the space.
    pub const OUT_OF_BOUNDS: ErrorCode = ErrorCode(0x1082);
    /// A write to a read-only space.
    pub const READ_ONLY: ErrorCode = ErrorCode(0x1083);
    /// A read of a space whose bytes cannot be read back (a firmware space): the Message
    /// Network's "not implemented" (node-protocols.md §2.3; MC §4.3 has no code of its own
    /// for a write-only space, and the space is known, so not 0x1081).
    pub const NOT_READABLE: ErrorCode = ErrorCode(0x1040);
    /// Temporary: busy (no room for another stream transfer).
    pub const BUSY: ErrorCode = ErrorCode(0x2020);
    /// Temporary: the firmware failed its checksum.
    pub const FIRMWARE_CHECKSUM: ErrorCode = ErrorCode(0x2088);
    /// Permanent: the firmware does not fit this hardware.
    pub const FIRMWARE_INCOMPATIBLE: ErrorCode = ErrorCode(0x1088);
    /// Permanent: the firmware is invalid or corrupted.
    pub const FIRMWARE_CORRUPTED: ErrorCode = ErrorCode(0x1089);
}

/// Why bytes are not a Memory Configuration command or reply. Small and `Copy`; it names
/// what was wrong.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
pub enum DecodeError {
    /// Byte 0 is not 0x20, or the datagram is empty.
    #[error("not a Memory Configuration datagram")]
    NotMemoryConfiguration,
    /// The datagram ends before a field the command needs.
    #[error("the datagram ends before its {0}")]
    TooShort(&'static str),
    /// Byte 1 names no command (or a reply where a command was expected, or the reverse).
    #[error("unknown command byte 0x{0:02X}")]
    UnknownCommand(u8),
    /// A Write or Read carries no data or more than 64 bytes.
    #[error("a datagram read or write carries 1 to 64 bytes")]
    BadLength,
}

/// Bits 1-0 of byte 1 for the three spaces with a short code (node-protocols.md §3.1).
const fn space_bits(space: u8) -> u8 {
    match space {
        0xFD => 1,
        0xFE => 2,
        0xFF => 3,
        _ => 0,
    }
}

/// Reads the address (bytes 2-5) and the space (bits 1-0 of byte 1, or byte 6), returning
/// the bytes after them.
fn address_and_space(bytes: &[u8]) -> Result<(u32, u8, &[u8]), DecodeError> {
    let [_, command, a, b, c, d, rest @ ..] = bytes else { return Err(DecodeError::TooShort("address")) };
    let address = u32::from_be_bytes([*a, *b, *c, *d]);
    match command & 0x03 {
        0 => match rest {
            [space, rest @ ..] => Ok((address, *space, rest)),
            [] => Err(DecodeError::TooShort("space")),
        },
        bits => Ok((address, 0xFC + bits, rest)),
    }
}

/// How a command names its address space: in bits 1-0 of byte 1 (the short code of 0xFD,
/// 0xFE, 0xFF) or in byte 6. A reply names it the same way (OpenMRN answers in the form
/// asked; OlcbChecker's `mc30_read` checks it).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub enum SpaceForm {
    /// The short code where the space has one, else byte 6: what this crate sends.
    #[default]
    Short,
    /// Always byte 6.
    Long,
}

impl SpaceForm {
    /// The form of the command datagram `bytes` (`Short` for commands that name no space
    /// in byte 1).
    pub fn of(bytes: &[u8]) -> Self {
        match bytes {
            [CONTENT_ID, command, ..] if command & 0x80 == 0 && command & 0x03 == 0 => SpaceForm::Long,
            _ => SpaceForm::Short,
        }
    }
}

/// Writes `20 cmd addr [space]`: the short space code when there is one and `form` allows.
fn put_header(out: &mut Vec<u8>, base: u8, space: u8, address: u32, form: SpaceForm) {
    let bits = if form == SpaceForm::Long { 0 } else { space_bits(space) };
    out.push(CONTENT_ID);
    out.push(base | bits);
    out.extend_from_slice(&address.to_be_bytes());
    if bits == 0 {
        out.push(space);
    }
}

fn u32_at(bytes: &[u8], at: usize) -> Option<u32> {
    let word: [u8; 4] = bytes.get(at..at.checked_add(4)?)?.try_into().ok()?;
    Some(u32::from_be_bytes(word))
}

fn u16_at(bytes: &[u8], at: usize) -> Option<u16> {
    let word: [u8; 2] = bytes.get(at..at.checked_add(2)?)?.try_into().ok()?;
    Some(u16::from_be_bytes(word))
}

fn u48(bytes: &[u8]) -> Option<u64> {
    let six: [u8; 6] = bytes.get(..6)?.try_into().ok()?;
    let [a, b, c, d, e, f] = six;
    Some(u64::from_be_bytes([0, 0, a, b, c, d, e, f]))
}

fn put_u48(out: &mut Vec<u8>, value: u64) {
    out.extend_from_slice(value.to_be_bytes().get(2..).unwrap_or_default());
}

/// A zero-terminated string field: the bytes up to the NUL (or the end).
fn text(bytes: &[u8]) -> Vec<u8> {
    let len = bytes.iter().position(|b| *b == 0).unwrap_or(bytes.len());
    bytes.get(..len).unwrap_or_default().to_vec()
}

/// A command a configuration tool sends to a node (node-protocols.md §3.3).
#[derive(Debug, Clone, PartialEq, Eq)]
#[non_exhaustive]
pub enum Command {
    /// Read `count` bytes (1-64; the reserved top bit is dropped) at `address`.
    Read {
        /// Address space.
        space: u8,
        /// Start address.
        address: u32,
        /// Bytes wanted.
        count: u8,
    },
    /// Write `data` (1-64 bytes) at `address`.
    Write {
        /// Address space.
        space: u8,
        /// Start address.
        address: u32,
        /// The bytes.
        data: Vec<u8>,
    },
    /// Write Under Mask: memory bits whose mask bit is 1 take the data bit (MC §4.10).
    WriteUnderMask {
        /// Address space.
        space: u8,
        /// Start address.
        address: u32,
        /// One mask byte per address.
        mask: Vec<u8>,
        /// One data byte per address.
        data: Vec<u8>,
    },
    /// Read Stream: the node opens a stream proposing `destination_stream` (MC §4.6).
    ReadStream {
        /// Address space.
        space: u8,
        /// Start address.
        address: u32,
        /// The DID the requester has armed.
        destination_stream: u8,
        /// Bytes wanted; 0 and 0xFFFFFFFF both mean "to the end of the space" (C-6).
        count: u32,
    },
    /// Write Stream: the requester opens a stream with `source_stream` (MC §4.11).
    WriteStream {
        /// Address space.
        space: u8,
        /// Start address.
        address: u32,
        /// The SID the requester will use.
        source_stream: u8,
    },
    /// Get Configuration Options (0x80).
    GetOptions,
    /// Get Address Space Information (0x84).
    GetSpaceInfo {
        /// The space asked about.
        space: u8,
    },
    /// Lock / Reserve (0x88): test-and-set; 0 releases.
    Lock {
        /// The requester's Node ID, or 0 to release.
        node: u64,
    },
    /// Get Unique ID (0x8C): 0-7 Event IDs from the node's pool.
    GetUniqueId {
        /// How many (low 3 bits of the byte).
        count: u8,
    },
    /// Freeze (0xA1) a space: for space 0xEF, enter the Firmware Upgrade state.
    Freeze {
        /// The space.
        space: u8,
    },
    /// Unfreeze (0xA0) a space: for space 0xEF, leave the Firmware Upgrade state.
    Unfreeze {
        /// The space.
        space: u8,
    },
    /// Update Complete (0xA8).
    UpdateComplete,
    /// Reset / Reboot (0xA9).
    Reset,
    /// Reinitialize / Factory Reset (0xAA), naming the destination's Node ID.
    FactoryReset {
        /// The Node ID given (must be the destination's).
        node: u64,
    },
}

impl Command {
    /// Reads a command datagram (byte 0 = 0x20), liberally where peers differ.
    ///
    /// A command the crate is built without is [`DecodeError::UnknownCommand`], as the server
    /// built so answers it, and a firmware links none of its decoding: without the
    /// `optional-commands` feature Write Under Mask, Lock and Get Unique ID; without `streams`
    /// Read Stream and Write Stream.
    pub fn parse(bytes: &[u8]) -> Result<Self, DecodeError> {
        let [CONTENT_ID, command, rest @ ..] = bytes else { return Err(DecodeError::NotMemoryConfiguration) };
        let command = *command;
        let byte = |name| rest.first().copied().ok_or(DecodeError::TooShort(name));
        // Bit 2 is reserved and "checked on receipt" (MC-TN §2.4): such a byte is unknown.
        match command {
            0x00..=0x03 => {
                let (address, space, data) = address_and_space(bytes)?;
                if data.is_empty() || data.len() > MAX_DATA_LEN {
                    return Err(DecodeError::BadLength);
                }
                Ok(Command::Write { space, address, data: data.to_vec() })
            }
            0x08..=0x0B if cfg!(feature = "optional-commands") => {
                let (address, space, pairs) = address_and_space(bytes)?;
                if pairs.len() < 2 || pairs.len() > MAX_DATA_LEN || pairs.len() % 2 != 0 {
                    return Err(DecodeError::BadLength);
                }
                // Mask and data bytes alternate; split in one plain loop (flash).
                let (mut mask, mut data) = (Vec::with_capacity(pairs.len() / 2), Vec::with_capacity(pairs.len() / 2));
                for pair in pairs.chunks_exact(2) {
                    if let [m, d] = pair {
                        mask.push(*m);
                        data.push(*d);
                    }
                }
                Ok(Command::WriteUnderMask { space, address, mask, data })
            }
            0x20..=0x23 if cfg!(feature = "streams") => {
                let (address, space, rest) = address_and_space(bytes)?;
                // C-1: the FWU-TN trace puts 0xFF before the SID; take the byte after it.
                let source_stream = match rest {
                    [0xFF, sid, ..] => *sid,
                    [sid, ..] => *sid,
                    [] => return Err(DecodeError::TooShort("source stream ID")),
                };
                Ok(Command::WriteStream { space, address, source_stream })
            }
            0x40..=0x43 => {
                let (address, space, rest) = address_and_space(bytes)?;
                let count = rest.first().ok_or(DecodeError::TooShort("count"))? & 0x7F;
                Ok(Command::Read { space, address, count })
            }
            0x60..=0x63 if cfg!(feature = "streams") => {
                let (address, space, rest) = address_and_space(bytes)?;
                // The 0xFF placeholder is ignored on receipt; a missing count means "to end".
                let [_, did, count @ ..] = rest else { return Err(DecodeError::TooShort("destination stream ID")) };
                let count = u32_at(count, 0).unwrap_or(u32::MAX);
                Ok(Command::ReadStream { space, address, destination_stream: *did, count })
            }
            0x80 => Ok(Command::GetOptions),
            0x84 => Ok(Command::GetSpaceInfo { space: byte("space")? }),
            0x88 if cfg!(feature = "optional-commands") => {
                Ok(Command::Lock { node: u48(rest).ok_or(DecodeError::TooShort("Node ID"))? })
            }
            0x8C if cfg!(feature = "optional-commands") => Ok(Command::GetUniqueId { count: byte("count")? & 0x07 }),
            0xA0 => Ok(Command::Unfreeze { space: byte("space")? }),
            0xA1 => Ok(Command::Freeze { space: byte("space")? }),
            0xA8 => Ok(Command::UpdateComplete),
            0xA9 => Ok(Command::Reset),
            0xAA => Ok(Command::FactoryReset { node: u48(rest).ok_or(DecodeError::TooShort("Node ID"))? }),
            other => Err(DecodeError::UnknownCommand(other)),
        }
    }

    /// The datagram for this command, in the form node-protocols.md §10 says to send (the
    /// short space code where there is one; Write Stream without an 0xFF before the SID).
    pub fn to_bytes(&self) -> Vec<u8> {
        let mut out = Vec::with_capacity(16);
        match self {
            Command::Read { space, address, count } => {
                put_header(&mut out, 0x40, *space, *address, SpaceForm::Short);
                out.push(*count & 0x7F);
            }
            Command::Write { space, address, data } => {
                put_header(&mut out, 0x00, *space, *address, SpaceForm::Short);
                out.extend_from_slice(data);
            }
            Command::WriteUnderMask { space, address, mask, data } => {
                put_header(&mut out, 0x08, *space, *address, SpaceForm::Short);
                for (m, d) in mask.iter().zip(data) {
                    out.extend_from_slice(&[*m, *d]);
                }
            }
            Command::ReadStream { space, address, destination_stream, count } => {
                put_header(&mut out, 0x60, *space, *address, SpaceForm::Short);
                out.extend_from_slice(&[0xFF, *destination_stream]);
                out.extend_from_slice(&count.to_be_bytes());
            }
            Command::WriteStream { space, address, source_stream } => {
                put_header(&mut out, 0x20, *space, *address, SpaceForm::Short);
                out.push(*source_stream);
            }
            Command::GetOptions => out.extend_from_slice(&[CONTENT_ID, 0x80]),
            Command::GetSpaceInfo { space } => out.extend_from_slice(&[CONTENT_ID, 0x84, *space]),
            Command::Lock { node } => {
                out.extend_from_slice(&[CONTENT_ID, 0x88]);
                put_u48(&mut out, *node);
            }
            Command::GetUniqueId { count } => out.extend_from_slice(&[CONTENT_ID, 0x8C, *count & 0x07]),
            Command::Unfreeze { space } => out.extend_from_slice(&[CONTENT_ID, 0xA0, *space]),
            Command::Freeze { space } => out.extend_from_slice(&[CONTENT_ID, 0xA1, *space]),
            Command::UpdateComplete => out.extend_from_slice(&[CONTENT_ID, 0xA8]),
            Command::Reset => out.extend_from_slice(&[CONTENT_ID, 0xA9]),
            Command::FactoryReset { node } => {
                out.extend_from_slice(&[CONTENT_ID, 0xAA]);
                put_u48(&mut out, *node);
            }
        }
        out
    }
}

/// The Get Configuration Options reply (node-protocols.md §3.7).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct OptionsReply {
    /// Available commands (bytes 2-3): 0x8000 Write Under Mask, 0x4000 unaligned reads, 0x2000
    /// unaligned writes, 0x1000 OpenMRN's stream reads, 0x0800/0x0400/0x0200 ACDI access.
    pub commands: u16,
    /// Write lengths (byte 4): 0xE2 base, 0x01 stream reads and writes.
    pub write_lengths: u8,
    /// Highest address space.
    pub highest_space: u8,
    /// Lowest address space, if sent.
    pub lowest_space: Option<u8>,
    /// The optional name string (without its NUL).
    pub name: Vec<u8>,
}

impl OptionsReply {
    /// Write Under Mask supported.
    pub const WRITE_UNDER_MASK: u16 = 0x8000;
    /// Unaligned reads supported.
    pub const UNALIGNED_READS: u16 = 0x4000;
    /// Unaligned writes supported.
    pub const UNALIGNED_WRITES: u16 = 0x2000;
    /// OpenMRN's proposed "stream reads supported" bit (C-5: read, never sent).
    pub const OPENMRN_STREAM_READS: u16 = 0x1000;
    /// Space 0xFC readable.
    pub const ACDI_MANUFACTURER_READ: u16 = 0x0800;
    /// Space 0xFB readable.
    pub const ACDI_USER_READ: u16 = 0x0400;
    /// Space 0xFB writable.
    pub const ACDI_USER_WRITE: u16 = 0x0200;
    /// Byte 4 without streams: the reserved bits sent as 1 (MC-TN §2.4.14).
    pub const BASE_WRITE_LENGTHS: u8 = 0xE2;
    /// Byte 4 bit: stream reads and writes supported (C-5).
    pub const STREAMS: u8 = 0x01;

    /// The node can do Read Stream and Write Stream: either bit of C-5 is set.
    pub fn streams(&self) -> bool {
        self.write_lengths & Self::STREAMS != 0 || self.commands & Self::OPENMRN_STREAM_READS != 0
    }
}

/// The Get Address Space Information reply (node-protocols.md §3.8).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct SpaceInfoReply {
    /// The space (echo).
    pub space: u8,
    /// 0x87 (present) or 0x86 (not present).
    pub present: bool,
    /// Highest address, when sent (a 3-byte "not present" reply has none).
    pub highest_address: Option<u32>,
    /// Flag bit 0.
    pub read_only: bool,
    /// The lowest address, when the reply gives one (flag bit 1).
    pub lowest_address: Option<u32>,
    /// The optional description (without its NUL).
    pub description: Vec<u8>,
}

/// A reply a node sends back in its own datagram (node-protocols.md §3.3). The stream
/// replies keep `space: None` for OpenLcbCLib's form without the space byte (C-8).
#[derive(Debug, Clone, PartialEq, Eq)]
#[non_exhaustive]
pub enum Reply {
    /// Read Reply OK with the bytes read.
    ReadOk {
        /// Address space.
        space: u8,
        /// Start address.
        address: u32,
        /// The bytes (1-64).
        data: Vec<u8>,
    },
    /// Write Reply OK.
    WriteOk {
        /// Address space.
        space: u8,
        /// Start address.
        address: u32,
    },
    /// Read Stream Reply OK (MC §4.7).
    ReadStreamOk {
        /// Address space; `None` in OpenLcbCLib's form without byte 6 (C-8).
        space: Option<u8>,
        /// Start address.
        address: u32,
        /// The stream's SID.
        source_stream: u8,
        /// The stream's DID.
        destination_stream: u8,
        /// The count, when the reply carries one.
        count: Option<u32>,
    },
    /// Write Stream Reply OK (MC §4.12). OpenMRN's Bootloader sends no stream IDs (C-2).
    WriteStreamOk {
        /// Address space; `None` in OpenLcbCLib's form without byte 6 (C-8).
        space: Option<u8>,
        /// Start address.
        address: u32,
        /// (SID, DID), when sent. Never relied on (C-2).
        streams: Option<(u8, u8)>,
    },
    /// A failed Read, Write, Read Stream or Write Stream (byte 1 bit 3 set).
    Failed {
        /// Which command failed.
        kind: FailedKind,
        /// Address space; `None` in OpenLcbCLib's stream form without byte 6 (C-8).
        space: Option<u8>,
        /// Start address.
        address: u32,
        /// The error code (0 when the reply is too short to carry one).
        code: ErrorCode,
    },
    /// Get Configuration Options reply (0x82).
    Options(OptionsReply),
    /// Get Address Space Information reply (0x86 / 0x87).
    SpaceInfo(SpaceInfoReply),
    /// Lock / Reserve reply (0x8A): what the lock memory holds.
    Lock {
        /// The owner, or 0.
        owner: u64,
    },
    /// Get Unique ID reply (0x8D).
    UniqueIds {
        /// 0-7 Event IDs.
        ids: Vec<[u8; 8]>,
    },
}

/// Which command a [`Reply::Failed`] answers.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum FailedKind {
    /// A Read (0x58-0x5B).
    Read,
    /// A Write or Write Under Mask (0x18-0x1B).
    Write,
    /// A Read Stream (0x78-0x7B).
    ReadStream,
    /// A Write Stream (0x38-0x3B).
    WriteStream,
}

impl FailedKind {
    const fn base(self) -> u8 {
        match self {
            FailedKind::Write => 0x18,
            FailedKind::WriteStream => 0x38,
            FailedKind::Read => 0x58,
            FailedKind::ReadStream => 0x78,
        }
    }
}

/// Whether byte 1 of a 0x20 datagram is a reply (so it goes to the client, not the server).
pub fn is_reply(command: u8) -> bool {
    match command {
        // Bit 2 is reserved in the read/write range (MC-TN §2.4).
        0x10..=0x1B | 0x30..=0x3B | 0x50..=0x5B | 0x70..=0x7B => command & 0x04 == 0,
        0x82 | 0x86 | 0x87 | 0x8A | 0x8D => true,
        _ => false,
    }
}

/// For a stream reply (0x30/0x38/0x70/0x78 with space in byte 6): whether byte 6 is absent,
/// OpenLcbCLib's form (C-8), told by the length.
fn clib_form(command: u8, len: usize) -> bool {
    command & 0x03 == 0
        && match command {
            0x30 => len == 8 || len == 6,
            0x70 => len == 12 || len == 8,
            0x38 | 0x78 => len == 8,
            _ => false,
        }
}

fn stream_reply_space(bytes: &[u8]) -> Result<(u32, Option<u8>, &[u8]), DecodeError> {
    let command = bytes.get(1).copied().unwrap_or(0);
    if clib_form(command, bytes.len()) {
        let address = u32_at(bytes, 2).ok_or(DecodeError::TooShort("address"))?;
        return Ok((address, None, bytes.get(6..).unwrap_or_default()));
    }
    let (address, space, rest) = address_and_space(bytes)?;
    Ok((address, Some(space), rest))
}

impl Reply {
    /// Reads a reply datagram, liberally: stream replies without byte 6 (C-8), a Write Stream
    /// Reply of 6 or more bytes classified by byte 1 alone (C-2), space information of 3 to 12
    /// or more bytes (C-10), an Options reply without its lowest space.
    pub fn parse(bytes: &[u8]) -> Result<Self, DecodeError> {
        let [CONTENT_ID, command, rest @ ..] = bytes else { return Err(DecodeError::NotMemoryConfiguration) };
        let command = *command;
        if !is_reply(command) {
            return Err(DecodeError::UnknownCommand(command));
        }
        let failed_kind = match command & 0xF0 {
            0x10 => Some(FailedKind::Write),
            0x30 => Some(FailedKind::WriteStream),
            0x50 => Some(FailedKind::Read),
            0x70 => Some(FailedKind::ReadStream),
            _ => None,
        };
        if let Some(kind) = failed_kind.filter(|_| command & 0x08 != 0) {
            let (address, space, rest) = match kind {
                FailedKind::ReadStream | FailedKind::WriteStream => stream_reply_space(bytes)?,
                _ => {
                    let (address, space, rest) = address_and_space(bytes)?;
                    (address, Some(space), rest)
                }
            };
            let code = ErrorCode(u16_at(rest, 0).unwrap_or(0));
            return Ok(Reply::Failed { kind, space, address, code });
        }
        match command {
            0x10..=0x13 => {
                let (address, space, _) = address_and_space(bytes)?;
                Ok(Reply::WriteOk { space, address })
            }
            0x30..=0x33 => {
                let (address, space, rest) = stream_reply_space(bytes)?;
                let streams = match rest {
                    [sid, did, ..] => Some((*sid, *did)),
                    _ => None,
                };
                Ok(Reply::WriteStreamOk { space, address, streams })
            }
            0x50..=0x53 => {
                let (address, space, data) = address_and_space(bytes)?;
                if data.is_empty() || data.len() > MAX_DATA_LEN {
                    return Err(DecodeError::BadLength);
                }
                Ok(Reply::ReadOk { space, address, data: data.to_vec() })
            }
            0x70..=0x73 => {
                let (address, space, rest) = stream_reply_space(bytes)?;
                let [sid, did, count @ ..] = rest else { return Err(DecodeError::TooShort("stream IDs")) };
                Ok(Reply::ReadStreamOk {
                    space,
                    address,
                    source_stream: *sid,
                    destination_stream: *did,
                    count: u32_at(count, 0),
                })
            }
            0x82 => {
                let commands = u16_at(rest, 0).ok_or(DecodeError::TooShort("available commands"))?;
                let [_, _, write_lengths, highest_space, tail @ ..] = rest else {
                    return Err(DecodeError::TooShort("highest space"));
                };
                let (lowest_space, name) = match tail {
                    [lowest, name @ ..] => (Some(*lowest), text(name)),
                    [] => (None, Vec::new()),
                };
                Ok(Reply::Options(OptionsReply {
                    commands,
                    write_lengths: *write_lengths,
                    highest_space: *highest_space,
                    lowest_space,
                    name,
                }))
            }
            0x86 | 0x87 => {
                let [space, tail @ ..] = rest else { return Err(DecodeError::TooShort("space")) };
                let highest_address = u32_at(tail, 0);
                let flags = tail.get(4).copied().unwrap_or(0);
                // A lowest address of 0 is the default the reply may leave out.
                let lowest_given = flags & 0x02 != 0;
                let lowest_address = u32_at(tail, 5).filter(|low| lowest_given && *low != 0);
                let description_at = if lowest_given { 9 } else { 5 };
                Ok(Reply::SpaceInfo(SpaceInfoReply {
                    space: *space,
                    present: command == 0x87,
                    highest_address,
                    read_only: highest_address.is_some() && flags & 0x01 != 0,
                    lowest_address,
                    description: text(tail.get(description_at..).unwrap_or_default()),
                }))
            }
            0x8A => Ok(Reply::Lock { owner: u48(rest).ok_or(DecodeError::TooShort("Node ID"))? }),
            0x8D => {
                let ids = rest.chunks_exact(8).take(7).filter_map(|id| id.try_into().ok()).collect();
                Ok(Reply::UniqueIds { ids })
            }
            other => Err(DecodeError::UnknownCommand(other)),
        }
    }

    /// The datagram for this reply, strictly: the MC layouts, the short space code where
    /// there is one, a 3-byte "not present" space reply (C-10), no failure text.
    pub fn to_bytes(&self) -> Vec<u8> {
        self.to_bytes_in(SpaceForm::Short)
    }

    /// [`to_bytes`](Self::to_bytes), naming the space in `form`: a server answers in the form
    /// it was asked.
    pub fn to_bytes_in(&self, form: SpaceForm) -> Vec<u8> {
        match self {
            Reply::ReadOk { space, address, data } => read_ok_bytes(*space, *address, data, form),
            Reply::WriteOk { space, address } => write_ok_bytes(*space, *address, form),
            Reply::ReadStreamOk { space, address, source_stream, destination_stream, count } => {
                read_stream_ok_bytes(*space, *address, (*source_stream, *destination_stream), *count, form)
            }
            Reply::WriteStreamOk { space, address, streams } => write_stream_ok_bytes(*space, *address, *streams, form),
            Reply::Failed { kind, space, address, code } => failed_bytes(*kind, *space, *address, *code, form),
            Reply::Options(options) => options.to_bytes(),
            Reply::SpaceInfo(info) => info.to_bytes(),
            Reply::Lock { owner } => lock_bytes(*owner),
            Reply::UniqueIds { ids } => unique_ids_bytes(ids),
        }
    }
}

// One encoder per reply, which `Reply::to_bytes_in` dispatches to and the server calls
// directly: a firmware links the encoders of the replies it sends, not every reply's.

/// A reply datagram `put` writes.
fn reply_bytes(put: impl FnOnce(&mut Vec<u8>)) -> Vec<u8> {
    let mut out = Vec::with_capacity(16);
    put(&mut out);
    out
}

/// A stream reply's header: `space` in `form`, or none (OpenLcbCLib's form, C-8).
fn put_stream_header(out: &mut Vec<u8>, base: u8, space: Option<u8>, address: u32, form: SpaceForm) {
    match space {
        Some(space) => put_header(out, base, space, address, form),
        None => {
            out.extend_from_slice(&[CONTENT_ID, base]);
            out.extend_from_slice(&address.to_be_bytes());
        }
    }
}

/// Read Reply OK: the header, then `data`.
pub(crate) fn read_ok_bytes(space: u8, address: u32, data: &[u8], form: SpaceForm) -> Vec<u8> {
    reply_bytes(|out| {
        put_header(out, 0x50, space, address, form);
        out.extend_from_slice(data);
    })
}

/// Write Reply OK: the header alone.
pub(crate) fn write_ok_bytes(space: u8, address: u32, form: SpaceForm) -> Vec<u8> {
    reply_bytes(|out| put_header(out, 0x10, space, address, form))
}

/// Read Stream Reply OK: the header, the (SID, DID), the count if any.
pub(crate) fn read_stream_ok_bytes(
    space: Option<u8>,
    address: u32,
    (sid, did): (u8, u8),
    count: Option<u32>,
    form: SpaceForm,
) -> Vec<u8> {
    reply_bytes(|out| {
        put_stream_header(out, 0x70, space, address, form);
        out.extend_from_slice(&[sid, did]);
        if let Some(count) = count {
            out.extend_from_slice(&count.to_be_bytes());
        }
    })
}

/// Write Stream Reply OK: the header, the (SID, DID) if any.
pub(crate) fn write_stream_ok_bytes(
    space: Option<u8>,
    address: u32,
    streams: Option<(u8, u8)>,
    form: SpaceForm,
) -> Vec<u8> {
    reply_bytes(|out| {
        put_stream_header(out, 0x30, space, address, form);
        if let Some((sid, did)) = streams {
            out.extend_from_slice(&[sid, did]);
        }
    })
}

/// A failed command's reply: the header (a Read's or Write's names a space, 0 for none),
/// then `code`.
pub(crate) fn failed_bytes(
    kind: FailedKind,
    space: Option<u8>,
    address: u32,
    code: ErrorCode,
    form: SpaceForm,
) -> Vec<u8> {
    reply_bytes(|out| {
        match kind {
            FailedKind::Read | FailedKind::Write => put_header(out, kind.base(), space.unwrap_or(0), address, form),
            FailedKind::ReadStream | FailedKind::WriteStream => {
                put_stream_header(out, kind.base(), space, address, form)
            }
        }
        out.extend_from_slice(&code.0.to_be_bytes());
    })
}

/// Lock / Reserve Reply: the lock's owner.
pub(crate) fn lock_bytes(owner: u64) -> Vec<u8> {
    reply_bytes(|out| {
        out.extend_from_slice(&[CONTENT_ID, 0x8A]);
        put_u48(out, owner);
    })
}

/// Get Unique ID Reply: up to 7 IDs.
pub(crate) fn unique_ids_bytes(ids: &[[u8; 8]]) -> Vec<u8> {
    reply_bytes(|out| {
        out.extend_from_slice(&[CONTENT_ID, 0x8D]);
        for id in ids.iter().take(7) {
            out.extend_from_slice(id);
        }
    })
}

impl OptionsReply {
    /// The reply's datagram (0x82).
    pub(crate) fn to_bytes(&self) -> Vec<u8> {
        reply_bytes(|out| {
            out.extend_from_slice(&[CONTENT_ID, 0x82]);
            out.extend_from_slice(&self.commands.to_be_bytes());
            out.extend_from_slice(&[self.write_lengths, self.highest_space]);
            if let Some(lowest) = self.lowest_space {
                out.push(lowest);
                if !self.name.is_empty() {
                    out.extend_from_slice(&self.name);
                    out.push(0);
                }
            }
        })
    }
}

impl SpaceInfoReply {
    /// The reply's datagram (0x87 present, 0x86 not: then 3 bytes, C-10).
    pub(crate) fn to_bytes(&self) -> Vec<u8> {
        reply_bytes(|out| {
            out.extend_from_slice(&[CONTENT_ID, if self.present { 0x87 } else { 0x86 }, self.space]);
            if let Some(highest) = self.highest_address {
                out.extend_from_slice(&highest.to_be_bytes());
                let lowest = self.lowest_address.filter(|low| *low != 0);
                out.push(u8::from(self.read_only) | if lowest.is_some() { 0x02 } else { 0 });
                if let Some(low) = lowest {
                    out.extend_from_slice(&low.to_be_bytes());
                }
                if !self.description.is_empty() {
                    out.extend_from_slice(&self.description);
                    out.push(0);
                }
            }
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use alloc::vec;

    /// Parses `bytes` as a command, checks it is `expected`, and that it re-emits to `emitted`.
    fn command(bytes: &[u8], expected: Command, emitted: &[u8]) {
        let parsed = Command::parse(bytes).unwrap();
        assert_eq!(parsed, expected);
        assert_eq!(parsed.to_bytes(), emitted);
        assert_eq!(Command::parse(&parsed.to_bytes()).unwrap(), parsed);
    }

    fn reply(bytes: &[u8], expected: Reply, emitted: &[u8]) {
        let parsed = Reply::parse(bytes).unwrap();
        assert_eq!(parsed, expected);
        assert_eq!(parsed.to_bytes(), emitted);
        assert_eq!(Reply::parse(&parsed.to_bytes()).unwrap(), parsed);
    }

    // ----- §9.1 datagram write of 8 bytes to 0xFD -----

    #[test]
    fn write_of_worked_example_9_1() {
        let bytes = [0x20, 0x01, 0, 0, 0, 0, 1, 2, 3, 4, 5, 6, 7, 8];
        command(&bytes, Command::Write { space: 0xFD, address: 0, data: vec![1, 2, 3, 4, 5, 6, 7, 8] }, &bytes);
        reply(&[0x20, 0x11, 0, 0, 0, 0], Reply::WriteOk { space: 0xFD, address: 0 }, &[0x20, 0x11, 0, 0, 0, 0]);
        let failed = [0x20, 0x19, 0, 0, 0, 0, 0x10, 0x83];
        reply(
            &failed,
            Reply::Failed { kind: FailedKind::Write, space: Some(0xFD), address: 0, code: ErrorCode(0x1083) },
            &failed,
        );
    }

    // ----- §9.2 read of 64 bytes from the CDI -----

    #[test]
    fn read_of_worked_example_9_2() {
        let bytes = [0x20, 0x43, 0, 0, 0, 0, 0x40];
        command(&bytes, Command::Read { space: 0xFF, address: 0, count: 64 }, &bytes);
        let xml = b"<?xml version=\"1.0\"?>\n<cdi xmlns:xsi=\"http://www.w3.org/2001/XML";
        assert_eq!(xml.len(), 64);
        let mut answer = vec![0x20, 0x53, 0, 0, 0, 0];
        answer.extend_from_slice(xml);
        reply(&answer, Reply::ReadOk { space: 0xFF, address: 0, data: xml.to_vec() }, &answer);
        let failed = [0x20, 0x5B, 0, 0, 0, 0, 0x10, 0x82];
        reply(
            &failed,
            Reply::Failed { kind: FailedKind::Read, space: Some(0xFF), address: 0, code: ErrorCode(0x1082) },
            &failed,
        );
    }

    #[test]
    fn read_count_top_bit_is_ignored_and_data_bounded() {
        assert_eq!(
            Command::parse(&[0x20, 0x40, 0, 0, 1, 0, 0x22, 0xC0]).unwrap(),
            Command::Read { space: 0x22, address: 256, count: 0x40 }
        );
        assert_eq!(Command::parse(&[0x20, 0x00, 0, 0, 0, 0, 0x22]), Err(DecodeError::BadLength));
        assert_eq!(Command::parse(&[0x20, 0x01, 0, 0, 0, 0]), Err(DecodeError::BadLength));
        let mut long = vec![0x20, 0x01, 0, 0, 0, 0];
        long.extend_from_slice(&[0; 65]);
        assert_eq!(Command::parse(&long), Err(DecodeError::BadLength));
        assert_eq!(Command::parse(&[0x20, 0x41, 0, 0]), Err(DecodeError::TooShort("address")));
        assert_eq!(Command::parse(&[0x21, 0x80]), Err(DecodeError::NotMemoryConfiguration));
        assert_eq!(Command::parse(&[0x20, 0x44, 0, 0, 0, 0, 1]), Err(DecodeError::UnknownCommand(0x44)));
        assert_eq!(Command::parse(&[0x20, 0xAB]), Err(DecodeError::UnknownCommand(0xAB)));
    }

    // ----- §9.3 Write Stream to the firmware space -----

    #[test]
    fn write_stream_of_worked_example_9_3() {
        command(&[0x20, 0xA1, 0xEF], Command::Freeze { space: 0xEF }, &[0x20, 0xA1, 0xEF]);
        if cfg!(feature = "streams") {
            let bytes = [0x20, 0x20, 0, 0, 0, 0, 0xEF, 0x55];
            command(&bytes, Command::WriteStream { space: 0xEF, address: 0, source_stream: 0x55 }, &bytes);
        }
        // The reply as the OpenMRN Bootloader sends it: no stream IDs (C-2).
        let openmrn = [0x20, 0x30, 0, 0, 0, 0, 0xEF];
        reply(&openmrn, Reply::WriteStreamOk { space: Some(0xEF), address: 0, streams: None }, &openmrn);
        // The [MC] form, 9 bytes.
        let standard = [0x20, 0x30, 0, 0, 0, 0, 0xEF, 0x55, 0x5A];
        reply(
            &standard,
            Reply::WriteStreamOk { space: Some(0xEF), address: 0, streams: Some((0x55, 0x5A)) },
            &standard,
        );
        let bad_image = [0x20, 0x38, 0, 0, 0, 0, 0xEF, 0x10, 0x88];
        reply(
            &bad_image,
            Reply::Failed { kind: FailedKind::WriteStream, space: Some(0xEF), address: 0, code: ErrorCode(0x1088) },
            &bad_image,
        );
        command(&[0x20, 0xA0, 0xEF], Command::Unfreeze { space: 0xEF }, &[0x20, 0xA0, 0xEF]);
    }

    #[test]
    fn write_stream_with_the_fwu_tn_placeholder_is_accepted() {
        // C-1: the FWU-TN trace's 9-byte form, 0xFF before the SID; sent in the [MC] form.
        if cfg!(feature = "streams") {
            command(
                &[0x20, 0x20, 0, 0, 0, 0, 0xEF, 0xFF, 0x55],
                Command::WriteStream { space: 0xEF, address: 0, source_stream: 0x55 },
                &[0x20, 0x20, 0, 0, 0, 0, 0xEF, 0x55],
            );
        }
        // Its reply, DID before SID, is classified by byte 1 alone (C-2).
        assert!(matches!(
            Reply::parse(&[0x20, 0x30, 0, 0, 0, 0, 0xEF, 0x5A, 0x55]),
            Ok(Reply::WriteStreamOk { space: Some(0xEF), .. })
        ));
    }

    #[test]
    fn stream_replies_without_the_space_byte_are_accepted() {
        // C-8: OpenLcbCLib leaves byte 6 out of 0x30/0x38/0x70 replies.
        reply(
            &[0x20, 0x30, 0, 0, 0, 0, 0x55, 0x5A],
            Reply::WriteStreamOk { space: None, address: 0, streams: Some((0x55, 0x5A)) },
            &[0x20, 0x30, 0, 0, 0, 0, 0x55, 0x5A],
        );
        reply(
            &[0x20, 0x38, 0, 0, 0, 0, 0x10, 0x80],
            Reply::Failed { kind: FailedKind::WriteStream, space: None, address: 0, code: ErrorCode(0x1080) },
            &[0x20, 0x38, 0, 0, 0, 0, 0x10, 0x80],
        );
        reply(
            &[0x20, 0x70, 0, 0, 0, 0, 0x02, 0x01, 0, 0, 0, 0xC8],
            Reply::ReadStreamOk { space: None, address: 0, source_stream: 2, destination_stream: 1, count: Some(200) },
            &[0x20, 0x70, 0, 0, 0, 0, 0x02, 0x01, 0, 0, 0, 0xC8],
        );
    }

    // ----- §9.4 Read Stream -----

    #[test]
    fn read_stream_of_worked_example_9_4() {
        let answer = [0x20, 0x71, 0, 0, 0, 0, 0x02, 0x01, 0, 0, 0, 0xC8];
        reply(
            &answer,
            Reply::ReadStreamOk {
                space: Some(0xFD),
                address: 0,
                source_stream: 2,
                destination_stream: 1,
                count: Some(200),
            },
            &answer,
        );
        let failed = [0x20, 0x79, 0, 0, 0, 0, 0x10, 0x82];
        reply(
            &failed,
            Reply::Failed { kind: FailedKind::ReadStream, space: Some(0xFD), address: 0, code: ErrorCode(0x1082) },
            &failed,
        );
        if !cfg!(feature = "streams") {
            return;
        }
        let bytes = [0x20, 0x61, 0, 0, 0, 0, 0xFF, 0x01, 0, 0, 0, 0xC8];
        command(&bytes, Command::ReadStream { space: 0xFD, address: 0, destination_stream: 1, count: 200 }, &bytes);
        // The byte-6 form of the same command.
        let byte6 = [0x20, 0x60, 0, 0, 0, 0, 0xFD, 0xFF, 0x01, 0, 0, 0, 0xC8];
        let parsed = Command::parse(&byte6).unwrap();
        assert_eq!(parsed, Command::ReadStream { space: 0xFD, address: 0, destination_stream: 1, count: 200 });
        let low = [0x20, 0x60, 0, 0, 0, 0, 0x22, 0xFF, 0x01, 0, 0, 0, 0xC8];
        command(&low, Command::ReadStream { space: 0x22, address: 0, destination_stream: 1, count: 200 }, &low);
        // OpenMRN: a command without a count reads to the end.
        assert_eq!(
            Command::parse(&[0x20, 0x61, 0, 0, 0, 0, 0xFF, 0x01]).unwrap(),
            Command::ReadStream { space: 0xFD, address: 0, destination_stream: 1, count: u32::MAX }
        );
    }

    // ----- §9.6 smaller exchanges -----

    #[test]
    fn options_and_space_information_of_worked_example_9_6() {
        command(&[0x20, 0x80], Command::GetOptions, &[0x20, 0x80]);
        let options = [0x20, 0x82, 0x60, 0x00, 0xE3, 0xFF, 0xEF];
        let parsed = Reply::parse(&options).unwrap();
        reply(
            &options,
            Reply::Options(OptionsReply {
                commands: 0x6000,
                write_lengths: 0xE3,
                highest_space: 0xFF,
                lowest_space: Some(0xEF),
                name: Vec::new(),
            }),
            &options,
        );
        assert!(matches!(parsed, Reply::Options(o) if o.streams()));
        // An OpenMRN node with streams: avail 0x7000, lengths 0xE2 (C-5, either bit).
        let Ok(Reply::Options(openmrn)) = Reply::parse(&[0x20, 0x82, 0x70, 0x00, 0xE2, 0x28, 0x27]) else { panic!() };
        assert!(openmrn.streams());
        let Ok(Reply::Options(plain)) = Reply::parse(&[0x20, 0x82, 0x60, 0x00, 0xE2, 0xFF]) else { panic!() };
        assert!(!plain.streams());
        assert_eq!(plain.lowest_space, None);

        command(&[0x20, 0x84, 0xFD], Command::GetSpaceInfo { space: 0xFD }, &[0x20, 0x84, 0xFD]);
        let info = [0x20, 0x87, 0xFD, 0x00, 0x00, 0x01, 0xFF, 0x00];
        reply(
            &info,
            Reply::SpaceInfo(SpaceInfoReply {
                space: 0xFD,
                present: true,
                highest_address: Some(0x1FF),
                read_only: false,
                lowest_address: None,
                description: Vec::new(),
            }),
            &info,
        );
    }

    #[test]
    fn space_information_of_three_to_twelve_bytes() {
        // C-10: OpenMRN's 3 bytes, OpenLcbCLib's 8, and a full one with a low address.
        let absent = SpaceInfoReply {
            space: 0x22,
            present: false,
            highest_address: None,
            read_only: false,
            lowest_address: None,
            description: Vec::new(),
        };
        reply(&[0x20, 0x86, 0x22], Reply::SpaceInfo(absent.clone()), &[0x20, 0x86, 0x22]);
        let padded = Reply::parse(&[0x20, 0x86, 0x22, 0, 0, 0, 0, 0]).unwrap();
        assert!(matches!(padded, Reply::SpaceInfo(SpaceInfoReply { present: false, .. })));
        let full = [0x20, 0x87, 0xEF, 0, 1, 0, 0, 0x03, 0, 0, 0x10, 0, b'f', b'w', 0];
        reply(
            &full,
            Reply::SpaceInfo(SpaceInfoReply {
                space: 0xEF,
                present: true,
                highest_address: Some(0x10000),
                read_only: true,
                lowest_address: Some(0x1000),
                description: b"fw".to_vec(),
            }),
            &full,
        );
    }

    #[test]
    fn control_commands_and_their_replies() {
        let id = [0x05, 0x01, 0x01, 0x01, 0x40, 0x01];
        if cfg!(feature = "optional-commands") {
            let lock = [0x20, 0x88, 0x05, 0x01, 0x01, 0x01, 0x40, 0x01];
            command(&lock, Command::Lock { node: 0x05_01_01_01_40_01 }, &lock);
            command(&[0x20, 0x8C, 0xFA], Command::GetUniqueId { count: 2 }, &[0x20, 0x8C, 0x02]);
        }
        let mut locked = vec![0x20, 0x8A];
        locked.extend_from_slice(&id);
        reply(&locked, Reply::Lock { owner: 0x05_01_01_01_40_01 }, &locked);
        let ids = [0x20, 0x8D, 5, 1, 1, 1, 0x40, 2, 0, 1];
        reply(&ids, Reply::UniqueIds { ids: vec![[5, 1, 1, 1, 0x40, 2, 0, 1]] }, &ids);
        command(&[0x20, 0xA8], Command::UpdateComplete, &[0x20, 0xA8]);
        command(&[0x20, 0xA9], Command::Reset, &[0x20, 0xA9]);
        let factory = [0x20, 0xAA, 0x05, 0x01, 0x01, 0x01, 0x40, 0x02];
        command(&factory, Command::FactoryReset { node: 0x05_01_01_01_40_02 }, &factory);
        assert_eq!(Command::parse(&[0x20, 0xAA, 5, 1]), Err(DecodeError::TooShort("Node ID")));
    }

    #[test]
    #[cfg(feature = "optional-commands")]
    fn write_under_mask_pairs() {
        let bytes = [0x20, 0x09, 0, 0, 0, 4, 0xF0, 0xAB, 0x0F, 0xCD];
        command(
            &bytes,
            Command::WriteUnderMask { space: 0xFD, address: 4, mask: vec![0xF0, 0x0F], data: vec![0xAB, 0xCD] },
            &bytes,
        );
        assert_eq!(Command::parse(&[0x20, 0x09, 0, 0, 0, 4, 0xF0]), Err(DecodeError::BadLength));
    }

    #[test]
    fn commands_the_crate_is_built_without_are_unknown() {
        let optional: [&[u8]; 3] =
            [&[0x20, 0x09, 0, 0, 0, 4, 0xF0, 0xAB], &[0x20, 0x88, 5, 1, 1, 1, 0x40, 1], &[0x20, 0x8C, 2]];
        let stream: [&[u8]; 2] = [&[0x20, 0x20, 0, 0, 0, 0, 0xEF, 0x55], &[0x20, 0x61, 0, 0, 0, 0, 0xFF, 1]];
        for (built, commands) in
            [(cfg!(feature = "optional-commands"), optional.as_slice()), (cfg!(feature = "streams"), &stream)]
        {
            for bytes in commands {
                let parsed = Command::parse(bytes);
                if built {
                    assert!(parsed.is_ok(), "{bytes:02X?}: {parsed:?}");
                } else {
                    assert_eq!(parsed, Err(DecodeError::UnknownCommand(bytes[1])), "{bytes:02X?}");
                }
            }
        }
    }

    #[test]
    fn replies_and_commands_are_told_apart() {
        for command in [0x10, 0x1B, 0x30, 0x3B, 0x50, 0x53, 0x70, 0x7B, 0x82, 0x86, 0x87, 0x8A, 0x8D] {
            assert!(is_reply(command), "0x{command:02X}");
        }
        for command in [0x00, 0x08, 0x20, 0x40, 0x60, 0x80, 0x84, 0x88, 0x8C, 0xA0, 0xA9, 0x14, 0x54] {
            assert!(!is_reply(command), "0x{command:02X}");
        }
        assert_eq!(Reply::parse(&[0x20, 0x40, 0, 0, 0, 0, 1]), Err(DecodeError::UnknownCommand(0x40)));
    }
}
