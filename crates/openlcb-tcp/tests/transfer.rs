//! The worked transfer of wire-spec §9.2, end to end: two stream endpoints, each behind its own
//! `TcpLink`, exchanging exactly the published OpenLCB-TCP bytes of M1..M6.

mod common;

use common::{A, B, hex, node, vector};
use openlcb_stream::{Config, Event, Instant, OpenOptions, StreamEndpoint, StreamId};
use openlcb_tcp::TcpLink;

/// The configuration of §9.2: window 16, no early Proceed, no Initialization Complete.
fn config() -> Config {
    let mut c = Config::default();
    c.max_window = 16;
    c.early_proceed = false;
    c
}

/// Endpoint to endpoint, no link: everything each side sends goes to the other until quiet.
fn pump_direct(now: Instant, a: &mut StreamEndpoint, b: &mut StreamEndpoint) {
    loop {
        let mut moved = false;
        while let Some(msg) = a.poll_transmit() {
            b.handle_message(now, msg.as_ref());
            moved = true;
        }
        while let Some(msg) = b.poll_transmit() {
            a.handle_message(now, msg.as_ref());
            moved = true;
        }
        if !moved {
            break;
        }
    }
}

/// Opens and finishes `count` empty streams from `a` to `b`, so that `b`'s rotation of
/// destination stream IDs (from 0) hands out `count` next.
fn use_up_destination_ids(count: u8, a: &mut StreamEndpoint, b: &mut StreamEndpoint) {
    let now = Instant::ZERO;
    for _ in 0..count {
        let handle = a.open(now, OpenOptions::new(b.node_id(), 16)).unwrap();
        pump_direct(now, a, b);
        a.finish(now, handle).unwrap();
        pump_direct(now, a, b);
        for handle in b.handles().collect::<Vec<_>>() {
            assert_eq!(b.read(now, handle, &mut [0u8; 16]), Ok(0));
        }
    }
    while a.poll_event().is_some() {}
    while b.poll_event().is_some() {}
    assert_eq!((a.stream_count(), b.stream_count()), (0, 0));
}

/// One node: its endpoint and its link.
struct Node {
    endpoint: StreamEndpoint,
    link: TcpLink,
}

impl Node {
    /// Drains the endpoint into the link and takes the bytes the socket would write.
    fn transmit(&mut self, now: Instant) -> Vec<u8> {
        self.link.send_from(now, || self.endpoint.poll_transmit()).unwrap();
        let wire = self.link.transmit_pending().to_vec();
        self.link.advance_transmit(wire.len());
        wire
    }

    /// Feeds socket bytes through the link into the endpoint, in pieces of 7 bytes.
    fn receive(&mut self, now: Instant, wire: &[u8]) {
        for piece in wire.chunks(7) {
            let mut input = piece;
            while let Some(result) = self.link.read_message(&mut input) {
                self.endpoint.handle_message(now, result.unwrap());
            }
        }
        assert!(self.link.decoder().is_idle());
    }

    fn events(&mut self) -> Vec<Event> {
        core::iter::from_fn(|| self.endpoint.poll_event()).collect()
    }
}

/// Everything `from` sends at `now` goes over the "socket" to `to`; returns the bytes.
fn carry(now: Instant, from: &mut Node, to: &mut Node) -> Vec<u8> {
    let wire = from.transmit(now);
    to.receive(now, &wire);
    wire
}

#[test]
fn worked_example_moves_the_published_bytes_through_two_links() {
    let mut a = StreamEndpoint::new(node(A), config());
    let mut b = StreamEndpoint::new(node(B), config());
    // §9.2 has B choose DID 7; B hands out DIDs 0, 1, .. so seven streams come first.
    use_up_destination_ids(7, &mut a, &mut b);
    let mut a = Node { endpoint: a, link: TcpLink::new(node(A)) };
    let mut b = Node { endpoint: b, link: TcpLink::new(node(B)) };
    let data: Vec<u8> = (0u8..20).collect();
    let ms = Instant::from_millis;

    // M1: A asks for a stream with SID 4 and a window of 16.
    let sid = StreamId::new(4).unwrap();
    let stream = a.endpoint.open(ms(1), OpenOptions::new(node(B), 16).source_stream(sid)).unwrap();
    assert_eq!(carry(ms(1), &mut a, &mut b), hex(vector("M1 Initiate Request").wire));
    let Some(Event::Opened { handle: b_stream, info }) = b.events().into_iter().next() else {
        panic!("B did not open")
    };
    assert_eq!(info.destination_stream, StreamId::new(7));

    // M2: B accepts with DID 7.
    assert_eq!(carry(ms(2), &mut b, &mut a), hex(vector("M2 Initiate Reply").wire));
    assert!(matches!(a.events()[..], [Event::Opened { handle, .. }] if handle == stream));
    assert_eq!(a.endpoint.credit(stream), Some(16));

    // M3: A writes all 20 bytes; the credit lets 16 go, in one message.
    assert_eq!(a.endpoint.write(ms(3), stream, &data), Ok(16));
    assert_eq!(carry(ms(3), &mut a, &mut b), hex(vector("M3 Data Send 16 bytes").wire));
    assert_eq!(a.endpoint.credit(stream), Some(0));
    assert_eq!(carry(ms(3), &mut b, &mut a), [], "B's buffer is full until it reads");

    // M4: B reads the window, which frees the buffer and sends the Proceed.
    let mut received = vec![0u8; 32];
    assert_eq!(b.endpoint.read(ms(4), b_stream, &mut received), Ok(16));
    received.truncate(16);
    // The published M4 is the 2-byte Proceed; the core sends the 4-byte form every peer
    // parses (flags 00 00), so the frame is 2 bytes longer.
    let proceed =
        "80 00 00 00 1E 05 01 01 01 22 01 00 00 00 00 00 04 08 88 05 01 01 01 22 01 05 01 01 01 22 00 04 07 00 00";
    assert_eq!(vector("M4 Proceed").payload, [0x04, 0x07]);
    assert_eq!(carry(ms(4), &mut b, &mut a), hex(proceed));
    assert_eq!(a.endpoint.credit(stream), Some(16));

    // M5: the last 4 bytes.
    assert_eq!(a.endpoint.write(ms(5), stream, &data[16..]), Ok(4));
    assert_eq!(carry(ms(5), &mut a, &mut b), hex(vector("M5 Data Send 4 bytes").wire));

    // M6: the core sends Complete in form B with a 4-byte count (wire-spec §4.5), i.e. M6a's
    // payload `04 07 00 00 00 14` (length 0x20), here with capture time 6 as the sixth message.
    a.endpoint.finish(ms(6), stream).unwrap();
    assert_eq!(
        carry(ms(6), &mut a, &mut b),
        hex("80 00 00 00 20 05 01 01 01 22 00 00 00 00 00 00 06 08 A8 05 01 01 01 22 00 05 01 01 01 22 01
             04 07 00 00 00 14")
    );
    let finished = b.events().into_iter().find(|e| matches!(e, Event::Finished { .. }));
    assert_eq!(finished, Some(Event::Finished { handle: b_stream, total: 20, stated: Some(20), matched: true }));
    let mut rest = [0u8; 16];
    assert_eq!(b.endpoint.read(ms(6), b_stream, &mut rest), Ok(4));
    received.extend_from_slice(&rest[..4]);
    assert_eq!(received, data);

    // Nothing else crossed either link.
    assert_eq!((carry(ms(6), &mut a, &mut b), carry(ms(6), &mut b, &mut a)), (vec![], vec![]));
    assert_eq!((a.link.stats().messages_out, a.link.stats().messages_in), (4, 2));
    assert_eq!((b.link.stats().messages_out, b.link.stats().messages_in), (2, 4));
    assert_eq!(a.link.stats().bytes_out, 36 + 48 + 36 + 37);
}

/// Moves `data` from A to B over two links with a window of `window`, B reading everything
/// as it arrives; `inspect` sees the bytes of every carry from A to B. Returns what B read and
/// A's link.
fn transfer(config: Config, window: u16, data: &[u8], mut inspect: impl FnMut(&[u8])) -> (Vec<u8>, TcpLink) {
    let mut a = Node { endpoint: StreamEndpoint::new(node(A), config.clone()), link: TcpLink::new(node(A)) };
    let mut b = Node { endpoint: StreamEndpoint::new(node(B), config), link: TcpLink::new(node(B)) };
    let now = Instant::ZERO;
    let stream = a.endpoint.open(now, OpenOptions::new(node(B), window)).unwrap();
    let (mut sent, mut received, mut finished) = (0, Vec::new(), false);
    let mut buf = vec![0u8; 8192];
    for _ in 0..10_000 {
        if finished {
            break;
        }
        if sent < data.len() {
            sent += a.endpoint.write(now, stream, &data[sent..]).unwrap_or(0);
            if sent == data.len() {
                a.endpoint.finish(now, stream).unwrap();
            }
        }
        inspect(&carry(now, &mut a, &mut b));
        finished |= b.events().iter().any(|event| matches!(event, Event::Finished { matched: true, .. }));
        for handle in b.endpoint.handles().collect::<Vec<_>>() {
            while let Ok(n @ 1..) = b.endpoint.read(now, handle, &mut buf) {
                received.extend_from_slice(&buf[..n]);
            }
        }
        carry(now, &mut b, &mut a);
        a.events();
    }
    assert!(finished, "the transfer did not finish");
    (received, a.link)
}

#[test]
fn a_large_transfer_sends_whole_windows_as_single_messages() {
    let mut c = config();
    c.max_window = 4096;
    let data: Vec<u8> = (0..40_000u32).map(|i| (i * 7) as u8).collect();
    let mut data_sends = 0;
    let (received, a_link) = transfer(c, 4096, &data, |wire| {
        let mut decoder = openlcb_tcp::Decoder::default();
        let mut input = wire;
        while let Some(frame) = decoder.decode(&mut input) {
            let message = frame.unwrap().message;
            if message.mti == openlcb_stream::Mti::STREAM_DATA_SEND {
                // A whole window (the DID and 4096 bytes) in one message, except the tail.
                assert!(message.payload.len() == 4097 || data_sends == 9, "{} bytes", message.payload.len());
                data_sends += 1;
            }
        }
    });
    assert_eq!(received, data);
    assert_eq!(data_sends, 10);
    // Request, 10 Data Sends, Complete.
    assert_eq!(a_link.stats().messages_out, 12);
}

#[test]
fn a_transfer_with_the_default_config_and_early_proceed_completes() {
    let data: Vec<u8> = (0..100_000u32).map(|i| (i % 251) as u8).collect();
    let (received, _) = transfer(Config::default(), 2048, &data, |_| {});
    assert_eq!(received, data);
}
