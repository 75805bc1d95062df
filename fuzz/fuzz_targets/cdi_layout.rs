#![no_main]
libfuzzer_sys::fuzz_target!(|data: &[u8]| openlcb_cdi::fuzzing::cdi_layout(data));
