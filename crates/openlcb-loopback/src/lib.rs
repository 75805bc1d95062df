//! A deterministic OpenLCB network in one process: many nodes, each a real
//! [`StreamEndpoint`](openlcb_stream::StreamEndpoint) behind its real transport
//! ([`CanLink`](openlcb_can::CanLink) or [`TcpLink`](openlcb_tcp::TcpLink)), on a virtual
//! clock. CAN buses charge every frame its exact bit time, stuff bits included, and arbitrate
//! by identifier; OpenLCB-TCP pipes have latency and bandwidth; faults come from a seed.
//!
//! ```
//! use openlcb_loopback::{Network, NodeOptions, Outcome, TransferSpec};
//! use openlcb_stream::{Instant, NodeId};
//!
//! let mut net = Network::new(7);
//! let bus = net.add_bus(125_000, 16);
//! let a = net.add_can_node(NodeId::new(0x0501_0101_2200).unwrap(), bus, NodeOptions::default());
//! let b = net.add_can_node(NodeId::new(0x0501_0101_2201).unwrap(), bus, NodeOptions::default());
//! let t = net.add_transfer(TransferSpec::new(a, b, 10_000, 2048));
//! net.run(Instant::from_millis(60_000), 1_000_000).unwrap();
//! assert_eq!(net.transfers()[t].outcome, Outcome::Completed);
//! ```
//!
//! # Features
//!
#![doc = document_features::document_features!()]
#![forbid(unsafe_code)]
#![warn(missing_docs)]

pub mod bus;
#[cfg(feature = "fuzzing")]
#[doc(hidden)]
pub mod fuzzing;
mod net;
mod rng;

pub use net::{
    FrameCounts, FrameFaults, NetStats, Network, NeverIdle, NodeIndex, NodeOptions, Outcome, ScheduledFault,
    TransferReport, TransferSpec,
};
pub use rng::{Rng, pattern_byte};
