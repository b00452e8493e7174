//! libFuzzer harness of rove_fuzz::console_api::console_api (the body lives in the rove-fuzz library).
#![no_main]

libfuzzer_sys::fuzz_target!(|data: &[u8]| rove_fuzz::console_api::console_api(data));
