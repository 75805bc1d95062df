//! What the tool prints on stdout goes through here, so that a closed pipe
//! (`lcc-stream events identify | head -1`) ends the tool quietly, as it ends `grep`, instead
//! of the panic of `println!`.

use std::io::Write as _;

/// Prints a line on stdout (see [`write()`]).
macro_rules! outln {
    ($($arg:tt)*) => { $crate::stdout::write(format_args!("{}\n", format_args!($($arg)*))) };
}

/// Prints on stdout without a newline (see [`write()`]).
macro_rules! out {
    ($($arg:tt)*) => { $crate::stdout::write(format_args!($($arg)*)) };
}

/// Writes `text` on stdout. When the reader has gone (a closed pipe) the tool exits at once
/// with status 0: whoever read the output has what it wanted. Any other error is reported on
/// stderr once per write and the output goes on.
pub(crate) fn write(text: std::fmt::Arguments<'_>) {
    let mut stdout = std::io::stdout().lock();
    let written = stdout.write_fmt(text);
    exit_if_closed(written);
}

/// Writes `bytes` on stdout, as [`write()`] does; other errors are returned.
pub(crate) fn write_bytes(bytes: &[u8]) -> std::io::Result<()> {
    let mut stdout = std::io::stdout().lock();
    let written = stdout.write_all(bytes).and_then(|()| stdout.flush());
    if written.as_ref().is_err_and(is_closed) {
        std::process::exit(0);
    }
    written
}

fn is_closed(error: &std::io::Error) -> bool {
    error.kind() == std::io::ErrorKind::BrokenPipe
}

/// Ends the tool quietly when `result` is a closed pipe; reports other errors on stderr.
fn exit_if_closed(result: std::io::Result<()>) {
    match result {
        Ok(()) => {}
        Err(error) if is_closed(&error) => std::process::exit(0),
        Err(error) => eprintln!("lcc-stream: cannot write to stdout: {error}"),
    }
}
