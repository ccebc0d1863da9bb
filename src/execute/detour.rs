//! Joint-space detours for free moves that no straight line makes: waypoints from
//! one configuration to another whose straight joint segments the safety layer
//! accepts, found by RRT-Connect (Kuffner & LaValle, ICRA 2000) over the
//! configurations [`SafetyCheck::check_configuration`] accepts, then shortened.
//!
//! The release and park after a grasp needs it: from a grasp on the far branch of
//! the shoulder (the first joint half a turn from the park's), the joint line to the
//! park swings the palm over the robot and out of the workspace, and the palm's
//! straight line cannot change branch. The search is seeded: the same inputs give the
//! same detour. The motion built on it is checked again as a whole before it runs.

use super::safety::SafetyCheck;
use crate::robot::kinematics::{joint_distance_rad, ArmJoints, ARM_DOF};
use crate::robot::HandPose;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// Settings of the search.
#[derive(Debug, Clone, PartialEq)]
pub struct DetourOptions {
    /// Largest joint step between configurations checked along a segment (rad).
    pub check_step_rad: f64,
    /// Largest joint step by which a tree grows toward a sample (rad).
    pub grow_step_rad: f64,
    /// Samples drawn before giving up.
    pub max_samples: usize,
    /// Attempts to shortcut the path found between two of its waypoints.
    pub shortcuts: usize,
    /// Seed of the sampler.
    pub seed: u64,
}

impl Default for DetourOptions {
    fn default() -> Self {
        DetourOptions {
            check_step_rad: 0.04,
            grow_step_rad: 0.4,
            max_samples: 4000,
            shortcuts: 200,
            seed: 1,
        }
    }
}

/// One tree of the search: configurations and each one's parent.
struct Tree {
    nodes: Vec<(ArmJoints, usize)>,
}

impl Tree {
    fn new(root: ArmJoints) -> Tree {
        Tree {
            nodes: vec![(root, 0)],
        }
    }

    fn nearest(&self, q: &ArmJoints) -> usize {
        let distance = |p: &ArmJoints| (0..ARM_DOF).map(|j| (p[j] - q[j]).powi(2)).sum::<f64>();
        (0..self.nodes.len())
            .min_by(|&a, &b| distance(&self.nodes[a].0).total_cmp(&distance(&self.nodes[b].0)))
            .unwrap_or(0)
    }

    /// From node `k` back to the root.
    fn branch(&self, mut k: usize) -> Vec<ArmJoints> {
        let mut path = vec![self.nodes[k].0];
        while k != 0 {
            k = self.nodes[k].1;
            path.push(self.nodes[k].0);
        }
        path
    }
}

/// Whether every configuration on the straight joint segment `a`–`b` (a excluded),
/// at most `step_rad` apart, is accepted.
fn segment_clear(
    check: &SafetyCheck,
    hand: &HandPose,
    a: &ArmJoints,
    b: &ArmJoints,
    step_rad: f64,
) -> bool {
    let steps = (joint_distance_rad(a, b) / step_rad).ceil().max(1.0) as usize;
    (1..=steps).all(|k| {
        let t = k as f64 / steps as f64;
        let q: ArmJoints = std::array::from_fn(|j| a[j] + t * (b[j] - a[j]));
        check.check_configuration(&q, hand).is_ok()
    })
}

/// Grows `tree` from its node nearest `target` by at most one grow step toward it;
/// the new node's index, or `None` when the way is blocked.
fn grow(
    check: &SafetyCheck,
    hand: &HandPose,
    tree: &mut Tree,
    target: &ArmJoints,
    options: &DetourOptions,
) -> Option<usize> {
    let near = tree.nearest(target);
    let from = tree.nodes[near].0;
    let apart = joint_distance_rad(&from, target);
    if apart <= 0.0 {
        return None;
    }
    let t = (options.grow_step_rad / apart).min(1.0);
    let q: ArmJoints = std::array::from_fn(|j| from[j] + t * (target[j] - from[j]));
    segment_clear(check, hand, &from, &q, options.check_step_rad).then(|| {
        tree.nodes.push((q, near));
        tree.nodes.len() - 1
    })
}

/// Waypoints from `from` to `to` (both included) whose straight joint segments the
/// safety layer accepts with the hand as `hand`; `None` when either end is refused
/// or no detour is found within [`DetourOptions::max_samples`].
pub fn detour(
    check: &SafetyCheck,
    hand: &HandPose,
    from: &ArmJoints,
    to: &ArmJoints,
    options: &DetourOptions,
) -> Option<Vec<ArmJoints>> {
    if check.check_configuration(from, hand).is_err()
        || check.check_configuration(to, hand).is_err()
    {
        return None;
    }
    if segment_clear(check, hand, from, to, options.check_step_rad) {
        return Some(vec![*from, *to]);
    }
    let limits = check.limits();
    let lo: ArmJoints = std::array::from_fn(|j| limits.lower_rad[j] + limits.margin_rad);
    let hi: ArmJoints = std::array::from_fn(|j| limits.upper_rad[j] - limits.margin_rad);
    let mut rng = ChaCha8Rng::seed_from_u64(options.seed);
    // `a` grows toward a sample, `b` connects to what `a` reached; they swap roles.
    let (mut a, mut b) = (Tree::new(*from), Tree::new(*to));
    let mut a_is_from = true;
    for _ in 0..options.max_samples {
        let sample: ArmJoints = std::array::from_fn(|j| rng.gen_range(lo[j]..=hi[j]));
        if let Some(new) = grow(check, hand, &mut a, &sample, options) {
            let reached = a.nodes[new].0;
            while let Some(k) = grow(check, hand, &mut b, &reached, options) {
                if b.nodes[k].0 == reached {
                    let mut path = a.branch(new);
                    path.reverse();
                    path.extend(b.branch(k).into_iter().skip(1));
                    if !a_is_from {
                        path.reverse();
                    }
                    return Some(shortened(check, hand, path, options, &mut rng));
                }
            }
        }
        std::mem::swap(&mut a, &mut b);
        a_is_from = !a_is_from;
    }
    None
}

/// `path` with waypoints dropped where a straight segment can skip them: random
/// pairs first, then greedily from the start.
fn shortened(
    check: &SafetyCheck,
    hand: &HandPose,
    mut path: Vec<ArmJoints>,
    options: &DetourOptions,
    rng: &mut ChaCha8Rng,
) -> Vec<ArmJoints> {
    for _ in 0..options.shortcuts {
        if path.len() < 3 {
            break;
        }
        let i = rng.gen_range(0..path.len() - 2);
        let j = rng.gen_range(i + 2..path.len());
        if segment_clear(check, hand, &path[i], &path[j], options.check_step_rad) {
            path.drain(i + 1..j);
        }
    }
    let mut greedy = vec![path[0]];
    let mut i = 0;
    while i + 1 < path.len() {
        let j = (i + 1..path.len())
            .rev()
            .find(|&j| {
                j == i + 1 || segment_clear(check, hand, &path[i], &path[j], options.check_step_rad)
            })
            .unwrap_or(i + 1);
        greedy.push(path[j]);
        i = j;
    }
    greedy
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::execute::motions::checked_motion;
    use crate::execute::safety::SafetyLimits;
    use crate::execute::Phase;
    use crate::robot::shipped_robot;
    use std::sync::Arc;

    fn check() -> SafetyCheck {
        let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
            .join(crate::config::DEFAULT_CONFIG_PATH);
        let cell = crate::config::CellConfig::load(&path).unwrap();
        let robot = Arc::new(shipped_robot());
        let limits = SafetyLimits::from_cell(&cell, &robot);
        SafetyCheck::new(robot, limits)
    }

    const PARK: ArmJoints = crate::config::DEFAULT_PARK_JOINTS_RAD;

    /// A side grasp on the far branch of the shoulder, as a campaign executed it
    /// (first joint half a turn from the park's).
    const FAR_BRANCH: ArmJoints = [-2.7647, 1.2439, -0.2989, -1.7398, -2.9008, 1.1982, -2.8456];

    #[test]
    fn a_clear_joint_line_is_its_own_detour() {
        let check = check();
        let hand = HandPose::OPEN;
        let mut near = PARK;
        near[0] += 0.3;
        let path = detour(&check, &hand, &near, &PARK, &DetourOptions::default()).unwrap();
        assert_eq!(path, vec![near, PARK]);
    }

    #[test]
    fn a_detour_takes_the_arm_from_the_far_branch_to_the_park_where_the_joint_line_is_refused() {
        let check = check();
        let hand = HandPose::OPEN;
        let motion = |waypoints: &[ArmJoints]| {
            checked_motion(&check, 0.2, Phase::Park, "park", waypoints, None, &hand)
        };
        let refusal = motion(&[FAR_BRANCH, PARK]).unwrap_err();
        let path = detour(&check, &hand, &FAR_BRANCH, &PARK, &DetourOptions::default())
            .unwrap_or_else(|| panic!("no detour; the joint line: {refusal}"));
        assert_eq!(path.first(), Some(&FAR_BRANCH));
        assert_eq!(path.last(), Some(&PARK));
        // The whole motion through it passes the safety layer's own check.
        motion(&path).unwrap();
        // Seeded: the same detour again.
        let again = detour(&check, &hand, &FAR_BRANCH, &PARK, &DetourOptions::default());
        assert_eq!(again, Some(path));
    }

    #[test]
    fn an_end_the_safety_layer_refuses_has_no_detour() {
        let check = check();
        let hand = HandPose::OPEN;
        let mut beyond = PARK;
        beyond[1] = 3.0; // past the second joint's limit
        let options = DetourOptions::default();
        assert_eq!(detour(&check, &hand, &beyond, &PARK, &options), None);
        assert_eq!(detour(&check, &hand, &PARK, &beyond, &options), None);
    }
}
