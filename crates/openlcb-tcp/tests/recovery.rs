//! Bad input and its defined recovery (wire-spec §8): over-long and malformed lengths close the
//! link, link-control and chained messages are skipped, reserved bits are ignored, multi-part
//! messages are reassembled within the bound or rejected, truncated input is reported.

use openlcb_stream::{Message, Mti, NodeId};
use openlcb_tcp::{CaptureTime, DecodeError, Decoder, EncodeError, LinkPrefix, Part, TcpFrame};

const A: u64 = 0x05_01_01_01_22_00;
const B: u64 = 0x05_01_01_01_22_01;
const C: u64 = 0x05_01_01_01_22_02;

fn node(raw: u64) -> NodeId {
    NodeId::new(raw).unwrap()
}

fn prefix(gateway: u64, time: u64) -> LinkPrefix {
    LinkPrefix { gateway: node(gateway), capture_time: CaptureTime::new(time).unwrap() }
}

/// M3 of wire-spec §9.2: A sends 16 bytes to B on DID 7.
fn data_send() -> Message {
    let mut payload = vec![0x07];
    payload.extend(0u8..16);
    Message::addressed(Mti::STREAM_DATA_SEND, node(A), node(B), payload)
}

/// The encoded bytes of `message` behind `prefix`.
fn encode(prefix: LinkPrefix, message: &Message) -> Vec<u8> {
    let mut out = Vec::new();
    TcpFrame::new(prefix, message.as_ref()).encode_to(&mut out).unwrap();
    out
}

/// One link message with any flags and body (the bytes the length counts).
fn raw(flags: u16, body: &[u8]) -> Vec<u8> {
    let length = u32::try_from(body.len()).unwrap().to_be_bytes();
    let mut out = flags.to_be_bytes().to_vec();
    out.extend_from_slice(&length[1..]);
    out.extend_from_slice(body);
    out
}

/// `message` cut into parts at `cuts` (offsets into MTI + Node IDs + payload), each part with
/// the gateway `gateway` and capture times counting up from `time`.
fn parts(gateway: u64, time: u64, message: &Message, cuts: &[usize]) -> Vec<Vec<u8>> {
    let whole = encode(prefix(gateway, time), message);
    let content = &whole[17..];
    let mut bounds = vec![0];
    bounds.extend_from_slice(cuts);
    bounds.push(content.len());
    let count = bounds.len() - 1;
    (0..count)
        .map(|i| {
            let part = match i {
                0 => Part::First,
                i if i == count - 1 => Part::Last,
                _ => Part::Middle,
            };
            let mut body = prefix(gateway, time + i as u64).gateway.to_bytes().to_vec();
            body.extend_from_slice(&CaptureTime::new(time + i as u64).unwrap().to_bytes());
            body.extend_from_slice(&content[bounds[i]..bounds[i + 1]]);
            raw(0x8000 | part.flag_bits(), &body)
        })
        .collect()
}

/// What one decode call produced, owned.
#[derive(Debug, PartialEq)]
enum Out {
    Message(LinkPrefix, Message),
    Error(DecodeError),
}

/// Decodes `input` in pieces of `piece_len` bytes with `decoder`.
fn decode_with(decoder: &mut Decoder, input: &[u8], piece_len: usize) -> Vec<Out> {
    let mut out = Vec::new();
    for piece in input.chunks(piece_len.max(1)) {
        let mut piece = piece;
        while let Some(result) = decoder.decode(&mut piece) {
            out.push(match result {
                Ok(frame) => Out::Message(frame.prefix, frame.message.to_message()),
                Err(error) => Out::Error(error),
            });
        }
        assert!(piece.is_empty(), "decode returned None with input left");
    }
    out
}

/// Decodes `input` whole, one byte at a time and in pieces of 7; all three must agree.
fn decode_all_ways(max_length: u32, input: &[u8]) -> (Vec<Out>, Decoder) {
    let mut whole = Decoder::new(max_length);
    let expected = decode_with(&mut whole, input, input.len());
    for piece_len in [1, 7] {
        let mut decoder = Decoder::new(max_length);
        assert_eq!(decode_with(&mut decoder, input, piece_len), expected, "pieces of {piece_len}");
        assert_eq!(decoder.stats(), whole.stats(), "pieces of {piece_len}");
        assert_eq!(decoder.end_of_input(), whole.end_of_input(), "pieces of {piece_len}");
    }
    (expected, whole)
}

fn ok(gateway: u64, time: u64, message: Message) -> Out {
    Out::Message(prefix(gateway, time), message)
}

// ----- lengths that close the link -----

#[test]
fn over_long_length_fails_the_decoder_before_buffering() {
    let mut bytes = raw(0x8000, &[0u8; 101]);
    bytes.extend(encode(prefix(A, 1), &data_send()));
    let (out, decoder) = decode_all_ways(100, &bytes);
    let error = DecodeError::LengthTooLong { length: 101, max: 100 };
    assert_eq!(out, [Out::Error(error)]);
    assert!(error.closes_link());
    assert_eq!(decoder.failure(), Some(error));
    assert_eq!(decoder.end_of_input(), Err(error));
    assert_eq!(decoder.buffered_capacity(), 0);
}

#[test]
fn length_shorter_than_prefix_mti_and_source_fails_the_decoder() {
    let (out, decoder) = decode_all_ways(100, &raw(0x8000, &[0u8; 19]));
    let error = DecodeError::LengthTooShort { length: 19, needed: 20 };
    assert_eq!(out, [Out::Error(error)]);
    assert_eq!(decoder.failure(), Some(error));
}

#[test]
fn length_without_room_for_the_destination_of_an_addressed_mti_fails_the_decoder() {
    // The Proceed of §9.2 with its length cut to 25: the addressed MTI needs 26.
    let mut body = encode(prefix(B, 4), &Message::addressed(Mti::STREAM_DATA_PROCEED, node(B), node(A), vec![4, 7]));
    body.drain(..5);
    body.truncate(25);
    let mut bytes = raw(0x8000, &body);
    bytes.extend(encode(prefix(A, 5), &data_send()));
    let (out, decoder) = decode_all_ways(100, &bytes);
    let error = DecodeError::LengthTooShort { length: 25, needed: 26 };
    assert_eq!(out, [Out::Error(error)]);
    assert_eq!(decoder.failure(), Some(error));
}

#[test]
fn a_failed_decoder_discards_everything_after() {
    let mut decoder = Decoder::new(100);
    let mut input = &raw(0x8000, &[0u8; 200])[..];
    assert!(matches!(decoder.decode(&mut input), Some(Err(DecodeError::LengthTooLong { .. }))));
    let good = encode(prefix(A, 1), &data_send());
    let mut input = &good[..];
    assert!(decoder.decode(&mut input).is_none());
    assert!(input.is_empty());
    assert_eq!(decoder.stats().messages, 0);
}

// ----- messages skipped, decoding goes on -----

#[test]
fn link_control_messages_are_skipped_by_their_length_and_counted() {
    let mut bytes = raw(0x0000, &[0xAA; 7]);
    bytes.extend(raw(0x7FFF, &[]));
    bytes.extend(encode(prefix(A, 3), &data_send()));
    let (out, decoder) = decode_all_ways(100, &bytes);
    assert_eq!(out, [ok(A, 3, data_send())]);
    assert_eq!(decoder.stats().link_control_skipped, 2);
    assert_eq!(decoder.end_of_input(), Ok(()));
}

#[test]
fn link_control_message_over_the_bound_is_skipped_without_buffering() {
    let length = 5000;
    let mut bytes = raw(0x0000, &vec![0x55; length]);
    bytes.extend(encode(prefix(A, 3), &data_send()));
    let mut decoder = Decoder::new(100);
    // Pieces of 64 leave the data message whole in one piece: nothing at all is buffered.
    assert_eq!(decode_with(&mut decoder, &bytes, 64), [ok(A, 3, data_send())]);
    assert_eq!(decoder.buffered_capacity(), 0);
    assert_eq!(decoder.stats().link_control_skipped, 1);
}

#[test]
fn chained_message_is_rejected_and_skipped() {
    let mut chained = encode(prefix(A, 1), &data_send());
    chained[0] = 0xC0;
    let mut bytes = chained;
    bytes.extend(encode(prefix(A, 2), &data_send()));
    let (out, decoder) = decode_all_ways(100, &bytes);
    let error = DecodeError::Chained { flags: 0xC000 };
    assert_eq!(out, [Out::Error(error), ok(A, 2, data_send())]);
    assert!(!error.closes_link());
    assert_eq!(decoder.stats().chained_skipped, 1);
    assert_eq!(
        error.to_string(),
        "flags field 0xC000 has the chaining bit 0x4000 set; chained prefixes are not supported"
    );
}

#[test]
fn reserved_flag_bits_are_ignored() {
    let mut bytes = encode(prefix(A, 1), &data_send());
    bytes[0] = 0xB3;
    bytes[1] = 0xFF;
    let (out, _) = decode_all_ways(100, &bytes);
    assert_eq!(out, [ok(A, 1, data_send())]);
}

// ----- multi-part -----

#[test]
fn multi_part_message_is_reassembled_with_the_first_parts_prefix() {
    for cuts in [&[10][..], &[1, 2, 3], &[8, 14, 20], &[0, 31]] {
        let bytes = parts(A, 3, &data_send(), cuts).concat();
        let (out, decoder) = decode_all_ways(100, &bytes);
        assert_eq!(out, [ok(A, 3, data_send())], "cuts {cuts:?}");
        assert_eq!(decoder.stats().parts, cuts.len() as u64 + 1);
        assert_eq!(decoder.stats().messages, 1);
        assert_eq!(decoder.end_of_input(), Ok(()));
    }
}

#[test]
fn whole_messages_between_parts_are_delivered() {
    let p = parts(A, 3, &data_send(), &[10]);
    let proceed = Message::addressed(Mti::STREAM_DATA_PROCEED, node(B), node(A), vec![4, 7]);
    let bytes = [p[0].clone(), encode(prefix(B, 9), &proceed), p[1].clone()].concat();
    let (out, _) = decode_all_ways(100, &bytes);
    assert_eq!(out, [ok(B, 9, proceed), ok(A, 3, data_send())]);
}

#[test]
fn multi_part_message_within_the_bound_is_accepted_and_over_it_rejected() {
    // data_send() has 31 bytes of MTI, Node IDs and payload: length 43 as a whole message.
    let bytes = parts(A, 3, &data_send(), &[10, 20]).concat();
    assert_eq!(decode_all_ways(43, &bytes).0, [ok(A, 3, data_send())]);
    let proceed = Message::addressed(Mti::STREAM_DATA_PROCEED, node(B), node(A), vec![4, 7]);
    let mut over = bytes;
    over.extend(encode(prefix(B, 9), &proceed));
    let (out, decoder) = decode_all_ways(42, &over);
    assert_eq!(out, [Out::Error(DecodeError::PartsTooLong { max: 42 }), ok(B, 9, proceed)]);
    assert_eq!(decoder.stats().parts_rejected, 1);
    assert_eq!(decoder.end_of_input(), Ok(()));
    assert!(decoder.buffered_capacity() <= 2 * 42);

    // Over the bound at the middle part: the error comes once, the last part is dropped quietly.
    let (out, decoder) = decode_all_ways(26, &parts(A, 3, &data_send(), &[10, 20]).concat());
    assert_eq!(out, [Out::Error(DecodeError::PartsTooLong { max: 26 })]);
    assert_eq!(decoder.end_of_input(), Ok(()));
}

#[test]
fn part_without_a_first_part_is_rejected() {
    let p = parts(A, 3, &data_send(), &[10, 20]);
    for stray in [&p[1], &p[2]] {
        let flags = u16::from_be_bytes([stray[0], stray[1]]);
        let (out, _) = decode_all_ways(100, stray);
        assert_eq!(out, [Out::Error(DecodeError::PartWithoutFirst { flags })]);
    }
}

#[test]
fn a_new_first_part_drops_the_unfinished_message() {
    let old = parts(A, 3, &data_send(), &[10]);
    let new = parts(A, 7, &data_send(), &[12]);
    let bytes = [old[0].clone(), new[0].clone(), new[1].clone()].concat();
    let (out, decoder) = decode_all_ways(100, &bytes);
    assert_eq!(out, [Out::Error(DecodeError::PartsInterrupted), ok(A, 7, data_send())]);
    assert_eq!(decoder.stats().parts_rejected, 1);
}

#[test]
fn part_from_another_gateway_is_rejected_and_reassembly_goes_on() {
    let ours = parts(A, 3, &data_send(), &[10]);
    let theirs = parts(C, 5, &data_send(), &[10]);
    let bytes = [ours[0].clone(), theirs[1].clone(), ours[1].clone()].concat();
    let (out, _) = decode_all_ways(100, &bytes);
    let error = DecodeError::PartFromOtherGateway { expected: node(A), got: node(C) };
    assert_eq!(out, [Out::Error(error), ok(A, 3, data_send())]);
}

#[test]
fn parts_too_short_for_mti_and_node_ids_are_rejected() {
    let first = raw(0x8400, &[prefix(A, 1).gateway.to_bytes(), [0, 0, 0, 0, 0, 1]].concat());
    let last = raw(
        0x8800,
        &[&prefix(A, 2).gateway.to_bytes()[..], &[0, 0, 0, 0, 0, 2, 0x1F, 0x88, 5, 1, 1, 1, 0x22]].concat(),
    );
    let (out, decoder) = decode_all_ways(100, &[first, last].concat());
    assert_eq!(out, [Out::Error(DecodeError::PartsTooShort { got: 7, needed: 14 })]);
    assert_eq!(decoder.end_of_input(), Ok(()));
}

#[test]
fn part_shorter_than_the_link_prefix_fails_the_decoder() {
    let (out, decoder) = decode_all_ways(100, &raw(0x8400, &[0u8; 11]));
    let error = DecodeError::LengthTooShort { length: 11, needed: 12 };
    assert_eq!(out, [Out::Error(error)]);
    assert_eq!(decoder.failure(), Some(error));
}

// ----- truncated input -----

#[test]
fn truncated_input_is_reported_at_its_end() {
    let whole = encode(prefix(A, 1), &data_send());
    for (cut, missing) in [(3, 2), (5, 43), (30, 18), (whole.len() - 1, 1)] {
        let mut decoder = Decoder::default();
        assert_eq!(decode_with(&mut decoder, &whole[..cut], 1), []);
        assert_eq!(decoder.end_of_input(), Err(DecodeError::Truncated { missing }), "cut at {cut}");
        assert!(!decoder.is_idle());
    }
    let mut decoder = Decoder::default();
    let first = &parts(A, 3, &data_send(), &[10])[0];
    assert_eq!(decode_with(&mut decoder, first, 4), []);
    assert_eq!(decoder.end_of_input(), Err(DecodeError::PartsUnfinished));
}

#[test]
fn truncated_link_control_message_is_reported() {
    let mut decoder = Decoder::default();
    assert_eq!(decode_with(&mut decoder, &raw(0x0000, &[1, 2, 3])[..6], 2), []);
    assert_eq!(decoder.end_of_input(), Err(DecodeError::Truncated { missing: 2 }));
}

// ----- encoder refusals -----

#[test]
fn encoder_refuses_a_short_buffer_and_inconsistent_destinations() {
    let message = data_send();
    let frame = TcpFrame::new(prefix(A, 1), message.as_ref());
    let mut short = [0u8; 47];
    assert_eq!(frame.encode(&mut short), Err(EncodeError::BufferTooSmall { needed: 48, got: 47 }));
    assert_eq!(short, [0u8; 47], "nothing is written to a buffer that is too small");

    let mut missing = message.clone();
    missing.destination = None;
    let mut buf = [0u8; 64];
    let frame = TcpFrame::new(prefix(A, 1), missing.as_ref());
    assert_eq!(frame.encode(&mut buf), Err(EncodeError::MissingDestination { mti: Mti::STREAM_DATA_SEND }));

    let global = Message::addressed(Mti::VERIFY_NODE_ID_GLOBAL, node(A), node(B), vec![]);
    let frame = TcpFrame::new(prefix(A, 1), global.as_ref());
    let mut vec = Vec::new();
    assert_eq!(frame.encode_to(&mut vec), Err(EncodeError::UnexpectedDestination { mti: Mti::VERIFY_NODE_ID_GLOBAL }));
    assert!(vec.is_empty());
}

#[test]
fn encoder_refuses_a_length_over_24_bits() {
    let payload = vec![0u8; 0xFF_FFFF - 25];
    let message = Message::addressed(Mti::STREAM_DATA_SEND, node(A), node(B), payload);
    let mut out = Vec::new();
    let frame = TcpFrame::new(prefix(A, 1), message.as_ref());
    assert_eq!(frame.encode_to(&mut out), Err(EncodeError::TooLong { length: 0x100_0000 }));
    assert!(out.is_empty());
    let fits = Message { payload: message.payload[1..].to_vec(), ..message };
    assert_eq!(TcpFrame::new(prefix(A, 1), fits.as_ref()).encode_to(&mut out), Ok(0x100_0004));
}
