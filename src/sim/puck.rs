//! An emulator of the BH8-282's four pucks (F1, F2, F3 = nodes 11-13, spread = 14)
//! that talks only through a [`CanBus`], so it runs on a thread or as its own
//! process (`cell-sim-hand`).
//!
//! What it emulates:
//! - Properties: every number 0-127 holds a value; gets are answered on group 6
//!   (4 bytes, 6 for 32-bit properties). A get of P sent to a group is answered with
//!   a 22-bit position reply on group 3. A puck listens to its own node and to its
//!   groups GRPA/B/C (0, 7, 5) and ignores everything else.
//! - STAT: pucks power up in reset (monitor firmware: only STAT, VERS and ROLE are
//!   answered). STAT = 2 boots the motor firmware; the puck is silent for
//!   [`HandEmulatorConfig::boot`], then ready.
//! - Motion: CMD HI/HOME (home to 0), C (to CT at MCV), O (to OT at MOV), M (to DP at
//!   MV), IC/IO (by DS towards CT/OT), TC/TO (emulated as C/O); MODE = 5 moves to E
//!   at MV; setting M moves there; in MODE 3 setting P moves there and holds.
//!   Moves are trapezoidal (ACCEL in counts/ms per ms, speeds in counts/ms) and run
//!   in MODE 5; at the end MODE becomes 3 if HOLD != 0, else 0. MODE = 0 or 3 stops
//!   a move where it is. Motion commands before HI are ignored.
//! - Objects: closing (increasing counts) stalls where the joint reaches its
//!   contact angle ([`HandEmulatorConfig::contact_rad`]); after TSTOP ms stalled the
//!   move ends (TSTOP = 0: it pushes on in MODE 5 forever). A finger resting at
//!   its contact reads SG = 2000 + [`HandEmulatorConfig::contact_strain`], else 2000.
//! - Objects that are there ([`HandEmulator::with_feel`]): with a [`Feel`], the
//!   contact angles are asked for whenever a motion command reaches a finger while
//!   no finger presses on an object (so a closing hand stalls where the object
//!   is at that moment); after every frame the hand reports its joints, and a
//!   held object that slips out ([`Feel::still_held`] false) takes its contacts
//!   with it: the strain falls to 2000.
//!
//! State is a function of the injected clock's time, evaluated whenever a frame
//! arrives, so a test on a [`crate::clock::ManualClock`] sees motion advance exactly
//! as far as it advances the clock.

use crate::clock::Clock;
use crate::hw::can::{CanBus, CanError, CanFrame};
use crate::hw::hand::puck::{
    self, command, decode_request, group, is_wide, mode, role, split_id, status, Property, Puck,
    Request,
};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::thread::JoinHandle;
use std::time::Duration;

/// Counts per motor revolution the emulated encoders have (CTS).
pub const COUNTS_PER_REV: i32 = 4096;

/// Errors of configuring the emulator.
#[derive(Debug, thiserror::Error)]
pub enum SimPuckError {
    /// A contact angle outside the joint's range or not finite.
    #[error("{puck}: contact angle {value_rad} rad outside {min_rad}..={max_rad} rad")]
    BadContact {
        /// The puck.
        puck: Puck,
        /// The angle given (rad).
        value_rad: f64,
        /// Lower limit (rad).
        min_rad: f64,
        /// Upper limit (rad).
        max_rad: f64,
    },
}

/// How the emulated hand is set up.
#[derive(Debug, Clone, PartialEq)]
pub struct HandEmulatorConfig {
    /// Which pucks exist (F1, F2, F3, spread); an absent one never answers.
    pub present: [bool; 4],
    /// Joint angle (rad) where closing meets the object, per puck (`None`: free).
    pub contact_rad: [Option<f64>; 4],
    /// Encoder counts at power-up, before HI defines zero.
    pub initial_counts: [i32; 4],
    /// Silent time between STAT = 2 and ready.
    pub boot: Duration,
    /// VERS reported.
    pub firmware_version: i32,
    /// SG rise of a finger pressing on its contact.
    pub contact_strain: i32,
}

impl Default for HandEmulatorConfig {
    fn default() -> Self {
        HandEmulatorConfig {
            present: [true; 4],
            contact_rad: [None; 4],
            initial_counts: [4000, -3000, 2500, 1200],
            boot: Duration::from_millis(300),
            firmware_version: 190,
            contact_strain: 900,
        }
    }
}

/// Frame counts of the emulator.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct EmulatorStats {
    /// Frames received.
    pub received: u64,
    /// Replies sent.
    pub replies: u64,
    /// Frames for a puck that did not decode (ignored, as a puck would).
    pub garbled: u64,
}

/// What the emulated fingers close on: the simulated world seen from the hand
/// (`crate::sim::world::HandContact`), or a test's script.
pub trait Feel: Send {
    /// Where F1, F2, F3 stall when closing now from `start` (the spread and each
    /// finger's flex now: open, or a grasp's pre-shape) (flex angle, rad); `None`:
    /// free to the limit.
    fn contacts(&mut self, start: &crate::robot::HandPose) -> [Option<f64>; 3];
    /// Whether the object the fingers press on is still in the hand.
    fn still_held(&mut self) -> bool;
    /// The hand's joints now, and whether its fingers press on the object.
    fn hand_moved(&mut self, pose: &crate::robot::HandPose, holding: bool);
}

/// The four emulated pucks.
pub struct HandEmulator {
    clock: Arc<dyn Clock>,
    pucks: Vec<EmulatedPuck>,
    boot: Duration,
    stats: EmulatorStats,
    feel: Option<Box<dyn Feel>>,
}

impl HandEmulator {
    /// Pucks in reset, at their power-up counts, timed by `clock`.
    pub fn new(
        config: HandEmulatorConfig,
        clock: Arc<dyn Clock>,
    ) -> Result<HandEmulator, SimPuckError> {
        let mut pucks = Vec::new();
        for puck in Puck::ALL {
            let i = puck.index();
            let counts_per_rad = puck.counts_per_rad(COUNTS_PER_REV);
            let contact_counts = match config.contact_rad[i] {
                None => None,
                Some(value_rad) => {
                    let (min_rad, max_rad) = puck.range_rad();
                    if !(min_rad..=max_rad).contains(&value_rad) {
                        return Err(SimPuckError::BadContact {
                            puck,
                            value_rad,
                            min_rad,
                            max_rad,
                        });
                    }
                    Some(value_rad * counts_per_rad)
                }
            };
            if config.present[i] {
                pucks.push(EmulatedPuck::new(
                    puck,
                    &config,
                    counts_per_rad,
                    contact_counts,
                ));
            }
        }
        Ok(HandEmulator {
            clock,
            pucks,
            boot: config.boot,
            stats: EmulatorStats::default(),
            feel: None,
        })
    }

    /// The same emulator with contacts from `feel` instead of fixed angles.
    pub fn with_feel(mut self, feel: Box<dyn Feel>) -> HandEmulator {
        self.feel = Some(feel);
        for p in &mut self.pucks {
            p.lets_go_when_opened = true;
        }
        self
    }

    /// Before a frame: a held object that slipped out leaves the fingers (so
    /// the frame's answer already tells); a command that may close a finger
    /// (CMD C, TC, IC, M; MODE 5; a new M or P) while none presses on the object
    /// asks `feel` where the fingers stall.
    fn feel_before(&mut self, frame: &CanFrame, now: Duration) {
        let Some(feel) = self.feel.as_mut() else {
            return;
        };
        for p in &mut self.pucks {
            p.update(now);
        }
        if self.pucks.iter().any(EmulatedPuck::pressing) && !feel.still_held() {
            tracing::info!("emulated hand: the object slipped out");
            for p in &mut self.pucks {
                p.contact_counts = None;
            }
        }
        let address = split_id(frame.id());
        let closing = match decode_request(frame.data()) {
            Ok(Request::Set(id, value)) => {
                (id == Property::Cmd.id()
                    && [command::C, command::TC, command::IC, command::M].contains(&value))
                    || (id == Property::Mode.id() && value == mode::TRAPEZOIDAL)
                    || id == Property::M.id()
                    || id == Property::P.id()
            }
            _ => false,
        };
        let to_finger = self
            .pucks
            .iter()
            .any(|p| p.puck.is_finger() && p.listens_to(address));
        if !closing || !to_finger || self.pucks.iter().any(EmulatedPuck::pressing) {
            return;
        }
        let mut start = crate::robot::HandPose::OPEN;
        for p in &self.pucks {
            let rad = p.position / p.counts_per_rad;
            match p.puck {
                Puck::Spread => start.spread_rad = rad,
                finger => start.flex_rad[finger.index()] = rad,
            }
        }
        // A finger already on its way keeps the contact it set out for (its
        // motion stalls there): the fingers are sent one at a time, and the world
        // asked again from a start with a finger half closed may answer a hair
        // differently; the finger would stall at the old angle and, its contact
        // moved, not count as pressing (no strain on the executor's side).
        let contacts = feel.contacts(&start);
        for p in &mut self.pucks {
            if p.puck.is_finger() && p.motion.is_none() {
                p.contact_counts = contacts[p.puck.index()].map(|rad| rad * p.counts_per_rad);
            }
        }
    }

    /// After a frame: the hand's state goes to `feel`.
    fn feel_after(&mut self, now: Duration) {
        let Some(feel) = self.feel.as_mut() else {
            return;
        };
        for p in &mut self.pucks {
            p.update(now);
        }
        let holding = self.pucks.iter().any(EmulatedPuck::pressing);
        let mut pose = crate::robot::HandPose::OPEN;
        for p in &self.pucks {
            let rad = p.position / p.counts_per_rad;
            match p.puck {
                Puck::Spread => pose.spread_rad = rad,
                finger => pose.flex_rad[finger.index()] = rad,
            }
        }
        feel.hand_moved(&pose, holding);
    }

    /// Frame counts so far.
    pub fn stats(&self) -> EmulatorStats {
        self.stats
    }

    /// A present puck's position (counts), now.
    pub fn position_counts(&mut self, puck: Puck) -> Option<i32> {
        let now = self.clock.now();
        self.puck_mut(puck).map(|p| {
            p.update(now);
            p.position.round() as i32
        })
    }

    /// A present puck's property value, now.
    pub fn property(&mut self, puck: Puck, property: Property) -> Option<i32> {
        let now = self.clock.now();
        self.puck_mut(puck).map(|p| {
            p.update(now);
            p.read(property.id())
        })
    }

    /// Moves (or removes) the object a puck closes on.
    pub fn set_contact(&mut self, puck: Puck, contact_rad: Option<f64>) {
        if let Some(p) = self.puck_mut(puck) {
            p.contact_counts = contact_rad.map(|rad| rad * p.counts_per_rad);
        }
    }

    fn puck_mut(&mut self, puck: Puck) -> Option<&mut EmulatedPuck> {
        self.pucks.iter_mut().find(|p| p.puck == puck)
    }

    /// Handles one frame from the bus; returns the replies to send.
    pub fn handle(&mut self, frame: &CanFrame) -> Vec<CanFrame> {
        self.stats.received += 1;
        let now = self.clock.now();
        self.feel_before(frame, now);
        let address = split_id(frame.id());
        let mut replies = Vec::new();
        for p in &mut self.pucks {
            if !p.listens_to(address) {
                continue;
            }
            p.update(now);
            let request = match decode_request(frame.data()) {
                Ok(request) => request,
                Err(problem) => {
                    self.stats.garbled += 1;
                    tracing::debug!(puck = %p.puck, %frame, "ignored garbled frame: {problem}");
                    continue;
                }
            };
            match request {
                Request::Get(id) => {
                    if let Some(reply) = p.get(id, address.to_group) {
                        replies.push(reply);
                    }
                }
                Request::Set(id, value) => p.set(id, value, now, self.boot),
            }
        }
        self.stats.replies += replies.len() as u64;
        self.feel_after(now);
        replies
    }

    /// Serves `bus` until `stop` is set or the bus fails (the error is returned).
    pub fn run<B: CanBus + ?Sized>(
        &mut self,
        bus: &mut B,
        stop: &AtomicBool,
    ) -> Result<(), CanError> {
        while !stop.load(Ordering::SeqCst) {
            if let Some(frame) = bus.recv(Duration::from_millis(20))? {
                for reply in self.handle(&frame) {
                    bus.send(&reply)?;
                }
            }
        }
        Ok(())
    }

    /// Serves `bus` on a new thread.
    pub fn spawn<B: CanBus + 'static>(mut self, mut bus: B) -> EmulatorThread {
        let stop = Arc::new(AtomicBool::new(false));
        let flag = Arc::clone(&stop);
        let handle = std::thread::Builder::new()
            .name("hand-emulator".into())
            .spawn(move || {
                let result = self.run(&mut bus, &flag);
                if let Err(e) = &result {
                    tracing::error!("hand emulator stopped: {e}");
                }
                (self, result)
            })
            .map_err(|e| tracing::error!("cannot start the hand emulator thread: {e}"))
            .ok();
        EmulatorThread { stop, handle }
    }
}

/// A [`HandEmulator`] serving a bus on its own thread.
pub struct EmulatorThread {
    stop: Arc<AtomicBool>,
    handle: Option<JoinHandle<(HandEmulator, Result<(), CanError>)>>,
}

impl EmulatorThread {
    /// Stops the thread; returns the emulator (for inspection) and how its loop
    /// ended (`None` if the thread never started).
    pub fn stop(mut self) -> Option<(HandEmulator, Result<(), CanError>)> {
        self.stop.store(true, Ordering::SeqCst);
        let handle = self.handle.take()?;
        match handle.join() {
            Ok(result) => Some(result),
            Err(panic) => std::panic::resume_unwind(panic),
        }
    }
}

impl Drop for EmulatorThread {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::SeqCst);
        if let Some(handle) = self.handle.take() {
            let _ = handle.join();
        }
    }
}

/// A trapezoidal move under way.
#[derive(Debug, Clone, Copy)]
struct Motion {
    start: Duration,
    from: f64,
    to: f64,
    /// Acceleration (counts/s^2), peak speed (counts/s) and phase durations (s).
    accel: f64,
    peak_speed: f64,
    ramp_s: f64,
    cruise_s: f64,
    moving_mode: i32,
    end_mode: i32,
    /// Where and when (s after start) it meets the object.
    stall: Option<(f64, f64)>,
    /// Stall time after which the move ends (`None`: never).
    tstop_s: Option<f64>,
}

/// What a move command asks of the motor: the target, the trapezoid's limits, and
/// the modes during and after the move.
#[derive(Debug, Clone, Copy)]
struct MoveRequest {
    /// Target position (counts).
    to: f64,
    /// Cruise speed (counts/s).
    speed: f64,
    /// Acceleration (counts/s^2).
    accel: f64,
    /// MODE while moving.
    moving_mode: i32,
    /// MODE once the move ends.
    end_mode: i32,
}

impl Motion {
    /// The move from `from` (counts) that `request` asks for, starting at `start`;
    /// it stalls at `contact` (counts) if closing reaches it, and ends `tstop_ms`
    /// after stalling (never for 0).
    fn new(
        start: Duration,
        from: f64,
        request: MoveRequest,
        contact: Option<f64>,
        tstop_ms: i32,
    ) -> Motion {
        let MoveRequest {
            to,
            speed,
            accel,
            moving_mode,
            end_mode,
        } = request;
        let distance = (to - from).abs();
        let (mut ramp_s, mut peak_speed) = (speed / accel, speed);
        let cruise_s = if accel * ramp_s * ramp_s >= distance {
            ramp_s = (distance / accel).sqrt();
            peak_speed = accel * ramp_s;
            0.0
        } else {
            (distance - accel * ramp_s * ramp_s) / speed
        };
        let mut motion = Motion {
            start,
            from,
            to,
            accel,
            peak_speed,
            ramp_s,
            cruise_s,
            moving_mode,
            end_mode,
            stall: None,
            tstop_s: (tstop_ms > 0).then(|| f64::from(tstop_ms) / 1000.0),
        };
        // Only closing (increasing counts) meets the object.
        if let Some(c) = contact {
            if to > from && c < to {
                let at = c.max(from);
                motion.stall = Some((at, motion.time_to(at - from)));
            }
        }
        motion
    }

    fn duration_s(&self) -> f64 {
        2.0 * self.ramp_s + self.cruise_s
    }

    /// Distance covered after `t` s.
    fn covered(&self, t: f64) -> f64 {
        let total = (self.to - self.from).abs();
        let ramp = 0.5 * self.accel * self.ramp_s * self.ramp_s;
        if t <= 0.0 {
            0.0
        } else if t < self.ramp_s {
            0.5 * self.accel * t * t
        } else if t < self.ramp_s + self.cruise_s {
            ramp + self.peak_speed * (t - self.ramp_s)
        } else if t < self.duration_s() {
            let left = self.duration_s() - t;
            total - 0.5 * self.accel * left * left
        } else {
            total
        }
    }

    /// Time at which `distance` is covered (bisection; the profile is monotonic).
    fn time_to(&self, distance: f64) -> f64 {
        let (mut lo, mut hi) = (0.0, self.duration_s());
        for _ in 0..64 {
            let mid = 0.5 * (lo + hi);
            if self.covered(mid) < distance {
                lo = mid;
            } else {
                hi = mid;
            }
        }
        hi
    }
}

struct EmulatedPuck {
    puck: Puck,
    props: [i32; 128],
    counts_per_rad: f64,
    contact_counts: Option<f64>,
    contact_strain: i32,
    position: f64,
    /// With a [`Feel`]: a finger sent no farther than its contact lets go of the
    /// object ([`EmulatedPuck::start_move`]).
    lets_go_when_opened: bool,
    motion: Option<Motion>,
    booting_until: Option<Duration>,
    homed: bool,
}

impl EmulatedPuck {
    fn new(
        puck: Puck,
        config: &HandEmulatorConfig,
        counts_per_rad: f64,
        contact_counts: Option<f64>,
    ) -> EmulatedPuck {
        let finger = puck.is_finger();
        let mut props = [0; 128];
        let mut put = |p: Property, v: i32| props[usize::from(p.id())] = v;
        put(Property::Vers, config.firmware_version);
        put(
            Property::Role,
            role::HAND | if finger { role::STRAIN_GAUGE } else { 0 },
        );
        put(Property::Stat, status::RESET);
        put(Property::Mode, mode::IDLE);
        put(Property::Temp, 31);
        put(Property::Grpa, i32::from(group::ALL));
        put(Property::Grpb, i32::from(group::HAND_SECONDARY));
        put(Property::Grpc, i32::from(group::HAND));
        put(Property::Mt, if finger { 990 } else { 1500 });
        let speed = if finger { 200 } else { 60 };
        put(Property::Mv, speed);
        put(Property::Mcv, speed);
        put(Property::Mov, speed);
        put(Property::Ct, if finger { 195_000 } else { 35_950 });
        put(Property::Ot, 0);
        put(Property::Ds, if finger { 2_500 } else { 500 });
        put(Property::Cts, COUNTS_PER_REV);
        put(Property::Hsg, 10_000);
        put(Property::Hold, i32::from(!finger));
        put(Property::Tstop, 0);
        put(Property::Kp, 500);
        put(Property::Kd, 5_000);
        put(Property::Accel, 2);
        put(Property::Ipnm, 2_755);
        EmulatedPuck {
            puck,
            props,
            counts_per_rad,
            contact_counts,
            contact_strain: config.contact_strain,
            position: f64::from(config.initial_counts[puck.index()]),
            lets_go_when_opened: false,
            motion: None,
            booting_until: None,
            homed: false,
        }
    }

    fn prop(&self, p: Property) -> i32 {
        self.props[usize::from(p.id())]
    }

    fn put(&mut self, p: Property, v: i32) {
        self.props[usize::from(p.id())] = v;
    }

    fn listens_to(&self, address: puck::Address) -> bool {
        if address.source == self.puck.node() {
            return false;
        }
        if address.to_group {
            [Property::Grpa, Property::Grpb, Property::Grpc]
                .iter()
                .any(|&g| self.prop(g) == i32::from(address.destination))
        } else {
            address.destination == self.puck.node()
        }
    }

    /// Brings boot and motion up to `now`.
    fn update(&mut self, now: Duration) {
        if let Some(until) = self.booting_until {
            if now >= until {
                self.booting_until = None;
                self.put(Property::Stat, status::READY);
            }
        }
        let Some(m) = self.motion else {
            return;
        };
        let t = now.saturating_sub(m.start).as_secs_f64();
        let direction = (m.to - m.from).signum();
        match m.stall {
            Some((at, t_contact)) if t >= t_contact => {
                self.position = at;
                match m.tstop_s {
                    Some(tstop) if t >= t_contact + tstop => self.finish(m.end_mode),
                    _ => self.put(Property::Mode, m.moving_mode),
                }
            }
            _ if t >= m.duration_s() => {
                self.position = m.to;
                self.finish(m.end_mode);
            }
            _ => {
                self.position = m.from + direction * m.covered(t);
                self.put(Property::Mode, m.moving_mode);
            }
        }
    }

    fn finish(&mut self, end_mode: i32) {
        self.motion = None;
        self.put(Property::Mode, end_mode);
    }

    /// A finger resting on (or pushing into) its contact.
    fn pressing(&self) -> bool {
        self.puck.is_finger()
            && self
                .contact_counts
                .is_some_and(|c| self.position >= c - 0.5)
    }

    fn ready(&self) -> bool {
        self.booting_until.is_none() && self.prop(Property::Stat) == status::READY
    }

    fn read(&self, id: u8) -> i32 {
        match Property::from_id(id) {
            Some(Property::P) => self.position.round() as i32,
            Some(Property::Sg) if self.puck.is_finger() => {
                2000 + if self.pressing() {
                    self.contact_strain
                } else {
                    0
                }
            }
            _ => self.props[usize::from(id & 0x7F)],
        }
    }

    fn get(&self, id: u8, to_group: bool) -> Option<CanFrame> {
        if self.booting_until.is_some() {
            return None;
        }
        let monitor_answers = [Property::Stat, Property::Vers, Property::Role]
            .iter()
            .any(|p| p.id() == id);
        if !self.ready() && !monitor_answers {
            return None;
        }
        let value = self.read(id);
        if id == Property::P.id() && to_group {
            // Counts beyond 22 bits cannot occur: positions stay within +-2^21.
            return puck::position_reply_frame(self.puck.node(), value).ok();
        }
        Some(puck::property_reply_frame(self.puck.node(), id, value))
    }

    fn set(&mut self, id: u8, value: i32, now: Duration, boot: Duration) {
        let value = if is_wide(id) {
            value
        } else {
            i32::from(value as i16)
        };
        let Some(property) = Property::from_id(id) else {
            self.props[usize::from(id & 0x7F)] = value;
            return;
        };
        if property == Property::Stat {
            match value {
                status::READY
                    if self.prop(Property::Stat) == status::RESET
                        && self.booting_until.is_none() =>
                {
                    self.booting_until = Some(now + boot);
                }
                status::RESET => {
                    self.booting_until = None;
                    self.motion = None;
                    self.put(Property::Stat, status::RESET);
                    self.put(Property::Mode, mode::IDLE);
                }
                _ => {}
            }
            return;
        }
        if !self.ready() {
            return;
        }
        match property {
            Property::Vers | Property::Sg | Property::Temp => {}
            Property::Mode => self.set_mode(value, now),
            Property::Cmd => self.command(value, now),
            Property::P => {
                if self.prop(Property::Mode) == mode::PID && self.homed {
                    let speed = self.prop(Property::Mv);
                    self.start_move(value, speed, mode::PID, Some(mode::PID), now);
                }
            }
            Property::M => {
                self.put(Property::M, value);
                if self.homed {
                    let speed = self.prop(Property::Mv);
                    self.start_move(value, speed, mode::TRAPEZOIDAL, None, now);
                }
            }
            _ => self.put(property, value),
        }
    }

    fn set_mode(&mut self, value: i32, now: Duration) {
        match value {
            mode::TRAPEZOIDAL if self.homed => {
                let target = self.prop(Property::E);
                let speed = self.prop(Property::Mv);
                self.start_move(target, speed, mode::TRAPEZOIDAL, None, now);
            }
            mode::TRAPEZOIDAL => {
                tracing::debug!(puck = %self.puck, "MODE 5 before HI ignored");
            }
            other => {
                // Idle, hold, and the streaming modes (not emulated): stop here.
                self.motion = None;
                self.put(Property::Mode, other);
            }
        }
    }

    fn command(&mut self, value: i32, now: Duration) {
        let p = self.position.round() as i32;
        let (ct, ot, ds) = (
            self.prop(Property::Ct),
            self.prop(Property::Ot),
            self.prop(Property::Ds),
        );
        let (mcv, mov, mv) = (
            self.prop(Property::Mcv),
            self.prop(Property::Mov),
            self.prop(Property::Mv),
        );
        if matches!(value, command::HI | command::HOME) {
            self.homed = true;
            self.start_move(0, mov, mode::TRAPEZOIDAL, None, now);
            return;
        }
        if !self.homed {
            tracing::debug!(puck = %self.puck, command = command::name(value), "motion before HI ignored");
            return;
        }
        let (target, speed) = match value {
            command::C | command::TC => (ct, mcv),
            command::O | command::TO => (ot, mov),
            command::M => (self.prop(Property::Dp), mv),
            command::IC => ((p + ds).min(ct), mcv),
            command::IO => ((p - ds).max(ot), mov),
            command::RESET => {
                self.motion = None;
                self.put(Property::Mode, mode::IDLE);
                return;
            }
            _ => return,
        };
        self.start_move(target, speed, mode::TRAPEZOIDAL, None, now);
    }

    fn start_move(
        &mut self,
        target: i32,
        speed_counts_per_ms: i32,
        moving_mode: i32,
        end_mode: Option<i32>,
        now: Duration,
    ) {
        let end_mode = end_mode.unwrap_or(if self.prop(Property::Hold) != 0 {
            mode::PID
        } else {
            mode::IDLE
        });
        let speed = f64::from(speed_counts_per_ms.max(1)) * 1e3;
        let accel = f64::from(self.prop(Property::Accel).max(1)) * 1e6;
        // A finger sent no farther than its contact (opening the hand) does not
        // push on the object: with a [`Feel`] it lets go, and the next closing
        // asks where the object is. A contact at the open angle (a finger that
        // touches the object before it closes) would otherwise count as pressing
        // for ever, open hand included: the arm's side would be told that the hand
        // holds the object, and feel no contact on the next approach.
        if self.lets_go_when_opened
            && self.puck.is_finger()
            && self
                .contact_counts
                .is_some_and(|c| f64::from(target) <= c + 0.5)
        {
            self.contact_counts = None;
        }
        let request = MoveRequest {
            to: f64::from(target),
            speed,
            accel,
            moving_mode,
            end_mode,
        };
        self.motion = Some(Motion::new(
            now,
            self.position,
            request,
            self.contact_counts,
            self.prop(Property::Tstop),
        ));
        self.put(Property::Mode, moving_mode);
        self.update(now);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::clock::ManualClock;
    use crate::hw::hand::puck::{get_frame, group_id, node_id, set_frame};

    fn emulator(config: HandEmulatorConfig) -> (HandEmulator, ManualClock) {
        let clock = ManualClock::new();
        (
            HandEmulator::new(config, Arc::new(clock.clone())).unwrap(),
            clock,
        )
    }

    fn ask(emu: &mut HandEmulator, to: u16, p: Property) -> Vec<CanFrame> {
        emu.handle(&get_frame(to, p))
    }

    fn boot_and_home(emu: &mut HandEmulator, clock: &ManualClock) {
        for puck in Puck::ALL {
            emu.handle(&set_frame(node_id(puck.node()), Property::Stat, 2));
        }
        clock.advance(Duration::from_secs(1));
        emu.handle(&set_frame(group_id(5), Property::Cmd, command::HI));
        clock.advance(Duration::from_secs(5));
    }

    #[test]
    fn reset_pucks_answer_only_monitor_properties_then_boot() {
        let (mut emu, clock) = emulator(HandEmulatorConfig::default());
        let role = ask(&mut emu, 11, Property::Role);
        assert_eq!(role.len(), 1);
        assert_eq!(role[0].id(), 0x566);
        assert_eq!(role[0].data(), &[0x81, 0, 0x05, 0x08]);
        assert!(ask(&mut emu, 11, Property::Cts).is_empty());
        emu.handle(&set_frame(11, Property::Stat, 2));
        // Silent while booting.
        assert!(ask(&mut emu, 11, Property::Stat).is_empty());
        clock.advance(Duration::from_millis(300));
        assert_eq!(
            ask(&mut emu, 11, Property::Stat)[0].data(),
            &[0x85, 0, 2, 0]
        );
        // Other nodes' frames are not answered.
        assert!(ask(&mut emu, 15, Property::Stat).is_empty());
        assert!(emu.handle(&get_frame(0x566, Property::Stat)).is_empty());
    }

    #[test]
    fn group_get_of_p_gets_22_bit_replies_from_all_four() {
        let (mut emu, clock) = emulator(HandEmulatorConfig {
            initial_counts: [-1000, 0, 1000, 5],
            ..HandEmulatorConfig::default()
        });
        for puck in Puck::ALL {
            emu.handle(&set_frame(node_id(puck.node()), Property::Stat, 2));
        }
        clock.advance(Duration::from_secs(1));
        let replies = ask(&mut emu, group_id(5), Property::P);
        let text: Vec<String> = replies.iter().map(|f| f.to_string()).collect();
        assert_eq!(
            text,
            ["563#BFFC18", "583#800000", "5A3#8003E8", "5C3#800005"]
        );
        // Addressed to one puck, P is a 32-bit property reply on group 6.
        assert_eq!(
            ask(&mut emu, 11, Property::P)[0].to_string(),
            "566#B00018FCFFFF"
        );
    }

    #[test]
    fn trapezoidal_close_takes_finite_time_and_stalls_on_contact() {
        let contact_rad = 1.0;
        let (mut emu, clock) = emulator(HandEmulatorConfig {
            contact_rad: [Some(contact_rad), None, None, None],
            ..HandEmulatorConfig::default()
        });
        boot_and_home(&mut emu, &clock);
        assert_eq!(emu.position_counts(Puck::F1), Some(0));
        emu.handle(&set_frame(11, Property::Tstop, 50));
        emu.handle(&set_frame(12, Property::Tstop, 50));
        emu.handle(&set_frame(group_id(5), Property::Cmd, command::C));
        // Accelerating at 2e6 counts/s^2: after 50 ms, 0.5 * 2e6 * 0.05^2 = 2500.
        clock.advance(Duration::from_millis(50));
        assert_eq!(emu.position_counts(Puck::F2), Some(2500));
        assert_eq!(
            emu.property(Puck::F2, Property::Mode),
            Some(mode::TRAPEZOIDAL)
        );
        // F2 is free: ramp up 0.1 s (10,000 counts), cruise (195,000 - 20,000) /
        // 200,000 = 0.875 s, ramp down 0.1 s: 1.075 s in all, then idle (HOLD = 0).
        clock.advance(Duration::from_millis(1024));
        assert_eq!(
            emu.property(Puck::F2, Property::Mode),
            Some(mode::TRAPEZOIDAL)
        );
        clock.advance(Duration::from_millis(2));
        assert_eq!(emu.position_counts(Puck::F2), Some(195_000));
        assert_eq!(emu.property(Puck::F2, Property::Mode), Some(mode::IDLE));
        // F1 stalled at its contact and, TSTOP later, stopped there.
        let contact = (contact_rad * Puck::F1.counts_per_rad(4096)).round() as i32;
        assert_eq!(emu.position_counts(Puck::F1), Some(contact));
        assert_eq!(emu.property(Puck::F1, Property::Mode), Some(mode::IDLE));
        assert_eq!(emu.property(Puck::F1, Property::Sg), Some(2900));
        assert_eq!(emu.property(Puck::F2, Property::Sg), Some(2000));
        // F3 had TSTOP = 0 but no object: it arrives as well. The spread (HOLD = 1)
        // closed to its CT and holds.
        assert_eq!(emu.position_counts(Puck::F3), Some(195_000));
        assert_eq!(emu.position_counts(Puck::Spread), Some(35_950));
        assert_eq!(emu.property(Puck::Spread, Property::Mode), Some(mode::PID));
    }

    /// A scripted object: F1 touches it at the open angle, F2 at 1 rad; it stays
    /// in the hand; the emulator's reports are kept.
    struct Touching {
        asked: Arc<std::sync::atomic::AtomicUsize>,
        holding: Arc<AtomicBool>,
    }

    impl Feel for Touching {
        fn contacts(&mut self, _start: &crate::robot::HandPose) -> [Option<f64>; 3] {
            self.asked.fetch_add(1, Ordering::SeqCst);
            [Some(0.0), Some(1.0), None]
        }
        fn still_held(&mut self) -> bool {
            true
        }
        fn hand_moved(&mut self, _pose: &crate::robot::HandPose, holding: bool) {
            self.holding.store(holding, Ordering::SeqCst);
        }
    }

    /// Opening the hand lets go of the object, also one a finger touched at the
    /// open angle: the hand no longer reports holding it, and the next closing
    /// asks the world again. (It used to count as held for ever, so the arm's
    /// simulator felt no object on every later approach.)
    #[test]
    fn opening_the_hand_lets_go_of_an_object_touched_at_the_open_angle() {
        let (emu, clock) = emulator(HandEmulatorConfig::default());
        let asked = Arc::new(std::sync::atomic::AtomicUsize::new(0));
        let holding = Arc::new(AtomicBool::new(false));
        let mut emu = emu.with_feel(Box::new(Touching {
            asked: asked.clone(),
            holding: holding.clone(),
        }));
        boot_and_home(&mut emu, &clock);
        emu.handle(&set_frame(group_id(5), Property::Cmd, command::C));
        clock.advance(Duration::from_secs(5));
        emu.handle(&get_frame(11, Property::Sg));
        assert!(holding.load(Ordering::SeqCst));
        assert_eq!(asked.load(Ordering::SeqCst), 1);
        assert_eq!(emu.property(Puck::F1, Property::Sg), Some(2900));
        emu.handle(&set_frame(group_id(5), Property::Cmd, command::O));
        clock.advance(Duration::from_secs(5));
        emu.handle(&get_frame(11, Property::Sg));
        assert!(
            !holding.load(Ordering::SeqCst),
            "the open hand holds nothing"
        );
        assert_eq!(emu.property(Puck::F1, Property::Sg), Some(2000));
        assert_eq!(emu.position_counts(Puck::F2), Some(0));
        emu.handle(&set_frame(group_id(5), Property::Cmd, command::C));
        assert_eq!(
            asked.load(Ordering::SeqCst),
            2,
            "the next closing asks again"
        );
        clock.advance(Duration::from_secs(5));
        emu.handle(&get_frame(11, Property::Sg));
        assert!(holding.load(Ordering::SeqCst));
    }

    /// A world that answers a hair differently at every ask: the closing as the
    /// static auto-grasp sees it from a start with a finger half closed.
    struct Shifting {
        asked: usize,
    }

    impl Feel for Shifting {
        fn contacts(&mut self, _start: &crate::robot::HandPose) -> [Option<f64>; 3] {
            self.asked += 1;
            [Some(1.0 + 0.01 * self.asked as f64); 3]
        }
        fn still_held(&mut self) -> bool {
            true
        }
        fn hand_moved(&mut self, _pose: &crate::robot::HandPose, _holding: bool) {}
    }

    /// The driver closes the fingers one at a time (CMD C to F1, F2, F3). Each
    /// finger presses where it stalled, whatever the world answered when the next
    /// finger was sent: every finger feels the object. (A finger on its way used
    /// to take the later answer, stall at the earlier one and show no strain: the
    /// executor then stopped with "no_contact" on grasps that hold.)
    #[test]
    fn fingers_closed_one_at_a_time_each_press_where_they_stall() {
        let (emu, clock) = emulator(HandEmulatorConfig::default());
        let mut emu = emu.with_feel(Box::new(Shifting { asked: 0 }));
        boot_and_home(&mut emu, &clock);
        for node in [11, 12, 13] {
            emu.handle(&set_frame(node, Property::Cmd, command::C));
            clock.advance(Duration::from_millis(5));
        }
        clock.advance(Duration::from_secs(5));
        for finger in Puck::FINGERS {
            assert_eq!(emu.property(finger, Property::Sg), Some(2900), "{finger}");
        }
        let f1 = emu.position_counts(Puck::F1).unwrap();
        let f3 = emu.position_counts(Puck::F3).unwrap();
        assert!(
            f1 < f3,
            "each stalled where the world said when it was sent"
        );
    }

    #[test]
    fn without_tstop_a_stalled_finger_pushes_forever() {
        let (mut emu, clock) = emulator(HandEmulatorConfig {
            contact_rad: [Some(0.5), None, None, None],
            ..HandEmulatorConfig::default()
        });
        boot_and_home(&mut emu, &clock);
        emu.handle(&set_frame(11, Property::Cmd, command::C));
        clock.advance(Duration::from_secs(60));
        assert_eq!(
            emu.property(Puck::F1, Property::Mode),
            Some(mode::TRAPEZOIDAL)
        );
        // Stopping (MODE 3) holds it where it is.
        emu.handle(&set_frame(11, Property::Mode, mode::PID));
        assert_eq!(emu.property(Puck::F1, Property::Mode), Some(mode::PID));
        // Opening moves away from the object without stalling.
        emu.handle(&set_frame(11, Property::Tstop, 50));
        emu.handle(&set_frame(11, Property::Cmd, command::O));
        clock.advance(Duration::from_secs(5));
        assert_eq!(emu.position_counts(Puck::F1), Some(0));
    }

    #[test]
    fn incremental_default_and_streamed_moves_go_where_specified() {
        let (mut emu, clock) = emulator(HandEmulatorConfig::default());
        boot_and_home(&mut emu, &clock);
        let mut step = |frame: CanFrame| {
            emu.handle(&frame);
            clock.advance(Duration::from_secs(3));
            emu.position_counts(Puck::F2).unwrap()
        };
        step(set_frame(12, Property::Ds, 1000));
        assert_eq!(step(set_frame(12, Property::Cmd, command::IC)), 1000);
        assert_eq!(step(set_frame(12, Property::Cmd, command::IC)), 2000);
        assert_eq!(step(set_frame(12, Property::Cmd, command::IO)), 1000);
        step(set_frame(12, Property::Dp, 5000));
        assert_eq!(step(set_frame(12, Property::Cmd, command::M)), 5000);
        assert_eq!(step(set_frame(12, Property::M, 7000)), 7000);
        step(set_frame(12, Property::E, 9000));
        assert_eq!(step(set_frame(12, Property::Mode, mode::TRAPEZOIDAL)), 9000);
        step(set_frame(12, Property::Mode, mode::PID));
        assert_eq!(step(set_frame(12, Property::P, 8000)), 8000);
        assert_eq!(emu.property(Puck::F2, Property::Mode), Some(mode::PID));
        // IO stops at the open target. (DS is a 16-bit property: at most 32767.)
        emu.handle(&set_frame(12, Property::Ds, 30_000));
        emu.handle(&set_frame(12, Property::Cmd, command::IO));
        clock.advance(Duration::from_secs(3));
        assert_eq!(emu.position_counts(Puck::F2), Some(0));
    }

    #[test]
    fn motion_before_hi_is_ignored_and_garbage_is_counted() {
        let (mut emu, clock) = emulator(HandEmulatorConfig::default());
        for puck in Puck::ALL {
            emu.handle(&set_frame(node_id(puck.node()), Property::Stat, 2));
        }
        clock.advance(Duration::from_secs(1));
        emu.handle(&set_frame(11, Property::Cmd, command::C));
        clock.advance(Duration::from_secs(2));
        assert_eq!(emu.position_counts(Puck::F1), Some(4000));
        emu.handle(&CanFrame::new(11, &[0x9D, 0x00, 0x12]).unwrap());
        assert_eq!(emu.stats().garbled, 1);
    }

    #[test]
    fn absent_puck_never_answers_and_bad_contact_is_named() {
        let (mut emu, _clock) = emulator(HandEmulatorConfig {
            present: [true, true, false, true],
            ..HandEmulatorConfig::default()
        });
        assert!(ask(&mut emu, 13, Property::Role).is_empty());
        assert_eq!(ask(&mut emu, group_id(5), Property::Role).len(), 3);
        let err = HandEmulator::new(
            HandEmulatorConfig {
                contact_rad: [None, Some(3.0), None, None],
                ..HandEmulatorConfig::default()
            },
            Arc::new(ManualClock::new()),
        )
        .err()
        .unwrap()
        .to_string();
        assert!(err.contains("F2") && err.contains("3 rad"), "{err}");
    }
}
