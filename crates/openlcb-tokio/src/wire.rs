//! The transport under a node: a [`CanLink`] spoken as GridConnect text, or a [`TcpLink`]
//! spoken as OpenLCB-TCP binary. Both turn socket bytes into messages for the node and
//! the node's messages into one growing output buffer that the driver writes in batches.

use std::collections::VecDeque;

use openlcb_can::{CanConfig, CanLink, GridConnectDecoder, LinkEvent, gridconnect};
use openlcb_node::Node;
use openlcb_stream::{Instant, Message, MessageRef, NodeId, PeerChange, PeerChanges, Receiver};
use openlcb_tcp::TcpLink;

use crate::Error;
use crate::node::Join;

/// Which framing a node speaks to its hub.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Framing {
    /// CAN frames as GridConnect text (`:X19CC8123N...;`), the protocol of JMRI and OpenMRN
    /// hubs (port 12021 by convention). The node logs in with a CAN alias.
    GridConnect,
    /// Full-format messages in the binary OpenLCB-TCP framing.
    Tcp,
}

/// Frames and bytes that crossed a node's connection.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
#[non_exhaustive]
pub struct WireStats {
    /// CAN frames (GridConnect) or OpenLCB-TCP messages received.
    pub frames_in: u64,
    /// CAN frames (GridConnect) or OpenLCB-TCP messages sent.
    pub frames_out: u64,
    /// Bytes read from the socket.
    pub bytes_in: u64,
    /// Bytes written to the socket.
    pub bytes_out: u64,
    /// `write` calls that took bytes: one per batch, not one per frame.
    pub writes: u64,
    /// Undecodable input (GridConnect syntax errors, refused OpenLCB-TCP messages).
    pub decode_errors: u64,
}

/// Encoded output beyond this many bytes stops the framing of more messages (and so the
/// taking of more application data) until the socket has taken some.
pub(crate) const HIGH_WATER: usize = 256 * 1024;

/// What the CAN link hands up: the node, and the node's messages the driver holds for the
/// link, which a rename must reach too (they would go to a name the link forgot).
struct Above<'a> {
    node: &'a mut Node,
    waiting: &'a mut VecDeque<Message>,
}

impl PeerChanges for Above<'_> {
    fn peer_changed(&mut self, change: PeerChange) {
        if let PeerChange::Renamed { from, to } = change {
            for message in self.waiting.iter_mut() {
                message.rename_peer(from, to);
            }
        }
        self.node.peer_changed(change);
    }
}

impl Receiver for Above<'_> {
    fn handle_message(&mut self, now: Instant, msg: MessageRef<'_>) {
        crate::trace::memory_step(false, msg.mti, msg.source, msg.destination, msg.payload);
        self.node.handle_message(now, msg);
    }

    fn medium_busy(&mut self, now: Instant) {
        self.node.medium_busy(now);
    }
}

/// Acts on the CAN link's own events. Returns an error the node cannot recover from: a
/// duplicate Node ID found as this node joined (it then leaves the network, the driver
/// flushes its farewell).
fn apply_link_events(
    now: Instant,
    link: &mut CanLink,
    joining: &mut Joining,
    waiting: &mut VecDeque<Message>,
    node: &mut Node,
) -> Result<(), Error> {
    while let Some(event) = link.poll_event() {
        match event {
            LinkEvent::Permitted { .. } => *joining = Joining::Until(now + link.config().newcomer_window),
            LinkEvent::AliasLost { .. } => {
                *joining = Joining::LoggingIn;
                node.link_lost();
            }
            LinkEvent::DuplicateNodeId { other, newcomer: true } => {
                tracing::error!(
                    alias = other.as_raw(),
                    "duplicate Node ID: the node at this alias was here first; leaving"
                );
                waiting.clear();
                link.leave(Some(node.duplicate_node_id_report()));
                node.link_lost();
                return Err(Error::DuplicateNodeId { node: link.node_id() });
            }
            LinkEvent::DuplicateNodeId { other, newcomer: false } => {
                tracing::warn!(
                    alias = other.as_raw(),
                    "duplicate Node ID: another node announced this node's Node ID; reporting it and staying"
                );
                node.report_duplicate_node_id();
            }
            _ => {}
        }
    }
    Ok(())
}

/// How far a CAN node is in joining the network.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Joining {
    /// The alias login runs.
    LoggingIn,
    /// The alias is permitted; a node already holding this Node ID may answer until then.
    Until(Instant),
    /// Joined.
    Joined,
}

/// Logs a message going out if it is a step of Memory Configuration.
fn log_sent(message: &Message) {
    crate::trace::memory_step(true, message.mti, message.source, message.destination, &message.payload);
}

/// Messages handed to the CAN link at once; the rest wait in the driver's own queue (which
/// the streams' credit bounds), so that nothing is ever refused for a full link queue.
const CAN_LINK_QUEUE: usize = 16;

pub(crate) enum Wire {
    GridConnect {
        link: Box<CanLink>,
        decoder: GridConnectDecoder,
        /// Messages from the node not yet handed to the link.
        waiting: VecDeque<Message>,
        /// Encoded text; bytes before `taken` are written.
        out: Vec<u8>,
        taken: usize,
        /// How far the node is in joining the network.
        joining: Joining,
    },
    Tcp {
        link: TcpLink,
    },
}

impl Wire {
    pub(crate) fn new(protocol: Framing, now: Instant, node: NodeId, can: CanConfig) -> Self {
        match protocol {
            Framing::GridConnect => Wire::GridConnect {
                link: Box::new(CanLink::new(now, node, can)),
                decoder: GridConnectDecoder::default(),
                waiting: VecDeque::new(),
                out: Vec::with_capacity(HIGH_WATER + 4096),
                taken: 0,
                joining: Joining::LoggingIn,
            },
            Framing::Tcp => Wire::Tcp { link: TcpLink::new(node) },
        }
    }

    /// The node has joined as `join` asks: its alias is permitted and, unless `join` is
    /// [`Join::AtLogin`], nobody claimed its Node ID within the newcomer window (always true
    /// on OpenLCB-TCP).
    pub(crate) fn is_up(&mut self, now: Instant, join: Join) -> bool {
        match self {
            Wire::GridConnect { joining, .. } => {
                if matches!(*joining, Joining::Until(at) if at <= now) {
                    *joining = Joining::Joined;
                }
                match join {
                    Join::AfterNewcomerWindow => *joining == Joining::Joined,
                    Join::AtLogin => *joining != Joining::LoggingIn,
                }
            }
            Wire::Tcp { .. } => true,
        }
    }

    /// Feeds bytes read from the socket; every message goes to `node`. An `Err` means the
    /// connection must be closed.
    pub(crate) fn receive(
        &mut self,
        now: Instant,
        bytes: &[u8],
        node: &mut Node,
        stats: &mut WireStats,
    ) -> Result<(), Error> {
        stats.bytes_in += bytes.len() as u64;
        match self {
            Wire::GridConnect { link, decoder, joining, waiting, .. } => {
                // Peer changes reach the node (and the waiting messages) inside `handle_frame`.
                let mut above = Above { node, waiting };
                decoder.decode_all(bytes, |decoded| match decoded {
                    Ok(frame) => {
                        stats.frames_in += 1;
                        link.handle_frame(now, &frame, &mut above);
                    }
                    Err(_) => stats.decode_errors += 1,
                });
                apply_link_events(now, link, joining, above.waiting, above.node)
            }
            Wire::Tcp { link } => {
                let mut input = bytes;
                while let Some(decoded) = link.read_message(&mut input) {
                    match decoded {
                        Ok(msg) => {
                            stats.frames_in += 1;
                            crate::trace::memory_step(false, msg.mti, msg.source, msg.destination, msg.payload);
                            node.handle_message(now, msg);
                        }
                        Err(_) => stats.decode_errors += 1,
                    }
                }
                match link.failure() {
                    Some(failure) => Err(Error::Protocol(failure.to_string())),
                    None => Ok(()),
                }
            }
        }
    }

    /// Leaves the network: on CAN the alias is released (AMR) once what is queued is out.
    pub(crate) fn leave(&mut self) {
        if let Wire::GridConnect { link, .. } = self {
            link.leave(None);
        }
    }

    /// Runs the link's timers (a destination never found is lost to `node`).
    pub(crate) fn handle_timeout(&mut self, now: Instant, node: &mut Node) {
        if let Wire::GridConnect { link, waiting, .. } = self {
            link.handle_timeout(now, &mut Above { node, waiting });
        }
    }

    pub(crate) fn poll_timeout(&self) -> Option<Instant> {
        match self {
            Wire::GridConnect { link, joining: Joining::Until(at), .. } => {
                Some(link.poll_timeout().map_or(*at, |next| next.min(*at)))
            }
            Wire::GridConnect { link, .. } => link.poll_timeout(),
            Wire::Tcp { .. } => None,
        }
    }

    /// The link's events, for the node. Returns an error the node cannot recover from.
    pub(crate) fn poll_events(&mut self, now: Instant, node: &mut Node) -> Result<(), Error> {
        let Wire::GridConnect { link, joining, waiting, .. } = self else { return Ok(()) };
        apply_link_events(now, link, joining, waiting, node)
    }

    /// The CAN alias the link knows for `node`, its own included (once logged in).
    pub(crate) fn alias_of(&self, node: NodeId) -> Option<u16> {
        match self {
            Wire::GridConnect { link, .. } if node == link.node_id() => link.alias().map(|alias| alias.as_raw()),
            Wire::GridConnect { link, .. } => link.alias_of(node).map(|alias| alias.as_raw()),
            Wire::Tcp { .. } => None,
        }
    }

    /// There is room to frame more application data.
    pub(crate) fn has_room(&self) -> bool {
        match self {
            Wire::GridConnect { waiting, out, taken, .. } => waiting.is_empty() && out.len() - taken < HIGH_WATER,
            Wire::Tcp { link } => link.transmit_pending().len() < HIGH_WATER,
        }
    }

    /// Moves the node's messages down through the link into the output buffer, as far as
    /// the high-water mark allows.
    pub(crate) fn pump(&mut self, now: Instant, node: &mut Node, stats: &mut WireStats) {
        match self {
            Wire::GridConnect { link, waiting, out, taken, .. } => {
                waiting.extend(std::iter::from_fn(|| node.poll_transmit()).inspect(log_sent));
                while link.queued_messages() < CAN_LINK_QUEUE {
                    let Some(message) = waiting.pop_front() else { break };
                    // A refusal (no CAN form, link stopped) is counted in the link's stats.
                    let _ = link.send(now, message);
                }
                let mut text = [0u8; gridconnect::MAX_ENCODED_LEN];
                while out.len() - *taken < HIGH_WATER {
                    let Some(frame) = link.poll_transmit() else { break };
                    if let Ok(len) = gridconnect::encode(&frame, &mut text) {
                        out.extend_from_slice(text.get(..len).unwrap_or_default());
                        out.push(b'\n');
                        stats.frames_out += 1;
                    }
                    // Refill the link from the driver's queue as it drains.
                    if link.queued_messages() < CAN_LINK_QUEUE
                        && let Some(message) = waiting.pop_front()
                    {
                        let _ = link.send(now, message);
                    }
                }
            }
            Wire::Tcp { link } => {
                let before = link.stats().messages_out;
                // Encoding fails only for messages the core never builds.
                let _ = link.send_from(now, || node.poll_transmit().inspect(log_sent));
                stats.frames_out += link.stats().messages_out - before;
            }
        }
    }

    /// Encoded bytes not yet written.
    pub(crate) fn pending(&self) -> &[u8] {
        match self {
            Wire::GridConnect { out, taken, .. } => out.get(*taken..).unwrap_or_default(),
            Wire::Tcp { link } => link.transmit_pending(),
        }
    }

    /// The socket took `n` bytes of [`pending`](Self::pending), at `now`.
    pub(crate) fn advance(&mut self, n: usize, now: Instant, stats: &mut WireStats) {
        stats.bytes_out += n as u64;
        stats.writes += 1;
        match self {
            Wire::GridConnect { link, out, taken, .. } => {
                *taken = (*taken + n).min(out.len());
                if *taken == out.len() {
                    // Every frame the link handed out is written: the login's reserve wait
                    // counts from here.
                    link.frames_sent(now);
                    out.clear();
                    *taken = 0;
                } else if *taken > HIGH_WATER {
                    out.drain(..*taken);
                    *taken = 0;
                }
            }
            Wire::Tcp { link } => link.advance_transmit(n),
        }
    }

    /// Nothing is queued anywhere below the node.
    pub(crate) fn is_flushed(&self) -> bool {
        match self {
            Wire::GridConnect { link, waiting, out, taken, .. } => {
                waiting.is_empty() && link.queued_messages() == 0 && out.len() == *taken
            }
            Wire::Tcp { link } => link.transmit_pending().is_empty(),
        }
    }
}

#[cfg(test)]
#[allow(clippy::unwrap_used, clippy::panic)] // a test's assertions
mod tests {
    use openlcb_can::NodeAlias;
    use openlcb_node::NodeConfig;
    use openlcb_stream::Mti;

    use super::*;

    fn waiting(wire: &mut Wire) -> &mut VecDeque<Message> {
        let Wire::GridConnect { waiting, .. } = wire else { panic!("a CAN wire") };
        waiting
    }

    #[test]
    fn a_rename_reaches_the_messages_waiting_for_the_link() {
        let me = NodeId::new(0x0501_0101_2200).unwrap();
        let peer = NodeId::new(0x0501_0101_2201).unwrap();
        let provisional = NodeAlias::new(0x456).unwrap().provisional_node_id();
        let mut node = Node::new(me, NodeConfig::default());
        let mut wire = Wire::new(Framing::GridConnect, Instant::ZERO, me, CanConfig::default());
        let held = Message::addressed(Mti::VERIFY_NODE_ID_ADDRESSED, me, provisional, Vec::new());
        waiting(&mut wire).push_back(held);
        // The peer at alias 0x456 announces its Node ID.
        let mut stats = WireStats::default();
        wire.receive(Instant::ZERO, b":X19170456N050101012201;", &mut node, &mut stats).unwrap();
        assert_eq!(waiting(&mut wire).front().and_then(|m| m.destination), Some(peer));
    }
}
