//! A clock consumer: follows a generator, computes the time between its reports, asks for
//! its state when it lacks it.

use openlcb_stream::{Instant, Mti, NodeId};

use super::calendar::{DAY_MS, MINUTE_MS};
use super::model::Model;
use super::wire::{ClockMessage, Rate};
use super::{Bus, ClockChange, ClockState, ConsumerConfig, Heard};
use crate::node::bump;

/// How late a report of a minute's start may arrive, in real milliseconds, and still be taken
/// as that start.
const REPORT_DELAY_MS: i64 = 500;

#[derive(Debug)]
pub(crate) struct Consumer {
    config: ConsumerConfig,
    model: Model,
    /// The minute last told to the application.
    minute: i64,
    /// A synchronization sequence has been heard.
    synchronized: bool,
    /// The node the reports come from.
    generator: Option<NodeId>,
    /// When the generator was last heard.
    last_heard: Option<Instant>,
    /// When this consumer asks for the state.
    query_due: Option<Instant>,
    /// The minute a synchronization sequence just identified: a report of the next one from
    /// a stopped clock is its announcement, not the time (see the module documentation).
    identified_minute: Option<i64>,
    /// Date Rollover was heard: the next time report is of the day this midnight begins.
    midnight: Option<i64>,
    /// When the clock next enters a minute.
    tick_due: Option<Instant>,
}

impl Consumer {
    pub(crate) fn new(config: ConsumerConfig) -> Self {
        let start = super::GeneratorConfig::default().start;
        Consumer {
            config,
            model: Model::new(start, Rate::REAL_TIME, false),
            minute: start.to_ms().div_euclid(MINUTE_MS),
            synchronized: false,
            generator: None,
            last_heard: None,
            query_due: None,
            identified_minute: None,
            midnight: None,
            tick_due: None,
        }
    }

    pub(crate) fn state(&self, now: Instant) -> ClockState {
        let model = &self.model;
        ClockState { time: model.time(now), rate: model.rate, running: model.running, synchronized: self.synchronized }
    }

    /// Start-up (§6.1): the range, then a query unless the state comes first.
    pub(crate) fn start(&mut self, now: Instant, bus: &mut Bus<'_>) {
        self.model.touch(now);
        self.identify(bus);
        self.query_due = Some(now + self.config.query_delay);
    }

    /// The whole range consumed; the set commands (or only Query) produced.
    pub(crate) fn identify(&mut self, bus: &mut Bus<'_>) {
        bus.identify_range(Mti::CONSUMER_RANGE_IDENTIFIED, 0, 1 << 16);
        if self.config.controls {
            bus.identify_range(Mti::PRODUCER_RANGE_IDENTIFIED, 0x8000, 1 << 15);
        } else {
            bus.answer(Mti::PRODUCER_IDENTIFIED_UNKNOWN, bus.clock.event(ClockMessage::Query.suffix()));
        }
    }

    /// Sends a query now.
    pub(crate) fn query(&mut self, bus: &mut Bus<'_>) {
        self.query_due = None;
        bump(&mut bus.stats.queries_sent);
        bus.report(ClockMessage::Query);
    }

    pub(crate) fn deadline(&self) -> Option<Instant> {
        let silent = self.last_heard.filter(|_| self.model.running).map(|t| t + self.config.resync_after);
        [self.query_due, self.tick_due, silent].into_iter().flatten().min()
    }

    pub(crate) fn on_message(&mut self, now: Instant, bus: &mut Bus<'_>, heard: Heard) {
        self.model.touch(now);
        match heard.mti {
            Mti::IDENTIFY_CONSUMER => bus.answer(Mti::CONSUMER_IDENTIFIED_UNKNOWN, bus.clock.event(heard.suffix)),
            Mti::IDENTIFY_PRODUCER => {
                let produced = if self.config.controls { heard.suffix >= 0x8000 } else { heard.suffix == 0xF000 };
                if produced {
                    bus.answer(Mti::PRODUCER_IDENTIFIED_UNKNOWN, bus.clock.event(heard.suffix));
                }
            }
            Mti::PRODUCER_CONSUMER_EVENT_REPORT => match ClockMessage::decode(heard.suffix) {
                Some(message) => self.on_clock_message(now, bus, heard.from, message, false),
                None => bump(&mut bus.stats.reserved_ignored),
            },
            Mti::PRODUCER_IDENTIFIED_VALID => {
                if let Some(message) = ClockMessage::decode(heard.suffix) {
                    self.on_clock_message(now, bus, heard.from, message, true);
                }
            }
            _ => {}
        }
        self.after_change(now, bus);
    }

    /// A message of the clock; `identified`: a Producer Identified Valid (the generator's
    /// state, in its synchronization sequence), else a report.
    fn on_clock_message(
        &mut self,
        now: Instant,
        bus: &mut Bus<'_>,
        from: NodeId,
        message: ClockMessage,
        identified: bool,
    ) {
        let from_generator = message.is_report() || identified || message == ClockMessage::DateRollover;
        if from_generator {
            if self.generator.is_some_and(|g| g != from) {
                bump(&mut bus.stats.other_generators);
            }
            self.generator = Some(from);
            self.last_heard = Some(now);
        }
        let model = &mut self.model;
        let before = model.ms(now);
        match message {
            ClockMessage::ReportTime { hour, minute } if identified => {
                // The generator's minute, its second unknown (TN §2.6): the nearest moment
                // of that minute to the time computed here.
                let start = model.with_time_of_day(now, hour, minute) - model.entry_ms();
                model.set_ms(now, before.clamp(start, start + MINUTE_MS - 1));
                self.set_told(now, bus, before, from);
                self.identified_minute = Some(self.model.minute(now));
                self.query_due = None;
                if !core::mem::replace(&mut self.synchronized, true) {
                    bus.tell(ClockChange::Synchronized, Some(from));
                }
            }
            ClockMessage::ReportTime { hour, minute } => {
                let announced = self.identified_minute.take();
                let next = model.with_time_of_day(now, hour, minute).div_euclid(MINUTE_MS);
                let announcement = announced.is_some_and(|m| (next - m).abs() == 1 || (next - m).abs() == 1439);
                if !model.running && announcement {
                    return;
                }
                let ms = match self.midnight.take() {
                    Some(midnight) if model.rate.quarters() < 0 => {
                        midnight - DAY_MS + (i64::from(hour) * 60 + i64::from(minute)) * MINUTE_MS + model.entry_ms()
                    }
                    Some(midnight) => midnight + (i64::from(hour) * 60 + i64::from(minute)) * MINUTE_MS,
                    None => model.with_time_of_day(now, hour, minute),
                };
                // A report of the minute this consumer is well into is late, or stale (OpenMRN's
                // generator reports the minute it is in when an alarm set before a Set Time
                // fires): the time computed here stands. Within the network's delay of the
                // minute's start (half a real second, at most half a minute) it is the start.
                let into = if model.rate.quarters() < 0 { ms - before } else { before - ms };
                let delay = (i64::from(model.rate.quarters().unsigned_abs()) * REPORT_DELAY_MS / 4).min(MINUTE_MS / 2);
                if into > delay && into < MINUTE_MS {
                    return;
                }
                model.set_ms(now, ms);
                // A report more than a minute away from the time computed here: out of step.
                if (ms - before).abs() > MINUTE_MS + 1000 {
                    self.set_told(now, bus, before, from);
                    if self.synchronized && self.query_due.is_none() {
                        self.query_due = Some(now + self.config.step_check);
                    }
                }
            }
            ClockMessage::ReportDate { month, day } => match model.with_date(now, month, day) {
                Some(ms) => {
                    model.set_ms(now, ms);
                    self.set_told(now, bus, before, from);
                }
                None => bump(&mut bus.stats.reserved_ignored),
            },
            ClockMessage::ReportYear(year) => {
                model.set_ms(now, model.with_year(now, year));
                self.set_told(now, bus, before, from);
            }
            ClockMessage::ReportRate(rate) if rate != model.rate => {
                model.set_rate(now, rate);
                bus.tell(ClockChange::Rate(rate), Some(from));
            }
            // Start and stop are not echoed by the generator: its command is the change (and
            // the sequence's first message confirms it).
            ClockMessage::Start | ClockMessage::Stop => {
                let running = message == ClockMessage::Start;
                if identified {
                    self.query_due = None;
                }
                if running != model.running {
                    model.set_running(now, running);
                    bus.tell(if running { ClockChange::Started } else { ClockChange::Stopped }, Some(from));
                }
            }
            ClockMessage::DateRollover => {
                let ms = model.ms(now);
                self.midnight = Some((ms + DAY_MS / 2).div_euclid(DAY_MS) * DAY_MS);
            }
            // Another node asked: its answer serves this consumer too (TN §2.6.4).
            ClockMessage::Query => self.query_due = None,
            // The generator echoes what it makes of a set command.
            _ => {}
        }
    }

    /// The time was set from `before`: tell the application when it moved.
    fn set_told(&mut self, now: Instant, bus: &mut Bus<'_>, before: i64, from: NodeId) {
        if self.model.ms(now) != before {
            self.minute = self.model.minute(now);
            bus.tell(ClockChange::Set(self.model.time(now)), Some(from));
        }
    }

    pub(crate) fn on_timeout(&mut self, now: Instant, bus: &mut Bus<'_>) {
        self.model.touch(now);
        if self.query_due.is_some_and(|due| due <= now) {
            self.query(bus);
        }
        let silent = self.last_heard.is_some_and(|t| now.saturating_duration_since(t) >= self.config.resync_after);
        if self.model.running && silent {
            self.last_heard = Some(now);
            self.query(bus);
        }
        self.after_change(now, bus);
    }

    /// Tells the application of a minute begun, and sets the next timer.
    fn after_change(&mut self, now: Instant, bus: &mut Bus<'_>) {
        let minute = self.model.minute(now);
        if minute != self.minute && self.model.running {
            self.minute = minute;
            bus.tell(ClockChange::Minute(self.model.time(now)), None);
        }
        self.tick_due = self.model.next_minute_at(now);
    }
}
