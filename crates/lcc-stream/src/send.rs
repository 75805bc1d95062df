//! `lcc-stream send`: join the network as a node and send a file as one stream.

use std::path::PathBuf;
use std::process::ExitCode;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::{Duration, Instant};

use bytes::BytesMut;
use clap::Args;
use openlcb_stream::{AcceptPolicy, ContentUid, NodeId, OpenOptions, wire::ReplyCode};
use openlcb_tokio::{Error, Node, NodeOptions};
use serde::Serialize;
use tokio::io::AsyncReadExt as _;

use crate::net::{self, ConnectArgs};
use crate::progress::Progress;

/// The Node ID `send` uses unless told otherwise (from the range of the examples of this
/// project; pick your own from a range you own on a real layout).
pub(crate) const DEFAULT_SENDER: &str = "05.01.01.01.22.F0";

/// Bytes read from the file and handed to the stream at once.
const CHUNK: usize = 64 * 1024;

/// What exit status 0 of `send` promises (also in the README).
macro_rules! send_promise {
    () => {
        "\
Exit status 0 means: the receiver accepted the stream, granted credit for every byte, and
every byte and the Data Complete stating the byte count were written to the hub connection.
It does not mean that the receiver has stored the data: a receiver that fails after that
(disk full, killed) is not seen by `send`. `lcc-stream recv` reports and renames a file only
once every stated byte has arrived.

"
    };
}

/// The fields of `send --json`.
macro_rules! send_json {
    () => {
        "\
--json prints one object: file, to (Node ID), bytes (sent), elapsed_s, bytes_per_s, window
(negotiated on success, else the one proposed), result (ok, unreachable_hub, rejected,
timed_out, connection_lost, terminated, duplicate_node_id or error), and frames_out and
writes (on success) or error (a sentence).

"
    };
}

/// Options of `lcc-stream send`.
#[derive(Debug, Args)]
#[command(after_help = concat!(send_promise!(), send_json!(), net::exit_help!()))]
pub(crate) struct SendArgs {
    /// The file to send.
    file: PathBuf,
    /// The receiving node, e.g. 05.01.01.01.22.F1 (the default of `lcc-stream recv`); also
    /// 05:01:01:01:22:F1, 0501010122F1 or 0x0501010122F1.
    #[arg(long, value_name = "NODE_ID", value_parser = crate::args::node_id)]
    to: NodeId,
    /// This node's Node ID.
    #[arg(long, value_name = "NODE_ID", value_parser = crate::args::node_id, default_value = DEFAULT_SENDER)]
    node_id: NodeId,
    /// Window (Max Buffer Size) to propose, 1..=65535; the receiver may lower it.
    #[arg(long, default_value_t = 65535, value_parser = clap::value_parser!(u16).range(1..))]
    window: u16,
    /// Stream Content UID to send with the request (six bytes, like a Node ID).
    #[arg(long, value_name = "UID")]
    content_uid: Option<ContentUid>,
    /// Seconds to wait for the receiver's answer, for credit once it has run out (one deadline
    /// from that moment), and for the hub to take data the socket holds.
    #[arg(long, value_name = "SECS", default_value_t = 20, value_parser = crate::args::positive::<u64>)]
    timeout: u64,
    /// Print one JSON object instead of text.
    #[arg(long)]
    json: bool,
    #[command(flatten)]
    connect: ConnectArgs,
}

/// `send --json`: one object (see the help for its fields).
#[derive(Debug, Serialize)]
struct SendReport {
    file: String,
    to: String,
    bytes: u64,
    elapsed_s: f64,
    bytes_per_s: f64,
    window: u16,
    #[serde(skip_serializing_if = "Option::is_none")]
    frames_out: Option<u64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    writes: Option<u64>,
    result: &'static str,
    #[serde(skip_serializing_if = "Option::is_none")]
    error: Option<String>,
}

impl SendReport {
    /// The report of a transfer that came to `summary` and ended with `outcome`.
    fn new(args: &SendArgs, summary: &Summary, outcome: Result<(), &Error>) -> Self {
        let ok = outcome.is_ok();
        SendReport {
            file: args.file.display().to_string(),
            to: args.to.to_string(),
            bytes: summary.bytes,
            elapsed_s: summary.elapsed.as_secs_f64(),
            bytes_per_s: net::rate(summary.bytes, summary.elapsed.as_secs_f64()),
            window: summary.window,
            frames_out: ok.then_some(summary.frames_out),
            writes: ok.then_some(summary.writes),
            result: outcome.map_or_else(net::result_word, |()| "ok"),
            error: outcome.err().map(ToString::to_string),
        }
    }
}

/// What a transfer came to.
struct Summary {
    bytes: u64,
    elapsed: Duration,
    window: u16,
    frames_out: u64,
    writes: u64,
}

pub(crate) fn run(args: &SendArgs) -> Result<ExitCode, String> {
    net::runtime()?.block_on(send(args))
}

async fn send(args: &SendArgs) -> Result<ExitCode, String> {
    let mut file = match tokio::fs::File::open(&args.file).await {
        Ok(file) => file,
        Err(error) => {
            eprintln!("lcc-stream send: cannot read {}: {error}", args.file.display());
            return Ok(ExitCode::from(net::EXIT_FILE));
        }
    };
    let size = file.metadata().await.map(|m| m.len()).ok();
    let mut options = NodeOptions::new(args.node_id);
    options.node.snip = net::snip("send");
    options.node.stream.accept_policy = AcceptPolicy::RejectAll(ReplyCode::STREAMS_NOT_SUPPORTED);
    options.node.stream.reply_timeout = Duration::from_secs(args.timeout).into();
    options.node.stream.proceed_timeout = Duration::from_secs(args.timeout).into();
    options.write_timeout = Duration::from_secs(args.timeout);
    let report_error = |error: &Error, bytes: u64, elapsed: Duration| {
        if args.json {
            let summary = Summary { bytes, elapsed, window: args.window, frames_out: 0, writes: 0 };
            net::print_json(&SendReport::new(args, &summary, Err(error)));
        }
        net::fail("send", error)
    };

    let started = Instant::now();
    let mut interrupt = net::Interrupt::new()?;
    let connect = args.connect.node(options);
    let node = tokio::select! {
        connected = connect => match connected {
            Ok(node) => node,
            Err(error) => return Ok(report_error(&error, 0, started.elapsed())),
        },
        () = interrupt.wait() => return Ok(ExitCode::from(net::EXIT_INTERRUPTED)),
    };
    let written = AtomicU64::new(0);
    let outcome = tokio::select! {
        outcome = transfer(args, &node, &mut file, size, &written) => outcome,
        () = interrupt.wait() => Err(Stop::Interrupted),
    };
    // On an interrupt the stream was dropped inside `transfer`, which queued its TDE: the
    // orderly close writes it before the connection goes.
    let stats = node.stats().await.map(|s| s.wire).unwrap_or_default();
    node.close().await;
    let summary = match outcome {
        Ok(summary) => summary,
        Err(Stop::Failed(error)) => {
            return Ok(report_error(&error, written.load(Ordering::Relaxed), started.elapsed()));
        }
        Err(Stop::File(error)) => {
            eprintln!("lcc-stream send: cannot read {}: {error}", args.file.display());
            return Ok(ExitCode::from(net::EXIT_FILE));
        }
        Err(Stop::Interrupted) => {
            eprintln!(
                "lcc-stream send: interrupted after {} bytes; the stream was terminated (TDE 0x2000, temporary error)",
                written.load(Ordering::Relaxed)
            );
            return Ok(ExitCode::from(net::EXIT_INTERRUPTED));
        }
    };
    let summary = Summary { frames_out: stats.frames_out, writes: stats.writes, ..summary };
    if args.json {
        net::print_json(&SendReport::new(args, &summary, Ok(())));
    } else {
        println!(
            "sent {} bytes to {} in {:.3} s ({}), window {}, {} frames in {} writes",
            summary.bytes,
            args.to,
            summary.elapsed.as_secs_f64(),
            net::rate_text(net::rate(summary.bytes, summary.elapsed.as_secs_f64())),
            summary.window,
            summary.frames_out,
            summary.writes
        );
    }
    Ok(ExitCode::SUCCESS)
}

/// Why a transfer stopped early.
enum Stop {
    Failed(Error),
    File(std::io::Error),
    Interrupted,
}

/// Opens the stream, sends the file and finishes; `written` follows the progress.
async fn transfer(
    args: &SendArgs,
    node: &Node,
    file: &mut tokio::fs::File,
    size: Option<u64>,
    written: &AtomicU64,
) -> Result<Summary, Stop> {
    let mut open = OpenOptions::new(args.to, args.window);
    open.content_uid = args.content_uid;
    let mut stream = node.open(open).await.map_err(Stop::Failed)?;
    let window = stream.info().window;
    let progress = Progress::start(size, args.json);
    // Read the next chunk while the previous one goes out.
    let started = Instant::now();
    let mut next = read_chunk(file).await;
    let outcome = loop {
        let chunk = match next {
            Ok(chunk) if chunk.is_empty() => break Ok(()),
            Ok(chunk) => chunk.freeze(),
            Err(error) => break Err(Stop::File(error)),
        };
        let (sent, read) = tokio::join!(stream.write_all(chunk), read_chunk(file));
        if let Err(error) = sent {
            break Err(Stop::Failed(error));
        }
        written.store(stream.written(), Ordering::Relaxed);
        next = read;
        progress.set(stream.written());
    };
    progress.finish();
    outcome?;
    let bytes = stream.finish().await.map_err(Stop::Failed)?;
    Ok(Summary { bytes, elapsed: started.elapsed(), window, frames_out: 0, writes: 0 })
}

async fn read_chunk(file: &mut tokio::fs::File) -> std::io::Result<BytesMut> {
    let mut chunk = BytesMut::with_capacity(CHUNK);
    while chunk.len() < CHUNK {
        if file.read_buf(&mut chunk).await? == 0 {
            break;
        }
    }
    Ok(chunk)
}
