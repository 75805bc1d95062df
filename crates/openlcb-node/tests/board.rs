//! The application-node kit: the CDI a board's builder writes parses (with the CDI crate, as
//! a tool reads it) to exactly the addresses of its handles, with the declared defaults, and
//! the events a board declares follow what its space holds.

use openlcb_cdi::{EntryKind, Layout};
use openlcb_node::board::{Board, BoardBuilder, EventRole, EventSetting, IntSetting, StringSetting};
use openlcb_node::{MemorySpace, RamSpace, SnipInfo};
use openlcb_stream::EventId;

struct Line {
    name: StringSetting,
    mode: IntSetting,
    on: EventSetting,
    off: EventSetting,
}

/// The settings of the test board (as a firmware declares them: a function).
fn settings(config: &mut BoardBuilder) -> (StringSetting, IntSetting, Vec<Line>) {
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
    (name, delay, lines)
}

fn snip() -> SnipInfo {
    SnipInfo { manufacturer: "Acme <&>".into(), model: "IO-8".into(), ..SnipInfo::default() }
}

fn board() -> (Board, StringSetting, IntSetting, Vec<Line>) {
    let mut config = BoardBuilder::new("I/O <board>");
    let (name, delay, lines) = settings(&mut config);
    (config.finish(&snip()), name, delay, lines)
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
    assert!(board.cdi().contains("<manufacturer>Acme &lt;&amp;&gt;</manufacturer><model>IO-8</model>"));
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

#[test]
fn a_declared_board_renders_on_each_read_the_cdi_its_builder_writes() {
    let (built, name, delay, lines) = board();
    let (declared, (name2, delay2, lines2), mut space) = Board::declare("I/O <board>", &snip(), settings);
    assert_eq!(declared.cdi(), "", "a declared board keeps no CDI");
    assert_eq!((name2, delay2), (name, delay));
    assert!(lines2.iter().zip(&lines).all(|(a, b)| a.on == b.on && a.off == b.off && a.mode == b.mode));
    assert_eq!(declared.len(), built.len());
    let mut whole = built.cdi().as_bytes().to_vec();
    whole.push(0);
    assert_eq!(space.len() as usize, whole.len());
    assert!(space.read_only());
    for chunk in [1, 7, 64, 1000, whole.len() + 10] {
        let mut read = Vec::new();
        let mut at = 0;
        while at < space.len() {
            let mut buf = vec![0u8; chunk];
            let n = space.read(at, &mut buf).unwrap();
            assert!(n > 0, "a read inside the space returns bytes");
            read.extend_from_slice(&buf[..n]);
            at += n as u32;
        }
        assert_eq!(read, whole, "read in chunks of {chunk}");
    }
    assert_eq!(space.read(space.len(), &mut [0u8; 4]).unwrap(), 0, "at the end: nothing");
    assert!(space.read(space.len() + 1, &mut [0u8; 4]).is_err(), "past the end: out of bounds");
    assert!(space.write(0, b"x").is_err(), "the CDI is read-only");
    // The declared board's layout is the built one's: the same defaults and events.
    let (mut a, mut b) = (RamSpace::new(built.len()), RamSpace::new(declared.len()));
    built.factory_reset(&mut a).unwrap();
    declared.factory_reset(&mut b).unwrap();
    assert_eq!(a.as_bytes(), b.as_bytes());
    assert_eq!(built.events(&mut a), declared.events(&mut b));
}
