//! OpenLCB-TCP: a whole transfer between two endpoints, each behind its own `TcpLink` (payload
//! bytes per second), and the decoder and encoder alone (link bytes per second).

use criterion::{BenchmarkId, Criterion, Throughput, criterion_group, criterion_main};
use openlcb_benches::{NODE_A, NODE_B, Wire, endpoints};
use openlcb_stream::{Instant, Message, Mti, StreamEndpoint};
use openlcb_tcp::{CaptureTime, Decoder, LinkPrefix, TcpFrame, TcpLink};

/// How many bytes one socket read hands to the link.
const SOCKET_READ: usize = 16 * 1024;

/// Writes what `from` has encoded into `to`, in socket-read pieces, and hands every decoded
/// message to `endpoint`.
fn carry(now: Instant, from: &mut TcpLink, to: &mut TcpLink, endpoint: &mut StreamEndpoint) {
    let pending = from.transmit_pending();
    let written = pending.len();
    for piece in pending.chunks(SOCKET_READ) {
        let mut input = piece;
        while let Some(result) = to.read_message(&mut input) {
            endpoint.handle_message(now, result.expect("decode"));
        }
    }
    from.advance_transmit(written);
}

/// Two OpenLCB-TCP links, one per endpoint, joined by a byte pipe.
struct TcpWire {
    a: TcpLink,
    b: TcpLink,
}

impl Wire for TcpWire {
    fn carry(&mut self, now: Instant, from: &mut StreamEndpoint, to: &mut StreamEndpoint, a_to_b: bool) {
        let (sender, receiver) = if a_to_b { (&mut self.a, &mut self.b) } else { (&mut self.b, &mut self.a) };
        sender.send_from(now, || from.poll_transmit()).expect("encode");
        carry(now, sender, receiver, to);
    }
}

/// Moves `bytes` from A to B through two endpoints and two links.
fn transfer_over_links(bytes: usize, window: u16) -> usize {
    let (mut a, mut b) = endpoints(window);
    let mut wire = TcpWire { a: TcpLink::new(NODE_A), b: TcpLink::new(NODE_B) };
    openlcb_benches::transfer(Instant::ZERO, (&mut a, &mut b), &mut wire, bytes, window)
}

fn transfer(c: &mut Criterion) {
    const BYTES: usize = 1 << 20;
    let mut group = c.benchmark_group("tcp_transfer");
    group.throughput(Throughput::Bytes(BYTES as u64));
    for window in [2048u16, 65535] {
        group.bench_with_input(BenchmarkId::new("window", window), &window, |b, &window| {
            b.iter(|| assert_eq!(transfer_over_links(BYTES, window), BYTES));
        });
    }
    group.finish();
}

/// 1 MiB of stream data as Data Send messages of `chunk` data bytes, encoded back to back.
fn encoded_stream_data(chunk: usize) -> (Vec<Message>, Vec<u8>) {
    let payload = vec![0xA5u8; chunk + 1];
    let messages: Vec<Message> = (0..(1 << 20) / chunk)
        .map(|_| Message::addressed(Mti::STREAM_DATA_SEND, NODE_A, NODE_B, payload.clone()))
        .collect();
    let mut wire = Vec::new();
    for (i, message) in messages.iter().enumerate() {
        let prefix = LinkPrefix { gateway: NODE_A, capture_time: CaptureTime::wrapping(i as u64) };
        TcpFrame::new(prefix, message.as_ref()).encode_to(&mut wire).expect("encode");
    }
    (messages, wire)
}

fn codec(c: &mut Criterion) {
    let mut group = c.benchmark_group("tcp_codec");
    for chunk in [2048usize, 65535] {
        let (messages, wire) = encoded_stream_data(chunk);
        group.throughput(Throughput::Bytes(wire.len() as u64));
        for read in [1460usize, SOCKET_READ] {
            let id = BenchmarkId::new(format!("decode_reads_of_{read}"), format!("data_{chunk}"));
            group.bench_with_input(id, &wire, |b, wire| {
                b.iter(|| {
                    let mut decoder = Decoder::default();
                    let mut payload_bytes = 0;
                    for piece in wire.chunks(read) {
                        let mut input = piece;
                        while let Some(result) = decoder.decode(&mut input) {
                            payload_bytes += result.expect("decode").message.payload.len();
                        }
                    }
                    assert_eq!(payload_bytes, messages.len() * (chunk + 1));
                })
            });
        }
        let mut out = Vec::with_capacity(wire.len());
        group.bench_function(BenchmarkId::new("encode", format!("data_{chunk}")), |b| {
            b.iter(|| {
                out.clear();
                for message in &messages {
                    let prefix = LinkPrefix { gateway: NODE_A, capture_time: CaptureTime::MAX };
                    TcpFrame::new(prefix, message.as_ref()).encode_to(&mut out).expect("encode");
                }
                assert_eq!(out.len(), wire.len());
            })
        });
    }
    group.finish();
}

criterion_group!(benches, transfer, codec);
criterion_main!(benches);
