//! Injected time: drivers and emulators read time and wait through a [`Clock`], so
//! tests run on a [`ManualClock`] that never sleeps for real.
//!
//! Time is a [`Duration`] since the clock's epoch. [`SystemClock`]'s epoch is the Unix
//! epoch, but its time advances monotonically (it is anchored once, then follows
//! [`Instant`]), so it serves both for deadlines and for log timestamps.
//!
//! Calendar dates: [`format_utc`] is the crate's one formatter of UTC times (RFC 3339,
//! proleptic Gregorian calendar), used by the trial log's timestamps and the
//! calibration files.

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

/// How finely [`format_utc`] writes the time of day.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum UtcPrecision {
    /// Whole seconds: `2025-01-31T10:00:00Z`.
    Seconds,
    /// Milliseconds: `2025-01-31T10:00:00.250Z`.
    Millis,
}

/// Milliseconds since the Unix epoch now, by the system's wall clock (negative
/// before the epoch).
pub fn unix_ms_now() -> i64 {
    match SystemTime::now().duration_since(UNIX_EPOCH) {
        Ok(d) => i64::try_from(d.as_millis()).unwrap_or(i64::MAX),
        Err(e) => -i64::try_from(e.duration().as_millis()).unwrap_or(i64::MAX),
    }
}

/// Days since 1970-01-01 of a proleptic Gregorian date (H. Hinnant's algorithm).
pub fn days_from_civil(year: i64, month: u32, day: u32) -> i64 {
    let y = if month <= 2 { year - 1 } else { year };
    let era = y.div_euclid(400);
    let yoe = y - era * 400;
    let m = i64::from(month);
    let doy = (153 * (if m > 2 { m - 3 } else { m + 9 }) + 2) / 5 + i64::from(day) - 1;
    let doe = yoe * 365 + yoe / 4 - yoe / 100 + doy;
    era * 146_097 + doe - 719_468
}

/// The date (year, month, day) of a day count since 1970-01-01.
pub fn civil_from_days(days: i64) -> (i64, u32, u32) {
    let z = days + 719_468;
    let era = z.div_euclid(146_097);
    let doe = z - era * 146_097;
    let yoe = (doe - doe / 1460 + doe / 36_524 - doe / 146_096) / 365;
    let doy = doe - (365 * yoe + yoe / 4 - yoe / 100);
    let mp = (5 * doy + 2) / 153;
    let day = (doy - (153 * mp + 2) / 5 + 1) as u32;
    let month = if mp < 10 { mp + 3 } else { mp - 9 } as u32;
    let year = yoe + era * 400 + i64::from(month <= 2);
    (year, month, day)
}

/// `unix_ms` (milliseconds since the Unix epoch) as RFC 3339 UTC,
/// `YYYY-MM-DDTHH:MM:SS[.mmm]Z` (the fraction truncated to `precision`).
pub fn format_utc(unix_ms: i64, precision: UtcPrecision) -> String {
    let days = unix_ms.div_euclid(86_400_000);
    let ms_of_day = unix_ms.rem_euclid(86_400_000);
    let (year, month, day) = civil_from_days(days);
    let secs = ms_of_day / 1000;
    let fraction = match precision {
        UtcPrecision::Seconds => String::new(),
        UtcPrecision::Millis => format!(".{:03}", ms_of_day % 1000),
    };
    format!(
        "{year:04}-{month:02}-{day:02}T{:02}:{:02}:{:02}{fraction}Z",
        secs / 3600,
        secs / 60 % 60,
        secs % 60
    )
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

    #[test]
    fn formats_known_dates() {
        let secs = |unix_s: i64| format_utc(unix_s * 1000, UtcPrecision::Seconds);
        assert_eq!(secs(0), "1970-01-01T00:00:00Z");
        // 2000-02-29 (leap day) 12:34:56 UTC.
        assert_eq!(secs(951_827_696), "2000-02-29T12:34:56Z");
        assert_eq!(secs(1_735_689_599), "2024-12-31T23:59:59Z");
        assert_eq!(secs(-1), "1969-12-31T23:59:59Z");
        assert_eq!(
            format_utc(1_709_208_000_250, UtcPrecision::Millis),
            "2024-02-29T12:00:00.250Z"
        );
        assert_eq!(
            format_utc(1_709_208_000_999, UtcPrecision::Seconds),
            "2024-02-29T12:00:00Z"
        );
        for days in [-800_000, -1, 0, 59, 11_016, 2_932_896] {
            let (y, m, d) = civil_from_days(days);
            assert_eq!(days_from_civil(y, m, d), days);
        }
    }
}
