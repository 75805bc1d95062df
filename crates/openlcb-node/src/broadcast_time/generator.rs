//! A clock generator: keeps the time, reports it, takes set commands and answers queries.

use openlcb_stream::{Duration, Instant, Mti, NodeId};

use super::calendar::{ClockTime, DAY_MS, MINUTE_MS};
use super::model::Model;
use super::wire::{ClockMessage, Rate};
use super::{Bus, ClockChange, ClockError, ClockSet, ClockState, GeneratorConfig, Heard, SyncTail};
use crate::node::bump;

/// Reports of the time while running are at least this far apart (§6.2), but for the
/// minutes a consumer asked for and midnight.
const REPORT_INTERVAL: Duration = Duration::from_secs(60);

/// Minutes in a day: the bits of [`Generator::requested`].
const MINUTES_PER_DAY: usize = 24 * 60;

#[derive(Debug)]
pub(crate) struct Generator {
    config: GeneratorConfig,
    model: Model,
    /// The minute the clock was last seen in (a change by running is a minute begun).
    minute: i64,
    /// When the time was last reported.
    last_report: Option<Instant>,
    /// The synchronization sequence's last report waits for the next minute.
    tail_pending: bool,
    /// When the synchronization sequence goes out.
    sync_due: Option<Instant>,
    /// The first set command of the run the pending sequence answers.
    sets_since: Option<Instant>,
    /// When the last sequence went out.
    last_sync: Option<Instant>,
    /// When the year and date follow a midnight.
    rollover_due: Option<Instant>,
    /// When the clock next enters a minute.
    tick_due: Option<Instant>,
    /// The minutes of the day a consumer identified as consumed on their own (§6.2 item 2),
    /// one bit each.
    requested: [u64; MINUTES_PER_DAY.div_ceil(64)],
}

impl Generator {
    pub(crate) fn new(config: GeneratorConfig) -> Self {
        let model = Model::new(config.start, config.rate, config.running);
        let minute = config.start.to_ms().div_euclid(MINUTE_MS);
        Generator {
            config,
            model,
            minute,
            last_report: None,
            tail_pending: false,
            sync_due: None,
            sets_since: None,
            last_sync: None,
            rollover_due: None,
            tick_due: None,
            requested: [0; MINUTES_PER_DAY.div_ceil(64)],
        }
    }

    pub(crate) fn state(&self, now: Instant) -> ClockState {
        let model = &self.model;
        ClockState { time: model.time(now), rate: model.rate, running: model.running, synchronized: true }
    }

    /// Start-up (§6.1): the ranges, then the synchronization sequence at once.
    pub(crate) fn start(&mut self, now: Instant, bus: &mut Bus<'_>) {
        self.model.touch(now);
        self.identify(bus);
        self.sync_due = Some(now);
    }

    /// The whole range, produced and consumed.
    pub(crate) fn identify(&mut self, bus: &mut Bus<'_>) {
        bus.identify_range(Mti::PRODUCER_RANGE_IDENTIFIED, 0, 1 << 16);
        bus.identify_range(Mti::CONSUMER_RANGE_IDENTIFIED, 0, 1 << 16);
    }

    pub(crate) fn deadline(&self) -> Option<Instant> {
        [self.sync_due, self.rollover_due, self.tick_due].into_iter().flatten().min()
    }

    pub(crate) fn on_message(&mut self, now: Instant, bus: &mut Bus<'_>, heard: Heard) {
        self.model.touch(now);
        match heard.mti {
            Mti::PRODUCER_CONSUMER_EVENT_REPORT => self.on_report(now, bus, heard),
            Mti::IDENTIFY_PRODUCER => self.answer_producer(bus, heard.suffix),
            Mti::IDENTIFY_CONSUMER => bus.answer(Mti::CONSUMER_IDENTIFIED_UNKNOWN, bus.clock.event(heard.suffix)),
            // A consumer of the whole range has started: it wants the state (as OpenMRN's
            // generator, which answers it with the sequence).
            Mti::CONSUMER_RANGE_IDENTIFIED => self.request_sync(now),
            Mti(0x04C4..=0x04C7) => {
                if let Some(ClockMessage::ReportTime { hour, minute }) = ClockMessage::decode(heard.suffix) {
                    let bit = usize::from(hour) * 60 + usize::from(minute);
                    if let Some(word) = self.requested.get_mut(bit / 64) {
                        *word |= 1 << (bit % 64);
                    }
                }
            }
            Mti(0x0544..=0x0547) if ClockMessage::decode(heard.suffix).is_some_and(ClockMessage::is_report) => {
                bump(&mut bus.stats.other_generators);
            }
            _ => {}
        }
        self.retime(now);
    }

    fn on_report(&mut self, now: Instant, bus: &mut Bus<'_>, heard: Heard) {
        let Some(message) = ClockMessage::decode(heard.suffix) else {
            bump(&mut bus.stats.reserved_ignored);
            return;
        };
        match message {
            ClockMessage::Query => {
                bump(&mut bus.stats.queries);
                self.request_sync(now);
            }
            _ if message.is_report() => bump(&mut bus.stats.other_generators),
            _ => {
                if let Some(set) = ClockSet::of(message)
                    && (!self.config.accept_sets || self.set(now, bus, set, Some(heard.from)).is_err())
                {
                    bump(&mut bus.stats.sets_refused);
                }
            }
        }
    }

    /// Identify Producer: Valid for the clock's state now, Invalid for another report.
    fn answer_producer(&self, bus: &mut Bus<'_>, suffix: u16) {
        let Some(message) = ClockMessage::decode(suffix) else { return };
        let mti = match message {
            ClockMessage::Start | ClockMessage::Stop => {
                if (message == ClockMessage::Start) == self.model.running {
                    Mti::PRODUCER_IDENTIFIED_VALID
                } else {
                    Mti::PRODUCER_IDENTIFIED_INVALID
                }
            }
            _ if message.is_report() => {
                // `now` is not lent to Identify answers: the state as last seen.
                if self.reports_at(self.minute).contains(&message) {
                    Mti::PRODUCER_IDENTIFIED_VALID
                } else {
                    Mti::PRODUCER_IDENTIFIED_INVALID
                }
            }
            _ => Mti::PRODUCER_IDENTIFIED_UNKNOWN,
        };
        bus.answer(mti, bus.clock.event(suffix));
    }

    /// The reports of the clock's state in `minute`: time, date, year, rate.
    fn reports_at(&self, minute: i64) -> [ClockMessage; 4] {
        let t = ClockTime::from_ms(minute * MINUTE_MS);
        [
            ClockMessage::ReportTime { hour: t.hour, minute: t.minute },
            ClockMessage::ReportDate { month: t.month, day: t.day },
            ClockMessage::ReportYear(t.year),
            ClockMessage::ReportRate(self.model.rate),
        ]
    }

    /// Carries out `set` at `now`, from `from` (`None`: the application): the effective value
    /// is reported at once, the synchronization sequence follows (§6.5).
    pub(crate) fn set(
        &mut self,
        now: Instant,
        bus: &mut Bus<'_>,
        set: ClockSet,
        from: Option<NodeId>,
    ) -> Result<(), ClockError> {
        self.model.touch(now);
        let model = &mut self.model;
        let (echo, change) = match set {
            ClockSet::Time { hour, minute } => {
                model.set_ms(now, model.with_time_of_day(now, hour, minute));
                (Some(ClockMessage::ReportTime { hour, minute }), ClockChange::Set(model.time(now)))
            }
            ClockSet::Date { month, day } => {
                let ms = model.with_date(now, month, day).ok_or(ClockError::OutOfRange)?;
                model.set_ms(now, ms);
                (Some(ClockMessage::ReportDate { month, day }), ClockChange::Set(model.time(now)))
            }
            ClockSet::Year(year) => {
                model.set_ms(now, model.with_year(now, year));
                (Some(ClockMessage::ReportYear(year)), ClockChange::Set(model.time(now)))
            }
            ClockSet::Rate(rate) => {
                let rate = supported(&self.config, rate);
                model.set_rate(now, rate);
                (Some(ClockMessage::ReportRate(rate)), ClockChange::Rate(rate))
            }
            ClockSet::Start => {
                model.set_running(now, true);
                (None, ClockChange::Started)
            }
            ClockSet::Stop => {
                model.set_running(now, false);
                (None, ClockChange::Stopped)
            }
        };
        bump(&mut bus.stats.sets_applied);
        self.minute = self.model.minute(now);
        self.tail_pending = false;
        if let Some(echo) = echo {
            if matches!(echo, ClockMessage::ReportTime { .. }) {
                self.note_time_report(now, bus);
            }
            let event = bus.clock.event(echo.suffix());
            bus.answer(Mti::PRODUCER_CONSUMER_EVENT_REPORT, event);
        }
        bus.tell(change, from);
        let first = *self.sets_since.get_or_insert(now);
        self.sync_due = Some((now + self.config.sync_delay).min(first + self.config.max_sync_delay));
        self.retime(now);
        Ok(())
    }

    /// A query (or a consumer's start-up): the sequence soon, one for every query of a burst,
    /// at least [`GeneratorConfig::min_sync_interval`] after the last.
    pub(crate) fn request_sync(&mut self, now: Instant) {
        let allowed = self.last_sync.map_or(now, |t| t + self.config.min_sync_interval);
        let due = (now + self.config.query_delay).max(allowed);
        self.sync_due = Some(self.sync_due.map_or(due, |d| d.min(due)));
    }

    pub(crate) fn on_timeout(&mut self, now: Instant, bus: &mut Bus<'_>) {
        self.model.touch(now);
        let minute = self.model.minute(now);
        if minute != self.minute && self.model.running {
            self.minute_begun(now, bus, minute);
        }
        if self.rollover_due.is_some_and(|due| due <= now) {
            self.rollover_due = None;
            let [_, date, year, _] = self.reports_at(minute);
            bus.report(year);
            bus.report(date);
        }
        if self.sync_due.is_some_and(|due| due <= now) {
            self.sync(now, bus);
        }
        self.retime(now);
    }

    /// The running clock entered `minute`: its report when one is due (§6.2).
    fn minute_begun(&mut self, now: Instant, bus: &mut Bus<'_>, minute: i64) {
        let midnight = minute.div_euclid(DAY_MS / MINUTE_MS) != self.minute.div_euclid(DAY_MS / MINUTE_MS);
        self.minute = minute;
        let time = ClockTime::from_ms(minute * MINUTE_MS);
        bus.tell(ClockChange::Minute(time), None);
        if midnight {
            bus.report(ClockMessage::DateRollover);
            self.rollover_due = Some(now + self.config.rollover_delay);
        }
        let of_day = usize::from(time.hour) * 60 + usize::from(time.minute);
        let requested = self.requested.get(of_day / 64).is_some_and(|w| w & (1 << (of_day % 64)) != 0);
        let interval_passed = self.last_report.is_none_or(|t| now.saturating_duration_since(t) >= REPORT_INTERVAL);
        if midnight || requested || self.tail_pending || interval_passed {
            self.note_time_report(now, bus);
            bus.report(ClockMessage::ReportTime { hour: time.hour, minute: time.minute });
        }
        self.tail_pending = false;
    }

    /// The synchronization sequence (§6.3): start or stop, rate, year, date and time as
    /// Producer Identified Valid, then the report of the next minute ([`SyncTail`]).
    fn sync(&mut self, now: Instant, bus: &mut Bus<'_>) {
        self.sync_due = None;
        self.sets_since = None;
        self.last_sync = Some(now);
        bump(&mut bus.stats.syncs_sent);
        let minute = self.model.minute(now);
        self.minute = minute;
        let state = if self.model.running { ClockMessage::Start } else { ClockMessage::Stop };
        let [time, date, year, rate] = self.reports_at(minute);
        for message in [state, rate, year, date, time] {
            bus.send(Mti::PRODUCER_IDENTIFIED_VALID, bus.clock.event(message.suffix()));
        }
        match self.config.sync_tail {
            SyncTail::AtOnce => {
                let next = if self.model.rate.quarters() < 0 { minute - 1 } else { minute + 1 };
                let [next_time, ..] = self.reports_at(next);
                self.note_time_report(now, bus);
                bus.report(next_time);
            }
            SyncTail::WhenValid => self.tail_pending = self.model.running && self.model.rate.quarters() != 0,
        }
    }

    fn note_time_report(&mut self, now: Instant, bus: &mut Bus<'_>) {
        self.last_report = Some(now);
        bump(&mut bus.stats.time_reports_sent);
    }

    fn retime(&mut self, now: Instant) {
        self.tick_due = self.model.next_minute_at(now);
    }
}

/// The rate a Set Rate of `rate` gets: within the configured limits, never zero.
fn supported(config: &GeneratorConfig, rate: Rate) -> Rate {
    let (slowest, fastest) = (config.slowest.min(config.fastest), config.fastest);
    let rate = rate.clamp(slowest, fastest);
    if rate.quarters() != 0 {
        return rate;
    }
    let step = if fastest.quarters() > 0 { 1 } else { -1 };
    Rate::from_quarters(step).unwrap_or(Rate::REAL_TIME)
}
