//! A small Levenberg–Marquardt minimiser of a sum of squared residuals over a
//! manifold (the caller's `retract` applies a parameter step to a state).

use nalgebra::{DMatrix, DVector};

/// Step of the central-difference Jacobian (parameters are rad and m).
const JACOBIAN_STEP: f64 = 1e-6;
/// Stop when a step lowers the cost by less than this fraction.
const RELATIVE_DECREASE: f64 = 1e-12;

/// The result of a minimisation: the best state seen and its cost.
#[derive(Debug, Clone)]
pub(super) struct LmOutcome<S> {
    /// The best state (never worse than the start).
    pub state: S,
    /// Sum of squared residuals at the start.
    pub start_cost: f64,
    /// Sum of squared residuals at `state`.
    pub cost: f64,
    /// Accepted steps.
    pub iterations: usize,
}

/// Minimises `|residuals(state)|²` from `start` with `n_params` local parameters.
/// Only steps that lower the cost are accepted, so the outcome is never worse
/// than the start (a non-finite start cost returns the start unchanged).
pub(super) fn levenberg_marquardt<S: Clone>(
    start: S,
    n_params: usize,
    residuals: impl Fn(&S) -> DVector<f64>,
    retract: impl Fn(&S, &DVector<f64>) -> S,
    max_iterations: usize,
) -> LmOutcome<S> {
    let cost_of = |s: &S| residuals(s).norm_squared();
    let start_cost = cost_of(&start);
    let mut out = LmOutcome {
        state: start,
        start_cost,
        cost: start_cost,
        iterations: 0,
    };
    if !start_cost.is_finite() {
        return out;
    }
    let mut lambda = 1e-3;
    for _ in 0..max_iterations {
        let r = residuals(&out.state);
        let mut jac = DMatrix::zeros(r.len(), n_params);
        for k in 0..n_params {
            let mut step = DVector::zeros(n_params);
            step[k] = JACOBIAN_STEP;
            let plus = residuals(&retract(&out.state, &step));
            let minus = residuals(&retract(&out.state, &(-step)));
            jac.set_column(k, &((plus - minus) / (2.0 * JACOBIAN_STEP)));
        }
        let jtj = jac.transpose() * &jac;
        let gradient = jac.transpose() * &r;
        if gradient.amax() < 1e-15 {
            break;
        }
        let mut accepted = false;
        for _ in 0..16 {
            let mut damped = jtj.clone();
            for k in 0..n_params {
                damped[(k, k)] += lambda * (jtj[(k, k)] + 1e-9);
            }
            let Some(chol) = damped.cholesky() else {
                lambda *= 10.0;
                continue;
            };
            let delta = -chol.solve(&gradient);
            let candidate = retract(&out.state, &delta);
            let cost = cost_of(&candidate);
            if cost.is_finite() && cost < out.cost {
                let decrease = out.cost - cost;
                out.state = candidate;
                out.cost = cost;
                out.iterations += 1;
                lambda = (lambda / 3.0).max(1e-12);
                accepted = decrease > RELATIVE_DECREASE * cost;
                break;
            }
            lambda *= 4.0;
        }
        if !accepted {
            break;
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fits_an_exponential_and_never_increases_cost() {
        // y = a exp(b x): residuals nonlinear in b.
        let xs: Vec<f64> = (0..20).map(|i| i as f64 * 0.1).collect();
        let ys: Vec<f64> = xs.iter().map(|x| 2.0 * (-1.3 * x).exp()).collect();
        let residuals = |p: &[f64; 2]| {
            DVector::from_iterator(
                xs.len(),
                xs.iter().zip(&ys).map(|(x, y)| p[0] * (p[1] * x).exp() - y),
            )
        };
        let retract = |p: &[f64; 2], d: &DVector<f64>| [p[0] + d[0], p[1] + d[1]];
        let out = levenberg_marquardt([1.0, 0.0], 2, residuals, retract, 100);
        assert!((out.state[0] - 2.0).abs() < 1e-6 && (out.state[1] + 1.3).abs() < 1e-6);
        assert!(out.cost <= out.start_cost);
        // Starting at the optimum stays there.
        let out = levenberg_marquardt([2.0, -1.3], 2, residuals, retract, 100);
        assert_eq!(out.state, [2.0, -1.3]);
    }
}
