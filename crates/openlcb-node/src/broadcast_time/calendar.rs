//! The clocks' calendar: a fast time as milliseconds from 0000-01-01 00:00 in the proleptic
//! Gregorian calendar (the years Broadcast Time can name, 0 to 4095), and its conversion to a
//! date and a time of day.

/// Milliseconds in a fast minute and a fast day.
pub(crate) const MINUTE_MS: i64 = 60_000;
pub(crate) const DAY_MS: i64 = 24 * 60 * MINUTE_MS;

/// Days from 0000-01-01 to 0000-03-01 in the March-based count below.
const MARCH_OFFSET: i64 = 60;

/// A moment of a clock: its date and time of day, to the second.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub struct ClockTime {
    /// The year (0 to 4095 on the wire).
    pub year: u16,
    /// The month, 1 to 12.
    pub month: u8,
    /// The day of the month, from 1.
    pub day: u8,
    /// The hour, 0 to 23.
    pub hour: u8,
    /// The minute, 0 to 59.
    pub minute: u8,
    /// The second, 0 to 59.
    pub second: u8,
}

impl ClockTime {
    /// The moment, or `None` when a field is out of its range (a day the month lacks, an
    /// hour past 23, a year past 4095).
    pub fn new(year: u16, month: u8, day: u8, hour: u8, minute: u8, second: u8) -> Option<Self> {
        let valid = year <= 4095
            && (1..=12).contains(&month)
            && day >= 1
            && day <= days_in_month(year, month)
            && hour < 24
            && minute < 60
            && second < 60;
        valid.then_some(ClockTime { year, month, day, hour, minute, second })
    }

    /// The moment `seconds` after 1970-01-01 00:00 (the Unix epoch, as a host's clock
    /// counts; clamped to years 0 to 4095).
    pub fn from_unix_seconds(seconds: i64) -> Self {
        Self::from_ms(days_from_civil(1970, 1, 1) * DAY_MS + seconds.saturating_mul(1000))
    }

    /// The moment `millis` fast milliseconds later (earlier when negative), to the second,
    /// within years 0 to 4095.
    pub fn advanced(self, millis: i64) -> Self {
        Self::from_ms(self.to_ms().saturating_add(millis))
    }

    /// The moment `ms` milliseconds after 0000-01-01 00:00 (clamped to years 0 to 4095).
    pub(crate) fn from_ms(ms: i64) -> Self {
        let ms = clamp_to_calendar(ms);
        let (year, month, day) = civil_from_days(ms.div_euclid(DAY_MS));
        let of_day = ms.rem_euclid(DAY_MS) / 1000;
        ClockTime {
            year,
            month,
            day,
            hour: (of_day / 3600) as u8,
            minute: (of_day / 60 % 60) as u8,
            second: (of_day % 60) as u8,
        }
    }

    /// Milliseconds after 0000-01-01 00:00.
    pub(crate) fn to_ms(self) -> i64 {
        let days = days_from_civil(self.year, self.month, self.day);
        let seconds = i64::from(self.hour) * 3600 + i64::from(self.minute) * 60 + i64::from(self.second);
        days * DAY_MS + seconds * 1000
    }
}

impl core::fmt::Display for ClockTime {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        write!(
            f,
            "{:04}-{:02}-{:02} {:02}:{:02}:{:02}",
            self.year, self.month, self.day, self.hour, self.minute, self.second
        )
    }
}

/// `ms` within the years the clocks can name, 0 to 4095.
pub(crate) fn clamp_to_calendar(ms: i64) -> i64 {
    ms.clamp(0, (days_from_civil(4095, 12, 31) + 1) * DAY_MS - 1)
}

/// A leap year of the Gregorian calendar (year 0 is one).
pub(crate) fn is_leap(year: u16) -> bool {
    year.is_multiple_of(4) && (!year.is_multiple_of(100) || year.is_multiple_of(400))
}

/// Days in `month` (1 to 12) of `year`; 0 for a month out of range.
pub(crate) fn days_in_month(year: u16, month: u8) -> u8 {
    match month {
        1 | 3 | 5 | 7 | 8 | 10 | 12 => 31,
        4 | 6 | 9 | 11 => 30,
        2 if is_leap(year) => 29,
        2 => 28,
        _ => 0,
    }
}

/// Days from 0000-01-01 to the date, counted in 400-year eras of 146 097 days whose years
/// start in March (so that the leap day ends a year).
pub(crate) fn days_from_civil(year: u16, month: u8, day: u8) -> i64 {
    let (month, day) = (i64::from(month), i64::from(day));
    let year = i64::from(year) - i64::from(month <= 2);
    let era = year.div_euclid(400);
    let year_of_era = year - era * 400;
    let day_of_year = (153 * ((month + 9) % 12) + 2) / 5 + day - 1;
    let day_of_era = year_of_era * 365 + year_of_era / 4 - year_of_era / 100 + day_of_year;
    era * 146_097 + day_of_era + MARCH_OFFSET
}

/// The date `days` after 0000-01-01 (the inverse of [`days_from_civil`]).
fn civil_from_days(days: i64) -> (u16, u8, u8) {
    let days = days - MARCH_OFFSET;
    let era = days.div_euclid(146_097);
    let day_of_era = days - era * 146_097;
    let year_of_era = (day_of_era - day_of_era / 1460 + day_of_era / 36_524 - day_of_era / 146_096) / 365;
    let day_of_year = day_of_era - (365 * year_of_era + year_of_era / 4 - year_of_era / 100);
    let march_month = (5 * day_of_year + 2) / 153;
    let day = day_of_year - (153 * march_month + 2) / 5 + 1;
    let month = if march_month < 10 { march_month + 3 } else { march_month - 9 };
    let year = year_of_era + era * 400 + i64::from(month <= 2);
    (year.clamp(0, 4095) as u16, month as u8, day as u8)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn day_counts_match_the_known_ordinals() {
        assert_eq!(days_from_civil(0, 1, 1), 0);
        assert_eq!(days_from_civil(0, 3, 1), 60); // year 0 is a leap year
        // 1970-01-01 is day 719 163 counted from 0001-01-01 as day 1; year 0 has 366 days.
        assert_eq!(days_from_civil(1970, 1, 1), 719_163 + 366 - 1);
        for days in [0, 59, 60, 365, 366, 719_528, 1_000_000, days_from_civil(4095, 12, 31)] {
            let (y, m, d) = civil_from_days(days);
            assert_eq!(days_from_civil(y, m, d), days, "{y}-{m}-{d}");
        }
    }

    #[test]
    fn moments_round_trip_and_refuse_days_a_month_lacks() {
        let t = ClockTime::new(1956, 7, 4, 6, 30, 15).unwrap();
        assert_eq!(ClockTime::from_ms(t.to_ms()), t);
        assert_eq!(t.to_string(), "1956-07-04 06:30:15");
        assert!(ClockTime::new(2023, 2, 29, 0, 0, 0).is_none());
        assert!(ClockTime::new(2024, 2, 29, 0, 0, 0).is_some());
        assert!(ClockTime::new(1900, 2, 29, 0, 0, 0).is_none());
        assert!(ClockTime::new(2000, 2, 29, 0, 0, 0).is_some());
        assert!(ClockTime::new(2023, 7, 22, 24, 0, 0).is_none());
        let new_year = ClockTime::new(2023, 12, 31, 23, 59, 59).unwrap().to_ms() + 1000;
        assert_eq!(ClockTime::from_ms(new_year), ClockTime::new(2024, 1, 1, 0, 0, 0).unwrap());
        assert_eq!(t.advanced(-(6 * 3600 + 31 * 60) * 1000), ClockTime::new(1956, 7, 3, 23, 59, 15).unwrap());
        // 2026-12-04 21:33:11 UTC.
        assert_eq!(ClockTime::from_unix_seconds(1_796_419_991), ClockTime::new(2026, 12, 4, 21, 33, 11).unwrap());
    }
}
