//! `serve --produces/--consumes` with `events identify`, `events send` and `events watch`,
//! as separate processes through a hub on 127.0.0.1. Every wait is bounded.

mod common;

use common::{Bus, bounded, command, interrupt, reports, scratch, spawn, until};
use openlcb_tokio::{Hub, HubOptions};
use tokio::io::{AsyncBufReadExt, BufReader, Lines};
use tokio::process::{Child, ChildStderr};

const SERVER: &str = "05.01.01.01.22.E1";

async fn run(args: &[&str]) -> (bool, String, String) {
    let out = bounded("a command", command(args).output()).await.unwrap();
    (out.status.success(), String::from_utf8(out.stdout).unwrap(), String::from_utf8(out.stderr).unwrap())
}

/// `serve` producing and consuming a few events, with `extra` arguments; its stderr lines
/// once it serves.
async fn serve(addr: &str, dir: &std::path::Path, extra: &[&str]) -> (Child, Lines<BufReader<ChildStderr>>) {
    let firmware = dir.join("fw.bin");
    let mut args = vec![
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
    ];
    args.extend(extra);
    let mut child = spawn(&args);
    let mut lines = BufReader::new(child.stderr.take().unwrap()).lines();
    until(&mut lines, "serving spaces").await;
    (child, lines)
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn identify_lists_what_serve_produces_and_consumes_with_its_ranges() {
    let dir = scratch("events-identify");
    let hub = Hub::bind("127.0.0.1:0", None, HubOptions::default()).await.unwrap();
    let addr = hub.local_addr().to_string();
    let (_serve, _lines) = serve(&addr, &dir, &[]).await;

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
    let (_serve, mut lines) = serve(&addr, &dir, &[]).await;
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

/// A hub that holds a whole flood for a client that reads it late.
async fn flood_hub() -> (Hub, String) {
    let mut options = HubOptions::default();
    options.max_queued_bytes = 64 * 1024 * 1024;
    let hub = Hub::bind("127.0.0.1:0", None, options).await.unwrap();
    let addr = hub.local_addr().to_string();
    (hub, addr)
}

/// Reports of the consumed block 05.01.01.01.22.E1.02.00/16 sent in one go.
const FLOOD: usize = 50_000;

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn serve_json_counts_every_report_of_a_flood_as_received_or_dropped() {
    let dir = scratch("events-flood-json");
    let (_hub, addr) = flood_hub().await;
    let (mut serve, _lines) = serve(&addr, &dir, &["--json"]).await;
    let mut bus = Bus::connect(&addr).await;
    bus.send(&reports(0x6B0, 0x0501_0101_22E1_0200, 16, FLOOD)).await;
    bus.settle(0x6B0, SERVER).await;
    interrupt(&serve).await;
    let mut stdout = String::new();
    bounded("the report", tokio::io::AsyncReadExt::read_to_string(serve.stdout.as_mut().unwrap(), &mut stdout))
        .await
        .unwrap();
    let report: serde_json::Value = serde_json::from_str(stdout.trim()).unwrap();
    let (received, dropped) = (report["events_received"].as_u64(), report["events_dropped"].as_u64());
    assert_eq!(received.zip(dropped).map(|(r, d)| r + d), Some(FLOOD as u64), "{report}");
    let _ = std::fs::remove_dir_all(dir);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn serve_prints_or_says_it_dropped_every_report_of_a_flood() {
    let dir = scratch("events-flood-text");
    let (_hub, addr) = flood_hub().await;
    let (serve, mut lines) = serve(&addr, &dir, &[]).await;
    let mut bus = Bus::connect(&addr).await;
    // Nobody reads serve's stderr meanwhile: most reports find every queue full.
    bus.send(&reports(0x6B1, 0x0501_0101_22E1_0200, 16, FLOOD)).await;
    bus.settle(0x6B1, SERVER).await;
    interrupt(&serve).await;
    let (mut printed, mut said_dropped, mut end) = (0u64, 0u64, None);
    while let Some(line) = bounded("the rest of stderr", lines.next_line()).await.unwrap() {
        if line.starts_with("lcc-stream serve: event 05.01.01.01.22.E1.02.0") {
            assert!(line.ends_with("from alias 6B1"), "{line}");
            printed += 1;
        } else if let Some(dropped) = line.strip_prefix("lcc-stream serve: … ") {
            said_dropped += dropped.split_whitespace().next().unwrap().parse::<u64>().unwrap();
        } else if line.starts_with("lcc-stream serve: interrupted") {
            end = Some(line);
        }
    }
    // "lcc-stream serve: interrupted (P event reports printed, D dropped)"
    let end = end.expect("the last line");
    let counts: Vec<u64> = end.split(|c: char| !c.is_ascii_digit()).filter_map(|n| n.parse().ok()).collect();
    assert_eq!(counts, [printed, said_dropped], "{end}");
    assert_eq!(printed + said_dropped, FLOOD as u64, "{end}");
    assert!(said_dropped > 0, "{end}");
    let _ = std::fs::remove_dir_all(dir);
}
