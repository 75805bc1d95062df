//! What `read`, `write` and `firmware` share: joining as a client node, finding the target,
//! running one Memory Configuration operation with a progress bar (each step logged with
//! `-v`), its outcome and the JSON report.

use std::process::ExitCode;
use std::time::{Duration, Instant};

use clap::Args;
use openlcb_stream::NodeId;
use openlcb_tokio::{Error, Join, MemoryTransfer, Node, NodeOptions, Protocols, TransferPath};
use serde::Serialize;

use crate::files;
use crate::net::{self, ConnectArgs};
use crate::outcome::{Failure, Missing, Outcome};
use crate::pace::{PACE_HELP, PaceArgs};
use crate::progress::Progress;

/// How long the target has to answer the Protocol Support Inquiry that finds it.
const FIND_TIMEOUT: Duration = Duration::from_secs(3);

/// The fields of `--json` of `read`, `write` and `firmware`, for their `--help`.
pub(crate) const JSON_HELP: &str = "\
--json prints one object on every exit path: node (the target), space, address, bytes (moved,
also before a failure), path (\"stream\" or \"datagrams\": what was used; \"none\" if nothing
moved), file, elapsed_s (from the first command, once on the network), bytes_per_s, result
(the word of the exit status below) and, on failure, error (the reason, worded for a person);
write adds warning when the node refused the Update Complete that follows the bytes.

";

/// The outcomes `read`, `write` and `firmware` can end with beside those of every command
/// that joins the network.
const OUTCOMES: &[Outcome] = &[
    Outcome::Usage,
    Outcome::Rejected,
    Outcome::TimedOut,
    Outcome::NotFound,
    Outcome::Terminated,
    Outcome::FileError,
    Outcome::BadAnswer,
];

/// The after-help of `read`, `write` and `firmware`, with `extra` before the exit statuses.
pub(crate) fn after_help(extra: &str) -> String {
    format!("{JSON_HELP}{PACE_HELP}{extra}{}", net::network_help(OUTCOMES))
}

/// Options every client command takes.
#[derive(Debug, Clone, Args)]
pub(crate) struct ClientArgs {
    /// Use datagrams only (64-byte chunks), never a stream.
    #[arg(long)]
    pub(crate) no_stream: bool,
    #[command(flatten)]
    pub(crate) node_id: net::TransientId,
    /// Print one JSON object (fields below) instead of text; no progress bar.
    #[arg(long)]
    pub(crate) json: bool,
    #[command(flatten)]
    pub(crate) pace: PaceArgs,
    #[command(flatten)]
    pub(crate) connect: ConnectArgs,
}

impl ClientArgs {
    pub(crate) fn path(&self) -> TransferPath {
        if self.no_stream { TransferPath::Datagrams } else { TransferPath::Auto }
    }
}

/// What one client command did, as `--json` prints it.
#[derive(Debug, Serialize)]
pub(crate) struct Report {
    pub(crate) node: String,
    pub(crate) space: u8,
    pub(crate) address: u32,
    pub(crate) bytes: u64,
    pub(crate) path: &'static str,
    pub(crate) file: String,
    pub(crate) elapsed_s: f64,
    pub(crate) bytes_per_s: f64,
    pub(crate) result: &'static str,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub(crate) error: Option<String>,
    /// What failed after the work was done (`write`: Update Complete refused).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub(crate) warning: Option<String>,
}

/// What a client command came to: the bytes moved (also before a failure), and how.
#[derive(Debug, Default)]
pub(crate) struct Moved {
    pub(crate) bytes: u64,
    pub(crate) by_stream: bool,
    /// When the first command went out (None: the network was never joined).
    pub(crate) started: Option<Instant>,
    /// The bytes a read had received when it was cut short (interrupted, or too slow):
    /// its first bytes, in order.
    pub(crate) cut_short: Vec<u8>,
}

impl Report {
    /// The report of an operation on `peer` that came to `moved`.
    pub(crate) fn new(peer: NodeId, space: u8, address: u32, file: &std::path::Path, moved: &Moved) -> Self {
        let elapsed_s = moved.started.map_or(0.0, |started| started.elapsed().as_secs_f64());
        let path = match (moved.bytes, moved.by_stream) {
            (0, false) => "none",
            (_, true) => "stream",
            (_, false) => "datagrams",
        };
        Report {
            node: peer.to_string(),
            space,
            address,
            bytes: moved.bytes,
            path,
            file: file.display().to_string(),
            elapsed_s,
            bytes_per_s: net::rate(moved.bytes, elapsed_s),
            result: Outcome::Ok.word(),
            error: None,
            warning: None,
        }
    }
}

/// Joins the network as the client node and makes sure `peer` is there (exit 5 if not).
/// The work starts as soon as the alias is permitted ([`Join::AtLogin`], as OpenMRN's tools
/// do): a claim of this tool's Node ID within the newcomer window then fails the command
/// with the words of a duplicate Node ID, instead of holding every command 100 ms.
pub(crate) async fn join(args: &ClientArgs, command: &str, peer: NodeId) -> Result<Node, Failure> {
    let node = args.connect.join(&args.node_id, |id| {
        let mut options = NodeOptions::new(id);
        options.node.snip = net::snip(command);
        options.join = Join::AtLogin;
        options
    });
    let node = node.await?;
    find(&node, peer).await?;
    Ok(node)
}

/// Makes sure `peer` is there and has Memory Configuration (exit 5 if it is not there).
pub(crate) async fn find(node: &Node, peer: NodeId) -> Result<(), Failure> {
    tracing::info!(%peer, "asking for the node's protocols (PIP)");
    match node.protocols(peer, FIND_TIMEOUT).await {
        Ok(protocols) if protocols.contains(Protocols::MEMORY_CONFIGURATION) => {
            tracing::info!(%peer, protocols = %protocols.names().collect::<Vec<_>>().join(" "), "found the node");
            Ok(())
        }
        Ok(_) => Err(Failure::Lacks { peer, missing: Missing::Configuration, code: None }),
        Err(Error::NoAnswer { .. }) => Err(Failure::Net(Error::Unreachable(peer))),
        Err(error) => Err(Failure::Net(error)),
    }
}

/// `failure`, or, when it is a "not implemented" refusal from `peer` and the node's PIP
/// (asked now, within [`FIND_TIMEOUT`]) lists no protocol of `missing`, the words for that.
/// A PIP that does not come keeps `failure` as it is.
pub(crate) async fn name_what_is_missing(node: &Node, peer: NodeId, failure: Failure, missing: Missing) -> Failure {
    let Some(code) = failure.not_implemented_code() else { return failure };
    tracing::info!(%peer, %code, "asking the node's protocols (PIP) about a refusal");
    match node.protocols(peer, FIND_TIMEOUT).await {
        Ok(protocols) if !missing.is_in(protocols) => Failure::Lacks { peer, missing, code: Some(code) },
        _ => failure,
    }
}

/// Waits for `transfer` (of `total` bytes, if known) to end, showing its progress unless
/// `json`, until interrupted, or until it falls behind `pace` (then it is cancelled, and a
/// read's bytes so far go to `moved.cut_short`); `moved` follows the bytes and the path.
pub(crate) async fn follow<T>(
    node: &Node,
    mut transfer: MemoryTransfer<T>,
    total: Option<u64>,
    json: bool,
    pace: &PaceArgs,
    interrupt: &mut net::Interrupt,
    moved: &mut Moved,
) -> Result<T, Failure> {
    let started = Instant::now();
    let streams_before = stream_messages(node).await;
    let bar = Progress::start(total, json);
    let mut progress = transfer.watch_progress();
    let watched = transfer.watch_progress();
    let slow = pace.watch(started, total, || *watched.borrow());
    tokio::pin!(slow);
    let result = {
        let end = transfer.wait();
        tokio::pin!(end);
        loop {
            tokio::select! {
                result = &mut end => break result.map_err(Failure::Net),
                Ok(()) = progress.changed() => {
                    moved.bytes = *progress.borrow_and_update();
                    bar.set(moved.bytes);
                    interrupt.progress(moved.bytes, total);
                }
                slow = &mut slow => break Err(Failure::TooSlow(slow)),
                () = interrupt.wait() => break Err(Failure::Interrupted),
            }
        }
    };
    if let Err(Failure::Interrupted | Failure::TooSlow(_)) = &result {
        // The wait did not end: the operation still runs.
        moved.cut_short = transfer.cancel().await;
    }
    bar.finish();
    moved.bytes = moved.bytes.max(*progress.borrow());
    moved.by_stream = stream_messages(node).await > streams_before;
    tracing::info!(bytes = moved.bytes, by_stream = moved.by_stream, ok = result.is_ok(), "the operation ended");
    result
}

/// Stream messages this node has sent (a request or a reply, Proceeds, data): more after an
/// operation than before means that it went by stream. (Messages in would not tell: the
/// endpoint sees every message the node handles.)
async fn stream_messages(node: &Node) -> u64 {
    node.stats().await.map_or(0, |s| u64::from(s.endpoint.messages_out))
}

/// Sends `peer` Update Complete and waits for its answer (not shown: it moves no bytes).
pub(crate) async fn update_complete(
    node: &Node,
    peer: NodeId,
    pace: &PaceArgs,
    interrupt: &mut net::Interrupt,
) -> Result<(), Failure> {
    let transfer = node.update_complete(peer).await.map_err(Failure::Net)?;
    follow(node, transfer, None, true, pace, interrupt, &mut Moved::default()).await?;
    Ok(())
}

/// The words for an Update Complete that failed after the bytes were written and verified.
pub(crate) fn update_complete_warning(failure: &Failure) -> String {
    format!(
        "what was written stays written, but Update Complete failed ({failure}): the node may apply it only \
         after a reboot (`lcc-stream reboot NODE`)"
    )
}

/// What `write` and `firmware` put into a node.
pub(crate) enum Upload {
    /// The bytes of a file into `space` from `address`, then Update Complete unless
    /// `update_complete` is false.
    Space { space: u8, address: u32, update_complete: bool },
    /// A firmware image (space 0xEF from 0, between Freeze and Unfreeze).
    Firmware,
}

/// Runs `write` or `firmware`: the file's bytes (read, and so checked, before the network is
/// touched) into `peer`, with a progress bar, then the report; `done` words the success for
/// a person.
pub(crate) async fn upload(
    client: &ClientArgs,
    command: &str,
    peer: NodeId,
    file: &std::path::Path,
    what: Upload,
    done: impl FnOnce(&Report) -> String,
) -> Result<ExitCode, String> {
    let mut interrupt = net::Interrupt::new()?;
    let (space, address) = match what {
        Upload::Space { space, address, .. } => (space, address),
        Upload::Firmware => (SPACE_FIRMWARE, 0),
    };
    let mut moved = Moved::default();
    let mut warning = None;
    let outcome = async {
        let data = files::read_all(file).await?;
        let total = data.len() as u64;
        tracing::info!(file = %file.display(), bytes = total, "read the file");
        let node = join(client, command, peer).await?;
        moved.started = Some(Instant::now());
        tracing::info!(%peer, space = format!("0x{space:02X}"), address, bytes = total, "writing");
        let transfer = match what {
            Upload::Space { space, address, .. } => node.write_memory(peer, space, address, data, client.path()).await,
            Upload::Firmware => node.upgrade_firmware(peer, data, client.path()).await,
        };
        let written = match transfer {
            Ok(transfer) => {
                follow(&node, transfer, Some(total), client.json, &client.pace, &mut interrupt, &mut moved).await
            }
            Err(error) => Err(Failure::Net(error)),
        };
        let mut written = match (written, &what) {
            (Err(failure), Upload::Firmware) => {
                Err(name_what_is_missing(&node, peer, failure, Missing::FirmwareUpgrade).await)
            }
            (written, _) => written,
        };
        if written.is_ok()
            && let Upload::Space { update_complete: true, .. } = what
        {
            match update_complete(&node, peer, &client.pace, &mut interrupt).await {
                Err(Failure::Interrupted) => written = Err(Failure::Interrupted),
                Err(failure) => warning = Some(update_complete_warning(&failure)),
                Ok(()) => {}
            }
        }
        node.close().await;
        written
    }
    .await;
    let mut report = Report::new(peer, space, address, file, &moved);
    if let Some(warning) = warning {
        eprintln!("lcc-stream {command}: warning: {warning}");
        report.warning = Some(warning);
    }
    let text = outcome.map(|_| done(&report));
    Ok(finish(report, text, client.json, command))
}

/// Refuses to go on when `out` exists: no command writes over a file.
pub(crate) async fn refuse_existing(out: &std::path::Path) -> Result<(), Failure> {
    if tokio::fs::try_exists(out).await.map_err(|e| Failure::file(out, e))? {
        let taken = std::io::Error::new(std::io::ErrorKind::AlreadyExists, "the output file exists");
        return Err(Failure::file(out, taken));
    }
    Ok(())
}

/// Writes `bytes` to `out` through `out.part`, never over an existing file.
pub(crate) async fn save_new(out: &std::path::Path, bytes: &[u8]) -> Result<(), Failure> {
    let part = crate::recv::part_path(out);
    tokio::fs::write(&part, bytes).await.map_err(|e| Failure::file(&part, e))?;
    crate::recv::publish(&part, out).await.map_err(|e| Failure::file(out, e))
}

/// The firmware space.
const SPACE_FIRMWARE: u8 = 0xEF;

/// Prints `report` (text or JSON) and returns the exit status.
pub(crate) fn finish(report: Report, outcome: Result<String, Failure>, json: bool, command: &str) -> ExitCode {
    let (status, report) = match outcome {
        Ok(text) => {
            if !json && !text.is_empty() {
                net::say(&text);
            }
            (0, report)
        }
        Err(failure) => {
            eprintln!("lcc-stream {command}: {failure}");
            if let (Failure::Interrupted, SPACE_FIRMWARE) = (&failure, report.space) {
                eprintln!("lcc-stream {command}: {FIRMWARE_INTERRUPTED}");
            }
            let outcome = failure.outcome();
            let error = match (&failure, report.space) {
                (Failure::Interrupted, SPACE_FIRMWARE) => format!("interrupted; {FIRMWARE_INTERRUPTED}"),
                _ => failure.to_string(),
            };
            (outcome.status(), Report { result: outcome.word(), error: Some(error), ..report })
        }
    };
    if json {
        net::print_json(&report);
    }
    ExitCode::from(status)
}

/// What an interrupted firmware upgrade leaves behind, and how to finish it.
pub(crate) const FIRMWARE_INTERRUPTED: &str = "the node was left in firmware upgrade mode (frozen, space 0xEF \
partly written); run the same `lcc-stream firmware` command again to finish, or power-cycle the \
node if its bootloader falls back to the old image";

/// A number as `0xFD`, `0XFD` or `253`.
pub(crate) fn parse_number<T: TryFrom<u64>>(text: &str) -> Result<T, String> {
    let value = match text.strip_prefix("0x").or_else(|| text.strip_prefix("0X")) {
        Some(hex) => u64::from_str_radix(hex, 16),
        None => text.parse(),
    }
    .map_err(|e| format!("not a number: {e}"))?;
    T::try_from(value).map_err(|_| format!("{text} is out of range"))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn numbers_parse_in_hex_and_decimal() {
        assert_eq!(parse_number::<u8>("0xFD"), Ok(0xFD));
        assert_eq!(parse_number::<u8>("253"), Ok(253));
        assert_eq!(parse_number::<u32>("0X10"), Ok(16));
        assert!(parse_number::<u8>("0x100").is_err());
        assert!(parse_number::<u8>("fd").is_err());
    }
}
