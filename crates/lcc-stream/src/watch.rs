//! `lcc-stream events watch`: every event report as it comes. Senders' names (SNIP) are
//! looked up beside the stream, a few at a time, and lines reach stdout through a
//! [`Printer`]: a report the output cannot take is counted and said, never lost without a
//! word.

use std::collections::{HashMap, VecDeque};
use std::io::IsTerminal as _;
use std::process::ExitCode;
use std::time::{Duration, Instant};

use openlcb_stream::{EventId, NodeId};
use openlcb_tokio::{Error, EventNotice, EventNotices, Node, NodeOptions, SnipInfo};
use serde::Serialize;
use tokio::task::{Id as TaskId, JoinSet};

use crate::events::{event_text, well_known};
use crate::net::{self, ConnectArgs};
use crate::outcome::{Outcome, net_outcome};
use crate::peer::Peer;
use crate::printer::{Output, Printer};
use crate::reconnect::{self, ReconnectArgs, Stop};

/// SNIP lookups under way at once (also the node's limit of SNIP requests); a sender first
/// seen while all are busy is looked up at one of its later reports.
pub(crate) const LOOKUPS: usize = 8;
/// Senders whose name (or that they gave none) is remembered; the oldest is forgotten first.
const NAMES_KEPT: usize = 1024;

/// How `watch` prints: text or one JSON object a line.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Format {
    Text,
    Json,
}

/// One report as `watch --json` prints it.
#[derive(Debug, Serialize)]
struct ReportLine {
    time: f64,
    event: String,
    name: Option<&'static str>,
    #[serde(skip_serializing_if = "Option::is_none")]
    from: Option<String>,
    #[serde(skip_serializing_if = "Option::is_none")]
    from_alias: Option<String>,
    from_name: Option<String>,
    payload: String,
}

/// Reports lost since the last such line, where they were lost.
#[derive(Debug, Serialize)]
struct DroppedLine {
    time: f64,
    dropped: u64,
}

/// The last line: every report the node received is either printed or dropped.
#[derive(Debug, Serialize)]
struct SummaryLine {
    time: f64,
    reports: u64,
    printed: u64,
    dropped: u64,
}

/// Prints every report that reaches `node` until `interrupt` comes, joining the hub at
/// `connect` again (as `options` of the same Node ID) whenever it is lost, as `reconnect`
/// says; closes the node it ends with.
pub(crate) async fn watch(
    mut node: Node,
    connect: &ConnectArgs,
    options: impl Fn(NodeId) -> NodeOptions,
    reconnect: &ReconnectArgs,
    format: Format,
    interrupt: &mut net::Interrupt,
) -> Result<ExitCode, String> {
    let mut watch = Watch::new(format)?;
    let mut notices = listen(&node).await.map_err(|error| error.to_string())?;
    eprintln!("lcc-stream events: watching event reports (Ctrl-C stops)");
    let ended = loop {
        let lost = tokio::select! {
            notice = notices.next() => match notice {
                Some(notice) => {
                    watch.notice(&node, notice, notices.dropped());
                    continue;
                }
                None => node.closed().await,
            },
            Some(answer) = watch.names.asking.join_next_with_id(), if !watch.names.asking.is_empty() => {
                watch.names.answered(answer);
                continue;
            }
            () = interrupt.wait() => break Outcome::Interrupted.status(),
        };
        // What the node had handed over already is printed or counted too.
        while let Some(notice) = notices.try_next() {
            watch.notice(&node, notice, notices.dropped());
        }
        let stopped = if reconnect::is_lost(&lost) {
            let id = node.node_id();
            let attempt = || async {
                let node = connect.join_again(options(id)).await?;
                let notices = listen(&node).await.map_err(|error| error.to_string())?;
                Ok::<_, String>((node, notices))
            };
            match reconnect.rejoin("events", connect.addr(), &lost, interrupt, attempt).await {
                Ok((again, listening)) => {
                    (node, notices) = (again, listening);
                    watch.rejoined();
                    reconnect::say_rejoined("events", connect.addr(), &node).await;
                    continue;
                }
                Err(stop) => stop,
            }
        } else {
            Stop::GaveUp
        };
        if stopped == Stop::Interrupted {
            break Outcome::Interrupted.status();
        }
        eprintln!("lcc-stream events: {lost}");
        break net_outcome(&lost).status();
    };
    // What the node had handed over already is printed or counted too.
    while let Some(notice) = notices.try_next() {
        watch.notice(&node, notice, notices.dropped());
    }
    watch.finish(notices.dropped()).await;
    node.close().await;
    Ok(ExitCode::from(ended))
}

/// Listens to every event report that reaches `node` (a new connection's), then asks who is
/// there, so that the link knows their Node IDs and the reports name their senders by them.
async fn listen(node: &Node) -> Result<EventNotices, Error> {
    let notices = node.event_notices().await?;
    let _ = node.discover(Duration::from_millis(500), 1024).await;
    Ok(notices)
}

/// The state of one `watch`, kept across connections.
struct Watch {
    format: Format,
    start: Instant,
    names: Names,
    printer: Printer,
    /// What the output is, for the line that says reports were dropped.
    output: &'static str,
}

impl Watch {
    fn new(format: Format) -> Result<Self, String> {
        let output = if std::io::stdout().is_terminal() { "this terminal" } else { "this output" };
        let printer = Printer::start(Output::Stdout)?;
        Ok(Watch { format, start: Instant::now(), names: Names::default(), printer, output })
    }

    /// Queues the line of a report that reached `node`; `node_lost` is the listener's count
    /// of lost notices now.
    fn notice(&mut self, node: &Node, notice: EventNotice, node_lost: u64) {
        self.printer.node_lost(node_lost);
        let EventNotice::Report { from, event, payload } = notice else { return };
        let line = self.report_line(node, from, event, &payload);
        let time = self.time();
        let (format, output) = (self.format, self.output);
        self.printer.report(line, |dropped| dropped_line(format, time, dropped, output));
    }

    fn time(&self) -> f64 {
        self.start.elapsed().as_secs_f64()
    }

    /// A new connection: its listener counts from 0, and the questions asked over the lost
    /// one are asked again at their senders' next reports.
    fn rejoined(&mut self) {
        self.printer.new_listener();
        self.names.forget_questions();
    }

    fn report_line(&mut self, node: &Node, from: NodeId, event: EventId, payload: &[u8]) -> String {
        let peer = Peer::of(from);
        let line = ReportLine {
            time: self.time(),
            event: event.to_string(),
            name: well_known(event),
            from: peer.node_field(),
            from_alias: peer.alias_field(),
            from_name: self.names.name(node, from),
            payload: payload.iter().map(|b| format!("{b:02X}")).collect(),
        };
        match self.format {
            Format::Json => net::json_line(&line),
            Format::Text => {
                let name = line.from_name.as_ref().map(|name| format!(" \"{name}\"")).unwrap_or_default();
                let payload =
                    if line.payload.is_empty() { String::new() } else { format!(" payload {}", line.payload) };
                format!("{:9.3}  {}  from {peer}{name}{payload}\n", line.time, event_text(event))
            }
        }
    }

    /// Queues the last lines (what is still unsaid; with `--json` the summary), waits a
    /// while for the output to take them, and says the count on stderr.
    async fn finish(mut self, node_lost: u64) {
        self.printer.node_lost(node_lost);
        let time = self.time();
        let (printed, dropped, unsaid) = (self.printer.printed(), self.printer.dropped(), self.printer.unsaid());
        let mut last = Vec::new();
        if unsaid > 0 {
            last.push(dropped_line(self.format, time, unsaid, self.output));
        }
        if self.format == Format::Json {
            last.push(net::json_line(&SummaryLine { time, reports: printed + dropped, printed, dropped }));
        }
        let written = self.printer.finish(last).await;
        let tail = if written { "" } else { " (the output stopped taking lines: the last were not written)" };
        eprintln!("lcc-stream events: {printed} reports printed, {dropped} dropped{tail}");
    }
}

/// The line saying that `dropped` reports were lost here, at `time`.
fn dropped_line(format: Format, time: f64, dropped: u64, output: &str) -> String {
    match format {
        Format::Json => net::json_line(&DroppedLine { time, dropped }),
        Format::Text => dropped_text(time, dropped, output),
    }
}

/// `    3.200  … 312 reports dropped (the bus is faster than this terminal)`.
fn dropped_text(time: f64, dropped: u64, output: &str) -> String {
    format!("{time:9.3}  … {dropped} reports dropped (the bus is faster than {output})\n")
}

/// The user name of a node, or else its manufacturer and model.
fn snip_name(info: &SnipInfo) -> String {
    if info.user_name.is_empty() { format!("{} {}", info.manufacturer, info.model) } else { info.user_name.clone() }
}

/// What `watch` knows of senders' names: at most [`NAMES_KEPT`], the oldest forgotten first,
/// and at most [`LOOKUPS`] questions under way, each ending by the node's SNIP timeout.
#[derive(Default)]
struct Names {
    known: HashMap<NodeId, Option<String>>,
    /// The keys of `known`, oldest first.
    order: VecDeque<NodeId>,
    asking: JoinSet<Result<SnipInfo, Error>>,
    /// Whom each question under way asks.
    asked: HashMap<TaskId, NodeId>,
}

impl Names {
    /// The name of `sender` if it is known; else `None`, and the question is asked if one of
    /// the lookups is free and it is not under way already.
    fn name(&mut self, node: &Node, sender: NodeId) -> Option<String> {
        if let Some(name) = self.known.get(&sender) {
            return name.clone();
        }
        if self.asked.len() < LOOKUPS && !self.asked.values().any(|asked| *asked == sender) {
            let task = self.asking.spawn(node.snip(sender));
            self.asked.insert(task.id(), sender);
        }
        None
    }

    /// Takes an answer: the name, or that the sender gave none in time. A question the node
    /// had no room for is asked again at the sender's next report.
    fn answered(&mut self, answer: Result<(TaskId, Result<SnipInfo, Error>), tokio::task::JoinError>) {
        let (task, result) = match answer {
            Ok(answer) => answer,
            Err(error) => (error.id(), Err(Error::Busy)),
        };
        let Some(sender) = self.asked.remove(&task) else { return };
        match result {
            Ok(info) => self.remember(sender, Some(snip_name(&info))),
            Err(Error::Busy) => {}
            Err(_) => self.remember(sender, None),
        }
    }

    /// Drops the questions under way (asked over a connection that is gone): their senders
    /// are asked again when they next report.
    fn forget_questions(&mut self) {
        self.asking.abort_all();
        self.asked.clear();
    }

    fn remember(&mut self, sender: NodeId, name: Option<String>) {
        if self.known.len() >= NAMES_KEPT
            && !self.known.contains_key(&sender)
            && let Some(oldest) = self.order.pop_front()
        {
            self.known.remove(&oldest);
        }
        if self.known.insert(sender, name).is_none() {
            self.order.push_back(sender);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_dropped_line_says_how_many_and_why() {
        assert_eq!(
            dropped_text(3.2, 312, "this terminal"),
            "    3.200  … 312 reports dropped (the bus is faster than this terminal)\n"
        );
    }

    #[test]
    fn names_kept_are_bounded_and_the_oldest_goes_first() {
        let mut names = Names::default();
        let id = |n: u64| NodeId::new(0x0501_0101_0000 + n).unwrap();
        for n in 0..=NAMES_KEPT as u64 {
            names.remember(id(n), None);
        }
        names.remember(id(7), Some("Signal box".into()));
        assert_eq!((names.known.len(), names.order.len()), (NAMES_KEPT, NAMES_KEPT));
        assert!(!names.known.contains_key(&id(0)), "the oldest was forgotten");
        assert_eq!(names.known.get(&id(7)), Some(&Some("Signal box".to_string())));
    }
}
