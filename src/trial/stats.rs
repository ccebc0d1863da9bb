//! The paired sign test of the paper: grades encoded +1 / 0 / -1, paired trial by
//! trial (same object and placement), two-sided exact binomial test over the non-zero
//! differences.
//!
//! Under the null hypothesis each non-zero difference is positive with probability
//! 1/2, so with `n = wins + losses` and `m = min(wins, losses)` the two-sided p-value
//! is `min(1, 2 * P(X <= m))`, `X ~ Binomial(n, 1/2)`. The tail is summed in log space
//! (term ratios `C(n,k+1)/C(n,k) = (n-k)/(k+1)`, scaled by the largest term), which
//! is accurate to about 1e-13 relative for any n up to millions.

use serde::Serialize;
use std::collections::BTreeMap;

/// The outcome of a sign test between methods A and B.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct SignTest {
    /// Pairs where A's grade was better.
    pub wins: u64,
    /// Pairs where B's grade was better.
    pub losses: u64,
    /// Pairs with equal grades (not counted in `n`).
    pub ties: u64,
    /// Non-zero differences: `wins + losses`.
    pub n: u64,
    /// Two-sided exact p-value.
    pub p_value: f64,
}

/// `P(X <= m)` for `X ~ Binomial(n, 1/2)`.
pub fn binomial_half_cdf(n: u64, m: u64) -> f64 {
    if m >= n {
        return 1.0;
    }
    let ln_half_n = -(n as f64) * std::f64::consts::LN_2;
    // ln of C(n,k) / 2^n for k = 0..=m.
    let mut ln_terms = Vec::with_capacity(m as usize + 1);
    let mut ln_term = ln_half_n;
    ln_terms.push(ln_term);
    for k in 0..m {
        ln_term += ((n - k) as f64).ln() - ((k + 1) as f64).ln();
        ln_terms.push(ln_term);
    }
    let max = ln_terms.iter().copied().fold(f64::NEG_INFINITY, f64::max);
    // Sum smallest first for accuracy (terms grow with k for k < n/2).
    let scaled: f64 = ln_terms.iter().map(|&t| (t - max).exp()).sum();
    (max.exp() * scaled).min(1.0)
}

/// Two-sided exact sign-test p-value for `wins` positive and `losses` negative
/// differences (ties already dropped). 1 when there are none.
pub fn sign_test_p_value(wins: u64, losses: u64) -> f64 {
    let n = wins + losses;
    if n == 0 {
        return 1.0;
    }
    (2.0 * binomial_half_cdf(n, wins.min(losses))).min(1.0)
}

/// The sign test over paired differences (A's score minus B's).
pub fn sign_test(differences: impl IntoIterator<Item = i32>) -> SignTest {
    let (mut wins, mut losses, mut ties) = (0, 0, 0);
    for d in differences {
        match d.signum() {
            1 => wins += 1,
            -1 => losses += 1,
            _ => ties += 1,
        }
    }
    SignTest {
        wins,
        losses,
        ties,
        n: wins + losses,
        p_value: sign_test_p_value(wins, losses),
    }
}

/// A sign test between two methods' scores paired by key, and what could not be paired.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct PairedSignTest {
    /// The test over the paired keys.
    #[serde(flatten)]
    pub test: SignTest,
    /// Keys scored for A but not B.
    pub unpaired_a: u64,
    /// Keys scored for B but not A.
    pub unpaired_b: u64,
}

/// Pairs A's and B's scores (+1 / 0 / -1) by key and runs the sign test on A - B.
pub fn paired_sign_test<K: Ord>(a: &BTreeMap<K, i8>, b: &BTreeMap<K, i8>) -> PairedSignTest {
    let test = sign_test(
        a.iter()
            .filter_map(|(k, &sa)| b.get(k).map(|&sb| i32::from(sa) - i32::from(sb))),
    );
    let unpaired_a = a.keys().filter(|k| !b.contains_key(k)).count() as u64;
    let unpaired_b = b.keys().filter(|k| !a.contains_key(k)).count() as u64;
    PairedSignTest {
        test,
        unpaired_a,
        unpaired_b,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// P(X <= m) by Pascal's triangle with halving at each row: every entry is
    /// C(n,k)/2^n computed by additions and exact halvings only (independent of the
    /// log-space recurrence).
    fn cdf_by_pascal(n: usize, m: usize) -> f64 {
        let mut row = vec![1.0_f64];
        for _ in 0..n {
            let mut next = vec![0.0; row.len() + 1];
            for (k, &v) in row.iter().enumerate() {
                next[k] += v / 2.0;
                next[k + 1] += v / 2.0;
            }
            row = next;
        }
        row[..=m.min(n)].iter().sum()
    }

    fn rel_err(a: f64, b: f64) -> f64 {
        (a - b).abs() / b.abs().max(f64::MIN_POSITIVE)
    }

    #[test]
    fn cdf_matches_pascal_triangle() {
        for n in [1_u64, 2, 5, 22, 57, 100, 301, 600] {
            for m in [0, 1, n / 10, n / 3, n / 2, n.saturating_sub(1)] {
                let want = cdf_by_pascal(n as usize, m as usize);
                let got = binomial_half_cdf(n, m);
                assert!(rel_err(got, want) < 1e-11, "n={n} m={m}: {got} vs {want}");
            }
        }
    }

    #[test]
    fn small_cases_by_hand() {
        // n = 1: P = 2 * 1/2 = 1.  n = 5, 5-0: 2 / 32.  n = 6, 5-1: 2 * 7/64.
        assert_eq!(sign_test_p_value(1, 0), 1.0);
        assert!(rel_err(sign_test_p_value(5, 0), 2.0 / 32.0) < 1e-14);
        assert!(rel_err(sign_test_p_value(1, 5), 14.0 / 64.0) < 1e-14);
        assert_eq!(sign_test_p_value(0, 0), 1.0);
        assert_eq!(sign_test_p_value(7, 7), 1.0);
    }

    #[test]
    fn sign_test_counts_and_pairs() {
        let t = sign_test([2, 1, 0, -1, 0, 1, -2]);
        assert_eq!((t.wins, t.losses, t.ties, t.n), (3, 2, 2, 5));
        let a: BTreeMap<u32, i8> = [(1, 1), (2, 0), (3, -1), (4, 1)].into();
        let b: BTreeMap<u32, i8> = [(1, -1), (2, 0), (3, 1), (5, 0)].into();
        let p = paired_sign_test(&a, &b);
        assert_eq!((p.test.wins, p.test.losses, p.test.ties), (1, 1, 1));
        assert_eq!((p.unpaired_a, p.unpaired_b), (1, 1));
    }

    #[test]
    fn large_n_does_not_underflow() {
        // 2^-5000 underflows f64, yet the tail near the middle is well defined.
        let (n, m) = (5000_u64, 2400_u64);
        let want = cdf_by_pascal(n as usize, m as usize);
        assert!(rel_err(binomial_half_cdf(n, m), want) < 1e-9);
        // Normal approximation as a sanity bound: z = 99.5 / sqrt(1250) = 2.814,
        // two-sided tail 0.0049.
        let p = sign_test_p_value(m, n - m);
        assert!((p - 0.0049).abs() < 0.0002, "{p}");
    }
}
