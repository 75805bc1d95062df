//! `lcc-stream firmware`: upgrade a node's firmware (Freeze, the image into space 0xEF by
//! stream or datagrams, Unfreeze; a target that reboots has succeeded).

use std::path::PathBuf;
use std::process::ExitCode;
use std::time::Instant;

use clap::Args;
use openlcb_stream::NodeId;

use crate::memory::{self, ClientArgs, Report, Stop};
use crate::net;

/// The firmware space.
const SPACE_FIRMWARE: u8 = 0xEF;

/// Options of `lcc-stream firmware`.
#[derive(Debug, Args)]
#[command(after_help = concat!(memory::json_help!(), net::exit_help!()))]
pub(crate) struct FirmwareArgs {
    /// The image.
    file: PathBuf,
    /// The node to upgrade.
    #[arg(long, value_name = "NODE_ID")]
    to: NodeId,
    #[command(flatten)]
    client: ClientArgs,
}

pub(crate) fn run(args: &FirmwareArgs) -> Result<ExitCode, String> {
    net::runtime()?.block_on(upgrade(args))
}

async fn upgrade(args: &FirmwareArgs) -> Result<ExitCode, String> {
    let mut interrupt = net::Interrupt::new()?;
    let started = Instant::now();
    let outcome = async {
        let image = tokio::fs::read(&args.file).await.map_err(Stop::File)?;
        let total = image.len() as u64;
        let node = memory::join(&args.client, "firmware", args.to).await?;
        let transfer = node.upgrade_firmware(args.to, image, args.client.path()).await.map_err(Stop::Net)?;
        let bar = memory::progress_bar(Some(total), args.client.json);
        let written = memory::follow(transfer, &bar, &mut interrupt).await;
        node.close().await;
        written
    }
    .await;
    let bytes = *outcome.as_ref().unwrap_or(&0);
    let report = Report::new(args.to, SPACE_FIRMWARE, 0, &args.file, args.client.path(), bytes, started);
    let (elapsed_s, bytes_per_s) = (report.elapsed_s, report.bytes_per_s);
    let text = outcome.map(|bytes| {
        format!(
            "upgraded {} with {bytes} bytes of {} in {elapsed_s:.3} s ({})",
            args.to,
            args.file.display(),
            net::rate_text(bytes_per_s)
        )
    });
    Ok(memory::finish(report, text, args.client.json, "firmware"))
}
