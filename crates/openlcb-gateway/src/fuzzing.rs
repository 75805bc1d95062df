//! Entry points for the fuzz targets in `fuzz/`. Not a stable API.
//!
//! Assertions here are the fuzzers' oracles, so panicking and indexing are the point.
#![allow(clippy::indexing_slicing, clippy::panic, clippy::expect_used, clippy::unwrap_used, missing_docs)]

use alloc::vec::Vec;

use openlcb_can::CanFrame;
use openlcb_stream::{Duration, Instant, Message, Mti, NodeId};

use crate::{Gateway, GatewayConfig, GatewayEvent};

/// Nodes the operations talk about: two full-format nodes, two CAN nodes.
const NODES: [u64; 4] = [0x0501_0101_2210, 0x0501_0101_2211, 0x0501_0101_2200, 0x0501_0101_2201];
/// Aliases the CAN side uses: the first two are the CAN nodes', the rest anything.
const ALIASES: [u32; 4] = [0x123, 0x456, 0x789, 0xABC];
/// MTIs worth trying, most of them stream and alias related.
const MTIS: [u16; 16] = [
    0x0CC8, 0x0868, 0x1F88, 0x0888, 0x08A8, 0x0068, 0x00A8, 0x0100, 0x0170, 0x0490, 0x0488, 0x1C48, 0x2DA8, 0x05B4,
    0x0A28, 0x3FFF,
];

fn small_config() -> GatewayConfig {
    GatewayConfig {
        max_streams: 3,
        max_window: 64,
        max_proxied_nodes: 2,
        max_held_messages: 4,
        max_queued_messages: 4,
        max_message_len: 16,
        max_untracked_backlog: 32,
        alias_cache_size: 3,
        reassembly_slots: 2,
        ..GatewayConfig::default()
    }
}

/// Reads bytes off the fuzz input; zeros once it runs out.
struct Input<'a>(&'a [u8]);

impl Input<'_> {
    fn byte(&mut self) -> u8 {
        match self.0.split_first() {
            Some((&b, rest)) => {
                self.0 = rest;
                b
            }
            None => 0,
        }
    }

    fn bytes(&mut self, max: usize) -> Vec<u8> {
        let len = usize::from(self.byte()) % (max + 1);
        (0..len).map(|_| self.byte()).collect()
    }

    fn pick<T: Copy>(&mut self, items: &[T]) -> T {
        items[usize::from(self.byte()) % items.len()]
    }
}

/// A stream from full-format node `NODES[0]` to CAN node `NODES[2]` (alias `ALIASES[0]`),
/// set up before the fuzzed operations and fed position-dependent data during them. The
/// fuzzer may end it (a TDE, an AMR, a collision) but never change its bytes: what comes
/// out as stream data frames must be a prefix of what went in.
struct Tracked {
    proxy: u32,
    sent: Vec<u8>,
    received: Vec<u8>,
    /// The gateway stopped tracking it (idle, terminated, node gone): its source, told or
    /// not, sends nothing more, and what the gateway does with untracked data is not checked.
    ended: bool,
}

const TRACKED_SID: u8 = 5;
const TRACKED_DID: u8 = 9;
const TRACKED_WINDOW: usize = 64;

impl Tracked {
    /// Sends the request, lets the proxy log in, answers from the CAN node.
    fn open(gateway: &mut Gateway, now: &mut Instant) -> Option<Tracked> {
        let (source, destination) = (NodeId::new(NODES[0]).unwrap(), NodeId::new(NODES[2]).unwrap());
        let request = [0, TRACKED_WINDOW as u8, 0, 0, TRACKED_SID];
        gateway.handle_message(
            *now,
            Message::addressed(Mti::STREAM_INITIATE_REQUEST, source, destination, request.to_vec()).as_ref(),
        );
        let mut proxy = None;
        for _ in 0..20 {
            *now += Duration::from_millis(100);
            gateway.handle_timeout(*now);
            while let Some(frame) = gateway.poll_can_transmit() {
                let (id, data) = (frame.raw_id(), frame.payload());
                let to = data.get(..2).map(|d| (u32::from(d[0] & 0x0F) << 8) | u32::from(d[1]));
                if id & 0x1FFF_F000 == 0x19CC_8000 && to == Some(ALIASES[0]) {
                    proxy = Some(id & 0xFFF);
                }
            }
            while gateway.poll_message().is_some() {}
            if proxy.is_some() {
                break;
            }
        }
        let proxy = proxy?;
        let reply = [(proxy >> 8) as u8, proxy as u8, 0, TRACKED_WINDOW as u8, 0x80, 0x00, TRACKED_SID, TRACKED_DID];
        gateway.handle_can_frame(*now, &CanFrame::extended(0x1986_8000 | ALIASES[0], &reply).unwrap());
        while gateway.poll_message().is_some() {}
        Some(Tracked { proxy, sent: Vec::new(), received: Vec::new(), ended: false })
    }

    /// Sends the stream's next `len` bytes (never beyond the first window).
    fn send(&mut self, gateway: &mut Gateway, now: Instant, len: usize) {
        if self.ended {
            return;
        }
        let len = len.min(TRACKED_WINDOW - self.sent.len());
        let mut payload = alloc::vec![TRACKED_DID];
        payload.extend((self.sent.len()..self.sent.len() + len).map(|i| (i as u8).wrapping_mul(37) ^ 0x5A));
        self.sent.extend_from_slice(&payload[1..]);
        let (source, destination) = (NodeId::new(NODES[0]).unwrap(), NodeId::new(NODES[2]).unwrap());
        gateway.handle_message(now, Message::addressed(Mti::STREAM_DATA_SEND, source, destination, payload).as_ref());
    }

    /// Notes the stream's data frames among the gateway's CAN output.
    fn observe(&mut self, frame: &CanFrame) {
        let id = frame.raw_id();
        let data = frame.payload();
        if id >> 24 == 0x1F
            && (id >> 12) & 0xFFF == ALIASES[0]
            && id & 0xFFF == self.proxy
            && data.first() == Some(&TRACKED_DID)
        {
            self.received.extend_from_slice(&data[1..]);
        }
    }

    fn check(&self) {
        assert!(
            self.sent.starts_with(&self.received),
            "stream bytes changed: sent {:02X?}, got {:02X?}",
            self.sent,
            self.received
        );
    }
}

/// Arbitrary CAN frames and full-format messages into a gateway with small bounds, with
/// time steps and partial pulls of CAN frames. No panic; after draining the full-format
/// output, memory stays within the bound; every frame out is a valid OpenLCB frame; the
/// bytes of a tracked stream cross intact and in order.
pub fn gateway_ops(data: &[u8]) {
    let mut input = Input(data);
    let mut gateway = Gateway::new(Instant::ZERO, small_config());
    let mut now = Instant::ZERO;
    // The two CAN nodes announce themselves.
    for (alias, node) in ALIASES.iter().zip(&NODES[2..]) {
        let amd = CanFrame::extended(0x1070_1000 | alias, &NodeId::new(*node).unwrap().to_bytes()).unwrap();
        gateway.handle_can_frame(now, &amd);
    }
    let mut tracked = Tracked::open(&mut gateway, &mut now);
    let mut steps = 0;
    while !input.0.is_empty() && steps < 2_000 {
        steps += 1;
        match input.byte() % 7 {
            0 => {
                // A raw frame: any identifier, any data.
                let id = u32::from_be_bytes([input.byte(), input.byte(), input.byte(), input.byte()]);
                let payload = input.bytes(8);
                if let Some(frame) = CanFrame::extended(id, &payload) {
                    gateway.handle_can_frame(now, &frame);
                }
            }
            1 => {
                // A well-formed OpenLCB frame from one of the aliases.
                let source = input.pick(&ALIASES);
                let target = input.pick(&ALIASES);
                let mut payload = input.bytes(8);
                let id = match input.byte() % 4 {
                    0 => 0x1F00_0000 | (target << 12) | source,
                    3 => {
                        // A datagram frame (formats 2-5), to a proxy alias if there is one.
                        let full = NodeId::new(NODES[usize::from(input.byte() % 2)]).unwrap();
                        let to = gateway.proxy_alias(full).map_or(target, |a| u32::from(a.as_raw()));
                        (0x1A + u32::from(input.byte() % 4)) << 24 | (to << 12) | source
                    }
                    1 => {
                        if payload.len() >= 2 {
                            payload[0] = (payload[0] & 0x30) | (target >> 8) as u8;
                            payload[1] = target as u8;
                        }
                        0x1900_0000 | (u32::from(input.pick(&MTIS) & 0x0FFF) << 12) | source
                    }
                    _ => 0x1070_0000 | (u32::from(input.byte() % 4) << 12) | source,
                };
                if let Some(frame) = CanFrame::extended(id, &payload) {
                    gateway.handle_can_frame(now, &frame);
                }
            }
            2 => {
                // A full-format message between the nodes.
                let mti = Mti(input.pick(&MTIS));
                let source = NodeId::new(input.pick(&NODES)).unwrap();
                let destination = NodeId::new(input.pick(&NODES)).unwrap();
                let payload = input.bytes(if mti == Mti::STREAM_DATA_SEND { 200 } else { 20 });
                if tracked.is_some() && source.as_raw() == NODES[0] && destination.as_raw() == NODES[2] {
                    // The tracked stream's source speaks only through `Tracked::send`.
                    continue;
                }
                let message = if mti.is_addressed() {
                    Message::addressed(mti, source, destination, payload)
                } else {
                    Message::global(mti, source, payload)
                };
                gateway.handle_message(now, message.as_ref());
            }
            3 => {
                now += Duration::from_millis(u64::from(input.byte()) * 4);
                gateway.handle_timeout(now);
            }
            4 => {
                // The bus takes a few frames.
                for _ in 0..input.byte() % 16 {
                    let Some(frame) = gateway.poll_can_transmit() else { break };
                    assert!(frame.header().is_ok(), "invalid frame out: {frame:?}");
                    if let Some(t) = tracked.as_mut() {
                        t.observe(&frame);
                    }
                }
            }
            5 => {
                let len = usize::from(input.byte() % 24);
                if let Some(t) = tracked.as_mut() {
                    t.send(&mut gateway, now, len);
                }
            }
            _ => {
                if let Some(deadline) = gateway.poll_timeout() {
                    now = now.max(deadline);
                    gateway.handle_timeout(now);
                }
            }
        }
        let mut drained = 0;
        while gateway.poll_message().is_some() {
            drained += 1;
            assert!(drained < 100_000, "poll_message never ends");
        }
        while let Some(event) = gateway.poll_event() {
            if let (GatewayEvent::StreamEnded { stream, .. }, Some(t)) = (event, tracked.as_mut()) {
                t.ended |= stream.source.as_raw() == NODES[0] && stream.source_stream.as_raw() == TRACKED_SID;
            }
        }
        assert!(
            gateway.memory_in_use() <= gateway.memory_bound(),
            "memory {} over the bound {}",
            gateway.memory_in_use(),
            gateway.memory_bound()
        );
        assert!(gateway.tracked_streams() <= gateway.config().max_streams);
    }
    let mut frames = 0;
    while let Some(frame) = gateway.poll_can_transmit() {
        frames += 1;
        assert!(frames < 1_000_000, "poll_can_transmit never ends");
        if let Some(t) = tracked.as_mut() {
            t.observe(&frame);
        }
    }
    if let Some(t) = tracked.as_ref() {
        t.check();
    }
}
