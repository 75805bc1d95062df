//! Async drivers that run the sans-IO OpenLCB stream stack over any byte stream: TCP sockets,
//! serial ports (USB GridConnect adapters), pseudo-terminals, in-memory pipes.
//!
//! - [`Node`]: one OpenLCB node connected to a hub, speaking GridConnect text (a
//!   [`CanLink`](openlcb_can::CanLink) with alias login under the stream endpoint) or the
//!   binary OpenLCB-TCP framing (a [`TcpLink`](openlcb_tcp::TcpLink)). [`Node::open`] gives a
//!   [`SendStream`], [`Node::accept`] a [`RecvStream`].
//! - Memory Configuration ([`memory`]): [`Node::set_memory_server`] serves address spaces,
//!   [`Node::read_memory`], [`Node::write_memory`] and [`Node::upgrade_firmware`] configure
//!   and upgrade other nodes, with progress.
//! - A board ([`openlcb_node::board`], [`FileSpace`], [`SharedSpace`], [`Node::set_events`]):
//!   its configuration declared once, kept in a file, its events those the configuration
//!   holds. `examples/io_board.rs` is a complete 8-line I/O board in under 200 lines
//!   (`cargo run -p openlcb-tokio --example io_board -- HUB:PORT`).
//! - Broadcast Time ([`clock`]): the node's fast clocks.
//! - [`Hub`]: a hub that relays every frame from a client to every other client, with bounded
//!   per-client queues; [`Hub::attach`] adds a serial adapter or CAN interface,
//!   [`Hub::link_upstream`] joins another hub.
//! - `serial` (feature `serial`, on by default): USB GridConnect adapters through
//!   `tokio-serial`. [`can`]: CAN interfaces as byte streams ([`can::FrameStream`]), with
//!   SocketCAN behind the `socketcan` feature.
//!
//! # What the driver does
//!
//! Each node has one driver task that owns the socket, the
//! [`StreamEndpoint`](openlcb_stream::StreamEndpoint) and the link, and runs the drive loop
//! of the sans-IO crates: feed what the socket delivered, drain every output, arm one timer
//! for the earliest `poll_timeout` of link and endpoint. Its clock is microseconds since the
//! driver started. The handles talk to it through channels.
//!
//! - **Batched writes**: frames are encoded into one buffer; each turn of the loop hands the
//!   whole buffer to one `write` call ([`WireStats::writes`] counts them).
//! - **Back-pressure**: while the encoded output is above a high-water mark (the socket is not
//!   taking it), the driver stops taking application data; [`SendStream::write_all`] waits.
//!   On the receiving side, data not yet read by the application is bounded too, and no
//!   credit is granted past it, so a slow reader slows the source.
//! - **A lost connection** ends the driver with [`Error::ConnectionLost`], which every waiting
//!   call and every later call returns.
//!
//! [`Node::connect`] dials a TCP hub; [`Node::over`] runs a node over any [`ByteStream`] (a
//! serial port, a pseudo-terminal, a `tokio::io::duplex`). The connection is driven with
//! plain `read` and `write` calls rather than `tokio-util` codecs: the GridConnect and OpenLCB-TCP decoders are already resumable over
//! byte slices and hand out messages borrowed from their own buffers, which a codec's owned
//! items would copy once more.
//!
//! # Example
//!
//! A hub, a receiver and a sender, all on 127.0.0.1:
//!
//! ```
//! use openlcb_stream::{NodeId, OpenOptions};
//! use openlcb_tokio::{Framing, Hub, HubOptions, Node, NodeOptions};
//!
//! # #[tokio::main(flavor = "current_thread")]
//! # async fn main() -> Result<(), openlcb_tokio::Error> {
//! let hub = Hub::bind("127.0.0.1:0", None, HubOptions::default()).await?;
//! let addr = hub.local_addr().to_string();
//!
//! let receiver_id: NodeId = "05.01.01.01.22.F1".parse().unwrap();
//! let mut receiver = Node::connect(&addr, Framing::GridConnect, NodeOptions::new(receiver_id)).await?;
//! let sender_id: NodeId = "05.01.01.01.22.F0".parse().unwrap();
//! let sender = Node::connect(&addr, Framing::GridConnect, NodeOptions::new(sender_id)).await?;
//!
//! let send = async {
//!     let mut stream = sender.open(OpenOptions::new(receiver_id, 2048)).await?;
//!     stream.write_all(vec![7u8; 10_000]).await?;
//!     stream.finish().await
//! };
//! let receive = async {
//!     let mut stream = receiver.accept().await?;
//!     let mut data = Vec::new();
//!     while let Some(chunk) = stream.read().await? {
//!         data.extend_from_slice(&chunk);
//!     }
//!     Ok::<_, openlcb_tokio::Error>(data)
//! };
//! let (sent, received) = tokio::try_join!(send, receive)?;
//! assert_eq!(sent, 10_000);
//! assert_eq!(received, vec![7u8; 10_000]);
//! # Ok(()) }
//! ```

#![forbid(unsafe_code)]
#![deny(clippy::unwrap_used, clippy::expect_used, clippy::panic, clippy::indexing_slicing)]
#![warn(missing_docs)]

mod bridge;
pub mod can;
pub mod clock;
mod driver;
mod error;
pub mod events;
mod file_space;
pub mod hub;
mod io;
pub mod memory;
mod node;
mod requests;
#[cfg(feature = "serial")]
pub mod serial;
mod socket;
mod trace;
pub mod train;
mod wire;

pub use clock::ClockEvents;
pub use error::Error;
pub use events::EventNotices;
pub use file_space::{FileSpace, SharedSpace};
pub use hub::{Hub, HubEvent, HubOptions, HubStats};
pub use io::ByteStream;
pub use memory::{MemoryTransfer, ServerEvents};
pub use node::{DISCOVER_LIMIT, Join, Node, NodeOptions, NodeStats, RecvStream, SendStream, SentBytes};
pub use train::{ThrottleEvents, TrainEvents};

// What a user of this crate needs from the ones below it, so that sending a stream takes
// this crate alone.
pub use openlcb_can::CanConfig;
pub use openlcb_node::{
    DeclaredEvents, EventConfig, EventNotice, EventRange, EventRole, EventState, Listen, MemoryEvent, MemoryServer,
    NodeCommand, NodeConfig, Protocols, RamSpace, ReadOnlySpace, SnipInfo, TransferPath,
};
pub use openlcb_stream::{Config as StreamConfig, EventId, NodeId, OpenOptions};
pub use wire::{Framing, WireStats};
pub use {openlcb_can, openlcb_node, openlcb_stream};
