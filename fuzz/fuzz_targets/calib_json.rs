//! Fuzz target: the `calib_json` decoder of `graspcell::untrusted`.
#![no_main]

libfuzzer_sys::fuzz_target!(|data: &[u8]| {
    let _ = graspcell::untrusted::decode("calib_json", data);
});
