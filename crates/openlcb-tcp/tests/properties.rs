//! Properties over any messages and any cut of the byte stream.

use openlcb_stream::{Message, Mti, NodeId};
use openlcb_tcp::{CaptureTime, Decoder, LinkPrefix, TcpFrame};
use proptest::prelude::*;

fn any_frame() -> impl Strategy<Value = (LinkPrefix, Message)> {
    let node = || (0..=NodeId::MAX.as_raw()).prop_map(|raw| NodeId::new(raw).unwrap());
    (node(), 0..=CaptureTime::MAX.as_raw(), any::<u16>(), node(), node(), prop::collection::vec(any::<u8>(), 0..300))
        .prop_map(|(gateway, time, mti, source, destination, payload)| {
            let mti = Mti(mti);
            let prefix = LinkPrefix { gateway, capture_time: CaptureTime::new(time).unwrap() };
            let destination = mti.is_addressed().then_some(destination);
            (prefix, Message { mti, source, destination, payload })
        })
}

proptest! {
    /// Messages encoded back to back come out of the decoder equal and in order, however the
    /// bytes are cut, and re-encode to the same bytes.
    #[test]
    fn any_messages_survive_any_cut(
        frames in prop::collection::vec(any_frame(), 1..8),
        cuts in prop::collection::vec(any::<prop::sample::Index>(), 0..12),
    ) {
        let mut wire = Vec::new();
        for (prefix, message) in &frames {
            TcpFrame::new(*prefix, message.as_ref()).encode_to(&mut wire).unwrap();
        }
        let mut cuts: Vec<usize> = cuts.iter().map(|i| i.index(wire.len() + 1)).collect();
        cuts.sort_unstable();
        let mut decoder = Decoder::default();
        let (mut decoded, mut reencoded, mut start) = (Vec::new(), Vec::new(), 0);
        for end in cuts.into_iter().chain([wire.len()]) {
            let mut input = &wire[start..end];
            start = end;
            while let Some(result) = decoder.decode(&mut input) {
                let frame = result.unwrap();
                frame.encode_to(&mut reencoded).unwrap();
                decoded.push((frame.prefix, frame.message.to_message()));
            }
            prop_assert!(input.is_empty());
        }
        prop_assert_eq!(decoded, frames);
        prop_assert_eq!(reencoded, wire);
        prop_assert!(decoder.is_idle());
    }

    /// Any bytes in any pieces: no panic, every byte used, never more than twice the bound held.
    #[test]
    fn any_bytes_keep_the_decoder_bounded(
        bytes in prop::collection::vec(any::<u8>(), 0..2000),
        piece_len in 1usize..64,
        max_length in 0u32..200,
    ) {
        let mut decoder = Decoder::new(max_length);
        for piece in bytes.chunks(piece_len) {
            let mut input = piece;
            while decoder.decode(&mut input).is_some() {}
            prop_assert!(input.is_empty());
            prop_assert!(decoder.buffered_capacity() <= 2 * decoder.max_length() as usize);
        }
        prop_assert_eq!(decoder.stats().bytes, bytes.len() as u64);
    }
}
