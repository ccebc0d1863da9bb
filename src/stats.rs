//! Descriptive statistics of samples: medians and percentiles (benchmarks, residuals,
//! trial times). The one median of the crate: the middle value of an odd count, the
//! mean of the two middle values of an even count.

/// Median of a sample (sorts it): the middle value, or the mean of the two middle
/// values for an even count; NaN for an empty sample.
pub fn median(samples: &mut [f64]) -> f64 {
    if samples.is_empty() {
        return f64::NAN;
    }
    samples.sort_by(f64::total_cmp);
    let n = samples.len();
    if n % 2 == 1 {
        samples[n / 2]
    } else {
        0.5 * (samples[n / 2 - 1] + samples[n / 2])
    }
}

/// [`median`] of the finite values among `values`; `None` when there are none.
pub fn finite_median(values: impl IntoIterator<Item = f64>) -> Option<f64> {
    let mut finite: Vec<f64> = values.into_iter().filter(|x| x.is_finite()).collect();
    (!finite.is_empty()).then(|| median(&mut finite))
}

/// The `p`-quantile (0..=1, nearest rank) of a sample (sorts it); NaN when empty.
pub fn percentile(samples: &mut [f64], p: f64) -> f64 {
    if samples.is_empty() {
        return f64::NAN;
    }
    samples.sort_by(|a, b| a.total_cmp(b));
    let rank = ((samples.len() - 1) as f64 * p.clamp(0.0, 1.0)).round() as usize;
    samples[rank]
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_median_of_an_even_count_is_the_mean_of_the_middle_two() {
        assert_eq!(median(&mut [3.0, 1.0, 2.0]), 2.0);
        assert_eq!(median(&mut [4.0, 1.0, 3.0, 2.0]), 2.5);
        assert_eq!(median(&mut [7.0]), 7.0);
        assert!(median(&mut []).is_nan());
        assert_eq!(
            finite_median([1.0, f64::NAN, 4.0, f64::INFINITY]),
            Some(2.5)
        );
        assert_eq!(finite_median([f64::NAN]), None);
    }

    #[test]
    fn percentiles_are_nearest_rank() {
        let mut v = [5.0, 1.0, 4.0, 2.0, 3.0];
        assert_eq!(percentile(&mut v, 0.0), 1.0);
        assert_eq!(percentile(&mut v, 1.0), 5.0);
        assert_eq!(percentile(&mut v, 0.5), 3.0);
        assert!(percentile(&mut [], 0.5).is_nan());
    }
}
