//! The client side: reads, writes and firmware upgrades of another node's spaces, by
//! datagrams (64-byte chunks, one outstanding) and by streams, each an operation that ends
//! in one [`MemoryEvent`]. Without the `memory-client` feature the node starts no operation
//! and calls none of this: only the operation types stay in the API.
#![cfg_attr(not(feature = "memory-client"), allow(dead_code))]

use alloc::vec::Vec;

use openlcb_stream::wire::ErrorCode;
use openlcb_stream::{
    Duration, Event, Instant, Message, Mti, NodeId, OpenOptions, Role, StreamHandle, StreamId, Termination,
};

use super::wire::{Command, FailedKind, MAX_DATA_LEN, Reply, SPACE_FIRMWARE, codes};
use super::{MemoryError, MemoryEvent};
use crate::node::Cx;
use crate::node::Outputs;
use crate::service::ServiceChange;
use crate::{DatagramFailure, DatagramId, NodeEvent, OkFlags, Protocols};

/// Names one client operation ([`Node::read_memory`](crate::Node::read_memory) and the
/// others); its final [`MemoryEvent`] carries it.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct MemoryOperation(pub u32);

/// How often a finished stream transfer looks whether its last messages have left the
/// endpoint's queue, before the next step goes out behind them.
const STREAM_DRAIN_POLL: Duration = Duration::from_millis(1);

/// A command that asks a node to act on its configuration: one datagram, done at its
/// Datagram OK or at the node's restart (a node may reboot without an OK).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[non_exhaustive]
pub enum NodeCommand {
    /// Update Complete (MC §4.23): a tool has finished writing; the node applies what
    /// changed (the events it produces and consumes, say).
    UpdateComplete,
    /// Reset/Reboot (MC §4.24): the node restarts as at power-up.
    Reboot,
    /// Reinitialize/Factory Reset (MC §4.25): the node's configuration goes back to its
    /// defaults. The command names the node, so that a misaddressed one does nothing.
    FactoryReset,
}

impl NodeCommand {
    /// The command as `peer` receives it.
    fn to_wire(self, peer: NodeId) -> Command {
        match self {
            NodeCommand::UpdateComplete => Command::UpdateComplete,
            NodeCommand::Reboot => Command::Reset,
            NodeCommand::FactoryReset => Command::FactoryReset { node: peer.as_raw() },
        }
    }
}

/// How a client operation moves its bytes.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[non_exhaustive]
pub enum TransferPath {
    /// By stream when the node says it can (its Configuration Options for reads and writes,
    /// either bit of C-5; its PIP Stream bit for a firmware upgrade, FWU §5.5), by datagrams
    /// otherwise.
    #[default]
    Auto,
    /// Datagrams only (64-byte chunks).
    Datagrams,
    /// Stream only (Read Stream / Write Stream), no Options query first.
    Stream,
}

/// Why a client operation could not start.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
pub enum MemoryRequestError {
    /// [`MemoryConfigOptions::max_operations`](super::MemoryConfigOptions::max_operations)
    /// operations are running.
    #[error("too many memory operations are running")]
    TooMany,
    /// An operation with that node is running (its replies could not be told apart).
    #[error("an operation with that node is running")]
    Busy,
    /// The node is this node.
    #[error("a node cannot configure itself over the network")]
    SelfAddressed,
    /// A read longer than [`MemoryConfigOptions::max_read_len`](super::MemoryConfigOptions::max_read_len),
    /// or a write or image of 0 bytes or more than 4 GiB.
    #[error("the length is out of range")]
    BadLength,
    /// A stream path was asked for, and this node has streams off.
    #[error("streams are off on this node")]
    NoStreams,
}

#[derive(Debug)]
enum Kind {
    /// `len: None` reads to the end of the space; `reported`: `len` is the end the node
    /// itself reported (Get Address Space Info), not one the caller asked for. `limit`: the
    /// most bytes the read takes; `to_nul`: the read ends at the first NUL (a CDI), which
    /// is no part of the bytes handed over.
    Read {
        data: Vec<u8>,
        len: Option<u32>,
        reported: bool,
        limit: u32,
        to_nul: bool,
    },
    Write {
        data: Vec<u8>,
    },
    Firmware {
        image: Vec<u8>,
    },
    /// One command, done at its Datagram OK or the node's restart.
    Command(NodeCommand),
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Step {
    /// Get Configuration Options sent; its reply decides the path.
    Options,
    /// Get Address Space Information sent: a read to the end needs the size (a datagram
    /// read to know where to stop; any read to refuse a space larger than it may take
    /// before a byte moves), and a write of more than one command to refuse what does not fit.
    SpaceInfo { by_stream: bool },
    /// One datagram Read or Write of `len` bytes at offset `at` of the operation.
    Chunk { at: u32, len: u32 },
    /// Read Stream sent with `did` armed.
    ReadStream { did: StreamId, handle: Option<StreamHandle> },
    /// Write Stream sent with `sid`; the stream opens after the Datagram OK.
    WriteStream { sid: StreamId, handle: Option<StreamHandle>, sent: u64, finished: bool, replied: bool },
    /// Firmware: Freeze sent; waiting for OK or Initialization Complete (C-11).
    Freeze,
    /// Firmware: Protocol Support Inquiry sent; its Stream bit decides the path.
    Protocols,
    /// Firmware: Unfreeze sent; OK or a reboot ends the upgrade.
    Unfreeze,
    /// A [`NodeCommand`] sent; its Datagram OK or the node's restart ends the operation.
    Command(NodeCommand),
    /// Lock/Reserve sent before a write (MC §4.17), so that no other tool writes between
    /// its commands; the write goes on by stream or not as `by_stream` says.
    Lock { by_stream: bool },
}

#[derive(Debug)]
struct Operation {
    id: MemoryOperation,
    peer: NodeId,
    space: u8,
    address: u32,
    kind: Kind,
    path: TransferPath,
    step: Step,
    /// The command datagram waiting for its OK or Rejected.
    datagram: Option<DatagramId>,
    /// The OK came with Reply Pending: a reply datagram is due by `deadline`.
    awaiting_reply: bool,
    deadline: Option<Instant>,
    retries: u8,
    progress: u64,
    /// A Read Reply shorter than asked for, at (offset, length): trusted only once a second
    /// read says the same, since a CAN datagram that lost a middle frame looks just like one.
    short_reply: Option<(u32, usize)>,
    /// Lock/Reserve was asked for (a write asks once).
    lock_asked: bool,
    /// This node holds the peer's lock: released when the operation ends.
    locked: bool,
}

impl Kind {
    /// A whole-space read whose reported end is `end` (offset from the start).
    fn ends_at_reported(&self, end: u32) -> bool {
        matches!(self, Kind::Read { len: Some(len), reported: true, .. } if *len == end)
    }

    /// A read to the end of a space whose size the node did not give: it ends where the
    /// node's answers say the space ends.
    fn size_unknown(&self) -> bool {
        matches!(self, Kind::Read { len: None, .. })
    }

    /// A read of `len` bytes (`None`: to the end of the space), at most `limit`; `to_nul`:
    /// it ends at the first NUL.
    fn read(len: Option<u32>, limit: u32, to_nul: bool) -> Kind {
        Kind::Read { data: Vec::new(), len, reported: false, limit, to_nul }
    }
}

impl Operation {
    fn total(&self) -> u64 {
        match &self.kind {
            Kind::Read { len, .. } => len.map_or(0, u64::from),
            Kind::Write { data } => data.len() as u64,
            Kind::Firmware { image } => image.len() as u64,
            Kind::Command(_) => 0,
        }
    }

    fn payload(&self) -> &[u8] {
        match &self.kind {
            Kind::Write { data } => data,
            Kind::Firmware { image } => image,
            Kind::Read { .. } | Kind::Command(_) => &[],
        }
    }

    /// The server refused this operation's stream command for now (`code` temporary: no
    /// room for another stream transfer) before a byte moved, and the path is the client's
    /// choice ([`TransferPath::Auto`]): the same bytes can go by datagrams, which take no
    /// stream slot.
    fn may_go_by_datagrams(&self, code: ErrorCode) -> bool {
        let no_stream =
            matches!(self.step, Step::ReadStream { handle: None, .. } | Step::WriteStream { handle: None, .. });
        self.path == TransferPath::Auto && code.is_temporary() && no_stream && self.progress == 0 && self.total() > 0
    }

    fn stream_handle(&self) -> Option<StreamHandle> {
        match self.step {
            Step::ReadStream { handle, .. } | Step::WriteStream { handle, .. } => handle,
            _ => None,
        }
    }
}

/// Every operation this node runs as a Memory Configuration client.
#[derive(Debug, Default)]
pub(crate) struct MemoryClient {
    operations: Vec<Operation>,
    next_id: u32,
    next_stream: u8,
}

enum Outcome {
    Done,
    Fail(MemoryError),
}

/// What ends with `op`: its stream (terminated when `abort`, as for a failure) and the
/// node's lock it holds.
fn wind_up(cx: &mut Cx<'_>, op: &Operation, abort: bool) {
    if let (true, Some(handle)) = (abort, op.stream_handle()) {
        let _ = cx.streams.abort(cx.now, handle, ErrorCode::PERMANENT);
    }
    if op.locked {
        // Released once the last command is answered; its outcome needs nothing more.
        let _ = cx.send_datagram(op.peer, &Command::Lock { node: 0 }.to_bytes());
    }
}

/// The event that ends `op`.
fn final_event(op: Operation, outcome: Outcome) -> NodeEvent {
    let (operation, peer) = (op.id, op.peer);
    NodeEvent::Memory(match (outcome, op.kind) {
        (Outcome::Fail(error), _) => MemoryEvent::Failed { operation, peer, error },
        (Outcome::Done, Kind::Read { mut data, to_nul, .. }) => {
            if let Some(end) = data.iter().position(|&b| b == 0).filter(|_| to_nul) {
                data.truncate(end);
            }
            MemoryEvent::ReadDone { operation, peer, data }
        }
        (Outcome::Done, _) => MemoryEvent::WriteDone { operation, peer, len: op.progress },
    })
}

impl MemoryClient {
    pub(crate) fn has_operation_with(&self, peer: NodeId) -> bool {
        self.operations.iter().any(|o| o.peer == peer)
    }

    pub(crate) fn progress(&self, id: MemoryOperation) -> Option<u64> {
        self.operations.iter().find(|o| o.id == id).map(|o| o.progress)
    }

    pub(crate) fn wants_protocols(&self, peer: NodeId) -> bool {
        self.operations.iter().any(|o| o.peer == peer && o.step == Step::Protocols)
    }

    pub(crate) fn poll_timeout(&self) -> Option<Instant> {
        self.operations.iter().filter_map(|o| o.deadline).min()
    }

    // ----- starting -----

    pub(crate) fn read(
        &mut self,
        cx: &mut Cx<'_>,
        peer: NodeId,
        space: u8,
        address: u32,
        len: Option<u32>,
        path: TransferPath,
    ) -> Result<MemoryOperation, MemoryRequestError> {
        if len.is_some_and(|n| n == 0 || n > cx.options.max_read_len) {
            return Err(MemoryRequestError::BadLength);
        }
        let limit = cx.options.max_read_len;
        self.start(cx, peer, space, address, Kind::read(len, limit, false), path)
    }

    pub(crate) fn read_to_nul(
        &mut self,
        cx: &mut Cx<'_>,
        peer: NodeId,
        space: u8,
        limit: u32,
        path: TransferPath,
    ) -> Result<MemoryOperation, MemoryRequestError> {
        if limit == 0 || limit > cx.options.max_read_len {
            return Err(MemoryRequestError::BadLength);
        }
        self.start(cx, peer, space, 0, Kind::read(None, limit, true), path)
    }

    pub(crate) fn write(
        &mut self,
        cx: &mut Cx<'_>,
        peer: NodeId,
        space: u8,
        address: u32,
        data: Vec<u8>,
        path: TransferPath,
    ) -> Result<MemoryOperation, MemoryRequestError> {
        if data.is_empty() || u32::try_from(data.len()).is_err() {
            return Err(MemoryRequestError::BadLength);
        }
        self.start(cx, peer, space, address, Kind::Write { data }, path)
    }

    pub(crate) fn upgrade(
        &mut self,
        cx: &mut Cx<'_>,
        peer: NodeId,
        image: Vec<u8>,
        path: TransferPath,
    ) -> Result<MemoryOperation, MemoryRequestError> {
        if image.is_empty() || u32::try_from(image.len()).is_err() {
            return Err(MemoryRequestError::BadLength);
        }
        self.start(cx, peer, SPACE_FIRMWARE, 0, Kind::Firmware { image }, path)
    }

    pub(crate) fn command(
        &mut self,
        cx: &mut Cx<'_>,
        peer: NodeId,
        command: NodeCommand,
    ) -> Result<MemoryOperation, MemoryRequestError> {
        self.start(cx, peer, 0, 0, Kind::Command(command), TransferPath::Datagrams)
    }

    fn start(
        &mut self,
        cx: &mut Cx<'_>,
        peer: NodeId,
        space: u8,
        address: u32,
        kind: Kind,
        path: TransferPath,
    ) -> Result<MemoryOperation, MemoryRequestError> {
        if peer == cx.out.node {
            return Err(MemoryRequestError::SelfAddressed);
        }
        if path == TransferPath::Stream && !cx.streams_enabled() {
            return Err(MemoryRequestError::NoStreams);
        }
        if self.has_operation_with(peer) {
            return Err(MemoryRequestError::Busy);
        }
        if self.operations.len() >= cx.options.max_operations {
            return Err(MemoryRequestError::TooMany);
        }
        let id = MemoryOperation(self.next_id);
        self.next_id = self.next_id.wrapping_add(1);
        let firmware = matches!(kind, Kind::Firmware { .. });
        let command = match kind {
            Kind::Command(command) => Some(command),
            _ => None,
        };
        self.operations.push(Operation {
            id,
            peer,
            space,
            address,
            kind,
            path,
            step: Step::Options,
            datagram: None,
            awaiting_reply: false,
            deadline: None,
            retries: 0,
            progress: 0,
            short_reply: None,
            lock_asked: false,
            locked: false,
        });
        let index = self.operations.len() - 1;
        let outcome = match (path, command) {
            // FWU §5.5: Freeze first; the PIP asked after it decides the path.
            _ if firmware => self.send(cx, index, Step::Freeze, &Command::Freeze { space: SPACE_FIRMWARE }),
            (_, Some(command)) => self.send(cx, index, Step::Command(command), &command.to_wire(peer)),
            (TransferPath::Auto, None) if cx.streams_enabled() => {
                self.send(cx, index, Step::Options, &Command::GetOptions)
            }
            (TransferPath::Stream, None) => self.begin_transfer(cx, index, true),
            _ => self.begin_transfer(cx, index, false),
        };
        self.settle(cx, index, outcome);
        Ok(id)
    }

    /// Sends `command` as the operation's next step.
    fn send(&mut self, cx: &mut Cx<'_>, index: usize, step: Step, command: &Command) -> Option<Outcome> {
        let op = self.operations.get_mut(index)?;
        op.step = step;
        op.awaiting_reply = false;
        op.deadline = None;
        match cx.send_datagram(op.peer, &command.to_bytes()) {
            Some(id) => {
                op.datagram = Some(id);
                None
            }
            None => Some(Outcome::Fail(MemoryError::Rejected(codes::BUSY))),
        }
    }

    /// Starts moving bytes, by stream or by datagrams. A write of more than one command (or
    /// a stream) takes the node's lock first.
    fn begin_transfer(&mut self, cx: &mut Cx<'_>, index: usize, by_stream: bool) -> Option<Outcome> {
        let node = cx.out.node.as_raw();
        let op = self.operations.get_mut(index)?;
        let long_write = matches!(&op.kind, Kind::Write { data } if by_stream || data.len() > MAX_DATA_LEN);
        if long_write && !op.lock_asked {
            op.lock_asked = true;
            return self.send(cx, index, Step::Lock { by_stream }, &Command::Lock { node });
        }
        let space = op.space;
        let read_len = match &op.kind {
            Kind::Read { len, .. } => Some(*len),
            _ => None,
        };
        match (read_len, by_stream) {
            (Some(None), _) => self.send(cx, index, Step::SpaceInfo { by_stream }, &Command::GetSpaceInfo { space }),
            (Some(Some(_)), true) => self.read_stream(cx, index),
            (Some(Some(_)), false) => self.next_chunk(cx, index, 0),
            // A stream cannot say that its end fell outside the space (the Write Stream Reply
            // comes first), and datagrams would say it only after the commands that fit: for
            // a write of more than one command the space's size is asked for, and a write that
            // does not fit is refused before a byte goes out.
            _ if long_write => self.send(cx, index, Step::SpaceInfo { by_stream }, &Command::GetSpaceInfo { space }),
            (_, true) => self.write_stream(cx, index),
            (_, false) => self.next_chunk(cx, index, 0),
        }
    }

    /// Starts a write's bytes by stream or by datagrams, from its first byte.
    fn write_by(&mut self, cx: &mut Cx<'_>, index: usize, by_stream: bool) -> Option<Outcome> {
        if by_stream { self.write_stream(cx, index) } else { self.next_chunk(cx, index, 0) }
    }

    /// Moves the operation's bytes by datagrams after all, from its first byte.
    fn by_datagrams(&mut self, cx: &mut Cx<'_>, index: usize) -> Option<Outcome> {
        let op = self.operations.get_mut(index)?;
        op.awaiting_reply = false;
        op.retries = 0;
        self.next_chunk(cx, index, 0)
    }

    /// Sends Read Stream with a DID armed: the read's length, or to the end of the space
    /// (0xFFFFFFFF, C-6) when it has none of its own.
    fn read_stream(&mut self, cx: &mut Cx<'_>, index: usize) -> Option<Outcome> {
        let op = self.operations.get(index)?;
        let (peer, space, address) = (op.peer, op.space, op.address);
        let count = match &op.kind {
            Kind::Read { len: Some(len), reported: false, .. } => *len,
            _ => u32::MAX,
        };
        let did = self.free_stream_id(cx, peer, Role::Destination)?;
        let command = Command::ReadStream { space, address, destination_stream: did.as_raw(), count };
        self.send(cx, index, Step::ReadStream { did, handle: None }, &command)
    }

    /// Sends Write Stream; the stream opens after its Datagram OK.
    fn write_stream(&mut self, cx: &mut Cx<'_>, index: usize) -> Option<Outcome> {
        let op = self.operations.get(index)?;
        let (peer, space, address) = (op.peer, op.space, op.address);
        let sid = self.free_stream_id(cx, peer, Role::Source)?;
        let step = Step::WriteStream { sid, handle: None, sent: 0, finished: false, replied: false };
        self.send(cx, index, step, &Command::WriteStream { space, address, source_stream: sid.as_raw() })
    }

    /// A stream ID not in use with `peer` in `role` on this node's endpoint, rotating.
    fn free_stream_id(&mut self, cx: &Cx<'_>, peer: NodeId, role: Role) -> Option<StreamId> {
        let used: Vec<u8> = cx
            .streams
            .handles()
            .filter_map(|h| cx.streams.stream_info(h))
            .filter(|i| i.peer == peer && i.role == role)
            .filter_map(|i| match role {
                Role::Source => Some(i.source_stream.as_raw()),
                Role::Destination => i.destination_stream.map(StreamId::as_raw),
            })
            .collect();
        for _ in 0..255 {
            let candidate = self.next_stream;
            self.next_stream = if candidate >= 0xFE { 0 } else { candidate + 1 };
            if !used.contains(&candidate) {
                return StreamId::new(candidate);
            }
        }
        None
    }

    /// The datagram chunk at offset `at`, or the end of the transfer.
    fn next_chunk(&mut self, cx: &mut Cx<'_>, index: usize, at: u32) -> Option<Outcome> {
        let op = self.operations.get(index)?;
        let total = match op.kind {
            // Of unknown size: chunks until the node says the space ends, up to the limit.
            Kind::Read { len: None, limit, .. } if at >= limit => {
                return Some(Outcome::Fail(MemoryError::SpaceTooLarge { size: None, limit }));
            }
            Kind::Read { len: None, limit, .. } => limit,
            _ => u32::try_from(op.total()).unwrap_or(u32::MAX),
        };
        if at >= total {
            return self.transfer_done(cx, index);
        }
        let len = (total - at).min(MAX_DATA_LEN as u32);
        let address = op.address.saturating_add(at);
        let command = match &op.kind {
            Kind::Read { .. } => Command::Read { space: op.space, address, count: len as u8 },
            _ => {
                let data = op.payload().get(at as usize..(at + len) as usize).unwrap_or_default().to_vec();
                Command::Write { space: op.space, address, data }
            }
        };
        self.send(cx, index, Step::Chunk { at, len }, &command)
    }

    /// Every byte moved: a firmware upgrade goes on with Unfreeze; the rest are done.
    fn transfer_done(&mut self, cx: &mut Cx<'_>, index: usize) -> Option<Outcome> {
        let op = self.operations.get(index)?;
        if matches!(op.kind, Kind::Firmware { .. }) && op.step != Step::Unfreeze {
            return self.send(cx, index, Step::Unfreeze, &Command::Unfreeze { space: SPACE_FIRMWARE });
        }
        Some(Outcome::Done)
    }

    /// Ends the operation when `outcome` says so.
    fn settle(&mut self, cx: &mut Cx<'_>, index: usize, outcome: Option<Outcome>) {
        let Some(outcome) = outcome else { return };
        if index >= self.operations.len() {
            return;
        }
        let op = self.operations.swap_remove(index);
        wind_up(cx, &op, matches!(outcome, Outcome::Fail(_)));
        cx.out.event(final_event(op, outcome));
    }

    /// Ends operation `id` at once, with no event: its stream terminated, the node's lock
    /// released. A read hands over the bytes it has so far, in order from its address;
    /// any other operation an empty `Vec`. `None`: no such operation runs.
    pub(crate) fn cancel(&mut self, cx: &mut Cx<'_>, id: MemoryOperation) -> Option<Vec<u8>> {
        let index = self.operations.iter().position(|o| o.id == id)?;
        // What the stream has brought and the endpoint still holds is read too.
        let _ = self.drain_read(cx, index);
        let op = self.operations.swap_remove(index);
        wind_up(cx, &op, true);
        Some(match op.kind {
            Kind::Read { data, .. } => data,
            _ => Vec::new(),
        })
    }

    fn find(&self, peer: NodeId) -> Option<usize> {
        self.operations.iter().position(|o| o.peer == peer)
    }

    // ----- inputs -----

    /// The command datagram `id` was answered (OK or not); false when it is not ours.
    pub(crate) fn on_datagram_outcome(
        &mut self,
        cx: &mut Cx<'_>,
        id: DatagramId,
        result: Result<OkFlags, DatagramFailure>,
    ) -> bool {
        let Some(index) = self.operations.iter().position(|o| o.datagram == Some(id)) else { return false };
        let outcome = self.datagram_outcome(cx, index, result);
        self.settle(cx, index, outcome);
        true
    }

    fn datagram_outcome(
        &mut self,
        cx: &mut Cx<'_>,
        index: usize,
        result: Result<OkFlags, DatagramFailure>,
    ) -> Option<Outcome> {
        let reply_timeout = cx.options.reply_timeout;
        let reboot_timeout = cx.options.reboot_timeout;
        let op = self.operations.get_mut(index)?;
        op.datagram = None;
        let step = op.step;
        match (step, result) {
            // C-11: Freeze and Unfreeze succeed by OK or by the target restarting.
            (Step::Freeze, Ok(_) | Err(DatagramFailure::PeerRestarted)) => self.ask_protocols(cx, index),
            (Step::Unfreeze, Ok(_) | Err(DatagramFailure::PeerRestarted)) => Some(Outcome::Done),
            // MC §4.23: no reply datagram follows; the node may reset instead of an OK.
            (Step::Command(_), Ok(_) | Err(DatagramFailure::PeerRestarted)) => Some(Outcome::Done),
            (Step::Freeze | Step::Unfreeze, Err(DatagramFailure::TimedOut)) => {
                // The OpenMRN Bootloader sends no OK: wait on for its Initialization Complete.
                op.deadline = Some(cx.now + reboot_timeout);
                None
            }
            (Step::Chunk { at, len }, Ok(flags)) if !flags.reply_pending && !matches!(op.kind, Kind::Read { .. }) => {
                // C-9: a write done at once has no Write Reply.
                op.progress = u64::from(at.saturating_add(len));
                op.retries = 0;
                self.next_chunk(cx, index, at.saturating_add(len))
            }
            (Step::WriteStream { sid, .. }, Ok(flags)) => {
                // C-2: open the stream at once; the reply comes whenever it comes.
                let options = OpenOptions::new(op.peer, cx.options.stream_window.max(1)).source_stream(sid);
                match cx.streams.open(cx.now, options) {
                    Ok(handle) => {
                        if let Step::WriteStream { handle: slot, .. } = &mut op.step {
                            *slot = Some(handle);
                        }
                        op.awaiting_reply = flags.reply_pending;
                        op.deadline = Some(cx.now + cx.options.stream_timeout);
                        None
                    }
                    Err(_) => Some(Outcome::Fail(MemoryError::StreamRejected(codes::BUSY))),
                }
            }
            (Step::ReadStream { .. }, Ok(_)) => {
                op.awaiting_reply = true;
                op.deadline = Some(cx.now + cx.options.stream_timeout);
                None
            }
            (_, Ok(_)) => {
                op.awaiting_reply = true;
                op.deadline = Some(cx.now + reply_timeout);
                None
            }
            // A node without Get Address Space Information: the write goes ahead, and a space
            // error ends it (a stream with TDE, datagrams with the first command refused).
            (Step::SpaceInfo { by_stream }, Err(DatagramFailure::Rejected(_)))
                if matches!(op.kind, Kind::Write { .. }) =>
            {
                self.write_by(cx, index, by_stream)
            }
            // The same for a read to the end: a stream runs to the end of the space, datagrams
            // until the node says the space ends (an empty reply, out of bounds); past the
            // read's limit it is given up.
            (Step::SpaceInfo { by_stream }, Err(DatagramFailure::Rejected(_))) => {
                self.read_unknown_size(cx, index, by_stream)
            }
            (Step::Chunk { at, .. }, Err(DatagramFailure::Rejected(code)))
                if code == codes::OUT_OF_BOUNDS && op.kind.size_unknown() && at > 0 =>
            {
                Some(Outcome::Done)
            }
            // A node without Lock/Reserve (OpenMRN answers 0x1041): written without it.
            (Step::Lock { by_stream }, Err(DatagramFailure::Rejected(_))) => self.begin_transfer(cx, index, by_stream),
            (_, Err(DatagramFailure::Rejected(code))) if op.may_go_by_datagrams(code) => self.by_datagrams(cx, index),
            (_, Err(DatagramFailure::TimedOut)) => self.retry(cx, index),
            (_, Err(DatagramFailure::Rejected(code))) => Some(Outcome::Fail(MemoryError::Rejected(code))),
            (_, Err(DatagramFailure::PeerRestarted)) => Some(Outcome::Fail(MemoryError::PeerRestarted)),
            (_, Err(_)) => Some(Outcome::Fail(MemoryError::PeerLost)),
        }
    }

    /// Reads to the end of a space whose size the node does not give.
    fn read_unknown_size(&mut self, cx: &mut Cx<'_>, index: usize, by_stream: bool) -> Option<Outcome> {
        if by_stream { self.read_stream(cx, index) } else { self.next_chunk(cx, index, 0) }
    }

    fn ask_protocols(&mut self, cx: &mut Cx<'_>, index: usize) -> Option<Outcome> {
        let op = self.operations.get_mut(index)?;
        // A Freeze still waiting for its OK is answered by the restart: its outcome is moot.
        op.datagram = None;
        op.step = Step::Protocols;
        op.deadline = Some(cx.now + cx.options.reply_timeout);
        let inquiry = Message::addressed(Mti::PROTOCOL_SUPPORT_INQUIRY, cx.out.node, op.peer, Vec::new());
        cx.out.transmit(inquiry);
        None
    }

    /// The step's answer did not come: ask again (a lost reply, MC §4.4), or give up.
    fn retry(&mut self, cx: &mut Cx<'_>, index: usize) -> Option<Outcome> {
        let max = cx.options.max_retries;
        let op = self.operations.get_mut(index)?;
        if op.retries >= max {
            return Some(Outcome::Fail(MemoryError::TimedOut));
        }
        op.retries += 1;
        match op.step {
            Step::Options => self.send(cx, index, Step::Options, &Command::GetOptions),
            Step::SpaceInfo { by_stream } => {
                let space = op.space;
                self.send(cx, index, Step::SpaceInfo { by_stream }, &Command::GetSpaceInfo { space })
            }
            Step::Chunk { at, .. } => self.next_chunk(cx, index, at),
            Step::Protocols => self.ask_protocols(cx, index),
            Step::Command(command) => {
                let wire = command.to_wire(op.peer);
                self.send(cx, index, Step::Command(command), &wire)
            }
            Step::Lock { by_stream } => {
                let node = cx.out.node.as_raw();
                self.send(cx, index, Step::Lock { by_stream }, &Command::Lock { node })
            }
            _ => Some(Outcome::Fail(MemoryError::TimedOut)),
        }
    }

    /// A reply datagram from `peer` (already acknowledged by the node).
    pub(crate) fn on_reply(&mut self, cx: &mut Cx<'_>, peer: NodeId, bytes: &[u8]) {
        let Some(index) = self.find(peer) else { return };
        let Ok(reply) = Reply::parse(bytes) else { return };
        let outcome = self.reply_outcome(cx, index, reply);
        self.settle(cx, index, outcome);
    }

    fn reply_outcome(&mut self, cx: &mut Cx<'_>, index: usize, reply: Reply) -> Option<Outcome> {
        let node = cx.out.node.as_raw();
        let op = self.operations.get_mut(index)?;
        match (op.step, reply) {
            // An owner of 0 answers no Lock of ours (a late reply to our own release).
            (Step::Lock { .. }, Reply::Lock { owner: 0 }) => None,
            (Step::Lock { by_stream }, Reply::Lock { owner }) if owner == node => {
                op.locked = true;
                self.begin_transfer(cx, index, by_stream)
            }
            (Step::Lock { .. }, Reply::Lock { owner }) => Some(Outcome::Fail(MemoryError::Locked { owner })),
            (Step::Options, Reply::Options(options)) => {
                let by_stream = options.streams() && cx.streams_enabled();
                self.begin_transfer(cx, index, by_stream)
            }
            (Step::SpaceInfo { .. }, Reply::SpaceInfo(info)) if info.space != op.space => {
                Some(Outcome::Fail(MemoryError::WrongSpace { asked: op.space, answered: info.space }))
            }
            (Step::SpaceInfo { by_stream }, Reply::SpaceInfo(info)) => {
                let highest = info.highest_address.filter(|_| info.present);
                let Some(highest) = highest else {
                    // A read to the first NUL (a CDI) is read all the same: the node's answers
                    // to the reads say where the space ends, or that it has none (0x1081).
                    if matches!(op.kind, Kind::Read { to_nul: true, .. }) {
                        return self.read_unknown_size(cx, index, by_stream);
                    }
                    return Some(Outcome::Fail(MemoryError::Failed(codes::UNKNOWN_SPACE)));
                };
                // Bytes from the address to the end (up to 4 GiB: counted in 64 bits).
                let room = (u64::from(highest) + 1).checked_sub(u64::from(op.address)).filter(|&n| n > 0);
                if let Kind::Write { data } = &op.kind {
                    let fits = room.is_some_and(|room| data.len() as u64 <= room);
                    return if fits {
                        self.write_by(cx, index, by_stream)
                    } else {
                        Some(Outcome::Fail(MemoryError::Failed(codes::OUT_OF_BOUNDS)))
                    };
                }
                let Some(room) = room else {
                    return Some(Outcome::Fail(MemoryError::Failed(codes::OUT_OF_BOUNDS)));
                };
                // Refused before a byte moves: a whole read of a space larger than the limit.
                let limit = match op.kind {
                    Kind::Read { limit, .. } => limit,
                    _ => cx.options.max_read_len,
                };
                let Some(len) = u32::try_from(room).ok().filter(|&n| n <= limit) else {
                    return Some(Outcome::Fail(MemoryError::SpaceTooLarge { size: Some(room), limit }));
                };
                if let Kind::Read { len: want, reported, .. } = &mut op.kind {
                    *want = Some(len);
                    *reported = true;
                }
                if by_stream { self.read_stream(cx, index) } else { self.next_chunk(cx, index, 0) }
            }
            (Step::Chunk { at, .. }, Reply::ReadOk { space, address, .. })
                if space != op.space && address == op.address.saturating_add(at) =>
            {
                Some(Outcome::Fail(MemoryError::WrongSpace { asked: op.space, answered: space }))
            }
            (Step::Chunk { at, len }, Reply::ReadOk { address, data, .. })
                if address == op.address.saturating_add(at) =>
            {
                // MC §4.5: a reply may carry fewer bytes than asked for.
                let n = data.len().min(len as usize);
                if n < len as usize && op.short_reply != Some((at, n)) {
                    op.short_reply = Some((at, n));
                    return self.next_chunk(cx, index, at);
                }
                op.short_reply = None;
                if n == 0 {
                    // Twice nothing: the space ends here (a read of unknown size), or it does
                    // not hold what the read asked for.
                    return Some(if op.kind.size_unknown() {
                        Outcome::Done
                    } else {
                        Outcome::Fail(MemoryError::WrongLength { expected: op.total(), received: u64::from(at) })
                    });
                }
                let chunk = data.get(..n).unwrap_or_default();
                let mut ended = false;
                if let Kind::Read { data: buf, to_nul, .. } = &mut op.kind {
                    buf.extend_from_slice(chunk);
                    ended = *to_nul && chunk.contains(&0);
                }
                let next = at.saturating_add(n as u32);
                op.progress = u64::from(next);
                op.retries = 0;
                if ended { Some(Outcome::Done) } else { self.next_chunk(cx, index, next) }
            }
            (Step::Chunk { at, len }, Reply::WriteOk { address, .. }) if address == op.address.saturating_add(at) => {
                op.progress = u64::from(at.saturating_add(len));
                op.retries = 0;
                self.next_chunk(cx, index, at.saturating_add(len))
            }
            (Step::Chunk { at, len }, Reply::Failed { kind: FailedKind::Read, code, .. })
                if code == codes::OUT_OF_BOUNDS
                    && (op.kind.ends_at_reported(at.saturating_add(len)) || op.kind.size_unknown())
                    && at > 0 =>
            {
                // Liberal at the edge: a node that refuses the last address it reported itself
                // (OpenMRN's io_board: highest 0x157, 0x157 out of bounds) ends its space there,
                // as does one that gave no size.
                if let Kind::Read { len: want, .. } = &mut op.kind {
                    *want = Some(at);
                }
                Some(Outcome::Done)
            }
            (Step::ReadStream { .. } | Step::WriteStream { .. }, Reply::Failed { code, .. })
                if op.may_go_by_datagrams(code) =>
            {
                self.by_datagrams(cx, index)
            }
            (Step::Chunk { .. }, Reply::Failed { kind: FailedKind::Read | FailedKind::Write, code, .. })
            | (Step::ReadStream { .. }, Reply::Failed { kind: FailedKind::ReadStream, code, .. })
            | (Step::WriteStream { .. }, Reply::Failed { kind: FailedKind::WriteStream, code, .. }) => {
                Some(Outcome::Fail(MemoryError::Failed(code)))
            }
            (Step::ReadStream { .. }, Reply::ReadStreamOk { .. }) => {
                op.awaiting_reply = false;
                None
            }
            (Step::WriteStream { sid, handle, sent, finished, .. }, Reply::WriteStreamOk { .. }) => {
                op.step = Step::WriteStream { sid, handle, sent, finished, replied: true };
                op.awaiting_reply = false;
                if finished { self.transfer_done(cx, index) } else { None }
            }
            _ => None,
        }
    }

    /// `peer` sent Initialization Complete.
    pub(crate) fn peer_restarted(&mut self, cx: &mut Cx<'_>, peer: NodeId) {
        let Some(index) = self.find(peer) else { return };
        let outcome = match self.operations.get(index).map(|o| o.step) {
            // C-11: a Freeze answered by the target's restart (the OpenMRN Bootloader's way).
            Some(Step::Freeze) => self.ask_protocols(cx, index),
            // The Initialization Complete that follows our Freeze's OK: the inquiry sent after
            // the OK reaches the restarted target (a lost one is asked again at the deadline).
            Some(Step::Unfreeze | Step::Command(_)) => Some(Outcome::Done),
            // Streams and datagrams in flight end through their own events.
            _ => None,
        };
        self.settle(cx, index, outcome);
    }

    /// A Protocol Support Reply from `peer` while a firmware upgrade waits for it.
    pub(crate) fn on_protocols(&mut self, cx: &mut Cx<'_>, peer: NodeId, protocols: Protocols) {
        let Some(index) = self.find(peer) else { return };
        let Some(op) = self.operations.get_mut(index) else { return };
        if op.step != Step::Protocols {
            return;
        }
        op.deadline = None;
        let by_stream =
            protocols.contains(Protocols::STREAM) && op.path != TransferPath::Datagrams && cx.streams_enabled();
        let outcome = if op.path == TransferPath::Stream && !by_stream {
            Some(Outcome::Fail(MemoryError::NoStreams))
        } else {
            self.begin_transfer(cx, index, by_stream)
        };
        self.settle(cx, index, outcome);
    }

    /// A renamed peer's operations go on under its new name. A lost one's fail, nothing
    /// sent to it (its lock lapses by itself); their streams go to `ended` (the endpoint ends
    /// them itself).
    pub(crate) fn peer_changed(&mut self, out: &mut Outputs, ended: &mut Vec<StreamHandle>, change: ServiceChange) {
        for op in self.operations.iter_mut() {
            change.rename(&mut op.peer);
        }
        while let Some(index) = self.operations.iter().position(|o| change.loses(o.peer)) {
            let op = self.operations.swap_remove(index);
            if let Some(handle) = op.stream_handle() {
                ended.push(handle);
            }
            out.event(final_event(op, Outcome::Fail(MemoryError::PeerLost)));
        }
    }

    pub(crate) fn handle_timeout(&mut self, cx: &mut Cx<'_>) {
        while let Some(index) = self.operations.iter().position(|o| o.deadline.is_some_and(|d| d <= cx.now)) {
            let outcome = match self.operations.get_mut(index) {
                Some(op) => {
                    op.deadline = None;
                    match op.step {
                        Step::Freeze | Step::Unfreeze => Some(Outcome::Fail(MemoryError::TimedOut)),
                        Step::WriteStream { finished: true, replied: true, .. }
                            if cx.streams.sends_to_peer(op.peer) =>
                        {
                            op.deadline = Some(cx.now + STREAM_DRAIN_POLL);
                            None
                        }
                        Step::WriteStream { finished: true, replied: true, .. } => self.transfer_done(cx, index),
                        Step::ReadStream { .. } | Step::WriteStream { .. } => {
                            Some(Outcome::Fail(MemoryError::TimedOut))
                        }
                        _ => self.retry(cx, index),
                    }
                }
                None => None,
            };
            self.settle(cx, index, outcome);
        }
    }

    // ----- streams -----

    /// Takes a stream event of one of this client's transfers; false for any other.
    pub(crate) fn on_stream_event(&mut self, cx: &mut Cx<'_>, event: &Event) -> bool {
        if let Event::IncomingRequest { handle, info } = event {
            // C-4: the DID was armed before the Read Stream went out; the server's Initiate
            // Request may come before our command's OK.
            let armed = self.operations.iter_mut().find(|o| {
                o.peer == info.peer
                    && matches!(o.step, Step::ReadStream { did, handle: None } if Some(did) == info.destination_stream)
            });
            let Some(op) = armed else { return false };
            if cx.streams.accept(cx.now, *handle, None).is_ok() {
                if let Step::ReadStream { handle: slot, .. } = &mut op.step {
                    *slot = Some(*handle);
                }
                op.deadline = Some(cx.now + cx.options.stream_timeout);
            }
            return true;
        }
        if let Event::Opened { handle, info } = event {
            // With `AcceptAll` the endpoint accepted the server's request itself.
            let armed = self.operations.iter_mut().find(|o| {
                info.role == Role::Destination
                    && o.peer == info.peer
                    && matches!(o.step, Step::ReadStream { did, handle: None } if Some(did) == info.destination_stream)
            });
            if let Some(op) = armed {
                if let Step::ReadStream { handle: slot, .. } = &mut op.step {
                    *slot = Some(*handle);
                }
                op.deadline = Some(cx.now + cx.options.stream_timeout);
                return true;
            }
        }
        if matches!(event, Event::IncomingRequest { .. } | Event::Sent { .. }) {
            return false;
        }
        let handle = event.handle();
        let Some(index) = self.operations.iter().position(|o| o.stream_handle() == Some(handle)) else {
            return false;
        };
        let stream_timeout = cx.options.stream_timeout;
        if let Some(op) = self.operations.get_mut(index) {
            op.deadline = Some(cx.now + stream_timeout);
        }
        let outcome = match event {
            Event::Opened { .. } | Event::Writable { .. } => self.pump_write(cx, index),
            Event::Readable { .. } => self.drain_read(cx, index),
            Event::Finished { total, stated, matched, .. } => {
                let drained = self.drain_read(cx, index);
                // Bytes lost on the way (or a Complete that counts otherwise) fail the read.
                let stated = stated.filter(|_| !matched);
                drained.or_else(|| self.read_finished(index, *total, stated))
            }
            Event::Rejected { code, .. } => Some(Outcome::Fail(MemoryError::StreamRejected(ErrorCode(code.0)))),
            Event::Terminated { cause, .. } => Some(Outcome::Fail(match cause {
                Termination::ByPeer(code) => MemoryError::StreamEnded(*code),
                Termination::PeerRestarted => MemoryError::PeerRestarted,
                Termination::PeerLost | Termination::LinkLost => MemoryError::PeerLost,
                _ => MemoryError::StreamEnded(ErrorCode::PERMANENT),
            })),
            Event::TimedOut { kind, .. } => Some(Outcome::Fail(MemoryError::StreamTimedOut(*kind))),
            _ => None,
        };
        self.settle(cx, index, outcome);
        true
    }

    fn drain_read(&mut self, cx: &mut Cx<'_>, index: usize) -> Option<Outcome> {
        let op = self.operations.get_mut(index)?;
        let handle = op.stream_handle()?;
        let Kind::Read { data, len, limit, to_nul, .. } = &mut op.kind else { return None };
        let most = len.unwrap_or(*limit) as usize;
        let mut buf = [0u8; 512];
        loop {
            let n = cx.streams.read(cx.now, handle, &mut buf).unwrap_or(0);
            if n == 0 {
                break;
            }
            if data.len().saturating_add(n) > most {
                if *to_nul && data.contains(&0) {
                    // The document has ended; what the stream still brings is no part of it.
                    let _ = cx.streams.abort(cx.now, handle, ErrorCode::PERMANENT);
                    return Some(Outcome::Done);
                }
                // More than asked for, or than the space holds by the node's own report; a
                // read of unknown size (no Get Address Space Information) ran past the limit.
                return Some(Outcome::Fail(match len {
                    Some(len) => MemoryError::Overrun { expected: u64::from(*len) },
                    None => MemoryError::SpaceTooLarge { size: None, limit: *limit },
                }));
            }
            data.extend_from_slice(buf.get(..n).unwrap_or_default());
        }
        op.progress = data.len() as u64;
        None
    }

    /// The stream of a read ended with `total` bytes; `mismatch`: the count its Complete
    /// stated, when that differs. A read to the end of the space may end before the end the
    /// node reported (a node whose last reported address is not served, as by datagrams).
    fn read_finished(&mut self, index: usize, total: u64, mismatch: Option<u64>) -> Option<Outcome> {
        let op = self.operations.get(index)?;
        let Kind::Read { data, len, reported, .. } = &op.kind else { return None };
        let received = data.len() as u64;
        if let Some(stated) = mismatch {
            return Some(Outcome::Fail(MemoryError::CountMismatch { stated, received }));
        }
        match len {
            Some(want) if *reported && received <= u64::from(*want) && received == total && received > 0 => {
                Some(Outcome::Done)
            }
            Some(want) if u64::from(*want) != received || received != total => {
                Some(Outcome::Fail(MemoryError::WrongLength { expected: u64::from(*want), received }))
            }
            _ if received != total => Some(Outcome::Fail(MemoryError::WrongLength { expected: total, received })),
            // MC §4.7: a transfer is complete when the stream closes after at least one byte.
            _ if received == 0 => Some(Outcome::Fail(MemoryError::WrongLength { expected: 1, received })),
            _ => Some(Outcome::Done),
        }
    }

    /// Writes what the credit allows; once every byte is out and the last window has been
    /// acknowledged (FWU §5.4.1), finishes the stream.
    fn pump_write(&mut self, cx: &mut Cx<'_>, index: usize) -> Option<Outcome> {
        let op = self.operations.get_mut(index)?;
        let Step::WriteStream { sid, handle: Some(handle), sent, finished: false, replied } = op.step else {
            return None;
        };
        let payload: &[u8] = match &op.kind {
            Kind::Write { data } => data,
            Kind::Firmware { image } => image,
            Kind::Read { .. } | Kind::Command(_) => return None,
        };
        let mut sent = sent;
        while let Some(rest) = payload.get(sent as usize..).filter(|r| !r.is_empty()) {
            let taken = cx.streams.write(cx.now, handle, rest).unwrap_or(0);
            if taken == 0 {
                break;
            }
            sent = sent.saturating_add(taken as u64);
        }
        op.progress = sent;
        let all_out = sent >= payload.len() as u64;
        let acknowledged = cx.streams.credit(handle).is_some_and(|c| c > 0);
        let finished = all_out && acknowledged && cx.finish_stream(handle);
        op.step =
            Step::WriteStream { sid, handle: if finished { None } else { Some(handle) }, sent, finished, replied };
        if !finished {
            return None;
        }
        if replied {
            // The next step (Unfreeze) waits until the Complete has left the endpoint's queue
            // (`handle_timeout`): the node's own messages go before the streams', and an
            // Unfreeze ahead of the last data would end the upgrade without it.
            op.deadline = Some(cx.now);
            return None;
        }
        // C-2: the reply may come after the stream; wait for it as for a datagram reply.
        op.awaiting_reply = true;
        op.deadline = Some(cx.now + cx.options.reply_timeout);
        None
    }

    /// Streams whose last window may have been acknowledged since: finish them.
    pub(crate) fn poll_streams(&mut self, cx: &mut Cx<'_>) {
        let mut index = 0;
        while index < self.operations.len() {
            let waiting = self.operations.get(index).is_some_and(|o| {
                matches!(o.step, Step::WriteStream { handle: Some(h), sent, finished: false, .. }
                    if sent >= o.payload().len() as u64 && cx.streams.credit(h).is_some_and(|c| c > 0))
            });
            if waiting {
                let outcome = self.pump_write(cx, index);
                let before = self.operations.len();
                self.settle(cx, index, outcome);
                if self.operations.len() < before {
                    continue;
                }
            }
            index += 1;
        }
    }
}
