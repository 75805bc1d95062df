//! [`MemoryServer`]: the address spaces a node serves, and the server side of every
//! command, Read Stream (this node the source) and Write Stream (this node the destination).

use alloc::boxed::Box;
use alloc::vec::Vec;
use core::fmt;

use openlcb_stream::wire::ErrorCode;
use openlcb_stream::{AcceptOptions, Event, Instant, Message, Mti, NodeId, OpenOptions, StreamHandle, StreamId};

use super::Cx;
use super::space::{MemorySpace, SpaceError, acdi_manufacturer_bytes, acdi_user_bytes, read_slice};
#[cfg(feature = "traction")]
use super::wire::SPACE_FUNCTIONS;
use super::wire::{Command, DecodeError, FailedKind, OptionsReply, SpaceForm, SpaceInfoReply, codes};
use super::wire::{MAX_DATA_LEN, SPACE_ACDI_MANUFACTURER, SPACE_ACDI_USER, SPACE_CDI, SPACE_FDI, SPACE_FIRMWARE};
use super::wire::{failed_bytes, lock_bytes, read_ok_bytes, read_stream_ok_bytes, unique_ids_bytes};
use super::wire::{write_ok_bytes, write_stream_ok_bytes};
use super::{MemoryEvent, MemoryEvent as E};
use crate::node::bump;
use crate::service::{ServiceChange, earliest};
use crate::{OkFlags, Protocols, SnipInfo};

/// Bytes read from or written to a space at once on the stream paths.
const CHUNK: usize = 256;

/// Counters of the server.
///
/// Each counter stops at `u32::MAX` (32 bits: 64-bit counters cost flash on a
/// microcontroller).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
#[non_exhaustive]
pub struct MemoryServerStats {
    /// Commands answered.
    pub commands: u32,
    /// Commands refused with Datagram Rejected.
    pub rejected: u32,
    /// Stream transfers finished (both directions).
    pub streams_done: u32,
    /// Stream transfers that ended early (terminated, timed out, refused, a space error).
    pub streams_failed: u32,
    /// Holders of the lock or of an upgrade that did not answer a Verify Node ID: gone,
    /// what they held ended.
    pub holders_gone: u32,
}

/// A Verify Node ID sent to the node holding the lock or the upgrade because another node
/// was refused on its account. Answered by `deadline`: it is still here and the refusals
/// stand until then; not answered: it left without a word (`kill -9`, a pulled cable), and
/// what it held ends, so that the refused node's resend gets through.
#[derive(Debug, Clone, Copy)]
struct HolderCheck {
    holder: NodeId,
    deadline: Instant,
    answered: bool,
}

#[derive(Debug)]
enum Job {
    /// Read Stream: this node is the source.
    Read { handle: StreamHandle, space: u8, address: u32, next: u32, end: u32, count: u32, opened: bool },
    /// Write Stream: this node is the destination, once the request arrives.
    Write {
        sid: u8,
        /// The DID this node assigns (predicted until the stream is accepted).
        did: u8,
        handle: Option<StreamHandle>,
        space: u8,
        /// The command's address (the reply names it) and the next address to write.
        address: u32,
        next: u32,
        /// When the stream must have come (while `handle` is `None`).
        deadline: Instant,
        reply: WriteReply,
    },
}

/// When the Write Stream Reply goes out (node-protocols.md §10 C-2: OpenMRN's
/// `bootloader_client` waits for it before it initiates the stream; OlcbChecker's `mc80` and
/// OpenLcbCLib initiate at once and expect it after the stream's Complete).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum WriteReply {
    /// At this time, if the stream has not been asked for by then: the client waits for it.
    Due(Instant),
    /// After the stream's Complete: the client initiated at once.
    AfterComplete,
    /// Sent.
    Sent,
}

#[derive(Debug)]
struct Transfer {
    peer: NodeId,
    /// How the command named its space; its replies name it the same way.
    form: SpaceForm,
    job: Job,
}

/// The memory spaces of one node and the state of Memory Configuration's server side:
/// the lock, the Unique ID pool, the Firmware Upgrade state, the stream transfers running.
///
/// Build it with the `with_*` methods and hand it to
/// [`Node::set_memory_server`](crate::Node::set_memory_server); the node then announces
/// Memory Configuration in its PIP (and Firmware Upgrade when space 0xEF is served), and
/// every datagram with content ID 0x20 that is a command goes here.
pub struct MemoryServer {
    spaces: Vec<(u8, Box<dyn MemorySpace + Send>)>,
    acdi: bool,
    acdi_manufacturer: Vec<u8>,
    acdi_user: Vec<u8>,
    unique_ids: Vec<[u8; 8]>,
    lock: u64,
    /// The node whose Lock command took the lock (it may name another node: OlcbChecker's
    /// `mc40` locks with made-up Node IDs). Its presence is what a holder check asks about.
    lock_by: Option<NodeId>,
    /// The lock lapses at this time unless its owner sends another command (or stream data)
    /// first: a client that died does not lock the node for good.
    lock_deadline: Instant,
    frozen: bool,
    /// The node whose Freeze started this upgrade: only it may write space 0xEF or
    /// unfreeze (`None` once it restarted or left: the next Freeze takes over).
    firmware_owner: Option<NodeId>,
    firmware_written: u32,
    /// A transfer into space 0xEF failed since the last write at offset 0: Unfreeze is
    /// refused and the node stays frozen, so that a retry can start again (FWU §5.4.3).
    firmware_aborted: bool,
    /// Unfreeze came from this node while its Write Stream into space 0xEF was still open:
    /// the image ends, and the node unfreezes, when that stream ends.
    unfreeze_pending: Option<NodeId>,
    holder_check: Option<HolderCheck>,
    transfers: Vec<Transfer>,
    pub(crate) user_info_changed: bool,
    /// Space 0xF9 of a train node, kept by the node (`None`: not a train, or the application
    /// serves a space 0xF9 of its own).
    #[cfg(feature = "traction")]
    pub(crate) functions: Option<FunctionMirror>,
    stats: MemoryServerStats,
}

/// Space 0xF9 of a train (Train Control Standard §7.1, FDI TN §3.1): a byte per function
/// address, F0 at 0, kept equal to the train's functions by the node.
#[cfg(feature = "traction")]
#[derive(Debug, Default)]
pub(crate) struct FunctionMirror {
    /// Each function's value as a byte (255 for a larger one).
    pub(crate) values: Vec<u8>,
    /// A write of this node has changed `values` since the train last took them.
    pub(crate) written_by: Option<NodeId>,
}

impl fmt::Debug for MemoryServer {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let spaces: Vec<u8> = self.spaces.iter().map(|(n, _)| *n).collect();
        f.debug_struct("MemoryServer")
            .field("spaces", &spaces)
            .field("acdi", &self.acdi)
            .field("frozen", &self.frozen)
            .field("transfers", &self.transfers)
            .finish_non_exhaustive()
    }
}

impl Default for MemoryServer {
    fn default() -> Self {
        Self::new()
    }
}

impl MemoryServer {
    /// A server with no spaces.
    pub fn new() -> Self {
        MemoryServer {
            spaces: Vec::new(),
            acdi: false,
            acdi_manufacturer: Vec::new(),
            acdi_user: Vec::new(),
            unique_ids: Vec::new(),
            lock: 0,
            lock_by: None,
            lock_deadline: Instant::ZERO,
            frozen: false,
            firmware_owner: None,
            firmware_written: 0,
            firmware_aborted: false,
            unfreeze_pending: None,
            holder_check: None,
            transfers: Vec::new(),
            user_info_changed: false,
            #[cfg(feature = "traction")]
            functions: None,
            stats: MemoryServerStats::default(),
        }
    }

    /// Serves `space` as address space number `number` (replacing one of that number).
    /// Number 0xEF is the firmware target: writable only while frozen.
    pub fn with_space(mut self, number: u8, space: impl MemorySpace + Send + 'static) -> Self {
        self.spaces.retain(|(n, _)| *n != number);
        self.spaces.push((number, Box::new(space)));
        self
    }

    /// Serves the ACDI spaces 0xFC (read-only) and 0xFB (read/write) at the offsets of
    /// node-protocols.md §5.4, filled from the node's SNIP strings; a write to 0xFB changes
    /// the node's SNIP user name and description.
    pub fn with_acdi(mut self) -> Self {
        self.acdi = true;
        self
    }

    /// Event IDs Get Unique ID hands out, each once (MC §4.19). Without any, the command is
    /// refused with 0x1041.
    #[cfg(feature = "optional-commands")]
    pub fn with_unique_ids(mut self, ids: impl IntoIterator<Item = [u8; 8]>) -> Self {
        self.unique_ids.extend(ids);
        self
    }

    /// The space numbered `number`, to read back what was written (ACDI spaces excluded).
    pub fn space(&self, number: u8) -> Option<&(dyn MemorySpace + Send)> {
        self.spaces.iter().find(|(n, _)| *n == number).map(|(_, s)| s.as_ref())
    }

    /// The space numbered `number`, mutable.
    pub fn space_mut(&mut self, number: u8) -> Option<&mut (dyn MemorySpace + Send + 'static)> {
        self.spaces.iter_mut().find(|(n, _)| *n == number).map(|(_, s)| s.as_mut())
    }

    /// In the Firmware Upgrade state (after Freeze of space 0xEF).
    pub fn is_frozen(&self) -> bool {
        self.frozen
    }

    /// What this server adds to the node's Protocol Support Reply: Memory Configuration; CDI
    /// with space 0xFF; ACDI with its spaces ([`with_acdi`](Self::with_acdi)); Firmware
    /// Upgrade with space 0xEF, Firmware Upgrade Active instead while frozen (FWU §5.3).
    pub fn protocols(&self) -> Protocols {
        let mut protocols = Protocols::MEMORY_CONFIGURATION;
        if self.space(SPACE_CDI).is_some() {
            protocols = protocols | Protocols::CDI;
        }
        if self.space(SPACE_FDI).is_some() {
            protocols = protocols | Protocols::FDI;
        }
        if self.acdi {
            protocols = protocols | Protocols::ACDI;
        }
        if self.frozen {
            protocols = protocols | Protocols::FIRMWARE_UPGRADE_ACTIVE;
        } else if self.has_firmware() {
            protocols = protocols | Protocols::FIRMWARE_UPGRADE;
        }
        protocols
    }

    /// Serves a firmware target (space 0xEF).
    pub fn has_firmware(&self) -> bool {
        self.space(SPACE_FIRMWARE).is_some()
    }

    /// Who holds the lock (0: nobody).
    #[cfg(feature = "optional-commands")]
    pub fn lock_owner(&self) -> u64 {
        self.lock
    }

    /// The lock is held by another node than `peer` (and has not lapsed): `peer`'s writes
    /// are refused with 0x2000 (temporary: locked, MC-TN §2.4.4). MC §4.17 makes the lock
    /// voluntary; refusing writes is what keeps two tools from mixing their data.
    fn locked_out(&self, now: Instant, peer: NodeId) -> bool {
        cfg!(feature = "optional-commands") && self.lock != 0 && self.lock != peer.as_raw() && now < self.lock_deadline
    }

    /// The node that took the lock, when the lock keeps `peer` out (it names another node
    /// and has not lapsed).
    fn lock_holder_against(&self, now: Instant, peer: NodeId) -> Option<NodeId> {
        self.lock_by.filter(|_| self.locked_out(now, peer))
    }

    /// The node keeping `peer` from `space` (from writing it, with `write`), with the code
    /// `peer` is refused with while that node is known to be here: another's upgrade
    /// (0x1020, source not permitted) or, for a write, another's lock (0x2000, temporary:
    /// locked).
    fn kept_out_by(&self, now: Instant, peer: NodeId, space: u8, write: bool) -> Option<(NodeId, ErrorCode)> {
        match self.firmware_owner {
            Some(owner) if self.firmware_refused(peer, space) => Some((owner, ErrorCode::SOURCE_NOT_PERMITTED)),
            _ if write => self.lock_holder_against(now, peer).map(|holder| (holder, ErrorCode::TEMPORARY)),
            _ => None,
        }
    }

    /// The refusal of `peer` because another node holds `space` ([`kept_out_by`](Self::kept_out_by)),
    /// if one does: its code once the holder answered a Verify Node ID, 0x2000 (temporary:
    /// the sender resends) while it is asked.
    fn refusal(&mut self, cx: &mut Cx<'_>, peer: NodeId, space: u8, write: bool) -> Option<ErrorCode> {
        let (holder, code) = self.kept_out_by(cx.now, peer, space, write)?;
        // `peer` itself took a lock naming another node: nobody to ask.
        Some(if holder == peer || self.holder_answered(cx, holder) { code } else { ErrorCode::TEMPORARY })
    }

    /// Whether `holder` answered the Verify Node ID of the check running; without a check
    /// of it, one starts (a single one at a time: its Verify is the only message sent).
    fn holder_answered(&mut self, cx: &mut Cx<'_>, holder: NodeId) -> bool {
        if let Some(check) = self.holder_check.filter(|c| c.holder == holder) {
            return check.answered;
        }
        let deadline = cx.now + cx.options.holder_answer_timeout;
        self.holder_check = Some(HolderCheck { holder, deadline, answered: false });
        // Queued whatever the answers waiting: a Verify dropped would find a holder gone that
        // is not (one check at a time bounds them).
        let verify = Message::addressed(Mti::VERIFY_NODE_ID_ADDRESSED, cx.out.node, holder, Vec::new());
        cx.out.transmit(verify);
        false
    }

    /// A Verified Node ID (or a command) from `node`: a holder being checked is still here.
    pub(crate) fn peer_verified(&mut self, node: NodeId) {
        if let Some(check) = self.holder_check.as_mut().filter(|c| c.holder == node) {
            check.answered = true;
        }
    }

    /// Ends the holder check whose time is up; a holder that did not answer has left:
    /// what it held ends here, and the node hears it lost ([`Cx::departed`]).
    fn end_holder_check(&mut self, cx: &mut Cx<'_>) {
        let Some(check) = self.holder_check.filter(|c| cx.now >= c.deadline) else { return };
        self.holder_check = None;
        if !check.answered {
            bump(&mut self.stats.holders_gone);
            self.forget_peer(Some(check.holder));
            cx.departed = Some(check.holder);
        }
    }

    /// `peer` did something: a lock it holds (or took) lasts on.
    fn touch_lock(&mut self, now: Instant, timeout: openlcb_stream::Duration, peer: NodeId) {
        if cfg!(feature = "optional-commands")
            && self.lock != 0
            && (self.lock == peer.as_raw() || self.lock_by == Some(peer))
        {
            self.lock_deadline = now + timeout;
        }
    }

    /// The stream transfers running: never any without the `streams` feature, which the
    /// compiler is told here, so that it links none of their handling.
    fn transfers(&self) -> &[Transfer] {
        if cfg!(feature = "streams") { &self.transfers } else { &[] }
    }

    /// Stream transfers running (or waiting for their stream).
    pub fn active_streams(&self) -> usize {
        self.transfers.len()
    }

    /// Counters.
    pub fn stats(&self) -> MemoryServerStats {
        self.stats
    }

    /// The node's SNIP strings, to mirror in the ACDI spaces.
    pub(crate) fn mirror_snip(&mut self, snip: &SnipInfo) {
        self.acdi_manufacturer = acdi_manufacturer_bytes(snip);
        self.acdi_user = acdi_user_bytes(snip);
    }

    pub(crate) fn acdi_user(&self) -> &[u8] {
        &self.acdi_user
    }

    // ----- spaces, ACDI and a train's functions included -----

    /// The bytes of a space the server keeps itself: the ACDI spaces, a train's 0xF9.
    fn own_bytes(&self, space: u8) -> Option<&[u8]> {
        match space {
            SPACE_ACDI_MANUFACTURER if self.acdi => Some(&self.acdi_manufacturer),
            SPACE_ACDI_USER if self.acdi => Some(&self.acdi_user),
            #[cfg(feature = "traction")]
            SPACE_FUNCTIONS => self.functions.as_ref().map(|mirror| mirror.values.as_slice()),
            _ => None,
        }
    }

    fn space_len(&self, space: u8) -> Option<u32> {
        match self.own_bytes(space) {
            Some(bytes) => u32::try_from(bytes.len()).ok(),
            None => self.space(space).map(|s| s.len()),
        }
    }

    /// Read-only now: by nature, or the firmware space outside the Firmware Upgrade state.
    fn read_only(&self, space: u8) -> bool {
        match space {
            SPACE_ACDI_MANUFACTURER if self.acdi => true,
            SPACE_ACDI_USER if self.acdi => false,
            #[cfg(feature = "traction")]
            SPACE_FUNCTIONS if self.functions.is_some() => false,
            SPACE_FIRMWARE => !self.frozen,
            _ => self.space(space).is_none_or(|s| s.read_only()),
        }
    }

    /// Reads of `space` are refused: its bytes cannot be read back
    /// ([`MemorySpace::write_only`]).
    fn write_only(&self, space: u8) -> bool {
        self.own_bytes(space).is_none() && self.space(space).is_some_and(|s| s.write_only())
    }

    fn read_space(&mut self, space: u8, address: u32, buf: &mut [u8]) -> Result<usize, SpaceError> {
        let len = self.space_len(space).ok_or(SpaceError::OutOfBounds)?;
        if address >= len {
            return Err(SpaceError::OutOfBounds);
        }
        let room = usize::try_from(len - address).unwrap_or(usize::MAX).min(buf.len());
        let buf = buf.get_mut(..room).unwrap_or_default();
        if let Some(bytes) = self.own_bytes(space) {
            return read_slice(bytes, address, buf);
        }
        self.space_mut(space).ok_or(SpaceError::OutOfBounds)?.read(address, buf)
    }

    /// Stores `data` at `address` of `space` for `peer`, the writer (a train's Set Function
    /// comes from it).
    fn write_space(
        &mut self,
        #[cfg_attr(not(feature = "traction"), expect(unused_variables))] peer: NodeId,
        space: u8,
        address: u32,
        data: &[u8],
    ) -> Result<(), SpaceError> {
        let len = self.space_len(space).ok_or(SpaceError::OutOfBounds)?;
        if self.read_only(space) {
            return Err(SpaceError::ReadOnly);
        }
        let end = u32::try_from(data.len()).ok().and_then(|n| address.checked_add(n)).ok_or(SpaceError::OutOfBounds)?;
        if end > len {
            return Err(SpaceError::OutOfBounds);
        }
        let range = address as usize..end as usize;
        #[cfg(feature = "traction")]
        if let (SPACE_FUNCTIONS, Some(mirror)) = (space, &mut self.functions) {
            mirror.written_by = Some(peer);
            mirror.values.get_mut(range).ok_or(SpaceError::OutOfBounds)?.copy_from_slice(data);
            return Ok(());
        }
        if self.own_bytes(space).is_some() {
            // ACDI §5.1: byte 0 of space 0xFB is the layout's version, not the user's to write.
            if address == 0 {
                return Err(SpaceError::ReadOnly);
            }
            self.acdi_user.get_mut(range).ok_or(SpaceError::OutOfBounds)?.copy_from_slice(data);
            self.user_info_changed = true;
            return Ok(());
        }
        if space == SPACE_FIRMWARE && address == 0 && self.firmware_aborted {
            self.restart_image();
        }
        let written = self.space_mut(space).ok_or(SpaceError::OutOfBounds)?.write(address, data);
        if space == SPACE_FIRMWARE {
            match written {
                Ok(()) => self.firmware_written = self.firmware_written.max(end),
                Err(_) => self.firmware_aborted = true,
            }
        }
        written
    }

    /// A new image begins: nothing written, nothing aborted, the space's bytes discarded.
    fn restart_image(&mut self) {
        self.firmware_written = 0;
        self.firmware_aborted = false;
        if let Some(space) = self.space_mut(SPACE_FIRMWARE) {
            space.discard();
        }
    }

    /// Space 0xEF while another node's upgrade holds it: refused (0x1020, source not
    /// permitted), so that two loaders never mix their images.
    fn firmware_refused(&self, peer: NodeId, space: u8) -> bool {
        space == SPACE_FIRMWARE && self.frozen && self.firmware_owner.is_some_and(|owner| owner != peer)
    }

    /// The Options reply (node-protocols.md §3.7): stream bit 0x01 only with streams (C-5).
    fn options(&self, streams: bool) -> OptionsReply {
        let mut commands = OptionsReply::UNALIGNED_READS | OptionsReply::UNALIGNED_WRITES;
        if cfg!(feature = "optional-commands") {
            commands |= OptionsReply::WRITE_UNDER_MASK;
        }
        if self.acdi {
            commands |=
                OptionsReply::ACDI_MANUFACTURER_READ | OptionsReply::ACDI_USER_READ | OptionsReply::ACDI_USER_WRITE;
        }
        let acdi: &[u8] = if self.acdi { &[SPACE_ACDI_USER, SPACE_ACDI_MANUFACTURER] } else { &[] };
        // The lowest and highest space served, in plain loops (no iterator chain: flash).
        let mut bounds: Option<(u8, u8)> = None;
        let mut take = |n: u8| bounds = Some(bounds.map_or((n, n), |(low, high)| (low.min(n), high.max(n))));
        for (n, _) in &self.spaces {
            take(*n);
        }
        for n in acdi {
            take(*n);
        }
        #[cfg(feature = "traction")]
        if self.functions.is_some() {
            take(SPACE_FUNCTIONS);
        }
        let (lowest, highest) = bounds.unwrap_or((0xFD, 0xFF));
        OptionsReply {
            commands,
            write_lengths: OptionsReply::BASE_WRITE_LENGTHS | if streams { OptionsReply::STREAMS } else { 0 },
            highest_space: highest,
            lowest_space: Some(lowest),
            name: Vec::new(),
        }
    }

    fn space_info(&self, space: u8) -> SpaceInfoReply {
        match self.space_len(space) {
            Some(len) => SpaceInfoReply {
                space,
                present: true,
                highest_address: Some(len.saturating_sub(1)),
                read_only: self.read_only(space),
                lowest_address: None,
                description: Vec::new(),
            },
            None => SpaceInfoReply {
                space,
                present: false,
                highest_address: None,
                read_only: false,
                lowest_address: None,
                description: Vec::new(),
            },
        }
    }

    // ----- commands -----

    /// A command datagram from `peer`: answers it with Datagram OK or Rejected and, where
    /// the command has one, a reply datagram.
    pub(crate) fn on_command(&mut self, cx: &mut Cx<'_>, peer: NodeId, bytes: &[u8]) {
        bump(&mut self.stats.commands);
        if !cx.has_reply_room(peer) {
            // No reply could be queued: refused for now (the sender resends) rather than
            // promised and dropped. The bound is per peer, so one that never acknowledges
            // its replies does not starve the others.
            return self.reject(cx, peer, ErrorCode::BUFFER_UNAVAILABLE);
        }
        // A holder being checked that sends a command is still here.
        self.peer_verified(peer);
        self.end_holder_check(cx);
        self.touch_lock(cx.now, cx.options.lock_timeout, peer);
        let command = match Command::parse(bytes) {
            Ok(command) => command,
            Err(DecodeError::UnknownCommand(_) | DecodeError::NotMemoryConfiguration) => {
                return self.reject(cx, peer, codes::UNKNOWN_COMMAND);
            }
            Err(_) => return self.reject(cx, peer, codes::INVALID_ARGUMENTS),
        };
        let form = SpaceForm::of(bytes);
        match command {
            Command::Read { space, address, count } => {
                if self.space_len(space).is_none() {
                    return self.reject(cx, peer, codes::UNKNOWN_SPACE);
                }
                if self.write_only(space) {
                    return self.reject(cx, peer, codes::NOT_READABLE);
                }
                let mut buf = [0u8; MAX_DATA_LEN];
                let want = usize::from(count).clamp(1, MAX_DATA_LEN);
                let reply = match self.read_space(space, address, buf.get_mut(..want).unwrap_or_default()) {
                    Ok(n) if n > 0 => read_ok_bytes(space, address, buf.get(..n).unwrap_or_default(), form),
                    Ok(_) => failed_bytes(FailedKind::Read, Some(space), address, codes::OUT_OF_BOUNDS, form),
                    Err(e) => failed_bytes(FailedKind::Read, Some(space), address, e.code(), form),
                };
                cx.answer(peer, reply);
            }
            Command::Write { space, address, data } => self.write(cx, peer, (space, form), address, &data, None),
            Command::WriteUnderMask { space, address, mask, data } if cfg!(feature = "optional-commands") => {
                self.write(cx, peer, (space, form), address, &data, Some(&mask));
            }
            Command::ReadStream { space, address, destination_stream, count } => {
                self.read_stream(cx, peer, (space, form), address, destination_stream, count);
            }
            Command::WriteStream { space, address, source_stream } => {
                self.write_stream(cx, peer, (space, form), address, source_stream);
            }
            Command::GetOptions => {
                cx.answer(peer, self.options(cx.streams_enabled()).to_bytes());
            }
            Command::GetSpaceInfo { space } => {
                cx.answer(peer, self.space_info(space).to_bytes());
            }
            Command::Lock { node } if cfg!(feature = "optional-commands") => {
                // MC §4.17: test-and-set; a Node ID of 0 releases. A lapsed lock is free. The
                // node that took it gets its answers at once, whatever Node IDs it names; for
                // another, a taker that is gone is found so first (refused for now).
                if let Some(taker) = self.lock_by.filter(|by| *by != peer && self.lock != 0)
                    && node != 0
                    && cx.now < self.lock_deadline
                    && !self.holder_answered(cx, taker)
                {
                    return self.reject(cx, peer, ErrorCode::TEMPORARY);
                }
                if self.lock == 0 || node == 0 || cx.now >= self.lock_deadline {
                    self.lock = node;
                    self.lock_by = (node != 0).then_some(peer);
                    self.lock_deadline = cx.now + cx.options.lock_timeout;
                }
                cx.answer(peer, lock_bytes(self.lock));
            }
            Command::GetUniqueId { count } if cfg!(feature = "optional-commands") => {
                if self.unique_ids.is_empty() {
                    return self.reject(cx, peer, codes::UNKNOWN_COMMAND);
                }
                let n = usize::from(count.max(1)).min(self.unique_ids.len());
                let ids: Vec<[u8; 8]> = self.unique_ids.drain(..n).collect();
                cx.answer(peer, unique_ids_bytes(&ids));
            }
            // Without the `optional-commands` feature: none is implemented.
            Command::Lock { .. } | Command::GetUniqueId { .. } | Command::WriteUnderMask { .. } => {
                self.reject(cx, peer, codes::UNKNOWN_COMMAND);
            }
            Command::Freeze { space } => {
                if space != SPACE_FIRMWARE || !self.has_firmware() {
                    return self.reject(cx, peer, codes::UNKNOWN_SPACE);
                }
                if let Some(code) = self.refusal(cx, peer, SPACE_FIRMWARE, false) {
                    return self.reject(cx, peer, code);
                }
                // C-11: the OK, then Initialization Complete in the new state (FWU §5.2). A
                // Freeze while frozen gets the same answer (FWU-TN §2.6.2).
                self.frozen = true;
                self.firmware_owner = Some(peer);
                self.restart_image();
                cx.ok(peer, OkFlags::default());
                cx.announce = true;
                cx.out.event(crate::NodeEvent::Memory(E::Frozen { by: peer }));
            }
            Command::Unfreeze { space } => {
                if space != SPACE_FIRMWARE || !self.has_firmware() {
                    return self.reject(cx, peer, codes::UNKNOWN_SPACE);
                }
                if !self.frozen {
                    return cx.ok(peer, OkFlags::default());
                }
                if let Some(code) = self.refusal(cx, peer, SPACE_FIRMWARE, false) {
                    return self.reject(cx, peer, code);
                }
                if self.firmware_stream_open(peer) {
                    // On CAN the client's Unfreeze datagram may overtake the end of its own
                    // stream: the bytes still coming belong to the image, and the answer
                    // waits for the stream's end.
                    self.unfreeze_pending = Some(peer);
                } else {
                    self.unfreeze(cx, peer);
                }
            }
            Command::UpdateComplete => self.acknowledge(cx, peer, E::UpdateComplete { by: peer }),
            Command::Reset => {
                cx.reboot = true;
                self.acknowledge(cx, peer, E::ResetRequested { by: peer });
            }
            Command::FactoryReset { node } => {
                if node != cx.out.node.as_raw() {
                    return self.reject(cx, peer, codes::INVALID_ARGUMENTS);
                }
                self.acknowledge(cx, peer, E::FactoryResetRequested { by: peer });
            }
        }
    }

    fn acknowledge(&mut self, cx: &mut Cx<'_>, peer: NodeId, event: MemoryEvent) {
        cx.ok(peer, OkFlags::default());
        cx.out.event(crate::NodeEvent::Memory(event));
    }

    fn reject(&mut self, cx: &mut Cx<'_>, peer: NodeId, code: ErrorCode) {
        bump(&mut self.stats.rejected);
        cx.reject(peer, code);
    }

    /// Write and Write Under Mask: an unknown space or a read-only one is refused; a write
    /// done at once gets the OK without Reply Pending (C-9); a write that fails gets the OK
    /// with Reply Pending and a Failed reply.
    fn write(
        &mut self,
        cx: &mut Cx<'_>,
        peer: NodeId,
        (space, form): (u8, SpaceForm),
        address: u32,
        data: &[u8],
        mask: Option<&[u8]>,
    ) {
        if self.space_len(space).is_none() {
            return self.reject(cx, peer, codes::UNKNOWN_SPACE);
        }
        if self.read_only(space) {
            return self.reject(cx, peer, codes::READ_ONLY);
        }
        if let Some(code) = self.refusal(cx, peer, space, true) {
            return self.reject(cx, peer, code);
        }
        let mut merged = [0u8; MAX_DATA_LEN];
        let result = match mask {
            None => self.write_space(peer, space, address, data).and_then(|()| self.commit(space)),
            Some(mask) => {
                let merged = merged.get_mut(..data.len()).unwrap_or_default();
                self.read_space(space, address, merged).and_then(|n| {
                    if n < merged.len() {
                        return Err(SpaceError::OutOfBounds);
                    }
                    for ((old, new), m) in merged.iter_mut().zip(data).zip(mask) {
                        *old = (*old & !m) | (new & m);
                    }
                    self.write_space(peer, space, address, merged).and_then(|()| self.commit(space))
                })
            }
        };
        match result {
            // node-protocols.md C-9 allows either form; each of OpenMRN's clients needs its
            // own: bootloader_client's datagram path aborts on Reply Pending, and its
            // MemoryConfigClient (memconfig_utils, configuration tools) takes an OK alone as
            // the end of the whole write, dropping every chunk after the first.
            Ok(()) if space == SPACE_FIRMWARE => cx.ok(peer, OkFlags::default()),
            Ok(()) => {
                cx.answer(peer, write_ok_bytes(space, address, form));
            }
            Err(e) => {
                cx.answer(peer, failed_bytes(FailedKind::Write, Some(space), address, e.code(), form));
            }
        }
    }

    /// The checks a stream command passes before its OK: space known, address inside,
    /// readable for a Read Stream, writable for a Write Stream, streams on, room for one
    /// more transfer, and for one more of this peer's.
    fn check_stream(
        &mut self,
        cx: &mut Cx<'_>,
        peer: NodeId,
        space: u8,
        address: u32,
        write: bool,
    ) -> Result<(), ErrorCode> {
        if !cx.streams_enabled() {
            return Err(codes::UNKNOWN_COMMAND);
        }
        let len = self.space_len(space).ok_or(codes::UNKNOWN_SPACE)?;
        if !write && self.write_only(space) {
            return Err(codes::NOT_READABLE);
        }
        if write && self.read_only(space) {
            return Err(codes::READ_ONLY);
        }
        if let Some(code) = write.then(|| self.refusal(cx, peer, space, true)).flatten() {
            return Err(code);
        }
        if address >= len {
            return Err(codes::OUT_OF_BOUNDS);
        }
        let per_peer = (cx.options.max_server_streams / 2).max(1);
        let peers = self.transfers().iter().filter(|t| t.peer == peer).count();
        if self.transfers.len() >= cx.options.max_server_streams || peers >= per_peer {
            return Err(codes::BUSY);
        }
        Ok(())
    }

    /// Read Stream in the order of C-4: Datagram OK (Reply Pending) at once, the Initiate
    /// Request proposing the command's DID (none for 0xFF, wire-spec §4.1), the Reply once
    /// the stream is open, then data.
    fn read_stream(
        &mut self,
        cx: &mut Cx<'_>,
        peer: NodeId,
        (space, form): (u8, SpaceForm),
        address: u32,
        did: u8,
        count: u32,
    ) {
        if let Err(code) = self.check_stream(cx, peer, space, address, false) {
            return self.reject(cx, peer, code);
        }
        cx.ok(peer, OkFlags { reply_pending: true, timeout_exponent: 0 });
        let len = self.space_len(space).unwrap_or(0);
        // C-6: 0 and 0xFFFFFFFF both read to the end of the space.
        let available = len.saturating_sub(address);
        let want = if count == 0 || count == u32::MAX { available } else { count.min(available) };
        let mut options = OpenOptions::new(peer, cx.options.stream_window.max(1));
        if let Some(did) = StreamId::new(did) {
            options = options.proposed_destination(did);
        }
        match cx.streams.open(cx.now, options) {
            Ok(handle) => self.transfers.push(Transfer {
                peer,
                form,
                job: Job::Read {
                    handle,
                    space,
                    address,
                    next: address,
                    end: address.saturating_add(want),
                    count,
                    opened: false,
                },
            }),
            Err(_) => {
                bump(&mut self.stats.streams_failed);
                cx.send_reply(peer, failed_bytes(FailedKind::ReadStream, Some(space), address, codes::BUSY, form));
            }
        }
    }

    /// Write Stream (C-2, as target): Datagram OK (Reply Pending); the Write Stream Reply,
    /// naming the SID and the DID this node assigns, goes out when the client shows what it
    /// waits for ([`WriteReply`]): after the stream's Complete if the stream is asked for
    /// within [`MemoryConfigOptions::write_stream_reply_delay`], else at that time, before
    /// the stream. Later errors end the stream with TDE.
    fn write_stream(&mut self, cx: &mut Cx<'_>, peer: NodeId, (space, form): (u8, SpaceForm), address: u32, sid: u8) {
        if let Err(code) = self.check_stream(cx, peer, space, address, true) {
            return self.reject(cx, peer, code);
        }
        if StreamId::new(sid).is_none() {
            return self.reject(cx, peer, codes::INVALID_ARGUMENTS);
        }
        cx.ok(peer, OkFlags { reply_pending: true, timeout_exponent: 0 });
        let did = cx.streams.next_destination_id(peer).map_or(0xFF, StreamId::as_raw);
        // A repeated command (its OK lost) replaces the transfer waiting for the same SID;
        // the reply promised for the first goes out first.
        while let Some(index) = self
            .transfers()
            .iter()
            .position(|t| t.peer == peer && matches!(t.job, Job::Write { sid: s, handle: None, .. } if s == sid))
        {
            if matches!(self.write_reply(index), Some(WriteReply::Due(_))) {
                self.send_write_reply(cx, index, None);
            }
            self.transfers.swap_remove(index);
        }
        let deadline = cx.now + cx.options.stream_timeout;
        let reply = WriteReply::Due(cx.now + cx.options.write_stream_reply_delay);
        let job = Job::Write { sid, did, handle: None, space, address, next: address, deadline, reply };
        self.transfers.push(Transfer { peer, form, job });
    }

    /// Sends the Write Stream Reply of the transfer at `index` (a failure with `error`).
    fn send_write_reply(&mut self, cx: &mut Cx<'_>, index: usize, error: Option<ErrorCode>) {
        let Some(Transfer { peer, form, job: Job::Write { sid, did, space, address, reply, .. } }) =
            self.transfers.get_mut(index)
        else {
            return;
        };
        *reply = WriteReply::Sent;
        let reply = match error {
            None => write_stream_ok_bytes(Some(*space), *address, Some((*sid, *did)), *form),
            Some(code) => failed_bytes(FailedKind::WriteStream, Some(*space), *address, code, *form),
        };
        let peer = *peer;
        cx.send_reply(peer, reply);
    }

    // ----- streams -----

    fn position(&self, handle: StreamHandle) -> Option<usize> {
        self.transfers().iter().position(|t| match t.job {
            Job::Read { handle: h, .. } => h == handle,
            Job::Write { handle: h, .. } => h == Some(handle),
        })
    }

    /// Takes a stream event of one of the server's transfers; false for any other.
    pub(crate) fn on_stream_event(&mut self, cx: &mut Cx<'_>, event: &Event) -> bool {
        let claimed = self.transfer_event(cx, event);
        if let Some(peer) = self.unfreeze_pending.filter(|p| !self.firmware_stream_open(*p)) {
            self.unfreeze_pending = None;
            self.unfreeze(cx, peer);
        }
        claimed
    }

    /// Ends every Write Stream transfer of `peer` (its stream aborted with `code` when open),
    /// as an end that failed; a pending Unfreeze is then answered. Whether there was one.
    pub(crate) fn end_write_streams_of(&mut self, cx: &mut Cx<'_>, peer: NodeId, code: ErrorCode) -> bool {
        let mut ended = false;
        while let Some(index) =
            self.transfers().iter().position(|t| t.peer == peer && matches!(t.job, Job::Write { .. }))
        {
            if let Some(Transfer { job: Job::Write { handle: Some(handle), .. }, .. }) = self.transfers.get(index) {
                let _ = cx.streams.abort(cx.now, *handle, code);
            }
            self.end(index, false);
            ended = true;
        }
        // A pending Unfreeze waits for a firmware stream: only an ended one can release it.
        if ended && let Some(peer) = self.unfreeze_pending.filter(|p| !self.firmware_stream_open(*p)) {
            self.unfreeze_pending = None;
            self.unfreeze(cx, peer);
        }
        ended
    }

    /// A Write Stream of `peer` into space 0xEF is open (its stream has started).
    fn firmware_stream_open(&self, peer: NodeId) -> bool {
        self.transfers
            .iter()
            .any(|t| t.peer == peer && matches!(t.job, Job::Write { handle: Some(_), space: SPACE_FIRMWARE, .. }))
    }

    /// Answers the owner's Unfreeze. The image is what was written while frozen, once the
    /// space has stored it ([`MemorySpace::complete`]): then the OK, and the node leaves the
    /// Firmware Upgrade state. An aborted transfer (0x1089) or an image the space could not
    /// store is refused, and so is an Unfreeze with nothing written (no image); the node
    /// stays frozen for a retry (or a Reboot), as OpenMRN's bootloader
    /// refuses an Unfreeze whose flash did not complete.
    fn unfreeze(&mut self, cx: &mut Cx<'_>, by: NodeId) {
        let image_len = self.firmware_written;
        let aborted = self.firmware_aborted;
        let stored = match self.space_mut(SPACE_FIRMWARE) {
            // No byte written is no image (0x1089, firmware invalid, FWU §6.2), not an empty one.
            _ if aborted || image_len == 0 => Err(codes::FIRMWARE_CORRUPTED),
            Some(space) => space.complete(image_len).map_err(|e| e.code()),
            None => Err(codes::UNKNOWN_SPACE),
        };
        if let Err(code) = stored {
            self.reject(cx, by, code);
            return cx.out.event(crate::NodeEvent::Memory(E::UpgradeRefused { by, code }));
        }
        cx.ok(by, OkFlags::default());
        self.frozen = false;
        self.firmware_owner = None;
        cx.announce = true;
        cx.out.event(crate::NodeEvent::Memory(E::Unfrozen { by, image_len }));
    }

    fn transfer_event(&mut self, cx: &mut Cx<'_>, event: &Event) -> bool {
        if let Event::IncomingRequest { handle, info } = event {
            let waiting = self.transfers.iter_mut().find(|t| {
                t.peer == info.peer
                    && matches!(t.job, Job::Write { sid, handle: None, .. } if sid == info.source_stream.as_raw())
            });
            let Some(transfer) = waiting else { return false };
            let Job::Write { handle: slot, space, reply, did, .. } = &mut transfer.job else { return false };
            let space_window = self.spaces.iter().find(|(n, _)| n == space).and_then(|(_, s)| s.write_window());
            let window = space_window.unwrap_or(cx.options.write_stream_window).max(1);
            if cx.streams.accept_with(cx.now, *handle, AcceptOptions::new(Some(window), false)).is_ok() {
                *slot = Some(*handle);
                if let Some(assigned) = cx.streams.stream_info(*handle).and_then(|i| i.destination_stream) {
                    *did = assigned.as_raw();
                }
                if matches!(reply, WriteReply::Due(_)) {
                    // The client initiated without waiting for the reply: it comes after Complete.
                    *reply = WriteReply::AfterComplete;
                }
            }
            return true;
        }
        if matches!(event, Event::IncomingRequest { .. } | Event::Sent { .. }) {
            return false;
        }
        let handle = event.handle();
        let Some(index) = self.position(handle) else { return false };
        match event {
            Event::Opened { info, .. } => {
                if let Some(Transfer { peer, form, job: Job::Read { space, address, count, opened, .. } }) =
                    self.transfers.get_mut(index)
                {
                    *opened = true;
                    let streams = (info.source_stream.as_raw(), info.destination_stream.map_or(0xFF, StreamId::as_raw));
                    let reply = read_stream_ok_bytes(Some(*space), *address, streams, Some(*count), *form);
                    let peer = *peer;
                    cx.send_reply(peer, reply);
                }
                self.pump_read(cx, index);
            }
            Event::Writable { .. } => self.pump_read(cx, index),
            Event::Readable { .. } => self.drain_write(cx, index, false),
            Event::Finished { .. } => self.drain_write(cx, index, true),
            Event::Rejected { code, .. } => {
                if let Some(Transfer { peer, form, job: Job::Read { space, address, .. } }) = self.transfers.get(index)
                {
                    let reply = failed_bytes(FailedKind::ReadStream, Some(*space), *address, ErrorCode(code.0), *form);
                    let peer = *peer;
                    cx.send_reply(peer, reply);
                }
                self.end(index, false);
            }
            _ => {
                // A Read Stream whose stream never opened still owes its promised reply.
                if let Some(Transfer { peer, form, job: Job::Read { space, address, opened: false, .. } }) =
                    self.transfers.get(index)
                {
                    let reply = failed_bytes(FailedKind::ReadStream, Some(*space), *address, ErrorCode::TIMEOUT, *form);
                    let peer = *peer;
                    cx.send_reply(peer, reply);
                }
                // So does a Write Stream whose reply waited for a Complete that never came.
                if self.write_reply(index) == Some(WriteReply::AfterComplete) {
                    self.send_write_reply(cx, index, Some(ErrorCode::TIMEOUT));
                }
                self.end(index, false);
            }
        }
        true
    }

    fn end(&mut self, index: usize, done: bool) {
        if index < self.transfers.len() {
            // What a Write Stream that failed wrote stays: committed as a finished one is
            // (before its reply, in `drain_write`).
            if !done {
                let _ = self.commit_transfer(index);
            }
            let transfer = self.transfers.swap_remove(index);
            if done {
                bump(&mut self.stats.streams_done);
            } else {
                bump(&mut self.stats.streams_failed);
                // FWU §5.4.3: a stream into the image that ends early aborts the upgrade.
                if matches!(transfer.job, Job::Write { space: SPACE_FIRMWARE, .. }) {
                    self.firmware_aborted = true;
                }
            }
        }
    }

    /// Sends as much of a Read Stream as the credit allows; finishes at the end.
    fn pump_read(&mut self, cx: &mut Cx<'_>, index: usize) {
        let mut buf = [0u8; CHUNK];
        loop {
            let Some(Transfer { job: Job::Read { handle, space, next, end, opened: true, .. }, .. }) =
                self.transfers.get(index)
            else {
                return;
            };
            let (handle, space, next, end) = (*handle, *space, *next, *end);
            if next >= end {
                cx.finish_stream(handle);
                return self.end(index, true);
            }
            // Without credit, one byte still goes to `write`: coming up short is what makes
            // the endpoint raise `Writable` when the next Proceed arrives.
            let credit = (cx.streams.credit(handle).unwrap_or(0) as usize).max(1);
            let n = credit.min(CHUNK).min(usize::try_from(end - next).unwrap_or(CHUNK));
            let chunk = buf.get_mut(..n).unwrap_or_default();
            let read = match self.read_space(space, next, chunk) {
                Ok(0) | Err(_) => {
                    let _ = cx.streams.abort(cx.now, handle, codes::OUT_OF_BOUNDS);
                    return self.end(index, false);
                }
                Ok(read) => read,
            };
            let taken = cx.streams.write(cx.now, handle, buf.get(..read).unwrap_or_default()).unwrap_or(0);
            if let Some(Transfer { job: Job::Read { next, .. }, .. }) = self.transfers.get_mut(index) {
                *next = next.saturating_add(u32::try_from(taken).unwrap_or(0));
            }
            if taken < read {
                return;
            }
        }
    }

    /// Writes what a Write Stream has delivered into the space; a space error ends the
    /// stream with TDE carrying its code.
    fn drain_write(&mut self, cx: &mut Cx<'_>, index: usize, finished: bool) {
        let mut buf = [0u8; CHUNK];
        loop {
            let Some(Transfer { peer, job: Job::Write { handle: Some(handle), space, next, .. }, .. }) =
                self.transfers.get(index)
            else {
                return;
            };
            let (peer, handle, space, at) = (*peer, *handle, *space, *next);
            let n = cx.streams.read(cx.now, handle, &mut buf).unwrap_or(0);
            if n == 0 {
                break;
            }
            // Every byte the space can hold is stored; what lies past its end ends the stream.
            let room = self.space_len(space).map_or(0, |len| len.saturating_sub(at));
            let fits = n.min(usize::try_from(room).unwrap_or(usize::MAX));
            let stored = match buf.get(..fits).filter(|b| !b.is_empty()) {
                Some(part) => self.write_space(peer, space, at, part),
                None => Ok(()),
            };
            if let Err(e) = stored.and(if fits < n { Err(SpaceError::OutOfBounds) } else { Ok(()) }) {
                let _ = cx.streams.abort(cx.now, handle, e.code());
                if self.write_reply(index) == Some(WriteReply::AfterComplete) {
                    self.send_write_reply(cx, index, Some(e.code()));
                }
                return self.end(index, false);
            }
            let deadline = cx.now + cx.options.stream_timeout;
            if let Some(Transfer { peer, job: Job::Write { next, deadline: d, .. }, .. }) =
                self.transfers.get_mut(index)
            {
                *next = next.saturating_add(n as u32);
                *d = deadline;
                let peer = *peer;
                self.touch_lock(cx.now, cx.options.lock_timeout, peer);
            }
        }
        if finished {
            let stored = self.commit_transfer(index).err().map(|e| e.code());
            if self.write_reply(index) == Some(WriteReply::AfterComplete) {
                self.send_write_reply(cx, index, stored);
            }
            self.end(index, stored.is_none());
        }
    }

    /// [`MemorySpace::commit`] of `space`, at the end of a write command.
    fn commit(&mut self, space: u8) -> Result<(), SpaceError> {
        self.space_mut(space).map_or(Ok(()), |s| s.commit())
    }

    /// [`MemorySpace::commit`] of the space the Write Stream at `index` writes.
    fn commit_transfer(&mut self, index: usize) -> Result<(), SpaceError> {
        match self.transfers.get(index) {
            Some(Transfer { job: Job::Write { space, .. }, .. }) => self.commit(*space),
            _ => Ok(()),
        }
    }

    /// Where the Write Stream Reply of the transfer at `index` stands.
    fn write_reply(&self, index: usize) -> Option<WriteReply> {
        match self.transfers.get(index) {
            Some(Transfer { job: Job::Write { reply, .. }, .. }) => Some(*reply),
            _ => None,
        }
    }

    pub(crate) fn poll_timeout(&self) -> Option<Instant> {
        let check = self.holder_check.map(|c| c.deadline);
        self.transfers().iter().fold(check, |next, t| match t.job {
            Job::Write { reply: WriteReply::Due(at), .. } | Job::Write { handle: None, deadline: at, .. } => {
                earliest(next, Some(at))
            }
            _ => next,
        })
    }

    /// Sends the Write Stream Replies that are due (their clients wait for them before the
    /// stream), and forgets a Write Stream whose stream never came (the streams themselves
    /// have the endpoint's timers).
    pub(crate) fn handle_timeout(&mut self, cx: &mut Cx<'_>) {
        self.end_holder_check(cx);
        let now = cx.now;
        while let Some(index) = self
            .transfers()
            .iter()
            .position(|t| matches!(t.job, Job::Write { reply: WriteReply::Due(at), .. } if at <= now))
        {
            self.send_write_reply(cx, index, None);
        }
        while let Some(index) = self
            .transfers()
            .iter()
            .position(|t| matches!(t.job, Job::Write { handle: None, deadline, .. } if deadline <= now))
        {
            self.end(index, false);
        }
    }

    /// The node reinitializes (Reset/Reboot): no transfer, no lock, not frozen.
    pub(crate) fn reinitialize(&mut self) {
        self.transfers.clear();
        self.holder_check = None;
        self.lock = 0;
        self.lock_by = None;
        self.frozen = false;
        self.unfreeze_pending = None;
    }

    /// `peer` restarted or is gone: its transfers waiting for a stream are dropped (open
    /// streams end through the endpoint's events), its lock is released, and its upgrade
    /// may be taken over.
    pub(crate) fn forget_peer(&mut self, peer: Option<NodeId>) {
        if peer.is_none_or(|p| p.as_raw() == self.lock || Some(p) == self.lock_by) {
            self.lock = 0;
            self.lock_by = None;
        }
        // By position and an ordered remove: no `retain` (flash).
        while let Some(index) = self
            .transfers()
            .iter()
            .position(|t| peer.is_none_or(|p| p == t.peer) && matches!(t.job, Job::Write { handle: None, .. }))
        {
            self.transfers.remove(index);
        }
        // An upgrade whose owner is gone may be taken over by the next Freeze.
        if self.firmware_owner.is_some_and(|owner| peer.is_none_or(|p| p == owner)) {
            self.firmware_owner = None;
        }
    }

    /// A renamed peer keeps what is open under its new name. A lost one's transfers end,
    /// nothing sent to it; their streams go to `ended` (the endpoint ends them itself).
    pub(crate) fn peer_changed(&mut self, ended: &mut Vec<StreamHandle>, change: ServiceChange) {
        for t in self.transfers.iter_mut() {
            change.rename(&mut t.peer);
        }
        let checked = self.holder_check.as_mut().map(|c| &mut c.holder);
        for peer in [self.firmware_owner.as_mut(), self.unfreeze_pending.as_mut(), self.lock_by.as_mut(), checked]
            .into_iter()
            .flatten()
        {
            change.rename(peer);
        }
        let ServiceChange::Lost(lost) = change else { return };
        self.forget_peer(lost);
        self.unfreeze_pending = self.unfreeze_pending.filter(|p| !change.loses(*p));
        while let Some(index) = self.transfers().iter().position(|t| change.loses(t.peer)) {
            if let Some(Transfer { job: Job::Read { handle, .. } | Job::Write { handle: Some(handle), .. }, .. }) =
                self.transfers.get(index)
            {
                ended.push(*handle);
            }
            self.end(index, false);
        }
    }
}
