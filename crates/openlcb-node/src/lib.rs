//! One local OpenLCB (LCC) node, sans-IO.
//!
//! A real device speaks several protocols at once, and streams are mostly reached through
//! them. [`Node`] routes each received message to the protocol it belongs to: the stream
//! endpoint of [`openlcb_stream`], the datagram service, Memory Configuration (server and
//! client, [`memconfig`]), Simple Node Information (SNIP), Event Transport (events
//! produced and consumed, see below), Broadcast Time (the layout's fast clocks,
//! `broadcast_time`, feature `broadcast-time`), trains (Traction Control, Train Search and
//! FDI, `traction`, feature `traction`), and
//! the message-network basics it answers itself (Verify Node ID, Protocol Support Inquiry, and
//! Optional Interaction Rejected for addressed messages of protocols it lacks). Each
//! Optional Interaction Rejected or Terminate Due To Error goes to the protocol its MTI names,
//! so a rejected SNIP request never touches a stream. Its Protocol Support Reply announces
//! exactly what it implements.
//!
//! # The drive loop
//!
//! The shape is the stream core's: inputs ([`handle_message`](Node::handle_message),
//! [`handle_timeout`](Node::handle_timeout), and from the transport
//! [`peer_changed`](Node::peer_changed) and [`link_lost`](Node::link_lost)); commands ([`send_datagram`](Node::send_datagram),
//! [`answer_datagram`](Node::answer_datagram), [`request_snip`](Node::request_snip), and the
//! stream commands of the [`Streams`] view that [`streams_mut`](Node::streams_mut) lends);
//! outputs ([`poll_transmit`](Node::poll_transmit), [`poll_event`](Node::poll_event),
//! [`poll_timeout`](Node::poll_timeout)). Each input and command does all the work it
//! causes before it returns (Memory Configuration acts on its datagrams' outcomes and its
//! streams' events there), so the outputs only pop: after any input or command, drain
//! `poll_transmit` and `poll_event` in either order, then arm a timer for `poll_timeout`. A
//! driver that takes only the transmits (a firmware's) loses nothing: the events wait.
//!
//! Inside, each service (the datagram service, SNIP, Memory Configuration, Event
//! Transport, Broadcast Time, trains) has the same few entry points: a message, an error report, a peer change, a
//! timeout, its next deadline. The node answers the message-network basics itself, gives
//! every other message to the first service that takes it, and offers an OIR or TDE to each
//! service it may concern. A datagram carries its owner: its outcome (OK, Rejected, timed
//! out) goes back to whoever sent it, the application (`DatagramDelivered`,
//! `DatagramFailed`) or Memory Configuration.
//!
//! Two nodes back to back (a real program puts a transport in between): A asks B for its
//! SNIP, sends it a datagram B's application claims, and B answers it.
//!
//! ```
//! use openlcb_node::{DatagramAnswer, Node, NodeConfig, NodeEvent, OkFlags, SnipInfo};
//! use openlcb_stream::{Instant, NodeId};
//!
//! let a_id = NodeId::new(0x05_01_01_01_22_00).unwrap();
//! let b_id = NodeId::new(0x05_01_01_01_22_01).unwrap();
//! let mut b_config = NodeConfig::default();
//! b_config.snip = SnipInfo { manufacturer: "Acme".into(), model: "Widget".into(), ..SnipInfo::default() };
//! b_config.datagrams.claimed = vec![0x21];
//! let mut a = Node::new(a_id, NodeConfig::default());
//! let mut b = Node::new(b_id, b_config);
//! let now = Instant::ZERO;
//!
//! fn pump(now: Instant, a: &mut Node, b: &mut Node) {
//!     loop {
//!         let mut moved = false;
//!         while let Some(msg) = a.poll_transmit() { b.handle_message(now, msg.as_ref()); moved = true; }
//!         while let Some(msg) = b.poll_transmit() { a.handle_message(now, msg.as_ref()); moved = true; }
//!         if !moved { break; }
//!     }
//! }
//!
//! pump(now, &mut a, &mut b); // both announce themselves (Initialization Complete)
//! a.request_snip(now, b_id).unwrap();
//! let sent = a.send_datagram(now, b_id, &[0x21, 1, 2, 3]).unwrap();
//! pump(now, &mut a, &mut b);
//! // B's application gets the datagram and answers it.
//! while let Some(event) = b.poll_event() {
//!     if let NodeEvent::DatagramReceived { from, datagram } = event {
//!         assert_eq!(datagram.as_slice(), [0x21, 1, 2, 3]);
//!         b.answer_datagram(from, DatagramAnswer::Ok(OkFlags::default())).unwrap();
//!     }
//! }
//! pump(now, &mut a, &mut b);
//! let events: Vec<NodeEvent> = std::iter::from_fn(|| a.poll_event()).collect();
//! assert!(events.iter().any(|e| matches!(e, NodeEvent::SnipReceived { info, .. } if info.model == "Widget")));
//! assert!(events.iter().any(|e| matches!(e, NodeEvent::DatagramDelivered { id, .. } if *id == sent)));
//! ```
//!
//! # Memory Configuration
//!
//! A node serves address spaces once it has a [`MemoryServer`] (see [`memconfig`]); any
//! node is a client. Here B serves 256 bytes of RAM as space 0xFD; A writes four bytes by
//! datagrams and reads the whole space back by stream. Each operation ends in one
//! [`MemoryEvent`].
//!
//! ```
//! use openlcb_node::{MemoryEvent, MemoryServer, Node, NodeConfig, NodeEvent, RamSpace, TransferPath};
//! use openlcb_stream::{Instant, NodeId};
//!
//! let a_id = NodeId::new(0x05_01_01_01_22_00).unwrap();
//! let b_id = NodeId::new(0x05_01_01_01_22_01).unwrap();
//! let server = MemoryServer::new().with_space(0xFD, RamSpace::new(256));
//! let mut a = Node::new(a_id, NodeConfig::default());
//! let mut b = Node::new(b_id, NodeConfig::default()).with_memory_server(server);
//! let now = Instant::ZERO;
//!
//! // Passes messages both ways until quiet; returns A's Memory Configuration events.
//! fn pump(now: Instant, a: &mut Node, b: &mut Node) -> Vec<MemoryEvent> {
//!     let mut events = Vec::new();
//!     loop {
//!         let mut moved = false;
//!         while let Some(msg) = a.poll_transmit() { b.handle_message(now, msg.as_ref()); moved = true; }
//!         while let Some(msg) = b.poll_transmit() { a.handle_message(now, msg.as_ref()); moved = true; }
//!         // Events come after transmits and may queue more of them.
//!         while let Some(event) = a.poll_event() {
//!             if let NodeEvent::Memory(event) = event { events.push(event); }
//!             moved = true;
//!         }
//!         while b.poll_event().is_some() { moved = true; }
//!         if !moved { return events; }
//!     }
//! }
//!
//! pump(now, &mut a, &mut b);
//! a.write_memory(now, b_id, 0xFD, 8, vec![1, 2, 3, 4], TransferPath::Datagrams).unwrap();
//! assert!(matches!(pump(now, &mut a, &mut b)[..], [MemoryEvent::WriteDone { len: 4, .. }]));
//! a.read_memory(now, b_id, 0xFD, 0, None, TransferPath::Stream).unwrap();
//! let [MemoryEvent::ReadDone { data, .. }] = &pump(now, &mut a, &mut b)[..] else { panic!() };
//! assert_eq!(data.len(), 256);
//! assert_eq!(data[8..12], [1, 2, 3, 4]);
//! ```
//!
//! # Events
//!
//! [`NodeConfig::events`] declares what a node produces and consumes; the node answers the
//! Identify messages for them and announces them after its Initialization Complete. Here A
//! consumes a block of 16 events and B produces one of them and sends its report.
//!
//! ```
//! use openlcb_node::{DeclaredEvents, EventNotice, EventRange, EventState, Node, NodeConfig, NodeEvent};
//! use openlcb_stream::{EventId, Instant, Mti, NodeId};
//!
//! let button = EventId(0x0501_0101_2201_0003);
//! let mut a_config = NodeConfig::default();
//! let block = EventRange::covering(EventId(0x0501_0101_2201_0000), 16).unwrap();
//! a_config.events.consumed = vec![DeclaredEvents { range: block, state: EventState::Unknown }];
//! let mut b_config = NodeConfig::default();
//! b_config.events.produced = vec![DeclaredEvents::single(button, EventState::Valid)];
//! let mut a = Node::new(NodeId::new(0x05_01_01_01_22_00).unwrap(), a_config);
//! let mut b = Node::new(NodeId::new(0x05_01_01_01_22_01).unwrap(), b_config);
//!
//! // B's first messages: Initialization Complete, the Verify Node ID naming itself that a
//! // node with the same Node ID would answer, then what it produces.
//! let first: Vec<Mti> = std::iter::from_fn(|| b.poll_transmit()).map(|m| m.mti).collect();
//! assert_eq!(first, [Mti::INITIALIZATION_COMPLETE, Mti::VERIFY_NODE_ID_GLOBAL, Mti::PRODUCER_IDENTIFIED_VALID]);
//! while a.poll_transmit().is_some() {}
//!
//! b.send_event(button, &[]).unwrap();
//! while let Some(msg) = b.poll_transmit() {
//!     a.handle_message(Instant::ZERO, msg.as_ref());
//! }
//! let report = std::iter::from_fn(|| a.poll_event()).find_map(|e| match e {
//!     NodeEvent::Events(EventNotice::Report { event, .. }) => Some(event),
//!     _ => None,
//! });
//! assert_eq!(report, Some(button));
//! ```
//!
//! # Peers known by their CAN alias
//!
//! On CAN a peer may be known only by its alias; the CAN link then names it with a
//! provisional Node ID and tells the node when the name changes, as it learns it (the node is
//! the link's [`Receiver`](openlcb_stream::Receiver)). [`PeerChange::Renamed`](openlcb_stream::PeerChange::Renamed)
//! moves everything open with the old name (streams, datagrams, SNIP requests) to the new one,
//! so nothing is lost when a Node ID is learnt or a mapping forgotten.
//!
//! # Bounds
//!
//! Every table is sized by [`NodeConfig`]: answers beyond
//! [`transmit_queue_limit`](NodeConfig::transmit_queue_limit) are dropped and counted;
//! datagrams waiting, datagrams awaiting the application's answer and SNIP requests each have
//! their own bound. Nothing on the receive path panics.
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

pub mod board;
#[cfg(feature = "broadcast-time")]
pub mod broadcast_time;
mod config;
mod datagram;
mod events;
pub mod memconfig;
mod node;
mod service;
mod snip;
mod streams;
#[cfg(feature = "traction")]
pub mod traction;

#[cfg(feature = "fuzzing")]
#[doc(hidden)]
pub mod fuzzing;

#[cfg(feature = "broadcast-time")]
pub use broadcast_time::{ClockConfig, ClockEvent, ClockId, ClockSet, ClockStats, ClockTime};
pub use config::{NodeConfig, Protocols};
pub use datagram::{
    Datagram, DatagramAnswer, DatagramConfig, DatagramError, DatagramFailure, DatagramId, DatagramStats,
    MAX_DATAGRAM_LEN, OkFlags, rejection_code,
};
pub use events::{
    DeclaredEvents, EventConfig, EventError, EventNotice, EventRange, EventRole, EventState, EventStats, Listen,
};
pub use memconfig::{
    MemoryConfigOptions, MemoryError, MemoryEvent, MemoryOperation, MemoryRequestError, MemoryServer, MemorySpace,
    NodeCommand, RamSpace, ReadOnlySpace, SpaceError, TransferPath,
};
#[cfg(feature = "streams")]
pub use node::Streams;
pub use node::{DUPLICATE_NODE_ID_DETECTED, Node, NodeEvent, NodeStats};
pub use snip::{MAX_REPLY_LEN, SnipFailure, SnipField, SnipInfo, SnipRequestError, SnipTooLong};
#[cfg(feature = "traction")]
pub use traction::{Speed, TrainConfig, TrainEvent};
