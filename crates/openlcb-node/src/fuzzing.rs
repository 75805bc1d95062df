//! Fuzzing entry points (`cargo fuzz`, see `fuzz/`). Not part of the public API.

use alloc::vec::Vec;

use arbitrary::{Arbitrary, Unstructured};
use openlcb_stream::{Duration, Instant, Message, MessageRef, Mti, NodeId, PeerChange};

use crate::{DatagramAnswer, Node, NodeConfig, NodeEvent, OkFlags, SnipInfo};

/// SNIP: any bytes parse without panic, and what a parsed reply re-emits parses to the same
/// strings (cut to the standard's lengths), within the reply bound.
pub fn snip_roundtrip(data: &[u8]) {
    let info = SnipInfo::parse(data);
    let payload = info.to_payload();
    assert!(payload.len() <= crate::MAX_REPLY_LEN);
    let again = SnipInfo::parse(&payload);
    assert_eq!(again.to_payload(), payload, "emit is stable");
    if info.check().is_ok() {
        assert_eq!(again, info, "strings within their limits survive a round trip");
    }
}

const PEERS: [NodeId; 3] = [
    NodeId::from_bytes([5, 1, 1, 1, 0x40, 1]),
    NodeId::from_bytes([5, 1, 1, 1, 0x40, 3]),
    NodeId::from_bytes([0, 0, 0, 0, 0x03, 0x21]),
];

#[derive(Debug, Arbitrary)]
enum Op {
    /// A message from a peer: an MTI from a list of interesting ones (or any), a payload.
    Message {
        peer: u8,
        mti: u16,
        pick: u8,
        payload: Vec<u8>,
    },
    SendDatagram {
        peer: u8,
        payload: Vec<u8>,
    },
    Answer {
        peer: u8,
        ok: bool,
        flags: u8,
        code: u16,
    },
    RequestSnip {
        peer: u8,
    },
    Rename {
        from: u8,
        to: u8,
    },
    PeerLost {
        peer: u8,
    },
    LinkLost,
    Advance {
        millis: u16,
    },
}

const MTIS: [Mti; 14] = [
    Mti::DATAGRAM,
    Mti::DATAGRAM_RECEIVED_OK,
    Mti::DATAGRAM_REJECTED,
    Mti::OPTIONAL_INTERACTION_REJECTED,
    Mti::TERMINATE_DUE_TO_ERROR,
    Mti::SIMPLE_NODE_INFO_REQUEST,
    Mti::SIMPLE_NODE_INFO_REPLY,
    Mti::VERIFY_NODE_ID_GLOBAL,
    Mti::VERIFY_NODE_ID_ADDRESSED,
    Mti::PROTOCOL_SUPPORT_INQUIRY,
    Mti::INITIALIZATION_COMPLETE,
    Mti::STREAM_INITIATE_REQUEST,
    Mti::STREAM_DATA_SEND,
    Mti::STREAM_DATA_COMPLETE,
];

/// Random messages and commands on one node: no panic; every queue within its bound; every
/// datagram sent ends (delivered or failed) once the peers go quiet long enough.
pub fn node_ops(data: &[u8]) {
    let mut u = Unstructured::new(data);
    let Ok(ops) = Vec::<Op>::arbitrary(&mut u) else { return };
    let local = NodeId::from_bytes([5, 1, 1, 1, 0x40, 2]);
    let mut config = NodeConfig::default();
    config.datagrams.claimed = alloc::vec![0x20];
    config.datagrams.max_outgoing = 4;
    config.datagrams.max_awaiting_answer = 2;
    config.transmit_queue_limit = 16;
    config.max_snip_requests = 2;
    // Answers are capped by the queue limit; a TDE that ends a stream also goes to each of its
    // siblings with that peer (at most the per-peer stream bound).
    let limit = config.transmit_queue_limit + config.stream.max_streams_per_peer;
    let mut node = Node::new(local, config);
    let mut now = Instant::ZERO;
    let mut open = Vec::new();
    let peer = |i: u8| PEERS.get(usize::from(i) % PEERS.len()).copied().unwrap_or(PEERS[0]);
    let index = |i: u8| usize::from(i) % PEERS.len();
    // Per peer: datagrams received minus answers (OK or Rejected) sent to it. Each datagram
    // gets exactly one answer, to its sender (under its new name after a rename): never
    // below 0, 0 in the end.
    let mut unanswered = [0i64; PEERS.len()];
    for op in ops {
        match op {
            Op::Message { peer: p, mti, pick, payload } => {
                let mti = MTIS.get(usize::from(pick)).copied().unwrap_or(Mti(mti));
                let destination = mti.is_addressed().then_some(local);
                if let Some(n) = unanswered.get_mut(index(p)) {
                    match mti {
                        Mti::DATAGRAM => *n += 1,
                        // Initialization Complete (full or simple): the sender restarted, and
                        // what it sent before needs no answer.
                        Mti(0x0100 | 0x0101) => *n = 0,
                        _ => {}
                    }
                }
                node.handle_message(now, MessageRef { mti, source: peer(p), destination, payload: &payload });
            }
            Op::SendDatagram { peer: p, payload } => {
                if let Ok(id) = node.send_datagram(now, peer(p), &payload) {
                    open.push(id);
                }
            }
            Op::Answer { peer: p, ok, flags, code } => {
                let answer = if ok {
                    DatagramAnswer::Ok(OkFlags::from_byte(flags))
                } else {
                    DatagramAnswer::Rejected(openlcb_stream::wire::ErrorCode(code))
                };
                let _ = node.answer_datagram(peer(p), answer);
            }
            Op::RequestSnip { peer: p } => {
                let _ = node.request_snip(now, peer(p));
            }
            Op::Rename { from, to } => {
                if index(from) != index(to) {
                    let moved = unanswered.get_mut(index(from)).map(core::mem::take).unwrap_or(0);
                    if let Some(n) = unanswered.get_mut(index(to)) {
                        *n += moved;
                    }
                }
                node.peer_changed(PeerChange::Renamed { from: peer(from), to: peer(to) });
            }
            Op::PeerLost { peer: p } => {
                // Nobody is left to answer.
                if let Some(n) = unanswered.get_mut(index(p)) {
                    *n = 0;
                }
                node.peer_changed(PeerChange::Lost(peer(p)));
            }
            Op::LinkLost => {
                unanswered = [0; PEERS.len()];
                node.link_lost();
            }
            Op::Advance { millis } => {
                now += Duration::from_millis(u64::from(millis));
                node.handle_timeout(now);
            }
        }
        let mut sent = 0;
        while let Some(message) = node.poll_transmit() {
            sent += 1;
            count_answer(&message, &mut unanswered);
        }
        check_answers(&unanswered, false);
        // Each op adds a bounded number of other messages.
        assert!(sent <= limit + 8, "{sent} messages after one op");
        drain(&mut node, &mut open);
    }
    // Liveness: a long quiet time later, every datagram has ended, and every datagram
    // received has had its answer.
    for _ in 0..8 {
        now += Duration::from_secs(10);
        node.handle_timeout(now);
        while let Some(message) = node.poll_transmit() {
            count_answer(&message, &mut unanswered);
        }
        drain(&mut node, &mut open);
    }
    assert!(open.is_empty(), "datagrams never ended: {open:?}");
    check_answers(&unanswered, true);
}

/// `peer` restarted or left: nothing owed to it is counted any more.
fn forget(owed: &mut [i64; PEERS.len()], peer: NodeId) {
    if let Some(n) = PEERS.iter().position(|p| *p == peer).and_then(|i| owed.get_mut(i)) {
        *n = 0;
    }
}

/// Counts `message` if it answers a datagram of one of [`PEERS`].
fn count_answer(message: &openlcb_stream::Message, unanswered: &mut [i64; PEERS.len()]) {
    let answer = matches!(message.mti, Mti::DATAGRAM_RECEIVED_OK | Mti::DATAGRAM_REJECTED);
    let index = PEERS.iter().position(|p| Some(*p) == message.destination);
    if let (true, Some(n)) = (answer, index.and_then(|i| unanswered.get_mut(i))) {
        *n -= 1;
    }
}

/// No datagram answered twice; at the `end`, none left without an answer.
fn check_answers(unanswered: &[i64; PEERS.len()], end: bool) {
    assert!(unanswered.iter().all(|n| *n >= 0), "a datagram answered twice: {unanswered:?}");
    assert!(!end || unanswered.iter().all(|n| *n == 0), "datagrams never answered: {unanswered:?}");
}

fn drain(node: &mut Node, open: &mut Vec<crate::DatagramId>) {
    while let Some(event) = node.poll_event() {
        match event {
            NodeEvent::DatagramDelivered { id, .. } | NodeEvent::DatagramFailed { id, .. } => open.retain(|o| *o != id),
            _ => {}
        }
    }
}

/// Memory Configuration commands and replies: any bytes parse without panic, and what
/// parses re-emits to bytes that parse to the same value (emission is stable after that).
pub fn memconfig_roundtrip(data: &[u8]) {
    use crate::memconfig::{Command, Reply};
    // Half the inputs get the content ID, so most reach the command decoders.
    let mut prefixed = Vec::with_capacity(data.len() + 1);
    prefixed.push(crate::memconfig::wire::CONTENT_ID);
    prefixed.extend_from_slice(data);
    for input in [data, &prefixed[..]] {
        if let Ok(command) = Command::parse(input) {
            let bytes = command.to_bytes();
            assert!(bytes.len() <= crate::MAX_DATAGRAM_LEN, "{command:?} emits {} bytes", bytes.len());
            assert_eq!(Command::parse(&bytes).as_ref(), Ok(&command), "{input:02X?} -> {bytes:02X?}");
            assert_eq!(Command::parse(&bytes).map(|c| c.to_bytes()), Ok(bytes));
        }
        if let Ok(reply) = Reply::parse(input) {
            let bytes = reply.to_bytes();
            assert_eq!(Reply::parse(&bytes).as_ref(), Ok(&reply), "{input:02X?} -> {bytes:02X?}");
            assert_eq!(Reply::parse(&bytes).map(|r| r.to_bytes()), Ok(bytes));
        }
    }
}

/// What a peer does to a memory server.
#[derive(Debug, Arbitrary)]
enum ServerOp {
    /// A well-formed command built from these fields (`kind` picks which).
    Command {
        peer: u8,
        kind: u8,
        space: u8,
        address: u16,
        count: u8,
        stream: u8,
        data: Vec<u8>,
    },
    /// Any datagram with content ID 0x20.
    Raw {
        peer: u8,
        bytes: Vec<u8>,
    },
    /// Stream traffic for the server's transfers: `kind` picks the MTI; the IDs are the
    /// last ones the server used, or `stream`.
    Stream {
        peer: u8,
        kind: u8,
        stream: u8,
        payload: Vec<u8>,
    },
    /// Datagram OK or Rejected for the server's reply datagrams.
    Answer {
        peer: u8,
        ok: bool,
        code: u16,
    },
    Restart {
        peer: u8,
    },
    PeerLost {
        peer: u8,
    },
    Advance {
        millis: u16,
    },
}

/// Random commands and stream messages against a memory server: no panic; the spaces keep
/// their sizes; reads never return bytes beyond a space; stream transfers within their
/// bound; every datagram within 72 bytes; and once the peers go quiet, no transfer is left.
pub fn memconfig_server_ops(data: &[u8]) {
    use crate::memconfig::{Command, MemoryServer, RamSpace, ReadOnlySpace, Reply};
    let mut u = Unstructured::new(data);
    let Ok(ops) = Vec::<ServerOp>::arbitrary(&mut u) else { return };
    let local = NodeId::from_bytes([5, 1, 1, 1, 0x40, 2]);
    let mut config = NodeConfig::default();
    config.memory.max_server_streams = 2;
    config.stream.max_window = 64;
    let bound = config.memory.max_server_streams;
    let server = MemoryServer::new()
        .with_space(0xFD, RamSpace::new(300))
        .with_space(0x10, RamSpace::new(5))
        .with_space(0xFF, ReadOnlySpace::cdi("<cdi/>"))
        .with_space(0xEF, RamSpace::new(200))
        .with_acdi()
        .with_unique_ids([[1; 8], [2; 8]]);
    let mut node = Node::new(local, config).with_memory_server(server);
    let sizes = [(0xFD, 300), (0x10, 5), (0xFF, 7), (0xEF, 200)];
    let mut now = Instant::ZERO;
    let peer = |i: u8| PEERS.get(usize::from(i) % PEERS.len()).copied().unwrap_or(PEERS[0]);
    let spaces = [0xFD, 0x10, 0xFF, 0xEF, 0xFC, 0xFB, 0x33];
    // The last stream IDs the server put on the wire (SID, DID), for stream ops.
    let mut ids = (0u8, 0u8);
    // The model: space 0xFD as the datagram writes the server accepted left it (`None` once a
    // stream wrote it); per peer, replies promised by an OK with Reply Pending and not yet
    // sent; the node whose Freeze the server accepted, and whether it has gone since.
    let mut shadow: Option<Vec<u8>> = Some(alloc::vec![0; 300]);
    let mut promised = [0i64; PEERS.len()];
    let mut owner: Option<(NodeId, bool)> = None;
    for op in ops {
        // The command a peer sent in this step, to judge the server's answer by.
        let mut sent_command: Option<(NodeId, Command)> = None;
        let message = |mti, p: u8, payload: &[u8], node: &mut Node, now| {
            let destination = Some(local);
            node.handle_message(now, MessageRef { mti, source: peer(p), destination, payload });
        };
        match op {
            ServerOp::Command { peer: p, kind, space, address, count, stream, data } => {
                let space = spaces.get(usize::from(space) % spaces.len()).copied().unwrap_or(0xFD);
                let address = u32::from(address);
                let mut data = data;
                data.truncate(64);
                if data.is_empty() {
                    data.push(count);
                }
                let command = match kind % 12 {
                    0 => Command::Read { space, address, count },
                    1 => Command::Write { space, address, data },
                    2 => Command::WriteUnderMask { space, address, mask: data.clone(), data },
                    3 => Command::ReadStream { space, address, destination_stream: stream, count: u32::from(count) },
                    4 => Command::WriteStream { space, address, source_stream: stream },
                    5 => Command::GetOptions,
                    6 => Command::GetSpaceInfo { space },
                    7 => Command::Lock { node: u64::from(count) },
                    8 => Command::GetUniqueId { count },
                    9 => Command::Freeze { space },
                    10 => Command::Unfreeze { space },
                    _ => Command::FactoryReset { node: local.as_raw() },
                };
                message(Mti::DATAGRAM, p, &command.to_bytes(), &mut node, now);
                sent_command = Some((peer(p), command));
            }
            ServerOp::Raw { peer: p, bytes } => {
                let mut payload = alloc::vec![0x20];
                payload.extend(bytes.iter().take(71));
                message(Mti::DATAGRAM, p, &payload, &mut node, now);
                sent_command = Command::parse(&payload).ok().map(|c| (peer(p), c));
            }
            ServerOp::Stream { peer: p, kind, stream, mut payload } => {
                let (mti, head) = match kind % 5 {
                    0 => (Mti::STREAM_INITIATE_REPLY, alloc::vec![0, 64, 0x80, 0, ids.0, ids.1]),
                    1 => (Mti::STREAM_INITIATE_REQUEST, alloc::vec![0xFF, 0xFF, 0, 0, stream, 0xFF]),
                    2 => (Mti::STREAM_DATA_SEND, alloc::vec![ids.1]),
                    3 => (Mti::STREAM_DATA_PROCEED, alloc::vec![ids.0, ids.1, 0, 0]),
                    _ => (Mti::STREAM_DATA_COMPLETE, alloc::vec![stream, ids.1]),
                };
                let mut bytes = head;
                payload.truncate(64);
                bytes.append(&mut payload);
                message(mti, p, &bytes, &mut node, now);
            }
            ServerOp::Answer { peer: p, ok, code } => {
                if ok {
                    message(Mti::DATAGRAM_RECEIVED_OK, p, &[0], &mut node, now);
                } else {
                    message(Mti::DATAGRAM_REJECTED, p, &code.to_be_bytes(), &mut node, now);
                }
            }
            ServerOp::Restart { peer: p } => {
                let source = peer(p);
                owner = owner.map(|(o, gone)| (o, gone || o == source));
                // What was promised to a node that restarted is moot.
                forget(&mut promised, source);
                let payload = source.to_bytes();
                node.handle_message(
                    now,
                    MessageRef { mti: Mti::INITIALIZATION_COMPLETE, source, destination: None, payload: &payload },
                );
            }
            ServerOp::PeerLost { peer: p } => {
                owner = owner.map(|(o, gone)| (o, gone || o == peer(p)));
                forget(&mut promised, peer(p));
                node.peer_changed(PeerChange::Lost(peer(p)));
            }
            ServerOp::Advance { millis } => {
                now += Duration::from_millis(u64::from(millis) * 16);
                node.handle_timeout(now);
            }
        }
        let frozen_before = node.memory_server().is_some_and(|s| s.is_frozen());
        // Datagram OK (its flags) or Rejected sent to the commanding peer in this step.
        let mut answers: Vec<Option<u8>> = Vec::new();
        while let Some(sent) = node.poll_transmit() {
            assert!(sent.payload.len() <= crate::MAX_DATAGRAM_LEN || sent.mti == Mti::STREAM_DATA_SEND);
            let index = PEERS.iter().position(|p| Some(*p) == sent.destination);
            let to_commander = sent_command.as_ref().is_some_and(|(p, _)| Some(*p) == sent.destination);
            match sent.mti {
                Mti::DATAGRAM_RECEIVED_OK if to_commander => {
                    let flags = sent.payload.first().copied().unwrap_or(0);
                    answers.push(Some(flags));
                    if let (true, Some(i)) = (flags & 0x80 != 0, index) {
                        if let Some(n) = promised.get_mut(i) {
                            *n += 1;
                        }
                    }
                }
                Mti::DATAGRAM_REJECTED if to_commander => answers.push(None),
                Mti::VERIFY_NODE_ID_ADDRESSED => answer_verify(&mut node, now, &sent),
                Mti::DATAGRAM => {
                    if let Some(i) = index {
                        if let Some(n) = promised.get_mut(i) {
                            *n -= 1;
                        }
                    }
                    if let Ok(Reply::ReadOk { space, address, data }) = Reply::parse(&sent.payload) {
                        let size = sizes.iter().find(|(s, _)| *s == space).map_or(u32::MAX, |(_, n)| *n);
                        let end = address as usize + data.len();
                        assert!(space >= 0xFB || end <= size as usize, "read past the end of 0x{space:02X}");
                        // The reply of this step's own Read (a queued one was read earlier).
                        let this_read = matches!(sent_command, Some((_, Command::Read { space: 0xFD, address: a, .. })) if a == address);
                        if let (0xFD, true, Some(shadow)) = (space, to_commander && this_read, &shadow) {
                            let want = shadow.get(address as usize..end);
                            assert_eq!(want, Some(&data[..]), "a Read Reply differs from what was written");
                        }
                    }
                    if let Ok(Reply::WriteStreamOk { streams: Some((sid, did)), .. }) = Reply::parse(&sent.payload) {
                        ids = (sid, did);
                    }
                }
                // The node itself started again (Reset/Reboot: Initialization Complete, then
                // this Verify Node ID naming itself): what it promised before is moot, as for
                // a peer that restarted.
                Mti::VERIFY_NODE_ID_GLOBAL => promised = [0; PEERS.len()],
                Mti::STREAM_INITIATE_REQUEST => {
                    ids = (sent.payload.get(4).copied().unwrap_or(0), sent.payload.get(5).copied().unwrap_or(0))
                }
                Mti::STREAM_INITIATE_REPLY => {
                    ids = (sent.payload.get(4).copied().unwrap_or(0), sent.payload.get(5).copied().unwrap_or(0))
                }
                _ => {}
            }
        }
        while node.poll_event().is_some() {}
        if let Some((from, command)) = &sent_command {
            // Every command is answered exactly once (an owner's Unfreeze may wait for the end
            // of its own image stream).
            let deferred = matches!(command, Command::Unfreeze { .. }) && answers.is_empty();
            assert!(answers.len() == 1 || deferred, "{command:?} answered {} times", answers.len());
            let accepted = answers.first().is_some_and(Option::is_some);
            let frozen_by_other = owner.is_some_and(|(o, gone)| o != *from && !gone) && frozen_before;
            match command {
                Command::Write { space: 0xEF, .. } | Command::WriteStream { space: 0xEF, .. } => {
                    assert!(!(accepted && frozen_by_other), "a bystander wrote the firmware space");
                }
                Command::Unfreeze { space: 0xEF } => {
                    assert!(!(accepted && frozen_by_other), "a bystander unfroze the node");
                }
                Command::Freeze { space: 0xEF } if accepted => owner = Some((*from, false)),
                Command::Write { space: 0xFD, address, data } if accepted => {
                    let range =
                        shadow.as_mut().and_then(|s| s.get_mut(*address as usize..*address as usize + data.len()));
                    if let Some(range) = range {
                        range.copy_from_slice(data);
                    }
                }
                Command::WriteUnderMask { space: 0xFD, address, mask, data } if accepted => {
                    let range =
                        shadow.as_mut().and_then(|s| s.get_mut(*address as usize..*address as usize + data.len()));
                    if let Some(range) = range {
                        for ((old, new), m) in range.iter_mut().zip(data).zip(mask) {
                            *old = (*old & !m) | (new & m);
                        }
                    }
                }
                Command::WriteStream { space: 0xFD, .. } if accepted => shadow = None,
                _ => {}
            }
        }
        let server = node.memory_server();
        assert!(server.is_some_and(|s| s.active_streams() <= bound), "too many transfers");
        for (space, size) in sizes {
            let len = server.and_then(|s| s.space(space)).map(|s| s.len());
            assert_eq!(len, Some(size), "space 0x{space:02X} changed size");
        }
    }
    // Liveness: a long quiet time later, no transfer is left, and every reply promised has
    // gone out (each waits for the one before it to be answered or to time out).
    for _ in 0..60 {
        now += Duration::from_secs(5);
        node.handle_timeout(now);
        while let Some(sent) = node.poll_transmit() {
            let index = PEERS.iter().position(|p| Some(*p) == sent.destination);
            if let (Mti::DATAGRAM, Some(i)) = (sent.mti, index) {
                if let Some(n) = promised.get_mut(i) {
                    *n -= 1;
                }
            }
            answer_verify(&mut node, now, &sent);
        }
        while node.poll_event().is_some() {}
    }
    assert_eq!(node.memory_server().map(|s| s.active_streams()), Some(0), "a transfer never ended");
    assert!(promised.iter().all(|n| *n <= 0), "a reply promised by Reply Pending never came: {promised:?}");
    if let (Some(shadow), Some(space)) = (shadow, node.memory_server_mut().and_then(|s| s.space_mut(0xFD))) {
        let mut bytes = alloc::vec![0; 300];
        let _ = space.read(0, &mut bytes);
        assert!(bytes == shadow, "space 0xFD is not what the accepted writes left");
    }
}

/// The peers are alive: each answers an addressed Verify Node ID sent to it (MN §3.3), as the
/// memory server's check of a holder of its lock or upgrade expects of a node still there.
fn answer_verify(node: &mut Node, now: Instant, sent: &Message) {
    if let Some(to) = sent.destination.filter(|d| sent.mti == Mti::VERIFY_NODE_ID_ADDRESSED && PEERS.contains(d)) {
        node.handle_message(now, Message::verified_node_id(to).as_ref());
    }
}

/// One declaration of [`event_ops`]: a block of 2^`bits` from `first`.
#[derive(Debug, Arbitrary)]
struct Declaration {
    first: u64,
    bits: u8,
    state: u8,
}

#[derive(Debug, Arbitrary)]
enum EventOp {
    IdentifyProducer { event: u64, declared: Option<u8> },
    IdentifyConsumer { event: u64, declared: Option<u8> },
    IdentifyEvents { addressed: bool, to_us: bool },
    Report { event: u64, payload: Vec<u8> },
    Other { mti: u16, payload: Vec<u8> },
    Send { event: u64, payload: Vec<u8> },
    LinkLost,
}

/// Event Transport with random declarations and messages. The oracle: Identify Producer or
/// Consumer is answered by exactly one Identified message, with the declaration's state,
/// when the event is declared in that role, by none otherwise; Identify Events (global, or
/// addressed to this node) by exactly one message per declaration, in order, each naming
/// the declared event or range; reports reach the application exactly when consumed.
pub fn event_ops(data: &[u8]) {
    use crate::{DeclaredEvents, EventConfig, EventNotice, EventRange, EventState, Listen};
    use openlcb_stream::EventId;

    let mut u = Unstructured::new(data);
    let Ok((produced, consumed, everything, ops)) =
        <(Vec<Declaration>, Vec<Declaration>, bool, Vec<EventOp>)>::arbitrary(&mut u)
    else {
        return;
    };
    let declare = |list: Vec<Declaration>| -> Vec<DeclaredEvents> {
        list.into_iter()
            .take(8)
            .filter_map(|d| {
                let state = match d.state % 3 {
                    0 => EventState::Valid,
                    1 => EventState::Invalid,
                    _ => EventState::Unknown,
                };
                let count = 1u64.checked_shl(u32::from(d.bits % 64))?;
                Some(DeclaredEvents { range: EventRange::covering(EventId(d.first), count)?, state })
            })
            .collect()
    };
    let events = EventConfig {
        produced: declare(produced),
        consumed: declare(consumed),
        listen: if everything { Listen::Everything } else { Listen::Consumed },
    };
    let local = NodeId::from_bytes([5, 1, 1, 1, 0x40, 2]);
    let config = NodeConfig {
        events: events.clone(),
        send_initialization_complete: false,
        transmit_queue_limit: 16,
        ..NodeConfig::default()
    };
    let mut node = Node::new(local, config);
    let active = events.is_active();
    let peer = PEERS[0];
    let state_bits = |s: EventState| match s {
        EventState::Valid => 0,
        EventState::Invalid => 1,
        EventState::Unknown => 3,
    };
    // What Identify Events must bring: one message per declaration, in order.
    let mut pass = Vec::new();
    for (list, single, range) in [
        (&events.produced, Mti::PRODUCER_IDENTIFIED_VALID, Mti::PRODUCER_RANGE_IDENTIFIED),
        (&events.consumed, Mti::CONSUMER_IDENTIFIED_VALID, Mti::CONSUMER_RANGE_IDENTIFIED),
    ] {
        for d in list {
            let (mti, id) = if d.range.is_single() {
                (Mti(single.0 | state_bits(d.state)), d.range.first())
            } else {
                assert_eq!(EventRange::from_encoded(d.range.encoded()), d.range, "the range survives its encoding");
                (range, d.range.encoded())
            };
            pass.push((mti, id.to_bytes().to_vec()));
        }
    }
    let now = Instant::ZERO;
    for op in ops {
        let mut expected: Option<Vec<(Mti, Vec<u8>)>> = None;
        let mut consumed_report = None;
        match op {
            EventOp::IdentifyProducer { event, declared } | EventOp::IdentifyConsumer { event, declared } => {
                let producer = matches!(op, EventOp::IdentifyProducer { .. });
                let (list, mti, single) = if producer {
                    (&events.produced, Mti::IDENTIFY_PRODUCER, Mti::PRODUCER_IDENTIFIED_VALID)
                } else {
                    (&events.consumed, Mti::IDENTIFY_CONSUMER, Mti::CONSUMER_IDENTIFIED_VALID)
                };
                // Aim inside a declaration now and then.
                let event = match declared.and_then(|i| list.get(usize::from(i) % list.len().max(1))) {
                    Some(d) => EventId(d.range.first().0 | (event & !d.range.first().0 & d.range.last().0)),
                    None => EventId(event),
                };
                node.handle_message(
                    now,
                    MessageRef { mti, source: peer, destination: None, payload: &event.to_bytes() },
                );
                let answer = list.iter().find(|d| d.range.contains(event));
                expected = Some(match answer {
                    Some(d) if active => alloc::vec![(Mti(single.0 | state_bits(d.state)), event.to_bytes().to_vec())],
                    _ => Vec::new(),
                });
            }
            EventOp::IdentifyEvents { addressed, to_us } => {
                let (mti, destination) = match (addressed, to_us) {
                    (false, _) => (Mti::IDENTIFY_EVENTS_GLOBAL, None),
                    (true, true) => (Mti::IDENTIFY_EVENTS_ADDRESSED, Some(local)),
                    (true, false) => (Mti::IDENTIFY_EVENTS_ADDRESSED, Some(PEERS[1])),
                };
                node.handle_message(now, MessageRef { mti, source: peer, destination, payload: &[] });
                if active {
                    expected = Some(if addressed && !to_us { Vec::new() } else { pass.clone() });
                }
            }
            EventOp::Report { event, payload } => {
                let mut bytes = EventId(event).to_bytes().to_vec();
                bytes.extend_from_slice(&payload);
                let mti = Mti::PRODUCER_CONSUMER_EVENT_REPORT;
                node.handle_message(now, MessageRef { mti, source: peer, destination: None, payload: &bytes });
                let wanted = everything || events.consumed.iter().any(|d| d.range.contains(EventId(event)));
                consumed_report = Some((active && wanted, EventId(event), payload));
            }
            EventOp::Other { mti, payload } => {
                let mti = Mti(mti);
                let destination = mti.is_addressed().then_some(local);
                node.handle_message(now, MessageRef { mti, source: peer, destination, payload: &payload });
            }
            EventOp::Send { event, payload } => {
                let _ = node.send_event(EventId(event), &payload);
            }
            EventOp::LinkLost => node.link_lost(),
        }
        let sent: Vec<(Mti, Vec<u8>)> =
            core::iter::from_fn(|| node.poll_transmit()).map(|m| (m.mti, m.payload)).collect();
        assert!(sent.len() <= 16 + pass.len(), "{} messages after one op", sent.len());
        if let Some(expected) = expected {
            assert_eq!(sent, expected);
        }
        let notices: Vec<EventNotice> = core::iter::from_fn(|| node.poll_event())
            .filter_map(|e| match e {
                NodeEvent::Events(notice) => Some(notice),
                _ => None,
            })
            .collect();
        if let Some((wanted, event, payload)) = consumed_report {
            let got = notices.iter().any(|n| *n == EventNotice::Report { from: peer, event, payload: payload.clone() });
            assert_eq!(got, wanted, "report of {event:?} delivered");
        }
    }
}

/// One step of [`clock_ops`].
#[derive(Debug, Arbitrary)]
enum ClockOp {
    /// A clock event from a peer: which MTI (of a few), the low two bytes, of which clock.
    Event { mti: u8, suffix: u16, other_clock: bool },
    /// Time passes, in milliseconds.
    Wait(u16),
    /// The application sets the generator, or sends a set as the consumer.
    Set { generator: bool, what: u8, value: u16 },
}

/// Broadcast Time: a generator and a consumer node back to back, and a peer that sends any
/// clock event. The oracle: nothing panics, every state read back is a real moment, the
/// generator's synchronization sequences stay within their bound (one a second for queries,
/// one per three seconds for sets, and the start-up one), and the messages queued at once
/// stay few.
pub fn clock_ops(data: &[u8]) {
    use crate::broadcast_time::{ClockConfig, ClockId, ClockSet, ClockTime, GeneratorConfig, Rate};

    let mut u = Unstructured::new(data);
    let Ok((rate, running, ops)) = <(i16, bool, Vec<ClockOp>)>::arbitrary(&mut u) else { return };
    let clock = ClockId::DEFAULT_FAST;
    let mut generator = GeneratorConfig::default();
    generator.rate = Rate::from_quarters(rate.clamp(-2048, 2047)).unwrap_or(Rate::REAL_TIME);
    generator.running = running;
    let config =
        |c: ClockConfig| NodeConfig { clocks: alloc::vec![c], transmit_queue_limit: 16, ..NodeConfig::default() };
    let mut nodes = [
        Node::new(NodeId::from_bytes([5, 1, 1, 1, 0x40, 1]), config(ClockConfig::generator(clock, generator))),
        Node::new(NodeId::from_bytes([5, 1, 1, 1, 0x40, 2]), config(ClockConfig::consumer(clock))),
    ];
    let peer = PEERS[0];
    let mut now = Instant::from_secs(1);
    let start = now;
    for op in ops.into_iter().take(2000) {
        match op {
            ClockOp::Event { mti, suffix, other_clock } => {
                let mti = [
                    Mti::PRODUCER_CONSUMER_EVENT_REPORT,
                    Mti::PRODUCER_IDENTIFIED_VALID,
                    Mti::CONSUMER_IDENTIFIED_VALID,
                    Mti::CONSUMER_RANGE_IDENTIFIED,
                    Mti::IDENTIFY_PRODUCER,
                    Mti::IDENTIFY_CONSUMER,
                    Mti::IDENTIFY_EVENTS_GLOBAL,
                ][usize::from(mti % 7)];
                let id = if other_clock { ClockId::ALTERNATE_1 } else { clock };
                let message = Message::global(mti, peer, id.event(suffix).to_bytes());
                for node in &mut nodes {
                    node.handle_message(now, message.as_ref());
                }
            }
            ClockOp::Wait(ms) => now += Duration::from_millis(u64::from(ms)),
            ClockOp::Set { generator, what, value } => {
                let set = match what % 6 {
                    0 => ClockSet::Time { hour: (value % 24) as u8, minute: (value / 24 % 60) as u8 },
                    1 => ClockSet::Date { month: (value % 12 + 1) as u8, day: (value / 12 % 31 + 1) as u8 },
                    2 => ClockSet::Year(value % 4096),
                    3 => ClockSet::Rate(Rate::from_quarters((value % 4096) as i16 - 2048).unwrap_or(Rate::REAL_TIME)),
                    4 => ClockSet::Start,
                    _ => ClockSet::Stop,
                };
                let _ = nodes[usize::from(!generator)].set_clock(now, clock, set);
            }
        }
        // Each node's timers, then every message to the other, until quiet.
        for _ in 0..64 {
            let mut moved = false;
            for i in 0..2 {
                nodes[i].handle_timeout(now);
                let sent: Vec<Message> = core::iter::from_fn(|| nodes[i].poll_transmit()).collect();
                assert!(sent.len() <= 64, "{} messages at once", sent.len());
                for m in &sent {
                    nodes[1 - i].handle_message(now, m.as_ref());
                    moved = true;
                }
                while nodes[i].poll_event().is_some() {}
            }
            if !moved {
                break;
            }
        }
        for node in &nodes {
            let state = node.clock(clock, now).expect("the clock is there");
            let t = state.time;
            assert!(ClockTime::new(t.year, t.month, t.day, t.hour, t.minute, t.second).is_some(), "{t:?}");
        }
        let seconds = now.saturating_duration_since(start).as_millis() / 1000;
        let syncs = u64::from(nodes[0].clock_stats().syncs_sent);
        assert!(syncs <= 2 + seconds + seconds / 3 + 1, "{syncs} sequences in {seconds} s");
    }
}

/// One step of [`traction_ops`].
#[derive(Debug, Arbitrary)]
enum TrainOp {
    /// A Traction Control Command from the throttle to train `train % 3`: the payload as
    /// given, or (when `raw` is off) a well-formed command built from it.
    Command { train: u8, raw: bool, payload: Vec<u8> },
    /// One train attaches another as its listener, with flags.
    Attach { train: u8, listener: u8, flags: u8 },
    /// A global event (the emergency ones, or a search) from the throttle.
    Event { which: u8, query: u32 },
    /// Time passes, in milliseconds.
    Wait(u16),
}

/// Traction Control: three train nodes, which may list each other as listeners (loops and
/// reversed listeners included), and a throttle that sends any command. The oracle: nothing
/// panics; every query gets its reply (or a reject) and a malformed command a reject; a Set
/// Speed from the throttle leaves its train at exactly that speed once the messages settle;
/// forwarding settles (no listener loop circulates); tables stay within their bounds.
pub fn traction_ops(data: &[u8]) {
    use crate::traction::{EMERGENCY_OFF, EMERGENCY_STOP, SearchQuery, Speed, TrainConfig};

    let mut u = Unstructured::new(data);
    let Ok(ops) = <Vec<TrainOp>>::arbitrary(&mut u) else { return };
    let throttle = PEERS[0];
    let ids = [
        NodeId::from_bytes([5, 1, 1, 1, 0x41, 1]),
        NodeId::from_bytes([5, 1, 1, 1, 0x41, 2]),
        NodeId::from_bytes([5, 1, 1, 1, 0x41, 3]),
    ];
    let mut nodes: Vec<Node> = ids
        .iter()
        .zip([3u32, 1234, 77])
        .map(|(id, address)| {
            let mut train = TrainConfig::dcc(address);
            train.max_listeners = 2;
            train.allocate = address == 3;
            Node::new(*id, NodeConfig { train: Some(train), transmit_queue_limit: 32, ..NodeConfig::default() })
        })
        .collect();
    let mut now = Instant::from_secs(1);
    for op in ops.into_iter().take(500) {
        let mut to_throttle = Vec::new();
        let mut expect_answer = None;
        let mut expect_speed = None;
        match op {
            TrainOp::Command { train, raw, payload } => {
                let i = usize::from(train % 3);
                let payload = if raw {
                    payload
                } else {
                    let first = payload.first().copied().unwrap_or(0);
                    let mut built =
                        alloc::vec![[0x00, 0x01, 0x02, 0x10, 0x11, 0x20, 0x30, 0x40][usize::from(first % 8)]];
                    built.extend(payload.iter().skip(1).take(8));
                    built
                };
                let answered = match payload.as_slice() {
                    [] => true,
                    [0x10, ..] | [0x20, 0x03, ..] | [0x30, 0x03, ..] | [0x40, 0x01, ..] => true,
                    [0x11, _, _, _, ..] | [0x20, 0x01, _, _, _, _, _, _, _, ..] => true,
                    [0x30, 0x01 | 0x02, _, _, _, _, _, _, _, ..] => true,
                    _ => false,
                };
                if answered {
                    expect_answer = Some(ids[i]);
                }
                if let [0x00, hi, lo, ..] = payload.as_slice() {
                    expect_speed = Some((i, Speed::from_bits(u16::from_be_bytes([*hi, *lo]))));
                }
                let message = Message::addressed(Mti::TRACTION_CONTROL_COMMAND, throttle, ids[i], payload);
                nodes[i].handle_message(now, message.as_ref());
            }
            TrainOp::Attach { train, listener, flags } => {
                let (i, j) = (usize::from(train % 3), usize::from(listener % 3));
                let mut payload = alloc::vec![0x30, 0x01, flags];
                payload.extend_from_slice(&ids[j].to_bytes());
                let message = Message::addressed(Mti::TRACTION_CONTROL_COMMAND, throttle, ids[i], payload);
                nodes[i].handle_message(now, message.as_ref());
                expect_answer = Some(ids[i]);
            }
            TrainOp::Event { which, query } => {
                let event = match which % 6 {
                    0 => EMERGENCY_STOP,
                    1 => openlcb_stream::EventId(EMERGENCY_STOP.0 - 1),
                    2 => EMERGENCY_OFF,
                    3 => openlcb_stream::EventId(EMERGENCY_OFF.0 - 1),
                    4 => SearchQuery::event_for(query % 20_000, (query >> 24) as u8)
                        .unwrap_or(openlcb_stream::EventId(0)),
                    _ => openlcb_stream::EventId(0x0900_99FF_0000_0000 | u64::from(query)),
                };
                let message = Message::global(Mti::PRODUCER_CONSUMER_EVENT_REPORT, throttle, event.to_bytes());
                let search = Message::global(Mti::IDENTIFY_PRODUCER, throttle, event.to_bytes());
                for node in &mut nodes {
                    node.handle_message(now, message.as_ref());
                    node.handle_message(now, search.as_ref());
                }
            }
            TrainOp::Wait(ms) => now += Duration::from_millis(u64::from(ms)),
        }
        // Every train's timers, then each message to its destination, until quiet.
        let mut settled = false;
        for _ in 0..16 {
            let mut moved = false;
            for i in 0..3 {
                nodes[i].handle_timeout(now);
                let sent: Vec<Message> = core::iter::from_fn(|| nodes[i].poll_transmit()).collect();
                assert!(sent.len() <= 40, "{} messages at once", sent.len());
                for m in sent {
                    match m.destination {
                        Some(d) if d == throttle => to_throttle.push(m),
                        Some(d) => {
                            if let Some(j) = ids.iter().position(|id| *id == d) {
                                nodes[j].handle_message(now, m.as_ref());
                                moved = true;
                            }
                        }
                        None => {}
                    }
                }
                while nodes[i].poll_event().is_some() {}
            }
            if !moved {
                settled = true;
                break;
            }
        }
        assert!(settled, "forwarding between the trains did not settle");
        if let Some(train) = expect_answer {
            let answered = to_throttle.iter().any(|m| {
                m.source == train && matches!(m.mti, Mti::TRACTION_CONTROL_REPLY | Mti::OPTIONAL_INTERACTION_REJECTED)
            });
            assert!(answered, "no answer from {train}");
        }
        if let Some((i, speed)) = expect_speed {
            assert_eq!(nodes[i].train().map(|t| t.set_speed), Some(speed), "the Set Speed holds");
        }
        for node in &nodes {
            let state = node.train().expect("a train");
            assert!(state.listeners <= 2);
            if state.emergency_stop || state.global_stop || state.global_off {
                assert!(state.commanded_speed.is_zero());
            }
        }
    }
}
