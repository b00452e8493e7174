//! libFuzzer harness of rove_fuzz::site::site (the body lives in the rove-fuzz library).
#![no_main]

libfuzzer_sys::fuzz_target!(|data: &[u8]| rove_fuzz::site::site(data));
