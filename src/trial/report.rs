//! The report over a trial log: grade rates per method, failure causes as a share of
//! all graded trials (the paper's Table 2), and pairwise sign tests between methods.
//!
//! Conventions:
//! - Rates and cause shares are over each method's *graded* trials; ungraded trials
//!   are counted separately and otherwise ignored.
//! - The cause table counts trials graded *failure* (a partial grasp's cause, when
//!   given, is kept in the log but is not a failure).
//! - The sign test pairs trials by (campaign, object, placement). If one method has
//!   several graded trials with the same key (a repeated trial), the latest (highest
//!   id) is used and the others are counted in `superseded`. In a campaign the
//!   latest is also the one counted in the rates and causes (a campaign repeats a
//!   trial the link to the robot broke off, `cell::campaign::ended_on_link_fault`);
//!   outside campaigns every graded trial counts (the same object and placement
//!   index may be tried many times).

use super::grade::{FailureCause, Grade};
use super::log::{PairingKey, TrialRecord};
use super::stats::{paired_sign_test, PairedSignTest};
use serde::Serialize;
use std::collections::BTreeMap;
use std::fmt::Write as _;

/// Grade counts and rates of one method.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct MethodSummary {
    /// The method.
    pub method: String,
    /// Trials recorded (graded or not).
    pub trials: u64,
    /// Trials graded.
    pub graded: u64,
    /// Trials graded success.
    pub success: u64,
    /// Trials graded partial.
    pub partial: u64,
    /// Trials graded failure.
    pub failure: u64,
    /// Success, % of graded trials (`None` when none are graded).
    pub success_pct: Option<f64>,
    /// Partial, % of graded trials.
    pub partial_pct: Option<f64>,
    /// Failure, % of graded trials.
    pub failure_pct: Option<f64>,
}

/// One row of the cause table: failures with this cause, per method.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct CauseRow {
    /// The cause (`total` for the total row).
    pub cause: String,
    /// Failure count per method (in [`CauseTable::methods`] order).
    pub counts: Vec<u64>,
    /// Failures as % of the method's graded trials (`None` when none are graded).
    pub percent: Vec<Option<f64>>,
}

/// Failures by cause as a share of all graded trials: the paper's Table 2 layout.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct CauseTable {
    /// Column order.
    pub methods: Vec<String>,
    /// One row per cause.
    pub rows: Vec<CauseRow>,
    /// All failures.
    pub total: CauseRow,
}

/// The sign test between two methods: wins are pairs where `a` graded better.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct MethodComparison {
    /// Method A.
    pub a: String,
    /// Method B.
    pub b: String,
    /// The test of A against B.
    #[serde(flatten)]
    pub test: PairedSignTest,
}

/// Which trials a report covers: one campaign's or all, one task's or all.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Scope<'a> {
    /// Only this campaign's trials.
    pub campaign_id: Option<&'a str>,
    /// Only trials of this task (`top`, `side`, `handle`, …).
    pub task: Option<&'a str>,
}

impl<'a> Scope<'a> {
    /// Every trial of one campaign.
    pub fn campaign(id: &'a str) -> Scope<'a> {
        Scope {
            campaign_id: Some(id),
            task: None,
        }
    }

    /// Whether `t` is in scope.
    fn contains(&self, t: &TrialRecord) -> bool {
        self.campaign_id
            .is_none_or(|c| t.trial.campaign_id.as_deref() == Some(c))
            && self.task.is_none_or(|task| t.trial.task == task)
    }
}

/// The whole report.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Report {
    /// The campaign reported on (`None`: every trial in the log).
    pub campaign_id: Option<String>,
    /// The task reported on (`None`: every task).
    pub task: Option<String>,
    /// Trials considered.
    pub trials: u64,
    /// Of those, graded and counted.
    pub graded: u64,
    /// Of those, not graded yet.
    pub ungraded: u64,
    /// Graded trials left out of the sign tests because a later trial of the same
    /// method had the same pairing key (and, for campaign trials, out of the rates
    /// and causes too).
    pub superseded: u64,
    /// Of `superseded`, campaign trials: not in `graded`.
    pub superseded_in_campaigns: u64,
    /// Per method, in name order.
    pub methods: Vec<MethodSummary>,
    /// Failures by cause.
    pub failure_causes: CauseTable,
    /// Every pair of methods (A before B in name order).
    pub sign_tests: Vec<MethodComparison>,
}

fn pct(count: u64, of: u64) -> Option<f64> {
    (of > 0).then(|| 100.0 * count as f64 / of as f64)
}

/// The latest (highest id) graded trial of each method and pairing key: the one the
/// sign test pairs, and in a campaign the one that counts when a trial was run again.
pub fn latest_graded<'t>(
    trials: impl IntoIterator<Item = &'t TrialRecord>,
) -> BTreeMap<(&'t str, PairingKey), &'t TrialRecord> {
    let mut latest: BTreeMap<(&str, PairingKey), &TrialRecord> = BTreeMap::new();
    for t in trials.into_iter().filter(|t| t.grading.is_some()) {
        let entry = latest
            .entry((t.trial.method.as_str(), t.pairing_key()))
            .or_insert(t);
        if t.id > entry.id {
            *entry = t;
        }
    }
    latest
}

impl Report {
    /// Builds the report from the trials in `scope`.
    pub fn from_trials(trials: &[TrialRecord], scope: Scope) -> Report {
        let selected: Vec<&TrialRecord> = trials.iter().filter(|t| scope.contains(t)).collect();
        let mut by_method: BTreeMap<&str, Vec<&TrialRecord>> = BTreeMap::new();
        for t in &selected {
            by_method
                .entry(t.trial.method.as_str())
                .or_default()
                .push(t);
        }
        let methods: Vec<String> = by_method.keys().map(|m| m.to_string()).collect();

        let mut summaries = Vec::new();
        let mut cause_counts = vec![vec![0_u64; methods.len()]; FailureCause::ALL.len()];
        let latest = latest_graded(selected.iter().copied());
        let superseded = selected.iter().filter(|t| t.grading.is_some()).count() - latest.len();
        let mut superseded_in_campaigns = 0;
        for (col, (method, list)) in by_method.iter().enumerate() {
            let mut s = MethodSummary {
                method: method.to_string(),
                trials: list.len() as u64,
                graded: 0,
                success: 0,
                partial: 0,
                failure: 0,
                success_pct: None,
                partial_pct: None,
                failure_pct: None,
            };
            for t in list {
                let Some(g) = &t.grading else { continue };
                let is_latest = latest
                    .get(&(*method, t.pairing_key()))
                    .is_some_and(|l| l.id == t.id);
                if t.trial.campaign_id.is_some() && !is_latest {
                    superseded_in_campaigns += 1;
                    continue;
                }
                s.graded += 1;
                match g.grade {
                    Grade::Success => s.success += 1,
                    Grade::Partial => s.partial += 1,
                    Grade::Failure => {
                        s.failure += 1;
                        // A failure always has a cause (checked on grading).
                        let cause = g.cause.unwrap_or(FailureCause::Other);
                        let row = FailureCause::ALL.iter().position(|&c| c == cause);
                        cause_counts[row.unwrap_or(FailureCause::ALL.len() - 1)][col] += 1;
                    }
                }
            }
            s.success_pct = pct(s.success, s.graded);
            s.partial_pct = pct(s.partial, s.graded);
            s.failure_pct = pct(s.failure, s.graded);
            summaries.push(s);
        }

        let graded_of = |col: usize| summaries[col].graded;
        let rows: Vec<CauseRow> = FailureCause::ALL
            .iter()
            .zip(&cause_counts)
            .map(|(cause, counts)| CauseRow {
                cause: cause.to_string(),
                counts: counts.clone(),
                percent: counts
                    .iter()
                    .enumerate()
                    .map(|(c, &n)| pct(n, graded_of(c)))
                    .collect(),
            })
            .collect();
        let total_counts: Vec<u64> = summaries.iter().map(|s| s.failure).collect();
        let total = CauseRow {
            cause: "total".to_string(),
            percent: total_counts
                .iter()
                .enumerate()
                .map(|(c, &n)| pct(n, graded_of(c)))
                .collect(),
            counts: total_counts,
        };

        // Each method's scores by pairing key, from its latest graded trials.
        let mut scores: Vec<BTreeMap<&PairingKey, i8>> = vec![BTreeMap::new(); methods.len()];
        for ((method, key), t) in &latest {
            if let (Some(col), Some(g)) = (methods.iter().position(|m| m == method), &t.grading) {
                scores[col].insert(key, g.grade.score());
            }
        }
        let mut sign_tests = Vec::new();
        for i in 0..methods.len() {
            for j in i + 1..methods.len() {
                sign_tests.push(MethodComparison {
                    a: methods[i].clone(),
                    b: methods[j].clone(),
                    test: paired_sign_test(&scores[i], &scores[j]),
                });
            }
        }

        let graded = summaries.iter().map(|s| s.graded).sum();
        Report {
            campaign_id: scope.campaign_id.map(str::to_string),
            task: scope.task.map(str::to_string),
            trials: selected.len() as u64,
            graded,
            ungraded: selected.iter().filter(|t| t.grading.is_none()).count() as u64,
            superseded: superseded as u64,
            superseded_in_campaigns,
            methods: summaries,
            failure_causes: CauseTable {
                methods,
                rows,
                total,
            },
            sign_tests,
        }
    }

    /// The report as human-readable tables.
    pub fn to_text(&self) -> String {
        let mut out = String::new();
        let mut scope = match &self.campaign_id {
            Some(c) => format!("campaign {c}"),
            None => "all campaigns".to_string(),
        };
        if let Some(task) = &self.task {
            scope.push_str(&format!(", task {task}"));
        }
        let _ = writeln!(
            out,
            "Trial log ({scope}): {} trials, {} graded, {} ungraded",
            self.trials, self.graded, self.ungraded
        );
        if self.methods.is_empty() {
            return out;
        }
        let width = self
            .methods
            .iter()
            .map(|m| m.method.len())
            .max()
            .unwrap_or(6)
            .max(6);
        let cell = |n: u64, p: Option<f64>| match p {
            Some(p) => format!("{n} ({p:.1}%)"),
            None => format!("{n}"),
        };
        let _ = writeln!(
            out,
            "\n{:<width$}  {:>6}  {:>6}  {:>13}  {:>13}  {:>13}",
            "method", "trials", "graded", "success", "partial", "failure"
        );
        for m in &self.methods {
            let _ = writeln!(
                out,
                "{:<width$}  {:>6}  {:>6}  {:>13}  {:>13}  {:>13}",
                m.method,
                m.trials,
                m.graded,
                cell(m.success, m.success_pct),
                cell(m.partial, m.partial_pct),
                cell(m.failure, m.failure_pct),
            );
        }

        let table = &self.failure_causes;
        let col = width.max(8);
        let _ = writeln!(
            out,
            "\nFailures by cause, % of all graded trials (the paper's Table 2)"
        );
        let _ = write!(out, "{:<20}", "cause");
        for m in &table.methods {
            let _ = write!(out, "  {m:>col$}");
        }
        out.push('\n');
        for row in table.rows.iter().chain(std::iter::once(&table.total)) {
            let _ = write!(out, "{:<20}", row.cause);
            for p in &row.percent {
                let text = p.map_or("-".to_string(), |p| format!("{p:.1}"));
                let _ = write!(out, "  {text:>col$}");
            }
            out.push('\n');
        }

        if !self.sign_tests.is_empty() {
            let _ = writeln!(
                out,
                "\nSign tests, paired by (campaign, object, placement); two-sided exact"
            );
            let pair_w = self
                .sign_tests
                .iter()
                .map(|t| t.a.len() + t.b.len() + 4)
                .max()
                .unwrap_or(6);
            let _ = writeln!(
                out,
                "{:<pair_w$}  {:>5}  {:>6}  {:>5}  {:>4}  {:>10}  unpaired",
                "A vs B", "wins", "losses", "ties", "n", "p"
            );
            for t in &self.sign_tests {
                let _ = writeln!(
                    out,
                    "{:<pair_w$}  {:>5}  {:>6}  {:>5}  {:>4}  {:>10.3e}  {}/{}",
                    format!("{} vs {}", t.a, t.b),
                    t.test.test.wins,
                    t.test.test.losses,
                    t.test.test.ties,
                    t.test.test.n,
                    t.test.test.p_value,
                    t.test.unpaired_a,
                    t.test.unpaired_b,
                );
            }
        }
        if self.superseded > 0 {
            let _ = writeln!(
                out,
                "\n{} graded trial(s) repeated a method's (campaign, object, placement); the latest was paired{}",
                self.superseded,
                if self.superseded_in_campaigns > 0 {
                    format!(
                        " and, for the {} in campaigns, counted alone",
                        self.superseded_in_campaigns
                    )
                } else {
                    String::new()
                }
            );
        }
        out
    }
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use crate::geometry::PoseJson;
    use crate::trial::grade::Grading;
    use crate::trial::log::{NewTrial, ObjectRef, Placement};
    use crate::trial::time::UtcTimestamp;

    /// A campaign trial (`c1`) of a mug for `pour`, with `grade` (grade, cause).
    pub(crate) fn record(
        id: i64,
        method: &str,
        object: &str,
        placement: u32,
        grade: Option<(&str, Option<&str>)>,
    ) -> TrialRecord {
        TrialRecord {
            id,
            trial: NewTrial {
                started_at: UtcTimestamp::from_unix_ms(id * 1000),
                category: "mug".into(),
                task: "pour".into(),
                method: method.into(),
                object: ObjectRef {
                    name: object.into(),
                    seed: None,
                },
                placement: Placement {
                    index: placement,
                    base_from_object: PoseJson {
                        xyz: [0.5, 0.0, 0.0],
                        rpy: Some([0.0; 3]),
                        quat_xyzw: None,
                    },
                },
                campaign_id: Some("c1".into()),
                snapshot_path: None,
                fits: serde_json::Value::Null,
                planned_pose: None,
                planned_joints: None,
                outcome: None,
                seeds: Default::default(),
            },
            software_version: "test".into(),
            grading: grade.map(|(g, c)| Grading::parse(g, c, None).unwrap()),
            graded_at: None,
            grade_source: None,
        }
    }

    #[test]
    fn rates_causes_and_pairing() {
        let trials = vec![
            record(1, "a", "m1", 0, Some(("success", None))),
            record(2, "b", "m1", 0, Some(("failure", Some("registration")))),
            record(3, "a", "m1", 1, Some(("partial", None))),
            record(4, "b", "m1", 1, Some(("partial", Some("other")))),
            record(5, "a", "m2", 0, Some(("failure", Some("reachability")))),
            record(6, "b", "m2", 0, Some(("success", None))),
            record(7, "a", "m2", 1, None),
            // Repeat of b/m2/0: the later grade (failure) replaces the success.
            record(
                8,
                "b",
                "m2",
                0,
                Some(("failure", Some("shape-dissimilarity"))),
            ),
        ];
        let r = Report::from_trials(&trials, Scope::default());
        assert_eq!((r.trials, r.graded, r.ungraded, r.superseded), (8, 6, 1, 1));
        assert_eq!(r.superseded_in_campaigns, 1);
        let a = &r.methods[0];
        assert_eq!(
            (a.trials, a.graded, a.success, a.partial, a.failure),
            (4, 3, 1, 1, 1)
        );
        assert!((a.success_pct.unwrap() - 100.0 / 3.0).abs() < 1e-12);
        let b = &r.methods[1];
        // b's repeat of m2/0 replaces its first grade in the counts as well.
        assert_eq!(
            (b.trials, b.graded, b.success, b.partial, b.failure),
            (4, 3, 0, 1, 2)
        );
        // Causes: a has 1 reachability of 3; b has 1 registration + 1 shape of 3.
        let t = &r.failure_causes;
        assert_eq!(t.rows[0].counts, vec![1, 0]);
        assert_eq!(t.rows[1].counts, vec![0, 1]);
        assert_eq!(t.rows[2].counts, vec![0, 1]);
        assert!((t.rows[1].percent[1].unwrap() - 100.0 / 3.0).abs() < 1e-12);
        assert_eq!(t.total.counts, vec![1, 2]);
        assert!((t.total.percent[1].unwrap() - 200.0 / 3.0).abs() < 1e-12);
        // Pairs: m1/0 a+1 vs b-1 win; m1/1 tie; m2/0 a-1 vs b-1 (latest) tie.
        let s = &r.sign_tests[0].test;
        assert_eq!((s.test.wins, s.test.losses, s.test.ties), (1, 0, 2));
        assert_eq!((s.unpaired_a, s.unpaired_b), (0, 0));
        let text = r.to_text();
        assert!(text.contains("Table 2"));
        assert!(text.contains("a vs b"));
        // Campaign filter.
        assert_eq!(
            Report::from_trials(&trials, Scope::campaign("other")).trials,
            0
        );
    }

    #[test]
    fn a_task_scope_reports_that_task_alone_and_says_so() {
        let mut trials = vec![
            record(1, "a", "m1", 0, Some(("success", None))),
            record(2, "a", "m1", 1, Some(("failure", Some("reachability")))),
            record(3, "b", "m1", 0, Some(("failure", Some("registration")))),
        ];
        trials[1].trial.task = "handle".into();
        let handle = Report::from_trials(
            &trials,
            Scope {
                campaign_id: Some("c1"),
                task: Some("handle"),
            },
        );
        assert_eq!((handle.trials, handle.methods.len()), (1, 1));
        assert_eq!(handle.methods[0].failure, 1);
        assert_eq!(handle.task.as_deref(), Some("handle"));
        assert!(handle.to_text().contains("(campaign c1, task handle)"));
        let pour = Report::from_trials(
            &trials,
            Scope {
                task: Some("pour"),
                ..Scope::default()
            },
        );
        assert_eq!(pour.trials, 2);
        assert!(pour.to_text().contains("(all campaigns, task pour)"));
    }
}
