//! [`PeerChange::Renamed`](crate::PeerChange::Renamed): the transport changed the name it
//! gives a peer.

use super::StreamEndpoint;
use crate::NodeId;
use crate::event::{Event, Role, Termination};

impl StreamEndpoint {
    /// The transport now calls the peer `from` by the name `to`: every stream whose peer is
    /// `from` has peer `to` from now on, so that messages from `to` find it and its messages
    /// go to `to`. On CAN: a Node ID learnt for an alias known only by its provisional name,
    /// or forgotten again (cache eviction, global AME); the link applies it before the next
    /// message is delivered.
    ///
    /// If `to` already has a stream with the same role and local stream ID (the SID this node
    /// assigned as source, the DID as destination), the two cannot share the index: the one
    /// under `from` ends with [`Termination::Superseded`] and the one under `to`, which the
    /// peer reached under its new name, stays. (A superseded destination with unread data
    /// stays readable under `from` until it is read, like any closed stream.)
    ///
    /// Queued messages addressed to `from` are addressed to `to`. Renaming a peer to itself,
    /// or a peer without streams or queued messages, does nothing. Sends nothing.
    pub(super) fn rename_peer(&mut self, from: NodeId, to: NodeId) {
        if from == to {
            return;
        }
        // Messages already queued for the old name go to the new one too: the transport may
        // no longer know the old name by the time they leave.
        for message in self.out.transmits.iter_mut() {
            message.rename_peer(from, to);
        }
        // Role by role (sources first), each in slot order.
        for role in [Role::Source, Role::Destination] {
            for slot in 0..self.slots.len() {
                let Some(stream) = self.slots.get(slot).filter(|s| s.is_with(from, role)) else { continue };
                let Some(id) = stream.local_id() else { continue };
                if self.position(to, role, id).is_some() {
                    if let Some(handle) = self.find(from, role, id) {
                        self.end(Event::Terminated { handle, cause: Termination::Superseded });
                    }
                } else if let Some(stream) = self.slots.get_mut(slot) {
                    stream.peer = to;
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use alloc::vec;
    use alloc::vec::Vec;

    use crate::event::{Event, Role, Termination};
    use crate::wire::{DataSend, Emit, InitiateReply, InitiateRequest, ReplyCode};
    use crate::{Config, Instant, Message, MessageRef, Mti, NodeId, OpenOptions, StreamEndpoint, StreamId};

    const LOCAL: u64 = 0x0501_0101_2200;
    /// The provisional name of alias 0x031 on CAN.
    const PROVISIONAL: u64 = 0x0000_0000_0031;
    const REAL: u64 = 0x0501_0101_2231;
    const T0: Instant = Instant::ZERO;

    fn id(raw: u64) -> NodeId {
        NodeId::new(raw).unwrap()
    }

    fn sid(raw: u8) -> StreamId {
        StreamId::new(raw).unwrap()
    }

    fn endpoint() -> StreamEndpoint {
        StreamEndpoint::new(id(LOCAL), Config::default())
    }

    fn feed(endpoint: &mut StreamEndpoint, mti: Mti, from: u64, body: &impl Emit) {
        let payload = body.to_bytes();
        endpoint
            .handle_message(T0, MessageRef { mti, source: id(from), destination: Some(id(LOCAL)), payload: &payload });
    }

    /// A request from `from` with SID `did + 1` proposing DID `did`, accepted by the policy.
    fn request_from(endpoint: &mut StreamEndpoint, from: u64, did: u8) {
        let request = InitiateRequest {
            max_buffer_size: 64,
            source_stream: sid(did + 1),
            proposed_destination: Some(sid(did)),
            content_uid: None,
        };
        feed(endpoint, Mti::STREAM_INITIATE_REQUEST, from, &request);
    }

    /// An endpoint with one open destination stream from `REAL`, DID 7, its outputs drained.
    fn open_from_real() -> StreamEndpoint {
        let mut e = endpoint();
        request_from(&mut e, REAL, 7);
        drain(&mut e);
        e
    }

    fn data_from(endpoint: &mut StreamEndpoint, from: u64, did: u8, bytes: &[u8]) {
        let data = DataSend { destination_stream: sid(did), data: bytes };
        feed(endpoint, Mti::STREAM_DATA_SEND, from, &data);
    }

    fn drain(endpoint: &mut StreamEndpoint) -> (Vec<Message>, Vec<Event>) {
        (
            core::iter::from_fn(|| endpoint.poll_transmit()).collect(),
            core::iter::from_fn(|| endpoint.poll_event()).collect(),
        )
    }

    fn buffered(endpoint: &StreamEndpoint) -> Vec<usize> {
        endpoint.handles().filter_map(|h| endpoint.buffered(h)).collect()
    }

    fn peers(endpoint: &StreamEndpoint) -> Vec<(NodeId, Role)> {
        endpoint.handles().filter_map(|h| endpoint.stream_info(h)).map(|i| (i.peer, i.role)).collect()
    }

    #[test]
    fn destination_stream_follows_the_new_name() {
        let mut e = endpoint();
        request_from(&mut e, PROVISIONAL, 7);
        let (sent, _) = drain(&mut e);
        assert_eq!(sent[0].destination, Some(id(PROVISIONAL)), "the Reply goes to the provisional name");
        e.rename_peer(id(PROVISIONAL), id(REAL));
        assert_eq!(peers(&e), [(id(REAL), Role::Destination)]);
        // Data under the new name reaches the stream; under the old one it does not.
        data_from(&mut e, REAL, 7, &[1, 2, 3]);
        data_from(&mut e, PROVISIONAL, 7, &[9]);
        let handle = e.handles().next().unwrap();
        assert_eq!(e.buffered(handle), Some(3));
        assert_eq!(e.stats().unknown_stream_data, 1);
        let mut buf = [0u8; 8];
        assert_eq!(e.read(T0, handle, &mut buf), Ok(3));
        assert_eq!(buf[..3], [1, 2, 3]);
    }

    #[test]
    fn source_stream_follows_the_new_name_and_sends_to_it() {
        let mut e = endpoint();
        let handle = e.open(T0, OpenOptions::new(id(PROVISIONAL), 32)).unwrap();
        drain(&mut e);
        e.rename_peer(id(PROVISIONAL), id(REAL));
        let local_sid = e.stream_info(handle).unwrap().source_stream;
        let reply = InitiateReply {
            max_buffer_size: 32,
            code: ReplyCode::ACCEPT,
            source_stream: local_sid,
            destination_stream: Some(sid(9)),
        };
        feed(&mut e, Mti::STREAM_INITIATE_REPLY, REAL, &reply);
        let (_, events) = drain(&mut e);
        assert!(matches!(events.as_slice(), [Event::Opened { info, .. }] if info.peer == id(REAL)), "{events:?}");
        assert_eq!(e.write(T0, handle, &[5; 4]), Ok(4));
        let (sent, _) = drain(&mut e);
        assert_eq!(sent.len(), 1);
        assert_eq!((sent[0].mti, sent[0].destination), (Mti::STREAM_DATA_SEND, Some(id(REAL))));
    }

    #[test]
    fn clash_with_a_stream_under_the_new_name_supersedes_the_old_one() {
        let mut e = endpoint();
        request_from(&mut e, PROVISIONAL, 7);
        request_from(&mut e, REAL, 7);
        request_from(&mut e, PROVISIONAL, 8);
        drain(&mut e);
        let old = e.handles().next().unwrap();
        e.rename_peer(id(PROVISIONAL), id(REAL));
        let (sent, events) = drain(&mut e);
        assert!(sent.is_empty(), "a rename sends nothing");
        assert_eq!(events, vec![Event::Terminated { handle: old, cause: Termination::Superseded }]);
        assert_eq!(peers(&e), [(id(REAL), Role::Destination), (id(REAL), Role::Destination)]);
        assert_eq!(e.stream_count(), 2);
        // Both DIDs now answer under the new name.
        data_from(&mut e, REAL, 7, &[1]);
        data_from(&mut e, REAL, 8, &[2, 2]);
        assert_eq!(buffered(&e), [1, 2]);
    }

    #[test]
    fn renaming_to_itself_or_without_streams_does_nothing() {
        let mut e = open_from_real();
        e.rename_peer(id(REAL), id(REAL));
        e.rename_peer(id(PROVISIONAL), id(0x0501_0101_2299));
        assert_eq!(peers(&e), [(id(REAL), Role::Destination)]);
        assert_eq!(drain(&mut e), (vec![], vec![]));
    }

    #[test]
    fn renaming_back_restores_the_old_name() {
        let mut e = open_from_real();
        // Evicted from the link's cache, then learnt again.
        e.rename_peer(id(REAL), id(PROVISIONAL));
        assert_eq!(peers(&e), [(id(PROVISIONAL), Role::Destination)]);
        e.rename_peer(id(PROVISIONAL), id(REAL));
        data_from(&mut e, REAL, 7, &[1, 2]);
        assert_eq!(buffered(&e), [2]);
    }
}
