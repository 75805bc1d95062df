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
