//! Reassembly of addressed multi-frame messages in a bounded number of slots (wire-spec §7.2).

use alloc::vec::Vec;

use openlcb_stream::wire::ErrorCode;
use openlcb_stream::{Duration, Instant, Mti};

use crate::NodeAlias;
use crate::fragment::FramePosition;

/// What one message under assembly is keyed by: (source alias, destination alias, MTI).
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
    /// message is dropped; the new frame starts a new message.
    #[error("first frame before the previous message ended")]
    FirstBeforeLastEnded,
    /// No last frame came within the timeout (0x2011). The message is dropped.
    #[error("timeout waiting for the last frame")]
    Timeout,
    /// The message grew beyond the configured maximum length (0x2020). It is dropped.
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
}

#[derive(Debug)]
struct Slot {
    key: Option<ReassemblyKey>,
    buffer: Vec<u8>,
    deadline: Instant,
}

/// Bounded reassembly: `slots` messages at once, each at most `max_len` payload bytes, each
/// dropped when no frame of it arrived for `timeout`. All memory is taken up front.
#[derive(Debug)]
pub struct Reassembler {
    slots: Vec<Slot>,
    max_len: usize,
    timeout: Duration,
}

impl Reassembler {
    /// `slots` slots of `max_len` bytes each.
    pub fn new(slots: usize, max_len: usize, timeout: Duration) -> Self {
        let slots = (0..slots)
            .map(|_| Slot { key: None, buffer: Vec::with_capacity(max_len), deadline: Instant::ZERO })
            .collect();
        Reassembler { slots, max_len, timeout }
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
        let deadline = now + self.timeout;
        let max_len = self.max_len;
        let open = self.slots.iter().position(|s| s.key == Some(key));
        match (position, open) {
            (FramePosition::Only, _) => Ok(Some(data)),
            (FramePosition::First, open) => {
                let index = match open.or_else(|| self.slots.iter().position(|s| s.key.is_none())) {
                    Some(index) => index,
                    None => return Err(ReassemblyError::NoFreeSlot),
                };
                let slot = self.slots.get_mut(index).ok_or(ReassemblyError::NoFreeSlot)?;
                slot.key = Some(key);
                slot.deadline = deadline;
                slot.buffer.clear();
                append(slot, data, max_len)?;
                if open.is_some() { Err(ReassemblyError::FirstBeforeLastEnded) } else { Ok(None) }
            }
            (FramePosition::Middle | FramePosition::Last, None) => Err(ReassemblyError::MiddleWithoutFirst),
            (FramePosition::Middle | FramePosition::Last, Some(index)) => {
                let slot = self.slots.get_mut(index).ok_or(ReassemblyError::MiddleWithoutFirst)?;
                slot.deadline = deadline;
                append(slot, data, max_len)?;
                if position == FramePosition::Last {
                    slot.key = None;
                    Ok(Some(&slot.buffer))
                } else {
                    Ok(None)
                }
            }
        }
    }

    /// The key of one message whose wait ran out at `now` (it is dropped), if any. Call until
    /// `None`.
    pub fn take_expired(&mut self, now: Instant) -> Option<ReassemblyKey> {
        let slot = self.slots.iter_mut().find(|s| s.key.is_some() && s.deadline <= now)?;
        slot.key.take()
    }

    /// When the next open message times out.
    pub fn poll_timeout(&self) -> Option<Instant> {
        self.slots.iter().filter(|s| s.key.is_some()).map(|s| s.deadline).min()
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

    #[test]
    fn only_frame_passes_through() {
        let mut r = reassembler();
        assert_eq!(r.push(T0, key(1), FramePosition::Only, &[9]).unwrap(), Some(&[9][..]));
    }
}
