//! The PC's commands: each received datagram is classified, recorded and applied.

use super::FriSimulator;
use crate::hw::fri::datagram::{seq_ahead, CmdFlags, CommandDatagram, FriState};
use crate::hw::fri::{JOINTS, RELEASE_BIT};
use crate::sim::fri::{Answer, DropReason, ReceivedCommand, SimEvent};
use std::time::Duration;

impl FriSimulator {
    /// Takes in one datagram from the PC that arrived at `now`.
    pub fn receive(&mut self, bytes: &[u8], now: Duration) -> Answer {
        let command = match CommandDatagram::decode(bytes) {
            Ok(command) => command,
            Err(error) => {
                self.counters.bad_datagrams += 1;
                let at_s = self.at_s(now);
                self.push_event(SimEvent::BadDatagram { error, at_s });
                return Answer::Garbled;
            }
        };
        let refl = command.refl_seq_count;
        let Some(&(_, sent_at)) = self.sent.iter().rev().find(|(seq, _)| *seq == refl) else {
            self.counters.unexpected_answers += 1;
            let at_s = self.at_s(now);
            self.push_event(SimEvent::UnexpectedAnswer {
                refl_seq_count: refl,
                at_s,
            });
            return Answer::Unexpected;
        };
        if let Some(last) = self.last_answered {
            let ahead = seq_ahead(refl, last);
            if ahead == 0 || ahead > u16::MAX / 2 {
                self.counters.duplicate_answers += 1;
                return Answer::Duplicate;
            }
        }
        self.last_answered = Some(refl);
        if let Some(commands) = &mut self.commands {
            commands.push(ReceivedCommand {
                refl_seq_count: refl,
                state: self.state,
                cmd_flags: command.cmd_flags.raw(),
                jnt_pos_rad: command.jnt_pos.map(f64::from),
            });
        }
        let latency_s = now.saturating_sub(sent_at).as_secs_f64();
        if self.config.record_latencies {
            self.latencies_s.push(latency_s);
        }
        let answer = if refl == self.seq {
            self.current_latency_s = Some(latency_s);
            Answer::InTime { latency_s }
        } else {
            self.counters.late_answers += 1;
            Answer::Late { latency_s }
        };
        self.apply(&command, now);
        answer
    }

    fn apply(&mut self, command: &CommandDatagram, now: Duration) {
        let refl = command.refl_seq_count;
        // The KRL program's loop: friStop while the PC releases the robot.
        self.release_requested = command.krl.bools & RELEASE_BIT != 0;
        if self.release_requested && self.state == FriState::Command {
            self.drop_to_monitor(DropReason::Released, now);
            return;
        }
        match self.state {
            FriState::Monitor => {
                self.last_monitor_flags = command.cmd_flags;
                return;
            }
            FriState::Command => {}
            _ => return,
        }
        if command.cmd_flags != self.latched_flags {
            let reason = DropReason::FlagsChanged {
                latched: self.latched_flags.raw(),
                received: command.cmd_flags.raw(),
            };
            self.drop_to_monitor(reason, now);
            return;
        }
        let cycles = self.last_applied.map_or(1, |last| seq_ahead(refl, last));
        self.last_applied = Some(refl);
        if !self.latched_flags.contains(CmdFlags::JNT_POS) {
            return;
        }
        let q: [f64; JOINTS] = command.jnt_pos.map(f64::from);
        if let Some(reason) = self.limit_violation(&q) {
            self.drop_to_monitor(reason, now);
            return;
        }
        let dt = f64::from(cycles) * self.config.cycle_s;
        for (joint, (qj, last)) in q.iter().zip(self.last_cmd_rad).enumerate() {
            let speed_rad_s = (qj - last).abs() / dt;
            let limit_rad_s = self.config.velocity_limit_rad_s[joint];
            if speed_rad_s >= limit_rad_s {
                let reason = DropReason::VelocityLimit {
                    joint,
                    speed_rad_s,
                    limit_rad_s,
                };
                self.drop_to_monitor(reason, now);
                return;
            }
        }
        self.last_cmd_rad = q;
        self.prev_target_rad = self.target_rad;
        self.target_rad = q;
        self.new_command = true;
    }
}
