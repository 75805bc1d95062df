//! Stream Data Complete (0x08A8): four encodings in the wild, told apart by length.

use super::{BufferTooSmall, DecodeError, Emit, byte, need, put, stream_id};
use crate::{Mti, StreamId};

/// The byte count a Complete carries (wire-spec §4.5, C-8, C-10).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum CompleteCount {
    /// No count: forms A (2 bytes) and C (4 bytes), or form B with 0xFFFFFFFF.
    Unknown,
    /// Form B (6 bytes): the total payload bytes as a uint32 (modulo 2^32). 0 means 0 bytes.
    Total(u32),
    /// Form D (7 bytes, 2026 draft table): the total modulo 2^24.
    Modulo24(u32),
}

impl CompleteCount {
    /// The count as sent, if any.
    pub fn stated(self) -> Option<u32> {
        match self {
            CompleteCount::Unknown => None,
            CompleteCount::Total(n) | CompleteCount::Modulo24(n) => Some(n),
        }
    }

    /// How many more bytes must arrive after `received` for the count to match, or `None`
    /// for an unknown count. Counts are modular, so the answer is `(count - received) mod 2^k`.
    pub fn missing_after(self, received: u64) -> Option<u64> {
        match self {
            CompleteCount::Unknown => None,
            CompleteCount::Total(total) => Some(u64::from(total.wrapping_sub(received as u32))),
            CompleteCount::Modulo24(total) => Some(u64::from(total.wrapping_sub(received as u32) & 0x00FF_FFFF)),
        }
    }
}

/// Stream Data Complete, source to destination (draft §5.5, wire-spec §4.5).
///
/// Decoded by length: 2 = no count, 4 = flags only, 6 = uint32 count (0xFFFFFFFF unknown),
/// 7+ = uint24 count at bytes 4-6, 3 or 5 = malformed tail, IDs kept, no count.
/// Emitted as form B (6 bytes, `SID DID COUNT(4)`): the form OpenMRN and the conformance
/// checker use; it fits one CAN frame and lets the destination wait for data still in flight.
/// A value parsed from another form re-emits in its own form: [`CompleteCount::Unknown`] as
/// form A (2 bytes), [`CompleteCount::Modulo24`] as form D (7 bytes). The endpoint always
/// sends form B.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct DataComplete {
    /// The source's stream ID.
    pub source_stream: StreamId,
    /// The destination's stream ID.
    pub destination_stream: StreamId,
    /// The total bytes sent, if the source said.
    pub count: CompleteCount,
}

impl DataComplete {
    const MTI: Mti = Mti::STREAM_DATA_COMPLETE;

    /// Parses any of the four forms; either ID 0xFF is refused.
    pub fn parse(payload: &[u8]) -> Result<Self, DecodeError> {
        need(Self::MTI, payload, 2)?;
        let count = match payload.len() {
            6 => match u32::from_be_bytes([byte(payload, 2), byte(payload, 3), byte(payload, 4), byte(payload, 5)]) {
                u32::MAX => CompleteCount::Unknown,
                total => CompleteCount::Total(total),
            },
            n if n >= 7 => {
                CompleteCount::Modulo24(u32::from_be_bytes([0, byte(payload, 4), byte(payload, 5), byte(payload, 6)]))
            }
            _ => CompleteCount::Unknown,
        };
        Ok(DataComplete {
            source_stream: stream_id(Self::MTI, byte(payload, 0), "SID")?,
            destination_stream: stream_id(Self::MTI, byte(payload, 1), "DID")?,
            count,
        })
    }
}

impl Emit for DataComplete {
    /// 2, 6 or 7 by the count's form.
    fn buffer_len(&self) -> usize {
        match self.count {
            CompleteCount::Unknown => 2,
            CompleteCount::Total(_) => 6,
            CompleteCount::Modulo24(_) => 7,
        }
    }

    /// Writes form A, B or D.
    fn emit(&self, buf: &mut [u8]) -> Result<usize, BufferTooSmall> {
        let ids = [self.source_stream.as_raw(), self.destination_stream.as_raw()];
        match self.count {
            CompleteCount::Unknown => put(buf, &ids),
            CompleteCount::Total(n) => {
                let [c0, c1, c2, c3] = n.to_be_bytes();
                put(buf, &[ids[0], ids[1], c0, c1, c2, c3])
            }
            CompleteCount::Modulo24(n) => {
                let [_, c1, c2, c3] = n.to_be_bytes();
                put(buf, &[ids[0], ids[1], 0, 0, c1, c2, c3])
            }
        }
    }
}
