//! `lcc-stream read`: back up a memory space of a node into a file.
//!
//! The bytes go to `FILE.part`, claimed before the transfer starts, and it is renamed to
//! `FILE` only once every byte has arrived; an existing file is never overwritten.

use std::path::PathBuf;
use std::process::ExitCode;
use std::time::Instant;

use clap::Args;
use openlcb_stream::NodeId;

use crate::cdi;
use crate::memory::{self, ClientArgs, Report, Stop};
use crate::net;
use crate::recv::{part_path, publish};

/// Options of `lcc-stream read`.
#[derive(Debug, Args)]
#[command(after_help = concat!(memory::json_help!(), net::exit_help!()))]
pub(crate) struct ReadArgs {
    /// The node to read.
    #[arg(long, value_name = "NODE_ID")]
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
    /// The file written (never over an existing one).
    #[arg(long, value_name = "FILE")]
    out: PathBuf,
    #[command(flatten)]
    client: ClientArgs,
}

pub(crate) fn run(args: &ReadArgs) -> Result<ExitCode, String> {
    net::runtime()?.block_on(read(args))
}

async fn read(args: &ReadArgs) -> Result<ExitCode, String> {
    let mut interrupt = net::Interrupt::new()?;
    let mut started = Instant::now();
    let part = part_path(&args.out);
    let outcome = async {
        memory::refuse_existing(&args.out).await?;
        let claimed = tokio::fs::OpenOptions::new().write(true).create_new(true).open(&part).await;
        let file = claimed.map_err(Stop::File)?;
        let result = transfer(args, &mut interrupt, &mut started).await;
        let data = match result {
            Ok(data) => data,
            Err(stop) => {
                drop(file);
                let _ = tokio::fs::remove_file(&part).await;
                return Err(stop);
            }
        };
        save(file, &data).await.map_err(Stop::File)?;
        publish(&part, &args.out).await.map_err(Stop::File)?;
        Ok(data.len() as u64)
    }
    .await;
    let bytes = *outcome.as_ref().unwrap_or(&0);
    let report = Report::new(args.from, args.space, args.address, &args.out, args.client.path(), bytes, started);
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

/// Joins, finds the node and reads; `started` is set when the first command goes out.
async fn transfer(args: &ReadArgs, interrupt: &mut net::Interrupt, started: &mut Instant) -> Result<Vec<u8>, Stop> {
    let node = memory::join(&args.client, "read", args.from).await?;
    *started = Instant::now();
    let transfer = node
        .read_memory(args.from, args.space, args.address, args.length, args.client.path())
        .await
        .map_err(Stop::Net)?;
    let data = memory::follow(transfer, args.length.map(u64::from), args.client.json, interrupt).await;
    node.close().await;
    // The CDI's terminating NUL is no part of the document.
    if args.space == cdi::SPACE_CDI { data.map(cdi::trim_cdi) } else { data }
}

async fn save(mut file: tokio::fs::File, data: &[u8]) -> std::io::Result<()> {
    use tokio::io::AsyncWriteExt as _;
    file.write_all(data).await?;
    file.sync_all().await
}
