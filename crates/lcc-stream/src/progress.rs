//! The progress display of every long command (`send`, `recv`, and the Memory Configuration
//! commands): one line on stderr, decimal units (kB, MB, MB/s) as every rate the tool prints,
//! redrawn in place and fitted to the terminal's width.
//!
//! Use: make one with [`Progress::start`] when the transfer begins (`None` when the size is
//! unknown), call [`Progress::set`] with the bytes done after each chunk (not per frame; the
//! display redraws at most 10 times a second), and [`Progress::finish`] before printing the
//! result. It draws nothing when stderr is not a terminal or when the command prints JSON.
//! Several at once (recv's concurrent streams) share one [`ProgressGroup`].

use std::io::IsTerminal as _;

use indicatif::{MultiProgress, ProgressBar, ProgressDrawTarget, ProgressStyle};

/// With a known size: bytes, bar, rate, time left. Outside the bar it takes at most 33
/// columns, so it fits on one line of a 40-column terminal.
const SIZED: &str = "{decimal_bytes:>9}/{decimal_total_bytes:<9} {wide_bar} {decimal_bytes_per_sec:>11} {eta:>3}";
/// With no size known: bytes and rate.
const UNSIZED: &str = "{spinner} {decimal_bytes:>9} {decimal_bytes_per_sec:>11} {wide_msg}";

/// Where progress is drawn: stderr if it is a terminal and the output is for a person.
#[derive(Debug, Clone)]
pub(crate) struct ProgressGroup(MultiProgress);

impl ProgressGroup {
    /// A group on stderr, or a hidden one with `json` or when stderr is not a terminal.
    pub(crate) fn new(json: bool) -> Self {
        let target = if json || !std::io::stderr().is_terminal() {
            ProgressDrawTarget::hidden()
        } else {
            ProgressDrawTarget::stderr_with_hz(10)
        };
        ProgressGroup(MultiProgress::with_draw_target(target))
    }

    /// One transfer of `total` bytes (`None`: unknown), labelled `label` when unsized.
    pub(crate) fn start(&self, total: Option<u64>, label: &str) -> Progress {
        let bar = match total {
            Some(total) => ProgressBar::new(total).with_style(style(SIZED)),
            None => ProgressBar::no_length().with_style(style(UNSIZED)).with_message(label.to_string()),
        };
        Progress(self.0.add(bar))
    }
}

fn style(template: &str) -> ProgressStyle {
    // The templates are constants checked by the tests below.
    ProgressStyle::with_template(template).unwrap_or_else(|_| ProgressStyle::default_bar())
}

/// One transfer's line; see the module doc.
#[derive(Debug)]
pub(crate) struct Progress(ProgressBar);

impl Progress {
    /// A transfer shown on its own (see [`ProgressGroup::new`] for when it is drawn).
    pub(crate) fn start(total: Option<u64>, json: bool) -> Self {
        ProgressGroup::new(json).start(total, "")
    }

    /// `done` bytes have been transferred.
    pub(crate) fn set(&self, done: u64) {
        self.0.set_position(done);
    }

    /// Removes the line, before the result is printed.
    pub(crate) fn finish(self) {
        self.0.finish_and_clear();
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_templates_parse() {
        for template in [SIZED, UNSIZED] {
            assert!(ProgressStyle::with_template(template).is_ok(), "{template}");
        }
    }

    #[test]
    fn a_json_run_draws_nothing() {
        let progress = Progress::start(Some(100), true);
        assert!(progress.0.is_hidden());
        progress.set(50);
        progress.finish();
    }
}
