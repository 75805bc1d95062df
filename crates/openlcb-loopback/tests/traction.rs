//! Trains on the bit-timed CAN bus, every message through the real codecs: a throttle that
//! assigns itself and drives a two-train consist (the second a reversed listener of the
//! first), keeps it running through its heartbeats, and one that goes silent, whose train
//! stops at the heartbeat deadline.

use openlcb_loopback::{Network, NodeIndex, NodeOptions};
use openlcb_node::NodeEvent;
use openlcb_node::traction::{LISTENER_REVERSE, Speed, ThrottleConfig, ThrottleEvent, TractionCommand, TrainConfig};
use openlcb_stream::{Instant, NodeId};

const LEAD: NodeId = NodeId::from_bytes([5, 1, 1, 1, 0x22, 0x50]);
const TRAILER: NodeId = NodeId::from_bytes([5, 1, 1, 1, 0x22, 0x51]);
const CAB: NodeId = NodeId::from_bytes([5, 1, 1, 1, 0x22, 0x52]);

fn layout(answer_heartbeats: bool) -> (Network, [NodeIndex; 3]) {
    let mut net = Network::new(7);
    let bus = net.add_bus(125_000, 16);
    let train = |address| {
        let mut options = NodeOptions::default();
        options.node.train = Some(TrainConfig::dcc(address));
        options
    };
    let lead = net.add_can_node(LEAD, bus, train(3));
    let trailer = net.add_can_node(TRAILER, bus, train(4));
    let mut throttle = ThrottleConfig::default();
    throttle.answer_heartbeats = answer_heartbeats;
    let mut options = NodeOptions::default();
    options.node.throttle = Some(throttle);
    let cab = net.add_can_node(CAB, bus, options);
    net.run_until(Instant::from_secs(1), 1_000_000).unwrap();
    (net, [lead, trailer, cab])
}

fn command(net: &mut Network, cab: NodeIndex, to: NodeId, command: TractionCommand, until_ms: u64) {
    net.node(cab).unwrap().throttle_command(to, command).unwrap();
    net.run_until(Instant::from_millis(until_ms), 1_000_000).unwrap();
}

fn speed(net: &mut Network, node: NodeIndex) -> Speed {
    net.node(node).unwrap().train().unwrap().set_speed
}

#[test]
fn a_throttle_drives_a_consist_and_keeps_it_running_with_heartbeats() {
    let (mut net, [lead, trailer, cab]) = layout(true);
    command(&mut net, cab, LEAD, TractionCommand::AssignController { flags: 0, node: CAB }, 1_100);
    command(&mut net, cab, LEAD, TractionCommand::AttachListener { flags: LISTENER_REVERSE, node: TRAILER }, 1_200);
    let events = net.take_events(cab);
    assert!(events.contains(&NodeEvent::Throttle(ThrottleEvent::Assigned { train: LEAD })), "{events:?}");
    assert!(events.iter().any(|e| matches!(e, NodeEvent::Throttle(ThrottleEvent::ListenerChanged { code: 0, .. }))));
    let ahead = Speed::from_f32(2.5);
    command(&mut net, cab, LEAD, TractionCommand::SetSpeed { speed: ahead, forwarded: false }, 1_300);
    assert_eq!(speed(&mut net, lead), ahead);
    assert_eq!(speed(&mut net, trailer), ahead.reversed(), "the trailer runs the other way round");
    // A minute later both still run: the throttle answered every heartbeat request.
    net.run_until(Instant::from_secs(61), 10_000_000).unwrap();
    assert_eq!(speed(&mut net, lead), ahead);
    assert_eq!(speed(&mut net, trailer), ahead.reversed());
    let lead_stats = net.node(lead).unwrap().train_stats();
    assert!(lead_stats.heartbeats_sent >= 30 && lead_stats.heartbeat_timeouts == 0, "{lead_stats:?}");
}

#[test]
fn a_silent_throttle_has_its_consist_stopped_at_the_deadline() {
    let (mut net, [lead, trailer, cab]) = layout(false);
    command(&mut net, cab, LEAD, TractionCommand::AssignController { flags: 0, node: CAB }, 1_100);
    command(&mut net, cab, LEAD, TractionCommand::AttachListener { flags: 0, node: TRAILER }, 1_200);
    command(&mut net, cab, LEAD, TractionCommand::SetSpeed { speed: Speed::from_f32(-1.0), forwarded: false }, 1_300);
    assert_eq!(speed(&mut net, trailer), Speed::from_f32(-1.0));
    // Request 1.5 s after the last command, deadline 3 s after that.
    net.run_until(Instant::from_millis(5_700), 1_000_000).unwrap();
    assert_eq!(speed(&mut net, lead), Speed::from_f32(-1.0));
    net.run_until(Instant::from_millis(6_000), 1_000_000).unwrap();
    assert_eq!(speed(&mut net, lead), Speed::ZERO_REVERSE);
    assert_eq!(speed(&mut net, trailer), Speed::ZERO_REVERSE, "the stop is forwarded to the consist");
}
