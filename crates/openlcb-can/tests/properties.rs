//! Properties of framing: whatever is split into frames comes back whole, and every frame
//! respects the layout rules of wire-spec §7.2 and §7.3 and node-protocols §2.5.

use openlcb_can::gridconnect::{self, GridConnectDecoder};
use openlcb_can::{CanHeader, Fragments, FrameKind, FramePosition, NodeAlias, Reassembler, ReassemblyKey};
use openlcb_stream::{Duration, Instant, Mti};
use proptest::prelude::*;

fn alias(raw: u16) -> NodeAlias {
    NodeAlias::new(raw).unwrap()
}

proptest! {
    #[test]
    fn addressed_messages_reassemble_to_themselves(
        payload in proptest::collection::vec(any::<u8>(), 0..=300),
        can_mti in prop_oneof![Just(0x0CC8u16), Just(0x0868), Just(0x08A8), Just(0x0A08)],
    ) {
        let (source, destination) = (alias(0x123), alias(0x456));
        let frames: Vec<_> = Fragments::new(Mti(can_mti), source, Some(destination), &payload[..]).unwrap().collect();
        prop_assert_eq!(frames.len(), payload.len().div_ceil(6).max(1));
        let mut reassembler = Reassembler::new(1, 300, Duration::from_secs(3));
        let key = ReassemblyKey { source, destination, mti: Mti(can_mti) };
        let mut whole = None;
        for (i, frame) in frames.iter().enumerate() {
            let data = frame.payload();
            let last = i + 1 == frames.len();
            // First and middle frames carry 8 bytes; every frame names the destination.
            prop_assert!(last || data.len() == 8);
            prop_assert_eq!(u16::from_be_bytes([data[0] & 0x0F, data[1]]), 0x456);
            let position = FramePosition::from_flags(data[0]);
            if let Some(done) = reassembler.push(Instant::ZERO, key, position, &data[2..]).unwrap() {
                prop_assert!(last);
                whole = Some(done.to_vec());
            }
        }
        prop_assert_eq!(whole, Some(payload));
    }

    #[test]
    fn stream_data_frames_carry_the_did_and_seven_bytes_each(
        did in 0u8..0xFF,
        data in proptest::collection::vec(any::<u8>(), 0..=200),
    ) {
        let payload: Vec<u8> = std::iter::once(did).chain(data.iter().copied()).collect();
        let frames: Vec<_> =
            Fragments::new(Mti::STREAM_DATA_SEND, alias(0x123), Some(alias(0x456)), &payload[..]).unwrap().collect();
        prop_assert_eq!(frames.len(), data.len().div_ceil(7).max(1));
        let mut joined = Vec::new();
        for frame in &frames {
            prop_assert_eq!(frame.raw_id(), 0x1F45_6123);
            prop_assert_eq!(frame.payload()[0], did);
            prop_assert!(!frame.payload().is_empty());
            joined.extend_from_slice(&frame.payload()[1..]);
        }
        prop_assert_eq!(joined, data);
    }

    #[test]
    fn datagrams_reassemble_to_themselves(payload in proptest::collection::vec(any::<u8>(), 0..=72)) {
        let (source, destination) = (alias(0x123), alias(0x456));
        let frames: Vec<_> = Fragments::new(Mti::DATAGRAM, source, Some(destination), &payload[..]).unwrap().collect();
        prop_assert_eq!(frames.len(), payload.len().div_ceil(8).max(1));
        let mut reassembler = Reassembler::for_datagrams(1, Duration::from_secs(3));
        let key = ReassemblyKey { source, destination, mti: Mti::DATAGRAM };
        let mut whole = None;
        for (i, frame) in frames.iter().enumerate() {
            let header = CanHeader::parse(frame.raw_id()).unwrap();
            let FrameKind::Datagram { frame: part, destination: to } = header.kind else {
                return Err(TestCaseError::fail("not a datagram frame"));
            };
            prop_assert_eq!((to, header.source), (destination, source));
            let position = part.position();
            let last = i + 1 == frames.len();
            // All but the last frame are full; a middle frame is never empty.
            prop_assert!(last || frame.payload().len() == 8);
            prop_assert_eq!(position.is_last(), last);
            let done = if position == FramePosition::Only {
                Some(frame.payload().to_vec())
            } else {
                reassembler.push(Instant::ZERO, key, position, frame.payload()).unwrap().map(<[u8]>::to_vec)
            };
            if let Some(done) = done {
                prop_assert!(last);
                whole = Some(done);
            }
        }
        prop_assert_eq!(whole, Some(payload));
    }

    #[test]
    fn gridconnect_round_trips_any_extended_frame(
        id in 0u32..0x2000_0000,
        data in proptest::collection::vec(any::<u8>(), 0..=8),
    ) {
        let frame = openlcb_can::CanFrame::extended(id, &data).unwrap();
        let mut buf = [0u8; gridconnect::MAX_ENCODED_LEN];
        let n = gridconnect::encode(&frame, &mut buf).unwrap();
        prop_assert_eq!(n, 12 + 2 * data.len());
        let mut input = &buf[..n];
        prop_assert_eq!(GridConnectDecoder::new().decode(&mut input), Some(Ok(frame)));
    }
}
