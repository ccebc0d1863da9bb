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

/// A unit file as (section, key, value) triples; panics naming the file and line on
/// anything that is not a comment, a `[Section]` or a `Key=value` line.
fn parse_unit(path: &Path) -> Vec<(String, String, String)> {
    let text = std::fs::read_to_string(path).unwrap();
    let mut section = String::new();
    let mut entries = Vec::new();
    for (n, line) in text.lines().enumerate() {
        let line = line.trim();
        if line.is_empty() || line.starts_with('#') || line.starts_with(';') {
            continue;
        }
        if let Some(name) = line.strip_prefix('[').and_then(|l| l.strip_suffix(']')) {
            section = name.to_string();
            continue;
        }
        let (key, value) = line
            .split_once('=')
            .unwrap_or_else(|| panic!("{}:{}: not Key=value: {line}", path.display(), n + 1));
        assert!(
            !section.is_empty(),
            "{}:{}: key outside a section",
            path.display(),
            n + 1
        );
        entries.push((
            section.clone(),
            key.trim().to_string(),
            value.trim().to_string(),
        ));
    }
    entries
}

#[test]
fn every_systemd_unit_parses_and_is_hardened() {
    let files = files_under("systemd");
    let get = |entries: &[(String, String, String)], key: &str| {
        entries
            .iter()
            .find(|(s, k, _)| s == "Service" && k == key)
            .map(|(_, _, v)| v.clone())
    };
    let mut services = 0;
    for path in &files {
        let entries = parse_unit(path);
        let name = path.file_name().unwrap().to_str().unwrap();
        if name.ends_with(".target") {
            assert!(
                entries.iter().any(|(s, k, _)| s == "Unit" && k == "Wants"),
                "{name}"
            );
            continue;
        }
        assert!(
            name.ends_with(".service"),
            "{name}: unexpected file under systemd/"
        );
        services += 1;
        for (key, value) in [
            ("Type", "notify"),
            ("Restart", "on-failure"),
            ("NoNewPrivileges", "yes"),
            ("ProtectSystem", "strict"),
            ("ProtectHome", "yes"),
            ("PrivateTmp", "yes"),
        ] {
            assert_eq!(get(&entries, key).as_deref(), Some(value), "{name}: {key}");
        }
        assert!(get(&entries, "WatchdogSec").is_some(), "{name}: watchdog");
        let families = get(&entries, "RestrictAddressFamilies").unwrap();
        let executor = name == "cell-execute.service";
        assert!(families.contains("AF_UNIX"), "{name}");
        assert_eq!(
            families.contains("AF_INET"),
            executor,
            "{name}: AF_INET only for FRI"
        );
        assert_eq!(
            families.contains("AF_CAN"),
            executor,
            "{name}: AF_CAN only for the hand"
        );
        assert_eq!(
            get(&entries, "CPUSchedulingPolicy").is_some(),
            executor,
            "{name}: real time"
        );
        assert_eq!(
            get(&entries, "LimitMEMLOCK").is_some(),
            executor,
            "{name}: memlock"
        );
    }
    assert_eq!(services, 5, "one unit per stage");
}
