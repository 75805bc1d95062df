//! `send`'s progress display under a pseudo-terminal 40 columns wide (util-linux `script`
//! provides the terminal): it is redrawn in place and never wider than the terminal, so it
//! stays on one line; without a terminal nothing is drawn.

use std::process::{Command, Stdio};
use std::time::Duration;

use openlcb_tokio::{Framing, Hub, HubOptions, Node, NodeOptions};

const BIN: &str = env!("CARGO_BIN_EXE_lcc-stream");
const RECEIVER: &str = "05.01.01.01.22.F1";
const LIMIT: Duration = Duration::from_secs(120);

/// What a terminal shows of `raw` line by line: escape sequences removed, and each carriage
/// return starting the line over. Returns every piece drawn (so that overwritten drawings are
/// checked too) and the number of line feeds.
fn drawn_pieces(raw: &str) -> (Vec<String>, usize) {
    let mut pieces = Vec::new();
    let mut current = String::new();
    let mut chars = raw.chars().peekable();
    let mut line_feeds = 0;
    while let Some(c) = chars.next() {
        match c {
            '\x1b' => {
                // CSI: ESC [ parameters final-byte.
                if chars.next_if_eq(&'[').is_some() {
                    for c in chars.by_ref() {
                        if c.is_ascii_alphabetic() {
                            break;
                        }
                    }
                }
            }
            '\r' | '\n' => {
                line_feeds += usize::from(c == '\n');
                pieces.push(std::mem::take(&mut current));
            }
            c => current.push(c),
        }
    }
    pieces.push(current);
    (pieces.into_iter().filter(|p| !p.trim().is_empty()).collect(), line_feeds)
}

/// Sends `len` bytes with `lcc-stream send` to a slow in-process receiver, run by the program
/// and arguments `wrap` makes of the shell command; returns what that program printed.
async fn send_through(wrap: fn(&str) -> Vec<String>, len: usize) -> String {
    let dir = std::env::temp_dir().join(format!("lcc-stream-progress-{}-{len}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    let input = dir.join("input.bin");
    std::fs::write(&input, vec![0x5A; len]).unwrap();
    let hub = Hub::bind("127.0.0.1:0", None, HubOptions::default()).await.unwrap();
    let addr = hub.local_addr().to_string();
    let mut options = NodeOptions::new(RECEIVER.parse().unwrap());
    options.node.stream.max_window = 512;
    let mut receiver = Node::connect(&addr, Framing::GridConnect, options).await.unwrap();
    let reading = tokio::spawn(async move {
        let mut stream = receiver.accept().await.unwrap();
        // A slow reader, so that the transfer lasts long enough to be drawn several times.
        while stream.read().await.unwrap().is_some() {
            tokio::time::sleep(Duration::from_millis(2)).await;
        }
        stream.received()
    });
    let command = format!("{BIN} send {} --to {RECEIVER} --window 512 --connect {addr}", input.display());
    let args = wrap(&command);
    let output = tokio::time::timeout(
        LIMIT,
        tokio::process::Command::new(&args[0]).args(&args[1..]).stdin(Stdio::null()).kill_on_drop(true).output(),
    )
    .await
    .expect("send did not finish")
    .unwrap();
    assert!(output.status.success(), "{output:?}");
    assert_eq!(tokio::time::timeout(LIMIT, reading).await.unwrap().unwrap(), len as u64);
    let _ = std::fs::remove_dir_all(dir);
    String::from_utf8_lossy(&output.stdout).into_owned() + &String::from_utf8_lossy(&output.stderr)
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn progress_stays_on_one_line_of_a_40_column_terminal() {
    assert!(
        Command::new("script").arg("--version").stdout(Stdio::null()).status().is_ok_and(|s| s.success()),
        "this test needs util-linux `script` for a pseudo-terminal"
    );
    let in_terminal = |command: &str| {
        let script = format!("stty cols 40 rows 24; exec {command}");
        ["script", "-qefc", &script, "/dev/null"].map(String::from).to_vec()
    };
    let raw = send_through(in_terminal, 400_000).await;
    let (pieces, line_feeds) = drawn_pieces(&raw);
    let drawings: Vec<&String> = pieces.iter().filter(|p| p.contains("MB/s") || p.contains("kB/s")).collect();
    assert!(drawings.len() >= 2, "expected the progress to be drawn at least once before the result: {raw:?}");
    for drawing in &drawings[..drawings.len() - 1] {
        assert!(drawing.chars().count() <= 40, "wider than 40 columns: {drawing:?} in {raw:?}");
    }
    // The only line feed is the one after the result: every drawing was redrawn in place.
    assert_eq!(line_feeds, 1, "{raw:?}");
    assert!(pieces.last().unwrap().starts_with("sent 400000 bytes"), "{raw:?}");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn without_a_terminal_no_progress_is_drawn() {
    let raw = send_through(|command| ["sh", "-c", command].map(String::from).to_vec(), 100_000).await;
    let (pieces, line_feeds) = drawn_pieces(&raw);
    assert_eq!(line_feeds, 1, "{raw:?}");
    assert_eq!(pieces.len(), 1, "{raw:?}");
}
