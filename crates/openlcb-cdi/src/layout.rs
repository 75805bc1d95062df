//! Where every entry lives, and what JMRI calls it.
//!
//! The rules are OpenLCB_Java's `ConfigRepresentation` (JMRI's model of a node's
//! configuration), step by step:
//! - a segment's key is its name, or `seg<index>` when it has none (or only blanks);
//! - an item's key is its parent's key, `.`, and its name or `child<index>`;
//! - within a segment or group, each item starts at the end of the one before plus its own
//!   `offset` (negative moves back); the first starts at the segment's origin or where the
//!   group starts;
//! - a group replicated more than once holds copies `key(0)`, `key(1)`, ... one after the
//!   other, each as long as its items; a group of replication 0 or 1 holds its items directly;
//! - an `<eventid>` is 8 bytes, the others their `size`; a `<bit>` moves the position by its
//!   offset only.
//!
//! On top of JMRI, the layout is checked: every entry must lie inside its 32-bit space, no
//! two may share a byte, and the count is bounded.

use alloc::format;
use alloc::string::String;
use alloc::vec::Vec;

use crate::Error;
use crate::tree::{Cdi, Item, ItemKind, Map, java_trim};

/// The most entries (leaves and group copies) a layout holds; a CDI that asks for more (a
/// replication of a million, say) is refused rather than laid out.
pub const MAX_ENTRIES: usize = 200_000;

/// Every segment of a CDI with its entries at their absolute addresses.
#[derive(Debug, Clone, PartialEq)]
pub struct Layout {
    /// The segments, in document order.
    pub segments: Vec<LaidGroup>,
}

/// A segment, a group, or one copy of a replicated group, laid out.
#[derive(Debug, Clone, PartialEq)]
pub struct LaidGroup {
    /// JMRI's key.
    pub key: String,
    /// What a person reads: the name, or for a copy its repname with its number.
    pub label: Option<String>,
    /// The description.
    pub description: Option<String>,
    /// The memory space.
    pub space: u8,
    /// The first address (the segment's origin, or where the group starts).
    pub address: i64,
    /// The bytes it covers, offsets included.
    pub size: i64,
    /// What it holds, in document order.
    pub children: Vec<Laid>,
}

/// A node of the laid-out tree.
#[derive(Debug, Clone, PartialEq)]
pub enum Laid {
    /// A group, or a replicated group's copy.
    Group(LaidGroup),
    /// A value.
    Entry(Entry),
}

/// One value of the node's configuration.
#[derive(Debug, Clone, PartialEq)]
pub struct Entry {
    /// JMRI's key, e.g. `Port I/O.Line(3).Event On`.
    pub key: String,
    /// The name.
    pub name: Option<String>,
    /// The description.
    pub description: Option<String>,
    /// The memory space.
    pub space: u8,
    /// The absolute address in the space.
    pub address: u32,
    /// The bytes it takes.
    pub size: u32,
    /// Values and their labels.
    pub map: Map,
    /// The type, with its limits.
    pub kind: EntryKind,
}

/// The type of an [`Entry`].
#[derive(Debug, Clone, PartialEq)]
#[non_exhaustive]
pub enum EntryKind {
    /// A big-endian integer.
    Int {
        /// The least value allowed.
        min: Option<i64>,
        /// The greatest value allowed.
        max: Option<i64>,
        /// The factory value.
        default: Option<i64>,
    },
    /// An IEEE 754 number.
    Float {
        /// The least value allowed.
        min: Option<f64>,
        /// The greatest value allowed.
        max: Option<f64>,
        /// The factory value.
        default: Option<f64>,
    },
    /// An Event ID.
    EventId,
    /// A NUL-padded UTF-8 string.
    String,
    /// A button: writing `value` makes the node act.
    Action {
        /// What is written.
        value: i64,
        /// The button's text.
        button_text: Option<String>,
    },
    /// An element unknown here (a newer schema's).
    Unknown,
}

impl EntryKind {
    /// True for the kinds JMRI's backup holds: int, string and eventid (not float, action
    /// or unknown).
    pub fn in_backup(&self) -> bool {
        matches!(self, EntryKind::Int { .. } | EntryKind::String | EntryKind::EventId)
    }

    /// The word for the type, as `config show` and the JSON print it.
    pub fn word(&self) -> &'static str {
        match self {
            EntryKind::Int { .. } => "int",
            EntryKind::Float { .. } => "float",
            EntryKind::EventId => "eventid",
            EntryKind::String => "string",
            EntryKind::Action { .. } => "action",
            EntryKind::Unknown => "unknown",
        }
    }
}

/// A range of one space that one read fetches: a segment's span.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Span {
    /// The memory space.
    pub space: u8,
    /// The first address.
    pub address: u32,
    /// The bytes.
    pub len: u32,
}

impl Layout {
    /// Lays out `cdi`.
    pub fn new(cdi: &Cdi) -> Result<Layout, Error> {
        let mut count = 0;
        let mut segments = Vec::with_capacity(cdi.segments.len());
        for segment in &cdi.segments {
            let key = match &segment.name {
                Some(name) if !java_trim(name).is_empty() => name.clone(),
                _ => format!("seg{}", segment.index),
            };
            let address = i64::from(segment.origin);
            let mut children = Vec::new();
            let size = lay_items(&key, segment.space, &segment.items, address, &mut children, &mut count)?;
            segments.push(LaidGroup {
                key,
                label: segment.name.clone(),
                description: segment.description.clone(),
                space: segment.space,
                address,
                size,
                children,
            });
        }
        let layout = Layout { segments };
        layout.check_overlaps()?;
        Ok(layout)
    }

    /// Parses and lays out a CDI document.
    pub fn parse(xml: &str) -> Result<Layout, Error> {
        Layout::new(&Cdi::parse(xml)?)
    }

    /// Every entry, in document order (the order of JMRI's backup).
    pub fn entries(&self) -> impl Iterator<Item = &Entry> {
        let mut stack: Vec<core::slice::Iter<'_, Laid>> =
            self.segments.iter().rev().map(|s| s.children.iter()).collect();
        core::iter::from_fn(move || {
            loop {
                let top = stack.last_mut()?;
                match top.next() {
                    None => {
                        stack.pop();
                    }
                    Some(Laid::Entry(entry)) => return Some(entry),
                    Some(Laid::Group(group)) => stack.push(group.children.iter()),
                }
            }
        })
    }

    /// The entries whose key is `key` (more than one when a CDI repeats a name).
    pub fn find<'a>(&'a self, key: &'a str) -> impl Iterator<Item = &'a Entry> + 'a {
        self.entries().filter(move |e| e.key == key)
    }

    /// Each segment's span: from its first entry's address to its last one's end, one read
    /// apiece. Segments without entries have none.
    pub fn spans(&self) -> Vec<Span> {
        let mut spans = Vec::new();
        for segment in &self.segments {
            let mut range: Option<(u32, u32)> = None;
            let mut stack = Vec::from([segment.children.as_slice()]);
            while let Some(children) = stack.pop() {
                for child in children {
                    match child {
                        Laid::Group(group) => stack.push(&group.children),
                        Laid::Entry(entry) if entry.size > 0 => {
                            let end = entry.address + entry.size; // checked when laid out
                            range = Some(match range {
                                None => (entry.address, end),
                                Some((start, stop)) => (start.min(entry.address), stop.max(end)),
                            });
                        }
                        Laid::Entry(_) => {}
                    }
                }
            }
            if let Some((address, end)) = range {
                spans.push(Span { space: segment.space, address, len: end - address });
            }
        }
        spans
    }

    fn check_overlaps(&self) -> Result<(), Error> {
        let mut placed: Vec<&Entry> = self.entries().filter(|e| e.size > 0).collect();
        placed.sort_by_key(|e| (e.space, e.address));
        for pair in placed.windows(2) {
            if let [first, second] = pair
                && first.space == second.space
                && u64::from(second.address) < u64::from(first.address) + u64::from(first.size)
            {
                return Err(Error::Overlap { first: first.key.clone(), second: second.key.clone() });
            }
        }
        Ok(())
    }
}

/// JMRI's `processGroup`: lays out `items` from `origin` under `base`; returns the bytes
/// covered (offsets included).
fn lay_items(
    base: &str,
    space: u8,
    items: &[Item],
    origin: i64,
    out: &mut Vec<Laid>,
    count: &mut usize,
) -> Result<i64, Error> {
    let start = origin;
    let mut at = origin;
    for item in items {
        at = at.saturating_add(i64::from(item.offset));
        let name = match &item.name {
            Some(name) if !java_trim(name).is_empty() => name.clone(),
            _ => format!("child{}", item.index),
        };
        let key = format!("{base}.{name}");
        let (laid, size) = match &item.kind {
            ItemKind::Bit => continue,
            ItemKind::Group(group) => {
                let mut children = Vec::new();
                let size = if group.replication <= 1 {
                    lay_items(&key, space, &group.items, at, &mut children, count)?
                } else {
                    let mut total = 0i64;
                    for i in 0..group.replication {
                        bump(count)?;
                        let copy_key = format!("{key}({i})");
                        let copy_at = at.saturating_add(total);
                        let mut copy = Vec::new();
                        let size = lay_items(&copy_key, space, &group.items, copy_at, &mut copy, count)?;
                        children.push(Laid::Group(LaidGroup {
                            key: copy_key,
                            label: Some(repname(&group.repnames, i + 1, group.replication)),
                            description: None,
                            space,
                            address: copy_at,
                            size,
                            children: copy,
                        }));
                        total = total.saturating_add(size);
                    }
                    total
                };
                let laid = LaidGroup {
                    key,
                    label: item.name.clone(),
                    description: item.description.clone(),
                    space,
                    address: at,
                    size,
                    children,
                };
                (Laid::Group(laid), size)
            }
            leaf => {
                bump(count)?;
                let (size, kind) = match leaf {
                    ItemKind::Int { size, min, max, default } => {
                        (*size, EntryKind::Int { min: *min, max: *max, default: *default })
                    }
                    ItemKind::Float { size, min, max, default } => {
                        (*size, EntryKind::Float { min: *min, max: *max, default: *default })
                    }
                    ItemKind::EventId => (8, EntryKind::EventId),
                    ItemKind::String { size } => (*size, EntryKind::String),
                    ItemKind::Action { size, value, button_text } => {
                        (*size, EntryKind::Action { value: *value, button_text: button_text.clone() })
                    }
                    _ => (unknown_size(leaf), EntryKind::Unknown),
                };
                let address = u32::try_from(at)
                    .ok()
                    .filter(|a| u64::from(*a) + u64::from(size) <= 1 << 32)
                    .ok_or_else(|| Error::OutsideSpace { key: key.clone(), address: at })?;
                let entry = Entry {
                    key,
                    name: item.name.clone(),
                    description: item.description.clone(),
                    space,
                    address,
                    size,
                    map: item.map.clone(),
                    kind,
                };
                (Laid::Entry(entry), i64::from(size))
            }
        };
        out.push(laid);
        at = at.saturating_add(size);
    }
    Ok(at - start)
}

fn unknown_size(kind: &ItemKind) -> u32 {
    match kind {
        ItemKind::Unknown { size, .. } => *size,
        _ => 0,
    }
}

fn bump(count: &mut usize) -> Result<(), Error> {
    *count += 1;
    if *count > MAX_ENTRIES { Err(Error::TooManyEntries) } else { Ok(()) }
}

/// The label of copy `index` (from 1) of `replications`, by the CDI standard's rule as
/// JMRI's `getRepName` applies it: the `index`-th repname while there are more; the last one
/// extended with a number (counting on from its trailing digits, if any) after that.
pub fn repname(repnames: &[String], index: u32, replications: u32) -> String {
    let n = repnames.len();
    let i = index as usize;
    let Some(last) = repnames.last() else { return format!("Group {index}") };
    if i < n || (i == n && index == replications) {
        return repnames.get(i.saturating_sub(1)).cloned().unwrap_or_default();
    }
    let digits = last.bytes().rev().take_while(u8::is_ascii_digit).count();
    let (stem, tail) = last.split_at(last.len() - digits);
    let extra = i64::from(index) - n as i64;
    match tail.parse::<i64>() {
        Ok(first) => format!("{stem}{}", first + extra),
        Err(_) => format!("{last}{}", extra + 1),
    }
}
