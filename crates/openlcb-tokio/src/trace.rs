//! The Memory Configuration conversation at debug level (`RUST_LOG=openlcb_tokio=debug`, or
//! `lcc-stream -vv`): each command and reply datagram, its acknowledgement or rejection, and
//! the Protocol Support Inquiry and reply that come before. One line per message, never one
//! per frame; stream data is not logged (the driver logs a stream's opening and end).

use openlcb_stream::{Mti, NodeId};

/// Logs `payload` of a message with `mti` from `source` to `destination` if it is a step of
/// Memory Configuration; `sent` tells the direction.
pub(crate) fn memory_step(sent: bool, mti: Mti, source: NodeId, destination: Option<NodeId>, payload: &[u8]) {
    if !tracing::enabled!(tracing::Level::DEBUG) {
        return;
    }
    let step = match mti {
        Mti::DATAGRAM => match payload {
            [0x20, command, rest @ ..] => format!("{} ({} bytes)", command_name(*command, rest), payload.len()),
            _ => return,
        },
        Mti::DATAGRAM_RECEIVED_OK => "Datagram Received OK".to_string(),
        Mti::DATAGRAM_REJECTED => match payload {
            [high, low, ..] => format!("Datagram Rejected 0x{:02X}{:02X}", high, low),
            _ => "Datagram Rejected".to_string(),
        },
        Mti::PROTOCOL_SUPPORT_INQUIRY => "Protocol Support Inquiry".to_string(),
        Mti::PROTOCOL_SUPPORT_REPLY => "Protocol Support Reply".to_string(),
        Mti::OPTIONAL_INTERACTION_REJECTED => "Optional Interaction Rejected".to_string(),
        _ => return,
    };
    let peer = if sent { destination } else { Some(source) };
    let peer = peer.map_or_else(|| "all".to_string(), |p| p.to_string());
    if sent {
        tracing::debug!(to = %peer, "memory config: sent {step}");
    } else {
        tracing::debug!(from = %peer, "memory config: received {step}");
    }
}

/// The name of Memory Configuration command byte `command` (MC §4), with the address and
/// space where it carries them.
fn command_name(command: u8, rest: &[u8]) -> String {
    let name = family(command);
    if command >= 0x80 {
        return match rest.first() {
            Some(space) if matches!(command, 0x84 | 0x86 | 0x87 | 0xA0 | 0xA1) => format!("{name} space 0x{space:02X}"),
            _ => name.to_string(),
        };
    }
    let Some((address, rest)) = rest.split_first_chunk::<4>() else { return name.to_string() };
    let space = match command & 0x03 {
        0x00 => rest.first().copied(),
        low => Some(0xFC | low),
    };
    let address = u32::from_be_bytes(*address);
    match space {
        Some(space) => format!("{name} space 0x{space:02X} at 0x{address:08X}"),
        None => format!("{name} at 0x{address:08X}"),
    }
}

/// The commands below 0x80, by their byte with the space bits (0x03) cleared (MC §4).
const ADDRESSED: [(u8, &str); 13] = [
    (0x00, "Write"),
    (0x08, "Write Under Mask"),
    (0x10, "Write Reply"),
    (0x18, "Write Reply (failed)"),
    (0x20, "Write Stream"),
    (0x30, "Write Stream Reply"),
    (0x38, "Write Stream Reply (failed)"),
    (0x40, "Read"),
    (0x50, "Read Reply"),
    (0x58, "Read Reply (failed)"),
    (0x60, "Read Stream"),
    (0x70, "Read Stream Reply"),
    (0x78, "Read Stream Reply (failed)"),
];

fn family(command: u8) -> &'static str {
    if let Some((_, name)) = ADDRESSED.iter().find(|(base, _)| command & !0x03 == *base) {
        return name;
    }
    match command {
        0x80 => "Get Configuration Options",
        0x82 => "Get Configuration Options Reply",
        0x84 => "Get Address Space Information",
        0x86 | 0x87 => "Get Address Space Information Reply",
        0x88 => "Lock",
        0x8A => "Lock Reply",
        0xA0 => "Unfreeze",
        0xA1 => "Freeze",
        0xA8 => "Update Complete",
        0xA9 => "Reset/Reboot",
        0xAA => "Factory Reset",
        _ => "command",
    }
}
