//! The one shape of the node's services (datagrams, SNIP, Memory Configuration, events): the
//! same few entry points, called by [`Node`](crate::Node) with static dispatch, each with what
//! the node lends it for that call.

use openlcb_stream::wire::ErrorReport;
use openlcb_stream::{Instant, MessageRef, NodeId, PeerChange};

use crate::NodeConfig;
use crate::node::Outputs;

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

/// The earlier of two deadlines.
pub(crate) fn earliest(a: Option<Instant>, b: Option<Instant>) -> Option<Instant> {
    match (a, b) {
        (Some(a), Some(b)) => Some(a.min(b)),
        (a, b) => a.or(b),
    }
}
