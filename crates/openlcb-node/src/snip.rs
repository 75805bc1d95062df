//! Simple Node Information (SNIP, node-protocols.md §5): the strings a node tells about
//! itself, their wire form, and the requests this node makes for other nodes' strings.

use alloc::boxed::Box;
use alloc::string::String;
use alloc::vec::Vec;
use core::fmt;

use openlcb_stream::wire::ErrorReport;
use openlcb_stream::{Instant, Message, MessageRef, Mti, NodeId};

use crate::node::{NodeEvent, Outputs, bump};
use crate::service::{Lent, Service, ServiceChange, earliest};

/// The most bytes a SNIP reply can carry (SNIP-TN §2.5.1).
pub const MAX_REPLY_LEN: usize = 253;

/// A field of [`SnipInfo`], with the standard's byte limit (SNIP §5.1, without the NUL).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum SnipField {
    /// Manufacturer name, at most 40 bytes.
    Manufacturer,
    /// Model name, at most 40 bytes.
    Model,
    /// Hardware version, at most 20 bytes.
    HardwareVersion,
    /// Software version, at most 20 bytes.
    SoftwareVersion,
    /// User-provided node name, at most 62 bytes.
    UserName,
    /// User-provided node description, at most 63 bytes.
    UserDescription,
}

impl SnipField {
    /// Every field, in wire order.
    pub const ALL: [SnipField; 6] = [
        SnipField::Manufacturer,
        SnipField::Model,
        SnipField::HardwareVersion,
        SnipField::SoftwareVersion,
        SnipField::UserName,
        SnipField::UserDescription,
    ];

    /// The longest value in bytes, without the terminating NUL.
    pub const fn max_len(self) -> usize {
        match self {
            SnipField::Manufacturer | SnipField::Model => 40,
            SnipField::HardwareVersion | SnipField::SoftwareVersion => 20,
            SnipField::UserName => 62,
            SnipField::UserDescription => 63,
        }
    }

    /// A name for messages.
    pub const fn name(self) -> &'static str {
        match self {
            SnipField::Manufacturer => "manufacturer",
            SnipField::Model => "model",
            SnipField::HardwareVersion => "hardware version",
            SnipField::SoftwareVersion => "software version",
            SnipField::UserName => "user name",
            SnipField::UserDescription => "user description",
        }
    }
}

/// A SNIP string longer than its field allows.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
#[error("the {} is {len} bytes long; SNIP allows at most {}", field.name(), field.max_len())]
pub struct SnipTooLong {
    /// The field.
    pub field: SnipField,
    /// Its length in bytes.
    pub len: usize,
}

/// The six strings of Simple Node Information.
///
/// The reply is built with the standard's version bytes (4 and 2) and each string cut at its
/// limit on a character boundary; [`SnipInfo::check`] tells the caller beforehand which string
/// is too long. [`SnipInfo::parse`] is liberal: any version byte (extra strings skipped, as the
/// version is the number of strings in its section), missing strings empty, over-long strings
/// kept, bytes that are not UTF-8 replaced.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct SnipInfo {
    /// Manufacturer name.
    pub manufacturer: String,
    /// Model name.
    pub model: String,
    /// Hardware version.
    pub hardware_version: String,
    /// Software version.
    pub software_version: String,
    /// User-provided node name.
    pub user_name: String,
    /// User-provided node description.
    pub user_description: String,
}

impl SnipInfo {
    /// The value of `field`.
    pub fn get(&self, field: SnipField) -> &str {
        match field {
            SnipField::Manufacturer => &self.manufacturer,
            SnipField::Model => &self.model,
            SnipField::HardwareVersion => &self.hardware_version,
            SnipField::SoftwareVersion => &self.software_version,
            SnipField::UserName => &self.user_name,
            SnipField::UserDescription => &self.user_description,
        }
    }

    fn get_mut(&mut self, field: SnipField) -> &mut String {
        match field {
            SnipField::Manufacturer => &mut self.manufacturer,
            SnipField::Model => &mut self.model,
            SnipField::HardwareVersion => &mut self.hardware_version,
            SnipField::SoftwareVersion => &mut self.software_version,
            SnipField::UserName => &mut self.user_name,
            SnipField::UserDescription => &mut self.user_description,
        }
    }

    /// The first string longer than its field allows (or that holds a NUL, which would end it
    /// early on the wire: its length is then where the NUL is).
    pub fn check(&self) -> Result<(), SnipTooLong> {
        for field in SnipField::ALL {
            let value = self.get(field);
            let len = value.find('\0').unwrap_or(value.len());
            if value.len() > field.max_len() || len < value.len() {
                return Err(SnipTooLong { field, len: value.len() });
            }
        }
        Ok(())
    }

    /// The reply payload (SNIP §5.1): `04`, four NUL-terminated strings, `02`, two more.
    pub fn to_payload(&self) -> Vec<u8> {
        let mut out = Vec::with_capacity(MAX_REPLY_LEN);
        for field in SnipField::ALL {
            match field {
                SnipField::Manufacturer => out.push(4),
                SnipField::UserName => out.push(2),
                _ => {}
            }
            // Up to a NUL inside the value (found byte by byte: no string search in flash),
            // then at most the field's length, cut at a character boundary.
            let value = self.get(field);
            let nul = value.bytes().position(|b| b == 0).unwrap_or(value.len());
            out.extend_from_slice(truncate(value, nul.min(field.max_len())).as_bytes());
            out.push(0);
        }
        out
    }

    /// Reads a reply payload (or several concatenated), liberally.
    pub fn parse(payload: &[u8]) -> SnipInfo {
        let mut info = SnipInfo::default();
        let mut rest = payload;
        let mut fields = SnipField::ALL.iter();
        for section_len in [4usize, 2] {
            let Some((&version, tail)) = rest.split_first() else { break };
            rest = tail;
            // Version 1 means the section's standard count (SNIP §5.2); higher versions carry
            // extra strings, which are skipped.
            let strings = if version <= 1 { section_len } else { usize::from(version) };
            for index in 0..strings {
                let (value, tail) = next_string(rest);
                rest = tail;
                if index < section_len
                    && let Some(field) = fields.next()
                {
                    *info.get_mut(*field) = lossy_string(value);
                }
            }
        }
        info
    }

    /// Whether `payload` holds both sections with all the strings their versions announce:
    /// how a reply sent as many one-frame messages (older nodes, SNIP-TN §2.6) is known to be
    /// whole.
    pub fn is_complete(payload: &[u8]) -> bool {
        let mut rest = payload;
        for section_len in [4usize, 2] {
            let Some((&version, tail)) = rest.split_first() else { return false };
            rest = tail;
            let strings = if version <= 1 { section_len } else { usize::from(version) };
            for _ in 0..strings {
                let Some(end) = rest.iter().position(|&b| b == 0) else { return false };
                rest = rest.get(end + 1..).unwrap_or(&[]);
            }
        }
        true
    }
}

impl fmt::Display for SnipInfo {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{} {} (hw {}, sw {})", self.manufacturer, self.model, self.hardware_version, self.software_version)?;
        if !self.user_name.is_empty() {
            write!(f, " \"{}\"", self.user_name)?;
        }
        if !self.user_description.is_empty() {
            write!(f, " {}", self.user_description)?;
        }
        Ok(())
    }
}

/// A reply kept for the node's lifetime, without the room `to_payload` made for the longest
/// one (253 bytes, where a board's is often under 100: RAM on a microcontroller).
fn kept(mut reply: Vec<u8>) -> Vec<u8> {
    reply.shrink_to_fit();
    reply
}

/// The longest prefix of `value` of at most `max` bytes that ends on a character boundary.
fn truncate(value: &str, max: usize) -> &str {
    let mut end = value.len().min(max);
    while !value.is_char_boundary(end) {
        end -= 1;
    }
    value.get(..end).unwrap_or("")
}

/// `String::from_utf8_lossy(bytes).into_owned()`: the same text, with one U+FFFD for each
/// longest prefix of a valid sequence that breaks off (Unicode §3.9, as core replaces), decoded
/// here in far less flash than core's chunk iterator.
pub(crate) fn lossy_string(bytes: &[u8]) -> String {
    let mut text = String::with_capacity(bytes.len());
    let mut rest = bytes;
    while let Some((&first, tail)) = rest.split_first() {
        rest = tail;
        if first.is_ascii() {
            text.push(char::from(first));
            continue;
        }
        // The sequence's length, and the range its second byte must be in (Unicode table 3-7).
        let (len, low, high) = match first {
            0xC2..=0xDF => (2, 0x80, 0xBF),
            0xE0 => (3, 0xA0, 0xBF),
            0xED => (3, 0x80, 0x9F),
            0xE1..=0xEF => (3, 0x80, 0xBF),
            0xF0 => (4, 0x90, 0xBF),
            0xF1..=0xF3 => (4, 0x80, 0xBF),
            0xF4 => (4, 0x80, 0x8F),
            _ => (0, 0, 0),
        };
        let mut code = u32::from(first) & (0x7F >> len);
        let (mut taken, mut range) = (1, low..=high);
        while taken < len {
            let Some((&next, tail)) = rest.split_first().filter(|(b, _)| range.contains(*b)) else { break };
            rest = tail;
            code = code << 6 | u32::from(next & 0x3F);
            taken += 1;
            range = 0x80..=0xBF;
        }
        let whole = if taken == len { char::from_u32(code) } else { None };
        text.push(whole.unwrap_or(char::REPLACEMENT_CHARACTER));
    }
    text
}

/// The bytes up to the next NUL (or the end), and what follows the NUL.
fn next_string(bytes: &[u8]) -> (&[u8], &[u8]) {
    match bytes.iter().position(|&b| b == 0) {
        Some(end) => (bytes.get(..end).unwrap_or(&[]), bytes.get(end + 1..).unwrap_or(&[])),
        None => (bytes, &[]),
    }
}

/// Why a SNIP request of this node failed.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[non_exhaustive]
pub enum SnipFailure {
    /// No reply within [`NodeConfig::snip_timeout`](crate::NodeConfig::snip_timeout).
    TimedOut,
    /// The node answered Optional Interaction Rejected (it has no SNIP, or is busy).
    Rejected(openlcb_stream::wire::ErrorCode),
    /// The transport lost the node or our own link.
    PeerLost,
}

/// Why [`Node::request_snip`](crate::Node::request_snip) refused.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
pub enum SnipRequestError {
    /// A request to that node is still waiting for its reply (SNIP §6.2: one at a time).
    #[error("a SNIP request to that node is already waiting")]
    AlreadyPending,
    /// [`NodeConfig::max_snip_requests`](crate::NodeConfig::max_snip_requests) requests wait.
    #[error("too many SNIP requests are waiting")]
    TooMany,
    /// The node asked is this node.
    #[error("a node cannot ask itself")]
    SelfAddressed,
}

/// One request of this node waiting for its reply.
#[derive(Debug)]
struct PendingSnip {
    peer: NodeId,
    deadline: Instant,
    /// The reply so far (at most [`MAX_REPLY_LEN`] bytes).
    reply: Vec<u8>,
}

impl PendingSnip {
    /// Adds a reply message; returns whether the reply is now whole. A message longer than
    /// one CAN frame's 6 bytes is a whole framed reply; short ones are the frames of an older
    /// node, whole once every string has arrived.
    fn push(&mut self, payload: &[u8]) -> bool {
        let room = MAX_REPLY_LEN.saturating_sub(self.reply.len());
        self.reply.extend_from_slice(payload.get(..room.min(payload.len())).unwrap_or(&[]));
        payload.len() > 6 || SnipInfo::is_complete(&self.reply) || self.reply.len() >= MAX_REPLY_LEN
    }
}

/// SNIP both ways: the node's own strings, answered to every request, and the requests this
/// node makes, each waiting for its reply until its deadline.
#[derive(Debug)]
pub(crate) struct SnipService {
    /// The node's reply payload.
    reply: Vec<u8>,
    requests: Vec<PendingSnip>,
    /// Requests answered.
    pub(crate) answered: u32,
    /// Replies nobody here asked for.
    pub(crate) stray_replies: u32,
}

impl SnipService {
    /// The service for a node of `config` (its own strings, the bound and the wait of its
    /// requests: [`request`](Self::request) is given the bound and the wait again).
    pub(crate) fn new(config: &crate::NodeConfig) -> Self {
        // Without `snip-client` none is ever made.
        #[cfg(feature = "snip-client")]
        let requests = Vec::with_capacity(config.max_snip_requests);
        #[cfg(not(feature = "snip-client"))]
        let requests = Vec::new();
        SnipService { reply: kept(config.snip.to_payload()), requests, answered: 0, stray_replies: 0 }
    }

    /// The node's strings changed.
    pub(crate) fn set_info(&mut self, info: &SnipInfo) {
        self.reply = kept(info.to_payload());
    }

    /// The requests waiting for their replies: never any without the `snip-client` feature,
    /// which the compiler is told here, so that it links none of the reply handling.
    fn requests(&self) -> &[PendingSnip] {
        if cfg!(feature = "snip-client") { &self.requests } else { &[] }
    }

    /// Asks `peer` for its strings: at most `config.max_snip_requests` at once, each waiting
    /// `config.snip_timeout`.
    #[cfg(feature = "snip-client")]
    pub(crate) fn request(
        &mut self,
        config: &crate::NodeConfig,
        now: Instant,
        out: &mut Outputs,
        peer: NodeId,
    ) -> Result<(), SnipRequestError> {
        if peer == out.node {
            return Err(SnipRequestError::SelfAddressed);
        }
        if self.requests().iter().any(|p| p.peer == peer) {
            return Err(SnipRequestError::AlreadyPending);
        }
        if self.requests.len() >= config.max_snip_requests {
            return Err(SnipRequestError::TooMany);
        }
        self.requests.push(PendingSnip { peer, deadline: now + config.snip_timeout, reply: Vec::new() });
        out.transmit(Message::addressed(Mti::SIMPLE_NODE_INFO_REQUEST, out.node, peer, Vec::new()));
        Ok(())
    }

    /// Ends the request at `index` with its reply, unless it `failed`. A partial reply at
    /// the deadline is still worth having (SNIP-TN §2.6: be liberal).
    fn end(&mut self, out: &mut Outputs, index: usize, failed: Option<SnipFailure>) {
        let PendingSnip { peer, reply, .. } = self.requests.swap_remove(index);
        out.event(match failed {
            Some(failure) if reply.is_empty() || failure != SnipFailure::TimedOut => {
                NodeEvent::SnipFailed { peer, failure }
            }
            _ => NodeEvent::SnipReceived { peer, info: Box::new(SnipInfo::parse(&reply)) },
        });
    }
}

impl Service<Lent<'_>> for SnipService {
    fn handle_message(&mut self, cx: &mut Lent<'_>, msg: MessageRef<'_>) -> bool {
        let (out, peer) = (&mut *cx.out, msg.source);
        match msg.mti {
            Mti::SIMPLE_NODE_INFO_REQUEST => {
                bump(&mut self.answered);
                out.reply(Message::addressed(Mti::SIMPLE_NODE_INFO_REPLY, out.node, peer, self.reply.clone()));
            }
            Mti::SIMPLE_NODE_INFO_REPLY => {
                let Some(index) = self.requests().iter().position(|p| p.peer == peer) else {
                    bump(&mut self.stray_replies);
                    return true;
                };
                if self.requests.get_mut(index).is_some_and(|p| p.push(msg.payload)) {
                    self.end(out, index, None);
                }
            }
            _ => return false,
        }
        true
    }

    fn handle_error_report(&mut self, cx: &mut Lent<'_>, peer: NodeId, report: ErrorReport) -> bool {
        let named = matches!(report.mti, None | Some(Mti::SIMPLE_NODE_INFO_REQUEST));
        let Some(index) = self.requests().iter().position(|p| p.peer == peer).filter(|_| named) else { return false };
        self.end(cx.out, index, Some(SnipFailure::Rejected(report.code)));
        true
    }

    fn peer_changed(&mut self, out: &mut Outputs, change: ServiceChange) {
        for pending in self.requests.iter_mut() {
            change.rename(&mut pending.peer);
        }
        while let Some(index) = self.requests().iter().position(|p| change.loses(p.peer)) {
            self.end(out, index, Some(SnipFailure::PeerLost));
        }
    }

    fn handle_timeout(&mut self, cx: &mut Lent<'_>) {
        while let Some(index) = self.requests().iter().position(|p| p.deadline <= cx.now) {
            self.end(cx.out, index, Some(SnipFailure::TimedOut));
        }
    }

    fn poll_timeout(&self) -> Option<Instant> {
        self.requests().iter().fold(None, |next, p| earliest(next, Some(p.deadline)))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn example() -> SnipInfo {
        SnipInfo {
            manufacturer: "Acme".into(),
            model: "Widget".into(),
            hardware_version: "1.0".into(),
            software_version: "2.3".into(),
            user_name: "Yard".into(),
            user_description: "West end".into(),
        }
    }

    #[test]
    fn payload_of_the_worked_example() {
        // node-protocols.md §9.5: 36 bytes.
        let expected = b"\x04Acme\0Widget\x001.0\x002.3\0\x02Yard\0West end\0";
        assert_eq!(&example().to_payload()[..], &expected[..]);
        assert_eq!(SnipInfo::parse(expected), example());
        assert!(SnipInfo::is_complete(expected));
        assert!(!SnipInfo::is_complete(&expected[..35]));
    }

    #[test]
    fn parse_is_liberal() {
        // Version 1 in both sections means the standard counts.
        assert_eq!(SnipInfo::parse(b"\x01Acme\0Widget\x001.0\x002.3\0\x01Yard\0West end\0"), example());
        // Extra strings of a higher version are skipped.
        let extra = SnipInfo::parse(b"\x05Acme\0Widget\x001.0\x002.3\0extra\0\x03Yard\0West end\0more\0");
        assert_eq!(extra, example());
        // Missing fields are empty; a missing NUL ends the string at the end of the data.
        let short = SnipInfo::parse(b"\x04Acme\0Wid");
        assert_eq!((short.manufacturer.as_str(), short.model.as_str(), short.user_name.as_str()), ("Acme", "Wid", ""));
        assert_eq!(SnipInfo::parse(&[]), SnipInfo::default());
        // Vec<u8> that are not UTF-8 are replaced, not refused.
        assert_eq!(SnipInfo::parse(b"\x04\xFF\0").manufacturer, "\u{FFFD}");
    }

    #[test]
    fn over_long_strings_are_reported_and_cut() {
        let mut info = example();
        info.model = "é".repeat(30); // 60 bytes
        assert_eq!(info.check(), Err(SnipTooLong { field: SnipField::Model, len: 60 }));
        let payload = info.to_payload();
        let parsed = SnipInfo::parse(&payload);
        assert_eq!(parsed.model, "é".repeat(20), "cut at 40 bytes on a character boundary");
        assert!(payload.len() <= MAX_REPLY_LEN);
        info.model = "a\0b".into();
        assert!(info.check().is_err(), "a NUL would end the string early");
    }

    #[test]
    fn the_longest_reply_fits_the_bound() {
        let info = SnipInfo {
            manufacturer: "m".repeat(40),
            model: "m".repeat(40),
            hardware_version: "h".repeat(20),
            software_version: "s".repeat(20),
            user_name: "n".repeat(62),
            user_description: "d".repeat(63),
        };
        assert_eq!(info.check(), Ok(()));
        assert_eq!(info.to_payload().len(), MAX_REPLY_LEN);
    }

    #[test]
    fn pending_reply_from_frames_of_an_older_node() {
        let whole = example().to_payload();
        let mut pending = PendingSnip { peer: NodeId::MAX, deadline: Instant::ZERO, reply: Vec::new() };
        let chunks: Vec<&[u8]> = whole.chunks(6).collect();
        for (i, chunk) in chunks.iter().enumerate() {
            assert_eq!(pending.push(chunk), i + 1 == chunks.len(), "whole only after the last frame");
        }
        assert_eq!(SnipInfo::parse(&pending.reply), example());
    }
}
