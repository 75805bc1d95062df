//! [`Upper`]: what the driver delivers messages to and takes messages from; [`Clock`]: where
//! it reads the time.

use openlcb_can::LinkEvent;
use openlcb_node::Node;
use openlcb_stream::{Instant, Message, MessageRef, StreamEndpoint};

/// The layer above the CAN link: a [`StreamEndpoint`], or a whole node that routes messages to
/// its protocols. It has the sans-IO shape of the endpoint; the driver calls these in its
/// drive loop and leaves the layer's own events (`poll_event`) to the application.
pub trait Upper {
    /// A message for this node (or a global one) arrived. Its payload borrows the received
    /// frame or the link's reassembly buffer.
    fn handle_message(&mut self, now: Instant, message: MessageRef<'_>);

    /// The link reported something the layer must act on (alias lost, peer gone). The
    /// default ignores it.
    fn handle_link_event(&mut self, now: Instant, event: LinkEvent) {
        let _ = (now, event);
    }

    /// A deadline from [`poll_timeout`](Upper::poll_timeout) has passed. Early calls must be
    /// harmless.
    fn handle_timeout(&mut self, now: Instant);

    /// The next message to send. The driver takes messages only while the link has room, so
    /// the rest stays queued here.
    fn poll_transmit(&mut self) -> Option<Message>;

    /// When [`handle_timeout`](Upper::handle_timeout) is due next.
    fn poll_timeout(&self) -> Option<Instant>;
}

/// `Upper` for a layer with the endpoint's method names: a [`StreamEndpoint`], and a
/// [`Node`] (what a firmware should drive: it routes each message to its streams, datagrams,
/// SNIP and Memory Configuration, and sends Initialization Complete itself).
macro_rules! upper_by_name {
    ($($layer:ty),*) => {$(
        impl Upper for $layer {
            fn handle_message(&mut self, now: Instant, message: MessageRef<'_>) {
                <$layer>::handle_message(self, now, message);
            }

            /// Alias lost, or Node ID taken by a node that was there first: everything open
            /// ends (`link_lost`; the driver has the link leave); a peer
            /// released its alias or could not be found: what is open with it ends
            /// (`peer_lost`); a peer renamed: what is open with it goes on under the new
            /// name (`rename_peer`).
            fn handle_link_event(&mut self, _now: Instant, event: LinkEvent) {
                match event {
                    LinkEvent::AliasLost { .. } | LinkEvent::DuplicateNodeId { newcomer: true, .. } => {
                        self.link_lost()
                    }
                    LinkEvent::PeerLost { node, .. } | LinkEvent::Unreachable { node, .. } => self.peer_lost(node),
                    LinkEvent::PeerRenamed { from, to, .. } => self.rename_peer(from, to),
                    _ => {}
                }
            }

            fn handle_timeout(&mut self, now: Instant) {
                <$layer>::handle_timeout(self, now);
            }

            fn poll_transmit(&mut self) -> Option<Message> {
                <$layer>::poll_transmit(self)
            }

            fn poll_timeout(&self) -> Option<Instant> {
                <$layer>::poll_timeout(self)
            }
        }
    )*};
}

upper_by_name!(StreamEndpoint, Node);

impl<T: Upper + ?Sized> Upper for &mut T {
    fn handle_message(&mut self, now: Instant, message: MessageRef<'_>) {
        (**self).handle_message(now, message);
    }

    fn handle_link_event(&mut self, now: Instant, event: LinkEvent) {
        (**self).handle_link_event(now, event);
    }

    fn handle_timeout(&mut self, now: Instant) {
        (**self).handle_timeout(now);
    }

    fn poll_transmit(&mut self) -> Option<Message> {
        (**self).poll_transmit()
    }

    fn poll_timeout(&self) -> Option<Instant> {
        (**self).poll_timeout()
    }
}

/// The time, as the core counts it (microseconds from an origin the caller picks: boot,
/// usually). A hardware timer, a tick counter kept by an interrupt, or virtual time in tests.
/// Any `FnMut() -> Instant` is a clock.
pub trait Clock {
    /// Now. Must not go backwards.
    fn now(&mut self) -> Instant;
}

impl<F: FnMut() -> Instant> Clock for F {
    fn now(&mut self) -> Instant {
        self()
    }
}
