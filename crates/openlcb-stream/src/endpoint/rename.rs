//! Renaming a peer: the transport names it differently from now on.

use alloc::vec::Vec;

use super::{StreamEndpoint, StreamHandle};
use crate::{Event, NodeId, Termination};

impl StreamEndpoint {
    /// The transport names `from` as `to` from now on (on CAN: its Node ID was learnt, or its
    /// alias mapping forgotten): every stream with `from` goes on with `to`. A stream under
    /// `from` whose role and stream ID `to` already uses ends as
    /// [`Termination::Superseded`]: the two names were one node, and its newer stream wins.
    pub fn rename_peer(&mut self, from: NodeId, to: NodeId) {
        if from == to {
            return;
        }
        let moved: Vec<StreamHandle> =
            self.handles().filter(|h| self.stream(*h).is_some_and(|s| s.peer == from)).collect();
        for handle in moved {
            let Some((role, Some(id))) = self.stream(handle).map(|s| (s.role(), s.local_id())) else { continue };
            let key = (from, role, id);
            if self.index.contains_key(&(to, role, id)) {
                self.end(handle, |h| Event::Terminated { handle: h, cause: Termination::Superseded });
                continue;
            }
            let Some(slot) = self.index.remove(&key) else { continue };
            self.index.insert((to, role, id), slot);
            if let Some(stream) = self.slots.get_mut(usize::from(slot)).and_then(|s| s.stream.as_mut()) {
                stream.peer = to;
            }
        }
    }
}
