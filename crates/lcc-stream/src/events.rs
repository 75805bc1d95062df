//! `lcc-stream events`: watch the event reports on the bus, send one, and ask who produces
//! and consumes what. Also the `--produces`/`--consumes` arguments of `serve` and the names
//! of the well-known events, which `monitor` prints too.

use std::process::ExitCode;
use std::time::Duration;

use clap::{Args, Subcommand};
use openlcb_stream::{AcceptPolicy, EventId, NodeId, wire::ReplyCode};
use openlcb_tokio::{DeclaredEvents, EventNotice, EventRange, EventRole, EventState, Listen, Node, NodeOptions};
use serde::Serialize;

use crate::net::{self, ConnectArgs};
use crate::peer::Peer;
use crate::reconnect::{RECONNECT_HELP, ReconnectArgs};
use crate::watch::{self, Format};

/// Event IDs with a meaning fixed by the standards, printed by name.
const WELL_KNOWN: [(u64, &str); 10] = [
    (0x0100_0000_0000_FFFF, "Emergency Off"),
    (0x0100_0000_0000_FFFE, "Clear Emergency Off"),
    (0x0100_0000_0000_FFFD, "Emergency Stop"),
    (0x0100_0000_0000_FFFC, "Clear Emergency Stop"),
    (0x0100_0000_0000_FFF0, "Power supply brownout"),
    (0x0100_0000_0000_FFF1, "Node power brownout"),
    (0x0100_0000_0000_FE00, "Node ident button"),
    (0x0101_0000_0000_0201, "Duplicate Node ID Detected"),
    (0x0101_0000_0000_0601, "Firmware corrupted"),
    (0x0101_0000_0000_0602, "Firmware upgrade requested by a hardware switch"),
];

/// The name of a well-known event.
pub(crate) fn well_known(event: EventId) -> Option<&'static str> {
    WELL_KNOWN.iter().find(|(id, _)| *id == event.as_raw()).map(|(_, name)| *name)
}

/// The forms [`event_id`] accepts.
const EVENT_ID_FORMS: &str =
    "eight hex bytes: 05.01.01.01.22.00.00.01, 05:01:01:01:22:00:00:01, 0501010122000001 or 0x0501010122000001";

/// An Event ID in any of the forms people paste (dots, colons, bare hex, `0x` hex).
pub(crate) fn event_id(text: &str) -> Result<EventId, String> {
    text.parse().map_err(|_| format!("expected {EVENT_ID_FORMS}"))
}

/// `EVENT_ID` or `EVENT_ID/COUNT` (the COUNT IDs from EVENT_ID, rounded up to the aligned
/// block that holds them), all in state unknown.
pub(crate) fn declared(text: &str) -> Result<DeclaredEvents, String> {
    let (first, count) = match text.split_once('/') {
        Some((first, count)) => {
            let count = parse_count(count).ok_or_else(|| format!("`{count}` is not a count of Event IDs"))?;
            (first, count)
        }
        None => (text, 1),
    };
    let first = event_id(first)?;
    let range =
        EventRange::covering(first, count).ok_or_else(|| format!("{first}/{count} is no range of Event IDs"))?;
    Ok(DeclaredEvents { range, state: EventState::Unknown })
}

/// A count in decimal or `0x` hex.
fn parse_count(text: &str) -> Option<u64> {
    match text.strip_prefix("0x").or_else(|| text.strip_prefix("0X")) {
        Some(hex) => u64::from_str_radix(hex, 16).ok(),
        None => text.parse().ok(),
    }
}

/// `05.01.01.01.22.00.00.01`, or `05.01.01.01.22.00.01.00..=05.01.01.01.22.00.01.FF` for a
/// block; a well-known event with its name.
pub(crate) fn range_text(range: EventRange) -> String {
    if !range.is_single() {
        return format!("{}..={}", range.first(), range.last());
    }
    event_text(range.first())
}

/// An Event ID, with its name if it is well known.
pub(crate) fn event_text(event: EventId) -> String {
    match (well_known(event), clock_event(event)) {
        (Some(name), _) => format!("{event} ({name})"),
        (None, Some(clock)) => format!("{event} ({clock})"),
        (None, None) => event.to_string(),
    }
}

/// An event of one of the well-known Broadcast Time clocks in words: `default-fast: Report
/// Time 06:01`.
fn clock_event(event: EventId) -> Option<String> {
    use openlcb_tokio::openlcb_node::broadcast_time::{ClockId, ClockMessage};
    let (clock, suffix) = ClockId::of(event)?;
    ClockId::WELL_KNOWN.iter().find(|(id, _)| *id == clock)?;
    let what = match ClockMessage::decode(suffix)? {
        ClockMessage::ReportTime { hour, minute } => format!("Report Time {hour:02}:{minute:02}"),
        ClockMessage::ReportDate { month, day } => format!("Report Date {month:02}-{day:02}"),
        ClockMessage::ReportYear(year) => format!("Report Year {year}"),
        ClockMessage::ReportRate(rate) => format!("Report Rate {rate}"),
        ClockMessage::SetTime { hour, minute } => format!("Set Time {hour:02}:{minute:02}"),
        ClockMessage::SetDate { month, day } => format!("Set Date {month:02}-{day:02}"),
        ClockMessage::SetYear(year) => format!("Set Year {year}"),
        ClockMessage::SetRate(rate) => format!("Set Rate {rate}"),
        ClockMessage::Query => "Query".into(),
        ClockMessage::Stop => "Stop".into(),
        ClockMessage::Start => "Start".into(),
        ClockMessage::DateRollover => "Date Rollover".into(),
    };
    Some(format!("{clock}: {what}"))
}

/// Options of `lcc-stream events`.
#[derive(Debug, Args)]
#[command(after_help = format!("{}{}", "\
Event IDs are eight hex bytes: 05.01.01.01.22.00.00.01, 05:01:01:01:22:00:00:01,
0501010122000001 or 0x0501010122000001. Well-known events are printed by name.

", net::network_help(&[])))]
pub(crate) struct EventsArgs {
    #[command(subcommand)]
    command: EventsCommand,
}

/// How every `events` command joins the network.
#[derive(Debug, Args)]
struct Joining {
    #[command(flatten)]
    node_id: net::TransientId,
    #[command(flatten)]
    connect: ConnectArgs,
}

#[derive(Debug, Subcommand)]
enum EventsCommand {
    /// Print every event report on the bus as it comes, with its sender's Node ID and SNIP
    /// name, until Ctrl-C.
    ///
    /// A sender known only by its CAN alias is shown as that alias (`alias 4FF`). Each
    /// report is printed the moment it arrives. Names are looked up beside the stream (a
    /// few senders at a time, each for at most --snip-timeout): a report whose sender's name
    /// is not known yet is printed without it, and later reports of that sender carry it
    /// once the sender has answered. A sender that does not answer in time stays unnamed.
    ///
    /// Reports that come faster than the output takes them are dropped and counted, never
    /// lost without a word: a line `… 312 reports dropped (the bus is faster than this
    /// terminal)` stands where they were, and the end says on stderr how many were printed
    /// and how many dropped.
    ///
    /// A lost hub: the counts and the names learnt are kept, and a new login (same Node ID)
    /// watches on. While the hub was away nothing was seen.
    #[command(after_help = format!("{RECONNECT_HELP}{}", net::network_help(&[])))]
    Watch {
        /// One JSON object per report: time (seconds since start), event, name (well-known
        /// events; else null), from (the sender's Node ID) or, when only its CAN alias is
        /// known, from_alias (the alias in hex, "4FF") instead, from_name (its SNIP user
        /// name, else its model; null if not known yet) and payload (hex). Where reports
        /// were dropped, {time, dropped} (how many since the last such object); at the end
        /// {time, reports, printed, dropped} (reports = printed + dropped; dropped also
        /// counts the rare other event messages the node had no room for).
        #[arg(long)]
        json: bool,
        /// Seconds a sender has to answer the SNIP request that names it.
        #[arg(long, value_name = "SECS", default_value_t = 5, value_parser = crate::args::positive::<u64>)]
        snip_timeout: u64,
        #[command(flatten)]
        joining: Joining,
        #[command(flatten)]
        reconnect: ReconnectArgs,
    },
    /// Send one Producer/Consumer Event Report.
    Send {
        /// The event.
        #[arg(value_name = "EVENT_ID", value_parser = event_id)]
        event: EventId,
        /// Bytes after the Event ID (a report with payload), in hex, e.g. 01020304.
        #[arg(long, value_name = "HEX", value_parser = parse_hex)]
        payload: Option<Payload>,
        #[command(flatten)]
        joining: Joining,
    },
    /// Who produces and consumes what: Identify Events to every node, or Identify Producer
    /// and Identify Consumer for one event; the answers as a table.
    Identify {
        /// Ask about this event only.
        #[arg(value_name = "EVENT_ID", value_parser = event_id)]
        event: Option<EventId>,
        /// Seconds of quiet after the last answer before the table is complete.
        #[arg(long, value_name = "SECS", default_value_t = 1.0)]
        wait: f64,
        /// One JSON object per answer: node (its Node ID) or, when only its CAN alias is
        /// known, alias (in hex, "4FF") instead, role (producer/consumer), event (the first ID),
        /// last (the last ID of a range, else equal to event), name, state (valid, invalid,
        /// unknown; null for a range).
        #[arg(long)]
        json: bool,
        #[command(flatten)]
        joining: Joining,
    },
}

/// The bytes of `--payload` (one argument, not a list of them).
#[derive(Debug, Clone, PartialEq, Eq)]
struct Payload(Vec<u8>);

/// Bytes written as hex digits (spaces, dots and colons between bytes are allowed).
fn parse_hex(text: &str) -> Result<Payload, String> {
    let digits: String = text.chars().filter(|c| !matches!(c, ' ' | '.' | ':')).collect();
    let digits = digits.strip_prefix("0x").unwrap_or(&digits);
    if !digits.len().is_multiple_of(2) || !digits.bytes().all(|c| c.is_ascii_hexdigit()) {
        return Err("expected an even number of hex digits, e.g. 01020304".into());
    }
    (0..digits.len() / 2)
        .map(|i| u8::from_str_radix(digits.get(2 * i..2 * i + 2).unwrap_or_default(), 16).map_err(|e| e.to_string()))
        .collect::<Result<_, _>>()
        .map(Payload)
}

/// The bytes of a report's payload in hex (empty: none), as `--payload` takes them.
pub(crate) fn parse_payload(text: &str) -> Result<Vec<u8>, String> {
    if text.trim().is_empty() {
        return Ok(Vec::new());
    }
    parse_hex(text.trim()).map(|p| p.0)
}

pub(crate) fn run(args: &EventsArgs) -> Result<ExitCode, String> {
    net::runtime()?.block_on(events(args))
}

async fn events(args: &EventsArgs) -> Result<ExitCode, String> {
    let mut interrupt = net::Interrupt::new()?;
    let (EventsCommand::Watch { joining, .. }
    | EventsCommand::Send { joining, .. }
    | EventsCommand::Identify { joining, .. }) = &args.command;
    let snip_timeout = match &args.command {
        EventsCommand::Watch { snip_timeout, .. } => Some(openlcb_stream::Duration::from_secs(*snip_timeout)),
        _ => None,
    };
    let options = |id| {
        let mut options = NodeOptions::new(id);
        options.node.snip = net::snip("events");
        options.node.stream.accept_policy = AcceptPolicy::RejectAll(ReplyCode::BUFFER_UNAVAILABLE);
        options.node.events.listen = Listen::Everything;
        if let Some(timeout) = snip_timeout {
            options.node.snip_timeout = timeout;
            options.node.max_snip_requests = watch::LOOKUPS;
        }
        options
    };
    let node = match joining.connect.join(&joining.node_id, options).await {
        Ok(node) => node,
        Err(failure) => return Ok(net::fail("events", &failure)),
    };
    let result = match &args.command {
        EventsCommand::Watch { json, reconnect, .. } => {
            let format = if *json { Format::Json } else { Format::Text };
            // It closes the node it ends with.
            return watch::watch(node, &joining.connect, options, reconnect, format, &mut interrupt).await;
        }
        EventsCommand::Send { event, payload, .. } => {
            match node.send_event(*event, payload.clone().map(|p| p.0).unwrap_or_default()).await {
                Ok(()) => {
                    eprintln!("lcc-stream events: sent {}", event_text(*event));
                    Ok(ExitCode::SUCCESS)
                }
                Err(error) => Ok(net::fail("events send", &crate::outcome::Failure::Net(error))),
            }
        }
        EventsCommand::Identify { event, wait, json, .. } => identify(&node, *event, *wait, *json).await,
    };
    node.close().await;
    result
}

/// One answer as `identify --json` prints it.
#[derive(Debug, Serialize, PartialEq, Eq, PartialOrd, Ord)]
struct IdentifiedLine {
    #[serde(skip)]
    peer: Peer,
    #[serde(skip_serializing_if = "Option::is_none")]
    node: Option<String>,
    #[serde(skip_serializing_if = "Option::is_none")]
    alias: Option<String>,
    role: &'static str,
    event: String,
    last: String,
    name: Option<&'static str>,
    state: Option<&'static str>,
}

/// `producer` or `consumer`.
pub(crate) fn role_word(role: EventRole) -> &'static str {
    match role {
        EventRole::Producer => "producer",
        EventRole::Consumer => "consumer",
    }
}

/// `valid`, `invalid` or `unknown`.
pub(crate) fn state_word(state: EventState) -> &'static str {
    match state {
        EventState::Valid => "valid",
        EventState::Invalid => "invalid",
        EventState::Unknown => "unknown",
    }
}

impl IdentifiedLine {
    fn new(from: NodeId, role: EventRole, range: EventRange, state: Option<EventState>) -> Self {
        let peer = Peer::of(from);
        IdentifiedLine {
            peer,
            node: peer.node_field(),
            alias: peer.alias_field(),
            role: role_word(role),
            event: range.first().to_string(),
            last: range.last().to_string(),
            name: well_known(range.first()).filter(|_| range.is_single()),
            state: state.map(state_word),
        }
    }

    /// The table row: node, role, event or range, state.
    fn text(&self) -> String {
        let events =
            if self.event == self.last { self.event.clone() } else { format!("{}..={}", self.event, self.last) };
        let events = match self.name {
            Some(name) => format!("{events} ({name})"),
            None => events,
        };
        format!("{:17}  {:8}  {:48}  {}", self.peer.to_string(), self.role, events, self.state.unwrap_or("range"))
    }
}

async fn identify(node: &Node, event: Option<EventId>, wait: f64, json: bool) -> Result<ExitCode, String> {
    let mut notices = node.event_notices().await.map_err(|e| e.to_string())?;
    // Who is there first, so that the answers name their senders by Node ID.
    let _ = node.discover(Duration::from_millis(500), 1024).await;
    let asked = match event {
        Some(event) => {
            async {
                node.identify(EventRole::Producer, event).await?;
                node.identify(EventRole::Consumer, event).await
            }
            .await
        }
        None => node.identify_events(None).await,
    };
    if let Err(error) = asked {
        return Ok(net::fail("events identify", &crate::outcome::Failure::Net(error)));
    }
    let quiet = Duration::from_secs_f64(wait.clamp(0.05, 30.0));
    let mut lines = Vec::new();
    while let Ok(Some(notice)) = tokio::time::timeout(quiet, notices.next()).await {
        if let EventNotice::Identified { from, role, range, state } = notice {
            lines.push(IdentifiedLine::new(from, role, range, state));
        }
    }
    lines.sort();
    lines.dedup();
    if json {
        lines.iter().for_each(net::print_json);
    } else {
        outln!("{:17}  {:8}  {:48}  STATE", "NODE", "ROLE", "EVENT");
        for line in &lines {
            outln!("{}", line.text());
        }
        eprintln!("{} answer(s)", lines.len());
    }
    Ok(ExitCode::SUCCESS)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn event_ids_parse_in_every_pasted_form() {
        let dotted = event_id("05.01.01.01.22.00.00.01").unwrap();
        for form in ["05:01:01:01:22:00:00:01", "0501010122000001", "0x0501010122000001"] {
            assert_eq!(event_id(form).unwrap(), dotted, "{form}");
        }
        assert!(event_id("05.01.01.01.22.00").unwrap_err().contains("0x0501010122000001"));
    }

    #[test]
    fn declared_events_are_single_or_blocks() {
        let single = declared("05.01.01.01.22.00.00.01").unwrap();
        assert!(single.range.is_single());
        let block = declared("05.01.01.01.22.00.01.00/256").unwrap();
        assert_eq!(range_text(block.range), "05.01.01.01.22.00.01.00..=05.01.01.01.22.00.01.FF");
        assert_eq!(declared("05.01.01.01.22.00.01.00/0x10").unwrap().range.bits(), 4);
        assert!(declared("05.01.01.01.22.00.01.00/0").is_err());
        assert!(declared("05.01.01.01.22.00.01.00/x").is_err());
    }

    #[test]
    fn clock_events_of_the_well_known_clocks_are_in_words() {
        assert_eq!(
            event_text(EventId(0x0101_0000_0100_0601)),
            "01.01.00.00.01.00.06.01 (default-fast: Report Time 06:01)"
        );
        assert_eq!(event_text(EventId(0x0101_0000_0102_C010)), "01.01.00.00.01.02.C0.10 (alternate-1: Set Rate 4)");
        assert_eq!(
            event_text(EventId(0x0101_0000_0101_F003)),
            "01.01.00.00.01.01.F0.03 (default-realtime: Date Rollover)"
        );
        // A reserved code, and a clock that is not well known, stay plain.
        assert_eq!(event_text(EventId(0x0101_0000_0100_1800)), "01.01.00.00.01.00.18.00");
        assert_eq!(event_text(EventId(0x0501_0101_2200_0601)), "05.01.01.01.22.00.06.01");
    }

    #[test]
    fn well_known_events_are_named() {
        assert_eq!(event_text(EventId(0x0101_0000_0000_0201)), "01.01.00.00.00.00.02.01 (Duplicate Node ID Detected)");
        assert_eq!(event_text(EventId(0x0100_0000_0000_FFFD)), "01.00.00.00.00.00.FF.FD (Emergency Stop)");
        assert_eq!(event_text(EventId(0x0501_0101_2200_0001)), "05.01.01.01.22.00.00.01");
    }

    #[test]
    fn payloads_are_hex() {
        assert_eq!(parse_hex("01020304"), Ok(Payload(vec![1, 2, 3, 4])));
        assert_eq!(parse_hex("01 02:0A"), Ok(Payload(vec![1, 2, 10])));
        assert!(parse_hex("123").is_err());
        assert!(parse_hex("zz").is_err());
    }

    #[test]
    fn identified_rows_show_ranges_and_states() {
        let node = NodeId::new(0x05_01_01_01_22_01).unwrap();
        let range = EventRange::covering(EventId(0x0501_0101_2201_0100), 256).unwrap();
        let row = IdentifiedLine::new(node, EventRole::Producer, range, None);
        assert_eq!(
            (row.event.as_str(), row.last.as_str(), row.state),
            ("05.01.01.01.22.01.01.00", "05.01.01.01.22.01.01.FF", None)
        );
        assert!(row.text().contains("05.01.01.01.22.01.01.00..=05.01.01.01.22.01.01.FF  range"));
        let single =
            IdentifiedLine::new(node, EventRole::Consumer, EventRange::single(EventId(1)), Some(EventState::Valid));
        assert!(single.text().contains("consumer") && single.text().ends_with("valid"));
    }
}
