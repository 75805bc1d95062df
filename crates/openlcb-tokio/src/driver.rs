//! The driver task of a [`Node`](crate::Node): it owns the connection (any byte stream), the
//! sans-IO node and the link, and runs the sans-IO drive loop (handle input, drain outputs, arm the timer) between
//! the socket, the clock and the handles' commands.

use std::collections::HashMap;

use bytes::{Bytes, BytesMut};
use openlcb_node::{NodeEvent, SnipRequestError};
use openlcb_stream::wire::ErrorCode;
use openlcb_stream::{Event, Instant, NodeId, Role, StreamError, StreamHandle, StreamInfo};
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::sync::{mpsc, oneshot};

use crate::clock::ClockDriver;
use crate::events::EventDriver;
use crate::io::{ByteReader, ByteWriter, try_write};
use crate::memory::MemoryDriver;
use crate::node::{Command, Control, Join, NodeStats, SentBytes, Shared};
use crate::requests::Requests;
use crate::train::TrainDriver;
use crate::wire::{Wire, WireStats};
use crate::{Error, Framing, NodeOptions, RecvStream};

/// Bytes read from the socket at once.
pub(crate) const READ_CHUNK: usize = 64 * 1024;
/// The shortest GridConnect frame, `:X00000000N;`: so many bytes of input hold at most one
/// frame (OpenLCB-TCP messages are longer).
pub(crate) const SHORTEST_FRAME: usize = ":X00000000N;".len();
/// Received stream data the driver holds per stream for a reader that has not asked yet.
/// Taking data out of the endpoint frees its buffer, which sends the next Proceed; past this
/// bound the driver stops taking, and a slow reader slows the source.
const STAGING_LIMIT: usize = 256 * 1024;
/// Rounds of the inner loop per wake-up, so that reading the socket and the commands is not
/// starved while data moves.
const ROUNDS: usize = 8;

type OpenReply = oneshot::Sender<Result<(StreamHandle, StreamInfo), Error>>;
type DoneReply = oneshot::Sender<Result<(), Error>>;
type ReadReply = oneshot::Sender<Result<Option<Bytes>, Error>>;

/// A stream this node opened.
struct Sending {
    peer: NodeId,
    /// Waiting for Opened or Rejected.
    opening: Option<OpenReply>,
    /// Data the endpoint has not taken yet, from the offset, and who waits for it.
    write: Option<(Bytes, DoneReply)>,
    /// The stream ended early; the next command on it gets this.
    failed: Option<Error>,
    /// Bytes the endpoint took, shared with the handle.
    sent: SentBytes,
}

/// A stream another node opened to this one.
struct Receiving {
    peer: NodeId,
    /// Data taken from the endpoint, not yet handed to the reader.
    staging: BytesMut,
    /// A reader waiting for data.
    reader: Option<ReadReply>,
    /// How the stream ended, once it has.
    end: Option<Result<(), Error>>,
}

pub(crate) struct Driver {
    reader: ByteReader,
    writer: ByteWriter,
    start: tokio::time::Instant,
    /// The sans-IO node: streams, datagrams, SNIP, the message-network basics.
    stack: openlcb_node::Node,
    /// Handles' questions to other nodes, waiting for the node's answers.
    requests: Requests,
    /// Memory Configuration operations waiting for their end, and the server's events.
    memory: MemoryDriver,
    /// Listeners of event notices.
    events: EventDriver,
    clocks: ClockDriver,
    trains: TrainDriver,
    wire: Wire,
    stats: WireStats,
    commands: mpsc::Receiver<Command>,
    /// To give accepted streams a way back without keeping the driver alive.
    weak_commands: mpsc::WeakSender<Command>,
    incoming: mpsc::Sender<RecvStream>,
    shared: Shared,
    sends: HashMap<StreamHandle, Sending>,
    recvs: HashMap<StreamHandle, Receiving>,
    /// `finish` calls waiting until everything has been written to the socket.
    flush_waiters: Vec<DoneReply>,
    read_buf: Vec<u8>,
    /// Bytes of a read handed to the node at once, before its events are drained: few enough
    /// frames that the node's bounded event queue cannot fill (see [`notice_slice`]).
    read_slice: usize,
    scratch: Vec<u8>,
    /// See [`NodeOptions::write_timeout`].
    write_timeout: std::time::Duration,
    /// When the socket last took bytes, or had nothing to take.
    last_write: tokio::time::Instant,
    /// See [`NodeOptions::join`].
    join: Join,
}

impl Driver {
    pub(crate) fn new(
        (reader, writer): (ByteReader, ByteWriter),
        protocol: Framing,
        options: NodeOptions,
        commands: mpsc::Receiver<Command>,
        weak_commands: mpsc::WeakSender<Command>,
        incoming: mpsc::Sender<RecvStream>,
        shared: Shared,
    ) -> Self {
        let NodeOptions { node_id, node, can, write_timeout, join, .. } = options;
        let read_slice = notice_slice(node.transmit_queue_limit);
        let start = tokio::time::Instant::now();
        Driver {
            reader,
            writer,
            start,
            write_timeout,
            last_write: start,
            join,
            stack: openlcb_node::Node::new(node_id, node),
            requests: Requests::default(),
            memory: MemoryDriver::default(),
            events: EventDriver::default(),
            clocks: ClockDriver::default(),
            trains: TrainDriver::default(),
            wire: Wire::new(protocol, Instant::ZERO, node_id, can),
            stats: WireStats::default(),
            commands,
            weak_commands,
            incoming,
            shared,
            sends: HashMap::new(),
            recvs: HashMap::new(),
            flush_waiters: Vec::new(),
            read_buf: vec![0; READ_CHUNK],
            read_slice,
            scratch: vec![0; READ_CHUNK],
        }
    }

    /// Runs until the connection is lost or every handle is gone. `up` is told once the node
    /// may talk (alias permitted). Everyone still waiting then gets the error.
    pub(crate) async fn run(mut self, up: oneshot::Sender<()>) {
        let error = self.drive(up).await;
        // Handles that find their channel closed read this; the states dropped with `self`
        // close the channels of everyone still waiting.
        self.shared.set(error);
    }

    /// Microseconds since the driver started: the core's clock.
    fn now(&self) -> Instant {
        Instant::from_micros(u64::try_from(self.start.elapsed().as_micros()).unwrap_or(u64::MAX))
    }

    async fn drive(&mut self, up: oneshot::Sender<()>) -> Error {
        let mut up = Some(up);
        let sleep = tokio::time::sleep_until(self.start);
        tokio::pin!(sleep);
        loop {
            let busy = match self.step() {
                Ok(busy) => busy,
                Err(error) => return self.stop(error).await,
            };
            let now = self.now();
            if self.wire.is_up(now, self.join)
                && let Some(up) = up.take()
            {
                let _ = up.send(());
            }
            let want_write = !self.wire.pending().is_empty();
            let stalled_at = self.write_deadline(want_write);
            if stalled_at.is_some_and(|at| at <= tokio::time::Instant::now()) {
                return Error::WriteStalled(self.write_timeout);
            }
            let deadline = [self.wire.poll_timeout(), self.stack.poll_timeout()]
                .into_iter()
                .flatten()
                .map(|at| self.start + std::time::Duration::from_micros(at.as_micros()))
                .chain(stalled_at)
                .min();
            if let Some(at) = deadline {
                sleep.as_mut().reset(at);
            }
            tokio::select! {
                read = self.reader.read(&mut self.read_buf) => {
                    if let Err(error) = self.received(read) {
                        return self.stop(error).await;
                    }
                }
                written = self.writer.write(self.wire.pending()), if want_write => {
                    if let Err(error) = self.wrote(written) {
                        return error;
                    }
                }
                command = self.commands.recv() => match command {
                    Some(command) => self.command(command),
                    None => {
                        // Every handle is gone: write what is left, release the alias (a
                        // node leaving the network says so, CFT §6.2.4), then stop.
                        let goodbye = async {
                            self.flush().await?;
                            self.wire.leave();
                            self.flush().await
                        };
                        let _ = tokio::time::timeout(std::time::Duration::from_secs(1), goodbye).await;
                        return Error::Closed;
                    }
                },
                () = &mut sleep, if deadline.is_some() => {}
                // More work was left at once: come back after letting other tasks run.
                () = tokio::task::yield_now(), if busy => {}
            }
        }
    }

    /// Ends the drive loop with `error`; a node leaving the network for a duplicate Node ID
    /// first writes its farewell (the well-known event, AMR), for at most a second.
    async fn stop(&mut self, error: Error) -> Error {
        if matches!(error, Error::DuplicateNodeId { .. }) {
            let _ = tokio::time::timeout(std::time::Duration::from_secs(1), self.flush()).await;
        }
        error
    }

    /// When the pending output counts as stalled: [`NodeOptions::write_timeout`] after the
    /// socket last took bytes. `None` while nothing waits to be written.
    fn write_deadline(&mut self, want_write: bool) -> Option<tokio::time::Instant> {
        if !want_write {
            self.last_write = tokio::time::Instant::now();
            return None;
        }
        Some(self.last_write + self.write_timeout)
    }

    /// The drive loop's work at one instant: timers, events, application data in and out,
    /// framing, writing. Repeats while data moves, at most [`ROUNDS`] times; returns `true`
    /// if there may be more to do at once (the caller comes back without waiting).
    fn step(&mut self) -> Result<bool, Error> {
        let now = self.now();
        let deadline = [self.wire.poll_timeout(), self.stack.poll_timeout()].into_iter().flatten().min();
        if deadline.is_some_and(|at| at <= now) {
            self.wire.handle_timeout(now, &mut self.stack);
            self.stack.handle_timeout(now);
        }
        let mut busy = false;
        for _ in 0..ROUNDS {
            self.wire.poll_events(now, &mut self.stack)?;
            self.node_events(now);
            let moved = self.feed_writes(now) + self.fill_reads(now);
            self.node_events(now);
            self.memory.publish_progress(&self.stack);
            self.deliver_reads();
            let written = self.write_out(now)?;
            busy = moved > 0 || written > 0;
            if !busy {
                break;
            }
        }
        if self.wire.is_flushed() {
            for waiter in self.flush_waiters.drain(..) {
                let _ = waiter.send(Ok(()));
            }
        }
        Ok(busy)
    }

    /// Frames what the endpoint has queued and writes it, framing more while the socket takes
    /// everything (a window's frames may not fit under the high-water mark at once). Returns
    /// the bytes written; a full socket stops it (`writable` wakes the loop again).
    fn write_out(&mut self, now: Instant) -> Result<usize, Error> {
        let mut written = 0;
        loop {
            self.wire.pump(now, &mut self.stack, &mut self.stats);
            let pending = self.wire.pending().len();
            if pending == 0 {
                return Ok(written);
            }
            self.write_socket()?;
            let left = self.wire.pending().len();
            written += pending - left;
            if left > 0 {
                return Ok(written);
            }
        }
    }

    /// Feeds what one read delivered to the link.
    fn received(&mut self, read: std::io::Result<usize>) -> Result<(), Error> {
        match read {
            Ok(0) => Err(Error::closed_by_hub()),
            Ok(n) => {
                let now = self.now();
                if let Some(line) = self.read_buf.get(..n).and_then(hub_full) {
                    return Err(Error::HubFull(line));
                }
                // A read holds thousands of frames: the node's events are taken between
                // slices of it, so that none is lost to its bounded queue.
                let mut start = 0;
                while start < n {
                    let end = n.min(start + self.read_slice);
                    let bytes = self.read_buf.get(start..end).unwrap_or_default();
                    self.wire.receive(now, bytes, &mut self.stack, &mut self.stats)?;
                    self.node_events(now);
                    start = end;
                }
                Ok(())
            }
            Err(error) if error.kind() == std::io::ErrorKind::WouldBlock => Ok(()),
            Err(error) => Err(Error::lost(error)),
        }
    }

    /// Counts what one write took off the pending output.
    fn wrote(&mut self, written: std::io::Result<usize>) -> Result<(), Error> {
        match written {
            Ok(0) => Err(Error::lost(std::io::ErrorKind::WriteZero.into())),
            Ok(n) => {
                let now = self.now();
                self.wire.advance(n, now, &mut self.stats);
                self.last_write = tokio::time::Instant::now();
                Ok(())
            }
            Err(error) if error.kind() == std::io::ErrorKind::WouldBlock => Ok(()),
            Err(error) => Err(Error::lost(error)),
        }
    }

    /// Writes everything pending in one call if the connection takes it now (it may take
    /// less, or nothing: the drive loop's write then waits for it).
    fn write_socket(&mut self) -> Result<(), Error> {
        let pending = self.wire.pending();
        if pending.is_empty() {
            return Ok(());
        }
        match try_write(&mut self.writer, pending) {
            Some(written) => self.wrote(written),
            None => Ok(()),
        }
    }

    /// Writes until every framed byte is out.
    async fn flush(&mut self) -> Result<(), Error> {
        loop {
            self.wire.pump(self.now(), &mut self.stack, &mut self.stats);
            if self.wire.pending().is_empty() {
                return Ok(());
            }
            let written = self.writer.write(self.wire.pending()).await;
            self.wrote(written)?;
        }
    }

    // ----- commands from the handles -----

    fn command(&mut self, command: Command) {
        let now = self.now();
        match command {
            Command::Open { options, sent, reply } => match self.stack.streams_mut().open(now, options) {
                Ok(handle) => {
                    let sending =
                        Sending { peer: options.destination, opening: Some(reply), write: None, failed: None, sent };
                    self.sends.insert(handle, sending);
                }
                Err(error) => {
                    let _ = reply.send(Err(error.into()));
                }
            },
            Command::Write { handle, data, reply } => match self.sends.get_mut(&handle) {
                Some(Sending { failed: Some(error), .. }) => {
                    let _ = reply.send(Err(error.clone()));
                    self.sends.remove(&handle);
                }
                Some(sending) if sending.write.is_none() => sending.write = Some((data, reply)),
                _ => {
                    let _ = reply.send(Err(StreamError::NotOpen.into()));
                }
            },
            Command::Finish { handle, reply } => match self.sends.remove(&handle) {
                Some(Sending { failed: Some(error), .. }) => {
                    let _ = reply.send(Err(error));
                }
                Some(_) => match self.stack.streams_mut().finish(now, handle) {
                    Ok(()) => self.flush_waiters.push(reply),
                    Err(error) => {
                        let _ = reply.send(Err(error.into()));
                    }
                },
                None => {
                    let _ = reply.send(Err(StreamError::UnknownStream.into()));
                }
            },
            Command::Abort { handle, code } => {
                self.sends.remove(&handle);
                self.recvs.remove(&handle);
                let _ = self.stack.streams_mut().abort(now, handle, code);
            }
            Command::Read { handle, reply } => match self.recvs.get_mut(&handle) {
                Some(receiving) => receiving.reader = Some(reply),
                None => {
                    let _ = reply.send(Err(StreamError::UnknownStream.into()));
                }
            },
            Command::Discover { sink } => {
                self.requests.listen_verified(sink);
                self.stack.verify_all();
            }
            Command::Snip { peer, reply } => match self.stack.request_snip(now, peer) {
                // A second question to the same node shares the request already out.
                Ok(()) | Err(SnipRequestError::AlreadyPending) => {
                    if let Err(reply) = self.requests.ask_snip(peer, reply) {
                        let _ = reply.send(Err(Error::Busy));
                    }
                }
                Err(_) => {
                    let _ = reply.send(Err(Error::Busy));
                }
            },
            Command::Protocols { peer, reply } => match self.requests.ask_protocols(peer, reply) {
                Ok(()) => self.stack.request_protocols(peer),
                Err(reply) => {
                    let _ = reply.send(Err(Error::Busy));
                }
            },
            Command::AliasOf { node, reply } => {
                let _ = reply.send(self.wire.alias_of(node));
            }
            Command::Stats { reply } => {
                let _ = reply.send(NodeStats {
                    wire: self.stats,
                    endpoint: self.stack.streams().stats(),
                    node: self.stack.stats(),
                    memory_events_dropped: self.memory.dropped(),
                    event_notices_dropped: self.events.dropped(),
                });
            }
            Command::OwnSnip { reply } => {
                let _ = reply.send(self.stack.config().snip.clone());
            }
            Command::Memory(command) => self.memory.command(now, &mut self.stack, command),
            Command::Events(command) => self.events.command(&mut self.stack, command),
            Command::Clock(command) => self.clocks.command(now, &mut self.stack, command),
            Command::Train(command) => self.trains.command(&mut self.stack, command),
        }
    }

    // ----- the node's events -----

    fn node_events(&mut self, now: Instant) {
        self.events.node_dropped(self.stack.event_stats().notices_dropped.into());
        while let Some(event) = self.stack.poll_event() {
            let event = match event {
                NodeEvent::Stream(event) => event,
                NodeEvent::Memory(event) => {
                    self.memory.event(event);
                    continue;
                }
                NodeEvent::Events(notice) => {
                    self.events.notice(notice);
                    continue;
                }
                NodeEvent::Clock(event) => {
                    self.clocks.event(event);
                    continue;
                }
                NodeEvent::Train(event) => {
                    self.trains.event(event);
                    continue;
                }
                NodeEvent::Throttle(event) => {
                    self.trains.throttle_event(event);
                    continue;
                }
                event => {
                    self.requests.answer(event);
                    continue;
                }
            };
            log_stream_event(&event);
            match event {
                Event::Opened { handle, info } if info.role == Role::Source => {
                    if let Some(reply) = self.sends.get_mut(&handle).and_then(|s| s.opening.take()) {
                        let _ = reply.send(Ok((handle, info)));
                    }
                }
                Event::Opened { handle, info } => self.incoming_stream(now, handle, info),
                Event::Rejected { handle, code, .. } => {
                    if let Some(sending) = self.sends.remove(&handle)
                        && let Some(reply) = sending.opening
                    {
                        let _ = reply.send(Err(Error::Rejected { peer: sending.peer, code }));
                    }
                }
                Event::Finished { handle, total, stated, matched } => {
                    if let Some(receiving) = self.recvs.get_mut(&handle) {
                        receiving.end = Some(if matched {
                            Ok(())
                        } else {
                            Err(Error::CountMismatch { received: total, stated: stated.unwrap_or(0) })
                        });
                    }
                }
                Event::Terminated { handle, cause } => {
                    let opening = self.sends.get(&handle).is_some_and(|s| s.opening.is_some());
                    self.fail(handle, |peer| match cause {
                        openlcb_stream::Termination::PeerLost if opening => Error::Unreachable(peer),
                        cause => Error::Terminated { peer, cause },
                    });
                }
                Event::TimedOut { handle, kind } => self.fail(handle, |peer| Error::TimedOut { peer, kind }),
                _ => {}
            }
        }
    }

    /// The stream ended early: whoever waits on it learns why, now or at the next command.
    fn fail(&mut self, handle: StreamHandle, error: impl FnOnce(NodeId) -> Error) {
        if let Some(sending) = self.sends.get_mut(&handle) {
            let error = error(sending.peer);
            if let Some(reply) = sending.opening.take() {
                let _ = reply.send(Err(error));
                self.sends.remove(&handle);
            } else if let Some((_, reply)) = sending.write.take() {
                let _ = reply.send(Err(error));
                self.sends.remove(&handle);
            } else {
                sending.failed = Some(error);
            }
        } else if let Some(receiving) = self.recvs.get_mut(&handle) {
            receiving.end = Some(Err(error(receiving.peer)));
        }
    }

    /// A stream to this node was accepted: hand it to [`Node::accept`](crate::Node::accept),
    /// or terminate it if nobody can take it.
    fn incoming_stream(&mut self, now: Instant, handle: StreamHandle, info: StreamInfo) {
        let Some(commands) = self.weak_commands.upgrade() else {
            let _ = self.stack.streams_mut().abort(now, handle, ErrorCode::BUFFER_UNAVAILABLE);
            return;
        };
        let control = Control { commands, shared: self.shared.clone() };
        match self.incoming.try_send(RecvStream::new(handle, info, control)) {
            Ok(()) => {
                let receiving = Receiving { peer: info.peer, staging: BytesMut::new(), reader: None, end: None };
                self.recvs.insert(handle, receiving);
            }
            Err(refused) => {
                refused.into_inner().forget();
                let _ = self.stack.streams_mut().abort(now, handle, ErrorCode::BUFFER_UNAVAILABLE);
            }
        }
    }

    // ----- data -----

    /// Gives pending application data to the endpoint while the output has room; returns the
    /// bytes taken. Completed writes are answered, which lets the application send more.
    fn feed_writes(&mut self, now: Instant) -> usize {
        let mut taken = 0;
        for (&handle, sending) in &mut self.sends {
            if !self.wire.has_room() {
                break;
            }
            let Some((data, _)) = &mut sending.write else { continue };
            match self.stack.streams_mut().write(now, handle, data) {
                Ok(n) => {
                    taken += n;
                    sending.sent.add(n as u64);
                    bytes::Buf::advance(data, n);
                    if data.is_empty()
                        && let Some((_, reply)) = sending.write.take()
                    {
                        let _ = reply.send(Ok(()));
                    }
                }
                Err(StreamError::NotOpen) => {}
                Err(error) => {
                    if let Some((_, reply)) = sending.write.take() {
                        let _ = reply.send(Err(error.into()));
                    }
                }
            }
            // Put the new Data Sends into the output now, so `has_room` sees them.
            self.wire.pump(now, &mut self.stack, &mut self.stats);
        }
        taken
    }

    /// Takes received data out of the endpoint into each stream's staging buffer, up to the
    /// limit; returns the bytes taken.
    fn fill_reads(&mut self, now: Instant) -> usize {
        let mut taken = 0;
        for (&handle, receiving) in &mut self.recvs {
            while receiving.staging.len() < STAGING_LIMIT {
                let room = (STAGING_LIMIT - receiving.staging.len()).min(self.scratch.len());
                let Some(buf) = self.scratch.get_mut(..room) else { break };
                match self.stack.streams_mut().read(now, handle, buf) {
                    Ok(n @ 1..) => {
                        receiving.staging.extend_from_slice(buf.get(..n).unwrap_or_default());
                        taken += n;
                    }
                    _ => break,
                }
            }
        }
        taken
    }

    /// Answers waiting readers with staged data, or with the end once everything was read.
    fn deliver_reads(&mut self) {
        let endpoint = self.stack.streams();
        self.recvs.retain(|&handle, receiving| {
            if receiving.reader.is_none() {
                return true;
            }
            if !receiving.staging.is_empty() {
                if let Some(reply) = receiving.reader.take() {
                    let _ = reply.send(Ok(Some(receiving.staging.split().freeze())));
                }
                return true;
            }
            let drained = endpoint.buffered(handle).unwrap_or(0) == 0;
            match receiving.end.take() {
                Some(end) if drained => {
                    if let Some(reply) = receiving.reader.take() {
                        let _ = reply.send(end.map(|()| None));
                    }
                    false
                }
                end => {
                    receiving.end = end;
                    true
                }
            }
        });
    }
}

/// The bytes of input handed to the node between two drains of its events: a frame causes at
/// most one notice, and the node keeps `queue_limit` events before it drops notices, so half
/// as many frames (the rest of the room is for the events of what this node started).
fn notice_slice(queue_limit: usize) -> usize {
    (queue_limit / 2).max(1) * SHORTEST_FRAME
}

/// Logs the events that begin or end a stream (in the node's span), none per window or frame.
fn log_stream_event(event: &Event) {
    match event {
        Event::Opened { handle, info } => {
            tracing::info!(stream = ?handle, peer = %info.peer, role = ?info.role, window = info.window, "stream opened");
        }
        Event::Finished { handle, total, matched, .. } => {
            tracing::info!(stream = ?handle, total, matched, "stream finished");
        }
        Event::Rejected { handle, code, .. } => tracing::warn!(stream = ?handle, %code, "stream rejected"),
        Event::Terminated { handle, cause } => tracing::warn!(stream = ?handle, ?cause, "stream terminated"),
        Event::TimedOut { handle, kind } => tracing::warn!(stream = ?handle, ?kind, "stream timed out"),
        _ => {}
    }
}

/// The line a full hub sends before it closes a connection it refuses (`lcc-stream hub`:
/// "hub full: N clients connected; try again later"), if `bytes` begin with one. Frames
/// never begin so (GridConnect's begin with `:`).
fn hub_full(bytes: &[u8]) -> Option<String> {
    let line = bytes.strip_prefix(b"hub full")?;
    let end = line.iter().position(|b| matches!(b, b'\r' | b'\n')).unwrap_or(line.len());
    Some(format!("hub full{}", String::from_utf8_lossy(line.get(..end).unwrap_or_default())))
}
