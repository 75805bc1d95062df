//! `lcc-stream write`: restore a memory space of a node from a file, then tell the node with
//! Update Complete.

use std::path::PathBuf;
use std::process::ExitCode;

use clap::Args;
use openlcb_stream::NodeId;

use crate::memory::{self, ClientArgs, Upload};
use crate::net;

/// Options of `lcc-stream write`.
#[derive(Debug, Args)]
#[command(after_help = memory::after_help(""))]
pub(crate) struct WriteArgs {
    /// The file whose bytes are written (`-`: stdin), read whole before the network is
    /// touched.
    file: PathBuf,
    /// The node to write.
    #[arg(long, value_name = "NODE_ID", value_parser = crate::args::node_id)]
    to: NodeId,
    /// The address space (0xFD configuration, 0xFB ACDI user data).
    #[arg(long, default_value = "0xFD", value_parser = memory::parse_number::<u8>)]
    space: u8,
    /// The first address written.
    #[arg(long, default_value = "0", value_parser = memory::parse_number::<u32>)]
    address: u32,
    /// Do not end with Update Complete (`20 A8`), which tells the node to apply what was
    /// written; a refused one is a warning, not a failure.
    #[arg(long)]
    no_update_complete: bool,
    #[command(flatten)]
    client: ClientArgs,
}

pub(crate) fn run(args: &WriteArgs) -> Result<ExitCode, String> {
    let what = Upload::Space { space: args.space, address: args.address, update_complete: !args.no_update_complete };
    net::transfer_runtime()?.block_on(memory::upload(&args.client, "write", args.to, &args.file, what, |report| {
        format!(
            "wrote {} bytes of {} into space 0x{:02X} of {} in {:.3} s ({})",
            report.bytes,
            report.file,
            report.space,
            report.node,
            report.elapsed_s,
            net::rate_text(report.bytes_per_s)
        )
    }))
}
