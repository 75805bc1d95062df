#![no_main]
libfuzzer_sys::fuzz_target!(|data: &[u8]| openlcb_node::fuzzing::clock_ops(data));
