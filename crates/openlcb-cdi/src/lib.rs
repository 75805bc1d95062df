//! Sans-IO OpenLCB (LCC) Configuration Description Information (CDI).
//!
//! A node describes its settings in the XML document of its space 0xFF: segments of a memory
//! space, groups (replicated or not) and typed entries (`int`, `string`, `eventid`, `float`,
//! `action`) with sizes, offsets, limits and value maps. This crate reads that document
//! ([`Cdi::parse`]), works out where every entry lives and what JMRI calls it
//! ([`Layout`]), turns the node's bytes into values and back ([`Entry::decode`],
//! [`Entry::parse`], [`Entry::encode`]), and writes and reads JMRI's configuration backup
//! files ([`backup`]). It does no I/O: the bytes come from whatever reads the node's memory.
//!
//! The addresses and keys follow OpenLCB_Java's `ConfigRepresentation` (the model behind
//! JMRI's configuration dialog), so a backup made here restores in JMRI and one made there
//! restores here.
//!
//! ```
//! use openlcb_cdi::{Layout, Value, backup};
//!
//! let xml = r#"<cdi><segment space="253" origin="128"><name>Settings</name>
//!   <string size="8"><name>Name</name></string>
//!   <group replication="2"><name>Line</name><repname>Line 1</repname>
//!     <eventid><name>On</name></eventid>
//!     <int size="1" offset="2"><name>Mode</name><max>1</max>
//!       <map><relation><property>0</property><value>Input</value></relation>
//!            <relation><property>1</property><value>Output</value></relation></map></int>
//!   </group></segment></cdi>"#;
//! let layout = Layout::parse(xml)?;
//! let mode = layout.find("Settings.Line(1).Mode").next().unwrap();
//! assert_eq!((mode.space, mode.address), (253, 128 + 8 + 11 + 8 + 2));
//!
//! // A person's value, checked against the entry: a map label or the value itself.
//! let (value, bytes) = mode.parse_strict("Output")?;
//! assert_eq!((value, bytes), (Value::Int(1), vec![1]));
//! assert!(mode.parse_strict("2").is_err());
//!
//! // The node's bytes, read one span per segment, give JMRI's backup.
//! let mut snapshot = backup::Snapshot::new();
//! for span in layout.spans() {
//!     let mut bytes = vec![0; span.len as usize];
//!     bytes[..5].copy_from_slice(b"Yard\0");
//!     snapshot.insert(span, bytes);
//! }
//! let text = backup::write(&layout, &snapshot)?;
//! assert!(text.starts_with("Settings.Name=Yard\nSettings.Line(0).On=00.00.00.00.00.00.00.00\n"));
//!
//! // A restore writes only what differs.
//! let lines = backup::parse("Settings.Name=Main\nSettings.Line(0).Mode=0\nOld.Key=1\n")?;
//! let plan = backup::plan(&layout, &snapshot, &lines)?;
//! assert_eq!(plan.writes.len(), 1);
//! assert_eq!(plan.writes[0].bytes, b"Main\0\0\0\0");
//! assert_eq!((plan.unchanged, plan.unknown_keys.as_slice()), (1, ["Old.Key".to_string()].as_slice()));
//! # Ok::<(), Box<dyn std::error::Error>>(())
//! ```
//!
//! # Features
#![doc = document_features::document_features!()]
#![cfg_attr(not(test), no_std)]
#![forbid(unsafe_code)]

extern crate alloc;

pub mod backup;
#[cfg(feature = "fuzzing")]
#[doc(hidden)]
pub mod fuzzing;
mod layout;
mod tree;
mod value;

use alloc::string::String;

pub use layout::{Entry, EntryKind, Laid, LaidGroup, Layout, MAX_ENTRIES, Span, repname};
pub use tree::{Cdi, Group, Identification, Item, ItemKind, MAX_DEPTH, Map, Segment};
pub use value::{Value, ValueError, parse_event_id};

/// Why a CDI, a layout or a backup cannot be used.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum Error {
    /// The document is not well-formed XML.
    #[error("the CDI is not well-formed XML (line {line}, column {column})")]
    Xml {
        /// Where the parser stopped.
        line: u32,
        /// Where the parser stopped.
        column: u32,
    },
    /// An attribute or a `<min>`/`<max>`/`<default>`/`<value>` is not a number of its range.
    #[error("<{element}> has a malformed {field}")]
    BadNumber {
        /// The element.
        element: String,
        /// The attribute or child element.
        field: &'static str,
    },
    /// Groups nest deeper than [`MAX_DEPTH`].
    #[error("groups nest deeper than {MAX_DEPTH}")]
    TooDeep,
    /// The layout would hold more than [`MAX_ENTRIES`] entries.
    #[error("the CDI describes more than {MAX_ENTRIES} entries")]
    TooManyEntries,
    /// An entry starts before address 0 or ends past the end of its 32-bit space.
    #[error("{key} lies outside its space (address {address})")]
    OutsideSpace {
        /// The entry.
        key: String,
        /// Where it would start.
        address: i64,
    },
    /// Two entries share bytes.
    #[error("{first} and {second} overlap")]
    Overlap {
        /// The entry at the lower address.
        first: String,
        /// The one that starts inside it.
        second: String,
    },
    /// A snapshot lacks an entry's bytes.
    #[error("{key} was not read")]
    NotRead {
        /// The entry.
        key: String,
    },
    /// An entry's bytes do not decode.
    #[error("{key}: {error}")]
    Value {
        /// The entry.
        key: String,
        /// Why.
        error: ValueError,
    },
    /// A backup line has no `=`.
    #[error("line {line} of the backup is not key=value")]
    BackupLine {
        /// Its number, from 1.
        line: usize,
    },
}
