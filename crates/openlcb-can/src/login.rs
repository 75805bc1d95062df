//! [`AliasLogin`]: reserving, defending and releasing the local node's alias (CFT §6.2,
//! wire-spec §7.5), in the same handle/poll shape as the stream endpoint.
//!
//! ```text
//! Checking --(reserve wait elapsed: RID, AMD)--> Permitted
//!    ^  |                                            |
//!    |  +-- frame from our alias: next alias, CIDs   +-- CID with our alias: RID (defence)
//!    +------- other frame from our alias: AMR, Lost -+
//! Permitted --(release: AMR)--> Stopped (sends nothing more)
//! ```
//!
//! An AMD carrying this node's Node ID from another alias means a duplicate Node ID (CFT
//! §6.2.5): the login reports it and goes on, since only its owner can tell whether this node
//! is the newcomer (which then leaves, [`AliasLogin::release`]) or the node that was there
//! first (which keeps running).

use openlcb_stream::{Duration, Instant, NodeId};

use crate::alias::AliasGenerator;
use crate::frame::CanFrame;
use crate::header::{CanHeader, FrameKind};
use crate::{NodeAlias, bump, node_bytes, push_bounded};
use openlcb_stream::Queue;

/// Frames the login can have queued at once: CID 7..4, RID, AMD, AMR, one AMD answer.
const QUEUE_BOUND: usize = 8;
/// Events the login can have queued at once.
const EVENT_BOUND: usize = 8;

/// Where the login stands.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[non_exhaustive]
pub enum LoginState {
    /// Inhibited: CID frames sent for `alias`, waiting until `deadline` before RID.
    Checking {
        /// The tentative alias.
        alias: NodeAlias,
        /// When RID may go out.
        deadline: Instant,
    },
    /// The alias is ours and announced (AMD sent): anything may be sent.
    Permitted {
        /// The alias.
        alias: NodeAlias,
    },
    /// The alias was released ([`AliasLogin::release`]): nothing more is sent until the node
    /// is reset.
    Stopped,
}

/// What the login tells its owner.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[non_exhaustive]
pub enum LoginEvent {
    /// RID and AMD are queued: the node may send messages from `alias`.
    Permitted {
        /// The reserved alias.
        alias: NodeAlias,
    },
    /// A frame from another node used the tentative `alias` during the check; a new alias is
    /// being checked.
    Conflict {
        /// The abandoned alias.
        alias: NodeAlias,
    },
    /// Another node used our permitted `alias`: AMR is queued and a new login has started.
    /// Everything tied to the old alias (streams) is over.
    Lost {
        /// The released alias.
        alias: NodeAlias,
    },
    /// Another node (`other`) announced this node's Node ID in an AMD. The login goes on; its
    /// owner decides whether to [`release`](AliasLogin::release) the alias.
    DuplicateNodeId {
        /// The alias of the other node.
        other: NodeAlias,
    },
}

/// Counters of the login. Each counter stops at `u32::MAX`.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
#[non_exhaustive]
pub struct LoginStats {
    /// Tentative aliases abandoned because another node used them.
    pub conflicts: u32,
    /// RIDs sent to defend our alias against a CID.
    pub defences: u32,
    /// Permitted aliases lost to another node (AMR sent).
    pub losses: u32,
    /// AMDs sent in answer to AME.
    pub enquiry_answers: u32,
    /// Frames or events not queued because the queue was full.
    pub dropped: u32,
}

/// The local node's alias state machine. Feed it every received frame, call `handle_timeout`
/// when `poll_timeout` says, and send what `poll_transmit` returns, promptly: the reserve wait
/// counts from when the CID frames were queued, or from when a driver says they were sent
/// ([`frames_sent`](Self::frames_sent)), whichever is later.
#[derive(Debug, Clone)]
pub struct AliasLogin {
    node: NodeId,
    generator: AliasGenerator,
    reserve_wait: Duration,
    state: LoginState,
    transmits: Queue<CanFrame>,
    /// The CID frames of the alias being checked were all handed out, and no driver has said
    /// when they were sent.
    checks_unsent: bool,
    events: Queue<LoginEvent>,
    stats: LoginStats,
}

impl AliasLogin {
    /// Starts the login of `node` at `now`: the CID frames of the first alias are queued.
    /// The first alias is `first_alias` if given, else the generator's (seeded with `node`);
    /// later aliases always come from the generator.
    pub fn new(now: Instant, node: NodeId, first_alias: Option<NodeAlias>, reserve_wait: Duration) -> Self {
        let mut generator = AliasGenerator::new(node);
        let alias = first_alias.unwrap_or_else(|| generator.next_alias());
        let mut login = AliasLogin {
            node,
            generator,
            reserve_wait,
            state: LoginState::Checking { alias, deadline: now },
            transmits: Queue::with_capacity(QUEUE_BOUND),
            checks_unsent: false,
            events: Queue::new(),
            stats: LoginStats::default(),
        };
        login.check(now, alias);
        login
    }

    // ----- getters -----

    /// The state.
    pub fn state(&self) -> LoginState {
        self.state
    }

    /// The alias once permitted.
    pub fn alias(&self) -> Option<NodeAlias> {
        match self.state {
            LoginState::Permitted { alias } => Some(alias),
            _ => None,
        }
    }

    /// The local Node ID.
    pub fn node_id(&self) -> NodeId {
        self.node
    }

    /// Counters.
    pub fn stats(&self) -> LoginStats {
        self.stats
    }

    // ----- outputs -----

    /// The next frame to send.
    pub fn poll_transmit(&mut self) -> Option<CanFrame> {
        let frame = self.transmits.pop_front()?;
        if self.transmits.is_empty() && matches!(self.state, LoginState::Checking { .. }) {
            self.checks_unsent = true;
        }
        Some(frame)
    }

    /// The frames handed out by `poll_transmit` were sent by `now`. After the CID frames of
    /// an alias, the reserve wait counts from `now` if that is later than when they were
    /// queued: CFT §6.2.1 counts the 200 ms from the CIDs on the bus, and a driver that sends
    /// them some time after the login queued them (a first poll that comes late) would
    /// otherwise shorten it. Any other call is harmless.
    pub fn frames_sent(&mut self, now: Instant) {
        if !core::mem::take(&mut self.checks_unsent) {
            return;
        }
        if let LoginState::Checking { deadline, .. } = &mut self.state {
            *deadline = (*deadline).max(now + self.reserve_wait);
        }
    }

    /// The next event.
    pub fn poll_event(&mut self) -> Option<LoginEvent> {
        self.events.pop_front()
    }

    /// When to call `handle_timeout` next.
    pub fn poll_timeout(&self) -> Option<Instant> {
        match self.state {
            LoginState::Checking { deadline, .. } => Some(deadline),
            _ => None,
        }
    }

    // ----- inputs -----

    /// Moves on to Permitted once the reserve wait is over. Early or repeated calls are harmless.
    pub fn handle_timeout(&mut self, now: Instant) {
        let event = self.timeout(now);
        self.event(event);
    }

    /// [`handle_timeout`](Self::handle_timeout), returning its event rather than queueing it
    /// (a call has at most one).
    pub(crate) fn timeout(&mut self, now: Instant) -> Option<LoginEvent> {
        if let LoginState::Checking { alias, deadline } = self.state {
            if now < deadline {
                return None;
            }
            // CFT §6.2.1: RID ends the reservation, AMD enters Permitted.
            self.send(FrameKind::ReserveId, alias, false);
            self.send(FrameKind::AliasMapDefinition, alias, true);
            self.state = LoginState::Permitted { alias };
            return Some(LoginEvent::Permitted { alias });
        }
        None
    }

    /// Feeds one received frame. Returns true if the frame came from an alias this node holds
    /// or checks (it is not a peer's frame and must not be used further).
    pub fn handle_frame(&mut self, now: Instant, frame: &CanFrame) -> bool {
        match frame.header() {
            Ok(header) => self.handle_header(now, &header, frame.payload()),
            Err(_) => false,
        }
    }

    /// [`handle_frame`](Self::handle_frame) for a frame whose header is already parsed.
    pub fn handle_header(&mut self, now: Instant, header: &CanHeader, data: &[u8]) -> bool {
        let ours = self.holds(header.source);
        let event = self.header(now, header, data);
        self.event(event);
        ours
    }

    /// [`handle_header`](Self::handle_header), returning its event rather than queueing it (a
    /// call has at most one). Whether the frame came from our alias is
    /// [`holds`](Self::holds) of its source, asked before this call (the frame may move the
    /// login to another alias).
    pub(crate) fn header(&mut self, now: Instant, header: &CanHeader, data: &[u8]) -> Option<LoginEvent> {
        if self.state == LoginState::Stopped {
            return None;
        }
        // Only alias frames name a Node ID: parsed for them alone (every frame comes here).
        let claimed = || NodeId::from_slice(data);
        match header.kind {
            FrameKind::AliasMapEnquiry => {
                if let LoginState::Permitted { alias } = self.state {
                    // CFT §6.2.3: answer a global AME, or one naming our Node ID.
                    if (data.is_empty() || claimed() == Some(self.node))
                        && !self.has_queued(FrameKind::AliasMapDefinition)
                    {
                        bump(&mut self.stats.enquiry_answers);
                        self.send(FrameKind::AliasMapDefinition, alias, true);
                    }
                }
            }
            FrameKind::AliasMapDefinition if claimed() == Some(self.node) && !self.holds(header.source) => {
                // CFT §6.2.5: another node announced our Node ID.
                return Some(LoginEvent::DuplicateNodeId { other: header.source });
            }
            _ => {}
        }
        if !self.holds(header.source) {
            return None;
        }
        match (self.state, header.kind) {
            (LoginState::Checking { alias, .. }, _) => {
                bump(&mut self.stats.conflicts);
                self.check_next(now);
                Some(LoginEvent::Conflict { alias })
            }
            (LoginState::Permitted { alias }, FrameKind::CheckId { .. }) => {
                if !self.has_queued(FrameKind::ReserveId) {
                    bump(&mut self.stats.defences);
                    self.send(FrameKind::ReserveId, alias, false);
                }
                None
            }
            (LoginState::Permitted { alias }, _) => {
                bump(&mut self.stats.losses);
                self.transmits.clear();
                self.send(FrameKind::AliasMapReset, alias, true);
                self.check_next(now);
                Some(LoginEvent::Lost { alias })
            }
            (LoginState::Stopped, _) => None,
        }
    }

    // ----- commands -----

    /// Leaves the network: AMR for the permitted alias (CFT §6.2.4; nothing for an alias still
    /// being checked), then nothing more. Frames queued before are dropped, the AMR is not.
    pub fn release(&mut self) {
        let permitted = self.alias();
        self.transmits.clear();
        if let Some(alias) = permitted {
            self.send(FrameKind::AliasMapReset, alias, true);
        }
        self.state = LoginState::Stopped;
    }

    // ----- helpers -----

    /// The alias is ours: permitted, or being checked.
    pub(crate) fn holds(&self, alias: NodeAlias) -> bool {
        match self.state {
            LoginState::Checking { alias: ours, .. } | LoginState::Permitted { alias: ours } => ours == alias,
            LoginState::Stopped => false,
        }
    }

    /// Checks the generator's next alias.
    fn check_next(&mut self, now: Instant) {
        let next = self.generator.next_alias();
        self.check(now, next);
    }

    /// Queues CID 7..4 for `alias` (dropping frames of an abandoned alias but its AMR) and
    /// starts the wait.
    fn check(&mut self, now: Instant, alias: NodeAlias) {
        self.transmits.retain(|f| is_kind(f, FrameKind::AliasMapReset));
        let id = self.node.as_raw();
        // Node ID bits 47-36, 35-24, 23-12 and 11-0, from its two 24-bit halves (32-bit
        // arithmetic).
        let (high, low) = ((id >> 24) as u32, id as u32);
        for (sequence, bits) in [(7, high >> 12), (6, high), (5, low >> 12), (4, low)] {
            let node_id_bits = (bits & 0xFFF) as u16;
            self.send(FrameKind::CheckId { sequence, node_id_bits }, alias, false);
        }
        self.state = LoginState::Checking { alias, deadline: now + self.reserve_wait };
        self.checks_unsent = false;
    }

    fn has_queued(&self, kind: FrameKind) -> bool {
        self.transmits.iter().any(|f| is_kind(f, kind))
    }

    /// Queues the control frame `kind` from `alias`, carrying our Node ID if `with_node_id`.
    fn send(&mut self, kind: FrameKind, alias: NodeAlias, with_node_id: bool) {
        let node = node_bytes(self.node);
        let data = if with_node_id { node.as_slice() } else { &[] };
        let frame = CanFrame::build(CanHeader::control(kind, alias).to_id(), data, &[]);
        push_bounded(&mut self.transmits, QUEUE_BOUND, frame, &mut self.stats.dropped);
    }

    /// Queues `event`, if there is one, for `poll_event`.
    fn event(&mut self, event: Option<LoginEvent>) {
        let Some(event) = event else { return };
        if self.events.len() < EVENT_BOUND {
            self.events.push_back(event);
        } else {
            bump(&mut self.stats.dropped);
        }
    }
}

/// `frame` (one of the login's own control frames) is a `kind` frame: its identifier apart
/// from the source alias is that of `kind`.
fn is_kind(frame: &CanFrame, kind: FrameKind) -> bool {
    let id = CanHeader::control(kind, NodeAlias::MAX).to_id();
    (frame.raw_id() ^ id) & !0xFFF == 0
}

#[cfg(test)]
mod tests {
    use super::*;

    fn alias(raw: u16) -> NodeAlias {
        NodeAlias::new(raw).unwrap()
    }

    fn ids(login: &mut AliasLogin) -> Vec<u32> {
        core::iter::from_fn(|| login.poll_transmit()).map(|f| f.raw_id()).collect()
    }

    fn frame(id: u32, data: &[u8]) -> CanFrame {
        CanFrame::extended(id, data).unwrap()
    }

    const NODE: u64 = 0x0201_0D00_0003;

    fn login() -> AliasLogin {
        AliasLogin::new(Instant::ZERO, NodeId::new(NODE).unwrap(), Some(alias(0x555)), Duration::from_millis(200))
    }

    #[test]
    fn checking_cids_then_rid_and_amd_after_the_wait() {
        let mut l = login();
        assert_eq!(ids(&mut l), [0x1702_0555, 0x1610_D555, 0x1500_0555, 0x1400_3555]);
        assert_eq!(l.poll_timeout(), Some(Instant::from_millis(200)));
        l.handle_timeout(Instant::from_millis(199));
        assert_eq!(l.alias(), None);
        assert!(ids(&mut l).is_empty());
        l.handle_timeout(Instant::from_millis(200));
        assert_eq!(ids(&mut l), [0x1070_0555, 0x1070_1555]);
        assert_eq!(l.poll_event(), Some(LoginEvent::Permitted { alias: alias(0x555) }));
        assert_eq!(l.alias(), Some(alias(0x555)));
        assert_eq!(l.poll_timeout(), None);
    }

    #[test]
    fn the_reserve_wait_counts_from_the_cids_sent_when_the_driver_says_so() {
        let mut l = login();
        // Said before the CIDs are all out: nothing changes.
        l.poll_transmit();
        l.frames_sent(Instant::from_millis(50));
        assert_eq!(l.poll_timeout(), Some(Instant::from_millis(200)));
        assert_eq!(ids(&mut l).len(), 3);
        // The driver sent them 15 ms after the login queued them: 200 ms from then.
        l.frames_sent(Instant::from_millis(15));
        assert_eq!(l.poll_timeout(), Some(Instant::from_millis(215)));
        // Said again (other frames later): the wait is not put off.
        l.frames_sent(Instant::from_millis(100));
        assert_eq!(l.poll_timeout(), Some(Instant::from_millis(215)));
        l.handle_timeout(Instant::from_millis(214));
        assert_eq!(l.alias(), None, "no RID 199 ms after the CIDs");
        l.handle_timeout(Instant::from_millis(215));
        assert_eq!(ids(&mut l), [0x1070_0555, 0x1070_1555]);
        // Once permitted, nothing to move.
        l.frames_sent(Instant::from_millis(300));
        assert_eq!(l.poll_timeout(), None);
        // A driver whose sends come before the queueing time changes nothing either.
        let mut early = login();
        ids(&mut early);
        early.frames_sent(Instant::ZERO);
        assert_eq!(early.poll_timeout(), Some(Instant::from_millis(200)));
    }

    #[test]
    fn a_copy_queues_frames_like_the_original() {
        let mut l = login();
        ids(&mut l);
        let mut copy = l.clone();
        copy.handle_timeout(Instant::from_millis(200));
        assert_eq!(ids(&mut copy), [0x1070_0555, 0x1070_1555]);
        assert_eq!(copy.alias(), Some(alias(0x555)));
        assert_eq!(l.alias(), None);
    }

    #[test]
    fn checking_frame_from_our_alias_picks_the_next_alias() {
        let mut l = login();
        ids(&mut l);
        assert!(l.handle_frame(Instant::from_millis(50), &frame(0x1910_0555, &[1, 2, 3, 4, 5, 6])));
        assert_eq!(l.poll_event(), Some(LoginEvent::Conflict { alias: alias(0x555) }));
        let LoginState::Checking { alias: next, deadline } = l.state() else { panic!() };
        assert_ne!(next, alias(0x555));
        assert_eq!(deadline, Instant::from_millis(250));
        let expected = AliasGenerator::new(NodeId::new(NODE).unwrap()).next_alias();
        assert_eq!(next, expected, "retries come from the generator");
        assert_eq!(ids(&mut l).len(), 4);
    }

    #[test]
    fn permitted_cid_with_our_alias_is_defended_once() {
        let mut l = login();
        l.handle_timeout(Instant::from_millis(200));
        ids(&mut l);
        l.poll_event();
        assert!(l.handle_frame(Instant::from_millis(300), &frame(0x1712_3555, &[])));
        assert!(l.handle_frame(Instant::from_millis(300), &frame(0x1645_6555, &[])));
        assert_eq!(ids(&mut l), [0x1070_0555]);
        assert_eq!(l.alias(), Some(alias(0x555)));
        assert_eq!(l.stats().defences, 1);
    }

    #[test]
    fn permitted_other_frame_with_our_alias_sends_amr_and_starts_over() {
        let mut l = login();
        l.handle_timeout(Instant::from_millis(200));
        ids(&mut l);
        l.poll_event();
        assert!(l.handle_frame(Instant::from_millis(300), &frame(0x1070_1555, &[9, 9, 9, 9, 9, 9])));
        assert_eq!(l.poll_event(), Some(LoginEvent::Lost { alias: alias(0x555) }));
        let sent = ids(&mut l);
        assert_eq!(sent.first(), Some(&0x1070_3555), "AMR of the old alias first");
        assert_eq!(sent.len(), 5);
        assert!(matches!(l.state(), LoginState::Checking { .. }));
    }

    #[test]
    fn answers_global_ame_and_ame_for_us_only_when_permitted() {
        let mut l = login();
        ids(&mut l);
        assert!(!l.handle_frame(Instant::ZERO, &frame(0x1070_2777, &[])));
        assert!(ids(&mut l).is_empty(), "inhibited nodes never reply");
        l.handle_timeout(Instant::from_millis(200));
        ids(&mut l);
        l.handle_frame(Instant::from_millis(300), &frame(0x1070_2777, &[]));
        assert_eq!(ids(&mut l), [0x1070_1555]);
        l.handle_frame(Instant::from_millis(300), &frame(0x1070_2777, &NodeId::new(NODE).unwrap().to_bytes()));
        assert_eq!(ids(&mut l), [0x1070_1555]);
        l.handle_frame(Instant::from_millis(300), &frame(0x1070_2777, &[5, 1, 1, 1, 0x22, 1]));
        assert!(ids(&mut l).is_empty(), "AME for another node");
        assert_eq!(l.stats().enquiry_answers, 2);
    }

    #[test]
    fn permitted_amd_with_our_node_id_from_another_alias_is_reported_and_the_login_goes_on() {
        let mut l = login();
        l.handle_timeout(Instant::from_millis(200));
        ids(&mut l);
        l.poll_event();
        l.handle_frame(Instant::from_millis(300), &frame(0x1070_1777, &NodeId::new(NODE).unwrap().to_bytes()));
        assert_eq!(l.poll_event(), Some(LoginEvent::DuplicateNodeId { other: alias(0x777) }));
        assert_eq!(l.alias(), Some(alias(0x555)), "the node that was there first keeps running");
        l.handle_frame(Instant::from_millis(300), &frame(0x1070_2777, &[]));
        assert_eq!(ids(&mut l), [0x1070_1555], "it still answers a global AME");
    }

    #[test]
    fn permitted_release_sends_amr_and_then_nothing() {
        let mut l = login();
        l.handle_timeout(Instant::from_millis(200));
        ids(&mut l);
        l.handle_frame(Instant::from_millis(300), &frame(0x1070_2777, &[]));
        l.release();
        let sent: Vec<CanFrame> = core::iter::from_fn(|| l.poll_transmit()).collect();
        assert_eq!(sent.iter().map(|f| f.raw_id()).collect::<Vec<_>>(), [0x1070_3555], "AMR only");
        assert_eq!(sent[0].payload(), &NodeId::new(NODE).unwrap().to_bytes(), "the AMR carries our Node ID");
        assert_eq!(l.state(), LoginState::Stopped);
        l.handle_frame(Instant::from_millis(400), &frame(0x1070_2777, &[]));
        l.handle_frame(Instant::from_millis(400), &frame(0x1712_3555, &[]));
        l.handle_timeout(Instant::from_millis(9000));
        assert!(ids(&mut l).is_empty());
    }

    #[test]
    fn checking_release_sends_nothing() {
        let mut l = login();
        ids(&mut l);
        l.release();
        assert!(ids(&mut l).is_empty());
        assert_eq!(l.state(), LoginState::Stopped);
    }
}
