//! The published frames of wire-spec §7.5, §9.1 and §9.2, shared by the tests.

use openlcb_stream::Mti;

/// One format 1 or format 7 frame: its text and the message it carries.
pub struct Vector {
    pub text: &'static str,
    pub mti: Mti,
    pub source: u16,
    pub destination: u16,
    pub payload: &'static [u8],
}

const fn v(text: &'static str, mti: Mti, source: u16, destination: u16, payload: &'static [u8]) -> Vector {
    Vector { text, mti, source, destination, payload }
}

pub const REQ: Mti = Mti::STREAM_INITIATE_REQUEST;
pub const REPLY: Mti = Mti::STREAM_INITIATE_REPLY;
pub const DATA: Mti = Mti::STREAM_DATA_SEND;
pub const PROCEED: Mti = Mti::STREAM_DATA_PROCEED;
pub const COMPLETE: Mti = Mti::STREAM_DATA_COMPLETE;

/// §9.1 (a)-(d), every complete frame (the elided `:X1F4AA321N5A…` of (c) has no bytes).
pub const STREAM_TRACES: &[Vector] = &[
    // (a) OpenMRN StreamSender.cxxtest
    v(":X19CC822AN0225FFFF0000AAFF;", REQ, 0x22A, 0x225, &[0xFF, 0xFF, 0, 0, 0xAA, 0xFF]),
    v(":X19CC822AN0225EF320000AAFF;", REQ, 0x22A, 0x225, &[0xEF, 0x32, 0, 0, 0xAA, 0xFF]),
    v(":X19868225N022A00088000AA55;", REPLY, 0x225, 0x22A, &[0, 8, 0x80, 0, 0xAA, 0x55]),
    v(":X19868225N022A00001234AA55;", REPLY, 0x225, 0x22A, &[0, 0, 0x12, 0x34, 0xAA, 0x55]),
    v(":X1F22522AN55414243;", DATA, 0x22A, 0x225, &[0x55, 0x41, 0x42, 0x43]),
    v(":X1F22522AN554445464748494A;", DATA, 0x22A, 0x225, &[0x55, 0x44, 0x45, 0x46, 0x47, 0x48, 0x49, 0x4A]),
    v(":X1F22522AN554B4C;", DATA, 0x22A, 0x225, &[0x55, 0x4B, 0x4C]),
    v(":X19888225N022AAA55;", PROCEED, 0x225, 0x22A, &[0xAA, 0x55]),
    v(":X1F22522AN554D4E4F5051;", DATA, 0x22A, 0x225, &[0x55, 0x4D, 0x4E, 0x4F, 0x50, 0x51]),
    v(":X198A822AN0225AA5500000000;", COMPLETE, 0x22A, 0x225, &[0xAA, 0x55, 0, 0, 0, 0]),
    v(":X198A822AN0225AA5500000004;", COMPLETE, 0x22A, 0x225, &[0xAA, 0x55, 0, 0, 0, 4]),
    // (b) OpenMRN MemoryConfigStream.cxxtest
    v(":X19CC822AN077CFFFF00000237;", REQ, 0x22A, 0x77C, &[0xFF, 0xFF, 0, 0, 0x02, 0x37]),
    v(":X1986877CN022A00F080000237;", REPLY, 0x77C, 0x22A, &[0, 0xF0, 0x80, 0, 0x02, 0x37]),
    v(":X1F77C22AN3702030405060708;", DATA, 0x22A, 0x77C, &[0x37, 2, 3, 4, 5, 6, 7, 8]),
    v(":X1F77C22AN37090A0B0C0D0E;", DATA, 0x22A, 0x77C, &[0x37, 9, 10, 11, 12, 13, 14]),
    v(":X198A822AN077C02370000000D;", COMPLETE, 0x22A, 0x77C, &[0x02, 0x37, 0, 0, 0, 0x0D]),
    v(":X1986877CN022A00F021230237;", REPLY, 0x77C, 0x22A, &[0, 0xF0, 0x21, 0x23, 0x02, 0x37]),
    // (c) OpenMRN Bootloader.cxxtest
    v(":X19CC8321N04AA008000001A;", REQ, 0x321, 0x4AA, &[0, 0x80, 0, 0, 0x1A]),
    v(":X198684AAN0321008080001A5A;", REPLY, 0x4AA, 0x321, &[0, 0x80, 0x80, 0, 0x1A, 0x5A]),
    v(":X198884AAN03211A5A0000;", PROCEED, 0x4AA, 0x321, &[0x1A, 0x5A, 0, 0]),
    v(":X198A8321N04AA1A5A0000;", COMPLETE, 0x321, 0x4AA, &[0x1A, 0x5A, 0, 0]),
    v(":X198684AAN0321000042201A5A;", REPLY, 0x4AA, 0x321, &[0, 0, 0x42, 0x20, 0x1A, 0x5A]),
    // (d) Firmware Upgrade TN §4
    v(":X19CC83CCN04AAFFFF000055;", REQ, 0x3CC, 0x4AA, &[0xFF, 0xFF, 0, 0, 0x55]),
    v(":X198684AAN03CC01008000555A;", REPLY, 0x4AA, 0x3CC, &[0x01, 0, 0x80, 0, 0x55, 0x5A]),
    v(":X1F4AA3CCN5AA5456112B50B99;", DATA, 0x3CC, 0x4AA, &[0x5A, 0xA5, 0x45, 0x61, 0x12, 0xB5, 0x0B, 0x99]),
    v(":X198884AAN03CC555A0000;", PROCEED, 0x4AA, 0x3CC, &[0x55, 0x5A, 0, 0]),
    v(":X198A83CCN04AA555A;", COMPLETE, 0x3CC, 0x4AA, &[0x55, 0x5A]),
];

/// Every other published frame text: the CID sequences of §7.5, the worked example of §9.2
/// (logins, messages, variants, AME/AMR) and the GridConnect examples of §9.
pub const OTHER_FRAMES: &[&str] = &[
    ":X17020555N;",
    ":X1610D555N;",
    ":X15000555N;",
    ":X14003555N;",
    ":X10700555N;",
    ":X17123FEDN;",
    ":X16456FEDN;",
    ":X15789FEDN;",
    ":X14ABCFEDN;",
    ":X10700FEDN;",
    ":X17050123N;",
    ":X16101123N;",
    ":X15012123N;",
    ":X14200123N;",
    ":X10700123N;",
    ":X10701123N050101012200;",
    ":X19100123N050101012200;",
    ":X17050456N;",
    ":X16101456N;",
    ":X15012456N;",
    ":X14201456N;",
    ":X10700456N;",
    ":X10701456N050101012201;",
    ":X19100456N050101012201;",
    ":X19CC8123N04560010000004;",
    ":X19868456N0123001080000407;",
    ":X1F456123N0700010203040506;",
    ":X1F456123N070708090A0B0C0D;",
    ":X1F456123N070E0F;",
    ":X19888456N01230407;",
    ":X1F456123N0710111213;",
    ":X198A8123N04560407;",
    ":X198A8123N0456040700000014;",
    ":X198A8123N1456040700000000;",
    ":X198A8123N245614;",
    ":X19CC8123N04560010000004FF;",
    ":X19CC8123N14560010000004FF;",
    ":X19CC8123N24560501010122FF;",
    ":X19CC8123N1456001000000407;",
    ":X1F456123N07;",
    ":X19868456N0123000020200400;",
    ":X19068456N012310430CC8;",
    ":X190A8456N012320401F88;",
    ":X10702123N;",
    ":X10702123N050101012201;",
    ":X10703456N050101012201;",
    ":X19A0822AN13FB353433320037;",
    ":X19A0822AN33FB383500013031;",
    ":X19A0822AN23FB3435363700;",
    ":X195B4576NF0F1F2F3F4F5F6F7;",
];

/// Every published extended frame text.
pub fn all_frames() -> impl Iterator<Item = &'static str> {
    STREAM_TRACES.iter().map(|v| v.text).chain(OTHER_FRAMES.iter().copied())
}
