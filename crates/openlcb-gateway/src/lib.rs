//! Sans-IO OpenLCB (LCC) gateway between one CAN segment and one full-format (OpenLCB-TCP)
//! link, with Stream Transport tracking by the draft's gateway rules (wire-spec §6.5).
//!
//! [`Gateway`] takes CAN frames and full-format messages in and hands frames and messages out.
//! It never reads a clock, touches a socket or logs; time is an argument.
//!
//! - **Forwarding.** CAN frames become full-format messages: aliases are mapped to Node IDs
//!   (learned from AMD, Verified Node ID and Initialization Complete), format-1 multi-frame
//!   messages are reassembled, stream data frames (format 7) become Data Send messages.
//!   Full-format messages become frames. MTIs with the special bit (0x2000) stay where they
//!   are. Addressed traffic between two nodes on the same side stays on that side.
//! - **Datagrams** (node-protocols §2.5) cross both ways. CAN datagram frames (formats 2-5)
//!   addressed to a proxy alias are reassembled in [`GatewayConfig::datagram_slots`] slots of
//!   72 bytes, keyed by (source, destination) alias, and forwarded as one full-format
//!   Datagram (0x1C48); framing errors are answered on CAN with Datagram Rejected from that
//!   proxy alias, with the codes a CAN node uses (0x2041 middle or last without first, 0x2042
//!   first while one is open, both dropped, 0x2020 no free slot, 0x1000 over 72 bytes, 0x2011
//!   no last frame in time), and counted in [`GatewayStats::datagram_errors`]. A full-format
//!   Datagram is framed as formats 2-5 from the proxy alias of its source (more than 72
//!   bytes has no CAN form and is not forwarded). Datagram Received OK and Rejected are
//!   ordinary addressed messages.
//! - **Aliases only.** A CAN message (a datagram too) from an alias whose Node ID the gateway
//!   has not learnt is dropped and counted ([`GatewayStats::unknown_source_dropped`]): unlike
//!   a node's `CanLink`, which serves such a peer under a provisional name, the gateway has
//!   no Node ID to put on the full-format side.
//! - **Proxy aliases.** Each full-format node whose traffic goes onto CAN gets its own alias
//!   login (CID 7..4, RID, AMD) before its first message; its messages are held (bounded)
//!   until then. The gateway answers AME for those nodes, defends their aliases against CID,
//!   and on a collision releases the alias (AMR) and logs in again. A destination whose alias
//!   is not known is asked for with an AME; its messages wait, and are dropped with
//!   [`GatewayEvent::Unreachable`] after [`GatewayConfig::resolve_timeout`].
//! - **Streams.** Each stream that crosses is tracked from its Initiate Request and Reply. A
//!   Request's Max Buffer Size is lowered to [`GatewayConfig::max_window`]; a Reply is never
//!   changed. CAN data frames are merged into larger Data Send messages, forwarded when a
//!   window boundary is reached (bytes counted modulo the negotiated window), on a DID-only
//!   flush frame, before a Complete, and after [`GatewayConfig::merge_delay`] at the latest.
//!   The stream's first frame goes at once, and so does the first frame of every window once
//!   the destination has shown that it sends Proceeds ahead, so that its Proceed can come back
//!   while the rest of the window is still on the bus. Large full-format Data Sends are split
//!   into frames. A flush is passed on once the stream's buffer has drained. Proceeds are
//!   delayed (never dropped) until the buffer has drained, and for a source on the
//!   full-format side until it has used its credit, so the gateway never holds more than one
//!   window per stream. A Complete is delayed until the buffer has drained (and, from CAN,
//!   until data it overtook has arrived). TDE drops the stream's buffered data and delayed
//!   messages. Data of an untracked stream (no Request/Reply seen, or the table was full)
//!   crosses frame by frame.
//! - **Bounds.** Every table, queue and buffer is sized by [`GatewayConfig`];
//!   [`Gateway::memory_in_use`] reports the payload bytes held and never exceeds
//!   [`Gateway::memory_bound`] once the full-format output is drained.
//!
//! # The drive loop
//!
//! Inputs: [`handle_can_frame`](Gateway::handle_can_frame),
//! [`handle_message`](Gateway::handle_message) (as decoded by a `TcpLink`) and
//! [`handle_timeout`](Gateway::handle_timeout). Outputs:
//! [`poll_can_transmit`](Gateway::poll_can_transmit), [`poll_message`](Gateway::poll_message)
//! (to be encoded by a `TcpLink`), [`poll_event`](Gateway::poll_event) and
//! [`poll_timeout`](Gateway::poll_timeout).
//!
//! The rule: after any input, drain `poll_message` and `poll_event` until `None`. Pull frames
//! with `poll_can_transmit` whenever the CAN controller can take one (frames may wait inside
//! the gateway: that is its stream buffer), and drain `poll_message` again afterwards, since
//! sending frames can release delayed Proceeds and Completes. Then arm a timer for
//! `poll_timeout`.
//!
//! ```
//! use openlcb_can::CanFrame;
//! use openlcb_gateway::{Gateway, GatewayConfig, GatewayEvent};
//! use openlcb_stream::{Instant, Message, Mti, NodeId};
//!
//! let mut gateway = Gateway::new(Instant::ZERO, GatewayConfig::default());
//! let mut bus: Vec<CanFrame> = Vec::new(); // stands in for the CAN driver
//! let mut link: Vec<Message> = Vec::new(); // stands in for a TcpLink
//!
//! // One turn of the loop: whatever arrived on either side, then the outputs.
//! let mut turn = |now: Instant, frames: &[CanFrame], messages: &[Message], bus: &mut Vec<CanFrame>| {
//!     gateway.handle_timeout(now);
//!     for frame in frames {
//!         gateway.handle_can_frame(now, frame);
//!     }
//!     for message in messages {
//!         gateway.handle_message(now, message.as_ref());
//!     }
//!     while let Some(frame) = gateway.poll_can_transmit() {
//!         bus.push(frame); // a real driver stops when the controller is full
//!     }
//!     while let Some(message) = gateway.poll_message() {
//!         link.push(message);
//!     }
//!     while let Some(event) = gateway.poll_event() {
//!         if let GatewayEvent::ProxyPermitted { node, alias } = event {
//!             println!("{node} is {alias} on CAN");
//!         }
//!     }
//!     gateway.poll_timeout()
//! };
//!
//! // A full-format node says who it is: the gateway first reserves an alias for it.
//! let node = NodeId::new(0x05_01_01_01_22_10).unwrap();
//! let verified = Message::global(Mti::VERIFIED_NODE_ID, node, node.to_bytes().to_vec());
//! let wake = turn(Instant::ZERO, &[], &[verified], &mut bus);
//! assert_eq!(bus.len(), 4, "CID 7..4");
//! assert_eq!(wake, Some(Instant::from_millis(200)));
//! // 200 ms later: RID, AMD, then the message itself from the new alias.
//! turn(Instant::from_millis(200), &[], &[], &mut bus);
//! let ids: Vec<u32> = bus[4..].iter().map(|f| f.raw_id() & 0x1FFF_F000).collect();
//! assert_eq!(ids, [0x1070_0000, 0x1070_1000, 0x1917_0000]);
//! ```
//!
//! # Features
//!
#![doc = document_features::document_features!()]
#![cfg_attr(not(test), no_std)]
#![cfg_attr(not(test), deny(clippy::unwrap_used, clippy::expect_used, clippy::panic, clippy::indexing_slicing))]
#![forbid(unsafe_code)]
#![warn(missing_docs)]

extern crate alloc;
#[cfg(feature = "fuzzing")]
extern crate std;

mod config;
mod event;
mod gateway;
mod proxy;
mod stream;

#[cfg(feature = "fuzzing")]
#[doc(hidden)]
pub mod fuzzing;

pub use config::GatewayConfig;
pub use event::{GatewayEvent, GatewayStats, Side, StreamEnd, StreamKey};
pub use gateway::Gateway;
