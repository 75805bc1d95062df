//! Outgoing messages split into frames: [`Fragments`] (wire-spec §7.2, §7.3).
//!
//! - global messages: format 1, the payload in the data bytes (at most 8);
//! - a Producer/Consumer Event Report with payload (more than 8 bytes): format 1 frames of
//!   8 bytes with the CAN-MTIs 0xF16 (first: the Event ID), 0xF15 (middle) and 0xF14 (last);
//! - addressed messages: format 1, data bytes 0-1 = framing flags + destination alias, then at
//!   most 6 payload bytes a frame; an empty payload is one 2-byte frame;
//! - Stream Data Send: format 7 with the destination alias in the header, data byte 0 = DID,
//!   then at most 7 payload bytes a frame; a DID alone is one 1-byte frame (a flush);
//! - Datagram (node-protocols §2.5): both aliases in the header, no `fddd`, 8 payload bytes a
//!   frame: 0-8 bytes as one format 2 frame, more as format 3 (first), 4 (middle, never
//!   empty), 5 (last); at most 72 bytes.

use openlcb_stream::Mti;

use crate::NodeAlias;
use crate::frame::CanFrame;
use crate::header::{CanHeader, DatagramFrame, FrameKind};
use crate::reassembly::MAX_DATAGRAM_LEN;

/// Payload bytes of an addressed format 1 frame.
pub const ADDRESSED_PAYLOAD_PER_FRAME: usize = 6;
/// Payload bytes of a stream data frame, after the DID.
pub const STREAM_PAYLOAD_PER_FRAME: usize = 7;
/// Payload bytes of a datagram frame.
pub const DATAGRAM_PAYLOAD_PER_FRAME: usize = CanFrame::MAX_DATA;

/// The CAN-MTIs of the frames of a Producer/Consumer Event Report with payload (CAN Frame
/// Transfer; events.md): first, middle and last.
pub mod event_report {
    use super::FramePosition;

    /// The first frame: the Event ID.
    pub const FIRST: u16 = 0xF16;
    /// A middle frame: 8 payload bytes.
    pub const MIDDLE: u16 = 0xF15;
    /// The last frame: 1 to 8 payload bytes.
    pub const LAST: u16 = 0xF14;

    /// The CAN-MTI of the frame at `position`.
    pub const fn can_mti(position: FramePosition) -> u16 {
        match position {
            FramePosition::Only | FramePosition::First => FIRST,
            FramePosition::Middle => MIDDLE,
            FramePosition::Last => LAST,
        }
    }

    /// Where a frame with `can_mti` sits in its report, if it is one of these frames.
    pub const fn position(can_mti: u16) -> Option<FramePosition> {
        match can_mti {
            FIRST => Some(FramePosition::First),
            MIDDLE => Some(FramePosition::Middle),
            LAST => Some(FramePosition::Last),
            _ => None,
        }
    }
}

/// Framing flags in data byte 0 of an addressed frame (wire-spec §7.2, active low).
mod framing {
    /// More frames follow.
    pub(crate) const NOT_LAST: u8 = 0x10;
    /// Frames came before.
    pub(crate) const NOT_FIRST: u8 = 0x20;
    /// Both flag bits.
    pub(crate) const MASK: u8 = 0x30;
}

/// Where a frame of an addressed message sits in its message (data byte 0, bits 5-4).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum FramePosition {
    /// `00`: the whole message.
    Only,
    /// `01`: the first of several.
    First,
    /// `11`: neither first nor last.
    Middle,
    /// `10`: the last of several.
    Last,
}

impl FramePosition {
    /// The position named by data byte 0 of an addressed frame.
    pub const fn from_flags(byte0: u8) -> Self {
        match byte0 & framing::MASK {
            0 => FramePosition::Only,
            framing::NOT_LAST => FramePosition::First,
            framing::NOT_FIRST => FramePosition::Last,
            _ => FramePosition::Middle,
        }
    }

    /// The frame ends its message (`Only` or `Last`).
    pub const fn is_last(self) -> bool {
        matches!(self, FramePosition::Only | FramePosition::Last)
    }

    /// The flag bits for data byte 0.
    pub const fn flags(self) -> u8 {
        match self {
            FramePosition::Only => 0,
            FramePosition::First => framing::NOT_LAST,
            FramePosition::Middle => framing::NOT_LAST | framing::NOT_FIRST,
            FramePosition::Last => framing::NOT_FIRST,
        }
    }
}

/// Why a message cannot be put on CAN.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
pub enum EncodeError {
    /// An addressed MTI (or Stream Data Send) without a destination alias.
    #[error("{0:?} needs a destination")]
    MissingDestination(Mti),
    /// A Stream Data Send without even the DID byte.
    #[error("Stream Data Send without a DID")]
    EmptyStreamData,
    /// A global message of more than 8 bytes (this crate does not split global messages).
    #[error("global message of {0} bytes does not fit one frame")]
    GlobalTooLong(usize),
    /// A datagram of more than 72 bytes (DG §7.3.2).
    #[error("datagram of {0} bytes is longer than 72")]
    DatagramTooLong(usize),
    /// An MTI that format 1 cannot carry (bits 15-12 set) other than Stream Data Send and
    /// Datagram.
    #[error("{0:?} has no CAN form here")]
    Unsupported(Mti),
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Layout {
    Global,
    /// The identifier held is the first frame's; the others differ only in the CAN-MTI.
    EventReport,
    Addressed {
        destination: NodeAlias,
    },
    StreamData,
    /// The identifier held is the only frame's (format 2); formats 3-5 follow the position.
    Datagram,
}

/// An iterator over the frames of one message. Holds the payload (any `AsRef<[u8]>`, e.g. the
/// core's `Vec<u8>` payload) and an offset: no copy of the payload, no allocation.
#[derive(Debug, Clone)]
pub struct Fragments<P> {
    cursor: Cursor,
    payload: P,
}

/// Where a [`Fragments`] stands, apart from its payload: the framing code is the same for
/// every payload type.
#[derive(Debug, Clone, Copy)]
#[repr(C)] // Fields in the order written: short Thumb loads reach the ones read first.
pub(crate) struct Cursor {
    layout: Layout,
    finished: bool,
    id: u32,
    offset: usize,
}

impl<P: AsRef<[u8]>> Fragments<P> {
    /// The frames of `mti` from `source` to `destination` (`None` for a global message)
    /// carrying `payload`. For Stream Data Send the payload starts with the DID.
    pub fn new(mti: Mti, source: NodeAlias, destination: Option<NodeAlias>, payload: P) -> Result<Self, EncodeError> {
        let cursor = Cursor::new(mti, source, destination, payload.as_ref().len())?;
        Ok(Fragments { cursor, payload })
    }

    /// Frames still to come.
    pub fn remaining(&self) -> usize {
        self.cursor.remaining(self.payload.as_ref().len())
    }

    /// A frame is still to come (`remaining() > 0`, without counting them).
    pub(crate) fn has_more(&self) -> bool {
        !self.cursor.finished
    }

    /// Frames are still to come, and no other message's frame may go between them: all but
    /// stream data, whose frames stand alone (each names its stream).
    // Out of line: the one copy of the test `poll_transmit` makes for each message it frames.
    #[inline(never)]
    pub(crate) fn is_inside(&self) -> bool {
        self.has_more() && !matches!(self.cursor.layout, Layout::StreamData)
    }
}

impl<P: AsRef<[u8]>> Iterator for Fragments<P> {
    type Item = CanFrame;

    fn next(&mut self) -> Option<CanFrame> {
        self.cursor.next_frame(self.payload.as_ref())
    }

    fn size_hint(&self) -> (usize, Option<usize>) {
        let n = self.remaining();
        (n, Some(n))
    }
}

impl Cursor {
    /// The start of the frames of `mti` carrying `len` payload bytes, or why it has no CAN form.
    pub(crate) fn new(
        mti: Mti,
        source: NodeAlias,
        destination: Option<NodeAlias>,
        len: usize,
    ) -> Result<Self, EncodeError> {
        let (kind, layout) = if mti == Mti::STREAM_DATA_SEND {
            let destination = destination.ok_or(EncodeError::MissingDestination(mti))?;
            if len == 0 {
                return Err(EncodeError::EmptyStreamData);
            }
            (FrameKind::StreamData { destination }, Layout::StreamData)
        } else if mti == Mti::DATAGRAM {
            let destination = destination.ok_or(EncodeError::MissingDestination(mti))?;
            if len > MAX_DATAGRAM_LEN {
                return Err(EncodeError::DatagramTooLong(len));
            }
            // The identifier changes frame by frame (formats 2-5): see `next_frame`.
            (FrameKind::Datagram { frame: DatagramFrame::Only, destination }, Layout::Datagram)
        } else if mti == Mti::PRODUCER_CONSUMER_EVENT_REPORT && len > CanFrame::MAX_DATA {
            // The identifier changes frame by frame: see `next_frame`.
            (FrameKind::Message { can_mti: event_report::FIRST }, Layout::EventReport)
        } else if mti.as_raw() & 0xF000 != 0 {
            return Err(EncodeError::Unsupported(mti));
        } else if mti.is_addressed() {
            let destination = destination.ok_or(EncodeError::MissingDestination(mti))?;
            (FrameKind::Message { can_mti: mti.as_raw() }, Layout::Addressed { destination })
        } else {
            if len > CanFrame::MAX_DATA {
                return Err(EncodeError::GlobalTooLong(len));
            }
            (FrameKind::Message { can_mti: mti.as_raw() }, Layout::Global)
        };
        let id = CanHeader { kind, source }.to_id();
        Ok(Cursor { id, layout, offset: 0, finished: false })
    }

    /// Frames still to come of a payload of `len` bytes.
    fn remaining(&self, len: usize) -> usize {
        if self.finished {
            return 0;
        }
        match self.layout {
            Layout::Global => 1,
            Layout::Addressed { .. } => len.saturating_sub(self.offset).div_ceil(ADDRESSED_PAYLOAD_PER_FRAME).max(1),
            Layout::StreamData => {
                let body_left = len.saturating_sub(1).saturating_sub(self.offset);
                body_left.div_ceil(STREAM_PAYLOAD_PER_FRAME).max(1)
            }
            Layout::Datagram | Layout::EventReport => {
                len.saturating_sub(self.offset).div_ceil(DATAGRAM_PAYLOAD_PER_FRAME).max(1)
            }
        }
    }

    /// The next frame of `payload` (the same payload every call), if any is left.
    pub(crate) fn next_frame(&mut self, payload: &[u8]) -> Option<CanFrame> {
        if self.finished {
            return None;
        }
        let (per_frame, body) = match self.layout {
            Layout::Global | Layout::EventReport => (CanFrame::MAX_DATA, payload),
            Layout::Addressed { .. } => (ADDRESSED_PAYLOAD_PER_FRAME, payload),
            // The DID goes in every frame; the offset counts the bytes after it.
            Layout::StreamData => (STREAM_PAYLOAD_PER_FRAME, payload.get(1..).unwrap_or(&[])),
            Layout::Datagram => (DATAGRAM_PAYLOAD_PER_FRAME, payload),
        };
        let (chunk, position) = next_chunk(body, &mut self.offset, per_frame);
        self.finished = position.is_last();
        // Data bytes before the payload chunk: framing flags and destination, or the DID.
        let mut head = [0u8; 2];
        let (id, head_len) = match self.layout {
            Layout::Global => (self.id, 0),
            Layout::EventReport => {
                let below_first = u32::from(event_report::FIRST - event_report::can_mti(position));
                (self.id.wrapping_sub(below_first << 12), 0)
            }
            Layout::Addressed { destination } => {
                let [high, low] = destination.as_raw().to_be_bytes();
                head = [position.flags() | (high & 0x0F), low];
                (self.id, 2)
            }
            Layout::StreamData => {
                head[0] = payload.first().copied().unwrap_or(0);
                (self.id, 1)
            }
            Layout::Datagram => {
                // Formats 2 to 5 in the order of `DatagramFrame` (bits 26-24).
                let above_only = DatagramFrame::at(position) as u32;
                (self.id + (above_only << 24), 0)
            }
        };
        Some(CanFrame::build(id, head.get(..head_len).unwrap_or(&[]), chunk))
    }
}

/// The next chunk of at most `per_frame` bytes of `payload` from `offset` (moved past it),
/// and where its frame sits in the message. An empty payload is one `Only` frame.
fn next_chunk<'p>(payload: &'p [u8], offset: &mut usize, per_frame: usize) -> (&'p [u8], FramePosition) {
    let rest = payload.get(*offset..).unwrap_or(&[]);
    let chunk = rest.get(..per_frame).unwrap_or(rest);
    let first = *offset == 0;
    *offset = offset.saturating_add(chunk.len());
    let last = *offset >= payload.len();
    let position = match (first, last) {
        (true, true) => FramePosition::Only,
        (true, false) => FramePosition::First,
        (false, true) => FramePosition::Last,
        (false, false) => FramePosition::Middle,
    };
    (chunk, position)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn alias(raw: u16) -> NodeAlias {
        NodeAlias::new(raw).unwrap()
    }

    fn frames(mti: Mti, src: u16, dst: Option<u16>, payload: &[u8]) -> Vec<(u32, Vec<u8>)> {
        let it = Fragments::new(mti, alias(src), dst.map(alias), payload).unwrap();
        let hint = it.size_hint().0;
        let out: Vec<_> = it.map(|f| (f.raw_id(), f.payload().to_vec())).collect();
        assert_eq!(out.len(), hint, "size_hint");
        out
    }

    #[test]
    fn position_flags_round_trip() {
        for p in [FramePosition::Only, FramePosition::First, FramePosition::Middle, FramePosition::Last] {
            assert_eq!(FramePosition::from_flags(p.flags() | 0x0F), p);
        }
        assert_eq!(FramePosition::from_flags(0x14), FramePosition::First);
        assert_eq!(FramePosition::from_flags(0x24), FramePosition::Last);
    }

    #[test]
    fn addressed_message_without_payload_is_one_two_byte_frame() {
        assert_eq!(frames(Mti::VERIFY_NODE_ID_ADDRESSED, 0x123, Some(0x456), &[]), [(0x1948_8123, vec![0x04, 0x56])]);
    }

    #[test]
    fn addressed_message_of_exactly_six_bytes_is_one_frame() {
        let out = frames(Mti::STREAM_INITIATE_REPLY, 0x456, Some(0x123), &[0, 0x10, 0x80, 0, 4, 7]);
        assert_eq!(out, [(0x1986_8456, vec![0x01, 0x23, 0, 0x10, 0x80, 0, 4, 7])]);
    }

    #[test]
    fn addressed_message_of_thirteen_bytes_is_first_middle_last() {
        let payload: Vec<u8> = (1..=13).collect();
        let out = frames(Mti::STREAM_INITIATE_REQUEST, 0x123, Some(0xFED), &payload);
        assert_eq!(
            out,
            [
                (0x19CC_8123, vec![0x1F, 0xED, 1, 2, 3, 4, 5, 6]),
                (0x19CC_8123, vec![0x3F, 0xED, 7, 8, 9, 10, 11, 12]),
                (0x19CC_8123, vec![0x2F, 0xED, 13]),
            ]
        );
    }

    #[test]
    fn stream_data_takes_seven_bytes_a_frame() {
        let payload: Vec<u8> = core::iter::once(7).chain(0..16).collect();
        let out = frames(Mti::STREAM_DATA_SEND, 0x123, Some(0x456), &payload);
        assert_eq!(
            out,
            [
                (0x1F45_6123, vec![7, 0, 1, 2, 3, 4, 5, 6]),
                (0x1F45_6123, vec![7, 7, 8, 9, 10, 11, 12, 13]),
                (0x1F45_6123, vec![7, 14, 15]),
            ]
        );
        let exact: Vec<u8> = core::iter::once(7).chain(0..7).collect();
        assert_eq!(frames(Mti::STREAM_DATA_SEND, 0x123, Some(0x456), &exact).len(), 1);
    }

    #[test]
    fn stream_flush_is_a_did_only_frame() {
        assert_eq!(frames(Mti::STREAM_DATA_SEND, 0x123, Some(0x456), &[7]), [(0x1F45_6123, vec![7])]);
    }

    #[test]
    fn datagram_of_up_to_eight_bytes_is_one_format_2_frame() {
        assert_eq!(frames(Mti::DATAGRAM, 0x123, Some(0x456), &[]), [(0x1A45_6123, vec![])]);
        let eight: Vec<u8> = (1..=8).collect();
        assert_eq!(frames(Mti::DATAGRAM, 0x123, Some(0x456), &eight), [(0x1A45_6123, eight)]);
    }

    /// node-protocols §9.1: the 14-byte write, `:X1B456123N2001000000000102;` then
    /// `:X1D456123N030405060708;`.
    #[test]
    fn datagram_of_fourteen_bytes_is_first_and_last() {
        let payload = [0x20, 0x01, 0, 0, 0, 0, 1, 2, 3, 4, 5, 6, 7, 8];
        assert_eq!(
            frames(Mti::DATAGRAM, 0x123, Some(0x456), &payload),
            [(0x1B45_6123, payload[..8].to_vec()), (0x1D45_6123, payload[8..].to_vec())]
        );
    }

    #[test]
    fn datagram_of_72_bytes_is_first_seven_middles_last() {
        let payload: Vec<u8> = (0..72).collect();
        let out = frames(Mti::DATAGRAM, 0x123, Some(0x456), &payload);
        let ids: Vec<u32> = out.iter().map(|f| f.0).collect();
        assert_eq!(
            ids,
            [
                0x1B45_6123,
                0x1C45_6123,
                0x1C45_6123,
                0x1C45_6123,
                0x1C45_6123,
                0x1C45_6123,
                0x1C45_6123,
                0x1C45_6123,
                0x1D45_6123
            ]
        );
        assert!(out.iter().all(|f| f.1.len() == 8), "every frame full, no middle empty");
        assert_eq!(out.iter().flat_map(|f| f.1.clone()).collect::<Vec<u8>>(), payload);
        // Nine bytes: eight, then one in the last frame.
        let nine = frames(Mti::DATAGRAM, 0x123, Some(0x456), &[7; 9]);
        assert_eq!(nine, [(0x1B45_6123, vec![7; 8]), (0x1D45_6123, vec![7])]);
    }

    #[test]
    fn global_message_carries_the_payload_in_the_data() {
        let node = [5, 1, 1, 1, 0x22, 0];
        assert_eq!(frames(Mti::INITIALIZATION_COMPLETE, 0x123, None, &node), [(0x1910_0123, node.to_vec())]);
    }

    #[test]
    fn event_report_with_payload_is_first_middle_last() {
        let mut payload = vec![5, 1, 1, 1, 0x22, 0, 0, 1];
        payload.extend(1..=12);
        assert_eq!(
            frames(Mti::PRODUCER_CONSUMER_EVENT_REPORT, 0x123, None, &payload),
            [
                (0x19F1_6123, vec![5, 1, 1, 1, 0x22, 0, 0, 1]),
                (0x19F1_5123, (1..=8).collect()),
                (0x19F1_4123, vec![9, 10, 11, 12]),
            ]
        );
        // Four bytes of payload: first and last.
        let short = frames(Mti::PRODUCER_CONSUMER_EVENT_REPORT, 0x123, None, &payload[..12]);
        assert_eq!(short.iter().map(|f| f.0).collect::<Vec<_>>(), [0x19F1_6123, 0x19F1_4123]);
        // A plain report stays one frame.
        assert_eq!(frames(Mti::PRODUCER_CONSUMER_EVENT_REPORT, 0x123, None, &payload[..8])[0].0, 0x195B_4123);
    }

    #[test]
    fn refuses_what_it_cannot_carry() {
        let a = alias(0x123);
        let err = |mti, dst, payload: &[u8]| Fragments::new(mti, a, dst, payload).err();
        assert_eq!(err(Mti::STREAM_DATA_SEND, Some(a), &[]), Some(EncodeError::EmptyStreamData));
        assert_eq!(
            err(Mti::STREAM_DATA_SEND, None, &[1]),
            Some(EncodeError::MissingDestination(Mti::STREAM_DATA_SEND))
        );
        assert_eq!(
            err(Mti::STREAM_DATA_PROCEED, None, &[1, 2]),
            Some(EncodeError::MissingDestination(Mti::STREAM_DATA_PROCEED))
        );
        assert_eq!(err(Mti::DATAGRAM, Some(a), &[0; 73]), Some(EncodeError::DatagramTooLong(73)));
        assert_eq!(err(Mti::DATAGRAM, None, &[1]), Some(EncodeError::MissingDestination(Mti::DATAGRAM)));
        assert_eq!(err(Mti(0x1C68), Some(a), &[1]), Some(EncodeError::Unsupported(Mti(0x1C68))));
        assert_eq!(err(Mti::VERIFY_NODE_ID_GLOBAL, None, &[0; 9]), Some(EncodeError::GlobalTooLong(9)));
    }
}
