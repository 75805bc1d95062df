//! The OpenLCB-TCP byte vectors of wire-spec §8 and §9.2, shared by the tests.

#![allow(dead_code, reason = "each test uses its own subset")]

use openlcb_stream::{Message, Mti, NodeId};
use openlcb_tcp::{CaptureTime, LinkPrefix};

/// One published or derived vector: the fields and the exact bytes on the link.
pub(crate) struct Vector {
    pub(crate) name: &'static str,
    pub(crate) gateway: u64,
    pub(crate) capture_time: u64,
    pub(crate) mti: u16,
    pub(crate) source: u64,
    pub(crate) destination: Option<u64>,
    pub(crate) payload: &'static [u8],
    pub(crate) wire: &'static str,
}

pub(crate) const A: u64 = 0x05_01_01_01_22_00;
pub(crate) const B: u64 = 0x05_01_01_01_22_01;

/// A → B with gateway A (wire-spec §9.2: gateway = the sending node).
const fn a_to_b(name: &'static str, capture_time: u64, mti: u16, payload: &'static [u8], wire: &'static str) -> Vector {
    Vector { name, gateway: A, capture_time, mti, source: A, destination: Some(B), payload, wire }
}

/// B → A with gateway B.
const fn b_to_a(name: &'static str, capture_time: u64, mti: u16, payload: &'static [u8], wire: &'static str) -> Vector {
    Vector { name, gateway: B, capture_time, mti, source: B, destination: Some(A), payload, wire }
}

pub(crate) const VECTORS: &[Vector] = &[
    // wire-spec §8, OpenMRN IfTcp.cxxtest: the published addressed message (length 0x28).
    Vector {
        name: "OpenMRN addressed 0x0A08",
        gateway: 0x10_11_12_13_14_15,
        capture_time: 0x42,
        mti: 0x0A08,
        source: 0x05_01_02_03_04_05,
        destination: Some(0x15_11_12_13_14_15),
        payload: b"abcdefghijklmn",
        wire: "80 00 00 00 28 10 11 12 13 14 15 00 00 00 00 00 42 0A 08 05 01 02 03 04 05 15 11 12 13 14 15
               61 62 63 64 65 66 67 68 69 6A 6B 6C 6D 6E",
    },
    // wire-spec §8: a global message (PCER 0x05B4, 8-byte Event ID) has length 0x1C. The spec
    // gives no Event ID; this one is the worked example's node followed by 00 01.
    Vector {
        name: "global PCER with Event ID",
        gateway: A,
        capture_time: 0x0102_0304_0506,
        mti: 0x05B4,
        source: A,
        destination: None,
        payload: &[0x05, 0x01, 0x01, 0x01, 0x22, 0x00, 0x00, 0x01],
        wire: "80 00 00 00 1C 05 01 01 01 22 00 01 02 03 04 05 06 05 B4 05 01 01 01 22 00 05 01 01 01 22 00 00 01",
    },
    // wire-spec §9.2, the worked transfer.
    a_to_b(
        "M1 Initiate Request",
        1,
        0x0CC8,
        &[0x00, 0x10, 0x00, 0x00, 0x04],
        "80 00 00 00 1F 05 01 01 01 22 00 00 00 00 00 00 01 0C C8 05 01 01 01 22 00 05 01 01 01 22 01 00 10 00 00 04",
    ),
    b_to_a(
        "M2 Initiate Reply",
        2,
        0x0868,
        &[0x00, 0x10, 0x80, 0x00, 0x04, 0x07],
        "80 00 00 00 20 05 01 01 01 22 01 00 00 00 00 00 02 08 68 05 01 01 01 22 01 05 01 01 01 22 00 00 10 80 00 04 07",
    ),
    a_to_b(
        "M3 Data Send 16 bytes",
        3,
        0x1F88,
        &[0x07, 0x00, 0x01, 0x02, 0x03, 0x04, 0x05, 0x06, 0x07, 0x08, 0x09, 0x0A, 0x0B, 0x0C, 0x0D, 0x0E, 0x0F],
        "80 00 00 00 2B 05 01 01 01 22 00 00 00 00 00 00 03 1F 88 05 01 01 01 22 00 05 01 01 01 22 01
         07 00 01 02 03 04 05 06 07 08 09 0A 0B 0C 0D 0E 0F",
    ),
    b_to_a(
        "M4 Proceed",
        4,
        0x0888,
        &[0x04, 0x07],
        "80 00 00 00 1C 05 01 01 01 22 01 00 00 00 00 00 04 08 88 05 01 01 01 22 01 05 01 01 01 22 00 04 07",
    ),
    a_to_b(
        "M5 Data Send 4 bytes",
        5,
        0x1F88,
        &[0x07, 0x10, 0x11, 0x12, 0x13],
        "80 00 00 00 1F 05 01 01 01 22 00 00 00 00 00 00 05 1F 88 05 01 01 01 22 00 05 01 01 01 22 01 07 10 11 12 13",
    ),
    a_to_b(
        "M6 Complete form A",
        6,
        0x08A8,
        &[0x04, 0x07],
        "80 00 00 00 1C 05 01 01 01 22 00 00 00 00 00 00 06 08 A8 05 01 01 01 22 00 05 01 01 01 22 01 04 07",
    ),
    a_to_b(
        "M6a Complete form B",
        7,
        0x08A8,
        &[0x04, 0x07, 0x00, 0x00, 0x00, 0x14],
        "80 00 00 00 20 05 01 01 01 22 00 00 00 00 00 00 07 08 A8 05 01 01 01 22 00 05 01 01 01 22 01 04 07 00 00 00 14",
    ),
    // M6b, M1c and M1u: the spec elides the prefix and Node IDs ("…"). They are rebuilt from the
    // full rows (gateway and source A, destination B) with capture times 8, 9 and 10, the gaps
    // in the numbering of the other variants; the flags, length, MTI and payload are as printed.
    a_to_b(
        "M6b Complete form D",
        8,
        0x08A8,
        &[0x04, 0x07, 0x00, 0x00, 0x00, 0x00, 0x14],
        "80 00 00 00 21 05 01 01 01 22 00 00 00 00 00 00 08 08 A8 05 01 01 01 22 00 05 01 01 01 22 01 04 07 00 00 00 00 14",
    ),
    a_to_b(
        "M1c Request 6-byte form",
        9,
        0x0CC8,
        &[0x00, 0x10, 0x00, 0x00, 0x04, 0xFF],
        "80 00 00 00 20 05 01 01 01 22 00 00 00 00 00 00 09 0C C8 05 01 01 01 22 00 05 01 01 01 22 01 00 10 00 00 04 FF",
    ),
    a_to_b(
        "M1u Request with UID",
        10,
        0x0CC8,
        &[0x00, 0x10, 0x00, 0x00, 0x04, 0xFF, 0x05, 0x01, 0x01, 0x01, 0x22, 0xFF],
        "80 00 00 00 26 05 01 01 01 22 00 00 00 00 00 00 0A 0C C8 05 01 01 01 22 00 05 01 01 01 22 01
         00 10 00 00 04 FF 05 01 01 01 22 FF",
    ),
    a_to_b(
        "zero-payload flush",
        14,
        0x1F88,
        &[0x07],
        "80 00 00 00 1B 05 01 01 01 22 00 00 00 00 00 00 0E 1F 88 05 01 01 01 22 00 05 01 01 01 22 01 07",
    ),
    b_to_a(
        "R1 reject by Reply",
        11,
        0x0868,
        &[0x00, 0x00, 0x20, 0x20, 0x04, 0x00],
        "80 00 00 00 20 05 01 01 01 22 01 00 00 00 00 00 0B 08 68 05 01 01 01 22 01 05 01 01 01 22 00 00 00 20 20 04 00",
    ),
    b_to_a(
        "R2 reject by OIR",
        12,
        0x0068,
        &[0x10, 0x43, 0x0C, 0xC8],
        "80 00 00 00 1E 05 01 01 01 22 01 00 00 00 00 00 0C 00 68 05 01 01 01 22 01 05 01 01 01 22 00 10 43 0C C8",
    ),
    b_to_a(
        "T1 destination aborts",
        13,
        0x00A8,
        &[0x20, 0x40, 0x1F, 0x88],
        "80 00 00 00 1E 05 01 01 01 22 01 00 00 00 00 00 0D 00 A8 05 01 01 01 22 01 05 01 01 01 22 00 20 40 1F 88",
    ),
];

pub(crate) fn hex(text: &str) -> Vec<u8> {
    text.split_whitespace().map(|byte| u8::from_str_radix(byte, 16).unwrap()).collect()
}

pub(crate) fn node(raw: u64) -> NodeId {
    NodeId::new(raw).unwrap()
}

impl Vector {
    pub(crate) fn prefix(&self) -> LinkPrefix {
        LinkPrefix { gateway: node(self.gateway), capture_time: CaptureTime::new(self.capture_time).unwrap() }
    }

    pub(crate) fn message(&self) -> Message {
        Message {
            mti: Mti(self.mti),
            source: node(self.source),
            destination: self.destination.map(node),
            payload: self.payload.to_vec(),
        }
    }
}

/// The vector called `name`.
pub(crate) fn vector(name: &str) -> &'static Vector {
    VECTORS.iter().find(|v| v.name == name).unwrap()
}
