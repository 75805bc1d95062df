//! [`Gateway`]: the bridge itself. Stream tracking is in `tracking`, alias handling and the
//! CAN output in `can_side`.

mod can_side;
mod tracking;

use alloc::collections::VecDeque;
use alloc::vec::Vec;

use openlcb_can::{
    AliasCache, CanFrame, DatagramFrame, Fragments, FrameKind, FramePosition, NodeAlias, Reassembler, ReassemblyError,
    ReassemblyKey,
};
use openlcb_stream::{Instant, Message, MessageRef, Mti, NodeId, StreamId};

use crate::proxy::Proxy;
use crate::stream::Tracked;
use crate::{GatewayConfig, GatewayEvent, GatewayStats, Side, StreamEnd, StreamKey};

/// Events the gateway can have queued at once; more are dropped (the counters still count).
const EVENT_BOUND: usize = 64;
/// Times a proxy's tentative alias is replaced because it is known to be taken.
const ALIAS_RETRIES: usize = 16;

/// A message on its way to CAN.
#[derive(Debug)]
struct CanBound {
    message: Message,
    /// Stream data, and whose: `Some(Some(key))` tracked, `Some(None)` untracked.
    data_of: Option<Option<StreamKey>>,
}

impl CanBound {
    fn control(message: Message) -> Self {
        CanBound { message, data_of: None }
    }

    /// Stream payload bytes carried (DID excluded).
    fn data_len(&self) -> usize {
        match self.data_of {
            Some(_) => self.message.payload.len().saturating_sub(1),
            None => 0,
        }
    }
}

/// A message for CAN waiting for its source's alias or its destination's alias.
#[derive(Debug)]
struct Waiting {
    item: CanBound,
    /// Set once an AME for the destination went out.
    deadline: Option<Instant>,
}

/// A message for CAN with both aliases known.
#[derive(Debug)]
struct Ready {
    item: CanBound,
    source: NodeAlias,
    destination: Option<NodeAlias>,
}

/// What a message for CAN still needs.
enum Readiness {
    Ready(NodeAlias, Option<NodeAlias>),
    /// The source's alias is not permitted yet.
    AwaitSource,
    /// The destination's alias is unknown; the AME comes from `source`.
    AwaitDestination {
        source: NodeAlias,
        node: NodeId,
    },
    /// The source can never send (duplicate Node ID, or its proxy is gone).
    Undeliverable,
}

/// The frames of a message being sent.
#[derive(Debug)]
struct InFlight {
    fragments: Fragments<Vec<u8>>,
    source: NodeAlias,
    destination: Option<NodeAlias>,
    /// For stream data: the stream (`None` if untracked) and the payload bytes not sent yet.
    stream: Option<StreamKey>,
    bytes_left: usize,
}

impl InFlight {
    fn start(ready: Ready) -> Result<Self, openlcb_can::EncodeError> {
        let Ready { item, source, destination } = ready;
        let (stream, bytes_left) = (item.data_of.flatten(), item.data_len());
        let fragments = Fragments::new(item.message.mti, source, destination, item.message.payload)?;
        Ok(InFlight { fragments, source, destination, stream, bytes_left })
    }
}

/// A sans-IO bridge between one CAN segment and one full-format (OpenLCB-TCP) link, following
/// the draft's gateway rules (wire-spec §6.5). See the crate documentation for the drive loop.
#[derive(Debug)]
pub struct Gateway {
    config: GatewayConfig,
    /// The time of the latest `handle_*` call, for work done while frames are pulled.
    now: Instant,
    proxies: Vec<Proxy>,
    cache: AliasCache,
    reassembly: Reassembler,
    datagrams: Reassembler,
    streams: Vec<Tracked>,
    waiting: VecDeque<Waiting>,
    control: VecDeque<Ready>,
    data: VecDeque<Ready>,
    /// Control frames of the gateway itself (AME, AMR of an evicted proxy).
    raw_frames: VecDeque<CanFrame>,
    current_control: Option<InFlight>,
    current_data: Option<InFlight>,
    untracked_backlog: usize,
    to_full: VecDeque<Message>,
    events: VecDeque<GatewayEvent>,
    stats: GatewayStats,
}

impl Gateway {
    /// A gateway with nothing learned yet. All tables are allocated here, at their bounds.
    pub fn new(now: Instant, config: GatewayConfig) -> Self {
        Gateway {
            now,
            proxies: Vec::with_capacity(config.max_proxied_nodes),
            cache: AliasCache::new(config.alias_cache_size),
            reassembly: Reassembler::new(config.reassembly_slots, config.max_message_len, config.reassembly_timeout),
            datagrams: Reassembler::for_datagrams(config.datagram_slots, config.reassembly_timeout),
            streams: Vec::with_capacity(config.max_streams),
            waiting: VecDeque::with_capacity(config.max_held_messages),
            control: VecDeque::with_capacity(config.max_queued_messages),
            data: VecDeque::new(),
            raw_frames: VecDeque::with_capacity(raw_frame_bound(&config)),
            current_control: None,
            current_data: None,
            untracked_backlog: 0,
            to_full: VecDeque::new(),
            events: VecDeque::with_capacity(EVENT_BOUND),
            stats: GatewayStats::default(),
            config,
        }
    }

    // ----- getters -----

    /// The configuration.
    pub fn config(&self) -> &GatewayConfig {
        &self.config
    }

    /// Counters.
    pub fn stats(&self) -> GatewayStats {
        self.stats
    }

    /// Payload bytes held now: stream buffers, the untracked backlog, messages held or queued
    /// for CAN, and messages waiting in [`poll_message`](Self::poll_message). Once the
    /// full-format output is drained it never exceeds [`memory_bound`](Self::memory_bound).
    pub fn memory_in_use(&self) -> usize {
        let stream_bytes: usize = self.streams.iter().map(Tracked::buffered).sum();
        let held = self.waiting.iter().filter(|w| w.item.data_of.is_none()).map(|w| w.item.message.payload.len());
        let queued = self.control.iter().map(|r| r.item.message.payload.len());
        let output = self.to_full.iter().map(|m| m.payload.len());
        stream_bytes + self.untracked_backlog + held.chain(queued).chain(output).sum::<usize>()
    }

    /// The bound of [`memory_in_use`](Self::memory_in_use), from the configuration.
    pub fn memory_bound(&self) -> usize {
        self.config.memory_bound()
    }

    /// Streams tracked now.
    pub fn tracked_streams(&self) -> usize {
        self.streams.len()
    }

    /// The alias a full-format node holds on CAN, once permitted.
    pub fn proxy_alias(&self, node: NodeId) -> Option<NodeAlias> {
        self.proxies.iter().find(|p| p.node == node).and_then(Proxy::permitted_alias)
    }

    /// The CAN node holding `alias`, as learned from the segment.
    pub fn can_node(&self, alias: NodeAlias) -> Option<NodeId> {
        self.cache.peek_node(alias)
    }

    // ----- outputs -----

    /// The next frame for the CAN segment. Call whenever the CAN controller can take a frame;
    /// frames not pulled yet wait inside the gateway, within its bounds. Pulling frames drains
    /// stream buffers and may release delayed messages, so drain
    /// [`poll_message`](Self::poll_message) afterwards too.
    ///
    /// Order: alias login frames of the proxied nodes and the gateway's own control frames;
    /// the rest of an addressed message in progress (its frames go back to back); other
    /// messages (Replies, Proceeds, Completes, node traffic); stream data frames last, each
    /// message's frames in order but with other messages allowed between them (they have the
    /// higher priority, MN §7.3.7).
    pub fn poll_can_transmit(&mut self) -> Option<CanFrame> {
        let frame = self.next_can_frame()?;
        bump(&mut self.stats.frames_out);
        Some(frame)
    }

    /// The next message for the full-format link (to be encoded by a `TcpLink`).
    pub fn poll_message(&mut self) -> Option<Message> {
        let message = self.to_full.pop_front()?;
        bump(&mut self.stats.messages_out);
        Some(message)
    }

    /// The next event.
    pub fn poll_event(&mut self) -> Option<GatewayEvent> {
        self.events.pop_front()
    }

    /// When to call [`handle_timeout`](Self::handle_timeout) next.
    pub fn poll_timeout(&self) -> Option<Instant> {
        let logins = self.proxies.iter().filter_map(|p| p.login.poll_timeout());
        let waiting = self.waiting.iter().filter_map(|w| w.deadline);
        let streams = self.streams.iter().flat_map(|s| {
            let complete = s.complete.as_ref().filter(|_| s.awaits_overtaken_data(self.now)).map(|c| c.deadline);
            [s.merge_deadline, complete, Some(s.last_activity + self.config.stream_idle_timeout)]
        });
        let others = [self.reassembly.poll_timeout(), self.datagrams.poll_timeout(), self.departed_deadline()];
        logins.chain(waiting).chain(streams.flatten()).chain(others.into_iter().flatten()).min()
    }

    // ----- inputs -----

    /// Runs every timer due at `now`: proxy alias checks, merge buffers due, Completes that
    /// waited long enough for overtaken data, alias resolutions that ran out, reassembly
    /// timeouts (a datagram's is answered with Datagram Rejected 0x2011) and idle streams.
    /// Early or repeated calls are harmless.
    pub fn handle_timeout(&mut self, now: Instant) {
        self.now = now;
        for proxy in &mut self.proxies {
            proxy.login.handle_timeout(now);
        }
        self.drain_login_events(now);
        while self.reassembly.take_expired(now).is_some() {
            bump(&mut self.stats.reassembly_errors);
        }
        while let Some(key) = self.datagrams.take_expired(now) {
            self.datagram_failed(key, ReassemblyError::Timeout);
        }
        self.expire_resolutions(now);
        self.release_departed(now);
        let mut index = 0;
        while let Some(stream) = self.streams.get(index) {
            if stream.last_activity + self.config.stream_idle_timeout <= now {
                self.end_stream(index, StreamEnd::Idle);
                continue;
            }
            if stream.merge_deadline.is_some_and(|d| d <= now) {
                self.flush_merge(index);
            }
            if !self.settle(now, index) {
                index += 1;
            }
        }
    }

    /// Feeds one frame received from the CAN segment.
    pub fn handle_can_frame(&mut self, now: Instant, frame: &CanFrame) {
        self.now = now;
        bump(&mut self.stats.frames_in);
        let Ok(header) = frame.header() else {
            return bump(&mut self.stats.invalid_frames);
        };
        let data = frame.payload();
        // Every proxy login sees every frame: collisions, CID defence, AME answers.
        let mut from_proxy_alias = false;
        for proxy in &mut self.proxies {
            from_proxy_alias |= proxy.login.handle_header(now, &header, data);
        }
        self.drain_login_events(now);
        if from_proxy_alias {
            return;
        }
        match header.kind {
            FrameKind::AliasMapDefinition => {
                if let Some(node) = NodeId::from_slice(data) {
                    self.learn(now, header.source, node);
                }
            }
            FrameKind::AliasMapReset => self.can_node_left(header.source),
            // CFT §6.2.3: a global AME drops every cached mapping; the AMDs it causes refill it.
            FrameKind::AliasMapEnquiry if data.is_empty() => self.cache.clear(),
            FrameKind::Message { can_mti } => self.can_message(now, header.source, Mti(can_mti), data),
            FrameKind::StreamData { destination } => self.can_stream_data(now, header.source, destination, data),
            FrameKind::Datagram { frame: part, destination } => {
                self.can_datagram(now, header.source, part, destination, data);
            }
            FrameKind::ReservedFormat { .. } => bump(&mut self.stats.invalid_frames),
            _ => {}
        }
    }

    /// Feeds one message received from the full-format link (as decoded by a `TcpLink`).
    pub fn handle_message(&mut self, now: Instant, msg: MessageRef<'_>) {
        self.now = now;
        bump(&mut self.stats.messages_in);
        // MN §3.1.1: special MTIs never cross a gateway. Of the 0x1000 MTIs only Stream Data
        // Send and Datagram have a CAN form.
        let no_can_form = msg.mti.is_stream_or_datagram() && !matches!(msg.mti, Mti::STREAM_DATA_SEND | Mti::DATAGRAM);
        if msg.mti.is_special() || no_can_form {
            return bump(&mut self.stats.not_forwardable);
        }
        if self.cache.peek_alias(msg.source).is_some() {
            return bump(&mut self.stats.echoes_dropped);
        }
        let destination = if msg.mti.is_addressed() {
            let Some(destination) = msg.destination else {
                return bump(&mut self.stats.not_forwardable);
            };
            if self.proxies.iter().any(|p| p.node == destination) {
                return bump(&mut self.stats.stayed_local);
            }
            Some(destination)
        } else {
            None
        };
        // Refuse what has no CAN form now, before a proxy is spent on it.
        let placeholder = NodeAlias::MAX;
        if Fragments::new(msg.mti, placeholder, destination.map(|_| placeholder), msg.payload).is_err() {
            return bump(&mut self.stats.not_forwardable);
        }
        if msg.mti != Mti::STREAM_DATA_SEND && msg.payload.len() > self.config.max_message_len {
            return bump(&mut self.stats.queue_overflows);
        }
        if !self.ensure_proxy(now, msg.source) {
            return bump(&mut self.stats.proxy_table_full);
        }
        if msg.mti == Mti::DATAGRAM {
            bump(&mut self.stats.datagrams_forwarded);
        }
        self.forward(now, Side::Full, msg.to_message());
    }

    /// A full-format node left the full-format link (the connection that carried it closed).
    /// What it sent before it left still goes to CAN: its streams as source go on to their
    /// Complete, for at most [`GatewayConfig::departed_grace`]; its streams as destination
    /// end. Then the rest is dropped and counted, and the CAN alias held for it is released
    /// with an AMR, so that its Node ID may log in on the CAN side. Unknown nodes are ignored.
    pub fn handle_full_node_left(&mut self, now: Instant, node: NodeId) {
        self.now = now;
        self.full_node_left(now, node);
    }

    // ----- CAN side in -----

    fn can_message(&mut self, now: Instant, source: NodeAlias, mti: Mti, data: &[u8]) {
        if !mti.is_addressed() {
            if mti.announces_sender()
                && let Some(node) = NodeId::from_slice(data)
            {
                self.learn(now, source, node);
            }
            let Some(node) = self.cache.node(source) else {
                return bump(&mut self.stats.unknown_source_dropped);
            };
            return self.forward(now, Side::Can, Message::global(mti, node, data.to_vec()));
        }
        let [flags_and_high, low, body @ ..] = data else {
            return bump(&mut self.stats.invalid_frames);
        };
        let alias = NodeAlias::new(u16::from_be_bytes([flags_and_high & 0x0F, *low]));
        let Some((destination, ours)) = alias.and_then(|a| self.proxied_node(a).map(|n| (n, a))) else {
            return bump(&mut self.stats.stayed_local);
        };
        let key = ReassemblyKey { source, destination: ours, mti };
        let payload = match self.reassembly.push(now, key, FramePosition::from_flags(*flags_and_high), body) {
            Ok(Some(whole)) => whole.to_vec(),
            Ok(None) => return,
            Err(_) => return bump(&mut self.stats.reassembly_errors),
        };
        let Some(node) = self.cache.node(source) else {
            return bump(&mut self.stats.unknown_source_dropped);
        };
        self.forward(now, Side::Can, Message::addressed(mti, node, destination, payload));
    }

    /// A CAN datagram frame: reassembled when it is for a proxied node, forwarded whole.
    fn can_datagram(&mut self, now: Instant, source: NodeAlias, frame: DatagramFrame, alias: NodeAlias, data: &[u8]) {
        let Some(destination) = self.proxied_node(alias) else {
            return bump(&mut self.stats.stayed_local);
        };
        let key = ReassemblyKey { source, destination: alias, mti: Mti::DATAGRAM };
        let position = frame.position();
        let payload = if position == FramePosition::Only {
            // A whole datagram: the sender has given up any datagram it left open.
            self.datagrams.discard(key);
            data.to_vec()
        } else {
            match self.datagrams.push(now, key, position, data) {
                Ok(Some(whole)) => whole.to_vec(),
                Ok(None) => return,
                Err(error) => return self.datagram_failed(key, error),
            }
        };
        let Some(node) = self.cache.node(source) else {
            return bump(&mut self.stats.unknown_source_dropped);
        };
        bump(&mut self.stats.datagrams_forwarded);
        self.forward(now, Side::Can, Message::addressed(Mti::DATAGRAM, node, destination, payload));
    }

    fn can_stream_data(&mut self, now: Instant, source: NodeAlias, destination: NodeAlias, data: &[u8]) {
        let Some((&did, body)) = data.split_first() else {
            // Wire-spec §7.3: DLC 0 is invalid (no DID).
            return bump(&mut self.stats.invalid_frames);
        };
        let Some(destination) = self.proxied_node(destination) else {
            return bump(&mut self.stats.stayed_local);
        };
        let Some(node) = self.cache.node(source) else {
            return bump(&mut self.stats.unknown_source_dropped);
        };
        let tracked = StreamId::new(did).and_then(|did| self.find_open(node, destination, did, Side::Can));
        match tracked {
            Some(index) => self.merge_can_data(now, index, body),
            // Untracked: forwarded frame by frame.
            None => self.emit_full(Message::addressed(Mti::STREAM_DATA_SEND, node, destination, data.to_vec())),
        }
    }
}

/// The gateway's own frames queued at once: an AME per held message, an AMR per evicted
/// proxy, a Datagram Rejected per datagram slot (more rejects are dropped and counted).
fn raw_frame_bound(config: &GatewayConfig) -> usize {
    config.max_held_messages.saturating_add(config.max_proxied_nodes).saturating_add(config.datagram_slots)
}

fn other(side: Side) -> Side {
    match side {
        Side::Can => Side::Full,
        Side::Full => Side::Can,
    }
}

fn bump(counter: &mut u64) {
    *counter = counter.saturating_add(1);
}
