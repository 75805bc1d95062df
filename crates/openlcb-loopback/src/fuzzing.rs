//! Entry point of the `loopback_ops` fuzz target. Not a stable API.
#![allow(missing_docs)]

use arbitrary::Arbitrary;
use openlcb_stream::{Duration, Instant, NodeId};

use crate::{FrameFaults, Network, NodeOptions, Outcome, ScheduledFault, TransferSpec};

/// One step on a small network: three CAN nodes and a TCP pair.
#[derive(Debug, Clone, Arbitrary)]
pub enum Op {
    Transfer { from: u8, to: u8, bytes: u8, window: u16 },
    Reset(u8),
    Silence(u8),
    Collide(u8),
    Faults { drop: u8, duplicate: u8, bit_error: u8 },
    Run { centis: u8 },
}

pub fn loopback_ops(seed: u64, window: u16, early_proceed: bool, ops: &[Op]) {
    let mut options = NodeOptions::default();
    options.node.stream.max_window = window.max(1);
    options.node.stream.early_proceed = early_proceed;
    options.node.stream.max_streams = 8;
    options.node.stream.max_streams_per_peer = 8;
    let mut net = Network::new(seed);
    let bus = net.add_bus(1_000_000, 8);
    let id = |i: u64| NodeId::new(0x0501_0101_2200 + i).unwrap_or_default();
    let mut nodes: Vec<usize> = (0..3).map(|i| net.add_can_node(id(i), bus, options.clone())).collect();
    nodes.extend(net.add_tcp_pair(
        [id(3), id(4)],
        [options.clone(), options.clone()],
        Duration::from_millis(1),
        100_000,
    ));
    let pick = |n: u8| nodes[usize::from(n) % nodes.len()];
    let mut lossy = false;
    for op in ops.iter().take(64) {
        match *op {
            Op::Transfer { from, to, bytes, window } => {
                let (from, to) = (pick(from), pick(to));
                // The TCP pair is its own network: keep transfers within one.
                if from != to && (from < 3) == (to < 3) {
                    net.add_transfer(TransferSpec::new(from, to, 64 * u64::from(bytes), window.max(1)).at(net.now()));
                }
            }
            Op::Reset(n) => net.schedule(net.now(), ScheduledFault::Reset(pick(n))),
            Op::Silence(n) => net.schedule(net.now(), ScheduledFault::Silence(pick(n))),
            Op::Collide(n) => net.schedule(net.now(), ScheduledFault::AliasCollision(pick(n))),
            Op::Faults { drop, duplicate, bit_error } => {
                let p = |x: u8| f64::from(x) / 2550.0;
                lossy |= drop > 0 || duplicate > 0;
                net.set_frame_faults(FrameFaults { drop: p(drop), duplicate: p(duplicate), bit_error: p(bit_error) });
            }
            Op::Run { centis } => {
                let until = net.now() + Duration::from_millis(10 * u64::from(centis));
                net.run_until(until, 5_000_000).expect("a run of bounded virtual time settles");
            }
        }
    }
    net.run(Instant::from_micros(net.now().as_micros() + 600_000_000), 20_000_000).expect("never a hang");
    for report in net.transfers() {
        assert!(report.verified_prefix <= report.delivered);
        if !lossy {
            assert_ne!(report.outcome, Outcome::SilentCorruption, "{report:?}");
        }
        // Ten virtual minutes of quiet later every transfer has an outcome: none hangs.
        assert_ne!(report.outcome, Outcome::Pending, "a transfer never ended: {report:?}");
        if report.outcome == Outcome::Completed {
            assert_eq!(report.verified_prefix, report.spec.bytes, "{report:?}");
        }
    }
}
