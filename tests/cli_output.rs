//! The `cell` binary's output edges: a reader that goes away early, and error
//! messages that name each cause once.

use std::os::fd::OwnedFd;
use std::os::unix::net::UnixStream;
use std::path::Path;
use std::process::{Command, Output, Stdio};

/// The shipped cell configuration.
fn config() -> std::path::PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("robot/cell.toml")
}

/// Runs `cell` with `args`, its stdout a stream whose reading end is already closed,
/// so every write gets `EPIPE` (as under `| head -c1`, without the race).
fn run_into_closed_pipe(args: &[&str]) -> Output {
    let (writer, reader) = UnixStream::pair().unwrap();
    drop(reader);
    Command::new(env!("CARGO_BIN_EXE_cell"))
        .arg("--config")
        .arg(config())
        .args(args)
        .stdout(Stdio::from(OwnedFd::from(writer)))
        .stderr(Stdio::piped())
        .output()
        .unwrap()
}

#[test]
fn json_into_a_closed_pipe_exits_zero_quietly() {
    for args in [
        &["fk", "--joints", "0,0.5,0,-1,0,0.5,0", "--json"][..],
        &["fk", "--joints", "0,0.5,0,-1,0,0.5,0"][..],
        &["print-config"][..],
    ] {
        let out = run_into_closed_pipe(args);
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert!(out.status.success(), "{args:?}: {:?} {stderr}", out.status);
        assert!(stderr.is_empty(), "{args:?}: {stderr}");
    }
}

/// Runs `cell` with `args` and returns the exit status and stderr.
fn run(args: &[&str]) -> (std::process::ExitStatus, String) {
    let out = Command::new(env!("CARGO_BIN_EXE_cell"))
        .args(args)
        .output()
        .unwrap();
    (
        out.status,
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

#[test]
fn errors_name_each_cause_once() {
    // A directory that is never created, so both files are missing.
    let dir = std::env::temp_dir().join(format!("graspcell-cli-output-{}", std::process::id()));
    let missing = dir.join("missing.toml");
    let missing = missing.to_str().unwrap();
    // ConfigError::Read around an I/O error.
    let (status, stderr) = run(&["--config", missing, "fk", "--joints", "0,0,0,0,0,0,0"]);
    assert!(!status.success());
    assert_eq!(stderr.lines().count(), 1, "{stderr}");
    assert!(stderr.starts_with("error: cannot read config "), "{stderr}");
    assert!(stderr.contains("missing.toml"), "{stderr}");
    assert_eq!(stderr.matches("os error 2").count(), 1, "{stderr}");

    // MeshError::File around an I/O error.
    let mesh = dir.join("missing.obj");
    let config = config();
    let (status, stderr) = run(&[
        "--config",
        config.to_str().unwrap(),
        "quality",
        "--object",
        mesh.to_str().unwrap(),
        "--pose",
        "0,0,0.2,0,0,0",
        "--json",
    ]);
    assert!(!status.success());
    assert_eq!(stderr.lines().count(), 1, "{stderr}");
    assert_eq!(stderr.matches("missing.obj").count(), 1, "{stderr}");
    assert_eq!(stderr.matches("os error 2").count(), 1, "{stderr}");
}
