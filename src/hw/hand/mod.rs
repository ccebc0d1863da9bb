//! The Barrett BH8-282 driver: four pucks (F1, F2, F3, spread) on any [`CanBus`].
//!
//! Bring-up is [`Hand::wake`], [`Hand::identify`], [`Hand::initialise`]; then
//! [`Hand::open`], [`Hand::close`], [`Hand::move_to`], [`Hand::positions`],
//! [`Hand::strain`], [`Hand::stop`].
//!
//! Every call takes a timeout: the whole call's budget, measured on the injected
//! [`Clock`] (which also times the waits between polls). Each request/reply exchange
//! waits [`HandTiming::reply_timeout`] on the bus and is retried up to
//! [`HandTiming::attempts`] times, so a lost frame costs a retry, not the call.
//! Pucks never acknowledge a set, so a set that matters is read back, and a motion
//! command that the puck never acted on (it did not move, is not at the target and
//! was never seen in MODE 5) is sent again.
//!
//! A reply that does not decode is [`HandError::Garbled`]; a reply nobody asked for
//! (except a late answer to an exchange that already timed out) is
//! [`HandError::Unexpected`]. Both carry the frame, and neither is trusted.
//! Frames from other nodes to other nodes are ignored.
//!
//! # What stop does to the hardware
//!
//! [`Hand::stop`] sets MODE = 3 (PID position hold) on all four pucks with one
//! frame to the hand group 0x405, then confirms it per puck: any motion ends at
//! once and each motor actively holds the position it has, pressing on a grasped
//! object with up to its torque limit MT. [`Hand::idle`] sets MODE = 0 instead:
//! the motors are unpowered; the worm-geared fingers stay where they are (they are
//! not back-drivable), the spread can be pushed. Dropping a [`Hand`] sends nothing:
//! the pucks keep doing what they were last told.

pub mod puck;

use crate::clock::Clock;
use crate::config::CanConfig;
use crate::hw::can::{CanBus, CanError, CanFrame};
pub use puck::Puck;
use puck::{
    command, decode_position, decode_property_reply, group, mode, role, split_id, status, Property,
    PuckFrameError,
};
use std::collections::VecDeque;
use std::sync::Arc;
use std::time::Duration;

/// Oldest firmware whose property numbers this driver uses.
pub const MIN_FIRMWARE: i32 = 132;

/// Frames from unrelated nodes tolerated while waiting for one reply.
const MAX_IGNORED_PER_REPLY: usize = 256;

/// Timed-out exchanges whose late replies are still recognised.
const MAX_LATE: usize = 32;

/// Timing and tuning of the driver.
#[derive(Debug, Clone, PartialEq)]
pub struct HandTiming {
    /// How long one exchange waits for its reply.
    pub reply_timeout: Duration,
    /// Tries per exchange (and sends per unanswered motion command).
    pub attempts: u32,
    /// Gap between waking successive pucks.
    pub wake_gap: Duration,
    /// Wait after waking, while the pucks' transceivers power up.
    pub wake_settle: Duration,
    /// Period of polling MODE while a motion runs.
    pub poll_period: Duration,
    /// TSTOP of the fingers (ms stalled before a move ends).
    pub finger_tstop_ms: i32,
    /// TSTOP of the spread (ms).
    pub spread_tstop_ms: i32,
    /// A puck within this many counts of its target has reached it.
    pub position_tolerance_counts: i32,
}

impl Default for HandTiming {
    fn default() -> Self {
        HandTiming {
            reply_timeout: Duration::from_millis(50),
            attempts: 5,
            wake_gap: Duration::from_millis(10),
            wake_settle: Duration::from_secs(1),
            poll_period: Duration::from_millis(10),
            finger_tstop_ms: 50,
            spread_tstop_ms: 150,
            position_tolerance_counts: 500,
        }
    }
}

impl HandTiming {
    /// Defaults with the reply timeout of the cell configuration.
    pub fn from_config(config: &CanConfig) -> HandTiming {
        HandTiming {
            reply_timeout: Duration::from_secs_f64(config.reply_timeout_s),
            ..HandTiming::default()
        }
    }
}

/// What [`Hand::identify`] learnt about one puck.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct PuckInfo {
    /// Which puck.
    pub puck: Puck,
    /// ROLE (role number and option bits).
    pub role: i32,
    /// VERS, the firmware version.
    pub firmware: i32,
    /// CTS, encoder counts per motor revolution.
    pub counts_per_rev: i32,
    /// Counts per joint radian.
    pub counts_per_rad: f64,
    /// CT, the close target (counts).
    pub close_target_counts: i32,
    /// OT, the open target (counts).
    pub open_target_counts: i32,
    /// ROLE says a strain gauge is fitted.
    pub has_strain_gauge: bool,
}

/// Joint positions of the hand (rad).
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct HandPositions {
    /// Proximal joint angles of F1, F2, F3 (0 open, 2.44 folded over the palm).
    pub fingers_rad: [f64; 3],
    /// Spread angle (0 to pi).
    pub spread_rad: f64,
}

impl HandPositions {
    fn get(&self, puck: Puck) -> f64 {
        match puck {
            Puck::Spread => self.spread_rad,
            finger => self.fingers_rad[finger.index()],
        }
    }
}

/// How one puck's motion ended.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct MotionOutcome {
    /// Which puck.
    pub puck: Puck,
    /// Where it ended (rad).
    pub position_rad: f64,
    /// Where it was sent (rad).
    pub target_rad: f64,
    /// False when it stopped short: stalled (on an object) for TSTOP.
    pub reached_target: bool,
}

/// Errors of the hand driver; each names the puck and carries the numbers.
#[derive(Debug, thiserror::Error)]
pub enum HandError {
    /// The bus failed (the message names the interface).
    #[error(transparent)]
    Bus(#[from] CanError),
    /// A puck never answered.
    #[error("{puck} did not answer {request}: {attempts} attempts of {reply_timeout_s} s")]
    NoReply {
        /// The silent puck.
        puck: Puck,
        /// What was asked (`get STAT`).
        request: String,
        /// How many times it was asked.
        attempts: u32,
        /// How long each attempt waited (s).
        reply_timeout_s: f64,
    },
    /// A reply that does not decode.
    #[error("{puck}: garbled reply {frame} to {request}: {problem}")]
    Garbled {
        /// The puck the frame claims to come from.
        puck: Puck,
        /// What was asked.
        request: String,
        /// The frame.
        frame: CanFrame,
        /// What is wrong with it.
        problem: PuckFrameError,
    },
    /// A well-formed frame that answers nothing asked.
    #[error("{puck}: unexpected frame {frame} while waiting for {request}")]
    Unexpected {
        /// The puck the frame comes from.
        puck: Puck,
        /// What was being waited for.
        request: String,
        /// The frame.
        frame: CanFrame,
    },
    /// STAT is not ready after waking.
    #[error("{puck} is not ready after waking: STAT = {stat} (2 expected)")]
    NotReady {
        /// The puck.
        puck: Puck,
        /// Its STAT.
        stat: i32,
    },
    /// The node is not a hand puck.
    #[error("{puck}: ROLE = {role:#06x} is not a hand puck (ROLE & 0x1F must be 5)")]
    WrongRole {
        /// The puck.
        puck: Puck,
        /// Its ROLE.
        role: i32,
    },
    /// Firmware older than [`MIN_FIRMWARE`] numbers its properties differently.
    #[error("{puck}: firmware VERS = {version} is older than {min} (property numbers differ)")]
    Firmware {
        /// The puck.
        puck: Puck,
        /// Its VERS.
        version: i32,
        /// The oldest supported.
        min: i32,
    },
    /// A property value the puck reports makes no sense.
    #[error("{puck}: {property} = {value}: {problem}")]
    BadProperty {
        /// The puck.
        puck: Puck,
        /// The property.
        property: Property,
        /// Its value.
        value: i32,
        /// Why it cannot be used.
        problem: &'static str,
    },
    /// A call made before the bring-up step it needs.
    #[error("{operation}: call {needed} first")]
    NotReadyForCall {
        /// The call.
        operation: &'static str,
        /// What must come first.
        needed: &'static str,
    },
    /// A target outside the joint range, or not finite.
    #[error("{puck}: target {value_rad} rad outside {min_rad}..={max_rad} rad")]
    OutOfRange {
        /// The puck.
        puck: Puck,
        /// The target (rad).
        value_rad: f64,
        /// Lower limit (rad).
        min_rad: f64,
        /// Upper limit (rad).
        max_rad: f64,
    },
    /// The call's timeout passed.
    #[error("{operation} timed out after {timeout_s} s waiting for {puck}")]
    Timeout {
        /// The call.
        operation: &'static str,
        /// The puck still being waited for.
        puck: Puck,
        /// The call's timeout (s).
        timeout_s: f64,
    },
    /// A motion command the puck never acted on, however often it was sent.
    #[error("{puck} ignored CMD {command} (sent {attempts} times; at {position_counts} counts, target {target_counts})")]
    CommandIgnored {
        /// The puck.
        puck: Puck,
        /// The command's name.
        command: &'static str,
        /// Times sent.
        attempts: u32,
        /// Where the puck is (counts).
        position_counts: i32,
        /// Where it was sent (counts).
        target_counts: i32,
    },
    /// A set that did not take, however often it was sent.
    #[error(
        "{puck}: set {property} = {wanted} did not take (reads {read} after {attempts} attempts)"
    )]
    SetNotApplied {
        /// The puck.
        puck: Puck,
        /// The property.
        property: Property,
        /// The value sent.
        wanted: i32,
        /// The value read back.
        read: i32,
        /// Times sent.
        attempts: u32,
    },
}

/// Where a puck's reply to a request lands.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
struct Expected {
    puck: Puck,
    property: Property,
}

impl Expected {
    fn describe(&self) -> String {
        format!("get {}", self.property)
    }
}

/// How a received frame relates to the reply being waited for.
enum Verdict {
    Answer(Expected, i32),
    Late,
    Unrelated,
    /// A puck's frame that is garbled or answers nothing asked (a corrupted
    /// frame, or the reply to an exchange given up on): dropped, kept as the reason
    /// should the wait end without an answer.
    Noise(HandError),
}

/// A command that starts one puck's motion: the frames to send (again, if the
/// puck ignores them), its name for messages, and the target it moves to.
struct MotionCommand {
    puck: Puck,
    frames: Vec<CanFrame>,
    name: &'static str,
    target_counts: i32,
}

/// One motion being watched.
struct Motion {
    puck: Puck,
    command_frames: Vec<CanFrame>,
    command: &'static str,
    start_counts: i32,
    target_counts: i32,
    seen_moving: bool,
    sends: u32,
}

/// The BH8-282 on a CAN bus. See the module documentation.
pub struct Hand<B> {
    bus: B,
    clock: Arc<dyn Clock>,
    timing: HandTiming,
    info: Option<[PuckInfo; 4]>,
    initialised: bool,
    late: VecDeque<Expected>,
    /// The last frame dropped as noise since the current exchange began.
    noise: Option<HandError>,
}

impl<B: CanBus> Hand<B> {
    /// A driver on `bus`, timing its waits on `clock`. Sends nothing yet.
    pub fn new(bus: B, clock: Arc<dyn Clock>, timing: HandTiming) -> Hand<B> {
        Hand {
            bus,
            clock,
            timing,
            info: None,
            initialised: false,
            late: VecDeque::new(),
            noise: None,
        }
    }

    /// The bus.
    pub fn bus(&self) -> &B {
        &self.bus
    }

    /// The bus, giving up the driver.
    pub fn into_bus(self) -> B {
        self.bus
    }

    /// What [`Hand::identify`] found, if it ran.
    pub fn info(&self) -> Option<&[PuckInfo; 4]> {
        self.info.as_ref()
    }

    /// Wakes the pucks: STAT = 2 to each, [`HandTiming::wake_gap`] apart, waits
    /// [`HandTiming::wake_settle`], then reads STAT back from each (re-waking a puck
    /// that still reports reset, up to [`HandTiming::attempts`] times).
    pub fn wake(&mut self, timeout: Duration) -> Result<(), HandError> {
        let deadline = self.deadline(timeout);
        for puck in Puck::ALL {
            self.set(puck, Property::Stat, status::READY)?;
            self.clock.sleep(self.timing.wake_gap);
        }
        self.clock.sleep(self.timing.wake_settle);
        for puck in Puck::ALL {
            let mut tries = 1;
            loop {
                let stat = self.get(puck, Property::Stat, deadline, "wake", timeout)?;
                if stat == status::READY {
                    break;
                }
                if tries >= self.timing.attempts {
                    return Err(HandError::NotReady { puck, stat });
                }
                tries += 1;
                tracing::warn!(%puck, stat, "puck not ready after wake; waking it again");
                self.set(puck, Property::Stat, status::READY)?;
                self.clock.sleep(self.timing.wake_settle);
            }
        }
        Ok(())
    }

    /// Reads ROLE, VERS, CTS, CT and OT of each puck; checks it is a hand puck
    /// (ROLE & 0x1F == 5) with firmware >= 132.
    pub fn identify(&mut self, timeout: Duration) -> Result<[PuckInfo; 4], HandError> {
        let deadline = self.deadline(timeout);
        let mut infos = Vec::with_capacity(4);
        for puck in Puck::ALL {
            let get =
                |hand: &mut Self, property| hand.get(puck, property, deadline, "identify", timeout);
            let role_value = get(self, Property::Role)?;
            if role_value & role::MASK != role::HAND {
                return Err(HandError::WrongRole {
                    puck,
                    role: role_value,
                });
            }
            let firmware = get(self, Property::Vers)?;
            if firmware < MIN_FIRMWARE {
                return Err(HandError::Firmware {
                    puck,
                    version: firmware,
                    min: MIN_FIRMWARE,
                });
            }
            let counts_per_rev = get(self, Property::Cts)?;
            if counts_per_rev <= 0 {
                return Err(HandError::BadProperty {
                    puck,
                    property: Property::Cts,
                    value: counts_per_rev,
                    problem: "counts per revolution must be positive",
                });
            }
            infos.push(PuckInfo {
                puck,
                role: role_value,
                firmware,
                counts_per_rev,
                counts_per_rad: puck.counts_per_rad(counts_per_rev),
                close_target_counts: get(self, Property::Ct)?,
                open_target_counts: get(self, Property::Ot)?,
                has_strain_gauge: role_value & role::STRAIN_GAUGE != 0,
            });
        }
        let infos: [PuckInfo; 4] = [infos[0], infos[1], infos[2], infos[3]];
        tracing::info!(?infos, "hand identified");
        self.info = Some(infos);
        Ok(infos)
    }

    /// Initialises (HI): sets HOLD (0 fingers, 1 spread) and TSTOP, then CMD = HI
    /// to F1, F2, F3 and waits until they are done, then to the spread and waits.
    pub fn initialise(&mut self, timeout: Duration) -> Result<Vec<MotionOutcome>, HandError> {
        const OP: &str = "initialise";
        let deadline = self.deadline(timeout);
        self.require_identified(OP)?;
        for puck in Puck::ALL {
            let hold = i32::from(!puck.is_finger());
            self.set_verified(puck, Property::Hold, hold, deadline, OP, timeout)?;
            let tstop = self.tstop(puck);
            self.set_verified(puck, Property::Tstop, tstop, deadline, OP, timeout)?;
        }
        let mut outcomes =
            self.command_motion(OP, &Puck::FINGERS, command::HI, |_| 0, deadline, timeout)?;
        outcomes.extend(self.command_motion(
            OP,
            &[Puck::Spread],
            command::HI,
            |_| 0,
            deadline,
            timeout,
        )?);
        self.initialised = true;
        Ok(outcomes)
    }

    /// Opens the three fingers (CMD = O to each, after setting TSTOP) and waits.
    pub fn open(&mut self, timeout: Duration) -> Result<Vec<MotionOutcome>, HandError> {
        self.finger_command("open", command::O, timeout)
    }

    /// Closes the three fingers (TSTOP first, then CMD = C to each) and waits until
    /// each reaches its close target or stalls on an object for TSTOP.
    pub fn close(&mut self, timeout: Duration) -> Result<Vec<MotionOutcome>, HandError> {
        self.finger_command("close", command::C, timeout)
    }

    /// Moves fingers and spread to `target` (trapezoidal moves: E then MODE = 5) and
    /// waits until each arrives or stalls.
    pub fn move_to(
        &mut self,
        target: &HandPositions,
        timeout: Duration,
    ) -> Result<Vec<MotionOutcome>, HandError> {
        const OP: &str = "move_to";
        let deadline = self.deadline(timeout);
        let info = self.require_initialised(OP)?;
        let mut counts = [0; 4];
        for puck in Puck::ALL {
            let value_rad = target.get(puck);
            let (min_rad, max_rad) = puck.range_rad();
            if !(min_rad..=max_rad).contains(&value_rad) {
                return Err(HandError::OutOfRange {
                    puck,
                    value_rad,
                    min_rad,
                    max_rad,
                });
            }
            counts[puck.index()] = (value_rad * info[puck.index()].counts_per_rad).round() as i32;
        }
        for puck in Puck::ALL {
            let tstop = self.tstop(puck);
            self.set_verified(puck, Property::Tstop, tstop, deadline, OP, timeout)?;
            self.set_verified(
                puck,
                Property::E,
                counts[puck.index()],
                deadline,
                OP,
                timeout,
            )?;
        }
        let mut motions = Vec::new();
        for puck in Puck::ALL {
            let frame = puck::set_frame(
                puck::node_id(puck.node()),
                Property::Mode,
                mode::TRAPEZOIDAL,
            );
            let request = MotionCommand {
                puck,
                frames: vec![frame],
                name: "MODE 5",
                target_counts: counts[puck.index()],
            };
            motions.push(self.begin_motion(request, deadline, OP, timeout)?);
        }
        self.watch(OP, motions, deadline, timeout)
    }

    /// Joint positions (rad), from one get of P to the hand group (22-bit position
    /// replies).
    pub fn positions(&mut self, timeout: Duration) -> Result<HandPositions, HandError> {
        let info = self.require_identified("positions")?;
        let counts = self.position_counts_all(timeout)?;
        let rad = |puck: Puck| f64::from(counts[puck.index()]) / info[puck.index()].counts_per_rad;
        Ok(HandPositions {
            fingers_rad: [rad(Puck::F1), rad(Puck::F2), rad(Puck::F3)],
            spread_rad: rad(Puck::Spread),
        })
    }

    /// P (counts) of F1, F2, F3 and the spread, from one get of P to the hand group
    /// 0x405, answered by 22-bit position replies on group 3.
    pub fn position_counts_all(&mut self, timeout: Duration) -> Result<[i32; 4], HandError> {
        let deadline = self.deadline(timeout);
        self.group_positions(deadline, "positions", timeout)
    }

    /// One puck's position P (counts): a get of P on the puck's own identifier,
    /// answered as a property reply (group 6) or a 22-bit position reply (group 3).
    pub fn position_counts(&mut self, puck: Puck, timeout: Duration) -> Result<i32, HandError> {
        let deadline = self.deadline(timeout);
        self.get(puck, Property::P, deadline, "position_counts", timeout)
    }

    /// Raw strain gauge readings SG of F1, F2, F3 (0-4095, about 2000 unloaded).
    pub fn strain(&mut self, timeout: Duration) -> Result<[i32; 3], HandError> {
        let deadline = self.deadline(timeout);
        let mut sg = [0; 3];
        for puck in Puck::FINGERS {
            sg[puck.index()] = self.get(puck, Property::Sg, deadline, "strain", timeout)?;
        }
        Ok(sg)
    }

    /// Any property of one puck (diagnostics).
    pub fn get_property(
        &mut self,
        puck: Puck,
        property: Property,
        timeout: Duration,
    ) -> Result<i32, HandError> {
        let deadline = self.deadline(timeout);
        self.get(puck, property, deadline, "get_property", timeout)
    }

    /// Stops every motor where it is and holds it there (MODE = 3); see the module
    /// documentation for what that does to the hardware.
    pub fn stop(&mut self, timeout: Duration) -> Result<(), HandError> {
        self.set_mode_all("stop", mode::PID, timeout)
    }

    /// Unpowers every motor (MODE = 0); see the module documentation.
    pub fn idle(&mut self, timeout: Duration) -> Result<(), HandError> {
        self.set_mode_all("idle", mode::IDLE, timeout)
    }

    fn set_mode_all(
        &mut self,
        op: &'static str,
        value: i32,
        timeout: Duration,
    ) -> Result<(), HandError> {
        let deadline = self.deadline(timeout);
        self.bus.send(&puck::set_frame(
            puck::group_id(group::HAND),
            Property::Mode,
            value,
        ))?;
        for puck in Puck::ALL {
            self.set_verified(puck, Property::Mode, value, deadline, op, timeout)?;
        }
        Ok(())
    }

    fn finger_command(
        &mut self,
        op: &'static str,
        cmd: i32,
        timeout: Duration,
    ) -> Result<Vec<MotionOutcome>, HandError> {
        let deadline = self.deadline(timeout);
        let info = self.require_initialised(op)?;
        for puck in Puck::FINGERS {
            let tstop = self.tstop(puck);
            self.set_verified(puck, Property::Tstop, tstop, deadline, op, timeout)?;
        }
        let target = |puck: Puck| {
            let i = &info[puck.index()];
            if cmd == command::C {
                i.close_target_counts
            } else {
                i.open_target_counts
            }
        };
        self.command_motion(op, &Puck::FINGERS, cmd, target, deadline, timeout)
    }

    /// Sends CMD `cmd` to each of `pucks` and watches the motions to their targets.
    fn command_motion(
        &mut self,
        op: &'static str,
        pucks: &[Puck],
        cmd: i32,
        target: impl Fn(Puck) -> i32,
        deadline: Duration,
        timeout: Duration,
    ) -> Result<Vec<MotionOutcome>, HandError> {
        let mut motions = Vec::new();
        for &puck in pucks {
            let frame = puck::set_frame(puck::node_id(puck.node()), Property::Cmd, cmd);
            let request = MotionCommand {
                puck,
                frames: vec![frame],
                name: command::name(cmd),
                target_counts: target(puck),
            };
            motions.push(self.begin_motion(request, deadline, op, timeout)?);
        }
        self.watch(op, motions, deadline, timeout)
    }

    /// Reads the start position and sends the command.
    fn begin_motion(
        &mut self,
        command: MotionCommand,
        deadline: Duration,
        op: &'static str,
        timeout: Duration,
    ) -> Result<Motion, HandError> {
        let MotionCommand {
            puck,
            frames,
            name,
            target_counts,
        } = command;
        let start_counts = self.get(puck, Property::P, deadline, op, timeout)?;
        for frame in &frames {
            self.bus.send(frame)?;
        }
        Ok(Motion {
            puck,
            command_frames: frames,
            command: name,
            start_counts,
            target_counts,
            seen_moving: false,
            sends: 1,
        })
    }

    /// Polls MODE until every motion is done; a puck that is done without having
    /// moved, arrived or been seen moving never got its command: send it again.
    fn watch(
        &mut self,
        op: &'static str,
        mut pending: Vec<Motion>,
        deadline: Duration,
        timeout: Duration,
    ) -> Result<Vec<MotionOutcome>, HandError> {
        let tolerance = self.timing.position_tolerance_counts;
        let mut outcomes = Vec::new();
        while !pending.is_empty() {
            if self.clock.now() >= deadline {
                return Err(HandError::Timeout {
                    operation: op,
                    puck: pending[0].puck,
                    timeout_s: timeout.as_secs_f64(),
                });
            }
            self.clock.sleep(self.timing.poll_period);
            let mut still = Vec::new();
            for mut motion in pending {
                let puck = motion.puck;
                let current_mode = self.get(puck, Property::Mode, deadline, op, timeout)?;
                if current_mode == mode::TRAPEZOIDAL {
                    motion.seen_moving = true;
                    still.push(motion);
                    continue;
                }
                let position = self.get(puck, Property::P, deadline, op, timeout)?;
                let reached = (position - motion.target_counts).abs() <= tolerance;
                let moved = (position - motion.start_counts).abs() > tolerance;
                if motion.seen_moving || reached || moved {
                    let counts_per_rad = self
                        .info
                        .as_ref()
                        .map_or(1.0, |info| info[puck.index()].counts_per_rad);
                    outcomes.push(MotionOutcome {
                        puck,
                        position_rad: f64::from(position) / counts_per_rad,
                        target_rad: f64::from(motion.target_counts) / counts_per_rad,
                        reached_target: reached,
                    });
                    continue;
                }
                if motion.sends >= self.timing.attempts {
                    return Err(HandError::CommandIgnored {
                        puck,
                        command: motion.command,
                        attempts: motion.sends,
                        position_counts: position,
                        target_counts: motion.target_counts,
                    });
                }
                tracing::warn!(%puck, command = motion.command, "motion command not acted on; sending it again");
                for frame in &motion.command_frames {
                    self.bus.send(frame)?;
                }
                motion.sends += 1;
                still.push(motion);
            }
            pending = still;
        }
        outcomes.sort_by_key(|o| o.puck);
        Ok(outcomes)
    }

    fn tstop(&self, puck: Puck) -> i32 {
        if puck.is_finger() {
            self.timing.finger_tstop_ms
        } else {
            self.timing.spread_tstop_ms
        }
    }

    fn deadline(&self, timeout: Duration) -> Duration {
        self.clock.now() + timeout
    }

    fn require_identified(&self, operation: &'static str) -> Result<[PuckInfo; 4], HandError> {
        self.info.ok_or(HandError::NotReadyForCall {
            operation,
            needed: "identify",
        })
    }

    fn require_initialised(&self, operation: &'static str) -> Result<[PuckInfo; 4], HandError> {
        let info = self.require_identified(operation)?;
        if !self.initialised {
            return Err(HandError::NotReadyForCall {
                operation,
                needed: "initialise",
            });
        }
        Ok(info)
    }

    /// Sends an (unacknowledged) set to one puck.
    fn set(&mut self, puck: Puck, property: Property, value: i32) -> Result<(), HandError> {
        self.bus.send(&puck::set_frame(
            puck::node_id(puck.node()),
            property,
            value,
        ))?;
        Ok(())
    }

    /// Sets and reads back until the puck reports the value.
    fn set_verified(
        &mut self,
        puck: Puck,
        property: Property,
        value: i32,
        deadline: Duration,
        op: &'static str,
        timeout: Duration,
    ) -> Result<(), HandError> {
        let mut read = 0;
        for _ in 0..self.timing.attempts {
            self.set(puck, property, value)?;
            read = self.get(puck, property, deadline, op, timeout)?;
            if read == value {
                return Ok(());
            }
            tracing::warn!(%puck, %property, value, read, "set did not take; sending it again");
        }
        Err(HandError::SetNotApplied {
            puck,
            property,
            wanted: value,
            read,
            attempts: self.timing.attempts,
        })
    }

    /// Gets a property from one puck, retrying lost exchanges.
    fn get(
        &mut self,
        puck: Puck,
        property: Property,
        deadline: Duration,
        op: &'static str,
        timeout: Duration,
    ) -> Result<i32, HandError> {
        let expected = Expected { puck, property };
        let request = puck::get_frame(puck::node_id(puck.node()), property);
        let description = expected.describe();
        self.noise = None;
        for attempt in 1..=self.timing.attempts {
            self.check_deadline(deadline, op, puck, timeout)?;
            self.bus.send(&request)?;
            if let Some((_, value)) = self.await_reply(&[expected], &description)? {
                return Ok(value);
            }
            tracing::debug!(%puck, %property, attempt, "no reply");
            self.remember_late(expected);
        }
        // Frames came, but never the answer: say what they were.
        if let Some(noise) = self.noise.take() {
            return Err(noise);
        }
        Err(HandError::NoReply {
            puck,
            request: description,
            attempts: self.timing.attempts,
            reply_timeout_s: self.timing.reply_timeout.as_secs_f64(),
        })
    }

    /// Gets P from all four pucks with one request to the hand group; they answer
    /// with 22-bit position replies on group 3. A puck whose reply is lost is asked
    /// on its own.
    fn group_positions(
        &mut self,
        deadline: Duration,
        op: &'static str,
        timeout: Duration,
    ) -> Result<[i32; 4], HandError> {
        self.check_deadline(deadline, op, Puck::F1, timeout)?;
        self.bus
            .send(&puck::get_frame(puck::group_id(group::HAND), Property::P))?;
        let mut waiting: Vec<Expected> = Puck::ALL
            .iter()
            .map(|&puck| Expected {
                puck,
                property: Property::P,
            })
            .collect();
        let mut counts = [0; 4];
        while !waiting.is_empty() {
            let Some((answer, value)) = self.await_reply(&waiting, "get P from the hand group")?
            else {
                break;
            };
            counts[answer.puck.index()] = value;
            waiting.retain(|e| *e != answer);
        }
        for missing in waiting {
            tracing::debug!(puck = %missing.puck, "no position reply to the group get");
            self.remember_late(missing);
            counts[missing.puck.index()] =
                self.get(missing.puck, Property::P, deadline, op, timeout)?;
        }
        Ok(counts)
    }

    fn check_deadline(
        &self,
        deadline: Duration,
        operation: &'static str,
        puck: Puck,
        timeout: Duration,
    ) -> Result<(), HandError> {
        if self.clock.now() >= deadline {
            return Err(HandError::Timeout {
                operation,
                puck,
                timeout_s: timeout.as_secs_f64(),
            });
        }
        Ok(())
    }

    /// Records an exchange that timed out, so its reply, if it comes late, is
    /// recognised and dropped.
    fn remember_late(&mut self, expected: Expected) {
        if self.late.len() == MAX_LATE {
            self.late.pop_front();
        }
        self.late.push_back(expected);
    }

    /// Waits one reply timeout for an answer to one of `expected`.
    fn await_reply(
        &mut self,
        expected: &[Expected],
        request: &str,
    ) -> Result<Option<(Expected, i32)>, HandError> {
        let started = self.clock.now();
        let mut ignored = 0;
        loop {
            let waited = self.clock.now().saturating_sub(started);
            let remaining = self.timing.reply_timeout.saturating_sub(waited);
            if remaining.is_zero() {
                return Ok(None);
            }
            let Some(frame) = self.bus.recv(remaining)? else {
                return Ok(None);
            };
            match self.judge(expected, request, &frame)? {
                Verdict::Answer(answer, value) => return Ok(Some((answer, value))),
                Verdict::Late => {
                    tracing::debug!(%frame, "late reply to an exchange that timed out; dropped")
                }
                Verdict::Unrelated => {
                    ignored += 1;
                    if ignored > MAX_IGNORED_PER_REPLY {
                        return Ok(None);
                    }
                }
                Verdict::Noise(noise) => {
                    tracing::warn!("dropped: {noise}");
                    self.noise = Some(noise);
                    ignored += 1;
                    if ignored > MAX_IGNORED_PER_REPLY {
                        return Ok(None);
                    }
                }
            }
        }
    }

    /// Classifies a frame received while waiting for one of `expected`.
    fn judge(
        &mut self,
        expected: &[Expected],
        request: &str,
        frame: &CanFrame,
    ) -> Result<Verdict, HandError> {
        let address = split_id(frame.id());
        let Some(source) = Puck::from_node(address.source) else {
            return Ok(Verdict::Unrelated);
        };
        if !address.to_group {
            return Ok(Verdict::Unrelated);
        }
        let garbled = |problem| HandError::Garbled {
            puck: source,
            request: request.to_string(),
            frame: *frame,
            problem,
        };
        let answered = match address.destination {
            group::PROPERTY_REPLY => match decode_property_reply(frame.data()) {
                Ok((property, value)) => Property::from_id(property).map(|p| (p, value)),
                Err(problem) => return Ok(Verdict::Noise(garbled(problem))),
            },
            group::POSITION_REPLY => match decode_position(frame.data()) {
                Ok((counts, _secondary)) => Some((Property::P, counts)),
                Err(problem) => return Ok(Verdict::Noise(garbled(problem))),
            },
            _ => None,
        };
        let unexpected = || HandError::Unexpected {
            puck: source,
            request: request.to_string(),
            frame: *frame,
        };
        let Some((property, value)) = answered else {
            return Ok(Verdict::Noise(unexpected()));
        };
        let answer = Expected {
            puck: source,
            property,
        };
        if expected.contains(&answer) {
            // Possibly the late answer of an earlier timed-out attempt: same puck and
            // property, at most one reply timeout older.
            return Ok(Verdict::Answer(answer, value));
        }
        if let Some(i) = self.late.iter().position(|e| *e == answer) {
            self.late.remove(i);
            return Ok(Verdict::Late);
        }
        Ok(Verdict::Noise(unexpected()))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn timing_takes_the_reply_timeout_from_the_cell_config() {
        let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
            .join(crate::config::DEFAULT_CONFIG_PATH);
        let config = crate::config::CellConfig::load(&path).unwrap();
        let timing = HandTiming::from_config(&config.can);
        assert_eq!(
            timing.reply_timeout.as_secs_f64(),
            config.can.reply_timeout_s
        );
        assert_eq!(timing.attempts, HandTiming::default().attempts);
    }

    /// Issue 21's fault campaign: after a corrupted frame, the reply to the
    /// exchange given up on arrived during the next one and failed it, and so on
    /// for every later trial. Such frames are dropped while the answer is awaited.
    #[test]
    fn stale_and_garbled_frames_are_dropped_while_the_answer_is_awaited() {
        let bus = crate::hw::can::VirtualBus::new("noise");
        let mut pucks = bus.endpoint();
        let clock = Arc::new(crate::clock::SystemClock::new());
        let mut hand = Hand::new(bus.endpoint(), clock.clone(), HandTiming::default());
        let f1 = Puck::F1.node();
        let garbled =
            CanFrame::new(puck::reply_id(f1, group::PROPERTY_REPLY), &[0x81, 0x00]).unwrap();
        pucks
            .send(&puck::property_reply_frame(f1, Property::Stat.id(), 2))
            .unwrap();
        pucks.send(&garbled).unwrap();
        pucks
            .send(&puck::property_reply_frame(f1, Property::Tstop.id(), 50))
            .unwrap();
        let timeout = Duration::from_secs(2);
        let deadline = clock.now() + timeout;
        let got = hand.get(Puck::F1, Property::Tstop, deadline, "test", timeout);
        assert_eq!(got.unwrap(), 50);
        // A puck that only ever garbles: the exchange fails, naming the frame.
        for _ in 0..HandTiming::default().attempts {
            pucks.send(&garbled).unwrap();
        }
        let deadline = clock.now() + timeout;
        let err = hand
            .get(Puck::F1, Property::Tstop, deadline, "test", timeout)
            .unwrap_err()
            .to_string();
        assert!(err.contains("garbled reply 566#8100 to get TSTOP"), "{err}");
    }

    #[test]
    fn errors_name_the_puck_and_the_numbers() {
        let err = HandError::NoReply {
            puck: Puck::F3,
            request: "get STAT".into(),
            attempts: 5,
            reply_timeout_s: 0.05,
        };
        assert_eq!(
            err.to_string(),
            "F3 (node 13) did not answer get STAT: 5 attempts of 0.05 s"
        );
        let err = HandError::Garbled {
            puck: Puck::F1,
            request: "get ROLE".into(),
            frame: CanFrame::new(0x566, &[0x81, 0x00]).unwrap(),
            problem: PuckFrameError::Length {
                len: 2,
                expected: "4 or 6",
            },
        };
        assert_eq!(
            err.to_string(),
            "F1 (node 11): garbled reply 566#8100 to get ROLE: 2 data bytes where 4 or 6 are expected"
        );
    }
}
