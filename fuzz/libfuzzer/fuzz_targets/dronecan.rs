//! libFuzzer harness of rove_fuzz::dronecan::dronecan (the body lives in the rove-fuzz library).
#![no_main]

libfuzzer_sys::fuzz_target!(|data: &[u8]| rove_fuzz::dronecan::dronecan(data));
