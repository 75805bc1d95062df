//! Datagrams through the gateway, both ways: CAN frames 2-5 reassembled into one full-format
//! Datagram, a full-format Datagram framed as 2-5 from the proxy alias of its source, and
//! framing errors answered on CAN with Datagram Rejected from the proxy alias.

mod common;

use common::{CAN_NODE, FULL_NODE, Net, core_config, node_id};
use openlcb_can::CanFrame;
use openlcb_gateway::GatewayConfig;
use openlcb_stream::{Duration, Message, Mti};

fn started() -> Net {
    Net::started(GatewayConfig::default(), core_config(256), core_config(256))
}

/// (proxy alias of the full-format node, alias of the CAN node).
fn aliases(net: &Net) -> (u32, u32) {
    let proxy = net.gateway.proxy_alias(node_id(FULL_NODE)).unwrap().as_raw();
    (u32::from(proxy), u32::from(net.can_link.alias().unwrap().as_raw()))
}

fn frames(list: &[CanFrame]) -> Vec<(u32, Vec<u8>)> {
    list.iter().map(|f| (f.raw_id(), f.payload().to_vec())).collect()
}

/// The expected frames of `payload` as a datagram with header `0x1T dddsss`.
fn datagram_frames(destination: u32, source: u32, payload: &[u8]) -> Vec<(u32, Vec<u8>)> {
    let id = |format: u32| 0x1000_0000 | format << 24 | 0x0800_0000 | destination << 12 | source;
    if payload.len() <= 8 {
        return vec![(id(2), payload.to_vec())];
    }
    let chunks: Vec<&[u8]> = payload.chunks(8).collect();
    let last = chunks.len() - 1;
    chunks
        .iter()
        .enumerate()
        .map(|(i, chunk)| {
            (
                id(if i == 0 {
                    3
                } else if i == last {
                    5
                } else {
                    4
                }),
                chunk.to_vec(),
            )
        })
        .collect()
}

fn datagrams(messages: &[Message]) -> Vec<&Message> {
    messages.iter().filter(|m| m.mti == Mti::DATAGRAM).collect()
}

/// The CAN node sends `payload` to the full-format node; returns its frames and what reached
/// the full-format side.
fn can_to_full(net: &mut Net, payload: &[u8]) -> (Vec<(u32, Vec<u8>)>, Vec<Message>) {
    let (before_can, before_full) = (net.from_can_node.len(), net.to_full.len());
    let datagram = Message::addressed(Mti::DATAGRAM, node_id(CAN_NODE), node_id(FULL_NODE), payload.to_vec());
    net.can_link.send(net.now, datagram).unwrap();
    net.settle();
    let sent = frames(&net.from_can_node[before_can..]);
    (sent, datagrams(&net.to_full[before_full..]).into_iter().cloned().collect())
}

/// The full-format node sends `payload` to the CAN node; returns the gateway's frames and
/// what the CAN node's link delivered.
fn full_to_can(net: &mut Net, payload: &[u8]) -> (Vec<(u32, Vec<u8>)>, Vec<Message>) {
    let (before_can, before_delivered) = (net.from_gateway.len(), net.can_delivered.len());
    let datagram = Message::addressed(Mti::DATAGRAM, node_id(FULL_NODE), node_id(CAN_NODE), payload.to_vec());
    net.gateway.handle_message(net.now, datagram.as_ref());
    net.settle();
    let sent = frames(&net.from_gateway[before_can..]);
    let delivered = datagrams(&net.can_delivered[before_delivered..]).into_iter().cloned().collect();
    (sent, delivered)
}

#[test]
fn single_frame_datagram_can_to_full() {
    let mut net = started();
    let (proxy, can) = aliases(&net);
    let (sent, arrived) = can_to_full(&mut net, &[0x20, 0x80]);
    assert_eq!(sent, datagram_frames(proxy, can, &[0x20, 0x80]));
    assert_eq!(sent[0].0 >> 24, 0x1A);
    assert_eq!(arrived.len(), 1);
    let m = &arrived[0];
    assert_eq!(
        (m.source, m.destination, &m.payload[..]),
        (node_id(CAN_NODE), Some(node_id(FULL_NODE)), &[0x20, 0x80][..])
    );
    assert_eq!(net.gateway.stats().datagrams_forwarded, 1);
}

#[test]
fn datagram_of_72_bytes_can_to_full() {
    let mut net = started();
    let (proxy, can) = aliases(&net);
    let payload: Vec<u8> = (0..72).collect();
    let (sent, arrived) = can_to_full(&mut net, &payload);
    assert_eq!(sent.len(), 9);
    assert_eq!(sent, datagram_frames(proxy, can, &payload));
    assert_eq!(arrived.len(), 1, "one full-format message for nine frames");
    assert_eq!(arrived[0].payload[..], payload[..]);
}

#[test]
fn single_frame_datagram_full_to_can() {
    let mut net = started();
    let (proxy, can) = aliases(&net);
    let (sent, delivered) = full_to_can(&mut net, &[0x20, 0x43, 0, 0, 0, 0, 0x40]);
    assert_eq!(sent, [(0x1A00_0000 | can << 12 | proxy, vec![0x20, 0x43, 0, 0, 0, 0, 0x40])]);
    assert_eq!(delivered.len(), 1);
    let m = &delivered[0];
    assert_eq!((m.source, m.destination), (node_id(FULL_NODE), Some(node_id(CAN_NODE))));
    assert_eq!(m.payload[..], [0x20, 0x43, 0, 0, 0, 0, 0x40]);
}

#[test]
fn datagram_of_72_bytes_full_to_can() {
    let mut net = started();
    let (proxy, can) = aliases(&net);
    let payload: Vec<u8> = (0..72).map(|b| 0xFF - b).collect();
    let (sent, delivered) = full_to_can(&mut net, &payload);
    let first = sent.iter().position(|f| f.0 >> 24 == 0x1B).expect("a first frame");
    assert_eq!(sent[first..first + 9], datagram_frames(can, proxy, &payload)[..], "nine frames, back to back");
    assert_eq!(delivered.len(), 1);
    assert_eq!(delivered[0].payload[..], payload[..]);
}

#[test]
fn framing_errors_are_rejected_from_the_proxy_alias() {
    let mut net = started();
    let (proxy, can) = aliases(&net);
    let before = net.from_gateway.len();
    let frame = |format: u32, data: &[u8]| CanFrame::extended(format << 24 | proxy << 12 | can, data).unwrap();
    // A middle frame without a first is dropped; the last frame of that datagram is
    // answered once: 0x2041.
    net.gateway.handle_can_frame(net.now, &frame(0x1C, &[1, 2]));
    net.gateway.handle_can_frame(net.now, &frame(0x1D, &[1, 2]));
    // First, then silence: 0x2011 after the reassembly timeout.
    net.gateway.handle_can_frame(net.now, &frame(0x1B, &[1; 8]));
    let timeout = net.now + Duration::from_secs(3);
    net.advance_to(timeout);
    net.settle();
    let rejected = 0x19A4_8000 | proxy;
    let [high, low] = (can as u16).to_be_bytes();
    let sent: Vec<_> = frames(&net.from_gateway[before..]).into_iter().filter(|f| f.0 == rejected).collect();
    assert_eq!(sent, [(rejected, vec![high, low, 0x20, 0x41]), (rejected, vec![high, low, 0x20, 0x11])]);
    let errors = net.gateway.stats().datagram_errors;
    assert_eq!((errors.middle_without_first, errors.timeouts), (1, 1));
    assert!(datagrams(&net.to_full).is_empty());
}
