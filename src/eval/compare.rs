//! Our grasp against the best-single baseline: the verdict of one run and the
//! tallies of the paper's Figures 5 and 6 (share of runs better / equal / worse).

use crate::trial::stats::sign_test_p_value;
use serde::Serialize;

/// Default tolerance on epsilon under which two grasps count as equal: about 5 % of
/// a typical mug or bottle grasp's epsilon (0.1-0.3), well above the simulator's
/// rounding (bisection to 1e-4 rad).
pub const DEFAULT_EQUAL_TOLERANCE: f64 = 0.01;

/// How our grasp compares with best single in one run.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Verdict {
    /// Epsilon higher by at least the tolerance.
    Better,
    /// Epsilons within the tolerance.
    Equal,
    /// Epsilon lower by at least the tolerance.
    Worse,
}

/// The verdict for epsilons `ours` and `single`: equal when `|ours - single| <
/// tolerance` (or exactly equal, for a zero tolerance).
pub fn verdict(ours: f64, single: f64, tolerance: f64) -> Verdict {
    let d = ours - single;
    if d.abs() < tolerance || d == 0.0 {
        Verdict::Equal
    } else if d > 0.0 {
        Verdict::Better
    } else {
        Verdict::Worse
    }
}

/// Counts and means over a set of runs.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize)]
pub struct Tally {
    /// Runs counted.
    pub runs: usize,
    /// Runs where ours was better.
    pub better: usize,
    /// Runs where both were equal.
    pub equal: usize,
    /// Runs where ours was worse.
    pub worse: usize,
    /// `better / runs` in percent.
    pub better_pct: f64,
    /// `equal / runs` in percent.
    pub equal_pct: f64,
    /// `worse / runs` in percent.
    pub worse_pct: f64,
    /// Mean epsilon of our grasps.
    pub mean_epsilon: f64,
    /// Mean epsilon of the best-single grasps of the same runs.
    pub mean_epsilon_single: f64,
    /// Share of our grasps that are force closure (percent).
    pub force_closure_pct: f64,
    /// Share of the best-single grasps that are force closure (percent).
    pub force_closure_single_pct: f64,
    /// Two-sided exact sign test of ours against best single over the runs that
    /// differ (better against worse; 1 when none differ).
    pub sign_test_p: f64,
}

/// One run as the tally needs it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Pair {
    /// Our epsilon.
    pub ours: f64,
    /// Best single's epsilon.
    pub single: f64,
}

impl Tally {
    /// The tally of `pairs` with the equality `tolerance`.
    pub fn of(pairs: impl IntoIterator<Item = Pair>, tolerance: f64) -> Tally {
        let mut t = Tally::default();
        let (mut sum, mut sum_single) = (0.0, 0.0);
        let (mut fc, mut fc_single) = (0usize, 0usize);
        for p in pairs {
            t.runs += 1;
            match verdict(p.ours, p.single, tolerance) {
                Verdict::Better => t.better += 1,
                Verdict::Equal => t.equal += 1,
                Verdict::Worse => t.worse += 1,
            }
            sum += p.ours;
            sum_single += p.single;
            fc += usize::from(p.ours > 0.0);
            fc_single += usize::from(p.single > 0.0);
        }
        if t.runs > 0 {
            let n = t.runs as f64;
            let pct = |k: usize| 100.0 * k as f64 / n;
            t.better_pct = pct(t.better);
            t.equal_pct = pct(t.equal);
            t.worse_pct = pct(t.worse);
            t.mean_epsilon = sum / n;
            t.mean_epsilon_single = sum_single / n;
            t.force_closure_pct = pct(fc);
            t.force_closure_single_pct = pct(fc_single);
        }
        t.sign_test_p = sign_test_p_value(t.better as u64, t.worse as u64);
        t
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn verdict_uses_a_strict_tolerance() {
        assert_eq!(verdict(0.2, 0.1, 0.01), Verdict::Better);
        assert_eq!(verdict(0.1, 0.2, 0.01), Verdict::Worse);
        assert_eq!(verdict(0.105, 0.1, 0.01), Verdict::Equal);
        assert_eq!(verdict(0.0, 0.0, 0.01), Verdict::Equal);
        assert_eq!(verdict(0.11, 0.1, 0.0), Verdict::Better);
        assert_eq!(verdict(0.1, 0.1, 0.0), Verdict::Equal);
    }

    #[test]
    fn tally_counts_add_up_and_means_are_exact() {
        let pairs = [
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
                single: 0.15,
            },
            Pair {
                ours: 0.3,
                single: 0.0,
            },
        ];
        let t = Tally::of(pairs, 0.01);
        assert_eq!((t.runs, t.better, t.equal, t.worse), (4, 2, 1, 1));
        assert_eq!(t.better + t.equal + t.worse, t.runs);
        assert!((t.better_pct - 50.0).abs() < 1e-12);
        assert!((t.mean_epsilon - 0.15).abs() < 1e-12);
        assert!((t.mean_epsilon_single - 0.0875).abs() < 1e-12);
        assert!((t.force_closure_pct - 75.0).abs() < 1e-12);
        // Two better against one worse: no evidence either way.
        assert!((t.sign_test_p - 1.0).abs() < 1e-12);
        let ten_better = Tally::of(
            (0..10).map(|_| Pair {
                ours: 0.2,
                single: 0.0,
            }),
            0.01,
        );
        // 2 / 2^10: two-sided exact.
        assert!((ten_better.sign_test_p - 2.0 / 1024.0).abs() < 1e-12);
        assert_eq!(
            Tally::of([], 0.01),
            Tally {
                sign_test_p: 1.0,
                ..Tally::default()
            }
        );
    }
}
