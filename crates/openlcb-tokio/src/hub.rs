//! [`Hub`]: a TCP hub that relays every frame from one client to every other client.
//!
//! GridConnect clients (JMRI, OpenMRN, [`Node`](crate::Node)s with
//! [`Framing::GridConnect`]) share one virtual CAN segment; OpenLCB-TCP clients, on their own
//! listener, share one full-format link. Each frame is decoded and encoded again, so garbage
//! from one client never reaches the others (the decoder resynchronises and counts it).
//! With both listeners and [`HubOptions::bridge`], an [`openlcb_gateway::Gateway`] joins the
//! two groups as one more client of each: CAN nodes and OpenLCB-TCP nodes see each other,
//! streams included.
//!
//! # The pace of the hub
//!
//! Every client has its own queue, bounded by [`HubOptions::max_queued_bytes`]. The hub is
//! one bus, and like a CAN bus it runs at the pace of its slowest reader: when a frame finds
//! a client's queue full, the hub stops reading from the client that sent it until there is
//! room, so that TCP flow control slows the sender down (a stream's sender waits for its
//! Proceeds all the same). A client that only listens therefore never falls behind by more
//! than its queue, however much others move through the hub, and loses nothing. A client
//! that takes none of its queue for [`HubOptions::drain_timeout`] while a sender waits for it
//! is a dead socket: it is disconnected ([`HubEvent::SlowClient`]) and the senders go on.
//! One dead client thus holds the bus for at most that long, and the memory a hub holds for
//! a client is its queue and one write batch.
//!
//! # Slots
//!
//! The number of clients is capped ([`HubOptions::max_clients`]). While there are free slots,
//! nobody is closed for being quiet: a board that has nothing to say for hours, a throttle
//! that only listens, keep their place. When the hub is full, a slot needs a minimum rate:
//! a new client takes the slot of the client that completed fewer than
//! [`HubOptions::slot_min_frames`] frames in the last [`HubOptions::slot_window`] (the one
//! whose rate is the lowest, if there are several; [`HubEvent::Evicted`]). A client that
//! connected less than a window ago, an attached link and the bridge are never evicted. Only
//! if no client is below the rate is the new one told that the hub is full and closed
//! ([`HubEvent::Refused`]). A slot cannot be held with a frame now and then: clients that
//! each complete one frame a minute hold every slot only until someone else needs one.
//!
//! A client that says nothing at all for [`HubOptions::silent_timeout`] after connecting is
//! closed (bytes that never make a frame are not a word), and TCP keep-alive finds clients
//! that vanished.
//!
//! A client whose input ends is removed at once and its connection closed, whether it
//! closed its socket or only half-closed it (shut down its sending side): over TCP the two
//! cannot be told apart until a write to the client fails, which on a quiet bus may be
//! never, and a client that left must not hold its slot. A half-closed client therefore gets
//! no more frames; a client that wants to listen keeps its sending side open. The other way
//! round, a client that can no longer be written to (it reset its connection) gets nothing
//! more, but every frame it sent before is still read and relayed until its input ends: the
//! hub never drops a frame it took, not even one held up by a slow listener when its sender
//! left.
//!
//! Garbage is counted and reported at most once per [`GARBAGE_REPORT_INTERVAL`] per client.
//!
//! Besides TCP clients, the GridConnect group takes links: any byte stream of GridConnect
//! text ([`Hub::attach`]: a serial adapter, a CAN interface through
//! [`FrameStream`](crate::can::FrameStream)) and a connection to an upstream hub
//! ([`Hub::link_upstream`]), kept up with a bounded backoff.

use std::collections::HashMap;
use std::collections::VecDeque;
use std::fmt::Write as _;
use std::net::SocketAddr;
use std::sync::atomic::{AtomicBool, AtomicU64, AtomicUsize, Ordering};
use std::sync::{Arc, Mutex};

use bytes::{Bytes, BytesMut};
use openlcb_can::{CanFrame, CanHeader, FrameKind, GridConnectDecoder, NodeAlias, gridconnect};
use openlcb_tcp::Decoder;
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::{TcpListener, TcpStream};
use tokio::sync::{Notify, mpsc, oneshot};
use tokio::task::{AbortHandle, JoinSet};
use tokio::time::Instant;
use tracing::Instrument as _;

use crate::io::{ByteReader, ByteWriter};
use crate::{ByteStream, Error, Framing};
use openlcb_stream::NodeId;

/// A connected client, numbered from 1 in order of arrival.
pub type ClientId = u64;

/// The bridge's number as a client of the GridConnect group (numbered from the top, so that
/// real clients count from 1).
pub const BRIDGE_GRIDCONNECT: ClientId = ClientId::MAX;
/// The bridge's number as a client of the OpenLCB-TCP group.
pub const BRIDGE_TCP: ClientId = ClientId::MAX - 1;

/// A client's garbage is reported at most this often (with a count of what was skipped).
pub const GARBAGE_REPORT_INTERVAL: std::time::Duration = std::time::Duration::from_secs(10);

/// The most a client's writer holds for one `write` call, and what its buffer shrinks back to.
const WRITE_BATCH: usize = 64 * 1024;

/// Bounds and switches of a [`Hub`].
#[derive(Debug, Clone)]
#[non_exhaustive]
pub struct HubOptions {
    /// Bytes queued for one client (one chunk of frames more if a single chunk is larger).
    /// When a client's queue is full, the hub stops reading from the sender of the next frame
    /// for it until there is room (see [the module docs](self)).
    pub max_queued_bytes: usize,
    /// How long a sender may wait for room in a client's full queue: a client that takes
    /// nothing of it for this long is disconnected ([`HubEvent::SlowClient`]). Default 10 s,
    /// well within the 30 s a [`Node`](crate::Node) lets a stalled socket take
    /// ([`NodeOptions::write_timeout`](crate::NodeOptions::write_timeout)), so that the
    /// sender held up by a dead client is not given up itself.
    pub drain_timeout: std::time::Duration,
    /// Clients connected at once (both listeners, attached links included). When the hub is
    /// full, a new client takes the slot of a client below the minimum rate
    /// ([`HubOptions::slot_min_frames`] per [`HubOptions::slot_window`]), or is refused and
    /// closed if there is none.
    pub max_clients: usize,
    /// The window over which a client's rate is judged when the hub is full. `None` never
    /// evicts anyone: a new client of a full hub is refused. Default 60 s.
    pub slot_window: Option<std::time::Duration>,
    /// Complete frames a client must have sent in the last [`HubOptions::slot_window`] to keep
    /// its slot when the hub is full; 0 never evicts anyone. Default 10. The hub remembers
    /// the times of this many recent frames per client.
    pub slot_min_frames: u16,
    /// A client that sends no complete frame for this long after connecting is closed (a node
    /// logs in at once; a silent connection is a stray, a port scan or a client trickling an
    /// endless partial frame). `None` keeps them.
    pub silent_timeout: Option<std::time::Duration>,
    /// Report every relayed frame as a [`HubEvent::Frame`].
    pub trace: bool,
    /// Events held for [`Hub::next_event`]; more are dropped and counted.
    pub event_capacity: usize,
    /// With both listeners, bridge GridConnect and OpenLCB-TCP clients through a gateway.
    pub bridge: bool,
    /// The gateway's Node ID: written as the originating node of every OpenLCB-TCP message it
    /// forwards. Default 05.01.01.01.22.FE.
    pub gateway_node_id: NodeId,
    /// The largest stream window the gateway lets through (a request's Max Buffer Size is
    /// lowered to it), 1..=65535.
    pub gateway_max_window: u16,
}

impl Default for HubOptions {
    fn default() -> Self {
        HubOptions {
            max_queued_bytes: 1024 * 1024,
            drain_timeout: std::time::Duration::from_secs(10),
            max_clients: 64,
            slot_window: Some(std::time::Duration::from_secs(60)),
            slot_min_frames: 10,
            silent_timeout: Some(std::time::Duration::from_secs(60)),
            trace: false,
            event_capacity: 4096,
            bridge: true,
            gateway_node_id: NodeId::from_bytes([0x05, 0x01, 0x01, 0x01, 0x22, 0xFE]),
            gateway_max_window: 65535,
        }
    }
}

/// Something that happened at the hub.
#[derive(Debug, Clone, PartialEq, Eq)]
#[non_exhaustive]
pub enum HubEvent {
    /// A client connected.
    Connected {
        /// Its number.
        client: ClientId,
        /// Its address.
        peer: SocketAddr,
        /// The listener it came through.
        protocol: Framing,
    },
    /// A link that is not a TCP client joined the GridConnect group: a byte stream given to
    /// [`Hub::attach`] (a serial adapter) or the connection to an upstream hub
    /// ([`Hub::link_upstream`]).
    Attached {
        /// Its number.
        client: ClientId,
        /// What it is, as given (a device path, `upstream HOST:PORT`).
        name: String,
    },
    /// The upstream hub could not be reached or its connection ended; the link tries again
    /// after `retry_in`.
    UpstreamDown {
        /// The upstream hub's address.
        addr: String,
        /// What went wrong.
        reason: String,
        /// The wait before the next attempt.
        retry_in: std::time::Duration,
    },
    /// A client left or its connection failed.
    Disconnected {
        /// Its number.
        client: ClientId,
        /// Why.
        reason: String,
    },
    /// A client's queue was full and it took nothing of it for [`HubOptions::drain_timeout`]
    /// while a sender waited: it was disconnected.
    SlowClient {
        /// Its number.
        client: ClientId,
        /// Bytes it had queued.
        queued: usize,
    },
    /// The hub was full and a client below the minimum rate was disconnected to make room
    /// for a new one (see [`HubOptions::slot_min_frames`]).
    Evicted {
        /// Its number.
        client: ClientId,
        /// Complete frames it sent in the last [`HubOptions::slot_window`].
        frames: usize,
        /// The address of the client that took its slot.
        newcomer: SocketAddr,
    },
    /// A client sent something that is not a frame: at most one report per client per
    /// [`GARBAGE_REPORT_INTERVAL`], and one when it leaves, with the count since the last.
    Garbage {
        /// Its number.
        client: ClientId,
        /// Undecodable pieces since the last report.
        count: u64,
        /// What was wrong with the first of them.
        error: String,
    },
    /// A client closed its sending side or its connection. It is removed (a
    /// [`HubEvent::Disconnected`] follows): a client that stopped sending holds no slot.
    InputClosed {
        /// Its number.
        client: ClientId,
    },
    /// A client was refused: the hub has [`HubOptions::max_clients`] clients, none of them
    /// below the minimum rate.
    Refused {
        /// Its address.
        peer: SocketAddr,
        /// Clients connected.
        clients: usize,
    },
    /// A frame was relayed (only with [`HubOptions::trace`]).
    Frame {
        /// Who sent it.
        client: ClientId,
        /// The frame as text (GridConnect) or described (OpenLCB-TCP).
        text: String,
    },
}

/// Counters of a hub.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
#[non_exhaustive]
pub struct HubStats {
    /// Clients accepted so far.
    pub clients_accepted: u64,
    /// Clients connected now.
    pub clients_connected: usize,
    /// Frames received from clients and relayed.
    pub frames: u64,
    /// Undecodable input from clients.
    pub decode_errors: u64,
    /// Clients disconnected for taking nothing of a full queue for
    /// [`HubOptions::drain_timeout`].
    pub slow_clients: u64,
    /// Times a client's input was paused because a frame it sent found another client's
    /// queue full.
    pub senders_paused: u64,
    /// Clients disconnected to make room for a new one in a full hub.
    pub clients_evicted: u64,
    /// Events dropped because nobody read them.
    pub events_dropped: u64,
    /// Clients refused because the hub was full.
    pub clients_refused: u64,
    /// Bytes queued for all clients now (each client's share is bounded by
    /// [`HubOptions::max_queued_bytes`]).
    pub queued_bytes: usize,
}

pub(crate) struct Client {
    protocol: Framing,
    /// The bridge: never dropped for being slow (it is in-process and bounded by the gateway).
    bridge: bool,
    queue: mpsc::UnboundedSender<Bytes>,
    backlog: Arc<Backlog>,
    /// The client's recent frames, to judge its rate when the hub is full; `None` for those
    /// never evicted (attached links, the bridge).
    activity: Option<Activity>,
    /// The task writing to the client, stopped when it is removed.
    writer: Option<AbortHandle>,
    /// Dropped with the entry: the client's reader stops at its next read, never while it
    /// relays what it read (frames a client sent before it left reach everyone).
    _removal: oneshot::Sender<()>,
    /// Aliases the client announced (AMD) and has not released (AMR), at most
    /// [`ALIASES_PER_CLIENT`]: when it leaves, the hub releases them for it.
    aliases: Vec<(NodeAlias, NodeId)>,
    /// Node IDs the OpenLCB-TCP client carried (sources of its messages), at most
    /// [`NODES_PER_CLIENT`]: when it leaves, the bridge releases their CAN aliases.
    nodes: Vec<NodeId>,
}

/// What a new client's tasks get from [`State::add_client`].
pub(crate) struct NewClient {
    id: ClientId,
    /// The chunks to write to it.
    queue: mpsc::UnboundedReceiver<Bytes>,
    /// Their count.
    backlog: Arc<Backlog>,
    /// Ends when the client is removed.
    removed: oneshot::Receiver<()>,
}

/// The bytes queued for one client, counted against [`HubOptions::max_queued_bytes`] (the
/// bridge's are not counted), the signal senders wait on for room, and the client's socket
/// while its writer task does not write to it.
#[derive(Default)]
pub(crate) struct Backlog {
    bytes: AtomicUsize,
    /// Notified when the client's writer takes bytes out and when the client is removed.
    room: Notify,
    /// The client was removed or its writer ended: nothing more is queued for it.
    gone: AtomicBool,
    /// The client's socket when its writer task is idle (the task takes it for each write):
    /// a chunk for a client with nothing queued is written here at once by the reader that
    /// relays it, which saves a task's wake-up on every hop of a round trip. Every chunk for
    /// the client goes through this lock, so none overtakes another.
    idle_writer: Mutex<Option<ByteWriter>>,
}

impl Backlog {
    /// Counts `len` more bytes if they fit under `max` (an empty queue takes any chunk).
    fn reserve(&self, len: usize, max: usize) -> bool {
        self.bytes
            .fetch_update(Ordering::Relaxed, Ordering::Relaxed, |q| {
                (q == 0 || q.saturating_add(len) <= max).then(|| q.saturating_add(len))
            })
            .is_ok()
    }

    /// Hands `chunk` to the client (`true`): written to its socket at once if nothing is
    /// queued and its writer task is idle, and what the socket did not take queued first;
    /// otherwise queued on `queue` if it fits under `max`. `false`: the queue is full.
    fn offer(&self, chunk: &Bytes, max: usize, queue: &mpsc::UnboundedSender<Bytes>) -> bool {
        let Ok(mut idle) = self.idle_writer.lock() else { return false };
        let mut rest = chunk.clone();
        if self.queued() == 0
            && let Some(writer) = idle.as_mut()
            // Not ready, or failed: queued whole (the writer task meets the error itself).
            && let Some(Ok(written)) = crate::io::try_write(writer, chunk)
        {
            rest = chunk.slice(written.min(chunk.len())..);
            if rest.is_empty() {
                return true;
            }
        }
        // An empty queue takes any chunk, so the rest of a partial write always fits.
        if !self.reserve(rest.len(), max) {
            return false;
        }
        let _ = queue.send(rest);
        true
    }

    /// Waits until `chunk` fits and [offers](Self::offer) it (`true`), or until `deadline` or
    /// the client's removal (`false`).
    async fn offer_in_time(
        &self,
        chunk: &Bytes,
        max: usize,
        queue: &mpsc::UnboundedSender<Bytes>,
        deadline: Instant,
    ) -> bool {
        loop {
            // Registered before the check, so that no notification between the two is lost.
            let room = self.room.notified();
            tokio::pin!(room);
            room.as_mut().enable();
            if self.gone.load(Ordering::Relaxed) {
                return false;
            }
            if self.offer(chunk, max, queue) {
                return true;
            }
            if tokio::time::timeout_at(deadline, room).await.is_err() {
                return false;
            }
        }
    }

    /// The client's socket, for its writer task to write to (`None` once the client is gone).
    fn take_writer(&self) -> Option<ByteWriter> {
        self.idle_writer.lock().ok()?.take()
    }

    /// The writer task is done writing (for now): relays may write to `writer` at once again.
    fn put_writer(&self, writer: ByteWriter) {
        if let Ok(mut idle) = self.idle_writer.lock()
            && !self.is_closed()
        {
            *idle = Some(writer);
        }
    }

    /// The writer took `len` bytes out.
    fn take(&self, len: usize) {
        // Every byte taken was counted before it was queued (a removed client's count is 0).
        let _ = self.bytes.fetch_update(Ordering::Relaxed, Ordering::Relaxed, |q| Some(q.saturating_sub(len)));
        self.room.notify_waiters();
    }

    /// The client was removed or its writer ended: nothing more is queued for it, and nobody
    /// waits for it any more.
    fn close(&self) {
        self.gone.store(true, Ordering::Relaxed);
        self.bytes.store(0, Ordering::Relaxed);
        self.room.notify_waiters();
        // The socket closes now, not when the last relay lets go of this backlog.
        drop(self.take_writer());
    }

    fn is_closed(&self) -> bool {
        self.gone.load(Ordering::Relaxed)
    }

    fn queued(&self) -> usize {
        self.bytes.load(Ordering::Relaxed)
    }
}

/// When a client completed its last frames, at most [`HubOptions::slot_min_frames`] of them,
/// oldest first. A new client starts with that many at the time it connected: it counts as
/// keeping the rate for its first window.
struct Activity {
    recent: VecDeque<Instant>,
}

impl Activity {
    fn new(now: Instant, min_frames: u16) -> Self {
        Activity { recent: std::iter::repeat_n(now, usize::from(min_frames)).collect() }
    }

    /// Notes `frames` completed at `now`.
    fn note(&mut self, now: Instant, frames: u64) {
        let kept = self.recent.len();
        for _ in 0..frames.min(kept as u64) {
            self.recent.pop_front();
            self.recent.push_back(now);
        }
    }

    /// When the oldest of the remembered frames came, if the client is below the rate at
    /// `now` (that frame is more than `window` old); the earlier, the lower the rate.
    fn below_rate(&self, now: Instant, window: std::time::Duration) -> Option<Instant> {
        self.recent.front().copied().filter(|&oldest| now.duration_since(oldest) >= window)
    }

    /// Frames completed within `window` before `now`.
    fn frames_within(&self, now: Instant, window: std::time::Duration) -> usize {
        self.recent.iter().filter(|&&at| now.duration_since(at) < window).count()
    }
}

/// Aliases remembered per GridConnect client (a gateway or a host of many virtual nodes has
/// several; beyond this many the oldest is forgotten).
const ALIASES_PER_CLIENT: usize = 32;

/// Node IDs remembered per OpenLCB-TCP client (a hub or a gateway upstream carries several;
/// beyond this many the oldest is forgotten).
const NODES_PER_CLIENT: usize = 32;

pub(crate) struct State {
    options: HubOptions,
    clients: Mutex<HashMap<ClientId, Client>>,
    events: mpsc::Sender<HubEvent>,
    next_id: AtomicU64,
    accepted: AtomicU64,
    frames: AtomicU64,
    decode_errors: AtomicU64,
    slow_clients: AtomicU64,
    senders_paused: AtomicU64,
    evicted: AtomicU64,
    events_dropped: AtomicU64,
    refused: AtomicU64,
    /// With a bridge: where the Node IDs of OpenLCB-TCP clients that left go.
    departed: Option<mpsc::UnboundedSender<NodeId>>,
}

impl State {
    pub(crate) fn event(&self, event: HubEvent) {
        // Inside the client's span when it concerns one; frames only with `options.trace`.
        match &event {
            HubEvent::Frame { .. } => tracing::trace!(?event),
            HubEvent::Garbage { .. }
            | HubEvent::SlowClient { .. }
            | HubEvent::Evicted { .. }
            | HubEvent::Refused { .. } => tracing::warn!(?event),
            _ => tracing::info!(?event),
        }
        if self.events.try_send(event).is_err() {
            self.events_dropped.fetch_add(1, Ordering::Relaxed);
        }
    }

    /// Registers the bridge as a client of `protocol`'s group: its id and its queue.
    fn add_bridge_client(&self, protocol: Framing) -> (ClientId, mpsc::UnboundedReceiver<Bytes>) {
        let id = match protocol {
            Framing::GridConnect => BRIDGE_GRIDCONNECT,
            Framing::Tcp => BRIDGE_TCP,
        };
        let (queue, rx) = mpsc::unbounded_channel();
        let client = Client {
            protocol,
            bridge: true,
            queue,
            backlog: Arc::default(),
            activity: None,
            writer: None,
            // The bridge has no reader.
            _removal: oneshot::channel().0,
            aliases: Vec::new(),
            nodes: Vec::new(),
        };
        if let Ok(mut clients) = self.clients.lock() {
            clients.insert(id, client);
        }
        (id, rx)
    }

    /// Registers a new client of `protocol`'s group. A TCP client can be evicted from a full
    /// hub; a link (`evictable` false) never is.
    fn add_client(&self, protocol: Framing, evictable: bool) -> NewClient {
        let id = self.next_id.fetch_add(1, Ordering::Relaxed);
        self.accepted.fetch_add(1, Ordering::Relaxed);
        let (queue, rx) = mpsc::unbounded_channel();
        let (removal, removed) = oneshot::channel();
        let backlog = Arc::new(Backlog::default());
        let client = Client {
            protocol,
            bridge: false,
            queue,
            backlog: backlog.clone(),
            activity: evictable.then(|| Activity::new(Instant::now(), self.options.slot_min_frames)),
            writer: None,
            _removal: removal,
            aliases: Vec::new(),
            nodes: Vec::new(),
        };
        if let Ok(mut clients) = self.clients.lock() {
            clients.insert(id, client);
        }
        NewClient { id, queue: rx, backlog, removed }
    }

    /// Counts relayed frames and undecodable input.
    pub(crate) fn count(&self, frames: u64, errors: u64) {
        self.frames.fetch_add(frames, Ordering::Relaxed);
        self.decode_errors.fetch_add(errors, Ordering::Relaxed);
    }

    pub(crate) fn options(&self) -> &HubOptions {
        &self.options
    }

    /// Removes a client: its writer stops at once, its reader at its next read; `true` if it
    /// was still there. The bridge forgets
    /// the aliases it still held: a node that left without a word is forgotten, and its Node
    /// ID may join again, on either side. Nothing goes on the wire for a GridConnect client:
    /// a GridConnect hub is a wire, it relays and never originates a frame. For the Node IDs
    /// an OpenLCB-TCP client carried (and no other client still does), the bridge's gateway
    /// releases the CAN aliases it held for them, with an AMR each.
    fn remove(&self, client: ClientId) -> bool {
        let Ok(mut clients) = self.clients.lock() else { return false };
        let Some(entry) = clients.remove(&client) else { return false };
        let departed: Vec<NodeId> =
            entry.nodes.iter().copied().filter(|node| !clients.values().any(|c| c.nodes.contains(node))).collect();
        drop(clients);
        entry.writer.iter().for_each(AbortHandle::abort);
        entry.backlog.close();
        self.bridge_forgets(&entry.aliases);
        if let Some(bridge) = &self.departed {
            for node in departed {
                let _ = bridge.send(node);
            }
        }
        true
    }

    /// Records `node` as carried by the OpenLCB-TCP `client`, in its entry and in `seen` (the
    /// reader's copy, so that the lock is taken only for a Node ID not seen before).
    fn track_node(&self, client: ClientId, node: NodeId, seen: &mut Vec<NodeId>) {
        remember_node(seen, node);
        if let Ok(mut clients) = self.clients.lock()
            && let Some(entry) = clients.get_mut(&client)
        {
            remember_node(&mut entry.nodes, node);
        }
    }

    /// Tells the bridge (and only the bridge: no client sees it) that `aliases` were released,
    /// as if an AMR for each had come from the CAN side.
    fn bridge_forgets(&self, aliases: &[(NodeAlias, NodeId)]) {
        let mut chunk = BytesMut::new();
        let mut text = [0u8; gridconnect::MAX_ENCODED_LEN];
        for (alias, node) in aliases {
            let header = CanHeader::control(FrameKind::AliasMapReset, *alias);
            let Some(frame) = CanFrame::from_header(&header, &node.to_bytes()) else { continue };
            if let Ok(len) = gridconnect::encode(&frame, &mut text) {
                chunk.extend_from_slice(text.get(..len).unwrap_or_default());
                chunk.extend_from_slice(b"\n");
            }
        }
        if chunk.is_empty() {
            return;
        }
        if let Ok(clients) = self.clients.lock()
            && let Some(bridge) = clients.get(&BRIDGE_GRIDCONNECT)
        {
            let _ = bridge.queue.send(chunk.freeze());
        }
    }

    /// Follows a client's alias announcements (AMD) and releases (AMR). Called for control
    /// frames only, which are rare (logins), not for every frame.
    fn track_alias(&self, client: ClientId, frame: &CanFrame) {
        let Ok(header) = frame.header() else { return };
        let node = NodeId::from_slice(frame.payload());
        let Ok(mut clients) = self.clients.lock() else { return };
        let Some(entry) = clients.get_mut(&client) else { return };
        entry.aliases.retain(|(alias, _)| *alias != header.source);
        if let (FrameKind::AliasMapDefinition, Some(node)) = (header.kind, node) {
            if entry.aliases.len() >= ALIASES_PER_CLIENT {
                entry.aliases.remove(0);
            }
            entry.aliases.push((header.source, node));
        }
    }

    /// Queues `chunk` for every other client of the same protocol. For a client whose queue
    /// is full it waits (and the caller reads nothing meanwhile) until there is room, for at
    /// most [`HubOptions::drain_timeout`]; a client that made no room by then is dropped.
    pub(crate) async fn relay(&self, from: ClientId, protocol: Framing, chunk: &Bytes) {
        let max = self.options.max_queued_bytes;
        let mut full = Vec::new();
        if let Ok(clients) = self.clients.lock() {
            for (&id, client) in clients.iter() {
                // A client whose writer failed gets nothing more (its reader still relays).
                if id == from || client.protocol != protocol || client.queue.is_closed() {
                    continue;
                }
                if client.bridge {
                    let _ = client.queue.send(chunk.clone());
                } else if !client.backlog.offer(chunk, max, &client.queue) {
                    full.push((id, client.backlog.clone(), client.queue.clone()));
                }
            }
        }
        if full.is_empty() {
            return;
        }
        self.senders_paused.fetch_add(1, Ordering::Relaxed);
        let deadline = Instant::now() + self.options.drain_timeout;
        for (client, backlog, queue) in full {
            if !backlog.offer_in_time(chunk, max, &queue, deadline).await && !backlog.is_closed() && self.remove(client)
            {
                self.slow_clients.fetch_add(1, Ordering::Relaxed);
                self.event(HubEvent::SlowClient { client, queued: backlog.queued() });
            }
        }
    }

    /// Notes that `client` completed `frames` frames now (its rate, for a full hub).
    fn heard(&self, client: ClientId, frames: u64) {
        if let Ok(mut clients) = self.clients.lock()
            && let Some(activity) = clients.get_mut(&client).and_then(|c| c.activity.as_mut())
        {
            activity.note(Instant::now(), frames);
        }
    }

    /// In a full hub, disconnects the client with the lowest rate below the minimum to make
    /// room for `newcomer`; `false` if every client keeps the rate.
    fn evict_for(&self, newcomer: SocketAddr) -> bool {
        let Some(window) = self.options.slot_window else { return false };
        let now = Instant::now();
        let victim = self.clients.lock().ok().and_then(|clients| {
            clients
                .iter()
                .filter_map(|(&id, c)| {
                    let activity = c.activity.as_ref()?;
                    let oldest = activity.below_rate(now, window)?;
                    Some((oldest, id, activity.frames_within(now, window)))
                })
                .min()
        });
        let Some((_, client, frames)) = victim else { return false };
        if self.remove(client) {
            self.evicted.fetch_add(1, Ordering::Relaxed);
            self.event(HubEvent::Evicted { client, frames, newcomer });
        }
        true
    }
}

/// A running hub. Dropping it closes the listeners and every client connection.
#[derive(Debug)]
pub struct Hub {
    addr: SocketAddr,
    tcp_addr: Option<SocketAddr>,
    state: Arc<State>,
    events: mpsc::Receiver<HubEvent>,
    _listeners: JoinSet<()>,
}

impl std::fmt::Debug for State {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("State").field("options", &self.options).finish_non_exhaustive()
    }
}

impl Hub {
    /// Listens for GridConnect clients on `listen` (`host:port`; port 0 picks a free one) and,
    /// with `tcp_listen`, for OpenLCB-TCP clients, and starts relaying.
    pub async fn bind(listen: &str, tcp_listen: Option<&str>, options: HubOptions) -> Result<Hub, Error> {
        let bind = |addr: &str| {
            let addr = addr.to_string();
            async move { open_listener(&addr).await.map_err(|source| Error::Bind { addr, source: Arc::new(source) }) }
        };
        let listener = bind(listen).await?;
        let tcp_listener = match tcp_listen {
            Some(addr) => Some(bind(addr).await?),
            None => None,
        };
        let local = |listener: &TcpListener, addr: &str| {
            listener.local_addr().map_err(|source| Error::Bind { addr: addr.to_string(), source: Arc::new(source) })
        };
        let addr = local(&listener, listen)?;
        let tcp_addr = match (&tcp_listener, tcp_listen) {
            (Some(listener), Some(name)) => Some(local(listener, name)?),
            _ => None,
        };
        let (events_tx, events) = mpsc::channel(options.event_capacity.max(1));
        let bridged = options.bridge && tcp_listener.is_some();
        let (departed_tx, departed_rx) = if bridged {
            let (tx, rx) = mpsc::unbounded_channel();
            (Some(tx), Some(rx))
        } else {
            (None, None)
        };
        let state = Arc::new(State {
            options,
            clients: Mutex::new(HashMap::new()),
            events: events_tx,
            next_id: AtomicU64::new(1),
            accepted: AtomicU64::new(0),
            frames: AtomicU64::new(0),
            decode_errors: AtomicU64::new(0),
            slow_clients: AtomicU64::new(0),
            senders_paused: AtomicU64::new(0),
            evicted: AtomicU64::new(0),
            events_dropped: AtomicU64::new(0),
            refused: AtomicU64::new(0),
            departed: departed_tx,
        });
        let mut listeners = JoinSet::new();
        listeners.spawn(accept_loop(listener, Framing::GridConnect, state.clone()));
        if let Some(listener) = tcp_listener {
            listeners.spawn(accept_loop(listener, Framing::Tcp, state.clone()));
            if let Some(departed) = departed_rx {
                let [can, tcp] = [Framing::GridConnect, Framing::Tcp].map(|protocol| state.add_bridge_client(protocol));
                listeners.spawn(crate::bridge::run(can, tcp, departed, state.clone()));
            }
        }
        Ok(Hub { addr, tcp_addr, state, events, _listeners: listeners })
    }

    /// The GridConnect listener's address.
    pub fn local_addr(&self) -> SocketAddr {
        self.addr
    }

    /// The OpenLCB-TCP listener's address, if there is one.
    pub fn tcp_local_addr(&self) -> Option<SocketAddr> {
        self.tcp_addr
    }

    /// Events dropped so far because they were not read in time
    /// ([`HubStats::events_dropped`]), read without the locks that [`Hub::stats`] takes: cheap
    /// enough to ask for every event.
    pub fn events_dropped(&self) -> u64 {
        self.state.events_dropped.load(Ordering::Relaxed)
    }

    /// The counters now.
    pub fn stats(&self) -> HubStats {
        let state = &self.state;
        HubStats {
            clients_accepted: state.accepted.load(Ordering::Relaxed),
            clients_connected: state.clients.lock().map(|c| c.values().filter(|c| !c.bridge).count()).unwrap_or(0),
            frames: state.frames.load(Ordering::Relaxed),
            decode_errors: state.decode_errors.load(Ordering::Relaxed),
            slow_clients: state.slow_clients.load(Ordering::Relaxed),
            senders_paused: state.senders_paused.load(Ordering::Relaxed),
            clients_evicted: state.evicted.load(Ordering::Relaxed),
            events_dropped: state.events_dropped.load(Ordering::Relaxed),
            clients_refused: state.refused.load(Ordering::Relaxed),
            queued_bytes: state.clients.lock().map(|c| c.values().map(|c| c.backlog.queued()).sum()).unwrap_or(0),
        }
    }

    /// Relays between the GridConnect clients and `stream`, any byte stream that carries
    /// GridConnect text (a USB-serial adapter to a real CAN bus, a pseudo-terminal): it is
    /// one more client, numbered like the others, never closed for being silent (a quiet bus
    /// is no stray connection) nor evicted from a full hub. It leaves when the stream ends or
    /// fails ([`HubEvent::Disconnected`]).
    pub fn attach(&mut self, stream: impl ByteStream, name: &str) -> ClientId {
        let client = self.state.add_client(Framing::GridConnect, false);
        let id = client.id;
        self.state.event(HubEvent::Attached { client: id, name: name.to_string() });
        self._listeners.spawn(serve_link(client, crate::io::halves(stream), self.state.clone()));
        id
    }

    /// Joins the GridConnect hub at `addr` (`HOST:PORT`) as one of its clients and relays both
    /// ways: the two hubs' clients share one CAN segment. The link is never evicted from this
    /// hub when it is full. A lost or refused connection is tried again, after
    /// [`UPSTREAM_RETRY_FIRST`] and then twice as long each time up to [`UPSTREAM_RETRY_MAX`]
    /// ([`HubEvent::UpstreamDown`] says so); each new connection is a new client
    /// ([`HubEvent::Attached`]).
    pub fn link_upstream(&mut self, addr: &str) {
        self._listeners.spawn(upstream_loop(addr.to_string(), self.state.clone()));
    }

    /// The next event (connections, slow clients, garbage, traced frames).
    pub async fn next_event(&mut self) -> Option<HubEvent> {
        self.events.recv().await
    }
}

/// A listener on `addr` whose connections keep segments below a small peer window
/// (see [`SEGMENT_LIMIT`](crate::socket::SEGMENT_LIMIT): OpenMRN nodes shrink their buffers).
async fn open_listener(addr: &str) -> std::io::Result<TcpListener> {
    let mut last = std::io::Error::new(std::io::ErrorKind::InvalidInput, "the address resolves to nothing");
    for address in tokio::net::lookup_host(addr).await? {
        let socket =
            if address.is_ipv4() { tokio::net::TcpSocket::new_v4()? } else { tokio::net::TcpSocket::new_v6()? };
        socket.set_reuseaddr(true)?;
        crate::socket::limit_segments(&socket)?;
        match socket.bind(address).and_then(|()| socket.listen(1024)) {
            Ok(listener) => return Ok(listener),
            Err(error) => last = error,
        }
    }
    Err(last)
}

async fn accept_loop(listener: TcpListener, protocol: Framing, state: Arc<State>) {
    // Client tasks live here: when the hub is dropped, this task is aborted and they go too.
    let mut clients = JoinSet::new();
    loop {
        tokio::select! {
            accepted = listener.accept() => match accepted {
                Ok((socket, peer)) => start_client(&mut clients, socket, peer, protocol, &state),
                // Out of file descriptors and the like: keep serving the clients there are.
                Err(_) => tokio::time::sleep(std::time::Duration::from_millis(50)).await,
            },
            Some(_) = clients.join_next() => {}
        }
    }
}

fn start_client(tasks: &mut JoinSet<()>, socket: TcpStream, peer: SocketAddr, protocol: Framing, state: &Arc<State>) {
    let connected = state.clients.lock().map(|c| c.values().filter(|c| !c.bridge).count()).unwrap_or(0);
    if connected >= state.options.max_clients && !state.evict_for(peer) {
        state.refused.fetch_add(1, Ordering::Relaxed);
        state.event(HubEvent::Refused { peer, clients: connected });
        tasks.spawn(refuse(socket, protocol, connected));
        return;
    }
    let _ = socket.set_nodelay(true);
    let _ = crate::socket::keep_alive(&socket);
    let client = state.add_client(protocol, true);
    let id = client.id;
    let span = tracing::info_span!("client", id, %peer, ?protocol);
    span.in_scope(|| state.event(HubEvent::Connected { client: id, peer, protocol }));
    let (reader, writer) = crate::io::tcp_halves(socket);
    let silent_timeout = state.options.silent_timeout;
    let reading = read_client(id, reader, client.removed, protocol, silent_timeout, state.clone());
    tasks.spawn(reading.instrument(span.clone()));
    let writer = tasks.spawn(write_client(writer, client.queue, client.backlog).instrument(span));
    let registered = state
        .clients
        .lock()
        .ok()
        .and_then(|mut clients| clients.get_mut(&id).map(|client| client.writer = Some(writer.clone())));
    if registered.is_none() {
        // It left before its writer was registered.
        writer.abort();
    }
}

/// The first wait before an upstream hub is tried again.
pub const UPSTREAM_RETRY_FIRST: std::time::Duration = std::time::Duration::from_millis(250);
/// The longest wait between attempts to reach an upstream hub.
pub const UPSTREAM_RETRY_MAX: std::time::Duration = std::time::Duration::from_secs(5);
/// How long one attempt to reach an upstream hub may take.
const UPSTREAM_CONNECT_TIMEOUT: std::time::Duration = std::time::Duration::from_secs(5);

/// Keeps a link to the upstream hub at `addr` up for as long as the hub runs.
async fn upstream_loop(addr: String, state: Arc<State>) {
    let name = format!("upstream {addr}");
    let mut retry_in = UPSTREAM_RETRY_FIRST;
    loop {
        let reason = match tokio::time::timeout(UPSTREAM_CONNECT_TIMEOUT, crate::node::dial(&addr)).await {
            Ok(Ok(socket)) => {
                let _ = socket.set_nodelay(true);
                let client = state.add_client(Framing::GridConnect, false);
                state.event(HubEvent::Attached { client: client.id, name: name.clone() });
                serve_link(client, crate::io::tcp_halves(socket), state.clone()).await;
                // It was up: the next attempt starts from the shortest wait.
                retry_in = UPSTREAM_RETRY_FIRST;
                "the connection ended".to_string()
            }
            Ok(Err(error)) => error.to_string(),
            Err(_) => "no answer in time".to_string(),
        };
        state.event(HubEvent::UpstreamDown { addr: addr.clone(), reason, retry_in });
        tokio::time::sleep(retry_in).await;
        retry_in = (retry_in * 2).min(UPSTREAM_RETRY_MAX);
    }
}

/// Runs a link client (an attached stream, an upstream hub) until its input ends (which
/// removes it); its writer goes with it.
async fn serve_link(client: NewClient, (reader, writer): (ByteReader, ByteWriter), state: Arc<State>) {
    let reading = read_client(client.id, reader, client.removed, Framing::GridConnect, None, state);
    let writing = write_client(writer, client.queue, client.backlog);
    tokio::pin!(reading, writing);
    tokio::select! {
        () = &mut reading => {}
        // A link that can no longer be written to still relays what it sends until it ends.
        () = &mut writing => reading.await,
    }
}

/// Tells a client over the cap why it is closed. GridConnect clients get one line of text
/// (decoders skip text outside frames); OpenLCB-TCP clients just see the close.
async fn refuse(mut socket: TcpStream, protocol: Framing, clients: usize) {
    if protocol == Framing::GridConnect {
        let line = format!("hub full: {clients} clients connected; try again later\r\n");
        let _ = tokio::time::timeout(std::time::Duration::from_secs(1), socket.write_all(line.as_bytes())).await;
    }
    let _ = socket.shutdown().await;
}

/// Garbage from one client, counted between reports.
#[derive(Default)]
struct GarbageReport {
    count: u64,
    first: Option<String>,
    last_report: Option<tokio::time::Instant>,
}

impl GarbageReport {
    /// Counts one piece; keeps the description of the first piece since the last report.
    fn note(&mut self, error: impl FnOnce() -> String) {
        self.count += 1;
        if self.first.is_none() {
            self.first = Some(error());
        }
    }

    /// Reports what was counted if the interval is over (or `now_anyway`).
    fn flush(&mut self, id: ClientId, state: &State, now_anyway: bool) {
        let due = self.last_report.is_none_or(|at| at.elapsed() >= GARBAGE_REPORT_INTERVAL);
        if self.count == 0 || !(due || now_anyway) {
            return;
        }
        let error = self.first.take().unwrap_or_default();
        state.event(HubEvent::Garbage { client: id, count: std::mem::take(&mut self.count), error });
        self.last_report = Some(tokio::time::Instant::now());
    }
}

/// The protocol a client's first bytes are in, if it is not the one of its port: GridConnect
/// text starts with `:X` or `:S`; an OpenLCB-TCP message with the flags byte 0x80 (a
/// message, not a link control one) and never with `:`.
fn other_protocol(port: Framing, first: &[u8]) -> Option<&'static str> {
    match (port, first) {
        (Framing::Tcp, [b':', b'X' | b'x' | b'S' | b's', ..]) => Some("GridConnect"),
        (Framing::GridConnect, [0x80, ..]) => Some("OpenLCB-TCP"),
        _ => None,
    }
}

/// Reads a client's frames, encodes each again and relays them in one chunk per read; reads
/// nothing more while a client's full queue holds the chunk up. At the end of its input (a
/// close or a half-close) the client is removed; once it is `removed` by the hub, nothing
/// more is read.
async fn read_client(
    id: ClientId,
    mut reader: ByteReader,
    mut removed: oneshot::Receiver<()>,
    protocol: Framing,
    silent_timeout: Option<std::time::Duration>,
    state: Arc<State>,
) {
    let mut buf = vec![0u8; 16 * 1024];
    let mut gridconnect_decoder = GridConnectDecoder::default();
    let mut tcp_decoder = Decoder::default();
    let mut nodes = Vec::new();
    let mut chunk = BytesMut::new();
    let mut garbage = GarbageReport::default();
    // A complete frame heard (partial frames and garbage are not a word), and any input.
    let (mut heard, mut first_input, mut input_ended) = (false, true, false);
    let silent_deadline = silent_timeout.map(|t| tokio::time::Instant::now() + t);
    let reason: String = loop {
        let silent_until = silent_deadline.filter(|_| !heard);
        let n = tokio::select! {
            read = reader.read(&mut buf) => read,
            _ = &mut removed => break "removed".to_string(),
            () = sleep_until(silent_until) => break "sent no frame since it connected".to_string(),
        };
        let n = match n {
            Ok(0) => {
                input_ended = true;
                break CLOSED_BY_CLIENT.to_string();
            }
            Ok(n) => n,
            Err(error) => break departure(&error),
        };
        let input = buf.get(..n).unwrap_or_default();
        if std::mem::take(&mut first_input)
            && let Some(other) = other_protocol(protocol, input)
        {
            break format!("speaks {other} on this port (closed, so that it learns at once)");
        }
        let (frames, errors) = match protocol {
            Framing::GridConnect => {
                relay_gridconnect(id, input, &mut gridconnect_decoder, &mut chunk, &state, &mut garbage)
            }
            Framing::Tcp => relay_tcp(id, input, &mut tcp_decoder, &mut nodes, &mut chunk, &state, &mut garbage),
        };
        heard |= frames > 0;
        garbage.flush(id, &state, false);
        state.frames.fetch_add(frames, Ordering::Relaxed);
        state.decode_errors.fetch_add(errors, Ordering::Relaxed);
        if frames > 0 {
            state.heard(id, frames);
        }
        if !chunk.is_empty() {
            state.relay(id, protocol, &chunk.split().freeze()).await;
        }
        if let Some(failure) = tcp_decoder.failure() {
            break format!("sent an OpenLCB-TCP length that cannot be trusted ({failure})");
        }
    };
    garbage.flush(id, &state, true);
    // Removed (its aliases forgotten by the bridge) before anyone hears that it left.
    let removed = state.remove(id);
    if input_ended {
        state.event(HubEvent::InputClosed { client: id });
    }
    if removed {
        state.event(HubEvent::Disconnected { client: id, reason });
    }
}

fn relay_gridconnect(
    id: ClientId,
    input: &[u8],
    decoder: &mut GridConnectDecoder,
    chunk: &mut BytesMut,
    state: &State,
    garbage: &mut GarbageReport,
) -> (u64, u64) {
    let (mut frames, mut errors) = (0, 0);
    let mut text = [0u8; gridconnect::MAX_ENCODED_LEN];
    decoder.decode_all(input, |decoded| match decoded {
        Ok(frame) => {
            if is_alias_map_frame(&frame) {
                state.track_alias(id, &frame);
            }
            if let Ok(len) = gridconnect::encode(&frame, &mut text) {
                let text = text.get(..len).unwrap_or_default();
                chunk.extend_from_slice(text);
                chunk.extend_from_slice(b"\n");
                frames += 1;
                if state.options.trace {
                    state.event(HubEvent::Frame { client: id, text: String::from_utf8_lossy(text).into_owned() });
                }
            }
        }
        Err(error) => {
            errors += 1;
            garbage.note(|| error.to_string());
        }
    });
    (frames, errors)
}

/// Adds `node` to `nodes`, forgetting the oldest beyond [`NODES_PER_CLIENT`].
fn remember_node(nodes: &mut Vec<NodeId>, node: NodeId) {
    if nodes.len() >= NODES_PER_CLIENT {
        nodes.remove(0);
    }
    nodes.push(node);
}

/// An AMD or AMR: the frames that bind and release aliases.
fn is_alias_map_frame(frame: &CanFrame) -> bool {
    frame.header().is_ok_and(|h| matches!(h.kind, FrameKind::AliasMapDefinition | FrameKind::AliasMapReset))
}

/// Relays an OpenLCB-TCP client's messages; with a bridge, notes the Node IDs it carries
/// (`nodes`, the reader's copy of its entry's list).
fn relay_tcp(
    id: ClientId,
    mut input: &[u8],
    decoder: &mut Decoder,
    nodes: &mut Vec<NodeId>,
    chunk: &mut BytesMut,
    state: &State,
    garbage: &mut GarbageReport,
) -> (u64, u64) {
    let (mut frames, mut errors) = (0, 0);
    while let Some(decoded) = decoder.decode(&mut input) {
        match decoded {
            Ok(frame) => {
                let source = frame.message.source;
                if state.departed.is_some() && !nodes.contains(&source) {
                    state.track_node(id, source, nodes);
                }
                if frame.encode_to(chunk).is_ok() {
                    frames += 1;
                    if state.options.trace {
                        let message = frame.message;
                        let mut text = format!("MTI 0x{:04X} {}", message.mti.0, message.source);
                        if let Some(destination) = message.destination {
                            let _ = write!(text, " -> {destination}");
                        }
                        let _ = write!(text, ", {} bytes", message.payload.len());
                        state.event(HubEvent::Frame { client: id, text });
                    }
                }
            }
            Err(error) => {
                errors += 1;
                garbage.note(|| error.to_string());
            }
        }
    }
    (frames, errors)
}

/// The reason of [`HubEvent::Disconnected`] for a client that closed its connection (seen as
/// the end of its input, a broken pipe or a reset): it simply left.
pub const CLOSED_BY_CLIENT: &str = "closed the connection";

/// Why a client's socket failed, in words: a normal departure is [`CLOSED_BY_CLIENT`].
fn departure(error: &std::io::Error) -> String {
    use std::io::ErrorKind;
    match error.kind() {
        ErrorKind::BrokenPipe
        | ErrorKind::ConnectionReset
        | ErrorKind::ConnectionAborted
        | ErrorKind::UnexpectedEof => CLOSED_BY_CLIENT.to_string(),
        _ => error.to_string(),
    }
}

/// Waits until `at`, or for ever without one.
async fn sleep_until(at: Option<Instant>) {
    match at {
        Some(at) => tokio::time::sleep_until(at).await,
        None => std::future::pending().await,
    }
}

/// Writes a client's queue, many chunks per `write` call, until the client is removed or a
/// write fails; between writes the socket is lent to the relays ([`Backlog::offer`]). Then
/// nothing more is queued for it; its reader goes on until its input ends (what it sent
/// before its connection broke still reaches everyone).
async fn write_client(writer: ByteWriter, mut queue: mpsc::UnboundedReceiver<Bytes>, backlog: Arc<Backlog>) {
    backlog.put_writer(writer);
    let mut batch = Vec::new();
    let failure = loop {
        let Some(first) = queue.recv().await else { break None };
        // Taken before the chunk's bytes are: a relay writes at once only when neither is here.
        let Some(mut writer) = backlog.take_writer() else { break None };
        batch.extend_from_slice(&first);
        while batch.len() < WRITE_BATCH {
            let Ok(more) = queue.try_recv() else { break };
            batch.extend_from_slice(&more);
        }
        backlog.take(batch.len());
        if let Err(error) = writer.write_all(&batch).await {
            break Some(error);
        }
        backlog.put_writer(writer);
        batch.clear();
        // Memory goes back when a burst is over.
        batch.shrink_to(WRITE_BATCH);
    };
    queue.close();
    backlog.close();
    if let Some(error) = failure {
        tracing::debug!(%error, "writing to the client failed; it gets nothing more");
    }
}
