//! Every OpenLCB-TCP byte vector of wire-spec §8 and §9.2, encoded and decoded byte for byte,
//! and decoded again from every way of cutting the bytes.

mod common;

use bytes::BytesMut;
use common::{VECTORS, hex};
use openlcb_stream::Message;
use openlcb_tcp::{Decoder, LinkPrefix, TcpFrame};

/// Decodes `pieces` in order with one decoder; every message as (prefix, owned message).
fn decode_pieces<'a>(pieces: impl IntoIterator<Item = &'a [u8]>) -> Vec<(LinkPrefix, Message)> {
    let mut decoder = Decoder::default();
    let mut out = Vec::new();
    for piece in pieces {
        let mut input = piece;
        while let Some(result) = decoder.decode(&mut input) {
            let frame = result.unwrap();
            out.push((frame.prefix, frame.message.to_message()));
        }
        assert!(input.is_empty());
    }
    assert_eq!(decoder.end_of_input(), Ok(()));
    out
}

#[test]
fn every_vector_encodes_byte_for_byte() {
    for v in VECTORS {
        let wire = hex(v.wire);
        let message = v.message();
        let frame = TcpFrame::new(v.prefix(), message.as_ref());
        assert_eq!(frame.encoded_len(), wire.len(), "{}", v.name);

        let mut buf = vec![0u8; wire.len() + 3];
        assert_eq!(frame.encode(&mut buf), Ok(wire.len()), "{}", v.name);
        assert_eq!(&buf[..wire.len()], &wire[..], "{}", v.name);

        let mut bytes_mut = BytesMut::from(&b"xy"[..]);
        assert_eq!(frame.encode_to(&mut bytes_mut), Ok(wire.len()));
        assert_eq!(&bytes_mut[2..], &wire[..], "{}", v.name);

        let mut vec = Vec::new();
        assert_eq!(frame.encode_to(&mut vec), Ok(wire.len()));
        assert_eq!(vec, wire, "{}", v.name);
    }
}

#[test]
fn every_vector_decodes_whole() {
    for v in VECTORS {
        let wire = hex(v.wire);
        let mut decoder = Decoder::default();
        let mut input = &wire[..];
        let frame = decoder.decode(&mut input).unwrap().unwrap();
        assert_eq!(frame, TcpFrame::new(v.prefix(), v.message().as_ref()), "{}", v.name);
        assert!(input.is_empty());
        assert!(decoder.decode(&mut input).is_none());
        assert_eq!(decoder.stats().messages, 1);
        assert_eq!(decoder.stats().bytes, wire.len() as u64);
    }
}

#[test]
fn every_vector_decodes_one_byte_at_a_time() {
    for v in VECTORS {
        let wire = hex(v.wire);
        assert_eq!(decode_pieces(wire.chunks(1)), [(v.prefix(), v.message())], "{}", v.name);
    }
}

#[test]
fn every_vector_decodes_split_at_every_boundary() {
    for v in VECTORS {
        let wire = hex(v.wire);
        for cut in 0..=wire.len() {
            let (head, tail) = wire.split_at(cut);
            assert_eq!(decode_pieces([head, tail]), [(v.prefix(), v.message())], "{} cut at {cut}", v.name);
        }
    }
}

#[test]
fn all_vectors_back_to_back_decode_in_order_from_any_cut() {
    let wire: Vec<u8> = VECTORS.iter().flat_map(|v| hex(v.wire)).collect();
    let expected: Vec<_> = VECTORS.iter().map(|v| (v.prefix(), v.message())).collect();
    assert_eq!(decode_pieces([&wire[..]]), expected);
    for piece_len in [1, 2, 3, 5, 7, 17, 31, 64] {
        assert_eq!(decode_pieces(wire.chunks(piece_len)), expected, "pieces of {piece_len}");
    }
    for cut in 0..=wire.len() {
        let (head, tail) = wire.split_at(cut);
        assert_eq!(decode_pieces([head, tail]), expected, "cut at {cut}");
    }
}
