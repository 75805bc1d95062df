//! What `ui` watches while it serves: the nodes (found at the start, on Refresh, and as
//! they introduce themselves), the event reports and identifications its node hears, and the
//! bus decoded by `monitor`'s decoder, with the trace kept for download.

use std::collections::{BTreeSet, VecDeque};
use std::sync::Arc;
use std::time::{Duration, Instant};

use openlcb_can::gridconnect::GridConnectDecoder;
use openlcb_stream::{EventId, NodeId};
use openlcb_tokio::{EventNotice, EventRole, EventState};
use serde::Serialize;
use tokio::io::AsyncReadExt as _;
use tokio::task::JoinHandle;

use super::Shared;
use crate::events::well_known;
use crate::monitor::{self, Line, Monitor};
use crate::net::ConnectArgs;
use crate::nodes;
use crate::peer::Peer;

/// Seconds of quiet after the last Verified Node ID before a discovery is complete.
const DISCOVER_QUIET: Duration = Duration::from_secs(1);
/// Event reports kept for a page that opens later.
const KEPT_REPORTS: usize = 500;
/// Identified events kept (producers and consumers of every node).
const KEPT_IDENTIFIED: usize = 20_000;
/// Decoded monitor lines kept for a page that opens later.
const KEPT_LINES: usize = 2_000;
/// Trace lines kept for the download (the oldest go first; the trace says how many).
const KEPT_TRACE: usize = 1_000_000;

/// One event report as the page shows it.
#[derive(Debug, Clone, Serialize)]
pub(crate) struct Report {
    /// Seconds since `ui` started.
    pub(crate) time: f64,
    pub(crate) event: String,
    /// Its name, for a well-known event.
    pub(crate) name: Option<&'static str>,
    /// The sender: a Node ID, or `alias 4FF`.
    pub(crate) from: String,
    /// The sender's SNIP user name, else its model, if known.
    pub(crate) from_name: Option<String>,
    /// The bytes after the Event ID, in hex.
    pub(crate) payload: String,
}

/// One event a node produces or consumes, as Identify told.
#[derive(Debug, Clone, Serialize, PartialEq, Eq)]
pub(crate) struct Identified {
    pub(crate) node: String,
    pub(crate) role: &'static str,
    pub(crate) event: String,
    /// The last ID of a range (equal to `event` for one event).
    pub(crate) last: String,
    pub(crate) name: Option<&'static str>,
    /// valid, invalid, unknown; null for a range.
    pub(crate) state: Option<&'static str>,
}

/// What the watchers have gathered.
#[derive(Debug, Default)]
pub(crate) struct Gathered {
    pub(crate) reports: VecDeque<Report>,
    pub(crate) identified: VecDeque<Identified>,
    pub(crate) lines: VecDeque<Line>,
    /// GridConnect frames as `monitor --from` reads them: the time, then the frame.
    pub(crate) trace: VecDeque<String>,
    /// Trace lines dropped, the oldest first, past [`KEPT_TRACE`].
    pub(crate) trace_dropped: u64,
    /// Why there is no monitor, if there is none.
    pub(crate) monitor_off: Option<String>,
}

fn keep<T>(queue: &mut VecDeque<T>, item: T, most: usize) -> bool {
    queue.push_back(item);
    if queue.len() > most {
        queue.pop_front();
        return true;
    }
    false
}

/// Starts the watchers: a first discovery, the event watch and the monitor.
pub(crate) fn start(shared: &Arc<Shared>, connect: &ConnectArgs) -> Vec<JoinHandle<()>> {
    let started = Instant::now();
    let mut tasks = vec![tokio::spawn(discover(Arc::clone(shared)))];
    tasks.push(tokio::spawn(watch_events(Arc::clone(shared), started)));
    let connect = connect.clone();
    tasks.push(tokio::spawn(watch_bus(Arc::clone(shared), connect, started)));
    tasks.push(tokio::spawn(watch_clock(Arc::clone(shared))));
    tasks
}

/// Finds every node, asks each for its SNIP and PIP, and shows the table anew: a node that
/// was in it and did not answer goes; one learnt while the discovery ran stays (one that
/// introduced itself, or whose answer came after the quiet and was heard by the monitor).
pub(crate) async fn discover(shared: Arc<Shared>) {
    let before: BTreeSet<NodeId> = shared.nodes().keys().copied().collect();
    let found = match shared.node.discover(DISCOVER_QUIET, nodes::MOST_NODES).await {
        Ok(found) => found,
        Err(error) => {
            shared.push("notice", &serde_json::json!({ "error": format!("finding the nodes: {error}") }));
            return;
        }
    };
    let mut reports = std::collections::BTreeMap::new();
    for peer in found {
        reports.insert(peer, nodes::describe(&shared.node, peer).await);
    }
    let list: Vec<_> = {
        let mut table = shared.nodes();
        table.retain(|peer, _| !before.contains(peer));
        table.extend(reports);
        table.values().cloned().collect()
    };
    shared.push("nodes", &list);
}

/// Asks `peer` for its SNIP and PIP and puts it in the table (a node that introduced
/// itself, answered after a discovery's quiet, or sent something before we knew it).
pub(crate) async fn learn(shared: Arc<Shared>, peer: NodeId) {
    let report = nodes::describe(&shared.node, peer).await;
    let list: Vec<_> = {
        let mut table = shared.nodes();
        table.insert(peer, report);
        table.values().cloned().collect()
    };
    shared.push("nodes", &list);
}

/// Takes the node whose CAN alias is `alias` out of the table: its Alias Map Reset says that
/// it has left (or is about to take another alias, and so to introduce itself again).
fn forget(shared: &Shared, alias: &str) {
    let list: Vec<_> = {
        let mut table = shared.nodes();
        let before = table.len();
        table.retain(|_, report| report.alias.as_deref() != Some(alias));
        if table.len() == before {
            return;
        }
        table.values().cloned().collect()
    };
    shared.push("nodes", &list);
}

/// The name of `peer` in the table: its SNIP user name, else its model.
fn name_of(shared: &Shared, peer: NodeId) -> Option<String> {
    let table = shared.nodes();
    let snip = table.get(&peer)?.snip.as_ref()?;
    let name = if snip.user_name.is_empty() { &snip.model } else { &snip.user_name };
    Some(name.clone()).filter(|n| !n.is_empty())
}

fn hex(bytes: &[u8]) -> String {
    bytes.iter().map(|b| format!("{b:02X}")).collect()
}

/// A report or an identification as the page shows it.
pub(crate) fn identified(
    from: NodeId,
    role: EventRole,
    range: openlcb_tokio::EventRange,
    state: Option<EventState>,
) -> Identified {
    Identified {
        node: Peer::of(from).to_string(),
        role: crate::events::role_word(role),
        event: range.first().to_string(),
        last: range.last().to_string(),
        name: well_known(range.first()).filter(|_| range.is_single()),
        state: state.map(crate::events::state_word),
    }
}

async fn watch_events(shared: Arc<Shared>, started: Instant) {
    let mut notices = match shared.node.event_notices().await {
        Ok(notices) => notices,
        Err(error) => {
            tracing::info!(%error, "no event notices");
            return;
        }
    };
    while let Some(notice) = notices.next().await {
        let from = match &notice {
            EventNotice::Report { from, .. }
            | EventNotice::Learn { from, .. }
            | EventNotice::Identified { from, .. } => *from,
            _ => continue,
        };
        let known = shared.nodes().contains_key(&from);
        if !known && matches!(Peer::of(from), Peer::Node(_)) {
            tokio::spawn(learn(Arc::clone(&shared), from));
        }
        match notice {
            EventNotice::Report { from, event, payload } => report(&shared, started, from, event, &payload),
            EventNotice::Learn { from, event } => report(&shared, started, from, event, &[]),
            EventNotice::Identified { from, role, range, state } => {
                let row = identified(from, role, range, state);
                {
                    let mut gathered = shared.gathered();
                    if !gathered.identified.contains(&row) {
                        keep(&mut gathered.identified, row.clone(), KEPT_IDENTIFIED);
                    }
                }
                shared.push("identified", &row);
            }
            _ => {}
        }
    }
}

fn report(shared: &Shared, started: Instant, from: NodeId, event: EventId, payload: &[u8]) {
    let row = Report {
        time: started.elapsed().as_secs_f64(),
        event: event.to_string(),
        name: well_known(event),
        from: Peer::of(from).to_string(),
        from_name: name_of(shared, from),
        payload: hex(payload),
    };
    keep(&mut shared.gathered().reports, row.clone(), KEPT_REPORTS);
    shared.push("event", &row);
}

/// Listens to the bus as `monitor` does (a connection of its own, only listening) and
/// decodes it; a node's Initialization Complete, or a Verified Node ID from a node not in
/// the table, puts it there.
async fn watch_bus(shared: Arc<Shared>, connect: ConnectArgs, started: Instant) {
    if connect.serial.is_some() {
        shared.gathered().monitor_off =
            Some("the monitor listens through a hub or a CAN interface; a serial adapter has one user".into());
        return;
    }
    let mut stream = match connect.byte_stream().await {
        Ok(stream) => stream,
        Err(error) => {
            shared.gathered().monitor_off = Some(format!("no monitor: {error}"));
            return;
        }
    };
    let mut monitor = Monitor::default();
    let mut decoder = GridConnectDecoder::new();
    let mut buf = vec![0u8; 64 * 1024];
    let mut partial = Vec::new();
    let mut lines = Vec::new();
    loop {
        let n = match stream.read(&mut buf).await {
            Ok(0) | Err(_) => break,
            Ok(n) => n,
        };
        let time = started.elapsed().as_secs_f64();
        let bytes = buf.get(..n).unwrap_or_default();
        monitor::decode_text(&mut monitor, &mut decoder, time, bytes, &mut lines);
        let mut trace = Vec::new();
        for &byte in bytes {
            if byte == b'\n' {
                let text = String::from_utf8_lossy(&partial);
                let text = text.trim();
                if !text.is_empty() {
                    trace.push(format!("{time:.6} {text}"));
                }
                partial.clear();
            } else if partial.len() < 1024 {
                partial.push(byte);
            }
        }
        {
            let mut gathered = shared.gathered();
            for line in trace {
                if keep(&mut gathered.trace, line, KEPT_TRACE) {
                    gathered.trace_dropped += 1;
                }
            }
            for line in &lines {
                keep(&mut gathered.lines, line.clone(), KEPT_LINES);
            }
        }
        for line in lines.drain(..) {
            if line.message == "AMR" {
                forget(&shared, &line.source_alias);
            }
            // A Verified Node ID from a node not in the table: an answer to a discovery that
            // came after its quiet (a busy machine, a slow bus), or to another tool's Verify.
            let introduced = line.message.starts_with("Initialization Complete");
            let answered = line.message.starts_with("Verified Node ID");
            if (introduced || answered)
                && let Ok(peer) = line.detail.parse::<NodeId>()
                && peer != shared.node.node_id()
                && (introduced || !shared.nodes().contains_key(&peer))
            {
                tokio::spawn(learn(Arc::clone(&shared), peer));
            }
            shared.push("monitor", &line);
        }
    }
    shared.gathered().monitor_off = Some(format!("the monitor's connection to {} ended", connect.addr()));
}

/// The fast clock as the page shows it.
#[derive(Debug, Clone, Serialize, PartialEq)]
pub(crate) struct ClockView {
    /// Its name (`default-fast`, or its ID).
    pub(crate) clock: String,
    /// Its generator has been heard (else the rest is the consumer's guess).
    pub(crate) synchronized: bool,
    /// `1956-07-04 06:04:12`.
    pub(crate) time: String,
    pub(crate) rate: String,
    pub(crate) running: bool,
    /// As `clock --follow` prints it.
    pub(crate) text: String,
}

/// The clock's state now, if the node has it.
pub(crate) async fn clock_view(shared: &Shared) -> Option<ClockView> {
    let state = shared.node.clock(shared.clock).await.ok()??;
    Some(ClockView {
        clock: shared.clock.to_string(),
        synchronized: state.synchronized,
        time: state.time.to_string(),
        rate: state.rate.to_string(),
        running: state.running,
        text: crate::clock::state_text(shared.clock, &state),
    })
}

/// Shows the clock on every change (a minute begun, a set, a start or stop), after asking
/// its generator for its state.
async fn watch_clock(shared: Arc<Shared>) {
    let Ok(mut events) = shared.node.clock_events().await else { return };
    let _ = shared.node.query_clock(shared.clock).await;
    while events.next().await.is_some() {
        if let Some(view) = clock_view(&shared).await {
            shared.push("clock", &view);
        }
    }
}
