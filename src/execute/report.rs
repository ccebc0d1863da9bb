//! What the executor reports about one grasp.

use super::path::PathMethod;
use super::{ExecuteError, Phase};
use crate::geometry::PoseJson;
use crate::hw::fri::JOINTS;
use crate::hw::hand::{HandPositions, MotionOutcome, Puck};
use serde::{Serialize, Serializer};

/// How the grasp ended.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Outcome {
    /// Lifted and held.
    Success,
    /// Stopped with an error.
    Failed,
}

/// One phase: when it ran (s since the run began, on the executor's clock).
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct PhaseReport {
    /// The phase.
    pub phase: Phase,
    /// Start (s since the run began).
    pub started_s: f64,
    /// Duration (s).
    pub duration_s: f64,
    /// Whether it completed.
    pub ok: bool,
}

/// One arm motion as planned and checked.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct MotionReport {
    /// For straight palm paths: how the line is followed.
    pub method: Option<PathMethod>,
    /// Configurations passed through, start included.
    pub waypoints: usize,
    /// Trajectory duration (s).
    pub duration_s: f64,
    /// Peak palm speed (m/s).
    pub peak_palm_speed_m_s: f64,
    /// Largest palm distance from the straight line (m), for straight paths.
    pub max_position_deviation_m: Option<f64>,
    /// Largest palm rotation from the interpolated orientation (rad), for straight paths.
    pub max_rotation_deviation_rad: Option<f64>,
}

/// Where the guarded approach stopped.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct ApproachReport {
    /// How far beyond the planned pose the approach could go (m).
    pub overtravel_m: f64,
    /// Whether it stopped on contact (else it went the whole way).
    pub contact: bool,
    /// The external TCP force over its start value that stopped it (N).
    pub contact_force_n: Option<f64>,
    /// Signed distance of the palm at rest beyond the planned pose, along the
    /// approach axis (m; negative: short of it).
    pub beyond_plan_m: f64,
}

/// What stopping did to each device after a failure.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct StopReport {
    /// The arm's state after the stop.
    pub arm: String,
    /// The hand's state after the stop, or why stopping it failed.
    pub hand: String,
}

/// The robot's return to command mode after it left it while the arm stood still
/// before the grasp's first motion (the grasp went on).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct RejoinReport {
    /// The phase in which the link check found the robot out of command mode.
    pub lost_in: Phase,
    /// What it found.
    pub link: String,
    /// How long the grasp waited for command mode (s, executor's clock).
    pub waited_s: f64,
    /// Largest joint difference between the arm's command after the return and the
    /// validated start of the pre-grasp move (rad).
    pub drift_rad: f64,
}

/// What releasing and parking after a grasp did ([`super::Executor::release_and_park`]).
#[derive(Debug, Clone, Default, Serialize)]
pub struct ParkReport {
    /// Down to where the lift began, with the object.
    pub put_down: Option<MotionReport>,
    /// Back along the approach to the pre-grasp, the hand open.
    pub retreat: Option<MotionReport>,
    /// To the park joints.
    pub park: Option<MotionReport>,
    /// The whole release and park (s, executor's clock).
    pub total_s: f64,
}

/// The executor's account of one grasp.
#[derive(Debug, Serialize)]
pub struct ExecutionReport {
    /// Success or failure.
    pub outcome: Outcome,
    /// The error's short name ([`ExecuteError::kind`]).
    pub error_kind: Option<&'static str>,
    /// The error (its message in JSON).
    #[serde(serialize_with = "display_option")]
    pub error: Option<ExecuteError>,
    /// The phase that failed.
    pub failed_phase: Option<Phase>,
    /// The phases run, in order.
    pub phases: Vec<PhaseReport>,
    /// The robot's return to command mode before the arm first moved, if it had
    /// left it.
    pub rejoin: Option<RejoinReport>,
    /// The move to the pre-grasp joints.
    pub pregrasp_move: Option<MotionReport>,
    /// The approach.
    pub approach: Option<MotionReport>,
    /// Where the approach to contact stopped.
    pub approach_stop: Option<ApproachReport>,
    /// The lift.
    pub lift: Option<MotionReport>,
    /// How each finger's close ended.
    pub close: Vec<MotionOutcome>,
    /// Fingers on the object after closing.
    pub fingers_in_contact: Vec<Puck>,
    /// Strain gauges of F1, F2, F3 with the hand open (raw counts).
    pub strain_baseline: Option<[i32; 3]>,
    /// Strain gauges at the last reading (raw counts).
    pub strain: Option<[i32; 3]>,
    /// Hand joint positions at the end (rad).
    pub hand_positions: Option<HandPositions>,
    /// Measured arm joints at the end (rad).
    pub final_joints_rad: Option<[f64; JOINTS]>,
    /// Palm pose at the end (forward kinematics of the measured joints).
    pub final_palm: Option<PoseJson>,
    /// What stopping did, after a failure.
    pub stop: Option<StopReport>,
    /// Whole run (s, executor's clock).
    pub total_s: f64,
}

impl ExecutionReport {
    /// An empty report, before anything ran.
    pub fn new() -> ExecutionReport {
        ExecutionReport {
            outcome: Outcome::Failed,
            error_kind: None,
            error: None,
            failed_phase: None,
            phases: Vec::new(),
            rejoin: None,
            pregrasp_move: None,
            approach: None,
            approach_stop: None,
            lift: None,
            close: Vec::new(),
            fingers_in_contact: Vec::new(),
            strain_baseline: None,
            strain: None,
            hand_positions: None,
            final_joints_rad: None,
            final_palm: None,
            stop: None,
            total_s: 0.0,
        }
    }

    /// One paragraph for people.
    pub fn human(&self) -> String {
        let mut text = match (&self.outcome, &self.error) {
            (Outcome::Success, _) => format!("grasp executed in {:.2} s\n", self.total_s),
            (Outcome::Failed, Some(e)) => format!(
                "grasp FAILED after {:.2} s [{}]: {e}\n",
                self.total_s,
                e.kind()
            ),
            (Outcome::Failed, None) => format!("grasp FAILED after {:.2} s\n", self.total_s),
        };
        for p in &self.phases {
            text += &format!(
                "  {:<13} {:>7.3} s .. {:>7.3} s  {}\n",
                p.phase.to_string(),
                p.started_s,
                p.started_s + p.duration_s,
                if p.ok { "ok" } else { "FAILED" }
            );
        }
        if let Some(r) = &self.rejoin {
            text += &format!(
                "  rejoined command mode after {:.2} s ({}), arm command moved {:.1e} rad meanwhile\n",
                r.waited_s, r.link, r.drift_rad
            );
        }
        for (name, motion) in [
            ("pregrasp move", &self.pregrasp_move),
            ("approach", &self.approach),
            ("lift", &self.lift),
        ] {
            if let Some(m) = motion {
                text += &format!(
                    "  {name}: {} waypoints{}, {:.2} s, palm <= {:.3} m/s{}\n",
                    m.waypoints,
                    m.method.map(|x| format!(" ({x:?})")).unwrap_or_default(),
                    m.duration_s,
                    m.peak_palm_speed_m_s,
                    m.max_position_deviation_m
                        .map(|d| format!(", off the line <= {:.2} mm", d * 1e3))
                        .unwrap_or_default()
                );
            }
        }
        if !self.fingers_in_contact.is_empty() {
            let names: Vec<String> = self
                .fingers_in_contact
                .iter()
                .map(|p| p.to_string())
                .collect();
            text += &format!("  in contact: {}\n", names.join(", "));
        }
        if let Some(h) = &self.hand_positions {
            let counts = |s: Option<[i32; 3]>| s.map_or("-".to_string(), |s| format!("{s:?}"));
            text += &format!(
                "  hand: fingers {:.3?} rad, spread {:.3} rad; strain {} (open {})\n",
                h.fingers_rad,
                h.spread_rad,
                counts(self.strain),
                counts(self.strain_baseline)
            );
        }
        if let Some(q) = &self.final_joints_rad {
            text += &format!("  arm joints {q:.4?} rad\n");
        }
        if let Some(p) = &self.final_palm {
            text += &format!("  palm at {:.4?} m\n", p.xyz);
        }
        if let Some(s) = &self.stop {
            text += &format!("  stop: arm {}; hand {}\n", s.arm, s.hand);
        }
        text
    }
}

impl Default for ExecutionReport {
    fn default() -> Self {
        ExecutionReport::new()
    }
}

fn display_option<S: Serializer, T: std::fmt::Display>(
    value: &Option<T>,
    serializer: S,
) -> Result<S::Ok, S::Error> {
    match value {
        Some(v) => serializer.collect_str(v),
        None => serializer.serialize_none(),
    }
}
