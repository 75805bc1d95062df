//! Whole transfers through the gateway, CAN node <-> gateway <-> full-format node.

mod common;

use common::{CAN_NODE, FULL_NODE, Net, core_config, node_id, pattern};
use openlcb_can::{CanFrame, FrameKind};
use openlcb_gateway::{GatewayConfig, GatewayEvent, Side, StreamEnd};
use openlcb_stream::wire::{DataSend, InitiateReply, InitiateRequest};
use openlcb_stream::{Event, Message, Mti, OpenOptions};

fn gateway_config(max_window: u16) -> GatewayConfig {
    let mut config = GatewayConfig::default();
    config.max_window = max_window;
    config
}

/// The payloads of the stream messages of `mti` the gateway sent to the full-format node.
fn to_full(net: &Net, mti: Mti) -> Vec<Vec<u8>> {
    net.to_full.iter().filter(|m| m.mti == mti).map(|m| m.payload.to_vec()).collect()
}

/// The CAN-MTI payloads (after the 2 address bytes) of format-1 frames of `mti` from `frames`.
fn can_payloads(frames: &[CanFrame], mti: Mti) -> Vec<Vec<u8>> {
    frames
        .iter()
        .filter(|f| f.header().is_ok_and(|h| h.kind == FrameKind::Message { can_mti: mti.as_raw() }))
        .map(|f| f.payload()[2..].to_vec())
        .collect()
}

/// The payload lengths of the Data Sends the full node got, each checked not to cross a
/// boundary of `window`.
fn data_send_lengths(net: &Net, window: usize) -> Vec<usize> {
    let mut offset = 0;
    let mut lengths = Vec::new();
    for payload in to_full(net, Mti::STREAM_DATA_SEND) {
        let len = DataSend::parse(&payload).unwrap().data.len();
        assert!(offset % window + len <= window, "a Data Send of {len} at {offset} crosses a window boundary");
        offset += len;
        lengths.push(len);
    }
    lengths
}

#[test]
fn can_to_full_transfer_delivers_every_byte_with_merged_sends_inside_windows() {
    // The CAN node proposes 1024; the gateway lowers it to 256; the full node grants 200.
    let mut full = core_config(200);
    full.early_proceed = false;
    let mut net = Net::started(gateway_config(256), core_config(2048), full);
    let data = pattern(10_000);
    net.start_transfer(Side::Can, data.clone(), 1024);
    net.run_until(|n| n.full.finished.is_some());

    assert_eq!(net.full.finished, Some((10_000, true)));
    assert_eq!(net.full.received, data, "every byte, in order");

    // Request: 1024 on CAN, lowered to 256 on the full side.
    let sent = can_payloads(&net.from_can_node, Mti::STREAM_INITIATE_REQUEST);
    assert_eq!(InitiateRequest::parse(&sent[0]).unwrap().max_buffer_size, 1024);
    let forwarded = to_full(&net, Mti::STREAM_INITIATE_REQUEST);
    assert_eq!(InitiateRequest::parse(&forwarded[0]).unwrap().max_buffer_size, 256);
    assert_eq!(forwarded[0][2..], sent[0][2..], "only the buffer size changes");
    // Reply: 200 from the full node, 200 on CAN, byte for byte.
    let reply_full = net.from_full.iter().find(|m| m.mti == Mti::STREAM_INITIATE_REPLY).unwrap();
    let reply_can = can_payloads(&net.from_gateway, Mti::STREAM_INITIATE_REPLY);
    assert_eq!(InitiateReply::parse(&reply_full.payload).unwrap().max_buffer_size, 200);
    assert_eq!(reply_can, [reply_full.payload.to_vec()], "the Reply is never changed");

    // Merged Data Sends: never across a window boundary; after the stream's first frame
    // (forwarded at once, to see whether the destination sends Proceeds ahead) whole windows.
    let lengths = data_send_lengths(&net, 200);
    assert_eq!(lengths.iter().sum::<usize>(), 10_000);
    assert_eq!(lengths[..2], [7, 193]);
    assert!(lengths[2..].iter().all(|&len| len == 200), "{lengths:?}");
    let stats = net.gateway.stats();
    assert!(stats.data_frames_merged >= 10_000 / 7, "{stats:?}");
    assert_eq!(stats.windows_lowered, 1);
    assert!(
        net.gateway_events.iter().any(|e| matches!(e, GatewayEvent::StreamEnded { cause: StreamEnd::Completed, .. }))
    );
    assert_eq!(net.gateway.tracked_streams(), 0);
    assert_eq!(net.gateway.memory_in_use(), 0);
}

#[test]
fn destination_sending_proceeds_ahead_gets_each_window_started_at_once() {
    let mut net = Net::started(gateway_config(256), core_config(2048), core_config(256));
    net.can_node_frames_per_turn = 4;
    let data = pattern(2_560);
    net.start_transfer(Side::Can, data.clone(), 256);
    net.run_until(|n| n.full.finished.is_some());
    assert_eq!(net.full.received, data);
    // Each window: its first frame at once (so the early Proceed can come back while the
    // rest is on the bus), then the rest merged.
    let lengths = data_send_lengths(&net, 256);
    assert_eq!(lengths, [7, 249].repeat(10));
}

#[test]
fn full_to_can_transfer_over_a_slow_bus_delivers_every_byte_within_one_window() {
    let mut net = Net::started(gateway_config(512), core_config(256), core_config(2048));
    net.can_frames_per_turn = 3;
    let data = pattern(20_000);
    net.start_transfer(Side::Full, data.clone(), 4096);
    net.run_until(|n| n.can.finished.is_some());

    assert_eq!(net.can.finished, Some((20_000, true)));
    assert_eq!(net.can.received, data, "every byte, in order");
    let forwarded = can_payloads(&net.from_gateway, Mti::STREAM_INITIATE_REQUEST);
    assert_eq!(InitiateRequest::parse(&forwarded[0]).unwrap().max_buffer_size, 512);
    // The full node sent large Data Sends; CAN carried them as 7-byte frames.
    let largest = net.from_full.iter().filter(|m| m.mti == Mti::STREAM_DATA_SEND).map(|m| m.payload.len()).max();
    assert_eq!(largest, Some(257));
    let data_frames =
        net.from_gateway.iter().filter(|f| matches!(f.header().unwrap().kind, FrameKind::StreamData { .. }));
    assert!(data_frames.clone().all(|f| f.payload().len() <= 8));
    assert!(data_frames.count() >= 20_000 / 7);
    // Proceeds waited for the buffer; the gateway never held more than one window.
    assert!(net.gateway.stats().proceeds_delayed > 0, "{:?}", net.gateway.stats());
    assert!(net.max_memory <= 256, "held {} bytes for a 256-byte window", net.max_memory);
    assert_eq!(net.gateway.memory_in_use(), 0);
    // Delayed, never dropped: every Proceed of the CAN node reached the full node.
    let proceeds_sent = can_payloads(&net.from_can_node, Mti::STREAM_DATA_PROCEED).len();
    assert!(proceeds_sent >= 20_000 / 256);
    assert_eq!(to_full(&net, Mti::STREAM_DATA_PROCEED).len(), proceeds_sent);
}

#[test]
fn transfers_both_ways_at_once_stay_within_the_memory_bound() {
    let mut config = gateway_config(128);
    config.max_streams = 2;
    let mut net = Net::started(config.clone(), core_config(128), core_config(128));
    net.can_frames_per_turn = 2;
    let (up, down) = (pattern(5_000), pattern(7_000));
    net.start_transfer(Side::Can, up.clone(), 1000);
    net.start_transfer(Side::Full, down.clone(), 1000);
    net.run_until(|n| n.can.finished.is_some() && n.full.finished.is_some());
    assert_eq!(net.full.received, up);
    assert_eq!(net.can.received, down);
    assert!(net.max_memory <= 2 * 128, "held {} bytes", net.max_memory);
    assert!(net.max_memory <= config.memory_bound());
}

#[test]
fn complete_that_overtakes_data_is_held_until_the_data_drained() {
    let mut net = Net::started(gateway_config(256), core_config(2048), core_config(2048));
    let data = pattern(100);
    let handle = net.can.endpoint.open(net.now, OpenOptions::new(node_id(FULL_NODE), 256)).unwrap();
    net.run_until(|n| n.can.events.iter().any(|e| matches!(e, Event::Opened { .. })));
    // Catch the data frames and the Complete; let the Complete win arbitration over the
    // last three data frames, as it does on a real bus.
    net.intercept = true;
    assert_eq!(net.can.endpoint.write(net.now, handle, &data), Ok(100));
    net.can.endpoint.finish(net.now, handle).unwrap();
    net.settle();
    let frames = std::mem::take(&mut net.intercepted);
    let is_complete = |f: &CanFrame| f.header().unwrap().kind == FrameKind::Message { can_mti: 0x8A8 };
    let complete = *frames.iter().find(|f| is_complete(f)).expect("a Complete");
    let data_frames: Vec<CanFrame> = frames.iter().copied().filter(|f| !is_complete(f)).collect();
    assert_eq!(data_frames.len(), 15, "100 bytes in 7-byte frames");
    let (early, late) = data_frames.split_at(12);
    net.intercept = false;
    net.deliver_intercepted(early);
    net.deliver_intercepted(&[complete]);
    net.settle();
    assert_eq!(to_full(&net, Mti::STREAM_DATA_COMPLETE).len(), 0, "the Complete waits for the data");
    assert!(net.full.finished.is_none());
    assert_eq!(net.gateway.stats().completes_delayed, 1);

    net.deliver_intercepted(late);
    net.settle();
    let kinds: Vec<Mti> = net.to_full.iter().map(|m| m.mti).filter(|m| m.is_stream()).collect();
    assert_eq!(kinds.last(), Some(&Mti::STREAM_DATA_COMPLETE), "{kinds:?}");
    let merged: Vec<usize> = to_full(&net, Mti::STREAM_DATA_SEND).iter().map(|p| p.len() - 1).collect();
    assert_eq!(merged, [7, 93], "the first frame at once, the rest merged, before the Complete");
    assert_eq!(net.full.finished, Some((100, true)));
    assert_eq!(net.full.received, data);
}

#[test]
fn complete_from_the_full_side_waits_until_every_frame_left() {
    let mut net = Net::started(gateway_config(256), core_config(256), core_config(2048));
    net.can_frames_per_turn = 1;
    net.start_transfer(Side::Full, pattern(200), 256);
    net.run_until(|n| n.can.finished.is_some());
    // On CAN the Complete comes after the last data frame.
    let last_data =
        net.from_gateway.iter().rposition(|f| matches!(f.header().unwrap().kind, FrameKind::StreamData { .. }));
    let complete =
        net.from_gateway.iter().position(|f| f.header().unwrap().kind == FrameKind::Message { can_mti: 0x8A8 });
    assert!(complete > last_data, "Complete at {complete:?}, last data frame at {last_data:?}");
    assert_eq!(net.can.finished, Some((200, true)));
}

#[test]
fn terminate_drops_buffered_data_and_delayed_messages() {
    let mut net = Net::started(gateway_config(256), core_config(256), core_config(2048));
    let handle = net.full.endpoint.open(net.now, OpenOptions::new(node_id(CAN_NODE), 256)).unwrap();
    net.settle();
    net.can_frames_per_turn = 0; // the bus is busy: data stays in the gateway
    assert_eq!(net.full.endpoint.write(net.now, handle, &pattern(256)), Ok(256));
    net.settle();
    assert_eq!(net.gateway.memory_in_use(), 256, "a window buffered");
    net.full.endpoint.abort(net.now, handle, openlcb_stream::wire::ErrorCode::TEMPORARY).unwrap();
    net.settle();
    assert_eq!(net.gateway.memory_in_use(), 4, "buffered data dropped: only the TDE waits for the bus");
    assert_eq!(net.gateway.stats().data_bytes_dropped, 256);
    assert!(
        net.gateway_events.iter().any(|e| matches!(e, GatewayEvent::StreamEnded { cause: StreamEnd::Terminated, .. }))
    );
    let before = net.from_gateway.len();
    net.can_frames_per_turn = usize::MAX;
    net.settle();
    let kinds: Vec<FrameKind> = net.from_gateway[before..].iter().map(|f| f.header().unwrap().kind).collect();
    assert_eq!(kinds, [FrameKind::Message { can_mti: 0x0A8 }], "only the TDE goes out");
    assert!(net.can.received.is_empty());
}

#[test]
fn source_overrunning_its_window_is_terminated_at_both_ends() {
    let mut net = Net::started(gateway_config(64), core_config(64), core_config(2048));
    let handle = net.full.endpoint.open(net.now, OpenOptions::new(node_id(CAN_NODE), 64)).unwrap();
    net.settle();
    let did = net.full.endpoint.stream_info(handle).unwrap().destination_stream.unwrap();
    net.can_frames_per_turn = 0;
    // A misbehaving source: 3 x 40 bytes on a 64-byte window without waiting for a Proceed.
    for _ in 0..3 {
        let mut payload = vec![did.as_raw()];
        payload.extend_from_slice(&pattern(40));
        let send = Message::addressed(Mti::STREAM_DATA_SEND, node_id(FULL_NODE), node_id(CAN_NODE), payload);
        net.gateway.handle_message(net.now, send.as_ref());
    }
    assert_eq!(net.gateway.stats().overruns, 1);
    assert!(net.gateway.memory_in_use() <= 64 + 2 * 4, "held {}", net.gateway.memory_in_use());
    net.can_frames_per_turn = usize::MAX;
    net.settle();
    let tde_to_source: Vec<Vec<u8>> = to_full(&net, Mti::TERMINATE_DUE_TO_ERROR);
    assert_eq!(tde_to_source, [vec![0x20, 0x40, 0x1F, 0x88]]);
    let tde_to_destination = can_payloads(&net.from_gateway, Mti::TERMINATE_DUE_TO_ERROR);
    assert_eq!(tde_to_destination, [vec![0x20, 0x40, 0x08, 0x88]]);
    assert!(
        net.gateway_events.iter().any(|e| matches!(e, GatewayEvent::StreamEnded { cause: StreamEnd::Overrun, .. }))
    );
}

#[test]
fn a_full_node_that_leaves_right_after_its_complete_still_delivers_every_byte() {
    let mut net = Net::started(gateway_config(256), core_config(256), core_config(2048));
    net.can_frames_per_turn = 1;
    let data = pattern(2000);
    net.start_transfer(Side::Full, data.clone(), 4096);
    // The full-format node sends its last window and its Complete, then its connection
    // closes while the gateway still has data of it for the slow bus.
    for _ in 0..100_000 {
        if net.from_full.iter().any(|m| m.mti == Mti::STREAM_DATA_COMPLETE) {
            break;
        }
        if !net.turn() {
            let next = net.next_deadline().expect("a transfer under way");
            net.advance_to(next);
        }
    }
    assert!(net.can.received.len() < data.len(), "data still on its way to CAN: {}", net.can.received.len());
    let now = net.now;
    net.gateway.handle_full_node_left(now, Net::node(Side::Full));
    net.run_until(|n| n.can.finished.is_some());
    assert_eq!(net.can.finished, Some((2000, true)));
    assert_eq!(net.can.received, data);
    net.settle();
    // The proxy's alias goes once its traffic has: the AMR follows the Complete.
    let kind = |f: &CanFrame| f.header().unwrap().kind;
    let complete = net.from_gateway.iter().position(|f| kind(f) == FrameKind::Message { can_mti: 0x8A8 });
    let amr = net.from_gateway.iter().position(|f| kind(f) == FrameKind::AliasMapReset);
    assert!(complete.is_some() && amr > complete, "Complete at {complete:?}, AMR at {amr:?}");
    assert!(net.gateway_events.iter().any(|e| matches!(e, GatewayEvent::ProxyReleased { .. })));
    assert_eq!(net.gateway.stats().data_bytes_dropped, 0);
}
