//! An in-memory network for the integration tests: a CAN node (`CanLink` + `StreamEndpoint`),
//! the gateway, and a full-format node (`TcpLink` + `StreamEndpoint`), on virtual time. Every
//! frame and byte goes through the real codecs; a small loop moves them.
#![allow(dead_code, unreachable_pub)]

use openlcb_can::{CanConfig, CanFrame, CanLink, LinkEvent};
use openlcb_gateway::{Gateway, GatewayConfig, GatewayEvent, Side};
use openlcb_stream::{
    Config, Event, Instant, Message, MessageRef, NodeId, OpenOptions, PeerChange, PeerChanges, Receiver,
    StreamEndpoint, StreamError, StreamHandle,
};
use openlcb_tcp::TcpLink;

pub const CAN_NODE: u64 = 0x0501_0101_2200;
pub const FULL_NODE: u64 = 0x0501_0101_2210;
pub const GATEWAY_NODE: u64 = 0x0501_0101_22FF;

pub fn node_id(raw: u64) -> NodeId {
    NodeId::new(raw).unwrap()
}

pub fn pattern(len: usize) -> Vec<u8> {
    (0..len).map(|i| (i * 7 + i / 251) as u8).collect()
}

/// The layer above the CAN node's link: its endpoint, with a record of the messages.
struct Recording<'a> {
    endpoint: &'a mut StreamEndpoint,
    delivered: &'a mut Vec<Message>,
}

impl PeerChanges for Recording<'_> {
    fn peer_changed(&mut self, change: PeerChange) {
        self.endpoint.peer_changed(change);
    }
}

impl Receiver for Recording<'_> {
    fn handle_message(&mut self, now: Instant, message: MessageRef<'_>) {
        self.delivered.push(message.to_message());
        self.endpoint.handle_message(now, message);
    }

    fn medium_busy(&mut self, now: Instant) {
        self.endpoint.medium_busy(now);
    }
}

/// One stream endpoint and what it saw.
pub struct Peer {
    pub endpoint: StreamEndpoint,
    pub events: Vec<Event>,
    pub received: Vec<u8>,
    /// Total and match of the `Finished` event, once it came.
    pub finished: Option<(u64, bool)>,
    /// The outgoing transfer: the stream, its data, bytes written, whether `finish` was called.
    pub sending: Option<(StreamHandle, Vec<u8>, usize, bool)>,
}

impl Peer {
    fn new(id: u64, config: Config) -> Self {
        Peer {
            endpoint: StreamEndpoint::new(node_id(id), config),
            events: Vec::new(),
            received: Vec::new(),
            finished: None,
            sending: None,
        }
    }

    /// Writes what the credit allows, finishes once everything is written, reads everything
    /// received.
    fn work(&mut self, now: Instant) {
        if let Some((handle, data, sent, finished)) = &mut self.sending {
            if *sent < data.len() {
                match self.endpoint.write(now, *handle, &data[*sent..]) {
                    Ok(n) => *sent += n,
                    Err(StreamError::NotOpen) => {}
                    Err(e) => panic!("write failed: {e:?}"),
                }
            }
            if *sent == data.len() && !*finished && self.endpoint.finish(now, *handle).is_ok() {
                *finished = true;
            }
        }
        while let Some(event) = self.endpoint.poll_event() {
            if let Event::Finished { total, matched, .. } = event {
                self.finished = Some((total, matched));
            }
            self.events.push(event);
        }
        let mut buf = [0u8; 512];
        for handle in self.endpoint.handles().collect::<Vec<_>>() {
            while let Ok(n @ 1..) = self.endpoint.read(now, handle, &mut buf) {
                self.received.extend_from_slice(&buf[..n]);
            }
        }
    }
}

pub struct Net {
    pub now: Instant,
    pub can_link: CanLink,
    pub can: Peer,
    pub full_link: TcpLink,
    pub full: Peer,
    pub gateway: Gateway,
    pub gateway_link: TcpLink,
    /// Frames the gateway put on CAN.
    pub from_gateway: Vec<CanFrame>,
    /// Frames the CAN node put on CAN.
    pub from_can_node: Vec<CanFrame>,
    /// Messages the CAN node's link delivered.
    pub can_delivered: Vec<Message>,
    /// Messages the gateway sent to the full-format node.
    pub to_full: Vec<Message>,
    /// Messages the full-format node sent to the gateway.
    pub from_full: Vec<Message>,
    pub gateway_events: Vec<GatewayEvent>,
    /// The most frames the gateway may put on CAN per turn (a slow bus).
    pub can_frames_per_turn: usize,
    /// The most frames of the CAN node the gateway receives per turn (a slow bus).
    pub can_node_frames_per_turn: usize,
    /// Frames of the CAN node on their way to the gateway.
    pub on_the_bus: std::collections::VecDeque<CanFrame>,
    /// Hold frames of the CAN node back in `intercepted` instead of delivering them.
    pub intercept: bool,
    pub intercepted: Vec<CanFrame>,
    /// The largest `memory_in_use` seen after a turn.
    pub max_memory: usize,
}

pub fn core_config(window: u16) -> Config {
    let mut config = Config::default();
    config.max_window = window;
    config
}

impl Net {
    /// Both nodes announce themselves (Initialization Complete, the node layer's first
    /// message) as soon as their links can carry it.
    pub fn new(gateway: GatewayConfig, can_core: Config, full_core: Config) -> Self {
        let now = Instant::ZERO;
        let mut can_link = CanLink::new(now, node_id(CAN_NODE), CanConfig::default());
        can_link.send(now, Message::initialization_complete(node_id(CAN_NODE))).unwrap();
        let mut full_link = TcpLink::new(node_id(FULL_NODE));
        full_link.send(now, &Message::initialization_complete(node_id(FULL_NODE))).unwrap();
        Net {
            now,
            can_link,
            can: Peer::new(CAN_NODE, can_core),
            full_link,
            full: Peer::new(FULL_NODE, full_core),
            gateway: Gateway::new(now, gateway),
            gateway_link: TcpLink::new(node_id(GATEWAY_NODE)),
            from_gateway: Vec::new(),
            from_can_node: Vec::new(),
            can_delivered: Vec::new(),
            to_full: Vec::new(),
            from_full: Vec::new(),
            gateway_events: Vec::new(),
            can_frames_per_turn: usize::MAX,
            can_node_frames_per_turn: usize::MAX,
            on_the_bus: std::collections::VecDeque::new(),
            intercept: false,
            intercepted: Vec::new(),
            max_memory: 0,
        }
    }

    /// Both nodes logged in and known to each other.
    pub fn started(gateway: GatewayConfig, can_core: Config, full_core: Config) -> Self {
        let mut net = Net::new(gateway, can_core, full_core);
        net.settle();
        net.advance_to(Instant::from_millis(200));
        net.settle();
        assert!(net.can_link.alias().is_some(), "the CAN node logged in");
        assert!(net.gateway.proxy_alias(node_id(FULL_NODE)).is_some(), "the full node has a proxy alias");
        net
    }

    pub fn peer(&mut self, side: Side) -> &mut Peer {
        match side {
            Side::Can => &mut self.can,
            Side::Full => &mut self.full,
        }
    }

    pub fn node(side: Side) -> NodeId {
        match side {
            Side::Can => node_id(CAN_NODE),
            Side::Full => node_id(FULL_NODE),
        }
    }

    /// Opens a stream from the node on `from` to the other one, to send `data`.
    pub fn start_transfer(&mut self, from: Side, data: Vec<u8>, window: u16) -> StreamHandle {
        let to = Net::node(if from == Side::Can { Side::Full } else { Side::Can });
        let now = self.now;
        let peer = self.peer(from);
        let handle = peer.endpoint.open(now, OpenOptions::new(to, window)).unwrap();
        peer.sending = Some((handle, data, 0, false));
        handle
    }

    /// Delivers the frames held back by `intercept`, in the given order.
    pub fn deliver_intercepted(&mut self, frames: &[CanFrame]) {
        for frame in frames {
            self.gateway.handle_can_frame(self.now, frame);
        }
    }

    /// One pass of moving everything that is ready; false if nothing moved.
    pub fn turn(&mut self) -> bool {
        let now = self.now;
        let mut moved = false;
        self.can.work(now);
        self.full.work(now);

        // CAN node -> bus -> gateway.
        while let Some(message) = self.can.endpoint.poll_transmit() {
            let _ = self.can_link.send(now, message);
        }
        while let Some(frame) = self.can_link.poll_transmit() {
            moved = true;
            self.from_can_node.push(frame);
            if self.intercept {
                self.intercepted.push(frame);
            } else {
                self.on_the_bus.push_back(frame);
            }
        }
        for _ in 0..self.can_node_frames_per_turn {
            let Some(frame) = self.on_the_bus.pop_front() else { break };
            moved = true;
            self.gateway.handle_can_frame(now, &frame);
        }

        // Full-format node -> TCP bytes -> gateway.
        self.full_link.send_from(now, || self.full.endpoint.poll_transmit()).unwrap();
        let bytes = self.full_link.transmit_pending().to_vec();
        self.full_link.advance_transmit(bytes.len());
        let mut input = &bytes[..];
        while let Some(result) = self.gateway_link.read_message(&mut input) {
            let message = result.unwrap();
            moved = true;
            self.from_full.push(message.to_message());
            self.gateway.handle_message(now, message);
        }

        // Gateway -> bus -> CAN node, as many frames as the bus takes this turn.
        for _ in 0..self.can_frames_per_turn {
            let Some(frame) = self.gateway.poll_can_transmit() else { break };
            moved = true;
            self.from_gateway.push(frame);
            let mut above = Recording { endpoint: &mut self.can.endpoint, delivered: &mut self.can_delivered };
            self.can_link.handle_frame(now, &frame, &mut above);
        }
        self.apply_can_link_events();

        // Gateway -> TCP bytes -> full-format node.
        while let Some(message) = self.gateway.poll_message() {
            moved = true;
            self.gateway_link.send(now, &message).unwrap();
            self.to_full.push(message);
        }
        let bytes = self.gateway_link.transmit_pending().to_vec();
        self.gateway_link.advance_transmit(bytes.len());
        let mut input = &bytes[..];
        while let Some(result) = self.full_link.read_message(&mut input) {
            self.full.endpoint.handle_message(now, result.unwrap());
        }

        while let Some(event) = self.gateway.poll_event() {
            self.gateway_events.push(event);
        }
        self.max_memory = self.max_memory.max(self.gateway.memory_in_use());
        moved
    }

    /// The CAN link's own events. The rig applies no policy to a duplicate Node ID: the
    /// tests look at what the gateway does.
    fn apply_can_link_events(&mut self) {
        while let Some(event) = self.can_link.poll_event() {
            if let LinkEvent::AliasLost { .. } = event {
                self.can.endpoint.link_lost();
            }
        }
    }

    /// Turns until nothing moves.
    pub fn settle(&mut self) {
        for _ in 0..1_000_000 {
            if !self.turn() {
                return;
            }
        }
        panic!("the network never went quiet");
    }

    /// The earliest deadline of any part.
    pub fn next_deadline(&self) -> Option<Instant> {
        [
            self.can_link.poll_timeout(),
            self.can.endpoint.poll_timeout(),
            self.full.endpoint.poll_timeout(),
            self.gateway.poll_timeout(),
        ]
        .into_iter()
        .flatten()
        .min()
    }

    /// Moves the clock to `at` and runs every part's timers.
    pub fn advance_to(&mut self, at: Instant) {
        self.now = self.now.max(at);
        let now = self.now;
        let mut above = Recording { endpoint: &mut self.can.endpoint, delivered: &mut self.can_delivered };
        self.can_link.handle_timeout(now, &mut above);
        self.can.endpoint.handle_timeout(now);
        self.full.endpoint.handle_timeout(now);
        self.gateway.handle_timeout(now);
    }

    /// Settles, then jumps to the next deadline, until `done` holds (bounded).
    pub fn run_until(&mut self, mut done: impl FnMut(&Net) -> bool) {
        for _ in 0..100_000 {
            self.settle();
            if done(self) {
                return;
            }
            let next = self.next_deadline().expect("nothing left to wait for");
            self.advance_to(next);
        }
        panic!("never done");
    }
}
