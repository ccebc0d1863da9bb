//! Injected monotonic time, so that timing logic can be tested without sleeping.
//!
//! Code that needs "now" takes a [`Clock`]; processes pass [`SystemClock`], tests pass
//! [`ManualClock`] and advance it by hand.

use std::sync::Mutex;
use std::time::{Duration, Instant};

/// A monotonic clock: time elapsed since the clock's own epoch.
pub trait Clock: Send + Sync {
    /// Monotonic time since the clock's epoch; never decreases.
    fn now(&self) -> Duration;
}

/// The process's monotonic clock; its epoch is the moment it was created.
#[derive(Debug, Clone, Copy)]
pub struct SystemClock {
    epoch: Instant,
}

impl SystemClock {
    /// A clock reading zero now.
    pub fn new() -> SystemClock {
        SystemClock {
            epoch: Instant::now(),
        }
    }
}

impl Default for SystemClock {
    fn default() -> SystemClock {
        SystemClock::new()
    }
}

impl Clock for SystemClock {
    fn now(&self) -> Duration {
        self.epoch.elapsed()
    }
}

/// A clock that only moves when told to (for tests).
#[derive(Debug, Default)]
pub struct ManualClock {
    now: Mutex<Duration>,
}

impl ManualClock {
    /// A clock reading `start`.
    pub fn new(start: Duration) -> ManualClock {
        ManualClock {
            now: Mutex::new(start),
        }
    }

    /// Moves the clock forward by `step`.
    pub fn advance(&self, step: Duration) {
        let mut now = self.now.lock().unwrap_or_else(|e| e.into_inner());
        *now += step;
    }

    /// Sets the clock to `t`; a `t` earlier than the current reading is ignored
    /// (the clock is monotonic).
    pub fn set(&self, t: Duration) {
        let mut now = self.now.lock().unwrap_or_else(|e| e.into_inner());
        *now = (*now).max(t);
    }
}

impl Clock for ManualClock {
    fn now(&self) -> Duration {
        *self.now.lock().unwrap_or_else(|e| e.into_inner())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn manual_clock_moves_only_forward_and_when_told() {
        let clock = ManualClock::new(Duration::from_millis(5));
        assert_eq!(clock.now(), Duration::from_millis(5));
        clock.advance(Duration::from_micros(1500));
        assert_eq!(clock.now(), Duration::from_micros(6500));
        clock.set(Duration::from_millis(1));
        assert_eq!(clock.now(), Duration::from_micros(6500));
        clock.set(Duration::from_millis(10));
        assert_eq!(clock.now(), Duration::from_millis(10));
    }

    #[test]
    fn system_clock_is_monotonic() {
        let clock = SystemClock::new();
        let a = clock.now();
        let b = clock.now();
        assert!(b >= a);
    }
}
