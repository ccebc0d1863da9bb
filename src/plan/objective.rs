//! The objective of eq. 2 over the example grasps of one task:
//!
//! `f(X) = sum_{i,k in task} P(d(T_i^-1 X, theta_ik)) psi(q_ik) phi_i`
//!
//! where `d` is the translation difference and the rotation vector
//! `log(R_theta^T R_X)` in the example grasp's frame ([`super::chart`]): a distance on
//! the rotation group, without the gimbal lock of rpy differences. Reported **with**
//! the normalising constants of the densities (units: 1/(m^3 rad^3)), so that runs
//! compare. It is evaluated in log space (log-sum-exp over the grasps) so that far
//! from every grasp it stays finite instead of underflowing to 0; the optimiser
//! minimises `-ln f`, which has the same argmax as `f`.

use super::chart::{difference, matrix_of, mul, rotation_from_rpy, Mat3};
use super::kernel::{Kernel, KernelTerm};
use super::weights::Weights;
use super::{ExampleGrasp, ModelFit, PlanError};
use crate::geometry::{params_from_pose, pose_from_params, Pose, PoseParams};

/// One example grasp of the task, ready to evaluate.
#[derive(Debug, Clone)]
struct Term {
    /// Index into the caller's grasps.
    grasp: usize,
    /// Index into the caller's fits.
    model: usize,
    /// Index into [`Objective::frames`].
    frame: usize,
    /// `theta_ik`: its rotation (rows) and translation in the model frame.
    theta_rotation: Mat3,
    theta_translation: [f64; 3],
    kernel: KernelTerm,
    /// `ln psi(q_ik) + ln phi_i` (may be `-inf`: the grasp does not count).
    log_weight: f64,
}

/// `model_from_base` of one model, as a rotation matrix (rows) and a translation.
/// Plain arrays: the hot loop stays fast without inlining nalgebra's generics.
#[derive(Debug, Clone)]
struct Frame {
    rotation: Mat3,
    translation: [f64; 3],
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
            let theta = pose_from_params(&grasp.model_from_palm);
            let tt = theta.translation.vector;
            terms.push(Term {
                grasp: g,
                model: grasp.model,
                frame: frame_of_model[grasp.model],
                theta_rotation: matrix_of(&theta),
                theta_translation: [tt.x, tt.y, tt.z],
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
    /// pose of world rotation `rotation` and position `x`.
    #[inline]
    fn for_each_term(&self, rotation: &Mat3, x: &[f64; 3], mut visit: impl FnMut(&Term, f64)) {
        let mut frame = usize::MAX;
        let mut r = [[0.0; 3]; 3];
        let mut t = [0.0; 3];
        for term in &self.terms {
            if term.frame != frame {
                frame = term.frame;
                let f = &self.frames[frame];
                let a = &f.rotation;
                // r = a * rotation, t = a * x + translation.
                r = mul(a, rotation);
                t = std::array::from_fn(|i| {
                    a[i][0] * x[0] + a[i][1] * x[1] + a[i][2] * x[2] + f.translation[i]
                });
            }
            if term.log_weight == f64::NEG_INFINITY {
                continue;
            }
            let d = difference(&r, &t, &term.theta_rotation, &term.theta_translation);
            visit(term, term.log_weight + term.kernel.log_density(&d));
        }
    }

    /// `ln f(X)` for the palm pose of world parameters `x`.
    pub fn log_value(&self, x: &PoseParams) -> f64 {
        let rotation = rotation_from_rpy(x[3], x[4], x[5]);
        self.log_value_rt(&rotation, &[x[0], x[1], x[2]])
    }

    /// `ln f(X)` for a palm pose.
    pub fn log_value_at(&self, pose: &Pose) -> f64 {
        let t = pose.translation.vector;
        self.log_value_rt(&matrix_of(pose), &[t.x, t.y, t.z])
    }

    fn log_value_rt(&self, rotation: &Mat3, x: &[f64; 3]) -> f64 {
        let mut lse = LogSumExp::default();
        self.for_each_term(rotation, x, |_, t| lse.add(t));
        lse.value()
    }

    /// The grasp with the largest term at the palm pose (the first among equals).
    pub fn dominant_grasp(&self, pose: &Pose) -> usize {
        let t = pose.translation.vector;
        let mut best = (self.terms[0].grasp, f64::NEG_INFINITY);
        self.for_each_term(&matrix_of(pose), &[t.x, t.y, t.z], |term, t| {
            if t > best.1 {
                best = (term.grasp, t);
            }
        });
        best.0
    }

    /// The objective at the palm pose split by model and grasp.
    pub fn breakdown(&self, pose: &Pose) -> Breakdown {
        let x = pose.translation.vector;
        let mut total = LogSumExp::default();
        let mut per_model = vec![LogSumExp::default(); self.models];
        let mut per_grasp: Vec<(usize, f64)> = self
            .terms
            .iter()
            .map(|t| (t.grasp, f64::NEG_INFINITY))
            .collect();
        let mut slot = 0;
        self.for_each_term(&matrix_of(pose), &[x.x, x.y, x.z], |term, t| {
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
    use std::f64::consts::{FRAC_PI_2, PI};

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
            // d written out with nalgebra: translation in the model frame, the
            // rotation vector of theta^-1 * local (the shortest representative).
            let local = fit.base_from_model.inverse() * pose;
            let theta = pose_from_params(&g.model_from_palm);
            let dt = local.translation.vector - theta.translation.vector;
            let dr = (theta.rotation.inverse() * local.rotation).scaled_axis();
            let d = [dt.x, dt.y, dt.z, dr.x, dr.y, dr.z];
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
                let b = objective.breakdown(&pose_from_params(&x));
                assert!((b.log_value - got).abs() < 1e-12);
                let sum: f64 = b.per_model_log.iter().map(|l| l.exp()).sum();
                assert!((sum - got.exp()).abs() <= 1e-12 * got.exp().max(1e-300));
            }
        }
    }

    /// Issue 20: two grasps 5 deg apart at pitch -89 deg (stored as rpy, like the
    /// database's side grasps) are 5 deg apart, and with equal fits, q and Sigma their
    /// terms of eq. 2 half way between agree (within a factor of 2) for every kernel.
    #[test]
    fn grasps_five_degrees_apart_at_pitch_minus_89_share_the_objective() {
        use crate::plan::chart::{pose_difference, rotated_about_own_axes};
        let a_params = [0.0, 0.08, 0.06, -FRAC_PI_2, -89f64.to_radians(), -FRAC_PI_2];
        let a = pose_from_params(&a_params);
        let model = pose_from_params(&[0.6, 0.0, 0.0, 0.0, 0.0, 0.3]);
        let fits: Vec<ModelFit> = ["mug_a", "mug_b"]
            .iter()
            .map(|name| ModelFit {
                name: name.to_string(),
                base_from_model: model,
                eps_m2: 1e-5,
                sigma_m2: 2e-6,
            })
            .collect();
        let five = 5f64.to_radians();
        let mut largest_rpy_difference: f64 = 0.0;
        for axis in [
            [0.0, 0.0, 1.0],
            [0.0, 0.0, -1.0],
            [1.0, 0.0, 0.0],
            [0.0, 1.0, 0.0],
            [0.0, 0.6, -0.8],
        ] {
            let w = axis.map(|v| v * five);
            let b_params = params_from_pose(&rotated_about_own_axes(&a, w));
            let b = pose_from_params(&b_params);
            for (d, want) in (3..6).zip(&a_params[3..]) {
                let e = crate::geometry::wrap_angle(b_params[d] - want).abs();
                largest_rpy_difference = largest_rpy_difference.max(e);
            }
            let d = pose_difference(&b, &a);
            let angle = (d[3] * d[3] + d[4] * d[4] + d[5] * d[5]).sqrt();
            assert!(
                (angle - five).abs() < 0.1f64.to_radians(),
                "{axis:?}: {angle}"
            );
            let grasps = vec![
                grasp(0, "side", a_params, 0.2),
                grasp(1, "side", b_params, 0.2),
            ];
            let mut grasps = grasps;
            grasps[1].spread_rad = grasps[0].spread_rad;
            let half = model * rotated_about_own_axes(&a, w.map(|v| 0.5 * v));
            for kernel in [
                Kernel::Gaussian,
                Kernel::GAUSSIAN_R_DEFAULT,
                Kernel::LAPLACE_DEFAULT,
            ] {
                let objective =
                    Objective::new(&fits, &grasps, "side", &kernel, &Weights::default()).unwrap();
                let b = objective.breakdown(&half);
                let ratio = (b.per_grasp_log[0].1 - b.per_grasp_log[1].1).exp();
                assert!(
                    (0.5..=2.0).contains(&ratio),
                    "{} {axis:?}: terms {:?}",
                    kernel.name(),
                    b.per_grasp_log
                );
            }
        }
        // The case is the gimbal lock: some of these pairs differ by ~pi in roll and yaw.
        assert!(largest_rpy_difference > 2.5, "{largest_rpy_difference}");
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
        let gone = before.breakdown(&pose_from_params(&x)).per_grasp_log[0];
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
        fits[0].sigma_m2 = f64::INFINITY;
        let err = Objective::new(&fits, &grasps, "side", &k, &w)
            .unwrap_err()
            .to_string();
        assert!(err.contains("fit 0") && err.contains("sigma_m2"), "{err}");
        fits[0].sigma_m2 = 1e-6;
        grasps.push(grasp(7, "side", [0.0; 6], 0.1));
        let err = Objective::new(&fits, &grasps, "side", &k, &w)
            .unwrap_err()
            .to_string();
        assert!(err.contains("model 7"), "{err}");
    }
}
