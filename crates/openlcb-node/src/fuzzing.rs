//! Fuzzing entry points (`cargo fuzz`, see `fuzz/`). Not part of the public API.

use alloc::vec::Vec;

use arbitrary::{Arbitrary, Unstructured};
use openlcb_stream::{Duration, Instant, MessageRef, Mti, NodeId};

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
    let limit = config.transmit_queue_limit;
    let mut node = Node::new(local, config);
    let mut now = Instant::ZERO;
    let mut open = Vec::new();
    let peer = |i: u8| PEERS.get(usize::from(i) % PEERS.len()).copied().unwrap_or(PEERS[0]);
    for op in ops {
        match op {
            Op::Message { peer: p, mti, pick, payload } => {
                let mti = MTIS.get(usize::from(pick)).copied().unwrap_or(Mti(mti));
                let destination = mti.is_addressed().then_some(local);
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
            Op::Rename { from, to } => node.rename_peer(peer(from), peer(to)),
            Op::PeerLost { peer: p } => node.peer_lost(peer(p)),
            Op::LinkLost => node.link_lost(),
            Op::Advance { millis } => {
                now += Duration::from_millis(u64::from(millis));
                node.handle_timeout(now);
            }
        }
        let mut sent = 0;
        while node.poll_transmit().is_some() {
            sent += 1;
        }
        // Answers are capped; each op adds a bounded number of other messages.
        assert!(sent <= limit + 8, "{sent} messages after one op");
        drain(&mut node, &mut open);
    }
    // Liveness: a long quiet time later, every datagram has ended.
    for _ in 0..8 {
        now += Duration::from_secs(10);
        node.handle_timeout(now);
        while node.poll_transmit().is_some() {}
        drain(&mut node, &mut open);
    }
    assert!(open.is_empty(), "datagrams never ended: {open:?}");
}

fn drain(node: &mut Node, open: &mut Vec<crate::DatagramId>) {
    while let Some(event) = node.poll_event() {
        match event {
            NodeEvent::DatagramDelivered { id, .. } | NodeEvent::DatagramFailed { id, .. } => open.retain(|o| *o != id),
            _ => {}
        }
    }
}
