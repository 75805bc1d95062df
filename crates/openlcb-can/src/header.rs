//! The 29-bit OpenLCB CAN identifier as a typed view: [`CanHeader`] (wire-spec §7.1, §7.4).
//!
//! ```text
//! bit 28     reserved: send 1, ignore on receipt
//! bit 27     1 = OpenLCB message, 0 = CAN control frame
//! bits 26-12 content: message = format (26-24) + CAN-MTI or destination alias (23-12)
//!                     control = CID sequence (26-24) + Node ID bits, or 0x0700.. (RID, AMD, ..)
//! bits 11-0  source alias
//! ```

use openlcb_stream::Mti;

use crate::NodeAlias;
use crate::fragment::FramePosition;

/// Bit masks and shifts of the identifier.
mod field {
    pub(super) const ID_MASK: u32 = 0x1FFF_FFFF;
    pub(super) const RESERVED_BIT: u32 = 0x1000_0000;
    pub(super) const MESSAGE_BIT: u32 = 0x0800_0000;
    pub(super) const FORMAT_SHIFT: u32 = 24;
    pub(super) const VARIABLE_SHIFT: u32 = 12;
    pub(super) const TWELVE_BITS: u32 = 0xFFF;
}

/// Control frame content values (bits 26-12) other than CID (CFT §6.1).
mod control {
    pub(super) const RESERVE_ID: u16 = 0x0700;
    pub(super) const ALIAS_MAP_DEFINITION: u16 = 0x0701;
    pub(super) const ALIAS_MAP_ENQUIRY: u16 = 0x0702;
    pub(super) const ALIAS_MAP_RESET: u16 = 0x0703;
    pub(super) const ERROR_REPORT_FIRST: u16 = 0x0710;
    pub(super) const ERROR_REPORT_LAST: u16 = 0x0713;
}

/// Which of the four datagram frame formats (wire-spec §7.6).
// In the order of their formats: `CanHeader::to_id` counts on it.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum DatagramFrame {
    /// Format 2: a whole datagram of at most 8 bytes.
    Only,
    /// Format 3: the first frame.
    First,
    /// Format 4: a middle frame.
    Middle,
    /// Format 5: the final frame.
    Final,
}

impl DatagramFrame {
    /// The datagram frame format for a frame at `position` in its datagram.
    pub const fn at(position: FramePosition) -> Self {
        match position {
            FramePosition::Only => DatagramFrame::Only,
            FramePosition::First => DatagramFrame::First,
            FramePosition::Middle => DatagramFrame::Middle,
            FramePosition::Last => DatagramFrame::Final,
        }
    }

    /// Where the frame sits in its datagram, as for the frames of an addressed message.
    pub const fn position(self) -> FramePosition {
        match self {
            DatagramFrame::Only => FramePosition::Only,
            DatagramFrame::First => FramePosition::First,
            DatagramFrame::Middle => FramePosition::Middle,
            DatagramFrame::Final => FramePosition::Last,
        }
    }
}

/// What a frame is, from its identifier.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
#[non_exhaustive]
pub enum FrameKind {
    /// Format 1: a global or addressed message. The MTI is the 12-bit CAN-MTI (MN §7.3.1.3:
    /// only MTIs with bits 15-12 clear travel in format 1); the address bit (0x008) says
    /// whether data bytes 0-1 carry framing flags and a destination alias.
    Message {
        /// The 12-bit CAN-MTI, equal to the full MTI.
        can_mti: u16,
    },
    /// Formats 2-5: a datagram frame.
    Datagram {
        /// Which frame of the datagram.
        frame: DatagramFrame,
        /// The addressed node.
        destination: NodeAlias,
    },
    /// Format 7: Stream Data Send, DID in data byte 0 (wire-spec §7.3).
    StreamData {
        /// The addressed node.
        destination: NodeAlias,
    },
    /// Format 0 or 6 (reserved): ignore.
    ReservedFormat {
        /// The format, 0 or 6.
        format: u8,
        /// Bits 23-12.
        field: u16,
    },
    /// Check ID, sequence 7..=4, carrying 12 bits of the sender's Node ID.
    CheckId {
        /// 7, 6, 5 or 4 (CID7 carries Node ID bits 47-36, CID4 bits 11-0).
        sequence: u8,
        /// The 12 Node ID bits.
        node_id_bits: u16,
    },
    /// Reserve ID (RID).
    ReserveId,
    /// Alias Map Definition (AMD), 6-byte Node ID in the data.
    AliasMapDefinition,
    /// Alias Mapping Enquiry (AME), no data or a 6-byte Node ID.
    AliasMapEnquiry,
    /// Alias Map Reset (AMR), 6-byte Node ID in the data.
    AliasMapReset,
    /// Error Information Report 0..=3 (informative only).
    ErrorInformationReport(u8),
    /// Any other control content (reserved: ignore on receipt).
    ReservedControl {
        /// Bits 26-12.
        content: u16,
    },
}

/// The typed view of a 29-bit OpenLCB identifier.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct CanHeader {
    /// What the frame is.
    pub kind: FrameKind,
    /// The sending node's alias.
    pub source: NodeAlias,
}

/// Why an identifier is not a valid OpenLCB header.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
pub enum HeaderError {
    /// Bits above 28 are set: not a 29-bit identifier.
    #[error("identifier 0x{0:08X} does not fit 29 bits")]
    TooWide(u32),
    /// The source alias is 0, which no node may hold.
    #[error("source alias 0")]
    ZeroSourceAlias,
    /// A datagram or stream frame addressed to alias 0.
    #[error("destination alias 0")]
    ZeroDestinationAlias,
}

impl CanHeader {
    /// A format 1 header for `mti` (its low 12 bits; the caller checks bits 15-12 are clear).
    pub const fn message(mti: Mti, source: NodeAlias) -> Self {
        CanHeader { kind: FrameKind::Message { can_mti: mti.as_raw() & 0xFFF }, source }
    }

    /// A control frame header.
    pub const fn control(kind: FrameKind, source: NodeAlias) -> Self {
        CanHeader { kind, source }
    }

    /// Reads a raw identifier. Bit 28 is ignored (CFT §4); reserved formats and control
    /// values are kept, not refused.
    pub fn parse(id: u32) -> Result<Self, HeaderError> {
        if id & !field::ID_MASK != 0 {
            return Err(HeaderError::TooWide(id));
        }
        let source = NodeAlias::from_low_bits(id).ok_or(HeaderError::ZeroSourceAlias)?;
        let format = ((id >> field::FORMAT_SHIFT) & 0x7) as u8;
        let variable = ((id >> field::VARIABLE_SHIFT) & field::TWELVE_BITS) as u16;
        let destination = || NodeAlias::new(variable).ok_or(HeaderError::ZeroDestinationAlias);
        let kind = if id & field::MESSAGE_BIT != 0 {
            match format {
                1 => FrameKind::Message { can_mti: variable },
                // One arm for the four datagram formats: one destination check (flash).
                2..=5 => {
                    let frame = match format {
                        2 => DatagramFrame::Only,
                        3 => DatagramFrame::First,
                        4 => DatagramFrame::Middle,
                        _ => DatagramFrame::Final,
                    };
                    FrameKind::Datagram { frame, destination: destination()? }
                }
                7 => FrameKind::StreamData { destination: destination()? },
                format => FrameKind::ReservedFormat { format, field: variable },
            }
        } else {
            match (format, variable) {
                (4..=7, node_id_bits) => FrameKind::CheckId { sequence: format, node_id_bits },
                (0, control::RESERVE_ID) => FrameKind::ReserveId,
                (0, control::ALIAS_MAP_DEFINITION) => FrameKind::AliasMapDefinition,
                (0, control::ALIAS_MAP_ENQUIRY) => FrameKind::AliasMapEnquiry,
                (0, control::ALIAS_MAP_RESET) => FrameKind::AliasMapReset,
                (0, n @ control::ERROR_REPORT_FIRST..=control::ERROR_REPORT_LAST) => {
                    FrameKind::ErrorInformationReport((n - control::ERROR_REPORT_FIRST) as u8)
                }
                (format, variable) => FrameKind::ReservedControl { content: u16::from(format) << 12 | variable },
            }
        };
        Ok(CanHeader { kind, source })
    }

    /// The raw 29-bit identifier, with bit 28 set.
    pub fn to_id(&self) -> u32 {
        let (message, format, variable) = match self.kind {
            FrameKind::Message { can_mti } => (true, 1, can_mti),
            // Formats 2 to 5, in the order of the variants.
            FrameKind::Datagram { frame, destination } => (true, 2 + frame as u8, destination.as_raw()),
            FrameKind::StreamData { destination } => (true, 7, destination.as_raw()),
            FrameKind::ReservedFormat { format, field } => (true, format, field),
            FrameKind::CheckId { sequence, node_id_bits } => (false, sequence, node_id_bits),
            FrameKind::ReserveId => (false, 0, control::RESERVE_ID),
            FrameKind::AliasMapDefinition => (false, 0, control::ALIAS_MAP_DEFINITION),
            FrameKind::AliasMapEnquiry => (false, 0, control::ALIAS_MAP_ENQUIRY),
            FrameKind::AliasMapReset => (false, 0, control::ALIAS_MAP_RESET),
            FrameKind::ErrorInformationReport(n) => {
                (false, 0, control::ERROR_REPORT_FIRST.saturating_add(u16::from(n & 0x3)))
            }
            FrameKind::ReservedControl { content } => (false, (content >> 12) as u8, content),
        };
        let message_bit = if message { field::MESSAGE_BIT } else { 0 };
        field::RESERVED_BIT
            | message_bit
            | (u32::from(format) & 0x7) << field::FORMAT_SHIFT
            | (u32::from(variable) & field::TWELVE_BITS) << field::VARIABLE_SHIFT
            | u32::from(self.source.as_raw())
    }

    /// An OpenLCB message frame (bit 27 set) rather than a control frame.
    pub fn is_message(&self) -> bool {
        matches!(
            self.kind,
            FrameKind::Message { .. }
                | FrameKind::Datagram { .. }
                | FrameKind::StreamData { .. }
                | FrameKind::ReservedFormat { .. }
        )
    }

    /// The CAN frame format 0..=7 of a message frame, `None` for a control frame.
    pub fn frame_format(&self) -> Option<u8> {
        self.is_message().then(|| ((self.to_id() >> field::FORMAT_SHIFT) & 0x7) as u8)
    }

    /// The full MTI a message frame stands for: the CAN-MTI for format 1, Datagram (0x1C48)
    /// for formats 2-5, Stream Data Send (0x1F88) for format 7 (wire-spec §7.1).
    pub fn mti(&self) -> Option<Mti> {
        match self.kind {
            FrameKind::Message { can_mti } => Some(Mti(can_mti)),
            FrameKind::Datagram { .. } => Some(Mti::DATAGRAM),
            FrameKind::StreamData { .. } => Some(Mti::STREAM_DATA_SEND),
            _ => None,
        }
    }

    /// The destination alias carried in the identifier (datagram and stream frames).
    pub fn destination(&self) -> Option<NodeAlias> {
        match self.kind {
            FrameKind::Datagram { destination, .. } | FrameKind::StreamData { destination } => Some(destination),
            _ => None,
        }
    }
}

/// The identifier `id` (of a frame of this crate's making) is a message frame's, not a control
/// frame's: [`CanHeader::is_message`] from the identifier's bit 27 alone, without parsing it.
pub(crate) fn is_message_id(id: u32) -> bool {
    id & field::MESSAGE_BIT != 0
}

#[cfg(test)]
mod tests {
    use super::*;

    fn alias(raw: u16) -> NodeAlias {
        NodeAlias::new(raw).unwrap()
    }

    #[test]
    fn parse_format_1() {
        let h = CanHeader::parse(0x19CC_822A).unwrap();
        assert_eq!(h, CanHeader { kind: FrameKind::Message { can_mti: 0xCC8 }, source: alias(0x22A) });
        assert_eq!(h.mti(), Some(Mti::STREAM_INITIATE_REQUEST));
        assert_eq!(h.frame_format(), Some(1));
        assert!(h.is_message());
        assert_eq!(h.destination(), None);
    }

    #[test]
    fn parse_stream_data_and_datagrams() {
        let h = CanHeader::parse(0x1F22_522A).unwrap();
        assert_eq!(h.kind, FrameKind::StreamData { destination: alias(0x225) });
        assert_eq!(h.mti(), Some(Mti::STREAM_DATA_SEND));
        assert_eq!(h.frame_format(), Some(7));
        let h = CanHeader::parse(0x1A45_6123).unwrap();
        assert_eq!(h.kind, FrameKind::Datagram { frame: DatagramFrame::Only, destination: alias(0x456) });
        assert_eq!(h.mti(), Some(Mti::DATAGRAM));
        assert_eq!(
            CanHeader::parse(0x1D45_6123).unwrap().kind,
            FrameKind::Datagram { frame: DatagramFrame::Final, destination: alias(0x456) }
        );
        assert_eq!(CanHeader::parse(0x1E45_6123).unwrap().kind, FrameKind::ReservedFormat { format: 6, field: 0x456 });
        assert_eq!(CanHeader::parse(0x1F00_0123), Err(HeaderError::ZeroDestinationAlias));
    }

    #[test]
    fn parse_control_frames() {
        let cases = [
            (0x1702_0555, FrameKind::CheckId { sequence: 7, node_id_bits: 0x020 }),
            (0x1400_3555, FrameKind::CheckId { sequence: 4, node_id_bits: 0x003 }),
            (0x1070_0555, FrameKind::ReserveId),
            (0x1070_1555, FrameKind::AliasMapDefinition),
            (0x1070_2555, FrameKind::AliasMapEnquiry),
            (0x1070_3555, FrameKind::AliasMapReset),
            (0x1071_2555, FrameKind::ErrorInformationReport(2)),
            (0x1070_4555, FrameKind::ReservedControl { content: 0x0704 }),
            (0x1212_3555, FrameKind::ReservedControl { content: 0x2123 }),
        ];
        for (id, kind) in cases {
            let h = CanHeader::parse(id).unwrap();
            assert_eq!(h.kind, kind, "{id:08X}");
            assert_eq!(h.source, alias(0x555));
            assert!(!h.is_message());
            assert!(!is_message_id(id));
            assert_eq!(h.frame_format(), None);
            assert_eq!(h.to_id(), id, "{id:08X} round trip");
        }
    }

    #[test]
    fn reserved_bit_is_ignored_on_receipt_and_set_on_send() {
        let h = CanHeader::parse(0x09CC_822A).unwrap();
        assert_eq!(h.kind, FrameKind::Message { can_mti: 0xCC8 });
        assert_eq!(h.to_id(), 0x19CC_822A);
    }

    #[test]
    fn refuses_wide_ids_and_alias_zero() {
        assert_eq!(CanHeader::parse(0x2000_0000), Err(HeaderError::TooWide(0x2000_0000)));
        assert_eq!(CanHeader::parse(0x19CC_8000), Err(HeaderError::ZeroSourceAlias));
    }

    #[test]
    fn every_message_header_round_trips() {
        for id in [0x19CC_822A, 0x1F45_6123, 0x1B45_6123, 0x1C45_6123, 0x1845_6123, 0x1910_0123] {
            assert_eq!(CanHeader::parse(id).unwrap().to_id(), id, "{id:08X}");
            assert!(is_message_id(id));
        }
        assert_eq!(CanHeader::message(Mti::STREAM_DATA_COMPLETE, alias(0x123)).to_id(), 0x198A_8123);
    }
}
