//! The application-node kit: a board's configuration declared once, in code, giving both its
//! CDI (the XML a tool reads from space 0xFF) and the place of every setting in space 0xFD,
//! so that a firmware author writes neither XML nor offsets. The settings are typed handles
//! ([`IntSetting`], [`StringSetting`], [`EventSetting`]) that read and write the space; event
//! settings marked produced or consumed become the node's events ([`Board::events`]), so that
//! what the node answers and reports is what the configuration holds; [`Board::factory_reset`]
//! writes the declared defaults.
//!
//! A whole board on a host, with its file-backed space and its events following the
//! configuration at Update Complete, is `openlcb-tokio`'s `examples/io_board.rs`. A firmware
//! short of RAM declares its settings in a function and hands it to [`Board::declare`]: its
//! [`CdiSpace`] renders the XML on each read from that function, so that no copy of it is
//! kept (the Cortex-M0 board in `examples/cortex-m0` does so).
//!
//! Why a builder and not a derive macro: a builder is plain code (no proc-macro crate, no
//! `syn` in a firmware's build), its replicated groups come out as a `Vec` of the same
//! struct, and the offsets are computed as the XML is written, by the same calls, so they
//! cannot disagree.
//!
//! ```
//! use openlcb_node::board::{BoardBuilder, EventRole};
//! use openlcb_node::{MemorySpace, RamSpace, SnipInfo};
//! use openlcb_stream::EventId;
//!
//! struct Line { mode: openlcb_node::board::IntSetting, on: openlcb_node::board::EventSetting }
//! let mut config = BoardBuilder::new("Settings");
//! let name = config.string("Board name", 16, "north yard");
//! let lines: Vec<Line> = config.group("Line", 4, |g, i| Line {
//!     mode: g.int("Mode", 1, 0, &[(0, "Input"), (1, "Output")]),
//!     on: g.event("Event On", EventRole::Produced, EventId(0x0501_0101_2200_0000 + i as u64)),
//! });
//! let board = config.finish(&SnipInfo::default());
//! assert!(board.cdi().contains("<group replication=\"4\"><name>Line</name>"));
//! assert_eq!(lines[2].on.address(), 16 + 2 * 9 + 1);
//!
//! let mut space = RamSpace::new(board.len());
//! board.factory_reset(&mut space).unwrap();
//! assert_eq!(name.read(&mut space).unwrap(), "north yard");
//! assert_eq!(lines[3].on.read(&mut space).unwrap(), EventId(0x0501_0101_2200_0003));
//! lines[1].mode.write(&mut space, 1).unwrap();
//! assert_eq!(board.events(&mut space).produced.len(), 4);
//! ```

use alloc::string::String;
use alloc::vec::Vec;

use openlcb_stream::EventId;

use crate::memconfig::{MemorySpace, SpaceError};
use crate::{DeclaredEvents, EventConfig, EventState, SnipInfo};

/// What the node does with an event setting's Event ID.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum EventRole {
    /// It produces it (an input's event).
    Produced,
    /// It consumes it (an output's event).
    Consumed,
}

/// An integer setting of `size` bytes (1, 2, 4 or 8), big-endian.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct IntSetting {
    address: u32,
    size: u8,
}

/// A string setting of `size` bytes, NUL-padded UTF-8.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct StringSetting {
    address: u32,
    size: u32,
}

/// An Event ID setting (8 bytes).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct EventSetting {
    address: u32,
}

impl IntSetting {
    /// Its address in space 0xFD.
    pub fn address(self) -> u32 {
        self.address
    }

    /// The value the space holds.
    pub fn read(self, space: &mut (impl MemorySpace + ?Sized)) -> Result<u64, SpaceError> {
        let mut bytes = [0u8; 8];
        let len = usize::from(self.size);
        let got = space.read(self.address, bytes.get_mut(..len).unwrap_or_default())?;
        if got != len {
            return Err(SpaceError::OutOfBounds);
        }
        Ok(bytes.get(..len).unwrap_or_default().iter().fold(0, |v, b| v << 8 | u64::from(*b)))
    }

    /// Writes `value` (its low bytes, as many as the setting has).
    pub fn write(self, space: &mut (impl MemorySpace + ?Sized), value: u64) -> Result<(), SpaceError> {
        let bytes = value.to_be_bytes();
        space.write(self.address, bytes.get(8 - usize::from(self.size)..).unwrap_or_default())
    }
}

impl StringSetting {
    /// Its address in space 0xFD.
    pub fn address(self) -> u32 {
        self.address
    }

    /// The text the space holds, to its first NUL (bytes that are not UTF-8 are replaced).
    pub fn read(self, space: &mut (impl MemorySpace + ?Sized)) -> Result<String, SpaceError> {
        let mut bytes = alloc::vec![0u8; self.size as usize];
        let got = space.read(self.address, &mut bytes)?;
        bytes.truncate(got);
        let end = bytes.iter().position(|b| *b == 0).unwrap_or(bytes.len());
        Ok(String::from_utf8_lossy(bytes.get(..end).unwrap_or_default()).into_owned())
    }

    /// Writes `text`, cut to the setting's size less its NUL, NUL-padded.
    pub fn write(self, space: &mut (impl MemorySpace + ?Sized), text: &str) -> Result<(), SpaceError> {
        space.write(self.address, &padded(text, self.size))
    }
}

impl EventSetting {
    /// Its address in space 0xFD.
    pub fn address(self) -> u32 {
        self.address
    }

    /// The Event ID the space holds.
    pub fn read(self, space: &mut (impl MemorySpace + ?Sized)) -> Result<EventId, SpaceError> {
        let mut bytes = [0u8; 8];
        if space.read(self.address, &mut bytes)? != 8 {
            return Err(SpaceError::OutOfBounds);
        }
        Ok(EventId::from_bytes(bytes))
    }

    /// Writes `event`.
    pub fn write(self, space: &mut (impl MemorySpace + ?Sized), event: EventId) -> Result<(), SpaceError> {
        space.write(self.address, &event.to_bytes())
    }
}

/// Appends `text` in `size` bytes: cut at a character boundary to leave room for a NUL,
/// NUL-padded.
fn push_padded(out: &mut Vec<u8>, text: &str, size: u32) {
    let room = (size as usize).saturating_sub(1);
    let mut end = text.len().min(room);
    while !text.is_char_boundary(end) {
        end -= 1;
    }
    out.extend_from_slice(text.as_bytes().get(..end).unwrap_or_default());
    out.resize(out.len() + size as usize - end, 0);
}

/// `text` in `size` bytes, as [`push_padded`] lays it out.
fn padded(text: &str, size: u32) -> Vec<u8> {
    let mut bytes = Vec::with_capacity(size as usize);
    push_padded(&mut bytes, text, size);
    bytes
}

/// Where the builder's XML goes: every byte is counted, and those from `from` on are kept, up
/// to `limit` of them. The whole CDI ([`BoardBuilder::finish`]) keeps all from 0; a read of
/// a [`CdiSpace`] keeps the bytes it asks for; a layout keeps none.
#[derive(Debug)]
struct Sink {
    at: u32,
    from: u32,
    limit: usize,
    out: Vec<u8>,
}

impl Sink {
    /// Keeps everything.
    fn whole() -> Self {
        Sink { at: 0, from: 0, limit: usize::MAX, out: Vec::new() }
    }

    /// Keeps up to `limit` bytes from `from`.
    fn window(from: u32, limit: usize) -> Self {
        Sink { at: 0, from, limit, out: Vec::with_capacity(limit) }
    }

    fn push(&mut self, bytes: &[u8]) {
        let skip = self.from.saturating_sub(self.at) as usize;
        if let Some(tail) = bytes.get(skip..) {
            let room = self.limit - self.out.len();
            self.out.extend_from_slice(tail.get(..room.min(tail.len())).unwrap_or_default());
        }
        self.at = self.at.saturating_add(bytes.len() as u32);
    }

    fn push_str(&mut self, text: &str) {
        self.push(text.as_bytes());
    }

    /// Character data, escaped (the markup characters are ASCII: what lies between them is
    /// whole characters).
    fn push_escaped(&mut self, text: &str) {
        let bytes = text.as_bytes();
        let mut plain = 0;
        for (i, byte) in bytes.iter().enumerate() {
            let escape = match byte {
                b'&' => "&amp;",
                b'<' => "&lt;",
                b'>' => "&gt;",
                _ => continue,
            };
            self.push(bytes.get(plain..i).unwrap_or_default());
            self.push_str(escape);
            plain = i + 1;
        }
        self.push(bytes.get(plain..).unwrap_or_default());
    }

    /// `value` in decimal, by subtracting powers of ten: no formatting machinery and no 64-bit
    /// division, which a Cortex-M0 does in library code (about 2 KiB of flash between them).
    fn push_decimal(&mut self, mut value: u64) {
        let mut started = false;
        let mut power = 1u64;
        let powers: [u64; 20] = core::array::from_fn(|_| {
            let this = power;
            power = power.wrapping_mul(10);
            this
        });
        for (i, power) in powers.iter().enumerate().rev() {
            let mut digit = b'0';
            while value >= *power {
                value -= power;
                digit += 1;
            }
            if digit != b'0' || started || i == 0 {
                started = true;
                self.push(&[digit]);
            }
        }
    }

    /// The CDI before the configuration segment: the identification (from `snip`), the ACDI,
    /// the user name and description.
    fn push_prologue(&mut self, snip: &SnipInfo) {
        self.push_str(
            "<?xml version=\"1.0\" encoding=\"utf-8\"?>\n<cdi xmlns:xsi=\"http://www.w3.org/2001/XMLSchema-instance\" \
             xsi:noNamespaceSchemaLocation=\"http://openlcb.org/schema/cdi/1/4/cdi.xsd\">\n<identification>",
        );
        for (tag, value) in [
            ("manufacturer", &snip.manufacturer),
            ("model", &snip.model),
            ("hardwareVersion", &snip.hardware_version),
            ("softwareVersion", &snip.software_version),
        ] {
            for piece in ["<", tag, ">"] {
                self.push_str(piece);
            }
            self.push_escaped(value);
            for piece in ["</", tag, ">"] {
                self.push_str(piece);
            }
        }
        self.push_str(
            "</identification>\n<acdi/>\n<segment space=\"251\" origin=\"1\"><name>User identification</name>\
             <string size=\"63\"><name>User name</name></string>\
             <string size=\"64\"><name>User description</name></string></segment>\n",
        );
    }

    /// The start of the configuration segment, named `name`.
    fn push_segment(&mut self, name: &str) {
        self.push_str("<segment space=\"253\" origin=\"0\"><name>");
        self.push_escaped(name);
        self.push_str("</name>\n");
    }

    /// The CDI after the last setting.
    fn push_epilogue(&mut self) {
        self.push_str("</segment>\n</cdi>\n");
    }
}

/// Writes the settings of the configuration segment (and of a group, inside it) and works
/// out their addresses.
#[derive(Debug)]
pub struct BoardBuilder {
    xml: Sink,
    address: u32,
    /// The factory value of every byte of the settings so far (they lie end to end from 0).
    defaults: Vec<u8>,
    events: Vec<(EventSetting, EventRole)>,
    /// Only the XML is wanted (a [`CdiSpace`] read): no defaults or events are kept.
    render_only: bool,
    /// While a group's second and later replications are laid out, their XML is not written.
    quiet: bool,
}

impl BoardBuilder {
    /// The configuration segment (space 0xFD from address 0), named `name` in the CDI.
    pub fn new(name: &str) -> Self {
        let mut xml = Sink::whole();
        xml.push_segment(name);
        Self::writing(xml, false, false)
    }

    /// A builder at address 0 writing into `xml` (none at all while `quiet`), keeping the
    /// layout (defaults and events) unless `render_only`.
    fn writing(xml: Sink, render_only: bool, quiet: bool) -> Self {
        BoardBuilder { xml, address: 0, defaults: Vec::new(), events: Vec::new(), render_only, quiet }
    }

    /// Writes `pieces` in turn, each markup to copy, text to escape or a number. Nothing while
    /// a replication after the first is laid out.
    fn element(&mut self, pieces: &[Xml<'_>]) {
        if self.quiet {
            return;
        }
        for piece in pieces {
            match piece {
                Xml::Markup(markup) => self.xml.push_str(markup),
                Xml::Text(text) => self.xml.push_escaped(text),
                Xml::Number(value) => self.xml.push_decimal(*value),
            }
        }
    }

    /// Moves on past a setting of `size` bytes whose factory value `default` lays out.
    fn advance(&mut self, size: u32, default: impl FnOnce(&mut Vec<u8>)) {
        if !self.render_only {
            default(&mut self.defaults);
        }
        self.address += size;
    }

    /// An integer of `size` bytes (1, 2, 4 or 8) with its factory value and, if not empty, a
    /// map of values to labels (a select in a tool).
    pub fn int(&mut self, name: &str, size: u8, default: u64, map: &[(u64, &str)]) -> IntSetting {
        let size = match size {
            1 | 2 | 4 | 8 => size,
            _ => 1,
        };
        use Xml::{Markup, Number, Text};
        self.element(&[Markup("<int size=\""), Number(size.into()), Markup("\"><name>"), Text(name)]);
        self.element(&[Markup("</name><default>"), Number(default), Markup("</default>")]);
        if !map.is_empty() {
            self.element(&[Markup("<map>")]);
            for (value, label) in map {
                self.element(&[
                    Markup("<relation><property>"),
                    Number(*value),
                    Markup("</property><value>"),
                    Text(label),
                    Markup("</value></relation>"),
                ]);
            }
            self.element(&[Markup("</map>")]);
        }
        self.element(&[Markup("</int>\n")]);
        let setting = IntSetting { address: self.address, size };
        self.advance(size.into(), |defaults| {
            defaults.extend_from_slice(default.to_be_bytes().get(8 - usize::from(size)..).unwrap_or_default())
        });
        setting
    }

    /// A string of `size` bytes (its NUL included) with its factory value.
    pub fn string(&mut self, name: &str, size: u32, default: &str) -> StringSetting {
        use Xml::{Markup, Number, Text};
        self.element(&[
            Markup("<string size=\""),
            Number(size.into()),
            Markup("\"><name>"),
            Text(name),
            Markup("</name></string>\n"),
        ]);
        let setting = StringSetting { address: self.address, size };
        self.advance(size, |defaults| push_padded(defaults, default, size));
        setting
    }

    /// An Event ID the node produces or consumes, with its factory value.
    pub fn event(&mut self, name: &str, role: EventRole, default: EventId) -> EventSetting {
        self.element(&[Xml::Markup("<eventid><name>"), Xml::Text(name), Xml::Markup("</name></eventid>\n")]);
        let setting = EventSetting { address: self.address };
        if !self.render_only {
            self.events.push((setting, role));
        }
        self.advance(8, |defaults| defaults.extend_from_slice(&default.to_bytes()));
        setting
    }

    /// A group replicated `count` times (`count` 1: a plain group), its settings declared by
    /// `settings` (called once per replication, with its index): the handles of each.
    /// A tool labels the copies `name 1`, `name 2` and so on.
    pub fn group<T>(&mut self, name: &str, count: u32, settings: impl FnMut(&mut Self, u32) -> T) -> Vec<T> {
        self.replicated(name, &[Xml::Text(name), Xml::Markup(" 1")], count, settings)
    }

    /// A group replicated `count` times whose first copy a tool labels `first` and counts on
    /// from its number (the CDI standard increments a repname ending in digits): `"F0"` labels
    /// the copies F0, F1, F2 and so on. Otherwise as [`group`](Self::group).
    pub fn numbered_group<T>(
        &mut self,
        name: &str,
        first: &str,
        count: u32,
        settings: impl FnMut(&mut Self, u32) -> T,
    ) -> Vec<T> {
        self.replicated(name, &[Xml::Text(first)], count, settings)
    }

    /// A group replicated `count` times, `repname` labelling its first copy.
    fn replicated<T>(
        &mut self,
        name: &str,
        repname: &[Xml<'_>],
        count: u32,
        mut settings: impl FnMut(&mut Self, u32) -> T,
    ) -> Vec<T> {
        use Xml::{Markup, Number, Text};
        let count = count.max(1);
        self.element(&[Markup("<group replication=\""), Number(count.into()), Markup("\"><name>"), Text(name)]);
        if count > 1 {
            self.element(&[Markup("</name><repname>")]);
            self.element(repname);
            self.element(&[Markup("</repname>\n")]);
        } else {
            self.element(&[Markup("</name>\n")]);
        }
        let outer = self.quiet;
        let mut groups = Vec::with_capacity(count as usize);
        for index in 0..count {
            groups.push(settings(self, index));
            self.quiet = true;
        }
        self.quiet = outer;
        self.element(&[Markup("</group>\n")]);
        groups
    }

    /// The board: the whole CDI (identification from `snip`, ACDI, the user name and
    /// description, this segment), its size and defaults.
    pub fn finish(self, snip: &SnipInfo) -> Board {
        let mut cdi = Sink::whole();
        cdi.push_prologue(snip);
        cdi.push(&self.xml.out);
        cdi.push_epilogue();
        // Every piece was a `str`: the bytes are UTF-8.
        let cdi = String::from_utf8(cdi.out).unwrap_or_default();
        Board { cdi, len: self.address, defaults: self.defaults, events: self.events }
    }
}

/// A piece of an element the builder writes.
enum Xml<'a> {
    /// Copied as it is.
    Markup(&'a str),
    /// Character data, escaped.
    Text(&'a str),
    /// A number in decimal.
    Number(u64),
}

/// A board's configuration: its CDI, the size of its space 0xFD, its defaults and its event
/// settings ([`BoardBuilder::finish`], or [`Board::declare`] with no CDI kept).
#[derive(Debug, Clone)]
pub struct Board {
    cdi: String,
    len: u32,
    defaults: Vec<u8>,
    events: Vec<(EventSetting, EventRole)>,
}

impl Board {
    /// A board declared by `declare` (its settings in space 0xFD, named `name` in the CDI),
    /// for a firmware: the board and the handles `declare` returns, and its CDI as a space
    /// that renders the XML on demand ([`CdiSpace`]), so that neither RAM nor flash holds it.
    /// The board's [`cdi`](Self::cdi) is empty.
    pub fn declare<T>(
        name: &'static str,
        snip: &SnipInfo,
        declare: fn(&mut BoardBuilder) -> T,
    ) -> (Board, T, CdiSpace<T>) {
        // The layout only: no XML is written.
        let mut builder = BoardBuilder::writing(Sink::window(u32::MAX, 0), false, true);
        let handles = declare(&mut builder);
        let board =
            Board { cdi: String::new(), len: builder.address, defaults: builder.defaults, events: builder.events };
        let mut space = CdiSpace { name, snip: snip.clone(), declare, len: 0 };
        space.len = space.render(u32::MAX, 0).0;
        (board, handles, space)
    }

    /// The CDI XML (serve it as space 0xFF: [`ReadOnlySpace::cdi`](crate::ReadOnlySpace::cdi));
    /// empty for a board from [`Board::declare`], whose [`CdiSpace`] renders it.
    pub fn cdi(&self) -> &str {
        &self.cdi
    }

    /// Moves the CDI out, as the content of space 0xFF, without a copy. [`cdi`](Self::cdi)
    /// is empty afterwards; the settings, defaults and events are kept.
    pub fn take_cdi_space(&mut self) -> crate::ReadOnlySpace {
        let mut bytes = core::mem::take(&mut self.cdi).into_bytes();
        bytes.reserve_exact(1);
        bytes.push(0);
        bytes.shrink_to_fit();
        crate::ReadOnlySpace::new(bytes)
    }

    /// The bytes of space 0xFD the settings take.
    pub fn len(&self) -> u32 {
        self.len
    }

    /// No settings at all.
    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// Writes every setting's factory value (a Factory Reset), then commits the space.
    pub fn factory_reset(&self, space: &mut (impl MemorySpace + ?Sized)) -> Result<(), SpaceError> {
        space.write(0, &self.defaults)?;
        space.commit()
    }

    /// The node's events as `space` holds them now: each event setting produced or consumed
    /// as declared (settings of all zeros or all ones are unset, and left out).
    pub fn events(&self, space: &mut (impl MemorySpace + ?Sized)) -> EventConfig {
        let mut events = EventConfig::default();
        for (setting, role) in &self.events {
            let Ok(event) = setting.read(space) else { continue };
            if event.0 == 0 || event.0 == u64::MAX {
                continue;
            }
            let declared = DeclaredEvents::single(event, EventState::Unknown);
            match role {
                EventRole::Produced => events.produced.push(declared),
                EventRole::Consumed => events.consumed.push(declared),
            }
        }
        events
    }
}

/// The CDI of a board declared with [`Board::declare`], as space 0xFF: each read runs the
/// declaration again and keeps only the bytes it asks for. Neither RAM nor flash holds the
/// XML (1 083 B for the Cortex-M0 example's eight lines, and the copies a build of it
/// makes); a read costs the time to write the CDI up to its end, once.
/// The bytes are those [`BoardBuilder::finish`] writes for the same declaration, then the
/// NUL that ends a CDI (CDI §5.1).
pub struct CdiSpace<T> {
    name: &'static str,
    snip: SnipInfo,
    declare: fn(&mut BoardBuilder) -> T,
    len: u32,
}

impl<T> core::fmt::Debug for CdiSpace<T> {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.debug_struct("CdiSpace").field("name", &self.name).field("len", &self.len).finish_non_exhaustive()
    }
}

impl<T> CdiSpace<T> {
    /// Writes the whole CDI and its NUL, keeping up to `want` bytes from `from`: the length
    /// of it all and the bytes kept.
    fn render(&self, from: u32, want: usize) -> (u32, Vec<u8>) {
        let mut xml = Sink::window(from, want);
        xml.push_prologue(&self.snip);
        xml.push_segment(self.name);
        let mut builder = BoardBuilder::writing(xml, true, false);
        (self.declare)(&mut builder);
        builder.xml.push_epilogue();
        builder.xml.push(&[0]);
        (builder.xml.at, builder.xml.out)
    }
}

impl<T> MemorySpace for CdiSpace<T> {
    fn len(&self) -> u32 {
        self.len
    }

    fn read_only(&self) -> bool {
        true
    }

    fn read(&mut self, address: u32, buf: &mut [u8]) -> Result<usize, SpaceError> {
        if address > self.len {
            return Err(SpaceError::OutOfBounds);
        }
        let (_, bytes) = self.render(address, buf.len());
        Ok(crate::memconfig::copy_prefix(buf, &bytes))
    }

    fn write(&mut self, _address: u32, _data: &[u8]) -> Result<(), SpaceError> {
        Err(SpaceError::ReadOnly)
    }
}
