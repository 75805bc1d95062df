#![no_main]
libfuzzer_sys::fuzz_target!(|data: &[u8]| openlcb_node::fuzzing::memconfig_server_ops(data));
