//! `lcc-stream throttle`: find a train by its DCC address (Train Search, allocating it when
//! a command station offers to), take control of it, and drive it from the command line.

use std::process::ExitCode;
use std::time::Duration;

use clap::Args;
use openlcb_stream::NodeId;
use openlcb_tokio::openlcb_node::traction::{
    LISTENER_HIDE, LISTENER_LINK_F0, LISTENER_LINK_FN, LISTENER_REVERSE, SEARCH_ADDRESS_ONLY, SEARCH_ALLOCATE,
    SEARCH_EXACT, SearchQuery, Speed, ThrottleConfig, ThrottleEvent, TractionCommand,
};
use openlcb_tokio::{EventNotice, EventRole, EventState, Listen, Node, NodeOptions, ThrottleEvents};
use serde::Serialize;

use crate::net::{self, ConnectArgs};
use crate::outcome::{Failure, Outcome};
use crate::peer::Peer;

/// How long the train search, the assign and each query wait.
const ANSWER_WAIT: Duration = Duration::from_secs(3);

#[derive(Debug, Args)]
#[command(after_help = format!("{}{}", "\
The throttle searches for the train (allocating it, so a command station creates it when it
has none), assigns itself as its controller, gives the commands in the order below, reads
back the train's speed, and then releases it (--release) or keeps it, answering its
heartbeat requests, until Ctrl-C releases it. With nothing scripted, at a terminal, keys drive
it: Up/Down (or + -) speed in steps of 5 km/h, Right/Left (or f r) direction, 0-9 toggle
F0-F9, Space emergency stop, q (or Esc, Ctrl-C) releases it; a status line shows what the
train answers (each key's command is read back). A train that leaves the network while it is
driven (on CAN its alias released) is reported (`train-lost`) and ends the run with status 5.

Examples:
  lcc-stream throttle 3                                   drive DCC 3 from the keyboard
  lcc-stream throttle 3 --speed 40 --forward --function 0=on --release
  lcc-stream throttle 1234 --long --estop --release --json
  lcc-stream throttle 3 --attach 05.01.01.01.22.02:reverse,f0 --release     a consist

", net::network_help(&[Outcome::TimedOut, Outcome::NotFound])))]
pub(crate) struct ThrottleArgs {
    /// The train's DCC address.
    #[arg(value_parser = clap::value_parser!(u32).range(1..=10239), required_unless_present = "train")]
    address: Option<u32>,
    /// The train by its Node ID instead of a search (a train node that does not answer Train
    /// Search, such as OpenMRN's Linux `train`, found by `events identify 01.01.00.00.00.00.03.03`).
    #[arg(long, value_name = "NODE_ID", value_parser = crate::args::node_id, conflicts_with_all = ["address", "long"])]
    train: Option<NodeId>,
    /// Ask for the long (14-bit) address.
    #[arg(long)]
    long: bool,
    /// Set the speed, in km/h (scale).
    #[arg(long, value_name = "KM_H")]
    speed: Option<f32>,
    /// Run forwards (the default).
    #[arg(long, conflicts_with = "reverse")]
    forward: bool,
    /// Run in reverse.
    #[arg(long)]
    reverse: bool,
    /// Switch a function, NUMBER=on|off (repeat it).
    #[arg(long = "function", value_name = "NUMBER=on|off", value_parser = parse_function)]
    functions: Vec<(u32, bool)>,
    /// Emergency stop.
    #[arg(long)]
    estop: bool,
    /// Add a train to the consist as a listener: NODE_ID, optionally with :reverse, :f0,
    /// :fn, :hide (comma-separated), e.g. 05.01.01.01.22.02:reverse,f0 (repeat it).
    #[arg(long = "attach", value_name = "NODE_ID[:FLAGS]", value_parser = parse_listener)]
    attach: Vec<(NodeId, u8)>,
    /// Take a listener out of the consist (repeat it).
    #[arg(long = "detach", value_name = "NODE_ID", value_parser = crate::args::node_id)]
    detach: Vec<NodeId>,
    /// Release the train when done (else keep it until Ctrl-C).
    #[arg(long)]
    release: bool,
    /// One JSON object per answer of the train.
    #[arg(long)]
    json: bool,
    #[command(flatten)]
    node_id: net::TransientId,
    #[command(flatten)]
    connect: ConnectArgs,
}

impl ThrottleArgs {
    /// Keys drive the train: nothing scripted, no `--json`, and stdin and stderr a terminal.
    fn interactive(&self) -> bool {
        use std::io::IsTerminal as _;
        let scripted = self.speed.is_some()
            || self.forward
            || self.reverse
            || !self.functions.is_empty()
            || self.estop
            || !self.attach.is_empty()
            || !self.detach.is_empty()
            || self.release;
        !scripted && !self.json && std::io::stdin().is_terminal() && std::io::stderr().is_terminal()
    }
}

fn parse_function(text: &str) -> Result<(u32, bool), String> {
    let bad = || format!("`{text}` is no function: NUMBER=on or NUMBER=off, e.g. 0=on");
    let (number, state) = text.split_once('=').ok_or_else(bad)?;
    let number: u32 = number.trim().parse().map_err(|_| bad())?;
    let on = match state {
        "on" | "1" => true,
        "off" | "0" => false,
        _ => return Err(bad()),
    };
    Ok((number, on))
}

fn parse_listener(text: &str) -> Result<(NodeId, u8), String> {
    let (node, flags) = text.split_once(':').unwrap_or((text, ""));
    let node = crate::args::node_id(node)?;
    let mut bits = 0;
    for flag in flags.split(',').filter(|f| !f.is_empty()) {
        bits |= match flag {
            "reverse" => LISTENER_REVERSE,
            "f0" => LISTENER_LINK_F0,
            "fn" => LISTENER_LINK_FN,
            "hide" => LISTENER_HIDE,
            _ => return Err(format!("`{flag}` is no listener flag: reverse, f0, fn, hide")),
        };
    }
    Ok((node, bits))
}

pub(crate) fn run(args: &ThrottleArgs) -> Result<ExitCode, String> {
    net::runtime()?.block_on(throttle(args))
}

/// One answer as `--json` prints it.
#[derive(Debug, Serialize)]
struct AnswerLine {
    /// The train's Node ID, or (known only by its CAN alias) `train_alias`.
    #[serde(skip_serializing_if = "Option::is_none")]
    train: Option<String>,
    #[serde(skip_serializing_if = "Option::is_none")]
    train_alias: Option<String>,
    event: &'static str,
    #[serde(skip_serializing_if = "Option::is_none")]
    set_speed: Option<f32>,
    #[serde(skip_serializing_if = "Option::is_none")]
    emergency_stop: Option<bool>,
    #[serde(skip_serializing_if = "Option::is_none")]
    other: Option<String>,
}

fn print(json: bool, event: &ThrottleEvent) {
    let (train, name, speed, estop, other, text) = match *event {
        ThrottleEvent::Assigned { train } => {
            (train, "assigned", None, None, None, "controlled by this throttle".into())
        }
        ThrottleEvent::AssignRefused { train, result } => {
            (train, "refused", None, None, Some(format!("0x{result:02X}")), format!("refused us (0x{result:02X})"))
        }
        ThrottleEvent::Speeds { train, set, emergency_stop, .. } => {
            let text = format!("speed {set}{}", if emergency_stop { ", emergency stop" } else { "" });
            (train, "speeds", Some(set.to_f32() * 3.6), Some(emergency_stop), None, text)
        }
        ThrottleEvent::ControllerLost { train, to } => {
            let to = Peer::of(to);
            (train, "controller-lost", None, None, Some(to.to_string()), format!("taken over by {to}"))
        }
        ThrottleEvent::TrainLost { train } => {
            (train, "train-lost", None, None, None, "is gone: it left the network (or this link was lost)".into())
        }
        ThrottleEvent::Rejected { train, code } => {
            let code = format!("0x{:04X}", code.0);
            (train, "rejected", None, None, Some(code.clone()), format!("rejected a command ({code})"))
        }
        ThrottleEvent::ListenerChanged { train, listener, attached, code } => {
            let listener = Peer::of(listener);
            let done = if attached { "attached" } else { "detached" };
            let text = match code {
                0 => format!("listener {listener} {done}"),
                code => format!("listener {listener} not {done} (0x{code:04X})"),
            };
            let name = if attached { "listener-attached" } else { "listener-detached" };
            (train, name, None, None, Some(format!("{listener} 0x{code:04X}")), text)
        }
        ThrottleEvent::HeartbeatRequested { train, deadline_secs } => {
            (train, "heartbeat", None, None, Some(deadline_secs.to_string()), "heartbeat answered".into())
        }
        _ => return,
    };
    let train = Peer::of(train);
    if json {
        let (alias, train_alias) = (train.node_field(), train.alias_field());
        let line =
            AnswerLine { train: alias, train_alias, event: name, set_speed: speed, emergency_stop: estop, other };
        outln!("{}", serde_json::to_string(&line).unwrap_or_default());
    } else if name != "heartbeat" {
        outln!("train {train}: {text}");
    }
}

async fn throttle(args: &ThrottleArgs) -> Result<ExitCode, String> {
    let mut interrupt = net::Interrupt::new()?;
    let options = |id| {
        let mut options = NodeOptions::new(id);
        options.node.snip = net::snip("throttle");
        options.node.throttle = Some(ThrottleConfig::default());
        options.node.events.listen = Listen::Everything;
        options
    };
    let node = match args.connect.join(&args.node_id, options).await {
        Ok(node) => node,
        Err(failure) => return Ok(net::fail("throttle", &failure)),
    };
    // Every wait before the train is driven is bounded (ANSWER_WAIT); then Ctrl-C releases.
    let result = drive(args, &node, &mut interrupt).await;
    node.close().await;
    Ok(ExitCode::from(match result {
        Ok(Outcome::Interrupted) => Outcome::Ok.status(),
        Ok(outcome) => outcome.status(),
        Err(failure) => return Ok(net::fail("throttle", &failure)),
    }))
}

/// Waits for the first event `pick` takes.
pub(crate) async fn wait_for<T>(events: &mut ThrottleEvents, pick: impl Fn(&ThrottleEvent) -> Option<T>) -> Option<T> {
    tokio::time::timeout(ANSWER_WAIT, async {
        while let Some(event) = events.next().await {
            if let Some(found) = pick(&event) {
                return Some(found);
            }
        }
        None
    })
    .await
    .ok()
    .flatten()
}

/// Why a train could not be taken.
#[derive(Debug)]
pub(crate) enum NotAcquired {
    /// Nobody answered the search, or the train did not answer the assign.
    TimedOut(String),
    /// The train refused this throttle as its controller.
    Refused(String),
    /// The node's connection.
    Net(Failure),
}

/// Finds the train of DCC `address` (long when `long`) by Train Search, allocating it, and
/// takes it as its controller: its Node ID.
pub(crate) async fn acquire(
    node: &Node,
    notices: &mut openlcb_tokio::EventNotices,
    events: &mut ThrottleEvents,
    address: u32,
    long: bool,
) -> Result<NodeId, NotAcquired> {
    // DCC, long when asked: allocate, exact, address only.
    let mut flags = SEARCH_ALLOCATE | SEARCH_EXACT | SEARCH_ADDRESS_ONLY;
    if long {
        flags |= 0x08 | 0x04;
    }
    let search = SearchQuery::event_for(address, flags)
        .ok_or_else(|| NotAcquired::TimedOut(format!("DCC {address} cannot be searched for")))?;
    node.identify(EventRole::Producer, search).await.map_err(|e| NotAcquired::Net(Failure::Net(e)))?;
    let found = tokio::time::timeout(ANSWER_WAIT, async {
        while let Some(notice) = notices.next().await {
            if let EventNotice::Identified { from, role: EventRole::Producer, range, state: Some(EventState::Valid) } =
                notice
                && range.is_single()
                && range.first() == search
            {
                return Some(from);
            }
        }
        None
    })
    .await
    .ok()
    .flatten();
    let Some(train) = found else {
        return Err(NotAcquired::TimedOut(format!("no train or command station answered for DCC {address}")));
    };
    assign(node, events, train).await.map(|()| train)
}

/// Takes `train` as its controller.
pub(crate) async fn assign(node: &Node, events: &mut ThrottleEvents, train: NodeId) -> Result<(), NotAcquired> {
    let me = node.node_id();
    send(node, train, TractionCommand::AssignController { flags: 0, node: me }).await.map_err(NotAcquired::Net)?;
    let assigned = wait_for(events, |e| match e {
        ThrottleEvent::Assigned { train: t } if *t == train => Some(true),
        ThrottleEvent::AssignRefused { train: t, .. } if *t == train => Some(false),
        _ => None,
    })
    .await;
    match assigned {
        Some(true) => Ok(()),
        Some(false) => Err(NotAcquired::Refused(format!("{train} refused this throttle as its controller"))),
        None => Err(NotAcquired::TimedOut(format!("{train} did not answer the assign"))),
    }
}

async fn drive(args: &ThrottleArgs, node: &Node, interrupt: &mut net::Interrupt) -> Result<Outcome, Failure> {
    let mut notices = node.event_notices().await.map_err(Failure::Net)?;
    let mut events = node.throttle_events().await.map_err(Failure::Net)?;
    let taken = match (args.train, args.address) {
        (Some(train), _) => assign(node, &mut events, train).await.map(|()| train),
        (None, Some(address)) => acquire(node, &mut notices, &mut events, address, args.long).await,
        (None, None) => return Ok(Outcome::Usage),
    };
    let train = match taken {
        Ok(train) => train,
        Err(NotAcquired::Net(failure)) => return Err(failure),
        Err(NotAcquired::Refused(why)) => {
            eprintln!("lcc-stream throttle: {why}");
            return Ok(Outcome::Error);
        }
        Err(NotAcquired::TimedOut(why)) => {
            eprintln!("lcc-stream throttle: {why}");
            return Ok(Outcome::TimedOut);
        }
    };
    match args.address {
        Some(address) => eprintln!("lcc-stream throttle: DCC {address} is {}", Peer::of(train)),
        None => eprintln!("lcc-stream throttle: driving {}", Peer::of(train)),
    }
    print(args.json, &ThrottleEvent::Assigned { train });
    let me = node.node_id();
    if args.interactive() {
        let outcome = crate::throttle_tty::drive(node, &mut events, train, interrupt).await?;
        if outcome != Outcome::NotFound {
            send(node, train, TractionCommand::ReleaseController { flags: 0, node: me }).await?;
            eprintln!("lcc-stream throttle: released {}", Peer::of(train));
            tokio::time::sleep(Duration::from_millis(100)).await;
        }
        return Ok(outcome);
    }
    for (listener, flags) in &args.attach {
        send(node, train, TractionCommand::AttachListener { flags: *flags, node: *listener }).await?;
        answer_of_listener(args.json, &mut events, train, *listener).await;
    }
    for listener in &args.detach {
        send(node, train, TractionCommand::DetachListener { flags: 0, node: *listener }).await?;
        answer_of_listener(args.json, &mut events, train, *listener).await;
    }
    if let Some(kmh) = args.speed {
        let magnitude = Speed::from_f32((kmh / 3.6).abs());
        let speed = if args.reverse { magnitude.reversed() } else { magnitude };
        send(node, train, TractionCommand::SetSpeed { speed, forwarded: false }).await?;
    } else if args.reverse || args.forward {
        let stopped = if args.reverse { Speed::ZERO_REVERSE } else { Speed::ZERO_FORWARD };
        send(node, train, TractionCommand::SetSpeed { speed: stopped, forwarded: false }).await?;
    }
    for (address, on) in &args.functions {
        let command = TractionCommand::SetFunction { address: *address, value: u16::from(*on), forwarded: false };
        send(node, train, command).await?;
    }
    if args.estop {
        send(node, train, TractionCommand::EmergencyStop { forwarded: false }).await?;
    }
    send(node, train, TractionCommand::QuerySpeeds).await?;
    let speeds = wait_for(&mut events, |e| match e {
        ThrottleEvent::Speeds { train: t, .. } if *t == train => Some(*e),
        ThrottleEvent::Rejected { train: t, .. } if *t == train => Some(*e),
        _ => None,
    })
    .await;
    if let Some(event) = speeds {
        print(args.json, &event);
    }
    let outcome = if args.release {
        Outcome::Ok
    } else {
        eprintln!("lcc-stream throttle: driving {train}; Ctrl-C releases it");
        loop {
            tokio::select! {
                event = events.next() => match event {
                    Some(event) => {
                        print(args.json, &event);
                        if matches!(event, ThrottleEvent::ControllerLost { train: t, .. } if t == train) {
                            return Ok(Outcome::Ok);
                        }
                        // Nothing to release: the train is gone; the exit status says so.
                        if matches!(event, ThrottleEvent::TrainLost { train: t } if t == train) {
                            eprintln!("lcc-stream throttle: {train} left the network");
                            return Ok(Outcome::NotFound);
                        }
                    }
                    None => break Outcome::ConnectionLost,
                },
                () = interrupt.wait() => break Outcome::Ok,
            }
        }
    };
    send(node, train, TractionCommand::ReleaseController { flags: 0, node: me }).await?;
    eprintln!("lcc-stream throttle: released {}", Peer::of(train));
    // The release is queued; give the driver a moment to send it before the node closes.
    tokio::time::sleep(Duration::from_millis(100)).await;
    Ok(outcome)
}

/// Prints the train's answer to an attach or detach of `listener`.
async fn answer_of_listener(json: bool, events: &mut ThrottleEvents, train: NodeId, listener: NodeId) {
    let answer = wait_for(events, |e| match e {
        ThrottleEvent::ListenerChanged { train: t, listener: l, .. } if *t == train && *l == listener => Some(*e),
        ThrottleEvent::Rejected { train: t, .. } if *t == train => Some(*e),
        _ => None,
    })
    .await;
    match answer {
        Some(event) => print(json, &event),
        None => eprintln!("lcc-stream throttle: {train} did not answer about listener {listener}"),
    }
}

pub(crate) async fn send(node: &Node, train: NodeId, command: TractionCommand) -> Result<(), Failure> {
    node.throttle_command(train, command).await.map_err(Failure::Net)
}
