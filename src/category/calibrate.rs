//! Calibrated weights of eq. 2 for one category, stored in `category.json` by
//! `cell train` with the numbers they came from.
//!
//! - **Fit weight** `phi = exp(-lambda_eps (eps + sigma))` (4b): `lambda_eps = 1 /
//!   median(eps + sigma)` over leave-one-out fits of the category's own models (each
//!   model seen by the camera, the others registered to it), so that a typical fit
//!   weighs `1/e`, a fit twice as bad `1/e^2`, and a perfect one 1. A fixed `lambda_eps`
//!   of 1e4 / m^2 only reaches `1/e` at a 10 mm rms fit: registered mugs fit to a few
//!   millimetres, every model then weighs about 0.9, and the weights tell nothing.
//! - **Stability weight** `psi(q) = 1 - exp(-lambda_psi q)`: `lambda_psi = ln 2 /
//!   median(q)` over the database's grasps, so that the median grasp weighs 1/2 and
//!   the database's q range maps onto the steep part of `psi` (a fixed 10 put every
//!   mug grasp between 0.59 and 0.94).

use super::CategoryError;
use serde::{Deserialize, Serialize};

/// Minimum, median and maximum of a sample, with its size.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Spread {
    /// Sample size.
    pub count: usize,
    /// Smallest value.
    pub min: f64,
    /// Median (mean of the middle two for an even count).
    pub median: f64,
    /// Largest value.
    pub max: f64,
}

impl Spread {
    /// The spread of `values` (finite ones only); `None` when there are none.
    pub fn of(values: &[f64]) -> Option<Spread> {
        let mut v: Vec<f64> = values.iter().copied().filter(|x| x.is_finite()).collect();
        if v.is_empty() {
            return None;
        }
        let median = crate::stats::median(&mut v);
        let n = v.len();
        Some(Spread {
            count: n,
            min: v[0],
            median,
            max: v[n - 1],
        })
    }
}

/// How the leave-one-out fits were made.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LooSource {
    /// `partial` (one sim-camera view per model) or `complete`.
    pub view: String,
    /// Seed of placements, views and registration.
    pub seed: u64,
    /// Views (one per held-out model).
    pub views: usize,
    /// Models that failed to register, over all views (left out of the median).
    pub failed: usize,
}

/// The calibrated weights and the numbers they came from.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct WeightCalibration {
    /// `lambda_psi = ln 2 / median(q)`.
    pub lambda_psi: f64,
    /// `lambda_eps = 1 / median(eps + sigma)` (1/m^2).
    pub lambda_eps_per_m2: f64,
    /// The grasps' quality.
    pub q: Spread,
    /// `psi` at the smallest and the largest q.
    pub psi_range: [f64; 2],
    /// `eps + sigma` of the leave-one-out fits (m^2).
    pub fit_score_m2: Spread,
    /// `phi` at the best and the worst leave-one-out fit.
    pub phi_range: [f64; 2],
    /// How the fits were made.
    pub loo: LooSource,
}

/// The calibration from the database's grasp qualities `q` and the leave-one-out
/// fit scores `eps + sigma` (m^2). Errors name the sample that is empty or not
/// positive.
pub fn calibrate(
    q: &[f64],
    fit_scores_m2: &[f64],
    loo: LooSource,
) -> Result<WeightCalibration, CategoryError> {
    let invalid = |field: &str, value: String| CategoryError::Invalid {
        what: "weight calibration".into(),
        field: field.into(),
        value,
        problem: "needs at least one finite value with a median > 0".into(),
    };
    let q_spread = Spread::of(q)
        .filter(|s| s.median > 0.0)
        .ok_or_else(|| invalid("q", format!("{q:?}")))?;
    let fit = Spread::of(fit_scores_m2)
        .filter(|s| s.median > 0.0)
        .ok_or_else(|| invalid("leave-one-out eps + sigma", format!("{fit_scores_m2:?}")))?;
    let lambda_psi = std::f64::consts::LN_2 / q_spread.median;
    let lambda_eps_per_m2 = 1.0 / fit.median;
    let psi = |q: f64| -(-lambda_psi * q).exp_m1();
    let phi = |s: f64| (-lambda_eps_per_m2 * s).exp();
    Ok(WeightCalibration {
        lambda_psi,
        lambda_eps_per_m2,
        q: q_spread,
        psi_range: [psi(q_spread.min), psi(q_spread.max)],
        fit_score_m2: fit,
        phi_range: [phi(fit.min), phi(fit.max)],
        loo,
    })
}

impl WeightCalibration {
    /// Checks that both lambdas are finite and positive.
    pub fn validate(&self, what: &str) -> Result<(), CategoryError> {
        for (field, v) in [
            ("weights.lambda_psi", self.lambda_psi),
            ("weights.lambda_eps_per_m2", self.lambda_eps_per_m2),
        ] {
            if !(v.is_finite() && v > 0.0) {
                return Err(CategoryError::Invalid {
                    what: what.to_string(),
                    field: field.into(),
                    value: v.to_string(),
                    problem: "must be finite and > 0".into(),
                });
            }
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn source() -> LooSource {
        LooSource {
            view: "partial".into(),
            seed: 1,
            views: 3,
            failed: 0,
        }
    }

    #[test]
    fn the_median_fit_weighs_one_over_e_and_the_median_grasp_one_half() {
        let q = [0.09, 0.3, 0.15, 0.12];
        let scores = [4e-6, 1e-6, 2e-6, f64::NAN, 8e-6];
        let c = calibrate(&q, &scores, source()).unwrap();
        assert_eq!(c.q.median, 0.135);
        assert_eq!(c.fit_score_m2.count, 4);
        assert!((c.lambda_eps_per_m2 - 1.0 / 3e-6).abs() < 1e-6);
        assert!((-(-c.lambda_psi * 0.135f64).exp_m1() - 0.5).abs() < 1e-12);
        // The weights now tell the fits apart: the best weighs e^(8/3 - 1/3) times the worst.
        let ratio = c.phi_range[0] / c.phi_range[1];
        assert!((ratio.ln() - 7.0 / 3.0).abs() < 1e-9, "{ratio}");
        assert!(
            c.psi_range[0] < 0.4 && c.psi_range[1] > 0.75,
            "{:?}",
            c.psi_range
        );
        c.validate("test").unwrap();
    }

    #[test]
    fn empty_or_zero_samples_are_named() {
        let e = calibrate(&[], &[1e-6], source()).unwrap_err().to_string();
        assert!(e.contains("q"), "{e}");
        let e = calibrate(&[0.1], &[0.0, 0.0], source())
            .unwrap_err()
            .to_string();
        assert!(e.contains("eps + sigma"), "{e}");
        let mut c = calibrate(&[0.1], &[1e-6], source()).unwrap();
        c.lambda_psi = f64::NAN;
        assert!(c
            .validate("db")
            .unwrap_err()
            .to_string()
            .contains("lambda_psi"));
    }
}
