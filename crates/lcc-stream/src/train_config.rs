//! A `lcc-stream train` train's configuration: space 0xFD as its CDI (space 0xFF) lays it
//! out, declared once with the board kit (`openlcb_node::board`): the train's name, its DCC
//! address and address type, its speed steps, and the name and kind of each function key
//! F0-F68. A tool's change takes effect at Update Complete (which `config set` and JMRI send):
//! the train answers Train Search with its new address and name, and its FDI (space 0xFA)
//! names the new keys. Factory Reset writes the values the command line gave. The space is in
//! memory: a train's configuration lasts as long as the process.

use openlcb_tokio::openlcb_node::board::{Board, BoardBuilder, IntSetting, StringSetting};
use openlcb_tokio::openlcb_node::traction::{FunctionKind, FunctionName, TrainIdentity, TrainProtocol, fdi_space};
use openlcb_tokio::{MemoryServer, RamSpace, ReadOnlySpace, SharedSpace, SnipInfo};

/// Function keys a train's configuration names: F0 to F68, as many as the train keeps.
pub(crate) const FUNCTION_KEYS: u32 = 69;
/// The longest train name, its NUL included.
const NAME_SIZE: u32 = 32;
/// The longest function key name, its NUL included.
const KEY_NAME_SIZE: u32 = 16;
/// The speed steps a DCC decoder may use.
pub(crate) const SPEED_STEPS: [u64; 3] = [14, 28, 128];

/// What a train's configuration holds.
#[derive(Debug, Clone, PartialEq, Eq)]
pub(crate) struct TrainSetup {
    /// Its address, protocol and name, for Train Search.
    pub(crate) identity: TrainIdentity,
    /// 14, 28 or 128.
    pub(crate) speed_steps: u8,
    /// The keys that have a name, in key order: its FDI.
    pub(crate) functions: Vec<FunctionName>,
}

impl TrainSetup {
    /// One line for the log: `DCC 1234 (long) "Big Boy", 128 speed steps, 3 functions`.
    pub(crate) fn text(&self) -> String {
        let long = matches!(self.identity.protocol, TrainProtocol::Dcc { long: true });
        let name = if self.identity.name.is_empty() { String::new() } else { format!(" \"{}\"", self.identity.name) };
        format!(
            "DCC {}{}{name}, {} speed steps, {} named function{}",
            self.identity.address,
            if long { " (long)" } else { "" },
            self.speed_steps,
            self.functions.len(),
            if self.functions.len() == 1 { "" } else { "s" }
        )
    }
}

/// One function key's settings.
struct KeySettings {
    name: StringSetting,
    kind: IntSetting,
}

/// A train's configuration: the settings, their space, and the FDI they make.
pub(crate) struct TrainSettings {
    board: Board,
    name: StringSetting,
    address: IntSetting,
    long: IntSetting,
    speed_steps: IntSetting,
    keys: Vec<KeySettings>,
    space: SharedSpace<RamSpace>,
    fdi: SharedSpace<ReadOnlySpace>,
}

impl TrainSettings {
    /// The settings with `factory` as their defaults, the space holding them.
    pub(crate) fn new(factory: &TrainSetup, snip: &SnipInfo) -> TrainSettings {
        let mut config = BoardBuilder::new("Train");
        let name = config.string("Name", NAME_SIZE, &factory.identity.name);
        let address = config.int("DCC address", 2, u64::from(factory.identity.address), &[]);
        let long = matches!(factory.identity.protocol, TrainProtocol::Dcc { long: true });
        let long = config.int("Address type", 1, u64::from(long), &[(0, "Short"), (1, "Long")]);
        let steps: Vec<(u64, String)> = SPEED_STEPS.iter().map(|s| (*s, s.to_string())).collect();
        let steps: Vec<(u64, &str)> = steps.iter().map(|(s, text)| (*s, text.as_str())).collect();
        let speed_steps = config.int("Speed steps", 1, u64::from(factory.speed_steps), &steps);
        let keys = config.numbered_group("Function key", "F0", FUNCTION_KEYS, |g, number| {
            let named = factory.functions.iter().find(|f| f.number == number);
            let momentary = named.is_some_and(|f| f.kind == FunctionKind::Momentary);
            KeySettings {
                name: g.string("Name", KEY_NAME_SIZE, named.map_or("", |f| f.name.as_str())),
                kind: g.int("Kind", 1, u64::from(momentary), &[(0, "On/off"), (1, "Momentary")]),
            }
        });
        let board = config.finish(snip);
        let mut space = SharedSpace::new(RamSpace::new(board.len()));
        // A space of the board's own size takes its defaults.
        let _ = board.factory_reset(&mut space);
        let fdi = SharedSpace::new(fdi_space(&factory.functions));
        TrainSettings { board, name, address, long, speed_steps, keys, space, fdi }
    }

    /// The memory server of the train: its CDI, its configuration, ACDI, its FDI (space 0xF9,
    /// the function values, is the node's own).
    pub(crate) fn server(&self) -> MemoryServer {
        MemoryServer::new()
            .with_space(0xFF, ReadOnlySpace::cdi(self.board.cdi()))
            .with_space(0xFD, self.space.clone())
            .with_space(0xFA, self.fdi.clone())
            .with_acdi()
    }

    /// What the space holds now, checked: an address out of its range is refused with the
    /// reason (the train keeps what it had).
    pub(crate) fn read(&self) -> Result<TrainSetup, String> {
        let mut space = self.space.clone();
        let fault = |e| format!("the configuration could not be read: {e}");
        let address = u32::try_from(self.address.read(&mut space).map_err(fault)?).unwrap_or(u32::MAX);
        let long = self.long.read(&mut space).map_err(fault)? != 0;
        let highest = if long { 10239 } else { 127 };
        if !(1..=highest).contains(&address) {
            let kind = if long { "long" } else { "short" };
            return Err(format!("DCC address {address} is no {kind} address (1 to {highest})"));
        }
        let speed_steps = self.speed_steps.read(&mut space).map_err(fault)?;
        let speed_steps = match u8::try_from(speed_steps) {
            Ok(steps) if SPEED_STEPS.contains(&u64::from(steps)) => steps,
            _ => return Err(format!("{speed_steps} speed steps: a decoder has 14, 28 or 128")),
        };
        let mut functions = Vec::new();
        for (number, key) in (0u32..).zip(&self.keys) {
            let name = key.name.read(&mut space).map_err(fault)?;
            if name.is_empty() {
                continue;
            }
            let kind = if key.kind.read(&mut space).map_err(fault)? == 1 {
                FunctionKind::Momentary
            } else {
                FunctionKind::Binary
            };
            functions.push(FunctionName { number, name, kind });
        }
        let mut identity = TrainIdentity::dcc(address);
        identity.protocol = TrainProtocol::Dcc { long };
        identity.name = self.name.read(&mut space).map_err(fault)?;
        Ok(TrainSetup { identity, speed_steps, functions })
    }

    /// The FDI follows `setup`.
    pub(crate) fn show(&self, setup: &TrainSetup) {
        *self.fdi.lock() = fdi_space(&setup.functions);
    }

    /// Factory Reset: the defaults written again.
    pub(crate) fn factory_reset(&self) -> Result<(), String> {
        let mut space = self.space.clone();
        self.board.factory_reset(&mut space).map_err(|e| format!("the defaults could not be written: {e}"))
    }
}

#[cfg(test)]
mod tests {
    use openlcb_tokio::openlcb_node::MemorySpace;

    use super::*;

    fn factory() -> TrainSetup {
        let mut identity = TrainIdentity::dcc(3);
        identity.name = "Shunter".into();
        let functions = vec![
            FunctionName { number: 0, name: "Headlight".into(), kind: FunctionKind::Binary },
            FunctionName { number: 2, name: "Horn".into(), kind: FunctionKind::Momentary },
        ];
        TrainSetup { identity, speed_steps: 128, functions }
    }

    #[test]
    fn the_settings_start_as_the_command_line_and_follow_a_tools_writes() {
        let settings = TrainSettings::new(&factory(), &SnipInfo::default());
        assert_eq!(settings.read().unwrap(), factory());
        assert!(settings.board.cdi().contains("<name>Speed steps</name>"));
        let mut space = settings.space.clone();
        settings.address.write(&mut space, 1234).unwrap();
        settings.long.write(&mut space, 1).unwrap();
        settings.keys[5].name.write(&mut space, "Bell").unwrap();
        settings.keys[2].name.write(&mut space, "").unwrap();
        let setup = settings.read().unwrap();
        assert_eq!(setup.identity.address, 1234);
        assert_eq!(setup.identity.protocol, TrainProtocol::Dcc { long: true });
        let names: Vec<_> = setup.functions.iter().map(|f| (f.number, f.name.as_str())).collect();
        assert_eq!(names, [(0, "Headlight"), (5, "Bell")]);
        settings.show(&setup);
        let mut fdi = settings.fdi.clone();
        let mut xml = vec![0; fdi.len() as usize];
        fdi.read(0, &mut xml).unwrap();
        assert!(String::from_utf8_lossy(&xml).contains("<name>Bell</name>\n<number>5</number>"));
        settings.factory_reset().unwrap();
        assert_eq!(settings.read().unwrap(), factory());
    }

    #[test]
    fn an_address_out_of_range_or_odd_speed_steps_are_refused() {
        let settings = TrainSettings::new(&factory(), &SnipInfo::default());
        let mut space = settings.space.clone();
        settings.address.write(&mut space, 200).unwrap();
        assert!(settings.read().unwrap_err().contains("no short address"));
        settings.long.write(&mut space, 1).unwrap();
        settings.speed_steps.write(&mut space, 100).unwrap();
        assert!(settings.read().unwrap_err().contains("100 speed steps"));
        settings.address.write(&mut space, 0).unwrap();
        assert!(settings.read().unwrap_err().contains("no long address"));
    }
}
