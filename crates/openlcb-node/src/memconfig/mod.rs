//! Memory Configuration (datagram content ID 0x20, node-protocols.md §3) and the Firmware
//! Upgrade flow on top of it (§4): the wire types, a server of address spaces and a client,
//! each by datagrams and by streams.
//!
//! It is a module of the node crate rather than a crate of its own because it is made of
//! the node's other protocols: every command travels in a datagram of the node's datagram
//! service, the stream paths open and accept streams on the node's one stream endpoint, the
//! ACDI spaces mirror the node's SNIP strings, and the Firmware Upgrade state changes the
//! node's PIP bits and makes it announce itself again. Kept beside [`Node`](crate::Node), it
//! is fed from the node's one drive loop and its streams' events never reach the
//! application; a crate of its own would need the node to expose all of that as public API.
//!
//! Three parts:
//! - [`wire`]: every command and reply as a typed value ([`Command`], [`Reply`]) with
//!   `parse` (liberal where node-protocols.md §10 says "Accept") and `to_bytes` (strict);
//! - the server ([`MemoryServer`]): address spaces behind [`MemorySpace`], handed to the
//!   node with [`Node::set_memory_server`](crate::Node::set_memory_server);
//! - the client: [`Node::read_memory`](crate::Node::read_memory),
//!   [`Node::write_memory`](crate::Node::write_memory),
//!   [`Node::upgrade_firmware`](crate::Node::upgrade_firmware), each an operation with a
//!   [`MemoryOperation`] handle, progress, and one final [`MemoryEvent`].

pub mod wire;

mod client;
mod server;
mod space;

use alloc::vec::Vec;

use openlcb_stream::wire::{ErrorCode, ErrorReport};
use openlcb_stream::{Duration, Event, Instant, Message, MessageRef, Mti, NodeId, StreamHandle, TimeoutKind};

use crate::Protocols;
use crate::datagram::{DatagramId, DatagramOwner, DatagramService, OkFlags, Outcome, received_ok, rejected};
use crate::node::Outputs;
use crate::service::{Lent, Service, ServiceChange, earliest};
pub(crate) use client::MemoryClient;
pub use client::{MemoryOperation, MemoryRequestError, NodeCommand, TransferPath};
#[cfg(feature = "traction")]
pub(crate) use server::FunctionMirror;
pub use server::{MemoryServer, MemoryServerStats};
pub(crate) use space::copy_prefix;
pub use space::{
    ACDI_MANUFACTURER_LEN, ACDI_USER_LEN, MemorySpace, RamSpace, ReadOnlySpace, SpaceError, acdi_manufacturer_bytes,
    acdi_user_bytes, acdi_user_strings,
};
pub use wire::{Command, DecodeError, FailedKind, OptionsReply, Reply, SpaceForm, SpaceInfoReply};

/// Bounds and timers of Memory Configuration, server and client.
#[derive(Debug, Clone, PartialEq, Eq)]
#[non_exhaustive]
pub struct MemoryConfigOptions {
    /// How long the client waits for a Datagram OK's reply datagram (a Read Reply, a Write
    /// Reply, an Options reply...). OpenMRN's client waits 3 s. A lost reply is asked for
    /// again, up to [`max_retries`](Self::max_retries) times.
    pub reply_timeout: Duration,
    /// How often the client asks again for a chunk whose reply did not come.
    pub max_retries: u8,
    /// How long the client waits, after Freeze and after Unfreeze, for the target to answer
    /// (Datagram OK or Initialization Complete, C-11). Default 10 s: a bootloader logs in
    /// again first.
    pub reboot_timeout: Duration,
    /// The longest a stream transfer may go without progress, on either side, before it is
    /// given up (30 s: the OpenMRN Bootloader sends a Proceed only after a flash write).
    pub stream_timeout: Duration,
    /// The Max Buffer Size a stream source of this module proposes (the client's Write
    /// Stream, the server's Read Stream); the destination lowers it.
    pub stream_window: u16,
    /// The most the server grants a Write Stream: what a space can take in flight. A space
    /// may lower it with [`MemorySpace::write_window`].
    pub write_stream_window: u16,
    /// How long the server holds the Write Stream Reply for a client that initiates the
    /// stream at once (OlcbChecker, OpenLcbCLib: they expect the reply after the stream's
    /// Complete). A client that waits for the reply before it initiates (OpenMRN's
    /// `bootloader_client`) gets it after this long. Default 250 ms.
    pub write_stream_reply_delay: Duration,
    /// Stream transfers the server runs at once; one more is refused with 0x2020. Any one
    /// peer runs at most half of them (at least one), so that one node cannot take them all;
    /// a client refused so falls back to datagrams ([`TransferPath::Auto`]).
    pub max_server_streams: usize,
    /// Operations the client runs at once (one per peer).
    pub max_operations: usize,
    /// The most bytes one client read may ask for (its buffer).
    pub max_read_len: u32,
    /// Server: how long a Lock/Reserve holds without a command or stream data from its
    /// owner; then it lapses, so a client that died does not keep others from writing.
    pub lock_timeout: Duration,
    /// Server: how long the holder of the lock or of an upgrade has to answer the Verify
    /// Node ID sent when another node is refused on its account. Until then the other node
    /// is refused for now (0x2000: it resends); with no answer the holder has left, and
    /// what it held ends. Default 500 ms (a client's resends come after 200 ms, 400 ms,
    /// 800 ms: the third gets through).
    pub holder_answer_timeout: Duration,
}

impl Default for MemoryConfigOptions {
    fn default() -> Self {
        MemoryConfigOptions {
            reply_timeout: Duration::from_secs(3),
            max_retries: 3,
            reboot_timeout: Duration::from_secs(10),
            stream_timeout: Duration::from_secs(30),
            stream_window: 0xFFFF,
            write_stream_window: 2048,
            write_stream_reply_delay: Duration::from_millis(250),
            max_server_streams: 8,
            max_operations: 8,
            max_read_len: 16 * 1024 * 1024,
            lock_timeout: Duration::from_secs(10),
            holder_answer_timeout: Duration::from_millis(500),
        }
    }
}

/// Why a client operation failed.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[non_exhaustive]
pub enum MemoryError {
    /// The node refused the command datagram (Datagram Rejected, or OIR/TDE naming it):
    /// 0x1081 unknown space, 0x1083 read-only, 0x1041 unknown command, ...
    Rejected(ErrorCode),
    /// The node answered with a failed reply (0x1082 out of bounds, ...).
    Failed(ErrorCode),
    /// No answer within the configured wait, retries included.
    TimedOut,
    /// The stream of the transfer was refused at its Initiate.
    StreamRejected(ErrorCode),
    /// The stream ended early: terminated by the peer (with its code) or by this node.
    StreamEnded(ErrorCode),
    /// A stream wait ran out.
    StreamTimedOut(TimeoutKind),
    /// The stream delivered fewer bytes than asked for (or none).
    WrongLength {
        /// Bytes asked for.
        expected: u64,
        /// Bytes received.
        received: u64,
    },
    /// The stream's Data Complete stated another count than the bytes that arrived: bytes
    /// were lost on the way, or the node counts otherwise. Nothing read is handed over.
    CountMismatch {
        /// The count the Complete stated.
        stated: u64,
        /// Bytes that arrived.
        received: u64,
    },
    /// The node sent more than was asked for: more than the length of the read, or more
    /// than its space holds by its own Get Address Space Information reply.
    Overrun {
        /// The most bytes the read could take.
        expected: u64,
    },
    /// A reply named another space than the command (Get Address Space Information, Read
    /// Reply).
    WrongSpace {
        /// The space the command named.
        asked: u8,
        /// The space the reply named.
        answered: u8,
    },
    /// A read to the end of a space larger than
    /// [`MemoryConfigOptions::max_read_len`]: refused before a byte is read, once Get
    /// Address Space Information gave the size. Read the space in parts, each with a length.
    SpaceTooLarge {
        /// Bytes from the read's address to the end of the space, as the node reported them
        /// (`None`: the node does not answer Get Address Space Information, and its stream
        /// went past the limit).
        size: Option<u64>,
        /// The most one read takes.
        limit: u32,
    },
    /// The node restarted (Initialization Complete) in the middle of the operation.
    PeerRestarted,
    /// The transport lost the node or our own link.
    PeerLost,
    /// The reply made no sense for the command (wrong address, bad bytes).
    BadReply,
    /// The node has no stream support (only when streams were required).
    NoStreams,
    /// Another node holds the node's Lock/Reserve (MC §4.17): it is writing; nothing was
    /// written.
    Locked {
        /// The Node ID the lock holds.
        owner: u64,
    },
}

/// What Memory Configuration tells the application: the end of each client operation,
/// and what the server was asked to do that the application must carry out.
#[derive(Debug, Clone, PartialEq, Eq)]
#[non_exhaustive]
pub enum MemoryEvent {
    /// A read ended with all the bytes asked for (or the whole space).
    ReadDone {
        /// The operation.
        operation: MemoryOperation,
        /// The node read.
        peer: NodeId,
        /// The bytes.
        data: Vec<u8>,
    },
    /// A write (or a firmware upgrade) ended, every byte acknowledged.
    WriteDone {
        /// The operation.
        operation: MemoryOperation,
        /// The node written.
        peer: NodeId,
        /// Bytes written.
        len: u64,
    },
    /// An operation failed.
    Failed {
        /// The operation.
        operation: MemoryOperation,
        /// The node.
        peer: NodeId,
        /// Why.
        error: MemoryError,
    },
    /// Server: Freeze of space 0xEF; the node is now in the Firmware Upgrade state.
    Frozen {
        /// Who asked.
        by: NodeId,
    },
    /// Server: Unfreeze of space 0xEF; the node is back in the Operating state and the
    /// application may install the image (bytes `0..image_len` of space 0xEF).
    Unfrozen {
        /// Who asked.
        by: NodeId,
        /// One past the highest firmware byte written while frozen.
        image_len: u32,
    },
    /// Server: the Unfreeze of `by` was refused with `code` and the node stays frozen: the
    /// transfer into space 0xEF was aborted (0x1089), or the space could not store the image
    /// (its [`MemorySpace::complete`] failed). A retry starts again at offset 0.
    UpgradeRefused {
        /// Who asked.
        by: NodeId,
        /// The code of the Datagram Rejected sent.
        code: ErrorCode,
    },
    /// Server: Update Complete (the configuration tool is done; the node may apply it).
    UpdateComplete {
        /// Who said so.
        by: NodeId,
    },
    /// Server: Reset/Reboot (MC §4.24). The node has already reinitialized its protocols and
    /// announced itself again (see `Node`'s documentation of Reset/Reboot); the configuration
    /// must survive.
    ResetRequested {
        /// Who asked.
        by: NodeId,
    },
    /// Server: Factory Reset naming this node (MC §4.25).
    FactoryResetRequested {
        /// Who asked.
        by: NodeId,
    },
    /// Server: space 0xFB was written; the node's SNIP user name and description now
    /// follow it.
    UserInfoChanged,
}

/// What the server and the client get for one call: the node's queues, and the datagram
/// service and stream endpoint they are built on.
pub(crate) struct Cx<'a> {
    pub(crate) now: Instant,
    pub(crate) out: &'a mut Outputs,
    pub(crate) datagrams: &'a mut DatagramService,
    /// The datagram service's bounds and timers.
    datagram_config: &'a crate::DatagramConfig,
    pub(crate) streams: &'a mut crate::streams::Endpoint,
    /// See [`Cx::streams_enabled`].
    streams_enabled: bool,
    pub(crate) options: &'a MemoryConfigOptions,
    /// Streams Memory Configuration is done with (see [`MemoryConfig`]).
    ended: &'a mut Vec<StreamHandle>,
    /// The node must send Initialization Complete (it changed Firmware Upgrade state).
    pub(crate) announce: bool,
    /// Reset/Reboot was asked for: the node reinitializes once the command is answered.
    pub(crate) reboot: bool,
    /// The server found this peer gone (it held something and did not answer a Verify
    /// Node ID): the node treats it as lost.
    pub(crate) departed: Option<NodeId>,
}

impl<'a> Cx<'a> {
    /// What [`MemoryConfig::run`] lends for one call. Out of line: one copy for every kind of
    /// call (flash).
    #[inline(never)]
    fn new(lent: &'a mut MemoryLent<'_>, ended: &'a mut Vec<StreamHandle>) -> Self {
        Cx {
            now: lent.lent.now,
            out: lent.lent.out,
            datagrams: lent.datagrams,
            datagram_config: &lent.lent.config.datagrams,
            streams: lent.streams,
            streams_enabled: crate::streams::enabled(lent.lent.config),
            options: &lent.lent.config.memory,
            ended,
            announce: false,
            reboot: false,
            departed: None,
        }
    }

    /// The call is over: what it asks of the node goes to `reboot` and `departed`, and the
    /// Initialization Complete of a change of Firmware Upgrade state goes out.
    fn finish(self, reboot: &mut bool, departed: &mut Option<NodeId>) {
        *reboot |= self.reboot;
        *departed = departed.or(self.departed);
        if self.announce {
            // FWU §5.2: every change of state ends with a new Initialization Complete.
            let node = self.out.node;
            self.out.transmit(Message::initialization_complete(node));
        }
    }

    /// Streams are in use: never without the `streams` feature, which the compiler sees, so
    /// that it links none of Memory Configuration's stream paths.
    pub(crate) fn streams_enabled(&self) -> bool {
        cfg!(feature = "streams") && self.streams_enabled
    }

    /// Datagram Received OK for the datagram `to` sent.
    pub(crate) fn ok(&mut self, to: NodeId, flags: OkFlags) {
        self.out.reply(received_ok(self.out.node, to, flags));
    }

    /// Datagram Rejected for the datagram `to` sent.
    pub(crate) fn reject(&mut self, to: NodeId, code: ErrorCode) {
        self.out.reply(rejected(self.out.node, to, code));
    }

    /// Sends a command datagram of the client, whose outcome comes back to the client.
    pub(crate) fn send_datagram(&mut self, to: NodeId, payload: &[u8]) -> Option<DatagramId> {
        self.datagrams.send(self.datagram_config, self.now, self.out, to, payload, DatagramOwner::MemoryClient).ok()
    }

    /// Finishes a stream of Memory Configuration (its `Sent` event stays inside).
    pub(crate) fn finish_stream(&mut self, handle: StreamHandle) -> bool {
        let finished = self.streams.finish(self.now, handle).is_ok();
        if finished {
            self.ended.push(handle);
        }
        finished
    }

    /// Sends the server's reply datagram `reply` to `to`, which a Datagram OK promised: never
    /// dropped (its delivery is the datagram service's business). Out of line, taking the
    /// reply by value: one copy of its drop (flash).
    #[inline(never)]
    pub(crate) fn send_reply(&mut self, to: NodeId, reply: Vec<u8>) {
        self.datagrams.send_promised(self.datagram_config, self.now, self.out, to, &reply);
    }

    /// Answers the command datagram `to` sent with a Datagram OK promising a reply, then the
    /// reply datagram `reply` (a command answered at once).
    pub(crate) fn answer(&mut self, to: NodeId, reply: Vec<u8>) {
        self.ok(to, OkFlags { reply_pending: true, timeout_exponent: 0 });
        self.send_reply(to, reply);
    }

    /// A reply to `to` could be queued now.
    pub(crate) fn has_reply_room(&self, to: NodeId) -> bool {
        self.datagrams.has_room(self.datagram_config, to)
    }
}

/// What the node lends Memory Configuration: what every service gets, and the services it
/// is built on.
pub(crate) struct MemoryLent<'a> {
    pub(crate) lent: Lent<'a>,
    pub(crate) datagrams: &'a mut DatagramService,
    pub(crate) streams: &'a mut crate::streams::Endpoint,
}

/// Memory Configuration as one service of the node: the server (once set), the client, and
/// the streams they are done with, whose last event (the `Sent` of a stream they finished,
/// the `Terminated` of one whose peer was lost) is theirs, not the application's.
#[derive(Debug, Default)]
pub(crate) struct MemoryConfig {
    pub(crate) server: Option<MemoryServer>,
    client: MemoryClient,
    ended: Vec<StreamHandle>,
    /// A Reset/Reboot command was answered: the node reinitializes.
    pub(crate) reboot: bool,
    /// A peer the server found gone: the node treats it as lost.
    pub(crate) departed: Option<NodeId>,
}

impl MemoryConfig {
    /// The client, when the `memory-client` feature builds it in (without it the client is
    /// never called, so none of its code is linked).
    pub(crate) fn client(&self) -> Option<&MemoryClient> {
        cfg!(feature = "memory-client").then_some(&self.client)
    }

    /// Runs `f` on the server and the client with the node's parts lent to them.
    pub(crate) fn run<T>(
        &mut self,
        lent: &mut MemoryLent<'_>,
        f: impl FnOnce(&mut Cx<'_>, Option<&mut MemoryServer>, &mut MemoryClient) -> T,
    ) -> T {
        let MemoryConfig { server, client, ended, reboot, departed } = self;
        let mut cx = Cx::new(lent, ended);
        let result = f(&mut cx, server.as_mut(), client);
        cx.finish(reboot, departed);
        result
    }

    /// Runs `f` on the client (nothing without the `memory-client` feature).
    pub(crate) fn run_client(&mut self, lent: &mut MemoryLent<'_>, f: impl FnOnce(&mut Cx<'_>, &mut MemoryClient)) {
        if cfg!(feature = "memory-client") {
            self.run(lent, |cx, _, client| f(cx, client));
        }
    }

    /// A datagram with content ID 0x20 that Memory Configuration takes: a command when a
    /// server is configured; a reply when the client has an operation with the sender (or
    /// the application does not claim 0x20).
    fn takes_datagram(&self, datagrams: &DatagramService, peer: NodeId, payload: &[u8]) -> bool {
        match payload {
            [wire::CONTENT_ID, command, ..] if wire::is_reply(*command) => {
                self.client().is_some_and(|c| c.has_operation_with(peer) || !datagrams.claims(wire::CONTENT_ID))
            }
            [wire::CONTENT_ID, ..] => self.server.is_some(),
            _ => false,
        }
    }

    /// The outcome of one of the client's command datagrams.
    pub(crate) fn on_datagram_outcome(&mut self, lent: &mut MemoryLent<'_>, id: DatagramId, result: Outcome) {
        self.run_client(lent, |cx, client| {
            client.on_datagram_outcome(cx, id, result);
        });
    }

    /// Takes a stream event of one of its transfers (or the last event of a stream it is
    /// done with); false for any other.
    pub(crate) fn on_stream_event(&mut self, lent: &mut MemoryLent<'_>, event: &Event) -> bool {
        self.forget_ended(event)
            || self.run(lent, |cx, server, client| {
                server.is_some_and(|s| s.on_stream_event(cx, event))
                    || (cfg!(feature = "memory-client") && client.on_stream_event(cx, event))
            })
    }

    /// Whether `event` is about a stream Memory Configuration is done with; its last event
    /// ends the record.
    pub(crate) fn forget_ended(&mut self, event: &Event) -> bool {
        let handle = event.handle();
        let Some(index) = self.ended.iter().position(|h| *h == handle) else { return false };
        if matches!(
            event,
            Event::Sent { .. } | Event::Terminated { .. } | Event::TimedOut { .. } | Event::Rejected { .. }
        ) {
            self.ended.swap_remove(index);
        }
        true
    }

    /// Streams whose last window may have been acknowledged since: the client finishes them.
    pub(crate) fn poll_streams(&mut self, lent: &mut MemoryLent<'_>) {
        self.run_client(lent, |cx, client| client.poll_streams(cx));
    }
}

impl Service<MemoryLent<'_>> for MemoryConfig {
    /// Its datagrams (commands to the server, replies to the client), the Protocol Support
    /// Reply a firmware upgrade waits for, and Initialization Complete.
    fn handle_message(&mut self, lent: &mut MemoryLent<'_>, msg: MessageRef<'_>) -> bool {
        let peer = msg.source;
        match msg.mti {
            Mti::DATAGRAM if self.takes_datagram(lent.datagrams, peer, msg.payload) => {
                let is_reply = msg.payload.get(1).is_some_and(|c| wire::is_reply(*c));
                self.run(lent, |cx, server, client| {
                    if is_reply {
                        // Acknowledge a reply before anything else is sent (MC-TN §3.1.3.3).
                        cx.ok(peer, OkFlags::default());
                        if cfg!(feature = "memory-client") {
                            client.on_reply(cx, peer, msg.payload);
                        }
                    } else if let Some(server) = server {
                        server.on_command(cx, peer, msg.payload);
                    }
                });
                true
            }
            Mti::PROTOCOL_SUPPORT_REPLY if self.client().is_some_and(|c| c.wants_protocols(peer)) => {
                let protocols = Protocols::from_payload(msg.payload);
                self.run_client(lent, |cx, client| client.on_protocols(cx, peer, protocols));
                true
            }
            Mti::VERIFIED_NODE_ID | Mti::VERIFIED_NODE_ID_SIMPLE => {
                // The payload names the node (on CAN the source may be a provisional name).
                if let Some(server) = &mut self.server {
                    server.peer_verified(NodeId::from_slice(msg.payload).unwrap_or(peer));
                }
                false
            }
            Mti::INITIALIZATION_COMPLETE | Mti::INITIALIZATION_COMPLETE_SIMPLE => {
                if let Some(server) = &mut self.server {
                    server.forget_peer(Some(peer));
                }
                self.run_client(lent, |cx, client| client.peer_restarted(cx, peer));
                false
            }
            _ => false,
        }
    }

    /// Its commands travel in datagrams: a rejection reaches the client as its datagram's
    /// outcome. A report naming the datagram MTI from a peer whose Write Stream is running
    /// ends that transfer (the stream endpoint leaves a report about another protocol alone):
    /// a client that gives up its firmware stream so, with TDE, is answered at its Unfreeze.
    fn handle_error_report(&mut self, lent: &mut MemoryLent<'_>, peer: NodeId, report: ErrorReport) -> bool {
        if report.mti != Some(Mti::DATAGRAM) {
            return false;
        }
        let mut ended = false;
        self.run(lent, |cx, server, _| {
            if let Some(server) = server {
                ended = server.end_write_streams_of(cx, peer, report.code);
            }
        });
        ended
    }

    /// A lost peer's transfers and operations end here, nothing sent (the peer is gone);
    /// their streams' last events stay inside.
    fn peer_changed(&mut self, out: &mut Outputs, change: ServiceChange) {
        if let Some(server) = &mut self.server {
            server.peer_changed(&mut self.ended, change);
        }
        if cfg!(feature = "memory-client") {
            self.client.peer_changed(out, &mut self.ended, change);
        }
    }

    fn handle_timeout(&mut self, lent: &mut MemoryLent<'_>) {
        self.run(lent, |cx, server, client| {
            if let Some(server) = server {
                server.handle_timeout(cx);
            }
            if cfg!(feature = "memory-client") {
                client.handle_timeout(cx);
            }
        });
    }

    fn poll_timeout(&self) -> Option<Instant> {
        let server = self.server.as_ref().and_then(MemoryServer::poll_timeout);
        let client = self.client().and_then(MemoryClient::poll_timeout);
        earliest(server, client)
    }
}
