//! `serve --produces/--consumes` with `events identify`, `events send` and `events watch`,
//! as separate processes through a hub on 127.0.0.1. Every wait is bounded.

mod common;

use common::{bounded, command, scratch, spawn};
use openlcb_tokio::{Hub, HubOptions};
use tokio::io::{AsyncBufReadExt, BufReader, Lines};
use tokio::process::{Child, ChildStderr};

const SERVER: &str = "05.01.01.01.22.E1";

/// Reads lines of `lines` until one contains `needle`.
async fn until(lines: &mut Lines<BufReader<ChildStderr>>, needle: &str) -> String {
    bounded(needle, async {
        while let Some(line) = lines.next_line().await.unwrap() {
            if line.contains(needle) {
                return line;
            }
        }
        panic!("the output ended before `{needle}`");
    })
    .await
}

async fn run(args: &[&str]) -> (bool, String, String) {
    let out = bounded("a command", command(args).output()).await.unwrap();
    (out.status.success(), String::from_utf8(out.stdout).unwrap(), String::from_utf8(out.stderr).unwrap())
}

async fn serve(addr: &str, dir: &std::path::Path) -> (Child, Lines<BufReader<ChildStderr>>) {
    let firmware = dir.join("fw.bin");
    let mut child = spawn(&[
        "serve",
        "--connect",
        addr,
        "--node-id",
        SERVER,
        "--firmware-out",
        firmware.to_str().unwrap(),
        "--produces",
        "05.01.01.01.22.E1.00.01",
        "--produces",
        "05.01.01.01.22.E1.01.00/256",
        "--consumes",
        "05.01.01.01.22.E1.00.02",
        "--consumes",
        "05.01.01.01.22.E1.02.00/16",
    ]);
    let mut lines = BufReader::new(child.stderr.take().unwrap()).lines();
    until(&mut lines, "serving spaces").await;
    (child, lines)
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn identify_lists_what_serve_produces_and_consumes_with_its_ranges() {
    let dir = scratch("events-identify");
    let hub = Hub::bind("127.0.0.1:0", None, HubOptions::default()).await.unwrap();
    let addr = hub.local_addr().to_string();
    let (_serve, _lines) = serve(&addr, &dir).await;

    let (ok, stdout, stderr) = run(&["events", "identify", "--connect", &addr, "--json"]).await;
    assert!(ok, "{stderr}");
    let rows: Vec<serde_json::Value> = stdout.lines().map(|l| serde_json::from_str(l).unwrap()).collect();
    let of_server: Vec<(String, String, String, String)> = rows
        .iter()
        .filter(|r| r["node"] == SERVER)
        .map(|r| {
            let field = |k: &str| r[k].as_str().unwrap_or("range").to_string();
            (field("role"), field("event"), field("last"), field("state"))
        })
        .collect();
    let row = |role: &str, event: &str, last: &str, state: &str| (role.into(), event.into(), last.into(), state.into());
    assert_eq!(
        of_server,
        [
            row("consumer", "05.01.01.01.22.E1.00.02", "05.01.01.01.22.E1.00.02", "unknown"),
            row("consumer", "05.01.01.01.22.E1.02.00", "05.01.01.01.22.E1.02.0F", "range"),
            row("producer", "05.01.01.01.22.E1.00.01", "05.01.01.01.22.E1.00.01", "unknown"),
            row("producer", "05.01.01.01.22.E1.01.00", "05.01.01.01.22.E1.01.FF", "range"),
        ]
    );

    // One event: Identify Producer and Identify Consumer, answered for that event.
    let (ok, stdout, _) = run(&["events", "identify", "05.01.01.01.22.E1.01.7F", "--connect", &addr]).await;
    assert!(ok);
    let answers: Vec<&str> = stdout.lines().filter(|l| l.starts_with(SERVER)).collect();
    assert_eq!(answers.len(), 1, "{stdout}");
    assert!(answers[0].contains("producer") && answers[0].contains("05.01.01.01.22.E1.01.7F"), "{stdout}");
    let _ = std::fs::remove_dir_all(dir);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn serve_prints_the_consumed_events_that_events_send_sends() {
    let dir = scratch("events-send");
    let hub = Hub::bind("127.0.0.1:0", None, HubOptions::default()).await.unwrap();
    let addr = hub.local_addr().to_string();
    let (_serve, mut lines) = serve(&addr, &dir).await;
    let mut watch = spawn(&["events", "watch", "--connect", &addr, "--json", "--node-id", "05.01.01.01.22.E3"]);
    let mut watch_err = BufReader::new(watch.stderr.take().unwrap()).lines();
    until(&mut watch_err, "watching").await;

    // Not consumed: serve says nothing; consumed, with a payload (first and last frames).
    let send = |event: &'static str, payload: Option<&'static str>| {
        let addr = addr.clone();
        async move {
            let mut args = vec!["events", "send", event, "--connect", &addr, "--node-id", "05.01.01.01.22.E2"];
            if let Some(payload) = payload {
                args.extend(["--payload", payload]);
            }
            let (ok, _, stderr) = run(&args).await;
            assert!(ok, "{stderr}");
        }
    };
    send("05.01.01.01.22.E1.00.09", None).await;
    send("05.01.01.01.22.E1.02.05", Some("01020304")).await;
    let line = until(&mut lines, "event ").await;
    assert!(line.contains("05.01.01.01.22.E1.02.05 from 05.01.01.01.22.E2, payload 01020304"), "{line}");

    // The watcher saw both reports, with the payload.
    let mut out = BufReader::new(watch.stdout.take().unwrap()).lines();
    let mut seen = Vec::new();
    while seen.len() < 2 {
        let line = bounded("a watched report", out.next_line()).await.unwrap().unwrap();
        let report: serde_json::Value = serde_json::from_str(&line).unwrap();
        seen.push((report["event"].as_str().unwrap().to_string(), report["payload"].as_str().unwrap().to_string()));
    }
    assert_eq!(
        seen,
        [
            ("05.01.01.01.22.E1.00.09".to_string(), String::new()),
            ("05.01.01.01.22.E1.02.05".to_string(), "01020304".to_string())
        ]
    );
    let _ = std::fs::remove_dir_all(dir);
}
