//! The one shape of the node's services (datagrams, SNIP, Memory Configuration, events,
//! Broadcast Time): the same few entry points, called by [`Node`](crate::Node) with static
//! dispatch, each with what the node lends it for that call. The services that need only the
//! node's loan are held together in [`Services`], which routes to each of them: a new
//! protocol is one more field there, and nothing in the node changes.

use openlcb_stream::wire::ErrorReport;
use openlcb_stream::{Instant, MessageRef, NodeId, PeerChange};

#[cfg(feature = "broadcast-time")]
use crate::broadcast_time::ClockService;
use crate::datagram::DatagramService;
use crate::events::EventService;
use crate::memconfig::MemoryServer;
use crate::node::Outputs;
use crate::snip::SnipService;
#[cfg(feature = "traction")]
use crate::traction::TrainService;
use crate::{NodeConfig, Protocols};

/// A change of peer as the services take it: the transport's [`PeerChange`], or the loss of
/// this node's own link (every peer lost). Neither change reads the clock: a lost peer is
/// sent nothing, and a renamed one keeps every timer. (A restart is a message, Initialization
/// Complete, offered through [`Service::handle_message`] to each service it concerns.)
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum ServiceChange {
    /// `Some(peer)`: that peer is gone; `None`: this node lost its link, every peer is gone.
    Lost(Option<NodeId>),
    /// The transport now names `from` as `to`: everything open goes on under the new name.
    Renamed { from: NodeId, to: NodeId },
}

impl ServiceChange {
    /// The services' form of the transport's `change` (`None` for a kind they do not know).
    pub(crate) fn of(change: PeerChange) -> Option<Self> {
        match change {
            PeerChange::Lost(peer) => Some(ServiceChange::Lost(Some(peer))),
            PeerChange::Renamed { from, to } => Some(ServiceChange::Renamed { from, to }),
            _ => None,
        }
    }
    /// Whether the change ends what is open with `peer`.
    pub(crate) fn loses(self, peer: NodeId) -> bool {
        matches!(self, ServiceChange::Lost(lost) if lost.is_none_or(|p| p == peer))
    }

    /// The name `peer` has after the change.
    pub(crate) fn rename(self, peer: &mut NodeId) {
        if let ServiceChange::Renamed { from, to } = self
            && *peer == from
        {
            *peer = to;
        }
    }
}

/// What the node lends a service for one call: the time, its output queues, its
/// configuration.
pub(crate) struct Lent<'a> {
    pub(crate) now: Instant,
    pub(crate) out: &'a mut Outputs,
    pub(crate) config: &'a NodeConfig,
}

/// The entry points of every service. `C` is what the node lends it ([`Lent`], or more for a
/// service built on other services).
pub(crate) trait Service<C> {
    /// A message for this node; `false`: not this service's, the next one is asked.
    /// Initialization Complete is offered to every service that keeps something a restart
    /// of the peer ends.
    fn handle_message(&mut self, cx: &mut C, msg: MessageRef<'_>) -> bool;

    /// An Optional Interaction Rejected or Terminate Due To Error from `peer` that may be
    /// this service's; `false`: nothing of it waited on `peer`.
    fn handle_error_report(&mut self, cx: &mut C, peer: NodeId, report: ErrorReport) -> bool;

    /// A peer was lost or renamed.
    fn peer_changed(&mut self, out: &mut Outputs, change: ServiceChange);

    /// Runs the timers due at the lent time; early or repeated calls are harmless.
    fn handle_timeout(&mut self, cx: &mut C);

    /// The service's next deadline.
    fn poll_timeout(&self) -> Option<Instant>;
}

/// The services that need only the node's loan ([`Lent`]), routed to as one. Memory
/// Configuration, built on the datagram service and the stream endpoint, is the node's own.
#[derive(Debug)]
pub(crate) struct Services {
    pub(crate) datagrams: DatagramService,
    pub(crate) snip: SnipService,
    pub(crate) events: EventService,
    #[cfg(feature = "broadcast-time")]
    pub(crate) clocks: ClockService,
    #[cfg(feature = "traction")]
    pub(crate) trains: TrainService,
}

impl Services {
    /// The services of `config`.
    pub(crate) fn new(config: &NodeConfig) -> Self {
        let announce = config.send_initialization_complete;
        Services {
            datagrams: DatagramService::new(&config.datagrams),
            snip: SnipService::new(config),
            events: EventService::new(&config.events, announce),
            #[cfg(feature = "broadcast-time")]
            clocks: ClockService::new(&config.clocks, announce),
            #[cfg(feature = "traction")]
            trains: TrainService::new(config.train.as_ref(), config.throttle.as_ref(), announce),
        }
    }

    /// What the services announce in the Protocol Support Reply.
    pub(crate) fn protocols(&self, config: &NodeConfig) -> Protocols {
        #[cfg(feature = "broadcast-time")]
        let clocks = !config.clocks.is_empty();
        #[cfg(not(feature = "broadcast-time"))]
        let clocks = false;
        let mut protocols = Protocols::NONE;
        if config.events.is_active() || clocks {
            protocols = protocols | Protocols::EVENT_EXCHANGE;
        }
        #[cfg(feature = "traction")]
        if self.trains.is_train() {
            protocols = protocols | Protocols::EVENT_EXCHANGE | Protocols::TRAIN_CONTROL;
        }
        protocols
    }

    /// The next message the services send by themselves (announcements), after the node's
    /// queue is empty.
    pub(crate) fn poll_transmit(&mut self, config: &NodeConfig, node: NodeId) -> Option<openlcb_stream::Message> {
        self.events.poll_transmit(&config.events, node)
    }

    /// Everything is announced again once the link is back (its Initialization Complete).
    pub(crate) fn announce(&mut self, config: &NodeConfig) {
        self.events.announce(&config.events);
        #[cfg(feature = "broadcast-time")]
        self.clocks.announce();
        #[cfg(feature = "traction")]
        self.trains.announce();
    }

    /// The services that keep a space of the memory server themselves bring it up to date
    /// (a train's space 0xF9), and take what a tool wrote there.
    pub(crate) fn sync_memory(&mut self, out: &mut Outputs, server: &mut MemoryServer) {
        #[cfg(feature = "traction")]
        self.trains.sync_memory(out, server);
        #[cfg(not(feature = "traction"))]
        let _ = (out, server);
    }
}

impl Service<Lent<'_>> for Services {
    /// Datagrams and SNIP take their own messages; an Event Transport message concerns every
    /// service built on events (the declared events, the clocks and the train), so each of
    /// them sees it. The train takes Traction Control.
    fn handle_message(&mut self, cx: &mut Lent<'_>, msg: MessageRef<'_>) -> bool {
        if self.datagrams.handle_message(cx, msg) || self.snip.handle_message(cx, msg) {
            return true;
        }
        let taken = self.events.handle_message(cx, msg);
        #[cfg(feature = "broadcast-time")]
        let taken = self.clocks.handle_message(cx, msg) | taken;
        #[cfg(feature = "traction")]
        let taken = self.trains.handle_message(cx, msg) | taken;
        taken
    }

    fn handle_error_report(&mut self, cx: &mut Lent<'_>, peer: NodeId, report: ErrorReport) -> bool {
        // Every service hears it: one naming no MTI may concern several.
        let taken = [
            self.datagrams.handle_error_report(cx, peer, report),
            self.snip.handle_error_report(cx, peer, report),
            self.events.handle_error_report(cx, peer, report),
            #[cfg(feature = "broadcast-time")]
            self.clocks.handle_error_report(cx, peer, report),
        ]
        .contains(&true);
        #[cfg(feature = "traction")]
        let taken = self.trains.handle_error_report(cx, peer, report) | taken;
        taken
    }

    fn peer_changed(&mut self, out: &mut Outputs, change: ServiceChange) {
        self.datagrams.peer_changed(out, change);
        self.snip.peer_changed(out, change);
        self.events.peer_changed(out, change);
        #[cfg(feature = "broadcast-time")]
        self.clocks.peer_changed(out, change);
        #[cfg(feature = "traction")]
        self.trains.peer_changed(out, change);
    }

    fn handle_timeout(&mut self, cx: &mut Lent<'_>) {
        self.datagrams.handle_timeout(cx);
        self.snip.handle_timeout(cx);
        self.events.handle_timeout(cx);
        #[cfg(feature = "broadcast-time")]
        self.clocks.handle_timeout(cx);
        #[cfg(feature = "traction")]
        self.trains.handle_timeout(cx);
    }

    fn poll_timeout(&self) -> Option<Instant> {
        let messaging = earliest(self.datagrams.poll_timeout(), self.snip.poll_timeout());
        let events = self.events.poll_timeout();
        #[cfg(feature = "broadcast-time")]
        let events = earliest(events, self.clocks.poll_timeout());
        #[cfg(feature = "traction")]
        let events = earliest(events, self.trains.poll_timeout());
        earliest(messaging, events)
    }
}

/// The earlier of two deadlines.
pub(crate) fn earliest(a: Option<Instant>, b: Option<Instant>) -> Option<Instant> {
    match (a, b) {
        (Some(a), Some(b)) => Some(a.min(b)),
        (a, b) => a.or(b),
    }
}
