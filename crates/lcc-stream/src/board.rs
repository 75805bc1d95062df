//! `serve` as a board: every `eventid` setting of its configuration space (space 0xFD, as its
//! CDI lays it out: the built-in CDI's `Port(i).Event On` and `Event Off`) is an event the
//! node produces and consumes, as the configuration holds it now. `--input` lines (`port 2
//! on`) produce them; a report of one drives the output it names, printed on stdout. A tool's
//! change takes effect at Update Complete, which `config set` and `write` send.

use openlcb_cdi::{EntryKind, Layout};
use openlcb_stream::EventId;
use openlcb_tokio::openlcb_node::MemorySpace;
use openlcb_tokio::{DeclaredEvents, EventConfig, EventState};

/// The configuration space the board's events live in.
const CONFIG_SPACE: u8 = 0xFD;

/// One event setting of the board.
#[derive(Debug, Clone, PartialEq, Eq)]
struct Setting {
    /// What input lines and outputs call it: `port 2 on`, or the setting's CDI key.
    name: String,
    address: u32,
}

/// The board's event settings, from its CDI.
#[derive(Debug, Clone, Default)]
pub(crate) struct Board {
    settings: Vec<Setting>,
}

/// The events the settings hold now: (name, event) for each one set (not all zeros or ones).
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub(crate) struct Configured(Vec<(String, EventId)>);

impl Board {
    /// The event settings of space 0xFD in `cdi` (none for a CDI that does not parse).
    pub(crate) fn new(cdi: &str) -> Board {
        let Ok(layout) = Layout::parse(cdi) else { return Board::default() };
        let settings = layout
            .entries()
            .filter(|e| e.space == CONFIG_SPACE && e.kind == EntryKind::EventId && e.size == 8)
            .map(|e| Setting { name: port_name(&e.key).unwrap_or_else(|| e.key.clone()), address: e.address })
            .collect();
        Board { settings }
    }

    /// What the settings hold in `space` now.
    pub(crate) fn read(&self, space: &mut impl MemorySpace) -> Configured {
        let mut configured = Vec::new();
        for setting in &self.settings {
            let mut bytes = [0u8; 8];
            if space.read(setting.address, &mut bytes).ok() != Some(8) {
                continue;
            }
            let event = EventId::from_bytes(bytes);
            if event.as_raw() != 0 && event.as_raw() != u64::MAX {
                configured.push((setting.name.clone(), event));
            }
        }
        Configured(configured)
    }
}

impl Configured {
    /// The node's events: `produced` and `consumed` (from `--produces`, `--consumes`), and
    /// each configured event both produced and consumed.
    pub(crate) fn declarations(&self, produced: &[DeclaredEvents], consumed: &[DeclaredEvents]) -> EventConfig {
        let own = self.0.iter().map(|(_, event)| DeclaredEvents::single(*event, EventState::Unknown));
        let mut events = EventConfig::default();
        events.produced = produced.iter().copied().chain(own.clone()).collect();
        events.consumed = consumed.iter().copied().chain(own).collect();
        events
    }

    /// The event an input line names: `port 2 on` (any case, spaces as they come), or a
    /// setting's key.
    pub(crate) fn input(&self, line: &str) -> Result<EventId, String> {
        let wanted = line.split_whitespace().collect::<Vec<_>>().join(" ");
        self.0.iter().find(|(name, _)| name.eq_ignore_ascii_case(&wanted)).map(|(_, event)| *event).ok_or_else(|| {
            let known: Vec<&str> = self.0.iter().map(|(name, _)| name.as_str()).collect();
            if known.is_empty() {
                format!("no event is configured for `{wanted}` (no event setting is set: `config set` one)")
            } else {
                format!("no event is configured for `{wanted}` (configured: {})", known.join(", "))
            }
        })
    }

    /// The outputs `event` drives.
    pub(crate) fn outputs(&self, event: EventId) -> impl Iterator<Item = &str> {
        self.0.iter().filter(move |(_, e)| *e == event).map(|(name, _)| name.as_str())
    }

    /// `port 1 on = 05.01.01.01.22.F2.00.01, ...`, or `none`.
    pub(crate) fn text(&self) -> String {
        if self.0.is_empty() {
            return "none".into();
        }
        self.0.iter().map(|(name, event)| format!("{name} = {event}")).collect::<Vec<_>>().join(", ")
    }
}

/// `port 2 on` for a key `….Port(1).Event On` (a port's event as the built-in CDI names it).
fn port_name(key: &str) -> Option<String> {
    let (port, event) = key.rsplit_once('.')?;
    let index = port.rsplit_once("Port(")?.1.strip_suffix(')')?.parse::<u32>().ok()?;
    let state = match event {
        "Event On" => "on",
        "Event Off" => "off",
        _ => return None,
    };
    Some(format!("port {} {state}", index + 1))
}

#[cfg(test)]
mod tests {
    use super::*;
    use openlcb_tokio::RamSpace;

    const CDI: &str = r#"<cdi><segment space="253"><name>Configuration</name>
        <group replication="2"><name>Port</name><repname>Port 1</repname>
        <string size="4"><name>Name</name></string>
        <eventid><name>Event On</name></eventid><eventid><name>Event Off</name></eventid></group>
        <eventid><name>Alarm</name></eventid></segment></cdi>"#;

    #[test]
    fn a_boards_events_are_what_its_settings_hold() {
        let board = Board::new(CDI);
        let mut space = RamSpace::new(64);
        assert_eq!(board.read(&mut space), Configured::default(), "all zeros: nothing set");
        space.write(4 + 8, &[5, 1, 1, 1, 0x22, 0xF2, 0, 2]).unwrap(); // port 1 off
        space.write(20 + 4, &[5, 1, 1, 1, 0x22, 0xF2, 0, 3]).unwrap(); // port 2 on
        space.write(40, &[5, 1, 1, 1, 0x22, 0xF2, 0, 9]).unwrap(); // the alarm
        let configured = board.read(&mut space);
        assert_eq!(
            configured.text(),
            "port 1 off = 05.01.01.01.22.F2.00.02, port 2 on = 05.01.01.01.22.F2.00.03, Configuration.Alarm = 05.01.01.01.22.F2.00.09"
        );
        assert_eq!(configured.input(" Port  2 ON "), Ok(EventId(0x0501_0101_22F2_0003)));
        assert!(configured.input("port 3 on").unwrap_err().contains("configured: port 1 off"));
        assert_eq!(configured.outputs(EventId(0x0501_0101_22F2_0009)).collect::<Vec<_>>(), ["Configuration.Alarm"]);
        let events = configured.declarations(&[], &[]);
        assert_eq!((events.produced.len(), events.consumed.len()), (3, 3));
    }
}
