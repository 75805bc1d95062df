//! The application-node kit: the CDI a board's builder writes parses (with the CDI crate, as
//! a tool reads it) to exactly the addresses of its handles, with the declared defaults, and
//! the events a board declares follow what its space holds.

use openlcb_cdi::{EntryKind, Layout};
use openlcb_node::board::{BoardBuilder, EventRole, EventSetting, IntSetting, StringSetting};
use openlcb_node::{MemorySpace, RamSpace, SnipInfo};
use openlcb_stream::EventId;

struct Line {
    name: StringSetting,
    mode: IntSetting,
    on: EventSetting,
    off: EventSetting,
}

fn board() -> (openlcb_node::board::Board, StringSetting, IntSetting, Vec<Line>) {
    let mut config = BoardBuilder::new("I/O <board>");
    let name = config.string("Board name", 24, "yard & mainline");
    let delay = config.int("Debounce (ms)", 2, 20, &[]);
    let lines = config.group("Line", 8, |g, i| Line {
        name: g.string("Name", 16, ""),
        mode: g.int("Mode", 1, u64::from(i % 2), &[(0, "Input"), (1, "Output")]),
        on: g.event(
            "Event On",
            if i % 2 == 0 { EventRole::Produced } else { EventRole::Consumed },
            EventId(0x0501_0101_2260_0000 + 2 * u64::from(i)),
        ),
        off: g.event(
            "Event Off",
            if i % 2 == 0 { EventRole::Produced } else { EventRole::Consumed },
            EventId(0x0501_0101_2260_0001 + 2 * u64::from(i)),
        ),
    });
    let snip = SnipInfo { manufacturer: "Acme".into(), model: "IO-8".into(), ..SnipInfo::default() };
    (config.finish(&snip), name, delay, lines)
}

#[test]
fn the_cdi_a_tool_reads_puts_every_setting_where_its_handle_is() {
    let (board, name, delay, lines) = board();
    let layout = Layout::parse(board.cdi()).expect("the CDI parses");
    let address = |key: &str| layout.find(key).next().map(|e| (e.space, e.address)).unwrap_or_else(|| panic!("{key}"));
    assert_eq!(address("I/O <board>.Board name"), (253, name.address()));
    assert_eq!(address("I/O <board>.Debounce (ms)"), (253, delay.address()));
    for (i, line) in lines.iter().enumerate() {
        assert_eq!(address(&format!("I/O <board>.Line({i}).Name")), (253, line.name.address()));
        assert_eq!(address(&format!("I/O <board>.Line({i}).Mode")), (253, line.mode.address()));
        assert_eq!(address(&format!("I/O <board>.Line({i}).Event On")), (253, line.on.address()));
        assert_eq!(address(&format!("I/O <board>.Line({i}).Event Off")), (253, line.off.address()));
    }
    let mode = layout.find("I/O <board>.Line(0).Mode").next().unwrap();
    assert!(matches!(mode.kind, EntryKind::Int { default: Some(0), .. }));
    assert_eq!(board.len(), 24 + 2 + 8 * (16 + 1 + 8 + 8));
    assert!(board.cdi().contains("<manufacturer>Acme</manufacturer><model>IO-8</model>"));
}

#[test]
fn factory_reset_writes_the_defaults_and_the_events_follow_the_space() {
    let (board, name, delay, lines) = board();
    let mut space = RamSpace::new(board.len());
    let events = board.events(&mut space);
    assert!(events.produced.is_empty() && events.consumed.is_empty(), "all zeros: nothing declared");
    board.factory_reset(&mut space).unwrap();
    assert_eq!(name.read(&mut space).unwrap(), "yard & mainline");
    assert_eq!(delay.read(&mut space).unwrap(), 20);
    assert_eq!(lines[3].mode.read(&mut space).unwrap(), 1);
    let events = board.events(&mut space);
    assert_eq!((events.produced.len(), events.consumed.len()), (8, 8));
    // A tool changes line 1's Event On: the board's events are the new one.
    let new = EventId(0x0501_0101_2299_0001);
    lines[0].on.write(&mut space, new).unwrap();
    assert!(board.events(&mut space).produced.iter().any(|d| d.range.first() == new));
    // Long text is cut at a character boundary, leaving its NUL.
    name.write(&mut space, "ééééééééééééééééééééééé").unwrap();
    assert_eq!(name.read(&mut space).unwrap(), "ééééééééééé");
    let mut raw = [0u8; 24];
    space.read(name.address(), &mut raw).unwrap();
    assert_eq!(raw[22..], [0, 0]);
}

#[test]
fn a_numbered_group_labels_its_copies_on_from_the_first_number() {
    let mut config = BoardBuilder::new("Train");
    let keys = config.numbered_group("Function key", "F0", 4, |g, _| g.string("Name", 8, ""));
    let board = config.finish(&SnipInfo::default());
    assert!(board.cdi().contains("<name>Function key</name><repname>F0</repname>"), "{}", board.cdi());
    let layout = Layout::parse(board.cdi()).expect("the CDI parses");
    let mut labels = Vec::new();
    let mut stack: Vec<&openlcb_cdi::LaidGroup> = layout.segments.iter().collect();
    while let Some(group) = stack.pop() {
        for child in &group.children {
            if let openlcb_cdi::Laid::Group(copy) = child {
                labels.extend(copy.label.clone());
                stack.push(copy);
            }
        }
    }
    labels.sort();
    assert_eq!(labels, ["F0", "F1", "F2", "F3", "Function key"]);
    let third = layout.find("Train.Function key(2).Name").next().expect("the third key");
    assert_eq!(third.address, keys[2].address());
}
