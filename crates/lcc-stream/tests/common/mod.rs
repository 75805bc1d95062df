//! What the binary's test files share: the binary, a bounded wait, a scratch folder, and a
//! child process with piped output that dies with the test.

// Each test file uses what it needs of this module.
#![allow(dead_code)]

use std::future::Future;
use std::path::PathBuf;
use std::process::Stdio;
use std::time::Duration;

use tokio::process::{Child, Command};

/// The longest any one wait of a test may take.
pub(crate) const LIMIT: Duration = Duration::from_secs(120);
/// The binary under test.
pub(crate) const BIN: &str = env!("CARGO_BIN_EXE_lcc-stream");

/// `future`, or a panic naming `what` after [`LIMIT`].
pub(crate) async fn bounded<T>(what: &str, future: impl Future<Output = T>) -> T {
    match tokio::time::timeout(LIMIT, future).await {
        Ok(value) => value,
        Err(_) => panic!("{what} did not finish within {LIMIT:?}"),
    }
}

/// A fresh, empty directory for one test.
pub(crate) fn scratch(test: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("lcc-stream-test-{}-{test}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

/// The binary with `args`, stdin closed, stdout and stderr piped, killed when dropped.
pub(crate) fn command(args: &[&str]) -> Command {
    let mut command = Command::new(BIN);
    command.args(args).stdin(Stdio::null()).stdout(Stdio::piped()).stderr(Stdio::piped()).kill_on_drop(true);
    command
}

/// The binary with `args`, started.
pub(crate) fn spawn(args: &[&str]) -> Child {
    command(args).spawn().unwrap()
}

/// A raw GridConnect client of a hub: a peer on the bus that sends frames as text and reads
/// what the hub relays, line by line.
pub(crate) struct Bus {
    lines: tokio::io::Lines<tokio::io::BufReader<tokio::net::tcp::OwnedReadHalf>>,
    writer: tokio::net::tcp::OwnedWriteHalf,
}

impl Bus {
    pub(crate) async fn connect(addr: &str) -> Bus {
        use tokio::io::AsyncBufReadExt as _;
        let socket = bounded("connect", tokio::net::TcpStream::connect(addr)).await.unwrap();
        let (reader, writer) = socket.into_split();
        Bus { lines: tokio::io::BufReader::new(reader).lines(), writer }
    }

    /// Writes `text` (frames, each ending with `;` and a newline).
    pub(crate) async fn send(&mut self, text: &str) {
        use tokio::io::AsyncWriteExt as _;
        bounded("a write to the hub", self.writer.write_all(text.as_bytes())).await.unwrap();
    }

    /// Reads frames until one satisfies `wanted` (named `what`), and returns it.
    pub(crate) async fn until(&mut self, what: &str, wanted: impl Fn(&str) -> bool) -> String {
        bounded(what, async {
            while let Some(line) = self.lines.next_line().await.unwrap() {
                if wanted(&line) {
                    return line;
                }
            }
            panic!("the hub closed the connection before {what}");
        })
        .await
    }

    /// Sends a global Verify Node ID from `alias` and waits for the Verified Node ID of
    /// `node` (`05.01.01.01.22.E4`): by then that node has handled every frame sent before.
    pub(crate) async fn settle(&mut self, alias: u16, node: &str) {
        self.send(&format!(":X19490{alias:03X}N;\n")).await;
        let verified = format!("N{};", node.replace('.', ""));
        self.until("the Verified Node ID", |l| l.starts_with(":X19170") && l.ends_with(&verified)).await;
    }
}

/// `count` Producer/Consumer Event Reports from `alias`, of the events `first`, `first + 1`...
/// wrapping within the lowest `span` IDs (a power of two), as GridConnect text.
pub(crate) fn reports(alias: u16, first: u64, span: u64, count: usize) -> String {
    (0..count as u64).map(|i| format!(":X195B4{alias:03X}N{:016X};\n", first + i % span)).collect()
}

/// Reads lines of `lines` until one contains `needle`, and returns it.
pub(crate) async fn until<R: tokio::io::AsyncRead + Unpin>(
    lines: &mut tokio::io::Lines<tokio::io::BufReader<R>>,
    needle: &str,
) -> String {
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

/// Sends SIGINT (Ctrl-C) to a child.
pub(crate) async fn interrupt(child: &Child) {
    let pid = child.id().unwrap().to_string();
    let status = Command::new("kill").args(["-INT", &pid]).status().await.unwrap();
    assert!(status.success());
}
