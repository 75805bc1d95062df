//! Broadcast Time against the standard's interactions, message by message: a generator and a
//! consumer driven by hand-made messages on a virtual clock (the checks OlcbChecker's
//! `control_broadcasttime` makes, and the bounds), and the two roles against each other.

use openlcb_node::broadcast_time::{
    ClockChange, ClockConfig, ClockEvent, ClockId, ClockRole, ClockSet, ClockTime, ConsumerConfig, GeneratorConfig,
    Rate, SyncTail,
};
use openlcb_node::{Node, NodeConfig, NodeEvent};
use openlcb_stream::{Duration, EventId, Instant, Message, Mti, NodeId};

const CLOCK: ClockId = ClockId::DEFAULT_FAST;
const DUT: NodeId = NodeId::from_bytes([5, 1, 1, 1, 0x22, 1]);
const TOOL: NodeId = NodeId::from_bytes([5, 1, 1, 1, 0x22, 9]);

/// A node under test on a virtual clock, and what it sent, with when.
struct Bench {
    node: Node,
    now: Instant,
    sent: Vec<(Instant, Message)>,
    events: Vec<ClockEvent>,
}

impl Bench {
    fn new(clocks: Vec<ClockConfig>) -> Self {
        let mut config = NodeConfig::default();
        config.clocks = clocks;
        let mut bench =
            Bench { node: Node::new(DUT, config), now: Instant::from_secs(1), sent: Vec::new(), events: Vec::new() };
        bench.advance(Duration::from_millis(0));
        bench
    }

    fn generator(config: GeneratorConfig) -> Self {
        Bench::new(vec![ClockConfig::generator(CLOCK, config)])
    }

    /// Runs the node's timers for `span` of virtual time, each at its deadline.
    fn advance(&mut self, span: Duration) {
        let end = self.now + span;
        loop {
            self.node.handle_timeout(self.now);
            self.drain();
            match self.node.poll_timeout() {
                Some(due) if due <= end => self.now = due.max(self.now),
                _ => break,
            }
            if self.node.poll_timeout().is_some_and(|d| d <= self.now) {
                self.node.handle_timeout(self.now);
                self.drain();
                self.now += Duration::from_micros(1);
            }
        }
        self.now = end;
        self.node.handle_timeout(end);
        self.drain();
    }

    fn drain(&mut self) {
        while let Some(m) = self.node.poll_transmit() {
            self.sent.push((self.now, m));
        }
        while let Some(e) = self.node.poll_event() {
            if let NodeEvent::Clock(e) = e {
                self.events.push(e);
            }
        }
    }

    /// The tool sends `mti` with the clock's event `suffix`.
    fn hear(&mut self, mti: Mti, suffix: u16) {
        let msg = Message::global(mti, TOOL, CLOCK.event(suffix).to_bytes());
        self.node.handle_message(self.now, msg.as_ref());
        self.drain();
    }

    /// The tool sends a Producer/Consumer Event Report of the clock's `suffix`.
    fn pcer(&mut self, suffix: u16) {
        self.hear(Mti::PRODUCER_CONSUMER_EVENT_REPORT, suffix);
    }

    /// What was sent of the clock's events since `from`, as (MTI, low two bytes).
    fn clock_messages(&self, from: usize) -> Vec<(Mti, u16)> {
        self.sent[from..]
            .iter()
            .filter_map(|(_, m)| {
                let event = EventId::from_slice(&m.payload)?;
                (event.0 >> 16 == CLOCK.base().0 >> 16).then_some((m.mti, event.0 as u16))
            })
            .collect()
    }

    /// When each Report Time event was sent since `from`.
    fn time_reports(&self, from: usize) -> Vec<(Instant, u16)> {
        self.sent[from..]
            .iter()
            .filter(|(_, m)| m.mti == Mti::PRODUCER_CONSUMER_EVENT_REPORT)
            .filter_map(|(t, m)| {
                let suffix = EventId::from_slice(&m.payload)?.0 as u16;
                (suffix >> 8 < 0x18).then_some((*t, suffix))
            })
            .collect()
    }

    fn mark(&self) -> usize {
        self.sent.len()
    }
}

const PID: Mti = Mti::PRODUCER_IDENTIFIED_VALID;
const PCER: Mti = Mti::PRODUCER_CONSUMER_EVENT_REPORT;

fn at(year: u16, month: u8, day: u8, hour: u8, minute: u8) -> ClockTime {
    ClockTime::new(year, month, day, hour, minute, 0).unwrap()
}

fn rate(text: &str) -> Rate {
    text.parse().unwrap()
}

#[test]
fn a_generator_starts_with_its_ranges_then_its_state() {
    let mut config = GeneratorConfig::default();
    config.start = at(1956, 7, 4, 6, 0);
    config.rate = rate("4");
    let bench = Bench::generator(config);
    let sent: Vec<Mti> = bench.sent.iter().map(|(_, m)| m.mti).collect();
    assert_eq!(sent[..2], [Mti::INITIALIZATION_COMPLETE, Mti::VERIFY_NODE_ID_GLOBAL]);
    assert_eq!(
        bench.clock_messages(0),
        [
            (Mti::PRODUCER_RANGE_IDENTIFIED, 0xFFFF),
            (Mti::CONSUMER_RANGE_IDENTIFIED, 0xFFFF),
            (PID, 0xF001),
            (PID, 0x4010),
            (PID, 0x37A4),
            (PID, 0x2704),
            (PID, 0x0600),
        ],
        "stopped: no report of a next minute that will not come"
    );
}

/// bt20: set 01:23, 22 July 2023, 4x, stopped; each echoed at once, one sequence 3 s after
/// the last, with the values set.
#[test]
fn sets_are_echoed_at_once_and_the_state_follows_three_seconds_after_the_last() {
    for tail in [SyncTail::WhenValid, SyncTail::AtOnce] {
        let mut config = GeneratorConfig::default();
        config.sync_tail = tail;
        config.running = true;
        let mut bench = Bench::generator(config);
        bench.advance(Duration::from_secs(5));
        let mark = bench.mark();
        for suffix in [0x8117, 0xA716, 0xB7E7, 0xC010, 0xF001] {
            bench.pcer(suffix);
        }
        assert_eq!(bench.clock_messages(mark), [(PCER, 0x0117), (PCER, 0x2716), (PCER, 0x37E7), (PCER, 0x4010)]);
        let set_at = bench.now;
        bench.advance(Duration::from_millis(2_999));
        assert_eq!(bench.clock_messages(mark).len(), 4, "nothing more before 3 s");
        bench.advance(Duration::from_secs(5));
        let mut expected = vec![(PID, 0xF001), (PID, 0x4010), (PID, 0x37E7), (PID, 0x2716), (PID, 0x0117)];
        if tail == SyncTail::AtOnce {
            expected.push((PCER, 0x0118));
        }
        assert_eq!(bench.clock_messages(mark)[4..], expected, "{tail:?}");
        let sync_at = bench.sent[mark..].iter().find(|(_, m)| m.mti == PID).map(|(t, _)| *t);
        assert!(sync_at.is_some_and(|t| t.saturating_duration_since(set_at) == Duration::from_secs(3)));
        let state = bench.node.clock(CLOCK, bench.now).unwrap();
        assert_eq!((state.time, state.running, state.rate), (at(2023, 7, 22, 1, 23), false, rate("4")));
        assert_eq!(bench.node.clock_stats().sets_applied, 5);
    }
}

/// bt40: Set Time, a second later Set Rate: one sequence, 3 s after the second.
#[test]
fn sets_within_three_seconds_share_one_sequence() {
    let mut bench = Bench::generator(GeneratorConfig::default());
    bench.advance(Duration::from_secs(5));
    let mark = bench.mark();
    bench.pcer(0x822D);
    bench.advance(Duration::from_secs(1));
    bench.pcer(0xC018);
    bench.advance(Duration::from_secs(6));
    let starts = bench.clock_messages(mark).iter().filter(|(m, s)| *m == PID && *s == 0xF001).count();
    assert_eq!(starts, 1);
    assert_eq!(bench.clock_messages(mark)[..2], [(PCER, 0x022D), (PCER, 0x4018)]);
}

/// The bounds: a flood of queries costs one sequence per second, a flood of sets one per
/// ten seconds however long it lasts.
#[test]
fn floods_of_queries_and_sets_cost_a_bounded_number_of_sequences() {
    let mut bench = Bench::generator(GeneratorConfig::default());
    bench.advance(Duration::from_secs(5));
    let mark = bench.mark();
    for _ in 0..1000 {
        bench.pcer(0xF000);
        bench.advance(Duration::from_millis(10));
    }
    let syncs = bench.clock_messages(mark).iter().filter(|(m, s)| *m == PID && *s >> 12 == 0xF).count();
    assert!((9..=11).contains(&syncs), "10 s of queries: {syncs} sequences");
    assert_eq!(bench.node.clock_stats().queries, 1000);

    let mark = bench.mark();
    for minute in 0..2000u16 {
        bench.pcer(0x8000 | (minute % 60));
        bench.advance(Duration::from_millis(20));
    }
    let syncs = bench.clock_messages(mark).iter().filter(|(m, s)| *m == PID && *s >> 12 == 0xF).count();
    assert!((4..=5).contains(&syncs), "40 s of sets: {syncs} sequences");
}

/// bt50 and bt60: at 4x the time is reported at most once a real minute, but a minute a
/// consumer identified on its own is always reported.
#[test]
fn reports_are_a_real_minute_apart_but_requested_minutes_always_come() {
    let mut bench = Bench::generator(GeneratorConfig::default());
    bench.advance(Duration::from_secs(5));
    bench.hear(Mti::CONSUMER_IDENTIFIED_VALID, 0x0118);
    let mark = bench.mark();
    for suffix in [0x8100, 0xC010, 0xF002] {
        bench.pcer(suffix);
    }
    bench.advance(Duration::from_secs(600));
    let reports = bench.time_reports(mark);
    // 600 s at 4x is 150 fast minutes. The echo of the set (01:00) and the sequence's last
    // report (01:01, 15 s later, when it begins) come as §6.3 needs; after them one report a
    // real minute, and 01:24, asked for, at 6 + 24 * 15 s.
    assert_eq!(reports[..2].iter().map(|r| r.1).collect::<Vec<_>>(), [0x0100, 0x0101]);
    for pair in reports[1..].windows(2) {
        let gap = pair[1].0.saturating_duration_since(pair[0].0);
        let requested = pair[1].1 == 0x0118 || pair[0].1 == 0x0118;
        assert!(requested || gap >= Duration::from_secs(60), "{pair:?}");
    }
    assert!(reports.iter().any(|(_, s)| *s == 0x0118), "{reports:?}");
    assert!((10..=13).contains(&reports.len()), "{} reports: {reports:?}", reports.len());
}

/// bt70: through midnight at 10x: Date Rollover, then 00:00, and 3 s later the year and the
/// new date; the same backwards.
#[test]
fn midnight_brings_the_rollover_and_the_new_date() {
    let mut bench = Bench::generator(GeneratorConfig::default());
    bench.advance(Duration::from_secs(5));
    for suffix in [0x973A, 0xA716, 0xB7E7, 0xC028, 0xF002] {
        bench.pcer(suffix);
    }
    bench.advance(Duration::from_secs(5));
    let mark = bench.mark();
    bench.advance(Duration::from_secs(20));
    let sent: Vec<(Mti, u16)> = bench.clock_messages(mark);
    let rollover = sent.iter().position(|m| *m == (PCER, 0xF003)).expect("rollover");
    assert_eq!(sent[rollover + 1], (PCER, 0x0000));
    assert_eq!(sent[rollover + 2..rollover + 4], [(PCER, 0x37E7), (PCER, 0x2717)]);
    let when = |m: (Mti, u16)| {
        bench.sent[mark..]
            .iter()
            .find(|(_, s)| (s.mti, s.payload[7] as u16 | (s.payload[6] as u16) << 8) == m)
            .unwrap()
            .0
    };
    assert_eq!(when((PCER, 0x2717)).saturating_duration_since(when((PCER, 0xF003))), Duration::from_secs(3));

    // Backwards at -10x from 00:01 on 1 January 2024: into 31 December 2023.
    let mark = bench.mark();
    for suffix in [0xF001, 0xB7E8, 0xA101, 0x8001, 0xCFD8, 0xF002] {
        bench.pcer(suffix);
    }
    bench.advance(Duration::from_secs(20));
    let sent = bench.clock_messages(mark);
    let rollover = sent.iter().position(|m| *m == (PCER, 0xF003)).expect("rollover backwards");
    assert_eq!(sent[rollover + 1], (PCER, 0x173B));
    assert_eq!(sent[rollover + 2..rollover + 4], [(PCER, 0x37E7), (PCER, 0x2C1F)]);
}

/// Bad input: reserved codes and impossible dates are ignored and counted, sets are refused
/// by config, and a rate of zero becomes the smallest step.
#[test]
fn bogus_events_are_counted_and_refused_sets_change_nothing() {
    let mut bench = Bench::generator(GeneratorConfig::default());
    bench.advance(Duration::from_secs(5));
    let mark = bench.mark();
    for suffix in [0x983C, 0xA21E, 0x1800, 0xF004, 0xE123] {
        bench.pcer(suffix);
    }
    let short = Message::global(PCER, TOOL, vec![1, 1, 0, 0]);
    bench.node.handle_message(bench.now, short.as_ref());
    bench.advance(Duration::from_secs(5));
    assert_eq!(bench.clock_messages(mark), [], "nothing answers a bogus set");
    let stats = bench.node.clock_stats();
    assert_eq!((stats.reserved_ignored, stats.sets_refused, stats.sets_applied), (4, 1, 0));
    bench.pcer(0xC000);
    assert_eq!(bench.clock_messages(mark), [(PCER, 0x4001)], "zero is 0.25");

    let mut config = GeneratorConfig::default();
    config.accept_sets = false;
    let mut bench = Bench::generator(config);
    bench.advance(Duration::from_secs(5));
    let before = bench.node.clock(CLOCK, bench.now).unwrap();
    let mark = bench.mark();
    bench.pcer(0x8117);
    bench.pcer(0xF002);
    bench.advance(Duration::from_secs(5));
    assert_eq!(bench.clock_messages(mark), []);
    assert_eq!(bench.node.clock(CLOCK, bench.now).unwrap(), before);
    assert_eq!(bench.node.clock_stats().sets_refused, 2);
}

/// A consumer: identifies the range, asks for the state after start-up unless another node
/// asks first, follows the sequence, and answers Identify Consumer for every clock event.
#[test]
fn a_consumer_asks_once_follows_the_state_and_answers_for_the_range() {
    let mut bench = Bench::new(vec![ClockConfig::consumer(CLOCK)]);
    assert_eq!(
        bench.clock_messages(0),
        [(Mti::CONSUMER_RANGE_IDENTIFIED, 0xFFFF), (Mti::PRODUCER_IDENTIFIED_UNKNOWN, 0xF000)]
    );
    bench.advance(Duration::from_secs(1));
    assert_eq!(bench.clock_messages(0)[2..], [(PCER, 0xF000)], "its query");

    // Another consumer's query makes this one's unnecessary.
    let mut quiet = Bench::new(vec![ClockConfig::consumer(CLOCK)]);
    quiet.pcer(0xF000);
    quiet.advance(Duration::from_secs(2));
    assert_eq!(quiet.clock_messages(0).len(), 2);

    // bt110: the sequence of 01:23, 22 July 2023, 4x, stopped.
    for suffix in [0xF001, 0x4010, 0x37E7, 0x2716, 0x0117] {
        bench.hear(PID, suffix);
    }
    // OpenLcbCLib's reading: the next minute at once, from a stopped clock.
    bench.pcer(0x0118);
    bench.advance(Duration::from_secs(60));
    let state = bench.node.clock(CLOCK, bench.now).unwrap();
    assert_eq!(
        (state.time, state.running, state.rate, state.synchronized),
        (at(2023, 7, 22, 1, 23), false, rate("4"), true)
    );
    let mark = bench.mark();
    for suffix in [0xF001, 0x4010, 0x37E7, 0x2716, 0x0117, 0xF002, 0x8000, 0x4020] {
        bench.hear(Mti::IDENTIFY_CONSUMER, suffix);
    }
    let answers = bench.clock_messages(mark);
    assert_eq!(answers.len(), 8);
    assert!(answers.iter().all(|(m, _)| *m == Mti::CONSUMER_IDENTIFIED_UNKNOWN));

    // bt120, bt130: stop, start and rate reports are followed at once.
    bench.pcer(0xF002);
    bench.pcer(0x4020);
    let state = bench.node.clock(CLOCK, bench.now).unwrap();
    assert!(state.running && state.rate == rate("8"));
    bench.advance(Duration::from_millis(7_500));
    assert_eq!(bench.node.clock(CLOCK, bench.now).unwrap().time, at(2023, 7, 22, 1, 24));
    let changes: Vec<ClockChange> = bench.events.iter().map(|e| e.change).collect();
    for wanted in [ClockChange::Synchronized, ClockChange::Started, ClockChange::Rate(rate("8"))] {
        assert!(changes.contains(&wanted), "{wanted:?} in {changes:?}");
    }
    assert!(changes.contains(&ClockChange::Minute(at(2023, 7, 22, 1, 24))));
}

/// A report more than a minute from what the consumer computed: it follows it, and asks for
/// the state when no sequence follows.
#[test]
fn a_consumer_out_of_step_asks_again() {
    let mut config = ConsumerConfig::default();
    config.step_check = Duration::from_secs(5);
    let mut clock = ClockConfig::consumer(CLOCK);
    clock.role = ClockRole::Consumer(config);
    let mut bench = Bench::new(vec![clock]);
    bench.pcer(0xF000); // no start-up query
    for suffix in [0xF002, 0x4004, 0x37E7, 0x2716, 0x0117] {
        bench.hear(PID, suffix);
    }
    bench.advance(Duration::from_secs(30));
    let mark = bench.mark();
    bench.pcer(0x0930);
    assert_eq!(bench.node.clock(CLOCK, bench.now).unwrap().time, at(2023, 7, 22, 9, 48));
    bench.advance(Duration::from_secs(6));
    assert_eq!(bench.clock_messages(mark), [(PCER, 0xF000)]);
    assert_eq!(bench.node.clock_stats().queries_sent, 1);
}

/// Two generators on two clocks and two consumers, one of each clock, all on one bus: each
/// consumer follows its own clock only.
#[test]
fn several_clocks_on_one_bus_stay_apart() {
    let mut fast = GeneratorConfig::default();
    fast.start = at(1956, 7, 4, 6, 0);
    fast.rate = rate("4");
    fast.running = true;
    let mut real = GeneratorConfig::default();
    real.start = at(2026, 12, 4, 21, 0);
    real.running = true;
    let config = |clocks| {
        let mut c = NodeConfig::default();
        c.clocks = clocks;
        c
    };
    let ids = [0x10, 0x11, 0x12, 0x13].map(|n| NodeId::from_bytes([5, 1, 1, 1, 0x22, n]));
    let mut nodes = [
        Node::new(ids[0], config(vec![ClockConfig::generator(ClockId::DEFAULT_FAST, fast)])),
        Node::new(ids[1], config(vec![ClockConfig::generator(ClockId::ALTERNATE_1, real)])),
        Node::new(ids[2], config(vec![ClockConfig::consumer(ClockId::DEFAULT_FAST)])),
        Node::new(
            ids[3],
            config(vec![ClockConfig::consumer(ClockId::ALTERNATE_1), ClockConfig::consumer(ClockId::ALTERNATE_2)]),
        ),
    ];
    let mut now = Instant::ZERO;
    for _ in 0..1201 {
        now += Duration::from_millis(100);
        for node in &mut nodes {
            node.handle_timeout(now);
        }
        loop {
            let mut all = Vec::new();
            for node in &mut nodes {
                all.extend(std::iter::from_fn(|| node.poll_transmit()));
                while node.poll_event().is_some() {}
            }
            if all.is_empty() {
                break;
            }
            for m in &all {
                for node in &mut nodes {
                    node.handle_message(now, m.as_ref());
                }
            }
        }
    }
    // Two real minutes from the first timeout: the fast clock is 8 minutes on, the other 2.
    let fast_seen = nodes[2].clock(ClockId::DEFAULT_FAST, now).unwrap();
    let real_seen = nodes[3].clock(ClockId::ALTERNATE_1, now).unwrap();
    assert_eq!((fast_seen.time.hour, fast_seen.time.minute, fast_seen.rate), (6, 8, rate("4")));
    assert_eq!((real_seen.time.year, real_seen.time.hour, real_seen.time.minute), (2026, 21, 2));
    assert!(!nodes[3].clock(ClockId::ALTERNATE_2, now).unwrap().synchronized, "nobody generates alternate 2");
    for node in &nodes {
        assert_eq!(node.clock_stats().other_generators, 0);
    }
}

/// The application sets its own generator (out of band) and drives another's as a
/// consumer; a consumer's commands reach the bus as set events.
#[test]
fn the_application_sets_a_clock_of_its_own_or_sends_the_command() {
    let mut bench = Bench::generator(GeneratorConfig::default());
    bench.advance(Duration::from_secs(5));
    let mark = bench.mark();
    bench.node.set_clock(bench.now, CLOCK, ClockSet::Time { hour: 8, minute: 30 }).unwrap();
    bench.drain();
    assert_eq!(bench.clock_messages(mark), [(PCER, 0x081E)]);
    assert!(bench.node.set_clock(bench.now, CLOCK, ClockSet::Time { hour: 24, minute: 0 }).is_err());
    assert!(bench.node.set_clock(bench.now, ClockId::ALTERNATE_2, ClockSet::Start).is_err());

    let mut tool = Bench::new(vec![ClockConfig::consumer(CLOCK)]);
    let mark = tool.mark();
    tool.node.set_clock(tool.now, CLOCK, ClockSet::Rate(rate("-1.5"))).unwrap();
    tool.node.set_clock(tool.now, CLOCK, ClockSet::Date { month: 12, day: 25 }).unwrap();
    tool.drain();
    assert_eq!(tool.clock_messages(mark), [(PCER, 0xCFFA), (PCER, 0xAC19)]);
}

/// A report of the minute the consumer is well into (OpenMRN's generator sends one when an
/// alarm set before a Set Time fires) leaves the computed time; a report at the minute's
/// start puts it right; a sequence's time moves it only into that minute.
#[test]
fn a_consumer_keeps_its_seconds_against_late_reports_and_takes_the_minutes_start() {
    let mut bench = Bench::new(vec![ClockConfig::consumer(CLOCK)]);
    bench.pcer(0xF000);
    for suffix in [0xF002, 0x40F0, 0x37A4, 0x2704, 0x0600] {
        bench.hear(PID, suffix);
    }
    bench.pcer(0x0601); // 06:01 begins (60x)
    bench.advance(Duration::from_millis(900));
    bench.pcer(0x0601); // late: 54 fast seconds into 06:01
    let shown = bench.node.clock(CLOCK, bench.now).unwrap().time;
    assert_eq!((shown.minute, shown.second), (1, 54));
    bench.advance(Duration::from_millis(50));
    bench.pcer(0x0602); // 06:02 begins, 3 fast seconds before this consumer computed it
    let shown = bench.node.clock(CLOCK, bench.now).unwrap().time;
    assert_eq!((shown.minute, shown.second), (2, 0));
    bench.advance(Duration::from_millis(100));
    bench.pcer(0x0602); // 6 fast seconds late: within the delay, the start
    assert_eq!(bench.node.clock(CLOCK, bench.now).unwrap().time.second, 0);
    // A sequence identifying 06:02 while this consumer is at 06:02:30 keeps the seconds.
    bench.advance(Duration::from_millis(500));
    for suffix in [0xF002, 0x40F0, 0x37A4, 0x2704, 0x0602] {
        bench.hear(PID, suffix);
    }
    assert_eq!(bench.node.clock(CLOCK, bench.now).unwrap().time.second, 30);
}

/// A set while stopped: the time is the one set and stays there, its echo and the sequence
/// say so, and no minute is reported until it starts.
#[test]
fn a_set_while_stopped_holds_until_the_clock_starts() {
    let mut bench = Bench::generator(GeneratorConfig::default());
    bench.advance(Duration::from_secs(5));
    let mark = bench.mark();
    bench.pcer(0x8A0F); // 10:15
    bench.advance(Duration::from_secs(120));
    assert_eq!(bench.node.clock(CLOCK, bench.now).unwrap().time, at(2000, 1, 1, 10, 15));
    let sent = bench.clock_messages(mark);
    assert_eq!(sent[0], (PCER, 0x0A0F));
    assert_eq!(sent[1..], [(PID, 0xF001), (PID, 0x4004), (PID, 0x37D0), (PID, 0x2101), (PID, 0x0A0F)]);
    bench.pcer(0xF002);
    bench.advance(Duration::from_secs(61));
    assert_eq!(bench.node.clock(CLOCK, bench.now).unwrap().time, ClockTime::new(2000, 1, 1, 10, 16, 1).unwrap());
    assert!(bench.time_reports(mark).iter().any(|(_, s)| *s == 0x0A10), "10:16 reported once it runs");
}

/// A consumer that stops the clock itself (it does not hear its own command) stands once the
/// generator's sequence says so.
#[test]
fn a_consumer_that_sends_stop_stands_when_the_generator_says_it_stopped() {
    let mut bench = Bench::new(vec![ClockConfig::consumer(CLOCK)]);
    bench.pcer(0xF000);
    for suffix in [0xF002, 0x4010, 0x37E7, 0x2716, 0x0117] {
        bench.hear(PID, suffix);
    }
    bench.advance(Duration::from_secs(2));
    bench.node.set_clock(bench.now, CLOCK, ClockSet::Stop).unwrap();
    bench.drain();
    assert!(bench.node.clock(CLOCK, bench.now).unwrap().running, "not before the generator says so");
    bench.advance(Duration::from_secs(3));
    for suffix in [0xF001, 0x4010, 0x37E7, 0x2716, 0x0117] {
        bench.hear(PID, suffix);
    }
    assert!(!bench.node.clock(CLOCK, bench.now).unwrap().running);
}
