//! [`Node`]: one local node. It answers the message-network basics itself, routes every
//! other message to the first of its services that takes it, and drains them in one drive
//! loop.

use alloc::boxed::Box;
use alloc::vec::Vec;

#[cfg(feature = "streams")]
use openlcb_stream::wire::ReplyCode;
use openlcb_stream::wire::{Emit, ErrorCode, ErrorReport};
use openlcb_stream::{
    AcceptPolicy, Event, EventId, Instant, Message, MessageRef, Mti, NodeId, PeerChange, PeerChanges, Queue, Receiver,
};

#[cfg(feature = "broadcast-time")]
use crate::broadcast_time::ClockEvent;
use crate::datagram::{Datagram, DatagramFailure, DatagramId, DatagramService, OkFlags};
#[cfg(feature = "app-datagrams")]
use crate::datagram::{DatagramAnswer, DatagramError, DatagramOwner};
use crate::events::EventNotice;
pub(crate) use crate::memconfig::Cx;
use crate::memconfig::{MemoryConfig, MemoryEvent, MemoryLent, MemoryServer, acdi_user_strings};
#[cfg(feature = "memory-client")]
use crate::memconfig::{MemoryOperation, MemoryRequestError, NodeCommand, TransferPath};
use crate::service::{Lent, Service, ServiceChange, Services, earliest};
#[cfg(feature = "snip-client")]
use crate::snip::SnipRequestError;
use crate::snip::{SnipFailure, SnipInfo};
use crate::streams::{self, Endpoint};
use crate::{DatagramStats, NodeConfig, Protocols};
#[cfg(feature = "streams")]
use openlcb_stream::{AcceptOptions, OpenOptions, StreamEndpoint, StreamError, StreamHandle};

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
        /// Its bytes (boxed, so that the events every node raises stay small).
        datagram: Box<Datagram>,
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
        /// Its strings (boxed, so that the events every node raises stay small).
        info: Box<SnipInfo>,
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
    /// Broadcast Time: a clock of this node changed (see [`broadcast_time`](crate::broadcast_time)).
    #[cfg(feature = "broadcast-time")]
    Clock(ClockEvent),
    /// Traction Control, Train Search: the train changed, or a command station is asked to
    /// create one (see [`traction`](crate::traction)).
    #[cfg(feature = "traction")]
    Train(crate::traction::TrainEvent),
    /// Traction Control: a train answered this node's throttle, or took it off a train.
    #[cfg(feature = "traction")]
    Throttle(crate::traction::ThrottleEvent),
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

/// The counters the node keeps itself (the rest of [`NodeStats`] are its services', read when
/// asked for): 32-bit, each stopping at `u32::MAX`, as the node is built and kept in a
/// microcontroller's RAM.
#[derive(Debug, Default)]
struct MessageCounts {
    messages_in: u32,
    own_echoes: u32,
    not_for_us: u32,
    unknown_mti_rejected: u32,
    stray_error_reports: u32,
}

/// Counts one more, stopping at `u32::MAX`. Out of line: one call is smaller than the
/// saturating add (flash).
#[inline(never)]
pub(crate) fn bump(counter: &mut u32) {
    *counter = counter.saturating_add(1);
}

/// The node's own output queues, lent to each service.
#[derive(Debug)]
pub(crate) struct Outputs {
    pub(crate) node: NodeId,
    limit: usize,
    transmits: Queue<Message>,
    events: Queue<NodeEvent>,
    answers_dropped: u32,
}

impl Outputs {
    /// What a node sends when it starts: Initialization Complete, then a global Verify Node
    /// ID naming itself. A node already holding this Node ID answers it; on CAN the link sees
    /// that Verified Node ID from another alias and reports a duplicate (CFT §6.2.5, MN
    /// §3.3.2).
    fn announce_start(&mut self) {
        let node = self.node;
        self.transmit(Message::initialization_complete(node));
        self.transmit(Message::global(Mti::VERIFY_NODE_ID_GLOBAL, node, node.to_bytes().to_vec()));
    }

    /// Queues a message the node must send (a datagram, a request).
    pub(crate) fn transmit(&mut self, message: Message) {
        self.transmits.push_back(message);
    }

    /// Queues an answer, or drops and counts it when the queue is at its limit: a peer that
    /// floods queries must not grow it without bound.
    pub(crate) fn reply(&mut self, message: Message) {
        if self.transmits.len() >= self.limit {
            bump(&mut self.answers_dropped);
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

    /// Queues an event that ends something this node started (bounded by what it started).
    pub(crate) fn event(&mut self, event: NodeEvent) {
        self.events.push_back(event);
    }
}

/// One local OpenLCB node: the stream endpoint and the services built beside it (datagrams,
/// SNIP, Memory Configuration, events), with the message-network basics, in the handle /
/// command / poll shape of the stream core. See the crate documentation for the drive loop.
///
/// Once a memory server is set, the policy in [`NodeConfig::stream`] becomes
/// [`AcceptPolicy::Ask`] in the endpoint: the server claims the requests of the Write Streams
/// it was told of first (so that their window is what the space can take), and the node
/// applies the application's policy to the rest, at once. `AcceptAll` accepts them;
/// `RejectAll(code)` refuses them with `code` while Memory Configuration still takes its own:
/// the policy of a node that takes streams only for Memory Configuration. With
/// [`NodeConfig::streams_enabled`] off no stream is taken at all. Memory Configuration's
/// stream events never reach [`poll_event`](Node::poll_event): give stream commands through
/// [`streams_mut`](Node::streams_mut), which lets it act on them after each command.
///
/// A Memory Configuration Reset/Reboot command makes the node start again as after a
/// power-up, as far as its protocols go: every stream, datagram, SNIP request and Memory
/// Configuration operation ends, the Firmware Upgrade state and the lock end, and
/// Initialization Complete goes out after the command's Datagram OK. The spaces keep their
/// contents (they are the application's memory); the application is told with
/// `MemoryEvent::ResetRequested` and may do more (a firmware resets its processor).
#[derive(Debug)]
pub struct Node {
    pub(crate) config: NodeConfig,
    protocols: Protocols,
    streams: Endpoint,
    memory: MemoryConfig,
    pub(crate) services: Services,
    pub(crate) out: Outputs,
    stats: MessageCounts,
}

/// Lends the node's parts for one call: `$lent` is what every service gets, `$parts` binds
/// the stream endpoint, Memory Configuration and the other services.
macro_rules! lend {
    ($node:expr, $now:expr, |$lent:ident, $parts:pat_param| $body:expr) => {{
        let Node { config, out, streams, memory, services, .. } = $node;
        let mut $lent = Lent { now: $now, out, config };
        let $parts = (streams, memory, services);
        $body
    }};
}

/// Memory Configuration's loan: the node's queues, the datagram service, the endpoint.
fn memory_lent<'a>(
    now: Instant,
    out: &'a mut Outputs,
    config: &'a NodeConfig,
    datagrams: &'a mut DatagramService,
    streams: &'a mut Endpoint,
) -> MemoryLent<'a> {
    MemoryLent { lent: Lent { now, out, config }, datagrams, streams }
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
        };
        if config.send_initialization_complete {
            out.announce_start();
        }
        let services = Services::new(&config);
        let mut protocols = Protocols::DATAGRAM
            | Protocols::SIMPLE_NODE_INFORMATION
            | config.extra_protocols
            | services.protocols(&config);
        if streams::enabled(&config) {
            protocols = protocols | Protocols::STREAM;
        }
        Node {
            protocols,
            streams: streams::endpoint(id, &config),
            memory: MemoryConfig::default(),
            services,
            out,
            stats: MessageCounts::default(),
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
        let own = self.protocols | self.services.protocols(&self.config);
        match &self.memory.server {
            None => own,
            Some(server) => own | server.protocols(),
        }
    }

    /// The memory server, to read back its spaces and state.
    pub fn memory_server(&self) -> Option<&MemoryServer> {
        self.memory.server.as_ref()
    }

    /// The memory server, mutable (to change a space between transfers).
    pub fn memory_server_mut(&mut self) -> Option<&mut MemoryServer> {
        self.memory.server.as_mut()
    }

    /// Ends `operation` at once, and no event follows: its stream is terminated and the
    /// peer's lock released. A read hands over the bytes it has so far, in order from its
    /// address (the part of a whole read that arrived); any other operation an empty `Vec`.
    /// `None`: the operation has already ended (its event came or is on its way).
    #[cfg(feature = "memory-client")]
    pub fn cancel_memory(&mut self, now: Instant, operation: MemoryOperation) -> Option<Vec<u8>> {
        self.with_memory(now, |cx, _, client| client.cancel(cx, operation))
    }

    /// Bytes an operation has moved so far (`None` once it has ended).
    #[cfg(feature = "memory-client")]
    pub fn memory_progress(&self, operation: MemoryOperation) -> Option<u64> {
        self.memory.client().and_then(|c| c.progress(operation))
    }

    /// The stream endpoint, for its getters.
    #[cfg(feature = "streams")]
    pub fn streams(&self) -> &StreamEndpoint {
        &self.streams
    }

    /// The stream commands (`open`, `write`, `read`, `accept`, ...) and, through `Deref`, the
    /// endpoint's getters. Each command lets Memory Configuration act on what it caused, so
    /// that [`poll_event`](Self::poll_event) only pops.
    #[cfg(feature = "streams")]
    pub fn streams_mut(&mut self) -> Streams<'_> {
        Streams { node: self }
    }

    /// Counters.
    pub fn stats(&self) -> NodeStats {
        let counts = &self.stats;
        NodeStats {
            messages_in: counts.messages_in.into(),
            own_echoes: counts.own_echoes.into(),
            not_for_us: counts.not_for_us.into(),
            unknown_mti_rejected: counts.unknown_mti_rejected.into(),
            stray_error_reports: counts.stray_error_reports.into(),
            answers_dropped: self.out.answers_dropped.into(),
            snip_answered: self.services.snip.answered.into(),
            stray_snip_replies: self.services.snip.stray_replies.into(),
            datagrams: self.services.datagrams.stats,
        }
    }

    // ----- outputs -----

    /// The next message to send: the node's own (answers, datagrams, requests) first, then
    /// its event announcements, then the streams'.
    pub fn poll_transmit(&mut self) -> Option<Message> {
        let node = self.out.node;
        self.out
            .transmits
            .pop_front()
            .or_else(|| self.services.poll_transmit(&self.config, node))
            .or_else(|| self.streams.poll_transmit())
    }

    /// The next event. Every input and command has already done the work it caused; this
    /// only pops.
    pub fn poll_event(&mut self) -> Option<NodeEvent> {
        self.out.events.pop_front()
    }

    /// When to call `handle_timeout` next.
    pub fn poll_timeout(&self) -> Option<Instant> {
        let services = earliest(self.services.poll_timeout(), self.memory.poll_timeout());
        earliest(self.streams.poll_timeout(), services)
    }

    // ----- inputs -----

    /// Feeds one received message. The node answers the basics itself; anything else goes
    /// to the first service that takes it, and an error report to every service it may
    /// concern.
    pub fn handle_message(&mut self, now: Instant, msg: MessageRef<'_>) {
        bump(&mut self.stats.messages_in);
        if msg.source == self.out.node {
            bump(&mut self.stats.own_echoes);
            return;
        }
        if msg.destination.is_some_and(|d| d != self.out.node) || (msg.destination.is_none() && msg.mti.is_addressed())
        {
            bump(&mut self.stats.not_for_us);
            return;
        }
        match msg.mti {
            Mti::OPTIONAL_INTERACTION_REJECTED | Mti::TERMINATE_DUE_TO_ERROR => self.on_error_report(now, msg),
            _ if self.answer_basics(now, msg) => {}
            _ if self.offer(now, msg) => {}
            Mti::PROTOCOL_SUPPORT_REPLY => {
                let protocols = Protocols::from_payload(msg.payload);
                self.out.event(NodeEvent::ProtocolsReceived { peer: msg.source, protocols });
            }
            mti if mti.is_addressed() && !is_answer(mti) => {
                // MN §3.5.2: an addressed message of a protocol this node lacks.
                bump(&mut self.stats.unknown_mti_rejected);
                let oir = ErrorReport { code: ErrorCode::NOT_IMPLEMENTED_MTI, mti: Some(mti) };
                let node = self.out.node;
                self.out.reply(Message::addressed(
                    Mti::OPTIONAL_INTERACTION_REJECTED,
                    node,
                    msg.source,
                    oir.to_bytes(),
                ));
            }
            _ => {}
        }
        self.settle(now);
    }

    /// The message-network basics: Verify Node ID, Verified Node ID, Protocol Support
    /// Inquiry, and Initialization Complete (every service hears that the peer restarted).
    fn answer_basics(&mut self, now: Instant, msg: MessageRef<'_>) -> bool {
        let out = &mut self.out;
        match msg.mti {
            Mti::INITIALIZATION_COMPLETE | Mti::INITIALIZATION_COMPLETE_SIMPLE => {
                self.streams.handle_message(now, msg);
                lend!(self, now, |lent, (streams, memory, services)| {
                    services.handle_message(&mut lent, msg);
                    let datagrams = &mut services.datagrams;
                    memory.handle_message(&mut memory_lent(now, lent.out, lent.config, datagrams, streams), msg);
                });
            }
            Mti::VERIFIED_NODE_ID | Mti::VERIFIED_NODE_ID_SIMPLE => {
                // The payload names the node; on CAN the source may be a provisional name.
                let node = NodeId::from_slice(msg.payload).unwrap_or(msg.source);
                out.event(NodeEvent::Verified { node });
                // Memory Configuration may be asking whether a holder of its lock is here.
                let Node { config, out, streams, services, memory, .. } = self;
                let datagrams = &mut services.datagrams;
                memory.handle_message(&mut memory_lent(now, out, config, datagrams, streams), msg);
            }
            // MN §3.3.2: a global Verify is answered when it names no node, or this one.
            Mti::VERIFY_NODE_ID_GLOBAL
                if msg.payload.len() < 6 || NodeId::from_slice(msg.payload) == Some(out.node) =>
            {
                out.reply(Message::verified_node_id(out.node));
            }
            Mti::VERIFY_NODE_ID_ADDRESSED => out.reply(Message::verified_node_id(out.node)),
            Mti::PROTOCOL_SUPPORT_INQUIRY => {
                let flags = self.protocols().to_bytes().to_vec();
                let node = self.out.node;
                self.out.reply(Message::addressed(Mti::PROTOCOL_SUPPORT_REPLY, node, msg.source, flags));
            }
            _ => return false,
        }
        true
    }

    /// Offers `msg` to each service in turn; whether one took it.
    fn offer(&mut self, now: Instant, msg: MessageRef<'_>) -> bool {
        if msg.mti.is_stream() && streams::enabled(&self.config) {
            self.streams.handle_message(now, msg);
            return true;
        }
        lend!(self, now, |lent, (streams, memory, services)| {
            // Memory Configuration first: it takes the datagrams with its content ID.
            let datagrams = &mut services.datagrams;
            memory.handle_message(&mut memory_lent(now, lent.out, lent.config, datagrams, streams), msg)
                || services.handle_message(&mut lent, msg)
        })
    }

    /// An OIR or TDE goes to the services whose MTI it names; one naming nothing goes to
    /// every service with something open with that peer (node-protocols.md C-13).
    fn on_error_report(&mut self, now: Instant, msg: MessageRef<'_>) {
        let report = ErrorReport::parse(msg.payload);
        let peer = msg.source;
        let mut handled = false;
        if report.mti.is_none_or(Mti::is_stream) && streams::enabled(&self.config) {
            let before = self.streams.stats().stray_error_reports;
            self.streams.handle_message(now, msg);
            handled = self.streams.stats().stray_error_reports == before;
        }
        lend!(self, now, |lent, (streams, memory, services)| {
            handled |= services.handle_error_report(&mut lent, peer, report);
            let datagrams = &mut services.datagrams;
            let mut memory_lent = memory_lent(now, lent.out, lent.config, datagrams, streams);
            handled |= memory.handle_error_report(&mut memory_lent, peer, report);
        });
        if !handled {
            bump(&mut self.stats.stray_error_reports);
        }
    }

    /// Runs every timer due at `now`. Early or repeated calls are harmless.
    pub fn handle_timeout(&mut self, now: Instant) {
        self.streams.handle_timeout(now);
        lend!(self, now, |lent, (streams, memory, services)| {
            services.handle_timeout(&mut lent);
            let datagrams = &mut services.datagrams;
            memory.handle_timeout(&mut memory_lent(now, lent.out, lent.config, datagrams, streams));
        });
        self.settle(now);
    }

    /// The transport learnt a change of peer ([`PeerChange`]); a transport handed this node
    /// as its [`Receiver`] (the CAN link) calls it as it learns it.
    ///
    /// - [`PeerChange::Lost`]: what is open with the peer ends (streams, datagrams, SNIP
    ///   requests, Memory Configuration operations), and nothing more is sent to it.
    /// - [`PeerChange::Renamed`] (on CAN: its Node ID was learnt, or its mapping forgotten and
    ///   it is named by its alias): everything open with the old name goes on with the new
    ///   one, queued messages included.
    pub fn peer_changed(&mut self, change: PeerChange) {
        if let PeerChange::Renamed { from, to } = change {
            for message in self.out.transmits.iter_mut() {
                message.rename_peer(from, to);
            }
        }
        self.streams.peer_changed(change);
        if let Some(change) = ServiceChange::of(change) {
            self.tell_services(change);
        }
    }

    /// The transport saw another node's stream data on a shared medium (a CAN bus): the
    /// stream waits of this node run from `now` ([`StreamEndpoint::medium_busy`]).
    pub fn medium_busy(&mut self, now: Instant) {
        self.streams.medium_busy(now);
    }

    /// The transport lost its link (e.g. this node's CAN alias): everything open ends.
    pub fn link_lost(&mut self) {
        // The transport announces the node again once it is back; its events follow.
        self.services.announce(&self.config);
        self.streams.link_lost();
        self.tell_services(ServiceChange::Lost(None));
    }

    /// Tells every service of `change` (the endpoint has been told). A lost peer's streams
    /// end with it: the application hears of its own, Memory Configuration has let go of its.
    fn tell_services(&mut self, change: ServiceChange) {
        self.services.peer_changed(&mut self.out, change);
        self.memory.peer_changed(&mut self.out, change);
        while let Some(event) = self.streams.poll_event() {
            if !self.memory.forget_ended(&event) {
                self.out.event(NodeEvent::Stream(event));
            }
        }
    }

    // ----- commands -----

    /// Sends a datagram of at most 72 bytes to `to`. Datagrams to one node go one at a time
    /// (DG §6.1); later ones wait their turn. `DatagramDelivered` or `DatagramFailed` follows.
    #[cfg(feature = "app-datagrams")]
    pub fn send_datagram(&mut self, now: Instant, to: NodeId, payload: &[u8]) -> Result<DatagramId, DatagramError> {
        self.services.datagrams.send(
            &self.config.datagrams,
            now,
            &mut self.out,
            to,
            payload,
            DatagramOwner::Application,
        )
    }

    /// Answers the datagram `from` sent (raised by `DatagramReceived`).
    #[cfg(feature = "app-datagrams")]
    pub fn answer_datagram(&mut self, from: NodeId, answer: DatagramAnswer) -> Result<(), DatagramError> {
        self.services.datagrams.answer(&mut self.out, from, answer)
    }

    /// Asks `peer` for its Simple Node Information. `SnipReceived` or `SnipFailed` follows.
    #[cfg(feature = "snip-client")]
    pub fn request_snip(&mut self, now: Instant, peer: NodeId) -> Result<(), SnipRequestError> {
        self.services.snip.request(&self.config, now, &mut self.out, peer)
    }

    /// Sends a global Verify Node ID: every node on the network answers with Verified Node
    /// ID (how a tool finds who is there).
    pub fn verify_all(&mut self) {
        self.out.transmit(Message::global(Mti::VERIFY_NODE_ID_GLOBAL, self.out.node, Vec::new()));
    }

    /// Identifies every declared event and clock again, as after Initialization Complete (a
    /// generator sends its state too). The node does so by itself after its own
    /// Initialization Complete and after [`link_lost`](Node::link_lost); call this after
    /// announcing the node by other means (with
    /// [`NodeConfig::send_initialization_complete`](crate::NodeConfig::send_initialization_complete) off).
    pub fn announce_events(&mut self) {
        self.services.announce(&self.config);
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

    /// Routes what the services' work left for each other, in one place: the outcomes of the
    /// memory client's datagrams to it, the stream events to Memory Configuration or (with
    /// the application's accept policy for requests nobody claimed) to the application.
    /// Then a Reset/Reboot command answered reinitializes the node. Runs at the end of every
    /// input and stream command, with its time.
    fn settle(&mut self, now: Instant) {
        // The application's policy, for the requests Memory Configuration did not claim (the
        // endpoint raises requests only when it asks: with a server, or with `Ask`).
        let unclaimed_streams = streams::accept_policy(&self.config);
        let Node { config, out, streams, services, memory, .. } = self;
        let mut lent = memory_lent(now, out, config, &mut services.datagrams, streams);
        loop {
            let mut moved = false;
            while cfg!(feature = "memory-client")
                && let Some((id, result)) = lent.datagrams.poll_client_outcome()
            {
                moved = true;
                memory.on_datagram_outcome(&mut lent, id, result);
            }
            while let Some(event) = lent.streams.poll_event() {
                moved = true;
                match event {
                    _ if memory.on_stream_event(&mut lent, &event) => {}
                    Event::IncomingRequest { handle, .. } if unclaimed_streams != AcceptPolicy::Ask => {
                        let _ = match unclaimed_streams {
                            AcceptPolicy::RejectAll(code) => lent.streams.reject(now, handle, code),
                            _ => lent.streams.accept(now, handle, None),
                        };
                    }
                    event => lent.lent.out.event(NodeEvent::Stream(event)),
                }
            }
            memory.poll_streams(&mut lent);
            if !moved {
                break;
            }
        }
        self.update_user_info();
        self.sync_memory();
        if core::mem::take(&mut self.memory.reboot) {
            self.reinitialize();
        }
        if let Some(peer) = self.memory.departed.take() {
            self.peer_changed(PeerChange::Lost(peer));
        }
    }
}

/// The stream commands of a [`Node`], borrowed from [`Node::streams_mut`]; the endpoint's
/// getters through `Deref`. Each command takes `now`, and the node settles what it caused
/// (Memory Configuration acts on its streams' events) before it returns, so that
/// [`Node::poll_event`] only pops.
#[cfg(feature = "streams")]
#[derive(Debug)]
pub struct Streams<'a> {
    node: &'a mut Node,
}

#[cfg(feature = "streams")]
impl core::ops::Deref for Streams<'_> {
    type Target = StreamEndpoint;

    fn deref(&self) -> &StreamEndpoint {
        &self.node.streams
    }
}

#[cfg(feature = "streams")]
impl Streams<'_> {
    /// Runs one command of the endpoint, then settles the node.
    fn command<T>(&mut self, now: Instant, command: impl FnOnce(&mut StreamEndpoint) -> T) -> T {
        let result = command(&mut self.node.streams);
        self.node.settle(now);
        result
    }

    /// [`StreamEndpoint::open`]: sends a Stream Initiate Request.
    pub fn open(&mut self, now: Instant, options: OpenOptions) -> Result<StreamHandle, StreamError> {
        self.command(now, |s| s.open(now, options))
    }

    /// [`StreamEndpoint::write`]: queues what the credit allows; returns how much it took.
    pub fn write(&mut self, now: Instant, handle: StreamHandle, data: &[u8]) -> Result<usize, StreamError> {
        self.command(now, |s| s.write(now, handle, data))
    }

    /// [`StreamEndpoint::flush`]: sends a partly filled message now.
    pub fn flush(&mut self, now: Instant, handle: StreamHandle) -> Result<(), StreamError> {
        self.command(now, |s| s.flush(now, handle))
    }

    /// [`StreamEndpoint::finish`]: sends Stream Data Complete.
    pub fn finish(&mut self, now: Instant, handle: StreamHandle) -> Result<(), StreamError> {
        self.command(now, |s| s.finish(now, handle))
    }

    /// [`StreamEndpoint::accept`]: accepts a pending request.
    pub fn accept(&mut self, now: Instant, handle: StreamHandle, window: Option<u16>) -> Result<(), StreamError> {
        self.command(now, |s| s.accept(now, handle, window))
    }

    /// [`StreamEndpoint::accept_with`]: accepts a pending request with these options.
    pub fn accept_with(
        &mut self,
        now: Instant,
        handle: StreamHandle,
        options: AcceptOptions,
    ) -> Result<(), StreamError> {
        self.command(now, |s| s.accept_with(now, handle, options))
    }

    /// [`StreamEndpoint::reject`]: refuses a pending request with `code`.
    pub fn reject(&mut self, now: Instant, handle: StreamHandle, code: ReplyCode) -> Result<(), StreamError> {
        self.command(now, |s| s.reject(now, handle, code))
    }

    /// [`StreamEndpoint::read`]: takes received bytes; returns how many.
    pub fn read(&mut self, now: Instant, handle: StreamHandle, buf: &mut [u8]) -> Result<usize, StreamError> {
        self.command(now, |s| s.read(now, handle, buf))
    }

    /// [`StreamEndpoint::abort`]: ends the stream at once with Terminate Due To Error.
    pub fn abort(&mut self, now: Instant, handle: StreamHandle, code: ErrorCode) -> Result<(), StreamError> {
        self.command(now, |s| s.abort(now, handle, code))
    }
}

/// Memory Configuration: the server, the client, and what the node does for them.
impl Node {
    /// Serves `server`'s spaces from now on: datagrams with content ID 0x20 that are
    /// commands go to it, and the PIP announces Memory Configuration (and Firmware Upgrade
    /// with space 0xEF). Its ACDI spaces mirror this node's SNIP strings.
    pub fn set_memory_server(&mut self, mut server: MemoryServer) {
        server.mirror_snip(&self.config.snip);
        self.memory.server = Some(server);
        self.sync_memory();
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
        self.with_memory(now, |cx, _, client| client.read(cx, peer, space, address, len, path))
    }

    /// Reads `space` of `peer` from address 0 up to its first NUL, as a CDI (space 0xFF)
    /// ends, taking at most `limit` bytes: `ReadDone` follows with the bytes before the NUL,
    /// or `Failed` with [`MemoryError::SpaceTooLarge`](crate::MemoryError::SpaceTooLarge)
    /// once the space's reported size or its bytes pass `limit`. A node that does not answer
    /// Get Address Space Information (rejected, or "not present") is read until its answers
    /// end the space: a stream's end, an empty read, out of bounds, or the NUL.
    #[cfg(feature = "memory-client")]
    pub fn read_memory_to_nul(
        &mut self,
        now: Instant,
        peer: NodeId,
        space: u8,
        limit: u32,
        path: TransferPath,
    ) -> Result<MemoryOperation, MemoryRequestError> {
        self.with_memory(now, |cx, _, client| client.read_to_nul(cx, peer, space, limit, path))
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
        let image = image.into();
        self.with_memory(now, |cx, _, client| client.upgrade(cx, peer, image, path))
    }

    /// Tells `peer` that a configuration tool has finished writing (Update Complete, MC
    /// §4.23), so that it applies what changed; `WriteDone` (of 0 bytes) or `Failed` follows.
    #[cfg(feature = "memory-client")]
    pub fn update_complete(&mut self, now: Instant, peer: NodeId) -> Result<MemoryOperation, MemoryRequestError> {
        self.send_command(now, peer, NodeCommand::UpdateComplete)
    }

    /// Sends `peer` a [`NodeCommand`] (Update Complete, Reboot, Factory Reset); `WriteDone`
    /// (of 0 bytes) follows its Datagram OK or the node's restart, `Failed` a rejection.
    #[cfg(feature = "memory-client")]
    pub fn send_command(
        &mut self,
        now: Instant,
        peer: NodeId,
        command: NodeCommand,
    ) -> Result<MemoryOperation, MemoryRequestError> {
        self.with_memory(now, |cx, _, client| client.command(cx, peer, command))
    }

    /// Runs `f` on the memory server and client with the node's parts lent to them.
    #[cfg(feature = "memory-client")]
    fn with_memory<T>(
        &mut self,
        now: Instant,
        f: impl FnOnce(&mut Cx<'_>, Option<&mut MemoryServer>, &mut crate::memconfig::MemoryClient) -> T,
    ) -> T {
        let Node { config, out, services, streams, memory, .. } = self;
        memory.run(&mut memory_lent(now, out, config, &mut services.datagrams, streams), f)
    }

    /// Reset/Reboot (MC §4.24) of a library node: it starts again as after a power-up, as far
    /// as the protocols go. Every stream, datagram, SNIP request and Memory Configuration
    /// operation ends (their owners hear why), the Firmware Upgrade state and the lock end,
    /// and Initialization Complete goes out (after the reset command's Datagram OK). The
    /// spaces keep their contents: they are the application's memory, and the application,
    /// told by `MemoryEvent::ResetRequested`, may do more (a firmware resets its processor).
    fn reinitialize(&mut self) {
        self.link_lost();
        if let Some(server) = &mut self.memory.server {
            server.reinitialize();
        }
        self.out.announce_start();
    }

    /// The spaces the services keep follow them, and they what a tool wrote there.
    fn sync_memory(&mut self) {
        if let Some(server) = &mut self.memory.server {
            self.services.sync_memory(&mut self.out, server);
        }
    }

    /// A write to space 0xFB changed the user strings: SNIP follows them.
    fn update_user_info(&mut self) {
        let Some(server) = &mut self.memory.server else { return };
        if !core::mem::take(&mut server.user_info_changed) {
            return;
        }
        let (name, description) = acdi_user_strings(server.acdi_user());
        self.config.snip.user_name = name;
        self.config.snip.user_description = description;
        self.services.snip.set_info(&self.config.snip);
        self.out.event(NodeEvent::Memory(MemoryEvent::UserInfoChanged));
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

    fn medium_busy(&mut self, now: Instant) {
        Node::medium_busy(self, now);
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

#[cfg(test)]
mod tests {
    use super::bump;

    #[test]
    fn a_counter_stops_at_its_maximum() {
        let mut counter = u32::MAX - 1;
        bump(&mut counter);
        assert_eq!(counter, u32::MAX);
        bump(&mut counter);
        assert_eq!(counter, u32::MAX, "it does not wrap to 0");
    }
}
