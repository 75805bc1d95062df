//! An OpenLCB (LCC) node on a microcontroller's CAN peripheral, without an async runtime.
//!
//! [`Driver`] runs the sans-IO drive loop between
//! - a CAN peripheral implementing [`embedded_can::nb::Can`] (the trait HAL drivers such as
//!   bxcan, fdcan and mcp2515 implement),
//! - the node's [`CanLink`](openlcb_can::CanLink) (alias login, framing, alias resolution),
//! - the layer above, anything implementing [`Upper`]: a
//!   [`StreamEndpoint`](openlcb_stream::StreamEndpoint) or a whole
//!   [`Node`](openlcb_node::Node) out of the box,
//! - and a [`Clock`] the caller supplies (any `FnMut() -> Instant`).
//!
//! Each [`Driver::poll`] runs due timers, takes received frames into the link (which hands
//! the upper layer each peer change as it learns it, then the messages), moves the upper layer's messages into the link while it has room, and hands
//! frames to the peripheral until it answers `WouldBlock`; the refused frame is kept and
//! offered first next time, never lost. Nothing is allocated per frame.
//!
//! [`memory_bus`] is an in-memory bus whose ports implement the same trait, for host tests
//! and for firmware that runs several nodes on one chip.
//!
//! A whole board on this driver is the repository's `examples/cortex-m0`: an 8-line I/O board
//! on a Cortex-M0 (QEMU's `microbit`), its configuration in flash, its events bound to it, a
//! firmware image space, run by CI against a bus a test drives (`.ci/firmware-m0`).
//!
//! # The loop
//!
//! Two nodes on a memory bus, on virtual time, move 1000 bytes through a stream:
//!
//! ```
//! use core::cell::Cell;
//! use openlcb_can::{CanConfig, CanFrame, CanLink};
//! use openlcb_embedded::{Driver, memory_bus::MemoryBus};
//! use openlcb_stream::{Config, Event, Instant, NodeId, OpenOptions, StreamEndpoint};
//!
//! let (a_id, b_id) = (NodeId::new(0x05_01_01_01_22_00).unwrap(), NodeId::new(0x05_01_01_01_22_01).unwrap());
//! let bus: MemoryBus<CanFrame, 2, 4> = MemoryBus::new();
//! let time = Cell::new(Instant::ZERO);
//! let clock = || time.get();
//! let mut a = Driver::new(bus.port(0).unwrap(), clock, CanLink::new(time.get(), a_id, CanConfig::default()));
//! let mut b = Driver::new(bus.port(1).unwrap(), clock, CanLink::new(time.get(), b_id, CanConfig::default()));
//! let mut source = StreamEndpoint::new(a_id, Config::default());
//! let mut destination = StreamEndpoint::new(b_id, Config::default());
//!
//! let data = [0x5Au8; 1000];
//! let (mut stream, mut sent, mut received, mut buf) = (None, 0, 0, [0u8; 64]);
//! let mut finished = false;
//! while !finished {
//!     let pa = a.poll(&mut source).unwrap();
//!     let pb = b.poll(&mut destination).unwrap();
//!     // The application's part: events and commands of the upper layers.
//!     let mut worked = false;
//!     if stream.is_none() && a.link().alias().is_some() && b.link().alias().is_some() {
//!         stream = Some(source.open(time.get(), OpenOptions::new(b_id, 256)).unwrap());
//!         worked = true;
//!     }
//!     while let Some(event) = source.poll_event() {
//!         if let (Event::Opened { handle, .. } | Event::Writable { handle }) = event {
//!             worked = true;
//!             sent += source.write(time.get(), handle, &data[sent..]).unwrap();
//!             if sent == data.len() { source.finish(time.get(), handle).unwrap(); }
//!         }
//!     }
//!     while let Some(event) = destination.poll_event() {
//!         match event {
//!             Event::Readable { handle } => {
//!                 worked = true;
//!                 while let Ok(n @ 1..) = destination.read(time.get(), handle, &mut buf) { received += n; }
//!             }
//!             Event::Finished { total, matched, .. } => { assert!(matched && total == 1000); finished = true; }
//!             _ => {}
//!         }
//!     }
//!     // Nothing to do: sleep until the next deadline (here: jump there).
//!     if !worked && pa.is_idle() && pb.is_idle() {
//!         let next = [pa.deadline, pb.deadline].into_iter().flatten().min().expect("a timer runs");
//!         time.set(next.max(time.get()));
//!     }
//! }
//! assert_eq!(received, 1000);
//! assert!(time.get() >= Instant::from_millis(200)); // the alias login's reserve wait
//! ```

#![no_std]
#![forbid(unsafe_code)]
#![cfg_attr(not(test), deny(clippy::unwrap_used, clippy::expect_used, clippy::panic, clippy::indexing_slicing))]
#![warn(missing_docs)]

mod driver;
pub mod memory_bus;
mod upper;

pub use driver::{DEFAULT_RECEIVE_BUDGET, Driver, DriverStats, Error, Poll, convert};
pub use upper::{Clock, Upper};
