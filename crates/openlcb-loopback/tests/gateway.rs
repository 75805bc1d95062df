//! CAN node -> gateway -> full-format node and back, through the real gateway.

use openlcb_gateway::GatewayConfig;
use openlcb_loopback::{Network, NodeIndex, NodeOptions, Outcome, TransferSpec};
use openlcb_stream::{Duration, Instant, NodeId};

fn node(n: u64) -> NodeId {
    NodeId::new(0x0501_0101_2200 + n).unwrap()
}

fn options(window: u16) -> NodeOptions {
    let mut o = NodeOptions::default();
    o.node.stream.max_window = window;
    o
}

/// A CAN node and a full-format node behind a gateway whose window cap is `gateway_window`.
fn network(seed: u64, window: u16, gateway_window: u16) -> (Network, usize, NodeIndex, NodeIndex) {
    let mut net = Network::new(seed);
    let bus = net.add_bus(125_000, 16);
    let mut config = GatewayConfig::default();
    config.max_window = gateway_window;
    let gateway = net.add_gateway(node(0x10), bus, config, Duration::from_millis(1));
    let can = net.add_can_node(node(0), bus, options(window));
    let full = net.add_node_behind(gateway, node(1), options(window), Duration::from_millis(1), 1_000_000);
    (net, gateway, can, full)
}

#[test]
fn can_to_full_format_with_a_reduced_window() {
    let (mut net, gateway, can, full) = network(1, 4096, 512);
    let t = net.add_transfer(TransferSpec::new(can, full, 50_000, 4096));
    net.run(Instant::from_millis(600_000), 10_000_000).unwrap();
    let r = net.transfers()[t];
    assert_eq!(r.outcome, Outcome::Completed, "{r:?}");
    let (in_use, bound) = net.gateway_memory(gateway).unwrap();
    assert!(in_use <= bound);
    // 50 000 bytes in windows of at most 512: at least 97 Proceeds crossed the bus.
    assert!(net.stats().frames.proceed >= 50_000 / 512, "{:?}", net.stats().frames);
}

#[test]
fn full_format_to_can_with_a_reduced_window() {
    let (mut net, gateway, can, full) = network(2, 4096, 512);
    let t = net.add_transfer(TransferSpec::new(full, can, 50_000, 4096));
    net.run(Instant::from_millis(600_000), 10_000_000).unwrap();
    assert_eq!(net.transfers()[t].outcome, Outcome::Completed, "{:?}", net.transfers()[t]);
    let (in_use, bound) = net.gateway_memory(gateway).unwrap();
    assert!(in_use <= bound);
}

#[test]
fn both_ways_at_once() {
    let (mut net, _, can, full) = network(3, 2048, 2048);
    let there = net.add_transfer(TransferSpec::new(can, full, 20_000, 2048));
    let back = net.add_transfer(TransferSpec::new(full, can, 20_000, 2048));
    net.run(Instant::from_millis(600_000), 10_000_000).unwrap();
    let reports = net.transfers();
    assert_eq!(reports[there].outcome, Outcome::Completed, "{:?}", reports[there]);
    assert_eq!(reports[back].outcome, Outcome::Completed, "{:?}", reports[back]);
}
