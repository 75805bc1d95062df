//! Reassembly of addressed multi-frame messages (wire-spec §7.2) and of datagrams
//! (node-protocols §2.5) in a bounded number of slots.

use alloc::vec::Vec;

use openlcb_stream::wire::ErrorCode;
use openlcb_stream::{Duration, Instant, Mti};

use crate::fragment::FramePosition;
use crate::{NodeAlias, bump, earlier};

/// The longest datagram payload, in bytes (DG §7.3.2; node-protocols §2.1).
pub const MAX_DATAGRAM_LEN: usize = 72;

/// What one message under assembly is keyed by: (source alias, destination alias, MTI). For
/// datagrams the MTI is always [`Mti::DATAGRAM`], so the key is (source, destination), as DG
/// §7.2 asks.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct ReassemblyKey {
    /// The sender.
    pub source: NodeAlias,
    /// The addressed node.
    pub destination: NodeAlias,
    /// The message type.
    pub mti: Mti,
}

/// A frame that could not be reassembled (MN §3.5.5 codes where the standard has one).
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
pub enum ReassemblyError {
    /// A middle or last frame with no first frame before it (0x2041). The frame is dropped.
    #[error("middle or last frame without a first frame")]
    MiddleWithoutFirst,
    /// A first frame while a message with the same key was still open (0x2042). The old
    /// message is dropped; for an addressed message the new frame starts a new message, for a
    /// datagram it is dropped too (see [`Reassembler::for_datagrams`]).
    #[error("first frame before the previous message ended")]
    FirstBeforeLastEnded,
    /// No last frame came within the timeout (0x2011). The message is dropped.
    #[error("timeout waiting for the last frame")]
    Timeout,
    /// The message grew beyond the configured maximum length (0x2020; 0x1000 for a datagram
    /// over 72 bytes, which no resend can fix). It is dropped.
    #[error("message longer than the reassembly buffer")]
    TooLong,
    /// Every slot holds a message (0x2020). The first frame is dropped.
    #[error("no free reassembly slot")]
    NoFreeSlot,
}

impl ReassemblyError {
    /// The Message Network error code for an OIR answering this error.
    pub const fn code(self) -> ErrorCode {
        match self {
            ReassemblyError::MiddleWithoutFirst => ErrorCode(0x2041),
            ReassemblyError::FirstBeforeLastEnded => ErrorCode(0x2042),
            ReassemblyError::Timeout => ErrorCode(0x2011),
            ReassemblyError::TooLong | ReassemblyError::NoFreeSlot => ErrorCode::BUFFER_UNAVAILABLE,
        }
    }

    /// The code of the Datagram Rejected answering this error (node-protocols §2.5): as
    /// [`code`](Self::code), except that a datagram over 72 bytes is permanent 0x1000 (what
    /// OpenMRN sends: resending the same datagram cannot help).
    pub const fn datagram_code(self) -> ErrorCode {
        match self {
            ReassemblyError::TooLong => ErrorCode(0x1000),
            other => other.code(),
        }
    }
}

/// Reassembly errors by kind, for the counters of the link and the gateway. Each counter
/// stops at `u32::MAX`.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
#[non_exhaustive]
pub struct ReassemblyErrorCounts {
    /// [`ReassemblyError::MiddleWithoutFirst`] (0x2041).
    pub middle_without_first: u32,
    /// [`ReassemblyError::FirstBeforeLastEnded`] (0x2042).
    pub first_before_last_ended: u32,
    /// [`ReassemblyError::Timeout`] (0x2011).
    pub timeouts: u32,
    /// [`ReassemblyError::TooLong`].
    pub too_long: u32,
    /// [`ReassemblyError::NoFreeSlot`] (0x2020).
    pub no_free_slot: u32,
}

impl ReassemblyErrorCounts {
    /// Counts one `error`.
    pub fn record(&mut self, error: ReassemblyError) {
        let counter = match error {
            ReassemblyError::MiddleWithoutFirst => &mut self.middle_without_first,
            ReassemblyError::FirstBeforeLastEnded => &mut self.first_before_last_ended,
            ReassemblyError::Timeout => &mut self.timeouts,
            ReassemblyError::TooLong => &mut self.too_long,
            ReassemblyError::NoFreeSlot => &mut self.no_free_slot,
        };
        bump(counter);
    }

    /// All errors counted.
    pub fn total(&self) -> u64 {
        [self.middle_without_first, self.first_before_last_ended, self.timeouts, self.too_long, self.no_free_slot]
            .into_iter()
            .map(u64::from)
            .sum()
    }
}

/// What a [`Reassembler`] assembles: the rules differ where the standards differ.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Rules {
    /// Addressed format 1 messages: a second first frame restarts the message; the wait
    /// restarts with every frame.
    Messages,
    /// Datagrams: a second first frame drops both; the wait runs from the first frame.
    Datagrams,
}

#[derive(Debug)]
#[repr(C)] // Fields in the order written: short Thumb loads reach the ones read first.
struct Slot {
    key: Option<ReassemblyKey>,
    buffer: Vec<u8>,
    deadline: Instant,
}

/// Datagrams answered with an error and still arriving, remembered per reassembly slot: a
/// crowd of senders refused at once (all slots taken) is answered at once; beyond that many,
/// each is answered at its last frame instead (see [`Reassembler::for_datagrams`]).
const ANSWERED_PER_SLOT: usize = 16;

/// Bounded reassembly: `slots` messages at once, each at most `max_len` payload bytes, each
/// dropped when it is not complete within `timeout`. All memory is taken up front:
/// [`allocated`](Self::allocated) never changes.
#[derive(Debug)]
pub struct Reassembler {
    slots: Vec<Slot>,
    max_len: usize,
    timeout: Duration,
    rules: Rules,
    /// Datagrams already answered with an error whose remaining frames are still coming:
    /// dropped without a word until their last frame, so that each datagram gets one answer
    /// (DG §7.3.2). At most [`ANSWERED_PER_SLOT`] per slot: none is forgotten before its
    /// last frame, or that frame would be answered a second time.
    answered: Vec<ReassemblyKey>,
}

impl Reassembler {
    /// Addressed multi-frame messages: `slots` slots of `max_len` bytes each; a message is
    /// dropped when no frame of it arrived for `timeout`.
    pub fn new(slots: usize, max_len: usize, timeout: Duration) -> Self {
        Self::with_rules(slots, max_len, timeout, Rules::Messages)
    }

    /// Datagrams (node-protocols §2.5): `slots` datagrams of at most [`MAX_DATAGRAM_LEN`]
    /// bytes, keyed by (source, destination) with [`Mti::DATAGRAM`] in the key. Two rules
    /// differ from [`new`](Self::new):
    ///
    /// - A first frame while a datagram from the same source is open drops **both** the
    ///   partial datagram and the new first frame ([`ReassemblyError::FirstBeforeLastEnded`],
    ///   answered with the temporary 0x2042). Datagram Rejected carries no identifier and
    ///   only one datagram may be outstanding per pair (DG §6.1), so the sender takes 0x2042
    ///   as the answer to the datagram it is sending now and resends it; had the new first
    ///   frame been kept, that datagram would arrive twice.
    /// - The wait runs from the first frame, not from the latest one: 72 bytes take at most
    ///   nine frames, and a stream of empty middle frames cannot hold a slot for ever.
    ///
    /// A datagram gets exactly one answer. An error before its last frame is answered at once
    /// when it can be remembered (its later frames then go without a word); when the record
    /// is full it is not answered then, and its last frame is answered as that of a datagram
    /// whose first frame never came (0x2041), however many senders crowd in.
    pub fn for_datagrams(slots: usize, timeout: Duration) -> Self {
        Self::with_rules(slots, MAX_DATAGRAM_LEN, timeout, Rules::Datagrams)
    }

    fn with_rules(slots: usize, max_len: usize, timeout: Duration, rules: Rules) -> Self {
        let mut list = Vec::with_capacity(slots);
        // Within the capacity just allocated: no grow path.
        while list.len() < slots && list.len() < list.capacity() {
            list.push(Slot { key: None, buffer: Vec::with_capacity(max_len), deadline: Instant::ZERO });
        }
        let answered =
            Vec::with_capacity(if rules == Rules::Datagrams { slots.saturating_mul(ANSWERED_PER_SLOT) } else { 0 });
        Reassembler { slots: list, max_len, timeout, rules, answered }
    }

    /// Adds one frame's payload (data bytes 2..). Returns the whole payload when `position`
    /// ends a message; `Ok(None)` while it is still open. An `Only` frame is returned as is.
    pub fn push<'a>(
        &'a mut self,
        now: Instant,
        key: ReassemblyKey,
        position: FramePosition,
        data: &'a [u8],
    ) -> Result<Option<&'a [u8]>, ReassemblyError> {
        if position == FramePosition::Only {
            return Ok(Some(data));
        }
        let whole = self.add(now, key, position, data)?;
        Ok(whole.map(|slot| self.completed(slot)))
    }

    /// [`push`](Self::push) for a frame other than `Only`: the slot holding the whole payload
    /// once `position` ends the message (see [`completed`](Self::completed)).
    pub(crate) fn add(
        &mut self,
        now: Instant,
        key: ReassemblyKey,
        position: FramePosition,
        data: &[u8],
    ) -> Result<Option<usize>, ReassemblyError> {
        let result = self.add_frame(now, key, position, data);
        if self.rules == Rules::Datagrams {
            match result {
                // The rest of a datagram already answered: dropped without a second answer.
                Err(ReassemblyError::MiddleWithoutFirst) if self.unmute(key, position) => return Ok(None),
                // A datagram whose first frame never came is answered once, at its last.
                Err(ReassemblyError::MiddleWithoutFirst) if position == FramePosition::Middle => return Ok(None),
                Err(_) if position != FramePosition::Last && !self.mute(key) => return Ok(None),
                _ => {}
            }
        }
        result
    }

    /// A datagram's error is answered now: its later frames are dropped without a word.
    /// `false` when the record is full: then it is not answered now (its last frame is).
    fn mute(&mut self, key: ReassemblyKey) -> bool {
        if self.answered_at(key).is_some() {
            return true;
        }
        if self.answered.len() >= self.answered.capacity() {
            return false;
        }
        self.answered.push(key);
        true
    }

    /// A frame of the datagram `key` that was already answered: true if so (its last frame
    /// ends the silence).
    fn unmute(&mut self, key: ReassemblyKey, position: FramePosition) -> bool {
        if position == FramePosition::Last { self.forget_answer(key) } else { self.answered_at(key).is_some() }
    }

    /// Where the datagram `key` is in the record of those answered (once at most).
    fn answered_at(&self, key: ReassemblyKey) -> Option<usize> {
        self.answered.iter().position(|k| *k == key)
    }

    /// Forgets that the datagram `key` was answered (it is recorded once at most); true if it
    /// was.
    fn forget_answer(&mut self, key: ReassemblyKey) -> bool {
        let Some(index) = self.answered_at(key) else { return false };
        // The record is a set: its order does not matter.
        self.answered.swap_remove(index);
        true
    }

    fn add_frame(
        &mut self,
        now: Instant,
        key: ReassemblyKey,
        position: FramePosition,
        data: &[u8],
    ) -> Result<Option<usize>, ReassemblyError> {
        let first = position == FramePosition::First;
        if first {
            // A new datagram: whatever was answered before is over.
            self.forget_answer(key);
        }
        let open = self.slots.iter().position(|s| s.key.is_some_and(|k| k == key));
        let index = match open {
            Some(index) => index,
            None if first => self.slots.iter().position(|s| s.key.is_none()).ok_or(ReassemblyError::NoFreeSlot)?,
            None => return Err(ReassemblyError::MiddleWithoutFirst),
        };
        let slot = self.slots.get_mut(index).ok_or(ReassemblyError::NoFreeSlot)?;
        let restarted = first && open.is_some();
        if restarted && self.rules == Rules::Datagrams {
            slot.key = None;
            return Err(ReassemblyError::FirstBeforeLastEnded);
        }
        if first {
            slot.key = Some(key);
            slot.buffer.clear();
        }
        if first || self.rules == Rules::Messages {
            slot.deadline = now + self.timeout;
        }
        append(slot, data, self.max_len)?;
        if restarted {
            Err(ReassemblyError::FirstBeforeLastEnded)
        } else if position == FramePosition::Last {
            slot.key = None;
            Ok(Some(index))
        } else {
            Ok(None)
        }
    }

    /// The message [`add`](Self::add) completed in `slot`: it stays there until the next frame
    /// is added.
    pub(crate) fn completed(&self, slot: usize) -> &[u8] {
        self.slots.get(slot).map_or(&[], |s| s.buffer.as_slice())
    }

    /// The key of one message whose wait ran out at `now` (it is dropped), if any. Call until
    /// `None`.
    pub fn take_expired(&mut self, now: Instant) -> Option<ReassemblyKey> {
        loop {
            let slot = self.slots.iter_mut().find(|s| s.key.is_some() && s.deadline <= now)?;
            let key = slot.key.take()?;
            // Answered with 0x2011 when remembered: frames that come late are not answered
            // again. Otherwise dropped unanswered: its last frame is answered.
            if self.rules != Rules::Datagrams || self.mute(key) {
                return Some(key);
            }
        }
    }

    /// When the next open message times out.
    pub fn poll_timeout(&self) -> Option<Instant> {
        let mut next = None;
        self.earliest_into(&mut next);
        next
    }

    /// Moves `next` to the time the next open message times out, if that is earlier.
    pub(crate) fn earliest_into(&self, next: &mut Option<Instant>) {
        for slot in &self.slots {
            earlier(next, slot.key.map(|_| slot.deadline));
        }
    }

    /// Drops the open message with `key`, if there is one; true if there was.
    pub fn discard(&mut self, key: ReassemblyKey) -> bool {
        let open = self.slots.iter_mut().find(|s| s.key.is_some_and(|k| k == key));
        open.map(|slot| slot.key = None).is_some()
    }

    /// Drops every open message from `source` (its alias was released).
    pub fn forget_source(&mut self, source: NodeAlias) {
        for slot in &mut self.slots {
            if slot.key.is_some_and(|k| k.source == source) {
                slot.key = None;
            }
        }
    }

    /// Drops every open message.
    pub fn clear(&mut self) {
        for slot in &mut self.slots {
            slot.key = None;
        }
    }

    /// Messages being assembled.
    pub fn open_count(&self) -> usize {
        self.slots.iter().filter(|s| s.key.is_some()).count()
    }

    /// Payload bytes held by the messages being assembled; never more than
    /// [`bound`](Self::bound).
    pub fn buffered(&self) -> usize {
        self.slots.iter().filter(|s| s.key.is_some()).map(|s| s.buffer.len()).sum()
    }

    /// The most payload bytes held at once: slots times the longest message.
    pub fn bound(&self) -> usize {
        self.slots.len().saturating_mul(self.max_len)
    }

    /// Bytes allocated for the slot buffers, all at construction: this never changes.
    pub fn allocated(&self) -> usize {
        self.slots.iter().map(|s| s.buffer.capacity()).sum()
    }
}

fn append(slot: &mut Slot, data: &[u8], max_len: usize) -> Result<(), ReassemblyError> {
    if slot.buffer.len().saturating_add(data.len()) > max_len {
        slot.key = None;
        return Err(ReassemblyError::TooLong);
    }
    slot.buffer.extend_from_slice(data);
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn key(mti: u16) -> ReassemblyKey {
        ReassemblyKey {
            source: NodeAlias::new(0x22A).unwrap(),
            destination: NodeAlias::new(0x3FB).unwrap(),
            mti: Mti(mti),
        }
    }

    fn reassembler() -> Reassembler {
        Reassembler::new(2, 16, Duration::from_secs(3))
    }

    const T0: Instant = Instant::ZERO;

    #[test]
    fn first_middle_last_gives_the_whole_payload() {
        let mut r = reassembler();
        assert_eq!(r.push(T0, key(0xA08), FramePosition::First, &[1, 2, 3, 4, 5, 6]), Ok(None));
        assert_eq!(r.push(T0, key(0xA08), FramePosition::Middle, &[7, 8]), Ok(None));
        assert_eq!(r.open_count(), 1);
        let whole = r.push(T0, key(0xA08), FramePosition::Last, &[9]).unwrap().unwrap().to_vec();
        assert_eq!(whole, [1, 2, 3, 4, 5, 6, 7, 8, 9]);
        assert_eq!(r.open_count(), 0);
        assert_eq!(r.poll_timeout(), None);
    }

    #[test]
    fn keys_differing_only_in_mti_do_not_mix() {
        let mut r = reassembler();
        r.push(T0, key(0xA08), FramePosition::First, &[1]).unwrap();
        r.push(T0, key(0xCC8), FramePosition::First, &[2]).unwrap();
        assert_eq!(r.push(T0, key(0xCC8), FramePosition::Last, &[3]).unwrap(), Some(&[2, 3][..]));
        assert_eq!(r.push(T0, key(0xA08), FramePosition::Last, &[4]).unwrap(), Some(&[1, 4][..]));
    }

    #[test]
    fn middle_or_last_without_first_is_0x2041() {
        let mut r = reassembler();
        assert_eq!(r.push(T0, key(0xA08), FramePosition::Middle, &[1]), Err(ReassemblyError::MiddleWithoutFirst));
        assert_eq!(r.push(T0, key(0xA08), FramePosition::Last, &[1]), Err(ReassemblyError::MiddleWithoutFirst));
        assert_eq!(ReassemblyError::MiddleWithoutFirst.code(), ErrorCode(0x2041));
    }

    #[test]
    fn second_first_is_0x2042_and_restarts() {
        let mut r = reassembler();
        r.push(T0, key(0xA08), FramePosition::First, &[1]).unwrap();
        assert_eq!(r.push(T0, key(0xA08), FramePosition::First, &[2]), Err(ReassemblyError::FirstBeforeLastEnded));
        assert_eq!(r.push(T0, key(0xA08), FramePosition::Last, &[3]).unwrap(), Some(&[2, 3][..]));
        assert_eq!(ReassemblyError::FirstBeforeLastEnded.code(), ErrorCode(0x2042));
    }

    #[test]
    fn silent_message_times_out_with_0x2011() {
        let mut r = reassembler();
        r.push(T0, key(0xA08), FramePosition::First, &[1]).unwrap();
        let deadline = Instant::from_millis(3000);
        assert_eq!(r.poll_timeout(), Some(deadline));
        assert_eq!(r.take_expired(Instant::from_millis(2999)), None);
        assert_eq!(r.take_expired(deadline), Some(key(0xA08)));
        assert_eq!(r.take_expired(deadline), None);
        assert_eq!(r.push(T0, key(0xA08), FramePosition::Last, &[1]), Err(ReassemblyError::MiddleWithoutFirst));
        assert_eq!(ReassemblyError::Timeout.code(), ErrorCode(0x2011));
    }

    #[test]
    fn slots_and_length_are_bounded() {
        let mut r = reassembler();
        r.push(T0, key(1), FramePosition::First, &[1]).unwrap();
        r.push(T0, key(2), FramePosition::First, &[1]).unwrap();
        assert_eq!(r.push(T0, key(3), FramePosition::First, &[1]), Err(ReassemblyError::NoFreeSlot));
        r.forget_source(key(1).source);
        assert_eq!(r.open_count(), 0);
        r.push(T0, key(1), FramePosition::First, &[0; 10]).unwrap();
        assert_eq!(r.push(T0, key(1), FramePosition::Middle, &[0; 7]), Err(ReassemblyError::TooLong));
        assert_eq!(r.open_count(), 0);
    }

    fn datagram_key(source: u16) -> ReassemblyKey {
        ReassemblyKey {
            source: NodeAlias::new(source).unwrap(),
            destination: NodeAlias::new(0x456).unwrap(),
            mti: Mti::DATAGRAM,
        }
    }

    #[test]
    fn datagram_second_first_drops_both() {
        let mut r = Reassembler::for_datagrams(2, Duration::from_secs(3));
        r.push(T0, datagram_key(0x123), FramePosition::First, &[1; 8]).unwrap();
        assert_eq!(
            r.push(T0, datagram_key(0x123), FramePosition::First, &[2; 8]),
            Err(ReassemblyError::FirstBeforeLastEnded)
        );
        assert_eq!(r.open_count(), 0, "the partial datagram and the new first frame are gone");
        // The rest of the refused datagram is dropped without a second answer.
        assert_eq!(r.push(T0, datagram_key(0x123), FramePosition::Middle, &[3]), Ok(None));
        assert_eq!(r.push(T0, datagram_key(0x123), FramePosition::Last, &[3]), Ok(None));
        // A datagram with no first frame at all is answered once, at its last frame.
        assert_eq!(r.push(T0, datagram_key(0x124), FramePosition::Middle, &[3]), Ok(None));
        assert_eq!(
            r.push(T0, datagram_key(0x124), FramePosition::Last, &[3]),
            Err(ReassemblyError::MiddleWithoutFirst)
        );
    }

    #[test]
    fn a_crowd_refused_for_want_of_slots_hears_one_answer_each() {
        let mut r = Reassembler::for_datagrams(1, Duration::from_secs(3));
        r.push(T0, datagram_key(0x100), FramePosition::First, &[1; 8]).unwrap();
        // More than are remembered: those are answered at their last frame instead.
        for source in 0x101..0x131 {
            let first = r.push(T0, datagram_key(source), FramePosition::First, &[1; 8]);
            let expected = if source < 0x111 { Err(ReassemblyError::NoFreeSlot) } else { Ok(None) };
            assert_eq!(first, expected, "0x{source:03X}");
        }
        for source in 0x101..0x131 {
            assert_eq!(r.push(T0, datagram_key(source), FramePosition::Middle, &[2; 8]), Ok(None));
            let last = r.push(T0, datagram_key(source), FramePosition::Last, &[3]);
            let expected = if source < 0x111 { Ok(None) } else { Err(ReassemblyError::MiddleWithoutFirst) };
            assert_eq!(last, expected, "0x{source:03X}");
        }
    }

    #[test]
    fn datagram_wait_runs_from_the_first_frame() {
        let mut r = Reassembler::for_datagrams(1, Duration::from_secs(3));
        r.push(T0, datagram_key(0x123), FramePosition::First, &[1; 8]).unwrap();
        r.push(Instant::from_millis(2000), datagram_key(0x123), FramePosition::Middle, &[]).unwrap();
        assert_eq!(r.poll_timeout(), Some(Instant::from_millis(3000)));
        assert_eq!(r.take_expired(Instant::from_millis(3000)), Some(datagram_key(0x123)));
    }

    #[test]
    fn datagram_of_72_bytes_fits_and_73_does_not() {
        let mut r = Reassembler::for_datagrams(1, Duration::from_secs(3));
        let allocated = r.allocated();
        assert!(allocated >= MAX_DATAGRAM_LEN);
        r.push(T0, datagram_key(0x123), FramePosition::First, &[0; 8]).unwrap();
        for _ in 0..7 {
            r.push(T0, datagram_key(0x123), FramePosition::Middle, &[0; 8]).unwrap();
        }
        assert_eq!(r.buffered(), 64);
        let whole = r.push(T0, datagram_key(0x123), FramePosition::Last, &[9; 8]).unwrap().unwrap();
        assert_eq!(whole.len(), 72);
        r.push(T0, datagram_key(0x123), FramePosition::First, &[0; 8]).unwrap();
        for _ in 0..8 {
            r.push(T0, datagram_key(0x123), FramePosition::Middle, &[0; 8]).unwrap();
        }
        assert_eq!(r.push(T0, datagram_key(0x123), FramePosition::Last, &[0]), Err(ReassemblyError::TooLong));
        assert_eq!(ReassemblyError::TooLong.datagram_code(), ErrorCode(0x1000));
        assert_eq!(ReassemblyError::NoFreeSlot.datagram_code(), ErrorCode(0x2020));
        assert_eq!(r.allocated(), allocated, "no buffer grew");
        assert_eq!(r.bound(), MAX_DATAGRAM_LEN);
    }

    #[test]
    fn error_counts_record_each_kind() {
        let mut counts = ReassemblyErrorCounts::default();
        counts.record(ReassemblyError::MiddleWithoutFirst);
        counts.record(ReassemblyError::TooLong);
        counts.record(ReassemblyError::TooLong);
        assert_eq!((counts.middle_without_first, counts.too_long, counts.total()), (1, 2, 3));
    }

    #[test]
    fn only_frame_passes_through() {
        let mut r = reassembler();
        assert_eq!(r.push(T0, key(1), FramePosition::Only, &[9]).unwrap(), Some(&[9][..]));
    }
}
