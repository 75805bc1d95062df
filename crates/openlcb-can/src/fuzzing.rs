//! Entry points for the fuzz targets in `fuzz/`. Not a stable API.
//!
//! Assertions here are the fuzzers' oracles, so panicking and indexing are the point.
#![allow(clippy::indexing_slicing, clippy::panic, clippy::expect_used, clippy::unwrap_used, missing_docs)]

use alloc::vec::Vec;

use embedded_can::{ExtendedId, Frame, Id, StandardId};
use openlcb_stream::{Duration, Instant, MessageRef, Mti, NodeId, PeerChange, PeerChanges, Receiver};

use crate::gridconnect::{self, GridConnectDecoder, GridConnectError};
use crate::{CanConfig, CanFrame, CanHeader, CanLink, MAX_DATAGRAM_LEN, NodeAlias};

const LOCAL_NODE: u64 = 0x0501_0101_2200;
const LOCAL_ALIAS: u16 = 0x123;

/// The layer above for the targets: messages go to a closure, peer changes are checked.
struct Above<F> {
    deliver: F,
}

fn above<F: FnMut(MessageRef<'_>)>(deliver: F) -> Above<F> {
    Above { deliver }
}

impl<F> PeerChanges for Above<F> {
    fn peer_changed(&mut self, change: PeerChange) {
        if let PeerChange::Renamed { from, to } = change {
            assert_ne!(from, to, "a rename that changes nothing");
        }
    }
}

impl<F: FnMut(MessageRef<'_>)> Receiver for Above<F> {
    fn handle_message(&mut self, _now: Instant, message: MessageRef<'_>) {
        (self.deliver)(message);
    }

    fn medium_busy(&mut self, _now: Instant) {}
}

/// A link for 05.01.01.01.22.00 with small bounds, already permitted as alias 0x123.
fn permitted_link() -> CanLink {
    let config = CanConfig {
        first_alias: NodeAlias::new(LOCAL_ALIAS),
        alias_cache_size: 4,
        reassembly_slots: 2,
        max_message_len: 32,
        transmit_queue_limit: 8,
        unresolved_limit: 4,
        frame_queue_limit: 4,
        datagram_slots: 2,
        ..CanConfig::default()
    };
    let mut link = CanLink::new(Instant::ZERO, NodeId::new(LOCAL_NODE).unwrap(), config);
    link.handle_timeout(Instant::from_millis(200), &mut above(|_| {}));
    while link.poll_transmit().is_some() {}
    while link.poll_event().is_some() {}
    link
}

/// Drains the link and checks its bounds.
fn drain_and_check(link: &mut CanLink) -> Vec<CanFrame> {
    let mut frames = Vec::new();
    while let Some(frame) = link.poll_transmit() {
        assert!(frame.dlc() <= 8);
        assert!(frame.header().is_ok(), "the link sends valid OpenLCB frames only");
        frames.push(frame);
        assert!(frames.len() < 10_000, "poll_transmit never ends");
    }
    let mut events = 0;
    while link.poll_event().is_some() {
        events += 1;
        assert!(events < 10_000, "poll_event never ends");
    }
    assert!(link.queued_messages() <= link.config().transmit_queue_limit + 1);
    frames
}

/// Datagram Rejected frames among `frames`, per source of `sources` they answer.
fn rejections_to(frames: &[CanFrame], sources: &[u16], counts: &mut [u32]) {
    for frame in frames.iter().filter(|f| f.raw_id() >> 12 == 0x19A48) {
        let to = frame.payload().get(..2).map(|b| u16::from_be_bytes([b[0], b[1]]) & 0xFFF);
        if let Some(i) = sources.iter().position(|s| Some(*s) == to) {
            if let Some(count) = counts.get_mut(i) {
                *count += 1;
            }
        }
    }
}

fn check_delivery(max_len: usize) -> impl FnMut(openlcb_stream::MessageRef<'_>) {
    move |msg| assert!(msg.payload.len() <= max_len.max(8), "delivered {} bytes", msg.payload.len())
}

/// Any identifier and data: through the typed header (which must round-trip), GridConnect
/// (which must round-trip) and a permitted `CanLink`.
pub fn can_frame(data: &[u8]) {
    let Some((id_bytes, rest)) = data.split_first_chunk::<4>() else {
        return;
    };
    let raw = u32::from_be_bytes(*id_bytes);
    let (flags, payload) = rest.split_first().map_or((0, &[][..]), |(f, p)| (*f, p));
    let payload = &payload[..payload.len().min(8)];
    let frame = match flags % 4 {
        0 | 1 => CanFrame::extended(raw, payload).unwrap(),
        2 => CanFrame::new(Id::Standard(StandardId::new((raw & 0x7FF) as u16).unwrap()), payload).unwrap(),
        _ => CanFrame::new_remote(Id::Extended(ExtendedId::new(raw & 0x1FFF_FFFF).unwrap()), payload.len()).unwrap(),
    };
    if let Ok(header) = CanHeader::parse(raw & 0x1FFF_FFFF) {
        assert_eq!(header.to_id() | 0x1000_0000, raw & 0x1FFF_FFFF | 0x1000_0000, "header round trip");
        assert_eq!(CanHeader::parse(header.to_id()), Ok(header));
    }
    let mut text = [0u8; gridconnect::MAX_ENCODED_LEN];
    let n = gridconnect::encode(&frame, &mut text).unwrap();
    let mut decoder = GridConnectDecoder::new();
    let mut input = &text[..n];
    let decoded = decoder.decode(&mut input);
    if frame.is_extended() && !frame.is_remote_frame() {
        assert_eq!(decoded, Some(Ok(frame)), "GridConnect round trip");
    } else {
        assert_eq!(decoded, None, "standard and remote frames are skipped");
    }
    let mut link = permitted_link();
    let max_len = link.config().max_message_len;
    link.handle_frame(Instant::from_millis(300), &frame, &mut above(check_delivery(max_len)));
    drain_and_check(&mut link);
}

/// Arbitrary frame sequences into one permitted link: frames from four peer aliases (some
/// known, some not), addressed to us or not, with every framing flag, interleaved with
/// time steps. No panic; every queue stays within its bound.
pub fn can_reassembly(data: &[u8]) {
    const MTIS: [u16; 8] = [0xCC8, 0x868, 0x888, 0x8A8, 0x068, 0x0A8, 0x488, 0xA08];
    let mut link = permitted_link();
    let max_len = link.config().max_message_len;
    let mut now = Instant::from_millis(300);
    // Two peers known, two not.
    for (alias, node) in [(0x456u32, 0x0501_0101_2201u64), (0x789, 0x0501_0101_2202)] {
        let amd = CanFrame::extended(0x1070_1000 | alias, &NodeId::new(node).unwrap().to_bytes()).unwrap();
        link.handle_frame(now, &amd, &mut above(check_delivery(max_len)));
    }
    for op in data.chunks(4) {
        let [selector, a, b, c] = [0, 1, 2, 3].map(|i| op.get(i).copied().unwrap_or(0));
        let source = [0x456u32, 0x789, 0xABC, LOCAL_ALIAS.into()][usize::from(a & 3)];
        let destination = if a & 4 == 0 { LOCAL_ALIAS } else { 0x456 };
        let flags = (a >> 3) & 3;
        let mut payload = [0u8; 8];
        payload[0] = flags << 4 | (destination >> 8) as u8;
        payload[1] = destination as u8;
        payload[2] = b;
        payload[3] = c;
        let len = 2 + usize::from(c % 7);
        let frame = match selector % 8 {
            0..=3 => CanFrame::extended(
                0x1900_0000 | u32::from(MTIS[usize::from(selector >> 5)]) << 12 | source,
                &payload[..len],
            ),
            4 => CanFrame::extended(0x1F00_0000 | u32::from(destination) << 12 | source, &payload[1..1 + len.min(7)]),
            5 => {
                let node = [0x0501_0101_2201u64, 0x0501_0101_2202, 0x0501_0101_2203, LOCAL_NODE][usize::from(b & 3)];
                let kind = [0x1070_1000u32, 0x1070_3000, 0x1070_2000, 0x1917_0000][usize::from(c & 3)];
                CanFrame::extended(kind | source, &NodeId::new(node).unwrap().to_bytes())
            }
            6 => {
                now += Duration::from_millis(u64::from(b) * 20);
                link.handle_timeout(now, &mut above(|_| {}));
                None
            }
            _ => CanFrame::extended(0x1070_2000 | source, &[]),
        };
        if let Some(frame) = frame {
            link.handle_frame(now, &frame, &mut above(check_delivery(max_len)));
        }
        drain_and_check(&mut link);
    }
    if let Some(deadline) = link.poll_timeout() {
        link.handle_timeout(deadline, &mut above(|_| {}));
        drain_and_check(&mut link);
    }
}

/// Arbitrary datagram frames (formats 2-5) from three peers (two known, one not), with AMRs
/// and time steps, into one permitted link with two datagram slots. The oracle is a model of
/// the reassembly rules: every datagram delivered must equal the concatenated bytes of the
/// frames that made it, and be delivered exactly when the model completes one; reassembly
/// memory stays within its bound and no buffer grows.
pub fn can_datagram(data: &[u8]) {
    const SOURCES: [u16; 3] = [0x456, 0x789, 0xABC];
    const TIMEOUT_MS: u64 = 3000;
    let mut link = permitted_link();
    let allocated = link.reassembly_allocated();
    let slots = link.config().datagram_slots;
    let mut now = Instant::from_millis(300);
    for (alias, node) in [(0x456u32, 0x0501_0101_2201u64), (0x789, 0x0501_0101_2202)] {
        let amd = CanFrame::extended(0x1070_1000 | alias, &NodeId::new(node).unwrap().to_bytes()).unwrap();
        link.handle_frame(now, &amd, &mut above(|_| {}));
    }
    drain_and_check(&mut link);
    // Per source: the bytes of the open datagram and the time of its first frame.
    let mut model: [Option<(Vec<u8>, Instant)>; 3] = [None, None, None];
    // Per source: Datagram Rejected sent since its current datagram began (a first or only
    // frame begins one, a last frame ends one): never more than one (DG §7.3.2).
    let mut rejected = [0u32; 3];
    let check_once = |rejected: &[u32; 3]| {
        assert!(rejected.iter().all(|n| *n <= 1), "one datagram rejected more than once: {rejected:?}");
    };
    for op in data.chunks(3) {
        let [selector, a, b] = [0, 1, 2].map(|i| op.get(i).copied().unwrap_or(0));
        let index = usize::from(a % 3);
        let source = SOURCES[index];
        let len = usize::from(b % 9);
        let payload: Vec<u8> = (0..len).map(|i| a.wrapping_mul(31).wrapping_add(b).wrapping_add(i as u8)).collect();
        let format = match selector % 8 {
            0 => 2,
            1 | 2 => 3,
            3 | 4 => 4,
            5 => 5,
            6 => {
                now += Duration::from_millis(u64::from(b) * 40);
                link.handle_timeout(now, &mut above(|_| {}));
                for open in &mut model {
                    if open.as_ref().is_some_and(|(_, first)| *first + Duration::from_millis(TIMEOUT_MS) <= now) {
                        *open = None;
                    }
                }
                rejections_to(&drain_and_check(&mut link), &SOURCES, &mut rejected);
                check_once(&rejected);
                continue;
            }
            _ => {
                let amr = CanFrame::extended(0x1070_3000 | u32::from(source), &[5, 1, 1, 1, 0x22, 0x77]).unwrap();
                link.handle_frame(now, &amr, &mut above(|_| {}));
                model[index] = None;
                rejected[index] = 0;
                drain_and_check(&mut link);
                continue;
            }
        };
        let expected = match format {
            2 => {
                model[index] = None;
                Some(payload.clone())
            }
            3 => {
                let open = model.iter().filter(|m| m.is_some()).count();
                model[index] = match model[index] {
                    Some(_) => None, // 0x2042: both dropped
                    None if open >= slots => None,
                    None => Some((payload.clone(), now)),
                };
                None
            }
            _ => match model[index].take() {
                None => None,
                Some((mut bytes, first)) => {
                    bytes.extend_from_slice(&payload);
                    match (bytes.len() > MAX_DATAGRAM_LEN, format) {
                        (true, _) => None,
                        (false, 5) => Some(bytes),
                        (false, _) => {
                            model[index] = Some((bytes, first));
                            None
                        }
                    }
                }
            },
        };
        let id = 0x1000_0000 | format << 24 | 0x0800_0000 | u32::from(LOCAL_ALIAS) << 12 | u32::from(source);
        let frame = CanFrame::extended(id, &payload).unwrap();
        let mut delivered = Vec::new();
        link.handle_frame(
            now,
            &frame,
            &mut above(|msg| {
                assert_eq!(msg.mti, Mti::DATAGRAM);
                assert_eq!(msg.destination, NodeId::new(LOCAL_NODE));
                delivered.push(msg.payload.to_vec());
            }),
        );
        assert_eq!(delivered, expected.into_iter().collect::<Vec<_>>(), "datagram bytes from {source:03X}");
        let held: usize = model.iter().flatten().map(|(bytes, _)| bytes.len()).sum();
        assert_eq!(link.reassembly_in_use(), held, "the link holds what the model holds");
        assert!(link.reassembly_in_use() <= link.reassembly_bound());
        assert_eq!(link.reassembly_allocated(), allocated, "a reassembly buffer grew");
        if matches!(format, 2 | 3) {
            rejected[index] = 0;
        }
        rejections_to(&drain_and_check(&mut link), &SOURCES, &mut rejected);
        check_once(&rejected);
        if format == 5 {
            rejected[index] = 0;
        }
    }
}

/// Arbitrary text in arbitrary pieces: the first byte picks the piece size. The outcomes must
/// not depend on how the text is cut, and every frame must re-encode and decode to itself.
pub fn gridconnect_decode(data: &[u8]) {
    let Some((&piece, text)) = data.split_first() else {
        return;
    };
    let piece = usize::from(piece % 16) + 1;
    let whole = collect(&mut GridConnectDecoder::new(), [text]);
    let mut decoder = GridConnectDecoder::new();
    let pieces = collect(&mut decoder, text.chunks(piece));
    assert_eq!(whole, pieces, "outcomes depend on the cut");
    for frame in whole.iter().flatten() {
        let mut buf = [0u8; gridconnect::MAX_ENCODED_LEN];
        let n = gridconnect::encode(frame, &mut buf).unwrap();
        let again = collect(&mut GridConnectDecoder::new(), [&buf[..n]]);
        assert_eq!(again, [Ok(*frame)]);
    }
    let stats = decoder.stats();
    assert_eq!(stats.frames + stats.errors, whole.len() as u64);
}

fn collect<'a>(
    decoder: &mut GridConnectDecoder,
    pieces: impl IntoIterator<Item = &'a [u8]>,
) -> Vec<Result<CanFrame, GridConnectError>> {
    let mut out = Vec::new();
    for piece in pieces {
        decoder.decode_all(piece, |r| out.push(r));
    }
    out
}
