//! [`Event`]s: everything the application must know about its streams.

use crate::wire::{ErrorCode, ReplyClass, ReplyCode};
use crate::{ContentUid, NodeId, StreamHandle, StreamId};

/// Which end of a stream this node is.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub enum Role {
    /// This node sends the data.
    Source,
    /// This node receives the data.
    Destination,
}

impl Role {
    /// The role at the other end of the stream.
    pub const fn other(self) -> Role {
        match self {
            Role::Source => Role::Destination,
            Role::Destination => Role::Source,
        }
    }
}

/// What is known about a stream.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct StreamInfo {
    /// The node at the other end.
    pub peer: NodeId,
    /// This node's role.
    pub role: Role,
    /// The source's stream ID.
    pub source_stream: StreamId,
    /// The destination's stream ID, once assigned.
    pub destination_stream: Option<StreamId>,
    /// The negotiated window once open; the proposed Max Buffer Size before.
    pub window: u16,
    /// The content UID of the request, if any (the payload itself is opaque, wire-spec Q3).
    pub content_uid: Option<ContentUid>,
}

/// Why a stream ended before finishing.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[non_exhaustive]
pub enum Termination {
    /// The peer sent Terminate Due To Error (or an OIR naming a stream MTI).
    ByPeer(ErrorCode),
    /// The source sent more than the window it was granted: TDE 0x2040 was sent, and
    /// nothing of the message past the window was taken.
    WindowOverrun,
    /// The same source opened a new stream with this stream's SID: it has forgotten this one.
    Superseded,
    /// This node terminated another stream it has with the same node in the same role: a TDE
    /// names no stream, so that node ends all of them (wire-spec Q5), and this node does too.
    SiblingTerminated,
    /// The transport reported the peer gone (for example its CAN alias was released).
    PeerLost,
    /// The peer sent Initialization Complete: it restarted and has forgotten its streams.
    PeerRestarted,
    /// The transport lost the link (for example this node's CAN alias).
    LinkLost,
}

/// Which wait ran out.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
#[non_exhaustive]
pub enum TimeoutKind {
    /// The source waited for an Initiate Reply.
    Reply,
    /// The source waited for a Proceed (TDE 0x2010 was sent).
    Proceed,
    /// The destination heard nothing from a source holding credit (TDE 0x2010 was sent).
    Idle,
    /// The destination accepted a stream and no data came within
    /// [`Config::first_data_timeout`](crate::Config::first_data_timeout) (TDE 0x2010 was sent).
    FirstData,
    /// The application did not decide on an incoming request (it was refused with 0x2020).
    Decision,
}

/// Something the application must know. Drain with `poll_event` after every call.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[non_exhaustive]
pub enum Event {
    /// A request waits for `accept` or `reject` ([`AcceptPolicy::Ask`](crate::AcceptPolicy)).
    IncomingRequest {
        /// The pending stream.
        handle: StreamHandle,
        /// Who asks, with the proposed window and content UID.
        info: StreamInfo,
    },
    /// The stream is open: as source, the request was accepted; as destination, this node
    /// accepted it (by policy or by the application).
    Opened {
        /// The stream.
        handle: StreamHandle,
        /// The negotiated parameters.
        info: StreamInfo,
    },
    /// As source: the destination refused the request (by Reply or by OIR).
    Rejected {
        /// The stream, now closed.
        handle: StreamHandle,
        /// The raw code (an OIR's error code for a rejection by OIR).
        code: ReplyCode,
        /// Whether a retry may help.
        class: ReplyClass,
    },
    /// As destination: data waits to be read (raised when the buffer stops being empty).
    Readable {
        /// The stream.
        handle: StreamHandle,
    },
    /// As source: credit is back after a write came up short.
    Writable {
        /// The stream.
        handle: StreamHandle,
    },
    /// As destination: the source sent Complete and every byte it counted has arrived.
    /// Remaining buffered data can still be read; the handle is released once it has been.
    Finished {
        /// The stream.
        handle: StreamHandle,
        /// Bytes received.
        total: u64,
        /// The total the source stated, if it stated one (resolved from its modular count).
        stated: Option<u64>,
        /// `total` equals `stated` (true when nothing was stated).
        matched: bool,
    },
    /// As source: `finish` sent the Complete; the stream is over on this side and its handle
    /// released. (The destination's storing of the data is its own business: the protocol
    /// has no acknowledgement of a Complete.)
    Sent {
        /// The stream, now released.
        handle: StreamHandle,
        /// Bytes sent.
        total: u64,
    },
    /// The stream ended early. As destination, data received before stays readable.
    Terminated {
        /// The stream.
        handle: StreamHandle,
        /// Why.
        cause: Termination,
    },
    /// A wait ran out and the stream ended.
    TimedOut {
        /// The stream.
        handle: StreamHandle,
        /// Which wait.
        kind: TimeoutKind,
    },
}

impl Event {
    /// The stream the event is about.
    pub const fn handle(&self) -> StreamHandle {
        match *self {
            Event::IncomingRequest { handle, .. }
            | Event::Opened { handle, .. }
            | Event::Rejected { handle, .. }
            | Event::Readable { handle }
            | Event::Writable { handle }
            | Event::Finished { handle, .. }
            | Event::Sent { handle, .. }
            | Event::Terminated { handle, .. }
            | Event::TimedOut { handle, .. } => handle,
        }
    }
}
