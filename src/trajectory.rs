//! Time-parametrised joint trajectories within per-joint velocity and acceleration
//! limits.
//!
//! A [`Trajectory`] visits a list of waypoints, stopping at each one. Each segment is
//! a straight line in joint space, `q(t) = q0 + s(t) (q1 - q0)`, with one trapezoidal
//! (or, for short moves, triangular) profile `s(t)` from 0 to 1 shared by all joints,
//! so the joints start and arrive together and the path does not depend on the
//! timing. The profile is the fastest one along that line: it uses the largest
//! path speed and acceleration every joint allows, so at least one joint reaches
//! its acceleration limit, and its velocity limit when there is room to cruise. When
//! one joint is the slowest in both respects the segment takes exactly that joint's
//! own minimal time ([`minimal_duration_s`]).
//!
//! Limits are plain arrays (rad/s, rad/s^2); position limits are the safety layer's
//! business, not the trajectory's.

/// Errors of building a trajectory; each names the offending value.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum TrajectoryError {
    /// A limit is not a finite number > 0.
    #[error("{what} limit of joint {joint} is {value}; must be a finite number > 0")]
    BadLimit {
        /// `velocity` or `acceleration`.
        what: &'static str,
        /// Zero-based joint index.
        joint: usize,
        /// The value given.
        value: f64,
    },
    /// A waypoint holds NaN or an infinity.
    #[error("waypoint {waypoint}, joint {joint} is {value}; must be finite")]
    NonFiniteWaypoint {
        /// Zero-based waypoint index.
        waypoint: usize,
        /// Zero-based joint index.
        joint: usize,
        /// The value given.
        value: f64,
    },
    /// No waypoint was given.
    #[error("a trajectory needs at least one waypoint, got none")]
    NoWaypoints,
    /// A sampling period is not a finite number > 0.
    #[error("sampling period {cycle_s} s must be a finite number > 0")]
    BadCycle {
        /// The period given (s).
        cycle_s: f64,
    },
}

/// Per-joint velocity and acceleration limits.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct JointLimits<const N: usize> {
    /// Maximum speed of each joint (rad/s).
    pub velocity_rad_s: [f64; N],
    /// Maximum acceleration of each joint (rad/s^2).
    pub acceleration_rad_s2: [f64; N],
}

impl<const N: usize> JointLimits<N> {
    /// Checked limits: every value finite and > 0.
    pub fn new(
        velocity_rad_s: [f64; N],
        acceleration_rad_s2: [f64; N],
    ) -> Result<JointLimits<N>, TrajectoryError> {
        let limits = JointLimits {
            velocity_rad_s,
            acceleration_rad_s2,
        };
        limits.validate()?;
        Ok(limits)
    }

    /// Checks every value is finite and > 0.
    pub fn validate(&self) -> Result<(), TrajectoryError> {
        for (what, values) in [
            ("velocity", &self.velocity_rad_s),
            ("acceleration", &self.acceleration_rad_s2),
        ] {
            for (joint, &value) in values.iter().enumerate() {
                if !(value.is_finite() && value > 0.0) {
                    return Err(TrajectoryError::BadLimit { what, joint, value });
                }
            }
        }
        Ok(())
    }
}

/// Position, velocity and acceleration of every joint at one instant.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct JointSample<const N: usize> {
    /// Joint positions (rad).
    pub position: [f64; N],
    /// Joint velocities (rad/s).
    pub velocity: [f64; N],
    /// Joint accelerations (rad/s^2).
    pub acceleration: [f64; N],
}

/// The shortest time (s) one joint needs to move `distance_rad` from rest to rest
/// with speed at most `velocity_rad_s` and acceleration at most `acceleration_rad_s2`.
pub fn minimal_duration_s(distance_rad: f64, velocity_rad_s: f64, acceleration_rad_s2: f64) -> f64 {
    let d = distance_rad.abs();
    if d * acceleration_rad_s2 >= velocity_rad_s * velocity_rad_s {
        d / velocity_rad_s + velocity_rad_s / acceleration_rad_s2
    } else {
        2.0 * (d / acceleration_rad_s2).sqrt()
    }
}

/// A rest-to-rest trapezoidal profile of the path parameter s from 0 to 1.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Profile {
    /// Path acceleration (1/s^2).
    accel: f64,
    /// Peak path speed (1/s).
    peak: f64,
    /// Duration of the acceleration (and of the deceleration) phase (s).
    t_accel: f64,
    /// Duration of the constant-speed phase (s).
    t_cruise: f64,
    /// Total duration (s).
    duration: f64,
}

impl Profile {
    /// Fastest profile with path speed <= `speed` and acceleration <= `accel`.
    fn new(speed: f64, accel: f64) -> Profile {
        if speed * speed >= accel {
            // Triangular: never reaches `speed`.
            let t_accel = (1.0 / accel).sqrt();
            Profile {
                accel,
                peak: accel * t_accel,
                t_accel,
                t_cruise: 0.0,
                duration: 2.0 * t_accel,
            }
        } else {
            let t_accel = speed / accel;
            let t_cruise = 1.0 / speed - t_accel;
            Profile {
                accel,
                peak: speed,
                t_accel,
                t_cruise,
                duration: 2.0 * t_accel + t_cruise,
            }
        }
    }

    /// (s, ds/dt, d2s/dt2) at time `t` (clamped to the profile).
    fn eval(&self, t: f64) -> (f64, f64, f64) {
        if t <= 0.0 {
            (0.0, 0.0, 0.0)
        } else if t < self.t_accel {
            (0.5 * self.accel * t * t, self.accel * t, self.accel)
        } else if t < self.t_accel + self.t_cruise {
            let s_accel = 0.5 * self.accel * self.t_accel * self.t_accel;
            (s_accel + self.peak * (t - self.t_accel), self.peak, 0.0)
        } else if t < self.duration {
            let to_go = self.duration - t;
            (
                1.0 - 0.5 * self.accel * to_go * to_go,
                self.accel * to_go,
                -self.accel,
            )
        } else {
            (1.0, 0.0, 0.0)
        }
    }
}

/// One straight, rest-to-rest move between two waypoints.
#[derive(Debug, Clone, PartialEq)]
struct Segment<const N: usize> {
    start: [f64; N],
    end: [f64; N],
    profile: Profile,
}

impl<const N: usize> Segment<N> {
    /// The fastest straight move, or `None` when start and end coincide.
    fn new(start: [f64; N], end: [f64; N], limits: &JointLimits<N>) -> Option<Segment<N>> {
        let mut speed = f64::INFINITY;
        let mut accel = f64::INFINITY;
        for j in 0..N {
            let d = (end[j] - start[j]).abs();
            if d > 0.0 {
                speed = speed.min(limits.velocity_rad_s[j] / d);
                accel = accel.min(limits.acceleration_rad_s2[j] / d);
            }
        }
        accel.is_finite().then(|| Segment {
            start,
            end,
            profile: Profile::new(speed, accel),
        })
    }

    fn sample(&self, t: f64) -> JointSample<N> {
        if t >= self.profile.duration {
            return JointSample {
                position: self.end,
                velocity: [0.0; N],
                acceleration: [0.0; N],
            };
        }
        let (s, ds, dds) = self.profile.eval(t);
        JointSample {
            // (1 - s) q0 + s q1 is exactly q0 at s = 0 and exactly q1 at s = 1.
            position: std::array::from_fn(|j| (1.0 - s) * self.start[j] + s * self.end[j]),
            velocity: std::array::from_fn(|j| ds * (self.end[j] - self.start[j])),
            acceleration: std::array::from_fn(|j| dds * (self.end[j] - self.start[j])),
        }
    }
}

/// A joint trajectory through waypoints, at rest at each of them.
#[derive(Debug, Clone, PartialEq)]
pub struct Trajectory<const N: usize> {
    start: [f64; N],
    segments: Vec<Segment<N>>,
    /// Start time of each segment (s).
    start_times_s: Vec<f64>,
    duration_s: f64,
    limits: JointLimits<N>,
}

impl<const N: usize> Trajectory<N> {
    /// The fastest straight move from `q0` to `q1` (rad).
    pub fn point_to_point(
        q0: [f64; N],
        q1: [f64; N],
        limits: &JointLimits<N>,
    ) -> Result<Trajectory<N>, TrajectoryError> {
        Trajectory::through(&[q0, q1], limits)
    }

    /// Straight moves through `waypoints` (rad), stopping at each. A single waypoint
    /// gives a trajectory of zero duration; repeated waypoints are skipped.
    pub fn through(
        waypoints: &[[f64; N]],
        limits: &JointLimits<N>,
    ) -> Result<Trajectory<N>, TrajectoryError> {
        limits.validate()?;
        for (waypoint, q) in waypoints.iter().enumerate() {
            if let Some((joint, &value)) = q.iter().enumerate().find(|(_, v)| !v.is_finite()) {
                return Err(TrajectoryError::NonFiniteWaypoint {
                    waypoint,
                    joint,
                    value,
                });
            }
        }
        let start = *waypoints.first().ok_or(TrajectoryError::NoWaypoints)?;
        let mut segments = Vec::new();
        let mut start_times_s = Vec::new();
        let mut t = 0.0;
        for pair in waypoints.windows(2) {
            if let Some(segment) = Segment::new(pair[0], pair[1], limits) {
                start_times_s.push(t);
                t += segment.profile.duration;
                segments.push(segment);
            }
        }
        Ok(Trajectory {
            start,
            segments,
            start_times_s,
            duration_s: t,
            limits: *limits,
        })
    }

    /// Total duration (s).
    pub fn duration_s(&self) -> f64 {
        self.duration_s
    }

    /// The first waypoint (rad).
    pub fn start(&self) -> [f64; N] {
        self.start
    }

    /// The last waypoint (rad).
    pub fn end(&self) -> [f64; N] {
        self.segments.last().map_or(self.start, |s| s.end)
    }

    /// The limits it was built with.
    pub fn limits(&self) -> &JointLimits<N> {
        &self.limits
    }

    /// The state at time `t_s`; before the start it is the start, after the end the
    /// end, both exactly and at rest.
    pub fn sample(&self, t_s: f64) -> JointSample<N> {
        let at_rest = |position| JointSample {
            position,
            velocity: [0.0; N],
            acceleration: [0.0; N],
        };
        if self.segments.is_empty() || t_s <= 0.0 || t_s.is_nan() {
            return at_rest(self.start);
        }
        if t_s >= self.duration_s {
            return at_rest(self.end());
        }
        // The last segment starting at or before t.
        let k = self.start_times_s.partition_point(|&t0| t0 <= t_s) - 1;
        self.segments[k].sample(t_s - self.start_times_s[k])
    }

    /// Positions every `cycle_s` from 0 up to the end; the last is the end exactly.
    pub fn positions_every(&self, cycle_s: f64) -> Result<Vec<[f64; N]>, TrajectoryError> {
        if !(cycle_s.is_finite() && cycle_s > 0.0) {
            return Err(TrajectoryError::BadCycle { cycle_s });
        }
        let steps = (self.duration_s / cycle_s).ceil() as usize;
        Ok((0..=steps)
            .map(|k| self.sample(k as f64 * cycle_s).position)
            .collect())
    }
}

/// A stop from motion: all joints decelerate together, along the current direction
/// of motion, and come to rest within their acceleration limits.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StopProfile<const N: usize> {
    position: [f64; N],
    velocity: [f64; N],
    duration_s: f64,
}

impl<const N: usize> StopProfile<N> {
    /// The shortest synchronised stop from `position` moving at `velocity` (rad, rad/s):
    /// each joint decelerates uniformly to zero in the time the slowest needs.
    pub fn new(position: [f64; N], velocity: [f64; N], limits: &JointLimits<N>) -> StopProfile<N> {
        let duration_s = (0..N)
            .map(|j| velocity[j].abs() / limits.acceleration_rad_s2[j])
            .fold(0.0, f64::max);
        StopProfile {
            position,
            velocity,
            duration_s,
        }
    }

    /// Time to come to rest (s).
    pub fn duration_s(&self) -> f64 {
        self.duration_s
    }

    /// Where the joints come to rest (rad).
    pub fn rest_position(&self) -> [f64; N] {
        self.sample(self.duration_s).position
    }

    /// The state `t_s` after the stop began.
    pub fn sample(&self, t_s: f64) -> JointSample<N> {
        let t = t_s.clamp(0.0, self.duration_s);
        if self.duration_s == 0.0 {
            return JointSample {
                position: self.position,
                velocity: [0.0; N],
                acceleration: [0.0; N],
            };
        }
        let moving = t < self.duration_s;
        JointSample {
            position: std::array::from_fn(|j| {
                self.position[j] + self.velocity[j] * (t - 0.5 * t * t / self.duration_s)
            }),
            velocity: std::array::from_fn(|j| self.velocity[j] * (1.0 - t / self.duration_s)),
            acceleration: std::array::from_fn(|j| {
                if moving {
                    -self.velocity[j] / self.duration_s
                } else {
                    0.0
                }
            }),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// LBR4+ speed limits (rad/s) from the spec table, and a moderate acceleration.
    fn limits() -> JointLimits<7> {
        let deg = std::f64::consts::PI / 180.0;
        JointLimits::new(
            [110.0, 110.0, 128.0, 128.0, 204.0, 184.0, 184.0].map(|v| v * deg),
            [2.0, 2.0, 2.5, 2.5, 4.0, 4.0, 4.0],
        )
        .unwrap()
    }

    /// Checks the sampled positions against the limits by finite differences.
    #[allow(clippy::needless_range_loop)] // j indexes the samples and the limits alike
    fn assert_within_limits(positions: &[[f64; 7]], dt: f64, limits: &JointLimits<7>) {
        for w in positions.windows(2) {
            for j in 0..7 {
                let v = (w[1][j] - w[0][j]).abs() / dt;
                assert!(
                    v <= limits.velocity_rad_s[j] * (1.0 + 1e-9),
                    "joint {j} speed {v} > {}",
                    limits.velocity_rad_s[j]
                );
            }
        }
        for w in positions.windows(3) {
            for j in 0..7 {
                let a = (w[2][j] - 2.0 * w[1][j] + w[0][j]).abs() / (dt * dt);
                assert!(
                    a <= limits.acceleration_rad_s2[j] * (1.0 + 1e-6),
                    "joint {j} acceleration {a} > {}",
                    limits.acceleration_rad_s2[j]
                );
            }
        }
    }

    #[test]
    fn long_move_respects_limits_and_hits_endpoints_exactly() {
        let l = limits();
        let q0 = [0.1, -0.3, 0.7, 1.1, -2.0, 0.4, 0.0];
        let q1 = [-1.3, 0.9, -0.2, 0.3, 1.5, -0.8, 2.5];
        let traj = Trajectory::point_to_point(q0, q1, &l).unwrap();
        let dt = 0.001;
        let p = traj.positions_every(dt).unwrap();
        assert_eq!(p[0], q0);
        assert_eq!(*p.last().unwrap(), q1);
        assert_eq!(traj.sample(traj.duration_s()).position, q1);
        assert_eq!(traj.sample(1e9).position, q1);
        assert_eq!(traj.sample(-1.0).position, q0);
        assert_within_limits(&p, dt, &l);
        // Also the analytic velocity and acceleration.
        for k in 0..=1000 {
            let s = traj.sample(traj.duration_s() * k as f64 / 1000.0);
            for j in 0..7 {
                assert!(s.velocity[j].abs() <= l.velocity_rad_s[j] * (1.0 + 1e-12));
                assert!(s.acceleration[j].abs() <= l.acceleration_rad_s2[j] * (1.0 + 1e-12));
            }
        }
    }

    #[test]
    fn duration_is_the_slowest_joints_minimum_when_one_joint_dominates() {
        let l = limits();
        // Joint 0 moves far (trapezoid), the others a little: joint 0 binds both.
        let q0 = [0.0; 7];
        let q1 = [2.5, 0.1, -0.1, 0.05, 0.2, -0.3, 0.1];
        let traj = Trajectory::point_to_point(q0, q1, &l).unwrap();
        // Independent: rest-to-rest trapezoid t = d/v + v/a when d >= v^2/a.
        let (d, v, a) = (2.5, l.velocity_rad_s[0], l.acceleration_rad_s2[0]);
        assert!(d >= v * v / a);
        let expected = d / v + v / a;
        assert!(
            (traj.duration_s() - expected).abs() < 1e-12,
            "{}",
            traj.duration_s()
        );
        // Short move: triangle t = 2 sqrt(d/a).
        let q1 = [0.2, 0.01, 0.0, 0.0, 0.0, 0.0, 0.0];
        let traj = Trajectory::point_to_point(q0, q1, &l).unwrap();
        assert!((traj.duration_s() - 2.0 * (0.2f64 / 2.0).sqrt()).abs() < 1e-12);
        // Every joint's own minimum is a lower bound, and some joint saturates.
        let q1 = [3.0, -1.0, 0.0, 0.2, 6.0, 0.0, -1.5];
        let traj = Trajectory::point_to_point(q0, q1, &l).unwrap();
        let lower = (0..7)
            .map(|j| minimal_duration_s(q1[j], l.velocity_rad_s[j], l.acceleration_rad_s2[j]))
            .fold(0.0, f64::max);
        assert!(traj.duration_s() >= lower - 1e-12);
        let peak_accel_ratio = (0..7)
            .map(|j| traj.sample(1e-6).acceleration[j].abs() / l.acceleration_rad_s2[j])
            .fold(0.0, f64::max);
        assert!((peak_accel_ratio - 1.0).abs() < 1e-9, "{peak_accel_ratio}");
        let mid = traj.sample(0.5 * traj.duration_s());
        let peak_speed_ratio = (0..7)
            .map(|j| mid.velocity[j].abs() / l.velocity_rad_s[j])
            .fold(0.0, f64::max);
        assert!((peak_speed_ratio - 1.0).abs() < 1e-9, "{peak_speed_ratio}");
    }

    #[test]
    fn joints_move_on_a_straight_line_and_arrive_together() {
        let l = limits();
        let q0 = [0.0; 7];
        let q1 = [1.0, -0.5, 0.25, 0.0, 2.0, -1.0, 0.5];
        let traj = Trajectory::point_to_point(q0, q1, &l).unwrap();
        for k in 1..100 {
            let p = traj.sample(traj.duration_s() * k as f64 / 100.0).position;
            let s = p[0] / q1[0];
            assert!(s > 0.0 && s < 1.0);
            for j in 0..7 {
                assert!((p[j] - s * q1[j]).abs() < 1e-12, "joint {j} off the line");
            }
        }
    }

    #[test]
    fn waypoints_are_visited_at_rest_in_order() {
        let l = limits();
        let w = [
            [0.0; 7],
            [0.5, 0.2, 0.0, 0.0, 0.0, 0.0, 0.0],
            [0.5, 0.2, 0.0, 0.0, 0.0, 0.0, 0.0],
            [-0.5, 0.4, 1.0, -0.3, 0.0, 0.2, 0.1],
        ];
        let traj = Trajectory::through(&w, &l).unwrap();
        let d1 = minimal_duration_s(0.5, l.velocity_rad_s[0], l.acceleration_rad_s2[0]);
        let at_first = traj.sample(d1);
        assert_eq!(at_first.position, w[1]);
        assert!(at_first.velocity.iter().all(|v| v.abs() < 1e-12));
        assert_eq!(traj.end(), w[3]);
        let dt = 0.001;
        let p = traj.positions_every(dt).unwrap();
        assert_within_limits(&p, dt, &l);
        assert_eq!(*p.last().unwrap(), w[3]);
        assert!(p.iter().any(|q| *q == w[1]));
        // A single waypoint is a zero-length trajectory at that point.
        let hold = Trajectory::through(&w[1..2], &l).unwrap();
        assert_eq!(hold.duration_s(), 0.0);
        assert_eq!(hold.positions_every(dt).unwrap(), vec![w[1]]);
    }

    #[test]
    fn bad_input_is_named() {
        let l = limits();
        let mut bad = l;
        bad.acceleration_rad_s2[3] = 0.0;
        assert_eq!(
            Trajectory::point_to_point([0.0; 7], [1.0; 7], &bad),
            Err(TrajectoryError::BadLimit {
                what: "acceleration",
                joint: 3,
                value: 0.0
            })
        );
        let mut q = [0.0; 7];
        q[5] = f64::NAN;
        assert!(matches!(
            Trajectory::through(&[[0.0; 7], q], &l),
            Err(TrajectoryError::NonFiniteWaypoint {
                waypoint: 1,
                joint: 5,
                ..
            })
        ));
        // Issue 21 item 4: a joint target at infinity, or starting at one.
        q[5] = f64::INFINITY;
        assert!(matches!(
            Trajectory::point_to_point([0.0; 7], q, &l),
            Err(TrajectoryError::NonFiniteWaypoint { joint: 5, .. })
        ));
        assert!(matches!(
            Trajectory::point_to_point(q, [0.0; 7], &l),
            Err(TrajectoryError::NonFiniteWaypoint { waypoint: 0, .. })
        ));
        assert_eq!(
            Trajectory::<7>::through(&[], &l),
            Err(TrajectoryError::NoWaypoints)
        );
        let traj = Trajectory::point_to_point([0.0; 7], [1.0; 7], &l).unwrap();
        assert_eq!(
            traj.positions_every(0.0),
            Err(TrajectoryError::BadCycle { cycle_s: 0.0 })
        );
    }

    #[test]
    fn stop_profile_comes_to_rest_within_acceleration_limits() {
        let l = limits();
        let q0 = [0.0; 7];
        let q1 = [2.0, -1.0, 0.5, 0.0, 1.0, 0.0, 0.3];
        let traj = Trajectory::point_to_point(q0, q1, &l).unwrap();
        let now = traj.sample(0.4 * traj.duration_s());
        let stop = StopProfile::new(now.position, now.velocity, &l);
        assert!(stop.duration_s() > 0.0);
        let dt = 0.001;
        let steps = (stop.duration_s() / dt).ceil() as usize + 5;
        let p: Vec<[f64; 7]> = (0..=steps)
            .map(|k| stop.sample(k as f64 * dt).position)
            .collect();
        // Prefix with the motion before the stop, so the transition is checked too.
        let mut all = vec![
            traj.sample(0.4 * traj.duration_s() - 2.0 * dt).position,
            traj.sample(0.4 * traj.duration_s() - dt).position,
        ];
        all.extend(p.iter().copied());
        assert_within_limits(&all, dt, &l);
        let rest = stop.sample(stop.duration_s());
        assert!(rest.velocity.iter().all(|v| *v == 0.0));
        assert_eq!(rest.position, stop.rest_position());
        // Braking distance v^2 / (2 a') per joint, with a' = v / T.
        for j in 0..7 {
            let expected = now.position[j] + 0.5 * now.velocity[j] * stop.duration_s();
            assert!((rest.position[j] - expected).abs() < 1e-12);
        }
        let still = StopProfile::new(q1, [0.0; 7], &l);
        assert_eq!(still.duration_s(), 0.0);
        assert_eq!(still.sample(1.0).position, q1);
    }
}
