//! Peers known only by their alias: served at once under their provisional name, learnt in
//! the background, renamed when their name changes (node-protocols §7; issue: a peer that
//! sends AMD, then a global AME, and never answers Verify Node ID).

mod common;

use common::{A_ID, Node, Solo, alias, can_config, node_id};
use openlcb_can::NodeAlias;
use openlcb_stream::{Event, Instant, Message, MessageRef, Mti, NodeId, PeerChange, PeerChanges, Receiver, Role};

/// The Node ID of the peer on alias 0x031 in the trace.
const PEER_031: u64 = 0x0300_0000_0001;
const C_ID: u64 = 0x0501_0101_2202;

fn provisional(raw: u16) -> NodeId {
    alias(raw).provisional_node_id()
}

/// The (MTI, source) of every message the link delivered.
fn delivered(solo: &Solo) -> Vec<(Mti, NodeId)> {
    solo.node.delivered.iter().map(|m| (m.mti, m.source)).collect()
}

fn renames(changes: &[PeerChange]) -> Vec<(NodeId, NodeId)> {
    changes
        .iter()
        .filter_map(|c| match c {
            PeerChange::Renamed { from, to } => Some((*from, *to)),
            _ => None,
        })
        .collect()
}

// ----- AMD, then a global AME, never an answer to Verify -----

#[test]
fn peer_after_global_ame_is_served_at_once_by_alias() {
    let mut solo = Solo::permitted();
    assert_eq!(solo.inject(&[":X10701031N030000000001;"]), Vec::<String>::new());
    assert_eq!(solo.node.link.node_of(alias(0x031)), Some(node_id(PEER_031)));
    // The global AME: we answer with our AMD and forget the mapping (CFT §6.2.3).
    assert_eq!(solo.inject(&[":X10702031N;"]), [":X10701123N050101012200;"]);
    assert_eq!(
        solo.node.peer_changes,
        [
            PeerChange::Renamed { from: provisional(0x031), to: node_id(PEER_031) },
            PeerChange::Renamed { from: node_id(PEER_031), to: provisional(0x031) },
        ]
    );
    assert_eq!(solo.node.link.node_of(alias(0x031)), None);

    // PIP inquiry: answered at once, to alias 0x031, and nothing else goes out (no Verify
    // Node ID to learn its name: conformance tools see every frame).
    let sent = solo.inject(&[":X19828031N0123;"]);
    assert_eq!(sent, [":X19668123N0031601000000000;"]);
    // Addressed Verify Node ID: answered at once.
    assert_eq!(solo.inject(&[":X19488031N0123;"]), [":X19170123N050101012200;"]);
    // An Initiate Request: accepted at once.
    assert_eq!(solo.inject(&[":X19CC8031N01230010000004;"]), [":X19868123N0031001080000400;"]);
    // A datagram: delivered at once (the node, which serves no Memory Configuration, rejects
    // it with 0x1042, datagram type unknown).
    assert_eq!(solo.inject(&[":X1A123031N2080;"]), [":X19A48123N00311042;"]);
    let p = provisional(0x031);
    assert_eq!(
        delivered(&solo),
        [
            (Mti::PROTOCOL_SUPPORT_INQUIRY, p),
            (Mti::VERIFY_NODE_ID_ADDRESSED, p),
            (Mti::STREAM_INITIATE_REQUEST, p),
            (Mti::DATAGRAM, p),
        ]
    );
    assert_eq!(solo.node.delivered.last().unwrap().payload[..], [0x20, 0x80]);
    assert!(matches!(solo.node.events.as_slice(), [Event::Opened { info, .. }] if info.peer == p));

    // A reply addressed to the provisional name goes straight to 0x031: no AME, no Verify.
    let ok = Message::addressed(Mti::DATAGRAM_RECEIVED_OK, node_id(A_ID), p, &[0x00][..]);
    solo.node.link.send(solo.now, ok).unwrap();
    assert_eq!(solo.sent(), [":X19A28123N003100;"]);

    // Time passes: nothing is ever asked of the peer.
    assert_eq!(solo.advance_ms(10_000), Vec::<String>::new());
    assert_eq!(solo.node.link.poll_timeout(), None, "no timer for the alias");
    // It is still served: the stream it opened still takes its data.
    solo.inject(&[":X1F123031N00AABB;"]);
    assert_eq!(solo.node.received, [0xAA, 0xBB]);
}

// ----- an alias first seen in a message -----

#[test]
fn alias_first_seen_in_a_message_is_learnt_from_what_it_sends() {
    let mut solo = Solo::permitted();
    let sent = solo.inject(&[":X19CC8789N01230010000004;"]);
    assert_eq!(sent, [":X19868123N0789001080000400;"], "the Reply at once, and nothing else");
    assert_eq!(delivered(&solo), [(Mti::STREAM_INITIATE_REQUEST, provisional(0x789))]);
    assert_eq!(solo.advance_ms(10_000), Vec::<String>::new(), "nothing is asked");
    // It announces itself (here: answering someone else's Verify Node ID): renamed
    // provisional -> real, and the stream goes with it.
    assert_eq!(solo.inject(&[":X19170789N050101012202;"]), Vec::<String>::new());
    assert_eq!(solo.node.peer_changes, [PeerChange::Renamed { from: provisional(0x789), to: node_id(C_ID) }]);
    let handle = solo.node.endpoint().handles().next().unwrap();
    assert_eq!(solo.node.endpoint().stream_info(handle).unwrap().peer, node_id(C_ID));
    // Later messages carry the real Node ID; the stream finds its data; nothing more is asked.
    solo.inject(&[":X1F123789N000102;", ":X19828789N0123;"]);
    assert_eq!(solo.node.received, [1, 2]);
    assert_eq!(solo.node.delivered.last().unwrap().source, node_id(C_ID));
    assert_eq!(solo.advance_ms(10_000), Vec::<String>::new());
}

#[test]
fn global_message_from_unknown_alias_draws_no_frame() {
    let mut solo = Solo::permitted();
    // Producer/Consumer Event Report: delivered under the provisional name, nothing sent.
    assert_eq!(solo.inject(&[":X195B4789N0101000000000201;"]), Vec::<String>::new());
    // A global Verify Node ID: our Verified Node ID answers it, and nothing else goes out.
    assert_eq!(solo.inject(&[":X19490789N;"]), [":X19170123N050101012200;"]);
    assert_eq!(delivered(&solo), [(Mti(0x05B4), provisional(0x789)), (Mti::VERIFY_NODE_ID_GLOBAL, provisional(0x789))]);
    assert_eq!(solo.node.link.poll_timeout(), None);
}

// ----- renames -----

/// What reached the layer above, in order.
#[derive(Debug, PartialEq)]
enum Seen {
    Change(PeerChange),
    Message(Mti, NodeId),
}

/// A node above the link that logs what reaches it.
struct Logging<'a> {
    node: &'a mut openlcb_node::Node,
    log: Vec<Seen>,
}

impl PeerChanges for Logging<'_> {
    fn peer_changed(&mut self, change: PeerChange) {
        self.log.push(Seen::Change(change));
        self.node.peer_changed(change);
    }
}

impl Receiver for Logging<'_> {
    fn handle_message(&mut self, now: Instant, message: MessageRef<'_>) {
        self.log.push(Seen::Message(message.mti, message.source));
        self.node.handle_message(now, message);
    }

    fn medium_busy(&mut self, now: Instant) {
        self.node.medium_busy(now);
    }
}

#[test]
fn a_rename_reaches_the_layer_above_inside_handle_frame_before_the_next_message() {
    let mut solo = Solo::permitted();
    let now = solo.now;
    let Node { link, stack, .. } = &mut solo.node;
    let mut above = Logging { node: stack, log: Vec::new() };
    // A stream opened under the provisional name; then, in one burst with nothing done
    // between the frames, the peer's Verified Node ID and its data.
    link.handle_frame(now, &common::frame(":X19CC8789N01230010000004;"), &mut above);
    link.handle_frame(now, &common::frame(":X19170789N050101012202;"), &mut above);
    let (p, c) = (provisional(0x789), node_id(C_ID));
    assert_eq!(
        above.log,
        [
            Seen::Message(Mti::STREAM_INITIATE_REQUEST, p),
            Seen::Change(PeerChange::Renamed { from: p, to: c }),
            Seen::Message(Mti::VERIFIED_NODE_ID, c),
        ],
        "the rename, before handle_frame returned and before the message that taught it"
    );
    link.handle_frame(now, &common::frame(":X1F123789N000102;"), &mut above);
    assert_eq!(above.log.last(), Some(&Seen::Message(Mti::STREAM_DATA_SEND, c)));
    let handle = solo.node.endpoint().handles().next().unwrap();
    assert_eq!(solo.node.endpoint().stream_info(handle).unwrap().peer, c);
    let mut buf = [0u8; 8];
    assert_eq!(solo.node.endpoint().read(now, handle, &mut buf), Ok(2), "the data found its stream");
    assert_eq!(buf[..2], [1, 2]);
}

#[test]
fn amd_mapping_another_node_id_reports_the_old_one_lost() {
    let mut solo = Solo::permitted();
    solo.inject(&[":X10701456N050101012201;", ":X10701456N050101012202;"]);
    assert_eq!(
        solo.node.peer_changes,
        [
            PeerChange::Renamed { from: provisional(0x456), to: node_id(0x0501_0101_2201) },
            PeerChange::Lost(node_id(0x0501_0101_2201)),
        ]
    );
    assert_eq!(solo.node.link.node_of(alias(0x456)), Some(node_id(C_ID)));
}

#[test]
fn amr_reports_the_current_name_real_or_provisional() {
    let mut solo = Solo::permitted();
    solo.inject(&[":X10701456N050101012201;", ":X10703456N050101012201;", ":X10703789N050101012202;"]);
    assert_eq!(
        solo.node.peer_changes[1..],
        [PeerChange::Lost(node_id(0x0501_0101_2201)), PeerChange::Lost(provisional(0x789)),]
    );
}

#[test]
fn global_ame_renames_every_cached_peer_and_amds_rename_back() {
    let mut solo = Solo::permitted();
    solo.inject(&[":X10701456N050101012201;", ":X10701789N050101012202;", ":X10701ABCN050101012203;"]);
    // A stream from 0x456, under its Node ID.
    solo.inject(&[":X19CC8456N01230010000004;"]);
    solo.node.peer_changes.clear();
    assert_eq!(solo.inject(&[":X10702777N;"]), [":X10701123N050101012200;"]);
    let mut renamed = renames(&solo.node.peer_changes);
    renamed.sort();
    let expected = [(0x456, 0x0501_0101_2201), (0x789, 0x0501_0101_2202), (0xABC, 0x0501_0101_2203)]
        .map(|(a, n)| (node_id(n), provisional(a)));
    assert_eq!(renamed, expected, "one rename per cached entry");
    assert_eq!(solo.node.link.cached_aliases(), 0);
    let handle = solo.node.endpoint().handles().next().unwrap();
    assert_eq!(solo.node.endpoint().stream_info(handle).unwrap().peer, provisional(0x456));
    // Data from 0x456 still reaches its stream under the provisional name.
    solo.inject(&[":X1F123456N0011;"]);
    assert_eq!(solo.node.received, [0x11]);
    // The AMDs the AME provoked rename them back.
    solo.node.peer_changes.clear();
    solo.inject(&[":X10701456N050101012201;", ":X10701789N050101012202;"]);
    assert_eq!(
        renames(&solo.node.peer_changes),
        [(provisional(0x456), node_id(0x0501_0101_2201)), (provisional(0x789), node_id(0x0501_0101_2202))]
    );
    let info = solo.node.endpoint().stream_info(handle).unwrap();
    assert_eq!((info.peer, info.role), (node_id(0x0501_0101_2201), Role::Destination));
    solo.inject(&[":X1F123456N0022;"]);
    assert_eq!(solo.node.received, [0x11, 0x22]);
}

/// 1 000 distinct source aliases, each sending an Initiate Request: every request delivered
/// and answered (accept, or 0x2020 once the stream table is full), nothing asked of any; the
/// first 500 peers announce themselves (Verified Node ID) and fill the cache past its bound
/// (evictions rename them back to their provisional names), the last 500 never do. No table
/// ever grows past its configured bound.
#[test]
fn a_thousand_aliases_are_all_served_within_the_bounds() {
    let mut solo = Solo::permitted();
    let config = solo.node.link.config().clone();
    let mut replies = 0;
    let aliases = (0x200u16..).filter(|a| *a != 0x123).take(1000);
    for (i, raw) in aliases.enumerate() {
        let request = format!(":X19CC8{raw:03X}N01230010000004;");
        let sent = solo.inject(&[&request]);
        replies += sent.iter().filter(|f| f.starts_with(&format!(":X19868123N0{raw:03X}"))).count();
        assert_eq!(sent.len(), 1, "the reply only: {sent:?}");
        if i < 500 {
            let node = 0x0501_0101_0000 + u64::from(raw);
            let verified = format!(":X19170{raw:03X}N{node:012X};");
            assert_eq!(solo.inject(&[&verified]), Vec::<String>::new());
        }
        let link = &solo.node.link;
        assert!(link.cached_aliases() <= config.alias_cache_size);
        assert!(link.reassembly_in_use() <= link.reassembly_bound());
    }
    assert_eq!(solo.node.delivered.iter().filter(|m| m.mti == Mti::STREAM_INITIATE_REQUEST).count(), 1000);
    assert_eq!(replies, 1000, "every request answered");
    let renamed = renames(&solo.node.peer_changes);
    let learnt = renamed.iter().filter(|(from, _)| NodeAlias::from_provisional(*from).is_some()).count();
    let evicted = renamed.iter().filter(|(_, to)| NodeAlias::from_provisional(*to).is_some()).count();
    assert_eq!(learnt, 500, "the first 500 peers were learnt");
    assert_eq!(evicted, 500 - config.alias_cache_size, "evictions beyond the cache size");
    let stats = solo.node.link.stats();
    assert_eq!(stats.queue_overflows, 0, "no event and no frame was dropped");
    // The streams of evicted peers follow them: every stream's peer is its current name, a
    // provisional name for an alias not cached, a Node ID for one that is.
    for handle in solo.node.endpoint().handles().collect::<Vec<_>>() {
        let peer = solo.node.endpoint().stream_info(handle).unwrap().peer;
        let current = match NodeAlias::from_provisional(peer) {
            Some(a) => solo.node.link.node_of(a).is_none(),
            None => solo.node.link.alias_of(peer).is_some(),
        };
        assert!(current, "{peer} is a stale name");
    }
}

/// The link's room for peer changes is sized from the cache: a global AME with a full cache
/// of 200 entries hands up 200 renames, none dropped.
#[test]
fn global_ame_with_a_full_cache_drops_no_rename() {
    let mut can = can_config(0x123);
    can.alias_cache_size = 200;
    let mut solo = Solo::permitted_with(can);
    for raw in 0x200u16..0x2C8 {
        let node = 0x0501_0101_0000 + u64::from(raw);
        solo.inject(&[&format!(":X10701{raw:03X}N{node:012X};")]);
    }
    assert_eq!(solo.node.link.cached_aliases(), 200);
    solo.node.peer_changes.clear();
    // One frame: all 200 renames at once.
    solo.node.receive(solo.now, &common::frame(":X10702777N;"));
    assert_eq!(renames(&solo.node.peer_changes).len(), 200);
    assert_eq!(solo.node.link.stats().queue_overflows, 0);
}

/// The flood of the issue: 1 000 aliases that never answer Verify send ten Initiate Requests
/// each; every one of the 10 000 is answered (accepted, or 0x2020 once the stream table is
/// full), and no table grows past its bound.
#[test]
fn ten_thousand_requests_from_a_thousand_silent_aliases_are_all_answered() {
    let mut solo = Solo::permitted();
    let link_config = solo.node.link.config().clone();
    let max_streams = solo.node.endpoint().config().max_streams;
    let (mut accepted, mut busy) = (0, 0);
    for round in 1..=10u8 {
        for raw in (0x200u16..).filter(|a| *a != 0x123).take(1000) {
            let request = format!(":X19CC8{raw:03X}N012300100000{round:02X};");
            for frame in solo.inject(&[&request]) {
                let Some(reply) = frame.strip_prefix(&format!(":X19868123N0{raw:03X}")) else { continue };
                match &reply[4..8] {
                    "8000" => accepted += 1,
                    "2020" => busy += 1,
                    other => panic!("unexpected reply code {other} in {frame}"),
                }
            }
            assert!(solo.node.endpoint().stream_count() <= max_streams);
            assert!(solo.node.link.cached_aliases() <= link_config.alias_cache_size);
        }
    }
    assert_eq!(accepted + busy, 10_000, "every request answered");
    assert_eq!(accepted, max_streams, "the table fills, then every request is refused as busy");
    assert_eq!(solo.node.link.stats().queue_overflows, 0);
}
