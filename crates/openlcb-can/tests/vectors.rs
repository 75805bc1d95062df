//! Every published frame of wire-spec §7.2, §7.5 and §9.1, produced and accepted byte for
//! byte: each is decoded from its GridConnect text, re-encoded to the same text, read through
//! the typed header and the core's wire types, and built again from the full-format message.

mod common;

use common::published::{COMPLETE, DATA, REPLY, REQ, STREAM_TRACES};
use common::{alias, frame, node_id, text};
use openlcb_can::{AliasLogin, CanHeader, Fragments, FrameKind, FramePosition, Reassembler, ReassemblyKey};
use openlcb_stream::wire::{
    CompleteCount, DataComplete, DataProceed, DataSend, InitiateReply, InitiateRequest, ReplyClass, ReplyCode,
};
use openlcb_stream::{Duration, Instant, Mti, StreamId};

/// Accepted: text -> frame -> header and payload equal the vector; the frame re-encodes to the
/// same text. Produced: the message split by `Fragments` gives the same single frame.
#[test]
fn stream_traces_accepted_and_produced_byte_for_byte() {
    for vector in STREAM_TRACES {
        let received = frame(vector.text);
        assert_eq!(text(&received), vector.text, "re-encoding");
        let header = received.header().unwrap();
        assert_eq!(header.source, alias(vector.source), "{}", vector.text);
        assert_eq!(header.mti(), Some(vector.mti), "{}", vector.text);
        let payload = if vector.mti == DATA {
            assert_eq!(header.kind, FrameKind::StreamData { destination: alias(vector.destination) });
            received.payload()
        } else {
            let data = received.payload();
            assert_eq!(FramePosition::from_flags(data[0]), FramePosition::Only, "{}", vector.text);
            assert_eq!(u16::from_be_bytes([data[0] & 0x0F, data[1]]), vector.destination);
            &data[2..]
        };
        assert_eq!(payload, vector.payload, "{}", vector.text);

        let produced: Vec<String> =
            Fragments::new(vector.mti, alias(vector.source), Some(alias(vector.destination)), vector.payload)
                .unwrap()
                .map(|f| text(&f))
                .collect();
        assert_eq!(produced, [vector.text]);
    }
}

/// The payloads mean what §9.1 says they mean, read by the core's wire types.
#[test]
fn stream_traces_parse_as_documented() {
    let payload = |text: &str| {
        let f = frame(text);
        let data = f.payload().to_vec();
        if f.header().unwrap().mti() == Some(DATA) { data } else { data[2..].to_vec() }
    };
    let sid = |raw| StreamId::new(raw).unwrap();

    let request = InitiateRequest::parse(&payload(":X19CC822AN0225EF320000AAFF;")).unwrap();
    assert_eq!(
        (request.max_buffer_size, request.source_stream, request.proposed_destination),
        (0xEF32, sid(0xAA), None)
    );
    let request = InitiateRequest::parse(&payload(":X19CC822AN077CFFFF00000237;")).unwrap();
    assert_eq!(request.proposed_destination, Some(sid(0x37)));
    let request = InitiateRequest::parse(&payload(":X19CC8321N04AA008000001A;")).unwrap();
    assert_eq!((request.max_buffer_size, request.source_stream), (0x80, sid(0x1A)));

    let reply = InitiateReply::parse(&payload(":X19868225N022A00088000AA55;")).unwrap();
    assert_eq!(
        (reply.max_buffer_size, reply.class(), reply.destination_stream),
        (8, ReplyClass::Accepted, Some(sid(0x55)))
    );
    let reject = InitiateReply::parse(&payload(":X19868225N022A00001234AA55;")).unwrap();
    assert_eq!(reject.code, ReplyCode(0x1234));
    assert_ne!(reject.class(), ReplyClass::Accepted);
    // Code 0x2123 with a non-zero buffer is still a reject: bit 0x8000 is clear.
    let reject = InitiateReply::parse(&payload(":X1986877CN022A00F021230237;")).unwrap();
    assert_eq!((reject.max_buffer_size, reject.code), (0xF0, ReplyCode(0x2123)));
    assert_ne!(reject.class(), ReplyClass::Accepted);

    let data = payload(":X1F4AA3CCN5AA5456112B50B99;");
    let send = DataSend::parse(&data).unwrap();
    assert_eq!((send.destination_stream, send.data.len()), (sid(0x5A), 7));

    let proceed = DataProceed::parse(&payload(":X198884AAN03CC555A0000;")).unwrap();
    assert_eq!((proceed.source_stream, proceed.destination_stream), (sid(0x55), sid(0x5A)));

    let complete = DataComplete::parse(&payload(":X198A822AN077C02370000000D;")).unwrap();
    assert_eq!(complete.count, CompleteCount::Total(13));
    let complete = DataComplete::parse(&payload(":X198A83CCN04AA555A;")).unwrap();
    assert_eq!(complete.count, CompleteCount::Unknown);
}

/// §7.2: the SNIP reply of OpenMRN's SimpleInfoProtocol.cxxtest, first and last frames as
/// published, reassembled and produced again.
#[test]
fn multi_frame_snip_reply_first_and_last_frames() {
    let first = ":X19A0822AN13FB353433320037;";
    let middle = ":X19A0822AN33FB383500013031;";
    let last = ":X19A0822AN23FB3435363700;";
    let mut reassembler = Reassembler::new(1, 64, Duration::from_secs(3));
    let key = ReassemblyKey { source: alias(0x22A), destination: alias(0x3FB), mti: Mti(0xA08) };
    let mut whole = Vec::new();
    for (text_in, position) in
        [(first, FramePosition::First), (middle, FramePosition::Middle), (last, FramePosition::Last)]
    {
        let f = frame(text_in);
        assert_eq!(common::text(&f), text_in);
        assert_eq!(f.header().unwrap().kind, FrameKind::Message { can_mti: 0xA08 });
        assert_eq!(FramePosition::from_flags(f.payload()[0]), position);
        if let Some(done) = reassembler.push(Instant::ZERO, key, position, &f.payload()[2..]).unwrap() {
            whole = done.to_vec();
        }
    }
    assert_eq!(
        whole,
        [0x35, 0x34, 0x33, 0x32, 0x00, 0x37, 0x38, 0x35, 0x00, 0x01, 0x30, 0x31, 0x34, 0x35, 0x36, 0x37, 0x00]
    );
    let produced: Vec<String> =
        Fragments::new(Mti(0x0A08), alias(0x22A), Some(alias(0x3FB)), &whole[..]).unwrap().map(|f| text(&f)).collect();
    assert_eq!(produced, [first, middle, last]);
}

/// §7.5: the CID frames of OpenMRN's AliasAllocator.cxxtest (Node ID 02.01.0D.00.00.03,
/// alias 0x555) and of the CAN Frame Transfer TN (12.34.56.78.9A.BC, alias 0xFED), produced by
/// the login, and accepted as Check ID frames carrying the Node ID's bits.
#[test]
fn published_cid_sequences() {
    let cases: [(u64, u16, [&str; 5]); 2] = [
        (0x0201_0D00_0003, 0x555, [":X17020555N;", ":X1610D555N;", ":X15000555N;", ":X14003555N;", ":X10700555N;"]),
        (0x1234_5678_9ABC, 0xFED, [":X17123FEDN;", ":X16456FEDN;", ":X15789FEDN;", ":X14ABCFEDN;", ":X10700FEDN;"]),
    ];
    for (node, first_alias, expected) in cases {
        let mut login =
            AliasLogin::new(Instant::ZERO, node_id(node), Some(alias(first_alias)), Duration::from_millis(200));
        let mut sent: Vec<String> = core::iter::from_fn(|| login.poll_transmit()).map(|f| text(&f)).collect();
        login.handle_timeout(Instant::from_millis(200));
        sent.extend(core::iter::from_fn(|| login.poll_transmit()).map(|f| text(&f)));
        assert_eq!(sent[..5], expected);
        assert_eq!(sent[5], format!(":X10701{first_alias:03X}N{node:012X};"), "AMD follows RID");

        let mut rebuilt = 0u64;
        for (i, cid) in expected[..4].iter().enumerate() {
            let header = CanHeader::parse(frame(cid).raw_id()).unwrap();
            let FrameKind::CheckId { sequence, node_id_bits } = header.kind else { panic!("{cid} is not a CID") };
            assert_eq!(usize::from(sequence), 7 - i);
            rebuilt = rebuilt << 12 | u64::from(node_id_bits);
        }
        assert_eq!(rebuilt, node);
        assert_eq!(CanHeader::parse(frame(expected[4]).raw_id()).unwrap().kind, FrameKind::ReserveId);
    }
}

/// §9.2 variants: the multi-frame forms, the flush, rejects, AME and AMR.
#[test]
fn worked_example_variants() {
    /// MTI, source alias, destination alias, payload, published frames.
    type Case = (Mti, u16, u16, &'static [u8], &'static [&'static str]);
    let cases: [Case; 7] = [
        (COMPLETE, 0x123, 0x456, &[4, 7, 0, 0, 0, 0, 0x14], &[":X198A8123N1456040700000000;", ":X198A8123N245614;"]),
        (REQ, 0x123, 0x456, &[0, 0x10, 0, 0, 4, 0xFF], &[":X19CC8123N04560010000004FF;"]),
        (
            REQ,
            0x123,
            0x456,
            &[0, 0x10, 0, 0, 4, 0xFF, 5, 1, 1, 1, 0x22, 0xFF],
            &[":X19CC8123N14560010000004FF;", ":X19CC8123N24560501010122FF;"],
        ),
        (
            REQ,
            0x123,
            0x456,
            &[0, 0x10, 0, 0, 4, 7, 5, 1, 1, 1, 0x22, 0xFF],
            &[":X19CC8123N1456001000000407;", ":X19CC8123N24560501010122FF;"],
        ),
        (DATA, 0x123, 0x456, &[7], &[":X1F456123N07;"]),
        (REPLY, 0x456, 0x123, &[0, 0, 0x20, 0x20, 4, 0], &[":X19868456N0123000020200400;"]),
        (Mti::OPTIONAL_INTERACTION_REJECTED, 0x456, 0x123, &[0x10, 0x43, 0x0C, 0xC8], &[":X19068456N012310430CC8;"]),
    ];
    for (mti, source, destination, payload, expected) in cases {
        let produced: Vec<String> =
            Fragments::new(mti, alias(source), Some(alias(destination)), payload).unwrap().map(|f| text(&f)).collect();
        assert_eq!(produced, expected);
    }
    let tde =
        Fragments::new(Mti::TERMINATE_DUE_TO_ERROR, alias(0x456), Some(alias(0x123)), &[0x20, 0x40, 0x1F, 0x88][..]);
    assert_eq!(tde.unwrap().map(|f| text(&f)).collect::<Vec<_>>(), [":X190A8456N012320401F88;"]);
    for (text_in, kind) in [
        (":X10702123N;", FrameKind::AliasMapEnquiry),
        (":X10702123N050101012201;", FrameKind::AliasMapEnquiry),
        (":X10703456N050101012201;", FrameKind::AliasMapReset),
    ] {
        let f = frame(text_in);
        assert_eq!(f.header().unwrap().kind, kind);
        assert_eq!(text(&f), text_in);
    }
}

/// Every published frame text decodes, has a valid OpenLCB header whose identifier rebuilds
/// the same bits, and re-encodes to the same text.
#[test]
fn every_published_frame_round_trips() {
    let mut count = 0;
    for published in common::published::all_frames() {
        let f = frame(published);
        let header = f.header().unwrap_or_else(|e| panic!("{published}: {e}"));
        assert_eq!(header.to_id(), f.raw_id(), "{published}");
        assert_eq!(text(&f), published);
        count += 1;
    }
    assert_eq!(count, common::published::STREAM_TRACES.len() + common::published::OTHER_FRAMES.len());
}
