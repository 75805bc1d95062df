//! `lcc-stream read`: back up a memory space of a node into a file.
//!
//! The bytes go to `FILE.part`, claimed before the transfer starts, and it is renamed to
//! `FILE` only once every byte has arrived; an existing file is kept unless `--force`.
//! Interrupted (Ctrl-C, SIGTERM, SIGHUP), the read is cancelled and `FILE.part` is kept
//! with the bytes that had arrived, and the message says how many. With
//! `--out -` the bytes go to stdout; into a FIFO or a device (`/dev/null`) they are written
//! through once they have all arrived, with no `.part`, no rename and no need of `--force`.

use std::path::PathBuf;
use std::process::ExitCode;
use std::time::Instant;

use clap::Args;
use openlcb_stream::NodeId;

use tokio::io::AsyncWriteExt as _;

use crate::cdi;
use crate::files;
use crate::memory::{self, ClientArgs, Moved, Report};
use crate::net;
use crate::outcome::{Failure, Outcome};
use crate::recv::{part_path, publish};

/// What an interrupted read leaves, for the help.
const INTERRUPTED_HELP: &str = "\
Interrupted (Ctrl-C, SIGTERM, SIGHUP), the read stops and FILE.part is kept with the bytes
that had arrived (the first of the read); the message says how many. Exit status 130.

";

/// Options of `lcc-stream read`.
#[derive(Debug, Args)]
#[command(after_help = memory::after_help(INTERRUPTED_HELP))]
pub(crate) struct ReadArgs {
    /// The node to read.
    #[arg(long, value_name = "NODE_ID", value_parser = crate::args::node_id)]
    from: NodeId,
    /// The address space (0xFD configuration, 0xFF CDI, 0xFC/0xFB ACDI, 0xEF firmware).
    #[arg(long, default_value = "0xFD", value_parser = memory::parse_number::<u8>)]
    space: u8,
    /// The first address read.
    #[arg(long, default_value = "0", value_parser = memory::parse_number::<u32>)]
    address: u32,
    /// Bytes to read [default: to the end of the space].
    #[arg(long, value_parser = memory::parse_number::<u32>)]
    length: Option<u32>,
    /// The file written, or `-` for stdout (then the report goes to stderr, and --json is
    /// refused). An existing file is kept unless --force; a FIFO or a device is written into.
    #[arg(long, value_name = "FILE")]
    out: PathBuf,
    /// Replace an existing --out file (once every byte has arrived).
    #[arg(long)]
    force: bool,
    #[command(flatten)]
    client: ClientArgs,
}

pub(crate) fn run(args: &ReadArgs) -> Result<ExitCode, String> {
    if files::is_std(&args.out) && args.client.json {
        eprintln!("lcc-stream read: --out - writes the data to stdout, where --json would write too; choose one");
        return Ok(ExitCode::from(Outcome::Usage.status()));
    }
    if files::is_std(&args.out) {
        // stdout holds the data: what is said for a person goes to stderr.
        net::data_on_stdout();
    }
    net::runtime()?.block_on(read(args))
}

async fn read(args: &ReadArgs) -> Result<ExitCode, String> {
    let mut interrupt = net::Interrupt::new()?;
    let mut moved = Moved::default();
    let outcome = async {
        if files::is_std(&args.out) {
            let data = transfer(args, &mut interrupt, &mut moved).await?;
            crate::stdout::write_bytes(&data).map_err(|e| Failure::file(&args.out, e))?;
            return Ok(data.len() as u64);
        }
        if files::is_special(&args.out).await {
            // A FIFO or a device: the data goes into it, with no `.part` and no rename.
            let data = transfer(args, &mut interrupt, &mut moved).await?;
            files::write_through(&args.out, &data).await?;
            return Ok(data.len() as u64);
        }
        // Checked before the network is touched: the name is free (or --force), and a file
        // can be made beside it.
        let exists = tokio::fs::try_exists(&args.out).await.map_err(|e| Failure::file(&args.out, e))?;
        if exists && !args.force {
            let taken = std::io::Error::new(
                std::io::ErrorKind::AlreadyExists,
                "the file exists (it is kept; --force replaces it once every byte has arrived)",
            );
            return Err(Failure::file(&args.out, taken));
        }
        files::check_writable(&args.out).await?;
        let part = part_path(&args.out);
        let claimed = tokio::fs::OpenOptions::new().write(true).create_new(true).open(&part).await;
        let file = claimed.map_err(|e| Failure::file(&part, e))?;
        let result = transfer(args, &mut interrupt, &mut moved).await;
        let data = match result {
            Ok(data) => data,
            Err(Failure::Interrupted) => {
                let kept = std::mem::take(&mut moved.cut_short);
                moved.bytes = kept.len() as u64;
                save(file, &kept).await.map_err(|e| Failure::file(&part, e))?;
                return Err(Failure::InterruptedKeeping { part, bytes: moved.bytes });
            }
            Err(failure) => {
                drop(file);
                let _ = tokio::fs::remove_file(&part).await;
                return Err(failure);
            }
        };
        save(file, &data).await.map_err(|e| Failure::file(&part, e))?;
        if args.force {
            tokio::fs::rename(&part, &args.out).await.map_err(|e| Failure::file(&args.out, e))?;
        } else {
            publish(&part, &args.out).await.map_err(|e| Failure::file(&args.out, e))?;
        }
        Ok(data.len() as u64)
    }
    .await;
    if let Ok(bytes) = outcome {
        moved.bytes = bytes;
    }
    let report = Report::new(args.from, args.space, args.address, &args.out, &moved);
    let (elapsed_s, bytes_per_s) = (report.elapsed_s, report.bytes_per_s);
    let text = outcome.map(|bytes| {
        format!(
            "read {bytes} bytes of space 0x{:02X} from {} into {} in {elapsed_s:.3} s ({})",
            args.space,
            args.from,
            args.out.display(),
            net::rate_text(bytes_per_s)
        )
    });
    Ok(memory::finish(report, text, args.client.json, "read"))
}

/// Joins, finds the node and reads.
async fn transfer(args: &ReadArgs, interrupt: &mut net::Interrupt, moved: &mut Moved) -> Result<Vec<u8>, Failure> {
    let node = memory::join(&args.client, "read", args.from).await?;
    moved.started = Some(Instant::now());
    tracing::info!(peer = %args.from, space = format!("0x{:02X}", args.space), address = args.address, length = ?args.length, "reading");
    let transfer = node.read_memory(args.from, args.space, args.address, args.length, args.client.path()).await;
    let data = match transfer {
        Ok(transfer) => {
            memory::follow(
                &node,
                transfer,
                args.length.map(u64::from),
                args.client.json,
                &args.client.pace,
                interrupt,
                moved,
            )
            .await
        }
        Err(error) => Err(Failure::Net(error)),
    };
    node.close().await;
    // The CDI's terminating NUL is no part of the document.
    if args.space == cdi::SPACE_CDI { data.map(cdi::trim_cdi) } else { data }
}

async fn save(mut file: tokio::fs::File, data: &[u8]) -> std::io::Result<()> {
    file.write_all(data).await?;
    file.sync_all().await
}
