//! [`Network`]: nodes, CAN buses and OpenLCB-TCP pipes on one virtual clock, with scripted
//! transfers, seeded faults and a driver that never hangs.

use std::collections::{HashMap, VecDeque};

use bytes::Bytes;
use openlcb_can::gridconnect::{self, GridConnectDecoder};
use openlcb_can::{CanConfig, CanFrame, CanLink, LinkEvent, NodeAlias};
use openlcb_gateway::{Gateway, GatewayConfig};
use openlcb_node::{MemoryServer, Node, NodeConfig, NodeEvent, Streams};
use openlcb_stream::{Duration, Event, Instant, NodeId, OpenOptions, Role, StreamHandle, Termination, TimeoutKind};
use openlcb_tcp::TcpLink;

use crate::bus::{CanBus, Delivery};
use crate::rng::{Rng, pattern_byte};

/// Index of a node in its [`Network`].
pub type NodeIndex = usize;

/// How a node is built.
#[derive(Debug, Clone)]
pub struct NodeOptions {
    /// The node's configuration, its stream endpoint's included.
    pub node: NodeConfig,
    /// The CAN link's configuration (CAN nodes only).
    pub can: CanConfig,
    /// Time from a frame or byte arriving to the node acting on it.
    pub latency: Duration,
    /// Pass every received CAN frame through GridConnect text, encoder and decoder, as a
    /// node behind a GridConnect hub would.
    pub gridconnect: bool,
    /// Makes the node's Memory Configuration server (again after a reset).
    pub memory_server: Option<fn() -> MemoryServer>,
}

impl NodeOptions {
    fn build(&self, id: NodeId) -> Node {
        let node = Node::new(id, self.node.clone());
        match self.memory_server {
            Some(make) => node.with_memory_server(make()),
            None => node,
        }
    }
}

/// Events other than stream events a node keeps for [`Network::take_events`].
const KEPT_EVENTS: usize = 1024;

impl Default for NodeOptions {
    fn default() -> Self {
        NodeOptions {
            node: NodeConfig::default(),
            can: CanConfig::default(),
            latency: Duration::from_millis(1),
            gridconnect: false,
            memory_server: None,
        }
    }
}

/// Random faults applied to every CAN frame delivery, from the network's seed.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct FrameFaults {
    /// A receiver loses the frame (a gateway under overload).
    pub drop: f64,
    /// A receiver gets the frame twice.
    pub duplicate: f64,
    /// A bit error destroys the frame on the wire; controllers drop it and the sender's
    /// controller retransmits it.
    pub bit_error: f64,
}

/// A fault at a chosen moment.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ScheduledFault {
    /// The node restarts: new node and link, a new alias, its streams forgotten.
    Reset(NodeIndex),
    /// The node stops receiving and sending, for good. The transfers it has not opened yet
    /// end as `Terminated(LinkLost)`; its open streams are left to the peers' timeouts.
    Silence(NodeIndex),
    /// A frame from another node appears with this node's alias as its source: the node
    /// must give the alias up and log in again.
    AliasCollision(NodeIndex),
}

/// One transfer to run.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct TransferSpec {
    /// Sending node.
    pub from: NodeIndex,
    /// Receiving node.
    pub to: NodeIndex,
    /// Payload bytes.
    pub bytes: u64,
    /// Proposed window.
    pub window: u16,
    /// When the sender opens the stream.
    pub start: Instant,
}

impl TransferSpec {
    /// `bytes` from `from` to `to` with a proposed `window`, starting at once.
    pub fn new(from: NodeIndex, to: NodeIndex, bytes: u64, window: u16) -> Self {
        TransferSpec { from, to, bytes, window, start: Instant::ZERO }
    }

    /// Start at `at` instead.
    pub fn at(mut self, at: Instant) -> Self {
        self.start = at;
        self
    }
}

/// How a transfer ended.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Outcome {
    /// Still running.
    Pending,
    /// Every byte arrived, in order, and the counts matched.
    Completed,
    /// The destination refused the stream.
    Rejected,
    /// The stream ended early; `Termination` says how.
    Terminated(Termination),
    /// A wait ran out.
    TimedOut(TimeoutKind),
    /// The source said Complete but the count did not match what arrived: a loss, reported.
    CountMismatch,
    /// The destination accepted a Complete with a matching count, yet the bytes differ from
    /// what was sent. The harness flags it; it must never happen without frame faults.
    SilentCorruption,
}

/// What became of one transfer.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct TransferReport {
    /// What was asked for.
    pub spec: TransferSpec,
    /// The outcome.
    pub outcome: Outcome,
    /// Bytes the source wrote.
    pub sent: u64,
    /// Bytes the destination read.
    pub delivered: u64,
    /// Leading delivered bytes that match what was sent.
    pub verified_prefix: u64,
    /// When the source's request went out.
    pub opened_at: Option<Instant>,
    /// When the outcome was decided.
    pub ended_at: Option<Instant>,
}

/// CAN frames delivered, by what they carried.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct FrameCounts {
    /// Stream Data Send (format 7).
    pub stream_data: u64,
    /// Stream Data Proceed.
    pub proceed: u64,
    /// Stream Initiate Request and Reply.
    pub initiate: u64,
    /// Stream Data Complete.
    pub complete: u64,
    /// TDE and OIR.
    pub error_report: u64,
    /// Other OpenLCB messages (Initialization Complete, Verified Node ID, ...).
    pub other_message: u64,
    /// CAN control frames (CID, RID, AMD, AME, AMR).
    pub control: u64,
}

impl FrameCounts {
    fn count(&mut self, frame: &CanFrame) {
        use openlcb_can::FrameKind;
        use openlcb_stream::Mti;
        let counter = match frame.header().map(|h| h.kind) {
            Ok(FrameKind::StreamData { .. }) => &mut self.stream_data,
            Ok(FrameKind::Message { can_mti }) => match Mti(can_mti) {
                Mti::STREAM_DATA_PROCEED => &mut self.proceed,
                Mti::STREAM_INITIATE_REQUEST | Mti::STREAM_INITIATE_REPLY => &mut self.initiate,
                Mti::STREAM_DATA_COMPLETE => &mut self.complete,
                Mti::TERMINATE_DUE_TO_ERROR | Mti::OPTIONAL_INTERACTION_REJECTED => &mut self.error_report,
                _ => &mut self.other_message,
            },
            Ok(FrameKind::Datagram { .. }) => &mut self.other_message,
            _ => &mut self.control,
        };
        *counter += 1;
    }

    /// Each kind with its name, in a fixed order (for reports).
    pub fn by_kind(&self) -> [(&'static str, u64); 7] {
        [
            ("stream_data", self.stream_data),
            ("proceed", self.proceed),
            ("initiate", self.initiate),
            ("complete", self.complete),
            ("error_report", self.error_report),
            ("other_message", self.other_message),
            ("control", self.control),
        ]
    }

    /// All of them.
    pub fn total(&self) -> u64 {
        self.by_kind().iter().map(|(_, n)| n).sum()
    }

    /// The frames counted since `earlier` was taken.
    pub fn since(&self, earlier: &FrameCounts) -> FrameCounts {
        FrameCounts {
            stream_data: self.stream_data - earlier.stream_data,
            proceed: self.proceed - earlier.proceed,
            initiate: self.initiate - earlier.initiate,
            complete: self.complete - earlier.complete,
            error_report: self.error_report - earlier.error_report,
            other_message: self.other_message - earlier.other_message,
            control: self.control - earlier.control,
        }
    }
}

/// Counters of a whole run.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct NetStats {
    /// Driver steps taken.
    pub steps: u64,
    /// CAN frames delivered (counted once per frame, not per receiver), by kind.
    pub frames: FrameCounts,
    /// Bus busy time, summed over buses.
    pub bus_busy: Duration,
    /// Stuff bits sent.
    pub stuff_bits: u64,
    /// Bits sent (stuff bits included).
    pub bits: u64,
    /// Frames destroyed by bit errors.
    pub corrupted_frames: u64,
    /// Frame deliveries dropped by the drop fault.
    pub dropped_frames: u64,
    /// Frame deliveries doubled by the duplicate fault.
    pub duplicated_frames: u64,
    /// OpenLCB-TCP bytes carried by pipes.
    pub tcp_bytes: u64,
    /// Payload bytes read by destinations.
    pub payload_delivered: u64,
}

/// The run did not settle within its step bound: something is livelocked.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct NeverIdle {
    /// Steps taken.
    pub steps: u64,
    /// Virtual time reached.
    pub now: Instant,
}

impl core::fmt::Display for NeverIdle {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        write!(f, "the network never went idle: {} steps, virtual time {:?}", self.steps, self.now)
    }
}

impl std::error::Error for NeverIdle {}

#[derive(Debug)]
enum Inbound {
    Frame(CanFrame),
    Bytes(Bytes),
}

#[derive(Debug)]
enum Port {
    Can { bus: usize, port: usize, link: Box<CanLink> },
    Tcp { pipe: usize, side: usize, link: Box<TcpLink> },
}

#[derive(Debug)]
struct SimNode {
    id: NodeId,
    options: NodeOptions,
    stack: Node,
    port: Port,
    inbox: VecDeque<(Instant, Inbound)>,
    gridconnect: GridConnectDecoder,
    silent: bool,
    /// Transfers this node sends, by stream handle.
    sending: Vec<(StreamHandle, usize)>,
    /// Transfers this node receives, by stream handle.
    receiving: HashMap<StreamHandle, usize>,
    /// Run a turn at this time (or earlier).
    wake: Option<Instant>,
    /// Events other than stream events, the newest [`KEPT_EVENTS`].
    events: VecDeque<NodeEvent>,
}

/// What sits at the end of a pipe.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Station {
    Node(NodeIndex),
    Gateway(usize),
}

/// A gateway between a CAN bus and one OpenLCB-TCP pipe.
#[derive(Debug)]
struct SimGateway {
    gateway: Box<Gateway>,
    bus: usize,
    port: usize,
    /// Its pipe and side, once a full-format node is attached behind it.
    pipe: Option<(usize, usize)>,
    tcp: Box<TcpLink>,
    inbox: VecDeque<(Instant, Inbound)>,
    latency: Duration,
    wake: Option<Instant>,
}

#[derive(Debug)]
struct Pipe {
    ends: [Station; 2],
    latency: Duration,
    bytes_per_sec: u64,
    busy_until: [Instant; 2],
}

#[derive(Debug)]
struct Transfer {
    report: TransferReport,
    /// Key of its byte pattern.
    key: u64,
    /// The bytes to send, when given; otherwise `pattern_byte(key, i)`.
    data: Option<std::sync::Arc<[u8]>>,
    /// The SID to use, when given.
    chosen_source_stream: Option<openlcb_stream::StreamId>,
    source_stream: Option<u8>,
}

impl Transfer {
    fn byte(&self, index: u64) -> u8 {
        match &self.data {
            Some(data) => data.get(index as usize).copied().unwrap_or(0),
            None => pattern_byte(self.key, index),
        }
    }
}

/// Many nodes on virtual time. Build it, add nodes, buses, pipes and transfers, then [`run`](Network::run).
#[derive(Debug)]
pub struct Network {
    now: Instant,
    nodes: Vec<SimNode>,
    gateways: Vec<SimGateway>,
    buses: Vec<CanBus>,
    pipes: Vec<Pipe>,
    transfers: Vec<Transfer>,
    faults: FrameFaults,
    scheduled: Vec<(Instant, ScheduledFault)>,
    rng: Rng,
    stats: NetStats,
    scratch: Vec<u8>,
    trace: Option<Vec<(Instant, CanFrame)>>,
}

impl Network {
    /// An empty network whose random faults come from `seed`.
    pub fn new(seed: u64) -> Self {
        Network {
            now: Instant::ZERO,
            nodes: Vec::new(),
            gateways: Vec::new(),
            buses: Vec::new(),
            pipes: Vec::new(),
            transfers: Vec::new(),
            faults: FrameFaults::default(),
            scheduled: Vec::new(),
            rng: Rng::new(seed),
            stats: NetStats::default(),
            scratch: vec![0; 64 * 1024],
            trace: None,
        }
    }

    /// Adds a CAN bus at `bitrate` whose controllers queue at most `queue_limit` frames.
    pub fn add_bus(&mut self, bitrate: u32, queue_limit: usize) -> usize {
        self.buses.push(CanBus::new(bitrate, queue_limit));
        self.buses.len() - 1
    }

    /// Adds a node on CAN bus `bus`; it starts its alias login now.
    pub fn add_can_node(&mut self, id: NodeId, bus: usize, options: NodeOptions) -> NodeIndex {
        let port = self.buses.get_mut(bus).map_or(0, CanBus::attach);
        let link = Box::new(CanLink::new(self.now, id, options.can.clone()));
        self.push_node(id, options, Port::Can { bus, port, link })
    }

    /// Adds two nodes joined by an OpenLCB-TCP pipe with `latency` each way and
    /// `bytes_per_sec` of bandwidth each way.
    pub fn add_tcp_pair(
        &mut self,
        ids: [NodeId; 2],
        options: [NodeOptions; 2],
        latency: Duration,
        bytes_per_sec: u64,
    ) -> [NodeIndex; 2] {
        let pipe = self.pipes.len();
        let [oa, ob] = options;
        let a = self.push_node(ids[0], oa, Port::Tcp { pipe, side: 0, link: Box::new(TcpLink::new(ids[0])) });
        let b = self.push_node(ids[1], ob, Port::Tcp { pipe, side: 1, link: Box::new(TcpLink::new(ids[1])) });
        self.pipes.push(Pipe {
            ends: [Station::Node(a), Station::Node(b)],
            latency,
            bytes_per_sec: bytes_per_sec.max(1),
            busy_until: [self.now; 2],
        });
        [a, b]
    }

    /// Adds a gateway on CAN bus `bus`, with Node ID `id` for its OpenLCB-TCP side, acting
    /// `latency` after each frame or byte arrives; returns its number.
    pub fn add_gateway(&mut self, id: NodeId, bus: usize, config: GatewayConfig, latency: Duration) -> usize {
        let port = self.buses.get_mut(bus).map_or(0, CanBus::attach);
        self.gateways.push(SimGateway {
            gateway: Box::new(Gateway::new(self.now, config)),
            bus,
            port,
            pipe: None,
            tcp: Box::new(TcpLink::new(id)),
            inbox: VecDeque::new(),
            latency,
            wake: Some(self.now),
        });
        self.gateways.len() - 1
    }

    /// Adds a full-format node behind gateway `gateway`, joined to it by an OpenLCB-TCP pipe
    /// with `latency` and `bytes_per_sec` each way.
    pub fn add_node_behind(
        &mut self,
        gateway: usize,
        id: NodeId,
        options: NodeOptions,
        latency: Duration,
        bytes_per_sec: u64,
    ) -> NodeIndex {
        let pipe = self.pipes.len();
        let node = self.push_node(id, options, Port::Tcp { pipe, side: 1, link: Box::new(TcpLink::new(id)) });
        self.pipes.push(Pipe {
            ends: [Station::Gateway(gateway), Station::Node(node)],
            latency,
            bytes_per_sec: bytes_per_sec.max(1),
            busy_until: [self.now; 2],
        });
        if let Some(g) = self.gateways.get_mut(gateway) {
            g.pipe = Some((pipe, 0));
        }
        node
    }

    /// A gateway's memory in use and its bound, in bytes.
    pub fn gateway_memory(&self, gateway: usize) -> Option<(usize, usize)> {
        self.gateways.get(gateway).map(|g| (g.gateway.memory_in_use(), g.gateway.memory_bound()))
    }

    fn push_node(&mut self, id: NodeId, options: NodeOptions, port: Port) -> NodeIndex {
        self.nodes.push(SimNode {
            id,
            stack: options.build(id),
            options,
            port,
            inbox: VecDeque::new(),
            gridconnect: GridConnectDecoder::default(),
            silent: false,
            sending: Vec::new(),
            receiving: HashMap::new(),
            wake: Some(self.now),
            events: VecDeque::new(),
        });
        self.nodes.len() - 1
    }

    /// Starts recording every frame delivered on any bus, with the time it ended.
    pub fn record_frames(&mut self) {
        self.trace = Some(Vec::new());
    }

    /// The frames recorded since [`record_frames`](Self::record_frames).
    pub fn recorded_frames(&self) -> &[(Instant, CanFrame)] {
        self.trace.as_deref().unwrap_or_default()
    }

    /// Random faults for every frame delivery from now on.
    pub fn set_frame_faults(&mut self, faults: FrameFaults) {
        self.faults = faults;
    }

    /// A fault at time `at`.
    pub fn schedule(&mut self, at: Instant, fault: ScheduledFault) {
        self.scheduled.push((at, fault));
        self.scheduled.sort_by_key(|(t, _)| *t);
    }

    /// A transfer of a generated pattern; returns its number.
    pub fn add_transfer(&mut self, spec: TransferSpec) -> usize {
        self.push_transfer(spec, None, None)
    }

    /// A transfer of exactly `data` (its length overrides `spec.bytes`), optionally on a
    /// chosen SID; returns its number.
    pub fn add_transfer_of(
        &mut self,
        mut spec: TransferSpec,
        data: &[u8],
        sid: Option<openlcb_stream::StreamId>,
    ) -> usize {
        spec.bytes = data.len() as u64;
        self.push_transfer(spec, Some(data.into()), sid)
    }

    fn push_transfer(
        &mut self,
        spec: TransferSpec,
        data: Option<std::sync::Arc<[u8]>>,
        sid: Option<openlcb_stream::StreamId>,
    ) -> usize {
        let key = self.rng.next_u64();
        self.transfers.push(Transfer {
            report: TransferReport {
                spec,
                outcome: Outcome::Pending,
                sent: 0,
                delivered: 0,
                verified_prefix: 0,
                opened_at: None,
                ended_at: None,
            },
            key,
            data,
            chosen_source_stream: sid,
            source_stream: None,
        });
        if let Some(node) = self.nodes.get_mut(spec.from) {
            node.wake = Some(node.wake.map_or(spec.start, |w| w.min(spec.start)));
        }
        self.abandon_unopened(spec.from);
        self.transfers.len() - 1
    }

    /// The virtual time.
    pub fn now(&self) -> Instant {
        self.now
    }

    /// Byte `index` of transfer `transfer`'s payload (0 past its end or for no such transfer).
    pub fn transfer_byte(&self, transfer: usize, index: u64) -> u8 {
        self.transfers.get(transfer).map_or(0, |t| t.byte(index))
    }

    /// Reports of every transfer, in the order they were added.
    pub fn transfers(&self) -> Vec<TransferReport> {
        self.transfers.iter().map(|t| t.report).collect()
    }

    /// Counters.
    pub fn stats(&self) -> NetStats {
        let mut stats = self.stats;
        for bus in &self.buses {
            let b = bus.stats();
            stats.bus_busy = stats.bus_busy + Duration::from_micros(b.busy_ns / 1000);
            stats.bits += b.bits;
            stats.stuff_bits += b.stuff_bits;
            stats.corrupted_frames += b.corrupted;
        }
        stats
    }

    /// A node's stream commands (and, through them, its endpoint's getters), to script it
    /// directly.
    pub fn endpoint(&mut self, node: NodeIndex) -> Option<Streams<'_>> {
        self.nodes.get_mut(node).map(|n| n.stack.streams_mut())
    }

    /// A node, to script it directly (datagrams, SNIP).
    pub fn node(&mut self, node: NodeIndex) -> Option<&mut Node> {
        // A command given now may have queued messages: the node takes a turn at once.
        let now = self.now;
        self.nodes.get_mut(node).map(|n| {
            n.wake = Some(n.wake.map_or(now, |w| w.min(now)));
            &mut n.stack
        })
    }

    /// The events other than stream events `node` raised since the last call (datagrams,
    /// SNIP, Memory Configuration), oldest first.
    pub fn take_events(&mut self, node: NodeIndex) -> Vec<NodeEvent> {
        self.nodes.get_mut(node).map(|n| n.events.drain(..).collect()).unwrap_or_default()
    }

    /// A CAN node's current alias.
    pub fn alias(&self, node: NodeIndex) -> Option<NodeAlias> {
        match &self.nodes.get(node)?.port {
            Port::Can { link, .. } => link.alias(),
            Port::Tcp { .. } => None,
        }
    }

    /// The alias by which CAN knows `node`: its own if it is a CAN node, a gateway's proxy
    /// alias if it sits behind one.
    pub fn can_alias(&self, node: NodeIndex) -> Option<NodeAlias> {
        let id = self.nodes.get(node)?.id;
        self.alias(node).or_else(|| self.gateways.iter().find_map(|g| g.gateway.proxy_alias(id)))
    }

    /// The first bus's bitrate (for reports).
    pub fn bitrate(&self) -> Option<u32> {
        self.buses.first().map(CanBus::bitrate)
    }

    /// Runs until every transfer has an outcome and nothing is in flight, or `until` is
    /// reached; fails if that takes more than `max_steps` steps.
    pub fn run(&mut self, until: Instant, max_steps: u64) -> Result<(), NeverIdle> {
        self.drive(until, max_steps, true)
    }

    /// Runs until `until` even when everything has settled (timers, logins, keep-alives go
    /// on); fails if that takes more than `max_steps` steps.
    pub fn run_until(&mut self, until: Instant, max_steps: u64) -> Result<(), NeverIdle> {
        self.drive(until, max_steps, false)?;
        self.now = self.now.max(until);
        Ok(())
    }

    fn drive(&mut self, until: Instant, max_steps: u64, stop_when_settled: bool) -> Result<(), NeverIdle> {
        loop {
            self.stats.steps += 1;
            if self.stats.steps > max_steps {
                return Err(NeverIdle { steps: self.stats.steps, now: self.now });
            }
            self.apply_scheduled_faults();
            self.finish_frames();
            for index in 0..self.nodes.len() {
                if self.nodes.get(index).and_then(|n| n.wake).is_some_and(|w| w <= self.now) {
                    self.turn(index);
                }
            }
            for index in 0..self.gateways.len() {
                if self.gateways.get(index).and_then(|g| g.wake).is_some_and(|w| w <= self.now) {
                    self.gateway_turn(index);
                }
            }
            self.start_frames();
            let settled = self.transfers.iter().all(|t| t.report.outcome != Outcome::Pending)
                && self.buses.iter().all(|b| b.on_wire().is_none() && b.next_event_ns(self.now_ns()).is_none())
                && self.nodes.iter().all(|n| n.inbox.is_empty())
                && self.gateways.iter().all(|g| g.inbox.is_empty());
            if settled && stop_when_settled {
                return Ok(());
            }
            match self.next_event() {
                Some(next) if next <= until => self.now = next.max(self.now),
                _ => return Ok(()),
            }
        }
    }

    fn now_ns(&self) -> u64 {
        self.now.as_micros() * 1000
    }

    fn next_event(&self) -> Option<Instant> {
        let now_ns = self.now_ns();
        let bus = self
            .buses
            .iter()
            .filter_map(|b| b.next_event_ns(now_ns))
            .map(|ns| Instant::from_micros(ns.div_ceil(1000)))
            .min();
        let nodes = self.nodes.iter().filter(|n| !n.silent).filter_map(|n| n.wake).min();
        let gateways = self.gateways.iter().filter_map(|g| g.wake).min();
        let fault = self.scheduled.first().map(|(t, _)| *t);
        [bus, nodes, gateways, fault].into_iter().flatten().min()
    }

    fn apply_scheduled_faults(&mut self) {
        while let Some((at, fault)) = self.scheduled.first().copied() {
            if at > self.now {
                break;
            }
            self.scheduled.remove(0);
            match fault {
                ScheduledFault::Reset(node) => self.reset(node),
                ScheduledFault::Silence(node) => self.silence(node),
                ScheduledFault::AliasCollision(node) => self.collide(node),
            }
        }
    }

    fn reset(&mut self, index: NodeIndex) {
        let now = self.now;
        let fresh_alias = 1 + self.rng.below(0xFFE) as u16;
        let Some(node) = self.nodes.get_mut(index) else { return };
        node.inbox.clear();
        node.stack = node.options.build(node.id);
        match &mut node.port {
            Port::Can { bus, port, link } => {
                let mut can = node.options.can.clone();
                can.first_alias = NodeAlias::new(fresh_alias).filter(|a| Some(*a) != link.alias());
                **link = CanLink::new(now, node.id, can);
                if let Some(bus) = self.buses.get_mut(*bus) {
                    bus.clear(*port);
                }
            }
            Port::Tcp { link, .. } => **link = TcpLink::new(node.id),
        }
        let (sending, receiving) = (std::mem::take(&mut node.sending), std::mem::take(&mut node.receiving));
        node.wake = Some(now);
        for transfer in sending.iter().map(|(_, t)| *t).chain(receiving.values().copied()) {
            self.decide(transfer, Outcome::Terminated(Termination::LinkLost));
        }
    }

    fn silence(&mut self, index: NodeIndex) {
        let Some(node) = self.nodes.get_mut(index) else { return };
        node.silent = true;
        node.inbox.clear();
        node.wake = None;
        if let Port::Can { bus, port, .. } = &node.port
            && let Some(bus) = self.buses.get_mut(*bus)
        {
            bus.clear(*port);
        }
        self.abandon_unopened(index);
    }

    /// A silent node never runs again, so the transfers it was still to open never start:
    /// they end as `LinkLost` (the node lost its link for good). Its open streams are left to
    /// the peers' timeouts.
    fn abandon_unopened(&mut self, index: NodeIndex) {
        if !self.nodes.get(index).is_some_and(|n| n.silent) {
            return;
        }
        for t in 0..self.transfers.len() {
            let Some(transfer) = self.transfers.get(t) else { continue };
            if transfer.report.spec.from == index && transfer.report.opened_at.is_none() {
                self.decide(t, Outcome::Terminated(Termination::LinkLost));
            }
        }
    }

    /// A rogue Verified Node ID from another Node ID, carrying `index`'s alias.
    fn collide(&mut self, index: NodeIndex) {
        let Some(alias) = self.alias(index) else { return };
        let Some(Port::Can { bus, .. }) = self.nodes.get(index).map(|n| &n.port) else { return };
        let bus = *bus;
        let rogue = CanFrame::extended(0x1917_0000 | u32::from(alias.as_raw()), &[9, 9, 9, 9, 9, 9]);
        let arrival = self.now;
        for node in &mut self.nodes {
            if let (Port::Can { bus: b, .. }, Some(frame)) = (&node.port, rogue)
                && *b == bus
                && !node.silent
            {
                node.inbox.push_back((arrival + node.options.latency, Inbound::Frame(frame)));
                node.wake = Some(arrival);
            }
        }
    }

    fn finish_frames(&mut self) {
        let now_ns = self.now_ns();
        for bus_index in 0..self.buses.len() {
            let Some(wire) = self.buses.get_mut(bus_index).and_then(|b| b.finish(now_ns)) else { continue };
            let end = Instant::from_micros(wire.end_ns.div_ceil(1000));
            if let Some(sender) = self
                .nodes
                .iter_mut()
                .find(|n| matches!(&n.port, Port::Can { bus, port, .. } if *bus == bus_index && *port == wire.port))
            {
                sender.wake = Some(end);
            }
            if let Some(sender) = self.gateways.iter_mut().find(|g| g.bus == bus_index && g.port == wire.port) {
                sender.wake = Some(end);
            }
            if wire.delivery == Delivery::Corrupted {
                continue;
            }
            self.stats.frames.count(&wire.frame);
            if let Some(trace) = &mut self.trace {
                trace.push((end, wire.frame));
            }
            for node in &mut self.nodes {
                let Port::Can { bus, port, .. } = &node.port else { continue };
                if *bus != bus_index || *port == wire.port || node.silent {
                    continue;
                }
                let copies = if self.rng.chance(self.faults.drop) {
                    self.stats.dropped_frames += 1;
                    0
                } else if self.rng.chance(self.faults.duplicate) {
                    self.stats.duplicated_frames += 1;
                    2
                } else {
                    1
                };
                let arrival = end + node.options.latency;
                for _ in 0..copies {
                    node.inbox.push_back((arrival, Inbound::Frame(wire.frame)));
                }
                node.wake = Some(node.wake.map_or(arrival, |w| w.min(arrival)));
            }
            for gateway in &mut self.gateways {
                if gateway.bus != bus_index || gateway.port == wire.port {
                    continue;
                }
                let arrival = end + gateway.latency;
                gateway.inbox.push_back((arrival, Inbound::Frame(wire.frame)));
                gateway.wake = Some(gateway.wake.map_or(arrival, |w| w.min(arrival)));
            }
        }
    }

    fn start_frames(&mut self) {
        let now_ns = self.now_ns();
        let bit_error = self.faults.bit_error;
        for bus in &mut self.buses {
            let rng = &mut self.rng;
            bus.start(now_ns, |_| rng.chance(bit_error));
        }
    }

    /// One node acts on everything due at `now`, then says when it wants to act next.
    fn turn(&mut self, index: NodeIndex) {
        let now = self.now;
        let Some(node) = self.nodes.get_mut(index) else { return };
        if node.silent {
            node.wake = None;
            return;
        }
        let SimNode { stack, port, inbox, gridconnect: gc, options, .. } = node;
        match port {
            Port::Can { link, .. } => link.handle_timeout(now, stack),
            Port::Tcp { .. } => {}
        }
        stack.handle_timeout(now);
        while inbox.front().is_some_and(|(t, _)| *t <= now) {
            let Some((_, inbound)) = inbox.pop_front() else { break };
            match (inbound, &mut *port) {
                (Inbound::Frame(frame), Port::Can { link, .. }) => {
                    if options.gridconnect {
                        let mut text = [0u8; 32];
                        let n = gridconnect::encode(&frame, &mut text).unwrap_or(0);
                        let mut decoded = None;
                        gc.decode_all(text.get(..n).unwrap_or_default(), |r| decoded = r.ok());
                        if let Some(frame) = decoded {
                            link.handle_frame(now, &frame, stack);
                        }
                    } else {
                        link.handle_frame(now, &frame, stack);
                    }
                }
                (Inbound::Bytes(bytes), Port::Tcp { link, .. }) => {
                    let mut input = &bytes[..];
                    while let Some(result) = link.read_message(&mut input) {
                        if let Ok(msg) = result {
                            stack.handle_message(now, msg);
                        }
                    }
                }
                _ => {}
            }
        }
        self.start_due_transfers(index);
        // Events and transmits feed each other (a read sends a Proceed; a Proceed lets a
        // write through): loop until quiet.
        for _ in 0..64 {
            let events = self.handle_events(index);
            let moved = self.move_outbound(index);
            if !events && !moved {
                break;
            }
        }
        self.schedule_wake(index);
    }

    fn start_due_transfers(&mut self, index: NodeIndex) {
        let now = self.now;
        if !self.can_speak(index) {
            return;
        }
        for t in 0..self.transfers.len() {
            let Some(transfer) = self.transfers.get_mut(t) else { continue };
            let spec = transfer.report.spec;
            if spec.from != index || transfer.report.opened_at.is_some() || transfer.report.outcome != Outcome::Pending
            {
                continue;
            }
            if spec.start > now {
                continue;
            }
            let Some(to) = self.nodes.get(spec.to).map(|n| n.id) else { continue };
            let Some(node) = self.nodes.get_mut(index) else { continue };
            let mut options = OpenOptions::new(to, spec.window);
            options.source_stream = transfer.chosen_source_stream;
            match node.stack.streams_mut().open(now, options) {
                Ok(handle) => {
                    transfer.report.opened_at = Some(now);
                    transfer.source_stream =
                        node.stack.streams_mut().stream_info(handle).map(|i| i.source_stream.as_raw());
                    node.sending.push((handle, t));
                }
                Err(_) => {
                    transfer.report.outcome = Outcome::Rejected;
                    transfer.report.ended_at = Some(now);
                }
            }
        }
    }

    /// A CAN node speaks once its alias is permitted; a TCP node at once.
    fn can_speak(&self, index: NodeIndex) -> bool {
        match self.nodes.get(index).map(|n| &n.port) {
            Some(Port::Can { link, .. }) => matches!(link.login().state(), openlcb_can::LoginState::Permitted { .. }),
            Some(Port::Tcp { .. }) => true,
            None => false,
        }
    }

    fn handle_events(&mut self, index: NodeIndex) -> bool {
        let mut any = false;
        // Link events first: they may end streams.
        let Some(node) = self.nodes.get_mut(index) else { return any };
        if let Port::Can { link, .. } = &mut node.port {
            any |= apply_link_events(link, &mut node.stack);
        }
        loop {
            let Some(node) = self.nodes.get_mut(index) else { return any };
            let Some(event) = node.stack.poll_event() else { break };
            any = true;
            let NodeEvent::Stream(event) = event else {
                if node.events.len() >= KEPT_EVENTS {
                    node.events.pop_front();
                }
                node.events.push_back(event);
                continue;
            };
            match event {
                Event::Opened { handle, info } if info.role == Role::Destination => {
                    let found = self.transfers.iter().position(|t| {
                        t.report.outcome == Outcome::Pending
                            && t.report.spec.to == index
                            && self.nodes.get(t.report.spec.from).is_some_and(|n| n.id == info.peer)
                            && t.source_stream == Some(info.source_stream.as_raw())
                    });
                    if let (Some(t), Some(node)) = (found, self.nodes.get_mut(index)) {
                        node.receiving.insert(handle, t);
                    }
                }
                Event::Opened { handle, .. } | Event::Writable { handle } => self.write(index, handle),
                Event::Readable { handle } => self.read(index, handle),
                Event::Finished { handle, total, matched, .. } => {
                    self.read(index, handle);
                    if let Some(t) = self.nodes.get_mut(index).and_then(|n| n.receiving.remove(&handle)) {
                        let outcome = match self.transfers.get(t) {
                            Some(_) if !matched => Outcome::CountMismatch,
                            Some(tr) if tr.report.verified_prefix == total && total == tr.report.spec.bytes => {
                                Outcome::Completed
                            }
                            _ => Outcome::SilentCorruption,
                        };
                        self.decide(t, outcome);
                    }
                }
                Event::Rejected { handle, .. } => self.end_source(index, handle, Outcome::Rejected),
                Event::Terminated { handle, cause } => self.end_either(index, handle, Outcome::Terminated(cause)),
                Event::TimedOut { handle, kind } => self.end_either(index, handle, Outcome::TimedOut(kind)),
                _ => {}
            }
        }
        any
    }

    fn end_source(&mut self, index: NodeIndex, handle: StreamHandle, outcome: Outcome) {
        let Some(node) = self.nodes.get_mut(index) else { return };
        if let Some(pos) = node.sending.iter().position(|(h, _)| *h == handle) {
            let (_, t) = node.sending.swap_remove(pos);
            self.decide(t, outcome);
        }
    }

    fn end_either(&mut self, index: NodeIndex, handle: StreamHandle, outcome: Outcome) {
        self.read(index, handle);
        if let Some(t) = self.nodes.get_mut(index).and_then(|n| n.receiving.remove(&handle)) {
            self.decide(t, outcome);
        }
        self.end_source(index, handle, outcome);
    }

    /// The first outcome reported for a transfer stands.
    fn decide(&mut self, transfer: usize, outcome: Outcome) {
        if let Some(t) = self.transfers.get_mut(transfer)
            && t.report.outcome == Outcome::Pending
        {
            t.report.outcome = outcome;
            t.report.ended_at = Some(self.now);
        }
    }

    /// Writes the transfer's pattern as far as the credit goes; finishes when all is sent.
    fn write(&mut self, index: NodeIndex, handle: StreamHandle) {
        let now = self.now;
        let Some(node) = self.nodes.get_mut(index) else { return };
        let Some(t) = node.sending.iter().find(|(h, _)| *h == handle).map(|(_, t)| *t) else { return };
        let Some(transfer) = self.transfers.get_mut(t) else { return };
        loop {
            let left = transfer.report.spec.bytes - transfer.report.sent;
            let credit = u64::from(node.stack.streams_mut().credit(handle).unwrap_or(0));
            if left == 0 {
                if node.stack.streams_mut().finish(now, handle).is_ok() {
                    node.sending.retain(|(h, _)| *h != handle);
                }
                return;
            }
            // Offer at least one byte: a short write is what arms the `Writable` event.
            let n = left.min(credit.max(1)).min(self.scratch.len() as u64) as usize;
            let start = transfer.report.sent;
            for (i, byte) in self.scratch.iter_mut().take(n).enumerate() {
                *byte = transfer.byte(start + i as u64);
            }
            match node.stack.streams_mut().write(now, handle, self.scratch.get(..n).unwrap_or_default()) {
                Ok(written) if written > 0 => transfer.report.sent += written as u64,
                _ => return,
            }
        }
    }

    /// Reads everything buffered and checks it against the pattern.
    fn read(&mut self, index: NodeIndex, handle: StreamHandle) {
        let now = self.now;
        let Some(node) = self.nodes.get_mut(index) else { return };
        let transfer = node.receiving.get(&handle).and_then(|t| self.transfers.get_mut(*t));
        let mut sink = transfer;
        while let Ok(n @ 1..) = node.stack.streams_mut().read(now, handle, &mut self.scratch) {
            self.stats.payload_delivered += n as u64;
            if let Some(t) = sink.as_deref_mut() {
                let base = t.report.delivered;
                let intact = t.report.verified_prefix == base;
                if intact {
                    let good = self
                        .scratch
                        .iter()
                        .take(n)
                        .enumerate()
                        .take_while(|(i, b)| **b == t.byte(base + *i as u64))
                        .count();
                    t.report.verified_prefix += good as u64;
                }
                t.report.delivered += n as u64;
            }
        }
    }

    /// Endpoint messages into the link while it has room, link output onto the wire.
    fn move_outbound(&mut self, index: NodeIndex) -> bool {
        let now = self.now;
        let Some(node) = self.nodes.get_mut(index) else { return false };
        let mut moved = false;
        match &mut node.port {
            Port::Can { bus, port, link } => {
                // Take from the node only what the link can queue: a refused message is lost.
                while link.can_send() {
                    let Some(message) = node.stack.poll_transmit() else { break };
                    let _ = link.send(now, message);
                    moved = true;
                }
                let Some(bus) = self.buses.get_mut(*bus) else { return moved };
                while bus.room(*port) > 0 {
                    let Some(frame) = link.poll_transmit() else { break };
                    bus.submit(*port, frame);
                    moved = true;
                }
            }
            Port::Tcp { pipe, side, link } => {
                while let Some(message) = node.stack.poll_transmit() {
                    let _ = link.send(now, &message);
                    moved = true;
                }
                let pending = link.transmit_pending();
                if pending.is_empty() {
                    return moved;
                }
                let chunk = Bytes::copy_from_slice(pending);
                let len = chunk.len();
                link.advance_transmit(len);
                let (pipe, side) = (*pipe, *side);
                self.carry(pipe, side, chunk);
                moved = true;
            }
        }
        moved
    }

    fn carry(&mut self, pipe: usize, side: usize, chunk: Bytes) {
        let now = self.now;
        let Some(p) = self.pipes.get_mut(pipe) else { return };
        let len = chunk.len() as u64;
        self.stats.tcp_bytes += len;
        let Some(busy) = p.busy_until.get_mut(side) else { return };
        let sent_at = (*busy).max(now) + Duration::from_micros(len * 1_000_000 / p.bytes_per_sec);
        *busy = sent_at;
        let arrival = sent_at + p.latency;
        let (inbox, wake, latency) = match p.ends.get(1 - side) {
            Some(Station::Node(to)) => match self.nodes.get_mut(*to) {
                Some(node) if !node.silent => (&mut node.inbox, &mut node.wake, node.options.latency),
                _ => return,
            },
            Some(Station::Gateway(to)) => match self.gateways.get_mut(*to) {
                Some(g) => (&mut g.inbox, &mut g.wake, g.latency),
                None => return,
            },
            None => return,
        };
        let at = arrival + latency;
        inbox.push_back((at, Inbound::Bytes(chunk)));
        *wake = Some(wake.map_or(at, |w| w.min(at)));
    }

    /// A gateway acts on everything due: frames and bytes in, frames and bytes out.
    fn gateway_turn(&mut self, index: usize) {
        let now = self.now;
        let Some(g) = self.gateways.get_mut(index) else { return };
        g.gateway.handle_timeout(now);
        while g.inbox.front().is_some_and(|(t, _)| *t <= now) {
            let Some((_, inbound)) = g.inbox.pop_front() else { break };
            match inbound {
                Inbound::Frame(frame) => g.gateway.handle_can_frame(now, &frame),
                Inbound::Bytes(bytes) => {
                    let mut input = &bytes[..];
                    while let Some(result) = g.tcp.read_message(&mut input) {
                        if let Ok(msg) = result {
                            g.gateway.handle_message(now, msg);
                        }
                    }
                }
            }
        }
        while g.gateway.poll_event().is_some() {}
        if let Some(bus) = self.buses.get_mut(g.bus) {
            while bus.room(g.port) > 0 {
                let Some(frame) = g.gateway.poll_can_transmit() else { break };
                bus.submit(g.port, frame);
            }
        }
        while let Some(message) = g.gateway.poll_message() {
            let _ = g.tcp.send(now, &message);
        }
        let pending = g.tcp.transmit_pending();
        let outgoing = (!pending.is_empty()).then(|| Bytes::copy_from_slice(pending));
        if let Some(chunk) = &outgoing {
            g.tcp.advance_transmit(chunk.len());
        }
        g.wake = [g.inbox.front().map(|(t, _)| *t), g.gateway.poll_timeout()].into_iter().flatten().min();
        if let (Some(chunk), Some((pipe, side))) = (outgoing, g.pipe) {
            self.carry(pipe, side, chunk);
        }
    }

    fn schedule_wake(&mut self, index: NodeIndex) {
        let now = self.now;
        let next_start = self
            .transfers
            .iter()
            .filter(|t| {
                t.report.spec.from == index && t.report.opened_at.is_none() && t.report.outcome == Outcome::Pending
            })
            .map(|t| t.report.spec.start.max(now))
            .min();
        let Some(node) = self.nodes.get_mut(index) else { return };
        let link_timeout = match &node.port {
            Port::Can { link, .. } => link.poll_timeout(),
            Port::Tcp { .. } => None,
        };
        // A transfer waiting for its CAN alias is woken by the link's own timers.
        let waiting_start = next_start.filter(|t| *t > now);
        node.wake = [node.inbox.front().map(|(t, _)| *t), node.stack.poll_timeout(), link_timeout, waiting_start]
            .into_iter()
            .flatten()
            .min();
    }
}

/// Acts on a CAN node's own link events (its peer changes reach the node inside
/// `handle_frame` and `handle_timeout`); true if there was any.
fn apply_link_events(link: &mut CanLink, node: &mut Node) -> bool {
    let mut any = false;
    while let Some(event) = link.poll_event() {
        any = true;
        match event {
            LinkEvent::AliasLost { .. } => node.link_lost(),
            LinkEvent::DuplicateNodeId { newcomer: true, .. } => {
                link.leave(Some(node.duplicate_node_id_report()));
                node.link_lost();
            }
            LinkEvent::DuplicateNodeId { newcomer: false, .. } => node.report_duplicate_node_id(),
            _ => {}
        }
    }
    any
}
