//! Broadcast Time: the layout's fast clocks, carried in Event IDs (Broadcast Time Standard and
//! its Technical Note).
//!
//! A clock is named by the upper six bytes of its Event IDs ([`ClockId`]: one of the four
//! well-known clocks, or a unique ID); the lower two say what an event means
//! ([`ClockMessage`]): the time of day, the date, the year and the rate as reports, the same
//! as set commands, query, start, stop and date rollover. A node holds any number of clocks
//! ([`NodeConfig::clocks`](crate::NodeConfig::clocks)), each in one role:
//!
//! - a **generator** ([`ClockRole::Generator`]) keeps the time. It identifies the clock's
//!   whole range as produced and consumed, sends its synchronization sequence at start-up,
//!   3 s after the last set command, and (a fraction of a second later, to answer many at
//!   once) for each query; reports the time as minutes begin, at most once per real minute
//!   (always for a minute a consumer identified on its own, and at midnight, after Date
//!   Rollover, with the year and date 3 s later); takes set commands (or refuses them, by
//!   config) and echoes the effective value at once;
//! - a **consumer** ([`ClockRole::Consumer`]) follows a generator: it identifies the range as
//!   consumed, asks for the synchronization sequence after start-up (unless another node asked
//!   first), computes the time between reports from the rate, and asks again when a report
//!   shows it out of step or when a running clock has said nothing for longer than the
//!   standard allows. It may also drive the generator ([`Node::set_clock`]).
//!
//! Both roles tell the application what changed with [`NodeEvent::Clock`]
//! ([`ClockEvent`]): a minute begun, a time set, the rate, start and stop; and answer
//! [`Node::clock`] with the time now, to the millisecond.
//!
//! # Where the standard and real peers differ
//!
//! - **The last message of the synchronization sequence** (§6.3 item 6, "Producer/Consumer
//!   Event Report for Report Time event for next minute, when it becomes valid"). OpenMRN's
//!   `BroadcastTimeServer` sends it when that minute begins, and not at all while the clock
//!   stands; OpenLcbCLib sends it at once, for the minute after the one just identified, and
//!   OlcbChecker's `bt10`, `bt20` and `bt80` wait for it at once (5 s), even from a stopped
//!   clock. A generator here does what the sentence says and OpenMRN does
//!   ([`SyncTail::WhenValid`]): a report of a minute that has not begun would set every
//!   consumer that takes reports as the time (OpenMRN's) a minute ahead. [`SyncTail::AtOnce`]
//!   gives OpenLcbCLib's reading, for the conformance suite. A consumer here takes either: a
//!   report of the next minute right after the sequence, from a stopped clock, is that
//!   reading's announcement and leaves the time as identified; from a running clock it is
//!   taken as the minute begun.
//! - **Rate zero.** §6.5 moves a rate the generator does not support to the closest non-zero
//!   one, and the TN calls zero "stopped": a Set Rate of zero becomes the smallest step
//!   (0.25, or -0.25 when the generator runs only backwards).
//! - **A set time** starts the minute (`hh:mm:00`) running forwards, and ends it (`hh:mm:59.999`)
//!   running backwards, as OpenMRN does.
//!
//! # Bounds
//!
//! A flood of set commands costs one echo each (dropped and counted once the node's transmit
//! queue is full) and one synchronization sequence per
//! [`GeneratorConfig::max_sync_delay`]; a flood of queries one per
//! [`GeneratorConfig::min_sync_interval`]. A report or command with a reserved meaning (hour
//! 24, 31 April, a code the standard does not define) is ignored and counted
//! ([`ClockStats`]); nothing from the wire grows a table.
//!
//! # Example
//!
//! A generator at four times real time and a consumer on the Default Fast Clock, back to back
//! (a real program puts a transport between them):
//!
//! ```
//! use openlcb_node::broadcast_time::{ClockConfig, ClockId, ClockTime, GeneratorConfig, Rate};
//! use openlcb_node::{Node, NodeConfig};
//! use openlcb_stream::{Instant, NodeId};
//!
//! let mut generator = GeneratorConfig::default();
//! generator.start = ClockTime::new(1956, 7, 4, 6, 0, 0).unwrap();
//! generator.rate = "4".parse::<Rate>().unwrap();
//! generator.running = true;
//! let mut config = NodeConfig::default();
//! config.clocks = vec![ClockConfig::generator(ClockId::DEFAULT_FAST, generator)];
//! let mut station = Node::new(NodeId::new(0x05_01_01_01_22_00).unwrap(), config);
//! let mut config = NodeConfig::default();
//! config.clocks = vec![ClockConfig::consumer(ClockId::DEFAULT_FAST)];
//! let mut fascia = Node::new(NodeId::new(0x05_01_01_01_22_01).unwrap(), config);
//!
//! // Runs both nodes' timers to `now` and passes their messages until quiet.
//! fn run(now: Instant, a: &mut Node, b: &mut Node) {
//!     a.handle_timeout(now);
//!     b.handle_timeout(now);
//!     loop {
//!         let mut moved = false;
//!         while let Some(m) = a.poll_transmit() { b.handle_message(now, m.as_ref()); moved = true; }
//!         while let Some(m) = b.poll_transmit() { a.handle_message(now, m.as_ref()); moved = true; }
//!         if !moved { break; }
//!     }
//! }
//!
//! for ms in (0..=60_000).step_by(100) {
//!     run(Instant::from_millis(ms), &mut station, &mut fascia);
//! }
//! // A real minute later the fast clock is four minutes on, and the fascia shows it.
//! let now = Instant::from_millis(60_000);
//! let shown = fascia.clock(ClockId::DEFAULT_FAST, now).unwrap();
//! assert_eq!((shown.time.hour, shown.time.minute), (6, 4));
//! assert!(shown.running && shown.synchronized);
//! assert_eq!(shown.time, station.clock(ClockId::DEFAULT_FAST, now).unwrap().time);
//! ```

mod calendar;
mod consumer;
mod generator;
mod model;
mod wire;

use alloc::boxed::Box;
use alloc::vec::Vec;

use openlcb_stream::wire::ErrorReport;
use openlcb_stream::{Duration, EventId, Instant, Message, MessageRef, Mti, NodeId};

pub use calendar::ClockTime;
pub use wire::{ClockId, ClockMessage, Rate, RateError};

use crate::events::EventRange;
use crate::node::{Outputs, bump};
use crate::service::{Lent, Service, ServiceChange, earliest};
use crate::{Node, NodeEvent};
use consumer::Consumer;
use generator::Generator;

/// One clock of a node: its ID and its role.
#[derive(Debug, Clone, PartialEq, Eq)]
#[non_exhaustive]
pub struct ClockConfig {
    /// The clock.
    pub id: ClockId,
    /// Generator or consumer.
    pub role: ClockRole,
}

impl ClockConfig {
    /// A generator of `id`.
    pub fn generator(id: ClockId, config: GeneratorConfig) -> Self {
        ClockConfig { id, role: ClockRole::Generator(config) }
    }

    /// A consumer of `id` with the default timers, which does not announce that it sets the
    /// clock (it may all the same).
    pub fn consumer(id: ClockId) -> Self {
        ClockConfig { id, role: ClockRole::Consumer(ConsumerConfig::default()) }
    }
}

/// What a node does with a clock.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum ClockRole {
    /// It keeps the time and reports it.
    Generator(GeneratorConfig),
    /// It follows a generator.
    Consumer(ConsumerConfig),
}

/// When a generator sends the last message of its synchronization sequence, the report of
/// the next minute (see the module documentation).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
pub enum SyncTail {
    /// When that minute begins, and not while the clock stands (the standard's sentence,
    /// OpenMRN).
    #[default]
    WhenValid,
    /// At once, right after the Producer Identified messages (OpenLcbCLib, OlcbChecker).
    AtOnce,
}

/// A generator's start, its limits and its timers.
#[derive(Debug, Clone, PartialEq, Eq)]
#[non_exhaustive]
pub struct GeneratorConfig {
    /// The time it starts at.
    pub start: ClockTime,
    /// The rate it starts at.
    pub rate: Rate,
    /// It runs from the start.
    pub running: bool,
    /// It takes Set Time/Date/Year/Rate, Start and Stop from the bus (refused ones are
    /// counted in [`ClockStats::sets_refused`]).
    pub accept_sets: bool,
    /// The slowest rate a Set Rate gets (a lower one is raised to it).
    pub slowest: Rate,
    /// The fastest rate a Set Rate gets (a higher one is lowered to it).
    pub fastest: Rate,
    /// When the synchronization sequence's last report goes out.
    pub sync_tail: SyncTail,
    /// From the last set command to the synchronization sequence (§6.5: 3 s).
    pub sync_delay: Duration,
    /// From a query to the sequence that answers it, to answer every query of a start-up
    /// burst with one (TN §2.6.4: a few hundred milliseconds).
    pub query_delay: Duration,
    /// Sequences answering queries are at least this far apart.
    pub min_sync_interval: Duration,
    /// A run of set commands gets its sequence at most this long after the first, however
    /// long the run lasts.
    pub max_sync_delay: Duration,
    /// After Date Rollover and the midnight report, the year and date reports follow this
    /// much later (§6.2: 3 s).
    pub rollover_delay: Duration,
}

impl Default for GeneratorConfig {
    fn default() -> Self {
        GeneratorConfig {
            start: ClockTime { year: 2000, month: 1, day: 1, hour: 0, minute: 0, second: 0 },
            rate: Rate::REAL_TIME,
            running: false,
            accept_sets: true,
            slowest: Rate::MIN,
            fastest: Rate::MAX,
            sync_tail: SyncTail::default(),
            sync_delay: Duration::from_secs(3),
            query_delay: Duration::from_millis(200),
            min_sync_interval: Duration::from_secs(1),
            max_sync_delay: Duration::from_secs(10),
            rollover_delay: Duration::from_secs(3),
        }
    }
}

/// A consumer's timers.
#[derive(Debug, Clone, PartialEq, Eq)]
#[non_exhaustive]
pub struct ConsumerConfig {
    /// It announces the set commands as produced (Producer Range Identified for the upper
    /// half of the clock's range), as a clock control panel does; otherwise only Query.
    pub controls: bool,
    /// From start-up to its query, unless a synchronization sequence or another node's query
    /// comes first.
    pub query_delay: Duration,
    /// After a report that shows it out of step, the query that follows unless a
    /// synchronization sequence comes first (a set's comes 3 s after it).
    pub step_check: Duration,
    /// A running clock silent this long is asked again (§6.2: a report at least once per
    /// real hour).
    pub resync_after: Duration,
}

impl Default for ConsumerConfig {
    fn default() -> Self {
        ConsumerConfig {
            controls: false,
            query_delay: Duration::from_millis(500),
            step_check: Duration::from_secs(5),
            resync_after: Duration::from_secs(70 * 60),
        }
    }
}

/// A change of a clock, for the application ([`NodeEvent::Clock`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ClockEvent {
    /// The clock.
    pub clock: ClockId,
    /// What changed.
    pub change: ClockChange,
    /// The node whose message caused it (`None`: the clock's own running, or the
    /// application).
    pub from: Option<NodeId>,
}

/// What changed ([`ClockEvent`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[non_exhaustive]
pub enum ClockChange {
    /// The running clock entered a new minute.
    Minute(ClockTime),
    /// The time, date or year was set (or a report put a consumer right): the clock now
    /// shows this.
    Set(ClockTime),
    /// The rate changed.
    Rate(Rate),
    /// The clock started.
    Started,
    /// The clock stopped.
    Stopped,
    /// A consumer heard its first synchronization sequence: it knows the generator's state.
    Synchronized,
}

/// A clock's state now ([`Node::clock`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[non_exhaustive]
pub struct ClockState {
    /// The time.
    pub time: ClockTime,
    /// The rate.
    pub rate: Rate,
    /// It runs.
    pub running: bool,
    /// A generator: always; a consumer: it has heard a synchronization sequence.
    pub synchronized: bool,
}

/// A change asked of a clock ([`Node::set_clock`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ClockSet {
    /// The time of day.
    Time {
        /// 0 to 23.
        hour: u8,
        /// 0 to 59.
        minute: u8,
    },
    /// The date.
    Date {
        /// 1 to 12.
        month: u8,
        /// 1 to 31.
        day: u8,
    },
    /// The year, 0 to 4095.
    Year(u16),
    /// The rate.
    Rate(Rate),
    /// Start.
    Start,
    /// Stop.
    Stop,
}

impl ClockSet {
    /// The set command for this change.
    fn message(self) -> ClockMessage {
        match self {
            ClockSet::Time { hour, minute } => ClockMessage::SetTime { hour, minute },
            ClockSet::Date { month, day } => ClockMessage::SetDate { month, day },
            ClockSet::Year(year) => ClockMessage::SetYear(year),
            ClockSet::Rate(rate) => ClockMessage::SetRate(rate),
            ClockSet::Start => ClockMessage::Start,
            ClockSet::Stop => ClockMessage::Stop,
        }
    }

    /// The change a set command asks for (`None` for anything else).
    fn of(message: ClockMessage) -> Option<Self> {
        Some(match message {
            ClockMessage::SetTime { hour, minute } => ClockSet::Time { hour, minute },
            ClockMessage::SetDate { month, day } => ClockSet::Date { month, day },
            ClockMessage::SetYear(year) => ClockSet::Year(year),
            ClockMessage::SetRate(rate) => ClockSet::Rate(rate),
            ClockMessage::Start => ClockSet::Start,
            ClockMessage::Stop => ClockSet::Stop,
            _ => return None,
        })
    }
}

/// Why a clock command could not be given.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
pub enum ClockError {
    /// The node has no such clock in [`NodeConfig::clocks`](crate::NodeConfig::clocks).
    #[error("this node has no clock {0}")]
    UnknownClock(ClockId),
    /// An hour past 23, a minute past 59, a day the month lacks, a year past 4095.
    #[error("no such time or date")]
    OutOfRange,
    /// [`NodeConfig::transmit_queue_limit`](crate::NodeConfig::transmit_queue_limit) messages
    /// wait: try again once they are sent.
    #[error("the transmit queue is full")]
    QueueFull,
}

/// Counters of the clocks.
///
/// Each counter stops at `u32::MAX` (32 bits: 64-bit counters cost flash on a
/// microcontroller).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
#[non_exhaustive]
pub struct ClockStats {
    /// Set commands a generator carried out.
    pub sets_applied: u32,
    /// Set commands a generator refused ([`GeneratorConfig::accept_sets`] off, or a day the
    /// month lacks).
    pub sets_refused: u32,
    /// Queries a generator received.
    pub queries: u32,
    /// Synchronization sequences sent.
    pub syncs_sent: u32,
    /// Report Time events sent.
    pub time_reports_sent: u32,
    /// Events of a clock's range with a reserved meaning, ignored (§4.12).
    pub reserved_ignored: u32,
    /// Event messages too short to hold an Event ID.
    pub malformed: u32,
    /// Reports of a clock from a second node: another generator of a clock this node
    /// generates, or a consumer's generator changing (a misconfigured layout).
    pub other_generators: u32,
    /// Queries a consumer sent.
    pub queries_sent: u32,
    /// Clock events dropped because the application left
    /// [`NodeConfig::transmit_queue_limit`](crate::NodeConfig::transmit_queue_limit) events
    /// waiting.
    pub notices_dropped: u32,
}

/// What a clock's role lends its work: the node's queues, its Node ID, the clock and the
/// counters.
pub(crate) struct Bus<'a> {
    out: &'a mut Outputs,
    clock: ClockId,
    stats: &'a mut ClockStats,
}

impl Bus<'_> {
    /// A Producer/Consumer Event Report of the clock's `message`.
    fn report(&mut self, message: ClockMessage) {
        self.send(Mti::PRODUCER_CONSUMER_EVENT_REPORT, self.clock.event(message.suffix()));
    }

    /// Sends `mti` with `event` (a message of the clock's own).
    fn send(&mut self, mti: Mti, event: EventId) {
        let node = self.out.node;
        self.out.transmit(Message::global(mti, node, event.to_bytes()));
    }

    /// Answers another node with `mti` and `event` (dropped and counted by the node when its
    /// queue is full).
    fn answer(&mut self, mti: Mti, event: EventId) {
        let node = self.out.node;
        self.out.reply(Message::global(mti, node, event.to_bytes()));
    }

    /// Tells the application.
    fn tell(&mut self, change: ClockChange, from: Option<NodeId>) {
        if !self.out.notify(NodeEvent::Clock(ClockEvent { clock: self.clock, change, from })) {
            bump(&mut self.stats.notices_dropped);
        }
    }

    /// Range Identified (`mti`) for `count` of the clock's events from `suffix`.
    fn identify_range(&mut self, mti: Mti, suffix: u16, count: u64) {
        if let Some(range) = EventRange::covering(self.clock.event(suffix), count) {
            self.answer(mti, range.encoded());
        }
    }
}

/// A received message of one clock, as its role takes it.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Heard {
    /// The sender.
    from: NodeId,
    /// The message's MTI.
    mti: Mti,
    /// The lower two bytes of the Event ID.
    suffix: u16,
}

/// A clock in its role.
#[derive(Debug)]
enum Role {
    Generator(Box<Generator>),
    Consumer(Consumer),
}

#[derive(Debug)]
struct Clock {
    id: ClockId,
    role: Role,
}

/// The Broadcast Time service of a node: its clocks.
#[derive(Debug)]
pub(crate) struct ClockService {
    clocks: Vec<Clock>,
    /// The clocks are to be identified (and a generator's state sent) at the next timeout:
    /// after the node's Initialization Complete, which is queued first.
    announce: bool,
    stats: ClockStats,
}

impl ClockService {
    /// The clocks of `config`; `announce`: identify them once the node has started.
    pub(crate) fn new(config: &[ClockConfig], announce: bool) -> Self {
        let clocks = config
            .iter()
            .map(|c| Clock {
                id: c.id,
                role: match &c.role {
                    ClockRole::Generator(g) => Role::Generator(Box::new(Generator::new(g.clone()))),
                    ClockRole::Consumer(c) => Role::Consumer(Consumer::new(c.clone())),
                },
            })
            .collect();
        ClockService { clocks, announce: announce && !config.is_empty(), stats: ClockStats::default() }
    }

    /// Identify every clock again (after the node's Initialization Complete, or a lost link).
    pub(crate) fn announce(&mut self) {
        self.announce = !self.clocks.is_empty();
    }

    /// Runs `f` on clock `id` with the node's queues.
    fn with<T>(
        &mut self,
        out: &mut Outputs,
        id: ClockId,
        f: impl FnOnce(&mut Role, &mut Bus<'_>) -> T,
    ) -> Result<T, ClockError> {
        let clock = self.clocks.iter_mut().find(|c| c.id == id).ok_or(ClockError::UnknownClock(id))?;
        Ok(f(&mut clock.role, &mut Bus { out, clock: id, stats: &mut self.stats }))
    }
}

impl Service<Lent<'_>> for ClockService {
    /// Identify Events, and the event messages of the clocks' ranges.
    fn handle_message(&mut self, cx: &mut Lent<'_>, msg: MessageRef<'_>) -> bool {
        if self.clocks.is_empty() || !crate::events::is_event_mti(msg.mti) {
            return false;
        }
        let (now, out) = (cx.now, &mut *cx.out);
        if matches!(msg.mti, Mti::IDENTIFY_EVENTS_GLOBAL | Mti::IDENTIFY_EVENTS_ADDRESSED) {
            for clock in &mut self.clocks {
                let mut bus = Bus { out, clock: clock.id, stats: &mut self.stats };
                match &mut clock.role {
                    Role::Generator(g) => g.identify(&mut bus),
                    Role::Consumer(c) => c.identify(&mut bus),
                }
            }
            return true;
        }
        let Some(event) = EventId::from_slice(msg.payload) else {
            bump(&mut self.stats.malformed);
            return false;
        };
        let heard = |suffix| Heard { from: msg.source, mti: msg.mti, suffix };
        let mut taken = false;
        for clock in &mut self.clocks {
            let suffix = match msg.mti {
                // A Range Identified names its range by its low bits: the clock's whole
                // range is its ID followed by sixteen equal bits.
                Mti::CONSUMER_RANGE_IDENTIFIED | Mti::PRODUCER_RANGE_IDENTIFIED => {
                    match EventRange::from_encoded(event) {
                        range if range.first() == clock.id.base() && range.bits() == 16 => Some(0),
                        _ => None,
                    }
                }
                _ => ClockId::of(event).filter(|(id, _)| *id == clock.id).map(|(_, suffix)| suffix),
            };
            let Some(suffix) = suffix else { continue };
            taken = true;
            let mut bus = Bus { out, clock: clock.id, stats: &mut self.stats };
            match &mut clock.role {
                Role::Generator(g) => g.on_message(now, &mut bus, heard(suffix)),
                Role::Consumer(c) => c.on_message(now, &mut bus, heard(suffix)),
            }
        }
        taken
    }

    /// Broadcast Time has no interaction to reject.
    fn handle_error_report(&mut self, _: &mut Lent<'_>, _: NodeId, _: ErrorReport) -> bool {
        false
    }

    /// Nothing is kept per peer. (A lost link identifies the clocks again: the node asks.)
    fn peer_changed(&mut self, _: &mut Outputs, _: ServiceChange) {}

    fn handle_timeout(&mut self, cx: &mut Lent<'_>) {
        let (now, out) = (cx.now, &mut *cx.out);
        let announce = core::mem::take(&mut self.announce);
        for clock in &mut self.clocks {
            let mut bus = Bus { out, clock: clock.id, stats: &mut self.stats };
            match &mut clock.role {
                Role::Generator(g) => {
                    if announce {
                        g.start(now, &mut bus);
                    }
                    g.on_timeout(now, &mut bus);
                }
                Role::Consumer(c) => {
                    if announce {
                        c.start(now, &mut bus);
                    }
                    c.on_timeout(now, &mut bus);
                }
            }
        }
    }

    fn poll_timeout(&self) -> Option<Instant> {
        if self.announce {
            return Some(Instant::ZERO);
        }
        self.clocks.iter().fold(None, |due, clock| {
            earliest(
                due,
                match &clock.role {
                    Role::Generator(g) => g.deadline(),
                    Role::Consumer(c) => c.deadline(),
                },
            )
        })
    }
}

/// Broadcast Time commands.
impl Node {
    /// Clock `id` at `now`: its time, rate and whether it runs (`None`: no such clock here).
    pub fn clock(&self, id: ClockId, now: Instant) -> Option<ClockState> {
        let clock = self.services.clocks.clocks.iter().find(|c| c.id == id)?;
        Some(match &clock.role {
            Role::Generator(g) => g.state(now),
            Role::Consumer(c) => c.state(now),
        })
    }

    /// Changes clock `id`. A generator here changes at once (an "out of band" change: its
    /// effective value is reported, and the synchronization sequence follows 3 s later); a
    /// consumer sends the set command to the clock's generator, whose echo it then follows.
    pub fn set_clock(&mut self, now: Instant, id: ClockId, set: ClockSet) -> Result<(), ClockError> {
        let valid = match set {
            ClockSet::Time { hour, minute } => hour < 24 && minute < 60,
            ClockSet::Date { month, day } => (1..=12).contains(&month) && (1..=31).contains(&day),
            ClockSet::Year(year) => year <= 4095,
            ClockSet::Rate(_) | ClockSet::Start | ClockSet::Stop => true,
        };
        if !valid {
            return Err(ClockError::OutOfRange);
        }
        if !self.out.has_room() {
            return Err(ClockError::QueueFull);
        }
        self.services.clocks.with(&mut self.out, id, |role, bus| match role {
            Role::Generator(g) => g.set(now, bus, set, None),
            Role::Consumer(_) => {
                bus.report(set.message());
                Ok(())
            }
        })?
    }

    /// Asks the generator of clock `id` for its synchronization sequence (a generator here
    /// sends it, as for a query from the bus).
    pub fn query_clock(&mut self, now: Instant, id: ClockId) -> Result<(), ClockError> {
        if !self.out.has_room() {
            return Err(ClockError::QueueFull);
        }
        self.services.clocks.with(&mut self.out, id, |role, bus| match role {
            Role::Generator(g) => g.request_sync(now),
            Role::Consumer(c) => c.query(bus),
        })
    }

    /// The clocks' counters.
    pub fn clock_stats(&self) -> ClockStats {
        self.services.clocks.stats
    }
}
