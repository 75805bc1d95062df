#![no_main]
libfuzzer_sys::fuzz_target!(|data: &[u8]| openlcb_tcp::fuzzing::roundtrip(data));
