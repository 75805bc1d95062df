//! What a long-running command (`serve`, `recv`, `events watch`, live `monitor`) does when
//! it loses the hub: it says so, waits, and tries again, waiting twice as long after each
//! failed attempt, with the figures of `hub --upstream`
//! ([`UPSTREAM_RETRY_FIRST`], [`UPSTREAM_RETRY_MAX`]), until it is back, Ctrl-C comes or
//! `--reconnect-for` runs out. One-shot commands (`send`, `read`, `nodes`...) have none of
//! this: they exit with status 6.

use std::fmt::Display;
use std::future::Future;
use std::time::Duration;

use clap::Args;
use openlcb_tokio::hub::{UPSTREAM_RETRY_FIRST, UPSTREAM_RETRY_MAX};
use openlcb_tokio::{Error, Node};
use tokio::time::Instant;

use crate::net::Interrupt;
use crate::outcome::{Outcome, net_outcome};

/// The longest one attempt to reach the hub again may take (a node's connection and login
/// have bounds of their own, within this).
const ATTEMPT_LIMIT: Duration = Duration::from_secs(15);

/// `--no-reconnect` and `--reconnect-for` of a long-running command.
#[derive(Debug, Args)]
pub(crate) struct ReconnectArgs {
    /// Exit at once with status 6 when the connection to the hub is lost, as one-shot
    /// commands do (for scripts), instead of joining again.
    #[arg(long)]
    no_reconnect: bool,
    /// Give up, with status 6, when the hub has not been reached again this many seconds
    /// after it was lost [default: keep trying until Ctrl-C].
    #[arg(long, value_name = "SECS", conflicts_with = "no_reconnect", value_parser = crate::args::positive::<u64>)]
    reconnect_for: Option<u64>,
}

/// The help text that says what a long-running command does when it loses the hub.
pub(crate) const RECONNECT_HELP: &str = "\
A lost hub (restarted, a network blip) is not the end: the loss is said on stderr with the
wait before the next attempt, 0.25 s, then twice as long after each failed attempt, at most
5 s apart (as `hub --upstream`); each failed attempt is said with its reason, and the return
as `rejoined the hub at ADDR as ALIAS/NODE_ID`: the node logs in again from scratch, with
the same Node ID. What was under way at the loss ends with its error. --no-reconnect exits
with status 6 at once instead; --reconnect-for SECS gives up (status 6) after that long
without the hub; Ctrl-C while waiting exits with 130 at once.

";

/// Why a command stopped trying to reach the hub.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Stop {
    /// SIGINT, SIGTERM or SIGHUP while waiting or trying.
    Interrupted,
    /// `--no-reconnect`, or `--reconnect-for` ran out: the command ends as the loss says.
    GaveUp,
}

/// The waits between attempts: [`UPSTREAM_RETRY_FIRST`], then twice as long each time, at
/// most [`UPSTREAM_RETRY_MAX`].
#[derive(Debug)]
struct Backoff {
    next: Duration,
}

impl Backoff {
    fn new() -> Self {
        Backoff { next: UPSTREAM_RETRY_FIRST }
    }

    /// The wait before the next attempt.
    fn next_wait(&mut self) -> Duration {
        let wait = self.next;
        self.next = (wait * 2).min(UPSTREAM_RETRY_MAX);
        wait
    }
}

/// Whether the node ended because its connection was lost (rather than, say, another node
/// taking its Node ID), so that joining again may help.
pub(crate) fn is_lost(error: &Error) -> bool {
    net_outcome(error) == Outcome::ConnectionLost
}

impl ReconnectArgs {
    /// After the connection of `command` to `addr` was lost for `reason`: unless
    /// `--no-reconnect`, says so and calls `attempt` until it succeeds, with the waits of
    /// [`Backoff`] between attempts and each failure said. Stops at once on `interrupt`, and
    /// once `--reconnect-for` has passed since the loss.
    pub(crate) async fn rejoin<T, E: Display, F: Future<Output = Result<T, E>>>(
        &self,
        command: &str,
        addr: &str,
        reason: &dyn Display,
        interrupt: &mut Interrupt,
        mut attempt: impl FnMut() -> F,
    ) -> Result<T, Stop> {
        if self.no_reconnect {
            return Err(Stop::GaveUp);
        }
        let lost = Instant::now();
        let give_up = self.reconnect_for.map(|secs| lost + Duration::from_secs(secs));
        let mut backoff = Backoff::new();
        let mut wait = backoff.next_wait();
        eprintln!(
            "lcc-stream {command}: lost the hub at {addr}: {reason}; trying again in {:.2} s",
            wait.as_secs_f64()
        );
        let mut number = 0u64;
        loop {
            number += 1;
            let next = Instant::now() + wait;
            let next = give_up.map_or(next, |give_up| next.min(give_up));
            tokio::select! {
                () = tokio::time::sleep_until(next) => {}
                () = interrupt.wait() => return Err(Stop::Interrupted),
            }
            let failure = tokio::select! {
                tried = tokio::time::timeout(ATTEMPT_LIMIT, attempt()) => match tried {
                    Ok(Ok(joined)) => return Ok(joined),
                    Ok(Err(error)) => error.to_string(),
                    Err(_) => format!("no answer within {} s", ATTEMPT_LIMIT.as_secs()),
                },
                () = interrupt.wait() => return Err(Stop::Interrupted),
            };
            if give_up.is_some_and(|give_up| Instant::now() >= give_up) {
                eprintln!(
                    "lcc-stream {command}: attempt {number} failed: {failure}; giving up on the hub at {addr}, \
                     {:.0} s after the loss (--reconnect-for)",
                    lost.elapsed().as_secs_f64()
                );
                return Err(Stop::GaveUp);
            }
            wait = backoff.next_wait();
            eprintln!(
                "lcc-stream {command}: attempt {number} failed: {failure}; trying again in {:.2} s",
                wait.as_secs_f64()
            );
        }
    }
}

/// Says on stderr that `node` of `command` is back on the hub at `addr`, with its new CAN
/// alias (none over OpenLCB-TCP).
pub(crate) async fn say_rejoined(command: &str, addr: &str, node: &Node) {
    let id = node.node_id();
    match node.alias_of(id).await {
        Ok(Some(alias)) => eprintln!("lcc-stream {command}: rejoined the hub at {addr} as {alias:03X}/{id}"),
        _ => eprintln!("lcc-stream {command}: rejoined the hub at {addr} as {id}"),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_waits_double_up_to_those_of_hub_upstream() {
        let mut backoff = Backoff::new();
        let waits: Vec<u64> = (0..8).map(|_| backoff.next_wait().as_millis() as u64).collect();
        assert_eq!(waits, [250, 500, 1000, 2000, 4000, 5000, 5000, 5000]);
    }
}
