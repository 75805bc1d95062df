//! Socket options the drivers and the hub set on every TCP connection.

use std::time::Duration;

use socket2::{SockRef, TcpKeepalive};

/// The largest TCP segment this crate's sockets send (and advertise), in bytes: Ethernet's.
///
/// Why: OpenMRN's `hub` shrinks `SO_RCVBUF` to 8192 on every client *after* accepting it, so
/// its receive window (about 16 KB) ends up below the segment size Linux picked on loopback
/// at the handshake (32 KB, half the 64 KB window seen then). A Linux sender whose unsent
/// data does not fit the window sends nothing while that window is smaller than one segment,
/// except one zero-window probe per retransmission timeout (about 200 ms): a window of
/// GridConnect text larger than 16 KB (stream windows of 4032 bytes and more) then moved at
/// about 20 kB/s, which looked like a stall. With segments no larger than this, any window of
/// at least one segment can always be filled. On Ethernet paths segments are this size
/// anyway; on loopback to `lcc-stream hub` the measured rate did not drop.
pub(crate) const SEGMENT_LIMIT: u32 = 1460;

/// TCP keep-alive on hub connections: the first probe after this much silence.
pub(crate) const KEEPALIVE_IDLE: Duration = Duration::from_secs(60);
/// Between keep-alive probes.
pub(crate) const KEEPALIVE_INTERVAL: Duration = Duration::from_secs(10);
/// Unanswered probes before the kernel gives the connection up.
pub(crate) const KEEPALIVE_RETRIES: u32 = 6;

/// Caps the segment size of a socket not yet connected or listening (see [`SEGMENT_LIMIT`]).
pub(crate) fn limit_segments(socket: &tokio::net::TcpSocket) -> std::io::Result<()> {
    SockRef::from(socket).set_tcp_mss(SEGMENT_LIMIT)
}

/// Turns TCP keep-alive on: a peer that vanished without a word (power cut, cable pulled)
/// is found within about two minutes even when nothing is being sent to it.
pub(crate) fn keep_alive(socket: &tokio::net::TcpStream) -> std::io::Result<()> {
    let keepalive =
        TcpKeepalive::new().with_time(KEEPALIVE_IDLE).with_interval(KEEPALIVE_INTERVAL).with_retries(KEEPALIVE_RETRIES);
    SockRef::from(socket).set_tcp_keepalive(&keepalive)
}
