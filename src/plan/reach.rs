//! Reachability as the planner sees it: a trait the robot implements, so that the
//! planner's constraint handling can also be tested against simple, exactly known
//! feasible sets.

use crate::geometry::Pose;
use crate::robot::ik::IkSolution;
use crate::robot::kinematics::ArmJoints;
use crate::robot::{HandPose, Robot, Unreachable, UnreachableReason};

/// Whether a palm pose can be reached (IK inside the joint limits, no collision with
/// the table or itself, inside the workspace).
pub trait Reachability: Sync {
    /// The full check: `seeds` first, then whatever else the implementation tries.
    fn reach(
        &self,
        palm: &Pose,
        hand: &HandPose,
        seeds: &[ArmJoints],
    ) -> Result<IkSolution, Unreachable>;

    /// A quick, conservative check from nearby configurations (e.g. the solutions at
    /// neighbouring poses), tried in order: `Ok` only for reachable poses, but it may
    /// reject a reachable pose that needs a different arm configuration.
    fn reach_near(
        &self,
        palm: &Pose,
        hand: &HandPose,
        seeds: &[ArmJoints],
    ) -> Result<IkSolution, Unreachable> {
        self.reach(palm, hand, seeds)
    }

    /// A reachable pose at or near `palm`, found from nearby configurations `seeds`:
    /// `palm` itself when [`Reachability::reach_near`] accepts it; otherwise, if the
    /// implementation can, a nearby reachable pose (the default cannot: `None`).
    fn repair_near(
        &self,
        palm: &Pose,
        hand: &HandPose,
        seeds: &[ArmJoints],
    ) -> Option<(Pose, IkSolution)> {
        self.reach_near(palm, hand, seeds).ok().map(|s| (*palm, s))
    }

    /// A reachable palm pose near an unreachable one, if the implementation knows how
    /// to find one (none by default).
    fn nearest_reachable(&self, _palm: &Pose, _hand: &HandPose) -> Option<(Pose, IkSolution)> {
        None
    }

    /// Whether the arm can also move through the grasp at `palm` whose pre-grasp
    /// `pregrasp` it reaches (at joints `at` and `pre`): the move to the pre-grasp,
    /// the approach and the lift. `Err` says why not. By default reaching both poses
    /// is enough; the cell's protocol asks the executor ([`crate::cell::plan`]).
    fn motions(
        &self,
        _palm: &Pose,
        _pregrasp: &Pose,
        _hand: &HandPose,
        _at: &ArmJoints,
        _pre: &ArmJoints,
    ) -> Result<(), String> {
        Ok(())
    }
}

impl Reachability for Robot {
    fn reach(
        &self,
        palm: &Pose,
        hand: &HandPose,
        seeds: &[ArmJoints],
    ) -> Result<IkSolution, Unreachable> {
        Robot::reach(self, palm, hand, seeds)
    }

    /// One Levenberg–Marquardt solve from each seed in turn; for the first that
    /// converges to a collision-free configuration, the full check seeded with it
    /// (which then takes that solution at once). The fixed seed spread is never tried.
    fn reach_near(
        &self,
        palm: &Pose,
        hand: &HandPose,
        seeds: &[ArmJoints],
    ) -> Result<IkSolution, Unreachable> {
        let mut failure = None;
        if seeds.is_empty() {
            return Robot::reach(self, palm, hand, &[]);
        }
        for seed in seeds {
            let local = self.ik.solve_from(palm, seed);
            let reason = if !local.converged(self.ik.options()) {
                UnreachableReason::NoIkSolution {
                    pos_err_m: local.pos_err_m,
                    rot_err_rad: local.rot_err_rad,
                }
            } else if let Some(c) = self.collision_at(&local.joints, hand) {
                UnreachableReason::Collision(c)
            } else {
                return Robot::reach(self, palm, hand, &[local.joints]);
            };
            failure = Some(Unreachable {
                reason,
                best: Some(Box::new(local)),
            });
        }
        Err(failure.expect("at least one seed was tried"))
    }

    /// The local IK attempt from each seed (joint limits respected); the first that
    /// converges collision-free gives `palm` itself, else the attempt nearest the
    /// target gives the palm pose it reaches, if collision-free and it passes the full
    /// check — a local projection onto what the arm can reach.
    fn repair_near(
        &self,
        palm: &Pose,
        hand: &HandPose,
        seeds: &[ArmJoints],
    ) -> Option<(Pose, IkSolution)> {
        let w = self.ik.options().rotation_weight_m;
        let mut nearest: Option<IkSolution> = None;
        for seed in seeds {
            let local = self.ik.solve_from(palm, seed);
            if local.converged(self.ik.options())
                && self.collision_at(&local.joints, hand).is_none()
            {
                return Robot::reach(self, palm, hand, &[local.joints])
                    .ok()
                    .map(|s| (*palm, s));
            }
            let error = |s: &IkSolution| s.pos_err_m + w * s.rot_err_rad;
            if nearest.is_none_or(|n| error(&local) < error(&n)) {
                nearest = Some(local);
            }
        }
        let attempt = nearest?;
        if self.collision_at(&attempt.joints, hand).is_some() {
            return None;
        }
        let pose = self.arm().palm(&attempt.joints);
        Robot::reach(self, &pose, hand, &[attempt.joints])
            .ok()
            .map(|s| (pose, s))
    }

    /// The arm's own projection of the pose onto what it can reach: IK from every seed
    /// (joint limits respected, converged or not); of the attempts that collide with
    /// nothing, the one nearest the target (position error plus the IK's rotation
    /// weight times rotation error) whose palm pose passes the full check.
    fn nearest_reachable(&self, palm: &Pose, hand: &HandPose) -> Option<(Pose, IkSolution)> {
        let w = self.ik.options().rotation_weight_m;
        let mut attempts: Vec<IkSolution> = self
            .ik
            .seeds(&[])
            .map(|seed| self.ik.solve_from(palm, &seed))
            .filter(|s| self.collision_at(&s.joints, hand).is_none())
            .collect();
        attempts.sort_by(|a, b| {
            (a.pos_err_m + w * a.rot_err_rad).total_cmp(&(b.pos_err_m + w * b.rot_err_rad))
        });
        attempts.iter().take(3).find_map(|attempt| {
            let pose = self.arm().palm(&attempt.joints);
            Robot::reach(self, &pose, hand, &[attempt.joints])
                .ok()
                .map(|s| (pose, s))
        })
    }
}
