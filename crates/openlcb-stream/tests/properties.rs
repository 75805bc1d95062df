//! Properties over two endpoints wired back to back: for any data, write chunking, window,
//! early-Proceed setting, reader speed and 1..=8 interleaved streams, the bytes delivered are
//! the bytes sent, in order; the source's credit never exceeds what it was granted; the
//! destination never buffers more than its bound.

use openlcb_stream::{Config, Event, Instant, NodeId, OpenOptions, StreamEndpoint, StreamHandle};
use proptest::prelude::*;

const A: NodeId = NodeId::from_bytes([5, 1, 1, 1, 0x22, 0]);
const B: NodeId = NodeId::from_bytes([5, 1, 1, 1, 0x22, 1]);

#[derive(Debug, Clone)]
struct Scenario {
    window: u16,
    early_proceed: bool,
    /// Bytes per stream.
    payloads: Vec<Vec<u8>>,
    /// Write sizes, cycled.
    chunks: Vec<usize>,
    /// Bytes the reader takes per turn, cycled (the reader's speed).
    reads: Vec<usize>,
}

fn scenario() -> impl Strategy<Value = Scenario> {
    (
        prop_oneof![1u16..=64, 65u16..=4096, Just(65535u16)],
        any::<bool>(),
        prop::collection::vec(prop::collection::vec(any::<u8>(), 0..3000), 1..=8),
        prop::collection::vec(1usize..=5000, 1..6),
        prop::collection::vec(1usize..=5000, 1..6),
    )
        .prop_map(|(window, early_proceed, payloads, chunks, reads)| Scenario {
            window,
            early_proceed,
            payloads,
            chunks,
            reads,
        })
}

fn run(s: &Scenario) -> Result<(), TestCaseError> {
    let mut config = Config::default();
    config.max_window = s.window;
    config.early_proceed = s.early_proceed;
    config.max_streams_per_peer = 8;
    let mut a = StreamEndpoint::new(A, config.clone());
    let mut b = StreamEndpoint::new(B, config);
    let now = Instant::ZERO;
    let streams: Vec<StreamHandle> =
        s.payloads.iter().map(|_| a.open(now, OpenOptions::new(B, s.window)).expect("open")).collect();
    let mut written = vec![0usize; streams.len()];
    let mut finished_sent = vec![false; streams.len()];
    let mut opened = vec![false; streams.len()];
    let mut received: std::collections::HashMap<StreamHandle, (u8, Vec<u8>)> = Default::default();
    let mut done: Vec<(u8, Vec<u8>, bool)> = Vec::new();
    let mut buf = vec![0u8; 5000];
    for turn in 0..200_000usize {
        // Source: write a chunk on every open stream, finish when all is written.
        for (i, h) in streams.iter().enumerate() {
            if !opened[i] || finished_sent[i] {
                continue;
            }
            let chunk = s.chunks[(turn + i) % s.chunks.len()];
            let end = (written[i] + chunk).min(s.payloads[i].len());
            let before = a.credit(*h).expect("source credit");
            let n = a.write(now, *h, &s.payloads[i][written[i]..end]).expect("write");
            let after = a.credit(*h).expect("source credit");
            prop_assert_eq!(before as usize - n, after as usize, "credit drops by exactly what was sent");
            written[i] += n;
            if written[i] == s.payloads[i].len() {
                a.finish(now, *h).expect("finish");
                finished_sent[i] = true;
            }
        }
        // Wire: A's messages to B, and B's to A.
        let mut moved = false;
        while let Some(msg) = a.poll_transmit() {
            b.handle_message(now, msg.as_ref());
            moved = true;
        }
        while let Some(event) = a.poll_event() {
            if let Event::Opened { handle, .. } = event {
                opened[streams.iter().position(|h| *h == handle).expect("known")] = true;
            }
        }
        // Destination: note new streams and finishes, read at the reader's speed.
        while let Some(event) = b.poll_event() {
            match event {
                Event::Opened { handle, info } => {
                    received.insert(handle, (info.source_stream.as_raw(), Vec::new()));
                }
                Event::Finished { handle, matched, .. } => {
                    let h = handle;
                    let mut rest = received.remove(&h).expect("finished stream was opened");
                    while let Ok(n @ 1..) = b.read(now, h, &mut buf) {
                        rest.1.extend_from_slice(&buf[..n]);
                    }
                    done.push((rest.0, rest.1, matched));
                }
                Event::Readable { .. } => {}
                other => prop_assert!(false, "unexpected event {:?}", other),
            }
        }
        for (h, (_, bytes)) in received.iter_mut() {
            let buffered = b.buffered(*h).expect("open");
            prop_assert!(buffered <= b.buffer_capacity(*h).expect("open"));
            prop_assert!(buffered <= 2 * usize::from(s.window));
            let take = s.reads[turn % s.reads.len()].min(buf.len());
            let n = b.read(now, *h, &mut buf[..take]).expect("read");
            bytes.extend_from_slice(&buf[..n]);
        }
        while let Some(msg) = b.poll_transmit() {
            a.handle_message(now, msg.as_ref());
            moved = true;
        }
        if done.len() == streams.len() && !moved {
            break;
        }
    }
    prop_assert_eq!(done.len(), streams.len(), "every stream finished");
    // SIDs were handed out 0, 1, 2, ... in open order.
    done.sort_by_key(|d| d.0);
    for (i, (_, bytes, matched)) in done.iter().enumerate() {
        prop_assert!(*matched);
        prop_assert_eq!(bytes, &s.payloads[i]);
    }
    prop_assert_eq!(a.stream_count(), 0);
    prop_assert_eq!(b.stream_count(), 0);
    prop_assert_eq!(b.stats().window_overruns, 0);
    Ok(())
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 96, ..ProptestConfig::default() })]

    #[test]
    fn delivered_bytes_equal_sent_bytes(s in scenario()) {
        run(&s)?;
    }
}

#[test]
fn one_byte_window_many_streams() {
    let s = Scenario {
        window: 1,
        early_proceed: true,
        payloads: (0..8).map(|i| (0..100u8).map(|b| b ^ i).collect()).collect(),
        chunks: vec![3, 1],
        reads: vec![1],
    };
    run(&s).unwrap();
}
