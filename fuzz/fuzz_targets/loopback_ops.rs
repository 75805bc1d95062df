#![no_main]
use openlcb_loopback::fuzzing::{Op, loopback_ops};
libfuzzer_sys::fuzz_target!(|input: (u64, u16, bool, Vec<Op>)| loopback_ops(input.0, input.1, input.2, &input.3));
