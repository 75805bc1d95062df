//! The Memory Configuration server against a peer driven message by message: what it stores
//! and what it answers when the peer's transfer goes wrong.

use openlcb_node::memconfig::wire::Command;
use openlcb_node::{MemoryEvent, MemoryServer, MemorySpace, Node, NodeConfig, NodeEvent, RamSpace, SpaceError};
use openlcb_stream::{Instant, Message, Mti, NodeId};

const PEER: NodeId = NodeId::from_bytes([5, 1, 1, 1, 0x40, 1]);
const SERVER: NodeId = NodeId::from_bytes([5, 1, 1, 1, 0x40, 2]);
const SPACE_LEN: u32 = 65_536;

fn pattern(len: usize, key: u8) -> Vec<u8> {
    (0..len).map(|i| (i as u8).wrapping_mul(31).wrapping_add(key) ^ (i >> 8) as u8).collect()
}

/// A server with a 64 KiB configuration space of zeros and a 128 KiB firmware space.
fn server() -> Node {
    let memory =
        MemoryServer::new().with_space(0xFD, RamSpace::new(SPACE_LEN)).with_space(0xEF, RamSpace::new(128 * 1024));
    let mut node = Node::new(SERVER, NodeConfig::default()).with_memory_server(memory);
    let _ = std::iter::from_fn(|| node.poll_transmit()).count();
    node
}

/// Hands `server` one message from `from`; returns what it sends back (its events dropped).
fn deliver(server: &mut Node, from: NodeId, mti: Mti, payload: Vec<u8>) -> Vec<Message> {
    deliver_seeing(server, from, mti, payload, &mut Vec::new())
}

/// [`deliver`], keeping the events the message raised in `events`.
fn deliver_seeing(
    server: &mut Node,
    from: NodeId,
    mti: Mti,
    payload: Vec<u8>,
    events: &mut Vec<NodeEvent>,
) -> Vec<Message> {
    deliver_at(server, Instant::ZERO, from, mti, payload, events)
}

/// [`deliver_seeing`] at `now`.
fn deliver_at(
    server: &mut Node,
    now: Instant,
    from: NodeId,
    mti: Mti,
    payload: Vec<u8>,
    events: &mut Vec<NodeEvent>,
) -> Vec<Message> {
    server.handle_message(now, Message::addressed(mti, from, SERVER, payload).as_ref());
    events.extend(std::iter::from_fn(|| server.poll_event()));
    std::iter::from_fn(|| server.poll_transmit()).collect()
}

fn space(server: &mut Node, number: u8) -> Vec<u8> {
    let s = server.memory_server_mut().unwrap().space_mut(number).unwrap();
    let mut buf = vec![0; s.len() as usize];
    let n = s.read(0, &mut buf).unwrap();
    buf.truncate(n);
    buf
}

/// Opens a Write Stream from `from` into `space` at `address` (SID 0x42, window 2048);
/// returns the DID the server assigned.
fn open_write_stream(server: &mut Node, from: NodeId, space: u8, address: u32) -> u8 {
    let command = Command::WriteStream { space, address, source_stream: 0x42 };
    let answers = deliver(server, from, Mti::DATAGRAM, command.to_bytes());
    assert_eq!(answers.first().map(|m| m.mti), Some(Mti::DATAGRAM_RECEIVED_OK), "{answers:?}");
    let reply = deliver(server, from, Mti::STREAM_INITIATE_REQUEST, vec![0x08, 0x00, 0, 0, 0x42, 0xFF]);
    let accepted = reply.iter().find(|m| m.mti == Mti::STREAM_INITIATE_REPLY).expect("an Initiate Reply");
    assert_eq!(accepted.payload[2] & 0x80, 0x80, "accepted: {accepted:?}");
    accepted.payload[5]
}

#[test]
fn a_stream_write_past_the_end_stores_every_byte_that_fits_then_ends_with_tde() {
    let mut server = server();
    let did = open_write_stream(&mut server, PEER, 0xFD, 65_000);
    let data = pattern(1_000, 3);
    let mut answers = Vec::new();
    for chunk in data.chunks(200) {
        let mut payload = vec![did];
        payload.extend_from_slice(chunk);
        answers.extend(deliver(&mut server, PEER, Mti::STREAM_DATA_SEND, payload));
    }
    let stored = space(&mut server, 0xFD);
    assert_eq!(stored[65_000..], data[..536], "the 536 bytes that fit are stored");
    let tde = answers.iter().find(|m| m.mti == Mti::TERMINATE_DUE_TO_ERROR).expect("TDE");
    assert_eq!(tde.payload[..2], [0x10, 0x82][..], "out of bounds: {tde:?}");
}

const OTHER: NodeId = NodeId::from_bytes([5, 1, 1, 1, 0x40, 3]);

fn command(server: &mut Node, from: NodeId, command: &Command) -> Vec<Message> {
    deliver(server, from, Mti::DATAGRAM, command.to_bytes())
}

/// The first answer: `Ok(flags)` for Datagram Received OK, `Err(code)` for Rejected.
fn answer(answers: &[Message]) -> Result<Vec<u8>, u16> {
    let first = answers.iter().find(|m| matches!(m.mti, Mti::DATAGRAM_RECEIVED_OK | Mti::DATAGRAM_REJECTED));
    match first {
        Some(m) if m.mti == Mti::DATAGRAM_RECEIVED_OK => Ok(m.payload.clone()),
        Some(m) => Err(u16::from_be_bytes([m.payload[0], m.payload[1]])),
        None => panic!("no answer in {answers:?}"),
    }
}

/// Unfreeze from `from`: its answer and the events it raised.
fn unfreeze(server: &mut Node, from: NodeId) -> (Result<Vec<u8>, u16>, Vec<NodeEvent>) {
    let mut events = Vec::new();
    let bytes = Command::Unfreeze { space: 0xEF }.to_bytes();
    let answers = deliver_seeing(server, from, Mti::DATAGRAM, bytes, &mut events);
    (answer(&answers), events)
}

/// Streams `data` into the open Write Stream `did` (SID 0x42) and completes it, in messages
/// that never cross a window boundary (2048 bytes), each Proceed taken as it comes.
fn stream_image(server: &mut Node, from: NodeId, did: u8, data: &[u8]) {
    for chunk in data.chunks(256) {
        let mut payload = vec![did];
        payload.extend_from_slice(chunk);
        deliver(server, from, Mti::STREAM_DATA_SEND, payload);
    }
    let count = (data.len() as u32).to_be_bytes();
    let complete = vec![0x42, did, count[0], count[1], count[2], count[3]];
    deliver(server, from, Mti::STREAM_DATA_COMPLETE, complete);
}

#[test]
fn a_firmware_stream_ended_by_tde_is_refused_at_unfreeze_and_a_retry_succeeds() {
    let mut server = server();
    assert!(answer(&command(&mut server, PEER, &Command::Freeze { space: 0xEF })).is_ok());
    let did = open_write_stream(&mut server, PEER, 0xEF, 0);
    let mut payload = vec![did];
    payload.extend_from_slice(&pattern(1_000, 1));
    deliver(&mut server, PEER, Mti::STREAM_DATA_SEND, payload);
    // The loader gives up: TDE, then Unfreeze.
    deliver(&mut server, PEER, Mti::TERMINATE_DUE_TO_ERROR, vec![0x10, 0x00]);
    let (answered, events) = unfreeze(&mut server, PEER);
    assert_eq!(answered, Err(0x1089), "an aborted image is refused");
    assert!(events.iter().any(|e| matches!(e, NodeEvent::Memory(MemoryEvent::UpgradeRefused { .. }))));
    assert!(server.memory_server().unwrap().is_frozen(), "still frozen for a retry");
    // The retry starts again at offset 0 and completes.
    let image = pattern(3_000, 2);
    let did = open_write_stream(&mut server, PEER, 0xEF, 0);
    stream_image(&mut server, PEER, did, &image);
    let (answered, events) = unfreeze(&mut server, PEER);
    assert!(answered.is_ok(), "{answered:?}");
    assert!(events.iter().any(|e| matches!(e, NodeEvent::Memory(MemoryEvent::Unfrozen { image_len: 3_000, .. }))));
    assert!(!server.memory_server().unwrap().is_frozen());
    assert_eq!(space(&mut server, 0xEF)[..3_000], image[..]);
}

#[test]
fn only_the_node_that_froze_may_write_the_firmware_space_or_unfreeze() {
    let mut server = server();
    assert!(answer(&command(&mut server, PEER, &Command::Freeze { space: 0xEF })).is_ok());
    let write = |data: Vec<u8>| Command::Write { space: 0xEF, address: 0, data };
    assert!(answer(&command(&mut server, PEER, &write(vec![1; 64]))).is_ok());
    // A bystander is refused for now (0x2000) while the owner is asked whether it is still
    // here; it answers, and the bystander's Freeze, its writes by datagram and by stream,
    // its Unfreeze are refused for good.
    assert_eq!(answer(&command(&mut server, OTHER, &Command::Freeze { space: 0xEF })), Err(0x2000));
    server.handle_message(Instant::ZERO, Message::verified_node_id(PEER).as_ref());
    assert_eq!(answer(&command(&mut server, OTHER, &Command::Freeze { space: 0xEF })), Err(0x1020));
    assert_eq!(answer(&command(&mut server, OTHER, &write(vec![2; 64]))), Err(0x1020));
    let stream = Command::WriteStream { space: 0xEF, address: 0, source_stream: 7 };
    assert_eq!(answer(&command(&mut server, OTHER, &stream)), Err(0x1020));
    assert_eq!(unfreeze(&mut server, OTHER).0, Err(0x1020));
    assert!(server.memory_server().unwrap().is_frozen());
    // The owner's image is what it wrote.
    let (answered, events) = unfreeze(&mut server, PEER);
    assert!(answered.is_ok());
    let unfrozen = events.into_iter().find_map(|e| match e {
        NodeEvent::Memory(MemoryEvent::Unfrozen { by, image_len }) => Some((by, image_len)),
        _ => None,
    });
    assert_eq!(unfrozen, Some((PEER, 64)));
    assert_eq!(space(&mut server, 0xEF)[..64], [1; 64]);
}

/// A RAM space that counts its writes and commits (shared, to be read after the server
/// took the space) and, as `broken_flash`, cannot store an image (its `complete` fails).
struct TestSpace {
    ram: RamSpace,
    counts: std::sync::Arc<std::sync::Mutex<(usize, usize)>>,
    broken_flash: bool,
}

impl TestSpace {
    fn new(len: u32) -> Self {
        TestSpace { ram: RamSpace::new(len), counts: Default::default(), broken_flash: false }
    }
}

impl MemorySpace for TestSpace {
    fn len(&self) -> u32 {
        self.ram.len()
    }
    fn read_only(&self) -> bool {
        false
    }
    fn read(&mut self, address: u32, buf: &mut [u8]) -> Result<usize, SpaceError> {
        self.ram.read(address, buf)
    }
    fn write(&mut self, address: u32, data: &[u8]) -> Result<(), SpaceError> {
        self.counts.lock().unwrap().0 += 1;
        self.ram.write(address, data)
    }
    fn commit(&mut self) -> Result<(), SpaceError> {
        self.counts.lock().unwrap().1 += 1;
        Ok(())
    }
    fn complete(&mut self, _len: u32) -> Result<(), SpaceError> {
        if self.broken_flash { Err(SpaceError::Failed(openlcb_stream::wire::ErrorCode(0x2088))) } else { Ok(()) }
    }
}

#[test]
fn an_image_the_space_cannot_store_refuses_the_unfreeze_with_its_code() {
    let memory = MemoryServer::new().with_space(0xEF, TestSpace { broken_flash: true, ..TestSpace::new(4096) });
    let mut server = Node::new(SERVER, NodeConfig::default()).with_memory_server(memory);
    let _ = std::iter::from_fn(|| server.poll_transmit()).count();
    assert!(answer(&command(&mut server, PEER, &Command::Freeze { space: 0xEF })).is_ok());
    let write = Command::Write { space: 0xEF, address: 0, data: vec![9; 64] };
    assert!(answer(&command(&mut server, PEER, &write)).is_ok());
    let (answered, events) = unfreeze(&mut server, PEER);
    assert_eq!(answered, Err(0x2088));
    assert!(server.memory_server().unwrap().is_frozen());
    let refused = events.iter().any(
        |e| matches!(e, NodeEvent::Memory(MemoryEvent::UpgradeRefused { by, code }) if *by == PEER && code.0 == 0x2088),
    );
    assert!(refused, "the application is told");
}

#[test]
fn writes_of_others_are_refused_while_the_lock_is_held_until_it_lapses() {
    let mut server = server();
    let lock = Command::Lock { node: PEER.as_raw() };
    assert!(answer(&command(&mut server, PEER, &lock)).is_ok());
    let write = Command::Write { space: 0xFD, address: 0, data: vec![5; 8] };
    assert_eq!(answer(&command(&mut server, OTHER, &write)), Err(0x2000), "locked: temporary");
    let stream = Command::WriteStream { space: 0xFD, address: 0, source_stream: 7 };
    assert_eq!(answer(&command(&mut server, OTHER, &stream)), Err(0x2000));
    assert!(answer(&command(&mut server, PEER, &write)).is_ok(), "the owner writes");
    // The owner goes silent: the lock lapses after `lock_timeout` (10 s).
    let later = Instant::ZERO + openlcb_stream::Duration::from_secs(11);
    let answers = deliver_at(&mut server, later, OTHER, Mti::DATAGRAM, write.to_bytes(), &mut Vec::new());
    assert!(answer(&answers).is_ok(), "{answers:?}");
}

#[test]
fn a_peer_that_never_acknowledges_its_replies_does_not_starve_the_others() {
    let mut server = server();
    let read = Command::Read { space: 0xFD, address: 0, count: 16 };
    let mut promised = 0;
    let mut refused = 0;
    for _ in 0..40 {
        // Every Read is answered once: OK with a reply promised, or 0x2020 (none dropped).
        let answers = command(&mut server, PEER, &read);
        match answer(&answers) {
            Ok(flags) => {
                assert_eq!(flags, [0x80]);
                promised += 1;
            }
            Err(code) => {
                assert_eq!(code, 0x2020);
                refused += 1;
            }
        }
    }
    assert!(promised <= 4 && promised + refused == 40, "{promised} promised, {refused} refused");
    // Another node's read is answered, and its reply goes out at once.
    let answers = command(&mut server, OTHER, &read);
    assert_eq!(answer(&answers), Ok(vec![0x80]), "{answers:?}");
    assert!(answers.iter().any(|m| m.mti == Mti::DATAGRAM && m.destination == Some(OTHER)), "{answers:?}");
    // Every reply promised to the silent peer still goes out, one per datagram timeout.
    let mut replies = 0;
    let mut now = Instant::ZERO;
    for _ in 0..100 {
        let Some(next) = server.poll_timeout() else { break };
        now = now.max(next);
        server.handle_timeout(now);
        while server.poll_event().is_some() {}
        replies += std::iter::from_fn(|| server.poll_transmit())
            .filter(|m| m.mti == Mti::DATAGRAM && m.destination == Some(PEER))
            .count();
    }
    assert!(replies >= promised - 1, "{replies} of {promised} replies sent after the first");
}

/// A firmware space whose image cannot be read back.
struct WriteOnlyFlash(RamSpace);

impl MemorySpace for WriteOnlyFlash {
    fn len(&self) -> u32 {
        self.0.len()
    }
    fn read_only(&self) -> bool {
        false
    }
    fn write_only(&self) -> bool {
        true
    }
    fn read(&mut self, address: u32, buf: &mut [u8]) -> Result<usize, SpaceError> {
        self.0.read(address, buf)
    }
    fn write(&mut self, address: u32, data: &[u8]) -> Result<(), SpaceError> {
        self.0.write(address, data)
    }
}

#[test]
fn a_read_of_a_write_only_space_is_refused_with_not_implemented_by_datagram_and_by_stream() {
    let memory = MemoryServer::new().with_space(0xEF, WriteOnlyFlash(RamSpace::new(4096)));
    let mut server = Node::new(SERVER, NodeConfig::default()).with_memory_server(memory);
    let _ = std::iter::from_fn(|| server.poll_transmit()).count();
    let read = Command::Read { space: 0xEF, address: 0, count: 64 };
    let answers = command(&mut server, PEER, &read);
    assert_eq!(answer(&answers), Err(0x1040), "{answers:?}");
    assert!(!answers.iter().any(|m| m.mti == Mti::DATAGRAM), "no Read Reply follows a rejection: {answers:?}");
    let stream = Command::ReadStream { space: 0xEF, address: 0, destination_stream: 0x20, count: u32::MAX };
    let answers = command(&mut server, PEER, &stream);
    assert_eq!(answer(&answers), Err(0x1040), "{answers:?}");
    assert!(!answers.iter().any(|m| m.mti == Mti::STREAM_INITIATE_REQUEST), "no stream: {answers:?}");
    // Writing it still works (while frozen), and the space is still reported as present.
    assert!(answer(&command(&mut server, PEER, &Command::Freeze { space: 0xEF })).is_ok());
    let write = Command::Write { space: 0xEF, address: 0, data: vec![9; 64] };
    assert!(answer(&command(&mut server, PEER, &write)).is_ok());
}

#[test]
fn one_peer_takes_at_most_half_of_the_stream_transfers() {
    // Eight stream transfers (the default); a peer that asks for more than four is refused
    // with 0x2020, and another peer still gets one.
    let mut server = server();
    let read = |did: u8| Command::ReadStream { space: 0xFD, address: 0, destination_stream: did, count: 0 };
    for did in 0..4 {
        assert!(answer(&command(&mut server, PEER, &read(did))).is_ok(), "read stream {did}");
    }
    assert_eq!(answer(&command(&mut server, PEER, &read(4))), Err(0x2020), "a fifth for the same peer");
    const OTHER: NodeId = NodeId::from_bytes([5, 1, 1, 1, 0x40, 3]);
    assert!(answer(&command(&mut server, OTHER, &read(0))).is_ok(), "room left for another peer");
}

#[test]
fn a_write_stream_source_past_its_window_gets_tde_and_nothing_past_the_window_is_stored() {
    // 28 000 bytes into the 2 048-byte window at once: no Proceed left the server meanwhile.
    let mut server = server();
    let did = open_write_stream(&mut server, PEER, 0xFD, 0);
    let data = pattern(28_000, 5);
    for chunk in data.chunks(256) {
        let payload = [&[did][..], chunk].concat();
        server.handle_message(Instant::ZERO, Message::addressed(Mti::STREAM_DATA_SEND, PEER, SERVER, payload).as_ref());
    }
    let answers: Vec<Message> = std::iter::from_fn(|| server.poll_transmit()).collect();
    let tde = answers.iter().find(|m| m.mti == Mti::TERMINATE_DUE_TO_ERROR).expect("TDE");
    assert_eq!(tde.payload, [0x20, 0x40, 0x1F, 0x88], "{tde:?}");
    let stored = space(&mut server, 0xFD);
    assert_eq!(stored[..2048], data[..2048], "the window is stored");
    assert!(stored[2048..].iter().all(|b| *b == 0), "nothing past the window");
    // A source that waits for each Proceed is never cut off.
    let did = open_write_stream(&mut server, PEER, 0xFD, 0);
    let mut answers = Vec::new();
    for chunk in data.chunks(256) {
        answers.extend(deliver(&mut server, PEER, Mti::STREAM_DATA_SEND, [&[did][..], chunk].concat()));
    }
    assert!(answers.iter().all(|m| m.mti != Mti::TERMINATE_DUE_TO_ERROR), "{answers:?}");
    assert_eq!(space(&mut server, 0xFD)[..28_000], data[..]);
}

#[test]
fn a_space_commits_once_per_write_command_and_once_per_write_stream() {
    let watched = TestSpace::new(SPACE_LEN);
    let counts = watched.counts.clone();
    let memory = MemoryServer::new().with_space(0xFD, watched);
    let mut server = Node::new(SERVER, NodeConfig::default()).with_memory_server(memory);
    let _ = std::iter::from_fn(|| server.poll_transmit()).count();
    for address in [0, 64] {
        let write = Command::Write { space: 0xFD, address, data: vec![1; 64] };
        assert!(answer(&command(&mut server, PEER, &write)).is_ok());
    }
    assert_eq!(*counts.lock().unwrap(), (2, 2), "a commit per Write datagram");
    let did = open_write_stream(&mut server, PEER, 0xFD, 0);
    stream_image(&mut server, PEER, did, &pattern(20_000, 4));
    let (writes, commits) = *counts.lock().unwrap();
    assert!(writes > 10, "the stream's bytes came in pieces: {writes}");
    assert_eq!(commits, 3, "one commit for the whole transfer");
    assert_eq!(space(&mut server, 0xFD)[..20_000], pattern(20_000, 4)[..]);
}
