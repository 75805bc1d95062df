//! `lcc-stream firmware`: upgrade a node's firmware (Freeze, the image into space 0xEF by
//! stream or datagrams, Unfreeze; a target that reboots has succeeded).

use std::path::PathBuf;
use std::process::ExitCode;

use clap::Args;
use openlcb_stream::NodeId;

use crate::memory::{self, ClientArgs, Upload};
use crate::net;

/// What an interrupted upgrade means, for the help.
const FIRMWARE_HELP: &str = "\
Interrupted (Ctrl-C, SIGTERM, SIGHUP) or failed after the Freeze, the node stays in firmware
upgrade mode: run the same command again to finish.

";

/// Options of `lcc-stream firmware`.
#[derive(Debug, Args)]
#[command(after_help = memory::after_help(FIRMWARE_HELP))]
pub(crate) struct FirmwareArgs {
    /// The image (`-`: stdin), read whole before the network is touched.
    file: PathBuf,
    /// The node to upgrade.
    #[arg(long, value_name = "NODE_ID", value_parser = crate::args::node_id)]
    to: NodeId,
    #[command(flatten)]
    client: ClientArgs,
}

pub(crate) fn run(args: &FirmwareArgs) -> Result<ExitCode, String> {
    net::transfer_runtime()?.block_on(memory::upload(
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
