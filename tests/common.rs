//! Helpers shared by the integration tests that run the `cell` binary.

use std::path::PathBuf;
use std::process::Command;

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
