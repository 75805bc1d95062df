//! Stream Initiate Request (0x0CC8) and Stream Initiate Reply (0x0868), with the reply code.

use core::fmt;

use super::{BufferTooSmall, DecodeError, Emit, be16, byte, need, put, stream_id};
use crate::{ContentUid, Mti, StreamId};

/// Stream Initiate Request, source to destination (draft §5.1, wire-spec §4.1).
///
/// Wire: `BUF(2) FLAGS(2) SID [DID or FF] [UID(6)]`. The flags are reserved: sent as 0 and
/// ignored on receipt (draft §5.1, wire-spec C-16), so this type has no field for them. Emitted as 5 bytes, 6 with a proposed DID,
/// 12 with a content UID (byte 5 = 0xFF when no DID is proposed, as OpenMRN and the C library do).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct InitiateRequest {
    /// Max Buffer Size proposed by the source, 1..=65535.
    pub max_buffer_size: u16,
    /// The source's stream ID.
    pub source_stream: StreamId,
    /// A DID agreed beforehand by another protocol (byte 5; 0xFF or absent means none).
    pub proposed_destination: Option<StreamId>,
    /// The Stream Content UID (bytes 6-11), present only in payloads of 12 bytes or more.
    pub content_uid: Option<ContentUid>,
}

impl InitiateRequest {
    const MTI: Mti = Mti::STREAM_INITIATE_REQUEST;

    /// Parses a request. Needs 5 bytes; a buffer size of 0 or a SID of 0xFF is refused
    /// (wire-spec §4.1: OpenMRN rejects both as invalid arguments). 7..=11 byte payloads carry
    /// no UID; an all-zero UID counts as none.
    pub fn parse(payload: &[u8]) -> Result<Self, DecodeError> {
        need(Self::MTI, payload, 5)?;
        let max_buffer_size = be16(payload, 0);
        let source_stream = stream_id(Self::MTI, byte(payload, 4), "SID")?;
        if max_buffer_size == 0 {
            return Err(DecodeError::ZeroBufferSize);
        }
        let proposed_destination = payload.get(5).copied().and_then(StreamId::new);
        let content_uid = payload.get(6..12).and_then(|uid| <[u8; 6]>::try_from(uid).ok()).and_then(ContentUid::new);
        Ok(InitiateRequest { max_buffer_size, source_stream, proposed_destination, content_uid })
    }
}

impl Emit for InitiateRequest {
    /// The emitted length: 5, 6 or 12 bytes.
    fn buffer_len(&self) -> usize {
        match (self.content_uid, self.proposed_destination) {
            (Some(_), _) => 12,
            (None, Some(_)) => 6,
            (None, None) => 5,
        }
    }

    /// Writes the strict form (flags always 0) and returns its length.
    fn emit(&self, buf: &mut [u8]) -> Result<usize, BufferTooSmall> {
        let [b0, b1] = self.max_buffer_size.to_be_bytes();
        let did = self.proposed_destination.map_or(StreamId::RESERVED, StreamId::as_raw);
        let [u0, u1, u2, u3, u4, u5] = self.content_uid.map_or([0; 6], ContentUid::to_bytes);
        let all = [b0, b1, 0, 0, self.source_stream.as_raw(), did, u0, u1, u2, u3, u4, u5];
        put(buf, all.get(..self.buffer_len()).unwrap_or(&all))
    }
}

/// The error/accept code of an Initiate Reply (wire-spec §3.2), an open type that keeps the
/// raw value. Named constants follow the 2026 draft read through the Message Network codes.
#[derive(Clone, Copy, PartialEq, Eq, Hash)]
pub struct ReplyCode(pub u16);

/// What a reply code means to the source.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum ReplyClass {
    /// The stream is open (with a non-zero buffer size).
    Accepted,
    /// Do not retry.
    Permanent,
    /// May succeed if retried later.
    Temporary,
}

impl ReplyCode {
    /// Accept (the code this crate sends).
    pub const ACCEPT: ReplyCode = ReplyCode(0x8000);
    /// Permanent error, no detail.
    pub const PERMANENT: ReplyCode = ReplyCode(0x1000);
    /// Streams not supported / not accepted (draft 2026).
    pub const STREAMS_NOT_SUPPORTED: ReplyCode = ReplyCode(0x1010);
    /// Source not permitted.
    pub const SOURCE_NOT_PERMITTED: ReplyCode = ReplyCode(0x1020);
    /// Unimplemented, e.g. an unknown content UID (draft §7.2).
    pub const UNIMPLEMENTED: ReplyCode = ReplyCode(0x1040);
    /// Invalid arguments: what this crate answers to a malformed request (MN §3.5.5).
    pub const INVALID_REQUEST: ReplyCode = ReplyCode(0x1080);
    /// Temporary error, no detail.
    pub const TEMPORARY: ReplyCode = ReplyCode(0x2000);
    /// Buffer unavailable / destination busy: the stream table is full.
    pub const BUFFER_UNAVAILABLE: ReplyCode = ReplyCode(0x2020);
    /// Out of order / unexpected.
    pub const OUT_OF_ORDER: ReplyCode = ReplyCode(0x2040);

    /// Accept bit set, or the code 0x0000 that the 2026 draft also lists as accept.
    pub const fn is_accept(self) -> bool {
        self.0 & 0x8000 != 0 || self.0 == 0
    }

    /// Accept, permanent or temporary. A reject code with neither the permanent (0x1000) nor
    /// the temporary (0x2000) bit, such as OpenMRN's bootloader code 0x4220 from the old
    /// bit-field form, is taken as permanent: retrying an unknown refusal helps nobody.
    pub const fn class(self) -> ReplyClass {
        if self.is_accept() {
            ReplyClass::Accepted
        } else if self.0 & 0x2000 != 0 && self.0 & 0x1000 == 0 {
            ReplyClass::Temporary
        } else {
            ReplyClass::Permanent
        }
    }

    /// A short description of the well-known codes.
    pub const fn meaning(self) -> &'static str {
        match self.0 {
            0x8000 | 0x0000 => "accepted",
            0x1010 => "streams not supported",
            0x1020 => "source not permitted",
            0x1040 => "unimplemented (unknown content UID)",
            0x1043 => "this node takes no streams (unknown MTI or transport)",
            0x1080 => "invalid request",
            0x2020 => "buffer unavailable (destination busy)",
            0x2040 => "out of order",
            _ => match self.class() {
                ReplyClass::Accepted => "accepted",
                ReplyClass::Permanent => "permanent error",
                ReplyClass::Temporary => "temporary error",
            },
        }
    }
}

impl fmt::Debug for ReplyCode {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "ReplyCode(0x{:04X} {})", self.0, self.meaning())
    }
}

impl fmt::Display for ReplyCode {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "0x{:04X} ({})", self.0, self.meaning())
    }
}

/// Stream Initiate Reply, destination to source (draft §5.2, wire-spec §4.2).
///
/// Wire: `BUF(2) CODE(2) SID DID [text\0]`. Always emitted as 6 bytes; a trailing error text is
/// accepted and skipped on receipt.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct InitiateReply {
    /// Final Max Buffer Size: 1..=proposed on accept, 0 on reject.
    pub max_buffer_size: u16,
    /// Accept or the reason for refusing.
    pub code: ReplyCode,
    /// The SID echoed from the request.
    pub source_stream: StreamId,
    /// The DID assigned by the destination. A reject from some peers carries 0xFF: `None`.
    pub destination_stream: Option<StreamId>,
}

impl InitiateReply {
    const MTI: Mti = Mti::STREAM_INITIATE_REPLY;

    /// Parses a reply of 6 or more bytes. SID 0xFF is refused.
    pub fn parse(payload: &[u8]) -> Result<Self, DecodeError> {
        need(Self::MTI, payload, 6)?;
        Ok(InitiateReply {
            max_buffer_size: be16(payload, 0),
            code: ReplyCode(be16(payload, 2)),
            source_stream: stream_id(Self::MTI, byte(payload, 4), "SID")?,
            destination_stream: StreamId::new(byte(payload, 5)),
        })
    }

    /// Accepted: a non-zero buffer and an accept code (wire-spec §3.2 decoding rule).
    pub fn is_accepted(&self) -> bool {
        self.max_buffer_size > 0 && self.code.is_accept()
    }

    /// How the source should take this reply.
    pub fn class(&self) -> ReplyClass {
        if self.is_accepted() {
            ReplyClass::Accepted
        } else if self.code.is_accept() {
            // An accept code with buffer 0 cannot open a stream; nothing says retrying helps.
            ReplyClass::Permanent
        } else {
            self.code.class()
        }
    }
}

impl Emit for InitiateReply {
    /// Always 6.
    fn buffer_len(&self) -> usize {
        6
    }

    /// Writes the 6-byte form. `None` is written back as the 0xFF it was parsed from; the
    /// endpoint never emits it: its rejects carry DID 0x00 (wire-spec §4.2, the checker fails
    /// a 0xFF there).
    fn emit(&self, buf: &mut [u8]) -> Result<usize, BufferTooSmall> {
        let [b0, b1] = self.max_buffer_size.to_be_bytes();
        let [c0, c1] = self.code.0.to_be_bytes();
        let did = self.destination_stream.map_or(StreamId::RESERVED, StreamId::as_raw);
        put(buf, &[b0, b1, c0, c1, self.source_stream.as_raw(), did])
    }
}
