//! Fuzz target: the `ply` decoder of `graspcell::untrusted`.
#![no_main]

libfuzzer_sys::fuzz_target!(|data: &[u8]| {
    let _ = graspcell::untrusted::decode("ply", data);
});
