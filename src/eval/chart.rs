//! The better / equal / worse chart of an experiment (the paper's Figures 5 and 6):
//! one group of bars per task and kernel, drawn with the trial report's PNG bar
//! charts.

use super::loo::TallyRow;
use super::EvalError;
use crate::trial::plot::{grouped_bar_chart, Bar, Canvas, Rgb, GRADE_COLOURS};
use std::path::Path;

/// The chart of `rows` under `title`: groups `TASK KERNEL`, bars better (green),
/// equal (amber), worse (red) in percent of runs; rows without runs draw no bars.
pub fn verdict_chart(title: &str, rows: &[TallyRow]) -> (Canvas, Vec<Bar>) {
    let groups: Vec<String> = rows
        .iter()
        .map(|r| format!("{} {}", r.task, r.kernel))
        .collect();
    let series: Vec<(String, Rgb)> = ["better", "equal", "worse"]
        .iter()
        .zip(GRADE_COLOURS)
        .map(|(n, c)| (n.to_string(), c))
        .collect();
    let values: Vec<Vec<Option<f64>>> = rows
        .iter()
        .map(|r| {
            let t = &r.tally;
            if t.runs == 0 {
                vec![None; 3]
            } else {
                vec![Some(t.better_pct), Some(t.equal_pct), Some(t.worse_pct)]
            }
        })
        .collect();
    grouped_bar_chart(title, &groups, &series, &values)
}

/// The observer's grades of the novel-object experiment: one group of bars per task
/// and method, bars success (green), partial (amber), failure (red) in percent of
/// trials; rows without trials draw no bars.
pub fn grade_chart(title: &str, rows: &[super::novel::NovelRow]) -> (Canvas, Vec<Bar>) {
    let groups: Vec<String> = rows
        .iter()
        .map(|r| format!("{} {}", r.task, r.method))
        .collect();
    let series: Vec<(String, Rgb)> = ["success", "partial", "failure"]
        .iter()
        .zip(GRADE_COLOURS)
        .map(|(n, c)| (n.to_string(), c))
        .collect();
    let values: Vec<Vec<Option<f64>>> = rows
        .iter()
        .map(|r| {
            if r.trials == 0 {
                vec![None; 3]
            } else {
                vec![
                    Some(r.success_pct),
                    Some(r.partial_pct),
                    Some(r.failure_pct),
                ]
            }
        })
        .collect();
    grouped_bar_chart(title, &groups, &series, &values)
}

/// Writes the grade chart of `rows` to `path` (PNG, atomically).
pub fn write_grade_chart(
    path: &Path,
    title: &str,
    rows: &[super::novel::NovelRow],
) -> Result<(), EvalError> {
    let (canvas, _) = grade_chart(title, rows);
    canvas.save_png(path)?;
    Ok(())
}

/// Writes the chart of `rows` to `path` (PNG, atomically).
pub fn write_verdict_chart(path: &Path, title: &str, rows: &[TallyRow]) -> Result<(), EvalError> {
    let (canvas, _) = verdict_chart(title, rows);
    canvas.save_png(path)?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::eval::compare::{Pair, Tally};

    #[test]
    fn bars_follow_the_percentages() {
        let rows = vec![
            TallyRow {
                task: "top".into(),
                kernel: "laplace",
                tally: Tally::of(
                    [
                        Pair {
                            ours: 0.2,
                            single: 0.1,
                        },
                        Pair {
                            ours: 0.2,
                            single: 0.1,
                        },
                        Pair {
                            ours: 0.1,
                            single: 0.1,
                        },
                        Pair {
                            ours: 0.0,
                            single: 0.1,
                        },
                    ],
                    0.01,
                ),
                collisions: 0,
                collisions_single: 0,
            },
            TallyRow {
                task: "top".into(),
                kernel: "gaussian",
                tally: Tally::default(),
                collisions: 0,
                collisions_single: 0,
            },
        ];
        let (_, bars) = verdict_chart("TEST", &rows);
        assert_eq!(bars.len(), 3, "the empty row draws nothing");
        // better 50 % is twice as tall as equal and worse (25 % each).
        assert_eq!(bars[0].h, 2 * bars[1].h);
        assert_eq!(bars[1].h, bars[2].h);
    }
}
