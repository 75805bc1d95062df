//! The node's routing, the message-network basics, datagrams both ways and SNIP, each driven
//! by hand-made messages from a scripted peer, checking exactly what the node sends back.

use openlcb_node::{
    DatagramAnswer, DatagramFailure, Node, NodeConfig, NodeEvent, OkFlags, Protocols, SnipFailure, SnipInfo,
};
use openlcb_stream::wire::ErrorCode;
use openlcb_stream::{Duration, Event, Instant, MessageRef, Mti, NodeId, PeerChange, Termination};

const LOCAL: NodeId = NodeId::from_bytes([0x05, 0x01, 0x01, 0x01, 0x40, 0x02]);
const PEER: NodeId = NodeId::from_bytes([0x05, 0x01, 0x01, 0x01, 0x40, 0x01]);
const OTHER: NodeId = NodeId::from_bytes([0x05, 0x01, 0x01, 0x01, 0x40, 0x03]);

struct Bench {
    node: Node,
    now: Instant,
}

fn config() -> NodeConfig {
    let mut c = NodeConfig::default();
    c.send_initialization_complete = false;
    c.datagrams.claimed = vec![0x20];
    c.snip = SnipInfo {
        manufacturer: "Acme".into(),
        model: "Widget".into(),
        hardware_version: "1.0".into(),
        software_version: "2.3".into(),
        user_name: "Yard".into(),
        user_description: "West end".into(),
    };
    c
}

impl Bench {
    fn new(config: NodeConfig) -> Self {
        Bench { node: Node::new(LOCAL, config), now: Instant::ZERO }
    }

    fn from(&mut self, source: NodeId, mti: Mti, payload: &[u8]) {
        let destination = mti.is_addressed().then_some(LOCAL);
        self.node.handle_message(self.now, MessageRef { mti, source, destination, payload });
    }

    fn peer(&mut self, mti: Mti, payload: &[u8]) {
        self.from(PEER, mti, payload);
    }

    /// What the node sent, as (MTI, destination, payload).
    fn sent(&mut self) -> Vec<(Mti, Option<NodeId>, Vec<u8>)> {
        std::iter::from_fn(|| self.node.poll_transmit()).map(|m| (m.mti, m.destination, m.payload.to_vec())).collect()
    }

    fn sent_to_peer(&mut self) -> Vec<(Mti, Vec<u8>)> {
        self.sent()
            .into_iter()
            .map(|(mti, to, payload)| {
                assert!(to.is_none() || to == Some(PEER), "sent to {to:?}");
                (mti, payload)
            })
            .collect()
    }

    fn events(&mut self) -> Vec<NodeEvent> {
        std::iter::from_fn(|| self.node.poll_event()).collect()
    }

    fn advance(&mut self, by: Duration) {
        self.now += by;
        self.node.handle_timeout(self.now);
    }

    /// A stream from PEER (SID 4, window 16) accepted by the node; returns its DID.
    fn open_destination(&mut self) -> u8 {
        self.peer(Mti::STREAM_INITIATE_REQUEST, &[0, 16, 0, 0, 4]);
        let sent = self.sent_to_peer();
        assert_eq!(sent[0].0, Mti::STREAM_INITIATE_REPLY);
        assert!(matches!(self.events()[..], [NodeEvent::Stream(Event::Opened { .. })]));
        sent[0].1[5]
    }
}

// ===== Message-network basics =====

#[test]
fn basics_verify_node_id_global_and_addressed() {
    let mut b = Bench::new(config());
    b.peer(Mti::VERIFY_NODE_ID_GLOBAL, &[]);
    b.peer(Mti::VERIFY_NODE_ID_GLOBAL, &OTHER.to_bytes()); // asks for someone else
    b.peer(Mti::VERIFY_NODE_ID_GLOBAL, &LOCAL.to_bytes());
    b.peer(Mti::VERIFY_NODE_ID_ADDRESSED, &[]);
    let verified = (Mti::VERIFIED_NODE_ID, LOCAL.to_bytes().to_vec());
    assert_eq!(b.sent_to_peer(), [verified.clone(), verified.clone(), verified]);
}

#[test]
fn basics_protocol_support_names_exactly_what_is_implemented() {
    let mut b = Bench::new(config());
    b.peer(Mti::PROTOCOL_SUPPORT_INQUIRY, &[]);
    // Datagram 0x40 | Stream 0x20, SNIP 0x10 in byte 1.
    assert_eq!(b.sent_to_peer(), [(Mti::PROTOCOL_SUPPORT_REPLY, vec![0x60, 0x10, 0, 0, 0, 0])]);
    let mut no_streams = config();
    no_streams.streams_enabled = false;
    no_streams.extra_protocols = Protocols::MEMORY_CONFIGURATION;
    let mut b = Bench::new(no_streams);
    b.peer(Mti::PROTOCOL_SUPPORT_INQUIRY, &[]);
    assert_eq!(b.sent_to_peer(), [(Mti::PROTOCOL_SUPPORT_REPLY, vec![0x50, 0x10, 0, 0, 0, 0])]);
    // Without streams, a stream request is a protocol this node lacks.
    b.peer(Mti::STREAM_INITIATE_REQUEST, &[0, 16, 0, 0, 4]);
    assert_eq!(b.sent_to_peer(), [(Mti::OPTIONAL_INTERACTION_REJECTED, vec![0x10, 0x43, 0x0C, 0xC8])]);
}

#[test]
fn basics_unknown_addressed_mti_gets_oir_and_answers_are_never_answered() {
    let mut b = Bench::new(config());
    b.peer(Mti(0x0C48), b"hi"); // an addressed MTI nobody here handles
    b.peer(Mti::OPTIONAL_INTERACTION_REJECTED, &[0x10, 0x43, 0x0C, 0x48]);
    b.peer(Mti::DATAGRAM_RECEIVED_OK, &[0]);
    b.peer(Mti::SIMPLE_NODE_INFO_REPLY, b"\x04x\0");
    b.peer(Mti(0x05B4), &[0; 8]); // global: never answered
    assert_eq!(b.sent_to_peer(), [(Mti::OPTIONAL_INTERACTION_REJECTED, vec![0x10, 0x43, 0x0C, 0x48])]);
    assert_eq!(b.node.stats().unknown_mti_rejected, 1);
}

#[test]
fn basics_announce_first_and_ignore_echoes_and_others() {
    let mut node = Node::new(LOCAL, NodeConfig::default());
    let first = node.poll_transmit().unwrap();
    assert_eq!((first.mti, &first.payload[..]), (Mti::INITIALIZATION_COMPLETE, &LOCAL.to_bytes()[..]));
    let mut b = Bench::new(config());
    b.from(LOCAL, Mti::VERIFY_NODE_ID_GLOBAL, &[]);
    b.node.handle_message(
        b.now,
        MessageRef { mti: Mti::VERIFY_NODE_ID_ADDRESSED, source: PEER, destination: Some(OTHER), payload: &[] },
    );
    assert!(b.sent().is_empty());
    assert_eq!((b.node.stats().own_echoes, b.node.stats().not_for_us), (1, 1));
}

#[test]
fn basics_answers_beyond_the_queue_limit_are_dropped_and_counted() {
    let mut c = config();
    c.transmit_queue_limit = 3;
    let mut b = Bench::new(c);
    for _ in 0..10 {
        b.peer(Mti::VERIFY_NODE_ID_ADDRESSED, &[]);
    }
    assert_eq!(b.sent().len(), 3);
    assert_eq!(b.node.stats().answers_dropped, 7);
}

#[test]
fn basics_verified_and_protocol_replies_become_events() {
    let mut b = Bench::new(config());
    b.node.request_protocols(PEER);
    assert_eq!(b.sent_to_peer(), [(Mti::PROTOCOL_SUPPORT_INQUIRY, vec![])]);
    b.peer(Mti::PROTOCOL_SUPPORT_REPLY, &[0x70, 0x00, 0x10]);
    b.peer(Mti::VERIFIED_NODE_ID, &PEER.to_bytes());
    let protocols = Protocols::DATAGRAM | Protocols::STREAM | Protocols::MEMORY_CONFIGURATION;
    assert_eq!(
        b.events(),
        [
            NodeEvent::ProtocolsReceived { peer: PEER, protocols: protocols | Protocols::FIRMWARE_UPGRADE_ACTIVE },
            NodeEvent::Verified { node: PEER }
        ]
    );
}

// ===== Routing of OIR and TDE =====

#[test]
fn routing_tde_naming_snip_request_leaves_streams_open() {
    let mut b = Bench::new(config());
    let did = b.open_destination();
    b.node.request_snip(b.now, PEER).unwrap();
    b.sent();
    b.peer(Mti::TERMINATE_DUE_TO_ERROR, &[0x20, 0x20, 0x0D, 0xE8]);
    assert_eq!(b.events(), [NodeEvent::SnipFailed { peer: PEER, failure: SnipFailure::Rejected(ErrorCode(0x2020)) }]);
    assert_eq!(b.node.streams().stream_count(), 1, "the stream is untouched");
    b.peer(Mti::STREAM_DATA_SEND, &[did, 1, 2, 3]);
    assert!(matches!(b.events()[..], [NodeEvent::Stream(Event::Readable { .. })]));
}

#[test]
fn routing_tde_naming_data_send_from_our_source_ends_that_stream_at_once() {
    let mut b = Bench::new(config());
    let did = b.open_destination();
    b.peer(Mti::STREAM_DATA_SEND, &[did, 1, 2, 3]);
    b.events();
    b.sent();
    b.peer(Mti::TERMINATE_DUE_TO_ERROR, &[0x20, 0x00, 0x1F, 0x88]);
    let events = b.events();
    assert!(matches!(
        events[..],
        [NodeEvent::Stream(Event::Terminated { cause: Termination::ByPeer(ErrorCode(0x2000)), .. })]
    ));
    // What arrived stays readable; once read, the slot is free: the next request is accepted.
    let handle = b.node.streams().handles().next().unwrap();
    let mut buf = [0u8; 8];
    assert_eq!(b.node.streams_mut().read(b.now, handle, &mut buf), Ok(3));
    assert_eq!(b.node.streams().stream_count(), 0);
    b.open_destination();
}

#[test]
fn routing_oir_naming_datagram_rejects_the_datagram_not_the_streams() {
    let mut b = Bench::new(config());
    b.open_destination();
    let id = b.node.send_datagram(b.now, PEER, &[0x20, 0x80]).unwrap();
    b.sent();
    b.peer(Mti::OPTIONAL_INTERACTION_REJECTED, &[0x10, 0x43, 0x1C, 0x48]);
    assert_eq!(
        b.events(),
        [NodeEvent::DatagramFailed { id, to: PEER, failure: DatagramFailure::Rejected(ErrorCode(0x1043)) }]
    );
    assert_eq!(b.node.streams().stream_count(), 1);
    // Naming nothing and nothing waiting: counted as stray, streams still end (no MTI).
    b.peer(Mti::OPTIONAL_INTERACTION_REJECTED, &[0x10, 0x00, 0x0A, 0x28]);
    assert_eq!(b.node.stats().stray_error_reports, 1);
}

// ===== Datagrams received =====

#[test]
fn datagram_unclaimed_is_rejected_at_once() {
    let mut b = Bench::new(config());
    b.peer(Mti::DATAGRAM, &[0x30, 1, 2]); // Train Control: not claimed here
    b.peer(Mti::DATAGRAM, &[]); // no content ID at all
    let rejected = (Mti::DATAGRAM_REJECTED, vec![0x10, 0x42]);
    assert_eq!(b.sent_to_peer(), [rejected.clone(), rejected]);
    assert!(b.events().is_empty());
}

#[test]
fn datagram_claimed_is_raised_and_answered_ok_with_flags() {
    let mut b = Bench::new(config());
    b.peer(Mti::DATAGRAM, &[0x20, 0x43, 0, 0, 0, 0, 0x40]);
    let events = b.events();
    let [NodeEvent::DatagramReceived { from, datagram }] = &events[..] else { panic!("{events:?}") };
    assert_eq!((*from, datagram.as_slice()), (PEER, &[0x20, 0x43, 0, 0, 0, 0, 0x40][..]));
    assert!(b.sent().is_empty(), "nothing until the application answers");
    b.node.answer_datagram(PEER, DatagramAnswer::Ok(OkFlags { reply_pending: true, timeout_exponent: 0 })).unwrap();
    assert_eq!(b.sent_to_peer(), [(Mti::DATAGRAM_RECEIVED_OK, vec![0x80])]);
    assert!(b.node.answer_datagram(PEER, DatagramAnswer::Ok(OkFlags::default())).is_err(), "answered once");
    b.peer(Mti::DATAGRAM, &[0x20, 0x01]);
    b.events();
    b.node.answer_datagram(PEER, DatagramAnswer::Rejected(ErrorCode(0x1083))).unwrap();
    assert_eq!(b.sent_to_peer(), [(Mti::DATAGRAM_REJECTED, vec![0x10, 0x83])]);
}

#[test]
fn datagram_unanswered_is_rejected_as_busy_and_a_second_from_the_same_source_too() {
    let mut b = Bench::new(config());
    b.peer(Mti::DATAGRAM, &[0x20, 0x01]);
    b.peer(Mti::DATAGRAM, &[0x20, 0x02]); // one outstanding per pair
    assert_eq!(b.sent_to_peer(), [(Mti::DATAGRAM_REJECTED, vec![0x20, 0x20])]);
    assert_eq!(b.events().len(), 1);
    b.advance(Duration::from_millis(499));
    assert!(b.sent().is_empty());
    b.advance(Duration::from_millis(1));
    assert_eq!(b.sent_to_peer(), [(Mti::DATAGRAM_REJECTED, vec![0x20, 0x20])]);
    assert_eq!(b.node.stats().datagrams.answer_timeouts, 1);
}

// ===== Datagrams sent =====

#[test]
fn datagram_sent_delivered_with_reply_pending_flags() {
    let mut b = Bench::new(config());
    let id = b.node.send_datagram(b.now, PEER, &[0x20, 0x43, 0, 0, 0, 0, 0x40]).unwrap();
    assert_eq!(b.sent_to_peer(), [(Mti::DATAGRAM, vec![0x20, 0x43, 0, 0, 0, 0, 0x40])]);
    b.peer(Mti::DATAGRAM_RECEIVED_OK, &[0x83]);
    let flags = OkFlags { reply_pending: true, timeout_exponent: 3 };
    assert_eq!(b.events(), [NodeEvent::DatagramDelivered { id, to: PEER, flags }]);
    b.peer(Mti::DATAGRAM_RECEIVED_OK, &[]);
    assert_eq!(b.node.stats().datagrams.stray_answers, 1);
}

#[test]
fn datagram_one_outstanding_per_destination() {
    let mut b = Bench::new(config());
    let first = b.node.send_datagram(b.now, PEER, &[0x20, 1]).unwrap();
    let second = b.node.send_datagram(b.now, PEER, &[0x20, 2]).unwrap();
    let other = b.node.send_datagram(b.now, OTHER, &[0x20, 3]).unwrap();
    let sent = b.sent();
    assert_eq!(sent.len(), 2, "the second to PEER waits: {sent:?}");
    assert_eq!((sent[0].1, sent[1].1), (Some(PEER), Some(OTHER)));
    b.peer(Mti::DATAGRAM_RECEIVED_OK, &[0]);
    assert_eq!(b.sent_to_peer(), [(Mti::DATAGRAM, vec![0x20, 2])]);
    b.peer(Mti::DATAGRAM_RECEIVED_OK, &[0]);
    let delivered: Vec<_> = b
        .events()
        .into_iter()
        .filter_map(|e| match e {
            NodeEvent::DatagramDelivered { id, .. } => Some(id),
            _ => None,
        })
        .collect();
    assert_eq!(delivered, [first, second]);
    assert_ne!(other, first);
}

#[test]
fn datagram_temporary_rejection_is_resent_then_delivered() {
    let mut b = Bench::new(config());
    let id = b.node.send_datagram(b.now, PEER, &[0x20, 1]).unwrap();
    b.sent();
    b.peer(Mti::DATAGRAM_REJECTED, &[0x20, 0x20]);
    assert!(b.sent().is_empty() && b.events().is_empty());
    b.advance(Duration::from_millis(200));
    assert_eq!(b.sent_to_peer(), [(Mti::DATAGRAM, vec![0x20, 1])]);
    b.peer(Mti::DATAGRAM_REJECTED, &[0x20, 0x41]);
    b.advance(Duration::from_millis(399));
    assert!(b.sent().is_empty(), "the second wait is twice as long");
    b.advance(Duration::from_millis(1));
    assert_eq!(b.sent().len(), 1);
    b.peer(Mti::DATAGRAM_RECEIVED_OK, &[0]);
    assert_eq!(b.events(), [NodeEvent::DatagramDelivered { id, to: PEER, flags: OkFlags::default() }]);
    assert_eq!(b.node.stats().datagrams.resent, 2);
}

#[test]
fn datagram_temporary_rejection_too_often_fails() {
    let mut b = Bench::new(config());
    let id = b.node.send_datagram(b.now, PEER, &[0x20, 1]).unwrap();
    for _ in 0..3 {
        b.sent();
        b.peer(Mti::DATAGRAM_REJECTED, &[0x20, 0x00]);
        b.advance(Duration::from_secs(2));
    }
    assert_eq!(b.sent().len(), 1);
    b.peer(Mti::DATAGRAM_REJECTED, &[0x20, 0x00]);
    assert_eq!(
        b.events(),
        [NodeEvent::DatagramFailed { id, to: PEER, failure: DatagramFailure::Rejected(ErrorCode(0x2000)) }]
    );
}

#[test]
fn datagram_permanent_rejection_fails_at_once() {
    let mut b = Bench::new(config());
    let id = b.node.send_datagram(b.now, PEER, &[0x20, 1]).unwrap();
    b.sent();
    b.peer(Mti::DATAGRAM_REJECTED, &[0x10, 0x42]);
    assert_eq!(
        b.events(),
        [NodeEvent::DatagramFailed { id, to: PEER, failure: DatagramFailure::Rejected(ErrorCode(0x1042)) }]
    );
    // OpenLcbCLib's CAN-layer form (alias, then code) is read as the temporary code it is.
    b.node.send_datagram(b.now, PEER, &[0x20, 2]).unwrap();
    b.sent();
    b.peer(Mti::DATAGRAM_REJECTED, &[0x01, 0x23, 0x20, 0x41]);
    assert!(b.events().is_empty(), "resent, not failed");
}

#[test]
fn datagram_no_answer_times_out() {
    let mut b = Bench::new(config());
    let id = b.node.send_datagram(b.now, PEER, &[0x20, 1]).unwrap();
    b.sent();
    assert_eq!(b.node.poll_timeout(), Some(Instant::ZERO + Duration::from_secs(3)));
    b.advance(Duration::from_millis(2999));
    assert!(b.events().is_empty());
    b.advance(Duration::from_millis(1));
    assert_eq!(b.events(), [NodeEvent::DatagramFailed { id, to: PEER, failure: DatagramFailure::TimedOut }]);
}

#[test]
fn datagram_destination_restart_fails_it() {
    let mut b = Bench::new(config());
    let id = b.node.send_datagram(b.now, PEER, &[0x20, 0xA1, 0xEF]).unwrap(); // Freeze
    b.sent();
    b.peer(Mti::INITIALIZATION_COMPLETE, &PEER.to_bytes());
    assert_eq!(b.events(), [NodeEvent::DatagramFailed { id, to: PEER, failure: DatagramFailure::PeerRestarted }]);
}

#[test]
fn datagram_refused_commands() {
    let mut c = config();
    c.datagrams.max_outgoing = 1;
    let mut b = Bench::new(c);
    assert!(b.node.send_datagram(b.now, PEER, &[0; 73]).is_err());
    assert!(b.node.send_datagram(b.now, LOCAL, &[0x20]).is_err());
    b.node.send_datagram(b.now, PEER, &[0x20]).unwrap();
    assert!(b.node.send_datagram(b.now, OTHER, &[0x20]).is_err(), "queue full");
}

// ===== SNIP =====

#[test]
fn snip_request_is_answered_with_the_configured_strings() {
    let mut b = Bench::new(config());
    b.peer(Mti::SIMPLE_NODE_INFO_REQUEST, &[]);
    let expected = b"\x04Acme\0Widget\x001.0\x002.3\0\x02Yard\0West end\0".to_vec();
    assert_eq!(b.sent_to_peer(), [(Mti::SIMPLE_NODE_INFO_REPLY, expected)]);
}

#[test]
fn snip_reply_parsed_whole_or_from_frames_of_an_older_node() {
    let reply = b"\x04Acme\0Widget\x001.0\x002.3\0\x02Yard\0West end\0";
    let mut b = Bench::new(config());
    b.node.request_snip(b.now, PEER).unwrap();
    assert_eq!(b.sent_to_peer(), [(Mti::SIMPLE_NODE_INFO_REQUEST, vec![])]);
    assert!(b.node.request_snip(b.now, PEER).is_err(), "one at a time");
    b.peer(Mti::SIMPLE_NODE_INFO_REPLY, reply);
    let events = b.events();
    let [NodeEvent::SnipReceived { peer, info }] = &events[..] else { panic!("{events:?}") };
    assert_eq!((*peer, info.user_description.as_str()), (PEER, "West end"));
    // An older node sends each frame as a message of its own.
    b.node.request_snip(b.now, PEER).unwrap();
    for chunk in reply.chunks(6) {
        assert!(b.events().is_empty());
        b.peer(Mti::SIMPLE_NODE_INFO_REPLY, chunk);
    }
    assert!(matches!(&b.events()[..], [NodeEvent::SnipReceived { info, .. }] if info.model == "Widget"));
}

#[test]
fn snip_no_reply_times_out_and_partial_reply_is_kept() {
    let mut b = Bench::new(config());
    b.node.request_snip(b.now, PEER).unwrap();
    b.node.request_snip(b.now, OTHER).unwrap();
    b.peer(Mti::SIMPLE_NODE_INFO_REPLY, b"\x04Acme");
    b.advance(Duration::from_secs(3));
    let events = b.events();
    assert!(events.contains(&NodeEvent::SnipFailed { peer: OTHER, failure: SnipFailure::TimedOut }));
    assert!(
        events.iter().any(
            |e| matches!(e, NodeEvent::SnipReceived { peer, info } if *peer == PEER && info.manufacturer == "Acme")
        )
    );
}

// ===== Renames from the transport =====

#[test]
fn rename_moves_streams_and_datagrams_to_the_new_name() {
    let provisional = NodeId::new(0x031).unwrap();
    let mut b = Bench::new(config());
    b.from(provisional, Mti::STREAM_INITIATE_REQUEST, &[0, 16, 0, 0, 4]);
    let reply = b.sent();
    assert_eq!(reply[0].1, Some(provisional), "answered to the name it came with");
    let did = reply[0].2[5];
    b.events();
    let id = b.node.send_datagram(b.now, provisional, &[0x20, 1]).unwrap();
    b.sent();
    b.node.peer_changed(PeerChange::Renamed { from: provisional, to: PEER });
    b.peer(Mti::STREAM_DATA_SEND, &[did, 9]);
    b.peer(Mti::DATAGRAM_RECEIVED_OK, &[0]);
    let events = b.events();
    assert!(events.iter().any(|e| matches!(e, NodeEvent::Stream(Event::Readable { .. }))), "{events:?}");
    assert!(events.contains(&NodeEvent::DatagramDelivered { id, to: PEER, flags: OkFlags::default() }));
}

#[test]
fn peer_lost_fails_what_is_open_with_it() {
    let mut b = Bench::new(config());
    b.open_destination();
    let id = b.node.send_datagram(b.now, PEER, &[0x20, 1]).unwrap();
    b.node.request_snip(b.now, PEER).unwrap();
    b.node.peer_changed(PeerChange::Lost(PEER));
    let events = b.events();
    assert!(events.contains(&NodeEvent::DatagramFailed { id, to: PEER, failure: DatagramFailure::PeerLost }));
    assert!(events.contains(&NodeEvent::SnipFailed { peer: PEER, failure: SnipFailure::PeerLost }));
    assert!(
        events.iter().any(|e| matches!(e, NodeEvent::Stream(Event::Terminated { cause: Termination::PeerLost, .. })))
    );
}

#[test]
fn rename_readdresses_messages_still_queued() {
    // The driver takes the node's messages after a batch of frames; a rename in between must
    // reach the ones already queued, or they would go to a name the transport forgot.
    let provisional = NodeId::new(0x031).unwrap();
    let mut b = Bench::new(config());
    b.from(provisional, Mti::STREAM_INITIATE_REQUEST, &[0, 16, 0, 0, 4]); // the endpoint's reply
    b.from(provisional, Mti::PROTOCOL_SUPPORT_INQUIRY, &[]); // the node's own answer
    b.node.peer_changed(PeerChange::Renamed { from: provisional, to: PEER });
    let sent = b.sent();
    let mtis: Vec<Mti> = sent.iter().map(|(mti, _, _)| *mti).collect();
    assert_eq!(mtis, [Mti::PROTOCOL_SUPPORT_REPLY, Mti::STREAM_INITIATE_REPLY]);
    assert!(sent.iter().all(|(_, to, _)| *to == Some(PEER)), "{sent:?}");
}
