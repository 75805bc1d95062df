//! [`Node`]: one local node. It routes every message to the protocol it belongs to, answers
//! the message-network basics itself, and drains its protocols in one drive loop.

use alloc::vec::Vec;

use openlcb_stream::wire::{Emit, ErrorCode, ErrorReport};
use openlcb_stream::{
    AcceptPolicy, Event, EventId, Instant, Message, MessageRef, Mti, NodeId, PeerChange, PeerChanges, Queue, Receiver,
    StreamEndpoint, StreamHandle,
};

use crate::datagram::{
    Datagram, DatagramAnswer, DatagramError, DatagramFailure, DatagramId, DatagramService, OkFlags, rejected,
};
use crate::events::{EventNotice, EventService};
use crate::memconfig::{MemoryClient, MemoryConfigOptions, MemoryEvent, MemoryServer, acdi_user_strings, wire as mc};
#[cfg(feature = "memory-client")]
use crate::memconfig::{MemoryOperation, MemoryRequestError, TransferPath};
use crate::snip::{PendingSnip, SnipFailure, SnipInfo, SnipRequestError};
use crate::{DatagramStats, NodeConfig, Protocols};

/// The well-known Event ID Duplicate Node ID Detected.
pub const DUPLICATE_NODE_ID_DETECTED: EventId = EventId(0x0101_0000_0000_0201);

/// Something the application must know. Drain with [`Node::poll_event`] after every call.
#[derive(Debug, Clone, PartialEq, Eq)]
#[non_exhaustive]
pub enum NodeEvent {
    /// An event of the stream endpoint.
    Stream(Event),
    /// A datagram with a claimed content ID arrived; answer it with
    /// [`Node::answer_datagram`] within [`DatagramConfig::answer_timeout`](crate::DatagramConfig::answer_timeout).
    DatagramReceived {
        /// The sender.
        from: NodeId,
        /// Its bytes.
        datagram: Datagram,
    },
    /// A datagram this node sent was answered with Received OK.
    DatagramDelivered {
        /// The datagram.
        id: DatagramId,
        /// Its destination.
        to: NodeId,
        /// The flags of the OK (reply pending, timeout exponent).
        flags: OkFlags,
    },
    /// A datagram this node sent was not delivered.
    DatagramFailed {
        /// The datagram.
        id: DatagramId,
        /// Its destination.
        to: NodeId,
        /// Why.
        failure: DatagramFailure,
    },
    /// A node answered Verify Node ID (see [`Node::verify_all`]).
    Verified {
        /// The node, as its Verified Node ID message names it.
        node: NodeId,
    },
    /// A Protocol Support Reply arrived (see [`Node::request_protocols`]).
    ProtocolsReceived {
        /// The node that answered.
        peer: NodeId,
        /// What it supports.
        protocols: Protocols,
    },
    /// The answer to [`Node::request_snip`].
    SnipReceived {
        /// The node asked.
        peer: NodeId,
        /// Its strings.
        info: SnipInfo,
    },
    /// A SNIP request got no usable answer.
    SnipFailed {
        /// The node asked.
        peer: NodeId,
        /// Why.
        failure: SnipFailure,
    },
    /// Memory Configuration: a client operation ended, or the server was asked to do
    /// something the application carries out (reboot, install firmware, ...).
    Memory(MemoryEvent),
    /// Event Transport: a report, a Learn Event, or (when listening to everything) another
    /// node's Identified message.
    Events(EventNotice),
}

/// Counters of the node's own routing; each protocol has its own too.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
#[non_exhaustive]
pub struct NodeStats {
    /// Messages handled.
    pub messages_in: u64,
    /// Messages claiming to come from this node's own ID.
    pub own_echoes: u64,
    /// Addressed to another node.
    pub not_for_us: u64,
    /// Addressed messages of a protocol this node lacks, answered with OIR 0x1043.
    pub unknown_mti_rejected: u64,
    /// Answers (Verified Node ID, PIP, SNIP, OIR, datagram OK/Rejected) dropped because
    /// [`NodeConfig::transmit_queue_limit`] messages were waiting.
    pub answers_dropped: u64,
    /// OIR or TDE naming no protocol of this node, or one with nothing waiting.
    pub stray_error_reports: u64,
    /// SNIP requests answered.
    pub snip_answered: u64,
    /// SNIP replies nobody here asked for.
    pub stray_snip_replies: u64,
    /// The datagram service's counters.
    pub datagrams: DatagramStats,
}

/// The node's own output queues, lent to each protocol.
#[derive(Debug)]
pub(crate) struct Outputs {
    pub(crate) node: NodeId,
    limit: usize,
    transmits: Queue<Message>,
    events: Queue<NodeEvent>,
    answers_dropped: u64,
    /// Datagrams Memory Configuration sent and waits on: their outcome goes to
    /// `memory_inbox`, not to the application.
    memory_datagrams: Vec<DatagramId>,
    memory_inbox: Queue<NodeEvent>,
    /// Streams Memory Configuration finished: their `Sent` event is its, not the application's.
    memory_finished: Vec<StreamHandle>,
}

impl Outputs {
    /// What a node sends when it starts: Initialization Complete, then a global Verify Node
    /// ID naming itself. A node already holding this Node ID answers it; on CAN the link sees
    /// that Verified Node ID from another alias and reports a duplicate (CFT §6.2.5, MN
    /// §3.3.2).
    fn announce_start(&mut self) {
        let node = self.node;
        self.transmit(Message::initialization_complete(node));
        self.transmit(Message::global(Mti::VERIFY_NODE_ID_GLOBAL, node, node.to_bytes()));
    }

    /// Queues a message the node must send (a datagram, a request).
    pub(crate) fn transmit(&mut self, message: Message) {
        self.transmits.push_back(message);
    }

    /// Queues an answer, or drops and counts it when the queue is at its limit: a peer that
    /// floods queries must not grow it without bound.
    pub(crate) fn reply(&mut self, message: Message) {
        if self.transmits.len() >= self.limit {
            self.answers_dropped += 1;
        } else {
            self.transmits.push_back(message);
        }
    }

    /// Queues an event that another node caused, or drops it (`false`) when
    /// [`NodeConfig::transmit_queue_limit`] events wait: a flood must not grow the queue.
    pub(crate) fn notify(&mut self, event: NodeEvent) -> bool {
        let room = self.events.len() < self.limit;
        if room {
            self.events.push_back(event);
        }
        room
    }

    /// A message of the application's fits in the transmit queue.
    pub(crate) fn has_room(&self) -> bool {
        self.transmits.len() < self.limit
    }

    pub(crate) fn event(&mut self, event: NodeEvent) {
        if let NodeEvent::DatagramDelivered { id, .. } | NodeEvent::DatagramFailed { id, .. } = &event
            && let Some(index) = self.memory_datagrams.iter().position(|d| d == id)
        {
            self.memory_datagrams.swap_remove(index);
            self.memory_inbox.push_back(event);
            return;
        }
        self.events.push_back(event);
    }
}

/// What Memory Configuration's server and client get from the node for one call: its
/// queues, its datagram service and its stream endpoint.
pub(crate) struct Cx<'a> {
    pub(crate) now: Instant,
    pub(crate) out: &'a mut Outputs,
    pub(crate) datagrams: &'a mut DatagramService,
    pub(crate) streams: &'a mut StreamEndpoint,
    pub(crate) streams_enabled: bool,
    pub(crate) options: &'a MemoryConfigOptions,
    /// The node must send Initialization Complete (it changed Firmware Upgrade state).
    pub(crate) announce: bool,
    /// Reset/Reboot was asked for: the node reinitializes once the command is answered.
    pub(crate) reboot: bool,
}

impl Cx<'_> {
    /// Datagram Received OK for the datagram `to` sent.
    pub(crate) fn ok(&mut self, to: NodeId, flags: OkFlags) {
        let ok = Message::addressed(Mti::DATAGRAM_RECEIVED_OK, self.out.node, to, [flags.to_byte()].to_vec());
        self.out.reply(ok);
    }

    /// Datagram Rejected for the datagram `to` sent.
    pub(crate) fn reject(&mut self, to: NodeId, code: ErrorCode) {
        self.out.reply(rejected(self.out.node, to, code));
    }

    /// Sends a datagram whose outcome Memory Configuration takes.
    pub(crate) fn send_datagram(&mut self, to: NodeId, payload: &[u8]) -> Option<DatagramId> {
        let id = self.datagrams.send(self.now, self.out, to, payload).ok()?;
        self.out.memory_datagrams.push(id);
        Some(id)
    }

    /// Finishes a stream of Memory Configuration (its `Sent` event stays inside).
    pub(crate) fn finish_stream(&mut self, handle: StreamHandle) -> bool {
        let finished = self.streams.finish(self.now, handle).is_ok();
        if finished {
            self.out.memory_finished.push(handle);
        }
        finished
    }

    /// Sends a reply datagram that a Datagram OK promised: never dropped (its delivery is
    /// the datagram service's business).
    pub(crate) fn send_reply(&mut self, to: NodeId, payload: &[u8]) {
        let id = self.datagrams.send_promised(self.now, self.out, to, payload);
        self.out.memory_datagrams.push(id);
    }

    /// A reply to `to` could be queued now.
    pub(crate) fn has_reply_room(&self, to: NodeId) -> bool {
        self.datagrams.has_room(to)
    }
}

/// One local OpenLCB node: the stream endpoint, the datagram service, Memory
/// Configuration, SNIP and the message-network basics, in the handle / command / poll shape
/// of the stream core. See the crate documentation for the drive loop.
///
/// Once a memory server is set, the policy in [`NodeConfig::stream`] becomes
/// [`AcceptPolicy::Ask`] in the endpoint: the server claims the requests of the Write Streams
/// it was told of first (so that their window is what the space can take), and the node
/// applies the application's policy to the rest, at once. `AcceptAll` accepts them;
/// `RejectAll(code)` refuses them with `code` while Memory Configuration still takes its own:
/// the policy of a node that takes streams only for Memory Configuration. With
/// [`NodeConfig::streams_enabled`] off no stream is taken at all. While Memory
/// Configuration has something running, take stream events from
/// [`poll_event`](Node::poll_event), not from the endpoint: it keeps its own.
///
/// A Memory Configuration Reset/Reboot command makes the node start again as after a
/// power-up, as far as its protocols go: every stream, datagram, SNIP request and Memory
/// Configuration operation ends, the Firmware Upgrade state and the lock end, and
/// Initialization Complete goes out after the command's Datagram OK. The spaces keep their
/// contents (they are the application's memory); the application is told with
/// `MemoryEvent::ResetRequested` and may do more (a firmware resets its processor).
#[derive(Debug)]
pub struct Node {
    config: NodeConfig,
    protocols: Protocols,
    memory_server: Option<MemoryServer>,
    memory_client: MemoryClient,
    /// The time of the last call that gave one (for events drained by `poll_event`).
    last_now: Instant,
    streams: StreamEndpoint,
    datagrams: DatagramService,
    snip_reply: Vec<u8>,
    snip_requests: Vec<PendingSnip>,
    pub(crate) events: EventService,
    pub(crate) out: Outputs,
    stats: NodeStats,
}

impl Node {
    /// A node with Node ID `id`. With [`NodeConfig::send_initialization_complete`] its first
    /// transmit is Initialization Complete.
    pub fn new(id: NodeId, config: NodeConfig) -> Self {
        let mut out = Outputs {
            node: id,
            limit: config.transmit_queue_limit,
            transmits: Queue::new(),
            events: Queue::new(),
            answers_dropped: 0,
            memory_datagrams: Vec::new(),
            memory_inbox: Queue::new(),
            memory_finished: Vec::new(),
        };
        if config.send_initialization_complete {
            out.announce_start();
        }
        let mut protocols = Protocols::DATAGRAM | Protocols::SIMPLE_NODE_INFORMATION | config.extra_protocols;
        if config.streams_enabled {
            protocols = protocols | Protocols::STREAM;
        }
        if config.events.is_active() {
            protocols = protocols | Protocols::EVENT_EXCHANGE;
        }
        Node {
            protocols,
            memory_server: None,
            memory_client: MemoryClient::default(),
            last_now: Instant::ZERO,
            streams: StreamEndpoint::new(id, config.stream.clone()),
            datagrams: DatagramService::new(config.datagrams.clone()),
            snip_reply: config.snip.to_payload(),
            snip_requests: Vec::with_capacity(config.max_snip_requests),
            events: EventService::new(&config.events, config.send_initialization_complete),
            out,
            stats: NodeStats::default(),
            config,
        }
    }

    // ----- getters -----

    /// The local Node ID.
    pub fn node_id(&self) -> NodeId {
        self.out.node
    }

    /// The configuration.
    pub fn config(&self) -> &NodeConfig {
        &self.config
    }

    /// The protocols this node announces in its Protocol Support Reply: exactly what it
    /// implements, and with a memory server what it serves ([`MemoryServer::protocols`]).
    pub fn protocols(&self) -> Protocols {
        match &self.memory_server {
            None => self.protocols,
            Some(server) => self.protocols | server.protocols(),
        }
    }

    /// The memory server, to read back its spaces and state.
    pub fn memory_server(&self) -> Option<&MemoryServer> {
        self.memory_server.as_ref()
    }

    /// The memory server, mutable (to change a space between transfers).
    pub fn memory_server_mut(&mut self) -> Option<&mut MemoryServer> {
        self.memory_server.as_mut()
    }

    /// Bytes an operation has moved so far (`None` once it has ended).
    #[cfg(feature = "memory-client")]
    pub fn memory_progress(&self, operation: MemoryOperation) -> Option<u64> {
        self.memory_client.progress(operation)
    }

    /// The stream endpoint, for its getters.
    pub fn streams(&self) -> &StreamEndpoint {
        &self.streams
    }

    /// The stream endpoint, for its commands (`open`, `write`, `read`, `accept`, ...). Its
    /// messages and events come out of the node's `poll_transmit` and `poll_event`.
    pub fn streams_mut(&mut self) -> &mut StreamEndpoint {
        &mut self.streams
    }

    /// Counters.
    pub fn stats(&self) -> NodeStats {
        NodeStats { answers_dropped: self.out.answers_dropped, datagrams: self.datagrams.stats, ..self.stats }
    }

    // ----- outputs -----

    /// The next message to send: the node's own (answers, datagrams, requests) first, then
    /// its event announcements, then the streams'.
    pub fn poll_transmit(&mut self) -> Option<Message> {
        let node = self.out.node;
        self.out
            .transmits
            .pop_front()
            .or_else(|| self.events.poll_transmit(&self.config.events, node))
            .or_else(|| self.streams.poll_transmit())
    }

    /// The next event.
    ///
    /// Memory Configuration works here: the stream events and datagram outcomes of its
    /// transfers are taken in and acted on (which may queue messages for `poll_transmit`),
    /// so drain both, as the drive loop says, until neither has anything.
    pub fn poll_event(&mut self) -> Option<NodeEvent> {
        if self.out.events.is_empty() {
            self.settle(self.last_now);
        }
        self.out.events.pop_front()
    }

    /// When to call `handle_timeout` next.
    pub fn poll_timeout(&self) -> Option<Instant> {
        let snip = self.snip_requests.iter().map(|p| p.deadline).min();
        let server = self.memory_server.as_ref().and_then(MemoryServer::poll_timeout);
        let client = self.client().and_then(MemoryClient::poll_timeout);
        [self.streams.poll_timeout(), self.datagrams.poll_timeout(), snip, server, client].into_iter().flatten().min()
    }

    // ----- inputs -----

    /// Feeds one received message; it goes to the protocol it belongs to.
    pub fn handle_message(&mut self, now: Instant, msg: MessageRef<'_>) {
        self.last_now = now;
        self.stats.messages_in += 1;
        let protocols = self.protocols();
        let memory_datagram = msg.mti == Mti::DATAGRAM && self.is_memory_datagram(msg.source, msg.payload);
        if msg.source == self.out.node {
            self.stats.own_echoes += 1;
            return;
        }
        match msg.destination {
            Some(destination) if destination != self.out.node => {
                self.stats.not_for_us += 1;
                return;
            }
            None if msg.mti.is_addressed() => {
                self.stats.not_for_us += 1;
                return;
            }
            _ => {}
        }
        let peer = msg.source;
        let out = &mut self.out;
        match msg.mti {
            mti if mti.is_stream() && self.config.streams_enabled => self.streams.handle_message(now, msg),
            Mti::INITIALIZATION_COMPLETE | Mti::INITIALIZATION_COMPLETE_SIMPLE => {
                self.streams.handle_message(now, msg);
                self.datagrams.peer_restarted(now, out, peer);
                if let Some(server) = &mut self.memory_server {
                    server.forget_peer(Some(peer));
                }
                self.with_client(now, |cx, client| client.peer_restarted(cx, peer));
            }
            Mti::DATAGRAM if memory_datagram => self.on_memory_datagram(now, peer, msg.payload),
            Mti::OPTIONAL_INTERACTION_REJECTED | Mti::TERMINATE_DUE_TO_ERROR => self.on_error_report(now, msg),
            Mti::DATAGRAM => self.datagrams.on_datagram(now, out, peer, msg.payload),
            Mti::DATAGRAM_RECEIVED_OK => self.datagrams.on_received_ok(now, out, peer, msg.payload),
            Mti::DATAGRAM_REJECTED => {
                self.datagrams.on_rejected(now, out, peer, crate::datagram::rejection_code(msg.payload));
            }
            Mti::SIMPLE_NODE_INFO_REQUEST => {
                self.stats.snip_answered += 1;
                out.reply(Message::addressed(Mti::SIMPLE_NODE_INFO_REPLY, out.node, peer, self.snip_reply.clone()));
            }
            Mti::SIMPLE_NODE_INFO_REPLY => self.on_snip_reply(peer, msg.payload),
            Mti::PROTOCOL_SUPPORT_REPLY
                if cfg!(feature = "memory-client") && self.memory_client.wants_protocols(peer) =>
            {
                let protocols = Protocols::from_payload(msg.payload);
                self.with_client(now, |cx, client| client.on_protocols(cx, peer, protocols));
            }
            Mti::PROTOCOL_SUPPORT_REPLY => {
                out.event(NodeEvent::ProtocolsReceived { peer, protocols: Protocols::from_payload(msg.payload) });
            }
            Mti::VERIFIED_NODE_ID | Mti::VERIFIED_NODE_ID_SIMPLE => {
                // The payload names the node; on CAN the source may be a provisional name.
                let node = NodeId::from_slice(msg.payload).unwrap_or(peer);
                out.event(NodeEvent::Verified { node });
            }
            // MN §3.3.2: a global Verify is answered when it names no node, or this one.
            Mti::VERIFY_NODE_ID_GLOBAL
                if msg.payload.len() < 6 || NodeId::from_slice(msg.payload) == Some(out.node) =>
            {
                out.reply(Message::verified_node_id(out.node));
            }
            Mti::VERIFY_NODE_ID_ADDRESSED => out.reply(Message::verified_node_id(out.node)),
            Mti::PROTOCOL_SUPPORT_INQUIRY => {
                let flags = protocols.to_bytes().to_vec();
                out.reply(Message::addressed(Mti::PROTOCOL_SUPPORT_REPLY, out.node, peer, flags));
            }
            mti if crate::events::is_event_mti(mti) && self.config.events.is_active() => {
                self.events.handle_message(&self.config.events, out, msg);
            }
            mti if mti.is_addressed() && !is_answer(mti) => {
                // MN §3.5.2: an addressed message of a protocol this node lacks.
                self.stats.unknown_mti_rejected += 1;
                let oir = ErrorReport { code: ErrorCode::NOT_IMPLEMENTED_MTI, mti: Some(mti) };
                out.reply(Message::addressed(Mti::OPTIONAL_INTERACTION_REJECTED, out.node, peer, oir.to_bytes()));
            }
            _ => {}
        }
    }

    /// An OIR or TDE goes to the protocol whose MTI it names; one naming nothing goes to every
    /// protocol with something open with that peer (node-protocols.md C-13).
    fn on_error_report(&mut self, now: Instant, msg: MessageRef<'_>) {
        let report = ErrorReport::parse(msg.payload);
        let peer = msg.source;
        let to_streams = report.mti.is_none_or(Mti::is_stream) && self.config.streams_enabled;
        let to_datagrams = matches!(report.mti, None | Some(Mti::DATAGRAM));
        let to_snip = matches!(report.mti, None | Some(Mti::SIMPLE_NODE_INFO_REQUEST));
        let before = self.streams.stats().stray_error_reports;
        let mut handled = false;
        if to_streams {
            self.streams.handle_message(now, msg);
            handled |= self.streams.stats().stray_error_reports == before;
        }
        if to_datagrams && self.datagrams.is_waiting_for(peer) {
            // OpenMRN reads an OIR or TDE naming Datagram, or nothing, as a rejection.
            self.datagrams.on_rejected(now, &mut self.out, peer, report.code);
            handled = true;
        }
        if to_snip && let Some(index) = self.snip_requests.iter().position(|p| p.peer == peer) {
            self.snip_requests.swap_remove(index);
            self.out.event(NodeEvent::SnipFailed { peer, failure: SnipFailure::Rejected(report.code) });
            handled = true;
        }
        if !handled {
            self.stats.stray_error_reports += 1;
        }
    }

    fn on_snip_reply(&mut self, peer: NodeId, payload: &[u8]) {
        let Some(index) = self.snip_requests.iter().position(|p| p.peer == peer) else {
            self.stats.stray_snip_replies += 1;
            return;
        };
        let whole = self.snip_requests.get_mut(index).is_some_and(|p| p.push(payload));
        if whole {
            let done = self.snip_requests.swap_remove(index);
            self.out.event(NodeEvent::SnipReceived { peer, info: SnipInfo::parse(&done.reply) });
        }
    }

    /// Runs every timer due at `now`. Early or repeated calls are harmless.
    pub fn handle_timeout(&mut self, now: Instant) {
        self.last_now = now;
        self.streams.handle_timeout(now);
        self.datagrams.handle_timeout(now, &mut self.out);
        self.with_memory(now, |cx, server, _| {
            if let Some(server) = server {
                server.handle_timeout(cx);
            }
        });
        self.with_client(now, |cx, client| client.handle_timeout(cx));
        while let Some(index) = self.snip_requests.iter().position(|p| p.deadline <= now) {
            let expired = self.snip_requests.swap_remove(index);
            // A partial reply is still worth having (SNIP-TN §2.6: be liberal).
            let event = if expired.reply.is_empty() {
                NodeEvent::SnipFailed { peer: expired.peer, failure: SnipFailure::TimedOut }
            } else {
                NodeEvent::SnipReceived { peer: expired.peer, info: SnipInfo::parse(&expired.reply) }
            };
            self.out.event(event);
        }
    }

    /// The transport learnt a change of peer ([`PeerChange`]); a transport handed this node
    /// as its [`Receiver`] (the CAN link) calls it as it learns it.
    ///
    /// - [`PeerChange::Lost`]: the peer's streams end, datagrams to it fail, SNIP and Memory
    ///   Configuration requests to it fail.
    /// - [`PeerChange::Renamed`] (on CAN: its Node ID was learnt, or its mapping forgotten and
    ///   it is named by its alias): everything open with the old name goes on with the new
    ///   one, queued messages included.
    pub fn peer_changed(&mut self, change: PeerChange) {
        self.streams.peer_changed(change);
        match change {
            PeerChange::Lost(peer) => self.peer_lost(peer),
            PeerChange::Renamed { from, to } => self.rename_peer(from, to),
            _ => {}
        }
    }

    /// [`PeerChange::Renamed`] for all but the streams.
    fn rename_peer(&mut self, from: NodeId, to: NodeId) {
        for message in self.out.transmits.iter_mut() {
            message.rename_peer(from, to);
        }
        self.datagrams.rename_peer(from, to);
        if let Some(client) = self.client_mut() {
            client.rename_peer(from, to);
        }
        if let Some(server) = &mut self.memory_server {
            server.rename_peer(from, to);
        }
        for pending in self.snip_requests.iter_mut().filter(|p| p.peer == from) {
            pending.peer = to;
        }
    }

    /// [`PeerChange::Lost`] for all but the streams.
    fn peer_lost(&mut self, peer: NodeId) {
        self.datagrams.peer_lost(&mut self.out, Some(peer));
        self.fail_snip(Some(peer));
        self.forget_memory_peer(Some(peer));
    }

    /// The transport lost its link (e.g. this node's CAN alias): everything open ends.
    pub fn link_lost(&mut self) {
        // The transport announces the node again once it is back; its events follow.
        self.events.announce(&self.config.events);
        self.streams.link_lost();
        self.datagrams.peer_lost(&mut self.out, None);
        self.fail_snip(None);
        self.forget_memory_peer(None);
    }

    fn forget_memory_peer(&mut self, peer: Option<NodeId>) {
        if let Some(server) = &mut self.memory_server {
            server.forget_peer(peer);
        }
        let now = self.last_now;
        self.with_client(now, |cx, client| client.peer_lost(cx, peer));
    }

    fn fail_snip(&mut self, peer: Option<NodeId>) {
        while let Some(index) = self.snip_requests.iter().position(|p| peer.is_none_or(|n| n == p.peer)) {
            let lost = self.snip_requests.swap_remove(index);
            self.out.event(NodeEvent::SnipFailed { peer: lost.peer, failure: SnipFailure::PeerLost });
        }
    }

    // ----- commands -----

    /// Sends a datagram of at most 72 bytes to `to`. Datagrams to one node go one at a time
    /// (DG §6.1); later ones wait their turn. `DatagramDelivered` or `DatagramFailed` follows.
    pub fn send_datagram(&mut self, now: Instant, to: NodeId, payload: &[u8]) -> Result<DatagramId, DatagramError> {
        self.datagrams.send(now, &mut self.out, to, payload)
    }

    /// Answers the datagram `from` sent (raised by `DatagramReceived`).
    pub fn answer_datagram(&mut self, from: NodeId, answer: DatagramAnswer) -> Result<(), DatagramError> {
        self.datagrams.answer(&mut self.out, from, answer)
    }

    /// Asks `peer` for its Simple Node Information. `SnipReceived` or `SnipFailed` follows.
    pub fn request_snip(&mut self, now: Instant, peer: NodeId) -> Result<(), SnipRequestError> {
        if peer == self.out.node {
            return Err(SnipRequestError::SelfAddressed);
        }
        if self.snip_requests.iter().any(|p| p.peer == peer) {
            return Err(SnipRequestError::AlreadyPending);
        }
        if self.snip_requests.len() >= self.config.max_snip_requests {
            return Err(SnipRequestError::TooMany);
        }
        let deadline = now + self.config.snip_timeout;
        self.snip_requests.push(PendingSnip { peer, deadline, reply: Vec::new() });
        self.out.transmit(Message::addressed(Mti::SIMPLE_NODE_INFO_REQUEST, self.out.node, peer, Vec::new()));
        Ok(())
    }

    /// Sends a global Verify Node ID: every node on the network answers with Verified Node
    /// ID (how a tool finds who is there).
    pub fn verify_all(&mut self) {
        self.out.transmit(Message::global(Mti::VERIFY_NODE_ID_GLOBAL, self.out.node, Vec::new()));
    }

    /// Tells the network that another node holds this node's Node ID, by the well-known
    /// event Duplicate Node ID Detected (`01.01.00.00.00.00.02.01`, a Producer/Consumer
    /// Event Report). Call it when the transport reports a duplicate (on CAN,
    /// `LinkEvent::DuplicateNodeId`).
    pub fn report_duplicate_node_id(&mut self) {
        let report = self.duplicate_node_id_report();
        self.out.transmit(report);
    }

    /// The message [`report_duplicate_node_id`](Self::report_duplicate_node_id) sends, for a
    /// transport that sends it itself as it leaves the network (`CanLink::leave`).
    pub fn duplicate_node_id_report(&self) -> Message {
        let event = DUPLICATE_NODE_ID_DETECTED.to_bytes();
        Message::global(Mti::PRODUCER_CONSUMER_EVENT_REPORT, self.out.node, event.to_vec())
    }

    /// Asks `peer` which protocols it supports; `ProtocolsReceived` follows if it answers.
    pub fn request_protocols(&mut self, peer: NodeId) {
        self.out.transmit(Message::addressed(Mti::PROTOCOL_SUPPORT_INQUIRY, self.out.node, peer, Vec::new()));
    }
}

/// Memory Configuration: the server, the client, and the routing of their datagrams and
/// streams.
impl Node {
    /// Serves `server`'s spaces from now on: datagrams with content ID 0x20 that are
    /// commands go to it, and the PIP announces Memory Configuration (and Firmware Upgrade
    /// with space 0xEF). Its ACDI spaces mirror this node's SNIP strings.
    pub fn set_memory_server(&mut self, mut server: MemoryServer) {
        server.mirror_snip(&self.config.snip);
        self.memory_server = Some(server);
        // The server claims its Write Streams before anything is decided, to grant them the
        // window their space can take; the node applies the application's policy to the rest.
        self.streams.set_accept_policy(AcceptPolicy::Ask);
    }

    /// [`set_memory_server`](Self::set_memory_server), builder style.
    pub fn with_memory_server(mut self, server: MemoryServer) -> Self {
        self.set_memory_server(server);
        self
    }

    /// Reads `len` bytes (`None`: to the end of the space) of `space` from `address` on
    /// `peer`. Progress with [`memory_progress`](Self::memory_progress); `ReadDone` or
    /// `Failed` follows.
    #[cfg(feature = "memory-client")]
    pub fn read_memory(
        &mut self,
        now: Instant,
        peer: NodeId,
        space: u8,
        address: u32,
        len: Option<u32>,
        path: TransferPath,
    ) -> Result<MemoryOperation, MemoryRequestError> {
        self.last_now = now;
        self.with_memory(now, |cx, _, client| client.read(cx, peer, space, address, len, path))
    }

    /// Writes `data` into `space` from `address` on `peer`; `WriteDone` or `Failed` follows.
    #[cfg(feature = "memory-client")]
    pub fn write_memory(
        &mut self,
        now: Instant,
        peer: NodeId,
        space: u8,
        address: u32,
        data: impl Into<Vec<u8>>,
        path: TransferPath,
    ) -> Result<MemoryOperation, MemoryRequestError> {
        self.last_now = now;
        let data = data.into();
        self.with_memory(now, |cx, _, client| client.write(cx, peer, space, address, data, path))
    }

    /// Upgrades `peer`'s firmware with `image` (FWU §5.5): Freeze, Protocol Support
    /// Inquiry, the image to space 0xEF from address 0 by stream (when the target's PIP has
    /// the Stream bit) or by 64-byte datagram writes, Unfreeze. `WriteDone` or `Failed`
    /// follows; the target rebooting at Unfreeze counts as success.
    #[cfg(feature = "memory-client")]
    pub fn upgrade_firmware(
        &mut self,
        now: Instant,
        peer: NodeId,
        image: impl Into<Vec<u8>>,
        path: TransferPath,
    ) -> Result<MemoryOperation, MemoryRequestError> {
        self.last_now = now;
        let image = image.into();
        self.with_memory(now, |cx, _, client| client.upgrade(cx, peer, image, path))
    }

    /// Tells `peer` that a configuration tool has finished writing (Update Complete, MC
    /// §4.23), so that it applies what changed; `WriteDone` (of 0 bytes) or `Failed` follows.
    #[cfg(feature = "memory-client")]
    pub fn update_complete(&mut self, now: Instant, peer: NodeId) -> Result<MemoryOperation, MemoryRequestError> {
        self.last_now = now;
        self.with_memory(now, |cx, _, client| client.update_complete(cx, peer))
    }

    /// The Memory Configuration client, when the `memory-client` feature builds it in
    /// (without it the client is never called, so none of its code is linked).
    fn client(&self) -> Option<&MemoryClient> {
        cfg!(feature = "memory-client").then_some(&self.memory_client)
    }

    fn client_mut(&mut self) -> Option<&mut MemoryClient> {
        cfg!(feature = "memory-client").then_some(&mut self.memory_client)
    }

    /// Runs `f` on the client with the node's parts lent to it (nothing without the
    /// `memory-client` feature).
    fn with_client(&mut self, now: Instant, f: impl FnOnce(&mut Cx<'_>, &mut MemoryClient)) {
        if cfg!(feature = "memory-client") {
            self.with_memory(now, |cx, _, client| f(cx, client));
        }
    }

    /// Runs `f` on the memory server and client with the node's parts lent to them.
    fn with_memory<T>(
        &mut self,
        now: Instant,
        f: impl FnOnce(&mut Cx<'_>, Option<&mut MemoryServer>, &mut MemoryClient) -> T,
    ) -> T {
        let Node { config, out, datagrams, streams, memory_server, memory_client, .. } = self;
        let mut cx = Cx {
            now,
            out,
            datagrams,
            streams,
            streams_enabled: config.streams_enabled,
            options: &config.memory,
            announce: false,
            reboot: false,
        };
        let result = f(&mut cx, memory_server.as_mut(), memory_client);
        if cx.announce {
            // FWU §5.2: every change of state ends with a new Initialization Complete.
            let node = out.node;
            out.transmit(Message::initialization_complete(node));
        }
        result
    }

    /// A datagram with content ID 0x20 that Memory Configuration takes: a command when a
    /// server is configured; a reply when the client has an operation with the sender (or
    /// the application does not claim 0x20).
    fn is_memory_datagram(&self, peer: NodeId, payload: &[u8]) -> bool {
        match payload {
            [mc::CONTENT_ID, command, ..] if mc::is_reply(*command) => {
                self.client().is_some_and(|c| c.has_operation_with(peer) || !self.datagrams.claims(mc::CONTENT_ID))
            }
            [mc::CONTENT_ID, ..] => self.memory_server.is_some(),
            _ => false,
        }
    }

    fn on_memory_datagram(&mut self, now: Instant, peer: NodeId, payload: &[u8]) {
        let is_reply = payload.get(1).is_some_and(|c| mc::is_reply(*c));
        let reboot = self.with_memory(now, |cx, server, client| {
            if is_reply {
                // Acknowledge a reply before anything else is sent (MC-TN §3.1.3.3).
                cx.ok(peer, OkFlags::default());
                if cfg!(feature = "memory-client") {
                    client.on_reply(cx, peer, payload);
                }
            } else if let Some(server) = server {
                server.on_command(cx, peer, payload);
            }
            cx.reboot
        });
        self.update_user_info();
        if reboot {
            self.reinitialize();
        }
    }

    /// Reset/Reboot (MC §4.24) of a library node: it starts again as after a power-up, as far
    /// as the protocols go. Every stream, datagram, SNIP request and Memory Configuration
    /// operation ends (their owners hear why), the Firmware Upgrade state and the lock end,
    /// and Initialization Complete goes out (after the reset command's Datagram OK). The
    /// spaces keep their contents: they are the application's memory, and the application,
    /// told by `MemoryEvent::ResetRequested`, may do more (a firmware resets its processor).
    fn reinitialize(&mut self) {
        self.link_lost();
        if let Some(server) = &mut self.memory_server {
            server.reinitialize();
        }
        self.out.announce_start();
    }

    /// A write to space 0xFB changed the user strings: SNIP follows them.
    fn update_user_info(&mut self) {
        let Some(server) = &mut self.memory_server else { return };
        if !core::mem::take(&mut server.user_info_changed) {
            return;
        }
        let (name, description) = acdi_user_strings(server.acdi_user());
        self.config.snip.user_name = name;
        self.config.snip.user_description = description;
        self.snip_reply = self.config.snip.to_payload();
        self.out.event(NodeEvent::Memory(MemoryEvent::UserInfoChanged));
    }

    /// Feeds Memory Configuration what waits for it (its datagrams' outcomes, the stream
    /// events), raises the rest, and applies the application's accept policy to streams
    /// nobody here claimed. Runs from `poll_event`, at the time of the last input (the
    /// time those events arose).
    fn settle(&mut self, now: Instant) {
        // The application's policy, for the requests Memory Configuration did not claim (the
        // endpoint raises requests only when it asks: with a server, or with `Ask`).
        let unclaimed_streams = self.config.stream.accept_policy;
        loop {
            let mut moved = false;
            while let Some(event) = self.out.memory_inbox.pop_front() {
                moved = true;
                let (id, result) = match event {
                    NodeEvent::DatagramDelivered { id, flags, .. } => (id, Ok(flags)),
                    NodeEvent::DatagramFailed { id, failure, .. } => (id, Err(failure)),
                    _ => continue,
                };
                // Outcomes of the server's reply datagrams need nothing more.
                self.with_client(now, |cx, client| {
                    client.on_datagram_outcome(cx, id, result);
                });
            }
            while let Some(event) = self.streams.poll_event() {
                moved = true;
                let claimed = self.with_memory(now, |cx, server, client| {
                    server.is_some_and(|s| s.on_stream_event(cx, &event))
                        || (cfg!(feature = "memory-client") && client.on_stream_event(cx, &event))
                });
                let ours_sent = match event {
                    Event::Sent { handle, .. } => self.out.memory_finished.iter().position(|h| *h == handle),
                    _ => None,
                };
                match event {
                    _ if claimed => {}
                    Event::Sent { .. } if ours_sent.is_some() => {
                        if let Some(index) = ours_sent {
                            self.out.memory_finished.swap_remove(index);
                        }
                    }
                    Event::IncomingRequest { handle, .. } if unclaimed_streams != AcceptPolicy::Ask => {
                        let _ = match unclaimed_streams {
                            AcceptPolicy::RejectAll(code) => self.streams.reject(now, handle, code),
                            _ => self.streams.accept(now, handle, None),
                        };
                    }
                    event => self.out.events.push_back(NodeEvent::Stream(event)),
                }
            }
            self.with_client(now, |cx, client| client.poll_streams(cx));
            if !moved {
                break;
            }
        }
    }
}

impl PeerChanges for Node {
    fn peer_changed(&mut self, change: PeerChange) {
        Node::peer_changed(self, change);
    }
}

impl Receiver for Node {
    fn handle_message(&mut self, now: Instant, message: MessageRef<'_>) {
        Node::handle_message(self, now, message);
    }
}

/// Messages that answer something: rejecting them would start a loop of rejections.
fn is_answer(mti: Mti) -> bool {
    matches!(
        mti,
        Mti::OPTIONAL_INTERACTION_REJECTED
            | Mti::TERMINATE_DUE_TO_ERROR
            | Mti::PROTOCOL_SUPPORT_REPLY
            | Mti::DATAGRAM_RECEIVED_OK
            | Mti::DATAGRAM_REJECTED
            | Mti::SIMPLE_NODE_INFO_REPLY
    )
}
