//! The arm and the KRL program: the arm tracks the command (bridging one missing
//! answer), `friStart` once quality allows, and drops to monitor mode.

use super::FriSimulator;
use crate::hw::fri::datagram::{FriState, Quality};
use crate::hw::fri::JOINTS;
use crate::sim::fri::{DropReason, SimEvent};
use std::time::Duration;

impl FriSimulator {
    /// Moves the arm from the last step to `now`.
    pub(super) fn step_arm(&mut self, now: Duration) {
        let dt = now.saturating_sub(self.last_step).as_secs_f64();
        self.last_step = now;
        let desired = if self.state == FriState::Command {
            if !self.new_command && self.consecutive_misses == 1 {
                // Bridge a single missing answer with the last commanded velocity.
                let next: [f64; JOINTS] =
                    std::array::from_fn(|j| 2.0 * self.target_rad[j] - self.prev_target_rad[j]);
                self.prev_target_rad = self.target_rad;
                self.target_rad = next;
                if let Some(reason) = self.limit_violation(&next) {
                    self.drop_to_monitor(reason, now);
                    return;
                }
            }
            self.target_rad
        } else {
            self.krl_rad
        };
        let tau = self.config.tracking_time_constant_s;
        let alpha = if tau == 0.0 {
            1.0
        } else {
            1.0 - (-dt / tau).exp()
        };
        for (msr, goal) in self.msr_rad.iter_mut().zip(desired) {
            *msr += alpha * (goal - *msr);
        }
    }

    pub(super) fn run_state_machine(&mut self, now: Duration) {
        match self.state {
            FriState::Command if self.quality < Quality::Bad => {
                let answered = self.window.iter().filter(|l| l.is_some()).count();
                let reason = DropReason::LinkQuality {
                    quality: self.quality,
                    consecutive_misses: self.consecutive_misses,
                    answer_rate: answered as f64 / self.window.len().max(1) as f64,
                };
                self.drop_to_monitor(reason, now);
            }
            FriState::Monitor => {
                self.perfect_cycles = if self.quality == Quality::Perfect {
                    self.perfect_cycles + 1
                } else {
                    0
                };
                if self.start_requested
                    && !self.release_requested
                    && self.perfect_cycles >= self.config.start_after_perfect_cycles
                {
                    self.start_requested = false;
                    self.state = FriState::Command;
                    self.latched_flags = self.last_monitor_flags;
                    self.target_rad = self.krl_rad;
                    self.prev_target_rad = self.krl_rad;
                    self.last_cmd_rad = self.krl_rad;
                    self.last_applied = None;
                    let at_s = self.at_s(now);
                    self.push_event(SimEvent::StartedCommanding { at_s });
                }
            }
            _ => {}
        }
    }

    pub(super) fn drop_to_monitor(&mut self, reason: DropReason, now: Duration) {
        self.state = FriState::Monitor;
        // Stop where the arm is: the KRL command takes over at the measured position.
        self.krl_rad = self.msr_rad;
        self.target_rad = self.msr_rad;
        self.prev_target_rad = self.msr_rad;
        self.last_cmd_rad = self.msr_rad;
        self.last_applied = None;
        self.perfect_cycles = 0;
        if self.config.restart_after_drop
            && matches!(
                reason,
                DropReason::LinkQuality { .. } | DropReason::Released
            )
        {
            self.start_requested = true;
        }
        self.drop_reason = Some(reason);
        self.counters.drops_to_monitor += 1;
        let at_s = self.at_s(now);
        self.push_event(SimEvent::DroppedToMonitor { reason, at_s });
    }

    pub(super) fn limit_violation(&self, q: &[f64; JOINTS]) -> Option<DropReason> {
        (0..JOINTS).find_map(|joint| {
            let (lo, hi) = (
                self.config.position_min_rad[joint],
                self.config.position_max_rad[joint],
            );
            let limit_rad = if q[joint] <= lo {
                lo
            } else if q[joint] >= hi {
                hi
            } else {
                return None;
            };
            Some(DropReason::JointLimit {
                joint,
                commanded_rad: q[joint],
                limit_rad,
            })
        })
    }
}
