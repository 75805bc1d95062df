//! CDIs shaped like real products: addresses, keys, values and backups.

use openlcb_cdi::backup::{self, Snapshot};
use openlcb_cdi::{Cdi, EntryKind, Error, Layout, Value, ValueError};

const IO16: &str = include_str!("cdi/io16.xml");
const SIGNAL: &str = include_str!("cdi/signal.xml");
const ORIGINS: &str = include_str!("cdi/origins.xml");

fn at(layout: &Layout, key: &str) -> (u8, u32, u32) {
    let entry = layout.find(key).next().unwrap_or_else(|| panic!("no {key}"));
    (entry.space, entry.address, entry.size)
}

/// One line is 16 + 1 + 8 + 8 + 2 (offset) + 2 * 2 = 39 bytes.
#[test]
fn io_board_lines_and_nested_pulses_lie_where_jmri_puts_them() {
    let layout = Layout::parse(IO16).unwrap();
    assert_eq!(at(&layout, "Node ID.Node Name"), (251, 1, 63));
    assert_eq!(at(&layout, "Node ID.Node Description"), (251, 64, 64));
    assert_eq!(at(&layout, "Settings.Debounce (ms)"), (253, 0, 2));
    assert_eq!(at(&layout, "Settings.Line(0).Label"), (253, 2, 16));
    assert_eq!(at(&layout, "Settings.Line(0).Event On"), (253, 19, 8));
    assert_eq!(at(&layout, "Settings.Line(0).Event Off"), (253, 27, 8));
    assert_eq!(at(&layout, "Settings.Line(0).Pulse(0).Width (ms)"), (253, 37, 2));
    assert_eq!(at(&layout, "Settings.Line(0).Pulse(1).Width (ms)"), (253, 39, 2));
    assert_eq!(at(&layout, "Settings.Line(15).Event Off"), (253, 2 + 15 * 39 + 25, 8));
    assert_eq!(at(&layout, "Settings.Line(15).Pulse(1).Width (ms)"), (253, 2 + 15 * 39 + 37, 2));
    assert_eq!(at(&layout, "Settings.Version"), (253, 2 + 16 * 39, 1));
    let events = layout.entries().filter(|e| e.kind == EntryKind::EventId).count();
    assert_eq!(events, 32, "two events per line");
    assert_eq!(layout.entries().count(), 2 + 1 + 16 * 6 + 1);
    let spans = layout.spans();
    assert_eq!(spans.len(), 2);
    assert_eq!((spans[1].space, spans[1].address, spans[1].len), (253, 0, 2 + 16 * 39 + 1));
}

#[test]
fn repnames_number_the_copies() {
    let layout = Layout::parse(IO16).unwrap();
    let Some(openlcb_cdi::Laid::Group(lines)) = layout.segments[1].children.get(1) else { panic!() };
    let labels: Vec<_> = lines
        .children
        .iter()
        .map(|c| match c {
            openlcb_cdi::Laid::Group(g) => g.label.clone().unwrap(),
            openlcb_cdi::Laid::Entry(_) => unreachable!(),
        })
        .collect();
    assert_eq!(labels[0], "Line 1");
    assert_eq!(labels[15], "Line 16");
    assert_eq!(openlcb_cdi::repname(&["On".into(), "Off".into()], 2, 2), "Off");
    assert_eq!(openlcb_cdi::repname(&["Aspect".into()], 3, 8), "Aspect3");
    assert_eq!(openlcb_cdi::repname(&["A".into(), "B 7".into()], 4, 8), "B 9");
}

/// Unnamed segments and items take their index among the parent's child nodes, text and
/// comments included (JDOM's `indexOf`); offsets go back and forth; a `<bit>` moves on by
/// its offset only.
#[test]
fn origins_unnamed_items_and_negative_offsets() {
    let layout = Layout::parse(ORIGINS).unwrap();
    assert_eq!(at(&layout, "User Info.User Name"), (251, 1, 63));
    assert_eq!(at(&layout, "seg7.Serial Number"), (253, 4096, 4));
    assert_eq!(at(&layout, "seg7.Network.Upstream Node"), (253, 4112, 8));
    assert_eq!(at(&layout, "seg7.Network.Port"), (253, 4110, 2));
    assert_eq!(at(&layout, "seg7.Network.child6"), (253, 4120, 1));
    assert_eq!(at(&layout, "seg7.child7(0).Stop"), (253, 4124, 8));
    assert_eq!(at(&layout, "seg7.child7(1).Name"), (253, 4124 + 40 + 8, 32));
    let spans = layout.spans();
    assert_eq!((spans[1].address, spans[1].len), (4096, 4204 - 4096));
    let cdi = Cdi::parse(ORIGINS).unwrap();
    assert!(cdi.acdi);
    assert_eq!(cdi.identification.unwrap().model.as_deref(), Some("Throttle Bridge"));
}

#[test]
fn signal_head_maps_take_labels_or_values() {
    let layout = Layout::parse(SIGNAL).unwrap();
    let lamps = layout.find("Head.Aspect(2).Lamps").next().unwrap();
    assert_eq!(lamps.parse_strict("Green").unwrap(), (Value::Int(4), vec![4]));
    assert_eq!(lamps.parse_strict("green").unwrap().0, Value::Int(4), "labels ignore case when unambiguous");
    assert_eq!(lamps.parse_strict("3").unwrap().0, Value::Int(3));
    assert!(matches!(lamps.parse_strict("5"), Err(ValueError::NotInMap { .. })));
    assert!(matches!(lamps.parse_strict("Blue"), Err(ValueError::Unparsable { .. })));
    assert_eq!(lamps.label(&Value::Int(3)), Some("Red over yellow"));
    let brightness = layout.find("Head.Brightness").next().unwrap();
    assert!(matches!(brightness.parse_strict("101"), Err(ValueError::OutOfRange { .. })));
    assert_eq!(brightness.parse_strict("100").unwrap().1, [100]);
    let fade = layout.find("Head.Fade (s)").next().unwrap();
    assert_eq!(fade.parse_strict("1.5").unwrap().1, 1.5f32.to_be_bytes());
    assert!(fade.parse_strict("5.5").is_err());
    let flash = layout.find("Head.Flash rate (Hz)").next().unwrap();
    assert_eq!(flash.parse_strict("2").unwrap().1, [0x40, 0x00], "IEEE half");
    assert_eq!(flash.decode(&[0x3C, 0x00]).unwrap(), Value::Float(1.0));
    assert!(flash.parse_strict("70000").is_err(), "beyond a half's range");
    assert_eq!(at(&layout, "Head.Test lamps"), (253, 8 + 8 * 10 + 4, 1));
}

#[test]
fn values_encode_and_decode() {
    let layout = Layout::parse(ORIGINS).unwrap();
    let upstream = layout.find("seg7.Network.Upstream Node").next().unwrap();
    let bytes = [0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0xFE];
    assert_eq!(upstream.decode(&bytes).unwrap(), Value::Int(-2), "8 bytes read as Java's long");
    assert_eq!(upstream.encode(&Value::Int(-2)).unwrap(), bytes);
    assert_eq!(upstream.parse("0xFFFFFFFFFFFFFFFE").unwrap(), Value::Int(-2));
    let serial = layout.find("seg7.Serial Number").next().unwrap();
    assert_eq!(serial.decode(&[0x80, 0, 0, 1]).unwrap(), Value::Int(0x8000_0001), "unsigned below 8 bytes");
    assert!(serial.encode(&Value::Int(-1)).is_err());
    assert!(serial.encode(&Value::Int(1 << 32)).is_err());
    let stop = layout.find("seg7.child7(0).Stop").next().unwrap();
    let id = [5, 1, 1, 1, 0x22, 0xF2, 0, 0x0A];
    assert_eq!(stop.parse("05.01.01.01.22.F2.00.0A").unwrap(), Value::EventId(id));
    assert_eq!(stop.parse("5.1.1.1.22.f2.0.a").unwrap(), Value::EventId(id));
    assert_eq!(stop.parse("0501010122F2000A").unwrap(), Value::EventId(id));
    assert!(stop.parse("05.01.01.01.22.F2.00").is_err());
    assert_eq!(Value::EventId(id).to_string(), "05.01.01.01.22.F2.00.0A");
    let name = layout.find("seg7.child7(1).Name").next().unwrap();
    let mut expected = b"Cab 2".to_vec();
    expected.resize(32, 0);
    assert_eq!(name.encode(&Value::String("Cab 2".into())).unwrap(), expected, "NUL-padded to its size");
    assert_eq!(name.decode(&expected).unwrap(), Value::String("Cab 2".into()));
    assert!(matches!(name.encode(&Value::String("x".repeat(32))), Err(ValueError::TooLong { .. })));
    assert!(name.encode(&Value::String("x".repeat(31))).is_ok());
    assert!(matches!(name.encode(&Value::Int(1)), Err(ValueError::WrongType { .. })));
}

#[test]
fn bad_documents_are_typed_errors() {
    assert!(matches!(Layout::parse("<cdi><segment>"), Err(Error::Xml { .. })));
    assert!(matches!(Layout::parse("<cdi><segment space='x'/></cdi>"), Err(Error::BadNumber { .. })));
    let overlap = "<cdi><segment space='253'><int size='4'><name>A</name></int><int size='1' offset='-2'><name>B</name></int></segment></cdi>";
    assert_eq!(Layout::parse(overlap), Err(Error::Overlap { first: "seg0.A".into(), second: "seg0.B".into() }));
    let before = "<cdi><segment space='253'><int offset='-1'><name>A</name></int></segment></cdi>";
    assert!(matches!(Layout::parse(before), Err(Error::OutsideSpace { address: -1, .. })));
    let past = "<cdi><segment space='253' origin='4294967295'><int size='2'/></segment></cdi>";
    assert!(matches!(Layout::parse(past), Err(Error::OutsideSpace { .. })));
    let huge = "<cdi><segment space='253'><group replication='100000'><group replication='100000'><int/></group></group></segment></cdi>";
    assert_eq!(Layout::parse(huge), Err(Error::TooManyEntries));
    let deep = format!("<cdi><segment>{}{}</segment></cdi>", "<group>".repeat(40), "</group>".repeat(40));
    assert_eq!(Layout::parse(&deep), Err(Error::TooDeep));
    assert!(
        Layout::parse("<cdi><segment space='253'><int size='4'/></segment></cdi>\0\0garbage").is_ok(),
        "the NUL ends it"
    );
}

fn snapshot(layout: &Layout, fill: impl Fn(usize) -> u8) -> Snapshot {
    let mut snapshot = Snapshot::new();
    for span in layout.spans() {
        snapshot.insert(span, (0..span.len as usize).map(&fill).collect());
    }
    snapshot
}

#[test]
fn backup_lines_escape_and_restore_plans_only_differences() {
    let layout = Layout::parse(IO16).unwrap();
    let mut snap = snapshot(&layout, |_| 0);
    let text = backup::write(&layout, &snap).unwrap();
    assert_eq!(text.lines().count(), 2 + 1 + 16 * 6 + 1);
    assert!(text.starts_with(
        "Node ID.Node Name=\nNode ID.Node Description=\nSettings.Debounce (ms)=0\nSettings.Line(0).Label=\n"
    ));
    let mut names = b"a=b\\c\x01".to_vec();
    names.resize(127, 0);
    let mut settings = vec![0; layout.spans()[1].len as usize];
    settings[1] = 20; // Debounce: 20 ms, within 1..500
    snap = Snapshot::new();
    snap.insert(layout.spans()[0], names);
    snap.insert(layout.spans()[1], settings);
    let text = backup::write(&layout, &snap).unwrap();
    assert!(text.starts_with("Node ID.Node Name=a\\x003db\\x005cc\\x0001\n"), "{text}");
    let lines = backup::parse(&text).unwrap();
    assert_eq!(lines[0].value, "a=b\\c\x01");
    let plan = backup::plan(&layout, &snap, &lines).unwrap();
    assert!(plan.writes.is_empty() && plan.unknown_keys.is_empty() && plan.invalid.is_empty());
    let edited = text
        .replace("Settings.Line(3).Function=0", "Settings.Line(3).Function=2")
        .replace("Settings.Version=0", "Settings.Old=1");
    let plan = backup::plan(&layout, &snap, &backup::parse(&edited).unwrap()).unwrap();
    assert_eq!(plan.writes.len(), 1);
    assert_eq!((plan.writes[0].entry.address, plan.writes[0].bytes.as_slice()), (2 + 3 * 39 + 16, [2u8].as_slice()));
    assert_eq!(plan.unknown_keys, ["Settings.Old"]);
    let bad = text.replace("Settings.Debounce (ms)=20", "Settings.Debounce (ms)=600");
    let plan = backup::plan(&layout, &snap, &backup::parse(&bad).unwrap()).unwrap();
    assert_eq!(plan.invalid.len(), 1);
    assert!(matches!(backup::parse("# comment\n\nno equals sign\n"), Err(Error::BackupLine { line: 3 })));
}

#[test]
fn a_duplicate_line_is_named_with_both_line_numbers_and_a_byte_order_mark_is_no_part_of_a_key() {
    let layout = Layout::parse(IO16).unwrap();
    let snap = snapshot(&layout, |_| 0);
    let text =
        "\u{feff}Settings.Debounce (ms)=20\n# a comment\nSettings.Line(2).Function=1\nSettings.Debounce (ms)=30\n";
    let lines = backup::parse(text).unwrap();
    assert_eq!(lines[0].key, "Settings.Debounce (ms)");
    let plan = backup::plan(&layout, &snap, &lines).unwrap();
    assert!(plan.unknown_keys.is_empty(), "{:?}", plan.unknown_keys);
    let duplicate = backup::Duplicate { key: "Settings.Debounce (ms)".into(), first_line: 1, line: 4 };
    assert_eq!(plan.duplicates, [duplicate]);
    // A key the CDI has twice takes two lines, and neither is a duplicate.
    let twice = "Node ID.Node Name=a\nSettings.Line(0).Label=x\nSettings.Line(1).Label=y\n";
    let plan = backup::plan(&layout, &snap, &backup::parse(twice).unwrap()).unwrap();
    assert!(plan.duplicates.is_empty());
    // A whole backup fits in the bound, with room for as much again.
    let whole = backup::write(&layout, &snapshot(&layout, |_| 0xFF)).unwrap();
    assert!(whole.len() * 2 < backup::max_backup_bytes(&layout));
}

#[test]
fn neighbouring_writes_are_joined() {
    let layout = Layout::parse(IO16).unwrap();
    let snap = snapshot(&layout, |_| 0);
    let text = "Settings.Line(0).Event On=01.02.03.04.05.06.07.08\nSettings.Line(0).Event Off=01.02.03.04.05.06.07.09\nSettings.Line(2).Function=1\n";
    let plan = backup::plan(&layout, &snap, &backup::parse(text).unwrap()).unwrap();
    let runs = backup::coalesce(&plan.writes);
    assert_eq!(runs.len(), 2);
    assert_eq!((runs[0].0, runs[0].1, runs[0].2.len()), (253, 19, 16));
}

#[test]
fn escaping_matches_jmri() {
    assert_eq!(backup::escape("a=b"), "a\\x003db");
    assert_eq!(backup::escape("tab\there"), "tab\\x0009here");
    assert_eq!(backup::escape("\u{AD}soft"), "\\x00adsoft", "format characters");
    assert_eq!(backup::escape("\u{E000}"), "\\xe000", "private use");
    assert_eq!(backup::escape("Grüße €"), "Grüße €");
    assert_eq!(backup::unescape("\\x003d\\x00"), "=\\x00", "a short escape stays as it is");
    assert_eq!(backup::unescape("\\xzzzz"), "\\xzzzz");
}

/// The image the JMRI files in `tests/cdi` were made from: byte `i` of each space is
/// `(37 i + 11) mod 256`, and 0 at every 19th (see `tests/cdi/README.md`).
fn jmri_image(address: usize) -> u8 {
    if address.is_multiple_of(19) { 0 } else { ((address * 37 + 11) % 256) as u8 }
}

/// The layouts and backups OpenLCB_Java's own `ConfigRepresentation` and `BackupConfig`
/// made from these CDIs and that image, line for line and byte for byte.
#[test]
fn layouts_and_backups_are_jmris() {
    let cases = [
        (IO16, include_str!("cdi/io16.jmri-layout.txt"), include_str!("cdi/io16.jmri-backup.txt")),
        (SIGNAL, include_str!("cdi/signal.jmri-layout.txt"), include_str!("cdi/signal.jmri-backup.txt")),
        (ORIGINS, include_str!("cdi/origins.jmri-layout.txt"), include_str!("cdi/origins.jmri-backup.txt")),
    ];
    for (xml, jmri_layout, jmri_backup) in cases {
        let layout = Layout::parse(xml).unwrap();
        let ours: String =
            layout.entries().map(|e| format!("{}\t{}\t{}\t{}\n", e.key, e.space, e.address, e.size)).collect();
        assert_eq!(ours, jmri_layout);
        let mut snap = Snapshot::new();
        for span in layout.spans() {
            snap.insert(span, (span.address..span.address + span.len).map(|a| jmri_image(a as usize)).collect());
        }
        assert_eq!(backup::write(&layout, &snap).unwrap(), jmri_backup);
        let plan = backup::plan(&layout, &snap, &backup::parse(jmri_backup).unwrap()).unwrap();
        assert!(plan.unknown_keys.is_empty());
        assert!(plan.writes.iter().all(|c| c.old == c.new), "nothing to change but strings JMRI cut");
    }
}

/// An erased string (all 0xFF, no NUL: OpenMRN's io_board has such) decodes to replacement
/// characters longer than the entry; its own backup line is no change, not an error.
#[test]
fn a_backup_of_erased_strings_restores_as_unchanged() {
    let layout = Layout::parse(IO16).unwrap();
    let mut snap = Snapshot::new();
    snap.insert(layout.spans()[0], vec![0xFF; 127]);
    let mut settings = vec![0xFF; layout.spans()[1].len as usize];
    settings[..2].copy_from_slice(&[0, 20]);
    snap.insert(layout.spans()[1], settings);
    let text = backup::write(&layout, &snap).unwrap();
    assert!(text.starts_with(&format!("Node ID.Node Name={}\n", "\u{FFFD}".repeat(63))));
    let plan = backup::plan(&layout, &snap, &backup::parse(&text).unwrap()).unwrap();
    assert_eq!((plan.writes.len(), plan.invalid.len()), (0, 0), "{:?}", plan.invalid);
}

/// A factory-fresh board's backup restores onto a replacement whose bytes differ: erased
/// strings go back as 0xFF, a string that filled its entry goes back whole, and bytes that
/// were not UTF-8 beside text read back as the same line. The replacement's own backup is
/// then the board's, byte for byte.
#[test]
fn a_backup_restores_onto_a_replacement_and_reads_back_as_itself() {
    let layout = Layout::parse(IO16).unwrap();
    let mut names = vec![0xFF; 63];
    names.extend_from_slice(b"Full width description, sixty-four bytes with no NUL at its end!");
    let mut settings = vec![0xFF; layout.spans()[1].len as usize];
    settings[..2].copy_from_slice(&[0, 20]);
    settings[2..2 + 16].copy_from_slice(b"a\xFF\xC3b\xE2\x82\0\0\0\0\0\0\0\0\0\0");
    let mut board = Snapshot::new();
    board.insert(layout.spans()[0], names);
    board.insert(layout.spans()[1], settings);
    let text = backup::write(&layout, &board).unwrap();
    assert!(text.contains("\nSettings.Line(0).Label=a\u{FFFD}\u{FFFD}b\u{FFFD}\n"), "{text}");

    let replacement = snapshot(&layout, |_| 0);
    let plan = backup::plan(&layout, &replacement, &backup::parse(&text).unwrap()).unwrap();
    assert!(plan.invalid.is_empty(), "{:?}", plan.invalid);
    let mut restored = Snapshot::new();
    for span in layout.spans() {
        let mut bytes = replacement.get(span.space, span.address, span.len).unwrap().to_vec();
        for (space, address, run) in backup::coalesce(&plan.writes) {
            if space == span.space {
                let at = (address - span.address) as usize;
                bytes[at..at + run.len()].copy_from_slice(&run);
            }
        }
        restored.insert(span, bytes);
    }
    assert_eq!(backup::write(&layout, &restored).unwrap(), text);
    assert_eq!(restored.get(251, 1, 63).unwrap(), [0xFF; 63], "erased stays erased");

    // A person's value still keeps a byte for the NUL.
    let name = layout.find("Node ID.Node Name").next().unwrap();
    let error = name.parse_strict(&"x".repeat(63)).unwrap_err();
    assert_eq!(error, ValueError::TooLong { len: 63, size: 63, room: 62 });
    assert!(name.encode_restored(&Value::String("x".repeat(64))).is_err());
}
