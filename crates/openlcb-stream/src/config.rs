//! [`Config`]: every bound and timer of a [`StreamEndpoint`](crate::StreamEndpoint).

use crate::Duration;
use crate::wire::ReplyCode;

/// What the destination does with an incoming Stream Initiate Request.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[non_exhaustive]
pub enum AcceptPolicy {
    /// Accept every well-formed request while there is room (an `Opened` event follows).
    AcceptAll,
    /// Refuse every request with this code (a node that has streams but takes none now).
    RejectAll(ReplyCode),
    /// Raise `Event::IncomingRequest` and wait for `accept` or `reject`; a request left
    /// undecided for [`Config::decision_timeout`] is refused with 0x2020 (buffer unavailable).
    Ask,
}

/// Bounds and timers. Every table and buffer the endpoint keeps is sized from here.
///
/// Memory bound of the destination side: `max_streams` receive buffers of at most
/// `max_window` bytes (twice that with `early_proceed`). The source side buffers nothing: a
/// write is turned into Data Send messages at once, up to the credit.
#[derive(Debug, Clone, PartialEq, Eq)]
#[non_exhaustive]
pub struct Config {
    /// Streams open at once, both roles, all peers (incoming requests awaiting a decision
    /// count too). A request over the bound gets Initiate Reply 0x2020.
    pub max_streams: usize,
    /// Streams open at once with any one peer, per role (at most 255: the stream ID space).
    pub max_streams_per_peer: usize,
    /// The largest window (Max Buffer Size) this node grants as a destination, 1..=65535.
    pub max_window: u16,
    /// As destination, send one Proceed ahead, as soon as the first byte of a window has
    /// arrived, so the source never idles waiting (draft §7.3 allows at most one early
    /// Proceed). The receive buffer is then two windows.
    pub early_proceed: bool,
    /// What to do with incoming requests.
    pub accept_policy: AcceptPolicy,
    /// As source, how long to wait for the Initiate Reply. The message network standard wants
    /// at least 3 s; OpenMRN waits 20 s, and so does this crate by default.
    ///
    /// This wait and the Proceed, first-data and idle waits below are waits for the peer.
    /// Each runs again from the peer's latest progress on another stream in the same role (a
    /// Proceed from it, even for a stream that has ended; data from it), and from the latest
    /// stream data the transport saw on a shared medium
    /// ([`StreamEndpoint::medium_busy`](crate::StreamEndpoint::medium_busy)): streams take
    /// turns, on one node and on a CAN bus, and a peer waiting for its turn is not silent.
    /// Once the peer and the medium are quiet, each runs out as configured.
    pub reply_timeout: Duration,
    /// As source, how long to wait for a Proceed when out of credit before terminating with
    /// TDE 0x2010. Default 30 s: bootloaders writing flash between windows needed that long.
    pub proceed_timeout: Duration,
    /// As source, send a zero-length Data Send (keep-alive, draft §7.3) when nothing was sent
    /// for this long while the stream has credit. `None` disables it. Default 15 s.
    pub keepalive_interval: Option<Duration>,
    /// As destination, terminate (TDE 0x2010) a stream whose source sent nothing for this long
    /// while it held credit (a source that reset or went silent). `None` disables it.
    /// Default 60 s, four keep-alive intervals.
    pub idle_timeout: Option<Duration>,
    /// As destination, the payload bytes a stream must bring (at most its window, or its
    /// whole credit) to count as progress. Progress starts the idle wait again, and keeps
    /// the waits of the peer's other streams going. Keep-alives and smaller trickles of data
    /// start it again too, except within `idle_timeout` of a request refused because every
    /// slot was taken: then a stream that brings less than this in `idle_timeout` is
    /// terminated, and its slot goes to whoever is waiting. Default 256 bytes.
    pub min_idle_progress: u16,
    /// As destination, terminate (TDE 0x2010) an accepted stream that has brought no payload
    /// byte for this long (never longer than `idle_timeout`). `None` leaves only the idle
    /// timeout. Default 15 s: a source sends its first data right after the Reply, or, with
    /// many streams, in its turn (which other streams' data and a busy bus prolong, see
    /// [`reply_timeout`](Self::reply_timeout)); a peer that opens streams and sends nothing
    /// on a quiet bus then holds receive slots for 15 s instead of the whole idle timeout
    /// (60 s). Keep-alives are not data: they keep a stream that has started alive, not one
    /// that never did.
    pub first_data_timeout: Option<Duration>,
    /// As destination, how long a Complete that states more bytes than have arrived waits
    /// for data still in flight before the stream ends with a count mismatch. In-flight data
    /// is at most the credit the source holds and is already on the wire, so the grace only
    /// covers reordering on CAN (a Complete out-arbitrates data frames) and gateway delays.
    /// Default 2 s.
    pub complete_grace: Duration,
    /// With [`AcceptPolicy::Ask`], how long a request may wait for the application's decision.
    /// Default 500 ms, inside the 750 ms the message network standard allows for a response.
    pub decision_timeout: Duration,
}

impl Default for Config {
    fn default() -> Self {
        Config {
            max_streams: 64,
            max_streams_per_peer: 16,
            max_window: 2048,
            early_proceed: true,
            accept_policy: AcceptPolicy::AcceptAll,
            reply_timeout: Duration::from_secs(20),
            proceed_timeout: Duration::from_secs(30),
            keepalive_interval: Some(Duration::from_secs(15)),
            idle_timeout: Some(Duration::from_secs(60)),
            min_idle_progress: 256,
            first_data_timeout: Some(Duration::from_secs(15)),
            complete_grace: Duration::from_secs(2),
            decision_timeout: Duration::from_millis(500),
        }
    }
}

impl Config {
    /// The most receive-buffer memory the destination side can hold, in bytes.
    pub fn receive_memory_bound(&self) -> usize {
        let per_stream = usize::from(self.max_window) * if self.early_proceed { 2 } else { 1 };
        per_stream.saturating_mul(self.max_streams)
    }
}
