//! A clock's running state: the fast time at a real instant, the rate and whether it runs,
//! from which the fast time at any later instant follows without drift.

use openlcb_stream::{Duration, Instant};

use super::calendar::{ClockTime, DAY_MS, MINUTE_MS, clamp_to_calendar, days_from_civil, days_in_month};
use super::wire::Rate;

/// The fast time `base_ms` held at the real instant `anchor` and runs on from there at
/// `rate` while `running`. The anchor is the first instant the clock hears of (a node is
/// built before it knows the time).
#[derive(Debug, Clone, PartialEq, Eq)]
pub(crate) struct Model {
    base_ms: i64,
    anchor: Option<Instant>,
    pub(crate) rate: Rate,
    pub(crate) running: bool,
}

impl Model {
    pub(crate) fn new(start: ClockTime, rate: Rate, running: bool) -> Self {
        Model { base_ms: start.to_ms(), anchor: None, rate, running }
    }

    /// Fixes the anchor at `now` if the clock has not heard of a time yet.
    pub(crate) fn touch(&mut self, now: Instant) {
        self.anchor.get_or_insert(now);
    }

    /// The fast time at `now`, in milliseconds from 0000-01-01.
    pub(crate) fn ms(&self, now: Instant) -> i64 {
        match self.anchor {
            Some(anchor) if self.running => {
                let elapsed = i64::try_from(now.saturating_duration_since(anchor).as_micros()).unwrap_or(i64::MAX);
                let fast = elapsed.saturating_mul(i64::from(self.rate.quarters())).div_euclid(4000);
                self.base_ms.saturating_add(fast)
            }
            _ => self.base_ms,
        }
    }

    /// The moment at `now`.
    pub(crate) fn time(&self, now: Instant) -> ClockTime {
        ClockTime::from_ms(self.ms(now))
    }

    /// The fast minute at `now`, counted from 0000-01-01.
    pub(crate) fn minute(&self, now: Instant) -> i64 {
        self.ms(now).div_euclid(MINUTE_MS)
    }

    /// The fast time is `ms` at `now`.
    pub(crate) fn set_ms(&mut self, now: Instant, ms: i64) {
        self.base_ms = clamp_to_calendar(ms);
        self.anchor = Some(now);
    }

    /// Runs at `rate` from `now` on.
    pub(crate) fn set_rate(&mut self, now: Instant, rate: Rate) {
        self.set_ms(now, self.ms(now));
        self.rate = rate;
    }

    /// Runs or stands from `now` on.
    pub(crate) fn set_running(&mut self, now: Instant, running: bool) {
        self.set_ms(now, self.ms(now));
        self.running = running;
    }

    /// Where the clock stands in a minute it has just entered: its start running forwards,
    /// its last millisecond running backwards.
    pub(crate) fn entry_ms(&self) -> i64 {
        if self.rate.quarters() < 0 { MINUTE_MS - 1 } else { 0 }
    }

    /// The time at `now` with the time of day `hour:minute`, the day kept.
    pub(crate) fn with_time_of_day(&self, now: Instant, hour: u8, minute: u8) -> i64 {
        let day = self.ms(now).div_euclid(DAY_MS) * DAY_MS;
        day + (i64::from(hour) * 60 + i64::from(minute)) * MINUTE_MS + self.entry_ms()
    }

    /// The time at `now` on `month`/`day` of its year (the time of day kept), or `None` for
    /// a day the month lacks.
    pub(crate) fn with_date(&self, now: Instant, month: u8, day: u8) -> Option<i64> {
        let ms = self.ms(now);
        let year = ClockTime::from_ms(ms).year;
        (day >= 1 && day <= days_in_month(year, month))
            .then(|| days_from_civil(year, month, day) * DAY_MS + ms.rem_euclid(DAY_MS))
    }

    /// The time at `now` in `year` (29 February becomes the 28th in a common year).
    pub(crate) fn with_year(&self, now: Instant, year: u16) -> i64 {
        let ms = self.ms(now);
        let t = ClockTime::from_ms(ms);
        let day = t.day.min(days_in_month(year, t.month));
        days_from_civil(year.min(4095), t.month, day) * DAY_MS + ms.rem_euclid(DAY_MS)
    }

    /// The real instant, after `now`, at which the clock enters another minute (`None`
    /// while it stands).
    pub(crate) fn next_minute_at(&self, now: Instant) -> Option<Instant> {
        let anchor = self.anchor?;
        let quarters = i64::from(self.rate.quarters());
        if !self.running || quarters == 0 {
            return None;
        }
        let minute_start = self.minute(now) * MINUTE_MS;
        // The first real microsecond from the anchor whose fast time (rounded down, as
        // `ms` rounds) is in the next minute: forwards the minute's end, backwards the
        // millisecond before the minute's start.
        let micros = if quarters > 0 {
            let fast = (minute_start + MINUTE_MS - self.base_ms).max(1);
            fast.saturating_mul(4000).saturating_add(quarters - 1) / quarters
        } else {
            let fast = (self.base_ms - minute_start).max(0);
            fast.saturating_mul(4000) / -quarters + 1
        };
        Some(anchor + Duration::from_micros(u64::try_from(micros).unwrap_or(u64::MAX)))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn at(seconds: u64) -> Instant {
        Instant::from_micros(seconds * 1_000_000)
    }

    #[test]
    fn a_clock_at_four_times_enters_a_minute_every_fifteen_seconds() {
        let start = ClockTime::new(2023, 7, 22, 1, 0, 0).unwrap();
        let mut model = Model::new(start, Rate::from_quarters(16).unwrap(), true);
        model.touch(at(100));
        assert_eq!(model.next_minute_at(at(100)), Some(at(115)));
        assert_eq!(model.time(at(115)).minute, 1);
        assert_eq!(model.next_minute_at(at(115)), Some(at(130)));
        // Stopped, it holds its time.
        model.set_running(at(120), false);
        assert_eq!(model.time(at(500)), ClockTime::new(2023, 7, 22, 1, 1, 20).unwrap());
        assert_eq!(model.next_minute_at(at(500)), None);
    }

    #[test]
    fn a_clock_running_backwards_enters_the_minute_before() {
        let start = ClockTime::new(2023, 7, 22, 0, 0, 30).unwrap();
        let mut model = Model::new(start, Rate::from_quarters(-4).unwrap(), true);
        model.touch(at(0));
        let next = model.next_minute_at(at(0)).unwrap();
        let entered = model.time(next);
        assert_eq!((entered.day, entered.hour, entered.minute), (21, 23, 59));
        assert!(next.as_micros() > 30_000_000 && next.as_micros() <= 30_000_250, "{next:?}");
    }

    #[test]
    fn set_fields_keep_the_others() {
        let start = ClockTime::new(2024, 2, 29, 13, 45, 0).unwrap();
        let model = Model::new(start, Rate::REAL_TIME, false);
        let now = at(0);
        assert_eq!(ClockTime::from_ms(model.with_year(now, 2023)), ClockTime::new(2023, 2, 28, 13, 45, 0).unwrap());
        assert_eq!(model.with_date(now, 4, 31), None);
        let july = model.with_date(now, 7, 4).unwrap();
        assert_eq!(ClockTime::from_ms(july), ClockTime::new(2024, 7, 4, 13, 45, 0).unwrap());
        assert_eq!(
            ClockTime::from_ms(model.with_time_of_day(now, 6, 0)),
            ClockTime::new(2024, 2, 29, 6, 0, 0).unwrap()
        );
    }
}
