//! [`FriSimulator`], the robot-side FRI state machine: its state, the measurement
//! it sends each cycle, and what it reports.
//!
//! - `link`: which measurements were answered in time, and the link quality.
//! - `arm`: the arm's motion and the KRL program (`friStart`, drops to monitor mode).
//! - `receive`: the PC's commands.

mod arm;
mod link;
mod receive;

use super::force::ForceModel;
use super::{
    DropReason, ExternalForce, ReceivedCommand, SimConfig, SimCounters, SimError, SimEvent,
};
use crate::hw::fri::datagram::{
    CmdFlags, ControlMode, FriState, InterfaceState, LinkStats, MeasurementDatagram, Quality,
    RobotData, RobotState,
};
use crate::hw::fri::JOINTS;
use serde::Serialize;
use std::collections::VecDeque;
use std::time::Duration;

/// Number of measurements the link statistics cover.
pub const STATS_WINDOW: usize = 100;

/// Drive temperature the simulator reports.
const AMBIENT_TEMPERATURE: f32 = 25.0;
/// All seven drives powered, one bit each.
const POWER_ALL_DRIVES: u16 = 0x7f;
/// Most recent events kept; older ones are counted and dropped.
const EVENT_CAPACITY: usize = 1024;

/// The robot-side FRI state machine.
#[derive(Debug)]
pub struct FriSimulator {
    /// Source of `estExtTcpFT`.
    force_model: ForceModel,
    /// `estExtTcpFT` of the current cycle.
    ext_tcp_ft: [f64; 6],
    config: SimConfig,
    /// Time of `friOpen` (the first measurement).
    opened_at: Option<Duration>,
    next_send: Duration,
    last_step: Duration,
    state: FriState,
    quality: Quality,
    /// `sendSeqCount` of the latest measurement.
    seq: u16,
    /// Send times of the last measurements.
    sent: VecDeque<(u16, Duration)>,
    /// Newest measurement answered so far.
    last_answered: Option<u16>,
    /// Latency of the answer to the latest measurement, if it came.
    current_latency_s: Option<f64>,
    /// Per finished measurement: the latency when answered in time, else a miss.
    window: VecDeque<Option<f64>>,
    consecutive_misses: u32,
    msr_rad: [f64; JOINTS],
    /// The robot's own (KRL) command.
    krl_rad: [f64; JOINTS],
    /// The command the arm tracks in CMD (received or extrapolated).
    target_rad: [f64; JOINTS],
    prev_target_rad: [f64; JOINTS],
    /// The last received command and the measurement it reflected.
    last_cmd_rad: [f64; JOINTS],
    last_applied: Option<u16>,
    new_command: bool,
    latched_flags: CmdFlags,
    last_monitor_flags: CmdFlags,
    perfect_cycles: u32,
    start_requested: bool,
    /// The last command carried [`RELEASE_BIT`].
    ///
    /// [`RELEASE_BIT`]: crate::hw::fri::RELEASE_BIT
    release_requested: bool,
    drop_reason: Option<DropReason>,
    events: VecDeque<SimEvent>,
    counters: SimCounters,
    latencies_s: Vec<f64>,
    /// Every answer received, when recording ([`FriSimulator::record_commands`]).
    commands: Option<Vec<ReceivedCommand>>,
}

impl FriSimulator {
    /// A robot at `config.initial_joints_rad`, FRI not yet open (it opens in MON at
    /// the first [`poll`](FriSimulator::poll)).
    pub fn new(config: SimConfig) -> Result<FriSimulator, SimError> {
        config.validate()?;
        let q = config.initial_joints_rad;
        Ok(FriSimulator {
            force_model: ForceModel(None),
            ext_tcp_ft: [0.0; 6],
            opened_at: None,
            next_send: Duration::ZERO,
            last_step: Duration::ZERO,
            state: FriState::Off,
            quality: Quality::Unacceptable,
            seq: config.initial_seq_count.wrapping_sub(1),
            sent: VecDeque::with_capacity(STATS_WINDOW),
            last_answered: None,
            current_latency_s: None,
            window: VecDeque::with_capacity(STATS_WINDOW),
            consecutive_misses: 0,
            msr_rad: q,
            krl_rad: q,
            target_rad: q,
            prev_target_rad: q,
            last_cmd_rad: q,
            last_applied: None,
            new_command: false,
            latched_flags: CmdFlags::NONE,
            last_monitor_flags: CmdFlags::NONE,
            perfect_cycles: 0,
            start_requested: config.auto_start,
            release_requested: false,
            drop_reason: None,
            events: VecDeque::new(),
            counters: SimCounters::default(),
            latencies_s: Vec::new(),
            commands: None,
            config,
        })
    }

    /// The configuration.
    pub fn config(&self) -> &SimConfig {
        &self.config
    }

    /// Sets (or removes) the model of `estExtTcpFT`.
    pub fn set_external_force(&mut self, model: Option<Box<dyn ExternalForce>>) {
        self.force_model = ForceModel(model);
    }

    /// `estExtTcpFT` of the latest measurement (Fx Fy Fz N, Tz Ty Tx N m).
    pub fn ext_tcp_ft(&self) -> [f64; 6] {
        self.ext_tcp_ft
    }

    /// Monitor or command mode (OFF before the first poll).
    pub fn state(&self) -> FriState {
        self.state
    }

    /// The current link quality.
    pub fn quality(&self) -> Quality {
        self.quality
    }

    /// Measured joint positions (rad).
    pub fn joints_rad(&self) -> [f64; JOINTS] {
        self.msr_rad
    }

    /// Why the robot last dropped to MON, if it did.
    pub fn drop_reason(&self) -> Option<DropReason> {
        self.drop_reason
    }

    /// Cumulative counters.
    pub fn counters(&self) -> SimCounters {
        self.counters
    }

    /// Every answer latency so far (s), when `record_latencies` is set.
    pub fn latencies_s(&self) -> &[f64] {
        &self.latencies_s
    }

    /// Removes and returns the answer latencies recorded so far (s).
    pub fn take_latencies_s(&mut self) -> Vec<f64> {
        std::mem::take(&mut self.latencies_s)
    }

    /// Starts (or stops, `false`) keeping every command that answers a measurement
    /// ([`ReceivedCommand`]; grows without bound while on).
    pub fn record_commands(&mut self, on: bool) {
        self.commands = on.then(|| self.commands.take().unwrap_or_default());
    }

    /// Removes and returns the commands recorded so far (oldest first).
    pub fn take_commands(&mut self) -> Vec<ReceivedCommand> {
        self.commands
            .as_mut()
            .map(std::mem::take)
            .unwrap_or_default()
    }

    /// When the next measurement is due (clock time).
    pub fn next_send_time(&self) -> Duration {
        self.next_send
    }

    /// Removes and returns the events so far (oldest first).
    pub fn take_events(&mut self) -> Vec<SimEvent> {
        self.events.drain(..).collect()
    }

    /// Whether the KRL program will call `friStart` once quality allows.
    pub fn start_requested(&self) -> bool {
        self.start_requested
    }

    /// The KRL program asks for `friStart` again: it happens once quality has been
    /// PERFECT for `start_after_perfect_cycles` cycles.
    pub fn request_start(&mut self) {
        self.start_requested = true;
    }

    /// The KRL program calls `friStop`: CMD -> MON, the arm stops where it is.
    pub fn request_stop(&mut self, now: Duration) {
        self.start_requested = false;
        if self.state == FriState::Command {
            self.drop_to_monitor(DropReason::FriStop, now);
        }
    }

    fn at_s(&self, now: Duration) -> f64 {
        now.saturating_sub(self.opened_at.unwrap_or(now))
            .as_secs_f64()
    }

    fn push_event(&mut self, event: SimEvent) {
        match &event {
            SimEvent::DroppedToMonitor {
                reason: DropReason::Released,
                at_s,
            } => tracing::info!("FRI sim: released to monitor at {at_s:.3} s"),
            SimEvent::DroppedToMonitor { reason, at_s } => {
                tracing::warn!("FRI sim: dropped to monitor at {at_s:.3} s: {reason}")
            }
            SimEvent::BadDatagram { error, .. } => tracing::warn!("FRI sim: {error}"),
            other => tracing::info!("FRI sim: {other:?}"),
        }
        if self.events.len() == EVENT_CAPACITY {
            self.events.pop_front();
            self.counters.events_discarded += 1;
        }
        self.events.push_back(event);
    }

    /// Advances the robot to `now`; when a measurement is due, returns it (to be sent
    /// at once). The first call opens FRI in MON.
    pub fn poll(&mut self, now: Duration) -> Option<MeasurementDatagram> {
        let cycle = Duration::from_nanos((self.config.cycle_s * 1e9).round() as u64);
        if self.opened_at.is_none() {
            self.opened_at = Some(now);
            self.state = FriState::Monitor;
            self.last_step = now;
            self.next_send = now;
        }
        if now < self.next_send {
            return None;
        }
        if self.counters.measurements_sent > 0 {
            self.finish_cycle();
            self.step_arm(now);
        }
        self.update_quality(now);
        self.run_state_machine(now);
        if let Some(model) = &mut self.force_model.0 {
            self.ext_tcp_ft = model.tcp_ft(&self.msr_rad);
        }

        self.seq = self.seq.wrapping_add(1);
        if self.sent.len() == STATS_WINDOW {
            self.sent.pop_front();
        }
        self.sent.push_back((self.seq, now));
        self.current_latency_s = None;
        self.new_command = false;
        self.counters.measurements_sent += 1;
        self.next_send += cycle;
        if self.next_send <= now {
            self.counters.overruns += 1;
            self.next_send = now + cycle;
        }
        Some(self.measurement(now))
    }

    /// The measurement for the current cycle.
    fn measurement(&self, now: Duration) -> MeasurementDatagram {
        let commanding = self.state == FriState::Command;
        let to_f32 = |q: [f64; JOINTS]| q.map(|v| v as f32);
        let krl = to_f32(self.krl_rad);
        let offset: [f32; JOINTS] = if commanding {
            std::array::from_fn(|j| self.target_rad[j] as f32 - krl[j])
        } else {
            [0.0; JOINTS]
        };
        MeasurementDatagram {
            send_seq_count: self.seq,
            refl_seq_count: self.last_answered.unwrap_or(0),
            krl: Default::default(),
            interface: InterfaceState {
                timestamp_s: self.at_s(now) as f32,
                state: self.state,
                quality: self.quality,
                desired_msr_sample_time_s: self.config.cycle_s as f32,
                desired_cmd_sample_time_s: self.config.cycle_s as f32,
                safety_limits: 0.0,
                stats: self.link_stats(),
            },
            robot: RobotState {
                power: POWER_ALL_DRIVES,
                control: ControlMode::Position,
                error: 0,
                warning: 0,
                temperature: [AMBIENT_TEMPERATURE; JOINTS],
            },
            data: RobotData {
                msr_jnt_pos: to_f32(self.msr_rad),
                cmd_jnt_pos: krl,
                cmd_jnt_pos_fri_offset: offset,
                est_ext_tcp_ft: self.ext_tcp_ft.map(|v| v as f32),
                ..Default::default()
            },
        }
    }

    /// A summary for reports.
    pub fn summary(&self) -> SimSummary {
        SimSummary {
            state: self.state,
            quality: self.quality,
            joints_rad: self.msr_rad,
            drop_reason: self.drop_reason,
            counters: self.counters,
            link: self.link_stats(),
        }
    }
}

/// The simulator's state for reports.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct SimSummary {
    /// Monitor or command mode.
    pub state: FriState,
    /// Link quality.
    pub quality: Quality,
    /// Measured joint positions (rad).
    pub joints_rad: [f64; JOINTS],
    /// Why it last dropped to MON, if it did.
    pub drop_reason: Option<DropReason>,
    /// Cumulative counters.
    pub counters: SimCounters,
    /// Statistics over the last 100 measurements.
    pub link: LinkStats,
}
