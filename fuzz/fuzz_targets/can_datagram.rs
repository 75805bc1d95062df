#![no_main]
libfuzzer_sys::fuzz_target!(|data: &[u8]| openlcb_can::fuzzing::can_datagram(data));
