//! Datagram Transport (node-protocols.md §2): one datagram outstanding per destination, with
//! Received OK, Rejected (resent on temporary codes, bounded), and timeouts; incoming
//! datagrams go to the application by content ID, and every other one is rejected at once.

#[cfg(feature = "app-datagrams")]
use alloc::boxed::Box;
use alloc::vec::Vec;
use core::fmt;

use openlcb_stream::wire::{ErrorCode, ErrorReport};
use openlcb_stream::{Duration, Instant, Message, MessageRef, Mti, NodeId, Queue};

use crate::node::{NodeEvent, Outputs, bump};
use crate::service::{Lent, Service, ServiceChange, earliest};

/// The longest datagram (DG §4.1).
pub const MAX_DATAGRAM_LEN: usize = 72;

/// Bounds and timers of the datagram service.
#[derive(Debug, Clone, PartialEq, Eq)]
#[non_exhaustive]
pub struct DatagramConfig {
    /// Content IDs (byte 0) the application handles: a datagram starting with one of these
    /// raises [`NodeEvent::DatagramReceived`]. Every other datagram is rejected at once with
    /// 0x1042 (datagram type unknown, DG-TN §2.4.3.1).
    #[cfg(feature = "app-datagrams")]
    pub claimed: Vec<u8>,
    /// How long a sent datagram waits for Received OK or Rejected. MN §3.7 forbids less than
    /// 3 s; OpenMRN and OpenLcbCLib wait 3 s.
    pub timeout: Duration,
    /// How often a datagram rejected with a temporary code (0x2xxx) is sent again.
    pub max_retries: u8,
    /// The wait before the first resend; it doubles with each one.
    pub retry_delay: Duration,
    /// Datagrams accepted by `send_datagram` and not yet delivered or failed, all
    /// destinations together.
    pub max_outgoing: usize,
    /// Of those, the most for one destination: a peer that never acknowledges holds only
    /// this many, and the others still get theirs. Memory Configuration refuses a command
    /// with 0x2020 while its reply could not be queued.
    pub max_outgoing_per_destination: usize,
    /// Received datagrams waiting for the application's answer, all sources together. More
    /// are rejected with 0x2020 (buffer unavailable: the sender resends).
    #[cfg(feature = "app-datagrams")]
    pub max_awaiting_answer: usize,
    /// How long a received datagram may wait for `answer_datagram`; then it is rejected with
    /// 0x2020. Default 500 ms, inside the 750 ms MN §3.7 allows for a response.
    #[cfg(feature = "app-datagrams")]
    pub answer_timeout: Duration,
}

impl Default for DatagramConfig {
    fn default() -> Self {
        DatagramConfig {
            #[cfg(feature = "app-datagrams")]
            claimed: Vec::new(),
            timeout: Duration::from_secs(3),
            max_retries: 3,
            retry_delay: Duration::from_millis(200),
            max_outgoing: 16,
            max_outgoing_per_destination: 4,
            #[cfg(feature = "app-datagrams")]
            max_awaiting_answer: 8,
            #[cfg(feature = "app-datagrams")]
            answer_timeout: Duration::from_millis(500),
        }
    }
}

/// A received datagram, held inline (no allocation).
#[derive(Clone, Copy, PartialEq, Eq)]
pub struct Datagram {
    len: u8,
    bytes: [u8; MAX_DATAGRAM_LEN],
}

impl Datagram {
    /// A datagram holding `payload`, or `None` when it is longer than 72 bytes.
    pub fn new(payload: &[u8]) -> Option<Self> {
        let mut bytes = [0; MAX_DATAGRAM_LEN];
        bytes.get_mut(..payload.len())?.copy_from_slice(payload);
        Some(Datagram { len: payload.len() as u8, bytes })
    }

    /// The datagram's bytes; byte 0 is the content ID.
    pub fn as_slice(&self) -> &[u8] {
        self.bytes.get(..usize::from(self.len)).unwrap_or(&[])
    }

    /// The content ID (byte 0), if the datagram is not empty.
    pub fn content_id(&self) -> Option<u8> {
        self.as_slice().first().copied()
    }
}

impl fmt::Debug for Datagram {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "Datagram(")?;
        for byte in self.as_slice() {
            write!(f, "{byte:02X}")?;
        }
        write!(f, ")")
    }
}

/// Names one datagram sent with [`Node::send_datagram`](crate::Node::send_datagram).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct DatagramId(pub u32);

/// The flags byte of Datagram Received OK (DG §4.2).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct OkFlags {
    /// A reply datagram will follow (its meaning belongs to the higher protocol).
    pub reply_pending: bool,
    /// 0: no time given; 1..=15: the reply comes within 2^N seconds.
    pub timeout_exponent: u8,
}

impl OkFlags {
    /// Reads the flags byte (absent = 0; reserved bits ignored).
    pub fn from_byte(byte: u8) -> Self {
        OkFlags { reply_pending: byte & 0x80 != 0, timeout_exponent: byte & 0x0F }
    }

    /// The flags byte.
    pub fn to_byte(self) -> u8 {
        (if self.reply_pending { 0x80 } else { 0 }) | (self.timeout_exponent & 0x0F)
    }
}

/// The application's answer to a received datagram.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum DatagramAnswer {
    /// Datagram Received OK with these flags.
    Ok(OkFlags),
    /// Datagram Rejected with this code (0x1xxx permanent, 0x2xxx resend).
    Rejected(ErrorCode),
}

/// Why a datagram this node sent was not delivered.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[non_exhaustive]
pub enum DatagramFailure {
    /// Rejected with a permanent code, or with a temporary one too often.
    Rejected(ErrorCode),
    /// Neither OK nor Rejected within [`DatagramConfig::timeout`].
    TimedOut,
    /// The destination sent Initialization Complete while the datagram waited: it restarted
    /// (a Freeze for a firmware upgrade ends this way).
    PeerRestarted,
    /// The transport lost the destination or our own link.
    PeerLost,
}

/// Why a datagram command was refused.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
pub enum DatagramError {
    /// More than 72 bytes.
    #[error("a datagram holds at most 72 bytes")]
    TooLong,
    /// [`DatagramConfig::max_outgoing`] datagrams are waiting.
    #[error("too many datagrams are waiting to be delivered")]
    QueueFull,
    /// The destination is this node.
    #[error("a node cannot send a datagram to itself")]
    SelfAddressed,
    /// No datagram from that node waits for an answer.
    #[error("no datagram from that node waits for an answer")]
    NotAwaitingAnswer,
}

/// Counters of the datagram service.
///
/// Each counter stops at `u32::MAX` (32 bits: 64-bit counters cost flash on a
/// microcontroller).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
#[non_exhaustive]
pub struct DatagramStats {
    /// Datagrams handed to the application.
    pub received: u32,
    /// Received datagrams rejected at once: empty, or a content ID nobody claimed (0x1042).
    pub rejected_unclaimed: u32,
    /// Received datagrams rejected because the answer table was full or the source already
    /// had one waiting (0x2020).
    pub rejected_busy: u32,
    /// Received datagrams the application did not answer in time (rejected with 0x2020).
    pub answer_timeouts: u32,
    /// Datagrams sent, resends included.
    pub sent: u32,
    /// Resends after a temporary rejection.
    pub resent: u32,
    /// Datagrams answered with Received OK.
    pub delivered: u32,
    /// Datagrams that failed.
    pub failed: u32,
    /// OK or Rejected from a node we were not waiting for.
    pub stray_answers: u32,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum SendState {
    /// Behind another datagram to the same destination.
    Queued,
    /// Sent; waiting for OK or Rejected until the deadline.
    InFlight { deadline: Instant },
    /// Rejected with a temporary code; sent again at this time.
    Backoff { until: Instant },
}

/// Who sent a datagram: its outcome (OK, Rejected, timed out, lost) goes back there, as
/// OpenMRN's `DatagramClient` reports its `result()` to the one that wrote the datagram.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum DatagramOwner {
    /// [`Node::send_datagram`](crate::Node::send_datagram): `DatagramDelivered` or
    /// `DatagramFailed` follows.
    Application,
    /// A command of the Memory Configuration client: the client takes the outcome.
    MemoryClient,
    /// A reply of the Memory Configuration server: nothing waits on its outcome.
    MemoryServer,
}

/// The outcome of a datagram: its OK's flags, or why it failed.
pub(crate) type Outcome = Result<OkFlags, DatagramFailure>;

#[derive(Debug)]
struct Outgoing {
    id: DatagramId,
    owner: DatagramOwner,
    to: NodeId,
    payload: Vec<u8>,
    state: SendState,
    resends: u8,
}

#[derive(Debug, Clone, Copy)]
struct Awaiting {
    from: NodeId,
    deadline: Instant,
}

/// Both directions of Datagram Transport for one node.
#[derive(Debug)]
pub(crate) struct DatagramService {
    claimed: [u64; 4],
    outgoing: Queue<Outgoing>,
    awaiting: Vec<Awaiting>,
    /// Outcomes of the memory client's datagrams, until the node hands them to it.
    client_outcomes: Queue<(DatagramId, Outcome)>,
    next_id: u32,
    pub(crate) stats: DatagramStats,
}

impl DatagramService {
    /// The service bounded by `config`, which every call that sends, resends or takes in a
    /// datagram is given again (the node's own copy: none is kept here).
    pub(crate) fn new(config: &DatagramConfig) -> Self {
        #[cfg_attr(not(feature = "app-datagrams"), allow(unused_mut))]
        let mut claimed = [0u64; 4];
        #[cfg(feature = "app-datagrams")]
        for &content in &config.claimed {
            if let Some(word) = claimed.get_mut(usize::from(content / 64)) {
                *word |= 1 << (content % 64);
            }
        }
        // Without `app-datagrams` no datagram waits for the application.
        #[cfg(feature = "app-datagrams")]
        let awaiting = Vec::with_capacity(config.max_awaiting_answer);
        #[cfg(not(feature = "app-datagrams"))]
        let awaiting = Vec::new();
        DatagramService {
            outgoing: Queue::with_capacity(config.max_outgoing),
            awaiting,
            claimed,
            client_outcomes: Queue::new(),
            next_id: 0,
            stats: DatagramStats::default(),
        }
    }

    /// The application takes datagrams with this content ID.
    pub(crate) fn claims(&self, content: u8) -> bool {
        self.is_claimed(content)
    }

    /// Never without the `app-datagrams` feature, which the compiler is told here, so that
    /// it links none of the application's datagram handling.
    fn is_claimed(&self, content: u8) -> bool {
        cfg!(feature = "app-datagrams")
            && self.claimed.get(usize::from(content / 64)).is_some_and(|word| word & (1 << (content % 64)) != 0)
    }

    /// The received datagrams waiting for the application's answer: never any without the
    /// `app-datagrams` feature (see [`is_claimed`](Self::is_claimed)).
    fn awaiting(&self) -> &[Awaiting] {
        if cfg!(feature = "app-datagrams") { &self.awaiting } else { &[] }
    }

    // ----- sending -----

    /// Sends a datagram for `owner`, who gets its outcome.
    pub(crate) fn send(
        &mut self,
        config: &DatagramConfig,
        now: Instant,
        out: &mut Outputs,
        to: NodeId,
        payload: &[u8],
        owner: DatagramOwner,
    ) -> Result<DatagramId, DatagramError> {
        if payload.len() > MAX_DATAGRAM_LEN {
            return Err(DatagramError::TooLong);
        }
        if to == out.node {
            return Err(DatagramError::SelfAddressed);
        }
        if !self.has_room(config, to) {
            return Err(DatagramError::QueueFull);
        }
        Ok(self.queue(config, now, out, to, payload, owner))
    }

    /// Room for one more datagram to `to`: under both bounds of the config.
    pub(crate) fn has_room(&self, config: &DatagramConfig, to: NodeId) -> bool {
        self.outgoing.len() < config.max_outgoing
            && self.outgoing.iter().filter(|o| o.to == to).count() < config.max_outgoing_per_destination
    }

    /// Sends a reply of the memory server that was promised (a Datagram OK with Reply
    /// Pending went out, after [`has_room`](Self::has_room) said yes): queued even above the
    /// bounds, which the promises themselves bound.
    pub(crate) fn send_promised(
        &mut self,
        config: &DatagramConfig,
        now: Instant,
        out: &mut Outputs,
        to: NodeId,
        payload: &[u8],
    ) {
        let payload = payload.get(..MAX_DATAGRAM_LEN).unwrap_or(payload);
        self.queue(config, now, out, to, payload, DatagramOwner::MemoryServer);
    }

    fn queue(
        &mut self,
        config: &DatagramConfig,
        now: Instant,
        out: &mut Outputs,
        to: NodeId,
        payload: &[u8],
        owner: DatagramOwner,
    ) -> DatagramId {
        let id = DatagramId(self.next_id);
        self.next_id = self.next_id.wrapping_add(1);
        let busy = self.outgoing.iter().any(|o| o.to == to);
        let payload = payload.to_vec();
        self.outgoing.push_back(Outgoing { id, owner, to, payload, state: SendState::Queued, resends: 0 });
        if !busy {
            self.start_next(config, now, out, to);
        }
        id
    }

    /// Sends the first queued datagram to `to`, if any (one outstanding per destination).
    fn start_next(&mut self, config: &DatagramConfig, now: Instant, out: &mut Outputs, to: NodeId) {
        let deadline = now + config.timeout;
        if let Some(next) = self.outgoing.iter_mut().find(|o| o.to == to)
            && next.state == SendState::Queued
        {
            next.state = SendState::InFlight { deadline };
            bump(&mut self.stats.sent);
            out.transmit(Message::addressed(Mti::DATAGRAM, out.node, to, next.payload.clone()));
        }
    }

    /// A datagram to `peer` waits for its OK or Rejected (or for its resend).
    fn is_waiting_for(&self, peer: NodeId) -> bool {
        self.active(peer).is_some()
    }

    /// The datagram in flight to `to` (or waiting to be resent), if any.
    fn active(&self, to: NodeId) -> Option<usize> {
        self.outgoing.iter().position(|o| o.to == to && o.state != SendState::Queued)
    }

    fn finish(&mut self, config: &DatagramConfig, now: Instant, out: &mut Outputs, index: usize, result: Outcome) {
        let Some(done) = self.outgoing.remove(index) else { return };
        self.report(out, &done, result);
        self.start_next(config, now, out, done.to);
    }

    /// Gives the outcome of `done` to its owner.
    fn report(&mut self, out: &mut Outputs, done: &Outgoing, result: Outcome) {
        match result {
            Ok(_) => bump(&mut self.stats.delivered),
            Err(_) => bump(&mut self.stats.failed),
        }
        let (id, to) = (done.id, done.to);
        match (done.owner, result) {
            // Without the `app-datagrams` feature the application sends none.
            (DatagramOwner::Application, Ok(flags)) if cfg!(feature = "app-datagrams") => {
                out.event(NodeEvent::DatagramDelivered { id, to, flags });
            }
            (DatagramOwner::Application, Err(failure)) if cfg!(feature = "app-datagrams") => {
                out.event(NodeEvent::DatagramFailed { id, to, failure });
            }
            (DatagramOwner::Application, _) => {}
            // Without the `memory-client` feature nothing sends for the client.
            (DatagramOwner::MemoryClient, result) if cfg!(feature = "memory-client") => {
                self.client_outcomes.push_back((id, result));
            }
            (DatagramOwner::MemoryClient, _) => {}
            (DatagramOwner::MemoryServer, _) => {}
        }
    }

    /// The next outcome of a datagram of the memory client.
    pub(crate) fn poll_client_outcome(&mut self) -> Option<(DatagramId, Outcome)> {
        self.client_outcomes.pop_front()
    }

    fn on_received_ok(
        &mut self,
        config: &DatagramConfig,
        now: Instant,
        out: &mut Outputs,
        from: NodeId,
        payload: &[u8],
    ) {
        let Some(index) = self.active(from) else {
            bump(&mut self.stats.stray_answers);
            return;
        };
        let flags = OkFlags::from_byte(payload.first().copied().unwrap_or(0));
        self.finish(config, now, out, index, Ok(flags));
    }

    /// Datagram Rejected, or an OIR/TDE naming Datagram (or nothing), from `from`.
    fn on_rejected(&mut self, config: &DatagramConfig, now: Instant, out: &mut Outputs, from: NodeId, code: ErrorCode) {
        let Some(index) = self.active(from) else {
            bump(&mut self.stats.stray_answers);
            return;
        };
        let (retries, delay) = (config.max_retries, config.retry_delay);
        let Some(entry) = self.outgoing.get_mut(index) else { return };
        // DG §6.2: only a temporary code allows the same datagram again.
        if code.is_temporary() && entry.resends < retries {
            let backoff = Duration::from_micros(delay.as_micros().saturating_mul(1 << entry.resends.min(16)));
            entry.resends += 1;
            entry.state = SendState::Backoff { until: now + backoff };
            return;
        }
        self.finish(config, now, out, index, Err(DatagramFailure::Rejected(code)));
    }

    /// `peer` sent Initialization Complete: a datagram it had not answered is lost.
    fn peer_restarted(&mut self, config: &DatagramConfig, now: Instant, out: &mut Outputs, peer: NodeId) {
        if let Some(index) = self.active(peer) {
            self.finish(config, now, out, index, Err(DatagramFailure::PeerRestarted));
        }
        // By position and an ordered remove, as below: no `retain` (flash).
        while let Some(index) = self.awaiting().iter().position(|a| a.from == peer) {
            self.awaiting.remove(index);
        }
    }

    fn timeout(&mut self, config: &DatagramConfig, now: Instant, out: &mut Outputs) {
        loop {
            let expired = self
                .outgoing
                .iter()
                .position(|o| matches!(o.state, SendState::InFlight { deadline } if deadline <= now));
            let Some(index) = expired else { break };
            self.finish(config, now, out, index, Err(DatagramFailure::TimedOut));
        }
        let deadline = now + config.timeout;
        for o in self.outgoing.iter_mut() {
            if matches!(o.state, SendState::Backoff { until } if until <= now) {
                o.state = SendState::InFlight { deadline };
                bump(&mut self.stats.sent);
                bump(&mut self.stats.resent);
                out.transmit(Message::addressed(Mti::DATAGRAM, out.node, o.to, o.payload.clone()));
            }
        }
        while let Some(index) = self.awaiting().iter().position(|a| a.deadline <= now) {
            let expired = self.awaiting.swap_remove(index);
            bump(&mut self.stats.answer_timeouts);
            out.reply(rejected(out.node, expired.from, ErrorCode::BUFFER_UNAVAILABLE));
        }
    }

    // ----- receiving -----

    #[cfg_attr(not(feature = "app-datagrams"), allow(unused_variables))]
    fn on_datagram(&mut self, config: &DatagramConfig, now: Instant, out: &mut Outputs, from: NodeId, payload: &[u8]) {
        let claimed = payload.first().is_some_and(|&c| self.is_claimed(c));
        match Datagram::new(payload).filter(|_| claimed) {
            #[cfg(feature = "app-datagrams")]
            Some(datagram) => self.hand_to_application(config, now, out, from, datagram),
            _ => {
                bump(&mut self.stats.rejected_unclaimed);
                out.reply(rejected(out.node, from, ErrorCode::NOT_IMPLEMENTED_DATAGRAM_TYPE));
            }
        }
    }

    /// A datagram with a content ID the application claimed: it waits for its answer.
    #[cfg(feature = "app-datagrams")]
    fn hand_to_application(
        &mut self,
        config: &DatagramConfig,
        now: Instant,
        out: &mut Outputs,
        from: NodeId,
        datagram: Datagram,
    ) {
        let busy = self.awaiting.len() >= config.max_awaiting_answer || self.awaiting.iter().any(|a| a.from == from);
        if busy {
            bump(&mut self.stats.rejected_busy);
            return out.reply(rejected(out.node, from, ErrorCode::BUFFER_UNAVAILABLE));
        }
        self.awaiting.push(Awaiting { from, deadline: now + config.answer_timeout });
        bump(&mut self.stats.received);
        out.event(NodeEvent::DatagramReceived { from, datagram: Box::new(datagram) });
    }

    #[cfg(feature = "app-datagrams")]
    pub(crate) fn answer(
        &mut self,
        out: &mut Outputs,
        from: NodeId,
        answer: DatagramAnswer,
    ) -> Result<(), DatagramError> {
        let index = self.awaiting.iter().position(|a| a.from == from).ok_or(DatagramError::NotAwaitingAnswer)?;
        self.awaiting.swap_remove(index);
        let message = match answer {
            DatagramAnswer::Ok(flags) => received_ok(out.node, from, flags),
            DatagramAnswer::Rejected(code) => rejected(out.node, from, code),
        };
        out.transmit(message);
        Ok(())
    }
}

impl Service<Lent<'_>> for DatagramService {
    /// Datagrams nobody else took (Memory Configuration is asked first), their OKs and
    /// rejections, and Initialization Complete (what the peer had not answered is lost).
    fn handle_message(&mut self, cx: &mut Lent<'_>, msg: MessageRef<'_>) -> bool {
        let (config, now, out, peer) = (&cx.config.datagrams, cx.now, &mut *cx.out, msg.source);
        match msg.mti {
            Mti::DATAGRAM => self.on_datagram(config, now, out, peer, msg.payload),
            Mti::DATAGRAM_RECEIVED_OK => self.on_received_ok(config, now, out, peer, msg.payload),
            Mti::DATAGRAM_REJECTED => self.on_rejected(config, now, out, peer, rejection_code(msg.payload)),
            Mti::INITIALIZATION_COMPLETE | Mti::INITIALIZATION_COMPLETE_SIMPLE => {
                self.peer_restarted(config, now, out, peer);
                return false;
            }
            _ => return false,
        }
        true
    }

    /// OpenMRN reads an OIR or TDE naming Datagram, or nothing, as a rejection.
    fn handle_error_report(&mut self, cx: &mut Lent<'_>, peer: NodeId, report: ErrorReport) -> bool {
        let ours = matches!(report.mti, None | Some(Mti::DATAGRAM)) && self.is_waiting_for(peer);
        if ours {
            self.on_rejected(&cx.config.datagrams, cx.now, cx.out, peer, report.code);
        }
        ours
    }

    /// A lost peer: every datagram to it fails, and what it sent us is forgotten. Only the
    /// application hears of its own: the memory client and server end their work with the
    /// peer in their own hook.
    fn peer_changed(&mut self, out: &mut Outputs, change: ServiceChange) {
        let mut index = 0;
        while let Some(o) = self.outgoing.get_mut(index) {
            change.rename(&mut o.to);
            if !change.loses(o.to) {
                index += 1;
                continue;
            }
            if let Some(done) = self.outgoing.remove(index) {
                if cfg!(feature = "app-datagrams") && done.owner == DatagramOwner::Application {
                    self.report(out, &done, Err(DatagramFailure::PeerLost));
                } else {
                    bump(&mut self.stats.failed);
                }
            }
        }
        for a in self.awaiting.iter_mut() {
            change.rename(&mut a.from);
        }
        while let Some(index) = self.awaiting().iter().position(|a| change.loses(a.from)) {
            self.awaiting.remove(index);
        }
    }

    fn handle_timeout(&mut self, cx: &mut Lent<'_>) {
        self.timeout(&cx.config.datagrams, cx.now, cx.out);
    }

    fn poll_timeout(&self) -> Option<Instant> {
        let sends = self.outgoing.iter().fold(None, |next, o| match o.state {
            SendState::InFlight { deadline: at } | SendState::Backoff { until: at } => earliest(next, Some(at)),
            SendState::Queued => next,
        });
        self.awaiting().iter().fold(sends, |next, a| earliest(next, Some(a.deadline)))
    }
}

/// Datagram Received OK from `local` for the datagram `to` sent.
pub(crate) fn received_ok(local: NodeId, to: NodeId, flags: OkFlags) -> Message {
    Message::addressed(Mti::DATAGRAM_RECEIVED_OK, local, to, [flags.to_byte()].to_vec())
}

/// Datagram Rejected with `code` from `local` for the datagram `to` sent.
pub(crate) fn rejected(local: NodeId, to: NodeId, code: ErrorCode) -> Message {
    Message::addressed(Mti::DATAGRAM_REJECTED, local, to, code.0.to_be_bytes().to_vec())
}

/// The error code of a Datagram Rejected payload, read liberally (node-protocols.md §2.3,
/// §2.5): missing bits are 0; OpenLcbCLib's CAN layer puts the code in bytes 2-3 (after an
/// alias), so a code with neither class bit followed by one with a class bit is read from
/// there; a code with no class bit at all counts as permanent.
pub fn rejection_code(payload: &[u8]) -> ErrorCode {
    let word = |at: usize| match payload.get(at..) {
        Some([high, low, ..]) => u16::from_be_bytes([*high, *low]),
        Some([high]) => u16::from(*high) << 8,
        _ => 0,
    };
    let code = word(0);
    if code & 0x3000 == 0 && word(2) & 0x3000 != 0 && payload.len() >= 4 {
        return ErrorCode(word(2));
    }
    ErrorCode(code)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rejection_codes_are_read_liberally() {
        assert_eq!(rejection_code(&[0x20, 0x20]), ErrorCode(0x2020));
        assert_eq!(rejection_code(&[0x10]), ErrorCode(0x1000), "missing bits are 0");
        assert_eq!(rejection_code(&[]), ErrorCode(0));
        // OpenLcbCLib's CAN-layer form: alias 0x0123, then the code.
        assert_eq!(rejection_code(&[0x01, 0x23, 0x20, 0x41]), ErrorCode(0x2041));
        assert_eq!(rejection_code(&[0x10, 0x42, 0x00, 0x00]), ErrorCode(0x1042));
    }

    #[test]
    fn ok_flags_round_trip() {
        let flags = OkFlags::from_byte(0x83);
        assert_eq!(flags, OkFlags { reply_pending: true, timeout_exponent: 3 });
        assert_eq!(flags.to_byte(), 0x83);
        assert_eq!(OkFlags::from_byte(0x70), OkFlags::default(), "reserved bits are ignored");
    }

    #[test]
    fn datagram_holds_at_most_72_bytes() {
        assert_eq!(Datagram::new(&[0x20; 72]).map(|d| d.as_slice().len()), Some(72));
        assert!(Datagram::new(&[0; 73]).is_none());
        assert_eq!(Datagram::new(&[]).and_then(|d| d.content_id()), None);
    }
}
