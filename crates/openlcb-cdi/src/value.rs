//! Values of entries: decoding the bytes a node holds, checking and encoding what a person
//! types, and the text forms JMRI's backup uses.

use alloc::format;
use alloc::string::{String, ToString};
use alloc::vec;
use alloc::vec::Vec;

use crate::layout::{Entry, EntryKind};
use crate::tree::java_trim;

/// The value of one entry.
#[derive(Debug, Clone, PartialEq)]
#[non_exhaustive]
pub enum Value {
    /// An integer, as JMRI reads it: unsigned for 1 to 7 bytes, two's complement for 8.
    Int(i64),
    /// A floating-point number.
    Float(f64),
    /// An Event ID.
    EventId([u8; 8]),
    /// A string (up to its first NUL).
    String(String),
}

/// Why a value cannot be decoded, or cannot be stored in its entry.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum ValueError {
    /// The bytes given are not the entry's size.
    #[error("{got} bytes for an entry of {size}")]
    WrongLength {
        /// The entry's size.
        size: u32,
        /// The bytes given.
        got: usize,
    },
    /// The entry's size is not one its type can have (ints 1 to 8, floats 2, 4 or 8).
    #[error("a {kind} of {size} bytes cannot be read or written")]
    BadSize {
        /// The type.
        kind: &'static str,
        /// Its size.
        size: u32,
    },
    /// The text is not a value of the entry's type (nor a label of its map).
    #[error("`{text}` is not {expected}")]
    Unparsable {
        /// What was given.
        text: String,
        /// What the entry takes.
        expected: String,
    },
    /// The value is outside the entry's `min`..`max` or what its bytes hold.
    #[error("{value} is out of range ({min} to {max})")]
    OutOfRange {
        /// The value.
        value: String,
        /// The least allowed.
        min: String,
        /// The greatest allowed.
        max: String,
    },
    /// The string is longer than its entry holds (a person's text keeps one byte for the
    /// NUL; a backup's may fill the entry, see [`Entry::encode_restored`]).
    #[error("{len} bytes do not fit in a string of {size} (at most {room} bytes of text)")]
    TooLong {
        /// The text's length in bytes as it would be written.
        len: usize,
        /// The entry's size.
        size: u32,
        /// The most bytes of text it takes.
        room: u32,
    },
    /// The value is not in the entry's map.
    #[error("`{text}` is none of the values allowed: {allowed}")]
    NotInMap {
        /// What was given.
        text: String,
        /// The labels and values allowed.
        allowed: String,
    },
    /// The value is of another type than the entry.
    #[error("a {value} value for a {entry} entry")]
    WrongType {
        /// The value's type.
        value: &'static str,
        /// The entry's type.
        entry: &'static str,
    },
    /// Actions and unknown elements have no value to read or set.
    #[error("a {0} entry holds no value")]
    NoValue(&'static str),
}

impl Value {
    /// The type's word, as [`EntryKind::word`] has it.
    pub fn word(&self) -> &'static str {
        match self {
            Value::Int(_) => "int",
            Value::Float(_) => "float",
            Value::EventId(_) => "eventid",
            Value::String(_) => "string",
        }
    }
}

impl core::fmt::Display for Value {
    /// The text JMRI writes: `Long.toString` for ints, dotted upper-case hex for Event IDs,
    /// the string itself; floats in Rust's shortest form (JMRI's backup has none).
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            Value::Int(value) => write!(f, "{value}"),
            Value::Float(value) => write!(f, "{value}"),
            Value::EventId(bytes) => {
                for (i, byte) in bytes.iter().enumerate() {
                    if i > 0 {
                        f.write_str(".")?;
                    }
                    write!(f, "{byte:02X}")?;
                }
                Ok(())
            }
            Value::String(text) => f.write_str(text),
        }
    }
}

impl Entry {
    /// The value in `bytes` (exactly [`size`](Entry::size) of them).
    pub fn decode(&self, bytes: &[u8]) -> Result<Value, ValueError> {
        if bytes.len() != self.size as usize {
            return Err(ValueError::WrongLength { size: self.size, got: bytes.len() });
        }
        match &self.kind {
            EntryKind::Int { .. } => {
                self.int_size()?;
                Ok(Value::Int(bytes.iter().fold(0u64, |v, b| (v << 8) | u64::from(*b)) as i64))
            }
            EntryKind::Float { .. } => Ok(Value::Float(match bytes {
                [a, b] => f64::from(half::f16::from_be_bytes([*a, *b])),
                [a, b, c, d] => f64::from(f32::from_be_bytes([*a, *b, *c, *d])),
                &[a, b, c, d, e, f, g, h] => f64::from_be_bytes([a, b, c, d, e, f, g, h]),
                _ => return Err(ValueError::BadSize { kind: "float", size: self.size }),
            })),
            EntryKind::EventId => {
                let mut id = [0; 8];
                id.copy_from_slice(bytes);
                Ok(Value::EventId(id))
            }
            EntryKind::String => {
                let end = bytes.iter().position(|b| *b == 0).unwrap_or(bytes.len());
                Ok(Value::String(String::from_utf8_lossy(bytes.get(..end).unwrap_or_default()).into_owned()))
            }
            kind => Err(ValueError::NoValue(kind.word())),
        }
    }

    /// The bytes of `value` for this entry, once it is checked: its type, its size, its
    /// `min`..`max`. Strings are NUL-padded to the entry's size.
    pub fn encode(&self, value: &Value) -> Result<Vec<u8>, ValueError> {
        let wrong = || ValueError::WrongType { value: value.word(), entry: self.kind.word() };
        match (&self.kind, value) {
            (EntryKind::Int { min, max, .. }, Value::Int(v)) => {
                let size = self.int_size()?;
                let (lowest, highest) = int_limits(size, *min, *max);
                let shown = i128::from(*v);
                if shown < lowest || shown > highest {
                    return Err(ValueError::OutOfRange {
                        value: v.to_string(),
                        min: lowest.to_string(),
                        max: highest.to_string(),
                    });
                }
                Ok(v.to_be_bytes().get(8 - size as usize..).unwrap_or_default().to_vec())
            }
            (EntryKind::Float { min, max, .. }, Value::Float(v)) => {
                let below = min.is_some_and(|m| *v < m);
                let above = max.is_some_and(|m| *v > m);
                let bytes = match self.size {
                    2 => half::f16::from_f64(*v).to_be_bytes().to_vec(),
                    4 => (*v as f32).to_be_bytes().to_vec(),
                    8 => v.to_be_bytes().to_vec(),
                    size => return Err(ValueError::BadSize { kind: "float", size }),
                };
                let overflows =
                    v.is_finite() && !self.decode(&bytes).is_ok_and(|d| matches!(d, Value::Float(d) if d.is_finite()));
                if below || above || v.is_nan() || overflows {
                    let bound = |b: Option<f64>, none: &str| b.map_or(none.to_string(), |b| format!("{b}"));
                    return Err(ValueError::OutOfRange {
                        value: format!("{v}"),
                        min: bound(*min, "-inf"),
                        max: bound(*max, "inf"),
                    });
                }
                Ok(bytes)
            }
            (EntryKind::EventId, Value::EventId(id)) => Ok(id.to_vec()),
            (EntryKind::String, Value::String(text)) => {
                let size = self.size as usize;
                if text.len() >= size || text.contains('\0') {
                    return Err(ValueError::TooLong {
                        len: text.len(),
                        size: self.size,
                        room: self.size.saturating_sub(1),
                    });
                }
                let mut bytes = text.as_bytes().to_vec();
                bytes.resize(size, 0);
                Ok(bytes)
            }
            (EntryKind::Action { .. } | EntryKind::Unknown, _) => Err(ValueError::NoValue(self.kind.word())),
            _ => Err(wrong()),
        }
    }

    /// The bytes a backup line's `value` restores: checked as [`encode`](Entry::encode)
    /// checks a person's value, except for strings. A backup holds what the node held, so its
    /// text may fill the whole entry with no NUL, and each U+FFFD in it (a byte that was not
    /// UTF-8 when the backup was made; JMRI writes the same character) goes back as 0xFF, the
    /// byte of erased flash. 0xFF is never part of a UTF-8 character, so it reads back as one
    /// U+FFFD whatever its neighbours: a restored string reads back as the line it came from,
    /// and an erased string of a factory-fresh board restores onto its replacement.
    ///
    /// The erased value of an int or a float (every byte 0xFF: 65535 for two bytes, NaN) is
    /// restored even outside the entry's `min`..`max`, as a node that was never configured
    /// holds it; any other value out of range is refused as [`encode`](Entry::encode) does.
    pub fn encode_restored(&self, value: &Value) -> Result<Vec<u8>, ValueError> {
        let erased = vec![0xFF; self.size as usize];
        let text = match (&self.kind, value) {
            (EntryKind::String, Value::String(text)) => text,
            (EntryKind::Int { .. } | EntryKind::Float { .. }, _)
                if self.decode(&erased).is_ok_and(|e| same_number(&e, value)) =>
            {
                return Ok(erased);
            }
            _ => return self.encode(value),
        };
        let mut bytes = Vec::with_capacity(self.size as usize);
        for c in text.chars() {
            match c {
                char::REPLACEMENT_CHARACTER => bytes.push(0xFF),
                c => bytes.extend_from_slice(c.encode_utf8(&mut [0; 4]).as_bytes()),
            }
        }
        if bytes.len() > self.size as usize || text.contains('\0') {
            return Err(ValueError::TooLong { len: bytes.len(), size: self.size, room: self.size });
        }
        bytes.resize(self.size as usize, 0);
        Ok(bytes)
    }

    /// The value a person wrote: a label of the entry's map, or the value's own text (see
    /// [`parse`](Entry::parse)).
    pub fn parse_input(&self, text: &str) -> Result<Value, ValueError> {
        match self.map.property(text) {
            Some(property) => self.parse(property),
            None => self.parse(text),
        }
    }

    /// A value's own text, as a backup holds it: decimal or `0x` hex ints, dotted hex Event
    /// IDs, decimal floats, a string as it is. Only the form is checked here;
    /// [`encode`](Entry::encode) checks the range.
    pub fn parse(&self, text: &str) -> Result<Value, ValueError> {
        let unparsable =
            |expected: &str| ValueError::Unparsable { text: text.to_string(), expected: expected.to_string() };
        match &self.kind {
            EntryKind::Int { .. } => {
                parse_int(java_trim(text)).map(Value::Int).ok_or_else(|| unparsable("a whole number"))
            }
            EntryKind::Float { .. } => java_trim(text).parse().map(Value::Float).map_err(|_| unparsable("a number")),
            EntryKind::EventId => parse_event_id(text)
                .map(Value::EventId)
                .ok_or_else(|| unparsable("an Event ID (8 hex bytes, 05.01.01.01.22.F2.00.01)")),
            EntryKind::String => Ok(Value::String(text.to_string())),
            kind => Err(ValueError::NoValue(kind.word())),
        }
    }

    /// [`parse_input`](Entry::parse_input) and [`encode`](Entry::encode), and for an entry
    /// with a map, the value must be one of it: what `config set` demands of a person's value.
    pub fn parse_strict(&self, text: &str) -> Result<(Value, Vec<u8>), ValueError> {
        let value = self.parse_input(text)?;
        let bytes = self.encode(&value)?;
        if !self.map.is_empty() && self.label(&value).is_none() {
            let allowed: Vec<String> = self.map.relations.iter().map(|(p, v)| format!("{v} ({p})")).collect();
            return Err(ValueError::NotInMap { text: text.to_string(), allowed: allowed.join(", ") });
        }
        Ok((value, bytes))
    }

    /// The label of `value` in the entry's map, if it has one.
    pub fn label(&self, value: &Value) -> Option<&str> {
        let same = |property: &str| self.parse(property).is_ok_and(|v| v == *value);
        self.map.relations.iter().find(|(p, _)| same(p)).map(|(_, label)| label.as_str())
    }

    fn int_size(&self) -> Result<u32, ValueError> {
        match self.size {
            1..=8 => Ok(self.size),
            size => Err(ValueError::BadSize { kind: "int", size }),
        }
    }
}

/// The values an int of `size` bytes may take: what its bytes hold (unsigned, or any i64
/// for 8 bytes, as JMRI reads them), narrowed by `min` and `max`.
/// Whether two numbers are the same, NaN being the same as NaN.
fn same_number(a: &Value, b: &Value) -> bool {
    match (a, b) {
        (Value::Float(a), Value::Float(b)) => a == b || (a.is_nan() && b.is_nan()),
        (a, b) => a == b,
    }
}

fn int_limits(size: u32, min: Option<i64>, max: Option<i64>) -> (i128, i128) {
    let (low, high) =
        if size >= 8 { (i128::from(i64::MIN), i128::from(i64::MAX)) } else { (0, (1i128 << (8 * size)) - 1) };
    (min.map_or(low, |m| low.max(i128::from(m))), max.map_or(high, |m| high.min(i128::from(m))))
}

/// A whole number, decimal (signed) or `0x` hex.
fn parse_int(text: &str) -> Option<i64> {
    match text.strip_prefix("0x").or_else(|| text.strip_prefix("0X")) {
        Some(hex) => u64::from_str_radix(hex, 16).ok().map(|v| v as i64),
        None => text.parse::<i64>().ok().or_else(|| text.parse::<u64>().ok().map(|v| v as i64)),
    }
}

/// An Event ID as 8 hex bytes separated by dots or spaces (one or two digits each, as JMRI
/// takes them), or 16 hex digits with or without `0x`.
pub fn parse_event_id(text: &str) -> Option<[u8; 8]> {
    let text = java_trim(text);
    let mut id = [0u8; 8];
    let bare = text.strip_prefix("0x").or_else(|| text.strip_prefix("0X")).unwrap_or(text);
    if bare.len() == 16 && bare.bytes().all(|b| b.is_ascii_hexdigit()) {
        id = u64::from_str_radix(bare, 16).ok()?.to_be_bytes();
        return Some(id);
    }
    let mut parts = text.split(['.', ' ']).filter(|p| !p.is_empty());
    for byte in &mut id {
        let part = parts.next()?;
        if part.len() > 2 {
            return None;
        }
        *byte = u8::from_str_radix(part, 16).ok()?;
    }
    parts.next().is_none().then_some(id)
}
