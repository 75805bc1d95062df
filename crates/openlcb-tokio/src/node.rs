//! [`Node`]: one OpenLCB node on a hub, with [`SendStream`]s and [`RecvStream`]s.

use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::time::Duration;

use bytes::Bytes;
use openlcb_can::CanConfig;
use openlcb_node::broadcast_time::{ClockId, ClockSet, ClockState};
use openlcb_node::{MemoryServer, NodeCommand, NodeConfig, NodeStats as StackStats, Protocols, SnipInfo, TransferPath};
use openlcb_stream::wire::ErrorCode;
use openlcb_stream::{NodeId, OpenOptions, Stats, StreamHandle, StreamInfo};
use tokio::net::{TcpStream, lookup_host};
use tokio::sync::{mpsc, oneshot, watch};
use tokio::task::JoinHandle;
use tracing::Instrument as _;

use crate::clock::{ClockCommand, ClockEvents};
use crate::driver::Driver;
use crate::events::{EventCommand, EventNotices};
use crate::memory::{Done, MemoryCommand, MemoryTransfer, Operation, SERVER_EVENT_QUEUE, ServerEvents, TransferKey};
use crate::train::{ThrottleEvents, TrainCommand, TrainEvents};
use crate::{Error, Framing, WireStats};
use openlcb_node::{EventConfig, EventRole};
use openlcb_stream::EventId;

/// How a [`Node`] joins the network.
#[derive(Debug, Clone)]
#[non_exhaustive]
pub struct NodeOptions {
    /// This node's 48-bit Node ID. It must be unique on the network.
    pub node_id: NodeId,
    /// The node's bounds, timers and SNIP strings. Its stream configuration's `accept_policy`
    /// decides incoming requests (`AcceptAll` by default: every accepted stream comes out of
    /// [`Node::accept`]).
    pub node: NodeConfig,
    /// The CAN link's bounds and timers (GridConnect only). After its login the node sends a
    /// global Verify Node ID naming itself; an answer within [`CanConfig::newcomer_window`]
    /// means a running node has this node's ID: this node then fails with
    /// [`Error::DuplicateNodeId`] (from [`Node::connect`] itself unless [`join`](Self::join)
    /// says otherwise), and the running node keeps running. By default the link's own frame
    /// queue has room for one frame per frame of a whole read (`frame_queue_limit` 5461), so
    /// that a burst of datagrams from many nodes gets every answer.
    pub can: CanConfig,
    /// How long to wait for the TCP connection and the alias login.
    pub connect_timeout: Duration,
    /// How long the socket may take none of the pending output before the connection is
    /// given up with [`Error::WriteStalled`] (a hub that stopped reading). Default 30 s,
    /// the endpoint's Proceed timeout.
    pub write_timeout: Duration,
    /// When [`Node::connect`] and [`Node::over`] return on CAN: after the newcomer window
    /// (the default) or as soon as the alias is permitted.
    pub join: Join,
}

/// When a CAN node's [`Node::connect`] returns. Either way the newcomer window runs its
/// course, and a node that finds its Node ID taken within it leaves the network.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
#[non_exhaustive]
pub enum Join {
    /// Once [`CanConfig::newcomer_window`] has passed with nobody claiming this Node ID, so
    /// that a duplicate is the error of the connect itself: for a node that runs for long (a
    /// board, a server), which must not start work it cannot finish.
    #[default]
    AfterNewcomerWindow,
    /// As soon as the alias is permitted and Initialization Complete is sent, as OpenMRN's
    /// nodes and tools do: a command starts its work one newcomer window sooner. A claim of
    /// this Node ID within the window then ends the running node with
    /// [`Error::DuplicateNodeId`], which whatever it is doing gets: for a short-lived tool.
    AtLogin,
}

/// The link's defaults, but room for one frame of its own (a Datagram Rejected, an AMD, an
/// OIR) for every frame of one read from the socket, however short: a burst of datagrams
/// from many nodes is answered in full before the driver sends (each frame causes at most
/// one); and a newcomer window of 100 ms, the wait before [`Node::connect`] returns unless
/// [`NodeOptions::join`] is [`Join::AtLogin`]. A node that has this Node ID answers the
/// global Verify Node ID within a few milliseconds, on the same hub or bus, through an
/// adapter too (500 ms made a firmware upgrade of 200 kB into OpenMRN's Bootloader 12% slower
/// than OpenMRN's own client, which waits for none). An answer later than that finds this
/// node joined: both nodes then report the duplicate and stay, as two that started together
/// do.
fn can_config() -> CanConfig {
    let mut can = CanConfig::default();
    can.frame_queue_limit = crate::driver::READ_CHUNK / crate::driver::SHORTEST_FRAME;
    can.newcomer_window = openlcb_stream::Duration::from_millis(100);
    can
}

impl NodeOptions {
    /// Defaults for the node `node_id`.
    pub fn new(node_id: NodeId) -> Self {
        NodeOptions {
            node_id,
            node: NodeConfig::default(),
            can: can_config(),
            connect_timeout: Duration::from_secs(5),
            write_timeout: Duration::from_secs(30),
            join: Join::AfterNewcomerWindow,
        }
    }
}

/// What a node has done so far.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
#[non_exhaustive]
pub struct NodeStats {
    /// Frames and bytes on the connection.
    pub wire: WireStats,
    /// The stream engine's counters of handled and refused input.
    pub endpoint: Stats,
    /// The node's own counters (routing, answers, datagrams).
    pub node: StackStats,
    /// Memory server events dropped because the application did not take them in time.
    pub memory_events_dropped: u64,
    /// Event notices lost, summed over the listeners (each one's
    /// [`EventNotices::dropped`]).
    pub event_notices_dropped: u64,
}

/// The longest [`Node::discover`] listens, however often nodes answer.
pub const DISCOVER_LIMIT: Duration = Duration::from_secs(30);

/// Requests from the handles to the driver task.
pub(crate) enum Command {
    Open {
        options: OpenOptions,
        sent: SentBytes,
        reply: oneshot::Sender<Result<(StreamHandle, StreamInfo), Error>>,
    },
    Write {
        handle: StreamHandle,
        data: Bytes,
        reply: oneshot::Sender<Result<(), Error>>,
    },
    Finish {
        handle: StreamHandle,
        reply: oneshot::Sender<Result<(), Error>>,
    },
    Abort {
        handle: StreamHandle,
        code: ErrorCode,
    },
    Read {
        handle: StreamHandle,
        reply: oneshot::Sender<Result<Option<Bytes>, Error>>,
    },
    Stats {
        reply: oneshot::Sender<NodeStats>,
    },
    /// This node's own Simple Node Information as it is now.
    OwnSnip {
        reply: oneshot::Sender<SnipInfo>,
    },
    /// Send Verify Node ID to everyone; forward every Verified Node ID to `sink`.
    Discover {
        sink: mpsc::Sender<NodeId>,
    },
    Snip {
        peer: NodeId,
        reply: oneshot::Sender<Result<SnipInfo, Error>>,
    },
    Protocols {
        peer: NodeId,
        reply: oneshot::Sender<Result<Protocols, Error>>,
    },
    AliasOf {
        node: NodeId,
        reply: oneshot::Sender<Option<u16>>,
    },
    Events(EventCommand),
    /// Broadcast Time: the node's clocks.
    Clock(ClockCommand),
    /// Traction: the node's train.
    Train(TrainCommand),
    /// Memory Configuration: serve spaces, or start a client operation.
    Memory(MemoryCommand),
}

/// Where the driver leaves the error it stopped with, for every handle to find.
#[derive(Debug, Default, Clone)]
pub(crate) struct Shared(Arc<Mutex<Option<Error>>>);

impl Shared {
    pub(crate) fn set(&self, error: Error) {
        if let Ok(mut slot) = self.0.lock() {
            slot.get_or_insert(error);
        }
    }

    /// The driver's final error, or [`Error::Closed`] if it stopped without one.
    pub(crate) fn error(&self) -> Error {
        self.0.lock().ok().and_then(|slot| slot.clone()).unwrap_or(Error::Closed)
    }
}

/// The link from a handle to the driver task.
#[derive(Debug, Clone)]
pub(crate) struct Control {
    pub(crate) commands: mpsc::Sender<Command>,
    pub(crate) shared: Shared,
}

impl Control {
    /// Sends a command and waits for its answer; a gone driver yields its final error.
    async fn call<T>(&self, command: impl FnOnce(oneshot::Sender<T>) -> Command) -> Result<T, Error> {
        let (reply, answer) = oneshot::channel();
        if self.commands.send(command(reply)).await.is_err() {
            return Err(self.shared.error());
        }
        answer.await.map_err(|_| self.shared.error())
    }
}

/// The error a driver stopped with, once it has finished stopping (it records the error
/// after it lets go of everything else).
async fn driver_error(driver: JoinHandle<()>, shared: &Shared) -> Error {
    let _ = tokio::time::timeout(Duration::from_secs(2), driver).await;
    shared.error()
}

/// A TCP connection to the first address `addr` (`host:port`) resolves to that answers.
pub(crate) async fn dial(addr: &str) -> std::io::Result<TcpStream> {
    let mut last = std::io::Error::new(std::io::ErrorKind::NotFound, "the name resolves to no address");
    for address in lookup_host(addr).await? {
        match connect_socket(address).await {
            Ok(socket) => return Ok(socket),
            Err(error) => last = error,
        }
    }
    Err(last)
}

/// A TCP connection to `address` with this crate's segment limit and keep-alive.
async fn connect_socket(address: std::net::SocketAddr) -> std::io::Result<TcpStream> {
    let socket = if address.is_ipv4() { tokio::net::TcpSocket::new_v4()? } else { tokio::net::TcpSocket::new_v6()? };
    crate::socket::limit_segments(&socket)?;
    let stream = socket.connect(address).await?;
    crate::socket::keep_alive(&stream)?;
    Ok(stream)
}

/// One OpenLCB node connected to a hub. A driver task runs its stack; this handle and its
/// streams talk to it through channels. The node keeps answering the network (Verify Node ID,
/// Protocol Support Inquiry, alias enquiries) as long as the handle or any stream lives.
///
/// ```no_run
/// use openlcb_stream::{NodeId, OpenOptions};
/// use openlcb_tokio::{Framing, Node, NodeOptions};
///
/// # async fn run() -> Result<(), openlcb_tokio::Error> {
/// let me: NodeId = "05.01.01.01.22.F0".parse().unwrap();
/// let peer: NodeId = "05.01.01.01.22.F1".parse().unwrap();
/// let node = Node::connect("127.0.0.1:12021", Framing::GridConnect, NodeOptions::new(me)).await?;
/// let mut stream = node.open(OpenOptions::new(peer, 2048)).await?; // Opened, or Rejected with its meaning
/// stream.write_all(&b"hello"[..]).await?;
/// stream.finish().await?;
/// # Ok(()) }
/// ```
#[derive(Debug)]
pub struct Node {
    node_id: NodeId,
    control: Control,
    incoming: mpsc::Receiver<RecvStream>,
    /// The driver task; `None` once [`closed`](Node::closed) saw it end (a finished task's
    /// handle must not be awaited again).
    driver: Option<JoinHandle<()>>,
}

impl Node {
    /// Connects to the hub at `addr` (`host:port`), logs in (on GridConnect: CAN alias
    /// reservation, about 200 ms) and sends Initialization Complete. Fails if the hub cannot be
    /// reached or the login does not finish within [`NodeOptions::connect_timeout`].
    pub async fn connect(addr: &str, protocol: Framing, options: NodeOptions) -> Result<Node, Error> {
        let connect_error =
            |source: std::io::Error| Error::Connect { addr: addr.to_string(), source: Arc::new(source) };
        let timeout = options.connect_timeout;
        let socket = tokio::time::timeout(timeout, dial(addr))
            .await
            .map_err(|_| connect_error(std::io::Error::new(std::io::ErrorKind::TimedOut, "no answer in time")))?
            .map_err(connect_error)?;
        // Small frames must not wait for Nagle's algorithm: the batching is done here.
        socket.set_nodelay(true).map_err(connect_error)?;
        Node::start(crate::io::tcp_halves(socket), addr, protocol, options).await.map_err(|error| match error {
            // A connection that breaks before the login is done never reached a hub (a
            // firewall or proxy that accepts and closes, a port that is not a hub).
            Error::ConnectionLost(source) => Error::Connect { addr: addr.to_string(), source },
            other => other,
        })
    }

    /// Runs a node over `stream`, any byte stream that carries `protocol` (a serial port to a
    /// USB GridConnect adapter, a pseudo-terminal, a `tokio::io::duplex`), logs in and sends
    /// Initialization Complete. Fails with [`Error::ConnectionLost`] if the stream ends before
    /// the login is done, or [`Error::Login`] if it does not finish within
    /// [`NodeOptions::connect_timeout`].
    ///
    /// ```
    /// use openlcb_tokio::{Framing, Node, NodeOptions};
    ///
    /// # #[tokio::main(flavor = "current_thread")]
    /// # async fn main() -> Result<(), openlcb_tokio::Error> {
    /// // Two nodes joined by an in-memory pipe, as if by a CAN bus.
    /// let (one, other) = tokio::io::duplex(64 * 1024);
    /// let id = |last| openlcb_tokio::NodeId::from_bytes([5, 1, 1, 1, 0x22, last]);
    /// let (a, b) = tokio::try_join!(
    ///     Node::over(one, Framing::GridConnect, NodeOptions::new(id(1))),
    ///     Node::over(other, Framing::GridConnect, NodeOptions::new(id(2))),
    /// )?;
    /// assert_eq!(a.discover(std::time::Duration::from_millis(500), 1).await?, vec![b.node_id()]);
    /// # Ok(()) }
    /// ```
    pub async fn over(stream: impl crate::ByteStream, protocol: Framing, options: NodeOptions) -> Result<Node, Error> {
        Node::start(crate::io::halves(stream), "a byte stream", protocol, options).await
    }

    /// Starts the driver on a connection's halves (`via` names the connection in logs) and
    /// waits for the login.
    async fn start(
        halves: (crate::io::ByteReader, crate::io::ByteWriter),
        via: &str,
        protocol: Framing,
        options: NodeOptions,
    ) -> Result<Node, Error> {
        let timeout = options.connect_timeout;
        let node_id = options.node_id;
        let shared = Shared::default();
        let (commands, command_rx) = mpsc::channel(64);
        let (incoming_tx, incoming) = mpsc::channel(options.node.stream.max_streams.max(1));
        let (up_tx, up) = oneshot::channel();
        let driver =
            Driver::new(halves, protocol, options, command_rx, commands.downgrade(), incoming_tx, shared.clone());
        let span = tracing::info_span!("node", %node_id, addr = via, ?protocol);
        let driver = tokio::spawn(driver.run(up_tx).instrument(span));
        let control = Control { commands, shared };
        match tokio::time::timeout(timeout, up).await {
            Ok(Ok(())) => Ok(Node { node_id, control, incoming, driver: Some(driver) }),
            Ok(Err(_)) => Err(driver_error(driver, &control.shared).await),
            Err(_) => {
                driver.abort();
                Err(Error::Login("the alias login did not finish in time"))
            }
        }
    }

    /// This node's Node ID.
    pub fn node_id(&self) -> NodeId {
        self.node_id
    }

    /// Asks `options.destination` for a stream and waits for its answer: the open stream, or
    /// [`Error::Rejected`] with the code (and its meaning), [`Error::Unreachable`],
    /// [`Error::TimedOut`].
    pub async fn open(&self, options: OpenOptions) -> Result<SendStream, Error> {
        let sent = SentBytes::default();
        let counter = sent.clone();
        let (handle, info) = self.control.call(|reply| Command::Open { options, sent: counter, reply }).await??;
        Ok(SendStream { handle, info, control: self.control.clone(), written: 0, sent, done: false })
    }

    /// The next stream another node opened to this one. Fails once the connection is gone
    /// (with the reason).
    pub async fn accept(&mut self) -> Result<RecvStream, Error> {
        self.incoming.recv().await.ok_or_else(|| self.control.shared.error())
    }

    /// Frame and stream counters.
    pub async fn stats(&self) -> Result<NodeStats, Error> {
        self.control.call(|reply| Command::Stats { reply }).await
    }

    /// This node's own Simple Node Information as it is now: a tool may have changed the user
    /// name and description (space 0xFB) since it connected, which the memory server reports as
    /// `MemoryEvent::UserInfoChanged`. A program that joins again after a lost connection
    /// passes this in its new [`NodeOptions`] to keep what the tool wrote.
    pub async fn own_snip(&self) -> Result<SnipInfo, Error> {
        self.control.call(|reply| Command::OwnSnip { reply }).await
    }

    /// Asks every node on the network who it is (global Verify Node ID) and returns the Node
    /// IDs that answer, in the order they answered. It stops `quiet` after the last answer,
    /// after `limit` answers, or after [`DISCOVER_LIMIT`] in all, whichever comes first.
    pub async fn discover(&self, quiet: Duration, limit: usize) -> Result<Vec<NodeId>, Error> {
        let (sink, mut answers) = mpsc::channel(limit.clamp(1, 1024));
        if self.control.commands.send(Command::Discover { sink }).await.is_err() {
            return Err(self.control.shared.error());
        }
        let give_up = tokio::time::Instant::now() + DISCOVER_LIMIT;
        let mut found = Vec::new();
        while found.len() < limit {
            let wait = quiet.min(give_up.saturating_duration_since(tokio::time::Instant::now()));
            match tokio::time::timeout(wait, answers.recv()).await {
                Ok(Some(node)) if !found.contains(&node) => found.push(node),
                Ok(Some(_)) => {}
                Ok(None) => return Err(self.control.shared.error()),
                Err(_) => break,
            }
        }
        Ok(found)
    }

    /// Asks `peer` for its Simple Node Information (the node's SNIP timeout applies). The
    /// question borrows nothing from the node, so many can run at once as tasks of their own.
    pub fn snip(&self, peer: NodeId) -> impl Future<Output = Result<SnipInfo, Error>> + Send + 'static {
        let control = self.control.clone();
        async move { control.call(|reply| Command::Snip { peer, reply }).await? }
    }

    /// Asks `peer` which protocols it supports, waiting at most `timeout` for the answer.
    pub async fn protocols(&self, peer: NodeId, timeout: Duration) -> Result<Protocols, Error> {
        match tokio::time::timeout(timeout, self.control.call(|reply| Command::Protocols { peer, reply })).await {
            Ok(answer) => answer?,
            Err(_) => Err(Error::NoAnswer { peer, what: "Protocol Support Inquiry" }),
        }
    }

    /// The CAN alias the node's link knows for `node`, this node's own included (always
    /// `None` over OpenLCB-TCP).
    pub async fn alias_of(&self, node: NodeId) -> Result<Option<u16>, Error> {
        self.control.call(|reply| Command::AliasOf { node, reply }).await
    }

    /// From now on, the event messages the node's
    /// [`EventConfig`](openlcb_node::EventConfig) lets through: every one the node receives
    /// after this returns is either taken from the listener or counted in its
    /// [`EventNotices::dropped`] (those it leaves waiting past
    /// [`EVENT_NOTICE_QUEUE`](crate::events::EVENT_NOTICE_QUEUE)).
    pub async fn event_notices(&self) -> Result<EventNotices, Error> {
        let (listening, registered) = oneshot::channel();
        let (command, notices) = EventCommand::listen(listening);
        self.control.commands.send(Command::Events(command)).await.map_err(|_| self.control.shared.error())?;
        registered.await.map_err(|_| self.control.shared.error())?;
        Ok(notices)
    }

    /// Sends a Producer/Consumer Event Report for `event`, with `payload` after it if not
    /// empty. [`Error::Busy`] while the node's transmit queue is full.
    pub async fn send_event(&self, event: EventId, payload: Vec<u8>) -> Result<(), Error> {
        self.control.call(|reply| Command::Events(EventCommand::Report { event, payload, reply })).await?
    }

    /// Sends Identify Events to every node (`None`) or one; the answers come out of
    /// [`event_notices`](Self::event_notices) when the node listens to everything.
    pub async fn identify_events(&self, peer: Option<NodeId>) -> Result<(), Error> {
        self.control.call(|reply| Command::Events(EventCommand::IdentifyEvents { peer, reply })).await?
    }

    /// Asks who produces or consumes `event` (Identify Producer or Identify Consumer).
    pub async fn identify(&self, role: EventRole, event: EventId) -> Result<(), Error> {
        self.control.call(|reply| Command::Events(EventCommand::Identify { role, event, reply })).await?
    }

    /// From now on, the changes of the node's clocks (declared in
    /// [`NodeOptions::node`](crate::NodeOptions::node)`.clocks`): minutes begun, sets, rate,
    /// start and stop.
    pub async fn clock_events(&self) -> Result<ClockEvents, Error> {
        let (listening, registered) = oneshot::channel();
        let (command, events) = ClockCommand::listen(listening);
        self.control.commands.send(Command::Clock(command)).await.map_err(|_| self.control.shared.error())?;
        registered.await.map_err(|_| self.control.shared.error())?;
        Ok(events)
    }

    /// Clock `clock` now (`None`: the node has no such clock).
    pub async fn clock(&self, clock: ClockId) -> Result<Option<ClockState>, Error> {
        self.control.call(|reply| Command::Clock(ClockCommand::State { clock, reply })).await
    }

    /// Changes clock `clock`: a generator of this node at once, a consumer's by the set
    /// command on the bus (see [`openlcb_node::Node::set_clock`]).
    pub async fn set_clock(&self, clock: ClockId, set: ClockSet) -> Result<(), Error> {
        let result = self.control.call(|reply| Command::Clock(ClockCommand::Set { clock, set, reply })).await?;
        result.map_err(crate::clock::clock_error)
    }

    /// Asks the generator of `clock` for its synchronization sequence.
    pub async fn query_clock(&self, clock: ClockId) -> Result<(), Error> {
        let result = self.control.call(|reply| Command::Clock(ClockCommand::Query { clock, reply })).await?;
        result.map_err(crate::clock::clock_error)
    }

    /// From now on, what the node's train (declared in
    /// [`NodeOptions::node`](crate::NodeOptions::node)`.train`) is told: speeds, functions,
    /// emergency stops, controllers, listeners, allocate searches.
    pub async fn train_events(&self) -> Result<TrainEvents, Error> {
        let (listening, registered) = oneshot::channel();
        let (command, events) = TrainCommand::listen(listening);
        self.control.commands.send(Command::Train(command)).await.map_err(|_| self.control.shared.error())?;
        registered.await.map_err(|_| self.control.shared.error())?;
        Ok(events)
    }

    /// The train's state (`None`: the node is no train).
    pub async fn train(&self) -> Result<Option<openlcb_node::traction::TrainState>, Error> {
        self.control.call(|reply| Command::Train(TrainCommand::State { reply })).await
    }

    /// The value of the train's function `address` (`None`: no train, or not kept).
    pub async fn train_function(&self, address: u32) -> Result<Option<u16>, Error> {
        self.control.call(|reply| Command::Train(TrainCommand::Function { address, reply })).await
    }

    /// Answers the Train Search `event` with Producer Identified Valid (a train created for
    /// it, see [`openlcb_node::Node::answer_train_search`]).
    pub async fn answer_train_search(&self, event: EventId) -> Result<(), Error> {
        let result = self.control.call(|reply| Command::Train(TrainCommand::AnswerSearch { event, reply })).await?;
        result.map_err(crate::train::train_error)
    }

    /// The train's address, protocol and name from now on (see
    /// [`openlcb_node::Node::set_train_identity`]): a configuration tool changed them.
    pub async fn set_train_identity(&self, identity: openlcb_node::traction::TrainIdentity) -> Result<(), Error> {
        let result = self.control.call(|reply| Command::Train(TrainCommand::SetIdentity { identity, reply })).await?;
        result.map_err(crate::train::train_error)
    }

    /// From now on, what trains answer the node's throttle (declared in
    /// [`NodeOptions::node`](crate::NodeOptions::node)`.throttle`).
    pub async fn throttle_events(&self) -> Result<ThrottleEvents, Error> {
        let (listening, registered) = oneshot::channel();
        let (command, events) = TrainCommand::listen_throttle(listening);
        self.control.commands.send(Command::Train(command)).await.map_err(|_| self.control.shared.error())?;
        registered.await.map_err(|_| self.control.shared.error())?;
        Ok(events)
    }

    /// Sends `command` to `train` as the node's throttle (see
    /// [`openlcb_node::Node::throttle_command`]).
    pub async fn throttle_command(
        &self,
        train: NodeId,
        command: openlcb_node::traction::TractionCommand,
    ) -> Result<(), Error> {
        let result =
            self.control.call(|reply| Command::Train(TrainCommand::Throttle { train, command, reply })).await?;
        result.map_err(crate::train::throttle_error)
    }

    /// Produces and consumes what `events` declares from now on (in place of
    /// [`NodeOptions::node`](crate::NodeOptions::node)`.events`), identifying every declaration
    /// at once: a board whose events a tool has configured (see
    /// [`openlcb_node::Node::set_events`]).
    pub async fn set_events(&self, events: EventConfig) -> Result<(), Error> {
        self.control.call(|reply| Command::Events(EventCommand::Declare { events, reply })).await?
    }

    /// Serves `server`'s address spaces from now on (Memory Configuration and, with space
    /// 0xEF, Firmware Upgrade in the PIP); what the server is asked to do that the
    /// application must carry out (Freeze, Unfreeze, Reset, a new user name...) comes out of
    /// the returned [`ServerEvents`]. Events the application leaves waiting past
    /// [`SERVER_EVENT_QUEUE`](crate::memory::SERVER_EVENT_QUEUE) are dropped and counted
    /// ([`NodeStats::memory_events_dropped`]).
    pub async fn set_memory_server(&self, server: MemoryServer) -> Result<ServerEvents, Error> {
        let (events, receiver) = mpsc::channel(SERVER_EVENT_QUEUE);
        let command = Command::Memory(MemoryCommand::Serve { server: Box::new(server), events });
        self.control.commands.send(command).await.map_err(|_| self.control.shared.error())?;
        Ok(ServerEvents::new(receiver))
    }

    /// Reads `len` bytes (`None`: to the end of the space) of `space` from `address` on
    /// `peer`, by `path`. The returned transfer shows the progress and ends with the bytes,
    /// or with [`Error::Memory`] (every step has a deadline, so it always ends).
    pub async fn read_memory(
        &self,
        peer: NodeId,
        space: u8,
        address: u32,
        len: Option<u32>,
        path: TransferPath,
    ) -> Result<MemoryTransfer<Vec<u8>>, Error> {
        let operation = Operation::Read { space, address, len };
        self.start_memory(peer, path, operation, read_bytes).await
    }

    /// Reads `space` of `peer` from address 0 up to its first NUL, as a CDI (space 0xFF)
    /// ends, taking at most `limit` bytes (at most the node's `max_read_len`); ends with the
    /// bytes before the NUL. A space whose reported size, or whose bytes, pass `limit` fails
    /// with [`MemoryError::SpaceTooLarge`](openlcb_node::MemoryError::SpaceTooLarge) at
    /// once; a node that does not answer Get Address Space Information is read until its
    /// answers end the space.
    pub async fn read_memory_to_nul(
        &self,
        peer: NodeId,
        space: u8,
        limit: u32,
        path: TransferPath,
    ) -> Result<MemoryTransfer<Vec<u8>>, Error> {
        self.start_memory(peer, path, Operation::ReadToNul { space, limit }, read_bytes).await
    }

    /// Writes `data` into `space` from `address` on `peer`, by `path`; ends with the count
    /// written.
    pub async fn write_memory(
        &self,
        peer: NodeId,
        space: u8,
        address: u32,
        data: impl Into<Bytes>,
        path: TransferPath,
    ) -> Result<MemoryTransfer<u64>, Error> {
        let operation = Operation::Write { space, address, data: data.into() };
        self.start_memory(peer, path, operation, written).await
    }

    /// Upgrades `peer`'s firmware with `image`: Freeze, the image into space 0xEF by stream
    /// or datagrams (`path`; `Auto` follows the target's PIP), Unfreeze. A target that
    /// reboots at Unfreeze has succeeded. Ends with the count written.
    pub async fn upgrade_firmware(
        &self,
        peer: NodeId,
        image: impl Into<Bytes>,
        path: TransferPath,
    ) -> Result<MemoryTransfer<u64>, Error> {
        self.start_memory(peer, path, Operation::Firmware { image: image.into() }, written).await
    }

    /// Sends `peer` Update Complete (`20 A8`), as a configuration tool does when it has
    /// finished writing, so that the node applies the changes; ends with 0 at its Datagram OK
    /// (or its restart).
    pub async fn update_complete(&self, peer: NodeId) -> Result<MemoryTransfer<u64>, Error> {
        self.send_command(peer, NodeCommand::UpdateComplete).await
    }

    /// Sends `peer` a [`NodeCommand`]: Update Complete, Reboot or Factory Reset. Ends with 0
    /// at its Datagram OK or at the node's restart (Initialization Complete), which is how
    /// many nodes answer a Reboot.
    pub async fn send_command(&self, peer: NodeId, command: NodeCommand) -> Result<MemoryTransfer<u64>, Error> {
        self.start_memory(peer, TransferPath::Datagrams, Operation::Command(command), written).await
    }

    async fn start_memory<T>(
        &self,
        peer: NodeId,
        path: TransferPath,
        operation: Operation,
        map: fn(Done) -> Option<T>,
    ) -> Result<MemoryTransfer<T>, Error> {
        let (progress, progress_rx) = watch::channel(0);
        let (reply, done) = oneshot::channel();
        let key = TransferKey::next();
        let command = Command::Memory(MemoryCommand::Start { key, peer, path, operation, progress, reply });
        self.control.commands.send(command).await.map_err(|_| self.control.shared.error())?;
        Ok(MemoryTransfer::new(key, progress_rx, done, &self.control, map))
    }

    /// Stops the node at once: the connection closes without a word to anyone, as if the
    /// program had crashed. Its streams fail with [`Error::Closed`]; peers find out by their
    /// own timeouts. (A node that is simply dropped stops once its last stream is done.)
    pub fn abort(self) {
        if let Some(driver) = &self.driver {
            driver.abort();
        }
    }

    /// Stops the node in an orderly way: whatever the driver still has to send (for example
    /// the Terminate Due To Error of streams just aborted) is written first, within about a
    /// second, then the connection closes. Drop or abort every stream first: the driver
    /// runs while any of them lives.
    pub async fn close(mut self) {
        self.incoming.close();
        let driver = self.driver.take();
        // Dropping the handle closes the command channel: the driver flushes and stops.
        drop(self);
        if let Some(driver) = driver {
            let _ = tokio::time::timeout(Duration::from_secs(2), driver).await;
        }
    }

    /// Waits until the driver stops (the connection was lost) and returns why.
    pub async fn closed(&mut self) -> Error {
        if let Some(driver) = &mut self.driver {
            let _ = driver.await;
            self.driver = None;
        }
        self.control.shared.error()
    }
}

/// The bytes of a read.
fn read_bytes(done: Done) -> Option<Vec<u8>> {
    match done {
        Done::Read(data) => Some(data),
        Done::Written(_) => None,
    }
}

/// The count of a write or an upgrade.
fn written(done: Done) -> Option<u64> {
    match done {
        Done::Written(len) => Some(len),
        Done::Read(_) => None,
    }
}

impl Drop for Node {
    fn drop(&mut self) {
        // Streams still open keep their own channel; the driver stops when the last one goes.
        self.incoming.close();
    }
}

/// The sending end of a stream this node opened.
#[derive(Debug)]
pub struct SendStream {
    handle: StreamHandle,
    info: StreamInfo,
    control: Control,
    written: u64,
    sent: SentBytes,
    done: bool,
}

/// The payload bytes of one [`SendStream`] handed to the transport in Data Send messages,
/// readable from anywhere, also once the stream is gone ([`SendStream::sent_bytes`]): after
/// an interruption or a failure, what the receiver can have got (never more; less if the
/// link lost some). The driver writes every message it has handed over before it closes.
#[derive(Debug, Clone, Default)]
pub struct SentBytes(Arc<AtomicU64>);

impl SentBytes {
    /// The count now.
    pub fn get(&self) -> u64 {
        self.0.load(Ordering::Relaxed)
    }

    pub(crate) fn add(&self, n: u64) {
        self.0.fetch_add(n, Ordering::Relaxed);
    }
}

impl SendStream {
    /// The negotiated parameters (destination, window, stream IDs, content UID).
    pub fn info(&self) -> &StreamInfo {
        &self.info
    }

    /// Bytes written so far: taken by [`write_all`](Self::write_all) calls that returned.
    pub fn written(&self) -> u64 {
        self.written
    }

    /// The bytes handed to the transport so far (also by a `write_all` still running), as a
    /// counter that outlives the stream.
    pub fn sent_bytes(&self) -> SentBytes {
        self.sent.clone()
    }

    /// Sends `data`, waiting while the window is used up or the socket is busy (so a slow
    /// receiver or a slow hub slows the caller). Returns once the driver has taken every byte.
    pub async fn write_all(&mut self, data: impl Into<Bytes>) -> Result<(), Error> {
        let data = data.into();
        let len = data.len() as u64;
        if len == 0 {
            return Ok(());
        }
        let handle = self.handle;
        let result = self.control.call(|reply| Command::Write { handle, data, reply }).await.and_then(|r| r);
        if result.is_err() {
            self.done = true;
        } else {
            self.written += len;
        }
        result
    }

    /// Sends Stream Data Complete with the byte count and waits until everything has been
    /// written to the socket. Returns the number of bytes sent.
    pub async fn finish(mut self) -> Result<u64, Error> {
        self.done = true;
        let handle = self.handle;
        self.control.call(|reply| Command::Finish { handle, reply }).await??;
        Ok(self.written)
    }

    /// Ends the stream at once with Terminate Due To Error 0x2000 (temporary error).
    pub fn abort(mut self) {
        self.send_abort();
    }

    fn send_abort(&mut self) {
        if !self.done {
            self.done = true;
            let _ = self.control.commands.try_send(Command::Abort { handle: self.handle, code: ErrorCode::TEMPORARY });
        }
    }
}

impl Drop for SendStream {
    /// A stream dropped before `finish` is aborted.
    fn drop(&mut self) {
        self.send_abort();
    }
}

/// The receiving end of a stream another node opened to this one.
#[derive(Debug)]
pub struct RecvStream {
    handle: StreamHandle,
    info: StreamInfo,
    control: Control,
    received: u64,
    done: bool,
}

impl RecvStream {
    pub(crate) fn new(handle: StreamHandle, info: StreamInfo, control: Control) -> Self {
        RecvStream { handle, info, control, received: 0, done: false }
    }

    /// Drops the handle without terminating the stream (the driver has already ended it).
    pub(crate) fn forget(mut self) {
        self.done = true;
    }

    /// Who sends, with the negotiated window and the content UID of the request.
    pub fn info(&self) -> &StreamInfo {
        &self.info
    }

    /// Bytes read so far.
    pub fn received(&self) -> u64 {
        self.received
    }

    /// The next piece of data; `Ok(None)` once the source has finished and every byte it
    /// counted has been read. Fails if the stream was terminated, timed out, its count did not
    /// match, or the connection was lost. Not reading slows the source down (no credit).
    pub async fn read(&mut self) -> Result<Option<Bytes>, Error> {
        if self.done {
            return Ok(None);
        }
        let handle = self.handle;
        let result = self.control.call(|reply| Command::Read { handle, reply }).await.and_then(|r| r);
        match &result {
            Ok(Some(data)) => self.received += data.len() as u64,
            Ok(None) | Err(_) => self.done = true,
        }
        result
    }

    /// Refuses the rest of the stream: Terminate Due To Error with `code` (0x2000 if unsure).
    pub fn abort(mut self, code: ErrorCode) {
        self.done = true;
        let _ = self.control.commands.try_send(Command::Abort { handle: self.handle, code });
    }
}

impl Drop for RecvStream {
    /// A stream dropped before its end is terminated (0x2000), so the source does not wait.
    fn drop(&mut self) {
        if !self.done {
            let _ = self.control.commands.try_send(Command::Abort { handle: self.handle, code: ErrorCode::TEMPORARY });
        }
    }
}
