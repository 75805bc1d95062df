//! `lcc-stream firmware`: upgrade a node's firmware (Freeze, the image into space 0xEF by
//! stream or datagrams, Unfreeze; a target that reboots has succeeded).

use std::path::PathBuf;
use std::process::ExitCode;

use clap::Args;
use openlcb_stream::NodeId;

use crate::memory::{self, ClientArgs, Upload};
use crate::net;

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
    net::runtime()?.block_on(memory::upload(
        &args.client,
        "firmware",
        args.to,
        &args.file,
        Upload::Firmware,
        |report| {
            format!(
                "upgraded {} with {} bytes of {} in {:.3} s ({})",
                report.node,
                report.bytes,
                report.file,
                report.elapsed_s,
                net::rate_text(report.bytes_per_s)
            )
        },
    ))
}
