//! `lcc-stream recv`: join the network as a node and write every incoming stream to a file.
//!
//! Data goes to `NAME.part` first; only a stream that finished with the byte count its source
//! stated is renamed to `NAME`. A failed stream stays `.part`; a stream that brought no data
//! leaves no file. Names are claimed exclusively: no file is ever overwritten, also across runs.

use std::io;
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::{Duration, Instant};

use clap::Args;
use openlcb_stream::wire::ErrorCode;
use openlcb_stream::{NodeId, StreamInfo};
use openlcb_tokio::{NodeOptions, RecvStream};
use serde::Serialize;
use tokio::io::{AsyncWriteExt as _, BufWriter};
use tokio::sync::watch;

use crate::files;
use crate::net::{self, ConnectArgs};
use crate::outcome::{Failure, Outcome};
use crate::peer::Peer;
use crate::progress::{Progress, ProgressGroup};
use crate::reconnect::{self, RECONNECT_HELP, ReconnectArgs, Stop};

/// Names tried for one stream before giving up (every one of them already taken).
const NAME_ATTEMPTS: u64 = 100_000;

/// The Node ID `recv` uses unless told otherwise (`send`'s default destination).
pub(crate) const DEFAULT_RECEIVER: &str = "05.01.01.01.22.F1";

/// `recv`'s after-help.
fn after_help() -> String {
    let outcomes = [Outcome::TimedOut, Outcome::Terminated, Outcome::FileError];
    format!(
        "\
--json prints one object per stream: file (final name, or the .part kept; absent if no data
came), from (the source's Node ID) or, when only its CAN alias is known, from_alias (in hex,
4FF) instead, bytes (received), elapsed_s, bytes_per_s, window (granted), result (the word
of the exit status below), content_uid (if the source sent one) and error (a sentence, on
failure). An exit before any stream ended (a connection or file error, an interrupt) prints
one object with result and error.

{RECONNECT_HELP}{}",
        net::network_help(&outcomes)
    )
}

/// Options of `lcc-stream recv`.
#[derive(Debug, Args)]
#[command(after_help = after_help())]
pub(crate) struct RecvArgs {
    /// Where to write: an existing directory (one file per stream, named after the sender and
    /// the first free counter), or a file name (if taken, or for later streams, `.1`, `.2`,
    /// ... is appended). An existing file is never overwritten. Checked before the network is
    /// touched.
    #[arg(long, value_name = "PATH", default_value = ".")]
    out: PathBuf,
    /// This node's Node ID.
    #[arg(long, value_name = "NODE_ID", value_parser = crate::args::node_id, default_value = DEFAULT_RECEIVER)]
    node_id: NodeId,
    /// The largest window (Max Buffer Size) granted, 1..=65535.
    #[arg(long, default_value_t = 65535, value_parser = clap::value_parser!(u16).range(1..))]
    window: u16,
    /// Grant the next window as soon as the current one starts arriving (two windows of
    /// buffer per stream), so the sender never waits for a Proceed.
    #[arg(long)]
    early_proceed: bool,
    /// Streams received at once; more are refused with 0x2020 (buffer unavailable).
    #[arg(long, default_value_t = 4, value_parser = clap::value_parser!(u16).range(1..=255))]
    max_streams: u16,
    /// Streams received at once from any one node (at most --max-streams), so one node
    /// cannot take every slot.
    #[arg(long, default_value_t = 2, value_parser = clap::value_parser!(u16).range(1..=255))]
    max_streams_per_peer: u16,
    /// Exit after the first stream ends (with its status).
    #[arg(long)]
    once: bool,
    /// Seconds a sender may stay silent in the middle of a stream before it is given up.
    #[arg(long, value_name = "SECS", default_value_t = 60, value_parser = crate::args::positive::<u64>)]
    timeout: u64,
    /// Print one JSON object per finished stream instead of text.
    #[arg(long)]
    json: bool,
    #[command(flatten)]
    connect: ConnectArgs,
    /// A lost hub: the streams under way end (their `.part` files kept), and a new login
    /// listens again.
    #[command(flatten)]
    reconnect: ReconnectArgs,
}

pub(crate) fn run(args: &RecvArgs) -> Result<ExitCode, String> {
    net::runtime()?.block_on(receive(args))
}

async fn receive(args: &RecvArgs) -> Result<ExitCode, String> {
    let mut interrupt = net::Interrupt::new()?;
    let mut reported = 0;
    let status = match listen(args, &mut interrupt, &mut reported).await {
        Ok(status) => status,
        Err(failure) => {
            if args.json && reported == 0 {
                net::print_json(&ExitReport { result: failure.outcome().word(), error: failure.to_string() });
            }
            eprintln!("lcc-stream recv: {failure}");
            failure.outcome().status()
        }
    };
    Ok(ExitCode::from(status))
}

/// `recv --json` when it ends before any stream did.
#[derive(Debug, Serialize)]
struct ExitReport {
    result: &'static str,
    error: String,
}

/// Checks `--out`, joins and receives until interrupted (or the first stream with --once);
/// `reported` counts the streams reported.
async fn listen(args: &RecvArgs, interrupt: &mut net::Interrupt, reported: &mut u64) -> Result<u8, Failure> {
    files::check_writable(&args.out).await?;
    let mut options = NodeOptions::new(args.node_id);
    options.node.snip = net::snip("recv");
    options.node.stream.max_window = args.window;
    options.node.stream.early_proceed = args.early_proceed;
    options.node.stream.max_streams = usize::from(args.max_streams);
    options.node.stream.max_streams_per_peer = usize::from(args.max_streams_per_peer.min(args.max_streams));
    options.node.stream.idle_timeout = Some(Duration::from_secs(args.timeout).into());
    let chosen = net::TransientId { chosen: Some(args.node_id) };
    let mut node = tokio::select! {
        node = args.connect.join(&chosen, |_| options.clone()) => node?,
        () = interrupt.wait() => return Err(Failure::Interrupted),
    };
    // On stderr even with --json: scripts can wait for this line before starting a sender.
    eprintln!("lcc-stream recv: node {} listening on {}", args.node_id, args.connect.addr());
    let counter = Arc::new(AtomicU64::new(0));
    let (stop, stopped) = watch::channel(false);
    let mut transfers = tokio::task::JoinSet::new();
    let progress = ProgressGroup::new(args.json);
    let mut accepting = true;
    loop {
        tokio::select! {
            accepted = node.accept(), if accepting => match accepted {
                Ok(stream) => {
                    let target = Target { out: args.out.clone(), counter: counter.clone() };
                    let shown = progress.start(None, &format!("from {}", Peer::of(stream.info().peer)));
                    transfers.spawn(save(stream, target, args.json, shown, stopped.clone()));
                    // With --once, take no more: the one stream decides the exit status.
                    accepting = !args.once;
                }
                Err(error) => {
                    // The streams under way end with the connection, each with its report.
                    while transfers.join_next().await.is_some() {
                        *reported += 1;
                    }
                    if !reconnect::is_lost(&error) {
                        return Err(Failure::Net(error));
                    }
                    let attempt = || args.connect.join_again(options.clone());
                    match args.reconnect.rejoin("recv", args.connect.addr(), &error, interrupt, attempt).await {
                        Ok(again) => {
                            node = again;
                            reconnect::say_rejoined("recv", args.connect.addr(), &node).await;
                        }
                        Err(Stop::Interrupted) => return Err(Failure::Interrupted),
                        Err(Stop::GaveUp) => return Err(Failure::Net(error)),
                    }
                }
            },
            Some(done) = transfers.join_next() => {
                *reported += 1;
                if args.once {
                    node.close().await;
                    return Ok(done.unwrap_or(1));
                }
            }
            () = interrupt.wait() => {
                // Every open stream ends with TDE and reports what it kept.
                let _ = stop.send(true);
                while transfers.join_next().await.is_some() {
                    *reported += 1;
                }
                node.close().await;
                return Err(Failure::Interrupted);
            }
        }
    }
}

/// Where the streams go: `--out` and the counter shared by every stream of this run.
struct Target {
    out: PathBuf,
    counter: Arc<AtomicU64>,
}

impl Target {
    /// Claims the next free name for a stream from `peer`: `NAME.part` is created exclusively
    /// and `NAME` does not exist yet. Names taken by earlier runs are skipped.
    async fn claim(&self, peer: NodeId) -> Result<(PathBuf, tokio::fs::File), Failure> {
        for _ in 0..NAME_ATTEMPTS {
            let path = target_path(&self.out, peer, self.counter.fetch_add(1, Ordering::Relaxed));
            if tokio::fs::try_exists(&path).await.map_err(|e| Failure::file(&path, e))? {
                continue;
            }
            let part = part_path(&path);
            match tokio::fs::OpenOptions::new().write(true).create_new(true).open(&part).await {
                Ok(file) => return Ok((path, file)),
                Err(error) if error.kind() == io::ErrorKind::AlreadyExists => continue,
                Err(error) => return Err(Failure::file(&part, error)),
            }
        }
        Err(Failure::file(&self.out, io::Error::other("every file name tried is taken")))
    }
}

/// Where stream number `n` from `peer` goes.
fn target_path(out: &Path, peer: NodeId, n: u64) -> PathBuf {
    if out.is_dir() {
        let name = peer.to_string().replace('.', "");
        out.join(format!("stream-{name}-{n}.bin"))
    } else if n == 0 {
        out.to_path_buf()
    } else {
        let mut name = out.as_os_str().to_owned();
        name.push(format!(".{n}"));
        PathBuf::from(name)
    }
}

pub(crate) fn part_path(path: &Path) -> PathBuf {
    let mut name = path.as_os_str().to_owned();
    name.push(".part");
    PathBuf::from(name)
}

/// Moves `part` to `path` without ever replacing a file: a hard link fails if `path` exists.
/// On a file system without hard links, a rename after checking that `path` is free.
pub(crate) fn publish_blocking(part: &Path, path: &Path) -> io::Result<()> {
    match std::fs::hard_link(part, path) {
        Ok(()) => std::fs::remove_file(part),
        Err(error) if error.kind() == io::ErrorKind::AlreadyExists => Err(error),
        Err(_) if !std::fs::exists(path)? => std::fs::rename(part, path),
        Err(error) => Err(error),
    }
}

/// [`publish_blocking`] off the runtime's threads.
pub(crate) async fn publish(part: &Path, path: &Path) -> io::Result<()> {
    let (part, path) = (part.to_path_buf(), path.to_path_buf());
    tokio::task::spawn_blocking(move || publish_blocking(&part, &path)).await.map_err(io::Error::other)?
}

/// The file a stream is written to, created when its first data arrives.
struct Output {
    path: PathBuf,
    file: BufWriter<tokio::fs::File>,
}

impl Output {
    async fn create(target: &Target, peer: NodeId) -> Result<Output, Failure> {
        let (path, file) = target.claim(peer).await?;
        Ok(Output { path, file: BufWriter::with_capacity(1 << 20, file) })
    }

    /// Flushes, syncs and publishes under the final name.
    async fn complete(mut self) -> Result<PathBuf, Failure> {
        let part = part_path(&self.path);
        self.file.flush().await.map_err(|e| Failure::file(&part, e))?;
        self.file.into_inner().sync_all().await.map_err(|e| Failure::file(&part, e))?;
        publish(&part, &self.path).await.map_err(|e| Failure::file(&self.path, e))?;
        Ok(self.path)
    }
}

/// Receives one stream (through `NAME.part`), reports it, and returns its exit status.
async fn save(
    mut stream: RecvStream,
    target: Target,
    json: bool,
    progress: Progress,
    mut stop: watch::Receiver<bool>,
) -> u8 {
    let info = *stream.info();
    let started = Instant::now();
    let mut output: Option<Output> = None;
    let received = async {
        loop {
            let chunk = tokio::select! {
                chunk = stream.read() => chunk.map_err(Failure::Net)?,
                _ = stop.wait_for(|stop| *stop) => return Err(Failure::Interrupted),
            };
            let Some(chunk) = chunk else { return Ok(()) };
            if output.is_none() {
                output = Some(Output::create(&target, info.peer).await?);
            }
            if let Some(out) = output.as_mut() {
                let part = part_path(&out.path);
                out.file.write_all(&chunk).await.map_err(|e| Failure::file(&part, e))?;
            }
            progress.set(stream.received());
        }
    }
    .await;
    let bytes = stream.received();
    progress.finish();
    if matches!(received, Err(Failure::Interrupted)) {
        // The source learns at once (TDE), rather than by its own timeout.
        stream.abort(ErrorCode::TEMPORARY);
    }
    let outcome = match (received, output) {
        (Ok(()), out) => finish(&target, info.peer, out).await,
        (Err(failure), Some(mut out)) => {
            // Whatever arrived stays in the `.part` file.
            let _ = out.file.flush().await;
            Err((failure, Some(part_path(&out.path))))
        }
        // A stream that brought no data leaves no file.
        (Err(failure), None) => Err((failure, None)),
    };
    report(&info, started.elapsed(), bytes, &outcome, json)
}

/// Publishes a stream that ended well; one without any data becomes an empty file.
async fn finish(target: &Target, peer: NodeId, out: Option<Output>) -> Result<PathBuf, (Failure, Option<PathBuf>)> {
    let out = match out {
        Some(out) => out,
        None => Output::create(target, peer).await.map_err(|failure| (failure, None))?,
    };
    let part = part_path(&out.path);
    out.complete().await.map_err(|failure| (failure, Some(part)))
}

/// `recv --json`: one object per stream (see the help for its fields).
#[derive(Debug, Serialize)]
struct RecvReport<'a> {
    #[serde(skip_serializing_if = "Option::is_none")]
    file: Option<&'a str>,
    #[serde(skip_serializing_if = "Option::is_none")]
    from: Option<String>,
    #[serde(skip_serializing_if = "Option::is_none")]
    from_alias: Option<String>,
    bytes: u64,
    elapsed_s: f64,
    bytes_per_s: f64,
    window: u16,
    result: &'static str,
    #[serde(skip_serializing_if = "Option::is_none")]
    content_uid: Option<String>,
    #[serde(skip_serializing_if = "Option::is_none")]
    error: Option<&'a str>,
}

/// Prints what came of one stream (text or JSON) and returns its exit status.
fn report(
    info: &StreamInfo,
    elapsed: Duration,
    bytes: u64,
    outcome: &Result<PathBuf, (Failure, Option<PathBuf>)>,
    json: bool,
) -> u8 {
    let bytes_per_s = net::rate(bytes, elapsed.as_secs_f64());
    let (status, result, error) = match outcome {
        Ok(_) => (0, Outcome::Ok.word(), None),
        Err((Failure::Interrupted, _)) => (
            Outcome::Interrupted.status(),
            Outcome::Interrupted.word(),
            Some("interrupted (the source was sent TDE 0x2000, temporary error)".to_string()),
        ),
        Err((failure, _)) => (failure.outcome().status(), failure.outcome().word(), Some(failure.to_string())),
    };
    let file = match outcome {
        Ok(path) | Err((_, Some(path))) => Some(path.display().to_string()),
        Err((_, None)) => None,
    };
    let from = Peer::of(info.peer);
    if json {
        net::print_json(&RecvReport {
            file: file.as_deref(),
            from: from.node_field(),
            from_alias: from.alias_field(),
            bytes,
            elapsed_s: elapsed.as_secs_f64(),
            bytes_per_s,
            window: info.window,
            result,
            content_uid: info.content_uid.map(|uid| uid.to_string()),
            error: error.as_deref(),
        });
    } else if let Some(error) = error {
        let kept = file.map_or_else(|| "no file written".to_string(), |file| format!("kept in {file}"));
        eprintln!("lcc-stream recv: stream from {from} failed after {bytes} bytes ({kept}): {error}");
    } else {
        net::say(&format!(
            "received {bytes} bytes from {from} into {} in {:.3} s ({}), window {}",
            file.unwrap_or_default(),
            elapsed.as_secs_f64(),
            net::rate_text(bytes_per_s),
            info.window
        ));
    }
    status
}
