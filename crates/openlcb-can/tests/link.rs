//! `CanLink` on virtual time: alias login, collisions, AME/AMR, duplicate Node ID, alias
//! resolution both ways, reassembly errors, and a peer's AMR in the middle of a stream.

mod common;

use common::{A_ID, B_ID, Bus, Node, Solo, alias, can_config, core_config, frame, node_id};
use openlcb_can::{CanConfig, LinkEvent, LoginState, SendError};
use openlcb_stream::{Duration, Event, Instant, Message, Mti, OpenOptions, PeerChange, Termination};

const C_ID: u64 = 0x0501_0101_2202;

// ----- login -----

#[test]
fn login_clean_holds_messages_until_permitted() {
    let mut solo = Solo::new(can_config(0x123));
    assert_eq!(solo.sent(), [":X17050123N;", ":X16101123N;", ":X15012123N;", ":X14200123N;"]);
    assert_eq!(solo.node.link.poll_timeout(), Some(Instant::from_millis(200)));
    assert_eq!(solo.advance_ms(199), Vec::<String>::new(), "the core's Initialization Complete waits");
    // RID and AMD, nothing between them (CFT §6.2.1); then Initialization Complete and the
    // global Verify Node ID naming itself that a node holding the same Node ID answers.
    assert_eq!(
        solo.advance_ms(1),
        [":X10700123N;", ":X10701123N050101012200;", ":X19100123N050101012200;", ":X19490123N050101012200;"]
    );
    assert_eq!(solo.node.link_events, [LinkEvent::Permitted { alias: alias(0x123) }]);
    assert_eq!(solo.node.link.poll_timeout(), None);
}

#[test]
fn login_without_a_fixed_alias_uses_the_generator() {
    let mut solo = Solo::new(CanConfig::default());
    assert_eq!(solo.sent()[0], ":X17050343N;", "0x343 is the generator's alias for 05.01.01.01.22.00");
}

#[test]
fn checking_collision_picks_a_new_alias_and_waits_again() {
    let mut solo = Solo::new(can_config(0x123));
    solo.sent();
    solo.advance_ms(100);
    // Another node sends from 0x123 while we check it.
    let sent = solo.inject(&[":X19100123N050101012209;"]);
    assert_eq!(sent, [":X17050343N;", ":X16101343N;", ":X15012343N;", ":X14200343N;"]);
    assert_eq!(solo.node.link.login().stats().conflicts, 1);
    assert_eq!(solo.advance_ms(199), Vec::<String>::new(), "a full wait for the new alias");
    assert_eq!(
        solo.advance_ms(1),
        [":X10700343N;", ":X10701343N050101012200;", ":X19100343N050101012200;", ":X19490343N050101012200;"]
    );
    assert_eq!(solo.node.link.alias(), Some(alias(0x343)));
}

#[test]
fn permitted_cid_with_our_alias_is_answered_with_rid() {
    let mut solo = Solo::permitted();
    assert_eq!(solo.inject(&[":X17999123N;"]), [":X10700123N;"]);
    assert_eq!(solo.node.link.alias(), Some(alias(0x123)));
    assert!(solo.node.link_events.is_empty());
}

#[test]
fn permitted_collision_sends_amr_logs_in_again_and_announces() {
    let mut solo = Solo::permitted();
    let sent = solo.inject(&[":X19170123N050101012209;"]);
    assert_eq!(sent, [":X10703123N050101012200;", ":X17050343N;", ":X16101343N;", ":X15012343N;", ":X14200343N;"]);
    assert_eq!(solo.node.link_events, [LinkEvent::AliasLost { alias: alias(0x123) }]);
    assert!(matches!(solo.node.link.login().state(), LoginState::Checking { .. }));
    // The link announces the node itself after the new login.
    assert_eq!(solo.advance_ms(200), [":X10700343N;", ":X10701343N050101012200;", ":X19100343N050101012200;"]);
}

#[test]
fn ame_global_and_for_us_are_answered_ame_for_others_not() {
    let mut solo = Solo::permitted();
    assert_eq!(solo.inject(&[":X10702456N;"]), [":X10701123N050101012200;"]);
    assert_eq!(solo.inject(&[":X10702456N050101012200;"]), [":X10701123N050101012200;"]);
    assert_eq!(solo.inject(&[":X10702456N050101012201;"]), Vec::<String>::new());
}

#[test]
fn global_ame_drops_the_cache_and_the_next_send_asks_again() {
    let mut solo = Solo::permitted();
    solo.inject(&[":X10701456N050101012201;"]);
    assert_eq!(solo.node.link.alias_of(node_id(B_ID)), Some(alias(0x456)));
    solo.inject(&[":X10702777N;"]);
    assert_eq!(solo.node.link.alias_of(node_id(B_ID)), None);
    let verify = Message::addressed(Mti::VERIFY_NODE_ID_ADDRESSED, node_id(A_ID), node_id(B_ID), Vec::new());
    solo.node.link.send(solo.now, verify).unwrap();
    assert_eq!(solo.sent(), [":X10702123N050101012201;"], "AME for B");
    assert_eq!(solo.inject(&[":X10701456N050101012201;"]), [":X19488123N0456;"]);
}

#[test]
fn duplicate_node_id_after_the_newcomer_window_is_reported_and_the_link_goes_on() {
    let mut solo = Solo::permitted();
    solo.advance_ms(1000);
    // The newcomer's AMD, then its Initialization Complete: one report for its alias.
    assert_eq!(solo.inject(&[":X10701777N050101012200;", ":X19100777N050101012200;"]), Vec::<String>::new());
    assert_eq!(solo.node.link_events, [LinkEvent::DuplicateNodeId { other: alias(0x777), newcomer: false }]);
    assert_eq!(solo.node.link.stats().own_node_claims, 2);
    assert!(solo.node.delivered.is_empty(), "a claim of our Node ID is not delivered");
    // A Verified Node ID with our Node ID from a third alias (OlcbChecker's me50_dup).
    solo.inject(&[":X19170888N050101012200;"]);
    assert_eq!(solo.node.link_events[1], LinkEvent::DuplicateNodeId { other: alias(0x888), newcomer: false });
    // The node that was there first keeps running: it answers and sends.
    assert_eq!(solo.inject(&[":X10702777N;"]), [":X10701123N050101012200;"]);
    let msg = Message::global(Mti::VERIFY_NODE_ID_GLOBAL, node_id(A_ID), Vec::new());
    solo.node.link.send(solo.now, msg).unwrap();
    assert_eq!(solo.sent(), [":X19490123N;"]);
}

#[test]
fn duplicate_node_id_in_the_newcomer_window_and_leave_sends_the_farewell_then_amr_then_nothing() {
    let mut solo = Solo::permitted();
    // The node that was there first answers our Verify Node ID at once.
    solo.inject(&[":X19170777N050101012200;"]);
    assert_eq!(solo.node.link_events, [LinkEvent::DuplicateNodeId { other: alias(0x777), newcomer: true }]);
    let queued = Message::global(Mti::VERIFY_NODE_ID_GLOBAL, node_id(A_ID), Vec::new());
    solo.node.link.send(solo.now, queued).unwrap();
    let report = Message::global(Mti(0x05B4), node_id(A_ID), &[1, 1, 0, 0, 0, 0, 2, 1][..]);
    solo.node.link.leave(Some(report));
    assert!(!solo.node.link.has_left());
    let frames: Vec<String> =
        core::iter::from_fn(|| solo.node.link.poll_transmit()).map(|f| common::text(&f)).collect();
    assert_eq!(frames, [":X195B4123N0101000000000201;", ":X10703123N050101012200;"], "the queued message is dropped");
    assert!(solo.node.link.has_left());
    let msg = Message::global(Mti::VERIFY_NODE_ID_GLOBAL, node_id(A_ID), Vec::new());
    assert_eq!(solo.node.link.send(solo.now, msg), Err(SendError::Stopped));
    assert_eq!(solo.inject(&[":X10702777N;", ":X17999123N;"]), Vec::<String>::new());
    assert_eq!(solo.advance_ms(5000), Vec::<String>::new());
}

// ----- alias resolution -----

#[test]
fn unknown_destination_is_resolved_with_ame() {
    let mut solo = Solo::permitted();
    let msg = Message::addressed(Mti::VERIFY_NODE_ID_ADDRESSED, node_id(A_ID), node_id(C_ID), Vec::new());
    solo.node.link.send(solo.now, msg.clone()).unwrap();
    solo.node.link.send(solo.now, msg).unwrap();
    assert_eq!(solo.sent(), [":X10702123N050101012202;"], "one AME for two messages");
    assert_eq!(solo.inject(&[":X10701789N050101012202;"]), [":X19488123N0789;", ":X19488123N0789;"]);
}

#[test]
fn messages_waiting_for_an_alias_are_bounded_on_their_own() {
    let mut can = can_config(0x123);
    can.unresolved_limit = 1;
    let mut solo = Solo::permitted_with(can);
    let to = |id| Message::addressed(Mti::VERIFY_NODE_ID_ADDRESSED, node_id(A_ID), node_id(id), Vec::new());
    solo.node.link.send(solo.now, to(C_ID)).unwrap();
    assert_eq!(solo.sent(), [":X10702123N050101012202;"], "AME for C");
    // A second unknown destination finds the waiting room full; a known one is sent.
    assert_eq!(solo.node.link.send(solo.now, to(B_ID)), Err(SendError::QueueFull));
    assert_eq!(solo.node.link.stats().send_refused, 1);
    solo.inject(&[":X10701456N050101012201;"]);
    solo.node.link.send(solo.now, to(B_ID)).unwrap();
    assert_eq!(solo.sent(), [":X19488123N0456;"]);
    // C answers: its message goes, and the room is free again.
    assert_eq!(solo.inject(&[":X10701789N050101012202;"]), [":X19488123N0789;"]);
    solo.node.link.send(solo.now, to(0x05_01_01_01_22_03)).unwrap();
    assert_eq!(solo.sent(), [":X10702123N050101012203;"]);
}

#[test]
fn unknown_destination_times_out_as_unreachable() {
    let mut solo = Solo::permitted();
    let msg = Message::addressed(Mti::VERIFY_NODE_ID_ADDRESSED, node_id(A_ID), node_id(C_ID), Vec::new());
    solo.node.link.send(solo.now, msg).unwrap();
    solo.sent();
    assert_eq!(solo.node.link.poll_timeout(), Some(solo.now + Duration::from_secs(1)));
    solo.advance_ms(999);
    assert!(solo.node.peer_changes.is_empty());
    solo.advance_ms(1);
    assert_eq!(solo.node.peer_changes, [PeerChange::Lost(node_id(C_ID))]);
    assert_eq!(solo.node.link.stats().unresolved_dropped, 1);
    assert_eq!(solo.node.link.poll_timeout(), None);
}

// ----- reassembly errors -----

#[test]
fn reassembly_errors_are_counted_and_rejected_with_oir() {
    let mut solo = Solo::permitted();
    solo.inject(&[":X10701789N050101012202;"]);
    // 0x2041: last frame without a first.
    assert_eq!(solo.inject(&[":X19CC8789N2123FF;"]), [":X19068123N078920410CC8;"]);
    // 0x2042: a second first frame. Only counted: the new message continues and completes.
    solo.inject(&[":X19CC8789N1123001000000407;"]);
    let sent = solo.inject(&[":X19CC8789N1123001000000407;", ":X19CC8789N2123050101012202;"]);
    assert_eq!(sent, [":X19868123N0789001080000407;"], "the restarted request was delivered");
    // 0x2011: no last frame within 3 s.
    solo.inject(&[":X19A08789N1123010203040506;"]);
    assert_eq!(solo.node.link.poll_timeout(), Some(solo.now + Duration::from_secs(3)));
    assert_eq!(solo.advance_ms(3000), [":X19068123N078920110A08;"]);
    let stats = solo.node.link.stats();
    assert_eq!((stats.middle_without_first, stats.first_before_last_ended, stats.reassembly_timeouts), (1, 1, 1));
}

#[test]
fn event_reports_with_payload_are_reassembled_and_never_answered() {
    let mut solo = Solo::permitted();
    // OlcbChecker ev60_ewp: first + last, first + middle + last.
    let sent = solo.inject(&[
        ":X19F16789N0501010122020000;",
        ":X19F14789N01020304;",
        ":X19F16789N0501010122020000;",
        ":X19F15789N0102030405060708;",
        ":X19F14789N090A0B0C;",
    ]);
    assert_eq!(sent, Vec::<String>::new());
    let reports: Vec<(Mti, Vec<u8>)> = solo.node.delivered.iter().map(|m| (m.mti, m.payload.clone())).collect();
    let event = [5, 1, 1, 1, 0x22, 2, 0, 0];
    let mut long = event.to_vec();
    long.extend(1..=12);
    assert_eq!(
        reports,
        [
            (Mti::PRODUCER_CONSUMER_EVENT_REPORT, [&event[..], &[1, 2, 3, 4]].concat()),
            (Mti::PRODUCER_CONSUMER_EVENT_REPORT, long)
        ]
    );
    // First + 255 middles + last: longer than the reassembly buffer, dropped and counted, and
    // (a global message) not answered.
    let mut flood = vec![":X19F16789N0501010122020000;"];
    flood.extend(std::iter::repeat_n(":X19F15789N0102030405060708;", 255));
    flood.push(":X19F14789N090A0B0C0D0E0F;");
    assert_eq!(solo.inject(&flood), Vec::<String>::new());
    assert_eq!(solo.node.delivered.len(), 2);
    assert_eq!(solo.node.link.stats().reassembly_overflows, 1);
    assert_eq!(solo.node.link.reassembly_in_use(), 0);
}

#[test]
fn frames_for_other_nodes_and_odd_frames_are_counted() {
    let mut solo = Solo::permitted();
    solo.inject(&[":X10701789N050101012202;"]);
    assert_eq!(solo.inject(&[":X19CC8789N04560010000004;", ":X1F456789N0700;"]), Vec::<String>::new());
    assert_eq!(solo.node.link.stats().not_for_us, 2);
    solo.inject(&[":X1F123789N;", ":X19CC8789N01;"]);
    assert_eq!(solo.node.link.stats().invalid_frames, 2);
    solo.inject(&[":X1E123789N2001;"]);
    assert_eq!(solo.node.link.stats().unsupported_ignored, 1, "reserved format 6");
    assert!(solo.node.events.is_empty());
    assert!(solo.node.delivered.is_empty());
}

// ----- two nodes -----

fn streaming_pair() -> (Bus, openlcb_stream::StreamHandle) {
    let mut bus = Bus::new(vec![
        Node::new(Instant::ZERO, A_ID, core_config(), can_config(0x123)),
        Node::new(Instant::ZERO, B_ID, core_config(), can_config(0x456)),
    ]);
    bus.advance_to(Instant::from_millis(200));
    bus.nodes[1].reading = false; // B's buffer fills: the stream stays open mid-transfer
    let now = bus.now;
    let stream = bus.nodes[0].endpoint().open(now, OpenOptions::new(node_id(B_ID), 16)).unwrap();
    bus.pump();
    assert_eq!(bus.nodes[0].endpoint().write(now, stream, &[0x55; 40]).unwrap(), 16);
    bus.pump();
    assert_eq!(bus.nodes[1].endpoint().stream_count(), 1);
    (bus, stream)
}

fn terminations(node: &Node) -> Vec<Termination> {
    node.events
        .iter()
        .filter_map(|e| match e {
            Event::Terminated { cause, .. } => Some(*cause),
            _ => None,
        })
        .collect()
}

#[test]
fn peer_amr_mid_stream_ends_the_stream_with_peer_lost() {
    let (mut bus, _) = streaming_pair();
    // B's alias is released (as seen by A only: B itself is not told).
    bus.nodes[0].receive(bus.now, &frame(":X10703456N050101012201;"));
    bus.pump();
    assert!(bus.nodes[0].peer_changes.contains(&PeerChange::Lost(node_id(B_ID))));
    assert_eq!(terminations(&bus.nodes[0]), [Termination::PeerLost]);
    assert_eq!(bus.nodes[0].endpoint().stream_count(), 0);
    assert_eq!(bus.nodes[0].link.alias_of(node_id(B_ID)), None);
}

#[test]
fn alias_taken_mid_stream_ends_both_sides_without_a_hang() {
    let (mut bus, _) = streaming_pair();
    // A third node uses A's alias: A sends AMR and logs in again; B hears the AMR.
    bus.broadcast(None, &frame(":X19170123N050101012209;"));
    bus.pump();
    assert!(bus.nodes[0].link_events.contains(&LinkEvent::AliasLost { alias: alias(0x123) }));
    assert_eq!(terminations(&bus.nodes[0]), [Termination::LinkLost]);
    assert!(bus.nodes[1].peer_changes.contains(&PeerChange::Lost(node_id(A_ID))));
    assert_eq!(terminations(&bus.nodes[1]), [Termination::PeerLost]);
    // Time runs on: A comes back with a new alias and B learns it; nothing is left waiting.
    bus.run_until(Instant::from_millis(120_000));
    assert_eq!(bus.nodes[0].link.alias(), Some(alias(0x343)));
    assert_eq!(bus.nodes[1].link.alias_of(node_id(A_ID)), Some(alias(0x343)));
    assert_eq!(bus.nodes[0].endpoint().stream_count(), 0);
    assert_eq!(bus.nodes[0].link.queued_messages(), 0);
    assert_eq!(bus.next_timeout(), None, "no timer left: no hang");
}

#[test]
fn send_refuses_messages_without_a_can_form_and_beyond_the_queue_bound() {
    let mut can = can_config(0x123);
    can.transmit_queue_limit = 2;
    let mut solo = Solo::new(can);
    let a = node_id(A_ID);
    let long = Message::global(Mti::VERIFY_NODE_ID_GLOBAL, a, vec![0u8; 9]);
    assert_eq!(solo.node.link.send(solo.now, long), Err(SendError::Encode(openlcb_can::EncodeError::GlobalTooLong(9))));
    // Not yet permitted: messages wait, up to the bound.
    let verify = Message::global(Mti::VERIFY_NODE_ID_GLOBAL, a, Vec::new());
    solo.node.link.send(solo.now, verify.clone()).unwrap();
    assert!(solo.node.link.can_send());
    solo.node.link.send(solo.now, verify.clone()).unwrap();
    assert!(!solo.node.link.can_send());
    assert_eq!(solo.node.link.send(solo.now, verify), Err(SendError::QueueFull));
    assert_eq!(solo.node.link.stats().send_refused, 2);
    assert_eq!(solo.node.link.queued_messages(), 2);
}

// ----- transmit order -----

#[test]
fn stream_control_goes_between_the_frames_of_stream_data_and_everything_else_keeps_its_place() {
    let mut solo = Solo::permitted();
    solo.inject(&[":X10701789N050101012202;"]);
    let to_c = |mti: Mti, payload: &[u8]| Message::addressed(mti, node_id(A_ID), node_id(C_ID), payload.to_vec());
    let link = &mut solo.node.link;
    // A DID and 21 bytes: three frames.
    link.send(solo.now, to_c(Mti::STREAM_DATA_SEND, &[7; 22])).unwrap();
    link.send(solo.now, to_c(Mti::STREAM_DATA_COMPLETE, &[4, 7, 0, 0, 0, 21])).unwrap();
    let first = link.poll_transmit().map(|f| common::text(&f));
    let data = ":X1F789123N0707070707070707;";
    assert_eq!(first.as_deref(), Some(data));
    // A Proceed and an Initiate Reply queued behind the data and its Complete go before
    // the data's next frame.
    link.send(solo.now, to_c(Mti::STREAM_DATA_PROCEED, &[5, 8])).unwrap();
    link.send(solo.now, to_c(Mti::STREAM_INITIATE_REPLY, &[0, 16, 0x80, 0, 6, 9])).unwrap();
    // Anything else keeps its place: an Unfreeze never overtakes the end of the stream.
    link.send(solo.now, to_c(Mti::DATAGRAM, &[0x20, 0xA0, 0xEF])).unwrap();
    assert_eq!(
        solo.sent(),
        [
            ":X19888123N07890508;",
            ":X19868123N0789001080000609;",
            data,
            data,
            ":X198A8123N0789040700000015;",
            ":X1A789123N20A0EF;"
        ]
    );
}

#[test]
fn stream_data_on_the_bus_tells_the_layer_above_that_the_medium_is_busy() {
    let mut solo = Solo::permitted();
    solo.inject(&[":X10701789N050101012202;", ":X19100789N050101012202;"]);
    assert!(solo.node.medium_busy.is_empty(), "no stream data yet");
    // Stream data to another node, then to this one (for no stream it has open).
    solo.inject(&[":X1F456789N0700;", ":X1F123789N0700;"]);
    assert_eq!(solo.node.medium_busy, [solo.now, solo.now]);
}

#[test]
fn stream_control_never_overtakes_a_message_queued_before_it() {
    // MC C-4: a server's Datagram OK goes before the Initiate Request of the Read Stream it
    // accepts (OlcbChecker waits for the OK, then for the request); an Initiate Reply keeps
    // its place behind a datagram too.
    let mut solo = Solo::permitted();
    solo.inject(&[":X10701789N050101012202;"]);
    let to_c = |mti: Mti, payload: &[u8]| Message::addressed(mti, node_id(A_ID), node_id(C_ID), payload.to_vec());
    let link = &mut solo.node.link;
    link.send(solo.now, to_c(Mti::DATAGRAM_RECEIVED_OK, &[0x80])).unwrap();
    link.send(solo.now, to_c(Mti::STREAM_INITIATE_REQUEST, &[0, 16, 0, 0, 4])).unwrap();
    link.send(solo.now, to_c(Mti::DATAGRAM, &[0x20, 0x30])).unwrap();
    link.send(solo.now, to_c(Mti::STREAM_INITIATE_REPLY, &[0, 16, 0x80, 0, 6, 9])).unwrap();
    assert_eq!(
        solo.sent(),
        [":X19A28123N078980;", ":X19CC8123N07890010000004;", ":X1A789123N2030;", ":X19868123N0789001080000609;"]
    );
}
