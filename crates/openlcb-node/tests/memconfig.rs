//! Memory Configuration server and client back to back, messages passed directly (the
//! loopback harness tests the same over CAN, OpenLCB-TCP and a gateway).

use openlcb_node::memconfig::wire::{Command, Reply};
use openlcb_node::{
    MemoryError, MemoryEvent, MemoryServer, Node, NodeCommand, NodeConfig, NodeEvent, Protocols, RamSpace,
    ReadOnlySpace, TransferPath,
};
use openlcb_stream::{Duration, Instant, Message, Mti, NodeId, OpenOptions, PeerChange};

const CLIENT: NodeId = NodeId::from_bytes([5, 1, 1, 1, 0x40, 1]);
const SERVER: NodeId = NodeId::from_bytes([5, 1, 1, 1, 0x40, 2]);

fn pattern(len: usize, key: u8) -> Vec<u8> {
    (0..len).map(|i| (i as u8).wrapping_mul(31).wrapping_add(key) ^ (i >> 8) as u8).collect()
}

fn server_with(config: NodeConfig, space_len: u32) -> Node {
    let server = MemoryServer::new()
        .with_space(0xFD, RamSpace::from_bytes(pattern(space_len as usize, 7)))
        .with_space(0xFF, ReadOnlySpace::cdi("<?xml version=\"1.0\"?><cdi/>"))
        .with_space(0xEF, RamSpace::new(128 * 1024))
        .with_acdi()
        .with_unique_ids([[5, 1, 1, 1, 0x40, 2, 0, 1], [5, 1, 1, 1, 0x40, 2, 0, 2]]);
    Node::new(SERVER, config).with_memory_server(server)
}

/// Two nodes passing messages back and forth on a clock that jumps to the next timer when
/// nothing moves.
struct Pair {
    now: Instant,
    client: Node,
    server: Node,
    events: Vec<NodeEvent>,
    server_events: Vec<NodeEvent>,
    /// Drop the n-th message the server sends (counting from 1), once.
    drop_server_message: Option<(usize, Mti)>,
    server_sent: usize,
}

impl Pair {
    fn new(client: NodeConfig, server: Node) -> Self {
        Pair {
            now: Instant::ZERO,
            client: Node::new(CLIENT, client),
            server,
            events: Vec::new(),
            server_events: Vec::new(),
            drop_server_message: None,
            server_sent: 0,
        }
    }

    fn pump(&mut self) {
        for _ in 0..1_000_000 {
            let mut moved = false;
            while let Some(m) = self.client.poll_transmit() {
                self.server.handle_message(self.now, m.as_ref());
                moved = true;
            }
            while let Some(m) = self.server.poll_transmit() {
                moved = true;
                if let Some((n, mti)) = self.drop_server_message
                    && m.mti == mti
                {
                    self.server_sent += 1;
                    if self.server_sent == n {
                        continue;
                    }
                }
                self.client.handle_message(self.now, m.as_ref());
            }
            let before = self.events.len() + self.server_events.len();
            self.events.extend(std::iter::from_fn(|| self.client.poll_event()));
            self.server_events.extend(std::iter::from_fn(|| self.server.poll_event()));
            moved |= self.events.len() + self.server_events.len() > before;
            if !moved {
                return;
            }
        }
        panic!("never idle");
    }

    /// Runs until the client raises a final memory event, or a minute of virtual time.
    fn finish(&mut self) -> MemoryEvent {
        let end = self.now + Duration::from_secs(120);
        loop {
            self.pump();
            if let Some(i) = self.events.iter().position(|e| {
                matches!(
                    e,
                    NodeEvent::Memory(
                        MemoryEvent::ReadDone { .. } | MemoryEvent::WriteDone { .. } | MemoryEvent::Failed { .. }
                    )
                )
            }) {
                let NodeEvent::Memory(event) = self.events.remove(i) else { unreachable!() };
                return event;
            }
            let next = [self.client.poll_timeout(), self.server.poll_timeout()].into_iter().flatten().min();
            match next {
                Some(t) if t <= end => {
                    self.now = self.now.max(t);
                    self.client.handle_timeout(self.now);
                    self.server.handle_timeout(self.now);
                }
                _ => panic!("hang: nothing ended by {:?}; events {:?}", self.now, self.events),
            }
        }
    }
}

fn read_back(node: &mut Node, space: u8) -> Vec<u8> {
    let s = node.memory_server_mut().unwrap().space_mut(space).unwrap();
    let mut buf = vec![0; s.len() as usize];
    let n = s.read(0, &mut buf).unwrap();
    buf.truncate(n);
    buf
}

impl Pair {
    /// No stream event of Memory Configuration's transfers reached either application.
    fn assert_no_stream_events(&self) {
        let leaked = self.events.iter().chain(&self.server_events).find(|e| matches!(e, NodeEvent::Stream(_)));
        assert!(leaked.is_none(), "{leaked:?}");
    }
}

fn read_all(path: TransferPath, len: Option<u32>) -> MemoryEvent {
    let mut pair = Pair::new(NodeConfig::default(), server_with(NodeConfig::default(), 4096));
    pair.pump();
    pair.client.read_memory(pair.now, SERVER, 0xFD, 0, len, path).unwrap();
    let end = pair.finish();
    pair.pump();
    pair.assert_no_stream_events();
    end
}

#[test]
fn read_by_datagrams_to_the_end_of_the_space() {
    match read_all(TransferPath::Datagrams, None) {
        MemoryEvent::ReadDone { data, .. } => assert_eq!(data, pattern(4096, 7)),
        other => panic!("{other:?}"),
    }
}

#[test]
fn read_by_stream_to_the_end_of_the_space() {
    match read_all(TransferPath::Stream, None) {
        MemoryEvent::ReadDone { data, .. } => assert_eq!(data, pattern(4096, 7)),
        other => panic!("{other:?}"),
    }
}

#[test]
fn read_auto_takes_the_stream_path_and_a_partial_range() {
    let mut pair = Pair::new(NodeConfig::default(), server_with(NodeConfig::default(), 4096));
    pair.pump();
    pair.client.read_memory(pair.now, SERVER, 0xFD, 100, Some(1000), TransferPath::Auto).unwrap();
    match pair.finish() {
        MemoryEvent::ReadDone { data, .. } => assert_eq!(data, pattern(4096, 7)[100..1100]),
        other => panic!("{other:?}"),
    }
    assert!(pair.server.memory_server().unwrap().stats().streams_done == 1, "the stream path was taken");
}

#[test]
fn read_auto_falls_back_to_datagrams_without_server_streams() {
    let mut config = NodeConfig::default();
    config.streams_enabled = false;
    let mut pair = Pair::new(NodeConfig::default(), server_with(config, 300));
    pair.pump();
    pair.client.read_memory(pair.now, SERVER, 0xFD, 0, None, TransferPath::Auto).unwrap();
    match pair.finish() {
        MemoryEvent::ReadDone { data, .. } => assert_eq!(data, pattern(300, 7)),
        other => panic!("{other:?}"),
    }
    assert_eq!(pair.server.memory_server().unwrap().stats().streams_done, 0);
}

#[test]
fn a_read_to_the_first_nul_hands_over_the_document_and_is_bounded() {
    let xml = b"<?xml version=\"1.0\"?><cdi/>";
    for path in [TransferPath::Datagrams, TransferPath::Stream] {
        let mut pair = Pair::new(NodeConfig::default(), server_with(NodeConfig::default(), 64));
        pair.pump();
        pair.client.read_memory_to_nul(pair.now, SERVER, 0xFF, 1024, path).unwrap();
        match pair.finish() {
            MemoryEvent::ReadDone { data, .. } => assert_eq!(data, xml, "{path:?}: up to the NUL, without it"),
            other => panic!("{path:?}: {other:?}"),
        }
        // A space that reports more than the bound is refused before a byte is read.
        pair.client.read_memory_to_nul(pair.now, SERVER, 0xFF, 10, path).unwrap();
        let size = xml.len() as u64 + 1;
        match pair.finish() {
            MemoryEvent::Failed { error: MemoryError::SpaceTooLarge { size: Some(s), limit: 10 }, .. } => {
                assert_eq!(s, size, "{path:?}");
            }
            other => panic!("{path:?}: {other:?}"),
        }
        assert_eq!(pair.server.memory_server().unwrap().stats().streams_done, u32::from(path == TransferPath::Stream));
    }
}

#[test]
fn a_cancelled_read_hands_over_what_it_has_and_ends_without_an_event() {
    let mut pair = Pair::new(NodeConfig::default(), server_with(NodeConfig::default(), 4096));
    pair.pump();
    let operation = pair.client.read_memory(pair.now, SERVER, 0xFD, 0, None, TransferPath::Datagrams).unwrap();
    assert_eq!(pair.client.cancel_memory(pair.now, operation), Some(Vec::new()), "nothing had arrived");
    assert_eq!(pair.client.cancel_memory(pair.now, operation), None, "it has ended");
    pair.pump();
    assert!(!pair.events.iter().any(|e| matches!(e, NodeEvent::Memory(_))), "{:?}", pair.events);
    // The next read with that node starts: the cancelled one holds nothing.
    pair.client.read_memory(pair.now, SERVER, 0xFD, 0, Some(100), TransferPath::Datagrams).unwrap();
    assert!(matches!(pair.finish(), MemoryEvent::ReadDone { data, .. } if data == pattern(4096, 7)[..100]));
}

fn write_then_verify(path: TransferPath) {
    let mut pair = Pair::new(NodeConfig::default(), server_with(NodeConfig::default(), 8192));
    pair.pump();
    let data = pattern(5000, 99);
    pair.client.write_memory(pair.now, SERVER, 0xFD, 1000, data.clone(), path).unwrap();
    match pair.finish() {
        MemoryEvent::WriteDone { len, .. } => assert_eq!(len, 5000),
        other => panic!("{other:?}"),
    }
    pair.pump();
    pair.assert_no_stream_events();
    let space = read_back(&mut pair.server, 0xFD);
    assert_eq!(&space[1000..6000], &data[..]);
    assert_eq!(&space[..1000], &pattern(8192, 7)[..1000]);
}

#[test]
fn write_by_datagrams_is_verified() {
    write_then_verify(TransferPath::Datagrams);
}

#[test]
fn write_by_stream_is_verified() {
    write_then_verify(TransferPath::Stream);
}

#[test]
fn firmware_upgrade_by_stream_and_by_datagrams() {
    // 100 000 bytes: the last window is a partial one.
    for (path, len) in
        [(TransferPath::Auto, 64 * 1024), (TransferPath::Datagrams, 64 * 1024), (TransferPath::Auto, 100_000)]
    {
        let mut pair = Pair::new(NodeConfig::default(), server_with(NodeConfig::default(), 16));
        pair.pump();
        assert!(pair.server.protocols().contains(Protocols::FIRMWARE_UPGRADE));
        let image = pattern(len, 3);
        pair.client.upgrade_firmware(pair.now, SERVER, image.clone(), path).unwrap();
        match pair.finish() {
            MemoryEvent::WriteDone { len: written, .. } => assert_eq!(written, len as u64),
            other => panic!("{other:?}"),
        }
        pair.pump();
        assert_eq!(&read_back(&mut pair.server, 0xEF)[..image.len()], &image[..]);
        assert!(!pair.server.memory_server().unwrap().is_frozen());
        assert!(pair.server.protocols().contains(Protocols::FIRMWARE_UPGRADE));
        let frozen = pair.server_events.iter().any(|e| matches!(e, NodeEvent::Memory(MemoryEvent::Frozen { .. })));
        let unfrozen = pair.server_events.iter().find_map(|e| match e {
            NodeEvent::Memory(MemoryEvent::Unfrozen { image_len, .. }) => Some(*image_len),
            _ => None,
        });
        assert!(frozen, "{path:?}");
        assert_eq!(unfrozen, Some(len as u32), "{path:?}, {len} bytes");
    }
}

#[test]
fn update_complete_ends_at_the_ok_and_reaches_the_server() {
    let mut pair = Pair::new(NodeConfig::default(), server_with(NodeConfig::default(), 16));
    pair.pump();
    pair.client.update_complete(pair.now, SERVER).unwrap();
    match pair.finish() {
        MemoryEvent::WriteDone { len, .. } => assert_eq!(len, 0),
        other => panic!("{other:?}"),
    }
    let told = pair
        .server_events
        .iter()
        .any(|e| matches!(e, NodeEvent::Memory(MemoryEvent::UpdateComplete { by }) if *by == CLIENT));
    assert!(told);
}

/// Reboot and Factory Reset from the client: each one datagram, done at the OK or the
/// restart; the Factory Reset names the server, which acts on it.
#[test]
fn reboot_and_factory_reset_reach_the_server_and_end() {
    for (command, told) in [
        (
            NodeCommand::Reboot,
            (|e: &MemoryEvent| matches!(e, MemoryEvent::ResetRequested { by } if *by == CLIENT))
                as fn(&MemoryEvent) -> bool,
        ),
        (NodeCommand::FactoryReset, |e| matches!(e, MemoryEvent::FactoryResetRequested { by } if *by == CLIENT)),
    ] {
        let mut pair = Pair::new(NodeConfig::default(), server_with(NodeConfig::default(), 16));
        pair.pump();
        pair.client.send_command(pair.now, SERVER, command).unwrap();
        match pair.finish() {
            MemoryEvent::WriteDone { len, .. } => assert_eq!(len, 0, "{command:?}"),
            other => panic!("{command:?}: {other:?}"),
        }
        let seen = pair.server_events.iter().any(|e| matches!(e, NodeEvent::Memory(m) if told(m)));
        assert!(seen, "{command:?}");
    }
}

#[test]
fn a_lost_read_reply_is_asked_for_again() {
    let mut pair = Pair::new(NodeConfig::default(), server_with(NodeConfig::default(), 640));
    pair.pump();
    // The server's third datagram (a Read Reply) is lost on the way.
    pair.drop_server_message = Some((3, Mti::DATAGRAM));
    pair.client.read_memory(pair.now, SERVER, 0xFD, 0, Some(640), TransferPath::Datagrams).unwrap();
    match pair.finish() {
        MemoryEvent::ReadDone { data, .. } => assert_eq!(data, pattern(640, 7)),
        other => panic!("{other:?}"),
    }
}

#[test]
fn errors_the_standard_names() {
    let mut pair = Pair::new(NodeConfig::default(), server_with(NodeConfig::default(), 64));
    pair.pump();
    pair.client.read_memory(pair.now, SERVER, 0x33, 0, Some(8), TransferPath::Datagrams).unwrap();
    assert!(matches!(pair.finish(), MemoryEvent::Failed { error: MemoryError::Rejected(c), .. } if c.0 == 0x1081));
    pair.client.write_memory(pair.now, SERVER, 0xFF, 0, vec![1], TransferPath::Datagrams).unwrap();
    assert!(matches!(pair.finish(), MemoryEvent::Failed { error: MemoryError::Rejected(c), .. } if c.0 == 0x1083));
    pair.client.read_memory(pair.now, SERVER, 0xFD, 64, Some(8), TransferPath::Datagrams).unwrap();
    assert!(matches!(pair.finish(), MemoryEvent::Failed { error: MemoryError::Failed(c), .. } if c.0 == 0x1082));
    pair.client.write_memory(pair.now, SERVER, 0xFD, 60, vec![1; 8], TransferPath::Datagrams).unwrap();
    assert!(matches!(pair.finish(), MemoryEvent::Failed { error: MemoryError::Failed(c), .. } if c.0 == 0x1082));
    // The firmware space is read-only outside the Firmware Upgrade state.
    pair.client.write_memory(pair.now, SERVER, 0xEF, 0, vec![1; 8], TransferPath::Stream).unwrap();
    assert!(matches!(pair.finish(), MemoryEvent::Failed { error: MemoryError::Rejected(c), .. } if c.0 == 0x1083));
    pair.client.read_memory(pair.now, SERVER, 0xFD, 60, Some(8), TransferPath::Stream).unwrap();
    assert!(matches!(pair.finish(), MemoryEvent::Failed { error: MemoryError::WrongLength { .. }, .. }));
}

#[test]
fn acdi_spaces_mirror_snip() {
    let mut config = NodeConfig::default();
    config.snip.manufacturer = "Acme".into();
    config.snip.user_name = "Yard".into();
    let mut pair = Pair::new(NodeConfig::default(), server_with(config, 64));
    pair.pump();
    pair.client.read_memory(pair.now, SERVER, 0xFC, 0, None, TransferPath::Datagrams).unwrap();
    let MemoryEvent::ReadDone { data, .. } = pair.finish() else { panic!() };
    assert_eq!(data.len(), 125);
    assert_eq!(&data[..6], b"\x04Acme\0");
    let mut name = b"West end".to_vec();
    name.push(0);
    pair.client.write_memory(pair.now, SERVER, 0xFB, 1, name, TransferPath::Datagrams).unwrap();
    assert!(matches!(pair.finish(), MemoryEvent::WriteDone { .. }));
    assert_eq!(pair.server.config().snip.user_name, "West end");
    pair.client.write_memory(pair.now, SERVER, 0xFC, 1, vec![0x41], TransferPath::Datagrams).unwrap();
    assert!(matches!(pair.finish(), MemoryEvent::Failed { error: MemoryError::Rejected(c), .. } if c.0 == 0x1083));
}

/// Sends one raw command from the client's node and returns the server's answers.
fn exchange(pair: &mut Pair, command: &[u8]) -> Vec<Message> {
    pair.pump();
    let now = pair.now;
    let msg = Message::addressed(Mti::DATAGRAM, CLIENT, SERVER, command.to_vec());
    pair.server.handle_message(now, msg.as_ref());
    let answers: Vec<Message> = std::iter::from_fn(|| pair.server.poll_transmit()).collect();
    // The client's node acknowledges the reply datagrams, so the next one can come.
    for answer in &answers {
        pair.client.handle_message(now, answer.as_ref());
    }
    pair.pump();
    answers
}

fn reply_of(answers: &[Message]) -> Option<Reply> {
    answers.iter().find(|m| m.mti == Mti::DATAGRAM).and_then(|m| Reply::parse(&m.payload).ok())
}

/// The reply datagram among `answers`, as bytes.
fn reply_bytes(answers: &[Message]) -> Vec<u8> {
    answers.iter().find(|m| m.mti == Mti::DATAGRAM).map(|m| m.payload.to_vec()).unwrap_or_default()
}

#[test]
fn every_command_is_answered_in_the_form_it_was_asked() {
    // OlcbChecker's mc30_read: a read naming 0xFD in byte 6 gets `20 50 addr FD data`.
    let mut pair = Pair::new(NodeConfig::default(), server_with(NodeConfig::default(), 64));
    let space = read_back(&mut pair.server, 0xFD);
    let long = reply_bytes(&exchange(&mut pair, &[0x20, 0x40, 0, 0, 0, 0, 0xFD, 2]));
    assert_eq!(long, [&[0x20, 0x50, 0, 0, 0, 0, 0xFD][..], &space[..2]].concat());
    let short = reply_bytes(&exchange(&mut pair, &[0x20, 0x41, 0, 0, 0, 0, 2]));
    assert_eq!(short, [&[0x20, 0x51, 0, 0, 0, 0][..], &space[..2]].concat());
    // Write, and a failed read, in both forms.
    assert_eq!(reply_bytes(&exchange(&mut pair, &[0x20, 0x00, 0, 0, 0, 1, 0xFD, 9])), [0x20, 0x10, 0, 0, 0, 1, 0xFD]);
    assert_eq!(reply_bytes(&exchange(&mut pair, &[0x20, 0x01, 0, 0, 0, 1, 9])), [0x20, 0x11, 0, 0, 0, 1]);
    let past = reply_bytes(&exchange(&mut pair, &[0x20, 0x40, 0, 0, 1, 0, 0xFD, 2]));
    assert_eq!(past, [0x20, 0x58, 0, 0, 1, 0, 0xFD, 0x10, 0x82]);
    let past = reply_bytes(&exchange(&mut pair, &[0x20, 0x41, 0, 0, 1, 0, 2]));
    assert_eq!(past, [0x20, 0x59, 0, 0, 1, 0, 0x10, 0x82]);
    // A space with no short code is always in byte 6.
    let cdi = reply_bytes(&exchange(&mut pair, &[0x20, 0x40, 0, 0, 0, 0, 0xFB, 1]));
    assert_eq!(cdi[..7], [0x20, 0x50, 0, 0, 0, 0, 0xFB]);
}

#[test]
fn read_stream_with_did_0xff_proposes_none_and_is_served() {
    // Wire-spec §4.1: 0xFF means "no DID proposed" (OlcbChecker's stream helper, OpenMRN).
    let mut pair = Pair::new(NodeConfig::default(), server_with(NodeConfig::default(), 64));
    let answers = exchange(&mut pair, &[0x20, 0x60, 0, 0, 0, 0, 0xFD, 0xFF, 0xFF, 0, 0, 0, 16]);
    assert_eq!((answers[0].mti, &answers[0].payload[..]), (Mti::DATAGRAM_RECEIVED_OK, &[0x80][..]), "{answers:?}");
    let request = answers.iter().find(|m| m.mti == Mti::STREAM_INITIATE_REQUEST).expect("the stream is offered");
    assert_eq!(request.payload.len(), 5, "no DID proposed: {:?}", request.payload);
}

#[test]
fn the_acdi_user_version_byte_is_not_writable() {
    // OlcbChecker's cd40: a write to 0xFB address 0 fails; the user name at 1 is writable.
    let mut pair = Pair::new(NodeConfig::default(), server_with(NodeConfig::default(), 64));
    let version = reply_bytes(&exchange(&mut pair, &[0x20, 0x00, 0, 0, 0, 0, 0xFB, 0x02]));
    assert_eq!(version, [0x20, 0x18, 0, 0, 0, 0, 0xFB, 0x10, 0x83], "Write Failed, read-only");
    let name = reply_bytes(&exchange(&mut pair, &[0x20, 0x00, 0, 0, 0, 1, 0xFB, b'A', 0]));
    assert_eq!(name, [0x20, 0x10, 0, 0, 0, 1, 0xFB]);
}

#[test]
fn reset_reinitializes_the_node_and_announces_it_after_the_ok() {
    // OlcbChecker's mc50_restart sends `20 A9` and waits for Initialization Complete.
    let mut pair = Pair::new(NodeConfig::default(), server_with(NodeConfig::default(), 64));
    let freeze = exchange(&mut pair, &Command::Freeze { space: 0xEF }.to_bytes());
    assert_eq!(freeze[0].mti, Mti::DATAGRAM_RECEIVED_OK);
    assert!(pair.server.memory_server().unwrap().is_frozen());
    let open = pair.server.streams_mut().open(pair.now, OpenOptions::new(CLIENT, 64)).unwrap();
    let answers = exchange(&mut pair, &Command::Reset.to_bytes());
    let mtis: Vec<Mti> = answers.iter().map(|m| m.mti).collect();
    assert_eq!(
        mtis[..3],
        [Mti::DATAGRAM_RECEIVED_OK, Mti::INITIALIZATION_COMPLETE, Mti::VERIFY_NODE_ID_GLOBAL],
        "{answers:?}"
    );
    assert!(!pair.server.memory_server().unwrap().is_frozen(), "the Firmware Upgrade state ended");
    assert!(pair.server.streams().stream_info(open).is_none(), "its streams ended");
    assert!(
        pair.server_events
            .iter()
            .any(|e| matches!(e, NodeEvent::Memory(MemoryEvent::ResetRequested { by }) if *by == CLIENT)),
        "the application is told"
    );
    assert_eq!(read_back(&mut pair.server, 0xFD), pattern(64, 7), "the configuration survives");
}

#[test]
fn server_control_commands() {
    let mut pair = Pair::new(NodeConfig::default(), server_with(NodeConfig::default(), 64));
    // Options: the stream bit only with streams (C-5).
    let answers = exchange(&mut pair, &Command::GetOptions.to_bytes());
    assert_eq!(answers[0].mti, Mti::DATAGRAM_RECEIVED_OK);
    assert_eq!(answers[0].payload[..], [0x80]);
    let Some(Reply::Options(options)) = reply_of(&answers) else { panic!() };
    assert_eq!(options.write_lengths, 0xE3);
    assert_eq!((options.highest_space, options.lowest_space), (0xFF, Some(0xEF)));
    // Lock: test-and-set, 0 releases.
    let lock = |node| Command::Lock { node }.to_bytes();
    assert_eq!(reply_of(&exchange(&mut pair, &lock(0x0501_0101_4001))), Some(Reply::Lock { owner: 0x0501_0101_4001 }));
    assert_eq!(reply_of(&exchange(&mut pair, &lock(0x0501_0101_4009))), Some(Reply::Lock { owner: 0x0501_0101_4001 }));
    assert_eq!(reply_of(&exchange(&mut pair, &lock(0))), Some(Reply::Lock { owner: 0 }));
    // Unique IDs from the pool, then 0x1041.
    let ids = reply_of(&exchange(&mut pair, &Command::GetUniqueId { count: 7 }.to_bytes()));
    assert!(matches!(ids, Some(Reply::UniqueIds { ids }) if ids.len() == 2));
    let none = exchange(&mut pair, &Command::GetUniqueId { count: 1 }.to_bytes());
    assert_eq!((none[0].mti, &none[0].payload[..]), (Mti::DATAGRAM_REJECTED, &[0x10, 0x41][..]));
    // Unknown command: 0x1041 (C-14).
    let unknown = exchange(&mut pair, &[0x20, 0xAB]);
    assert_eq!(&unknown[0].payload[..], [0x10, 0x41]);
    // Factory reset checks the Node ID.
    let wrong = exchange(&mut pair, &Command::FactoryReset { node: 0x0501_0101_4001 }.to_bytes());
    assert_eq!(&wrong[0].payload[..], [0x10, 0x80]);
    let right = exchange(&mut pair, &Command::FactoryReset { node: SERVER.as_raw() }.to_bytes());
    assert_eq!((right[0].mti, &right[0].payload[..]), (Mti::DATAGRAM_RECEIVED_OK, &[0][..]));
    let reset = exchange(&mut pair, &Command::Reset.to_bytes());
    assert_eq!(reset[0].mti, Mti::DATAGRAM_RECEIVED_OK);
    let events = &pair.server_events;
    assert!(events.iter().any(|e| matches!(e, NodeEvent::Memory(MemoryEvent::FactoryResetRequested { .. }))));
    assert!(events.iter().any(|e| matches!(e, NodeEvent::Memory(MemoryEvent::ResetRequested { .. }))));
    // Freeze: OK, then Initialization Complete, and PIP says Firmware Upgrade Active.
    let frozen = exchange(&mut pair, &Command::Freeze { space: 0xEF }.to_bytes());
    assert_eq!(frozen[0].mti, Mti::DATAGRAM_RECEIVED_OK);
    assert_eq!(frozen[1].mti, Mti::INITIALIZATION_COMPLETE);
    assert!(pair.server.protocols().contains(Protocols::FIRMWARE_UPGRADE_ACTIVE));
    assert!(!pair.server.protocols().contains(Protocols::FIRMWARE_UPGRADE));
    let info = reply_of(&exchange(&mut pair, &Command::GetSpaceInfo { space: 0x99 }.to_bytes()));
    assert_eq!(info.map(|r| r.to_bytes()), Some(vec![0x20, 0x86, 0x99]));
    let image = exchange(&mut pair, &[0x20, 0x00, 0, 0, 0, 0, 0xEF, 0xAA]);
    assert_eq!(image[0].mti, Mti::DATAGRAM_RECEIVED_OK);
    let unfrozen = exchange(&mut pair, &Command::Unfreeze { space: 0xEF }.to_bytes());
    assert_eq!(unfrozen[1].mti, Mti::INITIALIZATION_COMPLETE);
    assert!(pair.server.protocols().contains(Protocols::FIRMWARE_UPGRADE | Protocols::MEMORY_CONFIGURATION));
}

#[test]
fn a_firmware_write_is_answered_by_ok_alone_any_other_by_a_write_reply() {
    // C-9, worked example 9.1: OpenMRN's bootloader_client aborts on Reply Pending for its
    // firmware writes; OpenMRN's MemoryConfigClient stops a multi-chunk write after the first
    // chunk unless Reply Pending and a Write Reply come.
    let mut pair = Pair::new(NodeConfig::default(), server_with(NodeConfig::default(), 64));
    let answers = exchange(&mut pair, &[0x20, 0x01, 0, 0, 0, 0, 1, 2, 3, 4, 5, 6, 7, 8]);
    assert_eq!(answers.len(), 2);
    assert_eq!((answers[0].mti, &answers[0].payload[..]), (Mti::DATAGRAM_RECEIVED_OK, &[0x80][..]));
    assert_eq!((answers[1].mti, &answers[1].payload[..]), (Mti::DATAGRAM, &[0x20, 0x11, 0, 0, 0, 0][..]));
    assert_eq!(&read_back(&mut pair.server, 0xFD)[..8], [1, 2, 3, 4, 5, 6, 7, 8]);
    exchange(&mut pair, &[0x20, 0xA1, 0xEF]); // Freeze
    let answers = exchange(&mut pair, &[0x20, 0x00, 0, 0, 0, 0, 0xEF, 9, 8, 7]);
    assert_eq!(answers.len(), 1);
    assert_eq!((answers[0].mti, &answers[0].payload[..]), (Mti::DATAGRAM_RECEIVED_OK, &[0][..]));
    assert_eq!(&read_back(&mut pair.server, 0xEF)[..3], [9, 8, 7]);
}

#[test]
fn read_stream_server_order_is_ok_then_initiate_then_reply() {
    // C-4, as server: Datagram OK with Reply Pending at once, the Initiate Request proposing
    // the command's DID; the Reply only after the Initiate Reply.
    let mut pair = Pair::new(NodeConfig::default(), server_with(NodeConfig::default(), 200));
    let _ = std::iter::from_fn(|| pair.server.poll_transmit()).count();
    let command =
        Message::addressed(Mti::DATAGRAM, CLIENT, SERVER, vec![0x20, 0x61, 0, 0, 0, 0, 0xFF, 0x01, 0, 0, 0, 0xC8]);
    pair.server.handle_message(pair.now, command.as_ref());
    let answers: Vec<Message> = std::iter::from_fn(|| pair.server.poll_transmit()).collect();
    assert_eq!(answers.len(), 2, "{answers:?}");
    assert_eq!((answers[0].mti, &answers[0].payload[..]), (Mti::DATAGRAM_RECEIVED_OK, &[0x80][..]));
    assert_eq!(answers[1].mti, Mti::STREAM_INITIATE_REQUEST);
    assert_eq!(answers[1].payload[5], 0x01, "the proposed DID is the command's");
    let sid = answers[1].payload[4];
    let reply = Message::addressed(Mti::STREAM_INITIATE_REPLY, CLIENT, SERVER, vec![0x01, 0x00, 0x80, 0x00, sid, 0x01]);
    pair.server.handle_message(pair.now, reply.as_ref());
    while pair.server.poll_event().is_some() {}
    let after: Vec<Message> = std::iter::from_fn(|| pair.server.poll_transmit()).collect();
    assert_eq!(after[0].mti, Mti::DATAGRAM);
    assert_eq!(&after[0].payload[..], [0x20, 0x71, 0, 0, 0, 0, sid, 0x01, 0, 0, 0, 0xC8]);
    assert_eq!(after[1].mti, Mti::STREAM_DATA_SEND);
    let sent: usize = after.iter().filter(|m| m.mti == Mti::STREAM_DATA_SEND).map(|m| m.payload.len() - 1).sum();
    assert_eq!(sent, 200);
    assert_eq!(after.last().map(|m| m.mti), Some(Mti::STREAM_DATA_COMPLETE));
}

#[test]
fn read_stream_against_a_scripted_server_in_openmrn_order() {
    // OpenMRN's order (§3.10): Initiate Request first, the OK only after the Initiate Reply.
    let mut client = Node::new(CLIENT, NodeConfig::default());
    let now = Instant::ZERO;
    let _ = std::iter::from_fn(|| client.poll_transmit()).count();
    let op = client.read_memory(now, SERVER, 0xFD, 0, Some(200), TransferPath::Stream).unwrap();
    let command: Vec<Message> = std::iter::from_fn(|| client.poll_transmit()).collect();
    let Ok(Command::ReadStream { destination_stream: did, .. }) = Command::parse(&command[0].payload) else { panic!() };
    let from_server = |mti, payload: Vec<u8>| Message::addressed(mti, SERVER, CLIENT, payload);
    let initiate = from_server(Mti::STREAM_INITIATE_REQUEST, vec![0xFF, 0xFF, 0, 0, 0x02, did]);
    client.handle_message(now, initiate.as_ref());
    let answer: Vec<Message> = std::iter::from_fn(|| client.poll_transmit()).collect();
    assert_eq!(answer[0].mti, Mti::STREAM_INITIATE_REPLY);
    assert_eq!(&answer[0].payload[2..], [0x80, 0x00, 0x02, did]);
    client.handle_message(now, from_server(Mti::DATAGRAM_RECEIVED_OK, vec![0x80]).as_ref());
    let mut reply = vec![0x20, 0x71, 0, 0, 0, 0, 0x02, did, 0, 0, 0, 200];
    client.handle_message(now, from_server(Mti::DATAGRAM, std::mem::take(&mut reply)).as_ref());
    let data = pattern(200, 1);
    for chunk in data.chunks(64) {
        let mut payload = vec![did];
        payload.extend_from_slice(chunk);
        client.handle_message(now, from_server(Mti::STREAM_DATA_SEND, payload).as_ref());
    }
    client.handle_message(now, from_server(Mti::STREAM_DATA_COMPLETE, vec![0x02, did, 0, 0, 0, 200]).as_ref());
    let events: Vec<NodeEvent> = std::iter::from_fn(|| client.poll_event()).collect();
    assert!(
        events.iter().any(|e| matches!(e, NodeEvent::Memory(MemoryEvent::ReadDone { operation, data: d, .. })
            if *operation == op && *d == data)),
        "{events:?}"
    );
    assert!(!events.iter().any(|e| matches!(e, NodeEvent::Stream(_))), "the read's stream events stay inside");
}

/// A scripted stand-in for OpenMRN's `Bootloader.hxx`, stream build, as node-protocols.md
/// §4.5 reads it: no OK to Freeze (it logs in again), PIP `70 00 10 ..`, Write Stream Reply
/// `20 30 addr EF` without stream IDs sent before the Initiate, a window of the largest
/// power of two <= min(proposal, 1024), DID 0x5A always, 4-byte Proceeds sent only after a
/// "flash write" of `flash_delay`, no Write Stream Reply after Complete, OK without flags
/// to Unfreeze.
struct OpenMrnBootloader {
    flash_delay: Duration,
    sid: u8,
    window: usize,
    received: Vec<u8>,
    in_window: usize,
    /// Proceeds waiting for their flash write to finish.
    proceeds_due: Vec<Instant>,
    completed: bool,
    unfrozen: bool,
}

/// A peer played by a script: it answers each message, and may have answers due later.
trait Scripted {
    fn handle(&mut self, now: Instant, msg: &Message, out: &mut Vec<Message>);
    /// Answers due by `now` (a Proceed after a flash write).
    fn due(&mut self, _now: Instant, _out: &mut Vec<Message>) {}
    fn next_due(&self) -> Option<Instant> {
        None
    }
}

/// Runs `client` against `target` until the client's operation ends; fails on a hang or
/// on a stream event reaching the application.
fn run_scripted(client: &mut Node, target: &mut dyn Scripted) -> Option<MemoryEvent> {
    let mut now = Instant::ZERO;
    for _ in 0..100_000 {
        let mut answers = Vec::new();
        let mut sent = false;
        while let Some(m) = client.poll_transmit() {
            sent = true;
            target.handle(now, &m, &mut answers);
        }
        target.due(now, &mut answers);
        for a in &answers {
            client.handle_message(now, a.as_ref());
        }
        for event in std::iter::from_fn(|| client.poll_event()) {
            match event {
                NodeEvent::Memory(e) => return Some(e),
                NodeEvent::Stream(e) => panic!("a stream event of the operation leaked: {e:?}"),
                _ => {}
            }
        }
        if answers.is_empty() && !sent {
            let next = [client.poll_timeout(), target.next_due()].into_iter().flatten().min();
            now = next.expect("nothing to wait for: a hang").max(now);
            client.handle_timeout(now);
        }
    }
    None
}

impl Scripted for OpenMrnBootloader {
    fn due(&mut self, now: Instant, out: &mut Vec<Message>) {
        while self.proceeds_due.first().is_some_and(|t| *t <= now) {
            self.proceeds_due.remove(0);
            out.push(Message::addressed(Mti::STREAM_DATA_PROCEED, SERVER, CLIENT, vec![self.sid, 0x5A, 0, 0]));
        }
    }

    fn next_due(&self) -> Option<Instant> {
        self.proceeds_due.first().copied()
    }

    fn handle(&mut self, now: Instant, msg: &Message, out: &mut Vec<Message>) {
        let send =
            |out: &mut Vec<Message>, mti, payload: Vec<u8>| out.push(Message::addressed(mti, SERVER, CLIENT, payload));
        match msg.mti {
            Mti::DATAGRAM => match &msg.payload[..] {
                [0x20, 0xA1, 0xEF] => send(out, Mti::INITIALIZATION_COMPLETE, SERVER.to_bytes().to_vec()),
                [0x20, 0x20, a, b, c, d, 0xEF, sid] => {
                    self.sid = *sid;
                    send(out, Mti::DATAGRAM_RECEIVED_OK, vec![0x80]);
                    send(out, Mti::DATAGRAM, vec![0x20, 0x30, *a, *b, *c, *d, 0xEF]);
                }
                [0x20, 0xA0, 0xEF] => {
                    self.unfrozen = true;
                    send(out, Mti::DATAGRAM_RECEIVED_OK, vec![]);
                }
                other => panic!("the bootloader got {other:02X?}"),
            },
            Mti::PROTOCOL_SUPPORT_INQUIRY => send(out, Mti::PROTOCOL_SUPPORT_REPLY, vec![0x70, 0, 0x10, 0, 0, 0]),
            Mti::DATAGRAM_RECEIVED_OK => {}
            Mti::STREAM_INITIATE_REQUEST => {
                let proposal = usize::from(u16::from_be_bytes([msg.payload[0], msg.payload[1]]));
                assert_eq!(msg.payload[4], self.sid);
                let mut window = 1024;
                while window > proposal {
                    window /= 2;
                }
                self.window = window;
                let w = (window as u16).to_be_bytes();
                send(out, Mti::STREAM_INITIATE_REPLY, vec![w[0], w[1], 0x80, 0x00, self.sid, 0x5A]);
            }
            Mti::STREAM_DATA_SEND => {
                assert_eq!(msg.payload[0], 0x5A);
                let data = &msg.payload[1..];
                self.received.extend_from_slice(data);
                self.in_window += data.len();
                assert!(self.in_window <= self.window, "window overrun");
                if self.in_window == self.window {
                    self.in_window = 0;
                    self.proceeds_due.push(now + self.flash_delay);
                }
            }
            Mti::STREAM_DATA_COMPLETE => {
                assert_eq!(&msg.payload[..2], [self.sid, 0x5A]);
                self.completed = true;
            }
            _ => {}
        }
    }
}

#[test]
fn firmware_upgrade_against_a_scripted_openmrn_bootloader() {
    for flash_delay in [Duration::from_millis(0), Duration::from_secs(5)] {
        let mut client = Node::new(CLIENT, NodeConfig::default());
        let mut target = OpenMrnBootloader {
            flash_delay,
            sid: 0,
            window: 0,
            received: Vec::new(),
            in_window: 0,
            proceeds_due: Vec::new(),
            completed: false,
            unfrozen: false,
        };
        let image = pattern(3000, 42);
        client.upgrade_firmware(Instant::ZERO, SERVER, image.clone(), TransferPath::Auto).unwrap();
        let done = run_scripted(&mut client, &mut target);
        assert!(matches!(done, Some(MemoryEvent::WriteDone { len: 3000, .. })), "{done:?}");
        assert_eq!(target.window, 1024);
        assert!(target.completed && target.unfrozen);
        assert_eq!(target.received, image);
    }
}

#[test]
fn pip_has_memory_configuration_exactly_with_a_server() {
    let plain = Node::new(SERVER, NodeConfig::default());
    assert!(!plain.protocols().contains(Protocols::MEMORY_CONFIGURATION));
    let config_only = Node::new(SERVER, NodeConfig::default())
        .with_memory_server(MemoryServer::new().with_space(0xFD, RamSpace::new(16)));
    let bits = config_only.protocols();
    assert!(bits.contains(Protocols::MEMORY_CONFIGURATION | Protocols::DATAGRAM | Protocols::STREAM));
    assert!(!bits.contains(Protocols::FIRMWARE_UPGRADE) && !bits.contains(Protocols::FIRMWARE_UPGRADE_ACTIVE));
    let firmware = server_with(NodeConfig::default(), 16);
    assert!(firmware.protocols().contains(Protocols::FIRMWARE_UPGRADE));
    assert!(!bits.contains(Protocols::CDI) && !bits.contains(Protocols::ACDI), "neither is served");
}

#[test]
fn pip_announces_cdi_and_acdi_exactly_when_they_are_served() {
    let cdi = Node::new(SERVER, NodeConfig::default())
        .with_memory_server(MemoryServer::new().with_space(0xFF, RamSpace::new(16)));
    assert!(cdi.protocols().contains(Protocols::CDI));
    assert!(!cdi.protocols().contains(Protocols::ACDI));
    let acdi = Node::new(SERVER, NodeConfig::default()).with_memory_server(MemoryServer::new().with_acdi());
    assert!(acdi.protocols().contains(Protocols::ACDI));
    assert!(!acdi.protocols().contains(Protocols::CDI));
}

/// An OpenLcbCLib-style target as node-protocols.md §3.11 reads it: Datagram OK 0x80 to
/// Write Stream, the Write Stream Reply only after Complete and without the space byte
/// (`20 30 addr SID DID`, C-2, C-8).
struct ReplyAfterComplete {
    sid: u8,
    received: Vec<u8>,
}

impl Scripted for ReplyAfterComplete {
    fn handle(&mut self, _now: Instant, msg: &Message, out: &mut Vec<Message>) {
        let send =
            |out: &mut Vec<Message>, mti, payload: Vec<u8>| out.push(Message::addressed(mti, SERVER, CLIENT, payload));
        match msg.mti {
            Mti::DATAGRAM if msg.payload[1] == 0x20 => {
                self.sid = msg.payload[7];
                send(out, Mti::DATAGRAM_RECEIVED_OK, vec![0x80]);
            }
            // No Get Address Space Information: the client writes without knowing the size.
            Mti::DATAGRAM => send(out, Mti::DATAGRAM_REJECTED, vec![0x10, 0x41]),
            Mti::STREAM_INITIATE_REQUEST => {
                send(out, Mti::STREAM_INITIATE_REPLY, vec![0x01, 0x00, 0x80, 0x00, self.sid, 0x03]);
            }
            Mti::STREAM_DATA_SEND => {
                self.received.extend_from_slice(&msg.payload[1..]);
                if self.received.len().is_multiple_of(256) {
                    send(out, Mti::STREAM_DATA_PROCEED, vec![self.sid, 0x03]);
                }
            }
            Mti::STREAM_DATA_COMPLETE => send(out, Mti::DATAGRAM, vec![0x20, 0x30, 0, 0, 0, 0, self.sid, 0x03]),
            _ => {}
        }
    }
}

/// OpenMRN's io_board as seen here: space 0xFD reported with highest address 0x157, but a
/// read of 0x157 refused with 0x1082 (its last readable byte is 0x156); no streams.
struct EdgeRefusingNode {
    space: Vec<u8>,
}

impl Scripted for EdgeRefusingNode {
    fn handle(&mut self, _now: Instant, msg: &Message, out: &mut Vec<Message>) {
        let send = |out: &mut Vec<Message>, mti, p: Vec<u8>| out.push(Message::addressed(mti, SERVER, CLIENT, p));
        if msg.mti != Mti::DATAGRAM {
            return;
        }
        send(out, Mti::DATAGRAM_RECEIVED_OK, vec![0x80]);
        match Command::parse(&msg.payload).unwrap() {
            Command::GetOptions => send(out, Mti::DATAGRAM, vec![0x20, 0x82, 0x60, 0x00, 0xE2, 0xFF, 0xFB]),
            Command::GetSpaceInfo { space: 0xFD } => {
                send(out, Mti::DATAGRAM, vec![0x20, 0x87, 0xFD, 0, 0, 0x01, 0x57, 0])
            }
            Command::Read { address, count, .. } => {
                let start = address as usize;
                if start >= self.space.len() {
                    send(out, Mti::DATAGRAM, vec![0x20, 0x59, 0, 0, (address >> 8) as u8, address as u8, 0x10, 0x82]);
                } else {
                    let end = (start + usize::from(count)).min(self.space.len());
                    let mut reply = vec![0x20, 0x51, 0, 0, (address >> 8) as u8, address as u8];
                    reply.extend_from_slice(&self.space[start..end]);
                    send(out, Mti::DATAGRAM, reply);
                }
            }
            other => panic!("unexpected {other:?}"),
        }
    }
}

#[test]
fn whole_space_read_ends_where_the_node_refuses_the_last_address_it_reported() {
    let mut client = Node::new(CLIENT, NodeConfig::default());
    let space = pattern(0x157, 3);
    let mut target = EdgeRefusingNode { space: space.clone() };
    client.read_memory(Instant::ZERO, SERVER, 0xFD, 0, None, TransferPath::Auto).unwrap();
    let done = run_scripted(&mut client, &mut target);
    let Some(MemoryEvent::ReadDone { data, .. }) = done else { panic!("{done:?}") };
    assert_eq!(data, space, "the data is kept, 0x000-0x156");
    // Asked for a length, the same refusal is an error: the caller wanted those bytes.
    client.read_memory(Instant::ZERO, SERVER, 0xFD, 0, Some(0x158), TransferPath::Auto).unwrap();
    let done = run_scripted(&mut client, &mut target);
    assert!(matches!(done, Some(MemoryEvent::Failed { .. })), "{done:?}");
}

#[test]
fn write_stream_reply_after_complete_without_the_space_byte() {
    let mut client = Node::new(CLIENT, NodeConfig::default());
    let mut target = ReplyAfterComplete { sid: 0, received: Vec::new() };
    let data = pattern(1000, 8);
    client.write_memory(Instant::ZERO, SERVER, 0x10, 0, data.clone(), TransferPath::Stream).unwrap();
    let done = run_scripted(&mut client, &mut target);
    assert!(matches!(done, Some(MemoryEvent::WriteDone { len: 1000, .. })), "{done:?}");
    assert_eq!(target.received, data);
}

#[test]
fn write_stream_reply_to_a_client_that_waits_names_the_did_the_server_then_assigns() {
    // C-2, as target, for a client that waits for the reply before it initiates (OpenMRN's
    // bootloader_client): OK with Reply Pending, then after the reply delay `20 3x addr
    // [space] SID DID`, the DID being the one the Initiate Reply then carries; the window is
    // the server's bound.
    let mut config = NodeConfig::default();
    config.memory.write_stream_window = 512;
    let delay = config.memory.write_stream_reply_delay;
    let mut pair = Pair::new(NodeConfig::default(), server_with(config, 4096));
    let _ = std::iter::from_fn(|| pair.server.poll_transmit()).count();
    let command = Message::addressed(Mti::DATAGRAM, CLIENT, SERVER, vec![0x20, 0x21, 0, 0, 0, 0x10, 0x42]);
    pair.server.handle_message(pair.now, command.as_ref());
    let mut answers: Vec<Message> = std::iter::from_fn(|| pair.server.poll_transmit()).collect();
    assert_eq!(answers.len(), 1, "the OK only, at first: {answers:?}");
    assert_eq!((answers[0].mti, &answers[0].payload[..]), (Mti::DATAGRAM_RECEIVED_OK, &[0x80][..]));
    assert_eq!(pair.server.poll_timeout(), Some(pair.now + delay));
    pair.server.handle_timeout(pair.now + delay);
    answers.extend(std::iter::from_fn(|| pair.server.poll_transmit()));
    let Ok(Reply::WriteStreamOk { streams: Some((0x42, did)), .. }) = Reply::parse(&answers[1].payload) else {
        panic!("{answers:?}")
    };
    let initiate = Message::addressed(Mti::STREAM_INITIATE_REQUEST, CLIENT, SERVER, vec![0xFF, 0xFF, 0, 0, 0x42, 0xFF]);
    pair.server.handle_message(pair.now, initiate.as_ref());
    while pair.server.poll_event().is_some() {}
    let reply: Vec<Message> = std::iter::from_fn(|| pair.server.poll_transmit()).collect();
    assert_eq!(reply[0].mti, Mti::STREAM_INITIATE_REPLY);
    assert_eq!(&reply[0].payload[..], [0x02, 0x00, 0x80, 0x00, 0x42, did]);
}

#[test]
fn write_stream_reply_to_a_client_that_initiates_at_once_comes_after_the_complete() {
    // OlcbChecker's mc80 and OpenLcbCLib: the Initiate Request right after the OK, data,
    // Complete, and only then the Write Stream Reply (in the long form it was asked in).
    let mut pair = Pair::new(NodeConfig::default(), server_with(NodeConfig::default(), 4096));
    let _ = std::iter::from_fn(|| pair.server.poll_transmit()).count();
    let command = Message::addressed(Mti::DATAGRAM, CLIENT, SERVER, vec![0x20, 0x20, 0, 0, 0, 0x10, 0xFD, 0xA0]);
    pair.server.handle_message(pair.now, command.as_ref());
    let initiate = Message::addressed(Mti::STREAM_INITIATE_REQUEST, CLIENT, SERVER, vec![0x01, 0x00, 0, 0, 0xA0, 0xFF]);
    pair.server.handle_message(pair.now, initiate.as_ref());
    while pair.server.poll_event().is_some() {}
    let answers: Vec<Message> = std::iter::from_fn(|| pair.server.poll_transmit()).collect();
    assert!(answers.iter().all(|m| m.mti != Mti::DATAGRAM), "no reply before the stream ends: {answers:?}");
    let reply = answers.iter().find(|m| m.mti == Mti::STREAM_INITIATE_REPLY).unwrap();
    let did = reply.payload[5];
    pair.server.handle_timeout(pair.now + Duration::from_secs(1));
    assert!(std::iter::from_fn(|| pair.server.poll_transmit()).all(|m| m.mti != Mti::DATAGRAM), "not at the delay");
    let data = Message::addressed(Mti::STREAM_DATA_SEND, CLIENT, SERVER, vec![did, 0x5A]);
    let complete = Message::addressed(Mti::STREAM_DATA_COMPLETE, CLIENT, SERVER, vec![0xA0, did]);
    pair.server.handle_message(pair.now, data.as_ref());
    pair.server.handle_message(pair.now, complete.as_ref());
    while pair.server.poll_event().is_some() {}
    let after: Vec<Message> = std::iter::from_fn(|| pair.server.poll_transmit()).collect();
    let datagram = after.iter().find(|m| m.mti == Mti::DATAGRAM).expect("the Write Stream Reply");
    assert_eq!(&datagram.payload[..], [0x20, 0x30, 0, 0, 0, 0x10, 0xFD, 0xA0, did]);
    assert_eq!(read_back(&mut pair.server, 0xFD)[0x10], 0x5A);
}

#[test]
fn write_under_mask_changes_only_the_masked_bits() {
    let mut pair = Pair::new(NodeConfig::default(), server_with(NodeConfig::default(), 64));
    let before = read_back(&mut pair.server, 0xFD);
    let command = Command::WriteUnderMask { space: 0xFD, address: 2, mask: vec![0xF0, 0x0F], data: vec![0xAB, 0xCD] };
    let answers = exchange(&mut pair, &command.to_bytes());
    assert_eq!((answers[0].mti, &answers[0].payload[..]), (Mti::DATAGRAM_RECEIVED_OK, &[0x80][..]));
    assert_eq!(&answers[1].payload[..], [0x20, 0x11, 0, 0, 0, 2], "a Write Reply follows");
    let after = read_back(&mut pair.server, 0xFD);
    assert_eq!(after[2], (before[2] & 0x0F) | 0xA0);
    assert_eq!(after[3], (before[3] & 0xF0) | 0x0D);
    assert_eq!(after[4..], before[4..]);
    // Past the end: OK with Reply Pending and a Failed reply 0x1082.
    let past = Command::WriteUnderMask { space: 0xFD, address: 63, mask: vec![1, 1], data: vec![1, 1] };
    let answers = exchange(&mut pair, &past.to_bytes());
    assert_eq!(&answers[0].payload[..], [0x80]);
    assert!(matches!(reply_of(&answers), Some(Reply::Failed { code, .. }) if code.0 == 0x1082));
}

/// Upgrades a fresh server with `image` from a fresh client (Auto path: by stream), handing
/// every client message to `deliver`, which passes it to the server or holds it back.
/// Returns the server and the image length of its Unfrozen event.
fn upgrade_through(image: &[u8], mut deliver: impl FnMut(Message, &mut Node)) -> (Node, Option<u32>) {
    let mut client = Node::new(CLIENT, NodeConfig::default());
    let mut server = server_with(NodeConfig::default(), 16);
    client.upgrade_firmware(Instant::ZERO, SERVER, image.to_vec(), TransferPath::Auto).unwrap();
    let mut now = Instant::ZERO;
    let mut unfrozen = None;
    for _ in 0..10_000 {
        let mut moved = false;
        while let Some(m) = client.poll_transmit() {
            deliver(m, &mut server);
            moved = true;
        }
        while let Some(m) = server.poll_transmit() {
            client.handle_message(now, m.as_ref());
            moved = true;
        }
        while client.poll_event().is_some() {
            moved = true;
        }
        while let Some(event) = server.poll_event() {
            if let NodeEvent::Memory(MemoryEvent::Unfrozen { image_len, .. }) = event {
                unfrozen = Some(image_len);
            }
            moved = true;
        }
        if !moved {
            match client.poll_timeout().filter(|t| *t <= now + Duration::from_secs(60)) {
                Some(t) => {
                    now = now.max(t);
                    client.handle_timeout(now);
                }
                None => break,
            }
        }
    }
    (server, unfrozen)
}

fn is_unfreeze(m: &Message) -> bool {
    m.mti == Mti::DATAGRAM && m.payload.get(..3) == Some(&[0x20, 0xA0, 0xEF][..])
}

#[test]
fn firmware_unfreeze_never_overtakes_the_stream_complete() {
    // The client opens its Write Stream at once and ends the upgrade once the reply has
    // come: its Unfreeze must follow its Data Complete.
    let mut order = Vec::new();
    let (_, unfrozen) = upgrade_through(&pattern(100_000, 5), |m, server| {
        if m.mti == Mti::STREAM_DATA_COMPLETE {
            order.push("complete");
        } else if is_unfreeze(&m) {
            order.push("unfreeze");
        }
        server.handle_message(Instant::ZERO, m.as_ref());
    });
    assert_eq!(order, ["complete", "unfreeze"]);
    assert_eq!(unfrozen, Some(100_000));
}

#[test]
fn an_unfreeze_that_overtakes_the_stream_waits_for_its_end() {
    // An Unfreeze from the upgrading client that arrives before the last data and the
    // Complete of its Write Stream (CAN arbitration puts datagram frames first; a client that
    // does not wait for the Write Stream Reply): the image is still whole.
    let image = pattern(100_000, 9);
    let mut held = Vec::new();
    let mut data = 0;
    let (mut server, unfrozen) = upgrade_through(&image, |m, server| {
        if m.mti == Mti::STREAM_DATA_SEND {
            data += m.payload.len() - 1;
        }
        // Hold back the last window's data and the Complete, send the Unfreeze, then them.
        if data > 98_304 && held.is_empty() {
            let unfreeze = Message::addressed(Mti::DATAGRAM, CLIENT, SERVER, vec![0x20, 0xA0, 0xEF]);
            held.push(m);
            server.handle_message(Instant::ZERO, unfreeze.as_ref());
            return;
        }
        if !held.is_empty() && m.mti != Mti::DATAGRAM_RECEIVED_OK {
            for m in held.drain(..) {
                server.handle_message(Instant::ZERO, m.as_ref());
            }
        }
        server.handle_message(Instant::ZERO, m.as_ref());
    });
    assert_eq!(unfrozen, Some(100_000));
    assert_eq!(&read_back(&mut server, 0xEF)[..image.len()], &image[..]);
}

#[test]
fn a_node_taking_streams_only_for_memory_configuration_refuses_the_others() {
    use openlcb_stream::wire::ReplyCode;
    use openlcb_stream::{AcceptPolicy, Event};
    let mut config = NodeConfig::default();
    config.stream.accept_policy = AcceptPolicy::RejectAll(ReplyCode::STREAMS_NOT_SUPPORTED);
    let mut pair = Pair::new(NodeConfig::default(), server_with(config, 8192));
    pair.pump();
    let foreign = pair.client.streams_mut().open(pair.now, OpenOptions::new(SERVER, 64)).unwrap();
    pair.pump();
    let refusal = pair.events.iter().find_map(|e| match e {
        NodeEvent::Stream(Event::Rejected { handle, code, .. }) if *handle == foreign => Some(*code),
        _ => None,
    });
    assert_eq!(refusal, Some(ReplyCode::STREAMS_NOT_SUPPORTED), "{:?}", pair.events);
    assert!(!pair.server_events.iter().any(|e| matches!(e, NodeEvent::Stream(_))), "{:?}", pair.server_events);
    let data = pattern(3000, 5);
    pair.client.write_memory(pair.now, SERVER, 0xFD, 0, data.clone(), TransferPath::Stream).unwrap();
    match pair.finish() {
        MemoryEvent::WriteDone { len, .. } => assert_eq!(len, 3000),
        other => panic!("Memory Configuration's own stream is still taken: {other:?}"),
    }
    assert_eq!(&read_back(&mut pair.server, 0xFD)[..3000], &data[..]);
}

// ----- the node's shape: work done at each input, outcomes to their owners -----

impl Pair {
    /// Passes every queued message both ways once; returns how many.
    fn exchange(&mut self) -> usize {
        let mut moved = 0;
        while let Some(m) = self.client.poll_transmit() {
            self.server.handle_message(self.now, m.as_ref());
            moved += 1;
        }
        while let Some(m) = self.server.poll_transmit() {
            self.client.handle_message(self.now, m.as_ref());
            moved += 1;
        }
        moved
    }
}

#[test]
fn transfers_run_on_messages_alone_and_poll_event_only_pops() {
    // A driver that passes messages and leaves the events for later (a firmware's): every
    // step of a datagram write and of a stream read is taken at the input that caused it.
    let mut pair = Pair::new(NodeConfig::default(), server_with(NodeConfig::default(), 300));
    pair.pump(); // both announce themselves
    let data = pattern(200, 3);
    let write = pair.client.write_memory(pair.now, SERVER, 0xFD, 0, data.clone(), TransferPath::Datagrams).unwrap();
    while pair.exchange() > 0 {}
    assert_eq!(pair.client.memory_progress(write), None, "the write ended without poll_event");
    let read = pair.client.read_memory(pair.now, SERVER, 0xFD, 0, None, TransferPath::Stream).unwrap();
    while pair.exchange() > 0 {}
    assert_eq!(pair.client.memory_progress(read), None, "the read ended without poll_event");
    let events: Vec<NodeEvent> = std::iter::from_fn(|| pair.client.poll_event()).collect();
    let mut expected = pattern(300, 7);
    expected[..200].copy_from_slice(&data);
    assert!(
        matches!(events[..], [
        NodeEvent::Memory(MemoryEvent::WriteDone { operation, len: 200, .. }),
        NodeEvent::Memory(MemoryEvent::ReadDone { operation: second, ref data, .. }),
    ] if operation == write && second == read && *data == expected),
        "{events:?}"
    );
}

#[test]
fn a_lost_server_is_sent_nothing_and_the_operation_fails() {
    // A write of more than one chunk holds the server's lock; the peer is lost in the middle:
    // the operation fails at once, and no lock release (nor the next chunk) goes to it.
    let mut pair = Pair::new(NodeConfig::default(), server_with(NodeConfig::default(), 300));
    pair.pump(); // both announce themselves
    let write = pair.client.write_memory(pair.now, SERVER, 0xFD, 0, pattern(200, 3), TransferPath::Datagrams).unwrap();
    while pair.client.memory_progress(write) == Some(0) {
        assert!(pair.exchange() > 0, "the write stalled");
    }
    assert_eq!(pair.server.memory_server().map(|s| s.lock_owner()), Some(CLIENT.as_raw()));
    while pair.client.poll_transmit().is_some() {} // the next chunk, lost on the way
    pair.client.peer_changed(PeerChange::Lost(SERVER));
    let sent: Vec<Message> = std::iter::from_fn(|| pair.client.poll_transmit()).collect();
    assert!(sent.is_empty(), "sent to a lost peer: {sent:?}");
    let events: Vec<NodeEvent> = std::iter::from_fn(|| pair.client.poll_event()).collect();
    assert_eq!(
        events,
        [NodeEvent::Memory(MemoryEvent::Failed { operation: write, peer: SERVER, error: MemoryError::PeerLost })]
    );
}

#[test]
fn an_application_datagram_is_answered_to_the_application_while_an_operation_runs() {
    // The application's datagram and the client's commands go to the same node at once; each
    // outcome goes back to the one that sent the datagram.
    let mut config = NodeConfig::default();
    config.datagrams.claimed = vec![0x21];
    let mut pair = Pair::new(NodeConfig::default(), server_with(config, 300));
    pair.pump(); // both announce themselves
    let read = pair.client.read_memory(pair.now, SERVER, 0xFD, 0, Some(200), TransferPath::Datagrams).unwrap();
    let sent = pair.client.send_datagram(pair.now, SERVER, &[0x21, 1]).unwrap();
    // It waits behind the client's command (one datagram at a time to a node, DG §6.1).
    let received = loop {
        assert!(pair.exchange() > 0, "the datagram never arrived");
        let received = std::iter::from_fn(|| pair.server.poll_event()).find_map(|e| match e {
            NodeEvent::DatagramReceived { from, datagram } => Some((from, datagram.as_slice().to_vec())),
            _ => None,
        });
        if received.is_some() {
            break received;
        }
    };
    assert_eq!(received, Some((CLIENT, vec![0x21, 1])));
    let ok = openlcb_node::DatagramAnswer::Ok(openlcb_node::OkFlags::default());
    pair.server.answer_datagram(CLIENT, ok).unwrap();
    let event = pair.finish();
    assert!(
        matches!(event, MemoryEvent::ReadDone { operation, ref data, .. } if operation == read && data.len() == 200)
    );
    let delivered: Vec<&NodeEvent> =
        pair.events.iter().filter(|e| matches!(e, NodeEvent::DatagramDelivered { .. })).collect();
    assert_eq!(
        delivered,
        [&NodeEvent::DatagramDelivered { id: sent, to: SERVER, flags: openlcb_node::OkFlags::default() }]
    );
}

/// A firmware Write Stream that the client ends with TDE: with or without the optional MTI
/// field, and with the MTI the wire spec names for a source (0x0888) or another, the next
/// Unfreeze is answered (refused: the image is incomplete) and a retry can begin.
#[test]
fn a_firmware_stream_ended_by_tde_leaves_the_unfreeze_answered() {
    for tde in [
        vec![0x10, 0x00],
        vec![0x10, 0x00, 0x08, 0x88],
        vec![0x10, 0x00, 0x1F, 0x88],
        vec![0x10, 0x00, 0x00],
        vec![0x10, 0x00, 0x1C, 0x48],
        vec![0x10, 0x00, 0x0A, 0x28],
    ] {
        let mut pair = Pair::new(NodeConfig::default(), server_with(NodeConfig::default(), 16));
        let freeze = exchange(&mut pair, &Command::Freeze { space: 0xEF }.to_bytes());
        assert_eq!(freeze[0].mti, Mti::DATAGRAM_RECEIVED_OK);
        let write = exchange(&mut pair, &[0x20, 0x20, 0, 0, 0, 0, 0xEF, 0xA0]);
        assert_eq!(write[0].mti, Mti::DATAGRAM_RECEIVED_OK, "{tde:?}");
        let initiate =
            Message::addressed(Mti::STREAM_INITIATE_REQUEST, CLIENT, SERVER, vec![0x01, 0x00, 0, 0, 0xA0, 0xFF]);
        pair.server.handle_message(pair.now, initiate.as_ref());
        let answers: Vec<Message> = std::iter::from_fn(|| pair.server.poll_transmit()).collect();
        let did = answers.iter().find(|m| m.mti == Mti::STREAM_INITIATE_REPLY).expect("accepted").payload[5];
        let data = Message::addressed(Mti::STREAM_DATA_SEND, CLIENT, SERVER, vec![did, 1, 2, 3]);
        pair.server.handle_message(pair.now, data.as_ref());
        let end = Message::addressed(Mti::TERMINATE_DUE_TO_ERROR, CLIENT, SERVER, tde.clone());
        pair.server.handle_message(pair.now, end.as_ref());
        while pair.server.poll_event().is_some() {}
        let _ = std::iter::from_fn(|| pair.server.poll_transmit()).count();
        let mut unfreeze = exchange(&mut pair, &Command::Unfreeze { space: 0xEF }.to_bytes());
        let at_once = !unfreeze.is_empty();
        // A report about no interaction of ours leaves the stream to its own deadline.
        while unfreeze.is_empty()
            && let Some(next) = pair.server.poll_timeout().filter(|t| *t <= Instant::ZERO + Duration::from_secs(60))
        {
            pair.now = pair.now.max(next);
            pair.server.handle_timeout(pair.now);
            unfreeze.extend(
                std::iter::from_fn(|| pair.server.poll_transmit()).filter(|m| m.mti != Mti::STREAM_DATA_PROCEED),
            );
        }
        let refused = unfreeze.iter().find(|m| m.mti == Mti::DATAGRAM_REJECTED).map(|m| m.payload.to_vec());
        assert_eq!(refused, Some(vec![0x10, 0x89]), "TDE {tde:02X?}: {unfreeze:?}");
        assert_eq!(at_once, tde != [0x10, 0x00, 0x0A, 0x28], "TDE {tde:02X?}");
    }
}

/// Freeze then Unfreeze with nothing written: no image, refused with 0x1089 (firmware
/// invalid), nothing stored, and the node stays frozen for an upgrade.
#[test]
fn an_unfreeze_with_nothing_written_is_refused_as_no_image() {
    let mut pair = Pair::new(NodeConfig::default(), server_with(NodeConfig::default(), 16));
    let freeze = exchange(&mut pair, &Command::Freeze { space: 0xEF }.to_bytes());
    assert_eq!(freeze[0].mti, Mti::DATAGRAM_RECEIVED_OK);
    let unfreeze = exchange(&mut pair, &Command::Unfreeze { space: 0xEF }.to_bytes());
    assert_eq!((unfreeze[0].mti, &unfreeze[0].payload[..]), (Mti::DATAGRAM_REJECTED, &[0x10, 0x89][..]));
    assert!(pair.server.memory_server().unwrap().is_frozen());
    let unfrozen = pair.server_events.iter().any(|e| matches!(e, NodeEvent::Memory(MemoryEvent::Unfrozen { .. })));
    assert!(!unfrozen, "no image reached the application");
}

// ----- a holder of the lock or of an upgrade that left without a word -----

/// A loader that froze the server (or took its lock) and then vanished: no AMR, no answer.
const GONE: NodeId = NodeId::from_bytes([5, 1, 1, 1, 0x40, 9]);

/// Hands the server `command` from `from` and returns its answers (nothing goes back).
fn command_from(pair: &mut Pair, from: NodeId, command: &[u8]) -> Vec<Message> {
    let msg = Message::addressed(Mti::DATAGRAM, from, SERVER, command.to_vec());
    pair.server.handle_message(pair.now, msg.as_ref());
    std::iter::from_fn(|| pair.server.poll_transmit()).collect()
}

fn verify_to(answers: &[Message], node: NodeId) -> bool {
    answers.iter().any(|m| m.mti == Mti::VERIFY_NODE_ID_ADDRESSED && m.destination == Some(node))
}

fn rejected_with(answers: &[Message], code: u16) -> bool {
    answers.iter().any(|m| m.mti == Mti::DATAGRAM_REJECTED && m.payload[..2] == code.to_be_bytes())
}

#[test]
fn a_frozen_node_whose_loader_vanished_is_taken_over_by_the_next_upgrade() {
    let mut pair = Pair::new(NodeConfig::default(), server_with(NodeConfig::default(), 16));
    pair.pump();
    let frozen = command_from(&mut pair, GONE, &Command::Freeze { space: 0xEF }.to_bytes());
    assert_eq!(frozen[0].mti, Mti::DATAGRAM_RECEIVED_OK);
    // Another loader's whole upgrade: its Freeze is refused for now while the server asks
    // the owner, which never answers; a resend gets through.
    let image = pattern(3000, 5);
    pair.client.upgrade_firmware(pair.now, SERVER, image.clone(), TransferPath::Auto).unwrap();
    match pair.finish() {
        MemoryEvent::WriteDone { len, .. } => assert_eq!(len, 3000),
        other => panic!("the second loader failed: {other:?}"),
    }
    pair.pump();
    assert_eq!(&read_back(&mut pair.server, 0xEF)[..image.len()], &image[..]);
    assert!(!pair.server.memory_server().unwrap().is_frozen());
    assert_eq!(pair.server.memory_server().unwrap().stats().holders_gone, 1);
}

#[test]
fn a_loader_that_answers_keeps_its_upgrade() {
    let mut pair = Pair::new(NodeConfig::default(), server_with(NodeConfig::default(), 16));
    pair.pump();
    command_from(&mut pair, GONE, &Command::Freeze { space: 0xEF }.to_bytes());
    let freeze = Command::Freeze { space: 0xEF }.to_bytes();
    let first = command_from(&mut pair, CLIENT, &freeze);
    assert!(rejected_with(&first, 0x2000) && verify_to(&first, GONE), "{first:?}");
    // The owner is still here: the refusal becomes the permanent one (two loaders never mix).
    let verified = Message::verified_node_id(GONE);
    pair.server.handle_message(pair.now, verified.as_ref());
    pair.now += Duration::from_millis(200);
    let again = command_from(&mut pair, CLIENT, &freeze);
    assert!(rejected_with(&again, 0x1020), "{again:?}");
    let image = command_from(&mut pair, CLIENT, &[0x20, 0x00, 0, 0, 0, 0, 0xEF, 0xAA]);
    assert!(rejected_with(&image, 0x1020), "{image:?}");
    assert_eq!(pair.server.memory_server().unwrap().stats().holders_gone, 0);
}

#[test]
fn the_lock_of_a_vanished_node_ends_when_it_does_not_answer_and_when_it_leaves() {
    let mut pair = Pair::new(NodeConfig::default(), server_with(NodeConfig::default(), 16));
    pair.pump();
    let lock = |node: NodeId| Command::Lock { node: node.as_raw() }.to_bytes();
    command_from(&mut pair, GONE, &lock(GONE));
    assert_eq!(pair.server.memory_server().unwrap().lock_owner(), GONE.as_raw());
    // Asked while the holder is checked: refused for now, and asking does not extend it.
    let asked = command_from(&mut pair, CLIENT, &lock(CLIENT));
    assert!(rejected_with(&asked, 0x2000) && verify_to(&asked, GONE), "{asked:?}");
    pair.now += Duration::from_millis(600);
    pair.server.handle_timeout(pair.now);
    assert_eq!(pair.server.memory_server().unwrap().lock_owner(), 0, "no answer: the lock ended");
    assert_eq!(reply_of(&command_from(&mut pair, CLIENT, &lock(CLIENT))), Some(Reply::Lock { owner: CLIENT.as_raw() }));
    // A holder the transport reports gone (an AMR on CAN) releases it at once.
    pair.server.peer_changed(PeerChange::Lost(CLIENT));
    assert_eq!(pair.server.memory_server().unwrap().lock_owner(), 0);
}

#[test]
fn a_write_of_another_node_waits_for_the_lock_holder_to_be_found_gone() {
    // The client's own write by datagrams: Lock refused for now, resent, then granted.
    let mut pair = Pair::new(NodeConfig::default(), server_with(NodeConfig::default(), 64));
    pair.pump();
    command_from(&mut pair, GONE, &Command::Lock { node: GONE.as_raw() }.to_bytes());
    pair.client.write_memory(pair.now, SERVER, 0xFD, 0, vec![9; 40], TransferPath::Datagrams).unwrap();
    assert!(matches!(pair.finish(), MemoryEvent::WriteDone { .. }));
    assert_eq!(read_back(&mut pair.server, 0xFD)[..40], [9; 40]);
}

#[test]
fn lock_is_test_and_set_at_once_for_the_node_that_took_it_whatever_ids_it_names() {
    // OlcbChecker's mc40_lock: one sender locks with made-up Node IDs and expects each answer
    // at once (no holder check: the node that took the lock is the one asking).
    let mut pair = Pair::new(NodeConfig::default(), server_with(NodeConfig::default(), 16));
    pair.pump();
    let (a, b) = (0x0102_0304_0506, 0x0605_0403_0201);
    for (asked, owner) in [(0, 0), (a, a), (b, a), (0, 0), (b, b), (a, b), (a, b), (0, 0), (0, 0)] {
        let answers = exchange(&mut pair, &Command::Lock { node: asked }.to_bytes());
        assert_eq!(reply_of(&answers), Some(Reply::Lock { owner }), "Lock({asked:012X}): {answers:?}");
        assert!(!verify_to(&answers, NodeId::new(a).unwrap()) && !verify_to(&answers, NodeId::new(b).unwrap()));
    }
}

#[test]
fn a_holder_that_keeps_sending_commands_is_not_found_gone() {
    // A loader that does not answer Verify Node ID but is plainly there (it sends commands).
    let mut pair = Pair::new(NodeConfig::default(), server_with(NodeConfig::default(), 16));
    pair.pump();
    command_from(&mut pair, GONE, &Command::Freeze { space: 0xEF }.to_bytes());
    let freeze = Command::Freeze { space: 0xEF }.to_bytes();
    assert!(rejected_with(&command_from(&mut pair, CLIENT, &freeze), 0x2000));
    let image = command_from(&mut pair, GONE, &[0x20, 0x00, 0, 0, 0, 0, 0xEF, 0xAA]);
    assert_eq!(image[0].mti, Mti::DATAGRAM_RECEIVED_OK, "{image:?}");
    pair.now += Duration::from_millis(600);
    pair.server.handle_timeout(pair.now);
    assert_eq!(pair.server.memory_server().unwrap().stats().holders_gone, 0);
    let again = command_from(&mut pair, CLIENT, &freeze);
    assert!(!again.iter().any(|m| m.mti == Mti::DATAGRAM_RECEIVED_OK), "the owner's upgrade stays: {again:?}");
}
