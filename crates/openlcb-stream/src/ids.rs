//! Validated identifiers: [`NodeId`], [`EventId`], [`StreamId`] and [`ContentUid`].

use core::fmt;
use core::num::{NonZeroU8, NonZeroU64};
use core::str::FromStr;

/// A 48-bit OpenLCB Node ID, printed and parsed as `05.01.01.01.22.00`.
///
/// Node ID 0 is not a valid node (MN §3.3) but it is representable, because a few messages
/// (an empty AME, a global Verify Node ID) carry no node at all and callers want one type.
///
/// Held with bit 48 set above the 48-bit value, so that it is never zero and an
/// `Option<NodeId>` (a message's destination, a lock's holder) is as small as a `NodeId`:
/// 8 bytes instead of 16, in every queued message of a microcontroller's RAM.
#[derive(Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub struct NodeId(NonZeroU64);

/// The bit above the 48 of a Node ID that every held value has set.
const NODE_ID_HELD: u64 = 1 << 48;

impl NodeId {
    /// The largest Node ID: all 48 bits set.
    pub const MAX: NodeId = NodeId::held(0xFFFF_FFFF_FFFF);

    /// The value `raw` (48 bits) as held.
    const fn held(raw: u64) -> Self {
        // One plus the held value less one: the held value itself, as a `NonZeroU64` without
        // a check that could fail (the held bit makes it at least 2^48).
        NodeId(NonZeroU64::MIN.saturating_add((raw | NODE_ID_HELD) - 1))
    }

    /// A Node ID from its 48-bit value, or `None` if bits above 47 are set.
    pub const fn new(raw: u64) -> Option<Self> {
        if raw > Self::MAX.as_raw() { None } else { Some(NodeId::held(raw)) }
    }

    /// The 48-bit value.
    pub const fn as_raw(self) -> u64 {
        self.0.get() & !NODE_ID_HELD
    }

    /// A Node ID from its six wire bytes, most significant first.
    pub const fn from_bytes(b: [u8; 6]) -> Self {
        NodeId::held(
            (b[0] as u64) << 40
                | (b[1] as u64) << 32
                | (b[2] as u64) << 24
                | (b[3] as u64) << 16
                | (b[4] as u64) << 8
                | b[5] as u64,
        )
    }

    /// A Node ID from the first six bytes of `bytes`, or `None` if there are fewer.
    pub fn from_slice(bytes: &[u8]) -> Option<Self> {
        let six: [u8; 6] = bytes.get(..6)?.try_into().ok()?;
        Some(Self::from_bytes(six))
    }

    /// The six wire bytes, most significant first.
    pub const fn to_bytes(self) -> [u8; 6] {
        let b = self.as_raw().to_be_bytes();
        [b[2], b[3], b[4], b[5], b[6], b[7]]
    }
}

impl Default for NodeId {
    /// Node ID 0: no node.
    fn default() -> Self {
        NodeId::held(0)
    }
}

impl fmt::Display for NodeId {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let b = self.to_bytes();
        write!(f, "{:02X}.{:02X}.{:02X}.{:02X}.{:02X}.{:02X}", b[0], b[1], b[2], b[3], b[4], b[5])
    }
}

impl fmt::Debug for NodeId {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "NodeId({self})")
    }
}

/// Why a text could not be read as a [`NodeId`].
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
pub enum ParseNodeIdError {
    /// Not six groups of one or two hex digits separated by dots, nor 1..=12 bare hex digits.
    #[error("a Node ID is six hex bytes separated by dots, e.g. 05.01.01.01.22.00")]
    Format,
}

impl FromStr for NodeId {
    type Err = ParseNodeIdError;

    /// Accepts `05.01.01.01.22.00` (also with `:` or `-` separators) and bare hex such as
    /// `050101012200` or `0x050101012200`.
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        parse_hex_bytes::<6>(s).map(NodeId::from_bytes).ok_or(ParseNodeIdError::Format)
    }
}

/// `N` bytes written as `N` groups of one or two hex digits separated by `.`, `:` or `-`, or
/// as at most `2 * N` bare hex digits (with or without `0x`), most significant first.
fn parse_hex_bytes<const N: usize>(s: &str) -> Option<[u8; N]> {
    let s = s.trim();
    let mut bytes = [0u8; N];
    if s.contains(['.', ':', '-']) {
        let mut groups = s.split(['.', ':', '-']);
        for byte in &mut bytes {
            let group = groups.next()?;
            if group.is_empty() || group.len() > 2 {
                return None;
            }
            *byte = u8::from_str_radix(group, 16).ok()?;
        }
        return groups.next().is_none().then_some(bytes);
    }
    let hex = s.strip_prefix("0x").or_else(|| s.strip_prefix("0X")).unwrap_or(s);
    if hex.is_empty() || hex.len() > 2 * N || !hex.bytes().all(|c| c.is_ascii_hexdigit()) {
        return None;
    }
    let raw = u64::from_str_radix(hex, 16).ok()?.to_be_bytes();
    for (byte, raw) in bytes.iter_mut().zip(raw.get(8 - N..)?) {
        *byte = *raw;
    }
    Some(bytes)
}

/// A 64-bit Event ID (Event Transport), printed and parsed as `05.01.01.01.22.00.00.01`.
/// Its first six bytes are usually the Node ID of the node that assigned it.
#[derive(Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash, Default)]
pub struct EventId(pub u64);

impl EventId {
    /// An Event ID from its eight wire bytes, most significant first.
    pub const fn from_bytes(bytes: [u8; 8]) -> Self {
        EventId(u64::from_be_bytes(bytes))
    }

    /// An Event ID from the first eight bytes of `bytes` (a message's payload), or `None` if
    /// there are fewer.
    pub fn from_slice(bytes: &[u8]) -> Option<Self> {
        Some(Self::from_bytes(bytes.get(..8)?.try_into().ok()?))
    }

    /// The eight wire bytes, most significant first.
    pub const fn to_bytes(self) -> [u8; 8] {
        self.0.to_be_bytes()
    }

    /// The raw value.
    pub const fn as_raw(self) -> u64 {
        self.0
    }
}

impl fmt::Display for EventId {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let [a, b, c, d, e, g, h, i] = self.to_bytes();
        write!(f, "{a:02X}.{b:02X}.{c:02X}.{d:02X}.{e:02X}.{g:02X}.{h:02X}.{i:02X}")
    }
}

impl fmt::Debug for EventId {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "EventId({self})")
    }
}

/// Why a text could not be read as an [`EventId`].
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
pub enum ParseEventIdError {
    /// Not eight groups of one or two hex digits separated by dots, nor 1..=16 bare hex digits.
    #[error("an Event ID is eight hex bytes separated by dots, e.g. 05.01.01.01.22.00.00.01")]
    Format,
}

impl FromStr for EventId {
    type Err = ParseEventIdError;

    /// Accepts `05.01.01.01.22.00.00.01` (also with `:` or `-` separators) and bare hex such
    /// as `0501010122000001` or `0x0501010122000001`.
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        parse_hex_bytes::<8>(s).map(EventId::from_bytes).ok_or(ParseEventIdError::Format)
    }
}

/// A stream ID (SID or DID): 0..=254. The value 0xFF is reserved and is never a `StreamId`.
///
/// Draft §4 / TN §2.5: "0xFF must never be sent and must be ignored upon receipt".
/// Held inverted (0xFF becomes 0), so that `Option<StreamId>` is one byte with `None` where
/// 0xFF would be.
#[derive(Clone, Copy, PartialEq, Eq, Hash)]
pub struct StreamId(NonZeroU8);

impl StreamId {
    /// The lowest stream ID, 0.
    pub const MIN: StreamId = StreamId(NonZeroU8::MAX);
    /// The highest stream ID, 254.
    pub const MAX: StreamId = StreamId(NonZeroU8::MIN);
    /// The reserved raw value, used on the wire only as "no DID proposed" (wire-spec §10 C-17).
    pub const RESERVED: u8 = 0xFF;

    /// A stream ID, or `None` for the reserved 0xFF.
    pub const fn new(raw: u8) -> Option<Self> {
        match NonZeroU8::new(!raw) {
            Some(inverted) => Some(StreamId(inverted)),
            None => None,
        }
    }

    /// The raw byte.
    pub const fn as_raw(self) -> u8 {
        !self.0.get()
    }

    /// The next ID in the rotation 0, 1, .., 254, 0, ..
    pub const fn next(self) -> Self {
        match StreamId::new(self.as_raw().wrapping_add(1)) {
            Some(next) => next,
            None => StreamId::MIN,
        }
    }
}

impl PartialOrd for StreamId {
    fn partial_cmp(&self, other: &Self) -> Option<core::cmp::Ordering> {
        Some(self.cmp(other))
    }
}

impl Ord for StreamId {
    fn cmp(&self, other: &Self) -> core::cmp::Ordering {
        self.as_raw().cmp(&other.as_raw())
    }
}

impl fmt::Debug for StreamId {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "StreamId(0x{:02X})", self.as_raw())
    }
}

impl fmt::Display for StreamId {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "0x{:02X}", self.as_raw())
    }
}

/// A 6-byte Stream Content UID (draft §4): names what a stream carries. Never all zero.
/// Held as its 48-bit big-endian value, so that `Option<ContentUid>` is as small as one.
#[derive(Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub struct ContentUid(NonZeroU64);

impl ContentUid {
    /// A content UID, or `None` if all six bytes are zero.
    pub const fn new(bytes: [u8; 6]) -> Option<Self> {
        match NonZeroU64::new(NodeId::from_bytes(bytes).as_raw()) {
            Some(value) => Some(ContentUid(value)),
            None => None,
        }
    }

    /// The six bytes.
    pub const fn to_bytes(self) -> [u8; 6] {
        NodeId::held(self.0.get()).to_bytes()
    }
}

impl fmt::Debug for ContentUid {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "ContentUid({})", NodeId::held(self.0.get()))
    }
}

impl fmt::Display for ContentUid {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        fmt::Display::fmt(&NodeId::held(self.0.get()), f)
    }
}

impl FromStr for ContentUid {
    type Err = ParseNodeIdError;

    /// Same text forms as [`NodeId`]; all zero is refused.
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        let id: NodeId = s.parse()?;
        ContentUid::new(id.to_bytes()).ok_or(ParseNodeIdError::Format)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn event_ids_in_every_pasted_form_parse_alike() {
        let dotted: EventId = "05.01.01.01.22.00.00.01".parse().unwrap();
        assert_eq!(dotted, EventId(0x0501_0101_2200_0001));
        for form in ["05:01:01:01:22:00:00:01", "0501010122000001", "0x0501010122000001", "5.1.1.1.22.0.0.1"] {
            assert_eq!(form.parse::<EventId>().unwrap(), dotted, "{form}");
        }
        assert_eq!(dotted.to_string(), "05.01.01.01.22.00.00.01");
        assert_eq!(EventId::from_slice(&dotted.to_bytes()), Some(dotted));
        for bad in ["05.01.01.01.22.00.00", "05.01.01.01.22.00.00.01.02", "0x05010101220000011", "", "05..01"] {
            assert_eq!(bad.parse::<EventId>(), Err(ParseEventIdError::Format), "{bad}");
        }
        assert_eq!(EventId::from_slice(&[1, 2, 3]), None);
    }

    #[test]
    fn node_id_bytes_round_trip() {
        let id = NodeId::from_bytes([0x05, 0x01, 0x01, 0x01, 0x22, 0x00]);
        assert_eq!(id.as_raw(), 0x0501_0101_2200);
        assert_eq!(id.to_bytes(), [0x05, 0x01, 0x01, 0x01, 0x22, 0x00]);
        assert_eq!(NodeId::from_slice(&[1, 2, 3, 4, 5]), None);
        assert_eq!(NodeId::new(0x1_0000_0000_0000), None);
    }

    #[test]
    fn node_ids_keep_their_value_order_and_an_optional_one_is_as_small() {
        assert_eq!(core::mem::size_of::<Option<NodeId>>(), core::mem::size_of::<NodeId>());
        let ids = [0, 1, 0x0501_0101_2200, 0xFFFF_FFFF_FFFF].map(|raw| NodeId::new(raw).unwrap());
        assert_eq!(ids.map(NodeId::as_raw), [0, 1, 0x0501_0101_2200, 0xFFFF_FFFF_FFFF]);
        assert!(ids.windows(2).all(|pair| pair[0] < pair[1]), "{ids:?}");
        assert_eq!(NodeId::default().as_raw(), 0);
        assert_eq!(NodeId::MAX, ids[3]);
        assert_eq!(NodeId::from_bytes([0; 6]), NodeId::default());
        assert_eq!(ids[3].to_bytes(), [0xFF; 6]);
    }

    #[test]
    fn node_id_text_forms() {
        let id = NodeId::new(0x0501_0101_2200).unwrap();
        assert_eq!(id.to_string(), "05.01.01.01.22.00");
        assert_eq!("05.01.01.01.22.00".parse::<NodeId>(), Ok(id));
        assert_eq!("5.1.1.1.22.0".parse::<NodeId>(), Ok(id));
        assert_eq!("050101012200".parse::<NodeId>(), Ok(id));
        assert_eq!("0x050101012200".parse::<NodeId>(), Ok(id));
        for bad in ["", "05.01.01.01.22", "05.01.01.01.22.00.00", "05.01.01.01.22.100", "zz", "1234567890123"] {
            assert!(bad.parse::<NodeId>().is_err(), "{bad:?} parsed");
        }
    }

    #[test]
    fn stream_id_reserves_ff_and_rotates() {
        assert_eq!(StreamId::new(0xFF), None);
        assert_eq!(StreamId::new(0xFE).unwrap().next(), StreamId::new(0).unwrap());
        assert_eq!(StreamId::new(7).unwrap().next().as_raw(), 8);
    }

    #[test]
    fn content_uid_is_never_zero() {
        assert_eq!(ContentUid::new([0; 6]), None);
        let uid = ContentUid::new([5, 1, 1, 1, 0x22, 0xFF]).unwrap();
        assert_eq!(uid.to_string(), "05.01.01.01.22.FF");
        assert_eq!("05.01.01.01.22.FF".parse::<ContentUid>(), Ok(uid));
        assert!("00.00.00.00.00.00".parse::<ContentUid>().is_err());
    }
}
