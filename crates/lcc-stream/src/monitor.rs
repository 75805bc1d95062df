//! `lcc-stream monitor`: a decoded view of a CAN segment, live or from a saved trace. It only
//! listens: Node IDs are learnt from what nodes send anyway (AMD, Initialization Complete,
//! Verified Node ID), never asked for.
//!
//! The decoding is the libraries': GridConnect, headers and reassembly of `openlcb-can`, the
//! stream messages of `openlcb-stream`, Memory Configuration, SNIP and PIP of
//! `openlcb-node`. A frame that does not decode is printed raw, and the monitor goes on.

use std::collections::HashMap;
use std::path::PathBuf;
use std::process::ExitCode;

use clap::{Args, ValueEnum};
use openlcb_can::gridconnect::{self, GridConnectDecoder};
use openlcb_can::{CanFrame, CanHeader, FrameKind, FramePosition, NodeAlias, Reassembler, ReassemblyKey, event_report};
use openlcb_stream::wire::{DataComplete, DataProceed, ErrorReport, InitiateReply, InitiateRequest};
use openlcb_stream::{Duration, EventId, Instant, Mti, NodeId};
use openlcb_tokio::openlcb_node::memconfig::wire::{self as mc, Command, Reply};
use openlcb_tokio::openlcb_node::{OkFlags, Protocols, SnipInfo};
use openlcb_tokio::{EventRange, openlcb_can};
use serde::Serialize;
use tokio::io::AsyncReadExt as _;

use crate::events::{event_text, range_text};
use crate::net::{self, ConnectArgs};
use crate::outcome::Outcome;
use crate::reconnect::{RECONNECT_HELP, ReconnectArgs, Stop};

/// Messages being reassembled at once (addressed messages and reports with payload).
const MESSAGE_SLOTS: usize = 64;
/// The longest message reassembled (a report with payload may be long).
const MAX_MESSAGE_LEN: usize = 4096;
/// Datagrams being reassembled at once.
const DATAGRAM_SLOTS: usize = 64;
/// A message whose next frame does not come within this is dropped (as a node would).
const REASSEMBLY_TIMEOUT: Duration = Duration::from_secs(3);
/// Aliases whose Node ID is remembered.
const MOST_ALIASES: usize = 4096;

/// What a decoded line is about, for `--kind`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, ValueEnum, Serialize)]
#[serde(rename_all = "lowercase")]
pub(crate) enum Kind {
    /// CID, RID, AMD, AME, AMR and error information reports.
    Alias,
    /// Initialization Complete, Verify Node ID, Protocol Support, OIR, TDE.
    Node,
    /// Simple Node Information.
    Snip,
    /// Datagrams and their answers (Memory Configuration and firmware upgrade included).
    Datagram,
    /// Stream messages and stream data.
    Stream,
    /// Event Transport.
    Event,
    /// Frames and messages that did not decode.
    Raw,
}

/// Options of `lcc-stream monitor`.
#[derive(Debug, Args)]
#[command(after_help = format!("{}{RECONNECT_HELP}{}", "\
Prints one line per message (CAN frames reassembled): the time in seconds, the source (alias,
and Node ID once learnt), the destination, the message by name and its content decoded.
--from reads a saved trace: GridConnect frames one a line, as `lcc-stream hub --trace` or
OpenMRN's `hub -l` print them (a leading time in seconds is used when there is one).

--json prints one object per message: time, kind, source_alias, source (Node ID or null),
destination_alias and destination (null for global messages), message (its name), detail
(the decoded content) and raw (the frame, for what did not decode; else null).

Live, a lost hub is listened to again as below (monitor has no node, so no login: it says
`listening again on ADDR`); the filters and the Node IDs learnt are kept, and a line marks
the gap, whatever the filters: `    12.345  -- nothing seen for 3.2 s: the hub at ADDR was
lost (connection to the hub lost: ...) --`, with --json {time, gap_s, error}.

", net::network_help(&[])))]
pub(crate) struct MonitorArgs {
    /// Decode a saved trace instead of listening live (`-`: standard input).
    #[arg(long, value_name = "FILE", conflicts_with_all = ["connect", "serial"])]
    from: Option<PathBuf>,
    /// Only messages from or to this node: a Node ID, or a CAN alias in hex (e.g. 3B2);
    /// repeatable.
    #[arg(long, value_name = "NODE")]
    node: Vec<String>,
    /// Only lines of this kind; repeatable.
    #[arg(long, value_enum, value_name = "KIND")]
    kind: Vec<Kind>,
    /// One JSON object per message instead of text.
    #[arg(long)]
    json: bool,
    #[command(flatten)]
    connect: ConnectArgs,
    #[command(flatten)]
    reconnect: ReconnectArgs,
}

/// Where a live monitor saw nothing: the hub was lost at `time` for `gap_s` seconds.
#[derive(Debug, Serialize)]
struct GapLine<'a> {
    time: f64,
    gap_s: f64,
    error: &'a str,
}

impl GapLine<'_> {
    /// The text form.
    fn text(&self, addr: &str) -> String {
        format!(
            "{:10.3}  -- nothing seen for {:.1} s: the hub at {addr} was lost ({}) --",
            self.time, self.gap_s, self.error
        )
    }
}

/// One decoded message.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub(crate) struct Line {
    pub(crate) time: f64,
    pub(crate) kind: Kind,
    pub(crate) source_alias: String,
    pub(crate) source: Option<String>,
    pub(crate) destination_alias: Option<String>,
    pub(crate) destination: Option<String>,
    pub(crate) message: String,
    pub(crate) detail: String,
    pub(crate) raw: Option<String>,
}

impl Line {
    /// The text form.
    pub(crate) fn text(&self) -> String {
        let named = |alias: &str, node: &Option<String>| match node {
            Some(node) => format!("{alias} {node}"),
            None => alias.to_string(),
        };
        let source = named(&self.source_alias, &self.source);
        let to = match &self.destination_alias {
            Some(alias) => format!(" -> {}", named(alias, &self.destination)),
            None => String::new(),
        };
        let detail = if self.detail.is_empty() { String::new() } else { format!(": {}", self.detail) };
        format!("{:10.3}  {source}{to}  {}{detail}", self.time, self.message)
    }
}

/// Which lines to print.
#[derive(Debug, Default)]
struct Filter {
    nodes: Vec<NodeFilter>,
    kinds: Vec<Kind>,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum NodeFilter {
    Alias(NodeAlias),
    Node(NodeId),
}

impl NodeFilter {
    fn parse(text: &str) -> Result<Self, String> {
        if text.len() <= 3 {
            let alias = u16::from_str_radix(text, 16).ok().and_then(NodeAlias::new);
            return alias.map(NodeFilter::Alias).ok_or_else(|| format!("`{text}` is not a CAN alias (1 to FFF)"));
        }
        crate::args::node_id(text).map(NodeFilter::Node)
    }

    fn matches(self, alias: &str, node: Option<&str>) -> bool {
        match self {
            NodeFilter::Alias(want) => alias == format!("{:03X}", want.as_raw()),
            NodeFilter::Node(want) => node == Some(want.to_string().as_str()),
        }
    }
}

impl Filter {
    fn keeps(&self, line: &Line) -> bool {
        let kind = self.kinds.is_empty() || self.kinds.contains(&line.kind);
        let node = self.nodes.is_empty()
            || self.nodes.iter().any(|f| {
                f.matches(&line.source_alias, line.source.as_deref())
                    || line.destination_alias.as_deref().is_some_and(|a| f.matches(a, line.destination.as_deref()))
            });
        kind && node
    }
}

/// Stream data frames of one stream, merged into one line until something else comes.
#[derive(Debug)]
struct DataRun {
    time: f64,
    source: NodeAlias,
    destination: NodeAlias,
    did: u8,
    frames: u32,
    bytes: u64,
}

/// The decoder: frames in, lines out. Keeps what it has learnt of aliases, the messages
/// being reassembled, and the byte count of each stream.
pub(crate) struct Monitor {
    names: HashMap<NodeAlias, NodeId>,
    messages: Reassembler,
    datagrams: Reassembler,
    run: Option<DataRun>,
    /// Stream bytes seen per (source, destination, DID) since the stream was set up.
    streamed: HashMap<(NodeAlias, NodeAlias, u8), u64>,
}

impl Default for Monitor {
    fn default() -> Self {
        Monitor {
            names: HashMap::new(),
            messages: Reassembler::new(MESSAGE_SLOTS, MAX_MESSAGE_LEN, REASSEMBLY_TIMEOUT),
            datagrams: Reassembler::for_datagrams(DATAGRAM_SLOTS, REASSEMBLY_TIMEOUT),
            run: None,
            streamed: HashMap::new(),
        }
    }
}

impl Monitor {
    /// Decodes one frame seen at `time` (seconds); the lines it completes go to `out`.
    pub(crate) fn frame(&mut self, time: f64, frame: &CanFrame, out: &mut Vec<Line>) {
        let now = Instant::from_micros((time.max(0.0) * 1e6) as u64);
        while self.messages.take_expired(now).is_some() || self.datagrams.take_expired(now).is_some() {}
        let header = match frame.header() {
            Ok(header) => header,
            Err(error) => return out.push(self.raw_line(time, frame, None, &format!("not an OpenLCB frame: {error}"))),
        };
        if !matches!(header.kind, FrameKind::StreamData { .. }) {
            self.flush(out);
        }
        let data = frame.payload();
        let source = header.source;
        match header.kind {
            FrameKind::Message { can_mti } => self.message_frame(time, now, frame, source, can_mti, out),
            FrameKind::Datagram { frame: part, destination } => {
                let key = ReassemblyKey { source, destination, mti: Mti::DATAGRAM };
                match self.datagrams.push(now, key, part.position(), data) {
                    Ok(Some(whole)) => {
                        let whole = whole.to_vec();
                        out.push(self.message(time, source, Some(destination), Mti::DATAGRAM, &whole));
                    }
                    Ok(None) => {}
                    Err(error) => out.push(self.raw_line(time, frame, Some(destination), &error.to_string())),
                }
            }
            FrameKind::StreamData { destination } => self.stream_data(time, source, destination, data, frame, out),
            _ => {
                let line = self.alias_frame(time, &header, data);
                out.push(line);
            }
        }
    }

    /// Ends the merged stream data line, if one is open (at the end of the input).
    pub(crate) fn flush(&mut self, out: &mut Vec<Line>) {
        let Some(run) = self.run.take() else { return };
        let total = self.streamed.get(&(run.source, run.destination, run.did)).copied().unwrap_or(run.bytes);
        let detail =
            format!("DID 0x{:02X}, {} bytes in {} frames (stream total {total})", run.did, run.bytes, run.frames);
        let mut line = self.line(time_of(&run), Kind::Stream, run.source, Some(run.destination), "Stream Data Send");
        line.detail = detail;
        out.push(line);
    }

    fn message_frame(
        &mut self,
        time: f64,
        now: Instant,
        frame: &CanFrame,
        source: NodeAlias,
        can_mti: u16,
        out: &mut Vec<Line>,
    ) {
        let data = frame.payload();
        if let Some(position) = event_report::position(can_mti) {
            let key = ReassemblyKey { source, destination: source, mti: Mti::PRODUCER_CONSUMER_EVENT_REPORT };
            match self.messages.push(now, key, position, data) {
                Ok(Some(whole)) => {
                    let whole = whole.to_vec();
                    out.push(self.message(time, source, None, Mti::PRODUCER_CONSUMER_EVENT_REPORT, &whole));
                }
                Ok(None) => {}
                Err(error) => out.push(self.raw_line(time, frame, None, &error.to_string())),
            }
            return;
        }
        let mti = Mti(can_mti);
        if !mti.is_addressed() {
            return out.push(self.message(time, source, None, mti, data));
        }
        let [flags, low, body @ ..] = data else {
            return out.push(self.raw_line(time, frame, None, "addressed frame without a destination"));
        };
        let Some(destination) = NodeAlias::new(u16::from_be_bytes([flags & 0x0F, *low])) else {
            return out.push(self.raw_line(time, frame, None, "destination alias 0"));
        };
        let key = ReassemblyKey { source, destination, mti };
        match self.messages.push(now, key, FramePosition::from_flags(*flags), body) {
            Ok(Some(whole)) => {
                let whole = whole.to_vec();
                out.push(self.message(time, source, Some(destination), mti, &whole));
            }
            Ok(None) => {}
            Err(error) => out.push(self.raw_line(time, frame, Some(destination), &error.to_string())),
        }
    }

    fn stream_data(
        &mut self,
        time: f64,
        source: NodeAlias,
        destination: NodeAlias,
        data: &[u8],
        frame: &CanFrame,
        out: &mut Vec<Line>,
    ) {
        let Some((&did, bytes)) = data.split_first() else {
            self.flush(out);
            return out.push(self.raw_line(time, frame, Some(destination), "stream data frame without a DID"));
        };
        let same = self.run.as_ref().is_some_and(|r| (r.source, r.destination, r.did) == (source, destination, did));
        if !same {
            self.flush(out);
            self.run = Some(DataRun { time, source, destination, did, frames: 0, bytes: 0 });
        }
        if let Some(run) = &mut self.run {
            run.frames += 1;
            run.bytes += bytes.len() as u64;
        }
        *self.streamed.entry((source, destination, did)).or_default() += bytes.len() as u64;
    }

    /// A control frame: alias allocation and mapping.
    fn alias_frame(&mut self, time: f64, header: &CanHeader, data: &[u8]) -> Line {
        let source = header.source;
        let node = NodeId::from_slice(data);
        let (name, detail) = match header.kind {
            FrameKind::CheckId { sequence, node_id_bits } => {
                (format!("CID{sequence}"), format!("Node ID bits 0x{node_id_bits:03X}"))
            }
            FrameKind::ReserveId => ("RID".to_string(), String::new()),
            FrameKind::AliasMapDefinition => {
                if let Some(node) = node {
                    self.learn(source, node);
                }
                ("AMD".to_string(), node.map(|n| n.to_string()).unwrap_or_default())
            }
            FrameKind::AliasMapEnquiry => {
                ("AME".to_string(), node.map_or_else(|| "every node".to_string(), |n| n.to_string()))
            }
            FrameKind::AliasMapReset => {
                let line = self.line(time, Kind::Alias, source, None, "AMR");
                self.names.remove(&source);
                return Line { detail: node.map(|n| n.to_string()).unwrap_or_default(), ..line };
            }
            FrameKind::ErrorInformationReport(n) => (format!("Error Information Report {n}"), hex(data)),
            FrameKind::ReservedFormat { format, field } => {
                (format!("reserved frame format {format}"), format!("field 0x{field:03X}, data {}", hex(data)))
            }
            FrameKind::ReservedControl { content } => (format!("reserved control frame 0x{content:04X}"), hex(data)),
            _ => ("control frame".to_string(), hex(data)),
        };
        let kind = if matches!(header.kind, FrameKind::ReservedFormat { .. } | FrameKind::ReservedControl { .. }) {
            Kind::Raw
        } else {
            Kind::Alias
        };
        let mut line = self.line(time, kind, source, None, &name);
        line.detail = detail;
        line
    }

    /// A whole message: named and decoded.
    fn message(
        &mut self,
        time: f64,
        source: NodeAlias,
        destination: Option<NodeAlias>,
        mti: Mti,
        payload: &[u8],
    ) -> Line {
        if mti.announces_sender()
            && let Some(node) = NodeId::from_slice(payload)
        {
            self.learn(source, node);
        }
        let (kind, detail) = self.decode(source, destination, mti, payload);
        let name = mti.name().map_or_else(|| format!("MTI 0x{:04X}", mti.0), str::to_string);
        let mut line = self.line(time, kind, source, destination, &name);
        line.detail = detail;
        line
    }

    fn decode(
        &mut self,
        source: NodeAlias,
        destination: Option<NodeAlias>,
        mti: Mti,
        payload: &[u8],
    ) -> (Kind, String) {
        let node_text = || NodeId::from_slice(payload).map(|n| n.to_string()).unwrap_or_default();
        let event = EventId::from_slice(payload);
        match mti {
            Mti::INITIALIZATION_COMPLETE | Mti::INITIALIZATION_COMPLETE_SIMPLE => (Kind::Node, node_text()),
            Mti::VERIFIED_NODE_ID | Mti::VERIFIED_NODE_ID_SIMPLE => (Kind::Node, node_text()),
            Mti::VERIFY_NODE_ID_GLOBAL | Mti::VERIFY_NODE_ID_ADDRESSED => (Kind::Node, node_text()),
            Mti::PROTOCOL_SUPPORT_INQUIRY => (Kind::Node, String::new()),
            Mti::PROTOCOL_SUPPORT_REPLY => {
                let names: Vec<&str> = Protocols::from_payload(payload).names().collect();
                (Kind::Node, names.join(", "))
            }
            Mti::OPTIONAL_INTERACTION_REJECTED | Mti::TERMINATE_DUE_TO_ERROR => (Kind::Node, error_report(payload)),
            Mti::SIMPLE_NODE_INFO_REQUEST => (Kind::Snip, String::new()),
            Mti::SIMPLE_NODE_INFO_REPLY => (Kind::Snip, snip(payload)),
            Mti::DATAGRAM => (Kind::Datagram, datagram(payload)),
            Mti::DATAGRAM_RECEIVED_OK => {
                let flags = OkFlags::from_byte(payload.first().copied().unwrap_or(0));
                let pending = if flags.reply_pending { "reply pending" } else { "no reply pending" };
                let within = match flags.timeout_exponent {
                    0 => String::new(),
                    n => format!(", reply within {} s", 1u32 << n),
                };
                (Kind::Datagram, format!("{pending}{within}"))
            }
            Mti::DATAGRAM_REJECTED => (Kind::Datagram, error_report(payload)),
            Mti::STREAM_INITIATE_REQUEST => (
                Kind::Stream,
                decoded(InitiateRequest::parse(payload), payload, |r| {
                    let did = r.proposed_destination.map_or("none".to_string(), |d| format!("0x{:02X}", d.as_raw()));
                    let uid = r.content_uid.map(|u| format!(", content UID {u:?}")).unwrap_or_default();
                    format!(
                        "SID 0x{:02X}, proposed DID {did}, buffer {}{uid}",
                        r.source_stream.as_raw(),
                        r.max_buffer_size
                    )
                }),
            ),
            Mti::STREAM_INITIATE_REPLY => (
                Kind::Stream,
                decoded(InitiateReply::parse(payload), payload, |r| {
                    let did = r.destination_stream.map_or(0xFF, |d| d.as_raw());
                    if r.is_accepted()
                        && let Some(destination) = destination
                    {
                        // The stream starts: its byte count too (data flows from the requester).
                        self.streamed.insert((destination, source, did), 0);
                    }
                    let verdict = if r.is_accepted() {
                        "accepted".to_string()
                    } else {
                        format!("rejected {}: {}", r.code, r.code.meaning())
                    };
                    format!(
                        "SID 0x{:02X}, DID 0x{did:02X}, window {}, {verdict}",
                        r.source_stream.as_raw(),
                        r.max_buffer_size
                    )
                }),
            ),
            Mti::STREAM_DATA_PROCEED => (
                Kind::Stream,
                decoded(DataProceed::parse(payload), payload, |p| {
                    format!("SID 0x{:02X}, DID 0x{:02X}", p.source_stream.as_raw(), p.destination_stream.as_raw())
                }),
            ),
            Mti::STREAM_DATA_COMPLETE => (
                Kind::Stream,
                decoded(DataComplete::parse(payload), payload, |c| {
                    let did = c.destination_stream.as_raw();
                    let seen = self.streamed.remove(&(source, destination.unwrap_or(source), did)).unwrap_or(0);
                    let stated = c.count.stated().map_or("no count".to_string(), |n| format!("count {n}"));
                    format!("SID 0x{:02X}, DID 0x{did:02X}, {stated}, {seen} bytes seen", c.source_stream.as_raw())
                }),
            ),
            Mti::PRODUCER_CONSUMER_EVENT_REPORT
            | Mti::LEARN_EVENT
            | Mti::IDENTIFY_CONSUMER
            | Mti::IDENTIFY_PRODUCER => {
                let rest = payload.get(8..).filter(|p| !p.is_empty()).map(|p| format!(", payload {}", hex(p)));
                (Kind::Event, event.map(event_text).unwrap_or_default() + &rest.unwrap_or_default())
            }
            Mti(0x0544..=0x0547) | Mti(0x04C4..=0x04C7) => (Kind::Event, event.map(event_text).unwrap_or_default()),
            Mti::PRODUCER_RANGE_IDENTIFIED | Mti::CONSUMER_RANGE_IDENTIFIED => {
                (Kind::Event, event.map(|e| range_text(EventRange::from_encoded(e))).unwrap_or_default())
            }
            Mti::IDENTIFY_EVENTS_GLOBAL | Mti::IDENTIFY_EVENTS_ADDRESSED => (Kind::Event, String::new()),
            _ => (Kind::Raw, hex(payload)),
        }
    }

    fn learn(&mut self, alias: NodeAlias, node: NodeId) {
        if self.names.len() < MOST_ALIASES || self.names.contains_key(&alias) {
            self.names.insert(alias, node);
        }
    }

    /// A line with the names known now.
    fn line(&self, time: f64, kind: Kind, source: NodeAlias, destination: Option<NodeAlias>, message: &str) -> Line {
        let node = |alias: NodeAlias| self.names.get(&alias).map(NodeId::to_string);
        Line {
            time,
            kind,
            source_alias: format!("{:03X}", source.as_raw()),
            source: node(source),
            destination_alias: destination.map(|d| format!("{:03X}", d.as_raw())),
            destination: destination.and_then(node),
            message: message.to_string(),
            detail: String::new(),
            raw: None,
        }
    }

    /// A frame that did not decode, printed as it came.
    fn raw_line(&self, time: f64, frame: &CanFrame, destination: Option<NodeAlias>, why: &str) -> Line {
        let text = frame_text(frame);
        match NodeAlias::from_low_bits(frame.raw_id()) {
            Some(source) => {
                let mut line = self.line(time, Kind::Raw, source, destination, "undecoded frame");
                line.detail = format!("{why}: {text}");
                line.raw = Some(text);
                line
            }
            None => undecodable(time, text, why),
        }
    }
}

/// Text that is no OpenLCB frame at all (a standard frame, a broken one).
fn undecodable(time: f64, text: String, why: &str) -> Line {
    Line {
        time,
        kind: Kind::Raw,
        source_alias: "???".to_string(),
        source: None,
        destination_alias: None,
        destination: None,
        message: "undecoded frame".to_string(),
        detail: format!("{why}: {text}"),
        raw: Some(text),
    }
}

fn time_of(run: &DataRun) -> f64 {
    run.time
}

/// What `parsed` says, or why it did not parse and the bytes.
fn decoded<T, E: std::fmt::Display>(parsed: Result<T, E>, payload: &[u8], text: impl FnOnce(T) -> String) -> String {
    parsed.map_or_else(|error| format!("undecodable ({error}): {}", hex(payload)), text)
}

/// The frame as GridConnect text.
fn frame_text(frame: &CanFrame) -> String {
    let mut text = [0u8; gridconnect::MAX_ENCODED_LEN];
    match gridconnect::encode(frame, &mut text) {
        Ok(len) => String::from_utf8_lossy(text.get(..len).unwrap_or_default()).into_owned(),
        Err(_) => format!("id 0x{:08X} data {}", frame.raw_id(), hex(frame.payload())),
    }
}

fn hex(bytes: &[u8]) -> String {
    bytes.iter().map(|b| format!("{b:02X}")).collect::<Vec<_>>().join(" ")
}

/// OIR, TDE or Datagram Rejected: the code by its meaning, and the MTI it names.
fn error_report(payload: &[u8]) -> String {
    let report = ErrorReport::parse(payload);
    let mti =
        report.mti.map(|m| format!(" (to {})", m.name().map_or_else(|| format!("MTI 0x{:04X}", m.0), str::to_string)));
    format!("{} {}{}", report.code, report.code.meaning(), mti.unwrap_or_default())
}

fn snip(payload: &[u8]) -> String {
    let info = SnipInfo::parse(payload);
    format!(
        "\"{}\" \"{}\" hw \"{}\" sw \"{}\", user \"{}\" \"{}\"",
        info.manufacturer,
        info.model,
        info.hardware_version,
        info.software_version,
        info.user_name,
        info.user_description
    )
}

/// The name of an address space.
fn space(space: Option<u8>) -> String {
    match space {
        Some(mc::SPACE_CDI) => "0xFF (CDI)".into(),
        Some(mc::SPACE_ALL) => "0xFE (all memory)".into(),
        Some(mc::SPACE_CONFIG) => "0xFD (configuration)".into(),
        Some(mc::SPACE_ACDI_MANUFACTURER) => "0xFC (ACDI manufacturer)".into(),
        Some(mc::SPACE_ACDI_USER) => "0xFB (ACDI user)".into(),
        Some(mc::SPACE_FIRMWARE) => "0xEF (firmware)".into(),
        Some(other) => format!("0x{other:02X}"),
        None => "unnamed".into(),
    }
}

/// A Memory Configuration error code by its meaning.
fn memory_error(code: openlcb_stream::wire::ErrorCode) -> String {
    let meaning = match code {
        mc::codes::UNKNOWN_SPACE => "unknown address space",
        mc::codes::OUT_OF_BOUNDS => "address out of bounds",
        mc::codes::READ_ONLY => "read-only",
        mc::codes::FIRMWARE_CHECKSUM => "firmware checksum failed",
        mc::codes::FIRMWARE_INCOMPATIBLE => "firmware incompatible with this hardware",
        mc::codes::FIRMWARE_CORRUPTED => "firmware invalid or corrupted",
        code => code.meaning(),
    };
    format!("{code} {meaning}")
}

/// A datagram: Memory Configuration (with the firmware-upgrade steps named), or its bytes.
fn datagram(payload: &[u8]) -> String {
    let firmware = |s: u8| if s == mc::SPACE_FIRMWARE { "firmware upgrade: " } else { "" };
    match payload {
        [mc::CONTENT_ID, command, ..] if mc::is_reply(*command) => match Reply::parse(payload) {
            Ok(reply) => format!("Memory Configuration {}", memory_reply(&reply)),
            Err(error) => format!("Memory Configuration reply, undecodable ({error}): {}", hex(payload)),
        },
        [mc::CONTENT_ID, ..] => match Command::parse(payload) {
            Ok(command) => {
                let text = match &command {
                    Command::Read { space: s, address, count } => {
                        format!("{}Read {count} bytes at 0x{address:08X} of space {}", firmware(*s), space(Some(*s)))
                    }
                    Command::Write { space: s, address, data } => format!(
                        "{}Write {} bytes at 0x{address:08X} of space {}",
                        firmware(*s),
                        data.len(),
                        space(Some(*s))
                    ),
                    Command::WriteUnderMask { space: s, address, data, .. } => {
                        format!("Write Under Mask {} bytes at 0x{address:08X} of space {}", data.len(), space(Some(*s)))
                    }
                    Command::ReadStream { space: s, address, destination_stream, count } => format!(
                        "Read Stream {count} bytes at 0x{address:08X} of space {}, DID 0x{destination_stream:02X}",
                        space(Some(*s))
                    ),
                    Command::WriteStream { space: s, address, source_stream } => format!(
                        "{}Write Stream at 0x{address:08X} of space {}, SID 0x{source_stream:02X}",
                        firmware(*s),
                        space(Some(*s))
                    ),
                    Command::GetOptions => "Get Configuration Options".into(),
                    Command::GetSpaceInfo { space: s } => format!("Get Address Space Information {}", space(Some(*s))),
                    Command::Lock { node } => format!("Lock/Reserve 0x{node:012X}"),
                    Command::GetUniqueId { count } => format!("Get Unique ID ({count})"),
                    Command::Freeze { space: s } => format!("{}Freeze space {}", firmware(*s), space(Some(*s))),
                    Command::Unfreeze { space: s } => format!("{}Unfreeze space {}", firmware(*s), space(Some(*s))),
                    Command::UpdateComplete => "Update Complete".into(),
                    Command::Reset => "Reset/Reboot".into(),
                    Command::FactoryReset { node } => format!("Factory Reset 0x{node:012X}"),
                    other => format!("{other:?}"),
                };
                format!("Memory Configuration {text}")
            }
            Err(error) => format!("Memory Configuration command, undecodable ({error}): {}", hex(payload)),
        },
        [content, ..] => format!("content ID 0x{content:02X}, {} bytes: {}", payload.len(), hex(payload)),
        [] => "empty".into(),
    }
}

fn memory_reply(reply: &Reply) -> String {
    match reply {
        Reply::ReadOk { space: s, address, data } => {
            format!("Read Reply {} bytes at 0x{address:08X} of space {}", data.len(), space(Some(*s)))
        }
        Reply::WriteOk { space: s, address } => {
            format!("Write Reply OK at 0x{address:08X} of space {}", space(Some(*s)))
        }
        Reply::ReadStreamOk { space: s, address, source_stream, destination_stream, count } => format!(
            "Read Stream Reply at 0x{address:08X} of space {}, SID 0x{source_stream:02X} DID 0x{destination_stream:02X}{}",
            space(*s),
            count.map(|c| format!(", {c} bytes")).unwrap_or_default()
        ),
        Reply::WriteStreamOk { space: s, address, streams } => format!(
            "Write Stream Reply at 0x{address:08X} of space {}{}",
            space(*s),
            streams.map(|(sid, did)| format!(", SID 0x{sid:02X} DID 0x{did:02X}")).unwrap_or_default()
        ),
        Reply::Failed { kind, space: s, address, code } => {
            format!("{kind:?} failed at 0x{address:08X} of space {}: {}", space(*s), memory_error(*code))
        }
        Reply::Options(options) => format!(
            "Configuration Options: commands 0x{:04X}, write lengths 0x{:02X}, spaces up to 0x{:02X}",
            options.commands, options.write_lengths, options.highest_space
        ),
        Reply::SpaceInfo(info) => format!(
            "Address Space Information {}: {}{}{}",
            space(Some(info.space)),
            if info.present { "present" } else { "not present" },
            info.highest_address.map(|h| format!(", highest address 0x{h:08X}")).unwrap_or_default(),
            if info.read_only { ", read-only" } else { "" }
        ),
        Reply::Lock { owner } => format!("Lock/Reserve Reply, owner 0x{owner:012X}"),
        Reply::UniqueIds { ids } => format!("Unique ID Reply, {} IDs", ids.len()),
        other => format!("{other:?}"),
    }
}

/// The time at the front of a trace line (`hub --trace` prints seconds first), if any.
fn leading_time(line: &str) -> Option<f64> {
    line.split_whitespace().next()?.trim_end_matches(':').parse().ok()
}

/// Decodes every frame of `text` (one trace line, or what a connection gave), at `time`.
pub(crate) fn decode_text(
    monitor: &mut Monitor,
    decoder: &mut GridConnectDecoder,
    time: f64,
    text: &[u8],
    out: &mut Vec<Line>,
) {
    let mut input = text;
    loop {
        let before = input;
        let standard = decoder.stats().standard_ignored;
        let decoded = decoder.decode(&mut input);
        if decoder.stats().standard_ignored != standard {
            // The decoder skips 11-bit frames: OpenLCB has none, but they are on the bus.
            let taken = before.get(..before.len() - input.len()).unwrap_or_default();
            let text = String::from_utf8_lossy(taken).trim().to_string();
            out.push(undecodable(time, text, "a standard (11-bit) frame, not OpenLCB"));
        }
        match decoded {
            None => break,
            Some(Ok(frame)) => monitor.frame(time, &frame, out),
            Some(Err(error)) => {
                monitor.flush(out);
                let taken = before.get(..before.len() - input.len()).unwrap_or_default();
                let text = String::from_utf8_lossy(taken).trim().to_string();
                out.push(undecodable(time, text, &error.to_string()));
            }
        }
    }
}

/// The longest trace line decoded: a time, a client's name and a few GridConnect frames (one
/// is at most 30 characters). A longer line is no trace line: it is skipped to its end,
/// never held whole, and shown as one undecoded line.
const MAX_TRACE_LINE: usize = 1024;

/// Decodes a saved trace as it is read, a line at a time: every line's frames, timed by the
/// line's leading time if it has one (else by its line number, in milliseconds, to keep the
/// order). `print` is handed the decoded lines after each trace line; memory stays bounded
/// by [`MAX_TRACE_LINE`] whatever the input (a file with no newline, /dev/zero).
pub(crate) fn decode_trace(
    mut input: impl std::io::BufRead,
    mut print: impl FnMut(&mut Vec<Line>),
) -> std::io::Result<()> {
    let mut monitor = Monitor::default();
    let mut decoder = GridConnectDecoder::new();
    let mut out = Vec::new();
    let mut line = Vec::with_capacity(MAX_TRACE_LINE);
    let mut skipped = 0usize;
    let mut number = 0usize;
    loop {
        let available = input.fill_buf()?;
        let at_end = available.is_empty();
        let newline = available.iter().position(|&b| b == b'\n');
        let piece = available.get(..newline.unwrap_or(available.len())).unwrap_or_default();
        let room = MAX_TRACE_LINE.saturating_sub(line.len());
        line.extend_from_slice(piece.get(..piece.len().min(room)).unwrap_or_default());
        skipped = skipped.saturating_add(piece.len().saturating_sub(room));
        let used = newline.map_or(available.len(), |end| end + 1);
        input.consume(used);
        if newline.is_none() && !at_end {
            continue;
        }
        if !at_end || !line.is_empty() || skipped > 0 {
            trace_line(&mut monitor, &mut decoder, number, &line, skipped, &mut out);
            print(&mut out);
            number += 1;
            line.clear();
            skipped = 0;
        }
        if at_end {
            break;
        }
    }
    monitor.flush(&mut out);
    print(&mut out);
    Ok(())
}

/// Decodes one trace line, or reports it as undecoded when it was longer than
/// [`MAX_TRACE_LINE`] (`skipped` bytes past the bound were dropped).
fn trace_line(
    monitor: &mut Monitor,
    decoder: &mut GridConnectDecoder,
    number: usize,
    line: &[u8],
    skipped: usize,
    out: &mut Vec<Line>,
) {
    // Bytes that are not text (a binary log) become replacement characters, not an error.
    let text = String::from_utf8_lossy(line);
    let line = text.trim_end_matches('\r');
    let time = leading_time(line).unwrap_or(number as f64 / 1000.0);
    if skipped > 0 {
        monitor.flush(out);
        let total = MAX_TRACE_LINE.saturating_add(skipped);
        out.push(undecodable(
            time,
            format!("{} bytes", total),
            &format!("line {} longer than {MAX_TRACE_LINE} bytes", number + 1),
        ));
        return;
    }
    // The frames start at the first `:X` or `:S` (a client's name before them may hold
    // a `:` too).
    let start = line.find(":X").into_iter().chain(line.find(":S")).chain(line.find(":x")).min();
    let frames = start.map_or("", |start| line.get(start..).unwrap_or_default());
    decode_text(monitor, decoder, time, frames.as_bytes(), out);
}

pub(crate) fn run(args: &MonitorArgs) -> Result<ExitCode, String> {
    let filter = Filter {
        nodes: args
            .node
            .iter()
            .map(|n| NodeFilter::parse(n))
            .collect::<Result<_, _>>()
            .map_err(|e| format!("--node: {e}"))?,
        kinds: args.kind.clone(),
    };
    let print = |lines: &mut Vec<Line>| {
        for line in lines.drain(..).filter(|l| filter.keeps(l)) {
            if args.json {
                net::print_json(&line);
            } else {
                outln!("{}", line.text());
            }
        }
    };
    if let Some(path) = &args.from {
        let read = if path.as_os_str() == "-" {
            decode_trace(std::io::stdin().lock(), print)
        } else {
            let file = std::fs::File::open(path).map_err(|e| format!("{}: {e}", path.display()))?;
            decode_trace(std::io::BufReader::new(file), print)
        };
        read.map_err(|e| format!("{}: {e}", path.display()))?;
        return Ok(ExitCode::SUCCESS);
    }
    net::runtime()?.block_on(live(args, print))
}

/// Listens to the hub, serial adapter or CAN interface until it closes or Ctrl-C.
async fn live(args: &MonitorArgs, mut print: impl FnMut(&mut Vec<Line>)) -> Result<ExitCode, String> {
    let mut interrupt = net::Interrupt::new()?;
    let mut stream = match args.connect.byte_stream().await {
        Ok(stream) => stream,
        Err(error) => {
            eprintln!("lcc-stream monitor: {error}");
            return Ok(ExitCode::from(Outcome::UnreachableHub.status()));
        }
    };
    eprintln!("lcc-stream monitor: listening on {} (Ctrl-C stops)", args.connect.addr());
    let start = std::time::Instant::now();
    let mut monitor = Monitor::default();
    let mut decoder = GridConnectDecoder::new();
    let mut buf = vec![0u8; 64 * 1024];
    let mut lines = Vec::new();
    let addr = args.connect.addr();
    let status = loop {
        let lost = tokio::select! {
            read = stream.read(&mut buf) => match read {
                Ok(0) => "connection to the hub lost: it closed the connection".to_string(),
                Err(error) => format!("connection to the hub lost: {error}"),
                Ok(n) => {
                    let time = start.elapsed().as_secs_f64();
                    decode_text(&mut monitor, &mut decoder, time, buf.get(..n).unwrap_or_default(), &mut lines);
                    print(&mut lines);
                    continue;
                }
            },
            () = interrupt.wait() => break Outcome::Interrupted.status(),
        };
        // What was complete before the loss is shown; a frame cut in half is not.
        monitor.flush(&mut lines);
        print(&mut lines);
        let lost_at = start.elapsed().as_secs_f64();
        match args.reconnect.rejoin("monitor", addr, &lost, &mut interrupt, || args.connect.byte_stream()).await {
            Ok(again) => {
                stream = again;
                decoder = GridConnectDecoder::new();
                let time = start.elapsed().as_secs_f64();
                let gap = GapLine { time, gap_s: time - lost_at, error: &lost };
                if args.json {
                    net::print_json(&gap);
                } else {
                    outln!("{}", gap.text(addr));
                }
                eprintln!("lcc-stream monitor: listening again on {addr}");
            }
            Err(Stop::Interrupted) => break Outcome::Interrupted.status(),
            Err(Stop::GaveUp) => {
                eprintln!("lcc-stream monitor: {lost}");
                break Outcome::ConnectionLost.status();
            }
        }
    };
    monitor.flush(&mut lines);
    print(&mut lines);
    Ok(ExitCode::from(status))
}
