//! Faulty and unusual hubs on 127.0.0.1: a hub that stops reading, one that closes at once,
//! and a relay with the socket options of OpenMRN's `hub`. Every wait is bounded; every
//! loop stops by itself.

use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::Duration;

use bytes::BytesMut;
use openlcb_stream::{Message, Mti, NodeId, OpenOptions};
use openlcb_tcp::{CaptureTime, Decoder, LinkPrefix, TcpFrame};
use openlcb_tokio::{Error, Framing, Join, Node, NodeOptions};
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::{TcpListener, TcpStream};

mod common;
use common::{LIMIT, bounded};

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
    let node = bounded("joining", Node::connect(&addr, Framing::Tcp, options)).await.unwrap();
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
    let outcome = bounded("connecting", Node::connect(&addr, Framing::GridConnect, NodeOptions::new(id(0x12)))).await;
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
        bounded("joining", Node::connect(&addr, Framing::GridConnect, NodeOptions::new(receiver_id))).await.unwrap();
    let sender =
        bounded("joining", Node::connect(&addr, Framing::GridConnect, NodeOptions::new(sender_id))).await.unwrap();
    // The cause of the stall through OpenMRN's hub: segments larger than the ~16 KB window
    // such a hub advertises. Every node must keep its segments below it.
    let mss = bounded("the relay", relay).await.unwrap();
    assert!(mss.iter().all(|&m| m <= 8192), "segment sizes {mss:?} exceed a small hub's window");

    transfer(&sender, &mut receiver, 1 << 20, 65535).await;
}

// ----- the hub and its bridge -----

use openlcb_tokio::{Hub, HubEvent, HubOptions};

async fn start_hub(options: HubOptions) -> Hub {
    bounded("binding the hub", Hub::bind("127.0.0.1:0", Some("127.0.0.1:0"), options)).await.unwrap()
}

/// Moves `len` bytes from `sender` to `receiver` with `window` and checks they arrived intact.
async fn transfer(sender: &Node, receiver: &mut Node, len: usize, window: u16) {
    let destination = receiver.node_id();
    let payload = data(len);
    let send = async {
        let mut stream = sender.open(OpenOptions::new(destination, window)).await?;
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
    let (sent, got) = bounded("a transfer", async { tokio::try_join!(send, receive) }).await.unwrap();
    assert_eq!(sent, payload.len() as u64);
    assert!(got == payload, "the data arrived changed");
}

/// Reads GridConnect frames from a raw hub client until one starts with `last` (bounded).
async fn frames_until(socket: &mut TcpStream, last: &str) -> Vec<String> {
    let mut text = String::new();
    let mut buf = vec![0u8; 4096];
    bounded("the frames", async {
        loop {
            let frames: Vec<String> = text.split_whitespace().map(str::to_owned).collect();
            if frames.iter().any(|f| f.starts_with(last)) {
                return frames;
            }
            let n = socket.read(&mut buf).await.unwrap();
            assert!(n > 0, "the hub closed; got {text}");
            text.push_str(&String::from_utf8_lossy(&buf[..n]));
        }
    })
    .await
}

/// A frame's identifier without its source alias, and its data, as GridConnect text.
fn kind_and_data(frame: &str) -> (String, String) {
    let (id, data) = frame.trim_start_matches(":X").trim_end_matches(';').split_once('N').unwrap();
    (id[..id.len() - 3].to_owned(), data.to_owned())
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_node_logs_in_with_four_cids_rid_and_amd_and_nothing_between() {
    let hub = start_hub(HubOptions::default()).await;
    let mut observer = TcpStream::connect(hub.local_addr()).await.unwrap();
    until_clients(&hub, 1).await;
    let me = id(0x30);
    let _node =
        bounded("joining", Node::connect(&hub.local_addr().to_string(), Framing::GridConnect, NodeOptions::new(me)))
            .await
            .unwrap();
    let frames = frames_until(&mut observer, ":X19490").await;
    let kinds: Vec<(String, String)> = frames.iter().map(|f| kind_and_data(f)).collect();
    let own = "050101012230".to_owned();
    let prefixes: Vec<&str> = kinds.iter().map(|(k, _)| &k[..2]).take(4).collect();
    assert_eq!(prefixes, ["17", "16", "15", "14"], "four CIDs first: {frames:?}");
    assert_eq!(
        kinds[4..],
        [
            ("10700".to_owned(), String::new()),
            ("10701".to_owned(), own.clone()),
            ("19100".to_owned(), own.clone()),
            ("19490".to_owned(), own)
        ],
        "RID, AMD (CFT §6.2.1), Initialization Complete, then a Verify Node ID naming itself: {frames:?}"
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_running_node_reports_a_claim_of_its_node_id_and_keeps_running() {
    let hub = start_hub(HubOptions::default()).await;
    let me = id(0x31);
    let _node =
        bounded("joining", Node::connect(&hub.local_addr().to_string(), Framing::GridConnect, NodeOptions::new(me)))
            .await
            .unwrap();
    let mut checker = TcpStream::connect(hub.local_addr()).await.unwrap();
    until_clients(&hub, 2).await;
    // OlcbChecker's me50_dup: a Verified Node ID carrying the node's own ID from its alias.
    checker.write_all(b":X19170ABCN050101012231;\n").await.unwrap();
    let frames = frames_until(&mut checker, ":X195B4").await;
    let report = frames.last().unwrap();
    assert_eq!(
        kind_and_data(report),
        ("195B4".to_owned(), "0101000000000201".to_owned()),
        "Duplicate Node ID Detected"
    );
    // It keeps running: it answers a global Verify Node ID.
    checker.write_all(b":X19490ABCN;\n").await.unwrap();
    let frames = frames_until(&mut checker, ":X19170").await;
    assert_eq!(kind_and_data(frames.last().unwrap()), ("19170".to_owned(), "050101012231".to_owned()));
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_second_node_with_a_taken_node_id_refuses_to_join_and_the_first_keeps_running() {
    let hub = start_hub(HubOptions::default()).await;
    let addr = hub.local_addr().to_string();
    let taken = id(0x20);
    // A newcomer window long enough for the first node's answer however loaded the machine.
    let join = |node| {
        let mut options = NodeOptions::new(node);
        options.can.newcomer_window = openlcb_stream::Duration::from_secs(1);
        Node::connect(&addr, Framing::GridConnect, options)
    };
    let mut first = bounded("joining", join(taken)).await.unwrap();
    let mut observer = TcpStream::connect(hub.local_addr()).await.unwrap();
    until_clients(&hub, 2).await;
    let second = bounded("joining again", join(taken)).await;
    assert!(matches!(second, Err(Error::DuplicateNodeId { .. })), "got {second:?}");
    // The newcomer said so and released its alias; the first node reported it too.
    let frames = frames_until(&mut observer, ":X10703").await;
    let newcomer = &frames.last().unwrap()[7..10];
    let from_newcomer: Vec<String> =
        frames.iter().filter(|f| &f[7..10] == newcomer).map(|f| kind_and_data(f).0).collect();
    assert_eq!(from_newcomer[from_newcomer.len() - 2..], ["195B4", "10703"], "the event, then AMR: {frames:?}");
    let reports = frames.iter().filter(|f| f.starts_with(":X195B4") && f.ends_with("N0101000000000201;")).count();
    assert_eq!(reports, 2, "both nodes report it: {frames:?}");
    let sender = bounded("joining", join(id(0x21))).await.unwrap();
    transfer(&sender, &mut first, 10_000, 2048).await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_node_that_joins_at_login_talks_at_once_and_leaves_when_its_node_id_is_claimed() {
    let hub = start_hub(HubOptions::default()).await;
    let addr = hub.local_addr().to_string();
    let taken = id(0x22);
    let mut first =
        bounded("joining", Node::connect(&addr, Framing::GridConnect, NodeOptions::new(taken))).await.unwrap();
    let mut options = NodeOptions::new(taken);
    // The first node's answer comes long before the window ends, however loaded the machine:
    // a connect that waited for the window would fail.
    options.can.newcomer_window = openlcb_stream::Duration::from_secs(1);
    options.join = Join::AtLogin;
    let mut second = bounded("joining at login", Node::connect(&addr, Framing::GridConnect, options))
        .await
        .expect("a node that joins at login is connected before anyone could claim its Node ID");
    // The claim ends it within the window all the same.
    let error = bounded("the duplicate found", second.closed()).await;
    assert!(matches!(error, Error::DuplicateNodeId { .. }), "got {error:?}");
    let sender =
        bounded("joining", Node::connect(&addr, Framing::GridConnect, NodeOptions::new(id(0x23)))).await.unwrap();
    transfer(&sender, &mut first, 10_000, 2048).await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_node_that_closes_releases_its_alias() {
    let hub = start_hub(HubOptions::default()).await;
    let mut observer = TcpStream::connect(hub.local_addr()).await.unwrap();
    until_clients(&hub, 1).await;
    let node = bounded(
        "joining",
        Node::connect(&hub.local_addr().to_string(), Framing::GridConnect, NodeOptions::new(id(0x32))),
    )
    .await
    .unwrap();
    let login = frames_until(&mut observer, ":X10701").await;
    let alias = &login.last().unwrap()[7..10];
    node.close().await;
    let frames = frames_until(&mut observer, ":X10703").await;
    assert_eq!(frames.last().unwrap(), &format!(":X10703{alias}N050101012232;"), "AMR with its Node ID");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_hub_never_speaks_for_a_client_that_left() {
    let hub = start_hub(HubOptions::default()).await;
    let mut observer = TcpStream::connect(hub.local_addr()).await.unwrap();
    let mut leaver = TcpStream::connect(hub.local_addr()).await.unwrap();
    until_clients(&hub, 2).await;
    leaver.write_all(b":X10701342N050101012201;\n").await.unwrap();
    assert_eq!(frames_until(&mut observer, ":X10701").await, [":X10701342N050101012201;"]);
    drop(leaver);
    // Nothing comes: no AMR for the departed client's alias (a GridConnect hub is a wire).
    let mut buf = [0u8; 256];
    let read = tokio::time::timeout(Duration::from_millis(800), observer.read(&mut buf)).await;
    assert!(
        read.is_err(),
        "the hub sent {:?}",
        read.map(|n| String::from_utf8_lossy(&buf[..n.unwrap_or(0)]).into_owned())
    );
}

/// Waits (bounded in rounds) until the hub has `n` clients.
async fn until_clients(hub: &Hub, n: usize) {
    for _ in 0..500 {
        if hub.stats().clients_connected == n {
            return;
        }
        tokio::time::sleep(Duration::from_millis(10)).await;
    }
    panic!("the hub never got to {n} clients: {:?}", hub.stats());
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_node_id_that_left_the_gridconnect_side_can_join_over_openlcb_tcp() {
    let mut options = HubOptions::default();
    options.trace = true;
    let mut hub = start_hub(options).await;
    let gridconnect = hub.local_addr().to_string();
    let tcp = hub.tcp_local_addr().unwrap().to_string();
    let roaming = id(0x22);
    let sender = bounded("joining", Node::connect(&gridconnect, Framing::GridConnect, NodeOptions::new(id(0x23))))
        .await
        .unwrap();
    let mut was_here =
        bounded("joining", Node::connect(&gridconnect, Framing::GridConnect, NodeOptions::new(roaming))).await.unwrap();
    transfer(&sender, &mut was_here, 1000, 2048).await;
    // It leaves without a word (no AMR), like a program that was killed.
    was_here.abort();
    bounded("the hub noticing", async {
        while !matches!(hub.next_event().await, Some(HubEvent::InputClosed { .. }) | None) {}
    })
    .await;
    let mut back = bounded("joining over OpenLCB-TCP", Node::connect(&tcp, Framing::Tcp, NodeOptions::new(roaming)))
        .await
        .unwrap();
    // The gateway gives it a CAN alias (a proxy) once it has forgotten the old one.
    bounded("a proxy alias for the node", async {
        loop {
            match hub.next_event().await {
                Some(HubEvent::Frame { text, .. }) if text.contains("ProxyPermitted") => break,
                Some(_) => {}
                None => panic!("the hub stopped"),
            }
        }
    })
    .await;
    transfer(&sender, &mut back, 10_000, 2048).await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_node_id_that_left_the_openlcb_tcp_side_can_join_over_gridconnect() {
    let mut options = HubOptions::default();
    options.trace = true;
    let mut hub = start_hub(options).await;
    let gridconnect = hub.local_addr().to_string();
    let tcp = hub.tcp_local_addr().unwrap().to_string();
    let roaming = id(0x24);
    let sender = bounded("joining", Node::connect(&tcp, Framing::Tcp, NodeOptions::new(id(0x25)))).await.unwrap();
    let mut was_here = bounded("joining", Node::connect(&tcp, Framing::Tcp, NodeOptions::new(roaming))).await.unwrap();
    // On OpenLCB-TCP a node has joined once its Initialization Complete is written, which can
    // be before the hub has taken its connection: a request the sender (whose connection the
    // hub serves already) sent then would reach every client but it. A peer that learns of
    // the node from its Initialization Complete never meets that; this sender knows it
    // beforehand, so it waits for the hub.
    until_clients(&hub, 2).await;
    // The gateway gives every OpenLCB-TCP node a proxy alias on the CAN side.
    transfer(&sender, &mut was_here, 1000, 2048).await;
    // It leaves without a word, like a program that was killed.
    was_here.abort();
    bounded("the hub noticing", async {
        while !matches!(hub.next_event().await, Some(HubEvent::InputClosed { .. }) | None) {}
    })
    .await;
    // The gateway released the CAN alias it held for the node: the Node ID is free there.
    let mut back = bounded(
        "joining over GridConnect",
        Node::connect(&gridconnect, Framing::GridConnect, NodeOptions::new(roaming)),
    )
    .await
    .unwrap();
    // Through the gateway, which must know the node as a CAN node now.
    transfer(&sender, &mut back, 10_000, 2048).await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_hub_refuses_a_client_over_its_cap_and_says_so() {
    let mut options = HubOptions::default();
    options.max_clients = 2;
    let mut hub = start_hub(options).await;
    let addr = hub.local_addr();
    let _a = TcpStream::connect(addr).await.unwrap();
    let _b = TcpStream::connect(addr).await.unwrap();
    until_clients(&hub, 2).await;
    let mut third = TcpStream::connect(addr).await.unwrap();
    let mut said = String::new();
    bounded("the refusal", third.read_to_string(&mut said)).await.unwrap();
    assert!(said.contains("hub full"), "the refused client was told {said:?}");
    let refused = bounded("the event", async {
        loop {
            if let Some(HubEvent::Refused { clients, .. }) = hub.next_event().await {
                return clients;
            }
        }
    })
    .await;
    assert_eq!(refused, 2);
    assert_eq!(hub.stats().clients_refused, 1);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn clients_that_close_without_a_byte_free_their_slots() {
    let mut options = HubOptions::default();
    options.max_clients = 3;
    let hub = start_hub(options).await;
    let addr = hub.local_addr();
    // Twice the cap connect and close in silence, on a quiet hub (nothing is relayed to them).
    for _ in 0..6 {
        drop(TcpStream::connect(addr).await.unwrap());
        until_clients(&hub, 0).await;
    }
    let mut listener = TcpStream::connect(addr).await.unwrap();
    let mut talker = TcpStream::connect(addr).await.unwrap();
    until_clients(&hub, 2).await;
    talker.write_all(b":X19170456N0501010122AA;\n").await.unwrap();
    let mut got = vec![0u8; 64];
    let n = bounded("the frame", listener.read(&mut got)).await.unwrap();
    assert!(String::from_utf8_lossy(&got[..n]).contains(":X19170456N0501010122AA;"), "got {:?}", &got[..n]);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_client_trickling_a_frame_that_never_ends_is_closed() {
    let mut options = HubOptions::default();
    options.silent_timeout = Some(Duration::from_millis(300));
    let hub = start_hub(options).await;
    let mut trickler = TcpStream::connect(hub.local_addr()).await.unwrap();
    // One byte of a frame with no end every 50 ms, for at most ten times the timeout.
    let mut closed = false;
    for byte in b":X19170456N".iter().chain(b"0".repeat(54).iter()).take(60) {
        if trickler.write_all(&[*byte]).await.is_err() {
            closed = true;
            break;
        }
        let mut buf = [0u8; 16];
        if let Ok(read) = tokio::time::timeout(Duration::from_millis(50), trickler.read(&mut buf)).await {
            closed = matches!(read, Ok(0) | Err(_));
            if closed {
                break;
            }
        }
    }
    assert!(closed, "the trickling client was never closed: {:?}", hub.stats());
    until_clients(&hub, 0).await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn garbage_is_reported_in_aggregate_not_per_piece() {
    let mut hub = start_hub(HubOptions::default()).await;
    let mut noisy = TcpStream::connect(hub.local_addr()).await.unwrap();
    let garbage = ":Xzz;\n".repeat(1000);
    noisy.write_all(garbage.as_bytes()).await.unwrap();
    drop(noisy);
    let (mut reports, mut counted) = (0, 0);
    bounded("the reports", async {
        while let Some(event) = hub.next_event().await {
            match event {
                HubEvent::Garbage { count, .. } => {
                    reports += 1;
                    counted += count;
                }
                HubEvent::InputClosed { .. } => break,
                _ => {}
            }
        }
    })
    .await;
    assert_eq!(counted, hub.stats().decode_errors, "every piece is counted");
    assert!(counted >= 1000, "counted {counted}");
    assert!(reports <= 2, "{reports} reports for {counted} pieces");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_client_that_never_speaks_is_closed() {
    let mut options = HubOptions::default();
    options.silent_timeout = Some(Duration::from_millis(200));
    let hub = start_hub(options).await;
    let mut silent = TcpStream::connect(hub.local_addr()).await.unwrap();
    let mut buf = [0u8; 16];
    let n = bounded("the close", silent.read(&mut buf)).await.unwrap();
    assert_eq!(n, 0, "closed by the hub");
    until_clients(&hub, 0).await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn clients_that_never_read_leave_no_queued_bytes_behind() {
    let mut options = HubOptions::default();
    options.max_queued_bytes = 64 * 1024;
    options.drain_timeout = Duration::from_millis(300);
    let hub = start_hub(options).await;
    let addr = hub.local_addr();
    let mut idle = Vec::new();
    for _ in 0..5 {
        let socket = TcpStream::connect(addr).await.unwrap();
        socket2::SockRef::from(&socket).set_recv_buffer_size(4096).unwrap();
        idle.push(socket);
    }
    let mut flooder = TcpStream::connect(addr).await.unwrap();
    until_clients(&hub, 6).await;
    let frame = b":X19170456N0501010122AA;\n".repeat(1000);
    for _ in 0..400 {
        if hub.stats().slow_clients == 5 {
            break;
        }
        bounded("flooding", flooder.write_all(&frame)).await.unwrap();
    }
    assert_eq!(hub.stats().slow_clients, 5, "{:?}", hub.stats());
    until_clients(&hub, 1).await;
    assert_eq!(hub.stats().queued_bytes, 0, "nothing is held for clients that are gone");
}

/// Reads GridConnect text from `socket` for `time`; returns the frames, as text.
async fn frames_for(socket: &mut TcpStream, time: Duration) -> Vec<String> {
    let mut text = String::new();
    let mut buf = vec![0u8; 65536];
    let end = tokio::time::Instant::now() + time;
    while let Ok(Ok(n @ 1..)) = tokio::time::timeout_at(end, socket.read(&mut buf)).await {
        text.push_str(&String::from_utf8_lossy(&buf[..n]));
    }
    text.split(';').filter_map(|f| f.trim().strip_prefix(":X")).map(str::to_string).collect()
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_burst_of_datagrams_from_many_nodes_gets_one_answer_each() {
    let listener = TcpListener::bind("127.0.0.1:0").await.unwrap();
    let addr = listener.local_addr().unwrap().to_string();
    let node =
        tokio::spawn(async move { Node::connect(&addr, Framing::GridConnect, NodeOptions::new(id(0x30))).await });
    let (mut socket, _) = listener.accept().await.unwrap();
    // The node's login; its alias is in its AMD (`10701AAA`).
    let login = frames_for(&mut socket, Duration::from_millis(900)).await;
    let amd = login.iter().find(|f| f.starts_with("10701")).expect("an AMD");
    let alias = &amd[5..8];
    let node = bounded("joining", node).await.unwrap().unwrap();
    // 60 nodes each send one two-frame datagram, all at once: the link has 4 reassembly
    // slots, so most are refused for now (0x2020) by the link itself.
    let senders: Vec<u16> = (0..60).map(|i| 0x600 + i).collect();
    let mut burst = String::new();
    for (kind, data) in [("1B", "2040000000000040"), ("1D", "FD")] {
        for s in &senders {
            burst.push_str(&format!(":X{kind}{alias}{s:03X}N{data};\n"));
        }
    }
    socket.write_all(burst.as_bytes()).await.unwrap();
    let answers = frames_for(&mut socket, Duration::from_millis(1500)).await;
    for s in &senders {
        let to_it = |f: &&String| {
            (f.starts_with("19A28") || f.starts_with("19A48")) && f.get(9..13) == Some(&format!("{s:04X}")[..])
        };
        assert_eq!(answers.iter().filter(to_it).count(), 1, "answers to {s:03X} in {answers:?}");
    }
    drop(node);
}

/// A GridConnect client that only listens, and slowly: a 4 KiB receive buffer, 2 KiB taken
/// every 2 ms. Counts the frames it gets (`;` ends each) until the hub closes it.
async fn slow_listener(addr: std::net::SocketAddr, frames: Arc<AtomicU64>) -> &'static str {
    let socket = tokio::net::TcpSocket::new_v4().unwrap();
    socket.set_recv_buffer_size(4096).unwrap();
    let mut socket = socket.connect(addr).await.unwrap();
    let mut buf = vec![0u8; 2048];
    loop {
        match socket.read(&mut buf).await {
            Ok(0) => return "the hub closed the connection",
            Err(_) => return "the connection failed",
            Ok(n) => {
                let ends = buf[..n].iter().filter(|&&b| b == b';').count();
                frames.fetch_add(ends as u64, Ordering::Relaxed);
            }
        }
        tokio::time::sleep(Duration::from_millis(2)).await;
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_bulk_transfer_through_the_hub_costs_a_slow_listener_nothing() {
    let mut options = HubOptions::default();
    options.max_queued_bytes = 32 * 1024;
    options.silent_timeout = None;
    // GridConnect only: every frame relayed is one a client sent, and the listener gets all.
    let hub = bounded("binding the hub", Hub::bind("127.0.0.1:0", None, options)).await.unwrap();
    let heard = Arc::new(AtomicU64::new(0));
    let listener = tokio::spawn(slow_listener(hub.local_addr(), heard.clone()));
    until_clients(&hub, 1).await;
    let addr = hub.local_addr().to_string();
    let join = |node| Node::connect(&addr, Framing::GridConnect, NodeOptions::new(node));
    let sender = bounded("joining", join(id(0x40))).await.unwrap();
    let mut receiver = bounded("joining", join(id(0x41))).await.unwrap();
    // About 1.1 MB of GridConnect text for the listener: 35 times its queue.
    transfer(&sender, &mut receiver, 256 * 1024, 2048).await;
    // Once both have left (each with its AMR), nothing more is sent: the count is final.
    sender.close().await;
    receiver.close().await;
    until_clients(&hub, 1).await;
    let sent = hub.stats().frames;
    bounded("the listener hearing every frame", async {
        while heard.load(Ordering::Relaxed) < sent {
            assert!(!listener.is_finished(), "the listener lost its connection: {:?}", hub.stats());
            tokio::time::sleep(Duration::from_millis(10)).await;
        }
    })
    .await;
    assert_eq!(heard.load(Ordering::Relaxed), sent, "every frame, once");
    assert_eq!(hub.stats().slow_clients, 0, "{:?}", hub.stats());
    assert!(hub.stats().senders_paused > 0, "the listener never held the sender up: {:?}", hub.stats());
    listener.abort();
}

/// Frames sent by each of `senders` GridConnect clients: a PCER whose event ID is the sender
/// and the frame's number.
const NUMBERED_FRAMES: u32 = 3000;

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_slow_listener_gets_every_senders_frames_in_the_order_they_were_sent() {
    let mut options = HubOptions::default();
    options.silent_timeout = None;
    let hub = bounded("binding the hub", Hub::bind("127.0.0.1:0", None, options)).await.unwrap();
    // A small receive buffer, read in small pieces with pauses: the hub's writes to it are
    // partial or refused, and the rest waits in its queue.
    let socket = tokio::net::TcpSocket::new_v4().unwrap();
    socket.set_recv_buffer_size(4096).unwrap();
    let mut listener = socket.connect(hub.local_addr()).await.unwrap();
    until_clients(&hub, 1).await;
    let senders = 3u32;
    let mut sending = tokio::task::JoinSet::new();
    for sender in 0..senders {
        let addr = hub.local_addr();
        sending.spawn(async move {
            let mut socket = TcpStream::connect(addr).await.unwrap();
            for n in 0..NUMBERED_FRAMES {
                // One write per frame, as boards do.
                let frame = format!(":X195B4{:03X}N{:08X}{n:08X};", 0x100 + sender, sender);
                socket.write_all(frame.as_bytes()).await.unwrap();
            }
            socket
        });
    }
    let mut text = Vec::new();
    let mut buf = vec![0u8; 512];
    let total = (senders * NUMBERED_FRAMES) as usize;
    bounded("the listener hearing every frame", async {
        while text.iter().filter(|&&b| b == b';').count() < total {
            let n = listener.read(&mut buf).await.unwrap();
            assert!(n > 0, "the hub closed the listener: {:?}", hub.stats());
            text.extend_from_slice(&buf[..n]);
            tokio::time::sleep(Duration::from_micros(200)).await;
        }
    })
    .await;
    let mut next = vec![0u32; senders as usize];
    for frame in String::from_utf8(text).unwrap().split_whitespace() {
        let data = frame.trim_end_matches(';').split_once('N').unwrap().1;
        let sender = u32::from_str_radix(&data[..8], 16).unwrap() as usize;
        let n = u32::from_str_radix(&data[8..], 16).unwrap();
        assert_eq!(n, next[sender], "sender {sender}: frame {n} came where frame {} was due", next[sender]);
        next[sender] += 1;
    }
    assert_eq!(next, vec![NUMBERED_FRAMES; senders as usize], "every frame, once");
    assert_eq!(hub.stats().slow_clients, 0, "{:?}", hub.stats());
    while sending.join_next().await.is_some() {}
}

/// Options for the slot tests: `max_clients`, and a minimum rate of `min_frames` per `window`.
fn slot_options(max_clients: usize, min_frames: u16, window: Duration) -> HubOptions {
    let mut options = HubOptions::default();
    options.max_clients = max_clients;
    options.slot_min_frames = min_frames;
    options.slot_window = Some(window);
    options
}

/// Waits (bounded) for the hub's next [`HubEvent::Evicted`]: the client and its frames.
async fn next_eviction(hub: &mut Hub) -> (u64, usize) {
    bounded("an eviction", async {
        loop {
            match hub.next_event().await {
                Some(HubEvent::Evicted { client, frames, .. }) => return (client, frames),
                Some(_) => {}
                None => panic!("the hub stopped"),
            }
        }
    })
    .await
}

const FRAME: &[u8] = b":X19170456N0501010122AA;\n";

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn clients_sending_a_frame_now_and_then_cannot_hold_every_slot() {
    let window = Duration::from_millis(400);
    let mut hub = start_hub(slot_options(3, 3, window)).await;
    let addr = hub.local_addr();
    let mut holders = Vec::new();
    for _ in 0..3 {
        holders.push(TcpStream::connect(addr).await.unwrap());
    }
    until_clients(&hub, 3).await;
    // Every slot held by a client that completes a frame now and then: two per window, one
    // short of the rate, for four windows.
    for _ in 0..8 {
        for holder in &mut holders {
            holder.write_all(FRAME).await.unwrap();
        }
        tokio::time::sleep(window / 2).await;
    }
    let mut newcomer = TcpStream::connect(addr).await.unwrap();
    let (_, frames) = next_eviction(&mut hub).await;
    assert!(frames < 3, "evicted with {frames} frames in the window");
    until_clients(&hub, 3).await;
    // The newcomer is in: it hears the holders that stayed.
    for holder in &mut holders {
        let _ = holder.write_all(FRAME).await;
    }
    let heard = frames_until(&mut newcomer, ":X19170").await;
    assert!(!heard.iter().any(|f| f.contains("full")), "the newcomer was refused: {heard:?}");
    assert_eq!(hub.stats().clients_evicted, 1, "{:?}", hub.stats());
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn an_idle_client_keeps_its_slot_until_the_hub_is_full() {
    let window = Duration::from_millis(300);
    let mut hub = start_hub(slot_options(3, 2, window)).await;
    let addr = hub.local_addr();
    // Client 1 logs in with one frame and then only listens; client 2 keeps talking.
    let mut idle = TcpStream::connect(addr).await.unwrap();
    idle.write_all(FRAME).await.unwrap();
    let mut talker = TcpStream::connect(addr).await.unwrap();
    until_clients(&hub, 2).await;
    let talking = tokio::spawn(async move {
        for _ in 0..400 {
            if talker.write_all(FRAME).await.is_err() {
                return;
            }
            tokio::time::sleep(Duration::from_millis(25)).await;
        }
    });
    // Many windows go by, and one more client takes the last free slot: the idle client is
    // still there and hears the talker.
    tokio::time::sleep(window * 4).await;
    let _third = TcpStream::connect(addr).await.unwrap();
    until_clients(&hub, 3).await;
    assert!(!frames_until(&mut idle, ":X19170").await.is_empty());
    assert_eq!(hub.stats().clients_evicted, 0, "{:?}", hub.stats());
    // The hub is full: a fourth client takes the idle client's slot, not the talker's nor
    // that of the client that has only just come.
    let _fourth = TcpStream::connect(addr).await.unwrap();
    assert_eq!(next_eviction(&mut hub).await, (1, 0));
    until_clients(&hub, 3).await;
    let mut rest = Vec::new();
    let closed = bounded("the evicted client's close", idle.read_to_end(&mut rest)).await;
    assert!(closed.is_ok(), "{closed:?}");
    talking.abort();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_half_closed_client_is_removed_and_gets_no_more_frames() {
    let mut hub = start_hub(HubOptions::default()).await;
    let addr = hub.local_addr();
    let mut talker = TcpStream::connect(addr).await.unwrap();
    let mut half = TcpStream::connect(addr).await.unwrap();
    until_clients(&hub, 2).await;
    half.write_all(FRAME).await.unwrap();
    assert_eq!(frames_until(&mut talker, ":X19170").await.len(), 1);
    half.shutdown().await.unwrap();
    bounded("the hub noticing", async {
        while !matches!(hub.next_event().await, Some(HubEvent::InputClosed { .. }) | None) {}
    })
    .await;
    until_clients(&hub, 1).await;
    // What the talker sends now does not reach it: the hub closed its connection.
    talker.write_all(FRAME).await.unwrap();
    let mut rest = Vec::new();
    bounded("the close", half.read_to_end(&mut rest)).await.unwrap();
    assert!(rest.is_empty(), "a half-closed client got {:?}", String::from_utf8_lossy(&rest));
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn frames_read_from_a_client_whose_connection_broke_still_reach_a_slow_listener() {
    let mut options = HubOptions::default();
    options.max_queued_bytes = 4 * 1024;
    options.silent_timeout = None;
    let hub = bounded("binding the hub", Hub::bind("127.0.0.1:0", None, options)).await.unwrap();
    let addr = hub.local_addr();
    // The listener reads nothing for now: the hub holds the sender's frames up for it.
    let socket = tokio::net::TcpSocket::new_v4().unwrap();
    socket.set_recv_buffer_size(4096).unwrap();
    let mut listener = bounded("connecting", socket.connect(addr)).await.unwrap();
    let socket = tokio::net::TcpSocket::new_v4().unwrap();
    socket.set_send_buffer_size(256 * 1024).unwrap();
    let mut sender = bounded("connecting", socket.connect(addr)).await.unwrap();
    until_clients(&hub, 2).await;
    // More than the listener's socket buffers and queue take, less than they and the sender's
    // send buffer and the hub's receive buffer take: all written, much of it held up.
    const SENT: usize = 8000;
    bounded("sending", sender.write_all(&FRAME.repeat(SENT))).await.unwrap();
    tokio::time::sleep(Duration::from_millis(200)).await;
    assert!(hub.stats().frames < SENT as u64, "the hub did not hold the sender up: {:?}", hub.stats());
    // The sender goes while its frames are held up; the listener's frames make the hub write
    // to the closed connection until that fails.
    drop(sender);
    for _ in 0..20 {
        listener.write_all(FRAME).await.unwrap();
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
    // Now the listener reads: every frame the hub read from the sender reaches it, once (what
    // the sender's own kernel still held when its socket was reset never left it).
    let mut heard = 0;
    let mut buf = vec![0u8; 16 * 1024];
    while let Ok(Ok(n @ 1..)) = tokio::time::timeout(Duration::from_secs(2), listener.read(&mut buf)).await {
        heard += buf[..n].iter().filter(|&&b| b == b';').count() as u64;
    }
    until_clients(&hub, 1).await;
    assert_eq!(heard, hub.stats().frames - 20, "{:?}", hub.stats());
    assert_eq!(hub.stats().slow_clients, 0, "{:?}", hub.stats());
}
