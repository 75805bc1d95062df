//! Wire-spec §9.2 end to end: A (05.01.01.01.22.00, alias 0x123) sends 20 bytes to
//! B (05.01.01.01.22.01, alias 0x456) through two `CanLink`s and two `StreamEndpoint`s, with
//! window 16, SID 4 and DID 7; every frame on the bus is compared with the published text.

mod common;

use common::{A_ID, B_ID, Bus, Node, can_config, core_config, node_id};
use openlcb_stream::{Event, Instant, OpenOptions, StreamHandle, StreamId};

const A: usize = 0;
const B: usize = 1;

fn two_nodes() -> Bus {
    Bus::new(vec![
        Node::new(Instant::ZERO, A_ID, core_config(), can_config(0x123)),
        Node::new(Instant::ZERO, B_ID, core_config(), can_config(0x456)),
    ])
}

fn opened(node: &Node, handle: StreamHandle) -> bool {
    node.events.iter().any(|e| matches!(e, Event::Opened { handle: h, .. } if *h == handle))
}

#[test]
fn login_frames_of_a_and_b() {
    let mut bus = two_nodes();
    bus.pump();
    assert_eq!(bus.sent_by(A), [":X17050123N;", ":X16101123N;", ":X15012123N;", ":X14200123N;"]);
    assert_eq!(bus.sent_by(B), [":X17050456N;", ":X16101456N;", ":X15012456N;", ":X14201456N;"]);
    // Nothing more before the 200 ms are up.
    bus.advance_to(Instant::from_millis(199));
    assert_eq!(bus.trace.len(), 8);
    bus.advance_to(Instant::from_millis(200));
    let (a, b) = (bus.sent_by(A), bus.sent_by(B));
    assert_eq!(
        a[4..],
        [":X10700123N;", ":X10701123N050101012200;", ":X19100123N050101012200;", ":X19490123N050101012200;"]
    );
    assert_eq!(
        b[4..],
        [":X10700456N;", ":X10701456N050101012201;", ":X19100456N050101012201;", ":X19490456N050101012201;"]
    );
    // Each learnt the other's alias from its AMD / Initialization Complete.
    assert_eq!(bus.nodes[A].link.alias_of(node_id(B_ID)).map(|a| a.as_raw()), Some(0x456));
    assert_eq!(bus.nodes[B].link.alias_of(node_id(A_ID)).map(|a| a.as_raw()), Some(0x123));
}

#[test]
fn twenty_bytes_from_a_to_b_frame_for_frame() {
    let mut bus = two_nodes();
    bus.advance_to(Instant::from_millis(200));
    let b = node_id(B_ID);

    // B rotates its DIDs from 0: seven throwaway streams use DIDs 0..=6, so that the stream
    // of the example gets DID 7 as published.
    for _ in 0..7 {
        let now = bus.now;
        let handle = bus.nodes[A].endpoint().open(now, OpenOptions::new(b, 16)).unwrap();
        bus.pump();
        assert!(opened(&bus.nodes[A], handle));
        bus.nodes[A].endpoint().finish(now, handle).unwrap();
        bus.pump();
    }
    assert_eq!(bus.nodes[B].endpoint().stream_count(), 0);
    bus.clear_trace();
    bus.nodes[B].received.clear();

    let data: Vec<u8> = (0u8..20).collect();
    let now = bus.now;
    let options = OpenOptions::new(b, 16).source_stream(StreamId::new(4).unwrap());
    let stream = bus.nodes[A].endpoint().open(now, options).unwrap();
    bus.pump();
    assert!(opened(&bus.nodes[A], stream));
    let sent = bus.nodes[A].endpoint().write(now, stream, &data).unwrap();
    assert_eq!(sent, 16, "one window of credit");
    bus.pump();
    let rest = bus.nodes[A].endpoint().write(now, stream, &data[sent..]).unwrap();
    assert_eq!(rest, 4, "credit back after the Proceed");
    bus.nodes[A].endpoint().finish(now, stream).unwrap();
    bus.pump();

    let expected = [
        (A, ":X19CC8123N04560010000004;"),   // M1 Initiate Request, 5 bytes
        (B, ":X19868456N0123001080000407;"), // M2 Initiate Reply, accept, DID 7
        (A, ":X1F456123N0700010203040506;"), // M3 Data Send, 16 bytes in 3 frames
        (A, ":X1F456123N070708090A0B0C0D;"),
        (A, ":X1F456123N070E0F;"),
        (B, ":X19888456N012304070000;"),     // M4 Proceed
        (A, ":X1F456123N0710111213;"),       // M5 Data Send, 4 bytes
        (A, ":X198A8123N0456040700000014;"), // M6a: the core's Complete is form B, count 20
    ];
    let trace: Vec<(usize, &str)> = bus.trace.iter().map(|(s, t)| (*s, t.as_str())).collect();
    assert_eq!(trace, expected);
    assert_eq!(bus.nodes[B].received, data);
    let finished = bus.nodes[B].events.iter().rev().find_map(|e| match e {
        Event::Finished { total, matched, .. } => Some((*total, *matched)),
        _ => None,
    });
    assert_eq!(finished, Some((20, true)));
}
