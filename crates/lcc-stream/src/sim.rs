//! `lcc-stream sim`: one or more transfers on the loopback harness, reported against the
//! ceiling of the medium.

use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::process::ExitCode;

use clap::{Args, ValueEnum};
use openlcb_loopback::{FrameCounts, Network, NodeOptions, Outcome, TransferSpec};
use openlcb_stream::{Duration, Instant, NodeId};
use serde::Serialize;

/// Where the transfer runs.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub(crate) enum Topology {
    /// Two nodes on one CAN bus.
    Can,
    /// Two nodes on one OpenLCB-TCP link.
    Tcp,
    /// A CAN node, a gateway, and a full-format node behind it on an OpenLCB-TCP link.
    CanGatewayTcp,
}

/// Options of `lcc-stream sim`.
#[derive(Debug, Args)]
#[command(after_help = "\
--json prints one object: the options (topology, bitrate, window, early_proceed, latency_ms,
streams, nodes, seed), payload_bytes (asked for), delivered_bytes (arrived and verified), elapsed_s
(virtual), goodput_bytes_per_s (delivered_bytes / elapsed), ceiling_bytes_per_s (back-to-back
full frames without stuff bits), efficiency (delivered_bytes at the ceiling / elapsed, at most
1), bus_utilisation (0..1), tcp_bytes, frames (total and per kind: stream_data, proceed,
initiate, complete, error_report, other_message, control), verified, failures (why the
transfers that did not complete ended, and how many each) and real_time_s.

Exit status: 0 the transfer completed and verified; 1 it did not (or the simulation failed);
2 bad arguments, or parameters that cannot be simulated.")]
pub(crate) struct SimArgs {
    /// CAN bitrate, bits per second: 10000 to 1000000, the rates classical CAN runs at
    /// (LCC uses 125000). Slower or faster cannot be simulated faithfully and is refused.
    #[arg(long, default_value_t = 125_000, value_parser = clap::value_parser!(u32).range(10_000..=1_000_000))]
    bitrate: u32,
    /// Payload bytes per stream.
    #[arg(long, default_value_t = 262_144)]
    bytes: u64,
    /// Window (Max Buffer Size) proposed and granted, 1..=65535.
    #[arg(long, default_value_t = 2048, value_parser = clap::value_parser!(u16).range(1..))]
    window: u16,
    /// The destination sends one Proceed ahead.
    #[arg(long)]
    early_proceed: bool,
    /// Per-node processing latency, milliseconds (fractions allowed).
    #[arg(long, default_value_t = 1.0, value_parser = parse_latency)]
    latency: f64,
    /// Concurrent transfers from each sending node to its destination.
    #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u16).range(1..=255))]
    streams: u16,
    /// Nodes on the bus (can topology). With 2, the first sends to the second; with more,
    /// every node sends `--streams` transfers to the next one round a ring, so each node
    /// both sends and receives.
    #[arg(long, default_value_t = 2, value_parser = clap::value_parser!(u16).range(2..=1000))]
    nodes: u16,
    /// Network layout.
    #[arg(long, value_enum, default_value_t = Topology::Can)]
    topology: Topology,
    /// OpenLCB-TCP link bandwidth, bytes per second (tcp topology).
    #[arg(long, default_value_t = 12_500_000, value_parser = crate::args::positive::<u64>)]
    bandwidth: u64,
    /// Seed of the simulation.
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Print one JSON object instead of text.
    #[arg(long)]
    json: bool,
}

/// `--latency`: milliseconds, 0 to 10000.
fn parse_latency(text: &str) -> Result<f64, String> {
    match text.parse::<f64>() {
        Ok(ms) if (0.0..=10_000.0).contains(&ms) => Ok(ms),
        _ => Err("expected milliseconds from 0 to 10000".to_string()),
    }
}

/// What a run measured.
#[derive(Debug)]
struct Report {
    payload_bytes: u64,
    /// Leading bytes that arrived and matched what was sent, over all transfers.
    delivered_bytes: u64,
    /// Outcomes of the transfers that did not complete, with how many ended each way.
    failures: BTreeMap<String, u64>,
    elapsed: Duration,
    ceiling: Duration,
    frames: FrameCounts,
    bus_busy: Duration,
    tcp_bytes: u64,
    verified: bool,
    real_time_s: f64,
}

/// Node IDs of the simulated pair (the nodes of a ring count on from `SOURCE`) and of the
/// gateway (only in a pair).
const SOURCE: NodeId = NodeId::from_bytes([0x05, 0x01, 0x01, 0x01, 0x22, 0x00]);
const DESTINATION: NodeId = NodeId::from_bytes([0x05, 0x01, 0x01, 0x01, 0x22, 0x01]);
const GATEWAY: NodeId = NodeId::from_bytes([0x05, 0x01, 0x01, 0x01, 0x22, 0x10]);

/// Transfers start once both nodes have logged in (the alias reservation takes 200 ms).
const START: Instant = Instant::from_millis(300);

pub(crate) fn run(args: &SimArgs) -> Result<ExitCode, String> {
    if args.nodes > 2 && args.topology != Topology::Can {
        return Err("--nodes above 2 needs --topology can (one bus)".to_string());
    }
    let report = simulate(args)?;
    if args.json {
        crate::net::print_json(&json(args, &report));
    } else {
        out!("{}", text(args, &report));
    }
    Ok(if report.verified { ExitCode::SUCCESS } else { ExitCode::FAILURE })
}

fn node_options(args: &SimArgs) -> NodeOptions {
    let mut options = NodeOptions::default();
    options.node.stream.max_window = args.window;
    options.node.stream.early_proceed = args.early_proceed;
    // A node of a ring receives as many streams as it sends.
    let roles = if args.nodes > 2 { 2 } else { 1 };
    options.node.stream.max_streams = usize::from(args.streams) * roles;
    options.node.stream.max_streams_per_peer = usize::from(args.streams);
    options.can.transmit_queue_limit = options.can.transmit_queue_limit.max(usize::from(args.streams) * 4);
    options.latency = Duration::from_micros((args.latency * 1000.0).round() as u64);
    options
}

fn simulate(args: &SimArgs) -> Result<Report, String> {
    let wall = std::time::Instant::now();
    let mut net = Network::new(args.seed);
    let options = node_options(args);
    let pairs = match args.topology {
        Topology::Can => {
            let bus = net.add_bus(args.bitrate, 16);
            let nodes: Vec<_> = (0..u64::from(args.nodes))
                .map(|i| {
                    let id = NodeId::new(SOURCE.as_raw() + i).expect("a Node ID below 2^48");
                    net.add_can_node(id, bus, options.clone())
                })
                .collect();
            let senders = if args.nodes > 2 { nodes.len() } else { 1 };
            (0..senders).map(|i| (nodes[i], nodes[(i + 1) % nodes.len()])).collect()
        }
        Topology::Tcp => {
            let link_latency = options.latency;
            let [a, b] =
                net.add_tcp_pair([SOURCE, DESTINATION], [options.clone(), options], link_latency, args.bandwidth);
            vec![(a, b)]
        }
        Topology::CanGatewayTcp => {
            let bus = net.add_bus(args.bitrate, 16);
            let mut config = openlcb_gateway::GatewayConfig::default();
            config.max_window = args.window;
            config.max_streams = usize::from(args.streams).max(config.max_streams);
            let gateway = net.add_gateway(GATEWAY, bus, config, options.latency);
            let a = net.add_can_node(SOURCE, bus, options.clone());
            let link_latency = options.latency;
            vec![(a, net.add_node_behind(gateway, DESTINATION, options, link_latency, args.bandwidth))]
        }
    };
    let transfers: Vec<usize> = pairs
        .iter()
        .flat_map(|&(from, to)| std::iter::repeat_n((from, to), usize::from(args.streams)))
        .map(|(from, to)| net.add_transfer(TransferSpec::new(from, to, args.bytes, args.window).at(START)))
        .collect();
    net.run_until(START, 10_000_000).map_err(|e| e.to_string())?;
    let before = net.stats();
    let payload_bytes = args.bytes * transfers.len() as u64;
    // A generous bound: every payload byte may cost a driver step or two.
    let max_steps = 1_000_000 + 8 * payload_bytes;
    net.run(Instant::from_micros(u64::MAX / 2), max_steps).map_err(|e| e.to_string())?;
    let after = net.stats();
    let reports = net.transfers();
    let mine: Vec<_> = transfers.iter().filter_map(|t| reports.get(*t)).collect();
    let verified = mine.len() == transfers.len() && mine.iter().all(|r| r.outcome == Outcome::Completed);
    let delivered_bytes = mine.iter().map(|r| r.verified_prefix).sum();
    let mut failures = BTreeMap::new();
    for r in mine.iter().filter(|r| r.outcome != Outcome::Completed) {
        *failures.entry(format!("{:?}", r.outcome)).or_insert(0) += 1;
    }
    let opened = reports.iter().filter_map(|r| r.opened_at).min().unwrap_or(START);
    // A run that failed goes on delivering what was queued after its streams ended: it ends
    // when the network fell quiet.
    let ended = match reports.iter().filter_map(|r| r.ended_at).max() {
        Some(ended) if verified => ended,
        _ => net.now(),
    };
    let ceiling = match args.topology {
        Topology::Can | Topology::CanGatewayTcp => can_ceiling(delivered_bytes, args),
        Topology::Tcp => Duration::from_micros(delivered_bytes * 1_000_000 / args.bandwidth),
    };
    Ok(Report {
        payload_bytes,
        delivered_bytes,
        failures,
        elapsed: ended.saturating_duration_since(opened),
        ceiling,
        frames: after.frames.since(&before.frames),
        bus_busy: Duration::from_micros(after.bus_busy.as_micros() - before.bus_busy.as_micros()),
        tcp_bytes: after.tcp_bytes - before.tcp_bytes,
        verified,
        real_time_s: wall.elapsed().as_secs_f64(),
    })
}

/// The least time `bytes` of payload can take on the bus: back-to-back data frames of seven
/// bytes (DID + 7), each without a single stuff bit (67 + 8 x 8 bits), no requests, no
/// Proceeds, no gaps. Every real run takes at least this long, so efficiency is at most 1.
fn can_ceiling(bytes: u64, args: &SimArgs) -> Duration {
    const FRAME_BITS: u64 = 67; // an extended frame without data or stuff bits
    let frames = bytes.div_ceil(7);
    let bits = frames * (FRAME_BITS + 8) + 8 * bytes;
    Duration::from_micros(bits * 1_000_000 / u64::from(args.bitrate))
}

fn rate(bytes: u64, time: Duration) -> f64 {
    if time.as_micros() == 0 { 0.0 } else { bytes as f64 / time.as_secs_f64() }
}

fn efficiency(r: &Report) -> f64 {
    if r.elapsed.as_micros() == 0 { 0.0 } else { r.ceiling.as_secs_f64() / r.elapsed.as_secs_f64() }
}

fn utilisation(r: &Report) -> f64 {
    if r.elapsed.as_micros() == 0 { 0.0 } else { (r.bus_busy.as_secs_f64() / r.elapsed.as_secs_f64()).min(1.0) }
}

fn topology_name(t: Topology) -> &'static str {
    match t {
        Topology::Can => "can",
        Topology::Tcp => "tcp",
        Topology::CanGatewayTcp => "can-gateway-tcp",
    }
}

/// `sim --json`: one object (see the help for its fields).
#[derive(Debug, Serialize)]
struct SimReport {
    topology: &'static str,
    bitrate: u32,
    window: u16,
    early_proceed: bool,
    latency_ms: f64,
    streams: u16,
    nodes: u16,
    seed: u64,
    payload_bytes: u64,
    delivered_bytes: u64,
    elapsed_s: f64,
    goodput_bytes_per_s: f64,
    ceiling_bytes_per_s: f64,
    efficiency: f64,
    bus_utilisation: f64,
    tcp_bytes: u64,
    frames: BTreeMap<&'static str, u64>,
    verified: bool,
    failures: BTreeMap<String, u64>,
    real_time_s: f64,
}

fn json(args: &SimArgs, r: &Report) -> SimReport {
    let mut frames: BTreeMap<_, _> = r.frames.by_kind().into_iter().collect();
    frames.insert("total", r.frames.total());
    SimReport {
        topology: topology_name(args.topology),
        bitrate: args.bitrate,
        window: args.window,
        early_proceed: args.early_proceed,
        latency_ms: args.latency,
        streams: args.streams,
        nodes: args.nodes,
        seed: args.seed,
        payload_bytes: r.payload_bytes,
        delivered_bytes: r.delivered_bytes,
        elapsed_s: r.elapsed.as_secs_f64(),
        goodput_bytes_per_s: rate(r.delivered_bytes, r.elapsed),
        ceiling_bytes_per_s: rate(r.delivered_bytes, r.ceiling),
        efficiency: efficiency(r),
        bus_utilisation: utilisation(r),
        tcp_bytes: r.tcp_bytes,
        frames,
        verified: r.verified,
        failures: r.failures.clone(),
        real_time_s: r.real_time_s,
    }
}

fn text(args: &SimArgs, r: &Report) -> String {
    let mut out = String::new();
    let medium = match args.topology {
        Topology::Can => format!("CAN at {} bit/s", args.bitrate),
        Topology::Tcp => format!("OpenLCB-TCP at {} B/s", args.bandwidth),
        Topology::CanGatewayTcp => {
            format!("CAN at {} bit/s, a gateway, OpenLCB-TCP at {} B/s", args.bitrate, args.bandwidth)
        }
    };
    let senders =
        if args.nodes > 2 { format!(" from each of {} nodes to the next", args.nodes) } else { String::new() };
    let _ = writeln!(
        out,
        "{} stream(s){senders} of {} bytes over {medium}, window {}, early Proceed {}, latency {} ms, seed {}",
        args.streams,
        args.bytes,
        args.window,
        if args.early_proceed { "on" } else { "off" },
        args.latency,
        args.seed
    );
    let verdict = if r.verified {
        "verified".to_string()
    } else {
        let why: Vec<String> = r.failures.iter().map(|(outcome, n)| format!("{n} {outcome}")).collect();
        format!("NOT VERIFIED: {} delivered and verified; {}", r.delivered_bytes, why.join(", "))
    };
    let _ = writeln!(out, "  payload        {} bytes, {verdict}", r.payload_bytes);
    let _ = writeln!(out, "  elapsed        {:.3} s virtual ({:.3} s real)", r.elapsed.as_secs_f64(), r.real_time_s);
    let _ = writeln!(out, "  goodput        {:.0} bytes/s", rate(r.delivered_bytes, r.elapsed));
    let _ = writeln!(out, "  ceiling        {:.0} bytes/s", rate(r.delivered_bytes, r.ceiling));
    let _ = writeln!(out, "  efficiency     {:.4}", efficiency(r));
    if args.topology != Topology::Tcp {
        let _ = writeln!(out, "  bus busy       {:.1} %", 100.0 * utilisation(r));
        let kinds: Vec<String> = r.frames.by_kind().iter().map(|(kind, n)| format!("{n} {kind}")).collect();
        let _ = writeln!(out, "  frames         {} total: {}", r.frames.total(), kinds.join(", "));
    } else {
        let _ = writeln!(out, "  tcp bytes      {}", r.tcp_bytes);
    }
    out
}
