//! Trains on a [`Node`](crate::Node): the train declared in
//! [`NodeOptions::node`](crate::NodeOptions::node)`.train` runs inside the driver; what it is
//! told comes out of [`Node::train_events`](crate::Node::train_events), its state from
//! [`Node::train`](crate::Node::train), and [`Node::answer_train_search`](crate::Node::answer_train_search)
//! has a train a command station created answer the search it was created for.

use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};

use openlcb_node::traction::{
    ThrottleError, ThrottleEvent, TractionCommand, TrainError, TrainEvent, TrainIdentity, TrainState,
};
use openlcb_stream::EventId;
use openlcb_stream::NodeId;
use tokio::sync::{mpsc, oneshot};

use crate::Error;

/// Train events queued for one [`TrainEvents`] before more are dropped (and counted).
pub const TRAIN_EVENT_QUEUE: usize = 1024;

/// What the node's train is told, from [`Node::train_events`](crate::Node::train_events).
#[derive(Debug)]
pub struct TrainEvents {
    events: mpsc::Receiver<TrainEvent>,
    dropped: Arc<AtomicU64>,
}

impl TrainEvents {
    /// The next event; `None` once the node has stopped.
    pub async fn next(&mut self) -> Option<TrainEvent> {
        self.events.recv().await
    }

    /// Events this listener lost because it left [`TRAIN_EVENT_QUEUE`] waiting.
    pub fn dropped(&self) -> u64 {
        self.dropped.load(Ordering::Relaxed)
    }
}

/// What a handle asks of the driver's train.
#[derive(Debug)]
pub(crate) enum TrainCommand {
    Listen { sink: mpsc::Sender<TrainEvent>, dropped: Arc<AtomicU64>, listening: oneshot::Sender<()> },
    State { reply: oneshot::Sender<Option<TrainState>> },
    Function { address: u32, reply: oneshot::Sender<Option<u16>> },
    AnswerSearch { event: EventId, reply: oneshot::Sender<Result<(), TrainError>> },
    SetIdentity { identity: TrainIdentity, reply: oneshot::Sender<Result<(), TrainError>> },
    ListenThrottle { sink: mpsc::Sender<ThrottleEvent>, dropped: Arc<AtomicU64>, listening: oneshot::Sender<()> },
    Throttle { train: NodeId, command: TractionCommand, reply: oneshot::Sender<Result<(), ThrottleError>> },
}

/// What the node's throttle hears from trains, from
/// [`Node::throttle_events`](crate::Node::throttle_events).
#[derive(Debug)]
pub struct ThrottleEvents {
    events: mpsc::Receiver<ThrottleEvent>,
    dropped: Arc<AtomicU64>,
}

impl ThrottleEvents {
    /// The next event; `None` once the node has stopped.
    pub async fn next(&mut self) -> Option<ThrottleEvent> {
        self.events.recv().await
    }

    /// Events this listener lost because it left [`TRAIN_EVENT_QUEUE`] waiting.
    pub fn dropped(&self) -> u64 {
        self.dropped.load(Ordering::Relaxed)
    }
}

impl TrainCommand {
    /// A new listener: the command that registers it (answered on `listening`), and its end.
    pub(crate) fn listen(listening: oneshot::Sender<()>) -> (TrainCommand, TrainEvents) {
        let (sink, events) = mpsc::channel(TRAIN_EVENT_QUEUE);
        let dropped = Arc::new(AtomicU64::new(0));
        (TrainCommand::Listen { sink, dropped: dropped.clone(), listening }, TrainEvents { events, dropped })
    }

    /// A new throttle listener, as [`TrainCommand::listen`].
    pub(crate) fn listen_throttle(listening: oneshot::Sender<()>) -> (TrainCommand, ThrottleEvents) {
        let (sink, events) = mpsc::channel(TRAIN_EVENT_QUEUE);
        let dropped = Arc::new(AtomicU64::new(0));
        let command = TrainCommand::ListenThrottle { sink, dropped: dropped.clone(), listening };
        (command, ThrottleEvents { events, dropped })
    }
}

/// The driver's side: the listeners.
#[derive(Debug, Default)]
pub(crate) struct TrainDriver {
    listeners: Vec<(mpsc::Sender<TrainEvent>, Arc<AtomicU64>)>,
    throttle_listeners: Vec<(mpsc::Sender<ThrottleEvent>, Arc<AtomicU64>)>,
}

impl TrainDriver {
    pub(crate) fn command(&mut self, stack: &mut openlcb_node::Node, command: TrainCommand) {
        match command {
            TrainCommand::Listen { sink, dropped, listening } => {
                self.listeners.push((sink, dropped));
                let _ = listening.send(());
            }
            TrainCommand::State { reply } => {
                let _ = reply.send(stack.train());
            }
            TrainCommand::Function { address, reply } => {
                let _ = reply.send(stack.train_function(address));
            }
            TrainCommand::AnswerSearch { event, reply } => {
                let _ = reply.send(stack.answer_train_search(event));
            }
            TrainCommand::SetIdentity { identity, reply } => {
                let _ = reply.send(stack.set_train_identity(identity));
            }
            TrainCommand::ListenThrottle { sink, dropped, listening } => {
                self.throttle_listeners.push((sink, dropped));
                let _ = listening.send(());
            }
            TrainCommand::Throttle { train, command, reply } => {
                let _ = reply.send(stack.throttle_command(train, command));
            }
        }
    }

    /// Hands `event` to every listener still there; one whose queue is full loses it.
    pub(crate) fn event(&mut self, event: TrainEvent) {
        self.listeners.retain(|(sink, _)| !sink.is_closed());
        for (sink, dropped) in &self.listeners {
            if sink.try_send(event).is_err() {
                dropped.fetch_add(1, Ordering::Relaxed);
            }
        }
    }
}

impl TrainDriver {
    /// Hands `event` to every throttle listener still there.
    pub(crate) fn throttle_event(&mut self, event: ThrottleEvent) {
        self.throttle_listeners.retain(|(sink, _)| !sink.is_closed());
        for (sink, dropped) in &self.throttle_listeners {
            if sink.try_send(event).is_err() {
                dropped.fetch_add(1, Ordering::Relaxed);
            }
        }
    }
}

/// A throttle command's error as the driver's.
pub(crate) fn throttle_error(error: ThrottleError) -> Error {
    match error {
        ThrottleError::QueueFull => Error::Busy,
        error => Error::Throttle(error),
    }
}

/// A train command's error as the driver's.
pub(crate) fn train_error(error: TrainError) -> Error {
    match error {
        TrainError::QueueFull => Error::Busy,
        error => Error::Train(error),
    }
}
