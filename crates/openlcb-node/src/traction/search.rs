//! Train Search (Train Search Standard): the search Event IDs `09.00.99.FF.qq.qq.qq.rr`, six
//! nibbles of query and a flag byte, and the matching algorithm of its §6.3.

use alloc::string::String;

use openlcb_stream::EventId;

/// The upper four bytes of every Train Search Event ID (§5.1).
pub const SEARCH_PREFIX: u32 = 0x0900_99FF;

/// Flag: allocate a new train node when none matches (§5.2 Table 3).
pub const SEARCH_ALLOCATE: u8 = 0x80;
/// Flag: exact match only.
pub const SEARCH_EXACT: u8 = 0x40;
/// Flag: match only the address, not the name.
pub const SEARCH_ADDRESS_ONLY: u8 = 0x20;

/// The track protocol of a train, as Train Search names it (§5.2 Table 4).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
#[non_exhaustive]
pub enum TrainProtocol {
    /// DCC; `long`: a 14-bit (long) address, else a 7-bit (short) one.
    Dcc {
        /// A long address.
        long: bool,
    },
    /// Märklin-Motorola.
    MarklinMotorola,
    /// MFX / M4.
    Mfx,
    /// A native OpenLCB train.
    Native,
}

/// The track protocol a search asks for.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
#[non_exhaustive]
pub enum SearchProtocol {
    /// Any (the default).
    Any,
    /// Native OpenLCB trains.
    Native,
    /// MFX / M4.
    Mfx,
    /// Märklin-Motorola (any version).
    MarklinMotorola,
    /// DCC; `long`: the long address is asked for.
    Dcc {
        /// Force a 14-bit address.
        long: bool,
    },
}

/// What a train is known by in a search: its address, protocol and name.
#[derive(Debug, Clone, PartialEq, Eq)]
#[non_exhaustive]
pub struct TrainIdentity {
    /// The address within its protocol (a DCC address, 1 to 10239).
    pub address: u32,
    /// The track protocol.
    pub protocol: TrainProtocol,
    /// The user's name for the train (searched by its digits).
    pub name: String,
}

impl TrainIdentity {
    /// A DCC train at `address`: long from 128 on (the usual split), short below.
    pub fn dcc(address: u32) -> Self {
        TrainIdentity { address, protocol: TrainProtocol::Dcc { long: address >= 128 }, name: String::new() }
    }
}

/// A Train Search query: up to six nibbles and the flags.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct SearchQuery {
    nibbles: [u8; 6],
    flags: u8,
    protocol: SearchProtocol,
}

/// Why an Event ID is no usable search.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SearchError {
    /// Not in the Train Search range.
    NotSearch,
    /// A nibble 0xA-0xE or a reserved track protocol: "check upon receipt", it matches nothing.
    Reserved,
}

impl SearchQuery {
    /// Reads a search Event ID.
    pub fn parse(event: EventId) -> Result<Self, SearchError> {
        let raw = event.as_raw();
        if (raw >> 32) as u32 != SEARCH_PREFIX {
            return Err(SearchError::NotSearch);
        }
        let mut nibbles = [0u8; 6];
        for (i, nibble) in (0u32..).zip(nibbles.iter_mut()) {
            *nibble = ((raw >> (28 - 4 * i)) & 0xF) as u8;
            if (0xA..=0xE).contains(nibble) {
                return Err(SearchError::Reserved);
            }
        }
        let flags = (raw & 0xFF) as u8;
        let protocol = match (flags >> 3) & 0x3 {
            0b00 if flags & 0x04 != 0 => SearchProtocol::MarklinMotorola,
            0b00 => match flags & 0x3 {
                0b00 => SearchProtocol::Any,
                0b01 => SearchProtocol::Native,
                0b10 => SearchProtocol::Mfx,
                _ => return Err(SearchError::Reserved),
            },
            0b01 => SearchProtocol::Dcc { long: flags & 0x04 != 0 },
            _ => return Err(SearchError::Reserved),
        };
        Ok(SearchQuery { nibbles, flags, protocol })
    }

    /// The search for `address` with `flags` (the query's digits right-aligned, padded with
    /// 0xF), `None` past six digits.
    pub fn event_for(address: u32, flags: u8) -> Option<EventId> {
        if address > 999_999 {
            return None;
        }
        let mut query: u32 = 0xFF_FFFF;
        let mut rest = address;
        let mut shift = 0;
        loop {
            query = (query & !(0xF << shift)) | ((rest % 10) << shift);
            rest /= 10;
            shift += 4;
            if rest == 0 {
                break;
            }
        }
        Some(EventId(u64::from(SEARCH_PREFIX) << 32 | u64::from(query) << 8 | u64::from(flags)))
    }

    /// The flag byte.
    pub fn flags(&self) -> u8 {
        self.flags
    }

    /// The track protocol asked for.
    pub fn protocol(&self) -> SearchProtocol {
        self.protocol
    }

    /// The Allocate flag.
    pub fn allocate(&self) -> bool {
        self.flags & SEARCH_ALLOCATE != 0
    }

    /// The query's one number, when it holds exactly one run of digits.
    pub fn address(&self) -> Option<u32> {
        let mut runs = self.runs();
        let run = runs.next()?;
        if runs.next().is_some() {
            return None;
        }
        Some(run.iter().fold(0, |v, d| v * 10 + u32::from(*d)))
    }

    /// The maximal runs of digits.
    fn runs(&self) -> impl Iterator<Item = &[u8]> + '_ {
        self.nibbles.split(|n| *n == 0xF).filter(|run| !run.is_empty())
    }

    /// Whether `train` matches (§6.3).
    pub fn matches(&self, train: &TrainIdentity) -> bool {
        let protocol = matches!(
            (self.protocol, train.protocol),
            (SearchProtocol::Any, _)
                | (SearchProtocol::Native, TrainProtocol::Native)
                | (SearchProtocol::Mfx, TrainProtocol::Mfx)
                | (SearchProtocol::MarklinMotorola, TrainProtocol::MarklinMotorola)
                | (SearchProtocol::Dcc { .. }, TrainProtocol::Dcc { .. })
        );
        protocol && (self.matches_address(train) || (self.flags & SEARCH_ADDRESS_ONLY == 0 && self.matches_name(train)))
    }

    fn matches_address(&self, train: &TrainIdentity) -> bool {
        let Some(value) = self.address() else { return false };
        let long_asked = matches!(self.protocol, SearchProtocol::Dcc { long: true });
        let space = match train.protocol {
            TrainProtocol::Dcc { long } => value >= 128 || long_asked == long || (!long_asked && !self.allocate()),
            _ => true,
        };
        if !space {
            return false;
        }
        if self.flags & SEARCH_EXACT != 0 {
            return value == train.address;
        }
        let run = self.runs().next().unwrap_or_default();
        is_decimal_prefix(run, train.address)
    }

    fn matches_name(&self, train: &TrainIdentity) -> bool {
        let mut any = false;
        for run in self.runs() {
            any = true;
            if !name_has(&train.name, run, self.flags & SEARCH_EXACT != 0) {
                return false;
            }
        }
        any
    }
}

/// Whether the digits `run` begin the decimal representation of `value`.
fn is_decimal_prefix(run: &[u8], value: u32) -> bool {
    let count = value.checked_ilog10().unwrap_or(0) + 1;
    if run.len() > count as usize {
        return false;
    }
    run.iter().enumerate().all(|(i, digit)| {
        let power = 10u32.checked_pow(count - 1 - i as u32).unwrap_or(1);
        (value / power % 10) as u8 == *digit
    })
}

/// §6.3: a run of digits matches the name when, from a position with no digit just before
/// it, the name's digits (others skipped) begin with the run; exact: no digit follows.
fn name_has(name: &str, run: &[u8], exact: bool) -> bool {
    let bytes = name.as_bytes();
    (0..bytes.len()).any(|p| {
        if p > 0 && bytes.get(p - 1).is_some_and(u8::is_ascii_digit) {
            return false;
        }
        let mut wanted = run.iter();
        let mut next = wanted.next();
        let mut at = p;
        while let (Some(digit), Some(byte)) = (next, bytes.get(at)) {
            if byte.is_ascii_digit() {
                if byte - b'0' != *digit {
                    return false;
                }
                next = wanted.next();
            }
            at += 1;
        }
        next.is_none() && (!exact || !bytes.get(at).is_some_and(u8::is_ascii_digit))
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn q(raw: u64) -> Result<SearchQuery, SearchError> {
        SearchQuery::parse(EventId(raw))
    }

    #[test]
    fn olcbchecker_searches() {
        let twelve = TrainIdentity::dcc(12);
        let three = TrainIdentity::dcc(3);
        // ts10: "12" left-aligned, exact, address only: twelve only.
        assert!(q(0x090099FF_12FFFF60).unwrap().matches(&twelve));
        assert!(!q(0x090099FF_12FFFF60).unwrap().matches(&three));
        let allocate = q(0x090099FF_FFFF12E0).unwrap();
        assert!(allocate.allocate() && allocate.matches(&twelve) && !allocate.matches(&three));
        assert_eq!(allocate.address(), Some(12));
        // ts20: a prefix.
        assert!(q(0x090099FF_FFFFF120).unwrap().matches(&TrainIdentity::dcc(123)));
        assert!(!q(0x090099FF_FFFFF160).unwrap().matches(&TrainIdentity::dcc(123)));
        // ts30, ts40: reserved nibble and track protocols.
        assert_eq!(q(0x090099FF_FFFFFCE0), Err(SearchError::Reserved));
        for flags in [0xF0u64, 0xF8, 0xE3] {
            assert_eq!(q(0x090099FF_FFFF1200 | flags), Err(SearchError::Reserved));
        }
        assert_eq!(q(0x0101_0000_0000_0303), Err(SearchError::NotSearch));
    }

    #[test]
    fn dcc_address_spaces() {
        let short = TrainIdentity::dcc(3);
        let long3 = TrainIdentity { address: 3, protocol: TrainProtocol::Dcc { long: true }, name: String::new() };
        let long_query = q(SearchQuery::event_for(3, 0x40 | 0x08 | 0x04).unwrap().0).unwrap();
        assert!(long_query.matches(&long3) && !long_query.matches(&short));
        // A plain search finds both; a plain allocate only the short one.
        let plain = q(SearchQuery::event_for(3, 0x40).unwrap().0).unwrap();
        assert!(plain.matches(&long3) && plain.matches(&short));
        let alloc = q(SearchQuery::event_for(3, 0xC0).unwrap().0).unwrap();
        assert!(!alloc.matches(&long3) && alloc.matches(&short));
        assert!(
            !q(SearchQuery::event_for(3, 0x4A).unwrap().0)
                .unwrap()
                .matches(&TrainIdentity { protocol: TrainProtocol::Mfx, ..short.clone() })
        );
    }

    #[test]
    fn names() {
        let mut train = TrainIdentity::dcc(9);
        train.name = "BR 101 0-6-0".into();
        assert!(q(0x090099FF_101FFF00).unwrap().matches(&train));
        assert!(q(0x090099FF_10FFFF00).unwrap().matches(&train));
        assert!(!q(0x090099FF_10FFFF40).unwrap().matches(&train));
        assert!(q(0x090099FF_060FFF40).unwrap().matches(&train));
        assert!(!q(0x090099FF_01FFFF00).unwrap().matches(&train));
        assert!(!q(0x090099FF_101FFF20).unwrap().matches(&train));
    }

    #[test]
    fn event_for_pads_with_f() {
        assert_eq!(SearchQuery::event_for(12, 0xE0), Some(EventId(0x090099FF_FFFF12E0)));
        assert_eq!(SearchQuery::event_for(0, 0x00), Some(EventId(0x090099FF_FFFFF000)));
        assert_eq!(SearchQuery::event_for(1_000_000, 0), None);
    }
}
