//! Lines of output that the bus can outpace (the reports of `events watch` and `serve`):
//! written by a thread of their own through a bounded queue, so that a slow terminal or pipe
//! never holds up the node, and every report that cannot be printed is counted and said
//! where it was lost.

use std::io::Write as _;
use std::sync::mpsc::{Receiver, SyncSender, TrySendError, sync_channel};
use std::time::Duration;

use tokio::sync::oneshot;

/// Lines waiting to be written; a report that finds them all taken is dropped.
const PRINT_QUEUE: usize = 4096;
/// Bytes written at once, at most (a batch of the lines waiting).
const PRINT_BATCH: usize = 64 * 1024;
/// How long the end waits for the lines still queued to be written.
const DRAIN_LIMIT: Duration = Duration::from_secs(5);
/// How often the end tries again to queue its last lines.
const DRAIN_POLL: Duration = Duration::from_millis(10);

/// Where the lines go.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Output {
    Stdout,
    Stderr,
}

/// The queue to the printing thread, and the count of what went through it.
pub(crate) struct Printer {
    queue: SyncSender<String>,
    /// Told when the thread has written everything and ended.
    done: oneshot::Receiver<()>,
    /// Reports queued.
    printed: u64,
    /// Reports lost: by the node (its queue for the listener was full) or here.
    dropped: u64,
    /// Of `dropped`, those no line has said yet.
    unsaid: u64,
    /// The listener's count of lost notices, as last seen.
    node_lost: u64,
}

impl Printer {
    pub(crate) fn start(output: Output) -> Result<Printer, String> {
        let (queue, lines) = sync_channel(PRINT_QUEUE);
        let (finished, done) = oneshot::channel();
        std::thread::Builder::new()
            .name("output".into())
            .spawn(move || {
                print_all(&lines, output);
                let _ = finished.send(());
            })
            .map_err(|e| format!("cannot start the output thread: {e}"))?;
        Ok(Printer { queue, done, printed: 0, dropped: 0, unsaid: 0, node_lost: 0 })
    }

    /// Takes the listener's count of the notices it lost so far
    /// ([`EventNotices::dropped`](openlcb_tokio::EventNotices::dropped)): they were dropped too.
    pub(crate) fn node_lost(&mut self, node_lost: u64) {
        let lost = node_lost.saturating_sub(self.node_lost);
        self.node_lost = node_lost;
        self.dropped += lost;
        self.unsaid += lost;
    }

    /// The node's listener was replaced by a new one (a new connection to the hub): the
    /// counts that [`node_lost`](Self::node_lost) takes start again from 0.
    pub(crate) fn new_listener(&mut self) {
        self.node_lost = 0;
    }

    /// Queues the line of a report (it ends with a newline), after `said(count)`, the line
    /// saying how many were dropped since the last such line, if any were; a report that
    /// finds the queue full is dropped.
    pub(crate) fn report(&mut self, line: String, said: impl FnOnce(u64) -> String) {
        if self.unsaid > 0 && self.queue.try_send(said(self.unsaid)).is_ok() {
            self.unsaid = 0;
        }
        if self.queue.try_send(line).is_ok() {
            self.printed += 1;
        } else {
            self.dropped += 1;
            self.unsaid += 1;
        }
    }

    /// Reports queued so far.
    pub(crate) fn printed(&self) -> u64 {
        self.printed
    }

    /// Reports dropped so far.
    pub(crate) fn dropped(&self) -> u64 {
        self.dropped
    }

    /// Reports dropped that no line has said yet.
    pub(crate) fn unsaid(&self) -> u64 {
        self.unsaid
    }

    /// Queues `last` and waits until every line is written, for at most [`DRAIN_LIMIT`];
    /// `true` if they all were.
    pub(crate) async fn finish(self, last: Vec<String>) -> bool {
        let Printer { queue, done, .. } = self;
        let written = async move {
            for mut line in last {
                loop {
                    match queue.try_send(line) {
                        Ok(()) => break,
                        Err(TrySendError::Full(again)) => line = again,
                        Err(TrySendError::Disconnected(_)) => return false,
                    }
                    tokio::time::sleep(DRAIN_POLL).await;
                }
            }
            // The queue closes here: the thread ends once it has written the last line.
            drop(queue);
            done.await.is_ok()
        };
        tokio::time::timeout(DRAIN_LIMIT, written).await.unwrap_or(false)
    }
}

/// The printing thread: the lines waiting, a batch at a time, until the queue closes.
fn print_all(lines: &Receiver<String>, output: Output) {
    let mut batch = String::new();
    while let Ok(line) = lines.recv() {
        batch.clear();
        batch.push_str(&line);
        while batch.len() < PRINT_BATCH {
            match lines.try_recv() {
                Ok(more) => batch.push_str(&more),
                Err(_) => break,
            }
        }
        match output {
            Output::Stdout => out!("{batch}"),
            // Nowhere to say that stderr failed.
            Output::Stderr => drop(std::io::stderr().write_all(batch.as_bytes())),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_report_that_finds_the_queue_full_is_counted_and_said_before_the_next() {
        let (queue, lines) = sync_channel(2);
        let (_finished, done) = oneshot::channel();
        let mut printer = Printer { queue, done, printed: 0, dropped: 0, unsaid: 0, node_lost: 0 };
        let said = |n| format!("{n} dropped\n");
        printer.node_lost(2);
        printer.report("a\n".into(), said);
        printer.report("b\n".into(), said);
        let taken: Vec<String> = lines.try_iter().collect();
        assert_eq!(taken, ["2 dropped\n", "a\n"]);
        printer.report("c\n".into(), said);
        let taken: Vec<String> = lines.try_iter().collect();
        assert_eq!(taken, ["1 dropped\n", "c\n"]);
        assert_eq!((printer.printed(), printer.dropped(), printer.unsaid()), (2, 3, 0), "5 reports in all");
    }
}
