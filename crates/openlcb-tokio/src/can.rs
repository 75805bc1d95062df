//! CAN interfaces (SocketCAN's `can0`, any controller with a frame queue) as byte streams of
//! GridConnect text, so that the same [`Node`](crate::Node) driver and [`Hub`](crate::Hub)
//! serve them: [`FrameStream`] wraps a [`FrameBus`], the small frame source and sink a CAN
//! interface is to this crate.
//!
//! A controller that echoes the frames it sent (SocketCAN with `CAN_RAW_RECV_OWN_MSGS`, many
//! USB-CAN controllers in loopback mode) would make a node hear its own alias reservation
//! and take it for a collision. [`FrameStream`] remembers the frames it sent and drops a
//! received frame equal to one of them (identifier and data), once, and counts it
//! ([`FrameStream::echoes`]); a frame from another node that uses our alias still reaches
//! the link and is defended. Once it has heard one echo it knows the controller echoes and
//! sends no more than [`ECHO_MEMORY`] frames ahead of their echoes (the bus is the slower
//! side anyway); a controller that never echoes only has the last [`ECHO_MEMORY`] frames
//! remembered, and one whose [`FrameBus::may_echo`] says it never echoes (SocketCAN) none, so
//! that a node sending the same frames again from elsewhere on the bus is always heard.
//!
//! Each frame is turned into GridConnect text and back on its way: the driver's framing
//! works on bytes, and the text is at most [`gridconnect::MAX_ENCODED_LEN`] bytes a frame on
//! the stack, never an allocation.

use std::collections::VecDeque;
use std::pin::Pin;
use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};
use std::task::{Context, Poll, Waker};

use openlcb_can::{CanFrame, GridConnectDecoder, gridconnect};
use tokio::io::{AsyncRead, AsyncWrite, ReadBuf};

/// Frames remembered as sent, to recognise their echoes.
pub const ECHO_MEMORY: usize = 256;

/// A CAN interface as the drivers see it: frames in, frames out, in the shape of tokio's
/// `poll_*` methods. A test implements it with an in-memory bus.
pub trait FrameBus: Send + Unpin + 'static {
    /// The next frame heard on the bus.
    fn read_message(&mut self, cx: &mut Context<'_>) -> Poll<std::io::Result<CanFrame>>;
    /// Puts `frame` on the bus (queued by the controller), or `Pending` while it has no room.
    fn poll_send(&mut self, cx: &mut Context<'_>, frame: &CanFrame) -> Poll<std::io::Result<()>>;
    /// `false` if the controller is known never to hand back the frames it sent, so that
    /// [`FrameStream`] remembers none: a later frame equal to one sent here (the same node
    /// sending the same data again, from elsewhere on the bus) is then always read. `true`
    /// (the default) when it may echo.
    fn may_echo(&self) -> bool {
        true
    }
}

/// A [`FrameBus`] as a byte stream of GridConnect text, for
/// [`Node::over`](crate::Node::over) (with [`Framing::GridConnect`](crate::Framing)) or
/// [`Hub::attach`](crate::Hub::attach). Echoes of its own frames are dropped.
#[derive(Debug)]
pub struct FrameStream<B> {
    bus: B,
    /// Text of a received frame not yet read, from `text_start`.
    text: [u8; gridconnect::MAX_ENCODED_LEN + 1],
    text_start: usize,
    text_end: usize,
    decoder: GridConnectDecoder,
    /// A frame decoded from written text that the bus has not taken yet.
    unsent: Option<CanFrame>,
    sent: VecDeque<CanFrame>,
    echoes: Arc<AtomicU64>,
    /// A writer waiting for echoes to make room in `sent` (on a controller that echoes).
    waiting_writer: Option<Waker>,
}

impl<B: FrameBus> FrameStream<B> {
    /// Wraps `bus`.
    pub fn new(bus: B) -> Self {
        FrameStream {
            bus,
            text: [0; gridconnect::MAX_ENCODED_LEN + 1],
            text_start: 0,
            text_end: 0,
            decoder: GridConnectDecoder::default(),
            unsent: None,
            sent: VecDeque::with_capacity(ECHO_MEMORY),
            echoes: Arc::default(),
            waiting_writer: None,
        }
    }

    /// Echoes of this stream's own frames dropped so far (a counter that stays readable after
    /// the stream moved into a driver).
    pub fn echoes(&self) -> Arc<AtomicU64> {
        self.echoes.clone()
    }

    /// `true` (and forgotten) if `frame` is the echo of a frame sent here.
    fn is_echo(&mut self, frame: &CanFrame) -> bool {
        match self.sent.iter().position(|sent| sent == frame) {
            Some(at) => {
                self.sent.remove(at);
                self.echoes.fetch_add(1, Ordering::Relaxed);
                if let Some(writer) = self.waiting_writer.take() {
                    writer.wake();
                }
                true
            }
            None => false,
        }
    }

    /// Sends the frame waiting for the bus, if any; `Pending` while the bus has no room.
    fn poll_unsent(&mut self, cx: &mut Context<'_>) -> Poll<std::io::Result<()>> {
        let Some(frame) = self.unsent else { return Poll::Ready(Ok(())) };
        let echoing = self.echoes.load(Ordering::Relaxed) > 0;
        if echoing && self.sent.len() == ECHO_MEMORY {
            // The reader's next echo makes room.
            self.waiting_writer = Some(cx.waker().clone());
            return Poll::Pending;
        }
        std::task::ready!(self.bus.poll_send(cx, &frame))?;
        self.unsent = None;
        if !self.bus.may_echo() {
            return Poll::Ready(Ok(()));
        }
        if self.sent.len() == ECHO_MEMORY {
            self.sent.pop_front();
        }
        self.sent.push_back(frame);
        Poll::Ready(Ok(()))
    }
}

impl<B: FrameBus> AsyncRead for FrameStream<B> {
    fn poll_read(self: Pin<&mut Self>, cx: &mut Context<'_>, buf: &mut ReadBuf<'_>) -> Poll<std::io::Result<()>> {
        let this = self.get_mut();
        let mut filled = false;
        while buf.remaining() > 0 {
            if this.text_start == this.text_end {
                let frame = match this.bus.read_message(cx) {
                    Poll::Ready(Ok(frame)) => frame,
                    Poll::Ready(Err(error)) if !filled => return Poll::Ready(Err(error)),
                    // What was read goes out first; the error comes again at the next read.
                    Poll::Ready(Err(_)) | Poll::Pending if filled => break,
                    Poll::Ready(Err(_)) | Poll::Pending => return Poll::Pending,
                };
                if this.is_echo(&frame) {
                    continue;
                }
                let Ok(len) = gridconnect::encode(&frame, &mut this.text) else { continue };
                let Some(newline) = this.text.get_mut(len) else { continue };
                *newline = b'\n';
                (this.text_start, this.text_end) = (0, len + 1);
            }
            let text = this.text.get(this.text_start..this.text_end).unwrap_or_default();
            let n = text.len().min(buf.remaining());
            buf.put_slice(text.get(..n).unwrap_or_default());
            this.text_start += n;
            filled = true;
        }
        Poll::Ready(Ok(()))
    }
}

impl<B: FrameBus> AsyncWrite for FrameStream<B> {
    /// Takes text up to the end of one frame at a time and hands the frame to the bus; stops
    /// while the bus has no room (at most one frame is held here). Text that is not a frame
    /// is skipped, as the decoder resynchronises.
    fn poll_write(self: Pin<&mut Self>, cx: &mut Context<'_>, buf: &[u8]) -> Poll<std::io::Result<usize>> {
        let this = self.get_mut();
        let mut input = buf;
        loop {
            if this.poll_unsent(cx)?.is_pending() {
                let taken = buf.len() - input.len();
                return if taken > 0 { Poll::Ready(Ok(taken)) } else { Poll::Pending };
            }
            match this.decoder.decode(&mut input) {
                Some(Ok(frame)) => this.unsent = Some(frame),
                Some(Err(_)) => {}
                None => return Poll::Ready(Ok(buf.len())),
            }
        }
    }

    fn poll_flush(self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<std::io::Result<()>> {
        self.get_mut().poll_unsent(cx)
    }

    fn poll_shutdown(self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<std::io::Result<()>> {
        self.poll_flush(cx)
    }
}

/// Opens the SocketCAN interface `interface` (`can0`, `vcan0`) for
/// [`FrameStream::new`]. Not run on hardware by this crate's tests (they use an in-memory
/// [`FrameBus`]). A failure to open is [`Error::Device`](crate::Error::Device).
#[cfg(feature = "socketcan")]
pub fn open_socketcan(interface: &str) -> Result<socketcan::tokio::CanSocket, crate::Error> {
    socketcan::tokio::CanSocket::open(interface).map_err(|source| crate::Error::Device {
        kind: "CAN interface",
        device: interface.to_string(),
        source: Arc::new(source),
    })
}

/// The same frame in another crate's type (data frames only; a remote frame is `None`).
#[cfg(feature = "socketcan")]
fn convert<To: embedded_can::Frame>(frame: &impl embedded_can::Frame) -> Option<To> {
    if frame.is_remote_frame() { None } else { To::new(frame.id(), frame.data()) }
}

/// Linux's "no buffer space available": SocketCAN's answer when the interface's transmit
/// queue is full.
#[cfg(feature = "socketcan")]
const ENOBUFS: i32 = 105;

/// SocketCAN through `socketcan`'s tokio socket. Error frames and remote frames are skipped
/// (OpenLCB uses neither). A full transmit queue (`ENOBUFS`, which readiness does not
/// report) is retried at the task's next turn. The socket is opened without own-message
/// reception, so it never echoes.
#[cfg(feature = "socketcan")]
impl FrameBus for socketcan::tokio::CanSocket {
    fn read_message(&mut self, cx: &mut Context<'_>) -> Poll<std::io::Result<CanFrame>> {
        use futures_core::Stream;
        loop {
            match std::task::ready!(Pin::new(&mut *self).poll_next(cx)) {
                Some(Ok(frame)) => {
                    if let Some(frame) = convert(&frame) {
                        return Poll::Ready(Ok(frame));
                    }
                }
                Some(Err(socketcan::Error::Can(_))) => {}
                Some(Err(socketcan::Error::Io(error))) => return Poll::Ready(Err(error)),
                None => return Poll::Ready(Err(std::io::ErrorKind::BrokenPipe.into())),
            }
        }
    }

    fn poll_send(&mut self, cx: &mut Context<'_>, frame: &CanFrame) -> Poll<std::io::Result<()>> {
        use futures_sink::Sink;
        let Some(frame) = convert::<socketcan::CanFrame>(frame) else { return Poll::Ready(Ok(())) };
        let io = |error: socketcan::Error| match error {
            socketcan::Error::Io(error) => error,
            socketcan::Error::Can(error) => std::io::Error::other(error),
        };
        std::task::ready!(Sink::poll_ready(Pin::new(&mut *self), cx)).map_err(io)?;
        match Sink::start_send(Pin::new(&mut *self), frame).map_err(io) {
            Err(error)
                if matches!(error.kind(), std::io::ErrorKind::WouldBlock) || error.raw_os_error() == Some(ENOBUFS) =>
            {
                cx.waker().wake_by_ref();
                Poll::Pending
            }
            sent => Poll::Ready(sent),
        }
    }

    fn may_echo(&self) -> bool {
        false
    }
}
