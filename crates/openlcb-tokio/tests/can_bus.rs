//! The CAN-interface path ([`FrameStream`] over a [`FrameBus`]) against an in-memory bus
//! whose controllers echo every frame they send, as SocketCAN with own-message reception
//! does: logins, transfers, a hub attached to the bus, echo filtering. Every wait is bounded.

use std::sync::atomic::Ordering;
use std::sync::{Arc, Mutex};
use std::task::{Context, Poll};

use openlcb_can::CanFrame;
use openlcb_stream::NodeId;
use openlcb_tokio::can::{FrameBus, FrameStream};
use openlcb_tokio::{Framing, Hub, HubOptions, Node, NodeOptions};
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::sync::mpsc;

mod common;
use common::bounded;
#[path = "common/transfer.rs"]
mod transfer;
use transfer::moves;

/// One controller on a [`MemoryBus`]: what it sends reaches every controller, itself included
/// unless it is made not to echo ([`MemoryBus::quiet_controller`]).
struct Controller {
    bus: Arc<Mutex<Vec<mpsc::UnboundedSender<CanFrame>>>>,
    heard: mpsc::UnboundedReceiver<CanFrame>,
    /// Its own place on the bus, skipped when it sends, if it does not echo.
    quiet: Option<usize>,
}

/// A lossless in-memory CAN bus.
#[derive(Default)]
struct MemoryBus(Arc<Mutex<Vec<mpsc::UnboundedSender<CanFrame>>>>);

impl MemoryBus {
    fn controller(&self) -> Controller {
        let (tx, heard) = mpsc::unbounded_channel();
        self.0.lock().unwrap().push(tx);
        Controller { bus: self.0.clone(), heard, quiet: None }
    }

    /// A controller that never hears its own frames (SocketCAN as `open_socketcan` opens it).
    fn quiet_controller(&self) -> Controller {
        let controller = self.controller();
        let place = self.0.lock().unwrap().len() - 1;
        Controller { quiet: Some(place), ..controller }
    }
}

impl FrameBus for Controller {
    fn read_message(&mut self, cx: &mut Context<'_>) -> Poll<std::io::Result<CanFrame>> {
        self.heard.poll_recv(cx).map(|frame| frame.ok_or_else(|| std::io::ErrorKind::BrokenPipe.into()))
    }

    fn poll_send(&mut self, _cx: &mut Context<'_>, frame: &CanFrame) -> Poll<std::io::Result<()>> {
        for (place, controller) in self.bus.lock().unwrap().iter().enumerate() {
            if self.quiet != Some(place) {
                let _ = controller.send(*frame);
            }
        }
        Poll::Ready(Ok(()))
    }

    fn may_echo(&self) -> bool {
        self.quiet.is_none()
    }
}

fn id(last: u8) -> NodeId {
    NodeId::from_bytes([0x05, 0x01, 0x01, 0x01, 0x22, last])
}

fn pattern(len: usize) -> Vec<u8> {
    (0..len).map(|i| (i as u32).wrapping_mul(2_654_435_761).rotate_right(5) as u8).collect()
}

#[tokio::test]
async fn nodes_on_an_echoing_bus_log_in_and_move_a_stream() {
    let bus = MemoryBus::default();
    let (one, other) = (FrameStream::new(bus.controller()), FrameStream::new(bus.controller()));
    let echoes = [one.echoes(), other.echoes()];
    let (sender, mut receiver) = bounded("two logins on the bus", async {
        tokio::try_join!(
            Node::over(one, Framing::GridConnect, NodeOptions::new(id(1))),
            Node::over(other, Framing::GridConnect, NodeOptions::new(id(2))),
        )
    })
    .await
    .unwrap();
    let payload = pattern(256 * 1024);
    moves(&sender, &mut receiver, &payload, 2048).await;
    // Each heard its own login and data back and dropped it.
    for echoes in echoes {
        assert!(echoes.load(Ordering::Relaxed) > 4, "echoes were not dropped");
    }
}

#[tokio::test]
async fn a_hub_attached_to_the_bus_relays_between_a_bus_node_and_a_tcp_node() {
    let bus = MemoryBus::default();
    let mut hub = bounded("binding the hub", Hub::bind("127.0.0.1:0", None, HubOptions::default())).await.unwrap();
    hub.attach(FrameStream::new(bus.controller()), "can0");
    let mut on_bus = bounded(
        "login on the bus",
        Node::over(FrameStream::new(bus.controller()), Framing::GridConnect, NodeOptions::new(id(3))),
    )
    .await
    .unwrap();
    let on_tcp = bounded(
        "login through the hub",
        Node::connect(&hub.local_addr().to_string(), Framing::GridConnect, NodeOptions::new(id(4))),
    )
    .await
    .unwrap();
    let payload = pattern(100_000);
    moves(&on_tcp, &mut on_bus, &payload, 2048).await;
}

/// The next `lines` lines of GridConnect text `stream` reads.
async fn read_lines(stream: &mut FrameStream<Controller>, lines: usize) -> String {
    let mut text = Vec::new();
    bounded("reading", async {
        let mut buf = [0u8; 64];
        while text.iter().filter(|&&b| b == b'\n').count() < lines {
            let n = stream.read(&mut buf).await.unwrap();
            assert!(n > 0, "the bus ended");
            text.extend_from_slice(&buf[..n]);
        }
    })
    .await;
    String::from_utf8(text).unwrap()
}

#[tokio::test]
async fn an_echo_is_dropped_once_and_other_frames_are_read() {
    let bus = MemoryBus::default();
    let mut mine = FrameStream::new(bus.controller());
    let mut theirs = FrameStream::new(bus.controller());
    let echoes = mine.echoes();
    bounded("writing", async {
        mine.write_all(b":X19490123N;").await.unwrap();
        mine.flush().await.unwrap();
        // Another node says something, then the very same frame as ours (not an echo).
        theirs.write_all(b":X19170456N0501010122F0;\n:X19490123N;").await.unwrap();
        theirs.flush().await.unwrap();
    })
    .await;
    assert_eq!(read_lines(&mut mine, 2).await, ":X19170456N0501010122F0;\n:X19490123N;\n");
    assert_eq!(echoes.load(Ordering::Relaxed), 1);
}

/// A node that left the bus side of a hub and came back on the bus itself sends the very
/// frames the hub once put on the bus for it (same alias, same data): a controller that never
/// echoes must hear them all, not take them for echoes of its own.
#[tokio::test]
async fn a_controller_that_never_echoes_hears_frames_equal_to_its_own() {
    let bus = MemoryBus::default();
    let mut mine = FrameStream::new(bus.quiet_controller());
    let mut theirs = FrameStream::new(bus.controller());
    let frames = ":X19490123N;\n:X1A456123N0102030405060708;\n";
    bounded("writing", async {
        mine.write_all(frames.as_bytes()).await.unwrap();
        mine.flush().await.unwrap();
        theirs.write_all(frames.as_bytes()).await.unwrap();
        theirs.flush().await.unwrap();
    })
    .await;
    assert_eq!(read_lines(&mut mine, 2).await, frames);
    assert_eq!(mine.echoes().load(Ordering::Relaxed), 0);
}
