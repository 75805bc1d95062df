//! Sans-IO OpenLCB-TCP binary framing for the OpenLCB (LCC) stream core.
//!
//! On Ethernet and Wi-Fi, OpenLCB carries full-format messages whole: each one behind a
//! 2-byte flags field (0x8000), a 24-bit length, the Node ID of the node that put it onto
//! the link and a 48-bit capture time. This crate provides:
//!
//! - [`TcpFrame`]: a link prefix plus a core [`MessageRef`](openlcb_stream::MessageRef), with
//!   [`encoded_len`](TcpFrame::encoded_len), [`encode`](TcpFrame::encode) into a caller's
//!   `&mut [u8]` and [`encode_to`](TcpFrame::encode_to) any [`BufMut`](bytes::BufMut) (a
//!   reused [`BytesMut`](bytes::BytesMut) or `Vec<u8>`);
//! - [`Decoder`]: a bounded streaming decoder that takes bytes in pieces of any size;
//! - [`TcpLink`]: one node's adapter between a [`StreamEndpoint`](openlcb_stream::StreamEndpoint)
//!   and the byte stream, in the core's handle/poll shape.
//!
//! It does no I/O, reads no clock and never panics on input.
//!
//! # Encoding and decoding
//!
//! ```
//! use openlcb_stream::{Message, Mti, NodeId};
//! use openlcb_tcp::{CaptureTime, Decoder, LinkPrefix, TcpFrame};
//!
//! let a = NodeId::new(0x05_01_01_01_22_00).unwrap();
//! let b = NodeId::new(0x05_01_01_01_22_01).unwrap();
//! let proceed = Message::addressed(Mti::STREAM_DATA_PROCEED, b, a, &[0x04, 0x07][..]);
//! let prefix = LinkPrefix { gateway: b, capture_time: CaptureTime::new(4).unwrap() };
//!
//! let frame = TcpFrame::new(prefix, proceed.as_ref());
//! let mut buf = [0u8; 64];
//! let len = frame.encode(&mut buf).unwrap();
//! assert_eq!(len, frame.encoded_len());
//! assert_eq!(buf[..5], [0x80, 0x00, 0x00, 0x00, 0x1C]);
//!
//! // Bytes may arrive in any pieces; here one at a time.
//! let mut decoder = Decoder::default();
//! let mut decoded = None;
//! for byte in buf[..len].chunks(1) {
//!     let mut input = byte;
//!     while let Some(result) = decoder.decode(&mut input) {
//!         decoded = Some(result.unwrap().message.to_message());
//!     }
//! }
//! assert_eq!(decoded, Some(proceed));
//! ```
//!
//! # Driving a stream endpoint over a link
//!
//! [`TcpLink`] sits between a socket and an endpoint. Here two nodes are joined by an
//! in-memory "socket" and B answers A's Stream Initiate Request:
//!
//! ```
//! use openlcb_stream::{Config, Event, Instant, NodeId, OpenOptions, StreamEndpoint};
//! use openlcb_tcp::TcpLink;
//!
//! let (a_id, b_id) = (NodeId::new(0x05_01_01_01_22_00).unwrap(), NodeId::new(0x05_01_01_01_22_01).unwrap());
//! let (mut a, mut b) = (StreamEndpoint::new(a_id, Config::default()), StreamEndpoint::new(b_id, Config::default()));
//! let (mut a_link, mut b_link) = (TcpLink::new(a_id), TcpLink::new(b_id));
//! let now = Instant::from_millis(1);
//!
//! // Moves what `from` has to send into `to`'s endpoint: the socket write and read.
//! fn carry(now: Instant, from: &mut TcpLink, to: &mut TcpLink, to_endpoint: &mut StreamEndpoint) {
//!     let wire = from.transmit_pending().to_vec();
//!     from.advance_transmit(wire.len());
//!     let mut input = &wire[..];
//!     while let Some(result) = to.read_message(&mut input) {
//!         to_endpoint.handle_message(now, result.unwrap());
//!     }
//!     assert!(to.failure().is_none());
//! }
//!
//! let stream = a.open(now, OpenOptions::new(b_id, 256)).unwrap();
//! for _ in 0..3 {
//!     a_link.send_from(now, || a.poll_transmit()).unwrap();
//!     b_link.send_from(now, || b.poll_transmit()).unwrap();
//!     carry(now, &mut a_link, &mut b_link, &mut b);
//!     carry(now, &mut b_link, &mut a_link, &mut a);
//! }
//! assert!(matches!(a.poll_event(), Some(Event::Opened { handle, .. }) if handle == stream));
//! ```
//!
//! # Features
//!
#![doc = document_features::document_features!()]
#![cfg_attr(not(test), no_std)]
#![cfg_attr(not(test), deny(clippy::unwrap_used, clippy::expect_used, clippy::panic, clippy::indexing_slicing))]
#![warn(missing_docs)]

extern crate alloc;

mod decoder;
mod frame;
mod link;

#[cfg(feature = "fuzzing")]
#[doc(hidden)]
pub mod fuzzing;

pub use decoder::{DecodeError, Decoder, DecoderStats};
pub use frame::{
    CaptureTime, EncodeError, Flags, HEADER_LEN, LinkPrefix, MAX_LENGTH, MAX_STREAM_DATA_LENGTH, PREFIX_LEN, Part,
    TcpFrame,
};
pub use link::{LinkStats, TcpLink};
