//! Shared set-up for the criterion benches; run them with `cargo bench -p openlcb-benches`.
//!
//! The `instructions` example runs the same transfers once each, for an instruction count
//! under valgrind that does not depend on how busy the machine is (see its doc).

use openlcb_can::{CanConfig, CanLink, NodeAlias};
use openlcb_stream::{Config, Event, Instant, NodeId, OpenOptions, StreamEndpoint};

/// Node A, the source in every bench.
pub const NODE_A: NodeId = NodeId::from_bytes([0x05, 0x01, 0x01, 0x01, 0x22, 0x00]);
/// Node B, the destination in every bench.
pub const NODE_B: NodeId = NodeId::from_bytes([0x05, 0x01, 0x01, 0x01, 0x22, 0x01]);

/// The transport under test: moves what one endpoint has queued into the other.
pub trait Wire {
    /// Delivers everything `from` has to send to `to`; `a_to_b` tells the direction.
    fn carry(&mut self, now: Instant, from: &mut StreamEndpoint, to: &mut StreamEndpoint, a_to_b: bool);
}

/// No transport: the endpoints wired back to back.
pub struct BackToBack;

impl Wire for BackToBack {
    fn carry(&mut self, now: Instant, from: &mut StreamEndpoint, to: &mut StreamEndpoint, _a_to_b: bool) {
        while let Some(msg) = from.poll_transmit() {
            to.handle_message(now, msg.as_ref());
        }
    }
}

/// Two endpoints (A and B) with early Proceed and `window` as their largest window.
pub fn endpoints(window: u16) -> (StreamEndpoint, StreamEndpoint) {
    let mut config = Config::default();
    config.max_window = window;
    config.early_proceed = true;
    (StreamEndpoint::new(NODE_A, config.clone()), StreamEndpoint::new(NODE_B, config))
}

/// Moves `bytes` from `a` to `b` over `wire` with a stream proposing `window`, reading as fast
/// as data arrives; returns the bytes B read.
pub fn transfer(
    now: Instant,
    (a, b): (&mut StreamEndpoint, &mut StreamEndpoint),
    wire: &mut impl Wire,
    bytes: usize,
    window: u16,
) -> usize {
    let data = vec![0x5Au8; 64 * 1024];
    let mut buf = vec![0u8; 128 * 1024];
    let stream = a.open(now, OpenOptions::new(b.node_id(), window)).expect("open");
    let (mut sent, mut received, mut destination, mut finished) = (0usize, 0usize, None, false);
    while !finished {
        if sent < bytes {
            sent += a.write(now, stream, &data[..(bytes - sent).min(data.len())]).unwrap_or(0);
            if sent == bytes {
                a.finish(now, stream).expect("finish");
            }
        }
        wire.carry(now, a, b, true);
        while let Some(event) = b.poll_event() {
            match event {
                Event::Opened { handle, .. } => destination = Some(handle),
                Event::Finished { .. } => finished = true,
                Event::Terminated { .. } | Event::TimedOut { .. } => panic!("transfer failed: {event:?}"),
                _ => {}
            }
        }
        if let Some(handle) = destination {
            while let Ok(n @ 1..) = b.read(now, handle, &mut buf) {
                received += n;
            }
        }
        wire.carry(now, b, a, false);
        while a.poll_event().is_some() {}
    }
    received
}

/// Moves `bytes` from A to B through two endpoints wired back to back.
pub fn transfer_back_to_back(bytes: usize, window: u16) -> usize {
    let (mut a, mut b) = endpoints(window);
    transfer(Instant::ZERO, (&mut a, &mut b), &mut BackToBack, bytes, window)
}

/// Two CAN links, one per endpoint, on a bus that delivers every frame at once.
struct CanWire {
    a: CanLink,
    b: CanLink,
}

impl Wire for CanWire {
    fn carry(&mut self, now: Instant, from: &mut StreamEndpoint, to: &mut StreamEndpoint, a_to_b: bool) {
        let (sender, receiver) = if a_to_b { (&mut self.a, &mut self.b) } else { (&mut self.b, &mut self.a) };
        while let Some(msg) = from.poll_transmit() {
            sender.send(now, msg).expect("queue");
        }
        while let Some(frame) = sender.poll_transmit() {
            receiver.handle_frame(now, &frame, to);
        }
    }
}

/// A CAN link for `id` that logs in with `first_alias`.
fn link(id: NodeId, first_alias: u16) -> CanLink {
    let mut can = CanConfig::default();
    can.first_alias = NodeAlias::new(first_alias);
    CanLink::new(Instant::ZERO, id, can)
}

/// Logs in two nodes and moves `bytes` from A to B through their `CanLink`s.
pub fn transfer_over_can(bytes: usize, window: u16) -> usize {
    let (mut a, mut b) = endpoints(window);
    let mut wire = CanWire { a: link(NODE_A, 0x123), b: link(NODE_B, 0x456) };
    let login = Instant::from_millis(200);
    for now in [Instant::ZERO, login] {
        wire.a.handle_timeout(now, &mut a);
        wire.b.handle_timeout(now, &mut b);
        for _ in 0..4 {
            wire.carry(now, &mut a, &mut b, true);
            wire.carry(now, &mut b, &mut a, false);
        }
    }
    transfer(login, (&mut a, &mut b), &mut wire, bytes, window)
}
