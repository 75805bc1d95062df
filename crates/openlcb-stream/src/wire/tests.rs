//! Parse, emit and reject cases per message type. Payload vectors are the data bytes of the
//! published frames in wire-spec §9.1 (after the 2-byte `fddd` header) and the full-format
//! column of §9.2.

use super::*;
use crate::ContentUid;

fn sid(raw: u8) -> StreamId {
    StreamId::new(raw).unwrap()
}

fn emitted(msg: &impl Emit) -> std::vec::Vec<u8> {
    msg.to_bytes().to_vec()
}

// ----- Initiate Request -----

#[test]
fn request_parse_six_byte_openmrn_form() {
    // 9.1(a) `:X19CC822AN0225FFFF0000AAFF;`
    let r = InitiateRequest::parse(&[0xFF, 0xFF, 0x00, 0x00, 0xAA, 0xFF]).unwrap();
    assert_eq!(r.max_buffer_size, 0xFFFF);
    assert_eq!(r.source_stream, sid(0xAA));
    assert_eq!(r.proposed_destination, None, "byte 5 = FF means no proposal");
    assert_eq!(r.content_uid, None);
    // 9.1(b) `:X19CC822AN077CFFFF00000237;` proposes DID 0x37.
    let r = InitiateRequest::parse(&[0xFF, 0xFF, 0x00, 0x00, 0x02, 0x37]).unwrap();
    assert_eq!((r.source_stream, r.proposed_destination), (sid(2), Some(sid(0x37))));
}

#[test]
fn request_parse_five_byte_form() {
    // 9.1(c) `:X19CC8321N04AA008000001A;` and 9.1(d) `:X19CC83CCN04AAFFFF000055;`
    let r = InitiateRequest::parse(&[0x00, 0x80, 0x00, 0x00, 0x1A]).unwrap();
    assert_eq!((r.max_buffer_size, r.source_stream, r.proposed_destination), (0x80, sid(0x1A), None));
    let r = InitiateRequest::parse(&[0xFF, 0xFF, 0x00, 0x00, 0x55]).unwrap();
    assert_eq!((r.max_buffer_size, r.source_stream), (0xFFFF, sid(0x55)));
}

#[test]
fn request_parse_twelve_bytes_with_uid() {
    // 9.2 M1u: UID 05.01.01.01.22.FF, no DID proposal.
    let r = InitiateRequest::parse(&[0x00, 0x10, 0x00, 0x00, 0x04, 0xFF, 0x05, 0x01, 0x01, 0x01, 0x22, 0xFF]).unwrap();
    assert_eq!(r.content_uid, ContentUid::new([5, 1, 1, 1, 0x22, 0xFF]));
    assert_eq!(r.proposed_destination, None);
    // 7..=11 bytes carry no UID; an all-zero UID is none.
    assert_eq!(InitiateRequest::parse(&[0, 0x10, 0, 0, 4, 7, 5, 1, 1]).unwrap().content_uid, None);
    assert_eq!(InitiateRequest::parse(&[0, 0x10, 0, 0, 4, 7, 0, 0, 0, 0, 0, 0]).unwrap().content_uid, None);
}

#[test]
fn request_parse_ignores_flags() {
    let r = InitiateRequest::parse(&[0x00, 0x10, 0x01, 0x80, 0x04]).unwrap();
    assert_eq!(emitted(&r), [0x00, 0x10, 0x00, 0x00, 0x04], "flags are sent as 0");
}

#[test]
fn request_reject_short_zero_buffer_and_reserved_sid() {
    assert_eq!(
        InitiateRequest::parse(&[0x00, 0x10, 0x00, 0x00]),
        Err(DecodeError::TooShort { mti: Mti::STREAM_INITIATE_REQUEST, needed: 5, got: 4 })
    );
    assert_eq!(InitiateRequest::parse(&[0x00, 0x00, 0x00, 0x00, 0x04]), Err(DecodeError::ZeroBufferSize));
    assert!(matches!(
        InitiateRequest::parse(&[0x00, 0x10, 0x00, 0x00, 0xFF]),
        Err(DecodeError::ReservedStreamId { field: "SID", .. })
    ));
}

#[test]
fn request_emit_picks_5_6_or_12_bytes() {
    // 9.2 M1, M1c-with-DID, M1u, and the same proposing DID 07.
    let mut r =
        InitiateRequest { max_buffer_size: 16, source_stream: sid(4), proposed_destination: None, content_uid: None };
    assert_eq!(emitted(&r), [0x00, 0x10, 0x00, 0x00, 0x04]);
    r.proposed_destination = Some(sid(7));
    assert_eq!(emitted(&r), [0x00, 0x10, 0x00, 0x00, 0x04, 0x07]);
    r.content_uid = ContentUid::new([5, 1, 1, 1, 0x22, 0xFF]);
    assert_eq!(emitted(&r), [0x00, 0x10, 0x00, 0x00, 0x04, 0x07, 0x05, 0x01, 0x01, 0x01, 0x22, 0xFF]);
    r.proposed_destination = None;
    assert_eq!(emitted(&r), [0x00, 0x10, 0x00, 0x00, 0x04, 0xFF, 0x05, 0x01, 0x01, 0x01, 0x22, 0xFF]);
    assert_eq!(r.emit(&mut [0u8; 11]), Err(BufferTooSmall { needed: 12, got: 11 }));
}

// ----- Initiate Reply -----

#[test]
fn reply_parse_accept_and_reject() {
    // 9.1(a) `:X19868225N022A00088000AA55;` accept, buffer 8.
    let r = InitiateReply::parse(&[0x00, 0x08, 0x80, 0x00, 0xAA, 0x55]).unwrap();
    assert!(r.is_accepted());
    assert_eq!((r.max_buffer_size, r.source_stream, r.destination_stream), (8, sid(0xAA), Some(sid(0x55))));
    // `...00001234AA55;` reject code 0x1234, buffer 0: permanent.
    let r = InitiateReply::parse(&[0x00, 0x00, 0x12, 0x34, 0xAA, 0x55]).unwrap();
    assert!(!r.is_accepted());
    assert_eq!((r.code, r.class()), (ReplyCode(0x1234), ReplyClass::Permanent));
    // 9.1(b) reject variant: 0x2123 with a non-zero buffer is still a reject (temporary).
    let r = InitiateReply::parse(&[0x00, 0xF0, 0x21, 0x23, 0x02, 0x37]).unwrap();
    assert_eq!((r.is_accepted(), r.class()), (false, ReplyClass::Temporary));
    // 9.1(c) OpenMRN bootloader's old bit-field code 0x4220: a reject, taken as permanent.
    let r = InitiateReply::parse(&[0x00, 0x00, 0x42, 0x20, 0x1A, 0x5A]).unwrap();
    assert_eq!(r.class(), ReplyClass::Permanent);
}

#[test]
fn reply_parse_accepts_code_zero_with_buffer_and_skips_text() {
    // Wire-spec Q4: 0x0000 with a non-zero buffer is an accept (2026 draft, C library).
    let r = InitiateReply::parse(&[0x00, 0x40, 0x00, 0x00, 0x04, 0x07]).unwrap();
    assert_eq!(r.class(), ReplyClass::Accepted);
    // Accept code with buffer 0 cannot open anything.
    let r = InitiateReply::parse(&[0x00, 0x00, 0x80, 0x00, 0x04, 0x07]).unwrap();
    assert_eq!((r.is_accepted(), r.class()), (false, ReplyClass::Permanent));
    // Optional error text after byte 5.
    let r = InitiateReply::parse(b"\x00\x00\x10\x40\x04\x00no such content\0").unwrap();
    assert_eq!(r.code, ReplyCode::UNIMPLEMENTED);
    // A reject naming DID 0xFF is still a reject.
    assert_eq!(InitiateReply::parse(&[0, 0, 0x20, 0x20, 4, 0xFF]).unwrap().destination_stream, None);
}

#[test]
fn reply_reject_short_and_reserved_sid() {
    assert!(matches!(InitiateReply::parse(&[0, 8, 0x80, 0, 4]), Err(DecodeError::TooShort { needed: 6, got: 5, .. })));
    assert!(matches!(InitiateReply::parse(&[0, 8, 0x80, 0, 0xFF, 7]), Err(DecodeError::ReservedStreamId { .. })));
}

#[test]
fn reply_emit_accept_and_rejects() {
    // 9.2 M2 and R1.
    let accept = InitiateReply {
        max_buffer_size: 16,
        code: ReplyCode::ACCEPT,
        source_stream: sid(4),
        destination_stream: Some(sid(7)),
    };
    assert_eq!(emitted(&accept), [0x00, 0x10, 0x80, 0x00, 0x04, 0x07]);
    let reject = InitiateReply {
        max_buffer_size: 0,
        code: ReplyCode::BUFFER_UNAVAILABLE,
        source_stream: sid(4),
        destination_stream: Some(sid(0)),
    };
    assert_eq!(emitted(&reject), [0x00, 0x00, 0x20, 0x20, 0x04, 0x00]);
    // A parsed 0xFF round-trips; the endpoint itself never sends one (see states.rs).
    let odd = InitiateReply::parse(&[0, 0, 0x20, 0x20, 4, 0xFF]).unwrap();
    assert_eq!(emitted(&odd), [0x00, 0x00, 0x20, 0x20, 0x04, 0xFF]);
}

#[test]
fn reply_code_classes() {
    assert_eq!(ReplyCode::ACCEPT.class(), ReplyClass::Accepted);
    assert_eq!(ReplyCode(0x0000).class(), ReplyClass::Accepted);
    for code in [0x1000, 0x1010, 0x1020, 0x1040, 0x1080] {
        assert_eq!(ReplyCode(code).class(), ReplyClass::Permanent, "{code:#06x}");
    }
    for code in [0x2000, 0x2020, 0x2040] {
        assert_eq!(ReplyCode(code).class(), ReplyClass::Temporary, "{code:#06x}");
    }
    assert_eq!(format!("{}", ReplyCode::BUFFER_UNAVAILABLE), "0x2020 (buffer unavailable (destination busy))");
}

// ----- Data Send -----

#[test]
fn data_send_parse_and_emit() {
    // 9.1(a) `:X1F22522AN55414243;` DID 55 + "ABC"; 9.2 zero-payload flush `07`.
    let d = DataSend::parse(&[0x55, 0x41, 0x42, 0x43]).unwrap();
    assert_eq!((d.destination_stream, d.data), (sid(0x55), &b"ABC"[..]));
    assert_eq!(emitted(&d), [0x55, 0x41, 0x42, 0x43]);
    let flush = DataSend::parse(&[0x07]).unwrap();
    assert!(flush.data.is_empty());
    assert_eq!(emitted(&flush), [0x07]);
    assert_eq!(d.emit(&mut [0u8; 3]), Err(BufferTooSmall { needed: 4, got: 3 }));
}

#[test]
fn data_send_reject_empty_and_reserved_did() {
    assert!(matches!(DataSend::parse(&[]), Err(DecodeError::TooShort { needed: 1, got: 0, .. })));
    assert!(matches!(DataSend::parse(&[0xFF, 1, 2]), Err(DecodeError::ReservedStreamId { field: "DID", .. })));
}

// ----- Data Proceed -----

#[test]
fn proceed_parse_two_and_four_bytes() {
    // 9.2 M4 `04 07`; 9.1(c) 4-byte form `1A 5A 00 00`; flags ignored.
    assert_eq!(
        DataProceed::parse(&[0x04, 0x07]).unwrap(),
        DataProceed { source_stream: sid(4), destination_stream: sid(7) }
    );
    assert_eq!(DataProceed::parse(&[0x1A, 0x5A, 0x00, 0x00]).unwrap().destination_stream, sid(0x5A));
    assert_eq!(DataProceed::parse(&[0x1A, 0x5A, 0x12, 0x34]).unwrap().source_stream, sid(0x1A));
}

#[test]
fn proceed_emit_four_bytes_as_openmrn_and_openlcb_java_expect() {
    let p = DataProceed { source_stream: sid(0xAA), destination_stream: sid(0x55) };
    assert_eq!(emitted(&p), [0xAA, 0x55, 0x00, 0x00]);
}

#[test]
fn proceed_reject_short_and_reserved() {
    assert!(matches!(DataProceed::parse(&[4]), Err(DecodeError::TooShort { needed: 2, .. })));
    assert!(DataProceed::parse(&[0xFF, 7]).is_err());
    assert!(DataProceed::parse(&[4, 0xFF]).is_err());
}

// ----- Data Complete -----

#[test]
fn complete_parse_all_forms_by_length() {
    let c = |p: &[u8]| DataComplete::parse(p).unwrap().count;
    assert_eq!(c(&[0x55, 0x5A]), CompleteCount::Unknown, "form A, 9.1(d)");
    assert_eq!(c(&[0x1A, 0x5A, 0x00, 0x00]), CompleteCount::Unknown, "form C, 9.1(c)");
    assert_eq!(c(&[0xAA, 0x55, 0, 0, 0, 4]), CompleteCount::Total(4), "form B, 9.1(a)");
    assert_eq!(c(&[0xAA, 0x55, 0, 0, 0, 0]), CompleteCount::Total(0), "0 is zero bytes (C-10)");
    assert_eq!(c(&[0xAA, 0x55, 0xFF, 0xFF, 0xFF, 0xFF]), CompleteCount::Unknown, "all ones is unknown");
    assert_eq!(c(&[0x04, 0x07, 0, 0, 0, 0, 0x14]), CompleteCount::Modulo24(20), "form D, 9.2 M6b");
    assert_eq!(c(&[0x04, 0x07, 0]), CompleteCount::Unknown, "3 bytes: IDs kept, no count");
    assert_eq!(c(&[0x04, 0x07, 0, 0, 0]), CompleteCount::Unknown, "5 bytes: IDs kept, no count");
    assert_eq!(DataComplete::parse(&[0x02, 0x37, 0, 0, 0, 0x0D]).unwrap().source_stream, sid(2));
}

#[test]
fn complete_emit_form_b_or_a() {
    // 9.2 M6a (count 20) and M6 (no count).
    let mut c = DataComplete { source_stream: sid(4), destination_stream: sid(7), count: CompleteCount::Total(20) };
    assert_eq!(emitted(&c), [0x04, 0x07, 0x00, 0x00, 0x00, 0x14]);
    c.count = CompleteCount::Unknown;
    assert_eq!(emitted(&c), [0x04, 0x07]);
    c.count = CompleteCount::Modulo24(20);
    assert_eq!(emitted(&c), [0x04, 0x07, 0, 0, 0, 0, 0x14]);
}

#[test]
fn complete_reject_short_and_reserved() {
    assert!(matches!(DataComplete::parse(&[4]), Err(DecodeError::TooShort { needed: 2, .. })));
    assert!(DataComplete::parse(&[0xFF, 7, 0, 0, 0, 0]).is_err());
}

#[test]
fn complete_count_missing_is_modular() {
    assert_eq!(CompleteCount::Unknown.missing_after(10), None);
    assert_eq!(CompleteCount::Total(20).missing_after(16), Some(4));
    assert_eq!(CompleteCount::Total(3).missing_after(u64::from(u32::MAX) + 2), Some(2));
    assert_eq!(CompleteCount::Modulo24(5).missing_after(0x0100_0003), Some(2));
    assert_eq!(CompleteCount::Total(10).missing_after(12), Some(u64::from(u32::MAX) - 1));
}

// ----- OIR / TDE -----

#[test]
fn error_report_parse_full_and_short() {
    // 9.2 R2 (OIR 0x1043 for 0x0CC8) and T1 (TDE 0x2040 for 0x1F88).
    assert_eq!(
        ErrorReport::parse(&[0x10, 0x43, 0x0C, 0xC8]),
        ErrorReport { code: ErrorCode::NOT_IMPLEMENTED_MTI, mti: Some(Mti::STREAM_INITIATE_REQUEST) }
    );
    assert_eq!(ErrorReport::parse(&[0x20, 0x40, 0x1F, 0x88, 0xDE, 0xAD]).mti, Some(Mti::STREAM_DATA_SEND));
    // OpenMRN's bootloader sends just the code; some send nothing.
    assert_eq!(ErrorReport::parse(&[0x10, 0x10]), ErrorReport { code: ErrorCode(0x1010), mti: None });
    assert_eq!(ErrorReport::parse(&[]), ErrorReport { code: ErrorCode(0), mti: None });
    assert_eq!(ErrorReport::parse(&[0x20, 0x40, 0x1F]).mti, None);
}

#[test]
fn error_report_emit() {
    let tde = ErrorReport { code: ErrorCode::OUT_OF_ORDER, mti: Some(Mti::STREAM_DATA_SEND) };
    assert_eq!(emitted(&tde), [0x20, 0x40, 0x1F, 0x88]);
    assert_eq!(emitted(&ErrorReport { code: ErrorCode(0x1080), mti: None }), [0x10, 0x80]);
    assert!(ErrorCode(0x1080).is_permanent() && ErrorCode::TIMEOUT.is_temporary());
}

#[test]
fn strict_forms_round_trip_byte_for_byte() {
    let requests: [&[u8]; 3] =
        [&[0, 0x80, 0, 0, 0x1A], &[0xFF, 0xFF, 0, 0, 2, 0x37], &[0, 0x10, 0, 0, 4, 0xFF, 5, 1, 1, 1, 0x22, 0xFF]];
    for payload in requests {
        assert_eq!(emitted(&InitiateRequest::parse(payload).unwrap()), payload);
    }
    let completes: [&[u8]; 3] = [&[0x55, 0x5A], &[0xAA, 0x55, 0, 0, 0, 4], &[4, 7, 0, 0, 0, 0, 0x14]];
    for payload in completes {
        assert_eq!(emitted(&DataComplete::parse(payload).unwrap()), payload);
    }
    let reply = [0x01, 0x00, 0x80, 0x00, 0x55, 0x5A];
    assert_eq!(emitted(&InitiateReply::parse(&reply).unwrap()), reply);
}
