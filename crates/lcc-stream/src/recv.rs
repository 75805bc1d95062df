//! `lcc-stream recv`: join the network as a node and write every incoming stream to a file.
//!
//! Data goes to `NAME.part` first; only a stream that finished with the byte count its source
//! stated is renamed to `NAME`. A failed stream stays `.part`.

use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::{Duration, Instant};

use clap::Args;
use openlcb_stream::NodeId;
use openlcb_tokio::{Error, Node, NodeOptions, RecvStream};
use tokio::io::AsyncWriteExt as _;

use crate::net::{self, ConnectArgs, Json};

/// The Node ID `recv` uses unless told otherwise (`send`'s default destination).
pub(crate) const DEFAULT_RECEIVER: &str = "05.01.01.01.22.F1";

/// Options of `lcc-stream recv`.
#[derive(Debug, Args)]
#[command(after_help = net::EXIT_HELP)]
pub(crate) struct RecvArgs {
    /// Where to write: an existing directory (one file per stream, named after the sender and
    /// a counter), or a file name (later streams get `.1`, `.2`, ... appended).
    #[arg(long, value_name = "PATH", default_value = ".")]
    out: PathBuf,
    /// This node's Node ID.
    #[arg(long, value_name = "NODE_ID", default_value = DEFAULT_RECEIVER)]
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
    /// Exit after the first stream ends (with its status).
    #[arg(long)]
    once: bool,
    /// Seconds a sender may stay silent in the middle of a stream before it is given up.
    #[arg(long, value_name = "SECS", default_value_t = 60)]
    timeout: u64,
    /// Print one JSON object per finished stream instead of text.
    #[arg(long)]
    json: bool,
    #[command(flatten)]
    connect: ConnectArgs,
}

pub(crate) fn run(args: &RecvArgs) -> Result<ExitCode, String> {
    net::runtime()?.block_on(receive(args))
}

async fn receive(args: &RecvArgs) -> Result<ExitCode, String> {
    let mut options = NodeOptions::new(args.node_id);
    options.config.max_window = args.window;
    options.config.early_proceed = args.early_proceed;
    options.config.max_streams = usize::from(args.max_streams);
    options.config.idle_timeout = Some(Duration::from_secs(args.timeout).into());
    let mut node = match Node::connect(args.connect.addr(), args.connect.protocol.into(), options).await {
        Ok(node) => node,
        Err(error) => return Ok(net::fail("recv", &error)),
    };
    // On stderr even with --json: scripts can wait for this line before starting a sender.
    eprintln!("lcc-stream recv: node {} listening on {}", args.node_id, args.connect.addr());
    let counter = Arc::new(AtomicU64::new(0));
    let mut transfers = tokio::task::JoinSet::new();
    loop {
        tokio::select! {
            accepted = node.accept() => match accepted {
                Ok(stream) => {
                    let path = target_path(&args.out, stream.info().peer, counter.fetch_add(1, Ordering::Relaxed));
                    let json = args.json;
                    transfers.spawn(async move { save(stream, path, json).await });
                    if args.once {
                        // Take no more: the one stream decides the exit status.
                        let status = transfers.join_next().await.and_then(Result::ok).unwrap_or(1);
                        return Ok(ExitCode::from(status));
                    }
                }
                Err(error) => {
                    while transfers.join_next().await.is_some() {}
                    return Ok(net::fail("recv", &error));
                }
            },
            Some(_) = transfers.join_next() => {}
            _ = tokio::signal::ctrl_c() => return Ok(ExitCode::SUCCESS),
        }
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

fn part_path(path: &Path) -> PathBuf {
    let mut name = path.as_os_str().to_owned();
    name.push(".part");
    PathBuf::from(name)
}

/// Receives one stream into `path` (through `path.part`), reports it, and returns its exit
/// status.
async fn save(mut stream: RecvStream, path: PathBuf, json: bool) -> u8 {
    let info = *stream.info();
    let part = part_path(&path);
    let started = Instant::now();
    let outcome = async {
        let file = tokio::fs::File::create(&part).await.map_err(Failure::File)?;
        let mut file = tokio::io::BufWriter::with_capacity(1 << 20, file);
        let received = async {
            while let Some(chunk) = stream.read().await.map_err(Failure::Stream)? {
                file.write_all(&chunk).await.map_err(Failure::File)?;
            }
            Ok(())
        }
        .await;
        // Whatever arrived is in the `.part` file, also after a failure.
        let flushed = file.flush().await.map_err(Failure::File);
        received?;
        flushed?;
        file.into_inner().sync_all().await.map_err(Failure::File)?;
        tokio::fs::rename(&part, &path).await.map_err(Failure::File)
    }
    .await;
    let elapsed = started.elapsed();
    let bytes = stream.received();
    let bytes_per_s = net::rate(bytes, elapsed.as_secs_f64());
    let (status, result, error) = match &outcome {
        Ok(()) => (0, "ok", None),
        Err(Failure::Stream(error)) => (net::exit_status(error), net::result_word(error), Some(error.to_string())),
        Err(Failure::File(error)) => (net::EXIT_FILE, "file_error", Some(error.to_string())),
    };
    let written_to = if outcome.is_ok() { &path } else { &part };
    if json {
        let mut report = Json::default()
            .str("file", &written_to.display().to_string())
            .str("from", &info.peer.to_string())
            .num("bytes", bytes)
            .float("elapsed_s", elapsed.as_secs_f64())
            .float("bytes_per_s", bytes_per_s)
            .num("window", info.window)
            .str("result", result);
        if let Some(uid) = info.content_uid {
            report = report.str("content_uid", &uid.to_string());
        }
        if let Some(error) = &error {
            report = report.str("error", error);
        }
        println!("{}", report.finish());
    } else if let Some(error) = error {
        eprintln!(
            "lcc-stream recv: stream from {} failed after {bytes} bytes (kept in {}): {error}",
            info.peer,
            written_to.display()
        );
    } else {
        println!(
            "received {bytes} bytes from {} into {} in {:.3} s ({}), window {}",
            info.peer,
            written_to.display(),
            elapsed.as_secs_f64(),
            net::rate_text(bytes_per_s),
            info.window
        );
    }
    status
}

enum Failure {
    Stream(Error),
    File(std::io::Error),
}
