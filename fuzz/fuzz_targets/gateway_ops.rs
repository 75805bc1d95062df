#![no_main]
libfuzzer_sys::fuzz_target!(|data: &[u8]| openlcb_gateway::fuzzing::gateway_ops(data));
