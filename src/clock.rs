//! Injected time: drivers and emulators read time and wait through a [`Clock`], so
//! tests run on a [`ManualClock`] that never sleeps for real.
//!
//! Time is a [`Duration`] since the clock's epoch. [`SystemClock`]'s epoch is the Unix
//! epoch, but its time advances monotonically (it is anchored once, then follows
//! [`Instant`]), so it serves both for deadlines and for log timestamps.

use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};

/// A source of monotonic time that can also wait.
pub trait Clock: Send + Sync {
    /// Time since the clock's epoch; never decreases.
    fn now(&self) -> Duration;
    /// Waits for `duration` of this clock's time.
    fn sleep(&self, duration: Duration);
}

/// The real clock: Unix time at construction, then advancing with [`Instant`].
#[derive(Debug, Clone, Copy)]
pub struct SystemClock {
    anchor: Instant,
    anchor_since_epoch: Duration,
}

impl SystemClock {
    /// A clock anchored at the present instant.
    pub fn new() -> SystemClock {
        SystemClock {
            anchor: Instant::now(),
            anchor_since_epoch: SystemTime::now()
                .duration_since(UNIX_EPOCH)
                .unwrap_or_default(),
        }
    }
}

impl Default for SystemClock {
    fn default() -> Self {
        SystemClock::new()
    }
}

impl Clock for SystemClock {
    fn now(&self) -> Duration {
        self.anchor_since_epoch + self.anchor.elapsed()
    }

    fn sleep(&self, duration: Duration) {
        std::thread::sleep(duration);
    }
}

/// A clock for tests: time moves only when advanced; `sleep` advances it at once.
///
/// Clones share one time. Because `sleep` returns immediately after advancing, it
/// models one sleeping thread (the one under test); other threads should only read.
/// A settle hook ([`ManualClock::with_settle`]) lets `sleep` first wait until
/// simulated devices on other threads have handled what was sent to them, so they
/// see the time at which it was sent.
#[derive(Clone, Default)]
pub struct ManualClock {
    now: Arc<Mutex<Duration>>,
    settle: Option<Arc<dyn Fn() + Send + Sync>>,
}

impl std::fmt::Debug for ManualClock {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("ManualClock")
            .field("now", &self.now())
            .field("settle", &self.settle.is_some())
            .finish()
    }
}

impl ManualClock {
    /// A clock at time zero.
    pub fn new() -> ManualClock {
        ManualClock::default()
    }

    /// A clock at `start`.
    pub fn starting_at(start: Duration) -> ManualClock {
        ManualClock {
            now: Arc::new(Mutex::new(start)),
            settle: None,
        }
    }

    /// The same clock (shared time) whose `sleep` first calls `settle`.
    pub fn with_settle(&self, settle: impl Fn() + Send + Sync + 'static) -> ManualClock {
        ManualClock {
            now: Arc::clone(&self.now),
            settle: Some(Arc::new(settle)),
        }
    }

    /// Moves time forward by `duration`.
    pub fn advance(&self, duration: Duration) {
        let mut now = self.now.lock().unwrap_or_else(|e| e.into_inner());
        *now += duration;
    }

    /// Moves time forward to `t` (never backward).
    pub fn set(&self, t: Duration) {
        let mut now = self.now.lock().unwrap_or_else(|e| e.into_inner());
        *now = (*now).max(t);
    }
}

impl Clock for ManualClock {
    fn now(&self) -> Duration {
        *self.now.lock().unwrap_or_else(|e| e.into_inner())
    }

    fn sleep(&self, duration: Duration) {
        if let Some(settle) = &self.settle {
            settle();
        }
        self.advance(duration);
    }
}

impl<C: Clock + ?Sized> Clock for Arc<C> {
    fn now(&self) -> Duration {
        (**self).now()
    }

    fn sleep(&self, duration: Duration) {
        (**self).sleep(duration)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn manual_clock_moves_only_when_told_and_clones_share_time() {
        let clock = ManualClock::starting_at(Duration::from_secs(5));
        let other = clock.clone();
        assert_eq!(clock.now(), Duration::from_secs(5));
        clock.sleep(Duration::from_millis(250));
        other.advance(Duration::from_millis(750));
        assert_eq!(other.now(), Duration::from_secs(6));
        assert_eq!(clock.now(), Duration::from_secs(6));
    }

    #[test]
    fn settle_hook_runs_before_sleep_advances() {
        let clock = ManualClock::new();
        let seen = Arc::new(Mutex::new(Vec::new()));
        let log = Arc::clone(&seen);
        let observer = clock.clone();
        let settling = clock.with_settle(move || log.lock().unwrap().push(observer.now()));
        settling.sleep(Duration::from_secs(1));
        settling.sleep(Duration::from_secs(1));
        settling.advance(Duration::from_secs(1));
        assert_eq!(
            *seen.lock().unwrap(),
            [Duration::ZERO, Duration::from_secs(1)]
        );
        assert_eq!(clock.now(), Duration::from_secs(3));
    }

    #[test]
    fn system_clock_is_unix_time_and_monotonic() {
        let clock = SystemClock::new();
        let a = clock.now();
        let b = clock.now();
        assert!(b >= a);
        // After 2023-11-14 (1.7e9 s) and before 2100.
        assert!(
            a.as_secs() > 1_700_000_000 && a.as_secs() < 4_102_444_800,
            "{a:?}"
        );
    }
}
