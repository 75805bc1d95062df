//! A whole full-format transfer between two endpoints wired back to back: payload bytes per
//! second through the stream core alone, at a small and the largest window.

use criterion::{BenchmarkId, Criterion, Throughput, criterion_group, criterion_main};
use openlcb_benches::transfer_back_to_back;

fn transfer(c: &mut Criterion) {
    const BYTES: usize = 1 << 20;
    let mut group = c.benchmark_group("stream_transfer");
    group.throughput(Throughput::Bytes(BYTES as u64));
    for window in [2048u16, 65535] {
        group.bench_with_input(BenchmarkId::new("window", window), &window, |b, &window| {
            b.iter(|| assert_eq!(transfer_back_to_back(BYTES, window), BYTES));
        });
    }
    group.finish();
}

fn wire(c: &mut Criterion) {
    use openlcb_stream::wire::{DataComplete, DataProceed, InitiateReply, InitiateRequest};
    let mut group = c.benchmark_group("stream_wire_parse");
    group.bench_function("request", |b| {
        b.iter(|| InitiateRequest::parse(std::hint::black_box(&[0, 16, 0, 0, 4, 0xFF])))
    });
    group.bench_function("reply", |b| b.iter(|| InitiateReply::parse(std::hint::black_box(&[0, 16, 0x80, 0, 4, 7]))));
    group.bench_function("proceed", |b| b.iter(|| DataProceed::parse(std::hint::black_box(&[4, 7]))));
    group.bench_function("complete", |b| b.iter(|| DataComplete::parse(std::hint::black_box(&[4, 7, 0, 0, 0, 20]))));
    group.finish();
}

criterion_group!(benches, transfer, wire);
criterion_main!(benches);
