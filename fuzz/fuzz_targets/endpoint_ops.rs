#![no_main]
libfuzzer_sys::fuzz_target!(|ops: Vec<openlcb_stream::fuzzing::Op>| openlcb_stream::fuzzing::endpoint_ops(&ops));
