//! Nodes and hubs over byte streams that are not TCP clients: a pseudo-terminal standing in
//! for a USB-serial GridConnect adapter, and hubs chained by `link_upstream`. Everything on 127.0.0.1 (ephemeral ports); every wait is bounded.

use openlcb_stream::{NodeId, OpenOptions};
use openlcb_tokio::serial::{self, SerialPort};
use openlcb_tokio::{Error, Framing, Hub, HubEvent, HubOptions, Node, NodeOptions};
use tokio_serial::SerialPort as _;

mod common;
use common::bounded;
#[path = "common/transfer.rs"]
mod transfer;
use transfer::moves;

const MIB: usize = 1024 * 1024;

fn id(last: u8) -> NodeId {
    NodeId::from_bytes([0x05, 0x01, 0x01, 0x01, 0x22, last])
}

/// Data that differs at every offset of a window.
fn pattern(len: usize) -> Vec<u8> {
    (0..len).map(|i| (i as u32).wrapping_mul(2_654_435_761).rotate_right(7) as u8).collect()
}

async fn gridconnect_hub() -> Hub {
    bounded("binding a hub", Hub::bind("127.0.0.1:0", None, HubOptions::default())).await.unwrap()
}

async fn join(addr: &str, node: NodeId) -> Node {
    bounded("joining", Node::connect(addr, Framing::GridConnect, NodeOptions::new(node))).await.unwrap()
}

/// Waits for the hub's next [`HubEvent::Attached`]; returns its name.
async fn attached(hub: &mut Hub) -> String {
    bounded("a link attaching", async {
        loop {
            match hub.next_event().await {
                Some(HubEvent::Attached { name, .. }) => return name,
                Some(_) => {}
                None => panic!("the hub's events ended"),
            }
        }
    })
    .await
}

/// A pseudo-terminal pair; the second is the terminal side, with its device path.
fn pty() -> (SerialPort, SerialPort, String) {
    let (master, terminal) = SerialPort::pair().unwrap();
    let path = terminal.name().unwrap();
    (master, terminal, path)
}

#[tokio::test]
async fn a_node_on_a_serial_port_sends_a_mebibyte_to_a_tcp_node_through_the_hub() {
    // The hub holds the pty's master as if it were the adapter; the node opens the terminal
    // side by its path, as `--serial /dev/pts/N` would.
    let (master, _terminal, path) = pty();
    let mut hub = gridconnect_hub().await;
    hub.attach(master, "pty");
    assert_eq!(attached(&mut hub).await, "pty");
    let port = serial::open(&path, serial::DEFAULT_BAUD).unwrap();
    let serial_node =
        bounded("login over the pty", Node::over(port, Framing::GridConnect, NodeOptions::new(id(1)))).await.unwrap();
    let mut tcp_node = join(&hub.local_addr().to_string(), id(2)).await;

    let payload = pattern(MIB);
    moves(&serial_node, &mut tcp_node, &payload, 2048).await;

    // And back, from the TCP side to the serial side.
    let mut serial_node = serial_node;
    let back = pattern(100_000);
    moves(&tcp_node, &mut serial_node, &back, 65535).await;
}

#[tokio::test]
async fn a_serial_port_that_cannot_be_opened_is_a_device_error_naming_it() {
    match serial::open("/nonexistent/tty-of-no-adapter", serial::DEFAULT_BAUD) {
        Err(error @ Error::Device { .. }) => {
            assert_eq!(error.to_string(), "cannot open the serial port /nonexistent/tty-of-no-adapter: no such device")
        }
        other => panic!("expected a device error, got {:?}", other.map(|_| "a port")),
    }
}

#[tokio::test]
async fn two_chained_hubs_carry_a_stream_across() {
    let upstream = gridconnect_hub().await;
    let mut downstream = gridconnect_hub().await;
    let upstream_addr = upstream.local_addr().to_string();
    downstream.link_upstream(&upstream_addr);
    assert_eq!(attached(&mut downstream).await, format!("upstream {upstream_addr}"));

    let mut receiver = join(&upstream_addr, id(5)).await;
    let sender = join(&downstream.local_addr().to_string(), id(6)).await;
    let payload = pattern(200_000);
    moves(&sender, &mut receiver, &payload, 2048).await;
}

#[tokio::test]
async fn a_restarted_upstream_hub_fails_the_transfer_across_and_the_next_one_works() {
    let upstream = gridconnect_hub().await;
    let upstream_addr = upstream.local_addr().to_string();
    let mut downstream = gridconnect_hub().await;
    downstream.link_upstream(&upstream_addr);
    attached(&mut downstream).await;
    let sender = join(&downstream.local_addr().to_string(), id(7)).await;
    let mut receiver = join(&upstream_addr, id(8)).await;

    // The upstream hub goes away once the receiver has some of the data.
    let destination = receiver.node_id();
    let payload = pattern(4 * MIB);
    let send = async {
        let mut stream = sender.open(OpenOptions::new(destination, 512)).await?;
        for chunk in payload.chunks(64 * 1024) {
            stream.write_all(chunk.to_vec()).await?;
        }
        stream.finish().await
    };
    let cut = async {
        let mut stream = receiver.accept().await.unwrap();
        let first = stream.read().await.unwrap();
        assert!(first.is_some_and(|chunk| !chunk.is_empty()), "no data arrived before the cut");
        drop(upstream);
    };
    let (sent, ()) = bounded("the interrupted transfer", async { tokio::join!(send, cut) }).await;
    assert!(sent.is_err(), "a transfer across a hub that went away reported success: {sent:?}");
    drop(receiver);

    // The same address again: the link comes back by itself.
    let upstream = bounded("binding the upstream hub again", Hub::bind(&upstream_addr, None, HubOptions::default()))
        .await
        .unwrap();
    assert_eq!(attached(&mut downstream).await, format!("upstream {upstream_addr}"));
    let mut receiver = join(&upstream.local_addr().to_string(), id(9)).await;
    let payload = pattern(200_000);
    moves(&sender, &mut receiver, &payload, 2048).await;
}

#[tokio::test]
async fn an_unreachable_upstream_hub_is_reported_with_a_growing_bounded_wait() {
    // A port nobody listens on: bind one, note it, close it.
    let addr = std::net::TcpListener::bind("127.0.0.1:0").unwrap().local_addr().unwrap().to_string();
    let mut hub = gridconnect_hub().await;
    hub.link_upstream(&addr);
    let mut waits = Vec::new();
    bounded("three failed attempts", async {
        while waits.len() < 3 {
            if let Some(HubEvent::UpstreamDown { addr: down, retry_in, .. }) = hub.next_event().await {
                assert_eq!(down, addr);
                waits.push(retry_in);
            }
        }
    })
    .await;
    assert_eq!(waits[0], openlcb_tokio::hub::UPSTREAM_RETRY_FIRST);
    assert!(waits.windows(2).all(|pair| pair[1] >= pair[0] && pair[1] <= openlcb_tokio::hub::UPSTREAM_RETRY_MAX));
    assert!(waits[2] > waits[0], "the wait did not grow: {waits:?}");
}
