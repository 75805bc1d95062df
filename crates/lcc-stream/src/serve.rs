//! `lcc-stream serve`: a node that serves memory spaces, a test partner for configuration
//! tools and firmware loaders: 0xFF (CDI), 0xFD (configuration), 0xFC/0xFB (ACDI, mirroring
//! SNIP) and 0xEF (firmware, saved to a file at each Unfreeze: the Unfreeze is refused, and
//! the loader told, when the image cannot be saved).

use std::io::Write as _;
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::sync::{Arc, Mutex};

use clap::Args;
use openlcb_stream::wire::ReplyCode;
use openlcb_stream::{AcceptPolicy, NodeId};
use openlcb_tokio::openlcb_node::{MemorySpace, SpaceError};
use openlcb_tokio::{
    DeclaredEvents, Error, EventNotice, EventNotices, FileSpace, MemoryEvent, MemoryServer, Node, NodeOptions,
    RamSpace, ReadOnlySpace, ServerEvents, SharedSpace,
};
use serde::Serialize;

use crate::board::{Board, Configured};
use crate::net::{self, ConnectArgs};
use crate::outcome::{Failure, Outcome, net_outcome};
use crate::peer::Peer;
use crate::printer::{Output, Printer};
use crate::reconnect::{self, RECONNECT_HELP, ReconnectArgs, Stop};
use crate::recv::{part_path, publish_blocking};

/// The Node ID `serve` uses unless told otherwise.
const DEFAULT_SERVER: &str = "05.01.01.01.22.F2";
/// The configuration space without `--config`: this many bytes in memory.
const DEFAULT_CONFIG_LEN: u32 = 256;
/// The largest firmware image taken (the size space 0xEF announces).
const FIRMWARE_MAX: u32 = 16 * 1024 * 1024;

/// The fields of `serve --json`.
macro_rules! serve_json_help {
    () => {
        "\
The board: every eventid setting of space 0xFD (the built-in CDI's Port(i).Event On and
Event Off) is produced and consumed as the configuration holds it; a tool's change takes
effect at its Update Complete (which `config set` and `write` send), and the node identifies
the new events at once. --input lines (`port 2 on`, or a setting's CDI key) produce them; a
report of one drives its output: a line on stdout, `port 3 off (EVENT from NODE)`, or with
--json {output, event, from or from_alias}.

--json prints one object when the node stops: node, config_bytes (the size of space 0xFD),
cdi_bytes, firmware (one object per image received: from (the loader's Node ID, or
from_alias, its CAN alias in hex, when only that is known), bytes, file, and error when it
could not be saved), user_info_changes (writes of space 0xFB), events_received (reports and
Learn Event messages of consumed events taken), events_dropped (those the node received but
had no room for: with events_received, every one that came), memory_events_dropped (the
memory server's notices lost the same way), result (the word of the exit status below) and,
on failure, error.

"
    };
}

/// Options of `lcc-stream serve`.
#[derive(Debug, Args)]
#[command(after_help = format!(
    "{}{RECONNECT_HELP}{}",
    serve_json_help!(),
    net::network_help(&[Outcome::Usage, Outcome::FileError])
))]
pub(crate) struct ServeArgs {
    /// This node's Node ID.
    #[arg(long, value_name = "NODE_ID", default_value = DEFAULT_SERVER)]
    node_id: NodeId,
    /// The CDI XML served as space 0xFF [default: a built-in CDI describing space 0xFD and
    /// the user name and description].
    #[arg(long, value_name = "FILE")]
    cdi: Option<PathBuf>,
    /// The configuration space 0xFD: this file (its size; writes go to it, each write
    /// command whole: a datagram's bytes in place, a Write Stream's by replacing the file
    /// once at its end) [default: 256 bytes in memory].
    #[arg(long, value_name = "FILE")]
    config: Option<PathBuf>,
    /// Where each firmware image (space 0xEF) is written at Unfreeze; by default
    /// `firmware-<node id>.bin` in the current folder. An image never replaces a file: it
    /// takes the first free name of FILE, FILE-1, FILE-2 ... (before the extension).
    #[arg(long, value_name = "FILE")]
    firmware_out: Option<PathBuf>,
    /// Replace the firmware file if it exists (every image is then written to FILE).
    #[arg(long)]
    force: bool,
    /// The SNIP user name (also space 0xFB).
    #[arg(long, value_name = "TEXT", default_value = "")]
    name: String,
    /// The SNIP user description (also space 0xFB).
    #[arg(long, value_name = "TEXT", default_value = "")]
    description: String,
    /// An event this node produces: EVENT_ID, or EVENT_ID/COUNT for a block (rounded up to
    /// the aligned block that holds them); repeatable. Identify messages are answered for
    /// them, and the PIP announces Event Exchange.
    #[arg(long, value_name = "EVENT_ID[/COUNT]", value_parser = crate::events::declared)]
    produces: Vec<DeclaredEvents>,
    /// An event this node consumes (forms as --produces); repeatable. Each report of one is
    /// printed on stderr as it comes; reports that come faster than stderr takes them are
    /// dropped, and a line says how many where they were lost.
    #[arg(long, value_name = "EVENT_ID[/COUNT]", value_parser = crate::events::declared)]
    consumes: Vec<DeclaredEvents>,
    /// Take no part in streams: every transfer goes by datagrams.
    #[arg(long)]
    no_streams: bool,
    /// Read input lines from this file or FIFO (`-`: stdin), each naming an event setting of
    /// space 0xFD as the board's input: `port 2 on` (the built-in CDI's ports), or the
    /// setting's CDI key. The event the setting holds is produced (a Producer/Consumer Event
    /// Report).
    #[arg(long, value_name = "FILE")]
    input: Option<PathBuf>,
    /// Print one JSON object (fields below) when the node stops, instead of text.
    #[arg(long)]
    json: bool,
    #[command(flatten)]
    connect: ConnectArgs,
    /// A lost hub: the spaces (the configuration file, the CDI, the events declared) stay as
    /// they are, and a new login serves them again.
    #[command(flatten)]
    reconnect: ReconnectArgs,
}

/// What `serve --json` prints.
#[derive(Debug, Default, Serialize)]
struct ServeReport {
    node: String,
    config_bytes: u32,
    cdi_bytes: u32,
    firmware: Vec<ImageReport>,
    user_info_changes: u64,
    events_received: u64,
    events_dropped: u64,
    memory_events_dropped: u64,
    result: &'static str,
    #[serde(skip_serializing_if = "Option::is_none")]
    error: Option<String>,
}

/// One firmware image received.
#[derive(Debug, Serialize)]
struct ImageReport {
    #[serde(skip_serializing_if = "Option::is_none")]
    from: Option<String>,
    #[serde(skip_serializing_if = "Option::is_none")]
    from_alias: Option<String>,
    bytes: u32,
    file: String,
    #[serde(skip_serializing_if = "Option::is_none")]
    error: Option<String>,
}

impl ImageReport {
    fn new(from: NodeId, bytes: u32, file: String, error: Option<String>) -> Self {
        let from = Peer::of(from);
        ImageReport { from: from.node_field(), from_alias: from.alias_field(), bytes, file, error }
    }
}

pub(crate) fn run(args: &ServeArgs) -> Result<ExitCode, String> {
    net::runtime()?.block_on(serve(args))
}

async fn serve(args: &ServeArgs) -> Result<ExitCode, String> {
    let mut interrupt = net::Interrupt::new()?;
    let spaces = match Spaces::open(args) {
        Ok(spaces) => spaces,
        Err(error) => {
            eprintln!("lcc-stream serve: {error}");
            return Ok(ExitCode::from(Outcome::FileError.status()));
        }
    };
    let mut options = NodeOptions::new(args.node_id);
    options.node.snip = net::snip("serve");
    options.node.snip.user_name.clone_from(&args.name);
    options.node.snip.user_description.clone_from(&args.description);
    if let Err(too_long) = options.node.snip.check() {
        eprintln!("lcc-stream serve: the {} is too long ({} bytes)", too_long.field.name(), too_long.len);
        return Ok(ExitCode::from(Outcome::Usage.status()));
    }
    options.node.streams_enabled = !args.no_streams;
    // Streams are for Memory Configuration only: any other is refused, not swallowed.
    options.node.stream.accept_policy = AcceptPolicy::RejectAll(ReplyCode::STREAMS_NOT_SUPPORTED);
    // The board's events as its configuration holds them, beside --produces and --consumes,
    // declared from the start so that the node announces them once.
    let mut configured = spaces.board.read(&mut *spaces.config.lock());
    options.node.events = configured.declarations(&args.produces, &args.consumes);
    let mut report = ServeReport {
        node: args.node_id.to_string(),
        config_bytes: spaces.config.len(),
        cdi_bytes: spaces.cdi.len(),
        ..ServeReport::default()
    };
    let image = spaces.image.clone();
    // On stderr even with --json: the name the first image will take.
    eprintln!("lcc-stream serve: firmware images go to {}", image.next_path().display());
    let connect = args.connect.node(options.clone());
    let mut node = tokio::select! {
        connected = connect => match connected {
            Ok(node) => node,
            Err(error) => return Ok(net::fail("serve", &Failure::Net(error))),
        },
        () = interrupt.wait() => return Ok(ExitCode::from(Outcome::Interrupted.status())),
    };
    let (mut events, mut notices) = match serve_on(&node, &spaces).await {
        Ok(started) => started,
        Err(error) => return Ok(net::fail("serve", &Failure::Net(error))),
    };
    // The reports go to stderr beside the loop, so that a slow terminal never holds it up.
    let mut printer = if args.json { None } else { Some(Printer::start(Output::Stderr)?) };
    // On stderr even with --json: scripts can wait for this line before starting a tool.
    eprintln!(
        "lcc-stream serve: node {} serving spaces 0xFF 0xFD 0xFC 0xFB 0xEF on {}",
        args.node_id,
        args.connect.addr()
    );
    for (verb, list) in [("produces", &args.produces), ("consumes", &args.consumes)] {
        for declared in list {
            eprintln!("lcc-stream serve: {verb} {}", crate::events::range_text(declared.range));
        }
    }
    if configured != Configured::default() && !args.json {
        eprintln!("lcc-stream serve: the board's events: {}", configured.text());
    }
    let mut input = match &args.input {
        Some(path) => Some(input_lines(path)?),
        None => None,
    };
    // Notices lost by the listeners of earlier connections.
    let mut dropped_before = 0;
    let status = loop {
        let lost = tokio::select! {
            event = events.next() => match event {
                Some(event) => {
                    // A tool's change takes effect when it says it is done (or the node restarts).
                    let applies = matches!(event, MemoryEvent::UpdateComplete { .. } | MemoryEvent::ResetRequested { .. });
                    let user_info = matches!(event, MemoryEvent::UserInfoChanged);
                    on_event(event, args, &image, &mut report);
                    // A new login after a lost hub keeps the user name and description a tool wrote.
                    if user_info && let Ok(snip) = node.own_snip().await {
                        options.node.snip = snip;
                    }
                    match applies {
                        true => match apply_board(&node, &spaces, args, &mut configured).await {
                            Ok(()) => continue,
                            Err(error) => error,
                        },
                        false => continue,
                    }
                }
                None => node.closed().await,
            },
            Some(notice) = notices.next() => {
                drive_outputs(&notice, &configured, args.json);
                on_notice(&notice, notices.dropped(), printer.as_mut(), &mut report);
                continue;
            }
            line = next_line(&mut input) => {
                match line {
                    Some(line) => produce(&node, &configured, &line).await,
                    None => input = None,
                }
                continue;
            }
            error = node.closed() => error,
            () = interrupt.wait() => {
                report.result = Outcome::Interrupted.word();
                break Outcome::Interrupted.status();
            }
        };
        // What the node had handed over already is printed too.
        while let Some(notice) = notices.try_next() {
            on_notice(&notice, notices.dropped(), printer.as_mut(), &mut report);
        }
        let stopped = if reconnect::is_lost(&lost) {
            let attempt = || async {
                // A new login declares the board's events as they are now.
                let mut options = options.clone();
                options.node.events = configured.declarations(&args.produces, &args.consumes);
                let node = args.connect.join_again(options).await?;
                let started = serve_on(&node, &spaces).await.map_err(|error| error.to_string())?;
                Ok::<_, String>((node, started))
            };
            match args.reconnect.rejoin("serve", args.connect.addr(), &lost, &mut interrupt, attempt).await {
                Ok((again, started)) => {
                    dropped_before += notices.dropped();
                    (node, (events, notices)) = (again, started);
                    if let Some(printer) = printer.as_mut() {
                        printer.new_listener();
                    }
                    reconnect::say_rejoined("serve", args.connect.addr(), &node).await;
                    continue;
                }
                Err(stop) => stop,
            }
        } else {
            Stop::GaveUp
        };
        if stopped == Stop::Interrupted {
            report.result = Outcome::Interrupted.word();
            break Outcome::Interrupted.status();
        }
        (report.result, report.error) = (net_outcome(&lost).word(), Some(lost.to_string()));
        break net_outcome(&lost).status();
    };
    // What the node had handed over already is printed too.
    while let Some(notice) = notices.try_next() {
        on_notice(&notice, notices.dropped(), printer.as_mut(), &mut report);
    }
    report.events_dropped = dropped_before + notices.dropped();
    if let Ok(stats) = node.stats().await {
        report.memory_events_dropped = stats.memory_events_dropped;
    }
    node.close().await;
    let reports = match printer {
        Some(mut printer) => {
            printer.node_lost(notices.dropped());
            let (printed, dropped, unsaid) = (printer.printed(), printer.dropped(), printer.unsaid());
            printer.finish(if unsaid > 0 { vec![dropped_reports(unsaid)] } else { Vec::new() }).await;
            format!(" ({printed} event reports printed, {dropped} dropped)")
        }
        None => String::new(),
    };
    if args.json {
        outln!("{}", serde_json::to_string(&report).map_err(|e| e.to_string())?);
    } else if let Some(error) = &report.error {
        eprintln!("lcc-stream serve: {error}{reports}");
    } else {
        eprintln!("lcc-stream serve: interrupted{reports}");
    }
    Ok(ExitCode::from(status))
}

/// Declares the board's events as space 0xFD holds them now, beside `--produces` and
/// `--consumes`, when they differ from `configured`, and says what they are.
async fn apply_board(node: &Node, spaces: &Spaces, args: &ServeArgs, configured: &mut Configured) -> Result<(), Error> {
    let now = spaces.board.read(&mut *spaces.config.lock());
    if now == *configured {
        return Ok(());
    }
    node.set_events(now.declarations(&args.produces, &args.consumes)).await?;
    if !args.json {
        eprintln!("lcc-stream serve: the board's events: {}", now.text());
    }
    *configured = now;
    Ok(())
}

/// The lines of `--input` (`-`: stdin), read beside the node; the channel ends with the input.
/// A thread of its own reads them (not the runtime's blocking pool, which would hold the
/// tool's exit until the input ends).
fn input_lines(path: &Path) -> Result<tokio::sync::mpsc::Receiver<String>, String> {
    use std::io::BufRead as _;
    let (sink, lines) = tokio::sync::mpsc::channel(64);
    let reader: Box<dyn std::io::Read + Send> = if path == Path::new("-") {
        Box::new(std::io::stdin())
    } else {
        Box::new(std::fs::File::open(path).map_err(|e| format!("cannot open the input {}: {e}", path.display()))?)
    };
    std::thread::spawn(move || {
        for line in std::io::BufReader::new(reader).lines() {
            let Ok(line) = line else { break };
            if !line.trim().is_empty() && sink.blocking_send(line).is_err() {
                break;
            }
        }
    });
    Ok(lines)
}

/// The next input line; never, without `--input` or once it has ended.
async fn next_line(input: &mut Option<tokio::sync::mpsc::Receiver<String>>) -> Option<String> {
    match input {
        Some(lines) => lines.recv().await,
        None => std::future::pending().await,
    }
}

/// Produces the event of the setting `line` names.
async fn produce(node: &Node, configured: &Configured, line: &str) {
    let event = match configured.input(line) {
        Ok(event) => event,
        Err(why) => return eprintln!("lcc-stream serve: input `{}`: {why}", line.trim()),
    };
    match node.send_event(event, Vec::new()).await {
        Ok(()) => eprintln!("lcc-stream serve: input `{}`: produced {}", line.trim(), crate::events::event_text(event)),
        Err(error) => eprintln!("lcc-stream serve: input `{}`: {error}", line.trim()),
    }
}

/// One output driven, as `serve --json` prints it.
#[derive(Debug, Serialize)]
struct OutputLine<'a> {
    output: &'a str,
    event: String,
    #[serde(skip_serializing_if = "Option::is_none")]
    from: Option<String>,
    #[serde(skip_serializing_if = "Option::is_none")]
    from_alias: Option<String>,
}

/// Drives (prints on stdout) every output a consumed report names.
fn drive_outputs(notice: &EventNotice, configured: &Configured, json: bool) {
    let EventNotice::Report { from, event, .. } = notice else { return };
    let peer = Peer::of(*from);
    for output in configured.outputs(*event) {
        if json {
            let line = OutputLine {
                output,
                event: event.to_string(),
                from: peer.node_field(),
                from_alias: peer.alias_field(),
            };
            outln!("{}", serde_json::to_string(&line).unwrap_or_default());
        } else {
            outln!("{output} ({event} from {peer})");
        }
    }
}

/// Serves `spaces` on `node` (a new connection's), and listens to its event reports.
async fn serve_on(node: &Node, spaces: &Spaces) -> Result<(ServerEvents, EventNotices), Error> {
    let events = node.set_memory_server(spaces.server()).await?;
    Ok((events, node.event_notices().await?))
}

/// Prints a consumed event's report (or a Learn Event) on stderr as it comes, with `printer`
/// (none with `--json`); `node_lost` is the listener's count of lost notices.
fn on_notice(notice: &EventNotice, node_lost: u64, printer: Option<&mut Printer>, report: &mut ServeReport) {
    let text = match notice {
        EventNotice::Report { from, event, payload } if payload.is_empty() => {
            format!("event {} from {}", crate::events::event_text(*event), Peer::of(*from))
        }
        EventNotice::Report { from, event, payload } => {
            let hex: String = payload.iter().map(|b| format!("{b:02X}")).collect();
            format!("event {} from {}, payload {hex}", crate::events::event_text(*event), Peer::of(*from))
        }
        EventNotice::Learn { from, event } => {
            format!("learn event {} from {} (ignored)", crate::events::event_text(*event), Peer::of(*from))
        }
        _ => return,
    };
    report.events_received += 1;
    if let Some(printer) = printer {
        printer.node_lost(node_lost);
        printer.report(format!("lcc-stream serve: {text}\n"), dropped_reports);
    }
}

/// The line saying that `dropped` event reports were not printed.
fn dropped_reports(dropped: u64) -> String {
    format!("lcc-stream serve: … {dropped} event reports dropped (they came faster than they could be printed)\n")
}

/// Says on stderr what the server was asked to do and did.
fn on_event(event: MemoryEvent, args: &ServeArgs, image: &Image, report: &mut ServeReport) {
    let say = |text: String| {
        if !args.json {
            eprintln!("lcc-stream serve: {text}");
        }
    };
    match event {
        MemoryEvent::Frozen { by } => say(format!("frozen for a firmware upgrade by {}", Peer::of(by))),
        MemoryEvent::Unfrozen { by, image_len } => {
            let file = image.last_saved().map(|p| p.display().to_string()).unwrap_or_default();
            say(format!("firmware of {image_len} bytes from {} written to {file}", Peer::of(by)));
            report.firmware.push(ImageReport::new(by, image_len, file, None));
        }
        MemoryEvent::UpgradeRefused { by, code } => {
            let why = image.last_error().unwrap_or_else(|| "the transfer was aborted".to_string());
            say(format!("Unfreeze of {} refused with 0x{:04X}, still frozen: {why}", Peer::of(by), code.0));
            let file = image.next_path().display().to_string();
            report.firmware.push(ImageReport::new(by, 0, file, Some(why)));
        }
        MemoryEvent::UserInfoChanged => {
            report.user_info_changes += 1;
            say("user name and description changed (space 0xFB)".to_string());
        }
        MemoryEvent::UpdateComplete { by } => say(format!("update complete, said {}", Peer::of(by))),
        MemoryEvent::ResetRequested { by } => say(format!(
            "reset asked for by {}: the node started again (streams ended, Initialization Complete sent)",
            Peer::of(by)
        )),
        MemoryEvent::FactoryResetRequested { by } => {
            say(format!("factory reset asked for by {} (ignored)", Peer::of(by)))
        }
        _ => {}
    }
}

/// `firmware-<node id>.bin` in the current folder (the Node ID's digits, as `recv` names files).
fn default_firmware_path(node: NodeId) -> PathBuf {
    PathBuf::from(format!("firmware-{}.bin", node.to_string().replace('.', "")))
}

/// `out`, or with `force` unset the first of `out`, `out-1`, `out-2` ... that is free
/// (the number before the extension).
fn free_path(out: &Path, force: bool) -> PathBuf {
    if force || !out.exists() {
        return out.to_path_buf();
    }
    let stem = out.file_stem().unwrap_or_default().to_string_lossy();
    let extension = out.extension().map(|e| format!(".{}", e.to_string_lossy())).unwrap_or_default();
    (1u32..)
        .map(|n| out.with_file_name(format!("{stem}-{n}{extension}")))
        .find(|candidate| !candidate.exists())
        .unwrap_or_else(|| out.to_path_buf())
}

/// Writes `bytes` through `<path>.part`, synced, then publishes it under `path` in one step
/// (a rename or a link), so `path` never holds part of them, even if the process is killed:
/// replacing a file only with `replace`.
fn save_whole(path: &Path, bytes: &[u8], replace: bool) -> std::io::Result<()> {
    let part = part_path(path);
    let written = std::fs::File::create(&part).and_then(|mut file| {
        if let Ok(meta) = std::fs::metadata(path) {
            // A file replaced keeps its permissions.
            file.set_permissions(meta.permissions())?;
        }
        file.write_all(bytes)?;
        file.sync_all()?;
        if replace { std::fs::rename(&part, path) } else { publish_blocking(&part, path) }
    });
    if written.is_err() {
        let _ = std::fs::remove_file(&part);
    }
    written
}

/// Fails unless a file can be created beside `path` (the `.part` an image is written to).
fn check_writable(path: &Path) -> Result<(), String> {
    let part = part_path(path);
    std::fs::File::create(&part)
        .and_then(|_| std::fs::remove_file(&part))
        .map_err(|e| format!("cannot write firmware images to {}: {e}", path.display()))
}

/// The spaces `serve` hands to its node, kept across connections: each connection's memory
/// server is handed the same spaces.
struct Spaces {
    cdi: ReadOnlySpace,
    /// The board the CDI describes: its event settings.
    board: Board,
    config: SharedSpace<ConfigSpace>,
    image: Image,
}

impl Spaces {
    fn open(args: &ServeArgs) -> Result<Spaces, String> {
        let config = match &args.config {
            Some(path) => ConfigSpace::open(path)?,
            None => ConfigSpace::Memory(RamSpace::new(DEFAULT_CONFIG_LEN)),
        };
        let xml = match &args.cdi {
            Some(path) => std::fs::read_to_string(path).map_err(|e| format!("cannot read {}: {e}", path.display()))?,
            None => builtin_cdi(config.len()),
        };
        let (cdi, board) = (ReadOnlySpace::cdi(&xml), Board::new(&xml));
        let firmware_out = args.firmware_out.clone().unwrap_or_else(|| default_firmware_path(args.node_id));
        check_writable(&firmware_out)?;
        Ok(Spaces { cdi, board, config: SharedSpace::new(config), image: Image::new(firmware_out, args.force) })
    }

    /// A memory server for a new connection, over these spaces. A firmware image that was
    /// being received when the last connection was lost is dropped (that upgrade ended).
    fn server(&self) -> MemoryServer {
        let mut image = self.image.clone();
        image.discard();
        MemoryServer::new()
            .with_space(0xFF, self.cdi.clone())
            .with_space(0xFD, self.config.clone())
            .with_space(0xEF, image)
            .with_acdi()
    }
}

/// The bytes of space 0xFD the built-in settings take (the rest are described as spare
/// bytes): a 32-byte string, a mode (1 byte, mapped), a delay (2 bytes, 0..1000), a float,
/// and 4 ports of 33 bytes (a name, two events, a pulse length).
const SETTINGS_LEN: u32 = 32 + 1 + 2 + 4 + 4 * PORT_LEN;
/// One port of the built-in CDI.
const PORT_LEN: u32 = 16 + 8 + 8 + 1;

/// A CDI describing this node: its identification, the ACDI user space and `config_len`
/// bytes of space 0xFD (settings of every type the CDI has, then spare bytes; a space too
/// small for the settings is all spare bytes).
fn builtin_cdi(config_len: u32) -> String {
    let snip = net::snip("serve");
    let (settings, spare) = match config_len.checked_sub(SETTINGS_LEN) {
        Some(spare) => (BUILTIN_SETTINGS, spare),
        None => ("", config_len),
    };
    let spare = if spare > 0 {
        format!(
            r#"<group replication="{spare}"><name>Spare</name><repname>Byte</repname><int size="1"><name>Value</name></int></group>"#
        )
    } else {
        String::new()
    };
    format!(
        r#"<?xml version="1.0" encoding="utf-8"?>
<cdi xmlns:xsi="http://www.w3.org/2001/XMLSchema-instance" xsi:noNamespaceSchemaLocation="http://openlcb.org/schema/cdi/1/4/cdi.xsd">
<identification><manufacturer>{}</manufacturer><model>{}</model><hardwareVersion>{}</hardwareVersion><softwareVersion>{}</softwareVersion></identification>
<acdi/>
<segment space="251" origin="1"><name>User identification</name>
<string size="63"><name>User name</name></string>
<string size="64"><name>User description</name></string>
</segment>
<segment space="253" origin="0"><name>Configuration</name><description>{config_len} bytes of storage</description>
{settings}{spare}
</segment>
</cdi>
"#,
        snip.manufacturer, snip.model, snip.hardware_version, snip.software_version
    )
}

/// The settings of the built-in CDI ([`SETTINGS_LEN`] bytes).
const BUILTIN_SETTINGS: &str = r#"<string size="32"><name>Label</name><description>A name for this node's purpose</description></string>
<int size="1"><name>Mode</name><default>0</default><map><relation><property>0</property><value>Idle</value></relation><relation><property>1</property><value>Active</value></relation><relation><property>2</property><value>Test</value></relation></map></int>
<int size="2"><name>Delay (ms)</name><min>0</min><max>1000</max><default>100</default></int>
<float size="4"><name>Scale</name><min>0</min><max>100</max><default>1</default></float>
<group replication="4"><name>Port</name><repname>Port 1</repname>
<string size="16"><name>Name</name></string>
<eventid><name>Event On</name></eventid>
<eventid><name>Event Off</name></eventid>
<int size="1"><name>Pulse (x10 ms)</name><min>0</min><max>100</max></int>
</group>
"#;

/// Space 0xFD: a file ([`FileSpace`]: each write command reaches it whole, once, so that it
/// holds the space as it was before or after each command, even when `serve` is killed), or
/// bytes in memory.
enum ConfigSpace {
    File(FileSpace),
    Memory(RamSpace),
}

impl ConfigSpace {
    fn open(path: &Path) -> Result<ConfigSpace, String> {
        FileSpace::open(path).map(ConfigSpace::File).map_err(|e| match e.kind() {
            std::io::ErrorKind::InvalidData => format!("{} must hold 1 byte to 4 GiB", path.display()),
            _ => format!("cannot use {}: {e}", path.display()),
        })
    }

    fn space(&mut self) -> &mut dyn MemorySpace {
        match self {
            ConfigSpace::File(file) => file,
            ConfigSpace::Memory(bytes) => bytes,
        }
    }
}

impl MemorySpace for ConfigSpace {
    fn len(&self) -> u32 {
        match self {
            ConfigSpace::File(file) => file.len(),
            ConfigSpace::Memory(bytes) => bytes.len(),
        }
    }
    fn read_only(&self) -> bool {
        false
    }
    fn read(&mut self, address: u32, buf: &mut [u8]) -> Result<usize, SpaceError> {
        self.space().read(address, buf)
    }
    fn write(&mut self, address: u32, data: &[u8]) -> Result<(), SpaceError> {
        self.space().write(address, data)
    }
    fn commit(&mut self) -> Result<(), SpaceError> {
        self.space().commit()
    }
}

/// Space 0xEF: the image being received, saved when its Unfreeze comes; shared with the
/// loop that reports where it went.
#[derive(Debug, Clone)]
struct Image(Arc<Mutex<ImageState>>);

#[derive(Debug)]
struct ImageState {
    bytes: Vec<u8>,
    out: PathBuf,
    force: bool,
    /// Where the last image went, or why it could not be saved.
    last: Option<Result<PathBuf, String>>,
}

impl Image {
    fn new(out: PathBuf, force: bool) -> Image {
        Image(Arc::new(Mutex::new(ImageState { bytes: Vec::new(), out, force, last: None })))
    }

    fn state(&self) -> Result<std::sync::MutexGuard<'_, ImageState>, SpaceError> {
        self.0.lock().map_err(|_| SpaceError::Failed(openlcb_stream::wire::ErrorCode::PERMANENT))
    }

    /// The file the next image will be written to.
    fn next_path(&self) -> PathBuf {
        self.state().map(|s| free_path(&s.out, s.force)).unwrap_or_default()
    }

    fn last_saved(&self) -> Option<PathBuf> {
        self.state().ok()?.last.clone()?.ok()
    }

    fn last_error(&self) -> Option<String> {
        self.state().ok()?.last.clone()?.err()
    }
}

impl MemorySpace for Image {
    fn len(&self) -> u32 {
        FIRMWARE_MAX
    }
    fn read_only(&self) -> bool {
        false
    }
    /// The image goes to a file at Unfreeze: nothing can be read back over the network (a
    /// read got zeros where no byte was written).
    fn write_only(&self) -> bool {
        true
    }
    fn read(&mut self, address: u32, buf: &mut [u8]) -> Result<usize, SpaceError> {
        let state = self.state()?;
        let bytes = &state.bytes;
        let n = buf.len().min(FIRMWARE_MAX.saturating_sub(address) as usize);
        let (buf, at) = (buf.get_mut(..n).unwrap_or_default(), address as usize);
        buf.fill(0);
        if let Some(held) = bytes.get(at..) {
            let m = held.len().min(n);
            if let (Some(to), Some(from)) = (buf.get_mut(..m), held.get(..m)) {
                to.copy_from_slice(from);
            }
        }
        Ok(n)
    }
    fn write(&mut self, address: u32, data: &[u8]) -> Result<(), SpaceError> {
        let mut state = self.state()?;
        let bytes = &mut state.bytes;
        let at = address as usize;
        let end = at.saturating_add(data.len()).min(FIRMWARE_MAX as usize);
        if bytes.len() < end {
            bytes.resize(end, 0);
        }
        if let (Some(to), Some(from)) = (bytes.get_mut(at..end), data.get(..end.saturating_sub(at))) {
            to.copy_from_slice(from);
        }
        Ok(())
    }
    fn complete(&mut self, len: u32) -> Result<(), SpaceError> {
        let mut state = self.state()?;
        state.bytes.resize(len as usize, 0);
        let path = free_path(&state.out, state.force);
        let saved = save_whole(&path, &state.bytes, state.force);
        state.last = Some(saved.as_ref().map(|()| path.clone()).map_err(|e| format!("{}: {e}", path.display())));
        state.bytes = Vec::new();
        saved.map_err(|_| SpaceError::Failed(openlcb_stream::wire::ErrorCode::PERMANENT))
    }
    fn discard(&mut self) {
        if let Ok(mut state) = self.state() {
            state.bytes = Vec::new();
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn image_space_keeps_what_was_written_and_reads_zeros_past_it() {
        let dir = std::env::temp_dir().join(format!("lcc-stream-image-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let out = dir.join("image.bin");
        let _ = std::fs::remove_file(&out);
        let mut image = Image::new(out.clone(), false);
        image.write(4, &[1, 2, 3]).unwrap();
        let mut buf = [0xAA; 8];
        assert_eq!(image.read(2, &mut buf).unwrap(), 8);
        assert_eq!(buf, [0, 0, 1, 2, 3, 0, 0, 0]);
        image.complete(7).unwrap();
        assert_eq!(std::fs::read(&out).unwrap(), [0, 0, 0, 0, 1, 2, 3]);
        // The next image takes a fresh name; a completed image leaves an empty buffer.
        image.complete(2).unwrap();
        assert_eq!(std::fs::read(dir.join("image-1.bin")).unwrap(), [0, 0]);
        assert_eq!(std::fs::read(&out).unwrap(), [0, 0, 0, 0, 1, 2, 3], "never overwritten");
        std::fs::remove_dir_all(&dir).unwrap();
    }

    /// Every byte of space 0xFD is described, once, whatever its size.
    #[test]
    fn builtin_cdi_describes_the_configuration_space() {
        for config_len in [1, 100, SETTINGS_LEN, SETTINGS_LEN + 1, DEFAULT_CONFIG_LEN, 4096] {
            let layout = openlcb_cdi::Layout::parse(&builtin_cdi(config_len)).unwrap();
            let config = layout.spans().into_iter().find(|s| s.space == 0xFD).unwrap();
            assert_eq!((config.address, config.len), (0, config_len), "{config_len}");
            let bytes: u32 = layout.entries().filter(|e| e.space == 0xFD).map(|e| e.size).sum();
            assert_eq!(bytes, config_len, "no gaps ({config_len})");
        }
        let layout = openlcb_cdi::Layout::parse(&builtin_cdi(DEFAULT_CONFIG_LEN)).unwrap();
        let kinds: Vec<&str> = layout.entries().map(|e| e.kind.word()).collect();
        for kind in ["int", "float", "string", "eventid"] {
            assert!(kinds.contains(&kind), "{kind}");
        }
        assert!(layout.find("Configuration.Port(3).Event Off").next().is_some());
        assert!(!layout.find("Configuration.Mode").next().unwrap().map.is_empty());
    }
}
