//! The train side of Traction Control, Train Search and FDI, message by message on a virtual
//! clock: what OlcbChecker's `control_traincontrol`, `control_trainsearch` and `control_fdi`
//! check, and the bounds, forwarding and heartbeat rules of the standard beyond them.

#![cfg(feature = "traction")]

use openlcb_node::memconfig::MemoryServer;
use openlcb_node::traction::{
    CLEAR_EMERGENCY_OFF, CLEAR_EMERGENCY_STOP, EMERGENCY_OFF, EMERGENCY_STOP, FunctionKind, FunctionName, IS_TRAIN,
    LISTENER_LINK_F0, LISTENER_LINK_FN, LISTENER_REVERSE, SearchQuery, Speed, TrainChange, TrainConfig, TrainError,
    TrainEvent, TrainProtocol, fdi_space, fdi_xml,
};
use openlcb_node::{Node, NodeConfig, NodeEvent, Protocols};
use openlcb_stream::{Duration, EventId, Instant, Message, Mti, NodeId, PeerChange};

const DUT: NodeId = NodeId::from_bytes([5, 1, 1, 1, 0x22, 1]);
const TOOL: NodeId = NodeId::from_bytes([5, 1, 1, 1, 0x22, 9]);
const OTHER: NodeId = NodeId::from_bytes([5, 1, 1, 1, 0x22, 10]);
const LISTENER_A: NodeId = NodeId::from_bytes([5, 1, 1, 1, 0x22, 0x20]);
const LISTENER_B: NodeId = NodeId::from_bytes([5, 1, 1, 1, 0x22, 0x21]);

struct Bench {
    node: Node,
    now: Instant,
    sent: Vec<Message>,
    events: Vec<TrainEvent>,
}

impl Bench {
    fn new(config: TrainConfig) -> Self {
        let mut node_config = NodeConfig::default();
        node_config.train = Some(config);
        let mut bench = Bench {
            node: Node::new(DUT, node_config),
            now: Instant::from_secs(1),
            sent: Vec::new(),
            events: Vec::new(),
        };
        bench.advance(Duration::ZERO);
        bench
    }

    fn dcc(address: u32) -> Self {
        Bench::new(TrainConfig::dcc(address))
    }

    fn advance(&mut self, span: Duration) {
        let end = self.now + span;
        loop {
            self.node.handle_timeout(self.now);
            self.drain();
            match self.node.poll_timeout() {
                Some(due) if due <= end && due > self.now => self.now = due,
                _ => break,
            }
        }
        self.now = end;
        self.node.handle_timeout(end);
        self.drain();
    }

    fn drain(&mut self) {
        while let Some(m) = self.node.poll_transmit() {
            self.sent.push(m);
        }
        while let Some(e) = self.node.poll_event() {
            if let NodeEvent::Train(e) = e {
                self.events.push(e);
            }
        }
    }

    fn take(&mut self) -> Vec<Message> {
        core::mem::take(&mut self.sent)
    }

    fn command_from(&mut self, from: NodeId, payload: &[u8]) -> Vec<Message> {
        self.sent.clear();
        let msg = Message::addressed(Mti::TRACTION_CONTROL_COMMAND, from, DUT, payload.to_vec());
        self.node.handle_message(self.now, msg.as_ref());
        self.drain();
        self.take()
    }

    fn command(&mut self, payload: &[u8]) -> Vec<Message> {
        self.command_from(TOOL, payload)
    }

    /// The one Traction Control Reply `payload` gets.
    fn ask(&mut self, payload: &[u8]) -> Vec<u8> {
        let sent = self.command(payload);
        let replies: Vec<_> = sent.iter().filter(|m| m.mti == Mti::TRACTION_CONTROL_REPLY).collect();
        assert_eq!(replies.len(), 1, "{sent:?}");
        assert_eq!(replies[0].destination, Some(TOOL));
        replies[0].payload.to_vec()
    }

    fn global(&mut self, mti: Mti, event: EventId) -> Vec<Message> {
        self.sent.clear();
        let msg = Message::global(mti, TOOL, event.to_bytes());
        self.node.handle_message(self.now, msg.as_ref());
        self.drain();
        self.take()
    }

    fn set_speed(&mut self, bits: u16) {
        let [hi, lo] = bits.to_be_bytes();
        assert!(self.command(&[0x00, hi, lo]).is_empty());
    }

    fn speeds(&mut self) -> (u16, u8, u16) {
        let r = self.ask(&[0x10]);
        assert_eq!(r.len(), 8);
        assert_eq!(r[0], 0x10);
        (u16::from_be_bytes([r[1], r[2]]), r[3], u16::from_be_bytes([r[4], r[5]]))
    }
}

fn with_node(prefix: &[u8], node: NodeId) -> Vec<u8> {
    let mut v = prefix.to_vec();
    v.extend_from_slice(&node.to_bytes());
    v
}

fn oir_code(sent: &[Message]) -> u16 {
    assert_eq!(sent.len(), 1, "{sent:?}");
    assert_eq!(sent[0].mti, Mti::OPTIONAL_INTERACTION_REJECTED);
    assert_eq!(&sent[0].payload[2..4], &[0x05, 0xEB]);
    u16::from_be_bytes([sent[0].payload[0], sent[0].payload[1]])
}

// ----- identity -----

#[test]
fn a_train_announces_train_control_and_is_train() {
    let mut bench = Bench::dcc(3);
    assert!(bench.node.protocols().contains(Protocols::TRAIN_CONTROL));
    assert!(bench.node.protocols().contains(Protocols::EVENT_EXCHANGE));
    let plain = Node::new(DUT, NodeConfig::default());
    assert!(!plain.protocols().contains(Protocols::TRAIN_CONTROL));
    // tr010: Identify Events (addressed) gives Is Train as produced.
    bench.sent.clear();
    let msg = Message::addressed(Mti::IDENTIFY_EVENTS_ADDRESSED, TOOL, DUT, Vec::new());
    bench.node.handle_message(bench.now, msg.as_ref());
    bench.drain();
    let sent = bench.take();
    assert!(sent.iter().any(|m| m.mti == Mti::PRODUCER_IDENTIFIED_VALID && m.payload == IS_TRAIN.to_bytes()));
    let sent = bench.global(Mti::IDENTIFY_PRODUCER, IS_TRAIN);
    assert_eq!(sent.len(), 1);
    assert_eq!(sent[0].mti, Mti::PRODUCER_IDENTIFIED_VALID);
}

#[test]
fn fdi_is_served_read_only_and_announced() {
    let functions = [
        FunctionName { number: 0, name: "Headlight".into(), kind: FunctionKind::Binary },
        FunctionName { number: 2, name: "Horn".into(), kind: FunctionKind::Momentary },
    ];
    let xml = fdi_xml(&functions);
    // FDI Standard §5.1.2, §5.1.4: the reserved space, origin and size attributes omitted.
    assert!(xml.contains("<segment>") && !xml.contains("space=") && !xml.contains("size="));
    assert!(xml.contains("https://openlcb.org/schema/fdi/1/1/fdi.xsd"));
    let mut node = Node::new(DUT, NodeConfig::default())
        .with_memory_server(MemoryServer::new().with_space(0xFA, fdi_space(&functions)));
    assert!(node.protocols().contains(Protocols::FDI));
    let space = node.memory_server_mut().unwrap().space_mut(0xFA).unwrap();
    assert!(space.read_only());
    assert_eq!(space.len() as usize, xml.len() + 1);
    let mut buf = vec![0; xml.len() + 1];
    assert_eq!(space.read(0, &mut buf).unwrap(), xml.len() + 1);
    assert_eq!(buf.last(), Some(&0));
}

// ----- speed, functions, emergency stop -----

#[test]
fn speed_keeps_its_direction_and_the_sign_of_zero() {
    let mut bench = Bench::dcc(3);
    for bits in [0xBE4C, 0x8000, 0x3E4C, 0x0000] {
        bench.set_speed(bits);
        assert_eq!(bench.speeds(), (bits, 0, bits));
        assert_eq!(bench.node.train().unwrap().set_speed, Speed::from_bits(bits));
    }
    let last = bench.events.iter().rev().find_map(|e| match e.change {
        TrainChange::Speed { set, commanded } => Some((set, commanded, e.from)),
        _ => None,
    });
    assert_eq!(last, Some((Speed::ZERO_FORWARD, Speed::ZERO_FORWARD, Some(TOOL))));
}

#[test]
fn emergency_stop_zeroes_the_set_speed_in_its_direction_until_the_next_set() {
    let mut bench = Bench::dcc(3);
    bench.set_speed(0xBE4C);
    assert!(bench.command(&[0x02]).is_empty());
    assert_eq!(bench.speeds(), (0x8000, 1, 0x8000));
    assert!(bench.events.iter().any(|e| e.change == TrainChange::EmergencyStop));
    bench.set_speed(0x3E4C);
    assert_eq!(bench.speeds(), (0x3E4C, 0, 0x3E4C));
}

#[test]
fn global_stop_and_off_stop_the_train_but_keep_the_set_speed() {
    let mut bench = Bench::dcc(3);
    bench.set_speed(0xBE4C);
    for (on, off, change) in [
        (EMERGENCY_STOP, CLEAR_EMERGENCY_STOP, TrainChange::GlobalStop as fn(bool) -> TrainChange),
        (EMERGENCY_OFF, CLEAR_EMERGENCY_OFF, TrainChange::GlobalOff),
    ] {
        bench.events.clear();
        bench.global(Mti::PRODUCER_CONSUMER_EVENT_REPORT, on);
        assert_eq!(bench.speeds(), (0xBE4C, 0, 0x8000));
        assert!(bench.events.contains(&TrainEvent { change: change(true), from: Some(TOOL) }));
        // A Set Speed while it holds is kept, and the train still stands.
        bench.set_speed(0x3E4C);
        assert_eq!(bench.speeds(), (0x3E4C, 0, 0x0000));
        bench.global(Mti::PRODUCER_CONSUMER_EVENT_REPORT, off);
        assert_eq!(bench.speeds(), (0x3E4C, 0, 0x3E4C));
        assert!(bench.events.contains(&TrainEvent {
            change: TrainChange::Speed { set: Speed::from_bits(0x3E4C), commanded: Speed::from_bits(0x3E4C) },
            from: Some(TOOL)
        }));
        bench.set_speed(0xBE4C);
    }
    // Both at once: clearing one leaves the train stopped.
    bench.global(Mti::PRODUCER_CONSUMER_EVENT_REPORT, EMERGENCY_STOP);
    bench.global(Mti::PRODUCER_CONSUMER_EVENT_REPORT, EMERGENCY_OFF);
    bench.global(Mti::PRODUCER_CONSUMER_EVENT_REPORT, CLEAR_EMERGENCY_STOP);
    assert_eq!(bench.speeds().2, 0x8000);
    let state = bench.node.train().unwrap();
    assert!(state.global_off && !state.global_stop);
}

#[test]
fn functions_are_set_queried_and_bounded() {
    let mut bench = Bench::dcc(3);
    assert!(bench.command(&[0x01, 0, 0, 0, 0, 1]).is_empty());
    assert_eq!(bench.ask(&[0x11, 0, 0, 0]), vec![0x11, 0, 0, 0, 0, 1]);
    assert_eq!(bench.node.train_function(0), Some(1));
    assert!(bench.events.iter().any(|e| e.change == TrainChange::Function { address: 0, value: 1 }));
    assert!(bench.command(&[0x01, 0, 0, 68, 0, 1]).is_empty());
    // Past F68 (the default bound), both are rejected: 0x1080.
    assert_eq!(oir_code(&bench.command(&[0x01, 0, 0, 69, 0, 1])), 0x1080);
    assert_eq!(oir_code(&bench.command(&[0x11, 0x01, 0, 0])), 0x1080);
}

/// The bench's train with a memory server (its FDI), as `lcc-stream train` serves it.
fn train_with_memory() -> Bench {
    let mut bench = Bench::dcc(3);
    let functions = [FunctionName { number: 0, name: "Headlight".into(), kind: FunctionKind::Binary }];
    bench.node.set_memory_server(MemoryServer::new().with_space(0xFA, fdi_space(&functions)));
    bench
}

impl Bench {
    /// The datagrams `payload` from `from` gets back (its Received OK acknowledged), each
    /// with the answer's MTI.
    fn datagram_from(&mut self, from: NodeId, payload: &[u8]) -> Vec<(Mti, Vec<u8>)> {
        self.sent.clear();
        let msg = Message::addressed(Mti::DATAGRAM, from, DUT, payload.to_vec());
        self.node.handle_message(self.now, msg.as_ref());
        self.drain();
        let mut answers = Vec::new();
        for m in self.take() {
            if m.mti == Mti::DATAGRAM {
                let ok = Message::addressed(Mti::DATAGRAM_RECEIVED_OK, from, DUT, vec![0]);
                self.node.handle_message(self.now, ok.as_ref());
            }
            answers.push((m.mti, m.payload.to_vec()));
        }
        self.drain();
        answers
    }

    /// The reply datagram of a Memory Configuration command.
    fn memory(&mut self, payload: &[u8]) -> Vec<u8> {
        let answers = self.datagram_from(TOOL, payload);
        let replies: Vec<_> = answers.iter().filter(|(mti, _)| *mti == Mti::DATAGRAM).collect();
        assert_eq!(replies.len(), 1, "{answers:?}");
        replies[0].1.clone()
    }
}

#[test]
fn space_0xf9_holds_a_byte_per_function_read_and_written_as_set_function() {
    let mut bench = train_with_memory();
    // Get Address Space Information: F0-F68, 69 bytes, writable.
    let info = bench.memory(&[0x20, 0x84, 0xF9]);
    assert_eq!(&info[..7], &[0x20, 0x87, 0xF9, 0, 0, 0, 68], "{info:02X?}");
    assert_eq!(info[7] & 0x01, 0, "read-only flag: {info:02X?}");
    // Set Function F2 = 1 and F5 = 300: the space shows 1 and 255 (Train Control §7.1).
    assert!(bench.command(&[0x01, 0, 0, 2, 0, 1]).is_empty());
    assert!(bench.command(&[0x01, 0, 0, 5, 0x01, 0x2C]).is_empty());
    let read = bench.memory(&[0x20, 0x40, 0, 0, 0, 0, 0xF9, 8]);
    assert_eq!(read, vec![0x20, 0x50, 0, 0, 0, 0, 0xF9, 0, 0, 1, 0, 0, 255, 0, 0]);
    // A throttle's write (OpenLCB_Java's ThrottleFunctionDatagram: F3 on) is a Set Function
    // from it: told to the application, answered by Query Function, forwarded to a listener
    // linked to Fn, and F5's unchanged 255 leaves its 300 alone.
    let listener = with_node(&[0x30, 0x01, LISTENER_LINK_FN], LISTENER_A);
    bench.command(&listener);
    bench.events.clear();
    let answers = bench.datagram_from(TOOL, &[0x20, 0x00, 0, 0, 0, 3, 0xF9, 1, 0, 255]);
    assert!(answers.iter().any(|(mti, _)| *mti == Mti::DATAGRAM_RECEIVED_OK), "{answers:?}");
    assert_eq!(
        bench.events,
        vec![TrainEvent { change: TrainChange::Function { address: 3, value: 1 }, from: Some(TOOL) }]
    );
    assert_eq!(bench.ask(&[0x11, 0, 0, 3]), vec![0x11, 0, 0, 3, 0, 1]);
    assert_eq!(bench.node.train_function(5), Some(300));
    let sent = bench.datagram_from(TOOL, &[0x20, 0x00, 0, 0, 0, 3, 0xF9, 0]);
    let forwarded: Vec<_> = sent.iter().filter(|(mti, _)| *mti == Mti::TRACTION_CONTROL_COMMAND).collect();
    assert_eq!(forwarded, vec![&(Mti::TRACTION_CONTROL_COMMAND, vec![0x81, 0, 0, 3, 0, 0])]);
    // Past F68: out of bounds, nothing changes.
    let refused = bench.memory(&[0x20, 0x00, 0, 0, 0, 69, 0xF9, 1]);
    assert_eq!(refused[1], 0x18, "write failed: {refused:02X?}");
}

#[test]
fn an_applications_own_space_0xf9_is_left_alone() {
    let mut bench = Bench::dcc(3);
    let own = openlcb_node::memconfig::RamSpace::new(4);
    bench.node.set_memory_server(MemoryServer::new().with_space(0xF9, own));
    assert!(bench.command(&[0x01, 0, 0, 1, 0, 1]).is_empty());
    let read = bench.memory(&[0x20, 0x40, 0, 0, 0, 0, 0xF9, 4]);
    assert_eq!(read, vec![0x20, 0x50, 0, 0, 0, 0, 0xF9, 0, 0, 0, 0]);
}

#[test]
fn bad_commands_get_the_standards_reject_never_a_panic() {
    let mut bench = Bench::dcc(3);
    assert_eq!(oir_code(&bench.command(&[])), 0x1080);
    assert_eq!(oir_code(&bench.command(&[0x00, 0x3E])), 0x1080);
    assert_eq!(oir_code(&bench.command(&[0x20, 0x01, 0x00, 1, 2])), 0x1080);
    assert_eq!(oir_code(&bench.command(&[0x07])), 0x1041);
    assert_eq!(oir_code(&bench.command(&[0x40, 0x07])), 0x1041);
    assert_eq!(oir_code(&bench.command(&[0x90])), 0x1041);
    assert_eq!(oir_code(&bench.command(&with_node(&[0x20, 0x04, 0], OTHER))), 0x1041);
    // Every payload of up to three bytes, and long ones: answered or rejected.
    for a in 0..=255u8 {
        for b in [0u8, 1, 2, 3, 4, 0x7F, 0xFF] {
            let _ = bench.command(&[a, b]);
            let _ = bench.command(&[a, b, 0xFF]);
            let _ = bench.command(&[a, b, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0]);
        }
    }
    assert!(bench.node.train_stats().rejected > 100);
}

// ----- controller -----

#[test]
fn a_new_controller_is_assigned_and_the_old_one_told() {
    let mut bench = Bench::dcc(3);
    assert_eq!(bench.ask(&[0x20, 0x03]), vec![0x20, 0x03, 0, 0, 0, 0, 0, 0, 0]);
    assert_eq!(bench.ask(&with_node(&[0x20, 0x01, 0], TOOL)), vec![0x20, 0x01, 0]);
    assert_eq!(bench.ask(&[0x20, 0x03]), with_node(&[0x20, 0x03, 1], TOOL));
    // Another throttle takes over: accepted, and the old controller notified.
    let sent = bench.command_from(OTHER, &with_node(&[0x20, 0x01, 0], OTHER));
    assert_eq!(sent.len(), 2, "{sent:?}");
    assert_eq!(sent[0].mti, Mti::TRACTION_CONTROL_COMMAND);
    assert_eq!(sent[0].destination, Some(TOOL));
    assert_eq!(sent[0].payload, with_node(&[0x20, 0x04, 0], OTHER));
    assert_eq!(sent[1].payload, vec![0x20, 0x01, 0]);
    assert!(
        bench
            .events
            .iter()
            .any(|e| e.change == TrainChange::ControllerAssigned { controller: OTHER, previous: Some(TOOL) })
    );
    // The old controller cannot release what it no longer holds; the new one can.
    assert!(bench.command(&with_node(&[0x20, 0x02, 0], TOOL)).is_empty());
    assert_eq!(bench.node.train().unwrap().controller, Some(OTHER));
    assert!(bench.command_from(OTHER, &with_node(&[0x20, 0x02, 0], OTHER)).is_empty());
    assert_eq!(bench.node.train().unwrap().controller, None);
    // The old controller's answer to the notify is taken quietly (no OIR).
    let reply = Message::addressed(Mti::TRACTION_CONTROL_REPLY, TOOL, DUT, vec![0x20, 0x04, 0]);
    bench.node.handle_message(bench.now, reply.as_ref());
    bench.drain();
    assert!(bench.take().is_empty());
}

#[test]
fn a_reservation_is_held_by_one_node_and_refuses_other_assigns() {
    let mut bench = Bench::dcc(3);
    assert_eq!(bench.ask(&[0x40, 0x01]), vec![0x40, 0x01, 0]);
    assert_eq!(bench.ask(&[0x40, 0x01]), vec![0x40, 0x01, 0]);
    let sent = bench.command_from(OTHER, &[0x40, 0x01]);
    assert_eq!(sent[0].payload[..2], [0x40, 0x01]);
    assert_ne!(sent[0].payload[2], 0);
    let sent = bench.command_from(OTHER, &with_node(&[0x20, 0x01, 0], OTHER));
    assert_eq!(sent[0].payload, vec![0x20, 0x01, 0x02]);
    assert!(bench.command(&[0x40, 0x02]).is_empty());
    assert_eq!(bench.command_from(OTHER, &[0x40, 0x01])[0].payload, vec![0x40, 0x01, 0]);
    // A restart of the holder ends its reservation.
    let init = Message::initialization_complete(OTHER);
    bench.node.handle_message(bench.now, init.as_ref());
    bench.drain();
    assert_eq!(bench.node.train().unwrap().reserved_by, None);
}

// ----- listeners -----

#[test]
fn listeners_attach_update_detach_and_are_queried_in_order() {
    let mut bench = Bench::dcc(3);
    assert_eq!(bench.ask(&[0x30, 0x03, 0]), vec![0x30, 0x03, 0]);
    let ok = |node| {
        let mut v = with_node(&[0x30, 0x01], node);
        v.extend([0, 0]);
        v
    };
    assert_eq!(bench.ask(&with_node(&[0x30, 0x01, LISTENER_REVERSE], LISTENER_A)), ok(LISTENER_A));
    assert_eq!(bench.ask(&with_node(&[0x30, 0x01, LISTENER_LINK_F0], LISTENER_B)), ok(LISTENER_B));
    // Updating A's flags keeps its place.
    assert_eq!(bench.ask(&with_node(&[0x30, 0x01, LISTENER_REVERSE | LISTENER_LINK_FN], LISTENER_A)), ok(LISTENER_A));
    assert_eq!(
        bench.ask(&[0x30, 0x03, 0]),
        with_node(&[0x30, 0x03, 2, 0, LISTENER_REVERSE | LISTENER_LINK_FN], LISTENER_A)
    );
    assert_eq!(bench.ask(&[0x30, 0x03, 1]), with_node(&[0x30, 0x03, 2, 1, LISTENER_LINK_F0], LISTENER_B));
    assert_eq!(bench.ask(&[0x30, 0x03, 2]), vec![0x30, 0x03, 2]);
    assert_eq!(bench.ask(&[0x30, 0x03]), vec![0x30, 0x03, 2]);
    let mut detach_a = with_node(&[0x30, 0x02], LISTENER_A);
    detach_a.extend([0, 0]);
    assert_eq!(bench.ask(&with_node(&[0x30, 0x02, 0], LISTENER_A)), detach_a);
    let mut not_found = with_node(&[0x30, 0x02], LISTENER_A);
    not_found.extend([0x10, 0x30]);
    assert_eq!(bench.ask(&with_node(&[0x30, 0x02, 0], LISTENER_A)), not_found);
    // The train itself cannot listen to itself: already exists.
    let mut itself = with_node(&[0x30, 0x01], DUT);
    itself.extend([0x10, 0x32]);
    assert_eq!(bench.ask(&with_node(&[0x30, 0x01, 0], DUT)), itself);
}

#[test]
fn a_flood_of_attaches_cannot_grow_the_table_past_its_bound() {
    let mut config = TrainConfig::dcc(3);
    config.max_listeners = 4;
    let mut bench = Bench::new(config);
    for i in 0..100u64 {
        let node = NodeId::new(0x0501_0101_3000 + i).unwrap();
        let reply = bench.ask(&with_node(&[0x30, 0x01, 0], node));
        let code = u16::from_be_bytes([reply[8], reply[9]]);
        assert_eq!(code, if i < 4 { 0 } else { 0x2020 });
    }
    assert_eq!(bench.node.train().unwrap().listeners, 4);
    assert_eq!(bench.ask(&[0x30, 0x03]), vec![0x30, 0x03, 4]);
}

#[test]
fn commands_are_forwarded_to_listeners_as_their_flags_say_never_back() {
    let mut bench = Bench::dcc(3);
    bench.ask(&with_node(&[0x30, 0x01, LISTENER_REVERSE | LISTENER_LINK_F0], LISTENER_A));
    bench.ask(&with_node(&[0x30, 0x01, LISTENER_LINK_FN], LISTENER_B));
    let forwarded = |sent: &[Message]| -> Vec<(NodeId, Vec<u8>)> {
        sent.iter()
            .filter(|m| m.mti == Mti::TRACTION_CONTROL_COMMAND)
            .map(|m| (m.destination.unwrap(), m.payload.to_vec()))
            .collect()
    };
    let sent = bench.command(&[0x00, 0x3E, 0x4C]);
    assert_eq!(forwarded(&sent), vec![(LISTENER_A, vec![0x80, 0xBE, 0x4C]), (LISTENER_B, vec![0x80, 0x3E, 0x4C])]);
    let sent = bench.command(&[0x01, 0, 0, 0, 0, 1]);
    assert_eq!(forwarded(&sent), vec![(LISTENER_A, vec![0x81, 0, 0, 0, 0, 1])]);
    let sent = bench.command(&[0x01, 0, 0, 2, 0, 1]);
    assert_eq!(forwarded(&sent), vec![(LISTENER_B, vec![0x81, 0, 0, 2, 0, 1])]);
    let sent = bench.command(&[0x02]);
    assert_eq!(forwarded(&sent), vec![(LISTENER_A, vec![0x82]), (LISTENER_B, vec![0x82])]);
    // A command from a listener (P set, in a consist) is carried out and goes to the others.
    let sent = bench.command_from(LISTENER_A, &[0x80, 0xBC, 0x00]);
    assert_eq!(forwarded(&sent), vec![(LISTENER_B, vec![0x80, 0xBC, 0x00])]);
    assert_eq!(bench.node.train().unwrap().set_speed, Speed::from_bits(0xBC00));
    // Queries are not forwarded.
    assert!(forwarded(&bench.command(&[0x10])).is_empty());
    assert!(bench.node.train_stats().forwarded >= 7);
}

// ----- heartbeat -----

fn heartbeat_requests(sent: &[Message]) -> usize {
    sent.iter().filter(|m| m.mti == Mti::TRACTION_CONTROL_REPLY && m.payload == [0x40, 0x03, 3]).count()
}

#[test]
fn heartbeat_is_asked_while_running_and_a_silent_controller_stops_the_train() {
    let mut bench = Bench::dcc(3);
    bench.ask(&with_node(&[0x30, 0x01, 0], LISTENER_A));
    bench.ask(&with_node(&[0x20, 0x01, 0], TOOL));
    bench.command(&[0x00, 0x3E, 0x4C]);
    bench.advance(Duration::from_millis(1400));
    assert_eq!(heartbeat_requests(&bench.take()), 0);
    bench.advance(Duration::from_millis(200));
    assert_eq!(heartbeat_requests(&bench.take()), 1);
    // A No-op answers it: the next one comes 1.5 s later, and the train runs on.
    assert!(bench.command(&[0x40, 0x03]).is_empty());
    bench.advance(Duration::from_millis(2900));
    assert_eq!(bench.speeds().0, 0x3E4C);
    // That query answered the second request too; now the controller falls silent.
    bench.advance(Duration::from_millis(1500));
    assert_eq!(heartbeat_requests(&bench.take()), 1);
    bench.advance(Duration::from_millis(2900));
    assert_eq!(bench.node.train().unwrap().set_speed, Speed::from_bits(0x3E4C));
    bench.advance(Duration::from_millis(200));
    let sent = bench.take();
    assert!(sent.iter().any(|m| m.destination == Some(LISTENER_A) && m.payload == [0x80, 0x00, 0x00]), "{sent:?}");
    assert_eq!(bench.node.train().unwrap().set_speed, Speed::ZERO_FORWARD);
    assert!(bench.events.iter().any(|e| e.change == TrainChange::HeartbeatTimedOut(TOOL)));
    assert_eq!(bench.node.train_stats().heartbeat_timeouts, 1);
    // Standing, nothing is asked.
    bench.advance(Duration::from_secs(10));
    assert_eq!(heartbeat_requests(&bench.take()), 0);
}

#[test]
fn no_heartbeat_when_stopped_stopped_by_e_stop_or_without_controller() {
    let mut bench = Bench::dcc(3);
    bench.set_speed(0x3E4C);
    bench.advance(Duration::from_secs(10));
    assert_eq!(heartbeat_requests(&bench.take()), 0, "no controller");
    assert_eq!(bench.speeds().0, 0x3E4C);
    bench.ask(&with_node(&[0x20, 0x01, 0], TOOL));
    bench.command(&[0x02]);
    bench.advance(Duration::from_secs(10));
    assert_eq!(heartbeat_requests(&bench.take()), 0, "e-stop");
    bench.set_speed(0x3E4C);
    bench.command(&with_node(&[0x20, 0x02, 0], TOOL));
    bench.advance(Duration::from_secs(10));
    assert_eq!(heartbeat_requests(&bench.take()), 0, "released");
    assert_eq!(bench.speeds().0, 0x3E4C, "a released train runs on as last commanded");
    let mut config = TrainConfig::dcc(3);
    config.heartbeat = None;
    let mut bench = Bench::new(config);
    bench.ask(&with_node(&[0x20, 0x01, 0], TOOL));
    bench.set_speed(0x3E4C);
    bench.advance(Duration::from_secs(10));
    assert_eq!(heartbeat_requests(&bench.take()), 0, "heartbeat off");
}

// ----- train search -----

#[test]
fn searches_that_match_are_answered_and_allocation_is_handed_to_the_application() {
    let mut config = TrainConfig::dcc(3);
    config.allocate = true;
    let mut bench = Bench::new(config);
    for (event, answered) in [
        (0x090099FF_FFFFF360u64, true),
        (0x090099FF_3FFFFF20, true),
        (0x090099FF_12FFFF60, false),
        (0x090099FF_FFFFFCE0, false),
        (0x090099FF_FFFF03F0, false),
    ] {
        let sent = bench.global(Mti::IDENTIFY_PRODUCER, EventId(event));
        assert_eq!(
            sent.iter().any(|m| m.mti == Mti::PRODUCER_IDENTIFIED_VALID && m.payload == event.to_be_bytes()),
            answered,
            "{event:X}"
        );
    }
    bench.events.clear();
    let search = EventId(0x090099FF_FFFF12E0);
    assert!(bench.global(Mti::IDENTIFY_PRODUCER, search).is_empty());
    assert_eq!(
        bench.events,
        vec![TrainEvent {
            change: TrainChange::Allocate { event: search, address: 12, protocol: TrainProtocol::Dcc { long: false } },
            from: Some(TOOL)
        }]
    );
    // Reserved values allocate nothing.
    bench.events.clear();
    bench.global(Mti::IDENTIFY_PRODUCER, EventId(0x090099FF_FFFFFCE0));
    assert!(bench.events.is_empty());
    assert_eq!(bench.node.answer_train_search(search), Err(TrainError::NoMatch));

    // The train created for it answers the search, and does not announce Is Train first.
    let mut created = TrainConfig::dcc(12);
    created.announce = false;
    let mut train = Bench::new(created);
    assert!(train.take().iter().all(|m| m.mti != Mti::PRODUCER_IDENTIFIED_VALID));
    train.node.answer_train_search(search).unwrap();
    train.drain();
    let sent = train.take();
    assert_eq!(sent.len(), 1);
    assert_eq!(sent[0].payload, search.to_bytes());
    assert_eq!(SearchQuery::event_for(12, 0xE0), Some(search));
}

#[test]
fn a_train_that_does_not_allocate_ignores_allocate_searches() {
    let mut bench = Bench::dcc(3);
    bench.events.clear();
    assert!(bench.global(Mti::IDENTIFY_PRODUCER, EventId(0x090099FF_FFFF12E0)).is_empty());
    assert!(bench.events.is_empty());
}

#[test]
fn a_listener_loop_with_a_reversed_listener_settles() {
    // A listens to B (reversed), B to C, C to A: a throttle's speed goes round once.
    let ids = [LISTENER_A, LISTENER_B, OTHER];
    let mut nodes: Vec<Node> = ids
        .iter()
        .map(|id| {
            let mut config = NodeConfig::default();
            config.train = Some(TrainConfig::dcc(3));
            Node::new(*id, config)
        })
        .collect();
    let now = Instant::from_secs(1);
    for (i, flags) in [(0, LISTENER_REVERSE), (1, 0), (2, 0)] {
        let attach = Message::addressed(
            Mti::TRACTION_CONTROL_COMMAND,
            TOOL,
            ids[i],
            with_node(&[0x30, 0x01, flags], ids[(i + 1) % 3]),
        );
        nodes[i].handle_message(now, attach.as_ref());
    }
    let set = Message::addressed(Mti::TRACTION_CONTROL_COMMAND, TOOL, ids[0], vec![0x00, 0x3E, 0x4C]);
    nodes[0].handle_message(now, set.as_ref());
    let mut rounds = 0;
    loop {
        let mut moved = false;
        for i in 0..3 {
            while let Some(m) = nodes[i].poll_transmit() {
                if let Some(j) = ids.iter().position(|id| Some(*id) == m.destination) {
                    nodes[j].handle_message(now, m.as_ref());
                    moved = true;
                }
            }
        }
        rounds += 1;
        assert!(rounds < 10, "the loop circulates");
        if !moved {
            break;
        }
    }
    let speeds: Vec<u16> = nodes.iter().map(|n| n.train().unwrap().set_speed.to_bits()).collect();
    assert_eq!(speeds, vec![0x3E4C, 0xBE4C, 0xBE4C]);
    assert_eq!(nodes[0].train_stats().loops_cut, 1);
}

// ----- the throttle side -----

use openlcb_node::traction::{ThrottleConfig, ThrottleError, ThrottleEvent, TractionCommand};

/// A train and throttles back to back, on a virtual clock.
struct Layout {
    nodes: Vec<Node>,
    now: Instant,
    events: Vec<(usize, ThrottleEvent)>,
}

impl Layout {
    /// Node 0 is a DCC 3 train; nodes 1.. are throttles.
    fn new(throttles: usize, config: ThrottleConfig) -> Self {
        let mut nodes = vec![Node::new(DUT, {
            let mut c = NodeConfig::default();
            c.train = Some(TrainConfig::dcc(3));
            c
        })];
        for i in 0..throttles {
            let mut c = NodeConfig::default();
            c.throttle = Some(config.clone());
            nodes.push(Node::new(NodeId::new(0x0501_0101_2250 + i as u64).unwrap(), c));
        }
        let mut layout = Layout { nodes, now: Instant::from_secs(1), events: Vec::new() };
        layout.run(Duration::ZERO);
        layout
    }

    fn id(&self, i: usize) -> NodeId {
        self.nodes[i].node_id()
    }

    fn send(&mut self, from: usize, command: TractionCommand) -> Result<(), ThrottleError> {
        let train = self.id(0);
        let result = self.nodes[from].throttle_command(train, command);
        self.run(Duration::ZERO);
        result
    }

    /// Passes every message to its destination (or everyone), with the timers, for `span`.
    fn run(&mut self, span: Duration) {
        let end = self.now + span;
        loop {
            for _ in 0..32 {
                let mut moved = false;
                for i in 0..self.nodes.len() {
                    self.nodes[i].handle_timeout(self.now);
                    while let Some(m) = self.nodes[i].poll_transmit() {
                        for j in 0..self.nodes.len() {
                            if j != i && m.destination.is_none_or(|d| d == self.nodes[j].node_id()) {
                                self.nodes[j].handle_message(self.now, m.as_ref());
                                moved = true;
                            }
                        }
                    }
                    while let Some(e) = self.nodes[i].poll_event() {
                        if let NodeEvent::Throttle(e) = e {
                            self.events.push((i, e));
                        }
                    }
                }
                if !moved {
                    break;
                }
            }
            let next = self.nodes.iter().filter_map(Node::poll_timeout).min();
            match next {
                Some(due) if due <= end && due > self.now => self.now = due,
                _ => break,
            }
        }
        self.now = end;
    }
}

#[test]
fn a_throttle_assigns_drives_and_keeps_its_train_alive_with_heartbeats() {
    let mut layout = Layout::new(1, ThrottleConfig::default());
    let me = layout.id(1);
    layout.send(1, TractionCommand::AssignController { flags: 0, node: me }).unwrap();
    assert!(layout.events.contains(&(1, ThrottleEvent::Assigned { train: DUT })));
    assert_eq!(layout.nodes[1].controlled_trains(), &[DUT]);
    layout.send(1, TractionCommand::SetSpeed { speed: Speed::from_f32(-1.5), forwarded: false }).unwrap();
    layout.send(1, TractionCommand::SetFunction { address: 0, value: 1, forwarded: false }).unwrap();
    // Twenty silent seconds: the throttle answers every heartbeat request, the train runs on.
    layout.run(Duration::from_secs(20));
    let requests = layout.events.iter().filter(|(_, e)| matches!(e, ThrottleEvent::HeartbeatRequested { .. })).count();
    assert!(requests >= 10, "{requests} heartbeat requests");
    assert_eq!(layout.nodes[0].train_stats().heartbeat_timeouts, 0);
    layout.events.clear();
    layout.send(1, TractionCommand::QuerySpeeds).unwrap();
    layout.send(1, TractionCommand::QueryFunction { address: 0 }).unwrap();
    layout.send(1, TractionCommand::QueryController).unwrap();
    let speed = Speed::from_f32(-1.5);
    assert_eq!(
        layout.events,
        vec![
            (
                1,
                ThrottleEvent::Speeds {
                    train: DUT,
                    set: speed,
                    emergency_stop: false,
                    commanded: speed,
                    actual: Speed::NAN
                }
            ),
            (1, ThrottleEvent::Function { train: DUT, address: 0, value: 1 }),
            (1, ThrottleEvent::Controller { train: DUT, controller: Some(me) }),
        ]
    );
    layout.send(1, TractionCommand::ReleaseController { flags: 0, node: me }).unwrap();
    assert!(layout.nodes[1].controlled_trains().is_empty());
    assert_eq!(layout.nodes[0].train().unwrap().controller, None);
}

#[test]
fn a_throttle_without_heartbeat_answers_loses_the_train_and_one_taken_over_is_told() {
    let mut quiet = ThrottleConfig::default();
    quiet.answer_heartbeats = false;
    let mut layout = Layout::new(2, quiet);
    let (first, second) = (layout.id(1), layout.id(2));
    layout.send(1, TractionCommand::AssignController { flags: 0, node: first }).unwrap();
    layout.send(1, TractionCommand::SetSpeed { speed: Speed::from_f32(2.0), forwarded: false }).unwrap();
    layout.run(Duration::from_secs(6));
    assert_eq!(layout.nodes[0].train().unwrap().set_speed, Speed::ZERO_FORWARD, "stopped by the heartbeat");
    // The second throttle takes over: the first is told and lets go.
    layout.send(2, TractionCommand::AssignController { flags: 0, node: second }).unwrap();
    assert!(layout.events.contains(&(1, ThrottleEvent::ControllerLost { train: DUT, to: second })));
    assert!(layout.events.contains(&(2, ThrottleEvent::Assigned { train: DUT })));
    assert!(layout.nodes[1].controlled_trains().is_empty());
    // Consist edits and rejects reach the throttle.
    layout.events.clear();
    layout.send(2, TractionCommand::AttachListener { flags: LISTENER_REVERSE, node: LISTENER_A }).unwrap();
    layout.send(2, TractionCommand::QueryListeners { index: Some(0) }).unwrap();
    layout.send(2, TractionCommand::QueryFunction { address: 500 }).unwrap();
    assert_eq!(
        layout.events,
        vec![
            (2, ThrottleEvent::ListenerChanged { train: DUT, listener: LISTENER_A, attached: true, code: 0 }),
            (2, ThrottleEvent::Listener { train: DUT, count: 1, entry: Some((0, LISTENER_REVERSE, LISTENER_A)) }),
            (2, ThrottleEvent::Rejected { train: DUT, code: openlcb_stream::wire::ErrorCode::INVALID_ARGUMENTS }),
        ]
    );
}

#[test]
fn a_throttle_controls_no_more_trains_than_its_bound() {
    let mut one = ThrottleConfig::default();
    one.max_trains = 1;
    let mut layout = Layout::new(1, one);
    let me = layout.id(1);
    layout.send(1, TractionCommand::AssignController { flags: 0, node: me }).unwrap();
    let other = NodeId::new(0x0501_0101_2299).unwrap();
    let assign = TractionCommand::AssignController { flags: 0, node: me };
    assert_eq!(layout.nodes[1].throttle_command(other, assign), Err(ThrottleError::TooManyTrains));
    let mut plain = Node::new(TOOL, NodeConfig::default());
    assert_eq!(plain.throttle_command(DUT, TractionCommand::QuerySpeeds), Err(ThrottleError::NotAThrottle));
}

#[test]
fn a_vanished_train_is_reported_to_its_throttle_and_no_longer_controlled() {
    let mut layout = Layout::new(2, ThrottleConfig::default());
    let me = layout.id(1);
    layout.send(1, TractionCommand::AssignController { flags: 0, node: me }).unwrap();
    assert_eq!(layout.nodes[1].controlled_trains(), [DUT]);
    layout.events.clear();
    // Another node leaving tells nothing; the train leaving (its alias released on CAN) does,
    // to the throttle that controls it only.
    layout.nodes[1].peer_changed(PeerChange::Lost(NodeId::new(0x0501_0101_2299).unwrap()));
    layout.nodes[2].peer_changed(PeerChange::Lost(DUT));
    layout.nodes[1].peer_changed(PeerChange::Lost(DUT));
    layout.run(Duration::ZERO);
    assert_eq!(layout.events, vec![(1, ThrottleEvent::TrainLost { train: DUT })]);
    assert!(layout.nodes[1].controlled_trains().is_empty());
    // A train assigned again and this node's own link lost: the same word.
    layout.send(1, TractionCommand::AssignController { flags: 0, node: me }).unwrap();
    layout.events.clear();
    layout.nodes[1].link_lost();
    layout.run(Duration::ZERO);
    assert_eq!(layout.events, vec![(1, ThrottleEvent::TrainLost { train: DUT })]);
}
