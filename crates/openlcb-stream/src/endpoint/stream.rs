//! One stream's state: the fields both roles share, and the source or destination half.

use alloc::vec;
use alloc::vec::Vec;

use super::timer::TimerTable;
use crate::event::{Role, StreamInfo};
use crate::{ContentUid, NodeId, StreamId};

/// A stream in the endpoint's table.
#[derive(Debug)]
pub(crate) struct Stream {
    pub(crate) peer: NodeId,
    pub(crate) source_stream: StreamId,
    pub(crate) destination_stream: Option<StreamId>,
    /// Proposed Max Buffer Size until open, then the negotiated window.
    pub(crate) window: u16,
    pub(crate) content_uid: Option<ContentUid>,
    pub(crate) timers: TimerTable,
    pub(crate) half: Half,
}

/// The role-specific part.
#[derive(Debug)]
pub(crate) enum Half {
    Source(Source),
    Destination(Destination),
}

/// Source states. A source stream leaves the table as soon as it ends, so there is no
/// closed state.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum SourceState {
    /// Initiate Request sent (draft state "Initiated").
    AwaitingReply,
    /// Accepted (draft state "Open").
    Sending,
}

#[derive(Debug)]
pub(crate) struct Source {
    pub(crate) state: SourceState,
    /// Bytes the source may still send; never negative, grows by a window per Proceed.
    pub(crate) credit: u32,
    /// Payload bytes sent so far.
    pub(crate) sent: u64,
    /// Payload bytes sent into the current window (`sent` modulo the window, kept so that
    /// `write` needs no 64-bit division).
    pub(crate) window_sent: u32,
    /// A write came up short: raise `Writable` when credit returns.
    pub(crate) write_blocked: bool,
}

/// Destination states.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum DestinationState {
    /// Request received; the application decides ([`AcceptPolicy::Ask`](crate::AcceptPolicy)).
    AwaitingDecision,
    /// Accepted (draft state "Open").
    Receiving,
    /// Complete arrived before all the data it counted: wait for `expected` bytes in total.
    Draining { expected: u64 },
    /// Ended (finished, terminated or timed out); buffered data waits for the application.
    Closed,
}

#[derive(Debug)]
pub(crate) struct Destination {
    pub(crate) state: DestinationState,
    /// Received, not yet read: one window, or two with early Proceed.
    pub(crate) buffer: ByteRing,
    /// Total bytes the source has been allowed to send (a window per Proceed, plus the first).
    /// The 64-bit byte counts cannot overflow (2^64 bytes), so they add without saturating.
    pub(crate) granted: u64,
    /// Total payload bytes received.
    pub(crate) received: u64,
    pub(crate) early_proceed: bool,
}

impl Stream {
    pub(crate) fn role(&self) -> Role {
        match self.half {
            Half::Source(_) => Role::Source,
            Half::Destination(_) => Role::Destination,
        }
    }

    /// The ID this node assigned: SID as source, DID as destination.
    pub(crate) fn local_id(&self) -> Option<StreamId> {
        match self.half {
            Half::Source(_) => Some(self.source_stream),
            Half::Destination(_) => self.destination_stream,
        }
    }

    /// A destination that has ended and only waits for its data to be read.
    pub(crate) fn is_closed(&self) -> bool {
        matches!(&self.half, Half::Destination(d) if d.state == DestinationState::Closed)
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
}

impl Destination {
    pub(crate) fn new(window: u16, early_proceed: bool) -> Self {
        let capacity = usize::from(window) * if early_proceed { 2 } else { 1 };
        Destination {
            state: DestinationState::Receiving,
            buffer: ByteRing::new(capacity),
            granted: u64::from(window),
            received: 0,
            early_proceed,
        }
    }

    /// A pending request has no buffer yet.
    pub(crate) fn pending() -> Self {
        Destination {
            state: DestinationState::AwaitingDecision,
            buffer: ByteRing::new(0),
            granted: 0,
            received: 0,
            early_proceed: false,
        }
    }

    /// Credit the source still holds.
    pub(crate) fn outstanding(&self) -> u64 {
        self.granted.saturating_sub(self.received)
    }

    pub(crate) fn free_space(&self) -> usize {
        self.buffer.free()
    }

    /// Draft §7.3: a Proceed grants one more window. Without early Proceed it goes once the
    /// current window has fully arrived; with it, one window ahead as soon as the first byte
    /// of the current window is in. Either way only while the buffer can hold everything the
    /// source could then send: this is where a slow reader slows the source.
    pub(crate) fn proceed_due(&self, window: u16) -> bool {
        if self.state != DestinationState::Receiving {
            return false;
        }
        let window = u64::from(window);
        let outstanding = self.outstanding();
        let due = if self.early_proceed { outstanding < window } else { outstanding == 0 };
        let room = self.free_space() as u64;
        due && room >= outstanding + window
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
