//! `--json` output of the built binary, parsed with serde_json: one object with the fields the
//! help lists.

use std::process::Command;

use serde_json::Value;

const BIN: &str = env!("CARGO_BIN_EXE_lcc-stream");

#[test]
fn sim_json_is_one_object_with_the_documented_fields() {
    let output = Command::new(BIN).args(["sim", "--bytes", "4096", "--window", "256", "--json"]).output().unwrap();
    assert!(output.status.success(), "{output:?}");
    let report: Value = serde_json::from_slice(&output.stdout).unwrap();
    let help =
        String::from_utf8_lossy(&Command::new(BIN).args(["sim", "--help"]).output().unwrap().stdout).into_owned();
    let object = report.as_object().unwrap();
    for key in object.keys() {
        assert!(help.contains(key.as_str()), "{key} is not documented in sim --help");
    }
    assert_eq!(report["payload_bytes"], 4096);
    assert_eq!(report["window"], 256);
    assert_eq!(report["verified"], true);
    assert_eq!(report["topology"], "can");
    let frames = report["frames"].as_object().unwrap();
    let kinds: u64 = frames.iter().filter(|(kind, _)| *kind != "total").map(|(_, n)| n.as_u64().unwrap()).sum();
    assert_eq!(frames["total"].as_u64(), Some(kinds));
    assert!(report["efficiency"].as_f64().is_some_and(|e| e > 0.0 && e <= 1.0), "{report}");
}

#[test]
fn send_and_recv_help_list_their_json_fields() {
    let help = |command| {
        String::from_utf8_lossy(&Command::new(BIN).args([command, "--help"]).output().unwrap().stdout).into_owned()
    };
    for field in
        ["file", "to", "bytes", "elapsed_s", "bytes_per_s", "window", "result", "frames_out", "writes", "error"]
    {
        assert!(help("send").contains(field), "send: {field}");
    }
    for field in ["file", "from", "bytes", "elapsed_s", "bytes_per_s", "window", "result", "content_uid", "error"] {
        assert!(help("recv").contains(field), "recv: {field}");
    }
}

fn sim_json(args: &[&str]) -> (bool, Value) {
    let output = Command::new(BIN).arg("sim").args(args).arg("--json").output().unwrap();
    (output.status.success(), serde_json::from_slice(&output.stdout).unwrap())
}

#[test]
fn sim_255_streams_on_one_bus_all_complete_within_the_ceiling() {
    // At the default window each stream waits 77 s for its next turn on the bus.
    let (ok, report) = sim_json(&["--streams", "255", "--bytes", "4096"]);
    assert!(ok, "{report}");
    assert_eq!(report["verified"], true);
    assert_eq!(report["delivered_bytes"], 255 * 4096);
    assert!(report["efficiency"].as_f64().is_some_and(|e| e > 0.5 && e <= 1.0), "{report}");
}

#[test]
fn sim_that_does_not_verify_counts_only_delivered_bytes_and_says_why() {
    // Nodes that take 10 s to answer anything: the Initiate Reply comes after the 20 s wait.
    let (ok, report) = sim_json(&["--streams", "4", "--bytes", "4096", "--topology", "tcp", "--latency", "10000"]);
    assert!(!ok);
    assert_eq!(report["verified"], false);
    let delivered = report["delivered_bytes"].as_u64().unwrap();
    assert!(delivered < 4 * 4096, "{report}");
    assert_eq!(report["failures"]["TimedOut(Reply)"], 4, "{report}");
    let failures: u64 = report["failures"].as_object().unwrap().values().map(|n| n.as_u64().unwrap()).sum();
    assert!(failures > 0, "{report}");
    assert!(report["efficiency"].as_f64().is_some_and(|e| e <= 1.0), "{report}");
    let goodput = report["goodput_bytes_per_s"].as_f64().unwrap();
    assert!((goodput - delivered as f64 / report["elapsed_s"].as_f64().unwrap()).abs() < 1.0, "{report}");
}
