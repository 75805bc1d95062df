//! Broadcast Time on a [`Node`](crate::Node): the clocks declared in
//! [`NodeOptions::node`](crate::NodeOptions::node)`.clocks` run inside the driver; their
//! changes come out of [`Node::clock_events`](crate::Node::clock_events), their state from
//! [`Node::clock`](crate::Node::clock), and [`Node::set_clock`](crate::Node::set_clock) and
//! [`Node::query_clock`](crate::Node::query_clock) drive them (or, from a consumer, the
//! generator on the bus).

use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};

use openlcb_node::broadcast_time::{ClockError, ClockEvent, ClockId, ClockSet, ClockState};
use openlcb_stream::Instant;
use tokio::sync::{mpsc, oneshot};

use crate::Error;

/// Clock events queued for one [`ClockEvents`] before more are dropped (and counted): a
/// fast clock at its fastest begins about nine minutes a real second.
pub const CLOCK_EVENT_QUEUE: usize = 1024;

/// The changes of the node's clocks, from [`Node::clock_events`](crate::Node::clock_events).
#[derive(Debug)]
pub struct ClockEvents {
    events: mpsc::Receiver<ClockEvent>,
    dropped: Arc<AtomicU64>,
}

impl ClockEvents {
    /// The next change; `None` once the node has stopped.
    pub async fn next(&mut self) -> Option<ClockEvent> {
        self.events.recv().await
    }

    /// Changes this listener lost because it left [`CLOCK_EVENT_QUEUE`] waiting.
    pub fn dropped(&self) -> u64 {
        self.dropped.load(Ordering::Relaxed)
    }
}

/// What a handle asks of the driver's clocks.
#[derive(Debug)]
pub(crate) enum ClockCommand {
    Listen { sink: mpsc::Sender<ClockEvent>, dropped: Arc<AtomicU64>, listening: oneshot::Sender<()> },
    State { clock: ClockId, reply: oneshot::Sender<Option<ClockState>> },
    Set { clock: ClockId, set: ClockSet, reply: oneshot::Sender<Result<(), ClockError>> },
    Query { clock: ClockId, reply: oneshot::Sender<Result<(), ClockError>> },
}

impl ClockCommand {
    /// A new listener: the command that registers it (answered on `listening`), and its end.
    pub(crate) fn listen(listening: oneshot::Sender<()>) -> (ClockCommand, ClockEvents) {
        let (sink, events) = mpsc::channel(CLOCK_EVENT_QUEUE);
        let dropped = Arc::new(AtomicU64::new(0));
        (ClockCommand::Listen { sink, dropped: dropped.clone(), listening }, ClockEvents { events, dropped })
    }
}

/// The driver's side: the listeners.
#[derive(Debug, Default)]
pub(crate) struct ClockDriver {
    listeners: Vec<(mpsc::Sender<ClockEvent>, Arc<AtomicU64>)>,
}

impl ClockDriver {
    pub(crate) fn command(&mut self, now: Instant, stack: &mut openlcb_node::Node, command: ClockCommand) {
        match command {
            ClockCommand::Listen { sink, dropped, listening } => {
                self.listeners.push((sink, dropped));
                let _ = listening.send(());
            }
            ClockCommand::State { clock, reply } => {
                let _ = reply.send(stack.clock(clock, now));
            }
            ClockCommand::Set { clock, set, reply } => {
                let _ = reply.send(stack.set_clock(now, clock, set));
            }
            ClockCommand::Query { clock, reply } => {
                let _ = reply.send(stack.query_clock(now, clock));
            }
        }
    }

    /// Hands `event` to every listener still there; one whose queue is full loses it.
    pub(crate) fn event(&mut self, event: ClockEvent) {
        self.listeners.retain(|(sink, _)| !sink.is_closed());
        for (sink, dropped) in &self.listeners {
            if sink.try_send(event).is_err() {
                dropped.fetch_add(1, Ordering::Relaxed);
            }
        }
    }
}

/// A clock command's error as the driver's.
pub(crate) fn clock_error(error: ClockError) -> Error {
    match error {
        ClockError::QueueFull => Error::Busy,
        error => Error::Clock(error),
    }
}
