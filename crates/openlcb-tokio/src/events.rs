//! Event Transport on a [`Node`](crate::Node): sending reports and Identify messages
//! ([`Node::send_event`](crate::Node::send_event), [`Node::identify_events`](crate::Node::identify_events),
//! [`Node::identify`](crate::Node::identify)) and receiving what the node's
//! [`EventConfig`](openlcb_node::EventConfig) lets through ([`Node::event_notices`](crate::Node::event_notices)).
//!
//! The events the node produces and consumes are declared in
//! [`NodeOptions::node`](crate::NodeOptions::node)`.events`; the node answers Identify
//! messages for them by itself.

use openlcb_node::{EventError, EventNotice, EventRole};
use openlcb_stream::{EventId, NodeId};
use tokio::sync::{mpsc, oneshot};

use crate::Error;

/// Notices queued for one [`EventNotices`] before more are dropped (and counted in
/// [`NodeStats::event_notices_dropped`](crate::NodeStats::event_notices_dropped)).
pub const EVENT_NOTICE_QUEUE: usize = 256;

/// The event messages a node receives (reports, Learn Event, and with
/// [`Listen::Everything`](openlcb_node::Listen::Everything) every Identified message), from
/// [`Node::event_notices`](crate::Node::event_notices).
#[derive(Debug)]
pub struct EventNotices {
    notices: mpsc::Receiver<EventNotice>,
}

impl EventNotices {
    pub(crate) fn new(notices: mpsc::Receiver<EventNotice>) -> Self {
        EventNotices { notices }
    }

    /// The next notice; `None` once the node has stopped.
    pub async fn next(&mut self) -> Option<EventNotice> {
        self.notices.recv().await
    }
}

/// What a handle asks of the driver's event service.
#[derive(Debug)]
pub(crate) enum EventCommand {
    Listen { sink: mpsc::Sender<EventNotice> },
    Report { event: EventId, payload: Vec<u8>, reply: oneshot::Sender<Result<(), Error>> },
    IdentifyEvents { peer: Option<NodeId>, reply: oneshot::Sender<Result<(), Error>> },
    Identify { role: EventRole, event: EventId, reply: oneshot::Sender<Result<(), Error>> },
}

/// The driver's side: the listeners, and the commands carried out on the sans-IO node.
#[derive(Debug, Default)]
pub(crate) struct EventDriver {
    listeners: Vec<mpsc::Sender<EventNotice>>,
    dropped: u64,
}

impl EventDriver {
    pub(crate) fn command(&mut self, stack: &mut openlcb_node::Node, command: EventCommand) {
        let (result, reply) = match command {
            EventCommand::Listen { sink } => {
                self.listeners.push(sink);
                return;
            }
            EventCommand::Report { event, payload, reply } => (stack.send_event(event, &payload), reply),
            EventCommand::IdentifyEvents { peer, reply } => (stack.identify_events(peer), reply),
            EventCommand::Identify { role, event, reply } => (stack.identify(role, event), reply),
        };
        let _ = reply.send(result.map_err(|_: EventError| Error::Busy));
    }

    /// Hands `notice` to every listener still there; one that lets its queue fill loses it.
    pub(crate) fn notice(&mut self, notice: EventNotice) {
        self.listeners.retain(|sink| !sink.is_closed());
        for sink in &self.listeners {
            if sink.try_send(notice.clone()).is_err() {
                self.dropped += 1;
            }
        }
    }

    pub(crate) fn dropped(&self) -> u64 {
        self.dropped
    }
}
