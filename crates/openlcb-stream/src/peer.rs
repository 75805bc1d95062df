//! [`PeerChange`]: what a transport learns about a peer; [`PeerChanges`] and [`Receiver`]: the
//! layer above a transport, which the transport is handed with each input.
//!
//! A transport that names peers by something other than their Node ID (CAN aliases) learns
//! that a peer left or has a new name while it handles a frame or a timer. It tells the layer
//! above at once, through the `&mut impl Receiver` it was handed with that input (as rustls
//! hands its state machine the sink it writes into), so the change is applied before the
//! next message is delivered. No driver has to remember to drain a queue between two frames.

use crate::{Instant, MessageRef, NodeId};

/// A change of peer that a transport learnt, for the layer above to apply at once.
///
/// There is no "restarted": a restart is a message (Initialization Complete), which the
/// layer above receives in order and acts on itself.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
#[non_exhaustive]
pub enum PeerChange {
    /// The transport can no longer reach this peer (on CAN: it released its alias with AMR,
    /// its alias now belongs to another Node ID, or no alias was found for it within the
    /// resolve timeout). The layer above ends everything open with it (its streams end with
    /// [`Termination::PeerLost`](crate::Termination::PeerLost), requests to it fail) without
    /// sending anything to it.
    Lost(NodeId),
    /// The transport names the peer `from` as `to` from now on: messages from it carry `to`
    /// as their source, and messages to `to` reach it (on CAN: a Node ID was learnt for an
    /// alias known by its provisional name, or forgotten again on a cache eviction or a
    /// global AME). The layer above moves everything keyed by `from` to `to` (streams,
    /// queued messages, requests waiting for an answer), so that the next message from the
    /// peer finds it. Nothing is sent.
    Renamed {
        /// The name used until now.
        from: NodeId,
        /// The name used from now on.
        to: NodeId,
    },
}

/// What takes the [`PeerChange`]s a transport learns: the layer above it (a
/// [`StreamEndpoint`](crate::StreamEndpoint), a node), or a driver's wrapper that also moves
/// the messages it holds.
pub trait PeerChanges {
    /// Applies `change` now: the transport calls this the moment it learns it, before it
    /// delivers any later message.
    fn peer_changed(&mut self, change: PeerChange);
}

/// The layer above a transport: it receives the messages, and the peer changes, in the order
/// the transport learns them.
pub trait Receiver: PeerChanges {
    /// A message for this node (or a global one) arrived. Its payload borrows the transport's
    /// buffer.
    fn handle_message(&mut self, now: Instant, message: MessageRef<'_>);

    /// The transport saw another node's stream data go by on a shared medium (on CAN: a
    /// stream data frame, to this node or another) at `now`: the medium is busy with streams,
    /// so a peer may be waiting for its turn rather than silent (see
    /// [`StreamEndpoint::medium_busy`](crate::StreamEndpoint::medium_busy)). A wrapper
    /// passes it on to what it wraps: it has no default, so that none drops it unawares.
    fn medium_busy(&mut self, now: Instant);
}

impl<T: PeerChanges + ?Sized> PeerChanges for &mut T {
    fn peer_changed(&mut self, change: PeerChange) {
        (**self).peer_changed(change);
    }
}

impl<T: Receiver + ?Sized> Receiver for &mut T {
    fn handle_message(&mut self, now: Instant, message: MessageRef<'_>) {
        (**self).handle_message(now, message);
    }

    fn medium_busy(&mut self, now: Instant) {
        (**self).medium_busy(now);
    }
}
