//! Datagrams on CAN (node-protocols §2.5): frames 2-5 both ways through two `CanLink`s, the
//! worked examples of §9.1 and §9.6 byte for byte, and every framing error answered with
//! Datagram Rejected.

mod common;

use common::{A_ID, B_ID, Bus, Node, Solo, alias, can_config, claiming_every_datagram, node_id};
use openlcb_can::{CanConfig, EncodeError, SendError};
use openlcb_stream::{Instant, Message, Mti};

/// A (alias 0x123) and B (alias 0x456) logged in, each knowing the other from its AMD.
fn pair() -> Bus {
    let mut bus = Bus::new(vec![
        Node::with_config(Instant::ZERO, A_ID, claiming_every_datagram(), can_config(0x123)),
        Node::with_config(Instant::ZERO, B_ID, claiming_every_datagram(), can_config(0x456)),
    ]);
    bus.advance_to(Instant::from_millis(200));
    bus.clear_trace();
    for node in &mut bus.nodes {
        node.delivered.clear();
    }
    bus
}

/// Sends `payload` as a datagram from node `from` to the other, and returns the frames that
/// carried it (the answers of the receiving stream core are left out).
fn send_datagram(bus: &mut Bus, from: usize, payload: &[u8]) -> Vec<String> {
    let (source, destination) = if from == 0 { (A_ID, B_ID) } else { (B_ID, A_ID) };
    let datagram = Message::addressed(Mti::DATAGRAM, node_id(source), node_id(destination), payload.to_vec());
    let now = bus.now;
    bus.nodes[from].link.send(now, datagram).unwrap();
    bus.pump();
    bus.sent_by(from).iter().map(|t| t.to_string()).collect()
}

fn datagrams_delivered(node: &Node) -> Vec<&Message> {
    node.delivered.iter().filter(|m| m.mti == Mti::DATAGRAM).collect()
}

// ----- both ways through two links -----

#[test]
fn single_frame_datagram_both_ways() {
    let mut bus = pair();
    // node-protocols §9.6: Get Configuration Options, and its reply.
    assert_eq!(send_datagram(&mut bus, 0, &[0x20, 0x80]), [":X1A456123N2080;"]);
    bus.clear_trace();
    let reply = [0x20, 0x82, 0x60, 0x00, 0xE3, 0xFF, 0xEF];
    assert_eq!(send_datagram(&mut bus, 1, &reply), [":X1A123456N20826000E3FFEF;"]);
    let at_b = datagrams_delivered(&bus.nodes[1]);
    assert_eq!(at_b.len(), 1);
    assert_eq!((at_b[0].source, at_b[0].destination), (node_id(A_ID), Some(node_id(B_ID))));
    assert_eq!(at_b[0].payload[..], [0x20, 0x80]);
    let at_a = datagrams_delivered(&bus.nodes[0]);
    assert_eq!((at_a.len(), &at_a[0].payload[..]), (1, &reply[..]));
}

#[test]
fn worked_example_write_of_eight_bytes_is_first_and_last() {
    let mut bus = pair();
    // node-protocols §9.1: 20 01 | address 00000000 | 01..08, from CT 0x123 to target 0x456.
    let payload = [0x20, 0x01, 0, 0, 0, 0, 1, 2, 3, 4, 5, 6, 7, 8];
    assert_eq!(send_datagram(&mut bus, 0, &payload), [":X1B456123N2001000000000102;", ":X1D456123N030405060708;"]);
    assert_eq!(datagrams_delivered(&bus.nodes[1])[0].payload[..], payload);
    // Its answer is an ordinary addressed message: Datagram Received OK, flags 00.
    let now = bus.now;
    let ok = Message::addressed(Mti::DATAGRAM_RECEIVED_OK, node_id(B_ID), node_id(A_ID), &[0x00][..]);
    bus.nodes[1].link.send(now, ok).unwrap();
    bus.clear_trace();
    bus.pump();
    assert_eq!(bus.sent_by(1), [":X19A28456N012300;"]);
    let last = bus.nodes[0].delivered.last().unwrap();
    assert_eq!((last.mti, &last.payload[..]), (Mti::DATAGRAM_RECEIVED_OK, &[0x00][..]));
}

#[test]
fn datagram_of_72_bytes_both_ways() {
    let mut bus = pair();
    let payload: Vec<u8> = (0..72).collect();
    let frames = send_datagram(&mut bus, 0, &payload);
    let mut expected = vec![":X1B456123N0001020304050607;".to_string()];
    for i in 1..8u8 {
        let bytes: String = (i * 8..i * 8 + 8).map(|b| format!("{b:02X}")).collect();
        expected.push(format!(":X1C456123N{bytes};"));
    }
    expected.push(":X1D456123N4041424344454647;".to_string());
    assert_eq!(frames, expected);
    assert_eq!(datagrams_delivered(&bus.nodes[1])[0].payload[..], payload[..]);

    bus.clear_trace();
    let back: Vec<u8> = (0..72).map(|b| 0xFF - b).collect();
    let frames = send_datagram(&mut bus, 1, &back);
    assert_eq!(frames.len(), 9);
    assert_eq!(frames[0], ":X1B123456NFFFEFDFCFBFAF9F8;");
    assert!(frames[1..8].iter().all(|f| f.starts_with(":X1C123456N") && f.len() == 28));
    assert_eq!(frames[8], ":X1D123456NBFBEBDBCBBBAB9B8;");
    assert_eq!(datagrams_delivered(&bus.nodes[0])[0].payload[..], back[..]);
}

#[test]
fn datagram_over_72_bytes_is_refused_by_send() {
    let mut bus = pair();
    let long = Message::addressed(Mti::DATAGRAM, node_id(A_ID), node_id(B_ID), vec![0u8; 73]);
    let now = bus.now;
    assert_eq!(bus.nodes[0].link.send(now, long), Err(SendError::Encode(EncodeError::DatagramTooLong(73))));
}

#[test]
fn datagram_rejected_is_an_ordinary_addressed_message() {
    let mut bus = pair();
    let now = bus.now;
    let rejected = Message::addressed(Mti::DATAGRAM_REJECTED, node_id(B_ID), node_id(A_ID), &[0x10, 0x42][..]);
    bus.nodes[1].link.send(now, rejected).unwrap();
    bus.pump();
    // node-protocols §9.6.
    assert_eq!(bus.sent_by(1), [":X19A48456N01231042;"]);
    let last = bus.nodes[0].delivered.last().unwrap();
    assert_eq!((last.mti, last.source, &last.payload[..]), (Mti::DATAGRAM_REJECTED, node_id(B_ID), &[0x10, 0x42][..]));
}

// ----- receiving: one link, frames by hand -----

/// A link at 0x123 that knows 0x456 and 0x789 (from their AMDs).
fn receiver(can: CanConfig) -> Solo {
    let mut solo = Solo::logged_in(Solo::with_config(can, claiming_every_datagram()));
    solo.inject(&[":X10701456N050101012201;", ":X10701789N050101012202;"]);
    solo
}

/// Frames `solo` sends after `texts` (its node takes every datagram, so these are the link's).
fn answers(solo: &mut Solo, texts: &[&str]) -> Vec<String> {
    solo.inject(texts)
}

#[test]
fn interleaved_frames_from_two_sources_are_assembled_apart() {
    let mut solo = receiver(can_config(0x123));
    let sent = answers(
        &mut solo,
        &[
            ":X1B123456N0101010101010101;",
            ":X1B123789N0202020202020202;",
            ":X1C123456N1111111111111111;",
            ":X1D123789N22;",
            ":X1D123456N3333;",
        ],
    );
    assert_eq!(sent, Vec::<String>::new());
    let got: Vec<_> = datagrams_delivered(&solo.node).into_iter().map(|m| (m.source, m.payload.to_vec())).collect();
    assert_eq!(
        got,
        [
            (node_id(0x0501_0101_2202), [[2u8; 8].as_slice(), &[0x22]].concat()),
            (node_id(B_ID), [[1u8; 8].as_slice(), &[0x11; 8], &[0x33, 0x33]].concat()),
        ]
    );
    assert_eq!(solo.node.link.reassembly_in_use(), 0);
}

#[test]
fn middle_or_last_without_first_is_rejected_0x2041() {
    let mut solo = receiver(can_config(0x123));
    // One answer for the datagram whose first frame never came: at its last frame.
    assert_eq!(answers(&mut solo, &[":X1C123789N0102;"]), Vec::<String>::new());
    assert_eq!(answers(&mut solo, &[":X1D123789N0102;"]), [":X19A48123N07892041;"]);
    assert_eq!(solo.node.link.stats().datagram_errors.middle_without_first, 1);
    assert!(datagrams_delivered(&solo.node).is_empty());
}

#[test]
fn first_before_last_is_rejected_0x2042_and_drops_both() {
    let mut solo = receiver(can_config(0x123));
    let sent = answers(&mut solo, &[":X1B123789N0101010101010101;", ":X1B123789N0202020202020202;"]);
    assert_eq!(sent, [":X19A48123N07892042;"]);
    // The new first frame went too; its last frame, already answered, goes without a word.
    assert_eq!(answers(&mut solo, &[":X1D123789N03;"]), Vec::<String>::new());
    // The sender's resend goes through cleanly.
    assert_eq!(answers(&mut solo, &[":X1B123789N0202020202020202;", ":X1D123789N03;"]), Vec::<String>::new());
    let got = datagrams_delivered(&solo.node);
    assert_eq!((got.len(), got[0].payload.len()), (1, 9));
    assert_eq!(solo.node.link.stats().datagram_errors.first_before_last_ended, 1);
}

#[test]
fn datagram_over_72_bytes_is_rejected_0x1000() {
    let mut solo = receiver(can_config(0x123));
    let mut frames = vec![":X1B123789N0000000000000000;"];
    frames.extend([":X1C123789N0000000000000000;"; 8]);
    assert_eq!(answers(&mut solo, &frames), Vec::<String>::new(), "72 bytes so far");
    assert_eq!(answers(&mut solo, &[":X1D123789N00;"]), [":X19A48123N07891000;"]);
    assert_eq!(solo.node.link.stats().datagram_errors.too_long, 1);
    assert_eq!(solo.node.link.reassembly_in_use(), 0, "the partial datagram is dropped");
    assert!(datagrams_delivered(&solo.node).is_empty());
}

#[test]
fn datagram_without_last_frame_times_out_0x2011() {
    let mut solo = receiver(can_config(0x123));
    answers(&mut solo, &[":X1B123789N0101010101010101;"]);
    assert_eq!(solo.advance_ms(1000), Vec::<String>::new());
    // A middle frame does not restart the wait: it runs from the first frame.
    answers(&mut solo, &[":X1C123789N0101010101010101;"]);
    assert_eq!(solo.advance_ms(1999), Vec::<String>::new());
    assert_eq!(solo.advance_ms(1), [":X19A48123N07892011;"]);
    assert_eq!(solo.node.link.stats().datagram_errors.timeouts, 1);
    // The late last frame of the datagram answered with 0x2011 is not answered again.
    assert_eq!(answers(&mut solo, &[":X1D123789N01;"]), Vec::<String>::new());
}

#[test]
fn no_free_slot_at_a_first_frame_is_rejected_0x2020() {
    let mut can = can_config(0x123);
    can.datagram_slots = 2;
    let mut solo = receiver(can);
    let sent = answers(
        &mut solo,
        &[":X1B123456N0101010101010101;", ":X1B123789N0101010101010101;", ":X1B123ABCN0101010101010101;"],
    );
    assert_eq!(sent, [":X19A48123N0ABC2020;"]);
    assert_eq!(answers(&mut solo, &[":X1D123ABCN0303;"]), Vec::<String>::new(), "answered once");
    assert_eq!(solo.node.link.stats().datagram_errors.no_free_slot, 1);
    // A single-frame datagram needs no slot (0xABC is unknown: nothing is asked of it).
    assert_eq!(answers(&mut solo, &[":X1A123ABCN20;"]), Vec::<String>::new());
    assert_eq!(datagrams_delivered(&solo.node).len(), 1);
    assert!(solo.node.link.reassembly_in_use() <= solo.node.link.reassembly_bound());
}

#[test]
fn datagrams_for_another_alias_are_not_for_us() {
    let mut solo = receiver(can_config(0x123));
    assert_eq!(answers(&mut solo, &[":X1A456789N2080;", ":X1C456789N01;"]), Vec::<String>::new());
    assert_eq!(solo.node.link.stats().not_for_us, 2);
    assert!(solo.node.delivered.iter().all(|m| m.mti != Mti::DATAGRAM));
}

#[test]
fn datagram_from_an_unknown_alias_is_delivered_under_its_provisional_name() {
    let mut solo = receiver(can_config(0x123));
    // OpenMRN's bootloader_client opens with this Write Stream datagram (issue 9).
    let sent = solo.inject(&[":X1A1237E5N202000000000EF55;"]);
    assert_eq!(sent, Vec::<String>::new(), "nothing is asked of it");
    let got = datagrams_delivered(&solo.node);
    assert_eq!(got[0].source, alias(0x7E5).provisional_node_id());
    assert_eq!(got[0].payload[..], [0x20, 0x20, 0, 0, 0, 0, 0xEF, 0x55]);
    // The answer to the provisional name goes straight to 0x7E5.
    let rejected = Message::addressed(
        Mti::DATAGRAM_REJECTED,
        node_id(A_ID),
        alias(0x7E5).provisional_node_id(),
        &[0x10, 0x42][..],
    );
    solo.node.link.send(solo.now, rejected).unwrap();
    assert_eq!(solo.sent(), [":X19A48123N07E51042;"]);
}

#[test]
fn a_crowd_of_interleaved_datagrams_gets_exactly_one_answer_each() {
    // 500 senders, every slot taken: each first frame, then each middle, then each last.
    let mut can = can_config(0x123);
    can.datagram_slots = 4;
    let mut solo = receiver(can);
    let senders: Vec<u16> = (0x200..0x200 + 500).collect();
    let mut sent = Vec::new();
    for frame in ["1B", "1C", "1D"] {
        for alias in &senders {
            sent.extend(answers(&mut solo, &[&format!(":X{frame}123{alias:03X}N0101010101010101;")]));
        }
    }
    let delivered = datagrams_delivered(&solo.node).len();
    assert_eq!(delivered, 4, "one per slot went through");
    for alias in &senders {
        let answered = sent.iter().filter(|f| f.contains(&format!("N0{alias:03X}"))).count();
        assert!(answered <= 1, "0x{alias:03X} heard {answered} answers: {sent:?}");
    }
    assert_eq!(sent.len() + delivered, senders.len(), "every datagram is answered or delivered");
    assert!(sent.iter().all(|f| f.starts_with(":X19A48123N") && (f.ends_with("2020;") || f.ends_with("2041;"))));
}
