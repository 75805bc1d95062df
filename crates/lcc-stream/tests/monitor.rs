//! `lcc-stream monitor --from` on saved traces: every decoded line checked against the
//! golden file beside the trace (a real firmware upgrade of OpenMRN's Bootloader by
//! `lcc-stream firmware`, and `lcc-stream events` with OpenMRN's io_board, both recorded
//! with `lcc-stream hub --trace`; and frames from the references, with some that do not
//! decode), the JSON form and the filters.

mod common;

use std::path::PathBuf;
use std::process::Command;

use common::BIN;

fn fixture(name: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures").join(name)
}

/// `monitor --from TRACE ARGS...`: its stdout lines.
fn monitor(trace: &str, args: &[&str]) -> Vec<String> {
    let out = Command::new(BIN).arg("monitor").arg("--from").arg(fixture(trace)).args(args).output().unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    String::from_utf8(out.stdout).unwrap().lines().map(str::to_string).collect()
}

fn golden(trace: &str, expected: &str) {
    let lines = monitor(trace, &[]);
    let expected = std::fs::read_to_string(fixture(expected)).unwrap();
    let expected: Vec<&str> = expected.lines().collect();
    for (n, (got, want)) in lines.iter().zip(&expected).enumerate() {
        assert_eq!(got, want, "line {}", n + 1);
    }
    assert_eq!(lines.len(), expected.len());
}

#[test]
fn a_firmware_upgrade_of_openmrns_bootloader_decodes_line_by_line() {
    golden("firmware-into-openmrn-bootloader.trace", "firmware-into-openmrn-bootloader.expected");
}

#[test]
fn events_with_openmrns_io_board_decode_line_by_line() {
    golden("events-with-openmrn-io-board.trace", "events-with-openmrn-io-board.expected");
    // Its reports, the one with payload reassembled from its first and last frames.
    let reports: Vec<String> = monitor("events-with-openmrn-io-board.trace", &["--kind", "event"])
        .into_iter()
        .filter(|l| l.contains("Event Report"))
        .collect();
    assert_eq!(reports.len(), 2, "{reports:?}");
    assert!(reports[1].ends_with("05.01.01.01.22.F6.00.01, payload 01 02 03 04"), "{}", reports[1]);
}

#[test]
fn reference_frames_decode_line_by_line_and_undecodable_ones_are_printed_raw() {
    golden("hand-made.trace", "hand-made.expected");
}

#[test]
fn the_upgrade_steps_are_named() {
    let lines = monitor("firmware-into-openmrn-bootloader.trace", &["--kind", "datagram"]);
    let steps: Vec<&str> = lines.iter().filter_map(|l| l.split_once("Memory Configuration ").map(|(_, s)| s)).collect();
    assert_eq!(
        steps,
        [
            "firmware upgrade: Freeze space 0xEF (firmware)",
            "firmware upgrade: Write Stream at 0x00000000 of space 0xEF (firmware), SID 0x00",
            "Write Stream Reply at 0x00000000 of space 0xEF (firmware)",
            "firmware upgrade: Unfreeze space 0xEF (firmware)",
        ]
    );
}

#[test]
fn json_gives_one_object_per_message() {
    let lines = monitor("hand-made.trace", &["--json"]);
    assert_eq!(lines.len(), monitor("hand-made.trace", &[]).len());
    let objects: Vec<serde_json::Value> = lines.iter().map(|l| serde_json::from_str(l).unwrap()).collect();
    let report = &objects[2];
    assert_eq!(report["kind"], "event");
    assert_eq!(report["source_alias"], "123");
    assert_eq!(report["source"], "05.01.01.01.22.00");
    assert_eq!(report["message"], "Producer/Consumer Event Report");
    assert_eq!(report["detail"], "01.01.00.00.00.00.02.01 (Duplicate Node ID Detected)");
    assert!(report["destination"].is_null() && report["raw"].is_null());
    let raw: Vec<&serde_json::Value> = objects.iter().filter(|o| o["kind"] == "raw").collect();
    assert_eq!(
        raw.iter().map(|o| o["raw"].as_str().unwrap()).collect::<Vec<_>>(),
        [":X19ABC123N01;", ":X19F15123N01;", ":S123N01;"]
    );
}

#[test]
fn filters_by_node_and_kind() {
    let events = monitor("hand-made.trace", &["--kind", "event"]);
    assert_eq!(events.len(), 7);
    assert!(events.iter().all(|l| l.contains("Event") || l.contains("Identified")));
    // By alias or by Node ID: every line names that node as source or destination.
    let by_alias = monitor("hand-made.trace", &["--node", "456"]);
    let by_id = monitor("hand-made.trace", &["--node", "05.01.01.01.22.01"]);
    assert_eq!(by_alias, by_id);
    assert!(by_alias.iter().all(|l| l.contains("456 05.01.01.01.22.01")));
    assert_eq!(by_alias.len(), 13);
    let out = Command::new(BIN)
        .args(["monitor", "--node", "xyz", "--from"])
        .arg(fixture("hand-made.trace"))
        .output()
        .unwrap();
    assert!(!out.status.success());
}
