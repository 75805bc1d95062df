//! The Memory Configuration server against a peer driven message by message: what it stores
//! and what it answers when the peer's transfer goes wrong.

use openlcb_node::memconfig::wire::Command;
use openlcb_node::{MemoryServer, Node, NodeConfig, RamSpace};
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

/// Hands `server` one message from `from`; returns what it sends back (its events drained).
fn deliver(server: &mut Node, from: NodeId, mti: Mti, payload: Vec<u8>) -> Vec<Message> {
    server.handle_message(Instant::ZERO, Message::addressed(mti, from, SERVER, payload).as_ref());
    while server.poll_event().is_some() {}
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
