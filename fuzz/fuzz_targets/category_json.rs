//! Fuzz target: the `category_json` decoder of `graspcell::untrusted`.
#![no_main]

libfuzzer_sys::fuzz_target!(|data: &[u8]| {
    let _ = graspcell::untrusted::decode("category_json", data);
});
