//! Event Transport on a [`Node`](crate::Node): sending reports and Identify messages
//! ([`Node::send_event`](crate::Node::send_event), [`Node::identify_events`](crate::Node::identify_events),
//! [`Node::identify`](crate::Node::identify)) and receiving what the node's
//! [`EventConfig`] lets through ([`Node::event_notices`](crate::Node::event_notices)).
//!
//! The events the node produces and consumes are declared in
//! [`NodeOptions::node`](crate::NodeOptions::node)`.events`; the node answers Identify
//! messages for them by itself.

use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};

use openlcb_node::{EventConfig, EventError, EventNotice, EventRole};
use openlcb_stream::{EventId, NodeId};
use tokio::sync::{mpsc, oneshot};

use crate::Error;

/// Notices queued for one [`EventNotices`] before more are dropped (and counted in
/// [`EventNotices::dropped`]): room for every report of one read from the connection, so
/// that a listener that keeps up loses none.
pub const EVENT_NOTICE_QUEUE: usize = 4096;

/// The shortest Producer/Consumer Event Report in GridConnect text.
const SHORTEST_REPORT: usize = ":X195B4000N0000000000000000;".len();
const _: () = assert!(EVENT_NOTICE_QUEUE >= crate::driver::READ_CHUNK / SHORTEST_REPORT);

/// The event messages a node receives (reports, Learn Event, and with
/// [`Listen::Everything`](openlcb_node::Listen::Everything) every Identified message), from
/// [`Node::event_notices`](crate::Node::event_notices).
#[derive(Debug)]
pub struct EventNotices {
    notices: mpsc::Receiver<EventNotice>,
    dropped: Arc<AtomicU64>,
}

impl EventNotices {
    /// The next notice; `None` once the node has stopped.
    pub async fn next(&mut self) -> Option<EventNotice> {
        self.notices.recv().await
    }

    /// The next notice already waiting, if any (it never waits).
    pub fn try_next(&mut self) -> Option<EventNotice> {
        self.notices.try_recv().ok()
    }

    /// The notices this listener has lost so far: those that found its queue of
    /// [`EVENT_NOTICE_QUEUE`] full, and those the node itself had no room for. Every notice
    /// the node received since the listener started is either taken from it or counted here.
    pub fn dropped(&self) -> u64 {
        self.dropped.load(Ordering::Relaxed)
    }
}

/// What a handle asks of the driver's event service.
#[derive(Debug)]
pub(crate) enum EventCommand {
    /// Registers a listener and says so (`listening`).
    Listen {
        sink: mpsc::Sender<EventNotice>,
        dropped: Arc<AtomicU64>,
        listening: oneshot::Sender<()>,
    },
    Report {
        event: EventId,
        payload: Vec<u8>,
        reply: oneshot::Sender<Result<(), Error>>,
    },
    IdentifyEvents {
        peer: Option<NodeId>,
        reply: oneshot::Sender<Result<(), Error>>,
    },
    Identify {
        role: EventRole,
        event: EventId,
        reply: oneshot::Sender<Result<(), Error>>,
    },
    Declare {
        events: EventConfig,
        reply: oneshot::Sender<Result<(), Error>>,
    },
}

impl EventCommand {
    /// A new listener: the command that registers it (answered on `listening`), and its end.
    pub(crate) fn listen(listening: oneshot::Sender<()>) -> (EventCommand, EventNotices) {
        let (sink, notices) = mpsc::channel(EVENT_NOTICE_QUEUE);
        let dropped = Arc::new(AtomicU64::new(0));
        (EventCommand::Listen { sink, dropped: dropped.clone(), listening }, EventNotices { notices, dropped })
    }
}

/// One listener: its queue and its count of notices lost.
#[derive(Debug)]
struct Listener {
    sink: mpsc::Sender<EventNotice>,
    dropped: Arc<AtomicU64>,
}

impl Listener {
    fn lose(&self, count: u64) {
        self.dropped.fetch_add(count, Ordering::Relaxed);
    }
}

/// The driver's side: the listeners, and the commands carried out on the sans-IO node.
#[derive(Debug, Default)]
pub(crate) struct EventDriver {
    listeners: Vec<Listener>,
    /// Notices lost, summed over the listeners.
    dropped: u64,
    /// The node's own count of notices it dropped, as last seen.
    node_dropped: u64,
}

impl EventDriver {
    pub(crate) fn command(&mut self, stack: &mut openlcb_node::Node, command: EventCommand) {
        let (result, reply) = match command {
            EventCommand::Listen { sink, dropped, listening } => {
                self.listeners.push(Listener { sink, dropped });
                let _ = listening.send(());
                return;
            }
            EventCommand::Report { event, payload, reply } => (stack.send_event(event, &payload), reply),
            EventCommand::IdentifyEvents { peer, reply } => (stack.identify_events(peer), reply),
            EventCommand::Identify { role, event, reply } => (stack.identify(role, event), reply),
            EventCommand::Declare { events, reply } => {
                stack.set_events(events);
                (Ok(()), reply)
            }
        };
        let _ = reply.send(result.map_err(|_: EventError| Error::Busy));
    }

    /// Hands `notice` to every listener still there; one that lets its queue fill loses it.
    pub(crate) fn notice(&mut self, notice: EventNotice) {
        self.listeners.retain(|listener| !listener.sink.is_closed());
        let Some((last, others)) = self.listeners.split_last() else { return };
        for listener in others {
            if listener.sink.try_send(notice.clone()).is_err() {
                listener.lose(1);
                self.dropped += 1;
            }
        }
        if last.sink.try_send(notice).is_err() {
            last.lose(1);
            self.dropped += 1;
        }
    }

    /// Takes the node's count of the notices it dropped (`total` so far): those since the
    /// last look were lost to every listener.
    pub(crate) fn node_dropped(&mut self, total: u64) {
        let lost = total.saturating_sub(self.node_dropped);
        self.node_dropped = total;
        if lost > 0 {
            for listener in &self.listeners {
                listener.lose(lost);
            }
            self.dropped += lost * self.listeners.len() as u64;
        }
    }

    pub(crate) fn dropped(&self) -> u64 {
        self.dropped
    }
}
