//! Event Transport (Producer/Consumer events): the events this node produces and consumes
//! ([`EventConfig`]), the answers to Identify Producer, Identify Consumer and Identify
//! Events, the announcements after Initialization Complete, and the reports and Learn Event
//! messages it receives ([`EventNotice`]).
//!
//! A Range Identified message carries one Event ID whose low bits give the range: the run
//! of equal bits at the bottom (all ones or all zeros) is the part that varies, so a block
//! of 2^n IDs aligned on 2^n is sent with its low n bits the opposite of bit n (Event
//! Transport Standard; OpenMRN's `EventRegistry::align_mask` rounds a base and size up to
//! such a block the same way).
//!
//! Identify Events (global or addressed) is answered by one pass over everything declared,
//! produced one message at a time as the node's transmit queue is drained: the answers are
//! global, so one pass serves every node that asked meanwhile, and a flood of Identify
//! Events from a thousand nodes costs no memory at all.

use alloc::vec::Vec;

use openlcb_stream::wire::ErrorReport;
use openlcb_stream::{EventId, Instant, Message, MessageRef, Mti, NodeId};

use crate::node::{Outputs, bump};
use crate::service::{Lent, Service, ServiceChange};
use crate::{Node, NodeEvent};

/// What a producer or consumer knows of the state an event stands for (Event Transport
/// §4.3 and the Identified MTIs' low bits).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
pub enum EventState {
    /// The state the event reports is the current one.
    Valid,
    /// The current state is another one.
    Invalid,
    /// Not known (the usual answer of a node without state).
    #[default]
    Unknown,
}

impl EventState {
    /// The low two bits of a Producer or Consumer Identified MTI.
    const fn mti_bits(self) -> u16 {
        match self {
            EventState::Valid => 0,
            EventState::Invalid => 1,
            EventState::Unknown => 3,
        }
    }

    /// The state of a Producer or Consumer Identified MTI (the reserved value 2 as unknown).
    const fn from_mti(mti: Mti) -> Self {
        match mti.0 & 3 {
            0 => EventState::Valid,
            1 => EventState::Invalid,
            _ => EventState::Unknown,
        }
    }
}

/// A block of 2^`bits` Event IDs aligned on 2^`bits` (`bits` 0: one Event ID).
#[derive(Clone, Copy, PartialEq, Eq, Hash)]
pub struct EventRange {
    base: EventId,
    bits: u8,
}

impl EventRange {
    /// The most bits a range varies (the Range Identified encoding needs one bit above them).
    pub const MAX_BITS: u8 = 63;

    /// One Event ID.
    pub const fn single(event: EventId) -> Self {
        EventRange { base: event, bits: 0 }
    }

    /// The smallest aligned block that holds the `count` IDs from `first` (rounded as
    /// OpenMRN's `align_mask` does), or `None` for a count of 0 or one past the last ID.
    pub fn covering(first: EventId, count: u64) -> Option<Self> {
        let last = first.0.checked_add(count.checked_sub(1)?)?;
        let bits = u64::BITS - (first.0 ^ last).leading_zeros();
        let bits = u8::try_from(bits).ok().filter(|b| *b <= Self::MAX_BITS)?;
        Some(EventRange { base: EventId(first.0 & !mask(bits)), bits })
    }

    /// The range a Range Identified message names.
    pub fn from_encoded(encoded: EventId) -> Self {
        let low_run = if encoded.0 & 1 == 1 { encoded.0.trailing_ones() } else { encoded.0.trailing_zeros() };
        let bits = u8::try_from(low_run).unwrap_or(Self::MAX_BITS).min(Self::MAX_BITS);
        EventRange { base: EventId(encoded.0 & !mask(bits)), bits }
    }

    /// The Event ID a Range Identified message carries for this range (for one Event ID:
    /// the ID itself, which is no range at all).
    pub const fn encoded(self) -> EventId {
        let low = mask(self.bits);
        if self.bits == 0 || self.base.0 & (low + 1) != 0 { self.base } else { EventId(self.base.0 | low) }
    }

    /// The first Event ID.
    pub const fn first(self) -> EventId {
        self.base
    }

    /// The last Event ID.
    pub const fn last(self) -> EventId {
        EventId(self.base.0 | mask(self.bits))
    }

    /// How many bits vary: the range holds 2^`bits` IDs.
    pub const fn bits(self) -> u8 {
        self.bits
    }

    /// `event` is in the range.
    pub const fn contains(self, event: EventId) -> bool {
        event.0 & !mask(self.bits) == self.base.0
    }

    /// One Event ID, not a block of them.
    pub const fn is_single(self) -> bool {
        self.bits == 0
    }
}

impl core::fmt::Debug for EventRange {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        if self.is_single() {
            write!(f, "EventRange({})", self.base)
        } else {
            write!(f, "EventRange({}..={})", self.base, self.last())
        }
    }
}

/// The low `bits` bits set.
const fn mask(bits: u8) -> u64 {
    if bits >= 64 { u64::MAX } else { (1u64 << bits) - 1 }
}

/// Events this node produces or consumes, with the state they stand for.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct DeclaredEvents {
    /// One Event ID or a block of them.
    pub range: EventRange,
    /// What Identify Producer/Consumer answers for them.
    pub state: EventState,
}

impl DeclaredEvents {
    /// One Event ID in state `state`.
    pub const fn single(event: EventId, state: EventState) -> Self {
        DeclaredEvents { range: EventRange::single(event), state }
    }
}

/// Which received event messages reach the application as [`EventNotice`]s.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
pub enum Listen {
    /// Reports of the events this node consumes, and Learn Event.
    #[default]
    Consumed,
    /// Every report, Learn Event, and every Producer/Consumer (Range) Identified on the
    /// network: what a bus monitor or a configuration tool wants.
    Everything,
}

/// The events a node produces and consumes. With none declared the node takes no part in
/// Event Transport (its PIP has no Event Exchange bit) unless [`listen`](Self::listen) is
/// [`Listen::Everything`].
#[derive(Debug, Clone, PartialEq, Eq, Default)]
#[non_exhaustive]
pub struct EventConfig {
    /// The events this node produces.
    pub produced: Vec<DeclaredEvents>,
    /// The events this node consumes.
    pub consumed: Vec<DeclaredEvents>,
    /// Which received messages reach the application.
    pub listen: Listen,
}

impl EventConfig {
    /// The node takes part in Event Transport: it declares events, or listens to them all.
    pub fn is_active(&self) -> bool {
        self.declared() > 0 || self.listen == Listen::Everything
    }

    /// Declarations, produced and consumed.
    fn declared(&self) -> usize {
        self.produced.len() + self.consumed.len()
    }
}

/// Producer or consumer.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum EventRole {
    /// Produces the events (sends their reports).
    Producer,
    /// Consumes the events (acts on their reports).
    Consumer,
}

/// An event message for the application ([`NodeEvent::Events`]).
#[derive(Debug, Clone, PartialEq, Eq)]
#[non_exhaustive]
pub enum EventNotice {
    /// A Producer/Consumer Event Report.
    Report {
        /// The node that sent it.
        from: NodeId,
        /// The event.
        event: EventId,
        /// The bytes after the Event ID (empty for a plain report).
        payload: Vec<u8>,
    },
    /// Learn Event (teaching): the application decides whether to take the event on.
    Learn {
        /// The node that sent it.
        from: NodeId,
        /// The event taught.
        event: EventId,
    },
    /// Another node identified an event or range it produces or consumes (with
    /// [`Listen::Everything`] only).
    Identified {
        /// The node.
        from: NodeId,
        /// Producer or consumer.
        role: EventRole,
        /// The event, or the range of a Range Identified.
        range: EventRange,
        /// The state of a Producer/Consumer Identified; `None` for a Range Identified.
        state: Option<EventState>,
    },
}

/// Why an event could not be sent.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
pub enum EventError {
    /// [`NodeConfig::transmit_queue_limit`](crate::NodeConfig::transmit_queue_limit) messages
    /// already wait: try again once they are sent.
    #[error("the transmit queue is full")]
    QueueFull,
}

/// Counters of the event service.
///
/// Each counter stops at `u32::MAX` (32 bits: 64-bit counters cost flash on a
/// microcontroller).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
#[non_exhaustive]
pub struct EventStats {
    /// Identify Events messages received (each starts or extends one announcement pass).
    pub identify_events: u32,
    /// Reports received and handed to the application.
    pub reports_delivered: u32,
    /// Reports received for events this node does not consume (with [`Listen::Consumed`]).
    pub reports_ignored: u32,
    /// Event messages too short to hold an Event ID.
    pub malformed: u32,
    /// Notices dropped because the application left
    /// [`NodeConfig::transmit_queue_limit`](crate::NodeConfig::transmit_queue_limit) events
    /// waiting.
    pub notices_dropped: u32,
}

/// The Event Transport service of a node. Its declarations are the node's
/// [`NodeConfig::events`](crate::NodeConfig::events), lent to each call.
#[derive(Debug)]
pub(crate) struct EventService {
    /// The announcement pass: the index of the next declaration to identify, and how many
    /// are left (0: no pass running).
    next: usize,
    left: usize,
    pub(crate) stats: EventStats,
}

impl EventService {
    /// The service of `config`; `announce`: identify everything at once (right after the
    /// node's Initialization Complete).
    pub(crate) fn new(config: &EventConfig, announce: bool) -> Self {
        let mut service = EventService { next: 0, left: 0, stats: EventStats::default() };
        if announce {
            service.announce(config);
        }
        service
    }

    /// Identifies everything declared once more (after Initialization Complete, and for
    /// each Identify Events): a pass that goes on from where a running one stands, so that
    /// it ends with every declaration sent since the request.
    pub(crate) fn announce(&mut self, config: &EventConfig) {
        self.left = config.declared();
    }

    /// The next message of the announcement pass, if one is running.
    pub(crate) fn poll_transmit(&mut self, config: &EventConfig, node: NodeId) -> Option<Message> {
        let total = config.declared();
        if self.left == 0 || total == 0 {
            return None;
        }
        self.left -= 1;
        // Wrapped by comparison, not `%`: a Cortex-M0 divides in library code. (`next` is past
        // the end when the declarations shrank: the pass goes on from the first.)
        let index = if self.next < total { self.next } else { 0 };
        self.next = if index + 1 < total { index + 1 } else { 0 };
        let (role, declared) = match config.produced.get(index) {
            Some(declared) => (EventRole::Producer, declared),
            None => (EventRole::Consumer, config.consumed.get(index - config.produced.len())?),
        };
        Some(identified(node, role, *declared, declared.range.first()))
    }

    /// A received message with an event MTI (the node routes only those here).
    fn on_message(&mut self, config: &EventConfig, out: &mut Outputs, msg: MessageRef<'_>) {
        if matches!(msg.mti, Mti::IDENTIFY_EVENTS_GLOBAL | Mti::IDENTIFY_EVENTS_ADDRESSED) {
            bump(&mut self.stats.identify_events);
            self.announce(config);
            return;
        }
        let Some(event) = EventId::from_slice(msg.payload) else {
            bump(&mut self.stats.malformed);
            return;
        };
        let from = msg.source;
        let everything = config.listen == Listen::Everything;
        match msg.mti {
            Mti::IDENTIFY_PRODUCER => answer(out, &config.produced, EventRole::Producer, event),
            Mti::IDENTIFY_CONSUMER => answer(out, &config.consumed, EventRole::Consumer, event),
            Mti::PRODUCER_CONSUMER_EVENT_REPORT => {
                if everything || find(&config.consumed, event).is_some() {
                    bump(&mut self.stats.reports_delivered);
                    let payload = msg.payload.get(8..).unwrap_or_default().to_vec();
                    self.notify(out, EventNotice::Report { from, event, payload });
                } else {
                    bump(&mut self.stats.reports_ignored);
                }
            }
            Mti::LEARN_EVENT => self.notify(out, EventNotice::Learn { from, event }),
            mti if everything => {
                if let Some((role, state)) = identified_kind(mti) {
                    let range =
                        if state.is_some() { EventRange::single(event) } else { EventRange::from_encoded(event) };
                    self.notify(out, EventNotice::Identified { from, role, range, state });
                }
            }
            _ => {}
        }
    }

    fn notify(&mut self, out: &mut Outputs, notice: EventNotice) {
        if !out.notify(NodeEvent::Events(notice)) {
            bump(&mut self.stats.notices_dropped);
        }
    }
}

impl Service<Lent<'_>> for EventService {
    /// The messages with an event MTI, while the node produces or consumes anything.
    fn handle_message(&mut self, cx: &mut Lent<'_>, msg: MessageRef<'_>) -> bool {
        let events = &cx.config.events;
        let ours = is_event_mti(msg.mti) && events.is_active();
        if ours {
            self.on_message(events, cx.out, msg);
        }
        ours
    }

    /// Event Transport has no interaction to reject.
    fn handle_error_report(&mut self, _: &mut Lent<'_>, _: NodeId, _: ErrorReport) -> bool {
        false
    }

    /// Nothing is open with a peer. (A lost link announces the node's events again: the
    /// node asks for that, as it has the declarations.)
    fn peer_changed(&mut self, _: &mut Outputs, _: ServiceChange) {}

    /// No timers.
    fn handle_timeout(&mut self, _: &mut Lent<'_>) {}

    fn poll_timeout(&self) -> Option<Instant> {
        None
    }
}

/// Identify Producer or Consumer: the Identified message for `event` if `list` declares it
/// (for an event inside a declared range, Identified for that event with the range's state,
/// as OpenMRN's range handlers answer).
fn answer(out: &mut Outputs, list: &[DeclaredEvents], role: EventRole, event: EventId) {
    if let Some(declared) = find(list, event) {
        out.reply(identified(out.node, role, DeclaredEvents::single(event, declared.state), event));
    }
}

/// Event Transport commands.
impl Node {
    /// Sends a Producer/Consumer Event Report for `event`, with `payload` after the Event ID
    /// if it is not empty (on CAN a report with payload travels as first/middle/last frames).
    pub fn send_event(&mut self, event: EventId, payload: &[u8]) -> Result<(), EventError> {
        let mut bytes = Vec::with_capacity(8 + payload.len());
        bytes.extend_from_slice(&event.to_bytes());
        bytes.extend_from_slice(payload);
        self.send_event_message(Mti::PRODUCER_CONSUMER_EVENT_REPORT, None, bytes)
    }

    /// Asks every node (`None`) or one for the events it produces and consumes; the answers
    /// come as [`EventNotice::Identified`] with [`Listen::Everything`].
    pub fn identify_events(&mut self, peer: Option<NodeId>) -> Result<(), EventError> {
        let mti = if peer.is_some() { Mti::IDENTIFY_EVENTS_ADDRESSED } else { Mti::IDENTIFY_EVENTS_GLOBAL };
        self.send_event_message(mti, peer, Vec::new())
    }

    /// Asks who produces (`EventRole::Producer`) or consumes `event`.
    pub fn identify(&mut self, role: EventRole, event: EventId) -> Result<(), EventError> {
        let mti = match role {
            EventRole::Producer => Mti::IDENTIFY_PRODUCER,
            EventRole::Consumer => Mti::IDENTIFY_CONSUMER,
        };
        self.send_event_message(mti, None, event.to_bytes().to_vec())
    }

    /// Sends Learn Event for `event` (teaching: the nodes in learn mode take it on).
    pub fn teach_event(&mut self, event: EventId) -> Result<(), EventError> {
        self.send_event_message(Mti::LEARN_EVENT, None, event.to_bytes().to_vec())
    }

    /// Produces and consumes what `events` declares from now on (a board whose events a tool
    /// has just configured), and identifies every declaration again, as after Initialization
    /// Complete, so that the network learns the new Event IDs (and Identify answers and
    /// reports follow them at once).
    pub fn set_events(&mut self, events: EventConfig) {
        let Node { config, services, .. } = self;
        config.events = events;
        services.events.announce(&config.events);
    }

    /// The event service's counters.
    pub fn event_stats(&self) -> EventStats {
        self.services.events.stats
    }

    fn send_event_message(&mut self, mti: Mti, to: Option<NodeId>, payload: Vec<u8>) -> Result<(), EventError> {
        if !self.out.has_room() {
            return Err(EventError::QueueFull);
        }
        let node = self.out.node;
        self.out.transmit(Message { mti, payload, source: node, destination: to });
        Ok(())
    }
}

/// The first declaration that holds `event`.
fn find(list: &[DeclaredEvents], event: EventId) -> Option<&DeclaredEvents> {
    list.iter().find(|d| d.range.contains(event))
}

/// Producer/Consumer Identified for `event` (a single declaration), or Range Identified.
fn identified(node: NodeId, role: EventRole, declared: DeclaredEvents, event: EventId) -> Message {
    let (single, range) = match role {
        EventRole::Producer => (Mti::PRODUCER_IDENTIFIED_VALID, Mti::PRODUCER_RANGE_IDENTIFIED),
        EventRole::Consumer => (Mti::CONSUMER_IDENTIFIED_VALID, Mti::CONSUMER_RANGE_IDENTIFIED),
    };
    if declared.range.is_single() {
        Message::global(Mti(single.0 | declared.state.mti_bits()), node, event.to_bytes().to_vec())
    } else {
        Message::global(range, node, declared.range.encoded().to_bytes().to_vec())
    }
}

/// The role of an Identified MTI, and its state (`None` for Range Identified).
fn identified_kind(mti: Mti) -> Option<(EventRole, Option<EventState>)> {
    match mti {
        Mti::PRODUCER_RANGE_IDENTIFIED => Some((EventRole::Producer, None)),
        Mti::CONSUMER_RANGE_IDENTIFIED => Some((EventRole::Consumer, None)),
        Mti(0x0544..=0x0547) => Some((EventRole::Producer, Some(EventState::from_mti(mti)))),
        Mti(0x04C4..=0x04C7) => Some((EventRole::Consumer, Some(EventState::from_mti(mti)))),
        _ => None,
    }
}

/// The MTIs Event Transport takes (all global but addressed Identify Events).
pub(crate) const fn is_event_mti(mti: Mti) -> bool {
    matches!(
        mti.0,
        0x08F4 | 0x04A4 | 0x04C4..=0x04C7 | 0x0914 | 0x0524 | 0x0544..=0x0547 | 0x0968 | 0x0970 | 0x0594 | 0x05B4
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    fn id(raw: u64) -> EventId {
        EventId(raw)
    }

    #[test]
    fn a_range_of_two_is_sent_with_its_low_bit_opposite_bit_one() {
        let range = EventRange::covering(id(0x0501_0101_2200_0010), 2).unwrap();
        assert_eq!(range.bits(), 1);
        assert_eq!(range.encoded(), id(0x0501_0101_2200_0011));
        assert_eq!(EventRange::from_encoded(range.encoded()), range);
        assert!(range.contains(id(0x0501_0101_2200_0011)) && !range.contains(id(0x0501_0101_2200_0012)));
        // Bit 1 set: the low bit is sent as 0.
        let odd = EventRange::covering(id(0x0501_0101_2200_0012), 2).unwrap();
        assert_eq!(odd.encoded(), id(0x0501_0101_2200_0012));
        assert_eq!(EventRange::from_encoded(odd.encoded()), odd);
    }

    #[test]
    fn ranges_of_256_and_65536() {
        let r8 = EventRange::covering(id(0x0501_0101_2200_0100), 256).unwrap();
        assert_eq!((r8.bits(), r8.encoded()), (8, id(0x0501_0101_2200_0100)));
        assert_eq!(r8.last(), id(0x0501_0101_2200_01FF));
        assert_eq!(EventRange::from_encoded(r8.encoded()), r8);
        let r16 = EventRange::covering(id(0x0501_0101_2200_0000), 0x1_0000).unwrap();
        assert_eq!((r16.bits(), r16.encoded()), (16, id(0x0501_0101_2200_FFFF)));
        assert_eq!(EventRange::from_encoded(r16.encoded()), r16);
        assert!(r16.contains(id(0x0501_0101_2200_1234)) && !r16.contains(id(0x0501_0101_2201_0000)));
    }

    #[test]
    fn a_base_that_is_not_aligned_is_rounded_to_the_covering_block() {
        // 0x..05 to 0x..0C straddles 0x08: the aligned block of 16 from 0x..00 holds it.
        let range = EventRange::covering(id(0x0501_0101_2200_0005), 8).unwrap();
        assert_eq!((range.first(), range.bits()), (id(0x0501_0101_2200_0000), 4));
        for raw in 0x0501_0101_2200_0005..=0x0501_0101_2200_000C {
            assert!(range.contains(id(raw)));
        }
    }

    #[test]
    fn a_range_of_one_is_a_single_event() {
        let one = EventRange::covering(id(0x0501_0101_2200_0007), 1).unwrap();
        assert!(one.is_single());
        assert_eq!(one, EventRange::single(id(0x0501_0101_2200_0007)));
        assert_eq!(EventRange::covering(id(1), 0), None);
        assert_eq!(EventRange::covering(id(u64::MAX), 2), None);
    }

    #[test]
    fn identified_mtis_carry_the_state() {
        let node = NodeId::new(0x05_01_01_01_22_01).unwrap();
        let e = id(0x0501_0101_2201_0001);
        let cases = [
            (EventRole::Producer, EventState::Valid, 0x0544),
            (EventRole::Producer, EventState::Invalid, 0x0545),
            (EventRole::Producer, EventState::Unknown, 0x0547),
            (EventRole::Consumer, EventState::Valid, 0x04C4),
            (EventRole::Consumer, EventState::Unknown, 0x04C7),
        ];
        for (role, state, mti) in cases {
            let msg = identified(node, role, DeclaredEvents::single(e, state), e);
            assert_eq!((msg.mti, msg.payload.as_slice()), (Mti(mti), e.to_bytes().as_slice()));
            assert_eq!(identified_kind(msg.mti), Some((role, Some(state))));
        }
    }
}
