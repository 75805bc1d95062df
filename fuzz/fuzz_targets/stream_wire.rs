#![no_main]
libfuzzer_sys::fuzz_target!(|data: &[u8]| openlcb_stream::fuzzing::stream_wire(data));
