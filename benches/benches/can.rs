//! The CAN transport: GridConnect text encode and decode (text bytes/s and frames/s), frame
//! splitting and header parsing (frames/s), and a whole stream transfer through two
//! `CanLink`s and two endpoints (payload bytes/s).

use std::hint::black_box;

use criterion::{Criterion, Throughput, criterion_group, criterion_main};
use openlcb_benches::{NODE_A, NODE_B};
use openlcb_can::gridconnect::{self, GridConnectDecoder};
use openlcb_can::{CanConfig, CanFrame, CanHeader, CanLink, Fragments, NodeAlias};
use openlcb_stream::{Config, Event, Instant, Mti, OpenOptions, StreamEndpoint};

const FRAMES: usize = 1024;

fn alias(raw: u16) -> NodeAlias {
    NodeAlias::new(raw).expect("alias")
}

/// A stream's worth of traffic: full data frames with a Proceed now and then.
fn sample_frames() -> Vec<CanFrame> {
    let payload: Vec<u8> = std::iter::once(7).chain((0..7 * FRAMES).map(|i| i as u8)).collect();
    let data = Fragments::new(Mti::STREAM_DATA_SEND, alias(0x123), Some(alias(0x456)), payload).expect("data");
    let proceed = CanFrame::extended(0x1988_8456, &[0x01, 0x23, 0x04, 0x07]).expect("proceed");
    data.enumerate().flat_map(|(i, f)| if i % 64 == 63 { vec![f, proceed] } else { vec![f] }).take(FRAMES).collect()
}

fn sample_text(frames: &[CanFrame]) -> Vec<u8> {
    let mut text = Vec::new();
    let mut buf = [0u8; gridconnect::MAX_ENCODED_LEN];
    for frame in frames {
        let n = gridconnect::encode(frame, &mut buf).expect("encode");
        text.extend_from_slice(&buf[..n]);
        text.push(b'\n');
    }
    text
}

fn encode_all(frames: &[CanFrame], out: &mut [u8]) -> usize {
    let mut at = 0;
    for frame in frames {
        at += gridconnect::encode(frame, &mut out[at..]).expect("room");
    }
    at
}

fn decode_all(text: &[u8]) -> usize {
    let mut decoder = GridConnectDecoder::new();
    let mut count = 0;
    decoder.decode_all(text, |r| count += usize::from(r.is_ok()));
    count
}

fn gridconnect(c: &mut Criterion) {
    let frames = sample_frames();
    let text = sample_text(&frames);
    let mut out = vec![0u8; text.len() + gridconnect::MAX_ENCODED_LEN];
    for (name, throughput) in [
        ("gridconnect_text", Throughput::Bytes(text.len() as u64)),
        ("gridconnect_frames", Throughput::Elements(frames.len() as u64)),
    ] {
        let mut group = c.benchmark_group(name);
        group.throughput(throughput);
        group.bench_function("encode", |b| b.iter(|| encode_all(black_box(&frames), &mut out)));
        group.bench_function("decode", |b| b.iter(|| assert_eq!(decode_all(black_box(&text)), FRAMES)));
        group.finish();
    }
}

fn frames(c: &mut Criterion) {
    let sample = sample_frames();
    let payload = bytes::Bytes::from(std::iter::once(7).chain((0..7 * FRAMES).map(|i| i as u8)).collect::<Vec<u8>>());
    let mut group = c.benchmark_group("can_frames");
    group.throughput(Throughput::Elements(FRAMES as u64));
    group.bench_function("split_stream_data", |b| {
        b.iter(|| {
            let fragments = Fragments::new(Mti::STREAM_DATA_SEND, alias(0x123), Some(alias(0x456)), payload.clone());
            fragments.expect("data").map(|f| f.payload().len()).sum::<usize>()
        })
    });
    group.bench_function("parse_header", |b| {
        b.iter(|| black_box(&sample).iter().filter(|f| CanHeader::parse(f.raw_id()).is_ok()).count())
    });
    group.finish();
}

/// One node: link and endpoint.
struct Node {
    link: CanLink,
    endpoint: StreamEndpoint,
}

impl Node {
    fn new(id: openlcb_stream::NodeId, first_alias: u16, window: u16) -> Self {
        let mut core = Config::default();
        core.max_window = window;
        let mut can = CanConfig::default();
        can.first_alias = Some(alias(first_alias));
        Node { link: CanLink::new(Instant::ZERO, id, can), endpoint: StreamEndpoint::new(id, core) }
    }
}

/// Everything `from` has to send, framed, onto `to`. Returns the frames moved.
fn deliver(now: Instant, from: &mut Node, to: &mut Node) -> usize {
    while let Some(msg) = from.endpoint.poll_transmit() {
        from.link.send(now, msg).expect("queue");
    }
    let mut moved = 0;
    while let Some(frame) = from.link.poll_transmit() {
        let endpoint = &mut to.endpoint;
        to.link.handle_frame(now, &frame, |msg| endpoint.handle_message(now, msg));
        moved += 1;
    }
    moved
}

/// Logs in two nodes and moves `bytes` from A to B through their links.
fn transfer_over_can(bytes: usize, window: u16) -> usize {
    let (mut a, mut b) = (Node::new(NODE_A, 0x123, window), Node::new(NODE_B, 0x456, window));
    let login = Instant::from_millis(200);
    for now in [Instant::ZERO, login] {
        a.link.handle_timeout(now);
        b.link.handle_timeout(now);
        while deliver(now, &mut a, &mut b) + deliver(now, &mut b, &mut a) > 0 {}
    }
    let now = login;
    let stream = a.endpoint.open(now, OpenOptions::new(NODE_B, window)).expect("open");
    let data = vec![0x5Au8; 64 * 1024];
    let mut buf = vec![0u8; 128 * 1024];
    let (mut sent, mut received, mut dest, mut finished) = (0usize, 0usize, None, false);
    while !finished {
        if sent < bytes {
            sent += a.endpoint.write(now, stream, &data[..(bytes - sent).min(data.len())]).unwrap_or(0);
            if sent == bytes {
                a.endpoint.finish(now, stream).expect("finish");
            }
        }
        deliver(now, &mut a, &mut b);
        while let Some(event) = b.endpoint.poll_event() {
            match event {
                Event::Opened { handle, .. } => dest = Some(handle),
                Event::Finished { .. } => finished = true,
                _ => {}
            }
        }
        if let Some(h) = dest {
            while let Ok(n @ 1..) = b.endpoint.read(now, h, &mut buf) {
                received += n;
            }
        }
        deliver(now, &mut b, &mut a);
        while a.endpoint.poll_event().is_some() {}
    }
    received
}

fn transfer(c: &mut Criterion) {
    const BYTES: usize = 1 << 20;
    let mut group = c.benchmark_group("can_stream_transfer");
    group.throughput(Throughput::Bytes(BYTES as u64));
    group.bench_function("window_2048", |b| b.iter(|| assert_eq!(transfer_over_can(BYTES, 2048), BYTES)));
    group.finish();
}

criterion_group!(benches, gridconnect, frames, transfer);
criterion_main!(benches);
