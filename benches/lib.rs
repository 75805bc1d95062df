//! Shared set-up for the criterion benches; run them with `cargo bench -p openlcb-benches`.

use openlcb_stream::{Config, Event, Instant, NodeId, OpenOptions, StreamEndpoint};

/// Node A, the source in every bench.
pub const NODE_A: NodeId = NodeId::from_bytes([0x05, 0x01, 0x01, 0x01, 0x22, 0x00]);
/// Node B, the destination in every bench.
pub const NODE_B: NodeId = NodeId::from_bytes([0x05, 0x01, 0x01, 0x01, 0x22, 0x01]);

/// Moves `bytes` from A to B through two endpoints wired back to back (no transport), with
/// early Proceed and the given window; returns the bytes B read.
pub fn transfer_back_to_back(bytes: usize, window: u16) -> usize {
    let mut config = Config::default();
    config.max_window = window;
    config.early_proceed = true;
    let mut a = StreamEndpoint::new(NODE_A, config.clone());
    let mut b = StreamEndpoint::new(NODE_B, config);
    let now = Instant::ZERO;
    let data = vec![0x5Au8; 64 * 1024];
    let mut buf = vec![0u8; 128 * 1024];
    let stream = a.open(now, OpenOptions::new(NODE_B, window)).expect("open");
    let (mut sent, mut received, mut dest) = (0usize, 0usize, None);
    let mut finished = false;
    while !finished {
        if sent < bytes {
            sent += a.write(now, stream, &data[..(bytes - sent).min(data.len())]).unwrap_or(0);
            if sent == bytes {
                a.finish(now, stream).expect("finish");
            }
        }
        while let Some(msg) = a.poll_transmit() {
            b.handle_message(now, msg.as_ref());
        }
        while let Some(event) = b.poll_event() {
            match event {
                Event::Opened { handle, .. } => dest = Some(handle),
                Event::Finished { .. } => finished = true,
                _ => {}
            }
        }
        if let Some(h) = dest {
            while let Ok(n @ 1..) = b.read(now, h, &mut buf) {
                received += n;
            }
        }
        while let Some(msg) = b.poll_transmit() {
            a.handle_message(now, msg.as_ref());
        }
        while a.poll_event().is_some() {}
    }
    received
}
