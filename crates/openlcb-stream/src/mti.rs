//! The 16-bit common-format Message Type Indicator, as an open type.

use core::fmt;

/// An MTI (MN §3.1.1). Unknown values keep their raw bits, print as hex and can be quoted
/// back in an Optional Interaction Rejected.
#[derive(Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub struct Mti(pub u16);

impl Mti {
    /// Initialization Complete (full protocol).
    pub const INITIALIZATION_COMPLETE: Mti = Mti(0x0100);
    /// Initialization Complete, simple node.
    pub const INITIALIZATION_COMPLETE_SIMPLE: Mti = Mti(0x0101);
    /// Verify Node ID, addressed.
    pub const VERIFY_NODE_ID_ADDRESSED: Mti = Mti(0x0488);
    /// Verify Node ID, global.
    pub const VERIFY_NODE_ID_GLOBAL: Mti = Mti(0x0490);
    /// Verified Node ID.
    pub const VERIFIED_NODE_ID: Mti = Mti(0x0170);
    /// Verified Node ID, simple node.
    pub const VERIFIED_NODE_ID_SIMPLE: Mti = Mti(0x0171);
    /// Optional Interaction Rejected.
    pub const OPTIONAL_INTERACTION_REJECTED: Mti = Mti(0x0068);
    /// Terminate Due To Error.
    pub const TERMINATE_DUE_TO_ERROR: Mti = Mti(0x00A8);
    /// Protocol Support Inquiry.
    pub const PROTOCOL_SUPPORT_INQUIRY: Mti = Mti(0x0828);
    /// Protocol Support Reply.
    pub const PROTOCOL_SUPPORT_REPLY: Mti = Mti(0x0668);
    /// Datagram (the whole message, full format).
    pub const DATAGRAM: Mti = Mti(0x1C48);
    /// Datagram Received OK.
    pub const DATAGRAM_RECEIVED_OK: Mti = Mti(0x0A28);
    /// Datagram Rejected.
    pub const DATAGRAM_REJECTED: Mti = Mti(0x0A48);
    /// Simple Node Information Request.
    pub const SIMPLE_NODE_INFO_REQUEST: Mti = Mti(0x0DE8);
    /// Simple Node Information Reply.
    pub const SIMPLE_NODE_INFO_REPLY: Mti = Mti(0x0A08);
    /// Stream Initiate Request.
    pub const STREAM_INITIATE_REQUEST: Mti = Mti(0x0CC8);
    /// Stream Initiate Reply.
    pub const STREAM_INITIATE_REPLY: Mti = Mti(0x0868);
    /// Stream Data Send.
    pub const STREAM_DATA_SEND: Mti = Mti(0x1F88);
    /// Stream Data Proceed.
    pub const STREAM_DATA_PROCEED: Mti = Mti(0x0888);
    /// Stream Data Complete.
    pub const STREAM_DATA_COMPLETE: Mti = Mti(0x08A8);

    /// Identify Consumer (Event ID).
    pub const IDENTIFY_CONSUMER: Mti = Mti(0x08F4);
    /// Consumer Range Identified (an Event ID whose low bits give the range).
    pub const CONSUMER_RANGE_IDENTIFIED: Mti = Mti(0x04A4);
    /// Consumer Identified, valid (the consumer's state matches this event).
    pub const CONSUMER_IDENTIFIED_VALID: Mti = Mti(0x04C4);
    /// Consumer Identified, invalid.
    pub const CONSUMER_IDENTIFIED_INVALID: Mti = Mti(0x04C5);
    /// Consumer Identified, reserved state.
    pub const CONSUMER_IDENTIFIED_RESERVED: Mti = Mti(0x04C6);
    /// Consumer Identified, state unknown.
    pub const CONSUMER_IDENTIFIED_UNKNOWN: Mti = Mti(0x04C7);
    /// Identify Producer (Event ID).
    pub const IDENTIFY_PRODUCER: Mti = Mti(0x0914);
    /// Producer Range Identified (an Event ID whose low bits give the range).
    pub const PRODUCER_RANGE_IDENTIFIED: Mti = Mti(0x0524);
    /// Producer Identified, valid (the producer's state matches this event).
    pub const PRODUCER_IDENTIFIED_VALID: Mti = Mti(0x0544);
    /// Producer Identified, invalid.
    pub const PRODUCER_IDENTIFIED_INVALID: Mti = Mti(0x0545);
    /// Producer Identified, reserved state.
    pub const PRODUCER_IDENTIFIED_RESERVED: Mti = Mti(0x0546);
    /// Producer Identified, state unknown.
    pub const PRODUCER_IDENTIFIED_UNKNOWN: Mti = Mti(0x0547);
    /// Identify Events, addressed.
    pub const IDENTIFY_EVENTS_ADDRESSED: Mti = Mti(0x0968);
    /// Identify Events, global.
    pub const IDENTIFY_EVENTS_GLOBAL: Mti = Mti(0x0970);
    /// Learn Event (Event ID).
    pub const LEARN_EVENT: Mti = Mti(0x0594);
    /// Producer/Consumer Event Report: an Event ID, and with more than 8 bytes a payload
    /// after it (on CAN the frames of CAN-MTIs 0xF16, 0xF15, 0xF14).
    pub const PRODUCER_CONSUMER_EVENT_REPORT: Mti = Mti(0x05B4);
    /// Traction Control Command (Train Control Standard §4.3), addressed.
    pub const TRACTION_CONTROL_COMMAND: Mti = Mti(0x05EB);
    /// Traction Control Reply (Train Control Standard §4.4), addressed.
    pub const TRACTION_CONTROL_REPLY: Mti = Mti(0x01E9);

    /// The raw value.
    pub const fn as_raw(self) -> u16 {
        self.0
    }

    /// A destination Node ID follows the source (bit 0x0008).
    pub const fn is_addressed(self) -> bool {
        self.0 & 0x0008 != 0
    }

    /// An Event ID begins the payload (bit 0x0004).
    pub const fn has_event(self) -> bool {
        self.0 & 0x0004 != 0
    }

    /// The data part of a stream or datagram (bit 0x1000): on CAN a frame format, not a CAN-MTI.
    pub const fn is_stream_or_datagram(self) -> bool {
        self.0 & 0x1000 != 0
    }

    /// Must not be forwarded through gateways (bit 0x2000).
    pub const fn is_special(self) -> bool {
        self.0 & 0x2000 != 0
    }

    /// The priority group, 0 (highest) to 3 (bits 11-10).
    pub const fn priority(self) -> u8 {
        ((self.0 >> 10) & 0x3) as u8
    }

    /// One of the five stream MTIs.
    pub const fn is_stream(self) -> bool {
        matches!(self.0, 0x0CC8 | 0x0868 | 0x1F88 | 0x0888 | 0x08A8)
    }

    /// A global message whose payload is the sender's own Node ID (Initialization Complete,
    /// Verified Node ID; MN §3.3.1-3.3.2): it teaches a transport the sender's address.
    pub const fn announces_sender(self) -> bool {
        matches!(self.0, 0x0100 | 0x0101 | 0x0170 | 0x0171)
    }

    /// A well-known name, or `None` for values this crate has no constant for.
    pub const fn name(self) -> Option<&'static str> {
        Some(match self.0 {
            0x0100 | 0x0101 => "Initialization Complete",
            0x0488 | 0x0490 => "Verify Node ID",
            0x0170 | 0x0171 => "Verified Node ID",
            0x0068 => "Optional Interaction Rejected",
            0x00A8 => "Terminate Due To Error",
            0x0828 => "Protocol Support Inquiry",
            0x0668 => "Protocol Support Reply",
            0x1C48 => "Datagram",
            0x0A28 => "Datagram Received OK",
            0x0A48 => "Datagram Rejected",
            0x0DE8 => "Simple Node Information Request",
            0x0A08 => "Simple Node Information Reply",
            0x0CC8 => "Stream Initiate Request",
            0x0868 => "Stream Initiate Reply",
            0x1F88 => "Stream Data Send",
            0x0888 => "Stream Data Proceed",
            0x08A8 => "Stream Data Complete",
            0x08F4 => "Identify Consumer",
            0x04A4 => "Consumer Range Identified",
            0x04C4 => "Consumer Identified Valid",
            0x04C5 => "Consumer Identified Invalid",
            0x04C6 => "Consumer Identified Reserved",
            0x04C7 => "Consumer Identified Unknown",
            0x0914 => "Identify Producer",
            0x0524 => "Producer Range Identified",
            0x0544 => "Producer Identified Valid",
            0x0545 => "Producer Identified Invalid",
            0x0546 => "Producer Identified Reserved",
            0x0547 => "Producer Identified Unknown",
            0x0968 | 0x0970 => "Identify Events",
            0x0594 => "Learn Event",
            0x05B4 => "Producer/Consumer Event Report",
            0x05EB => "Traction Control Command",
            0x01E9 => "Traction Control Reply",
            _ => return None,
        })
    }
}

impl fmt::Debug for Mti {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self.name() {
            Some(name) => write!(f, "Mti(0x{:04X} {name})", self.0),
            None => write!(f, "Mti(0x{:04X})", self.0),
        }
    }
}

impl fmt::Display for Mti {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "0x{:04X}", self.0)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bits_of_the_stream_mtis() {
        assert!(Mti::STREAM_DATA_SEND.is_addressed());
        assert!(Mti::STREAM_DATA_SEND.is_stream_or_datagram());
        assert!(!Mti::STREAM_DATA_PROCEED.is_stream_or_datagram());
        assert_eq!(Mti::STREAM_INITIATE_REQUEST.priority(), 3);
        assert_eq!(Mti::STREAM_DATA_COMPLETE.priority(), 2);
        assert!(!Mti::VERIFY_NODE_ID_GLOBAL.is_addressed());
        assert!(Mti(0x05B4).has_event());
        assert_eq!(format!("{:?}", Mti(0x1234)), "Mti(0x1234)");
        assert_eq!(format!("{:?}", Mti::STREAM_DATA_SEND), "Mti(0x1F88 Stream Data Send)");
    }
}
