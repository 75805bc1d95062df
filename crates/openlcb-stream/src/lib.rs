//! Sans-IO OpenLCB (LCC) Stream Transport.
//!
//! [`StreamEndpoint`] is one local node's stream engine, both roles at once, for many streams
//! with many peers. It never reads a clock, touches a socket, spawns or logs: messages go in,
//! messages and events come out, and time is an argument. Transports (CAN, OpenLCB-TCP) turn
//! its full-format [`Message`]s into bytes and back.
//!
//! # The drive loop
//!
//! Calls come in four families:
//! - **inputs**: [`handle_message`](StreamEndpoint::handle_message) for each received
//!   message, [`handle_timeout`](StreamEndpoint::handle_timeout) when the timer fires;
//! - **commands**: [`open`](StreamEndpoint::open), [`write`](StreamEndpoint::write),
//!   [`flush`](StreamEndpoint::flush), [`finish`](StreamEndpoint::finish),
//!   [`abort`](StreamEndpoint::abort), [`accept`](StreamEndpoint::accept),
//!   [`reject`](StreamEndpoint::reject), [`read`](StreamEndpoint::read);
//! - **peer changes** from the transport: [`peer_changed`](StreamEndpoint::peer_changed)
//!   ([`PeerChange`]; a transport that learns them calls it itself, through [`Receiver`]);
//! - **outputs**: [`poll_transmit`](StreamEndpoint::poll_transmit),
//!   [`poll_event`](StreamEndpoint::poll_event), [`poll_timeout`](StreamEndpoint::poll_timeout);
//! - **getters** such as [`credit`](StreamEndpoint::credit) and [`stats`](StreamEndpoint::stats).
//!
//! The rule: after any input or command, drain `poll_transmit` and `poll_event` until they
//! return `None`, then arm a timer for `poll_timeout`.
//!
//! Here two endpoints are wired back to back (a real program puts a transport in between)
//! and 10 000 bytes move from A to B through a 256-byte window:
//!
//! ```
//! use openlcb_stream::{Config, Event, Instant, NodeId, OpenOptions, StreamEndpoint};
//!
//! let a_id = NodeId::new(0x05_01_01_01_22_00).unwrap();
//! let b_id = NodeId::new(0x05_01_01_01_22_01).unwrap();
//! let mut a = StreamEndpoint::new(a_id, Config::default());
//! let mut b = StreamEndpoint::new(b_id, Config::default());
//! let now = Instant::ZERO;
//!
//! // Deliver everything each side has to send to the other, until both are quiet.
//! fn pump(now: Instant, a: &mut StreamEndpoint, b: &mut StreamEndpoint) {
//!     loop {
//!         let mut moved = false;
//!         while let Some(msg) = a.poll_transmit() { b.handle_message(now, msg.as_ref()); moved = true; }
//!         while let Some(msg) = b.poll_transmit() { a.handle_message(now, msg.as_ref()); moved = true; }
//!         if !moved { break; }
//!     }
//! }
//!
//! let data: Vec<u8> = (0..10_000u32).map(|i| i as u8).collect();
//! let stream = a.open(now, OpenOptions::new(b_id, 256)).unwrap();
//! pump(now, &mut a, &mut b);
//!
//! let (mut sent, mut received, mut finished) = (0, Vec::new(), false);
//! let mut buf = [0u8; 512];
//! while !finished {
//!     // The source writes what its credit allows; `write` says how much it took.
//!     if sent < data.len() {
//!         sent += a.write(now, stream, &data[sent..]).unwrap();
//!         if sent == data.len() { a.finish(now, stream).unwrap(); }
//!     }
//!     pump(now, &mut a, &mut b);
//!     // The destination reads; reading frees buffer space, which lets a Proceed go out.
//!     while let Some(event) = b.poll_event() {
//!         match event {
//!             Event::Opened { .. } | Event::Readable { .. } => {}
//!             Event::Finished { total, matched, .. } => { assert!(matched); assert_eq!(total, 10_000); finished = true; }
//!             other => panic!("unexpected {other:?}"),
//!         }
//!     }
//!     for handle in b.handles().collect::<Vec<_>>() {
//!         while let Ok(n @ 1..) = b.read(now, handle, &mut buf) { received.extend_from_slice(&buf[..n]); }
//!     }
//!     while a.poll_event().is_some() {}
//!     pump(now, &mut a, &mut b);
//!     if let Some(deadline) = a.poll_timeout() { assert!(deadline > now); }
//! }
//! assert_eq!(received, data);
//! ```
//!
//! # What is on the wire
//!
//! [`wire`] has one type per stream message with `parse` (liberal where real peers differ)
//! and [`Emit`](wire::Emit) (one strict form). The byte layouts and the resolution of every
//! contradiction between the drafts are documented next to each type.
//!
//! # Bounds
//!
//! Every table and buffer is sized by [`Config`]; bad input is counted in [`Stats`] and
//! ignored, or refused with the code the draft asks for, and never panics.
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
mod endpoint;
mod event;
mod ids;
mod message;
mod mti;
mod peer;
mod queue;
mod time;
pub mod wire;

#[cfg(feature = "fuzzing")]
#[doc(hidden)]
pub mod fuzzing;

pub use config::{AcceptPolicy, Config};
pub use endpoint::{AcceptOptions, OpenOptions, Stats, StreamEndpoint, StreamError, StreamHandle};
pub use event::{Event, Role, StreamInfo, Termination, TimeoutKind};
pub use ids::{ContentUid, EventId, NodeId, ParseEventIdError, ParseNodeIdError, StreamId};
pub use message::{Message, MessageRef};
pub use mti::Mti;
pub use peer::{PeerChange, PeerChanges, Receiver};
pub use queue::Queue;
pub use time::{Duration, Instant};
