//! Questions the handles asked other nodes (who is there, SNIP, protocols), waiting in the
//! driver for the node's answers.

use openlcb_node::{NodeEvent, Protocols, SnipFailure, SnipInfo};
use openlcb_stream::NodeId;
use tokio::sync::{mpsc, oneshot};

use crate::Error;

/// Questions waiting at once, of each kind; more are refused with [`Error::Busy`].
const LIMIT: usize = 64;

type SnipReply = oneshot::Sender<Result<SnipInfo, Error>>;
type ProtocolsReply = oneshot::Sender<Result<Protocols, Error>>;

#[derive(Default)]
pub(crate) struct Requests {
    /// Handles listening for Verified Node ID answers.
    verified: Vec<mpsc::Sender<NodeId>>,
    snip: Vec<(NodeId, SnipReply)>,
    protocols: Vec<(NodeId, ProtocolsReply)>,
}

impl Requests {
    pub(crate) fn listen_verified(&mut self, sink: mpsc::Sender<NodeId>) {
        self.verified.retain(|s| !s.is_closed());
        if self.verified.len() < LIMIT {
            self.verified.push(sink);
        }
    }

    /// Records a SNIP question; gives the reply back when there is no room.
    pub(crate) fn ask_snip(&mut self, peer: NodeId, reply: SnipReply) -> Result<(), SnipReply> {
        ask(&mut self.snip, peer, reply)
    }

    /// Records a protocols question; gives the reply back when there is no room.
    pub(crate) fn ask_protocols(&mut self, peer: NodeId, reply: ProtocolsReply) -> Result<(), ProtocolsReply> {
        ask(&mut self.protocols, peer, reply)
    }

    /// Hands a node event to whoever asked for it.
    pub(crate) fn answer(&mut self, event: NodeEvent) {
        match event {
            NodeEvent::Verified { node } => {
                // A listener that is full or gone misses the answer; it is never waited for.
                self.verified.retain(|sink| sink.try_send(node).is_ok() || !sink.is_closed());
            }
            NodeEvent::SnipReceived { peer, info } => {
                for reply in take(&mut self.snip, peer) {
                    let _ = reply.send(Ok(SnipInfo::clone(&info)));
                }
            }
            NodeEvent::SnipFailed { peer, failure } => {
                for reply in take(&mut self.snip, peer) {
                    let _ = reply.send(Err(Error::Snip { peer, failure }));
                }
            }
            NodeEvent::ProtocolsReceived { peer, protocols } => {
                for reply in take(&mut self.protocols, peer) {
                    let _ = reply.send(Ok(protocols));
                }
            }
            _ => {}
        }
    }
}

/// Records a question to `peer` if another fits (questions whose asker gave up are dropped
/// first); gives the reply back when there is no room.
fn ask<T>(
    waiting: &mut Vec<(NodeId, oneshot::Sender<T>)>,
    peer: NodeId,
    reply: oneshot::Sender<T>,
) -> Result<(), oneshot::Sender<T>> {
    waiting.retain(|(_, reply)| !reply.is_closed());
    if waiting.len() >= LIMIT {
        return Err(reply);
    }
    waiting.push((peer, reply));
    Ok(())
}

/// Removes and returns the replies waiting for `peer`.
fn take<T>(waiting: &mut Vec<(NodeId, T)>, peer: NodeId) -> Vec<T> {
    let mut taken = Vec::new();
    let mut index = 0;
    while index < waiting.len() {
        if waiting.get(index).is_some_and(|(p, _)| *p == peer) {
            taken.push(waiting.swap_remove(index).1);
        } else {
            index += 1;
        }
    }
    taken
}

/// A SNIP failure worded for a person.
pub(crate) fn snip_failure_text(peer: NodeId, failure: SnipFailure) -> String {
    match failure {
        SnipFailure::TimedOut => format!("node {peer} did not answer the SNIP request in time"),
        SnipFailure::Rejected(code) => format!("node {peer} refused the SNIP request: {code} ({})", code.meaning()),
        SnipFailure::PeerLost => format!("node {peer} left the network before answering the SNIP request"),
        _ => format!("the SNIP request to node {peer} failed"),
    }
}
