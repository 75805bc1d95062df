//! `lcc-stream cdi`: a node's CDI (space 0xFF) as clean XML, without the NUL that ends it
//! in the space.
//!
//! Every command that reads a CDI (`cdi`, and `config` before anything else) reads it up to
//! its first NUL and at most [`MAX_CDI_BYTES`]; an empty CDI, or one that would pass the
//! bound, is an error that says so.

use std::path::PathBuf;
use std::process::ExitCode;
use std::time::Instant;

use clap::Args;
use openlcb_stream::NodeId;
use openlcb_tokio::Node;

use openlcb_tokio::Error;
use openlcb_tokio::openlcb_node::MemoryError;

use crate::memory::{self, ClientArgs, Moved, Report};
use crate::net;
use crate::outcome::Failure;

/// The CDI's space.
pub(crate) const SPACE_CDI: u8 = 0xFF;

/// The most bytes a CDI may have here (1 MiB). Real CDIs are tens of KiB, and OpenMRN's
/// largest are well under 1 MiB; a node that reports a larger CDI space, or whose CDI runs
/// on past this without its NUL, is refused at once instead of being read for minutes.
pub(crate) const MAX_CDI_BYTES: u32 = 1024 * 1024;

/// What the help of every command that reads a CDI says about it.
pub(crate) fn cdi_help() -> String {
    format!(
        "\
The CDI is read up to its first NUL, at most {MAX_CDI_BYTES} bytes (1 MiB): a CDI space that
reports more, a CDI with no NUL within that, and an empty CDI (nothing but white space before
the NUL) fail with exit status 11, and nothing is written. A node that does not answer Get
Address Space Information for space 0xFF is read until its answers end the space.

"
    )
}

/// Why a node's CDI cannot be taken.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum CdiFault {
    /// Nothing but white space before the NUL.
    Empty,
    /// More than [`MAX_CDI_BYTES`]: the size its space reports (`None`: the node gave
    /// none, and its bytes went on past the bound without a NUL).
    TooLarge { size: Option<u64> },
}

impl std::fmt::Display for CdiFault {
    /// The words that follow "the CDI of node N".
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            CdiFault::Empty => write!(f, "is empty: space 0xFF holds nothing but white space before its NUL"),
            CdiFault::TooLarge { size: Some(size) } => write!(
                f,
                "is too large: its space 0xFF holds {size} bytes by the node's own report, more than the \
                 {MAX_CDI_BYTES} bytes (1 MiB) a CDI may have; nothing was read"
            ),
            CdiFault::TooLarge { size: None } => {
                write!(f, "has no end: no NUL within {MAX_CDI_BYTES} bytes (1 MiB), the most a CDI may have")
            }
        }
    }
}

/// Options of `lcc-stream cdi`.
#[derive(Debug, Args)]
#[command(after_help = memory::after_help(&cdi_help()))]
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

/// The document of a CDI space's bytes (`read --space 0xFF`): up to its first NUL.
pub(crate) fn trim_cdi(mut bytes: Vec<u8>) -> Vec<u8> {
    if let Some(end) = bytes.iter().position(|b| *b == 0) {
        bytes.truncate(end);
    }
    bytes
}

/// Reads `peer`'s CDI up to its NUL, with a progress bar unless `json`: an empty CDI and
/// one larger than [`MAX_CDI_BYTES`] fail.
pub(crate) async fn read_cdi(
    node: &Node,
    peer: NodeId,
    client: &ClientArgs,
    interrupt: &mut net::Interrupt,
    moved: &mut Moved,
) -> Result<Vec<u8>, Failure> {
    let transfer = node.read_memory_to_nul(peer, SPACE_CDI, MAX_CDI_BYTES, client.path()).await?;
    let xml = match memory::follow(node, transfer, None, client.json, &client.pace, interrupt, moved).await {
        Err(Failure::Net(Error::Memory { error: MemoryError::SpaceTooLarge { size, .. }, .. })) => {
            return Err(Failure::BadCdi { peer, fault: CdiFault::TooLarge { size } });
        }
        read => read?,
    };
    if xml.iter().all(u8::is_ascii_whitespace) {
        return Err(Failure::BadCdi { peer, fault: CdiFault::Empty });
    }
    Ok(xml)
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
