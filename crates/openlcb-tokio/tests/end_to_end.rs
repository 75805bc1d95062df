//! End-to-end: a hub and nodes on 127.0.0.1 (ephemeral ports), real sockets, every wait
//! bounded by a timeout.

use std::time::Duration;

use openlcb_stream::wire::ReplyCode;
use openlcb_stream::{AcceptPolicy, NodeId, OpenOptions};
use openlcb_tokio::{Error, Framing, Hub, HubEvent, HubOptions, Node, NodeOptions};
use tokio::io::AsyncWriteExt;

mod common;
use common::bounded;

fn id(last: u8) -> NodeId {
    NodeId::from_bytes([0x05, 0x01, 0x01, 0x01, 0x22, last])
}

/// Deterministic data that differs at every offset of a window.
fn data(len: usize, seed: u8) -> Vec<u8> {
    (0..len).map(|i| (i as u32).wrapping_mul(2_654_435_761).rotate_right(13) as u8 ^ seed).collect()
}

async fn start_hub(options: HubOptions) -> Hub {
    bounded("binding the hub", Hub::bind("127.0.0.1:0", Some("127.0.0.1:0"), options)).await.unwrap()
}

fn addr(hub: &Hub, protocol: Framing) -> String {
    match protocol {
        Framing::Tcp => hub.tcp_local_addr().unwrap().to_string(),
        _ => hub.local_addr().to_string(),
    }
}

async fn join(addr: &str, protocol: Framing, node: NodeId, window: u16) -> Node {
    let mut options = NodeOptions::new(node);
    options.node.stream.max_window = window;
    bounded("joining", Node::connect(addr, protocol, options)).await.unwrap()
}

/// Sends `payload` from `sender` to `receiver` and returns what arrived.
async fn transfer(sender: &Node, receiver: &mut Node, payload: &[u8], window: u16) -> Vec<u8> {
    let destination = receiver.node_id();
    let send = async {
        let mut stream = sender.open(OpenOptions::new(destination, window)).await?;
        for chunk in payload.chunks(100_000) {
            stream.write_all(chunk.to_vec()).await?;
        }
        stream.finish().await
    };
    let receive = async {
        let mut stream = receiver.accept().await?;
        assert_eq!(stream.info().peer, sender.node_id());
        let mut received = Vec::new();
        while let Some(chunk) = stream.read().await? {
            received.extend_from_slice(&chunk);
        }
        assert_eq!(stream.received(), received.len() as u64);
        Ok::<_, Error>(received)
    };
    let (sent, received) = bounded("a transfer", async { tokio::try_join!(send, receive) }).await.unwrap();
    assert_eq!(sent, payload.len() as u64);
    received
}

async fn sizes_through_hub(protocol: Framing) {
    const WINDOW: u16 = 2048;
    let hub = start_hub(HubOptions::default()).await;
    let addr = addr(&hub, protocol);
    let mut receiver = join(&addr, protocol, id(0xF1), WINDOW).await;
    let sender = join(&addr, protocol, id(0xF0), WINDOW).await;
    let w = usize::from(WINDOW);
    for (n, len) in [0, 1, 7, 8, w - 1, w, w + 1, 4 * 1024 * 1024].into_iter().enumerate() {
        let payload = data(len, n as u8);
        let received = transfer(&sender, &mut receiver, &payload, WINDOW).await;
        assert!(received == payload, "{protocol:?}: {len} bytes did not arrive intact ({} arrived)", received.len());
    }
    let stats = sender.stats().await.unwrap();
    // Batching: a window's CAN frames go out in a few write calls, not one call per frame.
    // (On OpenLCB-TCP a window is one message anyway.)
    if protocol == Framing::GridConnect {
        assert!(stats.wire.writes * 10 < stats.wire.frames_out, "{:?}", stats.wire);
    }
    assert_eq!(hub.stats().decode_errors, 0);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn gridconnect_transfers_of_every_edge_size_through_the_hub() {
    sizes_through_hub(Framing::GridConnect).await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn openlcb_tcp_transfers_of_every_edge_size_through_the_hub() {
    sizes_through_hub(Framing::Tcp).await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn two_senders_to_one_receiver_at_once() {
    let hub = start_hub(HubOptions::default()).await;
    let addr = addr(&hub, Framing::GridConnect);
    let mut receiver = join(&addr, Framing::GridConnect, id(0xF1), 4096).await;
    let a = join(&addr, Framing::GridConnect, id(0xA0), 4096).await;
    let b = join(&addr, Framing::GridConnect, id(0xB0), 4096).await;
    let (payload_a, payload_b) = (data(300_000, 0xAA), data(200_001, 0xBB));
    let receiver_id = receiver.node_id();

    async fn send(node: &Node, to: NodeId, payload: Vec<u8>) -> Result<u64, Error> {
        let mut stream = node.open(OpenOptions::new(to, 4096)).await?;
        for chunk in payload.chunks(50_000) {
            stream.write_all(chunk.to_vec()).await?;
        }
        stream.finish().await
    }
    let receive = async {
        let (mut first, mut second) = (receiver.accept().await?, receiver.accept().await?);
        // Read both at once, so neither sender waits for the other.
        let (first, second) = tokio::try_join!(read_all(&mut first), read_all(&mut second))?;
        Ok::<_, Error>(vec![first, second])
    };
    let (sent_a, sent_b, mut results) = bounded("two transfers", async {
        tokio::try_join!(send(&a, receiver_id, payload_a.clone()), send(&b, receiver_id, payload_b.clone()), receive)
    })
    .await
    .unwrap();
    assert_eq!((sent_a, sent_b), (300_000, 200_001));
    results.sort_by_key(|(peer, _)| *peer);
    assert_eq!(results[0].0, a.node_id());
    assert!(results[0].1 == payload_a, "stream from A damaged");
    assert_eq!(results[1].0, b.node_id());
    assert!(results[1].1 == payload_b, "stream from B damaged");
}

/// Reads a stream to its end: the sender and the bytes.
async fn read_all(stream: &mut openlcb_tokio::RecvStream) -> Result<(NodeId, Vec<u8>), Error> {
    let mut received = Vec::new();
    while let Some(chunk) = stream.read().await? {
        received.extend_from_slice(&chunk);
    }
    Ok((stream.info().peer, received))
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_rejection_reports_the_code_and_its_meaning() {
    let hub = start_hub(HubOptions::default()).await;
    let addr = addr(&hub, Framing::GridConnect);
    let mut options = NodeOptions::new(id(0xF1));
    options.node.stream.accept_policy = AcceptPolicy::RejectAll(ReplyCode::BUFFER_UNAVAILABLE);
    let _busy = bounded("joining", Node::connect(&addr, Framing::GridConnect, options)).await.unwrap();
    let sender = join(&addr, Framing::GridConnect, id(0xF0), 2048).await;
    let error = bounded("open", sender.open(OpenOptions::new(id(0xF1), 2048))).await.unwrap_err();
    assert!(matches!(error, Error::Rejected { code: ReplyCode::BUFFER_UNAVAILABLE, .. }), "{error:?}");
    let text = error.to_string();
    assert!(text.contains("0x2020") && text.contains("buffer unavailable"), "{text}");
    assert!(error.is_temporary());
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_node_nobody_answers_for_is_reported_unreachable() {
    let hub = start_hub(HubOptions::default()).await;
    let addr = addr(&hub, Framing::GridConnect);
    let sender = join(&addr, Framing::GridConnect, id(0xF0), 2048).await;
    let error = bounded("open", sender.open(OpenOptions::new(id(0x99), 2048))).await.unwrap_err();
    assert!(matches!(error, Error::Unreachable(node) if node == id(0x99)), "{error:?}");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn an_unreachable_hub_is_a_connect_error() {
    // Bind and drop a listener: its port is free and nothing listens there.
    let port = std::net::TcpListener::bind("127.0.0.1:0").unwrap().local_addr().unwrap().port();
    let addr = format!("127.0.0.1:{port}");
    let error =
        bounded("connect", Node::connect(&addr, Framing::GridConnect, NodeOptions::new(id(0xF0)))).await.unwrap_err();
    assert!(matches!(error, Error::Connect { .. }), "{error:?}");
    assert!(error.to_string().contains(&addr));
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_restarted_hub_loses_its_clients_and_serves_new_ones() {
    let hub = start_hub(HubOptions::default()).await;
    let addr = addr(&hub, Framing::GridConnect);
    let mut receiver = join(&addr, Framing::GridConnect, id(0xF1), 2048).await;
    let mut sender = join(&addr, Framing::GridConnect, id(0xF0), 2048).await;
    let before = data(10_000, 1);
    assert!(transfer(&sender, &mut receiver, &before, 2048).await == before);

    drop(hub);
    for node in [&mut sender, &mut receiver] {
        let error = bounded("noticing the lost hub", node.closed()).await;
        assert!(matches!(error, Error::ConnectionLost(_)), "{error:?}");
        // Every later call reports the same.
        let error = bounded("open after loss", node.open(OpenOptions::new(id(0x01), 16))).await.unwrap_err();
        assert!(matches!(error, Error::ConnectionLost(_)), "{error:?}");
    }

    // The same port again; new nodes with the same Node IDs.
    let hub = bounded("rebinding", Hub::bind(&addr, None, HubOptions::default())).await.unwrap();
    assert_eq!(hub.local_addr().to_string(), addr);
    let mut receiver = join(&addr, Framing::GridConnect, id(0xF1), 2048).await;
    let sender = join(&addr, Framing::GridConnect, id(0xF0), 2048).await;
    let after = data(100_000, 2);
    assert!(transfer(&sender, &mut receiver, &after, 2048).await == after);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn garbage_from_one_client_does_not_hurt_the_others() {
    let mut hub = start_hub(HubOptions::default()).await;
    let addr = addr(&hub, Framing::GridConnect);
    let mut receiver = join(&addr, Framing::GridConnect, id(0xF1), 2048).await;
    let sender = join(&addr, Framing::GridConnect, id(0xF0), 2048).await;

    let mut rogue = bounded("rogue connect", tokio::net::TcpStream::connect(&addr)).await.unwrap();
    let garbage: Vec<u8> = (0..64 * 1024u32).map(|i| (i.wrapping_mul(2_246_822_519) >> 7) as u8).collect();
    let payload = data(500_000, 3);
    let spew = async {
        for _ in 0..8 {
            rogue.write_all(&garbage).await?;
            // Half frames, bad ids, over-long frames.
            rogue.write_all(b":X19CC8;:XZZZN00;:X1FFFFFFFFFN0102;:X19170123N").await?;
            rogue.write_all(&[b'0'; 300]).await?;
        }
        rogue.flush().await
    };
    let (received, spewed) = bounded("transfer beside garbage", async {
        tokio::join!(transfer(&sender, &mut receiver, &payload, 2048), spew)
    })
    .await;
    spewed.unwrap();
    assert!(received == payload, "the transfer beside the garbage was damaged");
    let mut saw_garbage = false;
    while let Ok(Some(event)) = tokio::time::timeout(Duration::from_secs(1), hub.next_event()).await {
        saw_garbage |= matches!(event, HubEvent::Garbage { .. });
        if saw_garbage {
            break;
        }
    }
    assert!(saw_garbage, "the hub reported no garbage");
    assert!(hub.stats().decode_errors > 0);
    // The hub still takes new clients.
    let late = join(&addr, Framing::GridConnect, id(0xF2), 2048).await;
    let again = data(3000, 4);
    assert!(transfer(&late, &mut receiver, &again, 2048).await == again);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_client_that_does_not_read_is_dropped_and_the_rest_go_on() {
    let mut options = HubOptions::default();
    options.max_queued_bytes = 64 * 1024;
    let mut hub = start_hub(options).await;
    let addr = addr(&hub, Framing::GridConnect);
    // Connects with a small receive buffer, then never reads.
    let socket = tokio::net::TcpSocket::new_v4().unwrap();
    socket.set_recv_buffer_size(4096).unwrap();
    let _stuck = bounded("stuck connect", socket.connect(addr.parse().unwrap())).await.unwrap();
    let stuck = bounded("the connect event", async {
        loop {
            if let Some(HubEvent::Connected { client, .. }) = hub.next_event().await {
                break client;
            }
        }
    })
    .await;
    let mut receiver = join(&addr, Framing::GridConnect, id(0xF1), 2048).await;
    let sender = join(&addr, Framing::GridConnect, id(0xF0), 2048).await;
    // Enough text to fill the stuck client's socket buffers and its queue.
    let payload = data(4 * 1024 * 1024, 5);
    assert!(transfer(&sender, &mut receiver, &payload, 2048).await == payload);
    assert_eq!(hub.stats().slow_clients, 1);
    let dropped = bounded("the slow-client event", async {
        loop {
            match hub.next_event().await {
                Some(HubEvent::SlowClient { client, .. }) => break Some(client),
                Some(_) => {}
                None => break None,
            }
        }
    })
    .await;
    assert_eq!(dropped, Some(stuck), "the stuck client is the one dropped");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_receiver_that_vanishes_mid_transfer_fails_the_sender() {
    let hub = start_hub(HubOptions::default()).await;
    let addr = addr(&hub, Framing::GridConnect);
    let mut options = NodeOptions::new(id(0xF0));
    options.node.stream.proceed_timeout = openlcb_stream::Duration::from_millis(1500);
    let sender = bounded("joining", Node::connect(&addr, Framing::GridConnect, options)).await.unwrap();
    let mut receiver = join(&addr, Framing::GridConnect, id(0xF1), 2048).await;

    let mut stream = bounded("open", sender.open(OpenOptions::new(id(0xF1), 2048))).await.unwrap();
    let mut incoming = bounded("accept", receiver.accept()).await.unwrap();
    stream.write_all(vec![1u8; 1000]).await.unwrap();
    let first = bounded("first data", incoming.read()).await.unwrap();
    assert!(first.is_some_and(|chunk| !chunk.is_empty()));
    // The receiver vanishes without a word, as if its program had crashed.
    receiver.abort();
    // A crashed program runs no destructors: its stream handle must not say goodbye either.
    std::mem::forget(incoming);

    let result = bounded("sending into the void", async {
        loop {
            stream.write_all(vec![2u8; 10_000]).await?;
        }
        #[allow(unreachable_code)]
        Ok::<(), Error>(())
    })
    .await;
    let error = result.unwrap_err();
    // A hub is a wire: it never speaks for the vanished node (no AMR), so the sender's
    // Proceed timeout ends the stream.
    let timed_out = matches!(error, Error::TimedOut { kind: openlcb_stream::TimeoutKind::Proceed, .. });
    assert!(timed_out, "{error:?}");
    assert!(error.to_string().contains("05.01.01.01.22.F1"), "{error}");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_hub_bridges_openlcb_tcp_and_gridconnect_nodes_both_ways() {
    let hub = start_hub(HubOptions::default()).await;
    let (gridconnect, tcp) = (addr(&hub, Framing::GridConnect), addr(&hub, Framing::Tcp));
    let mut can_node = join(&gridconnect, Framing::GridConnect, id(0xC1), 2048).await;
    let mut tcp_node = join(&tcp, Framing::Tcp, id(0x71), 2048).await;
    for (n, window) in [2048u16, 300].into_iter().enumerate() {
        let payload = data(100_003, n as u8);
        let received = transfer(&tcp_node, &mut can_node, &payload, window).await;
        assert!(received == payload, "OpenLCB-TCP -> GridConnect, window {window}: damaged");
        let received = transfer(&can_node, &mut tcp_node, &payload, window).await;
        assert!(received == payload, "GridConnect -> OpenLCB-TCP, window {window}: damaged");
    }
}

/// A bare GridConnect client: sends text, reads frames until one matches.
struct RawClient {
    socket: tokio::net::TcpStream,
    decoder: openlcb_can::GridConnectDecoder,
    frames: std::collections::VecDeque<openlcb_can::CanFrame>,
}

impl RawClient {
    async fn connect(addr: &str) -> Self {
        let socket = bounded("raw connect", tokio::net::TcpStream::connect(addr)).await.unwrap();
        RawClient { socket, decoder: Default::default(), frames: Default::default() }
    }

    async fn send(&mut self, text: &str) {
        self.socket.write_all(text.as_bytes()).await.unwrap();
    }

    /// The next frame whose id, with the source alias masked off, is `id`.
    async fn expect(&mut self, id: u32) -> openlcb_can::CanFrame {
        use tokio::io::AsyncReadExt;
        bounded("an answer", async {
            loop {
                while let Some(frame) = self.frames.pop_front() {
                    if frame.raw_id() & 0x1FFF_F000 == id {
                        return frame;
                    }
                }
                let mut buf = [0u8; 4096];
                let n = self.socket.read(&mut buf).await.unwrap();
                assert!(n > 0, "the hub closed the connection");
                let frames = &mut self.frames;
                self.decoder.decode_all(&buf[..n], |frame| frames.extend(frame.ok()));
            }
        })
        .await
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_node_answers_alias_enquiry_verify_node_id_and_protocol_support_inquiry() {
    let hub = start_hub(HubOptions::default()).await;
    let addr = addr(&hub, Framing::GridConnect);
    let _node = join(&addr, Framing::GridConnect, id(0xF1), 2048).await;
    let mut raw = RawClient::connect(&addr).await;
    // Announce alias 0xAAA for 05.01.01.01.22.99 (AMD), so the node knows who asks.
    raw.send(":X10701AAAN050101012299;").await;

    // AME for its Node ID: AMD with its Node ID.
    raw.send(":X10702AAAN0501010122F1;\n").await;
    let amd = raw.expect(0x1070_1000).await;
    assert_eq!(amd.payload(), id(0xF1).to_bytes());
    let alias = amd.raw_id() & 0xFFF;

    // Global Verify Node ID: Verified Node ID.
    raw.send(":X19490AAAN;").await;
    assert_eq!(raw.expect(0x1917_0000).await.payload(), id(0xF1).to_bytes());

    // Addressed Protocol Support Inquiry: the reply to alias 0xAAA with the Stream bit.
    raw.send(&format!(":X19828AAAN{alias:04X};")).await;
    let reply = raw.expect(0x1966_8000).await;
    assert_eq!(&reply.payload()[..2], &[0x0A, 0xAA]);
    assert_ne!(reply.payload()[2] & 0x20, 0, "no Stream bit in {reply:?}");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_window_whose_frames_exceed_the_output_buffer_still_flows() {
    // 65535 bytes are about 270 kB of GridConnect text, more than the driver frames at once.
    let hub = start_hub(HubOptions::default()).await;
    let addr = addr(&hub, Framing::GridConnect);
    for (n, early_proceed) in [false, true].into_iter().enumerate() {
        let mut options = NodeOptions::new(id(0xE0 + n as u8));
        options.node.stream.max_window = 65535;
        options.node.stream.early_proceed = early_proceed;
        let mut receiver = bounded("joining", Node::connect(&addr, Framing::GridConnect, options)).await.unwrap();
        let sender = join(&addr, Framing::GridConnect, id(0xD0 + n as u8), 65535).await;
        let payload = data(3 * 65535 + 1, 9);
        assert!(transfer(&sender, &mut receiver, &payload, 65535).await == payload, "early Proceed {early_proceed}");
    }
}
