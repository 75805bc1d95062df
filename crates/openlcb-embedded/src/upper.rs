//! [`Upper`]: what the driver delivers messages to and takes messages from; [`Clock`]: where
//! it reads the time.

use openlcb_node::Node;
use openlcb_stream::{Instant, Message, Receiver, StreamEndpoint};

/// The layer above the CAN link: a [`StreamEndpoint`], or a whole node that routes messages to
/// its protocols. It has the sans-IO shape of the endpoint; the driver calls these in its
/// drive loop and leaves the layer's own events (`poll_event`) to the application.
///
/// As a [`Receiver`] it is handed to the link with every frame and timer: the link gives it
/// each message and, the moment it learns them, the peer changes
/// ([`PeerChange`](openlcb_stream::PeerChange): a peer gone, renamed), so that a rename is
/// applied before the messages sent under the new name.
pub trait Upper: Receiver {
    /// The link lost this node's alias, or left the network after a duplicate Node ID:
    /// everything open ends.
    fn link_lost(&mut self);

    /// The well-known event Duplicate Node ID Detected from this node, if the layer sends
    /// it: when another node announces this node's Node ID, the driver sends it (and, when
    /// this node came second, leaves the network after it).
    fn duplicate_node_id_report(&self) -> Option<Message>;

    /// A deadline from [`poll_timeout`](Upper::poll_timeout) has passed. Early calls must be
    /// harmless.
    fn handle_timeout(&mut self, now: Instant);

    /// The next message to send. The driver takes messages only while the link has room, so
    /// the rest stays queued here.
    fn poll_transmit(&mut self) -> Option<Message>;

    /// When [`handle_timeout`](Upper::handle_timeout) is due next.
    fn poll_timeout(&self) -> Option<Instant>;
}

/// `Upper` for a layer with the endpoint's method names: a [`StreamEndpoint`] (which sends
/// no report of its own), and a [`Node`] (what a firmware should drive: it routes each
/// message to its streams, datagrams, SNIP and Memory Configuration, sends Initialization
/// Complete itself, and reports a duplicate Node ID).
macro_rules! upper_by_name {
    ($($layer:ty => $report:expr),*) => {$(
        impl Upper for $layer {
            fn link_lost(&mut self) {
                <$layer>::link_lost(self);
            }

            fn duplicate_node_id_report(&self) -> Option<Message> {
                let report: fn(&$layer) -> Option<Message> = $report;
                report(self)
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

upper_by_name!(StreamEndpoint => |_| None, Node => |node| Some(node.duplicate_node_id_report()));

impl<T: Upper + ?Sized> Upper for &mut T {
    fn link_lost(&mut self) {
        (**self).link_lost();
    }

    fn duplicate_node_id_report(&self) -> Option<Message> {
        (**self).duplicate_node_id_report()
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
