//! What the gateway reports: [`GatewayEvent`]s, the [`StreamKey`] of a tracked stream, and
//! [`GatewayStats`].

use openlcb_can::{NodeAlias, ReassemblyErrorCounts};
use openlcb_stream::{NodeId, StreamId};

/// The two sides of the gateway.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Side {
    /// The CAN segment.
    Can,
    /// The full-format (OpenLCB-TCP) link.
    Full,
}

/// Names a stream that crosses the gateway (wire-spec §5.1: source, destination and SID).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct StreamKey {
    /// The node sending the data.
    pub source: NodeId,
    /// The node receiving it.
    pub destination: NodeId,
    /// The source's stream ID.
    pub source_stream: StreamId,
}

/// Why the gateway stopped tracking a stream.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[non_exhaustive]
pub enum StreamEnd {
    /// The Complete was forwarded after the buffered data.
    Completed,
    /// The destination refused the request (Reply with a reject code, or OIR).
    Rejected,
    /// Terminate Due To Error from either end: buffered data and delayed messages dropped.
    Terminated,
    /// The source sent more than the window allows and the buffer was full: both ends got
    /// Terminate Due To Error 0x2040.
    Overrun,
    /// A node of the stream restarted, released its alias, or its proxy alias was lost.
    NodeGone,
    /// The same source opened a new stream with the same SID and destination.
    Superseded,
    /// No traffic for [`GatewayConfig::stream_idle_timeout`](crate::GatewayConfig::stream_idle_timeout).
    Idle,
}

/// Something the driver may want to know. Drain with [`poll_event`](crate::Gateway::poll_event).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[non_exhaustive]
pub enum GatewayEvent {
    /// A full-format node now holds `alias` on CAN; its held messages go out.
    ProxyPermitted {
        /// The full-format node.
        node: NodeId,
        /// Its alias on CAN.
        alias: NodeAlias,
    },
    /// A CAN node used a proxied alias: AMR was sent and a new alias is being checked. The
    /// node's streams are over.
    ProxyAliasLost {
        /// The full-format node.
        node: NodeId,
        /// The released alias.
        alias: NodeAlias,
    },
    /// A CAN node announced a proxied node's Node ID: nothing more is sent for that node.
    DuplicateNodeId {
        /// The full-format node.
        node: NodeId,
        /// The CAN alias that announced the same Node ID.
        other: NodeAlias,
    },
    /// A full-format node left ([`handle_full_node_left`](crate::Gateway::handle_full_node_left))
    /// and what it sent has gone out (or its grace ran out): its proxy is forgotten, its
    /// streams are over.
    ProxyReleased {
        /// The full-format node.
        node: NodeId,
        /// The alias released with an AMR; `None` if its login had not finished (nothing was
        /// announced, so nothing is sent).
        alias: Option<NodeAlias>,
    },
    /// No CAN alias was found for `node` within the resolve timeout; messages to it dropped.
    Unreachable {
        /// The destination asked for.
        node: NodeId,
        /// Messages dropped.
        dropped: usize,
    },
    /// A stream was accepted by its destination and is tracked from now on.
    StreamOpened {
        /// The stream.
        stream: StreamKey,
        /// Where its source is.
        source_side: Side,
        /// The negotiated window, as the Reply carried it.
        window: u16,
    },
    /// The gateway stopped tracking a stream.
    StreamEnded {
        /// The stream.
        stream: StreamKey,
        /// Why.
        cause: StreamEnd,
    },
}

/// Counters. Everything dropped or refused is counted here; nothing is a panic.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
#[non_exhaustive]
pub struct GatewayStats {
    /// CAN frames handled.
    pub frames_in: u64,
    /// CAN frames returned by `poll_can_transmit`.
    pub frames_out: u64,
    /// Full-format messages handled.
    pub messages_in: u64,
    /// Full-format messages returned by `poll_message`.
    pub messages_out: u64,
    /// Standard, remote, malformed frames, addressed frames without destination bytes and
    /// stream frames without a DID.
    pub invalid_frames: u64,
    /// Datagrams forwarded: CAN datagrams reassembled for the full-format side, full-format
    /// datagrams framed onto CAN (counted when queued).
    pub datagrams_forwarded: u64,
    /// CAN datagram framing errors, each answered with Datagram Rejected from the proxy
    /// alias the datagram was addressed to.
    pub datagram_errors: ReassemblyErrorCounts,
    /// MTIs with the special bit (0x2000) or without a CAN form: not forwarded.
    pub not_forwardable: u64,
    /// Addressed CAN traffic for CAN nodes, and full-format traffic for full-format nodes:
    /// it stays on its side.
    pub stayed_local: u64,
    /// CAN messages (datagrams included) from an alias whose Node ID is unknown: dropped, since
    /// the full-format side needs a Node ID.
    pub unknown_source_dropped: u64,
    /// Full-format messages claiming the Node ID of a CAN node (dropped).
    pub echoes_dropped: u64,
    /// Multi-frame CAN messages that could not be reassembled.
    pub reassembly_errors: u64,
    /// Messages dropped because the held or queued messages reached their bound, or were
    /// longer than `max_message_len`.
    pub queue_overflows: u64,
    /// Messages dropped because their destination's alias was not found.
    pub unresolved_dropped: u64,
    /// Messages dropped because no proxy entry was free.
    pub proxy_table_full: u64,
    /// Queued messages dropped because their proxy alias was lost or their CAN peer left.
    pub lost_with_alias: u64,
    /// Initiate Requests whose Max Buffer Size was lowered.
    pub windows_lowered: u64,
    /// Streams forwarded without tracking because the stream table was full.
    pub untracked_streams: u64,
    /// Stream data of untracked streams dropped because the backlog was full.
    pub untracked_data_dropped: u64,
    /// CAN stream data frames merged into a tracked stream's buffer.
    pub data_frames_merged: u64,
    /// Data Send messages built from merged CAN frames.
    pub merged_messages: u64,
    /// Proceeds held until the buffer drained.
    pub proceeds_delayed: u64,
    /// Completes held until the buffer drained (or the overtaken data arrived).
    pub completes_delayed: u64,
    /// Stream data bytes dropped on TDE, overrun, or a lost node.
    pub data_bytes_dropped: u64,
    /// Streams terminated because the source overran its window.
    pub overruns: u64,
}
