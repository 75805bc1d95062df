//! `lcc-stream cdi`: a node's CDI (space 0xFF) as clean XML, without the NUL that ends it
//! in the space.

use std::path::PathBuf;
use std::process::ExitCode;
use std::time::Instant;

use clap::Args;
use openlcb_stream::NodeId;
use openlcb_tokio::Node;

use crate::memory::{self, ClientArgs, Moved, Report};
use crate::net;
use crate::outcome::Failure;

/// The CDI's space.
pub(crate) const SPACE_CDI: u8 = 0xFF;

/// Options of `lcc-stream cdi`.
#[derive(Debug, Args)]
#[command(after_help = memory::after_help(""))]
pub(crate) struct CdiArgs {
    /// The node whose CDI is read.
    #[arg(long, value_name = "NODE_ID", value_parser = crate::args::node_id)]
    from: NodeId,
    /// The file written (never over an existing one) [default: standard output].
    #[arg(long, value_name = "FILE")]
    out: Option<PathBuf>,
    #[command(flatten)]
    client: ClientArgs,
}

/// The document of a CDI space's bytes: up to its first NUL.
pub(crate) fn trim_cdi(mut bytes: Vec<u8>) -> Vec<u8> {
    if let Some(end) = bytes.iter().position(|b| *b == 0) {
        bytes.truncate(end);
    }
    bytes
}

/// Reads `peer`'s CDI, with a progress bar unless `json`.
pub(crate) async fn read_cdi(
    node: &Node,
    peer: NodeId,
    client: &ClientArgs,
    interrupt: &mut net::Interrupt,
    moved: &mut Moved,
) -> Result<Vec<u8>, Failure> {
    let transfer = node.read_memory(peer, SPACE_CDI, 0, None, client.path()).await?;
    memory::follow(node, transfer, None, client.json, &client.pace, interrupt, moved).await.map(trim_cdi)
}

pub(crate) fn run(args: &CdiArgs) -> Result<ExitCode, String> {
    net::runtime()?.block_on(cdi(args))
}

async fn cdi(args: &CdiArgs) -> Result<ExitCode, String> {
    let mut interrupt = net::Interrupt::new()?;
    let mut moved = Moved::default();
    let outcome = async {
        if let Some(out) = &args.out {
            memory::refuse_existing(out).await?;
        }
        let node = memory::join(&args.client, "cdi", args.from).await?;
        moved.started = Some(Instant::now());
        let xml = read_cdi(&node, args.from, &args.client, &mut interrupt, &mut moved).await;
        node.close().await;
        let xml = xml?;
        moved.bytes = xml.len() as u64;
        match &args.out {
            Some(out) => memory::save_new(out, &xml).await?,
            None if !args.client.json => {
                let stdout = std::path::Path::new("-");
                crate::stdout::write_bytes(&xml).map_err(|e| Failure::file(stdout, e))?;
            }
            None => {}
        }
        Ok(xml.len() as u64)
    }
    .await;
    let file = args.out.clone().unwrap_or_else(|| PathBuf::from("-"));
    let report = Report::new(args.from, SPACE_CDI, 0, &file, &moved);
    let text = outcome.map(|bytes| match &args.out {
        Some(out) => format!("read the CDI of {} ({bytes} bytes) into {}", args.from, out.display()),
        None => String::new(),
    });
    Ok(memory::finish(report, text.map(|t| t.trim().to_string()), args.client.json, "cdi"))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_nul_and_what_follows_it_are_cut() {
        assert_eq!(trim_cdi(b"<cdi/>\0".to_vec()), b"<cdi/>");
        assert_eq!(trim_cdi(b"<cdi/>\0\xFF\xFF".to_vec()), b"<cdi/>");
        assert_eq!(trim_cdi(b"<cdi/>".to_vec()), b"<cdi/>");
    }
}
