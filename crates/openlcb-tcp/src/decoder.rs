//! [`Decoder`]: a bounded, resumable decoder of the OpenLCB-TCP byte stream.

use alloc::vec::Vec;

use openlcb_stream::NodeId;

use crate::frame::{
    self, Flags, HEADER_LEN, LinkPrefix, MAX_STREAM_DATA_LENGTH, MIN_WHOLE_LENGTH, PREFIX_LEN, Part, TcpFrame,
};

/// Why bytes from the link were refused.
///
/// Errors for which [`closes_link`](DecodeError::closes_link) is true leave the decoder
/// [failed](Decoder::failure): a byte stream whose length field cannot be trusted cannot be
/// resynchronised, so the connection must be closed. The others reject one message, which
/// the length field delimits, and decoding goes on.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
pub enum DecodeError {
    /// The length field exceeds the decoder's bound. Closes the link.
    #[error("length field {length} exceeds the bound of {max} bytes")]
    LengthTooLong {
        /// The length field.
        length: u32,
        /// The decoder's bound.
        max: u32,
    },
    /// The length field is too short for the fixed fields of the message. Closes the link.
    #[error("length field {length} is shorter than the {needed} bytes the message's fixed fields need")]
    LengthTooShort {
        /// The length field.
        length: u32,
        /// What the prefix, MTI and Node IDs need.
        needed: u32,
    },
    /// The flags field has the chaining bit 0x4000 set. No chained-prefix layout is defined
    /// (wire-spec Q8) and OpenMRN asserts the bit is clear; the message was skipped.
    #[error("flags field 0x{flags:04X} has the chaining bit 0x4000 set; chained prefixes are not supported")]
    Chained {
        /// The flags field.
        flags: u16,
    },
    /// The parts of a multi-part message add up to more than the decoder's bound; the
    /// message is dropped (its remaining parts are skipped).
    #[error("multi-part message exceeds the bound of {max} bytes")]
    PartsTooLong {
        /// The decoder's bound, in length-field bytes.
        max: u32,
    },
    /// A middle or last part arrived with no first part before it; the part was dropped.
    #[error("flags field 0x{flags:04X} marks a middle or last part, but no first part came before it")]
    PartWithoutFirst {
        /// The flags field.
        flags: u16,
    },
    /// A first part arrived while another multi-part message was unfinished; the unfinished
    /// one was dropped and the new one started.
    #[error("a first part arrived before the last part of the previous multi-part message")]
    PartsInterrupted,
    /// A middle or last part came from another gateway than the first part; it was dropped.
    #[error("part from gateway {got} while reassembling a message from {expected}")]
    PartFromOtherGateway {
        /// The gateway of the first part.
        expected: NodeId,
        /// The gateway of this part.
        got: NodeId,
    },
    /// The reassembled parts are shorter than an MTI and its Node IDs; the message was dropped.
    #[error("reassembled message of {got} bytes is shorter than the {needed} bytes its MTI and Node IDs need")]
    PartsTooShort {
        /// What the parts held.
        got: u32,
        /// What the MTI and Node IDs need.
        needed: u32,
    },
    /// The input ended inside a message ([`Decoder::end_of_input`]).
    #[error("input ended {missing} bytes before the end of a message")]
    Truncated {
        /// Bytes still expected (at least; a header cut short hides its length).
        missing: u32,
    },
    /// The input ended between the parts of a multi-part message ([`Decoder::end_of_input`]).
    #[error("input ended before the last part of a multi-part message")]
    PartsUnfinished,
}

impl DecodeError {
    /// This error leaves the decoder failed: the connection must be closed.
    pub const fn closes_link(self) -> bool {
        matches!(self, DecodeError::LengthTooLong { .. } | DecodeError::LengthTooShort { .. })
    }
}

/// Counters of what the decoder has seen. Nothing here is ever a panic.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
#[non_exhaustive]
pub struct DecoderStats {
    /// OpenLCB messages delivered (a reassembled multi-part message counts once).
    pub messages: u64,
    /// Bytes consumed from the input.
    pub bytes: u64,
    /// Link-control messages (flag 0x8000 clear) skipped by their length.
    pub link_control_skipped: u64,
    /// Messages with the chaining bit, skipped by their length.
    pub chained_skipped: u64,
    /// Parts of multi-part messages received (first, middle and last).
    pub parts: u64,
    /// Multi-part messages dropped (too long, interrupted, too short) and stray parts.
    pub parts_rejected: u64,
}

/// Where the decoder is in the byte stream.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum State {
    /// Reading flags and length; `have` of the 5 bytes are in `bytes`.
    Header { have: usize, bytes: [u8; HEADER_LEN] },
    /// Reading the `length` bytes of an OpenLCB message (or part) into the body buffer.
    Body { flags: Flags, length: usize },
    /// Skipping a message that is not delivered (link control, chaining).
    Skip { remaining: usize },
    /// The length field could not be trusted; everything from here on is discarded.
    Failed(DecodeError),
}

impl State {
    const START: State = State::Header { have: 0, bytes: [0; HEADER_LEN] };
}

/// A multi-part message being put back together (wire-spec §8, §10 C-15).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
struct Reassembling {
    /// The gateway and capture time of the first part.
    prefix: LinkPrefix,
    /// Over the bound: the rest of its parts are dropped quietly.
    discarding: bool,
}

/// What one call to `advance` ended with, without borrowing the decoder.
enum Step<'i> {
    /// Nothing complete yet: the input is used up.
    NeedMore,
    /// A whole message found entirely inside the input (no copy).
    Frame(TcpFrame<'i>),
    /// A whole message now in the body buffer.
    Buffered,
    /// A multi-part message now in the reassembly buffer.
    Reassembled,
    /// A message or part refused.
    Error(DecodeError),
}

/// What a message's body turned out to be.
enum BodyOutcome<'b> {
    /// A whole message.
    Frame(TcpFrame<'b>),
    /// A part (or an error about one).
    Part(PartOutcome),
    /// A whole message too short for its fixed fields: the length field lied.
    Malformed(DecodeError),
}

/// What became of one part of a multi-part message.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum PartOutcome {
    /// Kept (or quietly dropped with the rest of a message over the bound).
    Stored,
    /// It was the last part: the message is complete in the reassembly buffer.
    Reassembled,
    /// Refused.
    Rejected(DecodeError),
}

/// The multi-part state, kept apart from the body buffer so both can be borrowed at once.
#[derive(Debug, Default)]
struct Reassembly {
    /// The message being collected, if any.
    current: Option<Reassembling>,
    /// The prefix of the message just completed, until the next call clears `bytes`.
    delivered: Option<LinkPrefix>,
    /// MTI, Node IDs and payload collected so far (the parts without their prefixes).
    bytes: Vec<u8>,
    /// The bound on `bytes`: the decoder's bound less the one prefix a whole message carries.
    max: usize,
}

impl Reassembly {
    /// Takes one part (not [`Part::Whole`]): its prefix and the bytes after it.
    fn take_part(&mut self, part: Part, flags: Flags, prefix: LinkPrefix, content: &[u8]) -> PartOutcome {
        let mut interrupted = false;
        match (part, self.current) {
            (Part::Whole, _) => return PartOutcome::Stored,
            (Part::First, current) => {
                interrupted = current.is_some_and(|c| !c.discarding);
                self.bytes.clear();
                self.current = Some(Reassembling { prefix, discarding: false });
            }
            (Part::Middle | Part::Last, None) => {
                return PartOutcome::Rejected(DecodeError::PartWithoutFirst { flags: flags.as_raw() });
            }
            (Part::Middle | Part::Last, Some(current)) if current.prefix.gateway != prefix.gateway => {
                let (expected, got) = (current.prefix.gateway, prefix.gateway);
                return PartOutcome::Rejected(DecodeError::PartFromOtherGateway { expected, got });
            }
            (Part::Middle | Part::Last, Some(current)) if current.discarding => {
                if part == Part::Last {
                    self.current = None;
                }
                return PartOutcome::Stored;
            }
            (Part::Middle | Part::Last, Some(_)) => {}
        }
        let total = self.bytes.len().saturating_add(content.len());
        if total > self.max {
            self.bytes.clear();
            self.current = self.current.filter(|_| part != Part::Last).map(|c| Reassembling { discarding: true, ..c });
            let max = u32::try_from(self.max + PREFIX_LEN).unwrap_or(u32::MAX);
            return PartOutcome::Rejected(DecodeError::PartsTooLong { max });
        }
        // Grow by doubling, but never past the bound.
        let capacity = total.max(self.bytes.capacity().saturating_mul(2)).min(self.max);
        self.bytes.reserve_exact(capacity.saturating_sub(self.bytes.len()));
        self.bytes.extend_from_slice(content);
        if interrupted {
            return PartOutcome::Rejected(DecodeError::PartsInterrupted);
        }
        if part != Part::Last {
            return PartOutcome::Stored;
        }
        let first = self.current.take();
        match frame::parse_message(&self.bytes) {
            Ok(_) => {
                self.delivered = first.map(|c| c.prefix);
                PartOutcome::Reassembled
            }
            Err(short) => {
                let got = u32::try_from(self.bytes.len()).unwrap_or(u32::MAX);
                let needed = u32::try_from(short.needed).unwrap_or(u32::MAX);
                self.bytes.clear();
                PartOutcome::Rejected(DecodeError::PartsTooShort { got, needed })
            }
        }
    }
}

/// A streaming decoder of the OpenLCB-TCP byte stream: bytes go in in pieces of any size,
/// [`TcpFrame`]s come out.
///
/// A message that lies wholly inside the input is returned borrowing the input (no copy);
/// one split across inputs is gathered in a buffer of at most
/// [`max_length`](Self::max_length) bytes, and a multi-part message in a second one of the
/// same bound, so the decoder never holds more than twice the bound however the input is cut.
///
/// Recovery, per wire-spec §8:
/// - a length field over the bound, or too short for the message's fixed fields, fails the
///   decoder for good ([`DecodeError::closes_link`]): close the connection;
/// - link-control messages (flag 0x8000 clear) are skipped by their length and counted;
/// - reserved flag bits (0x3000, 0x03FF) are ignored;
/// - multi-part messages (0x0400 "not last", 0x0800 "not first") are reassembled within the
///   bound or rejected with an error;
/// - the chaining bit 0x4000 rejects the message with [`DecodeError::Chained`].
///
/// ```
/// use openlcb_tcp::Decoder;
///
/// let bytes = [
///     0x80, 0x00, 0x00, 0x00, 0x1C, // flags, length
///     0x05, 0x01, 0x01, 0x01, 0x22, 0x01, 0x00, 0x00, 0x00, 0x00, 0x00, 0x04, // prefix
///     0x08, 0x88, 0x05, 0x01, 0x01, 0x01, 0x22, 0x01, 0x05, 0x01, 0x01, 0x01, 0x22, 0x00, // MTI, Node IDs
///     0x04, 0x07, // payload
/// ];
/// let mut decoder = Decoder::default();
/// let (first, second) = bytes.split_at(20);
/// let mut input: &[u8] = first;
/// assert!(decoder.decode(&mut input).is_none()); // buffered, waiting for the rest
/// let mut input: &[u8] = second;
/// let frame = decoder.decode(&mut input).unwrap().unwrap();
/// assert_eq!(frame.message.payload, [0x04, 0x07]);
/// assert!(input.is_empty());
/// ```
#[derive(Debug)]
pub struct Decoder {
    state: State,
    max_length: usize,
    /// A message split across inputs, gathered here (at most `max_length` bytes).
    body: Vec<u8>,
    reassembly: Reassembly,
    /// The last call delivered from `body` or `reassembly`; they are cleared on the next.
    delivered_from_buffer: bool,
    stats: DecoderStats,
}

impl Default for Decoder {
    /// A decoder bounded to the largest message the stream core sends,
    /// [`MAX_STREAM_DATA_LENGTH`].
    fn default() -> Self {
        Decoder::new(MAX_STREAM_DATA_LENGTH)
    }
}

impl Decoder {
    /// A decoder that refuses length fields over `max_length` (clamped to at least the
    /// smallest addressed message, 26, and at most the 24-bit maximum).
    pub fn new(max_length: u32) -> Self {
        let max_length = max_length.clamp(MIN_WHOLE_LENGTH as u32 + 6, frame::MAX_LENGTH) as usize;
        Decoder {
            state: State::START,
            max_length,
            body: Vec::new(),
            reassembly: Reassembly { max: max_length - PREFIX_LEN, ..Reassembly::default() },
            delivered_from_buffer: false,
            stats: DecoderStats::default(),
        }
    }

    /// The bound on the length field (and on a reassembled message's would-be length field).
    pub fn max_length(&self) -> u32 {
        u32::try_from(self.max_length).unwrap_or(u32::MAX)
    }

    /// Counters of what was seen.
    pub fn stats(&self) -> DecoderStats {
        self.stats
    }

    /// The error that failed the decoder, if one did. A failed decoder discards all input:
    /// close the connection.
    pub fn failure(&self) -> Option<DecodeError> {
        match self.state {
            State::Failed(error) => Some(error),
            _ => None,
        }
    }

    /// Bytes of buffer memory held (the capacity of both buffers); never more than twice
    /// [`max_length`](Self::max_length).
    pub fn buffered_capacity(&self) -> usize {
        self.body.capacity() + self.reassembly.bytes.capacity()
    }

    /// The decoder sits between messages: ending the input here loses nothing.
    pub fn is_idle(&self) -> bool {
        self.end_of_input().is_ok()
    }

    /// Says whether the input may end here: `Err` with [`DecodeError::Truncated`] inside a
    /// message, [`DecodeError::PartsUnfinished`] between the parts of one, the failure of a
    /// failed decoder.
    pub fn end_of_input(&self) -> Result<(), DecodeError> {
        let missing = |n: usize| DecodeError::Truncated { missing: u32::try_from(n).unwrap_or(u32::MAX) };
        match self.state {
            State::Failed(error) => Err(error),
            State::Header { have: have @ 1.., .. } => Err(missing(HEADER_LEN.saturating_sub(have))),
            State::Body { length, .. } => Err(missing(length.saturating_sub(self.body.len()))),
            State::Skip { remaining } => Err(missing(remaining)),
            State::Header { .. } if self.reassembly.current.is_some() => Err(DecodeError::PartsUnfinished),
            State::Header { .. } => Ok(()),
        }
    }

    /// Decodes the next message from `input`, advancing `input` past the bytes it used.
    ///
    /// Call it until it returns `None`: `input` is then empty (every byte is either part of a
    /// returned message or kept in the decoder's buffer for the next call). `Some(Err(..))`
    /// reports a refused message or part and decoding goes on with the next call, unless
    /// the error [closes the link](DecodeError::closes_link); a failed decoder returns `None`
    /// and discards its input.
    ///
    /// The frame borrows `input` or the decoder until the next call.
    pub fn decode<'s, 'i: 's>(&'s mut self, input: &mut &'i [u8]) -> Option<Result<TcpFrame<'s>, DecodeError>> {
        if core::mem::take(&mut self.delivered_from_buffer) {
            self.body.clear();
            if self.reassembly.delivered.take().is_some() {
                self.reassembly.bytes.clear();
            }
        }
        let before = input.len();
        let step = self.advance(input);
        let used = before - input.len();
        self.stats.bytes = self.stats.bytes.saturating_add(used as u64);
        if matches!(step, Step::Frame(_) | Step::Buffered | Step::Reassembled) {
            self.stats.messages = self.stats.messages.saturating_add(1);
        }
        match step {
            Step::NeedMore => None,
            Step::Error(error) => Some(Err(error)),
            Step::Frame(frame) => Some(Ok(frame)),
            Step::Buffered => {
                self.delivered_from_buffer = true;
                Some(frame::parse_body(&self.body).map_err(|short| length_too_short(self.body.len(), short.needed)))
            }
            Step::Reassembled => {
                self.delivered_from_buffer = true;
                let Reassembly { bytes, delivered, .. } = &self.reassembly;
                let prefix = (*delivered)?;
                let parsed = frame::parse_message(bytes).map(|message| TcpFrame { prefix, message });
                Some(parsed.map_err(|short| length_too_short(bytes.len() + PREFIX_LEN, short.needed + PREFIX_LEN)))
            }
        }
    }

    /// Moves through `input` until a message is complete, a message is refused, or the input
    /// is used up. What it returns borrows only `input`, never the decoder.
    fn advance<'i>(&mut self, input: &mut &'i [u8]) -> Step<'i> {
        loop {
            match &mut self.state {
                State::Failed(_) => {
                    *input = &[];
                    return Step::NeedMore;
                }
                State::Header { have, bytes } => {
                    let (taken, rest) = input.split_at(input.len().min(HEADER_LEN - *have));
                    if let Some(to) = bytes.get_mut(*have..*have + taken.len()) {
                        to.copy_from_slice(taken);
                    }
                    *have += taken.len();
                    *input = rest;
                    if *have < HEADER_LEN {
                        return Step::NeedMore;
                    }
                    let [f0, f1, l0, l1, l2] = *bytes;
                    if let Some(error) =
                        self.on_header(Flags(u16::from_be_bytes([f0, f1])), u32::from_be_bytes([0, l0, l1, l2]))
                    {
                        return Step::Error(error);
                    }
                }
                State::Skip { remaining } => {
                    let n = input.len().min(*remaining);
                    *remaining -= n;
                    *input = input.get(n..).unwrap_or_default();
                    if *remaining > 0 {
                        return Step::NeedMore;
                    }
                    self.state = State::START;
                }
                State::Body { flags, length } => {
                    let (flags, length) = (*flags, *length);
                    let outcome =
                        if let Some((body, rest)) = input.split_at_checked(length).filter(|_| self.body.is_empty()) {
                            *input = rest;
                            self.state = State::START;
                            match on_body(&mut self.reassembly, &mut self.stats, flags, body) {
                                BodyOutcome::Frame(frame) => return Step::Frame(frame),
                                BodyOutcome::Part(outcome) => Ok(outcome),
                                BodyOutcome::Malformed(error) => Err(error),
                            }
                        } else {
                            if self.body.is_empty() {
                                self.body.reserve_exact(length);
                            }
                            let (taken, rest) = input.split_at(input.len().min(length.saturating_sub(self.body.len())));
                            self.body.extend_from_slice(taken);
                            *input = rest;
                            if self.body.len() < length {
                                return Step::NeedMore;
                            }
                            self.state = State::START;
                            let outcome = match on_body(&mut self.reassembly, &mut self.stats, flags, &self.body) {
                                BodyOutcome::Frame(_) => return Step::Buffered,
                                BodyOutcome::Part(outcome) => Ok(outcome),
                                BodyOutcome::Malformed(error) => Err(error),
                            };
                            self.body.clear();
                            outcome
                        };
                    match outcome {
                        Ok(PartOutcome::Stored) => {}
                        Ok(PartOutcome::Reassembled) => return Step::Reassembled,
                        Ok(PartOutcome::Rejected(error)) => return Step::Error(error),
                        Err(error) => return Step::Error(self.fail(error)),
                    }
                }
            }
        }
    }

    /// The flags and length are known: decide what to do with the bytes they announce.
    fn on_header(&mut self, flags: Flags, length: u32) -> Option<DecodeError> {
        let length_usize = length as usize;
        if !flags.is_openlcb_message() {
            self.stats.link_control_skipped = self.stats.link_control_skipped.saturating_add(1);
            self.state = State::Skip { remaining: length_usize };
            return None;
        }
        if length_usize > self.max_length {
            return Some(self.fail(DecodeError::LengthTooLong { length, max: self.max_length() }));
        }
        if flags.is_chained() {
            self.stats.chained_skipped = self.stats.chained_skipped.saturating_add(1);
            self.state = State::Skip { remaining: length_usize };
            return Some(DecodeError::Chained { flags: flags.as_raw() });
        }
        let needed = if flags.part() == Part::Whole { MIN_WHOLE_LENGTH } else { PREFIX_LEN };
        if length_usize < needed {
            return Some(self.fail(length_too_short(length_usize, needed)));
        }
        self.state = State::Body { flags, length: length_usize };
        None
    }

    fn fail(&mut self, error: DecodeError) -> DecodeError {
        self.state = State::Failed(error);
        self.body = Vec::new();
        self.reassembly.bytes = Vec::new();
        self.reassembly.current = None;
        error
    }
}

/// Sorts one message's body: a whole message is parsed, a part goes to the reassembly.
fn on_body<'b>(reassembly: &mut Reassembly, stats: &mut DecoderStats, flags: Flags, body: &'b [u8]) -> BodyOutcome<'b> {
    let part = flags.part();
    if part == Part::Whole {
        return match frame::parse_body(body) {
            Ok(frame) => BodyOutcome::Frame(frame),
            Err(short) => BodyOutcome::Malformed(length_too_short(body.len(), short.needed)),
        };
    }
    stats.parts = stats.parts.saturating_add(1);
    let Some((prefix, content)) = frame::parse_prefix(body) else {
        return BodyOutcome::Malformed(length_too_short(body.len(), PREFIX_LEN));
    };
    let outcome = reassembly.take_part(part, flags, prefix, content);
    if matches!(outcome, PartOutcome::Rejected(_)) {
        stats.parts_rejected = stats.parts_rejected.saturating_add(1);
    }
    BodyOutcome::Part(outcome)
}

fn length_too_short(length: usize, needed: usize) -> DecodeError {
    DecodeError::LengthTooShort {
        length: u32::try_from(length).unwrap_or(u32::MAX),
        needed: u32::try_from(needed).unwrap_or(u32::MAX),
    }
}
