//! Memory Configuration on a [`Node`](crate::Node): serving address spaces
//! ([`Node::set_memory_server`](crate::Node::set_memory_server)) and reading, writing and upgrading
//! the spaces of other nodes ([`Node::read_memory`](crate::Node::read_memory),
//! [`Node::write_memory`](crate::Node::write_memory),
//! [`Node::upgrade_firmware`](crate::Node::upgrade_firmware)).
//!
//! The protocol is [`openlcb_node::memconfig`]'s; the driver runs it and tells each waiting
//! handle how its operation ended. Every wait ends: the sans-IO client gives each step a
//! deadline ([`MemoryConfigOptions`](openlcb_node::MemoryConfigOptions): reply, stream and
//! reboot waits), and a driver that stops fails every operation with its reason.

use std::sync::atomic::{AtomicU64, Ordering};

use bytes::Bytes;
use openlcb_node::{
    MemoryError, MemoryEvent, MemoryOperation, MemoryRequestError, MemoryServer, NodeCommand, TransferPath,
};
use openlcb_stream::wire::ErrorCode;
use openlcb_stream::{Instant, NodeId};
use tokio::sync::{mpsc, oneshot, watch};

use crate::Error;

/// Server events queued for the application before more are dropped (and counted).
pub const SERVER_EVENT_QUEUE: usize = 64;

/// What a node serving memory spaces was asked to do, for the application to carry out,
/// from [`Node::set_memory_server`](crate::Node::set_memory_server): the server's variants of
/// [`MemoryEvent`] (`Frozen`, `Unfrozen` with the image's length, `UpdateComplete`,
/// `ResetRequested`, `FactoryResetRequested`, `UserInfoChanged`).
#[derive(Debug)]
pub struct ServerEvents {
    events: mpsc::Receiver<MemoryEvent>,
}

impl ServerEvents {
    pub(crate) fn new(events: mpsc::Receiver<MemoryEvent>) -> Self {
        ServerEvents { events }
    }

    /// The next event; `None` once the node has stopped.
    pub async fn next(&mut self) -> Option<MemoryEvent> {
        self.events.recv().await
    }
}

/// What a client operation is asked to do.
#[derive(Debug, Clone)]
pub(crate) enum Operation {
    Read { space: u8, address: u32, len: Option<u32> },
    ReadToNul { space: u8, limit: u32 },
    Write { space: u8, address: u32, data: Bytes },
    Firmware { image: Bytes },
    Command(NodeCommand),
}

/// How a client operation ended well: the bytes read, or the count written.
#[derive(Debug)]
pub(crate) enum Done {
    Read(Vec<u8>),
    Written(u64),
}

type DoneReply = oneshot::Sender<Result<Done, Error>>;

/// Requests of the handles to the driver's Memory Configuration.
#[derive(Debug)]
pub(crate) enum MemoryCommand {
    Serve {
        server: Box<MemoryServer>,
        events: mpsc::Sender<MemoryEvent>,
    },
    Start {
        key: TransferKey,
        peer: NodeId,
        path: TransferPath,
        operation: Operation,
        progress: watch::Sender<u64>,
        reply: DoneReply,
    },
    /// Ends the operation of `key` at once; `reply` gets a read's bytes so far (`None`: it
    /// had ended).
    Cancel {
        key: TransferKey,
        reply: oneshot::Sender<Option<Vec<u8>>>,
    },
}

/// Names one [`MemoryTransfer`] between its handle and the driver, unique in the process.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) struct TransferKey(u64);

impl TransferKey {
    /// A key no other transfer has.
    pub(crate) fn next() -> Self {
        static NEXT: AtomicU64 = AtomicU64::new(0);
        TransferKey(NEXT.fetch_add(1, Ordering::Relaxed))
    }
}

/// A client operation running, from the handle's point of view: progress now, and the end
/// (or [`cancel`](Self::cancel) it). Like a stream, it keeps the node's driver running
/// while it lives.
#[derive(Debug)]
pub struct MemoryTransfer<T> {
    key: TransferKey,
    progress: watch::Receiver<u64>,
    done: oneshot::Receiver<Result<Done, Error>>,
    commands: mpsc::Sender<crate::node::Command>,
    shared: crate::node::Shared,
    map: fn(Done) -> Option<T>,
}

impl<T> MemoryTransfer<T> {
    pub(crate) fn new(
        key: TransferKey,
        progress: watch::Receiver<u64>,
        done: oneshot::Receiver<Result<Done, Error>>,
        control: &crate::node::Control,
        map: fn(Done) -> Option<T>,
    ) -> Self {
        let (commands, shared) = (control.commands.clone(), control.shared.clone());
        MemoryTransfer { key, progress, done, commands, shared, map }
    }

    /// Bytes moved so far (read, or written and acknowledged by credit or reply).
    pub fn progress(&self) -> u64 {
        *self.progress.borrow()
    }

    /// A watch of the progress, to await its changes beside [`finish`](Self::finish); it
    /// closes when the operation ends.
    pub fn watch_progress(&self) -> watch::Receiver<u64> {
        self.progress.clone()
    }

    /// Waits for the end: the bytes read (for a read) or the count written.
    pub async fn finish(mut self) -> Result<T, Error> {
        self.wait().await
    }

    /// Waits for the end, as [`finish`](Self::finish) does, keeping the handle: a wait
    /// dropped before its end (beside a Ctrl-C in a `select!`) leaves the transfer to
    /// [`cancel`](Self::cancel). Wait no more once it has returned.
    pub async fn wait(&mut self) -> Result<T, Error> {
        match (&mut self.done).await {
            Ok(Ok(done)) => (self.map)(done).ok_or(Error::Closed),
            Ok(Err(error)) => Err(error),
            Err(_) => Err(self.shared.error()),
        }
    }

    /// Ends the operation at once (its stream terminated, the node's lock released) and
    /// hands over the bytes a read had received so far, in order from its address; a write
    /// or an upgrade hands over none. A read that ended meanwhile hands over all its bytes.
    /// Call it only before a [`wait`](Self::wait) has returned.
    pub async fn cancel(self) -> Vec<u8> {
        let (reply, answer) = oneshot::channel();
        let command = crate::node::Command::Memory(MemoryCommand::Cancel { key: self.key, reply });
        if self.commands.send(command).await.is_ok()
            && let Ok(Some(data)) = answer.await
        {
            return data;
        }
        match self.done.await {
            Ok(Ok(Done::Read(data))) => data,
            _ => Vec::new(),
        }
    }
}

struct Running {
    key: TransferKey,
    operation: MemoryOperation,
    progress: watch::Sender<u64>,
    reply: DoneReply,
}

/// The driver's part: operations waiting for their end, and where server events go.
#[derive(Default)]
pub(crate) struct MemoryDriver {
    running: Vec<Running>,
    events: Option<mpsc::Sender<MemoryEvent>>,
    /// Server events dropped because the application did not take them.
    dropped: u64,
}

impl MemoryDriver {
    pub(crate) fn command(&mut self, now: Instant, stack: &mut openlcb_node::Node, command: MemoryCommand) {
        match command {
            MemoryCommand::Serve { server, events } => {
                stack.set_memory_server(*server);
                self.events = Some(events);
            }
            MemoryCommand::Cancel { key, reply } => {
                let data = match self.running.iter().position(|r| r.key == key) {
                    Some(index) => stack.cancel_memory(now, self.running.swap_remove(index).operation),
                    None => None,
                };
                let _ = reply.send(data);
            }
            MemoryCommand::Start { key, peer, path, operation, progress, reply } => {
                let started = match operation {
                    Operation::Read { space, address, len } => stack.read_memory(now, peer, space, address, len, path),
                    Operation::ReadToNul { space, limit } => stack.read_memory_to_nul(now, peer, space, limit, path),
                    Operation::Write { space, address, data } => {
                        stack.write_memory(now, peer, space, address, data, path)
                    }
                    Operation::Firmware { image } => stack.upgrade_firmware(now, peer, image, path),
                    Operation::Command(command) => stack.send_command(now, peer, command),
                };
                match started {
                    Ok(operation) => self.running.push(Running { key, operation, progress, reply }),
                    Err(error) => {
                        let _ = reply.send(Err(Error::MemoryRequest(error)));
                    }
                }
            }
        }
    }

    /// Takes a Memory Configuration event of the node.
    pub(crate) fn event(&mut self, event: MemoryEvent) {
        let (operation, result) = match event {
            MemoryEvent::ReadDone { operation, data, .. } => (operation, Ok(Done::Read(data))),
            MemoryEvent::WriteDone { operation, len, .. } => (operation, Ok(Done::Written(len))),
            MemoryEvent::Failed { operation, peer, error } => (operation, Err(memory_error(peer, error))),
            server => {
                let sent = self.events.as_ref().is_some_and(|events| events.try_send(server).is_ok());
                self.dropped += u64::from(!sent);
                return;
            }
        };
        if let Some(index) = self.running.iter().position(|r| r.operation == operation) {
            let running = self.running.swap_remove(index);
            if let Ok(Done::Written(len)) = &result {
                running.progress.send_replace(*len);
            }
            let _ = running.reply.send(result);
        }
    }

    /// Publishes each running operation's progress (only what changed wakes a watcher).
    pub(crate) fn publish_progress(&self, stack: &openlcb_node::Node) {
        for running in &self.running {
            if let Some(now) = stack.memory_progress(running.operation) {
                running.progress.send_if_modified(|shown| std::mem::replace(shown, now) != now);
            }
        }
    }

    /// Server events dropped because the application's queue was full or gone.
    pub(crate) fn dropped(&self) -> u64 {
        self.dropped
    }
}

/// A failed operation as this crate's error.
fn memory_error(peer: NodeId, error: MemoryError) -> Error {
    Error::Memory { peer, error }
}

/// Words for a person, one per [`MemoryError`].
pub(crate) fn memory_error_text(peer: NodeId, error: MemoryError) -> String {
    match error {
        MemoryError::Rejected(code) => {
            format!("node {peer} refused the command: {code} ({})", memory_code_meaning(code))
        }
        MemoryError::Failed(code) => format!("node {peer} failed the command: {code} ({})", memory_code_meaning(code)),
        MemoryError::TimedOut => format!("node {peer} did not answer the Memory Configuration command in time"),
        MemoryError::StreamRejected(code) => format!("node {peer} refused the stream: {code} ({})", code.meaning()),
        MemoryError::StreamEnded(code) => {
            format!("the stream with node {peer} ended early: {code} ({})", memory_code_meaning(code))
        }
        MemoryError::StreamTimedOut(_) => format!("the stream with node {peer} stalled"),
        MemoryError::WrongLength { expected, received } => {
            format!("node {peer} sent {received} bytes where {expected} were expected")
        }
        MemoryError::CountMismatch { stated, received } => format!(
            "the stream from node {peer} ended with a Data Complete stating {stated} bytes after {received} had \
             arrived (bytes lost on the way, or a wrong count); nothing read was kept"
        ),
        MemoryError::Overrun { expected } => {
            format!(
                "node {peer} sent more than {expected} bytes, the most asked for (the length, or the size its space \
                 has by its own report); nothing read was kept"
            )
        }
        MemoryError::WrongSpace { asked, answered } => {
            format!("node {peer} answered for space 0x{answered:02X} where space 0x{asked:02X} was asked for")
        }
        MemoryError::SpaceTooLarge { size: Some(size), limit } => format!(
            "the space of node {peer} holds {size} bytes from that address, more than the {limit} one read takes"
        ),
        MemoryError::SpaceTooLarge { size: None, limit } => {
            format!(
                "the space of node {peer} holds more than the {limit} bytes one read takes (it gave no size, and its \
                 bytes went on past that)"
            )
        }
        MemoryError::PeerRestarted => format!("node {peer} restarted in the middle of the operation"),
        MemoryError::PeerLost => format!("node {peer} left the network"),
        MemoryError::BadReply => format!("node {peer} answered with a reply that does not fit the command"),
        MemoryError::NoStreams => format!("node {peer} does not support streams"),
        MemoryError::Locked { owner } => {
            let owner = NodeId::new(owner).map_or_else(|| format!("{owner:012X}"), |id| id.to_string());
            format!("node {peer} is locked by {owner}, which is writing it")
        }
        _ => format!("the Memory Configuration operation with node {peer} failed"),
    }
}

/// What an error code means in a Memory Configuration or Firmware Upgrade reply: the
/// detail codes of MC §4.3 and FWU, then the general codes of the Message Network standard.
pub fn memory_code_meaning(code: ErrorCode) -> &'static str {
    match code.0 {
        0x1081 => "address space unknown",
        0x1082 => "out of bounds: the space does not reach that address",
        0x1083 => "write to a read-only space",
        0x1088 => "firmware incompatible with this hardware",
        0x1089 => "firmware invalid or corrupted",
        0x2088 => "firmware failed its checksum; send it again",
        _ => code.meaning(),
    }
}

/// Words for a person, one per [`MemoryRequestError`].
pub(crate) fn request_error_text(error: MemoryRequestError) -> String {
    format!("the Memory Configuration operation cannot start: {error}")
}
