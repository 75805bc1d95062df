//! `lcc-stream hub`: a GridConnect TCP hub, and an OpenLCB-TCP one beside it, bridged by a
//! gateway.

use std::process::ExitCode;

use clap::Args;
use openlcb_stream::NodeId;
use std::collections::HashMap;

use openlcb_tokio::hub::{BRIDGE_GRIDCONNECT, BRIDGE_TCP, CLOSED_BY_CLIENT, ClientId};
use openlcb_tokio::{Error, Hub, HubEvent, HubOptions};

use crate::net::{self, GRIDCONNECT_ADDR, TCP_ADDR};
use crate::outcome::{Failure, Outcome, exit_help};

/// Options of `lcc-stream hub`.
#[derive(Debug, Args)]
#[command(after_help = exit_help(&[Outcome::Ok, Outcome::Error, Outcome::Usage, Outcome::UnreachableHub, Outcome::Interrupted]))]
pub(crate) struct HubArgs {
    /// Where GridConnect clients connect. The default is reachable from this machine only;
    /// for JMRI or nodes on other machines listen on all interfaces (0.0.0.0:12021) or on
    /// one of this machine's addresses.
    #[arg(long, value_name = "ADDR", default_value = GRIDCONNECT_ADDR)]
    listen: String,
    /// Relay between the clients and a USB GridConnect adapter on the CAN bus (e.g.
    /// /dev/ttyACM0 or COM3): the clients reach the real bus through the hub.
    #[arg(long, value_name = "DEVICE")]
    serial: Option<String>,
    /// Relay between the clients and a SocketCAN interface, e.g. can0 (Linux).
    #[cfg(target_os = "linux")]
    #[arg(long, value_name = "IFACE")]
    can: Option<String>,
    /// The serial port's line rate in bits per second (USB adapters ignore it).
    #[arg(long, value_name = "N", default_value_t = openlcb_tokio::serial::DEFAULT_BAUD, requires = "serial")]
    baud: u32,
    /// Join another GridConnect hub as one of its clients and relay both ways (both hubs'
    /// clients share one CAN segment); a lost link is tried again, waiting up to 5 s.
    #[arg(long, value_name = "HOST:PORT")]
    upstream: Option<String>,
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
    /// Print every frame as it passes, raw (GridConnect text). For a decoded view (messages
    /// by name, datagrams, streams, events) run `lcc-stream monitor` beside the hub, or on
    /// this output saved to a file (`monitor --from FILE`). The trace never slows the bus:
    /// frames it cannot print in time (a slow terminal) are relayed all the same, and a line
    /// of the trace says how many it left out.
    #[arg(long)]
    trace: bool,
    /// Bytes queued for one client. The hub runs at the pace of its slowest reader, like a
    /// CAN bus: when a client's queue is full, the hub stops reading from whoever sends the
    /// next frame for it until there is room, so a bulk transfer slows down rather than cost
    /// a listening client its connection.
    #[arg(long, value_name = "BYTES", default_value_t = 1024 * 1024, value_parser = crate::args::positive::<usize>)]
    max_queue: usize,
    /// Seconds a client may take nothing of its full queue while senders wait for it; then it
    /// is disconnected as too slow (a dead connection), and the others go on.
    #[arg(long, value_name = "SECS", default_value_t = 10, value_parser = crate::args::positive::<u64>)]
    drain_timeout: u64,
    /// Clients connected at once (both listeners and links). When the hub is full, a new
    /// client takes the slot of the client with the lowest rate below --slot-min-frames per
    /// --slot-window (quiet clients keep their slots while there is room); if every client
    /// keeps the rate, the new one is refused.
    #[arg(long, value_name = "N", default_value_t = 64)]
    max_clients: usize,
    /// Complete frames a client must send per --slot-window to keep its slot when the hub is
    /// full (a client that connected less than a window ago, --serial, --can and --upstream
    /// are never evicted); 0 never evicts anyone.
    #[arg(long, value_name = "N", default_value_t = 10)]
    slot_min_frames: u16,
    /// The window, in seconds, of --slot-min-frames; 0 never evicts anyone.
    #[arg(long, value_name = "SECS", default_value_t = 60)]
    slot_window: u64,
    /// Seconds a new client may stay silent (send nothing at all) before it is closed;
    /// 0 keeps silent clients.
    #[arg(long, value_name = "SECS", default_value_t = 60)]
    silent_timeout: u64,
}

pub(crate) fn run(args: &HubArgs) -> Result<ExitCode, String> {
    net::runtime()?.block_on(serve(args))
}

async fn serve(args: &HubArgs) -> Result<ExitCode, String> {
    let mut interrupt = net::Interrupt::new()?;
    let mut options = HubOptions::default();
    options.trace = args.trace;
    options.max_queued_bytes = args.max_queue;
    options.max_clients = args.max_clients;
    options.drain_timeout = std::time::Duration::from_secs(args.drain_timeout);
    options.slot_min_frames = args.slot_min_frames;
    options.slot_window = (args.slot_window > 0).then(|| std::time::Duration::from_secs(args.slot_window));
    options.silent_timeout = (args.silent_timeout > 0).then(|| std::time::Duration::from_secs(args.silent_timeout));
    options.bridge = !args.no_bridge;
    options.gateway_node_id = args.gateway_node_id;
    let tcp = (!args.no_tcp).then_some(args.tcp_listen.as_str());
    let mut hub = match Hub::bind(&args.listen, tcp, options).await {
        Ok(hub) => hub,
        Err(Error::Bind { addr, source }) => return Ok(bind_failed(args, &addr, &source)),
        Err(error) => return Ok(net::fail("hub", &Failure::Net(error))),
    };
    match hub.tcp_local_addr() {
        Some(tcp) => eprintln!(
            "lcc-stream hub: GridConnect on {}, OpenLCB-TCP on {tcp} ({})",
            hub.local_addr(),
            if args.no_bridge { "not bridged" } else { "bridged" }
        ),
        None => eprintln!("lcc-stream hub: GridConnect on {}", hub.local_addr()),
    }
    if hub.local_addr().ip().is_loopback() {
        eprintln!("lcc-stream hub: reachable from this machine only (--listen 0.0.0.0:12021 opens it to others)");
    }
    let mut names = ClientNames::default();
    if let Some(device) = &args.serial {
        match openlcb_tokio::serial::open(device, args.baud) {
            Ok(port) => {
                hub.attach(port, device);
            }
            Err(error) => return Ok(net::fail("hub", &Failure::Net(error))),
        }
    }
    #[cfg(target_os = "linux")]
    if let Some(interface) = &args.can {
        match openlcb_tokio::can::open_socketcan(interface) {
            Ok(socket) => {
                hub.attach(openlcb_tokio::can::FrameStream::new(socket), interface);
            }
            Err(error) => return Ok(net::fail("hub", &Failure::Net(error))),
        }
    }
    if let Some(upstream) = &args.upstream {
        hub.link_upstream(upstream);
    }
    loop {
        tokio::select! {
            event = hub.next_event() => match event {
                Some(event) => {
                    names.print_left_out(hub.events_dropped());
                    names.print(&event);
                }
                None => return Ok(ExitCode::SUCCESS),
            },
            () = interrupt.wait() => {
                let stats = hub.stats();
                eprintln!(
                    "lcc-stream hub: interrupted; {} clients served, {} frames relayed, {} decode errors, {} slow clients dropped, {} evicted from a full hub, {} events not shown",
                    stats.clients_accepted,
                    stats.frames,
                    stats.decode_errors,
                    stats.slow_clients,
                    stats.clients_evicted,
                    stats.events_dropped
                );
                return Ok(ExitCode::from(Outcome::Interrupted.status()));
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
    ExitCode::from(Outcome::Usage.status())
}

/// What the hub prints about its clients: their names, the time since the hub started, and
/// how many events it has said it left out.
struct ClientNames {
    start: std::time::Instant,
    names: HashMap<ClientId, String>,
    left_out: u64,
}

impl Default for ClientNames {
    fn default() -> Self {
        let names = HashMap::from([(BRIDGE_GRIDCONNECT, "bridge".to_string()), (BRIDGE_TCP, "bridge".to_string())]);
        ClientNames { start: std::time::Instant::now(), names, left_out: 0 }
    }
}

impl ClientNames {
    fn name(&self, client: ClientId) -> std::borrow::Cow<'_, str> {
        match self.names.get(&client) {
            Some(name) => name.as_str().into(),
            None => format!("client {client}").into(),
        }
    }

    /// Says in the trace, where it notices, that events were dropped since it last said so
    /// (`dropped` is the hub's count so far). The line holds no frame, so `monitor --from`
    /// passes over it.
    fn print_left_out(&mut self, dropped: u64) {
        if dropped > self.left_out {
            let at = self.start.elapsed().as_secs_f64();
            let hub = "(hub)";
            outln!(
                "{at:>10.3} {hub:<24} {} events not shown here: the trace fell behind (the frames were relayed)",
                dropped - self.left_out
            );
            self.left_out = dropped;
        }
    }

    fn print(&mut self, event: &HubEvent) {
        match event {
            HubEvent::Connected { client, peer, protocol } => {
                self.names.insert(*client, format!("client {client} ({peer})"));
                eprintln!("client {client} connected from {peer} ({protocol:?})")
            }
            HubEvent::Attached { client, name } => {
                self.names.insert(*client, format!("client {client} ({name})"));
                eprintln!("client {client} is {name}")
            }
            HubEvent::UpstreamDown { addr, reason, retry_in } => {
                eprintln!("upstream {addr} down: {reason}; trying again in {:.2} s", retry_in.as_secs_f64())
            }
            HubEvent::Disconnected { client, reason } if reason == CLOSED_BY_CLIENT => {
                eprintln!("{} left", self.name(*client));
                self.names.remove(client);
            }
            HubEvent::Disconnected { client, reason } => {
                eprintln!("{} dropped: {reason}", self.name(*client));
                self.names.remove(client);
            }
            HubEvent::SlowClient { client, queued } => {
                eprintln!(
                    "{} dropped: too slow (it took none of the {queued} bytes waiting for it within --drain-timeout)",
                    self.name(*client)
                );
                self.names.remove(client);
            }
            HubEvent::Evicted { client, frames, newcomer } => {
                eprintln!(
                    "{} dropped: the hub is full and it sent {frames} frames in the last --slot-window; its slot went to {newcomer}",
                    self.name(*client)
                );
                self.names.remove(client);
            }
            HubEvent::Garbage { client, count, error } => {
                eprintln!("{} sent {count} undecodable pieces (the first: {error})", self.name(*client))
            }
            HubEvent::Refused { peer, clients } => {
                eprintln!(
                    "refused a client from {peer}: the hub is full ({clients} clients, --max-clients) and none could be evicted (--slot-min-frames, --slot-window)"
                )
            }
            HubEvent::Frame { client, text } => {
                let at = self.start.elapsed().as_secs_f64();
                outln!("{at:>10.3} {:<24} {text}", self.name(*client))
            }
            _ => {}
        }
    }
}
