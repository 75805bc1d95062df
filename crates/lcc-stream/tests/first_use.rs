//! What a layout owner meets on first use, with the built binary: free Node IDs for tools that
//! come and go, error codes in words, files named and checked before the network is touched,
//! `-v` for Memory Configuration, a wrong port told apart from an empty network, `--json` on
//! every exit path, signals, departures in the hub's log, shell completions and the manual
//! page, `-q` and `-`, and devices named in their errors. Every wait is bounded.

mod common;

use std::process::{Output, Stdio};

use common::{bounded, command, scratch};
use serde_json::Value;
use tokio::io::{AsyncBufReadExt, AsyncReadExt, AsyncWriteExt, BufReader};
use tokio::process::Child;

/// `lcc-stream hub` on ephemeral ports: the child and its GridConnect and OpenLCB-TCP
/// addresses; its stderr is collected into the returned channel.
async fn hub() -> (Child, String, String, tokio::sync::mpsc::UnboundedReceiver<String>) {
    let mut hub = command(&["hub", "--listen", "127.0.0.1:0", "--tcp-listen", "127.0.0.1:0"]).spawn().unwrap();
    let mut lines = BufReader::new(hub.stderr.take().unwrap()).lines();
    let first = bounded("the hub", async { lines.next_line().await.unwrap().unwrap() }).await;
    // "lcc-stream hub: GridConnect on A, OpenLCB-TCP on B (bridged)"
    let words: Vec<&str> = first.split_whitespace().collect();
    let (gridconnect, tcp) = (words[4].trim_end_matches(',').to_string(), words[7].to_string());
    let (tx, rx) = tokio::sync::mpsc::unbounded_channel();
    tokio::spawn(async move {
        while let Ok(Some(line)) = lines.next_line().await {
            let _ = tx.send(line);
        }
    });
    (hub, gridconnect, tcp, rx)
}

/// Runs the binary with `args` to its end.
async fn run(args: &[&str]) -> Output {
    bounded(&args.join(" "), command(args).output()).await.unwrap()
}

fn text(bytes: &[u8]) -> String {
    String::from_utf8_lossy(bytes).into_owned()
}

/// The stderr of a command that ended with exit status `code`.
fn exits(output: &Output, code: i32) -> String {
    let stderr = text(&output.stderr);
    assert_eq!(output.status.code(), Some(code), "{stderr}");
    stderr
}

/// Exactly one JSON object on stdout.
fn one_object(output: &Output) -> Value {
    let stdout = text(&output.stdout);
    let lines: Vec<&str> = stdout.lines().collect();
    assert_eq!(lines.len(), 1, "not one line of JSON: {stdout:?} {}", text(&output.stderr));
    serde_json::from_str(lines[0]).unwrap_or_else(|e| panic!("{e}: {stdout}"))
}

/// Starts a long-lived command and waits for `ready` on its stderr (which is then drained).
async fn start(args: &[&str], ready: &str) -> Child {
    let mut child = command(args).spawn().unwrap();
    let mut lines = BufReader::new(child.stderr.take().unwrap()).lines();
    bounded(ready, async {
        while let Some(line) = lines.next_line().await.unwrap() {
            if line.contains(ready) {
                return;
            }
        }
        panic!("stderr ended before {ready:?}");
    })
    .await;
    tokio::spawn(async move { while let Ok(Some(_)) = lines.next_line().await {} });
    child
}

fn signal(child: &Child, signal: &str) {
    let pid = child.id().unwrap().to_string();
    assert!(std::process::Command::new("kill").args(["-s", signal, &pid]).status().unwrap().success());
}

/// A port nothing listens on.
fn closed_port() -> String {
    let port = std::net::TcpListener::bind("127.0.0.1:0").unwrap().local_addr().unwrap().port();
    format!("127.0.0.1:{port}")
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn transient_tools_find_free_node_ids_beside_serve_and_each_other() {
    let (_hub, addr, _, _) = hub().await;
    let dir = scratch("transient");
    let _serve =
        start(&["serve", "--connect", &addr, "--firmware-out", dir.join("fw.bin").to_str().unwrap()], "serving").await;
    let nodes = run(&["nodes", "--connect", &addr]).await;
    assert!(nodes.status.success(), "{}", text(&nodes.stderr));
    assert!(text(&nodes.stdout).contains("05.01.01.01.22.F2"), "{}", text(&nodes.stdout));
    // Two reads at once, neither told a Node ID.
    let out = |n: u8| dir.join(format!("backup-{n}.bin")).to_str().unwrap().to_string();
    let (one, two) = (out(1), out(2));
    let read = |out: &str| {
        command(&["read", "--from", "05.01.01.01.22.F2", "--length", "64", "--out", out, "--connect", &addr]).output()
    };
    let (first, second) = bounded("two reads", async { tokio::join!(read(&one), read(&two)) }).await;
    for output in [first.unwrap(), second.unwrap()] {
        assert!(output.status.success(), "{}", text(&output.stderr));
    }
    let _ = std::fs::remove_dir_all(dir);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_duplicate_node_id_names_the_option_that_changes_it() {
    let (_hub, addr, _, _) = hub().await;
    let dir = scratch("duplicate");
    let _first = start(&["recv", "--connect", &addr, "--out", dir.to_str().unwrap()], "listening").await;
    let second = run(&["recv", "--connect", &addr, "--out", dir.to_str().unwrap()]).await;
    assert_eq!(second.status.code(), Some(10), "{}", text(&second.stderr));
    assert!(text(&second.stderr).contains("--node-id"), "{}", text(&second.stderr));
    let _ = std::fs::remove_dir_all(dir);
}

/// A target scripted on the hub's GridConnect port, Node ID 05.01.01.01.22.F3 (alias 0x5F3),
/// that answers a lookup of its Node ID at once but the first PIP request only once the hub
/// has carried another node's Verified Node ID for `claimed` (12 hex digits): the asker gets
/// that claim first, on the same connection. It stops `quiet` after the last frame once
/// `done` is set (or after 20 s) and returns every frame it saw.
async fn target_answering_after_a_claim(
    addr: &str,
    claimed: &'static str,
    done: tokio::sync::watch::Receiver<bool>,
) -> tokio::task::JoinHandle<String> {
    let mut socket = tokio::net::TcpStream::connect(addr).await.unwrap();
    socket.write_all(b":X107015F3N0501010122F3;").await.unwrap();
    tokio::spawn(async move {
        let quiet = std::time::Duration::from_millis(300);
        let give_up = tokio::time::Instant::now() + std::time::Duration::from_secs(20);
        let (mut seen, mut buf) = (String::new(), [0u8; 4096]);
        let (mut asker, mut claim_seen, mut answered) = (None::<String>, false, false);
        while tokio::time::Instant::now() < give_up {
            let n = match tokio::time::timeout(quiet, socket.read(&mut buf)).await {
                Ok(Ok(n @ 1..)) => n,
                Ok(_) => break,
                Err(_) if *done.borrow() => break,
                Err(_) => continue,
            };
            let before = seen.len();
            seen.push_str(&text(&buf[..n]));
            for frame in seen[before..].split_inclusive(';').filter(|f| f.ends_with(';')) {
                let (header, data) = frame.trim().split_once('N').unwrap_or(("", ""));
                let lookup = (header.starts_with(":X10702") || header.starts_with(":X19490"))
                    && (data == ";" || data == "0501010122F3;");
                if lookup {
                    socket.write_all(b":X107015F3N0501010122F3;:X191705F3N0501010122F3;").await.unwrap();
                }
                if header.starts_with(":X19828") && data == "05F3;" {
                    asker = Some(header[7..10].to_string());
                }
                let from = header.get(7..10).unwrap_or("");
                if header.starts_with(":X19170") && data == format!("{claimed};") && Some(from) != asker.as_deref() {
                    claim_seen = true;
                }
                if let (Some(asker), true, false) = (&asker, claim_seen, answered) {
                    socket.write_all(format!(":X196685F3N0{asker}705820000000;").as_bytes()).await.unwrap();
                    answered = true;
                }
            }
        }
        seen
    })
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_firmware_upgrade_under_a_taken_node_id_exits_10_and_a_rerun_goes_through() {
    let (_hub, addr, _, _) = hub().await;
    let dir = scratch("taken-firmware");
    let image = dir.join("image.bin");
    std::fs::write(&image, vec![0x5A; 300]).unwrap();
    let image = image.to_str().unwrap();
    let firmware_out = dir.join("fw.bin");
    let _serve =
        start(&["serve", "--connect", &addr, "--firmware-out", firmware_out.to_str().unwrap()], "serving").await;
    let taken = "05.01.01.01.22.77";
    let _holder =
        start(&["recv", "--connect", &addr, "--node-id", taken, "--out", dir.to_str().unwrap()], "listening").await;
    // The tool starts its work at login, so whether the holder's claim comes before or after
    // a step depends on how fast the holder answers; this target makes it come before the
    // target's first answer, so the tool must leave with the words of a duplicate before it
    // has frozen anything. A second upgrade with a free Node ID then goes through at once.
    let (done, done_rx) = tokio::sync::watch::channel(false);
    let target = target_answering_after_a_claim(&addr, "050101012277", done_rx).await;
    let upgrade = run(&["firmware", image, "--to", "05.01.01.01.22.F3", "--node-id", taken, "--connect", &addr]).await;
    done.send(true).unwrap();
    let stderr = exits(&upgrade, 10);
    assert!(stderr.contains("already has Node ID 05.01.01.01.22.77") && stderr.contains("--node-id"), "{stderr}");
    let seen = bounded("the target's frames", target).await.unwrap();
    let frames: Vec<&str> = seen.split(';').map(str::trim).collect();
    let sent = |mti: &str| frames.iter().any(|f| f.starts_with(mti) && f.ends_with("N050101012277"));
    assert!(sent(":X19170"), "the holder claimed its Node ID: {seen}");
    let tool_joined = sent(":X19100");
    assert!(tool_joined, "the target saw the tool's Initialization Complete: {seen}");
    assert!(!seen.contains("N20A1EF;"), "a Freeze went out under a taken Node ID: {seen}");
    let again = run(&["firmware", image, "--to", "05.01.01.01.22.F2", "--connect", &addr]).await;
    assert!(again.status.success(), "{}", text(&again.stderr));
    assert_eq!(std::fs::read(&firmware_out).unwrap(), vec![0x5A; 300]);
    let _ = std::fs::remove_dir_all(dir);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn memory_configuration_codes_are_worded_and_steps_are_logged_with_v() {
    let (_hub, addr, _, _) = hub().await;
    let dir = scratch("codes");
    let _serve =
        start(&["serve", "--connect", &addr, "--firmware-out", dir.join("fw.bin").to_str().unwrap()], "serving").await;
    let out = dir.join("x.bin");
    let out = out.to_str().unwrap();
    let unknown =
        run(&["read", "--from", "05.01.01.01.22.F2", "--space", "0x10", "--out", out, "--connect", &addr]).await;
    let stderr = exits(&unknown, 4);
    assert!(stderr.contains("0x1081 (address space unknown)") && stderr.contains("no such address space"), "{stderr}");
    // -v: the steps; -vv: every command and reply, by datagrams here.
    let logged = run(&[
        "-vv",
        "read",
        "--from",
        "05.01.01.01.22.F2",
        "--length",
        "16",
        "--no-stream",
        "--out",
        "-",
        "--connect",
        &addr,
    ])
    .await;
    let stderr = text(&logged.stderr);
    assert!(logged.status.success(), "{stderr}");
    assert_eq!(logged.stdout.len(), 16, "the bytes go to stdout");
    for step in ["asking for the node's protocols", "found the node", "sent Read space 0xFD", "received Read Reply"] {
        assert!(stderr.contains(step), "no {step:?} in {stderr}");
    }
    let _ = std::fs::remove_dir_all(dir);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn files_are_named_and_checked_before_the_network_is_touched() {
    // Nothing listens: a command that touched the network first would exit 3.
    let addr = closed_port();
    let dir = scratch("files");
    let missing = dir.join("missing.bin");
    let missing = missing.to_str().unwrap();
    for args in [
        &["write", missing, "--to", "05.01.01.01.22.F2"][..],
        &["firmware", missing, "--to", "05.01.01.01.22.F2"],
        &["send", missing, "--to", "05.01.01.01.22.F1"],
        &["send", dir.to_str().unwrap(), "--to", "05.01.01.01.22.F1"],
        &["recv", "--out", dir.join("no-such-dir/out.bin").to_str().unwrap()],
    ] {
        let output = run(&[args, &["--connect", &addr]].concat()).await;
        let stderr = text(&output.stderr);
        assert_eq!(output.status.code(), Some(8), "{args:?}: {stderr}");
        assert!(stderr.contains(dir.to_str().unwrap()), "{args:?} does not name the file: {stderr}");
    }
    let taken = dir.join("taken.bin");
    std::fs::write(&taken, b"keep").unwrap();
    let read =
        run(&["read", "--from", "05.01.01.01.22.F2", "--out", taken.to_str().unwrap(), "--connect", &addr]).await;
    let stderr = exits(&read, 8);
    assert!(stderr.contains("taken.bin") && stderr.contains("--force"), "{stderr}");
    // --json: one object, with the shared word.
    let json = run(&["send", missing, "--to", "05.01.01.01.22.F1", "--json", "--connect", &addr]).await;
    assert_eq!(one_object(&json)["result"], "file_error");
    let _ = std::fs::remove_dir_all(dir);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_wrong_port_is_told_apart_from_an_empty_network() {
    let (_hub, gridconnect, tcp, _) = hub().await;
    let nodes = run(&["nodes", "--connect", &tcp]).await;
    let stderr = exits(&nodes, 3);
    assert!(stderr.contains("does not speak GridConnect") && stderr.contains("--protocol tcp"), "{stderr}");
    // A hub that drops what it cannot read (OpenMRN's) looks like an empty network: a hint.
    let empty = run(&["nodes", "--protocol", "tcp", "--connect", &tcp]).await;
    let stderr = exits(&empty, 0);
    assert!(stderr.contains("0 node(s) answered") && stderr.contains("may speak GridConnect"), "{stderr}");
    let send = run(&[
        "send",
        "Cargo.toml",
        "--to",
        "05.01.01.01.22.F1",
        "--protocol",
        "tcp",
        "--json",
        "--connect",
        &gridconnect,
    ])
    .await;
    assert_eq!(send.status.code(), Some(3), "{}", text(&send.stderr));
    assert_eq!(one_object(&send)["result"], "unreachable_hub");
    assert!(text(&send.stderr).contains("does not speak OpenLCB-TCP"), "{}", text(&send.stderr));
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn read_reports_the_path_it_used_and_a_peer_not_found_like_everyone() {
    let (_hub, addr, _, _) = hub().await;
    let dir = scratch("path");
    let _serve =
        start(&["serve", "--connect", &addr, "--firmware-out", dir.join("fw.bin").to_str().unwrap()], "serving").await;
    for (extra, path) in [(&[][..], "stream"), (&["--no-stream"][..], "datagrams")] {
        let out = dir.join(format!("{path}.bin"));
        let args = ["read", "--from", "05.01.01.01.22.F2", "--length", "100", "--json", "--connect", &addr, "--out"];
        let output = run(&[&args[..], &[out.to_str().unwrap()], extra].concat()).await;
        let report = one_object(&output);
        assert_eq!((report["path"].as_str(), report["bytes"].as_u64()), (Some(path), Some(100)), "{report}");
    }
    // Absent: a Node ID outside the transient range (05.01.01.01.22.80-BF) the tools pick from.
    let absent = run(&["read", "--from", "05.01.01.01.22.7E", "--out", "-", "--connect", &addr]).await;
    assert_eq!(absent.status.code(), Some(5));
    let json =
        run(&["send", "Cargo.toml", "--to", "05.01.01.01.22.7E", "--json", "--timeout", "2", "--connect", &addr]).await;
    assert_eq!(json.status.code(), Some(5), "{}", text(&json.stderr));
    let _ = std::fs::remove_dir_all(dir);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn sighup_is_an_interrupt_and_the_hub_exits_130() {
    let (hub, addr, _, _) = hub().await;
    let dir = scratch("sighup");
    let recv = start(&["recv", "--connect", &addr, "--json", "--out", dir.to_str().unwrap()], "listening").await;
    signal(&recv, "HUP");
    let output = bounded("recv", recv.wait_with_output()).await.unwrap();
    assert_eq!(output.status.code(), Some(130), "{}", text(&output.stderr));
    assert_eq!(one_object(&output)["result"], "interrupted");
    signal(&hub, "INT");
    let output = bounded("the hub", hub.wait_with_output()).await.unwrap();
    assert_eq!(output.status.code(), Some(130));
    let help = text(&run(&["firmware", "--help"]).await.stdout);
    assert!(help.contains("upgrade mode") && help.contains("run the same command again"), "{help}");
    let _ = std::fs::remove_dir_all(dir);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_client_that_closes_its_connection_simply_left() {
    let (_hub, addr, _, mut log) = hub().await;
    let mut leaving = tokio::net::TcpStream::connect(&addr).await.unwrap();
    leaving.write_all(b":X19490123N;\n").await.unwrap();
    let mut staying = tokio::net::TcpStream::connect(&addr).await.unwrap();
    tokio::time::sleep(std::time::Duration::from_millis(200)).await;
    drop(leaving);
    // Frames relayed to the closed socket: a broken pipe or a reset at the hub.
    for _ in 0..50 {
        staying.write_all(b":X19490456N;\n").await.unwrap();
        tokio::time::sleep(std::time::Duration::from_millis(10)).await;
    }
    let line = bounded("the departure", async {
        loop {
            let line = log.recv().await.unwrap();
            if line.contains("client 1 ") && !line.contains("connected") {
                return line;
            }
        }
    })
    .await;
    assert!(line.ends_with(" left"), "{line}");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn completions_man_page_quiet_and_stdin() {
    let bash = run(&["completions", "bash"]).await;
    assert!(bash.status.success() && text(&bash.stdout).contains("lcc-stream"));
    let man = run(&["man"]).await;
    assert!(text(&man.stdout).starts_with(".ie") || text(&man.stdout).contains(".TH"), "{}", text(&man.stdout));
    // Each subcommand has its page, by name or all into a folder.
    let restore = run(&["man", "config", "restore"]).await;
    assert!(text(&restore.stdout).contains(".TH lcc-stream-config-restore 1"), "{}", text(&restore.stdout));
    assert!(text(&restore.stdout).contains("dry\\-run"), "its options: {}", text(&restore.stdout));
    assert_eq!(run(&["man", "nope"]).await.status.code(), Some(2));
    let pages = scratch("man-pages");
    assert!(run(&["man", "--dir", pages.to_str().unwrap()]).await.status.success());
    for page in ["lcc-stream.1", "lcc-stream-send.1", "lcc-stream-config-restore.1", "lcc-stream-events-watch.1"] {
        assert!(pages.join(page).exists(), "{page}");
    }
    let (_hub, addr, _, _) = hub().await;
    let dir = scratch("stdin");
    let out = dir.join("in.bin");
    let _recv = start(&["recv", "--connect", &addr, "--out", out.to_str().unwrap()], "listening").await;
    let mut send = command(&["-q", "send", "-", "--to", "05.01.01.01.22.F1", "--connect", &addr])
        .stdin(Stdio::piped())
        .spawn()
        .unwrap();
    let mut stdin = send.stdin.take().unwrap();
    stdin.write_all(b"from stdin").await.unwrap();
    drop(stdin);
    let output = bounded("send", send.wait_with_output()).await.unwrap();
    assert!(output.status.success(), "{}", text(&output.stderr));
    assert!(output.stdout.is_empty(), "-q printed {}", text(&output.stdout));
    let arrived = bounded("the file", async {
        loop {
            if let Ok(data) = std::fs::read(&out) {
                return data;
            }
            tokio::time::sleep(std::time::Duration::from_millis(50)).await;
        }
    })
    .await;
    assert_eq!(arrived, b"from stdin");
    let _ = std::fs::remove_dir_all(dir);
}

#[tokio::test]
async fn devices_are_named_with_what_went_wrong() {
    let help = text(&run(&["send", "--help"]).await.stdout);
    assert!(help.contains("--can <IFACE>"), "--can is missing from the default build");
    let serial = run(&["nodes", "--serial", "/dev/null"]).await;
    let stderr = exits(&serial, 3);
    assert!(stderr.contains("serial port /dev/null") && stderr.contains("not a serial port"), "{stderr}");
    let can = run(&["nodes", "--can", "nosuchcan0"]).await;
    let stderr = exits(&can, 3);
    assert!(stderr.contains("CAN interface nosuchcan0") && !stderr.contains("hub"), "{stderr}");
}
