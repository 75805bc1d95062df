//! The message-network basics a node needs to be found and to interoperate: Verify Node ID,
//! Protocol Support Inquiry, and OIR for addressed messages nobody here handles.

use bytes::Bytes;

use crate::config::Config;
use crate::wire::{Emit, ErrorCode, ErrorReport};
use crate::{Message, MessageRef, Mti, NodeId};

/// The Stream protocol bit of the Protocol Support Reply (MN §3.3.7).
pub const PROTOCOL_STREAM: u64 = 0x2000_0000_0000;

/// Initialization Complete for `node` (MN §3.3.1): the first message a node sends.
pub fn initialization_complete(node: NodeId) -> Message {
    Message::global(Mti::INITIALIZATION_COMPLETE, node, Bytes::copy_from_slice(&node.to_bytes()))
}

/// Verified Node ID for `node`.
pub fn verified_node_id(node: NodeId) -> Message {
    Message::global(Mti::VERIFIED_NODE_ID, node, Bytes::copy_from_slice(&node.to_bytes()))
}

/// The answer of node `local` to `msg`, a message already known to be global or addressed to
/// `local`, if it calls for one:
/// - Verify Node ID, global (with no Node ID or with `local`'s) or addressed: Verified Node ID;
/// - Protocol Support Inquiry: Protocol Support Reply with the Stream bit (6 bytes);
/// - any other addressed MTI, unless it is itself an OIR or TDE or a reply no one here asked
///   for: OIR 0x1043 quoting the MTI (when [`Config::reject_unknown_mti`]).
pub fn answer(local: NodeId, config: &Config, msg: MessageRef<'_>) -> Option<Message> {
    match msg.mti {
        Mti::VERIFY_NODE_ID_GLOBAL => {
            let asks_for_us = msg.payload.len() < 6 || NodeId::from_slice(msg.payload) == Some(local);
            asks_for_us.then(|| verified_node_id(local))
        }
        Mti::VERIFY_NODE_ID_ADDRESSED => Some(verified_node_id(local)),
        Mti::PROTOCOL_SUPPORT_INQUIRY => {
            let flags = (PROTOCOL_STREAM | config.extra_protocols) & NodeId::MAX.as_raw();
            let bytes = NodeId::new(flags).unwrap_or_default().to_bytes();
            Some(Message::addressed(Mti::PROTOCOL_SUPPORT_REPLY, local, msg.source, Bytes::copy_from_slice(&bytes)))
        }
        mti if mti.is_addressed() && config.reject_unknown_mti && !is_unsolicited_answer(mti) => {
            let oir = ErrorReport { code: ErrorCode::NOT_IMPLEMENTED_MTI, mti: Some(mti) };
            Some(Message::addressed(Mti::OPTIONAL_INTERACTION_REJECTED, local, msg.source, oir.to_bytes()))
        }
        _ => None,
    }
}

/// Messages that answer something: rejecting them would start a loop of rejections.
fn is_unsolicited_answer(mti: Mti) -> bool {
    matches!(
        mti,
        Mti::OPTIONAL_INTERACTION_REJECTED
            | Mti::TERMINATE_DUE_TO_ERROR
            | Mti::PROTOCOL_SUPPORT_REPLY
            | Mti::DATAGRAM_RECEIVED_OK
            | Mti::DATAGRAM_REJECTED
    )
}
