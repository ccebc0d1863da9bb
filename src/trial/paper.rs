//! The paper's robot results (Nikandrova & Kyrki 2015, Table 2; `specs/method.md`)
//! next to a report's: failures by cause as % of all grasps, per method.

use super::report::Report;
use std::fmt::Write as _;

/// The methods of the paper's Table 2, as the cell names them.
pub const PAPER_METHODS: [&str; 3] = ["best-single", "gaussian-r", "laplace"];

/// The rows of the paper's Table 2: cause (as the trial log names it) and % of all
/// grasps for best single, Gaussian-R (s = 700) and Laplace (b = 700).
pub const PAPER_TABLE_2: [(&str, [f64; 3]); 5] = [
    ("reachability", [11.0, 18.0, 11.0]),
    ("registration", [21.0, 3.5, 3.5]),
    ("shape-dissimilarity", [46.0, 3.5, 0.0]),
    ("other", [0.0, 18.0, 14.0]),
    ("total", [78.0, 43.0, 28.5]),
];

/// Our failure percentage of `cause` (`total` for all) for `method`, if reported.
fn ours(report: &Report, cause: &str, method: &str) -> Option<f64> {
    let column = report
        .failure_causes
        .methods
        .iter()
        .position(|m| m == method)?;
    let row = if cause == "total" {
        &report.failure_causes.total
    } else {
        report
            .failure_causes
            .rows
            .iter()
            .find(|r| r.cause == cause)?
    };
    row.percent.get(column).copied().flatten()
}

/// The comparison as text: one row per cause, "ours / paper" per method.
pub fn comparison_text(report: &Report) -> String {
    let mut text =
        String::from("\nFailures by cause, % of all grasps: this run / the paper's Table 2\n");
    let _ = writeln!(
        text,
        "{:<22}{:>18}{:>18}{:>18}",
        "cause", "best-single", "gaussian-r", "laplace"
    );
    let mut rows: Vec<(&str, [f64; 3])> = PAPER_TABLE_2.to_vec();
    // The cell's own cause, which the paper folds into "other".
    rows.insert(3, ("execution", [f64::NAN; 3]));
    for (cause, paper) in rows {
        let _ = write!(text, "{cause:<22}");
        for (m, method) in PAPER_METHODS.iter().enumerate() {
            let ours = ours(report, cause, method).map_or("-".to_string(), |v| format!("{v:.1}"));
            let theirs = if paper[m].is_nan() {
                "-".to_string()
            } else {
                format!("{:.1}", paper[m])
            };
            let _ = write!(text, "{:>18}", format!("{ours} / {theirs}"));
        }
        text.push('\n');
    }
    text.push_str(
        "(paper: 6 novel mugs x 5 placements, top grasp; Laplace beat best single at p < 0.00002, Gaussian-R at p < 0.0005)\n",
    );
    text
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn paper_totals_add_up_and_an_empty_report_prints_dashes() {
        for m in 0..3 {
            let sum: f64 = PAPER_TABLE_2[..4].iter().map(|(_, v)| v[m]).sum();
            assert!((sum - PAPER_TABLE_2[4].1[m]).abs() < 1e-9, "column {m}");
        }
        let report = Report::from_trials(&[], Default::default());
        let text = comparison_text(&report);
        assert!(text.contains("- / 78.0"), "{text}");
        assert!(text.contains("shape-dissimilarity"));
    }
}
