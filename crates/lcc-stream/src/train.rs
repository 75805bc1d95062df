//! `lcc-stream train`: a virtual command station that is a train itself (DCC address 3 by
//! default) and creates a train node for each address a throttle asks it to allocate. It
//! prints every command its trains get.

use std::collections::BTreeMap;
use std::process::ExitCode;
use std::sync::{Arc, Mutex};
use std::time::Instant;

use clap::Args;
use openlcb_stream::{EventId, NodeId};
use openlcb_tokio::openlcb_node::memconfig::MemoryServer;
use openlcb_tokio::openlcb_node::traction::{
    FunctionKind, FunctionName, TrainChange, TrainConfig, TrainEvent, TrainIdentity, TrainProtocol, fdi_space,
};
use openlcb_tokio::{Node, NodeOptions};
use serde::Serialize;

use crate::net::{self, ConnectArgs};
use crate::outcome::{Failure, Outcome};
use crate::peer::Peer;

#[derive(Debug, Args)]
#[command(after_help = format!("{}{}", "\
The node is a train (Traction Control: speed, functions, emergency stop, controller,
listeners for consists, reservation, heartbeat; the global Emergency Stop and Off events) and
a command station: an allocate search (Train Search) for an address it has no train for
creates one, a node of its own with the next Node ID, up to --allocate trains. Every train
serves its FDI (space 0xFA) naming the --function keys.

Examples:
  lcc-stream train                                        DCC 3, trains created on demand
  lcc-stream train --address 1234 --function 0=Headlight --function 2=Horn --momentary 2
  lcc-stream train --json --allocate 0                    one train, one JSON line a command

", net::network_help(&[])))]
pub(crate) struct TrainArgs {
    /// The DCC address of this node's own train (long from 128 on, or with --long).
    #[arg(long, default_value_t = 3, value_parser = clap::value_parser!(u32).range(1..=10239))]
    address: u32,
    /// A long (14-bit) DCC address even below 128.
    #[arg(long)]
    long: bool,
    /// The train's name (a search may find it by the digits in it).
    #[arg(long, default_value = "")]
    name: String,
    /// A function key's name for the FDI, NUMBER=NAME (repeat it) [default: 0=Headlight].
    #[arg(long = "function", value_name = "NUMBER=NAME", value_parser = parse_function)]
    functions: Vec<(u32, String)>,
    /// These functions are momentary (a horn), not on/off.
    #[arg(long = "momentary", value_name = "NUMBER")]
    momentary: Vec<u32>,
    /// Trains created for allocate searches, at most (0: none).
    #[arg(long, default_value_t = 8, value_name = "MAX")]
    allocate: usize,
    /// The heartbeat deadline given to a controller, in seconds (0: no heartbeat).
    #[arg(long, default_value_t = 3, value_parser = clap::value_parser!(u64).range(0..=3600))]
    heartbeat: u64,
    /// One JSON object per change: time (seconds since start), train (its address), node,
    /// change, and what it carries (set_speed and commanded_speed as m/s, negative in reverse;
    /// function and value; node and flags; controller), and from (the Node ID of the sender)
    /// or, when only its CAN alias is known, from_alias.
    #[arg(long)]
    json: bool,
    #[command(flatten)]
    node_id: net::TransientId,
    #[command(flatten)]
    connect: ConnectArgs,
}

fn parse_function(text: &str) -> Result<(u32, String), String> {
    let bad = || format!("`{text}` is no function: NUMBER=NAME, e.g. 0=Headlight");
    let (number, name) = text.split_once('=').ok_or_else(bad)?;
    let number: u32 = number.trim().parse().map_err(|_| bad())?;
    if number > 68 || name.is_empty() {
        return Err(format!("`{text}`: a function is 0 to 68 with a name"));
    }
    Ok((number, name.to_string()))
}

pub(crate) fn run(args: &TrainArgs) -> Result<ExitCode, String> {
    net::runtime()?.block_on(train(args))
}

/// One change as `--json` prints it.
#[derive(Debug, Serialize)]
struct ChangeLine {
    time: f64,
    train: u32,
    node: String,
    change: &'static str,
    #[serde(skip_serializing_if = "Option::is_none")]
    set_speed: Option<f32>,
    #[serde(skip_serializing_if = "Option::is_none")]
    commanded_speed: Option<f32>,
    #[serde(skip_serializing_if = "Option::is_none")]
    function: Option<u32>,
    #[serde(skip_serializing_if = "Option::is_none")]
    value: Option<u16>,
    #[serde(skip_serializing_if = "Option::is_none")]
    on: Option<bool>,
    #[serde(skip_serializing_if = "Option::is_none")]
    other: Option<String>,
    #[serde(skip_serializing_if = "Option::is_none")]
    flags: Option<u8>,
    #[serde(skip_serializing_if = "Option::is_none")]
    from: Option<String>,
    #[serde(skip_serializing_if = "Option::is_none")]
    from_alias: Option<String>,
}

/// What every train of this process shares: the output, the FDI, the trains there are.
struct Station {
    json: bool,
    started: Instant,
    functions: Vec<FunctionName>,
    heartbeat: u64,
    /// The trains by (address, long), with their Node IDs.
    trains: Mutex<BTreeMap<(u32, bool), NodeId>>,
}

impl Station {
    /// `allocate`: the command station takes allocate searches; `created`: a train it made.
    fn config(&self, identity: TrainIdentity, allocate: bool, created: bool) -> TrainConfig {
        let mut config = TrainConfig::dcc(identity.address);
        config.identity = identity;
        config.allocate = allocate;
        // A created train answers the search it was made for instead.
        config.announce = !created;
        config.heartbeat = (self.heartbeat > 0).then(|| openlcb_stream::Duration::from_secs(self.heartbeat));
        config
    }

    fn print(&self, address: u32, node: NodeId, event: &TrainEvent) {
        let peer = event.from.map(Peer::of);
        let mut line = ChangeLine {
            time: self.started.elapsed().as_secs_f64(),
            train: address,
            node: node.to_string(),
            change: "",
            set_speed: None,
            commanded_speed: None,
            function: None,
            value: None,
            on: None,
            other: None,
            flags: None,
            from: peer.and_then(Peer::node_field),
            from_alias: peer.and_then(Peer::alias_field),
        };
        let text = match event.change {
            TrainChange::Speed { set, commanded } => {
                line.change = "speed";
                line.set_speed = Some(set.to_f32());
                line.commanded_speed = Some(commanded.to_f32());
                if set == commanded { format!("speed {set}") } else { format!("speed {set}, stopped: {commanded}") }
            }
            TrainChange::Function { address, value } => {
                line.change = "function";
                line.function = Some(address);
                line.value = Some(value);
                let name = self.functions.iter().find(|f| f.number == address).map(|f| format!(" ({})", f.name));
                format!("F{address}{} = {value}", name.unwrap_or_default())
            }
            TrainChange::EmergencyStop => {
                line.change = "emergency-stop";
                "emergency stop".into()
            }
            TrainChange::GlobalStop(on) => {
                line.change = "global-stop";
                line.on = Some(on);
                format!("Emergency Stop All {}", if on { "on" } else { "cleared" })
            }
            TrainChange::GlobalOff(on) => {
                line.change = "global-off";
                line.on = Some(on);
                format!("Emergency Off All {}", if on { "on" } else { "cleared" })
            }
            TrainChange::ControllerAssigned { controller, previous } => {
                line.change = "controller-assigned";
                line.other = Some(controller.to_string());
                match previous {
                    Some(old) => format!("controller {controller} (was {old})"),
                    None => format!("controller {controller}"),
                }
            }
            TrainChange::ControllerReleased(controller) => {
                line.change = "controller-released";
                line.other = Some(controller.to_string());
                format!("controller {controller} released it")
            }
            TrainChange::HeartbeatTimedOut(controller) => {
                line.change = "heartbeat-timeout";
                line.other = Some(controller.to_string());
                format!("controller {controller} missed its heartbeat: stopping")
            }
            TrainChange::ListenerAttached { node, flags } => {
                line.change = "listener-attached";
                line.other = Some(node.to_string());
                line.flags = Some(flags);
                format!("listener {node} attached (flags 0x{flags:02X})")
            }
            TrainChange::ListenerDetached(node) => {
                line.change = "listener-detached";
                line.other = Some(node.to_string());
                format!("listener {node} detached")
            }
            TrainChange::Reserved(node) => {
                line.change = "reserved";
                line.other = Some(node.to_string());
                format!("reserved by {node}")
            }
            TrainChange::ReservationReleased(node) => {
                line.change = "reservation-released";
                line.other = Some(node.to_string());
                format!("reservation of {node} released")
            }
            TrainChange::Allocate { address, .. } => {
                line.change = "allocate";
                line.value = u16::try_from(address).ok();
                format!("asked to allocate DCC {address}")
            }
            _ => {
                line.change = "other";
                "other change".into()
            }
        };
        if self.json {
            outln!("{}", serde_json::to_string(&line).unwrap_or_default());
        } else {
            let by = peer.map(|p| format!(" (by {p})")).unwrap_or_default();
            outln!("train {address}: {text}{by}");
        }
    }
}

fn node_options(station: &Station, id: NodeId, identity: TrainIdentity, allocate: bool, created: bool) -> NodeOptions {
    let mut options = NodeOptions::new(id);
    options.node.snip = net::snip("train");
    options.node.snip.user_name = format!("DCC {}", identity.address);
    options.node.train = Some(station.config(identity, allocate, created));
    options
}

async fn train(args: &TrainArgs) -> Result<ExitCode, String> {
    let mut interrupt = net::Interrupt::new()?;
    let mut functions: Vec<FunctionName> = if args.functions.is_empty() {
        vec![FunctionName { number: 0, name: "Headlight".into(), kind: FunctionKind::Binary }]
    } else {
        args.functions
            .iter()
            .map(|(number, name)| FunctionName { number: *number, name: name.clone(), kind: FunctionKind::Binary })
            .collect()
    };
    for function in &mut functions {
        if args.momentary.contains(&function.number) {
            function.kind = FunctionKind::Momentary;
        }
    }
    let station = Arc::new(Station {
        json: args.json,
        started: Instant::now(),
        functions,
        heartbeat: args.heartbeat,
        trains: Mutex::new(BTreeMap::new()),
    });
    let long = args.long || args.address >= 128;
    let mut identity = TrainIdentity::dcc(args.address);
    identity.protocol = TrainProtocol::Dcc { long };
    identity.name = args.name.clone();
    let options = |id| node_options(&station, id, identity.clone(), args.allocate > 0, false);
    let node = match args.connect.join(&args.node_id, options).await {
        Ok(node) => node,
        Err(failure) => return Ok(net::fail("train", &failure)),
    };
    let mut node = node;
    if let Err(error) = serve_fdi(&node, &station).await {
        return Ok(net::fail("train", &Failure::Net(error)));
    }
    let mut events = match node.train_events().await {
        Ok(events) => events,
        Err(error) => return Ok(net::fail("train", &Failure::Net(error))),
    };
    station.trains.lock().map_err(|_| "poisoned")?.insert((args.address, long), node.node_id());
    eprintln!(
        "lcc-stream train: DCC {}{} as {} (Ctrl-C stops)",
        args.address,
        if long { " (long)" } else { "" },
        node.node_id()
    );
    let mut created: Vec<Node> = Vec::new();
    let outcome = loop {
        tokio::select! {
            event = events.next() => {
                let Some(event) = event else { break Outcome::ConnectionLost };
                station.print(args.address, node.node_id(), &event);
                if let TrainChange::Allocate { event: search, address, protocol } = event.change
                    && let Some(train) = allocate(args, &station, &node, created.len(), search, address, protocol).await
                {
                    created.push(train);
                }
            }
            () = interrupt.wait() => break Outcome::Interrupted,
            error = node.closed() => {
                eprintln!("lcc-stream train: {error}");
                break Outcome::ConnectionLost;
            }
        }
    };
    for train in created {
        train.close().await;
    }
    node.close().await;
    Ok(ExitCode::from(match outcome {
        Outcome::Interrupted => Outcome::Ok.status(),
        other => other.status(),
    }))
}

/// Serves the train's FDI (space 0xFA).
async fn serve_fdi(node: &Node, station: &Station) -> Result<(), openlcb_tokio::Error> {
    let server = MemoryServer::new().with_space(0xFA, fdi_space(&station.functions));
    node.set_memory_server(server).await.map(drop)
}

/// Creates the train an allocate search asked for, unless this process has it (it
/// answered itself) or has created `--allocate` already; it answers `search` once it is on
/// the network.
async fn allocate(
    args: &TrainArgs,
    station: &Arc<Station>,
    node: &Node,
    count: usize,
    search: EventId,
    address: u32,
    protocol: TrainProtocol,
) -> Option<Node> {
    let long = matches!(protocol, TrainProtocol::Dcc { long: true });
    if station.trains.lock().ok()?.contains_key(&(address, long)) {
        return None;
    }
    if count >= args.allocate {
        eprintln!("lcc-stream train: not creating DCC {address}: {} trains created already", args.allocate);
        return None;
    }
    let id = NodeId::new(node.node_id().as_raw() + 1 + count as u64)?;
    let mut identity = TrainIdentity::dcc(address);
    identity.protocol = protocol;
    let chosen = net::TransientId { chosen: Some(id) };
    let train = match args.connect.join(&chosen, |id| node_options(station, id, identity.clone(), false, true)).await {
        Ok(train) => train,
        Err(failure) => {
            eprintln!("lcc-stream train: could not create DCC {address}: {}", failure.brief());
            return None;
        }
    };
    if let Err(error) = serve_fdi(&train, station).await {
        eprintln!("lcc-stream train: DCC {address}: {error}");
    }
    let mut events = train.train_events().await.ok()?;
    if let Err(error) = train.answer_train_search(search).await {
        eprintln!("lcc-stream train: DCC {address} could not answer the search: {error}");
    }
    station.trains.lock().ok()?.insert((address, long), id);
    eprintln!("lcc-stream train: created DCC {address}{} as {id}", if long { " (long)" } else { "" });
    let station = station.clone();
    tokio::spawn(async move {
        while let Some(event) = events.next().await {
            station.print(address, id, &event);
        }
    });
    Some(train)
}
