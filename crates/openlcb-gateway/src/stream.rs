//! The state the gateway keeps for one stream that crosses it.

use alloc::vec::Vec;

use openlcb_stream::wire::CompleteCount;
use openlcb_stream::{Instant, StreamId};

use crate::{Side, StreamKey};

/// The longest Complete payload kept (form D, wire-spec §4.5); longer tails carry nothing.
pub(crate) const COMPLETE_MAX_LEN: usize = 7;

/// Where a tracked stream stands.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Phase {
    /// The Request went through; no Reply yet.
    Requested {
        /// The Max Buffer Size forwarded (after lowering).
        proposed: u16,
    },
    /// The destination accepted.
    Open {
        /// The destination's stream ID.
        destination_stream: StreamId,
        /// The negotiated window, as the Reply carried it.
        window: u16,
        /// The most this stream may hold in the gateway: the window, or the forwarded
        /// proposal if a Reply granted more than was asked.
        bound: u16,
    },
}

/// A Complete held until the stream's buffer has drained.
#[derive(Debug, Clone)]
pub(crate) struct HeldComplete {
    /// The payload as received (at most [`COMPLETE_MAX_LEN`] bytes).
    pub(crate) payload: Vec<u8>,
    /// The count the source stated.
    pub(crate) count: CompleteCount,
    /// When to forward it even if the data it counts has not all arrived.
    pub(crate) deadline: Instant,
}

/// One tracked stream.
#[derive(Debug)]
pub(crate) struct Tracked {
    pub(crate) key: StreamKey,
    /// The side the source (and its data) is on.
    pub(crate) source_side: Side,
    pub(crate) phase: Phase,
    /// Source on CAN: the merge buffer, DID first, then the payload bytes not yet forwarded.
    pub(crate) merge: Vec<u8>,
    /// When the merge buffer must be forwarded at the latest.
    pub(crate) merge_deadline: Option<Instant>,
    /// Source on the full-format side: payload bytes queued for CAN, not yet sent as frames.
    pub(crate) queued: usize,
    /// Payload bytes received from the source.
    pub(crate) received: u64,
    /// Proceeds forwarded to the source.
    pub(crate) proceeds_released: u64,
    /// Proceeds held for the source.
    pub(crate) proceeds_held: u32,
    /// Proceeds received from the destination.
    pub(crate) proceeds_seen: u64,
    /// The destination sends Proceeds ahead (draft §7.3): one came before the window it
    /// follows had all passed the gateway.
    pub(crate) destination_proceeds_early: bool,
    /// A flush (zero-length Data Send) waits for the buffer to drain.
    pub(crate) flush_pending: bool,
    /// The Complete, held.
    pub(crate) complete: Option<HeldComplete>,
    /// The last message of this stream seen.
    pub(crate) last_activity: Instant,
}

impl Tracked {
    pub(crate) fn requested(now: Instant, key: StreamKey, source_side: Side, proposed: u16) -> Self {
        Tracked {
            key,
            source_side,
            phase: Phase::Requested { proposed },
            merge: Vec::new(),
            merge_deadline: None,
            queued: 0,
            received: 0,
            proceeds_released: 0,
            proceeds_held: 0,
            proceeds_seen: 0,
            destination_proceeds_early: false,
            flush_pending: false,
            complete: None,
            last_activity: now,
        }
    }

    /// The destination's stream ID once open.
    pub(crate) fn destination_stream(&self) -> Option<StreamId> {
        match self.phase {
            Phase::Open { destination_stream, .. } => Some(destination_stream),
            Phase::Requested { .. } => None,
        }
    }

    /// The negotiated window (1 at least) once open.
    pub(crate) fn window(&self) -> u64 {
        match self.phase {
            Phase::Open { window, .. } => u64::from(window.max(1)),
            Phase::Requested { proposed } => u64::from(proposed.max(1)),
        }
    }

    /// The buffer bound once open.
    pub(crate) fn bound(&self) -> usize {
        match self.phase {
            Phase::Open { bound, .. } => usize::from(bound.max(1)),
            Phase::Requested { .. } => 0,
        }
    }

    /// Payload bytes the gateway holds for this stream.
    pub(crate) fn buffered(&self) -> usize {
        self.merge.len().saturating_sub(1).saturating_add(self.queued)
    }

    /// Payload bytes that fit before the next window boundary (counted from the stream start,
    /// modulo the negotiated window).
    pub(crate) fn to_window_boundary(&self) -> u64 {
        let window = self.window();
        window - self.received % window
    }

    /// A Proceed may go to the source: the buffer is empty (draft §7.5) and, for a source on
    /// the full-format side, the credit it holds as far as the gateway has seen is used up.
    /// Data for CAN waits in the gateway until the bus takes it, so a Proceed released
    /// earlier would let the source put up to two windows into the buffer (draft §7.3 allows
    /// one Proceed ahead). Data from CAN never piles up: the merge buffer is forwarded at
    /// every window boundary, so early Proceeds pass as soon as it is empty.
    pub(crate) fn proceed_releasable(&self) -> bool {
        if self.buffered() > 0 {
            return false;
        }
        let granted = self.window().saturating_mul(self.proceeds_released.saturating_add(1));
        self.source_side == Side::Can || self.received >= granted
    }

    /// Counts a Proceed from the destination and notes whether it came ahead of its window.
    pub(crate) fn proceed_seen(&mut self) {
        self.proceeds_seen = self.proceeds_seen.saturating_add(1);
        if self.received < self.window().saturating_mul(self.proceeds_seen) {
            self.destination_proceeds_early = true;
        }
    }

    /// A held Complete from CAN still waits for data it counts that has not arrived (the
    /// Complete out-arbitrated the last data frames, wire-spec §6.3 note).
    pub(crate) fn awaits_overtaken_data(&self, now: Instant) -> bool {
        let Some(complete) = &self.complete else { return false };
        if self.source_side != Side::Can || now >= complete.deadline {
            return false;
        }
        // Counts are modular: a large gap is a count from some other reckoning, not data in
        // flight (at most two windows can be outstanding).
        complete.count.missing_after(self.received).is_some_and(|missing| missing != 0 && missing <= 2 * self.window())
    }
}

#[cfg(test)]
mod tests {
    use openlcb_stream::{Duration, NodeId};

    use super::*;

    fn open_stream(window: u16, source_side: Side) -> Tracked {
        let key = StreamKey {
            source: NodeId::new(1).unwrap(),
            destination: NodeId::new(2).unwrap(),
            source_stream: StreamId::new(4).unwrap(),
        };
        let mut stream = Tracked::requested(Instant::ZERO, key, source_side, window);
        stream.phase = Phase::Open { destination_stream: StreamId::new(7).unwrap(), window, bound: window };
        stream
    }

    #[test]
    fn window_boundaries_count_from_the_stream_start() {
        let mut stream = open_stream(100, Side::Can);
        assert_eq!(stream.to_window_boundary(), 100);
        stream.received = 250;
        assert_eq!(stream.to_window_boundary(), 50);
        stream.received = 300;
        assert_eq!(stream.to_window_boundary(), 100);
    }

    #[test]
    fn proceed_waits_for_an_empty_buffer_and_used_credit() {
        let mut stream = open_stream(100, Side::Full);
        stream.received = 60;
        assert!(!stream.proceed_releasable(), "the source still holds 40 bytes of credit");
        stream.received = 100;
        stream.queued = 1;
        assert!(!stream.proceed_releasable(), "one byte still waits for the bus");
        stream.queued = 0;
        assert!(stream.proceed_releasable());
        stream.proceeds_released = 1;
        assert!(!stream.proceed_releasable(), "the next one needs the second window used");
        stream.received = 200;
        assert!(stream.proceed_releasable());
    }

    #[test]
    fn proceed_to_a_can_source_waits_only_for_the_merge_buffer() {
        let mut stream = open_stream(100, Side::Can);
        stream.received = 10;
        assert!(stream.proceed_releasable(), "an early Proceed passes while nothing is buffered");
        stream.merge = vec![7, 1, 2, 3];
        assert!(!stream.proceed_releasable());
    }

    #[test]
    fn complete_from_can_waits_only_for_data_in_flight() {
        let mut stream = open_stream(100, Side::Can);
        let held = |count| HeldComplete { payload: Vec::new(), count, deadline: Instant::from_millis(1000) };
        stream.received = 90;
        stream.complete = Some(held(CompleteCount::Total(100)));
        assert!(stream.awaits_overtaken_data(Instant::ZERO));
        assert!(!stream.awaits_overtaken_data(Instant::ZERO + Duration::from_secs(1)), "not past the deadline");
        stream.received = 100;
        assert!(!stream.awaits_overtaken_data(Instant::ZERO));
        stream.complete = Some(held(CompleteCount::Total(100_000)));
        assert!(!stream.awaits_overtaken_data(Instant::ZERO), "more than two windows off: not in flight");
        stream.complete = Some(held(CompleteCount::Unknown));
        assert!(!stream.awaits_overtaken_data(Instant::ZERO));
        stream.received = 0x0100_0000 + 10;
        stream.complete = Some(held(CompleteCount::Modulo24(20)));
        assert!(stream.awaits_overtaken_data(Instant::ZERO), "counted modulo 2^24");
    }
}
