//! Memory Configuration clients and servers on the harness when a transfer cannot do what
//! was asked: the client is told, and no space holds what nobody completed.

use openlcb_loopback::{Network, NodeIndex, NodeOptions};
use openlcb_node::{MemoryError, MemoryEvent, MemoryServer, NodeEvent, RamSpace, TransferPath};
use openlcb_stream::{Duration, Instant, NodeId};

const KIB64: u32 = 64 * 1024;

fn node(n: u64) -> NodeId {
    NodeId::new(0x0501_0101_4000 + n).unwrap()
}

fn pattern(len: u32, key: u32) -> Vec<u8> {
    (0..len).map(|i| (i.wrapping_mul(2_654_435_761).wrapping_add(key) >> 13) as u8).collect()
}

/// A 64 KiB configuration space (a pattern) and a 128 KiB firmware target.
fn server() -> MemoryServer {
    MemoryServer::new()
        .with_space(0xFD, RamSpace::from_bytes(pattern(KIB64, 1)))
        .with_space(0xEF, RamSpace::new(128 * 1024))
}

/// `clients` client nodes (numbered 1..) and one server (node 100) on a 125 kbit/s bus,
/// logged in.
fn bus(clients: u64) -> (Network, Vec<NodeIndex>, NodeIndex) {
    let mut net = Network::new(7);
    let bus = net.add_bus(125_000, 16);
    let clients = (1..=clients).map(|n| net.add_can_node(node(n), bus, NodeOptions::default())).collect();
    let options = NodeOptions { memory_server: Some(server), ..NodeOptions::default() };
    let server = net.add_can_node(node(100), bus, options);
    net.run_until(Instant::from_millis(1_000), 1_000_000).unwrap();
    (net, clients, server)
}

/// Runs until every one of `clients` raised the end of its operation (at most ten minutes
/// of virtual time); the events in the order of `clients`.
fn finish_all(net: &mut Network, clients: &[NodeIndex]) -> Vec<MemoryEvent> {
    let mut ends: Vec<Option<MemoryEvent>> = vec![None; clients.len()];
    let end = net.now() + Duration::from_secs(600);
    while net.now() < end && ends.iter().any(Option::is_none) {
        let step = net.now() + Duration::from_millis(250);
        net.run_until(step, 100_000_000).unwrap();
        for (slot, client) in ends.iter_mut().zip(clients) {
            for event in net.take_events(*client) {
                if let NodeEvent::Memory(
                    e @ (MemoryEvent::ReadDone { .. } | MemoryEvent::WriteDone { .. } | MemoryEvent::Failed { .. }),
                ) = event
                {
                    slot.get_or_insert(e);
                }
            }
        }
    }
    ends.into_iter().map(|e| e.expect("an operation never ended: a hang")).collect()
}

fn space(net: &mut Network, server: NodeIndex, number: u8) -> Vec<u8> {
    let s = net.node(server).unwrap().memory_server_mut().unwrap().space_mut(number).unwrap();
    let mut buf = vec![0; s.len() as usize];
    let n = s.read(0, &mut buf).unwrap();
    buf.truncate(n);
    buf
}

#[test]
fn a_stream_write_that_does_not_fit_is_refused_before_a_byte_is_sent() {
    for path in [TransferPath::Stream, TransferPath::Auto] {
        let (mut net, clients, server) = bus(1);
        let before = space(&mut net, server, 0xFD);
        let now = net.now();
        net.node(clients[0]).unwrap().write_memory(now, node(100), 0xFD, 65_000, pattern(1_000, 9), path).unwrap();
        let end = finish_all(&mut net, &clients);
        assert!(
            matches!(end[0], MemoryEvent::Failed { error: MemoryError::Failed(code), .. } if code.0 == 0x1082),
            "{path:?}: {end:?}"
        );
        assert!(space(&mut net, server, 0xFD) == before, "{path:?}: nothing written");
        // What fits is written, to the last byte of the space.
        let now = net.now();
        let tail = pattern(536, 10);
        net.node(clients[0]).unwrap().write_memory(now, node(100), 0xFD, 65_000, tail.clone(), path).unwrap();
        let end = finish_all(&mut net, &clients);
        assert!(matches!(end[0], MemoryEvent::WriteDone { len: 536, .. }), "{path:?}: {end:?}");
        assert!(space(&mut net, server, 0xFD)[65_000..] == tail[..], "{path:?}: the tail stored");
    }
}

/// The one of `ends` that succeeded (the other must have failed), and its index.
fn the_winner(ends: &[MemoryEvent]) -> usize {
    let done: Vec<usize> = (0..ends.len()).filter(|i| matches!(ends[*i], MemoryEvent::WriteDone { .. })).collect();
    assert_eq!(done.len(), 1, "exactly one succeeds: {ends:?}");
    done[0]
}

#[test]
fn two_writers_at_once_never_mix_their_data() {
    for path in [TransferPath::Datagrams, TransferPath::Stream] {
        let (mut net, clients, server) = bus(2);
        let images = [pattern(4_096, 21), pattern(4_096, 22)];
        let now = net.now();
        for (client, image) in clients.iter().zip(&images) {
            net.node(*client).unwrap().write_memory(now, node(100), 0xFD, 0, image.clone(), path).unwrap();
        }
        let ends = finish_all(&mut net, &clients);
        let winner = the_winner(&ends);
        let loser = &ends[1 - winner];
        assert!(
            matches!(loser, MemoryEvent::Failed { error: MemoryError::Locked { owner }, .. } if *owner == node(1 + winner as u64).as_raw()),
            "{path:?}: {loser:?}"
        );
        assert!(space(&mut net, server, 0xFD)[..4_096] == images[winner][..], "{path:?}: the winner's data, whole");
        // The lock was released: the other writes now.
        let now = net.now();
        let loser = clients[1 - winner];
        net.node(loser).unwrap().write_memory(now, node(100), 0xFD, 0, images[1 - winner].clone(), path).unwrap();
        let end = finish_all(&mut net, &[loser]);
        assert!(matches!(end[0], MemoryEvent::WriteDone { .. }), "{path:?}: {end:?}");
        assert!(space(&mut net, server, 0xFD)[..4_096] == images[1 - winner][..]);
    }
}

#[test]
fn two_firmware_loaders_at_once_one_fails_and_the_image_is_the_others() {
    for path in [TransferPath::Datagrams, TransferPath::Auto] {
        let (mut net, clients, server) = bus(2);
        let images = [pattern(20_000, 31), pattern(30_000, 32)];
        let now = net.now();
        for (client, image) in clients.iter().zip(&images) {
            net.node(*client).unwrap().upgrade_firmware(now, node(100), image.clone(), path).unwrap();
        }
        let ends = finish_all(&mut net, &clients);
        let winner = the_winner(&ends);
        assert!(
            matches!(ends[1 - winner], MemoryEvent::Failed { error: MemoryError::Rejected(code), .. } if code.0 == 0x1020),
            "{path:?}: {ends:?}"
        );
        let unfrozen = net.take_events(server).into_iter().find_map(|e| match e {
            NodeEvent::Memory(MemoryEvent::Unfrozen { image_len, .. }) => Some(image_len),
            _ => None,
        });
        assert_eq!(unfrozen, Some(images[winner].len() as u32), "{path:?}");
        let len = images[winner].len();
        assert!(space(&mut net, server, 0xEF)[..len] == images[winner][..], "{path:?}: the winner's image");
    }
}

/// (frame type nibble, destination alias, source alias) of a datagram frame, or for Datagram
/// OK/Rejected (type 0) the alias in its data.
fn datagram_frame(frame: &openlcb_can::CanFrame) -> Option<(u32, u16, u16)> {
    let id = frame.raw_id();
    let source = (id & 0xFFF) as u16;
    match id >> 24 {
        kind @ 0x1A..=0x1D => Some((kind, ((id >> 12) & 0xFFF) as u16, source)),
        0x19 if matches!((id >> 12) & 0xFFF, 0xA28 | 0xA48) => {
            let data = frame.payload();
            let to = u16::from_be_bytes([*data.first()?, *data.get(1)?]) & 0xFFF;
            Some((0, to, source))
        }
        _ => None,
    }
}

#[test]
fn every_datagram_sent_is_answered_exactly_once_under_a_crowd() {
    const CROWD: u64 = 60;
    let (mut net, clients, server) = bus(CROWD);
    // A crowd takes longer to log in.
    net.run_until(Instant::from_millis(10_000), 10_000_000).unwrap();
    let server_alias = net.can_alias(server).unwrap().as_raw();
    net.record_frames();
    let now = net.now();
    for client in &clients {
        // A 40-byte Write: a datagram of six frames, interleaved on the bus with the others.
        let write = openlcb_node::memconfig::wire::Command::Write { space: 0xFD, address: 0, data: vec![7; 34] };
        net.node(*client).unwrap().send_datagram(now, node(100), &write.to_bytes()).unwrap();
    }
    net.run_until(now + Duration::from_secs(120), 100_000_000).unwrap();
    let mut sent = std::collections::HashMap::<u16, i64>::new();
    for (_, frame) in net.recorded_frames() {
        match datagram_frame(frame) {
            // A datagram starts (first or only frame) towards the server.
            Some((0x1A | 0x1B, to, from)) if to == server_alias => *sent.entry(from).or_default() += 1,
            // The server answers it.
            Some((0, to, from)) if from == server_alias => *sent.entry(to).or_default() -= 1,
            _ => {}
        }
    }
    let unanswered: Vec<_> = sent.iter().filter(|(_, n)| **n != 0).collect();
    assert!(unanswered.is_empty(), "datagrams minus answers per sender: {unanswered:?}");
    for client in &clients {
        let delivered = net.take_events(*client).iter().any(|e| matches!(e, NodeEvent::DatagramDelivered { .. }));
        assert!(delivered, "each datagram is delivered in the end");
    }
}
