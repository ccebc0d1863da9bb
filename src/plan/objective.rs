//! The objective of eq. 2 over the example grasps of one task:
//!
//! `f(X) = sum_{i,k in task} P(param(T_i^-1 X) - theta_ik) psi(q_ik) phi_i`
//!
//! reported **with** the normalising constants of the densities (units: 1/(m^3 rad^3)),
//! so that runs compare. It is evaluated in log space (log-sum-exp over the grasps)
//! so that far from every grasp it stays finite instead of underflowing to 0; the
//! optimiser minimises `-ln f`, which has the same argmax as `f`.

use super::kernel::{Kernel, KernelTerm};
use super::weights::Weights;
use super::{ExampleGrasp, ModelFit, PlanError};
use crate::geometry::{param_difference, params_from_pose, pose_from_params, Pose, PoseParams};

/// One example grasp of the task, ready to evaluate.
#[derive(Debug, Clone)]
struct Term {
    /// Index into the caller's grasps.
    grasp: usize,
    /// Index into the caller's fits.
    model: usize,
    /// Index into [`Objective::frames`].
    frame: usize,
    /// `theta_ik`, canonical (angles as `params_from_pose` gives them).
    theta: PoseParams,
    kernel: KernelTerm,
    /// `ln psi(q_ik) + ln phi_i` (may be `-inf`: the grasp does not count).
    log_weight: f64,
}

/// `model_from_base` of one model, as a rotation matrix (rows) and a translation.
/// Plain arrays: the hot loop stays fast without inlining nalgebra's generics.
#[derive(Debug, Clone)]
struct Frame {
    rotation: [[f64; 3]; 3],
    translation: [f64; 3],
}

/// `R = Rz(az) Ry(ay) Rx(ax)` as rows (the URDF rpy convention of `pose_from_params`).
#[inline]
fn rotation_from_rpy(ax: f64, ay: f64, az: f64) -> [[f64; 3]; 3] {
    let (sr, cr) = ax.sin_cos();
    let (sp, cp) = ay.sin_cos();
    let (sy, cy) = az.sin_cos();
    [
        [cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
        [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
        [-sp, cp * sr, cp * cr],
    ]
}

/// The rpy angles of a rotation matrix, with the same branches as nalgebra's
/// `Rotation3::euler_angles` (so as `params_from_pose`).
#[inline]
fn rpy_from_rotation(m: &[[f64; 3]; 3]) -> (f64, f64, f64) {
    if m[2][0].abs() < 1.0 {
        let pitch = -m[2][0].asin();
        let c = pitch.cos();
        (
            (m[2][1] / c).atan2(m[2][2] / c),
            pitch,
            (m[1][0] / c).atan2(m[0][0] / c),
        )
    } else if m[2][0] <= -1.0 {
        (m[0][1].atan2(m[0][2]), std::f64::consts::FRAC_PI_2, 0.0)
    } else {
        (-m[0][1].atan2(-m[0][2]), -std::f64::consts::FRAC_PI_2, 0.0)
    }
}

/// The objective of eq. 2 for one task, with everything that does not depend on the
/// candidate pose precomputed.
#[derive(Debug, Clone)]
pub struct Objective {
    frames: Vec<Frame>,
    terms: Vec<Term>,
    models: usize,
}

/// The objective at one pose, split by model and by grasp.
#[derive(Debug, Clone, PartialEq)]
pub struct Breakdown {
    /// `ln f`.
    pub log_value: f64,
    /// `ln` of each model's share of the sum (`-inf` for models without a task grasp),
    /// indexed like the fits.
    pub per_model_log: Vec<f64>,
    /// `(grasp index, ln of its term)` for each grasp of the task.
    pub per_grasp_log: Vec<(usize, f64)>,
}

/// Fails with a message naming `what` unless `value` is finite and `>= 0` (or `> 0`).
pub(crate) fn check_value(
    what: &str,
    value: f64,
    strictly_positive: bool,
) -> Result<(), PlanError> {
    let ok = value.is_finite()
        && if strictly_positive {
            value > 0.0
        } else {
            value >= 0.0
        };
    if ok {
        Ok(())
    } else {
        Err(PlanError::BadValue {
            what: what.to_string(),
            value,
            problem: if strictly_positive {
                "must be a finite number > 0"
            } else {
                "must be a finite number >= 0"
            },
        })
    }
}

/// Validates fits and grasps (all of them, not only the task's).
pub fn validate(fits: &[ModelFit], grasps: &[ExampleGrasp]) -> Result<(), PlanError> {
    if fits.is_empty() {
        return Err(PlanError::NoFits);
    }
    if grasps.is_empty() {
        return Err(PlanError::NoGrasps);
    }
    for (i, fit) in fits.iter().enumerate() {
        let what = |field: &str| format!("fit {i} ({}) {field}", fit.name);
        check_value(&what("eps_m2"), fit.eps_m2, false)?;
        check_value(&what("sigma_m2"), fit.sigma_m2, false)?;
        let p = params_from_pose(&fit.base_from_model);
        let q = fit.base_from_model.rotation.quaternion();
        for (j, v) in p.iter().chain(q.coords.iter()).enumerate() {
            if !v.is_finite() {
                return Err(PlanError::BadValue {
                    what: what(&format!("base_from_model component {j}")),
                    value: *v,
                    problem: "must be finite",
                });
            }
        }
    }
    for (g, grasp) in grasps.iter().enumerate() {
        let what = |field: &str| format!("grasp {g} (task {}) {field}", grasp.task);
        if grasp.model >= fits.len() {
            return Err(PlanError::ModelIndex {
                grasp: g,
                model: grasp.model,
                count: fits.len(),
            });
        }
        for (j, v) in grasp.model_from_palm.iter().enumerate() {
            if !v.is_finite() {
                return Err(PlanError::BadValue {
                    what: what(&format!("model_from_palm[{j}]")),
                    value: *v,
                    problem: "must be finite",
                });
            }
        }
        check_value(&what("q"), grasp.q, false)?;
        if !grasp.spread_rad.is_finite() {
            return Err(PlanError::BadValue {
                what: what("spread_rad"),
                value: grasp.spread_rad,
                problem: "must be finite",
            });
        }
        for (j, s) in grasp.sigma.iter().enumerate() {
            check_value(&what(&format!("sigma[{j}]")), *s, true)?;
        }
    }
    Ok(())
}

/// Checks the kernel's parameters (finite; `s >= 0`, `b > 0`).
pub fn validate_kernel(kernel: &Kernel) -> Result<(), PlanError> {
    let strictly = matches!(kernel, Kernel::Laplace { .. });
    for (name, value) in kernel.parameters() {
        check_value(&format!("kernel {} {name}", kernel.name()), value, strictly)?;
    }
    Ok(())
}

impl Objective {
    /// The objective for `task` over the given fits and grasps.
    pub fn new(
        fits: &[ModelFit],
        grasps: &[ExampleGrasp],
        task: &str,
        kernel: &Kernel,
        weights: &Weights,
    ) -> Result<Objective, PlanError> {
        validate(fits, grasps)?;
        validate_kernel(kernel)?;
        check_value("weights lambda_psi", weights.lambda_psi, true)?;
        check_value(
            "weights lambda_eps_per_m2",
            weights.lambda_eps_per_m2,
            false,
        )?;
        let mut task_grasps: Vec<usize> = (0..grasps.len())
            .filter(|&g| grasps[g].task == task)
            .collect();
        if task_grasps.is_empty() {
            let mut available: Vec<&str> = grasps.iter().map(|g| g.task.as_str()).collect();
            available.sort_unstable();
            available.dedup();
            return Err(PlanError::NoGraspsForTask {
                task: task.to_string(),
                available: available.join(", "),
            });
        }
        // Group by model so each candidate pose is mapped into each frame once.
        task_grasps.sort_by_key(|&g| grasps[g].model);
        let mut frames = Vec::new();
        let mut frame_of_model = vec![usize::MAX; fits.len()];
        let mut terms = Vec::with_capacity(task_grasps.len());
        for g in task_grasps {
            let grasp = &grasps[g];
            let fit = &fits[grasp.model];
            if frame_of_model[grasp.model] == usize::MAX {
                frame_of_model[grasp.model] = frames.len();
                let model_from_base = fit.base_from_model.inverse();
                let r = model_from_base.rotation.to_rotation_matrix();
                let t = model_from_base.translation.vector;
                frames.push(Frame {
                    rotation: std::array::from_fn(|i| std::array::from_fn(|j| r[(i, j)])),
                    translation: [t.x, t.y, t.z],
                });
            }
            terms.push(Term {
                grasp: g,
                model: grasp.model,
                frame: frame_of_model[grasp.model],
                theta: params_from_pose(&pose_from_params(&grasp.model_from_palm)),
                kernel: kernel.term(&grasp.sigma),
                log_weight: weights.log_psi(grasp.q) + weights.log_phi(fit.eps_m2, fit.sigma_m2),
            });
        }
        if terms.iter().all(|t| t.log_weight == f64::NEG_INFINITY) {
            return Err(PlanError::ZeroWeight {
                task: task.to_string(),
            });
        }
        Ok(Objective {
            frames,
            terms,
            models: fits.len(),
        })
    }

    /// Indices (into the caller's grasps) of the task's grasps, grouped by model.
    pub fn grasps(&self) -> impl Iterator<Item = usize> + '_ {
        self.terms.iter().map(|t| t.grasp)
    }

    /// Calls `visit(term, ln term)` for every grasp of the task at the candidate palm
    /// pose `x` (world parameters).
    #[inline]
    fn for_each_term(&self, x: &PoseParams, mut visit: impl FnMut(&Term, f64)) {
        let rotation = rotation_from_rpy(x[3], x[4], x[5]);
        let mut frame = usize::MAX;
        let mut local = [0.0; 6];
        for term in &self.terms {
            if term.frame != frame {
                frame = term.frame;
                let f = &self.frames[frame];
                let a = &f.rotation;
                // r = a * rotation, t = a * x + translation.
                let r: [[f64; 3]; 3] = std::array::from_fn(|i| {
                    std::array::from_fn(|j| {
                        a[i][0] * rotation[0][j]
                            + a[i][1] * rotation[1][j]
                            + a[i][2] * rotation[2][j]
                    })
                });
                let t: [f64; 3] = std::array::from_fn(|i| {
                    a[i][0] * x[0] + a[i][1] * x[1] + a[i][2] * x[2] + f.translation[i]
                });
                let (ax, ay, az) = rpy_from_rotation(&r);
                local = [t[0], t[1], t[2], ax, ay, az];
            }
            if term.log_weight == f64::NEG_INFINITY {
                continue;
            }
            let d = param_difference(&local, &term.theta);
            visit(term, term.log_weight + term.kernel.log_density(&d));
        }
    }

    /// `ln f(X)` for the palm pose of world parameters `x`.
    pub fn log_value(&self, x: &PoseParams) -> f64 {
        let mut lse = LogSumExp::default();
        self.for_each_term(x, |_, t| lse.add(t));
        lse.value()
    }

    /// `ln f(X)` for a palm pose.
    pub fn log_value_at(&self, pose: &Pose) -> f64 {
        self.log_value(&params_from_pose(pose))
    }

    /// The grasp with the largest term at `x` (the first among equals).
    pub fn dominant_grasp(&self, x: &PoseParams) -> usize {
        let mut best = (self.terms[0].grasp, f64::NEG_INFINITY);
        self.for_each_term(x, |term, t| {
            if t > best.1 {
                best = (term.grasp, t);
            }
        });
        best.0
    }

    /// The objective at `x` split by model and grasp.
    pub fn breakdown(&self, x: &PoseParams) -> Breakdown {
        let mut total = LogSumExp::default();
        let mut per_model = vec![LogSumExp::default(); self.models];
        let mut per_grasp: Vec<(usize, f64)> = self
            .terms
            .iter()
            .map(|t| (t.grasp, f64::NEG_INFINITY))
            .collect();
        let mut slot = 0;
        self.for_each_term(x, |term, t| {
            total.add(t);
            per_model[term.model].add(t);
            while per_grasp[slot].0 != term.grasp {
                slot += 1;
            }
            per_grasp[slot].1 = t;
        });
        Breakdown {
            log_value: total.value(),
            per_model_log: per_model.iter().map(LogSumExp::value).collect(),
            per_grasp_log: per_grasp,
        }
    }
}

/// A running `ln sum exp(t_i)` that never overflows or underflows.
#[derive(Debug, Clone, Copy)]
struct LogSumExp {
    max: f64,
    scaled_sum: f64,
}

impl Default for LogSumExp {
    fn default() -> Self {
        LogSumExp {
            max: f64::NEG_INFINITY,
            scaled_sum: 0.0,
        }
    }
}

impl LogSumExp {
    #[inline]
    fn add(&mut self, t: f64) {
        if t == f64::NEG_INFINITY {
            return;
        }
        if t > self.max {
            self.scaled_sum = self.scaled_sum * (self.max - t).exp() + 1.0;
            self.max = t;
        } else {
            self.scaled_sum += (t - self.max).exp();
        }
    }

    fn value(&self) -> f64 {
        if self.max == f64::NEG_INFINITY {
            f64::NEG_INFINITY
        } else {
            self.max + self.scaled_sum.ln()
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::plan::test_support::{grasp, two_model_database};
    use nalgebra::{Matrix6, Vector6};
    use rand::{Rng, SeedableRng};
    use std::f64::consts::PI;

    /// Eq. 2 written out independently: full covariance matrices, nalgebra's own
    /// parametrisation, plain sums in linear space.
    fn reference_value(
        fits: &[ModelFit],
        grasps: &[ExampleGrasp],
        task: &str,
        kernel: &Kernel,
        weights: &Weights,
        x: &PoseParams,
    ) -> f64 {
        let pose = pose_from_params(x);
        let mut sum = 0.0;
        for g in grasps.iter().filter(|g| g.task == task) {
            let fit = &fits[g.model];
            let local = params_from_pose(&(fit.base_from_model.inverse() * pose));
            let theta = params_from_pose(&pose_from_params(&g.model_from_palm));
            let mut d = [0.0; 6];
            for i in 0..6 {
                d[i] = local[i] - theta[i];
                if i >= 3 {
                    // Wrap by hand: the nearest representative of d modulo 2 pi.
                    while d[i] > PI {
                        d[i] -= 2.0 * PI;
                    }
                    while d[i] < -PI {
                        d[i] += 2.0 * PI;
                    }
                }
            }
            let density = match *kernel {
                Kernel::Gaussian | Kernel::GaussianR { .. } => {
                    let (st, sr) = match *kernel {
                        Kernel::GaussianR {
                            s_translation_m2,
                            s_rotation_rad2,
                        } => (s_translation_m2, s_rotation_rad2),
                        _ => (0.0, 0.0),
                    };
                    let cov = Matrix6::from_diagonal(&Vector6::from_fn(|i, _| {
                        g.sigma[i].powi(2) + if i < 3 { st } else { sr }
                    }));
                    let dv = Vector6::from_column_slice(&d);
                    let q = (dv.transpose() * cov.try_inverse().unwrap() * dv)[0];
                    (-0.5 * q).exp() / ((2.0 * PI).powi(6) * cov.determinant()).sqrt()
                }
                Kernel::Laplace {
                    b_translation_m,
                    b_rotation_rad,
                } => (0..6)
                    .map(|i| {
                        let b = if i < 3 {
                            b_translation_m
                        } else {
                            b_rotation_rad
                        };
                        (-d[i].abs() / b).exp() / (2.0 * b)
                    })
                    .product(),
            };
            let psi = 1.0 - (-weights.lambda_psi * g.q).exp();
            let phi = match weights.fit {
                super::super::FitWeight::Eps => (-weights.lambda_eps_per_m2 * fit.eps_m2).exp(),
                super::super::FitWeight::EpsSigma => {
                    (-weights.lambda_eps_per_m2 * (fit.eps_m2 + fit.sigma_m2)).exp()
                }
            };
            sum += density * psi * phi;
        }
        sum
    }

    #[test]
    fn objective_matches_the_written_out_sum() {
        let (fits, grasps) = two_model_database();
        let weights = Weights::default();
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
        for kernel in [
            Kernel::Gaussian,
            Kernel::GaussianR {
                s_translation_m2: 1e-4,
                s_rotation_rad2: 0.1,
            },
            Kernel::LAPLACE_DEFAULT,
        ] {
            let objective = Objective::new(&fits, &grasps, "side", &kernel, &weights).unwrap();
            for _ in 0..200 {
                // Near the grasps (where the sum is not negligible) and anywhere.
                let x: PoseParams = [
                    rng.gen_range(0.55..0.7),
                    rng.gen_range(-0.1..0.1),
                    rng.gen_range(0.05..0.2),
                    rng.gen_range(-PI..PI),
                    rng.gen_range(-1.5..1.5),
                    rng.gen_range(-PI..PI),
                ];
                let want = reference_value(&fits, &grasps, "side", &kernel, &weights, &x);
                let got = objective.log_value(&x);
                if want > 1e-300 {
                    assert!(
                        (got - want.ln()).abs() < 1e-9,
                        "{} at {x:?}: {got} vs {}",
                        kernel.name(),
                        want.ln()
                    );
                } else {
                    assert!(got < -600.0, "{got}");
                }
                let b = objective.breakdown(&x);
                assert!((b.log_value - got).abs() < 1e-12);
                let sum: f64 = b.per_model_log.iter().map(|l| l.exp()).sum();
                assert!((sum - got.exp()).abs() <= 1e-12 * got.exp().max(1e-300));
            }
        }
    }

    #[test]
    fn plain_rotations_match_nalgebra() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(11);
        for i in 0..1000 {
            let mut p: [f64; 3] = std::array::from_fn(|_| rng.gen_range(-PI..PI));
            if i % 10 == 0 {
                p[1] = if i % 20 == 0 { PI / 2.0 } else { -PI / 2.0 }; // gimbal lock
            }
            let m = rotation_from_rpy(p[0], p[1], p[2]);
            let r = nalgebra::Rotation3::from_euler_angles(p[0], p[1], p[2]);
            for a in 0..3 {
                for b in 0..3 {
                    assert!((m[a][b] - r[(a, b)]).abs() < 1e-15);
                }
            }
            let (x, y, z) = rpy_from_rotation(&m);
            let (rx, ry, rz) = r.euler_angles();
            assert!((x - rx).abs() < 1e-12 && (y - ry).abs() < 1e-12 && (z - rz).abs() < 1e-12);
        }
    }

    #[test]
    fn far_from_every_grasp_the_log_stays_finite() {
        let (fits, grasps) = two_model_database();
        let objective = Objective::new(
            &fits,
            &grasps,
            "side",
            &Kernel::Gaussian,
            &Weights::default(),
        )
        .unwrap();
        let v = objective.log_value(&[5.0, 5.0, 5.0, 0.0, 0.0, 0.0]);
        assert!(v.is_finite() && v < -1e4, "{v}");
    }

    #[test]
    fn grasps_of_zero_quality_do_not_count() {
        let (fits, mut grasps) = two_model_database();
        let kernel = Kernel::LAPLACE_DEFAULT;
        let w = Weights::default();
        let x = [0.62, 0.01, 0.1, 0.0, 1.2, 0.3];
        let before = Objective::new(&fits, &grasps, "side", &kernel, &w).unwrap();
        let gone = before.breakdown(&x).per_grasp_log[0];
        grasps[gone.0].q = 0.0;
        let after = Objective::new(&fits, &grasps, "side", &kernel, &w).unwrap();
        let diff = before.log_value(&x).exp() - after.log_value(&x).exp();
        assert!((diff - gone.1.exp()).abs() < 1e-9 * diff.abs());
        for g in grasps.iter_mut() {
            g.q = 0.0;
        }
        assert!(matches!(
            Objective::new(&fits, &grasps, "side", &kernel, &w),
            Err(PlanError::ZeroWeight { .. })
        ));
    }

    #[test]
    fn bad_inputs_are_named() {
        let (mut fits, mut grasps) = two_model_database();
        let k = Kernel::Gaussian;
        let w = Weights::default();
        let err = Objective::new(&fits, &grasps, "pour", &k, &w).unwrap_err();
        assert!(matches!(err, PlanError::NoGraspsForTask { .. }));
        assert!(err.to_string().contains("pour") && err.to_string().contains("side"));
        assert!(matches!(
            Objective::new(&[], &grasps, "side", &k, &w),
            Err(PlanError::NoFits)
        ));
        assert!(matches!(
            Objective::new(&fits, &[], "side", &k, &w),
            Err(PlanError::NoGrasps)
        ));
        grasps[1].sigma[4] = 0.0;
        let err = Objective::new(&fits, &grasps, "side", &k, &w)
            .unwrap_err()
            .to_string();
        assert!(err.contains("grasp 1") && err.contains("sigma[4]"), "{err}");
        grasps[1].sigma[4] = 0.1;
        fits[1].eps_m2 = f64::NAN;
        let err = Objective::new(&fits, &grasps, "side", &k, &w)
            .unwrap_err()
            .to_string();
        assert!(
            err.contains("fit 1") && err.contains("eps_m2") && err.contains("NaN"),
            "{err}"
        );
        fits[1].eps_m2 = 1e-5;
        grasps.push(grasp(7, "side", [0.0; 6], 0.1));
        let err = Objective::new(&fits, &grasps, "side", &k, &w)
            .unwrap_err()
            .to_string();
        assert!(err.contains("model 7"), "{err}");
    }
}
