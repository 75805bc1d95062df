//! The CAN transport: GridConnect text encode and decode (text bytes/s and frames/s), frame
//! splitting and header parsing (frames/s), and a whole stream transfer through two
//! `CanLink`s and two endpoints (payload bytes/s).

use std::hint::black_box;

use criterion::{Criterion, Throughput, criterion_group, criterion_main};
use openlcb_benches::transfer_over_can;
use openlcb_can::gridconnect::{self, GridConnectDecoder};
use openlcb_can::{CanFrame, CanHeader, Fragments, NodeAlias};
use openlcb_stream::Mti;

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

fn transfer(c: &mut Criterion) {
    const BYTES: usize = 1 << 20;
    let mut group = c.benchmark_group("can_stream_transfer");
    group.throughput(Throughput::Bytes(BYTES as u64));
    group.bench_function("window_2048", |b| b.iter(|| assert_eq!(transfer_over_can(BYTES, 2048), BYTES)));
    group.finish();
}

criterion_group!(benches, gridconnect, frames, transfer);
criterion_main!(benches);
