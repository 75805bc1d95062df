//! The CDI as a tree: what the XML says, before any address is worked out.
//!
//! Reading follows OpenLCB_Java's `JdomCdiRep` (the reader inside JMRI), so that the tree and
//! the names built from it are the ones JMRI sees: an element's name is the text of its first
//! `<name>` child; `<repname>`, `<name>`, `<description>`, `<link>` and `<hints>` are not
//! items; `<bit>` is an item that takes no room; any other unknown element is an item of
//! `size` bytes (0 without one), as a newer schema may add. Numbers are decimal as the schema
//! has them (JMRI's `Integer.parseInt` after trimming); a malformed one is an error here,
//! where JMRI would quietly read 0.

use alloc::string::{String, ToString};
use alloc::vec::Vec;

use crate::Error;

/// How deep groups may nest; deeper documents are refused (no real CDI comes near).
pub const MAX_DEPTH: usize = 32;

/// A parsed CDI document.
#[derive(Debug, Clone, PartialEq)]
pub struct Cdi {
    /// `<identification>`, when present.
    pub identification: Option<Identification>,
    /// `<acdi/>` is present: the node has the ACDI spaces 0xFC and 0xFB.
    pub acdi: bool,
    /// The `<segment>`s, in document order.
    pub segments: Vec<Segment>,
}

/// The `<identification>` element.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Identification {
    /// `<manufacturer>`.
    pub manufacturer: Option<String>,
    /// `<model>`.
    pub model: Option<String>,
    /// `<hardwareVersion>`.
    pub hardware_version: Option<String>,
    /// `<softwareVersion>`.
    pub software_version: Option<String>,
    /// `<map>`: further properties.
    pub map: Map,
}

/// A `<segment>`: items in one memory space from an origin.
#[derive(Debug, Clone, PartialEq)]
pub struct Segment {
    /// The text of `<name>`.
    pub name: Option<String>,
    /// The text of `<description>`.
    pub description: Option<String>,
    /// The `space` attribute (0 when absent, as JMRI reads it).
    pub space: u8,
    /// The `origin` attribute (0 when absent).
    pub origin: u32,
    /// The position among its parent's child nodes (text and comments count, as in JDOM):
    /// JMRI names an unnamed segment `seg<index>`.
    pub index: usize,
    /// The items, in document order.
    pub items: Vec<Item>,
}

/// One item of a segment or group.
#[derive(Debug, Clone, PartialEq)]
pub struct Item {
    /// The text of `<name>`.
    pub name: Option<String>,
    /// The text of `<description>`.
    pub description: Option<String>,
    /// The `offset` attribute: bytes skipped before the item (negative goes back).
    pub offset: i32,
    /// The position among its parent's child nodes: JMRI names an unnamed item
    /// `child<index>`.
    pub index: usize,
    /// `<map>`: values and their labels.
    pub map: Map,
    /// What the item is.
    pub kind: ItemKind,
}

/// What an item is, with what only that kind has.
#[derive(Debug, Clone, PartialEq)]
#[non_exhaustive]
pub enum ItemKind {
    /// `<group>`.
    Group(Group),
    /// `<int>`: a big-endian integer of `size` bytes.
    Int {
        /// `size` (1 when absent).
        size: u32,
        /// `<min>`.
        min: Option<i64>,
        /// `<max>`.
        max: Option<i64>,
        /// `<default>`.
        default: Option<i64>,
    },
    /// `<float>`: IEEE 754 of `size` bytes (2, 4 or 8).
    Float {
        /// `size` (1 when absent, as JMRI reads it; no value can be decoded then).
        size: u32,
        /// `<min>`.
        min: Option<f64>,
        /// `<max>`.
        max: Option<f64>,
        /// `<default>`.
        default: Option<f64>,
    },
    /// `<eventid>`: 8 bytes.
    EventId,
    /// `<string>`: `size` bytes of UTF-8, NUL-terminated unless full.
    String {
        /// `size` (1 when absent).
        size: u32,
    },
    /// `<action>`: writing `value` into `size` bytes makes the node act.
    Action {
        /// `size` (1 when absent).
        size: u32,
        /// `<value>`.
        value: i64,
        /// `<buttonText>`.
        button_text: Option<String>,
    },
    /// `<bit>`: described by older schemas; it takes no room (JMRI lays out nothing for it
    /// but still applies its offset).
    Bit,
    /// An element no schema version known here has: `size` bytes (0 without the attribute).
    Unknown {
        /// The element's name.
        element: String,
        /// `size`.
        size: u32,
    },
}

/// A `<group>`.
#[derive(Debug, Clone, PartialEq)]
pub struct Group {
    /// The `replication` attribute (0 when absent; 0 and 1 both mean one copy, unnumbered).
    pub replication: u32,
    /// The `<repname>`s, for labels of the copies.
    pub repnames: Vec<String>,
    /// The items of one copy.
    pub items: Vec<Item>,
}

/// A `<map>`: `(property, value)` pairs, `property` being the stored value's text and
/// `value` its label.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct Map {
    /// The relations in document order.
    pub relations: Vec<(String, String)>,
}

impl Map {
    /// The label of the stored value `property` (JMRI's `getEntry`: the first exact match).
    pub fn label(&self, property: &str) -> Option<&str> {
        self.relations.iter().find(|(p, _)| p == property).map(|(_, v)| v.as_str())
    }

    /// The stored value whose label is `label` (exact match first, then the only match
    /// ignoring ASCII case).
    pub fn property(&self, label: &str) -> Option<&str> {
        if let Some((p, _)) = self.relations.iter().find(|(_, v)| v == label) {
            return Some(p);
        }
        let mut matches = self.relations.iter().filter(|(_, v)| v.eq_ignore_ascii_case(label));
        match (matches.next(), matches.next()) {
            (Some((p, _)), None) => Some(p),
            _ => None,
        }
    }

    /// True when the map has no relation.
    pub fn is_empty(&self) -> bool {
        self.relations.is_empty()
    }
}

impl Cdi {
    /// Parses a CDI document. A trailing NUL (as space 0xFF ends) and anything after it is
    /// ignored.
    pub fn parse(xml: &str) -> Result<Cdi, Error> {
        let xml = xml.split('\0').next().unwrap_or_default();
        let options = roxmltree::ParsingOptions { allow_dtd: true, ..roxmltree::ParsingOptions::default() };
        let document = roxmltree::Document::parse_with_options(xml, options)
            .map_err(|e| Error::Xml { line: e.pos().row, column: e.pos().col })?;
        let root = document.root_element();
        let identification = child(root, "identification").map(|id| Identification {
            manufacturer: child_text(id, "manufacturer"),
            model: child_text(id, "model"),
            hardware_version: child_text(id, "hardwareVersion"),
            software_version: child_text(id, "softwareVersion"),
            map: map_of(id),
        });
        let mut segments = Vec::new();
        for (index, node) in root.children().enumerate() {
            if !is_element(node, "segment") {
                continue;
            }
            segments.push(Segment {
                name: child_text(node, "name"),
                description: child_text(node, "description"),
                space: number(node, "space", 0)?,
                origin: number(node, "origin", 0)?,
                index,
                items: items(node, 0)?,
            });
        }
        Ok(Cdi { identification, acdi: child(root, "acdi").is_some(), segments })
    }
}

fn is_element(node: roxmltree::Node<'_, '_>, name: &str) -> bool {
    node.is_element() && node.tag_name().name() == name
}

fn child<'a, 'i>(node: roxmltree::Node<'a, 'i>, name: &str) -> Option<roxmltree::Node<'a, 'i>> {
    node.children().find(|n| is_element(*n, name))
}

/// JDOM's `getText`: the element's own text children, joined.
fn text_of(node: roxmltree::Node<'_, '_>) -> String {
    node.children().filter(|n| n.is_text()).filter_map(|n| n.text()).collect()
}

fn child_text(node: roxmltree::Node<'_, '_>, name: &str) -> Option<String> {
    child(node, name).map(text_of)
}

/// JDOM's `getTextNormalize`: trimmed, inner runs of white space as one space.
fn normalized(node: roxmltree::Node<'_, '_>, name: &str) -> Option<String> {
    let text = child_text(node, name)?;
    let words: Vec<&str> = text.split_ascii_whitespace().collect();
    Some(words.join(" "))
}

/// Java's `String.trim`: every character up to U+0020 off both ends.
pub(crate) fn java_trim(text: &str) -> &str {
    text.trim_matches(|c: char| c <= ' ')
}

/// An attribute as a decimal number (JMRI's `getIntValue`), `default` when absent.
fn number<T: core::str::FromStr>(
    node: roxmltree::Node<'_, '_>,
    attribute: &'static str,
    default: T,
) -> Result<T, Error> {
    match node.attribute(attribute) {
        None => Ok(default),
        Some(text) => java_trim(text)
            .parse()
            .map_err(|_| Error::BadNumber { element: node.tag_name().name().to_string(), field: attribute }),
    }
}

/// A `<min>`, `<max>`, `<default>` or `<value>` child as a number, decimal or `0x` hex.
fn bound<T: core::str::FromStr>(
    node: roxmltree::Node<'_, '_>,
    field: &'static str,
    hex: fn(&str) -> Option<T>,
) -> Result<Option<T>, Error> {
    let Some(text) = normalized(node, field) else { return Ok(None) };
    let parsed = match text.strip_prefix("0x").or_else(|| text.strip_prefix("0X")) {
        Some(digits) => hex(digits),
        None => text.parse().ok(),
    };
    match parsed {
        Some(value) => Ok(Some(value)),
        None => Err(Error::BadNumber { element: node.tag_name().name().to_string(), field }),
    }
}

fn hex_int(digits: &str) -> Option<i64> {
    u64::from_str_radix(digits, 16).ok().map(|v| v as i64)
}

fn no_hex(_: &str) -> Option<f64> {
    None
}

fn map_of(node: roxmltree::Node<'_, '_>) -> Map {
    let Some(map) = child(node, "map") else { return Map::default() };
    let relations = map
        .children()
        .filter(|n| is_element(*n, "relation"))
        .filter_map(|r| Some((child_text(r, "property")?, child_text(r, "value")?)))
        .collect();
    Map { relations }
}

/// The items of a segment or group (JMRI's `Nested.getItems`).
fn items(parent: roxmltree::Node<'_, '_>, depth: usize) -> Result<Vec<Item>, Error> {
    if depth > MAX_DEPTH {
        return Err(Error::TooDeep);
    }
    let mut found = Vec::new();
    for (index, node) in parent.children().enumerate() {
        if !node.is_element() {
            continue;
        }
        let element = node.tag_name().name();
        let kind = match element {
            "repname" | "name" | "description" | "link" | "hints" => continue,
            "group" => ItemKind::Group(Group {
                replication: number(node, "replication", 0)?,
                repnames: node.children().filter(|n| is_element(*n, "repname")).map(text_of).collect(),
                items: items(node, depth + 1)?,
            }),
            "int" => ItemKind::Int {
                size: number(node, "size", 1)?,
                min: bound(node, "min", hex_int)?,
                max: bound(node, "max", hex_int)?,
                default: bound(node, "default", hex_int)?,
            },
            "float" => ItemKind::Float {
                size: number(node, "size", 1)?,
                min: bound(node, "min", no_hex)?,
                max: bound(node, "max", no_hex)?,
                default: bound(node, "default", no_hex)?,
            },
            "eventid" => ItemKind::EventId,
            "string" => ItemKind::String { size: number(node, "size", 1)? },
            "action" => ItemKind::Action {
                size: number(node, "size", 1)?,
                value: bound(node, "value", hex_int)?.unwrap_or(0),
                button_text: normalized(node, "buttonText"),
            },
            "bit" => ItemKind::Bit,
            other => ItemKind::Unknown { element: other.to_string(), size: number(node, "size", 0)? },
        };
        found.push(Item {
            name: child_text(node, "name"),
            description: child_text(node, "description"),
            offset: number(node, "offset", 0)?,
            index,
            map: map_of(node),
            kind,
        });
    }
    Ok(found)
}
