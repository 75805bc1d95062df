//! What the examples of this crate share.

use openlcb_node::Node;
use openlcb_stream::Instant;

/// Delivers everything each node has to send to the other, straight from one's
/// `poll_transmit` into the other's `handle_message`, until both are quiet; says whether any
/// message crossed.
pub(crate) fn pump(now: Instant, a: &mut Node, b: &mut Node) -> bool {
    let mut crossed = false;
    loop {
        let mut moved = false;
        while let Some(msg) = a.poll_transmit() {
            b.handle_message(now, msg.as_ref());
            moved = true;
        }
        while let Some(msg) = b.poll_transmit() {
            a.handle_message(now, msg.as_ref());
            moved = true;
        }
        if !moved {
            return crossed;
        }
        crossed = true;
    }
}
