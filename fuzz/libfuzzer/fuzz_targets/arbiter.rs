//! libFuzzer harness of rove_fuzz::arbiter::arbiter (the body lives in the rove-fuzz library).
#![no_main]

libfuzzer_sys::fuzz_target!(|data: &[u8]| rove_fuzz::arbiter::arbiter(data));
