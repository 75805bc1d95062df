//! The byte streams the drivers and the hub run over: any `AsyncRead + AsyncWrite`, split
//! into its two directions and boxed, so that one driver serves TCP, serial ports,
//! pseudo-terminals and in-memory pipes alike. The box costs one indirect call per read or
//! write (a whole batch of frames), never one per frame.

use std::pin::Pin;
use std::task::{Context, Poll, Waker};

use tokio::io::{AsyncRead, AsyncWrite};

/// The receiving half of a connection.
pub(crate) type ByteReader = Box<dyn AsyncRead + Send + Unpin>;
/// The sending half of a connection.
pub(crate) type ByteWriter = Box<dyn AsyncWrite + Send + Unpin>;

/// A byte stream a [`Node`](crate::Node) or a [`Hub`](crate::Hub) can run over: a TCP
/// stream, a serial port, a pseudo-terminal, an in-memory duplex.
pub trait ByteStream: AsyncRead + AsyncWrite + Send + Unpin + 'static {}

impl<T: AsyncRead + AsyncWrite + Send + Unpin + 'static> ByteStream for T {}

/// Splits any byte stream into its boxed halves (through tokio's `split`, which shares the
/// stream between them). TCP streams are split without sharing by [`tcp_halves`].
pub(crate) fn halves(stream: impl ByteStream) -> (ByteReader, ByteWriter) {
    let (reader, writer) = tokio::io::split(stream);
    (Box::new(reader), Box::new(writer))
}

/// A TCP stream's halves, each owning its direction of the socket.
pub(crate) fn tcp_halves(stream: tokio::net::TcpStream) -> (ByteReader, ByteWriter) {
    let (reader, writer) = stream.into_split();
    (Box::new(reader), Box::new(writer))
}

/// Writes what the stream takes at once without waiting: `None` if it takes nothing now.
/// The stream's own readiness is polled again (with the task's waker) by the awaited write
/// of the drive loop, so nothing is lost by polling here with a waker that does nothing.
pub(crate) fn try_write(writer: &mut ByteWriter, bytes: &[u8]) -> Option<std::io::Result<usize>> {
    let mut context = Context::from_waker(Waker::noop());
    match Pin::new(writer).poll_write(&mut context, bytes) {
        Poll::Ready(written) => Some(written),
        Poll::Pending => None,
    }
}
