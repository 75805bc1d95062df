//! Sans-IO OpenLCB (LCC) CAN transport, so that the stream core runs unchanged over a CAN
//! segment.
//!
//! - [`CanHeader`]: the 29-bit identifier as a typed view; [`CanFrame`]: an identifier and up
//!   to 8 data bytes, implementing [`embedded_can::Frame`] (re-exported as [`embedded_can`]).
//! - [`Fragments`]: a message split into frames (format 1 with framing flags and 6 payload
//!   bytes a frame, formats 2-5 for datagrams with 8 bytes a frame, format 7 stream data with
//!   the DID and 7 payload bytes a frame); [`Reassembler`]: bounded reassembly with the
//!   message network's and the datagram transport's error cases.
//! - [`AliasLogin`]: CID 7..4, the reserve wait, RID, AMD; defence, loss and duplicate Node
//!   ID detection; [`AliasGenerator`]: the Technical Note's preferred alias generator.
//! - [`AliasCache`]: remote alias mappings, bounded, least recently used evicted first.
//! - [`CanLink`]: one node's adapter between core [`Message`](openlcb_stream::Message)s and
//!   frames, tying the above together.
//! - [`gridconnect`]: the `:X19CC8123N...;` text form, encoder and resumable decoder.
//!
//! # The drive loop
//!
//! [`CanLink`] has the shape of the stream endpoint: inputs
//! [`handle_frame`](CanLink::handle_frame) and [`handle_timeout`](CanLink::handle_timeout),
//! the command [`send`](CanLink::send), outputs [`poll_transmit`](CanLink::poll_transmit),
//! [`poll_event`](CanLink::poll_event) and [`poll_timeout`](CanLink::poll_timeout). After any
//! input or command, drain the outputs, then arm a timer for the earliest `poll_timeout` of
//! link and endpoint.
//!
//! Each input is handed the layer above, a [`Receiver`](openlcb_stream::Receiver) (the
//! `Node` of `openlcb-node`, a `StreamEndpoint`, or a driver's wrapper around one), as rustls
//! hands its state machine the sink it writes into. The link gives it every
//! [`PeerChange`](openlcb_stream::PeerChange) (a peer gone, renamed) the moment it learns it,
//! and then the message the frame completed, borrowing the frame (or the link's reassembly
//! buffer), so the node takes it without a copy. A rename is thus applied before the next
//! message, whatever the driver does; [`poll_event`](CanLink::poll_event) only tells the
//! link's own status ([`LinkEvent`]).
//!
//! ```
//! use openlcb_can::{CanConfig, CanFrame, CanLink, LinkEvent};
//! use openlcb_node::{Node, NodeConfig};
//! use openlcb_stream::{Instant, NodeId};
//!
//! let id = NodeId::new(0x05_01_01_01_22_00).unwrap();
//! let mut node = Node::new(id, NodeConfig::default());
//! let mut link = CanLink::new(Instant::ZERO, id, CanConfig::default());
//! let mut bus: Vec<CanFrame> = Vec::new(); // stands in for the CAN driver
//!
//! // One turn of the loop: at `now`, with whatever frames arrived.
//! let mut turn = |now: Instant, received: &[CanFrame], bus: &mut Vec<CanFrame>| {
//!     // Peer changes and messages go straight to the node.
//!     link.handle_timeout(now, &mut node);
//!     node.handle_timeout(now);
//!     for frame in received {
//!         link.handle_frame(now, frame, &mut node);
//!     }
//!     // The link's own status.
//!     while let Some(event) = link.poll_event() {
//!         match event {
//!             LinkEvent::AliasLost { .. } => node.link_lost(),
//!             // Another node has our Node ID: say so; the one that came second leaves.
//!             LinkEvent::DuplicateNodeId { newcomer: false, .. } => node.report_duplicate_node_id(),
//!             LinkEvent::DuplicateNodeId { newcomer: true, .. } => {
//!                 link.leave(Some(node.duplicate_node_id_report()));
//!                 node.link_lost();
//!             }
//!             _ => {}
//!         }
//!     }
//!     // Take from the node only what the link has room for: the rest waits there.
//!     while link.can_send() {
//!         let Some(msg) = node.poll_transmit() else { break };
//!         let _ = link.send(now, msg); // a message with no CAN form is counted and dropped
//!     }
//!     while let Some(frame) = link.poll_transmit() {
//!         bus.push(frame);
//!     }
//!     while let Some(_event) = node.poll_event() { /* the application's business */ }
//!     [link.poll_timeout(), node.poll_timeout()].into_iter().flatten().min()
//! };
//!
//! // CID 7..4 go out at once; the node's Initialization Complete waits for the alias.
//! let wake = turn(Instant::ZERO, &[], &mut bus);
//! assert_eq!(bus.len(), 4);
//! assert_eq!(wake, Some(Instant::from_millis(200)));
//! // 200 ms later: RID, AMD, then Initialization Complete and a global Verify Node ID
//! // naming this node (a node already holding its Node ID would answer).
//! turn(Instant::from_millis(200), &[], &mut bus);
//! let ids: Vec<u32> = bus[4..].iter().map(CanFrame::raw_id).collect();
//! assert_eq!(ids, [0x1070_0343, 0x1070_1343, 0x1910_0343, 0x1949_0343]);
//!
//! // A peer at alias 0x456 opens a stream under its provisional name, then announces its
//! // Node ID (Verified Node ID) and sends data, in one burst: the rename reaches the node
//! // inside `handle_frame`, so the data finds the stream under the new name.
//! let peer = NodeId::new(0x05_01_01_01_22_01).unwrap();
//! let burst = [
//!     CanFrame::extended(0x19CC_8456, &[0x03, 0x43, 0x00, 0x10, 0x00, 0x00, 0x04]).unwrap(),
//!     CanFrame::extended(0x1917_0456, &peer.to_bytes()).unwrap(),
//!     CanFrame::extended(0x1F34_3456, &[0x00, 0xAA, 0xBB]).unwrap(),
//! ];
//! turn(Instant::from_millis(300), &burst, &mut bus);
//! let handle = node.streams_mut().handles().next().unwrap();
//! assert_eq!(node.streams_mut().stream_info(handle).unwrap().peer, peer);
//! let mut data = [0u8; 8];
//! assert_eq!(node.streams_mut().read(Instant::from_millis(300), handle, &mut data), Ok(2));
//! ```
//!
//! # Choices where the standards leave room
//!
//! - Reassembly errors are counted in [`LinkStats`]. Those that lose a message (0x2041, 0x2011,
//!   and 0x2020 when no slot or length is left) are answered with Optional Interaction
//!   Rejected quoting the MTI ([`CanConfig::reject_reassembly_errors`]): the receiver declines
//!   the broken interaction (a TDE would end every stream with that peer in the core). 0x2042
//!   is only counted: the new first frame starts a message that may well complete, and an
//!   OIR quoting the same MTI would read as a rejection of it.
//! - A message from an alias not in the cache is delivered at once under the alias's
//!   provisional name, [`NodeAlias::provisional_node_id`] (`00.00.00.00.0A.AA`), and its
//!   Node ID is learnt passively, from the AMD, Verified Node ID or Initialization Complete it
//!   sends anyway: the link never sends a frame just to learn a name. When
//!   the name of an alias changes (learnt, evicted from the cache, global AME) the link
//!   hands [`PeerChange::Renamed`](openlcb_stream::PeerChange::Renamed) to the layer above;
//!   see [`CanLink`].
//! - A message to a provisional name goes straight to its alias. A message for a node whose
//!   alias is unknown waits while an AME for that Node ID is out; after
//!   [`CanConfig::resolve_timeout`] it is dropped and the node is
//!   [`PeerChange::Lost`](openlcb_stream::PeerChange::Lost) to the layer above.
//! - A duplicate Node ID is found after the login, by the standard's means (CFT §6.2.5): an
//!   AMD, Verified Node ID or Initialization Complete carrying this node's Node ID from
//!   another alias. The login itself is CID 7..4, RID, AMD and nothing else (CFT §6.2.1).
//!   [`LinkEvent::DuplicateNodeId`] says whether this node is the newcomer, which then
//!   [`leave`](CanLink::leave)s with AMR; the node that was there first keeps running.
//! - After losing its alias the link logs in again with the generator's next alias and sends
//!   Initialization Complete itself (the endpoint sends it only once, when created).
//! - Datagrams (formats 2-5, at most 72 bytes) are framed and reassembled by the link
//!   ([`Reassembler::for_datagrams`]); framing errors are answered with Datagram Rejected
//!   (0x2041, 0x2042, 0x2020, 0x1000, 0x2011). Global messages longer than one frame are
//!   refused by [`CanLink::send`].
//! - The link does not see its own transmitted frames; a driver whose controller echoes them
//!   must filter them out, or they read as an alias collision.
//!
//! # Features
//!
#![doc = document_features::document_features!()]
#![cfg_attr(not(test), no_std)]
#![cfg_attr(not(test), deny(clippy::unwrap_used, clippy::expect_used, clippy::panic, clippy::indexing_slicing))]
#![warn(missing_docs)]

extern crate alloc;

mod alias;
mod cache;
mod fragment;
mod frame;
pub mod gridconnect;
mod header;
mod link;
mod login;
mod reassembly;

#[cfg(feature = "fuzzing")]
#[doc(hidden)]
pub mod fuzzing;

pub use embedded_can;

pub use alias::{AliasGenerator, NodeAlias};
pub use cache::AliasCache;
pub use fragment::{
    ADDRESSED_PAYLOAD_PER_FRAME, DATAGRAM_PAYLOAD_PER_FRAME, EncodeError, Fragments, FramePosition,
    STREAM_PAYLOAD_PER_FRAME, event_report,
};
pub use frame::{CanFrame, FrameError};
pub use gridconnect::{GridConnectDecoder, GridConnectError};
pub use header::{CanHeader, DatagramFrame, FrameKind, HeaderError};
pub use link::{CanConfig, CanLink, LinkEvent, LinkStats, SendError};
pub use login::{AliasLogin, LoginEvent, LoginState, LoginStats};
pub use reassembly::{MAX_DATAGRAM_LEN, Reassembler, ReassemblyError, ReassemblyErrorCounts, ReassemblyKey};

/// Counts one more, stopping at `u32::MAX` (32-bit counters: 64-bit ones cost flash on a
/// microcontroller).
#[inline(never)]
fn bump(counter: &mut u32) {
    *counter = counter.saturating_add(1);
}

/// Moves `next` to `time` if that is earlier (or `next` is `None`): one copy of the 64-bit
/// comparison for every `poll_timeout`.
#[inline(never)]
fn earlier(next: &mut Option<openlcb_stream::Instant>, time: Option<openlcb_stream::Instant>) {
    if let Some(time) = time
        && next.is_none_or(|next| time < next)
    {
        *next = Some(time);
    }
}

/// The six wire bytes of `node`: one copy of the byte shuffle for every frame that carries a
/// Node ID.
#[inline(never)]
fn node_bytes(node: openlcb_stream::NodeId) -> [u8; 6] {
    node.to_bytes()
}

/// Counts `n` more, stopping at `u32::MAX`.
#[inline(never)]
fn add(counter: &mut u32, n: usize) {
    *counter = counter.saturating_add(u32::try_from(n).unwrap_or(u32::MAX));
}

/// Adds `item` at the back of `queue` if it holds fewer than `limit` items
/// ([`Queue::push_within`](openlcb_stream::Queue::push_within)), else drops it and counts it
/// in `overflows`. Every such queue is allocated with room for `limit` items when it is made.
fn push_bounded<T>(queue: &mut openlcb_stream::Queue<T>, limit: usize, item: T, overflows: &mut u32) {
    if !queue.push_within(limit, item) {
        bump(overflows);
    }
}
