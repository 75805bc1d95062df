//! What `read`, `write` and `firmware` share: joining as a client node, finding the target,
//! running one Memory Configuration operation with a progress bar, exit statuses and the
//! JSON report.

use std::io::IsTerminal as _;
use std::process::ExitCode;
use std::time::{Duration, Instant};

use clap::Args;
use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};
use openlcb_stream::NodeId;
use openlcb_tokio::openlcb_node::MemoryError;
use openlcb_tokio::{Error, MemoryTransfer, Node, NodeOptions, Protocols, TransferPath};
use serde::Serialize;

use crate::net::{self, ConnectArgs};

/// The Node ID `read`, `write` and `firmware` use unless told otherwise.
pub(crate) const DEFAULT_CLIENT: &str = "05.01.01.01.22.F3";

/// How long the target has to answer the Protocol Support Inquiry that finds it.
const FIND_TIMEOUT: Duration = Duration::from_secs(3);

/// The fields of `--json` of `read`, `write` and `firmware`, for their `--help`.
macro_rules! json_help {
    () => {
        "\
--json prints one object: node (the target), space, address, bytes (moved), path (\"stream\"
or \"datagrams\": what was asked; \"auto\" lets the target's answers decide), file,
elapsed_s (from the first command, once on the network), bytes_per_s, result (\"ok\", \"rejected\", \"timed_out\", \"not_found\",
\"connection_lost\", \"terminated\", \"file_error\", \"interrupted\", \"error\") and, on failure,
error (the reason, worded for a person).

"
    };
}
pub(crate) use json_help;

/// Options every client command takes.
#[derive(Debug, Args)]
pub(crate) struct ClientArgs {
    /// Use datagrams only (64-byte chunks), never a stream.
    #[arg(long)]
    pub(crate) no_stream: bool,
    /// This node's Node ID.
    #[arg(long, value_name = "NODE_ID", default_value = DEFAULT_CLIENT)]
    pub(crate) node_id: NodeId,
    /// Print one JSON object (fields below) instead of text; no progress bar.
    #[arg(long)]
    pub(crate) json: bool,
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
}

impl Report {
    /// The report of a successful operation that moved `bytes` since `started`.
    pub(crate) fn new(
        peer: NodeId,
        space: u8,
        address: u32,
        file: &std::path::Path,
        path: TransferPath,
        bytes: u64,
        started: Instant,
    ) -> Self {
        let elapsed_s = started.elapsed().as_secs_f64();
        Report {
            node: peer.to_string(),
            space,
            address,
            bytes,
            path: path_word(path),
            file: file.display().to_string(),
            elapsed_s,
            bytes_per_s: net::rate(bytes, elapsed_s),
            result: "ok",
            error: None,
        }
    }
}

/// Why a client command stopped.
pub(crate) enum Stop {
    Net(Error),
    File(std::io::Error),
    Interrupted,
}

impl Stop {
    fn status(&self) -> u8 {
        match self {
            Stop::Net(error) => status(error),
            Stop::File(_) => net::EXIT_FILE,
            Stop::Interrupted => net::EXIT_INTERRUPTED,
        }
    }

    fn word(&self) -> &'static str {
        match self {
            Stop::Net(Error::Unreachable(_)) => "not_found",
            Stop::Net(error @ Error::Memory { .. }) => match status(error) {
                4 => "rejected",
                5 => "timed_out",
                6 => "connection_lost",
                7 => "terminated",
                _ => "error",
            },
            Stop::Net(error) => net::result_word(error),
            Stop::File(_) => "file_error",
            Stop::Interrupted => "interrupted",
        }
    }
}

impl std::fmt::Display for Stop {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Stop::Net(error) => write!(f, "{error}"),
            Stop::File(error) => write!(f, "{error}"),
            Stop::Interrupted => write!(f, "interrupted"),
        }
    }
}

/// The exit status for `error`: net.rs's, with Memory Configuration's failures sorted in.
fn status(error: &Error) -> u8 {
    match error {
        Error::Memory { error, .. } => match error {
            MemoryError::Rejected(_) | MemoryError::Failed(_) | MemoryError::StreamRejected(_) => 4,
            MemoryError::NoStreams | MemoryError::Locked { .. } => 4,
            MemoryError::TimedOut | MemoryError::StreamTimedOut(_) => 5,
            MemoryError::PeerLost => 5,
            MemoryError::StreamEnded(_) | MemoryError::WrongLength { .. } | MemoryError::PeerRestarted => 7,
            _ => 1,
        },
        error => net::exit_status(error),
    }
}

/// Joins the network as the client node and makes sure `peer` is there (exit 5 if not).
pub(crate) async fn join(args: &ClientArgs, command: &str, peer: NodeId) -> Result<Node, Stop> {
    let mut options = NodeOptions::new(args.node_id);
    options.node.snip = net::snip(command);
    let node = args.connect.node(options).await.map_err(Stop::Net)?;
    match node.protocols(peer, FIND_TIMEOUT).await {
        Ok(protocols) if protocols.contains(Protocols::MEMORY_CONFIGURATION) => Ok(node),
        Ok(_) => Err(Stop::Net(Error::Memory { peer, error: MemoryError::Rejected(NOT_IMPLEMENTED) })),
        Err(Error::NoAnswer { .. }) => Err(Stop::Net(Error::Unreachable(peer))),
        Err(error) => Err(Stop::Net(error)),
    }
}

/// The code of a node that does not implement Memory Configuration (OIR 0x1042).
const NOT_IMPLEMENTED: openlcb_stream::wire::ErrorCode = openlcb_stream::wire::ErrorCode(0x1042);

/// A progress bar on stderr, drawn only on a terminal and without `--json`.
fn progress_bar(total: Option<u64>, json: bool) -> ProgressBar {
    let target = if json || !std::io::stderr().is_terminal() {
        ProgressDrawTarget::hidden()
    } else {
        ProgressDrawTarget::stderr()
    };
    let bar = ProgressBar::with_draw_target(total, target);
    let template = if total.is_some() {
        "{bar:30} {bytes}/{total_bytes} {bytes_per_sec} ETA {eta}"
    } else {
        "{spinner} {bytes} {bytes_per_sec}"
    };
    if let Ok(style) = ProgressStyle::with_template(template) {
        bar.set_style(style);
    }
    bar
}

/// Waits for `transfer` (of `total` bytes, if known) to end, showing its progress unless
/// `json`, or until interrupted.
pub(crate) async fn follow<T>(
    transfer: MemoryTransfer<T>,
    total: Option<u64>,
    json: bool,
    interrupt: &mut net::Interrupt,
) -> Result<T, Stop> {
    let bar = progress_bar(total, json);
    let mut progress = transfer.watch_progress();
    let end = transfer.finish();
    tokio::pin!(end);
    loop {
        tokio::select! {
            result = &mut end => {
                bar.finish_and_clear();
                return result.map_err(Stop::Net);
            }
            Ok(()) = progress.changed() => bar.set_position(*progress.borrow_and_update()),
            () = interrupt.wait() => {
                bar.abandon();
                return Err(Stop::Interrupted);
            }
        }
    }
}

/// What `write` and `firmware` put into a node.
pub(crate) enum Upload {
    /// The bytes of a file into `space` from `address`.
    Space { space: u8, address: u32 },
    /// A firmware image (space 0xEF from 0, between Freeze and Unfreeze).
    Firmware,
}

/// Runs `write` or `firmware`: the file's bytes into `peer`, with a progress bar, then the
/// report; `done` words the success for a person.
pub(crate) async fn upload(
    client: &ClientArgs,
    command: &str,
    peer: NodeId,
    file: &std::path::Path,
    what: Upload,
    done: impl FnOnce(&Report) -> String,
) -> Result<ExitCode, String> {
    let mut interrupt = net::Interrupt::new()?;
    let mut started = Instant::now();
    let (space, address) = match what {
        Upload::Space { space, address } => (space, address),
        Upload::Firmware => (SPACE_FIRMWARE, 0),
    };
    let outcome = async {
        let data = tokio::fs::read(file).await.map_err(Stop::File)?;
        let total = data.len() as u64;
        let node = join(client, command, peer).await?;
        started = Instant::now();
        let transfer = match what {
            Upload::Space { space, address } => node.write_memory(peer, space, address, data, client.path()).await,
            Upload::Firmware => node.upgrade_firmware(peer, data, client.path()).await,
        };
        let written = follow(transfer.map_err(Stop::Net)?, Some(total), client.json, &mut interrupt).await;
        node.close().await;
        written
    }
    .await;
    let bytes = *outcome.as_ref().unwrap_or(&0);
    let report = Report::new(peer, space, address, file, client.path(), bytes, started);
    let text = outcome.map(|_| done(&report));
    Ok(finish(report, text, client.json, command))
}

/// The firmware space.
const SPACE_FIRMWARE: u8 = 0xEF;

/// Prints `report` (text or JSON) and returns the exit status.
pub(crate) fn finish(report: Report, outcome: Result<String, Stop>, json: bool, command: &str) -> ExitCode {
    let (status, report) = match outcome {
        Ok(text) => {
            if !json {
                println!("{text}");
            }
            (0, report)
        }
        Err(stop) => {
            if !json {
                eprintln!("lcc-stream {command}: {stop}");
            }
            let error = Some(stop.to_string());
            (stop.status(), Report { result: stop.word(), error, ..report })
        }
    };
    if json {
        match serde_json::to_string(&report) {
            Ok(line) => println!("{line}"),
            Err(error) => eprintln!("lcc-stream {command}: {error}"),
        }
    }
    ExitCode::from(status)
}

/// The words of a path for reports.
fn path_word(path: TransferPath) -> &'static str {
    match path {
        TransferPath::Datagrams => "datagrams",
        TransferPath::Stream => "stream",
        _ => "auto",
    }
}

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
