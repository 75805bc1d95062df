//! For random topologies, windows, latencies and seeds, without faults, every transfer
//! completes and delivers exactly what was sent.

use openlcb_loopback::{Network, NodeIndex, NodeOptions, Outcome, TransferSpec};
use openlcb_stream::{Duration, Instant, NodeId};
use proptest::prelude::*;

#[derive(Debug, Clone)]
struct Case {
    tcp: bool,
    nodes: usize,
    window: u16,
    early_proceed: bool,
    latency_us: u64,
    bitrate: u32,
    transfers: Vec<(usize, usize, u64)>,
    seed: u64,
    gridconnect: bool,
}

fn case() -> impl Strategy<Value = Case> {
    (any::<bool>(), 2usize..=6, prop_oneof![1u16..=32, 33u16..=2048, Just(65535u16)], any::<bool>(), 0u64..=5_000)
        .prop_flat_map(|(tcp, nodes, window, early_proceed, latency_us)| {
            let nodes = if tcp { 2 } else { nodes };
            (
                Just((tcp, nodes, window, early_proceed, latency_us)),
                prop_oneof![Just(125_000u32), Just(250_000), Just(1_000_000)],
                prop::collection::vec((0..nodes, 0..nodes, 0u64..3000), 1..5),
                any::<u64>(),
                any::<bool>(),
            )
        })
        .prop_map(|((tcp, nodes, window, early_proceed, latency_us), bitrate, transfers, seed, gridconnect)| Case {
            tcp,
            nodes,
            window,
            early_proceed,
            latency_us,
            bitrate,
            transfers: transfers.into_iter().filter(|(f, t, _)| f != t).collect(),
            seed,
            gridconnect,
        })
}

fn run(c: &Case) -> Result<(), TestCaseError> {
    let mut options = NodeOptions::default();
    options.node.stream.max_window = c.window;
    options.node.stream.early_proceed = c.early_proceed;
    options.latency = Duration::from_micros(c.latency_us);
    options.gridconnect = c.gridconnect;
    let mut net = Network::new(c.seed);
    let id = |i: usize| NodeId::new(0x0501_0101_2200 + i as u64).expect("node id");
    let nodes: Vec<NodeIndex> = if c.tcp {
        net.add_tcp_pair(
            [id(0), id(1)],
            [options.clone(), options.clone()],
            Duration::from_micros(c.latency_us),
            1_000_000,
        )
        .to_vec()
    } else {
        let bus = net.add_bus(c.bitrate, 16);
        (0..c.nodes).map(|i| net.add_can_node(id(i), bus, options.clone())).collect()
    };
    let ts: Vec<usize> = c
        .transfers
        .iter()
        .map(|(f, t, bytes)| net.add_transfer(TransferSpec::new(nodes[*f], nodes[*t], *bytes, c.window)))
        .collect();
    net.run(Instant::from_millis(3_600_000), 20_000_000).map_err(|e| TestCaseError::fail(e.to_string()))?;
    let reports = net.transfers();
    for t in ts {
        let r = reports[t];
        prop_assert_eq!(r.outcome, Outcome::Completed, "{:?}", r);
        prop_assert_eq!(r.delivered, r.spec.bytes);
        prop_assert_eq!(r.verified_prefix, r.spec.bytes);
    }
    Ok(())
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 48, ..ProptestConfig::default() })]

    #[test]
    fn every_transfer_completes_exactly(c in case()) {
        run(&c)?;
    }
}
