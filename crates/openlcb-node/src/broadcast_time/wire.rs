//! The clock's Event IDs (Broadcast Time Standard §4): the clock's ID in the upper six bytes,
//! what the event says in the lower two.

use core::fmt;
use core::str::FromStr;

use openlcb_stream::{EventId, NodeId};

/// A clock: the upper six bytes of its Event IDs (one of the four well-known clocks, or a
/// unique ID of the generator's maker or of the person who set it up).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct ClockId(pub NodeId);

impl ClockId {
    /// The Default Fast Clock, `01.01.00.00.01.00`.
    pub const DEFAULT_FAST: ClockId = ClockId(NodeId::from_bytes([1, 1, 0, 0, 1, 0]));
    /// The Default Real-time Clock, `01.01.00.00.01.01`.
    pub const DEFAULT_REALTIME: ClockId = ClockId(NodeId::from_bytes([1, 1, 0, 0, 1, 1]));
    /// Alternate Clock 1, `01.01.00.00.01.02`.
    pub const ALTERNATE_1: ClockId = ClockId(NodeId::from_bytes([1, 1, 0, 0, 1, 2]));
    /// Alternate Clock 2, `01.01.00.00.01.03`.
    pub const ALTERNATE_2: ClockId = ClockId(NodeId::from_bytes([1, 1, 0, 0, 1, 3]));

    /// The well-known clocks with the names `lcc-stream clock --clock` takes.
    pub const WELL_KNOWN: [(ClockId, &'static str); 4] = [
        (ClockId::DEFAULT_FAST, "default-fast"),
        (ClockId::DEFAULT_REALTIME, "default-realtime"),
        (ClockId::ALTERNATE_1, "alternate-1"),
        (ClockId::ALTERNATE_2, "alternate-2"),
    ];

    /// The Event ID of this clock with `suffix` as its lower two bytes.
    pub const fn event(self, suffix: u16) -> EventId {
        EventId(self.0.as_raw() << 16 | suffix as u64)
    }

    /// The first Event ID of the clock's range (all 65 536 of them are the clock's).
    pub const fn base(self) -> EventId {
        self.event(0)
    }

    /// The clock an Event ID belongs to and its lower two bytes (`None` for upper bytes of
    /// zero, which name no clock).
    pub fn of(event: EventId) -> Option<(ClockId, u16)> {
        Some((ClockId(NodeId::new(event.0 >> 16)?), event.0 as u16))
    }
}

impl fmt::Display for ClockId {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match ClockId::WELL_KNOWN.iter().find(|(id, _)| id == self) {
            Some((_, name)) => f.write_str(name),
            None => write!(f, "{}", self.0),
        }
    }
}

impl FromStr for ClockId {
    type Err = openlcb_stream::ParseNodeIdError;

    /// A well-known clock's name (`default-fast`, ...) or six dotted hex bytes.
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        match ClockId::WELL_KNOWN.iter().find(|(_, name)| name.eq_ignore_ascii_case(s)) {
            Some((id, _)) => Ok(*id),
            None => s.parse().map(ClockId),
        }
    }
}

/// A clock's rate: how many fast seconds pass in a real one, in quarters (the standard's
/// 12-bit signed fixed point `rrrrrrrrrr.rr`, -512.00 to 511.75; negative runs backwards).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct Rate(i16);

impl Rate {
    /// Real time.
    pub const REAL_TIME: Rate = Rate(4);
    /// The slowest rate backwards, -512.00.
    pub const MIN: Rate = Rate(-2048);
    /// The fastest rate, 511.75.
    pub const MAX: Rate = Rate(2047);

    /// The rate of `quarters` quarters (4: real time), or `None` outside -2048 to 2047.
    pub const fn from_quarters(quarters: i16) -> Option<Rate> {
        if quarters >= Self::MIN.0 && quarters <= Self::MAX.0 { Some(Rate(quarters)) } else { None }
    }

    /// The rate in quarters.
    pub const fn quarters(self) -> i16 {
        self.0
    }

    /// The rate of a Report or Set Rate event's twelve low bits.
    const fn from_bits(bits: u16) -> Rate {
        let bits = (bits & 0x0FFF) as i16;
        Rate(if bits & 0x0800 != 0 { bits - 0x1000 } else { bits })
    }

    /// The twelve low bits of its Report Rate event.
    const fn bits(self) -> u16 {
        self.0 as u16 & 0x0FFF
    }
}

impl fmt::Display for Rate {
    /// As a number: `4`, `0.25`, `-1.5`, `511.75`.
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let sign = if self.0 < 0 { "-" } else { "" };
        let quarters = self.0.unsigned_abs();
        let fraction = match quarters % 4 {
            1 => ".25",
            2 => ".5",
            3 => ".75",
            _ => "",
        };
        write!(f, "{sign}{}{fraction}", quarters / 4)
    }
}

/// A rate that is not a multiple of 0.25 from -512 to 511.75.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
#[error("a rate is a multiple of 0.25 from -512 to 511.75")]
pub struct RateError;

impl FromStr for Rate {
    type Err = RateError;

    /// `4`, `0.25`, `-1.5`, `511.75`: a number in quarters.
    fn from_str(s: &str) -> Result<Self, RateError> {
        let (negative, digits) = match s.strip_prefix('-') {
            Some(rest) => (true, rest),
            None => (false, s.strip_prefix('+').unwrap_or(s)),
        };
        let (whole, fraction) = digits.split_once('.').unwrap_or((digits, ""));
        if whole.is_empty() || !whole.bytes().all(|b| b.is_ascii_digit()) {
            return Err(RateError);
        }
        let whole: i32 = whole.parse().map_err(|_| RateError)?;
        let fraction = fraction.trim_end_matches('0');
        let quarter = match fraction {
            "" => 0,
            "25" => 1,
            "5" => 2,
            "75" => 3,
            _ => return Err(RateError),
        };
        let quarters = whole.checked_mul(4).and_then(|q| q.checked_add(quarter)).ok_or(RateError)?;
        let quarters = if negative { -quarters } else { quarters };
        i16::try_from(quarters).ok().and_then(Rate::from_quarters).ok_or(RateError)
    }
}

/// What one of a clock's events says (its lower two bytes, Broadcast Time Standard §4).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum ClockMessage {
    /// Report Time: the clock's time of day.
    ReportTime {
        /// 0 to 23.
        hour: u8,
        /// 0 to 59.
        minute: u8,
    },
    /// Report Date.
    ReportDate {
        /// 1 to 12.
        month: u8,
        /// 1 to 31.
        day: u8,
    },
    /// Report Year, 0 to 4095.
    ReportYear(u16),
    /// Report Rate.
    ReportRate(Rate),
    /// Set Time.
    SetTime {
        /// 0 to 23.
        hour: u8,
        /// 0 to 59.
        minute: u8,
    },
    /// Set Date.
    SetDate {
        /// 1 to 12.
        month: u8,
        /// 1 to 31.
        day: u8,
    },
    /// Set Year, 0 to 4095.
    SetYear(u16),
    /// Set Rate.
    SetRate(Rate),
    /// Query: the generator answers with its synchronization sequence.
    Query,
    /// Stop the clock.
    Stop,
    /// Start the clock.
    Start,
    /// Date Rollover: the time is about to pass midnight.
    DateRollover,
}

/// The flag that turns a report into the matching set command.
const SET: u16 = 0x8000;

impl ClockMessage {
    /// What `suffix` says, or `None` for one the standard reserves (§4.12: ignored when
    /// received), such as hour 24, minute 60 or month 13.
    pub fn decode(suffix: u16) -> Option<Self> {
        let [high, low] = suffix.to_be_bytes();
        let set = suffix & SET != 0;
        let message = match suffix {
            0xF000 => ClockMessage::Query,
            0xF001 => ClockMessage::Stop,
            0xF002 => ClockMessage::Start,
            0xF003 => ClockMessage::DateRollover,
            _ => match (high & 0x70) >> 4 {
                0 | 1 if high & 0x7F < 24 && low < 60 => {
                    let (hour, minute) = (high & 0x7F, low);
                    if set { ClockMessage::SetTime { hour, minute } } else { ClockMessage::ReportTime { hour, minute } }
                }
                2 if (1..=12).contains(&(high & 0x0F)) && (1..=31).contains(&low) => {
                    let (month, day) = (high & 0x0F, low);
                    if set { ClockMessage::SetDate { month, day } } else { ClockMessage::ReportDate { month, day } }
                }
                3 => {
                    let year = suffix & 0x0FFF;
                    if set { ClockMessage::SetYear(year) } else { ClockMessage::ReportYear(year) }
                }
                4 => {
                    let rate = Rate::from_bits(suffix);
                    if set { ClockMessage::SetRate(rate) } else { ClockMessage::ReportRate(rate) }
                }
                _ => return None,
            },
        };
        Some(message)
    }

    /// The lower two bytes of its Event ID.
    pub fn suffix(self) -> u16 {
        let report = |m: ClockMessage| m.suffix();
        match self {
            ClockMessage::ReportTime { hour, minute } => u16::from_be_bytes([hour, minute]),
            ClockMessage::ReportDate { month, day } => u16::from_be_bytes([0x20 | month, day]),
            ClockMessage::ReportYear(year) => 0x3000 | (year & 0x0FFF),
            ClockMessage::ReportRate(rate) => 0x4000 | rate.bits(),
            ClockMessage::SetTime { hour, minute } => SET | report(ClockMessage::ReportTime { hour, minute }),
            ClockMessage::SetDate { month, day } => SET | report(ClockMessage::ReportDate { month, day }),
            ClockMessage::SetYear(year) => SET | report(ClockMessage::ReportYear(year)),
            ClockMessage::SetRate(rate) => SET | report(ClockMessage::ReportRate(rate)),
            ClockMessage::Query => 0xF000,
            ClockMessage::Stop => 0xF001,
            ClockMessage::Start => 0xF002,
            ClockMessage::DateRollover => 0xF003,
        }
    }

    /// A report of the clock's state (what a generator produces), not a command to it.
    pub fn is_report(self) -> bool {
        matches!(
            self,
            ClockMessage::ReportTime { .. }
                | ClockMessage::ReportDate { .. }
                | ClockMessage::ReportYear(_)
                | ClockMessage::ReportRate(_)
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_suffix_decodes_to_what_it_encodes_or_is_reserved() {
        let mut defined = 0;
        for suffix in 0..=u16::MAX {
            if let Some(message) = ClockMessage::decode(suffix) {
                defined += 1;
                assert_eq!(message.suffix(), suffix, "{message:?}");
            }
        }
        // 24*60 times, 12*31 dates, 4096 years, 4096 rates, each twice (report and set),
        // and query, stop, start, rollover.
        assert_eq!(defined, 2 * (24 * 60 + 12 * 31 + 4096 + 4096) + 4);
    }

    #[test]
    fn the_standards_examples() {
        assert_eq!(ClockMessage::decode(0x0117), Some(ClockMessage::ReportTime { hour: 1, minute: 23 }));
        assert_eq!(ClockMessage::decode(0x9417), Some(ClockMessage::SetTime { hour: 20, minute: 23 }));
        assert_eq!(ClockMessage::decode(0x2716), Some(ClockMessage::ReportDate { month: 7, day: 22 }));
        assert_eq!(ClockMessage::decode(0x37E7), Some(ClockMessage::ReportYear(2023)));
        // TN §2.4.4: 0x4800 is -512.00, 0x4FFF is -0.25.
        assert_eq!(ClockMessage::decode(0x4800), Some(ClockMessage::ReportRate(Rate::MIN)));
        assert_eq!(ClockMessage::decode(0x4FFF), Some(ClockMessage::ReportRate(Rate(-1))));
        assert_eq!(ClockMessage::decode(0xC010), Some(ClockMessage::SetRate(Rate(16))));
        for reserved in [0x1800, 0x003C, 0x2D01, 0x2700, 0x5000, 0xF004, 0xE000] {
            assert_eq!(ClockMessage::decode(reserved), None, "{reserved:04X}");
        }
    }

    #[test]
    fn rates_parse_and_print_in_quarters() {
        for (text, quarters) in [("4", 16), ("0.25", 1), ("-1.5", -6), ("511.75", 2047), ("-512", -2048), ("1.50", 6)] {
            let rate: Rate = text.parse().unwrap();
            assert_eq!(rate.quarters(), quarters, "{text}");
        }
        assert_eq!(Rate(-6).to_string(), "-1.5");
        assert_eq!(Rate(2047).to_string(), "511.75");
        for bad in ["512", "0.3", "", "-", "x", "1.2.3", "-513"] {
            assert_eq!(bad.parse::<Rate>(), Err(RateError), "{bad}");
        }
    }

    #[test]
    fn clocks_are_named_or_dotted() {
        assert_eq!("default-fast".parse::<ClockId>(), Ok(ClockId::DEFAULT_FAST));
        assert_eq!(ClockId::ALTERNATE_2.to_string(), "alternate-2");
        let custom: ClockId = "05.01.01.01.22.00".parse().unwrap();
        assert_eq!(custom.event(0xF000), EventId(0x0501_0101_2200_F000));
        assert_eq!(ClockId::of(EventId(0x0101_0000_0100_0117)), Some((ClockId::DEFAULT_FAST, 0x0117)));
    }
}
