//! Two sans-IO stream endpoints wired back to back: A opens a stream to B and sends 100 kB
//! through a 2048-byte window; B reads it. Every message goes straight from one endpoint's
//! `poll_transmit` into the other's `handle_message`, so the whole drive loop fits on a page.
//!
//! `cargo run -p openlcb-stream --example back_to_back`

use openlcb_stream::{Config, Event, Instant, NodeId, OpenOptions, StreamEndpoint};

/// Delivers everything each side has to send to the other until both are quiet; returns how
/// many messages crossed.
fn pump(now: Instant, a: &mut StreamEndpoint, b: &mut StreamEndpoint) -> usize {
    let mut moved = 0;
    loop {
        let before = moved;
        while let Some(msg) = a.poll_transmit() {
            b.handle_message(now, msg.as_ref());
            moved += 1;
        }
        while let Some(msg) = b.poll_transmit() {
            a.handle_message(now, msg.as_ref());
            moved += 1;
        }
        if moved == before {
            return moved;
        }
    }
}

fn main() {
    let a_id: NodeId = "05.01.01.01.22.00".parse().expect("a valid Node ID");
    let b_id: NodeId = "05.01.01.01.22.01".parse().expect("a valid Node ID");
    let mut a = StreamEndpoint::new(a_id, Config::default());
    let mut b = StreamEndpoint::new(b_id, Config::default());
    let now = Instant::ZERO;
    let data: Vec<u8> = (0..100_000u32).map(|i| (i % 251) as u8).collect();

    let stream = a.open(now, OpenOptions::new(b_id, 2048)).expect("a free stream slot");
    let (mut sent, mut received, mut messages) = (0, Vec::new(), 0);
    let mut buf = [0u8; 4096];
    let mut done = (false, false); // (A saw Sent, B saw Finished)
    while done != (true, true) {
        messages += pump(now, &mut a, &mut b);
        while let Some(event) = a.poll_event() {
            match event {
                // Credit arrived: write what it allows; `write` says how much it took.
                Event::Opened { .. } | Event::Writable { .. } if sent < data.len() => {
                    sent += a.write(now, stream, &data[sent..]).expect("an open stream");
                    if sent == data.len() {
                        a.finish(now, stream).expect("an open stream");
                    }
                }
                Event::Sent { total, .. } => {
                    println!("A: stream sent, {total} bytes; its handle is released");
                    done.0 = true;
                }
                Event::Opened { .. } | Event::Writable { .. } => {}
                other => panic!("A: unexpected {other:?}"),
            }
        }
        while let Some(event) = b.poll_event() {
            match event {
                Event::Opened { info, .. } => println!("B: stream from {} opened, window {}", info.peer, info.window),
                Event::Readable { handle } => {
                    // Reading frees buffer space, which lets B's next Proceed go out.
                    while let Ok(n @ 1..) = b.read(now, handle, &mut buf) {
                        received.extend_from_slice(&buf[..n]);
                    }
                }
                Event::Finished { total, matched, .. } => {
                    println!("B: stream finished, {total} bytes, count matched: {matched}");
                    done.1 = true;
                }
                other => panic!("B: unexpected {other:?}"),
            }
        }
    }
    assert_eq!(received, data, "the data arrived changed");
    println!("{} bytes moved in {messages} messages, verified", received.len());
}

/// `cargo test` runs the example (`test = true` in Cargo.toml); it asserts on what it moves.
#[test]
fn moves_and_verifies_a_stream() {
    main();
}
