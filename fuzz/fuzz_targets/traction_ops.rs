#![no_main]
libfuzzer_sys::fuzz_target!(|data: &[u8]| openlcb_node::fuzzing::traction_ops(data));
