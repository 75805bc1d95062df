//! JMRI's configuration backup: a text file of `key=value` lines, one per int, string and
//! Event ID entry in document order (OpenLCB_Java `cdi/cmd/BackupConfig.java`), in UTF-8 with
//! `\n` line ends. In keys and values `=`, `\` and invisible characters (control, format,
//! private-use and unassigned code points) are written `\xHHHH` (`cdi/cmd/Util.java`).
//!
//! Reading follows `RestoreConfig`: lines starting with `#` and empty lines are skipped,
//! the key ends at the first `=`. A leading byte-order mark (Windows editors write one) is
//! no part of the first key. A key has as many lines as the CDI has entries of that key; a
//! line past those is a duplicate, and [`plan`] lists it with both line numbers so that a
//! restore writes nothing rather than guess which value was meant. How large a backup of a
//! layout can be is [`max_backup_bytes`].

use alloc::format;
use alloc::string::String;
use alloc::vec::Vec;
use core::fmt::Write as _;

use unicode_general_category::{GeneralCategory, get_general_category};

use crate::Error;
use crate::layout::{Entry, Layout, Span};
use crate::value::{Value, ValueError};

/// The bytes read from a node: one block per [`Span`].
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct Snapshot {
    blocks: Vec<(Span, Vec<u8>)>,
}

impl Snapshot {
    /// An empty snapshot.
    pub fn new() -> Snapshot {
        Snapshot::default()
    }

    /// Adds the bytes read for `span` (fewer than asked for: a node's space ended early).
    pub fn insert(&mut self, span: Span, bytes: Vec<u8>) {
        self.blocks.push((span, bytes));
    }

    /// The `len` bytes at `address` of `space`, if one block holds them all.
    pub fn get(&self, space: u8, address: u32, len: u32) -> Option<&[u8]> {
        self.blocks.iter().find_map(|(span, bytes)| {
            let from = address.checked_sub(span.address).filter(|_| span.space == space)? as usize;
            bytes.get(from..from.checked_add(len as usize)?)
        })
    }

    /// The value of `entry`.
    pub fn value(&self, entry: &Entry) -> Result<Value, Error> {
        let bytes = self
            .get(entry.space, entry.address, entry.size)
            .ok_or_else(|| Error::NotRead { key: entry.key.clone() })?;
        entry.decode(bytes).map_err(|error| Error::Value { key: entry.key.clone(), error })
    }
}

/// The backup file JMRI writes for `layout` and the node's bytes in `snapshot`.
pub fn write(layout: &Layout, snapshot: &Snapshot) -> Result<String, Error> {
    let mut out = String::new();
    for entry in layout.entries().filter(|e| e.kind.in_backup()) {
        let value = snapshot.value(entry)?;
        out.push_str(&escape(&entry.key));
        out.push('=');
        out.push_str(&escape(&format!("{value}")));
        out.push('\n');
    }
    Ok(out)
}

/// One `key=value` line of a backup.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Line {
    /// The line's number, from 1.
    pub number: usize,
    /// The key, unescaped.
    pub key: String,
    /// The value's text, unescaped.
    pub value: String,
}

/// The lines of a backup file (ours or JMRI's). A line with no `=` is an error (JMRI skips
/// it with a warning; a restore should not go on from a file it half understands).
pub fn parse(text: &str) -> Result<Vec<Line>, Error> {
    let mut lines = Vec::new();
    let text = text.strip_prefix('\u{feff}').unwrap_or(text);
    for (index, line) in text.lines().enumerate() {
        if line.is_empty() || line.starts_with('#') {
            continue;
        }
        let (key, value) = line.split_once('=').ok_or(Error::BackupLine { line: index + 1 })?;
        lines.push(Line { number: index + 1, key: unescape(key), value: unescape(value) });
    }
    Ok(lines)
}

/// `Util.escapeString`.
pub fn escape(text: &str) -> String {
    let mut out = String::with_capacity(text.len());
    for c in text.chars() {
        let invisible = matches!(
            get_general_category(c),
            GeneralCategory::Control
                | GeneralCategory::Format
                | GeneralCategory::PrivateUse
                | GeneralCategory::Unassigned
        );
        if invisible || c == '=' || c == '\\' {
            let _ = write!(out, "\\x{:04x}", u32::from(c));
        } else {
            out.push(c);
        }
    }
    out
}

/// `Util.unescapeString`: `\x` and four hex digits is that code point; anything else is
/// kept as it is.
pub fn unescape(text: &str) -> String {
    let mut out = String::with_capacity(text.len());
    let mut rest = text;
    while let Some(at) = rest.find("\\x") {
        let (before, from) = rest.split_at(at);
        out.push_str(before);
        let code = from
            .get(2..6)
            .filter(|h| h.bytes().all(|b| b.is_ascii_hexdigit()))
            .and_then(|h| u32::from_str_radix(h, 16).ok());
        match code.and_then(char::from_u32) {
            Some(c) => {
                out.push(c);
                rest = from.get(6..).unwrap_or_default();
            }
            None => {
                out.push('\\');
                rest = from.get(1..).unwrap_or_default();
            }
        }
    }
    out.push_str(rest);
    out
}

/// What a restore would change.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Plan {
    /// The entries to write: their key, new value and bytes, in the backup's order.
    pub writes: Vec<Change>,
    /// Lines whose value the node already holds.
    pub unchanged: usize,
    /// Keys of the backup the CDI does not have (renamed by a firmware upgrade, say): never
    /// guessed at.
    pub unknown_keys: Vec<String>,
    /// Lines whose value the entry cannot take.
    pub invalid: Vec<(String, ValueError)>,
    /// Lines for a key past the entries the CDI has of it.
    pub duplicates: Vec<Duplicate>,
}

/// A backup line for a key whose every entry had a line already.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Duplicate {
    /// The key.
    pub key: String,
    /// The line that gave the key's first value, from 1.
    pub first_line: usize,
    /// The line past the key's entries, from 1.
    pub line: usize,
}

/// The most bytes a backup of `layout` can take, with room to spare: every entry's key and
/// its value with each byte escaped (`\xHHHH`), twice over (keys a firmware upgrade renamed),
/// and 64 KiB of comments. A larger file is not a backup of this node.
pub fn max_backup_bytes(layout: &Layout) -> usize {
    let entries: usize = layout
        .entries()
        .filter(|e| e.kind.in_backup())
        .map(|e| e.key.len().saturating_add((e.size as usize).saturating_mul(6)).saturating_add(32))
        .fold(0, usize::saturating_add);
    entries.saturating_mul(2).saturating_add(64 * 1024)
}

/// One entry a restore writes.
#[derive(Debug, Clone, PartialEq)]
pub struct Change {
    /// The entry.
    pub entry: Entry,
    /// What the node holds now.
    pub old: Value,
    /// What the backup says.
    pub new: Value,
    /// `new` encoded.
    pub bytes: Vec<u8>,
}

/// Compares a backup with the node's bytes. A key the CDI repeats takes the backup's lines
/// for it in order: the first line the first entry, and so on.
pub fn plan(layout: &Layout, snapshot: &Snapshot, lines: &[Line]) -> Result<Plan, Error> {
    let mut plan = Plan::default();
    // Each key seen: how many lines it had, and the first one's number.
    let mut used: Vec<(&str, usize, usize)> = Vec::new();
    for line in lines {
        let (seen, first_line) = match used.iter_mut().find(|(k, _, _)| *k == line.key) {
            Some((_, n, first)) => {
                *n += 1;
                (*n - 1, *first)
            }
            None => {
                used.push((&line.key, 1, line.number));
                (0, line.number)
            }
        };
        let Some(entry) = layout.find(&line.key).filter(|e| e.kind.in_backup()).nth(seen) else {
            if seen == 0 || layout.find(&line.key).next().is_none() {
                plan.unknown_keys.push(line.key.clone());
            } else {
                plan.duplicates.push(Duplicate { key: line.key.clone(), first_line, line: line.number });
            }
            continue;
        };
        // What the node holds already is no change.
        let old = snapshot.value(entry)?;
        let checked = entry.parse(&line.value).and_then(|new| match new == old {
            true => Ok(None),
            false => entry.encode_restored(&new).map(|bytes| Some((new, bytes))),
        });
        match checked {
            Ok(None) => plan.unchanged += 1,
            Ok(Some((new, bytes))) => plan.writes.push(Change { entry: entry.clone(), old, new, bytes }),
            Err(error) => plan.invalid.push((line.key.clone(), error)),
        }
    }
    Ok(plan)
}

/// Writes joined where they touch: `(space, address, bytes)` in address order, so that a
/// restore of many neighbours is one operation.
pub fn coalesce(changes: &[Change]) -> Vec<(u8, u32, Vec<u8>)> {
    let mut sorted: Vec<&Change> = changes.iter().collect();
    sorted.sort_by_key(|c| (c.entry.space, c.entry.address));
    let mut runs: Vec<(u8, u32, Vec<u8>)> = Vec::new();
    for change in sorted {
        let entry = &change.entry;
        match runs.last_mut() {
            Some((space, address, bytes))
                if *space == entry.space && u64::from(*address) + bytes.len() as u64 == u64::from(entry.address) =>
            {
                bytes.extend_from_slice(&change.bytes);
            }
            _ => runs.push((entry.space, entry.address, change.bytes.clone())),
        }
    }
    runs
}
