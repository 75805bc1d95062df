//! [`StreamEndpoint`]: one local node's stream engine, both roles, many streams and peers.
//!
//! Inputs are `handle_message` and `handle_timeout`; commands are `open`, `write`, `flush`,
//! `finish`, `abort`, `accept`, `reject` and `read`; outputs are `poll_transmit`,
//! `poll_event` and `poll_timeout`. After any input or command, drain `poll_transmit` and
//! `poll_event` until `None`, then arm a timer for `poll_timeout`.

mod rename;
mod stream;

use alloc::vec::Vec;

use self::stream::{LAST, LIVE_DESTINATION, NEVER, SOURCE, State, Stream};
use crate::config::{AcceptPolicy, Config};
use crate::event::{Event, Role, StreamInfo, Termination, TimeoutKind};
use crate::wire::{
    CompleteCount, DataComplete, DataProceed, DataSend, Emit, ErrorCode, ErrorReport, InitiateReply, InitiateRequest,
    ReplyClass, ReplyCode,
};
use crate::{
    ContentUid, Duration, Instant, Message, MessageRef, Mti, NodeId, PeerChange, PeerChanges, Queue, Receiver, StreamId,
};

/// Names one stream of one endpoint. A handle outlives its stream safely: once the stream is
/// gone, commands on it return [`StreamError::UnknownStream`], even if the slot is reused.
#[derive(Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub struct StreamHandle {
    slot: u16,
    generation: u16,
}

impl core::fmt::Debug for StreamHandle {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        write!(f, "StreamHandle({}#{})", self.slot, self.generation)
    }
}

/// Why a command on a stream could not be carried out.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
pub enum StreamError {
    /// No such stream (never existed, or it has ended and been released).
    #[error("no such stream")]
    UnknownStream,
    /// The command belongs to the other role (e.g. `write` on a destination stream).
    #[error("the command is for the other end of the stream")]
    WrongRole,
    /// The stream is not in a state that allows the command (e.g. `write` before `Opened`).
    #[error("the stream is not open")]
    NotOpen,
    /// [`Config::max_streams`] streams are open.
    #[error("the stream table is full")]
    TableFull,
    /// [`Config::max_streams_per_peer`] streams are open with that node, or no stream ID is free.
    #[error("no stream ID is free for that node")]
    NoFreeStreamId,
    /// The requested source stream ID is in use with that node.
    #[error("that stream ID is in use with that node")]
    StreamIdInUse,
    /// The proposed destination stream ID is the DID of a stream this node is still sending
    /// to that node on: Data Send names only the DID, so the destination could not tell the
    /// two streams' data apart.
    #[error("that destination stream ID is in use by a stream to that node")]
    DestinationIdInUse,
    /// A Max Buffer Size of 0 was asked for.
    #[error("the Max Buffer Size must be 1..=65535")]
    ZeroBufferSize,
    /// The destination is this node itself.
    #[error("a node cannot open a stream to itself")]
    SelfAddressed,
}

/// What to open: [`StreamEndpoint::open`]'s argument.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[non_exhaustive]
pub struct OpenOptions {
    /// The destination node.
    pub destination: NodeId,
    /// Proposed Max Buffer Size (the destination may lower it), 1..=65535.
    pub max_buffer_size: u16,
    /// What the stream carries (draft §7.2: needed when the stream was not announced).
    pub content_uid: Option<ContentUid>,
    /// A DID agreed beforehand by another protocol (Memory Configuration Read Stream).
    pub proposed_destination: Option<StreamId>,
    /// A SID agreed beforehand by another protocol (Memory Configuration Write Stream);
    /// otherwise the endpoint picks one, rotating so a recently closed SID is not reused.
    pub source_stream: Option<StreamId>,
}

impl OpenOptions {
    /// A stream to `destination` proposing `max_buffer_size`, no UID, no proposed IDs.
    pub fn new(destination: NodeId, max_buffer_size: u16) -> Self {
        OpenOptions { destination, max_buffer_size, content_uid: None, proposed_destination: None, source_stream: None }
    }

    /// Carry a Stream Content UID.
    pub fn content_uid(mut self, uid: ContentUid) -> Self {
        self.content_uid = Some(uid);
        self
    }

    /// Propose a DID agreed by another protocol.
    pub fn proposed_destination(mut self, did: StreamId) -> Self {
        self.proposed_destination = Some(did);
        self
    }

    /// Use this SID.
    pub fn source_stream(mut self, sid: StreamId) -> Self {
        self.source_stream = Some(sid);
        self
    }
}

/// How [`StreamEndpoint::accept_with`] accepts one stream.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[non_exhaustive]
pub struct AcceptOptions {
    /// The most this node grants; `None` for [`Config::max_window`]. The reply carries the
    /// smaller of this and what the source proposed.
    pub window: Option<u16>,
    /// Send one Proceed ahead for this stream (see [`Config::early_proceed`]).
    pub early_proceed: bool,
}

impl AcceptOptions {
    /// Accept with `window` (or the endpoint's largest) and early Proceed as chosen.
    pub fn new(window: Option<u16>, early_proceed: bool) -> Self {
        AcceptOptions { window, early_proceed }
    }
}

/// Inputs that were ignored or refused, by cause. Nothing here is ever a panic. Each counter
/// stops at `u32::MAX` (32 bits: 64-bit counters cost flash on a microcontroller).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
#[non_exhaustive]
pub struct Stats {
    /// Messages handled.
    pub messages_in: u32,
    /// Messages queued for transmission.
    pub messages_out: u32,
    /// Addressed to another node.
    pub not_for_us: u32,
    /// A stream message that did not parse (too short, 0xFF stream ID, zero buffer).
    pub malformed: u32,
    /// Data Send for a DID not open with that source.
    pub unknown_stream_data: u32,
    /// Proceed for a stream that is not open, or with the wrong DID.
    pub stray_proceeds: u32,
    /// Complete for an unknown stream, with the wrong SID, or a duplicate.
    pub stray_completes: u32,
    /// Reply for no pending request, or a second Reply.
    pub stray_replies: u32,
    /// TDE or OIR that matched no stream.
    pub stray_error_reports: u32,
    /// Data beyond the granted window (the source's credit): each ended its stream with
    /// TDE 0x2040.
    pub window_overruns: u32,
    /// Data beyond the count a Complete stated, or after the stream ended.
    pub excess_data: u32,
    /// Accepting Replies whose window exceeded what was proposed (used as given).
    pub oversized_windows: u32,
    /// Incoming requests refused (any code).
    pub requests_refused: u32,
    /// Messages of other protocols (neither a stream message, nor a TDE/OIR, nor
    /// Initialization Complete): the node routes those elsewhere.
    pub not_stream: u32,
    /// Messages claiming to come from this node's own ID.
    pub own_echoes: u32,
}
/// The outputs, kept apart from the stream table so both can be borrowed at once.
#[derive(Debug)]
struct Outputs {
    node: NodeId,
    transmits: Queue<Message>,
    events: Queue<Event>,
    stats: Stats,
}

impl Outputs {
    /// Sends a stream control message (at most 12 bytes: the longest is a request with a
    /// content UID), encoded on the stack so that only [`send_slices`](Self::send_slices)
    /// allocates.
    fn send_wire(&mut self, mti: Mti, peer: NodeId, body: &impl Emit) {
        let mut buf = [0u8; 12];
        let n = body.emit(&mut buf).unwrap_or(0);
        self.send_slices(mti, peer, buf.get(..n).unwrap_or_default(), &[]);
    }

    /// Sends a message whose payload is `head` then `tail`: the one place that allocates one.
    #[inline(never)]
    fn send_slices(&mut self, mti: Mti, peer: NodeId, head: &[u8], tail: &[u8]) {
        let mut payload = Vec::with_capacity(head.len() + tail.len());
        for part in [head, tail] {
            payload.extend_from_slice(part);
        }
        bump(&mut self.stats.messages_out);
        self.transmits.push_back(Message::addressed(mti, self.node, peer, payload));
    }

    #[inline(never)]
    fn event(&mut self, event: Event) {
        self.events.push_back(event);
    }
}

/// Which streams [`StreamEndpoint::end_each`] ends: those in one of `states` (a bit per
/// [`State`]), with `peer` unless [`ANY_PEER`] is among them.
#[derive(Debug, Clone, Copy)]
struct Selection {
    peer: NodeId,
    states: u8,
}

/// In a [`Selection`]'s states: whatever the peer (no state has this bit).
const ANY_PEER: u8 = 1 << 7;
const _: () = assert!(State::Closed.bit() < ANY_PEER, "a state's bit is ANY_PEER");

impl Selection {
    /// Every stream.
    const ALL: Selection =
        Selection { peer: NodeId::MAX, states: ANY_PEER | SOURCE | LIVE_DESTINATION | State::Closed.bit() };

    /// The streams with `peer` that are not closed, in `role` (`None`: both roles).
    fn live(peer: NodeId, role: Option<Role>) -> Self {
        let states = match role {
            Some(Role::Source) => SOURCE,
            Some(Role::Destination) => LIVE_DESTINATION,
            None => SOURCE | LIVE_DESTINATION,
        };
        Selection { peer, states }
    }

    /// The source streams with `peer` whose request waits for its Reply.
    fn waiting(peer: NodeId) -> Self {
        Selection { peer, states: State::AwaitingReply.bit() }
    }

    /// What `peer` forgot when it restarted: its streams but requests waiting for their Reply
    /// and closed destinations.
    fn forgotten(peer: NodeId) -> Self {
        Selection { peer, states: State::Sending.bit() | LIVE_DESTINATION }
    }

    /// Whether the selection takes the stream `s`.
    fn picks(self, s: &Stream) -> bool {
        self.states & s.state.bit() != 0 && (self.states & ANY_PEER != 0 || self.peer == s.peer)
    }
}

/// How [`StreamEndpoint::end_each`] ends each stream: the event it raises.
#[derive(Debug, Clone, Copy)]
enum Ending {
    /// [`Event::Terminated`] with this cause.
    Terminated(Termination),
    /// [`Event::Rejected`] with this code and class.
    Rejected(ReplyCode, ReplyClass),
}

/// One node's stream engine. See the crate documentation for the drive loop.
#[derive(Debug)]
#[repr(C)] // The table first, the configuration last: short loads reach what is read most.
pub struct StreamEndpoint {
    /// The stream table, searched linearly by (peer, role, the ID this node assigned): it is
    /// small (bounded by `max_streams`), and a map's code costs kilobytes of flash.
    slots: Vec<Stream>,
    next_source_id: StreamId,
    next_destination_id: StreamId,
    /// When the medium last carried another node's stream data ([`Self::medium_busy`]).
    medium_busy: Instant,
    /// When a request was last refused because every slot was taken: for an idle wait after
    /// that, only [`Config::min_idle_progress`] keeps a stream's slot.
    turned_away: Instant,
    out: Outputs,
    config: Config,
}

impl StreamEndpoint {
    /// An endpoint for the local node `node`. It sends only stream messages: announcing the
    /// node and answering the message-network basics is the node's job (`openlcb-node`).
    pub fn new(node: NodeId, config: Config) -> Self {
        let out = Outputs { node, transmits: Queue::new(), events: Queue::new(), stats: Stats::default() };
        StreamEndpoint {
            config,
            slots: Vec::new(),
            next_source_id: StreamId::MIN,
            next_destination_id: StreamId::MIN,
            medium_busy: Instant::ZERO,
            turned_away: Instant::ZERO,
            out,
        }
    }

    // ----- getters -----

    /// The local Node ID.
    pub fn node_id(&self) -> NodeId {
        self.out.node
    }

    /// The configuration.
    pub fn config(&self) -> &Config {
        &self.config
    }

    /// What to do with incoming requests from now on (a protocol above that claims some
    /// streams, like Memory Configuration, switches `AcceptAll` to `Ask`). Requests already
    /// waiting for a decision keep waiting.
    pub fn set_accept_policy(&mut self, policy: AcceptPolicy) {
        self.config.accept_policy = policy;
    }

    /// Counters of handled, ignored and refused inputs.
    pub fn stats(&self) -> Stats {
        self.out.stats
    }

    /// Streams in the table (open, pending, or closed with unread data).
    pub fn stream_count(&self) -> usize {
        self.slots.iter().filter(|s| s.is_live()).count()
    }

    /// What is known about a stream.
    pub fn stream_info(&self, handle: StreamHandle) -> Option<StreamInfo> {
        self.stream(handle).map(Stream::info)
    }

    /// As source: bytes that may be written now without waiting for a Proceed.
    pub fn credit(&self, handle: StreamHandle) -> Option<u32> {
        let stream = self.stream(handle)?;
        match stream.state {
            State::Sending => Some(stream.credit),
            State::AwaitingReply => Some(0),
            _ => None,
        }
    }

    /// As destination: bytes received and not yet read.
    pub fn buffered(&self, handle: StreamHandle) -> Option<usize> {
        self.destination(handle).map(|d| d.buffer.len())
    }

    /// As destination: the most `buffered` can ever be for this stream.
    pub fn buffer_capacity(&self, handle: StreamHandle) -> Option<usize> {
        self.destination(handle).map(|d| d.buffer.capacity())
    }

    /// The DID this endpoint will assign to the next request from `peer` that proposes
    /// none (Memory Configuration's Write Stream Reply names it before the request comes).
    pub fn next_destination_id(&self, peer: NodeId) -> Option<StreamId> {
        self.free_id(peer, Role::Destination).ok()
    }

    /// Every live handle, in slot order.
    pub fn handles(&self) -> impl Iterator<Item = StreamHandle> + '_ {
        self.slots.iter().enumerate().filter(|(_, s)| s.is_live()).map(|(slot, s)| handle_of(slot, s))
    }

    // ----- outputs -----

    /// A message to `peer` waits to be sent (the layer above keeps its own messages to
    /// `peer` behind it).
    pub fn sends_to_peer(&self, peer: NodeId) -> bool {
        self.out.transmits.iter().any(|m| m.destination == Some(peer))
    }

    /// The next message to send.
    pub fn poll_transmit(&mut self) -> Option<Message> {
        let message = self.out.transmits.pop_front()?;
        if message.mti == Mti::STREAM_DATA_PROCEED {
            self.proceed_sent(&message);
        }
        Some(message)
    }

    /// A Proceed leaves for the transport: only now may its source send the window it
    /// grants. Data past the credit before that is an overrun (the source did not wait).
    fn proceed_sent(&mut self, proceed: &Message) {
        let (Some(peer), Ok(ids)) = (proceed.destination, DataProceed::parse(&proceed.payload)) else { return };
        if let Some((_, stream, _)) = self.lookup(peer, Role::Destination, ids.destination_stream)
            && stream.proceeds_queued > 0
        {
            stream.proceeds_queued -= 1;
            stream.credit += u32::from(stream.window);
        }
    }

    /// The next event.
    pub fn poll_event(&mut self) -> Option<Event> {
        self.out.events.pop_front()
    }

    /// When to call `handle_timeout` next.
    pub fn poll_timeout(&self) -> Option<Instant> {
        let mut next = NEVER;
        for stream in &self.slots {
            next = next.min(stream.deadline).min(stream.keepalive);
        }
        (next != NEVER).then_some(next)
    }

    // ----- inputs -----

    /// Feeds one received message. Messages for other nodes are ignored (and counted).
    pub fn handle_message(&mut self, now: Instant, msg: MessageRef<'_>) {
        bump(&mut self.out.stats.messages_in);
        if msg.source == self.out.node {
            bump(&mut self.out.stats.own_echoes);
            return;
        }
        match msg.destination {
            Some(dest) if dest != self.out.node => {
                bump(&mut self.out.stats.not_for_us);
                return;
            }
            None if msg.mti.is_addressed() => {
                bump(&mut self.out.stats.malformed);
                return;
            }
            _ => {}
        }
        let peer = msg.source;
        match msg.mti {
            Mti::STREAM_INITIATE_REQUEST => self.on_request(now, peer, msg.payload),
            Mti::STREAM_INITIATE_REPLY => self.on_reply(now, peer, msg.payload),
            Mti::STREAM_DATA_SEND => self.on_data(now, peer, msg.payload),
            Mti::STREAM_DATA_PROCEED => self.on_proceed(now, peer, msg.payload),
            Mti::STREAM_DATA_COMPLETE => self.on_complete(now, peer, msg.payload),
            Mti::OPTIONAL_INTERACTION_REJECTED | Mti::TERMINATE_DUE_TO_ERROR => {
                self.on_error_report(msg.mti, peer, ErrorReport::parse(msg.payload));
            }
            Mti::INITIALIZATION_COMPLETE | Mti::INITIALIZATION_COMPLETE_SIMPLE => self.peer_restarted(peer),
            _ => bump(&mut self.out.stats.not_stream),
        }
    }

    /// Runs every wait due at `now`. Calling it early or twice is harmless.
    pub fn handle_timeout(&mut self, now: Instant) {
        // A wait that is not running never comes due, not even at the end of time.
        let now = now.min(LAST);
        let keepalive_at = later(now, self.config.keepalive_interval);
        for slot in 0..self.slots.len() {
            if let Some(stream) = self.slots.get_mut(slot)
                && stream.deadline <= now
            {
                stream.deadline = NEVER;
                self.on_deadline(now, slot);
            }
            // After the deadline: a stream that it ended sends no keep-alive.
            if let Some(stream) = self.slots.get_mut(slot)
                && stream.keepalive <= now
            {
                stream.keepalive = NEVER;
                if send_flush(stream, &mut self.out).is_ok() {
                    stream.keepalive = keepalive_at;
                }
            }
        }
    }

    /// The transport learnt a change of peer ([`PeerChange`]); a transport handed this
    /// endpoint as its [`Receiver`] calls it as it learns it.
    ///
    /// - [`PeerChange::Lost`]: every stream with the peer ends with
    ///   [`Termination::PeerLost`], without sending anything to it.
    /// - [`PeerChange::Renamed`]: the streams and queued messages of the peer go on under its
    ///   new name (see the `rename` module: a clash with a stream under the new name ends the
    ///   old one with [`Termination::Superseded`]).
    pub fn peer_changed(&mut self, change: PeerChange) {
        match change {
            PeerChange::Lost(peer) => self.end_all_with(peer, Termination::PeerLost),
            PeerChange::Renamed { from, to } => self.rename_peer(from, to),
        }
    }

    /// The transport saw another node's stream data go by on a shared medium (a CAN bus, where
    /// stream data has the lowest priority) at `now`, to this node or another. Streams on the
    /// medium may hold back this node's peers, whose frames lose arbitration (or wait behind
    /// their own data): until it falls quiet, the Reply, Proceed, first-data and idle waits
    /// run from the last such frame, so a peer waiting for its turn is not taken for a silent
    /// one. Once no stream moves, every wait runs out as configured.
    pub fn medium_busy(&mut self, now: Instant) {
        self.medium_busy = now;
    }

    /// The transport lost its link (e.g. this node's CAN alias): every stream ends with
    /// [`Termination::LinkLost`].
    pub fn link_lost(&mut self) {
        self.end_each(Selection::ALL, Ending::Terminated(Termination::LinkLost));
    }

    // ----- commands: source -----

    /// Sends a Stream Initiate Request. `Opened` or `Rejected` (or `TimedOut`) follows.
    pub fn open(&mut self, now: Instant, options: OpenOptions) -> Result<StreamHandle, StreamError> {
        if options.max_buffer_size == 0 {
            return Err(StreamError::ZeroBufferSize);
        }
        if options.destination == self.out.node {
            return Err(StreamError::SelfAddressed);
        }
        let peer = options.destination;
        if options.proposed_destination.is_some_and(|did| self.sends_to(peer, did, None)) {
            return Err(StreamError::DestinationIdInUse);
        }
        let reply_at = later(now, Some(self.config.reply_timeout));
        let (handle, stream, sid) =
            self.add_stream(State::AwaitingReply, peer, options.source_stream, options.max_buffer_size)?;
        stream.source_stream = sid;
        stream.destination_stream = options.proposed_destination;
        stream.content_uid = options.content_uid;
        stream.deadline = reply_at;
        let request = InitiateRequest {
            max_buffer_size: options.max_buffer_size,
            source_stream: sid,
            proposed_destination: options.proposed_destination,
            content_uid: options.content_uid,
        };
        self.out.send_wire(Mti::STREAM_INITIATE_REQUEST, peer, &request);
        Ok(handle)
    }

    /// Sends as much of `data` as the credit allows, as Data Send messages that never cross a
    /// window boundary, and returns how many bytes were taken. A short count means: wait for
    /// `Writable`. Each message is one allocation (its payload); nothing is buffered.
    pub fn write(&mut self, now: Instant, handle: StreamHandle, data: &[u8]) -> Result<usize, StreamError> {
        let keepalive_at = later(now, self.config.keepalive_interval);
        let proceed_at = later(now, Some(self.config.proceed_timeout));
        let (stream, out) = self.parts(handle)?;
        let did = sending_to(stream)?;
        let window = u32::from(stream.window.max(1));
        let mut rest = data;
        while !rest.is_empty() && stream.credit > 0 {
            // Never merge bytes of two windows into one message (draft §7.3, gateways count on it).
            let to_boundary = window.saturating_sub(stream.window_sent).max(1);
            let n = rest.len().min(stream.credit as usize).min(to_boundary as usize);
            let (chunk, tail) = rest.split_at(n);
            out.send_slices(Mti::STREAM_DATA_SEND, stream.peer, &[did.as_raw()], chunk);
            stream.credit -= n as u32;
            stream.count += n as u64;
            stream.window_sent += n as u32;
            if stream.window_sent >= window {
                stream.window_sent = 0;
            }
            rest = tail;
        }
        let taken = data.len() - rest.len();
        if !rest.is_empty() {
            stream.write_blocked = true;
        }
        if taken > 0 {
            // One deadline, from the moment credit ran out: a write that finds no credit
            // changes no timer (drivers call `write` on every wake-up).
            if stream.credit == 0 {
                stream.deadline = proceed_at;
            }
            stream.keepalive = keepalive_at;
        }
        Ok(taken)
    }

    /// Sends a zero-length Data Send (a flush: gateways pass on what they hold). Uses no credit.
    pub fn flush(&mut self, now: Instant, handle: StreamHandle) -> Result<(), StreamError> {
        let keepalive_at = later(now, self.config.keepalive_interval);
        let (stream, out) = self.parts(handle)?;
        send_flush(stream, out)?;
        stream.keepalive = keepalive_at;
        Ok(())
    }

    /// Sends Stream Data Complete with the byte count (form B, 6 bytes; wire-spec §4.5) and
    /// releases the stream. Its SID is not reused until the rotation comes round again.
    pub fn finish(&mut self, _now: Instant, handle: StreamHandle) -> Result<(), StreamError> {
        let (stream, out) = self.parts(handle)?;
        let complete = DataComplete {
            source_stream: stream.source_stream,
            destination_stream: sending_to(stream)?,
            count: CompleteCount::Total(stream.count as u32),
        };
        out.send_wire(Mti::STREAM_DATA_COMPLETE, stream.peer, &complete);
        let total = stream.count;
        self.end(Event::Sent { handle, total });
        Ok(())
    }

    // ----- commands: destination -----

    /// Accepts a request raised by `IncomingRequest`, granting `min(proposed, window,
    /// Config::max_window)` (`window: None` means `Config::max_window`).
    pub fn accept(&mut self, now: Instant, handle: StreamHandle, window: Option<u16>) -> Result<(), StreamError> {
        let early_proceed = self.config.early_proceed;
        self.accept_with(now, handle, AcceptOptions { window, early_proceed })
    }

    /// Accepts a request raised by `IncomingRequest` with this stream's own window and early
    /// Proceed choice. The receive buffer of a stream never exceeds the per-stream bound of
    /// [`Config`] (`max_window`, doubled when [`Config::early_proceed`] is on): early Proceed
    /// on an endpoint configured without it halves the window so that two fit.
    pub fn accept_with(
        &mut self,
        now: Instant,
        handle: StreamHandle,
        options: AcceptOptions,
    ) -> Result<(), StreamError> {
        self.pending(handle)?;
        let mut most = self.config.max_window;
        if options.early_proceed && !self.config.early_proceed {
            most = (most / 2).max(1);
        }
        let local = options.window.unwrap_or(most).min(most);
        self.accept_stream(now, handle, local, options.early_proceed);
        Ok(())
    }

    /// Refuses a request raised by `IncomingRequest` with `code` (a reject code: 0x1xxx or
    /// 0x2xxx; an accept code is replaced by 0x1000).
    pub fn reject(&mut self, _now: Instant, handle: StreamHandle, code: ReplyCode) -> Result<(), StreamError> {
        let (peer, sid) = self.pending(handle)?;
        let code = if code.is_accept() { ReplyCode::PERMANENT } else { code };
        self.refuse(peer, sid, code);
        self.release(handle);
        Ok(())
    }

    /// Copies received bytes into `buf` and returns how many. `Ok(0)` means nothing is
    /// buffered now (wait for `Readable`). Reading frees buffer space, which may send a
    /// Proceed. Once a closed stream has been read empty its handle is released.
    pub fn read(&mut self, now: Instant, handle: StreamHandle, buf: &mut [u8]) -> Result<usize, StreamError> {
        let (idle, min_progress) = (self.config.idle_timeout, self.config.min_idle_progress);
        let (stream, out) = self.parts(handle)?;
        match stream.state {
            State::AwaitingReply | State::Sending => return Err(StreamError::WrongRole),
            State::AwaitingDecision => return Err(StreamError::NotOpen),
            _ => {}
        }
        let n = stream.buffer.pop(buf);
        if stream.is_closed() && stream.buffer.is_empty() {
            stream.release();
        } else if send_due_proceed(stream, out) {
            // A new window: its bytes count as progress from here.
            stream.mark_progress(min_progress);
            restart_idle(stream, later(now, idle));
        }
        Ok(n)
    }

    // ----- commands: both roles -----

    /// Ends the stream at once with Terminate Due To Error `code` (e.g. 0x2000) and releases
    /// it; unread data is discarded. A pending request is refused instead, a closed stream is
    /// just released. No event follows for this stream; the TDE names no stream, so the other
    /// streams in the same role with that node end too ([`Termination::SiblingTerminated`]).
    pub fn abort(&mut self, _now: Instant, handle: StreamHandle, code: ErrorCode) -> Result<(), StreamError> {
        let stream = self.stream(handle).ok_or(StreamError::UnknownStream)?;
        let (peer, role, sid, state) = (stream.peer, stream.role(), stream.source_stream, stream.state);
        self.release(handle);
        match state {
            State::AwaitingDecision => self.refuse(peer, sid, ReplyCode(code.0)),
            State::Closed => {}
            _ => {
                self.terminate(peer, role, code);
            }
        }
        Ok(())
    }

    // ----- message handlers -----

    fn on_request(&mut self, now: Instant, peer: NodeId, payload: &[u8]) {
        let request = match InitiateRequest::parse(payload) {
            Ok(request) => request,
            Err(_) => {
                self.count_malformed();
                // Wire-spec §6.3: answer what can be answered. With a usable SID, a Reply with
                // buffer 0 and 0x1080; without enough bytes for one, an OIR so the source
                // stops waiting. A SID of 0xFF must be ignored.
                match payload.get(4) {
                    Some(&raw) => {
                        if let Some(sid) = StreamId::new(raw) {
                            self.refuse(peer, sid, ReplyCode::INVALID_REQUEST);
                        }
                    }
                    None => {
                        let oir =
                            ErrorReport { code: ErrorCode::INVALID_ARGUMENTS, mti: Some(Mti::STREAM_INITIATE_REQUEST) };
                        self.out.send_wire(Mti::OPTIONAL_INTERACTION_REJECTED, peer, &oir);
                    }
                }
                return;
            }
        };
        let sid = request.source_stream;
        if let Some(handle) = self.find_by_source_id(peer, sid) {
            if let Ok((stream, out)) = self.parts(handle)
                && is_duplicate_request(stream, &request)
            {
                // The same request again (a duplicated frame): answer it the same way.
                return send_accept(stream, out);
            }
            // The source no longer knows the old stream (it reset): that one is over.
            self.end(Event::Terminated { handle, cause: Termination::Superseded });
        }
        if let Err(code) = self.admit(now, peer, &request) {
            self.refuse(peer, sid, code);
        }
    }

    /// Takes a new request into the table and accepts it or asks the application, or says
    /// with which code to refuse it.
    fn admit(&mut self, now: Instant, peer: NodeId, request: &InitiateRequest) -> Result<(), ReplyCode> {
        if let AcceptPolicy::RejectAll(code) = self.config.accept_policy {
            return Err(code);
        }
        let ask = self.config.accept_policy == AcceptPolicy::Ask;
        let decision_at = later(now, Some(self.config.decision_timeout));
        let added =
            self.add_stream(State::AwaitingDecision, peer, request.proposed_destination, request.max_buffer_size);
        let (handle, stream, did) = match added {
            Ok(added) => added,
            Err(error) => {
                if error == StreamError::TableFull {
                    self.turned_away = now;
                }
                return Err(ReplyCode::BUFFER_UNAVAILABLE);
            }
        };
        stream.source_stream = request.source_stream;
        stream.destination_stream = Some(did);
        stream.content_uid = request.content_uid;
        if ask {
            stream.deadline = decision_at;
            let info = stream.info();
            self.out.event(Event::IncomingRequest { handle, info });
        } else {
            self.accept_stream(now, handle, self.config.max_window, self.config.early_proceed);
        }
        Ok(())
    }

    fn on_reply(&mut self, now: Instant, peer: NodeId, payload: &[u8]) {
        let Ok(reply) = InitiateReply::parse(payload) else { return self.count_malformed() };
        let keepalive_at = later(now, self.config.keepalive_interval);
        // A Reply naming the DID of another of our streams to that node answers an earlier
        // request with this SID (one this node gave up on): taking it would mix the two
        // streams' data at the destination. The answer to this request is still to come.
        let stale = reply.destination_stream.is_some_and(|did| self.sends_to(peer, did, Some(reply.source_stream)));
        let class = reply.class();
        let found = self
            .lookup(peer, Role::Source, reply.source_stream)
            .filter(|(_, stream, _)| stream.state == State::AwaitingReply && !(stale && class == ReplyClass::Accepted));
        let Some((handle, stream, out)) = found else { return bump(&mut self.out.stats.stray_replies) };
        match (class, reply.destination_stream) {
            (ReplyClass::Accepted, Some(did)) => {
                if reply.max_buffer_size > stream.window {
                    // The destination counts windows of the size it chose; using a smaller one
                    // here would deadlock, so take it as given (and count the oddity).
                    bump(&mut out.stats.oversized_windows);
                }
                stream.state = State::Sending;
                stream.credit = u32::from(reply.max_buffer_size);
                stream.window = reply.max_buffer_size;
                stream.destination_stream = Some(did);
                stream.deadline = NEVER;
                stream.keepalive = keepalive_at;
                let info = stream.info();
                out.event(Event::Opened { handle, info });
            }
            // An accept without a usable DID cannot be answered: wait for the timeout.
            (ReplyClass::Accepted, None) => self.count_malformed(),
            (class, _) => {
                self.end(Event::Rejected { handle, code: reply.code, class });
            }
        }
    }

    fn on_data(&mut self, now: Instant, peer: NodeId, payload: &[u8]) {
        let Ok(data) = DataSend::parse(payload) else { return self.count_malformed() };
        let idle_at = later(now, self.config.idle_timeout);
        let min_progress = self.config.min_idle_progress;
        let pressed = self.pressed(now);
        let Some((handle, stream, out)) = self.lookup(peer, Role::Destination, data.destination_stream) else {
            return bump(&mut self.out.stats.unknown_stream_data);
        };
        if !matches!(stream.state, State::Receiving | State::Draining) {
            return bump(&mut out.stats.excess_data);
        }
        let bytes = data.data;
        let len = bytes.len() as u32;
        // Past the credit (at most two windows: the buffer's size): a source that does not
        // keep to its window cannot be trusted with the rest of the data either (wire-spec
        // §6.4). The message is not half-taken; what came before it stays.
        if len > stream.credit || bytes.len() > stream.buffer.free() {
            bump(&mut out.stats.window_overruns);
            self.end(Event::Terminated { handle, cause: Termination::WindowOverrun });
            return self.terminate(peer, Role::Destination, ErrorCode::OUT_OF_ORDER);
        }
        stream.credit -= len;
        if stream.buffer.is_empty() && !bytes.is_empty() {
            out.event(Event::Readable { handle });
        }
        stream.buffer.push(bytes);
        stream.count += u64::from(len);
        if stream.state == State::Draining && stream.count >= stream.expected {
            let (total, expected) = (stream.count, stream.expected);
            return self.end(finished(handle, total, Some(expected)));
        }
        // Progress: `min_idle_progress` bytes since the wait last started (at most a window),
        // or the whole credit used (the source then waits for this node's Proceed).
        let progressed = stream.count >= stream.progress_at || stream.credit == 0;
        if progressed {
            stream.mark_progress(min_progress);
            stream.heard = now;
        }
        send_due_proceed(stream, out);
        // A keep-alive before any data does not lift the first-data wait; once every slot
        // was wanted, neither keep-alives nor a trickle of data keep a slot, only progress.
        if stream.count > 0 && (progressed || !pressed) {
            restart_idle(stream, idle_at);
        }
    }

    fn on_proceed(&mut self, now: Instant, peer: NodeId, payload: &[u8]) {
        let Ok(proceed) = DataProceed::parse(payload) else { return self.count_malformed() };
        // Any Proceed from the peer, even one for a stream that has ended here, shows that it
        // takes in this node's data: the streams still waiting their turn are not ignored.
        for stream in self.slots.iter_mut().filter(|s| s.is_with(peer, Role::Source)) {
            stream.heard = now;
        }
        let found = self.lookup(peer, Role::Source, proceed.source_stream).filter(|(_, stream, _)| {
            stream.state == State::Sending && stream.destination_stream == Some(proceed.destination_stream)
        });
        let Some((handle, stream, out)) = found else { return bump(&mut self.out.stats.stray_proceeds) };
        stream.credit = stream.credit.saturating_add(u32::from(stream.window));
        stream.deadline = NEVER;
        if core::mem::take(&mut stream.write_blocked) {
            out.event(Event::Writable { handle });
        }
    }

    fn on_complete(&mut self, now: Instant, peer: NodeId, payload: &[u8]) {
        let Ok(complete) = DataComplete::parse(payload) else { return self.count_malformed() };
        let grace_at = later(now, Some(self.config.complete_grace));
        let found = self.lookup(peer, Role::Destination, complete.destination_stream).filter(|(_, stream, _)| {
            stream.source_stream == complete.source_stream && stream.state == State::Receiving
        });
        let Some((handle, stream, _)) = found else { return bump(&mut self.out.stats.stray_completes) };
        let received = stream.count;
        let stated = match complete.count.missing_after(received) {
            None => None,
            Some(0) => Some(received),
            // On CAN a Complete out-arbitrates data frames still queued (wire-spec §6.3 note):
            // wait for what the source may still have in flight, never more than its credit.
            Some(missing) if missing <= u64::from(stream.credit) => {
                stream.state = State::Draining;
                stream.expected = received + missing;
                stream.deadline = grace_at;
                return;
            }
            // The count cannot be reached: it is below what arrived, or beyond any credit.
            Some(_) => complete.count.stated().map(u64::from),
        };
        self.end(finished(handle, received, stated));
    }

    fn on_error_report(&mut self, mti: Mti, peer: NodeId, report: ErrorReport) {
        // An OIR naming the request refuses every request still waiting at that peer; it
        // carries no SID (draft §7.1).
        if mti == Mti::OPTIONAL_INTERACTION_REJECTED && report.mti == Some(Mti::STREAM_INITIATE_REQUEST) {
            let code = ReplyCode(report.code.0);
            let class = if code.is_accept() { ReplyClass::Permanent } else { code.class() };
            if self.end_each(Selection::waiting(peer), Ending::Rejected(code, class)) == 0 {
                bump(&mut self.out.stats.stray_error_reports);
            }
            return;
        }
        // A TDE (or OIR) names the last MTI of the interaction, which tells which end the peer
        // is; it does not say which stream (wire-spec Q5). The draft (§7.4) has the destination
        // name Data Send and the source name Proceed, but real sources terminate their own
        // stream naming Data Send too: so the streams in the role the MTI implies end, or, when
        // there is none, the streams in the other role. With no MTI, every stream with that
        // peer ends. One naming another protocol's MTI is not about streams at all.
        let peer_is = match report.mti {
            Some(Mti::STREAM_DATA_SEND | Mti::STREAM_INITIATE_REQUEST | Mti::STREAM_DATA_COMPLETE) => {
                Some(Role::Destination)
            }
            Some(Mti::STREAM_DATA_PROCEED | Mti::STREAM_INITIATE_REPLY) => Some(Role::Source),
            Some(_) => return bump(&mut self.out.stats.stray_error_reports),
            None => None,
        };
        let ending = Ending::Terminated(Termination::ByPeer(report.code));
        let mut ended = self.end_each(Selection::live(peer, peer_is.map(Role::other)), ending);
        if ended == 0 && peer_is.is_some() {
            ended = self.end_each(Selection::live(peer, peer_is), ending);
        }
        if ended == 0 {
            bump(&mut self.out.stats.stray_error_reports);
        }
    }

    /// The wait of the stream in `slot` ran out; what that means follows from its state.
    /// Out of line: inlined into `handle_timeout`'s loop it took 168 more bytes of flash.
    #[inline(never)]
    fn on_deadline(&mut self, now: Instant, slot: usize) {
        if self.peer_progress(now, slot) {
            return;
        }
        let Some(stream) = self.slots.get(slot) else { return };
        let handle = handle_of(slot, stream);
        let (peer, role, sid, received) = (stream.peer, stream.role(), stream.source_stream, stream.count);
        let kind = match stream.state {
            State::AwaitingReply => TimeoutKind::Reply,
            State::AwaitingDecision => {
                self.refuse(peer, sid, ReplyCode::BUFFER_UNAVAILABLE);
                TimeoutKind::Decision
            }
            State::Draining => {
                // The grace for in-flight data is over: the count cannot be made up.
                let expected = stream.expected;
                return self.end(finished(handle, received, Some(expected)));
            }
            State::Sending => TimeoutKind::Proceed,
            State::Receiving if received == 0 => TimeoutKind::FirstData,
            State::Receiving => TimeoutKind::Idle,
            State::Free | State::Closed => return,
        };
        self.end(Event::TimedOut { handle, kind });
        // An open stream that timed out is terminated.
        if matches!(kind, TimeoutKind::Proceed | TimeoutKind::FirstData | TimeoutKind::Idle) {
            self.terminate(peer, role, ErrorCode::TIMEOUT);
        }
    }

    // ----- helpers -----

    /// Opens the pending destination stream `handle` with at most `local_window`.
    fn accept_stream(&mut self, now: Instant, handle: StreamHandle, local_window: u16, early: bool) {
        let first_data_at = later(now, self.receive_wait(0));
        let min_progress = self.config.min_idle_progress;
        let Ok((stream, out)) = self.parts(handle) else { return };
        stream.open_destination(stream.window.min(local_window).max(1), early);
        stream.mark_progress(min_progress);
        stream.deadline = first_data_at;
        send_accept(stream, out);
        let info = stream.info();
        out.event(Event::Opened { handle, info });
    }

    /// The wait of a receiving stream that has `received` bytes so far: until the first data,
    /// or between data.
    fn receive_wait(&self, received: u64) -> Option<Duration> {
        let (idle, first_data) = (self.config.idle_timeout, self.config.first_data_timeout);
        if received > 0 {
            return idle;
        }
        match (idle, first_data) {
            (Some(idle), Some(first)) => Some(if first < idle { first } else { idle }),
            (idle, first) => idle.or(first),
        }
    }

    /// A wait for the peer of the stream in `slot` ran out (its Reply, a Proceed, the first
    /// data, more data): if the peer made progress on another stream in the same role within
    /// that wait (a Proceed, data), it is busy, not silent (streams take turns), and if the
    /// medium carried others' streams, the peer may be waiting for its turn on it. Then the
    /// wait starts again from the later of the two and this returns true.
    fn peer_progress(&mut self, now: Instant, slot: usize) -> bool {
        let Some(stream) = self.slots.get(slot) else { return false };
        let wait = match stream.state {
            State::AwaitingReply => Some(self.config.reply_timeout),
            State::Sending => Some(self.config.proceed_timeout),
            State::Receiving => self.receive_wait(stream.count),
            _ => return false,
        };
        let (peer, role) = (stream.peer, stream.role());
        // A busy medium does not keep a receive slot that someone was refused: a trickle's
        // own frames keep the bus busy too.
        let busy = if role == Role::Destination && self.pressed(now) { Instant::ZERO } else { self.medium_busy };
        let heard = self.slots.iter().filter(|s| s.is_with(peer, role)).fold(busy, |t, s| t.max(s.heard));
        let resume_at = later(heard, wait);
        let Some(stream) = self.slots.get_mut(slot) else { return false };
        if resume_at <= now {
            return false;
        }
        stream.deadline = resume_at;
        true
    }

    /// A request was refused within the idle wait because every slot was taken: receive
    /// slots are wanted, and only progress keeps one.
    fn pressed(&self, now: Instant) -> bool {
        self.turned_away > Instant::ZERO && later(self.turned_away, self.config.idle_timeout) >= now
    }

    /// The peer and SID of the pending request `handle`, or why it is not one.
    fn pending(&self, handle: StreamHandle) -> Result<(NodeId, StreamId), StreamError> {
        let stream = self.stream(handle).ok_or(StreamError::UnknownStream)?;
        match stream.state {
            State::AwaitingDecision => Ok((stream.peer, stream.source_stream)),
            State::AwaitingReply | State::Sending => Err(StreamError::WrongRole),
            _ => Err(StreamError::NotOpen),
        }
    }

    /// Sends a refusing Reply: buffer 0, the SID echoed, DID 0 (never 0xFF, wire-spec §4.2).
    #[inline(never)]
    fn refuse(&mut self, peer: NodeId, sid: StreamId, code: ReplyCode) {
        bump(&mut self.out.stats.requests_refused);
        let reply =
            InitiateReply { max_buffer_size: 0, code, source_stream: sid, destination_stream: Some(StreamId::MIN) };
        self.out.send_wire(Mti::STREAM_INITIATE_REPLY, peer, &reply);
    }

    /// Ends a stream with `event` (about it): a source or pending stream is released at once,
    /// a destination keeps its unread data until the application has read it.
    fn end(&mut self, event: Event) {
        let Ok((stream, out)) = self.parts(event.handle()) else { return };
        // Only a destination buffers data.
        if !stream.buffer.is_empty() {
            stream.state = State::Closed;
            stream.stop_timers();
        } else {
            stream.release();
        }
        out.event(event);
    }

    /// Ends every stream that `selects` picks, in slot order, each with the event of `ending`;
    /// returns how many.
    fn end_each(&mut self, selection: Selection, ending: Ending) -> usize {
        let mut ended = 0;
        for slot in 0..self.slots.len() {
            let Some(stream) = self.slots.get(slot) else { continue };
            if selection.picks(stream) {
                let handle = handle_of(slot, stream);
                self.end(match ending {
                    Ending::Terminated(cause) => Event::Terminated { handle, cause },
                    Ending::Rejected(code, class) => Event::Rejected { handle, code, class },
                });
                ended += 1;
            }
        }
        ended
    }

    /// `peer` announced itself: every stream it had taken part in is forgotten there. A request
    /// still waiting for its Reply stays: messages from one node arrive in order, so the peer
    /// will see the request after its restart and answer it.
    fn peer_restarted(&mut self, peer: NodeId) {
        self.end_each(Selection::forgotten(peer), Ending::Terminated(Termination::PeerRestarted));
    }

    /// Sends `peer` the TDE `code` for a stream of this node in `role` that just ended here.
    /// The TDE names no stream, so the peer may end every stream it has with this node in the
    /// other role (wire-spec §6.4, Q5; this endpoint does): the streams here that it ends must
    /// end here too ([`Termination::SiblingTerminated`]), or their data would later land in a
    /// new stream given the same DID. Each gets its own TDE, for a peer that ends one stream
    /// per TDE.
    fn terminate(&mut self, peer: NodeId, role: Role, code: ErrorCode) {
        let siblings =
            self.end_each(Selection::live(peer, Some(role)), Ending::Terminated(Termination::SiblingTerminated));
        // Draft §7.4: the source terminates naming 0x0888, the destination naming 0x1F88.
        let mti = match role {
            Role::Source => Mti::STREAM_DATA_PROCEED,
            Role::Destination => Mti::STREAM_DATA_SEND,
        };
        let report = ErrorReport { code, mti: Some(mti) };
        for _ in 0..=siblings {
            self.out.send_wire(Mti::TERMINATE_DUE_TO_ERROR, peer, &report);
        }
    }

    /// Ends every stream with `peer` that is not over yet, without sending anything.
    fn end_all_with(&mut self, peer: NodeId, cause: Termination) {
        self.end_each(Selection::live(peer, None), Ending::Terminated(cause));
    }

    fn count_malformed(&mut self) {
        bump(&mut self.out.stats.malformed);
    }

    /// Takes a slot for a new stream with `peer` in `state`, proposing `window`, under the ID
    /// this node assigns: `wanted` if it is free, else the next free one in the rotation. The
    /// rotation goes on past every ID it gives out, and past a wanted one it would give out
    /// next: so that the ID of a stream that just ended here is not given out again at once
    /// (its peer may not have heard yet, and its data would land in the new stream). A wanted
    /// ID elsewhere leaves the rotation where it is (never back onto an ID it gave out just
    /// before).
    fn add_stream(
        &mut self,
        state: State,
        peer: NodeId,
        wanted: Option<StreamId>,
        window: u16,
    ) -> Result<(StreamHandle, &mut Stream, StreamId), StreamError> {
        let role = state.role();
        let id = match wanted {
            Some(id) if self.position(peer, role, id).is_some() => return Err(StreamError::StreamIdInUse),
            Some(id) => id,
            None => self.free_id(peer, role)?,
        };
        self.check_room(peer, role)?;
        let rotation = match role {
            Role::Source => &mut self.next_source_id,
            Role::Destination => &mut self.next_destination_id,
        };
        if wanted.is_none() || id == *rotation {
            *rotation = id.next();
        }
        let (handle, stream) = vacant(&mut self.slots, self.config.max_streams)?;
        stream.state = state;
        stream.peer = peer;
        stream.window = window;
        Ok((handle, stream, id))
    }

    fn check_room(&self, peer: NodeId, role: Role) -> Result<(), StreamError> {
        let (mut streams, mut with_peer) = (0, 0);
        for stream in &self.slots {
            streams += usize::from(stream.is_live());
            with_peer += usize::from(stream.is_with(peer, role));
        }
        if streams >= self.config.max_streams {
            return Err(StreamError::TableFull);
        }
        if with_peer >= self.config.max_streams_per_peer.min(255) {
            return Err(StreamError::NoFreeStreamId);
        }
        Ok(())
    }

    /// The next ID in the rotation not open with `peer` in `role`.
    fn free_id(&self, peer: NodeId, role: Role) -> Result<StreamId, StreamError> {
        let mut id = match role {
            Role::Source => self.next_source_id,
            Role::Destination => self.next_destination_id,
        };
        for _ in 0..255 {
            if self.position(peer, role, id).is_none() {
                return Ok(id);
            }
            id = id.next();
        }
        Err(StreamError::NoFreeStreamId)
    }

    /// Frees the slot of `handle`, if it still names a stream.
    fn release(&mut self, handle: StreamHandle) {
        if let Ok((stream, _)) = self.parts(handle) {
            stream.release();
        }
    }

    /// The stream `handle` names, if it is still in the table.
    #[inline(never)]
    fn stream(&self, handle: StreamHandle) -> Option<&Stream> {
        self.slots.get(usize::from(handle.slot)).filter(|s| s.is_live() && s.generation == handle.generation)
    }

    /// As [`stream`](Self::stream), a destination only.
    fn destination(&self, handle: StreamHandle) -> Option<&Stream> {
        self.stream(handle).filter(|s| s.role() == Role::Destination)
    }

    /// The stream `handle` names, with the outputs.
    #[inline(never)]
    fn parts(&mut self, handle: StreamHandle) -> Result<(&mut Stream, &mut Outputs), StreamError> {
        let stream = self
            .slots
            .get_mut(usize::from(handle.slot))
            .filter(|s| s.is_live() && s.generation == handle.generation)
            .ok_or(StreamError::UnknownStream)?;
        Ok((stream, &mut self.out))
    }

    /// The slot of the stream with `peer` in `role` under the ID this node assigned.
    #[inline(never)]
    fn position(&self, peer: NodeId, role: Role, id: StreamId) -> Option<usize> {
        self.slots.iter().position(|s| s.is(peer, role, id))
    }

    /// Whether a source stream to `peer` (open, or requested proposing it) other than the one
    /// with SID `except` uses DID `did`.
    fn sends_to(&self, peer: NodeId, did: StreamId, except: Option<StreamId>) -> bool {
        self.slots.iter().any(|s| {
            s.is_with(peer, Role::Source) && s.destination_stream == Some(did) && Some(s.source_stream) != except
        })
    }

    /// The stream with `peer` in `role` under the ID this node assigned.
    fn find(&self, peer: NodeId, role: Role, id: StreamId) -> Option<StreamHandle> {
        let slot = self.position(peer, role, id)?;
        Some(handle_of(slot, self.slots.get(slot)?))
    }

    /// As [`find`](Self::find), with the stream itself and the outputs.
    fn lookup(&mut self, peer: NodeId, role: Role, id: StreamId) -> Option<(StreamHandle, &mut Stream, &mut Outputs)> {
        let slot = self.position(peer, role, id)?;
        let stream = self.slots.get_mut(slot)?;
        Some((handle_of(slot, stream), stream, &mut self.out))
    }

    /// The destination stream from `peer` with the source's SID `sid` that is not over yet
    /// (a closed one, with unread data, has ended already: a new request cannot end it again).
    fn find_by_source_id(&self, peer: NodeId, sid: StreamId) -> Option<StreamHandle> {
        let slot = self
            .slots
            .iter()
            .position(|s| s.is_with(peer, Role::Destination) && s.source_stream == sid && !s.is_closed())?;
        Some(handle_of(slot, self.slots.get(slot)?))
    }
}

/// The handle of the stream in `slot`.
fn handle_of(slot: usize, stream: &Stream) -> StreamHandle {
    StreamHandle { slot: slot as u16, generation: stream.generation }
}

/// A free slot for a new stream (a new one while there are fewer than `max_streams`), to be
/// filled in place, and the handle it will have.
fn vacant(slots: &mut Vec<Stream>, max_streams: usize) -> Result<(StreamHandle, &mut Stream), StreamError> {
    let slot = match slots.iter().position(|s| !s.is_live()) {
        Some(free) => free,
        None if slots.len() < max_streams.min(usize::from(u16::MAX)) => {
            slots.push(Stream::free());
            slots.len() - 1
        }
        None => return Err(StreamError::TableFull),
    };
    let stream = slots.get_mut(slot).ok_or(StreamError::TableFull)?;
    Ok((handle_of(slot, stream), stream))
}

/// The deadline `after` from `now`, if there is a wait (one place for the saturating 64-bit
/// add).
#[inline(never)]
fn later(now: Instant, after: Option<Duration>) -> Instant {
    after.map_or(NEVER, |after| now + after)
}

/// Adds one to a counter. Out of line: one call is smaller than the saturating add.
#[inline(never)]
fn bump(counter: &mut u32) {
    *counter = counter.saturating_add(1);
}

/// The `Finished` event of a destination stream that received `total` bytes of `stated`.
fn finished(handle: StreamHandle, total: u64, stated: Option<u64>) -> Event {
    Event::Finished { handle, total, stated, matched: stated.is_none_or(|s| s == total) }
}

/// The DID of an open source stream, or why `stream` is not one.
fn sending_to(stream: &Stream) -> Result<StreamId, StreamError> {
    match (stream.state, stream.destination_stream) {
        (State::Sending, Some(did)) => Ok(did),
        (State::AwaitingReply | State::Sending, _) => Err(StreamError::NotOpen),
        _ => Err(StreamError::WrongRole),
    }
}

/// A zero-length Data Send on an open source stream.
fn send_flush(stream: &Stream, out: &mut Outputs) -> Result<(), StreamError> {
    out.send_slices(Mti::STREAM_DATA_SEND, stream.peer, &[sending_to(stream)?.as_raw()], &[]);
    Ok(())
}

/// The same request again, for an open stream nothing has arrived on yet.
fn is_duplicate_request(stream: &Stream, request: &InitiateRequest) -> bool {
    stream.state == State::Receiving
        && stream.count == 0
        && stream.content_uid == request.content_uid
        && request.proposed_destination.is_none_or(|did| stream.destination_stream == Some(did))
        && stream.window <= request.max_buffer_size
}

/// Sends the accepting Initiate Reply of a destination stream, with its window.
fn send_accept(stream: &Stream, out: &mut Outputs) {
    let reply = InitiateReply {
        max_buffer_size: stream.window,
        code: ReplyCode::ACCEPT,
        source_stream: stream.source_stream,
        destination_stream: stream.destination_stream,
    };
    out.send_wire(Mti::STREAM_INITIATE_REPLY, stream.peer, &reply);
}

/// Sends the Proceed the destination owes, if any (never more than one ahead, see
/// `Stream::proceed_due`), and says whether it did.
fn send_due_proceed(stream: &mut Stream, out: &mut Outputs) -> bool {
    let Some(did) = stream.destination_stream.filter(|_| stream.proceed_due()) else { return false };
    stream.proceeds_queued = stream.proceeds_queued.saturating_add(1);
    let proceed = DataProceed { source_stream: stream.source_stream, destination_stream: did };
    out.send_wire(Mti::STREAM_DATA_PROCEED, stream.peer, &proceed);
    true
}

/// Runs the idle timer only while the source holds credit: a source waiting for a Proceed
/// (because our reader is slow) is not idle.
fn restart_idle(stream: &mut Stream, idle_at: Instant) {
    stream.deadline = if stream.granted() > 0 { idle_at } else { NEVER };
}

impl PeerChanges for StreamEndpoint {
    fn peer_changed(&mut self, change: PeerChange) {
        StreamEndpoint::peer_changed(self, change);
    }
}

impl Receiver for StreamEndpoint {
    fn medium_busy(&mut self, now: Instant) {
        StreamEndpoint::medium_busy(self, now);
    }

    fn handle_message(&mut self, now: Instant, message: MessageRef<'_>) {
        StreamEndpoint::handle_message(self, now, message);
    }
}
