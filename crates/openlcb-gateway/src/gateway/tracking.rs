//! Stream tracking (wire-spec §6.5): merging CAN data into Data Sends, window accounting,
//! delayed Proceeds and Completes, flushes, TDE.

use openlcb_stream::wire::{
    DataComplete, DataProceed, DataSend, Emit, ErrorCode, ErrorReport, InitiateReply, InitiateRequest,
};
use openlcb_stream::{Instant, Message, Mti, NodeId, StreamId};

use super::{CanBound, Gateway, bump, other};
use crate::stream::{COMPLETE_MAX_LEN, HeldComplete, Phase, Tracked};
use crate::{GatewayEvent, Side, StreamEnd, StreamKey};

impl Gateway {
    /// Appends CAN stream data to a tracked stream's merge buffer, forwarding it at each
    /// window boundary (and the stream's first frame, and for a destination that sends
    /// Proceeds ahead the first frame of each window, at once); a DID-only frame (a flush)
    /// forwards the buffer and then the flush.
    pub(super) fn merge_can_data(&mut self, now: Instant, index: usize, mut body: &[u8]) {
        let Some(stream) = self.streams.get_mut(index) else { return };
        stream.last_activity = now;
        if body.is_empty() {
            self.flush_merge(index);
            self.pass_flush(index);
            self.settle(now, index);
            return;
        }
        bump(&mut self.stats.data_frames_merged);
        while !body.is_empty() {
            let Some(stream) = self.streams.get_mut(index) else { return };
            let room = stream.bound().saturating_sub(stream.buffered());
            let to_boundary = usize::try_from(stream.to_window_boundary()).unwrap_or(usize::MAX);
            let n = body.len().min(to_boundary).min(room.max(1));
            let (chunk, rest) = body.split_at(n.min(body.len()));
            if stream.merge.is_empty() {
                stream.merge.push(stream.destination_stream().map_or(StreamId::RESERVED, StreamId::as_raw));
                stream.merge_deadline = Some(now + self.config.merge_delay);
            }
            // For a destination that sends Proceeds ahead, the first frame of a window goes at
            // once, so that its Proceed can come back while the rest of the window is still
            // on the bus (draft §7.3). The stream's very first frame goes at once too: it is
            // how such a destination shows itself.
            let early_start =
                (stream.destination_proceeds_early || stream.received == 0) && stream.received % stream.window() == 0;
            stream.merge.extend_from_slice(chunk);
            stream.received = stream.received.saturating_add(chunk.len() as u64);
            if early_start || stream.received % stream.window() == 0 || stream.buffered() >= stream.bound() {
                self.flush_merge(index);
            }
            body = rest;
        }
        self.settle(now, index);
    }

    /// Forwards a tracked CAN stream's merge buffer as one Data Send.
    pub(super) fn flush_merge(&mut self, index: usize) {
        let Some(stream) = self.streams.get_mut(index) else { return };
        stream.merge_deadline = None;
        if stream.merge.len() <= 1 {
            stream.merge.clear();
            return;
        }
        let payload = core::mem::take(&mut stream.merge);
        let message = Message::addressed(Mti::STREAM_DATA_SEND, stream.key.source, stream.key.destination, payload);
        bump(&mut self.stats.merged_messages);
        self.emit_full(message);
    }

    // ----- full-format side in -----

    /// A full-format Data Send: tracked data is counted against its stream's window and
    /// queued for CAN; a flush waits for the stream's buffer to drain.
    pub(super) fn full_data_send(&mut self, now: Instant, message: Message) {
        let tracked = DataSend::parse(&message.payload).ok().and_then(|data| {
            message.destination.and_then(|destination| {
                self.find_open(message.source, destination, data.destination_stream, Side::Full)
            })
        });
        let len = message.payload.len().saturating_sub(1);
        let Some(index) = tracked else {
            if len > 0 {
                if self.untracked_backlog.saturating_add(len) > self.config.max_untracked_backlog {
                    return bump(&mut self.stats.untracked_data_dropped);
                }
                self.untracked_backlog += len;
                return self.route_to_can(now, CanBound { message, data_of: Some(None) });
            }
            return self.route_to_can(now, CanBound::control(message));
        };
        let Some(stream) = self.streams.get_mut(index) else { return };
        stream.last_activity = now;
        if len == 0 {
            stream.flush_pending = true;
            self.settle(now, index);
            return;
        }
        if stream.buffered().saturating_add(len) > stream.bound() {
            return self.overrun(now, index);
        }
        stream.queued += len;
        stream.received = stream.received.saturating_add(len as u64);
        let key = stream.key;
        self.route_to_can(now, CanBound { message, data_of: Some(Some(key)) });
    }

    // ----- both sides: stream tracking -----

    /// Handles a message that crosses from `from` to the other side: stream messages update
    /// the tracking (and may be held), everything else goes straight on.
    pub(super) fn forward(&mut self, now: Instant, from: Side, message: Message) {
        let mut message = message;
        match message.mti {
            Mti::STREAM_INITIATE_REQUEST => message = self.on_request(now, from, message),
            Mti::STREAM_INITIATE_REPLY => self.on_reply(now, from, &message),
            Mti::STREAM_DATA_SEND => return self.full_data_send(now, message),
            Mti::STREAM_DATA_PROCEED if self.hold_proceed(now, from, &message) => return,
            Mti::STREAM_DATA_COMPLETE if self.hold_complete(now, from, &message) => return,
            Mti::TERMINATE_DUE_TO_ERROR | Mti::OPTIONAL_INTERACTION_REJECTED => self.on_error_report(&message),
            Mti::INITIALIZATION_COMPLETE | Mti::INITIALIZATION_COMPLETE_SIMPLE => {
                self.end_streams_of(message.source, StreamEnd::NodeGone);
            }
            _ => {}
        }
        self.send_toward(now, other(from), message);
    }

    /// Tracks the stream of a Request and lowers its Max Buffer Size to `max_window`.
    pub(super) fn on_request(&mut self, now: Instant, from: Side, mut message: Message) -> Message {
        let (Ok(request), Some(destination)) = (InitiateRequest::parse(&message.payload), message.destination) else {
            return message;
        };
        let proposed = request.max_buffer_size.min(self.config.max_window.max(1));
        if proposed < request.max_buffer_size {
            bump(&mut self.stats.windows_lowered);
            // Only bytes 0-1 change, in place: flags, IDs, UID and anything after stay as sent.
            if let Some(size) = message.payload.get_mut(..2) {
                size.copy_from_slice(&proposed.to_be_bytes());
            }
        }
        let key = StreamKey { source: message.source, destination, source_stream: request.source_stream };
        if let Some(index) = self.streams.iter().position(|s| s.key == key) {
            self.end_stream(index, StreamEnd::Superseded);
        }
        if self.streams.len() < self.config.max_streams {
            self.streams.push(Tracked::requested(now, key, from, proposed));
        } else {
            bump(&mut self.stats.untracked_streams);
        }
        message
    }

    /// Opens (or forgets, on a reject) the stream a Reply answers. The Reply is never changed.
    pub(super) fn on_reply(&mut self, now: Instant, from: Side, message: &Message) {
        let (Ok(reply), Some(source)) = (InitiateReply::parse(&message.payload), message.destination) else {
            return;
        };
        let key = StreamKey { source, destination: message.source, source_stream: reply.source_stream };
        let Some(index) = self.streams.iter().position(|s| s.key == key && s.source_side == other(from)) else {
            return;
        };
        let Some(stream) = self.streams.get_mut(index) else { return };
        let Phase::Requested { proposed } = stream.phase else { return };
        match reply.destination_stream.filter(|_| reply.is_accepted()) {
            Some(destination_stream) => {
                let window = reply.max_buffer_size;
                stream.phase = Phase::Open { destination_stream, window, bound: window.min(proposed) };
                stream.last_activity = now;
                let event = GatewayEvent::StreamOpened { stream: key, source_side: stream.source_side, window };
                self.event(event);
            }
            None => self.end_stream(index, StreamEnd::Rejected),
        }
    }

    /// Holds a Proceed for a tracked stream until its buffer has drained and the source has
    /// used the credit it holds. Returns true if held (it is released later, never dropped).
    pub(super) fn hold_proceed(&mut self, now: Instant, from: Side, message: &Message) -> bool {
        let (Ok(proceed), Some(source)) = (DataProceed::parse(&message.payload), message.destination) else {
            return false;
        };
        let key = StreamKey { source, destination: message.source, source_stream: proceed.source_stream };
        let Some(stream) = self.streams.iter_mut().find(|s| {
            s.key == key && s.source_side == other(from) && s.destination_stream() == Some(proceed.destination_stream)
        }) else {
            return false;
        };
        stream.last_activity = now;
        stream.proceed_seen();
        if stream.proceeds_held == 0 && stream.proceed_releasable() {
            stream.proceeds_released = stream.proceeds_released.saturating_add(1);
            return false;
        }
        stream.proceeds_held = stream.proceeds_held.saturating_add(1);
        bump(&mut self.stats.proceeds_delayed);
        true
    }

    /// Holds a Complete for a tracked stream until its buffer has drained (and, from CAN,
    /// until the data it counts has arrived). Returns true if held.
    pub(super) fn hold_complete(&mut self, now: Instant, from: Side, message: &Message) -> bool {
        let (Ok(complete), Some(destination)) = (DataComplete::parse(&message.payload), message.destination) else {
            return false;
        };
        let key = StreamKey { source: message.source, destination, source_stream: complete.source_stream };
        let Some(index) = self.streams.iter().position(|s| {
            s.key == key && s.source_side == from && s.destination_stream() == Some(complete.destination_stream)
        }) else {
            return false;
        };
        let Some(stream) = self.streams.get_mut(index) else { return false };
        stream.last_activity = now;
        let kept = message.payload.len().min(COMPLETE_MAX_LEN);
        stream.complete = Some(HeldComplete {
            payload: message.payload.get(..kept).unwrap_or_default().to_vec(),
            count: complete.count,
            deadline: now + self.config.complete_wait,
        });
        if !self.settle(now, index) {
            bump(&mut self.stats.completes_delayed);
        }
        true
    }

    /// TDE ends the matching streams at once, dropping their data and delayed messages (draft
    /// §7.5); so does an OIR naming a stream MTI. The TDE does not say which stream: every
    /// stream between the pair in the roles its MTI names is ended (wire-spec Q5).
    pub(super) fn on_error_report(&mut self, message: &Message) {
        let Some(receiver) = message.destination else { return };
        let sender = message.source;
        let report = ErrorReport::parse(&message.payload);
        let (sender_is_source, sender_is_destination) = match report.mti {
            Some(Mti::STREAM_DATA_SEND) | Some(Mti::STREAM_INITIATE_REQUEST) => (false, true),
            Some(Mti::STREAM_DATA_PROCEED) | Some(Mti::STREAM_INITIATE_REPLY) => (true, false),
            Some(mti) if mti.is_stream() => (true, true),
            None if message.mti == Mti::TERMINATE_DUE_TO_ERROR => (true, true),
            _ => return,
        };
        let cause =
            if message.mti == Mti::OPTIONAL_INTERACTION_REJECTED || report.mti == Some(Mti::STREAM_INITIATE_REQUEST) {
                StreamEnd::Rejected
            } else {
                StreamEnd::Terminated
            };
        let mut index = 0;
        while let Some(stream) = self.streams.get(index) {
            let k = stream.key;
            let matches = (sender_is_source && k.source == sender && k.destination == receiver)
                || (sender_is_destination && k.source == receiver && k.destination == sender);
            if matches {
                self.end_stream(index, cause);
            } else {
                index += 1;
            }
        }
    }

    /// The source overran its window and the buffer is full: both ends get TDE 0x2040 and
    /// the stream's data is dropped.
    pub(super) fn overrun(&mut self, now: Instant, index: usize) {
        let Some(stream) = self.streams.get(index) else { return };
        let (key, source_side) = (stream.key, stream.source_side);
        bump(&mut self.stats.overruns);
        self.end_stream(index, StreamEnd::Overrun);
        let code = ErrorCode::OUT_OF_ORDER;
        // As the destination towards the source (MTI 0x1F88), as the source towards the
        // destination (MTI 0x0888), draft §7.4.
        let to_source = ErrorReport { code, mti: Some(Mti::STREAM_DATA_SEND) };
        let to_destination = ErrorReport { code, mti: Some(Mti::STREAM_DATA_PROCEED) };
        let tde = Mti::TERMINATE_DUE_TO_ERROR;
        self.send_toward(now, source_side, Message::addressed(tde, key.destination, key.source, to_source.to_bytes()));
        let to_dest = Message::addressed(tde, key.source, key.destination, to_destination.to_bytes());
        self.send_toward(now, other(source_side), to_dest);
    }

    /// Releases what waited for the stream's buffer to drain: a flush, Proceeds, and the
    /// Complete (after which the stream is forgotten). Returns true if the stream ended (its
    /// index now names the next stream).
    pub(super) fn settle(&mut self, now: Instant, index: usize) -> bool {
        let Some(stream) = self.streams.get(index) else { return false };
        if stream.buffered() == 0 && stream.flush_pending {
            self.pass_flush(index);
        }
        while self.streams.get(index).is_some_and(|s| s.proceeds_held > 0 && s.proceed_releasable()) {
            self.release_proceed(now, index);
        }
        let Some(stream) = self.streams.get(index) else { return false };
        if stream.complete.is_none() || stream.awaits_overtaken_data(now) {
            return false;
        }
        if stream.source_side == Side::Can {
            self.flush_merge(index);
        }
        let Some(stream) = self.streams.get(index) else { return false };
        if stream.buffered() > 0 {
            return false;
        }
        // The stream is over: Proceeds still held go to the source (harmless, never dropped),
        // then the Complete to the destination.
        while self.streams.get(index).is_some_and(|s| s.proceeds_held > 0) {
            self.release_proceed(now, index);
        }
        let Some(stream) = self.streams.get_mut(index) else { return false };
        let (key, source_side) = (stream.key, stream.source_side);
        if let Some(complete) = stream.complete.take() {
            let message = Message::addressed(Mti::STREAM_DATA_COMPLETE, key.source, key.destination, complete.payload);
            self.send_toward(now, other(source_side), message);
        }
        self.end_stream(index, StreamEnd::Completed);
        true
    }

    pub(super) fn release_proceed(&mut self, now: Instant, index: usize) {
        let Some(stream) = self.streams.get_mut(index) else { return };
        let Some(destination_stream) = stream.destination_stream() else { return };
        stream.proceeds_held = stream.proceeds_held.saturating_sub(1);
        stream.proceeds_released = stream.proceeds_released.saturating_add(1);
        let (key, source_side) = (stream.key, stream.source_side);
        let proceed = DataProceed { source_stream: key.source_stream, destination_stream };
        let message = Message::addressed(Mti::STREAM_DATA_PROCEED, key.destination, key.source, proceed.to_bytes());
        self.send_toward(now, source_side, message);
    }

    /// Passes on a flush (zero-length Data Send) towards the destination.
    pub(super) fn pass_flush(&mut self, index: usize) {
        let Some(stream) = self.streams.get_mut(index) else { return };
        let Some(destination_stream) = stream.destination_stream() else { return };
        stream.flush_pending = false;
        let (key, source_side) = (stream.key, stream.source_side);
        let payload = alloc::vec![destination_stream.as_raw()];
        let message = Message::addressed(Mti::STREAM_DATA_SEND, key.source, key.destination, payload);
        let now = self.now;
        match other(source_side) {
            Side::Full => self.emit_full(message),
            Side::Can => self.route_to_can(now, CanBound::control(message)),
        }
    }

    /// Forgets a stream: its buffered data and delayed messages are dropped.
    pub(super) fn end_stream(&mut self, index: usize, cause: StreamEnd) {
        if index >= self.streams.len() {
            return;
        }
        let stream = self.streams.swap_remove(index);
        let key = stream.key;
        let mut dropped = stream.buffered();
        let is_this_stream = |item: &CanBound| item.data_of == Some(Some(key));
        self.waiting.retain(|w| !is_this_stream(&w.item));
        self.data.retain(|r| !is_this_stream(&r.item));
        if self.current_data.as_ref().is_some_and(|d| d.stream == Some(key)) {
            self.current_data = None;
        }
        if cause == StreamEnd::Completed {
            dropped = 0;
        }
        self.stats.data_bytes_dropped = self.stats.data_bytes_dropped.saturating_add(dropped as u64);
        self.event(GatewayEvent::StreamEnded { stream: key, cause });
    }

    /// Ends every stream `node` takes part in.
    pub(super) fn end_streams_of(&mut self, node: NodeId, cause: StreamEnd) {
        let mut index = 0;
        while let Some(stream) = self.streams.get(index) {
            if stream.key.source == node || stream.key.destination == node {
                self.end_stream(index, cause);
            } else {
                index += 1;
            }
        }
    }

    /// The open stream `source` -> `destination` with `did` whose source is on `side`.
    pub(super) fn find_open(&self, source: NodeId, destination: NodeId, did: StreamId, side: Side) -> Option<usize> {
        self.streams.iter().position(|s| {
            s.key.source == source
                && s.key.destination == destination
                && s.source_side == side
                && s.destination_stream() == Some(did)
        })
    }
}
