//! [`CanLink`]: one local node's adapter between full-format [`Message`]s and CAN frames.

use alloc::collections::VecDeque;
use alloc::vec::Vec;

use bytes::Bytes;
use openlcb_stream::wire::{Emit, ErrorReport};
use openlcb_stream::{Duration, Instant, Message, MessageRef, Mti, NodeId, node};

use crate::NodeAlias;
use crate::cache::AliasCache;
use crate::fragment::{EncodeError, Fragments, FramePosition};
use crate::frame::{CanFrame, FrameError};
use crate::header::{CanHeader, FrameKind};
use crate::login::{AliasLogin, LoginEvent, LoginState};
use crate::reassembly::{Reassembler, ReassemblyError, ReassemblyKey};

/// Events the link can have queued at once; more are dropped and counted.
const EVENT_BOUND: usize = 64;

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
    /// The longest addressed message payload reassembled, and the longest held inbound
    /// message, in bytes.
    pub max_message_len: usize,
    /// How long a multi-frame message may wait for its next frame (0x2011 after that).
    pub reassembly_timeout: Duration,
    /// Answer reassembly errors that lose a message (0x2041, 0x2011, and 0x2020 for no room)
    /// with Optional Interaction Rejected to the sender, quoting the MTI. 0x2042 is only
    /// counted: the message it starts goes on.
    pub reject_reassembly_errors: bool,
    /// Messages accepted by [`CanLink::send`] and not yet framed (including those waiting
    /// for an alias). More are refused with [`SendError::QueueFull`].
    pub transmit_queue_limit: usize,
    /// Frames the link itself queues (AME, OIR, Verify Node ID); more are dropped and counted.
    pub frame_queue_limit: usize,
    /// How long to wait for an unknown alias to be resolved, both ways: an AME for a Node ID
    /// we want to send to, an addressed Verify Node ID to an alias we heard from.
    pub resolve_timeout: Duration,
    /// Received messages held while their sender's alias is being resolved.
    pub max_held_messages: usize,
    /// Ask for our own Node ID (AME) before claiming it, waiting this long for an answer
    /// ([`AliasLogin::with_node_id_check`]); `None` (the default) does not ask.
    pub node_id_check: Option<Duration>,
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
            frame_queue_limit: 16,
            resolve_timeout: Duration::from_secs(1),
            max_held_messages: 8,
            node_id_check: None,
        }
    }
}

/// Something the driver must know or act on.
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
    /// Another node announced this node's Node ID: the link sends nothing more.
    DuplicateNodeId {
        /// That node's alias.
        other: NodeAlias,
    },
    /// A peer released its alias (AMR). Call `StreamEndpoint::peer_lost(node)`.
    PeerLost {
        /// The peer.
        node: NodeId,
        /// The alias it released.
        alias: NodeAlias,
    },
    /// No alias could be found for `node` within the resolve timeout; messages to it were
    /// dropped. Call `StreamEndpoint::peer_lost(node)`.
    Unreachable {
        /// The node asked for.
        node: NodeId,
        /// Messages dropped.
        dropped: usize,
    },
}

/// Why [`CanLink::send`] refused a message (it is dropped and counted).
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
pub enum SendError {
    /// A duplicate Node ID stopped the link.
    #[error("the link stopped after a duplicate Node ID")]
    Stopped,
    /// [`CanConfig::transmit_queue_limit`] messages are queued.
    #[error("the transmit queue is full")]
    QueueFull,
    /// The message has no CAN form.
    #[error(transparent)]
    Encode(#[from] EncodeError),
}

/// Frames and messages ignored, refused or dropped, by cause.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
#[non_exhaustive]
pub struct LinkStats {
    /// Frames handled.
    pub frames_in: u64,
    /// Frames returned by `poll_transmit`.
    pub frames_out: u64,
    /// Standard (11-bit) frames ignored.
    pub standard_ignored: u64,
    /// Remote frames ignored.
    pub remote_ignored: u64,
    /// Frames with a bad header, an addressed frame shorter than 2 bytes, or a stream frame
    /// without DID.
    pub invalid_frames: u64,
    /// Addressed and stream frames for another node.
    pub not_for_us: u64,
    /// Datagram frames (not implemented here) and reserved formats ignored.
    pub unsupported_ignored: u64,
    /// Global messages claiming our Node ID from another alias.
    pub own_node_claims: u64,
    /// 0x2041: a middle or last frame without a first.
    pub middle_without_first: u64,
    /// 0x2042: a first frame before the previous message ended.
    pub first_before_last_ended: u64,
    /// 0x2011: no last frame in time.
    pub reassembly_timeouts: u64,
    /// Multi-frame messages longer than `max_message_len`, or with no free slot.
    pub reassembly_overflows: u64,
    /// Received messages held until their sender's alias was known.
    pub held_inbound: u64,
    /// Received messages dropped because their sender's alias stayed unknown (or no room).
    pub unknown_source_dropped: u64,
    /// Messages to send dropped because no alias was found for their destination.
    pub unresolved_dropped: u64,
    /// Messages refused by `send`.
    pub send_refused: u64,
    /// Queued messages dropped when the alias was lost or the link stopped.
    pub messages_dropped: u64,
    /// Link-originated frames or events dropped because their queue was full.
    pub queue_overflows: u64,
}

#[derive(Debug)]
struct Outgoing {
    message: Message,
    destination: Option<NodeAlias>,
}

#[derive(Debug)]
struct Unresolved {
    message: Message,
    node: NodeId,
    /// Set once the AME went out.
    deadline: Option<Instant>,
}

#[derive(Debug)]
struct Held {
    in_use: bool,
    arrival: u64,
    source: NodeAlias,
    mti: Mti,
    addressed: bool,
    payload: Vec<u8>,
    deadline: Instant,
}

/// One node's CAN adapter: alias login, framing, reassembly and alias resolution, so that the
/// stream endpoint speaks in Node IDs only. See the crate documentation for the drive loop.
#[derive(Debug)]
pub struct CanLink {
    node: NodeId,
    config: CanConfig,
    login: AliasLogin,
    announced: bool,
    cache: AliasCache,
    reassembly: Reassembler,
    scratch: Vec<u8>,
    frames: VecDeque<CanFrame>,
    messages: VecDeque<Outgoing>,
    current: Option<Fragments<Bytes>>,
    unresolved: VecDeque<Unresolved>,
    held: Vec<Held>,
    arrivals: u64,
    events: VecDeque<LinkEvent>,
    stats: LinkStats,
}

impl CanLink {
    /// A link for `node`, starting its alias login at `now` (the CID frames are the first
    /// transmits). All tables are allocated here, at their configured bounds.
    pub fn new(now: Instant, node: NodeId, config: CanConfig) -> Self {
        let login = AliasLogin::new(now, node, config.first_alias, config.reserve_wait)
            .with_node_id_check(config.node_id_check);
        let held = (0..config.max_held_messages)
            .map(|_| Held {
                in_use: false,
                arrival: 0,
                source: NodeAlias::MAX,
                mti: Mti(0),
                addressed: false,
                payload: Vec::with_capacity(config.max_message_len),
                deadline: Instant::ZERO,
            })
            .collect();
        CanLink {
            node,
            login,
            announced: false,
            cache: AliasCache::new(config.alias_cache_size),
            reassembly: Reassembler::new(config.reassembly_slots, config.max_message_len, config.reassembly_timeout),
            scratch: Vec::with_capacity(config.max_message_len),
            frames: VecDeque::with_capacity(config.frame_queue_limit),
            messages: VecDeque::with_capacity(config.transmit_queue_limit.saturating_add(1)),
            current: None,
            unresolved: VecDeque::with_capacity(config.transmit_queue_limit),
            held,
            arrivals: 0,
            events: VecDeque::with_capacity(EVENT_BOUND),
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

    /// Messages accepted by `send` and not yet fully framed.
    pub fn queued_messages(&self) -> usize {
        self.messages.len()
            + self.unresolved.len()
            + usize::from(self.current.as_ref().is_some_and(|c| c.remaining() > 0))
    }

    /// `send` has room for another message. A driver that must not lose stream data polls
    /// the endpoint only while this holds (the endpoint keeps the rest queued).
    pub fn can_send(&self) -> bool {
        self.login.state() != LoginState::Stopped
            && self.messages.len() + self.unresolved.len() < self.config.transmit_queue_limit
    }

    // ----- commands -----

    /// Queues `message` for transmission. Addressed messages go to the cached alias of their
    /// destination; an unknown destination is resolved with an AME first (messages wait, at
    /// most [`CanConfig::resolve_timeout`], then [`LinkEvent::Unreachable`]). Messages wait
    /// until the alias is permitted. Takes no allocation.
    pub fn send(&mut self, now: Instant, message: Message) -> Result<(), SendError> {
        let result = self.enqueue(now, message);
        if result.is_err() {
            bump(&mut self.stats.send_refused);
        }
        result
    }

    fn enqueue(&mut self, now: Instant, message: Message) -> Result<(), SendError> {
        if self.login.state() == LoginState::Stopped {
            return Err(SendError::Stopped);
        }
        let addressed = message.mti.is_addressed();
        let destination = if addressed { message.destination } else { None };
        // Check the message has a CAN form now, so that failures reach the caller.
        let placeholder = NodeAlias::MAX;
        Fragments::new(message.mti, placeholder, destination.map(|_| placeholder), &message.payload[..])?;
        if !self.can_send() {
            return Err(SendError::QueueFull);
        }
        let Some(node) = destination else {
            self.messages.push_back(Outgoing { message, destination: None });
            return Ok(());
        };
        let waiting = self.unresolved.iter().any(|u| u.node == node);
        match self.cache.alias(node) {
            Some(alias) if !waiting => self.messages.push_back(Outgoing { message, destination: Some(alias) }),
            _ => {
                // A node already being resolved shares the AME out for it and its deadline.
                let deadline = self.unresolved.iter().find(|u| u.node == node).and_then(|u| u.deadline);
                self.unresolved.push_back(Unresolved { message, node, deadline });
                self.send_enquiries(now);
            }
        }
        Ok(())
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

    fn next_frame(&mut self) -> Option<CanFrame> {
        if let Some(frame) = self.login.poll_transmit() {
            return Some(frame);
        }
        let alias = self.login.alias()?;
        let mid_message = self.current.as_ref().is_some_and(|c| c.remaining() > 0);
        if let Some(front) = self.frames.front() {
            if !mid_message || front.header().is_ok_and(|h| !h.is_message()) {
                return self.frames.pop_front();
            }
        }
        loop {
            if let Some(frame) = self.current.as_mut().and_then(Iterator::next) {
                return Some(frame);
            }
            self.current = None;
            let Outgoing { message, destination } = self.messages.pop_front()?;
            match Fragments::new(message.mti, alias, destination, message.payload) {
                Ok(fragments) => self.current = Some(fragments),
                Err(_) => bump(&mut self.stats.send_refused),
            }
        }
    }

    /// The next event.
    pub fn poll_event(&mut self) -> Option<LinkEvent> {
        self.events.pop_front()
    }

    /// When to call `handle_timeout` next.
    pub fn poll_timeout(&self) -> Option<Instant> {
        let unresolved = self.unresolved.iter().filter_map(|u| u.deadline);
        let held = self.held.iter().filter(|h| h.in_use).map(|h| h.deadline);
        [self.login.poll_timeout(), self.reassembly.poll_timeout()]
            .into_iter()
            .flatten()
            .chain(unresolved)
            .chain(held)
            .min()
    }

    // ----- inputs -----

    /// Runs every timer due at `now`: the login's reserve wait, reassembly timeouts (0x2011),
    /// and alias resolutions that ran out. Early or repeated calls are harmless.
    pub fn handle_timeout(&mut self, now: Instant) {
        self.login.handle_timeout(now);
        self.drain_login_events(now);
        while let Some(key) = self.reassembly.take_expired(now) {
            self.reassembly_error(key.source, key.mti, ReassemblyError::Timeout);
        }
        while let Some(node) = self.unresolved.iter().find(|u| u.deadline.is_some_and(|d| d <= now)).map(|u| u.node) {
            let before = self.unresolved.len();
            self.unresolved.retain(|u| u.node != node);
            let dropped = before - self.unresolved.len();
            self.stats.unresolved_dropped = self.stats.unresolved_dropped.saturating_add(dropped as u64);
            self.event(LinkEvent::Unreachable { node, dropped });
        }
        for held in self.held.iter_mut().filter(|h| h.in_use && h.deadline <= now) {
            held.in_use = false;
            bump(&mut self.stats.unknown_source_dropped);
        }
    }

    /// Feeds one received frame. Every complete message for this node (or global) is handed
    /// to `deliver`, borrowing its payload from `frame` (single frames, stream data) or from
    /// the link's reassembly buffer: nothing is allocated. Usually
    /// `|msg| endpoint.handle_message(now, msg)`.
    pub fn handle_frame(&mut self, now: Instant, frame: &CanFrame, mut deliver: impl FnMut(MessageRef<'_>)) {
        bump(&mut self.stats.frames_in);
        let header = match frame.header() {
            Ok(header) => header,
            Err(FrameError::Standard) => return bump(&mut self.stats.standard_ignored),
            Err(FrameError::Remote) => return bump(&mut self.stats.remote_ignored),
            Err(_) => return bump(&mut self.stats.invalid_frames),
        };
        let data = frame.payload();
        let from_our_alias = self.login.handle_header(now, &header, data);
        self.drain_login_events(now);
        if from_our_alias {
            return;
        }
        match header.kind {
            FrameKind::AliasMapDefinition => {
                if let Some(node) = NodeId::from_slice(data) {
                    self.learn(header.source, node, &mut deliver);
                }
            }
            FrameKind::AliasMapReset => self.forget(header.source, NodeId::from_slice(data)),
            // CFT §6.2.3: a global AME drops every cached mapping; the AMDs it causes refill it.
            FrameKind::AliasMapEnquiry if data.is_empty() => self.cache.clear(),
            FrameKind::Message { can_mti } => self.on_message(now, header.source, Mti(can_mti), data, &mut deliver),
            FrameKind::StreamData { destination } => {
                if Some(destination) != self.login.alias() {
                    return bump(&mut self.stats.not_for_us);
                }
                if data.is_empty() {
                    // Wire-spec §7.3: DLC 0 is invalid (no DID).
                    return bump(&mut self.stats.invalid_frames);
                }
                self.deliver_or_hold(now, header.source, Mti::STREAM_DATA_SEND, true, data, &mut deliver);
            }
            FrameKind::Datagram { .. } | FrameKind::ReservedFormat { .. } => bump(&mut self.stats.unsupported_ignored),
            _ => {}
        }
    }

    // ----- received messages -----

    fn on_message(
        &mut self,
        now: Instant,
        source: NodeAlias,
        mti: Mti,
        data: &[u8],
        deliver: &mut impl FnMut(MessageRef<'_>),
    ) {
        if !mti.is_addressed() {
            if mti.announces_sender() {
                match NodeId::from_slice(data) {
                    Some(node) if node == self.node => {
                        return bump(&mut self.stats.own_node_claims);
                    }
                    Some(node) => self.learn(source, node, deliver),
                    None => {}
                }
            }
            return self.deliver_or_hold(now, source, mti, false, data, deliver);
        }
        let [flags_and_high, low, body @ ..] = data else {
            return bump(&mut self.stats.invalid_frames);
        };
        let destination = NodeAlias::new(u16::from_be_bytes([flags_and_high & 0x0F, *low]));
        let Some(ours) = self.login.alias().filter(|ours| destination == Some(*ours)) else {
            return bump(&mut self.stats.not_for_us);
        };
        let position = FramePosition::from_flags(*flags_and_high);
        if position == FramePosition::Only {
            // The usual case: the payload is handed over straight from the frame.
            return self.deliver_or_hold(now, source, mti, true, body, deliver);
        }
        let key = ReassemblyKey { source, destination: ours, mti };
        match self.reassembly.push(now, key, position, body) {
            Ok(None) => {}
            Ok(Some(whole)) => {
                // Copied once into a buffer of the link so the reassembler is free again;
                // `scratch` has room for `max_message_len` bytes, so this never allocates.
                self.scratch.clear();
                self.scratch.extend_from_slice(whole);
                let message = core::mem::take(&mut self.scratch);
                self.deliver_or_hold(now, source, mti, true, &message, deliver);
                self.scratch = message;
            }
            Err(error) => self.reassembly_error(source, mti, error),
        }
    }

    fn deliver_or_hold(
        &mut self,
        now: Instant,
        source: NodeAlias,
        mti: Mti,
        addressed: bool,
        payload: &[u8],
        deliver: &mut impl FnMut(MessageRef<'_>),
    ) {
        let destination = addressed.then_some(self.node);
        if let Some(node) = self.cache.node(source) {
            return deliver(MessageRef { mti, source: node, destination, payload });
        }
        // The sender's Node ID is unknown: hold the message and ask it (addressed Verify Node
        // ID; its Verified Node ID, or any AMD, releases what is held, in arrival order).
        let first_from_source = !self.held.iter().any(|h| h.in_use && h.source == source);
        let slot = self.held.iter_mut().find(|h| !h.in_use);
        let Some(slot) = slot.filter(|_| payload.len() <= self.config.max_message_len) else {
            return bump(&mut self.stats.unknown_source_dropped);
        };
        self.arrivals = self.arrivals.wrapping_add(1);
        slot.in_use = true;
        slot.arrival = self.arrivals;
        slot.source = source;
        slot.mti = mti;
        slot.addressed = addressed;
        slot.payload.clear();
        slot.payload.extend_from_slice(payload);
        slot.deadline = now + self.config.resolve_timeout;
        bump(&mut self.stats.held_inbound);
        if first_from_source {
            if let Some(ours) = self.login.alias() {
                let verify = Fragments::new(Mti::VERIFY_NODE_ID_ADDRESSED, ours, Some(source), [0u8; 0])
                    .ok()
                    .and_then(|mut f| f.next());
                self.queue_frame(verify);
            }
        }
    }

    /// Records `alias` <-> `node`, then hands over messages held from `alias` and releases
    /// messages waiting for `node`'s alias.
    fn learn(&mut self, alias: NodeAlias, node: NodeId, deliver: &mut impl FnMut(MessageRef<'_>)) {
        if node == self.node {
            return;
        }
        self.cache.insert(alias, node);
        let local = self.node;
        while let Some(held) = self.held.iter_mut().filter(|h| h.in_use && h.source == alias).min_by_key(|h| h.arrival)
        {
            held.in_use = false;
            let destination = held.addressed.then_some(local);
            deliver(MessageRef { mti: held.mti, source: node, destination, payload: &held.payload });
        }
        let mut index = 0;
        while let Some(waiting) = self.unresolved.get(index) {
            if waiting.node != node {
                index += 1;
                continue;
            }
            if let Some(Unresolved { message, .. }) = self.unresolved.remove(index) {
                self.messages.push_back(Outgoing { message, destination: Some(alias) });
            }
        }
    }

    /// A peer released `alias` (AMR naming `released`): forget it, drop what was queued for
    /// it or from it. The AMR's Node ID is reported: the cache may already map the alias to
    /// the node that collided with it.
    fn forget(&mut self, alias: NodeAlias, released: Option<NodeId>) {
        self.reassembly.forget_source(alias);
        for held in self.held.iter_mut().filter(|h| h.in_use && h.source == alias) {
            held.in_use = false;
            bump(&mut self.stats.unknown_source_dropped);
        }
        let before = self.messages.len();
        self.messages.retain(|m| m.destination != Some(alias));
        self.stats.messages_dropped = self.stats.messages_dropped.saturating_add((before - self.messages.len()) as u64);
        let cached = self.cache.remove_alias(alias);
        if let Some(node) = released.filter(|n| *n != self.node).or(cached) {
            self.event(LinkEvent::PeerLost { node, alias });
        }
    }

    fn reassembly_error(&mut self, source: NodeAlias, mti: Mti, error: ReassemblyError) {
        let counter = match error {
            ReassemblyError::MiddleWithoutFirst => &mut self.stats.middle_without_first,
            ReassemblyError::FirstBeforeLastEnded => &mut self.stats.first_before_last_ended,
            ReassemblyError::Timeout => &mut self.stats.reassembly_timeouts,
            _ => &mut self.stats.reassembly_overflows,
        };
        bump(counter);
        let answer = self.config.reject_reassembly_errors && error != ReassemblyError::FirstBeforeLastEnded;
        let Some(ours) = self.login.alias().filter(|_| answer) else {
            return;
        };
        let mut payload = [0u8; 4];
        let report = ErrorReport { code: error.code(), mti: Some(mti) };
        let Ok(len) = report.emit(&mut payload) else {
            return;
        };
        let oir =
            Fragments::new(Mti::OPTIONAL_INTERACTION_REJECTED, ours, Some(source), payload.get(..len).unwrap_or(&[]))
                .ok()
                .and_then(|mut f| f.next());
        self.queue_frame(oir);
    }

    // ----- login and alias resolution -----

    fn drain_login_events(&mut self, now: Instant) {
        while let Some(event) = self.login.poll_event() {
            match event {
                LoginEvent::Permitted { alias } => {
                    if self.announced {
                        // After a re-login the endpoint will not announce the node again.
                        let announce =
                            Outgoing { message: node::initialization_complete(self.node), destination: None };
                        self.messages.push_front(announce);
                    }
                    self.announced = true;
                    self.send_enquiries(now);
                    self.event(LinkEvent::Permitted { alias });
                }
                LoginEvent::Lost { alias } => {
                    self.drop_traffic();
                    self.event(LinkEvent::AliasLost { alias });
                }
                LoginEvent::DuplicateNodeId { other } => {
                    self.drop_traffic();
                    self.event(LinkEvent::DuplicateNodeId { other });
                }
                _ => {}
            }
        }
    }

    /// Everything tied to the old alias goes: queued messages, partial messages, held frames.
    fn drop_traffic(&mut self) {
        let queued = self.messages.len() + self.unresolved.len() + usize::from(self.current.is_some());
        self.stats.messages_dropped = self.stats.messages_dropped.saturating_add(queued as u64);
        self.messages.clear();
        self.unresolved.clear();
        self.current = None;
        self.frames.clear();
        self.reassembly.clear();
        for held in &mut self.held {
            held.in_use = false;
        }
    }

    /// Sends an AME for every node waiting for its alias that has not had one, once permitted.
    fn send_enquiries(&mut self, now: Instant) {
        let Some(ours) = self.login.alias() else {
            return;
        };
        let deadline = now + self.config.resolve_timeout;
        while let Some(node) = self.unresolved.iter().find(|u| u.deadline.is_none()).map(|u| u.node) {
            for waiting in self.unresolved.iter_mut().filter(|u| u.node == node) {
                waiting.deadline = Some(deadline);
            }
            let enquiry =
                CanFrame::from_header(&CanHeader::control(FrameKind::AliasMapEnquiry, ours), &node.to_bytes());
            self.queue_frame(enquiry);
        }
    }

    fn queue_frame(&mut self, frame: Option<CanFrame>) {
        match frame {
            Some(frame) if self.frames.len() < self.config.frame_queue_limit => self.frames.push_back(frame),
            _ => bump(&mut self.stats.queue_overflows),
        }
    }

    fn event(&mut self, event: LinkEvent) {
        if self.events.len() < EVENT_BOUND {
            self.events.push_back(event);
        } else {
            bump(&mut self.stats.queue_overflows);
        }
    }
}

fn bump(counter: &mut u64) {
    *counter = counter.saturating_add(1);
}
