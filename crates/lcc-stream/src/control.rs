//! `lcc-stream reboot` and `lcc-stream factory-reset`: the Reboot and Factory Reset buttons
//! of a configuration tool. Each sends the node one Memory Configuration command and ends
//! at its Datagram OK or at the node's restart (Initialization Complete), which is how many
//! nodes answer a Reboot.

use std::process::ExitCode;

use clap::Args;
use openlcb_stream::NodeId;
use openlcb_tokio::NodeCommand;
use serde_json::json;

use crate::memory::{self, ClientArgs, Moved};
use crate::net;
use crate::outcome::{Failure, Outcome};

/// Options of `lcc-stream reboot`.
#[derive(Debug, Args)]
#[command(after_help = after_help())]
pub(crate) struct RebootArgs {
    /// The node.
    #[arg(value_name = "NODE_ID", value_parser = crate::args::node_id)]
    node: NodeId,
    #[command(flatten)]
    client: ClientArgs,
}

/// Options of `lcc-stream factory-reset`.
#[derive(Debug, Args)]
#[command(after_help = after_help())]
pub(crate) struct FactoryResetArgs {
    /// The node.
    #[arg(value_name = "NODE_ID", value_parser = crate::args::node_id)]
    node: NodeId,
    /// Do it: every setting of the node goes back to its default (without --yes nothing is
    /// sent and the exit status is 2).
    #[arg(long)]
    yes: bool,
    #[command(flatten)]
    client: ClientArgs,
}

fn after_help() -> String {
    let outcomes = [Outcome::Usage, Outcome::Rejected, Outcome::TimedOut, Outcome::NotFound];
    format!(
        "--json prints one object: node, command, result (the word of the exit status below) and, on \
         failure, error.\n\n{}",
        net::network_help(&outcomes)
    )
}

pub(crate) fn reboot(args: &RebootArgs) -> Result<ExitCode, String> {
    let done = format!("{} accepted the reboot", args.node);
    send(NodeCommand::Reboot, args.node, &args.client, "reboot", Ok(done))
}

pub(crate) fn factory_reset(args: &FactoryResetArgs) -> Result<ExitCode, String> {
    let done = match args.yes {
        true => Ok(format!("{} accepted the factory reset (its settings are not read back)", args.node)),
        false => Err(format!(
            "nothing sent: a factory reset puts every setting of {} back to its default; add --yes to do it \
             (`config backup` saves them first)",
            args.node
        )),
    };
    send(NodeCommand::FactoryReset, args.node, &args.client, "factory-reset", done)
}

/// Sends `command` to `peer` (unless `done` is already a refusal) and prints the outcome.
fn send(
    command: NodeCommand,
    peer: NodeId,
    client: &ClientArgs,
    name: &str,
    done: Result<String, String>,
) -> Result<ExitCode, String> {
    let outcome = match done {
        Err(refusal) => Err((Outcome::Usage, refusal)),
        Ok(done) => net::runtime()?.block_on(async {
            let mut interrupt = net::Interrupt::new()?;
            let sent = async {
                let node = memory::join(client, name, peer).await?;
                let transfer = node.send_command(peer, command).await.map_err(Failure::Net);
                let sent = match transfer {
                    Ok(transfer) => {
                        let moved = &mut Moved::default();
                        memory::follow(&node, transfer, None, true, &client.pace, &mut interrupt, moved).await
                    }
                    Err(failure) => Err(failure),
                };
                node.close().await;
                sent
            };
            Ok::<_, String>(sent.await.map(|_| done).map_err(|failure| (failure.outcome(), failure.to_string())))
        })?,
    };
    let mut report = json!({ "node": peer.to_string(), "command": name });
    let status = match outcome {
        Ok(done) => {
            if !client.json {
                net::say(&done);
            }
            report["result"] = json!(Outcome::Ok.word());
            Outcome::Ok.status()
        }
        Err((outcome, error)) => {
            eprintln!("lcc-stream {name}: {error}");
            report["result"] = json!(outcome.word());
            report["error"] = json!(error);
            outcome.status()
        }
    };
    if client.json {
        net::print_json(&report);
    }
    Ok(ExitCode::from(status))
}
