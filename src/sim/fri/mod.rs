//! A robot-side FRI 1.x simulator of the LBR4+ (KRC with a KRL program that calls
//! `friOpen`, waits for quality PERFECT, then `friStart`).
//!
//! [`FriSimulator`] is a pure state machine: its behaviour is a function of the times
//! passed to [`FriSimulator::poll`] and the bytes (and arrival times) passed to
//! [`FriSimulator::receive`], so tests drive it without sockets or sleeping.
//! [`spawn_udp`] / [`run_udp`] put it on a UDP socket with a real clock
//! (`cell-sim-arm`).
//!
//! Model (the simulator's own choices where the spec gives no numbers):
//! - One measurement every `cycle_s`. A measurement counts as answered in time when a
//!   command reflecting its `sendSeqCount` arrives before the next measurement is
//!   sent; otherwise it is a miss. Statistics cover the last 100 measurements:
//!   `answerRate`, `missRate`, `latency` (mean, s), `jitter` (max - min latency, s),
//!   and `missCounter` (misses since `friOpen`).
//! - Quality ([`QualityThresholds`]): PERFECT needs a full window with miss rate at
//!   most 1 % and the last answer in time; then OK (<= 5 %, at most one consecutive
//!   miss), BAD (<= 20 %, fewer than 5 consecutive misses), else UNACCEPTABLE.
//! - The KRL program calls `friStart` after quality has been PERFECT for
//!   `start_after_perfect_cycles` cycles: the state goes MON -> CMD and `cmdFlags` are
//!   latched from the last answer.
//! - In CMD the arm tracks the commanded `jntPos` (directly, or with a first-order lag).
//!   A single missing answer is bridged by extrapolating the last commanded velocity;
//!   further misses hold the command.
//! - The robot drops to MON and stops the arm where it is (its own command becomes the
//!   measured position, offset zero) when quality falls below BAD, when a commanded
//!   position is at or beyond a joint limit, when a commanded step implies a speed at
//!   or above a joint's velocity limit, or when `cmdFlags` change in CMD. The KRL
//!   program does not call `friStart` again unless [`FriSimulator::request_start`].
//! - The KRL program calls `friStop` when a command sets [`RELEASE_BIT`] of
//!   `boolData` (the PC is done), and does not call `friStart` while it is set.
//! - `estExtTcpFT` comes from an [`ExternalForce`] model when one is set
//!   ([`FriSimulator::set_external_force`]; `cell-sim-arm --scene` uses the
//!   simulated world's contact force, [`crate::sim::world::ArmContact`]), evaluated
//!   at the measured joints every cycle; zero otherwise.
//! - Not simulated (sent as zeros): Cartesian poses, torques, Jacobian, mass matrix,
//!   gravity. Drive temperatures are a constant ambient value.
//!
//! # Modules
//! - `error`: [`SimError`], what can go wrong.
//! - `config`: [`SimConfig`], [`QualityThresholds`] and the LBR4+ limits.
//! - `event`: [`SimEvent`], [`DropReason`], [`Answer`], [`ReceivedCommand`] and
//!   [`SimCounters`], what the simulated robot saw or did.
//! - `force`: [`ExternalForce`], the contact force at the tool, and
//!   [`BackgroundForce`], which computes it beside the cycle.
//! - `simulator`: [`FriSimulator`], the robot's state machine (its link quality, its
//!   arm and KRL program, and the PC's commands), and [`SimSummary`].
//! - `udp`: [`run_udp`] and [`spawn_udp`], the simulator on a UDP socket.
//!
//! [`RELEASE_BIT`]: crate::hw::fri::RELEASE_BIT

mod config;
mod error;
mod event;
mod force;
mod simulator;
mod udp;

pub use config::{
    QualityThresholds, SimConfig, LBR4_POSITION_LIMIT_RAD, LBR4_VELOCITY_LIMIT_RAD_S,
};
pub use error::SimError;
pub use event::{Answer, DropReason, ReceivedCommand, SimCounters, SimEvent};
pub use force::{BackgroundForce, ExternalForce};
pub use simulator::{FriSimulator, SimSummary, STATS_WINDOW};
pub use udp::{run_udp, spawn_udp, SimHandle};

#[cfg(test)]
mod tests;
