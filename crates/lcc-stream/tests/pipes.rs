//! The tool and the files it writes into: a closed pipe ends a command quietly (as it ends
//! `grep`), and `monitor --from` holds at most one bounded line whatever it is fed.

mod common;

use std::io::Write as _;
use std::process::{Command, Stdio};

use common::BIN;

/// Runs the binary with `args` and its stdout closed before it writes anything (what
/// `| head -1` does once it has its line): it must exit with 0 and print nothing on stderr.
fn exits_quietly_on_a_closed_pipe(args: &[&str]) {
    let mut child = Command::new(BIN)
        .args(args)
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    drop(child.stdout.take());
    let out = child.wait_with_output().unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{args:?}: {:?}, stderr: {stderr}", out.status);
    assert!(!stderr.contains("panicked"), "{args:?}: {stderr}");
}

#[test]
fn completions_into_a_closed_pipe_exit_quietly() {
    exits_quietly_on_a_closed_pipe(&["completions", "bash"]);
}

#[test]
fn the_manual_page_into_a_closed_pipe_exits_quietly() {
    exits_quietly_on_a_closed_pipe(&["man"]);
}

#[test]
fn a_decoded_trace_into_a_closed_pipe_exits_quietly() {
    let trace = concat!(env!("CARGO_MANIFEST_DIR"), "/tests/fixtures/firmware-into-openmrn-bootloader.trace");
    exits_quietly_on_a_closed_pipe(&["monitor", "--from", trace]);
}

/// The peak resident memory of a running process, in KiB (`VmHWM` in /proc).
fn peak_kib(pid: u32) -> u64 {
    let status = std::fs::read_to_string(format!("/proc/{pid}/status")).unwrap();
    let line = status.lines().find(|l| l.starts_with("VmHWM:")).unwrap();
    line.split_whitespace().nth(1).unwrap().parse().unwrap()
}

#[test]
fn monitor_from_stdin_holds_no_unterminated_line_whole() {
    let mut child = Command::new(BIN)
        .args(["monitor", "--from", "-"])
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let mut stdin = child.stdin.take().unwrap();
    // 64 MiB without a newline, then a real frame on a line of its own.
    let zeros = vec![0u8; 1 << 20];
    for _ in 0..64 {
        stdin.write_all(&zeros).unwrap();
    }
    stdin.write_all(b"\n 1.000 :X19490123N;\n").unwrap();
    stdin.flush().unwrap();
    // Still running (its stdin is open): what it took at its peak for 64 MiB of one line.
    std::thread::sleep(std::time::Duration::from_millis(200));
    let peak = peak_kib(child.id());
    drop(stdin);
    let out = child.wait_with_output().unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    assert!(peak < 32 * 1024, "peak resident memory {peak} KiB for a 64 MiB line");
    let stdout = String::from_utf8(out.stdout).unwrap();
    let lines: Vec<&str> = stdout.lines().collect();
    assert_eq!(lines.len(), 2, "{stdout}");
    assert!(lines[0].contains("line 1 longer than 1024 bytes") && lines[0].contains("67108864 bytes"), "{}", lines[0]);
    assert!(lines[1].contains("Verify Node ID"), "{}", lines[1]);
}
