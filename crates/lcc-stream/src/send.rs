//! `lcc-stream send`: join the network as a node and send a file as one stream.

use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::sync::OnceLock;
use std::sync::atomic::{AtomicU16, Ordering};
use std::time::{Duration, Instant};

use bytes::BytesMut;
use clap::Args;
use openlcb_stream::{AcceptPolicy, ContentUid, NodeId, OpenOptions, wire::ReplyCode};
use openlcb_tokio::{Node, NodeOptions, SentBytes};
use serde::Serialize;
use tokio::io::AsyncReadExt as _;

use crate::files;
use crate::memory;
use crate::net::{self, ConnectArgs};
use crate::outcome::{Failure, Missing, Outcome};
use crate::pace::{PACE_HELP, PaceArgs};
use crate::progress::Progress;

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
const SEND_JSON: &str = "\
--json prints one object on every exit path: file, to (Node ID), bytes (handed to the bus in
Data Send messages, also on failure: what the receiver can have got, never less), elapsed_s,
bytes_per_s, window (negotiated once the stream opened, else the one proposed), result (the
word of the exit status below), and frames_out and writes (on success) or error (a sentence).

";

/// The outcomes `send` can end with.
const OUTCOMES: &[Outcome] =
    &[Outcome::Rejected, Outcome::TimedOut, Outcome::NotFound, Outcome::Terminated, Outcome::FileError];

/// `send`'s after-help.
fn after_help() -> String {
    format!("{}{SEND_JSON}{PACE_HELP}{}", send_promise!(), net::network_help(OUTCOMES))
}

/// Options of `lcc-stream send`.
#[derive(Debug, Args)]
#[command(after_help = after_help())]
pub(crate) struct SendArgs {
    /// The file to send (`-`: stdin), checked before the network is touched.
    file: PathBuf,
    /// The receiving node, e.g. 05.01.01.01.22.F1 (the default of `lcc-stream recv`); also
    /// 05:01:01:01:22:F1, 0501010122F1 or 0x0501010122F1.
    #[arg(long, value_name = "NODE_ID", value_parser = crate::args::node_id)]
    to: NodeId,
    #[command(flatten)]
    node_id: net::TransientId,
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
    pace: PaceArgs,
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
    fn new(args: &SendArgs, summary: &Summary, outcome: Result<(), &Failure>) -> Self {
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
            result: outcome.map_or_else(|failure| failure.outcome().word(), |()| Outcome::Ok.word()),
            error: outcome.err().map(ToString::to_string),
        }
    }
}

/// What a transfer came to.
#[derive(Default)]
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
    let mut interrupt = net::Interrupt::new()?;
    let started = Instant::now();
    let summary = Summary { window: args.window, ..Summary::default() };
    let sent = OnceLock::new();
    let window = AtomicU16::new(args.window);
    let outcome = connect_and_send(args, &mut interrupt, &sent, &window).await;
    let summary = match outcome {
        Ok(summary) => summary,
        Err(failure) => {
            let bytes = sent.get().map_or(0, SentBytes::get);
            let summary =
                Summary { bytes, elapsed: started.elapsed(), window: window.load(Ordering::Relaxed), ..summary };
            if args.json {
                net::print_json(&SendReport::new(args, &summary, Err(&failure)));
            }
            if let Failure::Interrupted = failure {
                eprintln!(
                    "lcc-stream send: interrupted after {bytes} bytes handed to the bus (the receiver can have \
                     got that many, no more); an open stream was terminated (TDE 0x2000, temporary error)"
                );
            } else if sent.get().is_some() {
                eprintln!("lcc-stream send: {failure} ({bytes} bytes had been handed to the bus)");
            } else {
                eprintln!("lcc-stream send: {failure}");
            }
            return Ok(ExitCode::from(failure.outcome().status()));
        }
    };
    if args.json {
        net::print_json(&SendReport::new(args, &summary, Ok(())));
    } else {
        net::say(&format!(
            "sent {} bytes to {} in {:.3} s ({}), window {}, {} frames in {} writes",
            summary.bytes,
            args.to,
            summary.elapsed.as_secs_f64(),
            net::rate_text(net::rate(summary.bytes, summary.elapsed.as_secs_f64())),
            summary.window,
            summary.frames_out,
            summary.writes
        ));
    }
    Ok(ExitCode::SUCCESS)
}

/// Checks the file, joins, sends, and closes the node, also when interrupted.
async fn connect_and_send(
    args: &SendArgs,
    interrupt: &mut net::Interrupt,
    sent: &OnceLock<SentBytes>,
    window: &AtomicU16,
) -> Result<Summary, Failure> {
    let (mut input, size) = Input::open(&args.file).await?;
    let node = args.connect.join(&args.node_id, |id| {
        let mut options = NodeOptions::new(id);
        options.node.snip = net::snip("send");
        options.node.stream.accept_policy = AcceptPolicy::RejectAll(ReplyCode::STREAMS_NOT_SUPPORTED);
        options.node.stream.reply_timeout = Duration::from_secs(args.timeout).into();
        options.node.stream.proceed_timeout = Duration::from_secs(args.timeout).into();
        options.write_timeout = Duration::from_secs(args.timeout);
        options
    });
    let node = tokio::select! {
        node = node => node?,
        () = interrupt.wait() => return Err(Failure::Interrupted),
    };
    // On an interrupt the stream is dropped inside `transfer`, which queues its TDE: the
    // orderly close writes it before the connection goes.
    let outcome = tokio::select! {
        outcome = transfer(args, &node, &mut input, size, sent, window) => outcome,
        () = interrupt.wait() => Err(Failure::Interrupted),
    };
    let outcome = match outcome {
        Err(failure) => Err(memory::name_what_is_missing(&node, args.to, failure, Missing::Streams).await),
        done => done,
    };
    let stats = node.stats().await.map(|s| s.wire).unwrap_or_default();
    node.close().await;
    let summary = outcome?;
    Ok(Summary { frames_out: stats.frames_out, writes: stats.writes, ..summary })
}

/// What is sent: a file or stdin.
enum Input {
    File(tokio::fs::File),
    Stdin(tokio::io::Stdin),
}

impl Input {
    /// Opens `path` (stdin for `-`), with its size if known.
    async fn open(path: &Path) -> Result<(Input, Option<u64>), Failure> {
        if files::is_std(path) {
            return Ok((Input::Stdin(tokio::io::stdin()), None));
        }
        let (file, size) = files::open(path).await?;
        Ok((Input::File(file), Some(size)))
    }

    /// The next chunk, empty at the end.
    async fn chunk(&mut self) -> std::io::Result<BytesMut> {
        let mut chunk = BytesMut::with_capacity(CHUNK);
        while chunk.len() < CHUNK {
            let read = match self {
                Input::File(file) => file.read_buf(&mut chunk).await?,
                Input::Stdin(stdin) => stdin.read_buf(&mut chunk).await?,
            };
            if read == 0 {
                break;
            }
        }
        Ok(chunk)
    }
}

/// Opens the stream, sends the input and finishes, unless it falls behind `--min-rate`;
/// `sent` (the bytes handed to the bus, kept when the transfer is dropped) and `window`
/// follow the progress.
async fn transfer(
    args: &SendArgs,
    node: &Node,
    input: &mut Input,
    size: Option<u64>,
    sent: &OnceLock<SentBytes>,
    window: &AtomicU16,
) -> Result<Summary, Failure> {
    let mut open = OpenOptions::new(args.to, args.window);
    open.content_uid = args.content_uid;
    let asked = Instant::now();
    let mut stream = node.open(open).await?;
    let started = Instant::now();
    let counter = stream.sent_bytes();
    let _ = sent.set(counter.clone());
    window.store(stream.info().window, Ordering::Relaxed);
    let progress = Progress::start(size, args.json);
    let slow = args.pace.watch(asked, size, || counter.get());
    tokio::pin!(slow);
    // Read the next chunk while the previous one goes out.
    let mut next = input.chunk().await;
    let outcome = loop {
        let chunk = match next {
            Ok(chunk) if chunk.is_empty() => break Ok(()),
            Ok(chunk) => chunk.freeze(),
            Err(error) => break Err(Failure::file(&args.file, error)),
        };
        let (written, read) = tokio::select! {
            both = async { tokio::join!(stream.write_all(chunk), input.chunk()) } => both,
            slow = &mut slow => break Err(Failure::TooSlow(slow)),
        };
        if let Err(error) = written {
            break Err(Failure::Net(error));
        }
        next = read;
        progress.set(stream.written());
    };
    progress.finish();
    outcome?;
    let window = stream.info().window;
    let bytes = stream.finish().await?;
    Ok(Summary { bytes, elapsed: started.elapsed(), window, frames_out: 0, writes: 0 })
}
