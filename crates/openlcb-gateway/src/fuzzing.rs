//! Entry points for the fuzz targets in `fuzz/`. Not a stable API.
//!
//! Assertions here are the fuzzers' oracles, so panicking and indexing are the point.
#![allow(clippy::indexing_slicing, clippy::panic, clippy::expect_used, clippy::unwrap_used, missing_docs)]

use alloc::vec::Vec;

use openlcb_can::CanFrame;
use openlcb_stream::{Duration, Instant, Message, Mti, NodeId};

use crate::{Gateway, GatewayConfig};

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

/// Arbitrary CAN frames and full-format messages into a gateway with small bounds, with
/// time steps and partial pulls of CAN frames. No panic; after draining the full-format
/// output, memory stays within the bound; every frame out is a valid OpenLCB frame.
pub fn gateway_ops(data: &[u8]) {
    let mut input = Input(data);
    let mut gateway = Gateway::new(Instant::ZERO, small_config());
    let mut now = Instant::ZERO;
    // The two CAN nodes announce themselves.
    for (alias, node) in ALIASES.iter().zip(&NODES[2..]) {
        let amd = CanFrame::extended(0x1070_1000 | alias, &NodeId::new(*node).unwrap().to_bytes()).unwrap();
        gateway.handle_can_frame(now, &amd);
    }
    let mut steps = 0;
    while !input.0.is_empty() && steps < 2_000 {
        steps += 1;
        match input.byte() % 6 {
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
        while gateway.poll_event().is_some() {}
        assert!(
            gateway.memory_in_use() <= gateway.memory_bound(),
            "memory {} over the bound {}",
            gateway.memory_in_use(),
            gateway.memory_bound()
        );
        assert!(gateway.tracked_streams() <= gateway.config().max_streams);
    }
    let mut frames = 0;
    while gateway.poll_can_transmit().is_some() {
        frames += 1;
        assert!(frames < 1_000_000, "poll_can_transmit never ends");
    }
}
