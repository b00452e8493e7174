//! libFuzzer harness of rove_fuzz::web_page::web_page (the body lives in the rove-fuzz library).
#![no_main]

libfuzzer_sys::fuzz_target!(|data: &[u8]| rove_fuzz::web_page::web_page(data));
