//! The long-running commands (`serve`, `recv`, `events watch`, `monitor`) outlive their hub:
//! an in-process hub on 127.0.0.1 is dropped and a new one bound on the same address, and
//! each command says the loss, joins again and works through the new hub. `--no-reconnect`
//! and `--reconnect-for` exit with 6, Ctrl-C while waiting with 130. Every wait is bounded;
//! children are killed when a test ends.

mod common;

use std::process::ExitStatus;

use common::{BIN, Bus, bounded, interrupt, scratch, spawn};
use openlcb_tokio::{Hub, HubOptions};
use tokio::io::{AsyncBufReadExt, BufReader};
use tokio::process::Child;
use tokio::sync::mpsc;

const SERVER: &str = "05.01.01.01.22.E6";
const RECEIVER: &str = "05.01.01.01.22.E7";
const WATCHER: &str = "05.01.01.01.22.E8";

/// A hub on 127.0.0.1, on an ephemeral port; its address.
async fn first_hub() -> (Hub, String) {
    let hub = Hub::bind("127.0.0.1:0", None, HubOptions::default()).await.unwrap();
    let addr = hub.local_addr().to_string();
    (hub, addr)
}

/// A new hub on `addr`, once the address is free again (the dropped hub's listener closes
/// a moment after it is dropped).
async fn hub_again(addr: &str) -> Hub {
    bounded("the address free again", async {
        loop {
            match Hub::bind(addr, None, HubOptions::default()).await {
                Ok(hub) => return hub,
                Err(_) => tokio::time::sleep(std::time::Duration::from_millis(50)).await,
            }
        }
    })
    .await
}

/// A child of the binary, its stdout and stderr read line by line beside the test (so that
/// it never waits for them), and everything said on stderr so far.
struct Tool {
    child: Child,
    stdout: mpsc::UnboundedReceiver<String>,
    stderr: mpsc::UnboundedReceiver<String>,
    said: String,
}

impl Tool {
    fn start(args: &[&str]) -> Tool {
        let mut child = spawn(args);
        let stdout = lines_of(child.stdout.take().unwrap());
        let stderr = lines_of(child.stderr.take().unwrap());
        Tool { child, stdout, stderr, said: String::new() }
    }

    /// Waits for a line of stderr that contains `needle`, and returns it.
    async fn said(&mut self, needle: &str) -> String {
        let (stderr, said) = (&mut self.stderr, &mut self.said);
        bounded(needle, async {
            while let Some(line) = stderr.recv().await {
                said.push_str(&line);
                said.push('\n');
                if line.contains(needle) {
                    return line;
                }
            }
            panic!("stderr ended before a line with {needle:?}; it said:\n{said}");
        })
        .await
    }

    /// Waits for a line of stdout that contains `needle`, and returns it.
    async fn printed(&mut self, needle: &str) -> String {
        let stdout = &mut self.stdout;
        bounded(needle, async {
            while let Some(line) = stdout.recv().await {
                if line.contains(needle) {
                    return line;
                }
            }
            panic!("stdout ended before a line with {needle:?}");
        })
        .await
    }

    /// Waits for the exit; the status and the rest of stderr.
    async fn exit(mut self) -> (ExitStatus, String) {
        let status = bounded("the exit", self.child.wait()).await.unwrap();
        while let Some(line) = bounded("the rest of stderr", self.stderr.recv()).await {
            self.said.push_str(&line);
            self.said.push('\n');
        }
        (status, self.said)
    }
}

/// The lines of `output`, as they come.
fn lines_of(output: impl tokio::io::AsyncRead + Unpin + Send + 'static) -> mpsc::UnboundedReceiver<String> {
    let (tx, rx) = mpsc::unbounded_channel();
    tokio::spawn(async move {
        let mut lines = BufReader::new(output).lines();
        while let Ok(Some(line)) = lines.next_line().await {
            let _ = tx.send(line);
        }
    });
    rx
}

/// Runs the binary with `args` to its end: its status and stderr.
async fn run(args: &[&str]) -> (ExitStatus, String) {
    let output =
        tokio::process::Command::new(BIN).args(args).stdin(std::process::Stdio::null()).kill_on_drop(true).output();
    let output = bounded(&args.join(" "), output).await.unwrap();
    (output.status, String::from_utf8_lossy(&output.stderr).into_owned())
}

/// Drops `hub` and checks that `tool` says the loss, with the wait before the next attempt;
/// then binds a new hub on `addr` and waits until `tool` says `back`.
async fn restart(hub: Hub, addr: &str, tool: &mut Tool, back: &str) -> Hub {
    drop(hub);
    let lost = tool.said("lost the hub").await;
    assert!(lost.contains(addr) && lost.contains("trying again in 0.25 s"), "{lost}");
    let hub = hub_again(addr).await;
    tool.said(back).await;
    hub
}

#[tokio::test(flavor = "multi_thread")]
async fn serve_rejoins_a_restarted_hub_with_its_spaces_and_user_name_and_answers_a_read() {
    let dir = scratch("reconnect-serve");
    let (hub, addr) = first_hub().await;
    // Firmware images would go to the scratch folder, not the current one.
    let firmware = dir.join("firmware.bin");
    let mut serve =
        Tool::start(&["serve", "--connect", &addr, "--node-id", SERVER, "--firmware-out", firmware.to_str().unwrap()]);
    serve.said("serving spaces").await;
    // Bytes written before the restart: the configuration space (in memory) keeps them.
    let written = dir.join("written.bin");
    let bytes: Vec<u8> = (0..64u8).map(|i| i.wrapping_mul(37) ^ 0x5A).collect();
    std::fs::write(&written, &bytes).unwrap();
    let (status, stderr) = run(&["write", written.to_str().unwrap(), "--to", SERVER, "--connect", &addr]).await;
    assert!(status.success(), "{stderr}");
    // A user name written by a tool (space 0xFB, after its version byte) outlives the login too.
    let name = dir.join("name.bin");
    std::fs::write(&name, b"Yard 7\0").unwrap();
    let name = name.to_str().unwrap();
    let write_name = ["write", name, "--to", SERVER, "--space", "0xFB", "--address", "1", "--connect", addr.as_str()];
    let (status, stderr) = run(&write_name).await;
    assert!(status.success(), "{stderr}");
    serve.said("user name and description changed").await;

    let hub = restart(hub, &addr, &mut serve, "rejoined the hub").await;
    let back = serve.said.lines().find(|l| l.contains("rejoined the hub")).unwrap_or_default().to_string();
    assert!(back.contains(&format!("at {addr} as ")) && back.ends_with(&format!("/{SERVER}")), "{back}");

    let read = dir.join("read.bin");
    let read_path = read.to_str().unwrap();
    let (status, stderr) =
        run(&["read", "--from", SERVER, "--length", "64", "--out", read_path, "--connect", &addr]).await;
    assert!(status.success(), "{stderr}");
    assert_eq!(std::fs::read(&read).unwrap(), bytes, "the space kept what was written before the restart");
    let listed = tokio::process::Command::new(BIN)
        .args(["nodes", "--connect", &addr, "--json", "--wait", "0.5"])
        .stdin(std::process::Stdio::null())
        .kill_on_drop(true)
        .output();
    let listed = bounded("nodes", listed).await.unwrap();
    let listed = String::from_utf8_lossy(&listed.stdout).into_owned();
    let server = listed
        .lines()
        .map(|line| serde_json::from_str::<serde_json::Value>(line).unwrap())
        .find(|node| node["node_id"] == SERVER);
    let server = server.unwrap_or_else(|| panic!("`nodes` did not list {SERVER}: {listed}"));
    assert_eq!(server["snip"]["user_name"], "Yard 7", "SNIP after the new login: {server}");
    let read_name = ["read", "--from", SERVER, "--space", "0xFB", "--address", "1", "--length", "7"];
    let (status, stderr) = run(&[&read_name[..], &["--out", read_path, "--force", "--connect", &addr]].concat()).await;
    assert!(status.success(), "{stderr}");
    assert_eq!(std::fs::read(&read).unwrap(), b"Yard 7\0", "space 0xFB after the new login");
    drop(hub);
    let _ = std::fs::remove_dir_all(dir);
}

#[tokio::test(flavor = "multi_thread")]
async fn recv_listens_again_after_the_hub_restarts_and_takes_the_next_stream() {
    let dir = scratch("reconnect-recv");
    let out = dir.join("in");
    std::fs::create_dir_all(&out).unwrap();
    let (hub, addr) = first_hub().await;
    let mut recv = Tool::start(&["recv", "--out", out.to_str().unwrap(), "--node-id", RECEIVER, "--connect", &addr]);
    recv.said("listening on").await;
    let hub = restart(hub, &addr, &mut recv, "rejoined the hub").await;

    let input = dir.join("input.bin");
    let bytes: Vec<u8> = (0..20_000u32).map(|i| (i.wrapping_mul(2_654_435_761) >> 13) as u8).collect();
    std::fs::write(&input, &bytes).unwrap();
    let (status, stderr) = run(&["send", input.to_str().unwrap(), "--to", RECEIVER, "--connect", &addr]).await;
    assert!(status.success(), "{stderr}");
    recv.printed("received 20000 bytes").await;
    let files: Vec<_> = std::fs::read_dir(&out).unwrap().map(|e| e.unwrap().path()).collect();
    assert_eq!(files.len(), 1, "{files:?}");
    assert_eq!(std::fs::read(&files[0]).unwrap(), bytes);
    drop(hub);
    let _ = std::fs::remove_dir_all(dir);
}

#[tokio::test(flavor = "multi_thread")]
async fn a_stream_cut_by_the_loss_is_kept_as_part_and_said_then_recv_listens_again() {
    let dir = scratch("reconnect-recv-cut");
    let out = dir.join("in");
    std::fs::create_dir_all(&out).unwrap();
    let input = dir.join("input.bin");
    std::fs::write(&input, vec![0xA5; 8 * 1024 * 1024]).unwrap();
    let (hub, addr) = first_hub().await;
    let mut recv = Tool::start(&["recv", "--out", out.to_str().unwrap(), "--node-id", RECEIVER, "--connect", &addr]);
    recv.said("listening on").await;
    let send =
        Tool::start(&["send", input.to_str().unwrap(), "--to", RECEIVER, "--connect", &addr, "--window", "2048"]);
    // The hub goes once the stream's first bytes are in their `.part` file.
    bounded("the stream's .part file", async {
        while std::fs::read_dir(&out).unwrap().next().is_none() {
            tokio::time::sleep(std::time::Duration::from_millis(20)).await;
        }
    })
    .await;
    let hub = restart(hub, &addr, &mut recv, "rejoined the hub").await;
    let cut = recv.said.lines().find(|l| l.contains("failed after")).unwrap_or_default().to_string();
    assert!(cut.contains(".part)") && cut.contains("connection to the hub lost"), "{}", recv.said);
    let kept: Vec<_> = std::fs::read_dir(&out).unwrap().map(|e| e.unwrap().path()).collect();
    assert!(kept.len() == 1 && kept[0].to_string_lossy().ends_with(".part"), "{kept:?}");
    let (status, stderr) = send.exit().await;
    assert_eq!(status.code(), Some(6), "send, a one-shot command, still exits 6: {stderr}");
    drop(hub);
    let _ = std::fs::remove_dir_all(dir);
}

#[tokio::test(flavor = "multi_thread")]
async fn events_watch_rejoins_and_prints_a_report_sent_after_the_restart() {
    let (hub, addr) = first_hub().await;
    let mut watch = Tool::start(&["events", "watch", "--connect", &addr, "--node-id", WATCHER]);
    watch.said("watching").await;
    let hub = restart(hub, &addr, &mut watch, "rejoined the hub").await;

    let mut bus = Bus::connect(&addr).await;
    bus.send(":X195B44F1N0501010122E80001;\n").await;
    let line = watch.printed("05.01.01.01.22.E8.00.01").await;
    assert!(line.contains("from alias 4F1"), "{line}");
    interrupt(&watch.child).await;
    let (status, stderr) = watch.exit().await;
    assert_eq!(status.code(), Some(130), "{stderr}");
    assert!(stderr.contains("1 reports printed, 0 dropped"), "{stderr}");
    drop(hub);
}

#[tokio::test(flavor = "multi_thread")]
async fn monitor_listens_again_marks_the_gap_and_shows_frames_after_the_restart() {
    let (hub, addr) = first_hub().await;
    let mut monitor = Tool::start(&["monitor", "--connect", &addr]);
    monitor.said("listening on").await;
    let hub = restart(hub, &addr, &mut monitor, "listening again on").await;

    let gap = monitor.printed("nothing seen for").await;
    assert!(gap.contains(&format!("the hub at {addr} was lost")), "{gap}");
    let mut bus = Bus::connect(&addr).await;
    bus.send(":X194904F2N;\n").await;
    let line = monitor.printed("4F2").await;
    assert!(line.contains("Verify Node ID"), "{line}");
    drop(hub);
}

#[tokio::test(flavor = "multi_thread")]
async fn no_reconnect_exits_6_at_once_as_before() {
    let dir = scratch("reconnect-none");
    let (hub, addr) = first_hub().await;
    let mut recv = Tool::start(&[
        "recv",
        "--out",
        dir.to_str().unwrap(),
        "--node-id",
        RECEIVER,
        "--connect",
        &addr,
        "--no-reconnect",
    ]);
    recv.said("listening on").await;
    let mut watch = Tool::start(&["events", "watch", "--connect", &addr, "--node-id", WATCHER, "--no-reconnect"]);
    watch.said("watching").await;
    drop(hub);
    for (name, tool) in [("recv", recv), ("events watch", watch)] {
        let (status, stderr) = tool.exit().await;
        assert_eq!(status.code(), Some(6), "{name}: {stderr}");
        assert!(stderr.contains("connection to the hub lost") && !stderr.contains("trying again"), "{stderr}");
    }
    let _ = std::fs::remove_dir_all(dir);
}

#[tokio::test(flavor = "multi_thread")]
async fn reconnect_for_gives_up_with_6_once_the_hub_stays_away() {
    let (hub, addr) = first_hub().await;
    let mut monitor = Tool::start(&["monitor", "--connect", &addr, "--reconnect-for", "1"]);
    monitor.said("listening on").await;
    drop(hub);
    monitor.said("lost the hub").await;
    let (status, stderr) = monitor.exit().await;
    assert_eq!(status.code(), Some(6), "{stderr}");
    assert!(stderr.contains("attempt 1 failed: cannot reach"), "each attempt is said: {stderr}");
    assert!(stderr.contains("giving up on the hub") && stderr.contains("(--reconnect-for)"), "{stderr}");
}

#[tokio::test(flavor = "multi_thread")]
async fn ctrl_c_while_waiting_for_the_hub_exits_130_at_once() {
    let dir = scratch("reconnect-interrupt");
    let firmware = dir.join("firmware.bin");
    let (hub, addr) = first_hub().await;
    let mut serve =
        Tool::start(&["serve", "--connect", &addr, "--node-id", SERVER, "--firmware-out", firmware.to_str().unwrap()]);
    serve.said("serving spaces").await;
    drop(hub);
    serve.said("lost the hub").await;
    // In the backoff, between two failed attempts.
    serve.said("attempt 1 failed").await;
    interrupt(&serve.child).await;
    let (status, stderr) = serve.exit().await;
    assert_eq!(status.code(), Some(130), "{stderr}");
    assert!(stderr.contains("interrupted"), "{stderr}");
    let _ = std::fs::remove_dir_all(dir);
}
