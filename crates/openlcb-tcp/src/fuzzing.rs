//! Entry points for the fuzz targets (feature `fuzzing`). Not a stable API.
//!
//! They check with `assert!`: a failed check is a finding.

use alloc::vec::Vec;

use openlcb_stream::{MessageRef, Mti, NodeId};

use crate::{CaptureTime, Decoder, HEADER_LEN, LinkPrefix, TcpFrame};

/// Piece lengths drawn from a seed: a small xorshift, so one input byte picks a whole cut.
struct PieceLengths(u32);

impl PieceLengths {
    fn next(&mut self) -> usize {
        self.0 ^= self.0 << 13;
        self.0 ^= self.0 >> 17;
        self.0 ^= self.0 << 5;
        // Mostly short pieces, sometimes long ones.
        let len = if self.0 & 0x100 == 0 { self.0 % 8 } else { self.0 % 300 };
        len as usize + 1
    }
}

/// Cuts `bytes` into pieces of lengths drawn from `seed`.
fn pieces(bytes: &[u8], seed: u8) -> impl Iterator<Item = &[u8]> {
    let mut lengths = PieceLengths(u32::from(seed) | 0x1_0000);
    let mut rest = bytes;
    core::iter::from_fn(move || {
        if rest.is_empty() {
            return None;
        }
        let (piece, tail) = rest.split_at(lengths.next().min(rest.len()));
        rest = tail;
        Some(piece)
    })
}

/// Arbitrary bytes in arbitrary pieces: the decoder must not panic, must use every byte it is
/// given, and must never hold more than twice its bound. The first byte picks the bound (small,
/// so over-long lengths are common), the second the cut.
pub fn decode_in_pieces(data: &[u8]) {
    let [bound, seed, bytes @ ..] = data else { return };
    let mut decoder = Decoder::new(26 + u32::from(*bound) * 3);
    let max = decoder.max_length() as usize;
    let mut delivered = 0u64;
    for piece in pieces(bytes, *seed) {
        let mut input = piece;
        while let Some(result) = decoder.decode(&mut input) {
            if let Ok(frame) = result {
                delivered += 1;
                assert!(frame.encoded_len() <= max + HEADER_LEN, "a delivered message exceeds the bound");
            }
        }
        assert!(input.is_empty(), "decode returned None with input left");
        assert!(decoder.buffered_capacity() <= 2 * max, "the decoder holds more than twice its bound");
    }
    assert_eq!(decoder.stats().messages, delivered);
    assert_eq!(decoder.stats().bytes, bytes.len() as u64);
    let _ = decoder.end_of_input();
}

/// What decodes re-encodes to the same bytes, and what encodes decodes to the same message.
///
/// 1. `data` is decoded in one piece; every whole (one-part) message re-encodes to the bytes
///    it came from, except reserved flag bits, which are sent as 0.
/// 2. `data` is read as a message (MTI, Node IDs, capture time, payload), encoded, decoded in
///    pieces cut by `data[0]`, and must come back equal and re-encode to the same bytes.
pub fn roundtrip(data: &[u8]) {
    reencode_what_decodes(data);
    decode_what_encodes(data);
}

fn reencode_what_decodes(data: &[u8]) {
    let mut decoder = Decoder::default();
    let mut input = data;
    let mut encoded = Vec::new();
    loop {
        let (before, parts_before) = (input, decoder.stats().parts);
        let Some(result) = decoder.decode(&mut input) else { break };
        let Ok(frame) = result else { continue };
        encoded.clear();
        assert!(frame.encode_to(&mut encoded).is_ok(), "a decoded message does not encode");
        if decoder.stats().parts != parts_before {
            continue; // reassembled: its bytes were spread over several parts
        }
        // A whole message is the tail of what this call consumed (link-control and chained
        // messages before it were skipped in the same call).
        let consumed = before.get(..before.len() - input.len()).unwrap_or_default();
        let original = consumed.len().checked_sub(encoded.len()).and_then(|start| consumed.get(start..));
        let flags = original.and_then(|o| o.first_chunk::<2>()).map(|f| u16::from_be_bytes(*f));
        assert_eq!(flags.map(|f| f & 0xCC00), Some(0x8000), "a whole message was delivered with unexpected flags");
        assert_eq!(original.and_then(|o| o.get(2..)), encoded.get(2..), "re-encoded bytes differ");
    }
}

fn decode_what_encodes(data: &[u8]) {
    let mut reader = data;
    let mut take = |n: usize| -> Option<&[u8]> {
        let (head, tail) = reader.split_at_checked(n)?;
        reader = tail;
        Some(head)
    };
    let (Some(&[seed]), Some(mti), Some(gateway), Some(time), Some(source), Some(destination)) =
        (take(1), take(2), take(6), take(6), take(6), take(6))
    else {
        return;
    };
    let mti = Mti(u16::from_be_bytes([mti.first().copied().unwrap_or(0), mti.get(1).copied().unwrap_or(0)]));
    let node = |bytes: &[u8]| NodeId::from_slice(bytes).unwrap_or_default();
    let message = MessageRef {
        mti,
        source: node(source),
        destination: mti.is_addressed().then(|| node(destination)),
        payload: reader,
    };
    let capture_time = CaptureTime::wrapping(NodeId::from_slice(time).map_or(0, NodeId::as_raw));
    let frame = TcpFrame::new(LinkPrefix { gateway: node(gateway), capture_time }, message);
    let mut encoded = Vec::new();
    assert_eq!(frame.encode_to(&mut encoded), Ok(frame.encoded_len()));

    let mut decoder = Decoder::new(crate::MAX_LENGTH);
    let mut decoded = 0;
    let mut reencoded = Vec::new();
    for piece in pieces(&encoded, seed) {
        let mut input = piece;
        while let Some(result) = decoder.decode(&mut input) {
            assert_eq!(result, Ok(frame), "the decoded message differs");
            if let Ok(back) = result {
                assert!(back.encode_to(&mut reencoded).is_ok());
            }
            decoded += 1;
        }
    }
    assert_eq!(decoded, 1);
    assert_eq!(reencoded, encoded, "re-encoded bytes differ");
    assert!(decoder.is_idle());
}
