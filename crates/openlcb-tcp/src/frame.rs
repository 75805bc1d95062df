//! The OpenLCB-TCP message layout (wire-spec §8) and its encoder.
//!
//! ```text
//! offset size field
//!      0    2 flags                 0x8000 = OpenLCB message; 0x0C00 = multi-part bits
//!      2    3 length                bytes after this field
//!      5    6 gateway Node ID       the node that put the message onto this link
//!     11    6 capture time          48-bit, only needs to increase
//!     17    2 MTI
//!     19    6 source Node ID
//!     25    6 destination Node ID   only if MTI & 0x0008
//!  25/31    n payload               (an Event ID first if MTI & 0x0004)
//! ```

use core::fmt;

use bytes::BufMut;
use openlcb_stream::{Instant, MessageRef, Mti, NodeId};

/// Flags (2 bytes) and length (3 bytes): what must be read before a message's size is known.
pub const HEADER_LEN: usize = 5;
/// Gateway Node ID (6 bytes) and capture time (6 bytes): the start of what the length counts.
pub const PREFIX_LEN: usize = 12;
/// The largest value the 24-bit length field can hold.
pub const MAX_LENGTH: u32 = 0xFF_FFFF;
/// The length field of the largest message the stream core can send: a Stream Data Send
/// carrying a whole 65535-byte window (prefix, MTI, two Node IDs, DID, data).
pub const MAX_STREAM_DATA_LENGTH: u32 = (PREFIX_LEN + MTI_LEN + 2 * NODE_ID_LEN + 1 + 65_535) as u32;

const MTI_LEN: usize = 2;
const NODE_ID_LEN: usize = 6;
/// The longest run of fixed fields before the payload: header, prefix, MTI, two Node IDs.
const MAX_FIXED_LEN: usize = HEADER_LEN + PREFIX_LEN + MTI_LEN + 2 * NODE_ID_LEN;

/// The 16-bit flags field, as an open type: unknown and reserved bits keep their raw value.
#[derive(Clone, Copy, PartialEq, Eq, Hash)]
pub struct Flags(pub u16);

impl Flags {
    /// What this crate sends: an OpenLCB message, in one part, no chaining.
    pub const MESSAGE: Flags = Flags(0x8000);
    /// Bit 0x8000: set for an OpenLCB message, clear for a link-control message.
    pub const OPENLCB_MESSAGE_BIT: u16 = 0x8000;
    /// Bit 0x4000: another prefix follows (chaining; no layout is defined, wire-spec Q8).
    pub const CHAINING_BIT: u16 = 0x4000;
    /// Bit 0x0800: this part is not the first of its message (wire-spec §10 C-15).
    pub const NOT_FIRST_BIT: u16 = 0x0800;
    /// Bit 0x0400: this part is not the last of its message (wire-spec §10 C-15).
    pub const NOT_LAST_BIT: u16 = 0x0400;

    /// The raw value.
    pub const fn as_raw(self) -> u16 {
        self.0
    }

    /// An OpenLCB message (bit 0x8000); otherwise a link-control message.
    pub const fn is_openlcb_message(self) -> bool {
        self.0 & Self::OPENLCB_MESSAGE_BIT != 0
    }

    /// The chaining bit 0x4000 is set.
    pub const fn is_chained(self) -> bool {
        self.0 & Self::CHAINING_BIT != 0
    }

    /// Which part of a multi-part message this is. Reserved bits play no part.
    pub const fn part(self) -> Part {
        match (self.0 & Self::NOT_FIRST_BIT != 0, self.0 & Self::NOT_LAST_BIT != 0) {
            (false, false) => Part::Whole,
            (false, true) => Part::First,
            (true, true) => Part::Middle,
            (true, false) => Part::Last,
        }
    }
}

impl fmt::Debug for Flags {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "Flags(0x{:04X})", self.0)
    }
}

/// Where a message on the link sits in a multi-part sequence (flags 0x0C00).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Part {
    /// A whole message (neither bit).
    Whole,
    /// The first part (0x0400, "not last").
    First,
    /// A middle part (both bits).
    Middle,
    /// The last part (0x0800, "not first").
    Last,
}

impl Part {
    /// The flag bits that say this part.
    pub const fn flag_bits(self) -> u16 {
        match self {
            Part::Whole => 0,
            Part::First => Flags::NOT_LAST_BIT,
            Part::Middle => Flags::NOT_FIRST_BIT | Flags::NOT_LAST_BIT,
            Part::Last => Flags::NOT_FIRST_BIT,
        }
    }
}

/// The 48-bit capture time of the link prefix: milliseconds or a sequence number chosen by the
/// node that puts the message onto the link. It only needs to increase.
#[derive(Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash, Default)]
pub struct CaptureTime(u64);

impl CaptureTime {
    /// The largest capture time: all 48 bits set.
    pub const MAX: CaptureTime = CaptureTime(0xFFFF_FFFF_FFFF);

    /// A capture time, or `None` if bits above 47 are set.
    pub const fn new(raw: u64) -> Option<Self> {
        if raw > Self::MAX.0 { None } else { Some(CaptureTime(raw)) }
    }

    /// The low 48 bits of `raw`, for a counter that may run past 48 bits.
    pub const fn wrapping(raw: u64) -> Self {
        CaptureTime(raw & Self::MAX.0)
    }

    /// The milliseconds of `now` since the caller's epoch (wrapping at 48 bits).
    pub const fn from_instant(now: Instant) -> Self {
        Self::wrapping(now.as_millis())
    }

    /// The 48-bit value.
    pub const fn as_raw(self) -> u64 {
        self.0
    }

    /// The six wire bytes, most significant first.
    pub const fn to_bytes(self) -> [u8; 6] {
        let b = self.0.to_be_bytes();
        [b[2], b[3], b[4], b[5], b[6], b[7]]
    }

    /// A capture time from its six wire bytes.
    pub const fn from_bytes(bytes: [u8; 6]) -> Self {
        CaptureTime(NodeId::from_bytes(bytes).as_raw())
    }
}

impl fmt::Debug for CaptureTime {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "CaptureTime({})", self.0)
    }
}

/// What the link adds in front of a full-format message: who put it on the link, and when.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct LinkPrefix {
    /// The originating node or gateway: the node that put the message onto this link.
    pub gateway: NodeId,
    /// When (or in which order) it did.
    pub capture_time: CaptureTime,
}

/// Why a message cannot be encoded.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
pub enum EncodeError {
    /// The caller's buffer is smaller than [`TcpFrame::encoded_len`].
    #[error("buffer of {got} bytes is too small, {needed} needed")]
    BufferTooSmall {
        /// What `encoded_len` asked for.
        needed: usize,
        /// What the caller gave.
        got: usize,
    },
    /// The length field would exceed its 24 bits.
    #[error("length field would be {length}, more than the 24-bit maximum {MAX_LENGTH}")]
    TooLong {
        /// The length the message needs.
        length: usize,
    },
    /// The MTI has the address bit but the message has no destination.
    #[error("{mti:?} is addressed but the message has no destination Node ID")]
    MissingDestination {
        /// The message type.
        mti: Mti,
    },
    /// The MTI has no address bit but the message has a destination.
    #[error("{mti:?} is global but the message has a destination Node ID")]
    UnexpectedDestination {
        /// The message type.
        mti: Mti,
    },
}

/// One OpenLCB message on the link: the link prefix and the full-format message.
///
/// Decoded frames borrow their payload from the input or the decoder's buffer; frames to send
/// borrow it from the core's [`Message`](openlcb_stream::Message) via `as_ref()`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct TcpFrame<'a> {
    /// Who put the message onto the link, and when.
    pub prefix: LinkPrefix,
    /// The full-format message.
    pub message: MessageRef<'a>,
}

impl<'a> TcpFrame<'a> {
    /// A frame of `message` behind `prefix`.
    pub const fn new(prefix: LinkPrefix, message: MessageRef<'a>) -> Self {
        TcpFrame { prefix, message }
    }

    /// The value of the length field: everything after it.
    pub fn length_field(&self) -> usize {
        let destination = if self.message.mti.is_addressed() { NODE_ID_LEN } else { 0 };
        (PREFIX_LEN + MTI_LEN + NODE_ID_LEN + destination).saturating_add(self.message.payload.len())
    }

    /// The exact number of bytes [`encode`](Self::encode) writes.
    pub fn encoded_len(&self) -> usize {
        HEADER_LEN.saturating_add(self.length_field())
    }

    /// Writes the frame (flags 0x8000, one part) to the front of `buf` and returns its length.
    /// Never panics: a short buffer gets [`EncodeError::BufferTooSmall`] and is left as it was.
    pub fn encode(&self, buf: &mut [u8]) -> Result<usize, EncodeError> {
        let mut cursor = buf;
        self.encode_to(&mut cursor)
    }

    /// Appends the frame (flags 0x8000, one part) to `out` and returns the number of bytes
    /// appended. A `BytesMut` or `Vec<u8>` grows as needed (a reused one with room does not
    /// allocate); a `&mut [u8]` without room gets [`EncodeError::BufferTooSmall`] and nothing
    /// is written.
    pub fn encode_to<B: BufMut + ?Sized>(&self, out: &mut B) -> Result<usize, EncodeError> {
        let fixed = self.fixed_fields()?;
        let needed = fixed.len().saturating_add(self.message.payload.len());
        let got = out.remaining_mut();
        if got < needed {
            return Err(EncodeError::BufferTooSmall { needed, got });
        }
        out.put_slice(fixed.as_slice());
        out.put_slice(self.message.payload);
        Ok(needed)
    }

    /// The checks every encoder makes before writing a byte.
    fn check(&self) -> Result<(), EncodeError> {
        let mti = self.message.mti;
        match (mti.is_addressed(), self.message.destination) {
            (true, None) => return Err(EncodeError::MissingDestination { mti }),
            (false, Some(_)) => return Err(EncodeError::UnexpectedDestination { mti }),
            _ => {}
        }
        let length = self.length_field();
        if length > MAX_LENGTH as usize {
            return Err(EncodeError::TooLong { length });
        }
        Ok(())
    }

    /// Checks the frame and lays out everything before the payload, in wire order: the one
    /// place that knows the field order.
    fn fixed_fields(&self) -> Result<FixedFields, EncodeError> {
        self.check()?;
        let length = u32::try_from(self.length_field()).unwrap_or(MAX_LENGTH).to_be_bytes();
        let destination = self.message.destination.map(NodeId::to_bytes);
        let fields: [&[u8]; 7] = [
            &Flags::MESSAGE.0.to_be_bytes(),
            length.get(1..).unwrap_or_default(),
            &self.prefix.gateway.to_bytes(),
            &self.prefix.capture_time.to_bytes(),
            &self.message.mti.as_raw().to_be_bytes(),
            &self.message.source.to_bytes(),
            destination.as_ref().map_or(&[], |d| d.as_slice()),
        ];
        let mut fixed = FixedFields { bytes: [0; MAX_FIXED_LEN], len: 0 };
        for field in fields {
            if let Some(to) = fixed.bytes.get_mut(fixed.len..fixed.len + field.len()) {
                to.copy_from_slice(field);
                fixed.len += field.len();
            }
        }
        Ok(fixed)
    }
}

/// Flags, length, prefix, MTI and Node IDs of one frame, laid out.
struct FixedFields {
    bytes: [u8; MAX_FIXED_LEN],
    len: usize,
}

impl FixedFields {
    fn as_slice(&self) -> &[u8] {
        self.bytes.get(..self.len).unwrap_or_default()
    }

    fn len(&self) -> usize {
        self.len
    }
}

/// Reads the link prefix and full-format message from `body`: the bytes the length field
/// counts, of a whole (one-part) message.
pub(crate) fn parse_body(body: &[u8]) -> Result<TcpFrame<'_>, MessageTooShort> {
    let (prefix, rest) = parse_prefix(body).ok_or(MessageTooShort { needed: PREFIX_LEN })?;
    let message = parse_message(rest).map_err(|short| MessageTooShort { needed: PREFIX_LEN + short.needed })?;
    Ok(TcpFrame { prefix, message })
}

/// Splits the 12-byte link prefix off `body`.
pub(crate) fn parse_prefix(body: &[u8]) -> Option<(LinkPrefix, &[u8])> {
    let (gateway, rest) = body.split_first_chunk::<NODE_ID_LEN>()?;
    let (time, rest) = rest.split_first_chunk::<6>()?;
    Some((LinkPrefix { gateway: NodeId::from_bytes(*gateway), capture_time: CaptureTime::from_bytes(*time) }, rest))
}

/// Reads MTI, source, destination (for addressed MTIs) and payload.
pub(crate) fn parse_message(bytes: &[u8]) -> Result<MessageRef<'_>, MessageTooShort> {
    const GLOBAL_LEN: usize = MTI_LEN + NODE_ID_LEN;
    let (mti, rest) = bytes.split_first_chunk::<MTI_LEN>().ok_or(MessageTooShort { needed: GLOBAL_LEN })?;
    let mti = Mti(u16::from_be_bytes(*mti));
    let needed = if mti.is_addressed() { GLOBAL_LEN + NODE_ID_LEN } else { GLOBAL_LEN };
    let (source, rest) = rest.split_first_chunk::<NODE_ID_LEN>().ok_or(MessageTooShort { needed })?;
    let (destination, payload) = if mti.is_addressed() {
        let (destination, rest) = rest.split_first_chunk::<NODE_ID_LEN>().ok_or(MessageTooShort { needed })?;
        (Some(NodeId::from_bytes(*destination)), rest)
    } else {
        (None, rest)
    };
    Ok(MessageRef { mti, source: NodeId::from_bytes(*source), destination, payload })
}

/// The bytes are fewer than the fixed fields need.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) struct MessageTooShort {
    /// How many bytes the fixed fields need.
    pub(crate) needed: usize,
}

/// The smallest length field of a whole OpenLCB message: prefix, MTI and source.
pub(crate) const MIN_WHOLE_LENGTH: usize = PREFIX_LEN + MTI_LEN + NODE_ID_LEN;

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn flags_name_the_parts() {
        assert_eq!(Flags(0x8000).part(), Part::Whole);
        assert_eq!(Flags(0x8400).part(), Part::First);
        assert_eq!(Flags(0x8C00).part(), Part::Middle);
        assert_eq!(Flags(0x8800).part(), Part::Last);
        assert_eq!(Flags(0x83FF).part(), Part::Whole);
        for part in [Part::Whole, Part::First, Part::Middle, Part::Last] {
            assert_eq!(Flags(0x8000 | part.flag_bits()).part(), part);
        }
        assert!(Flags(0xC000).is_chained());
        assert!(!Flags(0x7FFF).is_openlcb_message());
    }

    #[test]
    fn capture_time_is_48_bits() {
        assert_eq!(CaptureTime::new(1 << 48), None);
        assert_eq!(CaptureTime::wrapping((1 << 48) + 5).as_raw(), 5);
        assert_eq!(CaptureTime::from_instant(Instant::from_millis(0x42)).to_bytes(), [0, 0, 0, 0, 0, 0x42]);
        let t = CaptureTime::new(0x0102_0304_0506).unwrap();
        assert_eq!(CaptureTime::from_bytes(t.to_bytes()), t);
    }

    #[test]
    fn max_stream_data_length_fits_a_whole_window() {
        assert_eq!(MAX_STREAM_DATA_LENGTH, 12 + 2 + 6 + 6 + 1 + 65_535);
    }
}
