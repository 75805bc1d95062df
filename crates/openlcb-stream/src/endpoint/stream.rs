//! One slot of the stream table: a stream of either role, or nothing.
//!
//! The fields are flat: one state byte says which role and where in its life the stream is,
//! and the fields both roles need (the credit, the byte count) are shared, so that the code
//! never matches on a role-specific half.

use alloc::vec;
use alloc::vec::Vec;

use crate::event::{Role, StreamInfo};
use crate::{ContentUid, Instant, NodeId, StreamId};

/// Where a stream is in its life; the role follows from it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum State {
    /// The slot holds no stream.
    Free,
    /// Source: Initiate Request sent (draft state "Initiated").
    AwaitingReply,
    /// Source: accepted (draft state "Open").
    Sending,
    /// Destination: request received; the application decides
    /// ([`AcceptPolicy::Ask`](crate::AcceptPolicy)).
    AwaitingDecision,
    /// Destination: accepted (draft state "Open").
    Receiving,
    /// Destination: Complete arrived before all the data it counted: wait for `expected`
    /// bytes in total.
    Draining,
    /// Destination: ended (finished, terminated or timed out); buffered data waits for the
    /// application. A source stream leaves the table as soon as it ends.
    Closed,
}

/// The deadline of a wait that is not running (the end of time: 584 000 years on).
pub(crate) const NEVER: Instant = Instant::from_micros(u64::MAX);

/// The latest time a wait can come due: just before [`NEVER`].
pub(crate) const LAST: Instant = Instant::from_micros(u64::MAX - 1);

/// The states of a source stream (a bit each, see [`State::bit`]): waiting for its Reply, or
/// sending.
pub(crate) const SOURCE: u8 = State::AwaitingReply.bit() | State::Sending.bit();
/// The states of a destination stream that is not over yet.
pub(crate) const LIVE_DESTINATION: u8 = State::AwaitingDecision.bit() | State::Receiving.bit() | State::Draining.bit();

impl State {
    /// The state's bit in a set of states.
    pub(crate) const fn bit(self) -> u8 {
        1 << self as u8
    }

    /// The role of a stream in this state (a free slot's is meaningless).
    pub(crate) fn role(self) -> Role {
        match self {
            State::AwaitingReply | State::Sending => Role::Source,
            _ => Role::Destination,
        }
    }
}

/// A slot of the endpoint's table. Each state has at most one wait running, in `deadline`:
/// the Reply (`AwaitingReply`), a Proceed while out of credit (`Sending`), the application's
/// decision (`AwaitingDecision`), the source's silence while it holds credit (`Receiving`),
/// the grace for data still in flight (`Draining`). A sending source also keeps alive.
///
/// The fields stay in the order written (`repr(C)`): the small ones read at every message
/// come first, where Thumb's short loads and stores reach them (this saves about 170 bytes of
/// flash on a Cortex-M3).
#[derive(Debug)]
#[repr(C)]
pub(crate) struct Stream {
    pub(crate) state: State,
    pub(crate) source_stream: StreamId,
    pub(crate) destination_stream: Option<StreamId>,
    /// Source: a write came up short: raise `Writable` when credit returns.
    pub(crate) write_blocked: bool,
    /// Destination: one Proceed goes ahead of the data.
    pub(crate) early_proceed: bool,
    /// Proposed Max Buffer Size until open, then the negotiated window.
    pub(crate) window: u16,
    /// Bumped when the slot is freed, so that old handles no longer match.
    pub(crate) generation: u16,
    /// Bytes the source may still send before the next Proceed: the same figure at both
    /// ends (grows by a window per Proceed; at the destination, once the Proceed is handed
    /// to the transport: a source cannot have seen it before).
    pub(crate) credit: u32,
    /// Destination: Proceeds queued and not yet handed to the transport.
    pub(crate) proceeds_queued: u8,
    /// Source: payload bytes sent into the current window (`count` modulo the window, kept so
    /// that `write` needs no 64-bit division).
    pub(crate) window_sent: u32,
    /// Destination: received, not yet read (one window, or two with early Proceed).
    pub(crate) buffer: ByteRing,
    pub(crate) peer: NodeId,
    pub(crate) content_uid: Option<ContentUid>,
    /// When the wait of the current state runs out.
    pub(crate) deadline: Instant,
    /// Source: when to send the next keep-alive.
    pub(crate) keepalive: Instant,
    /// When the peer last showed progress on this stream: data arrived (destination) or a
    /// Proceed did (source); `Instant::ZERO` until then. The peer's progress on any of its
    /// streams in a role keeps the waits of the others in that role going.
    pub(crate) heard: Instant,
    /// Payload bytes sent (source) or received (destination) so far. 64 bits cannot
    /// overflow, so it adds without saturating.
    pub(crate) count: u64,
    /// Destination, draining: the byte count the Complete stated.
    pub(crate) expected: u64,
    /// Destination: the `count` that will be progress for the idle wait (see
    /// [`Stream::mark_progress`]).
    pub(crate) progress_at: u64,
}

impl Stream {
    /// An empty slot.
    pub(crate) fn free() -> Self {
        Stream {
            generation: 0,
            state: State::Free,
            peer: NodeId::default(),
            source_stream: StreamId::MIN,
            destination_stream: None,
            window: 0,
            content_uid: None,
            deadline: NEVER,
            keepalive: NEVER,
            heard: Instant::ZERO,
            credit: 0,
            proceeds_queued: 0,
            count: 0,
            window_sent: 0,
            expected: 0,
            progress_at: 0,
            write_blocked: false,
            early_proceed: false,
            buffer: ByteRing::new(0),
        }
    }

    /// Frees the slot: every field back to empty, the receive buffer released, the
    /// generation on.
    pub(crate) fn release(&mut self) {
        let generation = self.generation.wrapping_add(1);
        *self = Stream::free();
        self.generation = generation;
    }

    pub(crate) fn is_live(&self) -> bool {
        self.state != State::Free
    }

    pub(crate) fn role(&self) -> Role {
        self.state.role()
    }

    /// A stream in the table with `peer` in `role` under the ID this node assigned, `id`.
    pub(crate) fn is(&self, peer: NodeId, role: Role, id: StreamId) -> bool {
        self.is_with(peer, role) && self.assigned(role) == Some(id)
    }

    /// A stream in the table with `peer` in `role`.
    pub(crate) fn is_with(&self, peer: NodeId, role: Role) -> bool {
        let states = match role {
            Role::Source => SOURCE,
            Role::Destination => LIVE_DESTINATION | State::Closed.bit(),
        };
        states & self.state.bit() != 0 && self.peer == peer
    }

    /// The ID this node assigned: SID as source, DID as destination.
    pub(crate) fn local_id(&self) -> Option<StreamId> {
        self.assigned(self.role())
    }

    /// The ID this node assigns to a stream in `role`: the SID as source, the DID as
    /// destination.
    fn assigned(&self, role: Role) -> Option<StreamId> {
        match role {
            Role::Source => Some(self.source_stream),
            Role::Destination => self.destination_stream,
        }
    }

    /// A destination that has ended and only waits for its data to be read.
    pub(crate) fn is_closed(&self) -> bool {
        self.state == State::Closed
    }

    /// Stops every wait.
    pub(crate) fn stop_timers(&mut self) {
        self.deadline = NEVER;
        self.keepalive = NEVER;
    }

    pub(crate) fn info(&self) -> StreamInfo {
        StreamInfo {
            peer: self.peer,
            role: self.role(),
            source_stream: self.source_stream,
            destination_stream: self.destination_stream,
            window: self.window,
            content_uid: self.content_uid,
        }
    }

    /// Destination: the idle wait starts again for progress here: `min_progress` more bytes
    /// (at most a window) are progress.
    #[inline(never)]
    pub(crate) fn mark_progress(&mut self, min_progress: u16) {
        self.progress_at = self.count + u64::from(min_progress.min(self.window).max(1));
    }

    /// Destination: accepted with `window`; the receive buffer is allocated here.
    pub(crate) fn open_destination(&mut self, window: u16, early_proceed: bool) {
        let capacity = usize::from(window) * if early_proceed { 2 } else { 1 };
        self.state = State::Receiving;
        self.window = window;
        self.buffer = ByteRing::new(capacity);
        self.credit = u32::from(window);
        self.proceeds_queued = 0;
        self.early_proceed = early_proceed;
    }

    /// Destination: what the source may send once every queued Proceed has gone.
    pub(crate) fn granted(&self) -> u32 {
        self.credit + u32::from(self.proceeds_queued) * u32::from(self.window)
    }

    /// Draft §7.3: a Proceed grants one more window. Without early Proceed it goes once the
    /// current window has fully arrived; with it, one window ahead as soon as the first byte
    /// of the current window is in. Either way only while the buffer can hold everything the
    /// source could then send: this is where a slow reader slows the source.
    pub(crate) fn proceed_due(&self) -> bool {
        if self.state != State::Receiving {
            return false;
        }
        let (window, granted) = (u32::from(self.window), self.granted());
        let due = if self.early_proceed { granted < window } else { granted == 0 };
        due && self.buffer.free() as u32 >= granted + window
    }
}

/// A destination's receive buffer: a ring of bytes of fixed capacity, allocated at accept.
/// Data goes in and out in at most two slice copies.
#[derive(Debug)]
pub(crate) struct ByteRing {
    bytes: Vec<u8>,
    head: usize,
    len: usize,
}

impl ByteRing {
    pub(crate) fn new(capacity: usize) -> Self {
        ByteRing { bytes: vec![0; capacity], head: 0, len: 0 }
    }

    pub(crate) fn len(&self) -> usize {
        self.len
    }

    pub(crate) fn is_empty(&self) -> bool {
        self.len == 0
    }

    pub(crate) fn capacity(&self) -> usize {
        self.bytes.len()
    }

    pub(crate) fn free(&self) -> usize {
        self.bytes.len() - self.len
    }

    /// `index` taken round the ring once (`index` < 2 × capacity; no division).
    fn wrap(&self, index: usize) -> usize {
        if index >= self.bytes.len() { index - self.bytes.len() } else { index }
    }

    /// Appends as much of `data` as fits; returns how much that was.
    pub(crate) fn push(&mut self, data: &[u8]) -> usize {
        let n = data.len().min(self.free());
        let tail = self.wrap(self.head + self.len);
        let first = n.min(self.bytes.len() - tail);
        copy(self.bytes.get_mut(tail..tail + first), data.get(..first));
        if first < n {
            copy(self.bytes.get_mut(..n - first), data.get(first..n));
        }
        self.len += n;
        n
    }

    /// Moves the oldest bytes into `to`; returns how many.
    pub(crate) fn pop(&mut self, to: &mut [u8]) -> usize {
        let n = to.len().min(self.len);
        let first = n.min(self.bytes.len() - self.head);
        copy(to.get_mut(..first), self.bytes.get(self.head..self.head + first));
        if first < n {
            copy(to.get_mut(first..n), self.bytes.get(..n - first));
        }
        self.head = self.wrap(self.head + n);
        self.len -= n;
        n
    }
}

fn copy(to: Option<&mut [u8]>, from: Option<&[u8]>) {
    if let (Some(to), Some(from)) = (to, from) {
        to.copy_from_slice(from);
    }
}

#[cfg(test)]
mod tests {
    use super::ByteRing;

    #[test]
    fn byte_ring_keeps_order_across_the_wrap_and_never_exceeds_its_capacity() {
        let mut ring = ByteRing::new(7);
        let mut next_in = 0u8;
        let mut next_out = 0u8;
        for round in 0..50usize {
            let data: [u8; 5] = core::array::from_fn(|i| next_in.wrapping_add(i as u8));
            let taken = ring.push(&data[..round % 6]);
            next_in = next_in.wrapping_add(taken as u8);
            assert!(ring.len() <= ring.capacity());
            let mut out = [0u8; 4];
            let n = ring.pop(&mut out[..round % 5]);
            for byte in &out[..n] {
                assert_eq!(*byte, next_out);
                next_out = next_out.wrapping_add(1);
            }
            assert_eq!(ring.free(), 7 - ring.len());
        }
        assert!(next_out > 50, "data went through");
        let mut empty = ByteRing::new(0);
        assert_eq!(empty.push(&[1, 2]), 0);
        assert_eq!(empty.pop(&mut [0; 2]), 0);
    }
}
