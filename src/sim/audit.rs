//! An independent audit of what the robot received: every joint command the
//! simulated LBR4+ took off the wire (its datagram-level record,
//! [`super::fri::ReceivedCommand`]) checked against the cell's limits, without
//! trusting the executor's own bookkeeping. Used by the safety property test and by
//! `cell-sim-arm --audit` for the fault campaign (`cell chaos`).

use super::fri::ReceivedCommand;
use crate::config::CellConfig;
use crate::hw::fri::datagram::FriState;
use crate::hw::fri::JOINTS;
use crate::robot::Robot;
use serde::{Deserialize, Serialize};

/// What an audit found so far.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct AuditReport {
    /// Commands checked.
    pub commands: u64,
    /// Commands that broke a limit.
    pub unsafe_commands: u64,
    /// Why the first unsafe command was unsafe.
    pub first_unsafe: Option<String>,
}

/// Checks a stream of received commands, in order, against: the URDF's joint
/// positions; the configured velocity (URDF x `limits.joint_velocity_scale`) and
/// acceleration between consecutive cycles in command mode (allowing the f32
/// rounding on the wire); the palm at least `table.palm_clearance_m` above the table
/// and inside the workspace (1 mm slack: the safety layer checks every 5 ms of
/// trajectory time).
pub struct CommandAudit<'a> {
    robot: &'a Robot,
    cell: &'a CellConfig,
    dt_s: f64,
    /// The last two commands checked (oldest first).
    recent: Vec<ReceivedCommand>,
    report: AuditReport,
}

impl<'a> CommandAudit<'a> {
    /// An audit of commands sent every `dt_s` seconds (the FRI cycle).
    pub fn new(robot: &'a Robot, cell: &'a CellConfig, dt_s: f64) -> Self {
        CommandAudit {
            robot,
            cell,
            dt_s,
            recent: Vec::with_capacity(3),
            report: AuditReport::default(),
        }
    }

    /// Checks the next command; returns why it is unsafe, if it is.
    pub fn check(&mut self, c: &ReceivedCommand) -> Option<String> {
        let i = self.report.commands;
        self.report.commands += 1;
        let problem = self.problem(c).map(|p| format!("command {i}: {p}"));
        if let Some(p) = &problem {
            self.report.unsafe_commands += 1;
            self.report.first_unsafe.get_or_insert_with(|| p.clone());
        }
        self.recent.push(*c);
        if self.recent.len() > 2 {
            self.recent.remove(0);
        }
        problem
    }

    /// Checks every command of `commands`; returns the first problem.
    pub fn check_all(&mut self, commands: &[ReceivedCommand]) -> Option<String> {
        commands
            .iter()
            .fold(None, |first, c| first.or(self.check(c)))
    }

    /// The audit so far.
    pub fn report(&self) -> &AuditReport {
        &self.report
    }

    fn problem(&self, c: &ReceivedCommand) -> Option<String> {
        let arm = &self.robot.description.variables[..JOINTS];
        let cell = self.cell;
        let dt_s = self.dt_s;
        let rounding = |q: f64| q.abs() * f64::from(f32::EPSILON);
        let q = c.jnt_pos_rad;
        for j in 0..JOINTS {
            if !(arm[j].lower_rad <= q[j] && q[j] <= arm[j].upper_rad) {
                return Some(format!("joint {j} at {} rad", q[j]));
            }
        }
        let p = self.robot.arm().palm(&q).translation.vector;
        let min_z = cell.table.height_m + cell.table.palm_clearance_m - 1e-3;
        if p.z < min_z {
            return Some(format!("palm at z {} m", p.z));
        }
        let (lo, hi) = (cell.workspace.min_m, cell.workspace.max_m);
        if (0..3).any(|k| p[k] < lo[k] - 1e-3 || p[k] > hi[k] + 1e-3) {
            return Some(format!("palm at {p:?} outside the workspace"));
        }
        if c.state != FriState::Command {
            return None;
        }
        // Consecutive commands in command mode: each answers the measurement after
        // the one the previous answered.
        let follows = |a: &ReceivedCommand, b: &ReceivedCommand| {
            a.state == FriState::Command && b.refl_seq_count == a.refl_seq_count.wrapping_add(1)
        };
        let n = self.recent.len();
        if n >= 1 && follows(&self.recent[n - 1], c) {
            let prev = self.recent[n - 1].jnt_pos_rad;
            for j in 0..JOINTS {
                let v = (q[j] - prev[j]).abs() / dt_s;
                let limit = arm[j].velocity_rad_s * cell.limits.joint_velocity_scale
                    + (rounding(q[j]) + rounding(prev[j])) / dt_s;
                if v > limit * (1.0 + 1e-9) {
                    return Some(format!("joint {j} at {v} rad/s > {limit}"));
                }
            }
            if n >= 2 && follows(&self.recent[0], &self.recent[1]) {
                let (a0, a1) = (self.recent[0].jnt_pos_rad, prev);
                for j in 0..JOINTS {
                    let a = (q[j] - 2.0 * a1[j] + a0[j]).abs() / (dt_s * dt_s);
                    let limit = cell.limits.joint_acceleration_rad_s2
                        + (rounding(q[j]) + 2.0 * rounding(a1[j]) + rounding(a0[j]))
                            / (dt_s * dt_s);
                    if a > limit * (1.0 + 1e-9) {
                        return Some(format!("joint {j} at {a} rad/s^2 > {limit}"));
                    }
                }
            }
        }
        None
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::config::CellConfig;

    fn command(seq: u16, q: [f64; JOINTS]) -> ReceivedCommand {
        ReceivedCommand {
            refl_seq_count: seq,
            state: FriState::Command,
            cmd_flags: 0,
            jnt_pos_rad: q,
        }
    }

    #[test]
    fn the_audit_names_a_jump_a_joint_limit_and_the_table() {
        let cell = CellConfig::load(std::path::Path::new(crate::config::BUILTIN_CONFIG)).unwrap();
        let robot = Robot::load(&cell).unwrap();
        let home = [0.0, -0.3, 0.0, 1.6, 0.0, -0.8, 0.0];
        let mut audit = CommandAudit::new(&robot, &cell, 0.005);
        assert_eq!(audit.check(&command(1, home)), None);
        assert_eq!(audit.check(&command(2, home)), None);
        let mut jump = home;
        jump[0] += 0.1; // 20 rad/s
        let why = audit.check(&command(3, jump)).unwrap();
        assert!(why.contains("joint 0") && why.contains("rad/s"), "{why}");
        let mut beyond = home;
        beyond[1] = 3.0;
        let why = audit.check(&command(40, beyond)).unwrap();
        assert!(why.contains("joint 1 at 3"), "{why}");
        // Elbow folded down: the palm goes under the table.
        let low = [0.0, 1.9, 0.0, -1.0, 0.0, 0.0, 0.0];
        let why = audit.check(&command(80, low)).unwrap();
        assert!(why.contains("palm"), "{why}");
        let report = audit.report();
        assert_eq!((report.commands, report.unsafe_commands), (5, 3));
        assert!(report
            .first_unsafe
            .as_ref()
            .unwrap()
            .starts_with("command 2"));
    }
}
