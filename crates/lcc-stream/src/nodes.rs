//! `lcc-stream nodes`: who is on the network, with their names (SNIP) and protocols (PIP).

use std::process::ExitCode;
use std::time::Duration;

use clap::Args;
use openlcb_stream::{AcceptPolicy, NodeId, wire::ReplyCode};
use openlcb_tokio::{Error, Node, NodeOptions, Protocols, SnipInfo};
use serde::Serialize;

use crate::net::{self, ConnectArgs};
use crate::outcome::Failure;

/// The most nodes listed.
pub(crate) const MOST_NODES: usize = 1024;
/// How long each node may take to answer the Protocol Support Inquiry.
const PIP_TIMEOUT: Duration = Duration::from_secs(3);

/// The fields of `nodes --json`.
const NODES_JSON: &str = "\
--json prints one object per node: node_id, alias (CAN alias in hex, null over OpenLCB-TCP),
snip (manufacturer, model, hardware_version, software_version, user_name, user_description;
null if it did not answer), protocols (names; null if it did not answer) and errors (why SNIP
or PIP gave nothing). A failure prints one object with result (the word of the exit status
below) and error.

";

/// Options of `lcc-stream nodes`.
#[derive(Debug, Args)]
#[command(after_help = format!("{NODES_JSON}{}", net::network_help(&[])))]
pub(crate) struct NodesArgs {
    #[command(flatten)]
    node_id: net::TransientId,
    /// Seconds of quiet after the last answer to Verify Node ID before the list is complete
    /// (0.05 to 30).
    #[arg(long, value_name = "SECS", default_value_t = 1.0, value_parser = parse_wait)]
    wait: f64,
    /// Print one JSON object per node (one per line) instead of text.
    #[arg(long)]
    json: bool,
    #[command(flatten)]
    connect: ConnectArgs,
}

fn parse_wait(text: &str) -> Result<f64, String> {
    let secs: f64 = text.parse().map_err(|_| format!("`{text}` is not a number of seconds"))?;
    if (0.05..=30.0).contains(&secs) { Ok(secs) } else { Err("the quiet period must be 0.05 to 30 seconds".into()) }
}

/// One node as `--json` prints it (and `ui` shows it).
#[derive(Debug, Clone, Serialize)]
pub(crate) struct NodeReport {
    /// `05.01.01.01.22.F1`.
    pub(crate) node_id: String,
    /// The CAN alias in hex (`"3B2"`), or null over OpenLCB-TCP.
    pub(crate) alias: Option<String>,
    /// The SNIP strings, or null when the node did not answer.
    pub(crate) snip: Option<SnipReport>,
    /// The names of the protocols it announces, or null when it did not answer.
    pub(crate) protocols: Option<Vec<&'static str>>,
    /// Why SNIP or PIP gave nothing, if either did.
    pub(crate) errors: Vec<String>,
}

/// The SNIP strings of a node.
#[derive(Debug, Clone, Serialize)]
pub(crate) struct SnipReport {
    pub(crate) manufacturer: String,
    pub(crate) model: String,
    pub(crate) hardware_version: String,
    pub(crate) software_version: String,
    pub(crate) user_name: String,
    pub(crate) user_description: String,
}

impl From<SnipInfo> for SnipReport {
    fn from(info: SnipInfo) -> Self {
        SnipReport {
            manufacturer: info.manufacturer,
            model: info.model,
            hardware_version: info.hardware_version,
            software_version: info.software_version,
            user_name: info.user_name,
            user_description: info.user_description,
        }
    }
}

pub(crate) fn run(args: &NodesArgs) -> Result<ExitCode, String> {
    net::runtime()?.block_on(list(args))
}

async fn list(args: &NodesArgs) -> Result<ExitCode, String> {
    match discover(args).await {
        Ok(reports) => {
            for report in &reports {
                if args.json {
                    net::print_json(report);
                } else {
                    net::say(&text_line(report));
                }
            }
            if !args.json && !net::quiet() {
                eprintln!("{} node(s) answered", reports.len());
                if let Some(hint) = reports.is_empty().then(|| args.connect.empty_network_hint()).flatten() {
                    eprintln!("lcc-stream nodes: {hint}");
                }
            }
            Ok(ExitCode::SUCCESS)
        }
        Err(failure) => {
            if args.json {
                net::print_json(
                    &serde_json::json!({ "result": failure.outcome().word(), "error": failure.to_string() }),
                );
            }
            Ok(net::fail("nodes", &failure))
        }
    }
}

/// Joins, finds the nodes and asks each for its SNIP and PIP.
async fn discover(args: &NodesArgs) -> Result<Vec<NodeReport>, Failure> {
    let node = args.connect.join(&args.node_id, |id| {
        let mut options = NodeOptions::new(id);
        options.node.snip = net::snip("nodes");
        options.node.stream.accept_policy = AcceptPolicy::RejectAll(ReplyCode::BUFFER_UNAVAILABLE);
        options
    });
    let node = node.await?;
    let found = node.discover(Duration::from_secs_f64(args.wait), MOST_NODES).await?;
    if found.is_empty()
        && let Some(failure) = args.connect.heard_the_other_protocol(&node).await
    {
        node.close().await;
        return Err(failure);
    }
    // One node at a time, its SNIP and PIP at once: answers take milliseconds, and a node that
    // does not answer costs at most the SNIP and PIP timeouts.
    let mut reports = Vec::with_capacity(found.len());
    for peer in &found {
        reports.push(describe(&node, *peer).await);
    }
    node.close().await;
    Ok(reports)
}

/// Asks one node for its SNIP and PIP at once.
pub(crate) async fn describe(node: &Node, peer: NodeId) -> NodeReport {
    let (snip, protocols) = tokio::join!(node.snip(peer), node.protocols(peer, PIP_TIMEOUT));
    // Asked after the answers (or their timeouts): by then the link has taken in whatever
    // named the peer's alias, even when another connection (`ui`'s monitor) heard it first.
    let alias = node.alias_of(peer).await;
    let mut errors = Vec::new();
    let snip = keep(snip, &mut errors).map(SnipReport::from);
    let protocols = keep(protocols, &mut errors).map(|p: Protocols| p.names().collect());
    let alias = keep(alias, &mut errors).flatten().map(|a| format!("{a:03X}"));
    NodeReport { node_id: peer.to_string(), alias, snip, protocols, errors }
}

/// The value, or `None` with the error's text recorded.
fn keep<T>(result: Result<T, Error>, errors: &mut Vec<String>) -> Option<T> {
    result.map_err(|e| errors.push(e.to_string())).ok()
}

fn text_line(report: &NodeReport) -> String {
    let mut line = report.node_id.clone();
    if let Some(alias) = &report.alias {
        line.push_str(&format!("  alias {alias}"));
    }
    match &report.snip {
        Some(s) => {
            line.push_str(&format!(
                "  {} {} (hw {}, sw {})",
                s.manufacturer, s.model, s.hardware_version, s.software_version
            ));
            if !s.user_name.is_empty() {
                line.push_str(&format!("  \"{}\"", s.user_name));
            }
            if !s.user_description.is_empty() {
                line.push_str(&format!("  {}", s.user_description));
            }
        }
        None => line.push_str("  (no SNIP)"),
    }
    match &report.protocols {
        Some(names) => line.push_str(&format!("  [{}]", names.join(" "))),
        None => line.push_str("  [no PIP]"),
    }
    line
}
