//! Full-format messages: [`MessageRef`] borrowed on the way in, [`Message`] owned on the way out.

use alloc::vec::Vec;

use crate::{Mti, NodeId};

/// A received message, borrowing its payload from the transport's buffer.
///
/// For MTIs with the event bit the Event ID is the first 8 bytes of `payload`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct MessageRef<'a> {
    /// The message type.
    pub mti: Mti,
    /// The sending node.
    pub source: NodeId,
    /// The addressed node, for MTIs with the address bit (`None` for global messages).
    pub destination: Option<NodeId>,
    /// The data after the MTI and Node IDs.
    pub payload: &'a [u8],
}

/// A message to send, owning its payload: one allocation, built once and moved (never
/// copied) by the core and the transports until it is framed. Its fields are laid out in the
/// order written (`repr(C)`), what every layer reads first at the front.
#[derive(Debug, Clone, PartialEq, Eq)]
#[repr(C)]
pub struct Message {
    /// The message type.
    pub mti: Mti,
    /// The data after the MTI and Node IDs.
    pub payload: Vec<u8>,
    /// The sending node.
    pub source: NodeId,
    /// The addressed node, for MTIs with the address bit (`None` for global messages).
    pub destination: Option<NodeId>,
}

impl Message {
    /// A global (unaddressed) message.
    pub fn global(mti: Mti, source: NodeId, payload: impl Into<Vec<u8>>) -> Self {
        Message { mti, source, destination: None, payload: payload.into() }
    }

    /// An addressed message.
    pub fn addressed(mti: Mti, source: NodeId, destination: NodeId, payload: impl Into<Vec<u8>>) -> Self {
        Message { mti, source, destination: Some(destination), payload: payload.into() }
    }

    /// Initialization Complete for `node` (MN §3.3.1): the first message a node sends.
    pub fn initialization_complete(node: NodeId) -> Self {
        Message::global(Mti::INITIALIZATION_COMPLETE, node, node.to_bytes().to_vec())
    }

    /// Verified Node ID for `node` (MN §3.3.2): the answer to Verify Node ID.
    pub fn verified_node_id(node: NodeId) -> Self {
        Message::global(Mti::VERIFIED_NODE_ID, node, node.to_bytes().to_vec())
    }

    /// The transport now names the peer `from` as `to` (see `PeerChange::Renamed`): a
    /// message queued for `from` goes to `to`.
    pub fn rename_peer(&mut self, from: NodeId, to: NodeId) {
        if self.destination == Some(from) {
            self.destination = Some(to);
        }
    }

    /// A view of this message as if it had just been received.
    pub fn as_ref(&self) -> MessageRef<'_> {
        MessageRef { mti: self.mti, source: self.source, destination: self.destination, payload: &self.payload }
    }
}

impl MessageRef<'_> {
    /// An owned copy (copies the payload).
    pub fn to_message(&self) -> Message {
        Message { mti: self.mti, source: self.source, destination: self.destination, payload: self.payload.to_vec() }
    }
}
