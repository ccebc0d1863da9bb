//! Every file shipped under `robot/` (and later `calib/`, `systemd/`) parses.

use graspcell::config::CellConfig;
use graspcell::robot::Robot;
use std::path::{Path, PathBuf};

fn files_under(dir: &str) -> Vec<PathBuf> {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join(dir);
    let mut files = Vec::new();
    let mut stack = vec![root];
    while let Some(d) = stack.pop() {
        for entry in std::fs::read_dir(&d).unwrap() {
            let path = entry.unwrap().path();
            if path.is_dir() {
                stack.push(path);
            } else {
                files.push(path);
            }
        }
    }
    files.sort();
    files
}

#[test]
fn every_file_under_robot_parses() {
    let files = files_under("robot");
    assert!(!files.is_empty());
    let mut urdfs = 0;
    for path in &files {
        match path.extension().and_then(|e| e.to_str()) {
            Some("toml") => {
                let config = CellConfig::load(path).unwrap_or_else(|e| panic!("{e}"));
                Robot::load(&config).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
            }
            Some("urdf") => {
                let text = std::fs::read_to_string(path).unwrap();
                urdf_rs::read_from_string(&text)
                    .unwrap_or_else(|e| panic!("{}: {e}", path.display()));
                urdfs += 1;
            }
            _ => panic!(
                "{}: unexpected file type under robot/; teach this test to parse it",
                path.display()
            ),
        }
    }
    assert!(urdfs >= 1);
}
