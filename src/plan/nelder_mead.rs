//! Nelder–Mead simplex minimisation with the semantics of Lagarias, Reeds, Wright and
//! Wright (1998), as Matlab's `fminsearch` implements them.
//!
//! - Initial simplex: `x0` and, for each coordinate `j`, `x0` with component `j`
//!   scaled by 1.05 (or set to 0.00025 when it is zero).
//! - Coefficients: reflection 1, expansion 2, contraction (outside and inside) 0.5,
//!   shrink 0.5.
//! - Each iteration: reflect the worst vertex through the centroid of the others;
//!   expand if the reflection beats the best vertex (keep the expansion only if it
//!   beats the reflection); accept the reflection if it beats the second worst;
//!   otherwise contract outside (if the reflection beats the worst; accepted when
//!   not worse than the reflection) or inside (accepted when strictly better than the
//!   worst), and shrink toward the best vertex when the contraction fails.
//! - Ties: vertices are re-ordered by a stable sort after each step with the new
//!   vertex last, so a new vertex goes after the old ones it ties with and a shrink
//!   keeps the best vertex first among equals (Lagarias et al.'s rules).
//! - Stops when the simplex's spread in function value is within `tol_fun` **and**
//!   its spread in every coordinate from the best vertex is within `tol_x` (each
//!   floored at 10 ulp of the best value), or after `max_iterations` iterations or
//!   `max_evaluations` evaluations (both 200 n by default). The initial simplex counts
//!   as one iteration, as in `fminsearch`.
//!
//! NaN values are treated as `+inf`, so a point where the function is undefined is
//! never preferred; an infeasible point may be given `+inf` on purpose.

/// Stopping rules of [`nelder_mead`] (the `fminsearch` defaults by `Default`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct NelderMeadOptions {
    /// Tolerance on the simplex size in each coordinate (`TolX`).
    pub tol_x: f64,
    /// Tolerance on the spread of function values over the simplex (`TolFun`).
    pub tol_fun: f64,
    /// Iteration limit; `None` is 200 times the dimension (`MaxIter`).
    pub max_iterations: Option<usize>,
    /// Evaluation limit; `None` is 200 times the dimension (`MaxFunEvals`).
    pub max_evaluations: Option<usize>,
}

impl Default for NelderMeadOptions {
    fn default() -> Self {
        NelderMeadOptions {
            tol_x: 1e-4,
            tol_fun: 1e-4,
            max_iterations: None,
            max_evaluations: None,
        }
    }
}

/// The outcome of one [`nelder_mead`] run.
#[derive(Debug, Clone, PartialEq)]
pub struct NelderMeadResult {
    /// The best vertex.
    pub x: Vec<f64>,
    /// The function value there.
    pub fx: f64,
    /// Iterations, counting the initial simplex as one (as `fminsearch`).
    pub iterations: usize,
    /// Function evaluations.
    pub evaluations: usize,
    /// True when the tolerances were met (false: an iteration or evaluation limit).
    pub converged: bool,
}

/// Relative perturbation of a non-zero component in the initial simplex.
const USUAL_DELTA: f64 = 0.05;
/// Value given to a zero component in the initial simplex.
const ZERO_TERM_DELTA: f64 = 0.00025;
const RHO: f64 = 1.0;
const CHI: f64 = 2.0;
const PSI: f64 = 0.5;
const SIGMA: f64 = 0.5;

/// Spacing of doubles at `x` (Matlab's `eps(x)`).
fn ulp(x: f64) -> f64 {
    let a = x.abs();
    if !a.is_finite() {
        return f64::NAN;
    }
    f64::from_bits(a.to_bits() + 1) - a
}

/// Minimises `f` from `x0` (see the module doc for the exact semantics).
///
/// Returns the best vertex, its value, the iterations and the evaluations. An empty
/// `x0` returns at once with `f(x0)`.
pub fn nelder_mead(
    f: impl FnMut(&[f64]) -> f64,
    x0: &[f64],
    options: &NelderMeadOptions,
) -> NelderMeadResult {
    minimise(f, x0, None, options)
}

/// [`nelder_mead`] with a given initial simplex: `x0` and, for each coordinate `j`,
/// `x0` with `steps[j]` added to component `j` (for coordinates centred on the
/// start, where `fminsearch`'s 5 % rule would give a vanishing step). `steps` must
/// have the length of `x0`.
pub fn nelder_mead_with_steps(
    f: impl FnMut(&[f64]) -> f64,
    x0: &[f64],
    steps: &[f64],
    options: &NelderMeadOptions,
) -> NelderMeadResult {
    assert_eq!(steps.len(), x0.len(), "one initial step per coordinate");
    minimise(f, x0, Some(steps), options)
}

fn minimise(
    mut f: impl FnMut(&[f64]) -> f64,
    x0: &[f64],
    steps: Option<&[f64]>,
    options: &NelderMeadOptions,
) -> NelderMeadResult {
    let n = x0.len();
    let mut eval = |x: &[f64]| {
        let v = f(x);
        if v.is_nan() {
            f64::INFINITY
        } else {
            v
        }
    };
    if n == 0 {
        let fx = eval(x0);
        return NelderMeadResult {
            x: Vec::new(),
            fx,
            iterations: 0,
            evaluations: 1,
            converged: true,
        };
    }
    let max_iterations = options.max_iterations.unwrap_or(200 * n);
    let max_evaluations = options.max_evaluations.unwrap_or(200 * n);

    // Vertex j is vertices[j*n..(j+1)*n]; order[k] is the index of the k-th best.
    let mut vertices = vec![0.0; (n + 1) * n];
    let mut values = vec![0.0; n + 1];
    vertices[..n].copy_from_slice(x0);
    values[0] = eval(x0);
    for j in 0..n {
        let y = &mut vertices[(j + 1) * n..(j + 2) * n];
        y.copy_from_slice(x0);
        y[j] = if let Some(steps) = steps {
            y[j] + steps[j]
        } else if y[j] != 0.0 {
            (1.0 + USUAL_DELTA) * y[j]
        } else {
            ZERO_TERM_DELTA
        };
        values[j + 1] = eval(&vertices[(j + 1) * n..(j + 2) * n]);
    }
    let mut order: Vec<usize> = (0..=n).collect();
    let sort = |order: &mut Vec<usize>, values: &[f64]| {
        // Stable: among equal values the earlier position stays first.
        order.sort_by(|&a, &b| values[a].total_cmp(&values[b]));
    };
    sort(&mut order, &values);
    let mut iterations = 1;
    let mut evaluations = n + 1;

    let mut centroid = vec![0.0; n];
    let mut xr = vec![0.0; n];
    let mut xe = vec![0.0; n];
    let mut xc = vec![0.0; n];
    let mut converged = false;
    while evaluations < max_evaluations && iterations < max_iterations {
        let best = order[0];
        let fbest = values[best];
        let vbest = &vertices[best * n..(best + 1) * n];
        let fun_spread = order[1..]
            .iter()
            .map(|&j| (fbest - values[j]).abs())
            .fold(0.0, f64::max);
        let x_spread = order[1..]
            .iter()
            .flat_map(|&j| {
                vertices[j * n..(j + 1) * n]
                    .iter()
                    .zip(vbest)
                    .map(|(a, b)| (a - b).abs())
            })
            .fold(0.0, f64::max);
        let vmax = vbest.iter().copied().fold(f64::NEG_INFINITY, f64::max);
        // A NaN spread (from +inf - +inf) compares false: not converged.
        if fun_spread <= options.tol_fun.max(10.0 * ulp(fbest))
            && x_spread <= options.tol_x.max(10.0 * ulp(vmax))
        {
            converged = true;
            break;
        }
        let worst = order[n];
        let second_worst = order[n - 1];
        centroid.iter_mut().for_each(|c| *c = 0.0);
        for &j in &order[..n] {
            for (c, v) in centroid.iter_mut().zip(&vertices[j * n..(j + 1) * n]) {
                *c += v;
            }
        }
        centroid.iter_mut().for_each(|c| *c /= n as f64);
        let vworst: Vec<f64> = vertices[worst * n..(worst + 1) * n].to_vec();
        let combine = |out: &mut [f64], a: f64, b: f64| {
            // out = a * centroid + b * worst
            for ((o, c), w) in out.iter_mut().zip(&centroid).zip(&vworst) {
                *o = a * c + b * w;
            }
        };
        combine(&mut xr, 1.0 + RHO, -RHO);
        let fxr = eval(&xr);
        evaluations += 1;
        let mut replace: Option<(&[f64], f64)> = None;
        let mut shrink = false;
        if fxr < fbest {
            combine(&mut xe, 1.0 + RHO * CHI, -RHO * CHI);
            let fxe = eval(&xe);
            evaluations += 1;
            replace = Some(if fxe < fxr { (&xe, fxe) } else { (&xr, fxr) });
        } else if fxr < values[second_worst] {
            replace = Some((&xr, fxr));
        } else if fxr < values[worst] {
            combine(&mut xc, 1.0 + PSI * RHO, -PSI * RHO);
            let fxc = eval(&xc);
            evaluations += 1;
            if fxc <= fxr {
                replace = Some((&xc, fxc));
            } else {
                shrink = true;
            }
        } else {
            combine(&mut xc, 1.0 - PSI, PSI);
            let fxcc = eval(&xc);
            evaluations += 1;
            if fxcc < values[worst] {
                replace = Some((&xc, fxcc));
            } else {
                shrink = true;
            }
        }
        if let Some((x, fx)) = replace {
            vertices[worst * n..(worst + 1) * n].copy_from_slice(x);
            values[worst] = fx;
            // The new vertex goes last among ties: move `worst` to the end of `order`
            // before the stable sort.
            order.retain(|&j| j != worst);
            order.push(worst);
        } else if shrink {
            let vbest: Vec<f64> = vertices[best * n..(best + 1) * n].to_vec();
            for &j in &order[1..] {
                let v = &mut vertices[j * n..(j + 1) * n];
                for (x, b) in v.iter_mut().zip(&vbest) {
                    *x = b + SIGMA * (*x - b);
                }
                values[j] = eval(&vertices[j * n..(j + 1) * n]);
            }
            evaluations += n;
        }
        sort(&mut order, &values);
        iterations += 1;
    }
    let best = order[0];
    NelderMeadResult {
        x: vertices[best * n..(best + 1) * n].to_vec(),
        fx: values[best],
        iterations,
        evaluations,
        converged,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn rosenbrock(x: &[f64]) -> f64 {
        100.0 * (x[1] - x[0] * x[0]).powi(2) + (1.0 - x[0]).powi(2)
    }

    #[test]
    fn rosenbrock_matches_fminsearch() {
        // Matlab's documentation: from [-1.2, 1], f = 8.17766e-10 after 85 iterations
        // and 159 evaluations; its banana example from [-1.9, 2]: 114 and 210.
        let r = nelder_mead(rosenbrock, &[-1.2, 1.0], &NelderMeadOptions::default());
        assert!(r.converged);
        assert!((r.fx - 8.17766e-10).abs() < 1e-14, "{}", r.fx);
        assert!((r.x[0] - 1.0).abs() < 1e-4 && (r.x[1] - 1.0).abs() < 1e-4);
        assert_eq!((r.iterations, r.evaluations), (85, 159));
        let r = nelder_mead(rosenbrock, &[-1.9, 2.0], &NelderMeadOptions::default());
        assert!(r.converged && r.fx < 1e-8, "{r:?}");
        assert_eq!((r.iterations, r.evaluations), (114, 210));
    }

    #[test]
    fn first_steps_follow_the_rules_by_hand() {
        // f = (x - 3)^2 from 1: simplex {1, 1.05}; reflect to 1.1 beats the best, so
        // expand to 1.15 (kept, better); then reflect 1.25, expand 1.35.
        let mut seen = Vec::new();
        nelder_mead(
            |x| {
                seen.push(x[0]);
                (x[0] - 3.0).powi(2)
            },
            &[1.0],
            &NelderMeadOptions::default(),
        );
        let want = [1.0, 1.05, 1.1, 1.15, 1.25, 1.35];
        for (got, want) in seen.iter().zip(want) {
            assert!((got - want).abs() < 1e-12, "{seen:?}");
        }
        // From the minimum: simplex {3, 3.15}; the reflection 2.85 ties the worst, so
        // contract inside (3.075), again (2.925 ties; 3.0375).
        seen.clear();
        nelder_mead(
            |x| {
                seen.push(x[0]);
                (x[0] - 3.0).powi(2)
            },
            &[3.0],
            &NelderMeadOptions::default(),
        );
        let want = [3.0, 3.15, 2.85, 3.075, 2.925, 3.0375];
        for (got, want) in seen.iter().zip(want) {
            assert!((got - want).abs() < 1e-12, "{seen:?}");
        }
        // A zero component starts at 0.00025.
        seen.clear();
        nelder_mead(
            |x| {
                seen.push(x[1]);
                x[0] * x[0] + x[1] * x[1]
            },
            &[1.0, 0.0],
            &NelderMeadOptions::default(),
        );
        assert_eq!(&seen[..3], &[0.0, 0.0, 0.00025]);
    }

    #[test]
    fn given_steps_make_the_initial_simplex() {
        let mut seen = Vec::new();
        let r = nelder_mead_with_steps(
            |x| {
                seen.push([x[0], x[1]]);
                (x[0] - 0.3).powi(2) + (x[1] + 0.2).powi(2)
            },
            &[0.0, 0.0],
            &[0.1, -0.05],
            &NelderMeadOptions::default(),
        );
        assert_eq!(&seen[..3], &[[0.0, 0.0], [0.1, 0.0], [0.0, -0.05]]);
        assert!(
            (r.x[0] - 0.3).abs() < 1e-2 && (r.x[1] + 0.2).abs() < 1e-2,
            "{r:?}"
        );
    }

    #[test]
    fn ties_keep_the_first_vertex() {
        // A constant function: every step ties, the simplex shrinks onto x0, which
        // stays the best vertex.
        let x0 = [0.3, -2.0, 5.0];
        let r = nelder_mead(|_| 1.0, &x0, &NelderMeadOptions::default());
        assert!(r.converged);
        assert_eq!(r.x, x0.to_vec());
        assert_eq!(r.fx, 1.0);
    }

    #[test]
    fn quadratic_minimum_and_limits() {
        let f = |x: &[f64]| {
            (x[0] - 1.0).powi(2) + 2.0 * (x[1] + 2.0).powi(2) + 3.0 * (x[2] - 0.5).powi(2)
        };
        // The default tolerances stop within TolFun of the minimum value...
        let r = nelder_mead(f, &[0.0, 0.0, 0.0], &NelderMeadOptions::default());
        assert!(r.converged && r.fx < 1e-4, "{r:?}");
        for (x, c) in r.x.iter().zip([1.0, -2.0, 0.5]) {
            assert!((x - c).abs() < 1e-2, "{r:?}");
        }
        // ...tight ones at the minimum.
        let tight = NelderMeadOptions {
            tol_x: 1e-9,
            tol_fun: 1e-14,
            ..NelderMeadOptions::default()
        };
        let r = nelder_mead(f, &[0.0, 0.0, 0.0], &tight);
        assert!(r.converged && r.fx < 1e-12, "{r:?}");
        for (x, c) in r.x.iter().zip([1.0, -2.0, 0.5]) {
            assert!((x - c).abs() < 1e-6, "{r:?}");
        }
        // An evaluation limit stops the search early, unconverged.
        let options = NelderMeadOptions {
            max_evaluations: Some(40),
            ..NelderMeadOptions::default()
        };
        let r = nelder_mead(rosenbrock, &[-1.2, 1.0], &options);
        assert!(!r.converged && (40..=42).contains(&r.evaluations), "{r:?}");
        // NaN counts as +inf: the search walks away from where f is undefined.
        let r = nelder_mead(
            |x| {
                if x[0] < 0.5 {
                    f64::NAN
                } else {
                    (x[0] - 2.0).powi(2)
                }
            },
            &[1.0],
            &NelderMeadOptions::default(),
        );
        assert!((r.x[0] - 2.0).abs() < 1e-3, "{r:?}");
    }
}
