//! Faulty and unusual hubs on 127.0.0.1: a hub that stops reading, one that closes at once,
//! and a relay with the socket options of OpenMRN's `hub`. Every wait is bounded; every
//! loop stops by itself.

use std::future::Future;
use std::time::Duration;

use bytes::BytesMut;
use openlcb_stream::{Message, Mti, NodeId, OpenOptions};
use openlcb_tcp::{CaptureTime, Decoder, LinkPrefix, TcpFrame};
use openlcb_tokio::{Error, Node, NodeOptions, Protocol};
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::{TcpListener, TcpStream};

/// No single step of a test may take longer than this.
const LIMIT: Duration = Duration::from_secs(120);

async fn bounded<T>(what: &str, future: impl Future<Output = T>) -> T {
    match tokio::time::timeout(LIMIT, future).await {
        Ok(value) => value,
        Err(_) => panic!("{what} did not finish within {LIMIT:?}"),
    }
}

fn id(last: u8) -> NodeId {
    NodeId::from_bytes([0x05, 0x01, 0x01, 0x01, 0x22, last])
}

/// Data that differs at every offset of a window.
fn data(len: usize) -> Vec<u8> {
    (0..len).map(|i| (i as u32).wrapping_mul(2_654_435_761).rotate_right(13) as u8).collect()
}

fn encode(out: &mut BytesMut, hub: NodeId, message: &Message) {
    let prefix = LinkPrefix { gateway: hub, capture_time: CaptureTime::wrapping(0) };
    TcpFrame::new(prefix, message.as_ref()).encode_to(out).unwrap();
}

/// A hub that answers the first Initiate Request with an accept and a great deal of credit,
/// then never reads again: the sender's output piles up in the socket.
async fn hub_that_stops_reading(listener: TcpListener, me: NodeId, sender: NodeId) {
    let (mut socket, _) = listener.accept().await.unwrap();
    socket2::SockRef::from(&socket).set_recv_buffer_size(4096).unwrap();
    let mut decoder = Decoder::default();
    let mut buf = vec![0u8; 4096];
    let sid = 'request: loop {
        let n = socket.read(&mut buf).await.unwrap();
        assert!(n > 0, "the node left before asking for a stream");
        let mut input = &buf[..n];
        while let Some(frame) = decoder.decode(&mut input) {
            let message = frame.unwrap().message;
            if message.mti == Mti::STREAM_INITIATE_REQUEST {
                break 'request message.payload[4];
            }
        }
    };
    let mut out = BytesMut::new();
    let reply = Message::addressed(Mti::STREAM_INITIATE_REPLY, me, sender, vec![0xFF, 0xFF, 0x80, 0x00, sid, 1]);
    encode(&mut out, me, &reply);
    for _ in 0..200 {
        encode(&mut out, me, &Message::addressed(Mti::STREAM_DATA_PROCEED, me, sender, vec![sid, 1]));
    }
    socket.write_all(&out).await.unwrap();
    // Hold the connection open, reading nothing, until the node gives it up.
    let _ = socket.readable().await;
    tokio::time::sleep(LIMIT).await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_hub_that_stops_reading_ends_the_transfer_with_write_stalled() {
    let listener = TcpListener::bind("127.0.0.1:0").await.unwrap();
    let addr = listener.local_addr().unwrap().to_string();
    let (sender_id, receiver_id) = (id(0x10), id(0x11));
    let hub = tokio::spawn(hub_that_stops_reading(listener, receiver_id, sender_id));
    let mut options = NodeOptions::new(sender_id);
    options.write_timeout = Duration::from_millis(500);
    let node = bounded("joining", Node::connect(&addr, Protocol::Tcp, options)).await.unwrap();
    let mut stream = bounded("opening", node.open(OpenOptions::new(receiver_id, 65535))).await.unwrap();
    let chunk = data(1 << 20);
    let outcome = bounded("writing into a hub that reads nothing", async {
        // 13 MB of credit is more than any socket buffer takes; the loop ends on the error.
        for _ in 0..64 {
            stream.write_all(chunk.clone()).await?;
        }
        Ok::<_, Error>(())
    })
    .await;
    assert!(matches!(outcome, Err(Error::WriteStalled(_))), "got {outcome:?}");
    hub.abort();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_port_that_closes_at_once_is_an_unreachable_hub() {
    let listener = TcpListener::bind("127.0.0.1:0").await.unwrap();
    let addr = listener.local_addr().unwrap().to_string();
    let closer = tokio::spawn(async move {
        // Accept and close, like a firewall or a service that is not a hub.
        for _ in 0..4 {
            let Ok((socket, _)) = listener.accept().await else { return };
            drop(socket);
        }
    });
    let outcome = bounded("connecting", Node::connect(&addr, Protocol::GridConnect, NodeOptions::new(id(0x12)))).await;
    assert!(matches!(outcome, Err(Error::Connect { .. })), "got {outcome:?}");
    closer.abort();
}

/// What OpenMRN's `hub` does to every client it accepts (`FdUtils::optimize_socket_fd`).
fn openmrn_socket_options(socket: &TcpStream) {
    let socket = socket2::SockRef::from(socket);
    socket.set_recv_buffer_size(8192).unwrap();
    socket.set_send_buffer_size(8192).unwrap();
}

/// Copies one client's bytes to the other, a frame's worth per write as OpenMRN's hub does.
async fn pump(mut from: tokio::net::tcp::OwnedReadHalf, mut to: tokio::net::tcp::OwnedWriteHalf) {
    let mut buf = vec![0u8; 8192];
    loop {
        let n = match from.read(&mut buf).await {
            Ok(0) | Err(_) => return,
            Ok(n) => n,
        };
        for piece in buf[..n].chunks(64) {
            if to.write_all(piece).await.is_err() {
                return;
            }
        }
    }
}

/// A two-client relay with OpenMRN's socket options. Returns the segment size each client
/// advertised (as the relay sees it).
async fn small_window_relay(listener: TcpListener) -> [u32; 2] {
    let (a, _) = listener.accept().await.unwrap();
    let (b, _) = listener.accept().await.unwrap();
    openmrn_socket_options(&a);
    openmrn_socket_options(&b);
    let mss = [&a, &b].map(|s| socket2::SockRef::from(s).tcp_mss().unwrap());
    let (a_read, a_write) = a.into_split();
    let (b_read, b_write) = b.into_split();
    tokio::spawn(pump(a_read, b_write));
    tokio::spawn(pump(b_read, a_write));
    mss
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_large_window_crosses_a_relay_with_small_socket_buffers() {
    let listener = TcpListener::bind("127.0.0.1:0").await.unwrap();
    let addr = listener.local_addr().unwrap().to_string();
    let relay = tokio::spawn(small_window_relay(listener));
    let (sender_id, receiver_id) = (id(0x13), id(0x14));
    let mut receiver =
        bounded("joining", Node::connect(&addr, Protocol::GridConnect, NodeOptions::new(receiver_id))).await.unwrap();
    let sender =
        bounded("joining", Node::connect(&addr, Protocol::GridConnect, NodeOptions::new(sender_id))).await.unwrap();
    // The cause of the stall through OpenMRN's hub: segments larger than the ~16 KB window
    // such a hub advertises. Every node must keep its segments below it.
    let mss = bounded("the relay", relay).await.unwrap();
    assert!(mss.iter().all(|&m| m <= 8192), "segment sizes {mss:?} exceed a small hub's window");

    let payload = data(1 << 20);
    let send = async {
        let mut stream = sender.open(OpenOptions::new(receiver_id, 65535)).await?;
        stream.write_all(payload.clone()).await?;
        stream.finish().await
    };
    let receive = async {
        let mut stream = receiver.accept().await?;
        let mut got = Vec::new();
        while let Some(chunk) = stream.read().await? {
            got.extend_from_slice(&chunk);
        }
        Ok::<_, Error>(got)
    };
    let (sent, got) = bounded("the transfer", async { tokio::try_join!(send, receive) }).await.unwrap();
    assert_eq!(sent, payload.len() as u64);
    assert!(got == payload, "the data arrived changed");
}
