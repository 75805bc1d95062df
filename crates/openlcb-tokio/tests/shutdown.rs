//! Every way a node's handle can end, in whatever order the hub and the node go: no panic.

use openlcb_stream::NodeId;
use openlcb_tokio::{Framing, Hub, HubOptions, Node, NodeOptions};

mod common;
use common::bounded;

#[tokio::test]
async fn close_after_the_hub_went_away_and_closed_returned() {
    for protocol in [Framing::GridConnect, Framing::Tcp] {
        let hub = Hub::bind("127.0.0.1:0", Some("127.0.0.1:0"), HubOptions::default()).await.unwrap();
        let addr = match protocol {
            Framing::Tcp => hub.tcp_local_addr().unwrap().to_string(),
            _ => hub.local_addr().to_string(),
        };
        let id = NodeId::from_bytes([0x05, 0x01, 0x01, 0x01, 0x22, 0x31]);
        let mut node = bounded("joining", Node::connect(&addr, protocol, NodeOptions::new(id))).await.unwrap();
        drop(hub);
        // The driver ends with the connection; `closed` sees it end, and `close` after it
        // (what `serve` does on its way out) must not poll the finished task again.
        let _ = bounded("the connection's end", node.closed()).await;
        let _ = bounded("closed again", node.closed()).await;
        bounded("close", node.close()).await;
    }
}
