//! `-v` and `RUST_LOG`: spans per hub client and per node, one line per stream event, and
//! nothing by default.

use std::process::Command;

const BIN: &str = env!("CARGO_BIN_EXE_lcc-stream");

fn demo_stderr(verbose: &[&str], rust_log: Option<&str>) -> String {
    let mut command = Command::new(BIN);
    command.args(verbose).args(["demo", "--bytes", "10000"]).env_remove("RUST_LOG");
    if let Some(filter) = rust_log {
        command.env("RUST_LOG", filter);
    }
    let output = command.output().unwrap();
    assert!(output.status.success(), "{output:?}");
    String::from_utf8_lossy(&output.stderr).into_owned()
}

#[test]
fn verbose_logs_clients_and_streams_in_their_spans() {
    let stderr = demo_stderr(&["-v"], None);
    assert!(stderr.contains("client{id=1"), "{stderr}");
    assert!(stderr.contains("Connected"), "{stderr}");
    assert!(stderr.contains("node{node_id=05.01.01.01.22.F1"), "{stderr}");
    assert_eq!(stderr.matches("stream opened").count(), 2, "{stderr}");
    assert_eq!(stderr.matches("stream finished").count(), 1, "{stderr}");
    assert!(!stderr.contains("\x1b["), "colours without a terminal: {stderr}");
}

#[test]
fn no_logs_by_default_and_rust_log_picks_the_detail() {
    assert_eq!(demo_stderr(&[], None), "");
    let stderr = demo_stderr(&[], Some("openlcb_tokio::driver=info"));
    assert!(stderr.contains("stream opened") && !stderr.contains("client{"), "{stderr}");
}
