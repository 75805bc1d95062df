//! `lcc-stream write`: restore a memory space of a node from a file.

use std::path::PathBuf;
use std::process::ExitCode;
use std::time::Instant;

use clap::Args;
use openlcb_stream::NodeId;

use crate::memory::{self, ClientArgs, Report, Stop};
use crate::net;

/// Options of `lcc-stream write`.
#[derive(Debug, Args)]
#[command(after_help = concat!(memory::json_help!(), net::exit_help!()))]
pub(crate) struct WriteArgs {
    /// The file whose bytes are written.
    file: PathBuf,
    /// The node to write.
    #[arg(long, value_name = "NODE_ID")]
    to: NodeId,
    /// The address space (0xFD configuration, 0xFB ACDI user data).
    #[arg(long, default_value = "0xFD", value_parser = memory::parse_number::<u8>)]
    space: u8,
    /// The first address written.
    #[arg(long, default_value = "0", value_parser = memory::parse_number::<u32>)]
    address: u32,
    #[command(flatten)]
    client: ClientArgs,
}

pub(crate) fn run(args: &WriteArgs) -> Result<ExitCode, String> {
    net::runtime()?.block_on(write(args))
}

async fn write(args: &WriteArgs) -> Result<ExitCode, String> {
    let mut interrupt = net::Interrupt::new()?;
    let started = Instant::now();
    let outcome = async {
        let data = tokio::fs::read(&args.file).await.map_err(Stop::File)?;
        let total = data.len() as u64;
        let node = memory::join(&args.client, "write", args.to).await?;
        let transfer =
            node.write_memory(args.to, args.space, args.address, data, args.client.path()).await.map_err(Stop::Net)?;
        let bar = memory::progress_bar(Some(total), args.client.json);
        let written = memory::follow(transfer, &bar, &mut interrupt).await;
        node.close().await;
        written
    }
    .await;
    let bytes = *outcome.as_ref().unwrap_or(&0);
    let report = Report::new(args.to, args.space, args.address, &args.file, args.client.path(), bytes, started);
    let (elapsed_s, bytes_per_s) = (report.elapsed_s, report.bytes_per_s);
    let text = outcome.map(|bytes| {
        format!(
            "wrote {bytes} bytes of {} into space 0x{:02X} of {} in {elapsed_s:.3} s ({})",
            args.file.display(),
            args.space,
            args.to,
            net::rate_text(bytes_per_s)
        )
    });
    Ok(memory::finish(report, text, args.client.json, "write"))
}
