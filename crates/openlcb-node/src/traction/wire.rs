//! The Traction Control messages (Train Control Standard §4.3, §4.4): the speed as float16,
//! the commands a train takes, and the replies it sends.

use core::fmt;

use openlcb_stream::NodeId;

/// A speed and direction as the standard's signed float16 (IEEE 754 half precision, metres
/// per second): the sign bit is the direction (set: reverse), so zero has two values,
/// forward `0x0000` and reverse `0x8000`. Any bits are kept as they came; NaN (`0xFFFF`)
/// says "not known" in a Query Speeds reply.
#[derive(Clone, Copy, PartialEq, Eq, Hash, Default)]
pub struct Speed(u16);

impl Speed {
    /// Stopped, forward.
    pub const ZERO_FORWARD: Speed = Speed(0x0000);
    /// Stopped, reverse.
    pub const ZERO_REVERSE: Speed = Speed(0x8000);
    /// Not known (a Query Speeds reply's speed the train cannot give).
    pub const NAN: Speed = Speed(0xFFFF);

    /// The speed of these wire bits.
    pub const fn from_bits(bits: u16) -> Self {
        Speed(bits)
    }

    /// The wire bits.
    pub const fn to_bits(self) -> u16 {
        self.0
    }

    /// The sign bit: the train runs (or stands) in reverse.
    pub const fn is_reverse(self) -> bool {
        self.0 & 0x8000 != 0
    }

    /// Zero magnitude (either direction).
    pub const fn is_zero(self) -> bool {
        self.0 & 0x7FFF == 0
    }

    /// Not a number.
    pub const fn is_nan(self) -> bool {
        self.0 & 0x7C00 == 0x7C00 && self.0 & 0x03FF != 0
    }

    /// Zero in the same direction: what an emergency stop leaves.
    pub const fn stopped(self) -> Self {
        Speed(self.0 & 0x8000)
    }

    /// The same magnitude in the other direction.
    pub const fn reversed(self) -> Self {
        Speed(self.0 ^ 0x8000)
    }

    /// The value in metres per second, negative in reverse (-0.0 for stopped in reverse).
    pub fn to_f32(self) -> f32 {
        let sign = u32::from(self.0 >> 15) << 31;
        let exp = u32::from((self.0 >> 10) & 0x1F);
        let man = u32::from(self.0 & 0x3FF);
        match exp {
            0 => {
                let magnitude = man as f32 / 16_777_216.0;
                if sign != 0 { -magnitude } else { magnitude }
            }
            31 => f32::from_bits(sign | 0x7F80_0000 | (man << 13)),
            _ => f32::from_bits(sign | ((exp + 112) << 23) | (man << 13)),
        }
    }

    /// The float16 nearest `value` (metres per second; negative or -0.0 is reverse).
    /// Magnitudes past 65504 become infinite, ones below 2^-24 zero.
    pub fn from_f32(value: f32) -> Self {
        let bits = value.to_bits();
        let sign = ((bits >> 16) & 0x8000) as u16;
        if value.is_nan() {
            return Speed(sign | 0x7E00);
        }
        let exp = ((bits >> 23) & 0xFF) as i32 - 127 + 15;
        let man = bits & 0x7F_FFFF;
        if exp >= 31 {
            return Speed(sign | 0x7C00);
        }
        if exp <= 0 {
            if exp < -10 {
                return Speed(sign);
            }
            let full = man | 0x80_0000;
            let shift = (14 - exp) as u32;
            let half = (full >> shift) + ((full >> (shift - 1)) & 1);
            return Speed(sign | half as u16);
        }
        // Round to nearest; a carry out of the mantissa moves the exponent, as it must.
        let half = ((exp as u32) << 10 | man >> 13) + ((man >> 12) & 1);
        Speed(sign | half.min(0x7C00) as u16)
    }
}

impl fmt::Debug for Speed {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "Speed(0x{:04X} {})", self.0, self)
    }
}

impl fmt::Display for Speed {
    /// `forward 1.5 m/s`, `reverse 0 m/s`, `unknown`.
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        if self.is_nan() {
            return f.write_str("unknown");
        }
        let direction = if self.is_reverse() { "reverse" } else { "forward" };
        write!(f, "{direction} {} m/s", self.to_f32().abs())
    }
}

/// Listener flag: reserved (Train Control Standard §4.3).
pub const LISTENER_RESERVED: u8 = 0x01;
/// Listener flag: the listener runs the other way round (forwarded speeds are reversed).
pub const LISTENER_REVERSE: u8 = 0x02;
/// Listener flag: F0 is forwarded to it.
pub const LISTENER_LINK_F0: u8 = 0x04;
/// Listener flag: the other functions are forwarded to it.
pub const LISTENER_LINK_FN: u8 = 0x08;
/// Listener flag: user interfaces do not show it (a throttle, automation).
pub const LISTENER_HIDE: u8 = 0x80;

/// Byte 0 bit 7 of a command: forwarded by a train to its listener.
pub(crate) const FORWARDED: u8 = 0x80;

pub(crate) const SET_SPEED: u8 = 0x00;
pub(crate) const SET_FUNCTION: u8 = 0x01;
pub(crate) const EMERGENCY_STOP: u8 = 0x02;
pub(crate) const QUERY_SPEEDS: u8 = 0x10;
pub(crate) const QUERY_FUNCTION: u8 = 0x11;
pub(crate) const CONTROLLER: u8 = 0x20;
pub(crate) const LISTENER: u8 = 0x30;
pub(crate) const MANAGEMENT: u8 = 0x40;

pub(crate) const CONTROLLER_ASSIGN: u8 = 0x01;
pub(crate) const CONTROLLER_RELEASE: u8 = 0x02;
pub(crate) const CONTROLLER_QUERY: u8 = 0x03;
pub(crate) const CONTROLLER_CHANGING: u8 = 0x04;
pub(crate) const LISTENER_ATTACH: u8 = 0x01;
pub(crate) const LISTENER_DETACH: u8 = 0x02;
pub(crate) const LISTENER_QUERY: u8 = 0x03;
pub(crate) const MANAGEMENT_RESERVE: u8 = 0x01;
pub(crate) const MANAGEMENT_RELEASE: u8 = 0x02;
pub(crate) const MANAGEMENT_NOOP: u8 = 0x03;

/// A Traction Control Command as a train takes it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[non_exhaustive]
pub enum TractionCommand {
    /// Set Speed/Direction; `forwarded`: the P bit (sent by a train to its listener).
    SetSpeed {
        /// The speed.
        speed: Speed,
        /// The P bit.
        forwarded: bool,
    },
    /// Set Function: a 24-bit address of space 0xF9 and its value.
    SetFunction {
        /// The function (F0 is 0).
        address: u32,
        /// Its value (0 off, 1 on for a binary function).
        value: u16,
        /// The P bit.
        forwarded: bool,
    },
    /// Emergency Stop.
    EmergencyStop {
        /// The P bit.
        forwarded: bool,
    },
    /// Query Speeds.
    QuerySpeeds,
    /// Query Function.
    QueryFunction {
        /// The function.
        address: u32,
    },
    /// Controller Configuration: Assign Controller.
    AssignController {
        /// The flags byte (reserved).
        flags: u8,
        /// The controller.
        node: NodeId,
    },
    /// Controller Configuration: Release Controller.
    ReleaseController {
        /// The flags byte (reserved).
        flags: u8,
        /// The controller releasing itself.
        node: NodeId,
    },
    /// Controller Configuration: Query Controller.
    QueryController,
    /// Controller Configuration: Controller Changing Notify (a train to its old controller).
    ControllerChanging {
        /// The flags byte (reserved).
        flags: u8,
        /// The node that asked to be the controller.
        node: NodeId,
    },
    /// Listener Configuration: Attach Node (or update its flags).
    AttachListener {
        /// The listener's flags.
        flags: u8,
        /// The listener.
        node: NodeId,
    },
    /// Listener Configuration: Detach Node.
    DetachListener {
        /// The flags byte (reserved).
        flags: u8,
        /// The listener.
        node: NodeId,
    },
    /// Listener Configuration: Query Nodes, with the index asked for.
    QueryListeners {
        /// The index, if any.
        index: Option<u8>,
    },
    /// Train Control Management: Reserve.
    Reserve,
    /// Train Control Management: Release.
    Release,
    /// Train Control Management: No-op (answers a heartbeat request).
    Noop,
}

/// Why a command could not be read: the reject it gets.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum CommandError {
    /// Too short for its instruction.
    Short,
    /// An instruction or sub-instruction the standard does not define.
    Unknown,
}

fn node_at(payload: &[u8], at: usize) -> Result<NodeId, CommandError> {
    payload.get(at..at + 6).and_then(NodeId::from_slice).ok_or(CommandError::Short)
}

fn u24_at(payload: &[u8], at: usize) -> Result<u32, CommandError> {
    match payload.get(at..at + 3) {
        Some([a, b, c]) => Ok(u32::from_be_bytes([0, *a, *b, *c])),
        _ => Err(CommandError::Short),
    }
}

impl TractionCommand {
    /// Reads a Traction Control Command payload. Bytes past the instruction's are ignored.
    pub(crate) fn parse(payload: &[u8]) -> Result<Self, CommandError> {
        let first = *payload.first().ok_or(CommandError::Short)?;
        let forwarded = first & FORWARDED != 0;
        let sub = || payload.get(1).copied().ok_or(CommandError::Short);
        let flags = || payload.get(2).copied().ok_or(CommandError::Short);
        Ok(match first & !FORWARDED {
            SET_SPEED => match payload.get(1..3) {
                Some([hi, lo]) => TractionCommand::SetSpeed { speed: Speed(u16::from_be_bytes([*hi, *lo])), forwarded },
                _ => return Err(CommandError::Short),
            },
            SET_FUNCTION => {
                let address = u24_at(payload, 1)?;
                let value = match payload.get(4..6) {
                    Some([hi, lo]) => u16::from_be_bytes([*hi, *lo]),
                    _ => u16::from(*payload.get(4).ok_or(CommandError::Short)?),
                };
                TractionCommand::SetFunction { address, value, forwarded }
            }
            EMERGENCY_STOP => TractionCommand::EmergencyStop { forwarded },
            _ if forwarded => return Err(CommandError::Unknown),
            QUERY_SPEEDS => TractionCommand::QuerySpeeds,
            QUERY_FUNCTION => TractionCommand::QueryFunction { address: u24_at(payload, 1)? },
            CONTROLLER => match sub()? {
                CONTROLLER_ASSIGN => TractionCommand::AssignController { flags: flags()?, node: node_at(payload, 3)? },
                CONTROLLER_RELEASE => {
                    TractionCommand::ReleaseController { flags: flags()?, node: node_at(payload, 3)? }
                }
                CONTROLLER_QUERY => TractionCommand::QueryController,
                CONTROLLER_CHANGING => {
                    TractionCommand::ControllerChanging { flags: flags()?, node: node_at(payload, 3)? }
                }
                _ => return Err(CommandError::Unknown),
            },
            LISTENER => match sub()? {
                LISTENER_ATTACH => TractionCommand::AttachListener { flags: flags()?, node: node_at(payload, 3)? },
                LISTENER_DETACH => TractionCommand::DetachListener { flags: flags()?, node: node_at(payload, 3)? },
                LISTENER_QUERY => TractionCommand::QueryListeners { index: payload.get(2).copied() },
                _ => return Err(CommandError::Unknown),
            },
            MANAGEMENT => match sub()? {
                MANAGEMENT_RESERVE => TractionCommand::Reserve,
                MANAGEMENT_RELEASE => TractionCommand::Release,
                MANAGEMENT_NOOP => TractionCommand::Noop,
                _ => return Err(CommandError::Unknown),
            },
            _ => return Err(CommandError::Unknown),
        })
    }

    /// The payload of this command.
    pub fn to_bytes(self) -> alloc::vec::Vec<u8> {
        let p = |forwarded: bool| if forwarded { FORWARDED } else { 0 };
        let with_node = |a: u8, b: u8, flags: u8, node: NodeId| {
            let mut v = alloc::vec![a, b, flags];
            v.extend_from_slice(&node.to_bytes());
            v
        };
        match self {
            TractionCommand::SetSpeed { speed, forwarded } => {
                let [hi, lo] = speed.to_bits().to_be_bytes();
                alloc::vec![SET_SPEED | p(forwarded), hi, lo]
            }
            TractionCommand::SetFunction { address, value, forwarded } => {
                let [_, a, b, c] = address.to_be_bytes();
                let [hi, lo] = value.to_be_bytes();
                alloc::vec![SET_FUNCTION | p(forwarded), a, b, c, hi, lo]
            }
            TractionCommand::EmergencyStop { forwarded } => alloc::vec![EMERGENCY_STOP | p(forwarded)],
            TractionCommand::QuerySpeeds => alloc::vec![QUERY_SPEEDS],
            TractionCommand::QueryFunction { address } => {
                let [_, a, b, c] = address.to_be_bytes();
                alloc::vec![QUERY_FUNCTION, a, b, c]
            }
            TractionCommand::AssignController { flags, node } => with_node(CONTROLLER, CONTROLLER_ASSIGN, flags, node),
            TractionCommand::ReleaseController { flags, node } => {
                with_node(CONTROLLER, CONTROLLER_RELEASE, flags, node)
            }
            TractionCommand::QueryController => alloc::vec![CONTROLLER, CONTROLLER_QUERY],
            TractionCommand::ControllerChanging { flags, node } => {
                with_node(CONTROLLER, CONTROLLER_CHANGING, flags, node)
            }
            TractionCommand::AttachListener { flags, node } => with_node(LISTENER, LISTENER_ATTACH, flags, node),
            TractionCommand::DetachListener { flags, node } => with_node(LISTENER, LISTENER_DETACH, flags, node),
            TractionCommand::QueryListeners { index } => {
                let mut v = alloc::vec![LISTENER, LISTENER_QUERY];
                v.extend(index);
                v
            }
            TractionCommand::Reserve => alloc::vec![MANAGEMENT, MANAGEMENT_RESERVE],
            TractionCommand::Release => alloc::vec![MANAGEMENT, MANAGEMENT_RELEASE],
            TractionCommand::Noop => alloc::vec![MANAGEMENT, MANAGEMENT_NOOP],
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn float16_round_trips() {
        for (value, bits) in [(0.0f32, 0x0000u16), (-0.0, 0x8000), (1.0, 0x3C00), (-2.0, 0xC000), (0.5, 0x3800)] {
            assert_eq!(Speed::from_f32(value).to_bits(), bits, "{value}");
            assert_eq!(Speed::from_bits(bits).to_f32().to_bits(), value.to_bits());
        }
        assert_eq!(Speed::from_bits(0x3E4C).to_f32(), 1.574_218_8);
        assert!(Speed::NAN.is_nan());
        assert!(Speed::ZERO_REVERSE.is_zero() && Speed::ZERO_REVERSE.is_reverse());
        assert_eq!(Speed::from_bits(0xBE4C).stopped(), Speed::ZERO_REVERSE);
        assert_eq!(Speed::from_f32(1.0e6).to_bits(), 0x7C00);
        assert_eq!(Speed::from_f32(1.0e-9).to_bits(), 0x0000);
        for bits in 0..0x7C00u16 {
            assert_eq!(Speed::from_f32(Speed::from_bits(bits).to_f32()).to_bits(), bits);
        }
    }

    #[test]
    fn commands_parse_and_emit() {
        let node = NodeId::new(0x0501_0101_2200).unwrap();
        for command in [
            TractionCommand::SetSpeed { speed: Speed::from_bits(0xBE4C), forwarded: false },
            TractionCommand::SetFunction { address: 0x01_0203, value: 1, forwarded: true },
            TractionCommand::EmergencyStop { forwarded: false },
            TractionCommand::QuerySpeeds,
            TractionCommand::QueryFunction { address: 2 },
            TractionCommand::AssignController { flags: 0, node },
            TractionCommand::ReleaseController { flags: 0, node },
            TractionCommand::QueryController,
            TractionCommand::ControllerChanging { flags: 0, node },
            TractionCommand::AttachListener { flags: LISTENER_REVERSE, node },
            TractionCommand::DetachListener { flags: 0, node },
            TractionCommand::QueryListeners { index: Some(1) },
            TractionCommand::QueryListeners { index: None },
            TractionCommand::Reserve,
            TractionCommand::Release,
            TractionCommand::Noop,
        ] {
            assert_eq!(TractionCommand::parse(&command.to_bytes()), Ok(command));
        }
        assert_eq!(TractionCommand::parse(&[]), Err(CommandError::Short));
        assert_eq!(TractionCommand::parse(&[0x00, 0x01]), Err(CommandError::Short));
        assert_eq!(TractionCommand::parse(&[0x20, 0x01, 0, 1, 2]), Err(CommandError::Short));
        assert_eq!(TractionCommand::parse(&[0x05]), Err(CommandError::Unknown));
        assert_eq!(TractionCommand::parse(&[0x90]), Err(CommandError::Unknown));
        assert_eq!(TractionCommand::parse(&[0x40, 0x09]), Err(CommandError::Unknown));
        // A one-byte function value (older throttles) is taken too.
        assert_eq!(
            TractionCommand::parse(&[0x01, 0, 0, 0, 1]),
            Ok(TractionCommand::SetFunction { address: 0, value: 1, forwarded: false })
        );
    }
}
