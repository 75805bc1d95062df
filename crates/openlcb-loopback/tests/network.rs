//! Whole networks on the harness: the worked example, many streams, many nodes, faults.

use openlcb_can::{NodeAlias, gridconnect};
use openlcb_loopback::{FrameFaults, Network, NodeIndex, NodeOptions, Outcome, ScheduledFault, TransferSpec};
use openlcb_stream::{Config, Duration, Instant, NodeId, StreamId, Termination, TimeoutKind};

const MINUTE: Instant = Instant::from_millis(60_000);

fn node(n: u64) -> NodeId {
    NodeId::new(0x0501_0101_2200 + n).unwrap()
}

fn options(window: u16, early_proceed: bool) -> NodeOptions {
    let mut o = NodeOptions::default();
    o.node.stream.max_window = window;
    o.node.stream.early_proceed = early_proceed;
    o
}

fn can_pair(seed: u64, a: NodeOptions, b: NodeOptions) -> (Network, NodeIndex, NodeIndex) {
    let mut net = Network::new(seed);
    let bus = net.add_bus(125_000, 16);
    let a = net.add_can_node(node(0), bus, a);
    let b = net.add_can_node(node(1), bus, b);
    (net, a, b)
}

fn text(frame: &openlcb_can::CanFrame) -> String {
    let mut buf = [0u8; 32];
    let n = gridconnect::encode(frame, &mut buf).unwrap();
    String::from_utf8(buf[..n].to_vec()).unwrap()
}

#[test]
fn worked_example_of_wire_spec_9_2() {
    let mut a = options(16, false);
    a.can.first_alias = NodeAlias::new(0x123);
    let mut b = options(16, false);
    b.can.first_alias = NodeAlias::new(0x456);
    let (mut net, a, b) = can_pair(1, a, b);
    net.record_frames();
    let data: Vec<u8> = (0..20).collect();
    let t = net.add_transfer_of(TransferSpec::new(a, b, 0, 16), &data, StreamId::new(4));
    net.run(MINUTE, 100_000).unwrap();
    assert_eq!(net.transfers()[t].outcome, Outcome::Completed);
    let frames: Vec<String> = net.recorded_frames().iter().map(|(_, f)| text(f)).collect();
    let first_stream_frame = frames.iter().position(|f| f.starts_with(":X19CC8")).unwrap();
    // B chooses the DID; a fresh node's first is 00 (the spec's example has B choose 07).
    let stream: Vec<&str> = frames[first_stream_frame..].iter().map(String::as_str).collect();
    assert_eq!(
        stream,
        [
            ":X19CC8123N04560010000004;",
            ":X19868456N0123001080000400;",
            ":X1F456123N0000010203040506;",
            ":X1F456123N000708090A0B0C0D;",
            ":X1F456123N000E0F;",
            ":X19888456N012304000000;",
            ":X1F456123N0010111213;",
            ":X198A8123N0456040000000014;",
        ]
    );
    // Login of both nodes came first: CID 7..4 with the brief's aliases, then RID, AMD.
    assert!(frames[..first_stream_frame].contains(&":X17050123N;".to_string()));
    assert!(frames[..first_stream_frame].contains(&":X10701456N050101012201;".to_string()));
}

#[test]
fn worked_example_through_gridconnect_text() {
    let mut a = options(16, false);
    a.gridconnect = true;
    let mut b = options(16, false);
    b.gridconnect = true;
    let (mut net, a, b) = can_pair(2, a, b);
    let t = net.add_transfer(TransferSpec::new(a, b, 5000, 16));
    net.run(MINUTE, 1_000_000).unwrap();
    assert_eq!(net.transfers()[t].outcome, Outcome::Completed);
}

#[test]
fn two_hundred_fifty_five_concurrent_streams_between_one_pair() {
    let mut o = options(64, true);
    o.node.stream.max_streams = 255;
    o.node.stream.max_streams_per_peer = 255;
    let (mut net, a, b) = can_pair(3, o.clone(), o);
    let transfers: Vec<usize> = (0..255).map(|_| net.add_transfer(TransferSpec::new(a, b, 100, 64))).collect();
    net.run(Instant::from_millis(600_000), 10_000_000).unwrap();
    let reports = net.transfers();
    for t in transfers {
        assert_eq!(reports[t].outcome, Outcome::Completed, "transfer {t}: {:?}", reports[t]);
    }
}

#[test]
fn fifty_nodes_each_sending_to_another_on_one_bus() {
    let mut net = Network::new(4);
    let bus = net.add_bus(125_000, 16);
    let nodes: Vec<NodeIndex> = (0..50).map(|i| net.add_can_node(node(i), bus, options(256, true))).collect();
    for (i, from) in nodes.iter().enumerate() {
        net.add_transfer(TransferSpec::new(*from, nodes[(i + 1) % 50], 1024, 256));
    }
    net.run(Instant::from_millis(600_000), 10_000_000).unwrap();
    for report in net.transfers() {
        assert_eq!(report.outcome, Outcome::Completed, "{report:?}");
    }
    assert!(net.stats().frames.stream_data >= 50 * 1024 / 7);
}

/// Every transfer of `net` completed and delivered what was sent; the latest end.
fn all_completed(net: &Network) -> Instant {
    let reports = net.transfers();
    for report in &reports {
        assert_eq!(report.outcome, Outcome::Completed, "{report:?}");
        assert_eq!(report.verified_prefix, report.delivered, "{report:?}");
    }
    reports.iter().filter_map(|r| r.ended_at).max().unwrap()
}

#[test]
fn two_hundred_fifty_five_streams_at_the_default_window_wait_their_turn() {
    // 255 windows of 2048 bytes take 77 s to cross a 125 kbit/s bus: each stream waits far
    // longer than the Proceed (30 s) and first-data (15 s) waits for its next turn.
    let mut o = NodeOptions::default();
    o.node.stream.max_streams = 255;
    o.node.stream.max_streams_per_peer = 255;
    let (mut net, a, b) = can_pair(11, o.clone(), o);
    for _ in 0..255 {
        net.add_transfer(TransferSpec::new(a, b, 4096, 2048));
    }
    net.run(Instant::from_millis(3_600_000), 20_000_000).unwrap();
    let ended = all_completed(&net);
    // The sender shared the bus window by window: the first stream to finish still waited
    // for a turn after every other stream's first window (one stream after another would
    // finish the first at 1/255 of the run).
    let first = net.transfers().iter().filter_map(|r| r.ended_at).min().unwrap();
    assert!(first.as_millis() * 10 > ended.as_millis() * 4, "first done at {first:?}, last at {ended:?}");
}

#[test]
fn fifty_nodes_each_with_four_streams_to_the_next_on_one_bus() {
    // CAN arbitration serves the pair with the lowest destination alias first: the others
    // wait, longer than every default wait, until the streams ahead of them are done.
    let mut net = Network::new(12);
    let bus = net.add_bus(125_000, 16);
    let nodes: Vec<NodeIndex> = (0..50).map(|i| net.add_can_node(node(i), bus, NodeOptions::default())).collect();
    for (i, from) in nodes.iter().enumerate() {
        for _ in 0..4 {
            net.add_transfer(TransferSpec::new(*from, nodes[(i + 1) % 50], 2048, 2048));
        }
    }
    net.run(Instant::from_millis(3_600_000), 20_000_000).unwrap();
    let ended = all_completed(&net);
    assert!(ended > Instant::from_millis(60_000), "the bus was busy longer than the idle wait: {ended:?}");
}

#[test]
fn transfer_over_an_openlcb_tcp_pipe() {
    let mut net = Network::new(5);
    let [a, b] = net.add_tcp_pair(
        [node(0), node(1)],
        [options(2048, true), options(2048, true)],
        Duration::from_millis(1),
        1_000_000,
    );
    let t = net.add_transfer(TransferSpec::new(a, b, 1 << 20, 2048));
    net.run(MINUTE, 1_000_000).unwrap();
    let report = net.transfers()[t];
    assert_eq!(report.outcome, Outcome::Completed);
    assert!(net.stats().tcp_bytes > 1 << 20);
}

// ----- faults, injected mid-stream -----

/// The outcome is a completed transfer, or a failure that was reported while the delivered
/// bytes are a prefix of what was sent; never a hang, never silent corruption.
fn assert_safe(net: &mut Network, t: usize) -> Outcome {
    net.run(Instant::from_millis(600_000), 10_000_000).expect("never a hang");
    let r = net.transfers()[t];
    assert_ne!(r.outcome, Outcome::Pending, "{r:?}");
    assert_ne!(r.outcome, Outcome::SilentCorruption, "{r:?}");
    if r.outcome == Outcome::Completed {
        assert_eq!(r.verified_prefix, r.spec.bytes);
    }
    r.outcome
}

#[test]
fn destination_reset_mid_stream() {
    let (mut net, a, b) = can_pair(6, options(256, true), options(256, true));
    let t = net.add_transfer(TransferSpec::new(a, b, 20_000, 256));
    net.schedule(Instant::from_millis(1_500), ScheduledFault::Reset(b));
    let outcome = assert_safe(&mut net, t);
    assert!(matches!(outcome, Outcome::Terminated(_)), "{outcome:?}");
    let r = net.transfers()[t];
    assert!(r.delivered > 0 && r.delivered < 20_000);
    assert_eq!(r.verified_prefix, r.delivered, "what arrived is a prefix of what was sent");
    let later = net.now() + Duration::from_secs(1);
    net.run_until(later, 1_000_000).unwrap();
    assert_ne!(net.alias(b), None, "the reset node logged in again");
}

#[test]
fn source_reset_mid_stream() {
    let (mut net, a, b) = can_pair(7, options(256, true), options(256, true));
    let t = net.add_transfer(TransferSpec::new(a, b, 20_000, 256));
    net.schedule(Instant::from_millis(1_500), ScheduledFault::Reset(a));
    assert!(matches!(assert_safe(&mut net, t), Outcome::Terminated(_)));
    // The destination learns of it from the source's new Initialization Complete.
    let later = net.now() + Duration::from_secs(1);
    net.run_until(later, 1_000_000).unwrap();
    let b_stats = net.endpoint(b).unwrap().stream_count();
    assert_eq!(b_stats, 0, "the destination released the dead stream");
}

#[test]
fn alias_collision_mid_stream() {
    let (mut net, a, b) = can_pair(8, options(256, true), options(256, true));
    let t = net.add_transfer(TransferSpec::new(a, b, 20_000, 256));
    net.run_until(Instant::from_millis(1_000), 1_000_000).unwrap();
    let old = net.alias(a);
    assert!(old.is_some());
    net.schedule(Instant::from_millis(1_500), ScheduledFault::AliasCollision(a));
    let outcome = assert_safe(&mut net, t);
    assert_eq!(outcome, Outcome::Terminated(Termination::LinkLost));
    let later = net.now() + Duration::from_secs(1);
    net.run_until(later, 1_000_000).unwrap();
    assert_ne!(net.alias(a), old, "a new alias after the collision");
    assert!(net.alias(a).is_some());
}

#[test]
fn destination_goes_silent_mid_stream() {
    let (mut net, a, b) = can_pair(9, options(256, true), options(256, true));
    let t = net.add_transfer(TransferSpec::new(a, b, 20_000, 256));
    net.schedule(Instant::from_millis(1_500), ScheduledFault::Silence(b));
    assert_eq!(assert_safe(&mut net, t), Outcome::TimedOut(TimeoutKind::Proceed));
}

#[test]
fn source_goes_silent_mid_stream() {
    let (mut net, a, b) = can_pair(10, options(256, true), options(256, true));
    let t = net.add_transfer(TransferSpec::new(a, b, 20_000, 256));
    net.schedule(Instant::from_millis(1_500), ScheduledFault::Silence(a));
    assert_eq!(assert_safe(&mut net, t), Outcome::TimedOut(TimeoutKind::Idle));
}

#[test]
fn transfers_a_silent_node_was_still_to_open_end_as_link_lost() {
    let (mut net, a, b) = can_pair(11, options(256, true), options(256, true));
    // Due after the silence, and added after it: neither can ever start.
    let due_later = net.add_transfer(TransferSpec::new(a, b, 1_000, 256).at(Instant::from_millis(2_000)));
    net.schedule(Instant::ZERO, ScheduledFault::Silence(a));
    net.run_until(Instant::from_millis(10), 10_000).unwrap();
    let added_after = net.add_transfer(TransferSpec::new(a, b, 1_000, 256));
    for t in [due_later, added_after] {
        assert_eq!(assert_safe(&mut net, t), Outcome::Terminated(Termination::LinkLost));
        assert_eq!(net.transfers()[t].sent, 0);
    }
    // The other way round is up to the protocol: no node answers for that Node ID.
    let to_silent = net.add_transfer(TransferSpec::new(b, a, 1_000, 256).at(net.now()));
    assert_eq!(assert_safe(&mut net, to_silent), Outcome::Terminated(Termination::PeerLost));
}

#[test]
fn dropped_frames_are_reported_never_silent() {
    for seed in 0..8 {
        let (mut net, a, b) = can_pair(100 + seed, options(256, true), options(256, true));
        net.set_frame_faults(FrameFaults { drop: 0.002, ..FrameFaults::default() });
        let t = net.add_transfer(TransferSpec::new(a, b, 20_000, 256));
        let outcome = assert_safe(&mut net, t);
        if net.stats().dropped_frames == 0 {
            assert_eq!(outcome, Outcome::Completed);
        }
    }
}

#[test]
fn duplicated_frames_are_reported_never_silent() {
    for seed in 0..8 {
        let (mut net, a, b) = can_pair(200 + seed, options(256, true), options(256, true));
        net.set_frame_faults(FrameFaults { duplicate: 0.002, ..FrameFaults::default() });
        let t = net.add_transfer(TransferSpec::new(a, b, 20_000, 256));
        let outcome = assert_safe(&mut net, t);
        if net.stats().duplicated_frames == 0 {
            assert_eq!(outcome, Outcome::Completed);
        }
    }
}

#[test]
fn bit_errors_cost_time_not_data() {
    let (mut net, a, b) = can_pair(11, options(256, true), options(256, true));
    net.set_frame_faults(FrameFaults { bit_error: 0.01, ..FrameFaults::default() });
    let t = net.add_transfer(TransferSpec::new(a, b, 20_000, 256));
    assert_eq!(assert_safe(&mut net, t), Outcome::Completed, "the controller retransmits");
    assert!(net.stats().corrupted_frames > 0);
}

#[test]
fn a_rejected_stream_ends_the_transfer() {
    let mut o = options(256, true);
    o.node.stream = {
        let mut c = Config::default();
        c.accept_policy =
            openlcb_stream::AcceptPolicy::RejectAll(openlcb_stream::wire::ReplyCode::SOURCE_NOT_PERMITTED);
        c
    };
    let (mut net, a, b) = can_pair(12, options(256, true), o);
    let t = net.add_transfer(TransferSpec::new(a, b, 100, 256));
    assert_eq!(assert_safe(&mut net, t), Outcome::Rejected);
}

#[test]
fn runs_are_deterministic() {
    let run = || {
        let (mut net, a, b) = can_pair(13, options(256, true), options(256, true));
        net.set_frame_faults(FrameFaults { bit_error: 0.01, ..FrameFaults::default() });
        let t = net.add_transfer(TransferSpec::new(a, b, 5000, 256));
        net.run(MINUTE, 1_000_000).unwrap();
        (net.transfers()[t], net.stats())
    };
    assert_eq!(run(), run());
}

#[test]
fn never_idle_is_reported_not_hung() {
    let (mut net, a, b) = can_pair(14, options(256, true), options(256, true));
    net.add_transfer(TransferSpec::new(a, b, 1 << 20, 256));
    let err = net.run(Instant::from_millis(6_000_000), 50).unwrap_err();
    assert_eq!(err.steps, 51);
}
