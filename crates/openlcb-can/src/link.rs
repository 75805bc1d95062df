//! [`CanLink`]: one local node's adapter between full-format [`Message`]s and CAN frames.
//!
//! # Peers known only by their alias
//!
//! The alias cache is knowledge, never a gate (CFT §6.2.3 makes every node forget its
//! mappings on a global AME; conformance tools never answer Verify Node ID):
//!
//! - **Provisional names.** A message of any kind (global, addressed, stream data, datagram)
//!   from an alias whose Node ID is not cached is delivered at once, with the alias's
//!   provisional name as its source: [`NodeAlias::provisional_node_id`], `00.00.00.00.0A.AA`
//!   (a first byte of 0x00 is reserved and never a real node, UID §5.13). Nothing is held.
//! - **Learning passively.** The link never asks a peer for its Node ID just to serve it:
//!   conformance tools and busy 125 kbit/s buses see every frame. Mappings are learnt from
//!   what peers send anyway: AMD, Verified Node ID and Initialization Complete (a claimed
//!   Node ID that is itself provisional-looking, 00.00.00.00.0x.xx, is never learnt), and the
//!   AMDs a global AME provokes.
//! - **Renames.** Whenever the name the link uses for an alias changes, it hands
//!   [`PeerChange::Renamed`] to the layer above: on learning (provisional -> Node ID), on
//!   eviction of the least recently used entry from the full cache (Node ID -> provisional),
//!   and on a global AME for every cached entry (Node ID -> provisional; the cache is then
//!   cleared, and the AMDs the AME provokes rename the peers back). A mapping to a different
//!   Node ID than cached is [`PeerChange::Lost`] for the old Node ID, then takes the new one.
//!   An AMR is `Lost` with the alias's current name, real or provisional. A Node ID that
//!   turns up on a new alias moves there silently: its old alias is forgotten (the streams
//!   follow the Node ID, which did not change). The changes of one input are handed up before
//!   it returns and before the message it delivers (the layer above is an argument of
//!   [`CanLink::handle_frame`] and [`CanLink::handle_timeout`]), so evicting an entry loses no
//!   message and no stream, whatever the driver does.
//! - **Duplicate Node ID.** An AMD, Verified Node ID or Initialization Complete carrying this
//!   node's Node ID from another alias means another node holds it (CFT §6.2.5): the link
//!   reports [`LinkEvent::DuplicateNodeId`], saying whether it came within
//!   [`CanConfig::newcomer_window`] of this node's login (this node is then the newcomer: its
//!   owner should send the well-known event and [`leave`](CanLink::leave)), and goes on.
//! - **Outbound.** A message addressed to a provisional name goes straight to that alias: no
//!   cache lookup, no AME. A message to a real Node ID goes to its cached alias, or waits for
//!   an AME answer and is dropped after `resolve_timeout`: the node is then
//!   [`PeerChange::Lost`] to the layer above.
//!
//! A message that teaches a mapping (Verified Node ID, Initialization Complete) is delivered
//! under the new name, after its rename.
//!
//! # Datagrams
//!
//! Datagram frames (formats 2-5) to our alias are reassembled in
//! [`CanConfig::datagram_slots`] slots of 72 bytes keyed by (source alias, destination
//! alias), see [`Reassembler::for_datagrams`], and delivered whole as [`Mti::DATAGRAM`].
//! Framing errors are answered with Datagram Rejected (0x0A48) to the sender's alias and
//! counted in [`LinkStats::datagram_errors`]: a middle or last frame without a first 0x2041;
//! a first frame while one from the same source is open 0x2042 (both dropped); no free slot
//! at a first frame 0x2020; more than 72 bytes 0x1000 (permanent, as OpenMRN sends; the
//! partial datagram is dropped); no last frame within [`CanConfig::reassembly_timeout`] of
//! the first 0x2011. A single-frame datagram from a source with a datagram still open ends
//! the open one quietly (the sender has moved on). Each datagram gets exactly one answer,
//! however many senders crowd in (see [`Reassembler::for_datagrams`]). Datagram Received OK and
//! Rejected are ordinary addressed messages.

use alloc::vec::Vec;

use openlcb_stream::{Duration, Instant, Message, MessageRef, Mti, NodeId, PeerChange, PeerChanges, Receiver};

use crate::cache::AliasCache;
use crate::fragment::{Cursor, EncodeError, Fragments, FramePosition, event_report};
use crate::frame::{CanFrame, FrameError};
use crate::header::{self, CanHeader, FrameKind};
use crate::login::{AliasLogin, LoginEvent, LoginState};
use crate::reassembly::{Reassembler, ReassemblyError, ReassemblyErrorCounts, ReassemblyKey};
use crate::{NodeAlias, add, bump, earlier, node_bytes, push_bounded};
use openlcb_stream::Queue;

/// Events the link can have queued at once (its own status: permitted, alias lost, duplicate
/// Node ID); beyond that they are dropped and counted.
const EVENT_BOUND: usize = 16;

/// Bounds and timers of a [`CanLink`]. Every table and buffer it keeps is sized from here.
#[derive(Debug, Clone, PartialEq, Eq)]
#[non_exhaustive]
pub struct CanConfig {
    /// The first alias to try; `None` takes the first alias of the Technical Note's
    /// generator seeded with the Node ID. Retries always come from the generator.
    pub first_alias: Option<NodeAlias>,
    /// How long to wait after the CID frames before RID (CFT §6.2.1: at least 200 ms).
    pub reserve_wait: Duration,
    /// Remote alias mappings kept (least recently used evicted first).
    pub alias_cache_size: usize,
    /// Addressed multi-frame messages assembled at once.
    pub reassembly_slots: usize,
    /// The longest addressed message payload reassembled, in bytes.
    pub max_message_len: usize,
    /// How long a multi-frame message may wait for its next frame, and a datagram for its
    /// last frame counted from its first (0x2011 after that).
    pub reassembly_timeout: Duration,
    /// Datagrams (formats 3-5) assembled at once, 72 bytes each.
    pub datagram_slots: usize,
    /// Answer reassembly errors that lose a message (0x2041, 0x2011, and 0x2020 for no room)
    /// with Optional Interaction Rejected to the sender, quoting the MTI. 0x2042 is only
    /// counted: the message it starts goes on.
    pub reject_reassembly_errors: bool,
    /// Messages accepted by [`CanLink::send`] and not yet framed (including those waiting
    /// for an alias). More are refused with [`SendError::QueueFull`].
    pub transmit_queue_limit: usize,
    /// Of those, the messages that may wait for their destination's alias at once (an AME
    /// out for it); more are refused with [`SendError::QueueFull`]. A board that answers
    /// tools, which it hears from first, needs few.
    pub unresolved_limit: usize,
    /// Frames the link itself queues (AME, OIR, Datagram Rejected, and
    /// Initialization Complete after a re-login, first into the queue emptied with the old
    /// alias); more are dropped and counted.
    pub frame_queue_limit: usize,
    /// How long to wait for an AME answer for a Node ID we want to send to.
    pub resolve_timeout: Duration,
    /// A duplicate Node ID found within this long of the alias being permitted makes this
    /// node the newcomer ([`LinkEvent::DuplicateNodeId`]): the node that was there first
    /// answers the newcomer's announcements within it (the global Verify Node ID naming
    /// itself that nodes send after Initialization Complete).
    pub newcomer_window: Duration,
}

impl Default for CanConfig {
    fn default() -> Self {
        CanConfig {
            first_alias: None,
            reserve_wait: Duration::from_millis(200),
            alias_cache_size: 64,
            reassembly_slots: 8,
            max_message_len: 256,
            reassembly_timeout: Duration::from_secs(3),
            reject_reassembly_errors: true,
            transmit_queue_limit: 64,
            unresolved_limit: 64,
            frame_queue_limit: 16,
            resolve_timeout: Duration::from_secs(1),
            newcomer_window: Duration::from_millis(500),
            datagram_slots: 4,
        }
    }
}

/// A change of the link's own status, for the driver to know or act on.
///
/// Changes of peer (a peer gone, renamed, unreachable) are not events: the link hands them to
/// the layer above as it learns them ([`PeerChange`], through the [`Receiver`] passed to
/// [`CanLink::handle_frame`] and [`CanLink::handle_timeout`]). These events are not ordering
/// critical, so a queue is enough: an alias loss drops every queued and partial message with
/// the alias, and no message for this node can arrive before the new login, which takes a
/// [`handle_timeout`](CanLink::handle_timeout) after the reserve wait; a duplicate Node ID's
/// message is not delivered. Drain them after each input all the same.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[non_exhaustive]
pub enum LinkEvent {
    /// The alias is reserved and announced; queued messages now go out.
    Permitted {
        /// The local alias.
        alias: NodeAlias,
    },
    /// Another node used our alias: AMR was queued and a new login started. Call
    /// `StreamEndpoint::link_lost`: streams on the old alias are over. After the new login
    /// the link sends Initialization Complete itself.
    AliasLost {
        /// The released alias.
        alias: NodeAlias,
    },
    /// Another node announced this node's Node ID (AMD, Verified Node ID or Initialization
    /// Complete from another alias). The link goes on; it reports one alias at most once a
    /// second. Send the well-known event Duplicate Node ID Detected; a `newcomer` should then
    /// [`leave`](CanLink::leave) the network, the node that was there first keeps running.
    DuplicateNodeId {
        /// That node's alias.
        other: NodeAlias,
        /// Found within [`CanConfig::newcomer_window`] of this node's login: this node came
        /// second.
        newcomer: bool,
    },
}

/// Why [`CanLink::send`] refused a message (it is dropped and counted).
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
pub enum SendError {
    /// The link has left the network ([`CanLink::leave`]).
    #[error("the link has left the network")]
    Stopped,
    /// [`CanConfig::transmit_queue_limit`] messages are queued.
    #[error("the transmit queue is full")]
    QueueFull,
    /// The message has no CAN form.
    #[error(transparent)]
    Encode(#[from] EncodeError),
}

/// Frames and messages ignored, refused or dropped, by cause. Each counter stops at
/// `u32::MAX` (32 bits: 64-bit counters cost flash on a microcontroller).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
#[non_exhaustive]
pub struct LinkStats {
    /// Frames handled.
    pub frames_in: u32,
    /// Frames returned by `poll_transmit`.
    pub frames_out: u32,
    /// Standard (11-bit) frames ignored.
    pub standard_ignored: u32,
    /// Remote frames ignored.
    pub remote_ignored: u32,
    /// Frames with a bad header, an addressed frame shorter than 2 bytes, or a stream frame
    /// without DID.
    pub invalid_frames: u32,
    /// Addressed and stream frames for another node.
    pub not_for_us: u32,
    /// Frames of the reserved formats 0 and 6 ignored.
    pub unsupported_ignored: u32,
    /// AMD, Verified Node ID or Initialization Complete claiming our Node ID from another
    /// alias (each a duplicate Node ID; the messages are not delivered).
    pub own_node_claims: u32,
    /// 0x2041: a middle or last frame of an addressed message without a first (datagrams:
    /// `datagram_errors`).
    pub middle_without_first: u32,
    /// 0x2042: a first frame of an addressed message before the previous one ended.
    pub first_before_last_ended: u32,
    /// 0x2011: no last frame of an addressed message in time.
    pub reassembly_timeouts: u32,
    /// Multi-frame messages longer than `max_message_len`, or with no free slot.
    pub reassembly_overflows: u32,
    /// Datagram framing errors, each answered with Datagram Rejected.
    pub datagram_errors: ReassemblyErrorCounts,
    /// Messages delivered with a provisional name (their sender's Node ID was not cached).
    pub provisional_deliveries: u32,
    /// Messages to send dropped because no alias was found for their destination.
    pub unresolved_dropped: u32,
    /// Messages refused by `send`.
    pub send_refused: u32,
    /// Queued messages dropped when the alias was lost or the link stopped.
    pub messages_dropped: u32,
    /// Link-originated frames or events dropped because their queue was full.
    pub queue_overflows: u32,
}

/// A message accepted by `send`: ready to frame, or waiting for its destination's alias.
#[derive(Debug)]
struct Outgoing {
    message: Message,
    /// The destination alias (`None` for a global message and while waiting for the alias).
    destination: Option<NodeAlias>,
    /// While waiting: when to give up, set once the AME went out.
    deadline: Option<Instant>,
    /// Stream control in the lane that overtakes stream data (see [`CanLink::ready`]).
    ahead: bool,
}

impl Outgoing {
    fn new(message: Message, destination: Option<NodeAlias>) -> Self {
        Outgoing { message, destination, deadline: None, ahead: false }
    }

    /// A destination's answers (Initiate Reply, Proceed): the lane that goes between two
    /// frames of stream data.
    fn is_stream_control(&self) -> bool {
        matches!(self.message.mti, Mti::STREAM_INITIATE_REPLY | Mti::STREAM_DATA_PROCEED)
    }

    /// Stream data or the Complete behind it: what stream control may overtake.
    fn is_stream_data(&self) -> bool {
        matches!(self.message.mti, Mti::STREAM_DATA_SEND | Mti::STREAM_DATA_COMPLETE)
    }

    /// The message waits for (or was sent to) the alias of `node`.
    fn is_for(&self, node: NodeId) -> bool {
        self.message.destination == Some(node)
    }
}

/// One node's CAN adapter: alias login, framing, reassembly (messages and datagrams) and
/// alias resolution, so that the stream endpoint speaks in Node IDs only. See the crate
/// documentation for the drive loop.
///
/// A peer whose Node ID is not cached is served at once under its provisional name
/// ([`NodeAlias::provisional_node_id`]); its Node ID is learnt from what it sends anyway
/// (AMD, Verified Node ID, Initialization Complete), never asked for, and every change of the name of
/// an alias is reported as [`PeerChange::Renamed`]: learnt (provisional -> Node ID),
/// evicted from the full cache or a global AME (Node ID -> provisional). A mapping to another
/// Node ID than cached reports [`PeerChange::Lost`] for the old one; an AMR reports
/// `Lost` under the current name. Messages to a provisional name go straight to its
/// alias. Every such change is handed to the layer above (the [`Receiver`] passed to
/// [`handle_frame`](Self::handle_frame) and [`handle_timeout`](Self::handle_timeout)) before
/// that call returns and before any later message is delivered: no driver can apply a rename
/// late.
#[derive(Debug)]
#[repr(C)] // Fields in the order written: short Thumb loads reach the ones read first.
pub struct CanLink {
    node: NodeId,
    config: CanConfig,
    login: AliasLogin,
    announced: bool,
    cache: AliasCache,
    reassembly: Reassembler,
    datagrams: Reassembler,
    frames: Queue<CanFrame>,
    /// Messages ready to send, in the order they came (stream data, a stream's Complete
    /// behind its data, a datagram such as an Unfreeze behind the stream before it), but for
    /// those marked [`ahead`](Outgoing::ahead): stream control ([`Outgoing::is_stream_control`])
    /// that came when only stream data waited. Those go first, in their own order, before the
    /// next frame of stream data, as a Reply or a Proceed must not wait behind this node's own
    /// data to others (which loses arbitration on a busy bus, as all stream data does).
    messages: Queue<Outgoing>,
    /// The message being framed, from `messages`; other frames go between its frames only
    /// if it is stream data.
    current: Option<Fragments<Vec<u8>>>,
    /// The stream control message being framed (one that was ahead).
    current_control: Option<Fragments<Vec<u8>>>,
    /// Messages waiting for their destination's alias (an AME answer).
    unresolved: Queue<Outgoing>,
    /// When the alias was last permitted (for [`CanConfig::newcomer_window`]).
    permitted_at: Instant,
    /// The last duplicate Node ID reported: the other alias, and when.
    last_duplicate: Option<(NodeAlias, Instant)>,
    /// [`leave`](Self::leave) was called: AMR goes out once the queued messages have.
    leaving: bool,
    events: Queue<LinkEvent>,
    stats: LinkStats,
}

impl CanLink {
    /// A link for `node`, starting its alias login at `now` (the CID frames are the first
    /// transmits). All tables are allocated here, at their configured bounds.
    pub fn new(now: Instant, node: NodeId, config: CanConfig) -> Self {
        let login = AliasLogin::new(now, node, config.first_alias, config.reserve_wait);
        CanLink {
            node,
            login,
            announced: false,
            cache: AliasCache::new(config.alias_cache_size),
            reassembly: Reassembler::new(config.reassembly_slots, config.max_message_len, config.reassembly_timeout),
            datagrams: Reassembler::for_datagrams(config.datagram_slots, config.reassembly_timeout),
            frames: Queue::with_capacity(config.frame_queue_limit),
            messages: Queue::with_capacity(config.transmit_queue_limit),
            current: None,
            current_control: None,
            unresolved: Queue::with_capacity(config.unresolved_limit.min(config.transmit_queue_limit)),
            permitted_at: now,
            last_duplicate: None,
            leaving: false,
            events: Queue::with_capacity(EVENT_BOUND),
            stats: LinkStats::default(),
            config,
        }
    }

    // ----- getters -----

    /// The local Node ID.
    pub fn node_id(&self) -> NodeId {
        self.node
    }

    /// The local alias, once permitted.
    pub fn alias(&self) -> Option<NodeAlias> {
        self.login.alias()
    }

    /// The alias login (state and counters).
    pub fn login(&self) -> &AliasLogin {
        &self.login
    }

    /// The configuration.
    pub fn config(&self) -> &CanConfig {
        &self.config
    }

    /// Counters.
    pub fn stats(&self) -> LinkStats {
        self.stats
    }

    /// The cached alias of a remote node.
    pub fn alias_of(&self, node: NodeId) -> Option<NodeAlias> {
        self.cache.peek_alias(node)
    }

    /// The cached node holding a remote alias.
    pub fn node_of(&self, alias: NodeAlias) -> Option<NodeId> {
        self.cache.peek_node(alias)
    }

    /// The name messages from `alias` carry now: its cached Node ID, else its provisional
    /// name.
    pub fn name_of(&self, alias: NodeAlias) -> NodeId {
        self.cache.peek_node(alias).unwrap_or(alias.provisional_node_id())
    }

    /// Remote alias mappings cached now (at most [`CanConfig::alias_cache_size`]).
    pub fn cached_aliases(&self) -> usize {
        self.cache.len()
    }

    /// Payload bytes held in partly reassembled messages and datagrams; never more than
    /// [`reassembly_bound`](Self::reassembly_bound).
    pub fn reassembly_in_use(&self) -> usize {
        self.reassembly.buffered() + self.datagrams.buffered()
    }

    /// The bound of [`reassembly_in_use`](Self::reassembly_in_use): `reassembly_slots` times
    /// `max_message_len` plus `datagram_slots` times 72.
    pub fn reassembly_bound(&self) -> usize {
        self.reassembly.bound().saturating_add(self.datagrams.bound())
    }

    /// Bytes allocated for reassembly buffers: fixed when the link is made.
    #[cfg(feature = "fuzzing")]
    pub(crate) fn reassembly_allocated(&self) -> usize {
        self.reassembly.allocated() + self.datagrams.allocated()
    }

    /// Messages accepted by `send` and not yet fully framed.
    pub fn queued_messages(&self) -> usize {
        self.messages.len()
            + self.unresolved.len()
            + usize::from(self.current.as_ref().is_some_and(Fragments::has_more))
            + usize::from(self.current_control.as_ref().is_some_and(Fragments::has_more))
    }

    /// `send` has room for another message. A driver that must not lose stream data polls
    /// the endpoint only while this holds (the endpoint keeps the rest queued).
    pub fn can_send(&self) -> bool {
        !self.has_stopped() && !self.queue_full()
    }

    /// [`leave`](Self::leave) was called: the link takes no more messages.
    fn has_stopped(&self) -> bool {
        self.leaving || self.login.state() == LoginState::Stopped
    }

    /// The link has left the network: its AMR is out (or it never held an alias) and it will
    /// send nothing more.
    pub fn has_left(&self) -> bool {
        self.login.state() == LoginState::Stopped
    }

    /// [`CanConfig::transmit_queue_limit`] messages are queued (ready or waiting for an alias).
    #[inline(always)]
    fn queue_full(&self) -> bool {
        self.messages.len() + self.unresolved.len() >= self.config.transmit_queue_limit
    }

    // ----- commands -----

    /// Queues `message` for transmission. Addressed messages to a provisional name
    /// ([`NodeAlias::provisional_node_id`]) go straight to that alias; others go to the cached
    /// alias of their destination, and an unknown destination is resolved with an AME first
    /// (messages wait, at most [`CanConfig::resolve_timeout`], then they are dropped and the
    /// destination is [`PeerChange::Lost`]). Messages wait until the alias is permitted. Takes no
    /// allocation.
    pub fn send(&mut self, now: Instant, message: Message) -> Result<(), SendError> {
        let result = self.enqueue(now, message);
        if result.is_err() {
            bump(&mut self.stats.send_refused);
        }
        result
    }

    fn enqueue(&mut self, now: Instant, message: Message) -> Result<(), SendError> {
        if self.has_stopped() {
            return Err(SendError::Stopped);
        }
        let addressed = message.mti.is_addressed();
        let destination = if addressed { message.destination } else { None };
        // Check the message has a CAN form now, so that failures reach the caller.
        let placeholder = NodeAlias::MAX;
        Cursor::new(message.mti, placeholder, destination.map(|_| placeholder), message.payload.len())?;
        if self.queue_full() {
            return Err(SendError::QueueFull);
        }
        let resolved = destination.map(|node| self.alias_for(node)).transpose();
        if resolved.is_err() && self.unresolved.len() >= self.config.unresolved_limit {
            return Err(SendError::QueueFull);
        }
        let mut outgoing = Outgoing::new(message, None);
        match resolved {
            Ok(alias) => {
                outgoing.destination = alias;
                self.ready(outgoing);
            }
            Err(deadline) => {
                outgoing.deadline = deadline;
                // Never refused: the queues together and this one are below their limits.
                self.unresolved.push_within(self.config.unresolved_limit, outgoing);
            }
        }
        if resolved.is_err() {
            self.send_enquiries(now);
        }
        Ok(())
    }

    /// Queues a message whose destination alias is known, in its lane. Never refused: the
    /// queues together hold at most the limit (the callers checked).
    fn ready(&mut self, mut outgoing: Outgoing) {
        // Ahead of stream data only, never of another message queued before it (the scan
        // runs for stream control only: once per window).
        outgoing.ahead = outgoing.is_stream_control() && self.messages.iter().all(|m| m.ahead || m.is_stream_data());
        self.messages.push_within(self.config.transmit_queue_limit, outgoing);
    }

    /// The alias to send to `node`: its provisional alias, or its cached one unless messages
    /// already wait for it; else `Err` with the deadline of the AME out for it, if one is.
    fn alias_for(&mut self, node: NodeId) -> Result<NodeAlias, Option<Instant>> {
        if let Some(alias) = NodeAlias::from_provisional(node) {
            return Ok(alias);
        }
        // A node already being resolved shares the AME out for it and its deadline.
        let alias = self.cache.alias(node);
        match self.unresolved.iter().find(|u| u.is_for(node)) {
            Some(waiting) => Err(waiting.deadline),
            None => alias.ok_or(None),
        }
    }

    /// Leaves the network, as a node does that found it came second with a duplicate Node
    /// ID: every queued message is dropped, `farewell` goes out (a global message, such as
    /// the well-known event Duplicate Node ID Detected), then AMR releases the alias (CFT
    /// §6.2.4), and nothing more. `send` refuses from now on; [`has_left`](Self::has_left)
    /// tells when the AMR is out.
    pub fn leave(&mut self, farewell: Option<Message>) {
        self.drop_traffic();
        if let Some(message) = farewell.filter(|m| !m.mti.is_addressed()) {
            self.messages.push_within(self.config.transmit_queue_limit, Outgoing::new(message, None));
        }
        self.leaving = true;
    }

    // ----- outputs -----

    /// The next frame to put on the bus. Login frames first; once permitted, frames the link
    /// originates, then the frames of queued messages, each message's frames back to back
    /// (only control frames go between them, MN §7.3.7).
    pub fn poll_transmit(&mut self) -> Option<CanFrame> {
        let frame = self.next_frame()?;
        bump(&mut self.stats.frames_out);
        Some(frame)
    }

    /// Every frame `poll_transmit` handed out so far was sent by `now` (given to the
    /// peripheral, or written). A driver says so after each batch it sends, so that the alias
    /// login's reserve wait counts from the CID frames on the bus rather than from when they
    /// were queued ([`AliasLogin::frames_sent`]); one comparison when no login is under way.
    pub fn frames_sent(&mut self, now: Instant) {
        self.login.frames_sent(now);
    }

    fn next_frame(&mut self) -> Option<CanFrame> {
        if let Some(frame) = self.login.poll_transmit() {
            return Some(frame);
        }
        let alias = self.login.alias()?;
        // Inside a message that is not stream data no other message's frame goes between.
        let inside = |current: &Option<Fragments<Vec<u8>>>| current.as_ref().is_some_and(Fragments::is_inside);
        let mut inside_current = inside(&self.current);
        if let Some(front) = self.frames.front()
            && (!(inside_current || inside(&self.current_control)) || !header::is_message_id(front.raw_id()))
        {
            return self.frames.pop_front();
        }
        loop {
            if let Some(control) = self.current_control.as_mut() {
                if let Some(frame) = control.next() {
                    return Some(frame);
                }
                self.current_control = None;
            }
            // Stream control between two frames of stream data, never inside another message
            // (so a message that is ahead is never taken below as the next message).
            if !inside_current
                && let Some(index) = self.messages.iter().position(|m| m.ahead)
                && let Some(outgoing) = self.messages.remove(index)
            {
                self.current_control = self.fragments(alias, outgoing);
                continue;
            }
            if let Some(frame) = self.current.as_mut().and_then(Iterator::next) {
                return Some(frame);
            }
            self.current = None;
            let Some(outgoing) = self.messages.pop_front() else { return self.leave_now() };
            self.current = self.fragments(alias, outgoing);
            inside_current = inside(&self.current);
        }
    }

    /// The frames of `outgoing`, sent from `alias` (`None`, counted, if it has no CAN form).
    fn fragments(&mut self, alias: NodeAlias, outgoing: Outgoing) -> Option<Fragments<Vec<u8>>> {
        let Outgoing { message, destination, .. } = outgoing;
        let fragments = Fragments::new(message.mti, alias, destination, message.payload);
        if fragments.is_err() {
            bump(&mut self.stats.send_refused);
        }
        fragments.ok()
    }

    /// Once leaving and nothing is left to send but frames of the link's own: the AMR.
    fn leave_now(&mut self) -> Option<CanFrame> {
        if !self.leaving {
            return None;
        }
        self.leaving = false;
        self.frames.clear();
        self.login.release();
        self.login.poll_transmit()
    }

    /// The next event of the link's own status (peer changes go to the layer above as they
    /// happen).
    pub fn poll_event(&mut self) -> Option<LinkEvent> {
        self.events.pop_front()
    }

    /// When to call `handle_timeout` next.
    pub fn poll_timeout(&self) -> Option<Instant> {
        let mut next = self.login.poll_timeout();
        self.reassembly.earliest_into(&mut next);
        self.datagrams.earliest_into(&mut next);
        for waiting in self.unresolved.iter() {
            earlier(&mut next, waiting.deadline);
        }
        next
    }

    // ----- inputs -----

    /// Runs every timer due at `now`: the login's reserve wait, reassembly timeouts (0x2011,
    /// for messages and datagrams) and alias resolutions that ran out. A destination no alias
    /// was found for is [`PeerChange::Lost`] to `above` (its messages are dropped) before this
    /// returns. Early or repeated calls are harmless.
    pub fn handle_timeout<A: PeerChanges + ?Sized>(&mut self, now: Instant, mut above: &mut A) {
        self.run_timers(now, &mut above);
    }

    /// [`handle_timeout`](Self::handle_timeout) through `dyn`: one copy whatever the layer
    /// above.
    #[inline(never)]
    fn run_timers(&mut self, now: Instant, above: Above<'_>) {
        if let Some(event) = self.login.timeout(now) {
            self.login_event(now, event);
        }
        loop {
            let expired = self.reassembly.take_expired(now).or_else(|| self.datagrams.take_expired(now));
            let Some(key) = expired else { break };
            self.reassembly_error(key, ReassemblyError::Timeout);
        }
        loop {
            let expired = self.unresolved.iter().find(|u| u.deadline.is_some_and(|d| d <= now));
            let Some(node) = expired.and_then(|u| u.message.destination) else { break };
            let dropped = self.unresolved.retain(|u| !u.is_for(node));
            add(&mut self.stats.unresolved_dropped, dropped);
            above.peer_changed(PeerChange::Lost(node));
        }
    }

    /// Feeds one received frame. Every peer change it reveals ([`PeerChange`]: a Node ID
    /// learnt, a mapping forgotten or replaced, an alias released) is handed to `above` first,
    /// then the complete message it ends, if any, for this node (or global), borrowing its
    /// payload from `frame` (single frames, stream data) or from the link's reassembly
    /// buffer: nothing is allocated. A message from an alias whose Node ID is not cached
    /// carries the alias's provisional name as its source.
    ///
    /// So a rename is applied above the link before this call returns, and before the
    /// message that taught it (a Verified Node ID, an Initialization Complete) arrives under
    /// the new name: the next message from that alias finds its streams under that name. The
    /// driver has nothing to apply between two frames.
    pub fn handle_frame<A: Receiver + ?Sized>(&mut self, now: Instant, frame: &CanFrame, mut above: &mut A) {
        self.receive(now, frame, &mut above);
    }

    /// [`handle_frame`](Self::handle_frame) through `dyn`: one copy of the receive path
    /// whatever the layer above.
    #[inline(never)]
    fn receive(&mut self, now: Instant, frame: &CanFrame, above: &mut dyn Receiver) {
        bump(&mut self.stats.frames_in);
        let header = match frame.header() {
            Ok(header) => header,
            Err(FrameError::Standard) => return bump(&mut self.stats.standard_ignored),
            Err(FrameError::Remote) => return bump(&mut self.stats.remote_ignored),
            Err(_) => return bump(&mut self.stats.invalid_frames),
        };
        let data = frame.payload();
        // Before the login sees the frame, which may move it to another alias.
        let from_our_alias = self.login.holds(header.source);
        if let Some(event) = self.login.header(now, &header, data) {
            self.login_event(now, event);
        }
        if from_our_alias {
            return;
        }
        let source = header.source;
        // Every message frame, whatever its format: its MTI, its destination alias (read for
        // addressed MTIs only), where it sits in its message, and its payload.
        let (mti, destination, position, body) = match header.kind {
            FrameKind::AliasMapDefinition => {
                // One with our Node ID is the login's to report.
                if let Some(node) = NodeId::from_slice(data) {
                    self.learn(source, node, above);
                }
                return;
            }
            FrameKind::AliasMapReset => return self.forget(source, above),
            // CFT §6.2.3: a global AME drops every cached mapping; the AMDs it causes refill it.
            FrameKind::AliasMapEnquiry if data.is_empty() => return self.forget_all_mappings(above),
            FrameKind::Message { can_mti } => {
                let mti = Mti(can_mti);
                if let Some(position) = event_report::position(can_mti) {
                    // A report with payload: global, so keyed by its source alone.
                    (Mti::PRODUCER_CONSUMER_EVENT_REPORT, None, position, data)
                } else if mti.is_addressed() {
                    let [flags_and_high, low, body @ ..] = data else {
                        return bump(&mut self.stats.invalid_frames);
                    };
                    let destination = NodeAlias::new(u16::from_be_bytes([flags_and_high & 0x0F, *low]));
                    (mti, destination, FramePosition::from_flags(*flags_and_high), body)
                } else {
                    if mti.announces_sender() {
                        match NodeId::from_slice(data) {
                            Some(node) if node == self.node => return self.duplicate(now, source),
                            Some(node) => self.learn(source, node, above),
                            None => {}
                        }
                    }
                    (mti, None, FramePosition::Only, data)
                }
            }
            FrameKind::StreamData { destination } => {
                above.medium_busy(now);
                (Mti::STREAM_DATA_SEND, Some(destination), FramePosition::Only, data)
            }
            FrameKind::Datagram { frame, destination } => (Mti::DATAGRAM, Some(destination), frame.position(), data),
            FrameKind::ReservedFormat { .. } => return bump(&mut self.stats.unsupported_ignored),
            _ => return,
        };
        // Addressed messages, stream data and datagrams are ours only if sent to our alias; a
        // global message in several frames is keyed by its source alone.
        let addressee = if mti.is_addressed() {
            match self.login.alias() {
                Some(ours) if destination == Some(ours) => ours,
                _ => return bump(&mut self.stats.not_for_us),
            }
        } else {
            source
        };
        if mti == Mti::STREAM_DATA_SEND && body.is_empty() {
            // Wire-spec §7.3: DLC 0 is invalid (no DID).
            return bump(&mut self.stats.invalid_frames);
        }
        let key = ReassemblyKey { source, destination: addressee, mti };
        let whole = if position == FramePosition::Only {
            if mti == Mti::DATAGRAM {
                // A whole datagram: the sender has given up any datagram it left open.
                self.datagrams.discard(key);
            }
            // The usual case: the payload is handed over straight from the frame.
            None
        } else {
            match self.reassembler(mti).add(now, key, position, body) {
                Ok(Some(slot)) => Some(slot),
                Ok(None) => return,
                Err(error) => return self.reassembly_error(key, error),
            }
        };
        let source = self.name_sender(source);
        let destination = mti.is_addressed().then_some(self.node);
        // A whole multi-frame message stays in its slot until the next frame is added there.
        let payload = match whole {
            Some(slot) => self.reassembler(mti).completed(slot),
            None => body,
        };
        above.handle_message(now, MessageRef { mti, source, destination, payload });
    }

    // ----- received messages -----

    /// The reassembler for messages of `mti`: datagrams or addressed messages.
    fn reassembler(&mut self, mti: Mti) -> &mut Reassembler {
        if mti == Mti::DATAGRAM { &mut self.datagrams } else { &mut self.reassembly }
    }

    /// The name of `source` for a whole message from it: its cached Node ID, or its
    /// provisional name (nothing is asked: the Node ID is learnt from what the peer sends).
    fn name_sender(&mut self, source: NodeAlias) -> NodeId {
        match self.cache.node(source) {
            Some(node) => node,
            None => {
                bump(&mut self.stats.provisional_deliveries);
                source.provisional_node_id()
            }
        }
    }

    /// Another alias claimed our Node ID: reported, at most once a second per alias.
    fn duplicate(&mut self, now: Instant, other: NodeAlias) {
        bump(&mut self.stats.own_node_claims);
        let again = Duration::from_secs(1);
        if self.last_duplicate.is_some_and(|(alias, at)| alias == other && now < at + again) {
            return;
        }
        self.last_duplicate = Some((other, now));
        let newcomer = now < self.permitted_at + self.config.newcomer_window;
        self.event(LinkEvent::DuplicateNodeId { other, newcomer });
    }

    /// Records `alias` <-> `node`, reports the renames it causes, and releases messages
    /// waiting for `node`'s alias.
    fn learn(&mut self, alias: NodeAlias, node: NodeId, above: Above<'_>) {
        if node == self.node || NodeAlias::from_provisional(node).is_some() {
            return;
        }
        let previous = self.cache.peek_node(alias);
        if let Some(old) = previous.filter(|old| *old != node) {
            above.peer_changed(PeerChange::Lost(old));
        }
        if let Some((evicted, evicted_node)) = self.cache.insert(alias, node) {
            unname(evicted, evicted_node, above);
        }
        if previous.is_none() {
            above.peer_changed(PeerChange::Renamed { from: alias.provisional_node_id(), to: node });
        }
        while let Some(index) = self.unresolved.iter().position(|waiting| waiting.is_for(node)) {
            if let Some(mut waiting) = self.unresolved.remove(index) {
                waiting.destination = Some(alias);
                self.ready(waiting);
            }
        }
    }

    /// A peer released `alias` (AMR): forget it, drop what was queued for it or from it, and
    /// report it lost under its current name.
    fn forget(&mut self, alias: NodeAlias, above: Above<'_>) {
        self.reassembly.forget_source(alias);
        self.datagrams.forget_source(alias);
        let dropped = self.messages.retain(|m| m.destination != Some(alias));
        add(&mut self.stats.messages_dropped, dropped);
        let node = self.cache.remove_alias(alias).unwrap_or(alias.provisional_node_id());
        above.peer_changed(PeerChange::Lost(node));
    }

    /// A global AME (CFT §6.2.3): every cached peer goes back to its provisional name.
    fn forget_all_mappings(&mut self, above: Above<'_>) {
        while let Some((alias, node)) = self.cache.pop() {
            unname(alias, node, above);
        }
    }

    /// Counts an error of the message or datagram `key` and answers it: a datagram with
    /// Datagram Rejected (DG §7.3.2), a message with Optional Interaction Rejected quoting its
    /// MTI if so configured (never for 0x2042).
    fn reassembly_error(&mut self, key: ReassemblyKey, error: ReassemblyError) {
        let ReassemblyKey { source, mti, .. } = key;
        // The answer's payload: the error code, then (OIR only) the MTI it answers.
        let (answer, code, len) = if mti == Mti::DATAGRAM {
            self.stats.datagram_errors.record(error);
            (Mti::DATAGRAM_REJECTED, error.datagram_code(), 2)
        } else {
            let counter = match error {
                ReassemblyError::MiddleWithoutFirst => &mut self.stats.middle_without_first,
                ReassemblyError::FirstBeforeLastEnded => &mut self.stats.first_before_last_ended,
                ReassemblyError::Timeout => &mut self.stats.reassembly_timeouts,
                _ => &mut self.stats.reassembly_overflows,
            };
            bump(counter);
            // A global message (a report with payload) is never answered.
            let global = !mti.is_addressed();
            if !self.config.reject_reassembly_errors || error == ReassemblyError::FirstBeforeLastEnded || global {
                return;
            }
            (Mti::OPTIONAL_INTERACTION_REJECTED, error.code(), 4)
        };
        let [c0, c1] = code.0.to_be_bytes();
        let [m0, m1] = mti.0.to_be_bytes();
        self.queue_addressed(answer, source, [c0, c1, m0, m1].get(..len).unwrap_or(&[]));
    }

    /// Queues a one-frame addressed message of the link's own (at most 6 payload bytes) from
    /// our alias to `to`, once permitted.
    fn queue_addressed(&mut self, mti: Mti, to: NodeAlias, payload: &[u8]) {
        // Data bytes 0-1: framing flags 00 (the only frame) and the destination alias.
        self.queue_message(mti, &to.as_raw().to_be_bytes(), payload);
    }

    /// Queues a one-frame message of the link's own from our alias, data `head` then `body`
    /// (at most 8 bytes in all), once permitted.
    fn queue_message(&mut self, mti: Mti, head: &[u8], body: &[u8]) {
        if let Some(ours) = self.login.alias() {
            self.queue_frame(CanHeader::message(mti, ours).to_id(), head, body);
        }
    }

    // ----- login and alias resolution -----

    /// Acts on what the login reported, if anything.
    fn login_event(&mut self, now: Instant, event: LoginEvent) {
        match event {
            LoginEvent::Permitted { alias } => {
                self.permitted_at = now;
                if self.announced {
                    // After a re-login the endpoint will not announce the node again: the
                    // link does, first of all (its frame queue was emptied with the alias).
                    self.queue_message(Mti::INITIALIZATION_COMPLETE, &node_bytes(self.node), &[]);
                }
                self.announced = true;
                self.send_enquiries(now);
                self.event(LinkEvent::Permitted { alias });
            }
            LoginEvent::Lost { alias } => {
                self.drop_traffic();
                self.event(LinkEvent::AliasLost { alias });
            }
            LoginEvent::DuplicateNodeId { other } => self.duplicate(now, other),
            _ => {}
        }
    }

    /// Everything tied to the old alias goes: queued messages, partial messages and
    /// datagrams, frames of the link's own.
    fn drop_traffic(&mut self) {
        let queued = self.queued_messages();
        add(&mut self.stats.messages_dropped, queued);
        self.messages.clear();
        self.unresolved.clear();
        self.current = None;
        self.current_control = None;
        self.frames.clear();
        self.reassembly.clear();
        self.datagrams.clear();
    }

    /// Sends an AME for every node waiting for its alias that has not had one, once permitted.
    fn send_enquiries(&mut self, now: Instant) {
        let Some(ours) = self.login.alias() else {
            return;
        };
        let deadline = now + self.config.resolve_timeout;
        let id = CanHeader::control(FrameKind::AliasMapEnquiry, ours).to_id();
        loop {
            let unasked = self.unresolved.iter().find(|u| u.deadline.is_none());
            let Some(node) = unasked.and_then(|u| u.message.destination) else { break };
            for waiting in self.unresolved.iter_mut() {
                if waiting.is_for(node) {
                    waiting.deadline = Some(deadline);
                }
            }
            self.queue_frame(id, &node_bytes(node), &[]);
        }
    }

    /// Queues a frame of the link's own: identifier `id`, data `head` then `body` (at most 8
    /// bytes in all).
    fn queue_frame(&mut self, id: u32, head: &[u8], body: &[u8]) {
        let frame = CanFrame::build(id, head, body);
        push_bounded(&mut self.frames, self.config.frame_queue_limit, frame, &mut self.stats.queue_overflows);
    }

    fn event(&mut self, event: LinkEvent) {
        push_bounded(&mut self.events, EVENT_BOUND, event, &mut self.stats.queue_overflows);
    }
}

/// The layer above, as the link's one copy of its receive and timer paths takes it.
type Above<'a> = &'a mut dyn PeerChanges;

/// Tells `above` that `alias`, known as `node` until now, goes back to its provisional name.
fn unname(alias: NodeAlias, node: NodeId, above: Above<'_>) {
    above.peer_changed(PeerChange::Renamed { from: node, to: alias.provisional_node_id() });
}
