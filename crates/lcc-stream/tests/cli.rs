//! The built `lcc-stream` binary end to end: `hub`, `send`, `recv` and `demo` as separate
//! processes on 127.0.0.1 (ephemeral ports). Every wait is bounded; children are killed when
//! a test ends.

mod common;

use std::path::{Path, PathBuf};
use std::process::ExitStatus;

use common::{bounded, command, scratch, spawn};
use openlcb_stream::wire::ReplyCode;
use openlcb_stream::{AcceptPolicy, NodeId, OpenOptions};
use openlcb_tokio::{Framing, Hub, HubEvent, HubOptions, Node, NodeOptions};
use tokio::io::{AsyncBufReadExt, BufReader};
use tokio::process::{Child, ChildStderr, Command};

const RECEIVER: &str = "05.01.01.01.22.F1";

fn data(len: usize) -> Vec<u8> {
    (0..len).map(|i| (i as u32).wrapping_mul(2_654_435_761).rotate_right(11) as u8).collect()
}

/// Reads `child`'s stderr until a line contains `needle`; returns that line. The rest of
/// stderr is drained in the background so the child never blocks on it.
async fn wait_for_line(child: &mut Child, needle: &str) -> String {
    let stderr: ChildStderr = child.stderr.take().unwrap();
    let mut lines = BufReader::new(stderr).lines();
    let line = bounded(needle, async {
        while let Some(line) = lines.next_line().await.unwrap() {
            if line.contains(needle) {
                return line;
            }
        }
        panic!("stderr ended before a line with {needle:?}");
    })
    .await;
    tokio::spawn(async move { while let Ok(Some(_)) = lines.next_line().await {} });
    line
}

/// Waits for `child` to exit; returns its status, stdout and stderr.
async fn finish(child: Child) -> (ExitStatus, String, String) {
    let output = bounded("a child process", child.wait_with_output()).await.unwrap();
    let text = |bytes: Vec<u8>| String::from_utf8_lossy(&bytes).into_owned();
    (output.status, text(output.stdout), text(output.stderr))
}

/// The value of `key` in a one-line JSON object (parsed with serde_json), as text: a string's
/// contents, or a number or boolean as JSON writes it.
fn field(json: &str, key: &str) -> String {
    let object: serde_json::Value = serde_json::from_str(json.trim()).unwrap_or_else(|e| panic!("{e}: {json}"));
    match object.get(key) {
        Some(serde_json::Value::String(text)) => text.clone(),
        Some(value) => value.to_string(),
        None => panic!("no {key} in {json}"),
    }
}

/// Starts `lcc-stream hub` on ephemeral ports; returns it with its GridConnect and
/// OpenLCB-TCP addresses.
async fn start_hub_binary() -> (Child, String, String) {
    let mut hub = spawn(&["hub", "--listen", "127.0.0.1:0", "--tcp-listen", "127.0.0.1:0"]);
    let line = wait_for_line(&mut hub, "GridConnect on").await;
    // "lcc-stream hub: GridConnect on A, OpenLCB-TCP on B"
    let words: Vec<&str> = line.split_whitespace().collect();
    let gridconnect = words[4].trim_end_matches(',').to_string();
    let tcp = words[7].to_string();
    (hub, gridconnect, tcp)
}

/// `send` (speaking `from`) to `recv` (speaking `to`) through `lcc-stream hub`.
async fn send_file_through_the_hub_binary(from: &str, to: &str, window: &str, len: usize) {
    let dir = scratch(&format!("send-{from}-{to}-{window}-{len}"));
    let input = dir.join("input.bin");
    let output = dir.join("output.bin");
    let payload = data(len);
    std::fs::write(&input, &payload).unwrap();
    let (_hub, gridconnect, tcp) = start_hub_binary().await;
    let addr_of = |protocol: &str| if protocol == "tcp" { tcp.clone() } else { gridconnect.clone() };

    let out = output.to_str().unwrap();
    let recv_addr = addr_of(to);
    let mut recv = spawn(&["recv", "--connect", &recv_addr, "--protocol", to, "--once", "--json", "--out", out]);
    wait_for_line(&mut recv, "listening").await;
    let input_arg = input.to_str().unwrap();
    let send = spawn(&[
        "send",
        input_arg,
        "--to",
        RECEIVER,
        "--connect",
        &addr_of(from),
        "--protocol",
        from,
        "--window",
        window,
        "--json",
    ]);
    let (status, stdout, stderr) = finish(send).await;
    assert!(status.success(), "send failed: {status} {stderr}");
    assert_eq!(field(&stdout, "result"), "ok", "{stdout}");
    assert_eq!(field(&stdout, "bytes"), len.to_string());
    assert_eq!(field(&stdout, "window"), window);
    assert!(field(&stdout, "bytes_per_s").parse::<f64>().is_ok());
    assert!(field(&stdout, "elapsed_s").parse::<f64>().is_ok());

    let (status, stdout, _) = finish(recv).await;
    assert!(status.success(), "recv failed: {status} {stdout}");
    assert_eq!(field(&stdout, "result"), "ok", "{stdout}");
    assert_eq!(field(&stdout, "bytes"), len.to_string());
    assert!(std::fs::read(&output).unwrap() == payload, "the received file differs");
    assert!(!part(&output).exists());
    let _ = std::fs::remove_dir_all(dir);
}

fn part(path: &Path) -> PathBuf {
    let mut name = path.as_os_str().to_owned();
    name.push(".part");
    PathBuf::from(name)
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn send_and_recv_move_a_file_through_the_hub_over_gridconnect() {
    send_file_through_the_hub_binary("gridconnect", "gridconnect", "2048", 300_001).await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn send_and_recv_move_a_file_through_the_hub_over_openlcb_tcp() {
    send_file_through_the_hub_binary("tcp", "tcp", "65535", 1_000_000).await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_hub_bridges_an_openlcb_tcp_sender_to_a_gridconnect_receiver() {
    send_file_through_the_hub_binary("tcp", "gridconnect", "65535", 200_000).await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn an_empty_file_is_a_stream_of_zero_bytes() {
    send_file_through_the_hub_binary("gridconnect", "gridconnect", "65535", 0).await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_killed_receiver_makes_the_sender_exit_non_zero() {
    let dir = scratch("killed");
    let input = dir.join("input.bin");
    let output = dir.join("output.bin");
    std::fs::write(&input, data(8 * 1024 * 1024)).unwrap();
    let mut options = HubOptions::default();
    options.trace = true;
    let mut hub = Hub::bind("127.0.0.1:0", None, options).await.unwrap();
    let addr = hub.local_addr().to_string();

    let mut recv = spawn(&["recv", "--connect", &addr, "--once", "--out", output.to_str().unwrap()]);
    wait_for_line(&mut recv, "listening").await;
    let send = spawn(&[
        "send",
        input.to_str().unwrap(),
        "--to",
        RECEIVER,
        "--connect",
        &addr,
        "--window",
        "2048",
        "--timeout",
        "2",
    ]);
    // Kill the receiver once stream data (CAN frame type 7, `:X1F...`) is passing.
    bounded("stream data at the hub", async {
        loop {
            match hub.next_event().await {
                Some(HubEvent::Frame { text, .. }) if text.starts_with(":X1F") => break,
                Some(_) => {}
                None => panic!("the hub stopped"),
            }
        }
    })
    .await;
    recv.kill().await.unwrap();

    let (status, _, stderr) = finish(send).await;
    // The hub releases the killed receiver's alias (the sender hears it left: 7); through a
    // hub that does not, the sender's wait for credit runs out (5).
    assert!(matches!(status.code(), Some(5 | 7)), "{stderr}");
    assert!(stderr.contains("05.01.01.01.22.F1"), "{stderr}");
    assert!(!output.exists(), "a killed receiver left a file under the final name");
    let _ = std::fs::remove_dir_all(dir);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_terminated_stream_stays_part_and_recv_says_how_much_arrived() {
    let dir = scratch("terminated");
    let output = dir.join("output.bin");
    let hub = Hub::bind("127.0.0.1:0", None, HubOptions::default()).await.unwrap();
    let addr = hub.local_addr().to_string();
    let mut recv = spawn(&["recv", "--connect", &addr, "--once", "--json", "--out", output.to_str().unwrap()]);
    wait_for_line(&mut recv, "listening").await;

    let sender = bounded(
        "join",
        Node::connect(&addr, Framing::GridConnect, NodeOptions::new(NodeId::new(0x0501_0101_22A0).unwrap())),
    )
    .await
    .unwrap();
    let mut stream = bounded("open", sender.open(OpenOptions::new(RECEIVER.parse().unwrap(), 2048))).await.unwrap();
    bounded("write", stream.write_all(data(5000))).await.unwrap();
    stream.abort();

    let (status, stdout, _) = finish(recv).await;
    assert_eq!(status.code(), Some(7), "{stdout}");
    assert_eq!(field(&stdout, "result"), "terminated", "{stdout}");
    // The peer's code is printed with its meaning.
    assert!(field(&stdout, "error").contains("0x2000 (temporary error)"), "{stdout}");
    let arrived: u64 = field(&stdout, "bytes").parse().unwrap();
    assert!(arrived <= 5000);
    assert!(!output.exists(), "a terminated stream was renamed to the final name");
    assert_eq!(std::fs::metadata(part(&output)).unwrap().len(), arrived);
    let _ = std::fs::remove_dir_all(dir);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_rejected_stream_exits_4_with_the_meaning() {
    let dir = scratch("rejected");
    let input = dir.join("input.bin");
    std::fs::write(&input, data(100)).unwrap();
    let hub = Hub::bind("127.0.0.1:0", None, HubOptions::default()).await.unwrap();
    let addr = hub.local_addr().to_string();
    let mut options = NodeOptions::new(RECEIVER.parse().unwrap());
    options.node.stream.accept_policy = AcceptPolicy::RejectAll(ReplyCode::BUFFER_UNAVAILABLE);
    let _busy = bounded("join", Node::connect(&addr, Framing::GridConnect, options)).await.unwrap();

    let send = spawn(&["send", input.to_str().unwrap(), "--to", RECEIVER, "--connect", &addr]);
    let (status, _, stderr) = finish(send).await;
    assert_eq!(status.code(), Some(4), "{stderr}");
    assert!(stderr.contains("0x2020") && stderr.contains("buffer unavailable"), "{stderr}");
    let _ = std::fs::remove_dir_all(dir);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn an_unreachable_hub_exits_3() {
    let port = std::net::TcpListener::bind("127.0.0.1:0").unwrap().local_addr().unwrap().port();
    let addr = format!("127.0.0.1:{port}");
    let dir = scratch("unreachable");
    let input = dir.join("input.bin");
    std::fs::write(&input, data(10)).unwrap();
    let send = spawn(&["send", input.to_str().unwrap(), "--to", RECEIVER, "--connect", &addr, "--json"]);
    let (status, stdout, stderr) = finish(send).await;
    assert_eq!(status.code(), Some(3), "{stderr}");
    assert!(stderr.contains("cannot reach the hub") && stderr.contains(&addr), "{stderr}");
    assert!(stderr.contains("start a hub (`lcc-stream hub`)") && stderr.contains("LCC_HUB"), "{stderr}");
    assert_eq!(field(&stdout, "result"), "unreachable_hub");
    let recv = spawn(&["recv", "--connect", &addr]);
    assert_eq!(finish(recv).await.0.code(), Some(3));
    // The hub's address set once, in the environment.
    let mut nodes = command(&["nodes", "--json"]);
    nodes.env("LCC_HUB", &addr);
    let (status, _, stderr) = finish(nodes.spawn().unwrap()).await;
    assert_eq!(status.code(), Some(3), "{stderr}");
    assert!(stderr.contains(&addr), "LCC_HUB is where it went: {stderr}");
    // A serial port given beside it is taken instead, with no conflict.
    let mut serial = command(&["nodes", "--serial", "/dev/lcc-stream-no-such-port"]);
    serial.env("LCC_HUB", &addr);
    let (status, _, stderr) = finish(serial.spawn().unwrap()).await;
    assert!(status.code() != Some(2) && stderr.contains("lcc-stream-no-such-port"), "{status:?} {stderr}");
    let _ = std::fs::remove_dir_all(dir);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_hub_is_set_once_in_the_settings_file() {
    let port = std::net::TcpListener::bind("127.0.0.1:0").unwrap().local_addr().unwrap().port();
    let addr = format!("127.0.0.1:{port}");
    let dir = scratch("settings");
    let settings = dir.join("config.toml");
    std::fs::write(&settings, format!("# the layout's hub\nhub = \"{addr}\"\n")).unwrap();
    let mut nodes = command(&["nodes"]);
    nodes.env("LCC_STREAM_CONFIG", &settings).env_remove("LCC_HUB");
    let (status, _, stderr) = finish(nodes.spawn().unwrap()).await;
    assert_eq!(status.code(), Some(3), "{stderr}");
    assert!(stderr.contains(&addr), "the file's hub is where it went: {stderr}");
    // LCC_HUB wins over the file.
    let mut nodes = command(&["nodes"]);
    nodes.env("LCC_STREAM_CONFIG", &settings).env("LCC_HUB", "127.0.0.1:1");
    let (_, _, stderr) = finish(nodes.spawn().unwrap()).await;
    assert!(stderr.contains("127.0.0.1:1") && !stderr.contains(&addr), "{stderr}");
    // A file that cannot be used stops every command with words, exit 2.
    for (text, says) in [("hub = \"nowhere\"\n", "has no port"), ("hubb = \"x:1\"\n", "unknown field")] {
        std::fs::write(&settings, text).unwrap();
        let mut nodes = command(&["nodes"]);
        nodes.env("LCC_STREAM_CONFIG", &settings);
        let (status, _, stderr) = finish(nodes.spawn().unwrap()).await;
        assert_eq!(status.code(), Some(2), "{stderr}");
        assert!(stderr.contains("the settings file") && stderr.contains(says), "{stderr}");
    }
    let _ = std::fs::remove_dir_all(dir);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_full_hub_is_named_full() {
    let mut options = HubOptions::default();
    options.max_clients = 1;
    let hub = Hub::bind("127.0.0.1:0", None, options).await.unwrap();
    let addr = hub.local_addr().to_string();
    let _only_client = tokio::net::TcpStream::connect(&addr).await.unwrap();
    let (status, stdout, stderr) = finish(spawn(&["nodes", "--connect", &addr, "--json"])).await;
    assert_eq!(status.code(), Some(3), "{stderr}");
    assert!(stderr.contains("the hub refused this connection (hub full: 1 clients connected"), "{stderr}");
    assert!(!stderr.contains("does not speak"), "{stderr}");
    assert_eq!(field(&stdout, "result"), "unreachable_hub");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_demo_verifies_its_transfer() {
    for protocol in ["gridconnect", "tcp"] {
        let demo = spawn(&["demo", "--bytes", "200000", "--protocol", protocol]);
        let (status, stdout, stderr) = finish(demo).await;
        assert!(status.success(), "{stdout}{stderr}");
        assert!(stdout.contains("verified: every byte arrived"), "{stdout}");
        assert!(stdout.contains("moved 200000 bytes"), "{stdout}");
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_hub_that_goes_away_mid_transfer_makes_send_exit_6() {
    let dir = scratch("hub-gone");
    let input = dir.join("input.bin");
    std::fs::write(&input, data(8 * 1024 * 1024)).unwrap();
    let mut options = HubOptions::default();
    options.trace = true;
    let mut hub = Hub::bind("127.0.0.1:0", None, options).await.unwrap();
    let addr = hub.local_addr().to_string();
    let mut receiver =
        bounded("join", Node::connect(&addr, Framing::GridConnect, NodeOptions::new(RECEIVER.parse().unwrap())))
            .await
            .unwrap();
    // Reads whatever comes until the connection goes.
    tokio::spawn(async move {
        if let Ok(mut stream) = receiver.accept().await {
            while let Ok(Some(_)) = stream.read().await {}
        }
    });

    let send = spawn(&["send", input.to_str().unwrap(), "--to", RECEIVER, "--connect", &addr, "--window", "2048"]);
    bounded("stream data at the hub", async {
        loop {
            match hub.next_event().await {
                Some(HubEvent::Frame { text, .. }) if text.starts_with(":X1F") => break,
                Some(_) => {}
                None => panic!("the hub stopped"),
            }
        }
    })
    .await;
    drop(hub);

    let (status, _, stderr) = finish(send).await;
    assert_eq!(status.code(), Some(6), "{stderr}");
    assert!(stderr.contains("connection to the hub lost"), "{stderr}");
    let _ = std::fs::remove_dir_all(dir);
}

// ----- faults: files, signals, exit statuses -----

/// A scripted OpenLCB-TCP peer: sends hand-made messages, waits for a given MTI.
struct RawPeer {
    socket: tokio::net::TcpStream,
    decoder: openlcb_tcp::Decoder,
    me: NodeId,
    buf: Vec<u8>,
    held: Vec<u8>,
}

impl RawPeer {
    async fn connect(addr: &str, me: NodeId) -> RawPeer {
        let socket = bounded("connect", tokio::net::TcpStream::connect(addr)).await.unwrap();
        RawPeer { socket, decoder: openlcb_tcp::Decoder::default(), me, buf: vec![0; 4096], held: Vec::new() }
    }

    async fn send(&mut self, mti: openlcb_stream::Mti, to: NodeId, payload: &[u8]) {
        use tokio::io::AsyncWriteExt as _;
        let message = openlcb_stream::Message::addressed(mti, self.me, to, payload.to_vec());
        let prefix = openlcb_tcp::LinkPrefix { gateway: self.me, capture_time: openlcb_tcp::CaptureTime::wrapping(0) };
        let mut out = bytes::BytesMut::new();
        openlcb_tcp::TcpFrame::new(prefix, message.as_ref()).encode_to(&mut out).unwrap();
        self.socket.write_all(&out).await.unwrap();
    }

    /// The payload of the next message with `mti` addressed to this peer.
    async fn expect(&mut self, mti: openlcb_stream::Mti) -> Vec<u8> {
        use tokio::io::AsyncReadExt as _;
        bounded("a message", async {
            loop {
                let mut input = &self.held[..];
                let mut found = None;
                while let Some(frame) = self.decoder.decode(&mut input) {
                    let message = frame.unwrap().message;
                    if message.mti == mti && message.destination == Some(self.me) {
                        found = Some(message.payload.to_vec());
                        break;
                    }
                }
                let rest = input.to_vec();
                self.held = rest;
                if let Some(payload) = found {
                    return payload;
                }
                let n = self.socket.read(&mut self.buf).await.unwrap();
                assert!(n > 0, "the hub closed the connection");
                self.held.extend_from_slice(&self.buf[..n]);
            }
        })
        .await
    }

    /// Opens a stream to `to` (SID `sid`, window 2048); returns the DID.
    async fn open(&mut self, to: NodeId, sid: u8) -> Option<u8> {
        use openlcb_stream::Mti;
        self.send(Mti::STREAM_INITIATE_REQUEST, to, &[0x08, 0x00, 0x00, 0x00, sid]).await;
        let reply = self.expect(Mti::STREAM_INITIATE_REPLY).await;
        (reply[2] & 0x80 != 0).then(|| reply[5])
    }
}

fn peer_id(last: u8) -> NodeId {
    NodeId::from_bytes([0x05, 0x01, 0x01, 0x01, 0x22, last])
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_complete_stating_more_than_arrived_exits_7_and_keeps_the_part() {
    use openlcb_stream::Mti;
    let dir = scratch("short-complete");
    let output = dir.join("output.bin");
    let (_hub, _, tcp) = start_hub_binary().await;
    // --timeout 600: the mismatch must not wait for the idle timeout.
    let args = ["recv", "--connect", &tcp, "--protocol", "tcp", "--once", "--json", "--timeout", "600", "--out"];
    let mut recv = spawn(&[&args[..], &[output.to_str().unwrap()]].concat());
    wait_for_line(&mut recv, "listening").await;
    let mut peer = RawPeer::connect(&tcp, peer_id(0xB0)).await;
    let did = peer.open(RECEIVER.parse().unwrap(), 3).await.expect("accepted");
    peer.send(Mti::STREAM_DATA_SEND, RECEIVER.parse().unwrap(), &[did, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10]).await;
    peer.send(Mti::STREAM_DATA_COMPLETE, RECEIVER.parse().unwrap(), &[3, did, 0, 0, 0, 20]).await;
    let (status, stdout, _) = finish(recv).await;
    assert_eq!(status.code(), Some(7), "{stdout}");
    assert_eq!(field(&stdout, "bytes"), "10");
    assert!(field(&stdout, "error").contains("said it sent 20"), "{stdout}");
    assert_eq!(std::fs::read(part(&output)).unwrap(), [1, 2, 3, 4, 5, 6, 7, 8, 9, 10]);
    assert!(!output.exists());
    let _ = std::fs::remove_dir_all(dir);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn one_peer_cannot_take_every_recv_slot_and_empty_streams_leave_no_file() {
    let dir = scratch("slots");
    let (_hub, _, tcp) = start_hub_binary().await;
    let mut recv = spawn(&["recv", "--connect", &tcp, "--protocol", "tcp", "--out", dir.to_str().unwrap()]);
    wait_for_line(&mut recv, "listening").await;
    let receiver: NodeId = RECEIVER.parse().unwrap();
    let mut hog = RawPeer::connect(&tcp, peer_id(0xB1)).await;
    let mut opened = 0;
    for sid in 0..4 {
        opened += usize::from(hog.open(receiver, sid).await.is_some());
    }
    assert_eq!(opened, 2, "one peer got {opened} of the 4 slots");
    let mut other = RawPeer::connect(&tcp, peer_id(0xB2)).await;
    assert!(other.open(receiver, 0).await.is_some(), "another peer is refused");
    // The hog's streams bring no data: they end after the first-data wait, leaving no file.
    let tde = hog.expect(openlcb_stream::Mti::TERMINATE_DUE_TO_ERROR).await;
    assert_eq!(&tde[..2], &[0x20, 0x10]);
    let _ = hog.expect(openlcb_stream::Mti::TERMINATE_DUE_TO_ERROR).await;
    let files: Vec<_> = std::fs::read_dir(&dir).unwrap().collect();
    assert!(files.is_empty(), "streams without data left {files:?}");
    drop(recv);
    let _ = std::fs::remove_dir_all(dir);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn recv_never_overwrites_a_file_of_an_earlier_run() {
    let dir = scratch("no-overwrite");
    let sender_name = "stream-0501010122F0-0.bin";
    std::fs::write(dir.join(sender_name), b"earlier run").unwrap();
    std::fs::write(dir.join("stream-0501010122F0-1.bin.part"), b"earlier part").unwrap();
    let input = dir.join("input.bin");
    let payload = data(3000);
    std::fs::write(&input, &payload).unwrap();
    let (_hub, gridconnect, _) = start_hub_binary().await;
    let out = dir.join("out");
    std::fs::create_dir(&out).unwrap();
    std::fs::rename(dir.join(sender_name), out.join(sender_name)).unwrap();
    std::fs::rename(dir.join("stream-0501010122F0-1.bin.part"), out.join("stream-0501010122F0-1.bin.part")).unwrap();
    let mut recv = spawn(&["recv", "--connect", &gridconnect, "--once", "--out", out.to_str().unwrap()]);
    wait_for_line(&mut recv, "listening").await;
    let sender = ["--node-id", "05.01.01.01.22.F0"];
    let send =
        spawn(&[&["send", input.to_str().unwrap(), "--to", RECEIVER, "--connect", &gridconnect][..], &sender].concat());
    assert!(finish(send).await.0.success());
    let (status, stdout, stderr) = finish(recv).await;
    assert!(status.success(), "{stdout}{stderr}");
    assert_eq!(std::fs::read(out.join(sender_name)).unwrap(), b"earlier run");
    assert_eq!(std::fs::read(out.join("stream-0501010122F0-1.bin.part")).unwrap(), b"earlier part");
    assert_eq!(std::fs::read(out.join("stream-0501010122F0-2.bin")).unwrap(), payload, "{stdout}");
    let _ = std::fs::remove_dir_all(dir);
}

/// Sends SIGTERM to a child.
async fn terminate(child: &Child) {
    let pid = child.id().unwrap().to_string();
    let status = Command::new("kill").args(["-TERM", &pid]).status().await.unwrap();
    assert!(status.success());
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn sigterm_ends_recv_streams_with_tde_keeps_the_part_and_exits_130() {
    let dir = scratch("sigterm-recv");
    let output = dir.join("output.bin");
    let hub = Hub::bind("127.0.0.1:0", None, HubOptions::default()).await.unwrap();
    let addr = hub.local_addr().to_string();
    let mut recv = spawn(&["recv", "--connect", &addr, "--json", "--out", output.to_str().unwrap()]);
    wait_for_line(&mut recv, "listening").await;
    let sender =
        bounded("join", Node::connect(&addr, Framing::GridConnect, NodeOptions::new(peer_id(0xB3)))).await.unwrap();
    let mut stream = bounded("open", sender.open(OpenOptions::new(RECEIVER.parse().unwrap(), 2048))).await.unwrap();
    bounded("write", stream.write_all(data(5000))).await.unwrap();
    terminate(&recv).await;
    let (status, stdout, _) = finish(recv).await;
    assert_eq!(status.code(), Some(130), "{stdout}");
    assert_eq!(field(&stdout, "result"), "interrupted", "{stdout}");
    assert!(field(&stdout, "file").ends_with(".part"), "{stdout}");
    let kept: u64 = field(&stdout, "bytes").parse().unwrap();
    // The sender is told at once: its next write fails with the termination.
    let error = bounded("the TDE", async {
        loop {
            if let Err(error) = stream.write_all(data(100)).await {
                return error;
            }
        }
    })
    .await;
    assert!(matches!(error, openlcb_tokio::Error::Terminated { .. }), "{error:?}");
    assert_eq!(std::fs::metadata(part(&output)).unwrap().len(), kept);
    assert!(!output.exists());
    let _ = std::fs::remove_dir_all(dir);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn sigterm_ends_the_send_stream_with_tde_and_exits_130() {
    let dir = scratch("sigterm-send");
    let input = dir.join("input.bin");
    std::fs::write(&input, data(4 * 1024 * 1024)).unwrap();
    let hub = Hub::bind("127.0.0.1:0", None, HubOptions::default()).await.unwrap();
    let addr = hub.local_addr().to_string();
    let mut receiver =
        bounded("join", Node::connect(&addr, Framing::GridConnect, NodeOptions::new(RECEIVER.parse().unwrap())))
            .await
            .unwrap();
    let send = spawn(&["send", input.to_str().unwrap(), "--to", RECEIVER, "--connect", &addr, "--window", "2048"]);
    let mut stream = bounded("accept", receiver.accept()).await.unwrap();
    // Take a little, then stop reading: the sender waits for credit.
    let first = bounded("first data", stream.read()).await.unwrap();
    assert!(first.is_some());
    terminate(&send).await;
    let (status, _, stderr) = finish(send).await;
    assert_eq!(status.code(), Some(130), "{stderr}");
    assert!(stderr.contains("interrupted after"), "{stderr}");
    let outcome = bounded("the TDE", async {
        loop {
            match stream.read().await {
                Ok(Some(_)) => {}
                other => return other,
            }
        }
    })
    .await;
    assert!(matches!(outcome, Err(openlcb_tokio::Error::Terminated { .. })), "{outcome:?}");
    let _ = std::fs::remove_dir_all(dir);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn an_interrupted_send_reports_every_byte_it_handed_to_the_bus() {
    let dir = scratch("interrupted-count");
    let input = dir.join("input.bin");
    std::fs::write(&input, data(4 * 1024 * 1024)).unwrap();
    let hub = Hub::bind("127.0.0.1:0", None, HubOptions::default()).await.unwrap();
    let addr = hub.local_addr().to_string();
    let mut receiver =
        bounded("join", Node::connect(&addr, Framing::GridConnect, NodeOptions::new(RECEIVER.parse().unwrap())))
            .await
            .unwrap();
    let args = ["send", input.to_str().unwrap(), "--to", RECEIVER, "--connect", &addr, "--window", "2048", "--json"];
    let send = spawn(&args);
    let mut stream = bounded("accept", receiver.accept()).await.unwrap();
    // Take a little, then stop reading: the sender stops in the middle of one of its chunks,
    // waiting for credit, and is interrupted there.
    let first = bounded("first data", stream.read()).await.unwrap().unwrap();
    terminate(&send).await;
    let (status, stdout, stderr) = finish(send).await;
    assert_eq!(status.code(), Some(130), "{stderr}");
    let reported: u64 = field(&stdout, "bytes").parse().unwrap();
    let mut kept = first.len() as u64;
    let end = bounded("the TDE", async {
        loop {
            match stream.read().await {
                Ok(Some(bytes)) => kept += bytes.len() as u64,
                other => return other,
            }
        }
    })
    .await;
    assert!(matches!(end, Err(openlcb_tokio::Error::Terminated { .. })), "{end:?}");
    assert_eq!(reported, kept, "what send reports is what the receiver got");
    assert!(stderr.contains(&format!("interrupted after {kept} bytes handed to the bus")), "{stderr}");
    let _ = std::fs::remove_dir_all(dir);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_second_hub_names_the_listener_it_cannot_open_and_exits_2() {
    let (_hub, _, tcp) = start_hub_binary().await;
    let second = spawn(&["hub", "--listen", "127.0.0.1:0", "--tcp-listen", &tcp]);
    let (status, _, stderr) = finish(second).await;
    assert_eq!(status.code(), Some(2), "{stderr}");
    assert!(stderr.contains("OpenLCB-TCP listener") && stderr.contains(&tcp), "{stderr}");
    assert!(stderr.contains("--tcp-listen") && stderr.contains("--no-tcp"), "{stderr}");
    let bad = spawn(&["hub", "--listen", "not-an-address", "--no-tcp"]);
    let (status, _, stderr) = finish(bad).await;
    assert_eq!(status.code(), Some(2), "{stderr}");
    assert!(stderr.contains("GridConnect listener") && stderr.contains("--listen"), "{stderr}");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_port_that_closes_at_once_exits_3() {
    let listener = tokio::net::TcpListener::bind("127.0.0.1:0").await.unwrap();
    let addr = listener.local_addr().unwrap().to_string();
    tokio::spawn(async move {
        for _ in 0..4 {
            let Ok((socket, _)) = listener.accept().await else { return };
            drop(socket);
        }
    });
    let recv = spawn(&["recv", "--connect", &addr]);
    let (status, _, stderr) = finish(recv).await;
    assert_eq!(status.code(), Some(3), "{stderr}");
    assert!(stderr.contains("cannot reach the hub"), "{stderr}");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_second_recv_with_a_taken_node_id_exits_10_and_the_first_keeps_running() {
    let dir = scratch("duplicate");
    let (_hub, gridconnect, _) = start_hub_binary().await;
    let output = dir.join("output.bin");
    let mut first = spawn(&["recv", "--connect", &gridconnect, "--once", "--out", output.to_str().unwrap()]);
    wait_for_line(&mut first, "listening").await;
    let second = spawn(&["recv", "--connect", &gridconnect, "--out", dir.to_str().unwrap()]);
    let (status, _, stderr) = finish(second).await;
    assert_eq!(status.code(), Some(10), "{stderr}");
    assert!(stderr.contains("already has Node ID"), "{stderr}");
    let input = dir.join("input.bin");
    std::fs::write(&input, data(5000)).unwrap();
    let send = spawn(&["send", input.to_str().unwrap(), "--to", RECEIVER, "--connect", &gridconnect]);
    assert!(finish(send).await.0.success());
    let (status, _, stderr) = finish(first).await;
    assert!(status.success(), "{stderr}");
    assert_eq!(std::fs::read(&output).unwrap(), data(5000));
    let _ = std::fs::remove_dir_all(dir);
}

/// Resident memory of a process in KiB (Linux), 0 where unknown.
fn resident_kib(pid: u32) -> u64 {
    let status = std::fs::read_to_string(format!("/proc/{pid}/status")).unwrap_or_default();
    let line = status.lines().find(|l| l.starts_with("VmRSS:")).unwrap_or("VmRSS: 0 kB");
    line.split_whitespace().nth(1).and_then(|n| n.parse().ok()).unwrap_or(0)
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_flood_of_requests_from_a_thousand_aliases_is_answered_and_memory_stays_flat() {
    use tokio::io::{AsyncReadExt as _, AsyncWriteExt as _};
    const ALIASES: u16 = 1000;
    const PER_ALIAS: u8 = 10;
    let dir = scratch("flood");
    let (_hub, gridconnect, _) = start_hub_binary().await;
    let mut flood = bounded("connect", tokio::net::TcpStream::connect(&gridconnect)).await.unwrap();
    let mut recv = spawn(&["recv", "--connect", &gridconnect, "--out", dir.to_str().unwrap()]);
    wait_for_line(&mut recv, "listening").await;
    let pid = recv.id().unwrap();
    // Learn recv's alias from its AMD (it is 05.01.01.01.22.F1).
    let mut seen = String::new();
    let mut buf = vec![0u8; 64 * 1024];
    let recv_alias = bounded("recv's AMD", async {
        loop {
            let n = flood.read(&mut buf).await.unwrap();
            assert!(n > 0);
            seen.push_str(&String::from_utf8_lossy(&buf[..n]));
            let amd = seen.lines().find(|l| l.starts_with(":X10701") && l.ends_with("N0501010122F1;"));
            if let Some(amd) = amd {
                return u16::from_str_radix(&amd[7..10], 16).unwrap();
            }
        }
    })
    .await;
    let before = resident_kib(pid);
    // 1 000 aliases other than recv's own (an AMD from it would be a collision).
    let aliases: Vec<u16> = (0x100..0x600).filter(|a| *a != recv_alias).take(usize::from(ALIASES)).collect();
    let to_write = aliases.clone();
    let (mut reader, mut writer) = flood.into_split();
    let writing = tokio::spawn(async move {
        for (i, alias) in to_write.iter().enumerate() {
            let mut text = format!(":X10701{alias:03X}N050101013{i:03X};\n");
            for sid in 0..PER_ALIAS {
                text += &format!(":X19CC8{alias:03X}N{recv_alias:04X}FFFF0000{sid:02X};\n");
            }
            writer.write_all(text.as_bytes()).await.unwrap();
        }
        writer
    });
    // Count the Initiate Replies addressed to each alias.
    let mut answered = vec![0u8; usize::from(ALIASES)];
    let mut total = 0usize;
    let mut pending = String::new();
    let prefix = format!(":X19868{recv_alias:03X}N");
    bounded("every reply", async {
        while total < usize::from(ALIASES) * usize::from(PER_ALIAS) {
            let n = reader.read(&mut buf).await.unwrap();
            assert!(n > 0, "the hub closed the connection after {total} replies");
            pending.push_str(&String::from_utf8_lossy(&buf[..n]));
            let last = pending.rfind('\n').map_or(0, |i| i + 1);
            for line in pending[..last].lines() {
                if let Some(data) = line.strip_prefix(&prefix) {
                    let to = u16::from_str_radix(&data[1..4], 16).unwrap();
                    let code = &data[8..12];
                    assert!(code == "8000" || code == "2020", "reply code {code}: {line}");
                    let index = aliases.iter().position(|a| *a == to);
                    if let Some(count) = index.and_then(|i| answered.get_mut(i)) {
                        *count += 1;
                        total += 1;
                    }
                }
            }
            pending.drain(..last);
        }
    })
    .await;
    let _writer = writing.await.unwrap();
    assert!(answered.iter().all(|&n| n == PER_ALIAS), "some aliases were not answered");
    let after = resident_kib(pid);
    assert!(after < before + 32 * 1024, "recv grew from {before} KiB to {after} KiB");
    drop(recv);
    let _ = std::fs::remove_dir_all(dir);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_duplicate_announced_later_is_reported_and_recv_keeps_running() {
    use tokio::io::{AsyncReadExt as _, AsyncWriteExt as _};
    let (_hub, gridconnect, _) = start_hub_binary().await;
    let mut recv = spawn(&["recv", "--connect", &gridconnect]);
    wait_for_line(&mut recv, "listening").await;
    // A newcomer announces the same Node ID: recv, which was there first, sends the
    // well-known event Duplicate Node ID Detected and goes on.
    let mut other = bounded("connect", tokio::net::TcpStream::connect(&gridconnect)).await.unwrap();
    other.write_all(b":X10701ABCN0501010122F1;\n").await.unwrap();
    let mut seen = String::new();
    let mut buf = [0u8; 512];
    bounded("the report", async {
        while !seen.contains("N0101000000000201;") {
            let n = other.read(&mut buf).await.unwrap();
            assert!(n > 0, "the hub closed: {seen}");
            seen.push_str(&String::from_utf8_lossy(&buf[..n]));
        }
    })
    .await;
    assert!(seen.contains(":X195B4"), "a Producer/Consumer Event Report: {seen}");
    tokio::time::sleep(std::time::Duration::from_millis(500)).await;
    assert!(recv.try_wait().unwrap().is_none(), "recv keeps running");
}

/// A pseudo-terminal pair: the master end, the terminal end (held open so that the master
/// does not hang up) and the terminal's device path.
fn pty() -> (tokio_serial::SerialStream, tokio_serial::SerialStream, String) {
    use tokio_serial::SerialPort as _;
    let (master, terminal) = tokio_serial::SerialStream::pair().unwrap();
    let path = terminal.name().unwrap();
    (master, terminal, path)
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn hub_serial_relays_between_a_node_on_the_serial_line_and_recv_over_tcp() {
    let dir = scratch("hub-serial");
    let output = dir.join("output.bin");
    let (master, _terminal, path) = pty();
    let mut hub = spawn(&["hub", "--listen", "127.0.0.1:0", "--no-tcp", "--serial", &path]);
    let line = wait_for_line(&mut hub, "GridConnect on").await;
    let addr = line.split_whitespace().nth(4).unwrap().to_string();
    let mut recv = spawn(&["recv", "--connect", &addr, "--once", "--json", "--out", output.to_str().unwrap()]);
    wait_for_line(&mut recv, "listening").await;

    // The node on the line's far end, where an adapter's CAN bus would be.
    let me = NodeId::from_bytes([0x05, 0x01, 0x01, 0x01, 0x22, 0xF0]);
    let node =
        bounded("login over the pty", Node::over(master, Framing::GridConnect, NodeOptions::new(me))).await.unwrap();
    let payload = data(256 * 1024);
    bounded("sending over the serial line", async {
        let mut stream = node.open(OpenOptions::new(RECEIVER.parse().unwrap(), 2048)).await.unwrap();
        stream.write_all(payload.clone()).await.unwrap();
        stream.finish().await.unwrap();
    })
    .await;
    let (status, stdout, _) = finish(recv).await;
    assert!(status.success(), "recv failed: {status} {stdout}");
    assert_eq!(field(&stdout, "bytes"), payload.len().to_string());
    assert!(std::fs::read(&output).unwrap() == payload, "the received file differs");
    let _ = std::fs::remove_dir_all(dir);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn send_serial_reaches_a_node_behind_the_adapter() {
    let dir = scratch("send-serial");
    let input = dir.join("input.bin");
    let payload = data(200_000);
    std::fs::write(&input, &payload).unwrap();
    // A hub on the master end plays the adapter and its bus; the receiver is on that bus.
    let (master, _terminal, path) = pty();
    let mut bus = Hub::bind("127.0.0.1:0", None, HubOptions::default()).await.unwrap();
    bus.attach(master, "the adapter");
    let receiver_id: NodeId = RECEIVER.parse().unwrap();
    let mut receiver = bounded(
        "the receiver's login",
        Node::connect(&bus.local_addr().to_string(), Framing::GridConnect, NodeOptions::new(receiver_id)),
    )
    .await
    .unwrap();
    let send = spawn(&["send", input.to_str().unwrap(), "--to", RECEIVER, "--serial", &path, "--json"]);
    let received = bounded("the stream from send --serial", async {
        let mut stream = receiver.accept().await.unwrap();
        let mut received = Vec::new();
        while let Some(chunk) = stream.read().await.unwrap() {
            received.extend_from_slice(&chunk);
        }
        received
    })
    .await;
    let (status, stdout, stderr) = finish(send).await;
    assert!(status.success(), "send failed: {status} {stderr}");
    assert_eq!(field(&stdout, "result"), "ok", "{stdout}");
    assert!(received == payload, "the data differs after {} bytes", received.len());
    let _ = std::fs::remove_dir_all(dir);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn send_and_recv_on_two_hubs_chained_with_upstream() {
    let dir = scratch("upstream");
    let (input, output) = (dir.join("input.bin"), dir.join("output.bin"));
    let payload = data(150_000);
    std::fs::write(&input, &payload).unwrap();
    let (_upstream, upstream_addr, _) = start_hub_binary().await;
    let mut downstream =
        spawn(&["hub", "--listen", "127.0.0.1:0", "--no-tcp", "--upstream", &upstream_addr, "--silent-timeout", "0"]);
    // Its address, then the line saying the link is up.
    let stderr = downstream.stderr.take().unwrap();
    let mut lines = BufReader::new(stderr).lines();
    let (addr, linked) = bounded("the downstream hub linking", async {
        let mut addr = None;
        while let Some(line) = lines.next_line().await.unwrap() {
            if line.contains("GridConnect on") {
                addr = line.split_whitespace().nth(4).map(str::to_string);
            }
            if line.contains("is upstream") {
                return (addr.unwrap(), line);
            }
        }
        panic!("the downstream hub's stderr ended");
    })
    .await;
    assert!(linked.contains(&upstream_addr), "{linked}");
    tokio::spawn(async move { while let Ok(Some(_)) = lines.next_line().await {} });

    let mut recv = spawn(&["recv", "--connect", &upstream_addr, "--once", "--json", "--out", output.to_str().unwrap()]);
    wait_for_line(&mut recv, "listening").await;
    let send = spawn(&["send", input.to_str().unwrap(), "--to", RECEIVER, "--connect", &addr, "--json"]);
    let (status, stdout, stderr) = finish(send).await;
    assert!(status.success(), "send failed: {status} {stdout} {stderr}");
    let (status, stdout, _) = finish(recv).await;
    assert!(status.success(), "recv failed: {status} {stdout}");
    assert!(std::fs::read(&output).unwrap() == payload, "the received file differs");
    let _ = std::fs::remove_dir_all(dir);
}

/// `hub --trace` never slows the bus: while nobody reads the trace (a stalled terminal, here
/// a pipe not read), the frames are relayed all the same, and once the trace is read again a
/// line of it says how many events it left out.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_trace_that_falls_behind_relays_every_frame_and_says_how_many_it_left_out() {
    use tokio::io::{AsyncReadExt as _, AsyncWriteExt as _};
    // Far more trace lines than the pipe (64 KiB) and the hub's event queue (4096) hold.
    const FRAMES: usize = 20_000;
    let mut hub = spawn(&["hub", "--listen", "127.0.0.1:0", "--no-tcp", "--trace"]);
    let line = wait_for_line(&mut hub, "GridConnect on").await;
    let addr = line.split_whitespace().nth(4).unwrap().to_string();
    let mut sender = bounded("connect", tokio::net::TcpStream::connect(&addr)).await.unwrap();
    let mut listener = bounded("connect", tokio::net::TcpStream::connect(&addr)).await.unwrap();
    let frames: String = (0..FRAMES).map(|i| format!(":X19490{:03X}N;\n", 0x100 + i % 0x600)).collect();
    let writing = tokio::spawn(async move { sender.write_all(frames.as_bytes()).await.map(|()| sender) });
    // The other client gets every frame while the trace is not read.
    let mut received = 0usize;
    let mut buf = vec![0u8; 64 * 1024];
    bounded("every frame relayed", async {
        while received < FRAMES {
            let n = listener.read(&mut buf).await.unwrap();
            assert!(n > 0, "the hub closed the connection after {received} frames");
            received += buf[..n].iter().filter(|b| **b == b';').count();
        }
    })
    .await;
    assert_eq!(received, FRAMES);
    let _sender = bounded("writing", writing).await.unwrap().unwrap();
    // Now the trace is read: it holds fewer frame lines than frames, and says so.
    let stdout = hub.stdout.take().unwrap();
    let mut lines = BufReader::new(stdout).lines();
    let (traced, note) = bounded("the note of what the trace left out", async {
        let mut traced = 0usize;
        while let Some(line) = lines.next_line().await.unwrap() {
            if line.contains(":X19490") {
                traced += 1;
            } else if line.contains("events not shown here") {
                return (traced, line);
            }
        }
        panic!("the trace ended without saying what it left out");
    })
    .await;
    let left_out: usize = note.split_whitespace().nth(2).unwrap().parse().unwrap();
    assert!(left_out > 0 && traced + left_out <= FRAMES, "{traced} traced, {note}");
}
