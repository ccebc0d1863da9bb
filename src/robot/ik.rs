//! Inverse kinematics of the palm pose for the seven arm joints.
//!
//! Damped least squares with Levenberg–Marquardt damping: each step solves
//! `(J W J^T + lambda I) y = W e`, `dq = J^T y` on the weighted 6-D pose error
//! (position in metres, rotation as a world-frame rotation vector times
//! [`IkOptions::rotation_weight_m`]), clamps into the joint limits, and keeps the step
//! only if the error falls (else raises the damping). Several seeds are tried in
//! order — the caller's (current configuration, previous solution), then a fixed,
//! deterministic spread over the joint ranges — so that joint-limit stalls and the
//! redundancy of the 7-DOF arm do not hide a solution.

use super::kinematics::{ArmJoints, ArmKinematics, ARM_DOF};
use crate::geometry::{pose_error, Pose};
use nalgebra::{Matrix6, Vector6};

/// Tolerances and effort of one solve.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct IkOptions {
    /// A solution counts as converged within this position error (m).
    pub accept_position_m: f64,
    /// ... and this rotation error (rad).
    pub accept_rotation_rad: f64,
    /// Iteration stops early below this position error (m).
    pub target_position_m: f64,
    /// ... and this rotation error (rad).
    pub target_rotation_rad: f64,
    /// Iterations per seed.
    pub max_iterations: usize,
    /// Metres of position error one radian of rotation error counts as.
    pub rotation_weight_m: f64,
    /// Largest joint step per iteration (rad).
    pub max_step_rad: f64,
    /// Solutions stay this far inside the URDF joint limits (rad): more than the
    /// executor's safety margin (0.01 rad), so every reachable plan is executable.
    pub limit_margin_rad: f64,
}

impl Default for IkOptions {
    fn default() -> Self {
        IkOptions {
            accept_position_m: 1e-3,
            accept_rotation_rad: 0.01,
            target_position_m: 1e-6,
            target_rotation_rad: 1e-5,
            max_iterations: 60,
            rotation_weight_m: 0.2,
            max_step_rad: 0.5,
            limit_margin_rad: 0.02,
        }
    }
}

/// The result of solving from one seed.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct IkSolution {
    /// Joint angles (rad), inside the limits.
    pub joints: ArmJoints,
    /// Palm position error (m).
    pub pos_err_m: f64,
    /// Palm rotation error (rad).
    pub rot_err_rad: f64,
    /// Iterations used.
    pub iterations: usize,
}

impl IkSolution {
    /// True when within the acceptance tolerances of `options`.
    pub fn converged(&self, options: &IkOptions) -> bool {
        self.pos_err_m <= options.accept_position_m
            && self.rot_err_rad <= options.accept_rotation_rad
    }
}

/// Inverse kinematics solver over an [`ArmKinematics`].
#[derive(Debug, Clone)]
pub struct IkSolver {
    arm: ArmKinematics,
    options: IkOptions,
    spread: Vec<ArmJoints>,
}

/// Number of fixed spread seeds tried after the caller's.
pub const SPREAD_SEEDS: usize = 24;

impl IkSolver {
    /// A solver with the given options and a deterministic spread of seeds.
    pub fn new(arm: ArmKinematics, options: IkOptions) -> IkSolver {
        let spread = (1..=SPREAD_SEEDS).map(|i| halton_seed(&arm, i)).collect();
        IkSolver {
            arm,
            options,
            spread,
        }
    }

    /// The arm this solver inverts.
    pub fn arm(&self) -> &ArmKinematics {
        &self.arm
    }

    /// The solve options.
    pub fn options(&self) -> &IkOptions {
        &self.options
    }

    /// Seeds to try for `first` (caller's seeds, in priority order): those clamped into
    /// the limits, then the fixed spread.
    pub fn seeds<'a>(&'a self, first: &'a [ArmJoints]) -> impl Iterator<Item = ArmJoints> + 'a {
        first
            .iter()
            .map(|q| self.arm.clamp_within(q, self.options.limit_margin_rad))
            .chain(self.spread.iter().copied())
    }

    /// Solves from every seed in turn until `accept` takes a converged solution;
    /// returns it, or the solution with the smallest error if none is accepted.
    pub fn solve_with(
        &self,
        target: &Pose,
        first_seeds: &[ArmJoints],
        mut accept: impl FnMut(&IkSolution) -> bool,
    ) -> Result<IkSolution, IkSolution> {
        let mut best: Option<IkSolution> = None;
        for seed in self.seeds(first_seeds) {
            let s = self.solve_from(target, &seed);
            if s.converged(&self.options) && accept(&s) {
                return Ok(s);
            }
            let better = best.is_none_or(|b| self.weighted(&s) < self.weighted(&b));
            if better {
                best = Some(s);
            }
        }
        Err(best.expect("at least one seed is always tried"))
    }

    /// Solves from the caller's seeds, then the spread; the first converged solution.
    pub fn solve(
        &self,
        target: &Pose,
        first_seeds: &[ArmJoints],
    ) -> Result<IkSolution, IkSolution> {
        self.solve_with(target, first_seeds, |_| true)
    }

    fn weighted(&self, s: &IkSolution) -> f64 {
        s.pos_err_m + self.options.rotation_weight_m * s.rot_err_rad
    }

    /// Levenberg–Marquardt from one seed (clamped into the limits).
    pub fn solve_from(&self, target: &Pose, seed: &ArmJoints) -> IkSolution {
        let o = &self.options;
        let w = o.rotation_weight_m;
        let mut q = self.arm.clamp_within(seed, self.options.limit_margin_rad);
        let (mut pose, mut jacobian) = self.arm.palm_and_jacobian(&q);
        let mut error = weighted_error(target, &pose, w);
        let mut cost = error.norm_squared();
        let mut lambda: f64 = 1e-4;
        let mut iterations = 0;
        while iterations < o.max_iterations {
            let (dp, dr) = pose_error(target, &pose);
            if dp <= o.target_position_m && dr <= o.target_rotation_rad {
                break;
            }
            iterations += 1;
            // Weight the rotation rows of J like the error.
            let mut jw = jacobian;
            for r in 3..6 {
                for c in 0..ARM_DOF {
                    jw[(r, c)] *= w;
                }
            }
            let mut improved = false;
            while lambda < 1e6 {
                let a: Matrix6<f64> = jw * jw.transpose() + Matrix6::identity() * lambda;
                let Some(chol) = a.cholesky() else {
                    lambda *= 10.0;
                    continue;
                };
                let y = chol.solve(&error);
                let mut dq = jw.transpose() * y;
                let step = dq.amax();
                if step > o.max_step_rad {
                    dq *= o.max_step_rad / step;
                }
                let mut candidate = q;
                for i in 0..ARM_DOF {
                    candidate[i] += dq[i];
                }
                let candidate = self
                    .arm
                    .clamp_within(&candidate, self.options.limit_margin_rad);
                let (cpose, cjac) = self.arm.palm_and_jacobian(&candidate);
                let cerror = weighted_error(target, &cpose, w);
                let ccost = cerror.norm_squared();
                if ccost < cost {
                    q = candidate;
                    pose = cpose;
                    jacobian = cjac;
                    error = cerror;
                    cost = ccost;
                    lambda = (lambda * 0.3).max(1e-9);
                    improved = true;
                    break;
                }
                lambda *= 8.0;
            }
            if !improved {
                break; // stalled: at a limit or a local minimum
            }
        }
        let (pos_err_m, rot_err_rad) = pose_error(target, &pose);
        IkSolution {
            joints: q,
            pos_err_m,
            rot_err_rad,
            iterations,
        }
    }
}

/// The 6-D error `[p_target - p; w * log(R_target R^T)]` in the base frame.
fn weighted_error(target: &Pose, pose: &Pose, w: f64) -> Vector6<f64> {
    let dp = target.translation.vector - pose.translation.vector;
    let dr = (target.rotation * pose.rotation.inverse()).scaled_axis() * w;
    Vector6::new(dp.x, dp.y, dp.z, dr.x, dr.y, dr.z)
}

/// The `index`-th point of a Halton sequence over the middle 80 % of each joint range.
fn halton_seed(arm: &ArmKinematics, index: usize) -> ArmJoints {
    const BASES: [usize; ARM_DOF] = [2, 3, 5, 7, 11, 13, 17];
    let mut q = [0.0; ARM_DOF];
    for (i, base) in BASES.iter().enumerate() {
        let u = radical_inverse(index, *base);
        let (lo, hi) = (arm.lower_rad[i], arm.upper_rad[i]);
        let mid = 0.5 * (lo + hi);
        q[i] = mid + (u - 0.5) * 0.8 * (hi - lo);
    }
    q
}

fn radical_inverse(mut index: usize, base: usize) -> f64 {
    let mut result = 0.0;
    let mut f = 1.0 / base as f64;
    while index > 0 {
        result += f * (index % base) as f64;
        index /= base;
        f /= base as f64;
    }
    result
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::robot::shipped_robot;
    use rand::{Rng, SeedableRng};

    #[test]
    fn round_trip_of_1000_random_configurations() {
        let robot = shipped_robot();
        let arm = robot.arm();
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(2026);
        let n = 1000;
        let mut converged = 0;
        for _ in 0..n {
            let q: ArmJoints =
                std::array::from_fn(|i| rng.gen_range(arm.lower_rad[i]..=arm.upper_rad[i]));
            let target = arm.palm(&q);
            // The true configuration is not given: only the fixed spread of seeds.
            if let Ok(s) = robot.ik.solve(&target, &[]) {
                assert!(arm.out_of_limits(&s.joints).is_none());
                let (dp, dr) = pose_error(&arm.palm(&s.joints), &target);
                assert!(dp <= 1e-3 && dr <= 0.01);
                converged += 1;
            }
        }
        assert!(converged * 100 >= 99 * n, "{converged} of {n} converged");
    }

    #[test]
    fn caller_seed_is_tried_first_and_kept_when_it_solves() {
        let robot = shipped_robot();
        let q = [0.2, 0.4, -0.3, -1.0, 0.5, 0.8, -0.2];
        let target = robot.arm().palm(&q);
        let s = robot.ik.solve(&target, &[q]).unwrap();
        assert_eq!(s.iterations, 0);
        assert_eq!(s.joints, q);
    }

    #[test]
    fn halton_seeds_are_inside_the_limits_and_distinct() {
        let robot = shipped_robot();
        let seeds: Vec<_> = robot.ik.seeds(&[]).collect();
        assert_eq!(seeds.len(), SPREAD_SEEDS);
        for s in &seeds {
            assert!(robot.arm().out_of_limits(s).is_none());
        }
        assert!(seeds.windows(2).all(|w| w[0] != w[1]));
    }
}
