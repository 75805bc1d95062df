//! `serve` as a board: a port's event set by `config set` is what `events identify` sees
//! next, an input line produces it, and a report of a port's event drives that output
//! (printed on stdout). Processes through a hub on 127.0.0.1; every wait is bounded.

mod common;

use std::process::Stdio;

use common::{BIN, Bus, bounded, command, interrupt};
use openlcb_tokio::{Hub, HubOptions};
use tokio::io::{AsyncBufReadExt, AsyncWriteExt, BufReader};
use tokio::process::Command;

const BOARD: &str = "05.01.01.01.22.D1";

async fn run(args: &[&str]) -> (bool, String, String) {
    let out = bounded("a command", command(args).output()).await.unwrap();
    (out.status.success(), String::from_utf8(out.stdout).unwrap(), String::from_utf8(out.stderr).unwrap())
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_configured_port_is_identified_produced_from_input_and_drives_its_output() {
    let hub = Hub::bind("127.0.0.1:0", None, HubOptions::default()).await.unwrap();
    let addr = hub.local_addr().to_string();
    let mut serve = Command::new(BIN)
        .args(["serve", "--connect", &addr, "--node-id", BOARD, "--input", "-"])
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .kill_on_drop(true)
        .spawn()
        .unwrap();
    let mut said = BufReader::new(serve.stderr.take().unwrap()).lines();
    bounded("serve to start", async {
        while let Some(line) = said.next_line().await.unwrap() {
            if line.contains("serving spaces") {
                break;
            }
        }
    })
    .await;
    let (ok, _, stderr) = run(&["events", "identify", "--connect", &addr, "--json"]).await;
    assert!(ok && !stderr.contains(BOARD), "nothing configured yet: {stderr}");

    for (key, event) in [
        ("Configuration.Port(0).Event On", "05.01.01.01.22.D1.00.01"),
        ("Configuration.Port(2).Event Off", "05.01.01.01.22.D1.00.06"),
    ] {
        let (ok, _, stderr) = run(&["config", "set", BOARD, key, event, "--connect", &addr]).await;
        assert!(ok, "{stderr}");
    }
    let (ok, stdout, stderr) = run(&["events", "identify", "--connect", &addr, "--json"]).await;
    assert!(ok, "{stderr}");
    for event in ["05.01.01.01.22.D1.00.01", "05.01.01.01.22.D1.00.06"] {
        for role in ["producer", "consumer"] {
            assert!(
                stdout.lines().any(|l| l.contains(event) && l.contains(&format!("\"{role}\""))),
                "{event} as {role}: {stdout}"
            );
        }
    }

    // An input line produces the port's event.
    let mut bus = Bus::connect(&addr).await;
    let mut stdin = serve.stdin.take().unwrap();
    stdin.write_all(b"port 1 on\nport 4 on\n").await.unwrap();
    bus.until("port 1's event", |l| l.starts_with(":X195B4") && l.ends_with("N0501010122D10001;")).await;

    // A report of a port's event drives its output.
    let (ok, _, stderr) = run(&["events", "send", "05.01.01.01.22.D1.00.06", "--connect", &addr]).await;
    assert!(ok, "{stderr}");
    let mut printed = BufReader::new(serve.stdout.take().unwrap()).lines();
    let output = bounded("the output", printed.next_line()).await.unwrap().unwrap();
    assert!(output.starts_with("port 3 off (05.01.01.01.22.D1.00.06 from"), "{output}");
    let refused = bounded("the refused line", async {
        while let Some(line) = said.next_line().await.unwrap() {
            if line.contains("`port 4 on`") {
                return line;
            }
        }
        panic!("serve ended");
    })
    .await;
    assert!(refused.contains("configured: port 1 on, port 3 off"), "{refused}");
    interrupt(&serve).await;
    assert!(bounded("serve to stop", serve.wait()).await.unwrap().code().is_some());
}
