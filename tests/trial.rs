//! The trial log end to end: crash safety under SIGKILL, the sign test against exact
//! integer arithmetic, CSV import/export, and bad input through the `cell` binary.

use graspcell::fsio::TempDir;
use graspcell::geometry::PoseJson;
use graspcell::trial::{
    FailureCause, Grade, GradeSource, Grading, NewTrial, ObjectRef, Placement, Report, Scope,
    TrialError, TrialId, TrialLog, UtcTimestamp,
};
use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
fn trial(method: &str, object: u32, placement: u32) -> NewTrial {
    NewTrial {
        started_at: UtcTimestamp::from_unix_ms(1_740_000_000_000 + i64::from(object) * 60_000),
        category: "mug".into(),
        task: "pour".into(),
        method: method.into(),
        object: ObjectRef {
            name: format!("mug-novel-{object}"),
            seed: Some(u64::from(object) + 100),
        },
        placement: Placement {
            index: placement,
            base_from_object: PoseJson {
                xyz: [0.5 + 0.01 * f64::from(placement), -0.1, 0.0],
                rpy: Some([0.0, 0.0, 0.3 * f64::from(placement)]),
                quat_xyzw: None,
            },
        },
        campaign_id: Some("test-campaign".into()),
        snapshot_path: Some(PathBuf::from(format!("snapshots/{object}-{placement}.pcd"))),
        fits: serde_json::json!([{"model": "mug-1", "eps": 0.01}]),
        planned_pose: None,
        planned_joints: None,
        outcome: Some(serde_json::json!({"lifted": true})),
        seeds: [("plan".to_string(), 7_u64)].into(),
    }
}

fn at(s: i64) -> UtcTimestamp {
    UtcTimestamp::from_unix_ms(1_750_000_000_000 + s * 1000)
}

fn grading(grade: Grade, cause: Option<FailureCause>) -> Grading {
    Grading::new(grade, cause, None).unwrap()
}

/// C(n, k) exactly, by the multiplicative formula (every intermediate is an integer).
fn binomial(n: u128, k: u128) -> u128 {
    (0..k).fold(1, |c, i| c * (n - i) / (i + 1))
}

/// 2 * sum_{k <= m} C(n, k) / 2^n, summed exactly in integers, then one rounding.
fn exact_two_sided_p(n: u128, m: u128) -> f64 {
    let tail: u128 = (0..=m).map(|k| binomial(n, k)).sum();
    (2.0 * tail as f64 / 2f64.powi(n as i32)).min(1.0)
}

/// Records a campaign of two methods whose grades give `wins` / `losses` / `ties`
/// for `a` against `b` (wins: a success vs b failure, alternating with a partial vs b
/// failure; losses: a failure vs b success; ties: equal grades).
fn paired_campaign(log: &mut TrialLog, wins: u32, losses: u32, ties: u32) {
    use FailureCause::*;
    use Grade::*;
    let mut pairs = Vec::new();
    for i in 0..wins {
        let a = if i % 2 == 0 { Success } else { Partial };
        pairs.push((a, Failure));
    }
    pairs.extend((0..losses).map(|_| (Failure, Success)));
    pairs.extend((0..ties).map(|i| {
        if i % 2 == 0 {
            (Partial, Partial)
        } else {
            (Success, Success)
        }
    }));
    for (i, (ga, gb)) in pairs.into_iter().enumerate() {
        let (object, placement) = (i as u32 / 5, i as u32 % 5);
        for (method, g) in [("a", ga), ("b", gb)] {
            let id = log.record_trial(&trial(method, object, placement)).unwrap();
            let cause = (g == Failure).then_some(if i % 3 == 0 {
                Registration
            } else {
                ShapeDissimilarity
            });
            log.grade(id, &grading(g, cause), GradeSource::Simulated, at(i as i64))
                .unwrap();
        }
    }
}

#[test]
fn sign_test_p_values_equal_exact_integer_computation() {
    let dir = TempDir::new("trial-signtest").unwrap();
    for (wins, losses, ties) in [(20_u32, 2_u32, 6_u32), (70, 40, 3), (9, 11, 0), (0, 0, 4)] {
        let path = dir.join(format!("{wins}-{losses}-{ties}.sqlite"));
        let mut log = TrialLog::open(&path).unwrap();
        paired_campaign(&mut log, wins, losses, ties);
        let report = Report::from_trials(&log.trials().unwrap(), Scope::campaign("test-campaign"));
        assert_eq!(report.sign_tests.len(), 1);
        let t = &report.sign_tests[0];
        assert_eq!((t.a.as_str(), t.b.as_str()), ("a", "b"));
        let s = t.test.test;
        assert_eq!(
            (s.wins, s.losses, s.ties, s.n),
            (
                wins.into(),
                losses.into(),
                ties.into(),
                u64::from(wins + losses)
            )
        );
        let n = u128::from(wins + losses);
        let want = if n == 0 {
            1.0
        } else {
            exact_two_sided_p(n, u128::from(wins.min(losses)))
        };
        let rel = (s.p_value - want).abs() / want;
        assert!(rel < 1e-12, "{wins}/{losses}: {} vs {want}", s.p_value);
    }
    // The brief's case written out: 2 * (1 + 22 + 231) / 2^22.
    assert_eq!(exact_two_sided_p(22, 2), 508.0 / 4_194_304.0);
}

#[test]
fn report_counts_the_failure_table_from_the_log() {
    let dir = TempDir::new("trial-report").unwrap();
    let mut log = TrialLog::open(dir.join("t.sqlite")).unwrap();
    paired_campaign(&mut log, 20, 2, 6);
    let r = Report::from_trials(&log.trials().unwrap(), Scope::default());
    // b fails in 20 of 28 pairs (wins of a); a fails in 2 (losses).
    let b = &r.methods[1];
    assert_eq!((b.graded, b.failure), (28, 20));
    let total = &r.failure_causes.total;
    assert_eq!(total.counts, vec![2, 20]);
    assert!((total.percent[1].unwrap() - 2000.0 / 28.0).abs() < 1e-9);
    // Causes: pair i fails by registration when i % 3 == 0, else shape dissimilarity.
    let reg_b = (0..20).filter(|i| i % 3 == 0).count() as u64;
    let reg_row = r
        .failure_causes
        .rows
        .iter()
        .find(|r| r.cause == "registration")
        .unwrap();
    let shape_row = r
        .failure_causes
        .rows
        .iter()
        .find(|r| r.cause == "shape-dissimilarity")
        .unwrap();
    assert_eq!(reg_row.counts[1], reg_b);
    assert_eq!(shape_row.counts[1], 20 - reg_b);
    let charts = graspcell::trial::plot::write_charts(&r, &dir.join("png")).unwrap();
    for c in charts {
        let bytes = std::fs::read(&c).unwrap();
        assert_eq!(&bytes[..8], b"\x89PNG\r\n\x1a\n", "{}", c.display());
    }
}

#[test]
fn regrading_keeps_history_and_unknown_trials_change_nothing() {
    let dir = TempDir::new("trial-regrade").unwrap();
    let mut log = TrialLog::open(dir.join("t.sqlite")).unwrap();
    let id = log.record_trial(&trial("laplace", 1, 0)).unwrap();
    let first = grading(Grade::Failure, Some(FailureCause::Registration));
    let second = Grading::new(Grade::Partial, None, Some("re-watched the video".into())).unwrap();
    assert_eq!(
        log.grade(id, &first, GradeSource::Observer, at(1)).unwrap(),
        None
    );
    assert_eq!(
        log.grade(id, &second, GradeSource::Command, at(2)).unwrap(),
        Some(first.clone())
    );
    let history = log.grade_history(id).unwrap();
    assert_eq!(history.len(), 2);
    assert_eq!(
        (&history[0].grading, history[0].source),
        (&first, GradeSource::Observer)
    );
    assert_eq!(
        (&history[1].grading, history[1].graded_at),
        (&second, at(2))
    );
    let rec = log.trial(id).unwrap();
    assert_eq!(
        (rec.grading, rec.graded_at),
        (Some(second.clone()), Some(at(2)))
    );

    let err = log
        .grade(id + 7, &first, GradeSource::Command, at(3))
        .unwrap_err();
    assert!(matches!(err, TrialError::UnknownTrial { .. }), "{err:?}");
    assert!(err
        .to_string()
        .contains(&format!("no trial with id {}", id + 7)));
    assert_eq!(log.grade_history(id).unwrap().len(), 2);
    assert_eq!(log.grade_history(id + 7).unwrap().len(), 0);
    assert_eq!(log.trial_count().unwrap(), 1);
    assert_eq!(log.integrity_check().unwrap(), "ok");
}

#[test]
fn export_then_import_round_trips_grades() {
    let dir = TempDir::new("trial-csv").unwrap();
    let (src_path, dst_path) = (dir.join("src.sqlite"), dir.join("dst.sqlite"));
    let mut src = TrialLog::open(&src_path).unwrap();
    let mut dst = TrialLog::open(&dst_path).unwrap();
    let gradings = [
        Some(
            Grading::new(
                Grade::Success,
                None,
                Some("clean, \"textbook\" lift".into()),
            )
            .unwrap(),
        ),
        Some(
            Grading::new(
                Grade::Failure,
                Some(FailureCause::ShapeDissimilarity),
                Some("hit\nthe rim".into()),
            )
            .unwrap(),
        ),
        None,
        Some(grading(Grade::Partial, Some(FailureCause::Execution))),
        Some(grading(Grade::Failure, Some(FailureCause::Reachability))),
    ];
    for (i, g) in gradings.iter().enumerate() {
        let t = trial(
            if i % 2 == 0 { "laplace" } else { "best-single" },
            i as u32,
            1,
        );
        let a = src.record_trial(&t).unwrap();
        let b = dst.record_trial(&t).unwrap();
        assert_eq!(a, b);
        if let Some(g) = g {
            src.grade(a, g, GradeSource::Observer, at(i as i64))
                .unwrap();
        }
    }
    let csv_path = dir.join("grades.csv");
    std::fs::write(&csv_path, src.export_csv().unwrap()).unwrap();
    let summary = dst.import_grades_csv(&csv_path, at(100)).unwrap();
    assert_eq!(
        (
            summary.rows,
            summary.graded,
            summary.unchanged,
            summary.blank
        ),
        (5, 4, 0, 1)
    );
    let got: Vec<Option<Grading>> = dst
        .trials()
        .unwrap()
        .into_iter()
        .map(|t| t.grading)
        .collect();
    assert_eq!(got, gradings.to_vec());
    // Importing again changes nothing and adds no history.
    let again = dst.import_grades_csv(&csv_path, at(200)).unwrap();
    assert_eq!((again.graded, again.unchanged), (0, 4));
    assert_eq!(dst.grade_history(1).unwrap().len(), 1);
    // Both logs now export the same grades (the first four columns).
    let src_rows = graspcell::trial::csv::parse_csv(&src.export_csv().unwrap(), &csv_path).unwrap();
    let dst_rows = graspcell::trial::csv::parse_csv(&dst.export_csv().unwrap(), &csv_path).unwrap();
    for (a, b) in src_rows.iter().zip(&dst_rows) {
        assert_eq!(a.fields[..4], b.fields[..4]);
    }
    assert_eq!(src_rows.len(), 6);
    assert_eq!(dst_rows.len(), 6);
}

#[test]
fn a_bad_csv_line_imports_nothing() {
    let dir = TempDir::new("trial-csvbad").unwrap();
    let mut log = TrialLog::open(dir.join("t.sqlite")).unwrap();
    for i in 0..3 {
        log.record_trial(&trial("laplace", i, 0)).unwrap();
    }
    log.grade(
        1,
        &grading(Grade::Success, None),
        GradeSource::Observer,
        at(0),
    )
    .unwrap();
    let before: Vec<_> = log.trials().unwrap();
    for (csv, line, needle) in [
        // Line 4 names a trial that does not exist: rows 2 and 3 must not be applied.
        (
            "trial_id,grade,cause,note\n1,failure,other,\n2,partial,,\n99,success,,\n",
            4,
            "no trial with id 99",
        ),
        (
            "trial_id,grade,cause,note\n1,failure,other,\n2,excellent,,\n",
            3,
            "invalid grade",
        ),
        (
            "trial_id,grade,cause,note\n1,failure,,\n",
            2,
            "needs a cause",
        ),
    ] {
        let path = dir.join("bad.csv");
        std::fs::write(&path, csv).unwrap();
        let err = log.import_grades_csv(&path, at(9)).unwrap_err();
        let msg = err.to_string();
        assert!(
            msg.starts_with(&format!("{}:{line}: ", path.display())),
            "{msg}"
        );
        assert!(msg.contains(needle), "{msg}");
        assert_eq!(log.trials().unwrap(), before);
        assert_eq!(log.grade_history(1).unwrap().len(), 1);
    }
}

#[test]
fn corrupt_files_are_reported_and_left_byte_for_byte() {
    let dir = TempDir::new("trial-corrupt").unwrap();
    // Not SQLite at all.
    let text = dir.join("notes.sqlite");
    std::fs::write(&text, "trial 1: success\ntrial 2: failure (grip)\n").unwrap();
    // A real log whose pages were overwritten after the header.
    let damaged = dir.join("damaged.sqlite");
    {
        let mut log = TrialLog::open(&damaged).unwrap();
        for i in 0..40 {
            log.record_trial(&trial("laplace", i, 0)).unwrap();
        }
    }
    let mut bytes = std::fs::read(&damaged).unwrap();
    assert!(bytes.len() > 8192, "{}", bytes.len());
    for b in &mut bytes[100..] {
        *b = 0xA5;
    }
    std::fs::write(&damaged, &bytes).unwrap();

    for path in [&text, &damaged] {
        let before = std::fs::read(path).unwrap();
        for open in [TrialLog::open, TrialLog::open_existing] {
            let err = open(path).unwrap_err();
            assert!(
                matches!(
                    err,
                    TrialError::NotSqlite { .. } | TrialError::Corrupt { .. }
                ),
                "{err:?}"
            );
            let msg = err.to_string();
            assert!(
                msg.contains(&path.display().to_string()) && msg.contains("untouched"),
                "{msg}"
            );
        }
        // The command line says the same, and exits non-zero.
        let out = cell(&["report", "--log", path.to_str().unwrap()]);
        assert!(!out.status.success());
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert!(stderr.contains(&path.display().to_string()), "{stderr}");
        assert_eq!(std::fs::read(path).unwrap(), before, "{}", path.display());
        assert!(!Path::new(&format!("{}-wal", path.display())).exists());
    }
}

fn cell(args: &[&str]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_cell"))
        .args(args)
        .stdin(Stdio::null())
        .output()
        .unwrap()
}

#[test]
fn cell_grade_report_import_export_on_the_command_line() {
    let dir = TempDir::new("trial-cli").unwrap();
    let log_path = dir.join("trials/t.sqlite");
    let log_arg = log_path.to_str().unwrap();
    {
        let mut log = TrialLog::open(&log_path).unwrap();
        paired_campaign(&mut log, 3, 1, 1);
        log.record_trial(&trial("a", 9, 0)).unwrap(); // id 11, ungraded
    }
    let ok = |args: &[&str]| {
        let out = cell(args);
        assert!(
            out.status.success(),
            "{args:?}: {}",
            String::from_utf8_lossy(&out.stderr)
        );
        String::from_utf8(out.stdout).unwrap()
    };
    let fail = |args: &[&str]| {
        let out = cell(args);
        assert!(!out.status.success(), "{args:?} succeeded");
        String::from_utf8(out.stderr).unwrap()
    };

    let json: serde_json::Value = serde_json::from_str(&ok(&[
        "grade",
        "--trial",
        "11",
        "--grade",
        "failure",
        "--cause",
        "shape dissimilarity",
        "--note",
        "slipped off the handle",
        "--log",
        log_arg,
        "--json",
    ]))
    .unwrap();
    assert_eq!(json["grade"], "failure");
    assert_eq!(json["cause"], "shape-dissimilarity");
    assert_eq!(json["previous"], serde_json::Value::Null);

    let e = fail(&[
        "grade", "--trial", "999", "--grade", "success", "--log", log_arg,
    ]);
    assert!(e.contains("no trial with id 999"), "{e}");
    let e = fail(&[
        "grade",
        "--trial",
        "11",
        "--grade",
        "excellent",
        "--log",
        log_arg,
    ]);
    assert!(e.contains("invalid grade \"excellent\""), "{e}");
    let e = fail(&[
        "grade", "--trial", "11", "--grade", "failure", "--log", log_arg,
    ]);
    assert!(e.contains("needs a cause"), "{e}");
    let e = fail(&[
        "grade", "--trial", "11", "--grade", "f", "--cause", "gremlins", "--log", log_arg,
    ]);
    assert!(e.contains("invalid failure cause \"gremlins\""), "{e}");
    let e = fail(&["report", "--log", log_arg, "--task", "hanlde"]);
    assert!(
        e.contains("no trial of task \"hanlde\"; the log's tasks: pour"),
        "{e}"
    );
    let pour: serde_json::Value = serde_json::from_str(&ok(&[
        "report", "--log", log_arg, "--task", "pour", "--json",
    ]))
    .unwrap();
    assert_eq!(
        (pour["task"].as_str(), pour["trials"].as_u64()),
        (Some("pour"), Some(11))
    );
    let e = fail(&["report", "--log", dir.join("none.sqlite").to_str().unwrap()]);
    assert!(e.contains("no trial log here"), "{e}");
    assert!(!dir.join("none.sqlite").exists());
    {
        let log = TrialLog::open_existing(&log_path).unwrap();
        assert_eq!(log.trial_count().unwrap(), 11);
        assert_eq!(log.grade_history(11).unwrap().len(), 1);
        assert_eq!(log.integrity_check().unwrap(), "ok");
    }

    // Interactive grading through stdin when --grade is left out.
    let mut child = Command::new(env!("CARGO_BIN_EXE_cell"))
        .args(["grade", "--trial", "11", "--log", log_arg, "--json"])
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    use std::io::Write;
    child
        .stdin
        .take()
        .unwrap()
        .write_all(b"p\n5\nre-graded from video\n")
        .unwrap();
    let out = child.wait_with_output().unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let json: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(
        (json["grade"].as_str(), json["cause"].as_str()),
        (Some("partial"), Some("other"))
    );
    assert_eq!(json["previous"]["grade"], "failure");

    let report: serde_json::Value = serde_json::from_str(&ok(&[
        "report",
        "--log",
        log_arg,
        "--json",
        "--png",
        dir.join("png").to_str().unwrap(),
    ]))
    .unwrap();
    assert_eq!(report["trials"], 11);
    assert_eq!(report["sign_tests"][0]["wins"], 3);
    assert_eq!(report["sign_tests"][0]["losses"], 1);
    assert_eq!(report["charts"].as_array().unwrap().len(), 2);
    assert!(dir.join("png/outcomes.png").exists() && dir.join("png/failure_causes.png").exists());
    let human = ok(&["report", "--log", log_arg]);
    assert!(
        human.contains("Table 2") && human.contains("a vs b"),
        "{human}"
    );

    let export = ok(&["log", "export", "--log", log_arg]);
    assert_eq!(export.lines().count(), 12);
    assert!(export.starts_with("trial_id,grade,cause,note,"));
    let out_csv = dir.join("export.csv");
    ok(&[
        "log",
        "export",
        "--log",
        log_arg,
        "--out",
        out_csv.to_str().unwrap(),
    ]);
    assert_eq!(std::fs::read_to_string(&out_csv).unwrap(), export);

    let paper = dir.join("paper.csv");
    std::fs::write(
        &paper,
        "trial_id,grade,cause,note\n11,success,,\"looked fine, on reflection\"\n",
    )
    .unwrap();
    let json: serde_json::Value = serde_json::from_str(&ok(&[
        "log",
        "import",
        paper.to_str().unwrap(),
        "--log",
        log_arg,
        "--json",
    ]))
    .unwrap();
    assert_eq!(
        (json["graded"].as_u64(), json["rows"].as_u64()),
        (Some(1), Some(1))
    );
    let log = TrialLog::open_existing(&log_path).unwrap();
    let h = log.grade_history(11).unwrap();
    assert_eq!(
        h.iter().map(|e| e.grading.grade).collect::<Vec<_>>(),
        [Grade::Failure, Grade::Partial, Grade::Success]
    );
    assert_eq!(h[2].source, GradeSource::Import);
}

// ---------------------------------------------------------------------------------
// Crash safety: a child process writes and grades trials in a loop and is killed with
// SIGKILL; every trial and grade it reported as committed must be in the log.

const CRASH_ENV: &str = "GRASPCELL_TEST_CRASH_LOG";

/// The grade the crash child gives trial `id` on its `attempt`-th grading.
fn crash_grading(id: TrialId, attempt: i64) -> Grading {
    match (id + attempt) % 3 {
        0 => Grading::new(Grade::Success, None, None).unwrap(),
        1 => Grading::new(Grade::Partial, None, Some(format!("t{id} a{attempt}"))).unwrap(),
        _ => Grading::new(
            Grade::Failure,
            Some(FailureCause::ALL[(id % 5) as usize]),
            None,
        )
        .unwrap(),
    }
}

/// Not a test on its own: the child process of
/// `killed_writer_loses_no_committed_trial_or_grade`, run through the test harness
/// with the log path in `GRASPCELL_TEST_CRASH_LOG`. Prints a line after each commit.
#[test]
#[ignore = "child process of killed_writer_loses_no_committed_trial_or_grade"]
fn crash_child_writes_and_grades() {
    let Ok(path) = std::env::var(CRASH_ENV) else {
        return;
    };
    let mut log = TrialLog::open(&path).unwrap();
    for i in 0..20_000_u32 {
        let id = log.record_trial(&trial("laplace", i / 5, i % 5)).unwrap();
        println!("COMMITTED recorded {id}");
        log.grade(
            id,
            &crash_grading(id, 0),
            GradeSource::Simulated,
            at(i64::from(i)),
        )
        .unwrap();
        println!("COMMITTED graded {id} 0");
        // Re-grade an earlier trial now and then: history must keep every grade.
        if id > 3 && id % 4 == 0 {
            let old = id - 3;
            let attempt = log.grade_history(old).unwrap().len() as i64;
            log.grade(
                old,
                &crash_grading(old, attempt),
                GradeSource::Command,
                at(i64::from(i)),
            )
            .unwrap();
            println!("COMMITTED graded {old} {attempt}");
        }
    }
}

#[test]
fn killed_writer_loses_no_committed_trial_or_grade() {
    let dir = TempDir::new("trial-crash").unwrap();
    let path = dir.join("trials.sqlite");
    let exe = std::env::current_exe().unwrap();
    // The child's test name: this module's path without the crate (`trial::...` in
    // the one `tests` binary, bare if cargo also builds this file on its own).
    let child_test = match module_path!().split_once("::") {
        Some((_, module)) => format!("{module}::crash_child_writes_and_grades"),
        None => "crash_child_writes_and_grades".to_string(),
    };
    let mut recorded: Vec<TrialId> = Vec::new();
    // Grades each trial was reported (committed) to have, by attempt, in order.
    let mut graded: std::collections::BTreeMap<TrialId, Vec<i64>> = Default::default();
    for (round, kill_after) in [(0, 40_usize), (1, 90), (2, 15)] {
        let mut child = Command::new(&exe)
            .args([
                "--exact",
                &child_test,
                "--ignored",
                "--nocapture",
                "--test-threads=1",
            ])
            .env(CRASH_ENV, &path)
            .stdout(Stdio::piped())
            .stderr(Stdio::null())
            .spawn()
            .unwrap();
        let mut lines = BufReader::new(child.stdout.take().unwrap()).lines();
        let mut seen = 0;
        let mut killed = false;
        while let Some(Ok(line)) = lines.next() {
            // libtest may put its own text before the first line with --nocapture.
            let Some(start) = line.find("COMMITTED ") else {
                continue;
            };
            let rest = &line[start + "COMMITTED ".len()..];
            let words: Vec<&str> = rest.split(' ').collect();
            match words[..] {
                ["recorded", id] => recorded.push(id.parse().unwrap()),
                ["graded", id, attempt] => {
                    let list = graded.entry(id.parse().unwrap()).or_default();
                    list.push(attempt.parse().unwrap());
                }
                _ => panic!("{line}"),
            }
            seen += 1;
            if seen == kill_after && !killed {
                // SIGKILL: no destructors, no SQLite close, no checkpoint. The lines
                // already in the pipe are still read: those commits happened.
                child.kill().unwrap();
                killed = true;
            }
        }
        assert!(killed, "round {round}: child ended before it was killed");
        let status = child.wait().unwrap();
        assert!(!status.success(), "round {round}: {status:?}");
    }
    assert!(recorded.len() >= 50, "{}", recorded.len());

    let log = TrialLog::open_existing(&path).unwrap();
    assert_eq!(log.integrity_check().unwrap(), "ok");
    let trials = log.trials().unwrap();
    let ids: Vec<TrialId> = trials.iter().map(|t| t.id).collect();
    for id in &recorded {
        assert!(
            ids.contains(id),
            "committed trial {id} lost; log has {ids:?}"
        );
    }
    // At most one unreported trial per round (committed, killed before printing).
    assert!(
        ids.len() <= recorded.len() + 3,
        "{} vs {}",
        ids.len(),
        recorded.len()
    );
    for t in &trials {
        // Every stored trial is whole.
        let object = t.trial.object.name.strip_prefix("mug-novel-").unwrap();
        let want = trial("laplace", object.parse().unwrap(), t.trial.placement.index);
        assert_eq!(t.trial, want, "trial {}", t.id);
        let history = log.grade_history(t.id).unwrap();
        let reported = graded.get(&t.id).cloned().unwrap_or_default();
        // The reported grades are a prefix of the history (one more may have been
        // committed just before the kill), and the current grade is the last one.
        assert!(
            history.len() >= reported.len() && history.len() <= reported.len() + 1,
            "trial {}",
            t.id
        );
        for (attempt, event) in history.iter().enumerate() {
            assert_eq!(
                event.grading,
                crash_grading(t.id, attempt as i64),
                "trial {}",
                t.id
            );
        }
        // Reported attempts index the history (checked above) in increasing order.
        assert!(reported.windows(2).all(|w| w[0] < w[1]), "trial {}", t.id);
        assert!(
            reported.iter().all(|&a| (a as usize) < history.len()),
            "trial {}",
            t.id
        );
        assert_eq!(
            t.grading.as_ref(),
            history.last().map(|e| &e.grading),
            "trial {}",
            t.id
        );
    }
}
