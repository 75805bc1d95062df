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

use openlcb_stream::wire::ErrorCode;
use openlcb_stream::{Duration, NodeId, TimeoutKind};

pub(crate) use client::MemoryClient;
pub use client::{MemoryOperation, MemoryRequestError, TransferPath};
pub use server::{MemoryServer, MemoryServerStats};
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
    /// Stream transfers the server runs at once; one more is refused with 0x2020.
    pub max_server_streams: usize,
    /// Operations the client runs at once (one per peer).
    pub max_operations: usize,
    /// The most bytes one client read may ask for (its buffer).
    pub max_read_len: u32,
    /// Server: how long a Lock/Reserve holds without a command or stream data from its
    /// owner; then it lapses, so a client that died does not keep others from writing.
    pub lock_timeout: Duration,
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
