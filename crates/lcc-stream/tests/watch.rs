//! `events watch` (and `events identify`) against raw GridConnect peers through a hub on
//! 127.0.0.1: reports are printed as they come while names are looked up beside them, a
//! flood is printed or counted report for report, and a sender known only by its CAN alias
//! is shown as that alias. Every wait is bounded.

mod common;

use common::{Bus, bounded, interrupt, reports, spawn};
use openlcb_can::{Fragments, NodeAlias, gridconnect};
use openlcb_stream::Mti;
use openlcb_tokio::{Hub, HubOptions};
use serde_json::Value;
use tokio::io::{AsyncBufReadExt, BufReader, Lines};
use tokio::process::{Child, ChildStdout};

/// A hub on 127.0.0.1 that holds a whole flood for a client that reads it late.
async fn hub() -> (Hub, String) {
    let mut options = HubOptions::default();
    options.max_queued_bytes = 64 * 1024 * 1024;
    let hub = Hub::bind("127.0.0.1:0", None, options).await.unwrap();
    let addr = hub.local_addr().to_string();
    (hub, addr)
}

/// `events watch ARGS...` on `addr` as `node`, once it says it is watching; its stdout lines.
async fn watch(addr: &str, node: &str, args: &[&str]) -> (Child, Lines<BufReader<ChildStdout>>) {
    let mut all = vec!["events", "watch", "--connect", addr, "--node-id", node];
    all.extend(args);
    let mut child = spawn(&all);
    let mut stderr = BufReader::new(child.stderr.take().unwrap()).lines();
    bounded("watching", async {
        while let Some(line) = stderr.next_line().await.unwrap() {
            if line.contains("watching") {
                return;
            }
        }
        panic!("events watch ended before watching");
    })
    .await;
    // The rest of stderr is read, so that the tool never waits for it.
    tokio::spawn(async move { while let Ok(Some(_)) = stderr.next_line().await {} });
    let stdout = BufReader::new(child.stdout.take().unwrap()).lines();
    (child, stdout)
}

/// The next line of `lines` as JSON.
async fn next_json(lines: &mut Lines<BufReader<ChildStdout>>) -> Value {
    let line = bounded("a line of events watch", lines.next_line()).await.unwrap().expect("the output ended");
    serde_json::from_str(&line).unwrap_or_else(|e| panic!("{e}: {line}"))
}

/// The frames of a SNIP reply from `from` to `to` naming the node `user_name`.
fn snip_reply(from: u16, to: u16, user_name: &str) -> String {
    let mut payload = vec![4];
    for field in ["Acme", "Signal 4", "1", "2"] {
        payload.extend(field.as_bytes());
        payload.push(0);
    }
    payload.push(2);
    payload.extend(user_name.as_bytes());
    payload.extend([0, 0]);
    let (from, to) = (NodeAlias::new(from).unwrap(), NodeAlias::new(to).unwrap());
    let mut text = Vec::new();
    for frame in Fragments::new(Mti::SIMPLE_NODE_INFO_REPLY, from, Some(to), payload).unwrap() {
        gridconnect::encode_to(&frame, &mut text).unwrap();
        text.push(b'\n');
    }
    String::from_utf8(text).unwrap()
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_report_is_printed_before_its_sender_answers_snip_and_later_reports_carry_the_name() {
    const SENDER: &str = "05.01.01.01.22.E6";
    let (_hub, addr) = hub().await;
    let (_watch, mut out) = watch(&addr, "05.01.01.01.22.E3", &["--json"]).await;
    let mut bus = Bus::connect(&addr).await;
    bus.send(":X107015A1N0501010122E6;\n").await;
    bus.send(":X195B45A1N0501010122E60001;\n").await;
    // Printed while the question of its name is still unanswered: this peer answers only
    // once it has seen the line.
    let first = next_json(&mut out).await;
    assert_eq!((first["event"].as_str(), first["from"].as_str()), (Some("05.01.01.01.22.E6.00.01"), Some(SENDER)));
    assert_eq!(first["from_name"], Value::Null);
    let request = bus.until("the SNIP request", |l| l.starts_with(":X19DE8") && l.ends_with("N05A1;")).await;
    let asker = u16::from_str_radix(&request[7..10], 16).unwrap();
    bus.send(&snip_reply(0x5A1, asker, "Signal box")).await;
    // A later report carries the name, once the answer has been taken.
    let mut named = None;
    for n in 0..50u16 {
        bus.send(&format!(":X195B45A1N0501010122E6{:04X};\n", 0x100 + n)).await;
        let line = next_json(&mut out).await;
        if line["from_name"] == "Signal box" {
            named = Some(line);
            break;
        }
        tokio::time::sleep(std::time::Duration::from_millis(100)).await;
    }
    let named = named.expect("no report carried the sender's name");
    assert_eq!(named["from"], SENDER);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn twenty_senders_that_never_answer_snip_hold_up_no_report() {
    let (_hub, addr) = hub().await;
    // Lookups that would wait 300 s each: a report waiting for one would not come within
    // the bound of this test.
    let (_watch, mut out) = watch(&addr, "05.01.01.01.22.E7", &["--json", "--snip-timeout", "300"]).await;
    let mut bus = Bus::connect(&addr).await;
    let senders: Vec<u16> = (0x601..=0x615).collect();
    let text: String = senders.iter().map(|alias| format!(":X195B4{alias:03X}N05010101{alias:08X};\n")).collect();
    bus.send(&text).await;
    for alias in senders {
        let line = next_json(&mut out).await;
        let from_alias = format!("{alias:03X}");
        assert_eq!(line["from_alias"].as_str(), Some(from_alias.as_str()), "{line}");
        assert_eq!(
            line["event"].as_str().unwrap(),
            format!("05.01.01.01.00.00.{:02X}.{:02X}", alias >> 8, alias & 0xFF)
        );
        assert!(line.get("from").is_none(), "no Node ID for an alias-only sender: {line}");
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn every_report_of_a_flood_is_printed_or_counted_as_dropped() {
    const WATCHER: &str = "05.01.01.01.22.E4";
    const FLOOD: usize = 50_000;
    let (_hub, addr) = hub().await;
    let (watch, mut out) = watch(&addr, WATCHER, &["--json"]).await;
    let mut bus = Bus::connect(&addr).await;
    // Nobody reads the output meanwhile: most reports find every queue full.
    bus.send(&reports(0x6A0, 0x0501_0101_22E4_0000, 0x1_0000, FLOOD)).await;
    bus.settle(0x6A0, WATCHER).await;
    interrupt(&watch).await;
    let (mut printed, mut said_dropped, mut summary) = (0u64, 0u64, None);
    while let Some(line) = bounded("the rest of the output", out.next_line()).await.unwrap() {
        let line: Value = serde_json::from_str(&line).unwrap();
        if line.get("event").is_some() {
            printed += 1;
        } else if line.get("reports").is_some() {
            summary = Some(line);
        } else {
            said_dropped += line["dropped"].as_u64().unwrap();
        }
    }
    let summary = summary.expect("a summary at the end");
    let dropped = summary["dropped"].as_u64().unwrap();
    assert_eq!(summary["reports"], FLOOD as u64, "{summary}");
    assert_eq!(summary["printed"], printed, "{summary}");
    assert_eq!(printed + dropped, FLOOD as u64, "{summary}");
    assert_eq!(said_dropped, dropped, "every dropped report is said where it was lost");
    assert!(dropped > 0, "nobody read the output during the flood: {summary}");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_sender_known_only_by_its_alias_is_shown_as_alias_4ff_in_watch_and_identify() {
    let (_hub, addr) = hub().await;
    let (_watch, mut out) = watch(&addr, "05.01.01.01.22.E5", &[]).await;
    let mut bus = Bus::connect(&addr).await;
    bus.send(":X195B44FFN0501010122E50001;\n").await;
    let line = bounded("the report", out.next_line()).await.unwrap().unwrap();
    assert!(line.contains("05.01.01.01.22.E5.00.01  from alias 4FF"), "{line}");
    assert!(!line.contains("00.00.00.00.04.FF"), "{line}");

    let identify = common::command(&["events", "identify", "--connect", &addr, "--json"]).output();
    let answering = async {
        bus.until("Identify Events", |l| l.starts_with(":X19970")).await;
        bus.send(":X195474FFN0501010122E50001;\n").await;
    };
    let (identified, ()) = bounded("events identify", async { tokio::join!(identify, answering) }).await;
    let identified = identified.unwrap();
    assert!(identified.status.success(), "{}", String::from_utf8_lossy(&identified.stderr));
    let rows: Vec<Value> =
        String::from_utf8(identified.stdout).unwrap().lines().map(|l| serde_json::from_str(l).unwrap()).collect();
    let row = rows.iter().find(|r| r["event"] == "05.01.01.01.22.E5.00.01").expect("the alias's answer");
    assert_eq!((row["alias"].as_str(), row.get("node"), row["role"].as_str()), (Some("4FF"), None, Some("producer")));
}
