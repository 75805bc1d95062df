//! `lcc-stream demo`: a hub, a receiving node and a sending node on 127.0.0.1, talking through
//! real sockets; generated data is sent, verified and measured. Nothing to set up.

use std::process::ExitCode;
use std::time::Instant;

use clap::Args;
use openlcb_stream::{NodeId, OpenOptions};
use openlcb_tokio::{Error, Framing, Hub, HubOptions, Node, NodeOptions};

use crate::net::{self, ProtocolArg};
use crate::outcome::{Failure, Outcome, exit_help};
use crate::recv::DEFAULT_RECEIVER;
/// The sending node of the demo (on its own hub, so it meets no other node).
const DEMO_SENDER: &str = "05.01.01.01.22.F0";

/// Options of `lcc-stream demo`.
#[derive(Debug, Args)]
#[command(after_help = exit_help(&[Outcome::Ok, Outcome::Error, Outcome::Usage, Outcome::ConnectionLost, Outcome::Terminated, Outcome::VerifyFailed]))]
pub(crate) struct DemoArgs {
    /// Bytes to move.
    #[arg(long, default_value_t = 4 * 1024 * 1024)]
    bytes: usize,
    /// Window (Max Buffer Size), 1..=65535.
    #[arg(long, default_value_t = 65535, value_parser = clap::value_parser!(u16).range(1..))]
    window: u16,
    /// The receiver grants one window ahead (two windows of buffer), as `recv --early-proceed`.
    #[arg(long)]
    early_proceed: bool,
    /// The framing the two nodes speak to the hub.
    #[arg(long, value_enum, default_value_t = ProtocolArg::Gridconnect)]
    protocol: ProtocolArg,
}

pub(crate) fn run(args: &DemoArgs) -> Result<ExitCode, String> {
    net::runtime()?.block_on(demo(args))
}

/// Deterministic, incompressible-looking test data (xorshift64*).
pub(crate) fn generate(len: usize, seed: u64) -> Vec<u8> {
    let mut x = seed | 1;
    let mut data = Vec::with_capacity(len + 8);
    while data.len() < len {
        x ^= x >> 12;
        x ^= x << 25;
        x ^= x >> 27;
        data.extend_from_slice(&x.wrapping_mul(0x2545_F491_4F6C_DD1D).to_le_bytes());
    }
    data.truncate(len);
    data
}

async fn demo(args: &DemoArgs) -> Result<ExitCode, String> {
    let protocol = Framing::from(args.protocol);
    let tcp = (protocol == Framing::Tcp).then_some("127.0.0.1:0");
    let hub = match Hub::bind("127.0.0.1:0", tcp, HubOptions::default()).await {
        Ok(hub) => hub,
        Err(error) => return Ok(net::fail("demo", &Failure::Net(error))),
    };
    let addr = match protocol {
        Framing::Tcp => hub.tcp_local_addr().unwrap_or(hub.local_addr()),
        _ => hub.local_addr(),
    }
    .to_string();
    outln!("hub listening on {addr} ({protocol:?})");

    let receiver_id: NodeId = DEFAULT_RECEIVER.parse().map_err(|e| format!("{e}"))?;
    let sender_id: NodeId = DEMO_SENDER.parse().map_err(|e| format!("{e}"))?;
    let data = generate(args.bytes, 0x0501_0101_22F0);

    let mut receiver_options = NodeOptions::new(receiver_id);
    receiver_options.node.stream.max_window = args.window;
    receiver_options.node.stream.early_proceed = args.early_proceed;
    let mut receiver = match Node::connect(&addr, protocol, receiver_options).await {
        Ok(node) => node,
        Err(error) => return Ok(net::fail("demo receiver", &Failure::Net(error))),
    };
    outln!("receiver {receiver_id} joined");
    let receiving = tokio::spawn(async move {
        let mut stream = receiver.accept().await?;
        let mut received = Vec::new();
        while let Some(chunk) = stream.read().await? {
            received.extend_from_slice(&chunk);
        }
        let stats = receiver.stats().await?;
        Ok::<_, Error>((received, stats))
    });

    let sender = match Node::connect(&addr, protocol, NodeOptions::new(sender_id)).await {
        Ok(node) => node,
        Err(error) => return Ok(net::fail("demo sender", &Failure::Net(error))),
    };
    outln!("sender {sender_id} joined; sending {} bytes, window {}", args.bytes, args.window);
    let started = Instant::now();
    let sending = async {
        let mut stream = sender.open(OpenOptions::new(receiver_id, args.window)).await?;
        let window = stream.info().window;
        for chunk in data.chunks(256 * 1024) {
            stream.write_all(chunk.to_vec()).await?;
        }
        let sent = stream.finish().await?;
        Ok::<_, Error>((sent, window))
    };
    let (sent, window) = match sending.await {
        Ok(sent) => sent,
        Err(error) => return Ok(net::fail("demo sender", &Failure::Net(error))),
    };
    let (received, receiver_stats) = match receiving.await {
        Ok(Ok(received)) => received,
        Ok(Err(error)) => return Ok(net::fail("demo receiver", &Failure::Net(error))),
        Err(error) => return Err(format!("the receiving task failed: {error}")),
    };
    let elapsed = started.elapsed().as_secs_f64();
    let sender_stats = sender.stats().await.map(|s| s.wire).unwrap_or_default();
    let hub_stats = hub.stats();

    let verified = received == data;
    outln!(
        "moved {} bytes in {elapsed:.3} s: {} (window {window}, early Proceed {})",
        received.len(),
        net::rate_text(net::rate(received.len() as u64, elapsed)),
        if args.early_proceed { "on" } else { "off" }
    );
    outln!(
        "sender: {} frames out in {} writes; receiver: {} frames in, {} out; hub: {} frames relayed",
        sender_stats.frames_out,
        sender_stats.writes,
        receiver_stats.wire.frames_in,
        receiver_stats.wire.frames_out,
        hub_stats.frames
    );
    if verified && sent == data.len() as u64 {
        outln!("verified: every byte arrived, in order");
        Ok(ExitCode::SUCCESS)
    } else {
        eprintln!("lcc-stream demo: data did NOT verify ({} bytes sent, {} received)", sent, received.len());
        Ok(ExitCode::from(Outcome::VerifyFailed.status()))
    }
}
