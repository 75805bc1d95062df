//! `lcc-stream train` as a separate process through `lcc-stream hub`, driven by a scripted
//! OpenLCB-TCP throttle: controller, speed, functions, and a train created for an allocate
//! search, each printed as a JSON line. Every wait is bounded.

mod common;

use common::{bounded, interrupt, spawn, until};
use openlcb_stream::{Message, Mti, NodeId};
use tokio::io::{AsyncBufReadExt, AsyncReadExt as _, AsyncWriteExt as _, BufReader, Lines};
use tokio::process::{Child, ChildStderr, ChildStdout};

/// A scripted OpenLCB-TCP peer.
struct Throttle {
    socket: tokio::net::TcpStream,
    decoder: openlcb_tcp::Decoder,
    me: NodeId,
    held: Vec<u8>,
}

impl Throttle {
    async fn send(&mut self, message: Message) {
        let prefix = openlcb_tcp::LinkPrefix { gateway: self.me, capture_time: openlcb_tcp::CaptureTime::wrapping(0) };
        let mut out = bytes::BytesMut::new();
        openlcb_tcp::TcpFrame::new(prefix, message.as_ref()).encode_to(&mut out).unwrap();
        self.socket.write_all(&out).await.unwrap();
    }

    async fn command(&mut self, to: NodeId, payload: &[u8]) {
        self.send(Message::addressed(Mti::TRACTION_CONTROL_COMMAND, self.me, to, payload.to_vec())).await;
    }

    /// The next message with `mti` that `wanted` takes.
    async fn expect(&mut self, mti: Mti, wanted: impl Fn(&Message) -> bool) -> Message {
        bounded("a message", async {
            let mut buf = vec![0; 4096];
            loop {
                let mut input = &self.held[..];
                let mut found = None;
                while let Some(frame) = self.decoder.decode(&mut input) {
                    let m = frame.unwrap().message;
                    let message = match m.destination {
                        Some(to) => Message::addressed(m.mti, m.source, to, m.payload.to_vec()),
                        None => Message::global(m.mti, m.source, m.payload.to_vec()),
                    };
                    if message.mti == mti && wanted(&message) {
                        found = Some(message);
                        break;
                    }
                }
                self.held = input.to_vec();
                if let Some(message) = found {
                    return message;
                }
                let n = self.socket.read(&mut buf).await.unwrap();
                assert!(n > 0, "the hub closed the connection");
                self.held.extend_from_slice(&buf[..n]);
            }
        })
        .await
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_throttle_drives_the_train_and_has_a_second_one_allocated() {
    let mut hub = spawn(&["hub", "--listen", "127.0.0.1:0", "--tcp-listen", "127.0.0.1:0"]);
    let mut hub_err: Lines<BufReader<ChildStderr>> = BufReader::new(hub.stderr.take().unwrap()).lines();
    let line = until(&mut hub_err, "GridConnect on").await;
    let words: Vec<&str> = line.split_whitespace().collect();
    let (gridconnect, tcp) = (words[4].trim_end_matches(',').to_string(), words[7].to_string());
    tokio::spawn(async move { while let Ok(Some(_)) = hub_err.next_line().await {} });

    let train_id: NodeId = "05.01.01.01.22.01".parse().unwrap();
    let mut train = spawn(&[
        "train",
        "--connect",
        &gridconnect,
        "--node-id",
        "05.01.01.01.22.01",
        "--json",
        "--function",
        "0=Headlight",
        "--function",
        "2=Horn",
        "--momentary",
        "2",
    ]);
    let mut said: Lines<BufReader<ChildStderr>> = BufReader::new(train.stderr.take().unwrap()).lines();
    let mut printed: Lines<BufReader<ChildStdout>> = BufReader::new(train.stdout.take().unwrap()).lines();
    until(&mut said, "DCC 3 as 05.01.01.01.22.01").await;

    let me: NodeId = "05.01.01.01.22.C0".parse().unwrap();
    let socket = bounded("connect", tokio::net::TcpStream::connect(&tcp)).await.unwrap();
    let mut throttle = Throttle { socket, decoder: openlcb_tcp::Decoder::default(), me, held: Vec::new() };
    let to_me = move |m: &Message| m.destination == Some(me);

    let mut assign = vec![0x20, 0x01, 0x00];
    assign.extend_from_slice(&me.to_bytes());
    throttle.command(train_id, &assign).await;
    let reply = throttle.expect(Mti::TRACTION_CONTROL_REPLY, to_me).await;
    assert_eq!(reply.payload, vec![0x20, 0x01, 0x00]);
    let line = until(&mut printed, "\"controller-assigned\"").await;
    assert!(line.contains("\"train\":3") && line.contains("05.01.01.01.22.C0"), "{line}");

    throttle.command(train_id, &[0x00, 0xBE, 0x4C]).await;
    let line = until(&mut printed, "\"speed\"").await;
    assert!(line.contains("\"set_speed\":-1.57"), "{line}");
    throttle.command(train_id, &[0x01, 0, 0, 2, 0, 1]).await;
    let line = until(&mut printed, "\"function\"").await;
    assert!(line.contains("\"function\":2") && line.contains("\"value\":1"), "{line}");
    throttle.command(train_id, &[0x10]).await;
    let reply = throttle.expect(Mti::TRACTION_CONTROL_REPLY, to_me).await;
    assert_eq!(reply.payload[..4], [0x10, 0xBE, 0x4C, 0x00]);

    // An allocate search for DCC 12: a train node of its own is created and answers it.
    let search = 0x0900_99FF_FFFF_12E0u64.to_be_bytes();
    throttle.send(Message::global(Mti::IDENTIFY_PRODUCER, me, search.to_vec())).await;
    let answer = throttle.expect(Mti::PRODUCER_IDENTIFIED_VALID, |m| m.payload == search).await;
    assert_ne!(answer.source, train_id);
    until(&mut said, "created DCC 12").await;
    // The new train takes commands too, and says so with its own address.
    throttle.command(answer.source, &[0x00, 0x3C, 0x00]).await;
    let line = until(&mut printed, "\"train\":12").await;
    assert!(line.contains("\"set_speed\":1.0"), "{line}");

    interrupt(&train).await;
    assert!(bounded("the train to stop", train.wait()).await.unwrap().success());
}

/// `lcc-stream hub` on 127.0.0.1 and `lcc-stream train --json` on it with `args`, logged in.
struct Station {
    _hub: Child,
    /// The hub's GridConnect address.
    gridconnect: String,
    train: Child,
    said: Lines<BufReader<ChildStderr>>,
    printed: Lines<BufReader<ChildStdout>>,
}

async fn station(args: &[&str]) -> Station {
    let mut hub = spawn(&["hub", "--listen", "127.0.0.1:0", "--tcp-listen", "127.0.0.1:0"]);
    let mut hub_err = BufReader::new(hub.stderr.take().unwrap()).lines();
    let line = until(&mut hub_err, "GridConnect on").await;
    let gridconnect = line.split_whitespace().nth(4).unwrap().trim_end_matches(',').to_string();
    tokio::spawn(async move { while let Ok(Some(_)) = hub_err.next_line().await {} });
    let mut train_args = vec!["train", "--connect", &gridconnect, "--json"];
    train_args.extend(args);
    let mut train = spawn(&train_args);
    let mut said = BufReader::new(train.stderr.take().unwrap()).lines();
    let printed = BufReader::new(train.stdout.take().unwrap()).lines();
    until(&mut said, "DCC 3 as").await;
    Station { _hub: hub, gridconnect, train, said, printed }
}

/// `lcc-stream ARGS --connect HUB`, bounded; its output, once it has succeeded.
async fn succeeds(hub: &str, args: &[&str]) -> std::process::Output {
    let command = [args, &["--connect", hub]].concat();
    let out = bounded(args[0], common::command(&command).output()).await.unwrap();
    assert!(out.status.success(), "{args:?}: {}", String::from_utf8_lossy(&out.stderr));
    out
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn our_throttle_finds_allocates_drives_and_releases_a_train() {
    let Station { _hub: _keep, gridconnect, mut train, mut said, mut printed } =
        station(&["--node-id", "05.01.01.01.22.01"]).await;

    // DCC 3 is the station's own train.
    let out = succeeds(
        &gridconnect,
        &["throttle", "3", "--speed", "36", "--reverse", "--function", "0=on", "--release", "--json"],
    )
    .await;
    let (stdout, stderr) = (String::from_utf8_lossy(&out.stdout), String::from_utf8_lossy(&out.stderr));
    assert!(stdout.contains("\"event\":\"assigned\""), "{stdout}");
    assert!(stdout.contains("\"event\":\"speeds\"") && stdout.contains("\"set_speed\":-36"), "{stdout}");
    assert!(stderr.contains("released"), "{stderr}");
    // A train known only by its alias is named so, never by a provisional Node ID.
    assert!(!stderr.contains("00.00.00.00.") && !stdout.contains("00.00.00.00."), "{stderr}{stdout}");
    let line = until(&mut printed, "\"speed\"").await;
    assert!(line.contains("\"set_speed\":-10"), "{line}");
    until(&mut printed, "\"function\"").await;
    until(&mut printed, "\"controller-released\"").await;

    // DCC 44 is not there: the throttle's allocating search has it created.
    succeeds(&gridconnect, &["throttle", "44", "--speed", "10", "--release"]).await;
    until(&mut said, "created DCC 44").await;
    until(&mut printed, "\"train\":44").await;

    // A consist: DCC 44 (the station's first created train, the next Node ID) listens to
    // DCC 3, reversed; a speed for 3 reaches 44 the other way round.
    let throttle =
        ["throttle", "3", "--attach", "05.01.01.01.22.02:reverse", "--speed", "18", "--forward", "--release"];
    let out = succeeds(&gridconnect, &throttle).await;
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(stdout.contains("listener 05.01.01.01.22.02 attached"), "{stdout}");
    let line = until(&mut printed, "\"set_speed\":-5").await;
    assert!(line.contains("\"train\":44"), "{line}");

    interrupt(&train).await;
    assert!(bounded("the train to stop", train.wait()).await.unwrap().success());
}

/// A train that does not answer Train Search (OpenMRN's Linux `train`) is driven by its Node
/// ID: `throttle --train` assigns it without a search.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn our_throttle_drives_a_train_given_by_its_node_id() {
    let Station { _hub: _keep, gridconnect, mut train, said: _, mut printed } =
        station(&["--node-id", "05.01.01.01.22.0A", "--allocate", "0"]).await;
    succeeds(&gridconnect, &["throttle", "--train", "05.01.01.01.22.0A", "--speed", "18", "--release"]).await;
    let line = until(&mut printed, "\"speed\"").await;
    assert!(line.contains("\"set_speed\":5"), "{line}");
    until(&mut printed, "\"controller-released\"").await;
    interrupt(&train).await;
    assert!(bounded("the train to stop", train.wait()).await.unwrap().success());
}

/// A train that leaves while the throttle drives it (on CAN its alias released, AMR): the
/// throttle says so (`train-lost`) and exits with status 5 (`not_found`), not waiting forever.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_train_that_leaves_while_driven_ends_the_throttle_with_train_lost() {
    let Station { _hub: _keep, gridconnect, mut train, said: _, mut printed } =
        station(&["--node-id", "05.01.01.01.22.0B", "--allocate", "0"]).await;
    let mut throttle = common::command(&["throttle", "3", "--speed", "20", "--json", "--connect", &gridconnect]);
    let mut throttle =
        throttle.stdout(std::process::Stdio::piped()).stderr(std::process::Stdio::piped()).spawn().unwrap();
    let mut throttle_out = BufReader::new(throttle.stdout.take().unwrap()).lines();
    let speeds = until(&mut throttle_out, "\"event\":\"speeds\"").await;
    let driven = speeds.split(",\"event\"").next().unwrap().to_string();
    until(&mut printed, "\"speed\"").await;
    // The station stops in an orderly way: its link releases the alias.
    interrupt(&train).await;
    assert!(bounded("the train to stop", train.wait()).await.unwrap().success());
    let line = until(&mut throttle_out, "\"event\":\"train-lost\"").await;
    assert!(line.starts_with(&driven), "the train driven is the one lost: {line} after {speeds}");
    let status = bounded("the throttle to end", throttle.wait()).await.unwrap();
    assert_eq!(status.code(), Some(5), "the throttle's exit status");
}

/// The throttle at a terminal (a pseudo-terminal, through `script` from util-linux): Up twice
/// is 10 km/h, `0` switches F0 on, `q` releases the train; each shows on the train's side and
/// on the status line.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_throttle_at_a_terminal_is_driven_by_its_keys() {
    let Station { _hub: _keep, gridconnect, mut train, said: _, mut printed } =
        station(&["--node-id", "05.01.01.01.22.0C", "--allocate", "0"]).await;
    let command = format!("{} throttle 3 --connect {gridconnect}", common::BIN);
    let mut terminal = tokio::process::Command::new("script")
        .args(["-qfec", &command, "/dev/null"])
        .stdin(std::process::Stdio::piped())
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .kill_on_drop(true)
        .spawn()
        .expect("script (util-linux) runs");
    let mut keys = terminal.stdin.take().unwrap();
    let mut screen = terminal.stdout.take().unwrap();
    let seen = std::sync::Arc::new(std::sync::Mutex::new(String::new()));
    tokio::spawn({
        let seen = seen.clone();
        async move {
            let mut buf = [0u8; 1024];
            while let Ok(n @ 1..) = screen.read(&mut buf).await {
                seen.lock().unwrap().push_str(&String::from_utf8_lossy(&buf[..n]));
            }
        }
    });
    let shown = |text: &'static str| {
        let seen = seen.clone();
        bounded(text, async move {
            while !seen.lock().unwrap().contains(text) {
                tokio::time::sleep(std::time::Duration::from_millis(20)).await;
            }
        })
    };
    shown("0 km/h forward").await;
    keys.write_all(b"\x1b[A").await.unwrap();
    shown("5 km/h forward").await;
    keys.write_all(b"\x1b[A").await.unwrap();
    shown("10 km/h forward").await;
    let line = until(&mut printed, "\"set_speed\":2.7").await;
    assert!(line.contains("\"speed\""), "{line}");
    keys.write_all(b"0").await.unwrap();
    shown("; F0").await;
    until(&mut printed, "\"function\"").await;
    keys.write_all(b"q").await.unwrap();
    until(&mut printed, "\"controller-released\"").await;
    let status = bounded("the throttle to end", terminal.wait()).await.unwrap();
    assert!(status.success(), "{status:?}: {}", seen.lock().unwrap());
    interrupt(&train).await;
    assert!(bounded("the train to stop", train.wait()).await.unwrap().success());
}

/// A train's configuration, as a tool changes it: `config set` gives DCC 3 a long address
/// 1234 and names F1; the train answers the search for 1234, its FDI names the key, and its
/// function space (0xF9) holds the function a throttle set.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_tool_configures_the_train_and_a_throttle_finds_it_by_its_new_address() {
    let Station { _hub: _keep, gridconnect, mut train, said: _, mut printed } =
        station(&["--node-id", "05.01.01.01.22.0C", "--allocate", "0"]).await;
    let node = "05.01.01.01.22.0C";
    for (key, value) in
        [("Train.Address type", "Long"), ("Train.DCC address", "1234"), ("Train.Function key(1).Name", "Bell")]
    {
        succeeds(&gridconnect, &["config", "set", node, key, value]).await;
    }
    let line = until(&mut printed, "DCC 1234 (long)").await;
    assert!(line.contains("\"configured\""), "{line}");
    let line = until(&mut printed, "2 named functions").await;
    assert!(line.contains("DCC 1234 (long)"), "{line}");

    succeeds(&gridconnect, &["throttle", "1234", "--function", "1=on", "--release"]).await;
    until(&mut printed, "\"function\"").await;

    let read = ["read", "--from", node, "--space", "0xF9", "--out", "-", "-q"];
    let functions = succeeds(&gridconnect, &read).await.stdout;
    assert_eq!(functions.get(..2), Some(&[0, 1][..]), "F1 is on, F0 off");
    let read = ["read", "--from", node, "--space", "0xFA", "--out", "-", "-q"];
    let fdi = String::from_utf8_lossy(&succeeds(&gridconnect, &read).await.stdout).into_owned();
    assert!(fdi.contains("<name>Bell</name>\n<number>1</number>"), "{fdi}");

    interrupt(&train).await;
    assert!(bounded("the train to stop", train.wait()).await.unwrap().success());
}
