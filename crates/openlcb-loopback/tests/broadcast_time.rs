//! Broadcast Time on the bit-timed CAN bus: a day of a fast clock at 60x with a consumer that
//! keeps within a fast second of the generator all day, through midnight, and a generator
//! that restarts.

use openlcb_loopback::{Network, NodeIndex, NodeOptions, ScheduledFault};
use openlcb_node::NodeEvent;
use openlcb_node::broadcast_time::{ClockChange, ClockConfig, ClockId, ClockTime, GeneratorConfig};
use openlcb_stream::{Instant, NodeId};

const CLOCK: ClockId = ClockId::DEFAULT_FAST;

/// Seconds from the start of January of `t`'s year (the test stays in January).
fn seconds(t: ClockTime) -> i64 {
    ((i64::from(t.day) * 24 + i64::from(t.hour)) * 60 + i64::from(t.minute)) * 60 + i64::from(t.second)
}

fn clocked(clock: ClockConfig) -> NodeOptions {
    let mut options = NodeOptions::default();
    options.node.clocks = vec![clock];
    options
}

/// A generator at 60x from 23:00 on 1 January 2025 and a consumer, on one 125 kbit/s bus.
fn layout() -> (Network, NodeIndex, NodeIndex) {
    let mut generator = GeneratorConfig::default();
    generator.start = ClockTime::new(2025, 1, 1, 23, 0, 0).unwrap();
    generator.rate = "60".parse().unwrap();
    generator.running = true;
    let mut net = Network::new(11);
    let bus = net.add_bus(125_000, 16);
    let g = net.add_can_node(
        NodeId::new(0x0501_0101_2250).unwrap(),
        bus,
        clocked(ClockConfig::generator(CLOCK, generator)),
    );
    let c = net.add_can_node(NodeId::new(0x0501_0101_2251).unwrap(), bus, clocked(ClockConfig::consumer(CLOCK)));
    (net, g, c)
}

fn state(net: &mut Network, node: NodeIndex) -> (ClockTime, bool) {
    let now = net.now();
    let s = net.node(node).unwrap().clock(CLOCK, now).unwrap();
    (s.time, s.synchronized)
}

#[test]
fn a_consumer_follows_a_day_at_sixty_times_within_a_fast_second() {
    let (mut net, g, c) = layout();
    net.run_until(Instant::from_secs(2), 1_000_000).unwrap();
    let mut minutes = 0;
    let mut worst = 0;
    // A fast day is 24 real minutes; sample every real second.
    for second in 2..=(24 * 60 + 2) {
        net.run_until(Instant::from_secs(second), 1_000_000).unwrap();
        let (generated, _) = state(&mut net, g);
        let (followed, synchronized) = state(&mut net, c);
        assert!(synchronized);
        let drift = (seconds(generated) - seconds(followed)).abs();
        worst = worst.max(drift);
        assert!(drift <= 1, "at {second} s: generator {generated}, consumer {followed}");
        minutes += net
            .take_events(c)
            .iter()
            .filter(|e| matches!(e, NodeEvent::Clock(e) if matches!(e.change, ClockChange::Minute(_))))
            .count();
        net.take_events(g);
    }
    let (end, _) = state(&mut net, c);
    assert_eq!((end.day, end.hour), (2, 23), "through midnight into 2 January: {end}");
    // Every fast minute told to the application once (a report may land a hair early).
    assert!((1438..=1441).contains(&minutes), "{minutes} minutes");
    let stats = net.node(g).unwrap().clock_stats();
    // At 60x a real minute is a fast hour: about 25 reports in the day, the midnight one
    // and the sequence's included, never one a real minute.
    assert!((20..=30).contains(&stats.time_reports_sent), "{stats:?}");
    // The generator's start-up sequence came before the consumer's query was due.
    assert_eq!(net.node(c).unwrap().clock_stats().queries_sent, 0);
    eprintln!("worst drift {worst} fast s over a fast day at 60x");
}

#[test]
fn a_consumer_follows_a_generator_that_restarts() {
    let (mut net, g, c) = layout();
    net.run_until(Instant::from_secs(120), 10_000_000).unwrap();
    let (before, _) = state(&mut net, c);
    assert_eq!((before.day, before.hour, before.minute), (2, 0, 59), "{before}");
    // The generator restarts from its configured start (23:00 on the 1st).
    net.schedule(Instant::from_millis(120_500), ScheduledFault::Reset(g));
    net.run_until(Instant::from_secs(125), 10_000_000).unwrap();
    let (generated, _) = state(&mut net, g);
    let (followed, _) = state(&mut net, c);
    assert_eq!((followed.day, followed.hour), (1, 23), "{followed}");
    assert!((seconds(generated) - seconds(followed)).abs() <= 1, "{generated} vs {followed}");
}
