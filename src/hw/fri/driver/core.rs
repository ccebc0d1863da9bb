//! [`DriverCore`]: the driver's protocol logic as a pure, clock-driven state machine
//! (measurement and time in, command and events out), with the [`ForceGuard`] that
//! stops a motion on contact.

use super::{DriverConfig, DriverCounters, FriError, FriEvent, FriStatus, RELEASE_BIT};
use crate::hw::fri::datagram::{
    seq_ahead, CmdFlags, CommandDatagram, DatagramError, FriState, KrlData, MeasurementDatagram,
    Quality,
};
use crate::hw::fri::JOINTS;
use crate::trajectory::{StopProfile, Trajectory};
use std::collections::VecDeque;
use std::net::SocketAddr;
use std::time::Duration;

/// Most recent events kept; older ones are counted and dropped.
const EVENT_CAPACITY: usize = 4096;

/// A guard on a motion: stop (decelerate, then hold) at the first measurement
/// whose estimated external TCP force (`estExtTcpFT`, force part) differs from
/// its value at the motion's start by more than `threshold_n`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ForceGuard {
    /// The contact force (N), > 0.
    pub threshold_n: f64,
}

/// The force part of `estExtTcpFT` (N).
fn tcp_force(m: &MeasurementDatagram) -> [f64; 3] {
    std::array::from_fn(|i| f64::from(m.data.est_ext_tcp_ft[i]))
}

#[derive(Debug, Clone)]
enum Motion {
    /// Not commanding: mirror the robot.
    Mirror,
    /// Command a fixed position.
    Hold([f64; JOINTS]),
    /// Follow a trajectory; `t_s` is the time of the last commanded sample.
    Follow {
        id: u64,
        trajectory: Box<Trajectory<JOINTS>>,
        t_s: f64,
        /// The guard and the TCP force at the start.
        guard: Option<(ForceGuard, [f64; 3])>,
    },
    /// Decelerate to rest, then hold; `id` is the motion stopped.
    Brake {
        id: u64,
        profile: StopProfile<JOINTS>,
        t_s: f64,
    },
}

/// The driver's protocol logic: a pure function of measurements, times and requests.
#[derive(Debug)]
pub struct DriverCore {
    config: DriverConfig,
    send_seq: u16,
    last: Option<MeasurementDatagram>,
    last_rx: Option<Duration>,
    late: bool,
    /// While late: the last stale sequence number, the first of a possible restart.
    restart_seq: Option<u16>,
    motion: Motion,
    commanding: bool,
    commanded_rad: [f64; JOINTS],
    next_id: u64,
    /// Outcome of the most recent finished motion.
    outcome: Option<(u64, Result<(), FriError>)>,
    withhold: bool,
    /// Commands ask the KRL program to leave command mode ([`RELEASE_BIT`]).
    release: bool,
    pub(super) events: VecDeque<FriEvent>,
    counters: DriverCounters,
}

impl DriverCore {
    /// A driver that has not yet seen the robot.
    pub fn new(config: DriverConfig) -> Result<DriverCore, FriError> {
        config.validate()?;
        Ok(DriverCore {
            config,
            send_seq: 0,
            last: None,
            last_rx: None,
            late: false,
            restart_seq: None,
            motion: Motion::Mirror,
            commanding: false,
            commanded_rad: [0.0; JOINTS],
            next_id: 1,
            outcome: None,
            withhold: false,
            release: false,
            events: VecDeque::new(),
            counters: DriverCounters::default(),
        })
    }

    /// The configuration.
    pub fn config(&self) -> &DriverConfig {
        &self.config
    }

    pub(super) fn push(&mut self, event: FriEvent) {
        match &event {
            // A guarded move stopping on contact is the approach working.
            FriEvent::MotionAborted {
                error: FriError::Contact { .. },
                ..
            } => tracing::info!("FRI: {event:?}"),
            FriEvent::DroppedToMonitor { .. }
            | FriEvent::MeasurementLate { .. }
            | FriEvent::MotionAborted { .. }
            | FriEvent::SocketError { .. }
            | FriEvent::ForeignDatagram { .. }
            | FriEvent::BadDatagram { .. } => tracing::warn!("FRI: {event:?}"),
            _ => tracing::info!("FRI: {event:?}"),
        }
        if self.events.len() == EVENT_CAPACITY {
            self.events.pop_front();
            self.counters.events_discarded += 1;
        }
        self.events.push_back(event);
    }

    /// Removes and returns the events so far (oldest first).
    pub fn take_events(&mut self) -> Vec<FriEvent> {
        self.events.drain(..).collect()
    }

    fn finish(&mut self, id: u64, result: Result<(), FriError>) {
        match &result {
            Ok(()) => self.push(FriEvent::MotionFinished { id }),
            Err(error) => self.push(FriEvent::MotionAborted {
                id,
                error: error.clone(),
            }),
        }
        self.outcome = Some((id, result));
    }

    fn running_id(&self) -> Option<u64> {
        match self.motion {
            Motion::Follow { id, .. } => Some(id),
            _ => None,
        }
    }

    /// Ends a running trajectory (not a stop in progress) with `error`.
    fn abort(&mut self, error: FriError) {
        if let Some(id) = self.running_id() {
            self.finish(id, Err(error));
        }
    }

    /// Whether `m` lets the driver command, and if not, why.
    fn commandable(&self, m: &MeasurementDatagram) -> Result<(), FriError> {
        let (state, quality, power) = (m.interface.state, m.interface.quality, m.robot.power);
        if state != FriState::Command || power == 0 {
            Err(FriError::NotCommanding {
                state,
                quality,
                power,
            })
        } else if quality < self.config.min_command_quality {
            Err(FriError::QualityTooLow {
                quality,
                min: self.config.min_command_quality,
            })
        } else {
            Ok(())
        }
    }

    /// Takes in one measurement received at `now`; returns the command to send back
    /// to its sender, or `None` when it must not be answered (stale, unusable, or
    /// answers are being withheld).
    pub fn on_measurement(
        &mut self,
        m: &MeasurementDatagram,
        now: Duration,
    ) -> Option<CommandDatagram> {
        let seq = m.send_seq_count;
        let gap = match &self.last {
            Some(prev) => {
                let gap = seq_ahead(seq, prev.send_seq_count);
                let stale = gap == 0 || gap > u16::MAX / 2;
                // After a silence (the link is late: motion aborted, holding), two
                // consecutive "old" numbers are the robot's counter starting over
                // (FRI closed and reopened on the KRC), not stale datagrams.
                let restarted = stale
                    && self.late
                    && self.restart_seq.is_some_and(|r| seq == r.wrapping_add(1));
                if restarted {
                    self.push(FriEvent::SequenceRestarted {
                        seq,
                        latest_seq: prev.send_seq_count,
                    });
                    self.restart_seq = None;
                    1
                } else if stale {
                    self.restart_seq = self.late.then_some(seq);
                    self.counters.stale_measurements += 1;
                    self.push(FriEvent::StaleMeasurement {
                        seq,
                        latest_seq: prev.send_seq_count,
                    });
                    return None;
                } else {
                    gap
                }
            }
            None => 1,
        };
        self.restart_seq = None;
        // The period travels as f32; FRI periods are whole milliseconds, so round to µs.
        let dt_s = (f64::from(m.interface.desired_msr_sample_time_s) * 1e6).round() / 1e6;
        if !(dt_s > 0.0 && dt_s <= 1.0) {
            self.push(FriEvent::BadSampleTime {
                value_s: m.interface.desired_msr_sample_time_s,
            });
            return None;
        }
        self.counters.measurements += 1;
        if self.late {
            self.late = false;
            let after_s = now
                .saturating_sub(self.last_rx.unwrap_or(now))
                .as_secs_f64();
            self.push(FriEvent::LinkRestored { after_s });
        }
        let (prev_state, prev_quality, prev_seq) = self.last.as_ref().map_or(
            (FriState::Off, Quality::Unacceptable, seq.wrapping_sub(1)),
            |p| (p.interface.state, p.interface.quality, p.send_seq_count),
        );
        if gap > 1 {
            self.counters.missed_measurements += u64::from(gap - 1);
            self.push(FriEvent::MeasurementsMissed {
                after_seq: prev_seq,
                received_seq: seq,
                missed: gap - 1,
            });
        }
        let (state, quality) = (m.interface.state, m.interface.quality);
        if state != prev_state {
            self.push(FriEvent::StateChanged {
                from: prev_state,
                to: state,
                seq,
            });
            if prev_state == FriState::Command && self.release {
                self.push(FriEvent::Released { seq });
            } else if prev_state == FriState::Command {
                let during_motion = !matches!(self.motion, Motion::Mirror | Motion::Hold(_));
                self.push(FriEvent::DroppedToMonitor {
                    state,
                    quality,
                    during_motion,
                    seq,
                });
            }
        }
        if quality != prev_quality {
            self.push(FriEvent::QualityChanged {
                from: prev_quality,
                to: quality,
                seq,
            });
        }
        self.last = Some(*m);
        self.last_rx = Some(now);

        let mirrored = m.mirrored_jnt_pos().map(f64::from);
        let target = match self.commandable(m) {
            Err(why) => {
                if !matches!(self.motion, Motion::Mirror) {
                    let error = match why {
                        FriError::NotCommanding { state, quality, .. } => {
                            FriError::LeftCommandMode { state, quality }
                        }
                        other => other,
                    };
                    self.abort(error);
                    self.motion = Motion::Mirror;
                }
                self.commanding = false;
                mirrored
            }
            Ok(()) => {
                self.commanding = true;
                self.check_guard(m);
                self.advance(f64::from(gap) * dt_s, mirrored)
            }
        };
        self.commanded_rad = target.map(|v| f64::from(v as f32));
        self.send_seq = self.send_seq.wrapping_add(1);
        let command = CommandDatagram {
            send_seq_count: self.send_seq,
            refl_seq_count: seq,
            cmd_flags: CmdFlags::JNT_POS,
            jnt_pos: target.map(|v| v as f32),
            krl: KrlData {
                bools: if self.release { RELEASE_BIT } else { 0 },
                ..KrlData::default()
            },
            ..Default::default()
        };
        if self.withhold {
            self.counters.withheld += 1;
            None
        } else {
            self.counters.answers += 1;
            Some(command)
        }
    }

    /// Stops a guarded motion whose force threshold `m` exceeds.
    fn check_guard(&mut self, m: &MeasurementDatagram) {
        let Motion::Follow {
            id,
            guard: Some((guard, start)),
            ..
        } = &self.motion
        else {
            return;
        };
        let f = tcp_force(m);
        let force_n = (0..3)
            .map(|i| (f[i] - start[i]).powi(2))
            .sum::<f64>()
            .sqrt();
        if force_n > guard.threshold_n {
            let (id, threshold_n) = (*id, guard.threshold_n);
            self.brake();
            self.finish(
                id,
                Err(FriError::Contact {
                    id,
                    force_n,
                    threshold_n,
                }),
            );
        }
    }

    /// Moves the motion on by `dt_s` and returns the position to command.
    fn advance(&mut self, dt_s: f64, mirrored: [f64; JOINTS]) -> [f64; JOINTS] {
        match &mut self.motion {
            Motion::Mirror => {
                self.motion = Motion::Hold(mirrored);
                mirrored
            }
            Motion::Hold(q) => *q,
            Motion::Follow {
                id,
                trajectory,
                t_s,
                ..
            } => {
                *t_s += dt_s;
                if *t_s >= trajectory.duration_s() {
                    let (id, end) = (*id, trajectory.end());
                    self.motion = Motion::Hold(end);
                    self.finish(id, Ok(()));
                    end
                } else {
                    trajectory.sample(*t_s).position
                }
            }
            Motion::Brake { profile, t_s, .. } => {
                *t_s += dt_s;
                let q = profile.sample(*t_s).position;
                if *t_s >= profile.duration_s() {
                    self.motion = Motion::Hold(q);
                }
                q
            }
        }
    }

    /// Takes in one datagram from `from` received at `now`: dropped (counted, never
    /// answered) unless it comes from the robot ([`DriverConfig::robot`]), then
    /// decoded and handled as [`DriverCore::on_measurement`]. Returns the command
    /// to send back to `from`, if any.
    pub fn on_datagram(
        &mut self,
        bytes: &[u8],
        from: SocketAddr,
        now: Duration,
    ) -> Option<CommandDatagram> {
        if !self.config.robot.admits(from) {
            self.counters.foreign_datagrams += 1;
            let dropped = self.counters.foreign_datagrams;
            if dropped.is_power_of_two() {
                self.push(FriEvent::ForeignDatagram {
                    from,
                    robot: self.config.robot,
                    dropped,
                });
            }
            return None;
        }
        match MeasurementDatagram::decode(bytes) {
            Ok(m) => self.on_measurement(&m, now),
            Err(error) => {
                self.on_bad_datagram(error);
                None
            }
        }
    }

    /// Reports a datagram that failed to decode.
    pub fn on_bad_datagram(&mut self, error: DatagramError) {
        self.counters.bad_datagrams += 1;
        self.push(FriEvent::BadDatagram { error });
    }

    /// Checks for a late measurement at `now`; the first time one is overdue by
    /// `timeout_s` this reports it, aborts the motion and stops the arm: a running
    /// trajectory decelerates from its last command within its limits, then holds.
    /// Holding at once would answer the next measurement, when the link comes back
    /// with the robot still commanding, with a step in velocity. Returns whether it
    /// did so now.
    pub fn check_late(&mut self, now: Duration) -> bool {
        let Some(last_rx) = self.last_rx else {
            return false;
        };
        let waited_s = now.saturating_sub(last_rx).as_secs_f64();
        if self.late || waited_s < self.config.timeout_s {
            return false;
        }
        self.late = true;
        self.counters.late += 1;
        let timeout_s = self.config.timeout_s;
        self.push(FriEvent::MeasurementLate {
            waited_s,
            timeout_s,
        });
        self.abort(FriError::MeasurementLate {
            waited_s,
            timeout_s,
        });
        self.brake();
        true
    }

    /// Starts following `trajectory` from the next measurement. It must start (within
    /// `start_tolerance_rad`) where the arm is commanded, the robot must be
    /// commandable and no other motion running. Returns the motion's id.
    pub fn start_trajectory(&mut self, trajectory: Trajectory<JOINTS>) -> Result<u64, FriError> {
        self.start_motion(trajectory, None)
    }

    /// [`DriverCore::start_trajectory`] with a force guard: the motion stops
    /// (decelerates, then holds) at the first measurement whose external TCP force
    /// exceeds `guard` over the force when it started, and ends with
    /// [`FriError::Contact`].
    pub fn start_guarded_trajectory(
        &mut self,
        trajectory: Trajectory<JOINTS>,
        guard: ForceGuard,
    ) -> Result<u64, FriError> {
        if !(guard.threshold_n.is_finite() && guard.threshold_n > 0.0) {
            return Err(FriError::BadConfig {
                field: "force guard threshold_n",
                value: guard.threshold_n.to_string(),
                problem: "must be a finite force > 0",
            });
        }
        self.start_motion(trajectory, Some(guard))
    }

    fn start_motion(
        &mut self,
        trajectory: Trajectory<JOINTS>,
        guard: Option<ForceGuard>,
    ) -> Result<u64, FriError> {
        if let Some(id) = self.running_id() {
            return Err(FriError::Busy { id });
        }
        let Some(m) = self.last.filter(|_| !self.late) else {
            return Err(FriError::NotCommanding {
                state: self.last.map_or(FriState::Off, |m| m.interface.state),
                quality: self
                    .last
                    .map_or(Quality::Unacceptable, |m| m.interface.quality),
                power: self.last.map_or(0, |m| m.robot.power),
            });
        };
        self.commandable(&m)?;
        // A stop still decelerating: a motion starting from rest would be a step in
        // velocity.
        if let Motion::Brake { id, .. } = self.motion {
            return Err(FriError::Busy { id });
        }
        let current = match &self.motion {
            Motion::Hold(q) => *q,
            _ => m.mirrored_jnt_pos().map(f64::from),
        };
        let start = trajectory.start();
        let tolerance_rad = self.config.start_tolerance_rad;
        for joint in 0..JOINTS {
            if (start[joint] - current[joint]).abs() > tolerance_rad {
                return Err(FriError::StartMismatch {
                    joint,
                    start_rad: start[joint],
                    current_rad: current[joint],
                    tolerance_rad,
                });
            }
        }
        let id = self.next_id;
        self.next_id += 1;
        self.motion = Motion::Follow {
            id,
            trajectory: Box::new(trajectory),
            t_s: 0.0,
            guard: guard.map(|g| (g, tcp_force(&m))),
        };
        Ok(id)
    }

    /// Stops a running trajectory: decelerates to rest within its acceleration
    /// limits, then holds. The motion ends with [`FriError::Stopped`].
    pub fn stop(&mut self) {
        if let Some(id) = self.brake() {
            self.finish(id, Err(FriError::Stopped { id }));
        }
    }

    /// Turns a running trajectory into a stop profile (decelerate within its
    /// limits, then hold); returns its id.
    fn brake(&mut self) -> Option<u64> {
        let Motion::Follow {
            id,
            trajectory,
            t_s,
            ..
        } = &self.motion
        else {
            return None;
        };
        let now = trajectory.sample(*t_s);
        let profile = StopProfile::new(now.position, now.velocity, trajectory.limits());
        let id = *id;
        self.motion = Motion::Brake {
            id,
            profile,
            t_s: 0.0,
        };
        Some(id)
    }

    /// Whether the arm is still moving under the driver's command (following or braking).
    pub fn is_moving(&self) -> bool {
        matches!(self.motion, Motion::Follow { .. } | Motion::Brake { .. })
    }

    /// The outcome of motion `id` once it has ended.
    pub fn outcome(&self, id: u64) -> Option<Result<(), FriError>> {
        if id == 0 || id >= self.next_id {
            return Some(Err(FriError::UnknownMotion { id }));
        }
        match &self.outcome {
            Some((done, result)) if *done == id => Some(result.clone()),
            // An older motion ended before the latest one started.
            Some((done, _)) if *done > id => Some(Ok(())),
            _ => None,
        }
    }

    /// Stops any motion and asks the robot to leave command mode ([`RELEASE_BIT`] in
    /// every command from now on).
    pub fn release(&mut self) {
        self.stop();
        self.release = true;
    }

    /// Whether the robot is released: the driver asked for it and the robot is out
    /// of command mode, or the link is gone (nothing left to release).
    pub fn is_released(&self) -> bool {
        self.release
            && (self.late
                || self
                    .last
                    .is_none_or(|m| m.interface.state != FriState::Command))
    }

    /// Withholds (`true`) or resumes answers: fault injection for tests.
    pub fn set_withhold_answers(&mut self, withhold: bool) {
        self.withhold = withhold;
    }

    /// A snapshot of the link and the arm.
    pub fn status(&self) -> FriStatus {
        let m = self.last.unwrap_or_default();
        FriStatus {
            state: m.interface.state,
            quality: m.interface.quality,
            power: m.robot.power,
            control: m.robot.control,
            commanding: self.commanding && !self.late,
            motion_id: self.running_id(),
            measured_rad: m.data.msr_jnt_pos.map(f64::from),
            commanded_rad: self.commanded_rad,
            last_seq: self.last.map(|m| m.send_seq_count),
            late: self.late,
            link: m.interface.stats,
            counters: self.counters,
            est_ext_tcp_ft: m.data.est_ext_tcp_ft.map(f64::from),
            moving: self.is_moving(),
        }
    }
}

#[cfg(test)]
mod tests;
