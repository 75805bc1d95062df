//! Runs one transfer of the benches, 1 MiB, a given number of times, for an instruction count.
//!
//! Criterion's wall times swing by 10-20 % on a shared machine; the instructions one run
//! executes do not depend on the machine's load. Count them with valgrind:
//!
//! ```text
//! cargo build --release -p openlcb-benches --example instructions
//! valgrind --tool=callgrind --callgrind-out-file=/dev/null \
//!     target/release/examples/instructions stream-2048 3
//! ```
//!
//! valgrind prints `Collected : N`, the instructions of the whole program (start-up included,
//! the same for every transfer). The transfers, with their criterion bench:
//! - `stream-2048`, `stream-65535`: two endpoints back to back (`stream_transfer/window/W`);
//! - `can-2048`: through two `CanLink`s (`can_stream_transfer/window_2048`).

use std::process::ExitCode;

use openlcb_benches::{transfer_back_to_back, transfer_over_can};

const BYTES: usize = 1 << 20;

fn main() -> ExitCode {
    let mut args = std::env::args().skip(1);
    let transfer: fn() -> usize = match args.next().as_deref() {
        Some("stream-2048") => || transfer_back_to_back(BYTES, 2048),
        Some("stream-65535") => || transfer_back_to_back(BYTES, 65535),
        Some("can-2048") => || transfer_over_can(BYTES, 2048),
        _ => return usage(),
    };
    let Some(Ok(times)) = args.next().map(|n| n.parse::<u32>()) else { return usage() };
    for _ in 0..times {
        let moved = std::hint::black_box(transfer());
        if moved != BYTES {
            eprintln!("the transfer moved {moved} bytes, not {BYTES}");
            return ExitCode::FAILURE;
        }
    }
    ExitCode::SUCCESS
}

fn usage() -> ExitCode {
    eprintln!("usage: instructions stream-2048|stream-65535|can-2048 TIMES");
    ExitCode::from(2)
}
