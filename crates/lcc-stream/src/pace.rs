//! The progress rule that makes every transfer end: after a grace period, the bytes moved
//! must keep up with a minimum average rate. Each step of an operation has its own deadline
//! (a reply, a Proceed, a reboot); this rule ends the transfers whose every step comes in
//! time but carries next to nothing (a node that trickles a byte a second).

use std::fmt;
use std::time::{Duration, Instant};

use clap::Args;

/// How often the rule is checked.
const CHECK_EVERY: Duration = Duration::from_millis(250);

/// The help of the rule, for the commands that keep it.
pub(crate) const PACE_HELP: &str = "\
Every transfer ends: each step has its deadline (a reply, a Proceed, a reboot), and after
--grace seconds the average rate since the first command must stay above --min-rate bytes per
second (so a transfer of N bytes has at most grace + N / min-rate seconds), until every byte
has moved; a transfer that falls behind is given up with exit 5 (timed_out).

";

/// `--min-rate` and `--grace`.
#[derive(Debug, Clone, Copy, Args)]
pub(crate) struct PaceArgs {
    /// The slowest average rate, in bytes per second, a transfer may keep once --grace has
    /// passed; below it the transfer is given up (exit 5). 0: no minimum, the transfer then
    /// lasts as long as the other node keeps answering each step in time, however little it
    /// sends.
    #[arg(long, value_name = "BYTES_PER_S", default_value_t = 100)]
    min_rate: u64,
    /// Seconds before --min-rate applies (a target's reboot at Freeze, a slow first answer).
    #[arg(long, value_name = "SECS", default_value_t = 30.0, value_parser = grace)]
    grace: f64,
}

fn grace(text: &str) -> Result<f64, String> {
    match text.parse::<f64>() {
        Ok(secs) if (0.0..1e9).contains(&secs) => Ok(secs),
        _ => Err("a number of seconds, 0 or more".into()),
    }
}

/// A transfer that fell behind [`PaceArgs`]: what it had moved, and when.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct TooSlow {
    pub(crate) bytes: u64,
    pub(crate) elapsed: Duration,
    pub(crate) min_rate: u64,
    pub(crate) grace: f64,
}

impl fmt::Display for TooSlow {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "the transfer was given up after {:.1} s with {} bytes moved: slower than --min-rate {} \
             bytes per second once the --grace of {} s had passed (a lower --min-rate, or 0, waits longer)",
            self.elapsed.as_secs_f64(),
            self.bytes,
            self.min_rate,
            self.grace
        )
    }
}

impl PaceArgs {
    /// The rule's verdict at `elapsed` with `bytes` moved of `total` (if known).
    fn behind(&self, elapsed: Duration, bytes: u64, total: Option<u64>) -> bool {
        let since = elapsed.as_secs_f64() - self.grace;
        let done = total.is_some_and(|total| bytes >= total);
        self.min_rate > 0 && since > 0.0 && !done && (bytes as f64) < self.min_rate as f64 * since
    }

    /// Resolves once a transfer that started at `started` falls behind; `moved` says the
    /// bytes moved so far. Never resolves with `--min-rate 0`.
    pub(crate) async fn watch(&self, started: Instant, total: Option<u64>, moved: impl Fn() -> u64) -> TooSlow {
        let mut tick = tokio::time::interval(CHECK_EVERY);
        tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
        loop {
            tick.tick().await;
            let (elapsed, bytes) = (started.elapsed(), moved());
            if self.behind(elapsed, bytes, total) {
                return TooSlow { bytes, elapsed, min_rate: self.min_rate, grace: self.grace };
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn pace(min_rate: u64, grace: f64) -> PaceArgs {
        PaceArgs { min_rate, grace }
    }

    #[test]
    fn a_transfer_is_behind_only_after_the_grace_and_below_the_rate() {
        let rule = pace(100, 10.0);
        let at = Duration::from_secs;
        assert!(!rule.behind(at(9), 0, None), "within the grace");
        assert!(!rule.behind(at(20), 1_000, None), "exactly on the rate");
        assert!(rule.behind(at(20), 999, None), "one byte short");
        assert!(!rule.behind(at(1_000), 50, Some(50)), "every byte moved: the step deadlines rule");
        assert!(!pace(0, 0.0).behind(at(1_000_000), 0, None), "no minimum");
    }
}
