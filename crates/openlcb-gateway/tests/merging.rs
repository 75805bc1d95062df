//! How stream data is merged, flushed and passed on.

mod common;

use common::{CAN_NODE, FULL_NODE, Net, core_config, node_id, pattern};
use openlcb_can::{CanFrame, FrameKind};
use openlcb_gateway::GatewayConfig;
use openlcb_stream::{Event, Mti, OpenOptions, StreamHandle};

fn started() -> Net {
    Net::started(GatewayConfig::default(), core_config(256), core_config(256))
}

/// Opens a stream from the CAN node to the full node and waits until it is open.
fn open_from_can(net: &mut Net) -> StreamHandle {
    let handle = net.can.endpoint.open(net.now, OpenOptions::new(node_id(FULL_NODE), 256)).unwrap();
    net.run_until(|n| n.can.events.iter().any(|e| matches!(e, Event::Opened { .. })));
    handle
}

/// The payload lengths (DID excluded) of the Data Sends the full node got.
fn data_sends(net: &Net) -> Vec<usize> {
    net.to_full.iter().filter(|m| m.mti == Mti::STREAM_DATA_SEND).map(|m| m.payload.len() - 1).collect()
}

#[test]
fn merge_timer_forwards_a_trickle() {
    let mut net = started();
    let handle = open_from_can(&mut net);
    assert_eq!(net.can.endpoint.write(net.now, handle, &pattern(10)), Ok(10));
    net.settle();
    assert_eq!(data_sends(&net), [7], "the stream's first frame goes at once, three bytes wait");
    assert_eq!(net.gateway.memory_in_use(), 3);
    let deadline = net.gateway.poll_timeout().unwrap();
    assert_eq!(deadline, net.now + GatewayConfig::default().merge_delay);
    net.advance_to(deadline);
    net.settle();
    assert_eq!(data_sends(&net), [7, 3]);
    assert_eq!(net.full.received, pattern(10));
}

#[test]
fn flush_frame_forwards_the_buffer_then_the_flush() {
    let mut net = started();
    let handle = open_from_can(&mut net);
    net.can.endpoint.write(net.now, handle, &pattern(30)).unwrap();
    net.can.endpoint.flush(net.now, handle).unwrap();
    net.settle();
    assert_eq!(data_sends(&net), [7, 23, 0], "merged data, then the flush, without waiting");
    assert_eq!(net.gateway.memory_in_use(), 0);
}

#[test]
fn flush_from_the_full_side_is_passed_on_after_the_buffer_drained() {
    let mut net = started();
    let handle = net.full.endpoint.open(net.now, OpenOptions::new(node_id(CAN_NODE), 256)).unwrap();
    net.settle();
    net.can_frames_per_turn = 0;
    net.full.endpoint.write(net.now, handle, &pattern(100)).unwrap();
    net.full.endpoint.flush(net.now, handle).unwrap();
    net.settle();
    assert_eq!(net.gateway.memory_in_use(), 100, "the data waits for the bus, the flush for the data");
    let before = net.from_gateway.len();
    net.can_frames_per_turn = 1;
    net.settle();
    let stream_frames: Vec<usize> = net.from_gateway[before..]
        .iter()
        .filter(|f| matches!(f.header().unwrap().kind, FrameKind::StreamData { .. }))
        .map(|f| f.payload().len())
        .collect();
    assert_eq!(stream_frames.len(), 16, "15 data frames and the flush");
    assert_eq!(stream_frames.last(), Some(&1), "the DID-only flush comes last");
    assert!(stream_frames[..15].iter().all(|&len| len > 1));
    assert_eq!(net.can.received, pattern(100));
}

#[test]
fn untracked_stream_data_crosses_frame_by_frame() {
    let mut net = started();
    let can_alias = u32::from(net.can_link.alias().unwrap().as_raw());
    let proxy = u32::from(net.gateway.proxy_alias(node_id(FULL_NODE)).unwrap().as_raw());
    let before = net.to_full.len();
    // No Request or Reply was seen for DID 9: the frames are still forwarded, one by one.
    for chunk in [&[9, 1, 2, 3, 4, 5, 6, 7][..], &[9, 8, 9][..], &[9][..]] {
        let frame = CanFrame::extended(0x1F00_0000 | proxy << 12 | can_alias, chunk).unwrap();
        net.gateway.handle_can_frame(net.now, &frame);
    }
    net.settle();
    let forwarded: Vec<Vec<u8>> = net.to_full[before..].iter().map(|m| m.payload.to_vec()).collect();
    assert_eq!(forwarded, [vec![9, 1, 2, 3, 4, 5, 6, 7], vec![9, 8, 9], vec![9]]);
    assert!(net.to_full[before..].iter().all(|m| m.mti == Mti::STREAM_DATA_SEND
        && m.source == node_id(CAN_NODE)
        && m.destination == Some(node_id(FULL_NODE))));
}

#[test]
fn idle_streams_are_forgotten() {
    let mut config = GatewayConfig::default();
    config.stream_idle_timeout = openlcb_stream::Duration::from_secs(5);
    let mut core = core_config(256);
    core.keepalive_interval = None;
    core.idle_timeout = None;
    let mut net = Net::started(config, core.clone(), core);
    open_from_can(&mut net);
    assert_eq!(net.gateway.tracked_streams(), 1);
    net.advance_to(net.now + openlcb_stream::Duration::from_secs(5));
    net.settle();
    assert_eq!(net.gateway.tracked_streams(), 0);
}
