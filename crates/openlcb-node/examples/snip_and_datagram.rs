//! Two sans-IO nodes back to back: A asks B for its Simple Node Information (SNIP) and sends
//! it a datagram, which B's application accepts. Messages go straight from one node's
//! `poll_transmit` into the other's `handle_message`.
//!
//! `cargo run -p openlcb-node --example snip_and_datagram`

use openlcb_node::{DatagramAnswer, Node, NodeConfig, NodeEvent, OkFlags, SnipInfo};
use openlcb_stream::{Instant, NodeId};

mod common;
use common::pump;

/// The datagram content A sends: first byte 0x21, a content ID B claims.
const DATAGRAM: [u8; 4] = [0x21, 1, 2, 3];

fn main() {
    let a_id: NodeId = "05.01.01.01.22.00".parse().expect("a valid Node ID");
    let b_id: NodeId = "05.01.01.01.22.01".parse().expect("a valid Node ID");
    let mut b_config = NodeConfig::default();
    b_config.snip = SnipInfo { manufacturer: "Acme".into(), model: "Widget".into(), ..SnipInfo::default() };
    b_config.datagrams.claimed = vec![DATAGRAM[0]];
    let mut a = Node::new(a_id, NodeConfig::default());
    let mut b = Node::new(b_id, b_config);
    let now = Instant::ZERO;

    pump(now, &mut a, &mut b); // both announce themselves (Initialization Complete)
    a.request_snip(now, b_id).expect("room for a SNIP request");
    let sent = a.send_datagram(now, b_id, &DATAGRAM).expect("a datagram slot for B");
    pump(now, &mut a, &mut b);

    // B's application gets the datagram and answers it.
    let mut answered = false;
    while let Some(event) = b.poll_event() {
        if let NodeEvent::DatagramReceived { from, datagram } = event {
            println!("B: datagram {:02X?} from {from}", datagram.as_slice());
            b.answer_datagram(from, DatagramAnswer::Ok(OkFlags::default())).expect("a datagram to answer");
            answered = true;
        }
    }
    assert!(answered, "B received no datagram");
    pump(now, &mut a, &mut b);

    let (mut snip, mut delivered) = (None, false);
    while let Some(event) = a.poll_event() {
        match event {
            NodeEvent::SnipReceived { info, .. } => snip = Some(info),
            NodeEvent::DatagramDelivered { id, .. } if id == sent => delivered = true,
            _ => {}
        }
    }
    let snip = snip.expect("B's SNIP");
    println!("A: {b_id} is \"{}\" \"{}\"", snip.manufacturer, snip.model);
    assert_eq!(snip.model, "Widget");
    assert!(delivered, "B did not acknowledge the datagram");
    println!("A: the datagram was delivered (Datagram Received OK)");
}

/// `cargo test` runs the example (`test = true` in Cargo.toml); it asserts on the exchange.
#[test]
fn exchanges_snip_and_a_datagram() {
    main();
}
