//! `lcc-stream train`: a virtual command station that is a train itself (DCC address 3 by
//! default) and creates a train node for each address a throttle asks it to allocate. It
//! prints every command its trains get.

use std::collections::BTreeMap;
use std::process::ExitCode;
use std::sync::{Arc, Mutex};
use std::time::Instant;

use clap::Args;
use openlcb_stream::{EventId, NodeId};
use openlcb_tokio::openlcb_node::traction::{
    FunctionKind, FunctionName, TrainChange, TrainConfig, TrainEvent, TrainIdentity, TrainProtocol,
};
use openlcb_tokio::{MemoryEvent, Node, NodeOptions, ServerEvents};
use serde::Serialize;

use crate::net::{self, ConnectArgs};
use crate::outcome::{Failure, Outcome};
use crate::peer::Peer;
use crate::train_config::{SPEED_STEPS, TrainSettings, TrainSetup};

#[derive(Debug, Args)]
#[command(after_help = format!("{}{}", "\
The node is a train (Traction Control: speed, functions, emergency stop, controller,
listeners for consists, reservation, heartbeat; the global Emergency Stop and Off events) and
a command station: an allocate search (Train Search) for an address it has no train for
creates one, a node of its own with the next Node ID, up to --allocate trains. Every train
serves its FDI (space 0xFA) naming the --function keys, its function values (space 0xF9),
and its configuration with a CDI (name, DCC address, address type, speed steps, a name and
kind for each key F0-F68; `lcc-stream config` or JMRI change it, in effect at Update
Complete; kept in memory while the process runs).

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
    /// The decoder's speed steps, as the configuration shows them: 14, 28 or 128.
    #[arg(long, default_value_t = 128, value_parser = parse_speed_steps)]
    speed_steps: u8,
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

fn parse_speed_steps(text: &str) -> Result<u8, String> {
    text.parse::<u8>()
        .ok()
        .filter(|steps| SPEED_STEPS.contains(&u64::from(*steps)))
        .ok_or_else(|| format!("`{text}`: a decoder has 14, 28 or 128 speed steps"))
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

/// What every train of this process shares: the output, the factory settings, the trains
/// there are.
struct Station {
    json: bool,
    started: Instant,
    /// The function keys a train starts with (the command line's).
    functions: Vec<FunctionName>,
    speed_steps: u8,
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

    /// A line of `train`'s output, `change` and the rest to fill in.
    fn line(&self, train: &Kept, from: Option<Peer>) -> ChangeLine {
        ChangeLine {
            time: self.started.elapsed().as_secs_f64(),
            train: train.setup.identity.address,
            node: train.id.to_string(),
            change: "",
            set_speed: None,
            commanded_speed: None,
            function: None,
            value: None,
            on: None,
            other: None,
            flags: None,
            from: from.and_then(Peer::node_field),
            from_alias: from.and_then(Peer::alias_field),
        }
    }

    fn emit(&self, line: &ChangeLine, text: &str, from: Option<Peer>) {
        if self.json {
            outln!("{}", serde_json::to_string(line).unwrap_or_default());
        } else {
            let by = from.map(|p| format!(" (by {p})")).unwrap_or_default();
            outln!("train {}: {text}{by}", line.train);
        }
    }

    fn print(&self, train: &Kept, event: &TrainEvent) {
        let peer = event.from.map(Peer::of);
        let mut line = self.line(train, peer);
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
                let names = &train.setup.functions;
                let name = names.iter().find(|f| f.number == address).map(|f| format!(" ({})", f.name));
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
        self.emit(&line, &text, peer);
    }

    /// `train` took a new configuration from `by`; it was `was` (its address).
    fn print_configured(&self, train: &Kept, was: u32, by: NodeId) {
        let peer = Some(Peer::of(by));
        let mut line = self.line(train, peer);
        line.change = "configured";
        line.other = Some(train.setup.text());
        let text = format!("configured as {}", train.setup.text());
        let text = if was == line.train { text } else { format!("{text} (was DCC {was})") };
        self.emit(&line, &text, peer);
    }
}

/// One train of this process: its node, its configuration, what it was configured as.
struct Kept {
    id: NodeId,
    settings: TrainSettings,
    setup: TrainSetup,
}

impl Kept {
    /// Serves the configuration of the train on `node`, which starts as `setup`; the memory
    /// events to act on ([`Kept::on_memory`]).
    async fn serve(node: &Node, setup: TrainSetup) -> Result<(Kept, ServerEvents), openlcb_tokio::Error> {
        let settings = TrainSettings::new(&setup, &net::snip("train"));
        let events = node.set_memory_server(settings.server()).await?;
        Ok((Kept { id: node.node_id(), settings, setup }, events))
    }

    /// Update Complete takes what a tool wrote; Factory Reset the defaults.
    async fn on_memory(&mut self, node: &Node, station: &Station, event: MemoryEvent) {
        let by = match event {
            MemoryEvent::UpdateComplete { by } => by,
            MemoryEvent::FactoryResetRequested { by } => {
                if let Err(error) = self.settings.factory_reset() {
                    eprintln!("lcc-stream train: DCC {}: {error}", self.setup.identity.address);
                }
                by
            }
            _ => return,
        };
        let was = self.setup.identity.address;
        let setup = match self.settings.read() {
            Ok(setup) if setup == self.setup => return,
            Ok(setup) => setup,
            Err(why) => return eprintln!("lcc-stream train: DCC {was}: configuration not taken: {why}"),
        };
        let key = |identity: &TrainIdentity| {
            (identity.address, matches!(identity.protocol, TrainProtocol::Dcc { long: true }))
        };
        if key(&setup.identity) != key(&self.setup.identity) {
            let Ok(mut trains) = station.trains.lock() else { return };
            if trains.get(&key(&setup.identity)).is_some_and(|id| *id != self.id) {
                return eprintln!(
                    "lcc-stream train: DCC {was}: configuration not taken: DCC {} is another train here",
                    setup.identity.address
                );
            }
            trains.remove(&key(&self.setup.identity));
            trains.insert(key(&setup.identity), self.id);
        }
        if let Err(error) = node.set_train_identity(setup.identity.clone()).await {
            return eprintln!("lcc-stream train: DCC {was}: {error}");
        }
        self.settings.show(&setup);
        self.setup = setup;
        station.print_configured(self, was, by);
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
        speed_steps: args.speed_steps,
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
    let (mut kept, mut asked) = match Kept::serve(&node, station.setup(identity.clone())).await {
        Ok(served) => served,
        Err(error) => return Ok(net::fail("train", &Failure::Net(error))),
    };
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
    let mut created: Vec<Created> = Vec::new();
    let outcome = loop {
        tokio::select! {
            event = events.next() => {
                let Some(event) = event else { break Outcome::ConnectionLost };
                station.print(&kept, &event);
                if let TrainChange::Allocate { event: search, address, protocol } = event.change
                    && let Some(train) = allocate(args, &station, &node, created.len(), search, address, protocol).await
                {
                    created.push(train);
                }
            }
            Some(event) = asked.next() => kept.on_memory(&node, &station, event).await,
            () = interrupt.wait() => break Outcome::Interrupted,
            error = node.closed() => {
                eprintln!("lcc-stream train: {error}");
                break Outcome::ConnectionLost;
            }
        }
    };
    for (stop, running) in created {
        let _ = stop.send(());
        let _ = running.await;
    }
    node.close().await;
    Ok(ExitCode::from(match outcome {
        Outcome::Interrupted => Outcome::Ok.status(),
        other => other.status(),
    }))
}

impl Station {
    /// The settings a train at `identity` starts with.
    fn setup(&self, identity: TrainIdentity) -> TrainSetup {
        TrainSetup { identity, speed_steps: self.speed_steps, functions: self.functions.clone() }
    }
}

/// A train created for a search: how to stop it, and its task (which closes its node).
type Created = (tokio::sync::oneshot::Sender<()>, tokio::task::JoinHandle<()>);

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
) -> Option<Created> {
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
    let (mut kept, mut asked) = match Kept::serve(&train, station.setup(identity.clone())).await {
        Ok(served) => served,
        Err(error) => {
            eprintln!("lcc-stream train: DCC {address}: {error}");
            train.close().await;
            return None;
        }
    };
    let mut events = train.train_events().await.ok()?;
    if let Err(error) = train.answer_train_search(search).await {
        eprintln!("lcc-stream train: DCC {address} could not answer the search: {error}");
    }
    station.trains.lock().ok()?.insert((address, long), id);
    eprintln!("lcc-stream train: created DCC {address}{} as {id}", if long { " (long)" } else { "" });
    let station = station.clone();
    let (stop, mut stopped) = tokio::sync::oneshot::channel();
    let running = tokio::spawn(async move {
        loop {
            tokio::select! {
                event = events.next() => match event {
                    Some(event) => station.print(&kept, &event),
                    None => break,
                },
                Some(event) = asked.next() => kept.on_memory(&train, &station, event).await,
                _ = &mut stopped => break,
            }
        }
        train.close().await;
    });
    Some((stop, running))
}
