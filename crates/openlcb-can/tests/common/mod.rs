//! A virtual CAN bus for the integration tests: nodes (a `CanLink` and a `StreamEndpoint`
//! each), virtual time, every frame broadcast to every other node and recorded as
//! GridConnect text.
#![allow(dead_code, unreachable_pub)]

pub mod published;

use openlcb_can::gridconnect::{self, GridConnectDecoder};
use openlcb_can::{CanConfig, CanFrame, CanLink, LinkEvent, NodeAlias};
use openlcb_stream::{
    Config, Duration, Event, Instant, Message, MessageRef, NodeId, PeerChange, PeerChanges, Receiver,
};

pub const A_ID: u64 = 0x0501_0101_2200;
pub const B_ID: u64 = 0x0501_0101_2201;

pub fn node_id(raw: u64) -> NodeId {
    NodeId::new(raw).unwrap()
}

pub fn alias(raw: u16) -> NodeAlias {
    NodeAlias::new(raw).unwrap()
}

/// The GridConnect text of a frame.
pub fn text(frame: &CanFrame) -> String {
    let mut buf = [0u8; gridconnect::MAX_ENCODED_LEN];
    let n = gridconnect::encode(frame, &mut buf).unwrap();
    String::from_utf8(buf[..n].to_vec()).unwrap()
}

/// The frame of one GridConnect text.
pub fn frame(text: &str) -> CanFrame {
    let mut decoder = GridConnectDecoder::new();
    let mut input = text.as_bytes();
    let frame = decoder.decode(&mut input).expect("a whole frame").expect("a valid frame");
    assert!(input.is_empty(), "one frame only: {text}");
    frame
}

/// The core configuration of the worked example (wire-spec §9.2).
pub fn core_config() -> Config {
    let mut c = Config::default();
    c.max_window = 16;
    c.early_proceed = false;
    c
}

pub fn can_config(first_alias: u16) -> CanConfig {
    let mut c = CanConfig::default();
    c.first_alias = Some(alias(first_alias));
    c
}

pub struct Node {
    pub link: CanLink,
    /// The node above the link (it answers the message-network basics, SNIP, datagrams).
    pub stack: openlcb_node::Node,
    pub link_events: Vec<LinkEvent>,
    /// Every peer change the link handed up, in order.
    pub peer_changes: Vec<PeerChange>,
    /// Every time the link said the bus carries another node's stream data.
    pub medium_busy: Vec<Instant>,
    pub events: Vec<Event>,
    /// The node's other events (datagrams, SNIP, ...).
    pub node_events: Vec<openlcb_node::NodeEvent>,
    /// Every message the link delivered, as it was delivered.
    pub delivered: Vec<Message>,
    pub received: Vec<u8>,
    /// Read received stream data as it arrives.
    pub reading: bool,
}

impl Node {
    /// A link and the node above it, whose stream endpoint has the configuration `core`.
    pub fn new(now: Instant, id: u64, core: Config, can: CanConfig) -> Self {
        let mut config = openlcb_node::NodeConfig::default();
        config.stream = core;
        Node::with_config(now, id, config, can)
    }

    /// A link and the node above it.
    pub fn with_config(now: Instant, id: u64, config: openlcb_node::NodeConfig, can: CanConfig) -> Self {
        Node {
            link: CanLink::new(now, node_id(id), can),
            stack: openlcb_node::Node::new(node_id(id), config),
            link_events: Vec::new(),
            peer_changes: Vec::new(),
            medium_busy: Vec::new(),
            events: Vec::new(),
            node_events: Vec::new(),
            delivered: Vec::new(),
            received: Vec::new(),
            reading: true,
        }
    }

    /// Feeds one frame from the bus (the link hands peer changes and messages to the node),
    /// then the link's events to the node. Every delivered message is recorded in
    /// `delivered`, every peer change in `peer_changes`.
    pub fn receive(&mut self, now: Instant, frame: &CanFrame) {
        let Node { link, stack, delivered, peer_changes, medium_busy, .. } = self;
        link.handle_frame(now, frame, &mut Recording { stack, delivered, peer_changes, medium_busy });
        self.apply_link_events();
    }

    /// Runs the timers of link and node.
    pub fn handle_timeout(&mut self, now: Instant) {
        let Node { link, stack, delivered, peer_changes, medium_busy, .. } = self;
        link.handle_timeout(now, &mut Recording { stack, delivered, peer_changes, medium_busy });
        self.stack.handle_timeout(now);
    }

    /// Link events to the node, recorded in `link_events`. The rig applies no policy of its
    /// own to a duplicate Node ID: the tests act on it, to see what the link does.
    pub fn apply_link_events(&mut self) {
        while let Some(event) = self.link.poll_event() {
            if let LinkEvent::AliasLost { .. } = event {
                self.stack.link_lost();
            }
            self.link_events.push(event);
        }
    }

    /// Link events to the node, node messages to the link, data read. Returns the
    /// frames the link has to send.
    pub fn service(&mut self, now: Instant) -> Vec<CanFrame> {
        self.apply_link_events();
        if self.reading {
            let mut buf = [0u8; 64];
            for handle in self.endpoint().handles().collect::<Vec<_>>() {
                while let Ok(n @ 1..) = self.endpoint().read(now, handle, &mut buf) {
                    self.received.extend_from_slice(&buf[..n]);
                }
            }
        }
        while let Some(event) = self.stack.poll_event() {
            match event {
                openlcb_node::NodeEvent::Stream(event) => self.events.push(event),
                other => self.node_events.push(other),
            }
        }
        while let Some(msg) = self.stack.poll_transmit() {
            self.link.send(now, msg).expect("the link takes the message");
        }
        core::iter::from_fn(|| self.link.poll_transmit()).collect()
    }

    /// The node's stream commands (and, through them, its endpoint's getters).
    pub fn endpoint(&mut self) -> openlcb_node::Streams<'_> {
        self.stack.streams_mut()
    }

    pub fn poll_timeout(&self) -> Option<Instant> {
        [self.link.poll_timeout(), self.stack.poll_timeout()].into_iter().flatten().min()
    }
}

/// The layer above the link in the rig: the node, with a record of what reaches it.
struct Recording<'a> {
    stack: &'a mut openlcb_node::Node,
    delivered: &'a mut Vec<Message>,
    peer_changes: &'a mut Vec<PeerChange>,
    medium_busy: &'a mut Vec<Instant>,
}

impl PeerChanges for Recording<'_> {
    fn peer_changed(&mut self, change: PeerChange) {
        self.peer_changes.push(change);
        self.stack.peer_changed(change);
    }
}

impl Receiver for Recording<'_> {
    fn handle_message(&mut self, now: Instant, message: MessageRef<'_>) {
        self.delivered.push(message.to_message());
        self.stack.handle_message(now, message);
    }

    fn medium_busy(&mut self, now: Instant) {
        self.medium_busy.push(now);
        self.stack.medium_busy(now);
    }
}

/// A layer above that hands each message to a closure and takes no notice of peer changes:
/// for tests of the link's framing alone.
pub struct Messages<F>(F);

pub fn messages<F: FnMut(MessageRef<'_>)>(deliver: F) -> Messages<F> {
    Messages(deliver)
}

impl<F> PeerChanges for Messages<F> {
    fn peer_changed(&mut self, _change: PeerChange) {}
}

impl<F: FnMut(MessageRef<'_>)> Receiver for Messages<F> {
    fn handle_message(&mut self, _now: Instant, message: MessageRef<'_>) {
        (self.0)(message);
    }

    fn medium_busy(&mut self, _now: Instant) {}
}

pub struct Bus {
    pub now: Instant,
    pub nodes: Vec<Node>,
    /// Every frame sent, as (sender index, GridConnect text).
    pub trace: Vec<(usize, String)>,
}

impl Bus {
    pub fn new(nodes: Vec<Node>) -> Self {
        Bus { now: Instant::ZERO, nodes, trace: Vec::new() }
    }

    /// Moves frames between the nodes until no one has anything to send.
    pub fn pump(&mut self) {
        for _ in 0..100_000 {
            let mut moved = false;
            for i in 0..self.nodes.len() {
                let frames = self.nodes[i].service(self.now);
                for frame in frames {
                    moved = true;
                    self.broadcast(Some(i), &frame);
                }
            }
            if !moved {
                return;
            }
        }
        panic!("the bus never went quiet");
    }

    /// Puts `frame` on the bus as if from a node outside the test (or from node `from`).
    pub fn broadcast(&mut self, from: Option<usize>, frame: &CanFrame) {
        self.trace.push((from.unwrap_or(usize::MAX), text(frame)));
        let now = self.now;
        for (j, node) in self.nodes.iter_mut().enumerate() {
            if Some(j) != from {
                node.receive(now, frame);
            }
        }
    }

    /// Advances virtual time to `t`, runs the timers, pumps.
    pub fn advance_to(&mut self, t: Instant) {
        assert!(t >= self.now);
        self.now = t;
        for node in &mut self.nodes {
            node.handle_timeout(t);
        }
        self.pump();
    }

    /// The earliest timer of any node.
    pub fn next_timeout(&self) -> Option<Instant> {
        self.nodes.iter().filter_map(Node::poll_timeout).min()
    }

    /// Runs timers in order until none is due before `limit`.
    pub fn run_until(&mut self, limit: Instant) {
        self.pump();
        let mut turns = 0;
        while let Some(t) = self.next_timeout().filter(|t| *t <= limit) {
            turns += 1;
            assert!(turns < 100_000, "a timer keeps firing at {t:?}");
            self.advance_to(t.max(self.now));
        }
        if self.now < limit {
            self.advance_to(limit);
        }
    }

    /// The trace of one sender as text.
    pub fn sent_by(&self, sender: usize) -> Vec<&str> {
        self.trace.iter().filter(|(s, _)| *s == sender).map(|(_, t)| t.as_str()).collect()
    }

    /// Forgets the trace so far.
    pub fn clear_trace(&mut self) {
        self.trace.clear();
    }
}

/// One node (link + endpoint) driven by hand: frames in as text, frames out as text.
pub struct Solo {
    pub now: Instant,
    pub node: Node,
}

/// A node configuration whose application takes every datagram (nothing is rejected above the
/// link), so that tests see only what the link itself answers.
pub fn claiming_every_datagram() -> openlcb_node::NodeConfig {
    let mut config = openlcb_node::NodeConfig::default();
    config.stream = core_config();
    config.datagrams.claimed = (0..=255).collect();
    config
}

impl Solo {
    pub fn new(can: CanConfig) -> Self {
        Solo::with_config(can, {
            let mut config = openlcb_node::NodeConfig::default();
            config.stream = core_config();
            config
        })
    }

    pub fn with_config(can: CanConfig, config: openlcb_node::NodeConfig) -> Self {
        Solo { now: Instant::ZERO, node: Node::with_config(Instant::ZERO, A_ID, config, can) }
    }

    /// Logged in as 0x123, the login frames drained.
    pub fn permitted() -> Self {
        Self::permitted_with(can_config(0x123))
    }

    /// Logged in with `can` (whose first alias must be free), the login frames drained.
    pub fn permitted_with(can: CanConfig) -> Self {
        Self::logged_in(Solo::new(can))
    }

    /// `solo` logged in as 0x123, the login frames drained.
    pub fn logged_in(mut solo: Solo) -> Self {
        solo.advance_ms(200);
        assert_eq!(solo.node.link.alias(), Some(alias(0x123)));
        solo.node.link_events.clear();
        solo.node.peer_changes.clear();
        solo
    }

    pub fn sent(&mut self) -> Vec<String> {
        self.node.service(self.now).iter().map(text).collect()
    }

    pub fn inject(&mut self, texts: &[&str]) -> Vec<String> {
        for t in texts {
            self.node.receive(self.now, &frame(t));
        }
        self.sent()
    }

    pub fn advance_ms(&mut self, ms: u64) -> Vec<String> {
        self.now += Duration::from_millis(ms);
        self.node.handle_timeout(self.now);
        self.sent()
    }
}
