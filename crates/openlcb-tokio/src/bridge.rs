//! The hub's bridge between its GridConnect and OpenLCB-TCP clients: an
//! [`openlcb_gateway::Gateway`] that is one more client of each group.
//!
//! It receives every frame the GridConnect clients send and every message the OpenLCB-TCP
//! clients send (as the hub relays them), feeds them to the gateway, and relays what the
//! gateway hands out to the other group: CAN frames as GridConnect text, messages in the
//! OpenLCB-TCP framing with the gateway's Node ID as originating node. Full-format nodes get
//! proxy aliases on the CAN side; streams crossing are tracked by the gateway's rules. When an
//! OpenLCB-TCP client leaves, the hub sends the Node IDs it carried, and the gateway releases
//! their proxy aliases. Like any sender, the bridge waits while a client's queue is full. The
//! gateway's clock is microseconds since the bridge started.

use std::sync::Arc;

use bytes::{Bytes, BytesMut};
use openlcb_can::{GridConnectDecoder, gridconnect};
use openlcb_gateway::{Gateway, GatewayConfig};
use openlcb_stream::{Instant, NodeId};
use openlcb_tcp::{CaptureTime, Decoder, LinkPrefix, TcpFrame};
use tokio::sync::mpsc;

use crate::Framing;
use crate::hub::{ClientId, HubEvent, State};

/// One side of the bridge: its client id in the hub and the chunks relayed to it.
type Side = (ClientId, mpsc::UnboundedReceiver<Bytes>);

pub(crate) async fn run(can: Side, tcp: Side, mut departed: mpsc::UnboundedReceiver<NodeId>, state: Arc<State>) {
    let (can_id, mut can_rx) = can;
    let (tcp_id, mut tcp_rx) = tcp;
    let start = tokio::time::Instant::now();
    let now = || Instant::from_micros(u64::try_from(start.elapsed().as_micros()).unwrap_or(u64::MAX));
    let mut config = GatewayConfig::default();
    config.max_window = state.options().gateway_max_window.max(1);
    let mut gateway = Gateway::new(now(), config);
    let gateway_node = state.options().gateway_node_id;
    let mut gridconnect_decoder = GridConnectDecoder::default();
    let mut tcp_decoder = Decoder::default();
    let (mut to_can, mut to_tcp) = (BytesMut::new(), BytesMut::new());
    let sleep = tokio::time::sleep_until(start);
    tokio::pin!(sleep);
    loop {
        let deadline = gateway.poll_timeout();
        if let Some(at) = deadline {
            sleep.as_mut().reset(start + std::time::Duration::from_micros(at.as_micros()));
        }
        tokio::select! {
            // CAN side first when both have input: the hub's own AMRs for a client that left
            // are queued here before anything a client connecting after that can send, and
            // the gateway must forget the old node before it sees a new one with its Node ID.
            // Departures first of all, for the same reason (from the OpenLCB-TCP side).
            biased;
            Some(node) = departed.recv() => gateway.handle_full_node_left(now(), node),
            chunk = can_rx.recv() => {
                let Some(chunk) = chunk else { return };
                let now = now();
                gridconnect_decoder.decode_all(&chunk, |decoded| {
                    if let Ok(frame) = decoded {
                        gateway.handle_can_frame(now, &frame);
                    }
                });
            }
            chunk = tcp_rx.recv() => {
                let Some(chunk) = chunk else { return };
                let now = now();
                let mut input = &chunk[..];
                while let Some(decoded) = tcp_decoder.decode(&mut input) {
                    if let Ok(frame) = decoded {
                        gateway.handle_message(now, frame.message);
                    }
                }
                // The hub encoded these itself: a failure here would be a bug, not input.
                if tcp_decoder.failure().is_some() {
                    tcp_decoder = Decoder::default();
                }
            }
            () = &mut sleep, if deadline.is_some() => {}
        }
        let now = now();
        gateway.handle_timeout(now);
        // Frames out, then messages (pulling frames may release delayed Proceeds and
        // Completes), until both are drained.
        let mut text = [0u8; gridconnect::MAX_ENCODED_LEN];
        let mut frames = 0;
        loop {
            let mut moved = false;
            while let Some(frame) = gateway.poll_can_transmit() {
                if let Ok(len) = gridconnect::encode(&frame, &mut text) {
                    let text = text.get(..len).unwrap_or_default();
                    to_can.extend_from_slice(text);
                    to_can.extend_from_slice(b"\n");
                    frames += 1;
                    // The bridge's own frames, under its own client number.
                    if state.options().trace {
                        let text = String::from_utf8_lossy(text).into_owned();
                        state.event(HubEvent::Frame { client: can_id, text });
                    }
                }
                moved = true;
            }
            while let Some(message) = gateway.poll_message() {
                let prefix = LinkPrefix { gateway: gateway_node, capture_time: CaptureTime::from_instant(now) };
                if TcpFrame::new(prefix, message.as_ref()).encode_to(&mut to_tcp).is_ok() {
                    frames += 1;
                }
                moved = true;
            }
            if !moved {
                break;
            }
        }
        while let Some(event) = gateway.poll_event() {
            if state.options().trace {
                state.event(HubEvent::Frame { client: can_id, text: format!("gateway: {event:?}") });
            }
        }
        state.count(frames, 0);
        if !to_can.is_empty() {
            state.relay(can_id, Framing::GridConnect, &to_can.split().freeze()).await;
        }
        if !to_tcp.is_empty() {
            state.relay(tcp_id, Framing::Tcp, &to_tcp.split().freeze()).await;
        }
    }
}
