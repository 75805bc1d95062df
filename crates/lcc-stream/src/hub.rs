//! `lcc-stream hub`: a GridConnect TCP hub, and an OpenLCB-TCP one beside it, bridged by a
//! gateway.

use std::process::ExitCode;

use clap::Args;
use openlcb_stream::NodeId;
use openlcb_tokio::{Error, Hub, HubEvent, HubOptions};

use crate::net::{self, GRIDCONNECT_ADDR, TCP_ADDR};

/// Options of `lcc-stream hub`.
#[derive(Debug, Args)]
#[command(after_help = net::EXIT_HELP)]
pub(crate) struct HubArgs {
    /// Where GridConnect clients connect.
    #[arg(long, value_name = "ADDR", default_value = GRIDCONNECT_ADDR)]
    listen: String,
    /// Where OpenLCB-TCP clients connect (opened by default, beside --listen). A gateway
    /// bridges them with the GridConnect clients (CAN nodes and OpenLCB-TCP nodes see each
    /// other, streams included). A second hub needs another port here too, or --no-tcp.
    #[arg(long, value_name = "ADDR", default_value = TCP_ADDR)]
    tcp_listen: String,
    /// Do not listen for OpenLCB-TCP clients.
    #[arg(long)]
    no_tcp: bool,
    /// Keep the two groups apart: GridConnect clients talk among themselves, OpenLCB-TCP
    /// clients among themselves.
    #[arg(long)]
    no_bridge: bool,
    /// The gateway's Node ID (it is the originating node of what it forwards to OpenLCB-TCP).
    #[arg(long, value_name = "NODE_ID", value_parser = crate::args::node_id, default_value = "05.01.01.01.22.FE")]
    gateway_node_id: NodeId,
    /// Print every frame as it passes.
    #[arg(long)]
    trace: bool,
    /// Bytes queued for one client before it is disconnected as too slow.
    #[arg(long, value_name = "BYTES", default_value_t = 1024 * 1024, value_parser = crate::args::positive::<usize>)]
    max_queue: usize,
    /// Clients connected at once (both listeners); more are refused.
    #[arg(long, value_name = "N", default_value_t = 64)]
    max_clients: usize,
    /// Seconds a new client may stay silent (send nothing at all) before it is closed;
    /// 0 keeps silent clients.
    #[arg(long, value_name = "SECS", default_value_t = 60)]
    silent_timeout: u64,
}

pub(crate) fn run(args: &HubArgs) -> Result<ExitCode, String> {
    net::runtime()?.block_on(serve(args))
}

async fn serve(args: &HubArgs) -> Result<ExitCode, String> {
    let mut options = HubOptions::default();
    options.trace = args.trace;
    options.max_queued_bytes = args.max_queue;
    options.max_clients = args.max_clients;
    options.silent_timeout = (args.silent_timeout > 0).then(|| std::time::Duration::from_secs(args.silent_timeout));
    options.bridge = !args.no_bridge;
    options.gateway_node_id = args.gateway_node_id;
    let tcp = (!args.no_tcp).then_some(args.tcp_listen.as_str());
    let mut hub = match Hub::bind(&args.listen, tcp, options).await {
        Ok(hub) => hub,
        Err(Error::Bind { addr, source }) => return Ok(bind_failed(args, &addr, &source)),
        Err(error) => return Ok(net::fail("hub", &error)),
    };
    match hub.tcp_local_addr() {
        Some(tcp) => eprintln!(
            "lcc-stream hub: GridConnect on {}, OpenLCB-TCP on {tcp} ({})",
            hub.local_addr(),
            if args.no_bridge { "not bridged" } else { "bridged" }
        ),
        None => eprintln!("lcc-stream hub: GridConnect on {}", hub.local_addr()),
    }
    loop {
        tokio::select! {
            event = hub.next_event() => match event {
                Some(event) => print_event(&event),
                None => return Ok(ExitCode::SUCCESS),
            },
            _ = tokio::signal::ctrl_c() => {
                let stats = hub.stats();
                eprintln!(
                    "lcc-stream hub: stopping; {} clients served, {} frames relayed, {} decode errors, {} slow clients dropped",
                    stats.clients_accepted, stats.frames, stats.decode_errors, stats.slow_clients
                );
                return Ok(ExitCode::SUCCESS);
            }
        }
    }
}

/// Says which listener could not be opened and how to move or disable it; a usage error.
fn bind_failed(args: &HubArgs, addr: &str, source: &std::io::Error) -> ExitCode {
    let tcp = !args.no_tcp && addr == args.tcp_listen && addr != args.listen;
    if tcp {
        eprintln!(
            "lcc-stream hub: cannot open the OpenLCB-TCP listener on {addr}: {source}\n\
             (it is opened beside the GridConnect listener by default; move it with \
             --tcp-listen HOST:PORT or turn it off with --no-tcp)"
        );
    } else {
        eprintln!(
            "lcc-stream hub: cannot open the GridConnect listener on {addr}: {source}\n\
             (choose another with --listen HOST:PORT, e.g. --listen 127.0.0.1:12031)"
        );
    }
    ExitCode::from(net::EXIT_USAGE)
}

fn print_event(event: &HubEvent) {
    match event {
        HubEvent::Connected { client, peer, protocol } => {
            eprintln!("client {client} connected from {peer} ({protocol:?})")
        }
        HubEvent::Disconnected { client, reason } => eprintln!("client {client} left: {reason}"),
        HubEvent::SlowClient { client, queued } => {
            eprintln!("client {client} dropped: too slow ({queued} bytes were waiting for it)")
        }
        HubEvent::Garbage { client, count, error } => {
            eprintln!("client {client} sent {count} undecodable pieces (the first: {error})")
        }
        HubEvent::Refused { peer, clients } => {
            eprintln!("refused a client from {peer}: {clients} clients connected (--max-clients)")
        }
        HubEvent::Frame { client, text } => println!("{client:>3} {text}"),
        _ => {}
    }
}
