//! Argument validation of the built `lcc-stream` binary: every bad value is refused by clap
//! with exit status 2 and a message that says what is expected; nothing connects.

use std::process::{Command, Output};

const BIN: &str = env!("CARGO_BIN_EXE_lcc-stream");

fn run(args: &[&str]) -> Output {
    Command::new(BIN).args(args).output().unwrap()
}

/// Runs `args`, expects exit status 2 and returns stderr.
fn refused(args: &[&str]) -> String {
    let output = run(args);
    let stderr = String::from_utf8_lossy(&output.stderr).into_owned();
    assert_eq!(output.status.code(), Some(2), "{args:?}: {stderr}");
    stderr
}

#[test]
fn zero_timeouts_bitrates_and_queues_are_refused() {
    for args in [
        &["send", "f", "--to", "05.01.01.01.22.F1", "--timeout", "0"][..],
        &["recv", "--timeout", "0"],
        &["sim", "--bandwidth", "0"],
        &["hub", "--max-queue", "0"],
        &["hub", "--drain-timeout", "0"],
    ] {
        assert!(refused(args).contains("must be at least 1"), "{args:?}");
    }
    assert!(refused(&["sim", "--latency=-1"]).contains("milliseconds"));
    assert!(refused(&["sim", "--bitrate", "0"]).contains("10000..=1000000"));
}

#[test]
fn a_hub_address_without_a_port_is_refused_with_exit_2() {
    let stderr = refused(&["recv", "--connect", "127.0.0.1"]);
    assert!(stderr.contains("HOST:PORT") && stderr.contains("no port"), "{stderr}");
}

#[test]
fn a_malformed_node_id_names_every_accepted_form() {
    let stderr = refused(&["send", "f", "--to", "05.01.01"]);
    for form in ["05.01.01.01.22.F1", "05:01:01:01:22:F1", "0501010122F1", "0x0501010122F1"] {
        assert!(stderr.contains(form), "{form} missing from: {stderr}");
    }
}

#[test]
fn reserved_node_ids_are_refused() {
    for id in ["00.00.00.00.00.00", "FF.FF.FF.FF.FF.FF", "0x000000000001"] {
        assert!(refused(&["recv", "--node-id", id]).contains("reserved"), "{id}");
    }
}

#[test]
fn pasted_node_id_forms_get_past_argument_parsing() {
    // An unreachable hub (a port nobody listens on) is exit 3: the Node ID was accepted.
    let port = std::net::TcpListener::bind("127.0.0.1:0").unwrap().local_addr().unwrap().port();
    let addr = format!("127.0.0.1:{port}");
    for id in ["05:01:01:01:22:F1", "0501010122F1", "0x0501010122F1"] {
        let output = run(&["nodes", "--node-id", id, "--connect", &addr]);
        assert_eq!(output.status.code(), Some(3), "{id}: {}", String::from_utf8_lossy(&output.stderr));
    }
}

#[test]
fn demo_early_proceed_is_a_switch_like_recv_and_sim() {
    let stderr = refused(&["demo", "--early-proceed", "true"]);
    assert!(stderr.contains("unexpected argument"), "{stderr}");
    for command in ["demo", "recv", "sim"] {
        let help = String::from_utf8_lossy(&run(&[command, "--help"]).stdout).into_owned();
        assert!(help.contains("--early-proceed  ") || help.contains("--early-proceed\n"), "{command}: {help}");
    }
}

#[test]
fn each_command_lists_the_exit_statuses_it_can_return() {
    let top = String::from_utf8_lossy(&run(&["--help"]).stdout).into_owned();
    assert!(top.contains("Each command's --help lists the exit statuses"), "{top}");
    let sim = String::from_utf8_lossy(&run(&["sim", "--help"]).stdout).into_owned();
    assert!(sim.contains("Exit status") && sim.contains("2 bad arguments"), "{sim}");
    let help = |command: &str| String::from_utf8_lossy(&run(&[command, "--help"]).stdout).into_owned();
    // The hub never looks for a node; read does, and never verifies like the demo.
    let hub = help("hub");
    assert!(hub.contains("130  interrupted") && !hub.contains("not_found"), "{hub}");
    let read = help("read");
    assert!(read.contains("  5  not_found") && read.contains("  8  file_error"), "{read}");
    assert!(!read.contains("verify_failed"), "{read}");
    assert!(help("demo").contains("  9  verify_failed"));
    assert!(help("nodes").contains(" 10  duplicate_node_id"));
}

#[test]
fn sim_refuses_a_bitrate_it_cannot_simulate() {
    for bitrate in ["1", "9999", "2000000"] {
        let stderr = refused(&["sim", "--bitrate", bitrate]);
        assert!(stderr.contains("10000..=1000000"), "{bitrate}: {stderr}");
    }
    assert!(run(&["sim", "--bitrate", "10000", "--bytes", "1024"]).status.success());
}
