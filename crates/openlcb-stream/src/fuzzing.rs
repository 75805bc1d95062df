//! Entry points for the fuzz targets in `fuzz/`. Not a stable API.
//!
//! Assertions here are the fuzzers' oracles, so panicking and indexing are the point.
#![allow(clippy::indexing_slicing, clippy::panic, clippy::expect_used, missing_docs)]

use alloc::vec::Vec;

use arbitrary::Arbitrary;

use crate::wire::{DataComplete, DataProceed, DataSend, Emit, ErrorReport, InitiateReply, InitiateRequest};
use crate::wire::{ErrorCode, ReplyCode};
use crate::{AcceptPolicy, Config, Duration, Instant, MessageRef, Mti, NodeId, OpenOptions, StreamEndpoint};

/// Parses `data` as every stream message. Each parser accepts exactly what the spec lets a
/// receiver accept (wire-spec §3-§4: the minimum length, no 0xFF stream ID, a request with a
/// non-zero buffer; longer forms are liberal), checked against a statement of those rules
/// written apart from the parsers. Whatever parses must re-emit and re-parse to the same
/// value, and re-emit to the same bytes.
pub fn stream_wire(data: &[u8]) {
    let id_at = |i: usize| data.get(i).is_some_and(|&b| b != 0xFF);
    let expect = |what: &str, parsed: bool, allowed: bool| {
        assert_eq!(parsed, allowed, "{what} {} {data:02X?}", if parsed { "accepted" } else { "refused" });
    };
    let buffer = data.get(..2).map(|b| u16::from_be_bytes([b[0], b[1]]));
    expect("request", InitiateRequest::parse(data).is_ok(), data.len() >= 5 && id_at(4) && buffer != Some(0));
    expect("reply", InitiateReply::parse(data).is_ok(), data.len() >= 6 && id_at(4));
    expect("data send", DataSend::parse(data).is_ok(), id_at(0));
    expect("proceed", DataProceed::parse(data).is_ok(), id_at(0) && id_at(1));
    expect("complete", DataComplete::parse(data).is_ok(), id_at(0) && id_at(1));
    fn check<T: Emit + PartialEq + core::fmt::Debug>(first: T, reparse: impl Fn(&[u8]) -> Option<T>) {
        let bytes = first.to_bytes();
        assert_eq!(bytes.len(), first.buffer_len());
        let second = reparse(&bytes).expect("emitted bytes must parse");
        assert_eq!(first, second);
        assert_eq!(second.to_bytes(), bytes);
    }
    if let Ok(m) = InitiateRequest::parse(data) {
        check(m, |b| InitiateRequest::parse(b).ok());
    }
    if let Ok(m) = InitiateReply::parse(data) {
        check(m, |b| InitiateReply::parse(b).ok());
    }
    if let Ok(m) = DataSend::parse(data) {
        let bytes = m.to_bytes();
        assert_eq!(&bytes[..], data, "Data Send re-emits exactly what it parsed");
    }
    if let Ok(m) = DataProceed::parse(data) {
        check(m, |b| DataProceed::parse(b).ok());
    }
    if let Ok(m) = DataComplete::parse(data) {
        check(m, |b| DataComplete::parse(b).ok());
    }
    check(ErrorReport::parse(data), |b| Some(ErrorReport::parse(b)));
}

/// Who a fuzzed message claims to come from.
#[derive(Debug, Clone, Copy, Arbitrary)]
pub enum Sender {
    /// The other endpoint of the pair.
    Peer,
    /// A third node no stream knows.
    Stranger,
    /// This endpoint's own Node ID.
    Itself,
}

/// One step of a fuzzed session between endpoints A and B.
#[derive(Debug, Clone, Arbitrary)]
pub enum Op {
    /// Deliver everything queued between A and B.
    Pump,
    /// Hand an arbitrary message to A (or B).
    Inject { to_b: bool, from: Sender, mti: u16, addressed_elsewhere: bool, payload: Vec<u8> },
    /// A stream message with a chosen MTI and payload, to A (or B) from its peer.
    InjectStream { to_b: bool, kind: u8, payload: Vec<u8> },
    /// Open a stream from A to B (or B to A).
    Open { from_b: bool, window: u16, sid: Option<u8>, did: Option<u8> },
    /// Write `len` bytes on stream number `stream`.
    Write { from_b: bool, stream: u8, len: u16 },
    /// Flush.
    Flush { from_b: bool, stream: u8 },
    /// Finish.
    Finish { from_b: bool, stream: u8 },
    /// Abort with a code.
    Abort { on_b: bool, stream: u8, code: u16 },
    /// Accept a pending request with a window.
    Accept { on_b: bool, stream: u8, window: Option<u16> },
    /// Reject a pending request.
    Reject { on_b: bool, stream: u8, code: u16 },
    /// Read up to `len` bytes.
    Read { on_b: bool, stream: u8, len: u16 },
    /// Let time pass and run timers.
    Advance { millis: u16 },
    /// A node loses its link: A (or B) itself with `whole_link`, else its peer.
    Lost { on_b: bool, whole_link: bool },
    /// A (or B) sees other nodes' stream data on its bus: its waits run from now.
    MediumBusy { on_b: bool },
}

const A: NodeId = NodeId::from_bytes([5, 1, 1, 1, 0x22, 0]);
const B: NodeId = NodeId::from_bytes([5, 1, 1, 1, 0x22, 1]);
const STRANGER: NodeId = NodeId::from_bytes([9, 9, 9, 9, 9, 9]);

/// The byte at `offset` of every stream with source stream ID `sid`: position-dependent, so
/// that a lost, repeated or reordered byte shows.
fn pattern(sid: u8, offset: u64) -> u8 {
    (offset as u32).wrapping_mul(0x9E37_79B1).rotate_right(13) as u8 ^ (offset >> 8) as u8 ^ sid
}

/// What the oracle knows of the data: bytes written per source stream, bytes read per
/// destination stream, and whether anything but the endpoints themselves has talked (an
/// injected message may carry any bytes, so the data check then stops).
#[derive(Default)]
struct Ledger {
    written: alloc::collections::BTreeMap<(usize, crate::StreamHandle), u64>,
    read: alloc::collections::BTreeMap<(usize, crate::StreamHandle), u64>,
    tampered: bool,
}

impl Ledger {
    /// Writes the stream's next bytes (up to `len`) and checks the credit arithmetic.
    fn write(&mut self, now: Instant, endpoint: &mut StreamEndpoint, side: usize, h: crate::StreamHandle, len: usize) {
        let Some(sid) = endpoint.stream_info(h).map(|i| i.source_stream.as_raw()) else { return };
        let offset = self.written.get(&(side, h)).copied().unwrap_or(0);
        let data: Vec<u8> = (0..len as u64).map(|i| pattern(sid, offset + i)).collect();
        let before = endpoint.credit(h);
        if let Ok(n) = endpoint.write(now, h, &data) {
            let after = endpoint.credit(h).unwrap_or(0);
            assert_eq!(before.unwrap_or(0) - after, n as u32, "credit drops by what was written");
            *self.written.entry((side, h)).or_default() += n as u64;
        }
    }

    /// Reads up to `buf.len()` bytes and checks they are the next bytes the source wrote.
    fn read(
        &mut self,
        now: Instant,
        endpoint: &mut StreamEndpoint,
        side: usize,
        h: crate::StreamHandle,
        buf: &mut [u8],
    ) {
        let Some(sid) = endpoint.stream_info(h).map(|i| i.source_stream.as_raw()) else { return };
        let Ok(n) = endpoint.read(now, h, buf) else { return };
        let offset = self.read.get(&(side, h)).copied().unwrap_or(0);
        if !self.tampered {
            for (i, byte) in buf[..n].iter().enumerate() {
                assert_eq!(
                    *byte,
                    pattern(sid, offset + i as u64),
                    "byte {} of stream SID {sid} changed",
                    offset + i as u64
                );
            }
        }
        *self.read.entry((side, h)).or_default() += n as u64;
    }
}

/// After the operations: a long quiet time in which a driver wakes up every few seconds,
/// calls `write` with nothing (as drivers do), pumps, and reads everything. Every stream
/// must then have ended, or be a source holding credit: its application's turn (it was
/// told with `Opened` or `Writable`). A stream still waiting on its peer is a hang.
fn quiet_time(pair: &mut [StreamEndpoint; 2], ledger: &mut Ledger, mut now: Instant) {
    let mut buf = [0u8; 4096];
    for _ in 0..120 {
        for (side, endpoint) in pair.iter_mut().enumerate() {
            let handles: Vec<crate::StreamHandle> = endpoint.handles().collect();
            for h in handles {
                if endpoint.credit(h).is_some() {
                    let _ = endpoint.write(now, h, &[]);
                } else {
                    while endpoint.buffered(h).is_some_and(|b| b > 0) {
                        ledger.read(now, endpoint, side, h, &mut buf);
                    }
                }
            }
        }
        pump(pair, now);
        now += Duration::from_secs(5);
        for endpoint in pair.iter_mut() {
            endpoint.handle_timeout(now);
            while endpoint.poll_event().is_some() {}
        }
        pump(pair, now);
    }
    for (side, endpoint) in pair.iter().enumerate() {
        for h in endpoint.handles() {
            let info = endpoint.stream_info(h);
            // A source holding credit waits for its own application; so does the destination
            // it keeps alive with keep-alives.
            let source_waits_for_its_application = endpoint.credit(h).is_some_and(|c| c > 0);
            let its_source_waits = info.is_some_and(|info| {
                let other = &pair[1 - side];
                other.handles().any(|g| {
                    other.credit(g).is_some_and(|c| c > 0)
                        && other.stream_info(g).is_some_and(|o| {
                            o.source_stream == info.source_stream
                                && o.peer == endpoint.node_id()
                                && info.peer == other.node_id()
                        })
                })
            });
            assert!(
                source_waits_for_its_application || its_source_waits,
                "{h:?} still waits after 10 quiet minutes: {info:?}"
            );
        }
    }
}

/// Delivers everything queued between the two endpoints (bounded rounds).
fn pump(pair: &mut [StreamEndpoint; 2], now: Instant) {
    for _ in 0..64 {
        let mut moved = false;
        for side in 0..2 {
            while let Some(msg) = pair[side].poll_transmit() {
                pair[1 - side].handle_message(now, msg.as_ref());
                moved = true;
            }
        }
        if !moved {
            break;
        }
    }
}

/// Runs `ops` against two small endpoints and checks the bounds after every step, the data
/// read against the data written, and at the end that nothing waits forever.
pub fn endpoint_ops(ops: &[Op]) {
    let config = |ask: bool| Config {
        max_streams: 6,
        max_streams_per_peer: 4,
        max_window: 300,
        accept_policy: if ask { AcceptPolicy::Ask } else { AcceptPolicy::AcceptAll },
        ..Config::default()
    };
    let mut pair = [StreamEndpoint::new(A, config(false)), StreamEndpoint::new(B, config(true))];
    let ids = [A, B];
    let mut now = Instant::ZERO;
    let mut ledger = Ledger::default();
    let mut buf = [0u8; 4096];
    for op in ops.iter().take(512) {
        match op {
            Op::Pump => pump(&mut pair, now),
            Op::Inject { to_b, from, mti, addressed_elsewhere, payload } => {
                ledger.tampered = true;
                let to = usize::from(*to_b);
                let source = match from {
                    Sender::Peer => ids[1 - to],
                    Sender::Stranger => STRANGER,
                    Sender::Itself => ids[to],
                };
                let mti = Mti(*mti);
                let destination = mti.is_addressed().then_some(if *addressed_elsewhere { STRANGER } else { ids[to] });
                pair[to].handle_message(now, MessageRef { mti, source, destination, payload });
            }
            Op::InjectStream { to_b, kind, payload } => {
                ledger.tampered = true;
                let to = usize::from(*to_b);
                let mti = [
                    Mti::STREAM_INITIATE_REQUEST,
                    Mti::STREAM_INITIATE_REPLY,
                    Mti::STREAM_DATA_SEND,
                    Mti::STREAM_DATA_PROCEED,
                    Mti::STREAM_DATA_COMPLETE,
                    Mti::TERMINATE_DUE_TO_ERROR,
                    Mti::OPTIONAL_INTERACTION_REJECTED,
                ][usize::from(*kind) % 7];
                pair[to]
                    .handle_message(now, MessageRef { mti, source: ids[1 - to], destination: Some(ids[to]), payload });
            }
            Op::Open { from_b, window, sid, did } => {
                let from = usize::from(*from_b);
                let mut options = OpenOptions::new(ids[1 - from], *window);
                options.source_stream = sid.and_then(crate::StreamId::new);
                options.proposed_destination = did.and_then(crate::StreamId::new);
                let _ = pair[from].open(now, options);
            }
            Op::Write { from_b, stream, len } => {
                let side = usize::from(*from_b);
                if let Some(h) = nth_handle(&pair[side], *stream) {
                    ledger.write(now, &mut pair[side], side, h, usize::from(*len).min(4096));
                }
            }
            Op::Flush { from_b, stream } => {
                let side = usize::from(*from_b);
                if let Some(h) = nth_handle(&pair[side], *stream) {
                    let _ = pair[side].flush(now, h);
                }
            }
            Op::Finish { from_b, stream } => {
                let side = usize::from(*from_b);
                if let Some(h) = nth_handle(&pair[side], *stream) {
                    let _ = pair[side].finish(now, h);
                }
            }
            Op::Abort { on_b, stream, code } => {
                let side = usize::from(*on_b);
                if let Some(h) = nth_handle(&pair[side], *stream) {
                    let _ = pair[side].abort(now, h, ErrorCode(*code));
                }
            }
            Op::Accept { on_b, stream, window } => {
                let side = usize::from(*on_b);
                if let Some(h) = nth_handle(&pair[side], *stream) {
                    let _ = pair[side].accept(now, h, *window);
                }
            }
            Op::Reject { on_b, stream, code } => {
                let side = usize::from(*on_b);
                if let Some(h) = nth_handle(&pair[side], *stream) {
                    let _ = pair[side].reject(now, h, ReplyCode(*code));
                }
            }
            Op::Read { on_b, stream, len } => {
                let side = usize::from(*on_b);
                if let Some(h) = nth_handle(&pair[side], *stream) {
                    let len = usize::from(*len).min(buf.len());
                    ledger.read(now, &mut pair[side], side, h, &mut buf[..len]);
                }
            }
            Op::Advance { millis } => {
                now += Duration::from_millis(u64::from(*millis) * 100);
                for endpoint in &mut pair {
                    endpoint.handle_timeout(now);
                }
            }
            Op::MediumBusy { on_b } => pair[usize::from(*on_b)].medium_busy(now),
            Op::Lost { on_b, whole_link } => {
                // One node lost its link (its CAN alias): it ends every stream, its peer hears
                // it go (AMR) and ends its streams with it, and the transport drops what was
                // queued between them (it was addressed to an alias that is gone). Data Send
                // carries no SID: a peer that forgot a stream the other still sends on would
                // mix two streams, which a real link loss never lets happen.
                let side = usize::from(*on_b);
                let lost = if *whole_link { side } else { 1 - side };
                pair[lost].link_lost();
                pair[1 - lost].peer_changed(crate::PeerChange::Lost(ids[lost]));
                for endpoint in &mut pair {
                    while endpoint.poll_transmit().is_some() {}
                }
            }
        }
        for endpoint in &mut pair {
            check_bounds(endpoint);
            while endpoint.poll_event().is_some() {}
        }
    }
    quiet_time(&mut pair, &mut ledger, now);
}

fn nth_handle(endpoint: &StreamEndpoint, n: u8) -> Option<crate::StreamHandle> {
    let count = endpoint.handles().count();
    if count == 0 {
        return None;
    }
    endpoint.handles().nth(usize::from(n) % count)
}

fn check_bounds(endpoint: &StreamEndpoint) {
    let config = endpoint.config();
    assert!(endpoint.stream_count() <= config.max_streams);
    assert_eq!(endpoint.stream_count(), endpoint.handles().count());
    for h in endpoint.handles() {
        if let (Some(buffered), Some(capacity)) = (endpoint.buffered(h), endpoint.buffer_capacity(h)) {
            assert!(buffered <= capacity, "buffered {buffered} > capacity {capacity}");
            assert!(capacity <= 2 * usize::from(config.max_window));
        }
    }
}
