//! The simulated robot and KRL program: [`SimConfig`], [`QualityThresholds`], and
//! the LBR4+ data-sheet limits.

use super::SimError;
use crate::hw::fri::JOINTS;

/// LBR4+ joint position limits, symmetric about zero (rad): ±170°, ±120° alternating.
pub const LBR4_POSITION_LIMIT_RAD: [f64; JOINTS] = [
    2.967_060, 2.094_395, 2.967_060, 2.094_395, 2.967_060, 2.094_395, 2.967_060,
];

/// LBR4+ joint velocity limits (rad/s): 110, 110, 128, 128, 204, 184, 184 deg/s.
pub const LBR4_VELOCITY_LIMIT_RAD_S: [f64; JOINTS] = [
    1.919_862, 1.919_862, 2.234_021, 2.234_021, 3.560_472, 3.211_406, 3.211_406,
];

/// When link quality is good enough for each level.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct QualityThresholds {
    /// Highest miss rate (0..=1) over a full window that is still PERFECT.
    pub perfect_max_miss_rate: f64,
    /// Highest miss rate that is still OK.
    pub ok_max_miss_rate: f64,
    /// Highest miss rate that is still BAD.
    pub bad_max_miss_rate: f64,
    /// Consecutive misses from which quality is at most BAD (one miss is bridged).
    pub bad_consecutive_misses: u32,
    /// Consecutive misses from which quality is UNACCEPTABLE.
    pub unacceptable_consecutive_misses: u32,
}

impl QualityThresholds {
    /// Thresholds from command-line text: miss rates `PERFECT,OK,BAD` (fractions)
    /// and consecutive misses `BAD,UNACCEPTABLE` (whole numbers). Checked fully by
    /// [`SimConfig::validate`].
    pub fn from_text(miss_rates: &str, consecutive_misses: &str) -> Result<Self, SimError> {
        let bad = |field: &str, value: &str, problem| SimError::BadConfig {
            field: field.to_string(),
            value: value.to_string(),
            problem,
        };
        let rates = crate::geometry::parse_numbers(miss_rates, 3, "miss rates")
            .map_err(|_| bad("quality miss rates", miss_rates, "expected PERFECT,OK,BAD"))?;
        let counts: Vec<u32> = consecutive_misses
            .split(',')
            .map(|t| t.trim().parse::<u32>())
            .collect::<Result<_, _>>()
            .ok()
            .filter(|c: &Vec<u32>| c.len() == 2)
            .ok_or_else(|| {
                bad(
                    "quality consecutive misses",
                    consecutive_misses,
                    "expected two whole numbers BAD,UNACCEPTABLE",
                )
            })?;
        Ok(QualityThresholds {
            perfect_max_miss_rate: rates[0],
            ok_max_miss_rate: rates[1],
            bad_max_miss_rate: rates[2],
            bad_consecutive_misses: counts[0],
            unacceptable_consecutive_misses: counts[1],
        })
    }
}

impl Default for QualityThresholds {
    fn default() -> QualityThresholds {
        QualityThresholds {
            perfect_max_miss_rate: 0.01,
            ok_max_miss_rate: 0.05,
            bad_max_miss_rate: 0.20,
            bad_consecutive_misses: 2,
            unacceptable_consecutive_misses: 5,
        }
    }
}

/// The simulated robot and KRL program.
#[derive(Debug, Clone, PartialEq)]
pub struct SimConfig {
    /// Measurement period (s); FRI allows 0.001 to 0.1.
    pub cycle_s: f64,
    /// Joint positions at start (rad).
    pub initial_joints_rad: [f64; JOINTS],
    /// Lower joint limits (rad).
    pub position_min_rad: [f64; JOINTS],
    /// Upper joint limits (rad).
    pub position_max_rad: [f64; JOINTS],
    /// Joint speed limits (rad/s).
    pub velocity_limit_rad_s: [f64; JOINTS],
    /// Time constant of the joints' first-order lag behind the command (s); 0 tracks
    /// the command exactly.
    pub tracking_time_constant_s: f64,
    /// Cycles of PERFECT quality after which the KRL program calls `friStart`.
    pub start_after_perfect_cycles: u32,
    /// Whether the KRL program calls `friStart` at all (else the robot stays in MON).
    pub auto_start: bool,
    /// Whether the KRL program calls `friStart` again after the link dropped the
    /// robot to monitor mode, or after the PC released it ([`RELEASE_BIT`]) and a
    /// PC clears the bit again (a loop around `friStart`, as cell programs have): it
    /// is back in command mode once quality has been PERFECT for
    /// `start_after_perfect_cycles` cycles. `friStop` and limit violations still end
    /// command mode for good.
    ///
    /// [`RELEASE_BIT`]: crate::hw::fri::RELEASE_BIT
    pub restart_after_drop: bool,
    /// Quality levels.
    pub quality: QualityThresholds,
    /// `sendSeqCount` of the first measurement.
    pub initial_seq_count: u16,
    /// Keep every answer latency (for benchmarks; grows without bound).
    pub record_latencies: bool,
}

impl Default for SimConfig {
    fn default() -> SimConfig {
        SimConfig {
            cycle_s: 0.001,
            initial_joints_rad: [0.0; JOINTS],
            position_min_rad: LBR4_POSITION_LIMIT_RAD.map(|l| -l),
            position_max_rad: LBR4_POSITION_LIMIT_RAD,
            velocity_limit_rad_s: LBR4_VELOCITY_LIMIT_RAD_S,
            tracking_time_constant_s: 0.0,
            start_after_perfect_cycles: 10,
            auto_start: true,
            restart_after_drop: false,
            quality: QualityThresholds::default(),
            initial_seq_count: 0,
            record_latencies: false,
        }
    }
}

impl SimConfig {
    /// Defaults with the joint position and velocity limits of `robot`'s URDF (the
    /// seven arm joints) instead of the LBR4+ data-sheet constants.
    pub fn from_robot(robot: &crate::robot::Robot) -> SimConfig {
        let arm = &robot.description.variables[..JOINTS];
        SimConfig {
            position_min_rad: std::array::from_fn(|j| arm[j].lower_rad),
            position_max_rad: std::array::from_fn(|j| arm[j].upper_rad),
            velocity_limit_rad_s: std::array::from_fn(|j| arm[j].velocity_rad_s),
            ..SimConfig::default()
        }
    }

    /// Checks every value is in range.
    pub fn validate(&self) -> Result<(), SimError> {
        let bad = |field: String, value: f64, problem| SimError::BadConfig {
            field,
            value: value.to_string(),
            problem,
        };
        if !(self.cycle_s.is_finite() && (0.001..=0.1).contains(&self.cycle_s)) {
            return Err(bad(
                "cycle_s".into(),
                self.cycle_s,
                "FRI cycles are 0.001 to 0.1 s",
            ));
        }
        if !(self.tracking_time_constant_s.is_finite() && self.tracking_time_constant_s >= 0.0) {
            return Err(bad(
                "tracking_time_constant_s".into(),
                self.tracking_time_constant_s,
                "must be a finite number >= 0",
            ));
        }
        for j in 0..JOINTS {
            let v = self.velocity_limit_rad_s[j];
            if !(v.is_finite() && v > 0.0) {
                return Err(bad(
                    format!("velocity_limit_rad_s[{j}]"),
                    v,
                    "must be a finite number > 0",
                ));
            }
            let (lo, hi) = (self.position_min_rad[j], self.position_max_rad[j]);
            if !(lo.is_finite() && hi.is_finite() && lo < hi) {
                return Err(bad(
                    format!("position_min_rad[{j}]"),
                    lo,
                    "must be finite and below position_max_rad",
                ));
            }
            let q = self.initial_joints_rad[j];
            if !(q > lo && q < hi) {
                return Err(bad(
                    format!("initial_joints_rad[{j}]"),
                    q,
                    "must lie strictly inside the joint limits",
                ));
            }
        }
        let t = &self.quality;
        for (field, rate) in [
            ("quality.perfect_max_miss_rate", t.perfect_max_miss_rate),
            ("quality.ok_max_miss_rate", t.ok_max_miss_rate),
            ("quality.bad_max_miss_rate", t.bad_max_miss_rate),
        ] {
            if !(0.0..=1.0).contains(&rate) {
                return Err(bad(field.into(), rate, "must be a fraction in 0..=1"));
            }
        }
        if t.bad_consecutive_misses < 2
            || t.unacceptable_consecutive_misses <= t.bad_consecutive_misses
        {
            return Err(bad(
                "quality.unacceptable_consecutive_misses".into(),
                t.unacceptable_consecutive_misses.into(),
                "need 2 <= bad_consecutive_misses < unacceptable_consecutive_misses",
            ));
        }
        Ok(())
    }
}
