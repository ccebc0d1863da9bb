//! Helpers shared by the integration tests that run the `cell` binary.

use std::path::PathBuf;
use std::process::Command;
use std::sync::atomic::{AtomicUsize, Ordering};

/// The repository root.
pub fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

/// The shipped cell configuration, `robot/cell.toml`.
pub fn config_path() -> String {
    root()
        .join("robot/cell.toml")
        .to_string_lossy()
        .into_owned()
}

/// A fresh directory for one test (`graspcell-<suite>-<name>-<pid>-<n>`); the test
/// removes it.
pub fn temp_dir(suite: &str, name: &str) -> PathBuf {
    static COUNTER: AtomicUsize = AtomicUsize::new(0);
    let dir = std::env::temp_dir().join(format!(
        "graspcell-{suite}-{name}-{}-{}",
        std::process::id(),
        COUNTER.fetch_add(1, Ordering::SeqCst)
    ));
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

/// Runs the `cell` binary from the repository root with the shipped configuration;
/// returns success, stdout, stderr.
pub fn cell(args: &[&str]) -> (bool, String, String) {
    let out = Command::new(env!("CARGO_BIN_EXE_cell"))
        .current_dir(root())
        .arg("--config")
        .arg(config_path())
        .args(args)
        .output()
        .unwrap();
    (
        out.status.success(),
        String::from_utf8_lossy(&out.stdout).into_owned(),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}
