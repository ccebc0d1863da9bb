//! Replays every input the fuzzers found (`tests/fuzz_regressions/<target>/`) and
//! the seed corpus of issue 21 through [`graspcell::untrusted::decode`] on stable:
//! each must decode to `Ok` or `Err`, never panic. A crash that `cargo fuzz`
//! finds is fixed in its decoder and its input is committed here.

use crate::common::root;
use graspcell::untrusted::{decode, TARGETS};

#[test]
fn every_fuzz_regression_input_decodes_without_panicking() {
    let dir = root().join("tests/fuzz_regressions");
    let mut replayed = 0;
    for entry in std::fs::read_dir(&dir).unwrap() {
        let target_dir = entry.unwrap().path();
        let target = target_dir
            .file_name()
            .unwrap()
            .to_str()
            .unwrap()
            .to_string();
        if !target_dir.is_dir() {
            continue;
        }
        assert!(
            TARGETS.contains(&target.as_str()),
            "{}: not a decoder (one of {TARGETS:?})",
            target_dir.display()
        );
        for input in std::fs::read_dir(&target_dir).unwrap() {
            let path = input.unwrap().path();
            let bytes = std::fs::read(&path).unwrap();
            let outcome = std::panic::catch_unwind(|| decode(&target, &bytes));
            assert!(outcome.is_ok(), "{}: the decoder panicked", path.display());
            replayed += 1;
        }
    }
    assert!(replayed > 0, "no regression inputs under {}", dir.display());
}
