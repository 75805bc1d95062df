//! `lcc-stream clock`: the layout's fast clock (Broadcast Time). Run a generator, follow a
//! clock as a consumer, or drive a generator on the bus (set, start, stop, rate).

use std::io::IsTerminal as _;
use std::process::ExitCode;
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};

use clap::{Args, Subcommand, ValueEnum};
use openlcb_stream::AcceptPolicy;
use openlcb_stream::wire::ReplyCode;
use openlcb_tokio::openlcb_node::broadcast_time::{
    ClockChange, ClockConfig, ClockEvent, ClockId, ClockMessage, ClockRole, ClockSet, ClockState, ClockTime,
    ConsumerConfig, GeneratorConfig, Rate, SyncTail,
};
use openlcb_tokio::{EventNotice, EventNotices, EventState, Listen, Node, NodeOptions};
use serde::Serialize;

use crate::net::{self, ConnectArgs};
use crate::outcome::{Failure, Outcome, net_outcome};
use crate::peer::Peer;
use crate::reconnect::{self, RECONNECT_HELP, ReconnectArgs, Stop};

/// How long a command waits for the generator to confirm it: its echo of a set comes at
/// once, its synchronization sequence (which confirms start and stop) 3 s after the last.
const CONFIRM_WAIT: Duration = Duration::from_secs(5);
/// How long an answer other than the one asked for waits for one that agrees (see
/// [`set_confirmed`]).
const CONTRARY_WAIT: Duration = Duration::from_millis(500);

/// How often the live line of a terminal is redrawn.
const LIVE_REFRESH: Duration = Duration::from_millis(250);

#[derive(Debug, Args)]
#[command(args_conflicts_with_subcommands = true)]
#[command(after_help = format!("{}{}{}", "\
Clocks: default-fast (01.01.00.00.01.00), default-realtime, alternate-1, alternate-2, or a
unique ID of six hex bytes. Rates are multiples of 0.25 from -512 to 511.75 (negative runs
backwards). The generator answers queries, set commands, start and stop from any node, and
reports the time as minutes begin (at most once a real minute, always at midnight and for a
minute a consumer asked for).

Examples:
  lcc-stream clock --rate 4 --time 06:00 --date 1956-07-04     a fast clock for the session
  lcc-stream clock --follow                                    what the fascia clocks show
  lcc-stream clock set --time 08:30                            any node's generator
  lcc-stream clock stop; lcc-stream clock rate 8; lcc-stream clock start

A generator or a follower that loses the hub joins it again; a generator goes on from the
time it had (run on for the time away).

", RECONNECT_HELP, net::network_help(&[Outcome::TimedOut])))]
pub(crate) struct ClockArgs {
    #[command(subcommand)]
    command: Option<ClockCommand>,
    #[command(flatten)]
    run: RunArgs,
}

/// The clock a command is about, and how it joins the network.
#[derive(Debug, Args)]
struct Joining {
    /// The clock: default-fast, default-realtime, alternate-1, alternate-2 or six hex bytes.
    #[arg(long, default_value = "default-fast", value_parser = parse_clock)]
    clock: ClockId,
    #[command(flatten)]
    node_id: net::TransientId,
    #[command(flatten)]
    connect: ConnectArgs,
}

/// Running a generator, or following a clock.
#[derive(Debug, Args)]
struct RunArgs {
    /// Follow the clock as a consumer (a clock face) instead of generating it.
    #[arg(long)]
    follow: bool,
    /// The rate it starts at.
    #[arg(long, default_value = "1", value_parser = parse_rate, conflicts_with = "follow")]
    rate: Rate,
    /// The time it starts at, HH:MM [default: now, UTC].
    #[arg(long, value_parser = parse_time, conflicts_with = "follow")]
    time: Option<(u8, u8)>,
    /// The date it starts at, YYYY-MM-DD [default: today, UTC].
    #[arg(long, value_parser = parse_date, conflicts_with = "follow")]
    date: Option<(u16, u8, u8)>,
    /// Start stopped (a set or `clock start` starts it).
    #[arg(long, conflicts_with = "follow")]
    stopped: bool,
    /// Refuse set, start and stop commands from the bus.
    #[arg(long, conflicts_with = "follow")]
    refuse_sets: bool,
    /// When the synchronization sequence's last report (the next minute) goes out:
    /// when-valid, as the standard's sentence and OpenMRN read it, or at-once, as OpenLcbCLib
    /// and OlcbChecker's bt10, bt20 and bt80 expect.
    #[arg(long, value_enum, default_value_t = Tail::WhenValid, conflicts_with = "follow")]
    sync_tail: Tail,
    #[command(flatten)]
    reconnect: ReconnectArgs,
    /// One JSON object per change: time (seconds since start), clock, change (minute, set,
    /// rate, started, stopped, synchronized), clock_time, rate, running, and from (the Node ID
    /// of the node that caused it) or, when only its CAN alias is known, from_alias.
    #[arg(long)]
    json: bool,
    #[command(flatten)]
    joining: Joining,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
enum Tail {
    WhenValid,
    AtOnce,
}

#[derive(Debug, Subcommand)]
enum ClockCommand {
    /// Set a generator's time, date (with its year) or rate; waits for its echo.
    Set {
        /// The time of day, HH:MM.
        #[arg(long, value_parser = parse_time)]
        time: Option<(u8, u8)>,
        /// The date, YYYY-MM-DD (Set Year and Set Date).
        #[arg(long, value_parser = parse_date)]
        date: Option<(u16, u8, u8)>,
        /// The rate.
        #[arg(long, value_parser = parse_rate)]
        rate: Option<Rate>,
        #[command(flatten)]
        joining: Joining,
    },
    /// Start a generator; waits for its synchronization sequence to say it runs.
    Start {
        #[command(flatten)]
        joining: Joining,
    },
    /// Stop a generator; waits for its synchronization sequence to say it stands.
    Stop {
        #[command(flatten)]
        joining: Joining,
    },
    /// Set a generator's rate; waits for its echo.
    Rate {
        /// The rate, e.g. 4, 0.25 or -1.
        #[arg(value_parser = parse_rate, allow_hyphen_values = true)]
        rate: Rate,
        #[command(flatten)]
        joining: Joining,
    },
}

pub(crate) fn parse_clock(text: &str) -> Result<ClockId, String> {
    text.parse().map_err(|_| {
        format!("`{text}` is no clock: default-fast, default-realtime, alternate-1, alternate-2 or six hex bytes")
    })
}

pub(crate) fn parse_rate(text: &str) -> Result<Rate, String> {
    text.parse().map_err(|e| format!("`{text}`: {e}"))
}

pub(crate) fn parse_time(text: &str) -> Result<(u8, u8), String> {
    let bad = || format!("`{text}` is no time of day: HH:MM, 00:00 to 23:59");
    let (hour, minute) = text.split_once(':').ok_or_else(bad)?;
    let (hour, minute): (u8, u8) = (hour.parse().map_err(|_| bad())?, minute.parse().map_err(|_| bad())?);
    (hour < 24 && minute < 60).then_some((hour, minute)).ok_or_else(bad)
}

fn parse_date(text: &str) -> Result<(u16, u8, u8), String> {
    let bad = || format!("`{text}` is no date: YYYY-MM-DD, years 0 to 4095");
    let mut parts = text.splitn(3, '-');
    let mut next = || parts.next().ok_or_else(bad);
    let (year, month, day) = (next()?, next()?, next()?);
    let (year, month, day): (u16, u8, u8) =
        (year.parse().map_err(|_| bad())?, month.parse().map_err(|_| bad())?, day.parse().map_err(|_| bad())?);
    ClockTime::new(year, month, day, 0, 0, 0).map(|_| (year, month, day)).ok_or_else(bad)
}

pub(crate) fn run(args: &ClockArgs) -> Result<ExitCode, String> {
    net::runtime()?.block_on(clock(args))
}

async fn clock(args: &ClockArgs) -> Result<ExitCode, String> {
    let mut interrupt = net::Interrupt::new()?;
    let Some(command) = &args.command else { return run_clock(&args.run, &mut interrupt).await };
    let (ClockCommand::Set { joining, .. }
    | ClockCommand::Start { joining }
    | ClockCommand::Stop { joining }
    | ClockCommand::Rate { joining, .. }) = command;
    let sets: Vec<ClockSet> = match command {
        ClockCommand::Set { time, date, rate, .. } => {
            let mut sets = Vec::new();
            if let Some((year, month, day)) = date {
                sets.extend([ClockSet::Year(*year), ClockSet::Date { month: *month, day: *day }]);
            }
            if let Some((hour, minute)) = time {
                sets.push(ClockSet::Time { hour: *hour, minute: *minute });
            }
            sets.extend(rate.map(ClockSet::Rate));
            if sets.is_empty() {
                eprintln!("lcc-stream clock set: give --time, --date or --rate");
                return Ok(ExitCode::from(Outcome::Usage.status()));
            }
            sets
        }
        ClockCommand::Start { .. } => vec![ClockSet::Start],
        ClockCommand::Stop { .. } => vec![ClockSet::Stop],
        ClockCommand::Rate { rate, .. } => vec![ClockSet::Rate(*rate)],
    };
    let clock = joining.clock;
    let options = |id| {
        let mut options = node_options(id, "clock");
        options.node.clocks = vec![controlling_consumer(clock)];
        options.node.events.listen = Listen::Everything;
        options
    };
    let node = match joining.connect.join(&joining.node_id, options).await {
        Ok(node) => node,
        Err(failure) => return Ok(net::fail("clock", &failure)),
    };
    let result = tokio::select! {
        result = drive(&node, clock, &sets) => result,
        () = interrupt.wait() => Ok(ExitCode::from(Outcome::Interrupted.status())),
    };
    node.close().await;
    result
}

/// Sends each of `sets` to the generator of `clock` and waits for it to confirm.
async fn drive(node: &Node, clock: ClockId, sets: &[ClockSet]) -> Result<ExitCode, String> {
    let mut notices = match node.event_notices().await {
        Ok(notices) => notices,
        Err(error) => return Ok(net::fail("clock", &Failure::Net(error))),
    };
    for set in sets {
        match set_confirmed(node, &mut notices, clock, *set).await {
            Ok(words) => eprintln!("lcc-stream clock: {words}"),
            Err(Unconfirmed::Net(failure)) => return Ok(net::fail("clock", &failure)),
            Err(Unconfirmed::NoGenerator(words)) => {
                eprintln!("lcc-stream clock: {words}");
                return Ok(ExitCode::from(Outcome::TimedOut.status()));
            }
        }
    }
    Ok(ExitCode::SUCCESS)
}

/// Why a set was not confirmed.
pub(crate) enum Unconfirmed {
    /// The node could not send it, or stopped.
    Net(Failure),
    /// No generator confirmed it in time: the words for that.
    NoGenerator(String),
}

/// Sends `set` to the generator of `clock` (by `node`, a consumer of it that controls) and
/// waits for its confirmation in `notices` (taken before): the words of what it did.
pub(crate) async fn set_confirmed(
    node: &Node,
    notices: &mut EventNotices,
    clock: ClockId,
    set: ClockSet,
) -> Result<String, Unconfirmed> {
    node.set_clock(clock, set).await.map_err(|e| Unconfirmed::Net(Failure::Net(e)))?;
    let asked = set_text(set);
    let mut deadline = tokio::time::Instant::now() + CONFIRM_WAIT;
    // An answer other than what was asked may be one the generator sent before it took the
    // set (its synchronization, crossing the set on the bus): it stands only if no answer
    // that agrees follows, within CONTRARY_WAIT for a set the generator echoes at once, and
    // within the whole wait for start and stop (confirmed by its next synchronization).
    let echoed = !matches!(set, ClockSet::Start | ClockSet::Stop);
    let mut contrary = None;
    let confirmed = loop {
        let notice = match tokio::time::timeout_at(deadline, notices.next()).await {
            Ok(Some(notice)) => notice,
            Ok(None) => return Err(Unconfirmed::Net(Failure::Net(openlcb_tokio::Error::Closed))),
            Err(_) => break contrary,
        };
        if let Some((from, message)) = confirmation(clock, set, &notice) {
            if message_text(message) == asked {
                break Some((from, message));
            }
            if echoed && contrary.is_none() {
                deadline = deadline.min(tokio::time::Instant::now() + CONTRARY_WAIT);
            }
            contrary = Some((from, message));
        }
    };
    let Some((from, message)) = confirmed else {
        return Err(Unconfirmed::NoGenerator(format!(
            "no generator of {clock} confirmed {} within {} s (is one on the bus, and does it take sets?)",
            set_text(set),
            CONFIRM_WAIT.as_secs()
        )));
    };
    let got = message_text(message);
    let from = Peer::of(from);
    Ok(if asked == got {
        format!("{clock} {got} (generator {from})")
    } else {
        format!("{clock} asked {asked}, the generator {from} made it {got}")
    })
}

/// A consumer of `clock` that may set it (set, start, stop and rate commands to its
/// generator), listening to every event (the generator's answers).
pub(crate) fn controlling_consumer(clock: ClockId) -> ClockConfig {
    let mut consumer = ConsumerConfig::default();
    consumer.controls = true;
    let mut config = ClockConfig::consumer(clock);
    config.role = ClockRole::Consumer(consumer);
    config
}

/// The generator's confirmation of `set` in `notice`: the echo of a set (a report of the
/// same kind), or for start and stop its synchronization sequence's first message.
fn confirmation(clock: ClockId, set: ClockSet, notice: &EventNotice) -> Option<(openlcb_stream::NodeId, ClockMessage)> {
    let (from, event, identified) = match notice {
        EventNotice::Report { from, event, .. } => (*from, *event, false),
        EventNotice::Identified { from, range, state: Some(EventState::Valid), .. } if range.is_single() => {
            (*from, range.first(), true)
        }
        _ => return None,
    };
    let (id, suffix) = ClockId::of(event)?;
    let message = ClockMessage::decode(suffix)?;
    let matches = match (set, message) {
        (ClockSet::Time { .. }, ClockMessage::ReportTime { .. }) => !identified,
        (ClockSet::Date { .. }, ClockMessage::ReportDate { .. })
        | (ClockSet::Year(_), ClockMessage::ReportYear(_))
        | (ClockSet::Rate(_), ClockMessage::ReportRate(_)) => !identified,
        (ClockSet::Start | ClockSet::Stop, ClockMessage::Start | ClockMessage::Stop) => identified,
        _ => false,
    };
    (id == clock && matches).then_some((from, message))
}

fn set_text(set: ClockSet) -> String {
    match set {
        ClockSet::Time { hour, minute } => format!("time {hour:02}:{minute:02}"),
        ClockSet::Date { month, day } => format!("date --{month:02}-{day:02}"),
        ClockSet::Year(year) => format!("year {year}"),
        ClockSet::Rate(rate) => format!("rate {rate}"),
        ClockSet::Start => "running".into(),
        ClockSet::Stop => "stopped".into(),
    }
}

fn message_text(message: ClockMessage) -> String {
    match message {
        ClockMessage::ReportTime { hour, minute } => set_text(ClockSet::Time { hour, minute }),
        ClockMessage::ReportDate { month, day } => set_text(ClockSet::Date { month, day }),
        ClockMessage::ReportYear(year) => set_text(ClockSet::Year(year)),
        ClockMessage::ReportRate(rate) => set_text(ClockSet::Rate(rate)),
        ClockMessage::Start => "running".into(),
        _ => "stopped".into(),
    }
}

fn node_options(id: openlcb_stream::NodeId, command: &str) -> NodeOptions {
    let mut options = NodeOptions::new(id);
    options.node.snip = net::snip(command);
    options.node.stream.accept_policy = AcceptPolicy::RejectAll(ReplyCode::BUFFER_UNAVAILABLE);
    options
}

/// One change as `--json` prints it.
#[derive(Debug, Serialize)]
struct ChangeLine {
    time: f64,
    clock: String,
    change: &'static str,
    clock_time: String,
    rate: String,
    running: bool,
    #[serde(skip_serializing_if = "Option::is_none")]
    from: Option<String>,
    #[serde(skip_serializing_if = "Option::is_none")]
    from_alias: Option<String>,
}

/// The clock `args` asks for: a consumer, or a generator starting at `start` (its time, rate
/// and whether it runs).
fn clock_config(args: &RunArgs, start: Option<(ClockTime, Rate, bool)>) -> Result<ClockConfig, String> {
    let clock = args.joining.clock;
    if args.follow {
        return Ok(ClockConfig::consumer(clock));
    }
    let mut generator = GeneratorConfig::default();
    match start {
        Some(state) => (generator.start, generator.rate, generator.running) = state,
        None => {
            let now = SystemTime::now().duration_since(UNIX_EPOCH).map_or(0, |d| d.as_secs() as i64);
            let today = ClockTime::from_unix_seconds(now);
            let (year, month, day) = args.date.unwrap_or((today.year, today.month, today.day));
            let (hour, minute) = args.time.unwrap_or((today.hour, today.minute));
            generator.start = ClockTime::new(year, month, day, hour, minute, 0).ok_or("no such date")?;
            generator.rate = args.rate;
            generator.running = !args.stopped;
        }
    }
    generator.accept_sets = !args.refuse_sets;
    generator.sync_tail = match args.sync_tail {
        Tail::WhenValid => SyncTail::WhenValid,
        Tail::AtOnce => SyncTail::AtOnce,
    };
    Ok(ClockConfig::generator(clock, generator))
}

/// Runs a generator (or follows the clock) until Ctrl-C, joining the hub again when it is
/// lost: a generator goes on from the time it had.
async fn run_clock(args: &RunArgs, interrupt: &mut net::Interrupt) -> Result<ExitCode, String> {
    let clock = args.joining.clock;
    let command = if args.follow { "clock --follow" } else { "clock" };
    let options = |id, config: &ClockConfig| {
        let mut options = node_options(id, command);
        options.node.clocks = vec![config.clone()];
        options
    };
    let first = clock_config(args, None)?;
    let mut node = match args.joining.connect.join(&args.joining.node_id, |id| options(id, &first)).await {
        Ok(node) => node,
        Err(failure) => return Ok(net::fail("clock", &failure)),
    };
    let what = if args.follow { "following" } else { "generating" };
    eprintln!("lcc-stream clock: {what} {clock} as {} (Ctrl-C stops)", node.node_id());
    let live = !args.json && std::io::stdout().is_terminal();
    let started = Instant::now();
    let mut refresh = tokio::time::interval(LIVE_REFRESH);
    // The clock's state as last seen, and when.
    let mut last: Option<(ClockState, Instant)> = None;
    let outcome = 'joined: loop {
        let mut events = match node.clock_events().await {
            Ok(events) => events,
            Err(error) => break net_outcome(&error),
        };
        let lost = loop {
            tokio::select! {
                event = events.next() => {
                    let Some(event) = event else { break node.closed().await };
                    match node.clock(clock).await {
                        Ok(Some(state)) => {
                            print_change(args.json, live, started, &event, &state);
                            last = Some((state, Instant::now()));
                        }
                        _ => break node.closed().await,
                    }
                }
                _ = refresh.tick() => match node.clock(clock).await {
                    Ok(Some(state)) => {
                        if live {
                            out!("\r\x1b[K{}", state_text(clock, &state));
                        }
                        last = Some((state, Instant::now()));
                    }
                    _ => break node.closed().await,
                },
                () = interrupt.wait() => break 'joined Outcome::Interrupted,
                error = node.closed() => break error,
            }
        };
        if live {
            outln!("");
        }
        if !reconnect::is_lost(&lost) {
            eprintln!("lcc-stream clock: {lost}");
            break net_outcome(&lost);
        }
        // A generator goes on from where it was: its last state, run on for the time away.
        let resumed = last.filter(|_| !args.follow).map(|(state, seen)| {
            let away = i64::try_from(seen.elapsed().as_millis()).unwrap_or(i64::MAX);
            let fast = if state.running { away.saturating_mul(i64::from(state.rate.quarters())) / 4 } else { 0 };
            (state.time.advanced(fast), state.rate, state.running)
        });
        let config = clock_config(args, resumed)?;
        let id = node.node_id();
        let attempt = || args.joining.connect.join_again(options(id, &config));
        match args.reconnect.rejoin("clock", args.joining.connect.addr(), &lost, interrupt, attempt).await {
            Ok(again) => {
                node = again;
                reconnect::say_rejoined("clock", args.joining.connect.addr(), &node).await;
            }
            Err(Stop::Interrupted) => break Outcome::Interrupted,
            Err(Stop::GaveUp) => break net_outcome(&lost),
        }
    };
    if live {
        outln!("");
    }
    node.close().await;
    Ok(ExitCode::from(match outcome {
        Outcome::Interrupted => Outcome::Ok.status(),
        other => other.status(),
    }))
}

/// `1956-07-04 06:04:12  running at 4x` (or `stopped`, and `waiting for the generator`).
pub(crate) fn state_text(clock: ClockId, state: &ClockState) -> String {
    if !state.synchronized {
        return format!("{clock}: waiting for its generator");
    }
    let running = if state.running { format!("running at {}x", state.rate) } else { "stopped".into() };
    format!("{clock}: {}  {running}", state.time)
}

fn print_change(json: bool, live: bool, started: Instant, event: &ClockEvent, state: &ClockState) {
    let (change, said) = match event.change {
        ClockChange::Minute(_) => ("minute", None),
        ClockChange::Set(t) => ("set", Some(format!("set to {t}"))),
        ClockChange::Rate(rate) => ("rate", Some(format!("rate {rate}x"))),
        ClockChange::Started => ("started", Some("started".to_string())),
        ClockChange::Stopped => ("stopped", Some("stopped".to_string())),
        ClockChange::Synchronized => ("synchronized", Some("synchronized with its generator".to_string())),
        _ => ("other", None),
    };
    let peer = event.from.map(Peer::of);
    let from = peer.map(|p| p.to_string());
    if json {
        let line = ChangeLine {
            time: started.elapsed().as_secs_f64(),
            clock: event.clock.to_string(),
            change,
            clock_time: state.time.to_string(),
            rate: state.rate.to_string(),
            running: state.running,
            from: peer.and_then(Peer::node_field),
            from_alias: peer.and_then(Peer::alias_field),
        };
        outln!("{}", serde_json::to_string(&line).unwrap_or_default());
    } else if live {
        if let Some(said) = said {
            let by = from.map(|n| format!(" by {n}")).unwrap_or_default();
            outln!("\r\x1b[K{}: {said}{by}", event.clock);
        }
    } else {
        let by = from.map(|n| format!(" (by {n})")).unwrap_or_default();
        outln!("{}  [{change}{by}]", state_text(event.clock, state));
    }
}
